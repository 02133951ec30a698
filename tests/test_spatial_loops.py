"""Spatial loops: 6-D frame constraints, platforms of U-P-S legs, prismatic passive joints.

Checked against finite differences of the loop-closed forward kinematics
(:meth:`Robot.configuration` closes the loops at every perturbed point):

* the closed-loop platform Jacobian (rows [v; w]) and its derivative;
* K_C = d(J^T W)/d theta at a dead wrench (base axes) and K_C^tw at a body-fixed wrench, whose
  multiplier term carries everything here (the platform hangs from passive joints only);
* a "6D" (weld) loop: a second virtual chain welded to the platform gives the same Jacobian and
  K_C at its end as the platform frame itself; its constraint derivatives off the loop;
* another choice of actuated joints (a leg's prismatic joint passive, a universal joint
  actuated), and the 6-UPS hexapod (robots/hexapod) with its stiffness map.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from stiffness.errors import StiffnessError
from stiffness.mechanics.formulation import (
    joint_connection_stiffness,
    joint_stiffness,
    target_state,
    twist_basis_stiffness,
)
from stiffness.mechanics.platform import (
    jacobian_derivative,
    lie_bracket_term,
    platform_stiffness,
    solve_pose,
    stiffness_map,
)
from stiffness.robot import kinematics
from stiffness.robot.loops import read_loop_declaration
from stiffness.robot.platform import VIRTUAL_JOINTS
from stiffness.robot.robot import load_robot
from stiffness.robot.sources import robots_directory

GD = robots_directory() / "griffis-duffy"
#: A configuration away from the shipped one (leg lengths, m).
OFF_SHIPPED = np.array([0.2290, 0.1910, 0.1830, 0.2030, 0.1395, 0.1620])
RNG_WRENCH = np.array([30.0, -12.0, 45.0, 1.5, -2.0, 0.7])  # N, N.m


def _closed_neutral(robot, coords):
    """Closed configuration from the neutral passive joints at ``coords``."""
    q = robot._tree_configuration(np.asarray(coords, float), pin.neutral(robot.model))
    return robot.loop.close(robot.model, robot.data, q)


def _fd_over_coordinates(robot, coords, fn, h=1e-6):
    """Central differences of fn(q) over the compliant coordinates (loops closed)."""
    q0 = robot.configuration(coords, seed=_closed_neutral(robot, coords))
    cols = []
    for i in robot.compliant_in_coordinates:
        vals = []
        for sign in (1.0, -1.0):
            c = np.array(coords, float)
            c[i] += sign * h
            vals.append(np.asarray(fn(robot.configuration(c, seed=q0))))
        cols.append((vals[0] - vals[1]) / (2 * h))
    return q0, np.stack(cols, axis=-1)


def _pose(robot, q):
    pin.framesForwardKinematics(robot.model, robot.data, q)
    return robot.data.oMf[robot.target_frame_id].copy()


@pytest.fixture(scope="module")
def gd():
    return load_robot("griffis-duffy")


# --------------------------------------------------------------------------- 6-D loops


GHOST_JOINTS = tuple(f"ghost_{n.split('_')[1]}" for n in VIRTUAL_JOINTS)


@pytest.fixture(scope="module")
def welded(tmp_path_factory):
    """Griffis-Duffy plus a second virtual 6-DoF chain ('ghost') welded to the platform by a
    "6D" loop; the target is the ghost's end, 2 cm off its origin."""
    folder = tmp_path_factory.mktemp("welded")
    urdf = (GD / "griffis-duffy.urdf").read_text()
    links, joints, parent = [], [], "base_link"
    axes = ("1 0 0", "0 1 0", "0 0 1") * 2
    for i, name in enumerate(GHOST_JOINTS):
        child = "ghost" if i == 5 else f"{name}_link"
        kind = "prismatic" if i < 3 else "revolute"
        joints.append(
            f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="0 0 0" rpy="0 0 0"/><axis xyz="{axes[i]}"/>'
            '<limit effort="1" velocity="1" lower="-3" upper="3"/></joint>')
        links.append(f'<link name="{child}"/>')
        parent = child
    urdf = urdf.replace("</robot>", "".join(links) + "".join(joints) + "</robot>")
    (folder / "welded.urdf").write_text(urdf)
    loops = (GD / "griffis-duffy.loops.yaml").read_text().splitlines()
    out = []
    for line in loops:
        if line.startswith("type:"):
            out.append("  - [platform, ghost]")
            line = line.replace("]", ', "6D"]')
        elif line.startswith("passive_joints:"):
            line = line.replace("]", ", " + ", ".join(GHOST_JOINTS) + "]")
        out.append(line)
    (folder / "welded.loops.yaml").write_text("\n".join(out) + "\n")
    return load_robot(folder / "welded.urdf", frame="ghost", target_offset=[0.0, 0.02, 0.0],
                      compliant_joints=[f"leg{i}" for i in range(1, 7)])


def test_6d_declaration(welded):
    decl = read_loop_declaration(Path(welded.name).with_suffix(".loops.yaml"))
    assert decl.pairs[-1].kind == "6D" and decl.pairs[0].kind == "3D"
    loop = welded.loop
    assert loop.n_rows == 6 * 3 + 6 and loop.n_world_rows == 6 * 3 + 9
    assert len(loop.passive_v) == 24


def test_unsupported_loop_type(tmp_path):
    text = (GD / "griffis-duffy.loops.yaml").read_text().replace('"3D"]', '"5D"]')
    (tmp_path / "bad.yaml").write_text(text)
    with pytest.raises(StiffnessError, match="'5D' is not supported; use '3D'.*or '6D'"):
        read_loop_declaration(tmp_path / "bad.yaml")


def test_6d_constraint_derivatives_off_the_loop(welded):
    """jacobian() is the exact derivative of the (log6) residual, world_jacobian/world_hessian
    those of the 9-row world residual, at an open configuration."""
    model, data, loop = welded.model, welded.data, welded.loop
    rng = np.random.default_rng(3)
    q = pin.integrate(model, _closed_neutral(welded, welded.defaults.get("q_SI", OFF_SHIPPED)),
                      rng.uniform(-0.3, 0.3, model.nv))
    kinematics.update_kinematics(model, data, q)
    assert np.linalg.norm(loop.residual(model, data)[-6:]) > 1e-2
    jac, wjac, whess = (loop.jacobian(model, data), loop.world_jacobian(model, data),
                        loop.world_hessian(model, data))

    def at(qq, what):
        kinematics.update_first_order(model, data, qq)
        return {"res": loop.residual, "wres": loop.world_residual,
                "wjac": loop.world_jacobian}[what](model, data)

    h = 1e-6
    for b in range(model.nv):
        dv = np.zeros(model.nv)
        dv[b] = h
        qp, qm = pin.integrate(model, q, dv), pin.integrate(model, q, -dv)
        np.testing.assert_allclose(jac[:, b], (at(qp, "res") - at(qm, "res")) / (2 * h),
                                   atol=2e-8)
        np.testing.assert_allclose(wjac[:, b], (at(qp, "wres") - at(qm, "wres")) / (2 * h),
                                   atol=2e-8)
        np.testing.assert_allclose(whess[:, :, b], (at(qp, "wjac") - at(qm, "wjac")) / (2 * h),
                                   atol=2e-7)


def test_6d_world_rows_are_redundant(welded, gd):
    """27 world rows of rank 24 (the weld's 9 rows have rank 6); Pinocchio's 24 rows regular."""
    q = _closed_neutral(welded, gd.defaults["q_SI"])
    kinematics.update_first_order(welded.model, welded.data, q)
    cw = welded.loop.world_jacobian(welded.model, welded.data)[:, welded.loop.passive_v]
    sv = np.linalg.svd(cw, compute_uv=False)
    assert cw.shape == (27, 24) and np.sum(sv > 1e-9 * sv[0]) == 24
    assert welded.loop.passive_rank(welded.model, welded.data) == 24


@pytest.mark.parametrize("coords", ["shipped", "off"])
def test_weld_reproduces_the_platform(welded, gd, coords):
    """The welded ghost's end (+2 cm) has the Jacobian, K_C and K_C^tw of the platform frame
    shifted by 2 cm: everything passes through the 6D loop's multipliers."""
    c = np.array(gd.defaults["q_SI"]) if coords == "shipped" else OFF_SHIPPED
    shifted = load_robot("griffis-duffy", target_offset=[0.0, 0.02, 0.0])
    qa = shifted.configuration(c)
    qb = welded.configuration(c, seed=_closed_neutral(welded, gd.defaults["q_SI"]))
    sa, sb = target_state(shifted, qa, RNG_WRENCH), target_state(welded, qb, RNG_WRENCH)
    np.testing.assert_allclose(sb.position, sa.position, atol=1e-12)
    np.testing.assert_allclose(sb.jacobian, sa.jacobian, atol=1e-9)
    np.testing.assert_allclose(sb.k_c, sa.k_c, atol=1e-8 * np.abs(sa.k_c).max())
    np.testing.assert_allclose(sb.k_c_twist, sa.k_c_twist, atol=1e-8 * np.abs(sa.k_c).max())


# ------------------------------------------------------------------ platform FD checks


def _check_jacobian_against_fk(robot, coords):
    """Body Jacobian of the target = FD of the loop-closed target pose: the derivative of
    log6(M) is Jlog6(M) times the body twist."""
    q0, fd = _fd_over_coordinates(robot, coords, lambda q: pin.log6(_pose(robot, q)).vector)
    body_fd = np.linalg.solve(pin.Jlog6(_pose(robot, q0)), fd)
    body = target_state(robot, q0).body_jacobian()
    np.testing.assert_allclose(body, body_fd, atol=1e-7 * np.abs(body).max())


def test_closed_loop_jacobian_is_fd_of_forward_kinematics(gd):
    """Body twist of the platform per leg-length rate = FD of the loop-closed platform pose."""
    _check_jacobian_against_fk(gd, OFF_SHIPPED)


def test_k_c_is_fd_of_closed_loop_jacobian(gd):
    """K_C = d(J^T W)/d theta (W dead, base axes); K_C^tw = d(J_b^T W_b)/d theta (W_b body)."""
    wrench = RNG_WRENCH
    q0, fd_world = _fd_over_coordinates(
        gd, OFF_SHIPPED, lambda q: target_state(gd, q).jacobian.T @ wrench)
    state = target_state(gd, q0, wrench)
    w_body = np.concatenate([state.rotation.T @ wrench[:3], state.rotation.T @ wrench[3:]])
    _, fd_body = _fd_over_coordinates(
        gd, OFF_SHIPPED, lambda q: target_state(gd, q).body_jacobian().T @ w_body)
    scale = np.abs(state.k_c).max()
    np.testing.assert_allclose(state.k_c, fd_world, atol=1e-6 * scale)
    np.testing.assert_allclose(state.k_c_twist, fd_body, atol=1e-6 * scale)
    # the multiplier term is all of it: the target's own Hessian has no leg columns
    assert scale > 1.0


def test_jacobian_derivative_is_fd(gd):
    q0, fd = _fd_over_coordinates(gd, OFF_SHIPPED, lambda q: target_state(gd, q).jacobian)
    d = jacobian_derivative(gd, q0)
    np.testing.assert_allclose(d, fd, atol=1e-6 * np.abs(d).max())


def test_other_actuated_joints_prismatic_passive(tmp_path, gd):
    """Leg 6's length passive (a passive prismatic joint), its first universal joint actuated
    instead: J and K_C against FD over the new coordinates."""
    text = (GD / "griffis-duffy.loops.yaml").read_text()
    text = text.replace("leg5, leg6]", "leg5, leg6_ux]").replace("leg6_ux, leg6_uy]",
                                                                  "leg6, leg6_uy]")
    (tmp_path / "alt.yaml").write_text(text)
    robot = load_robot(GD / "griffis-duffy.urdf", frame="platform", loops=tmp_path / "alt.yaml")
    assert "leg6" in robot.loop.passive_joints and "leg6_ux" in robot.compliant_joints
    coords_order = robot.coordinate_joints
    coords = np.array([dict(zip(gd.coordinate_joints, gd.defaults["q_SI"], strict=True)).get(
        n, 0.0) for n in coords_order])
    coords[coords_order.index("leg6_ux")] = 0.01
    _check_jacobian_against_fk(robot, coords)
    q0, fd_kc = _fd_over_coordinates(
        robot, coords, lambda q: target_state(robot, q).jacobian.T @ RNG_WRENCH)
    state = target_state(robot, q0, RNG_WRENCH)
    np.testing.assert_allclose(state.k_c, fd_kc, atol=1e-6 * np.abs(state.k_c).max())


def test_solve_pose_reaches_the_pose(gd):
    q0 = gd.configuration(np.array(gd.defaults["q_SI"]))
    goal = pin.SE3(pin.exp3(np.array([0.02, -0.03, 0.01])), np.array([0.003, -0.002, 0.004]))
    q = solve_pose(gd, goal, q0)
    assert np.linalg.norm(pin.log6(goal.actInv(_pose(gd, q))).vector) < 1e-10
    kinematics.update_first_order(gd.model, gd.data, q)
    assert np.linalg.norm(gd.loop.residual(gd.model, gd.data)) < 1e-10


# ------------------------------------------------------------------------------ hexapod


@pytest.fixture(scope="module")
def hexapod():
    return load_robot("hexapod")


def test_hexapod_home(hexapod):
    q = hexapod.configuration(np.array(hexapod.defaults["q_SI"]))
    pose = _pose(hexapod, q)
    np.testing.assert_allclose(pose.translation, [0.0, 0.0, 0.6], atol=1e-12)
    np.testing.assert_allclose(pose.rotation, np.eye(3), atol=1e-12)
    k = joint_stiffness(hexapod.defaults["k_theta_SI"], 6)
    ps = platform_stiffness(hexapod, q, k, wrench=np.array(hexapod.defaults["wrench_SI"]))
    assert np.allclose(ps.k_joint, ps.k_joint.T, rtol=0, atol=1e-6 * np.abs(ps.k_joint).max())
    assert np.all(np.linalg.eigvalsh(ps.k_joint) > 0)
    np.testing.assert_allclose(ps.k_twist - ps.k_twist.T, ps.bracket,
                               atol=1e-9 * np.abs(ps.k_twist).max())
    assert np.abs(ps.bracket).max() > 10.0  # the payload's moment and force do show
    unloaded = target_state(hexapod, q)
    np.testing.assert_allclose(twist_basis_stiffness(unloaded, k),
                               joint_connection_stiffness(unloaded, k), rtol=1e-12, atol=1e-3)


def test_hexapod_stiffness_map(hexapod):
    k = joint_stiffness(hexapod.defaults["k_theta_SI"], 6)
    poses = [pin.SE3(np.eye(3), np.array([x, 0.0, 0.6])) for x in (0.0, 0.05, 0.1)]
    poses.append(pin.SE3(pin.exp3(np.array([0.0, 0.0, 0.1])), np.array([0.1, 0.05, 0.62])))
    smap = stiffness_map(hexapod, poses, k, wrench=np.array(hexapod.defaults["wrench_SI"]))
    assert smap.translational_min.shape == (4,)
    assert np.all(smap.translational_min > 1e6) and np.all(smap.rotational_min > 1e5)
    assert np.all(np.diff(smap.translational_min[:3]) < 0)  # softer away from the centre
    assert smap.bracket_error.max() < 1e-6
    np.testing.assert_allclose(smap.positions[-1], [0.1, 0.05, 0.62], atol=1e-12)
    # leg lengths of the map are the lengths of the legs at that pose
    np.testing.assert_allclose(smap.leg_lengths[0], hexapod.defaults["q_SI"], atol=1e-12)


def test_lie_bracket_term_structure():
    """B[i, j] = W . (e_j x e_i): antisymmetric; nothing in the [v, v] block; the force enters
    the [v, w] block and the moment the [w, w] block as their cross-product matrices."""
    f, m = np.array([1.0, 2.0, 3.0]), np.array([-0.5, 0.25, 4.0])
    b = lie_bracket_term(np.concatenate([f, m]))
    np.testing.assert_allclose(b, -b.T, atol=1e-15)
    np.testing.assert_allclose(b[:3, :3], 0.0, atol=1e-15)
    np.testing.assert_allclose(b[3:, 3:], pin.skew(m), atol=1e-15)
    np.testing.assert_allclose(b[:3, 3:], pin.skew(f), atol=1e-15)
