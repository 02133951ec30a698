"""The one least-squares driver of both campaign kinds.

A campaign kind supplies only its observation: a :class:`Problem`, its residuals and their
Jacobian columns over a parameter vector ``x``, the parameters' bounds, how they are laid out
for identifiability (:class:`~stiffness.calibration.identifiability.Layout`) and each
parameter's nominal value, the value a parameter left out is held at. A deflection campaign's is
:class:`stiffness.calibration.fitting.Objective` (over a
:class:`~stiffness.elastic.effects.hypothesis.Hypothesis`); a pose campaign's
:class:`stiffness.calibration.pose_fit.PoseProblem` (over a
:class:`~stiffness.calibration.pose_model.PoseModel`). Everything else is here, once:

* :func:`fit`: which parameters the data identify (the one judgement,
  :func:`stiffness.calibration.identifiability.identifiable`, at the start's representative
  point; near aliases judged again at the optimum and the fit redone without them), the others
  held at their nominal values whatever the fit starts from (:func:`held_at_nominal`), and
  :func:`solve`;
* :func:`solve`: :func:`scipy.optimize.least_squares` over the kept columns within the
  parameters' bounds: trust-region reflective, or Levenberg-Marquardt followed, when its optimum
  is past a bound, by the bounded fit from the clipped optimum; under a robust loss
  (:data:`LOSSES`); the columns it leaves at a bound reported (their intervals one-sided); a
  :class:`Factored` problem (a large pose campaign's) handed to scipy on k + 1 rows with the
  full problem's steps, under least squares or a robust loss (:class:`Handed`); logarithmic
  parameters (a deflection model's ``ln k``) taken over their reciprocals when a bounded fit
  has not converged after :data:`CRAWL_NFEV` evaluations (:func:`_reciprocal_run`);
* the losses (:func:`loss_terms`, :func:`loss_sum`, :func:`objective_rss`), and the
  covariance (:func:`covariance_matrix`: ``sigma^2 (J^T J)^+`` with one cut-off for
  undetermined directions, or Huber's sandwich, :func:`sandwich_matrix`, for a robust loss).

Robust losses: ``loss`` other than ``linear`` minimises ``sum f^2 rho((r / f)^2)`` of the
residuals ``r`` with scipy's ``rho`` (``soft_l1``, ``huber``, ``cauchy``) and ``f`` the noise
std in the residuals' units, so a residual beyond about ``f`` weighs less than its square.
Such a fit's covariance is Huber's sandwich (M-estimator) covariance
``K^2 [sum phi'^2 / (N - p)] / mean(phi'')^2 (J^T J)^+`` with ``phi(r) = f^2 rho((r / f)^2) /
2``: it takes the spread from the residuals themselves through the loss, not from an assumed
noise, so its intervals stay honest when the data hold outliers or the noise is not the
declared one. It needs only the residuals and ``J^T J``: a :class:`Factored` problem's
comes from its triangular factor.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from scipy import linalg
from scipy.optimize import least_squares

from stiffness.calibration.identifiability import (
    Identifiability,
    Layout,
    identifiable,
    same_span,
)
from stiffness.elastic.effects.base import Held
from stiffness.errors import StiffnessError, UnknownNameError

#: Losses of every fit (scipy.optimize.least_squares'): ``linear`` is least squares.
LOSSES = ("linear", "soft_l1", "huber", "cauchy")
#: Singular values of the whitened residual Jacobian below this fraction of the largest are
#: zero: the data do not determine that direction.
SINGULAR_RTOL = 1e-10
#: A parameter with a component above this along an undetermined direction has infinite
#: variance.
UNSEEN_COMPONENT = 1e-8


#: A robust loss's rows from their residuals: their gradient factors and weights
#: (:func:`robust_rows`).
RowScaling = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


def loss_terms(loss: str, z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``rho(z)``, ``rho'(z)`` and ``rho''(z)`` of a loss of :data:`LOSSES` at ``z = (r/f)^2``
    (scipy's definitions: ``soft_l1`` ``2 (sqrt(1 + z) - 1)``, ``huber`` ``z`` up to 1 then
    ``2 sqrt(z) - 1``, ``cauchy`` ``ln(1 + z)``)."""
    z = np.asarray(z, dtype=float)
    if loss == "linear":
        return z, np.ones_like(z), np.zeros_like(z)
    if loss == "soft_l1":
        t = 1.0 + z
        return 2.0 * (np.sqrt(t) - 1.0), t ** -0.5, -0.5 * t ** -1.5
    if loss == "huber":
        small = z <= 1.0
        root = np.sqrt(np.where(small, 1.0, z))
        return (np.where(small, z, 2.0 * root - 1.0), np.where(small, 1.0, 1.0 / root),
                np.where(small, 0.0, -0.5 / root ** 3))
    if loss == "cauchy":
        t = 1.0 + z
        return np.log1p(z), 1.0 / t, -1.0 / t ** 2
    raise StiffnessError(f"unknown loss {loss!r}; valid losses: {', '.join(LOSSES)}")


def check_loss(loss: str, method: str = "trf") -> None:
    """Refuse a loss not in :data:`LOSSES`, or a robust one with ``method`` ``lm`` or
    ``both`` (Levenberg-Marquardt is least squares only), in one line."""
    if loss not in LOSSES:
        raise UnknownNameError(f"unknown loss {loss!r}; valid losses: {', '.join(LOSSES)}",
                               name=loss, choices=LOSSES)
    if loss != "linear" and method != "trf":
        raise StiffnessError(f"loss {loss} needs method trf (Levenberg-Marquardt is least "
                             "squares only); use --method trf or --loss linear")


@functools.cache
def gaussian_loss_mean(loss: str) -> float:
    """``E[rho(Z^2)]`` for a standard normal ``Z`` (1 for ``linear``; Gauss-Hermite, 80
    nodes): the expected loss of a residual at the noise scale, so that
    ``loss_value / gaussian_loss_mean`` counts like a sum of squares over the noise."""
    nodes, weights = np.polynomial.hermite_e.hermegauss(80)
    return float(np.sum(weights * loss_terms(loss, nodes ** 2)[0]) / math.sqrt(2.0 * math.pi))


def loss_sum(residuals: np.ndarray, loss: str, f_scale: float) -> float:
    """``sum f^2 rho((r / f)^2)`` of residuals ``r`` (the sum of squares for ``linear``; twice
    scipy's ``cost``)."""
    r = np.asarray(residuals, dtype=float).reshape(-1)
    if loss == "linear":
        return float(np.sum(r ** 2))
    return float(f_scale ** 2 * np.sum(loss_terms(loss, (r / f_scale) ** 2)[0]))


def objective_rss(residual: np.ndarray, loss: str, sigma: float) -> float:
    """The objective of residuals (any unit) as a sum of squares (that unit squared), what
    selection criteria compare: their sum of squares for least
    squares; for a robust ``loss`` ``sigma^2 sum rho((r / sigma)^2)`` over its Gaussian
    expectation (:func:`gaussian_loss_mean`: the same expectation, ``N sigma^2``, for Gaussian
    residuals of std ``sigma``; an outlier adds about ``2 sigma |r|`` instead of ``r^2``)."""
    if loss == "linear":
        r = np.asarray(residual, dtype=float).reshape(-1)
        return float(r @ r)
    return sigma ** 2 * loss_sum(np.asarray(residual) / sigma, loss, 1.0) / gaussian_loss_mean(
        loss)


def robust_rows(loss: str, f_scale: float) -> RowScaling:
    """scipy's scaling of a robust ``loss``'s rows (``least_squares``' own, done row by row):
    from residuals ``r``, their gradient factors ``psi = rho' r`` (``J^T psi`` is the
    objective's gradient over 2) and the weights ``w = sqrt(max(rho' + 2 z rho'', eps))`` of
    their Jacobian's rows (``(w J)^T (w J)`` is the Gauss-Newton matrix of the trust-region
    steps; ``z = (r / f_scale)^2``, ``eps`` the float64 machine epsilon); scipy's scaled
    residuals are ``psi / w``."""

    def scaling(residual: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r = np.asarray(residual, dtype=float)
        z = (r / f_scale) ** 2
        _, d_rho, dd_rho = loss_terms(loss, z)
        return d_rho * r, np.sqrt(np.maximum(d_rho + 2.0 * dd_rho * z, np.finfo(float).eps))

    return scaling


def carried_loss(z: np.ndarray) -> np.ndarray:
    """The loss (scipy's callable form: ``rho``, ``rho'``, ``rho''`` (3, m) at ``z``) under
    which a :class:`Factored` problem's robust fit is handed to scipy (:func:`solve`): the
    last residual carries the objective (its square is the cost; weight 0 in the steps), the
    others weigh as in least squares and cost nothing."""
    rho = np.zeros((3, z.size))
    rho[0, -1] = z[-1]
    rho[1, :-1] = 1.0
    return rho


def projected_residual(tri: np.ndarray, gradient: np.ndarray) -> np.ndarray:
    """``f`` (k,) with ``tri^T f = gradient``: the residual whose least squares on the
    Jacobian ``tri`` (k, k), upper triangular, has that gradient (the minimum-norm one
    where ``tri`` is singular)."""
    if np.all(np.diag(tri) != 0):
        return linalg.solve_triangular(tri, gradient, trans="T")
    return np.linalg.lstsq(tri.T, gradient, rcond=None)[0]


class Problem(Protocol):
    """A campaign's observation, what :func:`fit` and :func:`solve` need of it."""

    layout: Layout
    #: Each parameter's nominal value (p,), what a parameter left out of a fit (no effect,
    #: merged, undetermined) is held at whatever the fit starts from
    #: (:func:`held_at_nominal`): the model's start for its joint or effect.
    nominal: np.ndarray

    def fun(self, x: np.ndarray) -> np.ndarray:
        """The residuals the solver minimises at ``x`` (a large constant where the model
        cannot be evaluated, so the solver backs off)."""
        ...

    def jac(self, x: np.ndarray) -> np.ndarray:
        """Their derivative (N, p) w.r.t. ``x``."""
        ...

    def failed(self, x: np.ndarray) -> bool:
        """Whether the model cannot be evaluated at ``x``."""
        ...

    def bounds(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Each parameter's (lower, upper) bound, or ``None`` for an unbounded fit."""
        ...

    def columns(self, x: np.ndarray, final: bool) -> np.ndarray | None:
        """The regressor at ``x``, each column times its parameter's typical size and whitened
        by the noise std (:func:`~stiffness.calibration.identifiability.identifiable`), or
        ``None`` where the model cannot be evaluated; ``final``: at the optimum (the
        reported Jacobian's accuracy)."""
        ...

    def start(self, x: np.ndarray, ident: Identifiability) -> np.ndarray:
        """The start the fit solves from: ``x``, whose parameters ``ident`` leaves out are at
        their nominal values, or what the campaign kind puts instead (a pose campaign: all
        nominal where the sag diverges at ``x``); refuses a fit the kind cannot make."""
        ...


@runtime_checkable
class Factored(Problem, Protocol):
    """A problem whose Jacobian is never held whole (a large pose campaign's): its fit runs on
    triangular factors of it (:func:`solve`), computed from blocks of rows."""

    def factor(self, x: np.ndarray, columns: np.ndarray) -> np.ndarray:
        """``R`` (at most (k + 1, k + 1), upper triangular) of ``[r, J[:, columns]] = Q R``
        at ``x``: ``r`` :meth:`fun`'s residuals, ``J`` :meth:`jac`'s Jacobian."""
        ...

    def robust_factor(self, x: np.ndarray, columns: np.ndarray, scaling: RowScaling
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`fun`'s residuals ``r`` (N,) at ``x``, a robust loss's gradient
        ``J[:, columns]^T psi`` (k,) and ``R`` (at most (k, k), upper triangular) of
        ``diag(w) J[:, columns]``, ``(psi, w) = scaling(r)`` row by row
        (:func:`robust_rows`), in one pass over blocks of rows."""
        ...


@dataclass
class Options:
    """The solver's settings: ``method`` (``trf``, or ``lm``: Levenberg-Marquardt, least
    squares only), ``tolerance`` (its ``xtol``, ``ftol`` and ``gtol``), ``max_nfev`` (its
    evaluation budget, default ``40 (p + 1)``), ``x_scale`` (scipy's variable scale: a number,
    (p,) values, or ``None`` for scipy's default), ``loss`` (:data:`LOSSES`), ``f_scale``
    (a robust loss's soft threshold, in the residuals' units) and ``log_columns`` (parameters
    that are the logarithm of a positive quantity, a joint's ``ln k``: a bounded trf solve
    not converged after :data:`CRAWL_NFEV` evaluations goes on over their reciprocals,
    :func:`_reciprocal_run`)."""

    method: str = "trf"
    tolerance: float = 1e-10
    max_nfev: int | None = None
    x_scale: float | np.ndarray | None = None
    loss: str = "linear"
    f_scale: float = 1.0
    log_columns: tuple[int, ...] = ()


@dataclass
class Solution:
    """A solver's optimum: ``x`` (p,), the fitted and held parameters (``identifiability``),
    scipy's ``success``, ``status`` and ``message``, the evaluations (``nfev``), the columns left
    at a bound (``at_bound``, set exactly there in ``x``), and scipy's residuals ``fun`` and
    Jacobian ``jac`` over the kept columns at the optimum (``jac`` reweighted by a robust
    loss; for a :class:`Factored` problem the (k + 1, k) factor ``[r^T J / |r|; R_2]``
    instead, :func:`solve`: the same ``J^T J`` and ``J^T r``; under a robust loss ``[R; 0]``,
    ``R`` the factor of the loss's reweighted Jacobian)."""

    x: np.ndarray
    identifiability: Identifiability
    success: bool
    status: int
    message: str
    nfev: int
    at_bound: list[int]
    fun: np.ndarray
    jac: np.ndarray


def fit(problem: Problem, x0: np.ndarray, options: Options, resolution: float = 0.0,
        held: dict[int, Held] | None = None, near_at_start: bool = False) -> Solution:
    """The fit of ``problem`` from ``x0``: the identifiable parameters (at the representative
    point of ``x0``; near aliases at ``resolution``, noise std per typical size, judged at the
    optimum, and at the start too with ``near_at_start``), those of ``held`` (column: why)
    held as undetermined, every one left out held at its nominal value
    (:func:`held_at_nominal`, whatever ``x0`` says: a warm start is another fit's optimum),
    and :func:`solve`. When the near aliases at the optimum are not those of the start, the
    fit is redone from the optimum with them held (unless the optimum's reduction keeps the
    same span, other members of exact aliases: the same model). A fit that ends where the
    model diverges (a bounded refit from a bound) is returned as it ended: its residual is the
    diverged constant, and the caller never chooses it."""
    ident = identifiable(problem.layout, x0, lambda p: problem.columns(p, False),
                         resolution if near_at_start else 0.0).holding(held or {})
    sol = solve(problem, problem.start(held_at_nominal(problem, x0, ident), ident), ident,
                options)
    if resolution <= 0 or problem.failed(sol.x):
        return sol  # a fit ending where the model diverges is not judged again (never chosen)
    seen: list[np.ndarray] = []

    def columns(point: np.ndarray) -> np.ndarray | None:
        a = problem.columns(point, np.array_equal(point, sol.x))
        seen[:] = [] if a is None else [a]
        return a

    near = identifiable(problem.layout, sol.x, columns, resolution).holding(held or {})
    if set(near.kept) == set(ident.kept) or (
            seen and same_span(seen[0], ident.kept, near.kept)):
        return sol  # the same model (at most other members of exact aliases kept)
    again = solve(problem, problem.start(held_at_nominal(problem, sol.x, near), near), near,
                  options)
    again.nfev += sol.nfev
    return again


def held_at_nominal(problem: Problem, x: np.ndarray, ident: Identifiability) -> np.ndarray:
    """``x`` with the parameters ``ident`` leaves out (no effect, merged, undetermined) at
    their nominal values (:attr:`Problem.nominal`): the one rule of both campaign kinds. Not
    at ``x``'s: a fit's start is often another fit's optimum (a candidate extending the
    current model, a cross-validation fold, a refit without an effect), and a parameter held
    there would carry that fit's value, on other rows (a fold's held-out ones) or other
    columns, into this one and its report. An exact merge's kept parameters absorb the held
    one at any value (the same predictions); a near merge's move by the part of its column the
    kept ones cannot absorb (below the resolution per typical size the held value moves)."""
    out = np.array(x, dtype=float)
    left = [d.index for d in ident.dropped]
    out[left] = problem.nominal[left]
    return out


class Handed:
    """What :func:`solve` hands scipy for ``problem`` over its columns ``free``, the others
    held at ``x0``: the residuals and Jacobian, or a :class:`Factored` problem's few rows.

    A :class:`Factored` problem's least squares (linear loss) is handed to scipy on k + 1
    rows: the residuals ``[|r|, 0, ..., 0]`` and the Jacobian ``[r^T J / |r|; R_2]``, the
    factor ``R`` of ``[r, J] = Q R`` (:meth:`Factored.factor`) without its first column.
    Its ``J^T J`` and ``J^T r`` are the full problem's, and so is ``|r|``: every quantity
    Levenberg-Marquardt and trust-region reflective use (the steps, which depend on the
    Jacobian only through ``J^T J`` and ``J^T r``; the predicted and actual reductions; the
    column-norm scaling; the gradient test) is the full problem's, while only a block of the
    Jacobian's rows is ever held.

    Under a robust loss, scipy's trust-region reflective sees the problem only through the
    objective ``sum f^2 rho((r / f)^2) / 2`` (its cost), the gradient ``g = J^T psi`` and the
    Gauss-Newton matrix ``J^T diag(w^2) J`` of the rows scaled by the loss
    (:func:`robust_rows`). A :class:`Factored` problem's is handed to it on k + 1 rows: the
    Jacobian ``[R; 0]``, ``R`` the factor of ``diag(w) J``, and the residuals
    ``[R^-T g; sqrt(2 cost)]`` (:meth:`Factored.robust_factor`, :func:`projected_residual`)
    under :func:`carried_loss` (the last residual's square is the cost; the others weigh as in
    least squares): the same cost, gradient and Gauss-Newton matrix, so the same steps,
    reductions and tests, one block of rows held at a time. scipy's own scaled residuals
    ``psi / w`` are huge where a loss's curvature vanishes (``w = sqrt(eps)``: huber's and
    cauchy's far residuals) and cost the steps digits wherever they are mixed with the
    Jacobian; ``R^-T g`` has none of them. Each residual evaluation evaluates the
    Jacobian's blocks too (for ``R^-T g``, with the residuals), once per point.
    """

    def __init__(self, problem: Problem, x0: np.ndarray, free: np.ndarray,
                 options: Options) -> None:
        self.problem, self.x0, self.free = problem, x0, free
        self.loss, self.f_scale = options.loss, float(options.f_scale)
        # checked once: a runtime Protocol's isinstance inspects every member (0.1 ms, at
        # each Jacobian of a fit)
        self.factors: Factored | None = problem if isinstance(problem, Factored) else None
        self.factored = self.factors is not None
        self.scaling = robust_rows(self.loss, self.f_scale)
        self._weighted: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def loss_options(self) -> dict:
        """scipy's ``loss`` and ``f_scale`` arguments."""
        if self.loss == "linear":
            return {}
        if self.factored:
            return {"loss": carried_loss}
        return {"loss": self.loss, "f_scale": self.f_scale}

    def full(self, z: np.ndarray) -> np.ndarray:
        """The parameters (p,) with the solver's variables ``z`` (k,) at their columns."""
        x = self.x0.copy()
        x[self.free] = z
        return x

    def residual(self, z: np.ndarray) -> np.ndarray:
        """The residuals handed to scipy at ``z``."""
        if self.factored and self.loss != "linear":
            return self._robust(z)[1]
        r = self.problem.fun(self.full(z))
        if not self.factored:
            return r
        out = np.zeros(self.free.size + 1)
        out[0] = np.linalg.norm(r)
        return out

    def jacobian(self, z: np.ndarray) -> np.ndarray:
        """Their Jacobian at ``z``."""
        if self.factors is None:
            return self.problem.jac(self.full(z))[:, self.free]
        if self.loss != "linear":
            return self._robust(z)[0]
        tri = self.factors.factor(self.full(z), self.free)
        tri[0] *= -1.0 if tri[0, 0] < 0 else 1.0  # R[0, 0] = |r|: r = Q[:, 0] |r|
        out = np.zeros((self.free.size + 1, self.free.size))
        out[:tri.shape[0]] = tri[:, 1:]
        return out

    def _robust(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The Jacobian ``[R; 0]`` and the residuals ``[R^-T g; sqrt(2 cost)]`` at ``z``, kept
        for the last ``z`` (scipy asks for the residuals, then for the Jacobian of an
        accepted point)."""
        if self._weighted is None or not np.array_equal(self._weighted[0], z):
            assert self.factors is not None
            r, gradient, tri = self.factors.robust_factor(self.full(z), self.free,
                                                          self.scaling)
            jac = np.zeros((self.free.size + 1, self.free.size))
            jac[:tri.shape[0]] = tri
            out = np.append(projected_residual(jac[:-1], gradient),
                            math.sqrt(loss_sum(r, self.loss, self.f_scale)))
            self._weighted = (z.copy(), jac, out)
        return self._weighted[1], self._weighted[2]


def solve(problem: Problem, x0: np.ndarray, ident: Identifiability,
          options: Options) -> Solution:
    """:func:`scipy.optimize.least_squares` of ``problem`` over the kept columns of ``ident``,
    the others held at ``x0`` (module docstring). A :class:`Factored` problem is handed to
    scipy on k + 1 rows with the full problem's steps (:class:`Handed`); ``sol.fun`` is then
    the full residual at the optimum, and ``sol.jac`` the factor scipy was handed.
    """
    free = np.asarray(ident.kept, dtype=int)  # the solver's variables, in the kept order
    if not free.size:
        fun = problem.fun(x0)
        return Solution(x0, ident, True, 1, "no parameter is seen by the data", 1, [], fun,
                        np.zeros((fun.size, 0)))
    handed = Handed(problem, x0, free, options)
    kwargs: dict = {"xtol": options.tolerance, "ftol": options.tolerance,
                    "gtol": options.tolerance,
                    "max_nfev": options.max_nfev or 40 * (x0.size + 1),
                    **handed.loss_options()}
    if options.x_scale is not None:
        kwargs["x_scale"] = (options.x_scale if np.ndim(options.x_scale) == 0
                             else np.asarray(options.x_scale)[free])
    bounds = problem.bounds()
    lo, hi = ((np.full(x0.size, -np.inf), np.full(x0.size, np.inf)) if bounds is None
              else bounds)
    lo, hi = lo[free], hi[free]
    full = handed.full

    logs = np.flatnonzero(np.isin(free, options.log_columns))

    def run(z0: np.ndarray, method: str, bounded: bool):
        extra = {"bounds": (lo, hi)} if bounded and bounds is not None else {}
        if not (method == "trf" and extra and logs.size and kwargs["max_nfev"] > CRAWL_NFEV):
            return least_squares(handed.residual, z0, jac=handed.jacobian, method=method,
                                 **kwargs, **extra)
        first = least_squares(handed.residual, z0, jac=handed.jacobian, method=method,
                              **{**kwargs, "max_nfev": CRAWL_NFEV}, **extra)
        if first.status != 0:  # converged within CRAWL_NFEV evaluations
            return first
        rest = {**kwargs, "max_nfev": kwargs["max_nfev"] - CRAWL_NFEV}
        sol = _reciprocal_run(handed, np.clip(first.x, lo, hi), logs, lo, hi, rest)
        sol.nfev += first.nfev
        return sol

    sol = run(x0[free], options.method, options.method == "trf")
    nfev = int(sol.nfev)
    if options.method == "lm" and np.any((sol.x < lo) | (sol.x > hi)):
        # past a bound: the bounded fit from the clipped optimum (or, where the model cannot
        # be evaluated there, from the bounded parameters at their bound, else from the start)
        starts = [np.clip(sol.x, lo, hi),
                  np.where(np.isfinite(lo), lo, np.where(np.isfinite(hi), hi, sol.x)),
                  np.clip(x0[free], lo, hi)]
        start = next((z for z in starts[:-1] if not problem.failed(full(z))), starts[-1])
        sol = run(start, "trf", True)
        nfev += int(sol.nfev)
    active = np.flatnonzero(sol.active_mask)
    z = np.where(sol.active_mask < 0, lo, np.where(sol.active_mask > 0, hi, sol.x))
    return Solution(full(z), ident, bool(sol.success), int(sol.status), str(sol.message), nfev,
                    [int(i) for i in free[active]],
                    problem.fun(full(sol.x)) if handed.factored else sol.fun, sol.jac)


#: Evaluations after which a bounded trf fit with :attr:`Options.log_columns` goes on over
#: their reciprocals (:func:`_reciprocal_run`): a fit converging sooner is untouched.
CRAWL_NFEV = 30


def _reciprocal_run(handed: Handed, z0: np.ndarray, logs: np.ndarray, lo: np.ndarray,
                    hi: np.ndarray, kwargs: dict):
    """scipy's bounded trf of ``handed`` from ``z0`` (bounds ``lo``, ``hi``) with the
    variables at positions ``logs`` (logarithms, ``ln k``) replaced by ``w = exp(z0 - z)``
    (a compliance relative to the start's, 1 there), its result in ``z`` again: ``x`` and
    ``jac`` carried back, ``active_mask`` flipped where ``w`` is at a bound.

    The same problem and optimum, with a better path: where a near alias of a joint's
    compliance takes its share (a link bend, a transversal compliance), the best fit makes that
    joint rigid, ``w -> 0``; over ``ln k`` the slope vanishes as ``exp(-ln k)`` along the
    valley and trust-region reflective crawled there for 100-250 evaluations (fetch's arm,
    docs/performance.md), over ``w`` it reaches the bound as in a linear problem.
    """
    ref = z0[logs]

    def to_z(w: np.ndarray) -> np.ndarray:
        z = w.copy()
        z[logs] = ref - np.log(w[logs])
        return z

    def slope(w: np.ndarray) -> np.ndarray:
        d = np.ones(w.size)
        d[logs] = -1.0 / w[logs]  # dz/dw
        return d

    w_lo, w_hi, w0 = lo.copy(), hi.copy(), z0.copy()
    w_lo[logs], w_hi[logs], w0[logs] = np.exp(ref - hi[logs]), np.exp(ref - lo[logs]), 1.0
    sol = least_squares(lambda w: handed.residual(to_z(w)), w0,
                        jac=lambda w: handed.jacobian(to_z(w)) * slope(w), method="trf",
                        bounds=(w_lo, w_hi), **kwargs)
    sol.jac = sol.jac / slope(sol.x)
    sol.x = to_z(sol.x)
    sol.active_mask[logs] *= -1
    return sol


@dataclass
class Covariance:
    """Covariance of a fit's parameters and the SVD it comes from.

    Attributes
    ----------
    matrix
        (p, p) ``sigma^2 (J^T J)^+`` (inf rows/columns for parameters along undetermined
        directions).
    singular_values
        (p,) singular values of the whitened residual Jacobian ``J / sigma`` (zeros appended
        when there are fewer residuals than parameters), descending.
    directions
        (p, p) right-singular vectors (rows), in the order of ``singular_values``.
    undetermined
        (p,) mask of the singular values below :data:`SINGULAR_RTOL` times the largest.
    """

    matrix: np.ndarray
    singular_values: np.ndarray
    directions: np.ndarray
    undetermined: np.ndarray

    @property
    def rank(self) -> int:
        """How many directions the data determine: those a robust fit's sandwich spreads over
        (:func:`sandwich_matrix`), whose intervals then take ``n - rank`` degrees of freedom."""
        return int(np.count_nonzero(~self.undetermined))

    @property
    def condition_number(self) -> float:
        """Largest over smallest singular value (inf with an undetermined direction)."""
        if self.undetermined.any() or not self.singular_values.size:
            return math.inf
        return float(self.singular_values.max() / self.singular_values.min())


def covariance_matrix(jacobian: np.ndarray, sigma: float, loss: str = "linear",
                      residual: np.ndarray | None = None, f_scale: float = 1.0
                      ) -> Covariance:
    """The covariance of parameters whose residuals have the Jacobian ``jacobian`` (N, p) (or
    any (m, p) matrix with its ``J^T J``: a triangular factor), for a noise std ``sigma`` in
    the residuals' units: ``sigma^2 (J^T J)^+`` with one cut-off
    (:data:`SINGULAR_RTOL`) for undetermined directions; for a robust ``loss`` Huber's
    sandwich (:func:`sandwich_matrix`, of the ``residual`` (N,) at the optimum and the loss's
    ``f_scale``, both in the residuals' units) in the determined directions instead. A
    parameter along an undetermined direction has infinite variance."""
    white = jacobian / sigma
    p = white.shape[1]
    # the (N, N) left vectors are never used: all p right vectors are there unless N < p
    _, sv, vt = np.linalg.svd(white, full_matrices=white.shape[0] < p)
    s = np.zeros(p)
    s[: len(sv)] = sv
    smax = float(s.max()) if p else 0.0
    zero = s <= SINGULAR_RTOL * smax if smax > 0 else np.ones(p, dtype=bool)
    inv_s2 = np.where(zero, 0.0, 1.0 / np.where(zero, 1.0, s) ** 2)
    cov = (vt.T * inv_s2) @ vt
    if loss != "linear":
        if residual is None:
            raise StiffnessError("the covariance of a robust fit needs its residuals")
        cov = sandwich_matrix(np.asarray(residual).reshape(-1), jacobian, loss, f_scale,
                              vt[~zero])
    if zero.any():
        unseen = (np.abs(vt[zero]) > UNSEEN_COMPONENT).any(axis=0)
        cov[unseen, :] = np.inf
        cov[:, unseen] = np.inf
    return Covariance(cov, s, vt, zero)


def sandwich_matrix(residual: np.ndarray, jacobian: np.ndarray, loss: str, f_scale: float,
                    determined: np.ndarray) -> np.ndarray:
    """Huber's sandwich covariance of a robust fit's ``x`` within the ``determined``
    directions (see the module docstring).

    ``A^+ B A^+`` with the bread ``A = mean(phi'') J^T J`` and the meat
    ``B = sum(phi'^2) / (N - p) J^T J``, times Huber's small-sample factor
    ``K^2 = (1 + p var(phi'') / (N mean(phi'')^2))^2`` (Huber 1981, sec. 7.6): the spread is
    taken from the residuals through the loss, so gross outliers do not inflate it and the
    declared noise is not assumed. For the linear loss it is ``sigma_res^2 (J^T J)^+`` with
    ``sigma_res^2 = SS / (N - p)``.

    Parameters
    ----------
    residual
        (N,) residuals at the optimum (any unit).
    jacobian
        (N, p) derivative of those residuals w.r.t. ``x``, or any (m, p) matrix with its
        ``J^T J`` (a triangular factor: only ``J^T J`` is used).
    loss, f_scale
        The fit's loss (:data:`LOSSES`) and its soft threshold in the residuals' unit.
    determined
        (d, p) orthonormal directions of ``x`` the data determine.

    Returns
    -------
    (p, p) covariance of ``x`` (``x``'s units squared); infinite without a positive mean
    curvature of the loss or without more residuals than directions.
    """
    r = np.asarray(residual, dtype=float).reshape(-1)
    _, d_rho, dd_rho = loss_terms(loss, (r / f_scale) ** 2)
    psi = d_rho * r                                      # d phi / d r
    dpsi = d_rho + 2.0 * (r / f_scale) ** 2 * dd_rho     # d^2 phi / d r^2
    jac = jacobian @ determined.T                        # (N or m, d): its J^T J
    n, (d, p) = r.size, determined.shape
    mean_dpsi = float(np.mean(dpsi))
    if mean_dpsi <= 0 or n <= d:
        return np.full((p, p), np.inf)
    k = 1.0 + d / n * float(np.var(dpsi)) / mean_dpsi ** 2
    factor = k ** 2 * float(np.sum(psi ** 2)) / (n - d) / mean_dpsi ** 2
    # (J^T J)^-1 from J's singular values: pinv of J^T J (condition number squared) dropped a
    # determined direction weaker than 1e-8 of the strongest, its variance then 0
    _, sv, vt = np.linalg.svd(jac, full_matrices=False)
    return determined.T @ (factor * (vt.T / sv ** 2) @ vt) @ determined
