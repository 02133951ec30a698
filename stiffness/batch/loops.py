"""Batched loop closure (part of :mod:`stiffness.batch.kernels`, which re-exports its public names).

Loop closures are the expensive part of a closed-chain configuration: :func:`close_loops`
closes each distinct value of the *loop coordinates* (:func:`loop_coordinate_indices`: the
coordinates of the joints on the path between the loop frames; the others, e.g. the SK120's
theta1 and wrist, move the loop rigidly or not at all) once, by continuation for one anchor per
small cell of those coordinates and by a batched Newton iteration from the anchor for the rest.
That iteration, :func:`newton_closure`, is the one batched closure: the pose model closes its
rows with it from their own starts (:func:`close_rows`) and takes their tangent maps
``T = dq/du`` (:func:`tangent_maps`) from the residual's Jacobian it leaves.
:func:`tree_configurations` is the vectorised :meth:`~stiffness.robot.robot.Robot.configuration`
without closure (open chains, or the starting point of a closure).

Units: rad for revolute joints, m for prismatic ones and lengths.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from stiffness.batch.poses import (
    moving_point_jacobians,
    pinocchio_placements,
    support_mask,
)
from stiffness.errors import StiffnessError
from stiffness.robot.loops import CLOSURE_TOLERANCE_M, MAX_STEP
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
#: Residual, relative to the closure tolerance, below which a closure's Jacobian is read before
#: its last Newton step (:func:`newton_closure`): exact there to 1e-14 relative.
_EXACT_JACOBIAN = 1e-3


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
    Corrector: :func:`newton_closure`. Returns the configurations and the mask of keys that
    converged within :data:`_NEWTON_JUMP` of the prediction, in their anchor's assembly mode.
    """
    model, data = robot.model, robot.data
    layout = ClosureLayout.of(robot)
    coordinate_v = robot.coordinate_v[keys_at]
    pv = layout.passive_v
    _, c_anchor = closure_residuals(layout, model, data, anchor_q)
    u, s, vt = np.linalg.svd(c_anchor[:, :, pv], full_matrices=False)
    cutoff = 1e-9 * s[:, :1]
    s_inv = np.where(s > cutoff, 1.0 / np.where(s > cutoff, s, 1.0), 0.0)
    rates = -((np.swapaxes(vt, 1, 2) * s_inv[:, None, :]) @ np.swapaxes(u, 1, 2)
              @ c_anchor[:, :, coordinate_v])  # (m, np, d)
    coords = np.zeros((keys.shape[0], robot.n_coordinates))
    coords[:, keys_at] = keys
    q = tree_configurations(robot, coords)
    q[:, layout.passive_q] = anchor_q[:, layout.passive_q]
    q = layout.step(model, q, (rates @ (keys - anchor_keys)[..., None])[..., 0])
    predicted = q[:, layout.passive_q].copy()
    q, done, c_closed = newton_closure(layout, model, data, q, _NEWTON_ITERATIONS)
    jump = (np.abs(q[:, layout.passive_q] - predicted).max(axis=1) if layout.passive_q.size
            else 0.0)
    same = _same_mode(c_anchor[:, :, pv], s, vt, c_closed[:, :, pv])
    return q, done & (jump <= _NEWTON_JUMP) & same


@dataclass(frozen=True)
class ClosureLayout:
    """What closing a robot's loops reads of it, once (:meth:`of`; plain arrays, pickled with
    a pose model).

    Attributes
    ----------
    joints, offsets
        (P,) parent joint and (P, 3) position in its frame (m) of each point of
        :func:`loop_points`: consecutive points (a, b) make the world-axes residual rows
        ``p_b - p_a``.
    masks
        (P, nv) the velocity coordinates that move each point.
    passive_v, passive_q
        Velocity and configuration indices of the loops' passive joints.
    independent_v
        Every other velocity index (the independent coordinates ``u``).
    simple
        Whether every passive joint's configuration is its velocity coordinates (a step is
        ``q + dv``; else ``pin.integrate``).
    """

    joints: np.ndarray
    offsets: np.ndarray
    masks: np.ndarray
    passive_v: np.ndarray
    passive_q: np.ndarray
    independent_v: np.ndarray
    simple: bool

    @classmethod
    def of(cls, robot: Robot) -> ClosureLayout:
        """The layout of ``robot`` (with closed loops)."""
        model = robot.model
        joints, offsets = [], []
        for point in loop_points(robot):
            if len(point) == 1:
                frame = model.frames[point[0]]
                joints.append(int(frame.parentJoint))
                offsets.append(np.array(frame.placement.translation))
            else:
                joints.append(int(point[0]))
                offsets.append(np.array(point[1].translation))
        passive = [model.joints[model.getJointId(j)] for j in robot.loop.passive_joints]
        pv = np.asarray(robot.loop.passive_v, dtype=int)
        return cls(np.array(joints, dtype=int), np.array(offsets).reshape(-1, 3),
                   np.array([support_mask(model, j) for j in joints],
                            dtype=float).reshape(len(joints), model.nv),
                   pv, _passive_q_indices(robot), np.setdiff1d(np.arange(model.nv), pv),
                   all(j.nq == j.nv for j in passive))

    def step(self, model: pin.Model, q: np.ndarray, dv: np.ndarray) -> np.ndarray:
        """(m, nq) configurations ``q`` with their passive joints moved by ``dv`` (m, n_pv)."""
        if self.simple:
            out = q.copy()
            out[:, self.passive_q] += dv
            return out
        full = np.zeros((q.shape[0], model.nv))
        full[:, self.passive_v] = dv
        return np.array([pin.integrate(model, qi, di) for qi, di in zip(q, full, strict=True)])


def closure_residuals(layout: ClosureLayout, model: pin.Model, data: pin.Data, q: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The world-axes loop residual (m, r) of :func:`loop_points` (m) at the (m, nq)
    configurations ``q`` and its Jacobian (m, r, nv), from Pinocchio's joint placements and
    Jacobians of each row (:func:`stiffness.batch.poses.pinocchio_placements`; ``data``
    scratch space) and the points' in NumPy over the rows. Its zero set is the closed
    loop."""
    kin = pinocchio_placements(model, data, q, True)
    points = (np.einsum("mpab,pb->mpa", kin.rotation[:, layout.joints], layout.offsets)
              + kin.translation[:, layout.joints])
    jac = moving_point_jacobians(kin, points, layout.masks)
    m = q.shape[0]
    return ((points[:, 1::2] - points[:, ::2]).reshape(m, -1),
            (jac[:, 1::2] - jac[:, ::2]).reshape(m, -1, model.nv))


def newton_closure(layout: ClosureLayout, model: pin.Model, data: pin.Data, q: np.ndarray,
                   iterations: int = _NEWTON_ITERATIONS
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The loops closed over the passive joints from each row of ``q`` (m, nq), all rows at
    once: :meth:`~stiffness.robot.loops.LoopClosure.close`'s Gauss-Newton (minimum-norm
    least-squares steps, each at most :data:`~stiffness.robot.loops.MAX_STEP` long, so on
    the branch a row starts on) on the residual of :func:`closure_residuals`, each row until
    its residual is below :data:`~stiffness.robot.loops.CLOSURE_TOLERANCE_M`, at most
    ``iterations`` steps, and then one step more, so that a closure is exact to round-off and
    smooth in the row's coordinates (stopped at the tolerance, its error, up to 1e-11 m,
    would jump with them: central differences over steps of 1e-6 saw it). The Jacobian
    returned is the one before that last step where the residual there was below
    :data:`_EXACT_JACOBIAN` times the tolerance, else after it (one evaluation more): the
    tangent maps read it, and a Jacobian 1e-11 off its closure turned a sag of millimetres by
    1e-13 m.

    Returns
    -------
    q : (m, nq)
        The closed configurations (the last iterates where ``closed`` is False).
    closed : (m,)
        Rows that converged (to 1e3 times the tolerance after the last step).
    jacobian : (m, r, nv)
        The residual's Jacobian at the closure (the tangent maps' input, :func:`tangent_maps`).
    """
    q = q.copy()
    m = q.shape[0]
    done, stepped = np.zeros(m, dtype=bool), np.zeros(m, dtype=bool)
    c_at = np.empty((m, 3 * (layout.joints.size // 2), model.nv))
    active = np.arange(m)
    for k in range(iterations + 1):
        res, c_w = closure_residuals(layout, model, data, q[active])
        c_at[active] = c_w
        norm = np.linalg.norm(res, axis=1)
        if k == iterations:  # the last iterate: closed to the relaxed tolerance, or not
            kept = norm < 1e3 * CLOSURE_TOLERANCE_M
            active, res, c_w = active[kept], res[kept], c_w[kept]
        dv = _lstsq(c_w[:, :, layout.passive_v], -res, 1e-10)
        size = np.linalg.norm(dv, axis=1, keepdims=True)
        dv = np.where(size > MAX_STEP, dv * (MAX_STEP / np.maximum(size, MAX_STEP)), dv)
        q[active] = layout.step(model, q[active], dv)
        if k == iterations:
            done[active] = True
            break
        finished = stepped[active] | (norm < _EXACT_JACOBIAN * CLOSURE_TOLERANCE_M)
        stepped[active[norm < CLOSURE_TOLERANCE_M]] = True
        done[active[finished]] = True
        active = active[~finished]
        if active.size == 0:
            break
    return q, done, c_at


def _lstsq(a: np.ndarray, b: np.ndarray, rcond: float) -> np.ndarray:
    """Minimum-norm least-squares solutions (m, n) of the stacked systems ``a`` (m, r, n),
    ``b`` (m, r) (singular values below ``rcond`` times the largest dropped)."""
    u, s, vt = np.linalg.svd(a, full_matrices=False)
    cutoff = rcond * s[:, :1]
    s_inv = np.where(s > cutoff, 1.0 / np.where(s > cutoff, s, 1.0), 0.0)
    return ((np.swapaxes(vt, 1, 2) * s_inv[:, None, :]) @ np.swapaxes(u, 1, 2)
            @ b[..., None])[..., 0]


def tangent_maps(layout: ClosureLayout, jacobian: np.ndarray) -> np.ndarray:
    """(m, nv, nv) ``T = dq/du`` of the closed configurations whose residual Jacobian
    (:func:`closure_residuals`) is ``jacobian`` (m, r, nv): the identity on the independent
    coordinates, the passive rates ``-C_p^+ C_u`` (rank-revealing pseudo-inverse, as
    :meth:`~stiffness.robot.loops.LoopClosure.passive_rates`: planar loops give redundant
    rows) on the passive rows, zero passive columns. ``T^T tau`` is the generalised force the
    independent coordinates feel of the tree's ``tau``."""
    m, nv = jacobian.shape[0], jacobian.shape[2]
    pv, iv = layout.passive_v, layout.independent_v
    out = np.zeros((m, nv, nv))
    out[:, iv, iv] = 1.0
    out[:, pv[:, None], iv] = -np.linalg.pinv(jacobian[:, :, pv], rcond=1e-9) @ jacobian[:, :, iv]
    return out


def close_rows(robot: Robot, layout: ClosureLayout, model: pin.Model, data: pin.Data,
               q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The loops of ``robot`` closed from each row of ``q`` (m, nq) on ``model`` (the robot's,
    or a copy placed differently off the loops' paths), and the tangent maps there:
    :func:`newton_closure` with :meth:`~stiffness.robot.loops.LoopClosure.close`'s 50
    iterations, then :func:`tangent_maps`. Returns (m, nq) and (m, nv, nv).

    Raises
    ------
    LoopClosureError
        A row whose loop does not close (from the one-row closure, which names the loop).
    """
    closed, done, jacobian = newton_closure(layout, model, data, q, 50)
    if not done.all():  # the one-row closure: the same steps, or the loop it cannot close
        failed = np.flatnonzero(~done)
        closed[failed] = [robot.loop.close(model, data, q[i]) for i in failed]
        jacobian[failed] = closure_residuals(layout, model, data, closed[failed])[1]
    return closed, tangent_maps(layout, jacobian)


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

