"""Robust losses on pose campaigns (``diagnose --loss`` on tracker data, issue 29): gross
outliers (a marker seen through a reflection, a mislabelled row) against least squares.

Measured here (UR10, two markers, 50 poses, tracker noise 20 um declared, a 150 N payload;
hidden measuring frame, marker offsets, zero offsets and joint compliance; 2 of the 100 marker
positions moved by 50 x the noise in a random direction; seeds 0-7; the 8 zero offsets and
compliances the fit keeps per seed, 64 intervals):

============  ================  ==================================================
loss          95 % coverage     held-out 3-D RMS / (sqrt(3) noise), clean campaign
============  ================  ==================================================
linear        22 / 64           1.52 mean (seeds 1.38 to 1.74)
soft_l1       60 / 64           1.04 mean (seeds 0.93 to 1.18)
============  ================  ==================================================

The test checks every fitted parameter (frame and markers too, 160 intervals): soft_l1 covers
148 with standardised variance 1.15 (two-sided, tests/stats.py); least squares is not
consistent with 95 %.

Without outliers (40 poses; soft_l1 on seeds 0 and 1, huber with the noise undeclared on
seed 2) the robust fits move each parameter by at most 0.72 of its least-squares standard
deviation, their intervals are within 6 % of least squares' widths, and huber's robust noise
estimate is 0.94 of the true noise (0.91 before the robust fit's shrinkage of its residuals
was corrected, :func:`stiffness.calibration.outliers.residual_shrinkage`; over 100 seeds of 20
poses, soft_l1, 0.920 +- 0.011 before, 0.994 +- 0.012 after).
"""

from __future__ import annotations

import json

import numpy as np
import pinocchio as pin
import pytest
from pose_truth import add_intervals
from stats import Coverage, binomial_consistent

from stiffness.calibration.pose_campaign import write_pose_campaign
from stiffness.calibration.pose_fit import PoseFit, fit_pose_model, rows_of, starting_frame
from stiffness.calibration.pose_model import Marker, PoseModel
from stiffness.calibration.pose_register import validation_errors
from stiffness.cli.main import main
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.robot import load_robot

NOISE = 20e-6  # m
PAYLOAD = np.array([0.0, 0.0, -150.0, 0.0, 0.0, 0.0])  # N at tool0
FAMILIES = ["frame", "markers", "joint_offsets", "joint_compliance"]
MARKERS = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05])),
           Marker("elbow", "forearm_link", np.array([0.0, 0.05, 0.2]))]


@pytest.fixture(scope="module")
def ur10():
    return load_robot("ur10", frame="tool0")


def _hidden(rng: np.random.Generator) -> HiddenPoseErrors:
    return HiddenPoseErrors(
        pin.exp3(rng.normal(size=3)), rng.uniform(-2, 2, 3),
        np.array([m.offset for m in MARKERS]) + rng.normal(0, 2e-3, (2, 3)),
        rng.normal(0.0, 1e-3, 6), np.zeros((6, 6)),
        stiffness=np.array([3e5, 2e5, 1.2e5, 4e4, 3e4, 3e4]))


def _with_outliers(c, share: float, size: float, rng: np.random.Generator) -> np.ndarray:
    """Move ``share`` of the marker positions by ``size`` (m) in random directions; returns
    the (row, marker) pairs moved."""
    pairs = [(i, k) for i in range(c.n_rows) for k in range(len(c.markers))]
    moved = rng.choice(len(pairs), max(1, round(share * len(pairs))), replace=False)
    for p in moved:
        d = rng.normal(size=3)
        c.positions[pairs[p]] += size * d / np.linalg.norm(d)
    return moved


def _fit(robot, c, loss: str) -> tuple[PoseModel, PoseFit]:
    model = PoseModel(robot, c.markers, tuple(FAMILIES), starting_frame(c), c.loads)
    return model, fit_pose_model(model, c, rows_of(model, c), FAMILIES, loss=loss)


def test_soft_l1_recovers_the_truth_through_gross_outliers(ur10):
    """8 seeds, 2 % of the marker positions 50 x the noise off: soft_l1's intervals cover the
    truth of every fitted parameter at a consistent rate and spread and its held-out
    RMS on a clean campaign of the same arm is the noise's; least squares' coverage is not
    consistent with 95 % and its held-out RMS is a quarter above soft_l1's (numbers in the
    module docstring)."""
    cov = {"linear": Coverage(), "soft_l1": Coverage()}
    held = {"linear": [], "soft_l1": []}
    for seed in range(8):
        rng = np.random.default_rng(seed)
        hidden = _hidden(rng)
        c = simulate_pose_campaign(ur10, MARKERS, hidden, 50, NOISE, seed=seed, payload=PAYLOAD)
        clean = simulate_pose_campaign(ur10, MARKERS, hidden, 20, NOISE, seed=seed + 100,
                                       payload=PAYLOAD)
        _with_outliers(c, 0.02, 50 * NOISE, rng)
        for loss in cov:
            _, fit = _fit(ur10, c, loss)
            add_intervals(cov[loss], fit, hidden, c)
            held[loss].append(validation_errors(fit.model, fit.x, clean)["rms"]
                              / (np.sqrt(3) * NOISE))
    cov["soft_l1"].check()
    assert not binomial_consistent(cov["linear"].hits, cov["linear"].n), cov["linear"].summary()
    assert np.mean(held["soft_l1"]) < 1.1 and max(held["soft_l1"]) < 1.25, held
    assert np.mean(held["linear"]) > 1.25 * np.mean(held["soft_l1"]), held


def test_robust_fit_agrees_with_least_squares_without_outliers(ur10):
    """No outliers: soft_l1 (declared noise, 2 seeds) and huber (noise undeclared, estimated
    robustly) move each kept parameter by less than one least-squares standard deviation,
    with intervals within 25 % of least squares' widths; the fit records its loss, the
    scale's source and its intervals' noise (Student's t over n - p: selection.Noise)."""
    for seed, loss in ((0, "soft_l1"), (1, "soft_l1"), (2, "huber")):
        rng = np.random.default_rng(seed)
        c = simulate_pose_campaign(ur10, MARKERS, _hidden(rng), 40, NOISE, seed=seed,
                                   payload=PAYLOAD)
        _, ls = _fit(ur10, c, "linear")
        if loss == "huber":
            c.noise_std = None
        _, robust = _fit(ur10, c, loss)
        assert robust.loss == loss
        if loss == "huber":
            assert robust.sigma_source == "robust"
            assert robust.sigma == pytest.approx(NOISE, rel=0.25)
        else:
            assert robust.sigma_source == "declared" and robust.sigma == NOISE
        # its intervals' noise: the sandwich's, estimated over n - p, declared scale or not
        assert robust.noise.dof == robust.n_observed - robust.n_fitted
        assert ls.noise.declared and ls.noise.sigma == NOISE
        k = ls.identifiability.kept
        assert robust.identifiability.kept == k
        assert np.all(np.abs(robust.x[k] - ls.x[k]) < ls.std()[k])
        assert np.all(np.abs(robust.std()[k] / ls.std()[k] - 1.0) < 0.25)


def test_diagnose_loss_on_a_pose_campaign_file(ur10, tmp_path, capsys):
    """``diagnose --loss huber --out`` on a pose campaign with an outlier: accepted, named in
    the text report, recorded as ``loss`` in diagnosis.json; an unknown loss is refused."""
    rng = np.random.default_rng(21)
    hidden = _hidden(rng)
    hidden.stiffness = None
    c = simulate_pose_campaign(ur10, MARKERS, hidden, 15, NOISE, seed=21)
    moved = _with_outliers(c, 0.04, 50 * NOISE, rng)
    write_pose_campaign(c, tmp_path / "c")
    assert len(moved) == 1
    assert main(["diagnose", str(tmp_path / "c"), "--loss", "huber",
                 "--out", str(tmp_path / "d")]) == 0
    out = capsys.readouterr().out
    assert "loss huber" in out
    # not an RMS under the loss (torso-passive under soft_l1: RMS 1.27 mm beside 'CV RMS' 0.24)
    assert "under huber, the root of the held-out loss per component" in out
    record = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    assert record["loss"] == "huber" and record["kind"] == "poses"
    with pytest.raises(SystemExit):
        main(["diagnose", str(tmp_path / "c"), "--loss", "l2"])
    assert "invalid choice" in capsys.readouterr().err


@pytest.fixture(scope="module")
def xarm_least_squares():
    """An xArm7 campaign (40 poses, hidden frame, marker, zero offsets and springs) and its
    least-squares diagnosis, shared by the robust losses' tests."""
    from stiffness.calibration.pose_diagnose import diagnose_poses

    arm = load_robot("xarm7")
    n = arm.n_coordinates
    hidden = HiddenPoseErrors(np.eye(3), np.array([1.0, 0.5, 0.2]), np.array([[0, 0, 0.051]]),
                              np.full(n, 5e-4), np.zeros((n, 6)), np.full(n, 3e4))
    c = simulate_pose_campaign(arm, [Marker("tip", arm.target_frame, np.array([0, 0, 0.05]))],
                               hidden, 40, NOISE, seed=1)
    least = diagnose_poses(c)
    assert least.families == ["frame", "markers", "joint_offsets", "joint_compliance"]
    return c, least


@pytest.mark.parametrize("loss", ["soft_l1", "huber"])
def test_robust_diagnose_screens_families_as_least_squares_does(loss, xarm_least_squares):
    """With no outliers, a robust diagnosis adds the same families as least squares. The
    screen compares each candidate's linearised objective under the fit's loss with the
    current fit's: comparing a sum of squares with a robust loss sum (as once) rejected every
    family whose first step leaves the residual well above the noise (here the zero offsets,
    with the sag still unexplained: +186 instead of -60) and ended unexplained."""
    from stiffness.calibration.pose_diagnose import diagnose_poses

    c, least = xarm_least_squares
    robust = diagnose_poses(c, loss=loss)
    assert robust.families == least.families
    assert robust.unexplained is False
