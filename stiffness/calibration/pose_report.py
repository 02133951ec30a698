"""The text report and the output folder of a pose diagnosis (``stiffness diagnose`` on a pose
campaign) and of ``stiffness validate``."""

from __future__ import annotations

import json
import os
from pathlib import Path

from stiffness.calibration.pose_diagnose import (
    PoseDiagnosis,
    parameter_table,
    residual_structure,
    write_pose_model,
)
from stiffness.calibration.pose_fit import IDENTIFIABILITY_TOL
from stiffness.files import atomic_write, staged_folder

#: Files written by :func:`write_pose_diagnosis`.
POSE_DIAGNOSIS_FILES = {"diagnosis": "diagnosis.json", "model": "final-model.json"}


def format_pose_report(d: PoseDiagnosis) -> str:
    """The human-readable report of a pose diagnosis (lengths in the campaign's unit)."""
    c = d.campaign
    unit, lu = c.units.length, c.units.length_to_si
    noise = "not declared" if c.noise_std is None else f"{c.noise_std / lu:.4g} {unit}"
    lines = [f"pose campaign {c.name}: {c.n_rows} rows, {len(c.markers)} marker(s) "
             f"({', '.join(m.name for m in c.markers)}), {c.n_observed} measured components; "
             f"noise std {noise}; masses {d.masses}; loss {d.loss}",
             "", f"{'step':<5} {'family':<18} {'params':>6} {'RMS':>11} {'dBIC':>10} "
                 f"{'CV RMS':>11}" + ("  validation RMS" if d.steps[0].validation else "")]
    for i, s in enumerate(d.steps):
        row = (f"{i:<5} {s.family:<18} {s.fit.n_fitted:>6} {s.fit.rms() / lu:>11.4g} "
               f"{s.delta_bic:>10.4g} {s.cv_rms / lu:>11.4g}")
        if s.validation:
            row += f"  {s.validation['rms']:.4g} (3-D, {s.validation['unit']})"
        lines.append(row)
    if d.rejected:
        lines.append("not added (dBIC or held-out RMS): " + ", ".join(
            f"{f} ({v:+.3g})" for f, v in d.rejected.items()))
    lines += ["", _verdict(d), "", f"identifiability (tolerance {IDENTIFIABILITY_TOL:g}):"]
    lines += _dropped_lines(d)
    lines += ["", "fitted parameters (SI, 95 % interval):"]
    for p in (p for p in parameter_table(d.final) if p["fitted"]):
        lo, hi = p["interval_95"]
        lines.append(f"  {p['parameter']:<42} {p['value']:>12.5g} {p['unit']:<10} "
                     f"[{lo:.5g}, {hi:.5g}]")
    return "\n".join(lines)


def _verdict(d: PoseDiagnosis) -> str:
    p = d.gof()
    if p is None:
        return ("noise not declared: whether the final model explains the data to noise "
                "cannot be said; declare [measurement] noise_std")
    if not d.unexplained:
        return f"explained to noise (chi-square p = {p:.3g})"
    s = residual_structure(d.final, d.campaign)
    trend = max(s["row_trend"].values(), key=lambda t: abs(t["correlation"]), default=None)
    where = ("" if trend is None else
             f"; strongest trend along the rows: correlation {trend['correlation']:+.2f}")
    return (f"UNEXPLAINED: the residual is above the noise (chi-square p = {p:.3g}); RMS by "
            f"marker {s['rms_by_marker']}, by axis {s['rms_by_axis']}{where}")


def _dropped_lines(d: PoseDiagnosis) -> list[str]:
    ident = d.final.identifiability.to_dict(d.final.model)
    lines = [f"  fitted: {len(ident['kept'])} parameters"]
    for item in ident["dropped"]:
        if item["reason"] == "no effect":
            lines.append(f"  dropped {item['parameter']}: no effect on any marker")
        else:
            combo = " + ".join(f"{m['coefficient']:.3g} x {m['parameter']}"
                               for m in item["merged_into"][:3]) or "(negligible)"
            lines.append(f"  merged {item['parameter']}: absorbed as {combo}")
    return lines


def write_pose_diagnosis(d: PoseDiagnosis, folder: str | os.PathLike) -> dict[str, Path]:
    """Write ``diagnosis.json`` and ``final-model.json`` into ``folder``."""
    with staged_folder(folder) as stage:  # published whole, by one rename
        atomic_write(stage / POSE_DIAGNOSIS_FILES["diagnosis"],
                     json.dumps(d.to_dict(), indent=1, allow_nan=False) + "\n")
        write_pose_model(d.final, d.campaign, stage / POSE_DIAGNOSIS_FILES["model"])
    return {key: Path(folder) / name for key, name in POSE_DIAGNOSIS_FILES.items()}


def format_validation(result: dict) -> str:
    """The text of ``stiffness validate``: overall and per-marker 3-D errors."""
    unit = result["unit"]
    lines = [f"{result['rows']} rows; 3-D position error in {unit}:",
             f"  {'':<12} {'RMS':>11} {'mean':>11} {'max':>11} {'seen':>6}"]
    lines.append(_validation_row("all", result))
    for name, m in result["markers"].items():
        lines.append(_validation_row(name, m))
    return "\n".join(lines)


def _validation_row(name: str, r: dict) -> str:
    if r["rms"] is None:
        return f"  {name:<12} never seen"
    return (f"  {name:<12} {r['rms']:>11.4g} {r['mean_error']:>11.4g} {r['max_error']:>11.4g} "
            f"{r['rows']:>6}")
