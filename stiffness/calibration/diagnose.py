"""Discrepancy diagnosis: where a model and a campaign disagree, and which effect is missing.

:func:`diagnose` runs the workflow of ``stiffness diagnose``:

1. Fit the campaign's baseline (its ``baseline`` formulation over its ``compliant_joints``;
   ``ln k`` by least squares from a non-negative linear start and the paper's 1e5 N.m/rad).
2. Break the baseline's residuals down by configuration, axis, load magnitude and load sign,
   against the noise level: the declared ``noise_std``, else the pooled scatter of replicate
   rows (same configuration and force), else (said so) the residual scatter of the final model.
3. Extend the current model by each candidate of
   :func:`stiffness.elastic.effects.candidates` (its own parameters identified jointly
   with the stiffnesses; every candidate fitted to :data:`SCREEN_TOLERANCE`, the best
   :data:`REFINE_TOP` refitted to the engine's tolerance, side by side in forked workers by
   :func:`stiffness.calibration.fitting.fit_models`), rank them by BIC
   (``RSS / sigma^2 + p ln N`` with a known sigma, ``N ln(RSS / N) + p ln N`` otherwise;
   a parameter-free switch counts one parameter), keep those improving BIC by more than
   :data:`BIC_MARGIN`, cross-validate the best :data:`CV_TOP` over configurations
   (leave-one-configuration-out, or :data:`CV_FOLDS`-fold over configuration labels when there
   are many) and add the lowest-BIC one whose cross-validated error beats the current model's.
   Repeat until the model fits to noise (chi-square test of ``RSS / sigma^2`` at
   :data:`GOF_LEVEL` with ``N - p`` degrees of freedom, known sigma only) or nothing helps.
   With a known sigma, each step's BICs use ``c sigma^2``, ``c`` the step's overdispersion
   (:func:`step_dispersion`): what the best extension leaves above the noise counts as noise.
   If the search ends with the chi-square test still rejecting, the result is *unexplained*
   (:attr:`Diagnosis.unexplained`) and the final residual's structure
   (:func:`residual_structure`: by load direction and row order, correlations with each
   joint's torque and angle) says where to look.
4. Report the RMS after each step, each added effect's parameters with standard errors and 95 %
   intervals, the residuals before and after, the final model.
5. Report the candidates the campaign cannot tell from the winner (BIC within
   :data:`AMBIGUITY_BIC`, or fitted residual reductions with cosine similarity above
   :data:`SIMILARITY_LIMIT` and BIC within :data:`WEAK_BIC`) and propose the extra poses and
   loads where their predictions differ most, in noise units.

RMS values are over every dx, dy, dz residual component pooled. SI inside; the report converts
to the campaign's units.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import nnls
from scipy.special import chdtrc, fdtrc, ndtri, stdtrit

from stiffness.calibration import fitting
from stiffness.calibration.campaign import Campaign, Units, load_campaign
from stiffness.calibration.diagnosis_page import render_diagnosis
from stiffness.calibration.fitting import Fit, FitJob, kind_noise, observations
from stiffness.calibration.outliers import (
    OUTLIER_THRESHOLD,
    Outlier,
    describe_outliers,
    flag_fit,
    robust_noise,
)
from stiffness.elastic.effects import candidates
from stiffness.elastic.effects.base import Effect, Parameter
from stiffness.elastic.effects.geometry import Geometry, References, Rows
from stiffness.elastic.effects.hypothesis import Hypothesis
from stiffness.elastic.model_file import ModelEffect, ModelFile, jsonable
from stiffness.errors import StiffnessError, UnknownNameError
from stiffness.files import atomic_write, staged_folder
from stiffness.provenance import provenance

#: Goodness-of-fit level: the model explains the data to noise when the chi-square test of
#: ``RSS / sigma^2`` with ``N - p`` degrees of freedom does not reject at this level.
GOF_LEVEL = 0.95
#: A candidate must lower BIC by more than this.
BIC_MARGIN = 2.0
#: Number of best-BIC candidates cross-validated per step.
CV_TOP = 3
#: Solver tolerance of the first fit of every candidate: a step stops once it lowers the cost
#: by less than this fraction, a change of about ``1e-6 N`` in ``RSS / sigma^2``, far inside
#: :data:`BIC_MARGIN` (an extension that trades a joint's compliance against an equivalent
#: one crawls along that valley for a hundred steps otherwise).
SCREEN_TOLERANCE = 1e-6
#: The best candidates of a step (by the first fits' BIC) refitted to the engine's tolerance
#: from there: those ranked, cross-validated and compared.
REFINE_TOP = 6
#: Folds over configuration labels when there are more than :data:`LOCO_MAX` configurations.
CV_FOLDS = 6
#: Up to this many configurations, cross-validation leaves one configuration out at a time.
LOCO_MAX = 12
#: Largest number of effects added.
MAX_STEPS = 5
#: Candidates within this BIC of the winner cannot be told apart.
AMBIGUITY_BIC = 2.0
#: Candidates within this BIC of the winner and with similar signatures cannot be told apart.
WEAK_BIC = 6.0
#: Cosine similarity of fitted residual reductions above which signatures are "similar".
SIMILARITY_LIMIT = 0.95
#: Units of the model file's effect parameters (SI).
SI_UNITS = Units(angle="rad", force="N", length="m")
#: File names written by :meth:`Diagnosis.write`.
DIAGNOSIS_FILE, RESIDUALS_PLOT, FINAL_MODEL_FILE = (
    "diagnosis.json", "residuals.png", "final-model.json")
#: The diagnosis as a page (:mod:`stiffness.calibration.diagnosis_page`).
DIAGNOSIS_PAGE = "diagnosis.html"
#: Noise sources.
NOISE_SOURCES = ("declared", "replicates", "residuals")

_MIN_REPLICATE_DOF = 9


# ------------------------------------------------------------------------------------------
# fitting


def fit_job(model: Hypothesis, measured: np.ndarray, scale: float, x0: np.ndarray,
            max_nfev: int | None = None, tolerance: float = 1e-10, loss: str = "linear",
            f_scale: float = 1.0) -> FitJob:
    """The fitting engine's bounded trf fit of ``model`` on ``measured`` (m, 3) from ``x0``
    to the solver ``tolerance`` under ``loss`` (soft threshold ``f_scale`` in units of
    ``scale``), to run (:class:`stiffness.calibration.fitting.FitJob`)."""
    return FitJob(model, measured, scale, x0,
                  {"max_nfev": max_nfev, "x_scale": 1.0, "tolerance": tolerance,
                   "loss": loss, "f_scale": f_scale})


def fit_model(model: Hypothesis, measured: np.ndarray, scale: float, x0: np.ndarray,
              max_nfev: int | None = None, tolerance: float = 1e-10, loss: str = "linear",
              f_scale: float = 1.0) -> Fit:
    """:func:`fit_job`'s fit, in this process."""
    return fit_job(model, measured, scale, x0, max_nfev, tolerance, loss, f_scale).run()


def _linear_start(model: Hypothesis, measured: np.ndarray) -> np.ndarray:
    """ln k from the conventional model, linear in the compliances (non-negative LS)."""
    tau = model.rows.torques()[:, model.index[: len(model.compliant)]]
    jac = model.jv if model.rotation_weight is None else np.concatenate(
        [model.jv, model.rotation_weight * model.jw], axis=1)
    design = (jac[:, :, : len(model.compliant)] * tau[:, None, :]).reshape(
        -1, len(model.compliant))
    c, _ = nnls(design, measured.reshape(-1))
    k = np.where(c > 0, 1.0 / np.where(c > 0, c, 1.0), np.nan)
    fill = np.nanmax(k) * 100.0 if np.any(np.isfinite(k)) else 1e9
    return np.log(np.where(np.isfinite(k), k, fill))


def fit_baseline(model: Hypothesis, measured: np.ndarray, scale: float, loss: str = "linear"
                 ) -> Fit:
    """Baseline fit from the linear start and the paper's 1e5 N.m/rad start; the best kept
    (a robust ``loss`` scaled by ``scale``, the noise std)."""
    n = len(model.compliant)
    starts = [_linear_start(model, measured), np.full(n, math.log(1e5))]
    fits = [fit_model(model, measured, scale, x0, max_nfev=200 * (n + 1), loss=loss)
            for x0 in starts]
    return min(fits, key=lambda f: f.loss_rss)


def information_criterion(rss: float, n: int, p: int, sigma: float | None) -> float:
    """BIC: ``RSS / sigma^2 + p ln N`` (known sigma) or ``N ln(RSS / N) + p ln N``."""
    if sigma is not None:
        return rss / sigma ** 2 + p * math.log(n)
    return n * math.log(max(rss, 1e-300) / n) + p * math.log(n)


def step_dispersion(fits: list[Fit], n: int, sigma: float | None) -> float:
    """Overdispersion of a selection step: ``c = max(1, min_f RSS_f / (sigma^2 (N - p_f)))``
    over the current model and its extensions ``fits`` (1 with an unknown sigma).

    What the best extension leaves above the noise is structure no candidate of the step
    models; it acts as extra noise on every comparison of the step. The step's BICs therefore
    use ``c sigma^2`` (a quasi-likelihood BIC), so that a candidate must explain a share of the
    *remaining* misfit, not only beat the measurement noise, to be named. When one extension
    fits to noise, ``c = 1`` and the BIC is the plain known-sigma one.
    """
    if sigma is None:
        return 1.0
    ratios = [f.loss_rss / (sigma ** 2 * max(n - f.model.penalty_params, 1)) for f in fits]
    return max(1.0, min(ratios))


def config_folds(labels: tuple[str, ...], seed: int = 0) -> list[np.ndarray]:
    """Held-out row indices of each fold: one configuration label each, or
    :data:`CV_FOLDS` groups of labels when there are more than :data:`LOCO_MAX`."""
    labels_arr = np.asarray(labels)
    unique = list(dict.fromkeys(labels))
    if len(unique) < 2:
        return []
    if len(unique) <= LOCO_MAX:
        groups = [[u] for u in unique]
    else:
        order = np.random.default_rng(seed).permutation(len(unique))
        groups = [[unique[i] for i in order[f::CV_FOLDS]] for f in range(CV_FOLDS)]
    return [np.flatnonzero(np.isin(labels_arr, g)) for g in groups]


def cross_validate(fits: list[Fit], measured: np.ndarray, folds: list[np.ndarray],
                   workers: int | None = None) -> list[float]:
    """Cross-validated RMS residual (m) of each fit: each fold refitted without its rows, from
    the fit's ``x`` (every refit of every fit one job of
    :func:`stiffness.calibration.fitting.fit_models` on ``workers``)."""
    if not folds:
        return [math.nan] * len(fits)
    m = measured.shape[0]
    trains = [np.setdiff1d(np.arange(m), test) for test in folds]
    subs = fitting.fit_models([fit_job(f.model.with_rows(f.model.rows.subset(train)),
                                       measured[train], f.scale, f.x, loss=f.loss,
                                       f_scale=f.f_scale)
                               for f in fits for train in trains], workers)
    out = []
    for i, fit in enumerate(fits):
        total = 0.0
        for test, sub in zip(folds, subs[i * len(folds): (i + 1) * len(folds)], strict=True):
            try:
                with np.errstate(all="ignore"):
                    pred = fit.model.with_rows(fit.model.rows.subset(test)).predict(sub.x)
            except np.linalg.LinAlgError:
                total = math.inf
                break
            if not np.all(np.isfinite(pred)):
                total = math.inf
                break
            total += float(np.sum((pred - measured[test]) ** 2))
        out.append(math.sqrt(total / measured.size))
    return out


def _covariance(fit: Fit, sigma: float, measured: np.ndarray) -> np.ndarray:
    """Covariance of ``x``: the engine's ``sigma^2 (J^T J)^+`` (a robust fit's sandwich)."""
    return fitting.covariance(fit, sigma, measured).matrix


# ------------------------------------------------------------------------------------------
# noise


def replicate_noise(campaign: Campaign, kind: str = "translation"
                    ) -> tuple[float, int] | None:
    """Pooled std (m; rad for ``kind="rotation"``) of replicate rows (same coordinates and
    force) and its degrees of freedom, or ``None`` when the replicates give fewer than 9
    degrees of freedom (or the campaign measures no rotations)."""
    values = campaign.deflection if kind == "translation" else campaign.rotation
    if values is None:
        return None
    groups: dict[tuple, list[int]] = {}
    for i in range(campaign.n_rows):
        key = tuple(np.round(campaign.q[i], 9)) + tuple(np.round(campaign.wrench[i], 6))
        groups.setdefault(key, []).append(i)
    ss, dof = 0.0, 0
    for idx in groups.values():
        if len(idx) > 1:
            d = values[idx]
            ss += float(np.sum((d - d.mean(axis=0)) ** 2))
            dof += 3 * (len(idx) - 1)
    if dof < _MIN_REPLICATE_DOF:
        return None
    return math.sqrt(ss / dof), dof


# ------------------------------------------------------------------------------------------
# where the model disagrees


def disagreement(residuals: np.ndarray, campaign: Campaign, sigma: float,
                 rows: Rows | None = None, joints: tuple[str, ...] = ()) -> dict:
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
    if rows is not None:
        out.update(residual_structure(residuals, campaign, rows, joints, sigma))
    return out


#: Consecutive blocks of rows (in file order) of the ``by_row_order`` breakdown.
ROW_BLOCKS = 4
#: Number of strongest residual correlations listed in the text report.
REPORTED_CORRELATIONS = 5
_DIRECTION_NAMES = ("+fx", "-fx", "+fy", "-fy", "+fz", "-fz")


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
                       joints: tuple[str, ...], sigma: float) -> dict:
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
        The coordinate joints, the columns of ``rows``.
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
            "joint_angle": {j: correlation(rows.coords[:, i], residuals, sigma, lu)
                            for i, j in enumerate(joints)},
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


def _disagreement_lines(d: dict, unit: str, force_unit: str) -> list[str]:
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


# ------------------------------------------------------------------------------------------
# results


@dataclass
class Candidate:
    """One candidate extension at a step.

    Attributes
    ----------
    effect
        The effect.
    fit
        The extended model fitted.
    bic, delta_bic
        Its BIC and the change from the current model's.
    cv_rms
        Cross-validated RMS (m), when computed.
    """

    effect: Effect
    fit: Fit
    bic: float
    delta_bic: float
    cv_rms: float | None = None


@dataclass
class Ambiguity:
    """Two effects the campaign cannot tell apart, and the measurements that would.

    Attributes
    ----------
    step
        Step (1-based) at which they competed.
    chosen, other
        Labels of the added effect and of its rival.
    delta_bic
        BIC of the rival minus the chosen one's.
    similarity
        Cosine similarity of their fitted residual reductions.
    separation
        RMS difference of their predictions over the campaign, noise units.
    reason
        Why they cannot be told apart.
    cv_rms
        Cross-validated RMS (m) of the chosen and of the other (None if not computed).
    proposals
        Extra measurements, best first: coordinates, force, predicted deflections of both, the
        separation in noise units.
    """

    step: int
    chosen: str
    other: str
    delta_bic: float
    similarity: float
    separation: float
    reason: str = ""
    cv_rms: tuple[float | None, float | None] = (None, None)
    proposals: list[dict] = field(default_factory=list)

    def to_dict(self, length_to_si: float = 1.0) -> dict:
        """JSON-ready (CV RMS divided by ``length_to_si``)."""
        return {"step": self.step, "chosen": self.chosen, "other": self.other,
                "reason": self.reason, "delta_bic": self.delta_bic,
                "similarity": self.similarity,
                "cv_rms": [None if v is None else v / length_to_si for v in self.cv_rms],
                "separation_noise_units": self.separation, "proposals": self.proposals}


@dataclass
class Step:
    """One effect added.

    Attributes
    ----------
    effect
        The effect.
    fit
        The model after adding it.
    rms
        RMS residual (m).
    bic, delta_bic, cv_rms
        Its BIC, the BIC change, its cross-validated RMS (m).
    parameters
        The effect's parameters, campaign units.
    ranking
        The best candidates of the step: label, delta BIC, CV RMS (m) or None.
    dispersion
        The step's overdispersion (:func:`step_dispersion`): its BICs use the noise variance
        times this.
    """

    effect: Effect
    fit: Fit
    rms: float
    bic: float
    delta_bic: float
    cv_rms: float
    parameters: list[Parameter]
    ranking: list[dict]
    dispersion: float = 1.0


@dataclass
class Diagnosis:
    """Result of :func:`diagnose` (SI; :meth:`summary` and the files use campaign units).

    Attributes
    ----------
    campaign
        The campaign diagnosed.
    geometry
        Its robot's shared geometry.
    baseline
        The baseline fitted.
    baseline_stiffness
        Baseline stiffnesses with uncertainties (N.m/rad or N/m).
    final_stiffness
        The same in the final model.
    noise_std_m, noise_std_source, noise_note
        The noise level (m), where it comes from (:data:`NOISE_SOURCES`) and what that means.
    steps
        Effects added, in order.
    stop_reason
        Why the search stopped.
    baseline_disagreement, final_disagreement
        Residual breakdowns (:func:`disagreement`).
    gof_baseline, gof_final
        Chi-square p-values of the baseline and final fits (known noise only).
    ambiguities
        What the campaign cannot tell apart.
    cv_baseline
        Cross-validated RMS of the baseline (m).
    elapsed_s
        Wall time (s).
    unexplained
        ``True`` when the search ended (library exhausted, or nothing else passing BIC and
        cross-validation) with the chi-square test still rejecting the final model: something
        outside the library is in the data, and :attr:`final_disagreement` says where to look.
        ``False`` when the final model fits to noise; ``None`` when the noise is only estimated
        from the residuals (no test available).
    loss
        The loss of every fit (:data:`stiffness.calibration.fitting.LOSSES`).
    outliers, outlier_sigma_m
        The final model's rows beyond :data:`OUTLIER_THRESHOLD` noise std
        (:mod:`stiffness.calibration.outliers`; flagged, none dropped) and the noise std (m)
        they are standardised by.
    """

    campaign: Campaign
    geometry: Geometry
    baseline: Fit
    baseline_stiffness: list[Parameter]
    final_stiffness: list[Parameter]
    noise_std_m: float
    noise_std_source: str
    noise_note: str
    steps: list[Step]
    stop_reason: str
    baseline_disagreement: dict
    final_disagreement: dict
    gof_baseline: float | None
    gof_final: float | None
    ambiguities: list[Ambiguity]
    cv_baseline: float
    elapsed_s: float
    final_parameters: dict[str, list[Parameter]] = field(default_factory=dict)
    final_parameters_si: dict[str, list[Parameter]] = field(default_factory=dict)
    unexplained: bool | None = None
    measured: np.ndarray | None = None
    rotation_noise_std_rad: float | None = None
    rotation_noise_source: str | None = None
    loss: str = "linear"
    outliers: list[Outlier] = field(default_factory=list)
    outlier_sigma_m: float | None = None

    def rms_by_kind(self) -> dict:
        """RMS of the baseline's and the final model's residuals per kind: translations in
        the length unit, rotations (when measured) in the campaign's rotation unit."""
        measured = self.campaign.deflection if self.measured is None else self.measured
        out = {}
        for label, fit in (("baseline", self.baseline), ("final", self.final)):
            t, r = fit.rms_by_kind(measured)
            out[label] = {"translation": self._len(t), "rotation": None if r is None
                          else r / self.campaign.units.rotation_to_si}
        return out

    @property
    def final(self) -> Fit:
        """The final fit."""
        return self.steps[-1].fit if self.steps else self.baseline

    @property
    def unit(self) -> str:
        """The campaign's length unit."""
        return self.campaign.units.length

    def _len(self, value_m: float) -> float:
        return value_m / self.campaign.units.length_to_si

    @property
    def unexplained_note(self) -> str:
        """One sentence on the verdict of :attr:`unexplained`."""
        if self.unexplained is None:
            return ("not tested: the noise is estimated from the final model's residuals, so "
                    "whether something outside the library is left cannot be said")
        if not self.unexplained:
            return "the final model explains the data to noise (chi-square test)"
        return (f"the residual is still above the noise (chi-square p = {self.gof_final:.3g} "
                f"<= {1 - GOF_LEVEL:.2g}) and no further library effect passes BIC and "
                "cross-validation: the data contain something the library does not model; "
                "the residual's structure (where_final_disagrees) says where to look"
                + (f"; {len(self.outliers)} row(s) are flagged as outliers, which alone can "
                   "fail the test (see outliers)" if self.outliers else ""))

    @property
    def missing_effects(self) -> list[str]:
        """Names of the effects added."""
        return [s.effect.name for s in self.steps]

    def to_dict(self) -> dict:
        """The object ``stiffness diagnose --json`` prints (campaign units): exactly the keys
        of the issue; :meth:`record` has everything."""
        return jsonable({
            "baseline_rms": self._len(self.baseline.rms()),
            "noise_std": self._len(self.noise_std_m),
            "noise_std_source": self.noise_std_source,
            "steps": [{"effect": s.effect.name, "where": s.effect.where,
                       "rms": self._len(s.rms),
                       "parameters": {p.name: p.to_dict() for p in s.parameters}}
                      for s in self.steps],
            "missing_effects": self.missing_effects,
            "unexplained": self.unexplained,
            "final_rms": self._len(self.final.rms()),
            "unit": self.unit,
            "loss": self.loss,
            "outlier_threshold": OUTLIER_THRESHOLD,
            "outliers": [o.to_dict() for o in self.outliers],
            "rms_by_kind": self.rms_by_kind(),
        })

    def summary(self) -> dict:
        """The ``--json`` object (:meth:`to_dict`)."""
        return self.to_dict()

    def record(self) -> dict:
        """Everything (``diagnosis.json``): :meth:`to_dict` plus the breakdowns, rankings,
        ambiguities, proposals."""
        c = self.campaign
        out = self.to_dict()
        out.update({
            "campaign": c.name,
            "campaign_path": str(c.path) if c.path is not None else None,
            "rows": c.n_rows,
            "residual_components": (3 if c.rotation is None else 6) * c.n_rows,
            "configurations": len(set(c.config)),
            "baseline": self.baseline.model.describe(),
            "final_model": self.final.model.describe(),
            "noise_std_note": self.noise_note,
            "fits_to_noise": {"baseline_p_value": self.gof_baseline,
                              "final_p_value": self.gof_final, "level": GOF_LEVEL},
            "stop_reason": self.stop_reason,
            "unexplained_note": self.unexplained_note,
            "cv_rms": {"baseline": self._len(self.cv_baseline),
                       "steps": [self._len(s.cv_rms) for s in self.steps]},
            "baseline_stiffness": {p.name: p.to_dict() for p in self.baseline_stiffness},
            "final_stiffness": {p.name: p.to_dict() for p in self.final_stiffness},
            "step_details": [{"effect": s.effect.name, "where": s.effect.where,
                              "description": s.effect.describe(),
                              "delta_bic": s.delta_bic, "dispersion": s.dispersion,
                              "ranking": [
                                  {**r, "cv_rms": None if r["cv_rms"] is None
                                   else self._len(r["cv_rms"])} for r in s.ranking]}
                             for s in self.steps],
            "where_baseline_disagrees": self.baseline_disagreement,
            "where_final_disagrees": self.final_disagreement,
            "cannot_tell_apart": [a.to_dict(c.units.length_to_si) for a in self.ambiguities],
            "elapsed_s": self.elapsed_s,
            "rotation_unit": c.units.rotation,
            "rotation_noise_std": None if self.rotation_noise_std_rad is None
            else self.rotation_noise_std_rad / c.units.rotation_to_si,
            "rotation_noise_std_source": self.rotation_noise_source,
        })
        return jsonable(out)

    def model_file(self) -> ModelFile:
        """The final model in the model-file schema (SI): baseline stiffnesses with their
        intervals, each effect with its SI parameters and intervals, the noise."""
        c, f = self.campaign, self.final
        s = c.robot_settings
        refs = f.model.refs
        effects = []
        for e in f.model.effects:
            effects.append(ModelEffect(e.name, e.where, e.kind,
                                       self.final_parameters_si.get(e.label, []),
                                       e.file_settings(refs), e.describe()))
        stiff = self.final_stiffness
        return ModelFile(
            source=c.resolved_source(), **c.robot_options(),
            frame=self.geometry.robot.target_frame,
            target_offset_m=s.target_offset_m, compliant_joints=tuple(f.model.compliant),
            k_theta=np.array([p.value for p in stiff]), units=tuple(p.unit for p in stiff),
            formulation=f.model.baseline,
            standard_error=np.array([p.standard_error for p in stiff]),
            ci95_low=np.array([p.ci95[0] for p in stiff]),
            ci95_high=np.array([p.ci95[1] for p in stiff]),
            effects=tuple(effects), noise_std_m=self.noise_std_m,
            noise_source=self.noise_std_source, campaign=c.name, produced_by="diagnose",
            undetermined_joints=tuple(p.name for p in stiff if not (
                math.isfinite(p.ci95[1]) and p.ci95[0] > 0)),
            extra={
                "model": f.model.describe(), "rms": self._len(f.rms()),
                "noise_std": self._len(self.noise_std_m),
                "noise_std_source": self.noise_std_source, "unit": self.unit,
                "unexplained": self.unexplained, "unexplained_note": self.unexplained_note,
                "rotation_noise": None if self.rotation_noise_std_rad is None else {
                    "std_rad": self.rotation_noise_std_rad,
                    "source": self.rotation_noise_source,
                    "weight_m_per_rad": f.model.rotation_weight},
                "baseline": f.model.baseline, "compliant_joints": list(f.model.compliant),
                "parameter_vector": f.x.tolist(),
                "references": {"k_ref": refs.k_ref, "theta_ref": refs.theta_ref,
                               "force_ref": refs.force_ref,
                               "deflection_ref": refs.deflection_ref,
                               "tau_max": dict(zip(refs.joints, refs.tau_max.tolist(),
                                                   strict=True)),
                               "tau_smoothing": dict(zip(refs.joints,
                                                         refs.tau_smoothing.tolist(),
                                                         strict=True))},
            },
        )

    def write(self, folder: str | Path, command: str | None = None) -> dict[str, Path]:
        """Write ``diagnosis.json``, ``residuals.png``, ``final-model.json`` and
        ``diagnosis.html`` in ``folder``; ``command`` is recorded in the page's provenance
        (default: this process's command line)."""
        folder = Path(folder)
        record = self.record()
        png = residual_plot(self)
        with staged_folder(folder) as stage:  # published whole, by one rename
            atomic_write(stage / DIAGNOSIS_FILE, json.dumps(record, indent=1) + "\n")
            self.model_file().write(stage / FINAL_MODEL_FILE)
            atomic_write(stage / RESIDUALS_PLOT, png)
            atomic_write(stage / DIAGNOSIS_PAGE, render_diagnosis(record, png,
                                                                  provenance(command)))
        return {"diagnosis": folder / DIAGNOSIS_FILE, "plot": folder / RESIDUALS_PLOT,
                "final_model": folder / FINAL_MODEL_FILE, "page": folder / DIAGNOSIS_PAGE}


# ------------------------------------------------------------------------------------------
# the workflow


def _stiffness_parameters(fit: Fit, cov: np.ndarray, quantile: float) -> list[Parameter]:
    model = fit.model
    out = []
    for i, j in enumerate(model.compliant):
        k = math.exp(fit.x[i])
        se = math.sqrt(cov[i, i]) if math.isfinite(cov[i, i]) else math.inf
        prismatic = bool(model.geometry.prismatic[model.geometry.joints.index(j)])
        with np.errstate(over="ignore"):
            ci = (k * math.exp(-quantile * se) if math.isfinite(se) else 0.0,
                  k * math.exp(quantile * se) if math.isfinite(se) and quantile * se < 700
                  else math.inf)
        out.append(Parameter(j, k, k * se, ci, "N/m" if prismatic else "N.m/rad"))
    return out


def _effect_parameters(fit: Fit, cov: np.ndarray, quantile: float, units
                       ) -> dict[str, list[Parameter]]:
    model = fit.model
    out = {}
    for i, e in enumerate(model.effects):
        a, b = model.offsets[i + 1], model.offsets[i + 2]
        out[e.label] = e.report(fit.x[a:b], cov[a:b, a:b], model.refs, units, quantile)
    return out


def _gof(rss: float, n: int, p: int, sigma: float | None) -> float | None:
    if sigma is None or n <= p:
        return None
    return float(chdtrc(n - p, rss / sigma ** 2))


def diagnose(
    campaign: Campaign | str | os.PathLike,
    max_steps: int = MAX_STEPS,
    seed: int = 0,
    propose: bool = True,
    progress: Callable[[str], None] | None = None,
    workers: int | None = None,
    loss: str = "linear",
) -> Diagnosis:
    """Diagnose what the campaign's baseline model misses (see the module docstring).

    The function behind ``stiffness diagnose`` (:meth:`Diagnosis.to_dict` is its ``--json``
    object, :meth:`Diagnosis.write` writes its ``--out`` folder).

    Parameters
    ----------
    campaign
        The campaign (SI rows), or the path of a ``campaign.toml`` (or of its folder).
    max_steps
        Largest number of effects added.
    seed
        Seed of the fold assignment and of the poses sampled for experiment proposals.
    propose
        Whether to propose extra poses and loads for what cannot be told apart.
    progress
        Called with a line of text as the search goes.
    workers
        Processes fitting a step's candidates and cross-validation folds side by side
        (:func:`stiffness.calibration.fitting.fit_models`; default the usable cores, 1 in this
        process); the result does not depend on it.
    loss
        ``linear`` (least squares) or a robust loss of
        :data:`stiffness.calibration.fitting.LOSSES` for every fit, scaled by the noise std
        (declared, replicates', else a robust estimate); criteria then compare
        :attr:`stiffness.calibration.fitting.Fit.loss_rss` and intervals come from Huber's
        sandwich covariance.

    Returns
    -------
    Diagnosis

    Raises
    ------
    StiffnessError
        If a configuration cannot be assembled, there are too few residuals, or
        ``max_steps`` is negative.
    """
    if isinstance(max_steps, bool) or not isinstance(max_steps, int | np.integer) \
            or max_steps < 0:
        raise StiffnessError(f"--max-steps must be a non-negative integer (0: the baseline "
                             f"only), got {max_steps!r}")
    if loss not in fitting.LOSSES:
        raise UnknownNameError(f"unknown loss {loss!r}; valid losses: "
                               f"{', '.join(fitting.LOSSES)}", name=loss,
                               choices=fitting.LOSSES)
    if not isinstance(campaign, Campaign):
        campaign = load_campaign(campaign)
    t0 = time.perf_counter()
    say = progress or (lambda text: None)
    compliant = tuple(campaign.robot().compliant_joints)
    geo = Geometry.of(campaign.robot())
    rows = geo.rows(campaign.q, campaign.force, campaign.moment,
                    labels=[campaign.describe_row(i) for i in range(campaign.n_rows)])
    n = campaign.deflection.size * (1 if campaign.rotation is None else 2)
    if n <= len(compliant) + 1:
        raise StiffnessError(f"{n} residual components cannot diagnose a model of "
                             f"{len(compliant)} stiffnesses; add measurement rows")
    sigma, source, note = _translation_noise(campaign)
    base, measured, scale, rot_sigma, rot_source = _baseline_fit(
        campaign, Hypothesis(geo, rows, campaign.baseline, compliant, (),
                        References.of(geo, rows, 1e5, campaign.deflection)), n, sigma, loss)
    say(f"baseline {base.model.describe()}: RMS {base.rms():.4g} m")
    folds = config_folds(campaign.config, seed)
    cv_base = cross_validate([base], measured, folds, workers)[0]
    search = _Search(measured, folds, scale, n, sigma, workers, say)
    final, steps, ambiguities_raw, stop = search.run(base, cv_base, max_steps, campaign.units)
    p_final = final.model.penalty_params
    gof_final = _gof(final.loss_rss, n, p_final, sigma)
    if sigma is None:
        sigma_used = math.sqrt(final.loss_rss / max(n - p_final, 1))
        note = (f"estimated from the residuals of the final model ({final.model.describe()}, "
                f"{n - p_final} degrees of freedom): it includes any model error left, so the "
                "fit-to-noise test is not available and 'nothing missing' means only that no "
                "candidate helped")
    else:
        sigma_used = sigma
    known = sigma if loss == "linear" else None  # a sandwich estimates its spread: t
    quantile = _quantile(known, n, p_final)
    cov_final = _covariance(final, sigma_used, measured)
    cov_base = _covariance(base, sigma_used if sigma is not None else math.sqrt(
        base.loss_rss / max(n - base.model.penalty_params, 1)), measured)
    outliers, outlier_sigma = flag_fit(final, measured, sigma, p_final,
                                       tuple(campaign.config or ()), campaign.lines)
    ambiguities = _ambiguities(ambiguities_raw, sigma_used, campaign, geo,
                               seed if propose else None)
    return Diagnosis(
        campaign=campaign, geometry=geo, baseline=base,
        baseline_stiffness=_stiffness_parameters(base, cov_base, _quantile(
            known, n, base.model.penalty_params)),
        final_stiffness=_stiffness_parameters(final, cov_final, quantile),
        noise_std_m=float(sigma_used), noise_std_source=source, noise_note=note, steps=steps,
        stop_reason=stop,
        baseline_disagreement=disagreement((base.predicted - measured)[:, :3], campaign,
                                           sigma_used, rows, geo.joints),
        final_disagreement=disagreement((final.predicted - measured)[:, :3], campaign,
                                        sigma_used, rows, geo.joints),
        gof_baseline=_gof(base.loss_rss, n, base.model.penalty_params, sigma),
        gof_final=gof_final, unexplained=None if gof_final is None
        else bool(gof_final <= 1.0 - GOF_LEVEL),
        ambiguities=ambiguities, cv_baseline=cv_base,
        elapsed_s=time.perf_counter() - t0,
        final_parameters=_effect_parameters(final, cov_final, quantile, campaign.units),
        final_parameters_si=_effect_parameters(final, cov_final, quantile, SI_UNITS),
        measured=measured, rotation_noise_std_rad=rot_sigma, rotation_noise_source=rot_source,
        loss=loss, outliers=outliers, outlier_sigma_m=outlier_sigma,
    )


def _translation_noise(campaign: Campaign) -> tuple[float | None, str, str]:
    """The translation noise std (m; ``None`` when only the residuals can tell), its source
    (:data:`NOISE_SOURCES`) and a note on it: declared, else the replicates' scatter."""
    if campaign.noise_std_m is not None:
        return campaign.noise_std_m, "declared", "declared noise_std of the campaign"
    rep = replicate_noise(campaign)
    if rep is not None:
        return (rep[0], "replicates",
                f"pooled scatter of replicate rows ({rep[1]} degrees of freedom)")
    return None, "residuals", ""


def _baseline_fit(campaign: Campaign, model0: Hypothesis, n: int, sigma: float | None,
                  loss: str = "linear"
                  ) -> tuple[Fit, np.ndarray, float, float | None, str | None]:
    """The campaign's baseline ``model0`` fitted (rotations weighted by their noise, estimated
    from the baseline's residuals when not known), with the references of its stiffness;
    under a robust ``loss`` scaled by ``sigma`` (m), else by a robust estimate
    (:func:`stiffness.calibration.outliers.robust_noise`, twice).

    Returns
    -------
    The fit, the observations (m, rotations weighted), the residual scale (m), the rotation
    noise std (rad, or None) and its source.
    """
    deflection = campaign.deflection
    rms_meas = float(np.sqrt(np.mean(deflection ** 2)))
    scale = sigma if sigma is not None else max(rms_meas * 1e-2, 1e-12)
    rot_sigma, rot_source, weight = _rotation_noise(campaign, sigma)
    measured = observations(deflection, campaign.rotation, weight)
    model0 = model0.with_rotation_weight(weight)
    base = fit_baseline(model0, measured, scale, loss if sigma is not None else "linear")
    if rot_source == "residuals":  # the rotation noise from the baseline's residuals
        res_t, res_r = base.residuals(measured)
        s_t = sigma if sigma is not None else kind_noise(res_t, n, len(base.x))
        rot_sigma = kind_noise(res_r, n, len(base.x))
        if s_t and rot_sigma:
            weight = s_t / rot_sigma
            measured = observations(deflection, campaign.rotation, weight)
            base = fit_baseline(model0.with_rotation_weight(weight), measured, scale,
                                loss if sigma is not None else "linear")
    k_ref = float(np.exp(np.mean(base.x)))
    base.model = base.model.with_refs(References.of(model0.geometry, model0.rows, k_ref,
                                                    deflection))
    if sigma is None and loss == "linear":
        scale = max(base.rms(), 1e-12)
        base = fit_model(base.model, measured, scale, base.x)
    for _ in range(2 if sigma is None and loss != "linear" else 0):
        scale = robust_noise(base.predicted - measured, len(base.x)) or max(base.rms(), 1e-12)
        base = fit_model(base.model, measured, scale, base.x, loss=loss)
    return base, measured, scale, rot_sigma, rot_source


@dataclass
class _Search:
    """The effect search of :func:`diagnose` over fixed observations (m), cross-validation
    folds, residual scale (m), residual count, noise std (m, or None) and workers."""

    measured: np.ndarray
    folds: list[np.ndarray]
    scale: float
    n: int
    sigma: float | None
    workers: int | None
    say: Callable[[str], None]

    def run(self, base: Fit, cv_base: float, max_steps: int, units: Units
            ) -> tuple[Fit, list[Step], list[tuple[int, Candidate, Candidate, float]], str]:
        """Add effects until the model fits to noise, ``max_steps`` or nothing helps.

        Returns
        -------
        The final fit, the steps, the raw ambiguities ``(step, winner, other, similarity)``
        and why the search stopped.
        """
        current, cv_current = base, cv_base
        steps: list[Step] = []
        ambiguities: list[tuple[int, Candidate, Candidate, float]] = []
        while True:
            gof = _gof(current.loss_rss, self.n, current.model.penalty_params, self.sigma)
            if gof is not None and gof > 1.0 - GOF_LEVEL:
                return current, steps, ambiguities, (
                    f"the model explains the data to noise (chi-square p = {gof:.3g} > "
                    f"{1 - GOF_LEVEL:.2g})")
            if len(steps) >= max_steps:
                return (current, steps, ambiguities,
                        f"stopped after {max_steps} effects (max_steps)")
            results, dispersion = self.candidates(current)
            self.say(f"step {len(steps) + 1}: {len(results)} candidates; best "
                     + ", ".join(f"{c.effect.label} dBIC {c.delta_bic:.3g}"
                                 for c in results[:3]))
            winner, stop = self.winner(results, cv_current)
            if winner is None:
                return current, steps, ambiguities, stop
            for c in results[:CV_TOP]:
                if c is winner:
                    continue
                similarity = _similarity(current, winner.fit, c.fit, self.scale)
                d_bic = c.bic - winner.bic
                if d_bic < AMBIGUITY_BIC or (similarity > SIMILARITY_LIMIT
                                             and d_bic < WEAK_BIC):
                    ambiguities.append((len(steps) + 1, winner, c, similarity))
            steps.append(self.step(winner, results, dispersion, units))
            self.say(f"added {winner.effect.label}: RMS {winner.fit.rms():.4g} m")
            current, cv_current = winner.fit, winner.cv_rms

    def candidates(self, current: Fit) -> tuple[list[Candidate], float]:
        """Every library extension of ``current`` fitted (screened, the best refined), ranked
        by BIC, and the step's overdispersion."""
        effects = candidates(current.model)
        fits = list(zip(effects, fitting.fit_models(
            [fit_job(current.model.extended(e), self.measured, self.scale,
                     current.model.extend_x(current.x, e), tolerance=SCREEN_TOLERANCE,
                     loss=current.loss, f_scale=current.f_scale)
             for e in effects], self.workers), strict=True))
        results, _ = _ranked(current, fits, self.n, self.sigma)
        best = {id(c.effect) for c in results[:REFINE_TOP]}
        refine = [i for i, (e, _) in enumerate(fits) if id(e) in best]
        refined = fitting.fit_models([fit_job(fits[i][1].model, self.measured, self.scale,
                                              fits[i][1].x, loss=current.loss,
                                              f_scale=current.f_scale) for i in refine],
                                     self.workers)
        for i, fit in zip(refine, refined, strict=True):
            fits[i] = (fits[i][0], fit)
        return _ranked(current, fits, self.n, self.sigma)

    def winner(self, results: list[Candidate], cv_current: float
               ) -> tuple[Candidate | None, str]:
        """The lowest-BIC candidate past :data:`BIC_MARGIN` whose cross-validated error beats
        ``cv_current`` (m), or ``None`` and why not."""
        eligible = [c for c in results if c.delta_bic < -BIC_MARGIN]
        if not eligible:
            return None, (f"no candidate improves BIC by more than {BIC_MARGIN:g}" if results
                          else "no candidate left")
        winner = None
        tried = eligible[:CV_TOP]
        for c, cv in zip(tried, cross_validate([c.fit for c in tried], self.measured,
                                               self.folds, self.workers), strict=True):
            c.cv_rms = cv
            if winner is None and (not self.folds or c.cv_rms < cv_current):
                winner = c
        if winner is None:
            return None, ("no candidate that improves BIC also improves the error predicted "
                          "for held-out configurations (cross-validation)")
        return winner, ""

    def step(self, winner: Candidate, results: list[Candidate], dispersion: float,
             units: Units) -> Step:
        """The :class:`Step` that adds ``winner``: its parameters with intervals, the step's
        ranking."""
        fit = winner.fit
        sig = self.sigma if self.sigma is not None else math.sqrt(fit.loss_rss / max(
            self.n - fit.model.penalty_params, 1))
        cov = _covariance(fit, sig, self.measured)
        quantile = _quantile(self.sigma if fit.loss == "linear" else None, self.n,
                             fit.model.penalty_params)
        params = _effect_parameters(fit, cov, quantile, units)
        ranking = [{"effect": c.effect.name, "where": c.effect.where,
                    "delta_bic": c.delta_bic, "cv_rms": c.cv_rms} for c in results[:6]]
        return Step(winner.effect, fit, fit.rms(), winner.bic, winner.delta_bic,
                    winner.cv_rms, params[winner.effect.label], ranking, dispersion)


def _ambiguities(raw: list[tuple[int, Candidate, Candidate, float]], sigma: float,
                 campaign: Campaign, geo: Geometry, seed: int | None) -> list[Ambiguity]:
    """The pairs the campaign cannot tell apart, with why, and (``seed`` not None, first
    three) the measurements that would (:func:`propose_measurements`); ``sigma`` in m."""
    ambiguities = []
    for step_no, w, c, similarity in raw:
        sep = float(np.sqrt(np.mean((w.fit.predicted - c.fit.predicted) ** 2))) / sigma
        d_bic = c.bic - w.bic
        if d_bic < 0:
            reason = ("BIC prefers the other, but it does not predict held-out configurations "
                      "better than the current model (cross-validation)")
        elif d_bic < AMBIGUITY_BIC:
            reason = f"BIC within {AMBIGUITY_BIC:g}"
        elif c.fit.model.penalty_params > w.fit.model.penalty_params:
            reason = (f"similar signatures (cosine {similarity:.3f}); the chosen one wins by "
                      "parsimony (fewer parameters), hardly by fit")
        else:
            reason = (f"similar signatures (cosine {similarity:.3f}) and BIC within "
                      f"{WEAK_BIC:g}: weak evidence only")
        amb = Ambiguity(step_no, w.effect.label, c.effect.label, d_bic, similarity, sep,
                        reason, (w.cv_rms, c.cv_rms))
        if seed is not None and len(ambiguities) < 3:
            try:
                amb.proposals = propose_measurements(campaign, geo, w.fit, c.fit, sigma,
                                                     seed=seed)
            except StiffnessError as exc:  # no reachable pose sampled
                amb.proposals = [{"note": str(exc)}]
        ambiguities.append(amb)
    return ambiguities


def _ranked(current: Fit, fits: list[tuple[Effect, Fit]], n: int, sigma: float | None
            ) -> tuple[list[Candidate], float]:
    """A step's candidates by BIC (best first) under the step's overdispersion
    (:func:`step_dispersion`), and that dispersion."""
    dispersion = step_dispersion([current] + [f for _, f in fits], n, sigma)
    s_step = None if sigma is None else sigma * math.sqrt(dispersion)
    current_bic = information_criterion(current.loss_rss, n, current.model.penalty_params,
                                        s_step)
    results = [Candidate(e, f, b, b - current_bic) for e, f in fits
               for b in [information_criterion(f.loss_rss, n, f.model.penalty_params,
                                               s_step)]]
    results.sort(key=lambda c: c.bic)
    return results, dispersion


def _rotation_noise(campaign: Campaign, sigma: float | None
                    ) -> tuple[float | None, str | None, float | None]:
    """Rotation noise std (rad), its source and the rotation weight ``sigma_t / sigma_r``
    (m/rad) of a campaign with rotations (``None``s without): declared, else replicates,
    else ``residuals`` (then the weight is a first guess, the ratio of the measured RMS of
    each kind, refined from the baseline's residuals)."""
    if campaign.rotation is None:
        return None, None, None
    rms_t = float(np.sqrt(np.mean(campaign.deflection ** 2))) or 1.0
    rms_r = float(np.sqrt(np.mean(campaign.rotation ** 2))) or 1.0
    s_t = sigma if sigma is not None else rms_t
    if campaign.rotation_noise_std_rad is not None:
        rot, source = campaign.rotation_noise_std_rad, "declared"
    else:
        rep = replicate_noise(campaign, "rotation")
        rot, source = (rep[0], "replicates") if rep is not None else (None, "residuals")
    return rot, source, s_t / (rot if rot is not None else rms_r)


def _quantile(sigma: float | None, n: int, p: int) -> float:
    if sigma is not None:
        return float(ndtri(0.975))
    return float(stdtrit(max(n - p, 1), 0.975))


def _similarity(current: Fit, a: Fit, b: Fit, scale: float) -> float:
    """Cosine similarity of the residual reductions of two candidate fits."""
    da = (a.predicted - current.predicted).reshape(-1) / scale
    db = (b.predicted - current.predicted).reshape(-1) / scale
    na, nb = np.linalg.norm(da), np.linalg.norm(db)
    if na == 0 or nb == 0:
        return 0.0
    return float(da @ db / (na * nb))


# ------------------------------------------------------------------------------------------
# experiment design


def propose_measurements(campaign: Campaign, geometry: Geometry, a: Fit, b: Fit, sigma: float,
                         n_poses: int = 40, n_best: int = 3, seed: int = 0) -> list[dict]:
    """Extra poses and loads where two fitted models' predictions differ most.

    The experiment design's separation (:mod:`stiffness.calibration.experiment`): ``n_poses``
    reachable candidate poses, loads along the axes and cube diagonals at the campaign's largest
    force; the ``n_best`` poses, one load each, that add the most separation left after either
    model is refitted, in the campaign's units. Each proposal's ``separation_noise_units`` is
    ``|dx_a - dx_b| / sigma`` there.
    """
    from stiffness.calibration.experiment import (
        Alternatives,
        candidate_set,
        select_rows,
        separation_score,
        separation_statistics,
    )

    f_max = float(np.linalg.norm(campaign.force, axis=1).max())
    cands = candidate_set(geometry.robot, n_poses, f_max, seed)
    labels = (a.model.describe(), b.model.describe())
    sep = separation_statistics(Alternatives(a, b, labels, sigma, ""), cands)
    chosen = select_rows(sep.rows, sep.base, separation_score, min(n_best, cands.n_poses), 1)
    u = campaign.units
    prismatic = geometry.prismatic
    out = []
    for pose, load in zip(chosen.poses, chosen.loads[:, 0], strict=True):
        qc = cands.coords[pose].copy()
        qc[~prismatic] /= u.angle_to_si
        qc[prismatic] /= u.length_to_si
        force = cands.directions[load] * cands.max_force
        out.append({"q": qc.tolist(), "force": (force / u.force_to_si).tolist(),
                    "deflection_chosen": (sep.predicted_a[pose, load, :3]
                                          / u.length_to_si).tolist(),
                    "deflection_other": (sep.predicted_b[pose, load, :3]
                                         / u.length_to_si).tolist(),
                    "separation_noise_units": float(sep.raw[pose, load])})
    return out


# ------------------------------------------------------------------------------------------
# output


def format_report(d: Diagnosis) -> str:
    """The human-readable report of ``stiffness diagnose``."""
    c, unit = d.campaign, d.unit
    lu = c.units.length_to_si
    lines = [
        f"campaign {c.name}" + (f" ({c.path})" if c.path else "")
        + f": {c.n_rows} rows, {len(set(c.config))} configurations, {3 * c.n_rows} residual "
          f"components; lengths in {unit}",
        f"baseline: {d.baseline.model.describe()}; RMS {d.baseline.rms() / lu:.4g} {unit}",
        f"noise std: {d.noise_std_m / lu:.4g} {unit} ({d.noise_std_source}: {d.noise_note})",
    ]
    if d.gof_baseline is not None:
        verdict = "fits" if d.gof_baseline > 1 - GOF_LEVEL else "does NOT fit"
        lines.append(f"the baseline {verdict} to noise (chi-square p = {d.gof_baseline:.3g})")
    lines += ["", f"where the baseline disagrees (RMS in {unit}, and in noise std):"]
    lines += _disagreement_lines(d.baseline_disagreement, unit, c.units.force)
    lines += ["", f"{'step':<5} {'effect':<28} {'where':<30} {'RMS':>10} {'dBIC':>9} "
                  f"{'CV RMS':>10}"]
    lines.append(f"{0:<5} {'baseline':<28} {'':<30} {d.baseline.rms() / lu:>10.4g} {'':>9} "
                 f"{d.cv_baseline / lu:>10.4g}")
    for i, s in enumerate(d.steps, start=1):
        lines.append(f"{i:<5} {s.effect.name:<28} {s.effect.where or '':<30} "
                     f"{s.rms / lu:>10.4g} {s.delta_bic:>9.4g} {s.cv_rms / lu:>10.4g}")
    lines.append("")
    if d.steps:
        lines.append("identified effects (final model; 95 % intervals):")
        for s in d.steps:
            lines.append(f"  {s.effect.label}: {s.effect.describe()}")
            for p in d.final_parameters.get(s.effect.label, []):
                lines.append(f"    {p.name} = {p.value:.5g} +- {p.standard_error:.3g} {p.unit} "
                             f"[{p.ci95[0]:.5g}, {p.ci95[1]:.5g}]")
        lines.append("missing effects: " + ", ".join(s.effect.label for s in d.steps))
    else:
        lines.append("missing effects: none" + (
            " (the baseline explains the data to noise)" if d.gof_baseline is not None
            and d.gof_baseline > 1 - GOF_LEVEL else ""))
    lines.append("stiffness (final model): " + ", ".join(
        f"{p.name} {p.value:.5g} [{p.ci95[0]:.4g}, {p.ci95[1]:.4g}] {p.unit}"
        for p in d.final_stiffness))
    ratio = d.final.rms() / d.noise_std_m
    lines.append(f"final RMS {d.final.rms() / lu:.4g} {unit} ({ratio:.3g}x noise); "
                 f"stopped: {d.stop_reason}")
    if d.loss != "linear":
        lines.append(f"loss {d.loss} (every fit; intervals from Huber's sandwich covariance)")
    lines += describe_outliers(d.outliers)
    if d.unexplained:
        lines += ["", f"UNEXPLAINED: {d.unexplained_note}.",
                  f"where the final model disagrees (RMS in {unit}, and in noise std):"]
        lines += _disagreement_lines(d.final_disagreement, unit, c.units.force)
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
            cv = ", ".join("-" if v is None else f"{v / lu:.4g}" for v in a.cv_rms)
            lines.append(f"  step {a.step}: {a.chosen} vs {a.other}: {a.reason}; dBIC "
                         f"{a.delta_bic:+.3g}, CV RMS {cv} {unit}, signature similarity "
                         f"{a.similarity:.3f}; their predictions differ by {a.separation:.3g} "
                         "noise std RMS over this campaign")
            for p in a.proposals:
                if "note" in p:
                    lines.append(f"    {p['note']}")
                    continue
                q = ", ".join(f"{v:.4g}" for v in p["q"])
                f = ", ".join(f"{v:.4g}" for v in p["force"])
                lines.append(f"    measure q = [{q}] {c.units.angle}, F = [{f}] "
                             f"{c.units.force}: predicted difference "
                             f"{p['separation_noise_units']:.3g} noise std")
    return "\n".join(lines)


def residual_plot(d: Diagnosis) -> bytes:
    """PNG: residual components before (baseline) and after (final model), row by row."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lu = d.campaign.units.length_to_si
    before = (d.baseline.predicted[:, :3] - d.campaign.deflection) / lu
    after = (d.final.predicted[:, :3] - d.campaign.deflection) / lu
    sigma = d.noise_std_m / lu
    rows = np.arange(1, d.campaign.n_rows + 1)
    fig, axes = plt.subplots(3, 1, figsize=(10, 7.5), sharex=True)
    for k, ax in enumerate(axes):
        ax.axhspan(-2 * sigma, 2 * sigma, color="0.9", label="±2 noise std")
        ax.plot(rows, before[:, k], "x", color="0.45", label="baseline")
        ax.plot(rows, after[:, k], "o", ms=3.5, color=f"C{k}", label="final model")
        ax.axhline(0.0, color="0.3", lw=0.6)
        ax.set_ylabel(f"d{'xyz'[k]} residual ({d.unit})")
        ax.grid(alpha=0.3)
    labels = d.campaign.config
    starts = [i for i in range(len(labels)) if i == 0 or labels[i] != labels[i - 1]]
    if len(starts) <= 30:
        for ax in axes:
            for i in starts[1:]:
                ax.axvline(i + 0.5, color="0.8", lw=0.5)
    axes[0].legend(fontsize=8, ncol=3, loc="upper right")
    title = "missing: " + (", ".join(s.effect.label for s in d.steps) or "nothing")
    axes[0].set_title(f"{d.campaign.name}: RMS {d.baseline.rms() / lu:.3g} -> "
                      f"{d.final.rms() / lu:.3g} {d.unit} (noise {sigma:.3g}); {title}",
                      fontsize=9)
    axes[-1].set_xlabel("measurement row")
    buf = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return buf.getvalue()
