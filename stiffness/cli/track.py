"""``stiffness track``: a path tracked in MuJoCo, raw and with the compensator's commands.

Example::

    stiffness track --model identified-model.json --path path.csv --deg \\
        --wrench 0,0,-300 --json --plot tracking.png

The robot is exported with its springs and masses (as ``stiffness robot export --mjcf``),
driven along ``PATH.csv`` (the path format of ``stiffness compensate``) by a stiff position
loop (each tick the springs' rest is the command) under the process wrench, once commanding
the path and once the compensator's command each tick; the target's error from where the
unloaded program puts it is reported both ways (max and RMS, m).
"""

from __future__ import annotations

import argparse
import json

from stiffness.cli.flags import (
    add_model_flags,
    add_output_flags,
    add_wrench_flag,
    model_from_args,
    number,
    parse_list,
)
from stiffness.machining.tracking import TIMESTEP, track


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Flags of ``stiffness track``."""
    add_model_flags(parser)
    parser.add_argument("--path", metavar="PATH.csv", required=True,
                        help="joint path: one column per coordinate (joint names or q1..qn), "
                             "one row per point; optional fx,fy,fz[,mx,my,mz] per row")
    add_wrench_flag(parser, help="process wrench at the target, base axes: fx,fy,fz (N) or "
                                 "fx,fy,fz,mx,my,mz (N, N.m); --load is an alias")
    parser.add_argument("--deg", action="store_true", help="angles of PATH.csv in degrees")
    parser.add_argument("--segment-time", type=number, default=1.0, metavar="S",
                        help="time from one path point to the next, s (default 1)")
    parser.add_argument("--settle-time", type=number, default=0.5, metavar="S",
                        help="time at the first point before the path, s (default 0.5)")
    parser.add_argument("--timestep", type=number, default=TIMESTEP, metavar="S",
                        help=f"MuJoCo's step and the controller's tick, s (default {TIMESTEP})")
    parser.add_argument("--plot", metavar="PNG", help="draw both errors along the path here")
    add_output_flags(parser)


def run(args: argparse.Namespace) -> int:
    """Run ``stiffness track``; returns the exit code."""
    em = model_from_args(args, args.plot)
    result = track(em, args.path,
                   None if args.wrench is None else parse_list(args.wrench, "--wrench"),
                   deg=args.deg, segment_time=args.segment_time, settle_time=args.settle_time,
                   timestep=args.timestep)
    doc = result.to_dict()
    if args.plot:
        result.plot(args.plot)
    if args.json:
        print(json.dumps(doc, allow_nan=False))
        return 0
    raw, comp = doc["raw"], doc["compensated"]
    print(f"{doc['robot']} in MuJoCo: {doc['points']} points, {doc['ticks']} ticks of "
          f"{doc['timestep_s']:g} s, segments of {doc['segment_time_s']:g} s, weight "
          f"{'on' if doc['gravity'] else 'off'}")
    print(f"raw path:    max {raw['max_error_m']:.3g} m, RMS {raw['rms_error_m']:.3g} m")
    print(f"compensated: max {comp['max_error_m']:.3g} m, RMS {comp['rms_error_m']:.3g} m "
          f"(max {doc['max_reduction_factor']:.3g}x smaller)")
    if args.plot:
        print(f"written: {args.plot}")
    return 0
