"""A frame name a URDF gives both a link and its fixed joint (z1's ``gripperStator``, where
Pinocchio's ``getFrameId`` raises a bare ValueError, 'Several frames match the filter') works
as a pose campaign's marker frame and as the target of a simulated pose campaign: positions
checked against Pinocchio's forward kinematics of the link frame."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from stiffness.calibration.pose_model import Marker, PoseModel
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.robot import load_robot


def test_a_marker_on_a_frame_named_like_its_joint_is_simulated_and_modelled():
    robot = load_robot("z1")
    names = [f for f in robot.model.frames if f.name == "gripperStator"]
    assert len(names) == 2  # the link and the fixed joint
    offset = np.array([0.01, 0.02, 0.03])
    markers = [Marker("tip", "gripperStator", offset)]
    n_joints = robot.n_coordinates
    hidden = HiddenPoseErrors(np.eye(3), np.zeros(3), offset[None], np.zeros(n_joints),
                              np.zeros((n_joints, 6)), stiffness=None)
    campaign = simulate_pose_campaign(robot, markers, hidden, 3, 1e-12, seed=2)
    link = next(i for i, f in enumerate(robot.model.frames)
                if f.name == "gripperStator" and f.type == pin.FrameType.BODY)
    for q, seen in zip(campaign.q, campaign.positions[:, 0], strict=True):
        pin.framesForwardKinematics(robot.model, robot.data, robot.configuration(q))
        np.testing.assert_allclose(seen, robot.data.oMf[link].act(offset), atol=1e-9)
    model = PoseModel(robot, markers, ("joint_offsets",), (np.eye(3), np.zeros(3)))
    assert model.frame_ids == [link]
