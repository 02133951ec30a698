"""Workspace scan engine: stiffness and definiteness maps over many configurations, chunked.

Per configuration and load case a scan computes, with :mod:`stiffness.batch.kernels`: the
definiteness
class of K_C and of K_theta - K_C, the load factor at which K_theta - K_C stops being positive
definite, the enhanced Cartesian stiffness K_X (A&S eq. 10) and its principal values, and the
conventional K_X (eq. 8).

A scan is described by a :class:`ScanSpec` (JSON-serialisable) and cut into chunks of
``spec.chunk_size`` configurations; a chunk is a pure function of (spec, index)
(:func:`scan_chunk`), so any process can compute it. :func:`run_scan` runs the missing chunks
through :func:`stiffness.scan.distributed.run_chunks` (in this process, on a Dask LocalCluster or on
a remote cluster), writes each chunk to the output folder as soon as it is done (NPZ and/or
Parquet), so memory is bounded by the chunk size and a killed run loses only unfinished
chunks, and folds each chunk into a streaming :class:`MapAccumulator` for the summary and the
figures (:mod:`stiffness.scan.plots`). Running it again on the same folder resumes the scan.

Files in the output folder:

* ``manifest.json``: the scan's specification (robot, coordinates, loads, K_theta, units);
* ``chunks/chunk-NNNNN.npz`` ("npz") and/or ``maps.parquet/part-NNNNN.parquet`` ("parquet",
  one row per configuration and load case);
* ``chunks/aggregate-NNNNN.npz``: the chunk's contribution to the summary (marks it done);
* ``summary.json`` (class counts per load case, extremes) and the figures
  ``definiteness_counts.png``, ``definiteness_map.png``, ``stiffness_map.png``.

SI units: rad, m, N, N.m/rad, N/m.
"""

from __future__ import annotations

import functools
import json
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from stiffness.batch import kernels as batch
from stiffness.errors import MissingFileError, StiffnessError
from stiffness.files import atomic_write, atomic_write_with, output_folder
from stiffness.mechanics.formulation import DEFINITENESS_CLASSES
from stiffness.model.robot import Robot
from stiffness.scan.definiteness import grid_axis
from stiffness.scan.distributed import run_chunks, worker_robot

#: Version of the chunk layout written by this module.
LAYOUT_VERSION = 1
#: Bins per sampled map axis.
SAMPLE_BINS = 32
#: Classes counted per load case: the definiteness classes, then invalid configurations.
COUNT_LABELS = (*DEFINITENESS_CLASSES, "invalid")
#: Where the map arrays (NPZ and Parquet) hold NaN or inf, and why: nowhere else. Written in
#: ``manifest.json`` and ``summary.json`` (whose ``k_x_undefined`` counts, per load case, the
#: valid configurations where K_X is undefined; ``None`` in JSON stands for a non-finite value).
UNDEFINED = {
    "k_x, k_x_eigenvalues (Parquet: k_x_AB, k_x_eigK_N_per_m)":
        "NaN where regular is False: K_X = C^-1 does not exist there (a kinematic singularity "
        "or fewer compliant joints than directions: the compliance C is singular, condition "
        "number above 1e12; or K_theta - K_C singular: the buckling limit), or the "
        "configuration is invalid; the k_x_class is then -1 (Parquet: empty)",
    "k_x_conventional, k_x_conventional_eigenvalues (Parquet: k_x_conventional_eigK_N_per_m)":
        "NaN where regular_conventional is False: J K_theta^-1 J^T is singular (kinematic "
        "singularity), or the configuration is invalid",
    "position, critical_factor, k_c_diagonal (Parquet: x_m, y_m, z_m, critical_factor)":
        "NaN where valid is False: the loop is singular there (passive joints not determined) "
        "or could not be closed",
    "critical_factor (inf)":
        "+inf where K_C has no positive eigenvalue: no positive multiple of the load case "
        "makes K_theta - K_C indefinite (a zero load, or K_C negative semidefinite)",
}


# ---------------------------------------------------------------------------------- spec


@dataclass
class ScanSpec:
    """What a scan computes; JSON-serialisable, sent with every chunk.

    Attributes
    ----------
    robot
        Keyword arguments of :func:`stiffness.model.robot.load_robot`.
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
    from stiffness.papers.reproduction import table4_grid

    grid = table4_grid()
    grid.setflags(write=False)
    return grid


def _table4_size() -> int:
    """Number of configurations of the A&S Table IV grid."""
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
        ``regular_conventional`` (c,), ``k_x_conventional`` (c, r, r) and
        ``k_x_conventional_eigenvalues`` (c, r). NaN and inf only as :data:`UNDEFINED` says.
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
        "regular_conventional": conventional.regular[:, 0] & valid,
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
            undefined = int(p["k_x_counts"][j][-1]) - int(p["n"][0] - p["n_valid"][0])
            cases[name] = {
                "load": spec.loads[j],
                "k_x_undefined": undefined,
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
            "undefined": UNDEFINED,
        }


def _nanreduce(func: Callable[..., np.ndarray], values: np.ndarray, empty: float
               ) -> np.ndarray | float:
    """``func(values, axis=0)`` for a NaN-ignoring ``func``; ``empty`` where no value is."""
    if values.shape[0] == 0 or np.all(np.isnan(values)):
        return np.full(values.shape[1:], empty) if values.ndim > 1 else empty
    out = func(values, axis=0)
    return np.where(np.isnan(out), empty, out)


def _counts(row: np.ndarray) -> dict[str, int]:
    """Class counts of one load case, by :data:`COUNT_LABELS`."""
    return {label: int(v) for label, v in zip(COUNT_LABELS, row, strict=True)}


def _finite_or_none(value: float) -> float | None:
    """``value``, or None when it is not finite (JSON has no inf)."""
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
    table["regular_conventional"] = np.repeat(maps["regular_conventional"], n_loads)
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
        raise MissingFileError(f"{out} holds no NPZ chunk (chunks/chunk-*.npz); was it written "
                               "with --format parquet?", path=out)
    parts = [dict(np.load(f)) for f in files]
    return {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}


# ---------------------------------------------------------------------------------- run


def run_scan(spec: ScanSpec, out: str | os.PathLike, formats: tuple[str, ...] = ("npz",),
             scheduler: str | None = None, workers: int | None = None,
             client: object | None = None, plots: bool = True,
             progress: Callable[[int, int], None] | None = None,
             write_on_workers: bool | None = None) -> dict:
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
        Where the chunks run (see :func:`stiffness.scan.distributed.run_chunks`). A script that
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

    Returns
    -------
    dict
        JSON-ready summary (:meth:`MapAccumulator.summary`) with ``chunks`` (total, computed,
        resumed, chunk_size), ``compute_seconds``, ``units`` and, with figures,
        ``plot_seconds``; also written to ``out/summary.json``.
    """
    out = Path(out)
    manifest = {"layout": LAYOUT_VERSION, "spec": spec.to_dict(), "formats": list(formats),
                "n_configurations": spec.n_configurations, "n_chunks": spec.n_chunks,
                "units": _UNITS, "classes": list(DEFINITENESS_CLASSES), "undefined": UNDEFINED}
    manifest_file = out / "manifest.json"
    if manifest_file.is_file():
        previous = json.loads(manifest_file.read_text())
        if previous.get("spec") != json.loads(json.dumps(spec.to_dict())):
            raise StiffnessError(
                f"{out} holds a different scan (its manifest.json differs); give a new --out "
                "folder, or the same options to resume it"
            )
    else:
        output_folder(out)
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
        from stiffness.scan.plots import all_figures  # matplotlib only when drawing

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

