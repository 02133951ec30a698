"""``stiffness design``: the poses and loads to measure (experiment design).

Example::

    stiffness design --robot ur5 --compliant-joints shoulder_pan_joint,shoulder_lift_joint,\\
        elbow_joint --target-offset 0,0,0.1 --kq 3e4,2e4,1.5e4 --configs 8 \\
        --loads-per-config 3 --max-force 100 --noise 0.005 --out plan/

draws ``--candidates`` reachable poses (loads along the axes and cube diagonals at
``--max-force`` N), chooses ``--configs`` of them with ``--loads-per-config`` loads each that
maximise the Fisher information of ln k (``--criterion D|A|E``; :mod:`stiffness.calibration.
design`), and writes the plan: ``PLAN.csv`` (campaign measurement format without the measured
columns), or a folder with ``campaign.toml`` and ``plan.csv``. It prints the predicted standard
error of each stiffness relative to it, for the plan and for random plans of the same size.
``--existing CAMPAIGN`` completes a measured campaign; ``--separate A[:WHERE],B[:WHERE]``
chooses the rows that tell two alternatives fitted to it apart. Then ``stiffness simulate
--plan`` (in place of the rig), ``stiffness identify`` and ``stiffness diagnose``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from stiffness.calibration.campaign import load_campaign
from stiffness.calibration.experiment import CRITERIA
from stiffness.cli import flags
from stiffness.elastic.effects.hypothesis import BASELINES
from stiffness.elastic.model_file import read_model_file
from stiffness.files import output_folder
from stiffness.planning.design import (
    DEFAULT_CANDIDATES,
    DEFAULT_RANDOM_PLANS,
    DesignResult,
    check_sizes,
    design,
    design_robot,
    parse_separate,
)
from stiffness.planning.plan import check_plan_target
from stiffness.units import LENGTH_UNITS, Units


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Flags of ``stiffness design``."""
    flags.add_robot_flags(parser, robot_help="shipped robot (sk120), example-robot-data name, "
                                             "URDF path or robot.toml (default: --model's or "
                                             "--existing's)")
    parser.add_argument("--model", metavar="FILE",
                        help="identified model (identified-model.json): robot, target, "
                             "compliant joints and the nominal K_theta")
    flags.add_stiffness_flag(parser, help="nominal stiffness per compliant joint, N.m/rad (N/m "
                                          "prismatic); default --model's or the shipped robot's")
    parser.add_argument("--formulation", choices=BASELINES, default=None,
                        help="deflection model: enhanced (K - K_C) or conventional; default "
                             "--existing's baseline, else --model's, else enhanced")
    parser.add_argument("--configs", type=flags.integer, required=True, metavar="N",
                        help="configurations in the plan")
    parser.add_argument("--loads-per-config", type=flags.integer, default=4, metavar="M",
                        help="load directions per configuration; default 4")
    parser.add_argument("--max-force", type=flags.number, required=True, metavar="F",
                        help="load magnitude, N")
    parser.add_argument("--candidates", type=flags.integer, default=DEFAULT_CANDIDATES, metavar="K",
                        help=f"candidate poses drawn; default {DEFAULT_CANDIDATES}")
    parser.add_argument("--criterion", choices=CRITERIA, default="D",
                        help="D (log det of the Fisher information, default), A (sum of the "
                             "relative variances) or E (smallest eigenvalue)")
    parser.add_argument("--separate", metavar="EFFECT[:WHERE],EFFECT[:WHERE]",
                        help="choose the rows that tell these two alternatives, fitted to "
                             "--existing, apart (e.g. backlash:joint2,nonlinear_joint_stiffness:"
                             "joint2; a place NAME:WHERE or NAME(WHERE))")
    parser.add_argument("--existing", metavar="CAMPAIGN",
                        help="measured campaign whose rows count as already chosen")
    flags.add_strict_flag(parser)  # of --existing's CSV
    parser.add_argument("--noise", type=flags.number, metavar="STD",
                        help="measurement noise std per deflection component, in the files' "
                             "length unit (--units); default --existing's noise_std, else "
                             "0.005 mm")
    parser.add_argument("--units", choices=tuple(LENGTH_UNITS), default=None,
                        help="length unit of --noise and of the plan's campaign.toml; default "
                             "--existing's, else mm")
    parser.add_argument("--random-plans", type=flags.integer, default=DEFAULT_RANDOM_PLANS,
                        help=f"random plans compared with; default {DEFAULT_RANDOM_PLANS}")
    flags.add_seed_flag(parser, "random seed; default 0")
    parser.add_argument("--out", required=True, metavar="PLAN.csv",
                        help="plan to write: a .csv file, or a folder (campaign.toml + plan.csv)")
    flags.add_output_flags(parser, quiet_help="no progress on stderr")


def format_report(result: DesignResult) -> str:
    """Human-readable summary of a design."""
    d = result.to_dict()
    rel = d["predicted_relative_se"]
    lines = [
        f"{result.robot.title}: {d['configs']} configurations x "
        f"{d['rows'] // max(d['configs'], 1)} loads = {d['rows']} rows chosen from "
        f"{d['candidates']} candidate poses x {d['load_directions']} load directions at "
        f"{d['max_force_N']:.4g} N ({d['criterion']}-optimal, {d['formulation']} model, "
        f"{d['exchanges']} exchange{'' if d['exchanges'] == 1 else 's'} after the greedy pass)",
        f"nominal stiffness from {d['k_source']}; noise std "
        f"{result.noise_std_m / result.plan.units.length_to_si:.4g} {result.plan.units.length} "
        f"({d['noise_source']})",
    ]
    if result.existing_rows:
        lines.append(f"completes the existing campaign's {result.existing_rows} rows")
    lines += ["", "predicted standard error of k relative to k"
              + (" (the existing rows with the plan, with a random plan, alone):"
                 if result.existing is not None else ":")]
    head = f"  {'joint':<24} {'k (SI)':>11} {'plan':>12} {'random':>12}"
    if result.existing is not None:
        head += f" {'existing':>12}"
    lines.append(head)
    for i, j in enumerate(result.joints):
        row = (f"  {j:<24} {result.k[i]:>11.4g} {_pct(result.designed.relative_se[i]):>12} "
               f"{_pct(result.random_relative_se[:, i].mean()):>12}")
        if result.existing is not None:
            row += f" {_pct(result.existing.relative_se[i]):>12}"
        lines.append(row)
    ratio = result.se_ratio
    ratio_text = (f"ratio {ratio:.3g}" if math.isfinite(ratio) else
                  "no ratio (the plan determines no stiffness)")
    undetermined = not result.determined.all()
    lines.append(f"  mean: plan {_pct(result.designed.mean_relative_se)}, random plans of the "
                 f"same size {_pct(rel['random_plan_mean'] or float('inf'))} (mean of "
                 f"{rel['random_plans']}); {ratio_text}"
                 + (" over the determined stiffnesses" if undetermined and math.isfinite(ratio)
                    else ""))
    if undetermined or not math.isfinite(result.designed.mean_relative_se):
        lines.append(f"  {UNDETERMINED}: the rows leave that stiffness free (no measured "
                     "deflection depends on it: a singular Fisher information); add poses or "
                     "load directions that move that joint")
    if result.separate is not None:
        s = d["separate"]
        lines += ["", f"separating {s['effects'][0]} from {s['effects'][1]} (noise from "
                      f"{s['noise_source']}):",
                  f"  predicted separation: plan {_g(s['plan_noise_units'])} noise std, random "
                  f"plans {_g(s['random_mean_noise_units'])}, existing campaign "
                  f"{_g(s['existing_noise_units'])}"]
    lines += [f"note: {n}" for n in result.notes]
    return "\n".join(lines)


#: What an infinite or NaN standard error is printed as (explained below the table).
UNDETERMINED = "undetermined"


def _pct(v: float) -> str:
    return UNDETERMINED if not math.isfinite(v) else f"{100 * v:.3g} %"


def _g(v) -> str:
    return "-" if v is None else f"{v:.3g}"


def run(args: argparse.Namespace) -> int:
    """Run ``stiffness design``; returns the exit code."""
    check_sizes(args.configs, args.loads_per_config, args.candidates)
    out = Path(args.out)  # before the work: a bad --out fails at once
    output_folder(out.parent if out.suffix.lower() == ".csv" else out, create=False)
    check_plan_target(out)
    if args.separate is not None:
        parse_separate(args.separate)
    existing = load_campaign(args.existing) if args.existing else None
    model = None
    if args.model is not None:
        model = read_model_file(args.model)
        if args.robot is not None:
            model.check_robot(args.robot)
    given = flags.robot_flags(args)
    robot = design_robot(given.source, given.frame, given.target_offset, given.compliant_joints,
                         given.loops, given.fixed_base, model=model, existing=existing)
    units = existing.units if existing is not None else Units()
    if args.units is not None:
        units = Units(units.angle, units.force, args.units)
    flags.check_noise_std(args.noise, "--noise", units.length)
    flags.warn_rig_noise(args.noise, "--noise", units.length, units.length_to_si)
    show = sys.stderr.isatty() and not args.quiet

    def progress(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    result = design(
        robot, args.configs, args.max_force, loads_per_config=args.loads_per_config,
        candidates=args.candidates, criterion=args.criterion,
        k=None if args.kq is None else flags.parse_kq(args.kq, robot),
        k_source=None if args.kq is None else "--kq",
        noise_std_m=None if args.noise is None else args.noise * units.length_to_si,
        existing=existing, separate=args.separate, seed=args.seed,
        formulation=args.formulation, random_plans=args.random_plans, units=units,
        progress=progress if show else None, model=model)
    out = result.write(out)
    if args.json:
        print(json.dumps(result.to_dict(), indent=1, allow_nan=False))
        return 0
    print(format_report(result))
    print(f"plan written to {out}" + ("" if out.parent != Path(args.out) else
                                      f" (with {Path(args.out) / 'campaign.toml'})"))
    return 0
