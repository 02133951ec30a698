"""``stiffness scan``: stiffness and definiteness maps over a workspace.

Examples::

    stiffness scan --preset table4           # A&S Table IV on the SK120: 5824 x 8 loads
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
import re
import sys
import warnings
from pathlib import Path

import numpy as np

from stiffness.cli import flags
from stiffness.cli.flags import (
    parse_kq,
    parse_list,
    robot_flags,
    robot_from_args,
    stiffness_required,
)
from stiffness.cli.kx import elastic_model_from_args, model_file_from_args
from stiffness.errors import StiffnessError
from stiffness.mechanics.defaults import default_stiffness
from stiffness.papers.presets import PRESET_ROBOTS, SCAN_PRESETS
from stiffness.robot.robot import Robot, coordinate_index
from stiffness.workspace.definiteness import terminal_progress
from stiffness.workspace.request import DEFAULT_LOAD_N, scan, scan_spec
from stiffness.workspace.spec import (
    COMPRESSIONS,
    COUNT_LABELS,
    DERIVED_FIELDS,
    DTYPES,
    STORED_FIELDS,
    ScanSpec,
)

PRESETS = tuple(SCAN_PRESETS)
FORMATS = ("npz", "parquet", "both")


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Flags of ``stiffness scan``."""
    flags.add_robot_flags(parser, robot_help=(
        "shipped robot (sk120, griffis-duffy, hexapod), example-robot-data name (ur5, "
        "panda...), URDF path or robot.toml (required unless --model gives it)"))
    parser.add_argument("--model", metavar="FILE",
                        help="model file of `stiffness identify` or `stiffness diagnose --out`: "
                             "its robot, target, springs and joint-compliance and target-offset "
                             "effects (docs/model-file.md); the other flags override them")
    parser.add_argument("--preset", choices=PRESETS,
                        help="a scan the papers provide; table4: A&S Table IV on the SK120 "
                             "(theta1 -180..180, theta2 -70..70, theta3 -115..35 deg, step 0.2 "
                             "rad, wrist vertical; the eight +-100 N load cases; the robot's "
                             "K_theta; implies --robot sk120)")
    parser.add_argument("--axis", action="append", default=[], metavar="JOINT=LO:HI[:STEP]",
                        help="swept coordinate (joint name or q1, q2...): a grid LO..HI by "
                             "STEP, or a sampling range without STEP (rad or m; --deg); "
                             "repeat for several axes")
    parser.add_argument("--samples", type=flags.number,
                        help="random configurations (uniform in the --axis ranges, else in the "
                             "joint limits; a closed loop's within 0.5 rad of its reference "
                             "assembly, as design draws) instead of a grid")
    flags.add_seed_flag(parser, "seed of --samples; default 0")
    flags.add_configuration_flags(parser, q_help=(
        "values of the coordinates that are not swept: one per coordinate, or name=value "
        "pairs (joint names or q1, q2...); default the robot's default pose, else zero"))
    flags.add_wrench_flag(parser, repeat=True, help=(
        "dead load case at the target, base axes: fx,fy,fz (N) or fx,fy,fz,mx,my,mz (N, N.m); "
        "repeat for several; --load is an alias; default the robot's wrench_SI (as kx and "
        f"view), else {','.join(f'{v:g}' for v in DEFAULT_LOAD_N)}"))
    flags.add_stiffness_flag(parser)
    parser.add_argument("--rtol", type=flags.number, default=1e-9,
                        help="relative eigenvalue tolerance of the definiteness classes")
    parser.add_argument("--map-axes", help="two swept coordinates the figures are drawn over "
                                           "(default: the two with the most values)")
    parser.add_argument("--chunk-size", type=flags.integer, default=8192,
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
    parser.add_argument("--chunks-per-task", type=flags.integer,
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
    parser.add_argument("--workers", type=flags.integer,
                        help="without --scheduler: a Dask LocalCluster of N worker processes "
                             "on this machine (default: this process only)")
    parser.add_argument("--no-plots", action="store_true", help="write no figures")
    flags.add_output_flags(parser, json_help="print the summary as one JSON line",
                           quiet_help="no progress bar and no echo of the inputs")


_AXIS = re.compile(r"^\s*([^=]+?)\s*=\s*([^:]+):([^:]+)(?::([^:]+))?\s*$")


def _angle_scale(robot: Robot, index: int, deg: bool) -> float:
    """Factor to SI of a coordinate given on the command line (deg -> rad if revolute)."""
    prismatic = robot.is_prismatic(robot.coordinate_joints[index])
    return np.pi / 180.0 if deg and not prismatic else 1.0


def _refuse_unscannable(model) -> None:
    """The batched scan models joint springs only: refuse a model whose link or nonlinear
    effects would change K_X (kx and view apply them at chosen poses)."""
    extra = list(model.beyond_springs)
    if extra:
        raise StiffnessError(
            f"scan --model: {', '.join(extra)} change{'s' * (len(extra) == 1)} K_X beyond "
            "joint springs, which the "
            "batched scan does not model; use `stiffness kx --model` or `stiffness view "
            "--model` at chosen poses, or give --kq to scan the springs alone")


def _robot(args: argparse.Namespace) -> tuple[Robot, dict, list[float] | None]:
    """The robot of ``--model`` (with its stiffness effects) or of the robot flags, the
    arguments the chunks load it with, and its springs (N.m/rad, N/m; None: the robot's)."""
    model = elastic_model_from_args(args)
    declared = model_file_from_args(args)
    if model is not None and declared is not None:
        robot = model.robot
        _refuse_unscannable(model)
        robot_spec = {"source": declared.source, "frame": robot.target_frame,
                      "target_offset": robot.target_offset.tolist(),
                      "compliant_joints": list(robot.compliant_joints),
                      **{k: v for k, v in declared.robot_options().items() if v}}
        return robot, robot_spec, (model.k_theta.tolist() if args.kq is None
                                   else parse_kq(args.kq, robot))
    fallback = declared
    robot, compliant, offset = robot_from_args(args, fallback=fallback)
    robot_spec = {"source": str(args.robot) if args.robot else robot.name,
                  "frame": args.frame if fallback is None else robot.target_frame,
                  "target_offset": offset, "compliant_joints": compliant}
    # the workers load the same robot: its loop file and fixed base too (keys only when
    # given, so that the manifests of earlier scans still match for a resume)
    given = robot_flags(args, fallback)
    if given.loops:
        robot_spec["loops"] = str(Path(given.loops).resolve())
    if given.fixed_base:
        robot_spec["fixed_base"] = True
    if args.kq is None and default_stiffness(robot) is None:
        raise stiffness_required(robot)
    return robot, robot_spec, None if args.kq is None else parse_kq(args.kq, robot)


def _axes(robot: Robot, args: argparse.Namespace) -> list[tuple[str, tuple]]:
    """``--axis JOINT=LO:HI[:STEP]`` as ``(joint, (lo, hi[, step]))`` in SI (``--deg``)."""
    axes = []
    for text in args.axis:
        match = _AXIS.match(text)
        if match is None:
            raise StiffnessError(
                f"--axis takes JOINT=LO:HI:STEP (grid) or JOINT=LO:HI (sampling), got {text!r}"
            )
        scale = _angle_scale(robot, coordinate_index(robot, match.group(1), "--axis"),
                             args.deg)
        bounds = [parse_list(match.group(k), "--axis")[0] * scale for k in (2, 3)]
        if match.group(4) is not None:
            bounds.append(parse_list(match.group(4), "--axis")[0] * scale)
        _warn_beyond_limits(robot, match.group(1), bounds[:2], args.deg)
        axes.append((match.group(1), tuple(bounds)))
    return axes


def _warn_beyond_limits(robot: Robot, name: str, bounds: list[float], deg: bool) -> None:
    """Warn when an ``--axis`` range (rad, m) leaves its joint's limits, as ``--q`` does
    (``--axis elbow_joint=0:90:30`` without ``--deg`` swept 90 rad, silently)."""
    from stiffness.mechanics.ik import coordinate_limits

    index = coordinate_index(robot, name, "--axis")
    lo, hi = (float(v[index]) for v in coordinate_limits(robot))
    if lo - 1e-9 <= min(bounds) and max(bounds) <= hi + 1e-9:
        return
    joint = robot.coordinate_joints[index]
    hint = ("" if deg or robot.is_prismatic(joint) or not
            lo <= np.deg2rad(min(bounds)) <= np.deg2rad(max(bounds)) <= hi else
            " (the values look like degrees: add --deg)")
    warnings.warn(f"{robot.title}: --axis {name} runs {bounds[0]:.6g}..{bounds[1]:.6g}, beyond "
                  f"{joint}'s limits [{lo:.6g}, {hi:.6g}] (rad, m){hint}", stacklevel=2)


def scan_arguments(args: argparse.Namespace) -> tuple[Robot, dict]:
    """The robot of a command line and the keyword arguments of
    :func:`stiffness.workspace.request.scan_spec` (and of :func:`~stiffness.workspace.
    request.scan`) its flags give."""
    if args.preset is not None and args.robot is None and args.model is None:
        args.robot = PRESET_ROBOTS[args.preset]  # a preset is made for one robot
    robot, robot_spec, k_theta = _robot(args)
    preset = SCAN_PRESETS[args.preset](robot) if args.preset is not None else None
    return robot, {
        "robot_spec": robot_spec, "k_theta": k_theta, "preset": preset,
        "axes": _axes(robot, args), "samples": args.samples, "seed": args.seed,
        "q": None if preset is not None else flags.coordinates_from_args(robot, args,
                                                                          required=False),
        "wrench": [parse_list(text, "--wrench") for text in args.wrench],
        "rtol": args.rtol, "chunk_size": args.chunk_size, "fields": args.fields,
        "map_axes": None if args.map_axes is None else [
            t.strip() for t in args.map_axes.split(",") if t.strip()],
        "dtype": args.dtype, "compression": args.compression}


def build_spec(args: argparse.Namespace) -> tuple[ScanSpec, Robot]:
    """The scan specification of a command line (and the loaded robot)."""
    robot, arguments = scan_arguments(args)
    return scan_spec(robot, **arguments), robot


def echo_lines(spec: ScanSpec, robot: Robot, args: argparse.Namespace) -> list[str]:
    """The scan's inputs: fixed coordinates (name=value), load cases and K_theta, with sources."""
    preset = f"preset {spec.preset}" if spec.preset in PRESETS else None
    q_source = preset or flags.coordinates_source(robot, args)
    load_source = f"{flags.FROM_FLAG} --wrench" if args.wrench else (
        preset or (f"{flags.FROM_ROBOT} wrench_SI" if "wrench_SI" in robot.defaults else "default"))
    k_source = f"{flags.FROM_FLAG} --kq" if args.kq is not None else (
        flags.FROM_ROBOT if args.model is None else f"{flags.FROM_MODEL} {args.model}")
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
    robot, arguments = scan_arguments(args)
    flags.require_at_least_one(args.workers, "--workers")
    flags.require_at_least_one(args.chunks_per_task, "--chunks-per-task")
    formats = ("npz", "parquet") if args.format == "both" else (args.format,)
    bar: list = [None]  # the progress bar, labelled once the spec is known

    def echo(spec: ScanSpec) -> None:
        if not (args.quiet or args.json):
            print("\n".join(echo_lines(spec, robot, args)), flush=True)
        label = f"scan {spec.n_configurations} configurations x {len(spec.loads)} loads"
        bar[0] = terminal_progress(label, args.quiet)

    live = not args.quiet and sys.stderr.isatty()
    result = scan(robot, args.out, formats=formats, scheduler=args.scheduler,
                  workers=args.workers, plots=not args.no_plots,
                  progress=(lambda done, total: bar[0](done, total)) if live else None,
                  write_on_workers=True if args.shared_out else None,
                  chunks_per_task=args.chunks_per_task, on_spec=echo, **arguments)
    summary, spec, out = result.to_dict(), result.spec, result.out
    if args.json:
        json.dump(summary, sys.stdout)
        sys.stdout.write("\n")
        return 0
    print(f"{robot.title} {spec.preset}: {summary['configurations']} configurations "
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
        print(f"K_theta - K_C positive definite everywhere: {tangent_pd}"
              if summary["valid_configurations"] else "no valid configuration (none "
              "assembled, or all out of the limits): nothing to judge; give --q a pose of "
              "the robot, or sweep --axis where it reaches")
    for line in k_x_lines(summary):
        print(line)
    return 0


def k_x_lines(summary: dict) -> list[str]:
    """The console lines on K_X per load case: its principal stiffness ranges (N/m; N.m/rad
    for the rotational block of a 6-D K_X) over the configurations neither near-singular nor
    unstable, how many were left out and why, and where K_X is undefined."""
    lines = []
    valid = summary["valid_configurations"]
    near = summary.get("near_singular", 0)
    cases = summary["load_cases"].values()
    if valid and near == valid and all(c.get("k_x_undefined") == valid for c in cases):
        return [f"K_X: undefined at all {valid} valid configurations: the target moves in "
                "fewer than 3 directions at every one (a planar robot, or fewer than 3 "
                "compliant joints), so its 3x3 compliance is singular everywhere; `stiffness "
                "kx --q ...` gives the stiffness on the subspace it spans at one pose"] + [
            f"K_X, load case {name}: unstable (K_theta - K_C not positive definite) at "
            f"{case['unstable']} of {valid}" for name, case in summary["load_cases"].items()
            if case.get("unstable")]
    if any("k_x_undefined" in case for case in cases) and near:
        lines.append(f"left out of the K_X ranges: {near} of {valid} valid configurations "
                     f"near a singularity (sigma_min/sigma_max of the translational Jacobian "
                     f"below {summary['singularity_margin']:g}, where the largest principal "
                     "stiffness grows without bound)")
    for name, case in summary["load_cases"].items():
        if "k_x_undefined" not in case or not valid:  # none valid: said above
            continue
        undefined = case["k_x_undefined"]
        count = "all" if undefined == valid else f"{undefined} of"
        where = ("" if not undefined else
                 f"undefined at {count} {valid} valid configurations (the compliance C is "
                 "singular there: a kinematic singularity, fewer compliant joints than "
                 "directions, or the buckling limit; see 'undefined' in summary.json)")
        unstable = ("" if not case.get("unstable") else
                    f"unstable (K_theta - K_C not positive definite) at {case['unstable']} of "
                    f"{valid}, left out")
        lines.append(f"K_X, load case {name}: "
                     + "; ".join(t for t in (_ranges(case, valid), unstable, where) if t))
    return lines


def _ranges(case: dict, valid: int) -> str:
    """A load case's principal stiffness ranges, or why there is none (nothing when K_X is
    undefined everywhere: the caller says so)."""
    low, high = (case["min_principal_stiffness_N_per_m"],
                 case["max_principal_stiffness_N_per_m"])
    if low is None:
        return "" if case["k_x_undefined"] == valid else (
            "no principal stiffness (every configuration where K_X exists is near a "
            "singularity or unstable)")
    text = f"principal stiffness {low:.4g} to {high:.4g} N/m"
    if "min_rotational_stiffness_Nm_per_rad" in case:
        text = (f"translational principal stiffness {low:.4g} to {high:.4g} N/m, rotational "
                f"{case['min_rotational_stiffness_Nm_per_rad']:.4g} to "
                f"{case['max_rotational_stiffness_Nm_per_rad']:.4g} N.m/rad")
    return text
