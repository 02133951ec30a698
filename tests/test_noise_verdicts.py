"""One rule says a residual is above the noise (:func:`selection.above_noise`, ``p <= 1 -
GOF_LEVEL``): the searches' stop rule, a pose diagnosis's ``unexplained`` and ``validate``'s
verdict read it alike, at every p-value and at the level itself."""

from __future__ import annotations

from types import SimpleNamespace

from hypothesis import given
from hypothesis import strategies as st
from scipy import stats

from stiffness.calibration.pose_diagnosis import PoseDiagnosis
from stiffness.calibration.selection import GOF_LEVEL, Noise, fits_to_noise
from stiffness.calibration.validation import Validation


def validation(rows: int, rms: float, noise_std: float | None) -> Validation:
    """A validation of ``rows`` rows leaving a 3-D error RMS ``rms`` (no model evaluated)."""
    return Validation(model="m", campaign="c", kind="poses", robot={}, noise_std=noise_std,
                      errors={"rms": rms, "rows": rows,
                              "markers": {"tip": {"rms": rms, "rows": rows}}})


def test_two_markers_count_every_seen_position():
    """Two markers on 25 rows, one unseen on 5 of them: the chi-square sums the 45 seen
    3-D errors' squares over 135 components, computed here from the errors themselves (the
    verdict counted 3 per row, 75, and the squares of 25 mean errors: half the test for a
    two-marker campaign, p = 0.096 'consistent' where the 150 components gave about 0.035)."""
    import numpy as np

    from stiffness.calibration.breakdown import error_summary

    rng = np.random.default_rng(3)
    sigma = 2e-5
    err = np.linalg.norm(rng.normal(0.0, 1.2 * sigma, (25, 2, 3)), axis=2)
    err[:5, 1] = np.nan
    errors = {**error_summary(err, 1.0), "rows": 25,
              "markers": {name: error_summary(err[:, k], 1.0)
                          for k, name in enumerate(("tip", "elbow"))}}
    v = Validation(model="m", campaign="c", kind="poses", robot={}, noise_std=sigma,
                   errors=errors)
    assert v.components == 3 * 45
    chi2 = float(np.nansum(err ** 2) / sigma ** 2)
    assert abs(v.chi2 - chi2) <= 1e-9 * chi2
    assert abs(v.gof() - stats.chi2.sf(chi2, 135)) <= 1e-9


@given(rows=st.integers(1, 300), ratio=st.floats(0.0, 3.0), sigma=st.floats(1e-6, 1e-2))
def test_validate_verdict_is_the_chi_square_test_at_the_level(rows, ratio, sigma):
    """``validate``'s verdict is the chi-square test of ``sum r^2 / sigma^2`` over the 3n
    components, computed here from scipy directly: above the noise when p <= 0.05."""
    v = validation(rows, ratio * sigma, sigma)
    p = stats.chi2.sf(rows * ratio ** 2, 3 * rows)
    expected = "above the noise" if p <= 1 - GOF_LEVEL else "consistent with the noise"
    if abs(p - (1 - GOF_LEVEL)) > 1e-9:  # the two p-values agree to round-off only
        assert v.verdict == expected


def test_at_the_level_itself_every_verdict_says_above_the_noise(monkeypatch):
    """At p = 1 - GOF_LEVEL exactly the test rejects: the stop rule goes on, a pose diagnosis
    is unexplained and ``validate`` says above the noise (until 5 December 2026 the last two
    said the opposite, with ``p < 1 - GOF_LEVEL``)."""
    level = 1 - GOF_LEVEL
    monkeypatch.setattr(Noise, "goodness_of_fit", lambda self, rss, n, p, translations=None: level)
    assert fits_to_noise(1.0, 10, 1, Noise(1.0)) is None
    monkeypatch.setattr(Validation, "gof", lambda self: level)
    assert validation(10, 1.0, 1.0).verdict == "above the noise"
    diagnosis = SimpleNamespace(gof=lambda: level)
    assert PoseDiagnosis.unexplained.fget(diagnosis) is True
    diagnosis = SimpleNamespace(gof=lambda: level * (1 + 1e-12))
    assert PoseDiagnosis.unexplained.fget(diagnosis) is False


def test_no_noise_no_verdict():
    """Without a declared noise there is no verdict (``None``), not a guess."""
    assert validation(10, 1.0, None).verdict is None
    assert PoseDiagnosis.unexplained.fget(SimpleNamespace(gof=lambda: None)) is None
