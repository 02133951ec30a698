"""``stiffness robot export``: the URDF reloads to the same robot; the MJCF's springs, simulated
by MuJoCo (an independent engine), hold the target where the exact equilibrium puts it."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from stiffness.cli.main import main
from stiffness.errors import RobotFileWarning
from stiffness.mechanics.equilibrium import solve_equilibrium
from stiffness.robot.mjcf import robot_mjcf
from stiffness.robot.robot import load_robot

TOLERANCE = 1e-12
#: The SK120 as its maker describes it: a DH table with the parallelogram as a coupling.
SK120_DH = str(Path(__file__).resolve().parents[1] / "examples" / "sk120-dh" / "robot.toml")


def exported(robot_name: str, tmp_path: Path, *extra: str) -> Path:
    out = tmp_path / f"{Path(robot_name).parent.name or robot_name}.urdf"
    assert main(["robot", "export", "--robot", robot_name, "--urdf", str(out), "--quiet",
                 *extra]) == 0
    return out


def configurations(robot, count: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    if robot.loop.is_open_chain:
        return [pin.randomConfiguration(robot.model) for _ in range(count)]
    base = np.deg2rad(np.asarray(robot.defaults["q_deg"], dtype=float))
    return [robot.configuration(base + rng.uniform(-0.2, 0.2, base.shape))
            for _ in range(count)]


@pytest.mark.parametrize("name", ["ur5", "panda", "sk120", SK120_DH])
def test_urdf_reloads_to_the_same_kinematics_and_inertias(name, tmp_path):
    robot = load_robot(name)
    path = exported(name, tmp_path)
    back = load_robot(str(path), frame=robot.target_frame, target_offset=robot.target_offset)
    a, b = robot.model, back.model
    assert [a.names[j] for j in range(a.njoints)] == [b.names[j] for j in range(b.njoints)]
    for j in range(a.njoints):
        assert a.joints[j].shortname() == b.joints[j].shortname(), a.names[j]
        np.testing.assert_allclose(b.jointPlacements[j].homogeneous,
                                   a.jointPlacements[j].homogeneous, atol=TOLERANCE)
        np.testing.assert_allclose(b.inertias[j].toDynamicParameters(),
                                   a.inertias[j].toDynamicParameters(), atol=TOLERANCE)
    for limits in ("lowerPositionLimit", "upperPositionLimit", "effortLimit", "velocityLimit"):
        np.testing.assert_array_equal(getattr(b, limits), getattr(a, limits))
    assert back.mimics == robot.mimics
    if robot.coupling is None:  # a URDF holds the chain, not the controller's coordinates
        assert sorted(back.coordinate_joints) == sorted(robot.coordinate_joints)
    if not robot.loop.is_open_chain:  # the loops written beside the URDF were read back
        assert back.loop.pairs == robot.loop.pairs
        assert back.loop.passive_joints == robot.loop.passive_joints
    da, db = a.createData(), b.createData()
    for q in configurations(robot, 10, seed=1):
        pin.framesForwardKinematics(a, da, q)
        pin.framesForwardKinematics(b, db, q)
        np.testing.assert_allclose(db.oMf[back.target_frame_id].homogeneous,
                                   da.oMf[robot.target_frame_id].homogeneous, atol=TOLERANCE)
        for frame in a.frames:
            np.testing.assert_allclose(db.oMf[b.getFrameId(frame.name)].homogeneous,
                                       da.oMf[a.getFrameId(frame.name)].homogeneous,
                                       atol=TOLERANCE, err_msg=frame.name)


def simulate_to_rest(xml: str, force: np.ndarray, armature: float, damping: np.ndarray,
                     gravity: bool = False):
    """MuJoCo, gravity off (on with ``gravity``), ``force`` (N, world axes) held at the site
    ``stiffness_target``, damped until every joint velocity is below 1e-13: the site's position
    and qpos."""
    import mujoco

    m = mujoco.MjModel.from_xml_string(xml)
    if not gravity:
        m.opt.gravity[:] = 0.0
    m.opt.timestep = 1e-3
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    m.dof_armature[:] = armature  # rotor inertia: slows the wrist, does not change statics
    m.dof_damping[:] = damping
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    mujoco.mj_forward(m, d)
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "stiffness_target")
    for step in range(1, 100_001):
        d.qfrc_applied[:] = 0.0
        mujoco.mj_applyFT(m, d, force, np.zeros(3), d.site_xpos[site], m.site_bodyid[site],
                          d.qfrc_applied)
        mujoco.mj_step(m, d)
        if step > 10 and np.abs(d.qvel).max() < 1e-13:
            break
    else:
        raise AssertionError("MuJoCo did not come to rest")
    mujoco.mj_forward(m, d)
    return d.site_xpos[site].copy(), d.qpos.copy()


UR5_SPRINGS = {"shoulder_pan_joint": 8e4, "shoulder_lift_joint": 8e4, "elbow_joint": 5e4,
               "wrist_1_joint": 2e4, "wrist_2_joint": 2e4, "wrist_3_joint": 2e4}


@pytest.mark.parametrize("seed, compliant", [
    (0, tuple(UR5_SPRINGS)), (1, tuple(UR5_SPRINGS)),
    (2, ("shoulder_lift_joint", "elbow_joint", "wrist_2_joint")),  # the others welded rigid
])
def test_mujoco_springs_hold_the_target_at_the_exact_equilibrium(seed, compliant):
    """Measured: 1.5e-12 to 5.4e-12 of deflections of 0.56 to 1.1 mm."""
    rng = np.random.default_rng(seed)
    robot = load_robot("ur5", frame="tool0", target_offset=[0.0, 0.05, 0.1],
                       compliant_joints=compliant)
    k = np.array([UR5_SPRINGS[j] for j in compliant]) * rng.uniform(0.5, 2.0, len(compliant))
    q0 = robot.configuration(np.array([0.3, -1.1, 1.4, -0.6, 1.2, 0.4])
                             + rng.uniform(-0.3, 0.3, 6))
    force = rng.uniform(-80.0, 80.0, 3)
    xml = robot_mjcf(robot, dict(zip(robot.compliant_joints, k, strict=True)), q0)
    position, qpos = simulate_to_rest(xml, force, armature=0.05,
                                      damping=2.0 * np.sqrt(k * 0.5))
    exact = solve_equilibrium(robot, q0, np.diag(k), force)
    assert np.linalg.norm(exact.dx) > 1e-4  # a deflection worth comparing (m)
    relative = np.linalg.norm(position - exact.position) / np.linalg.norm(exact.dx)
    assert relative < 1e-6, relative
    np.testing.assert_allclose(qpos, exact.q[robot.compliant_v], atol=1e-9)


def test_mujoco_tendons_on_controller_coordinates_match_the_closed_loop_sk120():
    """The SK120 written as a DH chain with the parallelogram as a coupling, its springs on the
    controller's coordinates (fixed tendons: joint3's spans the shoulder and the elbow), under
    the paper's load in MuJoCo, holds the target where the shipped closed-loop model's exact
    equilibrium does. Measured: 1.6e-9 of the 1.07 mm deflection."""
    from stiffness.mechanics.defaults import default_coordinates

    robot, loop = load_robot(SK120_DH), load_robot("sk120")
    k = np.asarray(robot.defaults["k_theta_SI"], dtype=float)
    force = np.asarray(robot.defaults["wrench_SI"], dtype=float)
    coords = default_coordinates(robot)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RobotFileWarning)  # massless links
        xml = robot_mjcf(robot, dict(zip(robot.compliant_joints, k, strict=True)),
                         robot.configuration(coords))
    assert xml.count("<fixed ") == 3 and 'joint="elbow"' in xml
    position, _ = simulate_to_rest(xml, force, armature=1.0, damping=np.full(3, 2e3))
    exact = solve_equilibrium(loop, loop.configuration(coords), np.diag(k), force)
    relative = np.linalg.norm(position - exact.position) / np.linalg.norm(exact.dx)
    assert relative < 1e-6, relative


@pytest.mark.parametrize("name, compliant", [
    ("panda", None),  # a mimic follower
    ("panda", ("panda_joint2", "panda_joint4")),  # rigid joints welded, the gripper with them
    ("ur5", ("shoulder_lift_joint", "wrist_3_joint")),
])
def test_mjcf_sites_agree_with_pinocchio_at_the_rest_keyframe(name, compliant):
    """Every site where Pinocchio puts its frame, the mimic constraint satisfied, the springs
    at rest; one MuJoCo joint per spring (rigid joints welded) and per free mimic follower."""
    import mujoco

    robot = load_robot(name, compliant_joints=compliant)
    q = robot.configuration(np.linspace(0.1, 0.3, robot.n_coordinates))
    xml = robot_mjcf(robot, {j: 1e5 for j in robot.compliant_joints}, q)
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    mujoco.mj_forward(m, d)
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q)
    for i in range(m.nsite):
        placement = data.oMf[robot.model.getFrameId(m.site(i).name)]
        np.testing.assert_allclose(d.site_xpos[i], placement.translation, atol=1e-12)
        np.testing.assert_allclose(d.site_xmat[i].reshape(3, 3), placement.rotation,
                                   atol=1e-12)
    equality = d.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
    np.testing.assert_allclose(d.efc_pos[equality], 0.0, atol=1e-12)
    followers = sum(mimic.leader in robot.compliant_joints for mimic in robot.mimics)
    assert m.njnt == robot.n_compliant + followers and m.neq == followers
    np.testing.assert_allclose(d.qfrc_spring, 0.0, atol=1e-9)


def test_mjcf_from_a_model_file_carries_its_springs(tmp_path):
    import mujoco

    from stiffness.elastic.model_file import read_model_file

    model = Path(__file__).resolve().parents[1] / "docs" / "compensation" / "ur5-model.json"
    out = tmp_path / "ur5.xml"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RobotFileWarning)
        assert main(["robot", "export", "--model", str(model), "--mjcf", str(out),
                     "--quiet"]) == 0
    m = mujoco.MjModel.from_xml_path(str(out))
    written = read_model_file(model)
    springs = dict(zip(written.compliant_joints, written.k_theta, strict=True))
    springs.update({e.where: e.value("stiffness") for e in written.effects
                    if e.name == "joint_compliance"})
    for joint in range(m.njnt):
        assert m.jnt_stiffness[joint] == springs.get(m.joint(joint).name, 0.0)


@pytest.mark.parametrize("args, words", [
    (["--robot", "ur5"], ["--urdf", "--mjcf"]),
    (["--robot", "ur5", "--mjcf", "OUT"], ["--kq is required"]),
    (["--robot", "ur5", "--mjcf", "OUT", "--kq", "1,2"],
     ["--kq must be one finite positive stiffness per compliant joint of ur5"]),
    (["--robot", "nosuchrobot", "--urdf", "OUT"], ["nosuchrobot"]),
    (["--robot", "sk120", "--mjcf", "OUT"], ["closed loops", "--urdf"]),
    (["--robot", SK120_DH, "--compliant-joints", "joint1,joint2", "--kq", "1e6,1e6",
      "--mjcf", "OUT"], ["rigid controller coordinate 'joint3'"]),
    # springs for a URDF (which has none) were accepted and dropped, any count (TX40, 3 for 6)
    (["--robot", "ur5", "--urdf", "OUT", "--kq", "1,2,3"],
     ["--kq is for --mjcf", "add --mjcf OUT.xml, or drop --kq"]),
    (["--robot", "ur5", "--urdf", "OUT", "--q", "0,0,0,0,0,0"], ["--q is for --mjcf"]),
])
def test_bad_input_gives_one_line(args, words, tmp_path, capsys):
    out = str(tmp_path / "out.xml")
    assert main(["robot", "export", *[out if a == "OUT" else a for a in args]]) == 2
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(lines) == 1, lines
    for word in words:
        assert word in lines[0], lines[0]
    assert not (tmp_path / "out.xml").exists()


POINT_MASS_ARM = """name = "point-mass-arm"
compliant_joints = ["j1", "j2", "j3"]
[dh]
convention = "standard"
length_unit = "m"
angle_unit = "rad"
joints = [
  { name = "j1", alpha = 1.5707963267948966, a = 0.0, theta = 0.0, d = 0.4 },
  { name = "j2", alpha = 0.0, a = 0.5, theta = 0.0, d = 0.0 },
  { name = "j3", alpha = 0.0, a = 0.4, theta = 0.0, d = 0.0 },
]
tool = { xyz = [0.0, 0.0, 0.1], rpy = [0.0, 0.0, 0.0] }
links = [ { mass = 5.0, com = [0.0, 0.0, 0.0] }, { mass = 4.0, com = [-0.25, 0.0, 0.0] },
          { mass = 2.0, com = [-0.2, 0.0, 0.05] } ]
"""


def test_point_masses_export_and_sag_in_mujoco_as_in_the_exact_equilibrium(tmp_path):
    """A DH table's links given as point masses (no ``inertia``, as docs/robot-files.md
    allows): the URDF and the MJCF carry the 1 mm sphere's inertia (2/5 m r^2), and MuJoCo,
    gravity on, comes to rest where the exact equilibrium under the links' weight puts the
    target (measured: 3e-12 of a 1.4 mm sag)."""
    from stiffness.mechanics.gravity import gravity_preload
    from stiffness.robot.urdf_writer import POINT_MASS_RADIUS_M

    toml = tmp_path / "robot.toml"
    toml.write_text(POINT_MASS_ARM)
    robot = load_robot(str(toml))
    masses = [robot.model.inertias[j].mass for j in range(1, robot.model.njoints)]
    urdf = exported(str(toml), tmp_path)
    back = load_robot(str(urdf), frame=robot.target_frame)
    for j, mass in enumerate(masses, start=1):
        np.testing.assert_allclose(back.model.inertias[j].inertia,
                                   0.4 * mass * POINT_MASS_RADIUS_M ** 2 * np.eye(3), rtol=1e-12)
        np.testing.assert_allclose(back.model.inertias[j].lever, robot.model.inertias[j].lever,
                                   atol=1e-12)
    k = np.array([2e4, 1.5e4, 1e4])
    q0 = robot.configuration(np.array([0.3, 0.4, -0.6]))
    xml = robot_mjcf(robot, dict(zip(robot.compliant_joints, k, strict=True)), q0)
    position, _ = simulate_to_rest(xml, np.zeros(3), armature=0.05,
                                   damping=2.0 * np.sqrt(k * 0.5), gravity=True)
    exact = solve_equilibrium(robot, q0, np.diag(k), np.zeros(3),
                              preload=lambda q: gravity_preload(robot, q))
    assert np.linalg.norm(exact.dx) > 1e-4  # a sag worth comparing (m)
    relative = np.linalg.norm(position - exact.position) / np.linalg.norm(exact.dx)
    assert relative < 1e-6, relative


def test_mjcf_of_a_link_with_an_impossible_inertia_compiles_with_a_warning(tmp_path):
    """A URDF link whose principal moments break the triangle inequality (1 + 1 < 3 kg.m^2, as
    fetch's finger links): MuJoCo refused the export ('report this with the robot file'); it
    is balanced by MuJoCo's compiler, with a warning naming the link's joint, and still holds
    the spring."""
    import mujoco

    from stiffness.robot.mjcf import check_mjcf

    path = tmp_path / "odd.urdf"
    path.write_text("""<?xml version="1.0"?><robot name="odd"><link name="base"/>
  <link name="arm"><inertial><origin xyz="0.2 0 0"/><mass value="1"/>
    <inertia ixx="1" iyy="1" izz="3" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="tip"/>
  <joint name="swing" type="revolute"><parent link="base"/><child link="arm"/>
    <axis xyz="0 1 0"/><limit effort="1" velocity="1" lower="-1" upper="1"/></joint>
  <joint name="tip_joint" type="fixed"><parent link="arm"/><child link="tip"/>
    <origin xyz="0.4 0 0"/></joint></robot>""")
    robot = load_robot(path)
    with pytest.warns(RobotFileWarning, match="the inertia of the links of swing breaks the "
                                              "triangle inequality"):
        xml = robot_mjcf(robot, {"swing": 123.0}, pin.neutral(robot.model))
    check_mjcf(xml, robot.name)
    model = mujoco.MjModel.from_xml_string(xml)
    assert model.jnt_stiffness.tolist() == [123.0]


LIFT_ARM = """<?xml version="1.0"?><robot name="lift"><link name="base"/>
  <link name="column"><inertial><mass value="2"/>
    <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="arm"><inertial><origin xyz="0.2 0 0"/><mass value="1"/>
    <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="tip"/>
  <joint name="lift" type="prismatic"><parent link="base"/><child link="column"/>
    <axis xyz="0 0 1"/><limit effort="1" velocity="1" lower="0" upper="0.35"/></joint>
  <joint name="swing" type="revolute"><parent link="column"/><child link="arm"/>
    <origin xyz="0 0 0.5"/><axis xyz="0 1 0"/>
    <limit effort="1" velocity="1" lower="-1" upper="1"/></joint>
  <joint name="tip_joint" type="fixed"><parent link="arm"/><child link="tip"/>
    <origin xyz="0.4 0 0"/></joint></robot>"""


def test_mjcf_warns_of_springs_resting_on_a_joint_limit(tmp_path):
    """tiago's zero pose puts its torso lift on its lower limit (0 on [0, 0.35] m): MuJoCo's
    range stopped the lift's spring and the exported model deflected half as far as the
    toolkit's under a downward load, silently. A lift on its limit is warned about, and
    MuJoCo's rest misses the exact equilibrium by the lift's whole deflection; inside the
    limits no warning, and it agrees."""
    (tmp_path / "lift.urdf").write_text(LIFT_ARM)
    robot = load_robot(tmp_path / "lift.urdf")
    springs, force = {"lift": 1e4, "swing": 2e3}, np.array([0.0, 0.0, -50.0])
    missed = {}
    for height, warned in ((0.0, True), (0.1, False)):
        q0 = robot.configuration(np.array([height, 0.3]))
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always")
            xml = robot_mjcf(robot, springs, q0)
        said = [str(w.message) for w in seen if "a joint limit" in str(w.message)]
        assert said == (["lift: the springs of lift (0, limits [0, 0.35]) rest on or beyond a "
                         "joint limit, where MuJoCo's range stops their deflection one way (the "
                         "toolkit's statics ignore limits); give --q inside the limits"]
                        if warned else [])
        position, _ = simulate_to_rest(xml, force, armature=0.05, damping=np.array([300.0, 60.0]))
        exact = solve_equilibrium(robot, q0, np.diag(list(springs.values())), force)
        missed[height] = np.linalg.norm(position - exact.position) / np.linalg.norm(exact.dx)
    assert missed[0.0] > 0.5 and missed[0.1] < 1e-6, missed
