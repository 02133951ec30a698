"""Defaults a user would choose (issue 30, item 2): an end effector's fingers are not springs,
``--q`` and path files need no value for them, and without ``--q`` the robot's reference
configuration is used, echoed with its source and inside the joint limits.

Checked against example-robot-data itself (its loaders' ``q0``) and the URDF limits.
"""

from __future__ import annotations

import contextlib
import io
import json
import warnings

import numpy as np
import pytest
from example_robot_data import robots_loader

from stiffness.cli.main import main
from stiffness.mechanics.defaults import reference_configuration
from stiffness.mechanics.ik import coordinate_limits
from stiffness.robot.robot import load_robot
from stiffness.robot.sources import resolve_source

#: Arms with an end-effector branch (Panda: fingers; TALOS arm: gripper) and one without
#: (xArm 7), each with the joints of its arm in coordinate order.
ARMS = {
    "panda": [f"panda_joint{i}" for i in range(1, 8)],
    "talos_arm": [f"arm_left_{i}_joint" for i in range(2, 8)],
    "xarm7": [f"joint{i}" for i in range(1, 8)],
}


def run_cli(argv: list[str]) -> tuple[int, str, str]:
    """Exit status, stdout and stderr of ``stiffness ARGV`` run in this process."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


def loader_q0(name: str) -> np.ndarray:
    """example-robot-data's own ``q0`` of ``name`` (its loader class, run in full)."""
    return np.asarray(robots_loader.ROBOTS[name]().robot.q0, dtype=float)


@pytest.mark.parametrize("name", sorted(ARMS))
def test_springs_default_to_the_arm(name):
    robot = load_robot(name)
    assert robot.compliant_joints == tuple(ARMS[name])
    assert robot.chain_joints == tuple(ARMS[name])
    assert set(robot.branch_joints) == set(robot.coordinate_joints) - set(ARMS[name])


@pytest.mark.parametrize("name", sorted(ARMS))
def test_kx_without_q_uses_the_reference_posture(name):
    """``kx`` with only the arm's springs: the echoed q is example-robot-data's q0, inside the
    limits, with its source; no warning."""
    robot = load_robot(name)
    kq = ",".join(["1e5"] * len(ARMS[name]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        code, out, err = run_cli(["kx", "--robot", name, "--kq", kq, "--wrench", "0,0,-100",
                                  "--json"])
    assert code == 0, err
    doc = json.loads(out)
    q = np.array([doc["q_named"][j] for j in robot.coordinate_joints])
    np.testing.assert_allclose(q, robot.coordinates_of(loader_q0(name)), rtol=0, atol=1e-12)
    lo, hi = coordinate_limits(robot)
    assert np.all(q >= lo) and np.all(q <= hi)
    posture = robots_loader.ROBOTS[name].ref_posture
    assert doc["sources"]["q"] == f"robot default (example-robot-data reference posture " \
                                  f"{posture!r})"
    assert doc["compliant_joints"] == ARMS[name]


@pytest.mark.parametrize("name", sorted(ARMS))
def test_arm_values_suffice_for_q_and_path_files(name, tmp_path):
    """``--q`` with one value per arm joint, and a path file with one column per arm joint:
    the fingers keep their reference value."""
    robot = load_robot(name)
    arm = ARMS[name]
    reference = reference_configuration(robot).coords
    lo, hi = coordinate_limits(robot)
    inner = 0.5 * (lo + hi)
    values = [float(inner[robot.coordinate_joints.index(j)]) for j in arm]
    kq = ",".join(["1e5"] * len(arm))
    code, out, err = run_cli(["kx", "--robot", name, "--kq", kq, "--wrench", "0,0,-100",
                              "--q", ",".join(map(repr, values)), "--json"])
    assert code == 0, err
    doc = json.loads(out)
    for joint in robot.coordinate_joints:
        k = robot.coordinate_joints.index(joint)
        expected = values[arm.index(joint)] if joint in arm else reference[k]
        assert doc["q_named"][joint] == pytest.approx(expected, abs=1e-12)
    path = tmp_path / "path.csv"
    at_reference = [float(reference[robot.coordinate_joints.index(j)]) for j in arm]
    path.write_text(",".join(arm) + "\n" + ",".join(map(repr, values)) + "\n"
                    + ",".join(map(repr, at_reference)) + "\n")
    code, out, err = run_cli(["compensate", "--robot", name, "--kq", kq, "--wrench",
                              "0,0,-100", "--path", str(path), "--json"])
    assert code == 0, err
    doc = json.loads(out)
    assert len(doc["rows"]) == 2 and doc["joints"] == list(robot.coordinate_joints)


def test_configuration_outside_the_limits_is_warned_by_joint():
    """The Panda's zero pose: joint 4 is outside [-3.0718, -0.0698] rad."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code, _, err = run_cli(["kx", "--robot", "panda", "--kq", ",".join(["1e5"] * 7),
                                "--wrench", "0,0,-100", "--q", "0,0,0,0,0,0,0"])
    assert code == 0, err
    warned = [str(w.message) for w in caught if "limits" in str(w.message)]
    assert len(warned) == 1 and "panda_joint4 = 0 beyond its limits" in warned[0], warned
    assert "panda_joint1" not in warned[0]


def test_a_urdf_without_reference_takes_the_middle_of_limits_that_exclude_zero():
    """The Panda's URDF read as a file (no example-robot-data reference): the zero pose, with
    joint 4 at the middle of its limits."""
    robot = load_robot(str(resolve_source("panda").urdf))
    reference = reference_configuration(robot)
    lo, hi = coordinate_limits(robot)
    k = robot.coordinate_joints.index("panda_joint4")
    expected = np.zeros(robot.n_coordinates)
    expected[k] = 0.5 * (lo[k] + hi[k])
    np.testing.assert_array_equal(reference.coords, expected)
    assert "panda_joint4 at the middle of its limits" in reference.source
    assert np.all(reference.coords >= lo) and np.all(reference.coords <= hi)


def test_view_path_rows_need_no_finger_values(tmp_path):
    """``view --path``: rows of the Panda's 7 arm joints (deg); the finger keeps its reference."""
    from stiffness.machining.joint_path import read_joint_path

    robot = load_robot("panda")
    path = tmp_path / "path.csv"
    path.write_text("0,-45,0,-135,0,90,45\n10,-40,0,-130,0,92,46\n")
    rows = read_joint_path(path, robot, deg=True).coords
    finger = robot.coordinate_joints.index("panda_finger_joint1")
    reference = reference_configuration(robot).coords
    assert rows.shape == (2, 8) and np.all(rows[:, finger] == reference[finger])
    arm = [robot.coordinate_joints.index(j) for j in ARMS["panda"]]
    np.testing.assert_allclose(rows[1, arm], np.deg2rad([10, -40, 0, -130, 0, 92, 46]))


def test_view_path_cells_are_read_as_the_campaign_readers_read_them(tmp_path):
    """``view --path``: a NaN coordinate was read by numpy (and drawn as nothing), '1_0' was
    refused in numpy's words; each is now one line naming the line of the file, as the
    campaign readers say it; comments and blank lines are skipped."""
    from stiffness.errors import FileFormatError
    from stiffness.machining.joint_path import read_joint_path

    robot = load_robot("panda")
    path = tmp_path / "path.csv"
    path.write_text("# arm joints, deg\n0,-45,0,-135,0,90,45\n\n")
    assert read_joint_path(path, robot, deg=True).coords.shape == (1, 8)
    for bad, words in (("nan", "not a row of finite numbers"), ("1_0", "digit separators"),
                       ("x", "line 2")):
        path.write_text(f"0,-45,0,-135,0,90,45\n10,-40,0,{bad},0,92,46\n")
        with pytest.raises(FileFormatError, match=words) as info:
            read_joint_path(path, robot, deg=True)
        assert "line 2" in str(info.value) and "\n" not in str(info.value)
    path.write_text("0,-45,0,-135,0,90,45\n10,-40,0\n")
    with pytest.raises(FileFormatError, match="line 2"):
        read_joint_path(path, robot, deg=True)


def test_view_path_reads_compensates_path_file(tmp_path):
    """``view --path`` reads ``compensate --path``'s file, its header naming the columns (it
    said 'not a row of finite numbers' on the header line): the docs' UR5 path in degrees, and
    a Panda path by arm joint names, a unit and per-row loads (the finger keeps its
    reference)."""
    from pathlib import Path

    from stiffness.machining.joint_path import read_joint_path

    ur5 = load_robot("ur5")
    docs = Path(__file__).resolve().parents[1] / "docs" / "compensation" / "ur5-path.csv"
    expected = np.deg2rad(np.loadtxt(docs, delimiter=",", skiprows=1))
    np.testing.assert_allclose(read_joint_path(docs, ur5, deg=True).coords, expected,
                               rtol=1e-15)
    panda = load_robot("panda")
    path = tmp_path / "path.csv"
    header = [*ARMS["panda"][:1], f"{ARMS['panda'][1]} [rad]", *ARMS["panda"][2:]]
    path.write_text(",".join(header) + ",fx,fy,fz\n0,-0.8,0,-2.4,0,1.6,0.8,0,0,-10\n")
    rows = read_joint_path(path, panda).coords
    arm = [panda.coordinate_joints.index(j) for j in ARMS["panda"]]
    np.testing.assert_allclose(rows[0, arm], [0, -0.8, 0, -2.4, 0, 1.6, 0.8])
    finger = panda.coordinate_joints.index("panda_finger_joint1")
    assert rows.shape == (1, 8)
    assert rows[0, finger] == reference_configuration(panda).coords[finger]


def test_a_reference_posture_outside_a_revolute_limit_is_moved_by_a_turn_into_it():
    """kinova's posture 'arm_up' has j2s6s200_joint_3 at -1.5707 rad, outside its URDF limits
    [0.3316, 5.9516]; the reference is the same pose with that joint at -1.5707 + 2 pi (the
    target where the loader's q0 puts it, by forward kinematics), so kx warns of no limit."""
    import pinocchio as pin

    robot = load_robot("kinova")
    reference = reference_configuration(robot)
    raw = robot.coordinates_of(loader_q0("kinova"))
    joint = robot.coordinate_joints.index("j2s6s200_joint_3")
    assert raw[joint] == pytest.approx(-1.5707)
    expected = raw.copy()
    expected[joint] += 2 * np.pi
    np.testing.assert_allclose(reference.coords, expected, rtol=0, atol=1e-15)
    assert "j2s6s200_joint_3 moved by whole turns into its limits" in reference.source
    placed = []
    for coords in (raw, reference.coords):
        pin.framesForwardKinematics(robot.model, robot.data, robot.configuration(coords))
        placed.append(robot.data.oMf[robot.target_frame_id].homogeneous.copy())
    np.testing.assert_allclose(placed[0], placed[1], rtol=0, atol=1e-12)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        code, _, err = run_cli(["kx", "--robot", "kinova", "--kq", ",".join(["1e5"] * 6),
                                "--wrench", "0,0,-100", "--json"])
    assert code == 0, err


@pytest.mark.parametrize("read", [("panda_joint1", "panda_joint2", "panda_joint3", "panda_joint4",
                                   "panda_joint5", "panda_joint6", "panda_joint7"),
                                  ("panda_joint1", "panda_joint2", "panda_joint3",
                                   "panda_joint5", "panda_joint6", "panda_joint7")])
def test_import_note_names_only_held_joints_moved_into_their_limits(tmp_path, read):
    """campaign import --kind poses of the Panda's URDF file (its reference: the zero pose with
    joint 4 at the middle of its limits): the note on the coordinates without a column named
    joint 4 at the middle of its limits although the file reads it (FIGAROH's TALOS file named
    arm_right_2 and arm_right_4, both read); it names it only when joint 4 has no column."""
    rng = np.random.default_rng(3)
    lines = [",".join([*read, "tip_x", "tip_y", "tip_z"])]
    lines += [",".join(repr(float(v)) for v in [*rng.uniform(-0.5, -0.1, len(read)),
                                                  *rng.normal(0.4, 0.1, 3)]) for _ in range(5)]
    (tmp_path / "rig.csv").write_text("\n".join(lines) + "\n")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main(["campaign", "import", str(tmp_path / "rig.csv"), "--kind", "poses",
                     "--robot", str(resolve_source("panda").urdf), "--marker", "tip=panda_hand",
                     "--units", "angle=rad,length=m", "--quiet",
                     "--out", str(tmp_path / "c")]) == 0
    notes = [str(w.message) for w in caught if "have no column and are held" in str(w.message)]
    assert len(notes) == 1, [str(w.message) for w in caught]
    if "panda_joint4" in read:
        assert "panda_finger_joint1 at the reference configuration, the zero pose" in notes[0]
        assert "panda_joint4" not in notes[0] and "middle" not in notes[0], notes[0]
    else:
        assert "the zero pose with panda_joint4 at the middle of its limits" in notes[0], notes[0]


@pytest.mark.parametrize(("named", "said"), [
    ("panda_joint4=-1.2", "zero pose"),
    ("panda_joint1=0.1", "zero pose with panda_joint4 at the middle of its limits (zero is "
                         "outside them)")])
def test_q_pairs_echo_names_only_unnamed_joints_moved_into_their_limits(named, said):
    """kx --q name=value on the Panda's URDF file: the echo of the coordinates not named
    named joint 4 at the middle of its limits even when --q gives it."""
    urdf = str(resolve_source("panda").urdf)
    code, out, err = run_cli(["kx", "--robot", urdf, "--kq", ",".join(["1e5"] * 7),
                              "--wrench", "0,0,-100", "--q", named, "--json"])
    assert code == 0, err
    source = json.loads(out)["sources"]["q"]
    assert source == f"flag --q (coordinates not named: {said})", source
