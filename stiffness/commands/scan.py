"""``stiffness scan``: stiffness and definiteness maps over a workspace.

Examples::

    stiffness scan --robot sk120 --preset table4            # A&S Table IV: 5824 x 8 loads
    stiffness scan --robot ur5 --kq 3e5,3e5,2e5,4e4,4e4,4e4 --deg \\
        --axis shoulder_lift_joint=-90:0:5 --axis elbow_joint=0:150:5 --load 0,0,-200
    stiffness scan --robot ur5 --kq ... --samples 1000000 --workers 2
    stiffness scan --robot panda --kq ... --samples 1e7 --scheduler tcp://10.0.0.5:8786

Per configuration and load case the scan computes, with :mod:`stiffness.batch`: the
definiteness class of K_C and of K_theta - K_C, the load factor at which K_theta - K_C stops
being positive definite, the enhanced Cartesian stiffness K_X (A&S eq. 10) and its principal
values, and the conventional K_X (eq. 8). The scan is cut into chunks (``--chunk-size``
configurations); each chunk is written to ``--out`` as soon as it is done (NPZ and/or Parquet),
so memory is bounded by the chunk size and a killed run (or worker) loses only unfinished
chunks: run the same command with the same ``--out`` to resume. ``--workers N`` spreads the
chunks over a Dask LocalCluster, ``--scheduler ADDRESS`` over an existing Dask cluster; the
default runs them in this process, through the same code. In this process and on a
LocalCluster each chunk is written by the process that computes it; on a remote cluster the
chunk's arrays come back and are written here, unless ``--shared-out`` says the workers see
``--out`` too.

Files in ``--out`` (default: a new folder ``<robot>-<preset>`` in the current directory):

* ``manifest.json``: the scan's specification (robot, coordinates, loads, K_theta, units);
* ``chunks/chunk-NNNNN.npz`` (``--format npz``) and/or ``maps.parquet/part-NNNNN.parquet``
  (``--format parquet``, one row per configuration and load case);
* ``chunks/aggregate-NNNNN.npz``: the chunk's contribution to the summary (marks it done);
* ``summary.json`` (class counts per load case, extremes) and the figures
  ``definiteness_counts.png``, ``definiteness_map.png``, ``stiffness_map.png``.

SI units: rad (``--deg`` for degrees on the command line), m, N, N.m/rad, N/m.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import re
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from stiffness import batch
from stiffness.commands.kx import parse_list, robot_from_args
from stiffness.distributed import run_chunks, worker_robot
from stiffness.errors import StiffnessError, did_you_mean
from stiffness.files import atomic_write, atomic_write_with
from stiffness.formulation import DEFINITENESS_CLASSES
from stiffness.robot import Robot
from stiffness.scan import grid_axis, terminal_progress

PRESETS = ("table4",)
FORMATS = ("npz", "parquet", "both")
#: Version of the chunk layout written by this module.
LAYOUT_VERSION = 1
#: Default load case when none is given (N): 100 N downwards.
DEFAULT_LOAD_N = (0.0, 0.0, -100.0)
#: Bins per sampled map axis.
SAMPLE_BINS = 32
#: Classes counted per load case: the definiteness classes, then invalid configurations.
COUNT_LABELS = (*DEFINITENESS_CLASSES, "invalid")


# ---------------------------------------------------------------------------------- spec


@dataclass
class ScanSpec:
    """What a scan computes; JSON-serialisable, sent with every chunk.

    Attributes
    ----------
    robot
        Keyword arguments of :func:`stiffness.robot.load_robot`.
    preset
        "table4" (A&S Table IV grid), "grid" or "samples".
    coordinate_joints
        The robot's coordinate joints (order of every coordinate vector).
    base
        Coordinates (rad, m) of the joints that are not swept.
    axes
        Swept coordinates: ``{"index", "joint", "lower", "upper", "step"}`` (rad or m);
        ``step`` is None for sampled axes.
    samples
        Number of random configurations (uniform in the axes' ranges), or None for a grid.
    seed
        Seed of the samples (chunk ``i`` draws from ``default_rng([seed, i])``).
    loads
        (L, 3) forces (N) or (L, 6) wrenches (N, N.m) at the target, base axes.
    load_names
        One name per load case.
    k_theta
        Joint stiffness per compliant joint (N.m/rad, N/m).
    rtol
        Relative eigenvalue tolerance of the definiteness classes.
    chunk_size
        Configurations per chunk.
    map_axes
        Positions in ``axes`` of the (up to two) coordinates the figures are drawn over.
    """

    robot: dict
    preset: str
    coordinate_joints: list[str]
    base: list[float]
    axes: list[dict]
    samples: int | None
    seed: int
    loads: list[list[float]]
    load_names: list[str]
    k_theta: list[float]
    rtol: float = 1e-9
    chunk_size: int = 8192
    map_axes: list[int] = field(default_factory=list)
    layout: int = LAYOUT_VERSION

    @classmethod
    def from_dict(cls, data: dict) -> ScanSpec:
        """Rebuild a spec from :meth:`to_dict` output."""
        return cls(**data)

    def to_dict(self) -> dict:
        """JSON-ready form."""
        return asdict(self)

    @property
    def axis_lengths(self) -> list[int]:
        """Number of values of each grid axis."""
        return [len(grid_axis(a["lower"], a["upper"], a["step"])) for a in self.axes]

    @property
    def n_configurations(self) -> int:
        """Number of configurations scanned."""
        if self.preset == "table4":
            return _table4_size()
        if self.samples is not None:
            return int(self.samples)
        return int(np.prod(self.axis_lengths)) if self.axes else 1

    @property
    def n_chunks(self) -> int:
        """Number of chunks."""
        return -(-self.n_configurations // self.chunk_size)

    @property
    def rows(self) -> int:
        """Cartesian rows of K_X: 3 for force loads, 6 for wrenches."""
        return 3 if len(self.loads[0]) == 3 else 6

    def chunk_coordinates(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Global configuration indices and coordinates (rad, m) of chunk ``index``."""
        start = index * self.chunk_size
        stop = min(self.n_configurations, start + self.chunk_size)
        ids = np.arange(start, stop, dtype=np.int64)
        if self.preset == "table4":
            return ids, _table4_grid()[start:stop].copy()
        coords = np.repeat(np.asarray(self.base, dtype=float)[None, :], stop - start, axis=0)
        if self.samples is not None:
            rng = np.random.default_rng([self.seed, index])
            for a in self.axes:
                coords[:, a["index"]] = rng.uniform(a["lower"], a["upper"], stop - start)
        elif self.axes:
            values = [grid_axis(a["lower"], a["upper"], a["step"]) for a in self.axes]
            for a, vals, idx in zip(self.axes, values,
                                    np.unravel_index(ids, [len(v) for v in values]), strict=True):
                coords[:, a["index"]] = vals[idx]
        return ids, coords


@functools.lru_cache(maxsize=1)
def _table4_grid() -> np.ndarray:
    """The A&S Table IV grid (rad), computed once per process (read-only)."""
    from stiffness.reproduction import table4_grid

    grid = table4_grid()
    grid.setflags(write=False)
    return grid


def _table4_size() -> int:
    return int(_table4_grid().shape[0])


# ---------------------------------------------------------------------------------- chunk


def scan_chunk(spec_dict: dict, index: int) -> dict[str, np.ndarray]:
    """Compute chunk ``index`` of a scan (runs on a worker; a pure function of its inputs).

    Returns
    -------
    dict
        Arrays (``c`` configurations, ``L`` loads, ``n`` compliant joints, ``r`` rows):
        ``index`` (c,), ``coordinates`` (c, n_coordinates) rad/m, ``position`` (c, 3) m,
        ``valid`` (c,), ``k_c_class``, ``tangent_class``, ``k_x_class`` (c, L) int8 codes
        into DEFINITENESS_CLASSES (-1 invalid), ``critical_factor`` (c, L),
        ``k_c_det_positive`` (c, L), ``k_c_diagonal`` (c, 3, n) N.m/rad per N,
        ``k_x`` (c, L, r, r) N/m, ``k_x_eigenvalues`` (c, L, r) N/m, ``regular`` (c, L),
        ``k_x_conventional`` (c, r, r) and ``k_x_conventional_eigenvalues`` (c, r).
    """
    spec = ScanSpec.from_dict(spec_dict)
    robot = worker_robot(spec.robot)
    return compute_maps(robot, spec, *spec.chunk_coordinates(index))


def compute_maps(robot: Robot, spec: ScanSpec, ids: np.ndarray, coords: np.ndarray
                 ) -> dict[str, np.ndarray]:
    """The arrays of :func:`scan_chunk` for given configurations."""
    loads = np.asarray(spec.loads, dtype=float)
    k_theta = np.asarray(spec.k_theta, dtype=float)
    rows = spec.rows
    closed = batch.close_loops(robot, coords)
    q = np.where(closed.closed[:, None], closed.q, batch.tree_configurations(robot, coords))
    moments = loads.shape[1] == 6 and bool(np.any(loads[:, 3:] != 0))
    kin = batch.batch_kinematics(robot, q, moments=moments, pose=True)
    valid = closed.closed & kin.valid
    k_c = batch.complementary_stiffness(kin, loads)
    dmap = batch.definiteness_map(kin, loads, k_theta, rtol=spec.rtol, k_c=k_c)
    enhanced = batch.evaluate(robot, kin, loads, k_theta, "enhanced", rows=rows)
    conventional = batch.evaluate(robot, kin, loads[:1], k_theta, "conventional", rows=rows)
    eig = batch.symmetric_eigenvalues(enhanced.k_x)
    eig_conv = batch.symmetric_eigenvalues(conventional.k_x[:, 0])
    invalid = ~valid
    out = {
        "index": ids,
        "coordinates": coords,
        "position": kin.position,
        "valid": valid,
        "k_c_class": dmap.k_c_class,
        "tangent_class": dmap.tangent_class,
        "k_x_class": batch.definiteness_codes(eigenvalues=eig, rtol=spec.rtol),
        "critical_factor": dmap.critical_factor,
        "k_c_det_positive": dmap.determinant_positive,
        "k_c_diagonal": dmap.k_c_diagonal,
        "k_x": enhanced.k_x,
        "k_x_eigenvalues": eig,
        "regular": enhanced.regular & valid[:, None],
        "k_x_conventional": conventional.k_x[:, 0],
        "k_x_conventional_eigenvalues": eig_conv,
    }
    if invalid.any():
        for key in ("position", "critical_factor", "k_c_diagonal", "k_x", "k_x_eigenvalues",
                    "k_x_conventional", "k_x_conventional_eigenvalues"):
            out[key] = out[key].astype(float, copy=True)
            out[key][invalid] = np.nan
        for key in ("k_c_class", "tangent_class", "k_x_class"):
            out[key][invalid] = batch.INVALID_CLASS
        out["k_c_det_positive"][invalid] = False
    return out


# ---------------------------------------------------------------------------------- aggregate


class MapAccumulator:
    """Streaming summary and figure data of a scan (memory independent of its size).

    Per load case: class counts of K_C, K_theta - K_C and K_X, det K_C > 0 counts, the smallest
    critical load factor and the extreme principal stiffnesses; per bin of the map axes: the
    smallest principal stiffness of K_X (over the other coordinates) and the class counts of K_C.
    """

    def __init__(self, spec: ScanSpec) -> None:
        self.spec = spec
        n_loads = len(spec.loads)
        self.edges = [_bin_edges(spec, spec.axes[i]) for i in spec.map_axes]
        shape = tuple(len(e) - 1 for e in self.edges)
        k = len(COUNT_LABELS)
        self.parts = {
            "n": np.zeros(1, dtype=np.int64),
            "n_valid": np.zeros(1, dtype=np.int64),
            "k_c_counts": np.zeros((n_loads, k), dtype=np.int64),
            "tangent_counts": np.zeros((n_loads, k), dtype=np.int64),
            "k_x_counts": np.zeros((n_loads, k), dtype=np.int64),
            "det_positive": np.zeros(n_loads, dtype=np.int64),
            "critical_min": np.full(n_loads, np.inf),
            "critical_argmin": np.full(n_loads, -1, dtype=np.int64),
            "k_x_min": np.full(n_loads, np.inf),
            "k_x_max": np.full(n_loads, -np.inf),
            "k_x_conventional_min": np.full(1, np.inf),
            "k_x_conventional_max": np.full(1, -np.inf),
            "map_min_stiffness": np.full((*shape, n_loads), np.inf),
            "map_conventional_min": np.full(shape, np.inf),
            "map_min_ratio": np.full((*shape, n_loads), np.inf),
            "map_k_c_counts": np.zeros((*shape, n_loads, k), dtype=np.int64),
        }

    def chunk_parts(self, maps: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """A chunk's contribution (same keys as the totals)."""
        spec = self.spec
        n_loads = len(spec.loads)
        k = len(COUNT_LABELS)
        parts = {key: value.copy() for key, value in self.parts.items()}
        valid = maps["valid"]
        parts["n"][0] = valid.shape[0]
        parts["n_valid"][0] = int(valid.sum())
        for name in ("k_c", "tangent", "k_x"):
            codes = np.where(maps[f"{name}_class"] < 0, k - 1, maps[f"{name}_class"])
            for j in range(n_loads):
                parts[f"{name}_counts"][j] = np.bincount(codes[:, j], minlength=k)
        parts["det_positive"] = maps["k_c_det_positive"].sum(axis=0)
        crit = np.where(np.isnan(maps["critical_factor"]), np.inf, maps["critical_factor"])
        if crit.shape[0]:
            arg = np.argmin(crit, axis=0)
            parts["critical_min"] = crit[arg, np.arange(n_loads)]
            parts["critical_argmin"] = np.where(np.isfinite(parts["critical_min"]),
                                                maps["index"][arg], -1)
        low = maps["k_x_eigenvalues"][..., 0]
        high = maps["k_x_eigenvalues"][..., -1]
        with np.errstate(invalid="ignore"):
            parts["k_x_min"] = np.fmin(parts["k_x_min"], _nanreduce(np.nanmin, low, np.inf))
            parts["k_x_max"] = np.fmax(parts["k_x_max"], _nanreduce(np.nanmax, high, -np.inf))
            conv = maps["k_x_conventional_eigenvalues"]
            parts["k_x_conventional_min"][0] = _nanreduce(np.nanmin, conv[:, 0], np.inf)
            parts["k_x_conventional_max"][0] = _nanreduce(np.nanmax, conv[:, -1], -np.inf)
        if self.edges:
            cells = [np.clip(np.digitize(maps["coordinates"][:, spec.axes[i]["index"]], e) - 1,
                             0, len(e) - 2) for i, e in zip(spec.map_axes, self.edges,
                                                            strict=True)]
            flat = np.ravel_multi_index(cells, parts["map_conventional_min"].shape)
            size = parts["map_conventional_min"].size
            lowest = parts["map_min_stiffness"].reshape(size, n_loads)
            np.fmin.at(lowest, flat, np.where(np.isnan(low), np.inf, low))
            conv_low = parts["map_conventional_min"].reshape(size)
            np.fmin.at(conv_low, flat, np.where(np.isnan(conv[:, 0]), np.inf, conv[:, 0]))
            with np.errstate(invalid="ignore", divide="ignore"):
                ratio = low / conv[:, :1]
            ratios = parts["map_min_ratio"].reshape(size, n_loads)
            np.fmin.at(ratios, flat, np.where(np.isfinite(ratio), ratio, np.inf))
            counts = parts["map_k_c_counts"].reshape(size, n_loads, k)
            codes = np.where(maps["k_c_class"] < 0, k - 1, maps["k_c_class"])
            np.add.at(counts, (flat[:, None], np.arange(n_loads)[None, :], codes), 1)
        return parts

    def add(self, parts: dict[str, np.ndarray]) -> None:
        """Merge a chunk's contribution."""
        p = self.parts
        for key in ("n", "n_valid", "k_c_counts", "tangent_counts", "k_x_counts",
                    "det_positive", "map_k_c_counts"):
            p[key] = p[key] + parts[key]
        better = parts["critical_min"] < p["critical_min"]
        p["critical_min"] = np.where(better, parts["critical_min"], p["critical_min"])
        p["critical_argmin"] = np.where(better, parts["critical_argmin"], p["critical_argmin"])
        for key in ("k_x_min", "k_x_conventional_min", "map_min_stiffness",
                    "map_conventional_min", "map_min_ratio"):
            p[key] = np.fmin(p[key], parts[key])
        for key in ("k_x_max", "k_x_conventional_max"):
            p[key] = np.fmax(p[key], parts[key])

    def summary(self) -> dict:
        """JSON-ready summary of the scan so far."""
        spec, p = self.spec, self.parts
        cases = {}
        for j, name in enumerate(spec.load_names):
            crit = float(p["critical_min"][j])
            magnitude = float(np.linalg.norm(spec.loads[j][:3]))
            cases[name] = {
                "load": spec.loads[j],
                "k_c": _counts(p["k_c_counts"][j]),
                "k_theta_minus_k_c": _counts(p["tangent_counts"][j]),
                "k_x": _counts(p["k_x_counts"][j]),
                "k_c_determinant_positive": int(p["det_positive"][j]),
                "min_critical_load_factor": _finite_or_none(crit),
                "min_critical_force_N": _finite_or_none(crit * magnitude)
                if magnitude > 0 else None,
                "min_critical_configuration": int(p["critical_argmin"][j]),
                "min_principal_stiffness_N_per_m": _finite_or_none(float(p["k_x_min"][j])),
                "max_principal_stiffness_N_per_m": _finite_or_none(float(p["k_x_max"][j])),
            }
        return {
            "robot": spec.robot["source"],
            "preset": spec.preset,
            "configurations": int(p["n"][0]),
            "valid_configurations": int(p["n_valid"][0]),
            "load_cases": cases,
            "conventional_min_principal_stiffness_N_per_m": _finite_or_none(
                float(p["k_x_conventional_min"][0])),
            "conventional_max_principal_stiffness_N_per_m": _finite_or_none(
                float(p["k_x_conventional_max"][0])),
        }


def _nanreduce(func, values: np.ndarray, empty: float) -> np.ndarray | float:
    if values.shape[0] == 0 or np.all(np.isnan(values)):
        return np.full(values.shape[1:], empty) if values.ndim > 1 else empty
    out = func(values, axis=0)
    return np.where(np.isnan(out), empty, out)


def _counts(row: np.ndarray) -> dict[str, int]:
    return {label: int(v) for label, v in zip(COUNT_LABELS, row, strict=True)}


def _finite_or_none(value: float) -> float | None:
    return value if np.isfinite(value) else None


def _bin_edges(spec: ScanSpec, axis: dict) -> np.ndarray:
    """Bin edges of a map axis: midpoints between grid values, or uniform for samples."""
    if spec.preset == "table4":
        values = np.unique(_table4_grid()[:, axis["index"]])
    elif axis["step"] is None:
        return np.linspace(axis["lower"], axis["upper"], SAMPLE_BINS + 1)
    else:
        values = grid_axis(axis["lower"], axis["upper"], axis["step"])
    if values.shape[0] == 1:
        return np.array([values[0] - 0.5, values[0] + 0.5])
    mid = 0.5 * (values[1:] + values[:-1])
    return np.concatenate([[2 * values[0] - mid[0]], mid, [2 * values[-1] - mid[-1]]])


# ---------------------------------------------------------------------------------- files


def chunk_path(out: Path, index: int) -> Path:
    """NPZ file of chunk ``index``."""
    return out / "chunks" / f"chunk-{index:05d}.npz"


def parquet_path(out: Path, index: int) -> Path:
    """Parquet part file of chunk ``index``."""
    return out / "maps.parquet" / f"part-{index:05d}.parquet"


def aggregate_path(out: Path, index: int) -> Path:
    """Aggregate file of chunk ``index`` (written last: the chunk is done)."""
    return out / "chunks" / f"aggregate-{index:05d}.npz"


def write_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write arrays to an NPZ file atomically."""
    atomic_write_with(path, lambda f: np.savez(f, **arrays))


def write_parquet(path: Path, spec: ScanSpec, maps: dict[str, np.ndarray]) -> None:
    """One row per configuration and load case (tidy table), written atomically."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise StiffnessError("--format parquet needs pyarrow: pip install pyarrow") from exc
    c, n_loads = maps["k_c_class"].shape
    rows = spec.rows
    names = np.array([*DEFINITENESS_CLASSES, ""])
    table = {
        "configuration": np.repeat(maps["index"], n_loads),
        "load_case": np.tile(np.array(spec.load_names), c),
    }
    for k, joint in enumerate(spec.coordinate_joints):
        table[f"q_{joint}"] = np.repeat(maps["coordinates"][:, k], n_loads)
    for k, axis in enumerate("xyz"):
        table[f"{axis}_m"] = np.repeat(maps["position"][:, k], n_loads)
    table["valid"] = np.repeat(maps["valid"], n_loads)
    for name in ("k_c", "tangent", "k_x"):
        table[f"{name}_class"] = names[maps[f"{name}_class"].reshape(-1)]
    table["critical_factor"] = maps["critical_factor"].reshape(-1)
    table["k_c_det_positive"] = maps["k_c_det_positive"].reshape(-1)
    table["regular"] = maps["regular"].reshape(-1)
    for k in range(rows):
        table[f"k_x_eig{k}_N_per_m"] = maps["k_x_eigenvalues"][..., k].reshape(-1)
        table[f"k_x_conventional_eig{k}_N_per_m"] = np.repeat(
            maps["k_x_conventional_eigenvalues"][:, k], n_loads)
    for a in range(rows):
        for b in range(rows):
            table[f"k_x_{a}{b}"] = maps["k_x"][:, :, a, b].reshape(-1)
    arrow = pa.table(table)
    atomic_write_with(path, lambda f: pq.write_table(arrow, f))


def write_chunk(out: Path, spec: ScanSpec, index: int, maps: dict[str, np.ndarray],
                formats: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Write a chunk's map files, then its aggregate (which marks it done); returns the
    aggregate (:meth:`MapAccumulator.chunk_parts`)."""
    if "npz" in formats:
        write_npz(chunk_path(out, index), maps)
    if "parquet" in formats:
        write_parquet(parquet_path(out, index), spec, maps)
    parts = MapAccumulator(spec).chunk_parts(maps)
    write_npz(aggregate_path(out, index), parts)
    return parts


def scan_chunk_to_files(spec_dict: dict, out: str, formats: tuple[str, ...], index: int
                        ) -> dict[str, np.ndarray]:
    """Compute chunk ``index`` and write its files where it runs (a worker sharing the output
    folder's filesystem); only the small aggregate travels back."""
    maps = scan_chunk(spec_dict, index)
    return write_chunk(Path(out), ScanSpec.from_dict(spec_dict), index, maps, tuple(formats))


def load_scan(out: str | os.PathLike) -> dict[str, np.ndarray]:
    """All NPZ chunks of a scan concatenated in configuration order (memory grows with it)."""
    out = Path(out)
    files = sorted((out / "chunks").glob("chunk-*.npz"))
    if not files:
        raise StiffnessError(f"{out} holds no NPZ chunk (chunks/chunk-*.npz); was it written "
                             "with --format parquet?")
    parts = [dict(np.load(f)) for f in files]
    return {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}


# ---------------------------------------------------------------------------------- run


def run_scan(spec: ScanSpec, out: str | os.PathLike, formats: tuple[str, ...] = ("npz",),
             scheduler: str | None = None, workers: int | None = None,
             client: object | None = None, plots: bool = True,
             progress=None, write_on_workers: bool | None = None) -> dict:
    """Run (or resume) a scan into ``out``; returns the summary.

    Parameters
    ----------
    spec
        What to compute.
    out
        Output folder; if it holds a scan with the same spec, its finished chunks are kept.
    formats
        "npz" and/or "parquet".
    scheduler, workers, client
        Where the chunks run (see :func:`stiffness.distributed.run_chunks`). A script that
        starts a LocalCluster (``workers`` > 1) must guard its entry point with
        ``if __name__ == "__main__":`` (worker processes are spawned).
    plots
        Draw the figures.
    progress
        Called with (configurations done, total).
    write_on_workers
        Each chunk's files are written by the process that computes it and only its aggregate
        travels back (needs ``out`` on a filesystem the workers share); otherwise the chunk's
        arrays travel back and this process writes them. Default: True in this process and on
        a LocalCluster, False on a remote scheduler or a given client.
    """
    out = Path(out)
    manifest = {"layout": LAYOUT_VERSION, "spec": spec.to_dict(), "formats": list(formats),
                "n_configurations": spec.n_configurations, "n_chunks": spec.n_chunks,
                "units": _UNITS, "classes": list(DEFINITENESS_CLASSES)}
    manifest_file = out / "manifest.json"
    if manifest_file.is_file():
        previous = json.loads(manifest_file.read_text())
        if previous.get("spec") != json.loads(json.dumps(spec.to_dict())):
            raise StiffnessError(
                f"{out} holds a different scan (its manifest.json differs); give a new --out "
                "folder, or the same options to resume it"
            )
    else:
        out.mkdir(parents=True, exist_ok=True)
        atomic_write(manifest_file, json.dumps(manifest, indent=1))
    acc = MapAccumulator(spec)
    done = set()
    for index in range(spec.n_chunks):
        agg = aggregate_path(out, index)
        have = [chunk_path(out, index).is_file() if "npz" in formats else True,
                parquet_path(out, index).is_file() if "parquet" in formats else True]
        if agg.is_file() and all(have):
            acc.add(dict(np.load(agg)))
            done.add(index)
    total = spec.n_configurations
    counter = {"configurations": sum(
        min(spec.chunk_size, total - i * spec.chunk_size) for i in done)}
    if progress is not None and done:
        progress(counter["configurations"], total)

    if write_on_workers is None:
        write_on_workers = scheduler is None and client is None

    def on_result(index: int, result: dict[str, np.ndarray]) -> None:
        parts = result if write_on_workers else write_chunk(out, spec, index, result, formats)
        acc.add(parts)
        counter["configurations"] += int(parts["n"][0])
        if progress is not None:
            progress(counter["configurations"], total)

    t0 = time.perf_counter()
    todo = [i for i in range(spec.n_chunks) if i not in done]
    if write_on_workers:
        func_args = (scan_chunk_to_files, (spec.to_dict(), str(out.resolve()), tuple(formats)))
    else:
        func_args = (scan_chunk, (spec.to_dict(),))
    computed = run_chunks(*func_args, todo, on_result, scheduler=scheduler, workers=workers,
                          client=client)
    elapsed = time.perf_counter() - t0
    summary = acc.summary()
    summary["chunks"] = {"total": spec.n_chunks, "computed": computed, "resumed": len(done),
                         "chunk_size": spec.chunk_size}
    summary["compute_seconds"] = elapsed
    summary["units"] = _UNITS
    if plots:
        t1 = time.perf_counter()
        for name, png in all_figures(spec, acc).items():
            atomic_write(out / name, png)
        summary["plot_seconds"] = time.perf_counter() - t1
    atomic_write(out / "summary.json", json.dumps(summary, indent=1))
    return summary


_UNITS = {
    "coordinates": "rad (m for prismatic joints)", "position": "m", "loads": "N (N.m)",
    "k_theta": "N.m/rad (N/m prismatic)", "k_c_diagonal": "N.m/rad per N of unit force",
    "k_x": "N/m (translational block)", "k_x_eigenvalues": "N/m",
    "critical_factor": "dimensionless multiplier of the load case",
}


# ---------------------------------------------------------------------------------- figures

_CLASS_COLOURS = ("#2ca02c", "#98df8a", "#d62728", "#ff9896", "#7f7f7f", "#000000")


def _axis_label(spec: ScanSpec, position: int) -> tuple[str, float]:
    """Label and display scale (rad -> deg for revolute joints) of a map axis."""
    axis = spec.axes[position]
    robot = worker_robot(spec.robot)
    joint = robot.model.joints[robot.model.getJointId(axis["joint"])]
    if joint.shortname().startswith("JointModelP"):
        return f"{axis['joint']} (m)", 1.0
    return f"{axis['joint']} (deg)", 180.0 / np.pi


def _load_title(spec: ScanSpec, j: int) -> str:
    load = ",".join(f"{v:g}" for v in spec.loads[j])
    return f"case {spec.load_names[j]}: ({load}) N"


def _png(fig) -> bytes:
    import io

    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def _panels(count: int):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = min(4, count)
    rows = -(-count // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols + 1.2, 3.4 * rows + 0.6),
                             squeeze=False)
    fig.subplots_adjust(left=0.06, right=0.86 if count > 1 else 0.8, bottom=0.1, top=0.88,
                        wspace=0.6, hspace=0.42)
    for ax in axes.flat[count:]:
        ax.set_visible(False)
    return fig, list(axes.flat[:count])


def counts_figure(spec: ScanSpec, acc: MapAccumulator) -> bytes:
    """Stacked bars: configurations per definiteness class of K_C, per load case."""
    fig, (ax,) = _panels(1)
    fig.set_size_inches(max(5.0, 0.9 * len(spec.loads) + 2), 3.8)
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
    return _png(fig)


def _mesh(ax, spec: ScanSpec, acc: MapAccumulator, values: np.ndarray, **kwargs):
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
    return _png(fig)


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
    return _png(fig)


def all_figures(spec: ScanSpec, acc: MapAccumulator) -> dict[str, bytes]:
    """File name -> PNG bytes of the scan's figures."""
    figures = {"definiteness_counts.png": counts_figure(spec, acc)}
    if acc.edges:
        figures["stiffness_map.png"] = stiffness_figure(spec, acc)
        figures["definiteness_map.png"] = definiteness_figure(spec, acc)
    return figures


# ---------------------------------------------------------------------------------- CLI


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Flags of ``stiffness scan``."""
    parser.add_argument("--robot", required=True,
                        help="shipped robot (sk120), example-robot-data name (ur5, panda...) "
                             "or URDF path")
    parser.add_argument("--preset", choices=PRESETS,
                        help="table4: A&S Table IV on the SK120 (theta1 -180..180, theta2 "
                             "-70..70, theta3 -115..35 deg, step 0.2 rad, wrist vertical; the "
                             "eight +-100 N load cases; the paper's K_theta)")
    parser.add_argument("--axis", action="append", default=[], metavar="JOINT=LO:HI[:STEP]",
                        help="swept coordinate (joint name or q1, q2...): a grid LO..HI by "
                             "STEP, or a sampling range without STEP (rad or m; --deg); "
                             "repeat for several axes")
    parser.add_argument("--samples", type=float,
                        help="random configurations (uniform in the --axis ranges, else in the "
                             "joint limits) instead of a grid")
    parser.add_argument("--seed", type=int, default=0, help="seed of --samples; default 0")
    parser.add_argument("--q", help="values of the coordinates that are not swept (all "
                                    "coordinates, comma-separated); default the robot's "
                                    "default pose, else zero")
    parser.add_argument("--deg", action="store_true",
                        help="angles of --axis and --q in degrees")
    parser.add_argument("--load", action="append", default=[], metavar="FX,FY,FZ[,MX,MY,MZ]",
                        help="dead load case at the target, base axes (N, N.m); repeat for "
                             f"several; default {','.join(f'{v:g}' for v in DEFAULT_LOAD_N)}")
    parser.add_argument("--kq", help="joint stiffness per compliant joint, N.m/rad (N/m "
                                     "prismatic); default the robot's")
    parser.add_argument("--frame", help="frame carrying the target (default: robot's own)")
    parser.add_argument("--target-offset", help="target in the frame's axes, m: x,y,z")
    parser.add_argument("--compliant-joints", help="comma-separated joint names (default: all)")
    parser.add_argument("--rtol", type=float, default=1e-9,
                        help="relative eigenvalue tolerance of the definiteness classes")
    parser.add_argument("--map-axes", help="two swept coordinates the figures are drawn over "
                                           "(default: the two with the most values)")
    parser.add_argument("--chunk-size", type=int, default=8192,
                        help="configurations per chunk (memory and the work a killed worker "
                             "loses); default 8192")
    parser.add_argument("--format", choices=FORMATS, default="npz",
                        help="map files: npz (default), parquet (needs pyarrow) or both")
    parser.add_argument("--out", help="output folder (default: a new folder <robot>-<preset> "
                                      "here); an existing scan folder is resumed")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="Dask scheduler address (tcp://host:8786): run the chunks on that "
                             "cluster")
    parser.add_argument("--shared-out", action="store_true",
                        help="with --scheduler: the workers share the --out folder's filesystem "
                             "and write their chunks there themselves (default: the chunks "
                             "travel back and this process writes them)")
    parser.add_argument("--workers", type=int,
                        help="without --scheduler: a Dask LocalCluster of N worker processes "
                             "on this machine (default: this process only)")
    parser.add_argument("--no-plots", action="store_true", help="write no figures")
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON line")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


_AXIS = re.compile(r"^\s*([^=]+?)\s*=\s*([^:]+):([^:]+)(?::([^:]+))?\s*$")


def _joint_index(robot: Robot, name: str) -> int:
    names = list(robot.coordinate_joints)
    if name in names:
        return names.index(name)
    match = re.fullmatch(r"q(\d+)", name)
    if match and 1 <= int(match.group(1)) <= len(names):
        return int(match.group(1)) - 1
    raise StiffnessError(
        f"--axis {name!r} is not a coordinate of {robot.name}; use a joint name or q1..q"
        f"{len(names)}: {did_you_mean(name, names)}"
    )


def _angle_scale(robot: Robot, index: int, deg: bool) -> float:
    joint = robot.model.joints[robot.model.getJointId(robot.coordinate_joints[index])]
    return np.pi / 180.0 if deg and not joint.shortname().startswith("JointModelP") else 1.0


def _joint_range(robot: Robot, index: int) -> tuple[float, float]:
    """Sampling range of a coordinate: its joint limits, or [-pi, pi] when unlimited."""
    model = robot.model
    joint = model.joints[model.getJointId(robot.coordinate_joints[index])]
    prismatic = joint.shortname().startswith("JointModelP")
    if joint.nq == 1:
        lo = float(model.lowerPositionLimit[joint.idx_q])
        hi = float(model.upperPositionLimit[joint.idx_q])
        if np.isfinite(lo) and np.isfinite(hi) and hi > lo and max(abs(lo), abs(hi)) < 1e3:
            return lo, hi
    if prismatic:
        raise StiffnessError(
            f"prismatic joint {robot.coordinate_joints[index]!r} has no finite limits: give its "
            "range with --axis NAME=LO:HI (m)"
        )
    return -np.pi, np.pi


def build_spec(args: argparse.Namespace) -> tuple[ScanSpec, Robot]:
    """The scan specification of a command line (and the loaded robot)."""
    robot, compliant, offset = robot_from_args(args)
    robot_spec = {"source": str(args.robot), "frame": args.frame, "target_offset": offset,
                  "compliant_joints": compliant}
    if args.kq is not None:
        k_theta = parse_list(args.kq, "--kq")
    elif "k_theta_SI" in robot.defaults and compliant is None:
        k_theta = [float(v) for v in robot.defaults["k_theta_SI"]]
    else:
        raise StiffnessError(
            f"--kq is required for {robot.name}: one stiffness per compliant joint "
            f"({', '.join(robot.compliant_joints)}), N.m/rad (N/m prismatic)"
        )
    batch.as_joint_stiffness(k_theta, robot.n_compliant)  # validates
    if args.chunk_size < 1:
        raise StiffnessError(f"--chunk-size must be a positive number, got {args.chunk_size}")
    if args.rtol < 0:
        raise StiffnessError(f"--rtol must be >= 0, got {args.rtol}")
    loads = [parse_list(text, "--load") for text in args.load]
    for load in loads:
        if len(load) not in (3, 6):
            raise StiffnessError(f"--load takes fx,fy,fz (N) or fx,fy,fz,mx,my,mz; got {load}")
    if loads and len({len(x) for x in loads}) > 1:
        loads = [x + [0.0] * (6 - len(x)) for x in loads]
    names = [str(i + 1) for i in range(len(loads))]

    if args.preset == "table4":
        if args.axis or args.samples is not None:
            raise StiffnessError("--preset table4 fixes the grid: drop --axis and --samples")
        if robot.n_coordinates != 6 or robot.n_compliant != 3:
            raise StiffnessError(
                "--preset table4 is the SK120 grid of A&S Table IV (six coordinates, three "
                f"compliant joints); {robot.name} has {robot.n_coordinates} and "
                f"{robot.n_compliant}"
            )
        from stiffness.reproduction import table4_loads

        if not loads:
            names, table = table4_loads()
            loads = table.tolist()
        axes = [{"index": i, "joint": robot.coordinate_joints[i], "lower": None, "upper": None,
                 "step": None} for i in range(3)]
        spec = ScanSpec(robot=robot_spec, preset="table4",
                        coordinate_joints=list(robot.coordinate_joints),
                        base=[0.0] * robot.n_coordinates, axes=axes, samples=None, seed=0,
                        loads=loads, load_names=names, k_theta=k_theta, rtol=args.rtol,
                        chunk_size=args.chunk_size, map_axes=[1, 2])
        return spec, robot

    if not loads:
        loads, names = [list(DEFAULT_LOAD_N)], ["1"]
    if args.q is not None:
        base = np.array(parse_list(args.q, "--q"))
        if base.shape[0] != robot.n_coordinates:
            raise StiffnessError(
                f"--q needs {robot.n_coordinates} values ({', '.join(robot.coordinate_joints)}),"
                f" got {base.shape[0]}"
            )
        base = base * np.array([_angle_scale(robot, i, args.deg)
                                for i in range(robot.n_coordinates)])
    elif "q_SI" in robot.defaults:
        base = np.asarray(robot.defaults["q_SI"], dtype=float)
    elif "q_deg" in robot.defaults:
        base = np.deg2rad(np.asarray(robot.defaults["q_deg"], dtype=float))
    else:
        base = np.zeros(robot.n_coordinates)
    samples = None
    if args.samples is not None:
        if args.samples < 1 or args.samples != int(args.samples):
            raise StiffnessError(f"--samples must be a positive integer, got {args.samples:g}")
        samples = int(args.samples)
    axes = []
    for text in args.axis:
        match = _AXIS.match(text)
        if match is None:
            raise StiffnessError(
                f"--axis takes JOINT=LO:HI:STEP (grid) or JOINT=LO:HI (sampling), got {text!r}"
            )
        index = _joint_index(robot, match.group(1))
        scale = _angle_scale(robot, index, args.deg)
        lo, hi = (parse_list(match.group(k), "--axis")[0] * scale for k in (2, 3))
        step = None if match.group(4) is None else parse_list(match.group(4), "--axis")[0] * scale
        if hi < lo:
            raise StiffnessError(f"--axis {text!r}: the upper bound is below the lower one")
        if samples is None and (step is None or step <= 0):
            raise StiffnessError(
                f"--axis {text!r} needs a positive STEP for a grid (or give --samples N)"
            )
        if any(a["index"] == index for a in axes):
            raise StiffnessError(f"--axis repeats {robot.coordinate_joints[index]}")
        axes.append({"index": index, "joint": robot.coordinate_joints[index], "lower": lo,
                     "upper": hi, "step": None if samples is not None else step})
    if not axes and samples is None:
        samples = 10000
    if not axes:
        for index in range(robot.n_coordinates):
            lo, hi = _joint_range(robot, index)
            axes.append({"index": index, "joint": robot.coordinate_joints[index], "lower": lo,
                         "upper": hi, "step": None})
    preset = "samples" if samples is not None else "grid"
    spec = ScanSpec(robot=robot_spec, preset=preset,
                    coordinate_joints=list(robot.coordinate_joints), base=base.tolist(),
                    axes=axes, samples=samples, seed=args.seed, loads=loads, load_names=names,
                    k_theta=k_theta, rtol=args.rtol, chunk_size=args.chunk_size,
                    map_axes=_map_axes(robot, axes, args.map_axes, samples))
    return spec, robot


def _map_axes(robot: Robot, axes: list[dict], text: str | None, samples: int | None
              ) -> list[int]:
    """Positions in ``axes`` of the figures' axes."""
    if text is not None:
        chosen = []
        for name in (t.strip() for t in text.split(",") if t.strip()):
            index = _joint_index(robot, name)
            where = [k for k, a in enumerate(axes) if a["index"] == index]
            if not where:
                raise StiffnessError(f"--map-axes {name!r} is not a swept coordinate (--axis)")
            chosen.append(where[0])
        if not 1 <= len(chosen) <= 2:
            raise StiffnessError("--map-axes takes one or two swept coordinates")
        return chosen
    if samples is not None:
        return list(range(min(2, len(axes))))
    lengths = [len(grid_axis(a["lower"], a["upper"], a["step"])) for a in axes]
    order = sorted(range(len(axes)), key=lambda k: -lengths[k])
    return sorted(k for k in order[:2] if lengths[k] > 1)


def default_out(spec: ScanSpec) -> Path:
    """A new folder ``<robot>-<preset>`` (``-2``, ``-3``... if taken) in the current directory."""
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", Path(spec.robot["source"]).stem) or "robot"
    base = Path.cwd() / f"{stem}-{spec.preset}"
    candidate, k = base, 1
    while candidate.exists():
        k += 1
        candidate = base.with_name(f"{base.name}-{k}")
    return candidate


def run(args: argparse.Namespace) -> int:
    """Run the scan, print the summary."""
    spec, _ = build_spec(args)
    if args.workers is not None and args.workers < 1:
        raise StiffnessError(f"--workers must be at least 1, got {args.workers}")
    out = Path(args.out) if args.out else default_out(spec)
    formats = ("npz", "parquet") if args.format == "both" else (args.format,)
    label = f"scan {spec.n_configurations} configurations x {len(spec.loads)} loads"
    progress = terminal_progress(label, args.quiet)
    t0 = time.perf_counter()
    summary = run_scan(spec, out, formats=formats, scheduler=args.scheduler,
                       workers=args.workers, plots=not args.no_plots, progress=progress,
                       write_on_workers=True if args.shared_out else None)
    summary["out"] = str(out)
    summary["wall_seconds"] = time.perf_counter() - t0
    if args.json:
        json.dump(summary, sys.stdout)
        sys.stdout.write("\n")
        return 0
    print(f"{summary['robot']} {spec.preset}: {summary['configurations']} configurations "
          f"({summary['valid_configurations']} valid) x {len(spec.loads)} load cases in "
          f"{summary['wall_seconds']:.2f} s -> {out}")
    header = f"{'case':>6} {'load (N)':>24} " + " ".join(f"{c:>6}" for c in COUNT_LABELS)
    print("definiteness of K_C per load case:")
    print(header)
    for name, case in summary["load_cases"].items():
        load = ",".join(f"{v:g}" for v in case["load"])
        print(f"{name:>6} {load:>24} " + " ".join(f"{case['k_c'][c]:>6}" for c in COUNT_LABELS))
    tangent_pd = all(c["k_theta_minus_k_c"]["PD"] == summary["valid_configurations"]
                     for c in summary["load_cases"].values())
    print(f"K_theta - K_C positive definite everywhere: {tangent_pd}")
    return 0
