"""``transversal_compliance`` on a robot whose springs act on its controller's coordinates
(``[controller] springs_on = "controller"``, ``q_chain = A u + b``; tests/data/torso-passive:
five coordinates drive six chain joints, the chest pitch ``t4 = -T2 - T3`` passive), issue 35:
every revolute chain joint a compliant coordinate turns may tilt in its bearing, in deflection
and in pose campaigns.

Before, the tilts were looked for among the compliant joints, here controller coordinates:
none was a candidate, the pose simulator refused to hide one, and a deflection campaign
hiding a tilt of t3 was diagnosed with two link bends and ``gravity_preload`` as stand-ins,
T1 at 30.5e3 against 40e3 N.m/rad, ending UNEXPLAINED.

* the candidates are the six chain joints (t4 driven by T2 and T3);
* the deflection fit's analytic columns equal central differences (tilts of t3 and of the
  passive t4, springs' ``ln k``, translations and rotations);
* a deflection campaign hiding a tilt of t3 is diagnosed with it alone, reporting the
  intervals of the model fitted directly, whose coverage over 25 small campaigns is checked
  two-sidedly (too narrow and too wide both fail); a pose campaign names it too.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from deflection_columns import assert_columns
from stats import Coverage

from stiffness.calibration.deflection_parameters import stiffness_parameters
from stiffness.calibration.diagnose import diagnose
from stiffness.calibration.diagnosis import SI_UNITS
from stiffness.calibration.fitting import compliance_covariance
from stiffness.calibration.pose_diagnose import diagnose_poses
from stiffness.calibration.pose_model import Marker
from stiffness.calibration.poses import sample_coordinates
from stiffness.calibration.selection import Noise, fit_model
from stiffness.elastic.effects import candidates, make_effect
from stiffness.elastic.effects.base import effect_report
from stiffness.elastic.effects.geometry import Geometry, References
from stiffness.elastic.effects.hypothesis import Hypothesis
from stiffness.elastic.effects.joint_laws import ComplementaryStiffness
from stiffness.planning.simulate import build_truth, parse_effect, simulate
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.planning.simulate_request import draw_loads
from stiffness.robot.robot import load_robot
from stiffness.units import Units

TORSO = Path(__file__).parent / "data" / "torso-passive" / "robot.toml"
SPRINGS = ("T1", "T2", "T3", "A1", "A2")
K = np.array([4.0e4, 2.5e4, 2.0e4, 8.0e3, 6.0e3])  # N.m/rad, the file's k_theta_SI
TILT = np.array([2.0e4, 1.5e4])  # N.m/rad, the hidden tilt of t3
HIDDEN = "transversal_compliance:t3=2e4,1.5e4"
NOISE = 5e-6  # m
U = np.radians([[10.0, 20.0, 15.0, -30.0, 40.0], [-40.0, -10.0, 35.0, 60.0, -20.0]])
FORCES = np.array([[20.0, -15.0, -60.0], [-50.0, 30.0, 25.0]])


@pytest.fixture(scope="module")
def torso():
    return load_robot(str(TORSO))


def _hypothesis(robot, effects, rotation_weight=None) -> Hypothesis:
    geo = Geometry.of(robot)
    rows = geo.rows(np.repeat(U, 2, axis=0), np.tile(FORCES, (2, 1)),
                    np.tile([[1.0, -2.0, 0.5]], (4, 1)))
    refs = References.of(geo, rows, 2e4, np.full((1, 3), 1e-3))
    return Hypothesis(geo, rows, "enhanced", SPRINGS, tuple(effects), refs, rotation_weight)


def test_the_driven_chain_joints_are_candidates(torso):
    """One tilt candidate per chain joint the five springs turn, the passive t4 included (by
    T2 and T3); none before (0 of 6)."""
    assert torso.driven_joints(SPRINGS) == ("t1", "t2", "t3", "t4", "a1", "a2")
    assert torso.driven_joints(["T3"]) == ("t3", "t4")
    labels = {c.label for c in candidates(_hypothesis(torso, ()))}
    assert {f"transversal_compliance({j})" for j in ("t1", "t2", "t3", "t4", "a1", "a2")} \
        <= labels


@pytest.mark.parametrize("rotation_weight", [None, 0.2])
def test_analytic_columns_equal_central_differences(torso, rotation_weight):
    """The tilts' columns (the motion at unit variables) of t3 and of the passive t4, and the
    controller springs' ``ln k`` columns, against central differences of the whole prediction
    with the second-order kinematics on: 1e-6 relative."""
    geo = Geometry.of(torso)
    effects = (ComplementaryStiffness(), make_effect("transversal_compliance", "t3", geo),
               make_effect("transversal_compliance", "t4", geo))
    model = _hypothesis(torso, effects, rotation_weight)
    assert model.analytic_columns.all()
    x = np.concatenate([np.log(K), [0.7, 1.3], [0.4, 0.9]])
    assert_columns(model, x)


def _true_fit(robot, q, force, moment, deflection, effects: tuple) -> list:
    """The controller springs' and the effects' (``transversal_compliance(t3)`` last)
    parameters fitted directly to the rows (coordinates ``q``, loads N, N.m, deflections m;
    the enhanced baseline, the noise 5 um known) and reported as ``diagnose`` reports them
    (``stiffness_parameters``, ``effect_report``)."""
    geo = Geometry.of(robot)
    rows = geo.rows(q, force, moment)
    refs = References.of(geo, rows, 2e4, deflection)
    model = Hypothesis(geo, rows, "enhanced", SPRINGS, effects, refs)
    fit = fit_model(model, deflection, NOISE, np.concatenate([np.log(K), effects[-1].start()]))
    matrix = compliance_covariance(fit, NOISE, deflection)
    quantile = Noise(NOISE).two_sided()
    edge = Noise(NOISE).one_sided()
    n = len(SPRINGS)
    return [*stiffness_parameters(fit, matrix, quantile, edge),
            *effect_report(effects[-1], fit.x[n:], matrix[n:, n:], refs, SI_UNITS, quantile)]


def test_a_hidden_tilt_on_controller_springs_is_named():
    """8 configurations x 4 loads, 5 um noise, seed 1: the tilt of t3 is named first and
    alone, determined, and the search stops at the noise (before: link bends and
    gravity_preload as stand-ins, UNEXPLAINED at 7.9 x on 20 configurations); the reported
    intervals of the springs and the tilt are those of the model fitted directly
    (:func:`_true_fit`, to 1e-4), whose coverage the next test checks. Seeds 0-9: named first
    10 of 10 (3 times followed by complementary_stiffness), unexplained 2 of 10."""
    c = simulate(str(TORSO), effects=[HIDDEN], configs=8, noise_std_m=NOISE, seed=1).campaign
    d = diagnose(c, propose=False)
    assert [(s.effect.name, s.effect.where) for s in d.steps] == [
        ("transversal_compliance", "t3")]
    assert d.unexplained is False
    reported = [*d.final_stiffness, *d.final_parameters_si["transversal_compliance(t3)"]]
    direct = _true_fit(c.robot(), c.q, c.force, c.moment, c.deflection,
                       (make_effect("transversal_compliance", "t3", Geometry.of(c.robot())),))
    assert all(p.determined for p in reported[len(SPRINGS):])
    for p, q in zip(reported, direct, strict=True):
        assert p.value == pytest.approx(q.value, rel=1e-4), (p, q)
        assert p.ci95 == pytest.approx(q.ci95, rel=1e-4), (p, q)


def test_the_springs_and_tilt_intervals_cover_two_sidedly(torso):
    """25 campaigns of 4 configurations x 3 loads (5 um, seeds 0-24) hiding the tilt of t3:
    the true model (the five controller springs, the tilt, and complementary_stiffness, the
    exact equilibrium's second order that the simulation always holds) fitted directly
    reports 95 % intervals (175) that cover the truth two-sidedly
    (:meth:`stats.Coverage.check`). Measured over 200 seeds: 1326 of 1400 (94.7 %, two-sided
    binomial p 0.66), sum z^2 / n 1.04; at 20 configurations x 4 loads 1319 of 1400 (94.2 %,
    p 0.20), 1.03. Without complementary_stiffness, the model diagnose names in most seeds
    (the second order, 0.2-0.4 noise std RMS a component here, is named after the tilt in 3
    of 10 seeds at 8 configurations), the intervals are a little narrow: 1308 of 1400
    (93.4 %, p 0.011), 1.13; at 20 x 4, 1303 of 1400 (93.1 %, p 0.002), 1.14 (the springs'
    35 of 40 of seeds 0-7 measured before). No interval is at a bound. Seeds 0-24: 161 of
    175, 1.29; the intervals scaled 2x wider fail (variance 0.32), 2x narrower too (110 of
    175 covering)."""
    cov = Coverage()
    geo = Geometry.of(torso)
    truth = build_truth(torso, K, [parse_effect(HIDDEN)], Units(),  # no backlash: any
                        np.ones(len(geo.joints)), geo)  # smoothing torque (N.m) will do
    effects = (ComplementaryStiffness(), make_effect("transversal_compliance", "t3", geo))
    for seed in range(25):  # simulate's rows, without its effect sizes (half its time)
        rng = np.random.default_rng(seed)
        q = np.repeat(sample_coordinates(torso, 4, rng), 3, axis=0)
        force = np.vstack([draw_loads("random", 3, 100.0, rng) for _ in range(4)])
        deflection = truth.deflections(q, force) + rng.normal(0.0, NOISE, force.shape)
        for p, want in zip(_true_fit(torso, q, force, np.zeros_like(force), deflection,
                                     effects), [*K, *TILT], strict=True):
            assert not p.at_bound
            cov.add(p.value, p.ci95, want)
    cov.check(min_n=175)


def test_a_hidden_tilt_in_a_pose_campaign_is_named(torso):
    """The pose simulator hides the tilt of t3 (5e-5, 6e-5 rad/(N.m)) on the torso (before:
    refused, "name compliant revolute joints ... ()"); 30 poses, two markers, 20 um, a 100 N
    payload, seed 1: diagnose names transversal_compliance last and fits to noise (p 0.81),
    t3's two compliances and the five springs' covered (measured: t3 [4.64, 5.26] and [5.58,
    6.24] e-5). Seeds 0-7: named 8 of 8, t3's intervals covering 16 of 16, the springs' 37
    of 40, unexplained 1 of 8; seeds 0-99 (the families forced): 189 of 200 and 476 of 500
    (95.2 %, two-sided binomial p 0.94), sum z^2 / n 0.77 and 0.94."""
    markers = [Marker("tip", "tool", np.array([0.02, 0.0, 0.05])),
               Marker("chest", "t4_link", np.array([0.05, 0.0, 0.03]))]
    rng = np.random.default_rng(1)
    hidden = HiddenPoseErrors(pin.exp3(rng.normal(size=3)), rng.uniform(-2, 2, 3),
                              np.array([m.offset for m in markers])
                              + rng.normal(0, 2e-3, (2, 3)),
                              rng.normal(0, 1e-3, 6), np.zeros((6, 6)), K)
    truth = np.array([5e-5, 6e-5])
    hidden.transversal_compliance = {"t3": truth}
    c = simulate_pose_campaign(torso, markers, hidden, 30, 20e-6, seed=1,
                               payload=np.r_[30.0, -20.0, -100.0, 0.0, 0.0, 0.0])
    d = diagnose_poses(c, families=["joint_offsets", "joint_compliance"],
                       not_families=["geometry", "backlash", "gravity_compensator"])
    assert d.families[-1] == "transversal_compliance" and not d.unexplained
    found = {p["parameter"]: p["ci95"] for p in d.to_dict()["parameters"]}
    for i, c_true in enumerate(truth):
        low, high = found[f"t3 transversal compliance {i + 1}"]
        assert low <= c_true <= high
    for name, k in zip(SPRINGS, K, strict=True):
        low, high = found[f"{name} compliance"]
        assert low <= 1.0 / k <= high, name
