"""The pose model's sag solver (:meth:`PoseModel._loaded_rows`) against plain fixed-point
passes run to convergence with no cap: a steep lost motion's slow mode (steps shrinking by a
steady ratio) jumps to the same fixed point in fewer passes, and a sag the plain passes would
need more than ``SAG_ITERATIONS`` for is still declared diverging. A load that stiffens the
arm strongly (plain passes that oscillate and grow) sags to the one-pose Newton solver's stable
equilibrium; a buckling load is still refused."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from stiffness.calibration.exact_baseline import ExactObservation
from stiffness.calibration.pose_fit import campaign_settings, rows_of, starting_frame
from stiffness.calibration.pose_model import (
    SAG_ITERATIONS,
    SAG_TOLERANCE,
    Loads,
    Marker,
    PoseModel,
)
from stiffness.elastic.effects.geometry import Geometry, References
from stiffness.elastic.effects.hypothesis import Hypothesis
from stiffness.elastic.effects.pose_face import compliance_label
from stiffness.elastic.model import ElasticModel
from stiffness.errors import ConvergenceError, UnstableEquilibriumError
from stiffness.mechanics.equilibrium import solve_equilibrium
from stiffness.mechanics.formulation import target_state
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.robot import TARGET_FRAME, load_robot

FAMILIES = ("frame", "markers", "joint_offsets", "backlash")


@pytest.fixture(scope="module")
def backlash_model():
    arm = load_robot("xarm7")
    n = arm.n_coordinates
    hidden = HiddenPoseErrors(np.eye(3), np.array([1.0, 0.5, 0.2]), np.array([[0, 0, 0.051]]),
                              np.full(n, 5e-4), np.zeros((n, 6)), np.full(n, 3e4))
    c = simulate_pose_campaign(arm, [Marker("tip", arm.target_frame, np.array([0, 0, 0.05]))],
                               hidden, 12, 20e-6, seed=1)
    model = PoseModel(arm, c.markers, FAMILIES, starting_frame(c), c.loads,
                      campaign_settings(c))
    return model, c


def _plain(model: PoseModel, x: np.ndarray, rows) -> tuple[np.ndarray, int]:
    """The sag by plain passes ``s <- law(tau(q_c + delta_0 + s))`` from zero, every row
    until all converge (no cap but 10 000), and how many passes that took."""
    pin_model = model.perturbed_model(x)
    data = pin_model.createData()
    commanded = np.array([r.q_full for r in rows])
    offsets = model._offsets(x)
    sag = np.zeros((len(rows), pin_model.nv))
    for passes in range(1, 10_000):
        q, tangent = model._configurations(pin_model, data, commanded, offsets + sag)
        g, w = model._row_torques(pin_model, data, q, tangent, None, True)
        new = model.deflection(x, model._state(x, q, g, w, model._extras(pin_model, data, q)))
        step, sag = np.max(np.abs(new - sag)), new
        if step <= SAG_TOLERANCE:
            return sag, passes
    raise AssertionError("the plain passes do not converge")


def _solved(model: PoseModel, x: np.ndarray, rows, monkeypatch) -> tuple[np.ndarray, int]:
    """The solver's loaded configurations from a cold start and its passes."""
    passes = []
    deflection = PoseModel.deflection
    monkeypatch.setattr(PoseModel, "deflection",
                        lambda self, *a: passes.append(1) or deflection(self, *a))
    pin_model = model.perturbed_model(x)
    q, _, _ = model._loaded_rows(pin_model, pin_model.createData(), x, rows)
    monkeypatch.setattr(PoseModel, "deflection", deflection)
    return q, len(passes)


def _parameters(model: PoseModel, half_width: float) -> np.ndarray:
    x = np.zeros(model.size)
    x[model.slices()["backlash"]] = half_width
    return x


def test_slow_mode_jumps_to_the_plain_fixed_point(backlash_model, monkeypatch):
    """Backlash 0.07 rad on every spring: the plain passes need 34 (steps shrinking by a
    steady ratio on the slowest rows); the solver lands on their fixed point to the tolerance
    (3e-14 rad) in 15."""
    model, c = backlash_model
    x = _parameters(model, 0.07)
    rows = rows_of(model, c)
    sag, plain = _plain(model, x, rows)
    q, passes = _solved(model, x, rows, monkeypatch)
    commanded = np.array([r.q_full for r in rows])
    assert np.max(np.abs(q - (commanded + model._offsets(x) + sag))) < SAG_TOLERANCE
    assert passes < plain / 2, (passes, plain)


def test_sag_the_plain_passes_cannot_finish_in_time_still_diverges(backlash_model,
                                                                   monkeypatch):
    """Backlash 0.08 rad: the plain passes converge, but after 681, more than
    SAG_ITERATIONS: declared diverging as before the jumps (a fit refuses such a step)."""
    model, c = backlash_model
    x = _parameters(model, 0.08)
    rows = rows_of(model, c)
    _, plain = _plain(model, x, rows)
    assert plain > SAG_ITERATIONS
    with pytest.raises(ConvergenceError):
        _solved(model, x, rows, monkeypatch)


# ------------------------------------------------------------------ a load that stiffens the arm

UR5_ARM = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint")
UR5_U = np.array([0.3, -1.0, 1.2, -0.7, 1.1, 0.4])
#: a direction along which a pull on the tool stiffens the three soft joints (K_C negative
#: definite at UR5_U: -1.08, -0.65, -0.15 N.m/rad per N)
PULL = np.array([0.7784687, 0.24251962, 0.5789393])
SOFT_K = np.array([400.0, 300.0, 250.0])


@pytest.fixture(scope="module")
def soft_ur5():
    """The UR5 without gravity, its three arm joints on soft springs (SOFT_K, N.m/rad), its
    pose model with ``joint_compliance`` alone and those compliances."""
    robot = load_robot("ur5", target_offset=[0.0, 0.0, 0.1], compliant_joints=UR5_ARM)
    robot.model.gravity = pin.Motion.Zero()
    model = PoseModel(robot, [Marker("tool", TARGET_FRAME)], ("joint_compliance",),
                      (np.eye(3), np.zeros(3)), Loads(TARGET_FRAME, np.zeros((0, 6))))
    labels = [p.label for p in model.parameters]
    x = np.zeros(model.size)
    x[[labels.index(compliance_label(j)) for j in UR5_ARM]] = 1.0 / SOFT_K
    return robot, model, x


def _tool(robot, q: np.ndarray) -> np.ndarray:
    pin.framesForwardKinematics(robot.model, robot.data, q)
    return robot.data.oMf[robot.target_frame_id].translation.copy()


def test_a_load_that_stiffens_the_arm_sags_to_the_stable_equilibrium(soft_ur5):
    """A 250-350 N pull along the arm (PULL) on soft joints: at the equilibrium an eigenvalue
    of ``C K_C`` is below -1 (-1.11 to -1.61: the plain passes oscillate and grow, and were
    declared diverging), yet ``K - K_C`` is positive definite there (a stable equilibrium the
    one-pose Newton solver finds). The sag converges through Newton's steps to that solver's
    equilibrium and the elastic model's, row by row (and the exact baseline of identify, an
    observation of that sag, with it), to 1e-12 m of 0.22-0.24 m (measured
    1.3e-13 m, that solver's own tolerance, and 2e-16 m), a 100 N row (-0.42, its passes
    contract) in the same campaign to 1.1e-14 and 1.7e-14 m."""
    robot, model, x = soft_ur5
    u = np.array([UR5_U, UR5_U, UR5_U + 0.05, UR5_U])
    wrench = np.array([np.r_[f * PULL, 0.0, 0.0, 0.0] for f in (300.0, 350.0, 250.0, 100.0)])
    wrench[1, 3:] = [2.0, -1.0, 3.0]  # a moment too
    q0 = [robot.configuration(c) for c in u]
    y = model.evaluate(x, [model.row_terms(q, w) for q, w in zip(q0, wrench, strict=True)],
                       False)[0][:, 0]
    elastic = ElasticModel.with_effects(robot, SOFT_K, [])
    lowest = []
    for i, (q, w) in enumerate(zip(q0, wrench, strict=True)):
        eq = solve_equilibrium(robot, q, np.diag(SOFT_K), w)
        k_c = target_state(robot, eq.q, w).k_c
        tangent = np.diag(SOFT_K) - k_c
        assert np.linalg.eigvalsh(0.5 * (tangent + tangent.T)).min() > 0  # stable
        lowest.append(np.linalg.eigvals(k_c / SOFT_K[:, None]).real.min())
        assert np.abs(eq.dx).max() > 0.05
        np.testing.assert_allclose(y[i], _tool(robot, eq.q), rtol=0, atol=1e-12)
        twist = elastic.at(u[i], w).equilibrium().twist
        np.testing.assert_allclose(y[i] - _tool(robot, q), twist[:3], rtol=0, atol=1e-12)
    assert max(lowest[:3]) < -1.1 and lowest[3] > -0.5, lowest
    # identify --formulation exact observes the same sag
    geo = Geometry.of(robot)
    rows = geo.rows(u, wrench[:, :3], wrench[:, 3:])
    exact = Hypothesis(geo, rows, "exact", UR5_ARM, (), References.of(geo, rows, 2e4, np.full(
        (1, 3), 1e-3)), None, exact=ExactObservation).predict(np.log(SOFT_K))
    np.testing.assert_allclose(exact, y - [_tool(robot, q) for q in q0], rtol=0, atol=1e-12)


@pytest.mark.parametrize(("push", "says"), [(1.5e3, "does not converge"),
                                             (5e3, "no stable equilibrium")])
def test_a_buckling_load_is_still_refused(soft_ur5, push, says):
    """A 1.5 or 5 kN push along the arm (K - K_C indefinite at the commanded pose): the
    one-pose Newton solver finds no stable equilibrium, and the sag is refused in one line,
    its plain passes and then Newton's steps not converging (1.5 kN) or Newton's steps
    reaching an unstable equilibrium, ``I - C K_C`` with a negative eigenvalue (5 kN). (Under
    0.4 to 1 kN the arm snaps through to a stable equilibrium, 0.8 to 1.7 rad away, that
    both solvers find.)"""
    robot, model, x = soft_ur5
    q = robot.configuration(UR5_U)
    w = np.r_[-push * PULL, 0.0, 0.0, 0.0]
    tangent = np.diag(SOFT_K) - target_state(robot, q, w).k_c
    assert np.linalg.eigvalsh(0.5 * (tangent + tangent.T)).min() < 0
    with pytest.raises(UnstableEquilibriumError):
        solve_equilibrium(robot, q, np.diag(SOFT_K), w)
    with pytest.raises(ConvergenceError, match=says) as info:
        model.evaluate(x, [model.row_terms(q, w)], False)
    assert "\n" not in str(info.value)


def test_a_load_that_stiffens_a_loop_sags_to_the_newton_equilibrium():
    """The SK120 without gravity, its springs 1000 times softer, 387 N pulling the tool
    (C K_C's lowest eigenvalue -0.96 at the equilibrium, deflections of 0.47 rad; the plain
    passes from zero overshoot and grow): Newton's steps, started again from where the sag
    started and with the parallelogram closed at each pass, reach solve_equilibrium's
    equilibrium to 1e-10 m (measured 4.3e-12 m, that solver's closure; from the diverged
    passes they reached another stable equilibrium 0.95 m away)."""
    robot = load_robot("sk120")
    robot.model.gravity = pin.Motion.Zero()
    q = robot.configuration(np.deg2rad(robot.defaults["q_deg"]))
    k = 1e-3 * np.asarray(robot.defaults["k_theta_SI"], dtype=float)
    w = np.r_[387.46 * np.array([-0.8022655, -0.47192134, 0.36559583]), 0.0, 0.0, 0.0]
    model = PoseModel(robot, [Marker("tool", TARGET_FRAME)], ("joint_compliance",),
                      (np.eye(3), np.zeros(3)), Loads(TARGET_FRAME, np.zeros((0, 6))))
    labels = [p.label for p in model.parameters]
    x = np.zeros(model.size)
    x[[labels.index(compliance_label(j)) for j in robot.compliant_joints]] = 1.0 / k
    eq = solve_equilibrium(robot, q, np.diag(k), w)
    assert np.abs(eq.dtheta).max() > 0.4
    y = model.evaluate(x, [model.row_terms(q, w)], False)[0][0, 0]
    np.testing.assert_allclose(y, _tool(robot, eq.q), rtol=0, atol=1e-10)
