"""Batched elastostatics: K_C, compliance, K_X, eigen-decomposition and definiteness for arrays
of configurations and loads at once.

The one-at-a-time API (:func:`stiffness.formulation.target_state`) spends ~100 us of Python per
configuration. Here Pinocchio is called in a tight loop into preallocated arrays and everything
else is NumPy over the whole batch:

* Kinematic-Hessian route (:func:`batch_kinematics`; any robot, any number of loads): three
  calls per configuration of an open chain (joint kinematic Hessians, the target's frame
  Hessian, its frame Jacobian). ``K_C(W) = sum_k W_k B_k`` is linear in the wrench, so the
  kinematics keep the *unit-wrench basis* ``B_k = d(J^T e_k)/d theta`` and any number of load
  cases cost one small matrix product.
* Generalized-gravity route (:func:`single_force_kinematics`; open chains, one force): a dead
  force F at the target is gravity acting on a unit point mass there, so Pinocchio's
  ``computeGeneralizedGravityDerivatives`` on a copy of the model holding only that mass (and
  gravity -F) returns K_C(F) exactly, with no follower-load correction; with the frame
  Jacobian, two calls per configuration. :func:`evaluate` picks it for a single force.
* Closed loops (the SK120's five-bar): the basis is the reduced Hessian
  ``S^T (H_k - sum_j Lambda_jk Hc_j) S`` of :mod:`stiffness.formulation`, with the multipliers
  per unit wrench ``Lambda = pinv(C_p^T) J_p^T`` and the velocity map ``S``, batched.
* Loop closures are the expensive part of a closed-chain configuration: :func:`close_loops`
  closes each distinct value of the *loop coordinates* (the coordinates of the joints on the
  path between the loop frames; the others, e.g. the SK120's theta1 and wrist, move the loop
  rigidly or not at all) once, by continuation for one anchor per small cell of those
  coordinates and by a batched Newton iteration from the anchor for the rest.
* Compliance and K_X of symmetric tangents (pure forces) go through a Cholesky factorisation
  vectorised across the batch (one NumPy operation per matrix entry, not per matrix); the
  others, and those that are not positive definite, through LAPACK's LU.

Results equal :func:`~stiffness.formulation.target_state` and friends to round-off (tests:
relative 1e-10 on open chains, 1e-9 through a loop's pseudo-inverse). Where the one-at-a-time
API raises on a singular configuration, the batched one returns NaN and a mask.

Shapes: ``m`` configurations, ``L`` load cases, ``n`` compliant joints, ``r`` Cartesian rows
(3: translational, 6: [v; omega]). Units: SI (m, N, rad; K_C in N.m/rad; K_X in N/m for the
translational block; compliance in m/N). A :class:`~stiffness.robot.Robot` holds one
Pinocchio ``Data``: use one robot per thread.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from stiffness.errors import StiffnessError
from stiffness.formulation import DEFINITENESS_CLASSES, FORMULATIONS
from stiffness.robot import Robot

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED

#: Definiteness class codes: ``DEFINITENESS_CLASSES[code]`` ("PD", "PSD", "ND", "NSD", "ID");
#: -1 marks an invalid entry (singular or unreachable configuration).
CLASS_CODES = {name: i for i, name in enumerate(DEFINITENESS_CLASSES)}
INVALID_CLASS = -1

#: Condition-number limit of the compliance beyond which K_X is reported singular (NaN), as in
#: :func:`stiffness.formulation.cartesian_stiffness` (there: 2-norm; here: 1-norm estimate).
CONDITION_LIMIT = 1e12

#: Rank tolerance of the passive-joint constraint block, as in
#: :func:`stiffness.formulation.velocity_projection`.
_RANK_RTOL = 1e-9


# ------------------------------------------------------------------------------ kinematics


@dataclass
class BatchKinematics:
    """Load-independent kinematics of ``m`` configurations.

    Attributes
    ----------
    q
        (m, nq) full Pinocchio configurations (loops closed).
    jacobian
        (m, 6, n) target Jacobian w.r.t. the compliant joints, rows [v (m/rad); omega (rad/rad)],
        base axes at the target, loops closed.
    k_c_basis
        (m, w, n, n) complementary stiffness per unit wrench component:
        ``K_C(W) = sum_k W_k k_c_basis[:, k]`` (N.m/rad per N for k < 3, per N.m for k >= 3).
        ``w`` is 3 (forces only) or 6. For open chains, a transposed view of the array filled
        by Pinocchio (no copy).
    valid
        (m,) False where the loop is singular (passive joints not determined) or the
        configuration could not be closed; the other arrays hold NaN there.
    position
        (m, 3) target position in the base frame (m), or None if not requested.
    rotation
        (m, 3, 3) target orientation in the base frame, or None if not requested.
    """

    q: np.ndarray
    jacobian: np.ndarray
    k_c_basis: np.ndarray
    valid: np.ndarray
    position: np.ndarray | None = None
    rotation: np.ndarray | None = None

    @property
    def size(self) -> int:
        """Number of configurations m."""
        return self.q.shape[0]


def _unscramble(raw: np.ndarray) -> np.ndarray:
    """Batched kinematic-Hessian reorder: ``H[i, k, a, b] = dJ_i[k, a] / dq_b``.

    ``raw`` (m, 6, nv, nv) holds, per configuration, the array returned by
    ``getFrameKinematicHessian`` (the column-major tensor read in row-major order, see
    :mod:`stiffness.kinematics`). Returns a view.
    """
    m, _, nv, _ = raw.shape
    return raw.reshape(m, nv, nv, 6).transpose(0, 3, 2, 1)


def batch_kinematics(robot: Robot, q: np.ndarray, moments: bool = True,
                     pose: bool = False) -> BatchKinematics:
    """Target Jacobian and unit-wrench K_C basis of many configurations.

    Parameters
    ----------
    robot
        The robot (its ``data`` is used as scratch space).
    q
        (m, nq) full configurations with loops closed (see :func:`close_loops`), or (nq,).
    moments
        Keep the basis of the three moment components too (``w = 6``); with False, only
        forces (``w = 3``) can be applied, slightly faster.
    pose
        Also return the target position (m) and orientation.

    Returns
    -------
    BatchKinematics
        Equal to :func:`stiffness.formulation.target_states` to round-off. The raw Hessians
        (6 nv^2 doubles per frame and configuration) are held for blocks of configurations of
        at most :data:`_RAW_BYTES`, so the memory is bounded whatever ``m``.
    """
    q = np.ascontiguousarray(np.atleast_2d(np.asarray(q, dtype=float)))
    if q.shape[1] != robot.model.nq:
        raise StiffnessError(
            f"{robot.name} configurations have {robot.model.nq} values (Pinocchio q), got "
            f"{q.shape[1]}"
        )
    frames = 1 + (0 if robot.loop is None else len(_loop_points(robot)))
    per_configuration = 8 * 6 * robot.model.nv ** 2 * frames
    step = max(1, _RAW_BYTES // per_configuration)
    if q.shape[0] <= step:
        return _kinematics_block(robot, q, 6 if moments else 3, pose)
    blocks = [_kinematics_block(robot, q[s:s + step], 6 if moments else 3, pose)
              for s in range(0, q.shape[0], step)]
    return BatchKinematics(
        q=q,
        jacobian=np.concatenate([b.jacobian for b in blocks]),
        k_c_basis=np.concatenate([b.k_c_basis for b in blocks]),
        valid=np.concatenate([b.valid for b in blocks]),
        position=np.concatenate([b.position for b in blocks]) if pose else None,
        rotation=np.concatenate([b.rotation for b in blocks]) if pose else None,
    )


#: Largest size (bytes) of the raw kinematic Hessians held at once by :func:`batch_kinematics`.
_RAW_BYTES = 64 * 2**20


def _kinematics_block(robot: Robot, q: np.ndarray, w: int, pose: bool) -> BatchKinematics:
    """:func:`batch_kinematics` of one block of configurations."""
    model, data = robot.model, robot.data
    m, nv = q.shape[0], model.nv
    fid = robot.target_frame_id
    loop_points = [] if robot.loop is None else _loop_points(robot)
    raw = np.empty((m, 6, nv, nv))
    j_full = np.empty((m, 6, nv))
    raw_loop = np.empty((len(loop_points), m, 6, nv, nv))
    j_loop = np.empty((len(loop_points), m, 6, nv))
    placement = np.empty((m, 4, 4)) if pose else None
    # the velocity map uses the exact derivative of Pinocchio's closure residual, as
    # formulation.velocity_projection: for point pairs from the frame positions (see
    # _closed_loop_basis), otherwise (6D pairs) from LoopClosure.jacobian itself
    points_only = robot.loop is not None and all(p.kind == "3D" for p in robot.loop.pairs)
    loop_pos = np.empty((len(loop_points), m, 3)) if points_only else None
    loop_jac = (np.empty((m, robot.loop.n_rows, nv))
                if robot.loop is not None and not points_only else None)

    hessians = pin.computeJointKinematicHessians
    frame_hessian = pin.getFrameKinematicHessian
    frame_jacobian = pin.getFrameJacobian
    update_placement = pin.updateFramePlacement
    if not loop_points and not pose:  # the hot loop: three calls per configuration
        for i in range(m):
            hessians(model, data, q[i])  # also computes the joint Jacobians and placements
            raw[i] = frame_hessian(model, data, fid, LWA)
            j_full[i] = frame_jacobian(model, data, fid, LWA)
    else:
        for i in range(m):
            hessians(model, data, q[i])
            raw[i] = frame_hessian(model, data, fid, LWA)
            j_full[i] = frame_jacobian(model, data, fid, LWA)
            for f, point in enumerate(loop_points):
                raw_loop[f, i] = frame_hessian(model, data, *point, LWA)
                j_loop[f, i] = frame_jacobian(model, data, *point, LWA)
                if points_only:
                    loop_pos[f, i] = update_placement(model, data, point[0]).translation
            if loop_jac is not None:
                loop_jac[i] = robot.loop.jacobian(model, data)
            if pose:
                placement[i] = update_placement(model, data, fid).homogeneous

    cv = robot.compliant_v
    valid = np.ones(m, dtype=bool)
    if robot.loop is None:
        # raw read as (m, b, a, k) is the unit-wrench basis [m, k, a, b], transposed
        basis_t = raw.reshape(m, nv, nv, 6)
        if not _is_identity_selection(cv, nv):
            basis_t = basis_t[:, cv[:, None], cv[None, :]]
            j_full = j_full[:, :, cv]
        basis = basis_t[..., :w].transpose(0, 3, 2, 1)
        jac = j_full
    else:
        basis, jac, valid = _closed_loop_basis(robot, _unscramble(raw), j_full, raw_loop,
                                               j_loop, w, loop_pos, loop_jac)
    return BatchKinematics(
        q=q, jacobian=jac, k_c_basis=basis, valid=valid,
        position=None if placement is None else placement[:, :3, 3].copy(),
        rotation=None if placement is None else placement[:, :3, :3].copy(),
    )


def _is_identity_selection(index: np.ndarray, size: int) -> bool:
    return index.shape[0] == size and bool(np.all(index == np.arange(size)))


#: Points (in a frame's own axes, m) whose coincidence closes a "6D" loop pair.
_FRAME_POINTS_M = (np.zeros(3), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))


def _loop_points(robot: Robot) -> list[tuple]:
    """Points whose world positions make the loop residual, as ``getFrame*`` arguments.

    Consecutive entries (a, b) form the rows ``p_b - p_a``: a "3D" pair is its two frame
    origins (``(frame_id,)``); a "6D" pair three points of each frame, its origin and the
    points one metre along its x and y axes (``(joint_id, placement)``), as
    :meth:`stiffness.loops.LoopClosure.world_residual`. The reduced Hessian does not depend on
    how the closure is written, only on its zero set.
    """
    model = robot.model
    points: list[tuple] = []
    for pair, (fa, fb) in zip(robot.loop.pairs, robot.loop.frame_ids, strict=True):
        if pair.kind == "3D":
            points += [(fa,), (fb,)]
            continue
        frame_a, frame_b = model.frames[fa], model.frames[fb]
        for offset in _FRAME_POINTS_M:
            shift = pin.SE3(np.eye(3), offset)
            points += [(frame_a.parentJoint, frame_a.placement * shift),
                       (frame_b.parentJoint, frame_b.placement * shift)]
    return points


def _closed_loop_basis(robot: Robot, hess: np.ndarray, j_full: np.ndarray,
                       raw_loop: np.ndarray, j_loop: np.ndarray, w: int,
                       loop_pos: np.ndarray | None, loop_jac: np.ndarray | None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reduced unit-wrench basis, closed-loop Jacobian and validity (see module docstring).

    World-axes loop residual ``c = p_b - p_a`` per point pair: Jacobian ``C`` (R, nv), Hessian
    ``Hc`` (R, nv, nv). Velocity map ``S``: identity on the compliant joints,
    ``-pinv(D_p) D_c`` on the passive ones (the other coordinate joints stay still), with ``D``
    the exact Jacobian of Pinocchio's residual ``R_a^T (p_b - p_a)`` rotated to world axes,
    ``C + (p_b - p_a) x J_a,omega`` (equal to ``C`` on the closed loop; off it, by the closure
    tolerance), or ``loop_jac`` when given. Multipliers per unit wrench:
    ``Lambda = pinv(C_p^T) J_p^T`` (minimum-norm, as the ``lstsq`` of the one-at-a-time path).
    """
    loop = robot.loop
    m, nv = j_full.shape[0], j_full.shape[2]
    n = robot.n_compliant
    cv, pv = robot.compliant_v, loop.passive_v
    pairs = range(0, raw_loop.shape[0], 2)
    c_w = np.concatenate([j_loop[p + 1, :, :3] - j_loop[p, :, :3] for p in pairs],
                         axis=1)  # (m, R, nv)
    hc = np.concatenate([
        _unscramble(raw_loop[p + 1])[:, :3] - _unscramble(raw_loop[p])[:, :3]
        for p in pairs], axis=1)  # (m, R, nv, nv)
    if loop_jac is not None:
        d_s = loop_jac
    else:
        d_s = np.concatenate([
            j_loop[p + 1, :, :3] - j_loop[p, :, :3]
            + np.cross((loop_pos[p + 1] - loop_pos[p])[:, :, None], j_loop[p, :, 3:], axis=1)
            for p in pairs], axis=1)
    # velocity map from the residual's Jacobian
    d_p = d_s[:, :, pv]
    u, s, vt = np.linalg.svd(d_p, full_matrices=False)
    scale = np.maximum(1.0, np.abs(d_p).max(axis=(1, 2)))
    valid = np.all(s > _RANK_RTOL * scale[:, None], axis=1)
    cutoff = _RANK_RTOL * s[:, :1]
    s_inv = np.where(s > cutoff, 1.0 / np.where(s > cutoff, s, 1.0), 0.0)
    rates = -((np.swapaxes(vt, 1, 2) * s_inv[:, None, :]) @ np.swapaxes(u, 1, 2)
              @ d_s[:, :, cv])  # -pinv(D_p) D_c
    proj = np.zeros((m, nv, n))
    proj[:, cv, np.arange(n)] = 1.0
    proj[:, pv, :] = rates
    # multipliers per unit wrench component: lambda = pinv(C_p^T) (J^T W)_p, world residual
    c_p = c_w[:, :, pv]  # (m, R, np)
    u, s, vt = np.linalg.svd(c_p, full_matrices=False)
    cutoff = 1e-10 * s[:, :1]
    s_inv = np.where(s > cutoff, 1.0 / np.where(s > cutoff, s, 1.0), 0.0)
    pinv_t = (u * s_inv[:, None, :]) @ vt  # (m, R, np) = pinv(C_p^T)
    lam = pinv_t @ np.swapaxes(j_full[:, :w, pv], 1, 2)  # (m, R, w)
    rows = hc.shape[1]
    dq = hess[:, :w] - (np.swapaxes(lam, 1, 2) @ hc.reshape(m, rows, nv * nv)).reshape(
        m, w, nv, nv)
    basis = np.swapaxes(proj, 1, 2)[:, None] @ dq @ proj[:, None]
    jac = j_full @ proj
    if not valid.all():
        basis[~valid] = np.nan
        jac[~valid] = np.nan
    return basis, jac, valid


_POINT_MASS_MODELS: dict[int, tuple[pin.Model, pin.Model, pin.Data]] = {}


def _point_mass_model(robot: Robot) -> tuple[pin.Model, pin.Data]:
    """Copy of the robot's model with one unit point mass at the target and no other inertia.

    Gravity ``g`` on that model is a dead force ``F = g`` (N) at the target, so Pinocchio's
    generalized-gravity derivative is exactly ``-K_C(F)`` (no follower-load correction; dead
    loads are what gravity is).
    Cached per robot model.
    """
    key = id(robot.model)
    cached = _POINT_MASS_MODELS.get(key)
    if cached is not None and cached[0] is robot.model:
        return cached[1], cached[2]
    model = pin.Model(robot.model)
    for j in range(model.njoints):
        model.inertias[j] = pin.Inertia.Zero()
    frame = model.frames[robot.target_frame_id]
    model.inertias[frame.parentJoint] = pin.Inertia(1.0, frame.placement.translation.copy(),
                                                    np.zeros((3, 3)))
    data = model.createData()
    if len(_POINT_MASS_MODELS) > 16:
        _POINT_MASS_MODELS.clear()
    _POINT_MASS_MODELS[key] = (robot.model, model, data)
    return model, data


def single_force_kinematics(robot: Robot, q: np.ndarray, force: np.ndarray
                            ) -> tuple[np.ndarray, np.ndarray]:
    """Target Jacobian and K_C of an open chain under one dead force, two Pinocchio calls each.

    ``K_C(F) = dg/dq`` of :func:`_point_mass_model` with gravity ``-F``
    (``computeGeneralizedGravityDerivatives``), the Jacobian from the joint Jacobians that call
    leaves in ``data``. Faster than :func:`batch_kinematics` for a single load case.

    Parameters
    ----------
    robot
        An open-chain robot (no loop).
    q
        (m, nq) configurations.
    force
        (3,) dead force at the target (N), base axes.

    Returns
    -------
    jacobian, k_c
        (m, 6, n) target Jacobian and (m, n, n) K_C (N.m/rad) w.r.t. the compliant joints.
    """
    if robot.loop is not None:
        raise StiffnessError("single_force_kinematics is for open chains; use batch_kinematics")
    model, data = _point_mass_model(robot)
    # gravity -F: the generalized gravity J^T F, whose derivative is K_C(F)
    model.gravity = pin.Motion(-np.asarray(force, dtype=float).reshape(3), np.zeros(3))
    q = np.ascontiguousarray(np.atleast_2d(np.asarray(q, dtype=float)))
    m, nv = q.shape[0], model.nv
    fid = robot.target_frame_id
    dg = np.empty((m, nv, nv))
    j_full = np.empty((m, 6, nv))
    gravity_derivatives = pin.computeGeneralizedGravityDerivatives
    frame_jacobian = pin.getFrameJacobian
    for i in range(m):
        dg[i] = gravity_derivatives(model, data, q[i])  # also fills the joint Jacobians
        j_full[i] = frame_jacobian(model, data, fid, LWA)
    cv = robot.compliant_v
    if not _is_identity_selection(cv, nv):
        dg = dg[:, cv[:, None], cv[None, :]]
        j_full = j_full[:, :, cv]
    return j_full, dg


# ------------------------------------------------------------------------------ loops


def loop_coordinate_indices(robot: Robot) -> np.ndarray:
    """Positions, in the coordinate vector, of the coordinates that change the loop closure.

    They are the coordinate joints on the path between the two frames of a loop pair (in the
    support of one frame but not of the other). Common ancestors move the loop rigidly and
    joints outside both supports do not touch it, so the passive joint values depend only on
    these coordinates. Empty for an open chain.
    """
    if robot.loop is None:
        return np.zeros(0, dtype=int)
    model = robot.model
    path: set[str] = set()
    for fa, fb in robot.loop.frame_ids:
        sa = set(model.supports[model.frames[fa].parentJoint])
        sb = set(model.supports[model.frames[fb].parentJoint])
        path |= {model.names[j] for j in sa ^ sb}
    return np.array([i for i, name in enumerate(robot.coordinate_joints) if name in path],
                    dtype=int)


def tree_configurations(robot: Robot, coordinates: np.ndarray,
                        base: np.ndarray | None = None) -> np.ndarray:
    """Full configurations (m, nq) with the coordinates set and other joints from ``base``.

    Vectorised :meth:`Robot.configuration` without loop closure; ``base`` defaults to
    Pinocchio's neutral configuration. Angles in rad, lengths in m.
    """
    coordinates = np.atleast_2d(np.asarray(coordinates, dtype=float))
    model = robot.model
    base = pin.neutral(model) if base is None else np.asarray(base, dtype=float)
    q = np.repeat(base[None, :], coordinates.shape[0], axis=0)
    for i, name in enumerate(robot.coordinate_joints):
        joint = model.joints[model.getJointId(name)]
        if joint.nq == 2:
            q[:, joint.idx_q] = np.cos(coordinates[:, i])
            q[:, joint.idx_q + 1] = np.sin(coordinates[:, i])
        else:
            q[:, joint.idx_q] = coordinates[:, i]
    return q


def _passive_q_indices(robot: Robot) -> np.ndarray:
    model = robot.model
    joints = (model.joints[model.getJointId(n)] for n in robot.loop.passive_joints)
    return np.concatenate([np.arange(j.idx_q, j.idx_q + j.nq) for j in joints]).astype(int)


@dataclass
class ClosedConfigurations:
    """Output of :func:`close_loops`.

    Attributes
    ----------
    q
        (m, nq) full configurations, loops closed (NaN where ``closed`` is False).
    closed
        (m,) whether the loop could be closed (the pose is reachable on the assembly branch).
    n_closures
        Number of distinct loop closures solved.
    """

    q: np.ndarray
    closed: np.ndarray
    n_closures: int


#: Cell size (rad or m) of the loop-coordinate grid whose cells share a continuation anchor.
#: Below the continuation step of Robot.configuration (0.15), so that a Newton correction from
#: an anchor is as safe as one continuation step.
_ANCHOR_CELL = 0.1
#: Largest passive-joint correction (rad or m) accepted from the predictor, as
#: Robot.configuration's continuation; beyond it the key is closed by continuation.
_NEWTON_JUMP = 0.05
_NEWTON_ITERATIONS = 12


def close_loops(robot: Robot, coordinates: np.ndarray) -> ClosedConfigurations:
    """Full configurations for many coordinate vectors, each loop closed once per distinct value
    of the loop coordinates (:func:`loop_coordinate_indices`).

    The distinct loop-coordinate values ("keys") are grouped in cells of
    :data:`_ANCHOR_CELL`; one key per cell (the anchor) is closed by continuation
    (:meth:`Robot.configuration`) from the previous anchor, the anchors visited in a snake
    order so that each continuation is short (the first from the robot's reference assembly; a
    failed continuation is retried from there). The other keys of a cell are closed together by
    a batched Newton iteration from their anchor's closure plus the first-order predictor
    (Pinocchio in a tight loop, the least-squares steps stacked in NumPy); a key whose
    correction exceeds the continuation's branch-jump bound, or that does not converge, falls
    back to continuation from its anchor. The result depends only on the set of coordinates
    given (not on their order), so a scan split into fixed chunks gives the same configurations
    whichever worker runs a chunk.

    Parameters
    ----------
    robot
        The robot.
    coordinates
        (m, n_coordinates) joint coordinates (rad or m).
    """
    coordinates = np.atleast_2d(np.asarray(coordinates, dtype=float))
    if coordinates.shape[1] != robot.n_coordinates:
        raise StiffnessError(
            f"{robot.name} has {robot.n_coordinates} coordinates "
            f"({', '.join(robot.coordinate_joints)}), got {coordinates.shape[1]} per row"
        )
    if not np.all(np.isfinite(coordinates)):
        raise StiffnessError("joint coordinates must be finite numbers")
    m = coordinates.shape[0]
    if robot.loop is None:
        return ClosedConfigurations(tree_configurations(robot, coordinates),
                                    np.ones(m, dtype=bool), 0)
    keys_at = loop_coordinate_indices(robot)
    keys, inverse = np.unique(coordinates[:, keys_at], axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    passive_q = _passive_q_indices(robot)
    passive, ok = _close_keys(robot, keys, keys_at, passive_q)
    q = tree_configurations(robot, coordinates)
    q[:, passive_q] = passive[inverse]
    closed = ok[inverse]
    q[~closed] = np.nan
    return ClosedConfigurations(q, closed, int(keys.shape[0]))


def _snake_order(cells: np.ndarray) -> np.ndarray:
    """Order of integer cells along a boustrophedon path (neighbours follow each other)."""
    columns = [cells[:, 0]]
    parity = cells[:, 0].copy()
    for k in range(1, cells.shape[1]):
        columns.append(np.where(parity % 2 == 0, cells[:, k], -cells[:, k]))
        parity = parity + cells[:, k]
    return np.lexsort(columns[::-1])


def _close_keys(robot: Robot, keys: np.ndarray, keys_at: np.ndarray, passive_q: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """Passive joint values (k, n_pq) and closed mask of each key (see :func:`close_loops`)."""
    n_keys = keys.shape[0]
    passive = np.full((n_keys, passive_q.shape[0]), np.nan)
    ok = np.zeros(n_keys, dtype=bool)
    base = np.zeros(robot.n_coordinates)

    def continuation(key: np.ndarray, seed: np.ndarray | None) -> np.ndarray | None:
        coords = base.copy()
        coords[keys_at] = key
        for attempt in ((seed, None) if seed is not None else (None,)):
            try:
                return robot.configuration(coords, seed=attempt)
            except StiffnessError:
                continue
        return None

    cells = np.floor(keys / _ANCHOR_CELL).astype(np.int64)
    cell_ids, first, owner = np.unique(cells, axis=0, return_index=True, return_inverse=True)
    owner = owner.reshape(-1)
    anchor_q = np.full((cell_ids.shape[0], robot.model.nq), np.nan)
    seed = None
    for c in _snake_order(cell_ids):
        k = first[c]
        q = continuation(keys[k], seed)
        if q is None:
            continue
        anchor_q[c], passive[k], ok[k], seed = q, q[passive_q], True, q
    others = np.flatnonzero((np.arange(n_keys) != first[owner]) & ok[first[owner]])
    if others.size:
        anchors = first[owner[others]]
        closed_q, good = _newton_from_anchors(robot, keys[others], keys[anchors],
                                              anchor_q[owner[others]], keys_at)
        passive[others[good]] = closed_q[good][:, passive_q]
        ok[others[good]] = True
        for k in others[~good]:
            q = continuation(keys[k], anchor_q[owner[k]])
            if q is not None:
                passive[k], ok[k] = q[passive_q], True
    # keys whose cell anchor failed: continuation from the reference assembly
    for k in np.flatnonzero(~ok & ~ok[first[owner]]):
        q = continuation(keys[k], None)
        if q is not None:
            passive[k], ok[k] = q[passive_q], True
    return passive, ok


def _newton_from_anchors(robot: Robot, keys: np.ndarray, anchor_keys: np.ndarray,
                         anchor_q: np.ndarray, keys_at: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Close the loop at each key by Newton from its anchor's closure, all keys at once.

    Predictor: the anchor's passive values plus their first-order rates times the key step.
    Corrector: Gauss-Newton on the world-axes residual of :func:`_loop_points` (its zero set is
    the closed loop), least squares by pseudo-inverse. Returns the configurations and the mask
    of keys that converged within :data:`_NEWTON_JUMP` of the prediction.
    """
    from stiffness.loops import CLOSURE_TOLERANCE_M

    model, data = robot.model, robot.data
    loop = robot.loop
    points = _loop_points(robot)
    coordinate_v = robot.coordinate_v[keys_at]
    pv = loop.passive_v
    simple = all(robot.model.joints[robot.model.getJointId(j)].nq ==
                 robot.model.joints[robot.model.getJointId(j)].nv for j in loop.passive_joints)
    passive_q = _passive_q_indices(robot)

    def residual_and_jacobian(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        m = q.shape[0]
        pos = np.empty((len(points), m, 3))
        jac = np.empty((len(points), m, 6, model.nv))
        joint_jacobians = pin.computeJointJacobians
        frame_jacobian = pin.getFrameJacobian
        for i in range(m):
            joint_jacobians(model, data, q[i])
            for f, point in enumerate(points):
                jac[f, i] = frame_jacobian(model, data, *point, LWA)
                if len(point) == 1:
                    pos[f, i] = pin.updateFramePlacement(model, data, point[0]).translation
                else:
                    pos[f, i] = (data.oMi[point[0]] * point[1]).translation
        pairs = range(0, len(points), 2)
        res = np.concatenate([pos[p + 1] - pos[p] for p in pairs], axis=1)
        c_w = np.concatenate([jac[p + 1, :, :3] - jac[p, :, :3] for p in pairs], axis=1)
        return res, c_w

    def lstsq(a: np.ndarray, b: np.ndarray, rcond: float) -> np.ndarray:
        u, s, vt = np.linalg.svd(a, full_matrices=False)
        cutoff = rcond * s[:, :1]
        s_inv = np.where(s > cutoff, 1.0 / np.where(s > cutoff, s, 1.0), 0.0)
        return ((np.swapaxes(vt, 1, 2) * s_inv[:, None, :]) @ np.swapaxes(u, 1, 2)
                @ b[..., None])[..., 0]

    def step(q: np.ndarray, dv: np.ndarray) -> np.ndarray:
        if simple:
            out = q.copy()
            out[:, passive_q] += dv
            return out
        full = np.zeros((q.shape[0], model.nv))
        full[:, pv] = dv
        return np.array([pin.integrate(model, qi, di) for qi, di in zip(q, full, strict=True)])

    # predictor from the anchors' rates
    _, c_anchor = residual_and_jacobian(anchor_q)
    u, s, vt = np.linalg.svd(c_anchor[:, :, pv], full_matrices=False)
    cutoff = 1e-9 * s[:, :1]
    s_inv = np.where(s > cutoff, 1.0 / np.where(s > cutoff, s, 1.0), 0.0)
    rates = -((np.swapaxes(vt, 1, 2) * s_inv[:, None, :]) @ np.swapaxes(u, 1, 2)
              @ c_anchor[:, :, coordinate_v])  # (m, np, d)
    coords = np.zeros((keys.shape[0], robot.n_coordinates))
    coords[:, keys_at] = keys
    q = tree_configurations(robot, coords)
    q[:, passive_q] = anchor_q[:, passive_q]
    q = step(q, (rates @ (keys - anchor_keys)[..., None])[..., 0])
    predicted = q[:, passive_q].copy()
    done = np.zeros(keys.shape[0], dtype=bool)
    active = np.arange(keys.shape[0])
    for _ in range(_NEWTON_ITERATIONS):
        res, c_w = residual_and_jacobian(q[active])
        norm = np.linalg.norm(res, axis=1)
        converged = norm < CLOSURE_TOLERANCE_M
        done[active[converged]] = True
        active = active[~converged]
        if active.size == 0:
            break
        dv = lstsq(c_w[~converged][:, :, pv], -res[~converged], 1e-10)
        q[active] = step(q[active], dv)
    if active.size:
        res, _ = residual_and_jacobian(q[active])
        done[active[np.linalg.norm(res, axis=1) < 1e3 * CLOSURE_TOLERANCE_M]] = True
    jump = np.abs(q[:, passive_q] - predicted).max(axis=1) if passive_q.size else 0.0
    return q, done & (jump <= _NEWTON_JUMP)


# ------------------------------------------------------------------------------ stiffness


def _as_loads(loads: np.ndarray, w: int) -> np.ndarray:
    """Load cases (L, 3 or 6) as (L, w) wrench components, checked."""
    loads = np.atleast_2d(np.asarray(loads, dtype=float))
    if loads.ndim != 2 or loads.shape[1] not in (3, 6):
        raise StiffnessError(
            "load cases are rows of a force (fx,fy,fz in N) or a wrench (fx,fy,fz,mx,my,mz in N, "
            f"N.m); got shape {loads.shape}"
        )
    if not np.all(np.isfinite(loads)):
        raise StiffnessError("loads must be finite numbers")
    if loads.shape[1] > w:
        if np.any(loads[:, w:] != 0.0):
            raise StiffnessError(
                "the kinematics were computed for forces only (moments=False); recompute them "
                "with moments=True to apply moments"
            )
        loads = loads[:, :w]
    out = np.zeros((loads.shape[0], w))
    out[:, : loads.shape[1]] = loads
    return out


def complementary_stiffness(kin: BatchKinematics, loads: np.ndarray,
                            twist: bool = False) -> np.ndarray:
    """K_C (m, L, n, n) for ``L`` dead load cases (N, N.m), base axes at the target.

    Parameters
    ----------
    kin
        Kinematics from :func:`batch_kinematics`.
    loads
        (L, 3) forces (N) or (L, 6) wrenches [F (N); M (N.m)], the same at every configuration.
    twist
        Return the Zefran-Kumar twist-basis K_C^tw instead (the wrench held fixed in the
        target's body axes), as ``TargetState.k_c_twist``.
    """
    wrenches = _as_loads(loads, kin.k_c_basis.shape[1])
    # basis[m, k, a, b] is stored as [m, b, a, k] for open chains: one matrix product
    k_c = np.matmul(kin.k_c_basis.transpose(0, 3, 2, 1), wrenches.T).transpose(0, 3, 2, 1)
    if twist:
        # F.(v_l x w_k) + M.(w_l x w_k) at [l, k], as in stiffness.formulation
        v, om = kin.jacobian[:, :3], kin.jacobian[:, 3:]
        f_cross = _cross_matrices(wrenches[:, :3])  # (L, 3, 3): [F x] with F.(a x b) = a^T X b
        k_c = k_c + np.einsum("mjl,Ljk,mkn->mLln", v, f_cross, om, optimize=True)
        if wrenches.shape[1] == 6:
            m_cross = _cross_matrices(wrenches[:, 3:])
            k_c = k_c + np.einsum("mjl,Ljk,mkn->mLln", om, m_cross, om, optimize=True)
    return k_c


def _cross_matrices(vectors: np.ndarray) -> np.ndarray:
    """(L, 3, 3) matrices X with ``a^T X b = v . (a x b)`` for each row v."""
    x = np.zeros((vectors.shape[0], 3, 3))
    x[:, 0, 1], x[:, 1, 0] = vectors[:, 2], -vectors[:, 2]
    x[:, 1, 2], x[:, 2, 1] = vectors[:, 0], -vectors[:, 0]
    x[:, 2, 0], x[:, 0, 2] = vectors[:, 1], -vectors[:, 1]
    return x


def as_joint_stiffness(k_theta: np.ndarray | list[float], n: int) -> np.ndarray:
    """K_theta (n, n) from n positive values (N.m/rad, N/m) or an (n, n) matrix."""
    k = np.asarray(k_theta, dtype=float)
    if k.ndim == 1:
        if k.shape[0] != n or not np.all(np.isfinite(k)) or np.any(k <= 0):
            raise StiffnessError(
                f"need {n} finite positive joint stiffnesses (N.m/rad, N/m), got {k.tolist()}"
            )
        return np.diag(k)
    if k.shape != (n, n) or not np.all(np.isfinite(k)):
        raise StiffnessError(f"K_theta must be {n} values or an ({n}, {n}) matrix")
    return k


def tangent_stiffness(k_theta: np.ndarray, k_c: np.ndarray,
                      formulation: str = "enhanced") -> np.ndarray:
    """K_theta - K_C (enhanced) or K_theta broadcast to K_C's shape (conventional)."""
    if formulation not in FORMULATIONS:
        raise StiffnessError(f"formulation must be one of {FORMULATIONS}, got {formulation!r}")
    if formulation == "enhanced":
        return k_theta - k_c
    return np.broadcast_to(k_theta, k_c.shape)


#: Matrices per block of batched linear algebra (keeps the work arrays in cache).
_BLOCK = 2048


def _cholesky_t(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cholesky factors of a batch-last stack ``a`` (n, n, M) (lower triangle read).

    Vectorised over M (one NumPy operation per entry column, not per matrix). Returns the
    lower factors and the mask of positive definite matrices (the others hold junk).
    """
    n = a.shape[0]
    low = np.zeros_like(a)
    ok = np.ones(a.shape[-1], dtype=bool)
    for j in range(n):
        d = a[j, j] - np.square(low[j, :j]).sum(axis=0) if j else a[j, j].copy()
        good = d > 0.0
        if not good.all():
            ok &= good
            d = np.where(good, d, 1.0)
        pivot = np.sqrt(d)
        low[j, j] = pivot
        if j + 1 < n:
            col = a[j + 1:, j]
            if j:
                col = col - (low[j + 1:, :j] * low[j, :j]).sum(axis=1)
            low[j + 1:, j] = col / pivot
    return low, ok


def _forward_t(low: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve ``low y = b`` for batch-last lower-triangular ``low`` (n, n, M), ``b`` (n, k, M)."""
    y = np.empty(np.broadcast_shapes(b.shape, (low.shape[0], 1, low.shape[2])))
    for i in range(low.shape[0]):
        s = b[i]
        if i:
            s = s - (low[i, :i, None] * y[:i]).sum(axis=0)
        y[i] = s / low[i, i]
    return y


def _gram_t(y: np.ndarray) -> np.ndarray:
    """``y^T y`` per matrix of a batch-last stack (n, k, M) -> (k, k, M)."""
    return (y[:, :, None] * y[:, None, :]).sum(axis=0)


def _spd_block_t(t_t: np.ndarray, j_t: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Compliance and its inverse through Cholesky factors, batch-last, symmetric tangents.

    ``C = Y^T Y`` with ``L Y = J^T`` (``T = L L^T``), ``K_X = Z^T Z`` with ``L_C Z = I``.
    ``t_t`` (n, n, M) (or (n, n, 1): the same T for all), ``j_t`` = J^T (n, r, M). Returns
    C, K_X (r, r, M) and the masks of positive definite T and C (elsewhere the results are junk
    and must be recomputed by LU).
    """
    r = j_t.shape[1]
    low, t_ok = _cholesky_t(t_t)
    c_t = _gram_t(_forward_t(low, j_t))
    low_c, c_ok = _cholesky_t(c_t)
    k_t = _gram_t(_forward_t(low_c, np.eye(r)[:, :, None]))
    return c_t, k_t, np.broadcast_to(t_ok, c_ok.shape), c_ok


def _spd_block(tangent: np.ndarray, jac: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_spd_block_t` for batch-first stacks (M, n, n), (M, r, n) -> (M, r, r)."""
    c_t, k_t, t_ok, c_ok = _spd_block_t(np.ascontiguousarray(tangent.transpose(1, 2, 0)),
                                        np.ascontiguousarray(jac.transpose(2, 1, 0)))
    return c_t.transpose(2, 0, 1), k_t.transpose(2, 0, 1), t_ok, c_ok


def _symmetric_stack(k_theta: np.ndarray, k_c: np.ndarray | None, jac: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """C, K_X (m, L, r, r) and the regular mask (m, L) for symmetric tangents, fast path.

    ``T = K_theta - K_C`` (``k_c`` (m, L, n, n)) or ``K_theta`` for every configuration
    (``k_c`` None, L = 1), ``jac`` (m, r, n). The tangents are laid out batch-last for the
    vectorised Cholesky path in cache-sized blocks; those that are not positive definite are
    redone by LU (:func:`_compliance_block`).
    """
    m, r, n = jac.shape
    n_loads = 1 if k_c is None else k_c.shape[1]
    c_out = np.empty((m, n_loads, r, r))
    k_out = np.empty((m, n_loads, r, r))
    ok_out = np.empty((m, n_loads), dtype=bool)
    step = max(1, _BLOCK // n_loads)
    for s in range(0, m, step):
        e = min(m, s + step)
        cols = (e - s) * n_loads
        j_t = jac[s:e].transpose(2, 1, 0)  # (n, r, mb)
        if n_loads > 1:
            j_t = np.broadcast_to(j_t[..., None], (n, r, e - s, n_loads))
        j_t = np.ascontiguousarray(j_t).reshape(n, r, cols)
        if k_c is None:
            t_t = k_theta[:, :, None]
        else:
            t_t = np.empty((n, n, e - s, n_loads))
            np.subtract(k_theta[:, :, None, None], k_c[s:e].transpose(2, 3, 0, 1), out=t_t)
            t_t = t_t.reshape(n, n, cols)
        c_t, k_t, ok_t, ok_c = _spd_block_t(t_t, j_t)
        c = c_t.transpose(2, 0, 1)
        k_x = k_t.transpose(2, 0, 1)
        redo = ~(ok_t & ok_c)
        if redo.any():
            idx = np.flatnonzero(redo)
            tangent = np.broadcast_to(t_t, (n, n, cols))[:, :, idx].transpose(2, 0, 1)
            c_r, k_r, t_r, _ = _compliance_block(tangent, j_t[:, :, idx].transpose(2, 1, 0),
                                                 True, False)
            c, k_x = c.copy(), k_x.copy()
            c[idx], k_x[idx] = c_r, k_r
            regular = _condition_ok(c, k_x)
            regular[idx] &= t_r & np.all(np.isfinite(k_r), axis=(1, 2))
        else:
            regular = _condition_ok(c, k_x)
        c_out[s:e] = c.reshape(e - s, n_loads, r, r)
        k_out[s:e] = k_x.reshape(e - s, n_loads, r, r)
        ok_out[s:e] = regular.reshape(e - s, n_loads)
    k_out[~ok_out] = np.nan
    return c_out, k_out, ok_out


def _solve_each(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """LU ``solve(a, b)`` of stacks (M, n, n), (M, n, k); singular systems give NaN, False."""
    try:
        return np.linalg.solve(a, b), np.ones(a.shape[0], dtype=bool)
    except np.linalg.LinAlgError:
        pass
    out = np.full(b.shape, np.nan)
    ok = np.ones(a.shape[0], dtype=bool)
    for i in range(a.shape[0]):
        try:
            out[i] = np.linalg.solve(a[i], b[i])
        except np.linalg.LinAlgError:
            ok[i] = False
    return out, ok


def _inverse_each(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """LU inverses of a stack (M, r, r), NaN for singular or non-finite matrices."""
    finite = np.all(np.isfinite(c), axis=(1, 2))
    out = np.full(c.shape, np.nan)
    ok = finite.copy()
    if finite.any():
        eye = np.broadcast_to(np.eye(c.shape[-1]), (int(finite.sum()), *c.shape[1:]))
        out[finite], ok[finite] = _solve_each(c[finite], eye)
    return out, ok


def _is_symmetric(a: np.ndarray) -> np.ndarray:
    """Per matrix: symmetric to round-off (|A - A^T| <= 1e-12 |A|, entrywise max norms)."""
    asym = np.abs(a - np.swapaxes(a, -1, -2)).max(axis=(-2, -1))
    return asym <= 1e-12 * np.abs(a).max(axis=(-2, -1))


def _condition_ok(c: np.ndarray, k_x: np.ndarray) -> np.ndarray:
    """1-norm condition estimate ``|C|_1 |C^-1|_1`` within :data:`CONDITION_LIMIT`."""
    norm_c = np.abs(c).sum(axis=-2).max(axis=-1)
    norm_k = np.abs(k_x).sum(axis=-2).max(axis=-1)
    with np.errstate(invalid="ignore", over="ignore"):
        return np.isfinite(norm_k) & (norm_c * norm_k <= CONDITION_LIMIT)


def _compliance_block(tangent: np.ndarray, jac: np.ndarray, with_k_x: bool,
                      symmetric: bool | None = None
                      ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, np.ndarray]:
    """C, K_X (or None), regular-T and regular-K_X masks of one block (M, n, n), (M, r, n).

    ``symmetric``: True when every tangent is known to be symmetric (pure forces), None to
    test each matrix.
    """
    m = tangent.shape[0]
    r = jac.shape[1]
    sym = np.ones(m, dtype=bool) if symmetric else _is_symmetric(tangent)
    if sym.all():
        c_t, k_t, ok_t, ok_c = _spd_block(tangent, jac)
        c = np.ascontiguousarray(c_t)
        k_x = np.ascontiguousarray(k_t) if with_k_x else None
        lu_t = ~ok_t
        lu_c = ~(ok_t & ok_c)
    else:
        c = np.empty((m, r, r))
        k_x = np.empty((m, r, r)) if with_k_x else None
        lu_t, lu_c = ~sym, ~sym
        if sym.any():
            idx = np.flatnonzero(sym)
            c_s, k_s, ok_t, ok_c = _spd_block(tangent[idx], jac[idx])
            c[idx], lu_t[idx] = c_s, ~ok_t
            if with_k_x:
                k_x[idx] = k_s
                lu_c[idx] = ~(ok_t & ok_c)
    t_ok = np.ones(m, dtype=bool)
    if lu_t.any():
        idx = np.flatnonzero(lu_t)
        x, ok = _solve_each(tangent[idx], np.swapaxes(jac[idx], 1, 2))
        c[idx] = jac[idx] @ x
        t_ok[idx] = ok
    kx_ok = t_ok
    if with_k_x:
        if lu_c.any():
            idx = np.flatnonzero(lu_c)
            k_x[idx], _ = _inverse_each(c[idx])
        kx_ok = t_ok & _condition_ok(c, k_x)
        if not kx_ok.all():
            k_x[~kx_ok] = np.nan
    if not t_ok.all():
        c[~t_ok] = np.nan
    return c, k_x, t_ok, kx_ok


def _compliance_stack(tangent: np.ndarray, jac: np.ndarray, with_k_x: bool,
                      symmetric: bool | None = None
                      ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, np.ndarray]:
    """:func:`_compliance_block` over a stack (..., n, n), (..., r, n) in cache-sized blocks."""
    shape = np.broadcast_shapes(tangent.shape[:-2], jac.shape[:-2])
    n, r = tangent.shape[-1], jac.shape[-2]
    t_flat = np.broadcast_to(tangent, (*shape, n, n)).reshape(-1, n, n)
    j_flat = np.broadcast_to(jac, (*shape, r, n)).reshape(-1, r, n)
    total = t_flat.shape[0]
    if total <= _BLOCK:
        c, k_x, t_ok, kx_ok = _compliance_block(t_flat, j_flat, with_k_x, symmetric)
    else:
        c = np.empty((total, r, r))
        k_x = np.empty((total, r, r)) if with_k_x else None
        t_ok = np.empty(total, dtype=bool)
        kx_ok = np.empty(total, dtype=bool)
        for s in range(0, total, _BLOCK):
            e = min(total, s + _BLOCK)
            c[s:e], kb, t_ok[s:e], kx_ok[s:e] = _compliance_block(
                t_flat[s:e], j_flat[s:e], with_k_x, symmetric)
            if with_k_x:
                k_x[s:e] = kb
    return (c.reshape(*shape, r, r), None if k_x is None else k_x.reshape(*shape, r, r),
            t_ok.reshape(shape), kx_ok.reshape(shape))


def compliance(jacobian: np.ndarray, tangent: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cartesian compliance ``C = J T^-1 J^T`` (m/N for translations), batched.

    Symmetric tangents go through a Cholesky factorisation vectorised across the batch; the
    others (and those that are not positive definite) through LAPACK's LU, as
    :func:`stiffness.formulation.compliance`.

    Parameters
    ----------
    jacobian
        (..., r, n) Jacobian rows (m/rad; rad/rad), broadcast against ``tangent``.
    tangent
        (..., n, n) tangent joint stiffness T (N.m/rad).

    Returns
    -------
    compliance, regular
        (..., r, r) compliance (NaN where T is singular) and the mask of regular T.
    """
    c, _, t_ok, _ = _compliance_stack(tangent, jacobian, with_k_x=False)
    return c, t_ok


def cartesian_stiffness(compliance_matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """K_X = C^-1 (N/m for translations), batched.

    Returns
    -------
    k_x, regular
        K_X, NaN where the compliance is singular (a condition-number estimate
        ``|C|_1 |C^-1|_1`` above :data:`CONDITION_LIMIT`, or NaN input), and the mask of
        regular entries.
    """
    c = np.asarray(compliance_matrix, dtype=float)
    shape, r = c.shape[:-2], c.shape[-1]
    flat = c.reshape(-1, r, r)
    k_x = np.empty_like(flat)
    ok = np.empty(flat.shape[0], dtype=bool)
    for s in range(0, flat.shape[0], _BLOCK):
        block = flat[s:s + _BLOCK]
        out = np.full(block.shape, np.nan)
        good = np.zeros(block.shape[0], dtype=bool)
        finite = np.all(np.isfinite(block), axis=(1, 2))
        sym = finite & _is_symmetric(np.where(finite[:, None, None], block, 0.0))
        if sym.any():
            low, pd = _cholesky_t(np.ascontiguousarray(block[sym].transpose(1, 2, 0)))
            z = _forward_t(low, np.eye(r)[:, :, None])
            idx = np.flatnonzero(sym)[pd]
            out[idx] = _gram_t(z).transpose(2, 0, 1)[pd]
            good[idx] = True
        rest = finite & ~good
        if rest.any():
            out[rest], good[rest] = _inverse_each(block[rest])
        good &= _condition_ok(block, out)
        out[~good] = np.nan
        k_x[s:s + _BLOCK], ok[s:s + _BLOCK] = out, good
    return k_x.reshape(c.shape), ok.reshape(shape)


def symmetric_eigenvalues(matrices: np.ndarray) -> np.ndarray:
    """Ascending eigenvalues of the symmetric parts, NaN for matrices holding NaN."""
    return _eigvalsh(0.5 * (matrices + np.swapaxes(matrices, -1, -2)))


def _eigvalsh(sym: np.ndarray) -> np.ndarray:
    """``eigvalsh`` of symmetric matrices, NaN for matrices holding NaN."""
    finite = np.all(np.isfinite(sym), axis=(-2, -1))
    if finite.all():
        return np.linalg.eigvalsh(sym)
    out = np.linalg.eigvalsh(np.where(finite[..., None, None], sym, 0.0))
    out[~finite] = np.nan
    return out


def definiteness_codes(matrices: np.ndarray | None = None, rtol: float = 1e-9, atol: float = 0.0,
                       eigenvalues: np.ndarray | None = None) -> np.ndarray:
    """Definiteness class codes of the quadratic forms, batched (int8).

    ``DEFINITENESS_CLASSES[code]`` names the class, with the rule of
    :func:`stiffness.formulation.definiteness`; :data:`INVALID_CLASS` (-1) where the matrix
    holds NaN. Give ``matrices`` (..., n, n) or their symmetric parts' ``eigenvalues`` (..., n).
    Matrices whose Gershgorin discs already decide PD or ND (with a margin far above the
    eigensolver's round-off) skip the eigen-decomposition.
    """
    if eigenvalues is not None:
        return _codes_from_eigenvalues(eigenvalues, rtol, atol)
    sym = 0.5 * (matrices + np.swapaxes(matrices, -1, -2))
    centre = np.diagonal(sym, axis1=-2, axis2=-1)
    radius = np.abs(sym).sum(axis=-1) - np.abs(centre)
    low, high = centre - radius, centre + radius
    with np.errstate(invalid="ignore"):
        bound = np.maximum(np.abs(low), np.abs(high)).max(axis=-1)  # >= max |eigenvalue|
        margin = atol + (rtol + 1e-12) * bound + 1e-12 * bound
        pd = low.min(axis=-1) > margin
        nd = high.max(axis=-1) < -margin
    codes = np.full(sym.shape[:-2], CLASS_CODES["PD"], dtype=np.int8)
    codes[nd] = CLASS_CODES["ND"]
    rest = ~(pd | nd)
    if rest.any():
        codes[rest] = _codes_from_eigenvalues(_eigvalsh(sym[rest]), rtol, atol)
    return codes


def _codes_from_eigenvalues(eig: np.ndarray, rtol: float, atol: float) -> np.ndarray:
    finite = np.all(np.isfinite(eig), axis=-1)
    eig = np.where(finite[..., None], eig, 0.0)
    tol = atol + rtol * np.maximum(np.abs(eig).max(axis=-1), 0.0)
    pos = eig > tol[..., None]
    neg = eig < -tol[..., None]
    codes = np.full(eig.shape[:-1], CLASS_CODES["ID"], dtype=np.int8)
    codes[~pos.any(axis=-1)] = CLASS_CODES["NSD"]
    codes[~neg.any(axis=-1)] = CLASS_CODES["PSD"]
    codes[neg.all(axis=-1)] = CLASS_CODES["ND"]
    codes[pos.all(axis=-1)] = CLASS_CODES["PD"]
    codes[~finite] = INVALID_CLASS
    return codes


def class_names(codes: np.ndarray) -> np.ndarray:
    """Class names ("PD", ..., "" for invalid) of an array of codes."""
    names = np.array([*DEFINITENESS_CLASSES, ""], dtype="<U3")
    return names[np.where(codes < 0, len(DEFINITENESS_CLASSES), codes)]


def critical_load_factor(k_theta: np.ndarray, k_c: np.ndarray) -> np.ndarray:
    """Load multiplier at which K_theta - s K_C stops being positive definite (inf if never).

    ``1 / lambda_max(K_theta^-1/2 sym(K_C) K_theta^-1/2)`` for a diagonal K_theta, as in
    :func:`stiffness.scan.definiteness_scan`; shape ``k_c.shape[:-2]``.
    """
    k_half_inv = np.diag(1.0 / np.sqrt(np.diag(k_theta)))
    sym = 0.5 * (k_c + np.swapaxes(k_c, -1, -2))
    top = _eigvalsh(k_half_inv @ sym @ k_half_inv)[..., -1]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(top > 0, 1.0 / np.where(top > 0, top, 1.0),
                        np.where(np.isnan(top), np.nan, np.inf))


def principal_stiffness(k_x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal values (ascending) and directions (columns) of the symmetric part of K_X."""
    sym = 0.5 * (k_x + np.swapaxes(k_x, -1, -2))
    finite = np.all(np.isfinite(sym), axis=(-2, -1))
    values, vectors = np.linalg.eigh(np.where(finite[..., None, None], sym, 0.0))
    values[~finite] = np.nan
    vectors[~finite] = np.nan
    return values, vectors


@dataclass
class BatchStiffness:
    """Stiffness of ``m`` configurations under ``L`` load cases (output of :func:`evaluate`).

    Attributes
    ----------
    loads
        (L, w) load cases (N, N.m).
    formulation
        "enhanced" (K_theta - K_C) or "conventional" (K_theta).
    rows
        Cartesian rows of J used: 3 (translations) or 6 ([v; omega]).
    jacobian
        (m, 6, n) target Jacobian w.r.t. the compliant joints (m/rad; rad/rad).
    k_c
        (m, L, n, n) complementary stiffness (N.m/rad).
    compliance
        (m, L, r, r) Cartesian compliance (m/N for translations), NaN where the tangent
        stiffness is singular.
    k_x
        (m, L, r, r) Cartesian stiffness (N/m for translations), NaN where singular.
    regular
        (m, L) False where K_X is NaN (invalid configuration, singular tangent stiffness or
        singular compliance).
    valid
        (m,) False for configurations whose kinematics are invalid (singular loop).
    """

    loads: np.ndarray
    formulation: str
    rows: int
    jacobian: np.ndarray
    k_c: np.ndarray
    compliance: np.ndarray
    k_x: np.ndarray
    regular: np.ndarray
    valid: np.ndarray


def evaluate(robot: Robot, q: np.ndarray | BatchKinematics, loads: np.ndarray,
             k_theta: np.ndarray | list[float], formulation: str = "enhanced",
             rows: int | None = None, block: int = 4096, method: str = "auto") -> BatchStiffness:
    """K_C, compliance and K_X of many configurations under many dead loads.

    Parameters
    ----------
    robot
        The robot.
    q
        (m, nq) closed configurations (see :func:`close_loops`), or kinematics already computed
        by :func:`batch_kinematics`.
    loads
        (L, 3) forces (N) or (L, 6) wrenches (N, N.m) applied at the target, base axes.
    k_theta
        Joint stiffness: n values (N.m/rad, N/m) or an (n, n) matrix.
    formulation
        "enhanced" (A&S eq. 10, K_theta - K_C) or "conventional" (eq. 8, K_C = 0).
    rows
        3 (translational compliance and K_X) or 6; default 3 for force loads, 6 for wrenches.
    block
        Configurations whose kinematics are held at once (memory ~2 kB each for six joints).
    method
        "hessian": kinematic Hessians (:func:`batch_kinematics`, any loads, any robot);
        "gravity": generalized-gravity derivatives (:func:`single_force_kinematics`: open
        chains, one force); "auto": "gravity" where it applies, else "hessian".

    Returns
    -------
    BatchStiffness
        Equal to the one-at-a-time :func:`stiffness.formulation.compliance` and
        :func:`~stiffness.formulation.cartesian_stiffness` to round-off.
    """
    if formulation not in FORMULATIONS:
        raise StiffnessError(f"formulation must be one of {FORMULATIONS}, got {formulation!r}")
    loads_arr = np.atleast_2d(np.asarray(loads, dtype=float))
    wrenches = _as_loads(loads_arr, 6)
    moments = bool(np.any(wrenches[:, 3:] != 0.0))
    if rows is None:
        rows = 3 if loads_arr.shape[-1] == 3 else 6
    if rows not in (3, 6):
        raise StiffnessError(f"rows must be 3 (translations) or 6, got {rows}")
    k_th = as_joint_stiffness(k_theta, robot.n_compliant)
    symmetric = bool(not moments and np.array_equal(k_th, k_th.T))
    gravity_ok = robot.loop is None and not moments and wrenches.shape[0] == 1
    if method not in ("auto", "hessian", "gravity"):
        raise StiffnessError(f"method must be auto, hessian or gravity, got {method!r}")
    if method == "gravity" and not gravity_ok:
        raise StiffnessError("method 'gravity' needs an open chain and a single force load")
    use_gravity = gravity_ok and method != "hessian" and not isinstance(q, BatchKinematics)
    if isinstance(q, BatchKinematics):
        m = q.size
        starts = [0]
    else:
        q = np.atleast_2d(np.asarray(q, dtype=float))
        m = q.shape[0]
        starts = range(0, m, block)
    n = robot.n_compliant
    n_loads = wrenches.shape[0]
    jacobian = np.empty((m, 6, n))
    k_c = np.empty((m, n_loads, n, n))
    c_x = np.empty((m, n_loads, rows, rows))
    k_x = np.empty((m, n_loads, rows, rows))
    regular = np.empty((m, n_loads), dtype=bool)
    valid = np.ones(m, dtype=bool)
    for start in starts:
        if isinstance(q, BatchKinematics):
            end, jac, kc, kin_valid = m, q.jacobian, complementary_stiffness(q, wrenches), q.valid
        elif use_gravity:
            end = min(m, start + block)
            jac, kc = single_force_kinematics(robot, q[start:end], wrenches[0, :3])
            kc, kin_valid = kc[:, None], None
        else:
            end = min(m, start + block)
            kin = batch_kinematics(robot, q[start:end], moments=moments)
            jac, kc, kin_valid = kin.jacobian, complementary_stiffness(kin, wrenches), kin.valid
        if symmetric:
            c, kx, ok = _symmetric_stack(k_th, kc if formulation == "enhanced" else None,
                                         jac[:, :rows])
        elif formulation == "enhanced":
            c, kx, _, ok = _compliance_stack(k_th - kc, jac[:, None, :rows], True)
        else:  # load-independent: once per configuration
            c, kx, _, ok = _compliance_stack(np.broadcast_to(k_th, (end - start, 1, n, n)),
                                             jac[:, None, :rows], True)
        jacobian[start:end], k_c[start:end] = jac, kc
        c_x[start:end], k_x[start:end], regular[start:end] = c, kx, ok
        if kin_valid is not None:
            valid[start:end] = kin_valid
    return BatchStiffness(wrenches[:, : 6 if moments else 3], formulation, rows, jacobian, k_c,
                          c_x, k_x, regular, valid)


# ------------------------------------------------------------------------------ definiteness map


@dataclass
class DefinitenessMap:
    """Per configuration and load case: the classes and critical load of the Table IV analysis.

    Attributes
    ----------
    k_c_class, tangent_class
        (m, L) int8 class codes of K_C and of K_theta - K_C (:data:`CLASS_CODES`).
    critical_factor
        (m, L) load multiplier at which K_theta - K_C stops being positive definite.
    determinant_positive
        (m, L) det K_C > 0 (the rule the printed Table IV appears to use).
    k_c_diagonal
        (m, 3, n) diagonal of K_C for unit forces along x, y, z (N.m/rad per N).
    """

    k_c_class: np.ndarray
    tangent_class: np.ndarray
    critical_factor: np.ndarray
    determinant_positive: np.ndarray
    k_c_diagonal: np.ndarray


def definiteness_map(kin: BatchKinematics, loads: np.ndarray, k_theta: np.ndarray,
                     rtol: float = 1e-9, k_c: np.ndarray | None = None) -> DefinitenessMap:
    """Definiteness of K_C and K_theta - K_C and the critical load factor, batched.

    The batched form of :func:`stiffness.scan.definiteness_scan` on given kinematics;
    ``k_c`` (m, L, n, n) may be passed if already computed.
    """
    k_th = as_joint_stiffness(k_theta, kin.jacobian.shape[2])
    if k_c is None:
        k_c = complementary_stiffness(kin, loads)
    diag = np.diagonal(kin.k_c_basis[:, :3], axis1=-2, axis2=-1).copy()
    finite = np.all(np.isfinite(k_c), axis=(-2, -1))
    with np.errstate(invalid="ignore"):
        det_positive = np.linalg.det(np.where(finite[..., None, None], k_c, 0.0)) > 0
    return DefinitenessMap(
        k_c_class=definiteness_codes(k_c, rtol=rtol),
        tangent_class=definiteness_codes(k_th - k_c, rtol=rtol),
        critical_factor=critical_load_factor(k_th, k_c),
        determinant_positive=det_positive & finite,
        k_c_diagonal=diag,
    )
