"""Exact elastostatic equilibrium under a dead load, loops closed, for any joint law.

Solves ``dtheta = f(J(theta)^T W)`` for the compliant-joint deflection ``dtheta = theta - theta_0``
(rigid joints held, passive loop joints following the closure), where the *joint law* ``f``
gives each joint's deflection under its torque:

* :class:`LinearSprings` ``f(tau) = K_theta^-1 tau`` (any symmetric positive definite
  ``K_theta``): the stationary point of
  ``Pi = 1/2 dtheta^T K_theta dtheta - W . x(theta)``, solved as ``K_theta dtheta = J^T W``;
* :class:`SpringLaw` ``f_j(tau_j) = c_j tau_j (1 + beta_j |tau_j|) + b_j tanh(tau_j / s_j)``:
  linear springs (``beta = b = 0``), softening or hardening springs (``beta``) and lost motion
  (backlash of half-width ``b`` smoothed over the torque ``s``); its terms are
  :mod:`stiffness.mechanics.law_terms`'.

Newton's method runs on the law's residual with ``d(J^T W)/d theta = K_C`` (A&S eq. 9), i.e. the
tangent ``K_t - K_C`` with ``K_t = (df/dtau)^-1``; the solution must be stable (``K_t - K_C``
positive definite). :func:`tangent_equilibrium` is the same fixed point at frozen geometry
(``tau = J^T W + K_C dtheta`` at the unloaded pose), the enhanced model of a nonlinear law.
The linear predictions of :mod:`stiffness.mechanics.formulation` are truncations of the exact
solution (see :func:`linear_departure`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from stiffness.errors import (
    ConvergenceError,
    LoopClosureError,
    UnstableEquilibriumError,
    wrong_argument,
)
from stiffness.mechanics.formulation import (
    TargetState,
    as_wrench,
    compliant_projection,
    full_configuration,
    tangent_joint_stiffness,
    target_state,
)
from stiffness.mechanics.law_terms import (
    linear,
    lost_motion,
    lost_motion_column,
    softening,
    softening_column,
)
from stiffness.robot.robot import Robot
from stiffness.units import float_array, whole_number

#: Absolute floor of the convergence test, relative to the largest residual term: the round-off
#: of the kinematics (a few eps) that couples every joint's residual to the largest term.
_ROUND_OFF = 16 * np.finfo(float).eps
#: Times a Newton step whose loops do not close is halved back towards the last deflection that
#: closed, before the equilibrium is given up as beyond the loops' reach.
_HALVINGS = 12


class JointLaw:
    """A joint torque-deflection law over the compliant joints (SI: N.m or N, rad or m).

    Subclasses give the Newton residual ``r(dtheta, tau)`` whose zero is the law, its
    derivative w.r.t. ``dtheta`` when ``d tau / d dtheta = K_C``, a start, and the tangent
    stiffness ``(df/dtau)^-1``.
    """

    def start(self, tau: np.ndarray) -> np.ndarray:
        """A first deflection for the torque ``tau`` (n,)."""
        raise NotImplementedError

    def residual(self, dtheta: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Residual (n,) that vanishes when ``dtheta`` is the law's deflection under ``tau``."""
        raise NotImplementedError

    def residual_jacobian(self, dtheta: np.ndarray, tau: np.ndarray, k_c: np.ndarray
                          ) -> np.ndarray:
        """(n, n) derivative of :meth:`residual` w.r.t. ``dtheta`` when ``d tau = K_C d dtheta``."""
        raise NotImplementedError

    def tangent_stiffness(self, tau: np.ndarray) -> np.ndarray:
        """(n, n) tangent joint stiffness ``(df/dtau)^-1`` at the torque ``tau``."""
        raise NotImplementedError


@dataclass
class LinearSprings(JointLaw):
    """``K_theta dtheta = tau`` with a (n, n) stiffness matrix (N.m/rad, N/m)."""

    k_theta: np.ndarray

    def __post_init__(self) -> None:
        self.k_theta = np.atleast_2d(np.asarray(self.k_theta, dtype=float))

    def start(self, tau):
        return np.linalg.solve(self.k_theta, tau)

    def residual(self, dtheta, tau):
        return dtheta @ self.k_theta.T - tau  # (..., n): also for stacks of rows

    def residual_jacobian(self, dtheta, tau, k_c):
        return self.k_theta - k_c

    def tangent_stiffness(self, tau):
        return self.k_theta


@dataclass
class SpringLaw(JointLaw):
    """Diagonal law ``dtheta_j = c_j tau_j (1 + beta_j |tau_j|) + b_j tanh(tau_j / s_j)``.

    Attributes (arrays over the compliant joints)
    ----------
    compliance
        ``c = 1 / k`` (rad/(N.m), m/N).
    beta
        Softening (> 0) or hardening (< 0) coefficient (1/(N.m), 1/N).
    backlash
        Lost-motion half-width ``b`` (rad, m).
    smoothing
        Torque ``s`` over which the dead band is smoothed (N.m, N).
    """

    compliance: np.ndarray
    beta: np.ndarray
    backlash: np.ndarray
    smoothing: np.ndarray

    @classmethod
    def of_stiffness(cls, k: np.ndarray) -> SpringLaw:
        """Linear springs of stiffnesses ``k``."""
        k = np.asarray(k, dtype=float)
        zero = np.zeros_like(k)
        return cls(1.0 / k, zero, zero.copy(), np.ones_like(k))

    @property
    def linear(self) -> bool:
        """Whether the law is ``dtheta = c tau``."""
        return not self.nonlinear_joints().size

    def __call__(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Deflections and their derivatives w.r.t. the torques, both shaped like ``tau``
        (..., n): the linear part ``c tau`` plus :meth:`_remainder`."""
        phi, slope = self._remainder(tau, slice(None))
        value, compliance = linear(self.compliance, tau)
        return value + phi, compliance + slope

    def nonlinear_joints(self) -> np.ndarray:
        """Indices of the joints whose law is not ``c tau`` (``beta`` or ``b`` non-zero)."""
        return np.flatnonzero((self.beta != 0.0) | (self.backlash != 0.0))

    def _remainder(self, tau: np.ndarray, joints: np.ndarray | slice
                   ) -> tuple[np.ndarray, np.ndarray]:
        """``phi(tau) = c beta tau |tau| + b tanh(tau / s)`` on ``joints`` (the law less its
        linear part ``c tau``) and its derivative, for torques ``tau`` (..., len(joints))."""
        soft, soft_slope = softening(self.compliance[joints] * self.beta[joints], tau)
        lost, lost_slope = lost_motion(self.backlash[joints], tau, self.smoothing[joints])
        return soft + lost, soft_slope + lost_slope

    def frozen_deflection(self, tau0: np.ndarray, k_c: np.ndarray | None = None,
                          iterations: int = 30, tolerance: float | None = None) -> np.ndarray:
        """Deflections solving ``dtheta = f(tau0 + K_C dtheta)`` at frozen geometry, batched.

        The law is its linear part plus a remainder on the nonlinear joints ``N``:
        ``dtheta = c tau + E_N phi(tau_N)``. With ``A = I - K_C diag(c)`` the torque is
        ``tau = a + G phi(tau_N)``, ``a = A^-1 tau0`` (the linear springs' torque) and
        ``G = A^-1 K_C E_N``, so Newton runs on the ``|N|`` torques of the nonlinear joints,
        ``t = a_N + G_N phi(t)``, from the linear springs' ``t = a_N``: one batched solve of
        ``A`` per call, then ``|N| x |N|`` steps (scalar ones for a single nonlinear joint).

        Parameters
        ----------
        tau0
            (..., n) torques ``J^T W`` of the unloaded pose (N.m, N).
        k_c
            (..., n, n) ``K_C`` there (N.m/rad), or ``None`` (conventional:
            ``dtheta = f(tau0)``).
        iterations
            Newton steps on the nonlinear joints' torques (none when the law is linear: the
            linear springs' answer solves it exactly).
        tolerance
            Stop early once every Newton residual is below this times the largest of those
            torques; ``None`` runs every step (the result is then a smooth function of the
            law's parameters, as a least-squares fit needs).

        Returns
        -------
        np.ndarray
            (..., n) deflections (rad, m).
        """
        if k_c is None:
            return self(tau0)[0] if not self.linear else self.compliance * tau0
        joints = self.nonlinear_joints()
        n = tau0.shape[-1]
        a_mat = np.eye(n) - k_c * self.compliance[..., None, :]
        rhs = np.concatenate([tau0[..., :, None], k_c[..., :, joints]], axis=-1)
        sol = np.linalg.solve(a_mat, rhs)
        tau_linear = sol[..., 0]
        if not joints.size:
            return self.compliance * tau_linear
        g = sol[..., 1:]
        g_n = g[..., joints, :]
        a_n = tau_linear[..., joints]
        t = a_n
        for _ in range(iterations):
            phi, slope = self._remainder(t, joints)
            residual = t - a_n - np.einsum("...ij,...j->...i", g_n, phi)
            if tolerance is not None and np.abs(residual).max() <= tolerance * max(
                    float(np.abs(t).max()), 1e-300):
                break
            if joints.size == 1:
                t = t - residual / (1.0 - g_n[..., 0] * slope)
            else:
                jac = np.eye(joints.size) - g_n * slope[..., None, :]
                t = t - np.linalg.solve(jac, residual[..., :, None])[..., :, 0]
        phi = self._remainder(t, joints)[0]
        dtheta = self.compliance * (tau_linear + np.einsum("...ij,...j->...i", g, phi))
        dtheta[..., joints] += phi
        return dtheta

    def deflection_tangent(self, tau0: np.ndarray, k_c: np.ndarray | None,
                           dtheta: np.ndarray, d_compliance: np.ndarray, d_beta: np.ndarray,
                           d_backlash: np.ndarray) -> np.ndarray:
        """Derivatives of :meth:`frozen_deflection`'s ``dtheta`` along changes of the law.

        Implicit function theorem on ``dtheta = f(tau0 + K_C dtheta)``:
        ``(I - diag(f'(tau)) K_C) d dtheta = df/dlaw``, with
        ``df/dc = tau (1 + beta |tau|)``, ``df/dbeta = c tau |tau|``,
        ``df/db = tanh(tau / s)`` joint by joint (``K_C = None``: ``d dtheta = df/dlaw``).

        Parameters
        ----------
        tau0, k_c
            As for :meth:`frozen_deflection`.
        dtheta
            (..., n) its solution.
        d_compliance, d_beta, d_backlash
            (P, n) changes of ``c``, ``beta`` and ``b`` per unit of each of ``P`` parameters.

        Returns
        -------
        np.ndarray
            (..., n, P) derivatives of the deflections.
        """
        tau = tau0 if k_c is None else tau0 + np.einsum("...ab,...b->...a", k_c, dtheta)
        square = softening_column(tau)
        rhs = ((tau + self.beta * square)[..., :, None] * d_compliance.T
               + (self.compliance * square)[..., :, None] * d_beta.T
               + lost_motion_column(tau, self.smoothing)[..., :, None] * d_backlash.T)
        if k_c is None:
            return rhs
        slope = self(tau)[1]
        return np.linalg.solve(np.eye(tau.shape[-1]) - slope[..., :, None] * k_c, rhs)

    def start(self, tau):
        return self(tau)[0]

    def residual(self, dtheta, tau):
        return dtheta - self(tau)[0]

    def residual_jacobian(self, dtheta, tau, k_c):
        return np.eye(len(dtheta)) - self(tau)[1][:, None] * k_c

    def tangent_stiffness(self, tau):
        return np.diag(1.0 / self(tau)[1])


def as_joint_law(law: JointLaw | np.ndarray) -> JointLaw:
    """A joint law, or linear springs of a (n, n) stiffness matrix."""
    return law if isinstance(law, JointLaw) else LinearSprings(law)


def tangent_equilibrium(law: JointLaw | np.ndarray, tau0: np.ndarray, k_c: np.ndarray,
                        iterations: int = 30) -> np.ndarray:
    """Deflection ``dtheta`` solving ``dtheta = f(tau0 + K_C dtheta)`` (frozen geometry).

    The enhanced model of a joint law: ``tau0 = J^T W`` and ``K_C`` at the unloaded pose. For
    linear springs it is ``(K_theta - K_C)^-1 tau0`` (A&S eq. 10); a :class:`SpringLaw` runs
    :meth:`SpringLaw.frozen_deflection`; any other law, Newton on its residual.
    """
    law = as_joint_law(law)
    if isinstance(law, LinearSprings):
        return np.linalg.solve(law.k_theta - k_c, tau0)
    if isinstance(law, SpringLaw):
        return law.frozen_deflection(tau0, k_c, iterations, tolerance=1e-14)
    dtheta = law.start(tau0)
    scale = max(float(np.abs(law.residual(np.zeros_like(tau0), tau0)).max()), 1e-300)
    for _ in range(iterations):
        tau = tau0 + k_c @ dtheta
        g = law.residual(dtheta, tau)
        if np.abs(g).max() <= 1e-14 * scale:
            break
        dtheta = dtheta - np.linalg.solve(law.residual_jacobian(dtheta, tau, k_c), g)
    return dtheta


@dataclass
class Equilibrium:
    """Deflected equilibrium of a loaded robot.

    Attributes
    ----------
    q
        Full configuration at equilibrium (loops closed).
    dtheta
        Compliant-joint deflection ``theta - theta_0`` (rad or m).
    dx
        Target displacement (3,) in the base frame (m).
    rotation
        Small rotation vector (3,) of the target frame, base axes (rad).
    iterations
        Newton iterations used.
    torque
        Compliant-joint torques ``J(theta)^T W`` at equilibrium (N.m or N).
    position
        Target position at equilibrium, base frame (m).
    """

    q: np.ndarray
    dtheta: np.ndarray
    dx: np.ndarray
    rotation: np.ndarray
    iterations: int
    torque: np.ndarray
    position: np.ndarray


def deflected_configuration(robot: Robot, q0: np.ndarray, dtheta: np.ndarray,
                            seed: np.ndarray) -> np.ndarray:
    """Configuration with the compliant joints moved by ``dtheta`` from ``q0``, loops closed.

    ``seed`` is a nearby closed configuration whose passive joints start the closure.
    """
    return deflected_configurations(robot, q0[None], np.asarray(dtheta)[None], seed[None])[0]


def deflected_configurations(robot: Robot, q0: np.ndarray, dtheta: np.ndarray,
                             seed: np.ndarray) -> np.ndarray:
    """:func:`deflected_configuration` of (m, nq) configurations ``q0`` and ``seed`` and (m, n)
    deflections ``dtheta``: (m, nq) configurations, loops closed."""
    model = robot.model
    dv = np.asarray(dtheta) @ compliant_projection(robot).T  # followers, couplings move too
    target = np.array([pin.integrate(model, a, b) for a, b in zip(q0, dv, strict=True)])
    if robot.loop.is_open_chain:
        return target
    # keep the coordinates from target, the passive joints from the seed, then close
    q = seed.copy()
    for j in robot.coordinate_joints:
        joint = model.joints[model.getJointId(j)]
        q[:, joint.idx_q: joint.idx_q + joint.nq] = target[:, joint.idx_q: joint.idx_q + joint.nq]
    return np.array([robot.loop.close(model, robot.data, row) for row in q])


def solve_equilibrium(
    robot: Robot,
    q0: np.ndarray,
    k_theta: JointLaw | np.ndarray,
    load: np.ndarray,
    tolerance: float = 1e-12,
    max_iterations: int = 60,
    preload: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None,
) -> Equilibrium:
    """Exact deflection of ``robot`` from the unloaded configuration ``q0`` under a dead load.

    Parameters
    ----------
    robot
        The robot.
    q0
        Unloaded full configuration (loops closed).
    k_theta
        The joint law: a (n, n) joint stiffness matrix (SI, :class:`LinearSprings`) or any
        :class:`JointLaw` (e.g. :class:`SpringLaw` with nonlinear springs and backlash).
    load
        Force (3,) N or wrench (6,) N, N.m at the target, base axes.
    tolerance
        Convergence on the law's residual ``r(dtheta, tau)``, per joint relative to the size of
        the terms that form it, plus a floor at the round-off of the largest of them:
        ``|r_i| <= tolerance * s_i + 16 eps max_j s_j`` (:func:`residual_scale`). Not relative
        to its value at zero deflection, ``|J^T W|``, which vanishes when the load runs along
        the arm while its round-off does not.
    max_iterations
        Newton iterations allowed.
    preload
        A configuration-dependent joint torque besides the load (the robot's weight, a
        spring compensator): ``preload(q) -> (tau_p (n,), d tau_p / d theta (n, n))`` over the
        compliant joints. The law then balances ``J^T W + tau_p(theta)`` and the tangent is
        ``K_t - K_C - d tau_p / d theta``. ``q0`` stays the *commanded* pose: with
        ``load = 0`` the result is the unloaded equilibrium under the preload.

    Raises
    ------
    ConvergenceError
        If Newton's method does not converge (the load may exceed the buckling load), or a
        closed-loop robot's loops close nowhere along a step, however damped (the load
        carries the mechanism out of their reach).
    UnstableEquilibriumError
        If the tangent stiffness becomes singular on the way, or the equilibrium found is
        unstable (K_theta - K_C not positive definite there): the load buckles the robot.
    """
    q0 = full_configuration(robot, q0)
    law = _joint_law(robot, k_theta)
    wrench = as_wrench(load)
    float_array(tolerance, "tolerance", "a relative tolerance > 0", ndim=0)
    base = target_state(robot, q0)
    tau0 = base.jacobian.T @ wrench
    if preload is not None:
        tau0 = tau0 + preload(q0)[0]
    q, dtheta, state, tau, k_c, iterations = _newton(robot, law, q0, tau0, wrench, preload,
                                                     tolerance, max_iterations)
    _check_stable(law, tau, k_c)
    rot = pin.log3(state.rotation @ base.rotation.T)
    return Equilibrium(q, dtheta, state.position - base.position, rot, iterations, tau,
                       state.position.copy())


def _newton(robot: Robot, law: JointLaw, q0: np.ndarray, tau0: np.ndarray, wrench: np.ndarray,
            preload: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]] | None,
            tolerance: float, max_iterations: int
            ) -> tuple[np.ndarray, np.ndarray, TargetState, np.ndarray, np.ndarray, int]:
    """Newton's method on the law's residual from ``law.start(tau0)`` (``tau0``: the joint
    torques at ``q0``, N.m or N), the loops closed at each step.

    Returns
    -------
    The configuration, deflection (rad, m), target state, joint torques (N.m, N) and K_C (with
    the preload's derivative) at the converged point, and the iterations used.

    Raises
    ------
    ConvergenceError, UnstableEquilibriumError
        As :func:`solve_equilibrium`: no convergence, loops that do not close, a singular
        tangent.
    """
    dtheta = law.start(tau0)
    q, closed = q0, np.zeros_like(dtheta)  # the last deflection whose loops closed, at q
    iterations = 0
    for iterations in range(1, whole_number(max_iterations, "max_iterations") + 1):  # noqa: B007
        q, dtheta = _closed_deflection(robot, q0, dtheta, q, closed, lambda: _raise_if_buckled(
            robot, law, q0, tau0, wrench, f"the loops of {robot.title} do not close on the way"))
        closed = dtheta
        state = target_state(robot, q, wrench)
        tau = state.jacobian.T @ wrench
        k_c = state.k_c
        if preload is not None:
            tau_p, k_p = preload(q)
            tau, k_c = tau + tau_p, k_c + k_p
        residual = law.residual(dtheta, tau)
        if converged(residual, residual_scale(law, dtheta, state.jacobian, wrench), tolerance):
            break
        try:
            step = np.linalg.solve(law.residual_jacobian(dtheta, tau, k_c), -residual)
        except np.linalg.LinAlgError as exc:
            raise UnstableEquilibriumError(
                "the tangent stiffness K_theta - K_C is singular on the way to the equilibrium: "
                "the load buckles the robot; reduce the load or stiffen the joints") from exc
        dtheta = dtheta + step
    else:
        _raise_if_buckled(robot, law, q0, tau0, wrench, "the exact equilibrium did not "
                          f"converge in {max_iterations} iterations")
        raise ConvergenceError(
            f"the exact equilibrium did not converge in {max_iterations} iterations "
            f"(residual {np.abs(residual).max():.3g}): the load may exceed the buckling load; "
            "reduce it or raise max_iterations"
        )
    return q, dtheta, state, tau, k_c, iterations


def _check_stable(law: JointLaw, tau: np.ndarray, k_c: np.ndarray) -> None:
    """Raise :class:`UnstableEquilibriumError` when the tangent ``K_theta - K_C`` (N.m/rad,
    N/m) at the equilibrium's joint torques ``tau`` (N.m, N) is not positive definite."""
    tangent = tangent_joint_stiffness(law.tangent_stiffness(tau), k_c)
    lowest = np.linalg.eigvalsh(0.5 * (tangent + tangent.T))[0]
    if lowest <= 0:
        raise UnstableEquilibriumError(
            f"the equilibrium found under this load is unstable (K_theta - K_C has the eigenvalue "
            f"{lowest:.3g} there): the load exceeds the buckling load of the robot in this "
            "configuration; reduce the load or stiffen the joints"
        )


def _raise_if_buckled(robot: Robot, law: JointLaw, q0: np.ndarray, tau0: np.ndarray,
                      wrench: np.ndarray, what: str) -> None:
    """Raise :class:`UnstableEquilibriumError` (``what`` saying what failed) when the tangent
    ``K_theta - K_C`` under ``wrench`` is already indefinite at the unloaded pose ``q0``."""
    start = tangent_joint_stiffness(law.tangent_stiffness(tau0),
                                    target_state(robot, q0, wrench).k_c)
    lowest = np.linalg.eigvalsh(0.5 * (start + start.T))[0]
    if lowest <= 0:
        raise UnstableEquilibriumError(
            f"{what} and K_theta - K_C under this load is already indefinite at the unloaded "
            f"pose (eigenvalue {lowest:.3g}): loads this large exceed the buckling load; "
            "reduce it or stiffen the joints")


def _closed_deflection(robot: Robot, q0: np.ndarray, dtheta: np.ndarray, q: np.ndarray,
                       last: np.ndarray, buckled: Callable[[], None]
                       ) -> tuple[np.ndarray, np.ndarray]:
    """The configuration at the deflection ``dtheta`` (rad, m) from ``q0``, loops closed from
    ``q`` (the closed configuration at the deflection ``last``), and that deflection; where the
    loops do not close there (a Newton step past their reach, on a soft mechanism near a
    singular pose), the step from ``last`` is halved up to :data:`_HALVINGS` times (a damped
    Newton step). An open chain, or a step whose loops close, is taken as it is.

    Raises
    ------
    UnstableEquilibriumError
        If the loops close at none of those deflections and ``buckled()`` finds the load past
        the buckling load.
    ConvergenceError
        If the loops close at none of those deflections otherwise: the load carries the
        mechanism out of their reach.
    """
    for _ in range(_HALVINGS + 1):
        try:
            return deflected_configuration(robot, q0, dtheta, q), dtheta
        except LoopClosureError as exc:
            error = exc
            dtheta = last + 0.5 * (dtheta - last)
    buckled()
    raise ConvergenceError(
        f"the loops of {robot.title} do not close at the deflection this load calls for, nor "
        f"at {0.5 ** _HALVINGS:.1e} of the way to it from the last that closed (largest joint "
        f"deflection {np.abs(last).max():.3g} rad or m): the load carries the mechanism out of "
        f"its loops' reach at this pose ({error}); reduce the load or stiffen the joints"
    ) from error


def _joint_law(robot: Robot, k_theta: JointLaw | np.ndarray) -> JointLaw:
    """``k_theta`` of :func:`solve_equilibrium` as a joint law, checked where it enters: a
    :class:`JointLaw`, or the (n, n) joint stiffness matrix of the compliant joints."""
    if not isinstance(k_theta, JointLaw):
        n = robot.n_compliant
        needed = (f"the ({n}, {n}) joint stiffness matrix of {robot.title} (N.m/rad, N/m "
                  "prismatic; np.diag(k) of one per compliant joint) or a JointLaw")
        if np.atleast_2d(float_array(k_theta, "k_theta", needed)).shape != (n, n):
            raise wrong_argument("k_theta", k_theta, needed)
    return as_joint_law(k_theta)


def converged(residual: np.ndarray, scale: np.ndarray, tolerance: float) -> np.ndarray:
    """Whether the law's residual ``r`` (..., n) is zero to ``tolerance``:
    ``|r_i| <= tolerance * s_i + 16 eps max_j s_j`` for every joint, with ``s``
    (:func:`residual_scale`) the size of its terms; one answer per row of a stack."""
    floor = _ROUND_OFF * scale.max(axis=-1, keepdims=True)
    return np.all(np.abs(residual) <= tolerance * scale + floor, axis=-1)


def torque_scale(jacobian: np.ndarray, wrench: np.ndarray) -> np.ndarray:
    """Per joint, the size of the load's torque before cancellation (N.m, N).

    ``|v_i| |F| + |omega_i| |M|`` with ``[v_i; omega_i]`` the i-th Jacobian column: the lever
    times the load, the bound of ``|J_i^T W|`` that does not vanish when the load runs along
    the arm (a 1 m lever under 100 N gives ``J^T W`` ~ 1e-14 N.m, the round-off of 100 N.m).
    Also for stacks: (..., 6, n) Jacobians and (..., 6) wrenches give (..., n).
    """
    return (np.linalg.norm(jacobian[..., :3, :], axis=-2)
            * np.linalg.norm(wrench[..., :3], axis=-1)[..., None]
            + np.linalg.norm(jacobian[..., 3:, :], axis=-2)
            * np.linalg.norm(wrench[..., 3:], axis=-1)[..., None])


def residual_scale(law: JointLaw, dtheta: np.ndarray, jacobian: np.ndarray,
                   wrench: np.ndarray) -> np.ndarray:
    """Per joint, the size of the terms of the law's residual ``r(dtheta, tau)``.

    ``|r(|dtheta|, 0)| + |r(0, torque_scale)|``: for linear springs ``|K_theta| |dtheta|`` plus
    the lever times the load (N.m, N); for a :class:`SpringLaw` ``|dtheta| + |f(torque_scale)|``
    (rad, m). Per joint, so that a stiff joint (1e10) does not loosen the test of a soft one
    (1e-2). Zero only for a zero load at rest.
    """
    zero = np.zeros_like(dtheta)
    return (np.abs(law.residual(np.abs(dtheta), zero))
            + np.abs(law.residual(zero, torque_scale(jacobian, wrench))))


@dataclass
class Departure:
    """How the linear predictions depart from the exact deflection as the load grows.

    Attributes
    ----------
    scales
        Load multipliers (dimensionless) applied to the reference load.
    exact, conventional, enhanced
        (m, 3) target displacements (m) at each scale.
    rate_conventional, rate_enhanced
        Fitted exponent p of ``|error| ~ scale^p`` (theory: 2 for both).
    """

    scales: np.ndarray
    exact: np.ndarray
    conventional: np.ndarray
    enhanced: np.ndarray
    rate_conventional: float
    rate_enhanced: float


def linear_departure(robot: Robot, q0: np.ndarray, k_theta: np.ndarray, load: np.ndarray,
                     scales: np.ndarray | None = None) -> Departure:
    """Compare the conventional and enhanced linear predictions with the exact equilibrium.

    The error of both linear predictions grows as the square of the load: the enhanced one
    carries K_C (first order in the load) but not the second-order kinematics of the
    deflection; the conventional one misses both.
    """
    wrench = as_wrench(load)
    scales = np.geomspace(1e-2, 1.0, 7) if scales is None else np.asarray(scales, dtype=float)
    exact_rows, conv_rows, enh_rows = [], [], []
    for s in scales:
        state = target_state(robot, q0, s * wrench)
        exact_rows.append(solve_equilibrium(robot, q0, k_theta, s * wrench).dx)
        conv_rows.append(_linear(state, k_theta, "conventional"))
        enh_rows.append(_linear(state, k_theta, "enhanced"))
    exact, conv, enh = np.array(exact_rows), np.array(conv_rows), np.array(enh_rows)

    def rate(pred):
        err = np.linalg.norm(pred - exact, axis=1)
        ok = err > 0
        return float(np.polyfit(np.log(scales[ok]), np.log(err[ok]), 1)[0])

    return Departure(scales, exact, conv, enh, rate(conv), rate(enh))


def _linear(state, k_theta: np.ndarray, formulation: str) -> np.ndarray:
    """Linear displacement of the target position (m): J (K_theta - K_C)^-1 J^T W."""
    tangent = tangent_joint_stiffness(k_theta, state.k_c, formulation)
    return state.jacobian[:3] @ np.linalg.solve(tangent, state.jacobian.T @ state.wrench)
