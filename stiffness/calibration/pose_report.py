"""The text report of a pose diagnosis (``stiffness diagnose`` on a pose campaign; its output
folder is :meth:`~stiffness.calibration.result.DiagnosisResult.write`)."""

from __future__ import annotations

from stiffness.calibration.certainty import how_sure_lines
from stiffness.calibration.identifiability import IDENTIFIABILITY_TOL
from stiffness.calibration.outliers import describe_outliers
from stiffness.calibration.pose_diagnosis import PoseDiagnosis
from stiffness.calibration.pose_page import not_added
from stiffness.calibration.steps_table import stage_table, stages, step_lines


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
        lines += ["", *stage_table(named)]
    if d.rejected:
        lines.append("not added (dBIC or held-out RMS): "
                     + not_added(d.rejected, d.not_judged))
    if d.stop_reason:
        lines.append(f"search stopped: {d.stop_reason}")
    # the verdict on the fit's lengths (NOT A CALIBRATION) and the markers' offset notes
    lines += ["", *filter(None, [d.plausibility.verdict()]), *d.plausibility.notes(),
              d.verdict(), *describe_outliers(d.outliers), "",
              f"identifiability (tolerance {IDENTIFIABILITY_TOL:g}):"]
    lines += _dropped_lines(d)
    lines += ["", "fitted parameters (SI, 95 % interval; one-sided at a physical bound):"]
    for p in (p for p in summary["parameters"] if p["fitted"]):
        lo, hi = ("no bound" if v is None else f"{v:.5g}" for v in p["interval_95"])
        lines.append(f"  {p['parameter']:<42} {p['value']:>12.5g} {p['unit']:<10} "
                     f"[{lo}, {hi}]" + ("  at its lower bound" if p["at_bound"]
                                                else "")
                     + ("" if p.get("determined", True) else
                        f"  undetermined ({p['physical_scale']})") + _softening(p))
    return "\n".join(lines + _how_sure_lines(d, summary))


def _softening(p: dict) -> str:
    """Beside a nonlinear spring's ``gamma``, its row's ``beta = gamma / c``
    (:func:`~stiffness.calibration.pose_model_file.parameter_table`), where it has one."""
    beta = p.get("beta")
    return "" if beta is None else f"  beta = gamma/c = {beta['value']:.4g} {beta['unit']}"


def _how_sure_lines(d: PoseDiagnosis, summary: dict) -> list[str]:
    """The held parameters and how sure the diagnosis is of each family it added
    (``summary``: its ``--json`` object), in the words of a deflection diagnosis's report."""
    held = [p for ps in d.named_parameters().values() for p in ps
            if p.held.startswith("held at its nominal value")]
    lines = ["", "held at nominal (the data do not determine them):",
             *[f"  {p.text()}" for p in held]] if held else []
    return lines + (["", *how_sure_lines(summary)] if d.how_sure else [])


#: How the identifiability lines name a parameter left out, by its reason.
_DROPPED = {"no effect": "dropped", "undetermined": "held"}


def _dropped_lines(d: PoseDiagnosis) -> list[str]:
    ident = d.final.identifiability
    labels = d.final.labels()
    return [f"  fitted: {len(ident.kept)} parameters"] + [
        f"  {_DROPPED.get(item.reason, 'merged')} {labels[item.index]}: "
        f"{item.describe(labels)}" for item in ident.dropped]
