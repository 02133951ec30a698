"""Rotations to second order, like translations (issue 31, item 3).

The complementary-stiffness step predicts the rotation vector of the target frame with its
second-order term ``1/2 sum_{a<b} (w_a x w_b) dtheta_a dtheta_b``: the prediction then matches
the exact equilibrium's rotation vector to third order in the load (the exponent is fitted),
its fitting Jacobian matches central differences, and a campaign with nothing hidden and 5 urad
rotation noise ends explained at the chi-square test's rate.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import binom

from stiffness.calibration.diagnose import diagnose
from stiffness.calibration.selection import GOF_LEVEL
from stiffness.elastic.effects import make_effect
from stiffness.elastic.effects.geometry import Geometry, References
from stiffness.elastic.effects.hypothesis import Hypothesis
from stiffness.mechanics.equilibrium import solve_equilibrium
from stiffness.planning.simulate import simulate
from stiffness.robot.robot import load_robot

JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
          "wrist_2_joint", "wrist_3_joint"]
K = np.array([4e3, 3e3, 2e3, 1e3, 1e3, 8e2])  # N.m/rad: soft, so the second order shows
COORDS = np.array([0.3, -1.1, 1.4, -0.6, 1.2, 0.4])  # rad
WRENCH = np.array([30.0, -20.0, 40.0, 2.0, -1.5, 1.0])  # N, N.m
SCALES = np.geomspace(0.05, 1.0, 7)


def _hypothesis(effects: tuple[str, ...]):
    robot = load_robot("ur5", compliant_joints=JOINTS, target_offset=[0.05, 0.02, 0.1])
    geo = Geometry.of(robot)
    rows = geo.rows(np.tile(COORDS, (len(SCALES), 1)), SCALES[:, None] * WRENCH[:3],
                    SCALES[:, None] * WRENCH[3:])
    refs = References.of(geo, rows, 2e3, np.full((1, 3), 1e-3))
    made = tuple(make_effect(e, None, geo) for e in effects)
    baseline = "conventional" if effects else "enhanced"
    return robot, Hypothesis(geo, rows, baseline, tuple(JOINTS), made, refs, rotation_weight=1.0)


def _exponent(pred: np.ndarray, exact: np.ndarray) -> float:
    err = np.linalg.norm(pred - exact, axis=1)
    return float(np.polyfit(np.log(SCALES), np.log(err), 1)[0])


def test_rotation_matches_the_exact_equilibrium_to_third_order():
    robot, second = _hypothesis(("complementary_stiffness",))
    q0 = robot.configuration(COORDS)
    exact = np.array([np.concatenate([e.dx, e.rotation]) for e in (
        solve_equilibrium(robot, q0, np.diag(K), s * WRENCH) for s in SCALES)])
    pred = second.predict(np.log(K))
    # measured: 2.99 for both kinds (error 1.4e-5 rad at the largest load, rotation 0.032 rad)
    assert 2.8 < _exponent(pred[:, 3:], exact[:, 3:]) < 3.2
    assert 2.8 < _exponent(pred[:, :3], exact[:, :3]) < 3.2
    # the first-order rotation J_w dtheta (K_C in the tangent) departs at second order: 2.00
    _, first = _hypothesis(())
    assert 1.8 < _exponent(first.predict(np.log(K))[:, 3:], exact[:, 3:]) < 2.2


def test_rotation_rows_of_the_fitting_jacobian_against_central_differences():
    _, model = _hypothesis(("complementary_stiffness",))
    x = np.log(K) + 0.1 * np.sin(np.arange(len(K)))
    _, jac = model.predict_with_jacobian(x)
    h = 1e-6
    for i in range(len(K)):
        e = np.zeros_like(x)
        e[i] = h
        fd = (model.predict(x + e) - model.predict(x - e)) / (2 * h)
        np.testing.assert_allclose(jac[:, 3:, i], fd[:, 3:], rtol=1e-6,
                                   atol=1e-9 * np.abs(fd[:, 3:]).max())
        np.testing.assert_allclose(jac[:, :3, i], fd[:, :3], rtol=1e-6,
                                   atol=1e-9 * np.abs(fd[:, :3]).max())


def test_nothing_hidden_with_rotation_noise_ends_explained():
    """10 seeds, UR5 arm soft enough that the rotation's second order is several times the
    5 urad noise. Before the rotation term all 10 ended unexplained (final rotation RMS 1.2 to
    1.8 times the noise); measured now: 0 of 10, rotation RMS 0.93 to 1.14 times the noise."""
    arm = JOINTS[:3]
    noise = 5e-6
    unexplained = 0
    for seed in range(10):
        sim = simulate("ur5", kq=[1e4, 1e4, 8e3], compliant_joints=arm,
                       target_offset_m=[0.0, 0.0, 0.1], max_force=150.0, noise_std_m=noise,
                       rotations=True, rotation_noise_std_rad=noise, configs=6,
                       loads_per_config=4, seed=seed)
        d = diagnose(sim.campaign, propose=False)
        unexplained += int(bool(d.unexplained))
        rms = d.to_dict()["rms_by_kind"]["final"]  # the --json object carries it
        rotation_rad = rms["rotation"] * sim.campaign.units.rotation_to_si
        assert rotation_rad < 1.5 * noise, (seed, rotation_rad)
    # the verdict rejects a right model at rate 1 - GOF_LEVEL = 5 %: more than 3 of 10 is a
    # 0.1 % event (binomial), the test's level: a correct model fails it once in a thousand
    limit = 3
    assert binom.sf(limit, 10, 1.0 - GOF_LEVEL) < 0.0011
    assert unexplained <= limit, unexplained
