"""``diagnosis.html``: the page of ``stiffness diagnose --out``, in the report's template.

Rendered from :meth:`stiffness.calibration.diagnosis.Diagnosis.record` (campaign units): the
residuals before and after, the effects added step by step with their BIC gain and RMS, the
parameters with 95 % intervals, the verdict on what is left (explained to noise, or
*unexplained*) with the final residual's structure (by load direction and row order, and its
correlation with each joint's torque and angle), and what the campaign cannot tell apart with
the poses and loads that would, and each step's model and the final model on a validation
campaign (``--validate``).
"""

from __future__ import annotations

from stiffness.calibration.certainty import how_sure_table
from stiffness.calibration.fit_verdict import verdict_sentence
from stiffness.calibration.outliers import outliers_section
from stiffness.calibration.parameter_section import parameter_rows, parameter_table
from stiffness.calibration.steps_table import scored_steps, stage_section, steps_table
from stiffness.calibration.validation_page import validation_section
from stiffness.htmlpage import (
    contents,
    esc,
    figure,
    heading,
    num,
    page,
    provenance_block,
    reproduce_block,
    table,
    vec,
)

SECTIONS = {
    "summary": "Summary",
    "provenance": "Provenance",
    "residuals": "Residuals before and after",
    "steps": "Effects added, step by step",
    "parameters": "Parameters with 95 % intervals",
    "outliers": "Rows flagged as outliers",
    "left": "What is left: the final residual's structure",
    "ambiguities": "What this campaign cannot tell apart",
    "validation": "Validation of the final model",
    "reproduce": "Reproduce this",
}


#: What the validation section says without a validation campaign.
HOW = ("the cross-validated RMS of each step (above) is the held-out check within this "
       "campaign; <code>stiffness diagnose CAMPAIGN --validate OTHER_CAMPAIGN</code> evaluates "
       "the final model on another campaign of the same robot without refitting")


def _by_configuration(before: dict, after: dict, unit: str) -> str:
    rows = []
    for label, b in before["by_configuration"].items():
        a = after["by_configuration"].get(label, {})
        rows.append([esc(label), b["rows"], b["rms"], b["ratio"], a.get("rms"), a.get("ratio")])
    return table("Residuals by configuration", ["configuration", "rows",
                 f"RMS before ({unit})", "before, in noise std", f"RMS after ({unit})",
                 "after, in noise std"], rows,
                 "Before: the baseline model; after: with every effect added. In noise std: "
                 "the RMS over the noise standard deviation (about 1 where the model explains "
                 "the data).")


def _verdict(d: dict) -> str:
    flag = d.get("unexplained")
    word = "not tested" if flag is None else ("<b>yes</b>" if flag else "no")
    return f"{word}: {esc(verdict_sentence(d))}"


def _group_rows(groups: dict) -> list[list]:
    return [[esc(k), g["rows"], g["rms"], g["ratio"], vec(g["mean"]) if g.get("mean")
             else "-"] for k, g in groups.items()]


def _correlation_rows(corr: dict, label: str) -> list[list]:
    rows = []
    for name, c in corr.items():
        if c["r2"] is None:
            rows.append([esc(label.format(name)), "-", "-", "-", "constant"])
            continue
        rows.append([esc(label.format(name)), vec(c["r"], 2), c["r2"], c["explained_ratio"],
                     c["p_value"]])
    return rows


def _left(d: dict, unit: str) -> list[str]:
    """The final residual's structure."""
    after = d["where_final_disagrees"]
    parts = [f"<p>{esc(verdict_sentence(d))}.</p>"]
    if "by_load_direction" not in after:
        return parts
    head = ["group", "rows", f"RMS ({unit})", "in noise std", f"mean dx, dy, dz ({unit})"]
    parts.append(table("Final residual by configuration, axis and load", head,
                       _group_rows(after["by_configuration"])
                       + [[esc(k), "", g["rms"], g["ratio"], num(g["mean"])]
                          for k, g in after["by_axis"].items()]
                       + [[f"{num(g['force_range'][0])} to {num(g['force_range'][1])} N", g["rows"],
                           g["rms"], g["ratio"], vec(g["mean"]) if g.get("mean") else "-"]
                          for g in after["by_load_magnitude"]],
                       "Per configuration, per axis (its mean is the bias) and per load-"
                       "magnitude tercile."))
    parts.append(table("Final residual by load direction and by row order", head,
                       _group_rows({f"load nearest {k}": g
                                    for k, g in after["by_load_direction"].items()})
                       + _group_rows({f"rows {g['row_range'][0]} to {g['row_range'][1]}": g
                                      for g in after["by_row_order"]}),
                       "Load direction: rows grouped by the axis nearest to their force. Row "
                       "order: consecutive blocks of rows in the file's order (a drift in time "
                       "shows here)."))
    corr = after["correlation"]
    rows = (_correlation_rows(corr["joint_torque"], "torque of {}")
            + _correlation_rows(corr["joint_angle"], "angle of {}")
            + _correlation_rows(corr["load_direction"], "load direction {}")
            + _correlation_rows({"": corr["load_magnitude"]}, "load magnitude{}")
            + _correlation_rows({"": corr["row_order"]}, "row order{}"))
    parts.append(table("Correlation of the final residual with each joint's torque and angle",
                       ["variable", "r with dx, dy, dz", "R² (share explained)",
                        "explained RMS (noise std)", "p-value"], rows,
                       "A straight line in the variable fitted to each residual axis: its "
                       "correlations, the share of the residual it explains pooled over the "
                       "axes, that part's RMS in noise std, and the F-test p-value. Large "
                       "shares with small p-values say where to look."))
    return parts


def _ambiguities(ambiguities: list[dict], unit: str) -> list[str]:
    """The ambiguities section: each effect added against its runner-up, and the poses and
    loads that would tell them apart."""
    parts = []
    if not ambiguities:
        parts.append("<p>None: every effect added is distinguishable from its runner-up.</p>")
    for a in ambiguities:
        parts.append(f"<p>Step {a['step']}: <b>{esc(a['chosen'])}</b> against "
                     f"<b>{esc(a['other'])}</b>, {esc(a['reason'])}.</p>")
        proposals = a.get("proposals", [])
        parts += [f"<p>{esc(p['note'])}</p>" for p in proposals if "note" in p]
        rows = [[vec(p["q"], 2), vec(p["force"], 1), vec(p["deflection_chosen"]),
                 vec(p["deflection_other"]), p["separation_noise_units"]]
                for p in proposals if "note" not in p]
        if rows:
            parts.append(table(f"Poses and loads that would tell {a['chosen']} from "
                               f"{a['other']}",
                               ["q (deg; m prismatic)", "force (N)",
                                f"deflection, {a['chosen']} ({unit})",
                                f"deflection, {a['other']} ({unit})",
                                "separation (noise std)"], rows,
                               "Each row a proposed measurement; separation: the difference "
                               "of the two predicted deflections over the noise."))
    return parts


def _steps(d: dict, unit: str) -> list[str]:
    """The steps' table and each step's best candidates."""
    parts: list[str] = []
    parts.append(steps_table(scored_steps(d), unit))
    for i, detail in enumerate(d["step_details"]):
        ranked = [[esc(r.get("effect", "")), esc(r.get("where") or ""), r.get("delta_bic"),
                   r.get("cv_rms")] for r in detail["ranking"][:6]]
        if ranked:
            parts.append(table(f"Step {i + 1}: the best candidates",
                               ["effect", "where", "ΔBIC", f"held-out RMS ({unit})"],
                               ranked, "The six best-ranked candidate effects of this step."))
    return parts


def render_diagnosis(d: dict, residuals_png: bytes | None, prov: dict) -> str:
    """The page.

    Parameters
    ----------
    d
        :meth:`~stiffness.calibration.diagnosis.Diagnosis.record` (lengths in the campaign's
        unit ``d["unit"]``).
    residuals_png
        The residual plot (before and after), embedded if given.
    prov
        :func:`stiffness.provenance.provenance`.
    """
    unit = d["unit"]
    title = f"Diagnosis of campaign {d['campaign']}" + (
        f" ({d['robot_name']})" if d.get("robot_name") else "")
    parts = [f"<h1>{esc(title)}</h1>", heading("summary", SECTIONS),
             table("What the diagnosis finds", ["quantity", "value"], [
                 ["baseline model", esc(d["baseline"])],
                 [f"baseline RMS residual ({unit})", d["baseline_rms"]],
                 [f"noise standard deviation ({unit})",
                  f"{num(d['noise_std'])} ({esc(d['noise_std_source'])})"],
                 ["effects added", esc(", ".join(d["final_parameters"]) or "none")],
                 [f"final RMS residual ({unit})", d["final_rms"]],
                 ["final model", esc(d["final_model"])],
                 ["why it stopped", esc(d["stop_reason"])],
                 ["loss", esc(d.get("loss", "linear"))],
                 ["link masses", esc(d.get("masses", "known"))],
                 ["rows flagged as outliers", len(d.get("outliers", []))],
                 ["unexplained", _verdict(d)],
                 ["measurements", f"{d['rows']} rows, {d['configurations']} configurations"],
             ], "RMS over all residual components, in the campaign's length unit."),
             contents(SECTIONS), heading("provenance", SECTIONS),
             provenance_block(prov, [("campaign", f"<code>{esc(d['campaign_path'])}</code>"
                                      if d.get("campaign_path") else "built in memory")]),
             heading("residuals", SECTIONS)]
    if d.get("noise_std_note"):
        parts.append(f"<p>{esc(d['noise_std_note'])}</p>")
    if residuals_png:
        parts.append(figure("residuals.png", residuals_png,
                            f"Residual components ({unit}) before and after the effects"))
    parts.append(_by_configuration(d["where_baseline_disagrees"], d["where_final_disagrees"],
                                   unit))
    parts.append(heading("steps", SECTIONS))
    parts += _steps(d, unit)
    parts += how_sure_table(d)
    parts.append(heading("parameters", SECTIONS))
    rows = parameter_rows("joint stiffness", d["final_stiffness"])
    for label, params in d["final_parameters"].items():  # the final fit's, not each step's
        rows += parameter_rows(label, params)
    parts.append(parameter_table(rows))
    parts.append(heading("outliers", SECTIONS))
    parts += outliers_section(d)
    parts.append(heading("left", SECTIONS))
    parts += _left(d, unit)
    parts.append(heading("ambiguities", SECTIONS))
    parts += _ambiguities(d["cannot_tell_apart"], unit)
    parts += [heading("validation", SECTIONS), *stage_section(d),
              *validation_section(d.get("validation"), HOW)]
    parts.append(reproduce_block(prov, "reproduce", SECTIONS,
                                 "The run writes this page, diagnosis.json, residuals.png and "
                                 "final-model.json."))
    return page(title, parts)
