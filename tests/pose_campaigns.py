"""Simulated pose campaigns shared by several test files."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from stiffness.calibration.pose_campaign import PoseCampaign
from stiffness.calibration.pose_model import Marker
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.robot import load_robot


def ur10_tip_campaign(poses: int, payload_n: float | None = None) -> PoseCampaign:
    """``poses`` UR10 poses of one marker on tool0 (20 um noise, seed 2) with a hidden frame,
    marker offset, zero offsets, link geometry errors and joint springs, under a downward
    payload of ``payload_n`` (N; ``None``: no payload)."""
    robot = load_robot("ur10", frame="tool0")
    markers = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05]))]
    rng = np.random.default_rng(2)
    hidden = HiddenPoseErrors(pin.exp3(rng.normal(size=3)), rng.uniform(-2, 2, 3),
                              np.array([m.offset for m in markers]) + 2e-3,
                              rng.normal(0.0, 1e-3, 6), rng.normal(0.0, 2e-4, (6, 6)),
                              stiffness=np.array([3e5, 2e5, 1.2e5, 4e4, 3e4, 3e4]))
    payload = None if payload_n is None else np.array([0.0, 0.0, -payload_n, 0, 0, 0])
    return simulate_pose_campaign(robot, markers, hidden, poses, 20e-6, seed=2, payload=payload)
