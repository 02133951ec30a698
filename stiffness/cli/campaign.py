"""``stiffness campaign import``: a campaign folder from the CSV files a rig writes.

Example::

    stiffness campaign import joints.csv forces.csv tracker.csv --robot ur5 \\
        --map q1=theta1,q2=theta2,q3=theta3,q4=theta4,q5=theta5,q6=theta6,fx=Fx,fy=Fy,fz=Fz \\
        --units angle=deg,force=N,length=mm --force-frame tool --noise 0.01 --out rig/

prints what it read (files and rows, each campaign column's source, range and unit) and writes
``rig/campaign.toml`` and ``rig/measurements.csv`` (atomically), which ``identify``,
``diagnose`` and ``design --existing`` read. Column names, deflection forms, units and frames:
:mod:`stiffness.calibration.rig_import` and docs/campaign-import.md.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np

from stiffness.calibration.campaign import CAMPAIGN_KINDS
from stiffness.calibration.campaign_toml import (
    BASELINES,
    CAMPAIGN_FILE,
    DEFAULT_DATA_FILE,
    RobotSettings,
)
from stiffness.calibration.campaign_writer import write_campaign
from stiffness.calibration.pose_campaign import write_pose_campaign
from stiffness.calibration.pose_import import ROTATION_FORMATS, import_pose_campaign
from stiffness.calibration.rig_import import (
    FRAMES,
    ImportSettings,
    import_campaign,
    load_import_robot,
    parse_pairs,
    read_mapping_file,
)
from stiffness.cli import flags
from stiffness.errors import StiffnessError
from stiffness.files import check_folder_name, output_folder


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Subcommands of ``stiffness campaign``."""
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    p = sub.add_parser("import", help="a campaign folder from a rig's CSV files",
                       description="a campaign folder from a rig's CSV files")
    p.add_argument("files", nargs="+", metavar="CSV", help="the rig's CSV files")
    flags.add_robot_flags(p)
    p.add_argument("--map", metavar="TARGET=COLUMN,...",
                   help="campaign column = file column, e.g. q1=theta1,fx=Base_Fx (FILE:COLUMN "
                        "for a name in several files); unmapped columns are read by their own "
                        "name")
    p.add_argument("--map-file", metavar="TOML",
                   help="[columns], [units], join, force_frame, deflection_frame, fixed in a "
                        "TOML file; the flags override it")
    p.add_argument("--fixed", metavar="JOINT=VALUE,...",
                   help="values of coordinates the files have no column for, in the files' "
                        "angle or length unit (as a campaign's [robot] fixed); default: the "
                        "robot's reference configuration")
    p.add_argument("--units", metavar="KIND=UNIT,...",
                   help="units of the files, e.g. angle=deg,force=N,length=mm (moment=N.mm); "
                        "default: the headers' own ('Fx [N]'); none is assumed")
    p.add_argument("--join", metavar="KEY",
                   help="join the files by this key column (default: by row order)")
    p.add_argument("--force-frame", choices=FRAMES,
                   help="frame of the forces and moments: base, or tool (the target frame at "
                        "each row's coordinates); default base")
    p.add_argument("--deflection-frame", choices=FRAMES,
                   help="frame of the deflections or positions; default base")
    p.add_argument("--noise", type=flags.number, metavar="STD",
                   help="measurement noise std, in the files' length unit (noise_std)")
    p.add_argument("--noise-rotation", type=flags.number, metavar="STD",
                   help="--kind poses with orientation columns: their noise std, in the files' "
                        "angle unit (noise_std_rotation)")
    p.add_argument("--rotation-format", choices=ROTATION_FORMATS, default="vector",
                   help="--kind poses: what the orientation columns hold, vector (rotation "
                        "vector, default) or rpy (roll, pitch, yaw about the fixed x, y, z "
                        "axes, R = Rz Ry Rx: ROS's, FIGAROH's phix,phiy,phiz) or quaternion "
                        "(columns <marker>_qx,_qy,_qz,_qw, the scalar last: a tracker's rigid "
                        "body)")
    p.add_argument("--baseline", choices=BASELINES, default="enhanced",
                   help="the model identify starts from; default enhanced")
    p.add_argument("--name", default="imported", help="campaign name; default imported")
    p.add_argument("--json", action="store_true",
                   help="print what was read as one JSON object")
    p.add_argument("--out", required=True, metavar="DIR", help="campaign folder to write")
    p.add_argument("--quiet", action="store_true",
                   help="print only the line naming what was written (no column report)")
    flags.add_strict_flag(p)
    p.add_argument("--kind", choices=CAMPAIGN_KINDS, default="deflections",
                   help="deflections (default) or poses: absolute marker positions in the "
                        "measuring system's frame (docs/absolute-poses.md)")
    p.add_argument("--marker", action="append", metavar="NAME=FRAME[@X,Y,Z[@RX,RY,RZ]]",
                   help="--kind poses: a marker, its columns NAME_x, NAME_y, NAME_z, on the "
                        "robot frame FRAME at the nominal offset X,Y,Z (the files' length "
                        "unit; default 0), its axes turned from the frame's by the rotation "
                        "vector RX,RY,RZ (the files' angle unit; a 6-D probe's mounting; "
                        "default 0); repeat for each marker")


def _settings(args: argparse.Namespace) -> ImportSettings:
    """The mapping file's settings with the flags over them."""
    base = read_mapping_file(args.map_file) if args.map_file else ImportSettings()
    fixed = {k: flags.parse_list(v, "--fixed")[0]
             for k, v in parse_pairs(args.fixed, "--fixed").items()}
    return ImportSettings({**base.column_map, **parse_pairs(args.map, "--map")},
                          {**base.units, **parse_pairs(args.units, "--units")},
                          args.join or base.join, args.force_frame or base.force_frame,
                          args.deflection_frame or base.deflection_frame,
                          {**base.fixed, **fixed})


def _run_poses(args: argparse.Namespace, robot_settings: RobotSettings, robot,
               settings: ImportSettings) -> int:
    """``--kind poses``: write a pose campaign."""
    if "tool" in (args.force_frame, args.deflection_frame):
        raise StiffnessError("--kind poses reads absolute positions in the measuring system's "
                             "frame and wrenches in world axes; drop --force-frame/"
                             "--deflection-frame tool")
    declared, turns = flags.parse_markers(args.marker)
    campaign, report = import_pose_campaign(args.files, robot_settings, settings, declared,
                                            args.name, args.noise, robot, args.noise_rotation,
                                            turns, args.rotation_format)
    flags.warn_rig_noise(args.noise, "--noise", campaign.units.length, campaign.units.length_to_si)
    path = write_pose_campaign(campaign, args.out)
    seen = np.isfinite(campaign.positions).all(axis=2).sum(axis=0)
    markers = {m.name: {"frame": m.frame, "rows_seen": int(n)}
               for m, n in zip(campaign.markers, seen, strict=True)}
    if args.json:
        print(json.dumps({"campaign": str(path), "kind": "poses", "rows": campaign.n_rows,
                          "markers": markers, "units": {"angle": campaign.units.angle,
                                                        "length": campaign.units.length},
                          "files": report.to_dict()["files"], "columns": report.columns},
                         indent=1))
    else:
        if not args.quiet:
            print("\n".join(report.lines()))
        print(f"wrote {path} ({campaign.n_rows} rows; " + ", ".join(
            f"{k} on {v['frame']} seen on {v['rows_seen']}" for k, v in markers.items())
            + f"; units {campaign.units.angle}, {campaign.units.length})")
    return 0


def _check_rig_files_kept(files: list[str], out: str) -> None:
    """Refuse an ``--out`` folder whose campaign files would replace a rig file read
    (``import rig/measurements.csv --out rig`` replaced the rig's own file, its extra columns
    and header units lost, with the converted one)."""
    for name in (CAMPAIGN_FILE, DEFAULT_DATA_FILE):
        target = Path(out) / name
        for given in files:
            if target.is_file() and Path(given).is_file() and os.path.samefile(target, given):
                raise StiffnessError(f"--out {out} would replace the rig's file {given} with "
                                     f"the campaign's {name}; give another --out folder (the "
                                     "rig's files stay as they are)")


def run(args: argparse.Namespace) -> int:
    """Run ``stiffness campaign import``; returns the exit code."""
    if args.marker and args.kind != "poses":
        raise StiffnessError("--marker is for --kind poses (absolute marker positions): add "
                             "--kind poses")
    robot_flags = flags.robot_flags(args)
    if robot_flags.source is None:
        raise StiffnessError("--robot is required: a shipped robot, an "
                                   "example-robot-data name, a URDF path or a robot.toml")
    flags.check_noise_std(args.noise, "--noise", "the files' length unit")
    flags.check_noise_std(args.noise_rotation, "--noise-rotation", "the files' angle unit")
    if args.noise_rotation is not None and args.kind != "poses":
        raise StiffnessError("--noise-rotation is for --kind poses")
    if args.rotation_format != "vector" and args.kind != "poses":
        raise StiffnessError("--rotation-format is for --kind poses")
    output_folder(args.out, create=False)
    check_folder_name(args.out)
    _check_rig_files_kept(args.files, args.out)
    settings = _settings(args)
    robot_settings = RobotSettings(
        robot_flags.source, robot_flags.frame,
        np.array(robot_flags.target_offset if robot_flags.target_offset is not None
                 else [0.0] * 3),
        None if robot_flags.compliant_joints is None else tuple(robot_flags.compliant_joints),
        robot_flags.loops, robot_flags.fixed_base)
    robot = load_import_robot(robot_settings)
    robot_settings.frame = robot.target_frame
    robot_settings.target_offset_m = robot.target_offset.copy()
    robot_settings.compliant_joints = tuple(robot.compliant_joints)
    if args.kind == "poses":
        return _run_poses(args, robot_settings, robot, settings)
    campaign, report = import_campaign(args.files, robot_settings, settings, args.name,
                                       args.baseline, args.noise, robot)
    flags.warn_rig_noise(args.noise, "--noise", campaign.units.length, campaign.units.length_to_si)
    path = write_campaign(campaign, args.out)
    if args.json:
        print(json.dumps({**report.to_dict(), "campaign": str(path)}, indent=1))
        return 0
    if not args.quiet:
        print("\n".join(report.lines()))
    print(f"wrote {path} ({campaign.n_rows} rows, {len(set(campaign.config or ()))} "
          f"configurations; units {campaign.units.angle}, {campaign.units.force}, "
          f"{campaign.units.length})")
    return 0
