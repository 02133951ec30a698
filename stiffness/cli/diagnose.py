"""``stiffness diagnose``: where a campaign's model disagrees with it, and what effect is missing.

Example::

    stiffness diagnose robots/sk120/campaigns/table2 --out diagnosis/

prints where the baseline disagrees with the measurements (by configuration, axis, load
magnitude and load sign, against the noise), the effects added one by one with the RMS residual
after each, their parameters with 95 % intervals, what the campaign cannot tell apart and the
extra poses and loads that would. ``--json`` prints one JSON object (``baseline_rms``,
``noise_std``, ``noise_std_source``, ``steps``, ``missing_effects``, ``final_rms``, ``unit``)
and nothing else on stdout; ``--out DIR`` writes ``diagnosis.json`` (everything),
``residuals.png`` (residuals before and after), ``final-model.json`` and ``diagnosis.html``
(all of it as a page: residuals, steps with their BIC change and RMS, parameters with intervals,
ambiguities with the proposed poses).
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import sys
from collections.abc import Callable
from pathlib import Path

from stiffness.calibration.campaign import campaign_kind, load_campaign
from stiffness.calibration.diagnose import MAX_STEPS, diagnose
from stiffness.calibration.diagnosis import DIAGNOSIS_FILE
from stiffness.calibration.diagnosis_report import format_report
from stiffness.calibration.pose_register import REFIT_REFUSED
from stiffness.calibration.solver import LOSSES
from stiffness.cli import flags
from stiffness.elastic.effects import MASSES
from stiffness.errors import StiffnessError
from stiffness.files import check_folder_name, output_folder, refuse_foreign_folder
from stiffness.workspace.definiteness import terminal_progress


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Flags of ``stiffness diagnose``."""
    parser.add_argument("campaign", metavar="CAMPAIGN",
                        help="campaign.toml, or the folder holding it")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object (campaign units) and nothing else")
    parser.add_argument("--out", metavar="DIR",
                        help="folder to write diagnosis.json, residuals.png, final-model.json "
                             "and diagnosis.html (the page) into (made if missing); default: "
                             "nothing written")
    parser.add_argument("--max-steps", type=flags.integer,
                        help=f"largest number of effects the search adds (a pose campaign's "
                             f"families, those forced by --families not counted; 0: the "
                             f"baseline only); default {MAX_STEPS} for a deflection campaign, "
                             f"no limit for a pose campaign")
    flags.add_seed_flag(parser, "seed of the cross-validation folds and proposed poses; default 0")
    parser.add_argument("--no-proposals", action="store_true",
                        help="do not propose extra poses and loads")
    parser.add_argument("--workers", type=flags.integer, metavar="N",
                        help="processes fitting a step's candidates side by side (default: "
                             "the usable cores; 1: all in this process); the result does not "
                             "depend on it. A pose campaign's candidates (each fit with its "
                             "held-out RMS) go to a Dask LocalCluster of N single-threaded "
                             "workers, as scan --workers (default: all in this process)")
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")
    flags.add_strict_flag(parser)
    parser.add_argument("--loss", choices=LOSSES, default="linear",
                        help="linear (least squares) or a robust loss for every fit, scaled "
                             "by the noise std, with intervals from Huber's sandwich "
                             "covariance (deflection and pose campaigns); default linear")
    parser.add_argument("--compensator-geometry", action="append", default=[],
                        metavar="JOINT=LEVER_M,BASE_M",
                        help="repeatable: the lever and base lengths (m) of a spring gravity "
                             "compensator on JOINT, e.g. joint2=0.12,0.35; default 0.1,0.3. "
                             "In a deflection campaign the base is fitted when the data "
                             "determine it, else held (a pose campaign holds both); the lever "
                             "always is the declared one (the torque depends on the lengths "
                             "only through F0 a, k a^2 and a/d)")
    parser.add_argument("--masses", choices=MASSES, default="known",
                        help="whether the robot's link masses are trusted or unknown: the "
                             "weight is then fitted from lumped gravity parameters (a pose "
                             "model's compliance-times-mass-moment family gravity_lumped; a "
                             "deflection campaign's candidate gravity_lumped, the links' "
                             "masses and mass moments, instead of gravity_preload); default "
                             "known")
    parser.add_argument("--families", metavar="A,B",
                        help="families forced into the model, added first in this order "
                             "whatever their BIC and held-out error, never removed again "
                             "(e.g. joint_offsets,geometry; a deflection campaign's are "
                             "effect names, each at its best place, or places such as "
                             "'transversal_compliance(joint3)' or "
                             "transversal_compliance:joint3); recorded in final-model.json")
    parser.add_argument("--not", dest="not_families", metavar="A,B",
                        help="families never tried (e.g. backlash; a deflection campaign's "
                             "are the library's effect names, e.g. transversal_compliance, "
                             "or places, never tried there: 'backlash(joint2)' or "
                             "backlash:joint2); recorded in final-model.json")
    parser.add_argument("--base-tilt", metavar="RX,RY",
                        help="pose campaigns: a measured tilt of the robot's base against "
                             "gravity, two angles in deg (rotation exp([rx, ry, 0]) of the "
                             "base's axes from level); every model feels gravity turned by "
                             "it, the base_tilt family fits what remains")
    parser.add_argument("--validate", metavar="CAMPAIGN",
                        help="another campaign of the same kind and robot every step's model "
                             "is evaluated on without refitting (the stage table: the gap "
                             "shrinking on held-out data; a deflection campaign's final "
                             "model file too, under validation)")
    flags.add_refit_flags(parser)


def command_line(args: argparse.Namespace) -> str:
    """The command that reproduces this run (recorded in diagnosis.html)."""
    steps = MAX_STEPS if args.max_steps is None else args.max_steps
    words = ["stiffness", "diagnose", str(args.campaign), "--out", str(args.out),
             "--max-steps", str(steps), "--seed", str(args.seed)]
    words += ["--no-proposals"] if args.no_proposals else []
    words += ["--validate", str(args.validate)] if args.validate else []
    words += ["--loss", args.loss] if getattr(args, "loss", "linear") != "linear" else []
    words += ["--masses", args.masses] if getattr(args, "masses", "known") != "known" else []
    words += ["--families", args.families] if getattr(args, "families", None) else []
    words += ["--not", args.not_families] if getattr(args, "not_families", None) else []
    for declared in getattr(args, "compensator_geometry", []):
        words += ["--compensator-geometry", declared]
    return shlex.join(words)


def pose_command_line(args: argparse.Namespace) -> str:
    """The command that reproduces a pose diagnosis (recorded in its diagnosis.html)."""
    words = ["stiffness", "diagnose", str(args.campaign), "--out", str(args.out),
             "--seed", str(args.seed), "--masses", args.masses]
    words += ["--validate", str(args.validate)] if args.validate else []
    words += flags.refit_flag_words(args)
    words += ["--loss", args.loss] if args.loss != "linear" else []
    words += ["--max-steps", str(args.max_steps)] if args.max_steps is not None else []
    words += ["--families", args.families] if args.families else []
    words += ["--not", args.not_families] if args.not_families else []
    words += ["--base-tilt", args.base_tilt] if args.base_tilt else []
    for declared in args.compensator_geometry:
        words += ["--compensator-geometry", declared]
    return shlex.join(words)


def compensator_geometry(declared: list[str]) -> dict[str, dict]:
    """``--compensator-geometry JOINT=LEVER_M,BASE_M`` flags as ``diagnose``'s
    ``effect_settings`` (m).

    Raises
    ------
    StiffnessError
        Not ``JOINT=LEVER_M,BASE_M`` with two numbers, or a joint given twice.
    """
    settings: dict[str, dict] = {}
    for text in declared:
        joint, sep, lengths = text.partition("=")
        values = flags.parse_list(lengths, "--compensator-geometry") if sep and lengths.strip() \
            else []
        if len(values) != 2:
            raise StiffnessError(f"--compensator-geometry {text!r}: give JOINT=LEVER_M,BASE_M, "
                                 "e.g. joint2=0.12,0.35")
        lever, base = values
        label = f"gravity_compensator({joint.strip()})"
        if label in settings:
            raise StiffnessError(f"--compensator-geometry names {joint.strip()} twice; give "
                                 "each joint once")
        settings[label] = {"lever_m": lever, "base_m": base}
    return settings


def run(args: argparse.Namespace) -> int:
    """Run ``stiffness diagnose``; returns the exit code."""
    flags.require_at_least_one(args.workers, "--workers")
    if campaign_kind(args.campaign) == "poses":
        return run_poses(args)
    if flags.refit_from_args(args):
        raise StiffnessError(REFIT_REFUSED)
    if args.base_tilt:
        raise StiffnessError("--base-tilt takes pose campaigns: a deflection campaign's "
                             "loaded-minus-unloaded positions do not see the base's tilt "
                             "against gravity to first order; drop it")
    declared = compensator_geometry(args.compensator_geometry)
    campaign = load_campaign(args.campaign)
    check_out_folder(args.out)  # before the work: a bad --out fails at once
    show = sys.stderr.isatty() and not args.quiet

    def progress(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    result = diagnose(campaign, max_steps=args.max_steps, seed=args.seed,
                      propose=not args.no_proposals, progress=progress if show else None,
                      workers=args.workers, loss=args.loss, effect_settings=declared,
                      masses=args.masses, validate=args.validate or None,
                      families=flags.parse_names(args.families) or (),
                      not_families=flags.parse_names(args.not_families) or ())
    paths = result.write(args.out, command_line(args)) if args.out else None
    if result.validation is None:
        return _emit(args.json, result.to_dict(), lambda: format_report(result), paths)
    from stiffness.calibration.validation_page import format_validation  # only with --validate

    validation = result.validation
    return _emit(args.json, result.to_dict(),
                 lambda: f"{format_report(result)}\n\nvalidation on {args.validate}:\n"
                         f"{format_validation(validation)}", paths)


def check_out_folder(out: str | None) -> None:
    """Refuse, before any work, an ``--out`` that cannot hold the diagnosis: a file in the
    way, a name ending in ``.json`` (not an existing folder), the form ``identify --out
    FILE.json`` takes for its one file, where diagnose writes several, or a folder that is not
    a previous diagnosis (a campaign's: publishing the diagnosis would delete its files).

    Raises
    ------
    StiffnessError
        The name ends in ``.json``; :class:`~stiffness.errors.OutputError` for a file in the way.
    """
    if out is None:
        return
    if Path(out).suffix.lower() == ".json" and not Path(out).is_dir():
        raise StiffnessError(f"--out {out}: diagnose writes a folder (diagnosis.json, "
                             f"final-model.json, diagnosis.html...), not one JSON file; give a "
                             f"folder name, e.g. --out {Path(out).with_suffix('')}")
    output_folder(out, create=False)
    check_folder_name(out)
    refuse_foreign_folder(out, DIAGNOSIS_FILE, "diagnosis")


def run_poses(args: argparse.Namespace) -> int:
    """``stiffness diagnose`` on a pose campaign (docs/absolute-poses.md)."""
    from stiffness.calibration.pose_campaign import load_pose_campaign  # only for pose campaigns
    from stiffness.calibration.pose_diagnose import diagnose_poses
    from stiffness.calibration.pose_report import format_pose_report

    campaign = load_pose_campaign(args.campaign)
    other = load_pose_campaign(args.validate) if args.validate else None
    refit = flags.refit_from_args(args)
    if refit and other is None:
        raise StiffnessError("--refit-frame and --refit-markers fit the measuring frame to "
                             "the validation campaign; give --validate OTHER_CAMPAIGN or drop "
                             "them")
    check_out_folder(args.out)
    show = sys.stderr.isatty() and not args.quiet
    result = diagnose_poses(campaign, masses=args.masses, seed=args.seed, validate=other,
                            progress=(lambda text: print(text, file=sys.stderr, flush=True))
                            if show else None, loss=args.loss, workers=args.workers,
                            bar=lambda label: terminal_progress(label, args.quiet),
                            families=flags.parse_names(args.families) or (),
                            not_families=flags.parse_names(args.not_families) or (),
                            base_tilt=None if args.base_tilt is None else [
                                math.radians(v)
                                for v in flags.parse_list(args.base_tilt, "--base-tilt")],
                            max_steps=args.max_steps, refit=refit,
                            effect_settings=compensator_geometry(args.compensator_geometry))
    paths = result.write(args.out, pose_command_line(args)) if args.out else None
    return _emit(args.json, result.to_dict(), lambda: format_pose_report(result), paths)


def _emit(as_json: bool, record: dict, report: Callable[[], str],
          paths: dict[str, Path] | None) -> int:
    """Print ``record`` as JSON, or the text report and the files written."""
    if as_json:
        print(json.dumps(record, indent=1, allow_nan=False))
        return 0
    print(report())
    if paths:
        print("written: " + ", ".join(str(p) for p in paths.values()))
    return 0
