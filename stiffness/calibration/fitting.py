"""The fitting engine: one objective, one least-squares call, one covariance.

Every fit of the toolkit (``stiffness identify``: the baseline's stiffnesses from several
starts; ``stiffness diagnose``: the baseline extended by effects, and its cross-validation)
goes through :func:`fit_model` on a :class:`stiffness.elastic.effects.hypothesis.Hypothesis` (an
identification is a diagnosis with no effects) and gets its uncertainty from
:func:`covariance`.

Objective (A&S eq. 12-13): the residuals ``r = (predicted - measured) / s`` of every dx, dy,
dz component, ``s`` a fixed scale (the declared noise std when known), minimised by
:func:`scipy.optimize.least_squares` over the model's parameter vector ``x`` (``ln k`` of the
stiffnesses, then each effect's scaled variables). The model's analytic Jacobian is used for
``ln k`` and the effects acting through the joint law, finite differences for the other
effects' variables. Only the parameters the data identify are fitted (:func:`identifiable`:
the one reduction of both campaign kinds, :mod:`stiffness.calibration.identifiability`, over
the baseline's compliances and then each effect's variables in the order added, at the
start's representative point, every absent effect at its typical size; near aliases judged
again at the optimum); the others
(no effect on the data: the stiffness of a joint whose axis passes through every load's line;
merged: a link bend about an axis parallel to a joint's, which that joint's compliance
absorbs; or undetermined: held by the diagnosis, :attr:`Hypothesis.held`) are held at their
start and reported as such (:attr:`Fit.identifiability`). Optional pseudo-residuals
``PRIOR_WEIGHT (x - x_anchor)`` keep directions the data do not see at the start instead of
letting them drift on round-off; they are left out of every reported quantity. Where the
model cannot be evaluated (a buckling load, a singular tangent) the residuals are a large
constant, so the solver backs off.

Rotations: a campaign that also measures the target frame's rotation is fitted on rows
``[dx; w dphi]`` (:attr:`stiffness.elastic.effects.hypothesis.Hypothesis.rotation_weight`,
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

Robust losses (:data:`LOSSES`): ``loss`` other than ``linear`` minimises
``sum f^2 rho((r / f)^2)`` of the scaled residuals ``r`` with scipy's ``rho`` (``soft_l1``,
``huber``, ``cauchy``) and ``f`` the noise std in scaled units, so a residual beyond about
``f`` weighs less than its square. Such a fit's covariance is Huber's sandwich (M-estimator)
covariance ``K^2 [sum phi'^2 / (N - p)] / mean(phi'')^2 (J^T J)^+`` with
``phi(r) = f^2 rho((r / f)^2) / 2`` (:func:`sandwich_matrix`): it takes the spread from the
residuals themselves through the loss, not from an assumed noise, so its intervals stay
honest when the data hold outliers or the noise is not the declared one.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, fields, replace

import numpy as np
from scipy.optimize import least_squares

from stiffness.calibration.identifiability import Identifiability, Layout
from stiffness.calibration.identifiability import identifiable as judge
from stiffness.cores import forked_map
from stiffness.elastic.effects.hypothesis import Hypothesis
from stiffness.errors import StiffnessError, UnknownNameError
from stiffness.robot.robot import Robot

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
#: Relative step of the central differences of the parameters without analytic derivatives.
_FD_STEP = 1e-6
#: Relative step of the solver's forward differences there (``sqrt(eps)``, as scipy's).
_FORWARD_STEP = float(np.sqrt(np.finfo(float).eps))
#: Stiffness (SI: N.m/rad or N/m) a baseline joint whose compliance moves no measurement is
#: held at when its robot declares none (``k_theta_SI``): identify's paper start, 1e8 N.mm/rad.
NOMINAL_STIFFNESS = 1e5
#: Losses of :func:`fit_model` (scipy.optimize.least_squares'): ``linear`` is least squares.
LOSSES = ("linear", "soft_l1", "huber", "cauchy")


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
    """``sum f^2 rho((r / f)^2)`` of scaled residuals ``r`` (the sum of squares for
    ``linear``; twice scipy's ``cost``)."""
    r = np.asarray(residuals, dtype=float).reshape(-1)
    if loss == "linear":
        return float(np.sum(r ** 2))
    return float(f_scale ** 2 * np.sum(loss_terms(loss, (r / f_scale) ** 2)[0]))


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
    loss, f_scale
        The loss (:data:`LOSSES`) and its soft threshold in units of ``scale``.
    loss_value
        ``sum f^2 rho((r / f)^2)`` of the scaled residuals at the optimum (:func:`loss_sum`).
    identifiability
        The parameters fitted and those held at their start (:func:`identifiable`; every one
        fitted when ``None``).
    at_bound
        Columns of ``x`` the bounded solver left at a bound (:meth:`Hypothesis.bounds`: a
        compliance at 0, a stiffness at the 1e14 rigid bound, a mass at 0).
    """

    model: Hypothesis
    x: np.ndarray
    predicted: np.ndarray
    rss: float
    jacobian: np.ndarray
    scale: float
    success: bool = True
    message: str = ""
    nfev: int = 0
    loss: str = "linear"
    f_scale: float = 1.0
    loss_value: float | None = None
    identifiability: Identifiability | None = None
    at_bound: list[int] = field(default_factory=list)

    @property
    def kept(self) -> list[int]:
        """Columns of ``x`` the fit moved (:attr:`identifiability`)."""
        if self.identifiability is None:
            return list(range(self.x.size))
        return list(self.identifiability.kept)

    @property
    def penalty_params(self) -> int:
        """Parameters the information criterion counts: the model's
        (:attr:`Hypothesis.penalty_params`) less those held as not identifiable."""
        held = 0 if self.identifiability is None else len(self.identifiability.dropped)
        return self.model.penalty_params - held

    @property
    def n_residuals(self) -> int:
        """Number of residual components."""
        return self.predicted.size

    @property
    def cost(self) -> float:
        """The minimised objective: ``rss / scale^2`` (linear loss), else
        :attr:`loss_value`."""
        if self.loss == "linear" or self.loss_value is None:
            return self.rss / self.scale ** 2
        return self.loss_value

    @property
    def loss_rss(self) -> float:
        """The objective as a sum of squares (m^2), what selection criteria and fit-to-noise
        tests compare: :attr:`rss` for the linear loss; for a robust one ``scale^2``
        :attr:`loss_value` over :func:`gaussian_loss_mean` (same expectation, ``N sigma^2``,
        for Gaussian residuals at the loss's scale ``sigma``; an outlier adds about
        ``2 f |r|`` instead of ``r^2``)."""
        if self.loss == "linear" or self.loss_value is None:
            return self.rss
        return self.loss_value * self.scale ** 2 / gaussian_loss_mean(self.loss)

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


def kind_noise(residual: np.ndarray | None, n_total: int, p: int) -> float | None:
    """Noise std of one kind from its residuals (any shape): ``sqrt(SS / (N_k - p N_k / N))``,
    the kind's share ``N_k / N`` of the ``p`` fitted parameters removed from its degrees of
    freedom; ``None`` without degrees of freedom (or without residuals of the kind)."""
    if residual is None:
        return None
    n_k = residual.size
    dof = n_k - p * n_k / max(n_total, 1)
    if dof <= 0:
        return None
    return math.sqrt(float(np.sum(residual ** 2)) / dof)


class Objective:
    """Scaled residuals ``(predicted - measured) / scale`` of a model over ``x`` and their
    Jacobian; with ``anchor``, the pseudo-residuals ``PRIOR_WEIGHT (x - anchor)`` appended.

    The Jacobian is the model's analytic one (:meth:`Hypothesis.predict_with_jacobian`) in its
    :attr:`Hypothesis.analytic_columns`; the other columns are finite differences (central for the
    reported :attr:`Fit.jacobian`, forward steps of :data:`_FORWARD_STEP` for the solver).
    """

    def __init__(self, model: Hypothesis, measured: np.ndarray, scale: float,
                 anchor: np.ndarray | None = None) -> None:
        self.model, self.measured, self.scale, self.anchor = model, measured, scale, anchor
        self.n_res, self.p = measured.size, model.n_params
        self.numeric = np.flatnonzero(~model.analytic_columns)
        self._key: bytes | None = None
        self._pred: np.ndarray | None = None
        self._jac: np.ndarray | None = None

    def _predict(self, x: np.ndarray, jacobian: bool
                 ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The model's prediction (and Jacobian) at ``x``, ``None`` where it fails."""
        if not np.all(np.abs(x) < _MAX_X):
            return None, None
        try:
            with np.errstate(all="ignore"):
                if jacobian:
                    pred, jac = self.model.predict_with_jacobian(x)
                else:
                    pred, jac = self.model.predict(x), None
        except (StiffnessError, np.linalg.LinAlgError, ValueError, FloatingPointError):
            return None, None
        if not np.all(np.isfinite(pred)) or (jac is not None and not np.all(np.isfinite(jac))):
            return None, None
        return pred, jac

    def _evaluate(self, x: np.ndarray) -> None:
        key = x.tobytes()
        if key != self._key:
            self._pred, self._jac = self._predict(x, jacobian=True)
            self._key = key

    def _scaled(self, pred: np.ndarray | None) -> np.ndarray:
        if pred is None:
            return np.full(self.n_res, PENALTY)
        return ((pred - self.measured) / self.scale).reshape(-1)

    def data(self, x: np.ndarray) -> np.ndarray:
        """Scaled data residuals (N,), or :data:`PENALTY` where the model fails."""
        self._evaluate(x)
        return self._scaled(self._pred)

    def data_jacobian(self, x: np.ndarray, central: bool = True) -> np.ndarray:
        """(N, p) derivative of the scaled data residuals w.r.t. ``x``: analytic columns and
        finite differences (central, else forward) in the others."""
        x = np.asarray(x, dtype=float)
        self._evaluate(x)
        if self._pred is None or self._jac is None:  # the model failed: no prediction
            return np.zeros((self.n_res, self.p))
        out = (self._jac / self.scale).reshape(self.n_res, self.p)
        r0 = self._scaled(self._pred)
        for i in self.numeric:
            h = (_FD_STEP if central else _FORWARD_STEP) * max(1.0, abs(x[i]))
            e = np.zeros_like(x)
            e[i] = h
            plus = self._scaled(self._predict(x + e, jacobian=False)[0])
            if central:
                minus = self._scaled(self._predict(x - e, jacobian=False)[0])
                out[:, i] = (plus - minus) / (2.0 * h)
            else:
                out[:, i] = (plus - r0) / h
        return out

    def fun(self, x: np.ndarray) -> np.ndarray:
        """Residuals handed to the solver."""
        r = self.data(x)
        if self.anchor is None:
            return r
        return np.concatenate([r, PRIOR_WEIGHT * (x - self.anchor)])

    def jac(self, x: np.ndarray) -> np.ndarray:
        """Their Jacobian (forward differences in the numeric columns)."""
        j = self.data_jacobian(x, central=False)
        if self.anchor is None:
            return j
        return np.vstack([j, PRIOR_WEIGHT * np.eye(self.p)])


def fit_model(model: Hypothesis, measured: np.ndarray, scale: float, x0: np.ndarray,
              method: str = "trf", bounded: bool = True, anchor: np.ndarray | None = None,
              tolerance: float = 1e-10, max_nfev: int | None = None,
              x_scale: float | None = None, loss: str = "linear", f_scale: float = 1.0,
              resolution: float = 0.0) -> Fit:
    """Least squares of ``model`` on ``measured`` (m, 3) from ``x0``.

    Parameters
    ----------
    model
        Hypothesis over the rows of ``measured``.
    measured
        (m, 3) measured deflections (m).
    scale
        Residual scale (m): the noise std if known.
    x0
        Start parameter vector (clipped into the bounds when ``bounded``).
    method
        ``trf`` or ``lm`` (Levenberg-Marquardt; unbounded only).
    bounded
        Whether to keep ``x`` within :meth:`Hypothesis.bounds`.
    anchor
        Anchor of the pseudo-residuals (see the module docstring), or ``None``.
    tolerance
        ``xtol``, ``ftol`` and ``gtol`` of the solver.
    max_nfev
        Evaluation budget (default ``40 (p + 1)``).
    x_scale
        Variable scale of the solver (default scipy's).
    loss
        One of :data:`LOSSES` (robust ones need ``method="trf"``).
    f_scale
        Soft threshold of a robust loss, in units of ``scale`` (the noise std / ``scale``).
    resolution
        Near aliases an effect's columns must be told from (:func:`identifiable`; ``scale``
        the noise std), 0 for none.

    The parameters of ``model.held`` (:attr:`Hypothesis.held`) stay at ``x0``, reported as
    undetermined with why (:meth:`Identifiability.holding`).
    """
    check_loss(loss, method)
    objective = Objective(model, measured, scale, anchor)
    x0 = np.asarray(x0, dtype=float)
    kwargs: dict = {"method": method, "xtol": tolerance, "ftol": tolerance, "gtol": tolerance,
                    "max_nfev": max_nfev or 40 * (model.n_params + 1)}
    if bounded:
        lo, hi = model.bounds()
        x0 = np.clip(x0, lo, hi)
    if x_scale is not None:
        kwargs["x_scale"] = x_scale
    if loss != "linear":
        kwargs.update(loss=loss, f_scale=float(f_scale))
    # parameters the data do not identify stay at the start: their huge Gauss-Newton step
    # would otherwise take the trust region and the solver would crawl
    labels = parameter_labels(model)
    hold = {i: model.held[label] for i, label in enumerate(labels) if label in model.held}
    ident = identifiable(objective, x0).holding(hold)
    # a joint whose compliance moves no measurement has no value but the one it is held at:
    # the same nominal for every fit (identify, diagnose), not its start
    unseen = [d.index for d in ident.dropped
              if d.index < len(model.compliant) and d.reason == "no effect"]
    if unseen:
        x0 = x0.copy()
        x0[unseen] = nominal_log_stiffness(model)[unseen]
    bounds = (lo, hi) if bounded else None
    x, success, message, nfev, at_bound = _solve(objective, x0, ident.kept, bounds, kwargs)
    jac = objective.data_jacobian(x)
    if resolution > 0:
        # near aliases where the data put the effects (how well the data tell a parameter
        # from others may depend on the fitted sizes): those merged there are held at their
        # start and the others refitted
        near = identifiable(objective, x, resolution, jac).holding(hold)
        if set(near.kept) != set(ident.kept):
            ident = near
            x = np.where(np.isin(np.arange(x.size), ident.kept), x, x0)
            x, success, message, more, at_bound = _solve(objective, x, ident.kept, bounds,
                                                         kwargs)
            nfev += more
            jac = objective.data_jacobian(x)
    r = objective.data(x)
    pred = measured + r.reshape(measured.shape) * scale
    return Fit(model, x, pred, float(np.sum((r * scale) ** 2)), jac, scale, success, message,
               int(nfev), loss, float(f_scale), loss_sum(r, loss, f_scale), ident, at_bound)


def _solve(objective: Objective, x0: np.ndarray, kept: list[int],
           bounds: tuple[np.ndarray, np.ndarray] | None, kwargs: dict
           ) -> tuple[np.ndarray, bool, str, int, list[int]]:
    """:func:`fit_model`'s solver call over the ``kept`` columns of ``x`` (the others held at
    ``x0``): the optimum, success, message, evaluations and the columns left at a bound."""
    free = np.zeros(x0.size, dtype=bool)
    free[kept] = True
    if not free.any():
        return x0, True, "no parameter is seen by the data", 1, []
    if bounds is not None:
        kwargs = {**kwargs, "bounds": (bounds[0][free], bounds[1][free])}

    def full(z: np.ndarray) -> np.ndarray:
        x = x0.copy()
        x[free] = z
        return x

    sol = least_squares(lambda z: objective.fun(full(z)), x0[free],
                        jac=lambda z: objective.jac(full(z))[:, free], **kwargs)
    at_bound = [int(i) for i in np.flatnonzero(free)[np.flatnonzero(sol.active_mask)]]
    return full(sol.x), bool(sol.success), str(sol.message), int(sol.nfev), at_bound


def nominal_log_stiffness(model: Hypothesis) -> np.ndarray:
    """``ln k`` of each baseline joint's nominal stiffness (:func:`nominal_stiffness`)."""
    return np.log(nominal_stiffness(model.geometry.robot, model.compliant))


def nominal_stiffness(robot: Robot, joints: Sequence[str]) -> np.ndarray:
    """Each joint's nominal stiffness (N.m/rad, N/m): the robot's declared ``k_theta_SI``
    (one per compliant joint its declaration names, positive), else
    :data:`NOMINAL_STIFFNESS`."""
    springs = list(robot.defaults.get("compliant_joints", robot.compliant_joints))
    declared = robot.defaults.get("k_theta_SI")
    values = dict(zip(springs, declared, strict=True)) if (
        declared is not None and len(declared) == len(springs)) else {}
    return np.array([float(values[j]) if float(values.get(j, 0.0)) > 0 else NOMINAL_STIFFNESS
                     for j in joints])


def parameter_labels(model: Hypothesis) -> list[str]:
    """Each column of ``model``'s parameter vector named: ``compliance(joint)`` for the
    baseline's ``ln k``, ``label.parameter`` for an effect's variable."""
    return [f"compliance({j})" for j in model.compliant] + [
        f"{e.label}.{name}" for e in model.effects for name in e.parameter_names]


def layout(model: Hypothesis) -> Layout:
    """How :func:`identifiable` judges ``model``'s parameters
    (:class:`stiffness.calibration.identifiability.Layout`): the baseline's compliances first
    (every one with an effect on the data kept: their undetermined combinations are the
    covariance's, :func:`covariance`), then each effect's own variables in the order added
    (near aliases of the columns before them merged), each followed by the settings
    :meth:`Effect.settings_freed` made parameters (a compensator's base: judged by its interval
    in diagnose, not as a near alias). Typical sizes: a compliance ``1 / k_ref``, an effect's
    variable one unit (:meth:`Effect.scale`); an absent effect is present at one unit clipped
    into its bounds."""
    n0 = len(model.compliant)
    refs = model.refs
    groups: list[list[int]] = [list(range(n0))]
    effects: list[tuple[list[int], list[int]]] = []
    typical = np.zeros(model.n_params)
    for i, e in enumerate(model.effects):
        start, stop = model.offsets[i + 1], model.offsets[i + 2]
        own = min(start + len(e.param_names), stop)
        groups += [list(range(start, own)), list(range(own, stop))]
        effects.append((list(range(start, own)), list(range(start, stop))))
        lo, hi = e.bounds()
        typical[start:stop] = np.clip(1.0, lo, hi)
    scales = np.concatenate([np.full(n0, 1.0 / refs.k_ref)]
                            + [e.scale(refs) for e in model.effects])
    return Layout(groups, [False] + [True, False] * len(model.effects), scales, typical,
                  effects, keep_first=True)


def identifiable(objective: Objective, x: np.ndarray, resolution: float = 0.0,
                 jacobian: np.ndarray | None = None) -> Identifiability:
    """The parameters ``objective``'s data identify near ``x``: the one judgement of both
    campaign kinds (:func:`stiffness.calibration.identifiability.identifiable`) by
    :func:`layout`, at the representative point of ``x`` (an absent effect present at its
    typical size, so that a parameter acting only through its size, a compensator's base, is
    judged as the data see it once the effect is there). The columns are in the fitted
    variables' physical units times their typical size: a compliance ``1 / k``
    (``-k d r / d ln k`` times ``1 / k_ref``, so a stiff joint is not mistaken for one without
    effect), an effect's SI value; merge coefficients are in those units. ``resolution``:
    noise std per typical size (the residuals scaled by the noise std), 0 for no near-alias
    merges. ``jacobian``: the data Jacobian at ``x`` when known."""
    model = objective.model
    n0 = len(model.compliant)

    def columns(point: np.ndarray) -> np.ndarray | None:
        if objective.data(point)[0] == PENALTY:
            return None
        given = jacobian is not None and np.array_equal(point, x)
        a = np.array(jacobian if given else objective.data_jacobian(point, central=False))
        a[:, :n0] *= -np.exp(point[:n0]) / model.refs.k_ref
        return a

    return judge(layout(model), np.asarray(x, dtype=float), columns, resolution)


@dataclass
class FitJob:
    """One fit of :func:`fit_models`: the arguments of :func:`fit_model`."""

    model: Hypothesis
    measured: np.ndarray
    scale: float
    x0: np.ndarray
    options: dict = field(default_factory=dict)

    def run(self) -> Fit:
        """The fit, in this process."""
        return fit_model(self.model, self.measured, self.scale, self.x0, **self.options)


#: Serial work (s) above which :func:`fit_models` forks workers (starting and joining two
#: costs about 0.03 s).
FORK_WORTH_S = 0.15


def _sent_back(job: FitJob) -> dict:
    """``job``'s fit without its model: the other fields of the :class:`Fit` (a forked worker
    sends back only the arrays)."""
    fit = job.run()
    return {f.name: getattr(fit, f.name) for f in fields(fit) if f.name != "model"}


def fit_models(jobs: list[FitJob], workers: int | None = None) -> list[Fit]:
    """Independent fits, in forked worker processes where that pays.

    The first job runs here; when the others would take longer than :data:`FORK_WORTH_S` at
    its pace, they run in forked workers, which inherit the jobs (nothing is pickled but each
    fit's arrays coming back). A fit costs the same there as here, and the results are those
    of :func:`fit_model` in this process, in the order of ``jobs``.

    Parameters
    ----------
    jobs
        The fits.
    workers
        Worker processes (default: the usable cores; :func:`stiffness.cores.forked_map`
        works in this process where forking is unsafe).
    """
    if not jobs:
        return []
    start = time.perf_counter()
    first = jobs[0].run()
    rest = jobs[1:]
    if (time.perf_counter() - start) * len(rest) < FORK_WORTH_S:
        return [first] + [job.run() for job in rest]
    sent = forked_map([functools.partial(_sent_back, job) for job in rest], workers)
    return [first] + [Fit(model=job.model, **values)
                      for values, job in zip(sent, rest, strict=True)]


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


def covariance(fit: Fit, sigma: float, measured: np.ndarray | None = None) -> Covariance:
    """The covariance of ``fit.x`` for a noise std ``sigma`` (m), with one cut-off
    (:data:`SINGULAR_RTOL`) for undetermined directions; for a robust loss, given the fitted
    observations ``measured``, the sandwich (:func:`sandwich_matrix`) in the determined
    directions instead of ``sigma^2 (J^T J)^+``. Over the fitted parameters only
    (:attr:`Fit.kept`): one held as not identifiable has infinite variance, a zero singular
    value and its own axis as direction."""
    kept = fit.kept
    full_p = fit.jacobian.shape[1]
    if len(kept) < full_p:
        sub = covariance(replace(fit, jacobian=fit.jacobian[:, kept],
                                             x=fit.x[kept], identifiability=None),
                         sigma, measured)
        held = np.setdiff1d(np.arange(full_p), kept)
        matrix = np.full((full_p, full_p), np.inf)
        matrix[np.ix_(kept, kept)] = sub.matrix
        directions = np.zeros((full_p, full_p))
        directions[: len(kept), kept] = sub.directions
        directions[len(kept) + np.arange(held.size), held] = 1.0
        return Covariance(matrix, np.concatenate([sub.singular_values, np.zeros(held.size)]),
                          directions, np.concatenate([sub.undetermined,
                                                      np.ones(held.size, dtype=bool)]))
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
    if fit.loss != "linear":
        if measured is None:
            raise StiffnessError("the covariance of a robust fit needs its observations")
        cov = sandwich_matrix(((fit.predicted - measured) / fit.scale).reshape(-1),
                              fit.jacobian, fit.loss, fit.f_scale, vt[~zero])
    if zero.any():
        unseen = (np.abs(vt[zero]) > UNSEEN_COMPONENT).any(axis=0)
        cov[unseen, :] = np.inf
        cov[:, unseen] = np.inf
    return Covariance(cov, s, vt, zero)


def sandwich_matrix(residual: np.ndarray, jacobian: np.ndarray, loss: str, f_scale: float,
                    determined: np.ndarray) -> np.ndarray:
    """Huber's sandwich covariance of a robust fit's ``x`` within the ``determined``
    directions (see the module docstring); any fit's: the deflection engine's
    (:func:`covariance`) and the pose fit's (:mod:`stiffness.calibration.pose_fit`).

    ``A^+ B A^+`` with the bread ``A = mean(phi'') J^T J`` and the meat
    ``B = sum(phi'^2) / (N - p) J^T J``, times Huber's small-sample factor
    ``K^2 = (1 + p var(phi'') / (N mean(phi'')^2))^2`` (Huber 1981, sec. 7.6): the spread is
    taken from the residuals through the loss, so gross outliers do not inflate it and the
    declared noise is not assumed. For the linear loss it is ``sigma_res^2 (J^T J)^+`` with
    ``sigma_res^2 = SS / (N - p)``.

    Parameters
    ----------
    residual
        (N,) residuals at the optimum divided by the fit's scale (dimensionless).
    jacobian
        (N, p) derivative of those scaled residuals w.r.t. ``x``.
    loss, f_scale
        The fit's loss (:data:`LOSSES`) and its soft threshold in units of the scale.
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
    return determined.T @ (factor * np.linalg.pinv(jac.T @ jac)) @ determined
