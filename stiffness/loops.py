"""Loop closures: declarations beside a URDF, Pinocchio constraints, closure, projection.

A URDF holds a tree; a closed chain is declared as a tree plus loop-closing frame pairs. The
declaration follows the "Extended URDF" YAML sidecar of Gepetto's toolbox-parallel-robots::

    closed_loop:              # frame pairs that coincide when the loop is closed
      - [coupler_end, forearm_rear]
    type: ["3D"]              # "3D": the two frame origins coincide (point constraint)
    name_mot: [joint1, joint2, joint3]   # actuated joints

Optional key ``passive_joints`` lists the loop's unactuated joints; by default they are the
joints on the path between the two frames of each pair that are not actuated.

Conventions (see docs/conventions.md): the closure residual is Pinocchio's
``PointAnchorConstraintModel`` residual (p_b - p_a in frame a's axes); its Jacobian is the exact
derivative of that residual. Second-order terms use the world-axes residual c_w = p_b - p_a,
whose Hessian comes from Pinocchio's kinematic Hessians; on the closed loop both Jacobians differ
by the rotation of frame a only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness import kinematics
from stiffness.errors import StiffnessError, did_you_mean

#: Closure tolerance on the loop residual (m).
CLOSURE_TOLERANCE_M = 1e-11


@dataclass(frozen=True)
class LoopPair:
    """Two frames whose origins coincide when the loop is closed."""

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
    StiffnessError
        If the file is missing, is not YAML, or lacks ``closed_loop``/``type``/``name_mot``.
    """
    import yaml

    path = Path(path)
    if not path.is_file():
        raise StiffnessError(f"loop declaration {path} does not exist; give the YAML sidecar path")
    try:
        content = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise StiffnessError(f"loop declaration {path} is not valid YAML: {exc}") from exc
    if not isinstance(content, dict):
        raise StiffnessError(f"loop declaration {path} must be a YAML mapping")
    missing = [k for k in ("closed_loop", "type", "name_mot") if k not in content]
    if missing:
        raise StiffnessError(
            f"loop declaration {path} lacks {', '.join(missing)}; it needs closed_loop (frame "
            "pairs), type (one of '3D' per pair) and name_mot (actuated joints)"
        )
    loops, kinds = content["closed_loop"], content["type"]
    if len(loops) != len(kinds):
        raise StiffnessError(
            f"loop declaration {path}: {len(loops)} closed_loop pairs but {len(kinds)} types"
        )
    pairs = []
    for pair, kind in zip(loops, kinds, strict=True):
        if len(pair) != 2:
            raise StiffnessError(f"loop declaration {path}: {pair} is not a pair of frame names")
        if kind not in ("3D",):
            raise StiffnessError(
                f"loop declaration {path}: loop type {kind!r} is not supported; use '3D'"
            )
        pairs.append(LoopPair(str(pair[0]), str(pair[1]), kind))
    passive = content.get("passive_joints")
    return LoopDeclaration(
        tuple(pairs),
        tuple(str(j) for j in content["name_mot"]),
        None if passive is None else tuple(str(j) for j in passive),
    )


@dataclass
class LoopClosure:
    """Loop-closure constraints of a model, built as Pinocchio point-anchor constraints.

    Attributes
    ----------
    pairs
        The declared frame pairs.
    frame_ids
        ``(frame_a_id, frame_b_id)`` for each pair.
    constraints
        One ``pin.PointAnchorConstraintModel`` per pair.
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
        """Number of constraint rows (3 per point constraint)."""
        return 3 * len(self.pairs)

    def residual(self, model: pin.Model, data: pin.Data) -> np.ndarray:
        """Closure residual (m), Pinocchio's convention; kinematics must be up to date."""
        out = []
        for cm, cd in zip(self.constraints, self.constraint_datas, strict=True):
            cm.calc(model, data, cd)
            out.append(np.array(cd.constraint_position_error))
        return np.concatenate(out)

    def jacobian(self, model: pin.Model, data: pin.Data) -> np.ndarray:
        """Exact Jacobian (n_rows, nv) of :meth:`residual`; joint Jacobians must be up to date."""
        rows = []
        for cm, cd in zip(self.constraints, self.constraint_datas, strict=True):
            cm.calc(model, data, cd)
            rows.append(np.array(pin.getConstraintJacobian(model, data, cm, cd)))
        return np.vstack(rows)

    def world_jacobian(self, model: pin.Model, data: pin.Data) -> np.ndarray:
        """Jacobian (n_rows, nv) of the world-axes residual p_b - p_a."""
        rows = []
        for fa, fb in self.frame_ids:
            ja = kinematics.frame_jacobian(model, data, fa)[:3]
            jb = kinematics.frame_jacobian(model, data, fb)[:3]
            rows.append(jb - ja)
        return np.vstack(rows)

    def world_hessian(self, model: pin.Model, data: pin.Data) -> np.ndarray:
        """Hessian (n_rows, nv, nv) of the world-axes residual p_b - p_a (Hessians current)."""
        blocks = []
        for fa, fb in self.frame_ids:
            ha = kinematics.frame_hessian(model, data, fa)[:3]
            hb = kinematics.frame_hessian(model, data, fb)[:3]
            blocks.append(hb - ha)
        return np.concatenate(blocks, axis=0)

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
        StiffnessError
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
        raise StiffnessError(
            f"the kinematic loop does not close (residual {np.linalg.norm(c):.3g} m after "
            f"{max_iterations} iterations): the configuration is out of the loop's reach; "
            "check the joint values and their units"
        )


def build_loop_closure(model: pin.Model, declaration: LoopDeclaration) -> LoopClosure:
    """Turn a declaration into Pinocchio constraints on ``model``.

    Raises
    ------
    StiffnessError
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
                raise StiffnessError(
                    f"loop frame {name!r} is not in the model; {did_you_mean(name, frame_names)}"
                )
            ids.append(model.getFrameId(name))
        fa, fb = (model.frames[i] for i in ids)
        cm = pin.PointAnchorConstraintModel(
            model, fa.parentJoint, fa.placement, fb.parentJoint, fb.placement
        )
        constraints.append(cm)
        datas.append(cm.createData())
        frame_ids.append((ids[0], ids[1]))
        support_a = set(model.supports[fa.parentJoint])
        support_b = set(model.supports[fb.parentJoint])
        path_joints |= {model.names[j] for j in support_a ^ support_b}
    for name in declaration.actuated:
        if name not in joint_names:
            raise StiffnessError(
                f"actuated joint {name!r} is not in the model; {did_you_mean(name, joint_names)}"
            )
    if declaration.passive is None:
        passive = tuple(
            j for j in joint_names if j in path_joints and j not in declaration.actuated
        )
    else:
        passive = declaration.passive
        for name in passive:
            if name not in joint_names:
                raise StiffnessError(
                    f"passive joint {name!r} is not in the model; "
                    f"{did_you_mean(name, joint_names)}"
                )
    joints = [model.joints[model.getJointId(j)] for j in passive]
    passive_v = np.concatenate([np.arange(j.idx_v, j.idx_v + j.nv) for j in joints]).astype(int)
    return LoopClosure(declaration.pairs, frame_ids, constraints, datas, passive, passive_v)
