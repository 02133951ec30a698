"""Draw the geometry of the ``gravity_compensator`` effect: docs/compensator-geometry.png.

    python scripts/compensator_geometry.py [--out docs/compensator-geometry.png]

The view looks along the joint's axis (the plane normal to it): the upward direction (against
gravity), the base point ``d = base_m`` above the axis, the lever point ``a = lever_m`` along
the link towards the centre of mass the joint carries, the spring between them, and the angle
``phi = theta - theta_up`` from straight up (:func:`stiffness.mechanics.gravity.upward_angle`,
:func:`stiffness.mechanics.gravity.compensator_torque`). Lengths as the effect's defaults
(``a = 0.1 m``, ``d = 0.3 m``); the centre of mass at 0.45 m and ``phi = 35 deg`` for the
drawing.
"""

from __future__ import annotations

import argparse
import io
import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from stiffness.elastic.effects.preloads import COMPENSATOR_GEOMETRY  # noqa: E402
from stiffness.files import atomic_write  # noqa: E402

#: The drawn angle from straight up (rad) and the carried centre of mass's distance (m).
PHI = math.radians(35.0)
COM_M = 0.45


def _spring(p: np.ndarray, q: np.ndarray, turns: int = 9, width: float = 0.012) -> np.ndarray:
    """(k, 2) points of a zigzag spring from ``p`` to ``q`` (straight ends)."""
    direction = q - p
    length = float(np.linalg.norm(direction))
    along, normal = direction / length, np.array([-direction[1], direction[0]]) / length
    s = np.concatenate([[0.0, 0.15], np.linspace(0.15, 0.85, 2 * turns + 1), [0.85, 1.0]])
    side = np.zeros_like(s)
    side[2:-2] = width * np.array([0.0] + [(-1.0) ** i for i in range(2 * turns - 1)] + [0.0])
    return p + np.outer(s * length, along) + np.outer(side, normal)


def draw() -> plt.Figure:
    """The figure: axis, upward direction, base point, lever, spring, phi."""
    a, d = float(COMPENSATOR_GEOMETRY["lever_m"]), float(COMPENSATOR_GEOMETRY["base_m"])
    link = np.array([-math.sin(PHI), math.cos(PHI)])  # the link's direction, phi from up
    base, lever, com = np.array([0.0, d]), a * link, COM_M * link
    fig, ax = plt.subplots(figsize=(6.4, 5.2))
    ax.annotate("", xy=(0.0, 0.44), xytext=(0.0, 0.0),
                arrowprops={"arrowstyle": "->", "ls": "--", "color": "0.45"})
    ax.text(0.012, 0.43, "up (against gravity)", color="0.35", va="top")
    ax.plot([0.0, com[0] * 1.08], [0.0, com[1] * 1.08], color="tab:blue", lw=6, alpha=0.35,
            solid_capstyle="round")
    ax.text(*(com * 1.1 + np.array([-0.02, 0.0])), "link", color="tab:blue", ha="right")
    ax.plot(*com, "o", ms=10, mfc="white", mec="black")
    ax.plot(*com, "+", ms=10, color="black")
    ax.text(com[0] - 0.025, com[1], "centre of mass the joint\ncarries (zero load)",
            ha="right", va="center", fontsize=9)
    ax.annotate("", xy=(com[0], com[1] - 0.12), xytext=tuple(com),
                arrowprops={"arrowstyle": "->", "color": "tab:red"})
    ax.text(com[0] + 0.01, com[1] - 0.1, "m g", color="tab:red")
    spring = _spring(lever, base)
    ax.plot(spring[:, 0], spring[:, 1], color="tab:green", lw=1.5)
    ax.text(*(0.5 * (lever + base) + np.array([0.06, -0.02])),
            "spring k_s\nF = F0 + k_s (L - L(phi=0))", color="tab:green", fontsize=9)
    ax.plot(*base, "s", color="black")
    ax.text(base[0] + 0.015, base[1], "base point, d = base_m above the axis", va="center",
            fontsize=9)
    ax.plot(*lever, "o", color="black", ms=5)
    ax.text(lever[0] - 0.015, lever[1] - 0.005, "lever point,\na = lever_m along the link",
            ha="right", va="top", fontsize=9)
    ax.plot(0.0, 0.0, "o", ms=12, mfc="white", mec="black")
    ax.plot(0.0, 0.0, ".", color="black")
    ax.text(0.02, -0.03, "joint axis (normal to the page)", fontsize=9)
    arc = np.linspace(0.0, PHI, 30)
    ax.plot(-0.16 * np.sin(arc), 0.16 * np.cos(arc), color="black", lw=1)
    ax.text(-0.16 * math.sin(PHI / 2) - 0.005, 0.16 * math.cos(PHI / 2) + 0.01,
            "phi = theta - theta_up", ha="right", fontsize=9)
    ax.set_aspect("equal")
    ax.set_xlim(-0.5, 0.32)
    ax.set_ylim(-0.06, 0.47)
    ax.axis("off")
    ax.set_title("gravity_compensator: the spring's torque vanishes with the link straight up\n"
                 "and opposes the weight elsewhere", fontsize=10)
    fig.tight_layout()
    return fig


def main() -> None:
    """Write the figure (atomically)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/compensator-geometry.png",
                        help="PNG to write; default docs/compensator-geometry.png")
    args = parser.parse_args()
    buffer = io.BytesIO()
    draw().savefig(buffer, format="png", dpi=110)
    print(atomic_write(args.out, buffer.getvalue()))


if __name__ == "__main__":
    main()
