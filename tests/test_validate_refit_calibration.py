"""``stiffness validate --refit-frame`` / ``--refit-markers``: the verdict is calibrated.

A right UR5 model (one marker, its measuring frame, marker offset and zero offsets fitted on
12 poses at 50 um) judged on 8 poses of the same robot seen from a tracker moved by a random
rigid motion (0.1 rad, 50 mm per axis): after the refit the verdict's p-value (the chi-square
on the components less the refitted parameters, with the model's parameter covariance) is
uniform, so "above the noise" comes at the test's 5 % level; an elbow zero offset changed by
4e-4 rad on the second day (0.2 mm at the marker, 4 noise stds) is rejected most of the time.

Measured over 400 seeds (1000-1399): --refit-frame 4.75 %, --refit-markers 5.5 % rejected (KS
p of the p-values 0.86 and 0.58); before 6 December 2026 (soft_l1's weights left in the
registration, the refitted columns zeroed in the covariance) 7.5 % and 9.5 %. With the 4e-4
rad elbow offset 96 % and 96 % of 200 (2e-4 rad: 31 %, 33 %). Without the degrees of freedom
the refit takes (24 components tested as if nothing were fitted) 0.75 % and 0.25 % of the 400,
and here the p-values' KS p 2e-15 and 8e-32 (this file fails). These 100 seeds: 3 and 7
rejected, KS p 0.36 and 0.44; the code before 6 December 2026 gives 5 and 9 (its 2.5-4.5 %
excess needs some 400 seeds to show).
docs/absolute-poses.md, Another day.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin
import pytest
from scipy import stats

import stiffness
from stiffness.calibration.pose_fit import fit_pose_model, rows_of, starting_frame
from stiffness.calibration.pose_model import Marker, PoseModel
from stiffness.calibration.pose_model_file import write_pose_model
from stiffness.calibration.selection import GOF_LEVEL
from stiffness.cli.main import main
from stiffness.errors import StiffnessError
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.robot import load_robot

NOISE = 50e-6  # m
FAMILIES = ("frame", "markers", "joint_offsets")
MARKERS = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05]))]
SEEDS = 100
ORIENTED_SEEDS = 30
TURN_NOISE = 5e-5  # rad, an oriented marker's (a 6-D probe's) rotation noise
POWER_SEEDS = 15
ELBOW_OFFSET = 4e-4  # rad, day B's elbow zero offset beyond day A's
LEVEL = 1.0 - GOF_LEVEL


def _days(robot, seed: int, path, elbow: float = 0.0, turns: float | None = None):
    """The model file of day A (12 poses) and the campaign of day B (8 poses): the same
    hidden marker offset and zero offsets (the elbow's moved by ``elbow`` rad), the tracker
    moved by a random rigid motion; the marker's orientations measured at ``turns`` rad
    when given."""
    rng = np.random.default_rng(1000 + seed)
    rotation, translation = pin.exp3(rng.normal(size=3)), rng.uniform(-2, 2, 3)
    offsets = np.array([m.offset for m in MARKERS]) + rng.normal(0, 2e-3, (1, 3))
    zeros = rng.normal(0, 1e-3, 6)
    day_a = simulate_pose_campaign(robot, MARKERS, HiddenPoseErrors(
        rotation, translation, offsets, zeros, np.zeros((6, 6))), 12, NOISE, seed=2 * seed,
        rotation_noise_std=turns)
    motion, shift = pin.exp3(rng.normal(0, 0.1, 3)), rng.normal(0, 0.05, 3)
    zeros_b = zeros + elbow * (np.arange(6) == 2)
    day_b = simulate_pose_campaign(robot, MARKERS, HiddenPoseErrors(
        motion @ rotation, motion @ translation + shift, offsets, zeros_b, np.zeros((6, 6))),
        8, NOISE, seed=2 * seed + 1, rotation_noise_std=turns)
    model = PoseModel(robot, day_a.markers, FAMILIES, starting_frame(day_a), day_a.loads)
    fit = fit_pose_model(model, day_a, rows_of(model, day_a), list(FAMILIES))
    return write_pose_model(fit, day_a, path / f"model-{seed}.json"), day_b


@pytest.fixture(scope="module")
def robot():
    return load_robot("ur5", frame="tool0")


@pytest.fixture(scope="module")
def honest(robot, tmp_path_factory):
    """Per refit (frame; frame and markers): the verdicts and p-values over SEEDS seeds."""
    root = tmp_path_factory.mktemp("honest")
    out: dict[tuple[str, ...], list[dict]] = {("frame",): [], ("frame", "markers"): []}
    for seed in range(SEEDS):
        model, day_b = _days(robot, seed, root)
        for refit, results in out.items():
            results.append(stiffness.validate(model, day_b, refit=refit).to_dict())
    return out


@pytest.mark.parametrize("refit", [("frame",), ("frame", "markers")])
def test_a_right_model_is_rejected_at_the_level(honest, refit):
    """The reported verdicts: "above the noise" within the two-sided 99 % binomial band of
    the 5 % level (1..11 of 100), the reported p-values uniform (Kolmogorov-Smirnov p >
    0.01), the degrees of freedom the 24 components less the 6 or 9 refitted, the parameter
    covariance in the test."""
    results = honest[refit]
    assert all(r["verdict_test"] == "noise and the model's parameter uncertainty"
               for r in results)
    assert {r["dof"] for r in results} == {24 - (9 if "markers" in refit else 6)}
    _assert_calibrated(results)


def _assert_calibrated(results: list[dict]) -> None:
    """The verdicts of a right model's seeds reject at :data:`LEVEL`: the count within its
    binomial 99 % interval, and the p-values uniform (KS p above 0.01)."""
    rejected = sum(r["verdict"] == "above the noise" for r in results)
    low, high = stats.binom.interval(0.99, len(results), LEVEL)
    assert low <= rejected <= high, rejected
    p = np.array([r["gof_p_with_parameters"] for r in results])
    assert stats.kstest(p, "uniform").pvalue > 0.01


def test_a_changed_elbow_offset_is_rejected(robot, tmp_path):
    """Day B's elbow zero offset 4e-4 rad off day A's (4 noise stds at the marker): the
    frame refitted does not absorb it; rejected in at least 80 % of POWER_SEEDS seeds (96 %
    of 200 measured) with the frame and with the markers refitted."""
    counts = {("frame",): 0, ("frame", "markers"): 0}
    for seed in range(POWER_SEEDS):
        model, day_b = _days(robot, SEEDS + seed, tmp_path, ELBOW_OFFSET)
        for refit in counts:
            verdict = stiffness.validate(model, day_b, refit=refit).verdict
            counts[refit] += verdict == "above the noise"
    assert all(c >= 0.8 * POWER_SEEDS for c in counts.values()), counts


def test_refitting_a_family_the_model_lacks_is_refused(robot, tmp_path, capsys):
    """A model fitted without marker offsets, validated with ``--refit-markers``: one line
    naming the family (a KeyError before), exit 2 on the command line; ``--refit-frame``
    still judges it."""
    _, day_b = _days(robot, 0, tmp_path)
    model = PoseModel(robot, day_b.markers, ("frame", "joint_offsets"),
                      starting_frame(day_b), day_b.loads)
    fit = fit_pose_model(model, day_b, rows_of(model, day_b), ["frame", "joint_offsets"])
    path = write_pose_model(fit, day_b, tmp_path / "no-markers.json")
    with pytest.raises(StiffnessError, match="no markers family .* without refitting markers"):
        stiffness.validate(path, day_b, refit=("frame", "markers"))
    stiffness.write_pose_campaign(day_b, tmp_path / "b")
    assert main(["validate", str(path), str(tmp_path / "b"), "--refit-markers"]) == 2
    assert "no markers family" in capsys.readouterr().err
    assert stiffness.validate(path, day_b, refit=("frame",)).to_dict()["dof"] == 24 - 6


def test_oriented_markers_are_in_the_registration(robot, tmp_path):
    """Day B measuring the marker's orientations at 5e-5 rad (50 um over 1 m): the frame is
    fitted to positions and orientations, as the verdict tests them, so the frame's own fit
    error is not left in the orientations. Over ORIENTED_SEEDS seeds "above the noise" within
    the two-sided 99 % binomial band (0..5 of 30), the p-values uniform (KS p > 0.01), the
    42 components less 6. Registered on positions alone (until 6 December 2026) a right model
    was rejected in 39.5 % of 200 seeds (13 of 200 now: 6.5 %; 5e-4 rad: 6 % before and
    after); here 1 of 30, KS p 0.73 (11 of 30 before)."""
    results = []
    for seed in range(ORIENTED_SEEDS):
        model, day_b = _days(robot, 2 * SEEDS + seed, tmp_path, turns=TURN_NOISE)
        results.append(stiffness.validate(model, day_b, refit=("frame",)).to_dict())
    assert {r["dof"] for r in results} == {8 * 6 - 6}
    _assert_calibrated(results)


def test_an_orientation_seen_without_its_position_is_in_the_registration(robot, tmp_path):
    """Day B's marker seen at 8 orientations but at 5 positions (3 rows' positions lost):
    the verdict tests the 15 position and 24 orientation components less the 6 refitted, and
    the frame is fitted to the same components. Checked independently of the registration:
    the frame fitted by scipy's least squares to those 39 components (orientations weighted
    sigma_t / sigma_r) lowers the registered frame's sum of squares (in noise stds squared)
    by less than 1e-6. Before, the 9 orientations without positions were left out of the
    refit: the drop was 0.21, 3.28, 4.44 on these seeds, and over 200 seeds a right model was
    rejected in 16 (8 %, KS p of the p-values 0.0018); now 6 (3 %, KS p 0.43)."""
    from scipy.optimize import least_squares

    from stiffness.calibration.pose_model_file import read_pose_model
    from stiffness.calibration.pose_register import (
        registered,
        validation_orientations,
        validation_residual,
    )

    for seed in range(3):
        model, day_b = _days(robot, 300 + seed, tmp_path, turns=TURN_NOISE)
        positions = day_b.positions.copy()
        positions[:3] = np.nan
        day_b = dataclasses.replace(day_b, positions=positions)
        assert np.isfinite(day_b.rotations[:3]).all()
        result = stiffness.validate(model, day_b, refit=("frame",)).to_dict()
        assert result["dof"] == 5 * 3 + 8 * 3 - 6
        calibration = read_pose_model(model, day_b.robot)
        moved, _ = registered(calibration.model, calibration.x, day_b, ("frame",))
        frame = calibration.model.slices()["frame"]

        def components(values, at=moved, model=calibration.model, campaign=day_b,
                       frame=frame):
            x = at.copy()
            x[frame] = values
            r = validation_residual(model, x, campaign)
            turned, _ = validation_orientations(model, x, campaign)
            return np.concatenate([r[np.isfinite(r)], NOISE / TURN_NOISE * turned]) / NOISE

        assert components(moved[frame]).size == 5 * 3 + 8 * 3
        start = float(np.sum(components(moved[frame]) ** 2))
        best = least_squares(components, moved[frame], x_scale="jac", xtol=1e-15, ftol=1e-15,
                             gtol=1e-15)
        assert start - 2.0 * best.cost < 1e-6, (seed, start - 2.0 * best.cost)
