"""The text report of a pose diagnosis (``stiffness diagnose`` on a pose campaign; its output
folder is :meth:`~stiffness.calibration.result.DiagnosisResult.write`)."""

from __future__ import annotations

from stiffness.calibration.certainty import how_sure_lines
from stiffness.calibration.fit_verdict import fit_lines, verdict_line
from stiffness.calibration.identifiability import IDENTIFIABILITY_TOL, Identifiability
from stiffness.calibration.outliers import describe_outliers
from stiffness.calibration.parameter_section import parameter_lines
from stiffness.calibration.pose_diagnosis import PoseDiagnosis
from stiffness.calibration.pose_page import not_added
from stiffness.calibration.steps_table import stage_table, stages, step_lines
from stiffness.calibration.validation_page import stage_frame_lines


def format_pose_report(d: PoseDiagnosis) -> str:
    """The human-readable report of a pose diagnosis (lengths in the campaign's unit)."""
    c, summary = d.campaign, d.summary()
    unit, lu = c.units.length, c.units.length_to_si
    noise = "not declared" if c.noise_std is None else f"{c.noise_std / lu:.4g} {unit}"
    lines = [f"pose campaign {c.name} of {c.robot.title}: {c.n_rows} rows, "
             f"{len(c.markers)} marker(s) ({', '.join(m.name for m in c.markers)}), "
             f"{c.n_observed} measured components; noise std {noise}; masses {d.masses}; "
             f"loss {d.loss}",
             ""]
    lines += step_lines(summary, [
        "CV RMS: leave one configuration out (linearised hat matrix; unbounded: one "
        "configuration alone determines a parameter)" + ("" if d.loss == "linear" else
        f"; under {d.loss}, the root of the held-out loss per component: the RMS for Gaussian "
        "residuals, less for large ones, not comparable with RMS")])
    if named := stages(summary):
        lines += ["", *stage_table(named), *stage_frame_lines(summary)]
    if d.rejected:
        lines.append("not added (dBIC or held-out RMS): "
                     + not_added(d.rejected, d.not_judged))
    lines += fit_lines(summary)
    # the verdict on the fit's lengths (NOT A CALIBRATION) and the markers' offset notes
    lines += ["", *filter(None, [d.plausibility.verdict()]), *d.plausibility.notes(),
              verdict_line(summary), *describe_outliers(d.outliers), "",
              f"identifiability (tolerance {IDENTIFIABILITY_TOL:g}):"]
    lines += dropped_lines(d.final.identifiability, d.final.labels())
    rows = {p["parameter"]: p for p in summary["parameters"]}
    held = {k: p for k, p in rows.items() if (p.get("held") or "").startswith("held at its "
                                                                             "nominal value")}
    lines += ["", "fitted parameters (SI, 95 % intervals):",
              *parameter_lines({k: p for k, p in rows.items() if p["fitted"]})]
    if held:
        lines += ["", "held at nominal (the data do not determine them):",
                  *parameter_lines(held)]
    lines += ["", *_frame_lines(summary["measuring_frame"], unit)]
    return "\n".join(lines + (["", *how_sure_lines(summary)] if d.how_sure else []))


def _frame_lines(frame: dict, unit: str) -> list[str]:
    """The fitted measuring frame whole (the ``frame`` parameters above are its correction
    to the starting estimate, not the frame)."""
    t, r = frame["translation"], frame["rotation_vector_deg"]
    return ["measuring frame (the robot world in the measuring system's axes, y = R p + t; "
            "the frame parameters are its correction to the starting estimate):",
            f"  t = ({t[0]:.6g}, {t[1]:.6g}, {t[2]:.6g}) {unit}, R = rotation vector "
            f"({r[0]:.6g}, {r[1]:.6g}, {r[2]:.6g}) deg"]


#: How the identifiability lines name a parameter left out, by its reason.
_DROPPED = {"no effect": "dropped", "undetermined": "held"}


#: More parameters without effect than this are printed as one line naming their owners (a
#: humanoid's legs, head and other arm under a one-arm campaign: 115 lines on FIGAROH's TALOS).
NO_EFFECT_LISTED = 6

#: Owners (joints, markers, frames) that line names before "and N more".
_OWNERS_NAMED = 8


def dropped_lines(ident: Identifiability, labels: list[str]) -> list[str]:
    """The identifiability section's lines: the number fitted, then each parameter left out
    with its reason; more than :data:`NO_EFFECT_LISTED` with no effect on the data (joints no
    marker moves with) as one line naming their owners, the first word of their labels
    (every one stays in the JSON's ``identifiability.dropped``)."""
    none = [labels[item.index] for item in ident.dropped if item.reason == "no effect"]
    grouped = len(none) > NO_EFFECT_LISTED
    lines = [f"  fitted: {len(ident.kept)} parameters"]
    if grouped:
        owners = list(dict.fromkeys(name.split(" ")[0] for name in none))
        more = len(owners) - _OWNERS_NAMED
        lines.append(f"  dropped {len(none)} parameters of {len(owners)} joints or frames: no "
                     "effect on the data (nothing measured moves with them): "
                     + ", ".join(owners[:_OWNERS_NAMED])
                     + (f" and {more} more" if more > 0 else "") + " (each one in --json)")
    return lines + [f"  {_DROPPED.get(item.reason, 'merged')} {labels[item.index]}: "
                    f"{item.describe(labels)}" for item in ident.dropped
                    if not (grouped and item.reason == "no effect")]
