"""``joint_offsets``' deflection face: the loaded minus the unloaded tool at ``q + delta_0``, seen
through the Jacobian there (:meth:`JointOffsets.jacobian_change`).

Checked against independent computations: its analytic Jacobian columns against central finite
differences of the prediction; its prediction against the exact equilibria
(:func:`stiffness.batch.equilibrium.solve_equilibria`) at the offset configurations minus those
at the commanded ones (error second order in the offsets); the simulator's hidden offsets
against the same exact equilibria.
"""

from __future__ import annotations

import numpy as np
import pytest

from stiffness.batch.equilibrium import solve_equilibria
from stiffness.elastic.effects import Geometry, Hypothesis, candidates, make_effect
from stiffness.elastic.effects.geometry import References
from stiffness.planning.simulate import parse_effect, simulate

#: a soft UR10 (docs/diagnose.md, "Joint zero offsets")
KQ = [1.2e5, 8e4, 6e4, 2e4, 2e4, 1.5e4]


@pytest.fixture(scope="module")
def ur10():
    sim = simulate("ur10", kq=KQ, configs=4, loads_per_config=2, max_force=300.0, seed=0,
                   noise_std_m=0.0)
    camp = sim.campaign
    robot = camp.robot()
    geo = Geometry.of(robot)
    return camp, robot, geo


def _model(geo, camp, force, extra=(), rotation_weight=None):
    rows = geo.rows(camp.q, force)
    refs = References.of(geo, rows, 4e4, camp.deflection)
    base = Hypothesis(geo, rows, "enhanced", tuple(geo.joints), tuple(extra), refs,
                      rotation_weight=rotation_weight)
    return base.extended(make_effect("joint_offsets", None, geo).on_rows(base, rows))


def test_wrist_3_offset_is_no_parameter_when_the_tool_is_on_its_axis(ur10):
    """The UR10's tool0 lies on wrist_3's axis: its offset moves no Jacobian the campaign
    sees, so the candidate has the other five joints."""
    camp, _, geo = ur10
    model = _model(geo, camp, camp.force)
    assert model.effects[-1].joints == geo.joints[:5]
    assert [e.label for e in candidates(model.with_effects(()))].count("joint_offsets") == 1


@pytest.mark.parametrize("extra, rotation_weight", [
    ((), None), (("complementary_stiffness",), None), (("backlash:elbow_joint",), 0.1)])
def test_analytic_columns_match_finite_differences(ur10, extra, rotation_weight):
    camp, _, geo = ur10
    effects = [make_effect(*(e.split(":") + [None])[:2], geo) for e in extra]
    model = _model(geo, camp, camp.force, effects, rotation_weight)
    rng = np.random.default_rng(1)
    x = np.concatenate([np.log(KQ), rng.normal(size=model.n_params - len(KQ))])
    _, jac = model.predict_with_jacobian(x)
    offsets = slice(model.offsets[-2], model.offsets[-1])
    assert model.analytic_columns[offsets].all()
    step = 1e-4
    for i in range(offsets.start, offsets.stop):
        e = np.zeros(model.n_params)
        e[i] = step
        fd = (model.predict(x + e) - model.predict(x - e)) / (2 * step)
        assert np.abs(jac[..., i] - fd).max() <= 1e-6 * np.abs(fd).max()


def test_prediction_is_the_exact_change_to_second_order(ur10):
    """Offsets of 4, 2, 1 and 0.5 mrad on every joint (random signs), a tenth of the load so
    that the deflection's own third order stays below: the prediction's change minus the exact
    equilibria's at ``q + delta_0`` minus at ``q`` falls as delta_0 squared (log-log slope 2),
    with the second-order kinematics in the model."""
    camp, robot, geo = ur10
    force = 0.1 * camp.force
    model = _model(geo, camp, force, [make_effect("complementary_stiffness", None, geo)])
    signs = np.random.default_rng(3).choice([-1.0, 1.0], 6)
    q = np.array([robot.configuration(c) for c in camp.q])
    exact0 = solve_equilibria(robot, q, np.diag(KQ), force).dx
    x0 = np.concatenate([np.log(KQ), np.zeros(5)])
    sizes, errors = np.array([4e-3, 2e-3, 1e-3, 5e-4]), []
    for d in sizes:
        delta = d * signs
        q_d = np.array([robot.configuration(c + delta) for c in camp.q])
        exact = solve_equilibria(robot, q_d, np.diag(KQ), force).dx - exact0
        change = model.predict(np.concatenate([np.log(KQ), delta[:5] / 1e-3])) - model.predict(x0)
        errors.append(np.sqrt(np.mean((change - exact) ** 2)))
        assert errors[-1] < 2.0 * d * np.sqrt(np.mean(exact ** 2))  # relative O(delta_0)
    slope = np.polyfit(np.log(sizes), np.log(errors), 1)[0]
    assert 1.8 < slope < 2.2


def test_simulated_offsets_are_the_exact_equilibria_at_the_offset_configuration():
    """``stiffness simulate --effect joint_offsets=...`` measures the exact equilibrium at
    ``q + delta_0`` (not the first-order model): its noise-free deflections equal
    :func:`solve_equilibria` there."""
    values = (0.2, -0.1, 0.15, -0.3, 0.25, -0.05)  # deg
    sim = simulate("ur10", kq=KQ, configs=3, loads_per_config=2, max_force=300.0, seed=2,
                   noise_std_m=0.0, effects=[parse_effect(
                       "joint_offsets=" + ",".join(str(v) for v in values))])
    camp = sim.campaign
    robot = camp.robot()
    q_d = np.array([robot.configuration(c + np.radians(values)) for c in camp.q])
    exact = solve_equilibria(robot, q_d, np.diag(KQ), camp.force).dx
    assert np.abs(camp.deflection - exact).max() < 1e-12  # SI
    q = np.array([robot.configuration(c) for c in camp.q])
    unmoved = solve_equilibria(robot, q, np.diag(KQ), camp.force).dx
    assert np.abs(unmoved - exact).max() > 1e-7  # the offsets show
