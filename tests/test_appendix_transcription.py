"""Tests of the verbatim transcription of Alici & Shirinzadeh (2005), Appendix I."""

from __future__ import annotations

import numpy as np
import pytest

from stiffness.papers.appendix import (
    APPENDIX_TERMS,
    Term,
    appendix_element,
    appendix_jacobian,
    appendix_kc,
)

# Number of printed terms per element, counted by hand in the printed Appendix I, eq. (17)
# (IEEE T-RO 21(4), 2005). J31 is printed as 0. Total: 78 terms.
PRINTED_TERM_COUNTS = {
    "J11": 21,
    "J12": 1,
    "J13": 11,
    "J21": 21,
    "J22": 1,
    "J23": 11,
    "J31": 0,
    "J32": 1,
    "J33": 11,
}

SYMBOLS = [f"L{i}" for i in range(1, 7)] + [f"D{i}" for i in range(1, 7)]


def _random_case(seed: int) -> tuple[np.ndarray, dict[str, float]]:
    rng = np.random.default_rng(seed)
    theta = rng.uniform(-np.pi, np.pi, 6)
    values = rng.uniform(-500.0, 500.0, len(SYMBOLS))
    lengths = {s: float(v) for s, v in zip(SYMBOLS, values, strict=True)}
    return theta, lengths


def test_term_counts() -> None:
    assert set(APPENDIX_TERMS) == set(PRINTED_TERM_COUNTS)
    for name, count in PRINTED_TERM_COUNTS.items():
        assert len(APPENDIX_TERMS[name]) == count, name
    assert sum(len(t) for t in APPENDIX_TERMS.values()) == 78


def test_term_str_and_validation() -> None:
    term = APPENDIX_TERMS["J11"][19]
    assert str(term) == "- L2 sin(t1) sin(t3) sin(t2-t3)"
    assert term == Term(-1, "L2", (("sin", "t1"), ("sin", "t3"), ("sin", "t2-t3")))
    with pytest.raises(ValueError):
        Term(2, "L1", ())
    with pytest.raises(ValueError):
        Term(1, "X1", ())
    with pytest.raises(ValueError):
        Term(1, "L1", (("tan", "t1"),))


@pytest.mark.parametrize("seed", range(5))
def test_simple_elements(seed: int) -> None:
    theta, lengths = _random_case(seed)
    t1, t2 = theta[0], theta[1]
    jac = appendix_jacobian(theta, lengths)
    l2 = lengths["L2"]
    assert jac[0, 1] == pytest.approx(l2 * np.cos(t1) * np.sin(t2), rel=1e-14)
    assert jac[1, 1] == pytest.approx(l2 * np.sin(t1) * np.sin(t2), rel=1e-14)
    assert jac[2, 1] == pytest.approx(l2 * np.cos(t2), rel=1e-14)
    assert jac[2, 0] == 0.0
    assert appendix_element("J32", theta, lengths) == pytest.approx(jac[2, 1], rel=1e-15)


def test_missing_lengths_are_zero() -> None:
    theta, _ = _random_case(0)
    np.testing.assert_array_equal(appendix_jacobian(theta, {}), np.zeros((3, 3)))
    jac = appendix_jacobian(theta, {"L3": 2.0})
    t1, t3 = theta[0], theta[2]
    # printed L3 terms: J11 -L3 s1 s3, J13 +L3 c1 c3, J21 +L3 c1 s3, J23 +L3 s1 c3, J33 -L3 s3
    expected = np.array(
        [
            [-np.sin(t1) * np.sin(t3), 0.0, np.cos(t1) * np.cos(t3)],
            [np.cos(t1) * np.sin(t3), 0.0, np.sin(t1) * np.cos(t3)],
            [0.0, 0.0, -np.sin(t3)],
        ]
    )
    np.testing.assert_allclose(jac, 2.0 * expected, rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize("seed", range(5))
def test_kc_matches_central_difference(seed: int) -> None:
    theta, lengths = _random_case(seed)
    force = np.random.default_rng(100 + seed).uniform(-100.0, 100.0, 3)
    kc = appendix_kc(theta, force, lengths)
    h = 1e-6
    kc_fd = np.zeros((3, 3))
    for j in range(3):
        step = np.zeros(6)
        step[j] = h
        dj = appendix_jacobian(theta + step, lengths) - appendix_jacobian(theta - step, lengths)
        kc_fd[:, j] = (dj / (2 * h)).T @ force
    assert kc.shape == (3, 3)
    assert kc.dtype == np.float64
    np.testing.assert_allclose(kc, kc_fd, rtol=1e-6, atol=1e-6 * np.abs(kc_fd).max())


def test_complex_input() -> None:
    theta, lengths = _random_case(7)
    jac_real = appendix_jacobian(theta, lengths)
    jac_c = appendix_jacobian(theta.astype(complex), lengths)
    assert np.iscomplexobj(jac_c)
    np.testing.assert_allclose(jac_c.real, jac_real, rtol=1e-14, atol=1e-12)
    np.testing.assert_array_equal(jac_c.imag, 0.0)
    # complex step on theta_4 gives the derivative of the printed expressions
    h = 1e-30
    th = theta.astype(complex)
    th[3] += 1j * h
    d_cs = appendix_jacobian(th, lengths).imag / h
    e = np.zeros(6)
    e[3] = 1e-6
    d_fd = (appendix_jacobian(theta + e, lengths) - appendix_jacobian(theta - e, lengths)) / 2e-6
    np.testing.assert_allclose(d_cs, d_fd, rtol=1e-6, atol=1e-6 * np.abs(d_fd).max())
    value = appendix_element("J11", th, lengths)
    assert isinstance(value, complex | np.complexfloating)
