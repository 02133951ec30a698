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
"""

from __future__ import annotations

import argparse
import json

from stiffness.calibration.campaign_toml import BASELINES
from stiffness.cli import flags
from stiffness.elastic.effects import LIBRARY
from stiffness.planning.design import DEFAULT_NOISE_STD_M
from stiffness.planning.simulate import TRUTH_FILE, simulate
from stiffness.planning.simulate_request import LOAD_PATTERNS
from stiffness.units import LENGTH_UNITS, Units


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Flags of ``stiffness simulate``."""
    flags.add_robot_flags(parser, robot_help="shipped robot (sk120), example-robot-data name, "
                                             "URDF path or robot.toml (required unless --plan "
                                             "is a folder naming it)")
    parser.add_argument("--plan", metavar="PLAN",
                        help="simulate exactly these rows: a PLAN.csv written by `stiffness "
                             "design`, or its folder (whose campaign.toml gives the robot "
                             "flags' defaults); --configs, --loads-per-config, --max-force and "
                             "--load-pattern are then not used")
    flags.add_stiffness_flag(parser, help="true stiffness per declared compliant joint, "
                                          "N.m/rad (N/m prismatic); default the shipped robot's")
    parser.add_argument("--effect", action="append", default=[], metavar="NAME[:WHERE]=VALUE",
                        help="hidden effect, repeatable: " + ", ".join(LIBRARY) + "; a "
                             "place NAME:WHERE or NAME(WHERE), e.g. "
                             "backlash:joint2=0.003 (deg), joint_compliance:joint5=3e5 "
                             "(N.m/rad), 'link_compliance:joint2->elbow=2e6' (N.m/rad), "
                             "nonlinear_joint_stiffness:joint3=0.001 (1/(N.m)), "
                             "frame_misalignment=2 (deg), target_offset=20 (--units), "
                             "force_sensor_bias=5 (N), complementary_stiffness, "
                             "gravity_preload=20[,cx,cy,cz] (kg, --units), "
                             "gravity_compensator:joint2=2e5,500[,lever,base] (N/m, N, "
                             "then m)")
    parser.add_argument("--configs", type=flags.integer, default=10,
                        help="configurations; default 10")
    parser.add_argument("--loads-per-config", type=flags.integer, default=4,
                        help="loads per configuration; default 4")
    parser.add_argument("--repeats", type=flags.integer, default=1,
                        help="measurements per load (replicates); default 1")
    parser.add_argument("--max-force", type=flags.number, default=100.0,
                        help="largest force, N; default 100")
    parser.add_argument("--load-pattern", choices=LOAD_PATTERNS, default="random",
                        help="random directions and magnitudes, a ramp along one direction per "
                             "configuration, or the six axis directions; default random")
    parser.add_argument("--noise", type=flags.number, metavar="STD",
                        help="measurement noise std per deflection component, in the files' "
                             "length unit (--units, default mm); default 0.005 mm")
    parser.add_argument("--rotations", action="store_true",
                        help="also write the measured rotations rx, ry, rz of the target frame")
    parser.add_argument("--rotation-noise", type=flags.number, default=None,
                        help="rotation noise std, deg; default --noise / 100 mm (rad)")
    parser.add_argument("--undeclared-noise", action="store_true",
                        help="do not write noise_std into the campaign")
    parser.add_argument("--baseline", choices=BASELINES,
                        help="declared baseline; default conventional when "
                             "complementary_stiffness is hidden, else enhanced")
    parser.add_argument("--joint-angles", default="motor", metavar="motor|link",
                        help="what the campaign records as joint angles: the commanded pose "
                             "(motor, which a hidden weight or compensator sags) or the "
                             "unloaded link pose (link); default motor")
    parser.add_argument("--units", choices=tuple(LENGTH_UNITS), default="mm",
                        help="length unit of the files, of --noise and of the lengths of "
                             "--effect; default mm")
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
    robot = flags.robot_flags(args)
    kq = flags.parse_list(args.kq, "--kq") if args.kq else None
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
    print(f"baseline {sim.campaign.baseline}; noise std {truth['noise_std']:.4g} "
          f"{truth['unit']}; the baseline's linearisation misses "
          f"{truth['baseline_model_error_noise_units']:.3g} noise std RMS")
    for label, size in truth["effect_rms_noise_units"].items():
        print(f"hidden {label}: changes the deflections by {size:.3g} noise std RMS")
    if not sim.effects:
        print("no hidden effect")
    return 0
