"""Model selection for ``diagnose``: fitting a hypothesis (from a non-negative linear start),
its information criterion and overdispersion, cross-validation over configurations (over one
configuration's loads, and what those rows can judge, when there is one), the test of
fitting to noise, the noise of a fit's intervals with their quantiles (:class:`Noise`) and
the noise of replicate rows.

SI inside (m, N, rad).
"""


from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import nnls
from scipy.special import chdtrc, fdtrc, gammaln, ndtri, stdtrit, xlogy

from stiffness.calibration import fitting
from stiffness.calibration.campaign import Campaign
from stiffness.calibration.fitting import Fit, FitJob
from stiffness.calibration.identifiability import NEAR_ALIAS_RESOLUTION
from stiffness.calibration.measurements import first_copies
from stiffness.calibration.outliers import STRAY_SHARE, flag_fit, robust_noise
from stiffness.calibration.solver import Covariance
from stiffness.elastic.effects.hypothesis import Hypothesis

#: Goodness-of-fit level: the model explains the data to noise when the test of
#: ``RSS / sigma^2`` (:meth:`Noise.goodness_of_fit`: chi-square with ``N - p`` degrees of
#: freedom for a declared noise, the lack-of-fit F test for the replicates') does not reject
#: at this level.
GOF_LEVEL = 0.95
#: A candidate (an effect, a pose family) must lower BIC by more than this to be added.
BIC_MARGIN = 2.0
#: Number of best-BIC candidates (effects, pose families) cross-validated per step.
CV_TOP = 3
#: The word that opens the reason a search refuses a fit whose values no robot has
#: (:meth:`~stiffness.calibration.search.SearchKind.unphysical`), read back by the verdict.
UNPHYSICAL = "unphysical"
#: Solver tolerance of the first fit of every candidate: a step stops once it lowers the cost
#: by less than this fraction, a change of about ``1e-6 N`` in ``RSS / sigma^2``, far inside
#: :data:`BIC_MARGIN` (an extension that trades a joint's compliance against an equivalent
#: one crawls along that valley for a hundred steps otherwise).
SCREEN_TOLERANCE = 1e-6
#: Folds over configuration labels when there are more than :data:`LOCO_MAX` configurations.
CV_FOLDS = 6
#: Up to this many configurations, cross-validation leaves one configuration out at a time.
LOCO_MAX = 12

_MIN_REPLICATE_DOF = 9


def fit_job(model: Hypothesis, measured: np.ndarray, scale: float, x0: np.ndarray,
            max_nfev: int | None = None, tolerance: float = 1e-10, loss: str = "linear",
            f_scale: float = 1.0) -> FitJob:
    """The fitting engine's bounded trf fit of ``model`` on ``measured`` (m, 3) from ``x0``
    to the solver ``tolerance`` under ``loss`` (soft threshold ``f_scale`` in units of
    ``scale``), to run (:class:`stiffness.calibration.fitting.FitJob`)."""
    return FitJob(model, measured, scale, x0,
                  {"max_nfev": max_nfev, "x_scale": 1.0, "tolerance": tolerance,
                   "loss": loss, "f_scale": f_scale, "resolution": NEAR_ALIAS_RESOLUTION})


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


def step_criteria(current: tuple[float, int], extensions: list[tuple[float, int]], n: int,
                  sigma: float | None) -> tuple[float, list[float], float]:
    """The information criteria of a selection step, for either campaign kind: the current
    model's BIC, each extension's, and the step's overdispersion ``c``; models are given as
    ``(RSS m^2, parameters)``.

    ``c = max(1, min_f RSS_f / (sigma^2 (N - p_f)))`` over the current model and its
    extensions (1 with an unknown sigma): what the best extension leaves above the noise is
    structure no candidate of the step models; it acts as extra noise on every comparison of
    the step. The step's BICs therefore use ``c sigma^2`` (a quasi-likelihood BIC), so that a
    candidate must explain a share of the *remaining* misfit, not only beat the measurement
    noise, to be named. When one extension fits to noise, ``c = 1`` and the BIC is the plain
    known-sigma one.
    """
    models = [current, *extensions]
    c = 1.0 if sigma is None else max(1.0, min(r / (sigma ** 2 * max(n - p, 1))
                                               for r, p in models))
    s_step = None if sigma is None else sigma * math.sqrt(c)
    return (information_criterion(current[0], n, current[1], s_step),
            [information_criterion(r, n, p, s_step) for r, p in extensions], c)


def config_folds(labels: tuple[str, ...], seed: int = 0, loads: np.ndarray | None = None
                 ) -> list[np.ndarray]:
    """Held-out row indices of each fold: one configuration label each, or
    :data:`CV_FOLDS` groups of labels when there are more than :data:`LOCO_MAX`. With a single
    configuration and the rows' ``loads`` (wrenches, (m, 6) N and N.m) given, the rows of
    one load each instead (its repeats held out together), grouped alike: one configuration's
    rows held out one load at a time (:func:`row_support` says which models they judge)."""
    keys: list = list(labels)
    if len(dict.fromkeys(keys)) < 2 and loads is not None:
        keys = [tuple(np.round(w, 6)) for w in np.asarray(loads)]
    unique = list(dict.fromkeys(keys))
    if len(unique) < 2:
        return []
    if len(unique) <= LOCO_MAX:
        groups = [[u] for u in range(len(unique))]
    else:
        order = np.random.default_rng(seed).permutation(len(unique))
        groups = [[int(i) for i in order[f::CV_FOLDS]] for f in range(CV_FOLDS)]
    index = {u: i for i, u in enumerate(unique)}
    which = np.array([index[k] for k in keys])
    return [np.flatnonzero(np.isin(which, g)) for g in groups]


def row_support(folds: list[np.ndarray], measured: np.ndarray, rss: float, p: int,
                noise: Noise | None, translations: tuple[float, int, float] | None = None,
                n: int | None = None) -> str | None:
    """Why the rows of one configuration cannot name a model of ``p`` parameters (residual sum
    of squares ``rss``, m^2) held out over ``folds`` (:func:`config_folds` over its loads), or
    ``None`` when they can: no load to hold out; a fold whose fit keeps no more residual
    components than ``p`` (the held-out error then judges an interpolation; with none left
    over all rows, the model explains them with zero degrees of freedom); or, with a known
    ``noise`` (declared or the replicates'), a fit below it (the lower tail of its test of
    fitting to the noise, :meth:`Noise.goodness_of_fit`, ``translations`` its, under
    ``1 - GOF_LEVEL``: an over-fit). ``rss``, ``p``, ``translations`` and ``n`` (default
    every component of ``measured``) are the test's (:func:`kept_terms`).
    """
    if not folds:
        return "one configuration with one load: no row to hold out"
    per_row = measured.shape[1]
    train = measured.size - per_row * max(len(f) for f in folds)
    if train <= p:
        return (f"{p} parameters, and the rows without one load leave {train} residual "
                f"components to fit them")
    n = measured.size if n is None else n
    gof = None if noise is None else noise.goodness_of_fit(rss, n, p, translations)
    if noise is None or gof is None:
        return None
    low = 1.0 - gof
    if low < 1.0 - GOF_LEVEL:
        return (f"fits below the noise (RMS {math.sqrt(rss / n) / noise.sigma:.2g}x the noise, "
                f"{noise.test} lower tail p = {low:.2g} < {1 - GOF_LEVEL:.2g}): an over-fit")
    return None


#: Family-wise level of the extra-sum-of-squares F test a candidate of a campaign of one
#: configuration passes to be named when its noise is not known (:func:`extra_fit`).
SELECTION_LEVEL = 0.05


def extra_fit(current: tuple[float, int], extension: tuple[float, int], n: int, tried: int
              ) -> str | None:
    """Why the rows do not show an extension of the current model, one of ``tried`` fitted in
    a step, to be real without a known noise, or ``None`` when they do; models are given as
    ``(RSS m^2, parameters)`` over ``n`` residual components.

    The extra-sum-of-squares F test of nested models: ``F = ((RSS0 - RSS1) / dp) /
    (RSS1 / (n - p1))`` against F(``dp``, ``n - p1``) (``dp = p1 - p0``, at least 1), whose
    null distribution needs no noise std (exact for linear models). The step names the best
    of its ``tried`` candidates, so each must pass at :data:`SELECTION_LEVEL` / ``tried``
    (Bonferroni): the step names a false effect at most at that level, whichever is best.
    """
    (rss0, p0), (rss1, p1) = current, extension
    dp, dof = max(p1 - p0, 1), n - p1
    if dof <= 0:
        return f"{p1} parameters on {n} residual components: no degree of freedom left"
    f = (rss0 - rss1) / dp / max(rss1 / dof, 1e-300)
    p = float(fdtrc(dp, dof, max(f, 0.0)))
    if p < SELECTION_LEVEL / max(tried, 1):
        return None
    return (f"the noise not known, the rows do not show it (extra-sum-of-squares F = {f:.3g} "
            f"on ({dp}, {dof}) degrees of freedom, p = {p:.2g}, not below "
            f"{SELECTION_LEVEL:g}/{max(tried, 1)}: the best of {max(tried, 1)} candidates)")


def cross_validate(fits: list[Fit], measured: np.ndarray, folds: list[np.ndarray],
                   workers: int | None = None) -> list[float]:
    """Cross-validated RMS residual (m) of each fit: each fold refitted without its rows, from
    the fit's ``x`` (every refit of every fit one job of
    :func:`stiffness.calibration.fitting.fit_models` on ``workers``)."""
    if not folds:
        return [math.nan] * len(fits)
    m = measured.shape[0]
    trains = [np.setdiff1d(np.arange(m), test) for test in folds]
    subs = fitting.fit_models([fit_job(f.model.replaced(rows=f.model.rows.subset(train)),
                                       measured[train], f.scale, f.x, loss=f.loss,
                                       f_scale=f.f_scale)
                               for f in fits for train in trains], workers)
    out = []
    for i, fit in enumerate(fits):
        total = 0.0
        for test, sub in zip(folds, subs[i * len(folds): (i + 1) * len(folds)], strict=True):
            try:
                with np.errstate(all="ignore"):
                    pred = fit.model.replaced(rows=fit.model.rows.subset(test)).predict(sub.x)
            except np.linalg.LinAlgError:
                total = math.inf
                break
            if not np.all(np.isfinite(pred)):
                total = math.inf
                break
            total += float(np.sum((pred - measured[test]) ** 2))
        out.append(math.sqrt(total / measured.size))
    return out


def held_ends(pull: list[float] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which parameters at their bound hold each end of another parameter's 95 % interval:
    ``(low, high)`` masks over them, true where moving the parameter that way (down, up)
    would take that one past its bound. ``pull``: the parameter's covariance with each of
    them (none held) times that one's inward direction (+1 at a lower bound, -1 at an upper
    one; NaN: none)."""
    values = np.nan_to_num(np.asarray(pull, dtype=float), nan=0.0)
    return values > 0, values < 0


#: How much freeing one bound parameter must widen an end of another's interval (a share of
#: that end's half-width) for that end to be said conditional on it (:func:`material_holders`):
#: 5 %, a correlation of 0.305 where one bound parameter holds the end.
MATERIAL_WIDENING = 0.05


def material_holders(covariance: np.ndarray, index: int, at_bound: list[int] | np.ndarray,
                     inward: list[float] | np.ndarray) -> np.ndarray:
    """Mask over ``at_bound`` (positions, ``inward`` as :func:`end_covariances`): the bound
    parameters that hold an end of parameter ``index``'s interval (:func:`held_ends`) and
    move it materially: freed alone, the others that end holds kept held, that end's
    standard deviation would grow by more than :data:`MATERIAL_WIDENING` (with one holder,
    a correlation beyond 0.305 with it in ``covariance``, none held)."""
    cov = np.asarray(covariance, dtype=float)
    bound = np.asarray(at_bound, dtype=int)
    out = np.zeros(bound.size, dtype=bool)
    if bound.size == 0 or not np.isfinite(cov[index, index]):
        return out
    pull = np.where(np.isfinite(np.diag(cov)[bound]), cov[index, bound], np.nan)
    for end in held_ends(pull * np.asarray(inward, dtype=float)):
        held = np.flatnonzero(end)
        var = holding(cov, bound[held])[index, index]
        for h in held:
            freed = holding(cov, bound[held[held != h]])[index, index]
            out[h] |= freed > (1.0 + MATERIAL_WIDENING) ** 2 * max(var, 0.0)
    return out


def holding(covariance: np.ndarray, held: np.ndarray | list[int]) -> np.ndarray:
    """``covariance`` (p, p) conditional on the parameters ``held`` (positions) held where
    they are: the Schur complement, the covariance of a linearised fit with them held; the
    rows of parameters along an undetermined direction (an infinite variance) are left as
    they are, and such a parameter holds nothing."""
    out = np.array(covariance, dtype=float)
    finite = np.flatnonzero(np.isfinite(np.diag(out)))
    held = np.intersect1d(np.asarray(held, dtype=int), finite)
    if held.size:
        block = out[np.ix_(finite, held)]
        out[np.ix_(finite, finite)] -= block @ np.linalg.lstsq(
            out[np.ix_(held, held)], block.T, rcond=None)[0]
    return out


def end_covariances(covariance: np.ndarray, index: int, at_bound: list[int],
                    inward: list[float] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The covariances the (low, high) ends of parameter ``index``'s 95 % interval are
    read from, the one rule of both campaign kinds at a bound: ``covariance`` (none held)
    :func:`holding` only the parameters at their bound (positions ``at_bound``, ``inward``
    +1 at a lower bound, -1 at an upper one) that moving the parameter that way would take
    past theirs (:func:`held_ends`). Holding every bound parameter on both ends (the
    covariance of a fit with them held) covered the other stiffnesses 117 times in 134 where
    a rigid neighbour's compliance, one standard error above 0, sat at its bound; holding on
    a pushed end every bound parameter, not only the pushed ones, 888 in 1000 on a bounded
    linear fit with a near alias (docs/diagnose.md, "Physical bounds"). Only these ends
    hold: the standard error printed beside the interval is ``covariance``'s own, none held,
    for both kinds (the interval lies within ``x -+ quantile se``, an end pulled in where a
    bound excludes it); the held one's was 3 times too small in spread where the truth sat
    above the bound (docs/diagnose.md, "Physical bounds")."""
    cov = np.asarray(covariance, dtype=float)
    bound = np.asarray(at_bound, dtype=int)
    if bound.size == 0 or not np.isfinite(cov[index, index]):
        return cov, cov
    pull = np.where(np.isfinite(np.diag(cov)[bound]), cov[index, bound], np.nan)
    low, high = held_ends(pull * np.asarray(inward, dtype=float))
    return (holding(cov, bound[low]) if low.any() else cov,
            holding(cov, bound[high]) if high.any() else cov)


def bounded_intervals(x: np.ndarray, lower: np.ndarray, covariance: np.ndarray,
                      at_bound: list[int], quantile: float, one_sided: float
                      ) -> tuple[np.ndarray, np.ndarray]:
    """95 % intervals ``(low, high)`` of parameters ``x`` (lower bounds ``lower``,
    ``covariance`` with none held), some (positions ``at_bound``) at their lower bound: those
    from the bound to ``x + one_sided se``; each end of the others' ``x -+ quantile se``
    with ``se`` from that end's :func:`end_covariances`, so that a parameter that took the
    share of a near alias sitting at its bound reaches back to sharing it; none below a
    bound."""
    se = np.sqrt(np.diag(covariance))
    low, high = x - quantile * se, x + quantile * se
    bound = np.asarray(at_bound, dtype=int)
    for c in range(x.size):
        if c in at_bound:
            continue
        ends = end_covariances(covariance, c, at_bound, np.ones(bound.size))
        low[c] = x[c] - quantile * np.sqrt(max(ends[0][c, c], 0.0))
        high[c] = x[c] + quantile * np.sqrt(max(ends[1][c, c], 0.0))
    low = np.maximum(low, lower)
    low[bound], high[bound] = x[bound], x[bound] + one_sided * se[bound]
    return low, high


#: Chi-square lower-tail probability below which residuals are too small for the declared
#: noise (:func:`noise_overstated`): a std under about half the noise over tens of components.
OVERSTATED_P = 1e-3


def noise_overstated(gof: float | None) -> bool:
    """Whether residuals are too small for the declared noise: the chi-square lower tail
    ``1 - gof`` (``gof`` from :meth:`Noise.goodness_of_fit`) below :data:`OVERSTATED_P`. The noise
    is then overstated (or the rows averaged): the intervals are too wide, and an effect
    smaller than the noise goes unseen."""
    return gof is not None and 1.0 - gof < OVERSTATED_P


def above_noise(gof: float) -> bool:
    """Whether the fit-to-noise test (:meth:`Noise.goodness_of_fit`, p-value ``gof``)
    rejects the model at :data:`GOF_LEVEL`: its residual is above the noise (``gof <= 1 -
    GOF_LEVEL``). The stop rule, both kinds' unexplained verdicts, identify's notes and
    validate's verdict."""
    return gof <= 1.0 - GOF_LEVEL


def fits_to_noise(rss: float, n: int, p: int, noise: Noise | None,
                  translations: tuple[float, int, float] | None = None, excluded: int = 0
                  ) -> str | None:
    """The stop rule of both campaign kinds' searches: why a search stops because its current
    model explains the data to the ``noise`` (:meth:`Noise.goodness_of_fit` not
    :func:`above_noise`, ``translations`` its; known noise only, ``None``: not known), or
    ``None`` when it goes on. ``rss``, ``n``, ``p`` and ``translations`` are the test's
    (:class:`NoiseTerms`, :func:`kept_terms`), which left ``excluded`` rows flagged as
    outliers out."""
    if noise is None:
        return None
    gof = noise.goodness_of_fit(rss, n, p, translations)
    if gof is None or above_noise(gof):
        return None
    return (f"the model explains the data to noise ({noise.test} p = {gof:.3g} > "
            f"{1 - GOF_LEVEL:.2g}{excluded_note(excluded)})")


def excluded_note(excluded: int) -> str:
    """The words of a fit-to-noise verdict on the rows :func:`kept_terms` left out: ``""``
    when none."""
    return (f"; {excluded} row(s) flagged as outliers left out of the test" if excluded
            else "")


@dataclass(frozen=True)
class NoiseTerms:
    """What the fit-to-noise test (:meth:`Noise.goodness_of_fit`) of a fit of either campaign
    kind reads, over the rows it keeps (:func:`kept_terms`).

    Attributes
    ----------
    rss
        Sum of squares of the kept rows' residual components (m^2; rotations weighted into
        translation-noise units as fitted).
    n
        Their count.
    p
        The fit's parameter count (:meth:`search.Fitted.terms`).
    translations
        The translations' part of the three where rotations are fitted beside them (their
        sum of squares, count and share of ``p``), read when the rotation noise is the
        residuals' (:attr:`Noise.residual_rotations`); ``None`` without rotations.
    excluded
        Rows flagged as outliers left out (a robust loss's; 0 under least squares).
    """

    rss: float
    n: int
    p: int
    translations: tuple[float, int, float] | None = None
    excluded: int = 0

    def p_value(self, noise: Noise | None) -> float | None:
        """:meth:`Noise.goodness_of_fit` of these terms, ``None`` when the noise is not known
        (``None``) or no test is available."""
        return None if noise is None else noise.goodness_of_fit(self.rss, self.n, self.p,
                                                                self.translations)

    def verdict(self, noise: Noise | None) -> str | None:
        """:func:`fits_to_noise` of these terms (the stop rule's words, ``None``: go on)."""
        return fits_to_noise(self.rss, self.n, self.p, noise, self.translations,
                             self.excluded)


def kept_terms(residual: np.ndarray, p: int, loss: str,
               flagged: Callable[[], Iterable[int]], jacobian: np.ndarray | None = None
               ) -> NoiseTerms:
    """The terms of the fit-to-noise test (:class:`NoiseTerms`) of a fit of either campaign
    kind, over the rows it keeps: the one place every test of fitting to the noise takes
    them from (both kinds' stop rule and verdict, ``identify``'s notes, whatever form the
    noise takes).

    Least squares keeps every row. A robust loss weighs gross rows down, and the test must not
    judge the fit by them: the rows ``flagged`` as outliers
    (:func:`~stiffness.calibration.outliers.flag_residuals`, standardised by the noise std
    the loss is scaled by; called only under a robust loss) are left out, and the test takes
    the plain sum of squares of the other rows' components over their count (chi-square with
    ``n - k - p`` degrees of freedom for ``k`` components left out), the translations' part
    too. Only stray rows are left out: when more than
    :data:`~stiffness.calibration.outliers.STRAY_SHARE` of the rows are flagged, they are a
    pattern the model misses (a model without a sizeable effect flags most rows), and every
    row stays in the test.

    Parameters
    ----------
    residual
        (m, k) residual components of each row (a deflection campaign's row: its load, ``dx``
        ... ``rz``; a pose campaign's: its pose, every marker's), predicted minus measured (m;
        rotations weighted into translation-noise units as fitted), NaN where not observed.
    p
        The fit's parameter count (:meth:`search.Fitted.terms`).
    loss
        The fit's loss (:data:`~stiffness.calibration.solver.LOSSES`).
    flagged
        The rows flagged as outliers (0-based), asked only under a robust loss.
    jacobian
        (m k, q) derivative of the residual components (row-major) with respect to the
        fitted parameters, given when the first three of a row's ``k = 6`` components are
        translations and the others rotations fitted beside them: the translations' share of
        ``p`` is ``p`` times the trace of the kept rows' hat matrix ``J (J^T J)^+ J^T`` over
        their translation components over its whole trace (for a linear model their residual
        sum of squares has mean ``(count - share) sigma^2``; :meth:`Noise.goodness_of_fit`).
    """
    rows = np.asarray(residual, dtype=float)
    keep = np.ones(rows.shape[0], dtype=bool)
    if loss != "linear":
        out = list(flagged())
        keep[out if len(out) <= STRAY_SHARE * rows.shape[0] else []] = False
    kept = rows[keep]
    values = kept[np.isfinite(kept)]
    translations = None
    if jacobian is not None:
        jac = jacobian.reshape(*rows.shape, -1)[keep].reshape(kept.size, -1)
        hat = np.einsum("ij,ij->i", jac, np.linalg.pinv(jac).T).reshape(kept.shape)
        total = float(hat.sum())
        share = p * float(hat[:, :3].sum()) / total if total > 0 else 0.0
        moved = kept[:, :3].reshape(-1)
        translations = (float(moved @ moved), moved.size, share)
    return NoiseTerms(float(values @ values), int(values.size), p, translations,
                      int(np.count_nonzero(~keep)))


def noise_terms(fit: Fit, measured: np.ndarray) -> NoiseTerms:
    """:func:`kept_terms` of a deflection ``fit`` to ``measured`` (m): its rows' residual
    components, the rows :func:`~stiffness.calibration.outliers.flag_fit` flags standardised
    by the noise std its loss is scaled by (``f_scale * scale``: the declared one, else the
    robust estimate), and with rotations its Jacobian over the fitted parameters."""
    def flagged() -> list[int]:
        found, _ = flag_fit(fit, measured, fit.f_scale * fit.scale, fit.penalty_params,
                            ("",) * measured.shape[0], None)
        return [o.row - 1 for o in found]

    jacobian = fit.jacobian[:, fit.kept] if measured.shape[1] == 6 else None
    return kept_terms(fit.predicted - measured, fit.penalty_params, fit.loss, flagged,
                      jacobian)


@dataclass(frozen=True)
class Noise:
    """A noise std, how it is known, and the quantiles of the 95 % intervals computed with it:
    the one rule of every reported interval of both campaign kinds (identify and diagnose,
    deflections and poses).

    A declared noise std is known: an interval's standardised error is normal, and the
    standard normal's quantiles apply. A noise estimated from the data with ``dof`` degrees of
    freedom (a fit's residuals, replicate rows) makes it Student's t with ``dof``. A robust
    fit's covariance (Huber's sandwich, :func:`~stiffness.calibration.solver.sandwich_matrix`)
    takes its spread from the fit's residuals whatever noise std scales its loss, declared or
    not: its intervals are those of a noise estimated over the fit's ``n - p`` degrees of
    freedom (:meth:`of_fit`).

    Attributes
    ----------
    sigma
        The noise std (m; a pose fit's position-noise units).
    dof
        ``None`` for a declared noise std; else the degrees of freedom it was estimated with.
    rotation_dof
        Degrees of freedom of the replicates' rotations among the fitted residuals, weighted
        by the ratio of the two kinds' replicate stds (their pure error is then ``sigma^2``
        per degree of freedom): pooled with :attr:`dof` by the lack-of-fit test only
        (:meth:`goodness_of_fit`), not by the intervals' quantile. With a declared
        :attr:`sigma` (:attr:`dof` ``None``), the rotations weighted by ``sigma / s_r``.
    rotations
        The rotations' share of the residual components (1/2 for a deflection campaign that
        measures them beside the translations, 0 without; :func:`pooled_replicates`): read
        by :meth:`goodness_of_fit` when one kind's noise is declared and the other's is its
        replicates'.
    residual_rotations
        Whether the rotations are weighted by a noise std estimated from the residuals
        (:func:`~stiffness.calibration.fitting.kind_noise`; neither declared nor the
        replicates'): their share of the residual is then fitted to the noise, and
        :meth:`goodness_of_fit` tests the translations alone.
    """

    sigma: float
    dof: int | None = None
    rotation_dof: int = 0
    rotations: float = 0.0
    residual_rotations: bool = False

    @classmethod
    def estimated(cls, sigma: float, n: int, p: int) -> Noise:
        """A noise std estimated from ``n`` residuals of a fit of ``p`` parameters: ``n - p``
        degrees of freedom (at least 1)."""
        return cls(sigma, max(n - p, 1))

    @property
    def declared(self) -> bool:
        """Whether the noise std is declared (known), not estimated from the data."""
        return self.dof is None

    def of_fit(self, loss: str, n: int, covariance: Covariance) -> Noise:
        """The noise of the intervals of a fit to ``n`` residuals under ``loss``
        (:data:`~stiffness.calibration.solver.LOSSES`) scaled by this one, whose reported
        ``covariance`` is given: this one for least squares; for a robust loss the
        sandwich's, estimated over ``n - p`` degrees of freedom (the std scaling the loss kept
        as :attr:`sigma`), ``p`` the directions that covariance spreads over
        (:attr:`~stiffness.calibration.solver.Covariance.rank`; the sandwich's own ``N - p``,
        :func:`~stiffness.calibration.solver.sandwich_matrix`): the one count of both
        campaign kinds, every fitted parameter the data see, those at their bound too (a
        pose fit's :attr:`~stiffness.calibration.pose_fit.PoseFit.covariance`, a deflection
        fit's in compliance units, :func:`~stiffness.calibration.fitting.compliance_spread`);
        not a parameter held as not identifiable, nor a parameterless switch
        (``complementary_stiffness``)."""
        return self if loss == "linear" else Noise.estimated(self.sigma, n, covariance.rank)

    def goodness_of_fit(self, rss: float, n: int, p: float,
                        translations: tuple[float, int, float] | None = None) -> float | None:
        """The p-value of a fit of ``p`` parameters (a kind's share of them: fractional)
        leaving residual sum of squares ``rss`` (m^2) over ``n`` components explaining them to
        this noise, or ``None`` when no test is available. ``translations``: the translations'
        part of the three when rotations are fitted beside them
        (:attr:`NoiseTerms.translations`: their ``rss``, component count and share of
        ``p``), read with :attr:`residual_rotations` only. Every caller takes the four from
        :func:`kept_terms` (:meth:`NoiseTerms.p_value`), over the rows a robust loss keeps.

        A declared noise: ``rss / sigma^2`` is chi-square with ``n - p`` degrees of freedom.
        A noise estimated with :attr:`dof` degrees of freedom is the pure error of replicate
        rows among the ``n`` fitted (``dof sigma^2`` of the residual is theirs): the
        lack-of-fit F test, ``((rss - dof sigma^2) / (n - p - dof)) / sigma^2`` against
        F(``n - p - dof``, ``dof``), exact for a linear model. Treating the estimate as known
        (chi-square) rejects a correct model too often: 8.3 % at the 5 % level on a linear
        model of 12 groups measured twice (72 components, 36 replicate degrees of freedom,
        20 000 draws; the F test 5.1 %). A noise estimated from the residuals themselves
        (:meth:`estimated`, ``dof = n - p``) leaves no lack-of-fit degree of freedom: ``None``.

        Replicates' rotations (:attr:`rotation_dof`, weighted by the ratio of the two kinds'
        replicate stds) hold ``rotation_dof sigma^2`` of the residual too: the pure error is
        both kinds', over ``dof + rotation_dof`` degrees of freedom. Each kind's lack of fit is
        divided by its own std estimate, so the statistic's mean is about ``nu / (nu - 2)`` of
        each kind's ``nu``, not the pooled one's: it is divided by their ratio (an
        approximation: the weight is itself estimated). Measured on linear models of 12 groups
        measured twice, 3 translation and 3 rotation components each (36 + 36 replicate
        degrees of freedom), the test rejects a correct model 5.4 % and 6.2 % of the time at
        the 5 % level on two random designs (20 000 and 4000 draws; 6.1 % with 4 groups,
        12 + 12); without the rotations' degrees of freedom 0.5 % and 0.6 % (it hardly ever
        rejects), with them but not the ratio 6.9 %.

        One kind's noise declared, the other's its replicates' (:attr:`rotation_dof` with a
        declared :attr:`sigma`, or :attr:`dof` with declared rotations, :attr:`rotations`
        their share): chi-square for the declared kind plus the other's lack-of-fit F
        (:meth:`_one_kind_replicated`). On the 12-group design above (4000 draws) it rejects
        a correct model 5.7 % (declared translations) and 5.4 % (declared rotations) of the
        time at the 5 % level; chi-square for all, the rule until 5 December 2026 for the
        first, 7.7 %, the F test for all (the second's) 0.30 %.

        The rotations' noise estimated from the residuals (:attr:`residual_rotations`): the
        weight ``sigma / s_r`` makes their residual ``(n_r - p_r) sigma^2`` by construction,
        so only the translations can tell a lack of fit: the test above of their part alone,
        ``translations`` (``None`` without it), their share of ``p`` the hat matrix's trace
        over them (exact in the mean for a linear model). With a declared translation noise,
        on linear draws of 12 rows (3 + 3 components, rotation std 7, 4 parameters, 4000
        draws, seeds 3-5) it rejects a correct model 5.05 %, 5.0 % and 5.1 % of the time at
        the 5 % level; the translations' alone with half of ``p`` (as ``kind_noise`` splits
        it) 3.2 %, 3.1 % and 3.0 % (the translations hold 3.9 of the 4 parameters' leverage);
        chi-square on ``rss`` with ``n - p`` degrees of freedom, the rule until 5 December
        2026, 1.0 %, 0.83 % and 0.90 % (the rotations' part, about fixed, counted as
        chi-square).
        """
        if self.residual_rotations:
            return None if translations is None else replace(
                self, residual_rotations=False).goodness_of_fit(*translations)
        if n <= p:
            return None
        if self.dof is None and not self.rotation_dof:
            return float(chdtrc(n - p, rss / self.sigma ** 2))
        if self.dof is None or (self.rotations and not self.rotation_dof):
            return self._one_kind_replicated(rss, n, p)
        pure = self.dof + self.rotation_dof
        lack = n - p - pure
        if lack <= 0:
            return None
        statistic = max(rss / self.sigma ** 2 - pure, 0.0) / lack
        if self.rotation_dof:
            statistic /= _inverse_chi2_mean(self.dof, self.rotation_dof) / _inverse_chi2_mean(pure)
        return float(fdtrc(lack, pure, statistic))

    def _one_kind_replicated(self, rss: float, n: int, p: float) -> float | None:
        """:meth:`goodness_of_fit` when one kind's noise is declared and the other's is its
        replicates' scatter over ``nu`` degrees of freedom (:attr:`dof` for the translations,
        :attr:`rotation_dof` for the rotations; the rotations weighted by the ratio of the
        two stds, :attr:`rotations` their share of the ``n`` components).

        Each kind takes its share of the ``p`` parameters (as
        :func:`~stiffness.calibration.fitting.kind_noise`): the declared kind's residual,
        divided by its std, is chi-square with ``a = (n - p) (1 - share)`` degrees of freedom;
        the replicated kind's (share ``share``) holds its pure error, exactly ``nu`` once
        divided by its own estimate, and its lack of fit over ``l = (n - p) share - nu``
        degrees of freedom divided by that estimate, ``l F(l, nu)``. So ``rss / sigma^2 - nu``
        is ``chi2(a) + l F(l, nu)``, the two independent (:func:`_chi2_plus_f_sf`): an
        approximation even for a linear model, in the split of ``p`` and in that the fit's
        projection moves with the estimated weight.
        """
        estimated_share, nu = ((self.rotations, self.rotation_dof) if self.dof is None
                               else (1.0 - self.rotations, self.dof))
        lack = (n - p) * estimated_share - nu
        known = (n - p) * (1.0 - estimated_share)
        statistic = rss / self.sigma ** 2 - nu
        if lack <= 0:
            return None if known <= 0 else float(chdtrc(known, max(statistic, 0.0)))
        return _chi2_plus_f_sf(statistic, known, lack, nu)

    @property
    def test(self) -> str:
        """The name of :meth:`goodness_of_fit`'s test: ``chi-square`` for a declared noise,
        ``lack-of-fit F`` for one estimated from replicates, ``chi-square + lack-of-fit F``
        when one kind's noise is declared and the other's is its replicates', each followed by
        `` of the translations`` when the rotations' noise is the residuals'."""
        if self.residual_rotations:
            return f"{replace(self, residual_rotations=False).test} of the translations"
        if self.declared:
            return "chi-square + lack-of-fit F" if self.rotation_dof else "chi-square"
        return "chi-square + lack-of-fit F" if self.rotations and not self.rotation_dof \
            else "lack-of-fit F"

    def quantile(self, level: float) -> float:
        """The ``level`` quantile of an interval's standardised error: the standard normal's
        for a declared noise, Student's t with :attr:`dof` for an estimated one (a deflection
        fit with measured rotations takes each parameter's own,
        :func:`~stiffness.calibration.deflection_noise.interval_quantiles`)."""
        if self.dof is None:
            return float(ndtri(level))
        return float(stdtrit(self.dof, level))

    def two_sided(self) -> float:
        """The quantile of a two-sided 95 % interval (97.5 %)."""
        return self.quantile(0.975)

    def one_sided(self) -> float:
        """The quantile of a one-sided 95 % interval (95 %), a parameter's at its bound."""
        return self.quantile(0.95)


def _chi2_plus_f_sf(x: float, known: float, lack: float, nu: int) -> float:
    """``P(A + lack F > x)`` for independent ``A`` chi-square with ``known`` degrees of
    freedom and ``F`` F(``lack``, ``nu``): ``P(A > x) + integral_0^x f_A(t) P(lack F > x - t)
    dt`` (one quadrature; ``known`` 0 is the F test alone)."""
    if x <= 0.0:
        return 1.0
    if known <= 0:
        return float(fdtrc(lack, nu, x / lack))
    half = 0.5 * known
    log_norm = -half * math.log(2.0) - gammaln(half)

    def density_times_tail(t: float) -> float:
        return math.exp(log_norm + xlogy(half - 1.0, t) - 0.5 * t) * float(
            fdtrc(lack, nu, (x - t) / lack))

    # imported here: scipy.integrate costs every diagnose and identify process ~27 ms of
    # CPU to import, and only this test (declared and replicate noise together) integrates
    from scipy.integrate import quad

    mode = min(max(known - 2.0, 0.0), x)
    inner, _ = quad(density_times_tail, 0.0, x, points=[mode] if 0.0 < mode < x else None,
                    limit=200, epsabs=0.0, epsrel=1e-7)
    return float(min(chdtrc(known, x) + inner, 1.0))


def _inverse_chi2_mean(*dofs: int) -> float:
    """The mean of ``nu / chi2(nu)`` (``nu / (nu - 2)``) averaged over ``dofs``: the mean of
    ``sigma^2 / s^2`` for a std ``s`` estimated over ``nu > 2`` degrees of freedom (replicates
    give at least 9)."""
    return float(np.mean([nu / max(nu - 2, 1) for nu in dofs]))


def _distinct(values: np.ndarray, rows: list[int]) -> list[int]:
    """Of ``rows``, those whose measured ``values`` are not an exact copy of an earlier one's
    (:func:`~stiffness.calibration.measurements.first_copies`)."""
    first = first_copies(values[rows])
    return [r for k, r in enumerate(rows) if first[k] == k]


def pooled_replicates(noise: Noise | None, campaign: Campaign, robust: bool = False
                      ) -> Noise | None:
    """``noise`` (the translations', declared or the replicates') as the fit-to-noise test
    of a campaign that measures rotations takes it, ``identify``'s and ``diagnose``'s: with
    the rotations' share of the residual components (:attr:`Noise.rotations`) when their
    noise is declared or the replicates', and in the latter case the rotation replicates'
    degrees of freedom (:attr:`Noise.rotation_dof`; the rotations then weighted by ``sigma``
    over the replicates' std); marked :attr:`Noise.residual_rotations` when their noise is
    estimated from the residuals (neither declared nor replicated); ``noise`` itself
    without rotations. ``robust`` as :func:`replicate_noise`'s."""
    if noise is None or campaign.rotation is None:
        return noise
    if campaign.rotation_noise_std_rad is not None:
        return replace(noise, rotations=0.5)
    rep = replicate_noise(campaign, "rotation", robust)
    if rep is None:
        return replace(noise, residual_rotations=True)
    return replace(noise, rotation_dof=rep[1], rotations=0.5)


def replicate_noise(campaign: Campaign, kind: str = "translation", robust: bool = False
                    ) -> tuple[float, int] | None:
    """Std (m; rad for ``kind="rotation"``) of replicate rows (same coordinates and force)
    and its degrees of freedom, or ``None`` when the replicates give fewer than 9 degrees of
    freedom (or the campaign measures no rotations). A row whose measured values copy an
    earlier replicate's to the last bit is the same row written twice, not a repeated
    measurement, and does not count (copies would give a noise of zero).

    The pooled scatter, ``sqrt(sum (d - mean)^2 / dof)``; with ``robust`` (for a robust
    loss), :func:`stiffness.calibration.outliers.robust_noise` of the deviations from their
    group's mean, each times ``sqrt(m / (m - 1))`` for its group of ``m`` rows (a deviation's
    std is ``sigma sqrt((m - 1) / m)``), which one gross outlier does not inflate (the pooled
    scatter when more than half the deviations are zero). That factor is the whole
    degrees-of-freedom correction (each scaled deviation is exactly N(0, sigma^2)): no
    parameter is counted for the group means, and no robust fit's shrinkage applies (a mean
    is least squares'); the median's finite-size bias is left (+0.26 % on 144 degrees of
    freedom, docs/outliers.md).
    """
    values = campaign.deflection if kind == "translation" else campaign.rotation
    if values is None:
        return None
    groups: dict[tuple, list[int]] = {}
    for i in range(campaign.n_rows):
        key = tuple(np.round(campaign.q[i], 9)) + tuple(np.round(campaign.wrench[i], 6))
        groups.setdefault(key, []).append(i)
    ss, dof, scaled = 0.0, 0, []
    for group in groups.values():
        idx = _distinct(values, group)
        if len(idx) > 1:
            d = values[idx] - values[idx].mean(axis=0)
            ss += float(np.sum(d ** 2))
            dof += 3 * (len(idx) - 1)
            scaled.append(d.reshape(-1) * math.sqrt(len(idx) / (len(idx) - 1)))
    if dof < _MIN_REPLICATE_DOF:
        return None
    sigma = robust_noise(np.concatenate(scaled), 0) if robust else None
    return (sigma if sigma is not None else math.sqrt(ss / dof)), dof
