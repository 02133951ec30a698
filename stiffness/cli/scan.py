"""``stiffness scan``: stiffness and definiteness maps over a workspace.

Examples::

    stiffness scan --robot sk120 --preset table4            # A&S Table IV: 5824 x 8 loads
    stiffness scan --robot ur5 --kq 3e5,3e5,2e5,4e4,4e4,4e4 --deg \\
        --axis shoulder_lift_joint=-90:0:5 --axis elbow_joint=0:150:5 --wrench 0,0,-200
    stiffness scan --robot ur5 --kq ... --samples 1000000 --workers 2
    stiffness scan --robot panda --kq ... --samples 1e7 --scheduler tcp://10.0.0.5:8786

This module turns the flags into a :class:`~stiffness.workspace.engine.ScanSpec` and hands it to
:func:`stiffness.workspace.engine.run_scan`, which computes, per configuration and load case, the
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

What is stored is chosen with ``--fields`` (default: everything but the coordinates, which the
manifest determines), in ``--dtype`` float64 or float32, with ``--compression``; nothing that
another stored array determines is stored (symmetric K_X as its upper triangle, no
eigenvalues): :func:`stiffness.workspace.engine.load_scan` rebuilds them. The run prints its bytes
per configuration. With Dask, a task computes ``--chunks-per-task`` consecutive chunks
(default: chosen from the measured per-task overhead). Presets (``--preset``) come from the
papers layer (:data:`stiffness.papers.presets.SCAN_PRESETS`).

Files in ``--out`` (default: a new folder ``<robot>-<preset>`` in the current directory):

* ``manifest.json``: the scan's specification (robot, coordinates, loads, K_theta, fields,
  dtype, units);
* ``chunks/chunk-NNNNN.npz`` (``--format npz``: the stored fields) and/or
  ``maps.parquet/part-NNNNN.parquet`` (``--format parquet``, one row per configuration and
  load case);
* ``chunks/aggregate-NNNNN.npz``: the chunk's contribution to the summary (marks it done);
* ``summary.json`` (class counts per load case, extremes) and the figures
  ``definiteness_counts.png``, ``definiteness_map.png``, ``stiffness_map.png``.

SI units: rad (``--deg`` for degrees on the command line), m, N, N.m/rad, N/m.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
import time
from pathlib import Path

import numpy as np

from stiffness.batch import kernels as batch
from stiffness.cli import flags
from stiffness.cli.flags import parse_list, robot_from_args, stiffness_required
from stiffness.cli.kx import _identified_model, compliant_model_from_args
from stiffness.elastic.model_file import BEYOND_SPRINGS
from stiffness.errors import StiffnessError
from stiffness.mechanics.defaults import default_stiffness
from stiffness.papers.presets import SCAN_PRESETS
from stiffness.robot.robot import Robot
from stiffness.workspace.definiteness import terminal_progress
from stiffness.workspace.engine import load_scan, run_scan, scan_chunk
from stiffness.workspace.spec import (
    COMPRESSIONS,
    COUNT_LABELS,
    DERIVED_FIELDS,
    DTYPES,
    STORED_FIELDS,
    ScanSpec,
    grid_length,
    parse_fields,
)

# The scan engine lives in stiffness.workspace.engine (figures: stiffness.workspace.plots);
# ScanSpec, load_scan, run_scan and scan_chunk are re-exported for code that imports them here.
__all__ = ["DEFAULT_LOAD_N", "FORMATS", "PRESETS", "ScanSpec", "build_spec", "configure_parser",
           "default_out", "load_scan", "run", "run_scan", "scan_chunk"]

PRESETS = tuple(SCAN_PRESETS)
FORMATS = ("npz", "parquet", "both")
#: Default load case when none is given (N): 100 N downwards.
DEFAULT_LOAD_N = (0.0, 0.0, -100.0)


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Flags of ``stiffness scan``."""
    flags.add_robot_flags(parser, robot_help=(
        "shipped robot (sk120, griffis-duffy, hexapod), example-robot-data name (ur5, "
        "panda...) or URDF path (required unless --model gives it)"))
    parser.add_argument("--model", metavar="FILE",
                        help="model file of `stiffness identify` or `stiffness diagnose --out`: "
                             "its robot, target, springs and joint-compliance and target-offset "
                             "effects (docs/model-file.md); the other flags override them")
    parser.add_argument("--preset", choices=PRESETS,
                        help="a scan the papers provide; table4: A&S Table IV on the SK120 "
                             "(theta1 -180..180, theta2 -70..70, theta3 -115..35 deg, step 0.2 "
                             "rad, wrist vertical; the eight +-100 N load cases; the robot's "
                             "K_theta)")
    parser.add_argument("--axis", action="append", default=[], metavar="JOINT=LO:HI[:STEP]",
                        help="swept coordinate (joint name or q1, q2...): a grid LO..HI by "
                             "STEP, or a sampling range without STEP (rad or m; --deg); "
                             "repeat for several axes")
    parser.add_argument("--samples", type=float,
                        help="random configurations (uniform in the --axis ranges, else in the "
                             "joint limits) instead of a grid")
    flags.add_seed_flag(parser, "seed of --samples; default 0")
    flags.add_configuration_flags(parser, q_help=(
        "values of the coordinates that are not swept: one per coordinate, or name=value "
        "pairs (joint names or q1, q2...); default the robot's default pose, else zero"))
    flags.add_wrench_flag(parser, repeat=True, help=(
        "dead load case at the target, base axes: fx,fy,fz (N) or fx,fy,fz,mx,my,mz (N, N.m); "
        "repeat for several; --load is an alias; default "
        f"{','.join(f'{v:g}' for v in DEFAULT_LOAD_N)}"))
    flags.add_stiffness_flag(parser)
    parser.add_argument("--rtol", type=float, default=1e-9,
                        help="relative eigenvalue tolerance of the definiteness classes")
    parser.add_argument("--map-axes", help="two swept coordinates the figures are drawn over "
                                           "(default: the two with the most values)")
    parser.add_argument("--chunk-size", type=int, default=8192,
                        help="configurations per chunk (memory and the work a killed worker "
                             "loses); default 8192")
    parser.add_argument("--format", choices=FORMATS, default="npz",
                        help="map files: npz (default), parquet (needs pyarrow) or both")
    parser.add_argument("--fields", metavar="NAME[,NAME...]",
                        help="what is stored per configuration (and computed): "
                             f"{', '.join(STORED_FIELDS)}, or all; derived fields "
                             f"({', '.join(k for k in DERIVED_FIELDS if DERIVED_FIELDS[k])}) "
                             "are rebuilt when read and select their source; default: all but "
                             "coordinates (rebuilt from the manifest)")
    parser.add_argument("--dtype", choices=DTYPES, default="float64",
                        help="storage type of the floating-point fields (computed in float64); "
                             "default float64")
    parser.add_argument("--compression", choices=COMPRESSIONS,
                        help="Parquet codec (default snappy); NPZ files are deflated with any "
                             "value but none (default: not compressed)")
    parser.add_argument("--chunks-per-task", type=int,
                        help="with Dask: consecutive chunks per task (default: chosen from the "
                             "measured per-task overhead)")
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
    flags.add_output_flags(parser, json_help="print the summary as one JSON line",
                           quiet_help="no progress bar and no echo of the inputs")


_AXIS = re.compile(r"^\s*([^=]+?)\s*=\s*([^:]+):([^:]+)(?::([^:]+))?\s*$")


def _angle_scale(robot: Robot, index: int, deg: bool) -> float:
    """Factor to SI of a coordinate given on the command line (deg -> rad if revolute)."""
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


def _refuse_unscannable(model) -> None:
    """The batched scan models joint springs only: refuse a model whose link or nonlinear
    effects would change K_X (kx and view apply them at chosen poses)."""
    extra = [e.label for e in model.applied
             if e.name in BEYOND_SPRINGS]
    if extra:
        raise StiffnessError(
            f"scan --model: {', '.join(extra)} change K_X beyond joint springs, which the "
            "batched scan does not model; use `stiffness kx --model` or `stiffness view "
            "--model` at chosen poses, or give --kq to scan the springs alone")


def build_spec(args: argparse.Namespace) -> tuple[ScanSpec, Robot]:
    """The scan specification of a command line (and the loaded robot)."""
    model = compliant_model_from_args(args)
    if model is not None:
        robot = model.robot
        _refuse_unscannable(model)
        compliant, offset = list(robot.compliant_joints), robot.target_offset.tolist()
        robot_spec = {"source": model.model.source, "frame": robot.target_frame,
                      "target_offset": offset, "compliant_joints": compliant,
                      **{k: v for k, v in model.model.robot_options().items() if v}}
    else:
        fallback = _identified_model(args)
        robot, compliant, offset = robot_from_args(args, fallback=fallback)
        robot_spec = {"source": str(args.robot) if args.robot else robot.name,
                      "frame": args.frame if fallback is None else robot.target_frame,
                      "target_offset": offset, "compliant_joints": compliant}
        # the workers load the same robot: its loop file and fixed base too (keys only when
        # given, so that the manifests of earlier scans still match for a resume)
        if getattr(args, "loops", None):
            robot_spec["loops"] = str(Path(args.loops).resolve())
        if getattr(args, "fixed_base", False):
            robot_spec["fixed_base"] = True
    if model is not None and args.kq is None:
        k_theta = model.k_theta.tolist()
    elif args.kq is not None:
        k_theta = parse_list(args.kq, "--kq")
    elif default_stiffness(robot) is not None:
        k_theta = default_stiffness(robot).tolist()
    else:
        raise stiffness_required(robot)
    batch.as_joint_stiffness(k_theta, robot.n_compliant)  # validates
    if args.chunk_size < 1:
        raise StiffnessError(f"--chunk-size must be a positive number, got {args.chunk_size}")
    if args.rtol < 0:
        raise StiffnessError(f"--rtol must be >= 0, got {args.rtol}")
    loads = [parse_list(text, "--wrench") for text in args.wrench]
    for load in loads:
        if len(load) not in (3, 6):
            raise StiffnessError(f"--wrench (alias --load) takes fx,fy,fz (N) or "
                                 f"fx,fy,fz,mx,my,mz (N, N.m); got {load}")
    if loads and len({len(x) for x in loads}) > 1:
        loads = [x + [0.0] * (6 - len(x)) for x in loads]
    names = [str(i + 1) for i in range(len(loads))]

    fields = parse_fields(args.fields)
    if args.preset is not None:
        if args.axis or args.samples is not None:
            raise StiffnessError(f"--preset {args.preset} fixes the grid: drop --axis and "
                                 "--samples")
        preset = SCAN_PRESETS[args.preset](robot)
        if not loads:
            names, loads = preset.load_names, preset.loads
        spec = ScanSpec(robot=robot_spec, preset=args.preset,
                        coordinate_joints=list(robot.coordinate_joints), base=preset.base,
                        axes=preset.axes, samples=None, seed=0, loads=loads,
                        load_names=names, k_theta=k_theta, rtol=args.rtol,
                        chunk_size=args.chunk_size, map_axes=preset.map_axes,
                        couplings=preset.couplings, fields=fields, dtype=args.dtype,
                        compression=args.compression)
        return spec, robot

    if not loads:
        loads, names = [list(DEFAULT_LOAD_N)], ["1"]
    base = flags.coordinates_from_args(robot, args, required=False)
    samples = None
    if args.samples is not None:
        if not math.isfinite(args.samples) or args.samples < 1 or args.samples != int(
                args.samples):
            raise StiffnessError(f"--samples must be a positive integer, got {args.samples:g}")
        samples = int(args.samples)
    axes = []
    for text in args.axis:
        match = _AXIS.match(text)
        if match is None:
            raise StiffnessError(
                f"--axis takes JOINT=LO:HI:STEP (grid) or JOINT=LO:HI (sampling), got {text!r}"
            )
        index = flags.coordinate_index(robot, match.group(1), "--axis")
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
                    map_axes=_map_axes(robot, axes, args.map_axes, samples), fields=fields,
                    dtype=args.dtype, compression=args.compression)
    return spec, robot


def _map_axes(robot: Robot, axes: list[dict], text: str | None, samples: int | None
              ) -> list[int]:
    """Positions in ``axes`` of the figures' axes."""
    if text is not None:
        chosen = []
        for name in (t.strip() for t in text.split(",") if t.strip()):
            index = flags.coordinate_index(robot, name, "--map-axes")
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


def default_out(spec: ScanSpec) -> Path:
    """A new folder ``<robot>-<preset>`` (``-2``, ``-3``... if taken) in the current directory."""
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", Path(spec.robot["source"]).stem) or "robot"
    base = Path.cwd() / f"{stem}-{spec.preset}"
    candidate, k = base, 1
    while candidate.exists():
        k += 1
        candidate = base.with_name(f"{base.name}-{k}")
    return candidate


def echo_lines(spec: ScanSpec, robot: Robot, args: argparse.Namespace) -> list[str]:
    """The scan's inputs: fixed coordinates (name=value), load cases and K_theta, with sources."""
    preset = f"preset {spec.preset}" if spec.preset in PRESETS else None
    q_source = preset or flags.coordinates_source(robot, args)
    load_source = f"{flags.FROM_FLAG} --wrench" if args.wrench else (preset or "default")
    k_source = f"{flags.FROM_FLAG} --kq" if args.kq is not None else flags.FROM_ROBOT
    swept = ", ".join(a["joint"] for a in spec.axes)
    loads = "; ".join(f"{name}: {','.join(f'{v:g}' for v in load)}"
                      for name, load in zip(spec.load_names, spec.loads, strict=True))
    return [
        f"q [{q_source}] (rad, m prismatic; swept: {swept}): "
        + flags.format_named(spec.coordinate_joints, spec.base),
        f"wrench [{load_source}] (N, N.m; base axes): {loads}",
        f"K_theta [{k_source}] (N.m/rad, N/m prismatic): "
        + flags.format_named(robot.compliant_joints, spec.k_theta),
    ]


def run(args: argparse.Namespace) -> int:
    """Run the scan, print the summary."""
    spec, robot = build_spec(args)
    flags.require_at_least_one(args.workers, "--workers")
    flags.require_at_least_one(args.chunks_per_task, "--chunks-per-task")
    out = Path(args.out) if args.out else default_out(spec)
    formats = ("npz", "parquet") if args.format == "both" else (args.format,)
    label = f"scan {spec.n_configurations} configurations x {len(spec.loads)} loads"
    if not (args.quiet or args.json):
        print("\n".join(echo_lines(spec, robot, args)), flush=True)
    progress = terminal_progress(label, args.quiet)
    t0 = time.perf_counter()
    summary = run_scan(spec, out, formats=formats, scheduler=args.scheduler,
                       workers=args.workers, plots=not args.no_plots, progress=progress,
                       write_on_workers=True if args.shared_out else None,
                       chunks_per_task=args.chunks_per_task)
    summary["out"] = str(out)
    summary["wall_seconds"] = time.perf_counter() - t0
    if args.json:
        json.dump(summary, sys.stdout)
        sys.stdout.write("\n")
        return 0
    print(f"{summary['robot']} {spec.preset}: {summary['configurations']} configurations "
          f"({summary['valid_configurations']} valid) x {len(spec.loads)} load cases in "
          f"{summary['wall_seconds']:.2f} s -> {out}")
    print(f"stored: {', '.join(spec.fields)} ({spec.dtype}); "
          f"{summary['bytes_per_configuration']:.1f} bytes per configuration "
          f"({summary['bytes_written'] / 1e6:.1f} MB written this run)")
    cases = summary["load_cases"]
    if cases and "k_c" in next(iter(cases.values())):
        header = f"{'case':>6} {'load (N)':>24} " + " ".join(f"{c:>6}" for c in COUNT_LABELS)
        print("definiteness of K_C per load case:")
        print(header)
        for name, case in cases.items():
            load = ",".join(f"{v:g}" for v in case["load"])
            print(f"{name:>6} {load:>24} "
                  + " ".join(f"{case['k_c'][c]:>6}" for c in COUNT_LABELS))
        tangent_pd = all(c["k_theta_minus_k_c"]["PD"] == summary["valid_configurations"]
                         for c in cases.values())
        print(f"K_theta - K_C positive definite everywhere: {tangent_pd}")
    for line in k_x_lines(summary):
        print(line)
    return 0


def k_x_lines(summary: dict) -> list[str]:
    """The console lines on K_X per load case: its principal stiffness range (N/m) and where
    it is undefined (the compliance is singular there)."""
    lines = []
    valid = summary["valid_configurations"]
    for name, case in summary["load_cases"].items():
        if "k_x_undefined" not in case:
            continue
        undefined = case["k_x_undefined"]
        low, high = (case["min_principal_stiffness_N_per_m"],
                     case["max_principal_stiffness_N_per_m"])
        count = "all" if undefined == valid else f"{undefined} of"
        where = ("" if not undefined else
                 f"undefined at {count} {valid} valid configurations (the compliance C is "
                 "singular there: a kinematic singularity, fewer compliant joints than "
                 "directions, or the buckling limit; see 'undefined' in summary.json)")
        found = "" if low is None else f"principal stiffness {low:.4g} to {high:.4g} N/m"
        lines.append(f"K_X, load case {name}: {'; '.join(t for t in (found, where) if t)}")
    return lines
