"""Two-sided checks of reported 95 % intervals against known truths (issue 40, item 1).

Every coverage test of the suite collects the intervals a user sees (``Parameter.ci95``,
``to_dict()``'s ``ci95``, a pose fit's ``interval_95``) with the truth each should cover, and
calls :meth:`Coverage.check`, which fails when the intervals are too narrow AND when they are
too wide:

* the number covering the truth must be consistent with 95 % (two-sided binomial, ``alpha``);
* the standardised errors ``z = (value - truth) / (half-width / 1.96)`` must have variance
  about 1: ``sum z^2`` within the two-sided ``alpha`` quantiles of chi-square (intervals 2x
  too wide give ``sum z^2 ~ n / 4``, 2x too narrow ``4 n``).

Both count ``n / design_effect`` independent intervals (default 2: the parameters of one
campaign are correlated, see :meth:`Coverage.check`).

A half-width is measured where the interval is symmetric about the reported value: on the
value's own scale, on its logarithm (``k exp(+-q s)``) or on its reciprocal (a stiffness from
its compliance's interval, as ``identify`` and ``diagnose`` report every stiffness); an
interval symmetric on none (one side at a bound; or its ends pulled unequally by parameters at
their bounds) is measured on the truth's side.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

#: The standard normal 97.5 % quantile: a 95 % interval is value +- Z95 standard errors.
Z95 = float(stats.norm.ppf(0.975))
_SCALES = (lambda v: v, np.log, lambda v: 1.0 / v)


def binomial_consistent(hits: int, n: int, level: float = 0.95, alpha: float = 1e-3) -> bool:
    """Whether ``hits`` of ``n`` is consistent with a rate ``level`` at two-sided ``alpha``."""
    return bool(stats.binom.cdf(hits, n, level) > alpha / 2
                and stats.binom.sf(hits - 1, n, level) > alpha / 2)


def binomial_at_least(hits: int, n: int, rate: float, alpha: float = 1e-3) -> bool:
    """Whether ``hits`` of ``n`` is consistent with a rate of at least ``rate`` (one-sided
    ``alpha``: a documented lower bound)."""
    return bool(stats.binom.cdf(hits, n, rate) > alpha)


def standardised_error(value: float, low: float, high: float, truth: float) -> float:
    """``(value - truth)`` over the standard error a 95 % interval ``[low, high]`` about
    ``value`` implies (see the module docstring for the scale it is measured on)."""
    if not low <= value <= high:
        raise AssertionError(f"not an interval about its value: {value} [{low}, {high}]")
    for g in _SCALES if math.isfinite(high - low) else ():
        if low <= 0.0 and g is not _SCALES[0]:
            continue
        gl, gv, gh = (float(g(v)) for v in (low, value, high))
        half = 0.5 * abs(gh - gl)
        if half > 0 and abs(abs(gh - gv) - abs(gv - gl)) <= 1e-6 * half:
            if truth <= 0.0 and g is not _SCALES[0]:
                return math.inf  # a positive quantity's truth at 0 lies off its scale
            return float(abs(gv - g(truth)) / (half / Z95))
    side = (value - low) if truth < value else (high - value)
    if side == 0.0:
        return 0.0 if truth == value else math.inf
    return abs(value - truth) / (side / Z95)


@dataclass
class Coverage:
    """Reported 95 % intervals and the truths they should cover, checked two-sided."""

    z: list[float] = field(default_factory=list)
    covered: list[bool] = field(default_factory=list)

    def add(self, value: float, ci95: Iterable[float], truth: float) -> None:
        """One reported interval ``ci95 = (low, high)`` about ``value`` and its truth."""
        low, high = (float(v) for v in ci95)
        self.z.append(standardised_error(float(value), low, high, float(truth)))
        self.covered.append(low <= truth <= high)

    def add_all(self, values, lows, highs, truths) -> None:
        """Arrays of values, interval bounds and truths (same shapes)."""
        for v, lo, hi, t in zip(np.ravel(values), np.ravel(lows), np.ravel(highs),
                                np.ravel(truths), strict=True):
            self.add(v, (lo, hi), t)

    def extend(self, other: Coverage) -> None:
        """Add the intervals ``other`` collected."""
        self.z += other.z
        self.covered += other.covered

    @property
    def n(self) -> int:
        return len(self.z)

    @property
    def hits(self) -> int:
        return int(sum(self.covered))

    @property
    def chi2(self) -> float:
        """``sum z^2`` of the standardised errors."""
        return float(np.sum(np.square(self.z)))

    def summary(self) -> str:
        return (f"{self.hits}/{self.n} covered, sum z^2 = {self.chi2:.4g} "
                f"(variance {self.chi2 / max(self.n, 1):.3g})")

    def check(self, min_n: int = 150, alpha: float = 1e-3, design_effect: float = 2.0) -> None:
        """Fail unless at least ``min_n`` intervals were added, the coverage is consistent
        with 95 % (two-sided binomial) and ``sum z^2`` lies within chi-square's two-sided
        ``alpha`` quantiles.

        The parameters of one campaign are correlated, which spreads both statistics beyond
        their independent laws: both tests count ``n / design_effect`` independent intervals
        (hits and ``sum z^2`` scaled alike). At the default 2 and n = 150, the variance of the
        standardised errors must lie within about [0.5, 1.6]: intervals 2x too wide (0.25)
        or too narrow (4) fail."""
        assert self.n >= min_n, f"only {self.n} intervals (at least {min_n}): {self.summary()}"
        n_eff = self.n / design_effect
        hits_eff = round(self.hits / design_effect)
        assert binomial_consistent(hits_eff, round(n_eff), alpha=alpha), (
            f"coverage not consistent with 95 %: {self.summary()}")
        low, high = stats.chi2.ppf([alpha / 2, 1 - alpha / 2], n_eff) / n_eff
        variance = self.chi2 / self.n
        assert low < variance < high, (
            f"standardised errors' variance not 1: {self.summary()}, "
            f"bounds [{low:.3g}, {high:.3g}]")
