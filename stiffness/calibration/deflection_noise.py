"""The noise of a deflection fit, for ``identify`` and ``diagnose`` alike: each kind's known
noise std (:func:`known_noise`, :func:`translation_noise`), the weight of measured rotations
beside the translations (:func:`weighting`) and the noise of a fit's intervals
(:func:`fit_noise`; a robust fit's unknown noise, :func:`robust_fit_noise`) with each
parameter's quantile (:func:`interval_quantiles`); and how
``identify`` applies them: its observations at the weight
(:func:`weighted_observations`), its robust loss's scale (:func:`robust_loss_options`), the
rotation noise of its best fit (:func:`residual_rotation_noise`) and the noise of its
intervals with the test against a known one (:func:`noise_level`).

A deflection campaign that measures rotations (rad) beside translations (m) is fitted on
``[d; w r]``, ``w = sigma_t / sigma_r`` (m/rad, :func:`~stiffness.calibration.fitting.
observations`), so that one scale ``sigma_t`` whitens both kinds. Each kind's noise std is
known when declared (``noise_std``, ``rotation_noise_std``), else when the campaign repeats
rows (the replicates' pooled scatter, robust under a robust loss:
:func:`~stiffness.calibration.selection.replicate_noise`), and otherwise estimated from the
residuals of a fit of that kind (:func:`~stiffness.calibration.fitting.kind_noise`). The
residuals depend on the weight they are fitted at, so an estimated std is the fixed point of
``w -> s_t(w) / s_r(w)`` over the caller's baseline fit at ``w``, reached from the ratio of
the known stds or, for an unknown one, of the measured RMS of that kind (:func:`weighting`).

A parameter's variance is then the sum of the translations' and the rotations' contributions,
each scaled by its kind's noise variance, known or estimated over its own degrees of freedom:
the quantile of its interval is Student's t with their Welch-Satterthwaite effective degrees
of freedom (:func:`interval_quantiles`, :func:`effective_dof`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.special import ndtri, stdtrit

from stiffness.calibration.campaign import Campaign
from stiffness.calibration.fitting import (
    Fit,
    compliance_slope,
    compliance_spread,
    fit_model,
    kind_noise,
    observations,
)
from stiffness.calibration.outliers import robust_noise, robust_noise_scale
from stiffness.calibration.selection import (
    GOF_LEVEL,
    OVERSTATED_P,
    Noise,
    NoiseTerms,
    above_noise,
    excluded_note,
    noise_overstated,
    pooled_replicates,
    replicate_noise,
)
from stiffness.elastic.effects.hypothesis import Hypothesis

#: The weight's fixed point is reached when a round moves it by at most this fraction.
WEIGHT_TOLERANCE = 1e-3
#: Baseline fits at most spent on the fixed point (2 to 11 on UR5 campaigns of 2 poses x 2
#: loads, from a first weight far below it: the measured rotations are mostly signal).
MAX_ROUNDS = 20
#: The robust rounds of both commands (:func:`robust_loss_options`) go on until a round moves
#: the loss's scale by at most this fraction of it ... Two rounds stopped while it still fell:
#: UR5, 12 rows, 3 springs, 20 um undeclared, soft_l1, two rows moved by 1000 noise stds,
#: seeds 0-99: least squares' residuals read 10-100 noise stds (seeds traced), each round
#: cuts that several fold, and two rounds left it above 3 noise stds on 25 seeds (max 24.9,
#: 270/300 intervals covering); settled, on 3 (max 10.8, a fixed point: the loss's fit at
#: that scale lets the gross rows hold a spring rigid), 275/300; clean and 20-50 stds
#: unchanged (docs/outliers.md).
SCALE_TOLERANCE = 0.01
#: ... in at most this many rounds (the first from least squares; those seeds settled in 3-9).
SCALE_ROUNDS = 12


def known_noise(campaign: Campaign, kind: str = "translation", robust: bool = False
                ) -> tuple[float, int | None, str] | None:
    """A ``kind``'s (``translation``, m; ``rotation``, rad) known noise std, its degrees of
    freedom and its source: the declared one (``None`` degrees of freedom, ``declared``),
    else the replicates' (``replicates``; robust under a robust loss,
    :func:`~stiffness.calibration.selection.replicate_noise`); ``None`` when only the
    residuals can tell (or the campaign measures no rotations)."""
    declared = (campaign.noise_std_m if kind == "translation"
                else campaign.rotation_noise_std_rad)
    if declared is not None:
        return declared, None, "declared"
    rep = replicate_noise(campaign, kind, robust=robust)
    return None if rep is None else (rep[0], rep[1], "replicates")


def translation_noise(campaign: Campaign, loss: str = "linear"
                      ) -> tuple[Noise | None, str, str]:
    """The translation noise (m; ``None`` when only the residuals can tell), its source
    (``declared``, ``replicates`` or ``residuals``) and a note on it: :func:`known_noise` with
    its degrees of freedom, the replicates' robust under a robust ``loss``."""
    known = known_noise(campaign, robust=loss != "linear")
    if known is None:
        return None, "residuals", ""
    sigma, dof, source = known
    if dof is None:
        return Noise(sigma), source, "declared noise_std of the campaign"
    if loss != "linear":
        return (Noise(sigma, dof), source,
                "robust scatter of replicate rows (1.4826 median |deviation from the group "
                f"mean|, {dof} degrees of freedom)")
    return (Noise(sigma, dof), source,
            f"pooled scatter of replicate rows ({dof} degrees of freedom)")


def fit_noise(known: Noise | None, fit: Fit, n: int, measured: np.ndarray) -> Noise:
    """The noise of ``fit``'s covariance and intervals over ``n`` residuals
    (:class:`~stiffness.calibration.selection.Noise`), ``fit`` to the observations
    ``measured`` (m): ``known`` (the campaign's, declared or the replicates' with their degrees
    of freedom), else estimated from ``fit``'s residuals over its ``n - p`` degrees of freedom:
    under a robust loss their robust scale (:func:`robust_fit_noise`), under least squares
    ``sqrt(SS / (n - p))``; under a robust loss the sandwich's, over the directions the
    reported covariance spreads over (:meth:`~stiffness.calibration.selection.Noise.of_fit`,
    :func:`compliance_spread`). identify's and diagnose's."""
    p = fit.penalty_params
    noise = known
    if noise is None:
        robust = robust_fit_noise(fit, measured)
        noise = Noise.estimated(robust if robust is not None
                                else math.sqrt(fit.loss_rss / max(n - p, 1)), n, p)
    return noise.of_fit(fit.loss, n, compliance_spread(replace(fit, loss="linear")))


def robust_fit_noise(fit: Fit, measured: np.ndarray) -> float | None:
    """The noise std (m) of a robust ``fit`` when no noise is known, identify's and diagnose's
    (issue 35: one estimate of one std): the robust scale of its residuals on ``measured``
    (m, rotations weighted), :func:`~stiffness.calibration.outliers.robust_noise` over its
    :attr:`~stiffness.calibration.fitting.Fit.penalty_params` at its loss's scale, the rule of
    the rounds that scaled the loss (:func:`~stiffness.calibration.outliers.robust_rounds`)
    applied to the fit itself. Not the loss's value at that scale (``loss_rss``), which a few
    gross rows inflate: on 300 UR5 campaigns of 12 rows, 2 of them moved by 20-50 noise
    stds, the robust scale is 1.30 times the true std (spread 0.28) and the loss's value 3.39
    (0.51); without gross rows 1.02 (0.21) and 1.00 (0.13) (docs/architecture.md). ``None``
    for least squares, or without degrees of freedom or nonzero residuals.
    """
    if fit.loss == "linear":
        return None
    return robust_noise(fit.predicted - measured, fit.penalty_params, fit.loss,
                        fit.f_scale * fit.scale)


def effective_dof(contributions: np.ndarray, dofs: np.ndarray) -> np.ndarray:
    """Welch-Satterthwaite effective degrees of freedom of variances ``V = sum_k c_k``, each
    contribution ``c_k = a_k s_k^2`` (rows of ``contributions``, one column per parameter)
    scaled by a noise variance estimated over ``dofs[k]`` degrees of freedom (``inf`` for a
    known one): ``nu_eff = V^2 / sum_k c_k^2 / nu_k`` (Satterthwaite 1946, eq. 3), ``inf``
    when every contributing variance is known. One kind alone gives its own ``nu_k``."""
    c = np.asarray(contributions, dtype=float)
    nu = np.asarray(dofs, dtype=float).reshape(-1, 1)
    spread = np.sum(np.divide(c ** 2, nu, out=np.zeros_like(c), where=np.isfinite(nu)), axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(spread > 0, np.sum(c, axis=0) ** 2 / spread, np.inf)


@dataclass(frozen=True)
class Quantiles:
    """The noise of a deflection fit's 95 % intervals and their quantiles
    (:func:`interval_quantiles`).

    Attributes
    ----------
    noise
        The noise of the fit's covariance (:func:`fit_noise`).
    dof
        Per column of the fit's ``x``, the degrees of freedom of its standardised error:
        Student's t with them, the standard normal where ``inf``.
    """

    noise: Noise
    dof: np.ndarray

    def quantile(self, level: float) -> np.ndarray:
        """Each parameter's ``level`` quantile (Student's t, the normal's at ``inf``)."""
        nu = np.asarray(self.dof, dtype=float)
        finite = np.isfinite(nu)
        return np.where(finite, stdtrit(np.where(finite, nu, 1.0), level), ndtri(level))

    def two_sided(self) -> np.ndarray:
        """Each parameter's quantile of a two-sided 95 % interval (97.5 %)."""
        return self.quantile(0.975)

    def one_sided(self) -> np.ndarray:
        """Each parameter's quantile of a one-sided 95 % interval (95 %), at its bound."""
        return self.quantile(0.95)

    @property
    def reported_dof(self) -> list[float | None]:
        """:attr:`dof` as a report gives it: ``None`` for the normal's (``inf``)."""
        return [float(v) if math.isfinite(v) else None for v in self.dof]


def kind_dof(campaign: Campaign, kind: str, n: int, p: int) -> float:
    """The degrees of freedom of a ``kind``'s (``translation``, ``rotation``) noise std in a
    fit of ``p`` parameters to ``n`` residual components of a campaign measuring rotations:
    ``inf`` declared, the replicates' (:func:`known_noise`), else the residuals' share,
    ``n / 2 - p / 2`` (:func:`~stiffness.calibration.fitting.kind_noise`)."""
    known = known_noise(campaign, kind)
    if known is None:
        return max(0.5 * (n - p), 1.0)
    return math.inf if known[1] is None else float(known[1])


def interval_quantiles(known: Noise | None, fit: Fit, n: int, campaign: Campaign | None,
                       measured: np.ndarray) -> Quantiles:
    """The noise of ``fit``'s 95 % intervals over ``n`` residual components
    (:func:`fit_noise` of ``known``, ``fit`` to ``measured``, m) and each parameter's
    quantile: the one rule of ``identify`` and ``diagnose``.

    Without measured rotations (or ``campaign`` ``None``), or under a robust loss (the
    sandwich takes its spread from the residuals over ``noise.dof``), every parameter takes
    the noise's degrees of freedom (:meth:`~stiffness.calibration.selection.Noise.quantile`). With
    rotations under least squares, a parameter's variance is ``a_t s_t^2 + a_r w^2 s_r^2``
    (``w = s_t / s_r``, so both terms are in ``s_t^2``): the diagonal of
    ``C G_kind^T G_kind C`` for each kind's rows ``G_kind`` of the whitened Jacobian in
    compliance units, ``C`` the covariance (:func:`compliance_spread`). Each kind's std comes
    with its own degrees of freedom (:func:`kind_dof`), and the parameter's t has their
    :func:`effective_dof`: about ``nu_r`` for a stiffness the rotations determine, hundreds
    for one the declared translations determine, ``inf`` (the normal's) with both declared.
    The normal's for every parameter under-covered with an undeclared rotation noise over few
    degrees of freedom, t with ``nu_r`` over-covered (2 poses x 2 loads, nu_r = 9: a
    rotation-determined stiffness 0.922 and 0.963, t with ``nu_eff`` 0.951; docs/diagnose.md,
    "Rotations")."""
    noise = fit_noise(known, fit, n, measured)
    out = np.full(fit.x.size, math.inf if noise.dof is None else float(noise.dof))
    if campaign is None or campaign.rotation is None or fit.loss != "linear":
        return Quantiles(noise, out)
    kept = np.asarray(fit.kept, dtype=int)
    jac = (fit.jacobian / compliance_slope(fit))[:, kept]  # rows of [d; w r], 6 per row
    cov = compliance_spread(fit).matrix[np.ix_(kept, kept)]  # a common factor: no matter
    dofs = np.array([kind_dof(campaign, k, n, fit.penalty_params)
                     for k in ("translation", "rotation")])
    rotation_rows = (np.arange(jac.shape[0]) % 6) >= 3
    with np.errstate(invalid="ignore"):
        parts = np.array([np.einsum("ij,ij->j", g @ cov, g @ cov)
                          for g in (jac[~rotation_rows], jac[rotation_rows])])
    out[kept] = np.where(np.isfinite(parts).all(axis=0), effective_dof(
        np.nan_to_num(parts), dofs), out[kept])  # an undetermined one's interval is infinite
    return Quantiles(noise, out)


@dataclass(frozen=True)
class RotationWeight:
    """The rotations' weight of a campaign that measures them (:func:`weighting`).

    Attributes
    ----------
    weight
        ``w = sigma_t / sigma_r`` (m/rad).
    sigma_rad
        The rotation noise std (rad): the known one, else the residuals' at :attr:`fit`
        (``None`` without degrees of freedom).
    source
        Where ``sigma_rad`` comes from: ``declared``, ``replicates`` or ``residuals``.
    fit
        The caller's baseline fit at :attr:`weight`, ``None`` when both noise stds are known
        (no fit was needed).
    """

    weight: float
    sigma_rad: float | None
    source: str
    fit: Fit | None = None

    def measured(self, campaign: Campaign) -> np.ndarray:
        """The campaign's observations at this weight (m; ``[d; w r]``)."""
        return observations(campaign.deflection, campaign.rotation, self.weight)


def weighting(campaign: Campaign, translation: float | None,
              fit: Callable[[float, Fit | None], Fit], robust: bool = False) -> RotationWeight:
    """The weight of a ``campaign``'s measured rotations, ``sigma_t / sigma_r`` (m/rad).

    Parameters
    ----------
    campaign
        A deflection campaign with measured rotations.
    translation
        The known translation noise std (m: declared, or the replicates'; :func:`known_noise`),
        ``None`` to estimate it from the residuals.
    fit
        The caller's baseline fit at a weight, ``fit(weight, previous)``, ``previous`` the
        last round's fit (``None`` at the first) to start from; asked only when a std is to be
        estimated.
    robust
        Whether the replicates' scatter is the robust one (a robust loss).

    Returns
    -------
    RotationWeight
        The weight with the rotation noise std: both known, their ratio and no fit; else the
        fixed point of ``w -> s_t / s_r``, each unknown std from the residuals of ``fit(w)``
        (:func:`~stiffness.calibration.fitting.kind_noise` over ``6 m`` components and the
        fit's parameters), from the known stds or the measured RMS of the unknown kind, until
        a round moves ``w`` by at most :data:`WEIGHT_TOLERANCE` of it (at most
        :data:`MAX_ROUNDS` fits), with the fit at the weight returned.
    """
    rotation = campaign.rotation
    assert rotation is not None  # a campaign with rotations
    known = known_noise(campaign, "rotation", robust)
    sigma_r, source = (known[0], known[2]) if known is not None else (None, "residuals")
    if translation is not None and sigma_r is not None:
        return RotationWeight(translation / sigma_r, sigma_r, source)
    rms_t = float(np.sqrt(np.mean(campaign.deflection ** 2))) or 1.0
    rms_r = float(np.sqrt(np.mean(rotation ** 2))) or 1.0
    weight = (translation or rms_t) / (sigma_r or rms_r)
    current: Fit | None = None
    estimated = sigma_r
    for _ in range(MAX_ROUNDS):
        current = fit(weight, current)
        res_t, res_r = current.residuals(observations(campaign.deflection, rotation, weight))
        n, p = 2 * campaign.deflection.size, len(current.x)
        s_t = translation if translation is not None else kind_noise(res_t, n, p)
        estimated = sigma_r if sigma_r is not None else kind_noise(res_r, n, p)
        if not s_t or not estimated or math.isclose(s_t / estimated, weight,
                                                    rel_tol=WEIGHT_TOLERANCE):
            break
        weight = s_t / estimated
    else:  # not settled: the last weight, fitted
        current = fit(weight, current)
    return RotationWeight(weight, estimated, source, current)


def weighted_observations(campaign: Campaign, model: Hypothesis, scale: float, options: dict,
                          known: Noise | None, loss: str, start_si: float
                          ) -> tuple[Hypothesis, tuple]:
    """``identify``'s model and the observations it is fitted to, as ``(model, (observations,
    weight (m/rad), rotation noise std (rad) or None, its source))``: the translations (m)
    alone, the last three ``None``, or with the rotations weighted by :func:`weighting`
    (``scale`` the residual scale, m; ``known`` the translations' noise; the fits start with
    every stiffness at ``start_si``, N.m/rad or N/m)."""
    if campaign.rotation is None:
        return model, (campaign.deflection, None, None, None)
    model, measured, weight, rot_sigma, rot_source = _fitted_weighting(
        campaign, model, scale, options, known, loss != "linear", start_si)
    return model, (measured, weight, rot_sigma, rot_source)


def _fitted_weighting(campaign: Campaign, model: Hypothesis, scale: float, options: dict,
                      known: Noise | None, robust: bool, start_si: float
                      ) -> tuple[Hypothesis, np.ndarray, float, float | None, str]:
    """The model and observations of a campaign with rotations, the weight
    ``w = sigma_t / sigma_r`` (m/rad), the rotation noise std (rad; ``None`` until estimated
    from the best fit's residuals) and its source: diagnose's rule (:func:`weighting`: each
    kind's declared std, else its replicates', else the fixed point over the residuals of a
    fit from every stiffness at ``start_si``), ``known`` the translations'
    (:func:`translation_noise`), the replicates' robust under a ``robust`` loss."""
    x_start = np.full(len(model.compliant), math.log(start_si))
    rotation = campaign.rotation
    assert rotation is not None  # a campaign with rotations

    def at(weight: float, previous: Fit | None) -> Fit:
        x0 = x_start if previous is None else previous.x
        return fit_model(model.replaced(rotation_weight=weight),
                         observations(campaign.deflection, rotation, weight), scale, x0,
                         anchor=x0, **options)

    rotations = weighting(campaign, None if known is None else known.sigma, at, robust)
    source = {"declared": "declared rotation_noise_std"}.get(rotations.source, rotations.source)
    return (model.replaced(rotation_weight=rotations.weight), rotations.measured(campaign),
            rotations.weight, rotations.sigma_rad if rotations.source != "residuals" else None,
            source)


def residual_scale(campaign: Campaign) -> float:
    """identify's fixed scale ``s`` (m) the residuals are divided by, that of the robust
    rounds of both commands (:func:`robust_loss_options`): the declared noise std, else the
    RMS of the measured deflections (``1e-3`` when they are all zero; sigma is then estimated
    from the residuals)."""
    if campaign.noise_std_m is not None:
        return campaign.noise_std_m
    rms = float(np.sqrt(np.mean(campaign.deflection ** 2)))
    return rms if rms > 0 else 1e-3


def fit_options(n_stiffnesses: int) -> dict:
    """identify's solver options for a model of ``n_stiffnesses`` springs, which the robust
    rounds of identify and diagnose fit with (:func:`robust_loss_options`; issue 35: one
    engine): ``ln k`` unbounded, tolerance 1e-12, ``200 (p + 1)`` evaluations. diagnose's
    former rounds (until 6 December 2026: bounded, tolerance 1e-10, from its bounded
    least-squares baseline) failed a UR5 campaign of 12 rows, two moved by 1000 noise stds:
    least squares put two of the three springs at the 1e14 rigid bound, the soft_l1 refit
    (scaled by 27 noise stds) stopped there after 6 evaluations, and the next scale was 23
    noise stds (first stiffness 33 200 N.m/rad); identify's rounds reach 1.08 (30 600, truth
    30 000)."""
    return {"bounded": False, "tolerance": 1e-12, "max_nfev": 200 * (n_stiffnesses + 1)}


def robust_loss_options(model: Hypothesis, measured: np.ndarray, scale: float, options: dict,
                        known: Noise | None, loss: str, start_si: float) -> dict:
    """``identify``'s solver ``options`` with a robust ``loss`` and its ``f_scale`` (in units
    of the residual ``scale``): the known noise std, else the robust one
    (:func:`~stiffness.calibration.outliers.robust_noise_scale`, from every stiffness at
    ``start_si``, its rounds until a round moves the scale by at most
    :data:`SCALE_TOLERANCE`, at most :data:`SCALE_ROUNDS`); for least squares, ``options``
    unchanged. identify's and diagnose's."""
    if loss == "linear":
        return options
    robust_sigma = robust_scale(model, measured, scale, options, known, loss, start_si)
    return {**options, "loss": loss, "f_scale": robust_sigma / float(scale)}


def robust_scale(model: Hypothesis, measured: np.ndarray, scale: float, options: dict,
                 known: Noise | None, loss: str, start_si: float) -> float:
    """The noise std (m) a robust ``loss`` is scaled by in both commands: the ``known`` one,
    else :func:`~stiffness.calibration.outliers.robust_noise_scale` of fits with ``options``
    to ``measured`` (m) at the residual ``scale`` (m), from every stiffness at ``start_si``,
    its rounds until a round moves the scale by at most :data:`SCALE_TOLERANCE`, at most
    :data:`SCALE_ROUNDS`."""
    return robust_noise_scale(model, measured, float(scale),
                              None if known is None else known.sigma, loss, options, start_si,
                              (SCALE_TOLERANCE, SCALE_ROUNDS))


def residual_rotation_noise(campaign: Campaign, fit: Fit, measured: np.ndarray,
                            sigma: float | None, source: str | None, n: int, p: int
                            ) -> tuple[np.ndarray | None, float | None]:
    """The rotation residuals (rad) of ``fit`` on ``measured`` and the rotation noise std
    (rad): ``sigma`` as given, or, when its ``source`` is the residuals (neither declared nor
    the replicates'), estimated from them over ``n`` residuals and ``p`` fitted parameters
    (:func:`~stiffness.calibration.fitting.kind_noise`); ``(None, sigma)`` when the
    ``campaign`` measured no rotations."""
    if campaign.rotation is None:
        return None, sigma
    residuals = fit.residuals(measured)[1]
    if source == "residuals":  # neither declared nor the replicates'
        sigma = kind_noise(residuals, n, p)
    return residuals, sigma


@dataclass(frozen=True)
class NoiseLevel:
    """The noise of an identification (:func:`noise_level`), ``identify``'s.

    Attributes
    ----------
    noise
        The noise std (m) the covariance uses and how it is known
        (:class:`~stiffness.calibration.selection.Noise`: declared, or estimated over the fit's
        ``n - p`` degrees of freedom); its intervals' quantiles are those of
        ``noise.of_fit(loss, n, covariance)``.
    source
        Where it comes from, in words (``Identification.sigma_source``).
    sigma_residual
        The residuals' own estimate (m), ``None`` without degrees of freedom.
    notes
        Where the residuals and a known noise disagree.
    fits_to_noise
        The test of fitting to the known noise (declared, or the replicates'): its
        ``p_value``, ``level``, ``test`` and ``final_rows_excluded`` (the rows flagged as
        outliers a robust loss's test left out); ``None`` when the noise is not known.
    """

    noise: Noise
    source: str
    sigma_residual: float | None
    notes: list[str]
    fits_to_noise: dict | None = None


def noise_level(campaign: Campaign, known: Noise | None, fit: Fit, measured: np.ndarray,
                n: int, p: int, terms: NoiseTerms) -> NoiseLevel:
    """The noise of ``identify``'s intervals (:class:`NoiseLevel`) from its best ``fit`` to
    ``measured`` (m) over ``n`` residuals and ``p`` fitted stiffnesses, ``known`` the
    campaign's known translation noise (declared, else the replicates', robust under a robust
    loss: :func:`translation_noise`, diagnose's); else estimated from the fit's residuals as
    diagnose estimates it (:func:`fit_noise`): under a robust loss their robust scale
    (:func:`robust_fit_noise`), under least squares ``SS / (N - p)``. A known one is tested
    as ``diagnose`` tests it, on the fit's ``terms``
    (:func:`~stiffness.calibration.selection.noise_terms`: a robust loss's flagged rows left
    out) through :func:`~stiffness.calibration.selection.pooled_replicates` (the rotation
    replicates' degrees of freedom with it, or the rotations' noise being the residuals')."""
    robust = fit.loss != "linear"
    dof = n - p
    sigma_res = math.sqrt(fit.rss / dof) if dof > 0 else None
    if known is not None:
        tested = pooled_replicates(known, campaign, robust)
        assert tested is not None  # a known noise
        if known.declared:
            return NoiseLevel(known, "declared noise_std", sigma_res,
                              *_tested(tested, terms, "declared noise_std"))
        scatter = "robust" if robust else "pooled"
        return NoiseLevel(known, f"replicates ({scatter} scatter, {known.dof} degrees of "
                          "freedom)", sigma_res, *_tested(tested, terms, "replicate rows' "
                                                          "scatter"))
    if (robust_sigma := robust_fit_noise(fit, measured)) is not None:
        return NoiseLevel(Noise.estimated(robust_sigma, n, p),
                          "robust estimate (1.4826 median |residual|)", sigma_res, [])
    # dof > 0 without a declared noise: identify's _check_residual_count
    assert sigma_res is not None
    return NoiseLevel(Noise.estimated(sigma_res, n, p), "residuals (SS / (N - p))", sigma_res,
                      [])


def _tested(noise: Noise, terms: NoiseTerms, name: str) -> tuple[list[str], dict]:
    """The notes and the ``fits_to_noise`` record of the test of fitting to a known
    ``noise`` (its ``name`` in words) on ``terms``: residuals above it (model error or an
    underestimated noise), or a declared one far below (overstated)."""
    gof = terms.p_value(noise)
    dof = terms.n - terms.p
    sigma = math.sqrt(terms.rss / dof) if dof > 0 else None
    left_out = excluded_note(terms.excluded)
    notes = []
    if sigma is not None and gof is not None and above_noise(gof):
        notes.append(
            f"the residuals (sigma {sigma * 1e3:.4g} mm) are larger than the {name} "
            f"({noise.sigma * 1e3:.4g} mm; {noise.test} p = {gof:.3g} <= "
            f"{1.0 - GOF_LEVEL:.2g}{left_out}): " + (
                "model error or underestimated noise; the confidence intervals are too narrow "
                "(stiffness diagnose finds what is missing)" if noise.declared else
                "the model misses something; the confidence intervals are too narrow "
                "(stiffness diagnose finds what is missing)"))
    if sigma is not None and noise.declared and noise_overstated(gof):
        notes.append(
            f"the residuals (sigma {sigma * 1e3:.4g} mm) are much smaller than the {name} "
            f"({noise.sigma * 1e3:.4g} mm; {noise.test} lower tail p < {OVERSTATED_P:g}"
            f"{left_out}): overstated noise, or averaged rows; the confidence intervals are too "
            "wide and an effect below the noise goes unseen")
    return notes, {"p_value": gof, "level": GOF_LEVEL, "test": noise.test,
                   "final_rows_excluded": terms.excluded}
