"""``stiffness robot export``: the loaded robot as a URDF, or as a MuJoCo model with its springs.

Examples::

    stiffness robot export --robot sk120 --urdf sk120-export.urdf
    stiffness robot export --robot ur5 --frame tool0 --kq 8e4,8e4,5e4,2e4,2e4,2e4 \\
        --mjcf ur5.xml
    stiffness robot export --model identified-model.json --mjcf identified.xml

``--urdf`` writes the robot as loaded (any source: a URDF, an example-robot-data name, a
shipped robot, a ``robot.toml``) with the one URDF writer, and its loops beside it
(``OUT.loops.yaml``). ``--mjcf`` writes a MuJoCo model with the links' inertias and, on each
compliant joint, its spring (``stiffness``, N.m/rad or N/m, from ``--kq``, the ``--model`` file
or the robot's own) at rest at ``--q`` (``springref``; default the robot's spring rest
``rest_q_SI``, else its default configuration, else zero). docs/robot-files.md describes both.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from stiffness.cli import flags
from stiffness.elastic.model_file import read_model_file
from stiffness.elastic.springs import model_springs
from stiffness.errors import StiffnessError
from stiffness.files import atomic_write
from stiffness.mechanics.defaults import default_stiffness
from stiffness.robot.calibration import (
    is_pose_calibration,
    read_pose_calibration,
    with_marker_frames,
)
from stiffness.robot.export import loops_yaml, robot_urdf
from stiffness.robot.mjcf import check_mjcf, robot_mjcf
from stiffness.robot.robot import Robot


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Subcommands of ``stiffness robot``."""
    sub = parser.add_subparsers(dest="robot_command", metavar="SUBCOMMAND", required=True)
    export = sub.add_parser("export", help="write the robot as a URDF or a MuJoCo model",
                            description=__doc__.split("\n\n")[0])
    flags.add_robot_flags(export, robot_help=(
        "shipped robot (sk120, griffis-duffy, hexapod), example-robot-data name (ur5, "
        "panda...), URDF path or robot.toml (required unless --model gives it)"))
    export.add_argument("--urdf", metavar="OUT.urdf",
                        help="write the robot as a URDF (and its loops as OUT.loops.yaml)")
    export.add_argument("--mjcf", metavar="OUT.xml",
                        help="write a MuJoCo model (MJCF) with the joint springs")
    export.add_argument("--model", metavar="FILE",
                        help="model file of `stiffness identify` or `stiffness diagnose --out`: "
                             "its robot and joint springs (docs/model-file.md)")
    flags.add_stiffness_flag(export)
    flags.add_configuration_flags(export, q_help=(
        "the springs' rest coordinates (springref), rad (m prismatic): values in coordinate "
        "order or name=value pairs; default the robot's rest_q_SI, else its default "
        "configuration, else zero"))
    export.add_argument("--quiet", action="store_true", help="print nothing on success")


def _springs(robot: Robot, args: argparse.Namespace, model) -> dict[str, float]:
    """The springs of ``--kq``, else the model file's, else the robot's own (N.m/rad, N/m)."""
    if args.kq is not None:
        return dict(zip(robot.compliant_joints, flags.parse_kq(args.kq, robot), strict=True))
    if model is not None:
        springs, left_out = model_springs(model)
        if left_out:
            print(f"stiffness robot export: note: not joint springs, left out of the MJCF: "
                  f"{', '.join(left_out)}", file=sys.stderr)
        return springs
    shipped = default_stiffness(robot)
    if shipped is None:
        raise flags.stiffness_required(robot)
    return dict(zip(robot.compliant_joints, (float(k) for k in shipped), strict=True))


def _rest_configuration(robot: Robot, args: argparse.Namespace) -> np.ndarray:
    """Full configuration at the springs' rest: ``--q``, else ``rest_q_SI``, else default."""
    if args.q is None and "rest_q_SI" in robot.defaults:
        coords = np.asarray(robot.defaults["rest_q_SI"], dtype=float)
    else:
        coords = flags.coordinates_from_args(robot, args, required=False)
    return robot.configuration(coords)


def run(args: argparse.Namespace) -> int:
    """Run ``stiffness robot export``."""
    if args.urdf is None and args.mjcf is None:
        raise StiffnessError("robot export needs --urdf OUT.urdf or --mjcf OUT.xml (or both)")
    model = read_model_file(args.model) if args.model is not None else None
    if model is not None and args.robot is not None:
        model.check_robot(args.robot)
    robot, _, _ = flags.robot_from_args(args, model)
    unused = [flag for flag, value in (("--kq", args.kq), ("--q", args.q)) if value is not None]
    if args.mjcf is None and unused:
        named = " and ".join(unused)
        raise StiffnessError(f"{named} {'are' if len(unused) > 1 else 'is'} for --mjcf (the "
                             "joint springs and their rest), and --urdf writes no springs (a "
                             f"URDF has none): add --mjcf OUT.xml, or drop {named}")
    loops_out = None if args.urdf is None else str(Path(args.urdf).with_suffix(".loops.yaml"))
    flags.check_outputs(args.mjcf, args.urdf, loops_out,
                        inputs={"--robot": args.robot, "--model": args.model,
                                "loop": robot.loop_file})
    written = []
    if args.mjcf is not None:
        springs = _springs(robot, args, model)
        text = robot_mjcf(robot, springs, _rest_configuration(robot, args))
        check_mjcf(text, robot.name)
        written.append(atomic_write(args.mjcf, text))
    if args.urdf is not None:
        written.append(atomic_write(args.urdf, robot_urdf(_with_markers(robot, args))))
        loops = loops_yaml(robot)
        if loops is not None:
            written.append(atomic_write(Path(args.urdf).with_suffix(".loops.yaml"), loops))
    if not args.quiet:
        for path in written:
            print(f"wrote {path}")
    return 0


def _with_markers(robot: Robot, args: argparse.Namespace) -> Robot:
    """A pose calibration's robot (``--model``) with its marker frames and the measuring
    frame (:func:`~stiffness.robot.calibration.with_marker_frames`); other robots as they are."""
    if args.model is None or not is_pose_calibration(args.model):
        return robot
    if not args.quiet:
        print("calibrated geometry; frames marker_<name> and measuring_frame")
    return with_marker_frames(robot, read_pose_calibration(args.model))
