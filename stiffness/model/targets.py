"""The default target frame and the frames a robot's joints move.

Rule (docs/robot-files.md): the target is the tip frame of the longest chain of moving joints
(joints with a degree of freedom, counted from the base); in a closed-loop robot, a branch
whose last joint carries a loop-closing frame is not a candidate (it closes a loop) unless all
branches are such ones. When several chains are equally long
and branch off a common moving joint (a hand's fingers, a gripper's jaws), the tip is on that
last common joint; when they share no moving joint (two legs), the first chain in model order is
taken. The tip frame is, among the frames carried by the tip joint, the one farthest from the
joint's origin, a link or tool frame before a joint frame, the last in model order on a tie.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin


def moving_depth(model: pin.Model) -> list[int]:
    """Number of joints with a degree of freedom from the base to each joint (inclusive)."""
    depth = [0] * model.njoints
    for j in range(1, model.njoints):
        depth[j] = depth[model.parents[j]] + (1 if model.joints[j].nv > 0 else 0)
    return depth


def moving_frames(model: pin.Model) -> list[str]:
    """Frames that at least one joint with a degree of freedom moves."""
    depth = moving_depth(model)
    return [f.name for f in model.frames if depth[f.parentJoint] > 0]


def default_target_frame(model: pin.Model, closure_frames: frozenset[str] = frozenset()
                         ) -> str | None:
    """Name of the default target frame (module docstring), or None when nothing moves.

    ``closure_frames`` are the loop-closing frames: a branch whose last joint carries one of them
    exists to close a loop, and is not a candidate chain unless every branch is such a one.
    """
    depth = moving_depth(model)
    if max(depth) == 0:
        return None
    has_child = {model.parents[j] for j in range(1, model.njoints)}
    leaves = [j for j in range(1, model.njoints) if j not in has_child and depth[j] > 0]
    closing = {f.parentJoint for f in model.frames if f.name in closure_frames}
    open_leaves = [j for j in leaves if j not in closing] or leaves
    longest = max(depth[j] for j in open_leaves)
    deepest = [j for j in open_leaves if depth[j] == longest]
    common = set(model.supports[deepest[0]])
    for j in deepest[1:]:
        common &= set(model.supports[j])
    shared = [j for j in common if j != 0 and model.joints[j].nv > 0]
    tip = max(shared, key=lambda j: depth[j]) if len(deepest) > 1 and shared else deepest[0]
    best, best_key = None, None
    for fid, frame in enumerate(model.frames):
        if frame.parentJoint != tip or frame.name in closure_frames:
            continue
        distance = float(np.linalg.norm(frame.placement.translation))
        key = (round(distance, 9), frame.type != pin.FrameType.JOINT, fid)
        if best_key is None or key > best_key:
            best, best_key = frame.name, key
    if best is None:  # only loop-closing frames on the tip joint
        return default_target_frame(model) if closure_frames else None
    return best
