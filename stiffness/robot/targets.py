"""The target frame (the default one, or the requested one checked), the frames a robot's joints
move, and the joints that do not move it (an end-effector branch, a gripper's jaws).

Rule (docs/robot-files.md): the target is the tip frame of the longest chain of moving joints
(joints with a degree of freedom, counted from the base); in a closed-loop robot, a branch
whose last joint carries a loop-closing frame is not a candidate (it closes a loop) unless all
branches are such ones. Of several equally long chains the first in model order is taken,
except that chains branching off it with fewer moving joints below the branch than above it (a
hand's fingers) move the tip up to their last common joint (the wrist), as do three or more such
chains of any lengths (a hand whose thumb is longer than its fingers: g1's); joints of
``<mimic>`` couplings (a gripper's jaws) and a last joint named as a jaw (``grip`` or ``jaw``
in its name or its link's, on an arm: z1's ``jointGripper``, so100's ``gripper``) do not lengthen
a chain. The tip frame is, among the frames carried by the tip joint, the one farthest from the
joint's origin, a link or tool frame before a joint frame, the last in model order on a tie;
a sensor's frame (a camera, range finder or IMU, by its name) only when there is no other;
frames at different places tied for farthest (a gripper's fixed fingers) give the frame they
branch from.
When every such frame sits at the joint's origin (double_pendulum's ``link2``), the default
target is the tip link's centre of mass, off the joint's axis, instead of that origin.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from stiffness.errors import StiffnessError, UnknownFrameError, did_you_mean, wrong_argument
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
    if max(depth) == 0:  # a robot that is only a gripper (pr2_gripper): its jaws are the chain
        return default_target_frame(model, closure_frames) if gripper else None
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
    tip = _palm(model, depth, tip, longest)
    # a loop-closing frame and the fixed-joint frame that carries it are not targets
    closing_frames = set(closure_frames) | {
        model.frames[model.frames[i].parentFrame].name for i in range(len(model.frames))
        if model.frames[i].name in closure_frames}
    keys = {}
    for fid, frame in enumerate(model.frames):
        if frame.parentJoint != tip or frame.name in closing_frames or _below(model, fid,
                                                                                gripper):
            continue
        distance = float(np.linalg.norm(frame.placement.translation))
        keys[fid] = (not _sensor(model, fid), round(distance, 9),
                     frame.type != pin.FrameType.JOINT, fid)
    best = model.frames[_branch_point(model, keys)].name if keys else None
    hand = _with_descendants(model, gripper) if best is None else gripper
    if hand != gripper:
        # the tip is a joint below a coupled jaw (PR2's finger tips): count it with the hand
        return default_target_frame(model, closure_frames, hand)
    if best is None:  # only loop-closing frames on the tip joint
        return default_target_frame(model, frozenset(), gripper) if closure_frames else None
    return best


def _branch_point(model: pin.Model, keys: dict[int, tuple]) -> int:
    """The frame of largest key, or, when frames at different places tie for it (a
    gripper's fixed fingers at the same distance on either side: the Robotics Toolbox Fetch's
    ``l_``/``r_gripper_finger_link``), the frame they branch from (``gripper_link``)."""
    best = max(keys, key=keys.__getitem__)
    tied = [f for f in keys if keys[f][:2] == keys[best][:2]]
    places = {tuple(np.round(model.frames[f].placement.translation, 9)) for f in tied}
    if len(places) < 2:
        return best
    chains = [_ancestors(model, f) for f in tied]
    return next(f for f in chains[0] if all(f in chain for chain in chains[1:]))


def _ancestors(model: pin.Model, frame_id: int) -> list[int]:
    """``frame_id`` and the frames it hangs from (through ``parentFrame``), nearest first."""
    out = [frame_id]
    while out[-1] > 0 and len(out) <= len(model.frames):
        out.append(model.frames[out[-1]].parentFrame)
    return out


_SENSOR_WORDS = ("camera", "optical", "depth", "color", "rgb", "infra", "range", "imu",
                 "accelerometer", "gyro", "lidar", "laser", "sonar", "kinect", "realsense")


def _sensor(model: pin.Model, frame_id: int) -> bool:
    """Whether frame ``frame_id`` is a sensor's (a camera, range finder, IMU: a word of
    ``_SENSOR_WORDS`` in its name, or, for a fixed joint's frame, in the link it carries),
    never the tool: Kinova Gen3's ``camera_depth_frame`` and Baxter's ``left_hand_range`` sit
    farther from the wrist than the tool frame beside them."""
    names = [model.frames[frame_id].name] + [
        f.name for f in model.frames if f.parentFrame == frame_id
        and model.frames[frame_id].type == pin.FrameType.FIXED_JOINT]
    return any(word in name.lower() for name in names for word in _SENSOR_WORDS)


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
        frame = model.frames[frame_id]  # a joint's name, not a link's that is spelled the same
        if frame.name in names and frame.type != pin.FrameType.BODY:
            return True
        frame_id = model.frames[frame_id].parentFrame
        seen += 1
    return False


def checked_target_frame(name: str, model: pin.Model, frame: str | None,
                  closure: frozenset[str], gripper: frozenset[str]) -> str:
    """The requested target frame, checked, or the default one."""
    if frame is not None and not isinstance(frame, str):
        raise wrong_argument("frame", frame, f"the name (str) of a frame of {name}")
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


def target_chain(model: pin.Model, frame_id: int, names: Sequence[str], coupled: bool,
                 mimics: Sequence[Mimic] = ()) -> tuple[str, ...]:
    """The joints of ``names`` on the chain from the base to frame ``frame_id``: the joints
    that move it (not a head, wheels, fingers or another limb), a ``<mimic>`` leader among them
    when its follower is on the chain (a gripper's jaw as the target: robotiq's
    ``left_inner_finger`` moved by ``finger_joint`` through its followers); all of ``names``
    when ``coupled`` (closed loops or a controller map may tie every coordinate to the target)."""
    if coupled:
        return tuple(names)
    supports = {model.names[j] for j in model.supports[model.frames[frame_id].parentJoint]}
    supports |= {m.leader for m in mimics if m.follower in supports}
    return tuple(name for name in names if name in supports)


def default_target_offset(model: pin.Model, frame_id: int) -> np.ndarray:
    """The default target's position (3,) in the axes of frame ``frame_id`` (m): the frame's
    origin, unless it is the link of a last joint that carries no other frame and sits at the
    joint's origin (double_pendulum's ``link2``), where that joint's spring would not move it;
    then the centre of mass of that link (zero when that is at the origin too, or massless).
    A tool frame at the joint's origin (xarm7's ``link_eef`` on the flange) is kept there."""
    frame = model.frames[frame_id]
    body = model.inertias[frame.parentJoint]
    attached = [f for f in model.frames if f.parentJoint == frame.parentJoint
                and f.type not in (pin.FrameType.JOINT, pin.FrameType.BODY)]
    if attached or np.linalg.norm(frame.placement.translation) > _AT_ORIGIN_M \
            or body.mass <= 0.0 or np.linalg.norm(body.lever) <= _AT_ORIGIN_M:
        return np.zeros(3)  # a tool frame at the origin (xarm7's flange) is meant there
    return np.asarray(frame.placement.actInv(body.lever), dtype=float).copy()


def gripper_joints(model: pin.Model, mimics: tuple[Mimic, ...]) -> frozenset[str]:
    """Joints of ``<mimic>`` couplings that act side by side (a gripper's jaws: the follower
    does not hang below its leader, and the leader carries no arm: :func:`_carries_arm`) and a
    last joint named as a jaw (:func:`jaw_joints`), which
    do not lengthen a chain for the default target."""
    out: set[str] = set(jaw_joints(model))
    coupled = {m.follower for m in mimics} | {m.leader for m in mimics}
    for m in mimics:
        if model.existJointName(m.follower) and model.existJointName(m.leader) and \
                model.getJointId(m.leader) in model.supports[model.getJointId(m.follower)]:
            continue  # a serial coupling: the follower extends the leader's chain
        if model.existJointName(m.leader) and _carries_arm(model, model.getJointId(m.leader),
                                                           coupled):
            continue  # a linkage inside the arm (irb6640's balancer cylinder on joint_2)
        out |= {m.leader, m.follower}
    return frozenset(out)


def _carries_arm(model: pin.Model, leader: int, coupled: set[str]) -> bool:
    """Whether joint ``leader`` carries more moving joints of no ``<mimic>`` coupling below it
    than there are moving joints above it: an arm's joint whose side-by-side follower is a
    linkage (a balancer's cylinder and piston), not a gripper's jaw, which carries at most its
    own coupled finger joints."""
    below = sum(1 for j in range(1, model.njoints) if j != leader and leader in model.supports[j]
                and model.joints[j].nv > 0 and model.names[j] not in coupled)
    return below > moving_depth(model)[model.parents[leader]]


_AT_ORIGIN_M = 1e-9  # a frame this close to its joint's origin sits at it (m)
_JAW_WORDS = ("grip", "jaw")


def jaw_joints(model: pin.Model) -> frozenset[str]:
    """Last joints of a chain (no joint with a degree of freedom below them) carried by other
    moving joints, whose name or link's name says it is a gripper's jaw (``grip`` or ``jaw`` in
    it) and that move it against a link named so too (the gripper's body, or fixed jaw): a
    gripper without a ``<mimic>`` coupling (z1's ``jointGripper`` on ``gripperStator``,
    so100's ``gripper`` moving the ``jaw`` link on the ``gripper`` link). A last joint moving
    a gripper as a whole (hextilt's, icub's) is not one, nor a hand's finger (the hand rule
    handles fingers)."""
    depth = moving_depth(model)
    parents_of_moving = {model.parents[j] for j in range(1, model.njoints)
                         if model.joints[j].nv > 0}
    out = set()
    for j in range(1, model.njoints):
        if model.joints[j].nv == 0 or j in parents_of_moving or depth[model.parents[j]] == 0:
            continue
        if _jaw_named([model.names[j]] + _links(model, j)) and \
                _jaw_named(_links(model, model.parents[j])):
            out.add(model.names[j])
    return frozenset(out)


def _links(model: pin.Model, joint: int) -> list[str]:
    """Names of the links (body frames) that joint ``joint`` carries, fixed ones included."""
    return [f.name for f in model.frames
            if f.parentJoint == joint and f.type == pin.FrameType.BODY]


def _jaw_named(names: list[str]) -> bool:
    """Whether one of ``names`` says it is part of a gripper (``grip`` or ``jaw`` in it)."""
    return any(word in name.lower() for name in names for word in _JAW_WORDS)


def _palm(model: pin.Model, depth: list[int], tip: int, longest: int) -> int:
    """The joint of ``tip``'s chain from which three or more chains branch that are shorter
    than the chain carrying it (a hand: a thumb and fingers, g1's thumb one joint longer than
    its fingers), else ``tip``."""
    joint = model.parents[tip]
    while joint and longest - depth[joint] <= depth[joint]:
        if sum(1 for c in range(1, model.njoints) if model.parents[c] == joint) >= 3:
            return joint
        joint = model.parents[joint]
    return tip
