"""Batched elastostatics (stiffness.batch.kernels) against the one-at-a-time API, on random inputs.

Every batched quantity is compared with :func:`stiffness.mechanics.formulation.target_state` and
friends
at the same configurations: the Jacobian, the unit-wrench K_C basis and K_C for forces and
wrenches (base and twist basis), the compliance and K_X of both formulations by both kinematic
routes (kinematic Hessians; generalized-gravity derivatives of a unit point mass), the
definiteness classes, the critical load factor and the Table IV definiteness scan.

Robots: UR5 (all six joints, or only the first three compliant), Panda (seven arm joints,
fingers rigid), the SK120 (its parallelogram loop) and, because a parallelogram's multiplier
term vanishes identically, a crank-rocker four-bar written here as a URDF (a "3D" pair, and the
same linkage cut inside a link and closed by a "6D" weld).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from stiffness.batch import kernels as batch
from stiffness.errors import SingularConfigurationError, StiffnessError
from stiffness.mechanics.formulation import (
    DEFINITENESS_CLASSES,
    cartesian_stiffness,
    compliance,
    definiteness,
    target_state,
    target_states,
)
from stiffness.robot.robot import load_robot

RTOL = 1e-10
#: Closed loops go through a pseudo-inverse of the passive constraint block (condition numbers
#: up to ~1e2 here): round-off is amplified accordingly.
RTOL_LOOP = 1e-9
UR5_K = np.array([3e5, 3e5, 2e5, 4e4, 4e4, 4e4])
PANDA_ARM = [f"panda_joint{i}" for i in range(1, 8)]


def _close(a, b, rtol=RTOL):
    """Entrywise agreement relative to the largest entry of the reference."""
    a, b = np.asarray(a), np.asarray(b)
    scale = max(float(np.abs(b).max()), 1e-300)
    return float(np.abs(a - b).max()) <= rtol * scale


# ------------------------------------------------------------------------------ robots


@pytest.fixture(scope="module")
def ur5():
    return load_robot("ur5")


@pytest.fixture(scope="module")
def ur5_arm():
    return load_robot("ur5", compliant_joints=["shoulder_pan_joint", "shoulder_lift_joint",
                                               "elbow_joint"])


@pytest.fixture(scope="module")
def panda():
    return load_robot("panda", compliant_joints=PANDA_ARM)


@pytest.fixture(scope="module")
def sk120():
    return load_robot("sk120")


def _joint(name, parent, child, xyz=(0, 0, 0), rpy=(0, 0, 0), kind="revolute"):
    axis = '<axis xyz="0 0 1"/><limit effort="1" velocity="1" lower="-7" upper="7"/>'
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/>'
            f'<child link="{child}"/><origin xyz="{" ".join(map(repr, map(float, xyz)))}" '
            f'rpy="{" ".join(map(repr, map(float, rpy)))}"/>'
            f'{axis if kind == "revolute" else ""}</joint>')


def _four_bar_closed_form(phi, a, b, c, d):
    crank_end = a * np.array([np.cos(phi), np.sin(phi)])
    to_pivot = np.array([d, 0.0]) - crank_end
    e = np.linalg.norm(to_pivot)
    coupler = np.arctan2(to_pivot[1], to_pivot[0]) + np.arccos((b * b + e * e - c * c)
                                                               / (2 * b * e))
    end = crank_end + b * np.array([np.cos(coupler), np.sin(coupler)])
    return coupler, np.arctan2(end[1], end[0] - d)


def _write_four_bar(folder, weld: bool):
    """Crank-rocker four-bar (0.2, 0.7, 0.5, ground 0.6) on a tilted plane, a tool joint on the
    coupler carrying the target. ``weld``: the rocker's far end carries a copy of the ground,
    welded ("6D") to it, instead of a point contact of the coupler and rocker ends ("3D")."""
    a, b, c, d = 0.2, 0.7, 0.5, 0.6
    beta0, psi0 = _four_bar_closed_form(0.0, a, b, c, d)
    links = ["base_link", "plane", "crank", "coupler", "coupler_end", "tool", "tool_tip",
             "rocker"]
    joints = [
        _joint("mount", "base_link", "plane", (0.1, -0.2, 0.3), (0.3, -0.5, 0.7), "fixed"),
        _joint("crank_joint", "plane", "crank"),
        _joint("coupler_joint", "crank", "coupler", (a, 0, 0), (0, 0, beta0)),
        _joint("coupler_end_joint", "coupler", "coupler_end", (b, 0, 0), kind="fixed"),
        _joint("tool_joint", "coupler", "tool", (0.35 * b, 0.15, 0)),
        _joint("tool_tip_joint", "tool", "tool_tip", (0.25, 0.05, 0), kind="fixed"),
    ]
    if weld:
        # the rocker hangs from the coupler end (towards the ground pivot, absolute angle
        # psi0 + pi); its far end, a copy of the ground pivot frame, is welded to it
        links += ["pivot_copy", "pivot"]
        joints += [
            _joint("rocker_joint", "coupler_end", "rocker", rpy=(0, 0, psi0 + np.pi - beta0)),
            _joint("pivot_joint", "rocker", "pivot_copy", (c, 0, 0),
                   rpy=(0, 0, -(psi0 + np.pi))),
            _joint("pivot_fixed", "plane", "pivot", (d, 0, 0), kind="fixed"),
        ]
        sidecar = ('closed_loop:\n  - [pivot, pivot_copy]\ntype: ["6D"]\n'
                   'name_mot: [crank_joint, tool_joint]\n')
    else:
        links += ["rocker_end"]
        joints += [
            _joint("rocker_joint", "plane", "rocker", (d, 0, 0), (0, 0, psi0)),
            _joint("rocker_end_joint", "rocker", "rocker_end", (c, 0, 0), kind="fixed"),
        ]
        sidecar = ('closed_loop:\n  - [coupler_end, rocker_end]\ntype: ["3D"]\n'
                   'name_mot: [crank_joint, tool_joint]\n')
    body = "".join(f'<link name="{x}"/>' for x in links) + "".join(joints)
    urdf = folder / ("welded.urdf" if weld else "fourbar.urdf")
    urdf.write_text(f'<?xml version="1.0"?>\n<robot name="fb">{body}</robot>\n')
    urdf.with_suffix(".loops.yaml").write_text(sidecar)
    return urdf


@pytest.fixture(scope="module")
def four_bar(tmp_path_factory):
    return load_robot(_write_four_bar(tmp_path_factory.mktemp("fourbar"), weld=False),
                      frame="tool_tip")


@pytest.fixture(scope="module")
def welded_four_bar(tmp_path_factory):
    path = _write_four_bar(tmp_path_factory.mktemp("welded"), weld=True)
    # "6D" loop pairs load and close: an error here is a failure, not a skip
    robot = load_robot(path, frame="tool_tip")
    robot.configuration(np.array([0.3, 0.2]))
    return robot


def _random_q(robot, m, seed):
    pin.seed(seed)
    return np.array([robot.follow(pin.randomConfiguration(robot.model)) for _ in range(m)])


def _sk120_coords(m, seed):
    rng = np.random.default_rng(seed)
    lo = np.deg2rad([-180, -70, -115, -180, -180, -180])
    hi = np.deg2rad([180, 70, 35, 180, 180, 180])
    return lo + rng.uniform(size=(m, 6)) * (hi - lo)


def _loop_conditioned(robot, q, threshold=1e-2):
    """Configurations whose passive constraint block is far from singular (there the closed-loop
    quantities are well conditioned, so round-off comparisons are meaningful)."""
    keep = []
    for qi in q:
        pin.computeJointJacobians(robot.model, robot.data, qi)
        cp = robot.loop.jacobian(robot.model, robot.data)[:, robot.loop.passive_v]
        keep.append(np.linalg.svd(cp, compute_uv=False)[-1] > threshold)
    return q[np.array(keep)]


@pytest.fixture(scope="module")
def configurations(ur5, ur5_arm, panda, sk120, four_bar):
    """name -> (robot, closed configurations) on random inputs."""
    out = {
        "ur5": (ur5, _random_q(ur5, 12, 1)),
        "ur5_arm": (ur5_arm, _random_q(ur5_arm, 8, 2)),
        "panda": (panda, _random_q(panda, 10, 3)),
    }
    closed = batch.close_loops(sk120, _sk120_coords(20, 4))
    out["sk120"] = (sk120, _loop_conditioned(sk120, closed.q[closed.closed]))
    rng = np.random.default_rng(5)
    fb = batch.close_loops(four_bar, rng.uniform(-np.pi, np.pi, (10, 2)))
    out["four_bar"] = (four_bar, fb.q[fb.closed])
    return out


ROBOTS = ["ur5", "ur5_arm", "panda", "sk120", "four_bar"]


# ------------------------------------------------------------------------------ kinematics


@pytest.mark.parametrize("name", ROBOTS)
def test_kinematics_and_k_c_equal_target_state(configurations, name):
    """J, the target pose and K_C of random wrenches (base and twist basis) equal the
    one-at-a-time target_state at every configuration, to round-off."""
    robot, q = configurations[name]
    assert q.shape[0] >= 5
    tol = RTOL if robot.loop.is_open_chain else RTOL_LOOP
    rng = np.random.default_rng(10)
    wrenches = rng.normal(size=(3, 6)) * np.array([100, 100, 100, 20, 20, 20])
    kin = batch.batch_kinematics(robot, q, pose=True)
    assert kin.valid.all()
    k_c = batch.complementary_stiffness(kin, wrenches)
    k_c_twist = batch.complementary_stiffness(kin, wrenches, twist=True)
    assert k_c.shape == (q.shape[0], 3, robot.n_compliant, robot.n_compliant)
    for i, qi in enumerate(q):
        states = target_states(robot, qi, list(wrenches))
        for j, state in enumerate(states):
            assert _close(kin.jacobian[i], state.jacobian, tol)
            assert _close(k_c[i, j], state.k_c, tol)
            assert _close(k_c_twist[i, j], state.k_c_twist, tol)
        assert _close(kin.position[i], states[0].position)
        assert _close(kin.rotation[i], states[0].rotation)
        # the basis is K_C of the unit wrenches
        units = target_states(robot, qi, list(np.eye(6)))
        assert _close(kin.k_c_basis[i], np.array([s.k_c for s in units]), tol)


def test_kinematics_in_memory_bounded_blocks(configurations, monkeypatch):
    """Held in blocks (a tiny raw-Hessian budget), the kinematics are the same arrays."""
    for name in ("ur5_arm", "sk120"):
        robot, q = configurations[name]
        whole = batch.batch_kinematics(robot, q, pose=True)
        monkeypatch.setattr(batch, "_RAW_BYTES", 1)
        blocks = batch.batch_kinematics(robot, q, pose=True)
        monkeypatch.undo()
        for key in ("jacobian", "k_c_basis", "valid", "position", "rotation"):
            np.testing.assert_array_equal(getattr(blocks, key), getattr(whole, key))


def test_forces_only_basis(configurations):
    """moments=False keeps the three force components; moments are then refused."""
    robot, q = configurations["ur5"]
    kin = batch.batch_kinematics(robot, q, moments=False)
    assert kin.k_c_basis.shape[1] == 3
    force = np.array([[10.0, -20.0, 30.0]])
    full = batch.batch_kinematics(robot, q)
    assert _close(batch.complementary_stiffness(kin, force),
                  batch.complementary_stiffness(full, force))
    with pytest.raises(StiffnessError, match="moments"):
        batch.complementary_stiffness(kin, [[0, 0, 1.0, 0, 0, 5.0]])


def test_welded_loop_equals_target_state(welded_four_bar):
    """A "6D" (weld) loop pair: the batched reduced Hessian equals target_state."""
    robot = welded_four_bar
    rng = np.random.default_rng(6)
    closed = batch.close_loops(robot, rng.uniform(-np.pi, np.pi, (8, 2)))
    q = closed.q[closed.closed]
    assert q.shape[0] >= 4
    wrenches = rng.normal(size=(2, 6)) * 50
    kin = batch.batch_kinematics(robot, q)
    k_c = batch.complementary_stiffness(kin, wrenches)
    for i, qi in enumerate(q):
        for j, state in enumerate(target_states(robot, qi, list(wrenches))):
            assert _close(k_c[i, j], state.k_c, 1e-9)
            assert _close(kin.jacobian[i], state.jacobian, 1e-9)


def test_multiplier_term_is_exercised(four_bar):
    """On the crank-rocker the multiplier term of the closed-loop K_C is large: dropping it
    would change K_C by O(1), so the agreement above tests it."""
    q = batch.close_loops(four_bar, np.array([[0.7, 0.3]])).q
    force = np.array([[30.0, -40.0, 10.0]])
    kin = batch.batch_kinematics(four_bar, q)
    with_term = batch.complementary_stiffness(kin, force)[0, 0]
    state = target_state(four_bar, q[0], force[0])
    s = state.projection
    pin.computeJointJacobians(four_bar.model, four_bar.data, q[0])
    pin.computeJointKinematicHessians(four_bar.model, four_bar.data)
    raw = pin.getFrameKinematicHessian(four_bar.model, four_bar.data, four_bar.target_frame_id,
                                       pin.LOCAL_WORLD_ALIGNED)
    hess = raw.reshape(-1).reshape(raw.shape, order="F")
    without = s.T @ np.einsum("k,kab->ab", force[0], hess[:3]) @ s
    assert np.abs(with_term - without).max() > 0.05 * np.abs(with_term).max()


# ------------------------------------------------------------------------------ loops


def test_close_loops_matches_robot_configuration(sk120):
    """Closures shared by loop coordinates equal Robot.configuration (1e-9 rad), and only the
    distinct (theta2, theta3) pairs are closed."""
    coords = _sk120_coords(6, 7)
    coords = np.concatenate([coords, coords + np.array([0.3, 0, 0, 0.2, -0.1, 0.4])])
    closed = batch.close_loops(sk120, coords)
    assert closed.closed.all()
    assert closed.n_closures == 6
    assert list(batch.loop_coordinate_indices(sk120)) == [1, 2]
    for c, q in zip(coords, closed.q, strict=True):
        assert np.abs(sk120.configuration(c) - q).max() < 1e-9


def test_close_loops_newton_from_anchors(sk120, four_bar):
    """Many keys per anchor cell (closed by batched Newton from the cell's anchor) equal
    Robot.configuration; the result does not depend on the order of the rows."""
    rng = np.random.default_rng(8)
    coords = _sk120_coords(80, 9)
    coords[:, 1:3] = coords[:1, 1:3] + rng.uniform(-0.25, 0.25, (80, 2))  # ~9 cells
    closed = batch.close_loops(sk120, coords)
    assert closed.closed.all() and closed.n_closures == 80
    for c, q in zip(coords[::7], closed.q[::7], strict=True):
        assert np.abs(sk120.configuration(c) - q).max() < 1e-9
    order = rng.permutation(80)
    np.testing.assert_array_equal(batch.close_loops(sk120, coords[order]).q, closed.q[order])
    # a four-bar all around the crank's circle (large multiplier term, no parallelogram)
    crank = np.linspace(-np.pi, np.pi, 50)
    closed = batch.close_loops(four_bar, np.column_stack([crank, np.zeros(50)]))
    assert closed.closed.all()
    for c, q in zip(crank[::5], closed.q[::5], strict=True):
        assert np.abs(four_bar.configuration(np.array([c, 0.0])) - q).max() < 1e-9


def test_close_loops_open_chain_and_unreachable(ur5, four_bar):
    closed = batch.close_loops(ur5, np.zeros((3, 6)))
    assert closed.closed.all() and closed.n_closures == 0
    assert batch.loop_coordinate_indices(ur5).size == 0
    # the coupler tool joint does not touch the loop: one closure for two configurations
    shared = batch.close_loops(four_bar, np.array([[0.4, 0.1], [0.4, -2.0]]))
    assert shared.n_closures == 1 and shared.closed.all()
    with pytest.raises(StiffnessError, match="coordinates"):
        batch.close_loops(ur5, np.zeros((2, 5)))
    with pytest.raises(StiffnessError, match="finite"):
        batch.close_loops(ur5, np.full((1, 6), np.nan))


def test_unclosable_configuration_is_flagged(tmp_path):
    """A triple-rocker whose crank cannot reach pi: those configurations are flagged, not
    raised, and the reachable ones are closed."""
    a, b, c, d = 0.5, 0.3, 0.35, 0.6
    beta0, psi0 = _four_bar_closed_form(0.0, a, b, c, d)
    links = ["base_link", "crank", "coupler", "coupler_end", "rocker", "rocker_end"]
    joints = [
        _joint("crank_joint", "base_link", "crank"),
        _joint("coupler_joint", "crank", "coupler", (a, 0, 0), (0, 0, beta0)),
        _joint("coupler_end_joint", "coupler", "coupler_end", (b, 0, 0), kind="fixed"),
        _joint("rocker_joint", "base_link", "rocker", (d, 0, 0), (0, 0, psi0)),
        _joint("rocker_end_joint", "rocker", "rocker_end", (c, 0, 0), kind="fixed"),
    ]
    body = "".join(f'<link name="{x}"/>' for x in links) + "".join(joints)
    urdf = tmp_path / "rockers.urdf"
    urdf.write_text(f'<?xml version="1.0"?>\n<robot name="r">{body}</robot>\n')
    urdf.with_suffix(".loops.yaml").write_text(
        'closed_loop:\n  - [coupler_end, rocker_end]\ntype: ["3D"]\nname_mot: [crank_joint]\n')
    robot = load_robot(urdf, frame="coupler_end")
    closed = batch.close_loops(robot, np.array([[0.1], [np.pi], [-0.1]]))
    assert closed.closed.tolist() == [True, False, True]
    assert np.isnan(closed.q[1]).all()


# ------------------------------------------------------------------------------ stiffness


@pytest.mark.parametrize("name", ROBOTS)
@pytest.mark.parametrize("formulation", ["enhanced", "conventional"])
def test_evaluate_equals_one_at_a_time(configurations, name, formulation):
    """Compliance and K_X (translational, forces; 6x6 under wrenches where J is square) equal
    formulation.compliance / cartesian_stiffness; where those raise, the batch flags the entry
    and returns NaN."""
    robot, q = configurations[name]
    tol = RTOL if robot.loop.is_open_chain else RTOL_LOOP
    rng = np.random.default_rng(11)
    k_theta = rng.uniform(2e4, 4e5, robot.n_compliant)
    forces = rng.normal(size=(2, 3)) * 300
    cases = [(forces, 3)]
    if robot.n_compliant == 6:
        cases.append((np.hstack([forces, rng.normal(size=(2, 3)) * 30]), 6))
    for loads, rows in cases:
        result = batch.evaluate(robot, q, loads, k_theta, formulation)
        assert result.rows == rows and result.valid.all()
        for i, qi in enumerate(q):
            for j, load in enumerate(loads):
                state = target_state(robot, qi, load)
                assert _close(result.k_c[i, j], state.k_c, tol)
                tangent = np.diag(k_theta) - (state.k_c if formulation == "enhanced" else 0)
                c = compliance(state.jacobian[:rows], tangent)
                assert _close(result.compliance[i, j], c, 1e-9)
                try:
                    k_x = cartesian_stiffness(c)
                except SingularConfigurationError:
                    assert not result.regular[i, j]
                    assert np.isnan(result.k_x[i, j]).all()
                    continue
                assert result.regular[i, j]
                cond = np.linalg.cond(c)
                assert _close(result.k_x[i, j], k_x, max(tol, 1e-14 * cond))


@pytest.mark.parametrize("name", ROBOTS)
def test_gravity_route_equals_hessian_route(configurations, name):
    """One force: the generalized-gravity route (two Pinocchio calls; on a loop with the
    closure derivatives of each distinct closure) gives the same K_C, compliance and K_X as
    the kinematic-Hessian route (itself checked against target_state)."""
    robot, q = configurations[name]
    k_theta = np.linspace(5e4, 2e5, robot.n_compliant)
    force = np.array([[120.0, -80.0, -250.0]])
    fast = batch.evaluate(robot, q, force, k_theta, method="gravity")
    slow = batch.evaluate(robot, q, force, k_theta, method="hessian")
    assert _close(fast.k_c, slow.k_c)
    assert _close(fast.jacobian, slow.jacobian)
    assert _close(fast.compliance, slow.compliance)
    regular = fast.regular & slow.regular
    np.testing.assert_array_equal(fast.regular, slow.regular)
    if regular.any():  # the four-bar's two joints give no regular 3x3 K_X
        assert _close(fast.k_x[regular], slow.k_x[regular], 1e-8)
    jac, k_c = batch.single_force_kinematics(robot, q, force[0])
    assert _close(k_c, slow.k_c[:, 0]) and _close(jac, slow.jacobian)


def test_evaluate_blocks_and_kinematics_input(configurations):
    """Splitting into blocks, or passing precomputed kinematics, changes nothing."""
    robot, q = configurations["panda"]
    loads = np.array([[0.0, 0.0, -200.0], [50.0, 10.0, 0.0]])
    k_theta = np.full(7, 1e5)
    whole = batch.evaluate(robot, q, loads, k_theta)
    blocks = batch.evaluate(robot, q, loads, k_theta, block=3)
    given = batch.evaluate(robot, batch.batch_kinematics(robot, q, moments=False), loads, k_theta)
    for other in (blocks, given):
        np.testing.assert_array_equal(other.k_x, whole.k_x)
        np.testing.assert_array_equal(other.compliance, whole.compliance)


def test_indefinite_tangent_goes_through_lu(ur5):
    """Under a huge load K_theta - K_C is indefinite: the Cholesky path declines and the LU
    path gives the one-at-a-time compliance."""
    q = np.array([[0.3, -1.0, 1.2, -0.7, 1.1, 0.4]])
    force = np.array([[0.0, 0.0, -5e6]])
    k_theta = np.full(6, 1e4)
    state = target_state(ur5, q[0], force[0])
    tangent = np.diag(k_theta) - state.k_c
    assert definiteness(tangent) == "ID"
    result = batch.evaluate(ur5, q, force, k_theta)
    assert _close(result.compliance[0, 0], compliance(state.jacobian[:3], tangent), 1e-9)


def test_singular_entries_are_flagged(ur5):
    """At q = 0 the UR5 is singular (K_X undefined): NaN and regular False, where the
    one-at-a-time API raises; a singular tangent gives a NaN compliance."""
    q = np.zeros((1, 6))
    state = target_state(ur5, q[0], np.zeros(3))
    with pytest.raises(SingularConfigurationError):
        cartesian_stiffness(compliance(state.jacobian, np.diag(UR5_K)))
    result = batch.evaluate(ur5, q, [[0.0, 0, 0, 0, 0, 0]], UR5_K)
    assert not result.regular[0, 0] and np.isnan(result.k_x).all()
    c, ok = batch.compliance(np.ones((1, 3, 2)), np.zeros((1, 2, 2)))
    assert not ok[0] and np.isnan(c).all()
    k_x, ok = batch.cartesian_stiffness(np.array([[[1.0, 0.0], [0.0, 0.0]],
                                                  [[2.0, 1.0], [1.0, 2.0]]]))
    assert ok.tolist() == [False, True]
    assert _close(k_x[1], np.linalg.inv([[2.0, 1.0], [1.0, 2.0]]))


def test_batched_linear_algebra_on_random_matrices():
    """compliance / cartesian_stiffness on stacks mixing symmetric positive definite,
    indefinite and asymmetric tangents equal NumPy's solve and inv."""
    rng = np.random.default_rng(12)
    m, n, r = 300, 6, 3
    a = rng.normal(size=(m, n, n))
    tangent = a @ np.swapaxes(a, 1, 2) + 0.1 * np.eye(n)
    tangent[::3] -= 4.0 * np.eye(n)  # indefinite
    tangent[1::7] += 0.3 * rng.normal(size=(len(range(1, m, 7)), n, n))  # asymmetric
    jac = rng.normal(size=(m, r, n))
    c, ok = batch.compliance(jac, tangent)
    assert ok.all()
    ref = jac @ np.linalg.solve(tangent, np.swapaxes(jac, 1, 2))
    for i in range(m):
        assert _close(c[i], ref[i], 1e-9)
    k_x, regular = batch.cartesian_stiffness(ref)
    assert regular.all()
    inv = np.linalg.inv(ref)
    for i in range(m):
        assert _close(k_x[i], inv[i], 1e-8 * max(1.0, np.linalg.cond(ref[i]) * 1e-6))


# ------------------------------------------------------------------------------ definiteness


def test_definiteness_codes_match_formulation():
    rng = np.random.default_rng(13)
    mats = []
    for eig in ([1, 2, 3], [0, 2, 3], [-1, -2, -3], [0, -2, -3], [-1, 2, 3], [0, 0, 0],
                [1e-12, 1, 2], [-1e-12, 1, 2], [0, 0, 5]):
        u = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        mats.append(u @ np.diag(eig) @ u.T + 0.3 * np.triu(rng.normal(size=(3, 3)), 1) * 0)
    mats.append(rng.normal(size=(3, 3)))  # asymmetric: its symmetric part decides
    # diagonally dominant (decided by Gershgorin discs) and borderline ones (by eigenvalues)
    for sign in (1.0, -1.0):
        mats.append(sign * (np.diag([5.0, 7.0, 9.0]) + 0.1 * rng.normal(size=(3, 3))))
        mats.append(sign * np.diag([1.0, 1.0, 2e-9]))
        mats.append(sign * np.diag([1.0, 1.0, 5e-10]))
    mats = np.array(mats)
    codes = batch.definiteness_codes(mats)
    names = batch.class_names(codes)
    for mat, name in zip(mats, names, strict=True):
        assert name == definiteness(mat)
    assert set(names) >= {"PD", "PSD", "ND", "NSD", "ID"}
    nan_codes = batch.definiteness_codes(np.full((2, 3, 3), np.nan))
    assert (nan_codes == batch.INVALID_CLASS).all()
    assert list(batch.class_names(nan_codes)) == ["", ""]
    assert list(DEFINITENESS_CLASSES) == list(batch.CLASS_CODES)


def test_definiteness_map_and_principal_stiffness(configurations):
    """Classes of K_C and K_theta - K_C, det sign, critical factor and principal values equal
    their one-at-a-time definitions."""
    robot, q = configurations["sk120"]
    k_theta = np.diag([1.4e6, 4.0e5, 9.3e5])
    loads = np.array([[100.0, 100, 100], [-100.0, 100, -100], [0, 0, -3e4]])
    kin = batch.batch_kinematics(robot, q, moments=False)
    dmap = batch.definiteness_map(kin, loads, k_theta)
    result = batch.evaluate(robot, kin, loads, np.diag(k_theta))
    values, vectors = batch.principal_stiffness(result.k_x)
    k_half = np.diag(1 / np.sqrt(np.diag(k_theta)))
    for i, qi in enumerate(q):
        for j, load in enumerate(loads):
            k_c = target_state(robot, qi, load).k_c
            assert batch.class_names(dmap.k_c_class[i, j]) == definiteness(k_c)
            assert batch.class_names(dmap.tangent_class[i, j]) == definiteness(k_theta - k_c)
            det = np.linalg.det(k_c)
            if abs(det) > 1e-9 * np.abs(k_c).max() ** 3:  # the sign is not round-off
                assert dmap.determinant_positive[i, j] == (det > 0)
            top = np.linalg.eigvalsh(k_half @ (0.5 * (k_c + k_c.T)) @ k_half)[-1]
            expected = 1 / top if top > 0 else np.inf
            assert dmap.critical_factor[i, j] == pytest.approx(expected, rel=1e-9)
            sym = 0.5 * (result.k_x[i, j] + result.k_x[i, j].T)
            assert _close(values[i, j], np.linalg.eigvalsh(sym))
            assert _close(sym @ vectors[i, j], vectors[i, j] * values[i, j], 1e-9)
        assert _close(dmap.k_c_diagonal[i], [np.diag(target_state(robot, qi, f).k_c)
                                             for f in np.eye(3)])


def test_batched_definiteness_scan_equals_definiteness_scan(sk120):
    """scan.batched_definiteness_scan gives the classes of scan.definiteness_scan on a slice of
    the Table IV grid (closures differ by the Newton tolerance only)."""
    from stiffness.papers.reproduction import table4_grid, table4_loads
    from stiffness.workspace.definiteness import batched_definiteness_scan, definiteness_scan

    grid = table4_grid()[::97]
    # keep the configurations away from the flattened parallelogram, where the closed-loop
    # quantities amplify the closure tolerance (1e-11 m) by up to ~1e6
    closed = batch.close_loops(sk120, grid)
    conditioned = _loop_conditioned(sk120, closed.q)
    keep = [any(np.array_equal(q, c) for c in conditioned) for q in closed.q]
    grid = grid[np.array(keep)]
    assert grid.shape[0] > 40
    _, loads = table4_loads()
    k_theta = np.diag(sk120.defaults["k_theta_SI"])
    calls = []
    fast = batched_definiteness_scan(sk120, grid, loads, k_theta, chunk=25,
                                     progress=lambda d, t: calls.append((d, t)))
    slow = definiteness_scan(sk120, grid, loads, k_theta)
    np.testing.assert_array_equal(fast.classes, slow.classes)
    np.testing.assert_array_equal(fast.tangent_classes, slow.tangent_classes)
    np.testing.assert_array_equal(fast.determinant_positive, slow.determinant_positive)
    # the critical factor is 1 / lambda_max(K^-1/2 K_C K^-1/2): the closure's error moves that
    # eigenvalue by an amount set by K_C's scale, so it is compared on that scale (a factor of
    # 3e5 against 3e3 elsewhere has an eigenvalue 100 times smaller, and its relative error
    # 100 times larger)
    top_fast, top_slow = 1.0 / fast.critical_factor, 1.0 / slow.critical_factor
    np.testing.assert_allclose(top_fast, top_slow, rtol=1e-7, atol=1e-7 * np.max(top_slow))
    np.testing.assert_allclose(fast.k_c_diagonal, slow.k_c_diagonal, rtol=1e-7, atol=1e-9)
    assert calls[-1] == (grid.shape[0], grid.shape[0]) and len(calls) == -(-grid.shape[0] // 25)


# ------------------------------------------------------------------------------ errors


def test_input_errors(ur5, sk120):
    with pytest.raises(StiffnessError, match="Pinocchio q"):
        batch.batch_kinematics(ur5, np.zeros((2, 5)))
    with pytest.raises(StiffnessError, match="force"):
        batch.evaluate(ur5, np.zeros((1, 6)), [[1.0, 2.0]], UR5_K)
    with pytest.raises(StiffnessError, match="finite"):
        batch.evaluate(ur5, np.zeros((1, 6)), [[np.nan, 0, 0]], UR5_K)
    with pytest.raises(StiffnessError, match="positive"):
        batch.evaluate(ur5, np.zeros((1, 6)), [[0, 0, 1.0]], -UR5_K)
    with pytest.raises(StiffnessError, match="formulation"):
        batch.evaluate(ur5, np.zeros((1, 6)), [[0, 0, 1.0]], UR5_K, formulation="exact")
    with pytest.raises(StiffnessError, match="rows"):
        batch.evaluate(ur5, np.zeros((1, 6)), [[0, 0, 1.0]], UR5_K, rows=4)
    with pytest.raises(StiffnessError, match="method"):
        batch.evaluate(ur5, np.zeros((1, 6)), [[0, 0, 1.0]], UR5_K, method="magic")
    with pytest.raises(StiffnessError, match="single force"):
        batch.evaluate(sk120, batch.close_loops(sk120, np.zeros((1, 6))).q,
                       [[0, 0, 1.0], [1.0, 0, 0]], [1e6, 1e6, 1e6], method="gravity")


# ------------------------------------------------------------------------------ benchmarks

try:  # pytest-benchmark is optional: `pytest --benchmark-only tests/test_batch.py`
    import pytest_benchmark  # noqa: F401

    HAVE_BENCHMARK = True
except ImportError:  # pragma: no cover - depends on the environment
    HAVE_BENCHMARK = False

if HAVE_BENCHMARK:
    _BENCH_M = 2048
    _FORCE = np.array([[120.0, -80.0, -250.0]])

    @pytest.mark.benchmark(group="ur5-per-batch-of-2048")
    def test_benchmark_batched_kx(benchmark, ur5):
        """Batched loaded K_X of 2048 UR5 configurations (scripts/bench.py has the ratios)."""
        q = _random_q(ur5, _BENCH_M, 20)
        result = benchmark.pedantic(batch.evaluate, args=(ur5, q, _FORCE, UR5_K), rounds=5,
                                    iterations=1)
        assert result.k_x.shape == (_BENCH_M, 1, 3, 3)

    @pytest.mark.benchmark(group="ur5-per-batch-of-2048")
    def test_benchmark_bare_pinocchio(benchmark, ur5):
        """The floor: computeStaticTorqueDerivatives once per configuration."""
        q = _random_q(ur5, _BENCH_M, 20)
        fext = pin.StdVec_Force()
        for _ in range(ur5.model.njoints):
            fext.append(pin.Force.Zero())
        frame = ur5.model.frames[ur5.target_frame_id]
        fext[frame.parentJoint] = pin.Force(_FORCE[0], np.cross(frame.placement.translation,
                                                                _FORCE[0]))

        def bare():
            for qi in q:
                pin.computeStaticTorqueDerivatives(ur5.model, ur5.data, qi, fext)

        benchmark.pedantic(bare, rounds=5, iterations=1)


def test_load_definiteness_equals_separate_definitions():
    """One eigen-decomposition of the scaled K_C gives the classes of K_C and K_theta - K_C
    (definiteness_codes), the critical factor (critical_load_factor) and the sign of det K_C,
    also for rank-deficient K_C, eigenvalues near the class tolerance and zero loads."""
    rng = np.random.default_rng(31)
    n, m = 4, 400
    k_theta = np.diag(rng.uniform(1e4, 8e4, n))
    vectors = np.linalg.qr(rng.normal(size=(m, n, n)))[0]
    values = rng.normal(size=(m, n)) * rng.uniform(1e2, 1e5, (m, 1))
    values[:100, 0] = 0.0                                           # rank-deficient
    values[100:200, 1] = 3e-9 * np.abs(values[100:200]).max(axis=1)  # near the tolerance
    values[200:260] = 0.0                                           # no load
    k_c = vectors @ (values[:, :, None] * np.swapaxes(vectors, 1, 2))
    k_c[300:320] *= 50.0                                            # beyond the critical load
    k_c[320] = np.nan
    d = batch.load_definiteness(k_theta, k_c)
    np.testing.assert_array_equal(d.k_c_class, batch.definiteness_codes(k_c))
    np.testing.assert_array_equal(d.tangent_class, batch.definiteness_codes(k_theta - k_c))
    np.testing.assert_array_equal(d.critical_factor, batch.critical_load_factor(k_theta, k_c))
    assert (d.tangent_class[300:320] != batch.CLASS_CODES["PD"]).any()
    finite = np.all(np.isfinite(k_c), axis=(1, 2))
    det = np.linalg.det(np.where(finite[:, None, None], k_c, 0.0))
    scale = np.abs(np.where(finite[:, None, None], k_c, 0.0)).max(axis=(1, 2))
    sure = finite & (np.abs(det) > 1e-9 * scale ** n)
    np.testing.assert_array_equal(d.determinant_positive[sure], det[sure] > 0)
    assert not d.determinant_positive[320]


@pytest.mark.parametrize("name", ["ur5", "ur5_arm", "panda"])
def test_unit_force_diagonal_from_the_jacobian(configurations, name):
    """The unit-force K_C diagonal read off the Jacobian equals the Hessian basis's."""
    robot, q = configurations[name]
    kin = batch.batch_kinematics(robot, q, moments=False)
    expected = np.diagonal(kin.k_c_basis[:, :3], axis1=-2, axis2=-1)
    assert _close(batch.unit_force_diagonal(robot, kin.jacobian), expected)


def test_one_degree_of_freedom_robot_batched_like_one_pose(tmp_path):
    """A robot with one joint (Pinocchio's bindings squeeze its Jacobians to shape (6,)):
    every batched route gives the single-pose K_C and compliance, and a scan runs."""
    from stiffness.cli.main import main

    inertial = ('<inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" '
                'izz="1"/></inertial>')
    urdf = tmp_path / "one.urdf"
    urdf.write_text(
        f'<robot name="one"><link name="a">{inertial}</link><link name="b">{inertial}</link>'
        '<link name="tip"/><joint name="j1" type="revolute"><parent link="a"/>'
        '<child link="b"/><origin xyz="0 0 0.5"/><axis xyz="0 1 0"/>'
        '<limit lower="-3" upper="3" effort="1" velocity="1"/></joint>'
        '<joint name="t" type="fixed"><parent link="b"/><child link="tip"/>'
        '<origin xyz="0.5 0 0.2"/></joint></robot>')
    robot = load_robot(str(urdf))
    q = batch.tree_configurations(robot, np.linspace(-2.0, 2.0, 9)[:, None])
    force = np.array([3.0, 0.0, -10.0])
    for method in ("gravity", "hessian"):
        out = batch.evaluate(robot, q, force, [100.0], method=method)
        for i in range(q.shape[0]):
            state = target_state(robot, q[i], force)
            np.testing.assert_allclose(out.k_c[i, 0], state.k_c, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(out.compliance[i, 0],
                                       compliance(state.jacobian[:3],
                                                  np.diag([100.0]) - state.k_c),
                                       rtol=1e-10, atol=1e-15)
    assert main(["scan", "--robot", str(urdf), "--kq", "100", "--samples", "30", "--out",
                 str(tmp_path / "scan"), "--no-plots", "--quiet"]) == 0
