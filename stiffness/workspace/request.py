"""A workspace scan from Python arguments: the :class:`~stiffness.workspace.spec.ScanSpec` of a
robot, its springs, the swept coordinates and the load cases (what ``stiffness scan`` turns its
flags into, :func:`scan_spec`), and :func:`scan`, which runs it and returns a
:class:`ScanResult` whose :meth:`ScanResult.to_dict` is the command's ``--json`` object.

SI units: rad (m for prismatic joints), N, N.m, N.m/rad, N/m.
"""

from __future__ import annotations

import math
import os
import re
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np

from stiffness.batch import kernels as batch
from stiffness.elastic.file_model import elastic_model_of
from stiffness.elastic.model_contents import ModelFile
from stiffness.elastic.model_file import read_model_file
from stiffness.errors import StiffnessError, wrong_argument
from stiffness.mechanics.defaults import (
    assembly_coordinates,
    default_stiffness,
    loop_sampling_box,
)
from stiffness.mechanics.ik import coordinate_limits
from stiffness.robot.robot import Robot, coordinate_index, load_robot
from stiffness.robot.sources import resolve_source
from stiffness.units import float_array, whole_number
from stiffness.workspace.engine import run_scan
from stiffness.workspace.spec import ScanSpec, grid_length, parse_fields

#: Default load case when none is given (N): 100 N downwards.
DEFAULT_LOAD_N = (0.0, 0.0, -100.0)
#: Random configurations drawn when neither axes nor a sample count are given.
DEFAULT_SAMPLES = 10000


@dataclass
class ScanPreset:
    """Options of a preset scan (a grid a paper provides: :mod:`stiffness.papers.presets`).

    Attributes
    ----------
    axes
        Grid axes ``{"index", "joint", "lower", "upper", "step"}`` (rad or m).
    base
        Coordinates of the joints that are not swept (rad, m).
    couplings
        ``{"index", "axis", "factor"}``: coordinate ``index`` gets ``factor`` times the value
        of ``axes[axis]`` added to its base value.
    load_names, loads
        Default load cases (N), used when no ``--load`` is given.
    map_axes
        Positions in ``axes`` of the figures' axes.
    name
        The preset's name (the scan's label).
    """

    axes: list[dict]
    base: list[float]
    couplings: list[dict]
    load_names: list[str]
    loads: list[list[float]]
    map_axes: list[int]
    name: str = "preset"


def joint_range(robot: Robot, index: int) -> tuple[float, float]:
    """Sampling range of a coordinate (rad, m): its joint limits, or [-pi, pi] when unlimited.

    Raises
    ------
    StiffnessError
        A prismatic joint without finite limits.
    """
    prismatic = robot.is_prismatic(robot.coordinate_joints[index])
    lower, upper = coordinate_limits(robot)  # +-inf for a continuous or unbounded joint
    lo, hi = float(lower[index]), float(upper[index])
    if np.isfinite(lo) and np.isfinite(hi) and hi > lo and max(abs(lo), abs(hi)) < 1e3:
        return lo, hi
    if prismatic:
        raise StiffnessError(
            f"prismatic joint {robot.coordinate_joints[index]!r} has no finite limits: give its "
            "range with --axis NAME=LO:HI (m)"
        )
    return -np.pi, np.pi


def load_cases(wrench: Sequence[float] | Sequence[Sequence[float]] | None
               ) -> tuple[list[list[float]], list[str]]:
    """The load cases (N, N.m; base axes) of one wrench or a list of them, named 1, 2...;
    forces are padded with zero moments when the cases mix 3 and 6 values.

    Raises
    ------
    StiffnessError
        No sequence of numbers, or a case with neither 3 nor 6 values.
    """
    needed = "fx,fy,fz (N) or fx,fy,fz,mx,my,mz (N, N.m), or a list of them"
    if wrench is None:
        return [], []
    if isinstance(wrench, str | bytes) or not hasattr(wrench, "__len__"):
        raise wrong_argument("wrench", wrench, needed)
    if len(wrench) == 0:
        return [], []
    flat = all(not hasattr(v, "__len__") for v in wrench)
    cases = cast("Sequence[Sequence[float]]", [wrench] if flat else wrench)
    loads = [float_array(w, "wrench", needed, ndim=1).tolist() for w in cases]
    for load in loads:
        if len(load) not in (3, 6):
            raise StiffnessError(f"--wrench (alias --load) takes fx,fy,fz (N) or "
                                 f"fx,fy,fz,mx,my,mz (N, N.m); got {load}")
    if len({len(x) for x in loads}) > 1:
        loads = [x + [0.0] * (6 - len(x)) for x in loads]
    return loads, [str(i + 1) for i in range(len(loads))]


def swept_axes(robot: Robot, axes: Mapping[str, Sequence[float]] | Sequence, grid: bool
               ) -> list[dict]:
    """The swept coordinates ``{"index", "joint", "lower", "upper", "step"}`` of ``axes``:
    joint name (or ``q<i>``) to ``(low, high)`` or ``(low, high, step)`` (rad, m), a mapping or
    a sequence of such pairs; every coordinate within its limits when empty (sampled; a
    closed loop's within :func:`~stiffness.mechanics.defaults.loop_sampling_box`).

    Raises
    ------
    StiffnessError
        An unknown coordinate, one swept twice, bounds in the wrong order, a grid axis without
        a positive step.
    """
    needed = "(low, high) or (low, high, step) in rad or m"
    if isinstance(axes, str) or not isinstance(axes, Mapping | Sequence | np.ndarray):
        raise wrong_argument("axes", axes, f"a mapping of coordinate names to {needed}")
    items = list(axes.items()) if isinstance(axes, Mapping) else list(axes)
    out: list[dict] = []
    for item in items:
        if isinstance(item, str) or not isinstance(item, Sequence) or len(item) != 2:
            raise wrong_argument("axes", axes, f"a mapping of coordinate names to {needed}, or "
                                 "a list of (name, bounds) pairs")
        name, bounds = item
        index = coordinate_index(robot, str(name), "--axis")
        if isinstance(bounds, str) or not isinstance(bounds, Sequence | np.ndarray) or len(
                bounds) not in (2, 3):
            raise wrong_argument(f"axes[{name!r}]", bounds, needed)
        lo, hi = float_array(bounds[:2], f"axes[{name!r}]", needed, finite=False).tolist()
        step = float(float_array(bounds[2], f"axes[{name!r}]", needed, ndim=0, finite=False)) \
            if len(bounds) > 2 and bounds[2] is not None else None
        if hi < lo:
            raise StiffnessError(f"--axis {name}: the upper bound is below the lower one")
        if grid and (step is None or step <= 0):
            raise StiffnessError(f"--axis {name} needs a positive STEP for a grid (or give "
                                 "--samples N)")
        if any(a["index"] == index for a in out):
            raise StiffnessError(f"--axis repeats {robot.coordinate_joints[index]}")
        out.append({"index": index, "joint": robot.coordinate_joints[index], "lower": lo,
                    "upper": hi, "step": step if grid else None})
    if not out:  # every coordinate, sampled: a closed loop near its reference assembly
        ranges = np.array([joint_range(robot, i) for i in range(robot.n_coordinates)])
        lower, upper = loop_sampling_box(robot, ranges[:, 0], ranges[:, 1])
        for index in range(robot.n_coordinates):
            out.append({"index": index, "joint": robot.coordinate_joints[index],
                        "lower": float(lower[index]), "upper": float(upper[index]),
                        "step": None})
    return out


def figure_axes(robot: Robot, axes: list[dict], names: Sequence[str] | None,
                samples: int | None) -> list[int]:
    """Positions in ``axes`` of the figures' axes: the named coordinates, else the first two
    sampled ones, else the two grid axes with the most values.

    Raises
    ------
    StiffnessError
        A name that is not swept, or not one or two names.
    """
    if names is not None:
        chosen = []
        for name in names:
            index = coordinate_index(robot, name, "--map-axes")
            where = [k for k, a in enumerate(axes) if a["index"] == index]
            if not where:
                raise StiffnessError(f"--map-axes {name!r} is not a swept coordinate (--axis)")
            chosen.append(where[0])
        if not 1 <= len(chosen) <= 2:
            raise StiffnessError("--map-axes takes one or two swept coordinates")
        return chosen
    if samples is not None:
        return list(range(min(2, len(axes))))
    lengths = [grid_length(a["lower"], a["upper"], a["step"]) for a in axes]
    order = sorted(range(len(axes)), key=lambda k: -lengths[k])
    return sorted(k for k in order[:2] if lengths[k] > 1)


def default_scan_load(robot: Robot) -> list[float]:
    """The load of a scan given none: the robot's declared ``wrench_SI`` (N, or N and N.m;
    base axes), the load ``kx`` and ``view`` use, else :data:`DEFAULT_LOAD_N`. A load held
    against springs at rest (``rest_q_SI``) depends on the configuration, so a scan does not
    take it as its one load case."""
    declared = robot.defaults.get("wrench_SI")
    return [float(v) for v in (DEFAULT_LOAD_N if declared is None else declared)]


def scan_spec(robot: Robot, robot_spec: dict, k_theta: Sequence[float] | np.ndarray | None,
              *, preset: ScanPreset | None = None,
              axes: Mapping[str, Sequence[float]] | Sequence = (),
              samples: float | None = None, seed: int = 0, q: np.ndarray | None = None,
              wrench: Sequence[float] | Sequence[Sequence[float]] | None = None,
              rtol: float = 1e-9, chunk_size: int = 8192,
              map_axes: Sequence[str] | None = None, fields: str | None = None,
              dtype: str = "float64", compression: str | None = None) -> ScanSpec:
    """What a scan of ``robot`` computes (see :class:`ScanSpec`).

    Parameters
    ----------
    robot, robot_spec
        The loaded robot, and the :func:`~stiffness.robot.robot.load_robot` arguments the
        chunks load it with (``source``, ``frame``, ``target_offset``, ``compliant_joints``
        and, when given, ``loops`` and ``fixed_base``).
    k_theta
        Joint stiffness per compliant joint (N.m/rad, N/m); default the robot's shipped one.
    preset
        A preset grid (its axes, coordinates and default loads); then no ``axes``/``samples``.
    axes, samples, seed
        Swept coordinates (:func:`swept_axes`, rad or m): a grid, or ``samples`` random
        configurations in their ranges (default :data:`DEFAULT_SAMPLES` over the joint limits
        when no axis is given; for a closed loop within
        :func:`~stiffness.mechanics.defaults.loop_sampling_box` of its reference assembly)
        drawn with ``seed``.
    q
        Coordinates of the joints not swept (rad, m); default the robot's shipped pose, else
        zero.
    wrench
        Load cases (:func:`load_cases`); default the preset's, else the robot's own
        (:func:`default_scan_load`).
    rtol, chunk_size, map_axes, fields, dtype, compression
        Definiteness tolerance, configurations per chunk, the figures' coordinates, stored
        fields (:func:`~stiffness.workspace.spec.parse_fields` text), storage type and codec.

    Raises
    ------
    StiffnessError
        Missing or bad springs, bad sizes, tolerance, axes or loads (one line each).
    """
    if k_theta is None:
        k_theta = default_stiffness(robot)
        if k_theta is None:
            raise StiffnessError(
                f"--kq is required for {robot.title}: one stiffness per compliant joint "
                f"({', '.join(robot.compliant_joints)}), N.m/rad (N/m prismatic)")
    springs: list[float] = float_array(
        k_theta, "k_theta", f"one stiffness per compliant joint of {robot.title} (N.m/rad, N/m "
        "prismatic)", finite=False).reshape(-1).tolist()
    batch.as_joint_stiffness(springs, robot.n_compliant)  # validates
    if chunk_size < 1:
        raise StiffnessError(f"--chunk-size must be a positive number, got {chunk_size}")
    if rtol < 0:
        raise StiffnessError(f"--rtol must be >= 0, got {rtol}")
    loads, names = load_cases(wrench)
    whole_number(seed, "seed", 0)
    stored = parse_fields(fields)
    common: dict[str, Any] = {
        "robot": robot_spec, "coordinate_joints": list(robot.coordinate_joints),
        "k_theta": springs, "rtol": rtol, "chunk_size": chunk_size, "fields": stored,
        "dtype": dtype, "compression": compression}
    if preset is not None:
        if len(axes) or samples is not None:
            raise StiffnessError(f"--preset {preset.name} fixes the grid: drop --axis and "
                                 "--samples")
        if not loads:
            names, loads = preset.load_names, preset.loads
        return ScanSpec(preset=preset.name, base=preset.base, axes=preset.axes, samples=None,
                        seed=0, loads=loads, load_names=names, map_axes=preset.map_axes,
                        couplings=preset.couplings, **common)
    if not loads:
        loads, names = [default_scan_load(robot)], ["1"]
    if samples is not None:
        samples = float(float_array(samples, "samples", "a positive whole number", ndim=0,
                                    finite=False))
        if not math.isfinite(samples) or samples < 1 or samples != int(samples):
            raise StiffnessError(f"--samples must be a positive integer, got {samples:g}")
        samples = int(samples)
    swept = swept_axes(robot, axes, grid=samples is None)
    if not len(axes) and samples is None:
        samples = DEFAULT_SAMPLES
    if q is None:
        q = assembly_coordinates(robot)  # a loop's assembly when zero does not close
    base = float_array(q, "q", f"the {robot.n_coordinates} coordinates of {robot.title} (rad, m)",
                       size=robot.n_coordinates).reshape(-1)
    return ScanSpec(preset="samples" if samples is not None else "grid", base=base.tolist(),
                    axes=swept, samples=samples, seed=seed, loads=loads, load_names=names,
                    map_axes=figure_axes(robot, swept, map_axes, samples), **common)


def default_out(spec: ScanSpec) -> Path:
    """A new folder ``<robot>-<preset>`` (``-2``, ``-3``... if taken) in the current directory."""
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", Path(spec.robot["source"]).stem) or "robot"
    base = Path.cwd() / f"{stem}-{spec.preset}"
    candidate, k = base, 1
    while candidate.exists():
        k += 1
        candidate = base.with_name(f"{base.name}-{k}")
    return candidate


@dataclass
class ScanResult:
    """A finished scan: its specification, folder and summary.

    Attributes
    ----------
    spec
        What was computed.
    out
        The scan folder (``manifest.json``, chunks, ``summary.json``, figures).
    summary
        :func:`~stiffness.workspace.engine.run_scan`'s summary.
    wall_seconds
        Wall time of the run (s).
    """

    spec: ScanSpec
    out: Path
    summary: dict
    wall_seconds: float

    def to_dict(self) -> dict:
        """The object ``stiffness scan --json`` prints: the summary with ``out`` and
        ``wall_seconds``."""
        return {**self.summary, "out": str(self.out), "wall_seconds": self.wall_seconds}


def model_robot(model: ModelFile | str | os.PathLike) -> tuple[Robot, dict, list[float]]:
    """The robot of a model file (``identified-model.json``, ``final-model.json``) with its
    joint-compliance and target effects, the arguments the chunks load it with, and its
    springs (N.m/rad, N/m).

    Raises
    ------
    StiffnessError
        A model whose link or nonlinear effects change K_X beyond joint springs (the batched
        scan models springs only).
    """
    declared = model if isinstance(model, ModelFile) else read_model_file(model)
    elastic = elastic_model_of(declared)
    extra = list(elastic.beyond_springs)
    if extra:
        raise StiffnessError(
            f"scan --model: {', '.join(extra)} change K_X beyond joint springs, which the "
            "batched scan does not model; use `stiffness kx --model` or `stiffness view "
            "--model` at chosen poses, or give --kq to scan the springs alone")
    robot = elastic.robot
    robot_spec = {"source": declared.source, "frame": robot.target_frame,
                  "target_offset": robot.target_offset.tolist(),
                  "compliant_joints": list(robot.compliant_joints),
                  **{k: v for k, v in declared.robot_options().items() if v}}
    return robot, robot_spec, elastic.k_theta.tolist()


def _reload_options(robot: Robot) -> dict:
    """What the chunks need beyond its name to reload ``robot`` as loaded: ``fixed_base``
    when its base was fixed, ``loops`` when its loop file is not the one its source finds
    by itself (keys only then, so that the specs of earlier scans still match)."""
    options: dict[str, Any] = {"fixed_base": True} if robot.fixed_base else {}
    if robot.loop_file is not None:
        found = resolve_source(robot.name).loop_file
        if found is None or Path(found).resolve() != Path(robot.loop_file).resolve():
            options["loops"] = str(Path(robot.loop_file).resolve())
    return options


def scan(robot: Robot | str | None = None, out: str | os.PathLike | None = None, *,
         model: ModelFile | str | os.PathLike | None = None,
         k_theta: Sequence[float] | np.ndarray | None = None,
         axes: Mapping[str, Sequence[float]] | Sequence = (), samples: float | None = None,
         seed: int = 0, q: np.ndarray | None = None,
         wrench: Sequence[float] | Sequence[Sequence[float]] | None = None,
         preset: ScanPreset | None = None, robot_spec: dict | None = None,
         formats: tuple[str, ...] = ("npz",), plots: bool = True,
         on_spec: Callable[[ScanSpec], None] | None = None, **options) -> ScanResult:
    """Scan a workspace: ``stiffness scan`` from Python (:meth:`ScanResult.to_dict` is its
    ``--json`` object).

    Parameters
    ----------
    robot
        The robot, or its source (shipped name, example-robot-data name, URDF path). A loaded
        robot is reloaded by the chunks from its name, target and compliant joints unless
        ``robot_spec`` says how.
    model
        Instead of ``robot``: a model file (or its path), whose robot, target and springs are
        scanned (:func:`model_robot`; ``k_theta`` replaces its springs).
    out
        Scan folder (an existing one with the same spec is resumed); default a new
        ``<robot>-<preset>`` folder here (:func:`default_out`).
    k_theta, axes, samples, seed, q, wrench, preset
        As :func:`scan_spec` (SI).
    robot_spec
        The chunks' :func:`~stiffness.robot.robot.load_robot` arguments (see above).
    formats, plots
        ``npz`` and/or ``parquet``; whether to draw the figures.
    on_spec
        Called with the spec before the run (the command prints its inputs).
    **options
        ``rtol``, ``chunk_size``, ``map_axes``, ``fields``, ``dtype``, ``compression`` (to
        :func:`scan_spec`) and ``scheduler``, ``workers``, ``write_on_workers``,
        ``chunks_per_task``, ``progress`` (to :func:`~stiffness.workspace.engine.run_scan`).

    Raises
    ------
    StiffnessError
        Bad inputs (:func:`scan_spec`), or a folder holding another scan.
    """
    spec_keys = ("rtol", "chunk_size", "map_axes", "fields", "dtype", "compression")
    run_keys = ("scheduler", "workers", "write_on_workers", "chunks_per_task", "progress")
    unknown = sorted(set(options) - set(spec_keys) - set(run_keys))
    if unknown:
        raise TypeError(f"scan() got unexpected keyword arguments {', '.join(unknown)}")
    if model is not None:
        if robot is not None:
            raise StiffnessError("give a robot or a model file, not both")
        robot, robot_spec, springs = model_robot(model)
        k_theta = springs if k_theta is None else k_theta
    if robot is None:
        raise StiffnessError("give a robot (or a model file)")
    if not isinstance(robot, Robot):
        robot_spec = robot_spec or {"source": str(robot), "frame": None,
                                    "target_offset": None, "compliant_joints": None}
        robot = load_robot(robot)
    robot_spec = robot_spec or {"source": robot.name, "frame": robot.target_frame,
                                "target_offset": robot.target_offset.tolist(),
                                "compliant_joints": list(robot.compliant_joints),
                                **_reload_options(robot)}
    spec = scan_spec(robot, robot_spec, k_theta, preset=preset, axes=axes, samples=samples,
                     seed=seed, q=q, wrench=wrench,
                     **{k: options[k] for k in spec_keys if k in options})
    if on_spec is not None:
        on_spec(spec)
    out = Path(out) if out is not None else default_out(spec)
    t0 = time.perf_counter()
    summary = run_scan(spec, out, formats=formats, plots=plots,
                       **{k: options[k] for k in run_keys if k in options})
    return ScanResult(spec, out, summary, time.perf_counter() - t0)
