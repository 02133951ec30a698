"""The one rule of every fit's 95 % intervals (``selection.Noise``, both campaign kinds,
identify and diagnose): a declared noise std takes the normal quantiles; a noise estimated from
the data takes Student's t with its degrees of freedom; and a robust fit's intervals, from
Huber's sandwich, take Student's t over the fit's ``n - p`` degrees of freedom whether the
noise std scaling its loss is declared or not (the sandwich takes its spread from the
residuals, not from that std).

The robust-and-declared case is checked here on a tiny problem: a linear model of 3
parameters observed by 6 residual components (3 degrees of freedom), Gaussian noise of a
declared std, fitted under soft_l1 scaled by that std, the covariance the engine's
(:func:`stiffness.calibration.solver.covariance_matrix`). Over 200 seeds (600 intervals) the
rule's intervals (t, 3.18 standard errors) cover 568 (standardised errors' variance 1.07) and
pass the two-sided check of tests/stats.py; the normal quantile's (1.96) cover 525 (2.82),
intervals twice as wide 595 (0.27), half as wide 487 (4.27): the check fails all three. On UR5
identifications of the same size (three compliant joints, one configuration, two loads,
declared noise, soft_l1, 720 intervals; docs/outliers.md) the normal quantile covered 0.879
and Student's t 0.965."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pose_campaigns import ur10_rigid_lift_campaign
from scipy import stats
from scipy.optimize import least_squares
from stats import Coverage

from stiffness.calibration.diagnose import diagnose
from stiffness.calibration.fitting import compliance_covariance
from stiffness.calibration.pose_fit import fit_pose_model, rows_of, starting_frame
from stiffness.calibration.pose_model import PoseModel
from stiffness.calibration.selection import Noise
from stiffness.calibration.solver import covariance_matrix
from stiffness.planning.simulate import simulate

SIGMA = 0.01
N, P, SEEDS = 6, 3, 200
N_INTERVALS = SEEDS * P


def _fits() -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(estimate, standard errors, truth) of a soft_l1 fit per seed, declared noise."""
    out = []
    for seed in range(SEEDS):
        rng = np.random.default_rng(seed)
        jac = rng.normal(size=(N, P))
        truth = rng.normal(size=P)
        y = jac @ truth + rng.normal(0.0, SIGMA, N)
        fit = least_squares(lambda x, j=jac, y=y: j @ x - y, np.zeros(P), loss="soft_l1",
                            f_scale=SIGMA, xtol=1e-12)
        cov = covariance_matrix(jac, SIGMA, "soft_l1", jac @ fit.x - y, SIGMA).matrix
        out.append((fit.x, np.sqrt(np.diag(cov)), truth))
    return out


def _coverage(fits, quantile: float) -> Coverage:
    cov = Coverage()
    for x, se, truth in fits:
        cov.add_all(x, x - quantile * se, x + quantile * se, truth)
    return cov


def test_a_robust_fits_intervals_take_students_t_even_with_a_declared_noise():
    """The rule's quantile for a robust fit with a declared noise: t with n - p = 3 degrees
    of freedom; its intervals pass the two-sided check (tests/stats.py: coverage consistent
    with 95 %, standardised errors of variance about 1), and the check fails the normal
    quantile's and the rule's scaled by 2 and by 0.5, so it can fail."""
    noise = Noise(SIGMA).of_fit("soft_l1", N, covariance_matrix(np.eye(N, P), SIGMA))
    assert noise.dof == N - P and noise.sigma == SIGMA
    assert noise.two_sided() == pytest.approx(3.182446, abs=1e-6)
    assert noise.one_sided() == pytest.approx(2.353363, abs=1e-6)
    fits = _fits()
    _coverage(fits, noise.two_sided()).check(min_n=N_INTERVALS)
    for wrong in (Noise(SIGMA).two_sided(), 2.0 * noise.two_sided(), 0.5 * noise.two_sided()):
        with pytest.raises(AssertionError):
            _coverage(fits, wrong).check(min_n=N_INTERVALS)


def test_the_rule_by_how_the_noise_is_known():
    """Declared: the normal quantiles, for least squares only; estimated from n residuals of
    p parameters: Student's t with n - p degrees of freedom (at least 1)."""
    declared = Noise(2e-6)
    six = covariance_matrix(np.eye(9, 6), 1.0)  # of rank 6
    assert declared.declared and declared.of_fit("linear", 9, six) is declared
    assert declared.two_sided() == pytest.approx(1.959964, abs=1e-6)
    assert declared.one_sided() == pytest.approx(1.644854, abs=1e-6)
    estimated = Noise.estimated(2e-6, 9, 6)
    assert not estimated.declared and estimated.dof == 3
    assert estimated.of_fit("linear", 9, six) is estimated
    assert Noise.estimated(1.0, 3, 5).dof == 1
    robust = declared.of_fit("huber", 9, six)
    assert robust == Noise(2e-6, 3) and robust.one_sided() == pytest.approx(2.353363, abs=1e-6)


def test_a_robust_fits_t_takes_the_directions_its_sandwich_spreads_over():
    """A parameterless switch (``complementary_stiffness``) counts in the information
    criterion's p but gives the sandwich no direction: diagnose's robust intervals take
    t(n - 3) over the three springs, as the sandwich's N - p does (they took t(n - 4)). The
    quantile is read back from each reported interval, ``k / (1 -+ t SE(k) / k)``."""
    sim = simulate("ur5", configs=3, loads_per_config=2, noise_std_m=5e-6, seed=1,
                   kq=[3e4, 2e4, 1.5e4], max_force=100.0, target_offset_m=[0.0, 0.0, 0.1],
                   compliant_joints=["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"])
    d = diagnose(sim.campaign, propose=False, workers=1, loss="huber", max_steps=0,
                 families=["complementary_stiffness"])
    assert d.final.penalty_params == 4 and len(d.final.kept) == 3
    t = stats.t.ppf(0.975, sim.campaign.deflection.size - 3)
    for p in d.final_stiffness:
        s = p.standard_error / p.value
        assert (1.0 - p.value / p.ci95[1]) / s == pytest.approx(t, rel=1e-9)
        assert (p.value / p.ci95[0] - 1.0) / s == pytest.approx(t, rel=1e-9)


def _rank(covariance: np.ndarray) -> int:
    """numpy's count of the directions ``covariance`` spreads over, on its correlation matrix
    (free of the parameters' units, which span 1e-14 to 1 here)."""
    s = np.sqrt(np.diag(covariance))
    return int(np.linalg.matrix_rank(covariance / np.outer(s, s), hermitian=True))


def test_a_robust_fits_t_counts_a_parameter_at_its_bound_in_both_kinds():
    """One count for both campaign kinds (``Noise.of_fit``): a robust fit's intervals take
    t(N - p), p the directions the covariance it reports spreads over, numpy's rank of it,
    a parameter at its bound among them. A pose fit counted only its free parameters' (p one
    less); a deflection fit its ``ln k`` columns', where a spring at its rigid bound
    (1e14 N.m/rad) vanished or not by a factor of 1e-10 (its compliance's column does not).

    Deflection: UR5, pan, lift, elbow, the lift rigid, one configuration under six loads
    (N = 18), huber, seed 5: the lift at its bound; its one-sided bound ``above 1 / (c + t se_c)``
    read back gives t(15), not t(16). Pose: UR10, 30 poses of two markers (N = 180), frame,
    markers and joint compliances, the lift rigid, huber, seed 3: the lift's compliance at 0,
    the fit's noise of N - 16 degrees of freedom, not 165."""
    arm = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint")
    sim = simulate("ur5", kq=[3e4, 1e13, 1.5e4], compliant_joints=arm,
                   target_offset_m=[0.0, 0.0, 0.1], max_force=100.0, noise_std_m=2e-5,
                   configs=1, loads_per_config=6, seed=5)
    measured = sim.campaign.deflection
    d = diagnose(sim.campaign, propose=False, workers=1, loss="huber", max_steps=0)
    assert d.final.at_bound == [1] and len(d.final.kept) == 3
    cov = compliance_covariance(d.final, 2e-5, measured)  # robust: the sandwich, any sigma
    p = _rank(cov)
    assert p == 3
    c = math.exp(-d.final.x[1])  # rad/(N.m), 1e-14
    se_c = math.sqrt(cov[1, 1]) * c
    t = (1.0 / d.final_stiffness[1].ci95[0] - c) / se_c
    assert t == pytest.approx(stats.t.ppf(0.95, measured.size - p), rel=1e-6)
    assert abs(t / stats.t.ppf(0.95, measured.size - p + 1) - 1.0) > 3e-3  # can fail

    c = ur10_rigid_lift_campaign()
    families = ["frame", "markers", "joint_compliance"]
    model = PoseModel(c.robot, c.markers, tuple(families), starting_frame(c), c.loads)
    fit = fit_pose_model(model, c, rows_of(model, c), families, loss="huber")
    assert len(fit.at_bound) == 1
    n = int(np.isfinite(fit.residual).sum())  # positions only: no orientations measured
    assert fit.noise.dof == n - _rank(fit.covariance) == 180 - 16
