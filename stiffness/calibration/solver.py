"""The one least-squares driver of both campaign kinds.

A campaign kind supplies only its observation: a :class:`Problem`, its residuals and their
Jacobian columns over a parameter vector ``x``, the parameters' bounds, how they are laid out
for identifiability (:class:`~stiffness.calibration.identifiability.Layout`) and the value a
parameter left out is held at. A deflection campaign's is
:class:`stiffness.calibration.fitting.Objective` (over a
:class:`~stiffness.elastic.effects.hypothesis.Hypothesis`); a pose campaign's
:class:`stiffness.calibration.pose_fit.PoseProblem` (over a
:class:`~stiffness.calibration.pose_model.PoseModel`). Everything else is here, once:

* :func:`fit`: which parameters the data identify (the one judgement,
  :func:`stiffness.calibration.identifiability.identifiable`, at the start's representative
  point; near aliases judged again at the optimum and the fit redone without them), the others
  held (:meth:`Problem.start`), and :func:`solve`;
* :func:`solve`: :func:`scipy.optimize.least_squares` over the kept columns within the
  parameters' bounds: trust-region reflective, or Levenberg-Marquardt followed, when its optimum
  is past a bound, by the bounded fit from the clipped optimum; under a robust loss
  (:data:`LOSSES`); the columns it leaves at a bound reported (their intervals one-sided);
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
declared one.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from scipy.optimize import least_squares

from stiffness.calibration.identifiability import (
    Identifiability,
    Layout,
    identifiable,
    same_span,
)
from stiffness.errors import StiffnessError, UnknownNameError

#: Losses of every fit (scipy.optimize.least_squares'): ``linear`` is least squares.
LOSSES = ("linear", "soft_l1", "huber", "cauchy")
#: Singular values of the whitened residual Jacobian below this fraction of the largest are
#: zero: the data do not determine that direction.
SINGULAR_RTOL = 1e-10
#: A parameter with a component above this along an undetermined direction has infinite
#: variance.
UNSEEN_COMPONENT = 1e-8


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
    selection criteria and fit-to-noise tests compare: their sum of squares for least
    squares; for a robust ``loss`` ``sigma^2 sum rho((r / sigma)^2)`` over its Gaussian
    expectation (:func:`gaussian_loss_mean`: the same expectation, ``N sigma^2``, for Gaussian
    residuals of std ``sigma``; an outlier adds about ``2 sigma |r|`` instead of ``r^2``)."""
    if loss == "linear":
        r = np.asarray(residual, dtype=float).reshape(-1)
        return float(r @ r)
    return sigma ** 2 * loss_sum(np.asarray(residual) / sigma, loss, 1.0) / gaussian_loss_mean(
        loss)


class Problem(Protocol):
    """A campaign's observation, what :func:`fit` and :func:`solve` need of it."""

    layout: Layout

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
        """``x`` with the parameters ``ident`` leaves out at the value they are held at."""
        ...


@runtime_checkable
class Factored(Problem, Protocol):
    """A problem whose Jacobian is never held whole (a large pose campaign's): its least
    squares runs on a triangular factor of it (:func:`solve`), computed from blocks of rows."""

    def factor(self, x: np.ndarray, columns: np.ndarray) -> np.ndarray:
        """``R`` (at most (k + 1, k + 1), upper triangular) of ``[r, J[:, columns]] = Q R``
        at ``x``: ``r`` :meth:`fun`'s residuals, ``J`` :meth:`jac`'s Jacobian."""
        ...


@dataclass
class Options:
    """The solver's settings: ``method`` (``trf``, or ``lm``: Levenberg-Marquardt, least
    squares only), ``tolerance`` (its ``xtol``, ``ftol`` and ``gtol``), ``max_nfev`` (its
    evaluation budget, default ``40 (p + 1)``), ``x_scale`` (scipy's variable scale: a number,
    (p,) values, or ``None`` for scipy's default), ``loss`` (:data:`LOSSES`) and ``f_scale``
    (a robust loss's soft threshold, in the residuals' units)."""

    method: str = "trf"
    tolerance: float = 1e-10
    max_nfev: int | None = None
    x_scale: float | np.ndarray | None = None
    loss: str = "linear"
    f_scale: float = 1.0


@dataclass
class Solution:
    """A solver's optimum: ``x`` (p,), the fitted and held parameters (``identifiability``),
    scipy's ``success``, ``status`` and ``message``, the evaluations (``nfev``), the columns left
    at a bound (``at_bound``, set exactly there in ``x``), and scipy's residuals ``fun`` and
    Jacobian ``jac`` over the kept columns at the optimum (``jac`` reweighted by a robust
    loss; for a :class:`Factored` problem's least squares the (k + 1, k) factor
    ``[r^T J / |r|; R_2]`` instead, :func:`solve`: the same ``J^T J`` and ``J^T r``)."""

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
        held: dict[int, str] | None = None, near_at_start: bool = False) -> Solution:
    """The fit of ``problem`` from ``x0``: the identifiable parameters (at the representative
    point of ``x0``; near aliases at ``resolution``, noise std per typical size, judged at the
    optimum, and at the start too with ``near_at_start``), those of ``held`` (column: why)
    held as undetermined, the others held at :meth:`Problem.start`, and :func:`solve`. When
    the near aliases at the optimum are not those of the start, the fit is redone from the
    optimum with them held (unless the optimum's reduction keeps the same span, other members
    of exact aliases: the same model). A fit that ends where the model diverges (a bounded
    refit from a bound) is returned as it ended: its residual is the diverged constant, and
    the caller never chooses it."""
    ident = identifiable(problem.layout, x0, lambda p: problem.columns(p, False),
                         resolution if near_at_start else 0.0).holding(held or {})
    start = problem.start(np.asarray(x0, dtype=float), ident)
    sol = solve(problem, start, ident, options)
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
    x = np.where(np.isin(np.arange(sol.x.size), near.kept), sol.x, start)
    again = solve(problem, problem.start(x, near), near, options)
    again.nfev += sol.nfev
    return again


def solve(problem: Problem, x0: np.ndarray, ident: Identifiability,
          options: Options) -> Solution:
    """:func:`scipy.optimize.least_squares` of ``problem`` over the kept columns of ``ident``,
    the others held at ``x0`` (module docstring).

    A :class:`Factored` problem's least squares (linear loss) is handed to scipy on k + 1
    rows: the residuals ``[|r|, 0, ..., 0]`` and the Jacobian ``[r^T J / |r|; R_2]``, the
    factor ``R`` of ``[r, J] = Q R`` (:meth:`Factored.factor`) without its first column.
    Its ``J^T J`` and ``J^T r`` are the full problem's, and so is ``|r|``: every quantity
    Levenberg-Marquardt and trust-region reflective use (the steps, which depend on the
    Jacobian only through ``J^T J`` and ``J^T r``; the predicted and actual reductions; the
    column-norm scaling; the gradient test) is the full problem's, while only a block of the
    Jacobian's rows is ever held (``sol.fun`` is then the full residual at the optimum, and
    ``sol.jac`` that factor).
    """
    free = np.asarray(ident.kept, dtype=int)  # the solver's variables, in the kept order
    if not free.size:
        fun = problem.fun(x0)
        return Solution(x0, ident, True, 1, "no parameter is seen by the data", 1, [], fun,
                        np.zeros((fun.size, 0)))
    kwargs: dict = {"xtol": options.tolerance, "ftol": options.tolerance,
                    "gtol": options.tolerance,
                    "max_nfev": options.max_nfev or 40 * (x0.size + 1)}
    if options.x_scale is not None:
        kwargs["x_scale"] = (options.x_scale if np.ndim(options.x_scale) == 0
                             else np.asarray(options.x_scale)[free])
    if options.loss != "linear":
        kwargs.update(loss=options.loss, f_scale=float(options.f_scale))
    bounds = problem.bounds()
    lo, hi = ((np.full(x0.size, -np.inf), np.full(x0.size, np.inf)) if bounds is None
              else bounds)
    lo, hi = lo[free], hi[free]

    def full(z: np.ndarray) -> np.ndarray:
        x = x0.copy()
        x[free] = z
        return x

    factored = options.loss == "linear" and isinstance(problem, Factored)

    def residual(z: np.ndarray) -> np.ndarray:
        if not factored:
            return problem.fun(full(z))
        out = np.zeros(free.size + 1)
        out[0] = np.linalg.norm(problem.fun(full(z)))
        return out

    def jacobian(z: np.ndarray) -> np.ndarray:
        if not isinstance(problem, Factored) or not factored:
            return problem.jac(full(z))[:, free]
        tri = problem.factor(full(z), free)
        tri[0] *= -1.0 if tri[0, 0] < 0 else 1.0  # R[0, 0] = |r|: r = Q[:, 0] |r|
        out = np.zeros((free.size + 1, free.size))
        out[:tri.shape[0]] = tri[:, 1:]
        return out

    def run(z0: np.ndarray, method: str, bounded: bool):
        extra = {"bounds": (lo, hi)} if bounded and bounds is not None else {}
        return least_squares(residual, z0, jac=jacobian, method=method, **kwargs, **extra)

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
                    problem.fun(full(sol.x)) if factored else sol.fun, sol.jac)


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
    def condition_number(self) -> float:
        """Largest over smallest singular value (inf with an undetermined direction)."""
        if self.undetermined.any() or not self.singular_values.size:
            return math.inf
        return float(self.singular_values.max() / self.singular_values.min())


def covariance_matrix(jacobian: np.ndarray, sigma: float, loss: str = "linear",
                      residual: np.ndarray | None = None, f_scale: float = 1.0
                      ) -> Covariance:
    """The covariance of parameters whose residuals have the Jacobian ``jacobian`` (N, p), for
    a noise std ``sigma`` in the residuals' units: ``sigma^2 (J^T J)^+`` with one cut-off
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
        (N, p) derivative of those residuals w.r.t. ``x``.
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
    jac = jacobian @ determined.T                        # (N, d)
    n, d = jac.shape
    p = jacobian.shape[1]
    mean_dpsi = float(np.mean(dpsi))
    if mean_dpsi <= 0 or n <= d:
        return np.full((p, p), np.inf)
    k = 1.0 + d / n * float(np.var(dpsi)) / mean_dpsi ** 2
    factor = k ** 2 * float(np.sum(psi ** 2)) / (n - d) / mean_dpsi ** 2
    # (J^T J)^-1 from J's singular values: pinv of J^T J (condition number squared) dropped a
    # determined direction weaker than 1e-8 of the strongest, its variance then 0
    _, sv, vt = np.linalg.svd(jac, full_matrices=False)
    return determined.T @ (factor * (vt.T / sv ** 2) @ vt) @ determined
