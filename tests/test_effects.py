"""The effect library and the cached deflection model (stiffness.elastic.effects)."""

from __future__ import annotations

import numpy as np
import pytest

from stiffness.elastic.effects import LIBRARY, candidates, make_effect
from stiffness.elastic.effects.geometry import Geometry, References, link_axes, rotation_matrix
from stiffness.elastic.effects.hypothesis import Hypothesis
from stiffness.elastic.effects.joint_laws import ComplementaryStiffness
from stiffness.elastic.effects.measurement import TargetOffset
from stiffness.errors import StiffnessError
from stiffness.mechanics.equilibrium import SpringLaw, solve_equilibrium
from stiffness.mechanics.formulation import deflection, target_state
from stiffness.planning.simulate import Truth
from stiffness.robot.robot import load_robot

UR5_ARM = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint")
SK120_K = np.array([1.4098e6, 4.0076e5, 9.3528e5])
SK120_A = np.deg2rad([-33.2004, 15.9, -55.5957, 0.0, -34.4045, -90.0])
UR5_Q = np.array([0.3, -1.0, 1.2, -0.5, 0.4, 0.2])


def _model(robot, coords, forces, baseline="enhanced", effects=()):
    geo = Geometry.of(robot)
    coords = np.atleast_2d(coords)
    forces = np.atleast_2d(forces)
    rows = geo.rows(np.repeat(coords, len(forces) // len(coords), axis=0), forces)
    refs = References.of(geo, rows, 1e5, np.full((1, 3), 1e-3))
    return Hypothesis(geo, rows, baseline, tuple(robot.compliant_joints), tuple(effects), refs)


#: Effects the issue requires (``deflection_offset``, ``gravity_lumped``, the weight of unknown
#: masses, and ``joint_offsets``, the joints' zero offsets, are extras).
REQUIRED_EFFECTS = {
    "complementary_stiffness", "joint_compliance", "link_compliance", "transversal_compliance",
    "backlash", "nonlinear_joint_stiffness", "frame_misalignment", "target_offset",
    "force_sensor_bias", "gravity_preload", "gravity_compensator"}


def test_library_names():
    assert REQUIRED_EFFECTS | {"deflection_offset", "gravity_lumped", "joint_offsets"} == set(
        LIBRARY)


@pytest.mark.parametrize("scale", [0.2, 1.0, 3.0])
def test_second_order_matches_exact_equilibrium_sk120(scale):
    robot = load_robot("sk120")
    force = scale * np.array([45.524, 364.5018, 211.3439])
    model = _model(robot, SK120_A, force, effects=(ComplementaryStiffness(),))
    pred = model.predict(np.log(SK120_K))[0]
    exact = solve_equilibrium(robot, robot.configuration(SK120_A), np.diag(SK120_K), force).dx
    assert np.linalg.norm(pred - exact) <= 1e-3 * np.linalg.norm(exact)
    # the linear enhanced model is measurably worse at the largest load
    linear = _model(robot, SK120_A, force).predict(np.log(SK120_K))[0]
    assert np.linalg.norm(linear - exact) > 10 * np.linalg.norm(pred - exact)


def test_second_order_matches_exact_equilibrium_ur5():
    robot = load_robot("ur5", compliant_joints=list(UR5_ARM))
    k = np.array([2e4, 2e4, 1e4])
    for force in ([50.0, -80.0, 120.0], [-100.0, 30.0, -60.0]):
        model = _model(robot, UR5_Q, force, baseline="conventional",
                       effects=(ComplementaryStiffness(),))
        pred = model.predict(np.log(k))[0]
        exact = solve_equilibrium(robot, robot.configuration(UR5_Q), np.diag(k), force).dx
        assert np.linalg.norm(pred - exact) <= 1e-3 * np.linalg.norm(exact)


def test_baselines_match_the_formulation_module():
    """The cached all-joints geometry restricted to the compliant joints is the compliant
    robot's own J and K_C (loops closed): eq. 8 and 10 row by row."""
    robot = load_robot("sk120")
    forces = np.array([[45.5, 364.5, 211.3], [-30.0, 100.0, -200.0]])
    q = robot.configuration(SK120_A)
    for baseline in ("conventional", "enhanced"):
        ref = [deflection(target_state(robot, q, f), np.diag(SK120_K), baseline) for f in forces]
        pred = _model(robot, SK120_A, forces, baseline).predict(np.log(SK120_K))
        np.testing.assert_allclose(pred, np.array(ref), rtol=1e-9, atol=1e-15)


def test_target_offset_effect_is_the_offset_robot():
    delta = np.array([0.03, -0.02, 0.05])
    plain = load_robot("ur5", compliant_joints=list(UR5_ARM))
    moved = load_robot("ur5", compliant_joints=list(UR5_ARM), target_offset=delta)
    forces = np.array([[50.0, -80.0, 120.0], [10.0, 60.0, -30.0]])
    k = np.log([2e4, 2e4, 1e4])
    model = _model(plain, UR5_Q, forces, baseline="conventional", effects=(TargetOffset(),))
    x = np.concatenate([k, delta / 0.01])
    ref = _model(moved, UR5_Q, forces, baseline="conventional").predict(k)
    np.testing.assert_allclose(model.predict(x), ref, rtol=1e-9, atol=1e-15)


def test_link_axes_are_normal_to_the_segment():
    rng = np.random.default_rng(0)
    p_a, p_b = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    rot = np.array([rotation_matrix(v) for v in rng.normal(size=(5, 3))])
    e1, e2 = link_axes(p_a, p_b, rot, 1)
    u = (p_b - p_a) / np.linalg.norm(p_b - p_a, axis=1, keepdims=True)
    np.testing.assert_allclose(np.sum(e1 * u, axis=1), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.sum(e2 * u, axis=1), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.sum(e1 * e2, axis=1), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(e2, axis=1), 1.0)


def test_rotation_matrix():
    phi = np.array([0.1, -0.2, 0.3])
    r = rotation_matrix(phi)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-14)
    np.testing.assert_allclose(r @ phi, phi, atol=1e-14)


def test_make_effect_checks_places():
    geo = Geometry.of(load_robot("sk120"))
    assert make_effect("backlash", "joint2", geo).label == "backlash(joint2)"
    assert make_effect("link_compliance", "joint2/elbow", geo).where == "joint2->elbow"
    with pytest.raises(StiffnessError, match="valid names"):
        make_effect("backlash", "joint9", geo)
    with pytest.raises(StiffnessError, match="unknown effect"):
        make_effect("backlashes", None, geo)
    with pytest.raises(StiffnessError, match="valid segments"):
        make_effect("link_compliance", "elbow->joint2", geo)
    with pytest.raises(StiffnessError, match="whole campaign"):
        make_effect("target_offset", "joint2", geo)


def test_candidates_cover_the_library():
    robot = load_robot("sk120")
    model = _model(robot, SK120_A, [45.5, 364.5, 211.3])
    names = {c.name for c in candidates(model)}
    # the SK120 has a closed loop: its weight (gravity_preload) is not modelled there
    assert REQUIRED_EFFECTS - {"gravity_preload"} <= names
    assert "gravity_preload" in {c.name for c in candidates(_model(
        load_robot("ur5"), [0, -1.2, 1.5, -0.3, 1.57, 0], [10.0, 0, 0]))}
    where = {c.label for c in candidates(model)}
    assert {"joint_compliance(joint4)", "joint_compliance(joint6)", "backlash(joint1)",
            "nonlinear_joint_stiffness(joint3)", "link_compliance(joint2->elbow)"} <= where
    # spherical wrist: coincident origins give one segment end, not two
    assert "link_compliance(joint4->joint6)" not in where
    extended = model.extended(ComplementaryStiffness())
    assert "complementary_stiffness" not in {c.name for c in candidates(extended)}


def test_truth_with_linear_law_is_solve_equilibrium():
    robot = load_robot("sk120")
    geo = Geometry.of(robot)
    law = SpringLaw(1.0 / SK120_K, np.zeros(3), np.zeros(3), np.ones(3))
    truth = Truth(robot, law, chain=geo.chain)
    force = 2.0 * np.array([45.524, 364.5018, 211.3439])
    dx = truth.deflections(SK120_A[None], force[None])[0]
    exact = solve_equilibrium(robot, robot.configuration(SK120_A), np.diag(SK120_K), force).dx
    np.testing.assert_allclose(dx, exact, rtol=1e-9, atol=1e-14)


@pytest.mark.parametrize("weight", [None, 0.05])
def test_model_jacobian_with_effects_is_the_derivative(weight):
    """Every candidate extension, alone and on top of a backlash and a gravity preload (two
    law effects and a preload's unloaded equilibrium), with and without rotations: the
    analytic columns of predict_with_jacobian equal central differences of predict."""
    robot = load_robot("ur5")
    geo = Geometry.of(robot)
    rng = np.random.default_rng(4)
    coords = np.repeat(rng.uniform(-1.5, 1.5, (4, 6)), 3, axis=0)
    forces = rng.normal(size=(12, 3)) * 150.0
    rows = geo.rows(coords, forces, rng.normal(size=(12, 3)) * 10.0)
    refs = References.of(geo, rows, 1e5, np.full((1, 3), 1e-3))
    base = Hypothesis(geo, rows, "enhanced", tuple(robot.compliant_joints), (), refs, weight)
    stacked = base.extended(make_effect("backlash", "elbow_joint", geo)).extended(
        make_effect("gravity_preload", None, geo))
    x_base = np.log([3e5, 3e5, 2e5, 4e4, 4e4, 4e4])
    x_stacked = np.concatenate([x_base, [0.4], [0.3, 0.2, -0.1, 0.1]])
    checked = 0
    for current, x_current in ((base, x_base), (stacked, x_stacked)):
        for effect in candidates(current):
            model = current.extended(effect)
            x = model.extend_x(x_current, effect)
            x[len(x_current):] += rng.uniform(0.1, 0.5, effect.n_params)
            pred, jac = model.predict_with_jacobian(x)
            np.testing.assert_allclose(pred, model.predict(x), rtol=1e-13, atol=1e-18)
            columns = np.flatnonzero(model.analytic_columns)
            assert np.array_equal(columns[:6], np.arange(6))
            scale = np.abs(jac[..., columns]).max()
            for i in columns:
                h = 1e-6 * max(1.0, abs(x[i]))
                step = np.zeros_like(x)
                step[i] = h
                fd = (model.predict(x + step) - model.predict(x - step)) / (2 * h)
                np.testing.assert_allclose(jac[..., i], fd, rtol=0, atol=1e-7 * scale,
                                           err_msg=f"{model.describe()}: column {i}")
            assert not jac[..., ~model.analytic_columns].any()
            checked += 1
    assert checked > 60


def test_an_unbounded_interval_is_marked_undetermined_in_json():
    """A parameter whose interval the data do not bound says so (issue 30): ``determined``."""
    from stiffness.elastic.effects.base import Parameter
    loose = Parameter("k", 3.0e7, float("inf"), (0.0, float("inf")), "N.m/rad").to_dict()
    tight = Parameter("k", 9.35e5, 1.2e4, (9.1e5, 9.6e5), "N.m/rad").to_dict()
    assert loose["determined"] is False and loose["ci95"] == [0.0, None]
    assert tight["determined"] is True
