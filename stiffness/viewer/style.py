"""Formatting and colours: value labels, round numbers, colour maps and the scene's colours.

Each ellipsoid is coloured by its smallest principal stiffness ``k_min`` (N/m) on a linear
range: oranges for the enhanced formulation, blues for the conventional one, viridis for the
field (:data:`COLORMAPS`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

#: Colour maps (matplotlib names) of the ellipsoids, by formulation, and of the field.
COLORMAPS = {"enhanced": "Oranges", "conventional": "Blues", "field": "viridis"}
#: Legend text of each formulation.
FORMULATION_LABELS = {
    "enhanced": "enhanced, K_theta - K_C (A&S eq. 10)",
    "conventional": "conventional, K_theta (A&S eq. 8)",
}
#: Colour (RGBA, 0..1) of the deflected robot.
DEFLECTED_RGBA = (0.85, 0.1, 0.1, 0.35)
#: Colours of the force and moment arrows (0xRRGGBB).
FORCE_COLOR = 0x2CA02C
MOMENT_COLOR = 0x9467BD
#: Rotational block of a 6x6 stiffness or compliance.
ROTATIONAL_COLOR = 0x17BECF


def format_value(value: float, unit: str = "") -> str:
    """Three significant digits, compact exponent (``1.41e6 N/m``); ``inf`` for unbounded."""
    if not np.isfinite(value):
        text = "inf" if value > 0 else "-inf"
    else:
        text = f"{value:.3g}"
        if "e" in text:
            mantissa, exponent = text.split("e")
            text = f"{mantissa}e{int(exponent)}"
    return f"{text} {unit}".strip()


def nice_below(value: float) -> float:
    """Largest of 1, 2, 5 x 10^k not above ``value`` (> 0)."""
    exponent = np.floor(np.log10(value))
    base = 10.0 ** exponent
    for step in (5.0, 2.0, 1.0):
        if step * base <= value * (1 + 1e-12):
            return float(step * base)
    return float(base)


def nice_above(value: float) -> float:
    """Smallest of 1, 2, 5 x 10^k not below ``value`` (> 0)."""
    exponent = np.floor(np.log10(value))
    base = 10.0 ** exponent
    for step in (1.0, 2.0, 5.0, 10.0):
        if step * base >= value * (1 - 1e-12):
            return float(step * base)
    return float(10.0 * base)


def hex_color(rgb: Sequence[float]) -> str:
    return "#" + "".join(f"{int(round(255 * float(c))):02x}" for c in rgb[:3])


def rgb_int(rgb: Sequence[float]) -> int:
    return int(hex_color(rgb)[1:], 16)


def _colormap(name: str) -> Any:
    from matplotlib import colormaps

    return colormaps[name]


def color_of(name: str, fraction: float) -> tuple[float, float, float]:
    """Colour of ``fraction`` in [0, 1] on a map; sequential maps skip their whitish end."""
    fraction = float(np.clip(fraction, 0.0, 1.0))
    if name != "viridis":
        fraction = 0.35 + 0.6 * fraction
    r, g, b, _ = _colormap(name)(fraction)
    return (r, g, b)


def colorbar_colors(name: str, n: int = 9) -> list[str]:
    return [hex_color(color_of(name, f)) for f in np.linspace(0.0, 1.0, n)]
