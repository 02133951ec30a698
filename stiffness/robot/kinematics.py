"""Frame kinematics from Pinocchio: positions, Jacobians and kinematic Hessians.

Every quirk of the pin 4.x Python bindings is fixed here, once:

* ``getFrameKinematicHessian`` returns the column-major C++ tensor read in row-major order;
  :func:`reorder_hessian` (used by :func:`frame_hessian`, :func:`point_hessian` and the batched
  kernels) reorders it so that ``H[k, a, b] = dJ[k, a] / dq_b``.
* For a model with one velocity coordinate the bindings return Jacobians and Hessians squeezed
  to shape (6,); :func:`frame_jacobian`, :func:`point_jacobian`, :func:`frame_hessian` and
  :func:`point_hessian` always return (6, nv) and (6, nv, nv) (or (3, nv, nv)).
* The URDF parser prints its errors on the C-level standard error: :func:`captured_stderr`.
* Only the ``LOCAL_WORLD_ALIGNED`` linear rows are the Hessian of the frame origin's position;
  this module only ever asks for that reference frame.
* ``Model.getFrameId(name)`` raises a bare ``ValueError`` when several frames share the name
  (a URDF link and joint of the same name): :func:`frame_id` picks one by type.

Spatial quantities follow Pinocchio's order: rows ``[linear (3); angular (3)]``, world axes,
at the frame origin. Units: m, rad.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import pinocchio as pin

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED

#: Which frame a name means when several frames share it: the link first.
_FRAME_TYPE_ORDER = (pin.FrameType.BODY, pin.FrameType.OP_FRAME, pin.FrameType.FIXED_JOINT,
                     pin.FrameType.JOINT, pin.FrameType.SENSOR)


def frame_id(model: pin.Model, name: str) -> int:
    """Index of the frame called ``name`` (which must exist); where several frames share the
    name (a URDF link and a joint), the first by type in :data:`_FRAME_TYPE_ORDER`: the body
    (link) frame, then an operational frame, a fixed joint, a joint, a sensor."""
    matches = [i for i, f in enumerate(model.frames) if f.name == name]
    if len(matches) == 1:
        return matches[0]
    order = {t: k for k, t in enumerate(_FRAME_TYPE_ORDER)}
    return min(matches, key=lambda i: (order.get(model.frames[i].type, len(order)), i))


def reach(model: pin.Model) -> float:
    """The robot's reach (m): the longest chain of joint and frame placements from the base
    (the sum of their lengths, whatever the pose), at least 0.1 m."""
    chain = [0.0] * model.njoints
    for j in range(1, model.njoints):
        chain[j] = chain[model.parents[j]] + float(np.linalg.norm(
            model.jointPlacements[j].translation))
    frames = [chain[f.parentJoint] + float(np.linalg.norm(f.placement.translation))
              for f in model.frames]
    return max([0.1, *chain, *frames])


def update_kinematics(model: pin.Model, data: pin.Data, q: np.ndarray) -> None:
    """Compute placements, joint Jacobians and kinematic Hessians at ``q``.

    Must precede :func:`frame_position`, :func:`frame_jacobian` and :func:`frame_hessian`.
    """
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    pin.computeJointKinematicHessians(model, data)


def update_first_order(model: pin.Model, data: pin.Data, q: np.ndarray) -> None:
    """Compute placements and joint Jacobians only (no Hessians) at ``q``."""
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)


def frame_position(data: pin.Data, frame_id: int) -> np.ndarray:
    """World position (m) of a frame origin, shape (3,)."""
    return data.oMf[frame_id].translation.copy()


def frame_rotation(data: pin.Data, frame_id: int) -> np.ndarray:
    """World orientation of a frame, shape (3, 3)."""
    return data.oMf[frame_id].rotation.copy()


def frame_jacobian(model: pin.Model, data: pin.Data, frame_id: int) -> np.ndarray:
    """Spatial Jacobian (6, nv) of a frame: rows [v; omega], world axes at its origin."""
    return np.asarray(pin.getFrameJacobian(model, data, frame_id, LWA)).reshape(6, model.nv)


def point_jacobian(model: pin.Model, data: pin.Data, joint_id: int, placement: pin.SE3
                   ) -> np.ndarray:
    """Spatial Jacobian (6, nv) of a point fixed to a joint (``placement`` in its frame)."""
    return np.asarray(pin.getFrameJacobian(model, data, joint_id, placement, LWA)).reshape(
        6, model.nv)


def _full_hessian(model: pin.Model, raw) -> np.ndarray:
    """Pinocchio's raw Hessian of one frame, unsqueezed to (6, nv, nv) (nv = 1 models)."""
    raw = np.asarray(raw)
    return raw if raw.ndim == 3 else raw.reshape(6, model.nv, model.nv)


def reorder_hessian(raw: np.ndarray) -> np.ndarray:
    """Kinematic Hessian ``H[..., k, a, b] = dJ[k, a] / dq_b`` from Pinocchio's raw array.

    ``raw`` (..., 6, nv, nv) holds, in its last three axes, the array returned by
    ``getFrameKinematicHessian``: the column-major C++ tensor read in row-major order (leading
    axes, e.g. a batch of configurations, are kept). The memory of each raw tensor, read as
    (nv, nv, 6), is ``H[k, a, b]`` at ``[b, a, k]``. Returns a view.
    """
    raw = np.asarray(raw)
    lead, (_, nv, _) = raw.shape[:-3], raw.shape[-3:]
    axes = tuple(range(len(lead)))
    return raw.reshape(lead + (nv, nv, 6)).transpose(axes + tuple(len(lead) + i for i in (2, 1, 0)))


def frame_hessian(model: pin.Model, data: pin.Data, frame_id: int) -> np.ndarray:
    """Kinematic Hessian (6, nv, nv) of a frame, ``H[k, a, b] = dJ[k, a] / dq_b``.

    Rows 0..2 are the Hessian of the world position of the frame origin (symmetric in a, b);
    rows 3..5 the derivative of the world-axes angular Jacobian. Hessians must be current
    (:func:`update_kinematics`).
    """
    return reorder_hessian(_full_hessian(
        model, pin.getFrameKinematicHessian(model, data, frame_id, LWA)))


def point_hessian(model: pin.Model, data: pin.Data, joint_id: int, placement: pin.SE3
                  ) -> np.ndarray:
    """Hessian (3, nv, nv) of the world position of a point fixed to a joint (m/rad^2).

    ``placement`` locates the point in the joint's frame. Hessians must be current
    (:func:`update_kinematics`).
    """
    raw = pin.getFrameKinematicHessian(model, data, joint_id, placement, LWA)
    return reorder_hessian(_full_hessian(model, raw))[:3]


@contextmanager
def captured_stderr() -> Iterator[list[str]]:
    """Capture the C-level standard error: Pinocchio's URDF parser (urdfdom) prints its
    diagnosis there instead of raising it. Yields a list that holds the text afterwards."""
    captured: list[str] = []
    try:
        fd = os.dup(2)
    except OSError:  # no file descriptor 2 (embedded interpreters): nothing to capture
        yield captured
        return
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield captured
        finally:
            os.dup2(fd, 2)
            os.close(fd)
            tmp.seek(0)
            captured.append(tmp.read().decode("utf-8", "replace"))
