"""Model rewrites: Gepetto's ``joint_name``/``joint_type`` and locking joints (fixed bases).

``joint_type`` semantics are those of Gepetto's ``completeRobotLoader``
(example-parallel-robots, ``loader_tools.py``), applied to the joint named in ``joint_name``:

* ``SPHERICAL``: the joint becomes a spherical joint (``JointModelSpherical``, 3 degrees of
  freedom) at the same placement, with the same name.
* ``UJOINT_AB`` (``XY``, ``YZ``, ``ZY``, and the other pairs of distinct axes): the joint becomes
  two revolute joints about the axes A then B of its placement frame (the URDF's ``<axis>`` is
  not used), named ``<name>_A`` and ``<name>_B``, the second at the same origin as the first.
  The link, its frames and its visuals hang on ``<name>_B``; the joint frame ``<name>`` is
  replaced by the joint frames ``<name>_A`` and ``<name>_B``.
* ``FIXED``: the joint is locked at its neutral value (0), as ``pin.buildReducedModel`` does.

Floating and planar bases are locked in the same way (:func:`lock_joints`) at their neutral
placement.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from stiffness.errors import FloatingBaseError
from stiffness.robot.kinematics import frame_id

#: Joint types of Gepetto's ``joint_type`` key (upper case; files may use any case).
JOINT_REWRITES = ("SPHERICAL", "FIXED") + tuple(
    f"UJOINT_{a}{b}" for a in "XYZ" for b in "XYZ" if a != b)

_AXIS_JOINTS = {"X": pin.JointModelRX, "Y": pin.JointModelRY, "Z": pin.JointModelRZ}


def rewrite_joints(model: pin.Model, visual, rewrites: dict[str, str]
                   ) -> tuple[pin.Model, pin.GeometryModel | None]:
    """Apply ``{joint name: joint type}`` rewrites (:data:`JOINT_REWRITES`) to a model.

    Returns the new model and its visual geometry (``visual`` re-attached, or None).
    """
    if not rewrites:
        return model, visual
    new = pin.Model()
    new.name = model.name
    new.gravity = model.gravity
    joint_map = {0: 0}  # old joint id -> new joint id carrying its body
    fixed: list[int] = []
    for jid in range(1, model.njoints):
        name, joint = model.names[jid], model.joints[jid]
        parent = joint_map[model.parents[jid]]
        placement = model.jointPlacements[jid]
        kind = rewrites.get(name)
        if kind == "SPHERICAL":
            new_id = new.addJoint(parent, pin.JointModelSpherical(), placement, name)
        elif kind is not None and kind.startswith("UJOINT_"):
            a, b = kind[-2], kind[-1]
            first = new.addJoint(parent, _AXIS_JOINTS[a](), placement, f"{name}_{a}")
            new_id = new.addJoint(first, _AXIS_JOINTS[b](), pin.SE3.Identity(), f"{name}_{b}")
        else:
            new_id = new.addJoint(parent, joint, placement, name)
            if kind == "FIXED":
                fixed.append(new_id)
        _copy_limits(model, jid, new, new_id)
        new.appendBodyToJoint(new_id, model.inertias[jid], pin.SE3.Identity())
        joint_map[jid] = new_id
    frame_map = {0: 0}
    for fid in range(1, len(model.frames)):
        frame = model.frames[fid]
        parent_frame = frame_map.get(frame.parentFrame, 0)
        kind = rewrites.get(frame.name) if frame.type == pin.FrameType.JOINT else None
        if kind is not None and kind.startswith("UJOINT_"):
            for axis in kind[-2:]:
                joint_name = f"{frame.name}_{axis}"
                frame_map[fid] = new.addFrame(pin.Frame(
                    joint_name, new.getJointId(joint_name), parent_frame, pin.SE3.Identity(),
                    pin.FrameType.JOINT), False)
                parent_frame = frame_map[fid]
            continue
        frame_map[fid] = new.addFrame(pin.Frame(
            frame.name, joint_map[frame.parentJoint], parent_frame, frame.placement, frame.type,
            frame.inertia), False)
    if visual is not None:
        visual = visual.copy()
        for obj in visual.geometryObjects:
            obj.parentJoint = joint_map[obj.parentJoint]
            obj.parentFrame = frame_map.get(obj.parentFrame, 0)
    return lock_joints(new, visual, [new.names[j] for j in fixed])


def _copy_limits(old: pin.Model, jid: int, new: pin.Model, new_id: int) -> None:
    """Keep the position limits of a joint whose type did not change."""
    o, n = old.joints[jid], new.joints[new_id]
    if o.nq == n.nq and o.shortname() == n.shortname():
        new.lowerPositionLimit[n.idx_q: n.idx_q + n.nq] = old.lowerPositionLimit[
            o.idx_q: o.idx_q + o.nq]
        new.upperPositionLimit[n.idx_q: n.idx_q + n.nq] = old.upperPositionLimit[
            o.idx_q: o.idx_q + o.nq]


def lock_joints(model: pin.Model, visual, names: list[str], reference: np.ndarray | None = None
                ) -> tuple[pin.Model, pin.GeometryModel | None]:
    """Lock the named joints at ``reference`` (default neutral); returns model and visuals."""
    if not names:
        return model, visual
    model = _reducible(model)
    ids = [model.getJointId(n) for n in names]
    q0 = pin.neutral(model) if reference is None else reference
    if visual is None:
        return pin.buildReducedModel(model, ids, q0), None
    reduced, geometries = pin.buildReducedModel(model, [visual], ids, q0)
    return reduced, geometries[0]


def _reducible(model: pin.Model) -> pin.Model:
    """A copy of ``model`` that ``pin.buildReducedModel`` accepts, where it would raise a bare
    ``ValueError``: frames sharing a name (a URDF link and a joint) get unique names (the body
    frame keeps it, as :func:`stiffness.robot.kinematics.frame_id` would choose; the others
    become ``<name>.<type>``), and velocity or effort limits whose lower bound exceeds the upper
    (seen in example-robot-data's reduced Talos legs) get the lower bound ``-upper``. Neither
    enters the elastostatics."""
    names = [f.name for f in model.frames]
    shared = {n for n in names if names.count(n) > 1}
    limits = [("lowerVelocityLimit", "upperVelocityLimit"),
              ("lowerEffortLimit", "upperEffortLimit")]
    crossed = [pair for pair in limits
               if np.any(np.asarray(getattr(model, pair[0])) > np.asarray(getattr(model, pair[1])))]
    if not shared and not crossed:
        return model
    model = pin.Model(model)
    for name in shared:
        keep = frame_id(model, name)
        for i, frame in enumerate(model.frames):
            if frame.name == name and i != keep:
                frame.name = f"{name}.{str(frame.type).lower()}"
                model.frames[i] = frame
    for low, high in crossed:
        lower, upper = np.array(getattr(model, low)), np.array(getattr(model, high))
        lower = np.where(lower > upper, -upper, lower)
        setattr(model, low, lower)
    return model


#: Joints of a floating or planar base (fixed by :func:`fix_base`).
BASE_JOINTS = {"JointModelFreeFlyer", "JointModelPlanar"}


def fix_base(model: pin.Model, visual, name: str, fixed_base: bool
              ) -> tuple[pin.Model, pin.GeometryModel | None, list[str]]:
    """Lock floating or planar base joints at their neutral placement when ``fixed_base``."""
    bases = [j for j in range(1, model.njoints)
             if model.parents[j] == 0 and model.joints[j].shortname() in BASE_JOINTS]
    if not bases:
        return model, visual, []
    described = ", ".join(f"{model.names[j]!r} ({model.joints[j].shortname()})" for j in bases)
    if not fixed_base:
        raise FloatingBaseError(
            f"{name} has a floating or planar base, joint {described}: fix the base at its "
            "neutral placement with --fixed-base (Python: load_robot(..., fixed_base=True))")
    names = [model.names[j] for j in bases]
    model, visual = lock_joints(model, visual, names)
    return model, visual, [f"base joint {described} fixed at its neutral placement"]


@dataclass(frozen=True)
class EditedVisual:
    """A source's visual geometry read on demand, with the joint rewrites and base fixing
    that :func:`load_robot` applied to its model (picklable)."""

    model: pin.Model
    read: Callable[[], pin.GeometryModel | None]
    rewrites: dict[str, str] | None
    name: str
    fixed_base: bool

    def __call__(self) -> pin.GeometryModel | None:
        model, visual = self.model, self.read()
        if self.rewrites is not None:
            model, visual = rewrite_joints(model, visual, self.rewrites)
        return fix_base(model, visual, self.name, self.fixed_base)[1]
