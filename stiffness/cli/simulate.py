"""``stiffness simulate``: a synthetic campaign with chosen effects hidden in it.

Example::

    stiffness simulate --robot ur5 --compliant-joints shoulder_pan_joint,shoulder_lift_joint,\\
        elbow_joint --kq 3e4,2e4,1.5e4 --effect backlash:shoulder_lift_joint=0.005 \\
        --configs 12 --loads-per-config 4 --max-force 100 --noise 0.005 --out sim/

writes ``sim/campaign.toml``, ``sim/measurements.csv`` (deflections of the exact elastostatic
equilibrium of the true robot, plus Gaussian noise) and ``sim/truth.json`` (the hidden effects,
their size in noise units, the settings). Run ``stiffness diagnose sim`` to see whether the rig
would detect them. Effect values: see :mod:`stiffness.planning.simulate` (stiffness N.m/rad,
angles in
deg, lengths in ``--units``, forces in N, beta in 1/(N.m)).

``--kind poses`` writes a pose campaign instead (docs/absolute-poses.md): ``--poses`` reachable
poses, the ``--marker`` positions a tracker sees in its own frame, with the pose effects
hidden (:mod:`stiffness.planning.pose_simulation`), e.g.::

    stiffness simulate --kind poses --robot ur10 --frame tool0 --poses 20 \\
        --marker tip=tool0@0,30,50 --effect joint_compliance:shoulder_lift_joint=2e4 \\
        --load 0,0,-100 --noise 0.02 --out sim-poses/
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import pinocchio as pin

from stiffness.calibration.campaign import CAMPAIGN_KINDS
from stiffness.calibration.campaign_toml import BASELINES
from stiffness.calibration.pose_model import Marker
from stiffness.cli import flags
from stiffness.elastic.effects import LIBRARY
from stiffness.errors import StiffnessError
from stiffness.planning.design import DEFAULT_NOISE_STD_M
from stiffness.planning.pose_simulation import DEFAULT_POSES, POSE_EFFECTS, simulate_poses
from stiffness.planning.simulate import TRUTH_FILE, simulate
from stiffness.planning.simulate_request import LOAD_PATTERNS
from stiffness.units import LENGTH_UNITS, Units

#: The flags of one campaign kind only (argparse destinations), refused with the other; their
#: defaults are applied after the check (the deflection flags' in :data:`_DEFLECTION_DEFAULTS`).
_DEFLECTION_ONLY = ("plan", "configs", "loads_per_config", "repeats", "max_force",
                    "load_pattern", "baseline", "joint_angles", "target_offset", "loops")
_POSE_ONLY = ("poses", "marker", "wrench", "drift")
_DEFLECTION_DEFAULTS = {"configs": 10, "loads_per_config": 4, "repeats": 1, "max_force": 100.0,
                        "load_pattern": "random", "joint_angles": "motor"}
#: A hidden effect's RMS beyond a rigid move of the measuring frame is printed when below this
#: share of its whole RMS: the frame every pose fit finds then takes out most of it (a base
#: joint's zero offset about a vertical axis: all of it).
FRAME_HIDDEN_SHARE = 0.5


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Flags of ``stiffness simulate``."""
    flags.add_robot_flags(parser, robot_help="shipped robot (sk120), example-robot-data name, "
                                             "URDF path or robot.toml (required unless --plan "
                                             "is a folder naming it)")
    parser.add_argument("--kind", choices=CAMPAIGN_KINDS, default="deflections",
                        help="deflections (default) or poses: the absolute positions of "
                             "--marker points a tracker sees in its own frame, at --poses "
                             "reachable poses under the arm's weight and --load "
                             "(docs/absolute-poses.md); the flags of the other kind are refused")
    parser.add_argument("--plan", metavar="PLAN",
                        help="simulate exactly these rows: a PLAN.csv written by `stiffness "
                             "design`, or its folder (whose campaign.toml gives the robot "
                             "flags' defaults); --configs, --loads-per-config, --max-force and "
                             "--load-pattern are then not used (deflections: design plans no "
                             "pose campaign)")
    flags.add_stiffness_flag(parser, help="true stiffness per declared compliant joint, "
                                          "N.m/rad (N/m prismatic); default the shipped robot's "
                                          "(poses: none, a rigid arm unless --effect "
                                          "joint_compliance gives a joint its spring)")
    parser.add_argument("--effect", action="append", default=[], metavar="NAME[:WHERE]=VALUE",
                        help="hidden effect, repeatable; deflections: " + ", ".join(LIBRARY)
                             + "; a "
                             "place NAME:WHERE or NAME(WHERE), e.g. "
                             "backlash:joint2=0.003 (deg; --units on a prismatic joint), "
                             "joint_compliance:joint5=3e5 "
                             "(N.m/rad), 'link_compliance:joint2->elbow=2e6' (N.m/rad), "
                             "nonlinear_joint_stiffness:joint3=0.001 (1/(N.m); 1/N "
                             "prismatic), "
                             "frame_misalignment=2 (deg), target_offset=20 (--units), "
                             "force_sensor_bias=5 (N), complementary_stiffness, "
                             "gravity_preload=20[,cx,cy,cz] (kg, --units), "
                             "gravity_compensator:joint2=2e5,500[,lever,base] (N/m, N, "
                             "then m); poses: " + ", ".join(POSE_EFFECTS) + ", e.g. "
                             "frame=RX,RY,RZ[,TX,TY,TZ] (deg, --units), "
                             "markers[:NAME]=DX,DY,DZ (--units), joint_offsets[:J]=V (deg), "
                             "geometry:J=DX,DY,DZ[,RX,RY,RZ] (--units, deg), "
                             "base_tilt=RX,RY (deg), joint_compliance:J=K (N.m/rad), "
                             "backlash:J=B (deg), gravity_compensator:J=K,F0 (N/m, N); the "
                             "others as for deflections")
    parser.add_argument("--configs", type=flags.integer,
                        help="configurations; default 10")
    parser.add_argument("--loads-per-config", type=flags.integer,
                        help="loads per configuration; default 4")
    parser.add_argument("--repeats", type=flags.integer,
                        help="measurements per load (replicates); default 1")
    parser.add_argument("--max-force", type=flags.number,
                        help="largest force, N; default 100")
    parser.add_argument("--poses", type=flags.integer,
                        help=f"--kind poses: reachable poses drawn; default {DEFAULT_POSES}")
    parser.add_argument("--marker", action="append", metavar="NAME=FRAME[@X,Y,Z[@RX,RY,RZ]]",
                        help="--kind poses: a marker the tracker sees, on the robot frame FRAME "
                             "at the declared offset X,Y,Z (--units; default 0), its axes "
                             "turned from the frame's by the rotation vector RX,RY,RZ (deg; a "
                             "6-D probe's mounting); repeat for each marker; default one, tip, "
                             "on the target frame (--frame)")
    flags.add_wrench_flag(parser, help="--kind poses: a payload at the target frame on every "
                                       "pose, world axes: fx,fy,fz (N) or fx,fy,fz,mx,my,mz "
                                       "(N, N.m); default none (the arm's weight only); --load "
                                       "is an alias")
    parser.add_argument("--drift", metavar="X,Y,Z",
                        help="--kind poses: the measuring frame's origin drifts linearly by "
                             "this over the campaign (--units); default 0")
    parser.add_argument("--load-pattern", choices=LOAD_PATTERNS,
                        help="random directions and magnitudes, a ramp along one direction per "
                             "configuration, or the six axis directions; default random")
    parser.add_argument("--noise", type=flags.number, metavar="STD",
                        help="measurement noise std per deflection (poses: marker position) "
                             "component, in the files' length unit (--units, default mm); "
                             "default 0.005 mm")
    parser.add_argument("--rotations", action="store_true",
                        help="also write the measured rotations rx, ry, rz of the target frame "
                             "(poses: the markers' orientations)")
    parser.add_argument("--rotation-noise", type=flags.number, default=None,
                        help="rotation noise std of --rotations, deg; default --noise / 100 mm "
                             "(rad)")
    parser.add_argument("--undeclared-noise", action="store_true",
                        help="do not write noise_std into the campaign")
    parser.add_argument("--baseline", choices=BASELINES,
                        help="declared baseline; default conventional when "
                             "complementary_stiffness is hidden, else enhanced")
    parser.add_argument("--joint-angles", metavar="motor|link",
                        help="what the campaign records as joint angles: the commanded pose "
                             "(motor, which a hidden weight or compensator sags) or the "
                             "unloaded link pose (link); default motor")
    parser.add_argument("--units", choices=tuple(LENGTH_UNITS), default="mm",
                        help="length unit of the files, of --noise and of the lengths of "
                             "--effect (and --marker, --drift); default mm")
    flags.add_seed_flag(parser, "random seed; default 0")
    parser.add_argument("--name", help="campaign name")
    flags.add_output_flags(parser, json_help="print the truth as one JSON object",
                           quiet_help="print only the files written")
    parser.add_argument("--out", required=True, metavar="DIR", help="campaign folder to write")


def run(args: argparse.Namespace) -> int:
    """Run ``stiffness simulate``; returns the exit code."""
    units = Units(length=args.units)
    flags.check_noise_std(args.noise, "--noise", args.units, zero=True)
    flags.warn_rig_noise(args.noise, "--noise", args.units, units.length_to_si)
    noise_std_m = DEFAULT_NOISE_STD_M if args.noise is None else args.noise * units.length_to_si
    flags.check_noise_std(args.rotation_noise, "--rotation-noise", units.angle, zero=True)
    _check_kind_flags(args)
    robot = flags.robot_flags(args)
    kq = flags.parse_list(args.kq, "--kq") if args.kq else None
    if args.kind == "poses":
        return _run_poses(args, robot, kq, units, noise_std_m)
    sim = simulate(
        robot.source, kq=kq, effects=args.effect,
        configs=args.configs, loads_per_config=args.loads_per_config,
        max_force=args.max_force, noise_std_m=noise_std_m, seed=args.seed,
        frame=robot.frame, target_offset_m=robot.target_offset,
        compliant_joints=robot.compliant_joints,
        baseline=args.baseline, units=units, load_pattern=args.load_pattern,
        repeats=args.repeats, declare_noise=not args.undeclared_noise, name=args.name,
        rotations=args.rotations,
        rotation_noise_std_rad=None if args.rotation_noise is None
        else args.rotation_noise * units.angle_to_si,
        loops=robot.loops, fixed_base=robot.fixed_base, plan=args.plan,
        joint_angles=args.joint_angles)
    path = sim.write(args.out)
    truth = sim.to_dict()
    if args.json:
        print(json.dumps(truth, indent=1))
        return 0
    print(f"wrote {path} ({sim.campaign.n_rows} rows) and {path.parent / TRUTH_FILE}")
    if args.quiet:
        return 0
    unit = truth["unit"]
    if sim.noise_std_m > 0:
        print(f"baseline {sim.campaign.baseline}; noise std {truth['noise_std']:.4g} {unit}; "
              f"the baseline's linearisation misses "
              f"{truth['baseline_model_error_noise_units']:.3g} noise std RMS")
    else:  # noise-free: sizes in the length unit (there is no noise std to count them in)
        print(f"baseline {sim.campaign.baseline}; no noise; the baseline's linearisation "
              f"misses {truth['baseline_model_error']:.3g} {unit} RMS")
    for label, size in truth["effect_rms"].items():
        ratio = truth["effect_rms_noise_units"][label]
        print(f"hidden {label}: changes the deflections by "
              + (f"{ratio:.3g} noise std RMS" if ratio is not None else f"{size:.3g} {unit} RMS"))
    if not sim.effects:
        print("no hidden effect")
    return 0


def _check_kind_flags(args: argparse.Namespace) -> None:
    """Refuse the flags of the other campaign kind (one line), then give the deflection flags
    their defaults."""
    other = _DEFLECTION_ONLY if args.kind == "poses" else _POSE_ONLY
    given = ["--load" if n == "wrench" else "--" + n.replace("_", "-") for n in other
             if getattr(args, n) not in (None, [])]
    if given:
        owner = "deflections" if args.kind == "poses" else "poses"
        one = len(given) == 1
        raise StiffnessError(f"{', '.join(given)} {'is' if one else 'are'} for --kind {owner}, "
                             f"not {args.kind}: drop {'it' if one else 'them'}"
                             + (" (stiffness design plans deflection campaigns only)"
                                if "--plan" in given else "")
                             + (" or add --kind poses" if owner == "poses" else ""))
    if args.rotation_noise is not None and not args.rotations:  # either kind: not ignored
        raise StiffnessError("--rotation-noise is the noise of the orientations --rotations "
                             "measures: add --rotations, or drop it")
    for name, value in _DEFLECTION_DEFAULTS.items():
        if getattr(args, name) is None:
            setattr(args, name, value)


def _run_poses(args: argparse.Namespace, robot: flags.RobotFlags, kq: list[float] | None,
               units: Units, noise_std_m: float) -> int:
    """``--kind poses``: simulate, write and print a pose campaign."""
    if robot.source is None:
        raise StiffnessError("--robot is required: a shipped robot, an example-robot-data name, "
                             "a URDF path or a robot.toml")
    declared, turns = flags.parse_markers(args.marker)
    markers = [Marker(m.name, m.frame, m.offset * units.length_to_si,
                      pin.exp3(turns.get(m.name, np.zeros(3)) * units.angle_to_si))
               for m in declared]
    wrench = flags.parse_list(args.wrench, "--load") if args.wrench else None
    drift = flags.parse_list(args.drift, "--drift") if args.drift else None
    if drift is not None and len(drift) != 3:
        raise StiffnessError(f"--drift takes three lengths X,Y,Z ({units.length}), got "
                             f"{len(drift)}")
    sim = simulate_poses(
        robot.source, markers or None, DEFAULT_POSES if args.poses is None else args.poses,
        args.effect, kq, noise_std_m, args.seed, wrench, args.rotations,
        None if args.rotation_noise is None else args.rotation_noise * units.angle_to_si,
        None if drift is None else np.array(drift) * units.length_to_si, units, args.name,
        robot.frame, robot.compliant_joints, robot.fixed_base, not args.undeclared_noise)
    path = sim.write(args.out)
    truth = sim.to_dict()
    if args.json:
        print(json.dumps(truth, indent=1))
        return 0
    c = sim.campaign
    print(f"wrote {path} ({c.n_rows} poses; markers "
          + ", ".join(f"{m.name} on {m.frame}" for m in c.markers)
          + f") and {path.parent / TRUTH_FILE}")
    if args.quiet:
        return 0
    print(f"noise std {truth['noise_std']:.4g} {truth['unit']} per position component")
    for label, size in truth["effect_rms"].items():
        noise = truth["effect_rms_noise_units"][label]
        beyond = truth["effect_rms_beyond_frame"].get(label)
        print(f"hidden {label}: moves the markers by {size:.3g} {truth['unit']} RMS"
              + ("" if noise is None else f", {noise:.3g} noise std")
              + ("" if beyond is None or beyond >= FRAME_HIDDEN_SHARE * size else
                 f"; {beyond:.3g} {truth['unit']} RMS beyond a rigid move of the measuring "
                 "frame, which every fit takes out: only that part can show"))
    if not truth["effect_rms"]:
        print("no hidden effect")
    return 0
