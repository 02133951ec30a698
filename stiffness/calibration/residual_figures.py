"""The residual figures of the diagnosis pages: the x, y and z components of a residual before
and after the effects, row by row, against the noise (matplotlib, Agg, PNG bytes).

One drawing for both campaign kinds: a deflection campaign's tool deflection
(:func:`stiffness.calibration.diagnosis.residual_plot`) and each marker of a pose campaign
(:func:`stiffness.calibration.pose_diagnosis.marker_residual_plots`).
"""

from __future__ import annotations

import numpy as np

from stiffness.calibration.breakdown import finite_rms
from stiffness.figures import png


def residual_axes_png(before: np.ndarray, after: np.ndarray, sigma: float | None, unit: str,
                      title: str, boundaries: list[int] | None = None) -> bytes:
    """PNG: the x, y and z residual of each row, before (left column, crosses) and after (right
    column, dots), each panel on its own scale.

    Parameters
    ----------
    before, after
        (n, 3) residual components in ``unit``; NaN where not measured (not drawn).
    sigma
        Noise standard deviation in ``unit`` (a ±2 sigma band), or None (no band).
    unit
        Length unit of the values, named on the axes.
    title
        Title above the top panel.
    boundaries
        Row indices (0-based) where a new configuration starts: a thin vertical line before
        each (at most 30 drawn, none beyond).
    """
    from matplotlib.figure import Figure

    rows = np.arange(1, before.shape[0] + 1)
    lines = np.asarray(boundaries[1:] if boundaries and len(boundaries) <= 30 else [],
                       dtype=float)
    fig = Figure(figsize=(11, 7.5))
    axes = fig.subplots(3, 2, sharex=True)
    for col, (values, word) in enumerate(((before, "before"), (after, "after"))):
        for k in range(3):
            ax = axes[k, col]
            if sigma:
                ax.axhspan(-2 * sigma, 2 * sigma, color="0.88", label="±2 noise std")
            ax.plot(rows, values[:, k], "x" if col == 0 else "o", ms=4, color=f"C{k}")
            ax.axhline(0.0, color="0.3", lw=0.6)
            ax.set_ylabel(f"{'xyz'[k]} residual ({unit})")
            ax.grid(alpha=0.3)
            if lines.size:  # one collection, not a line each: full height, as axvline draws
                ax.vlines(lines + 0.5, 0.0, 1.0, transform=ax.get_xaxis_transform(),
                          colors="0.8", lw=0.5)
        axes[0, col].set_title(f"{word} (RMS {finite_rms(values):.3g} {unit})", fontsize=9)
        axes[-1, col].set_xlabel("measurement row")
    if sigma:
        axes[0, 1].legend(fontsize=8, loc="upper right")
    fig.suptitle(title, fontsize=9)
    fig.subplots_adjust(left=0.09, right=0.99, top=0.92, bottom=0.07, hspace=0.1, wspace=0.3)
    return png(fig, dpi=100)
