"""The default target of robots the project does not ship: not on a gripper's moving jaw (z1,
so100, which have no ``<mimic>`` coupling to say so), not at the origin of the last joint
(double_pendulum's ``link2``, which that joint's spring would not move); a tool frame meant at
a joint's origin (xarm7's flange) is kept. Positions are checked by finite differences of the
target's placement, independent of the Jacobian under test."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from stiffness.robot.robot import load_robot


def _position(robot, coords: np.ndarray) -> np.ndarray:
    """The target's position in the base frame (m) at coordinates ``coords``."""
    q = robot.configuration(coords)
    pin.framesForwardKinematics(robot.model, robot.data, q)
    return robot.data.oMf[robot.target_frame_id].translation.copy()


def _moves(robot, joint: str, coords: np.ndarray, h: float = 1e-6) -> float:
    """How far the target moves per rad of ``joint`` (m/rad), central differences."""
    step = np.zeros(robot.n_coordinates)
    step[robot.coordinate_joints.index(joint)] = h
    return float(np.linalg.norm(_position(robot, coords + step)
                                - _position(robot, coords - step)) / (2 * h))


@pytest.mark.parametrize(("name", "jaw", "frame"), [("z1", "jointGripper", "gripperStator"),
                                                     ("so100", "gripper", "gripper")])
def test_default_target_is_not_on_a_grippers_moving_jaw(name, jaw, frame):
    """The jaw's joint neither moves the default target nor counts as a spring; it stays a
    coordinate (a joint of the end effector's branch); the arm's joints move the target (all
    but the wrist's roll, whose axis it may sit on, as z1's does)."""
    robot = load_robot(name, fixed_base=True)
    assert robot.target_frame == frame
    assert jaw not in robot.compliant_joints and jaw in robot.branch_joints
    coords = np.full(robot.n_coordinates, 0.3)
    assert _moves(robot, jaw, coords) < 1e-9
    assert min(_moves(robot, j, coords) for j in robot.compliant_joints[:-1]) > 1e-3


@pytest.mark.parametrize("name", ["double_pendulum", "double_pendulum_continuous"])
def test_default_target_of_a_bare_last_link_is_off_its_joint(name):
    """double_pendulum's last link carries no frame but its own, at joint2's origin: the target
    is its centre of mass (URDF inertial origin -0.0050107 1.9371E-10 0.10088), which joint2
    moves by its distance from the joint's x axis (0.10088 m/rad), not at the origin (0)."""
    robot = load_robot(name)
    assert robot.target_frame == "link2"
    np.testing.assert_allclose(robot.target_offset, [-0.0050107, 1.9371e-10, 0.10088],
                               atol=1e-15)
    coords = np.array([0.2, -0.4])
    assert _moves(robot, "joint2", coords) == pytest.approx(0.10088, rel=1e-6)
    assert load_robot(name, frame="link2").target_offset.tolist() == [0.0, 0.0, 0.0]


def test_a_tool_frame_at_a_joints_origin_is_kept_there():
    """xarm7's ``link_eef`` is the flange, at joint7's origin by design: no offset."""
    robot = load_robot("xarm7")
    assert robot.target_frame == "link_eef"
    assert robot.target_offset.tolist() == [0.0, 0.0, 0.0]


@pytest.mark.parametrize(("name", "frame"), [("g1_with_hands", "left_hand_palm_link"),
                                             ("alex_psyonic_hands", "Left_thumb_base")])
def test_default_target_of_a_hand_with_a_longer_thumb_is_on_the_palm(name, frame):
    """g1's thumb has three joints, its fingers two: the longest chain ended on the thumb's tip,
    whose joints were springs. Three or more short chains branching off the arm are a hand:
    the target is on the palm, which no finger moves, and the fingers are not springs."""
    robot = load_robot(name, fixed_base=True)
    assert robot.target_frame == frame
    fingers = [j for j in robot.coordinate_joints if "thumb" in j or "index" in j]
    assert fingers and not set(fingers) & set(robot.compliant_joints)
    coords = np.full(robot.n_coordinates, 0.2)
    assert max(_moves(robot, j, coords) for j in fingers) < 1e-9
