"""A pose calibration validated on a deflection campaign (``stiffness validate``): its
``final-model.json`` is the elastic model ``load_model`` reads of it, evaluated at each row's
load without refitting, by path as by a :class:`~stiffness.elastic.model_contents.ModelFile`
of it (the path was refused as the wrong kind of campaign until 6 December 2026, the
ModelFile evaluated). The verdict is checked against the chi-square computed by hand from
``load_model``'s deflections at the campaign's target, row by row. A pose diagnosis with
``--validate`` on a deflection campaign is refused in one line naming it, by path as by
object (the path read as a pose campaign and complained of its ``baseline`` key)."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from scipy import stats

from stiffness import load_model
from stiffness.calibration.campaign import load_campaign
from stiffness.calibration.diagnose import diagnose
from stiffness.calibration.pose_campaign import write_pose_campaign
from stiffness.calibration.pose_fit import (
    campaign_settings,
    fit_pose_model,
    rows_of,
    starting_frame,
)
from stiffness.calibration.pose_model import Marker, PoseModel
from stiffness.calibration.pose_model_file import write_pose_model
from stiffness.calibration.validation import validate
from stiffness.cli.main import main
from stiffness.elastic.model_file import read_model_file
from stiffness.errors import StiffnessError
from stiffness.planning.simulate import simulate
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.robot import load_robot

K = np.array([3e5, 2e5, 1.2e5, 4e4, 3e4, 3e4])  # N.m/rad
OFFSET = np.array([0.0, 0.03, 0.05])  # m, the marker on tool0
FAMILIES = ["frame", "markers", "joint_compliance"]
NOISE = 1e-5  # m


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A UR10 pose calibration (12 poses under 150 N, springs only: the calibrated robot's
    kinematics are the nominal ones) and a deflection campaign of the same arm (3
    configurations x 2 loads, 10 um declared), written."""
    folder = tmp_path_factory.mktemp("pose-on-deflections")
    robot = load_robot("ur10", frame="tool0")
    markers = [Marker("tip", "tool0", OFFSET)]
    hidden = HiddenPoseErrors(np.eye(3), np.zeros(3), OFFSET[None, :], np.zeros(6),
                              np.zeros((6, 6)), K)
    poses = simulate_pose_campaign(robot, markers, hidden, 12, NOISE, seed=1,
                                   payload=np.array([0.0, 0.0, -150.0, 0.0, 0.0, 0.0]))
    model = PoseModel(robot, markers, tuple(FAMILIES), starting_frame(poses), poses.loads,
                      campaign_settings(poses))
    fit = fit_pose_model(model, poses, rows_of(model, poses), FAMILIES)
    write_pose_campaign(poses, folder / "poses")
    path = write_pose_model(fit, poses, folder / "diagnosis" / "final-model.json")
    simulate("ur10", kq=K, configs=3, loads_per_config=2, noise_std_m=NOISE, seed=2,
             frame="tool0", target_offset_m=OFFSET).write(folder / "deflections")
    return path, folder / "deflections", folder / "poses"


def test_the_verdict_is_the_chi_square_of_load_model_s_deflections(files):
    path, deflections, _ = files
    campaign = load_campaign(deflections)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the springs the poses left undetermined: said once
        by_path = validate(str(path), deflections).to_dict()
        by_file = validate(read_model_file(path), deflections).to_dict()
        # at the campaign's target (the calibration's is tool0's origin), as validate
        # evaluates a model where its campaign measured
        elastic = load_model(path, frame="tool0", target_offset=OFFSET)
    wrench = np.hstack([campaign.force, np.zeros_like(campaign.force)])
    predicted = np.array([elastic.deflection(q, w, measured=True)
                          for q, w in zip(campaign.q, wrench, strict=True)])
    residual = campaign.deflection - predicted  # m
    chi2 = float(np.sum(residual ** 2) / NOISE ** 2)
    n = residual.size
    assert n == 18 and by_path["dof"] == n and by_path["kind"] == "deflections"
    assert by_path["chi2"] == pytest.approx(chi2, rel=1e-6)
    assert by_path["gof_p"] == pytest.approx(stats.chi2.sf(chi2, n), rel=1e-6)
    assert by_path["verdict"] == ("above the noise" if stats.chi2.sf(chi2, n) <= 0.05
                                  else "consistent with the noise")
    rms_mm = float(np.sqrt(np.mean(np.sum(residual ** 2, axis=1)))) * 1e3
    assert by_path["unit"] == "mm" and by_path["rms"] == pytest.approx(rms_mm, rel=1e-6)
    assert by_path["rms_over_noise"] == pytest.approx(rms_mm / (np.sqrt(3) * NOISE * 1e3),
                                                      rel=1e-6)
    # no covariance carried from the pose fit: the noise-only test, said so
    assert by_path["verdict_test"] == "noise only"
    assert not by_path["parameter_uncertainty"]["included"]
    by_file.pop("model"), by_path.pop("model")
    assert by_file == by_path


def test_the_command_line_evaluates_it_too(files, capsys):
    path, deflections, _ = files
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["validate", str(path), str(deflections), "--json"]) == 0
        expected = validate(str(path), deflections).chi2
    out = json.loads(capsys.readouterr().out)
    assert out["kind"] == "deflections" and out["chi2"] == pytest.approx(expected, rel=1e-12)


def test_a_pose_diagnosis_refuses_a_deflection_campaign_in_one_line(files):
    _, deflections, poses = files
    for other in (deflections, load_campaign(deflections)):
        with pytest.raises(StiffnessError) as info:
            diagnose(poses, validate=other)
        text = str(info.value)
        assert "\n" not in text and "not on the deflection campaign" in text, text
