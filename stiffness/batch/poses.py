"""Placements, joint Jacobians and gravity torques of many configurations of one Pinocchio
model, for array algebra over the rows (the pose model's evaluation,
:mod:`stiffness.calibration.pose_model`).

Pinocchio is called once per configuration in a tight loop that copies its results into
preallocated arrays (``data.oMi``'s members and ``data.J`` are NumPy views on Pinocchio's
memory, read without a copy of their own); everything derived from them (frame placements,
the Jacobian of a point fixed to a frame) is NumPy over the whole batch.

Shapes: ``m`` configurations, ``F`` frames (or points), ``nj`` joints (the universe
included). Units: SI (m, rad).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from stiffness.batch.linalg import cross, cross_matrices


@dataclass
class JointPlacements:
    """Every joint's placement in the world of ``m`` configurations.

    Attributes
    ----------
    rotation
        (m, nj, 3, 3) ``data.oMi[j].rotation``.
    translation
        (m, nj, 3) ``data.oMi[j].translation`` (m).
    jacobian
        (m, 6, nv) Pinocchio's joint Jacobians ``data.J`` (world axes, the spatial velocity
        at the world origin: rows [v (m/rad); omega (rad/rad)]), or ``None`` when not asked.
    """

    rotation: np.ndarray
    translation: np.ndarray
    jacobian: np.ndarray | None


@dataclass(frozen=True)
class JointKinds:
    """What the array kinematics read of a model's joints (:func:`joint_kinds`): read once
    for the copies of a model that differ only in placements, gravity or inertias.

    Attributes
    ----------
    axes
        (revolute, unit axis (3,) in the joint's frame) of each joint after the universe, or
        ``None`` when one is not a revolute or prismatic joint about or along a fixed axis.
    chain
        With ``axes``: (parent joint, ``idx_q``, ``idx_v``, the axis as a tuple of floats) of
        each joint after the universe (read from the bindings once, not at each placement).
    """

    axes: list[tuple[bool, np.ndarray]] | None
    chain: list[tuple[int, int, int, tuple[float, ...]]] = field(default_factory=list)


def joint_kinds(model: pin.Model) -> JointKinds:
    """The model's :class:`JointKinds`."""
    axes = _axis_joints(model)
    chain = [] if axes is None else [
        (int(model.parents[j]), int(model.joints[j].idx_q), int(model.joints[j].idx_v),
         tuple(float(a) for a in local)) for j, (_, local) in enumerate(axes, start=1)]
    return JointKinds(axes, chain)


def joint_placements(model: pin.Model, data: pin.Data, q: np.ndarray, jacobians: bool = True,
                     kinds: JointKinds | None = None) -> JointPlacements:
    """Joint placements (and joint Jacobians) of the (m, nq) configurations ``q``; ``kinds``
    the model's :func:`joint_kinds` when known (else read from ``model``).

    A model whose joints all turn or slide along a fixed axis (Pinocchio's ``R{X,Y,Z}``,
    ``P{X,Y,Z}``, ``RevoluteUnaligned``, ``PrismaticUnaligned``) is placed by array algebra over
    the configurations, joint after joint (:func:`_axis_joints`):
    ``oMi[j] = oMi[parent] M_j exp(q_j a_j)``, and the
    Jacobian column of joint ``j`` is ``[o_j x w_j; w_j]`` (revolute, ``w_j = R_j a_j``) or
    ``[R_j a_j; 0]`` (prismatic), Pinocchio's to round-off (tests). Any other model calls
    ``pin.computeJointJacobians`` (``pin.forwardKinematics`` without Jacobians) per
    configuration; ``data`` is then scratch space.
    """
    kinds = joint_kinds(model) if kinds is None else kinds
    axes = kinds.axes
    if axes is None:
        return pinocchio_placements(model, data, q, jacobians)
    m, nj = q.shape[0], model.njoints
    rotation = np.empty((m, nj, 3, 3))
    translation = np.empty((m, nj, 3))
    rotation[:, 0], translation[:, 0] = np.eye(3), 0.0
    jacobian = np.zeros((m, 6, model.nv)) if jacobians else None
    for j, ((revolute, local), (parent, idx_q, idx_v, key)) in enumerate(
            zip(axes, kinds.chain, strict=True), start=1):
        placement = model.jointPlacements[j]
        rot = rotation[:, parent] @ placement.rotation
        translation[:, j] = rotation[:, parent] @ placement.translation + translation[:, parent]
        value = q[:, idx_q]
        axis = rot @ local  # world axes; the joint's own motion keeps it
        if revolute:
            rotation[:, j] = rot @ _axis_rotations(key, value)
        else:
            rotation[:, j] = rot
            translation[:, j] += axis * value[:, None]
        if jacobian is not None:
            if revolute:
                jacobian[:, 3:, idx_v] = axis
                jacobian[:, :3, idx_v] = cross(translation[:, j], axis)
            else:
                jacobian[:, :3, idx_v] = axis
    return JointPlacements(rotation, translation, jacobian)


def _axis_joints(model: pin.Model) -> list[tuple[bool, np.ndarray]] | None:
    """(revolute, unit axis (3,) in the joint's frame) of each joint after the universe, or
    ``None`` when one is not a revolute or prismatic joint about or along a fixed axis."""
    out = []
    for j in range(1, model.njoints):
        kind = model.joints[j].shortname().replace("JointModel", "")
        if kind in ("RevoluteUnaligned", "PrismaticUnaligned"):
            out.append((kind[0] == "R", np.asarray(model.joints[j].extract().axis, float)))
        elif len(kind) == 2 and kind[0] in "RP" and kind[1] in "XYZ":
            out.append((kind[0] == "R", np.eye(3)["XYZ".index(kind[1])]))
        else:
            return None
    return out


def _axis_rotations(axis: tuple[float, ...], angle: np.ndarray) -> np.ndarray:
    """(m, 3, 3) rotations by ``angle`` (m,) (rad) about the unit ``axis`` (3 floats)
    (Rodrigues: ``I + sin K + (1 - cos) K^2``)."""
    eye, k, k2 = _axis_matrices(axis)
    return eye + np.sin(angle)[:, None, None] * k + (1.0 - np.cos(angle))[:, None, None] * k2


@functools.lru_cache(maxsize=256)
def _axis_matrices(axis: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``I``, ``K`` and ``K^2`` (3, 3) of :func:`_axis_rotations` for a joint axis, built once
    per axis (read-only): at each joint of each array kinematics they cost as much as the
    rotations."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]],
                  [-axis[1], axis[0], 0.0]])
    out = (np.eye(3), k, k @ k)
    for a in out:
        a.setflags(write=False)
    return out


def pinocchio_placements(model: pin.Model, data: pin.Data, q: np.ndarray, jacobians: bool
                          ) -> JointPlacements:
    """:func:`joint_placements` by one Pinocchio call per configuration, whatever the joints
    (the cheaper for a few rows: the array algebra's cost is per joint, about 0.1 ms on the
    SK120's eight joints whatever the rows, Pinocchio's per row, about 5 us)."""
    m, nj = q.shape[0], model.njoints
    rotation = np.empty((m, nj, 3, 3))
    translation = np.empty((m, nj, 3))
    jacobian = np.empty((m, 6, model.nv)) if jacobians else None
    rot_views = [data.oMi[j].rotation for j in range(nj)]
    trans_views = [data.oMi[j].translation for j in range(nj)]
    j_view = np.reshape(data.J, (6, model.nv))  # a view (squeezed when nv = 1)
    for i in range(m):
        if jacobian is not None:
            pin.computeJointJacobians(model, data, q[i])
            jacobian[i] = j_view
        else:
            pin.forwardKinematics(model, data, q[i])
        rotation[i] = rot_views
        translation[i] = trans_views
    return JointPlacements(rotation, translation, jacobian)


def frame_placements(model: pin.Model, kin: JointPlacements, frame_ids: list[int]
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Rotations (m, F, 3, 3) and translations (m, F, 3) of frames ``frame_ids`` in the world
    (``oMi[parent] * placement``, as ``pin.updateFramePlacements``)."""
    parents = [int(model.frames[f].parentJoint) for f in frame_ids]
    local_rot = np.array([model.frames[f].placement.rotation for f in frame_ids]).reshape(-1, 3, 3)
    local_t = np.array([model.frames[f].placement.translation for f in frame_ids]).reshape(-1, 3)
    rot_p, t_p = kin.rotation[:, parents], kin.translation[:, parents]
    return rot_p @ local_rot, np.einsum("mfab,fb->mfa", rot_p, local_t) + t_p


def support_mask(model: pin.Model, joint: int) -> np.ndarray:
    """(nv,) mask of the velocity coordinates of the joints that move ``joint``'s body (every
    coordinate of a joint with several, a free-flyer base's six)."""
    mask = np.zeros(model.nv, dtype=bool)
    for j in list(model.supports[joint])[1:]:
        mask[model.joints[j].idx_v: model.joints[j].idx_v + model.joints[j].nv] = True
    return mask


def support_masks(model: pin.Model, frame_ids: list[int]) -> np.ndarray:
    """(F, nv) 1 where a velocity coordinate moves frame ``frame_ids[f]``, else 0."""
    return np.array([support_mask(model, int(model.frames[f].parentJoint)) for f in frame_ids],
                    dtype=float).reshape(len(frame_ids), model.nv)


def point_jacobians(model: pin.Model, kin: JointPlacements, frame_ids: list[int],
                    points: np.ndarray, masks: np.ndarray | None = None) -> np.ndarray:
    """d point / d v (m, F, 3, nv), world axes, of points (m, F, 3) (world, m) fixed to
    frames ``frame_ids``: ``J_v - [p]x J_omega`` over the joints that move each frame (the
    columns of ``pin.getFrameJacobian(..., LOCAL_WORLD_ALIGNED)`` moved to the point);
    ``masks`` their :func:`support_masks` when known (a walk of each frame's chain)."""
    masks = support_masks(model, frame_ids) if masks is None else masks
    return moving_point_jacobians(kin, points, masks)


def moving_point_jacobians(kin: JointPlacements, points: np.ndarray, masks: np.ndarray
                           ) -> np.ndarray:
    """d point / d v (m, P, 3, nv), world axes, of points (m, P, 3) (world, m) each fixed to a
    body, ``masks`` (P, nv) the velocity coordinates that move each body
    (:func:`support_mask`): :func:`point_jacobians` of points not named by frames."""
    assert kin.jacobian is not None
    j_v, j_w = kin.jacobian[:, None, :3], kin.jacobian[:, None, 3:]
    lever = cross_matrices(points.reshape(-1, 3)).reshape(points.shape + (3,))
    # cross_matrices(p) is -[p]x: J_v + X J_omega = J_v - [p]x J_omega
    return (j_v + lever @ j_w) * masks[None, :, None, :]


def generalized_gravity(model: pin.Model, data: pin.Data, q: np.ndarray) -> np.ndarray:
    """(m, nv) ``pin.computeGeneralizedGravity`` of the (m, nq) configurations ``q`` (N.m or
    N)."""
    out = np.empty((q.shape[0], model.nv))
    gravity = pin.computeGeneralizedGravity
    for i in range(q.shape[0]):
        out[i] = gravity(model, data, q[i])
    return out


def integrate(model: pin.Model, q: np.ndarray, v: np.ndarray, kinds: JointKinds | None = None
              ) -> np.ndarray:
    """(m, nq) ``pin.integrate`` of each (m, nq) configuration by its (m, nv) or (nv,)
    displacement; ``kinds`` as for :func:`joint_placements`."""
    axes = _axis_joints(model) if kinds is None else kinds.axes
    if axes is not None:  # q and v are the same coordinates
        return q + v
    v = np.broadcast_to(v, (q.shape[0], model.nv))
    out = np.empty_like(q)
    step = pin.integrate
    for i in range(q.shape[0]):
        out[i] = step(model, q[i], v[i])
    return out


def frame_jacobians(model: pin.Model, data: pin.Data, q: np.ndarray, frame_id: int
                    ) -> np.ndarray:
    """(m, 6, nv) ``pin.getFrameJacobian(..., LOCAL_WORLD_ALIGNED)`` of one frame at the
    (m, nq) configurations ``q`` (after ``pin.computeJointJacobians``)."""
    out = np.empty((q.shape[0], 6, model.nv))
    rows = out[..., 0] if model.nv == 1 else out  # one coordinate: Pinocchio squeezes to (6,)
    jacobians, frame_jacobian = pin.computeJointJacobians, pin.getFrameJacobian
    for i in range(q.shape[0]):
        jacobians(model, data, q[i])
        rows[i] = frame_jacobian(model, data, frame_id, pin.LOCAL_WORLD_ALIGNED)
    return out


def mass_jacobians(model: pin.Model, kin: JointPlacements) -> np.ndarray:
    """(m, 3, nv) ``sum_k m_k J_k``, ``J_k`` the world-axes Jacobian of body ``k``'s centre of
    mass (kg.m/rad or kg), from the joint Jacobians ``kin`` (``data.mass[0]`` times
    ``pin.jacobianCenterOfMass``): column ``v`` of joint ``j`` is ``W_j J_v + J_omega x C_j``
    with ``W_j`` the mass and ``C_j`` the mass moment ``sum m_k c_k`` (world, kg.m) of ``j``'s
    subtree."""
    assert kin.jacobian is not None
    masses = np.array([model.inertias[k].mass for k in range(model.njoints)])
    levers = np.array([model.inertias[k].lever for k in range(model.njoints)])
    moments = masses[None, :, None] * (np.einsum("nkab,kb->nka", kin.rotation, levers)
                                       + kin.translation)  # (m, nj, 3)
    carried = np.zeros((model.nv, model.njoints))  # column v -> the bodies it moves
    for j in range(1, model.njoints):
        first = model.joints[j].idx_v
        carried[first:first + model.joints[j].nv, list(model.subtrees[j])] = 1.0
    weight = carried @ masses  # (nv,)
    moment = np.einsum("vk,nka->nav", carried, moments)  # (m, 3, nv)
    return weight * kin.jacobian[:, :3] + np.cross(kin.jacobian[:, 3:], moment, axis=1)


def gravity_regressors(model: pin.Model, data: pin.Data, q: np.ndarray,
                       derivative: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """The generalized gravity's regressor at the (m, nq) configurations ``q``, and its
    derivative when asked: ``g(q) = Y pi`` and ``dg/dq = Y_q pi`` (``g`` as
    ``pin.computeGeneralizedGravity``, ``M qdd + C + g = tau``; ``dg/dq`` as
    ``pin.computeGeneralizedGravityDerivatives``) for the gravity parameters ``pi`` of every
    body (mass, then the mass moments ``m c_x, m c_y, m c_z`` in its joint's frame; kg, kg.m:
    :data:`~stiffness.mechanics.gravity.GRAVITY_PARAMETERS`). Both faces of the lumped weight
    read it (``gravity_lumped``: the pose face ``Y`` at each row of the sag, the deflection face
    ``Y`` and ``Y_q`` at each distinct configuration).

    ``Y`` is the gravity columns of ``pin.computeJointTorqueRegressor`` at rest (zero velocity
    and acceleration), one call per configuration. ``Y_q`` in closed form from the joint
    Jacobians (:func:`joint_placements`): a unit mass at a point ``x`` fixed to body ``k`` has
    the potential ``-g0 . x`` (``g0 = model.gravity``), so its column is ``Y_a = -u_a . g0``
    over the coordinates ``a`` that move ``k``, ``u_a = v_a + w_a x x`` the point's velocity per
    unit rate (``[v_a; w_a]`` the joint Jacobian's column, world axes at the world origin). Of
    two such coordinates, ``b`` on a joint that supports ``a``'s (or is it), the column
    ``S_a`` turns with ``q_b`` as ``S_b x S_a`` and the point moves by ``u_b``, so

    ``(Y_q)_ab = (Y_q)_ba = -(w_b x u_a) . g0``    (Eq. 1; the potential's Hessian)

    (``(Y_q)_ba`` only when the joints differ). A mass moment ``m c_i``'s column is the unit
    mass at the joint's origin moved by the unit lever ``R_k e_i`` minus the unit mass at the
    origin: ``u_a = w_a x R_k e_i``. Tested against finite differences of ``Y`` and against
    ``pin.computeGeneralizedGravityDerivatives`` on bodies of random masses (open chains, a
    closed loop's tree, prismatic joints, a free-flyer base).

    Returns
    -------
    y, y_q
        (m, nv, njoints - 1, 4) N.m per kg or per kg.m (N for a prismatic joint's row; a view
        on the torque regressor), and (m, nv, nv, njoints - 1, 4) its derivative
        ``y_q[:, a, b] = d y[:, a] / d q_b`` (per rad, or per m), or ``None``.
    """
    m, nv, bodies = q.shape[0], model.nv, model.njoints - 1
    full = np.empty((m, nv, bodies, 10))  # each body's 10 dynamic parameters, the 4 first ours
    regressor, rest = pin.computeJointTorqueRegressor, np.zeros(nv)
    for i in range(m):
        full[i] = regressor(model, data, q[i], rest, rest).reshape(nv, bodies, 10)
    y = full[..., :4]
    if not derivative:
        return y, None
    kin = joint_placements(model, data, q)
    assert kin.jacobian is not None
    masks, proximal = _gravity_structure(tuple(model.parents), tuple(model.idx_vs),
                                         tuple(model.nvs))
    v, w = kin.jacobian[:, :3].transpose(0, 2, 1), kin.jacobian[:, 3:].transpose(0, 2, 1)
    origin = v[:, None] + cross(w[:, None], kin.translation[:, 1:, None])  # (m, B, nv, 3)
    lever = cross(w[:, None, None], kin.rotation[:, 1:].transpose(0, 1, 3, 2)[:, :, :, None])
    u = np.concatenate([origin[:, :, None], lever], axis=2) * masks[:, None, :, None]
    # a[:, a, b] = -(w_b x u_a) . g0 where a and b both move the body (Eq. 1)
    g0 = np.asarray(model.gravity.linear, dtype=float)
    a = -np.einsum("mkpac,mbc->mabkp", u, cross(g0, w)) * masks.T[None, None, :, :, None]
    return y, np.where(proximal[None, :, :, None, None], a, a.transpose(0, 2, 1, 3, 4))


@functools.lru_cache(maxsize=64)
def _gravity_structure(parents: tuple[int, ...], idx_v: tuple[int, ...], nvs: tuple[int, ...]
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Of a model's tree (:func:`gravity_regressors`): (njoints - 1, nv) 1.0 where a velocity
    coordinate moves a body, and (nv, nv) whether coordinate ``b``'s joint supports coordinate
    ``a``'s (or is it), built once per tree (read-only)."""
    nv = sum(nvs)
    joint_of = np.zeros(nv, dtype=int)
    for j in range(1, len(parents)):
        joint_of[idx_v[j]: idx_v[j] + nvs[j]] = j
    supports = np.zeros((len(parents), len(parents)), dtype=bool)  # [k, j]: j supports k
    for k in range(1, len(parents)):
        supports[k] = supports[parents[k]]
        supports[k, k] = True
    masks = supports[1:][:, joint_of].astype(float)
    proximal = supports[joint_of][:, joint_of]
    for a in (masks, proximal):
        a.setflags(write=False)
    return masks, proximal
