"""What a robot file declares, checked while a robot loads
(:func:`stiffness.robot.robot.load_robot`).

The coordinate joints and their order, the compliant joints, the mimic couplings that survive
the loop file's rewrites, the target offset and the ``[controller]`` coordinates
(docs/robot-files.md). Each check raises a :class:`~stiffness.errors.StiffnessError` of one line
naming the robot, the field and the fix.

Units: SI (m, rad).
"""

from __future__ import annotations

import os

import numpy as np
import pinocchio as pin

from stiffness.errors import (
    FlagValueWarning,
    RobotFileError,
    RobotFileWarning,
    StiffnessError,
    UnknownJointError,
    did_you_mean,
    warn_user,
    wrong_argument,
)
from stiffness.robot.coupling import CoordinateMap, read_coordinate_map
from stiffness.robot.kinematics import reach
from stiffness.robot.urdf import Mimic, warn
from stiffness.units import float_array

#: Pinocchio joints that can be coordinates: revolute, continuous and prismatic.
SUPPORTED_JOINTS = {
    "JointModelRX", "JointModelRY", "JointModelRZ", "JointModelRevoluteUnaligned",
    "JointModelPX", "JointModelPY", "JointModelPZ", "JointModelPrismaticUnaligned",
    "JointModelRUBX", "JointModelRUBY", "JointModelRUBZ", "JointModelRevoluteUnboundedUnaligned",
}


def checked_mimics(name: str, mimics: tuple[Mimic, ...], model: pin.Model, passive: set[str]
                  ) -> tuple[Mimic, ...]:
    """Mimic couplings that still apply after rewrites and locking (warn about the others)."""
    kept = []
    for m in mimics:
        if not (model.existJointName(m.follower) and model.existJointName(m.leader)):
            warn(f"{name}: mimic joint {m.follower!r} (leader {m.leader!r}) is not in the "
                 "model after the joint rewrites; its coupling is ignored")
            continue
        if m.leader in passive or any(m.leader == other.follower for other in mimics):
            raise StiffnessError(
                f"{name}: mimic joint {m.follower!r} follows {m.leader!r}, which is a passive "
                "loop joint or itself a mimic follower; make the leader an actuated joint "
                "(name_mot) or declare the follower passive")
        follower, leader = model.joints[model.getJointId(m.follower)], model.joints[
            model.getJointId(m.leader)]
        if follower.nv != 1 or leader.nv != 1:
            raise StiffnessError(f"{name}: mimic joint {m.follower!r} and its leader "
                                 f"{m.leader!r} must both have one degree of freedom")
        kept.append(m)
    return tuple(kept)


def target_offset_of(target_offset: np.ndarray | list[float] | None, settings: dict,
                     title: str, model: pin.Model, frame: str) -> np.ndarray:
    """The target's position (3,) in ``frame``'s axes (m): given, else the robot file's; one
    beyond the reach of ``title``'s ``model`` is warned about (:func:`warn_far_target`)."""
    given = target_offset is not None
    if target_offset is None:
        target_offset = settings.get("target_offset_m", [0.0, 0.0, 0.0])
    offset = float_array(target_offset, "target_offset", "three lengths in m",
                         finite=False).reshape(-1)
    if offset.shape != (3,) or not np.all(np.isfinite(offset)):
        raise StiffnessError(f"target offset must be three finite lengths in m, got {offset}")
    warn_far_target(title, model, frame, offset, given)
    return offset


#: The start of :func:`warn_far_target`'s message after the robot's name (a filter's pattern).
FAR_TARGET = ".*the target offset .* beyond the robot's reach"


def warn_far_target(title: str, model: pin.Model, frame: str, offset: np.ndarray,
                    given: bool) -> None:
    """Warn once (:class:`~stiffness.errors.FlagValueWarning` when the offset was ``given``,
    else :class:`~stiffness.errors.RobotFileWarning`) when the target ``offset`` (m) from
    ``frame`` is longer than the robot's reach (:func:`~stiffness.robot.kinematics.reach`): no
    tool is that long, the values were meant in mm (``--target-offset 0,0,100``)."""
    size, length = reach(model), float(np.linalg.norm(offset))
    if length <= size:
        return
    values = ",".join(f"{v:g}" for v in offset)
    warn_user(f"{title}: the target offset {values} m puts the target {length:.3g} m from frame "
              f"{frame}, beyond the robot's reach ({size:.3g} m); give it in m (in mm these "
              f"values are {length * 1e-3:.3g} m): --target-offset and robot.toml's "
              "target_offset_m are in m, a campaign's [robot] target_offset in its [units] "
              "length", FlagValueWarning if given else RobotFileWarning)


def joint_names(names: str | list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """Joint names given as a sequence, or as one string of comma-separated names (as the
    ``--compliant-joints`` flag takes them: ``"elbow_joint"`` was read as its letters)."""
    if isinstance(names, str):
        return tuple(n.strip() for n in names.split(","))
    if not isinstance(names, list | tuple) or not all(isinstance(n, str) for n in names):
        raise wrong_argument("compliant_joints", names, "joint names: a list of str, or one str "
                             "'a,b,...'")
    return tuple(names)


def free_joints(model: pin.Model, excluded: set[str]) -> list[str]:
    """Joints with a degree of freedom, in model order, but the ``excluded`` ones (passive
    loop joints, mimic followers): the coordinate joints.

    Raises
    ------
    StiffnessError
        If one of them is neither revolute, continuous nor prismatic.
    """
    coordinate_joints = []
    for jid in range(1, model.njoints):
        joint = model.joints[jid]
        joint_name = model.names[jid]
        if joint.nv == 0 or joint_name in excluded:
            continue
        if joint.shortname() not in SUPPORTED_JOINTS:
            fix = ("fix the base with --fixed-base, or declare it passive in a loop file"
                   if model.parents[jid] == 0 else
                   "it is not the base, which --fixed-base fixes: make it type=\"fixed\" in "
                   "the URDF if it does not move, or declare it passive in a loop file")
            raise StiffnessError(
                f"joint {joint_name!r} is a {joint.shortname()} with {joint.nv} degrees of "
                f"freedom; only revolute, continuous and prismatic joints can be coordinates "
                f"({fix})")
        coordinate_joints.append(joint_name)
    return coordinate_joints


def ordered_coordinates(name: str, settings: dict, coordinate_joints: list[str],
                         loops: str | os.PathLike | None) -> tuple[list[str], dict]:
    """The coordinate joints in the robot file's ``coordinate_order``, and the settings; a
    ``coordinate_order`` that a ``loops`` file made wrong is dropped with the coordinates'
    defaults (warned)."""
    order = settings.get("coordinate_order")
    if order is not None and loops is not None and sorted(order) != sorted(coordinate_joints):
        warn(f"{name}: the coordinate_order of its robot.toml does not match the coordinates "
             f"under the loop file {loops}; model order used, and its defaults for the "
             "coordinates (q, compliant joints, springs) dropped")
        settings = {k: v for k, v in settings.items() if k not in (
            "coordinate_order", "q_SI", "q_deg", "rest_q_SI", "compliant_joints", "k_theta_SI")}
        order = None
    if order is not None:
        if sorted(order) != sorted(coordinate_joints):
            raise StiffnessError(
                f"coordinate_order {order} of {name} must list exactly its coordinate joints "
                f"{coordinate_joints}"
            )
        coordinate_joints = list(order)
    return coordinate_joints, settings


def check_compliant(name: str, compliant_joints: tuple[str, ...], spring_names: list[str],
                     passive: set[str], dependent: set[str], coupling: CoordinateMap | None,
                     model: pin.Model | None = None) -> None:
    """Raise if a compliant joint carries no spring (not in ``spring_names``: the reason named,
    a fixed joint or a link of ``model`` among them) or is listed twice."""
    for joint_name in compliant_joints:
        if joint_name not in spring_names:
            why = (" (it is a passive loop joint)" if joint_name in passive else
                   " (it is a mimic follower: its leader carries the spring)"
                   if joint_name in dependent else _frame_kind(model, joint_name))
            if coupling is not None:
                why = (f" (its springs act on the {coupling.springs_on}'s coordinates: "
                       "[controller] springs_on)")
            raise UnknownJointError(
                f"compliant joint {joint_name!r} is not a coordinate joint of {name}{why}; "
                f"{did_you_mean(joint_name, spring_names)}", name=joint_name,
                choices=spring_names)
    if len(set(compliant_joints)) != len(compliant_joints):
        twice = next(j for j in compliant_joints if compliant_joints.count(j) > 1)
        raise StiffnessError(f"compliant joints repeat a name: {list(compliant_joints)} "
                             f"({twice!r} twice); name each joint once")


def _frame_kind(model: pin.Model | None, name: str) -> str:
    """What ``name`` is in ``model`` when it is no joint with a degree of freedom: a fixed joint
    (ROS-Industrial's ``joint_6-tool0``) or a link, with the joint that moves it."""
    if model is None or not model.existFrame(name):
        return ""
    frame = model.frames[model.getFrameId(name)]
    if frame.type == pin.FrameType.FIXED_JOINT:
        return " (it is a fixed joint: nothing turns it)"
    if frame.type == pin.FrameType.BODY and frame.parentJoint > 0:
        return f" (it is a link, moved by joint {model.names[frame.parentJoint]!r})"
    return ""


def controller_map(name: str, settings: dict, model: pin.Model, chain: list[str], looped: bool,
                mimics: tuple[Mimic, ...]) -> CoordinateMap | None:
    """The ``[controller]`` map of a robot file over its chain joints, or None without one."""
    if "controller" not in settings:
        return None
    path = settings.get("_file", name)
    if looped or mimics or "coordinate_order" in settings:
        what = "a closed loop" if looped else "mimic joints" if mimics else "coordinate_order"
        raise RobotFileError(path, None, f"[controller] coordinates cannot be combined with "
                             f"{what}: write the coupling in [controller] alone")
    kinds = {j: "prismatic" if model.joints[model.getJointId(j)].shortname().startswith(
        "JointModelP") else "revolute" for j in chain}
    dh = settings.get("dh")
    units = {k: dh[k] for k in ("angle_unit", "length_unit")
             if isinstance(dh, dict) and k in dh}
    return read_coordinate_map(settings["controller"], path, kinds, units)
