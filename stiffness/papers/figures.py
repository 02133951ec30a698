"""Figures of the SK120 report (matplotlib, Agg backend, PNG bytes)."""

from __future__ import annotations

import io

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from stiffness.mechanics.equilibrium import Departure  # noqa: E402
from stiffness.scan.definiteness import DefinitenessScan  # noqa: E402


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def force_deflection(curves: dict[str, dict]) -> bytes:
    """Figs. 4-6: deflection components (mm) against the load magnitude (N) per configuration.

    ``curves[name] = {"force_N": (k,), "conventional": (k, 3), "enhanced": (k, 3),
    "exact": (k, 3), "direction": (3,)}`` in mm.
    """
    fig, axes = plt.subplots(1, len(curves), figsize=(5 * len(curves), 4), squeeze=False)
    for ax, (name, c) in zip(axes[0], curves.items(), strict=True):
        for i, (axis, colour) in enumerate(zip("xyz", ("C0", "C1", "C2"), strict=True)):
            ax.plot(c["force_N"], c["exact"][:, i], "-", color=colour, label=f"d{axis} exact")
            ax.plot(c["force_N"], c["enhanced"][:, i], "--", color=colour,
                    label=f"d{axis} enhanced")
            ax.plot(c["force_N"], c["conventional"][:, i], ":", color=colour,
                    label=f"d{axis} conventional")
        ax.set_title(f"{name}: load along {np.round(c['direction'], 3).tolist()}")
        ax.set_xlabel("load magnitude (N)")
        ax.set_ylabel("deflection (mm)")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    return _png(fig)


def partial_derivative_maps(scan: DefinitenessScan) -> bytes:
    """Figs. 7-9: the parts of C11, C22, C33 (eq. 16) over the Table IV grid, mm/rad.

    Part k of C_ii is dJ[k, i]/dtheta_i, i.e. C_ii for a unit force along axis k.
    """
    diag = scan.k_c_diagonal * 1e3  # N.m/rad per N -> mm/rad
    fig, axes = plt.subplots(3, 3, figsize=(13, 8), sharex=True)
    index = np.arange(diag.shape[0])
    for i in range(3):
        for k in range(3):
            ax = axes[k, i]
            ax.plot(index, diag[:, k, i], ",", color="C0")
            ax.set_title(f"C{i + 1}{i + 1} part {k + 1}: dJ{'xyz'[k]}{i + 1}/dθ{i + 1}", fontsize=9)
            if i == 0:
                ax.set_ylabel("mm/rad")
            if k == 2:
                ax.set_xlabel("configuration index")
            ax.grid(alpha=0.3)
    return _png(fig)


def linear_vs_exact(departure: Departure, reference_force_N: float) -> bytes:
    """Error of the linear predictions against the exact equilibrium, log-log in the load."""
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4))
    force = departure.scales * reference_force_N
    for pred, name, style in ((departure.conventional, "conventional", "o-"),
                              (departure.enhanced, "enhanced", "s-")):
        err = np.linalg.norm(pred - departure.exact, axis=1) * 1e3
        rate = departure.rate_conventional if name == "conventional" else departure.rate_enhanced
        ax1.loglog(force, err, style, label=f"{name} (slope {rate:.2f})")
    ax1.set_xlabel("load magnitude (N)")
    ax1.set_ylabel("|linear - exact| deflection (mm)")
    ax1.legend()
    ax1.grid(alpha=0.3, which="both")
    ax2.plot(force, np.linalg.norm(departure.exact, axis=1) * 1e3, "k-", label="exact")
    ax2.plot(force, np.linalg.norm(departure.enhanced, axis=1) * 1e3, "--", label="enhanced")
    ax2.plot(force, np.linalg.norm(departure.conventional, axis=1) * 1e3, ":", label="conventional")
    ax2.set_xscale("log")
    ax2.set_yscale("log")
    ax2.set_xlabel("load magnitude (N)")
    ax2.set_ylabel("|deflection| (mm)")
    ax2.legend()
    ax2.grid(alpha=0.3, which="both")
    return _png(fig)


def stiffness_map(theta2_deg: np.ndarray, theta3_deg: np.ndarray, minimum: np.ndarray,
                  ratio: np.ndarray, load_N: float) -> bytes:
    """Minimum principal stiffness (N/mm) over (theta2, theta3), and enhanced/conventional."""
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.5))
    mesh = ax1.pcolormesh(theta3_deg, theta2_deg, minimum * 1e-3, shading="auto", cmap="viridis")
    fig.colorbar(mesh, ax=ax1, label="min principal stiffness (N/mm)")
    ax1.set_title("conventional K_X, theta1 = 0, wrist vertical")
    mesh2 = ax2.pcolormesh(theta3_deg, theta2_deg, ratio, shading="auto", cmap="coolwarm")
    fig.colorbar(mesh2, ax=ax2, label="min stiffness ratio enhanced / conventional")
    ax2.set_title(f"effect of K_C under a {load_N:g} N load along -z")
    for ax in (ax1, ax2):
        ax.set_xlabel("q3 (deg)")
        ax.set_ylabel("q2 (deg)")
    return _png(fig)


def table2_comparison(rows: list[dict]) -> bytes:
    """Measured against predicted Table II deflections (mm)."""
    fig, ax = plt.subplots(figsize=(5.5, 5))
    meas = np.array([r["measured_mm"] for r in rows]).ravel()
    for key, marker in (("paper_calculated_mm", "o"), ("enhanced_mm", "s"), ("exact_mm", "x")):
        ax.plot(meas, np.array([r[key] for r in rows]).ravel(), marker, label=key, alpha=0.8)
    lim = [min(meas.min(), 0) * 1.1, meas.max() * 1.1]
    ax.plot(lim, lim, "k-", lw=0.5)
    ax.set_xlabel("measured deflection component (mm)")
    ax.set_ylabel("predicted (mm)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return _png(fig)
