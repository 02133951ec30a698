"""Exact elastostatic equilibrium (stiffness.mechanics.equilibrium) and what the linear predictions
miss.

* The exact solution is checked independently: K_theta dtheta = J(theta)^T F with J from finite
  differences of the loop-closed forward kinematics, dx and the rotation from pin's kinematics.
* Total deflection from zero load: both linear predictions (conventional K_theta, enhanced
  K_theta - K_C, evaluated at the unloaded pose) err by O(F^2): fitted exponent 2.
* Incremental stiffness under a preload F0: the FD derivative d x_eq / dF at F0 equals the
  enhanced compliance J (K_theta - K_C)^-1 J^T evaluated at the deflected pose with F0 (the
  tangent of the equilibrium, up to the O(dF^2) FD error), while the conventional one is off
  by O(F0).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stiffness.calibration.exact_baseline import ExactObservation
from stiffness.elastic.effects.geometry import Geometry, References
from stiffness.elastic.effects.hypothesis import Hypothesis
from stiffness.errors import StiffnessError
from stiffness.mechanics.equilibrium import (
    SpringLaw,
    linear_departure,
    solve_equilibrium,
    tangent_equilibrium,
)
from stiffness.mechanics.formulation import compliance, deflection, target_state

UR5_Q = np.array([0.3, -1.0, 1.2, -0.7, 1.1, 0.4])
UR5_K = np.diag([3e4, 3e4, 2e4, 5e3, 5e3, 5e3])
UR5_F = np.array([100.0, 200.0, -50.0])
SK120_F = np.array([3e3, -5e3, 2e3])
FOUR_BAR_K = np.diag([50.0, 20.0])
FOUR_BAR_F = np.array([1.5, -2.0, 0.5])
PANDA_Q = np.array([0.2, -0.4, 0.3, -2.0, 0.1, 1.8, 0.6, 0.0])  # the second finger mimics
PANDA_K = np.diag([2e4, 2e4, 1.5e4, 1.5e4, 8e3, 8e3, 5e3])
PANDA_F = np.array([40.0, -30.0, -60.0])


@pytest.fixture(scope="module")
def cases(sk120, ur5, panda, four_bar_robot):
    """(robot, unloaded configuration, K_theta, reference force) per robot."""
    return {
        "sk120": (sk120, sk120.configuration(np.deg2rad(sk120.defaults["q_deg"])),
                  np.diag(sk120.defaults["k_theta_SI"]), SK120_F),
        "ur5": (ur5, ur5.configuration(UR5_Q), UR5_K, UR5_F),
        "panda": (panda, panda.configuration(PANDA_Q), PANDA_K, PANDA_F),
        "four_bar": (four_bar_robot, four_bar_robot.configuration(np.array([0.8, -0.4])),
                     FOUR_BAR_K, FOUR_BAR_F),
    }


def _pose(robot, q):
    pin.framesForwardKinematics(robot.model, robot.data, q)
    placement = robot.data.oMf[robot.target_frame_id]
    return placement.translation.copy(), placement.rotation.copy()


@pytest.mark.parametrize("name", ["sk120", "ur5", "panda", "four_bar"])
@pytest.mark.parametrize("scale", [1.0, 4.0])
def test_exact_equilibrium_balances_the_load(name, scale, cases, fd):
    robot, q0, k_theta, force = cases[name]
    force = scale * force
    eq = solve_equilibrium(robot, q0, k_theta, force)
    c0, c_eq = robot.coordinates_of(q0), robot.coordinates_of(eq.q)
    idx = robot.compliant_in_coordinates
    np.testing.assert_allclose(eq.dtheta, c_eq[idx] - c0[idx], atol=1e-14)
    rigid = np.setdiff1d(np.arange(robot.n_coordinates), idx)
    np.testing.assert_allclose(c_eq[rigid], c0[rigid], atol=1e-14)  # rigid joints held
    if not robot.loop.is_open_chain:
        pin.framesForwardKinematics(robot.model, robot.data, eq.q)
        assert np.linalg.norm(robot.loop.residual(robot.model, robot.data)) < 1e-10
    # balance with an independent (FD) Jacobian of the loop-closed target position
    jac = fd.coordinates(robot, c_eq, lambda s: s.position)
    torque = jac.T @ force
    assert np.abs(k_theta @ eq.dtheta - torque).max() <= 1e-7 * np.abs(torque).max()
    # a real deflection, far from the linear regime's rounding
    assert 1e-4 < np.linalg.norm(eq.dx) < 0.1
    p0, r0 = _pose(robot, q0)
    p1, r1 = _pose(robot, eq.q)
    np.testing.assert_allclose(eq.dx, p1 - p0, atol=1e-15)
    np.testing.assert_allclose(eq.rotation, pin.log3(r1 @ r0.T), atol=1e-15)
    # a stable equilibrium: the tangent K_theta - K_C at the solution is PD
    state = target_state(robot, eq.q, force)
    assert np.linalg.eigvalsh(k_theta - state.k_c).min() > 0


@pytest.mark.parametrize("name", ["sk120", "ur5"])
def test_nonlinear_joint_law_equilibrium(name, cases, fd):
    """Softening springs and backlash: dtheta = f(J(theta)^T F) with an independent FD J."""
    robot, q0, k_theta, force = cases[name]
    k = np.diag(k_theta)
    n = len(k)
    tau_scale = np.abs(target_state(robot, q0).jacobian[:3].T @ force).max()
    law = SpringLaw(1.0 / k, np.full(n, 2.0 / tau_scale), np.full(n, 2e-4),
                    np.full(n, 0.02 * tau_scale))
    eq = solve_equilibrium(robot, q0, law, force)
    jac = fd.coordinates(robot, robot.coordinates_of(eq.q), lambda s: s.position)
    tau = jac.T @ force
    c, beta, b, s = law.compliance, law.beta, law.backlash, law.smoothing
    expected = c * tau * (1 + beta * np.abs(tau)) + b * np.tanh(tau / s)
    np.testing.assert_allclose(eq.dtheta, expected, rtol=1e-6, atol=1e-9 * np.abs(expected).max())
    # far from the linear springs' answer: the law matters
    linear = solve_equilibrium(robot, q0, k_theta, force)
    assert np.abs(eq.dtheta - linear.dtheta).max() > 0.1 * np.abs(linear.dtheta).max()
    # linear springs through either law type give the same equilibrium
    same = solve_equilibrium(robot, q0, SpringLaw.of_stiffness(k), force)
    np.testing.assert_allclose(same.dtheta, linear.dtheta, rtol=1e-10)
    # the frozen-geometry fixed point of linear springs is the enhanced eq. 10
    state = target_state(robot, q0, force)
    frozen = tangent_equilibrium(k_theta, state.jacobian[:3].T @ force, state.k_c)
    np.testing.assert_allclose(frozen, np.linalg.solve(k_theta - state.k_c,
                                                       state.jacobian[:3].T @ force), rtol=1e-12)


def test_zero_load_leaves_the_robot_still(cases):
    robot, q0, k_theta, _ = cases["sk120"]
    eq = solve_equilibrium(robot, q0, k_theta, np.zeros(3))
    np.testing.assert_array_equal(eq.dtheta, 0.0)
    np.testing.assert_allclose(eq.dx, 0.0, atol=1e-15)


@pytest.mark.parametrize("name", ["sk120", "ur5"])
def test_both_linear_predictions_depart_at_second_order(name, cases):
    """From zero load, conventional and enhanced predictions both err by O(F^2): K_C adds a
    term of order F^2 to the deflection but not the second-order kinematics of the deflection."""
    robot, q0, k_theta, force = cases[name]
    dep = linear_departure(robot, q0, k_theta, force)
    assert 1.9 <= dep.rate_conventional <= 2.1
    assert 1.9 <= dep.rate_enhanced <= 2.1
    # the same rates from the errors recomputed here, with independent linear predictions
    state0 = target_state(robot, q0)
    jac = state0.translational_jacobian()
    errors = {"conventional": [], "enhanced": []}
    for s, exact in zip(dep.scales, dep.exact, strict=True):
        np.testing.assert_allclose(exact, solve_equilibrium(robot, q0, k_theta, s * force).dx,
                                   atol=1e-15)
        k_c = target_state(robot, q0, s * force).k_c
        conv = jac @ np.linalg.solve(k_theta, jac.T @ (s * force))
        enh = jac @ np.linalg.solve(k_theta - k_c, jac.T @ (s * force))
        errors["conventional"].append(np.linalg.norm(conv - exact))
        errors["enhanced"].append(np.linalg.norm(enh - exact))
    for kind, fitted in (("conventional", dep.rate_conventional), ("enhanced", dep.rate_enhanced)):
        err = np.array(errors[kind])
        assert err.min() > 1e-10  # well above the solver's accuracy
        rate = np.polyfit(np.log(dep.scales), np.log(err), 1)[0]
        assert abs(rate - fitted) < 1e-6
        # error / F^2 is constant to a few percent over two decades of load
        ratio = err / dep.scales**2
        assert ratio.max() / ratio.min() < 1.1
    np.testing.assert_allclose(
        np.linalg.norm(dep.conventional - dep.exact, axis=1), errors["conventional"], rtol=1e-9)
    np.testing.assert_allclose(
        np.linalg.norm(dep.enhanced - dep.exact, axis=1), errors["enhanced"], rtol=1e-9)


def _incremental_compliance(robot, q0, k_theta, preload, rel_step=1e-3):
    """d x_eq / dF at the preload, by central differences of the exact equilibrium."""
    step = rel_step * np.linalg.norm(preload)
    out = np.zeros((3, 3))
    for i in range(3):
        e = np.zeros(3)
        e[i] = step
        plus = solve_equilibrium(robot, q0, k_theta, preload + e).dx
        minus = solve_equilibrium(robot, q0, k_theta, preload - e).dx
        out[:, i] = (plus - minus) / (2 * step)
    return out


@pytest.mark.parametrize("name", ["sk120", "ur5", "panda", "four_bar"])
def test_enhanced_compliance_is_the_incremental_compliance_under_preload(name, cases):
    """Where the enhanced formulation helps: under a preload F0, the incremental compliance
    dx/dF of the exact equilibrium is J (K_theta - K_C) ^-1 J^T at the deflected pose with
    F0 (the FD error is O(dF^2)); the conventional J K_theta^-1 J^T is off by O(F0)."""
    robot, q0, k_theta, force = cases[name]
    conventional_errors = []
    for scale in (1.0, 2.0):
        preload = scale * force
        numeric = _incremental_compliance(robot, q0, k_theta, preload)
        eq = solve_equilibrium(robot, q0, k_theta, preload)
        state = target_state(robot, eq.q, preload)
        jac = state.translational_jacobian()
        enhanced = compliance(jac, k_theta - state.k_c)
        conventional = compliance(jac, k_theta)
        err_enh = np.linalg.norm(enhanced - numeric) / np.linalg.norm(numeric)
        err_conv = np.linalg.norm(conventional - numeric) / np.linalg.norm(numeric)
        assert err_enh < 1e-6
        assert err_conv > 1e-3
        conventional_errors.append(err_conv)
    # O(F0): doubling the preload doubles the conventional error
    assert 1.8 < conventional_errors[1] / conventional_errors[0] < 2.2


@pytest.mark.parametrize("name", ["sk120", "ur5", "four_bar"])
def test_at_unloaded_pose_k_c_is_the_load_part_of_the_first_order_change(name, cases):
    """At the unloaded pose, K_theta - K_C(F0) alone does not give the incremental compliance
    under F0: both unloaded-pose compliances err by O(F0), since they miss the pose change
    dJ = J(theta*) - J(theta0). Adding the first-order effect of dJ to the enhanced compliance
    leaves an O(F0^2) error, whereas adding it to the conventional one still leaves O(F0): K_C is
    exactly the load part of the first-order change of the incremental compliance."""
    robot, q0, k_theta, force = cases[name]
    errors = {"enhanced": [], "conventional": [], "enhanced+dJ": [], "conventional+dJ": []}
    for scale in (0.5, 1.0):
        preload = scale * force
        numeric = _incremental_compliance(robot, q0, k_theta, preload)
        state0 = target_state(robot, q0, preload)
        jac0 = state0.translational_jacobian()
        eq = solve_equilibrium(robot, q0, k_theta, preload)
        d_jac = target_state(robot, eq.q).translational_jacobian() - jac0
        for kind, tangent in (("enhanced", k_theta - state0.k_c), ("conventional", k_theta)):
            c0 = compliance(jac0, tangent)
            cross = d_jac @ np.linalg.solve(tangent, jac0.T)
            for label, c in ((kind, c0), (f"{kind}+dJ", c0 + cross + cross.T)):
                errors[label].append(np.linalg.norm(c - numeric) / np.linalg.norm(numeric))
    rate = {k: np.log2(v[1] / v[0]) for k, v in errors.items()}
    assert 0.85 < rate["enhanced"] < 1.15
    assert 0.85 < rate["conventional"] < 1.15
    assert 0.85 < rate["conventional+dJ"] < 1.15
    assert 1.8 < rate["enhanced+dJ"] < 2.2
    assert errors["enhanced+dJ"][1] < 0.1 * min(errors["enhanced"][1], errors["conventional"][1])


@pytest.mark.parametrize("name", ["sk120", "ur5"])
def test_deflection_is_first_order_exact_for_a_force(name, cases):
    """formulation.deflection (A&S eq. 11) agrees with the exact equilibrium to O(F^2)."""
    robot, q0, k_theta, force = cases[name]
    rel = []
    for s in (0.01, 0.02):
        state = target_state(robot, q0, s * force)
        exact = solve_equilibrium(robot, q0, k_theta, s * force).dx
        rel.append(np.linalg.norm(deflection(state, k_theta, "enhanced") - exact)
                   / np.linalg.norm(exact))
    assert rel[0] < 1e-3
    assert 1.8 < rel[1] / rel[0] < 2.2  # relative error O(F): absolute O(F^2)


def test_deflection_under_a_wrench_includes_the_moment(cases):
    robot, q0, k_theta, _ = cases["ur5"]
    wrench = np.array([10.0, 20.0, -5.0, 3.0, -2.0, 4.0])
    exact = solve_equilibrium(robot, q0, k_theta, wrench).dx
    state = target_state(robot, q0, wrench)
    predicted = deflection(state, k_theta, "enhanced")
    assert np.linalg.norm(predicted - exact) < 1e-2 * np.linalg.norm(exact)


def test_wrench_equilibrium_balances_moment(cases, fd):
    """With a moment, the balance uses the full 6-row Jacobian (angular rows from FD of the
    rotation are checked in test_formulation)."""
    robot, q0, k_theta, _ = cases["ur5"]
    wrench = np.array([10.0, 20.0, -5.0, 3.0, -2.0, 4.0])
    eq = solve_equilibrium(robot, q0, k_theta, wrench)
    jac = target_state(robot, eq.q).jacobian
    np.testing.assert_allclose(k_theta @ eq.dtheta, jac.T @ wrench, atol=1e-9)


def test_load_beyond_buckling_does_not_converge(cases):
    robot, q0, k_theta, _ = cases["ur5"]
    with pytest.raises(StiffnessError, match="did not converge.*exceed the buckling load"):
        solve_equilibrium(robot, q0, k_theta, np.array([0.0, 0.0, 1e5]))


def test_equilibrium_beyond_buckling_is_never_an_unstable_point(cases):
    """Either refuse (StiffnessError) or return a stable equilibrium (a minimiser of Pi)."""
    robot, q0, _, _ = cases["ur5"]
    k_theta, force = np.eye(6) * 100.0, np.array([0.0, 0.0, 1e6])
    try:
        eq = solve_equilibrium(robot, q0, k_theta, force)
    except StiffnessError:
        return
    tangent = k_theta - target_state(robot, eq.q, force).k_c
    assert np.linalg.eigvalsh(0.5 * (tangent + tangent.T)).min() > 0


@pytest.mark.parametrize("load", [np.ones(4), np.array([1.0, np.nan, 0.0])])
def test_bad_load_for_equilibrium(cases, load):
    robot, q0, k_theta, _ = cases["ur5"]
    with pytest.raises(StiffnessError, match="load"):
        solve_equilibrium(robot, q0, k_theta, load)


# ------------------------------------------------------------------ many rows at once (batch)


def _exact_baseline(robot, q_rows, loads, rotation_weight=None):
    """The deflection fit's exact baseline (the pose model's sag observed at the target) over
    the rows ``q_rows`` (m, nq) under ``loads`` (m, 3 or 6)."""
    loads = np.array([np.r_[w, 0.0, 0.0, 0.0] if len(w) == 3 else w for w in loads])
    geo = Geometry.of(robot)
    rows = geo.rows(np.array([robot.coordinates_of(q) for q in q_rows]), loads[:, :3],
                    loads[:, 3:])
    refs = References.of(geo, rows, 2e4, np.full((1, 3), 1e-3))
    return Hypothesis(geo, rows, "exact", tuple(robot.compliant_joints), (), refs,
                      rotation_weight, exact=ExactObservation)


@pytest.mark.parametrize("name", ["sk120", "ur5", "panda", "four_bar"])
def test_exact_baseline_equals_the_one_at_a_time_solver(name, cases):
    """The exact baseline over rows of loads (a wrench among them, two poses) equals
    solve_equilibrium row by row: the target's displacement and rotation to 1e-9 of their
    largest (the loops' closures; the open chains' to round-off)."""
    robot, q0, k_theta, force = cases[name]
    q1 = robot.configuration(robot.coordinates_of(q0) + 0.05)
    loads = np.array([np.r_[0.5 * force, 0, 0, 0], np.r_[2.0 * force, 0, 0, 0],
                      np.r_[force, 0.02 * np.abs(force).max() * np.array([1.0, -0.5, 0.3])],
                      np.r_[-force, 0, 0, 0]])
    q_rows = np.array([q0, q0, q0, q1])
    pred = _exact_baseline(robot, q_rows, loads, 1.0).predict(np.log(np.diag(k_theta)))
    one = [solve_equilibrium(robot, q, k_theta, load)
           for q, load in zip(q_rows, loads, strict=True)]
    dx, rotation = np.array([e.dx for e in one]), np.array([e.rotation for e in one])
    np.testing.assert_allclose(pred[:, :3], dx, rtol=0, atol=1e-9 * np.abs(dx).max())
    np.testing.assert_allclose(pred[:, 3:], rotation, rtol=0,
                               atol=1e-9 * np.abs(rotation).max())


def test_exact_baseline_refuses_a_load_beyond_buckling(cases):
    robot, q0, k_theta, force = cases["ur5"]
    model = _exact_baseline(robot, np.array([q0, q0]), np.array([force, [0.0, 0.0, 1e5]]))
    with pytest.raises(StiffnessError, match="buckling load"):
        model.predict(np.log(np.diag(k_theta)))


# ------------------------------------------------------------------ frozen-geometry joint law


def _random_law(data, n: int) -> tuple[SpringLaw, np.ndarray, np.ndarray]:
    """A law with some nonlinear joints, torques and a K_C that keeps the equilibrium stable
    and unique: ``|K_C| max f' <= 0.5`` (the law's fixed-point map is then a contraction)."""
    seed = data.draw(st.integers(0, 2 ** 31 - 1))
    rng = np.random.default_rng(seed)
    nonlinear = data.draw(st.lists(st.integers(0, n - 1), max_size=n, unique=True))
    k = rng.uniform(1e4, 1e6, n)
    beta = np.zeros(n)
    backlash = np.zeros(n)
    for j in nonlinear:
        beta[j] = rng.uniform(-0.004, 0.01)
        backlash[j] = rng.uniform(0.0, 3e-4)
    smoothing = rng.uniform(0.5, 5.0, n)
    tau0 = rng.normal(size=(20, n)) * 50.0
    tau_max = 2.0 * np.abs(tau0).max()  # |tau0 + K_C dtheta| stays below this
    slope = np.max(1.0 / k * (1.0 + 2.0 * np.abs(beta) * tau_max) + backlash / smoothing)
    k_c = rng.normal(size=(20, n, n))
    k_c *= rng.uniform(0.0, 0.5) / (slope * np.linalg.norm(k_c, ord=2, axis=(1, 2)).max())
    return SpringLaw(1.0 / k, beta, backlash, smoothing), tau0, k_c


@settings(max_examples=60, deadline=None)
@given(data=st.data(), n=st.integers(1, 7))
def test_frozen_deflection_solves_the_law(data, n):
    """The reduced Newton's answer satisfies dtheta = f(tau0 + K_C dtheta) row by row."""
    law, tau0, k_c = _random_law(data, n)
    dtheta = law.frozen_deflection(tau0, k_c, iterations=30, tolerance=1e-15)
    value, _ = law(tau0 + np.einsum("mab,mb->ma", k_c, dtheta))
    np.testing.assert_allclose(dtheta, value, rtol=1e-10, atol=1e-12 * np.abs(value).max())


@settings(max_examples=30, deadline=None)
@given(data=st.data(), n=st.integers(1, 6))
def test_deflection_tangent_is_the_derivative(data, n):
    """The implicit-function derivative along each law array equals central differences."""
    law, tau0, k_c = _random_law(data, n)
    dtheta = law.frozen_deflection(tau0, k_c, iterations=30, tolerance=1e-15)
    j = data.draw(st.integers(0, n - 1))
    steps = np.zeros((3, 3, n))  # (direction, array, joint): c, beta, b of joint j
    steps[0, 0, j] = 0.1 * law.compliance[j]
    steps[1, 1, j] = 1e-3
    steps[2, 2, j] = 1e-4
    for with_k_c in (k_c, None):
        ref = dtheta if with_k_c is not None else law.frozen_deflection(tau0, None)
        tangent = law.deflection_tangent(tau0, with_k_c, ref, *steps.transpose(1, 0, 2))
        for d in range(3):
            h = 1e-4
            moved = [SpringLaw(law.compliance + sign * h * steps[d, 0], law.beta
                               + sign * h * steps[d, 1], law.backlash + sign * h * steps[d, 2],
                               law.smoothing) for sign in (1.0, -1.0)]
            plus, minus = (m.frozen_deflection(tau0, with_k_c, 30, 1e-15) for m in moved)
            fd = (plus - minus) / (2 * h)
            np.testing.assert_allclose(tangent[..., d], fd, rtol=1e-5,
                                       atol=1e-7 * max(np.abs(fd).max(), 1e-30))


def test_loops_leaving_their_reach_under_a_buckling_load_say_buckling():
    """Griffis-Duffy's platform on its 1..6 kN/m legs, without its springs' rest lengths,
    buckles under 10 N: K_theta - K_C (computed here at the unloaded pose) is indefinite. The
    first Newton step overshoots the loops' reach; that was reported as a LoopClosureError
    ("check the joint values and their units", which the user never gave: `stiffness simulate
    --robot griffis-duffy` ended so); now the step is damped and the load named as too large.
    Under 0.1 N the same solver reaches K_theta dtheta = J(q)^T F at the closed pose."""
    from stiffness.errors import LoopClosureError, UnstableEquilibriumError
    from stiffness.mechanics.defaults import default_coordinates
    from stiffness.robot.robot import load_robot

    robot = load_robot("griffis-duffy")
    q0 = robot.configuration(default_coordinates(robot))
    k = np.diag(np.asarray(robot.defaults["k_theta_SI"], dtype=float))
    force = np.array([0.0, 0.0, -10.0])
    start = k - target_state(robot, q0, force).k_c
    assert np.linalg.eigvalsh(0.5 * (start + start.T))[0] < 0
    with pytest.raises(UnstableEquilibriumError, match="buckling load") as info:
        solve_equilibrium(robot, q0, k, force)
    assert not isinstance(info.value, LoopClosureError)
    small = force / 100
    eq = solve_equilibrium(robot, q0, k, small)
    jac = target_state(robot, eq.q).jacobian[:3]
    assert np.abs(k @ eq.dtheta - jac.T @ small).max() < 1e-9 * np.abs(jac.T @ small).max()
