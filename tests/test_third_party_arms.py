"""Defects found by running the commands on third-party industrial arm URDFs (ROS-Industrial,
MATLAB's and the Robotics Toolbox's robot files), each reproduced on a small URDF written here.
Positions are checked by finite differences of the target's placement."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.robot.robot import load_robot

_LIMIT = '<limit lower="-3" upper="3" effort="100" velocity="1"/>'
_INERTIAL = ('<inertial><mass value="{m}"/><origin xyz="0 0 0.1"/>'
             '<inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>')


def arm_urdf(extra: str = "", mass: float = 2.0, links: str = "") -> str:
    """A 4-joint arm (z, y, y, x axes; 0.3 m links) ending in a fixed ``tool0`` (0.05 m off
    joint_4's axis), with ``extra`` joints and ``links`` added."""
    axes = ["0 0 1", "0 1 0", "0 1 0", "1 0 0"]
    parts = ['<robot name="arm">', '<link name="base_link"/>']
    parent = "base_link"
    for i, axis in enumerate(axes, start=1):
        parts += [f'<link name="link_{i}">{_INERTIAL.format(m=mass)}</link>',
                  f'<joint name="joint_{i}" type="revolute"><parent link="{parent}"/>'
                  f'<child link="link_{i}"/><origin xyz="0 0 {0.3 if i > 1 else 0.1}"/>'
                  f'<axis xyz="{axis}"/>{_LIMIT}</joint>']
        parent = f"link_{i}"
    parts += ['<link name="tool0"/>', '<joint name="flange" type="fixed"><parent link="link_4"/>'
              '<child link="tool0"/><origin xyz="0.1 0.05 0"/></joint>', links, extra, "</robot>"]
    return "\n".join(parts)


def rail_urdf(tmp_path: Path, lower: str, upper: str) -> Path:
    """:func:`arm_urdf` on a prismatic rail along x (``rail_joint``, limits ``lower`` ..
    ``upper`` m as written in the file), written to ``tmp_path``; its path."""
    rail = ('<link name="rail"/><joint name="rail_joint" type="prismatic"><parent link="rail"/>'
            f'<child link="base_link"/><axis xyz="1 0 0"/><limit lower="{lower}" '
            f'upper="{upper}" effort="100" velocity="1"/></joint>')
    path = tmp_path / "rail.urdf"
    path.write_text(arm_urdf().replace('<link name="base_link"/>',
                                       '<link name="base_link"/>' + rail))
    return path


def _position(robot, coords: np.ndarray) -> np.ndarray:
    q = robot.configuration(coords)
    pin.framesForwardKinematics(robot.model, robot.data, q)
    return robot.data.oMf[robot.target_frame_id].act(robot.target_offset)


def _moves(robot, joint: str, coords: np.ndarray, h: float = 1e-6) -> float:
    """How far the target moves per rad of ``joint`` (m/rad), central differences."""
    step = np.zeros(robot.n_coordinates)
    step[robot.coordinate_joints.index(joint)] = h
    return float(np.linalg.norm(_position(robot, coords + step)
                                - _position(robot, coords - step)) / (2 * h))


_BALANCER = """
<link name="cylinder"/><link name="piston"/>
<joint name="joint_cylinder" type="continuous"><parent link="link_1"/><child link="cylinder"/>
  <origin xyz="-0.2 0 0.1"/><axis xyz="0 1 0"/><mimic joint="joint_2" multiplier="-0.25"/></joint>
<joint name="joint_piston" type="continuous"><parent link="link_2"/><child link="piston"/>
  <origin xyz="-0.2 0 0.05"/><axis xyz="0 1 0"/><mimic joint="joint_2" multiplier="-1.25"/></joint>
"""


def test_a_balancer_mimicking_the_shoulder_is_not_a_gripper(tmp_path: Path):
    """ABB irb6640/6600/6700 (ROS-Industrial) model the shoulder's balancer as two continuous
    joints mimicking joint_2, one beside it on link_1: the side-by-side coupling was read as a
    gripper's jaws, every frame below joint_2 as the gripper, and the default target became
    link_1 with joint_1 the only spring. The target is the tool, all four joints springs."""
    path = tmp_path / "balancer.urdf"
    path.write_text(arm_urdf(_BALANCER))
    robot = load_robot(path)
    assert robot.target_frame == "tool0"
    assert robot.compliant_joints == ("joint_1", "joint_2", "joint_3", "joint_4")
    coords = np.array([0.3, 0.4, -0.5, 0.2])
    assert min(_moves(robot, j, coords) for j in robot.compliant_joints) > 0.04


def test_a_grippers_jaws_on_the_arm_are_still_not_the_target(tmp_path: Path):
    """Two jaws on the last link, one mimicking the other side by side (a panda's fingers):
    the target stays on the arm's last link, the jaws are no springs and do not move it."""
    jaws = """
<link name="finger_l"/><link name="finger_r"/>
<joint name="finger_1" type="prismatic"><parent link="link_4"/><child link="finger_l"/>
  <origin xyz="0.05 0.01 0"/><axis xyz="0 1 0"/><limit lower="0" upper="0.04" effort="1"
  velocity="1"/></joint>
<joint name="finger_2" type="prismatic"><parent link="link_4"/><child link="finger_r"/>
  <origin xyz="0.05 -0.01 0"/><axis xyz="0 -1 0"/><limit lower="0" upper="0.04" effort="1"
  velocity="1"/><mimic joint="finger_1"/></joint>
"""
    path = tmp_path / "jaws.urdf"
    path.write_text(arm_urdf(_BALANCER + jaws))
    robot = load_robot(path)
    assert robot.target_frame == "tool0"
    assert robot.compliant_joints == ("joint_1", "joint_2", "joint_3", "joint_4")
    coords = np.array([0.3, 0.4, -0.5, 0.2, 0.01])
    assert _moves(robot, "finger_1", coords) < 1e-9


def test_a_camera_beside_the_tool_is_not_the_target(tmp_path: Path):
    """Kinova Gen3 (kortex) carries a camera module beside its tool frame, farther from the
    wrist: the default target was ``camera_depth_frame`` (and Baxter's ``left_hand_range``).
    The tool is the target."""
    sensors = """
<link name="camera_link"/><link name="camera_depth_frame"/>
<joint name="camera_module" type="fixed"><parent link="link_4"/><child link="camera_link"/>
  <origin xyz="0.1 0.1 0.05"/></joint>
<joint name="depth_module" type="fixed"><parent link="link_4"/><child link="camera_depth_frame"/>
  <origin xyz="0.1 0.12 0.06"/></joint>
"""
    path = tmp_path / "camera.urdf"
    path.write_text(arm_urdf(sensors))
    assert load_robot(path).target_frame == "tool0"


def test_a_path_of_another_arms_joints_is_not_called_a_model_file(tmp_path: Path):
    """A joint path written for ABB's joint_1..6 given to KUKA's kr16 (joint_a1..a6) with
    --robot: the message asked 'is the model file of another robot?', though no model file was
    given. It names the path and its fix."""
    import pytest

    from stiffness.errors import FileFormatError
    from stiffness.machining.joint_path import read_joint_path

    path = tmp_path / "arm.urdf"
    path.write_text(arm_urdf())
    robot = load_robot(path)
    csv = tmp_path / "path.csv"
    csv.write_text("joint_a1,joint_a2,joint_a3,joint_a4\n0,0.2,0.1,0\n")
    with pytest.raises(FileFormatError) as info:
        read_joint_path(csv, robot)
    message = str(info.value)
    assert "model file" not in message
    assert "a path of another robot?" in message and "joint_1, joint_2, joint_3, joint_4" \
        in message


def test_a_floating_or_planar_joint_inside_the_arm_is_not_sent_to_fixed_base(tmp_path: Path):
    """A floating or planar joint between two links of the arm: the message suggested
    --fixed-base, which fixes only the base and left the same error. It says so and names the
    fixes that apply; a floating joint at the base is still sent to --fixed-base, which loads
    it."""
    import pytest

    from stiffness.errors import StiffnessError

    text = arm_urdf()
    start = text.index('<joint name="joint_3"')
    end = text.index("</joint>", start)
    for kind in ("floating", "planar"):
        path = tmp_path / f"{kind}.urdf"
        path.write_text(text[:start] + text[start:end].replace('type="revolute"',
                                                               f'type="{kind}"') + text[end:])
        for fixed_base in (False, True):
            with pytest.raises(StiffnessError) as info:
                load_robot(path, fixed_base=fixed_base)
            message = str(info.value)
            assert "joint 'joint_3'" in message and "not the base" in message
            assert 'type="fixed"' in message and "--fixed-base fixes" in message
    base = tmp_path / "base.urdf"
    base.write_text(text.replace('<link name="base_link"/>', '<link name="world"/>'
                                 '<link name="base_link"/><joint name="free" type="floating">'
                                 '<parent link="world"/><child link="base_link"/></joint>'))
    with pytest.raises(StiffnessError, match="base.*with --fixed-base"):
        load_robot(base)
    assert load_robot(base, fixed_base=True).compliant_joints == (
        "joint_1", "joint_2", "joint_3", "joint_4")


def test_posture_without_a_wrench_names_the_flag(tmp_path: Path, capsys):
    """`stiffness posture` without --wrench said 'give a process wrench (fx,fy,fz[,mx,my,mz]
    in N, N.m)', naming neither the flag nor the path file's columns that give one."""
    from stiffness.cli.main import main

    path = tmp_path / "arm.urdf"
    path.write_text(arm_urdf())
    poses = tmp_path / "poses.csv"
    poses.write_text("x,y,z,ax,ay,az\n0.2,0.05,0.8,1,0,0\n0.21,0.05,0.8,1,0,0\n")
    assert main(["posture", "--robot", str(path), "--kq", "1e4,1e4,1e4,1e4", "--path",
                 str(poses), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "--wrench fx,fy,fz" in err and "fx,fy,fz columns in the poses file" in err


def test_a_fixed_joint_or_a_link_named_as_compliant_says_what_it_is(tmp_path: Path):
    """--compliant-joints naming ROS-Industrial's fixed ``joint6-tool0`` or a link said only
    'is not a coordinate joint'; it says which: a fixed joint, or a link and the joint that
    moves it."""
    import pytest

    from stiffness.errors import UnknownJointError

    path = tmp_path / "arm.urdf"
    path.write_text(arm_urdf())
    with pytest.raises(UnknownJointError, match=r"'flange' is not a coordinate joint of arm "
                       r"\(it is a fixed joint: nothing turns it\)"):
        load_robot(path, compliant_joints=["joint_2", "flange"])
    with pytest.raises(UnknownJointError, match=r"'link_3' is not a coordinate joint of arm "
                       r"\(it is a link, moved by joint 'joint_3'\)"):
        load_robot(path, compliant_joints="link_3")


def test_a_rail_with_placeholder_limits_is_sampled_near_its_reference(tmp_path: Path):
    """The Robotics Toolbox's Fetch puts its base on a prismatic joint limited to
    -999999..999999 m: poses were drawn up to a million metres out and `simulate`, `design`
    found 'only 0 of 8 reachable poses'. Such a range counts as none: the rail is drawn within
    0.1 m, as an unbounded prismatic joint is, and the campaign is written."""
    from stiffness.cli.main import main

    path = rail_urdf(tmp_path, "-999999", "999999")
    out = tmp_path / "campaign"
    assert main(["simulate", "--robot", str(path), "--kq", "1e5,1e4,1e4,1e4,1e4",
                 "--configs", "4", "--out", str(out), "--quiet"]) == 0
    lines = (out / "measurements.csv").read_text().splitlines()
    header = lines[0].split(",")
    rail_mm = [float(line.split(",")[header.index("q1")]) for line in lines[1:]]
    assert load_robot(path).coordinate_joints[0] == "rail_joint"
    assert min(rail_mm) >= 0.0 and max(rail_mm) <= 100.0  # mm, the campaign's unit


def test_backlash_on_a_prismatic_joint_is_said_in_the_length_unit(tmp_path: Path):
    """Kinova MOVO's linear_joint (a prismatic lift) with --effect backlash: its half-width is
    read in the campaign's length unit (mm), but truth.json's value_units said 'deg' for
    backlash (and 1/(N.m) for nonlinear_joint_stiffness), as `simulate --kind poses` did not.
    The lost motion is the mm given: the rail's deflection along its axis under a pull
    (loads along it) jumps by twice the half-width between opposite loads."""
    import json

    from stiffness.cli.main import main

    path = rail_urdf(tmp_path, "-0.5", "0.5")
    out = tmp_path / "campaign"
    assert main(["simulate", "--robot", str(path), "--kq", "1e8,1e8,1e8,1e8,1e8",
                 "--effect", "backlash:rail_joint=0.5", "--load-pattern", "axes",
                 "--configs", "2", "--noise", "0", "--out", str(out), "--quiet"]) == 0
    truth = json.loads((out / "truth.json").read_text())
    assert truth["value_units"]["backlash"] == "deg (mm prismatic)"
    assert truth["value_units"]["nonlinear_joint_stiffness"] == "1/(N.m) (1/N prismatic)"
    lines = (out / "measurements.csv").read_text().splitlines()
    header = lines[0].split(",")
    rows = [dict(zip(header, line.split(","), strict=True)) for line in lines[1:]]
    dx = {float(r["fx"]): float(r["dx"]) for r in rows[:6] if abs(float(r["fx"])) > 0}
    assert sorted(dx) == [-100.0, 100.0]
    # springs of 1e8 N/m and N.m/rad: the rest of the deflection is under 0.02 mm
    assert abs(dx[100.0] - dx[-100.0] - 2 * 0.5) < 0.02


def test_a_base_joints_offset_is_said_to_be_the_measuring_frames(tmp_path: Path, capsys):
    """`simulate --kind poses` with a zero offset hidden on PR2's l_shoulder_pan_joint (a
    vertical axis above a vertical lift: a rotation of every marker about it) said it 'moves
    the markers by 1.22 mm RMS, 244 noise std', and `diagnose` then found nothing: every pose
    fit takes out a rigid move of the measuring frame. The size beyond that move is reported
    (0 for the base joint, a rotation about a fixed axis being rigid; most of it for a joint
    whose offset bends the arm) and the text says only that part can show."""
    import json

    from stiffness.cli.main import main

    path = tmp_path / "arm.urdf"
    path.write_text(arm_urdf())
    out = tmp_path / "poses"
    assert main(["simulate", "--kind", "poses", "--robot", str(path), "--poses", "12",
                 "--effect", "joint_offsets:joint_1=0.2", "--effect",
                 "joint_offsets:joint_3=0.2", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    truth = json.loads((out / "truth.json").read_text())
    size, beyond = truth["effect_rms"], truth["effect_rms_beyond_frame"]
    assert size["joint_offsets(joint_1)"] > 0.1  # mm
    assert beyond["joint_offsets(joint_1)"] < 1e-9
    assert beyond["joint_offsets(joint_3)"] > 0.5 * size["joint_offsets(joint_3)"]
    base = next(line for line in printed.splitlines() if "(joint_1)" in line)
    elbow = next(line for line in printed.splitlines() if "(joint_3)" in line)
    assert "beyond a rigid move of the measuring frame" in base and "only that part" in base
    assert "beyond" not in elbow


def test_fixed_fingers_either_side_give_the_frame_they_branch_from(tmp_path: Path):
    """The Robotics Toolbox's Fetch has its fingers as fixed joints, 15 mm either side of
    ``gripper_link``: the farthest frame from the wrist was ``r_gripper_finger_link``, on one
    finger. Tied frames at different places give the frame they branch from; a single
    farthest frame is still taken (the tool0 of the other tests)."""
    fingers = """
<link name="gripper_link"/><link name="l_finger"/><link name="r_finger"/>
<joint name="gripper_mount" type="fixed"><parent link="link_4"/><child link="gripper_link"/>
  <origin xyz="0.15 0 0.05"/></joint>
<joint name="l_finger_joint" type="fixed"><parent link="gripper_link"/><child link="l_finger"/>
  <origin xyz="0 0.015 0"/></joint>
<joint name="r_finger_joint" type="fixed"><parent link="gripper_link"/><child link="r_finger"/>
  <origin xyz="0 -0.015 0"/></joint>
"""
    path = tmp_path / "fingers.urdf"
    path.write_text(arm_urdf(fingers))
    robot = load_robot(path)
    assert robot.target_frame == "gripper_link"
    coords = np.array([0.3, 0.4, -0.5, 0.2])
    assert min(_moves(robot, j, coords) for j in robot.compliant_joints) > 0.04
