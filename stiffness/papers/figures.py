"""Figures of the SK120 report (matplotlib's Agg renderer, PNG bytes).

Figures are built with :class:`matplotlib.figure.Figure` directly, not through pyplot: no
global figure manager, no backend to select, nothing to close. Their margins are fixed in
inches (:func:`stiffness.figures.margins`: text has a fixed size in points) instead of a
layout engine's, which cost 40 % of their drawing time.
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from stiffness.figures import margins, png
from stiffness.mechanics.equilibrium import Departure
from stiffness.papers.reproduction import row_labels
from stiffness.workspace.definiteness import DefinitenessScan


def force_deflection(rows: list[dict]) -> bytes:
    """Table II per configuration (each loaded along its own direction): each model's residual
    against the measurement, ``|model - measured|`` (mm), against the load magnitude (N).

    ``rows``: :func:`stiffness.papers.reproduction.table2` (``config``, ``force_N``, and the
    deflections ``measured_mm``, ``paper_calculated_mm``, ``conventional_mm``,
    ``enhanced_mm``, ``exact_mm``).
    """
    models = (("conventional_mm", "conventional (eq. 8)", "o:"),
              ("enhanced_mm", "enhanced (eq. 10)", "^--"),
              ("exact_mm", "exact equilibrium", "s-"),
              ("paper_calculated_mm", "paper's calculated", "x-."))
    configs = list(dict.fromkeys(r["config"] for r in rows))
    fig = Figure(figsize=(4.6 * len(configs), 4.2))
    axes = fig.subplots(1, len(configs), squeeze=False, sharey=True)
    margins(fig, 0.75, 0.15, 1.0, 0.55, wspace=0.08, hspace=0.25)
    for ax, config in zip(axes[0], configs, strict=True):
        mine = [r for r in rows if r["config"] == config]
        force = np.array([r["force_N"] for r in mine])
        magnitude = np.linalg.norm(force, axis=1)
        measured = np.array([r["measured_mm"] for r in mine])
        for key, label, style in models:
            residual = np.linalg.norm(np.array([r[key] for r in mine]) - measured, axis=1)
            ax.plot(magnitude, residual, style, label=label, mfc="none")
        direction = force[-1] / magnitude[-1]
        ax.set_title(f"configuration {config}: load along "
                     f"({', '.join(f'{v:.2f}' for v in direction)})", fontsize=10)
        ax.set_xlabel("load magnitude (N)")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("|model - measured| deflection (mm)")
    fig.legend(*axes[0][0].get_legend_handles_labels(), loc="lower center", ncol=4,
               fontsize=9, bbox_to_anchor=(0.5, 0.01))
    return png(fig, dpi=110)


def partial_derivative_maps(scan: DefinitenessScan) -> bytes:
    """Figs. 7-9: the parts of C11, C22, C33 (eq. 16) over the Table IV grid, mm/rad.

    Part k of C_ii is dJ[k, i]/dtheta_i, i.e. C_ii for a unit force along axis k. Drawn as maps
    over the printed angles (q3, q2) at the grid's q1 nearest 0 (q1 turns the x and y parts
    about the vertical and leaves the z part unchanged).
    """
    diag = scan.k_c_diagonal * 1e3  # N.m/rad per N -> mm/rad
    q_deg = np.rad2deg(scan.coordinates[:, :3])
    q1_values = np.unique(np.round(q_deg[:, 0], 6))
    q1 = q1_values[np.argmin(np.abs(q1_values))]
    keep = np.abs(q_deg[:, 0] - q1) < 1e-6
    q2_axis, q2_index = np.unique(np.round(q_deg[keep, 1], 6), return_inverse=True)
    q3_axis, q3_index = np.unique(np.round(q_deg[keep, 2], 6), return_inverse=True)
    fig = Figure(figsize=(13, 10))
    axes = fig.subplots(3, 3, sharex=True, sharey=True)
    margins(fig, 0.75, 0.85, 0.55, 0.7, wspace=0.3, hspace=0.25)
    floor = 1e-3 * float(np.max(np.abs(diag[keep])))  # below: numerically zero
    for i in range(3):
        for k in range(3):
            grid = np.full((q2_axis.size, q3_axis.size), np.nan)
            grid[q2_index, q3_index] = diag[keep, k, i]
            ax = axes[k, i]
            limit = max(float(np.nanmax(np.abs(grid))), floor)
            mesh = ax.pcolormesh(q3_axis, q2_axis, grid, shading="nearest", cmap="RdBu_r",
                                 vmin=-limit, vmax=limit)
            fig.colorbar(mesh, ax=ax, label="mm/rad")
            ax.set_title(rf"C{i + 1}{i + 1}, {'xyz'[k]} part: "
                         rf"$\partial J_{{{'xyz'[k]}{i + 1}}}/\partial\theta_{i + 1}$",
                         fontsize=10)
            if i == 0:
                ax.set_ylabel("joint angle q2 (deg)")
            if k == 2:
                ax.set_xlabel("joint angle q3 (deg)")
    fig.suptitle(f"Parts of the diagonal of K_C per newton of load along x, y, z "
                 f"(q1 = {q1:.1f} deg, wrist vertical)", fontsize=11)
    return png(fig, dpi=110)


def linear_vs_exact(departure: Departure, reference_force_N: float) -> bytes:
    """Error of the linear predictions against the exact equilibrium, log-log in the load."""
    fig = Figure(figsize=(11, 4))
    ax1, ax2 = fig.subplots(1, 2)
    margins(fig, 0.75, 0.15, 0.55, 0.15, wspace=0.25, hspace=0.25)
    force = departure.scales * reference_force_N
    for pred, name, style in ((departure.conventional, "conventional", "o-"),
                              (departure.enhanced, "enhanced", "s-")):
        err = np.linalg.norm(pred - departure.exact, axis=1) * 1e3
        rate = departure.rate_conventional if name == "conventional" else departure.rate_enhanced
        ax1.loglog(force, err, style, label=f"{name} (log-log slope {rate:.2f})")
    ax1.set_xlabel("load magnitude (N)")
    ax1.set_ylabel("error against the exact equilibrium (mm)")
    ax1.legend()
    ax1.grid(alpha=0.3, which="both")
    ax2.plot(force, np.linalg.norm(departure.exact, axis=1) * 1e3, "k-",
             label="exact equilibrium")
    ax2.plot(force, np.linalg.norm(departure.enhanced, axis=1) * 1e3, "--", label="enhanced")
    ax2.plot(force, np.linalg.norm(departure.conventional, axis=1) * 1e3, ":", label="conventional")
    ax2.set_xscale("log")
    ax2.set_yscale("log")
    ax2.set_xlabel("load magnitude (N)")
    ax2.set_ylabel("deflection magnitude (mm)")
    ax2.legend()
    ax2.grid(alpha=0.3, which="both")
    return png(fig, dpi=110)


#: Colour of the map cells without a value.
NO_VALUE_GREY = "#b8b8b8"


def stiffness_map(theta2_deg: np.ndarray, theta3_deg: np.ndarray, minimum: np.ndarray,
                  ratio: np.ndarray, load_N: float) -> bytes:
    """Minimum principal stiffness (N/mm) over (theta2, theta3), and enhanced/conventional;
    cells without a value (NaN: the flat parallelogram, a singular stiffness) grey, counted in
    each panel's legend."""
    import matplotlib
    from matplotlib.patches import Patch

    fig = Figure(figsize=(12, 4.5))
    ax1, ax2 = fig.subplots(1, 2)
    margins(fig, 0.75, 0.85, 0.55, 0.35, wspace=0.35, hspace=0.25)
    panels = ((ax1, minimum * 1e-3, "viridis", "smallest principal stiffness (N/mm)",
               "conventional stiffness (eq. 8), q1 = 0, wrist vertical"),
              (ax2, ratio, "coolwarm", "smallest principal stiffness, enhanced / conventional",
               f"effect of K_C under a {load_N:g} N load straight down"))
    for ax, values, name, label, title in panels:
        cmap = matplotlib.colormaps[name].copy()
        cmap.set_bad(NO_VALUE_GREY)
        mesh = ax.pcolormesh(theta3_deg, theta2_deg, np.ma.masked_invalid(values),
                             shading="auto", cmap=cmap)
        fig.colorbar(mesh, ax=ax, label=label)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("joint angle q3 (deg)")
        ax.set_ylabel("joint angle q2 (deg)")
        missing = int(np.count_nonzero(~np.isfinite(values)))
        if missing:
            ax.legend(handles=[Patch(facecolor=NO_VALUE_GREY,
                                     label=f"no value ({missing} cells): flat parallelogram "
                                           "or singular stiffness")],
                      loc="lower left", fontsize=7, framealpha=0.9)
    return png(fig, dpi=110)


def table2_comparison(rows: list[dict]) -> bytes:
    """Table II per row (A1..C5): measured, the paper's calculated and our deflections (mm)."""
    labels = row_labels(rows)
    x = np.arange(len(rows))
    series = (("measured_mm", "measured (laser tracker)", "ko"),
              ("paper_calculated_mm", "paper's calculated (eq. 10)", "s"),
              ("enhanced_mm", "ours, enhanced (eq. 10)", "^"),
              ("conventional_mm", "ours, conventional (eq. 8)", "x"))
    fig = Figure(figsize=(14, 4.6))
    axes = fig.subplots(1, 3)
    margins(fig, 0.75, 0.15, 1.05, 0.15, wspace=0.25, hspace=0.25)
    for a, ax in enumerate(axes):
        for key, label, style in series:
            ax.plot(x, [r[key][a] for r in rows], style, label=label, alpha=0.85,
                    mfc="none" if key != "measured_mm" else None)
        ax.set_xticks(x, labels, fontsize=8)
        ax.set_xlabel("Table II row (configuration and load step)")
        ax.set_ylabel(f"deflection along base {'xyz'[a]} (mm)")
        ax.grid(alpha=0.3)
    fig.legend(*axes[0].get_legend_handles_labels(), loc="lower center", ncol=4, fontsize=9,
               bbox_to_anchor=(0.5, 0.01))
    return png(fig, dpi=110)


def table3_work_per_load(rows: list[dict], corrupt: list[dict]) -> bytes:
    """Table III per row (A1..E5): printed eq. 14 work over |F|^2, corrupt rows marked."""
    labels = row_labels(rows)
    x = np.arange(len(rows))
    ratio = np.array([r["paper_work_cartesian"] / np.dot(r["force_N"], r["force_N"])
                      for r in rows])
    ours = np.array([r["work_cartesian_Nmm"] / np.dot(r["force_N"], r["force_N"]) for r in rows])
    fig = Figure(figsize=(11, 4.6))
    ax = fig.subplots()
    rows_of_legend = -(-(2 + len(corrupt)) // 3)
    margins(fig, 0.75, 0.15, 0.65 + 0.25 * rows_of_legend, 0.15, wspace=0.25, hspace=0.25)
    ax.plot(x, ratio, "o", label=r"printed eq. 14 work / $|F|^2$ (printed unit per N$^2$)")
    ax.plot(x, ours, "x",
            label=r"ours: eq. 14 from the enhanced deflection / $|F|^2$ (N·mm per N$^2$)")
    for c in corrupt:
        i = labels.index(f"{c['config']}{c['row']}")
        ax.plot(x[i], ratio[i], "o", ms=14, mfc="none", mec="C3",
                label=f"misprinted force: row {labels[i]}")
    ax.set_xticks(x, labels, fontsize=8)
    ax.set_xlabel("Table III row (configuration and load step)")
    ax.set_ylabel(r"work / $|F|^2$ (printed unit or N·mm, per N$^2$)")
    fig.legend(loc="lower center", ncol=3, fontsize=9, bbox_to_anchor=(0.5, 0.01))
    ax.grid(alpha=0.3)
    return png(fig, dpi=110)
