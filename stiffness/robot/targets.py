"""The target frame (the default one, or the requested one checked), the frames a robot's joints
move, and the joints that do not move it (an end-effector branch, a gripper's jaws).

Rule (docs/robot-files.md): the target is the tip frame of the longest chain of moving joints
(joints with a degree of freedom, counted from the base); in a closed-loop robot, a branch
whose last joint carries a loop-closing frame is not a candidate (it closes a loop) unless all
branches are such ones. Of several equally long chains the first in model order is taken,
except that chains branching off it with fewer moving joints below the branch than above it (a
hand's fingers) move the tip up to their last common joint (the wrist); joints of
``<mimic>`` couplings (a gripper's jaws) do not lengthen a chain. The tip frame is, among the
frames carried by the tip joint, the one farthest from the joint's origin, a link or tool frame
before a joint frame, the last in model order on a tie.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from stiffness.errors import StiffnessError, UnknownFrameError, did_you_mean
from stiffness.robot.urdf import Mimic


def moving_depth(model: pin.Model, uncounted: frozenset[str] = frozenset()) -> list[int]:
    """Number of joints with a degree of freedom from the base to each joint (inclusive),
    not counting the joints named in ``uncounted``."""
    depth = [0] * model.njoints
    for j in range(1, model.njoints):
        moves = model.joints[j].nv > 0 and model.names[j] not in uncounted
        depth[j] = depth[model.parents[j]] + (1 if moves else 0)
    return depth


def moving_frames(model: pin.Model) -> list[str]:
    """Frames that at least one joint with a degree of freedom moves."""
    depth = moving_depth(model)
    return [f.name for f in model.frames if depth[f.parentJoint] > 0]


def default_target_frame(model: pin.Model, closure_frames: frozenset[str] = frozenset(),
                         gripper: frozenset[str] = frozenset()) -> str | None:
    """Name of the default target frame (module docstring), or None when nothing moves.

    ``closure_frames`` are the loop-closing frames: a branch whose last joint carries one of them
    exists to close a loop, and is not a candidate chain unless every branch is such a one.
    ``gripper`` names the joints of ``<mimic>`` couplings (leaders and followers: a gripper's
    jaws), which do not lengthen a chain.
    """
    depth = moving_depth(model, gripper)
    if max(depth) == 0:
        return None
    has_child = {model.parents[j] for j in range(1, model.njoints)}
    leaves = [j for j in range(1, model.njoints) if j not in has_child and depth[j] > 0]
    closing = {f.parentJoint for f in model.frames if f.name in closure_frames}
    open_leaves = [j for j in leaves if j not in closing] or leaves
    longest = max(depth[j] for j in open_leaves)
    deepest = [j for j in open_leaves if depth[j] == longest]
    tip = deepest[0]
    while tip and model.names[tip] in gripper or depth[model.parents[tip]] == depth[tip] > 0:
        tip = model.parents[tip]  # up to the last joint that lengthens the chain
    for other in deepest[1:]:
        shared = [j for j in model.supports[other] if j in set(model.supports[deepest[0]])
                  and model.joints[j].nv > 0]
        branch = max(shared, key=lambda j: depth[j]) if shared else 0
        # branches shorter than the chain that carries them are one hand's fingers
        if branch and longest - depth[branch] <= depth[branch] \
                and branch in model.supports[tip] and branch != tip:
            tip = branch  # fingers or jaws of one hand: their last common joint
    # a loop-closing frame and the fixed-joint frame that carries it are not targets
    closing_frames = set(closure_frames) | {
        model.frames[model.frames[i].parentFrame].name for i in range(len(model.frames))
        if model.frames[i].name in closure_frames}
    best, best_key = None, None
    for fid, frame in enumerate(model.frames):
        if frame.parentJoint != tip or frame.name in closing_frames or _below(model, fid,
                                                                                gripper):
            continue
        distance = float(np.linalg.norm(frame.placement.translation))
        key = (round(distance, 9), frame.type != pin.FrameType.JOINT, fid)
        if best_key is None or key > best_key:
            best, best_key = frame.name, key
    hand = _with_descendants(model, gripper) if best is None else gripper
    if hand != gripper:
        # the tip is a joint below a coupled jaw (PR2's finger tips): count it with the hand
        return default_target_frame(model, closure_frames, hand)
    if best is None:  # only loop-closing frames on the tip joint
        return default_target_frame(model, frozenset(), gripper) if closure_frames else None
    return best


def _with_descendants(model: pin.Model, joints: frozenset[str]) -> frozenset[str]:
    """``joints`` and every joint below one of them (a gripper's jaws carry their finger
    joints, coupled or not: PR2's finger tips)."""
    if not joints:
        return joints
    return frozenset(model.names[j] for j in range(1, model.njoints)
                     if any(model.names[a] in joints for a in model.supports[j]))


def _below(model: pin.Model, frame_id: int, names: frozenset[str]) -> bool:
    """Whether a frame hangs (through fixed joints) below a frame named in ``names``: the
    links of a gripper's locked jaws."""
    seen = 0
    while frame_id > 0 and seen < len(model.frames):
        if model.frames[frame_id].name in names:
            return True
        frame_id = model.frames[frame_id].parentFrame
        seen += 1
    return False


def checked_target_frame(name: str, model: pin.Model, frame: str | None,
                  closure: frozenset[str], gripper: frozenset[str]) -> str:
    """The requested target frame, checked, or the default one."""
    frame_names = [f.name for f in model.frames]
    moving = moving_frames(model)
    if frame is None:
        frame = default_target_frame(model, closure, gripper)
        if frame is None:
            raise StiffnessError(f"no joint of {name} moves any frame: it has no degree of "
                                 "freedom left to be compliant (a fixed base leaves none when "
                                 "the base was its only joint); choose a robot with joints")
        return frame
    if not model.existFrame(frame):
        raise UnknownFrameError(
            f"frame {frame!r} is not in {name}; {did_you_mean(frame, frame_names)}",
            name=frame, choices=frame_names)
    if frame not in moving:
        raise UnknownFrameError(
            f"frame {frame!r} of {name} is not moved by any joint (it is fixed to the base), so "
            f"it has no stiffness to compute; choose a frame that moves: "
            f"{did_you_mean(frame, moving)}", name=frame, choices=moving)
    return frame


def branch_joints(model: pin.Model, frame_id: int, coordinate_joints: Sequence[str],
                  coupled: bool) -> tuple[str, ...]:
    """Coordinate joints of an end-effector branch: they hang below the joint that moves frame
    ``frame_id`` (fingers, a gripper's jaws), so that the frame does not depend on them. Other
    limbs (an arm or leg branching off higher up) are not among them; none when ``coupled``
    (closed loops or a controller map may tie every coordinate to the target)."""
    parent = model.frames[frame_id].parentJoint
    if coupled or parent == 0:
        return ()
    return tuple(name for name in coordinate_joints
                 if (jid := model.getJointId(name)) != parent and parent in model.supports[jid])


def target_chain(model: pin.Model, frame_id: int, names: Sequence[str], coupled: bool
                 ) -> tuple[str, ...]:
    """The joints of ``names`` on the chain from the base to frame ``frame_id``: the joints
    that move it (not a head, wheels, fingers or another limb); all of ``names`` when
    ``coupled`` (closed loops or a controller map may tie every coordinate to the target)."""
    if coupled:
        return tuple(names)
    supports = set(model.supports[model.frames[frame_id].parentJoint])
    return tuple(name for name in names if model.getJointId(name) in supports)


def gripper_joints(model: pin.Model, mimics: tuple[Mimic, ...]) -> frozenset[str]:
    """Joints of ``<mimic>`` couplings that act side by side (a gripper's jaws: the follower
    does not hang below its leader), which do not lengthen a chain for the default target."""
    out: set[str] = set()
    for m in mimics:
        if model.existJointName(m.follower) and model.existJointName(m.leader) and \
                model.getJointId(m.leader) in model.supports[model.getJointId(m.follower)]:
            continue  # a serial coupling: the follower extends the leader's chain
        out |= {m.leader, m.follower}
    return frozenset(out)
