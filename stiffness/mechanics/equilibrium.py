"""Exact elastostatic equilibrium under a dead load, loops closed.

Solves ``K_theta (theta - theta_0) = J(theta)^T W`` for the compliant joints ``theta`` (the
stationary point of ``Pi = 1/2 (theta - theta_0)^T K_theta (theta - theta_0) - W . x(theta)``,
rigid joints held, passive loop joints following the closure) by Newton's method with the
tangent ``K_theta - K_C(theta)``. The linear predictions of :mod:`stiffness.mechanics.formulation`
are
truncations of this solution (see :func:`linear_departure`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from stiffness.errors import ConvergenceError, UnstableEquilibriumError
from stiffness.mechanics.formulation import as_wrench, tangent_joint_stiffness, target_state
from stiffness.model.robot import Robot


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
    """

    q: np.ndarray
    dtheta: np.ndarray
    dx: np.ndarray
    rotation: np.ndarray
    iterations: int


def deflected_configuration(robot: Robot, q0: np.ndarray, dtheta: np.ndarray,
                            seed: np.ndarray) -> np.ndarray:
    """Configuration with the compliant joints moved by ``dtheta`` from ``q0``, loops closed.

    ``seed`` is a nearby closed configuration whose passive joints start the closure.
    """
    dv = np.zeros(robot.model.nv)
    dv[robot.compliant_v] = dtheta
    target = pin.integrate(robot.model, q0, dv)
    if robot.loop is None:
        return target
    # keep the coordinates from target, the passive joints from the seed, then close
    q = seed.copy()
    for j in robot.coordinate_joints:
        joint = robot.model.joints[robot.model.getJointId(j)]
        q[joint.idx_q: joint.idx_q + joint.nq] = target[joint.idx_q: joint.idx_q + joint.nq]
    return robot.loop.close(robot.model, robot.data, q)


def solve_equilibrium(
    robot: Robot,
    q0: np.ndarray,
    k_theta: np.ndarray,
    load: np.ndarray,
    tolerance: float = 1e-12,
    max_iterations: int = 50,
) -> Equilibrium:
    """Exact deflection of ``robot`` from the unloaded configuration ``q0`` under a dead load.

    Parameters
    ----------
    robot
        The robot.
    q0
        Unloaded full configuration (loops closed).
    k_theta
        (n, n) joint stiffness (SI).
    load
        Force (3,) N or wrench (6,) N, N.m at the target, base axes.
    tolerance
        Convergence on the relative torque residual.

    Raises
    ------
    ConvergenceError
        If Newton's method does not converge (the load may exceed the buckling load).
    UnstableEquilibriumError
        If the tangent stiffness becomes singular on the way, or the equilibrium found is
        unstable (K_theta - K_C not positive definite there): the load buckles the robot.
    """
    wrench = as_wrench(load)
    base = target_state(robot, q0)
    dtheta = np.linalg.solve(k_theta, base.jacobian.T @ wrench)
    q = q0
    scale = max(np.abs(base.jacobian.T @ wrench).max(), 1e-300)
    iterations = 0
    for iterations in range(1, max_iterations + 1):  # noqa: B007 (used after the loop)
        q = deflected_configuration(robot, q0, dtheta, q)
        state = target_state(robot, q, wrench)
        residual = k_theta @ dtheta - state.jacobian.T @ wrench
        if np.abs(residual).max() <= tolerance * scale:
            break
        tangent = k_theta - state.k_c
        try:
            step = np.linalg.solve(tangent, -residual)
        except np.linalg.LinAlgError as exc:
            raise UnstableEquilibriumError(
                "the tangent stiffness K_theta - K_C is singular on the way to the equilibrium: "
                "the load buckles the robot; reduce the load or stiffen the joints") from exc
        dtheta = dtheta + step
    else:
        raise ConvergenceError(
            f"the exact equilibrium did not converge in {max_iterations} iterations "
            f"(residual {np.abs(residual).max():.3g}): the load may exceed the buckling load; "
            "reduce it or raise max_iterations"
        )
    tangent = tangent_joint_stiffness(k_theta, state.k_c)
    lowest = np.linalg.eigvalsh(0.5 * (tangent + tangent.T))[0]
    if lowest <= 0:
        raise UnstableEquilibriumError(
            f"the equilibrium found under this load is unstable (K_theta - K_C has the eigenvalue "
            f"{lowest:.3g} there): the load exceeds the buckling load of the robot in this "
            "configuration; reduce the load or stiffen the joints"
        )
    rot = pin.log3(state.rotation @ base.rotation.T)
    return Equilibrium(q, dtheta, state.position - base.position, rot, iterations)


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
    exact, conv, enh = [], [], []
    for s in scales:
        state = target_state(robot, q0, s * wrench)
        exact.append(solve_equilibrium(robot, q0, k_theta, s * wrench).dx)
        conv.append(_linear(state, k_theta, "conventional"))
        enh.append(_linear(state, k_theta, "enhanced"))
    exact, conv, enh = map(np.array, (exact, conv, enh))

    def rate(pred):
        err = np.linalg.norm(pred - exact, axis=1)
        ok = err > 0
        return float(np.polyfit(np.log(scales[ok]), np.log(err[ok]), 1)[0])

    return Departure(scales, exact, conv, enh, rate(conv), rate(enh))


def _linear(state, k_theta: np.ndarray, formulation: str) -> np.ndarray:
    """Linear displacement of the target position (m): J (K_theta - K_C)^-1 J^T W."""
    tangent = tangent_joint_stiffness(k_theta, state.k_c, formulation)
    return state.jacobian[:3] @ np.linalg.solve(tangent, state.jacobian.T @ state.wrench)
