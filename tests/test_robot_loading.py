"""Loading robots (stiffness.robot.robot): sources, coordinates, configurations and every error
path.

Error messages must name the problem and the fix; the tests match on both.
"""

from __future__ import annotations

import pickle
import shutil

import numpy as np
import pinocchio as pin
import pytest

from stiffness.errors import FloatingBaseError, StiffnessError
from stiffness.mechanics.formulation import target_state
from stiffness.robot.robot import TARGET_FRAME, load_robot
from stiffness.robot.sources import (
    example_robot_names,
    resolve_source,
    robots_directory,
    shipped_robots,
)

SERIAL_URDF = """<?xml version="1.0"?>
<robot name="serial">
  <link name="base"/><link name="l1"/><link name="l2"/><link name="tip"/>
  <joint name="turn" type="continuous"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.1" rpy="0 0 0"/><axis xyz="0 0 1"/></joint>
  <joint name="slide" type="prismatic"><parent link="l1"/><child link="l2"/>
    <origin xyz="0.3 0 0" rpy="0.2 0 0"/><axis xyz="1 0 0"/>
    <limit effort="10" velocity="1" lower="-1" upper="1"/></joint>
  <joint name="tip_joint" type="fixed"><parent link="l2"/><child link="tip"/>
    <origin xyz="0.05 0.1 0" rpy="0 0 0"/></joint>
</robot>
"""


@pytest.fixture(scope="module")
def serial_urdf(tmp_path_factory):
    path = tmp_path_factory.mktemp("serial") / "serial.urdf"
    path.write_text(SERIAL_URDF)
    return path


# ------------------------------------------------------------------------------------ sources


def test_shipped_and_example_robot_names():
    assert "sk120" in shipped_robots()
    names = example_robot_names()
    assert {"ur5", "panda"} <= set(names)


def test_sk120_shipped_settings(sk120):
    assert sk120.coordinate_joints == tuple(f"joint{i}" for i in range(1, 7))
    assert sk120.compliant_joints == ("joint1", "joint2", "joint3")
    assert sk120.target_frame == "fixture_target"
    assert set(sk120.loop.passive_joints) == {"elbow", "coupler_joint"}
    assert sk120.model.existFrame(TARGET_FRAME)
    # config A of Table II closes the loop and keeps its coordinates
    coords = np.deg2rad(sk120.defaults["q_deg"])
    q = sk120.configuration(coords)
    np.testing.assert_allclose(sk120.coordinates_of(q), coords, atol=1e-14)
    pin.forwardKinematics(sk120.model, sk120.data, q)
    pin.updateFramePlacements(sk120.model, sk120.data)
    a, b = (sk120.model.getFrameId(n) for n in ("coupler_end", "forearm_rear"))
    gap = sk120.data.oMf[a].translation - sk120.data.oMf[b].translation
    assert np.linalg.norm(gap) < 1e-10


def test_sk120_continuation_and_seed_agree(sk120, sk120_coords):
    """Closing from the reference assembly by continuation and from a nearby closed seed lands
    on the same assembly."""
    rng = np.random.default_rng(31)
    for _ in range(4):
        coords = sk120_coords(rng.uniform(0, 1, 6))
        q = sk120.configuration(coords)
        nearby = sk120.configuration(coords + 0.05)
        q_seeded = sk120.configuration(coords, seed=nearby)
        np.testing.assert_allclose(pin.difference(sk120.model, q, q_seeded), 0.0, atol=1e-9)


def test_example_robot_defaults(ur5):
    assert ur5.target_frame == "tool0"  # the model's last frame
    assert ur5.compliant_joints == ur5.coordinate_joints
    assert ur5.n_compliant == 6 and ur5.loop.is_open_chain
    np.testing.assert_array_equal(ur5.target_offset, np.zeros(3))


def test_urdf_path_with_continuous_and_prismatic_joints(serial_urdf, fd):
    """A URDF path (str or Path); a continuous joint (cos/sin in q) and a prismatic one (m)."""
    robot = load_robot(str(serial_urdf))
    assert robot.coordinate_joints == ("turn", "slide")
    assert robot.target_frame == "tip"
    coords = np.array([2.5, 0.07])
    q = robot.configuration(coords)
    assert q.shape == (3,)  # continuous: (cos, sin)
    np.testing.assert_allclose(q[:2], [np.cos(2.5), np.sin(2.5)], atol=1e-15)
    np.testing.assert_allclose(robot.coordinates_of(q), coords, atol=1e-15)
    # tip position by hand: Rz(turn) [ (0.3 + slide) x + Rx(0.2) (0.05, 0.1, 0) ] + (0, 0, 0.1)
    rz = pin.rpy.rpyToMatrix(0, 0, 2.5)
    rx = pin.rpy.rpyToMatrix(0.2, 0, 0)
    expected = rz @ (np.array([0.3 + 0.07, 0, 0]) + rx @ np.array([0.05, 0.1, 0])) + [0, 0, 0.1]
    state = target_state(robot, q)
    np.testing.assert_allclose(state.position, expected, atol=1e-14)
    numeric = fd.coordinates(robot, coords, lambda s: s.position)
    assert fd.rel_err(state.jacobian[:3], numeric) <= 1e-8
    # the prismatic column is the slide axis in world axes (m per m)
    np.testing.assert_allclose(state.jacobian[:3, 1], rz[:, 0], atol=1e-14)
    same = load_robot(serial_urdf)
    np.testing.assert_allclose(target_state(same, same.configuration(coords)).position,
                               expected, atol=1e-14)


def test_compliant_subset_and_target_offset(serial_urdf):
    robot = load_robot(serial_urdf, frame="l1", target_offset=[0.0, 0.2, 0.0],
                       compliant_joints=["slide"])
    assert robot.compliant_joints == ("slide",)
    np.testing.assert_array_equal(robot.compliant_in_coordinates, [1])
    state = target_state(robot, robot.configuration(np.array([0.0, 0.1])))
    np.testing.assert_allclose(state.position, [0.0, 0.2, 0.1], atol=1e-15)
    assert state.jacobian.shape == (6, 1)
    np.testing.assert_allclose(state.jacobian[:, 0], 0.0, atol=1e-15)  # l1 does not slide


# -------------------------------------------------------------------------------- error paths


def test_unknown_robot_name_suggests_the_closest_names():
    """The shipped robots and a few close names, not all 75 (issue 30)."""
    with pytest.raises(StiffnessError) as info:
        load_robot("ur55")
    message = str(info.value)
    assert "unknown robot 'ur55'" in message
    assert "not an existing URDF file" in message
    from stiffness.robot.sources import shipped_robots

    assert f"not a shipped robot ({', '.join(shipped_robots())})" in message
    suggested = message.split("did you mean ")[1].split("?")[0].split(", ")
    assert suggested[0] == "ur5" and len(suggested) <= 4
    assert "panda" not in message and "talos" not in message


def test_missing_urdf_file(tmp_path):
    with pytest.raises(StiffnessError,
                       match="URDF file .*nope.urdf does not exist; give an existing"):
        load_robot(tmp_path / "nope.urdf")


BAD_XML = '<?xml version="1.0"?>\n<robot name="x"><link name="a"></robot>\n'
MISSING_PARENT = """<?xml version="1.0"?>
<robot name="x"><link name="a"/><link name="b"/>
  <joint name="j" type="revolute"><parent link="zzz"/><child link="b"/><axis xyz="0 0 1"/>
    <limit effort="1" velocity="1" lower="-1" upper="1"/></joint>
</robot>
"""


@pytest.mark.parametrize("text", [BAD_XML, MISSING_PARENT], ids=["invalid-xml", "missing-parent"])
def test_malformed_urdf_is_refused(tmp_path, text):
    path = tmp_path / "broken.urdf"
    path.write_text(text)
    with pytest.raises(StiffnessError, match=r"broken\.urdf.*(not a valid URDF|valid URDF model)"):
        load_robot(path)


@pytest.mark.parametrize(("text", "detail"), [(BAD_XML, r"line 2|mismatch"),
                                              (MISSING_PARENT, "zzz")],
                         ids=["invalid-xml", "missing-parent"])
def test_malformed_urdf_message_names_the_problem(tmp_path, text, detail):
    path = tmp_path / "broken.urdf"
    path.write_text(text)
    with pytest.raises(StiffnessError, match=detail):
        load_robot(path)


def test_unsupported_joint_type(tmp_path):
    path = tmp_path / "floating.urdf"
    path.write_text('<?xml version="1.0"?><robot name="f"><link name="a"/><link name="b"/>'
                    '<joint name="free" type="floating"><parent link="a"/><child link="b"/>'
                    "</joint></robot>")
    with pytest.raises(FloatingBaseError,
                       match="floating or planar base, joint 'free' .JointModelFreeFlyer.: fix "
                             "the base .*--fixed-base"):
        load_robot(path)



def test_unknown_frame():
    with pytest.raises(StiffnessError, match=r"frame 'tool9' is not in ur5; valid names: "
                       r".*tool0.*Did you mean tool0"):
        load_robot("ur5", frame="tool9")


def test_unknown_compliant_joint():
    with pytest.raises(StiffnessError, match=r"compliant joint 'elbow' is not a coordinate joint "
                       r"of ur5; valid names: shoulder_pan_joint.*Did you mean elbow_joint"):
        load_robot("ur5", compliant_joints=["shoulder_pan_joint", "elbow"])


def test_passive_loop_joint_as_compliant():
    with pytest.raises(StiffnessError, match=r"compliant joint 'elbow' is not a coordinate joint "
                       r"of sk120 \(it is a passive loop joint\); valid names: joint1"):
        load_robot("sk120", compliant_joints=["joint1", "elbow"])


def test_repeated_compliant_joint(serial_urdf):
    with pytest.raises(StiffnessError, match=r"compliant joints repeat a name: \['slide', "
                       r"'slide'\] \('slide' twice\); name each joint once"):
        load_robot(serial_urdf, compliant_joints=["slide", "slide"])


@pytest.mark.parametrize("offset", [[0.0, 1.0], [0.0, 1.0, np.nan], [[0.0, 0.1, 0.2, 0.3]]])
def test_bad_target_offset(offset, serial_urdf):
    with pytest.raises(StiffnessError, match="target offset must be three finite lengths in m"):
        load_robot(serial_urdf, target_offset=offset)


@pytest.mark.parametrize("name", ["ur5", "sk120"])
def test_wrong_number_of_coordinates(name, ur5, sk120):
    robot = {"ur5": ur5, "sk120": sk120}[name]
    with pytest.raises(StiffnessError, match=rf"{name} has 6 coordinates \(.*joint.*\) but 5 "
                       "values were given"):
        robot.configuration(np.zeros(5))
    with pytest.raises(StiffnessError, match="but 7 values"):
        robot.configuration(np.zeros(7))


@pytest.mark.parametrize("bad", [np.nan, np.inf])
@pytest.mark.parametrize("name", ["ur5", "sk120"])
def test_non_finite_coordinate(name, bad, ur5, sk120):
    robot = {"ur5": ur5, "sk120": sk120}[name]
    with pytest.raises(StiffnessError, match="joint coordinates must be finite numbers"):
        robot.configuration(np.array([0.1, 0.2, bad, 0.0, 0.0, 0.0]))


def test_coordinate_order_must_list_the_coordinate_joints(tmp_path, monkeypatch):
    """A shipped robot whose robot.toml coordinate_order misses a joint is refused."""
    folder = tmp_path / "sk120"
    shutil.copytree(robots_directory() / "sk120", folder)
    toml = (folder / "robot.toml").read_text()
    toml = toml.replace('coordinate_order = ["joint1", "joint2", "joint3", "joint4", "joint5", '
                        '"joint6"]', 'coordinate_order = ["joint1", "joint2", "joint3"]')
    assert 'coordinate_order = ["joint1", "joint2", "joint3"]' in toml
    (folder / "robot.toml").write_text(toml)
    monkeypatch.setenv("STIFFNESS_ROBOTS", str(tmp_path))
    assert shipped_robots() == ["sk120"]
    with pytest.raises(StiffnessError,
                       match="coordinate_order .* must list exactly its coordinate"):
        load_robot("sk120")


def test_package_level_api_matches_the_modules():
    """``stiffness.load_robot`` (the issue's spelling) is the loader of
    ``stiffness.robot.robot``."""
    import stiffness
    from stiffness.mechanics import formulation
    from stiffness.robot import robot

    assert stiffness.load_robot is robot.load_robot
    assert stiffness.target_state is formulation.target_state
    loaded = stiffness.load_robot("sk120")
    assert loaded.compliant_joints == ("joint1", "joint2", "joint3")
    assert loaded.loop.passive_joints == ("elbow", "coupler_joint")


@pytest.mark.parametrize("name", ["ur5", "panda", "solo12", "talos_arm", "double_pendulum"])
def test_example_robot_data_model_without_meshes_is_the_loaders(name):
    """An example-robot-data robot is read without its meshes (they are read when the viewer
    asks): the model is the library loader's own (SRDF posture and rotor parameters,
    free-flyer limits included), and the visual geometry read later is its geometry."""
    from example_robot_data import robots_loader

    reference = robots_loader.ROBOTS[name]().robot
    source = resolve_source(name)
    assert source.visual is None and source.visual_loader is not None
    assert source.model == reference.model
    robot = load_robot(name, fixed_base=True)
    assert robot._visual_loader is not None  # nothing read yet
    copy = pickle.loads(pickle.dumps(robot))  # a robot pickles before its meshes are read
    geometry = robot.visual_model
    assert [g.name for g in copy.visual_model.geometryObjects] == [
        g.name for g in geometry.geometryObjects]
    assert [g.name for g in geometry.geometryObjects] == [
        g.name for g in reference.visual_model.geometryObjects]
    assert robot.visual_model is geometry  # read once


def test_ur3_is_a_ur3():
    """example-robot-data's name table gives "ur3" the UR5's loader; "ur3" is the UR3 (upper arm
    0.24365 m, its URDF's shoulder-to-elbow length; the UR5's is 0.425 m) and its model is
    UR3Loader's."""
    from example_robot_data import robots_loader

    ur3 = load_robot("ur3")
    elbow = ur3.model.getJointId("elbow_joint")
    assert ur3.model.jointPlacements[elbow].translation[2] == pytest.approx(0.24365)
    assert resolve_source("ur3").model == robots_loader.UR3Loader().robot.model


@pytest.mark.parametrize("name", ["anymal_c", "b1_z1", "so100", "talos_legs"])
def test_example_robots_pinocchio_cannot_reduce_as_given(name):
    """Robots whose models ``pin.buildReducedModel`` refuses as they come (a link and a joint
    of the same name; lower velocity limits above the upper ones) load with a fixed base, keep
    unique frame names, and give a finite K_C equal to finite differences of J^T F."""
    robot = load_robot(name, fixed_base=True)
    names = [f.name for f in robot.model.frames]
    assert len(set(names)) == len(names)
    q = robot.configuration(np.full(robot.n_coordinates, 0.3))
    force = np.array([5.0, -3.0, -20.0])
    state = target_state(robot, q, force)
    assert np.all(np.isfinite(state.k_c))
    h = 1e-6
    n = robot.n_compliant
    numeric = np.empty((n, n))
    for j in range(n):
        step = np.zeros(robot.n_coordinates)
        step[robot.coordinate_joints.index(robot.compliant_joints[j])] = h
        coords = np.full(robot.n_coordinates, 0.3)
        up = target_state(robot, robot.configuration(coords + step), force).jacobian[:3].T @ force
        down = target_state(robot, robot.configuration(coords - step), force).jacobian[:3].T @ force
        numeric[:, j] = (up - down) / (2 * h)
    np.testing.assert_allclose(state.k_c, numeric, atol=1e-5 * max(1.0, np.abs(numeric).max()))


def test_example_robot_the_library_cannot_build_is_a_typed_error():
    """A loader that fails inside example-robot-data (cassie needs an SDF parser this
    Pinocchio lacks) is one line naming the robot and what to do, not the library's traceback."""
    with pytest.raises(StiffnessError, match="example-robot-data cannot build 'cassie'") as info:
        load_robot("cassie")
    assert "\n" not in str(info.value)
    # its description holds only SDF files: the fix names that, not "load its URDF file"
    assert "SDF model" in str(info.value) and "URDF file instead" not in str(info.value)


@pytest.mark.parametrize("name, target", [("pr2", "l_gripper_tool_frame"),
                                          ("romeo", "l_gripper")])
def test_default_target_above_a_hand_whose_fingers_are_partly_coupled(name, target):
    """Where the deepest joint hangs below a coupled jaw without being coupled itself (PR2's
    finger tips), the default target is the hand's tool frame, not an error."""
    robot = load_robot(name, fixed_base=True)
    assert robot.target_frame == target
    q = robot.configuration(np.zeros(robot.n_coordinates))
    assert np.all(np.isfinite(target_state(robot, q, np.array([0.0, 0.0, -10.0])).k_c))
