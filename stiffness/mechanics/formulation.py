"""Stiffness formulations: Jacobian, complementary stiffness K_C, compliance, Cartesian K_X.

Conventions (docs/conventions.md):

* The load is a force ``F`` (N) or a wrench ``W = [F; M]`` (N, N.m) applied at the target and
  held fixed in the base frame (a dead load). Joint torques that hold it: ``tau = J^T W``.
* ``J`` is the target Jacobian with respect to the compliant joints, loops closed: rows
  ``[v (3); omega (3)]`` (Pinocchio order), base-frame axes at the target.
* ``K_C = d(J^T W) / d theta`` (A&S eq. 9), from Pinocchio's kinematic Hessians; for a closed
  loop, the reduced Hessian ``S^T (sum_k W_k d2x_k) S + sum_p tau_p d2q_p/dtheta2``
  (:mod:`stiffness.mechanics.closed_loop`, equal to the multiplier form
  ``S^T (sum_k W_k d2x_k - sum_j lambda_j d2c_j) S``).
* Compliance ``C = J (K_theta - K_C)^-1 J^T`` and ``K_X = C^-1`` (A&S eq. 10 when J is square).
  ``conventional`` sets ``K_C = 0`` (A&S eq. 8).
* Six-dimensional stiffness (Zefran & Kumar): ``joint`` connection ``J^-T K_theta J^-1``
  (symmetric); ``twist`` basis (left-invariant fields of the target frame, body axes)
  ``J_b^-T (K_theta - K_C^tw) J_b^-1`` with ``K_C^tw`` the derivative of ``J_b^T W_b`` at fixed body
  wrench (asymmetric under load).

Units: SI (m, N, rad; stiffness N/m, N.m/rad, N.m/rad for joints, N for K_C of a revolute joint
under a force: N.m/rad).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from stiffness.errors import (
    SingularConfigurationError,
    StiffnessError,
    UndeterminedMotionError,
    UnknownNameError,
    wrong_argument,
)
from stiffness.mechanics import closed_loop
from stiffness.robot import kinematics
from stiffness.robot.robot import Robot
from stiffness.units import float_array

FORMULATIONS = ("conventional", "enhanced")
DEFINITENESS_CLASSES = ("PD", "PSD", "ND", "NSD", "ID")


def as_wrench(load: Sequence[float] | np.ndarray) -> np.ndarray:
    """A force (3,) or wrench (6,) as a wrench [F (N); M (N.m)], checked finite."""
    needed = "a force (fx,fy,fz in N) or a wrench (fx,fy,fz,mx,my,mz in N, N.m)"
    values = float_array(load, "the load", needed, finite=False).reshape(-1)
    if values.shape not in ((3,), (6,)):
        raise StiffnessError(f"a load is {needed}; got {values.shape[0]} values")
    if not np.isfinite(values).all():  # float_array's check and message, without a copy
        raise wrong_argument("the load", values, needed, "finite numbers: ")
    return np.concatenate([values, np.zeros(6 - values.shape[0])])


@dataclass
class TargetState:
    """Kinematic and load-dependent quantities at one configuration.

    Attributes
    ----------
    q
        Full Pinocchio configuration (loops closed).
    position
        Target position in the base frame (m).
    rotation
        Target frame orientation in the base frame.
    jacobian
        (6, n) target Jacobian w.r.t. the compliant joints, rows [v; omega], base axes.
    wrench
        Applied dead wrench [F; M] in the base frame.
    k_c
        (n, n) complementary stiffness ``d(J^T W)/d theta`` (N.m/rad for revolute joints).
    k_c_twist
        (n, n) the same with the wrench held fixed in the target's body axes (Zefran-Kumar
        twist basis).
    projection
        (nv, n) velocity map S from compliant-joint rates to all joint rates.
    """

    q: np.ndarray
    position: np.ndarray
    rotation: np.ndarray
    jacobian: np.ndarray
    wrench: np.ndarray
    k_c: np.ndarray
    k_c_twist: np.ndarray
    projection: np.ndarray

    def translational_jacobian(self) -> np.ndarray:
        """(3, n) Jacobian of the target position (m/rad)."""
        return self.jacobian[:3]

    def body_jacobian(self) -> np.ndarray:
        """(6, n) Jacobian in the target's body axes, rows [v; omega]."""
        rt = self.rotation.T
        return np.vstack([rt @ self.jacobian[:3], rt @ self.jacobian[3:]])


def velocity_projection(robot: Robot) -> np.ndarray:
    """Velocity map S (nv, n_compliant) of the current kinematics: q_dot = S theta_dot.

    Rigid coordinate joints stay still; mimic followers move with their leaders; passive loop
    joints follow the closure (:func:`stiffness.mechanics.closed_loop.velocity_map`, the
    toolkit's one rank test: passive motions that the constraints leave undetermined and
    that do not move the target, such as a rod spinning about its own axis, stay still).
    Kinematics (joint Jacobians, frame placements) must be up to date.

    Raises
    ------
    UndeterminedMotionError
        If the target's position depends on a passive motion the constraints leave undetermined
        (a loop singularity, or a passive joint no loop constrains).
    """
    model, data = robot.model, robot.data
    base = compliant_projection(robot)
    if robot.loop.is_open_chain:
        return base
    proj, _, valid, _ = closed_loop.velocity_map(
        robot.loop.world_jacobian(model, data)[None], robot.compliant_v, robot.loop.passive_v,
        base, _target_passive(robot))
    _require_determined(robot, valid)
    return proj[0]


def compliant_projection(robot: Robot) -> np.ndarray:
    """(nv, n_compliant) tree-joint rates per compliant rate, loops aside: identity on the
    compliant joints, each mimic follower at its multiplier times its leader; for springs on
    controller coordinates, each coordinate's column of the coupling's A
    (:meth:`Robot.rate_projection`)."""
    if robot.springs_on_controller:
        return robot.rate_projection(robot.compliant_joints)
    key = ("compliant_projection", tuple(robot.compliant_joints))
    kept = robot.slots.kept.get(key)
    if kept is None:  # made once per robot (inverse kinematics asks at every step)
        followers = [(robot.joint_v_index(m.follower), robot.joint_v_index(m.leader),
                      m.multiplier) for m in robot.mimics]
        kept = robot.slots.kept[key] = (
            closed_loop.base_projection(robot.compliant_v, robot.model.nv, followers),)
    return kept[0].copy()


def _target_passive(robot: Robot) -> np.ndarray:
    """(1, 3, n_p) the target position's Jacobian on the passive joints (kinematics current)."""
    j_pos = kinematics.frame_jacobian(robot.model, robot.data, robot.target_frame_id)[:3]
    return j_pos[:, robot.loop.passive_v][None]


def _require_determined(robot: Robot, valid: np.ndarray) -> None:
    """Return if ``valid[0]``, else raise :class:`UndeterminedMotionError` naming the joints
    of the passive motion that the loop leaves free and that moves the target (kinematics
    current)."""
    if bool(valid[0]):
        return
    model, data = robot.model, robot.data
    idle = robot.loop.idle_motions(model, data)
    j_pos = _target_passive(robot)[0]
    moved = np.linalg.norm(j_pos @ idle, axis=0) if idle.shape[1] else np.zeros(1)
    k = max(1, int(np.sum(moved > closed_loop.IDLE_MOTION_TOL
                          * max(1.0, float(np.abs(j_pos).max(initial=0.0))))))
    joints = _joints_of(robot, idle[:, int(np.argmax(moved))]) if idle.shape[1] else \
        list(robot.loop.passive_joints[:3])
    raise UndeterminedMotionError(
        f"the loop of {robot.title} is singular here: the target's position depends on an "
        f"undetermined motion ({k} passive motion(s) that the loop constraints leave "
        f"free move the target; mostly joints {', '.join(joints)}): the pose is a "
        "flattened or folded assembly (move away from it), or these joints belong in "
        "name_mot (actuated) or lack a loop")


def _joints_of(robot: Robot, motion: np.ndarray) -> list[str]:
    """Names of the passive joints that carry most of a passive motion (unit vector)."""
    names = []
    offset = 0
    for name in robot.loop.passive_joints:
        nv = robot.model.joints[robot.model.getJointId(name)].nv
        if np.linalg.norm(motion[offset: offset + nv]) > 0.3:
            names.append(name)
        offset += nv
    return names or list(robot.loop.passive_joints[:3])


def target_state(robot: Robot, q: np.ndarray, load: np.ndarray | None = None) -> TargetState:
    """Jacobian and complementary stiffness of the target at a (closed) configuration ``q``.

    Parameters
    ----------
    robot
        The robot.
    q
        Full configuration with loops closed (see :meth:`Robot.configuration`), or the
        robot's coordinates (rad, m), closed here (:func:`full_configuration`).
    load
        Dead force (3,) in N or wrench (6,) [N, N.m] at the target, base axes; default zero.
    """
    return target_states(robot, q, [np.zeros(6) if load is None else load])[0]


def target_jacobian(robot: Robot, q: np.ndarray) -> np.ndarray:
    """:func:`target_state`'s ``jacobian`` (6, n_compliant) alone (rows [v; omega], base axes
    at the target; m/rad, rad/rad): the same numbers, without the kinematic Hessians on an open
    chain (a closed loop's map S needs its closure derivatives: :func:`target_state`).

    Parameters
    ----------
    robot
        The robot.
    q
        Full configuration with loops closed, or the robot's coordinates (rad, m).
    """
    if not robot.loop.is_open_chain:
        return target_state(robot, q).jacobian
    model, data = robot.model, robot.data
    kinematics.update_first_order(model, data, full_configuration(robot, q))
    return kinematics.frame_jacobian(model, data, robot.target_frame_id) @ \
        velocity_projection(robot)


def full_configuration(robot: Robot, q: np.ndarray | list[float]) -> np.ndarray:
    """``q`` as Pinocchio's configuration (``model.nq`` values): as given when it has that
    size, else the robot's coordinates (:meth:`Robot.configuration`, loops closed: a list of
    joint angles, a closed loop's independent joints, a continuous joint's angle).

    Raises
    ------
    StiffnessError
        ``q`` has neither size (Pinocchio's own error was a C++ signature or an assertion).
    """
    values = float_array(q, "q", lambda: f"the {robot.n_coordinates} coordinates of "
                         f"{robot.title} (rad, m) or its full configuration of {robot.model.nq} "
                         "values").reshape(-1)
    if values.shape[0] == robot.model.nq:
        return values
    if values.shape[0] == robot.n_coordinates:
        return robot.configuration(values)
    raise StiffnessError(f"q has {values.shape[0]} values; give the {robot.n_coordinates} "
                         f"coordinates of {robot.title} ({', '.join(robot.coordinate_joints)}) "
                         f"or its full configuration of {robot.model.nq} values "
                         "(robot.configuration(coordinates))")


def target_states(robot: Robot, q: np.ndarray, loads: list | np.ndarray) -> list[TargetState]:
    """:func:`target_state` for several loads at one configuration, sharing the kinematics.

    For a closed loop, K_C is :func:`stiffness.mechanics.closed_loop.reduced_hessian` of the
    tree's Hessian term with the closure derivatives of this configuration (the stack of one
    of the batched API).
    """
    model, data = robot.model, robot.data
    wrenches = [as_wrench(load) for load in loads]
    q = full_configuration(robot, q)
    kinematics.update_kinematics(model, data, q)
    fid = robot.target_frame_id
    j_full = kinematics.frame_jacobian(model, data, fid)
    hess = kinematics.frame_hessian(model, data, fid)
    position = kinematics.frame_position(data, fid)
    rotation = kinematics.frame_rotation(data, fid)
    if robot.loop.is_open_chain:
        s = velocity_projection(robot)
        curvature = None
    else:
        closure = closed_loop.closure_derivatives(
            robot.loop.world_jacobian(model, data)[None],
            robot.loop.world_hessian(model, data)[None], robot.compliant_v,
            robot.loop.passive_v, compliant_projection(robot),
            j_full[:3, robot.loop.passive_v][None])
        _require_determined(robot, closure.valid)
        s, curvature = closure.projection[0], closure.curvature[0]
    jac = j_full @ s
    v, w = jac[:3], jac[3:]
    states = []
    for wrench in wrenches:
        # dQ_a/dq_b with Q = J^T W: sum_k W_k dJ[k, a]/dq_b
        dq = np.einsum("k,kab->ab", wrench, hess)
        if curvature is None:
            k_c = s.T @ dq @ s
        else:
            k_c = closed_loop.reduced_hessian(dq, (j_full.T @ wrench)[robot.loop.passive_v],
                                              s, curvature)
        # twist basis: d(J_b^T W_b)/d theta at fixed body wrench adds J_l^T [omega_k]x W, i.e.
        # F.(v_l x omega_k) + M.(omega_l x omega_k) at [l, k]
        cross = np.einsum("i,ijk,jl,km->lm", wrench[:3], _LEVI_CIVITA, v, w)
        cross += np.einsum("i,ijk,jl,km->lm", wrench[3:], _LEVI_CIVITA, w, w)
        states.append(TargetState(q=q.copy(), position=position, rotation=rotation, jacobian=jac,
                                  wrench=wrench, k_c=k_c, k_c_twist=k_c + cross, projection=s))
    return states


_LEVI_CIVITA = np.zeros((3, 3, 3))
for _i, _j, _k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
    _LEVI_CIVITA[_i, _j, _k], _LEVI_CIVITA[_i, _k, _j] = 1.0, -1.0


def joint_stiffness(k_theta: np.ndarray | list[float], n: int) -> np.ndarray:
    """Diagonal joint stiffness K_theta (n, n) from n positive values (N.m/rad or N/m).

    Raises
    ------
    StiffnessError
        On a wrong count, a non-finite or a non-positive value.
    """
    k = np.asarray(k_theta, dtype=float).reshape(-1)
    if k.shape[0] != n:
        raise StiffnessError(
            f"need one joint stiffness per compliant joint ({n}), got {k.shape[0]}"
        )
    if not np.all(np.isfinite(k)) or np.any(k <= 0):
        raise StiffnessError(f"joint stiffnesses must be finite and positive, got {k.tolist()}")
    return np.diag(k)


def tangent_joint_stiffness(
    k_theta: np.ndarray, k_c: np.ndarray, formulation: str = "enhanced"
) -> np.ndarray:
    """K_theta - K_C (enhanced) or K_theta (conventional)."""
    if formulation not in FORMULATIONS:
        raise UnknownNameError(f"formulation must be one of {', '.join(FORMULATIONS)}, got "
                               f"{formulation!r}", name=formulation, choices=FORMULATIONS)
    return k_theta - k_c if formulation == "enhanced" else k_theta.copy()


def compliance(jacobian: np.ndarray, tangent_stiffness: np.ndarray) -> np.ndarray:
    """Cartesian compliance ``C = J (K_theta - K_C)^-1 J^T`` (m/N for translations).

    Raises
    ------
    SingularConfigurationError
        If the tangent joint stiffness is singular.
    StiffnessError
        ``jacobian`` is not an (r, n) matrix of numbers, or ``tangent_stiffness`` not (n, n).
    """
    jacobian = float_array(jacobian, "jacobian", "an (r, n) matrix (m/rad for translations; "
                           "r Cartesian rows, n joints)", ndim=2)
    n = jacobian.shape[1]
    tangent_stiffness = float_array(
        tangent_stiffness, "tangent_stiffness",
        f"a ({n}, {n}) matrix (N.m/rad) for the {n} columns of the jacobian", ndim=2)
    if tangent_stiffness.shape != (n, n):
        raise wrong_argument("tangent_stiffness", tangent_stiffness,
                             f"a ({n}, {n}) matrix (N.m/rad) for the {n} columns of the jacobian")
    try:
        x = np.linalg.solve(tangent_stiffness, jacobian.T)
    except np.linalg.LinAlgError as exc:
        raise SingularConfigurationError(
            "the tangent joint stiffness K_theta - K_C is singular: the load is at the "
            "buckling limit of this configuration; reduce the load"
        ) from exc
    return jacobian @ x


#: Condition number of the compliance beyond which K_X = C^-1 is undefined (singular C): with
#: double precision (eps 2.2e-16) an inverse beyond it has fewer than ~4 correct digits.
CONDITION_LIMIT = 1e12


def cartesian_stiffness(compliance_matrix: np.ndarray) -> np.ndarray:
    """K_X = C^-1 (N/m for translations).

    Raises
    ------
    SingularConfigurationError
        If the compliance is singular, condition number above :data:`CONDITION_LIMIT` (the
        Jacobian loses rank: a kinematic singularity, or fewer compliant joints than Cartesian
        directions). :func:`subspace_stiffness` then gives the stiffness where it exists.
    StiffnessError
        ``compliance_matrix`` is not a square matrix of finite numbers.
    """
    needed = "a square matrix (m/N for translations)"
    compliance_matrix = float_array(compliance_matrix, "compliance_matrix", needed, ndim=2)
    if compliance_matrix.shape[0] != compliance_matrix.shape[1]:
        raise wrong_argument("compliance_matrix", compliance_matrix, needed)
    cond = np.linalg.cond(compliance_matrix)
    if not np.isfinite(cond) or cond > CONDITION_LIMIT:
        raise SingularConfigurationError(
            f"the compliance is singular (condition number {cond:.3g}): the target Jacobian "
            "loses rank here (kinematic singularity, or fewer compliant joints than directions), "
            "or the joint stiffnesses span more orders of magnitude than double precision can "
            "invert; use the compliance, or move away from the singularity"
        )
    return np.linalg.inv(compliance_matrix)


@dataclass
class SubspaceStiffness:
    """The Cartesian stiffness where it exists, for a singular compliance ``C`` (r < rows).

    With the singular value decomposition ``C = U S V^T`` and rank ``r`` (singular values above
    ``S_max / CONDITION_LIMIT``): the target moves only within ``range(C)`` (columns
    ``U_r``, the ``moving`` directions); wrenches in ``null(C)`` (columns ``V[:, r:]``, the
    ``rigid`` directions) move it not at all, the stiffness there is unbounded. On the moving
    subspace the stiffness is the pseudo-inverse ``K_r = C^+ = V_r S_r^-1 U_r^T``:
    ``W = K_r dx`` for ``dx`` in ``range(C)`` is the wrench of least norm that gives ``dx``.

    Attributes
    ----------
    rank
        r, the dimension of the moving subspace.
    moving
        (rows, r) orthonormal displacement directions the target can take.
    rigid
        (rows, rows - r) orthonormal wrench directions that do not move the target.
    stiffness
        (rows, rows) ``C^+`` (N/m for translations), base axes like ``C``.
    values
        (r,) its principal stiffnesses on the moving subspace, ascending: the eigenvalues of
        the symmetric part of ``U_r^T C^+ U_r`` (as :func:`ellipsoid`'s of a regular K_X);
        ``1 / S_r`` for a positive definite ``C``, negative ones where the load buckles the
        robot (``K_theta - K_C`` indefinite).
    """

    rank: int
    moving: np.ndarray
    rigid: np.ndarray
    stiffness: np.ndarray
    values: np.ndarray


def subspace_stiffness(compliance_matrix: np.ndarray) -> SubspaceStiffness:
    """The stiffness on the subspace a singular compliance spans (see :class:`SubspaceStiffness`).

    Exact for any compliance; equal to ``C^-1`` (rank full, ``rigid`` empty) for a regular one.
    """
    u, sv, vt = np.linalg.svd(compliance_matrix)
    rank = int(np.sum(sv > sv[0] / CONDITION_LIMIT)) if sv[0] > 0 else 0
    inv = np.zeros_like(sv)
    inv[:rank] = 1.0 / sv[:rank]
    stiffness = (vt.T * inv) @ u.T
    on_range = u[:, :rank].T @ stiffness @ u[:, :rank]  # signed: 1 / S_r carries no sign
    values = np.linalg.eigvalsh(0.5 * (on_range + on_range.T))
    return SubspaceStiffness(rank, u[:, :rank], vt[rank:].T, stiffness, values)


def deflection(state: TargetState, k_theta: np.ndarray, formulation: str = "enhanced",
               rows: slice = slice(0, 3)) -> np.ndarray:
    """Linear deflection ``J[rows] (K_theta - K_C)^-1 J^T W`` under the full load (eq. 11).

    ``rows`` selects the output (default the position, m); the whole wrench loads the joints.
    """
    n = state.k_c.shape[0]
    needed = f"a ({n}, {n}) joint stiffness matrix (N.m/rad, N/m; np.diag of the springs)"
    k_theta = float_array(k_theta, "k_theta", needed, ndim=2)
    if k_theta.shape != (n, n):
        raise wrong_argument("k_theta", k_theta, needed)
    tangent = tangent_joint_stiffness(k_theta, state.k_c, formulation)
    try:
        dtheta = np.linalg.solve(tangent, state.jacobian.T @ state.wrench)
    except np.linalg.LinAlgError as exc:
        raise SingularConfigurationError(
            "the tangent joint stiffness K_theta - K_C is singular: reduce the load") from exc
    return state.jacobian[rows] @ dtheta


def definiteness(matrix: np.ndarray, rtol: float = 1e-9, atol: float = 0.0) -> str:
    """Definiteness class of the quadratic form of ``matrix``: PD, PSD, ND, NSD or ID.

    Eigenvalues of the symmetric part with ``|lambda| <= atol + rtol * max|lambda|`` count as
    zero. A zero matrix is PSD.
    """
    eig = np.linalg.eigvalsh(0.5 * (matrix + matrix.T))
    tol = atol + rtol * max(float(np.max(np.abs(eig))), 0.0)
    pos, neg = eig > tol, eig < -tol
    if pos.all():
        return "PD"
    if neg.all():
        return "ND"
    if not neg.any():
        return "PSD"
    if not pos.any():
        return "NSD"
    return "ID"


def tangent_definiteness(k_theta: np.ndarray, tangent: np.ndarray, rtol: float = 1e-9) -> str:
    """Definiteness class of a tangent stiffness ``K_theta - K_C`` in the metric of K_theta.

    The class of ``L^-1 T L^-T`` (``L L^T = K_theta``): the same as that of ``T`` (Sylvester's
    law of inertia), but its eigenvalues are ``1 - s_i`` with ``s_i`` the load factors, so the
    zero tolerance ``rtol`` is relative to each joint's own stiffness, not to the stiffest
    (``definiteness(T)`` calls a 1e-2 N.m/rad joint next to a 1e10 N/m one zero: PSD).
    """
    low = np.linalg.cholesky(0.5 * (k_theta + k_theta.T))
    x = np.linalg.solve(low, np.linalg.solve(low, tangent).T)
    return definiteness(x, rtol=rtol)


@dataclass
class Ellipsoid:
    """Principal values (ascending) and directions (columns) of a symmetric stiffness."""

    values: np.ndarray
    directions: np.ndarray
    symmetric: bool


def ellipsoid(matrix: np.ndarray) -> Ellipsoid:
    """Principal values and directions of a stiffness (of its symmetric part if asymmetric)."""
    sym = 0.5 * (matrix + matrix.T)
    values, vectors = np.linalg.eigh(sym)
    asym = np.abs(matrix - matrix.T).max() <= 1e-9 * max(np.abs(matrix).max(), 1e-300)
    return Ellipsoid(values, vectors, bool(asym))


@dataclass
class WorkBalance:
    """Net works of A&S eq. 14 (Cartesian) and eq. 15 (joint space), J.

    ``cartesian`` uses the given K_X; ``joint_enhanced`` uses K_theta - K_C and
    ``joint_conventional`` K_theta alone. Eq. 15 is evaluated as printed in intent,
    ``Gamma^T dTheta`` (the printed ``Gamma^T dX`` mixes units).
    """

    cartesian: float
    joint_enhanced: float
    joint_conventional: float


def work_balance(force: np.ndarray, dx: np.ndarray, k_x: np.ndarray, dtheta: np.ndarray,
                 jacobian: np.ndarray, k_theta: np.ndarray, k_c: np.ndarray) -> WorkBalance:
    """Works of eq. 14 and 15 for a deflection (dx in m, dtheta in rad) under a force (N)."""
    gamma = jacobian.T @ force
    cart = float(force @ dx + 0.5 * dx @ k_x @ dx)
    joint_e = float(gamma @ dtheta + 0.5 * dtheta @ (k_theta - k_c) @ dtheta)
    joint_c = float(gamma @ dtheta + 0.5 * dtheta @ k_theta @ dtheta)
    return WorkBalance(cart, joint_e, joint_c)


def twist_basis_stiffness(state: TargetState, k_theta: np.ndarray) -> np.ndarray:
    """Zefran-Kumar twist-basis 6x6 stiffness K_a (body axes, rows [v; omega] ordering).

    ``K_a = J_b^-T (K_theta - K_C^tw) J_b^-1``; needs six compliant joints and a regular J_b.
    """
    jb = state.body_jacobian()
    _require_square(jb)
    jinv = np.linalg.inv(jb)
    return jinv.T @ (k_theta - state.k_c_twist) @ jinv


def joint_connection_stiffness(state: TargetState, k_theta: np.ndarray, body: bool = True
                               ) -> np.ndarray:
    """Zefran-Kumar joint-space-connection 6x6 stiffness ``J^-T K_theta J^-1`` (symmetric)."""
    jb = state.body_jacobian() if body else state.jacobian
    _require_square(jb)
    jinv = np.linalg.inv(jb)
    return jinv.T @ k_theta @ jinv


def _require_square(jac: np.ndarray) -> None:
    if jac.shape[0] != jac.shape[1]:
        raise StiffnessError(
            f"the 6x6 stiffness in a connection needs six compliant joints (J is {jac.shape}); "
            "use the compliance for other cases"
        )
    cond = np.linalg.cond(jac)
    if not np.isfinite(cond) or cond > CONDITION_LIMIT:
        raise SingularConfigurationError(
            f"the Jacobian is singular at this configuration (condition number {cond:.3g}): "
            "the 6x6 stiffness is undefined here; use the compliance, or move away from the "
            "singularity")
