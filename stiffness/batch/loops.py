"""Batched loop closure (part of :mod:`stiffness.batch.kernels`, which re-exports its public names).

Loop closures are the expensive part of a closed-chain configuration: :func:`close_loops`
closes each distinct value of the *loop coordinates* (:func:`loop_coordinate_indices`: the
coordinates of the joints on the path between the loop frames; the others, e.g. the SK120's
theta1 and wrist, move the loop rigidly or not at all) once, by continuation for one anchor per
small cell of those coordinates and by a batched Newton iteration from the anchor for the rest.
:func:`tree_configurations` is the vectorised :meth:`~stiffness.robot.robot.Robot.configuration`
without closure (open chains, or the starting point of a closure).

Units: rad for revolute joints, m for prismatic ones and lengths.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from stiffness.errors import StiffnessError
from stiffness.robot.robot import Robot

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


#: Points (in a frame's own axes, m) whose coincidence closes a "6D" loop pair.
_FRAME_POINTS_M = (np.zeros(3), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))


def loop_points(robot: Robot) -> list[tuple]:
    """Points whose world positions make the loop residual, as ``getFrame*`` arguments.

    Consecutive entries (a, b) form the rows ``p_b - p_a``: a "3D" pair is its two frame
    origins (``(frame_id,)``); a "6D" pair three points of each frame, its origin and the
    points one metre along its x and y axes (``(joint_id, placement)``), as
    :meth:`stiffness.robot.loops.LoopClosure.world_residual`. The reduced Hessian does not depend on
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


def loop_coordinate_indices(robot: Robot) -> np.ndarray:
    """Positions, in the coordinate vector, of the coordinates that change the loop closure.

    They are the coordinate joints on the path between the two frames of a loop pair (in the
    support of one frame but not of the other). Common ancestors move the loop rigidly and
    joints outside both supports do not touch it, so the passive joint values depend only on
    these coordinates. Empty for an open chain.
    """
    if robot.loop.is_open_chain:
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

    Vectorised :meth:`Robot.configuration` without loop closure (mimic followers set from their
    leaders); ``base`` defaults to Pinocchio's neutral configuration. Angles in rad, lengths in
    m.
    """
    coordinates = np.atleast_2d(np.asarray(coordinates, dtype=float))
    model = robot.model
    base = pin.neutral(model) if base is None else np.asarray(base, dtype=float)
    q = np.repeat(base[None, :], coordinates.shape[0], axis=0)
    names, values = robot.joint_values(coordinates)  # through a [controller] coupling
    for i, name in enumerate(names):
        joint = model.joints[model.getJointId(name)]
        if joint.nq == 2:
            q[:, joint.idx_q] = np.cos(values[:, i])
            q[:, joint.idx_q + 1] = np.sin(values[:, i])
        else:
            q[:, joint.idx_q] = values[:, i]
    for qi in q if robot.mimics else ():
        robot.follow(qi)  # mimic followers from their leaders (in place)
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
            f"{robot.title} has {robot.n_coordinates} coordinates "
            f"({', '.join(robot.coordinate_joints)}), got {coordinates.shape[1]} per row"
        )
    if not np.all(np.isfinite(coordinates)):
        raise StiffnessError("joint coordinates must be finite numbers")
    m = coordinates.shape[0]
    if robot.loop.is_open_chain:
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
    Corrector: Gauss-Newton on the world-axes residual of :func:`loop_points` (its zero set is
    the closed loop), least squares by pseudo-inverse. Returns the configurations and the mask
    of keys that converged within :data:`_NEWTON_JUMP` of the prediction.
    """
    from stiffness.robot.loops import CLOSURE_TOLERANCE_M

    model, data = robot.model, robot.data
    loop = robot.loop
    points = loop_points(robot)
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
    c_closed = np.zeros_like(c_anchor[:, :, pv])  # passive columns where each key closed
    active = np.arange(keys.shape[0])
    for _ in range(_NEWTON_ITERATIONS):
        res, c_w = residual_and_jacobian(q[active])
        norm = np.linalg.norm(res, axis=1)
        converged = norm < CLOSURE_TOLERANCE_M
        done[active[converged]] = True
        c_closed[active[converged]] = c_w[converged][:, :, pv]
        active = active[~converged]
        if active.size == 0:
            break
        dv = lstsq(c_w[~converged][:, :, pv], -res[~converged], 1e-10)
        q[active] = step(q[active], dv)
    if active.size:
        res, c_w = residual_and_jacobian(q[active])
        close = np.linalg.norm(res, axis=1) < 1e3 * CLOSURE_TOLERANCE_M
        done[active[close]] = True
        c_closed[active] = c_w[:, :, pv]
    jump = np.abs(q[:, passive_q] - predicted).max(axis=1) if passive_q.size else 0.0
    same = _same_mode(c_anchor[:, :, pv], s, vt, c_closed)
    return q, done & (jump <= _NEWTON_JUMP) & same


def _same_mode(c_anchor: np.ndarray, s: np.ndarray, vt: np.ndarray, c_closed: np.ndarray
               ) -> np.ndarray:
    """(m,) whether each closure kept its anchor's assembly mode.

    The batched :meth:`~stiffness.robot.loops.LoopClosure.mode_determinant`: the sign of
    ``det(B^T C V)`` with V the anchor's right singular vectors of its nonzero singular values
    (``s``, ``vt`` of the anchor's passive columns ``c_anchor``), B = C_anchor V and C the
    passive columns where the key closed (``c_closed``). A key that changed sign is closed by
    continuation from its anchor instead (which tells a singular pose from a jump).
    """
    rank = np.sum(s > 1e-9 * s[:, :1], axis=1)
    same = np.ones(c_anchor.shape[0], dtype=bool)
    for r in np.unique(rank):
        sel = rank == r
        v = np.swapaxes(vt[sel][:, :r, :], 1, 2)  # (k, n_passive, r)
        b = c_anchor[sel] @ v
        same[sel] = np.linalg.det(np.swapaxes(b, 1, 2) @ c_closed[sel] @ v) > 0
    return same


def point_supports(robot: Robot) -> np.ndarray:
    """(n_points, nv) masks of the velocity coordinates moving each loop point."""
    model = robot.model
    return np.array([support_mask(model, model.frames[point[0]].parentJoint
                                   if len(point) == 1 else point[0])
                     for point in loop_points(robot)], dtype=bool).reshape(-1, model.nv)


def support_mask(model: pin.Model, joint: int) -> np.ndarray:
    """(nv,) mask of the velocity coordinates of the joints that move ``joint``'s body (every
    coordinate of a joint with several, a free-flyer base's six)."""
    mask = np.zeros(model.nv, dtype=bool)
    for j in list(model.supports[joint])[1:]:
        mask[model.joints[j].idx_v: model.joints[j].idx_v + model.joints[j].nv] = True
    return mask
