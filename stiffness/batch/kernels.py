"""Batched elastostatics: K_C, compliance, K_X, eigen-decomposition and definiteness for arrays
of configurations and loads at once.

The one-at-a-time API (:func:`stiffness.mechanics.formulation.target_state`) spends ~100 us of
Python per configuration. Here Pinocchio is called in a tight loop into preallocated arrays and
everything else is NumPy over the whole batch:

* Kinematic-Hessian route (:func:`batch_kinematics`; any robot, any number of loads): three
  calls per configuration of an open chain (joint kinematic Hessians, the target's frame
  Hessian, its frame Jacobian). ``K_C(W) = sum_k W_k B_k`` is linear in the wrench, so the
  kinematics keep the *unit-wrench basis* ``B_k = d(J^T e_k)/d theta`` and any number of load
  cases cost one small matrix product.
* Generalized-gravity route (:func:`single_force_kinematics`; one force): a dead
  force F at the target is gravity acting on a unit point mass there, so Pinocchio's
  ``computeGeneralizedGravityDerivatives`` on a copy of the model holding only that mass (and
  gravity -F) returns K_C(F) exactly, with no follower-load correction; with the frame
  Jacobian, two calls per configuration. :func:`evaluate` picks it for a single force.
* Closed loops: the basis is the reduced Hessian ``S^T H_k S + sum_p J[k, p] dS_p`` of
  :mod:`stiffness.mechanics.closed_loop` (the same functions as the single-pose API), with the
  velocity map S and the closure curvature dS_p computed once per distinct closure (they depend
  only on the loop coordinates, :class:`_ClosurePass`), from the loop points' frame
  Jacobians alone where every joint has one velocity coordinate
  (:func:`projected_point_hessian`), so the per-configuration Pinocchio work is the open
  chain's.
* Loop closures are the expensive part of a closed-chain configuration from coordinates:
  :func:`close_loops` closes each distinct value of the *loop coordinates* (the coordinates of
  the joints on the path between the loop frames; the others, e.g. a base rotation or a
  wrist, move the loop rigidly or not at all) once, by continuation for one anchor per small
  cell of those coordinates and by a batched Newton iteration from the anchor for the rest.
* Compliance and K_X of symmetric tangents (pure forces) go through a Cholesky factorisation
  vectorised across the batch (one NumPy operation per matrix entry, not per matrix); the
  others, and those that are not positive definite, through LAPACK's LU.

Results equal :func:`~stiffness.mechanics.formulation.target_state` and friends to round-off
(tests: relative 1e-10 on open chains, 1e-9 through a loop's pseudo-inverse). Where the
one-at-a-time API raises on a singular configuration, the batched one returns NaN and a mask.

Shapes: ``m`` configurations, ``L`` load cases, ``n`` compliant joints, ``r`` Cartesian rows
(3: translational, 6: [v; omega]). Units: SI (m, N, rad; K_C in N.m/rad; K_X in N/m for the
translational block; compliance in m/N). A :class:`~stiffness.robot.robot.Robot` holds one
Pinocchio ``Data``: use one robot per thread.

Layout: this module holds the kinematics (:func:`batch_kinematics`,
:func:`single_force_kinematics`), K_C of the load cases (:func:`complementary_stiffness`) and
the pipelines built on them (:func:`evaluate`, :func:`definiteness_map`); the loop closures are
in :mod:`stiffness.batch.loops` and the stacked linear algebra in :mod:`stiffness.batch.linalg`,
whose public names are re-exported here (``batch.close_loops``, ``batch.compliance``...).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from stiffness.batch.linalg import (
    CLASS_CODES,
    CONDITION_LIMIT,
    INVALID_CLASS,
    as_joint_stiffness,
    as_load_cases,
    cartesian_stiffness,
    class_names,
    compliance,
    compliance_stack,
    critical_load_factor,
    cross_axis0,
    cross_matrices,
    definiteness_codes,
    distinct_rows,
    load_definiteness,
    principal_stiffness,
    projected_point_hessian,
    symmetric_eigenvalues,
    symmetric_stack,
    tangent_stiffness,
)
from stiffness.batch.loops import (
    LWA,
    ClosedConfigurations,
    close_loops,
    loop_coordinate_indices,
    loop_points,
    point_supports,
    tree_configurations,
)
from stiffness.batch.poses import support_mask
from stiffness.errors import StiffnessError, UnknownNameError
from stiffness.mechanics import closed_loop
from stiffness.mechanics.formulation import FORMULATIONS, compliant_projection
from stiffness.robot.kinematics import reorder_hessian
from stiffness.robot.robot import Robot

__all__ = [
    # kinematics and pipelines (this module)
    "BatchKinematics", "BatchStiffness", "DefinitenessMap", "batch_kinematics",
    "complementary_stiffness", "definiteness_map", "evaluate", "single_force_block",
    "one_coordinate_joints", "single_force_kinematics", "unit_force_diagonal",
    # loop closures (stiffness.batch.loops)
    "LWA", "ClosedConfigurations", "close_loops", "loop_coordinate_indices",
    "tree_configurations",
    # linear algebra (stiffness.batch.linalg)
    "CLASS_CODES", "CONDITION_LIMIT", "INVALID_CLASS", "as_joint_stiffness",
    "cartesian_stiffness", "class_names", "compliance", "critical_load_factor",
    "definiteness_codes", "load_definiteness", "principal_stiffness", "symmetric_eigenvalues",
    "tangent_stiffness",
]

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
            f"{robot.title} configurations have {robot.model.nq} values (Pinocchio q), got "
            f"{q.shape[1]}"
        )
    frames = 1 + (0 if robot.loop.is_open_chain else len(loop_points(robot)))
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
    raw = np.empty((m, 6, nv, nv))
    j_full = np.empty((m, 6, nv))
    placement = np.empty((m, 4, 4)) if pose else None
    closure = None if robot.loop.is_open_chain else _ClosurePass(robot, q)

    hessians = pin.computeJointKinematicHessians
    frame_hessian = pin.getFrameKinematicHessian
    frame_jacobian = pin.getFrameJacobian
    rotation, translation = _frame_placement_views(data, fid)
    j_rows = _jacobian_rows(j_full)
    if closure is None and not pose:  # the hot loop: three calls per configuration
        for i in range(m):
            hessians(model, data, q[i])  # also computes the joint Jacobians and placements
            raw[i] = frame_hessian(model, data, fid, LWA)
            j_rows[i] = frame_jacobian(model, data, fid, LWA)
    else:
        record = (lambda i: None) if closure is None else closure.recorder(model, data)
        for i in range(m):
            hessians(model, data, q[i])
            raw[i] = frame_hessian(model, data, fid, LWA)
            j_rows[i] = frame_jacobian(model, data, fid, LWA)  # also sets data.oMf[fid]
            record(i)
            if placement is not None:
                placement[i, :3, :3] = rotation
                placement[i, :3, 3] = translation

    if placement is not None:
        placement[:, 3] = (0.0, 0.0, 0.0, 1.0)
    valid = np.ones(m, dtype=bool)
    if closure is None and not robot.compliant_is_selection:
        # mimic followers move with their leaders, coupled chain joints with their
        # controller coordinates: S is not a selection
        e = compliant_projection(robot)
        basis = np.einsum("ia,mkij,jb->mkab", e, reorder_hessian(raw)[:, :w], e, optimize=True)
        jac = j_full @ e
    elif closure is None:
        # the Hessian rows are the unit-wrench basis [m, k, a, b] (a view of raw)
        cv = robot.compliant_v
        basis = reorder_hessian(raw)[:, :w]
        if not _is_identity_selection(cv, nv):
            basis = basis[:, :, cv[:, None], cv[None, :]]
            j_full = j_full[:, :, cv]
        jac = j_full
    else:
        proj, curvature, valid = closure.derivatives(j_full)
        pv = robot.loop.passive_v
        basis = closed_loop.reduced_hessian(reorder_hessian(raw)[:, :w], j_full[:, :w, pv],
                                            proj[:, None], curvature[:, None])
        jac = j_full @ proj
    return BatchKinematics(
        q=q, jacobian=jac, k_c_basis=basis, valid=valid,
        position=None if placement is None else placement[:, :3, 3].copy(),
        rotation=None if placement is None else placement[:, :3, :3].copy(),
    )


def _is_identity_selection(index: np.ndarray, size: int) -> bool:
    return index.shape[0] == size and bool(np.all(index == np.arange(size)))


def _frame_placement_views(data: pin.Data, fid: int) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (3, 3) and translation (3,) of ``data.oMf[fid]``: NumPy views on Pinocchio's
    memory (eigenpy exposes an SE3's members by reference), valid while ``data`` lives.

    After ``pin.getFrameJacobian(model, data, fid, ...)``, which sets ``data.oMf[fid]`` on its
    way (as ``pin.updateFramePlacement`` does; the tests compare the positions with the
    single-pose ones), they hold the frame's placement: copying them out costs half as much as
    reading the SE3 ``updateFramePlacement`` returns (a copy, whose ``.translation`` makes
    another), and the loops need no placement call.
    """
    placement = data.oMf[fid]
    return placement.rotation, placement.translation


def _jacobian_rows(jacobians: np.ndarray) -> np.ndarray:
    """Where the loops store frame Jacobians (..., 6, nv): the array itself, or its (..., 6)
    view for a model with one velocity coordinate, whose Jacobians Pinocchio's bindings return
    squeezed to (6,) (the quirk :mod:`stiffness.robot.kinematics` fixes for one pose)."""
    return jacobians[..., 0] if jacobians.shape[-1] == 1 else jacobians


class _ClosurePass:
    """Closure derivatives of a block of closed configurations, once per distinct closure.

    The passive joints, and so the velocity map S and the closure curvature dS_p
    (:mod:`stiffness.mechanics.closed_loop`), depend only on the values of the loop
    coordinates (:func:`loop_coordinate_indices`): joints that are common ancestors of a loop
    move it rigidly and the others do not touch it. The loop residual's derivatives are
    recorded at the first configuration of each distinct closure while the kinematics pass
    visits it (:meth:`recorder`), and the derivatives broadcast to the others.

    Where every joint has one velocity coordinate of its own (revolute, prismatic, helical...),
    they come from the points' frame Jacobians alone (:func:`projected_point_hessian`, one
    Jacobian per point and closure); otherwise from Pinocchio's frame Jacobians and kinematic
    Hessians.
    """

    def __init__(self, robot: Robot, q: np.ndarray) -> None:
        self.robot = robot
        self.points = loop_points(robot)
        key_q = _loop_key_q_indices(robot)
        first, inverse = distinct_rows(q[:, key_q])
        self.inverse = inverse
        self.first = first
        slot = np.full(q.shape[0], -1)
        slot[first] = np.arange(first.shape[0])  # distinct closure of a first visit, else -1
        self.slot = slot.tolist()
        k, nv, n_points = first.shape[0], robot.model.nv, len(self.points)
        self.analytic = one_coordinate_joints(robot)
        self.jac = np.empty((n_points, k, 6, nv))
        if not self.analytic:
            self.raw = np.empty((n_points, k, 6, nv, nv))

    def recorder(self, model: pin.Model, data: pin.Data, hessians: bool = True
                 ) -> Callable[[int], None]:
        """``record(i)``: store what the closure derivatives need at configuration ``i`` if
        it is the first of its closure (joint Jacobians and placements done; kinematic
        Hessians too unless ``hessians`` is False)."""
        slot, points, jac = self.slot, self.points, _jacobian_rows(self.jac)
        if self.analytic:
            frame_jacobian = pin.getFrameJacobian
            numbered = list(enumerate(points))

            def record(i: int) -> None:
                k = slot[i]
                if k < 0:
                    return
                for f, point in numbered:
                    jac[f, k] = frame_jacobian(model, data, *point, LWA)
            return record
        raw = self.raw

        def record_pinocchio(i: int) -> None:
            k = slot[i]
            if k < 0:
                return
            if not hessians:
                pin.computeJointKinematicHessians(model, data)
            for f, point in enumerate(points):
                raw[f, k] = pin.getFrameKinematicHessian(model, data, *point, LWA)
                jac[f, k] = pin.getFrameJacobian(model, data, *point, LWA)
        return record_pinocchio

    def derivatives(self, j_target: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Velocity maps (m, nv, n), curvatures (m, n_p, n, n) and validity (m,).

        ``j_target`` (m, >=3, nv): the target's Jacobian (linear rows first) at every
        configuration; a free passive motion is idle where it does not move the target at the
        first configuration of its closure (:mod:`stiffness.mechanics.closed_loop`).
        """
        robot = self.robot
        cv, pv = robot.compliant_v, robot.loop.passive_v
        base = compliant_projection(robot)
        target_passive = j_target[self.first, :3][:, :, pv]
        pairs = range(0, len(self.points), 2)
        if self.analytic:
            jac = self.jac  # (n_p, k, 6, nv), zero outside each point's support
            c = np.concatenate([jac[p + 1, :, :3] - jac[p, :, :3] for p in pairs], axis=1)
            proj, pinv, valid, _ = closed_loop.velocity_map(c, cv, pv, base, target_passive)
            proj_t = np.ascontiguousarray(proj.transpose(1, 2, 0))
            point_hss = []
            for f, support in enumerate(point_supports(robot)):  # its support columns only
                idx = np.flatnonzero(support)
                point_j = np.ascontiguousarray(jac[f][:, :, idx].transpose(1, 2, 0))  # (6, s, k)
                point_hss.append(projected_point_hessian(point_j[:3], point_j[3:], proj_t[idx]))
            hss = np.concatenate([point_hss[p + 1] - point_hss[p] for p in pairs], axis=1)
        else:
            c = np.concatenate([self.jac[p + 1, :, :3] - self.jac[p, :, :3] for p in pairs],
                               axis=1)
            hc = np.concatenate([reorder_hessian(self.raw[p + 1])[:, :3]
                                 - reorder_hessian(self.raw[p])[:, :3] for p in pairs], axis=1)
            proj, pinv, valid, _ = closed_loop.velocity_map(c, cv, pv, base, target_passive)
            hss = np.swapaxes(proj, 1, 2)[:, None] @ hc @ proj[:, None]
        curvature = closed_loop.closure_curvature(pinv, hss)
        if not valid.all():
            curvature[~valid] = np.nan
        at = self.inverse
        return proj[at], curvature[at], valid[at]


def unit_force_diagonal(robot: Robot, jacobian: np.ndarray) -> np.ndarray:
    """Diagonal of K_C under the unit forces x, y, z (m, 3, n), N.m/rad per N, from the target
    Jacobian alone, for open chains whose joints have one velocity coordinate each (others:
    the diagonal of :func:`batch_kinematics`'s ``k_c_basis``).

    ``K_C(e_k)[a, a] = d2 x_k / dq_a^2 = (omega_a x v_a)_k`` (the point Hessian of
    :func:`projected_point_hessian` on its diagonal), with ``[v_a; omega_a]`` the columns of the
    (m, 6, n) Jacobian, rows [v; omega].
    """
    if not robot.loop.is_open_chain or not one_coordinate_joints(robot) \
            or robot.springs_on_controller:  # a controller coordinate's column mixes joints
        raise StiffnessError(
            f"{robot.title}: the unit-force K_C diagonal is read off the Jacobian only for open "
            "chains of one-coordinate joints, each its own coordinate; take the diagonal of "
            "batch_kinematics' k_c_basis")
    v, om = jacobian[:, :3], jacobian[:, 3:]
    return cross_axis0(om.transpose(1, 0, 2), v.transpose(1, 0, 2)).transpose(1, 0, 2)


def _loop_key_q_indices(robot: Robot) -> np.ndarray:
    """Positions in q of the loop coordinates (:func:`loop_coordinate_indices`)."""
    model = robot.model
    out: list[int] = []
    for i in loop_coordinate_indices(robot):
        joint = model.joints[model.getJointId(robot.coordinate_joints[i])]
        out.extend(range(joint.idx_q, joint.idx_q + joint.nq))
    return np.array(out, dtype=int)


def one_coordinate_joints(robot: Robot) -> bool:
    """Whether the Jacobian-based Hessians apply (:func:`projected_point_hessian`,
    :func:`unit_force_diagonal`): every joint of the model has one velocity coordinate of its
    own and none is a mimic or composite joint."""
    model = robot.model
    for joint in list(model.joints)[1:]:
        name = joint.shortname()
        if joint.nv != 1 or "Mimic" in name or "Composite" in name:
            return False
    return True


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
    """Target Jacobian and K_C under one dead force, two Pinocchio calls per configuration.

    ``K_C(F) = dg/dq`` of :func:`_point_mass_model` with gravity ``-F``
    (``computeGeneralizedGravityDerivatives``), the Jacobian from the joint Jacobians that call
    leaves in ``data``. Faster than :func:`batch_kinematics` for a single load case. On a
    closed loop, the tree term of the reduced K_C
    (:func:`stiffness.mechanics.closed_loop.reduced_hessian`) is ``dg/dq``, or, where every
    joint has one velocity coordinate, ``F . d2p/dq2`` from the target's Jacobian with no
    derivative call (:func:`_closed_point_force_block`), with the closure derivatives of each
    distinct closure (:class:`_ClosurePass`).

    Parameters
    ----------
    robot
        The robot.
    q
        (m, nq) configurations (loops closed).
    force
        (3,) dead force at the target (N), base axes.

    Returns
    -------
    jacobian, k_c
        (m, 6, n) target Jacobian and (m, n, n) K_C (N.m/rad) w.r.t. the compliant joints;
        NaN where a loop is singular.
    """
    jac, k_c, _, _ = single_force_block(robot, q, force)
    return jac, k_c


def single_force_block(robot: Robot, q: np.ndarray, force: np.ndarray, pose: bool = False
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """:func:`single_force_kinematics`, the validity mask (m,) and, with ``pose``, the target
    positions (m, 3) in m (else None)."""
    model, data = _point_mass_model(robot)
    force = np.asarray(force, dtype=float).reshape(3)
    # gravity -F: the generalized gravity J^T F, whose derivative is K_C(F)
    model.gravity = pin.Motion(-force, np.zeros(3))
    q = np.ascontiguousarray(np.atleast_2d(np.asarray(q, dtype=float)))
    m, nv = q.shape[0], model.nv
    fid = robot.target_frame_id
    dg = np.empty((m, nv, nv))
    j_full = np.empty((m, 6, nv))
    gravity_derivatives = pin.computeGeneralizedGravityDerivatives
    frame_jacobian = pin.getFrameJacobian
    position = np.empty((m, 3)) if pose else None
    closure = None if robot.loop.is_open_chain else _ClosurePass(robot, q)
    if closure is not None and closure.analytic:
        return _closed_point_force_block(robot, model, data, q, force, closure, position)
    translation = _frame_placement_views(data, fid)[1]
    j_rows = _jacobian_rows(j_full)
    if closure is None and not pose:
        for i in range(m):
            dg[i] = gravity_derivatives(model, data, q[i])  # also fills the joint Jacobians
            j_rows[i] = frame_jacobian(model, data, fid, LWA)
    else:
        record = ((lambda i: None) if closure is None
                  else closure.recorder(model, data, hessians=False))
        for i in range(m):
            dg[i] = gravity_derivatives(model, data, q[i])
            j_rows[i] = frame_jacobian(model, data, fid, LWA)  # also sets data.oMf[fid]
            record(i)
            if position is not None:
                position[i] = translation
    if closure is None and not robot.compliant_is_selection:
        e = compliant_projection(robot)  # mimic followers, coupled chain joints
        return j_full @ e, e.T @ dg @ e, np.ones(m, dtype=bool), position
    if closure is None:
        cv = robot.compliant_v
        if not _is_identity_selection(cv, nv):
            dg = dg[:, cv[:, None], cv[None, :]]
            j_full = j_full[:, :, cv]
        return j_full, dg, np.ones(m, dtype=bool), position
    proj, curvature, valid = closure.derivatives(j_full)
    k_c = closed_loop.reduced_hessian(dg, (force @ j_full[:, :3])[:, robot.loop.passive_v],
                                      proj, curvature)
    return j_full @ proj, k_c, valid, position


def _closed_point_force_block(robot: Robot, model: pin.Model, data: pin.Data, q: np.ndarray,
                              force: np.ndarray, closure: _ClosurePass,
                              position: np.ndarray | None
                              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """:func:`single_force_block` on a closed loop whose joints have one velocity coordinate
    each, with no derivative call: per configuration the joint Jacobians and the target's
    frame Jacobian (and the loop points' at the first configuration of each closure).

    For a dead force F at the target p, the tree term of K_C is ``F . d2p/dq2``, which the
    target's Jacobian gives (``d2p/dq_a dq_b = omega_a x v_b(p)``), projected on the velocity
    map S without forming it (:func:`projected_point_hessian`, as for the loop points); the
    closure term is :func:`stiffness.mechanics.closed_loop.closure_term`.
    """
    m, fid = q.shape[0], robot.target_frame_id
    j_full = np.empty((m, 6, model.nv))
    joint_jacobians, frame_jacobian = pin.computeJointJacobians, pin.getFrameJacobian
    translation = _frame_placement_views(data, fid)[1]
    record = closure.recorder(model, data, hessians=False)
    j_rows = _jacobian_rows(j_full)
    for i in range(m):
        joint_jacobians(model, data, q[i])
        j_rows[i] = frame_jacobian(model, data, fid, LWA)  # also sets data.oMf[fid]
        record(i)
        if position is not None:
            position[i] = translation
    proj, curvature, valid = closure.derivatives(j_full)
    support = support_mask(model, model.frames[fid].parentJoint)
    target_j = np.ascontiguousarray(j_full[:, :, support].transpose(1, 2, 0))  # (6, s, m)
    proj_t = np.ascontiguousarray(proj[:, support].transpose(1, 2, 0))  # (s, n, m)
    tree = projected_point_hessian(target_j[:3], target_j[3:], proj_t, along=force)
    k_c = tree + closed_loop.closure_term((force @ j_full[:, :3])[:, robot.loop.passive_v],
                                          curvature)
    return j_full @ proj, k_c, valid, position


# ------------------------------------------------------------------------------ stiffness


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
    wrenches = as_load_cases(loads, kin.k_c_basis.shape[1])
    # basis[m, k, a, b] is stored as [m, b, a, k] for open chains: one matrix product
    k_c = np.matmul(kin.k_c_basis.transpose(0, 3, 2, 1), wrenches.T).transpose(0, 3, 2, 1)
    if twist:
        # F.(v_l x w_k) + M.(w_l x w_k) at [l, k], as in stiffness.mechanics.formulation
        v, om = kin.jacobian[:, :3], kin.jacobian[:, 3:]
        f_cross = cross_matrices(wrenches[:, :3])  # (L, 3, 3): [F x] with F.(a x b) = a^T X b
        k_c = k_c + np.einsum("mjl,Ljk,mkn->mLln", v, f_cross, om, optimize=True)
        if wrenches.shape[1] == 6:
            m_cross = cross_matrices(wrenches[:, 3:])
            k_c = k_c + np.einsum("mjl,Ljk,mkn->mLln", om, m_cross, om, optimize=True)
    return k_c


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
        "gravity": generalized-gravity derivatives (:func:`single_force_kinematics`: one
        force); "auto": "gravity" where it applies, else "hessian".

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
    wrenches = as_load_cases(loads_arr, 6)
    moments = bool(np.any(wrenches[:, 3:] != 0.0))
    if rows is None:
        rows = 3 if loads_arr.shape[-1] == 3 else 6
    if rows not in (3, 6):
        raise StiffnessError(f"rows must be 3 (translations) or 6, got {rows}")
    k_th = as_joint_stiffness(k_theta, robot.n_compliant)
    symmetric = bool(not moments and np.array_equal(k_th, k_th.T))
    gravity_ok = not moments and wrenches.shape[0] == 1
    if method not in ("auto", "hessian", "gravity"):
        raise UnknownNameError(f"method must be auto, hessian or gravity, got {method!r}",
                               name=method, choices=("auto", "hessian", "gravity"))
    if method == "gravity" and not gravity_ok:
        raise StiffnessError("method 'gravity' needs a single force load (no moments)")
    use_gravity = gravity_ok and method != "hessian" and not isinstance(q, BatchKinematics)
    starts: Sequence[int]
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
            jac, kc, kin_valid, _ = single_force_block(robot, q[start:end], wrenches[0, :3])
            kc = kc[:, None]
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

    The batched form of :func:`stiffness.workspace.definiteness.definiteness_scan` on given
    kinematics;
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
