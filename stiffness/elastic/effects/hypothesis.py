"""A deflection hypothesis: a baseline plus effects, predicting a campaign's rows as array algebra.

A campaign's deflections are explained by a :class:`Hypothesis`: the baseline
(``conventional`` ``J K^-1 J^T W`` or ``enhanced`` ``J (K - K_C(W))^-1 J^T W``, A&S eq. 8 and
10) over the campaign's compliant joints, extended by any number of effects from
:data:`stiffness.elastic.effects.LIBRARY`. Pinocchio ran once per distinct configuration
(:meth:`stiffness.elastic.effects.geometry.Geometry.rows`); every hypothesis is then array
algebra over the rows (:meth:`Hypothesis.predict`), cheap enough for least squares over dozens
of candidates with cross-validation (:mod:`stiffness.calibration.fitting`).

``complementary_stiffness`` gives ``K_C`` in the tangent stiffness *and* the second-order
kinematics of the deflection, ``dx = J dtheta + 1/2 sum_k e_k dtheta^T H_k dtheta`` with
``dtheta`` the fixed point of ``dtheta = K^-1 (J^T W + K_C(W) dtheta)``: the exact
elastostatic equilibrium to second order in the deflection.

With a :attr:`Hypothesis.rotation_weight` a hypothesis also predicts the rotation of the target
frame, ``J_w dtheta`` plus each effect's rotational part; with ``complementary_stiffness`` also
its second-order term ``1/2 sum_{a<b} (w_a x w_b) dtheta_a dtheta_b`` (the product of the
joints' exponentials to second order, Baker-Campbell-Hausdorff; ``w_a`` the world axes, chain
order), which is ``1/2 sum_k e_k dtheta^T K_C(e_k moment) dtheta`` since
``dw_b/dtheta_a = w_a x w_b`` for ``a`` before ``b``: rotations then match the exact
equilibrium's rotation vector to third order in the load, like translations.

Units: SI inside (m, N, rad, N.m/rad).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from stiffness.elastic.effects.base import Held
from stiffness.elastic.effects.deflection_face import DeflectionEffect
from stiffness.elastic.effects.geometry import (
    Geometry,
    References,
    Rows,
    contract_hessian,
    skew,
)
from stiffness.errors import StiffnessError, UnknownNameError
from stiffness.mechanics.equilibrium import SpringLaw

#: Newton iterations of the joint law when it is nonlinear (backlash, nonlinear spring).
LAW_ITERATIONS = 4
#: Baselines a model may start from (``exact``: the exact equilibrium of every row, without
#: effects, from the model's :class:`ExactForward`).
BASELINES = ("conventional", "enhanced", "exact")


class ExactForward(Protocol):
    """The ``exact`` baseline's forward model over a hypothesis's rows
    (:class:`stiffness.calibration.exact_baseline.ExactObservation`, the pose model's sag)."""

    def __call__(self, k: np.ndarray, jacobian: bool = True
                 ) -> tuple[np.ndarray, np.ndarray | None]:
        """The rows predicted at the stiffnesses ``k`` (SI, the hypothesis's joints), and
        with ``jacobian`` their derivatives in ``ln k``."""

# ------------------------------------------------------------------------------------------
# the hypothesis


class Hypothesis:
    """A deflection hypothesis: baseline formulation, compliant joints and effects, over some
    rows of a campaign (the model the fitting engine fits and compares).

    The parameter vector ``x`` is ``ln k`` of the baseline's compliant joints followed by each
    effect's scaled variables (SI values: the variables times :meth:`Effect.scale`).

    Parameters
    ----------
    geometry
        The robot's shared geometry.
    rows
        The rows to predict.
    baseline
        ``conventional`` or ``enhanced``.
    compliant
        The baseline's compliant joints.
    effects
        Effects, in the order added.
    refs
        Variable scales.
    rotation_weight
        ``None``: the model predicts the (m, 3) translations. A weight ``w`` (m/rad): it
        predicts (m, 6) rows ``[dx; w dphi]``, the rotation ``dphi`` of the target frame
        (rad, base axes) in translation-noise units (``w = sigma_t / sigma_r``), so that one
        residual scale whitens both kinds (:mod:`stiffness.calibration.fitting`).
    held
        Parameters held at their nominal value because the data do not determine them, by
        label (``compliance(joint)`` or ``effect_label.parameter``) with why
        (:func:`stiffness.calibration.fitting.fit_model` keeps them at the start; carried to
        every model derived from this one).
    exact
        What makes the ``exact`` baseline's forward model of a hypothesis (required with that
        baseline: :class:`stiffness.calibration.exact_baseline.ExactObservation`, which
        :func:`stiffness.calibration.identify.stiffness_model` gives); carried to every model
        derived from this one.
    """

    def __init__(self, geometry: Geometry, rows: Rows, baseline: str,
                 compliant: tuple[str, ...], effects: tuple[DeflectionEffect, ...],
                 refs: References, rotation_weight: float | None = None,
                 held: dict[str, Held] | None = None,
                 exact: Callable[[Hypothesis], ExactForward] | None = None) -> None:
        if baseline not in BASELINES:
            raise UnknownNameError(f"unknown baseline {baseline!r}; valid: {', '.join(BASELINES)}",
                                   name=baseline, choices=BASELINES)
        if baseline == "exact" and effects:
            raise StiffnessError("the exact baseline takes no effects (complementary_stiffness "
                                 "approximates it to second order); start from enhanced")
        if baseline == "exact" and exact is None:
            raise StiffnessError("the exact baseline needs its forward model: give "
                                 "exact=ExactObservation (stiffness.calibration.exact_baseline)")
        self.geometry, self.rows, self.baseline = geometry, rows, baseline
        self.compliant, self.effects, self.refs = tuple(compliant), tuple(effects), refs
        self.rotation_weight = None if rotation_weight is None else float(rotation_weight)
        self.held = dict(held or {})
        self.joints = self.compliant + tuple(str(e.where) for e in self.effects if e.adds_spring)
        self.index = np.array([geometry.joints.index(j) for j in self.joints], dtype=int)
        self.tangent = baseline == "enhanced" or any(e.second_order for e in self.effects)
        self.second_order = any(e.second_order for e in self.effects)
        sizes = [len(self.compliant)] + [e.n_params for e in self.effects]
        self.offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
        self.exact = exact
        #: the exact baseline's forward model over these rows, made at its first evaluation
        self._exact_forward: ExactForward | None = None
        self._prepare()

    def _prepare(self) -> None:
        idx, rows = self.index, self.rows
        self.jv = rows.jac[:, :3][:, :, idx]
        self.jw = rows.jac[:, 3:][:, :, idx]
        self.h = rows.k_c_unit[:, :, idx][:, :, :, idx]
        self._k_c: np.ndarray | None = None
        self._tau: np.ndarray | None = None

    # construction ----------------------------------------------------------------------------
    def replaced(self, **changes: Any) -> Hypothesis:
        """The same model with constructor arguments replaced (``rows``, ``baseline``,
        ``effects``, ``refs``, ``rotation_weight`` in m/rad or ``None``, ``held``,
        ``exact``)."""
        args = {"geometry": self.geometry, "rows": self.rows, "baseline": self.baseline,
                "compliant": self.compliant, "effects": self.effects, "refs": self.refs,
                "rotation_weight": self.rotation_weight, "held": self.held,
                "exact": self.exact}
        return Hypothesis(**{**args, **changes})

    def extended(self, effect: DeflectionEffect) -> Hypothesis:
        """This model plus ``effect``."""
        return self.replaced(effects=self.effects + (effect,))

    def through(self, i: int) -> list[int]:
        """Effect ``i`` and the effects acting through it, by position: the joint laws
        (:attr:`DeflectionEffect.through_law`) at the joint whose spring it adds
        (:attr:`DeflectionEffect.adds_spring`), which have no joint to act on without it."""
        e = self.effects[i]
        return [j for j, f in enumerate(self.effects) if j == i or (
            e.adds_spring and f.through_law and f.where == e.where)]

    def without(self, i: int, x: np.ndarray) -> tuple[Hypothesis, np.ndarray]:
        """The model without effect ``i`` and those acting through it (:meth:`through`), and
        ``x`` (its parameter vector) without their parameters."""
        gone = self.through(i)
        keep = np.ones(x.size, dtype=bool)
        for j in gone:
            keep[self.offsets[j + 1]: self.offsets[j + 2]] = False
        return self.replaced(effects=tuple(e for j, e in enumerate(self.effects)
                                       if j not in gone)), x[keep]

    def holding(self, held: dict[str, Held]) -> Hypothesis:
        """The same model with the parameters of ``held`` (label: why) held too."""
        return self.replaced(held={**self.held, **held})

    @property
    def n_outputs(self) -> int:
        """Predicted components per row: 3 (translation) or 6 (translation and rotation)."""
        return 3 if self.rotation_weight is None else 6

    def split(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Translations (m, 3) in m and rotations (m, 3) in rad (or ``None``) of predicted or
        measured rows in this model's output layout."""
        values = np.asarray(values, dtype=float)
        if self.rotation_weight is None:
            return values[:, :3], None
        return values[:, :3], values[:, 3:6] / self.rotation_weight

    @property
    def wrench(self) -> np.ndarray:
        """(m, 6) recorded wrenches of the rows."""
        return np.hstack([self.rows.force, self.rows.moment])

    def k_c(self) -> np.ndarray:
        """(m, n, n) ``K_C`` of each row's recorded wrench over :attr:`joints` (computed once;
        not to be modified)."""
        if self._k_c is None:
            self._k_c = np.einsum("mk,mkab->mab", self.wrench, self.h)
        return self._k_c

    def _torques(self) -> np.ndarray:
        """(m, n) ``J^T W`` of each row's recorded wrench over :attr:`joints` (computed once)."""
        if self._tau is None:
            self._tau = np.einsum("mkn,mk->mn", self.jv, self.rows.force) + np.einsum(
                "mkn,mk->mn", self.jw, self.rows.moment)
        return self._tau

    @property
    def n_params(self) -> int:
        """Length of the parameter vector."""
        return int(self.offsets[-1])

    @property
    def penalty_params(self) -> int:
        """Parameters counted by the information criterion (an effect without parameters, a
        switch, counts as one)."""
        return len(self.compliant) + sum(max(e.n_params, 1) for e in self.effects)

    def extend_x(self, x: np.ndarray, effect: DeflectionEffect) -> np.ndarray:
        """Start vector of :meth:`extended` from this model's ``x``."""
        return np.concatenate([x, effect.start()])

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounds of the parameter vector."""
        n0 = len(self.compliant)
        lo, hi = [np.full(n0, math.log(1e-3))], [np.full(n0, math.log(1e14))]
        for e in self.effects:
            a, b = e.bounds()
            lo.append(a)
            hi.append(b)
        return np.concatenate(lo), np.concatenate(hi)

    def effect_vars(self, x: np.ndarray, i: int) -> np.ndarray:
        """Optimiser variables of effect ``i``."""
        return x[self.offsets[i + 1]: self.offsets[i + 2]]

    def _effect_params(self, x: np.ndarray) -> list[np.ndarray]:
        return [self.effect_vars(x, i) * e.scale(self.refs) for i, e in enumerate(self.effects)]

    def stiffness(self, x: np.ndarray) -> np.ndarray:
        """Baseline stiffnesses (SI) of parameter vector ``x``."""
        return np.exp(x[: len(self.compliant)])

    # prediction ------------------------------------------------------------------------------
    def law(self, x: np.ndarray, params: list[np.ndarray] | None = None) -> SpringLaw:
        """The joint law over :attr:`joints`."""
        params = self._effect_params(x) if params is None else params
        n = len(self.joints)
        compliance = np.zeros(n)
        compliance[: len(self.compliant)] = np.exp(-x[: len(self.compliant)])
        law = SpringLaw(compliance, np.zeros(n), np.zeros(n),
                  self.refs.tau_smoothing[self.index].copy())
        for e, p in zip(self.effects, params, strict=True):
            if e.through_law:
                e.adjust_law(p, law, self.joints.index(e.where), self.refs)
        return law

    @property
    def analytic_columns(self) -> np.ndarray:
        """(p,) mask of the parameters :meth:`predict_with_jacobian` differentiates: ``ln k``,
        the variables of effects acting through the joint law
        (:attr:`DeflectionEffect.through_law`), of effects moving the target linearly
        (:attr:`DeflectionEffect.linear_motion`) and of effects changing the Jacobian linearly
        (:attr:`DeflectionEffect.moves_jacobian`); the fitting engine differentiates the others
        numerically."""
        mask = np.ones(self.n_params, dtype=bool)
        for i, e in enumerate(self.effects):
            mask[self.offsets[i + 1]: self.offsets[i + 2]] = (e.through_law or e.linear_motion
                                                              or e.moves_jacobian)
        return mask

    def _motion_columns(self, rows: Rows, force: np.ndarray, moment: np.ndarray,
                        point: np.ndarray) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """The columns of the effects moving the target linearly
        (:attr:`DeflectionEffect.linear_motion`): ``(position among the analytic columns,
        d dx / d u (m, 3), d dphi / d u (m, 3))`` per variable, exact (the motion at the unit
        variable: it is linear in its variables)."""
        analytic = np.cumsum(self.analytic_columns) - 1
        out = []
        for i, e in enumerate(self.effects):
            if not e.linear_motion:
                continue
            for k in range(e.n_params):
                unit = np.zeros(e.n_params)
                unit[k] = 1.0
                motion = e.target_motion(unit * e.scale(self.refs), self, rows, force, moment,
                                         point)
                assert motion is not None  # a linear motion moves the target
                out.append((int(analytic[self.offsets[i + 1] + k]), motion[0], motion[1]))
        return out

    def _moved_jacobian(self, params: list[np.ndarray], jv: np.ndarray, jw: np.ndarray,
                        force: np.ndarray, moment: np.ndarray, tangent: bool
                        ) -> tuple[np.ndarray, np.ndarray, list, np.ndarray | None]:
        """The Jacobian ``J + sum_e dJ_e`` of the effects changing it
        (:meth:`DeflectionEffect.jacobian_change`) and, with ``tangent``, each of their
        variables' ``(position among the analytic columns, dJ / d u (m, 6, n))`` with the
        torques' tangent ``d (J^T W) / d u`` (m, n, P) over the analytic columns (``None``
        without such an effect); exact, the change being linear in its variables."""
        moved, t_tau = [], None
        analytic = np.cumsum(self.analytic_columns) - 1
        for i, (e, p) in enumerate(zip(self.effects, params, strict=True)):
            if not e.moves_jacobian:
                continue
            change = e.jacobian_change(p, self, self.rows)
            if change is not None:
                jv, jw = jv + change[:, :3], jw + change[:, 3:]
            if not tangent:
                continue
            scale = e.scale(self.refs)
            for k in range(e.n_params):
                unit = np.zeros(e.n_params)
                unit[k] = scale[k]
                d_j = e.jacobian_change(unit, self, self.rows)
                assert d_j is not None  # a Jacobian-moving effect moves it
                moved.append((int(analytic[self.offsets[i + 1] + k]), d_j))
        if moved:
            t_tau = np.zeros(jv.shape[:1] + jv.shape[2:] + (int(self.analytic_columns.sum()),))
            for column, d_j in moved:
                t_tau[:, :, column] = (np.einsum("mkn,mk->mn", d_j[:, :3], force)
                                       + np.einsum("mkn,mk->mn", d_j[:, 3:], moment))
        return jv, jw, moved, t_tau

    def predict_with_jacobian(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predicted displacements (m, 3) and their derivatives (m, 3, p) w.r.t. ``x`` in
        the columns of :attr:`analytic_columns` (zeros in the others).

        Linear baselines without effects: ``d pred / d ln k_i = -J_v (K - K_C)^-1 e_i k_i u_i``
        with ``u = (K - K_C)^-1 J^T W``; exact: the implicit function theorem on
        ``K dtheta = J(theta)^T W``, ``d dtheta / d k_i = -(K - K_C(theta))^-1 e_i dtheta_i``.
        With effects: the implicit function theorem on the frozen-geometry law
        (:meth:`stiffness.mechanics.equilibrium.SpringLaw.deflection_tangent`), carried through
        the second-order kinematics, the preload's unloaded equilibrium and the effects'
        output maps (:meth:`DeflectionEffect.output_map`).

        Raises
        ------
        np.linalg.LinAlgError
            If the tangent stiffness is singular for some row.
        StiffnessError
            If the exact equilibrium does not converge or is unstable.
        """
        if self.effects:
            pred, _, _, tangent = self._predict(x, tangent=True)
            jac = np.zeros(pred.shape + (self.n_params,))
            jac[:, :, self.analytic_columns] = tangent
            return pred, jac
        k = np.exp(x[: len(self.compliant)])
        if self.baseline == "exact":
            exact, exact_jac = self._exact(k)
            assert exact_jac is not None  # asked for
            return exact, exact_jac
        a = np.broadcast_to(np.diag(k), (self.rows.n_rows, len(k), len(k))).copy()
        if self.baseline == "enhanced":
            a -= self.k_c()
        inv = np.linalg.inv(a)
        u = np.einsum("mij,mj->mi", inv, self._torques())
        out = self.jv if self.rotation_weight is None else np.concatenate(
            [self.jv, self.rotation_weight * self.jw], axis=1)
        pred = np.einsum("mij,mj->mi", out, u)
        return pred, -(out @ inv) * (u * k)[:, None, :]

    def _law_directions(self, x: np.ndarray, law: SpringLaw
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Changes (P, n) of the law's compliance, ``beta`` and backlash per unit of each
        parameter of :attr:`analytic_columns`: ``dc_i / d ln k_i = -c_i``, and for an effect
        acting through the law the difference of the laws one unit apart (exact: such an
        effect sets the law affinely)."""
        columns = np.flatnonzero(self.analytic_columns)
        n = len(self.joints)
        d = np.zeros((3, len(columns), n))
        n0 = len(self.compliant)
        d[0, np.arange(n0), np.arange(n0)] = -law.compliance[:n0]
        through = np.zeros(self.n_params, dtype=bool)
        for i, e in enumerate(self.effects):
            through[self.offsets[i + 1]: self.offsets[i + 2]] = e.through_law
        for row, column in enumerate(columns[n0:], start=n0):
            if not through[column]:  # a linear motion: the law does not move
                continue
            step = x.copy()
            step[column] += 1.0
            moved = self.law(step)
            d[:, row] = (moved.compliance - law.compliance, moved.beta - law.beta,
                         moved.backlash - law.backlash)
        return d[0], d[1], d[2]

    def _exact(self, k: np.ndarray, jacobian: bool = True
               ) -> tuple[np.ndarray, np.ndarray | None]:
        """Exact equilibria of every row and, with ``jacobian``, their derivatives w.r.t.
        ``ln k``, from the model's :class:`ExactForward` (made at the first call)."""
        if self._exact_forward is None:
            assert self.exact is not None  # required with the exact baseline
            self._exact_forward = self.exact(self)
        return self._exact_forward(k, jacobian)

    def predict(self, x: np.ndarray, detail: bool = False):
        """(m, 3) predicted measured displacements (m) for parameters ``x``; (m, 6)
        ``[dx; w dphi]`` with a :attr:`rotation_weight` (rotation ``J_w dtheta``, with the
        second-order kinematics also ``1/2 sum_k e_k dtheta^T K_C(e_k moment) dtheta``, plus
        the effects' rotational parts).

        Effects with a :meth:`DeflectionEffect.preload` (gravity) make the deflection the loaded
        minus the unloaded frozen-geometry equilibrium, ``dtheta = f(tau_W + tau_p + (K_C + K_p)
        dtheta_1) - f(tau_p + K_p dtheta_0)``. With motor-side joint angles (the rows'
        :attr:`~stiffness.elastic.effects.geometry.Rows.joint_angles`) it is seen through the
        kinematics of the preloaded pose to first order in ``dtheta_0``:
        ``dx += sum_k e_k dtheta^T H_k dtheta_0`` and
        ``dphi += sum_k e_k dtheta^T K_C(e_k moment) dtheta_0``; with link angles the rows'
        pose already is the preloaded one.

        With ``detail``, also returns the joint deflections (m, n) and torques (m, n).

        Raises
        ------
        np.linalg.LinAlgError
            If the tangent stiffness is singular for some row.
        """
        if self.baseline == "exact":
            if detail:
                raise StiffnessError("the exact baseline gives no linear detail")
            return self._exact(np.exp(x[: len(self.compliant)]), jacobian=False)[0]
        dx, dtheta, tau, _ = self._predict(x, tangent=False, torques=detail)
        return (dx, dtheta, tau) if detail else dx

    def _predict(self, x: np.ndarray, tangent: bool, torques: bool = False
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
        """:meth:`predict` of a linear-kinematics baseline: the predicted rows, the joint
        deflections, with ``torques`` the joint torques (else ``None``), and with ``tangent``
        the (m, 3 or 6, P) derivatives of the rows along the parameters of
        :attr:`analytic_columns`."""
        rows = self.rows
        params = self._effect_params(x)
        force, moment = rows.force, rows.moment
        for e, p in zip(self.effects, params, strict=True):
            force, moment = e.adjust_load(p, force, moment)
        jv, jw, point = self.jv, self.jw, rows.position
        for e, p in zip(self.effects, params, strict=True):
            shift = e.target_shift(p, rows)
            if shift is not None:
                jv = jv - skew(shift) @ jw
                point = point + shift
        jv, jw, moved, t_tau = self._moved_jacobian(params, jv, jw, force, moment, tangent)
        tau0 = np.einsum("mkn,mk->mn", jv, force) + np.einsum("mkn,mk->mn", jw, moment)
        law = self.law(x, params)
        directions = self._law_directions(x, law) if tangent else None
        k_c = None
        if self.tangent:
            k_c = np.einsum("mk,mkab->mab", np.hstack([force, moment]), self.h)
        pre_tau = pre_k = None
        for e, p in zip(self.effects, params, strict=True):
            pre = e.preload(p, self, rows)
            if pre is not None:
                pre_tau = pre[0] if pre_tau is None else pre_tau + pre[0]
                pre_k = pre[1] if pre_k is None else pre_k + pre[1]

        dtheta, t_theta, unloaded, t_unloaded = self._joint_deflection(
            law, directions, tau0, k_c, pre_tau, pre_k, t_tau)
        sag = (dtheta, t_theta, unloaded, t_unloaded)
        dx, t_dx = self._output(jv, self.h[:, :3], *sag)
        motions = [e.target_motion(p, self, rows, force, moment, point)
                   for e, p in zip(self.effects, params, strict=True)]
        for extra in motions:
            if extra is not None:
                dx = dx + extra[0]
        moving = []
        if t_dx is not None:  # with the tangent
            moving = self._motion_columns(rows, force, moment, point)
            for column, d_dx, _ in moving:
                t_dx[:, :, column] += d_dx
            for column, d_j in moved:  # the output's own Jacobian: dJ_v dtheta
                t_dx[:, :, column] += np.einsum("mkn,mn->mk", d_j[:, :3], dtheta)
        maps = [e.output_map(p) for e, p in zip(self.effects, params, strict=True)]
        for rot, offset in maps:
            if rot is not None:
                dx = dx @ rot.T
                if t_dx is not None:  # with the tangent
                    t_dx = rot @ t_dx
            if offset is not None:
                dx = dx + offset
        if self.rotation_weight is not None:  # K_C of unit moments: the rotation's H
            dphi, t_phi = self._output(jw, self.h[:, 3:], *sag)
            for column, d_j in moved:
                if t_phi is not None:  # with the tangent
                    t_phi[:, :, column] += np.einsum("mkn,mn->mk", d_j[:, 3:], dtheta)
            for extra in motions:
                if extra is not None:
                    dphi = dphi + extra[1]
            for column, _, d_phi in moving:
                if t_phi is not None:  # with the tangent
                    t_phi[:, :, column] += d_phi
            for rot, _ in maps:
                if rot is not None:
                    dphi = dphi @ rot.T
                    if t_phi is not None:  # with the tangent
                        t_phi = rot @ t_phi
            dx = np.hstack([dx, self.rotation_weight * dphi])
            if t_dx is not None and t_phi is not None:  # with the tangent
                t_dx = np.concatenate([t_dx, self.rotation_weight * t_phi], axis=1)
        tau = None
        if torques:
            tau = tau0 if k_c is None else tau0 + np.einsum("mab,mb->ma", k_c, dtheta)
        return dx, dtheta, tau, t_dx

    def _output(self, j: np.ndarray, h: np.ndarray, dtheta: np.ndarray,
                t_theta: np.ndarray | None, unloaded: np.ndarray | None,
                t_unloaded: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
        """One part of a row's output from the joint deflections ``dtheta`` (m, n): the
        translation (``j`` = J_v, ``h`` the Hessians H_k) or the rotation (J_w, ``K_C`` of the
        unit moments: ``1/2 sum_{a<b} (w_a x w_b) dtheta_a dtheta_b``). ``J dtheta``, with the
        second-order kinematics ``1/2 sum_k e_k dtheta^T H_k dtheta``, and with a preload's
        ``unloaded`` deflection the load seen on the arm it already deflected,
        ``sum_k e_k dtheta^T H_k dtheta_0``; and its tangent along the analytic parameters
        when ``t_theta`` (m, n, P) is given (``None`` otherwise)."""
        d = np.einsum("mkn,mn->mk", j, dtheta)
        t = None if t_theta is None else j @ t_theta
        if self.second_order:
            d = d + 0.5 * np.einsum("mkab,ma,mb->mk", h, dtheta, dtheta)
            if t is not None:
                t = t + 0.5 * (contract_hessian(h, dtheta, 2)
                               + contract_hessian(h, dtheta, 3)) @ t_theta
        if unloaded is not None:
            d = d + np.einsum("mkab,ma,mb->mk", h, dtheta, unloaded)
            if t is not None:
                t = (t + contract_hessian(h, unloaded, 3) @ t_theta
                     + contract_hessian(h, dtheta, 2) @ t_unloaded)
        return d, t

    def _joint_deflection(self, law: SpringLaw, directions: tuple | None, tau0: np.ndarray,
                          k_c: np.ndarray | None, pre_tau: np.ndarray | None,
                          pre_k: np.ndarray | None, t_tau: np.ndarray | None = None) -> tuple:
        """Joint deflections (m, n) of the rows under the load torques ``tau0`` (frozen
        geometry, ``K_C`` = ``k_c``), with ``directions`` their (m, n, P) tangent (and that of
        the load torques' changes ``t_tau`` (m, n, P), if any: ``(I - diag(f') K) d dtheta =
        diag(f') d tau0`` at the loaded equilibrium, ``K`` its stiffness); under a
        preload (torque ``pre_tau``, stiffness ``pre_k``) the loaded minus the unloaded
        equilibrium, and the unloaded one (the sag) with its tangent when the rows' angles are
        motor-side (else ``None``, the rows' pose being the preloaded one).

        With link angles the load's ``K_C`` acts on the deflection beyond the recorded pose
        only: loaded ``= f(tau_W + tau_p - K_C dtheta_0 + (K_C + K_p) dtheta_1)``, so that a
        linear law gives ``(K - K_C - K_p)^-1 tau_W``.
        """
        tangent = directions is not None

        def equilibrium(torque, stiffness, loaded=False):
            d = law.frozen_deflection(torque, stiffness, LAW_ITERATIONS)
            if not tangent:
                return d, None
            t = law.deflection_tangent(torque, stiffness, d, *directions)
            if loaded and t_tau is not None:
                t = t + torque_response(law, torque, stiffness, d, t_tau)
            return d, t

        if pre_tau is None or pre_k is None:
            dtheta, t_theta = equilibrium(tau0, k_c, loaded=True)
            return dtheta, t_theta, None, None
        unloaded, t_unloaded = equilibrium(pre_tau, pre_k)
        stiffness = pre_k if k_c is None else k_c + pre_k
        if self.rows.joint_angles == "link" and k_c is not None:
            torque = tau0 + pre_tau - np.einsum("mab,mb->ma", k_c, unloaded)
            loaded, t_loaded = equilibrium(torque, stiffness, loaded=True)
            if tangent:  # the torque moves with the unloaded deflection
                slope = law(torque + np.einsum("mab,mb->ma", stiffness, loaded))[1]
                eye = np.eye(slope.shape[-1])
                response = np.linalg.solve(eye - slope[..., :, None] * stiffness,
                                           slope[..., :, None] * eye)
                t_loaded = t_loaded - response @ (k_c @ t_unloaded)
        else:
            loaded, t_loaded = equilibrium(tau0 + pre_tau, stiffness, loaded=True)
        dtheta = loaded - unloaded
        t_theta = t_loaded - t_unloaded if tangent else None
        if self.rows.joint_angles == "link":
            return dtheta, t_theta, None, None
        return dtheta, t_theta, unloaded, t_unloaded

    def describe(self) -> str:
        """E.g. ``enhanced over joint1, joint2 + backlash(joint2)``."""
        text = f"{self.baseline} over {', '.join(self.compliant)}"
        return text + "".join(f" + {e.label}" for e in self.effects)


def torque_response(law: SpringLaw, tau0: np.ndarray, k_c: np.ndarray | None,
                    dtheta: np.ndarray, t_tau: np.ndarray) -> np.ndarray:
    """(m, n, P) change of :meth:`~stiffness.mechanics.equilibrium.SpringLaw.frozen_deflection`'s
    ``dtheta = f(tau0 + K_C dtheta)`` along changes ``t_tau`` (m, n, P) of the torques
    ``tau0``: the implicit function theorem, ``(I - diag(f') K_C) d dtheta = diag(f') d tau0``
    with ``f'`` the law's slope at the equilibrium's torque (``K_C = None``: ``diag(f')``)."""
    tau = tau0 if k_c is None else tau0 + np.einsum("...ab,...b->...a", k_c, dtheta)
    slope = law(tau)[1]
    if k_c is None:
        return slope[..., :, None] * t_tau
    return np.linalg.solve(np.eye(tau.shape[-1]) - slope[..., :, None] * k_c,
                           slope[..., :, None] * t_tau)
