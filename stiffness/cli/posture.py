"""``stiffness posture``: the stiffest posture about the tool axis along a path.

Example::

    stiffness posture --robot ur5 --target-offset 0.1,0,0.1 --kq 3e5,3e5,2e5,4e4,4e4,4e4 \\
        --path poses.csv --wrench 0,0,300 --steps 36 --max-step 10 --out posture.csv

``POSES.csv``: ``x,y,z`` (m, base frame) and a tool axis ``ax,ay,az`` (the direction of the
target frame's free axis, base frame) or a full orientation ``qw,qx,qy,qz``; optional
``fx,fy,fz[,mx,my,mz]`` (N, N.m) per row. ``OUT.csv`` repeats the input columns and adds the
joint path (one column per coordinate joint; rad, deg with ``--deg``, m for prismatic),
``angle_deg`` (the chosen rotation about the free axis), ``deflection_m`` and
``deflection_fixed_m`` (first-order position deflection with the chosen posture and with the
fixed angle on the same branch), ``ik_residual_m``, ``ik_residual_rad`` and ``branch`` (the
assembly branch, ``A`` being the branch of ``--start``; ``--json`` gives each branch's
coordinates at the first point); the figure (``--figure``, by default
``OUT.png``) shows both deflections and the angle along the path.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from stiffness.cli.compensate import add_wrench_flags, progress_printer
from stiffness.cli.flags import (
    add_model_flags,
    add_output_flags,
    integer,
    model_from_args,
    number,
    parse_list,
)
from stiffness.errors import StiffnessError
from stiffness.machining.joint_path import angular_coordinates
from stiffness.machining.posture import posture


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Flags of ``stiffness posture``."""
    add_model_flags(parser)
    parser.add_argument("--path", metavar="POSES.csv", required=True,
                        help="target poses: x,y,z (m) and ax,ay,az (tool axis) or "
                             "qw,qx,qy,qz; optional fx,fy,fz[,mx,my,mz] per row")
    parser.add_argument("--free-axis", default="z",
                        help="the target frame's axis the process is symmetric about: x, y, z "
                             "or ax,ay,az; default z")
    add_wrench_flags(parser)
    parser.add_argument("--steps", type=integer, default=36,
                        help="candidate angles about the free axis per point; default 36")
    parser.add_argument("--max-step", type=number, default=10.0, metavar="DEG",
                        help="largest joint change between consecutive points, deg; default 10")
    parser.add_argument("--reference-angle", type=number, default=0.0, metavar="DEG",
                        help="the fixed angle compared with, deg; default 0 (the first point's "
                             "orientation, carried along the path)")
    parser.add_argument("--singularity-margin", type=number, default=1e-3,
                        help="smallest admissible singular value of the target Jacobian "
                             "(m/rad); default 1e-3")
    parser.add_argument("--start", help="IK seed of the first point, one value per coordinate "
                                        "(rad, deg with --deg, m prismatic)")
    parser.add_argument("--deg", action="store_true",
                        help="joint values written (and --start) in degrees")
    parser.add_argument("--branch", default="any", metavar="any|keep",
                        help="any: the path may change assembly branch where the step bound "
                             "allows; keep: one branch throughout; default any")
    parser.add_argument("--ignore-workspace", action="store_true",
                        help="choose among every posture within the joint limits, not first "
                             "inside the robot's declared [workspace] (where its model is "
                             "calibrated); the points outside it are still reported")
    parser.add_argument("--no-refine", action="store_true",
                        help="skip the local refinement after the dynamic programming")
    parser.add_argument("--out", metavar="OUT.csv", help="write the joint path here")
    parser.add_argument("--figure", metavar="FIG.png",
                        help="figure of the deflections along the path; default OUT.png")
    add_output_flags(parser, quiet_help="no progress on stderr")


def run(args: argparse.Namespace) -> int:
    """Run ``stiffness posture``; returns the exit code."""
    figure = args.figure or (str(Path(args.out).with_suffix(".png")) if args.out else None)
    if args.figure and Path(args.figure).suffix.lower() != ".png":
        raise StiffnessError(f"--figure {args.figure}: the figure is a PNG image; give a file "
                             "name ending in .png")
    em = model_from_args(args, args.out, figure)
    start = None
    if args.start is not None:
        full = em.full
        start = np.array(parse_list(args.start, "--start"))
        if start.shape[0] != full.n_coordinates:
            raise StiffnessError(f"--start needs {full.n_coordinates} values "
                                 f"({', '.join(full.coordinate_joints)}), got {start.shape[0]}")
        start = start / np.where(angular_coordinates(full) & args.deg, 180.0 / np.pi, 1.0)
    result = posture(em, args.path, free_axis=args.free_axis,
                     wrench=None if args.wrench is None else parse_list(args.wrench, "--wrench"),
                     wrench_frame=args.wrench_frame, steps=args.steps,
                     max_step_deg=args.max_step, reference_angle_deg=args.reference_angle,
                     singularity_margin=args.singularity_margin, start=start,
                     refine=not args.no_refine, progress=progress_printer(args, "posture"),
                     deg=args.deg, branch=args.branch,
                     ignore_workspace=args.ignore_workspace)
    result.write(args.out, figure)
    doc = result.to_dict()
    if args.json:
        print(json.dumps(doc, allow_nan=False))
        return 0
    s = doc["summary"]
    steps = ([f"{s['max_joint_step_deg']:.3g} deg (bound {args.max_step:g})"]
             if result.angular.any() else []) \
        + ([f"{s['max_joint_step_m']:.3g} m prismatic"] if not result.angular.all() else [])
    print(f"{em.robot.title}: {s['points']} points, {args.steps} angles, max joint step "
          + ", ".join(steps))
    factor = s.get("max_reduction_factor")
    print(f"max deflection: {s['max_deflection_m']:.4g} m chosen, "
          f"{_fixed(s['max_deflection_fixed_m'])}"
          + (f" (factor {factor:.4g})" if factor is not None else ""))
    print(f"RMS deflection: {s['rms_deflection_m']:.4g} m chosen, "
          f"{_fixed(s['rms_deflection_fixed_m'])}")
    print(f"IK residual: {s['max_ik_residual_m']:.2g} m, {s['max_ik_residual_rad']:.2g} rad")
    print(f"branches: {s['branches_found']} found at the first point, used "
          f"{', '.join(s['branches_used'])}")
    for note in result.notes:
        print(f"note: {note}")
    for name in (args.out, figure):
        if name:
            print(f"written: {name}")
    return 0


def _fixed(value: float | None) -> str:
    """A fixed-angle deflection (m) as printed: out of reach at every point when ``None``
    (a note says so)."""
    return "fixed angle out of reach (note below)" if value is None else \
        f"{value:.4g} m fixed angle"
