"""Synthetic pose campaigns: what a tracker would see of an arm with hidden geometric and
elastic errors, under its weight and an optional payload.

The simulated truth is computed independently of the fitted model
(:mod:`stiffness.calibration.absolute`): the joint placements are perturbed exactly
(``M_j exp(eps_j)``), the sag is the exact static equilibrium of joint springs under gravity and
the applied wrench, ``K (q_l - q_c - delta_0) = J(q_l)^T w - g(q_l)`` (fixed-point iteration to
1e-14 rad; springs on a ``[controller]``'s coordinates ``u``, ``q_chain = A u + b``, hold
``K_u Delta u = A^T (J^T w - g)`` with ``Delta q = A Delta u``), and the measuring frame is an
arbitrary rigid placement.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from stiffness.calibration.absolute import Loads, Marker, one_dof_joints
from stiffness.calibration.campaign_toml import RobotSettings
from stiffness.calibration.pose_campaign import PoseCampaign
from stiffness.calibration.poses import sample_coordinates
from stiffness.errors import ConvergenceError
from stiffness.robot.robot import Robot
from stiffness.units import Units

#: Fixed-point tolerance of the sag (rad or m) and its iteration cap.
_SAG_TOL = 1e-14
_SAG_ITERATIONS = 200


@dataclass
class HiddenPoseErrors:
    """The truth a simulated pose campaign hides (SI).

    Attributes
    ----------
    frame_rotation, frame_translation
        Placement of the measuring frame: ``y = R p + t`` for a point ``p`` in robot world.
    marker_offsets
        (M, 3) true marker offsets in their frames (m).
    joint_offsets
        (n_joints,) zero offsets of the robot's 1-dof joints (model order), rad or m.
    placement_errors
        (n_joints, 6) placement errors ``eps_j`` of the same joints.
    stiffness
        (n_compliant,) joint stiffness (N.m/rad or N/m) of the robot's compliant joints, or
        ``None`` for a rigid arm.
    """

    frame_rotation: np.ndarray
    frame_translation: np.ndarray
    marker_offsets: np.ndarray
    joint_offsets: np.ndarray
    placement_errors: np.ndarray
    stiffness: np.ndarray | None = None
    drift: np.ndarray = field(default_factory=lambda: np.zeros(3))


def true_model(robot: Robot, hidden: HiddenPoseErrors) -> pin.Model:
    """The robot's model with the hidden placement errors applied (``M_j exp(eps_j)``)."""
    model = pin.Model(robot.model)
    for j, eps in zip(one_dof_joints(model), hidden.placement_errors, strict=True):
        model.jointPlacements[j] = model.jointPlacements[j] * pin.exp6(pin.Motion(eps))
    return model


def sagged_configuration(model: pin.Model, robot: Robot, q_command: np.ndarray,
                         stiffness: np.ndarray | None, wrench: np.ndarray | None,
                         load_frame: str) -> np.ndarray:
    """Exact joint springs' equilibrium under gravity and ``wrench`` (fixed point); the springs
    act on the robot's compliant coordinates (joints, or a ``[controller]``'s coordinates)."""
    if stiffness is None:
        return q_command
    data = model.createData()
    springs = robot.rate_projection(robot.compliant_joints)  # (nv, n_compliant) rates per spring
    fid = model.getFrameId(load_frame)
    dv = np.zeros(model.nv)
    for _ in range(_SAG_ITERATIONS):
        q = pin.integrate(model, q_command, dv)
        torque = -pin.computeGeneralizedGravity(model, data, q)
        if wrench is not None:
            pin.computeJointJacobians(model, data, q)
            pin.updateFramePlacements(model, data)
            torque = torque + pin.getFrameJacobian(model, data, fid,
                                                   pin.LOCAL_WORLD_ALIGNED).T @ wrench
        new = springs @ ((springs.T @ torque) / stiffness)
        if np.max(np.abs(new - dv)) < _SAG_TOL:
            return pin.integrate(model, q_command, new)
        dv = new
    raise ConvergenceError("the simulated sag did not converge: the springs are too soft for "
                           "the arm's weight; raise the stiffness")


def simulate_pose_campaign(robot: Robot, markers: list[Marker], hidden: HiddenPoseErrors,
                           n_poses: int, noise_std: float, seed: int = 0,
                           payload: np.ndarray | None = None, units: Units | None = None,
                           name: str = "simulated-poses") -> PoseCampaign:
    """A pose campaign of ``n_poses`` reachable poses seen through ``hidden``.

    Parameters
    ----------
    markers
        The markers with their *nominal* offsets (what the campaign file declares).
    payload
        A constant wrench (6,) at the robot's target frame (world axes), or ``None``.
    noise_std
        Isotropic Gaussian noise of each position component (m).
    """
    rng = np.random.default_rng(seed)
    q = sample_coordinates(robot, n_poses, rng)
    model = true_model(robot, hidden)
    data = model.createData()
    positions = np.empty((n_poses, len(markers), 3))
    for i, coords in enumerate(q):
        q_full = _command(robot, model, hidden, coords)
        q_l = sagged_configuration(model, robot, q_full, hidden.stiffness, payload,
                                   robot.target_frame)
        pin.framesForwardKinematics(model, data, q_l)
        for k, m in enumerate(markers):
            point = data.oMf[model.getFrameId(m.frame)].act(hidden.marker_offsets[k])
            positions[i, k] = (hidden.frame_rotation @ point + hidden.frame_translation
                               + hidden.drift * i / max(n_poses - 1, 1))
    positions += rng.normal(0.0, noise_std, positions.shape)
    loads = None if payload is None else Loads(robot.target_frame,
                                               np.tile(payload, (n_poses, 1)))
    settings = RobotSettings(robot.name, robot.target_frame,
                             compliant_joints=tuple(robot.compliant_joints))
    return PoseCampaign(name, robot, settings, units or Units("rad", "N", "m"), markers,
                        [f"p{i + 1}" for i in range(n_poses)], q, positions, loads, noise_std)


def _command(robot: Robot, model: pin.Model, hidden: HiddenPoseErrors, coords: np.ndarray
             ) -> np.ndarray:
    """The configuration the links are at before sagging: commanded plus zero offsets."""
    offsets = np.zeros(model.nv)
    offsets[[model.joints[j].idx_v for j in one_dof_joints(model)]] = hidden.joint_offsets
    return pin.integrate(model, robot.configuration(coords), offsets)
