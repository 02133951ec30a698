"""Posture along a path: poses reached, joint steps bounded, never worse than a fixed angle."""

from __future__ import annotations

import json

import numpy as np
import pytest

from stiffness.cli.main import main
from stiffness.elastic.model import ElasticModel
from stiffness.machining.poses import tool_frames
from stiffness.machining.posture import posture
from stiffness.mechanics.formulation import compliance, target_state
from stiffness.robot import kinematics
from stiffness.robot.robot import load_robot

UR5_K = [3e5, 3e5, 2e5, 4e4, 4e4, 4e4]  # N.m/rad
UR5_START = [0.0, -1.57, 1.57, -1.57, -1.57, 0.0]
#: A spindle 0.1 m off the wrist_3 axis: turning about the tool axis moves the wrist.
UR5_OFFSET = [0.1, 0.0, 0.1]


def _line(m):
    return np.column_stack([np.full(m, 0.45), np.linspace(-0.2, 0.2, m), np.full(m, 0.3)])


@pytest.fixture(scope="module")
def ur5_offset():
    return load_robot("ur5", target_offset=UR5_OFFSET)


@pytest.fixture(scope="module")
def ur5_path(ur5_offset):
    """10 points along a line, tool axis down, thrust along the tool axis (300 N). (20 points
    of the same line gave the same largest reduction, 1.1250007, in 1.6 times the CPU; 10 points
    take joint steps up to 5.7 deg, 20 points 2.7 deg, under the bound of 10.)"""
    em = ElasticModel.joint_springs(ur5_offset, UR5_K)
    positions = _line(10)
    axes = np.tile([0.0, 0.0, -1.0], (10, 1))
    result = posture(em, positions, axes=axes, wrench=[0.0, 0.0, 300.0], steps=36,
                     max_step_deg=10.0, start=UR5_START)
    return em, positions, axes, result


def test_every_configuration_reaches_its_pose(ur5_path):
    em, positions, axes, result = ur5_path
    robot = em.robot
    frames = tool_frames(np.array([0.0, 0.0, 1.0]), axes=axes)
    for i, p in enumerate(result.points):
        q = robot.configuration(p.coords)
        kinematics.update_first_order(robot.model, robot.data, q)
        m = robot.data.oMf[robot.target_frame_id]
        assert np.linalg.norm(m.translation - positions[i]) < 1e-9
        # the free axis points along the tool axis, and the angle is the reported one
        assert np.linalg.norm(m.rotation[:, 2] - axes[i]) < 1e-9
        rel = frames[i].T @ m.rotation
        assert abs(np.arctan2(rel[1, 0], rel[0, 0]) - p.angle) < 1e-9 or abs(
            abs(np.arctan2(rel[1, 0], rel[0, 0]) - p.angle) - 2 * np.pi) < 1e-9
        assert p.ik_position_error < 1e-9 and p.ik_rotation_error < 1e-9


def test_joint_steps_respect_the_bound(ur5_path):
    _, _, _, result = ur5_path
    steps = np.abs(np.diff(result.joint_path(), axis=0))
    assert steps.max() <= np.deg2rad(10.0) + 1e-9


def test_never_worse_than_the_fixed_angle_and_measurably_better(ur5_path):
    em, _, _, result = ur5_path
    k = np.diag(UR5_K)
    wrench = np.array([0.0, 0.0, 300.0])
    for p in result.points:
        # the reported deflection is the model's compliance times the load (independent path)
        state = target_state(em.robot, em.robot.configuration(p.coords), wrench)
        expected = compliance(state.jacobian[:3], k - state.k_c[:6, :6]) @ wrench
        np.testing.assert_allclose(p.deflection, expected, rtol=1e-9, atol=1e-15)
        assert np.linalg.norm(p.deflection) <= np.linalg.norm(p.deflection_fixed) * (1 + 1e-12)
    s = result.summary()
    # measured on this path: 1.125 (as on 20 and 50 points of the same line)
    assert s["max_reduction_factor"] > 1.05, s
    assert s["max_deflection_m"] < s["max_deflection_fixed_m"]


def test_redundant_arm_uses_its_null_space():
    """Panda (7 arm joints): the chosen postures are local minima along the self-motion."""
    from stiffness.elastic.loaded import linear_deflection
    from stiffness.mechanics.ik import solve_ik

    arm = [f"panda_joint{i}" for i in range(1, 8)]
    robot = load_robot("panda", frame="panda_hand", target_offset=[0.05, 0.0, 0.1],
                       compliant_joints=arm)
    em = ElasticModel.joint_springs(robot, [2e5, 2e5, 1.5e5, 1.5e5, 3e4, 3e4, 3e4])
    positions = np.column_stack([np.full(4, 0.5), np.linspace(-0.1, 0.1, 4), np.full(4, 0.3)])
    axes = np.tile([0.0, 0.0, -1.0], (4, 1))
    start = np.zeros(robot.n_coordinates)
    start[:7] = [0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8]
    wrench = [0.0, 0.0, 200.0]
    kwargs = dict(axes=axes, wrench=wrench, steps=8, max_step_deg=30.0,
                  reference_angle_deg=45.0, start=start)
    result = posture(em, positions, **kwargs)
    coarse = posture(em, positions, refine=False, **kwargs)
    assert result.summary()["fixed_reachable_points"] == 4
    full = em.full
    for i, (p, c) in enumerate(zip(result.points, coarse.points, strict=True)):
        q = robot.configuration(p.coords)
        kinematics.update_first_order(robot.model, robot.data, q)
        m = robot.data.oMf[robot.target_frame_id]
        assert np.linalg.norm(m.translation - positions[i]) < 1e-9
        assert np.linalg.norm(m.rotation[:, 2] - axes[i]) < 1e-9
        d = np.linalg.norm(p.deflection)
        assert d <= np.linalg.norm(p.deflection_fixed) * (1 + 1e-12)
        assert d <= np.linalg.norm(c.deflection) * (1 + 1e-12)
        # moving along the self-motion (pose held, re-projected by IK) does not lower it
        jac = target_state(full, q).jacobian[:, :7]
        null = np.linalg.svd(jac)[2][-1]
        for s in (-0.03, 0.03):
            seed = p.coords.copy()
            seed[:7] += s * null
            moved = solve_ik(full, m.translation, m.rotation, seed=seed, seed_q=q)
            other = np.linalg.norm(linear_deflection(em, moved.coords, wrench)[:3])
            assert other >= d * (1 - 1e-6)
    # the refinement (angle and null space) buys something over the candidates alone
    assert result.summary()["max_deflection_m"] < 0.97 * coarse.summary()["max_deflection_m"]
    assert np.abs(np.diff(result.joint_path(), axis=0)).max() <= np.deg2rad(30.0) + 1e-9


def _write_poses(path, positions, axes):
    lines = ["x,y,z,ax,ay,az"] + [",".join(repr(float(v)) for v in [*p, *a])
                                  for p, a in zip(positions, axes, strict=True)]
    path.write_text("\n".join(lines) + "\n")


def test_command_writes_path_figure_and_json(tmp_path, capsys):
    poses = tmp_path / "poses.csv"
    _write_poses(poses, _line(4), np.tile([0.0, 0.0, -1.0], (4, 1)))
    out = tmp_path / "out.csv"
    code = main(["posture", "--robot", "ur5", "--target-offset", "0.1,0,0.1", "--kq",
                 ",".join(map(str, UR5_K)), "--path", str(poses), "--wrench", "0,0,300",
                 "--steps", "12", "--max-step", "20", "--start", "0,-90,90,-90,-90,0", "--deg",
                 "--out", str(out), "--json", "--quiet"])
    assert code == 0
    doc = json.loads(capsys.readouterr().out)
    assert {"rows", "summary", "units"} <= set(doc)
    assert len(doc["rows"]) == 4 and doc["units"]["q"][0] == "deg"
    header = out.read_text().splitlines()[0].split(",")
    assert header[:6] == ["x", "y", "z", "ax", "ay", "az"]
    assert header[-6:] == ["angle_deg", "deflection_m", "deflection_fixed_m", "ik_residual_m",
                           "ik_residual_rad", "branch"]
    assert (tmp_path / "out.png").read_bytes()[:4] == b"\x89PNG"


def test_point_out_of_reach_is_named_and_nothing_written(tmp_path, capsys):
    positions = _line(3)
    positions[1] = [3.0, 0.0, 0.3]
    poses = tmp_path / "poses.csv"
    _write_poses(poses, positions, np.tile([0.0, 0.0, -1.0], (3, 1)))
    out = tmp_path / "out.csv"
    code = main(["posture", "--robot", "ur5", "--kq", ",".join(map(str, UR5_K)), "--path",
                 str(poses), "--wrench", "0,0,300", "--steps", "4", "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "row 2" in err and "out of reach" in err and "\n" not in err
    assert not out.exists() and not (tmp_path / "out.png").exists()


@pytest.mark.parametrize("case", ["missing", "nan", "both_orientations", "other_robot"])
def test_bad_pose_files_one_line(case, tmp_path, capsys):
    poses = tmp_path / "poses.csv"
    rows = "0.45,0.0,0.3,0,0,-1\n0.45,0.1,0.3,0,0,-1\n"
    args = ["--robot", "ur5", "--kq", ",".join(map(str, UR5_K))]
    expect = {"missing": "lacks the column(s) z", "nan": "line 3, column 2 (y)",
              "both_orientations": "exactly one of", "other_robot": "not 'sk120'"}[case]
    if case == "missing":
        poses.write_text("x,y,ax,ay,az\n0.45,0.0,0,0,-1\n")
    elif case == "nan":
        poses.write_text("x,y,z,ax,ay,az\n" + rows.replace("0.1", "nan"))
    elif case == "both_orientations":
        poses.write_text("x,y,z,ax,ay,az,qw,qx,qy,qz\n0.45,0,0.3,0,0,-1,1,0,0,0\n")
    else:
        poses.write_text("x,y,z,ax,ay,az\n" + rows)
        model = tmp_path / "m.json"
        model.write_text(json.dumps({
            "format": "stiffness-identified-model", "version": 1, "campaign": "t",
            "robot": {"source": "ur5", "frame": "tool0", "target_offset_m": [0, 0, 0],
                      "compliant_joints": ["shoulder_pan_joint"]},
            "formulation": "enhanced",
            "k_theta": {"joints": ["shoulder_pan_joint"], "values": [1e5], "unit": ["N.m/rad"]},
            "standard_error": [None], "ci95": {"low": [None], "high": [None]},
            "undetermined_joints": [], "residual_norm": {"eq12_m2": 0, "eq12_mm2": 0}}))
        args = ["--robot", "sk120", "--model", str(model)]
    out = tmp_path / "out.csv"
    code = main(["posture", *args, "--path", str(poses), "--wrench", "0,0,300", "--out",
                 str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and expect in err and "\n" not in err, err
    assert not out.exists()


def test_more_steps_than_the_search_can_take_are_refused(tmp_path, capsys):
    poses = tmp_path / "poses.csv"
    _write_poses(poses, _line(2), np.tile([0.0, 0.0, -1.0], (2, 1)))
    out = tmp_path / "out.csv"
    code = main(["posture", "--robot", "ur5", "--kq", ",".join(map(str, UR5_K)), "--path",
                 str(poses), "--wrench", "0,0,300", "--steps", "3601", "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "--steps 3601 is more than 3600" in err and "\n" not in err, err
    assert not out.exists()


def test_pose_columns_may_name_their_unit_in_brackets(tmp_path):
    """`x [m]`, `fx [N]` are those columns (read as without units, written back as given);
    `x [mm]` is refused with its fix. They were 'lacks the column(s) x, y, z'."""
    from stiffness.errors import FileFormatError
    from stiffness.machining.poses import read_poses

    rows = "0.45,-0.2,0.3,0,0,-1,1,2,-30\n0.45,-0.19,0.3,0,0,-1,1,2,-30\n"
    (tmp_path / "a.csv").write_text("x,y,z,ax,ay,az,fx,fy,fz\n" + rows)
    header = "x [m],y [m],z [m],ax,ay,az,fx [N],fy,fz"
    (tmp_path / "b.csv").write_text(header + "\n" + rows)
    plain, read = read_poses(tmp_path / "a.csv"), read_poses(tmp_path / "b.csv")
    np.testing.assert_array_equal(read.positions, plain.positions)
    np.testing.assert_array_equal(read.wrench, plain.wrench)
    assert read.header == header.split(",")
    (tmp_path / "c.csv").write_text(header.replace("x [m]", "x [mm]") + "\n" + rows)
    with pytest.raises(FileFormatError, match=r"line 1, column 1 \(x \[mm\]\): the header says "
                       "mm but x is read in m; convert the column to m"):
        read_poses(tmp_path / "c.csv")


def test_joint_step_is_degrees_of_revolute_and_metres_of_prismatic_joints():
    # the hexapod's legs (all prismatic) moved 2.4 mm and were reported as 0.138 deg
    from stiffness.machining.posture import PosturePoint, PostureResult

    def point(coords):
        return PosturePoint(np.array(coords), 0.0, np.zeros(3), np.zeros(3), 0.0, 0.0, "A",
                            q=np.array(coords))

    path = [[0.1, 0.70], [0.101, 0.75], [0.1005, 0.72]]  # a turn (rad), a slide (m)
    result = PostureResult([point(c) for c in path], ("turn", "slide"), 0.0, np.zeros(1),
                           np.deg2rad(10.0), [], None, np.array([True, False]), {})
    summary = result.summary()
    assert summary["max_joint_step_deg"] == pytest.approx(np.rad2deg(0.001), rel=1e-9)
    assert summary["max_joint_step_m"] == pytest.approx(0.05, rel=1e-9)


def test_a_loop_whose_zero_does_not_close_starts_from_its_assembly(tmp_path):
    """The hexapod's URDF and loop file without its robot.toml: no shipped coordinates, and
    zero leg lengths do not assemble. posture started its search at zero (a LoopClosureError
    out of the first IK) where every other command starts at the assembly found near zero
    (assembly_coordinates). At the home pose (0, 0, 0.6) m, level, the legs are the
    robot.toml's home lengths, 0.719285458839 m."""
    import shutil

    from stiffness.mechanics.defaults import default_coordinates
    from stiffness.robot.sources import robots_directory

    for name in ("hexapod.urdf", "hexapod.loops.yaml"):
        shutil.copy(robots_directory() / "hexapod" / name, tmp_path / name)
    robot = load_robot(str(tmp_path / "hexapod.urdf"), frame="platform",
                       loops=str(tmp_path / "hexapod.loops.yaml"))
    assert default_coordinates(robot) is None
    em = ElasticModel.joint_springs(robot, [1e7] * 6)
    result = posture(em, np.array([[0.0, 0.0, 0.6]]), axes=np.array([[0.0, 0.0, 1.0]]),
                     wrench=[0.0, 0.0, -300.0], steps=1, refine=False)
    np.testing.assert_allclose(result.points[0].coords, np.full(6, 0.719285458839), atol=1e-9)
