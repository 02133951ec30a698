"""What a workspace scan computes and stores: :class:`ScanSpec`, the stored fields, grid axes.

A scan is described by a JSON-serialisable :class:`ScanSpec` and cut into chunks of
``chunk_size`` configurations; chunk ``i``'s coordinates are a pure function of (spec, i)
(:meth:`ScanSpec.chunk_coordinates`), so any process can compute any chunk and the stored maps
need not hold the coordinates.

Stored fields (:data:`STORED_FIELDS`) are the per-configuration results that no other stored
array determines; :data:`DERIVED_FIELDS` are rebuilt from them when a scan is read
(:func:`stiffness.workspace.maps.derive`). SI units: rad, m, N, N.m/rad, N/m.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from stiffness.errors import StiffnessError
from stiffness.files import resolve_path, resolve_source, written_path, written_source
from stiffness.mechanics.formulation import DEFINITENESS_CLASSES

#: Version of the chunk layout (2: stored fields chosen, packed symmetric K_X, no derivable
#: arrays, coordinates rebuilt from the spec).
LAYOUT_VERSION = 2
#: Classes counted per load case: the definiteness classes, then invalid configurations.
COUNT_LABELS = (*DEFINITENESS_CLASSES, "invalid")
#: Bins per sampled map axis.
SAMPLE_BINS = 32

#: Stored fields and what they hold (``c`` configurations, ``L`` loads, ``n`` compliant joints,
#: ``r`` Cartesian rows). ``k_x`` and ``k_x_conventional`` are stored as their upper triangle
#: when symmetric (force loads).
STORED_FIELDS = {
    "coordinates": "(c, n_coordinates) rad/m; also rebuilt from the spec when not stored",
    "position": "(c, 3) target position, m",
    "valid": "(c,) the loop closed and is regular",
    "k_c_class": "(c, L) int8 definiteness class of K_C (-1 invalid)",
    "tangent_class": "(c, L) int8 definiteness class of K_theta - K_C",
    "critical_factor": "(c, L) load factor where K_theta - K_C stops being positive definite",
    "k_c_det_positive": "(c, L) det K_C > 0",
    "k_c_diagonal": "(c, 3, n) diagonal of K_C under unit forces x, y, z, N.m/rad per N",
    "k_x": "(c, L, r, r) enhanced K_X, N/m",
    "k_x_conventional": "(c, r, r) conventional K_X (K_C = 0), N/m",
}
#: Fields rebuilt when a scan is read, from the stored field they derive from.
DERIVED_FIELDS = {
    "index": None,
    "k_x_eigenvalues": "k_x",
    "k_x_class": "k_x",
    "regular": "k_x",
    "k_x_conventional_eigenvalues": "k_x_conventional",
    "regular_conventional": "k_x_conventional",
}
#: Fields stored by default: all of them but the coordinates (rebuilt from the spec).
DEFAULT_FIELDS = tuple(k for k in STORED_FIELDS if k != "coordinates")
#: Where the map arrays (NPZ and Parquet, as read back by ``load_scan``) hold NaN or inf, and
#: why: nowhere else. Written in ``manifest.json`` and ``summary.json`` (whose ``k_x_undefined``
#: counts, per load case, the valid configurations where K_X is undefined; ``None`` in JSON
#: stands for a non-finite value).
UNDEFINED = {
    "k_x, k_x_eigenvalues (Parquet: k_x_AB, k_x_eigK_N_per_m)":
        "NaN where regular is False: K_X = C^-1 does not exist there (a kinematic singularity "
        "or fewer compliant joints than directions: the compliance C is singular, condition "
        "number above 1e12; or K_theta - K_C singular: the buckling limit), or the "
        "configuration is invalid; the k_x_class is then -1 (Parquet: empty)",
    "k_x_conventional, k_x_conventional_eigenvalues (Parquet: k_x_conventional_eigK_N_per_m)":
        "NaN where regular_conventional is False: J K_theta^-1 J^T is singular (kinematic "
        "singularity), or the configuration is invalid",
    "position, critical_factor, k_c_diagonal (Parquet: x_m, y_m, z_m, critical_factor, "
    "k_c_diag_FJ)":
        "NaN where valid is False: the loop is singular there (passive joints not determined) "
        "or could not be closed",
    "critical_factor (inf)":
        "+inf where K_C has no positive eigenvalue: no positive multiple of the load case "
        "makes K_theta - K_C indefinite (a zero load, or K_C negative semidefinite); also in "
        "float32 storage where it exceeds 3.4e38",
}
#: Floating-point storage types.
DTYPES = ("float64", "float32")
#: Compression of the map files: Parquet codecs; for NPZ any of them means deflate.
COMPRESSIONS = ("none", "snappy", "zstd", "gzip")


def grid_length(lower: float, upper: float, step: float) -> int:
    """Number of values of :func:`grid_axis` (computed without building the axis).

    Raises
    ------
    StiffnessError
        A step so small that the count is not finite (e.g. 1e-320 over a finite range).
    """
    count = (upper - lower) / step + 1e-9
    if not math.isfinite(count):
        raise StiffnessError(f"a grid axis from {lower:g} to {upper:g} in steps of {step:g} has "
                             "no finite number of values; give a larger step")
    return int(math.floor(count)) + 1


def grid_axis(lower: float, upper: float, step: float) -> np.ndarray:
    """Values ``lower, lower + step, ...`` not beyond ``upper`` (same unit as the inputs)."""
    return lower + step * np.arange(grid_length(lower, upper, step))


def parse_fields(text: str | None) -> list[str]:
    """The stored fields of a ``--fields`` value (comma-separated; "all"; derived names pull in
    the field they derive from), in :data:`STORED_FIELDS` order.

    Raises
    ------
    StiffnessError
        On an unknown name (the choices are listed).
    """
    if text is None:
        return list(DEFAULT_FIELDS)
    wanted: set[str] = set()
    for name in (t.strip() for t in text.split(",") if t.strip()):
        if name == "all":
            wanted |= set(STORED_FIELDS)
        elif name in STORED_FIELDS:
            wanted.add(name)
        elif name in DERIVED_FIELDS:
            source = DERIVED_FIELDS[name]
            if source is not None:
                wanted.add(source)
        else:
            choices = ", ".join(["all", *STORED_FIELDS, *(k for k in DERIVED_FIELDS if k)])
            raise StiffnessError(f"--fields: unknown field {name!r}; choose from {choices}")
    if not wanted:
        raise StiffnessError("--fields names no field; e.g. --fields k_x,position")
    return [k for k in STORED_FIELDS if k in wanted]


@dataclass
class ScanSpec:
    """What a scan computes; JSON-serialisable, sent with every chunk.

    Attributes
    ----------
    robot
        Keyword arguments of :func:`stiffness.robot.robot.load_robot`.
    preset
        "grid", "samples", or the name of a preset that built the spec (a label).
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
    couplings
        Coordinates that follow swept ones linearly: ``{"index", "axis", "factor"}`` adds
        ``factor`` times the value of ``axes[axis]`` to coordinate ``index`` (on top of
        ``base``), e.g. a wrist kept vertical.
    fields
        Stored fields (:data:`STORED_FIELDS`).
    dtype
        Storage type of the floating-point fields (computation is float64).
    compression
        :data:`COMPRESSIONS` entry, or None for the defaults (NPZ uncompressed, Parquet
        snappy).
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
    couplings: list[dict] = field(default_factory=list)
    fields: list[str] = field(default_factory=lambda: list(DEFAULT_FIELDS))
    dtype: str = "float64"
    compression: str | None = None
    layout: int = LAYOUT_VERSION

    @classmethod
    def from_dict(cls, data: dict, folder: Path | None = None) -> ScanSpec:
        """Rebuild a spec from :meth:`to_dict` output; with ``folder`` (where the file holding
        it is), the robot's paths written relative to it are resolved against it."""
        if folder is None:
            return cls(**data)
        robot = dict(data["robot"])
        robot["source"] = resolve_source(robot["source"], folder)
        if robot.get("loops"):
            robot["loops"] = resolve_path(robot["loops"], folder)
        return cls(**{**data, "robot": robot})

    def to_dict(self, folder: Path | None = None) -> dict:
        """JSON-ready form; with ``folder`` (where it is written), the robot's source and loop
        file relative to it (:func:`~stiffness.files.written_source`)."""
        data = asdict(self)
        if folder is not None:
            robot = data["robot"]
            robot["source"] = written_source(robot["source"], folder)
            if robot.get("loops"):
                robot["loops"] = written_path(robot["loops"], folder)
        return data

    @property
    def axis_lengths(self) -> list[int]:
        """Number of values of each grid axis."""
        return [grid_length(a["lower"], a["upper"], a["step"]) for a in self.axes]

    @property
    def n_configurations(self) -> int:
        """Number of configurations scanned."""
        if self.samples is not None:
            return int(self.samples)
        return math.prod(self.axis_lengths) if self.axes else 1

    @property
    def n_chunks(self) -> int:
        """Number of chunks."""
        return -(-self.n_configurations // self.chunk_size)

    @property
    def rows(self) -> int:
        """Cartesian rows of K_X: 3 for force loads, 6 for wrenches."""
        return 3 if len(self.loads[0]) == 3 else 6

    @property
    def moments(self) -> bool:
        """Whether a load case holds a moment (then K_X is not symmetric)."""
        return len(self.loads[0]) == 6 and any(any(v != 0 for v in x[3:]) for x in self.loads)

    def chunk_range(self, index: int) -> tuple[int, int]:
        """First and one-past-last configuration of chunk ``index``."""
        start = index * self.chunk_size
        return start, min(self.n_configurations, start + self.chunk_size)

    def chunk_coordinates(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Global configuration indices and coordinates (rad, m) of chunk ``index``."""
        start, stop = self.chunk_range(index)
        ids = np.arange(start, stop, dtype=np.int64)
        coords = np.repeat(np.asarray(self.base, dtype=float)[None, :], stop - start, axis=0)
        swept = np.empty((stop - start, len(self.axes)))
        if self.samples is not None:
            rng = np.random.default_rng([self.seed, index])
            for k, a in enumerate(self.axes):
                swept[:, k] = rng.uniform(a["lower"], a["upper"], stop - start)
        elif self.axes:  # the grid_axis values at the chunk's indices, without the axes
            for k, (a, idx) in enumerate(zip(
                    self.axes, np.unravel_index(ids, self.axis_lengths), strict=True)):
                swept[:, k] = a["lower"] + a["step"] * idx
        for k, a in enumerate(self.axes):
            coords[:, a["index"]] = swept[:, k]
        for c in self.couplings:
            coords[:, c["index"]] = coords[:, c["index"]] + c["factor"] * swept[:, c["axis"]]
        return ids, coords

    @property
    def map_cells(self) -> int:
        """Cells of the figures' maps (bins of the map axes, times the load cases)."""
        bins = [SAMPLE_BINS if self.axes[i]["step"] is None else self.axis_lengths[i]
                for i in self.map_axes]
        return int(np.prod(bins, dtype=float)) * len(self.loads)

    def bin_edges(self, axis: dict) -> np.ndarray:
        """Bin edges of a map axis: midpoints between grid values, or uniform for samples."""
        if axis["step"] is None:
            return np.linspace(axis["lower"], axis["upper"], SAMPLE_BINS + 1)
        values = grid_axis(axis["lower"], axis["upper"], axis["step"])
        if values.shape[0] == 1:
            return np.array([values[0] - 0.5, values[0] + 0.5])
        mid = 0.5 * (values[1:] + values[:-1])
        return np.concatenate([[2 * values[0] - mid[0]], mid, [2 * values[-1] - mid[-1]]])
