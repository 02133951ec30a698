"""Batched elastostatics: K_C, compliance, K_X, eigen-decomposition and definiteness for arrays
of configurations and loads at once.

The one-at-a-time API (:func:`stiffness.mechanics.formulation.target_state`) spends ~100 us of
Python per
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
  ``S^T (H_k - sum_j Lambda_jk Hc_j) S`` of :mod:`stiffness.mechanics.formulation`, with the
  multipliers
  per unit wrench ``Lambda = pinv(C_p^T) J_p^T`` and the velocity map ``S``, batched.
* Loop closures are the expensive part of a closed-chain configuration: :func:`close_loops`
  closes each distinct value of the *loop coordinates* (the coordinates of the joints on the
  path between the loop frames; the others, e.g. the SK120's theta1 and wrist, move the loop
  rigidly or not at all) once, by continuation for one anchor per small cell of those
  coordinates and by a batched Newton iteration from the anchor for the rest.
* Compliance and K_X of symmetric tangents (pure forces) go through a Cholesky factorisation
  vectorised across the batch (one NumPy operation per matrix entry, not per matrix); the
  others, and those that are not positive definite, through LAPACK's LU.

Results equal :func:`~stiffness.mechanics.formulation.target_state` and friends to round-off (tests:
relative 1e-10 on open chains, 1e-9 through a loop's pseudo-inverse). Where the one-at-a-time
API raises on a singular configuration, the batched one returns NaN and a mask.

Shapes: ``m`` configurations, ``L`` load cases, ``n`` compliant joints, ``r`` Cartesian rows
(3: translational, 6: [v; omega]). Units: SI (m, N, rad; K_C in N.m/rad; K_X in N/m for the
translational block; compliance in m/N). A :class:`~stiffness.model.robot.Robot` holds one
Pinocchio ``Data``: use one robot per thread.

Layout: this module holds the kinematics (:func:`batch_kinematics`,
:func:`single_force_kinematics`), K_C of the load cases (:func:`complementary_stiffness`) and
the pipelines built on them (:func:`evaluate`, :func:`definiteness_map`); the loop closures are
in :mod:`stiffness.batch.loops` and the stacked linear algebra in :mod:`stiffness.batch.linalg`,
whose public names are re-exported here (``batch.close_loops``, ``batch.compliance``...).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from stiffness.batch.linalg import (
    CLASS_CODES,
    CONDITION_LIMIT,
    INVALID_CLASS,
    as_joint_stiffness,
    cartesian_stiffness,
    class_names,
    compliance,
    compliance_stack,
    critical_load_factor,
    definiteness_codes,
    principal_stiffness,
    symmetric_eigenvalues,
    symmetric_stack,
    tangent_stiffness,
)
from stiffness.batch.loops import (
    LWA,
    ClosedConfigurations,
    _loop_points,
    close_loops,
    loop_coordinate_indices,
    tree_configurations,
)
from stiffness.errors import StiffnessError, UnknownNameError
from stiffness.mechanics.formulation import FORMULATIONS
from stiffness.model.kinematics import reorder_hessian
from stiffness.model.robot import Robot

__all__ = [
    # kinematics and pipelines (this module)
    "BatchKinematics", "BatchStiffness", "DefinitenessMap", "batch_kinematics",
    "complementary_stiffness", "definiteness_map", "evaluate", "single_force_kinematics",
    # loop closures (stiffness.batch.loops)
    "LWA", "ClosedConfigurations", "close_loops", "loop_coordinate_indices",
    "tree_configurations",
    # linear algebra (stiffness.batch.linalg)
    "CLASS_CODES", "CONDITION_LIMIT", "INVALID_CLASS", "as_joint_stiffness",
    "cartesian_stiffness", "class_names", "compliance", "critical_load_factor",
    "definiteness_codes", "principal_stiffness", "symmetric_eigenvalues", "tangent_stiffness",
]

#: Rank tolerance of the passive-joint constraint block, as in
#: :func:`stiffness.mechanics.formulation.velocity_projection`.
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
        Equal to :func:`stiffness.mechanics.formulation.target_states` to round-off. The raw
        Hessians
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
    if robot.loop is None and robot.mimics:
        # mimic followers move with their leaders: S is not a selection (as
        # formulation.velocity_projection)
        e = _partial_projection(robot, nv)
        basis = np.einsum("ia,mkij,jb->mkab", e, reorder_hessian(raw)[:, :w], e, optimize=True)
        jac = j_full @ e
    elif robot.loop is None:
        # the Hessian rows are the unit-wrench basis [m, k, a, b] (a view of raw)
        basis = reorder_hessian(raw)[:, :w]
        if not _is_identity_selection(cv, nv):
            basis = basis[:, :, cv[:, None], cv[None, :]]
            j_full = j_full[:, :, cv]
        jac = j_full
    else:
        basis, jac, valid = _closed_loop_basis(robot, reorder_hessian(raw), j_full, raw_loop,
                                               j_loop, w, loop_pos, loop_jac)
    return BatchKinematics(
        q=q, jacobian=jac, k_c_basis=basis, valid=valid,
        position=None if placement is None else placement[:, :3, 3].copy(),
        rotation=None if placement is None else placement[:, :3, :3].copy(),
    )


def _partial_projection(robot: Robot, nv: int) -> np.ndarray:
    """(nv, n) rates of the compliant joints (identity) and their mimic followers."""
    n = robot.n_compliant
    e = np.zeros((nv, n))
    e[robot.compliant_v, np.arange(n)] = 1.0
    for mimic in robot.mimics:
        e[robot.joint_v_index(mimic.follower)] = mimic.multiplier * e[
            robot.joint_v_index(mimic.leader)]
    return e


def _determined_target(d_p: np.ndarray, s: np.ndarray, scale: np.ndarray,
                       j_passive: np.ndarray) -> np.ndarray:
    """Per configuration: whether the target position is determined by the closure.

    Passive motions the constraints leave free (null space of ``d_p``, (m, R, np)) are allowed
    when they do not move the target (``j_passive``: (m, 3, np) position Jacobian columns), as
    in :func:`stiffness.mechanics.formulation.velocity_projection`.
    """
    n_passive = d_p.shape[2]
    rank = np.sum(s > _RANK_RTOL * scale[:, None], axis=1)
    valid = np.ones(d_p.shape[0], dtype=bool)
    for i in np.flatnonzero(rank < n_passive):
        null = np.linalg.svd(d_p[i])[2][rank[i]:].T
        j = j_passive[i]
        moved = np.linalg.norm(j @ null, axis=0)
        valid[i] = not np.any(moved > 1e-8 * max(1.0, float(np.abs(j).max(initial=0.0))))
    return valid


def _is_identity_selection(index: np.ndarray, size: int) -> bool:
    return index.shape[0] == size and bool(np.all(index == np.arange(size)))


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
    pv = loop.passive_v
    pairs = range(0, raw_loop.shape[0], 2)
    c_w = np.concatenate([j_loop[p + 1, :, :3] - j_loop[p, :, :3] for p in pairs],
                         axis=1)  # (m, R, nv)
    hc = np.concatenate([
        reorder_hessian(raw_loop[p + 1])[:, :3] - reorder_hessian(raw_loop[p])[:, :3]
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
    valid = _determined_target(d_p, s, scale, j_full[:, :3, pv])
    cutoff = _RANK_RTOL * s[:, :1]
    s_inv = np.where(s > cutoff, 1.0 / np.where(s > cutoff, s, 1.0), 0.0)
    partial = _partial_projection(robot, nv)
    rates = -((np.swapaxes(vt, 1, 2) * s_inv[:, None, :]) @ np.swapaxes(u, 1, 2)
              @ (d_s @ partial))  # -pinv(D_p) D S_c (S_c: compliant joints and followers)
    proj = np.repeat(partial[None], m, axis=0)
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
        # F.(v_l x w_k) + M.(w_l x w_k) at [l, k], as in stiffness.mechanics.formulation
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
        Equal to the one-at-a-time :func:`stiffness.mechanics.formulation.compliance` and
        :func:`~stiffness.mechanics.formulation.cartesian_stiffness` to round-off.
    """
    if formulation not in FORMULATIONS:
        raise UnknownNameError(f"formulation must be one of {', '.join(FORMULATIONS)}, got "
                               f"{formulation!r}", name=formulation, choices=FORMULATIONS)
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
        raise UnknownNameError(f"method must be auto, hessian or gravity, got {method!r}",
                               name=method, choices=("auto", "hessian", "gravity"))
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
            c, kx, ok = symmetric_stack(k_th, kc if formulation == "enhanced" else None,
                                         jac[:, :rows])
        elif formulation == "enhanced":
            c, kx, _, ok = compliance_stack(k_th - kc, jac[:, None, :rows], True)
        else:  # load-independent: once per configuration
            c, kx, _, ok = compliance_stack(np.broadcast_to(k_th, (end - start, 1, n, n)),
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

    The batched form of :func:`stiffness.scan.definiteness.definiteness_scan` on given kinematics;
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
