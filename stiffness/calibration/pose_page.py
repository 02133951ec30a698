"""The page of a pose diagnosis (``diagnosis.html``, the report of a pose campaign): the steps,
the residuals before and after per marker and axis (a figure per marker), the named families
with how sure each is, the stage table with its figure (the held-out error after each step,
bars per marker), the validation of the final model, the parameters, what the campaign
cannot identify and the poses flagged as outliers; built from :meth:`PoseDiagnosis.to_dict`
with the house template (:mod:`stiffness.htmlpage`)."""

from __future__ import annotations

import numpy as np

from stiffness.calibration.certainty import how_sure_table
from stiffness.calibration.fit_verdict import verdict_sentence
from stiffness.calibration.outliers import outliers_section
from stiffness.calibration.parameter_section import parameter_rows, parameter_table
from stiffness.calibration.steps_table import stage_section, steps_table
from stiffness.calibration.validation_page import stage_frame_lines, validation_section
from stiffness.figures import png
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
)

SECTIONS = {"summary": "Summary", "provenance": "Provenance", "steps": "Steps",
            "residuals": "Residuals before and after, per marker and axis",
            "how-sure": "Named effects: how sure", "stages": "Held-out error per stage",
            "validation": "Validation of the final model", "parameters": "Parameters",
            "identifiability": "What the campaign cannot identify",
            "outliers": "Poses flagged as outliers", "reproduce": "Reproduce"}
#: The figure's file name inside the page (embedded, not written beside it).
STAGE_FIGURE = "stages.png"


def not_added(rejected: dict[str, float], not_judged: dict[str, str]) -> str:
    """The families tried and not added, each with its last BIC change, or why the search
    dropped it without judging it (a screened BIC change of a fit that could not be made is
    no verdict); families in a row dropped for one reason share its note."""
    names = list(rejected)
    notes = [not_judged.get(f) for f in names]
    return ", ".join(f"{f} ({rejected[f]:+.3g})" if note is None
                     else f if notes[k + 1:k + 2] == [note] else f"{f} ({note})"
                     for k, (f, note) in enumerate(zip(names, notes, strict=True)))


def stage_plot(d: dict) -> bytes | None:
    """PNG: the held-out mean 3-D error after each step, a bar per marker and one for all of
    them, the standard deviation as a whisker and the maximum as a dot (campaign unit); ``None``
    without a validation campaign."""
    stages = [s for s in d["steps"] if s.get("validation")]
    if not stages:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = ["all", *stages[0]["validation"]["markers"]]
    width = 0.8 / len(names)
    fig, ax = plt.subplots(figsize=(max(6.0, 1.3 * len(stages) + 2), 4.2))
    x = np.arange(len(stages))
    for n, name in enumerate(names):
        cells = [s["validation"] if name == "all" else s["validation"]["markers"][name]
                 for s in stages]
        mean = np.array([np.nan if c["mean_error"] is None else c["mean_error"] for c in cells])
        std = np.array([np.nan if c["std_error"] is None else c["std_error"] for c in cells])
        top = np.array([np.nan if c["max_error"] is None else c["max_error"] for c in cells])
        at = x - 0.4 + width * (n + 0.5)
        ax.bar(at, mean, width, yerr=std, capsize=2, color=f"C{n}", label=name)
        ax.plot(at, top, ".", color="0.2", ms=4)
    noise = d.get("noise_std")
    if noise:  # the 3-D error of pure noise: sigma sqrt(3) in RMS
        ax.axhline(noise * np.sqrt(3), color="0.4", ls="--", lw=0.8,
                   label="noise (RMS of 3-D)")
    ax.set_xticks(x, [f"{i} {s['family']}" for i, s in enumerate(stages)], rotation=20,
                  ha="right", fontsize=8)
    ax.set_yscale("log")
    ax.set_ylabel(f"held-out 3-D error ({d['unit']})")
    ax.set_title("mean ± std (bars), max (dots) after each step", fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    image = png(fig, dpi=100)
    plt.close(fig)
    return image


def _residuals(d: dict, residual_pngs: dict[str, bytes] | None) -> list[str]:
    """The final residual by marker and axis, its trend along the rows, and a figure per
    marker (before and after)."""
    unit, rs = d["unit"], d["residual_structure"]
    rows = ([[f"marker {esc(m)}", v] for m, v in rs["rms_by_marker"].items()]
            + [[f"axis {esc(a)}", v] for a, v in rs["rms_by_axis"].items()])
    parts = [table(f"Final residual RMS by marker and by axis ({unit})", ["where", "RMS"],
                   rows, "Measured minus predicted marker positions under the final model, "
                   "per component.")]
    trend = [[esc(a), t["slope_per_row"], t["correlation"]]
             for a, t in rs["row_trend"].items()]
    if trend:
        parts.append(table("Final residual's trend along the rows",
                           ["axis", f"slope ({unit} per row)", "correlation with the row"],
                           trend, "A drift in time (temperature, tracker) shows as a strong "
                           "correlation."))
    for name, image in (residual_pngs or {}).items():
        parts.append(figure(f"residuals-{name}.png", image,
                            f"Marker {name}: residual x, y, z ({unit}) per row, before (the "
                            "tracker placement and marker offsets only) and after (the final "
                            "model)"))
    return parts


def render_pose_diagnosis(d: dict, stage_png: bytes | None, prov: dict,
                          residual_pngs: dict[str, bytes] | None = None) -> str:
    """The page of a pose diagnosis.

    Parameters
    ----------
    d
        :meth:`~stiffness.calibration.pose_diagnose.PoseDiagnosis.to_dict` (lengths in the
        campaign's unit ``d["unit"]``).
    stage_png
        :func:`stage_plot`, embedded if given.
    prov
        :func:`stiffness.provenance.provenance`.
    residual_pngs
        :func:`~stiffness.calibration.pose_diagnosis.marker_residual_plots`: a figure per
        marker, embedded if given.
    """
    unit = d["unit"]
    title = f"Pose diagnosis of campaign {d['campaign']}" + (
        f" ({d['robot_name']})" if d.get("robot_name") else "")
    verdict = ("noise not declared" if d["unexplained"] is None else
               "UNEXPLAINED" if d["unexplained"] else "explained to noise")
    plausibility = d.get("plausibility") or {}
    if plausibility.get("verdict"):  # the fit is no calibration, whatever its chi-square
        verdict = f"{plausibility['verdict']} (chi-square: {verdict})"
    parts = [f"<h1>{esc(title)}</h1>", heading("summary", SECTIONS),
             table("What the diagnosis finds", ["quantity", "value"], [
                 ["families", esc(", ".join(d["families"]))],
                 [f"final RMS residual ({unit})", d["steps"][-1]["rms"]],
                 [f"noise standard deviation ({unit})", d["noise_std"]],
                 ["chi-square p of the final residual", d["gof_p"]],
                 ["verdict", esc(verdict)], ["masses", esc(d["masses"])],
                 ["poses flagged as outliers", len(d.get("outliers", []))],
                 ["loss", esc(d["loss"])]],
                 "RMS over all residual components, in the campaign's length unit."),
             f"<p>{esc(verdict_sentence(d))}.</p>", contents(SECTIONS),
             heading("provenance", SECTIONS), provenance_block(prov),
             heading("steps", SECTIONS)]
    parts.append(steps_table(d["steps"], unit))
    parts += [f"<p>Step {i} refused {esc(what)}: {esc(why)}</p>" for i, step in
              enumerate(d["steps"]) for what, why in (step.get("refused") or {}).items()]
    if d["rejected"]:
        parts.append("<p>Not added (ΔBIC or held-out RMS): "
                     + esc(not_added(d["rejected"], d.get("not_judged", {}))) + "</p>")
    parts += [heading("residuals", SECTIONS), *_residuals(d, residual_pngs),
              heading("how-sure", SECTIONS),
              *(how_sure_table(d) or ["<p>No effect named beyond the tracker placement and "
                                      "the marker offsets.</p>"]), heading("stages", SECTIONS)]
    if stage_png is None:
        parts.append("<p>No validation campaign: run <code>stiffness diagnose --validate "
                     "OTHER_CAMPAIGN</code> for the held-out error after each step.</p>")
    else:
        parts += stage_section(d)
        parts += [f"<p>{esc(line)}</p>" for line in stage_frame_lines(d)]
        parts.append(figure(STAGE_FIGURE, stage_png,
                            f"Held-out 3-D marker error after each step ({unit})"))
    how = ("run <code>stiffness diagnose CAMPAIGN --validate OTHER_CAMPAIGN</code> (or "
           "<code>stiffness report CAMPAIGN --validate OTHER_CAMPAIGN</code>) to evaluate the "
           "final model on measurements it was not fitted to")
    parts += [heading("validation", SECTIONS),
              *validation_section(d["steps"][-1].get("validation"), how),
              heading("parameters", SECTIONS),
              *_parameters(d)]
    parts += [heading("outliers", SECTIONS), *outliers_section(d)]
    parts.append(reproduce_block(prov, "reproduce", SECTIONS,
                                 "The run writes this page, diagnosis.json and "
                                 "final-model.json."))
    return page(title, parts)


def _parameters(d: dict) -> list[str]:
    """The fitted parameters with their intervals, then what the campaign cannot identify."""
    parts = [parameter_table([row for p in d["parameters"] if p["fitted"]
                              for row in parameter_rows(p["family"], {p["parameter"]: p})]),
             heading("identifiability", SECTIONS)]
    dropped = d["identifiability"]["dropped"]
    rows = [[esc(x["parameter"]), esc(x["reason"]), esc(" + ".join(
        f"{num(m['coefficient'], 3)} × {m['parameter']}" for m in x["merged_into"][:3]))]
        for x in dropped]
    parts.append(table("Parameters left out",
                       ["parameter", "reason", "acts on the data as (SI)"], rows,
                       "No effect: it moves no marker; merged: a combination of kept ones.")
                 if rows else "<p>Every parameter of the final model is identifiable.</p>")
    return parts
