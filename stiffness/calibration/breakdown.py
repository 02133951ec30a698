"""Where a model and a campaign disagree: the residuals broken down by configuration, axis,
load magnitude and sign against the noise (:func:`disagreement`), and the structure a final
residual keeps (by load direction and row order, correlations with each joint's torque and
angle: :func:`residual_structure`; a pose fit's per marker, per axis and along the rows:
:func:`marker_structure`), and the summary of 3-D error norms a validation reports for either
campaign kind (:func:`error_summary`).

Residuals in m; the breakdowns in the campaign's units.
"""


from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from scipy.special import fdtrc

from stiffness.calibration.campaign import Campaign
from stiffness.elastic.effects.geometry import Rows
from stiffness.units import Units

if TYPE_CHECKING:  # a pose fit is judged here; its module imports this one
    from stiffness.calibration.pose_campaign import PoseCampaign
    from stiffness.calibration.pose_fit import PoseFit

#: Consecutive blocks of rows (in file order) of the ``by_row_order`` breakdown.
ROW_BLOCKS = 4
#: Number of strongest residual correlations listed in the text report.
REPORTED_CORRELATIONS = 5
_DIRECTION_NAMES = ("+fx", "-fx", "+fy", "-fy", "+fz", "-fz")


def disagreement(residuals: np.ndarray, campaign: Campaign, sigma: float,
                 rows: Rows | None = None, joints: dict[str, np.ndarray] | None = None
                 ) -> dict:
    """Residual RMS by configuration, axis, load magnitude and load sign, in the campaign's
    length unit and in noise units (``ratio``); with ``rows`` and their ``joints``, also
    :func:`residual_structure` (load direction, row order, correlations)."""
    u = campaign.units
    lu = u.length_to_si
    force = campaign.force

    def group(idx: np.ndarray) -> dict:
        return _group(residuals, idx, sigma, lu)

    labels = np.asarray(campaign.config)
    out: dict = {"by_configuration": {
        lab: group(np.flatnonzero(labels == lab)) for lab in dict.fromkeys(campaign.config)}}
    out["by_axis"] = {}
    for k, name in enumerate(("dx", "dy", "dz")):
        r = residuals[:, k]
        rms = float(np.sqrt(np.mean(r ** 2)))
        out["by_axis"][name] = {"rms": rms / lu, "ratio": rms / sigma,
                                "mean": float(r.mean()) / lu}
    mag = np.linalg.norm(force, axis=1)
    edges = np.unique(np.quantile(mag, [0.0, 1 / 3, 2 / 3, 1.0]))
    bins = []
    for i in range(len(edges) - 1):
        last = i == len(edges) - 2
        sel = (mag >= edges[i]) & ((mag <= edges[i + 1]) if last else (mag < edges[i + 1]))
        g = group(np.flatnonzero(sel))
        g["force_range"] = [float(edges[i]) / u.force_to_si, float(edges[i + 1]) / u.force_to_si]
        bins.append(g)
    out["by_load_magnitude"] = bins
    out["by_load_sign"] = {}
    for k, name in enumerate(("fx", "fy", "fz")):
        scale = max(float(np.abs(force[:, k]).max()), 1e-12)
        pos = np.flatnonzero(force[:, k] > 1e-3 * scale)
        neg = np.flatnonzero(force[:, k] < -1e-3 * scale)
        out["by_load_sign"][name] = {"positive": group(pos), "negative": group(neg)}
    if rows is not None and joints is not None:
        out.update(residual_structure(residuals, campaign, rows, joints, sigma))
    return out


def _group(residuals: np.ndarray, idx: np.ndarray, sigma: float, lu: float) -> dict:
    """RMS (length unit), its ratio to the noise and the mean (length unit) of rows ``idx``."""
    r = residuals[idx]
    rms = float(np.sqrt(np.mean(r ** 2))) if r.size else math.nan
    return {"rows": int(len(idx)), "rms": rms / lu, "ratio": rms / sigma,
            "mean": (r.mean(axis=0) / lu).tolist() if r.size else None}


def correlation(variable: np.ndarray, residuals: np.ndarray, sigma: float, lu: float
                ) -> dict:
    """How much of the residual a straight line in one per-row variable explains.

    Each residual axis ``k`` is regressed on ``variable`` (with an intercept): its Pearson
    correlation ``r_k``, and pooled over the axes the explained fraction
    ``R^2 = sum_k r_k^2 SS_k / sum_k SS_k`` (``SS_k`` the centred sum of squares of axis ``k``),
    the RMS of the explained part (length unit and noise std) and the p-value of the F test
    ``F = (R^2 / 3) / ((1 - R^2) / (3 (m - 2)))`` with (3, 3 (m - 2)) degrees of freedom.

    Parameters
    ----------
    variable
        (m,) one value per row (a joint torque, a joint angle, the row index).
    residuals
        (m, 3) model minus measured (m).
    sigma, lu
        Noise std (m) and the campaign's length unit (m).
    """
    m = residuals.shape[0]
    v = np.asarray(variable, dtype=float) - np.mean(variable)
    r = residuals - residuals.mean(axis=0)
    sv = float(v @ v)
    ss = np.sum(r ** 2, axis=0)
    if m < 4 or sv <= 1e-24 * max(float(np.max(np.abs(variable))) ** 2, 1e-300) * m:
        return {"r": [None, None, None], "r2": None, "explained_rms": None,
                "explained_ratio": None, "p_value": None}
    slope_ss = (v @ r) ** 2 / sv
    with np.errstate(invalid="ignore", divide="ignore"):
        rk = np.where(ss > 0, np.sign(v @ r) * np.sqrt(slope_ss / np.where(ss > 0, ss, 1.0)),
                      0.0)
    total = float(ss.sum())
    r2 = float(slope_ss.sum() / total) if total > 0 else 0.0
    explained = math.sqrt(float(slope_ss.sum()) / residuals.size)
    dof2 = 3 * (m - 2)
    f_stat = (r2 / 3.0) / max((1.0 - r2) / dof2, 1e-300)
    return {"r": rk.tolist(), "r2": r2, "explained_rms": explained / lu,
            "explained_ratio": explained / sigma, "p_value": float(fdtrc(3, dof2, f_stat))}


def residual_structure(residuals: np.ndarray, campaign: Campaign, rows: Rows,
                       joints: dict[str, np.ndarray], sigma: float) -> dict:
    """Residual RMS by load direction and by row order, and the residual's correlation with
    each joint's torque, each joint's coordinate and the row order (:func:`correlation`).

    Parameters
    ----------
    residuals
        (m, 3) model minus measured (m).
    campaign
        The campaign (its units and force).
    rows
        The campaign's rows (:meth:`Geometry.rows`): the torques ``J^T W`` and coordinates.
    joints
        The spring joints, the columns of ``rows`` in order, each with its value per row (m,)
        (rad or m: :meth:`stiffness.elastic.effects.geometry.Geometry.angles`).
    sigma
        Noise std (m).
    """
    lu = campaign.units.length_to_si
    m = residuals.shape[0]
    force = campaign.force
    mag = np.linalg.norm(force, axis=1)
    unit = force / np.where(mag > 0, mag, 1.0)[:, None]
    axis = np.argmax(np.abs(unit), axis=1)
    code = 2 * axis + (unit[np.arange(m), axis] < 0)
    by_direction = {}
    for c, name in enumerate(_DIRECTION_NAMES):
        idx = np.flatnonzero((code == c) & (mag > 0))
        if len(idx):
            by_direction[name] = _group(residuals, idx, sigma, lu)
    blocks = [b for b in np.array_split(np.arange(m), min(ROW_BLOCKS, m)) if len(b)]
    by_order = []
    for b in blocks:
        g = _group(residuals, b, sigma, lu)
        g["row_range"] = [int(b[0]) + 1, int(b[-1]) + 1]
        by_order.append(g)
    torques = rows.torques()
    return {
        "by_load_direction": by_direction,
        "by_row_order": by_order,
        "correlation": {
            "joint_torque": {j: correlation(torques[:, i], residuals, sigma, lu)
                             for i, j in enumerate(joints)},
            "joint_angle": {j: correlation(angle, residuals, sigma, lu)
                            for j, angle in joints.items()},
            "load_direction": {name: correlation(unit[:, k], residuals, sigma, lu)
                               for k, name in enumerate(("fx", "fy", "fz"))},
            "load_magnitude": correlation(mag, residuals, sigma, lu),
            "row_order": correlation(np.arange(m, dtype=float), residuals, sigma, lu),
        },
    }


def strongest_correlations(structure: dict, n: int = REPORTED_CORRELATIONS) -> list[dict]:
    """The ``n`` per-row variables of ``structure["correlation"]`` whose straight line explains
    most of the residual: ``{variable, r2, explained_ratio, p_value, r}``, strongest first."""
    corr = structure.get("correlation", {})
    flat = []
    for kind, label in (("joint_torque", "torque of {}"), ("joint_angle", "angle of {}"),
                        ("load_direction", "load direction {}")):
        for name, c in corr.get(kind, {}).items():
            flat.append((label.format(name), c))
    for kind, label in (("load_magnitude", "load magnitude"), ("row_order", "row order")):
        if kind in corr:
            flat.append((label, corr[kind]))
    flat = [(v, c) for v, c in flat if c["r2"] is not None]
    flat.sort(key=lambda vc: -vc[1]["r2"])
    return [{"variable": v, **c} for v, c in flat[:n]]


def finite_rms(values: np.ndarray) -> float:
    """RMS of the finite values (NaN if none): a marker not seen is left out."""
    v = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(v ** 2))) if v.size else float("nan")


def error_summary(errors: np.ndarray, length_to_si: float) -> dict:
    """RMS, mean, standard deviation and max of 3-D error norms (m) in the campaign's unit,
    and how many were seen: the keys ``rms``, ``mean_error``, ``std_error`` (the spread of the
    norms about their mean, divided by the count), ``max_error``, ``rows``.

    NaN entries (a marker not seen) are left out; all-NaN gives ``None`` values.
    """
    e = errors[np.isfinite(errors)] / length_to_si
    if not e.size:
        return {"rms": None, "mean_error": None, "std_error": None, "max_error": None,
                "rows": 0}
    return {"rms": float(np.sqrt(np.mean(e ** 2))), "mean_error": float(e.mean()),
            "std_error": float(e.std()), "max_error": float(e.max()), "rows": int(e.size)}


def rotation_summary(angle: np.ndarray, units: Units) -> dict:
    """``rotation_rms``, ``rotation_mean_error``, ``rotation_max_error`` of rotation errors'
    angles (rad; NaN: not measured) in the campaign's rotation unit, and ``rotation_unit``:
    the rotation keys of a validation, a pose campaign's oriented markers' and a deflection
    campaign's measured rotations alike."""
    summary = error_summary(angle, units.rotation_to_si)
    return {**{f"rotation_{key}": summary[key] for key in ("rms", "mean_error", "max_error")},
            "rotation_unit": units.rotation}


def marker_structure(fit: PoseFit, campaign: PoseCampaign) -> dict:
    """Where a pose fit's residual sits: RMS per marker and per axis, and its trend along the rows.

    ``row_trend`` is the slope of each axis's residual against the row index (m per row) and
    the correlation coefficient: a drift (temperature, tracker) shows as a strong trend.
    """
    r = fit.residual
    lu = campaign.units.length_to_si
    per_marker = {m.name: finite_rms(r[:, k]) / lu for k, m in enumerate(campaign.markers)}
    per_axis = {a: finite_rms(r[:, :, i]) / lu for i, a in enumerate("xyz")}
    rows = np.arange(r.shape[0], dtype=float)
    trend = {}
    for i, a in enumerate("xyz"):
        values = np.nanmean(r[:, :, i], axis=1)
        ok = np.isfinite(values)
        if ok.sum() > 2 and np.std(values[ok]) > 0:
            slope = float(np.polyfit(rows[ok], values[ok], 1)[0])
            trend[a] = {"slope_per_row": slope / lu,
                        "correlation": float(np.corrcoef(rows[ok], values[ok])[0, 1])}
    return {"rms_by_marker": per_marker, "rms_by_axis": per_axis, "row_trend": trend}
