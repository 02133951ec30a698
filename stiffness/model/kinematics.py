"""Frame kinematics from Pinocchio: positions, Jacobians and kinematic Hessians.

Every quirk of the pin 4.x Python bindings is fixed here, once:

* ``getFrameKinematicHessian`` returns the column-major C++ tensor read in row-major order;
  :func:`reorder_hessian` (used by :func:`frame_hessian`, :func:`point_hessian` and the batched
  kernels) reorders it so that ``H[k, a, b] = dJ[k, a] / dq_b``.
* Only the ``LOCAL_WORLD_ALIGNED`` linear rows are the Hessian of the frame origin's position;
  this module only ever asks for that reference frame.

Spatial quantities follow Pinocchio's order: rows ``[linear (3); angular (3)]``, world axes,
at the frame origin. Units: m, rad.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


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
    return pin.getFrameJacobian(model, data, frame_id, LWA)


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
    return reorder_hessian(pin.getFrameKinematicHessian(model, data, frame_id, LWA))


def point_hessian(model: pin.Model, data: pin.Data, joint_id: int, placement: pin.SE3
                  ) -> np.ndarray:
    """Hessian (3, nv, nv) of the world position of a point fixed to a joint (m/rad^2).

    ``placement`` locates the point in the joint's frame. Hessians must be current
    (:func:`update_kinematics`).
    """
    raw = pin.getFrameKinematicHessian(model, data, joint_id, placement, LWA)
    return reorder_hessian(raw)[:3]
