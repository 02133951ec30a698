"""Robots as people already have them (issue 11): Gepetto's Extended-URDF loop files, tolerant
URDF reading, idle passive motions, the assembly search, floating bases, mimic joints, the
default target frame and planar arms with fewer than three task dimensions.

Every robot here is written in the test in Gepetto's format, and J and K_C are checked against
finite differences of kinematics written independently in the test (closed forms and a scalar
loop-closure equation solved by Newton), never against the library itself.

The RSSR-like linkage used below: a crank (``crank_joint``, motor, about z at the origin, length
A) carries a rod through ``rod_ball`` (a revolute joint in the URDF, rewritten by ``joint_type``);
the rod's far end ``rod_end`` meets ``rocker_end``, the end of a rocker (``rocker_joint``, about
y at P, length C) in a point contact ("3d"). A motor slide on the rocker carries the target
``tool_tip``. With a spherical ``rod_ball`` the rod spins idly about its own axis (it does not
move the target); with a universal joint it does not.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import CRANK_ROCKER, write_four_bar
from fuzzing import assert_reader_contract, byte_mutation
from hypothesis import given, settings
from hypothesis import strategies as st

from stiffness.cli.main import main
from stiffness.errors import (
    FileFormatError,
    FloatingBaseError,
    LoopClosureError,
    RobotFileError,
    RobotFileNote,
    RobotFileWarning,
    StiffnessError,
    UndeterminedMotionError,
)
from stiffness.mechanics.formulation import target_state
from stiffness.robot.robot import load_robot

A, C = 0.2, 0.3
P = np.array([0.5, 0.15, 0.0])
TOOL = np.array([0.05, 0.0, 0.0])  # tool_tip in the slide's frame (rocker axes)
FORCE = np.array([30.0, -20.0, 50.0])


def _rot_y(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rssr_urdf(rod_length: float, rod_type_in_urdf: str = "revolute",
               limit: str = '<limit effort="1" velocity="1"/>') -> str:
    """The linkage at zero joint values; the rod points from the crank end to the rocker end
    of the zero pose, scaled to ``rod_length`` (so the zero pose closes only when the length
    matches)."""
    crank_end = np.array([A, 0.0, 0.0])
    rocker_end = P + np.array([0.0, 0.0, C])
    rod = rocker_end - crank_end
    rod = rod / np.linalg.norm(rod) * rod_length
    v = " ".join(repr(float(x)) for x in rod)
    return f"""<?xml version="1.0"?>
<robot name="rssr">
  <link name="base_link"/><link name="crank"/><link name="rod"/><link name="rod_end"/>
  <link name="rocker"/><link name="rocker_end"/><link name="tool"/><link name="tool_tip"/>
  <joint name="crank_joint" type="revolute"><parent link="base_link"/><child link="crank"/>
    <axis xyz="0 0 1"/><limit effort="1" velocity="1" lower="-3.2" upper="3.2"/></joint>
  <joint name="rod_ball" type="{rod_type_in_urdf}"><parent link="crank"/><child link="rod"/>
    <origin xyz="{A} 0 0"/><axis xyz="0 0 1"/>
    <limit effort="1" velocity="1" lower="-3" upper="3"/></joint>
  <joint name="rod_end_joint" type="fixed"><parent link="rod"/><child link="rod_end"/>
    <origin xyz="{v}"/></joint>
  <joint name="rocker_joint" type="revolute"><parent link="base_link"/><child link="rocker"/>
    <origin xyz="{P[0]} {P[1]} {P[2]}"/><axis xyz="0 1 0"/>
    <limit effort="1" velocity="1" lower="-3" upper="3"/></joint>
  <joint name="rocker_end_joint" type="fixed"><parent link="rocker"/><child link="rocker_end"/>
    <origin xyz="0 0 {C}"/></joint>
  <joint name="slide" type="prismatic"><parent link="rocker"/><child link="tool"/>
    <origin xyz="0 0 {C}"/><axis xyz="0 0 1"/>{limit}</joint>
  <joint name="tool_tip_joint" type="fixed"><parent link="tool"/><child link="tool_tip"/>
    <origin xyz="{TOOL[0]} {TOOL[1]} {TOOL[2]}"/></joint>
</robot>
"""


def _rssr_yaml(rod_type: str) -> str:
    return ("closed_loop: [['rod_end', 'rocker_end']]\ntype: ['3d']\n"
            "name_mot: ['crank_joint', 'slide']\n"
            f"joint_name: ['rod_ball']\njoint_type: ['{rod_type}']\n")


def _rocker_angle(phi: float, rod_length: float, psi0: float = 0.0) -> float:
    """Independent closure: the rocker angle psi with |rocker_end - crank_end| = rod length
    (Newton on the scalar distance equation, from ``psi0``)."""
    crank_end = A * np.array([np.cos(phi), np.sin(phi), 0.0])
    psi = psi0
    for _ in range(100):
        d = P + C * np.array([np.sin(psi), 0.0, np.cos(psi)]) - crank_end
        f = d @ d - rod_length ** 2
        df = 2 * d @ (C * np.array([np.cos(psi), 0.0, -np.sin(psi)]))
        step = f / df
        psi -= step
        if abs(step) < 1e-15:
            break
    return psi


def _rssr_target(theta: np.ndarray, rod_length: float, psi0: float = 0.0) -> np.ndarray:
    phi, s = theta
    psi = _rocker_angle(phi, rod_length, psi0)
    return P + _rot_y(psi) @ (np.array([0.0, 0.0, C + s]) + TOOL)


def _fd_jacobian(fn, theta: np.ndarray, h: float = 1e-6) -> np.ndarray:
    cols = []
    for i in range(theta.size):
        e = np.zeros_like(theta)
        e[i] = h
        cols.append((fn(theta + e) - fn(theta - e)) / (2 * h))
    return np.column_stack(cols)


def _fd_hessian(fn, theta: np.ndarray, h: float = 1e-4) -> np.ndarray:
    """Hessian of a scalar function by central differences."""
    n = theta.size
    out = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            ei, ej = np.eye(n)[i] * h, np.eye(n)[j] * h
            out[i, j] = (fn(theta + ei + ej) - fn(theta + ei - ej) - fn(theta - ei + ej)
                         + fn(theta - ei - ej)) / (4 * h * h)
    return out


def _write(folder, urdf_text: str, yaml_text: str | None, urdf_name: str = "robot.urdf",
           yaml_name: str = "robot.yaml"):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / urdf_name).write_text(urdf_text)
    if yaml_text is not None:
        (folder / yaml_name).write_text(yaml_text)
    return folder / urdf_name


ROD = float(np.linalg.norm(P + np.array([0.0, 0.0, C]) - np.array([A, 0.0, 0.0])))


@pytest.fixture(scope="module")
def spinning(tmp_path_factory):
    """The linkage with a spherical rod_ball (Gepetto rewrite, lower-case type): idle spin."""
    path = _write(tmp_path_factory.mktemp("spin"), _rssr_urdf(ROD), _rssr_yaml("spherical"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        robot = load_robot(path)
    return robot, [str(w.message) for w in caught
                   if issubclass(w.category, RobotFileWarning)]


def test_gepetto_files_load_unchanged(spinning):
    robot, warned = spinning
    # robot.yaml found beside robot.urdf; the rewrite made rod_ball spherical; passive joints
    # are every joint that is not a motor
    assert not robot.loop.is_open_chain and robot.loop_file.endswith("robot.yaml")
    assert robot.model.joints[robot.model.getJointId("rod_ball")].shortname() == \
        "JointModelSpherical"
    assert set(robot.loop.passive_joints) == {"rod_ball", "rocker_joint"}
    assert robot.coordinate_joints == ("crank_joint", "slide")
    # the <limit> without bounds loads, with one warning naming the joint and the line
    assert len(warned) == 1 and "'slide' has a <limit> without lower and upper" in warned[0]
    assert ", line 18:" in warned[0]  # the line of that <limit>
    # the default target is the tip of the longest chain that does not close a loop
    assert robot.target_frame == "tool_tip"


def test_idle_rod_spin_is_allowed_and_counted(spinning):
    robot, _ = spinning
    theta = np.array([0.4, 0.03])
    assembly = robot.assemble(theta)
    assert assembly.idle_passive_motions == 1
    assert assembly.residual < 1e-10 and not assembly.assembly_search
    state = target_state(robot, assembly.q, FORCE)
    np.testing.assert_allclose(state.position, _rssr_target(theta, ROD), atol=1e-12)
    fd_j = _fd_jacobian(lambda t: _rssr_target(t, ROD), theta)
    np.testing.assert_allclose(state.jacobian[:3], fd_j, atol=1e-8)
    fd_kc = _fd_hessian(lambda t: FORCE @ _rssr_target(t, ROD), theta)
    np.testing.assert_allclose(state.k_c, fd_kc, atol=1e-5 * np.abs(fd_kc).max())


def test_target_on_the_spinning_rod_is_refused_in_those_words(tmp_path):
    """A target off the rod's axis moves with the idle spin: refused, saying so."""
    text = _rssr_urdf(ROD).replace(
        '<link name="rod_end"/>', '<link name="rod_end"/><link name="rod_flag"/>').replace(
        "</robot>", '<joint name="flag" type="fixed"><parent link="rod"/><child '
                    'link="rod_flag"/><origin xyz="0 0.1 0"/></joint></robot>')
    path = _write(tmp_path, text, _rssr_yaml("SPHERICAL"))
    with pytest.warns(RobotFileWarning):
        robot = load_robot(path, frame="rod_flag")
    q = robot.configuration(np.array([0.4, 0.0]))
    with pytest.raises(UndeterminedMotionError,
                       match="the target's position depends on an undetermined motion"):
        target_state(robot, q, FORCE)


LONG_ROD = 0.8  # unreachable at crank angle 0 (at most 0.618 m there), reachable near pi


@pytest.fixture(scope="module")
def searched(tmp_path_factory):
    """A universal rod joint (UJOINT_XY) and a rod too long for the zero pose to close."""
    path = _write(tmp_path_factory.mktemp("search"), _rssr_urdf(LONG_ROD),
                  _rssr_yaml("ujoint_xy"), "rssr.urdf", "rssr.yaml")
    return load_robot(path)


def test_ujoint_rewrite_as_gepetto(searched):
    names = list(searched.model.names)
    assert "rod_ball" not in names and {"rod_ball_X", "rod_ball_Y"} <= set(names)
    x, y = (searched.model.joints[searched.model.getJointId(n)] for n in
            ("rod_ball_X", "rod_ball_Y"))
    assert (x.shortname(), y.shortname()) == ("JointModelRX", "JointModelRY")
    assert set(searched.loop.passive_joints) == {"rod_ball_X", "rod_ball_Y", "rocker_joint"}


def test_pose_that_needs_the_assembly_search(searched):
    assembly = searched.assemble(None)  # the zero pose: it does not close
    assert assembly.assembly_search and assembly.residual < 1e-10
    assert assembly.idle_passive_motions == 0
    theta = searched.coordinates_of(assembly.q)
    assert abs(theta[0]) > 0.1
    # the nearest assembly lies on the edge of the crank's reach (a fold): continue from it to
    # a regular pose further in and check J and K_C there against the independent closure
    theta = theta + np.array([0.5 * np.sign(theta[0]), 0.02])
    q = searched.configuration(theta, seed=assembly.q)
    psi = searched._value(q, "rocker_joint")
    state = target_state(searched, q, FORCE)
    np.testing.assert_allclose(state.position, _rssr_target(theta, LONG_ROD, psi), atol=1e-11)
    fd_j = _fd_jacobian(lambda t: _rssr_target(t, LONG_ROD, psi), theta)
    np.testing.assert_allclose(state.jacobian[:3], fd_j, atol=1e-8)
    fd_kc = _fd_hessian(lambda t: FORCE @ _rssr_target(t, LONG_ROD, psi), theta)
    np.testing.assert_allclose(state.k_c, fd_kc, atol=1e-5 * np.abs(fd_kc).max())


def test_given_pose_out_of_reach_is_refused_with_residual_and_loop(searched):
    with pytest.raises(LoopClosureError, match=r"loop \[rod_end, rocker_end\] cannot be closed"
                       r".*residual of 0\.1[0-9]* m") as info:
        searched.configuration(np.array([0.0, 0.0]))
    # independently: the universal joint turns the rod about x then y of the crank frame
    from scipy.optimize import minimize

    rod0 = P + np.array([0.0, 0.0, C]) - np.array([A, 0.0, 0.0])
    rod0 = rod0 / np.linalg.norm(rod0) * LONG_ROD

    def gap(x):
        alpha, beta, psi = x
        ca, sa = np.cos(alpha), np.sin(alpha)
        rot_x = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
        rod_end = np.array([A, 0.0, 0.0]) + rot_x @ _rot_y(beta) @ rod0
        return np.linalg.norm(rod_end - P - C * np.array([np.sin(psi), 0.0, np.cos(psi)]))

    best = min(minimize(gap, x0, method="Nelder-Mead", options={"xatol": 1e-10, "fatol": 1e-12})
               .fun for x0 in np.random.default_rng(0).uniform(-np.pi, np.pi, (8, 3)))
    assert best > LONG_ROD - 0.6185  # never closer than the rocker end's farthest reach
    assert info.value.residual == pytest.approx(best, rel=1e-4)


def test_no_assembly_anywhere_is_refused(tmp_path):
    path = _write(tmp_path, _rssr_urdf(2.0), _rssr_yaml("UJOINT_XY"))
    robot = load_robot(path)
    with pytest.raises(LoopClosureError, match=r"no assembly near its zero pose.*loop "
                                               r"\[rod_end, rocker_end\].*residual.*the frames "
                                               r"of \[rod_end, rocker_end\] cannot meet even "
                                               r"with that loop alone"):
        robot.assemble(None)


def test_a_ball_closure_typed_as_a_weld_is_named_with_the_fix(tmp_path):
    """Gepetto's generateYAML types every pair 6d (their kangaroo_like: 5 of 11 pairs cannot
    weld). A planar four-bar's pin closure welded: the coupler and rocker would be parallel
    with their ends met, so |crank end - rocker pivot| = |c - b|, which the crank, turning,
    never reaches (that distance stays within [d - a, d + a]); as a point contact it closes."""
    bar = write_four_bar(tmp_path, "fourbar", **CRANK_ROCKER)
    a, b, c, d = (CRANK_ROCKER[k] for k in "abcd")
    assert abs(c - b) < d - a  # independently: no crank angle welds it
    load_robot(bar.urdf, frame="tool_tip").assemble(None)  # declared 3D: closes
    sidecar = bar.urdf.with_suffix("").with_suffix(".loops.yaml")
    sidecar.write_text(sidecar.read_text().replace('"3D"', '"6D"'))
    with pytest.raises(LoopClosureError, match=r"keeps a residual of [0-9.e-]+ m; the loops close "
                       r"with the 6d pairs typed 3d .*\(\[coupler_end, rocker_end\] cannot "
                       r"close as welds even alone\): type the ball and pin closures 3d") as info:
        load_robot(bar.urdf, frame="tool_tip").assemble(None)
    assert "\n" not in str(info.value)


def test_loop_frames_left_out_of_the_loop_file_are_named(tmp_path):
    """kangaroo_like's robot.yaml pairs closedloop0, 2..11 but not the URDF's closedloop1_A/B."""
    bar = write_four_bar(tmp_path, "fourbar", **CRANK_ROCKER)
    bar.urdf.write_text(bar.urdf.read_text().replace('"tool_tip"', '"closedloop1_A"'))
    with pytest.warns(RobotFileWarning, match=r"1 frames of fourbar.urdf named as loop-closure "
                      r"frames are in no closed_loop pair \(closedloop1_A\): their loops are "
                      r"left open"):
        load_robot(bar.urdf, frame="closedloop1_A")


def test_kx_json_configuration_and_closure(spinning, capsys):
    robot, _ = spinning
    path = robot.loop_file.replace("robot.yaml", "robot.urdf")
    assert main(["kx", "--robot", path, "--q", "0.4,0.03", "--kq", "1e4,2e5",
                 "--wrench", "30,-20,50", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    config = out["configuration"]
    assert set(config) == {"crank_joint", "rod_ball", "rocker_joint", "slide"}
    assert config["crank_joint"] == pytest.approx(0.4) and config["slide"] == pytest.approx(0.03)
    assert len(config["rod_ball"]) == 4  # a spherical joint: its quaternion, Pinocchio's q
    assert config["rocker_joint"] == pytest.approx(_rocker_angle(0.4, ROD), abs=1e-10)
    assert out["closure"]["idle_passive_motions"] == 1
    assert out["closure"]["assembly_search"] is False and out["closure"]["residual"] < 1e-10


# ------------------------------------------------------------------- loop-file format errors


@pytest.mark.parametrize(("yaml_text", "match"), [
    ("closed_loop: [[rod_end, rocker_end]]\ntype: ['3d']\nname_mot: [crank_joint, slide]\n"
     "motors: [x]\n", r"robot\.yaml, line 4: unknown key 'motors'.*valid keys: closed_loop"),
    ("closed_loop: [[rod_end, rocker_end]]\ntype: ['2d']\nname_mot: [crank_joint, slide]\n",
     r"robot\.yaml, line 2: loop type '2d' is not supported"),
    ("closed_loop: [[rod_end, rocker_end]]\ntype: ['3d']\nname_mot: [crank_joint, slide]\n"
     "joint_name: [rod_ball]\njoint_type: [BALL]\n", r"joint type 'BALL' of 'rod_ball'"),
    ("closed_loop: [[rod_end, rocker_end]]\ntype: ['3d']\nname_mot: [crank_joint, slide]\n"
     "joint_name: [rod_ball]\n", r"joint_type must list one type per joint_name"),
])
def test_loop_file_errors_name_file_line_and_problem(tmp_path, yaml_text, match):
    path = _write(tmp_path, _rssr_urdf(ROD), yaml_text)
    with pytest.raises(RobotFileError, match=match):
        load_robot(path)


def test_sidecar_order_and_the_loops_flag(tmp_path):
    """<name>.loops.yaml before <name>.yaml before robot.yaml; --loops/loops= overrides."""
    folder = tmp_path / "r"
    path = _write(folder, _rssr_urdf(ROD), _rssr_yaml("spherical"), "arm.urdf", "robot.yaml")
    (folder / "arm.yaml").write_text(_rssr_yaml("ujoint_xy"))
    with pytest.warns(RobotFileWarning):
        assert load_robot(path).loop_file.endswith("arm.yaml")
        (folder / "arm.loops.yaml").write_text(_rssr_yaml("spherical"))
        assert load_robot(path).loop_file.endswith("arm.loops.yaml")
        assert load_robot(path, loops=folder / "arm.yaml").loop_file.endswith("arm.yaml")
    (folder / "arm.loops.yaml").unlink()
    (folder / "arm.yaml").write_text("some: other config\n")
    with pytest.warns(RobotFileWarning, match="arm.yaml: not a loop declaration"):
        assert load_robot(path).loop_file.endswith("robot.yaml")


def test_a_robot_toml_naming_a_urdf_finds_the_sidecar_beside_it(tmp_path):
    """A robot.toml with urdf = "..." and no loops key closes the loops of the sidecar beside
    that URDF, as the URDF's own path does (it loaded the mechanism as an open tree, with a
    warning to declare the loops in the robot.yaml that was there); loops = "..." still wins."""
    folder = tmp_path / "r"
    path = _write(folder, _rssr_urdf(ROD), _rssr_yaml("spherical"), "arm.urdf", "robot.yaml")
    (folder / "leg.toml").write_text('urdf = "arm.urdf"\n')
    by_path, by_toml = load_robot(path), load_robot(folder / "leg.toml")
    assert by_toml.loop_file == by_path.loop_file == str(folder / "robot.yaml")
    assert by_toml.coordinate_joints == by_path.coordinate_joints
    assert len(by_toml.loop.pairs) == len(by_path.loop.pairs) == 1


def test_loop_frames_without_a_declaration_are_named_in_a_warning(tmp_path):
    """A URDF whose frames carry Gepetto's loop-frame names (closedloop<N>_A/_B) but has no
    loop declaration loads as an open tree, with a warning that says so and how to declare
    the loops; with the declaration, or with a URDF of no such frames, no such warning."""
    text = _rssr_urdf(ROD).replace("rod_end", "closedloop1_A").replace("rocker_end",
                                                                       "closedloop1_B")
    path = _write(tmp_path / "bare", text, None)
    with pytest.warns(RobotFileWarning) as caught:
        robot = load_robot(path)
    assert robot.loop_file is None and robot.n_coordinates == 4  # the rod's joint is free
    found = [str(w.message) for w in caught if "loop-closure frames" in str(w.message)]
    assert len(found) == 1
    assert "'closedloop1_A'" in found[0] and "open tree" in found[0]
    assert str(tmp_path / "bare" / "robot.yaml") in found[0] and "--loops" in found[0]
    declared = _rssr_yaml("spherical").replace("rod_end", "closedloop1_A").replace(
        "rocker_end", "closedloop1_B")
    (tmp_path / "loops.yaml").write_text(declared)
    for kwargs in ({"loops": tmp_path / "loops.yaml"}, {}):
        if not kwargs:
            (tmp_path / "bare" / "robot.yaml").write_text(declared)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            assert load_robot(path, **kwargs).loop_file is not None
        assert not [w for w in caught if "loop-closure frames" in str(w.message)]
    plain = tmp_path / "plain" / "planar.urdf"
    plain.parent.mkdir()
    plain.write_text(_planar_arm())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_robot(plain)
    assert not [w for w in caught if "loop-closure frames" in str(w.message)]


# ------------------------------------------------------------------------- URDF tolerance


def _planar_arm(extra: str = "", header: str = '<?xml version="1.0"?>') -> str:
    return f"""{header}
<robot name="planar">
  <link name="base_link"/><link name="l1"/><link name="l2"/><link name="tip"/>
  <link name="sonar"/>
  <joint name="sonar_joint" type="fixed"><parent link="base_link"/><child link="sonar"/>
    <origin xyz="0 0 0.5"/></joint>
  <joint name="j1" type="revolute"><parent link="base_link"/><child link="l1"/>
    <axis xyz="0 0 1"/><limit effort="1" velocity="1" lower="-3" upper="3"/></joint>
  <joint name="j2" type="continuous"><parent link="l1"/><child link="l2"/>
    <origin xyz="0.4 0 0"/><axis xyz="0 0 1"/></joint>
  <joint name="tip_joint" type="fixed"><parent link="l2"/><child link="tip"/>
    <origin xyz="0.3 0 0"/></joint>{extra}
</robot>
"""


def _planar_tip(theta, l3=0.0, mimic=(0.5, 0.1)):
    """Tip of the planar arm (links 0.4 and 0.3 m); with ``l3``, the tip of a third link whose
    joint follows the second: theta3 = multiplier * theta2 + offset."""
    t1, t2 = theta
    t3 = mimic[0] * t2 + mimic[1]
    return np.array([0.4 * np.cos(t1) + 0.3 * np.cos(t1 + t2) + l3 * np.cos(t1 + t2 + t3),
                     0.4 * np.sin(t1) + 0.3 * np.sin(t1 + t2) + l3 * np.sin(t1 + t2 + t3),
                     0.0])


def test_xml_header_version_0_0_loads_with_one_warning(tmp_path):
    path = tmp_path / "minitaur_like.urdf"
    path.write_text(_planar_arm(header='<?xml version="0.0"?>'))
    with pytest.warns(RobotFileWarning, match="XML declaration version '0.0' ignored") as rec:
        robot = load_robot(path)
    assert len([w for w in rec if issubclass(w.category, RobotFileWarning)]) == 1
    assert robot.coordinate_joints == ("j1", "j2")


def _unbounded_chain(n: int, lower: bool = False) -> str:
    """A serial chain of ``n`` revolute joints whose ``<limit>`` gives effort and velocity
    only (an Onshape export), ``lower="-1"`` on each with ``lower``."""
    bound = ' lower="-1"' if lower else ""
    joints = "".join(
        f'<link name="l{i + 1}"/><joint name="j{i + 1}" type="revolute"><parent link="l{i}"/>'
        f'<child link="l{i + 1}"/><origin xyz="0.1 0 0"/><axis xyz="0 0 1"/>'
        f'<limit effort="1" velocity="1"{bound}/></joint>\n' for i in range(n))
    return f'<?xml version="1.0"?>\n<robot name="chain"><link name="l0"/>\n{joints}</robot>\n'


def test_joints_without_bounds_are_one_note_not_one_line_each(tmp_path):
    """Gepetto's kangaroo_like has 63 joints whose <limit> has no bounds: it printed 63
    warning lines. Now one note per file counts them, names the first six with their lines,
    and they load unbounded."""
    path = tmp_path / "chain.urdf"
    path.write_text(_unbounded_chain(9))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        robot = load_robot(path)
    notes = [str(w.message) for w in caught if issubclass(w.category, RobotFileWarning)]
    assert [w.category for w in caught if issubclass(w.category, RobotFileWarning)] == [
        RobotFileNote]
    assert notes[0].startswith(f"{path}: 9 joints have a <limit> without lower and upper: "
                               "'j1' (line 3), 'j2' (line 4),")
    assert "'j6' (line 8) and 3 more; they are taken as unbounded" in notes[0]
    assert np.all(np.isinf(robot.model.lowerPositionLimit)) and np.all(
        np.isinf(robot.model.upperPositionLimit))
    path.write_text(_unbounded_chain(2, lower=True))  # a lower bound only: unbounded above
    with pytest.warns(RobotFileNote, match=r"2 joints have a <limit> without upper: 'j1' "
                      r"\(line 3\), 'j2' \(line 4\); they are taken as unbounded above"):
        robot = load_robot(path)
    np.testing.assert_array_equal(robot.model.lowerPositionLimit, [-1.0, -1.0])


def test_robot_file_notes_print_once_as_notes_and_not_under_quiet(tmp_path):
    from stiffness.cli.main import _one_line_warning

    path = tmp_path / "chain.urdf"
    path.write_text(_unbounded_chain(3))
    argv = ["kx", "--robot", str(path), "--kq", "1e3,1e3,1e3", "--wrench", "0,1,0"]
    for flags, expected in (([], 1), (["--quiet"], 0)):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            assert main([*argv, *flags]) == 0
        notes = [w for w in caught if issubclass(w.category, RobotFileWarning)]
        assert len(notes) == expected, (flags, [str(w.message) for w in notes])
    assert _one_line_warning("3 joints", RobotFileNote, "urdf.py", 1) == \
        "stiffness: note: 3 joints\n"


@pytest.mark.parametrize(("text", "line", "problem"), [
    (_planar_arm().replace('<origin xyz="0.4 0 0"/>', '<origin xyz="0.4 q 0"/>'), 10,
     "Unable to parse component"),
    (_planar_arm().replace('type="continuous"', 'type="hinge"'), 9, "no known type"),
    (_planar_arm().replace('<parent link="l1"/>', '<parent link="l9"/>'), 9,
     "names the parent link 'l9'"),
    (_planar_arm().replace("<link name=\"l2\"/>", "<link name=\"l2\">"), 13,
     "not well-formed XML: Opening and ending tag mismatch: link line 3"),
    # taken by Pinocchio's parser, but the joint cannot move as declared (they loaded)
    (_planar_arm().replace('<origin xyz="0.4 0 0"/><axis xyz="0 0 1"/>',
                           '<origin xyz="0.4 0 0"/><axis xyz="0 0 0"/>'), 10,
     "joint 'j2' has the zero axis xyz='0 0 0': it would move nothing; give the direction"),
    (_planar_arm().replace('lower="-3" upper="3"', 'lower="3" upper="-3"'), 8,
     "joint 'j1' has lower=3 above upper=-3; swap them"),
    # a xacro file given as a URDF: PAL's hey5_test.urdf.xacro (a hand whose links are all in
    # macros) read as 'no joint of hey5.urdf.xacro moves any frame'
    (_planar_arm('\n  <xacro:include filename="$(find arm)/urdf/hand.urdf.xacro"/>').replace(
        '<robot name="planar">', '<robot name="planar" xmlns:xacro="http://ros.org/wiki/xacro">'),
     13, "a xacro file, not a URDF: its <xacro:include> is not expanded; expand it first "
         "(`xacro bad.urdf > bad.expanded.urdf`"),
    (_planar_arm().replace('lower="-3"', 'lower="${-pi}"'), 8,
     "a xacro file, not a URDF: its lower='${-pi}' is not expanded"),
    # Pinocchio's 'Some components of min_effort are greater than max_effort' named no joint
    # (Halodi's eve_r3 writes effort="-1.0" velocity="-1.0" on 23 joints)
    (_planar_arm().replace('effort="1" velocity="1"', 'effort="-1.0" velocity="-1"'), 8,
     "joint 'j1' has a negative effort=-1.0 and velocity=-1 in its <limit>, which Pinocchio "
     "takes as a minimum above the maximum; write the limits as positive numbers"),
    # 'Could not find the 'robot' element in the xml file' for a Gazebo or MuJoCo file
    ('<?xml version="1.0"?>\n<sdf version="1.6"><model name="m"><link name="a"/></model></sdf>',
     2, "an SDFormat (Gazebo) file, not a URDF: its root element is <sdf>, a URDF's is <robot>"),
    ('<mujoco model="m">\n<worldbody/></mujoco>', 1,
     "a MuJoCo (MJCF) file, not a URDF: its root element is <mujoco>"),
    # 'No name given for the robot.' (ROBOTIS' open_manipulator, xacro-generated)
    (_planar_arm().replace('<robot name="planar">', '<robot>'), 2,
     'the <robot> element has no name attribute; name the robot, e.g. <robot name="arm">'),
])
def test_malformed_urdf_is_one_line_with_file_and_line(tmp_path, text, line, problem):
    path = tmp_path / "bad.urdf"
    path.write_text(text)
    with pytest.raises(RobotFileError) as info:
        load_robot(path)
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"{path}, line {line}")
    assert info.value.line == line and problem in message


# ---------------------------------------------------------- planar arms, mimics, bases, frames


def test_planar_2r_arm_kx_prints_the_subspace_and_exits_0(tmp_path, capsys):
    path = tmp_path / "planar.urdf"
    path.write_text(_planar_arm())
    robot = load_robot(path)
    assert robot.target_frame == "tip"  # not the sonar frame fixed to the base
    theta = np.array([0.3, 0.9])
    state = target_state(robot, robot.configuration(theta), FORCE)
    np.testing.assert_allclose(state.jacobian[:3], _fd_jacobian(_planar_tip, theta), atol=1e-9)
    fd_kc = _fd_hessian(lambda t: FORCE @ _planar_tip(t), theta)
    np.testing.assert_allclose(state.k_c, fd_kc, atol=1e-6 * np.abs(fd_kc).max())
    kq = np.array([120.0, 80.0])
    assert main(["kx", "--robot", str(path), "--q", "0.3,0.9", "--kq", "120,80",
                 "--wrench", "30,-20,50", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    j = _fd_jacobian(_planar_tip, theta)
    compliance = j @ np.linalg.solve(np.diag(kq) - fd_kc, j.T)
    np.testing.assert_allclose(out["compliance"], compliance, atol=1e-7 * np.abs(
        compliance).max())
    sub = out["K_X_subspace"]
    assert out["K_X"] is None and sub["rank"] == 2
    moving = np.array(sub["moving_directions"]).T
    np.testing.assert_allclose(np.abs(moving.T @ [0, 0, 1]), 0, atol=1e-12)  # the x-y plane
    np.testing.assert_allclose(sub["K_X"], np.linalg.pinv(compliance),
                               atol=1e-6 * np.abs(np.linalg.pinv(compliance)).max())
    assert main(["kx", "--robot", str(path), "--q", "0.3,0.9", "--kq", "120,80",
                 "--wrench", "30,-20,50"]) == 0
    text = capsys.readouterr().out
    assert "compliance" in text and "K_X on the 2-dimensional moving subspace" in text


def test_mimic_joint_follows_its_leader(tmp_path):
    extra = """
  <link name="l3"/><link name="tip3"/>
  <joint name="j3" type="revolute"><parent link="l2"/><child link="l3"/>
    <origin xyz="0.3 0 0"/><axis xyz="0 0 1"/><mimic joint="j2" multiplier="0.5" offset="0.1"/>
    <limit effort="1" velocity="1" lower="-3" upper="3"/></joint>
  <joint name="tip3_joint" type="fixed"><parent link="l3"/><child link="tip3"/>
    <origin xyz="0.2 0 0"/></joint>"""
    path = tmp_path / "mimic.urdf"
    path.write_text(_planar_arm(extra))
    robot = load_robot(path)
    assert robot.coordinate_joints == ("j1", "j2") == robot.compliant_joints
    assert robot.target_frame == "tip3"
    theta = np.array([0.3, 0.9])
    q = robot.configuration(theta)
    assert robot._value(q, "j3") == pytest.approx(0.5 * 0.9 + 0.1)

    def tip(t):
        return _planar_tip(t, l3=0.2)

    state = target_state(robot, q, FORCE)
    np.testing.assert_allclose(state.position, tip(theta), atol=1e-14)
    np.testing.assert_allclose(state.jacobian[:3], _fd_jacobian(tip, theta), atol=1e-9)
    fd_kc = _fd_hessian(lambda t: FORCE @ tip(t), theta)
    np.testing.assert_allclose(state.k_c, fd_kc, atol=1e-6 * np.abs(fd_kc).max())
    with pytest.raises(StiffnessError, match="mimic follower: its leader carries the spring"):
        load_robot(path, compliant_joints=["j1", "j3"])


@pytest.mark.parametrize("kind", ["floating", "planar"])
def test_floating_or_planar_base_needs_the_flag(tmp_path, kind, capsys):
    text = _planar_arm().replace(
        '<link name="base_link"/>', '<link name="world"/><link name="base_link"/>').replace(
        "</robot>", f'<joint name="root" type="{kind}"><parent link="world"/>'
                    '<child link="base_link"/><axis xyz="0 0 1"/></joint></robot>')
    path = tmp_path / "floating.urdf"
    path.write_text(text)
    with pytest.raises(FloatingBaseError, match="--fixed-base"):
        load_robot(path)
    robot = load_robot(path, fixed_base=True)
    assert robot.coordinate_joints == ("j1", "j2")
    theta = np.array([0.3, 0.9])
    state = target_state(robot, robot.configuration(theta), FORCE)
    np.testing.assert_allclose(state.jacobian[:3], _fd_jacobian(_planar_tip, theta), atol=1e-9)
    assert main(["kx", "--robot", str(path), "--q", "0.3,0.9", "--kq", "1,1",
                 "--wrench", "0,0,-1"]) == 2
    assert "--fixed-base" in capsys.readouterr().err
    assert main(["kx", "--robot", str(path), "--fixed-base", "--q", "0.3,0.9", "--kq", "1,1",
                 "--wrench", "0,0,-1"]) == 0
    out = capsys.readouterr().out
    assert out.count("fixed at its neutral placement") == 1


def test_frame_that_no_joint_moves_is_refused_with_the_moving_frames(tmp_path):
    path = tmp_path / "planar.urdf"
    path.write_text(_planar_arm())
    with pytest.raises(StiffnessError, match=r"frame 'sonar' .* not moved by any joint.*"
                                             r"frames? that moves?: .*tip"):
        load_robot(path, frame="sonar")


def test_robot_without_joints_is_refused_with_the_fix(tmp_path):
    """A URDF of fixed joints only (a drone's body once its base is fixed) has nothing to be
    compliant: one line that says so and what to do."""
    path = tmp_path / "body.urdf"
    path.write_text('<?xml version="1.0"?>\n<robot name="body"><link name="base"/>'
                    '<link name="rotor"/><joint name="mount" type="fixed"><parent link="base"/>'
                    '<child link="rotor"/></joint></robot>\n')
    with pytest.raises(StiffnessError, match="no joint of .* moves any frame.*choose a robot "
                                             "with joints"):
        load_robot(path)


def test_default_target_on_a_hand_is_the_wrist_tip(tmp_path):
    """Two equally long fingers: the target is on their last common joint, farthest out."""
    fingers = "".join(f"""
  <link name="f{i}"/><link name="f{i}_tip"/>
  <joint name="finger{i}" type="revolute"><parent link="l2"/><child link="f{i}"/>
    <origin xyz="0.3 {0.02 * (2 * i - 1)} 0"/><axis xyz="0 1 0"/>
    <limit effort="1" velocity="1" lower="-1" upper="1"/></joint>
  <joint name="f{i}_tip_joint" type="fixed"><parent link="f{i}"/><child link="f{i}_tip"/>
    <origin xyz="0.05 0 0"/></joint>""" for i in (0, 1))
    path = tmp_path / "hand.urdf"
    path.write_text(_planar_arm(fingers))
    assert load_robot(path).target_frame == "tip"


def test_declared_springs_of_an_arm_with_fingers_are_its_default(tmp_path, capsys):
    """A robot.toml naming a URDF with fingers beside the target's chain, declaring k_theta_SI
    for the chain's joints (its default springs, which the count check takes): the springs
    were compared with every coordinate, fingers included, and dropped, so kx asked for --kq
    (so101 with a robot.toml beside example-robot-data's URDF: 'k_theta_SI = [300, ...]'
    counted and ignored)."""
    from stiffness.mechanics.defaults import default_stiffness

    fingers = "".join(f"""
  <link name="f{i}"/>
  <joint name="finger{i}" type="revolute"><parent link="l2"/><child link="f{i}"/>
    <origin xyz="0.3 {0.02 * (2 * i - 1)} 0"/><axis xyz="0 1 0"/>
    <limit effort="1" velocity="1" lower="-1" upper="1"/></joint>""" for i in (0, 1))
    (tmp_path / "hand.urdf").write_text(_planar_arm(fingers))
    (tmp_path / "robot.toml").write_text('urdf = "hand.urdf"\nframe = "tip"\n'
                                         "k_theta_SI = [2000.0, 1000.0]\n")
    robot = load_robot(tmp_path / "robot.toml")
    assert robot.coordinate_joints == ("j1", "j2", "finger0", "finger1")
    assert robot.compliant_joints == ("j1", "j2")
    np.testing.assert_array_equal(default_stiffness(robot), [2000.0, 1000.0])
    assert main(["kx", "--robot", str(tmp_path / "robot.toml"), "--wrench", "0,10,0"]) == 0
    assert "K_theta [robot default] (N.m/rad, N/m prismatic): j1=2000,j2=1000" in \
        capsys.readouterr().out


# ------------------------------------------------------------------ one order per robot


def test_sk120_by_name_and_by_path_give_identical_kx(capsys):
    from stiffness.robot.sources import robots_directory

    path = str(robots_directory() / "sk120" / "sk120.urdf")
    flags = ["--q=-30,20,-50,10,-30,60", "--deg", "--kq", "1.4e6,4e5,9.3e5",
             "--wrench", "40,350,200", "--json"]
    results = []
    for source in ("sk120", path):
        assert main(["kx", "--robot", source, *flags]) == 0
        results.append(json.loads(capsys.readouterr().out))
    by_name, by_path = results
    assert by_name["coordinate_joints"] == by_path["coordinate_joints"]
    assert by_name["J"] == by_path["J"] and by_name["K_X"] == by_path["K_X"]
    assert by_name["frame"] == by_path["frame"] == "fixture_target"


def test_batch_kernels_allow_idle_motions_and_follow_mimics(spinning, tmp_path):
    """The vectorised kinematics (scan) agree with target_state (checked above against finite
    differences) on the idle rod spin and on a mimic follower."""
    from stiffness.batch.kernels import batch_kinematics

    robot, _ = spinning
    arm = tmp_path / "mimic.urdf"
    arm.write_text(_planar_arm("""
  <link name="l3"/><joint name="j3" type="revolute"><parent link="l2"/><child link="l3"/>
    <origin xyz="0.3 0 0"/><axis xyz="0 0 1"/><mimic joint="j2" multiplier="-0.7"/>
    <limit effort="1" velocity="1" lower="-3" upper="3"/></joint>"""))
    mimic = load_robot(arm, frame="l3", target_offset=[0.2, 0.05, 0.0])
    for r, coords in ((robot, [[0.4, 0.03], [-0.3, 0.1]]), (mimic, [[0.3, 0.9], [1.0, -0.5]])):
        q = np.array([r.configuration(np.array(c)) for c in coords])
        kin = batch_kinematics(r, q)
        assert kin.valid.all()
        for i in range(len(q)):
            state = target_state(r, q[i], FORCE)
            np.testing.assert_allclose(kin.jacobian[i], state.jacobian, atol=1e-12)
            k_c = np.einsum("k,kab->ab", FORCE, kin.k_c_basis[i][:3])
            np.testing.assert_allclose(k_c, state.k_c, atol=1e-10 * np.abs(state.k_c).max())


def test_a_folder_named_like_a_robot_does_not_hide_it(tmp_path, monkeypatch):
    """A campaign simulated into a folder named after its robot ("ur5") is read from the
    folder above it: the campaign's source "ur5" and --robot ur5 are the robot, not the
    folder (they said 'ur5 is a folder holding no robot.toml and no URDF file'); written as a
    path (./ur5) it is the folder, and a folder holding a URDF is still that robot."""
    from stiffness.calibration.campaign import load_campaign
    from stiffness.planning.simulate import simulate

    monkeypatch.chdir(tmp_path)
    simulate("ur5", kq=[3e4, 2e4, 1.5e4], compliant_joints=["shoulder_pan_joint",
             "shoulder_lift_joint", "elbow_joint"], configs=2, loads_per_config=1,
             seed=1).write("ur5")
    assert load_campaign("ur5").robot().coordinate_joints[0] == "shoulder_pan_joint"
    assert load_robot("ur5").n_coordinates == 6
    with pytest.raises(StiffnessError, match="ur5 is a folder holding no robot.toml"):
        load_robot("./ur5")
    (tmp_path / "panda").mkdir()
    (tmp_path / "panda" / "arm.urdf").write_text(_planar_arm())
    assert load_robot("panda").coordinate_joints == ("j1", "j2")


def test_example_robot_data_defaults_and_floating_base():
    """The default target of robots people use: the gripper of talos_arm (not a jaw or its motor
    link), tiago's grasping frame (not the sonar ring on its base); solo12's free flyer needs
    the flag, and with it the base is fixed and the default target is a foot."""
    assert load_robot("talos_arm").target_frame == "gripper_left_base_link"
    assert load_robot("tiago").target_frame == "hand_grasping_frame"
    with pytest.raises(FloatingBaseError, match=r"solo12 .*'root_joint' \(JointModelFreeFlyer\)"
                                                r".*--fixed-base.*fixed_base=True"):
        load_robot("solo12")
    solo = load_robot("solo12", fixed_base=True)
    assert solo.model.nq == solo.model.nv == solo.n_coordinates == 12
    assert solo.target_frame.endswith("_FOOT")
    assert any("fixed at its neutral placement" in note for note in solo.notes)


def test_simulated_campaign_keeps_the_loop_file_and_the_fixed_base(tmp_path, capsys):
    """``simulate --loops FILE --fixed-base`` writes both into the campaign's [robot] table, and
    the campaign reloads the same robot."""
    from stiffness.calibration.campaign import load_campaign

    (tmp_path / "arm").mkdir()
    text = _rssr_urdf(ROD).replace('<link name="base_link"/>',
                                   '<link name="world"/><link name="base_link"/>').replace(
        "</robot>", '<joint name="root" type="floating"><parent link="world"/>'
                    '<child link="base_link"/></joint></robot>')
    (tmp_path / "arm" / "robot.urdf").write_text(text)
    (tmp_path / "decl.yaml").write_text(_rssr_yaml("spherical"))
    out = tmp_path / "campaign"
    assert main(["simulate", "--robot", str(tmp_path / "arm" / "robot.urdf"), "--loops",
                 str(tmp_path / "decl.yaml"), "--fixed-base", "--kq", "1e4,2e5", "--configs",
                 "2", "--loads-per-config", "2", "--max-force", "10", "--out", str(out)]) == 0
    capsys.readouterr()
    toml = (out / "campaign.toml").read_text()
    assert 'loops = "../decl.yaml"' in toml and "fixed_base = true" in toml
    robot = load_campaign(out).robot()
    assert robot.fixed_base and Path(robot.loop_file).resolve() == tmp_path / "decl.yaml"
    assert robot.coordinate_joints == ("crank_joint", "slide")


def test_mimic_of_a_joint_not_in_the_file_is_ignored_with_a_warning(tmp_path):
    """A <mimic> tag whose leader is not a joint of the file (seen in example-robot-data's
    Alex hands) is ignored, as Pinocchio's parser ignores it, with a warning that says the
    follower is then an independent joint; the robot loads."""
    link = '<link name="{0}"><inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" ' \
           'iyy="1" iyz="0" izz="1"/></inertial></link>'
    joint = ('<joint name="{0}" type="revolute"><parent link="{1}"/><child link="{2}"/>'
             '<origin xyz="0 0 0.5"/><axis xyz="0 1 0"/>'
             '<limit lower="-3" upper="3" effort="1" velocity="1"/>{3}</joint>')
    urdf = tmp_path / "arm.urdf"
    urdf.write_text('<robot name="arm">' + "".join(link.format(n) for n in ("a", "b", "c"))
                    + joint.format("j1", "a", "b", "")
                    + joint.format("j2", "b", "c", '<mimic joint="nope"/>') + "</robot>")
    with pytest.warns(RobotFileWarning, match="'j2' mimics 'nope'.*independent joint"):
        robot = load_robot(str(urdf))
    assert robot.coordinate_joints == ("j1", "j2") and not robot.mimics


# ------------------------------------------------------------- a sidecar that is not UTF-8


def test_a_sidecar_not_in_utf8_is_one_line_or_ignored(tmp_path):
    """A robot.yaml beside the URDF in Latin-1 (an accented comment) raised
    UnicodeDecodeError (a traceback) while looking for its closed_loop key. A loop declaration
    so written is refused in one line naming the bytes; another YAML so written is ignored
    with the warning of any YAML without closed_loop."""
    path = _write(tmp_path / "a", _rssr_urdf(ROD), None)
    (tmp_path / "a" / "robot.yaml").write_bytes(
        (_rssr_yaml("spherical") + "# op\u00e9rateur\n").encode("latin-1"))
    with pytest.raises(FileFormatError, match=r"robot.yaml: not UTF-8 text \(byte \d+\); save "
                                             r"the loop declaration as UTF-8"):
        load_robot(path)
    path = _write(tmp_path / "b", _planar_arm(), None, urdf_name="planar.urdf")
    (tmp_path / "b" / "robot.yaml").write_bytes("name: x  # op\u00e9rateur\n".encode("latin-1"))
    with pytest.warns(RobotFileWarning, match="robot.yaml: not a loop declaration"):
        robot = load_robot(path)
    assert robot.coordinate_joints == ("j1", "j2")


@settings(max_examples=20, deadline=None)
@given(data=st.data())
def test_any_byte_of_a_sidecar_loads_or_is_one_line(tmp_path_factory, data):
    """A Gepetto robot.yaml with one to four bytes replaced, inserted or deleted: the robot
    loads, or one line, never another exception."""
    folder = tmp_path_factory.mktemp("sidecar")
    path = _write(folder, _rssr_urdf(ROD), None)
    (folder / "robot.yaml").write_bytes(data.draw(byte_mutation(_rssr_yaml("spherical"))))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        robot = assert_reader_contract(lambda: load_robot(path), folder)
    if robot is not None:
        assert robot.model.nq > 0


@given(after=st.integers(3, 12), tag=st.sampled_from(["include", "property", "macro", "arg",
                                                        "if", "my_hand"]))
def test_a_xacro_element_anywhere_is_refused_at_its_line(tmp_path_factory, after, tag):
    """Law: a ``<xacro:...>`` element inserted after any line of a valid URDF is refused as a
    xacro file at the element's line, naming it, whatever the macro."""
    lines = _planar_arm().replace(
        '<robot name="planar">',
        '<robot name="planar" xmlns:xacro="http://ros.org/wiki/xacro">').splitlines()
    lines.insert(after, f'<xacro:{tag} name="x"/>')
    path = tmp_path_factory.mktemp("xacro") / "arm.urdf.xacro"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(RobotFileError) as info:
        load_robot(path)
    assert info.value.line == after + 1
    assert f"a xacro file, not a URDF: its <xacro:{tag}> is not expanded" in str(info.value)
    assert "`xacro arm.urdf.xacro > arm.urdf`" in str(info.value)
