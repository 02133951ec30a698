"""``stiffness validate --refit-frame`` / ``--refit-markers``: a pose calibration judged on a
campaign of another day, the tracker moved (``stiffness.calibration.pose_register``).

FIGAROH's TALOS left arm calibrated on 7 February 2022 and validated on 10 February: 93 mm of
3-D error with the model's measuring frame, most of it the tracker's frame (and a marker plate
mounted again). Here a UR10 calibrated on one campaign and validated on another of the same
robot seen from a frame turned by 4 deg and moved by 30 mm: with the model's frame the error
is the motion; with the frame fitted the campaign is consistent with its noise, and the motion
fitted is the one simulated (an independent closed form: ``D = R_B R_A^T``,
``d = t_B - D t_A``).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from pose_campaigns import TWO_DAYS_SHIFT, TWO_DAYS_TURN, ur10_markers, ur10_two_days

import stiffness
from stiffness.calibration.pose_fit import fit_pose_model, rows_of, starting_frame
from stiffness.calibration.pose_model import PoseModel
from stiffness.calibration.pose_model_file import write_pose_model
from stiffness.cli.main import main
from stiffness.errors import StiffnessError
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.robot import load_robot

NOISE = 20e-6  # m
FAMILIES = ["frame", "markers", "joint_offsets"]
MARKERS = ur10_markers()
TURN, SHIFT = TWO_DAYS_TURN, TWO_DAYS_SHIFT  # rad, m: the tracker's motion between the days


@pytest.fixture(scope="module")
def days(tmp_path_factory):
    """The model file of day A (30 poses) and the campaign of day B (15 poses): the same
    hidden marker offsets and zero offsets, the measuring frame moved."""
    root = tmp_path_factory.mktemp("refit")
    day_a, day_b = ur10_two_days(NOISE)
    model = PoseModel(day_a.robot, day_a.markers, tuple(FAMILIES), starting_frame(day_a),
                      day_a.loads)
    fit = fit_pose_model(model, day_a, rows_of(model, day_a), FAMILIES)
    stiffness.write_pose_campaign(day_b, root / "b")
    for row in (3, 11):  # ghosts: the tracker took another marker for the tip
        day_b.positions[row, 0] += np.array([0.3, -0.2, 0.1])
    stiffness.write_pose_campaign(day_b, root / "ghosts")
    return write_pose_model(fit, day_a, root / "model.json"), root / "b"


def test_the_frame_fitted_on_another_day_leaves_the_noise(days):
    """With the model's frame: above the noise, the 3-D RMS over 1000 noise stds. Fitted
    (6 parameters): consistent with the noise (seeds fixed), the RMS within 30 % of the
    noise's ``sqrt(3) sigma``, 6 degrees of freedom fewer, and the motion the simulated one to
    1e-4 rad and 0.2 mm (the day-A fit's own frame error, 1e-5 rad at 2 m from the tracker,
    is in it)."""
    model, campaign = days
    plain = stiffness.validate(model, campaign).to_dict()
    assert plain["verdict"] == "above the noise"
    assert plain["rms"] > 1000 * NOISE
    assert plain["frame_refit"]["applied"] is False
    fitted = stiffness.validate(model, campaign, refit=("frame",)).to_dict()
    assert fitted["verdict"] == "consistent with the noise"
    assert abs(fitted["rms"] / (np.sqrt(3) * NOISE) - 1) < 0.3
    assert fitted["dof"] == plain["dof"] - 6
    frame = fitted["frame_refit"]
    assert frame["applied"] is True and frame["parameters"] == 6
    assert np.allclose(np.radians(frame["rotation_deg"]), TURN, atol=1e-4)
    assert np.allclose(frame["translation"], SHIFT, atol=2e-4)
    assert plain["frame_refit"]["rms"] == pytest.approx(fitted["rms"], rel=1e-6)


def test_the_report_says_the_error_is_the_frame(days, capsys):
    """Without the flag the text says the error is the frame's and names the flag; with it,
    the motion fitted."""
    model, campaign = days
    assert main(["validate", str(model), str(campaign)]) == 0
    out = capsys.readouterr().out
    assert "the error is mostly the measuring frame's" in out and "--refit-frame" in out
    assert main(["validate", str(model), str(campaign), "--refit-markers"]) == 0
    out = capsys.readouterr().out
    assert "measuring frame and marker offsets fitted to this campaign" in out
    assert "(12 parameters)" in out


def test_ghost_markers_do_not_move_the_frame_fitted(days):
    """Two of day B's 15 rows with the tip 0.37 m off (FIGAROH's TIAGo campaigns have such
    ghosts, 0.2-1 m): the frame fitted is still the simulated motion to 1e-4 rad and 0.2 mm
    (least squares moved it by centimetres), and those two rows are the ones flagged."""
    model, campaign = days
    fitted = stiffness.validate(model, campaign.parent / "ghosts", refit=("frame",)).to_dict()
    frame = fitted["frame_refit"]
    assert np.allclose(np.radians(frame["rotation_deg"]), TURN, atol=1e-4)
    assert np.allclose(frame["translation"], SHIFT, atol=2e-4)
    assert sorted({o["row"] for o in fitted["outliers"]}) == [4, 12]


def test_a_campaign_of_some_of_the_model_markers_is_validated(days, tmp_path):
    """Day B measuring the tip alone (the elbow marker fallen off) was refused ('validate
    with the same markers'); now the elbow is unseen: the tip's errors are those of the
    campaign with both, the elbow never seen, the chi-square on the tip's components. A
    campaign marker the model lacks is still refused."""
    model, campaign = days
    both = stiffness.validate(model, campaign, refit=("frame",)).to_dict()
    c = stiffness.load_pose_campaign(campaign)
    tip = dataclasses.replace(c, markers=c.markers[:1], positions=c.positions[:, :1])
    alone = stiffness.validate(model, tip).to_dict()
    plain = stiffness.validate(model, campaign).to_dict()
    assert alone["markers"]["tip"]["rms"] == pytest.approx(plain["markers"]["tip"]["rms"],
                                                           rel=1e-12)
    assert alone["markers"]["elbow"]["rms"] is None and alone["dof"] == 3 * c.n_rows
    refitted = stiffness.validate(model, tip, refit=("frame",)).to_dict()
    assert refitted["verdict"] == both["verdict"] == "consistent with the noise"
    other = dataclasses.replace(c, markers=[dataclasses.replace(c.markers[0], name="probe"),
                                            c.markers[1]])
    with pytest.raises(StiffnessError, match="marker 'probe' .* is not a marker of the model"):
        stiffness.validate(model, other)


def test_a_model_fitted_without_its_frame_is_validated(tmp_path, capsys):
    """A pose model fitted without the ``frame`` family (a tracker already registered to the
    robot's base) has no frame to register: validated as before the registration came (its
    3-D RMS that of the noise alone, ``sqrt(3)`` noise stds within 30 %, seeds fixed;
    ``frame_refit`` null), not refused; ``--refit-frame`` on it is refused naming that flag."""
    robot = load_robot("ur10", frame="tool0")
    markers = MARKERS[:1]
    hidden = HiddenPoseErrors(np.eye(3), np.zeros(3), np.array([m.offset for m in markers]),
                              np.zeros(6), np.zeros((6, 6)))
    day_a = simulate_pose_campaign(robot, markers, hidden, 20, NOISE, seed=1)
    day_b = simulate_pose_campaign(robot, markers, hidden, 12, NOISE, seed=2)
    families = ["markers", "joint_offsets"]
    model = PoseModel(robot, day_a.markers, tuple(families), starting_frame(day_a),
                      day_a.loads)
    fit = fit_pose_model(model, day_a, rows_of(model, day_a), families)
    path = write_pose_model(fit, day_a, tmp_path / "model.json")
    stiffness.write_pose_campaign(day_b, tmp_path / "b")
    result = stiffness.validate(path, tmp_path / "b").to_dict()
    assert result["frame_refit"] is None
    assert result["rms"] == pytest.approx(np.sqrt(3) * NOISE, rel=0.3)
    assert main(["validate", str(path), str(tmp_path / "b"), "--refit-frame"]) == 2
    err = capsys.readouterr().err
    assert "no frame family" in err and "(--refit-frame, --refit-markers)" in err, err
