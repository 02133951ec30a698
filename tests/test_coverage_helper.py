"""The two-sided coverage check of tests/stats.py against intervals built here from known
normal errors: right intervals pass, intervals 2x too wide or too narrow fail, on each scale
the reported intervals use (value's own, logarithm, reciprocal)."""

from __future__ import annotations

import numpy as np
import pytest
from stats import Z95, Coverage, standardised_error


def _coverage(factor: float, scale: str, n: int = 300, seed: int = 0) -> Coverage:
    rng = np.random.default_rng(seed)
    truth = rng.uniform(1.0, 3.0, n)
    se = 0.01 * truth
    estimate = truth + rng.normal(0.0, 1.0, n) * se      # on the scale the interval is built
    half = factor * Z95 * se
    cov = Coverage()
    for t, e, h, s in zip(truth, estimate, half, se, strict=True):
        if scale == "linear":
            cov.add(e, (e - h, e + h), t)
        elif scale == "log":            # k exp(+-q s_log), s_log = se / truth
            cov.add(e, (e * np.exp(-h / t), e * np.exp(h / t)), t)
        else:                           # 1 / c with c = 1 / e +- q se / t^2
            c, hc = 1.0 / e, h / t ** 2
            cov.add(e, (1.0 / (c + hc), 1.0 / (c - hc)), t)
        assert s > 0
    return cov


@pytest.mark.parametrize("scale", ["linear", "log", "reciprocal"])
def test_right_intervals_pass_and_wrong_widths_fail(scale):
    _coverage(1.0, scale).check()
    for factor in (2.0, 0.5):
        with pytest.raises(AssertionError):
            _coverage(factor, scale).check()


def test_too_few_intervals_fail_and_one_sided_intervals_are_measured_on_the_truths_side():
    with pytest.raises(AssertionError, match="only 100"):
        _coverage(1.0, "linear", n=100).check()
    # an interval held at a bound (value = low): its upper side sets the scale
    assert standardised_error(0.0, 0.0, Z95, 0.5) == pytest.approx(0.5)
    assert standardised_error(0.0, 0.0, Z95, -0.5) == np.inf
    with pytest.raises(AssertionError, match="not an interval"):
        standardised_error(2.0, 0.0, 1.0, 0.5)


def test_an_interval_pulled_unequally_is_measured_on_the_truths_side():
    """A pose fit's interval whose ends a parameter at its bound pulls unequally (symmetric
    on no scale) about a positive value, its truth at the bound 0: measured on the truth's
    side, z = 2.1 (it was infinite: the truth was taken to the log scale first; UR10 tilt
    campaign, seed 2, of docs/absolute-poses.md)."""
    z = standardised_error(4.221960955552629e-07, 2.854098504723621e-08,
                           8.152619261063945e-07, 0.0)
    assert z == pytest.approx(4.221960955552629e-07 / ((4.221960955552629e-07
                                                       - 2.854098504723621e-08) / Z95))
    assert 2.0 < z < 2.2
    # a stiffness interval (symmetric in its compliance) with its truth at 0 is off its scale
    assert standardised_error(1.0, 1.0 / 1.5, 1.0 / 0.5, 0.0) == np.inf
