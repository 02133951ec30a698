"""Exact elastostatic equilibria of many loaded configurations at once, linear springs.

:func:`solve_equilibria` is :func:`stiffness.mechanics.equilibrium.solve_equilibrium` with a
joint stiffness matrix ``K_theta`` over (m,) rows of configurations and dead wrenches: Newton's
method on ``K_theta dtheta = J(theta)^T W`` with the tangent ``K_theta - K_C(theta)`` (A&S eq. 9),
the same start, convergence test (:func:`stiffness.mechanics.equilibrium.converged`) and
stability test, every row iterated until it converges. Per iteration the rows still running
cost one pass of :func:`stiffness.batch.kernels.batch_kinematics` (three Pinocchio calls per
configuration of an open chain) and a few stacked NumPy operations, instead of ~100 us of
Python per row in the one-at-a-time API.

Units: SI (m, N, rad; ``K_theta`` N.m/rad or N/m; K_C N.m/rad).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NoReturn

import numpy as np
import pinocchio as pin

from stiffness.batch.kernels import BatchKinematics, batch_kinematics
from stiffness.errors import ConvergenceError, StiffnessError, UnstableEquilibriumError
from stiffness.mechanics.equilibrium import (
    LinearSprings,
    converged,
    deflected_configurations,
    residual_scale,
)
from stiffness.mechanics.formulation import as_wrench, target_state
from stiffness.robot.robot import Robot


@dataclass
class Equilibria:
    """Deflected equilibria of (m,) loaded configurations.

    Attributes
    ----------
    q
        (m, nq) full configurations at equilibrium (loops closed).
    dtheta
        (m, n) compliant-joint deflections ``theta - theta_0`` (rad or m).
    dx
        (m, 3) target displacements in the base frame (m).
    rotation
        (m, 3) small rotation vectors of the target frame, base axes (rad).
    iterations
        (m,) Newton iterations used by each row.
    torque
        (m, n) compliant-joint torques ``J(theta)^T W`` at equilibrium (N.m or N).
    jacobian
        (m, 6, n) target Jacobian at equilibrium, rows [v; omega].
    k_c
        (m, n, n) ``K_C`` of each row's wrench at equilibrium (N.m/rad).
    """

    q: np.ndarray
    dtheta: np.ndarray
    dx: np.ndarray
    rotation: np.ndarray
    iterations: np.ndarray
    torque: np.ndarray
    jacobian: np.ndarray
    k_c: np.ndarray


def unloaded_kinematics(robot: Robot, q0: np.ndarray) -> BatchKinematics:
    """Kinematics of the unloaded configurations ``q0`` (m, nq) that :func:`solve_equilibria`
    starts from (to compute once when the same rows are solved many times)."""
    return batch_kinematics(robot, q0, pose=True)


def solve_equilibria(robot: Robot, q0: np.ndarray, k_theta: np.ndarray, wrenches: np.ndarray,
                     base: BatchKinematics | None = None,
                     tolerance: float = 1e-12, max_iterations: int = 60) -> Equilibria:
    """Exact deflections of ``robot`` from (m, nq) unloaded configurations under dead loads.

    Parameters
    ----------
    robot
        The robot (its ``data`` is used as scratch space).
    q0
        (m, nq) unloaded full configurations (loops closed).
    k_theta
        (n, n) joint stiffness matrix (N.m/rad, N/m) of the compliant joints.
    wrenches
        (m, 3) forces (N) or (m, 6) wrenches [F; M] (N, N.m) at the target, base axes.
    base
        :func:`unloaded_kinematics` of ``q0``, if already computed.
    tolerance, max_iterations
        As in :func:`stiffness.mechanics.equilibrium.solve_equilibrium`, per row.

    Raises
    ------
    ConvergenceError
        If a row does not converge (the load may exceed its buckling load).
    UnstableEquilibriumError
        If the tangent stiffness of a row becomes singular on the way, or an equilibrium found
        is unstable (``K_theta - K_C`` not positive definite there).
    UndeterminedMotionError
        If a loop is singular at a deflected configuration.
    """
    q0 = np.atleast_2d(np.asarray(q0, dtype=float))
    wrench = np.atleast_2d(np.asarray(wrenches, dtype=float))
    if wrench.shape[1] != 6 or not np.all(np.isfinite(wrench)):  # forces, or a bad row named
        wrench = np.array([as_wrench(w) for w in wrench])
    law = LinearSprings(k_theta)
    kmat = law.k_theta
    base = unloaded_kinematics(robot, q0) if base is None else base
    if base.position is None or base.rotation is None:
        raise StiffnessError("the unloaded kinematics need the target pose: give "
                             "batch_kinematics(..., pose=True) as base")
    tau0 = np.einsum("mkn,mk->mn", base.jacobian, wrench)
    m, n = tau0.shape
    dtheta = np.linalg.solve(kmat, tau0.T).T  # the start K_theta^-1 J^T W of every row
    q = q0.copy()
    jac = np.empty((m, 6, n))
    k_c = np.empty((m, n, n))
    position = np.empty((m, 3))
    rotation = np.empty((m, 3, 3))
    iterations = np.zeros(m, dtype=int)
    running = np.arange(m)
    residual = np.zeros((m, n))
    for _ in range(max_iterations):
        q[running] = deflected_configurations(robot, q0[running], dtheta[running], q[running])
        kin = batch_kinematics(robot, q[running], pose=True)
        if not kin.valid.all():  # the one-pose API names the undetermined motion
            bad = running[np.flatnonzero(~kin.valid)[0]]
            target_state(robot, q[bad], wrench[bad])
        w = wrench[running]
        jac[running], position[running], rotation[running] = (kin.jacobian, kin.position,
                                                               kin.rotation)
        k_c[running] = np.einsum("mk,mkab->mab", w, kin.k_c_basis)
        iterations[running] += 1
        tau = np.einsum("mkn,mk->mn", kin.jacobian, w)
        r = law.residual(dtheta[running], tau)
        residual[running] = r
        done = converged(r, residual_scale(law, dtheta[running], kin.jacobian, w), tolerance)
        running, r = running[~done], r[~done]
        if not running.size:
            break
        try:
            step = np.linalg.solve(kmat - k_c[running], -r[..., None])[..., 0]
        except np.linalg.LinAlgError as exc:
            raise UnstableEquilibriumError(
                "the tangent stiffness K_theta - K_C is singular on the way to the equilibrium "
                "of a row: the load buckles the robot; reduce the load or stiffen the "
                "joints") from exc
        dtheta[running] += step
    if running.size:
        i = int(running[0])
        start_k_c = np.einsum("k,kab->ab", wrench[i], base.k_c_basis[i])
        _raise_unconverged(i, kmat - start_k_c, residual[i], max_iterations)
    _check_stable(kmat - k_c)
    rot = np.array([pin.log3(r @ r0.T) for r, r0 in zip(rotation, base.rotation, strict=True)])
    torque = np.einsum("mkn,mk->mn", jac, wrench)
    return Equilibria(q, dtheta, position - base.position, rot, iterations, torque, jac, k_c)


def _raise_unconverged(i: int, start_tangent: np.ndarray, residual: np.ndarray,
                       max_iterations: int) -> NoReturn:
    """Why row ``i`` did not converge: a load beyond buckling already at the unloaded pose
    (``start_tangent`` = K_theta - K_C there not positive definite), else too few iterations
    (``residual``: its last joint torque residual, N.m)."""
    lowest = _lowest_eigenvalue(start_tangent)
    if lowest <= 0:
        raise UnstableEquilibriumError(
            f"the exact equilibrium of row {i + 1} did not converge in {max_iterations} "
            f"iterations and K_theta - K_C under its load is already indefinite at the "
            f"unloaded pose (eigenvalue {lowest:.3g}): loads this large exceed the buckling "
            "load; reduce it or stiffen the joints")
    raise ConvergenceError(
        f"the exact equilibrium of row {i + 1} did not converge in {max_iterations} "
        f"iterations (residual {np.abs(residual).max():.3g}): the load may exceed the "
        "buckling load; reduce it or raise max_iterations")


def _check_stable(tangent: np.ndarray) -> None:
    """Raise :class:`UnstableEquilibriumError` naming the first row whose tangent stiffness
    K_theta - K_C (m, n, n) at its equilibrium is not positive definite."""
    lowest = _lowest_eigenvalue(tangent)
    if np.any(lowest <= 0):
        i = int(np.argmin(lowest))
        raise UnstableEquilibriumError(
            f"the equilibrium found under the load of row {i + 1} is unstable (K_theta - K_C "
            f"has the eigenvalue {lowest[i]:.3g} there): the load exceeds the buckling load of "
            "the robot in this configuration; reduce the load or stiffen the joints")


def _lowest_eigenvalue(tangent: np.ndarray) -> np.ndarray:
    """Lowest eigenvalue of the symmetric part of each (..., n, n) tangent stiffness."""
    return np.linalg.eigvalsh(0.5 * (tangent + np.swapaxes(tangent, -1, -2)))[..., 0]
