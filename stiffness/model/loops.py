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

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.errors import (
    FileFormatError,
    LoopClosureError,
    MissingFileError,
    UnknownFrameError,
    UnknownJointError,
    did_you_mean,
)
from stiffness.files import read_yaml
from stiffness.model import kinematics

#: Closure tolerance on the loop residual (m; rad for the rotation rows of a 6D pair).
CLOSURE_TOLERANCE_M = 1e-11

#: Supported loop types: rows of the Pinocchio residual per pair.
LOOP_TYPES = {"3D": 3, "6D": 6}

#: Offsets (in the frame's own axes, m) of the points whose coincidence makes a 6D pair's
#: world-axes residual: origin, one metre along x, one metre along y.
_FRAME_POINTS_M = (np.zeros(3), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))


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
    """Loop-closing frame pairs and the actuated (and optionally passive) joints."""

    pairs: tuple[LoopPair, ...]
    actuated: tuple[str, ...]
    passive: tuple[str, ...] | None = None


def read_loop_declaration(path: str | Path) -> LoopDeclaration:
    """Read an Extended-URDF loop declaration (YAML).

    Raises
    ------
    MissingFileError
        If the file is missing.
    FileFormatError
        If it is not YAML, or lacks ``closed_loop``/``type``/``name_mot``.
    """
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"loop declaration {path} does not exist; give the YAML sidecar "
                               "path", path=path)
    content = read_yaml(path, "loop declaration")
    if not isinstance(content, dict):
        raise FileFormatError("a loop declaration must be a YAML mapping (closed_loop, type, "
                              "name_mot)", path=path)
    missing = [k for k in ("closed_loop", "type", "name_mot") if k not in content]
    if missing:
        raise FileFormatError(
            f"the loop declaration lacks {', '.join(missing)}; it needs closed_loop (frame "
            "pairs), type (one of '3D' or '6D' per pair) and name_mot (actuated joints)",
            path=path)
    for key in ("closed_loop", "type", "name_mot", "passive_joints"):
        value = content.get(key, [])
        if not isinstance(value, list) or (key != "passive_joints" and not value):
            raise FileFormatError(
                f"{key} must be a non-empty YAML list (e.g. {key}: [a, b]), got {value!r}",
                path=path, field=key)
    loops, kinds = content["closed_loop"], content["type"]
    if len(loops) != len(kinds):
        raise FileFormatError(
            f"{len(loops)} closed_loop pairs but {len(kinds)} types; give one type per pair",
            path=path, field="type")
    pairs = []
    for pair, kind in zip(loops, kinds, strict=True):
        if not isinstance(pair, list) or len(pair) != 2:
            raise FileFormatError(
                f"{pair!r} is not a pair of frame names [frame_a, frame_b]", path=path,
                field="closed_loop")
        if kind not in LOOP_TYPES:
            raise FileFormatError(
                f"loop type {kind!r} is not supported; use '3D' (point constraint) or '6D' "
                "(frame constraint)", path=path, field="type")
        pairs.append(LoopPair(str(pair[0]), str(pair[1]), kind))
    passive = content.get("passive_joints")
    return LoopDeclaration(
        tuple(pairs),
        tuple(str(j) for j in content["name_mot"]),
        None if passive is None else tuple(str(j) for j in passive),
    )


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
    """

    pairs: tuple[LoopPair, ...]
    frame_ids: list[tuple[int, int]]
    constraints: list
    constraint_datas: list
    passive_joints: tuple[str, ...]
    passive_v: np.ndarray = field(repr=False)

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
        out = []
        for cm, cd in zip(self.constraints, self.constraint_datas, strict=True):
            cm.calc(model, data, cd)
            out.append(np.array(cd.constraint_position_error))
        return np.concatenate(out)

    def jacobian(self, model: pin.Model, data: pin.Data) -> np.ndarray:
        """Exact Jacobian (n_rows, nv) of :meth:`residual`; joint Jacobians must be up to date.

        For a "6D" pair Pinocchio's constraint Jacobian is the relative twist of frame b with
        respect to frame a in a's axes; the derivative of ``log6(aMb)`` is
        ``Jlog6(aMb) Ad(bMa)`` times it (equal to it on the closed loop).
        """
        rows = []
        for pair, cm, cd in zip(self.pairs, self.constraints, self.constraint_datas,
                                strict=True):
            cm.calc(model, data, cd)
            jac = np.array(pin.getConstraintJacobian(model, data, cm, cd))
            if pair.kind == "6D":
                a_m_b = cd.c1Mc2
                jac = pin.Jlog6(a_m_b) @ a_m_b.inverse().toActionMatrix() @ jac
            rows.append(jac)
        return np.vstack(rows)

    def _world_points(self, model: pin.Model):
        """Per pair, the ((joint_a, placement_a), (joint_b, placement_b)) point pairs."""
        out = []
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
        return np.concatenate(rows)

    def world_jacobian(self, model: pin.Model, data: pin.Data) -> np.ndarray:
        """Jacobian (n_world_rows, nv) of the world-axes residual p_b - p_a."""
        rows = []
        for points, (fa, fb) in zip(self._world_points(model), self.frame_ids, strict=True):
            if points is None:
                ja = kinematics.frame_jacobian(model, data, fa)[:3]
                jb = kinematics.frame_jacobian(model, data, fb)[:3]
                rows.append(jb - ja)
                continue
            for (ja, ma), (jb, mb) in points:
                rows.append(pin.getFrameJacobian(model, data, jb, mb, kinematics.LWA)[:3]
                            - pin.getFrameJacobian(model, data, ja, ma, kinematics.LWA)[:3])
        return np.vstack(rows)

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
        return np.concatenate(blocks, axis=0)

    def passive_rank(self, model: pin.Model, data: pin.Data, rtol: float = 1e-9) -> int:
        """Rank of the passive columns of :meth:`jacobian` (rank-revealing SVD).

        The passive joints are determined by the independent ones where it equals the number
        of passive velocity coordinates; rows beyond it are redundant (planar loops).
        """
        cp = self.jacobian(model, data)[:, self.passive_v]
        sv = np.linalg.svd(cp, compute_uv=False)
        return int(np.sum(sv > rtol * max(1.0, sv[0] if sv.size else 0.0)))

    def passive_rates(self, model: pin.Model, data: pin.Data, independent_v: np.ndarray
                      ) -> np.ndarray:
        """Rates of the passive joints per unit rate of the independent joints, (n_p, n_i).

        Least-squares (rank-revealing) solution of ``C_p dq_p = -C_i dq_i``; joint Jacobians
        must be up to date.
        """
        c = self.jacobian(model, data)
        return -np.linalg.pinv(c[:, self.passive_v], rcond=1e-9) @ c[:, independent_v]

    def close(
        self, model: pin.Model, data: pin.Data, q: np.ndarray, max_iterations: int = 50
    ) -> np.ndarray:
        """Solve the passive joints so that the loops close, by Gauss-Newton from ``q``.

        The independent joints keep their values. Seed ``q`` near the wanted assembly branch
        (the closure keeps the branch it starts on).

        Raises
        ------
        LoopClosureError
            If the loop does not close (the independent joints put it out of reach).
        """
        q = q.copy()
        for _ in range(max_iterations):
            kinematics.update_first_order(model, data, q)
            c = self.residual(model, data)
            if np.linalg.norm(c) < CLOSURE_TOLERANCE_M:
                return q
            cp = self.jacobian(model, data)[:, self.passive_v]
            step = np.linalg.lstsq(cp, -c, rcond=1e-10)[0]
            dv = np.zeros(model.nv)
            dv[self.passive_v] = step
            q = pin.integrate(model, q, dv)
        kinematics.update_first_order(model, data, q)
        c = self.residual(model, data)
        if np.linalg.norm(c) < 1e3 * CLOSURE_TOLERANCE_M:
            return q
        raise LoopClosureError(
            f"the kinematic loop does not close (residual {np.linalg.norm(c):.3g} m after "
            f"{max_iterations} iterations): the configuration is out of the loop's reach; "
            "check the joint values and their units"
        )


def build_loop_closure(model: pin.Model, declaration: LoopDeclaration) -> LoopClosure:
    """Turn a declaration into Pinocchio constraints on ``model``.

    Raises
    ------
    UnknownFrameError, UnknownJointError
        If a frame or joint named in the declaration is not in the model.
    """
    frame_names = [f.name for f in model.frames]
    joint_names = list(model.names)[1:]
    frame_ids, constraints, datas = [], [], []
    path_joints: set[str] = set()
    for pair in declaration.pairs:
        ids = []
        for name in (pair.frame_a, pair.frame_b):
            if not model.existFrame(name):
                raise UnknownFrameError(
                    f"loop frame {name!r} is not in the model; {did_you_mean(name, frame_names)}",
                    name=name, choices=frame_names)
            ids.append(model.getFrameId(name))
        fa, fb = (model.frames[i] for i in ids)
        anchor = (pin.FrameAnchorConstraintModel if pair.kind == "6D"
                  else pin.PointAnchorConstraintModel)
        cm = anchor(model, fa.parentJoint, fa.placement, fb.parentJoint, fb.placement)
        constraints.append(cm)
        datas.append(cm.createData())
        frame_ids.append((ids[0], ids[1]))
        support_a = set(model.supports[fa.parentJoint])
        support_b = set(model.supports[fb.parentJoint])
        path_joints |= {model.names[j] for j in support_a ^ support_b}
    for name in declaration.actuated:
        if name not in joint_names:
            raise UnknownJointError(
                f"actuated joint {name!r} is not in the model; {did_you_mean(name, joint_names)}",
                name=name, choices=joint_names)
    if declaration.passive is None:
        passive = tuple(
            j for j in joint_names if j in path_joints and j not in declaration.actuated
        )
    else:
        passive = declaration.passive
        for name in passive:
            if name not in joint_names:
                raise UnknownJointError(
                    f"passive joint {name!r} is not in the model; "
                    f"{did_you_mean(name, joint_names)}", name=name, choices=joint_names)
    joints = [model.joints[model.getJointId(j)] for j in passive]
    passive_v = np.concatenate([np.arange(j.idx_v, j.idx_v + j.nv) for j in joints]).astype(int)
    return LoopClosure(declaration.pairs, frame_ids, constraints, datas, passive, passive_v)

