"""A robot.toml is checked like a campaign.toml (issue 38 item 5), and robots with a base, a
head and wheels load quietly with springs on the joints that move the target (item 8)."""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from stiffness.errors import FileFormatError
from stiffness.mechanics.defaults import reference_configuration
from stiffness.robot.robot import load_robot
from stiffness.robot.sources import robots_directory

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "sk120-dh" / "robot.toml"


def edited(tmp_path: Path, old: str, new: str) -> Path:
    path = tmp_path / "robot.toml"
    text = EXAMPLE.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize(("old", "new", "words"), [
    ('frame = "tool"', 'fram = "tool"', "(fram): unknown key 'fram'; valid names: "),
    ('compliant_joints = ', 'complaint_joints = ', "Did you mean compliant_joints?"),
    ("k_theta_SI = [1.4098e6, 4.0076e5, 9.3528e5]", "k_theta_SI = [1.4098e6, 4.0076e5]",
     "(k_theta_SI): k_theta_SI has 2 values for 3 compliant joints (joint1, joint2, joint3); "
     "give one per compliant joint"),
    ("q_deg = [-33.2004, 15.9, -55.5957, 0.0, -34.4045, -90.0]", "q_deg = [1.0, 2.0]",
     "(q_deg): q_deg has 2 values for 6 coordinates (joint1, joint2, joint3, joint4"),
    ('compliant_joints = ["joint1", "joint2", "joint3"]', 'compliant_joints = ["joint1"]',
     "k_theta_SI has 3 values for 1 compliant joints (joint1)"),
    # a negative spring was refused only when kx used it, naming neither file nor key
    ("k_theta_SI = [1.4098e6, 4.0076e5, 9.3528e5]", "k_theta_SI = [1.4098e6, -4.0076e5, 9.3528e5]",
     "(k_theta_SI): k_theta_SI must be positive stiffnesses, one per compliant joint, N.m/rad"),
    ("k_theta_SI = [1.4098e6, 4.0076e5, 9.3528e5]", "k_theta_SI = [1.4098e6, 0, 9.3528e5]",
     "(k_theta_SI): k_theta_SI must be positive stiffnesses"),
    ("uniform = { joint1", "unifrom = { joint1",  # at load, not when poses are drawn
     "([workspace].unifrom): unknown key 'unifrom'; valid names: "),
])
def test_robot_toml_errors_name_file_and_field(tmp_path, old, new, words):
    with pytest.raises(FileFormatError) as info:
        load_robot(edited(tmp_path, old, new))
    message = str(info.value)
    assert message.startswith(str(tmp_path / "robot.toml")) and words in message, message


def test_tiago_loads_quietly_with_springs_on_the_arm_chain():
    """No 'invalid value encountered' (infinite limits' midpoint): the reference configuration
    has finite values; the default springs are the 8 joints from the base to the hand (not the
    head, wheels or 36 finger joints), each with a nonzero Jacobian column at a random pose,
    and the head's and wheels' columns are zero."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        robot = load_robot("tiago")
        reference = reference_configuration(robot)
    assert reference is not None and np.all(np.isfinite(reference.coords))
    assert robot.compliant_joints == ("torso_lift_joint", *(f"arm_{i}_joint" for i in
                                                            range(1, 8)))
    from stiffness.mechanics.formulation import target_state

    every = load_robot("tiago", compliant_joints=robot.coordinate_joints)
    coords = np.random.default_rng(3).uniform(-0.5, 0.5, every.n_coordinates)
    coords[0] = 0.1  # the torso lift inside its limits
    jac = target_state(every, every.configuration(coords), np.zeros(3)).jacobian
    norms = dict(zip(every.compliant_joints, np.linalg.norm(jac, axis=0), strict=True))
    assert all(norms[j] > 1e-3 for j in robot.compliant_joints), norms
    assert all(norms[j] < 1e-12 for j in every.coordinate_joints
               if j not in robot.compliant_joints), norms


def test_a_urdf_robot_toml_is_checked_too(tmp_path):
    """The shipped SK120's folder (a URDF, a loop file and a robot.toml), one key misspelt."""
    shutil.copytree(robots_directory() / "sk120", tmp_path / "r")
    toml = tmp_path / "r" / "robot.toml"
    text = toml.read_text()
    assert "\nframe = " in text
    toml.write_text(text.replace("\nframe = ", "\nframes = ", 1))
    with pytest.raises(FileFormatError, match="unknown key 'frames'.*Did you mean frame"):
        load_robot(toml)


def test_a_target_offset_beyond_the_reach_is_warned_about(tmp_path):
    """``--target-offset 0,0,100`` (meant in mm; the flag is in m) put the UR5's target 100 m
    from its flange silently: kx printed the stiffness there and simulate failed with 'found
    only 0 reachable poses ... check the joint limits'. Now one warning names the reach and the
    unit, from a flag (FlagValueWarning) or a robot.toml (RobotFileWarning); a real tool is
    quiet."""
    from stiffness.errors import FlagValueWarning, RobotFileWarning

    with pytest.warns(FlagValueWarning, match=r"ur5: the target offset 0,0,100 m puts the "
                                              r"target 100 m from frame tool0, beyond the "
                                              r"robot's reach \(1.33 m\); give it in m \(in mm "
                                              r"these values are 0.1 m\)"):
        load_robot("ur5", frame="tool0", target_offset=[0.0, 0.0, 100.0])
    path = edited(tmp_path, "target_offset_m = [0.0, 0.0, 0.0]",
                  "target_offset_m = [0.0, 0.0, 205.32]")
    with pytest.warns(RobotFileWarning, match=r"205 m from frame tool, beyond the robot's reach"):
        load_robot(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_robot("ur5", frame="tool0", target_offset=[0.0, 0.0, 0.3])


def test_an_empty_robot_name_and_a_string_of_joints(tmp_path, monkeypatch):
    """An empty robot name (an unset ``--robot $ROBOT``) loaded the one URDF of the working
    folder silently (``Path('')`` is '.'); ``compliant_joints="elbow_joint"`` was read as
    its letters ('compliant joint 'e' is not a coordinate joint'). Now the first is a one-line
    refusal and the second reads comma-separated names, as the flag does."""
    from stiffness.errors import UnknownRobotError

    shutil.copy(robots_directory() / "sk120" / "sk120.urdf", tmp_path / "arm.urdf")
    monkeypatch.chdir(tmp_path)
    for name in ("", "  "):
        with pytest.raises(UnknownRobotError, match="the robot is an empty name"):
            load_robot(name)
    assert load_robot("ur5", compliant_joints="elbow_joint").compliant_joints == ("elbow_joint",)
    assert load_robot("ur5", compliant_joints="elbow_joint, wrist_1_joint").compliant_joints \
        == ("elbow_joint", "wrist_1_joint")


GRIPPER = """<?xml version="1.0"?>
<robot name="grip">
  <link name="palm"/><link name="left_finger"/><link name="right_finger"/>
  <joint name="finger_joint" type="revolute"><parent link="palm"/><child link="left_finger"/>
    <origin xyz="0 0.02 0.05"/><axis xyz="1 0 0"/>
    <limit lower="0" upper="0.8" effort="1" velocity="1"/></joint>
  <joint name="right_finger_joint" type="revolute"><parent link="palm"/>
    <child link="right_finger"/><origin xyz="0 -0.02 0.05"/><axis xyz="1 0 0"/>
    <limit lower="-0.8" upper="0" effort="1" velocity="1"/>
    <mimic joint="finger_joint" multiplier="-1"/></joint>
</robot>
"""


def test_a_target_moved_by_a_mimic_follower_has_its_leader_as_spring(tmp_path):
    """A target on a ``<mimic>`` follower's link (robotiq 2F-85's default target, its
    ``left_inner_finger``) had no default compliant joint: the follower is no coordinate and
    its leader is not on the target's chain, so kx said '--kq has 1 value for the 0 compliant
    joints of robotiq_arg85_description ()'. The leader that moves it is the spring now."""
    path = tmp_path / "grip.urdf"
    path.write_text(GRIPPER)
    robot = load_robot(path, frame="right_finger", target_offset=[0.0, 0.0, 0.05])
    assert robot.compliant_joints == ("finger_joint",)
    step = 1e-6
    moved = (frame_point(robot, robot.configuration([0.3 + step]))
             - frame_point(robot, robot.configuration([0.3 - step]))) / (2 * step)
    np.testing.assert_allclose(robot_jacobian(robot, robot.configuration([0.3]))[:3, 0], moved,
                               atol=1e-8)
    assert np.linalg.norm(moved) > 0.04  # the follower's 5 cm lever, turned by the leader


def robot_jacobian(robot, q):
    from stiffness.mechanics.formulation import target_state

    return target_state(robot, q).jacobian


def frame_point(robot, q):
    import pinocchio as pin

    pin.framesForwardKinematics(robot.model, robot.data, q)
    return robot.data.oMf[robot.target_frame_id].translation.copy()
