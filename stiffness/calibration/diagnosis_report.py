"""The diagnosis as text: the report ``stiffness diagnose`` prints."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from stiffness.calibration.breakdown import strongest_correlations
from stiffness.calibration.certainty import how_sure_lines
from stiffness.calibration.fit_verdict import fit_lines, verdict_line
from stiffness.calibration.naming import STAND_IN_NOTE
from stiffness.calibration.outliers import describe_outliers
from stiffness.calibration.parameter_section import parameter_lines
from stiffness.calibration.selection import above_noise, noise_overstated
from stiffness.calibration.steps_table import stage_table, stages, step_lines

if TYPE_CHECKING:  # annotations only
    from stiffness.calibration.diagnosis import Diagnosis


def _disagreement_lines(d: dict, force_unit: str) -> list[str]:
    def cell(g: dict) -> str:
        return f"{g['rms']:.4g} ({g['ratio']:.2g}x)" if g["rows"] else "-"

    lines = ["  by configuration: " + ", ".join(
        f"{k} {cell(g)}" for k, g in d["by_configuration"].items())]
    lines.append("  by axis: " + ", ".join(
        f"{k} {g['rms']:.4g} ({g['ratio']:.2g}x, mean {g['mean']:+.3g})"
        for k, g in d["by_axis"].items()))
    lines.append("  by load magnitude: " + ", ".join(
        f"[{g['force_range'][0]:.4g}, {g['force_range'][1]:.4g}] {force_unit} {cell(g)}"
        for g in d["by_load_magnitude"]))
    lines.append("  by load sign: " + ", ".join(
        f"{k}>0 {cell(g['positive'])} {k}<0 {cell(g['negative'])}"
        for k, g in d["by_load_sign"].items()))
    if "by_load_direction" in d:
        lines.append("  by load direction (nearest axis): " + ", ".join(
            f"{k} {cell(g)}" for k, g in d["by_load_direction"].items()))
        lines.append("  by row order: " + ", ".join(
            f"rows {g['row_range'][0]}-{g['row_range'][1]} {cell(g)}"
            for g in d["by_row_order"]))
        strongest = strongest_correlations(d)
        if strongest:
            lines.append("  strongest correlations (share of the residual a straight line in "
                         "the variable explains):")
            for c in strongest:
                lines.append(f"    {c['variable']}: R2 {c['r2']:.2g}, "
                             f"{c['explained_ratio']:.2g} noise std RMS, "
                             f"p = {c['p_value']:.2g}")
    return lines


def format_report(d: Diagnosis) -> str:
    """The human-readable report of ``stiffness diagnose``."""
    c, unit, summary = d.campaign, d.unit, d.record()
    lu = c.units.length_to_si
    lines = [
        f"campaign {c.name}" + (f" ({c.path})" if c.path else "")
        + f" of {d.geometry.robot.title}: {c.n_rows} rows, {len(set(c.config))} "
          f"configurations, {3 * c.n_rows} residual components; lengths in {unit}",
        f"baseline: {d.baseline.model.describe()}; RMS {d.baseline.rms() / lu:.4g} {unit}",
        f"noise std: {d.noise_std_m / lu:.4g} {unit} ({d.noise_std_source}: {d.noise_note})",
    ]
    if d.gof_baseline is not None:
        verdict = "does NOT fit" if above_noise(d.gof_baseline) else "fits"
        lines.append(f"the baseline {verdict} to noise ({d.test} p = {d.gof_baseline:.3g})")
    lines += ["", f"where the baseline disagrees (RMS in {unit}, and in noise std):"]
    lines += _disagreement_lines(d.baseline_disagreement, c.units.force)
    one = [] if len(set(c.config)) > 1 else [
        "CV RMS: one configuration, held out one load at a time; an effect is named only "
        "where the rows without a load keep more residual components than its parameters and "
        "its fit is not below the noise" if math.isfinite(d.cv_baseline) else
        "CV RMS -: one configuration with one load, none to hold out: nothing is named"]
    lines += ["", *step_lines(summary, one)]
    if named := stages(summary):  # diagnose --validate: each step's model on the other one
        lines += ["", *stage_table(named)]
    lines.append("")
    if d.named_steps:
        lines.append("identified effects (final model; 95 % intervals):")
        for s in d.named_steps:
            stand_in = f" STAND-IN: {STAND_IN_NOTE}" if d.stand_in(s.effect.label) else ""
            lines.append(f"  {s.effect.label}: {s.effect.describe()}{stand_in}")
            lines += parameter_lines(summary["final_parameters"].get(s.effect.label, {}), "    ")
        found = [s.effect.label for s in d.named_steps if not d.stand_in(s.effect.label)]
        lines.append("missing effects: " + (", ".join(found) or "none found physical"))
        lines += how_sure_lines(summary)
    else:
        lines.append("missing effects: none" + (
            " (the baseline explains the data to noise)" if d.gof_baseline is not None
            and not above_noise(d.gof_baseline) else ""))
    lines += ["stiffness (final model; 95 % intervals):",
              *parameter_lines(summary["final_stiffness"])]
    if d.unexplained:  # identify's note on a fit above the noise, said where the numbers are
        lines.append("  these 95 % intervals (and the effects') take the final model as "
                     "complete: too narrow while it misses something (UNEXPLAINED, below)")
    lines += fit_lines(summary)
    if d.unexplained is False and noise_overstated(d.gof_final):
        lines.append(f"note: {verdict_line(summary)}")
    lines += describe_outliers(d.outliers)
    if d.unexplained:
        lines += ["", f"{verdict_line(summary)}.",
                  f"where the final model disagrees (RMS in {unit}, and in noise std):"]
        lines += _disagreement_lines(d.final_disagreement, c.units.force)
    if d.rotation_noise_std_rad is not None:
        kinds, ru = d.rms_by_kind(), d.campaign.units.rotation
        lines.append(f"RMS by kind: translations {kinds['baseline']['translation']:.4g} -> "
                     f"{kinds['final']['translation']:.4g} {unit}, rotations "
                     f"{kinds['baseline']['rotation']:.4g} -> {kinds['final']['rotation']:.4g} "
                     f"{ru} (rotation noise std "
                     f"{d.rotation_noise_std_rad / d.campaign.units.rotation_to_si:.4g} {ru}, "
                     f"{d.rotation_noise_source})")
    if d.ambiguities:
        lines += ["", "cannot tell apart:"]
        for a in d.ambiguities:
            cv = " against ".join(f"{v / lu:.4g} {unit}" if v is not None and math.isfinite(v)
                                  else "not cross-validated" for v in a.cv_rms)
            lines.append(f"  step {a.step}: {a.chosen} vs {a.other}: {a.reason}; dBIC "
                         f"{a.delta_bic:+.3g}, CV RMS {cv}, signature similarity "
                         f"{a.similarity:.3f}; their predictions differ by {a.separation:.3g} "
                         "noise std RMS over this campaign")
            for proposal in a.proposals:
                if "note" in proposal:
                    lines.append(f"    {proposal['note']}")
                    continue
                q = ", ".join(f"{v:.4g}" for v in proposal["q"])
                f = ", ".join(f"{v:.4g}" for v in proposal["force"])
                lines.append(f"    measure q = [{q}] {c.units.angle}, F = [{f}] "
                             f"{c.units.force}: predicted difference "
                             f"{proposal['separation_noise_units']:.3g} noise std")
    return "\n".join(lines)
