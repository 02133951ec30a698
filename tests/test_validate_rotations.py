"""``validate`` on a deflection campaign that measures rotations (``rx, ry, rz``): the chi-square
verdict takes the rotation components at their own declared noise (``rotation_noise_std``),
beside the translations at theirs; until 5 December 2026 it left them out without a word.

Checked against an independent computation (the conventional deflection ``J K^-1 J^T W`` of
:func:`stiffness.mechanics.formulation.deflection`, rows [v; omega], not the fit's array
algebra) and over many seeds: a model whose parameters are off their truth by draws from the
covariance its file states is called "above the noise" at the test's level (two-sided
binomial band and a Kolmogorov-Smirnov check of the p-values), and a model that predicts the
translations but not the rotations is caught only because the rotations are tested.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest
from scipy import stats
from ur5_arm import ARM, OFFSET, K, arm_rows

from stiffness.calibration.campaign import Campaign
from stiffness.calibration.campaign_toml import RobotSettings
from stiffness.calibration.diagnose import diagnose
from stiffness.calibration.pose_campaign import load_pose_campaign, write_pose_campaign
from stiffness.calibration.pose_fit import fit_pose_model, rows_of, starting_frame
from stiffness.calibration.pose_model import Marker, PoseModel
from stiffness.calibration.pose_model_file import write_pose_model
from stiffness.calibration.selection import GOF_LEVEL
from stiffness.calibration.validation import validate
from stiffness.calibration.validation_page import format_validation
from stiffness.elastic.model_contents import ModelFile
from stiffness.elastic.parameter_covariance import ParameterCovariance
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.robot import load_robot
from stiffness.units import Units

NOISE = 5e-6  # m
ROTATION_NOISE = 5e-6  # rad
SEEDS = 150


@pytest.fixture(scope="module")
def design():
    """The UR5 arm over 3 configurations x 2 loads (forces up to 100 N): the robot, the rows'
    coordinates and forces, and their true [translation; rotation] (m, rad) under ``K`` by
    the conventional formula."""
    return arm_rows(3, 2, rotations=True)


def _campaign(design, rng: np.random.Generator, rotation_noise: float | None = ROTATION_NOISE
              ) -> Campaign:
    """The design's rows measured with the declared noises (mm and deg, the default units)."""
    robot, q, force, truth = design
    settings = RobotSettings("ur5", target_offset_m=OFFSET, compliant_joints=ARM)
    return Campaign("rotations", "conventional", settings, q=q, force=force,
                    deflection=truth[:, :3] + rng.normal(size=force.shape) * NOISE,
                    rotation=truth[:, 3:] + rng.normal(size=force.shape) * ROTATION_NOISE,
                    noise_std_m=NOISE, rotation_noise_std_rad=rotation_noise,
                    config=tuple(f"c{i // 2}" for i in range(len(q))), _robot=robot)


def _model(robot, k: np.ndarray = K, covariance: np.ndarray | None = None) -> ModelFile:
    """A conventional model file of the arm's springs ``k``, with the covariance of their
    ``ln k`` or none."""
    return ModelFile(source="ur5", frame=robot.target_frame, target_offset_m=OFFSET,
                     compliant_joints=ARM, k_theta=np.asarray(k, dtype=float),
                     units=("N.m/rad",) * 3, formulation="conventional",
                     covariance=None if covariance is None else ParameterCovariance(
                         tuple(f"ln k_theta({j})" for j in ARM), ("1",) * 3, covariance))


def test_rotations_are_tested_at_their_own_noise(design):
    """The right model: ``chi2`` is ``sum r_t^2 / sigma_t^2 + sum r_r^2 / sigma_r^2`` of the
    residuals from the conventional formula, on 18 + 18 components; without a declared
    rotation noise the rotations are reported (their error angles) and left out."""
    robot, _, _, truth = design
    c = _campaign(design, np.random.default_rng(1))
    out = validate(_model(robot), c).to_dict()
    r_t = (c.deflection - truth[:, :3]).reshape(-1)
    r_r = (c.rotation - truth[:, 3:]).reshape(-1)
    expected = r_t @ r_t / NOISE ** 2 + r_r @ r_r / ROTATION_NOISE ** 2
    assert out["chi2"] == pytest.approx(expected, rel=1e-6)
    assert out["dof"] == 36 and out["rotation_components"] == 18
    assert out["gof_p"] == pytest.approx(stats.chi2.sf(expected, 36), rel=1e-6)
    assert out["rotation_noise_std"] == pytest.approx(np.degrees(ROTATION_NOISE), rel=1e-12)
    angles = np.degrees(np.linalg.norm(c.rotation - truth[:, 3:], axis=1))
    assert out["rotation_rms"] == pytest.approx(np.sqrt(np.mean(angles ** 2)), rel=1e-6)
    assert out["rotation_unit"] == "deg"

    undeclared = validate(_model(robot), replace(c, rotation_noise_std_rad=None)).to_dict()
    assert undeclared["dof"] == 18 and undeclared["rotation_components"] == 0
    assert undeclared["chi2"] == pytest.approx(r_t @ r_t / NOISE ** 2, rel=1e-6)
    assert undeclared["rotation_noise_std"] is None
    assert undeclared["rotation_rms"] == pytest.approx(out["rotation_rms"], rel=1e-12)
    assert "18 of the components rotations at their noise 0.0002865 deg" in format_validation(
        out)
    assert "rotations measured but not tested" in format_validation(undeclared)


def test_a_model_wrong_only_in_rotations_is_caught(design):
    """Rotations read 2 % high (a gyro's scale: 4 rotation noise stds per component on
    average here): the translations alone find the right springs consistent with the noise
    on 18 of 20 seeds (measured), the test with the rotations calls 20 of 20 above it."""
    robot, _, _, truth = design
    with_rotations = translations_only = 0
    for seed in range(20):
        c = _campaign(design, np.random.default_rng(100 + seed))
        c = replace(c, rotation=c.rotation + 0.02 * truth[:, 3:])
        with_rotations += validate(_model(robot), c).verdict == "above the noise"
        translations_only += validate(_model(robot), replace(
            c, rotation_noise_std_rad=None)).verdict == "above the noise"
    assert with_rotations == 20 and translations_only <= 3, (with_rotations, translations_only)


def test_false_alarms_at_the_level_with_the_parameters_uncertainty(design):
    """150 seeds: the springs' ln k drawn about their truth from the covariance the model
    file states (the parameters add 2.3 times the noise variance to a component on average),
    the campaign's noise drawn afresh. The verdict (with the parameters' uncertainty, on the
    translations and the rotations at their own noise) is "above the noise" within the
    two-sided binomial band of 5 % (alpha 1e-3: 1 to 18 of 150; measured 7) and its p-values
    pass a Kolmogorov-Smirnov test of uniformity (p > 1e-3; measured 0.18; over 800 other
    seeds the chi-square's mean was 36.03 and its variance 69.9, chi2(36)'s 36 and 72); the
    noise-only test rejects far more often (measured 120)."""
    robot, _, _, _ = design
    cov = np.diag([0.009, 0.006, 0.012]) ** 2
    cov[0, 1] = cov[1, 0] = 0.5 * 0.009 * 0.006
    draws = np.random.default_rng(5)
    above = noise_only = 0
    p_values = []
    for seed in range(SEEDS):
        rng = np.random.default_rng(1000 + seed)
        k = K * np.exp(draws.multivariate_normal(np.zeros(3), cov))
        result = validate(_model(robot, k, cov), _campaign(design, rng))
        out = result.to_dict()
        assert out["verdict_test"] == "noise and the model's parameter uncertainty"
        assert out["dof"] == 36
        p_values.append(out["gof_p_with_parameters"])
        above += out["verdict"] == "above the noise"
        noise_only += out["gof_p"] <= 1.0 - GOF_LEVEL
    low, high = stats.binom.ppf([5e-4, 1 - 5e-4], SEEDS, 1.0 - GOF_LEVEL)
    assert low <= above <= high, (above, noise_only)
    assert stats.kstest(p_values, "uniform").pvalue > 1e-3
    assert noise_only > high + 10, (noise_only, above)


def test_a_pose_campaigns_oriented_markers_are_tested_at_their_own_noise(tmp_path):
    """A pose calibration (UR10, two markers, 20 poses, frame, markers, offsets and geometry
    fitted with orientations) validated on another campaign with orientations (mm and deg):
    the test's components are the 3 + 3 of every marker seen, its ``chi2`` the positions'
    ``sum r^2 / sigma^2`` plus the orientations' ``sum |e|^2 / sigma_r^2`` with ``|e|`` the
    error angles ``rotation_rms`` reports (another path: each orientation's own
    ``log(R_pred R_meas^T)``), and the parameter term spans both kinds."""
    ur10 = load_robot("ur10", frame="tool0")
    markers = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05])),
               Marker("elbow", "forearm_link", np.array([0.0, 0.05, 0.2]))]
    rng = np.random.default_rng(5)
    eps = np.zeros((6, 6))
    eps[:, :2] = rng.normal(0.0, 4e-4, (6, 2))
    hidden = HiddenPoseErrors(pin.exp3(rng.normal(size=3)), rng.uniform(-2, 2, 3),
                              np.array([m.offset for m in markers]) + rng.normal(0, 2e-3, (2, 3)),
                              rng.normal(0.0, 1e-3, 6), eps)
    noise, noise_rot = 20e-6, 1e-4
    for name, seed in (("a", 5), ("b", 6)):
        write_pose_campaign(simulate_pose_campaign(
            ur10, markers, hidden, 20, noise, seed=seed, rotation_noise_std=noise_rot,
            payload=np.array([0.0, 0.0, -150.0, 0.0, 0.0, 0.0]),
            units=Units("rad", "N", "mm", rotation_unit="deg")), tmp_path / name)
    a = load_pose_campaign(tmp_path / "a")
    families = ["frame", "markers", "joint_offsets", "geometry"]
    model = PoseModel(ur10, a.markers, tuple(families), starting_frame(a), a.loads)
    write_pose_model(fit_pose_model(model, a, rows_of(model, a), families), a,
                     tmp_path / "model.json")
    result = validate(tmp_path / "model.json", tmp_path / "b")
    out = result.to_dict()
    positions = 3 * sum(m["rows"] for m in out["markers"].values())
    assert positions == 120 and out["rotation_components"] == 120 and out["dof"] == 240
    assert out["rotation_noise_std"] == pytest.approx(np.degrees(noise_rot), rel=1e-12)
    b = load_pose_campaign(tmp_path / "b")
    position_chi2 = (out["rms"] * 1e-3 / noise) ** 2 * positions / 3
    rotation_chi2 = (np.radians(out["rotation_rms"]) / noise_rot) ** 2 * b.n_rows * 2
    assert out["chi2"] == pytest.approx(position_chi2 + rotation_chi2, rel=1e-6)
    assert out["gof_p"] == pytest.approx(stats.chi2.sf(out["chi2"], 240), rel=1e-6)
    assert 0.3 < rotation_chi2 / 120 < 2.0  # the right model: about the noise
    term = result.parameters
    assert term is not None and term.residual.size == 240
    assert out["chi2_with_parameters"] <= out["chi2"]


def test_diagnose_validate_stages_test_the_rotations_too(design):
    """``diagnose --validate`` on a campaign with rotations: the baseline's stage (nothing
    added: the right model) takes the rotations as the final model file's validation does,
    the same chi-squares to round-off on 18 + 18 components."""
    robot, _, _, _ = design
    fitted = _campaign(design, np.random.default_rng(7))
    other = _campaign(design, np.random.default_rng(8))
    d = diagnose(fitted, propose=False, workers=1, validate=other)
    assert not d.steps
    final, base = d.validation, d.baseline_validation
    assert base is not None and final is not None
    for key in ("dof", "rotation_components"):
        assert base[key] == final[key] == {"dof": 36, "rotation_components": 18}[key]
    for key in ("chi2", "chi2_with_parameters"):
        assert base[key] == pytest.approx(final[key], rel=1e-9)
