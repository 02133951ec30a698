"""Deflection campaigns' fits: the observation, the fit, its result and its covariance.

Every fit of a deflection campaign (``stiffness identify``: the baseline's stiffnesses from
several starts; ``stiffness diagnose``: the baseline extended by effects, and its
cross-validation) goes through :func:`fit_model` on a
:class:`stiffness.elastic.effects.hypothesis.Hypothesis` (an identification is a diagnosis with
no effects) and gets its uncertainty from :func:`covariance`. The campaign kind supplies only
its observation, :class:`Objective`; the least-squares driver, identifiability, robust losses
and the covariance are the one engine of both campaign kinds
(:mod:`stiffness.calibration.solver`).

Objective (A&S eq. 12-13): the residuals ``r = (predicted - measured) / s`` of every dx, dy,
dz component, ``s`` a fixed scale (the declared noise std when known), minimised over the
model's parameter vector ``x`` (``ln k`` of the stiffnesses, then each effect's scaled
variables). The model's analytic Jacobian is used for ``ln k`` and the effects acting through
the joint law, finite differences for the other effects' variables. Only the parameters the
data identify are fitted (:func:`layout`: the baseline's compliances and then each effect's
variables in the order added, judged at the start's representative point, every absent effect
at its typical size; near aliases judged again at the optimum); the others (no effect on the
data: the stiffness of a joint whose axis passes through every load's line; merged: a link bend
about an axis parallel to a joint's, which that joint's compliance absorbs; or undetermined:
held by the diagnosis, :attr:`Hypothesis.held`) are held at their nominal values, whatever the
fit starts from (:func:`nominal_parameters`), and reported as such
(:attr:`Fit.identifiability`). Optional pseudo-residuals ``PRIOR_WEIGHT (x - x_anchor)`` keep
directions the data do not see at the start instead of letting them drift on round-off; they
are left out of every reported quantity. Where the model cannot be evaluated (a buckling load,
a singular tangent) the residuals are a large constant, so the solver backs off.

Rotations: a campaign that also measures the target frame's rotation is fitted on rows
``[dx; w dphi]`` (:attr:`stiffness.elastic.effects.hypothesis.Hypothesis.rotation_weight`,
:func:`observations`): with ``w = sigma_t / sigma_r`` the translation noise std ``sigma_t`` (m)
and the rotation noise std ``sigma_r`` (rad), one scale whitens both kinds and every quantity
below (RSS, chi-square, covariance, information criteria) holds in translation-noise units.
:func:`kind_noise` estimates a kind's std from the residuals when it is neither declared nor
known from replicates; :meth:`Fit.rms_by_kind` reports the RMS of each kind.

Covariance: ``cov(x) = sigma^2 (J^T J)^+`` with ``J`` the derivative of the residuals in
metres at the optimum, or, for a robust loss (``loss`` of
:data:`~stiffness.calibration.solver.LOSSES` other than ``linear``, its soft threshold
``f_scale`` in units of ``s``), Huber's sandwich
(:func:`stiffness.calibration.solver.covariance_matrix`).
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, fields, replace

import numpy as np

from stiffness.calibration import solver
from stiffness.calibration.identifiability import Identifiability, Layout
from stiffness.calibration.solver import (
    Covariance,
    check_loss,
    covariance_matrix,
    gaussian_loss_mean,
    loss_sum,
)
from stiffness.cores import forked_map
from stiffness.elastic.effects.hypothesis import Hypothesis
from stiffness.errors import StiffnessError
from stiffness.robot.robot import Robot

#: A baseline compliance within this many typical sizes (``1 / k_ref``) of zero is at its
#: bound, rigid to the data: the fit moves ``ln k``, whose column vanishes with the compliance,
#: so the solver stops short of the 1e14 bound wherever the data no longer see the joint.
RIGID_COMPLIANCE = 1e-6
#: Weight of the anchoring pseudo-residuals ``w (x - x_anchor)``: they move a determined
#: ``ln k`` by about ``w^2 / s^2`` of its distance to the anchor (s >~ 1).
PRIOR_WEIGHT = 1e-6
#: Scaled residual returned where the model cannot be evaluated.
PENALTY = 1e6
#: |x| beyond this (k ~ 1e100 for ln k) is a failed evaluation.
_MAX_X = 230.0
#: Points at which an :class:`Objective` keeps the model's prediction and Jacobian, the least
#: recently used dropped first: the solver's last points, a fit's start and representative point
#: (:func:`stiffness.calibration.solver.fit` judges identifiability there), its optimum.
_RECENT = 4
#: Relative step of the central differences of the parameters without analytic derivatives.
_FD_STEP = 1e-6
#: Relative step of the solver's forward differences there (``sqrt(eps)``, as scipy's).
_FORWARD_STEP = float(np.sqrt(np.finfo(float).eps))
#: Stiffness (SI: N.m/rad or N/m) a baseline joint whose compliance moves no measurement is
#: held at when its robot declares none (``k_theta_SI``): identify's paper start, 1e8 N.mm/rad.
NOMINAL_STIFFNESS = 1e5


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
        The loss (:data:`~stiffness.calibration.solver.LOSSES`) and its soft threshold in
        units of ``scale``.
    loss_value
        ``sum f^2 rho((r / f)^2)`` of the scaled residuals at the optimum (:func:`loss_sum`).
    identifiability
        The parameters fitted and those held at their nominal values (:func:`layout`,
        :func:`nominal_parameters`; every one fitted when ``None``).
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
        """The objective as a sum of squares (m^2), what selection criteria compare (the
        fit-to-noise test reads the rows a robust loss keeps instead,
        :func:`~stiffness.calibration.selection.noise_terms`): :attr:`rss` for the linear
        loss; for a robust one ``scale^2``
        :attr:`loss_value` over :func:`gaussian_loss_mean` (same expectation, ``N sigma^2``,
        for Gaussian residuals at the loss's scale ``sigma``; an outlier adds about
        ``2 f |r|`` instead of ``r^2``)."""
        if self.loss == "linear" or self.loss_value is None:
            return self.rss
        return self.loss_value * self.scale ** 2 / gaussian_loss_mean(self.loss)

    def rms(self) -> float:
        """RMS residual component (m; rotations in translation-noise units)."""
        return math.sqrt(self.rss / self.n_residuals)

    def terms(self) -> tuple[float, int]:
        """:attr:`loss_rss` (m^2) and :attr:`penalty_params` (:meth:`search.Fitted.terms`)."""
        return self.loss_rss, self.penalty_params

    def labels(self) -> list[str]:
        """Each column of :attr:`x` named (:func:`parameter_labels`)."""
        return parameter_labels(self.model)

    def additions(self) -> set[str]:
        """The labels of the effects the model adds to the baseline."""
        return {e.label for e in self.model.effects}

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
    """A deflection campaign's observation (:class:`stiffness.calibration.solver.Problem`):
    scaled residuals ``(predicted - measured) / scale`` of a model over ``x`` and their
    Jacobian; with ``anchor``, the pseudo-residuals ``PRIOR_WEIGHT (x - anchor)`` appended;
    the model's bounds unless not ``bounded``.

    The Jacobian is the model's analytic one (:meth:`Hypothesis.predict_with_jacobian`) in its
    :attr:`Hypothesis.analytic_columns`; the other columns are finite differences (central for the
    reported :attr:`Fit.jacobian`, forward steps of :data:`_FORWARD_STEP` for the solver).
    """

    def __init__(self, model: Hypothesis, measured: np.ndarray, scale: float,
                 anchor: np.ndarray | None = None, bounded: bool = True) -> None:
        self.model, self.measured, self.scale, self.anchor = model, measured, scale, anchor
        self.n_res, self.p = measured.size, model.n_params
        self.numeric = np.flatnonzero(~model.analytic_columns)
        self.layout = layout(model)
        self.nominal = nominal_parameters(model)
        self._bounds = model.bounds() if bounded else None
        self._key: bytes | None = None
        self._pred: np.ndarray | None = None
        self._jac: np.ndarray | None = None
        #: Whether a prediction depends only on ``x``: not the exact baseline's, whose sag
        #: starts from the last one computed (:class:`~stiffness.calibration.exact_baseline.
        #: ExactObservation`), so that only its last point is reused (a point computed again
        #: there may differ in the last bits, and so do the later ones).
        self._pure = model.baseline != "exact"
        #: The predictions and Jacobians kept (``x``'s bytes: either ``None`` where the model
        #: fails), :data:`_RECENT` of them (the last one only where not :attr:`_pure`).
        self._recent: dict[bytes, tuple[np.ndarray | None, np.ndarray | None]] = {}
        #: The last data Jacobian of each kind (central: True; forward: False, where
        #: :attr:`_pure`) and its ``x``: a fit's identifiability judges the columns at its
        #: start, where the solver's first Jacobian is taken again.
        self._jacobians: dict[bool, tuple[bytes, np.ndarray]] = {}

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
        if key == self._key:
            return
        kept = self._recent.pop(key, None) if self._pure else None
        if kept is None:
            kept = self._predict(x, jacobian=True)
        self._recent[key] = kept
        while len(self._recent) > (_RECENT if self._pure else 1):
            del self._recent[next(iter(self._recent))]
        self._pred, self._jac = kept
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
        last = self._jacobians.get(central)
        if last is not None and last[0] == x.tobytes() and (central or self._pure):
            return last[1].copy()
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
        self._jacobians[central] = (x.tobytes(), out.copy())
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

    def failed(self, x: np.ndarray) -> bool:
        """Whether the model cannot be evaluated at ``x``."""
        return bool(self.data(x)[0] == PENALTY)

    def bounds(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The model's bounds (:meth:`Hypothesis.bounds`), ``None`` for an unbounded fit."""
        return self._bounds

    def columns(self, x: np.ndarray, final: bool) -> np.ndarray | None:
        """The columns identifiability judges at ``x`` (:func:`layout`): the data Jacobian in
        the fitted variables' physical units times their typical size, a compliance ``1 / k``
        (``-k d r / d ln k`` times ``1 / k_ref``, so a stiff joint is not mistaken for one
        without effect), an effect's SI value; ``None`` where the model fails. ``final``: the
        central differences of the reported Jacobian, else forward ones."""
        if self.failed(x):
            return None
        a = self.data_jacobian(x, central=final)
        n0 = len(self.model.compliant)
        a[:, :n0] *= -np.exp(x[:n0]) / self.model.refs.k_ref
        return a

    def start(self, x: np.ndarray, ident: Identifiability) -> np.ndarray:
        """``x`` itself (its parameters left out already at :attr:`nominal`)."""
        return x


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
        One of :data:`~stiffness.calibration.solver.LOSSES` (robust ones need
        ``method="trf"``).
    f_scale
        Soft threshold of a robust loss, in units of ``scale`` (the noise std / ``scale``).
    resolution
        Near aliases an effect's columns must be told from
        (:func:`stiffness.calibration.identifiability.identifiable`; ``scale`` the noise std),
        0 for none.

    The parameters of ``model.held`` (:attr:`Hypothesis.held`), as those the data do not
    identify, are held at their nominal values (:func:`nominal_parameters`), the former
    reported as undetermined with why (:meth:`Identifiability.holding`).
    """
    check_loss(loss, method)
    objective = Objective(model, measured, scale, anchor, bounded)
    x0 = np.asarray(x0, dtype=float)
    if bounded:
        x0 = np.clip(x0, *model.bounds())
    labels = parameter_labels(model)
    hold = {i: model.held[label] for i, label in enumerate(labels) if label in model.held}
    logs = tuple(range(len(model.compliant))) if bounded and method == "trf" else ()
    sol = solver.fit(objective, x0, solver.Options(method, tolerance, max_nfev, x_scale, loss,
                                                   f_scale, logs), resolution, hold)
    x, at_bound = sol.x, list(sol.at_bound)
    if bounded:
        x, at_bound = _rigid(model, x, at_bound, sol.identifiability.kept)
    jac = objective.data_jacobian(x)
    r = objective.data(x)
    pred = measured + r.reshape(measured.shape) * scale
    return Fit(model, x, pred, float(np.sum((r * scale) ** 2)), jac, scale, sol.success,
               sol.message, sol.nfev, loss, float(f_scale), loss_sum(r, loss, f_scale),
               sol.identifiability, at_bound)


def rigid_joints(model: Hypothesis, x: np.ndarray, kept: Sequence[int]) -> list[int]:
    """The baseline joints of ``model`` fitted (in ``kept``) rigid to the data at ``x``: their
    compliance within :data:`RIGID_COMPLIANCE` typical sizes (``1 / k_ref``) of its bound's,
    the bound judged in compliance units, where the data see the parameter (the one rule of
    diagnose's bounded fits and identify's unbounded ones, whose ``ln k`` may run past it)."""
    n0 = len(model.compliant)
    hi = model.bounds()[1]
    u = model.refs.k_ref * (np.exp(-x[:n0]) - np.exp(-hi[:n0]))
    return [i for i in range(n0) if i in kept and u[i] <= RIGID_COMPLIANCE]


def reference_stiffness(fit: Fit, sigma: float, quantile: float | np.ndarray,
                        measured: np.ndarray | None = None) -> float:
    """``k_ref`` (SI) of a baseline ``fit`` of ln k: :func:`typical_stiffness` over the
    springs it fitted (:attr:`Fit.kept`) off their rigid bound (:attr:`Fit.at_bound`,
    :func:`rigid_joints`), their compliances' 95 % intervals ``c -+ quantile se_c`` (the
    report's, :func:`~stiffness.calibration.deflection_parameters.stiffness_parameters`:
    ``se_c = c se`` with ``se`` that of ``ln k`` from :func:`compliance_covariance` at the
    noise std ``sigma``, m; ``quantile`` one for all or one per column of ``fit.x``; robust
    fits need their observations ``measured``); else the springs' nominal stiffnesses.

    The physical scales (ten times ``1 / k_ref`` in compliance, the typical joint deflection)
    are judged against it: a wrist the data do not see, at its 1e14 bound, raised it from
    3.9e4 to 1.7e6 N.m/rad on a UR5 and called a true 0.02 deg backlash a stand-in, "its
    size not physical"."""
    n0 = len(fit.model.compliant)
    rigid = set(fit.at_bound) | set(rigid_joints(fit.model, fit.x, fit.kept))
    fitted = [i for i in fit.kept if i < n0 and i not in rigid]
    se = np.full(n0, np.inf)
    if fitted:
        with np.errstate(invalid="ignore"):
            se = np.sqrt(np.diag(compliance_covariance(fit, sigma, measured))[:n0])
    c = np.exp(-fit.x[:n0])
    q = np.broadcast_to(np.asarray(quantile, dtype=float), fit.x.shape)[:n0]
    with np.errstate(invalid="ignore"):
        low = c * (1.0 - q * se)
    return typical_stiffness(c, low, fitted,
                             nominal_stiffness(fit.model.geometry.robot, fit.model.compliant))


def typical_stiffness(compliance: Sequence[float] | np.ndarray,
                      low: Sequence[float] | np.ndarray, fitted: Sequence[int],
                      nominal: Sequence[float] | np.ndarray) -> float:
    """``k_ref`` (SI) of a fit's springs, the one rule of both campaign kinds' physical scales
    (a deflection fit's, :func:`reference_stiffness`; a pose fit's,
    :func:`stiffness.calibration.pose_parameters.reference_stiffness`): the geometric mean
    of the stiffnesses ``1 / compliance`` the fit determines, those among ``fitted`` (the
    springs it fitted and left off their bound) whose compliance's 95 % interval excludes
    zero (its low end ``low`` above zero: a finite stiffness interval); else the geometric
    mean of the ``nominal`` stiffnesses (declared or
    :data:`NOMINAL_STIFFNESS`). Compliances in rad/(N.m) or m/N, stiffnesses their inverse.

    A joint the data do not move, or cannot tell from rigid, sets no scale: a near-rigid
    spring off its bound whose interval reaches zero counted on the deflection side until
    the pose side's rule became both's (a UR10 pose campaign's median rule, one true spring
    of 2e4 N.m/rad beside an elbow and wrist_1 fitted nearly rigid, gave ``k_ref`` 3.1e5 and
    called that spring a stand-in)."""
    c, lo = np.asarray(compliance, dtype=float), np.asarray(low, dtype=float)
    seen = [i for i in fitted if c[i] > 0 and lo[i] > 0]
    if seen:
        return float(np.exp(-np.mean(np.log(c[seen]))))
    return float(np.exp(np.mean(np.log(np.asarray(nominal, dtype=float)))))


def _rigid(model: Hypothesis, x: np.ndarray, at_bound: list[int], kept: Sequence[int]
           ) -> tuple[np.ndarray, list[int]]:
    """``x`` with each joint rigid to the data (:func:`rigid_joints`) set at its bound (the
    stiffness's upper bound) and listed in ``at_bound``."""
    hi = model.bounds()[1]
    rigid = [i for i in rigid_joints(model, x, kept) if i not in at_bound]
    if not rigid:
        return x, at_bound
    x = x.copy()
    x[rigid] = hi[rigid]
    return x, sorted(at_bound + rigid)


def nominal_parameters(model: Hypothesis) -> np.ndarray:
    """``model``'s nominal parameter vector, what a parameter left out of a fit is held at
    (:func:`stiffness.calibration.solver.held_at_nominal`): each baseline joint's ``ln k`` at
    its nominal stiffness (:func:`nominal_log_stiffness`: the same for every fit, identify's
    and diagnose's), each effect's variables at its start (:meth:`Effect.start`: the effect
    nearly absent, a compensator's base at the declared one)."""
    return np.concatenate([nominal_log_stiffness(model)] + [e.start() for e in model.effects])


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
    """How identifiability judges ``model``'s parameters
    (:class:`stiffness.calibration.identifiability.Layout`): the baseline's compliances first
    (every one with an effect on the data kept: their undetermined combinations are the
    covariance's, :func:`covariance`), then each effect's own variables in the order added
    (near aliases of the columns before them merged), each followed by the settings
    :meth:`Settings.settings_freed` made parameters (a compensator's base: judged by its interval
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


def compliance_covariance(fit: Fit, sigma: float, measured: np.ndarray | None = None
                          ) -> np.ndarray:
    """:func:`compliance_spread`'s matrix carried back to ``ln k`` (``d ln k = -du / u``):
    :func:`covariance`'s matrix of ``fit.x`` wherever the problem is well conditioned, and a
    stiff joint's compliance stays a parameter the data see, so that a near alias of it is
    not judged as if that joint were held (its ``ln k`` column vanishes with its
    compliance). An infinite entry (a parameter along an undetermined direction) stays
    ``+inf``."""
    slope = compliance_slope(fit)
    matrix = compliance_spread(fit, sigma, measured).matrix
    with np.errstate(invalid="ignore"):
        return np.where(np.isinf(matrix), np.inf, matrix / np.outer(slope, slope))


def compliance_slope(fit: Fit) -> np.ndarray:
    """``d u / d x``: ``-u`` for the baseline's columns (``u = k_ref / k``), 1 for the others."""
    slope = np.ones(fit.x.size)
    n0 = len(fit.model.compliant)
    slope[:n0] = -fit.model.refs.k_ref * np.exp(-fit.x[:n0])
    return slope


def compliance_spread(fit: Fit, sigma: float = 1.0, measured: np.ndarray | None = None
                      ) -> Covariance:
    """:func:`covariance` of ``fit`` computed with the baseline's columns in compliance units
    ``u = k_ref / k`` (``dr/du = -dr/d ln k / u``): the covariance a deflection fit reports
    (:func:`compliance_covariance`) before it is carried back to ``ln k``. Its
    :attr:`~stiffness.calibration.solver.Covariance.rank` counts the directions that
    covariance spreads over, a spring at its rigid bound among them (its ``ln k`` column
    vanishes there, its compliance's does not): a robust fit's intervals take ``n - rank``
    degrees of freedom (:meth:`~stiffness.calibration.selection.Noise.of_fit`). A
    parameterless switch such as ``complementary_stiffness`` counts in
    :attr:`Fit.penalty_params`, not here."""
    return covariance(replace(fit, jacobian=fit.jacobian / compliance_slope(fit)), sigma,
                      measured)


def covariance(fit: Fit, sigma: float, measured: np.ndarray | None = None) -> Covariance:
    """The covariance of ``fit.x`` for a noise std ``sigma`` (m): the one covariance of both
    campaign kinds (:func:`stiffness.calibration.solver.covariance_matrix`; for a robust loss,
    given the fitted observations ``measured``, the sandwich). Over the fitted parameters only
    (:attr:`Fit.kept`): one held as not identifiable has infinite variance, a zero singular
    value and its own axis as direction."""
    kept = fit.kept
    full_p = fit.jacobian.shape[1]
    if len(kept) < full_p:
        sub = covariance(replace(fit, jacobian=fit.jacobian[:, kept],
                                 x=fit.x[kept], identifiability=None), sigma, measured)
        held = np.setdiff1d(np.arange(full_p), kept)
        matrix = np.full((full_p, full_p), np.inf)
        matrix[np.ix_(kept, kept)] = sub.matrix
        directions = np.zeros((full_p, full_p))
        directions[: len(kept), kept] = sub.directions
        directions[len(kept) + np.arange(held.size), held] = 1.0
        return Covariance(matrix, np.concatenate([sub.singular_values, np.zeros(held.size)]),
                          directions, np.concatenate([sub.undetermined,
                                                      np.ones(held.size, dtype=bool)]))
    if fit.loss != "linear" and measured is None:
        raise StiffnessError("the covariance of a robust fit needs its observations")
    residual = None if measured is None else (fit.predicted - measured).reshape(-1)
    return covariance_matrix(fit.jacobian * fit.scale, sigma, fit.loss, residual,
                             fit.f_scale * fit.scale)
