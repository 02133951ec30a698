"""Deflection compensation: exact commands checked by an independent root finder.

The independent check solves the torque balance ``law^-1(theta - theta_c) = J(theta)^T W`` with
scipy's root finder, ``J`` by central finite differences of the forward kinematics (loops closed
by :meth:`Robot.configuration`), never with the toolkit's equilibrium solver.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from scipy.optimize import root

from stiffness.elastic.effects.geometry import Geometry, link_axes
from stiffness.elastic.effects.link_bends import LinkCompliance
from stiffness.elastic.effects.parts import ElasticParts
from stiffness.elastic.loaded import LinkBend, loaded_equilibrium
from stiffness.elastic.model import ElasticModel
from stiffness.errors import StiffnessError
from stiffness.machining.compensation import compensate
from stiffness.mechanics.equilibrium import solve_equilibrium
from stiffness.mechanics.formulation import target_state
from stiffness.mechanics.ik import all_coordinates
from stiffness.robot import kinematics
from stiffness.robot.robot import load_robot

UR5_K = [3e5, 3e5, 2e5, 4e4, 4e4, 4e4]  # N.m/rad
UR5_PATH = np.array([[0.1, -1.2, 1.5, -0.3, 1.57, 0.2],
                     [0.4, -1.0, 1.2, -0.6, 1.3, 0.5]])


@pytest.fixture(scope="module")
def ur5():
    return load_robot("ur5")


@pytest.fixture(scope="module")
def sk120():
    return load_robot("sk120")


def _fk(robot, coords, seed):
    q = robot.configuration(coords, seed=seed)
    kinematics.update_first_order(robot.model, robot.data, q)
    m = robot.data.oMf[robot.target_frame_id]
    return m.translation.copy(), m.rotation.copy()


def _fd_jacobian(robot, coords, seed, columns, h=1e-6):
    """(6, k) FD Jacobian of the target (position; rotation vector) w.r.t. ``columns``."""
    out = []
    for i in columns:
        cp, cm = coords.copy(), coords.copy()
        cp[i] += h
        cm[i] -= h
        (pp, rp), (pm, rm) = _fk(robot, cp, seed), _fk(robot, cm, seed)
        out.append(np.concatenate([(pp - pm) / (2 * h), pin.log3(rp @ rm.T) / (2 * h)]))
    return np.array(out).T


def _independent_equilibrium(robot, command, k, wrench, seed):
    """Equilibrium coordinates of the springs ``k`` on the compliant joints at rest at
    ``command`` (rigid coordinates held), by scipy's root finder on the torque balance."""
    cols = robot.compliant_in_coordinates

    def balance(theta):
        coords = command.copy()
        coords[cols] = theta
        jac = _fd_jacobian(robot, coords, seed, cols)
        return k * (theta - command[cols]) - jac.T @ wrench

    sol = root(balance, command[cols], method="hybr", tol=1e-14)
    # the FD Jacobian is noisy at the 1e-14 level: judge by the torque balance itself
    assert np.abs(balance(sol.x)).max() / k.min() < 1e-12, sol.message
    coords = command.copy()
    coords[cols] = sol.x
    return coords


@pytest.mark.parametrize("case", ["ur5", "sk120"])
def test_exact_command_puts_target_on_nominal_pose(case, ur5, sk120):
    if case == "ur5":
        robot, k, path = ur5, np.array(UR5_K), UR5_PATH
        wrench = np.array([120.0, -80.0, -300.0, 4.0, -3.0, 2.0])
    else:
        robot, k = sk120, np.array(sk120.defaults["k_theta_SI"])
        c = np.deg2rad(sk120.defaults["q_deg"])
        path = np.array([c, c + np.deg2rad([10.0, 5.0, -8.0, 0.0, 0.0, 0.0])])
        wrench = np.array([45.5, 364.5, 211.3, 0.0, 0.0, 0.0])
    result = compensate(ElasticModel.joint_springs(robot, k), path, wrench)
    assert result.hold == "pose"
    for point, nominal in zip(result.points, path, strict=True):
        seed = point.q_nominal
        coords = _independent_equilibrium(robot, point.command, k, wrench, seed)
        p, r = _fk(robot, coords, seed)
        p_n, r_n = _fk(robot, nominal, seed)
        assert np.linalg.norm(p - p_n) < 1e-9
        assert np.linalg.norm(pin.log3(r @ r_n.T)) < 1e-9
        # the deflection it cancels is real (the uncompensated equilibrium moves the target)
        free = _independent_equilibrium(robot, nominal.copy(), k, wrench, seed)
        moved = _fk(robot, free, seed)[0] - p_n
        assert np.linalg.norm(moved) > 1e-4
        np.testing.assert_allclose(point.deflection, moved, atol=1e-9)
        assert np.linalg.norm(point.residual) < 1e-9


@settings(max_examples=12, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(coords=st.lists(st.floats(-2.5, 2.5), min_size=6, max_size=6),
       force=st.lists(st.floats(-400.0, 400.0), min_size=3, max_size=3),
       moment=st.lists(st.floats(-10.0, 10.0), min_size=3, max_size=3))
def test_closed_form_holds_for_any_pose_and_wrench(ur5, coords, force, moment):
    """For every configuration and wrench, the independent root finder rests the loaded UR5
    on the nominal pose at the closed-form command."""
    coords = np.array(coords)
    jac = _fd_jacobian(ur5, coords, None, range(6))
    assume(np.linalg.svd(jac, compute_uv=False)[-1] > 0.05)  # away from singularities
    wrench = np.array(force + moment)
    point = compensate(ElasticModel.joint_springs(ur5, UR5_K), coords[None], wrench).points[0]
    rest = _independent_equilibrium(ur5, point.command, np.array(UR5_K), wrench, None)
    p, r = _fk(ur5, rest, None)
    p_n, r_n = _fk(ur5, coords, None)
    assert np.linalg.norm(p - p_n) < 1e-9
    assert np.linalg.norm(pin.log3(r @ r_n.T)) < 1e-9


def test_first_order_residual_grows_as_the_square_of_the_load(ur5):
    em = ElasticModel.joint_springs(ur5, UR5_K)
    scales = np.geomspace(0.1, 1.0, 5)
    base = np.array([150.0, -100.0, -400.0])
    err = [np.linalg.norm(compensate(em, UR5_PATH[:1], s * base).points[0].residual_first_order)
           for s in scales]
    rate = np.polyfit(np.log(scales), np.log(err), 1)[0]
    assert 1.9 < rate < 2.1, rate
    assert err[-1] > 1e-8  # the first-order residual is not negligible at full load


def test_general_solver_agrees_with_the_closed_form_for_a_nonlinear_law(ur5):
    em = ElasticModel.joint_springs(ur5, UR5_K)
    em.law.beta[:] = [2e-3, 1e-3, -5e-4, 0.0, 3e-3, 0.0]
    em.law.backlash[1] = 2e-4
    em.law.smoothing[:] = 5.0
    wrench = [100.0, 50.0, -300.0]
    closed = compensate(em, UR5_PATH, wrench, method="closed-form")
    general = compensate(em, UR5_PATH, wrench, method="general")
    for a, b in zip(closed.points, general.points, strict=True):
        assert b.iterations >= 2  # the general solver starts from the uncompensated command
        np.testing.assert_allclose(a.command, b.command, atol=1e-11)
        assert np.linalg.norm(a.residual) < 1e-9


def _ur5_link_model(ur5):
    geometry = Geometry.of(ur5)
    a, b = "shoulder_lift_joint", "elbow_joint"
    joints = ElasticModel.joint_springs(ur5, UR5_K)
    bend = LinkBend(a, b, geometry.link_columns[(a, b)], (1.5e5, 8e4))
    return joints, ElasticModel(ur5, joints.law, (bend,)), geometry


def test_link_compliance_needs_the_general_solver(ur5):
    joints, linked, _ = _ur5_link_model(ur5)
    wrench = [100.0, 0.0, -300.0]
    general = compensate(linked, UR5_PATH, wrench)
    closed = compensate(joints, UR5_PATH, wrench)
    for g, c, nominal in zip(general.points, closed.points, UR5_PATH, strict=True):
        assert g.method == "general"
        assert np.linalg.norm(g.residual) < 1e-9
        assert np.linalg.norm(g.rotation_residual) < 1e-9
        # the joint-only closed form, loaded on the model with the link, leaves its bend
        left = loaded_equilibrium(linked, c.command, wrench, seed_q=c.q_nominal)
        p_n = _fk(ur5, nominal, c.q_nominal)[0]
        assert np.linalg.norm(left.position - p_n) > 1e-4


def test_a_method_the_model_cannot_take_is_refused_naming_its_bends_not_a_row(ur5):
    """method='closed-form' on a model that bends beyond its joints: one line naming the
    bends (a bearing tilt was called 'link compliance') and no path row (it said 'path row
    1: ...', though no row is at fault)."""
    from stiffness.elastic.model import _tilt_column

    _, linked, _ = _ur5_link_model(ur5)
    tilt = LinkBend("elbow_joint", "elbow_joint", _tilt_column(ur5, "elbow_joint"), (1e6, 1e6),
                    tilt=True)
    both = ElasticModel(ur5, linked.law, (*linked.links, tilt))
    with pytest.raises(StiffnessError) as info:
        compensate(both, UR5_PATH, [0.0, 0.0, -100.0], method="closed-form")
    assert str(info.value) == (
        "the closed form holds for joint compliance only; this model bends beyond its joints "
        "(link bend shoulder_lift_joint->elbow_joint, transversal compliance elbow_joint): use "
        "method 'general'")


def test_link_bend_matches_the_effect_library_to_first_order(ur5):
    """The exact bend at a small load equals the library's linear link-compliance term."""
    joints, linked, geometry = _ur5_link_model(ur5)
    bend = linked.links[0]
    force = np.array([10.0, -5.0, -20.0])
    coords = UR5_PATH[0]
    with_link = loaded_equilibrium(linked, coords, force)
    without = loaded_equilibrium(joints, coords, force)
    full = all_coordinates(ur5)
    q = full.configuration(coords)
    kinematics.update_first_order(full.model, full.data, q)
    data, model = full.data, full.model
    ja, jb = model.getJointId(bend.a), model.getJointId(bend.b)
    p_b = data.oMi[jb].translation
    e1, e2 = link_axes(data.oMi[ja].translation, p_b, data.oMi[model.parents[jb]].rotation,
                       bend.column)
    r = data.oMf[full.target_frame_id].translation - p_b
    m_b = np.cross(r, force)
    omega = e1 * (e1 @ m_b) / bend.stiffness[0] + e2 * (e2 @ m_b) / bend.stiffness[1]
    linear = np.cross(omega, r)
    assert LinkCompliance.name == "link_compliance"
    extra = with_link.position - without.position
    assert np.linalg.norm(extra - linear) < 0.02 * np.linalg.norm(linear)


@pytest.mark.parametrize("case", ["ur5", "sk120"])
def test_bent_jacobian_matches_finite_differences(case, ur5, sk120):
    """The exact Jacobian of the bent target w.r.t. coordinates and bend angles, on a serial arm
    and through the SK120's loop (the bend joint2->elbow has a passive joint at its end)."""
    from stiffness.elastic.loaded import bent_kinematics, frozen_axes

    if case == "ur5":
        _, linked, _ = _ur5_link_model(ur5)
        c = UR5_PATH[1]
    else:
        springs = ElasticModel.joint_springs(sk120, sk120.defaults["k_theta_SI"])
        column = Geometry.of(sk120).link_columns[("joint2", "elbow")]
        linked = ElasticModel(sk120, springs.law, (LinkBend("joint2", "elbow", column,
                                                            (2e6, 1e6)),))
        c = np.deg2rad(sk120.defaults["q_deg"])
    links = linked.ordered_links()
    q = linked.full.configuration(c)
    kinematics.update_first_order(linked.full.model, linked.full.data, q)
    axes = frozen_axes(linked, links)
    z = np.concatenate([c, [0.01, -0.02]])
    wrench = np.zeros(6)
    kin = bent_kinematics(linked, links, axes, z[:6], z[6:], wrench, q)
    h, fd = 1e-5, []
    for i in range(z.shape[0]):
        zp, zm = z.copy(), z.copy()
        zp[i] += h
        zm[i] -= h
        kp = bent_kinematics(linked, links, axes, zp[:6], zp[6:], wrench, q)
        km = bent_kinematics(linked, links, axes, zm[:6], zm[6:], wrench, q)
        fd.append(np.concatenate([(kp.position - km.position) / (2 * h),
                                  pin.log3(kp.rotation @ km.rotation.T) / (2 * h)]))
    np.testing.assert_allclose(np.array(fd).T, kin.jac, atol=1e-8)


# ------------------------------------------------------------------------------ the command

JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
          "wrist_2_joint", "wrist_3_joint"]


def _identified_model(path, source="ur5", frame="tool0", joints=JOINTS, k=UR5_K):
    import json

    n = len(joints)
    path.write_text(json.dumps({
        "format": "stiffness-identified-model", "version": 1, "campaign": "test",
        "robot": {"source": source, "frame": frame, "target_offset_m": [0.0, 0.0, 0.0],
                  "compliant_joints": joints},
        "formulation": "enhanced",
        "k_theta": {"joints": joints, "values": k, "unit": ["N.m/rad"] * n},
        "standard_error": [None] * n, "ci95": {"low": [None] * n, "high": [None] * n},
        "undetermined_joints": [], "residual_norm": {"eq12_m2": 0.0, "eq12_mm2": 0.0}}))
    return path


def _path_csv(path, rows, header=None, deg=True):
    header = header or [f"q{i + 1}" for i in range(6)]
    values = np.rad2deg(rows) if deg else rows
    path.write_text(",".join(header) + "\n" + "\n".join(
        ",".join(repr(float(v)) for v in r) for r in values) + "\n")
    return path


def test_command_csv_and_json(tmp_path, capsys):
    import json

    from stiffness.cli.main import main

    model = _identified_model(tmp_path / "m.json")
    path = _path_csv(tmp_path / "p.csv", UR5_PATH)
    out = tmp_path / "out.csv"
    code = main(["compensate", "--model", str(model), "--path", str(path), "--deg",
                 "--wrench", "0,0,-300", "--out", str(out), "--json", "--quiet"])
    assert code == 0
    doc = json.loads(capsys.readouterr().out)
    assert set(doc["summary"]) >= {"max_deflection_m", "rms_deflection_m", "max_residual_m",
                                   "max_residual_first_order_m"}
    assert set(doc["rows"][0]) >= {"q_command", "deflection", "residual",
                                   "residual_first_order"}
    assert "units" in doc and doc["units"]["q_command"][0] == "deg"
    lines = out.read_text().splitlines()
    assert lines[0].split(",") == ([f"q{i + 1}" for i in range(6)]
                                   + [f"{j}_cmd" for j in JOINTS]
                                   + [f"q{i + 1}_cmd" for i in range(6)]
                                   + ["dx", "dy", "dz", "ex", "ey", "ez", "ex1", "ey1", "ez1"])
    assert len(lines) == 1 + len(UR5_PATH)
    # the commands written (deg) are the library's commands
    expected = compensate(ElasticModel.joint_springs(load_robot("ur5"), UR5_K), UR5_PATH,
                          [0.0, 0.0, -300.0])
    cmd = np.array([float(v) for v in lines[1].split(",")[6:12]])
    np.testing.assert_array_equal(cmd, [float(v) for v in lines[1].split(",")[12:18]])
    np.testing.assert_allclose(np.deg2rad(cmd), expected.points[0].command, atol=1e-12)
    assert doc["summary"]["max_residual_m"] < 1e-9


def test_per_row_wrench_columns(tmp_path, capsys):
    import json

    from stiffness.cli.main import main

    model = _identified_model(tmp_path / "m.json")
    rows = np.hstack([UR5_PATH[[0, 0]], [[0.0, 0.0, -300.0], [0.0, 0.0, -150.0]]])
    path = tmp_path / "p.csv"
    path.write_text("shoulder_pan_joint,shoulder_lift_joint,elbow_joint,wrist_1_joint,"
                    "wrist_2_joint,wrist_3_joint,fx,fy,fz\n" + "\n".join(
                        ",".join(repr(float(v)) for v in r) for r in rows) + "\n")
    assert main(["compensate", "--model", str(model), "--path", str(path), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    d = [np.linalg.norm(r["deflection"]) for r in doc["rows"]]
    assert abs(d[1] / d[0] - 0.5) < 0.01  # the same point at half the load


@pytest.mark.parametrize("case", ["missing", "nan", "other_robot", "bad_wrench", "out_of_reach",
                                  "latin1"])
def test_bad_input_one_line_and_nothing_written(case, tmp_path, capsys):
    from stiffness.cli.main import main

    model = _identified_model(tmp_path / "m.json")
    path = _path_csv(tmp_path / "p.csv", UR5_PATH)
    wrench = "0,0,-300"
    if case == "missing":
        path = _path_csv(tmp_path / "p.csv", UR5_PATH[:, :5], header=[f"q{i}" for i in
                                                                         range(1, 6)])
        expect = "q6"
    elif case == "nan":
        rows = UR5_PATH.copy()
        rows[1, 2] = np.nan
        path = _path_csv(tmp_path / "p.csv", rows)
        expect = "line 3, column 3 (q3)"
    elif case == "other_robot":
        model = _identified_model(tmp_path / "m.json", source="sk120", frame="fixture_target",
                                  joints=["joint1", "joint2", "joint3"],
                                  k=[1.4e6, 4.0e5, 9.3e5])
        path = _path_csv(tmp_path / "p.csv", UR5_PATH, header=JOINTS)
        expect = "another robot"
    elif case == "bad_wrench":
        wrench = "0,0,-300,1"
        expect = "wrench"
    elif case == "latin1":  # a comment saved in latin-1, as the campaign reader refuses it
        text = _path_csv(tmp_path / "p.csv", UR5_PATH).read_text()
        path.write_bytes("# caf\u00e9\n".encode("latin-1") + text.encode())
        expect = "not UTF-8 text (byte 5); save the path file as UTF-8"
    else:
        rows = UR5_PATH.copy()
        rows[1, 2] = np.deg2rad(200.0)  # the elbow turns +-180 deg
        path = _path_csv(tmp_path / "p.csv", rows)
        expect = "path row 2: elbow_joint"
    out = tmp_path / "out.csv"
    code = main(["compensate", "--model", str(model), "--path", str(path), "--deg",
                 "--wrench", wrench, "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and expect in err and "\n" not in err, err
    assert not out.exists()
    assert not list(tmp_path.glob(".out.csv*"))


def test_bad_path_errors_are_typed(tmp_path, ur5):
    from stiffness.errors import (
        ConvergenceError,
        FileFormatError,
        MissingFileError,
        UnstableEquilibriumError,
    )
    from stiffness.machining.joint_path import read_joint_path

    rows = UR5_PATH.copy()
    rows[1, 2] = np.nan
    with pytest.raises(FileFormatError) as info:
        read_joint_path(_path_csv(tmp_path / "p.csv", rows), ur5, deg=True)
    assert (info.value.line, info.value.column, info.value.field) == (3, 3, "q3")
    with pytest.raises(MissingFileError):
        read_joint_path(tmp_path / "absent.csv", ur5)
    # a column given twice: which one is the joint's is not the reader's guess to make
    twice = np.column_stack([UR5_PATH, UR5_PATH[:, 1]])
    with pytest.raises(FileFormatError, match=r"line 1, column 7: the column 'q2' appears "
                       r"twice \(columns 2 and 7\)"):
        read_joint_path(_path_csv(tmp_path / "p2.csv", twice,
                                  [f"q{i + 1}" for i in range(6)] + ["q2"]), ur5, deg=True)
    # a load beyond what the springs hold: a typed solver error naming the row
    soft = ElasticModel.joint_springs(ur5, [30.0] * 6)
    with pytest.raises((ConvergenceError, UnstableEquilibriumError)) as info:
        compensate(soft, UR5_PATH, [0.0, 0.0, -3000.0])
    assert "path row 1" in str(info.value)


def test_path_columns_may_name_their_unit_in_brackets(ur5, tmp_path):
    """`elbow_joint [deg]`, `fx [N]`, `mx [Nm]` are those columns when the unit is the one they
    are read in (the same coordinates and loads as without units); another unit is refused
    with its fix. The columns were taken as unknown ('its columns name none of them: is the
    model file of another robot?', 'per-row loads need the columns fx, fy, fz')."""
    from stiffness.errors import FileFormatError
    from stiffness.machining.joint_path import read_joint_path

    joints = list(ur5.coordinate_joints)
    rows = np.column_stack([UR5_PATH, np.tile([1.0, -2.0, 30.0, 0.5, 0.0, 0.0], (2, 1))])
    loads = ["fx", "fy", "fz", "mx", "my", "mz"]
    plain = read_joint_path(_path_csv(tmp_path / "a.csv", rows, joints + loads), ur5, deg=True)
    with_units = [f"{j} [deg]" for j in joints] + ["fx [N]", "fy", "fz", "mx [Nm]", "my", "mz"]
    read = read_joint_path(_path_csv(tmp_path / "b.csv", rows, with_units), ur5, deg=True)
    np.testing.assert_array_equal(read.coords, plain.coords)
    np.testing.assert_array_equal(read.wrench, plain.wrench)
    assert read.header == with_units and read.column_of == joints
    with pytest.raises(FileFormatError, match=r"column 1 \(shoulder_pan_joint \[deg\]\): the "
                       "header says deg but shoulder_pan_joint is read in rad; give --deg"):
        read_joint_path(tmp_path / "b.csv", ur5)
    kilo = with_units[:6] + ["fx [kN]"] + with_units[7:]
    with pytest.raises(FileFormatError, match="the header says kN but fx is read in N; "
                       "convert the column to N"):
        read_joint_path(_path_csv(tmp_path / "c.csv", rows, kilo), ur5, deg=True)


def test_a_path_names_the_joints_that_move_the_target_and_the_other_limbs_are_held(tmp_path):
    """A fixed solo8 whose target is a foot: a path of that leg's two joints reads as all eight
    coordinates, the other legs held at the reference configuration (said in a note); a path
    that leaves out a joint of the leg is refused naming it. It needed all eight columns
    ('lacks the coordinate column(s) FR_HFE, ...')."""
    import warnings

    from stiffness.errors import DataFileNote, FileFormatError
    from stiffness.machining.joint_path import read_joint_path
    from stiffness.mechanics.defaults import default_coordinates

    solo = load_robot("solo8", fixed_base=True)
    leg = np.array([[0.5, -1.0], [0.6, -1.1]])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        read = read_joint_path(_path_csv(tmp_path / "leg.csv", leg, ["FL_HFE", "FL_KFE"],
                                         deg=False), solo)
    held = [w for w in caught if w.category is DataFileNote]
    assert len(held) == 1 and "6 of 8 coordinates have no column and are held at the " \
        "reference configuration (they do not move the target): FR_HFE" in str(held[0].message)
    full = np.tile(default_coordinates(solo), (2, 1))
    full[:, :2] = leg
    np.testing.assert_array_equal(read.coords, full)
    assert read.column_of == ["FL_HFE", "FL_KFE"]
    with pytest.raises(FileFormatError, match=r"lacks the coordinate column\(s\) FL_HFE of "):
        read_joint_path(_path_csv(tmp_path / "knee.csv", leg[:, 1:], ["FL_KFE"], deg=False),
                        solo)


def test_a_singular_pose_is_compensated_exactly_and_first_order_as_near_as_ik_gets():
    """A fixed solo8's leg stretched (a singular pose): the exact command (no inverse
    kinematics) cancels the deflection; the first-order comparison's shifted pose is out of
    reach by second order, so it is commanded at the closest pose IK finds and its residual
    says so (the whole path was refused: 'the target pose is out of reach ... move the pose
    into the workspace', a pose the robot reaches)."""
    solo = load_robot("solo8", fixed_base=True)
    model = ElasticModel.joint_springs(solo, [300.0, 300.0])
    point = compensate(model, np.zeros((1, 8)), [3.0, 0.0, 0.0]).points[0]
    deflection = np.linalg.norm(point.deflection)
    assert deflection > 1e-3 and np.linalg.norm(point.residual) < 1e-9 * deflection
    assert 0.0 < np.linalg.norm(point.residual_first_order) < 0.1 * deflection


def test_diagnosed_model_file_brings_its_effects(sk120):
    """A final-model.json of `stiffness diagnose` (simulated SK120 campaign with a hidden
    backlash on joint2 and a bend joint2->elbow of 2e6 N.m/rad): both reach the compensation."""
    from pathlib import Path

    from stiffness.elastic.model_file import load_model

    em = load_model(Path(__file__).parent / "data" / "sk120-final-model.json")
    assert em.law.backlash[em.robot.coordinate_joints.index("joint2")] > 0
    (bend,) = em.links
    assert (bend.a, bend.b) == ("joint2", "elbow")
    assert abs(bend.stiffness[1] / 2e6 - 1) < 0.1
    c = np.deg2rad(sk120.defaults["q_deg"])
    path = np.array([c, c + np.deg2rad([15.0, 5.0, -5.0, 0.0, 5.0, 0.0])])
    wrench = [0.0, -250.0, -200.0]
    result = compensate(em, path, wrench)
    joint_only = compensate(ElasticModel(em.robot, em.law), path, wrench)
    for point, closed, coords in zip(result.points, joint_only.points, path, strict=True):
        assert point.method == "general" and np.linalg.norm(point.residual) < 1e-9
        left = loaded_equilibrium(em, closed.command, wrench, seed_q=closed.q_nominal)
        nominal = _fk(sk120, coords, closed.q_nominal)[0]
        assert np.linalg.norm(left.position - nominal) > 1e-5


def _parameter(name, value, unit):
    from stiffness.elastic.effects.base import Parameter

    return Parameter(name, value, 0.0, (value, value), unit)


def test_model_file_effects_enter_the_elastic_model(tmp_path, ur5):
    """A model file (the one schema of identify and diagnose) with every kind of effect: the
    robot's effects enter the law and the bends, the measurement ones are listed, and the
    compensation still lands on the nominal pose."""
    from stiffness.elastic.model_contents import ModelEffect, ModelFile
    from stiffness.elastic.model_file import load_model

    arm = JOINTS[:5]
    effects = (
        ModelEffect("joint_compliance", "wrist_3_joint", "stiffness",
                    [_parameter("stiffness", 3e4, "N.m/rad")]),
        ModelEffect("nonlinear_joint_stiffness", "shoulder_lift_joint", "stiffness",
                    [_parameter("beta", 1e-3, "1/(N.m)")]),
        ModelEffect("backlash", "elbow_joint", "lost_motion",
                    [_parameter("half_width", 2e-4, "rad")], {"smoothing_torque": 2.0}),
        ModelEffect("link_compliance", "shoulder_lift_joint->elbow_joint", "stiffness",
                    [_parameter("stiffness_1", 1.5e5, "N.m/rad"),
                     _parameter("stiffness_2", 8e4, "N.m/rad")]),
        ModelEffect("frame_misalignment", None, "measurement",
                    [_parameter(n, 0.01, "rad") for n in ("rx", "ry", "rz")]),
        ModelEffect("target_offset", None, "stiffness",
                    [_parameter(n, v, "m") for n, v in (("dx", 0.0), ("dy", 0.0),
                                                        ("dz", 0.05))]),
    )
    path = ModelFile("ur5", "tool0", [0.0, 0.0, 0.0], arm, UR5_K[:5], ["N.m/rad"] * 5,
                     "enhanced", effects=effects, produced_by="diagnose").write(
        tmp_path / "final-model.json")
    em = load_model(path)
    joints = list(em.robot.coordinate_joints)
    assert em.law.compliance[joints.index("wrist_3_joint")] == pytest.approx(1 / 3e4)
    assert em.law.beta[joints.index("shoulder_lift_joint")] == pytest.approx(1e-3)
    assert em.law.backlash[joints.index("elbow_joint")] == pytest.approx(2e-4)
    assert em.law.smoothing[joints.index("elbow_joint")] == pytest.approx(2.0)
    assert [(b.a, b.b, b.stiffness) for b in em.links] == [
        ("shoulder_lift_joint", "elbow_joint", (1.5e5, 8e4))]
    np.testing.assert_allclose(em.robot.target_offset, [0.0, 0.0, 0.05])
    assert em.ignored == ("frame_misalignment",)
    result = compensate(em, UR5_PATH, [50.0, 0.0, -300.0])
    assert result.summary()["max_residual_m"] < 1e-9
    assert result.summary()["max_deflection_m"] > 1e-4


def test_loaded_equilibrium_agrees_with_the_joint_law_solver(ur5):
    """Joint laws only: the equilibrium over all coordinates (elastic) and the toolkit's
    joint-law solver (mechanics.equilibrium, compliant joints only) are the same point."""
    from stiffness.mechanics.equilibrium import SpringLaw, solve_equilibrium

    em = ElasticModel.joint_springs(ur5, UR5_K)
    em.law.beta[:] = [1e-3, 2e-3, 0.0, 1e-3, 0.0, 0.0]
    em.law.backlash[2] = 3e-4
    em.law.smoothing[:] = 4.0
    wrench = np.array([80.0, -40.0, -250.0, 2.0, 0.0, 1.0])
    command = UR5_PATH[0]
    mine = loaded_equilibrium(em, command, wrench)
    law = SpringLaw(em.law.compliance.copy(), em.law.beta.copy(), em.law.backlash.copy(),
                    em.law.smoothing.copy())
    theirs = solve_equilibrium(ur5, ur5.configuration(command), law, wrench)
    np.testing.assert_allclose(mine.coords - command, theirs.dtheta, atol=1e-12)


def test_linear_deflection_is_the_model_files_compliance(tmp_path, ur5):
    """The first-order deflection the posture search minimises (link bends included) equals
    the model file's compliance times the load (ElasticModel.at)."""
    from stiffness.elastic.loaded import linear_deflection
    from stiffness.elastic.model_contents import ModelEffect, ModelFile
    from stiffness.elastic.model_file import load_model

    bend = ModelEffect("link_compliance", "shoulder_lift_joint->elbow_joint", "stiffness",
                       [_parameter("stiffness_1", 1.5e5, "N.m/rad"),
                        _parameter("stiffness_2", 8e4, "N.m/rad")])
    path = ModelFile("ur5", "tool0", [0.0, 0.1, 0.05], JOINTS, UR5_K, ["N.m/rad"] * 6,
                     "enhanced", effects=(bend,), produced_by="diagnose").write(
        tmp_path / "final-model.json")
    em = load_model(path)
    wrench = np.array([60.0, -30.0, -300.0, 0.0, 0.0, 0.0])
    for coords in UR5_PATH:
        theirs = load_model(path).at(coords, wrench).compliance(slice(0, 6)) @ wrench
        np.testing.assert_allclose(linear_deflection(em, coords, wrench), theirs,
                                   rtol=1e-9, atol=1e-14)


def test_preloaded_model_cancels_the_weight_and_the_load(ur5):
    """A model with the arm's weight and a 4 kg payload (a preload): the closed-form command
    rests the target on the nominal pose under the process wrench *and* the weight. Checked by
    the root finder on ``k (theta - theta_c) = J^T (W + m g) - g(theta)`` with Pinocchio's
    generalised gravity, not the toolkit's preload."""
    k = np.array(UR5_K)
    em = ElasticModel.of_parts(
        ur5, ElasticParts(dict(zip(ur5.coordinate_joints, UR5_K, strict=True)),
                          payload=(4.0, np.zeros(3))))
    assert em.preloaded
    wrench = np.array([60.0, -40.0, -150.0, 2.0, -1.0, 1.0])
    weight = np.concatenate([4.0 * ur5.model.gravity.linear, np.zeros(3)])
    result = compensate(em, UR5_PATH, wrench)
    model, data = ur5.model, ur5.model.createData()
    for point, nominal in zip(result.points, UR5_PATH, strict=True):
        seed = point.q_nominal

        def balance(theta, command=point.command, seed=seed):
            jac = _fd_jacobian(ur5, theta, seed, range(6))
            gravity = pin.computeGeneralizedGravity(model, data, theta)
            return k * (theta - command) - jac.T @ (wrench + weight) + gravity

        sol = root(balance, nominal.copy(), method="hybr", tol=1e-14)
        assert np.abs(balance(sol.x)).max() / k.min() < 1e-12, sol.message
        p, r = _fk(ur5, sol.x, seed)
        p_n, r_n = _fk(ur5, nominal, seed)
        assert np.linalg.norm(p - p_n) < 1e-9
        assert np.linalg.norm(pin.log3(r @ r_n.T)) < 1e-9
        assert np.linalg.norm(point.residual) < 1e-9
        # the weight's sag is part of what is cancelled: mm here, against um of residual
        assert np.linalg.norm(point.deflection) > 1e-4
        assert np.linalg.norm(point.residual_first_order) < 0.1 * np.linalg.norm(
            point.deflection)


def test_preloaded_model_with_link_bends_is_refused_in_one_line(ur5):
    parts = ElasticParts(dict(zip(ur5.coordinate_joints, UR5_K, strict=True)),
                         bends=[("elbow_joint", "wrist_1_joint", 5e4, 3e4)],
                         payload=(4.0, np.zeros(3)))
    em = ElasticModel.of_parts(ur5, parts)
    with pytest.raises(StiffnessError) as err:
        compensate(em, UR5_PATH, np.array([0.0, 0.0, -100.0]))
    assert "preload" in str(err.value) and "\n" not in str(err.value)


def test_linear_deflection_under_a_preload_is_the_exact_equilibriums_slope(ur5):
    """Posture's first-order deflection under a preload (weight, payload, a compensator) is, at
    a small load (where ``K_C(W)`` vanishes), the load derivative of the exact equilibrium
    under that preload: central differences of ``solve_equilibrium(..., preload=em.preload)``
    at +-h W, to 1e-6 relative. Ignoring the preload's stiffness and operating point (the
    behaviour before) is off by 1.1 % here."""
    parts = ElasticParts(dict(zip(ur5.coordinate_joints, UR5_K, strict=True)),
                         payload=(6.0, np.zeros(3)))
    parts.add_compensator("shoulder_lift_joint", 2e5, 3000.0, {"lever_m": 0.1, "base_m": 0.3})
    em = ElasticModel.of_parts(ur5, parts)
    coords = UR5_PATH[0]
    wrench = np.array([80.0, -50.0, -200.0, 3.0, -2.0, 1.0])
    law = em.compliant_law()
    q = em.full.configuration(coords)

    def target(scale):
        eq = solve_equilibrium(em.robot, q, law, scale * wrench, preload=em.preload)
        m = target_state(em.robot, eq.q)
        return m.position, m.rotation

    h = 1e-3
    (pp, rp), (pm, rm) = target(h), target(-h)
    fd = np.concatenate([(pp - pm) / (2 * h), pin.log3(rp @ rm.T) / (2 * h)])
    linear = em.linear_deflection(coords, 1e-6 * wrench) / 1e-6
    np.testing.assert_allclose(linear, fd, rtol=0, atol=1e-6 * np.abs(fd).max())
    springs = ElasticModel.joint_springs(ur5, UR5_K)
    springs_only = springs.linear_deflection(coords, 1e-6 * wrench) / 1e-6
    assert np.abs(springs_only - fd).max() > 1e-4 * np.abs(fd).max()


def test_a_path_starting_at_a_singular_pose_is_held_by_pose_on_joint_springs(ur5):
    """A UR5 path from its singular upright home (0, -90, 0, -90, 0, 0 deg) on joint springs:
    `auto` holds the pose, as the arm can and the closed form does at any pose (it held the
    position only, for the whole path, because the first point was singular); the exact
    commands leave no position nor rotation error at either point, the first included. With a
    bending link (the general solver, which a singular pose can stall) the first point still
    decides."""
    home = np.array([0.0, -np.pi / 2, 0.0, -np.pi / 2, 0.0, 0.0])
    sv = np.linalg.svd(target_state(ur5, ur5.configuration(home)).jacobian, compute_uv=False)
    assert sv[-1] < 1e-9 * sv[0]  # the first point is singular
    joints, linked, _ = _ur5_link_model(ur5)
    path, wrench = np.vstack([home, UR5_PATH[0]]), [100.0, 0.0, -300.0]
    result = compensate(joints, path, wrench)
    assert result.hold == "pose"
    for point, nominal in zip(result.points, path, strict=True):
        assert np.linalg.norm(point.deflection) > 1e-4
        assert np.linalg.norm(point.residual) < 1e-12
        assert np.linalg.norm(point.rotation_residual) < 1e-12
        # independently: the springs at rest at the command settle on the nominal pose
        loaded = _independent_equilibrium(ur5, point.command, np.array(UR5_K),
                                          np.concatenate([wrench, np.zeros(3)]), point.q_nominal)
        (p, r), (p_n, r_n) = (_fk(ur5, c, point.q_nominal) for c in (loaded, nominal))
        assert np.linalg.norm(p - p_n) < 1e-9 and np.linalg.norm(pin.log3(r @ r_n.T)) < 1e-9
    assert compensate(linked, path, wrench).hold == "position"
