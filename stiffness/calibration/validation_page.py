"""A model's validation (either campaign kind): the final model's 3-D error on a campaign it
was not fitted to, overall and per marker (a deflection campaign's one "marker" is its target),
and the verdict against that campaign's noise when there is one (and which test it is: with the
model's parameter uncertainty, or the noise only); the section of the diagnosis pages and the
text of ``stiffness validate`` and ``diagnose --validate``."""

from __future__ import annotations

import numpy as np

from stiffness.calibration.outliers import OUTLIER_THRESHOLD, Outlier, describe_outliers
from stiffness.calibration.steps_table import refit_words, refitted, stage_table, stages
from stiffness.htmlpage import esc, table

#: The error keys of a validation record, in the table's order.
ERROR_KEYS = ("rms", "mean_error", "std_error", "max_error")


def validation_section(v: dict | None, how: str) -> list[str]:
    """The section's HTML parts.

    Parameters
    ----------
    v
        :func:`~stiffness.calibration.pose_register.validation_errors`,
        :func:`~stiffness.calibration.validation.deflection_errors` or
        :meth:`~stiffness.calibration.validation.Validation.to_dict` (campaign length unit);
        ``None``: no validation campaign.
    how
        HTML saying how to give one (shown when ``v`` is None).
    """
    if not v:
        return [f"<p>No validation campaign: {how}.</p>"]
    unit = v["unit"]
    headers = ["marker", "rows"] + [f"{k.split('_')[0]} ({unit})" for k in ERROR_KEYS]
    rotation = "rotation_rms" in v
    if rotation:
        headers += [f"rotation {k} ({v['rotation_unit']})" for k in ("RMS", "mean", "max")]

    def row(name: str, cell: dict) -> list:
        out = [esc(name), cell.get("rows", "")] + [cell[k] for k in ERROR_KEYS]
        return out + ([cell.get(f"rotation_{k}") for k in ("rms", "mean_error", "max_error")]
                      if rotation else [])

    parts = []
    if v.get("campaign"):
        parts.append(f"<p>Validation campaign: <code>{esc(v['campaign'])}</code>.</p>")
    parts.append(table(f"Final model on the validation campaign ({v['rows']} rows)", headers,
                       [row("all", v)] + [row(n, m) for n, m in v["markers"].items()],
                       "3-D position error (measured minus predicted) of the final model "
                       + refitted(v) + ": RMS, mean, standard deviation and maximum of its "
                       "norm."))
    if v.get("verdict"):  # the text's words (format_validation)
        parts.append(f"<p>{esc(_noise_verdict(v))}</p>")
    return parts


def format_validation(result: dict) -> str:
    """The text of ``stiffness validate``: overall and per-marker 3-D errors, the verdict
    against the campaign's noise, then the line of the stage table
    (:func:`~stiffness.calibration.steps_table.stage_table`) for this one model."""
    lines = [f"{result['rows']} rows; 3-D position error in {result['unit']}:",
             f"  {'':<12} {'RMS':>11} {'mean':>11} {'std':>11} {'max':>11} {'seen':>6}",
             *(_validation_row(n, r) for n, r in [("all", result), *result["markers"].items()])]
    flagged = describe_outliers([Outlier(**o) for o in result.get("outliers", [])],
                                result.get("outlier_threshold", OUTLIER_THRESHOLD))
    return "\n".join(lines + frame_lines(result) + [_noise_verdict(result)] + (
        flagged if result.get("verdict") is not None else []) + ["", *stage_table(
            [("model", result)])])


#: A model's frame registered anew that leaves at most this share of the 3-D RMS says the
#: campaign's measuring frame is not the model's.
FRAME_SHARE = 0.5


def frame_lines(result: dict, whose: str = "the model's",
                judged: str = "the errors and the verdict",
                campaign: str = "this campaign") -> list[str]:
    """What registering the measuring frame anew says (``result``: a validation object with
    ``rms`` and ``frame_refit``): after ``--refit-frame``, the motion fitted; without it, when
    it would leave at most :data:`FRAME_SHARE` of the RMS, that the error is mostly the
    frame's, with the flag. ``whose`` frame it moved from, what ``judged`` is after it and
    the ``campaign`` name the model and the campaign (``diagnose --validate``: the final
    model's, each step's errors, the validation campaign)."""
    frame = result.get("frame_refit")
    if not frame or frame["rms"] is None or result["rms"] is None:
        return []
    t = np.asarray(frame["translation"], dtype=float)
    angle = float(np.linalg.norm(frame["rotation_deg"]))
    motion = f"{np.linalg.norm(t):.4g} {frame['unit']} and {angle:.3g} deg"
    if frame["applied"]:
        return [f"{refit_words(frame['families'])} fitted to {campaign}: the frame moved by "
                f"{motion} from {whose}; "
                f"{judged} are after it ({frame['parameters']} parameters)"]
    if frame["rms"] > FRAME_SHARE * result["rms"]:
        return []
    return [f"note: the error is mostly the measuring frame's: {whose} frame moved by "
            f"{motion} leaves an RMS of {frame['rms']:.4g} {frame['unit']} "
            f"({frame['rms'] / result['rms']:.2g} of it); a campaign of another day or with "
            "the tracker moved is judged with --refit-frame"]


def stage_frame_lines(d: dict) -> list[str]:
    """:func:`frame_lines` of a diagnosis's stage table (``diagnose --validate``, its
    ``--json`` object ``d``): the final step's registration, what every step's errors are
    after with ``--refit-frame`` (none without a validation campaign)."""
    named = stages(d)
    return frame_lines(named[-1][1], "the final model's", "each step's errors",
                       "the validation campaign") if named else []


def _noise_verdict(result: dict) -> str:
    """The verdict line of ``stiffness validate`` against the campaign's declared noise."""
    if result.get("verdict") is None:
        return "no noise declared in the campaign: no verdict (declare [measurement] noise_std)"
    line = (f"verdict: {result['verdict'].upper()} (RMS {result['rms_over_noise']:.3g}x the "
            f"noise {result['noise_std']:.4g} {result['unit']} per axis; ")
    line = _rotations_said(result, line)
    if result.get("gof_p_with_parameters") is None:
        return (line + f"chi-square {result['chi2']:.4g} on {result['dof']} components, "
                f"p = {result['gof_p']:.3g}; the noise only: the model file carries no "
                "parameter covariance, its parameters' uncertainty is not included)")
    uncertainty = result["parameter_uncertainty"]
    left = uncertainty["left_out"]
    return (line + f"chi-square with the model's parameter uncertainty "
            f"{result['chi2_with_parameters']:.4g} on {result['dof']} components, "
            f"p = {result['gof_p_with_parameters']:.3g}; the parameters add "
            f"{uncertainty['prediction_variance_share']:.3g} of the noise variance"
            + (f", {len(left)} its fit did not determine taken as exact ({', '.join(left)})"
               if left else "")
            + f"; the noise alone: chi-square {result['chi2']:.4g}, p = {result['gof_p']:.3g})")


def _rotations_said(result: dict, line: str) -> str:
    """``line`` with what the test takes of the measured rotations: how many components at
    their own noise, or that they are not tested (no rotation noise declared)."""
    if result.get("rotation_components"):
        return line + (f"{result['rotation_components']} of the components rotations at their "
                       f"noise {result['rotation_noise_std']:.4g} {result['rotation_unit']}; ")
    if result.get("rotation_rms") is not None:
        return line + ("rotations measured but not tested: declare [measurement] "
                       "rotation_noise_std; ")
    return line


def _validation_row(name: str, r: dict) -> str:
    return f"  {name:<12} " + ("never seen" if r["rms"] is None else " ".join(
        f"{r[k]:>11.4g}" for k in ERROR_KEYS) + f" {r['rows']:>6}")
