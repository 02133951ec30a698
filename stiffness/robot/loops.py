"""Loop closures: declarations beside a URDF, Pinocchio constraints, closure, projection.

A URDF holds a tree; a closed chain is declared as a tree plus loop-closing frame pairs. The
declaration follows the "Extended URDF" YAML sidecar of Gepetto's toolbox-parallel-robots::

    closed_loop:              # frame pairs that coincide when the loop is closed
      - [coupler_end, forearm_rear]
    type: ["3D"]              # per pair: "3D" (point constraint) or "6D" (frame constraint)
    name_mot: [joint1, joint2, joint3]   # actuated joints

``"3D"``: the two frame origins coincide (a spherical joint). ``"6D"``: the two frames coincide,
origin and axes (a weld). Optional key ``passive_joints`` lists the loop's unactuated joints; by
default they are the joints on the path between the two frames of each pair that are not
actuated. Passive joints may be revolute, prismatic or multi-degree-of-freedom joints (the
closure steps on their velocity coordinates with ``pin.integrate``).

Conventions (see docs/conventions.md and docs/spatial-loops.md):

* ``"3D"``: the closure residual is Pinocchio's ``PointAnchorConstraintModel`` residual
  (p_b - p_a in frame a's axes, 3 rows, m).
* ``"6D"``: the residual is Pinocchio's ``FrameAnchorConstraintModel`` residual
  ``log6(oMa^-1 oMb)`` (6 rows, [m; rad]).

:meth:`LoopClosure.jacobian` is the exact derivative of that residual, on and off the loop.
Second-order terms use a world-axes residual built from points only, whose Hessian comes from
Pinocchio's kinematic Hessians of points: ``p_b - p_a`` for a ``"3D"`` pair; for a ``"6D"`` pair
the same for three points of each frame (its origin and the points one metre along its x and y
axes), 9 rows of rank 6. The world-axes rows are redundant wherever a loop is planar (or 6D):
every solve on them is rank-revealing (least squares / pseudo-inverse).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.errors import (
    LoopClosureError,
    MissingFileError,
    RobotFileError,
    UnknownFrameError,
    UnknownJointError,
    did_you_mean,
)
from stiffness.files import read_yaml
from stiffness.robot import kinematics
from stiffness.robot.rewrite import JOINT_REWRITES

#: Closure tolerance on the loop residual (m; rad for the rotation rows of a 6D pair).
CLOSURE_TOLERANCE_M = 1e-11

#: Smallest over largest singular value of the passive Jacobian (its nonzero ones elsewhere)
#: below which a pose is singular: the assembly modes meet there.
SINGULAR_RATIO = 1e-6

#: Longest Gauss-Newton step (rad or m, norm over the passive joints) of the closure.
MAX_STEP = 0.5

#: Supported loop types: rows of the Pinocchio residual per pair.
LOOP_TYPES = {"3D": 3, "6D": 6}

#: Offsets (in the frame's own axes, m) of the points whose coincidence makes a 6D pair's
#: world-axes residual: origin, one metre along x, one metre along y.
_FRAME_POINTS_M = (np.zeros(3), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))

#: Two points that coincide on a closed "6D" loop: (parent joint id, placement in its frame).
_PointPair = tuple[tuple[int, pin.SE3], tuple[int, pin.SE3]]


@dataclass(frozen=True)
class LoopPair:
    """Two frames that coincide when the loop is closed.

    ``kind`` is ``"3D"`` (their origins coincide) or ``"6D"`` (origins and axes coincide).
    """

    frame_a: str
    frame_b: str
    kind: str = "3D"


@dataclass(frozen=True)
class LoopDeclaration:
    """Loop-closing frame pairs, the actuated joints, joint rewrites and passive joints.

    ``rewrites`` maps joint names to Gepetto joint types (``joint_name``/``joint_type``, see
    :mod:`stiffness.robot.rewrite`); ``passive`` is None unless the file's ``passive_joints``
    lists them.
    """

    pairs: tuple[LoopPair, ...]
    actuated: tuple[str, ...]
    passive: tuple[str, ...] | None = None
    rewrites: dict = field(default_factory=dict)
    path: str = ""


#: Keys of a loop declaration: Gepetto's, then ours (``passive_joints``).
LOOP_KEYS = ("closed_loop", "type", "name_mot", "joint_name", "joint_type", "passive_joints")


def _names(path: Path, content: dict, key: str, required: bool) -> list[str]:
    """A list of names under ``key`` (empty when absent and not required)."""
    value = content.get(key, [])
    if value is None:
        value = []
    if not isinstance(value, list) or (required and not value) or not all(
            isinstance(v, str) for v in value):
        raise RobotFileError(path, _key_line(path, key),
                             f"{key} must be a {'non-empty ' if required else ''}YAML list of "
                             f"names (e.g. {key}: [a, b]), got {value!r}")
    return value


def _key_line(path: Path, key: str) -> int | None:
    """Line of a top-level key in a YAML file (for error messages)."""
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        if line.startswith(f"{key}:") or line.startswith(f"{key} :"):
            return number
    return None


def read_loop_declaration(path: str | Path) -> LoopDeclaration:
    """Read an Extended-URDF loop declaration (YAML, Gepetto's format; docs/robot-files.md).

    Keys: ``closed_loop`` (frame pairs), ``type`` (``3D``/``6D`` per pair, any case),
    ``name_mot`` (actuated joints), ``joint_name`` and ``joint_type`` (joint rewrites,
    ``SPHERICAL``, ``UJOINT_XY``/``YZ``/``ZY``/..., ``FIXED``, any case), and our
    ``passive_joints``.

    Raises
    ------
    MissingFileError
        If the file is missing.
    FileFormatError
        If it is not YAML (:func:`stiffness.files.read_yaml`), or (:class:`RobotFileError`) a
        required key is missing, a key or a type is unknown, or the lists do not match.
    """
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"loop declaration {path} does not exist; give the YAML sidecar "
                               "path", path=path)
    content = read_yaml(path, "loop declaration")
    if not isinstance(content, dict):
        raise RobotFileError(path, None, "a loop declaration must be a YAML mapping")
    unknown = [k for k in content if k not in LOOP_KEYS]
    if unknown:
        raise RobotFileError(path, _key_line(path, str(unknown[0])),
                             f"unknown key {unknown[0]!r} in a loop declaration; "
                             f"valid keys: {', '.join(LOOP_KEYS)}")
    missing = [k for k in ("closed_loop", "type", "name_mot") if k not in content]
    if missing:
        raise RobotFileError(
            path, None,
            f"the loop declaration lacks {', '.join(missing)}; it needs closed_loop (frame "
            "pairs), type (one of '3D' or '6D' per pair) and name_mot (actuated joints)")
    loops, kinds = content["closed_loop"], content["type"]
    for key, value in (("closed_loop", loops), ("type", kinds)):
        if not isinstance(value, list) or not value:
            raise RobotFileError(path, _key_line(path, key),
                                 f"{key} must be a non-empty YAML list (e.g. {key}: [a, b]), "
                                 f"got {value!r}")
    actuated = _names(path, content, "name_mot", required=True)
    if len(loops) != len(kinds):
        raise RobotFileError(path, _key_line(path, "type"),
                             f"{len(loops)} closed_loop pairs but {len(kinds)} types")
    pairs = []
    for pair, kind in zip(loops, kinds, strict=True):
        if not isinstance(pair, list) or len(pair) != 2:
            raise RobotFileError(path, _key_line(path, "closed_loop"),
                                 f"{pair!r} is not a pair of frame names [frame_a, frame_b]")
        if str(kind).upper() not in LOOP_TYPES:
            raise RobotFileError(path, _key_line(path, "type"),
                                 f"loop type {kind!r} is not supported; use '3D' (point "
                                 "constraint) or '6D' (frame constraint), in any case")
        pairs.append(LoopPair(str(pair[0]), str(pair[1]), str(kind).upper()))
    joint_names = _names(path, content, "joint_name", required=False)
    joint_types = content.get("joint_type") or []
    if not isinstance(joint_types, list) or len(joint_types) != len(joint_names):
        raise RobotFileError(path, _key_line(path, "joint_type"),
                             f"joint_type must list one type per joint_name entry "
                             f"({len(joint_names)}), got {joint_types!r}")
    rewrites = {}
    for name, kind in zip(joint_names, joint_types, strict=True):
        kind = str(kind).upper()
        if kind not in JOINT_REWRITES:
            raise RobotFileError(path, _key_line(path, "joint_type"),
                                 f"joint type {kind!r} of {name!r} is not supported; use one of "
                                 f"{', '.join(JOINT_REWRITES)}")
        if name in rewrites:
            raise RobotFileError(path, _key_line(path, "joint_name"),
                                 f"joint_name lists {name!r} twice")
        rewrites[name] = kind
    passive = content.get("passive_joints")
    if passive is not None:
        passive = tuple(_names(path, content, "passive_joints", required=False))
    return LoopDeclaration(tuple(pairs), tuple(actuated), passive, rewrites, str(path))


@dataclass
class LoopClosure:
    """Loop-closure constraints of a model, built as Pinocchio anchor constraints.

    Attributes
    ----------
    pairs
        The declared frame pairs.
    frame_ids
        ``(frame_a_id, frame_b_id)`` for each pair.
    constraints
        One ``pin.PointAnchorConstraintModel`` ("3D") or ``pin.FrameAnchorConstraintModel``
        ("6D") per pair.
    passive_joints
        Names of the loop's unactuated joints, solved from the closure.
    passive_v
        Velocity indices of the passive joints.

    An open chain (a tree) has the loop closure with no pairs (:meth:`open_chain`): no
    constraint rows, no passive joints.
    """

    pairs: tuple[LoopPair, ...]
    frame_ids: list[tuple[int, int]]
    constraints: list
    constraint_datas: list
    passive_joints: tuple[str, ...]
    passive_v: np.ndarray = field(repr=False)
    #: The constraints as one Pinocchio vector of generic constraints and of their datas, whose
    #: entries ``constraints`` and ``constraint_datas`` are (None unless every pair is "3D"):
    #: :meth:`jacobian` stacks their rows in one call.
    stacked: tuple | None = field(default=None, repr=False)

    @classmethod
    def open_chain(cls) -> LoopClosure:
        """The loop closure of a tree: no pairs, no constraints, no passive joints."""
        return cls((), [], [], [], (), np.zeros(0, dtype=int))

    @property
    def is_open_chain(self) -> bool:
        """Whether there is no loop to close (a tree)."""
        return not self.pairs

    @property
    def n_rows(self) -> int:
        """Number of rows of :meth:`residual` (3 per "3D" pair, 6 per "6D" pair)."""
        return sum(LOOP_TYPES[p.kind] for p in self.pairs)

    @property
    def n_world_rows(self) -> int:
        """Number of rows of :meth:`world_jacobian` (3 per "3D" pair, 9 per "6D" pair)."""
        return sum(3 if p.kind == "3D" else 3 * len(_FRAME_POINTS_M) for p in self.pairs)

    def residual(self, model: pin.Model, data: pin.Data) -> np.ndarray:
        """Closure residual (m; rad for 6D rotation rows), Pinocchio's convention.

        Placements (``computeJointJacobians`` or forward kinematics) must be up to date.
        """
        self._calc(model, data)
        return self._residual()

    def jacobian(self, model: pin.Model, data: pin.Data) -> np.ndarray:
        """Exact Jacobian (n_rows, nv) of :meth:`residual`; joint Jacobians must be up to date.

        For a "6D" pair Pinocchio's constraint Jacobian is the relative twist of frame b with
        respect to frame a in a's axes; the derivative of ``log6(aMb)`` is
        ``Jlog6(aMb) Ad(bMa)`` times it (equal to it on the closed loop).
        """
        self._calc(model, data)
        return self._jacobian(model, data)

    def _calc(self, model: pin.Model, data: pin.Data) -> None:
        """Evaluate the constraints (their datas) at the current placements."""
        for cm, cd in zip(self.constraints, self.constraint_datas, strict=True):
            cm.calc(model, data, cd)

    def _residual(self) -> np.ndarray:
        """:meth:`residual` from the constraint datas as :meth:`_calc` left them."""
        errors = [cd.constraint_position_error for cd in self.constraint_datas]
        if len(errors) == 1:
            return np.array(errors[0])
        return np.concatenate(errors) if errors else np.zeros(0)

    def _jacobian(self, model: pin.Model, data: pin.Data) -> np.ndarray:
        """:meth:`jacobian` from the constraint datas as :meth:`_calc` left them."""
        if self.stacked is not None:
            return pin.getConstraintsJacobian(model, data, *self.stacked)
        rows = []
        for pair, cm, cd in zip(self.pairs, self.constraints, self.constraint_datas,
                                strict=True):
            jac = pin.getConstraintJacobian(model, data, cm, cd)
            if pair.kind == "6D":
                a_m_b = cd.c1Mc2
                jac = pin.Jlog6(a_m_b) @ a_m_b.inverse().toActionMatrix() \
                    @ np.array(jac).reshape(-1, model.nv)
            rows.append(jac)
        if len(rows) == 1:
            return np.array(rows[0])
        return np.concatenate(rows) if rows else np.zeros((0, model.nv))

    def _world_points(self, model: pin.Model) -> list[list[_PointPair] | None]:
        """Per pair, the ((joint_a, placement_a), (joint_b, placement_b)) point pairs (None for
        a "3D" pair: its frame origins)."""
        out: list[list[_PointPair] | None] = []
        for pair, (fa, fb) in zip(self.pairs, self.frame_ids, strict=True):
            if pair.kind == "3D":
                out.append(None)
                continue
            frame_a, frame_b = model.frames[fa], model.frames[fb]
            out.append([((frame_a.parentJoint, frame_a.placement * pin.SE3(np.eye(3), d)),
                         (frame_b.parentJoint, frame_b.placement * pin.SE3(np.eye(3), d)))
                        for d in _FRAME_POINTS_M])
        return out

    def world_residual(self, model: pin.Model, data: pin.Data) -> np.ndarray:
        """World-axes residual (n_world_rows,), m: p_b - p_a for each point pair.

        Frame placements must be up to date (``framesForwardKinematics``).
        """
        rows = []
        for points, (fa, fb) in zip(self._world_points(model), self.frame_ids, strict=True):
            if points is None:
                rows.append(data.oMf[fb].translation - data.oMf[fa].translation)
                continue
            for (ja, ma), (jb, mb) in points:
                rows.append((data.oMi[jb] * mb).translation - (data.oMi[ja] * ma).translation)
        return np.concatenate(rows) if rows else np.zeros(0)

    def world_jacobian(self, model: pin.Model, data: pin.Data) -> np.ndarray:
        """Jacobian (n_world_rows, nv) of the world-axes residual p_b - p_a."""
        rows = []
        for points, (fa, fb) in zip(self._world_points(model), self.frame_ids, strict=True):
            if points is None:
                jac_a = kinematics.frame_jacobian(model, data, fa)[:3]
                jac_b = kinematics.frame_jacobian(model, data, fb)[:3]
                rows.append(jac_b - jac_a)
                continue
            for (ja, ma), (jb, mb) in points:
                rows.append(kinematics.point_jacobian(model, data, jb, mb)[:3]
                            - kinematics.point_jacobian(model, data, ja, ma)[:3])
        return np.vstack(rows) if rows else np.zeros((0, model.nv))

    def world_hessian(self, model: pin.Model, data: pin.Data) -> np.ndarray:
        """Hessian (n_world_rows, nv, nv) of the world-axes residual (Hessians current).

        ``H[r, a, b] = d2 c_r / dq_a dq_b`` (symmetric in a, b).
        """
        blocks = []
        for points, (fa, fb) in zip(self._world_points(model), self.frame_ids, strict=True):
            if points is None:
                ha = kinematics.frame_hessian(model, data, fa)[:3]
                hb = kinematics.frame_hessian(model, data, fb)[:3]
                blocks.append(hb - ha)
                continue
            for (ja, ma), (jb, mb) in points:
                blocks.append(kinematics.point_hessian(model, data, jb, mb)
                              - kinematics.point_hessian(model, data, ja, ma))
        return np.concatenate(blocks, axis=0) if blocks else np.zeros((0, model.nv, model.nv))

    def passive_rank(self, model: pin.Model, data: pin.Data, rtol: float = 1e-9) -> int:
        """Rank of the passive columns of :meth:`jacobian` (rank-revealing SVD).

        The passive joints are determined by the independent ones where it equals the number
        of passive velocity coordinates; rows beyond it are redundant (planar loops).
        """
        cp = self.jacobian(model, data)[:, self.passive_v]
        sv = np.linalg.svd(cp, compute_uv=False)
        return int(np.sum(sv > rtol * max(1.0, sv[0] if sv.size else 0.0)))

    def passive_rates(self, model: pin.Model, data: pin.Data, independent_v: np.ndarray,
                      jacobian: np.ndarray | None = None) -> np.ndarray:
        """Rates of the passive joints per unit rate of the independent joints, (n_p, n_i).

        Least-squares (rank-revealing) solution of ``C_p dq_p = -C_i dq_i``; joint Jacobians
        must be up to date (or give :meth:`jacobian` there).
        """
        c = self.jacobian(model, data) if jacobian is None else jacobian
        return -np.linalg.pinv(c[:, self.passive_v], rcond=1e-9) @ c[:, independent_v]

    def tangent(self, model: pin.Model, data: pin.Data, q: np.ndarray) -> np.ndarray:
        """(nv, nv) ``T = dq/du`` at the closed configuration ``q``: the identity on the
        independent coordinates (every one but the passive ones), :meth:`passive_rates` on
        the passive rows, zero passive columns; ``T^T tau`` is the generalised force the
        independent coordinates feel of the tree's ``tau`` (virtual work through the loop).
        Computes the joint Jacobians at ``q``."""
        independent = np.setdiff1d(np.arange(model.nv), self.passive_v)
        pin.computeJointJacobians(model, data, q)
        out = np.zeros((model.nv, model.nv))
        out[independent, independent] = 1.0
        out[np.ix_(self.passive_v, independent)] = self.passive_rates(model, data, independent)
        return out

    def passive_basis(self, model: pin.Model, data: pin.Data,
                      jacobian: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Basis ``(B, V)`` in which :meth:`mode_determinant` reads the assembly mode here.

        V (n_passive_v, r) spans the passive motions the loops determine (the identity when
        there is no idle motion; else the right singular vectors of the r nonzero singular
        values of the passive columns C_p of :meth:`jacobian`) and B = C_p V, so that
        ``det(B^T C_p V)`` is positive here (redundant rows of a planar loop drop out).
        Joint Jacobians must be up to date (or give :meth:`jacobian` there).
        """
        c = self.jacobian(model, data) if jacobian is None else jacobian
        return self._basis(c[:, self.passive_v], None)

    def _basis(self, cp: np.ndarray, rank: int | None, rtol: float = 1e-9
               ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`passive_basis` of the passive columns ``cp``, of ``rank`` (None: theirs)."""
        n = cp.shape[1]
        if rank is None and 0 < n <= cp.shape[0] and _regular(cp.T @ cp):
            rank = n  # full rank, without an SVD
        if rank == n:
            return cp, _identity(n)
        u, sv, vt = np.linalg.svd(cp, full_matrices=False)
        if rank is None:
            rank = int(np.sum(sv > rtol * max(1.0, sv[0] if sv.size else 0.0)))
        v = vt[:rank].T
        return cp @ v, v

    def mode_determinant(self, model: pin.Model, data: pin.Data,
                         basis: tuple[np.ndarray, np.ndarray]
                         ) -> tuple[float, tuple[np.ndarray, np.ndarray]]:
        """``det(B^T C_p V)`` at the current pose in a :meth:`passive_basis` taken at a nearby
        pose, and the basis to read the next pose in.

        Positive in the same assembly mode; negative across a parallel (type-2) singularity,
        where a singular value of the passive columns C_p passes through zero. The basis
        returned is this pose's, or the given one where this pose is singular (smallest over
        largest singular value below :data:`SINGULAR_RATIO`, where the modes meet and cannot
        be told apart). Joint Jacobians must be up to date.
        """
        b, v = basis
        cp = self.jacobian(model, data)[:, self.passive_v]
        n = cp.shape[1]
        bc = b.T @ cp
        det = _small_det(bc if v is _identity(n) else bc @ v)  # (times I: the same bits)
        here = self._basis(cp, n if v.shape[1] == n else None)
        rank = here[1].shape[1]
        if rank < v.shape[1] or rank and not _regular(here[0].T @ here[0]):
            here = basis
        return det, here

    def retyped(self, model: pin.Model, pairs: tuple[LoopPair, ...]) -> LoopClosure:
        """These loop pairs (frames of this closure's, any type) with this closure's passive
        joints, as Pinocchio constraints on ``model``."""
        declaration = LoopDeclaration(pairs, (), self.passive_joints)
        return build_loop_closure(model, declaration)

    def loop_residuals(self, model: pin.Model, data: pin.Data) -> list[tuple[str, float]]:
        """Name (``[frame_a, frame_b]``) and residual norm (m; rad) of each loop, placements
        current."""
        out = []
        for pair, cm, cd in zip(self.pairs, self.constraints, self.constraint_datas,
                                strict=True):
            cm.calc(model, data, cd)
            out.append((f"[{pair.frame_a}, {pair.frame_b}]",
                        float(np.linalg.norm(cd.constraint_position_error))))
        return out

    def idle_motions(self, model: pin.Model, data: pin.Data, rtol: float = 1e-9) -> np.ndarray:
        """Passive motions the constraints leave undetermined: (n_passive_v, k) orthonormal basis
        of the null space of the passive columns of :meth:`jacobian` (joint Jacobians current).
        """
        cp = self.jacobian(model, data)[:, self.passive_v]
        if cp.shape[1] == 0:
            return np.zeros((0, 0))
        _, sv, vt = np.linalg.svd(cp, full_matrices=True)
        rank = int(np.sum(sv > rtol * max(1.0, sv[0] if sv.size else 0.0)))
        return vt[rank:].T

    def close(
        self, model: pin.Model, data: pin.Data, q: np.ndarray, max_iterations: int = 50
    ) -> np.ndarray:
        """Solve the passive joints so that the loops close, by Gauss-Newton from ``q``.

        The independent joints keep their values; steps are minimum-norm (undetermined passive
        motions keep their values) and at most :data:`MAX_STEP` long. Seed ``q`` near the
        wanted assembly branch (the closure keeps the branch it starts on).

        Raises
        ------
        LoopClosureError
            If the loop does not close (the independent joints put it out of reach); the
            message names the loop with the largest residual.
        """
        q = q.copy()
        for _ in range(max_iterations):
            kinematics.update_first_order(model, data, q)
            self._calc(model, data)  # once for the residual and its Jacobian
            c = self._residual()
            if math.sqrt(c.dot(c)) < CLOSURE_TOLERANCE_M:  # np.linalg.norm's arithmetic
                return q
            cp = self._jacobian(model, data)[:, self.passive_v]
            step = np.linalg.lstsq(cp, -c, rcond=1e-10)[0]
            norm = math.sqrt(step.dot(step))
            if norm > MAX_STEP:
                step *= MAX_STEP / norm
            dv = np.zeros(model.nv)
            dv[self.passive_v] = step
            q = pin.integrate(model, q, dv)
        kinematics.update_first_order(model, data, q)
        c = self.residual(model, data)
        if np.linalg.norm(c) < 1e3 * CLOSURE_TOLERANCE_M:
            return q
        name, worst = max(self.loop_residuals(model, data), key=lambda item: item[1])
        raise LoopClosureError(
            f"the kinematic loop does not close at {name} (residual {np.linalg.norm(c):.3g} m "
            f"after {max_iterations} iterations): the configuration is out of the loop's reach; "
            "check the joint values and their units", loop=name, residual=worst)


@functools.cache
def _identity(n: int) -> np.ndarray:
    """The (n, n) identity, made once (read only)."""
    out = np.eye(n)
    out.flags.writeable = False
    return out


def _regular(gram: np.ndarray) -> bool:
    """Whether the Gram matrix ``C^T C`` (n x n, n >= 1) of some columns C is regular: its
    determinant above ``SINGULAR_RATIO^2 (trace / n)^n`` (for two columns, about their
    smallest singular value above :data:`SINGULAR_RATIO` of the largest)."""
    n = gram.shape[0]
    if n > 2:
        det, trace = _small_det(gram), float(gram.trace())
    else:  # the same sums as np.trace and _small_det, without their calls
        a = gram.tolist()
        det = a[0][0] if n == 1 else a[0][0] * a[1][1] - a[0][1] * a[1][0]
        trace = a[0][0] if n == 1 else a[0][0] + a[1][1]
    return det > SINGULAR_RATIO ** 2 * (trace / n) ** n


def _small_det(m: np.ndarray) -> float:
    """Determinant of a square matrix, written out up to 3 x 3 (1 for 0 x 0)."""
    n = m.shape[0]
    if n > 3:
        return float(np.linalg.det(m))
    if n == 0:
        return 1.0
    a = m.tolist()
    if n == 1:
        return a[0][0]
    if n == 2:
        return a[0][0] * a[1][1] - a[0][1] * a[1][0]
    return (a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
            - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
            + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]))


def build_loop_closure(model: pin.Model, declaration: LoopDeclaration,
                       dependent: tuple[str, ...] = ()) -> LoopClosure:
    """Turn a declaration into Pinocchio constraints on ``model``.

    Passive joints: the declaration's ``passive_joints``, else (as in Gepetto's loader) every
    joint with a degree of freedom that is not a motor (``name_mot``) and not ``dependent``
    (mimic followers, whose values follow their leaders).

    Raises
    ------
    UnknownFrameError, UnknownJointError
        If a frame or joint named in the declaration is not in the model.
    """
    frame_names = [f.name for f in model.frames]
    joint_names = list(model.names)[1:]
    where = f"loop declaration {declaration.path}: " if declaration.path else ""
    frame_ids, constraints, datas = [], [], []
    for pair in declaration.pairs:
        ids = []
        for name in (pair.frame_a, pair.frame_b):
            if not model.existFrame(name):
                raise UnknownFrameError(
                    f"{where}loop frame {name!r} is not in the model; "
                    f"{did_you_mean(name, frame_names)}", name=name, choices=frame_names)
            ids.append(kinematics.frame_id(model, name))
        fa, fb = (model.frames[i] for i in ids)
        anchor = (pin.FrameAnchorConstraintModel if pair.kind == "6D"
                  else pin.PointAnchorConstraintModel)
        cm = anchor(model, fa.parentJoint, fa.placement, fb.parentJoint, fb.placement)
        constraints.append(cm)
        datas.append(cm.createData())
        frame_ids.append((ids[0], ids[1]))
    for name in declaration.actuated:
        if name not in joint_names:
            raise UnknownJointError(
                f"{where}actuated joint {name!r} is not in the model; "
                f"{did_you_mean(name, joint_names)}", name=name, choices=joint_names)
    if declaration.passive is None:
        passive = tuple(
            j for j in joint_names if model.joints[model.getJointId(j)].nv > 0
            and j not in declaration.actuated and j not in dependent
        )
    else:
        passive = declaration.passive
        for name in passive:
            if name not in joint_names:
                raise UnknownJointError(
                    f"{where}passive joint {name!r} is not in the model; "
                    f"{did_you_mean(name, joint_names)}", name=name, choices=joint_names)
    joints = [model.joints[model.getJointId(j)] for j in passive]
    passive_v = np.concatenate(
        [np.arange(j.idx_v, j.idx_v + j.nv) for j in joints] + [np.zeros(0)]).astype(int)
    stacked = None
    if constraints and all(pair.kind == "3D" for pair in declaration.pairs):
        stacked = (pin.StdVec_ConstraintModel(), pin.StdVec_ConstraintData())
        for cm in constraints:
            stacked[0].append(pin.ConstraintModel(cm))
        for cm in stacked[0]:
            stacked[1].append(cm.createData())
        constraints = [cm.extract() for cm in stacked[0]]  # the vector's own, by reference
        datas = [cd.extract() for cd in stacked[1]]
    return LoopClosure(declaration.pairs, frame_ids, constraints, datas, passive, passive_v,
                       stacked)
