"""Joint-stiffness identification from a measurement campaign (Alici & Shirinzadeh, eq. 11-13).

The unknowns are the stiffnesses ``k`` of the campaign's compliant joints (N.m/rad for revolute
joints, N/m for prismatic ones). For each measurement row ``r`` (configuration ``q_r``, wrench
``W_r`` at the target, measured target displacement ``d_r``) the model predicts

* ``conventional``: ``J K^-1 J^T W`` (A&S eq. 8),
* ``enhanced``: ``J (K - K_C(W))^-1 J^T W`` (A&S eq. 10-11),
* ``exact``: the displacement of the exact elastostatic equilibrium
  (:func:`stiffness.mechanics.equilibrium.solve_equilibrium`; all rows at once as an
  observation of the pose model's sag, :class:`stiffness.calibration.exact_baseline.
  ExactObservation`; slower),

with ``J`` the translational target Jacobian w.r.t. the compliant joints. Identification is a
diagnosis with no effects: the model is the campaign's baseline
(:func:`stiffness_model`, a :class:`stiffness.elastic.effects.hypothesis.Hypothesis` without
effects; ``J`` and ``K_C`` computed once per row, ``K_C`` linear in the row's own load) and the
fit is the fitting engine's (:mod:`stiffness.calibration.fitting`): the residuals
``(predicted - measured) / s`` are stacked row by row (eq. 13) and their sum of squares
(eq. 12) is minimised by :func:`scipy.optimize.least_squares` (``trf`` and/or ``lm``) over
``ln k`` (positivity, and a scale-free parameterisation), from several starts: the paper's
``1e8 N.mm/rad`` and log-uniform random starts over ``1e2..1e8`` SI units; the best run is
kept and the result says whether all runs agree. Each run is anchored at its start by the
engine's tiny pseudo-residuals (:data:`stiffness.calibration.fitting.PRIOR_WEIGHT`), which
keep combinations the data do not see at their start instead of letting them drift on
round-off; they are left out of every reported quantity.

``s`` is the declared measurement noise ``noise_std`` if the campaign gives one (the residuals
are then whitened and ``sigma = noise_std``); otherwise ``s`` is a fixed scale and the noise
``sigma^2 = SS / (N - p)`` is estimated from the residual sum of squares ``SS`` of the ``N``
residuals and ``p`` stiffnesses. The covariance of ``ln k`` is the engine's
``sigma^2 (J_r^T J_r)^+`` (:func:`stiffness.calibration.fitting.covariance`) with ``J_r`` the
residual Jacobian at the optimum; standard errors follow by the delta method on ``ln k``,
``SE(k) = k SE(ln k)``, and a 95 % confidence interval of ``k`` is its compliance's, ``c -+ t
SE(c)`` with ``SE(c) = c SE(ln k)``, carried to ``k = 1 / c``: ``CI = [k / (1 + t SE(ln k)),
k / (1 - t SE(ln k))]`` (``t`` Student's with ``N - p`` degrees of freedom when sigma is
estimated, normal when declared; unbounded above when the compliance's interval reaches zero),
as diagnose reports it: a deflection is linear in the compliances.

A campaign with measured rotations (``rx, ry, rz``) is fitted on translations and rotations
together: the rotation residuals are weighted by ``w = sigma_t / sigma_r``
(:func:`stiffness.calibration.fitting.observations`), each kind's noise std declared, else its
replicates', else estimated from the residuals of preliminary fits at the weight's fixed
point (:func:`stiffness.calibration.deflection_noise.weighting`, diagnose's rule); ``sigma``
above is then ``sigma_t`` and the result reports the RMS of each kind.

A robust ``loss`` (scipy's ``soft_l1``, ``huber``, ``cauchy``, scaled by the declared noise,
else the replicates' robust scatter, else the robustly estimated noise) is minimised instead,
with intervals from Huber's sandwich covariance (:mod:`stiffness.calibration.fitting`) and
Student's ``t`` with ``N - p`` degrees of freedom, two-sided and one-sided at a bound alike,
the noise declared or not: the sandwich takes its spread from the residuals
(:class:`stiffness.calibration.selection.Noise`, the one rule).
Every identification flags the rows beyond 4 noise std (:mod:`stiffness.calibration.outliers`)
and drops none.

A stiffness is determined by diagnose's rule, the one rule of both commands and both campaign
kinds (:attr:`stiffness.elastic.effects.base.Parameter.determined`, :mod:`stiffness.calibration.
naming`, issue 36): fitted, with a finite 95 % interval whose compliance's width is narrower
than its physical scale, ten times the baseline's mean compliance ``1 / k_ref``
(:func:`stiffness.calibration.deflection_parameters.stiffness_parameters`, which diagnose
reports). A direction in ``ln k`` space is undetermined when its relative 95 % width exceeds 1
along a right-singular vector of the whitened residual Jacobian (singular value below
``t / asinh(1/2)``, or numerically zero).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, overload

import numpy as np

from stiffness.calibration.campaign import Campaign, campaign_kind, load_campaign
from stiffness.calibration.deflection_noise import (
    fit_options,
    interval_quantiles,
    noise_level,
    residual_rotation_noise,
    residual_scale,
    robust_loss_options,
    translation_noise,
    weighted_observations,
)
from stiffness.calibration.deflection_parameters import stiffness_parameters
from stiffness.calibration.exact_baseline import ExactObservation
from stiffness.calibration.fitting import (
    Fit,
    compliance_covariance,
    compliance_spread,
    covariance,
    fit_model,
    reference_stiffness,
    rigid_joints,
)
from stiffness.calibration.identification import (
    Identification,
    StartResult,
    UndeterminedDirection,
    stiffness_unit,
)
from stiffness.calibration.outliers import (
    OUTLIER_THRESHOLD,
    Outlier,
    flag_fit,
)
from stiffness.calibration.pose_campaign import PoseCampaign, load_pose_campaign
from stiffness.calibration.pose_identify import PoseIdentification, identify_poses
from stiffness.calibration.selection import (
    Noise,
    above_noise,
    material_holders,
    noise_terms,
)
from stiffness.calibration.sign_checks import flipped_column_note
from stiffness.calibration.solver import Covariance, check_loss
from stiffness.elastic.effects import make_effect
from stiffness.elastic.effects.base import stiffness_interval
from stiffness.elastic.effects.geometry import Geometry, References
from stiffness.elastic.effects.hypothesis import Hypothesis
from stiffness.errors import StiffnessError, UnknownNameError
from stiffness.robot.robot import Robot
from stiffness.units import whole_number

FORMULATIONS = ("conventional", "enhanced", "exact")
METHODS = ("trf", "lm", "both")
#: The paper's initial guess, 1e8 N.mm/rad, in N.m/rad.
PAPER_START_SI = 1e5
#: Range (SI) of the log-uniform random starts.
RANDOM_START_RANGE_SI = (1e2, 1e8)
#: A direction in ``ln k`` space is undetermined when its 95 % interval is wider than this
#: times its value (a stiffness is judged by diagnose's rule, module docstring).
REL_CI_WIDTH_LIMIT = 1.0
#: Two solutions agree when every determined ln k differs by less than this (0.1 %).
AGREEMENT_TOL_LOG = 1e-3
#: A stiffness biased by more than this many of its standard errors by the enhanced
#: formulation's first-order kinematics (:func:`kinematics_bias`) gets a note: its 95 %
#: interval then covers at most about 92.9 % rather than 95 %.
KINEMATICS_BIAS_NOTE = 0.5
#: Default name of the identified-model file.
MODEL_FILE = "identified-model.json"


def _starts(n: int, count: int, seed: int | None) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    lo, hi = np.log10(RANDOM_START_RANGE_SI)
    starts = [np.full(n, PAPER_START_SI)]
    starts += [10.0 ** rng.uniform(lo, hi, n) for _ in range(count - 1)]
    return starts


def _agree(a: np.ndarray, b: np.ndarray, determined: np.ndarray) -> bool:
    diff = np.abs(np.log(a) - np.log(b))[determined]
    return bool(np.all(diff < AGREEMENT_TOL_LOG))


@dataclass
class _Uncertainty:
    covariance_log: np.ndarray
    se_log: np.ndarray
    low: np.ndarray
    high: np.ndarray
    width: np.ndarray
    singular_values: np.ndarray
    condition_number: float
    directions: list[UndeterminedDirection]


def _uncertainty(cov: Covariance, k: np.ndarray, quantile: np.ndarray, joints: tuple[str, ...]
                 ) -> _Uncertainty:
    """Intervals and undetermined directions from the fitting engine's covariance of ln k:
    each stiffness's interval is its compliance's, ``c -+ quantile se_c`` with ``se_c = c
    se(ln k)`` (``quantile`` per joint), carried to ``k = 1 / c`` (a deflection is linear in
    the compliances; unbounded above when the compliance's interval reaches zero), as diagnose
    reports it (:func:`stiffness.calibration.deflection_parameters.stiffness_parameters`); a
    direction's width with the largest quantile."""
    se_log = np.sqrt(np.diag(cov.matrix))
    # the compliance 1 / k in units of itself: 1 +- quantile se(ln k)
    low, high = np.array([stiffness_interval((1.0 - q * s) * (1.0 / kk), (1.0 + q * s) * (1.0 / kk))
                          for q, s, kk in zip(quantile, se_log, k, strict=True)]).reshape(-1, 2).T
    with np.errstate(invalid="ignore"):
        width = (high - low) / k
    width = np.where(np.isfinite(width), width, np.inf)
    directions = []
    for s_j, v, zero in zip(cov.singular_values, cov.directions, cov.undetermined, strict=True):
        dir_width = math.inf
        if not zero and max(quantile) / s_j < 700.0:
            dir_width = 2.0 * math.sinh(max(quantile) / s_j)
        if dir_width <= REL_CI_WIDTH_LIMIT:
            continue
        v = v * (1.0 if v[np.argmax(np.abs(v))] > 0 else -1.0)
        comps = {j: float(c) for j, c in zip(joints, v, strict=True)}
        big = tuple(j for j, c in comps.items() if abs(c) >= 0.3)
        text = " ".join(f"{c:+.2f} ln K_{j}" for j, c in comps.items() if abs(c) >= 0.05)
        directions.append(UndeterminedDirection(comps, big, dir_width, text))
    return _Uncertainty(cov.matrix, se_log, low, high, width, cov.singular_values,
                        cov.condition_number, directions)


def stiffness_model(campaign: Campaign, formulation: str, robot: Robot | None = None
                    ) -> Hypothesis:
    """The campaign's baseline model without effects: its compliant joints under
    ``formulation`` over the campaign's rows
    (:class:`stiffness.elastic.effects.hypothesis.Hypothesis`).

    Raises
    ------
    StiffnessError
        Unknown formulation, or a row whose configuration cannot be assembled (named by its
        file, line and configuration).
    """
    if formulation not in FORMULATIONS:
        raise UnknownNameError(f"unknown formulation {formulation!r}; valid formulations: "
                               f"{', '.join(FORMULATIONS)}", name=formulation,
                               choices=FORMULATIONS)
    robot = robot if robot is not None else campaign.robot()
    geometry = Geometry.of(robot)
    rows = geometry.rows(campaign.q, campaign.force, campaign.moment,
                         labels=[campaign.describe_row(i) for i in range(campaign.n_rows)],
                         joint_angles=campaign.robot_settings.joint_angles)
    refs = References.of(geometry, rows, PAPER_START_SI, campaign.deflection)
    return Hypothesis(geometry, rows, formulation, tuple(robot.compliant_joints), (), refs,
                      exact=ExactObservation)


@overload
def identify(campaign: Campaign, formulation: str | None = ..., method: str = ...,
             starts: int = ..., seed: int | None = ..., robot: Robot | None = ...,
             progress: Callable[[int, int, str], None] | None = ..., loss: str = ...
             ) -> Identification: ...


@overload
def identify(campaign: PoseCampaign, formulation: str | None = ..., method: str = ...,
             starts: int = ..., seed: int | None = ..., robot: Robot | None = ...,
             progress: Callable[[int, int, str], None] | None = ..., loss: str = ...
             ) -> PoseIdentification: ...


@overload
def identify(campaign: str | os.PathLike, formulation: str | None = ..., method: str = ...,
             starts: int = ..., seed: int | None = ..., robot: Robot | None = ...,
             progress: Callable[[int, int, str], None] | None = ..., loss: str = ...
             ) -> Identification | PoseIdentification: ...


def identify(
    campaign: Campaign | PoseCampaign | str | os.PathLike,
    formulation: str | None = None,
    method: str = "trf",
    starts: int = 8,
    seed: int | None = 0,
    robot: Robot | None = None,
    progress: Callable[[int, int, str], None] | None = None,
    loss: str = "linear",
) -> Identification | PoseIdentification:
    """Identify the compliant joints' stiffnesses from a campaign (A&S eq. 11-13).

    The function behind ``stiffness identify`` (:meth:`Identification.to_dict` is its
    ``--json`` object once :meth:`Identification.write_model` has written the model file).
    A pose campaign (``kind = "poses"``) is identified by
    :func:`stiffness.calibration.pose_identify.identify_poses` (the pose diagnosis with the
    springs forced in and nothing searched), with ``loss``; it takes no ``formulation``,
    ``method`` other than ``trf`` or ``robot``, and draws no starts.

    Parameters
    ----------
    campaign
        The measurements (SI), or the path of a ``campaign.toml`` (or of its folder), of
        either kind.
    formulation
        ``conventional``, ``enhanced`` or ``exact``; default the campaign's baseline.
    method
        ``trf``, ``lm`` (Levenberg-Marquardt) or ``both`` (each start solved by both).
    starts
        Number of starts: the paper's ``1e8 N.mm/rad`` (1e5 SI) for every joint, then
        ``starts - 1`` log-uniform random starts over ``1e2..1e8`` SI. For the enhanced and
        exact formulations, start values below twice the largest eigenvalue of ``K_C`` over the
        rows are raised to it (below, ``K - K_C`` can be singular and the prediction has poles
        the solver cannot cross). The exact formulation first converges each start with the
        enhanced one, then refines with the exact equilibrium.
    seed
        Seed of the random starts.
    robot
        The campaign's robot (default :meth:`Campaign.robot`).
    progress
        Called as ``progress(done, total, text)`` after each least-squares run.
    loss
        ``linear`` (least squares), or the robust ``soft_l1``, ``huber`` or ``cauchy``
        (scipy's, ``f_scale`` the declared noise, the replicates' robust scatter or the
        robustly estimated noise; method ``trf`` only;
        intervals from Huber's sandwich covariance).

    Returns
    -------
    Identification or PoseIdentification
        Best solution over all starts and methods, with its uncertainty (a pose campaign:
        the springs' stiffnesses with the pose fit behind them).

    Raises
    ------
    StiffnessError
        Unknown formulation, method or loss (or a robust loss with ``lm``), fewer than one
        start, too few residuals (``lm`` needs
        at least as many residuals as stiffnesses; without a declared noise, sigma needs more
        residuals than stiffnesses), or a row whose configuration cannot be assembled; a
        ``formulation``, a ``method`` other than ``trf`` or a ``robot`` with a pose campaign.
    """
    if isinstance(campaign, PoseCampaign) or (
            not isinstance(campaign, Campaign) and campaign_kind(campaign) == "poses"):
        _check_pose_options(formulation, method, robot)
        return identify_poses(campaign if isinstance(campaign, PoseCampaign)
                              else load_pose_campaign(campaign), loss=loss)
    if not isinstance(campaign, Campaign):
        campaign = load_campaign(campaign)
    formulation = campaign.baseline if formulation is None else formulation
    _check_options(method, starts, loss, seed)
    rob = robot if robot is not None else campaign.robot()
    _check_residual_count(campaign, method, rob.n_compliant, loss)
    model = stiffness_model(campaign, formulation, rob)
    scale = residual_scale(campaign)
    options = fit_options(rob.n_compliant)
    known = translation_noise(campaign, loss)[0]  # diagnose's: declared, else the replicates'
    model, observed = weighted_observations(campaign, model, scale, options, known, loss,
                                            PAPER_START_SI)
    options = robust_loss_options(model, observed[0], scale, options, known, loss,
                                  PAPER_START_SI)
    floor = _k_c_floor(model, formulation)
    runs, fits = _least_squares_runs(model, observed[0], scale, formulation, method, starts,
                                     seed, floor, options, progress)
    return _identification(campaign, rob, model, formulation, method, runs, fits, floor,
                           observed, known)


def _identification(campaign: Campaign, rob: Robot, model: Hypothesis, formulation: str,
                    method: str, runs: list[StartResult], fits: list[Fit], floor: float,
                    observed: tuple, known: Noise | None = None) -> Identification:
    """The :class:`Identification` of the best run: its uncertainty, what is undetermined,
    whether the runs agree, the rows flagged as outliers. ``observed`` is ``(observations,
    weight (m/rad), rotation noise std (rad) or None, its source)``, the last three ``None``
    without measured rotations; ``known`` the campaign's known translation noise
    (:func:`~stiffness.calibration.deflection_noise.translation_noise`, ``None`` when not
    known)."""
    measured, weight, rot_sigma, rot_source = observed
    p = rob.n_compliant
    n_res = (3 if campaign.rotation is None else 6) * campaign.n_rows
    best_index = min(range(len(runs)), key=lambda i: runs[i].cost)
    best, best_fit = runs[best_index], fits[best_index]
    pred = best_fit.predicted[:, :3]
    fitted = len(best_fit.kept)  # a held stiffness takes no degree of freedom (as diagnose)
    rot_res, rot_sigma = residual_rotation_noise(campaign, best_fit, measured, rot_sigma,
                                                 rot_source, n_res, fitted)
    level = noise_level(campaign, known, best_fit, measured, n_res, fitted,
                        noise_terms(best_fit, measured))
    sigma, notes = level.noise.sigma, level.notes
    gof = None if level.fits_to_noise is None else level.fits_to_noise["p_value"]
    if best_fit.loss == "linear" and gof is not None and above_noise(gof):  # a sign reversed?
        notes += flipped_column_note(
            campaign, lambda c: stiffness_model(c, "enhanced" if formulation == "exact"
                                                else formulation, rob),
            best_fit.x, best_fit.rss, sigma, fit_options(p), weight)
    cov = covariance(best_fit, sigma, measured)
    intervals = interval_quantiles(level.noise, best_fit, n_res, campaign, measured)
    unc = _uncertainty(cov, best.k, intervals.two_sided(), rob.compliant_joints)
    bias = kinematics_bias(best_fit, cov.matrix) if formulation == "enhanced" else None
    notes += _bias_note(bias, rob.compliant_joints)
    rigid = _rigid(best_fit, sigma, measured, intervals.one_sided(), unc)
    outliers, flag_sigma = _outliers(best_fit, measured, campaign, fitted, notes)
    judged = stiffness_parameters(_judging(best_fit, campaign, sigma, intervals.two_sided(),
                                           measured), cov.matrix,
                                  intervals.two_sided(), intervals.one_sided())
    conditional = _conditional(compliance_spread(best_fit, sigma, measured).matrix
                               if rigid.any() else cov.matrix, rigid, rob.compliant_joints)
    scale = [p.scale_note for p in judged]
    if n_res <= fitted:  # nothing left to test the bound with: as diagnose, undetermined
        for j, names in enumerate(conditional):
            if names and judged[j].determined:
                scale[j] = (f"conditional on {', '.join(names)} held at its bound, with "
                            f"{n_res} residual components for {fitted} stiffnesses (no "
                            "residual freedom to test that bound)")
    undetermined = tuple(p.name for j, p in enumerate(judged)
                         if not p.determined or (conditional[j] and n_res <= fitted))
    determined = np.array([j not in undetermined for j in rob.compliant_joints])
    starts_agree, methods_agree = _agreement(runs, best, determined, method, notes)
    return Identification(
        **_provenance(campaign, rob),
        formulation=formulation,
        method=method,
        k=best.k,
        standard_error=best.k * unc.se_log,
        ci95_low=unc.low,
        ci95_high=unc.high,
        covariance_log=unc.covariance_log,
        noise=level.noise,
        sigma_source=level.source,
        sigma_residual_m=level.sigma_residual,
        residual_ss_m2=best_fit.rss,
        n_residuals=n_res,
        n_parameters=p,
        n_rows=campaign.n_rows,
        n_configurations=int(len(np.unique(model.rows.config_index))),
        condition_number=unc.condition_number,
        singular_values=unc.singular_values,
        relative_ci_width=unc.width,
        undetermined_joints=undetermined,
        undetermined_directions=unc.directions,
        starts=runs,
        starts_agree=bool(starts_agree),
        methods_agree=methods_agree,
        predicted=pred,
        residuals=pred - campaign.deflection,
        k_c_floor=floor,
        notes=notes,
        rotation_residuals=rot_res,
        rotation_sigma_rad=rot_sigma,
        rotation_sigma_source=rot_source,
        rotation_weight_m_per_rad=weight,
        loss=best_fit.loss,
        outliers=outliers,
        outlier_sigma_m=flag_sigma,
        stiffness_coordinates=rob.stiffness_coordinates,
        held=_held(best_fit),
        at_bound=tuple(bool(r) for r in rigid),
        kinematics_bias_se=bias,
        ci95_dof=tuple(intervals.reported_dof),
        physical_scale=tuple(scale),
        conditional_on=conditional,
        fits_to_noise=level.fits_to_noise,
    )


def _outliers(fit: Fit, measured: np.ndarray, campaign: Campaign, p: int, notes: list[str]
              ) -> tuple[list[Outlier], float | None]:
    """The rows of ``fit`` beyond :data:`OUTLIER_THRESHOLD` noise std and the noise std (m)
    they are flagged against (:func:`~stiffness.calibration.outliers.flag_fit`, ``p`` fitted
    parameters); appends a note when least squares kept some."""
    outliers, flag_sigma = flag_fit(fit, measured, campaign.noise_std_m, p,
                                    tuple(campaign.config or ()), campaign.lines)
    if outliers and fit.loss == "linear":
        notes.append(f"{len(outliers)} row(s) beyond {OUTLIER_THRESHOLD:g} noise std (listed "
                     "as outliers, kept in the fit); --loss soft_l1 weighs them down")
    return outliers, flag_sigma


def _provenance(campaign: Campaign, rob: Robot) -> dict[str, Any]:
    """The :class:`Identification` fields naming what was identified: the campaign and its
    path, the robot (source, loops, fixed base, name, target frame and offset, m), its
    compliant joints and their stiffness units."""
    options = campaign.robot_options()
    return {
        "campaign": campaign.name,
        "campaign_path": str(campaign.path) if campaign.path is not None else None,
        "robot_source": campaign.resolved_source(),
        "robot_loops": options["loops"],
        "robot_fixed_base": options["fixed_base"], "robot_name": rob.title,
        "robot_frame": rob.target_frame,
        "target_offset_m": rob.target_offset.copy(),
        "joints": tuple(rob.compliant_joints),
        "units": tuple(stiffness_unit(rob, j) for j in rob.compliant_joints),
    }


def _judging(fit: Fit, campaign: Campaign, sigma: float, quantile: np.ndarray,
             measured: np.ndarray) -> Fit:
    """``fit`` with diagnose's physical scales: its model's references at ``k_ref`` the
    geometric mean of the stiffnesses it determines (:func:`reference_stiffness`: their
    compliance's interval at the noise std ``sigma``, m, and two-sided ``quantile`` excluding
    zero), as diagnose sets them from its baseline
    (:func:`stiffness.calibration.diagnose`), so a stiffness's physical scale, ten times
    ``1 / k_ref`` in compliance, is the one diagnose judges it against."""
    model = fit.model
    refs = References.of(model.geometry, model.rows,
                         reference_stiffness(fit, sigma, quantile, measured),
                         campaign.deflection)
    return replace(fit, model=model.replaced(refs=refs))


def kinematics_bias(fit: Fit, cov_log: np.ndarray) -> np.ndarray:
    """Each stiffness's bias, in its standard errors, from the first-order kinematics of the
    ``enhanced`` formulation of ``fit`` (``dx = J dtheta``, A&S eq. 10): the second-order
    term of the exact equilibrium (``complementary_stiffness``'s at the fitted stiffnesses,
    exact to third order in the load) that least squares absorbs into ``ln k``,
    ``(J^T J)^-1 J^T`` of it (``J`` the fit's Jacobian over its kept parameters), over the
    standard errors ``sqrt(diag(cov_log))``; NaN for a held stiffness. It grows as the load
    squared: the deflection's second order over standard errors of the noise's size."""
    model = fit.model
    second = Hypothesis(model.geometry, model.rows, "conventional", model.compliant,
                        (make_effect("complementary_stiffness", None, model.geometry),),
                        model.refs, model.rotation_weight, model.held)
    gap = (second.predict(fit.x) - fit.predicted).reshape(-1)
    shift = np.full(fit.x.size, np.nan)
    shift[fit.kept] = np.linalg.lstsq(fit.jacobian[:, fit.kept] * fit.scale, gap, rcond=None)[0]
    n0 = len(model.compliant)
    with np.errstate(invalid="ignore", divide="ignore"):
        return shift[:n0] / np.sqrt(np.diag(cov_log)[:n0])


def _bias_note(bias: np.ndarray | None, joints: list[str] | tuple[str, ...]) -> list[str]:
    """A note naming the stiffnesses :func:`kinematics_bias` moves by more than
    :data:`KINEMATICS_BIAS_NOTE` standard errors (none: no note)."""
    if bias is None:
        return []
    over = [(j, b) for j, b in zip(joints, bias, strict=True)
            if math.isfinite(b) and abs(b) > KINEMATICS_BIAS_NOTE]
    if not over:
        return []
    named = ", ".join(f"{j} {b:+.2g}" for j, b in over)
    return [f"the enhanced formulation's first-order kinematics biases k by more than "
            f"{KINEMATICS_BIAS_NOTE:g} standard error at these loads ({named}; the exact "
            "equilibrium's second-order term, growing as the load squared): those intervals "
            "cover less than 95 %; --formulation exact fits it"]


def _rigid(fit: Fit, sigma: float, measured: np.ndarray, quantile: np.ndarray,
           unc: _Uncertainty) -> np.ndarray:
    """Which fitted stiffnesses are rigid to the data, as diagnose judges them
    (:func:`~stiffness.calibration.fitting.rigid_joints`); their intervals in ``unc`` made
    one-sided, the compliance's
    ``[0, quantile se_c]`` (``quantile`` the one-sided 95 % one per joint,
    :meth:`~stiffness.calibration.selection.Noise.one_sided`, as diagnose's) carried to
    ``k`` (above ``1 / (quantile se_c)``, ``se_c`` from the
    covariance in compliance units, where the data still see the joint), with no standard
    error (the delta method's ``k se(ln k)`` means nothing at ``c = 0``)."""
    n0 = len(fit.model.compliant)
    rigid = np.isin(np.arange(n0), rigid_joints(fit.model, fit.x, fit.kept))
    if rigid.any():
        var_log = np.diag(compliance_covariance(fit, sigma, measured))[:n0]
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            se_c = np.sqrt(var_log) * np.exp(-fit.x[:n0])  # SI: se(ln k) c
            unc.low[rigid] = np.where(np.isfinite(se_c), 1.0 / (quantile[:n0] * se_c),
                                      0.0)[rigid]
        unc.high[rigid] = np.inf
        unc.se_log[rigid] = np.inf
        unc.width[rigid] = np.inf
    return rigid


def _conditional(cov: np.ndarray, rigid: np.ndarray, joints: tuple[str, ...]
                 ) -> tuple[tuple[str, ...], ...]:
    """Per joint, the springs rigid to the data (``rigid``, at their bound) its estimate and
    interval are conditional on: those that hold an end of its interval and move it
    materially (:func:`~stiffness.calibration.selection.material_holders`, the rule of both
    campaign kinds, on ``cov`` in compliance units, where a rigid spring's variance is
    finite, :func:`~stiffness.calibration.fitting.compliance_spread`); none for a rigid one
    itself."""
    bound = np.flatnonzero(rigid)
    return tuple(() if rigid[j] else
                 tuple(joints[b] for b in bound[material_holders(cov, j, bound,
                                                                 np.ones(bound.size))])
                 for j in range(len(joints)))


def _held(fit: Fit) -> tuple[str | None, ...]:
    """Per parameter of ``fit``, why it was held at its nominal value (the identifiability's
    clause), or ``None``: fitted."""
    labels = fit.labels()
    ident = fit.identifiability
    dropped = [None if ident is None else ident.dropped_at(i) for i in range(fit.x.size)]
    return tuple(None if d is None else d.describe(labels) for d in dropped)


def _check_pose_options(formulation: str | None, method: str, robot: Robot | None) -> None:
    """Refuse the options a pose campaign does not take (one line each): its model is the
    sag's exact fixed point under its own robot, fitted by the pose engine."""
    if formulation is not None:
        raise StiffnessError(f"--formulation {formulation}: a pose campaign's springs are "
                             "fitted at the sag's exact fixed point; drop --formulation")
    if method != "trf":
        raise StiffnessError(f"--method {method}: a pose campaign is fitted by the pose "
                             "engine's trust-region solver; drop --method")
    if robot is not None:
        raise StiffnessError("robot=: a pose campaign names its robot in campaign.toml; "
                             "drop robot=")


def _check_options(method: str, starts: int, loss: str = "linear", seed: int | None = None
                   ) -> None:
    """Refuse an unknown method or loss, a robust loss with ``lm``, fewer than one start or a
    seed that is no whole number (one line; an unknown formulation: :func:`stiffness_model`)."""
    if seed is not None:
        whole_number(seed, "seed", 0)
    if method not in METHODS:
        raise UnknownNameError(f"unknown method {method!r}; valid methods: {', '.join(METHODS)}",
                               name=method, choices=METHODS)
    if whole_number(starts, "starts", None) < 1:
        raise StiffnessError(f"starts must be at least 1, got {starts}")
    check_loss(loss, method)


def _check_residual_count(campaign: Campaign, method: str, p: int, loss: str = "linear"
                          ) -> None:
    """Refuse a campaign with too few residuals for ``p`` stiffnesses (one line); a robust
    loss needs more residuals than stiffnesses (its sandwich covariance estimates the
    spread)."""
    n_res = (3 if campaign.rotation is None else 6) * campaign.n_rows
    if method in ("lm", "both") and n_res < p:
        raise StiffnessError(
            f"method lm needs at least as many residuals as stiffnesses ({n_res} < {p}); add "
            "measurement rows or use --method trf"
        )
    if (campaign.noise_std_m is None or loss != "linear") and n_res <= p:
        raise StiffnessError(
            f"{n_res} residuals cannot estimate the noise of {p} stiffnesses; add measurement "
            "rows or declare [measurement] noise_std"
        )


def _k_c_floor(model: Hypothesis, formulation: str) -> float:
    """The lowest start stiffness (SI): twice the largest eigenvalue of K_C over the rows
    (0 for the conventional formulation, which has no K_C)."""
    k_c = model.k_c()
    sym = 0.5 * (k_c + np.transpose(k_c, (0, 2, 1)))
    k_c_max = float(max(0.0, np.linalg.eigvalsh(sym).max())) if len(model.compliant) else 0.0
    return 0.0 if formulation == "conventional" else 2.0 * k_c_max


def _least_squares_runs(model: Hypothesis, measured: np.ndarray, scale: float, formulation: str,
                        method: str, starts: int, seed: int | None, floor: float,
                        options: dict, progress: Callable[[int, int, str], None] | None
                        ) -> tuple[list[StartResult], list[Fit]]:
    """Every least-squares run: each start (raised to ``floor``, SI) by each method; the
    exact formulation first converges each start with the enhanced one."""
    pre = model.replaced(baseline="enhanced") if formulation == "exact" else None
    methods = ("trf", "lm") if method == "both" else (method,)
    runs: list[StartResult] = []
    fits: list[Fit] = []
    total = int(starts) * len(methods)
    for k0 in _starts(len(model.compliant), int(starts), seed):
        k0 = np.maximum(k0, floor)
        x_start = np.log(k0)
        for meth in methods:
            x0 = x_start
            if pre is not None:
                x0 = fit_model(pre, measured, scale, x0, meth, anchor=x_start, **options).x
            fit = fit_model(model, measured, scale, x0, meth, anchor=x_start, **options)
            fits.append(fit)
            runs.append(StartResult(start=k0.copy(), method=meth, k=np.exp(fit.x),
                                    cost=fit.cost, success=fit.success, message=fit.message,
                                    nfev=fit.nfev))
            if progress is not None:
                progress(len(runs), total, f"{meth} from {np.array2string(k0, precision=3)}: "
                                           f"cost {runs[-1].cost:.6g}")
    return runs, fits


def _agreement(runs: list[StartResult], best: StartResult, determined: np.ndarray,
               method: str, notes: list[str]) -> tuple[bool, bool | None]:
    """Whether every run reached the best cost and stiffnesses, and (``both``) whether trf and
    lm agree; appends a note on runs that did not."""
    tol_cost = 1e-6 * best.cost + 1e-20
    at_best = [run.cost <= best.cost + tol_cost for run in runs]
    starts_agree = all(ok and _agree(run.k, best.k, determined)
                       for ok, run in zip(at_best, runs, strict=True))
    if not all(at_best):
        notes.append(
            f"{at_best.count(False)} of {len(runs)} runs ended at a higher cost (a local minimum, "
            "or stalled on a plateau where a stiffness is so high its joint no longer "
            "contributes); the best run is kept"
        )
    elif not starts_agree:
        notes.append("runs reach the same cost with different determined stiffnesses")
    methods_agree = None
    if method == "both":
        best_of = {mm: min((r for r in runs if r.method == mm), key=lambda r: r.cost)
                   for mm in ("trf", "lm")}
        methods_agree = _agree(best_of["trf"].k, best_of["lm"].k, determined) and abs(
            best_of["trf"].cost - best_of["lm"].cost) <= tol_cost
    return starts_agree, methods_agree
