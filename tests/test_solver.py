"""The one least-squares driver of both campaign kinds (stiffness.calibration.solver), on small
problems with closed-form answers: its bounded refit after Levenberg-Marquardt, the columns it
reports at a bound, and identifiability judged at the representative point."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import nnls

from stiffness.calibration.identifiability import Identifiability, Layout, same_span
from stiffness.calibration.solver import (
    CRAWL_NFEV,
    Factored,
    Options,
    covariance_matrix,
    fit,
    solve,
)


class Linear:
    """Residuals ``A x - b`` with ``x >= 0`` (a solver Problem)."""

    def __init__(self, a: np.ndarray, b: np.ndarray) -> None:
        self.a, self.b = a, b
        p = a.shape[1]
        self.layout = Layout([list(range(p))], [False], np.ones(p), np.ones(p))
        self.nominal = np.zeros(p)

    def fun(self, x):
        return self.a @ x - self.b

    def jac(self, x):
        return self.a

    def failed(self, x):
        return False

    def bounds(self):
        p = self.a.shape[1]
        return np.zeros(p), np.full(p, np.inf)

    def columns(self, x, final):
        return self.a.copy()

    def start(self, x, ident):
        return np.array(x, dtype=float)


class Curve(Linear):
    """Residuals ``x0 exp(-x1 t) + x2 sin(x3 t) - y`` over 400 samples, ``x >= 0``: a
    nonlinear problem handing scipy its full Jacobian."""

    def __init__(self, y: np.ndarray) -> None:
        super().__init__(np.zeros((y.size, 4)), y)
        self.t = np.linspace(0.0, 4.0, y.size)

    def fun(self, x):
        return x[0] * np.exp(-x[1] * self.t) + x[2] * np.sin(x[3] * self.t) - self.b

    def jac(self, x):
        e, s = np.exp(-x[1] * self.t), np.sin(x[3] * self.t)
        return np.column_stack([e, -x[0] * self.t * e, s,
                                x[2] * self.t * np.cos(x[3] * self.t)])


class FactoredCurve(Curve):
    """The same problem as a :class:`Factored` one: R of ``[r, J]`` from two row blocks, and
    a robust loss's gradient and R of its reweighted Jacobian, from two row blocks too."""

    def factor(self, x, columns):
        whole = np.column_stack([self.fun(x), self.jac(x)[:, columns]])
        top = np.linalg.qr(whole[:150], mode="r")
        return np.linalg.qr(np.vstack([top, whole[150:]]), mode="r")

    def robust_factor(self, x, columns, scaling):
        psi, w = scaling(self.fun(x))
        weighted = w[:, None] * self.jac(x)[:, columns]
        top = np.linalg.qr(weighted[:150], mode="r")
        return (self.fun(x), self.jac(x)[:, columns].T @ psi,
                np.linalg.qr(np.vstack([top, weighted[150:]]), mode="r"))


def test_a_factored_problem_takes_the_full_problems_steps():
    """Levenberg-Marquardt and trust-region reflective (a bound active) on the (k + 1)-row
    factor reach the full problem's optimum in the same number of evaluations (the same
    steps), its residual returned whole and a factor with its J^T J."""
    t = np.linspace(0.0, 4.0, 400)
    rng = np.random.default_rng(4)
    for truth, method in (([2.0, 0.7, 0.5, 3.0], "lm"), ([2.0, -0.2, 0.5, 3.0], "trf")):
        y = truth[0] * np.exp(-truth[1] * t) + truth[2] * np.sin(truth[3] * t)
        y = y + 0.01 * rng.normal(size=t.size)
        full, factored = Curve(y), FactoredCurve(y)
        assert isinstance(factored, Factored) and not isinstance(full, Factored)
        x0 = np.array([1.0, 1.0, 0.3, 2.9])
        a = solve(full, x0, Identifiability.full(4), Options(method, 1e-12))
        b = solve(factored, x0, Identifiability.full(4), Options(method, 1e-12))
        np.testing.assert_allclose(b.x, a.x, rtol=1e-9, atol=1e-12)
        assert (a.nfev, a.at_bound) == (b.nfev, b.at_bound)
        assert b.at_bound == ([1] if method == "trf" else [])
        np.testing.assert_allclose(b.fun, full.fun(b.x), atol=1e-15)
        assert b.jac.shape == (5, 4)
        np.testing.assert_allclose(b.jac.T @ b.jac, a.jac.T @ a.jac, rtol=1e-8)


@pytest.mark.parametrize("loss", ["huber", "cauchy", "soft_l1"])
def test_a_factored_robust_fit_takes_the_full_problems_steps(loss):
    """Under a robust loss (8 of the 400 samples off by 50 noise stds, the loss's scale the
    noise), trust-region reflective on the (k + 1)-row factor of the reweighted Jacobian
    reaches scipy's own robust optimum of the full problem (to the digits the full problem's
    steps keep: the same fit with its rows permuted moves by 3e-11), its residual returned
    whole, least squares' 1e-2 away."""
    t = np.linspace(0.0, 4.0, 400)
    rng = np.random.default_rng(6)
    y = 2.0 * np.exp(-0.7 * t) + 0.5 * np.sin(3.0 * t) + 0.01 * rng.normal(size=t.size)
    y[rng.choice(t.size, 8, replace=False)] += 0.5
    full, factored = Curve(y), FactoredCurve(y)
    x0 = np.array([1.5, 1.0, 0.3, 2.9])
    options = Options("trf", 1e-12, loss=loss, f_scale=0.01)
    a = solve(full, x0, Identifiability.full(4), options)
    b = solve(factored, x0, Identifiability.full(4), options)
    np.testing.assert_allclose(b.x, a.x, rtol=1e-9)
    assert a.success and b.success and a.at_bound == b.at_bound == []
    np.testing.assert_allclose(b.fun, full.fun(b.x), atol=1e-15)
    assert b.jac.shape == (5, 4) and not b.jac[4].any()
    ls = solve(full, x0, Identifiability.full(4), Options("trf", 1e-12))
    assert np.abs(ls.x - a.x).max() > 5e-3


def test_levenberg_marquardt_past_a_bound_is_refitted_under_it_as_nnls():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(30, 4))
    b = a @ np.array([1.0, -0.5, 2.0, 0.3]) + 0.01 * rng.normal(size=30)
    problem = Linear(a, b)
    sol = solve(problem, np.zeros(4), Identifiability.full(4), Options("lm", 1e-12))
    expected, _ = nnls(a, b)
    np.testing.assert_allclose(sol.x, expected, atol=1e-8)
    assert sol.at_bound == [1] and sol.x[1] == 0.0
    # unbounded Levenberg-Marquardt alone would have gone negative
    free, *_ = np.linalg.lstsq(a, b, rcond=None)
    assert free[1] < 0


def test_covariance_is_sigma_squared_inverse_normal_matrix():
    rng = np.random.default_rng(1)
    j = rng.normal(size=(40, 3))
    cov = covariance_matrix(j, 0.1).matrix
    np.testing.assert_allclose(cov, 0.01 * np.linalg.inv(j.T @ j), rtol=1e-10)


def test_a_robust_covariance_keeps_a_weakly_determined_direction():
    """Huber's sandwich of a fit whose residuals all lie within the loss's quadratic zone is
    the least-squares ``SS / (N - p) (J^T J)^-1``; with a column 1e-9 of the other's (a wrist
    joint's compliance on a Kinova arm, torques of 1e-4 N.m: found by the pose sweep of issue
    47) ``(J^T J)^+`` squared that to 1e-18, below pinv's cut-off, and the weak parameter's
    variance came out 0 (its interval zero wide, the parameter taken as determined)."""
    rng = np.random.default_rng(4)
    q, _ = np.linalg.qr(rng.normal(size=(60, 2)))
    s = np.array([1.0, 1e-9])
    j = q * s  # J^T J = diag(s^2) exactly
    r = rng.normal(0.0, 0.01, 60)
    cov = covariance_matrix(j, 0.01, "huber", r, 10.0).matrix
    expected = r @ r / 58 / s ** 2
    np.testing.assert_allclose(np.diag(cov), expected, rtol=1e-6)


class Bilinear:
    """``y = a t + a b t^2`` over ``(a, b)``: ``b`` moves nothing while ``a`` is 0 (an
    effect's setting that acts only through its size), one effect of two parameters."""

    def __init__(self, t: np.ndarray, y: np.ndarray) -> None:
        self.t, self.y = t, y
        self.layout = Layout([[0], [1]], [False, False], np.ones(2), np.ones(2),
                             [([0], [0, 1])])
        self.nominal = np.zeros(2)

    def fun(self, x):
        return x[0] * self.t + x[0] * x[1] * self.t ** 2 - self.y

    def jac(self, x):
        return np.column_stack([self.t + x[1] * self.t ** 2, x[0] * self.t ** 2])

    def failed(self, x):
        return False

    def bounds(self):
        return None

    def columns(self, x, final):
        return self.jac(x)

    def start(self, x, ident):
        return np.array(x, dtype=float)


def test_a_parameter_acting_through_an_absent_effect_is_judged_with_it_present():
    t = np.linspace(0.1, 1.0, 20)
    problem = Bilinear(t, 0.7 * t + 0.7 * 0.4 * t ** 2)
    # at the start a = 0: b's column is zero, yet at the representative point (a = 1) it is seen
    assert not np.any(problem.columns(np.zeros(2), False)[:, 1])
    sol = fit(problem, np.zeros(2), Options("lm", 1e-12))
    assert sol.identifiability.kept == [0, 1]
    np.testing.assert_allclose(sol.x, [0.7, 0.4], rtol=1e-8)


def test_reductions_keeping_other_members_of_exact_aliases_are_the_same_model():
    rng = np.random.default_rng(2)
    a = rng.normal(size=(12, 3))
    a = np.column_stack([a[:, 0], 2.0 * a[:, 0], a[:, 1], a[:, 1] + 1e-3 * a[:, 2]])
    assert same_span(a, [0, 2], [1, 2])          # 1 is 2 x column 0: the same model
    assert not same_span(a, [0, 2], [0, 3])      # 3 differs from 2 by a sine of ~1e-3
    assert not same_span(a, [0, 2], [0, 1, 2])


class LogCompliance(Linear):
    """Residuals ``a_0 exp(-x_0) + A_1 x_1 - b``: column 0's parameter is a joint's ``ln k``
    (its compliance ``exp(-x_0)``, ``x_0`` within [-5, 30]), the others ``>= 0``."""

    def fun(self, x):
        return self.a[:, 0] * np.exp(-x[0]) + self.a[:, 1:] @ x[1:] - self.b

    def jac(self, x):
        return np.column_stack([-self.a[:, 0] * np.exp(-x[0]), self.a[:, 1:]])

    def bounds(self):
        p = self.a.shape[1]
        return np.r_[-5.0, np.zeros(p - 1)], np.r_[30.0, np.full(p - 1, np.inf)]


def test_a_log_stiffness_is_solved_over_its_compliance_to_the_same_optimum():
    """``Options.log_columns``: where a near alias (column 1, column 0 plus 1 %) takes the
    compliance's share, the best fit makes the joint rigid (``ln k`` at its upper bound, the
    others the least squares without it); after ``CRAWL_NFEV`` evaluations over ``ln k`` the
    fit goes on over the compliance and gets there within 15 more (over ``ln k`` alone it
    crawled for 153). Where the
    optimum is inside the bounds, both give the same one (the closed form)."""
    rng = np.random.default_rng(3)
    a = rng.normal(size=(40, 3))
    a[:, 1] = a[:, 0] + 0.01 * rng.normal(size=40)
    rigid = LogCompliance(a, a @ np.array([-0.05, 1.0, 0.5]) + 1e-4 * rng.normal(size=40))
    x0 = np.array([0.0, 0.1, 0.1])
    sol = solve(rigid, x0, Identifiability.full(3), Options("trf", 1e-10, log_columns=(0,)))
    rest, *_ = np.linalg.lstsq(a[:, 1:], rigid.b, rcond=None)
    assert np.exp(-sol.x[0]) < 1e-6  # rigid to the tolerance (fitting's _rigid: at the bound)
    np.testing.assert_allclose(sol.x[1:], rest, rtol=1e-5)
    assert sol.nfev <= CRAWL_NFEV + 15
    np.testing.assert_allclose(sol.jac[:, 1:], rigid.jac(sol.x)[:, 1:], rtol=1e-12)
    assert np.abs(sol.jac[:, 0]).max() < 1e-9  # in ln k again (scipy's, before the bound)
    inside = LogCompliance(a, a @ np.array([0.3, 1.0, 0.5]))
    for logs in ((), (0,)):
        sol = solve(inside, x0, Identifiability.full(3), Options("trf", 1e-12, log_columns=logs))
        np.testing.assert_allclose(sol.x, [-np.log(0.3), 1.0, 0.5], rtol=1e-8)
