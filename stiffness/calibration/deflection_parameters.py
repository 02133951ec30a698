"""The parameters a deflection diagnosis reports: the baseline's joint stiffnesses and each
effect's parameters, with their 95 % intervals from the fit's covariance
(:func:`stiffness.calibration.fitting.compliance_covariance`), one-sided at a physical bound,
each end of the others' respecting the bounds by both campaign kinds' rule
(:func:`with_bounds`, :func:`~stiffness.calibration.selection.end_covariances`), and what
takes a held parameter's share (:func:`share`). The pose campaigns' counterpart is
:mod:`stiffness.calibration.pose_parameters`; the naming rules both follow are
:mod:`stiffness.calibration.naming`.

Units: the stiffnesses SI (N.m/rad, N/m), the effects' in the units asked for.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable

import numpy as np

from stiffness.calibration.fitting import Fit
from stiffness.calibration.identifiability import confounded
from stiffness.calibration.naming import one_sided
from stiffness.calibration.selection import end_covariances
from stiffness.elastic.effects.base import Parameter, effect_report, stiffness_report


def stiffness_parameters(fit: Fit, cov: np.ndarray, quantile: float | np.ndarray,
                         edge: float | np.ndarray) -> list[Parameter]:
    """The joint stiffnesses a diagnosis reports: ``k = exp(x)`` with the interval of its
    compliance ``c = 1 / k`` (``c -+ quantile se_c``, ``se_c = c se`` with ``se`` that of
    ``ln k`` from ``cov``; a predicted deflection is linear in the compliances) carried to
    the stiffness, ``[1 / (c + quantile se_c), 1 / (c - quantile se_c)]`` (``quantile`` and
    ``edge`` one for all or one per column of ``fit.x``,
    :func:`~stiffness.calibration.deflection_noise.interval_quantiles`; unbounded above
    when the compliance's interval reaches zero), in N.m/rad or N/m; a joint at its rigid bound
    (:func:`~stiffness.calibration.fitting.fit_model`) one-sided from there, with the one-sided
    quantile ``edge``; each end of the others' bounded as :func:`with_bounds` says. A fitted
    stiffness the data do not bound whose estimate is confounded with an effect's fitted
    parameter (:func:`~stiffness.calibration.identifiability.confounded`: correlation at
    least :data:`~stiffness.calibration.identifiability.ALIAS_CORRELATION` in ``cov``; a link
    bend about an axis nearly parallel to the joint's, which the near-alias merge of
    :mod:`~stiffness.calibration.identifiability` left in) is reported as not told apart from
    it, without an interval (:meth:`~stiffness.elastic.effects.base.Parameter.confounded_as`):
    its linearised interval runs along the alias and is not the joint's."""
    model = fit.model
    refs, top = model.refs, model.bounds()[1]
    quantile, edge = per_column(fit, quantile), per_column(fit, edge)

    def one(i: int, j: str, matrix: np.ndarray, q: float) -> Parameter:
        k = math.exp(fit.x[i])
        prismatic = bool(model.geometry.prismatic[model.geometry.joints.index(j)])
        u = refs.k_ref / k  # the compliance in its typical size, 1 / k_ref
        p = stiffness_report(j, u, float(matrix[i, i]) * u ** 2, 1.0 / refs.k_ref,
                             "N/m" if prismatic else "N.m/rad", q)
        rigid = i in fit.at_bound and fit.x[i] >= top[i]  # no standard error (2.7e26 N.m/rad)
        # judged as stiffness_report judged it (resolved against the physical scale, its note)
        return dataclasses.replace(p, value=k, standard_error=math.inf if rigid
                                   else p.standard_error, at_bound=rigid)

    effects = [c for c in fit.kept if c >= len(model.compliant)]
    out = [with_bounds(fit, i, one(i, j, cov, quantile[i]), cov,
                       functools.partial(one, i, j, q=quantile[i]),
                       edge=one(i, j, cov, edge[i]) if i in fit.at_bound else None)
           for i, j in enumerate(model.compliant)]
    return [p if p.held or p.determined else p.confounded_as(share(fit, i, cov, effects))
            for i, p in enumerate(out)]


def with_bounds(fit: Fit, index: int, parameter: Parameter, cov: np.ndarray,
                report: Callable[[np.ndarray], Parameter], reciprocal: bool = False,
                edge: Parameter | None = None) -> Parameter:
    """``parameter`` (column ``index`` of ``fit.x``, its interval from the covariance ``cov``)
    as held, with why, when the fit did not identify it (:attr:`Fit.identifiability`); at its
    physical bound (:attr:`Fit.at_bound`) with a one-sided 95 % interval from the bound
    (``edge``'s other end: the parameter reported with the one-sided quantile, as a pose fit
    reports it, :func:`~stiffness.calibration.selection.bounded_intervals`); else each end of
    its interval that of the parameter reported (``report`` of a covariance) from that end's
    covariance (:func:`~stiffness.calibration.selection.end_covariances`, the rule of both
    campaign kinds: the parameters at their bound that moving it that way would take past
    theirs held there): an interval that respects the bounds. Its standard error stays
    ``parameter``'s, from ``cov`` none held (both kinds' rule: a pose fit's ``std`` is its
    covariance's alike). ``reciprocal``: the parameter falls as its variable rises (a
    stiffness reported from a compliance variable), so the variable's low end is the
    parameter's high end."""
    dropped = None if fit.identifiability is None else fit.identifiability.dropped_at(index)
    if dropped is not None:
        return parameter.held_as(dropped.describe(fit.labels()))
    lo, hi = fit.model.bounds()
    inward = {b: 1.0 if abs(fit.x[b] - lo[b]) <= abs(fit.x[b] - hi[b]) else -1.0
              for b in fit.at_bound}
    if index in fit.at_bound:  # one reported from a compliance at zero is one-sided already
        side = parameter if edge is None else edge
        return side if side.at_bound else one_sided(side, inward[index] > 0)
    if not fit.at_bound:
        return parameter
    ends = end_covariances(cov, index, fit.at_bound, [inward[b] for b in fit.at_bound])
    if reciprocal:
        ends = ends[::-1]
    low = parameter.ci95[0] if ends[0] is cov else report(ends[0]).ci95[0]
    high = parameter.ci95[1] if ends[1] is cov else report(ends[1]).ci95[1]
    return dataclasses.replace(parameter, ci95=(low, high))


def effect_parameters(fit: Fit, cov: np.ndarray, quantile: float | np.ndarray,
                      edge: float | np.ndarray, units) -> dict[str, list[Parameter]]:
    """Each effect's parameters in ``fit`` with their intervals (from ``cov`` with the
    two-sided ``quantile``, or one-sided from a bound with the one-sided ``edge``, each one for
    all or one per column of ``fit.x``,
    :func:`~stiffness.calibration.deflection_noise.interval_quantiles`;
    each end bounded as :func:`with_bounds` says). A reported quantity beyond the
    effect's variables (``nonlinear_joint_stiffness``'s relative change, from its ``beta``)
    is held, at its bound or bounded as its last variable is, with its quantile."""
    model = fit.model
    quantile, edge = per_column(fit, quantile), per_column(fit, edge)
    out = {}
    for i, e in enumerate(model.effects):
        a, b = model.offsets[i + 1], model.offsets[i + 2]

        def reports(matrix: np.ndarray, q: np.ndarray, x: np.ndarray | None = None, e=e, a=a,
                    b=b) -> list[Parameter]:  # at fit.x, or at x
            u = fit.x[a:b] if x is None else x
            return _each_quantile(lambda v: effect_report(e, u, matrix[a:b, a:b], model.refs,
                                                          units, v), q[a:b])

        free = reports(cov, quantile)

        def report(matrix: np.ndarray, k: int, reports=reports) -> Parameter:
            return reports(matrix, quantile)[k]

        sided = reports(cov, edge) if any(a <= c < b for c in fit.at_bound) else free
        floor = [-math.inf] * len(free) if e.compliance_variables else [  # a stiffness's is 0
            p.value for p in reports(np.zeros_like(cov), quantile, e.bounds()[0])]
        out[e.label] = [_above(with_bounds(fit, a + min(k, b - a - 1), p, cov,
                                           functools.partial(report, k=k),
                                           e.compliance_variables and k < b - a, one), low)
                        for k, (p, one, low) in enumerate(zip(free, sided, floor,
                                                              strict=True))]
    return out


def per_column(fit: Fit, quantile: float | np.ndarray) -> np.ndarray:
    """``quantile`` for each column of ``fit.x``: one for all, or already one per column."""
    return np.broadcast_to(np.asarray(quantile, dtype=float), fit.x.shape)


def _each_quantile(report: Callable[[float], list[Parameter]], quantile: np.ndarray
                   ) -> list[Parameter]:
    """An effect's reported quantities (``report`` with a quantile), each with its variable's
    ``quantile`` (one per variable; a relative change beyond them, from the first variable,
    :func:`~stiffness.elastic.effects.base.effect_report`, the first's); none without
    variables."""
    reports = {float(q): report(float(q)) for q in np.unique(quantile)}
    size = len(reports[float(quantile[0])]) if quantile.size else 0
    return [reports[float(quantile[k if k < quantile.size else 0])][k] for k in range(size)]


def _above(parameter: Parameter, floor: float) -> Parameter:
    """``parameter`` with its interval's low end at ``floor`` (its physical lower bound in
    its unit: a mass, backlash or compensator stiffness is never negative) or above."""
    low, high = parameter.ci95
    return parameter if not low < floor else dataclasses.replace(parameter, ci95=(floor, high))


def share(fit: Fit, column: int, cov: np.ndarray, among: list[int] | None = None
          ) -> tuple[tuple[str, float], ...]:
    """What takes the share of parameter ``column`` of ``fit`` once it is held: the fitted
    parameters (of ``among``; every kept one by default) its estimate is correlated with
    (:func:`~stiffness.calibration.identifiability.confounded`, ``cov`` the fit's
    covariance), as (label, correlation) pairs
    (:attr:`~stiffness.elastic.effects.base.Held.confounded_with`; none for none)."""
    return confounded(cov, column, fit.kept if among is None else among, fit.labels())
