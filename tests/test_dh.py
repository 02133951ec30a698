"""Robots from DH tables and controller coordinates (issue 28, items 1, 2 and 4).

Every comparison is against an independent model: example-robot-data's UR URDFs, a URDF of the
same tree written here from DH matrices computed here, the shipped closed-loop SK120, finite
differences.
"""

from __future__ import annotations

import json
import math
import re
import shutil
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from stiffness.calibration.campaign import load_campaign
from stiffness.calibration.identify import identify
from stiffness.cli.main import main
from stiffness.errors import FileFormatError, RobotFileWarning, StiffnessError
from stiffness.mechanics.formulation import (
    cartesian_stiffness,
    compliance,
    joint_stiffness,
    tangent_joint_stiffness,
    target_state,
)
from stiffness.robot.robot import load_robot
from stiffness.robot.sources import robots_directory

ROOT = Path(__file__).resolve().parents[1]
SK120_DH = ROOT / "examples" / "sk120-dh" / "robot.toml"
TABLE2 = robots_directory() / "sk120" / "campaigns" / "table2"

# Universal Robots' published DH parameters (standard convention, m, rad).
UR_DH = {
    "ur5": dict(d=[0.089159, 0, 0, 0.10915, 0.09465, 0.0823], a=[0, -0.425, -0.39225, 0, 0, 0]),
    "ur10": dict(d=[0.1273, 0, 0, 0.163941, 0.1157, 0.0922], a=[0, -0.612, -0.5723, 0, 0, 0]),
}
UR_ALPHA = [math.pi / 2, 0, 0, math.pi / 2, -math.pi / 2, 0]


def _toml_value(value) -> str:
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + " }"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(float(value)) if not isinstance(value, bool) else str(value).lower()


def write_robot(path: Path, dh: dict, top: dict | None = None,
                controller: dict | None = None) -> Path:
    """A robot.toml from Python values (rows a list of dicts)."""
    lines = [f"{k} = {_toml_value(v)}" for k, v in (top or {}).items()]
    lines.append("[dh]")
    for key, value in dh.items():
        if key in ("joints", "frames", "links"):
            lines.append(f"{key} = [")
            lines += [f"  {_toml_value(row)}," for row in value]
            lines.append("]")
        else:
            lines.append(f"{key} = {_toml_value(value)}")
    if controller is not None:
        lines.append("[controller]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in controller.items()]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


def ur_rows(name: str) -> list[dict]:
    p = UR_DH[name]
    return [{"name": f"j{i + 1}", "type": "revolute", "alpha": UR_ALPHA[i], "a": p["a"][i],
             "theta": 0.0, "d": p["d"][i]} for i in range(6)]


def relative(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-300))


def stiffness_triple(robot, coords: np.ndarray, wrench: np.ndarray, k: np.ndarray):
    """J (6, n), K_C (n, n) and the 6x6 K_X (enhanced) at controller coordinates."""
    state = target_state(robot, robot.configuration(coords), wrench)
    tangent = tangent_joint_stiffness(joint_stiffness(k, len(k)), state.k_c)
    return state.jacobian, state.k_c, cartesian_stiffness(compliance(state.jacobian, tangent))


# ---------------------------------------------------------------------------------------------
# UR5 and UR10 from the maker's table


@pytest.mark.parametrize("name", ["ur5", "ur10"])
def test_ur_dh_table_equals_example_robot_data(tmp_path, name):
    """Alignment: DH frame 0 is example-robot-data's frame ``base`` (``base_link`` turned by
    pi about z), the DH tool frame is ``tool0``, and the joint values are the same."""
    dh = {"convention": "standard", "length_unit": "m", "angle_unit": "rad",
          "joints": ur_rows(name), "base": {"xyz": [0, 0, 0], "rpy": [0, 0, math.pi]}}
    mine = load_robot(write_robot(tmp_path / name / "robot.toml", dh))
    theirs = snap_right_angles(load_robot(name, frame="tool0"))
    assert mine.target_frame == "tool"
    rng = np.random.default_rng(5)
    worst = np.zeros(4)
    done = 0
    while done < 20:
        q = rng.uniform(-math.pi, math.pi, 6)
        wrench = np.concatenate([rng.normal(0, 300, 3), rng.normal(0, 30, 3)])
        k = rng.uniform(1e4, 1e6, 6)
        a, b = stiffness_triple(mine, q, wrench, k), stiffness_triple(theirs, q, wrench, k)
        if np.linalg.cond(b[2]) > 1e5:
            # near a singular pose K_X = C^-1 loses cond(C) * eps to rounding alone: with J
            # and K_C equal to 2e-16, K_X of the same model differs by 4.6e-10 at cond 2e8
            continue
        done += 1
        pa = target_state(mine, mine.configuration(q)).position
        pb = target_state(theirs, theirs.configuration(q)).position
        worst = np.maximum(worst, [relative(x, y) for x, y in zip(a, b, strict=True)]
                           + [float(np.abs(pa - pb).max())])
    assert worst.max() < 1e-10, worst


def snap_right_angles(robot):
    """The robot with its placements' rotation entries within 1e-9 of 0 or +-1 made exact.

    example-robot-data's UR URDFs write pi/2 as 1.57079632679 and pi as 3.14159265359 (5e-12
    and 2e-13 rad short of the published table's right angles). Unsnapped, J and K_C still
    agree to 1.0e-11 and 1.7e-11 (relative) and the compliance to 1.2e-11, but K_X = C^-1
    multiplies that by cond(C): up to 6e-10 entrywise near singular poses.
    """
    model = robot.model
    def snap(placement: pin.SE3) -> pin.SE3:
        rot = placement.rotation
        near = np.round(rot)
        return pin.SE3(np.where(np.abs(rot - near) < 1e-9, near, rot), placement.translation)
    for j in range(model.njoints):
        model.jointPlacements[j] = snap(model.jointPlacements[j])
    for frame in model.frames:
        frame.placement = snap(frame.placement)
    robot.data = model.createData()
    return robot


# ---------------------------------------------------------------------------------------------
# Craig (modified) and standard conventions


def dh_matrix(convention: str, alpha, a, theta, d) -> np.ndarray:
    """The 4x4 DH transform, written out here (not the module's)."""
    ca, sa, ct, st = math.cos(alpha), math.sin(alpha), math.cos(theta), math.sin(theta)
    if convention == "standard":
        return np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st],
                         [0, sa, ca, d], [0, 0, 0, 1.0]])
    return np.array([[ct, -st, 0, a], [st * ca, ct * ca, -sa, -sa * d],
                     [st * sa, ct * sa, ca, ca * d], [0, 0, 0, 1.0]])


ARM = [  # standard rows (m, rad) of an arm with a prismatic joint and a last-row offset
    dict(name="j1", type="revolute", alpha=-1.2, a=0.15, theta=0.3, d=0.4),
    dict(name="j2", type="revolute", alpha=0.4, a=0.7, theta=-0.5, d=0.05),
    dict(name="j3", type="prismatic", alpha=1.5707963267948966, a=0.1, theta=0.2, d=0.3),
    dict(name="j4", type="revolute", alpha=-0.7, a=0.02, theta=0.0, d=0.5),
    dict(name="j5", type="revolute", alpha=0.9, a=0.25, theta=1.1, d=-0.1),
]


def test_craig_and_standard_descriptions_give_identical_kinematics(tmp_path):
    """Standard row i = Rz Tz Tx(a_i) Rx(alpha_i); Craig's row i carries alpha_(i-1), a_(i-1),
    so the Craig table shifts alpha and a by one row and its tool takes the last Tx Rx."""
    rows = [dict(r, lower=-5, upper=5) for r in ARM]
    craig = [dict(r, alpha=(ARM[i - 1]["alpha"] if i else 0.0),
                  a=(ARM[i - 1]["a"] if i else 0.0)) for i, r in enumerate(rows)]
    last = ARM[-1]
    tool_rpy = [last["alpha"], 0.0, 0.0]
    units = {"length_unit": "m", "angle_unit": "rad"}
    std = load_robot(write_robot(tmp_path / "std" / "robot.toml",
                                 {"convention": "standard", **units, "joints": rows}))
    mod = load_robot(write_robot(tmp_path / "mod" / "robot.toml", {
        "convention": "modified", **units, "joints": craig,
        "tool": {"xyz": [last["a"], 0, 0], "rpy": tool_rpy}}))
    rng = np.random.default_rng(2)
    worst = 0.0
    for _ in range(20):
        q = rng.uniform(-2, 2, 5)
        expected = np.eye(4)
        for row, value in zip(ARM, q, strict=True):
            theta = row["theta"] + (value if row["type"] == "revolute" else 0.0)
            d = row["d"] + (value if row["type"] == "prismatic" else 0.0)
            expected = expected @ dh_matrix("standard", row["alpha"], row["a"], theta, d)
        wrench = rng.normal(0, 100, 6)
        for robot in (std, mod):
            pin.framesForwardKinematics(robot.model, robot.data, robot.configuration(q))
            placed = robot.data.oMf[robot.target_frame_id].homogeneous
            worst = max(worst, float(np.abs(placed - expected).max()))
        a, b = target_state(std, std.configuration(q), wrench), \
            target_state(mod, mod.configuration(q), wrench)
        assert relative(a.jacobian, b.jacobian) < 1e-12
        assert relative(a.k_c, b.k_c) < 1e-12
    assert worst < 1e-12


def test_modified_rows_match_their_matrix(tmp_path):
    """Each Craig row, alone, is Rx(alpha) Tx(a) Rz(theta) Tz(d) (written out here)."""
    row = dict(name="j", type="revolute", alpha=0.7, a=0.3, theta=-0.4, d=0.2)
    robot = load_robot(write_robot(tmp_path / "r" / "robot.toml", {
        "convention": "modified", "length_unit": "m", "angle_unit": "rad", "joints": [row]}))
    pin.framesForwardKinematics(robot.model, robot.data, robot.configuration(np.array([0.5])))
    expected = dh_matrix("modified", 0.7, 0.3, -0.4 + 0.5, 0.2)
    assert np.abs(robot.data.oMf[robot.target_frame_id].homogeneous - expected).max() < 1e-15


# ---------------------------------------------------------------------------------------------
# A tree: torso and two 7-joint arms, coupled torso joint, fixed hand frames


def _arm(prefix: str, parent: str, rng) -> list[dict]:
    rows = []
    for i in range(7):
        rows.append(dict(name=f"{prefix}{i + 1}", type="revolute",
                         alpha=float(rng.choice([-1, 1]) * math.pi / 2),
                         a=float(rng.uniform(0, .1)), theta=float(rng.uniform(-1, 1)),
                         d=float(rng.uniform(0, .3))))
    rows[0]["parent"] = parent
    return rows


def tree_description(rng) -> tuple[dict, dict, list[tuple[str, str, np.ndarray]]]:
    """DH section, controller and the (joint, parent, 4x4 origin) list of the same tree."""
    torso = [dict(name="t1", type="revolute", alpha=0.0, a=0.0, theta=0.0, d=0.8),
             dict(name="t2", type="revolute", alpha=math.pi / 2, a=0.05, theta=0.0, d=0.1)]
    frames = [dict(name="right_base", parent="t2", xyz=[0.0, -0.25, 0.3], rpy=[0.3, 0.0, 0.1]),
              dict(name="left_base", parent="t2", xyz=[0.0, 0.25, 0.3], rpy=[-0.3, 0.0, -0.1])]
    right, left = _arm("r", "right_base", rng), _arm("l", "left_base", rng)
    frames += [dict(name="r_hand", parent="r7", xyz=[0.0, 0.0, 0.12], rpy=[0.0, 0.0, 0.0]),
               dict(name="l_hand", parent="l7", xyz=[0.0, 0.0, 0.12], rpy=[0.0, 0.0, 0.0])]
    dh = {"convention": "modified", "length_unit": "m", "angle_unit": "rad",
          "joints": torso + right + left, "frames": frames}
    coords = ["J1", "J2"] + [f"R{i}" for i in range(1, 8)] + [f"L{i}" for i in range(1, 8)]
    chain = {"t1": "J1", "t2": "-J1 - J2"}
    chain.update({f"r{i}": f"R{i}" for i in range(1, 8)})
    chain.update({f"l{i}": f"L{i} + 0.1" for i in range(1, 8)})
    controller = {"coordinates": coords, "chain": chain, "springs_on": "controller"}
    return dh, controller, torso + right + left


def urdf_of_tree(rows: list[dict], frames: list[dict]) -> str:
    """The URDF of the tree: each joint's origin is its Craig row's fixed part, written here."""
    def origin(m: np.ndarray) -> str:
        rpy = pin.rpy.matrixToRpy(m[:3, :3])
        return (f'<origin xyz="{" ".join(repr(float(v)) for v in m[:3, 3])}" '
                f'rpy="{" ".join(repr(float(v)) for v in rpy)}"/>')
    parts = ['<robot name="tree">', '<link name="base"/>']
    previous = "base"
    for row in rows:
        parent = row.get("parent", previous)
        previous = row["name"]
        m = dh_matrix("modified", row["alpha"], row["a"], row["theta"], row["d"])
        parts += [f'<link name="{row["name"]}_body"/>',
                  f'<joint name="{row["name"]}" type="revolute"><parent link="{parent}_body"/>'
                  f'<child link="{row["name"]}_body"/>{origin(m)}<axis xyz="0 0 1"/>'
                  '<limit lower="-10" upper="10" effort="1" velocity="1"/></joint>']
    for frame in frames:
        m = np.eye(4)
        m[:3, :3] = pin.rpy.rpyToMatrix(np.array(frame["rpy"]))
        m[:3, 3] = frame["xyz"]
        parts += [f'<link name="{frame["name"]}_body"/>',
                  f'<joint name="{frame["name"]}_fixed" type="fixed"><parent '
                  f'link="{frame["parent"]}_body"/><child link="{frame["name"]}_body"/>'
                  f'{origin(m)}</joint>']
    parts.append("</robot>")
    return "\n".join(parts).replace('"base_body"', '"base"')


def test_two_arm_tree_equals_its_urdf(tmp_path):
    rng = np.random.default_rng(8)
    dh, controller, rows = tree_description(rng)
    path = write_robot(tmp_path / "tree" / "robot.toml", dh, {"frame": "r_hand"}, controller)
    mine = load_robot(path)
    assert mine.coordinate_joints == tuple(controller["coordinates"])
    urdf = tmp_path / "tree.urdf"
    urdf.write_text(urdf_of_tree(rows, dh["frames"]))
    every = load_robot(urdf, frame="r_hand_body").coordinate_joints  # springs on every joint
    theirs = load_robot(urdf, frame="r_hand_body", compliant_joints=every)
    # the coupling written out: t1 = J1, t2 = -J1 - J2, r_i = R_i, l_i = L_i + 0.1, rows in
    # the URDF model's joint order
    order = [r["name"] for r in rows]
    a_rows = np.eye(16)
    a_rows[1, :2] = -1.0
    b_rows = np.r_[np.zeros(9), np.full(7, 0.1)]
    at = [order.index(name) for name in theirs.coordinate_joints]
    a, b = a_rows[at], b_rows[at]
    worst = 0.0
    for _ in range(20):
        u = rng.uniform(-2, 2, 16)
        q_mine, q_theirs = mine.configuration(u), theirs.configuration(a @ u + b)
        pin.framesForwardKinematics(mine.model, mine.data, q_mine)
        pin.framesForwardKinematics(theirs.model, theirs.data, q_theirs)
        for hand in ("r_hand", "l_hand"):
            p = mine.data.oMf[mine.model.getFrameId(hand)].translation
            r = theirs.data.oMf[theirs.model.getFrameId(f"{hand}_body")].translation
            worst = max(worst, float(np.abs(p - r).max()))
        assert np.allclose(mine.coordinates_of(q_mine), u, atol=1e-12)
        # the Jacobian in controller coordinates is the chain's times A
        wrench = rng.normal(0, 50, 6)
        sm, st = target_state(mine, q_mine, wrench), target_state(theirs, q_theirs, wrench)
        assert relative(sm.jacobian, st.jacobian @ a) < 1e-12
        assert relative(sm.k_c, a.T @ st.k_c @ a) < 1e-12
    assert worst < 1e-12


def test_controller_complementary_stiffness_by_finite_differences(tmp_path):
    """K_C in controller coordinates = d(J_u^T W)/du, by central differences."""
    rng = np.random.default_rng(3)
    dh, controller, _ = tree_description(rng)
    robot = load_robot(write_robot(tmp_path / "t" / "robot.toml", dh, {"frame": "l_hand"},
                                   controller))
    u = rng.uniform(-1, 1, 16)
    wrench = rng.normal(0, 50, 6)
    state = target_state(robot, robot.configuration(u), wrench)
    h = 1e-6
    fd = np.zeros((16, 16))
    for i in range(16):
        du = np.zeros(16)
        du[i] = h
        plus = target_state(robot, robot.configuration(u + du), wrench).jacobian.T @ wrench
        minus = target_state(robot, robot.configuration(u - du), wrench).jacobian.T @ wrench
        fd[:, i] = (plus - minus) / (2 * h)
    assert relative(state.k_c, fd) < 1e-7


def test_springs_on_the_chain_equal_the_mapped_joint_stiffness(tmp_path):
    """Springs on the chain: the compliance J K^-1 J^T of the chain equals the controller's
    J_u (A^T K_chain A - K_C,u)^-1 J_u^T."""
    rng = np.random.default_rng(4)
    dh, controller, _ = tree_description(rng)
    top = {"frame": "r_hand"}
    on_ctrl = load_robot(write_robot(tmp_path / "c" / "robot.toml", dh, top, controller))
    on_chain = load_robot(write_robot(tmp_path / "j" / "robot.toml", dh, top,
                                      dict(controller, springs_on="chain")))
    assert on_chain.compliant_joints == on_ctrl.coupling.chain
    assert on_chain.stiffness_coordinates == "chain"
    assert on_ctrl.stiffness_coordinates == "controller"
    a = on_ctrl.coupling.matrix
    k_chain = rng.uniform(1e4, 1e5, 16)
    for _ in range(5):
        u = rng.uniform(-1, 1, 16)
        wrench = np.r_[rng.normal(0, 50, 3), np.zeros(3)]
        sc = target_state(on_ctrl, on_ctrl.configuration(u), wrench)
        sj = target_state(on_chain, on_chain.configuration(u), wrench)
        c_chain = compliance(sj.jacobian, np.diag(k_chain) - sj.k_c)
        c_ctrl = compliance(sc.jacobian, a.T @ np.diag(k_chain) @ a - sc.k_c)
        assert relative(c_ctrl, c_chain) < 1e-10


# ---------------------------------------------------------------------------------------------
# The SK120: parallelogram as a coupling against the shipped closed loop


def test_sk120_coupled_dh_equals_the_closed_loop_model():
    loop, dh = load_robot("sk120"), load_robot(SK120_DH)
    assert loop.coordinate_joints == dh.coordinate_joints
    assert loop.compliant_joints == dh.compliant_joints
    k = np.array(loop.defaults["k_theta_SI"])
    rng = np.random.default_rng(11)
    worst = np.zeros(4)
    for _ in range(20):
        u = np.deg2rad(rng.uniform([-90, -60, -100, -90, -100, -90], [90, 60, 25, 90, 100, 90]))
        force = rng.normal(0, 300, 3)
        sa = target_state(loop, loop.configuration(u), force)
        sb = target_state(dh, dh.configuration(u), force)
        ta = tangent_joint_stiffness(np.diag(k), sa.k_c)
        tb = tangent_joint_stiffness(np.diag(k), sb.k_c)
        kxa = cartesian_stiffness(compliance(sa.jacobian[:3], ta))
        kxb = cartesian_stiffness(compliance(sb.jacobian[:3], tb))
        worst = np.maximum(worst, [relative(sb.jacobian, sa.jacobian), relative(sb.k_c, sa.k_c),
                                   relative(kxb, kxa), float(np.abs(sb.position
                                                                    - sa.position).max())])
    assert worst.max() < 1e-10, worst


def test_identify_gives_the_same_stiffness_through_either_sk120(tmp_path):
    folder = tmp_path / "table2-dh"
    shutil.copytree(TABLE2, folder)
    toml = folder / "campaign.toml"
    text = toml.read_text().replace('source = "sk120"', f'source = "{SK120_DH.as_posix()}"')
    toml.write_text(text.replace('frame = "fixture_target"', 'frame = "tool"'))
    loop = identify(load_campaign(TABLE2), starts=2)
    coupled = identify(load_campaign(folder), starts=2)
    assert relative(coupled.k, loop.k) < 1e-8, (coupled.k, loop.k)
    # the exact equilibrium through the coupling (the pose model's sag, the batch kernels)
    exact_loop = identify(load_campaign(TABLE2), "exact", starts=1)
    exact_coupled = identify(load_campaign(folder), "exact", starts=1)
    # equal to where the fits stop: within 2e-8 of the optimum (ftol 1e-10 on a flat cost;
    # Gauss-Newton steps from the loop's fit measured 1.7e-8 in ln k, to the coupled fit's
    # stiffnesses within 6e-12)
    assert relative(exact_coupled.k, exact_loop.k) < 5e-8
    assert relative(exact_coupled.k, coupled.k) > 1e-5  # it is not the enhanced fit again
    assert coupled.stiffness_coordinates == "controller"
    assert loop.stiffness_coordinates == "chain"
    assert coupled.to_dict()["stiffness_coordinates"] == "controller"


def test_identify_text_and_json_state_the_coordinates(tmp_path, capsys):
    folder = tmp_path / "table2-dh"
    shutil.copytree(TABLE2, folder)
    toml = folder / "campaign.toml"
    toml.write_text(toml.read_text().replace('source = "sk120"', f'source = "{SK120_DH}"')
                    .replace('frame = "fixture_target"', 'frame = "tool"'))
    out = tmp_path / "model.json"
    assert main(["identify", str(folder), "--starts", "1", "--out", str(out)]) == 0
    assert capsys.readouterr().out.count("stiffness in controller coordinates") == 1
    assert main(["identify", str(folder), "--starts", "1", "--out", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["stiffness_coordinates"] == "controller"


def test_kx_takes_a_dh_robot_file_and_controller_coordinates(capsys):
    q = ["-33.2004", "15.9", "-55.5957", "0", "-34.4045", "-90"]
    q = ",".join(q)
    assert main(["kx", "--robot", str(SK120_DH), "--q", q, "--deg", "--json"]) == 0
    mine = json.loads(capsys.readouterr().out)
    assert main(["kx", "--robot", "sk120", "--q", q, "--deg", "--json"]) == 0
    theirs = json.loads(capsys.readouterr().out)
    assert mine["coordinate_joints"] == theirs["coordinate_joints"]
    assert relative(np.array(mine["K_X"]), np.array(theirs["K_X"])) < 1e-10


# ---------------------------------------------------------------------------------------------
# links, limits, units


def test_links_and_point_masses_weigh_what_they_say(tmp_path):
    """Gravity torque on a horizontal two-link arm: m g x_com summed, written out here."""
    rows = [dict(name="a", alpha=90.0, a=0.0, theta=0.0, d=0.0, lower=-90, upper=90),
            dict(name="b", alpha=0.0, a=500.0, theta=0.0, d=0.0, lower=-90, upper=90)]
    links = [dict(parent="b", mass=2.0, com=[-0.25, 0.0, 0.0],
                  inertia=[0.01, 0.02, 0.02, 0.0, 0.0, 0.0]),
             dict(parent="tool", mass=1.5)]
    robot = load_robot(write_robot(tmp_path / "w" / "robot.toml", {
        "convention": "standard", "length_unit": "mm", "angle_unit": "deg", "joints": rows,
        "links": links, "tool": {"xyz": [100.0, 0, 0]}}))
    assert np.allclose(robot.model.upperPositionLimit, np.deg2rad(90))
    q = robot.configuration(np.zeros(2))
    # joint b turns about the horizontal axis; the link lies along x: torque m g x
    tau = pin.computeGeneralizedGravity(robot.model, robot.data, q)
    expected = 9.81 * (2.0 * 0.25 + 1.5 * 0.6)
    assert abs(abs(tau[1]) - expected) < 1e-9 * expected
    assert abs(robot.model.inertias[2].mass - 3.5) < 1e-15


# ---------------------------------------------------------------------------------------------
# bad input: one line naming the file, the row and the field


BASE = {"convention": "standard", "length_unit": "m", "angle_unit": "rad"}


def _fails(tmp_path, dh, controller=None) -> str:
    path = write_robot(tmp_path / "bad" / "robot.toml", dh, controller=controller)
    with pytest.raises(FileFormatError) as info:
        load_robot(path)
    text = str(info.value)
    assert "\n" not in text and str(path) in text
    return text


def test_a_row_missing_a_field_names_row_and_field(tmp_path):
    rows = ur_rows("ur5")
    del rows[2]["d"]
    text = _fails(tmp_path, dict(BASE, joints=rows))
    assert "row 3 (j3).d" in text and "missing field d" in text


def test_unknown_convention(tmp_path):
    text = _fails(tmp_path, dict(BASE, convention="craig", joints=ur_rows("ur5")))
    assert "[dh].convention" in text and "'craig'" in text and "modified" in text


def test_unknown_parent(tmp_path):
    rows = ur_rows("ur5")
    rows[3]["parent"] = "j9"
    text = _fails(tmp_path, dict(BASE, joints=rows))
    assert "row 4 (j4).parent" in text and "unknown parent 'j9'" in text


def test_a_joint_on_a_frame_of_a_later_joint(tmp_path):
    rows = ur_rows("ur5")
    rows[1]["parent"] = "elbow_plate"
    frames = [{"name": "elbow_plate", "parent": "j3", "xyz": [0, 0, 0], "rpy": [0, 0, 0]}]
    text = _fails(tmp_path, dict(BASE, joints=rows, frames=frames))
    assert "(elbow_plate).parent" in text and "'j3'" in text and "later in the table" in text


def test_mixed_units(tmp_path):
    rows = ur_rows("ur5")
    rows[1]["a_mm"] = rows[1].pop("a") * 1e3
    text = _fails(tmp_path, dict(BASE, joints=rows))
    assert "row 2 (j2).a_mm" in text and "mixed units" in text


def test_missing_unit_and_unknown_field(tmp_path):
    text = _fails(tmp_path, {"convention": "standard", "angle_unit": "rad",
                             "joints": ur_rows("ur5")})
    assert "[dh].length_unit" in text
    rows = ur_rows("ur5")
    rows[0]["alpah"] = 0.0
    assert "row 1 (j1).alpah" in _fails(tmp_path, dict(BASE, joints=rows))


def _controller(chain: dict, coordinates=None) -> dict:
    return {"coordinates": coordinates or [f"J{i}" for i in range(1, 7)], "chain": chain}


def test_coupling_that_loses_coordinates(tmp_path):
    """More coordinates than chain joints, a coordinate no joint uses, two coordinates only
    ever moved together: one line naming the coordinates lost (A without full column rank)."""
    dh = dict(BASE, joints=ur_rows("ur5"))
    chain = {f"j{i}": f"J{i}" for i in range(1, 7)}
    text = _fails(tmp_path, dh, _controller(chain, [f"J{i}" for i in range(1, 8)]))
    assert "[controller].chain" in text and "'J7'" in text and "rank 6 for 7" in text
    singular = dict(chain, j3="J2")
    text = _fails(tmp_path, dh, _controller(singular))
    assert "[controller].chain" in text and "do not determine the coordinates 'J3'" in text
    together = dict(chain, j2="J2 + J3", j3="-J2 - J3")
    text = _fails(tmp_path, dh, _controller(together))
    assert "'J2', 'J3'" in text and "(J2 - J3 moves no chain joint)" in text
    text = _fails(tmp_path, dh, _controller(dict(chain, j3="J2 * J3")))
    assert "[controller].chain.j3" in text and "not linear" in text
    text = _fails(tmp_path, dh, _controller(dict(chain, j3="__import__('os')")))
    assert "[controller].chain.j3" in text and "not allowed" in text
    text = _fails(tmp_path, dh, _controller(dict(chain, j3="J2 + K3")))
    assert "'K3' is not a controller coordinate" in text
    missing = dict(chain)
    del missing["j6"]
    assert "[controller].chain.j6" in _fails(tmp_path, dh, _controller(missing))


def test_the_coupling_constant_is_in_the_angle_unit(tmp_path):
    dh = dict(BASE, angle_unit="deg", joints=[dict(r, alpha=math.degrees(r["alpha"]))
                                              for r in ur_rows("ur5")])
    chain = {f"j{i}": f"J{i}" for i in range(1, 7)}
    chain["j6"] = "-J6 + 90"
    robot = load_robot(write_robot(tmp_path / "c" / "robot.toml", dh,
                                   controller=_controller(chain)))
    q = robot.configuration(np.full(6, 0.2))
    assert abs(q[5] - (math.pi / 2 - 0.2)) < 1e-15
    with pytest.raises(StiffnessError, match="compliant joint 'j1'"):
        load_robot(robot.name, compliant_joints=["j1"])


def test_the_urdf_writer_writes_a_dh_tree(tmp_path):
    """A DH tree with fixed frames and inertias, exported by the one URDF writer and read back
    by Pinocchio's parser: the same hand placements, Jacobian and mass matrix (the chain's
    coordinates: a URDF has no controller coupling)."""
    from stiffness.robot.export import robot_urdf

    rng = np.random.default_rng(9)
    dh, _, rows = tree_description(rng)
    dh["links"] = [dict(parent=r["name"], mass=float(rng.uniform(1, 5)),
                        com=rng.uniform(-0.1, 0.1, 3).tolist(),
                        inertia=[0.05, 0.06, 0.07, 0.001, -0.002, 0.003]) for r in rows]
    path = write_robot(tmp_path / "t" / "robot.toml", dh, {"frame": "l_hand"})
    mine = load_robot(path, compliant_joints=load_robot(path).coordinate_joints)  # every joint
    urdf = tmp_path / "tree-export.urdf"
    urdf.write_text(robot_urdf(mine))
    back = load_robot(urdf, frame="l_hand",
                      compliant_joints=load_robot(urdf, frame="l_hand").coordinate_joints)
    # Pinocchio's URDF parser orders the branches its own way: match joints by name
    at = np.array([back.coordinate_joints.index(n) for n in mine.coordinate_joints])
    assert sorted(back.coordinate_joints) == sorted(mine.coordinate_joints)
    for _ in range(5):
        q = rng.uniform(-2, 2, mine.n_coordinates)
        q_back = np.empty_like(q)
        q_back[at] = q
        a, b = mine.configuration(q), back.configuration(q_back)
        wrench = rng.normal(0, 50, 6)
        sa, sb = target_state(mine, a, wrench), target_state(back, b, wrench)
        assert np.abs(sa.position - sb.position).max() < 1e-12
        assert relative(sb.jacobian[:, at], sa.jacobian) < 1e-12
        assert relative(sb.k_c[np.ix_(at, at)], sa.k_c) < 1e-12
        m_a = pin.crba(mine.model, mine.data, a)
        m_b = pin.crba(back.model, back.data, b)
        m_a, m_b = np.triu(m_a) + np.triu(m_a, 1).T, np.triu(m_b) + np.triu(m_b, 1).T
        assert relative(m_b[np.ix_(at, at)], m_a) < 1e-12


def test_scan_of_the_coupled_sk120_equals_the_loop_scan(tmp_path):
    """The batched route (close_loops, kernels, maps) through the coupling: a workspace scan of
    the DH SK120 equals the closed-loop one, map by map."""
    from stiffness.workspace.engine import load_scan

    axes = ["--axis", "joint2=-60:60:60", "--axis", "joint3=-100:20:60", "--deg", "--quiet",
            "--no-plots"]
    for robot, out in ((str(SK120_DH), "dh"), ("sk120", "loop")):
        assert main(["scan", "--robot", robot, *axes, "--out", str(tmp_path / out)]) == 0
    dh, loop = load_scan(tmp_path / "dh"), load_scan(tmp_path / "loop")
    for key in ("coordinates", "position", "k_c_diagonal", "k_x", "k_x_eigenvalues",
                "critical_factor"):
        assert relative(dh[key], loop[key]) < 1e-10, key
    for key in ("k_c_class", "tangent_class", "k_x_class", "valid"):
        assert np.array_equal(dh[key], loop[key]), key


def test_exact_equilibria_through_the_coupling_equal_the_loop_ones():
    """The exact elastostatic equilibrium moves the coupled chain joints with their controller
    coordinates: the deflections of the closed-loop SK120 (the exact baseline over many rows,
    through the coupling: :func:`test_identify_gives_the_same_stiffness_through_either_sk120`)."""
    from stiffness.mechanics.equilibrium import solve_equilibrium

    loop, dh = load_robot("sk120"), load_robot(SK120_DH)
    k = np.diag(loop.defaults["k_theta_SI"])
    rng = np.random.default_rng(12)
    u = np.deg2rad(rng.uniform([-90, -60, -100, -90, -100, -90], [90, 60, 25, 90, 100, 90],
                               (4, 6)))
    forces = rng.normal(0, 3000, (4, 3))
    q_loop = np.array([loop.configuration(x) for x in u])
    q_dh = np.array([dh.configuration(x) for x in u])
    for i in range(4):
        one_dh = solve_equilibrium(dh, q_dh[i], k, forces[i])
        one_loop = solve_equilibrium(loop, q_loop[i], k, forces[i])
        # deflections of ~5 mm, equal to the loop closure's and the solvers' tolerances
        assert np.abs(one_dh.dx - one_loop.dx).max() < 1e-10  # m
        assert relative(one_dh.dtheta, one_loop.dtheta) < 1e-9


def test_mjcf_export_of_a_coupled_robot(tmp_path):
    """Springs on the chain export as joint springs (the rigid chain joints welded); springs on
    controller coordinates as fixed tendons over the chain joints (tests/test_export.py checks
    them in MuJoCo against the closed-loop SK120)."""
    from stiffness.robot.mjcf import robot_mjcf

    dh = load_robot(SK120_DH)
    with pytest.warns(RobotFileWarning, match="massless links"):  # the example has no links
        xml = robot_mjcf(dh, dict.fromkeys(dh.compliant_joints, 1e6),
                         dh.configuration(np.zeros(6)))
    assert xml.count("<fixed ") == 3 and "stiffness=" not in xml.split("<tendon>")[0]
    text = SK120_DH.read_text().replace('springs_on = "controller"', 'springs_on = "chain"')
    text = text.replace('compliant_joints = ["joint1", "joint2", "joint3"]',
                        'compliant_joints = ["waist", "shoulder", "elbow"]')
    (tmp_path / "robot.toml").write_text(text)
    chain = load_robot(tmp_path / "robot.toml")
    u = np.deg2rad([10.0, 20.0, -30.0, 0.0, -60.0, 90.0])
    with pytest.warns(RobotFileWarning, match="massless links"):  # the example has no links
        xml = robot_mjcf(chain, dict(zip(chain.compliant_joints, [1e6, 2e6, 3e6], strict=True)),
                         chain.configuration(u))
    assert xml.count("<joint ") == 3 and 'stiffness="2000000.0"' in xml
    # springref of the elbow: its chain angle -(q2 + q3)
    elbow = re.search(r'<joint name="elbow"[^>]*springref="([^"]+)"', xml)
    assert elbow is not None and abs(float(elbow.group(1)) - np.deg2rad(10.0)) < 1e-15


def test_millimetres_and_degrees_are_the_same_arm(tmp_path):
    """The ARM table in mm and deg (limits too) equals it in m and rad; a prismatic joint's
    limits are lengths."""
    rows_si = [dict(r, lower=-1.5, upper=1.5) for r in ARM]
    rows_mm = []
    for r in rows_si:
        travel = 1e3 if r["type"] == "prismatic" else 180.0 / math.pi
        rows_mm.append(dict(r, alpha=math.degrees(r["alpha"]), theta=math.degrees(r["theta"]),
                            a=r["a"] * 1e3, d=r["d"] * 1e3, lower=r["lower"] * travel,
                            upper=r["upper"] * travel))
    si = load_robot(write_robot(tmp_path / "si" / "robot.toml", {
        "convention": "standard", "length_unit": "m", "angle_unit": "rad", "joints": rows_si,
        "tool": {"xyz": [0.1, 0.0, 0.2], "rpy": [0.3, 0.0, 0.0]}}))
    mm = load_robot(write_robot(tmp_path / "mm" / "robot.toml", {
        "convention": "standard", "length_unit": "mm", "angle_unit": "deg", "joints": rows_mm,
        "tool": {"xyz": [100.0, 0.0, 200.0], "rpy": [math.degrees(0.3), 0.0, 0.0]}}))
    assert np.allclose(mm.model.lowerPositionLimit, -1.5, rtol=0, atol=1e-15)
    q = np.random.default_rng(1).uniform(-1, 1, 5)
    a, b = target_state(si, si.configuration(q), np.ones(6)), \
        target_state(mm, mm.configuration(q), np.ones(6))
    assert relative(b.jacobian, a.jacobian) < 1e-14 and relative(b.k_c, a.k_c) < 1e-14


def test_compensation_through_the_coupling_equals_the_loop_model(tmp_path, capsys):
    path = tmp_path / "path.csv"
    path.write_text("joint1,joint2,joint3,joint4,joint5,joint6\n-30,10,-50,0,-40,-90\n"
                    "-20,12,-48,0,-42,-90\n")
    rows = {}
    for robot, out in ((str(SK120_DH), "dh.csv"), ("sk120", "loop.csv")):
        assert main(["compensate", "--robot", robot, "--path", str(path), "--deg", "--wrench",
                     "0,0,-2000", "--out", str(tmp_path / out), "--quiet"]) == 0
        text = (tmp_path / out).read_text().splitlines()
        rows[out] = np.array([[float(v) for v in line.split(",")] for line in text[1:]])
    assert relative(rows["dh.csv"], rows["loop.csv"]) < 1e-10
