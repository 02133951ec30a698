"""``stiffness identify``: joint stiffness from a measurement campaign (A&S eq. 11-13).

Example::

    stiffness identify robots/sk120/campaigns/table2 --method both --starts 8

prints the identified stiffness of each compliant joint (N.m/rad, and the papers' N.mm/rad)
with its standard error and 95 % confidence interval, the residual norm of eq. 12, the
condition number of the problem and the stiffnesses the data cannot determine. Nothing is
written unless ``--out`` is given, as for ``diagnose``: ``--out DIR`` writes
``DIR/identified-model.json`` (the folder made if missing, as ``diagnose --out DIR`` writes its
files in a folder), ``--out FILE.json`` that file. ``--json`` prints one JSON object instead of
the table. A pose campaign's springs are fitted with its measuring frame and markers
(:func:`stiffness.calibration.pose_identify.identify_poses`); ``--out`` then writes the pose
model file.
"""

from __future__ import annotations

import argparse
import functools
import math
import os
import sys
from pathlib import Path

from stiffness.calibration.campaign import campaign_kind, load_campaign
from stiffness.calibration.identification import Identification
from stiffness.calibration.identify import FORMULATIONS, METHODS, MODEL_FILE, identify
from stiffness.calibration.outliers import describe_outliers
from stiffness.calibration.pose_campaign import load_pose_campaign
from stiffness.calibration.pose_identify import PoseIdentification, identify_poses
from stiffness.calibration.result import IdentificationResult
from stiffness.calibration.solver import LOSSES
from stiffness.cli import flags
from stiffness.errors import StiffnessError
from stiffness.files import output_folder


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Flags of ``stiffness identify``."""
    parser.add_argument("campaign", metavar="CAMPAIGN",
                        help="campaign.toml, or the folder holding it")
    parser.add_argument("--formulation", choices=FORMULATIONS,
                        help="deflection model: conventional (J K^-1 J^T F), enhanced "
                             "(J (K - K_C)^-1 J^T F, A&S eq. 10) or exact (elastostatic "
                             "equilibrium, slower); default: the campaign's baseline")
    parser.add_argument("--method", choices=METHODS,
                        help="least-squares solver: trf, lm (Levenberg-Marquardt) or both; "
                             "default trf (deflection campaigns)")
    parser.add_argument("--starts", type=flags.integer,
                        help="number of starts: the paper's 1e8 N.mm/rad then log-uniform "
                             "random starts over 1e2..1e8 N.m/rad; default 8 (deflection "
                             "campaigns)")
    flags.add_seed_flag(parser, "seed of the random starts; default 0")
    parser.add_argument("--loss", choices=LOSSES, default="linear",
                        help="linear (least squares) or a robust loss scaled by the declared "
                             "or estimated noise, whose intervals come from Huber's sandwich "
                             "covariance (method trf only); default linear")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object (SI) instead of the table")
    parser.add_argument("--out", metavar="DIR|FILE.json",
                        help=f"write the identified model: DIR/{MODEL_FILE} in the folder DIR "
                             f"(made if missing, as diagnose --out DIR), or FILE.json (a name "
                             f"ending in .json); default: nothing written")
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")
    flags.add_strict_flag(parser)


def _g(value: float, digits: int = 5) -> str:
    """A number, or the word for an unbounded (inf) or undetermined (NaN) one."""
    if value != value:
        return "undetermined"
    return f"{value:.{digits}g}" if abs(value) != float("inf") else "unbounded"


def _undetermined_row(result: Identification, j: int) -> tuple[str, str, str, str, str, str]:
    """The table row of joint ``j``, which the data do not determine (diagnose's rule,
    :attr:`~stiffness.elastic.effects.base.Parameter.determined`): the word instead of its
    value and standard error, its 95 % interval (``at least`` its low end when unbounded
    above), and why (its physical scale, or an unbounded interval)."""
    low, high = result.ci95_low[j], result.ci95_high[j]
    bounded = math.isfinite(low) and math.isfinite(high)
    interval = f"[{_g(low)}, {_g(high)}]" if bounded else (
        f"at least {_g(low)}" if math.isfinite(low) and low > 0 else "unbounded")
    scale = result.physical_scale[j] if result.physical_scale else ""
    why = scale if bounded and scale else "the data do not bound it"
    return (result.joints[j], "undetermined", "-", "-", interval, f"undetermined: {why}")


def format_table(result: Identification) -> str:
    """Human-readable report of an identification."""
    revolute = all(u == "N.m/rad" for u in result.units)
    si = "N.m/rad" if revolute else "SI"
    paper = "N.mm/rad" if revolute else "N.mm/rad|N/mm"
    rows = [("joint", f"K ({si})", f"K ({paper})", f"SE ({si})", f"CI95 ({si})", "")]
    for j, joint in enumerate(result.joints):
        unit = "" if revolute else result.units[j]
        held = result.held_joints[j]
        if held is not None:  # not a value the data gave: say so, no number in its columns
            rows.append((joint, "-", "-", "-", "-", f"not fitted (held at "
                         f"{_g(result.k[j])} {result.units[j]}): {held}"))
            continue
        if result.at_bound and result.at_bound[j]:  # its compliance at zero: no value
            rows.append((joint, "rigid", "-", "-", f"above {_g(result.ci95_low[j])}",
                         "rigid to the data: its compliance at zero (one-sided 95 % interval)"))
            continue
        if joint in result.undetermined_joints:  # its interval, no value to read as measured
            rows.append(_undetermined_row(result, j))
            continue
        rows.append((
            joint,
            f"{_g(result.k[j])} {unit}".rstrip(),
            _g(result.k_paper_units[j]),
            _g(result.standard_error[j], 3),
            f"[{_g(result.ci95_low[j])}, {_g(result.ci95_high[j])}]",
            (f"conditional on {', '.join(result.conditional_on[j])} held at its bound"
             if result.conditional_on and result.conditional_on[j] else ""),
        ))
    widths = [max(len(r[c]) for r in rows) for c in range(len(rows[0]))]
    lines = [
        f"campaign {result.campaign}"
        + (f" ({result.campaign_path})" if result.campaign_path else "")
        + (f" of {result.robot_name}" if result.robot_name else "")
        + f": {result.n_rows} rows, {result.n_configurations} configurations, "
          f"{result.n_residuals} residuals, {result.n_parameters} stiffnesses",
        f"stiffness in {result.stiffness_coordinates} coordinates "
        + ("(the controller's, which the drives turn with)"
           if result.stiffness_coordinates == "controller" else "(the kinematic chain's joints)"),
        f"formulation {result.formulation}, method {result.method}, {len(result.starts)} "
        f"least-squares runs: " + ("all agree" if result.starts_agree else "they DISAGREE")
        + ("" if result.methods_agree is None else
           f"; trf and lm {'agree' if result.methods_agree else 'DISAGREE'}"),
        "",
    ]
    lines += ["  ".join(cell.ljust(w) for cell, w in zip(r, widths, strict=True)).rstrip()
              for r in rows]
    lines += [
        "",
        f"residual norm (eq. 12): {_g(result.residual_ss_mm2)} mm^2 = "
        f"{_g(result.residual_ss_m2)} m^2 (RMS {_g(result.rms_residual_m * 1e3, 4)} mm per "
        "component)",
        f"loss {result.loss}; sigma: {_g(result.sigma_m * 1e3, 4)} mm from "
        f"{result.sigma_source}; CI95: {result.ci95_method}",
        f"condition number (Jacobian w.r.t. ln k): {_g(result.condition_number, 4)}",
    ]
    if result.rotation_residuals is not None:
        kinds = result.rms_by_kind
        rms_t, rms_r = kinds["translation_m"], kinds["rotation_rad"]
        sigma_r, weight = result.rotation_sigma_rad, result.rotation_weight_m_per_rad
        # a campaign with rotations has both kinds and their weight
        assert rms_t is not None and rms_r is not None and weight is not None
        lines.append(
            f"RMS by kind: translations {_g(rms_t * 1e3, 4)} mm, rotations "
            f"{_g(rms_r, 4)} rad (rotation noise std "
            f"{'-' if sigma_r is None else _g(sigma_r, 4)} rad from "
            f"{result.rotation_sigma_source}; rotations weighted by "
            f"{_g(weight, 4)} m/rad)")
    if result.undetermined_directions or result.undetermined_joints:
        lines.append("undetermined: " + (", ".join(result.undetermined_joints) or "no single "
                                          "stiffness, but combinations:"))
        for d in result.undetermined_directions:
            lines.append(f"  direction {d.description} (relative CI width "
                         f"{_g(d.relative_ci_width, 3)})")
    else:
        lines.append("undetermined: none")
    lines += describe_outliers(result.outliers)
    lines += [f"note: {n}" for n in result.notes]
    return "\n".join(lines)


def model_path(out: str) -> Path:
    """Where ``--out`` writes the model: the file named when it ends in ``.json`` (and is not
    a folder), else ``identified-model.json`` in the folder ``out``, as ``diagnose --out``.

    Raises
    ------
    OutputError
        The folder cannot be written into (checked before the fit, nothing made).
    """
    path = Path(out)
    is_file = path.suffix.lower() == ".json" and not out.endswith(("/", os.sep)) \
        and not path.is_dir()
    output_folder(path.parent if is_file else path, create=False)
    return path if is_file else path / MODEL_FILE


def run(args: argparse.Namespace) -> int:
    """Run ``stiffness identify``; returns the exit code."""
    show = sys.stderr.isatty() and not args.quiet

    def progress(done: int, total: int, text: str) -> None:
        sys.stderr.write(f"\rleast-squares run {done}/{total}" + ("\n" if done == total else ""))
        sys.stderr.flush()

    path = None if args.out is None else model_path(args.out)  # a bad --out fails at once
    result: IdentificationResult
    if campaign_kind(args.campaign) == "poses":
        result = poses = _identify_poses(args)
        report = poses.format
    else:
        result = ident = identify(
            load_campaign(args.campaign), formulation=args.formulation,
            method=args.method or "trf", starts=8 if args.starts is None else args.starts,
            seed=args.seed, progress=progress if show else None, loss=args.loss)
        report = functools.partial(format_table, ident)
    out = None if path is None else result.write_model(path)
    if args.json:
        print(result.to_json())
        return 0
    print(report())
    print("identified model not written (--out DIR or --out FILE.json writes it)"
          if out is None else f"identified model written to {out}")
    return 0


def _identify_poses(args: argparse.Namespace) -> PoseIdentification:
    """``stiffness identify`` on a pose campaign: the springs with the measuring frame and
    markers (:func:`~stiffness.calibration.pose_identify.identify_poses`)."""
    for flag, value in (("--formulation", args.formulation), ("--method", args.method),
                        ("--starts", args.starts)):
        if value is not None:
            raise StiffnessError(f"{flag} takes deflection campaigns; {args.campaign} is a "
                                 f"pose campaign, fitted at the sag's exact fixed point by "
                                 f"the pose engine: drop {flag}")
    show = sys.stderr.isatty() and not args.quiet
    return identify_poses(load_pose_campaign(args.campaign), loss=args.loss,
                          progress=(lambda text: print(text, file=sys.stderr, flush=True))
                          if show else None)
