"""The fitting engine: one objective, one least-squares call, one covariance.

Every fit of the toolkit (``stiffness identify``: the baseline's stiffnesses from several
starts; ``stiffness diagnose``: the baseline extended by effects, and its cross-validation)
goes through :func:`fit_model` on a :class:`stiffness.calibration.effects.Model` (an
identification is a diagnosis with no effects) and gets its uncertainty from
:func:`covariance`.

Objective (A&S eq. 12-13): the residuals ``r = (predicted - measured) / s`` of every dx, dy,
dz component, ``s`` a fixed scale (the declared noise std when known), minimised by
:func:`scipy.optimize.least_squares` over the model's parameter vector ``x`` (``ln k`` of the
stiffnesses, then each effect's scaled variables). The model's analytic Jacobian is used when
it has one (a baseline without effects), else central differences. Optional pseudo-residuals
``PRIOR_WEIGHT (x - x_anchor)`` keep directions the data do not see at the start instead of
letting them drift on round-off; they are left out of every reported quantity. Where the
model cannot be evaluated (a buckling load, a singular tangent) the residuals are a large
constant, so the solver backs off.

Rotations: a campaign that also measures the target frame's rotation is fitted on rows
``[dx; w dphi]`` (:attr:`stiffness.calibration.effects.Model.rotation_weight`,
:func:`observations`): with ``w = sigma_t / sigma_r`` the translation noise std ``sigma_t`` (m)
and the rotation noise std ``sigma_r`` (rad), one scale whitens both kinds and every quantity
below (RSS, chi-square, covariance, information criteria) holds in translation-noise units.
:func:`kind_noise` estimates a kind's std from the residuals when it is neither declared nor
known from replicates; :meth:`Fit.rms_by_kind` reports the RMS of each kind.

Covariance: ``cov(x) = sigma^2 (J^T J)^+`` with ``J`` the derivative of the residuals in
metres at the optimum; singular values of the whitened ``J / sigma`` below
:data:`SINGULAR_RTOL` times the largest are undetermined directions (not inverted), and a
parameter with a component above :data:`UNSEEN_COMPONENT` along one of them has infinite
variance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from stiffness.calibration.effects import Model
from stiffness.errors import StiffnessError

#: Singular values of the whitened residual Jacobian below this fraction of the largest are
#: zero: the data do not determine that direction.
SINGULAR_RTOL = 1e-10
#: A parameter with a component above this along an undetermined direction has infinite
#: variance.
UNSEEN_COMPONENT = 1e-8
#: Weight of the anchoring pseudo-residuals ``w (x - x_anchor)``: they move a determined
#: ``ln k`` by about ``w^2 / s^2`` of its distance to the anchor (s >~ 1).
PRIOR_WEIGHT = 1e-6
#: Scaled residual returned where the model cannot be evaluated.
PENALTY = 1e6
#: |x| beyond this (k ~ 1e100 for ln k) is a failed evaluation.
_MAX_X = 230.0
#: Relative step of the central differences of models without an analytic Jacobian.
_FD_STEP = 1e-6


@dataclass
class Fit:
    """A model fitted to measurements.

    Attributes
    ----------
    model
        The model (over the fitted rows).
    x
        Parameter vector at the optimum.
    predicted
        (m, 3) predicted deflections (m).
    rss
        Residual sum of squares (m^2).
    jacobian
        (N, p) derivative of the residuals / scale w.r.t. ``x`` at the optimum.
    scale
        The residual scale (m).
    success, message, nfev
        From :func:`scipy.optimize.least_squares`.
    """

    model: Model
    x: np.ndarray
    predicted: np.ndarray
    rss: float
    jacobian: np.ndarray
    scale: float
    success: bool = True
    message: str = ""
    nfev: int = 0

    @property
    def n_residuals(self) -> int:
        """Number of residual components."""
        return self.predicted.size

    @property
    def cost(self) -> float:
        """Sum of squared scaled residuals ``rss / scale^2``."""
        return self.rss / self.scale ** 2

    def rms(self) -> float:
        """RMS residual component (m; rotations in translation-noise units)."""
        return math.sqrt(self.rss / self.n_residuals)

    def residuals(self, measured: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Translation (m, 3) residuals in m and rotation residuals (m, 3) in rad (or
        ``None``), predicted minus ``measured`` (the fitted observations)."""
        return self.model.split(self.predicted - measured)

    def rms_by_kind(self, measured: np.ndarray) -> tuple[float, float | None]:
        """RMS residual component of the translations (m) and of the rotations (rad, or
        ``None`` when the model predicts none)."""
        t, r = self.residuals(measured)
        return (float(np.sqrt(np.mean(t ** 2))),
                None if r is None else float(np.sqrt(np.mean(r ** 2))))


def observations(deflection: np.ndarray, rotation: np.ndarray | None,
                 weight: float | None) -> np.ndarray:
    """The fitted observations: the deflections (m, 3), or ``[d; w r]`` (m, 6) with measured
    rotations ``r`` (rad) and a weight ``w`` (m/rad)."""
    if rotation is None or weight is None:
        return np.asarray(deflection, dtype=float)
    return np.hstack([deflection, weight * np.asarray(rotation, dtype=float)])


def kind_noise(residual: np.ndarray, n_total: int, p: int) -> float | None:
    """Noise std of one kind from its residuals (any shape): ``sqrt(SS / (N_k - p N_k / N))``,
    the kind's share ``N_k / N`` of the ``p`` fitted parameters removed from its degrees of
    freedom; ``None`` without degrees of freedom."""
    n_k = residual.size
    dof = n_k - p * n_k / max(n_total, 1)
    if dof <= 0:
        return None
    return math.sqrt(float(np.sum(residual ** 2)) / dof)


class Objective:
    """Scaled residuals ``(predicted - measured) / scale`` of a model over ``x`` and their
    Jacobian; with ``anchor``, the pseudo-residuals ``PRIOR_WEIGHT (x - anchor)`` appended."""

    def __init__(self, model: Model, measured: np.ndarray, scale: float,
                 anchor: np.ndarray | None = None) -> None:
        self.model, self.measured, self.scale, self.anchor = model, measured, scale, anchor
        self.n_res, self.p = measured.size, model.n_params
        self._key: bytes | None = None
        self._pred: np.ndarray | None = None
        self._jac: np.ndarray | None = None

    def _evaluate(self, x: np.ndarray) -> None:
        key = x.tobytes()
        if key == self._key:
            return
        pred = jac = None
        if np.all(np.abs(x) < _MAX_X):
            try:
                with np.errstate(all="ignore"):
                    pred, jac = self.model.predict_with_jacobian(x)
                if not np.all(np.isfinite(pred)) or (jac is not None
                                                     and not np.all(np.isfinite(jac))):
                    pred = jac = None
            except (StiffnessError, np.linalg.LinAlgError, ValueError, FloatingPointError):
                pred = jac = None
        self._key, self._pred, self._jac = key, pred, jac

    @property
    def analytic(self) -> bool:
        """Whether the model gives its Jacobian."""
        return not self.model.effects

    def data(self, x: np.ndarray) -> np.ndarray:
        """Scaled data residuals (N,), or :data:`PENALTY` where the model fails."""
        self._evaluate(x)
        if self._pred is None:
            return np.full(self.n_res, PENALTY)
        return ((self._pred - self.measured) / self.scale).reshape(-1)

    def data_jacobian(self, x: np.ndarray) -> np.ndarray:
        """(N, p) derivative of the scaled data residuals w.r.t. ``x`` (analytic, else
        central differences)."""
        x = np.asarray(x, dtype=float)
        self._evaluate(x)
        if self._pred is None:
            return np.zeros((self.n_res, self.p))
        if self._jac is not None:
            return (self._jac / self.scale).reshape(self.n_res, self.p)
        out = np.empty((self.n_res, self.p))
        for i in range(self.p):
            h = _FD_STEP * max(1.0, abs(x[i]))
            e = np.zeros_like(x)
            e[i] = h
            out[:, i] = (self.data(x + e) - self.data(x - e)) / (2.0 * h)
        self._evaluate(x)
        return out

    def fun(self, x: np.ndarray) -> np.ndarray:
        """Residuals handed to the solver."""
        r = self.data(x)
        if self.anchor is None:
            return r
        return np.concatenate([r, PRIOR_WEIGHT * (x - self.anchor)])

    def jac(self, x: np.ndarray) -> np.ndarray:
        """Their Jacobian."""
        j = self.data_jacobian(x)
        if self.anchor is None:
            return j
        return np.vstack([j, PRIOR_WEIGHT * np.eye(self.p)])


def fit_model(model: Model, measured: np.ndarray, scale: float, x0: np.ndarray,
              method: str = "trf", bounded: bool = True, anchor: np.ndarray | None = None,
              tolerance: float = 1e-10, max_nfev: int | None = None,
              x_scale: float | None = None) -> Fit:
    """Least squares of ``model`` on ``measured`` (m, 3) from ``x0``.

    Parameters
    ----------
    model
        Model over the rows of ``measured``.
    measured
        (m, 3) measured deflections (m).
    scale
        Residual scale (m): the noise std if known.
    x0
        Start parameter vector (clipped into the bounds when ``bounded``).
    method
        ``trf`` or ``lm`` (Levenberg-Marquardt; unbounded only).
    bounded
        Whether to keep ``x`` within :meth:`Model.bounds`.
    anchor
        Anchor of the pseudo-residuals (see the module docstring), or ``None``.
    tolerance
        ``xtol``, ``ftol`` and ``gtol`` of the solver.
    max_nfev
        Evaluation budget (default ``40 (p + 1)``).
    x_scale
        Variable scale of the solver (default scipy's).
    """
    objective = Objective(model, measured, scale, anchor)
    x0 = np.asarray(x0, dtype=float)
    kwargs: dict = {"method": method, "xtol": tolerance, "ftol": tolerance, "gtol": tolerance,
                    "max_nfev": max_nfev or 40 * (model.n_params + 1)}
    if bounded:
        lo, hi = model.bounds()
        x0 = np.clip(x0, lo, hi)
        kwargs["bounds"] = (lo, hi)
    if objective.analytic:
        kwargs["jac"] = objective.jac
    if x_scale is not None:
        kwargs["x_scale"] = x_scale
    sol = least_squares(objective.fun, x0, **kwargs)
    r = objective.data(sol.x)
    pred = measured + r.reshape(measured.shape) * scale
    return Fit(model, sol.x, pred, float(np.sum((r * scale) ** 2)),
               objective.data_jacobian(sol.x), scale, bool(sol.success), str(sol.message),
               int(sol.nfev))


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


def covariance(fit: Fit, sigma: float) -> Covariance:
    """The covariance of ``fit.x`` for a noise std ``sigma`` (m), with one cut-off
    (:data:`SINGULAR_RTOL`) for undetermined directions."""
    white = fit.jacobian * (fit.scale / sigma)
    p = white.shape[1]
    # the (N, N) left vectors are never used: all p right vectors are there unless N < p
    _, sv, vt = np.linalg.svd(white, full_matrices=white.shape[0] < p)
    s = np.zeros(p)
    s[: len(sv)] = sv
    smax = float(s.max()) if p else 0.0
    zero = s <= SINGULAR_RTOL * smax if smax > 0 else np.ones(p, dtype=bool)
    inv_s2 = np.where(zero, 0.0, 1.0 / np.where(zero, 1.0, s) ** 2)
    cov = (vt.T * inv_s2) @ vt
    if zero.any():
        unseen = (np.abs(vt[zero]) > UNSEEN_COMPONENT).any(axis=0)
        cov[unseen, :] = np.inf
        cov[:, unseen] = np.inf
    return Covariance(cov, s, vt, zero)
