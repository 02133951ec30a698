"""Loop machinery (stiffness.robot.loops, Robot.configuration, closed-loop J and K_C) on test
linkages.

The SK120's five-bar is a parallelogram, whose multiplier term in the closed-loop K_C vanishes
identically (its passive angles are linear in the actuated ones), so it cannot test that term.
Here the loop machinery is checked on linkages where the term is large:

* a planar crank-rocker four-bar (lengths 0.2, 0.7, 0.5, ground 0.6: not a parallelogram), in
  the base x-y plane and mounted on a tilted plane, against its closed-form assembly;
* a spatial R-U-S-R linkage (non-planar loop, full-rank point constraint).

Closed-loop J and K_C are checked against central differences of the loop-closed forward
kinematics (Robot.configuration closes the loop at every perturbed point).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from stiffness.errors import SingularConfigurationError, StiffnessError
from stiffness.mechanics.formulation import target_state, velocity_projection
from stiffness.robot import kinematics
from stiffness.robot.loops import CLOSURE_TOLERANCE_M, read_loop_declaration
from stiffness.robot.robot import load_robot
from stiffness.robot.sources import robots_directory


def _wrap(x):
    return (np.asarray(x) + np.pi) % (2 * np.pi) - np.pi


def _joint_value(robot, q, name):
    return q[robot.model.joints[robot.model.getJointId(name)].idx_q]


@pytest.fixture(scope="module")
def linkages(four_bar_robot, tilted_four_bar_robot, spatial_robot):
    return {"planar": four_bar_robot, "tilted": tilted_four_bar_robot, "spatial": spatial_robot}


def _linkage_coordinates(kind, rng):
    """(crank, tool) angles: the crank turns fully on the crank-rocker; the spatial linkage is
    kept to |crank| < 1.2 rad, where it assembles."""
    crank = rng.uniform(-np.pi, np.pi) if kind != "spatial" else rng.uniform(-1.2, 1.2)
    return np.array([crank, rng.uniform(-np.pi, np.pi)])


# ------------------------------------------------------------------------------ declarations


def test_loop_declaration_of_sk120():
    decl = read_loop_declaration(robots_directory() / "sk120" / "sk120.loops.yaml")
    assert [(p.frame_a, p.frame_b, p.kind) for p in decl.pairs] == [
        ("coupler_end", "forearm_rear", "3D")]
    assert decl.actuated == ("joint1", "joint2", "joint3")
    assert decl.passive == ("elbow", "coupler_joint")


def test_default_passive_joints_are_the_loop_path(four_bar_robot, spatial_robot):
    """Without passive_joints, the passive joints are the unactuated joints on the loop path;
    the tool joint (off the loop) stays a coordinate."""
    assert four_bar_robot.loop.passive_joints == ("coupler_joint", "rocker_joint")
    assert four_bar_robot.coordinate_joints == ("crank_joint", "tool_joint")
    assert spatial_robot.loop.passive_joints == ("u1_joint", "u2_joint", "rocker_joint")
    assert spatial_robot.coordinate_joints == ("crank_joint", "tool_joint")


# ---------------------------------------------------------------------------------- closure


@pytest.mark.parametrize("which", ["four_bar", "tilted_four_bar"])
def test_planar_passive_joints_match_closed_form(which, request):
    """Continuation from the reference assembly keeps the +1 branch all around the crank's
    circle; the passive angles equal the closed-form four-bar solution."""
    geometry = request.getfixturevalue(which)
    robot = request.getfixturevalue(f"{which}_robot")
    for phi in np.linspace(-np.pi, np.pi, 13):
        q = robot.configuration(np.array([phi, 0.4]))
        coupler, rocker = geometry.passive_closed_form(phi)
        assert abs(_wrap(_joint_value(robot, q, "coupler_joint") - coupler)) < 1e-9
        assert abs(_wrap(_joint_value(robot, q, "rocker_joint") - rocker)) < 1e-9
        np.testing.assert_allclose(robot.coordinates_of(q), [phi, 0.4], atol=1e-15)
        kinematics.update_first_order(robot.model, robot.data, q)
        assert np.linalg.norm(robot.loop.residual(robot.model, robot.data)) < CLOSURE_TOLERANCE_M


def test_closed_form_branch_is_not_trivially_matched(four_bar):
    """The two assemblies differ by O(1) rad, so the comparison above discriminates branches."""
    for phi in np.linspace(-np.pi, np.pi, 13):
        up = np.array(four_bar.passive_closed_form(phi, branch=1))
        down = np.array(four_bar.passive_closed_form(phi, branch=-1))
        assert np.abs(_wrap(up - down)).min() > 0.5


def test_tilted_and_planar_four_bars_agree(four_bar_robot, tilted_four_bar_robot):
    """Mounting the linkage on a tilted plane rotates its kinematics rigidly: same joint
    solution, Jacobian rotated by the mount's rotation, same K_C for the rotated force."""
    mount = pin.rpy.rpyToMatrix(0.3, -0.5, 0.7)
    force = np.array([30.0, -40.0, 10.0])
    for phi in (-2.0, 0.5, 2.5):
        coords = np.array([phi, -0.3])
        flat = target_state(four_bar_robot, four_bar_robot.configuration(coords), force)
        tilted = target_state(tilted_four_bar_robot, tilted_four_bar_robot.configuration(coords),
                              mount @ force)
        np.testing.assert_allclose(tilted.q, flat.q, atol=1e-10)
        np.testing.assert_allclose(tilted.jacobian[:3], mount @ flat.jacobian[:3], atol=1e-10)
        np.testing.assert_allclose(tilted.k_c, flat.k_c, atol=1e-9 * np.abs(flat.k_c).max())


@pytest.mark.parametrize("kind", ["planar", "tilted", "spatial"])
def test_closed_loop_jacobian_and_kc_match_fd(kind, linkages, fd):
    """J = d x / d theta and K_C = d(J^T F)/d theta along the closed loop, where the multiplier
    term -S^T (sum_j lambda_j d2c_j) S is a large part of K_C."""
    robot = linkages[kind]
    rng = np.random.default_rng({"planar": 1, "tilted": 2, "spatial": 3}[kind])
    multiplier_share = []
    for _ in range(6):
        coords = _linkage_coordinates(kind, rng)
        q = robot.configuration(coords)
        force = rng.normal(size=3) * 100.0
        state = target_state(robot, q, force)
        jac_fd = fd.coordinates(robot, coords, lambda s: s.position)
        assert fd.rel_err(state.jacobian[:3], jac_fd) <= 1e-6
        kc_fd = fd.coordinates(robot, coords, lambda s, f=force: s.jacobian[:3].T @ f)
        assert fd.rel_err(state.k_c, kc_fd) <= 1e-6
        # the load-weighted target Hessian alone (no multiplier term), from pin's Hessians
        kinematics.update_kinematics(robot.model, robot.data, q)
        hess = kinematics.frame_hessian(robot.model, robot.data, robot.target_frame_id)[:3]
        s = state.projection
        open_part = s.T @ np.einsum("k,kab->ab", force, hess) @ s
        multiplier_share.append(fd.rel_err(open_part, kc_fd))
    # Dropping the multiplier term errs by 6 % to 400 % of K_C (Frobenius; measured: planar
    # 0.14..1.5, tilted 0.06..0.19, spatial 0.34..4.0), against the 1e-6 FD agreement above.
    assert min(multiplier_share) > 0.03
    assert max(multiplier_share) > 0.15


def test_sk120_parallelogram_has_no_multiplier_term(sk120, sk120_coords):
    """Contrast: for the SK120's exact parallelogram, K_C is the open-chain term alone."""
    rng = np.random.default_rng(4)
    for _ in range(3):
        q = sk120.configuration(sk120_coords(rng.uniform(0, 1, 6)))
        force = rng.normal(size=3) * 1e4
        state = target_state(sk120, q, force)
        kinematics.update_kinematics(sk120.model, sk120.data, q)
        hess = kinematics.frame_hessian(sk120.model, sk120.data, sk120.target_frame_id)[:3]
        open_part = state.projection.T @ np.einsum("k,kab->ab", force, hess) @ state.projection
        assert np.abs(state.k_c - open_part).max() <= 1e-12 * np.abs(state.k_c).max()


@pytest.mark.parametrize("kind", ["planar", "spatial"])
def test_velocity_projection_is_fd_of_closed_configuration(kind, linkages, sk120, sk120_coords):
    """S = d q / d theta (as a velocity, pin.difference) of the loop-closed configuration."""
    cases = [(linkages[kind], _linkage_coordinates(kind, np.random.default_rng(9)))]
    cases.append((sk120, sk120_coords(np.random.default_rng(9).uniform(0, 1, 6))))
    h = 1e-6
    for robot, coords in cases:
        q0 = robot.configuration(coords)
        kinematics.update_first_order(robot.model, robot.data, q0)
        s = velocity_projection(robot)
        for col, i in enumerate(robot.compliant_in_coordinates):
            c_plus, c_minus = coords.copy(), coords.copy()
            c_plus[i] += h
            c_minus[i] -= h
            q_plus = robot.configuration(c_plus, seed=q0)
            q_minus = robot.configuration(c_minus, seed=q0)
            numeric = pin.difference(robot.model, q_minus, q_plus) / (2 * h)
            np.testing.assert_allclose(s[:, col], numeric, atol=1e-7 * np.abs(numeric).max())


@pytest.mark.parametrize("kind", ["spatial", "sk120"])
def test_constraint_derivatives_match_fd_off_the_loop(kind, spatial_robot, sk120):
    """At an open (unclosed) configuration: jacobian() is the derivative of residual(),
    world_jacobian()/world_hessian() those of p_b - p_a in world axes."""
    robot = spatial_robot if kind == "spatial" else sk120
    model, data, loop = robot.model, robot.data, robot.loop
    rng = np.random.default_rng(21)
    q = pin.integrate(model, pin.neutral(model), rng.uniform(-0.5, 0.5, model.nv))
    kinematics.update_kinematics(model, data, q)
    assert np.linalg.norm(loop.residual(model, data)) > 1e-3  # really off the loop
    jac = loop.jacobian(model, data)
    wjac = loop.world_jacobian(model, data)
    whess = loop.world_hessian(model, data)

    def world_residual(qq):
        pin.framesForwardKinematics(model, data, qq)
        return np.concatenate([data.oMf[fb].translation - data.oMf[fa].translation
                               for fa, fb in loop.frame_ids])

    def pin_residual(qq):
        kinematics.update_first_order(model, data, qq)
        return loop.residual(model, data)

    def world_jac(qq):
        kinematics.update_first_order(model, data, qq)
        return loop.world_jacobian(model, data)

    h = 1e-6
    for b in range(model.nv):
        dv = np.zeros(model.nv)
        dv[b] = h
        qp, qm = pin.integrate(model, q, dv), pin.integrate(model, q, -dv)
        np.testing.assert_allclose(jac[:, b], (pin_residual(qp) - pin_residual(qm)) / (2 * h),
                                   atol=1e-8)
        np.testing.assert_allclose(wjac[:, b], (world_residual(qp) - world_residual(qm)) / (2 * h),
                                   atol=1e-8)
        np.testing.assert_allclose(whess[:, :, b], (world_jac(qp) - world_jac(qm)) / (2 * h),
                                   atol=1e-7)


def test_constraint_rank_planar_versus_spatial(four_bar_robot, tilted_four_bar_robot,
                                               spatial_robot):
    """A planar loop closed by a 3-D point constraint has rank 2 (redundant row along the plane
    normal, which for the tilted mount is no base axis); the spatial R-U-S-R has rank 3."""
    mount_normal = pin.rpy.rpyToMatrix(0.3, -0.5, 0.7)[:, 2]
    for robot, rank, normal in ((four_bar_robot, 2, np.array([0.0, 0.0, 1.0])),
                                (tilted_four_bar_robot, 2, mount_normal),
                                (spatial_robot, 3, None)):
        q = robot.configuration(np.array([0.7, 0.2]))
        kinematics.update_first_order(robot.model, robot.data, q)
        cw = robot.loop.world_jacobian(robot.model, robot.data)[:, robot.loop.passive_v]
        sv = np.linalg.svd(cw, compute_uv=False)
        assert np.sum(sv > 1e-9 * sv[0]) == rank
        if normal is not None:
            np.testing.assert_allclose(normal @ cw, 0.0, atol=1e-12)


def test_loop_at_toggle_is_singular(non_grashof_four_bar):
    """At the triple rocker's limit position (coupler and rocker aligned) the passive joints
    are not determined by the crank: velocity_projection and target_state raise."""
    g = non_grashof_four_bar
    robot = load_robot(g.urdf, frame="tool_tip")
    # crank end at distance b + c from the rocker pivot: a^2 + d^2 - 2 a d cos(phi) = (b + c)^2
    phi = np.arccos((g.a**2 + g.d**2 - (g.b + g.c) ** 2) / (2 * g.a * g.d))
    # coupler along the crank-end -> rocker-pivot line, rocker pointing back along it (exactly
    # aligned, so that the passive Jacobian's columns are parallel to rounding)
    crank_end = g.a * np.array([np.cos(phi), np.sin(phi)])
    gamma = np.arctan2(-crank_end[1], g.d - crank_end[0])
    coupler, rocker = gamma - phi - g.beta0, gamma + np.pi - g.psi0
    q = robot.configuration(np.array([0.0, 0.0]))
    for name, value in (("crank_joint", phi), ("coupler_joint", coupler),
                        ("rocker_joint", rocker)):
        q[robot.model.joints[robot.model.getJointId(name)].idx_q] = value
    kinematics.update_first_order(robot.model, robot.data, q)
    assert np.linalg.norm(robot.loop.residual(robot.model, robot.data)) < 1e-9
    with pytest.raises(SingularConfigurationError,
                       match=r"target's position depends on an undetermined motion \(1 passive"):
        velocity_projection(robot)
    with pytest.raises(SingularConfigurationError, match="flattened or folded"):
        target_state(robot, q)


def test_loop_that_cannot_close(non_grashof_four_bar):
    """Crank at pi: crank end 1.1 m from the rocker pivot > b + c = 0.65 m: no assembly."""
    robot = load_robot(non_grashof_four_bar.urdf, frame="tool_tip")
    robot.configuration(np.array([0.5, 0.0]))  # within reach: closes
    unreachable = (r"(loop does not close|cannot be closed).*"
                   r"(out of the loop's reach|unreachable)")
    with pytest.raises(StiffnessError, match=unreachable):
        robot.configuration(np.array([np.pi, 0.0]))
    q0 = robot.configuration(np.array([0.0, 0.0]))
    with pytest.raises(StiffnessError, match=unreachable):
        robot.configuration(np.array([np.pi, 0.0]), seed=q0)
    # the loop alone, from the crank at pi with the zero-configuration passive joints
    q = q0.copy()
    q[robot.model.joints[robot.model.getJointId("crank_joint")].idx_q] = np.pi
    with pytest.raises(StiffnessError, match=r"loop does not close.*check the joint values"):
        robot.loop.close(robot.model, robot.data, q)


# --------------------------------------------------------------------- loop declaration errors

GOOD = 'closed_loop:\n  - [coupler_end, rocker_end]\ntype: ["3D"]\nname_mot: [crank_joint]\n'


@pytest.mark.parametrize(
    ("text", "pattern"),
    [
        ('closed_loop: [[coupler_end, rocker_end]]\ntype: ["3D"]\n',
         "lacks name_mot.*needs closed_loop.*name_mot"),
        ("name_mot: [crank_joint]\n", "lacks closed_loop, type"),
        ('closed_loop: [[coupler_end, nope]]\ntype: ["3D"]\nname_mot: [crank_joint]\n',
         "loop frame 'nope' is not in the model; valid names:.*rocker_end"),
        ("closed_loop: [[coupler_end, rocker_end]\n  type: x\n", "not valid YAML"),
        ("- closed_loop\n- type\n", "must be a YAML mapping"),
        ("", "must be a YAML mapping"),
        ('closed_loop: [[coupler_end, rocker_end]]\ntype: ["2D"]\nname_mot: [crank_joint]\n',
         "loop type '2D' is not supported; use '3D'"),
        ('closed_loop: [[coupler_end, rocker_end]]\ntype: ["3D", "3D"]\nname_mot: [crank_joint]\n',
         "1 closed_loop pairs but 2 types"),
        ('closed_loop: [[coupler_end, rocker_end, tool]]\ntype: ["3D"]\nname_mot: [crank_joint]\n',
         "is not a pair of frame names"),
        ('closed_loop: [[coupler_end, rocker_end]]\ntype: ["3D"]\nname_mot: [crank]\n',
         "actuated joint 'crank' is not in the model.*Did you mean crank_joint"),
        (GOOD + "passive_joints: [coupler_joint, rockr]\n",
         "passive joint 'rockr' is not in the model.*rocker_joint"),
    ],
)
def test_loop_declaration_errors(four_bar, tmp_path, text, pattern):
    sidecar = tmp_path / "loops.yaml"
    sidecar.write_text(text)
    with pytest.raises(StiffnessError, match=pattern):
        load_robot(four_bar.urdf, frame="tool_tip", loops=sidecar)


def test_missing_loop_declaration(four_bar, tmp_path):
    with pytest.raises(StiffnessError, match="loop declaration .*nothere.yaml does not exist"):
        load_robot(four_bar.urdf, loops=tmp_path / "nothere.yaml")


def test_explicit_loop_file_overrides_sidecar(four_bar, tmp_path):
    """loops= replaces the sidecar: here the same loop with the passive joints listed."""
    sidecar = tmp_path / "explicit.yaml"
    sidecar.write_text(GOOD + "passive_joints: [rocker_joint, coupler_joint]\n")
    robot = load_robot(four_bar.urdf, frame="tool_tip", loops=sidecar)
    assert robot.loop.passive_joints == ("rocker_joint", "coupler_joint")
    q = robot.configuration(np.array([1.0, 0.0]))
    coupler, rocker = four_bar.passive_closed_form(1.0)
    assert abs(_wrap(_joint_value(robot, q, "coupler_joint") - coupler)) < 1e-9


@pytest.mark.parametrize(
    "text",
    ['closed_loop:\ntype: ["3D"]\nname_mot: [crank_joint]\n',
     'closed_loop: [[coupler_end, rocker_end]]\ntype: ["3D"]\nname_mot:\n'],
)
def test_loop_declaration_null_value(four_bar, tmp_path, text):
    sidecar = tmp_path / "loops.yaml"
    sidecar.write_text(text)
    with pytest.raises(StiffnessError, match="closed_loop|name_mot"):
        load_robot(four_bar.urdf, frame="tool_tip", loops=sidecar)


@pytest.mark.parametrize(
    ("text", "key"),
    [('closed_loop: [[coupler_end, rocker_end]]\ntype: ["3D"]\nname_mot: crank_joint\n',
      "name_mot"),
     ('closed_loop: [[coupler_end, rocker_end]]\ntype: "3D"\nname_mot: [crank_joint]\n', "type")],
)
def test_loop_declaration_scalar_instead_of_list(four_bar, tmp_path, text, key):
    sidecar = tmp_path / "loops.yaml"
    sidecar.write_text(text)
    with pytest.raises(StiffnessError, match=rf"{key}.*list"):
        load_robot(four_bar.urdf, frame="tool_tip", loops=sidecar)


def test_unreachable_from_a_seed_does_not_blame_the_reference_assembly(non_grashof_four_bar):
    robot = load_robot(non_grashof_four_bar.urdf, frame="tool_tip")
    seed = robot.configuration(np.array([0.5, 0.0]))
    with pytest.raises(StiffnessError) as info:
        robot.configuration(np.array([np.pi, 0.0]), seed=seed)
    assert "reference assembly" not in str(info.value)
