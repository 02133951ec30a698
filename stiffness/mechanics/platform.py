"""Six-dimensional stiffness of spring-loaded parallel platforms (Zefran & Kumar).

The platform is a closed-loop robot whose target is the platform frame and whose springs are
its legs (built by :mod:`stiffness.robot.platform`, or any robot with loops). Under the wrench
that holds the platform against springs with rest lengths other than the current ones
(:func:`stiffness.mechanics.wrench.holding_wrench`), the twist-basis stiffness is asymmetric;
:func:`lie_bracket_term` predicts its antisymmetric part from that wrench (eq. 34);
:func:`stiffness_map` maps the stiffness over platform poses, each pose reached by
:func:`solve_pose` (loop-closed inverse kinematics of the target frame). See
docs/spatial-loops.md.

Spatial vectors follow Pinocchio: twists ``[v; omega]``, wrenches ``[F; M]`` (N, N.m).
Units: SI (m, N, rad).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from stiffness.errors import ConvergenceError, StiffnessError
from stiffness.mechanics.formulation import (
    TargetState,
    joint_connection_stiffness,
    target_state,
    target_states,
    twist_basis_stiffness,
)
from stiffness.mechanics.wrench import body_wrench, holding_wrench
from stiffness.robot import kinematics
from stiffness.robot.robot import Robot


def lie_bracket_term(wrench_body: np.ndarray) -> np.ndarray:
    """Antisymmetric part of the twist-basis stiffness predicted by Zefran & Kumar eq. 34.

    ``K_a[i, j] - K_a[j, i] = [L_j, L_i](Phi) = <W, ad(e_j) e_i>`` for left-invariant basis
    twists ``e_i`` (Pinocchio order [v; omega]) and ``W`` the holding wrench in body
    components (``L_k(Phi) = W_k``). Units: N.m (rows/columns mixing linear and angular: N).

    Returns
    -------
    numpy.ndarray
        (6, 6) matrix ``B`` with ``B[i, j] = W . (e_j x e_i)`` (``x`` the motion cross
        product), Pinocchio order.
    """
    wrench = pin.Force(np.asarray(wrench_body, dtype=float))
    basis = [pin.Motion(e) for e in np.eye(6)]
    return np.array([[wrench.dot(basis[j].cross(basis[i])) for j in range(6)]
                     for i in range(6)])


def jacobian_derivative(robot: Robot, q: np.ndarray) -> np.ndarray:
    """Derivative of the closed-loop target Jacobian, ``D[k, a, b] = dJ[k, a] / d theta_b``.

    ``J`` is the (6, n) Jacobian w.r.t. the compliant joints, rows [v; omega], base axes at the
    target (loops closed). Row ``k`` is the complementary stiffness of the unit wrench ``e_k``:
    ``K_C(W) = sum_k W_k D[k]``. Units: m/rad^2 (m/m^2 for prismatic joints), rad/rad^2.
    """
    return np.stack([s.k_c for s in target_states(robot, q, np.eye(6))])


def solve_pose(robot: Robot, pose: pin.SE3, seed: np.ndarray, max_iterations: int = 50,
               tolerance: float = 1e-12) -> np.ndarray:
    """Closed configuration placing the target frame at ``pose`` (loop-closed inverse kinematics).

    Gauss-Newton on all joints for the loop residual and ``log6(pose^-1 oMt)``, from ``seed``
    (a configuration near the wanted assembly branch).

    Raises
    ------
    StiffnessError
        If the pose is not reached (outside the workspace, or a singular pose).
    """
    model, data, fid = robot.model, robot.data, robot.target_frame_id
    q = np.asarray(seed, dtype=float).copy()
    for _ in range(max_iterations):
        kinematics.update_first_order(model, data, q)
        err_m = pose.actInv(data.oMf[fid])
        err = pin.log6(err_m).vector
        res = np.concatenate([robot.loop.residual(model, data), err])
        if np.linalg.norm(res) < tolerance:
            return q
        jt = pin.Jlog6(err_m) @ pin.getFrameJacobian(model, data, fid, pin.ReferenceFrame.LOCAL)
        jac = np.vstack([robot.loop.jacobian(model, data), jt])
        q = pin.integrate(model, q, -np.linalg.lstsq(jac, res, rcond=1e-10)[0])
    raise ConvergenceError(
        f"the target frame of {robot.title} cannot reach the pose {pose.translation.round(6)} m "
        f"(residual {np.linalg.norm(res):.3g} after {max_iterations} iterations): outside "
        "the workspace, or a singular pose"
    )


@dataclass
class PlatformStiffness:
    """Six-dimensional stiffness of a platform at one configuration (Pinocchio order [v; w]).

    Attributes
    ----------
    state
        Kinematics and K_C under the holding wrench.
    k_joint
        Joint-space connection ``J^-T K_theta J^-1`` (symmetric), target body axes.
    k_twist
        Twist basis ``J^-T (K_theta - K_C^tw) J^-1`` (asymmetric under load), body axes.
    wrench_body
        Holding wrench in body axes [F; M] (N, N.m).
    bracket
        ``lie_bracket_term(wrench_body)``: the predicted ``k_twist - k_twist^T``.
    """

    state: TargetState
    k_joint: np.ndarray
    k_twist: np.ndarray
    wrench_body: np.ndarray
    bracket: np.ndarray


def platform_stiffness(robot: Robot, q: np.ndarray, k_theta: np.ndarray,
                       wrench: np.ndarray | None = None,
                       rest: np.ndarray | list[float] | None = None) -> PlatformStiffness:
    """Both Zefran-Kumar stiffnesses at a closed configuration.

    The load is ``wrench`` (dead, [F; M] base axes at the target), or else the wrench holding
    the target against springs at rest values ``rest``, or else zero.
    """
    if wrench is None:
        wrench = np.zeros(6) if rest is None else holding_wrench(robot, q, k_theta, rest)
    state = target_state(robot, q, wrench)
    w_body = body_wrench(state)
    return PlatformStiffness(state, joint_connection_stiffness(state, k_theta),
                             twist_basis_stiffness(state, k_theta), w_body,
                             lie_bracket_term(w_body))


@dataclass
class StiffnessMap:
    """Platform stiffness over a list of target poses.

    Attributes
    ----------
    positions
        (m, 3) target positions (m).
    leg_lengths
        (m, n) compliant-joint coordinates reaching them (m).
    translational_min, translational_max
        (m,) extreme principal stiffnesses (N/m) of the translational block of the compliance
        inverse, ``(C_vv)^-1`` with ``C = K_joint^-1``: the stiffness against a pure force with
        the platform free to rotate.
    rotational_min
        (m,) smallest principal stiffness of ``(C_ww)^-1`` (N.m/rad): against a pure moment.
    asymmetry
        (m,) ``||K_twist - K_twist^T|| / ||K_twist||`` (Frobenius) under the load.
    bracket_error
        (m,) ``max |K_twist - K_twist^T - bracket|``: the eq. 34 check at every pose (SI).
    condition
        (m,) condition number of the closed-loop Jacobian.
    """

    positions: np.ndarray
    leg_lengths: np.ndarray
    translational_min: np.ndarray
    translational_max: np.ndarray
    rotational_min: np.ndarray
    asymmetry: np.ndarray
    bracket_error: np.ndarray
    condition: np.ndarray


def stiffness_map(robot: Robot, poses: list[pin.SE3], k_theta: np.ndarray,
                  wrench: np.ndarray | None = None, seed: np.ndarray | None = None
                  ) -> StiffnessMap:
    """Stiffness of a platform's target over poses (visit neighbours in sequence).

    Each pose is reached by :func:`solve_pose` seeded with the previous solution (first:
    ``seed``, a closed configuration, default the robot's shipped configuration ``q_SI``); the
    load is the dead ``wrench`` ([F; M] base axes, default zero).

    Raises
    ------
    StiffnessError
        Without a seed for a robot that ships no ``q_SI``; on an unreachable pose.
    """
    if seed is None:
        if "q_SI" not in robot.defaults:
            raise StiffnessError(f"{robot.title} ships no q_SI: give a closed seed configuration")
        seed = robot.configuration(np.asarray(robot.defaults["q_SI"], dtype=float))
    q = seed
    out: dict[str, list] = {k: [] for k in StiffnessMap.__dataclass_fields__}
    for pose in poses:
        q = solve_pose(robot, pose, q)
        ps = platform_stiffness(robot, q, k_theta, wrench=wrench)
        comp = np.linalg.inv(ps.k_joint)
        trans = np.linalg.eigvalsh(np.linalg.inv(comp[:3, :3]))
        rot = np.linalg.eigvalsh(np.linalg.inv(comp[3:, 3:]))
        skew = ps.k_twist - ps.k_twist.T
        out["positions"].append(pose.translation.copy())
        out["leg_lengths"].append(robot.coordinates_of(q)[robot.compliant_in_coordinates])
        out["translational_min"].append(trans[0])
        out["translational_max"].append(trans[-1])
        out["rotational_min"].append(rot[0])
        out["asymmetry"].append(np.linalg.norm(skew) / np.linalg.norm(ps.k_twist))
        out["bracket_error"].append(np.abs(skew - ps.bracket).max())
        out["condition"].append(np.linalg.cond(ps.state.jacobian))
    return StiffnessMap(**{k: np.array(v) for k, v in out.items()})
