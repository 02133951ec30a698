"""The text of ``stiffness validate`` and ``diagnose --validate``, for deflection and pose
campaigns alike: a model's errors on another campaign of its robot
(:func:`~stiffness.calibration.validation.validate`), its verdict against the campaign's noise
and its line of the stage table."""

from __future__ import annotations

from stiffness.calibration.steps_table import stage_table


def format_validation(result: dict) -> str:
    """The text of ``stiffness validate``: overall and per-marker 3-D errors, the verdict
    against the campaign's noise, then the line of the stage table
    (:func:`~stiffness.calibration.steps_table.stage_table`) for this one model."""
    unit = result["unit"]
    lines = [f"{result['rows']} rows; 3-D position error in {unit}:",
             f"  {'':<12} {'RMS':>11} {'mean':>11} {'std':>11} {'max':>11} {'seen':>6}"]
    lines.append(_validation_row("all", result))
    for name, m in result["markers"].items():
        lines.append(_validation_row(name, m))
    return "\n".join(lines + [_noise_verdict(result), "", *stage_table([("model", result)])])


def _noise_verdict(result: dict) -> str:
    """The verdict line of ``stiffness validate`` against the campaign's declared noise."""
    if result.get("verdict") is None:
        return "no noise declared in the campaign: no verdict (declare [measurement] noise_std)"
    line = (f"verdict: {result['verdict'].upper()} (RMS {result['rms_over_noise']:.3g}x the "
            f"noise {result['noise_std']:.4g} {result['unit']} per axis; ")
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


def _validation_row(name: str, r: dict) -> str:
    if r["rms"] is None:
        return f"  {name:<12} never seen"
    return (f"  {name:<12} {r['rms']:>11.4g} {r['mean_error']:>11.4g} {r['std_error']:>11.4g} "
            f"{r['max_error']:>11.4g} {r['rows']:>6}")
