"""Figures of a workspace scan (:mod:`stiffness.workspace.engine`), drawn from its
:class:`~stiffness.workspace.maps.MapAccumulator` (PNG bytes, matplotlib's Agg backend).

* ``definiteness_counts.png``: configurations per definiteness class of K_C, per load case;
* ``stiffness_map.png``: smallest principal stiffness over the map axes (conventional K_X, and
  the enhanced/conventional ratio per load case);
* ``definiteness_map.png``: most frequent class of K_C over the map axes, per load case.

matplotlib is imported when a figure is drawn, not with this module.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from stiffness.figures import margins, png
from stiffness.workspace.distributed import worker_robot
from stiffness.workspace.maps import MapAccumulator
from stiffness.workspace.spec import COUNT_LABELS, ScanSpec

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.collections import QuadMesh
    from matplotlib.figure import Figure


_CLASS_COLOURS = ("#2ca02c", "#98df8a", "#d62728", "#ff9896", "#7f7f7f", "#000000")


def _axis_label(spec: ScanSpec, position: int) -> tuple[str, float]:
    """Label and display scale (rad -> deg for revolute joints) of a map axis."""
    axis = spec.axes[position]
    robot = worker_robot(spec.robot)
    if robot.is_prismatic(axis["joint"]):
        return f"{axis['joint']} (m)", 1.0
    return f"{axis['joint']} (deg)", 180.0 / np.pi


def _load_title(spec: ScanSpec, j: int) -> str:
    """Panel title of load case ``j``."""
    load = ",".join(f"{v:g}" for v in spec.loads[j])
    return f"case {spec.load_names[j]}: ({load}) N"


def _panels(count: int) -> tuple[Figure, list[Axes]]:
    """A figure of ``count`` panels, up to four per row (matplotlib's Agg renderer; no pyplot:
    no figure manager, nothing to close), room on the right for a colour bar's labels."""
    from matplotlib.figure import Figure

    cols = min(4, count)
    rows = -(-count // cols)
    fig = Figure(figsize=(4.2 * cols + 0.4, 3.4 * rows + 0.3))
    axes = fig.subplots(rows, cols, squeeze=False)
    margins(fig, 0.75, 1.1 if count > 1 else 0.3, 0.55, 0.75, wspace=0.6, hspace=0.42)
    for ax in axes.flat[count:]:
        ax.set_visible(False)
    return fig, list(axes.flat[:count])


def counts_figure(spec: ScanSpec, acc: MapAccumulator) -> bytes:
    """Stacked bars: configurations per definiteness class of K_C, per load case."""
    fig, (ax,) = _panels(1)
    fig.set_size_inches(max(5.0, 0.9 * len(spec.loads) + 2), 3.8)
    margins(fig, 0.8, 0.2, 0.55, 0.35, wspace=0.6, hspace=0.42)
    counts = acc.parts["k_c_counts"]
    x = np.arange(len(spec.loads))
    bottom = np.zeros(len(spec.loads))
    for k, label in enumerate(COUNT_LABELS):
        if counts[:, k].any():
            ax.bar(x, counts[:, k], bottom=bottom, color=_CLASS_COLOURS[k], label=label)
            bottom += counts[:, k]
    ax.set_xticks(x, spec.load_names)
    ax.set_xlabel("load case")
    ax.set_ylabel("configurations")
    ax.set_title(f"{spec.robot['source']} {spec.preset}: definiteness of K_C")
    ax.legend(fontsize=8, loc="upper right")
    return png(fig, dpi=100)


def _mesh(ax: Axes, spec: ScanSpec, acc: MapAccumulator, values: np.ndarray,
          **kwargs: Any) -> QuadMesh | None:
    """Draw a map over the map axes (1 axis: a line; 2 axes: a colour mesh)."""
    label0, scale0 = _axis_label(spec, spec.map_axes[0])
    if len(acc.edges) == 1:
        centres = 0.5 * (acc.edges[0][1:] + acc.edges[0][:-1]) * scale0
        ax.plot(centres, np.where(np.isfinite(values), values, np.nan), "o-", ms=3)
        ax.set_xlabel(label0)
        return None
    label1, scale1 = _axis_label(spec, spec.map_axes[1])
    mesh = ax.pcolormesh(acc.edges[1] * scale1, acc.edges[0] * scale0,
                         np.ma.masked_invalid(np.where(np.isfinite(values), values, np.nan)),
                         shading="flat", **kwargs)
    ax.set_xlabel(label1)
    ax.set_ylabel(label0)
    return mesh


def stiffness_figure(spec: ScanSpec, acc: MapAccumulator) -> bytes:
    """Smallest principal stiffness of the conventional K_X (N/mm) over the map axes (minimum
    over the other coordinates), and per load case the smallest ratio of the enhanced to the
    conventional smallest principal stiffness (below 1: the load softens the robot)."""
    from matplotlib.colors import LogNorm, TwoSlopeNorm

    n_loads = len(spec.loads)
    shown = min(n_loads, 11)
    fig, axes = _panels(shown + 1)
    two_d = len(acc.edges) == 2
    conv = acc.parts["map_conventional_min"] * 1e-3
    conv = np.where(np.isfinite(conv) & (conv > 0), conv, np.nan)
    kwargs = {}
    if two_d and np.nanmax(conv, initial=0) > np.nanmin(conv, initial=np.inf):
        kwargs = {"cmap": "viridis", "norm": LogNorm(np.nanmin(conv), np.nanmax(conv))}
    mesh = _mesh(axes[0], spec, acc, conv, **kwargs)
    if mesh is not None:
        fig.colorbar(mesh, ax=axes[0], fraction=0.08, pad=0.03)
    else:
        axes[0].set_ylabel("N/mm")
    axes[0].set_title("conventional: min principal stiffness (N/mm)", fontsize=9)
    ratios = acc.parts["map_min_ratio"]
    finite = ratios[np.isfinite(ratios)]
    spread = max(float(np.max(np.abs(finite - 1.0))) if finite.size else 0.0, 1e-9)
    mesh = None
    for j, ax in enumerate(axes[1:]):
        values = np.where(np.isfinite(ratios[..., j]), ratios[..., j], np.nan)
        kwargs = {"cmap": "coolwarm_r",
                  "norm": TwoSlopeNorm(1.0, 1.0 - spread, 1.0 + spread)} if two_d else {}
        mesh = _mesh(ax, spec, acc, values, **kwargs)
        if mesh is None:
            ax.set_ylabel("enhanced / conventional")
        ax.set_title(_load_title(spec, j), fontsize=9)
    if mesh is not None:  # one colour bar for all load cases (same scale)
        fig.colorbar(mesh, ax=axes[1:], label="min stiffness, enhanced / conventional")
    fig.suptitle(f"{spec.robot['source']} {spec.preset}: smallest principal stiffness of K_X "
                 "(minimum over the other coordinates)", fontsize=10)
    return png(fig, dpi=100)


def definiteness_figure(spec: ScanSpec, acc: MapAccumulator) -> bytes:
    """Most frequent definiteness class of K_C over the map axes, per load case."""
    from matplotlib.colors import BoundaryNorm, ListedColormap

    n_loads = len(spec.loads)
    shown = min(n_loads, 8)
    fig, axes = _panels(shown)
    counts = acc.parts["map_k_c_counts"]
    cmap = ListedColormap(_CLASS_COLOURS)
    norm = BoundaryNorm(np.arange(len(COUNT_LABELS) + 1) - 0.5, len(COUNT_LABELS))
    mesh = None
    for j, ax in enumerate(axes):
        c = counts[..., j, :]
        mode = np.argmax(c, axis=-1).astype(float)
        mode[c.sum(axis=-1) == 0] = np.nan
        mesh = _mesh(ax, spec, acc, mode, cmap=cmap, norm=norm) if len(acc.edges) == 2 \
            else _mesh(ax, spec, acc, mode)
        if len(acc.edges) == 1:
            ax.set_yticks(range(len(COUNT_LABELS)), COUNT_LABELS)
        ax.set_title(_load_title(spec, j), fontsize=9)
    if mesh is not None:
        bar = fig.colorbar(mesh, ax=axes, ticks=range(len(COUNT_LABELS)))
        bar.ax.set_yticklabels(COUNT_LABELS)
    fig.suptitle(f"{spec.robot['source']} {spec.preset}: most frequent class of K_C "
                 "(over the other coordinates)", fontsize=10)
    return png(fig, dpi=100)


def all_figures(spec: ScanSpec, acc: MapAccumulator) -> dict[str, bytes]:
    """File name -> PNG bytes of the scan's figures (those its fields compute)."""
    figures = {}
    if acc.needs["definiteness"]:
        figures["definiteness_counts.png"] = counts_figure(spec, acc)
    if acc.edges and acc.needs["k_x"] and acc.needs["conventional"]:
        figures["stiffness_map.png"] = stiffness_figure(spec, acc)
    if acc.edges and acc.needs["definiteness"]:
        figures["definiteness_map.png"] = definiteness_figure(spec, acc)
    return figures
