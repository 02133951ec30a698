"""``stiffness compensate``: joint commands that cancel the deflection along a path.

Example::

    stiffness compensate --model identified-model.json --path path.csv \\
        --wrench 0,0,-300 --deg --out compensated.csv

``PATH.csv`` has one column per coordinate (joint names, or q1..qn in the model's coordinate
order; rad, or deg with ``--deg``; m for prismatic joints), one row per point, and optionally
``fx,fy,fz[,mx,my,mz]`` (N, N.m) per row instead of ``--wrench``. ``OUT.csv`` repeats the input
columns and adds ``<joint>_cmd`` (the exact command, input unit; also ``q<i>_cmd`` for a path
whose columns are q1..qn), ``dx,dy,dz`` (uncompensated
deflection, m), ``ex,ey,ez`` (residual after the exact compensation, m) and ``ex1,ey1,ez1``
(after the first-order Cartesian compensation, m). Nothing is written when any row fails.
"""

from __future__ import annotations

import argparse
import json
import sys

from stiffness.cli.flags import (
    add_model_flags,
    add_output_flags,
    add_wrench_flag,
    model_from_args,
    parse_list,
)
from stiffness.machining.compensation import WRENCH_FRAMES, compensate


def add_wrench_flags(parser: argparse.ArgumentParser) -> None:
    """``--wrench`` (alias ``--load``) and ``--wrench-frame``."""
    add_wrench_flag(parser, help="process wrench at the target: fx,fy,fz (N) or "
                                 "fx,fy,fz,mx,my,mz (N, N.m); --load is an alias")
    parser.add_argument("--wrench-frame", choices=WRENCH_FRAMES, default="base",
                        help="axes of --wrench (and of per-row loads): base, or target (the "
                             "target frame at each nominal pose); default base")


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Flags of ``stiffness compensate``."""
    add_model_flags(parser)
    parser.add_argument("--path", metavar="PATH.csv", required=True,
                        help="joint path: one column per coordinate (joint names or q1..qn), "
                             "one row per point; optional fx,fy,fz[,mx,my,mz] per row")
    add_wrench_flags(parser)
    parser.add_argument("--deg", action="store_true",
                        help="angles of PATH.csv (and of the commands written) are in degrees")
    parser.add_argument("--hold", choices=("auto", "pose", "position"), default="auto",
                        help="what the compensation holds: the target position and orientation "
                             "(pose), its position only, or auto (pose when the robot can); "
                             "default auto")
    parser.add_argument("--method", choices=("auto", "closed-form", "general"), default="auto",
                        help="auto: closed form when joint compliance is the only effect, else "
                             "the general solver; default auto")
    parser.add_argument("--out", metavar="OUT.csv", help="write the compensated path here")
    add_output_flags(parser, quiet_help="no progress on stderr")


def progress_printer(args: argparse.Namespace, what: str):
    """A ``(done, total)`` progress callback on stderr when a TTY, else None (``--quiet``)."""
    if args.quiet or not sys.stderr.isatty():
        return None

    def show(done: int, total: int) -> None:
        end = "\n" if done == total else ""
        print(f"\r{what}: {done}/{total}", end=end, file=sys.stderr, flush=True)

    return show


def run(args: argparse.Namespace) -> int:
    """Run ``stiffness compensate``; returns the exit code."""
    em = model_from_args(args, args.out)
    result = compensate(em, args.path,
                        None if args.wrench is None else parse_list(args.wrench, "--wrench"),
                        wrench_frame=args.wrench_frame, hold=args.hold, method=args.method,
                        progress=progress_printer(args, "compensate"), deg=args.deg)
    if args.out:
        result.write(args.out)
    doc = result.to_dict()
    if args.json:
        print(json.dumps(doc, allow_nan=False))
        return 0
    s = doc["summary"]
    print(f"{em.robot.title}: {s['points']} points, {s['model']}; holds the {s['hold']}, "
          f"{'/'.join(s['method'])}")
    if s["ignored_effects"]:
        print(f"not compensated (measurement effects): {', '.join(s['ignored_effects'])}")
    print(f"deflection without compensation: max {s['max_deflection_m']:.4g} m, "
          f"RMS {s['rms_deflection_m']:.4g} m")
    print(f"residual, exact compensation:    max {s['max_residual_m']:.3g} m")
    print(f"residual, first-order (-C.F):    max {s['max_residual_first_order_m']:.3g} m")
    if args.out:
        print(f"written: {args.out}")
    return 0
