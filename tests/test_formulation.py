"""Stiffness formulations (stiffness.mechanics.formulation) against finite differences and the
papers.

* K_C = d(J^T W)/d theta: central differences of J(theta)^T W over the compliant coordinates, the
  loops closed by Robot.configuration (UR5, Panda, SK120), for a pure force and a 6-D wrench;
  the twist-basis K_C^tw = d(J_b^T W_b)/d theta at fixed body wrench likewise.
* The SK120's constrained (loop-closed) Jacobian: central differences of the target position.
* Symmetry (pure force) and linearity in the load of K_C, A&S's energy argument (eq. 14/15),
  congruence of definiteness, the redundant compliance (Panda): hypothesis property tests.
* Definiteness classes on hand-made matrices; every error path of the module.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import HealthCheck, assume, event, given, settings
from hypothesis import strategies as st

from stiffness.errors import SingularConfigurationError, StiffnessError
from stiffness.mechanics.formulation import (
    as_wrench,
    cartesian_stiffness,
    compliance,
    definiteness,
    ellipsoid,
    joint_connection_stiffness,
    joint_stiffness,
    tangent_joint_stiffness,
    target_state,
    twist_basis_stiffness,
    work_balance,
)

PROPERTY = settings(max_examples=25, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])

unit = st.floats(0.0, 1.0)
angle = st.floats(-np.pi, np.pi)
# unit vectors: azimuth and sine of elevation
direction = st.tuples(st.floats(-np.pi, np.pi), st.floats(-1.0, 1.0)).map(
    lambda a: np.array([np.sqrt(1 - a[1] ** 2) * np.cos(a[0]),
                        np.sqrt(1 - a[1] ** 2) * np.sin(a[0]), a[1]]))

UR5_Q = np.array([0.3, -1.0, 1.2, -0.7, 1.1, 0.4])
UR5_K = np.array([3e4, 3e4, 2e4, 5e3, 5e3, 5e3])


@pytest.fixture(scope="module")
def robots(sk120, ur5, ur5_arm, panda, sk120_coords):
    out = {"sk120": sk120, "ur5": ur5, "ur5_arm": ur5_arm, "panda": panda}
    out["_sk120_coords"] = sk120_coords
    return out


def _coordinates(robots, robot, draw_unit, angles):
    """Workspace coordinates: SK120 from six numbers in [0, 1]; others from angles (rad)."""
    if robot.name == "sk120":
        return robots["_sk120_coords"](draw_unit)
    c = np.full(robot.n_coordinates, 0.02)  # Panda's finger slides (m) stay at 2 cm
    n = min(len(angles), robot.n_coordinates, 7)  # revolute arm joints
    c[:n] = angles[:n]
    return c


def _random_coordinates(robot, rng, sk120_coords):
    if robot.name == "sk120":
        return sk120_coords(rng.uniform(0, 1, 6))
    return _coordinates(None, robot, None, rng.uniform(-np.pi, np.pi, robot.n_coordinates))


# ------------------------------------------------------------------ K_C and J against finite diff.


@pytest.mark.parametrize("name", ["ur5", "panda", "sk120"])
@pytest.mark.parametrize("kind", ["force", "wrench"])
def test_kc_is_fd_of_joint_torques(name, kind, robots, fd, sk120_coords):
    """K_C = d(J^T W)/d theta to 1e-6 relative at random (workspace) configurations."""
    robot = robots[name]
    rng = np.random.default_rng(100 + len(name) + len(kind))
    for _ in range(3):
        coords = _random_coordinates(robot, rng, sk120_coords)
        load = rng.normal(size=3) * 1e3
        if kind == "wrench":
            load = np.r_[load, rng.normal(size=3) * 1e2]
        wrench = as_wrench(load)
        state = target_state(robot, robot.configuration(coords), load)
        numeric = fd.coordinates(robot, coords, lambda s, w=wrench: s.jacobian.T @ w)
        assert state.k_c.shape == (robot.n_compliant, robot.n_compliant)
        assert fd.rel_err(state.k_c, numeric) <= 1e-6


@pytest.mark.parametrize("name", ["ur5", "sk120"])
def test_twist_basis_kc_is_fd_at_fixed_body_wrench(name, robots, fd, sk120_coords):
    """k_c_twist = d(J_b^T W_b)/d theta with W_b = R^T W held fixed in the target's body axes."""
    robot = robots[name]
    rng = np.random.default_rng(7)
    for _ in range(3):
        coords = _random_coordinates(robot, rng, sk120_coords)
        wrench = np.r_[rng.normal(size=3) * 1e3, rng.normal(size=3) * 1e2]
        state = target_state(robot, robot.configuration(coords), wrench)
        rot = state.rotation
        body_wrench = np.r_[rot.T @ wrench[:3], rot.T @ wrench[3:]]

        def body_torques(s, wb=body_wrench):
            jb = np.vstack([s.rotation.T @ s.jacobian[:3], s.rotation.T @ s.jacobian[3:]])
            return jb.T @ wb

        numeric = fd.coordinates(robot, coords, body_torques)
        assert fd.rel_err(state.k_c_twist, numeric) <= 1e-6
        # and it is not the base-frame K_C: the body-axes term is O(1) here
        assert fd.rel_err(state.k_c, numeric) > 1e-2


def test_sk120_constrained_jacobian_is_fd_of_closed_position(sk120, fd, sk120_coords):
    """J (loop closed, compliant joints) = d position / d theta and d orientation / d theta."""
    rng = np.random.default_rng(5)
    for _ in range(5):
        coords = sk120_coords(rng.uniform(0, 1, 6))
        state = target_state(sk120, sk120.configuration(coords))
        numeric = fd.coordinates(sk120, coords, lambda s: s.position)
        assert state.jacobian.shape == (6, 3)
        assert fd.rel_err(state.jacobian[:3], numeric) <= 1e-6
        # angular rows: world angular velocity, from the rotations at +-h
        h = 1e-6
        q0 = sk120.configuration(coords)
        for col, i in enumerate(sk120.compliant_in_coordinates):
            rots = []
            for sign in (1.0, -1.0):
                c = coords.copy()
                c[i] += sign * h
                rots.append(target_state(sk120, sk120.configuration(c, seed=q0)).rotation)
            omega = pin.log3(rots[0] @ rots[1].T) / (2 * h)
            np.testing.assert_allclose(state.jacobian[3:, col], omega, atol=1e-7)


def test_compliant_subset_selects_jacobian_columns(ur5, ur5_arm):
    """Rigid joints drop out: the 3-compliant-joint Jacobian and K_C are sub-blocks of the 6."""
    q = ur5.configuration(UR5_Q)
    force = np.array([100.0, -50.0, 80.0])
    full = target_state(ur5, q, force)
    arm = target_state(ur5_arm, ur5_arm.configuration(UR5_Q), force)
    np.testing.assert_allclose(arm.jacobian, full.jacobian[:, :3], atol=1e-14)
    np.testing.assert_allclose(arm.k_c, full.k_c[:3, :3], atol=1e-12)


def test_moment_makes_kc_asymmetric(ur5, fd):
    """Only a pure force gives a symmetric K_C: with a moment, K_C (checked by FD above) is not."""
    state = target_state(ur5, ur5.configuration(UR5_Q), np.array([0, 0, 0, 10.0, -20.0, 5.0]))
    asym = np.abs(state.k_c - state.k_c.T).max()
    assert asym > 0.1 * np.abs(state.k_c).max()


# ------------------------------------------------------------------------- hypothesis properties


@PROPERTY
@given(name=st.sampled_from(["sk120", "ur5", "panda"]),
       u=st.lists(unit, min_size=6, max_size=6),
       angles=st.lists(angle, min_size=7, max_size=7),
       force=st.lists(st.floats(-1e4, 1e4), min_size=3, max_size=3))
def test_kc_symmetric_for_pure_force(robots, name, u, angles, force):
    robot = robots[name]
    coords = _coordinates(robots, robot, u, np.array(angles))
    k_c = target_state(robot, robot.configuration(coords), np.array(force)).k_c
    scale = max(np.abs(k_c).max(), 1e-300)
    assert np.abs(k_c - k_c.T).max() <= 1e-10 * scale


@PROPERTY
@given(name=st.sampled_from(["sk120", "ur5", "panda"]),
       u=st.lists(unit, min_size=6, max_size=6),
       angles=st.lists(angle, min_size=7, max_size=7),
       w1=st.lists(st.floats(-1e3, 1e3), min_size=6, max_size=6),
       w2=st.lists(st.floats(-1e3, 1e3), min_size=6, max_size=6),
       alpha=st.floats(-5.0, 5.0), beta=st.floats(-5.0, 5.0))
def test_kc_linear_in_load(robots, name, u, angles, w1, w2, alpha, beta):
    robot = robots[name]
    q = robot.configuration(_coordinates(robots, robot, u, np.array(angles)))
    w1, w2 = np.array(w1), np.array(w2)
    k1 = target_state(robot, q, w1)
    k2 = target_state(robot, q, w2)
    k12 = target_state(robot, q, alpha * w1 + beta * w2)
    expected = alpha * k1.k_c + beta * k2.k_c
    # rounding floor: K_C is a sum of load x Hessian terms (Hessians O(1) m on these arms), so
    # where the load's K_C vanishes (a moment about an axis the joints do not feel) what is
    # left is round-off of |load| x |H| x eps, not a relative error
    floor = 1e-12 * (abs(alpha) * np.abs(w1).max() + abs(beta) * np.abs(w2).max())
    scale = abs(alpha) * np.abs(k1.k_c).max() + abs(beta) * np.abs(k2.k_c).max()
    assert np.abs(k12.k_c - expected).max() <= 1e-10 * scale + floor
    expected_tw = alpha * k1.k_c_twist + beta * k2.k_c_twist
    scale_tw = abs(alpha) * np.abs(k1.k_c_twist).max() + abs(beta) * np.abs(k2.k_c_twist).max()
    assert np.abs(k12.k_c_twist - expected_tw).max() <= 1e-10 * scale_tw + floor
    # a zero load gives a zero K_C
    assert np.abs(target_state(robot, q).k_c).max() == 0.0


def _square_case(robots, name, u, angles):
    """3x3 translational case (SK120, UR5 with three compliant joints): q, k_theta, reach."""
    robot = robots[name]
    coords = _coordinates(robots, robot, u, np.array(angles))
    k = np.array(robot.defaults["k_theta_SI"]) if name == "sk120" else UR5_K[:3]
    return robot, robot.configuration(coords), k


@PROPERTY
@given(name=st.sampled_from(["sk120", "ur5_arm"]),
       u=st.lists(unit, min_size=6, max_size=6),
       angles=st.lists(angle, min_size=6, max_size=6),
       fdir=direction, ratio=st.floats(1e-3, 0.3),
       ddir=direction, dsize=st.floats(1e-4, 0.02))
def test_energy_argument_eq14_eq15(robots, name, u, angles, fdir, ratio, ddir, dsize):
    """dX = J dTheta: eq. 14 with the enhanced K_X equals eq. 15 with K_theta - K_C, and eq. 15
    with K_C = 0 exceeds it by exactly 1/2 dTheta^T K_C dTheta (A&S section IV)."""
    robot, q, k = _square_case(robots, name, u, angles)
    force = fdir * ratio * k.min()  # K_C/K_theta ~ ratio * 1 m
    state = target_state(robot, q, force)
    jac = state.translational_jacobian()
    assume(np.linalg.cond(jac) < 1e6)
    k_theta = np.diag(k)
    tangent = k_theta - state.k_c
    assume(np.linalg.cond(tangent) < 1e8)
    k_x = cartesian_stiffness(compliance(jac, tangent))
    dtheta = dsize * ddir  # rad
    dx = jac @ dtheta
    works = work_balance(force, dx, k_x, dtheta, jac, k_theta, state.k_c)
    # eq. 14 and eq. 15 evaluated here from their printed definitions
    eq14 = force @ dx + 0.5 * dx @ k_x @ dx
    gamma = jac.T @ force
    eq15_enhanced = gamma @ dtheta + 0.5 * dtheta @ tangent @ dtheta
    half_kc = 0.5 * dtheta @ state.k_c @ dtheta
    scale = np.linalg.norm(force) * np.linalg.norm(dx) + np.abs(k).max() * dtheta @ dtheta
    tol = 1e-8 * scale
    assert abs(works.cartesian - eq14) <= tol
    assert abs(works.joint_enhanced - eq15_enhanced) <= tol
    assert abs(works.cartesian - works.joint_enhanced) <= tol
    assert abs((works.joint_conventional - works.cartesian) - half_kc) <= tol
    # with the conventional K_X (eq. 8) eq. 14 matches the conventional eq. 15 instead
    k_x_conv = cartesian_stiffness(compliance(jac, k_theta))
    conv = work_balance(force, dx, k_x_conv, dtheta, jac, k_theta, state.k_c)
    assert abs(conv.cartesian - conv.joint_conventional) <= tol


def _definiteness_case(robots, name, u, angles, fdir, ratio, moment):
    if name == "ur5":
        robot, k = robots["ur5"], UR5_K
        q = robot.configuration(np.array(angles))
        load = np.r_[fdir * ratio * k.min(),
                     np.array(moment) * ratio * k.min()]
        state = target_state(robot, q, load)
        jac = state.jacobian
    else:
        robot, q, k = _square_case(robots, name, u, angles)
        state = target_state(robot, q, fdir * ratio * k.min())
        jac = state.translational_jacobian()
    return jac, np.diag(k) - state.k_c


@PROPERTY
@given(name=st.sampled_from(["sk120", "ur5_arm", "ur5"]),
       u=st.lists(unit, min_size=6, max_size=6),
       angles=st.lists(angle, min_size=6, max_size=6),
       fdir=direction, ratio=st.floats(1e-3, 5.0),
       moment=st.lists(st.floats(-0.3, 0.3), min_size=3, max_size=3))
def test_definiteness_congruence_square_jacobian(robots, name, u, angles, fdir, ratio, moment):
    """For a square regular J, K_X = J^-T (K_theta - K_C) J^-1 has the inertia of K_theta - K_C
    (Sylvester): the same definiteness class, in particular PD <=> PD."""
    jac, tangent = _definiteness_case(robots, name, u, angles, fdir, ratio, moment)
    assume(np.linalg.cond(jac) < 1e5)
    eig = np.linalg.eigvalsh(0.5 * (tangent + tangent.T))
    assume(np.abs(eig).min() > 1e-6 * np.abs(eig).max())  # classes well separated from zero
    k_x = cartesian_stiffness(compliance(jac, tangent))
    event(f"K_theta - K_C is {definiteness(tangent)}")
    assert definiteness(k_x) == definiteness(tangent)
    assert (definiteness(k_x) == "PD") == bool(np.all(eig > 0))


def test_definiteness_congruence_sees_both_classes(sk120):
    """The property above is not vacuous: a growing load turns PD into indefinite at a fixed
    configuration, and K_X follows K_theta - K_C at every step."""
    q = sk120.configuration(np.deg2rad(sk120.defaults["q_deg"]))
    k_theta = np.diag(sk120.defaults["k_theta_SI"])
    classes = []
    for magnitude in np.geomspace(1e3, 1e7, 9):
        for direction_ in (np.array([0, 0, -1.0]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0])):
            state = target_state(sk120, q, magnitude * direction_)
            tangent = k_theta - state.k_c
            k_x = cartesian_stiffness(compliance(state.translational_jacobian(), tangent))
            assert definiteness(k_x) == definiteness(tangent)
            classes.append(definiteness(tangent))
    assert "PD" in classes
    assert {"ID", "ND"} & set(classes)


@PROPERTY
@given(angles=st.lists(angle, min_size=7, max_size=7),
       fdir=direction, ratio=st.floats(1e-4, 0.5),
       k=st.lists(st.floats(1e3, 1e5), min_size=7, max_size=7))
def test_redundant_compliance_symmetric_pd(panda, angles, fdir, ratio, k):
    """Panda (7 joints): C = J (K_theta - K_C)^-1 J^T, 3x3 and 6x6, is symmetric PD under a pure
    force whenever K_theta - K_C is PD (and J has full row rank)."""
    coords = np.r_[angles, 0.02]  # the second finger mimics the first
    force = fdir * ratio * min(k)
    state = target_state(panda, panda.configuration(coords), force)
    tangent = np.diag(k) - state.k_c
    assume(definiteness(tangent) == "PD")
    for jac in (state.translational_jacobian(), state.jacobian):
        assume(np.linalg.cond(jac) < 1e4)
        c = compliance(jac, tangent)
        assert c.shape == (jac.shape[0],) * 2
        assert np.abs(c - c.T).max() <= 1e-10 * np.abs(c).max()
        eig = np.linalg.eigvalsh(0.5 * (c + c.T))
        assert eig.min() > 0
        # the class is PD once the spread is within definiteness()'s relative tolerance (1e-9)
        assume(eig.min() > 1e-8 * eig.max())
        assert definiteness(c) == "PD"
        # K_X exists and is its inverse
        k_x = cartesian_stiffness(c)
        np.testing.assert_allclose(k_x @ c, np.eye(len(c)), atol=1e-6)


# --------------------------------------------------------------------- definiteness and ellipsoid


@pytest.mark.parametrize(
    ("matrix", "kwargs", "expected"),
    [
        (np.diag([1.0, 2.0, 3.0]), {}, "PD"),
        (np.diag([1.0, 0.0, 3.0]), {}, "PSD"),
        (-np.diag([1.0, 2.0, 3.0]), {}, "ND"),
        (np.diag([-1.0, 0.0, -3.0]), {}, "NSD"),
        (np.diag([1.0, -2.0, 3.0]), {}, "ID"),
        (np.zeros((3, 3)), {}, "PSD"),
        # eigenvalues 3 and 1 (symmetric [[2, 1], [1, 2]]) and -1, 3 ([[1, 2], [2, 1]])
        (np.array([[2.0, 1.0], [1.0, 2.0]]), {}, "PD"),
        (np.array([[1.0, 2.0], [2.0, 1.0]]), {}, "ID"),
        # only the symmetric part counts: [[1, 5], [-5, 1]] has symmetric part I
        (np.array([[1.0, 5.0], [-5.0, 1.0]]), {}, "PD"),
        # tolerances: 1e-12 against 1 is zero at rtol 1e-9, not at rtol 1e-15
        (np.diag([1.0, 1e-12]), {}, "PSD"),
        (np.diag([1.0, 1e-12]), {"rtol": 1e-15}, "PD"),
        (np.diag([1.0, -1e-12]), {}, "PSD"),
        (np.diag([1.0, -1e-12]), {"rtol": 1e-15}, "ID"),
        (np.diag([-1.0, 1e-3]), {"atol": 1e-2}, "NSD"),
        (np.diag([-1.0, 1e-3]), {}, "ID"),
    ],
)
def test_definiteness_classes(matrix, kwargs, expected):
    assert definiteness(matrix, **kwargs) == expected
    # invariant under congruence with a regular matrix (Sylvester)
    t = np.triu(np.ones_like(matrix)) + np.eye(len(matrix))
    if not kwargs:
        assert definiteness(t.T @ (0.5 * (matrix + matrix.T)) @ t) == expected


def test_ellipsoid_principal_values_and_directions():
    rot = pin.rpy.rpyToMatrix(0.3, -0.2, 1.1)
    values = np.array([5.0, 20.0, 100.0])
    matrix = rot @ np.diag(values) @ rot.T
    ell = ellipsoid(matrix)
    np.testing.assert_allclose(ell.values, values, rtol=1e-12)
    assert ell.symmetric
    for i in range(3):  # each direction is the matching column of rot, up to sign
        assert abs(abs(ell.directions[:, i] @ rot[:, i]) - 1.0) < 1e-12
    skew = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    asym = ellipsoid(matrix + skew)
    assert not asym.symmetric
    np.testing.assert_allclose(asym.values, values, rtol=1e-12)  # of the symmetric part


def test_tangent_joint_stiffness_formulations():
    k_theta, k_c = np.diag([3.0, 4.0]), np.array([[1.0, 0.5], [0.5, 2.0]])
    np.testing.assert_array_equal(tangent_joint_stiffness(k_theta, k_c, "enhanced"),
                                  [[2.0, -0.5], [-0.5, 2.0]])
    np.testing.assert_array_equal(tangent_joint_stiffness(k_theta, k_c, "conventional"), k_theta)


# ------------------------------------------------------------------------------------ error paths


@pytest.mark.parametrize("load", [np.ones(2), np.ones(4), np.ones(7)])
def test_wrong_size_load(ur5, load):
    q = ur5.configuration(UR5_Q)
    with pytest.raises(StiffnessError,
                       match=r"force \(fx,fy,fz in N\) or a wrench.*got \d+ values"):
        target_state(ur5, q, load)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_load(ur5, bad):
    q = ur5.configuration(UR5_Q)
    with pytest.raises(StiffnessError, match="load must be finite"):
        target_state(ur5, q, np.array([1.0, bad, 0.0]))
    with pytest.raises(StiffnessError, match="load must be finite"):
        as_wrench(np.array([1.0, 0.0, 0.0, 0.0, bad, 0.0]))


@pytest.mark.parametrize(
    ("values", "pattern"),
    [
        ([1e4, 0.0, 1e4], "finite and positive.*0.0"),
        ([1e4, -5.0, 1e4], "finite and positive.*-5.0"),
        ([1e4, np.nan, 1e4], "finite and positive"),
        ([1e4, np.inf, 1e4], "finite and positive"),
        ([1e4, 1e4], r"one joint stiffness per compliant joint \(3\), got 2"),
    ],
)
def test_bad_joint_stiffness(values, pattern):
    with pytest.raises(StiffnessError, match=pattern):
        joint_stiffness(values, 3)


def test_joint_stiffness_is_diagonal():
    np.testing.assert_array_equal(joint_stiffness([1.0, 2.0], 2), np.diag([1.0, 2.0]))


def test_unknown_formulation():
    with pytest.raises(StiffnessError, match=r"formulation must be one of .*conventional.*'magic'"):
        tangent_joint_stiffness(np.eye(2), np.eye(2), "magic")


def test_singular_tangent_stiffness_is_buckling():
    with pytest.raises(SingularConfigurationError,
                       match="K_theta - K_C is singular.*reduce the load"):
        compliance(np.eye(2), np.array([[1.0, 1.0], [1.0, 1.0]]))


def test_singular_compliance_at_ur5_singularity(ur5):
    """Elbow stretched (elbow_joint = 0): the 6x6 Jacobian loses rank; so does the wrist (q5=0)."""
    for coords in ([0.3, -1.0, 0.0, -0.7, 1.1, 0.4], [0.3, -1.0, 1.0, -0.7, 0.0, 0.4]):
        state = target_state(ur5, ur5.configuration(np.array(coords)))
        c = compliance(state.jacobian, np.diag(UR5_K))
        with pytest.raises(SingularConfigurationError, match="compliance is singular.*loses rank"):
            cartesian_stiffness(c)
        with pytest.raises(SingularConfigurationError, match="singular"):
            joint_connection_stiffness(state, np.diag(UR5_K))
    # away from the singularity it is regular
    state = target_state(ur5, ur5.configuration(UR5_Q))
    cartesian_stiffness(compliance(state.jacobian, np.diag(UR5_K)))


def test_singular_compliance_with_fewer_compliant_joints():
    from stiffness.robot.robot import load_robot

    robot = load_robot("ur5", compliant_joints=["shoulder_pan_joint", "shoulder_lift_joint"])
    state = target_state(robot, robot.configuration(UR5_Q), np.array([0.0, 0.0, -100.0]))
    c = compliance(state.translational_jacobian(), np.diag([3e4, 3e4]) - state.k_c)
    assert c.shape == (3, 3)
    with pytest.raises(SingularConfigurationError, match="fewer compliant joints than directions"):
        cartesian_stiffness(c)
    with pytest.raises(StiffnessError, match=r"needs six compliant joints \(J is \(6, 2\)\)"):
        twist_basis_stiffness(state, np.diag([3e4, 3e4]))
    with pytest.raises(StiffnessError, match="needs six compliant joints"):
        joint_connection_stiffness(state, np.diag([3e4, 3e4]))


def test_target_state_takes_coordinates_and_refuses_a_wrong_size():
    """``target_state(robot, [angles], load)`` (a list, or the SK120's 6 coordinates for its 8
    configuration values) ended in Pinocchio's C++-signature error or assertion; coordinates
    are now closed into the configuration (the same J and K_C), a wrong size is one line."""
    from stiffness.robot.robot import load_robot

    for name, coords in (("ur5", [0.0, -1.2, 1.5, -0.3, 1.57, 0.0]),
                         ("sk120", [-0.58, 0.28, -0.97, 0.0, -0.6, -1.57])):
        robot = load_robot(name)
        given = target_state(robot, coords, load=[0.0, 0.0, -100.0])
        closed = target_state(robot, robot.configuration(np.array(coords)), [0.0, 0.0, -100.0])
        np.testing.assert_array_equal(given.jacobian, closed.jacobian)
        np.testing.assert_array_equal(given.k_c, closed.k_c)
    with pytest.raises(StiffnessError, match=r"q has 2 values; give the 6 coordinates of sk120"):
        target_state(robot, [0.0, 0.0])
