"""``stiffness diagnose CAMPAIGN --validate OTHER --refit-frame`` / ``--refit-markers``: every
step's model judged on a pose campaign of another day after its measuring frame (and marker
offsets) is registered anew there (``stiffness.calibration.pose_register.stage_errors``), as
``stiffness validate --refit-frame`` judges one model.

A UR10 with hidden zero offsets and marker offsets, calibrated on day A (30 poses) and validated
on day B (15 poses) of the same robot seen from a tracker turned by 4 deg and moved by 30 mm
(simulated twice, the second frame ``D R_A``, ``D t_A + d``): with each step's own frame the
stage table's held-out errors are that motion (tens of mm) and the report says so; with the
frame fitted they are the noise's, ``sqrt(3) sigma`` for the model that has the zero offsets,
and the motion fitted is the simulated one.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from pose_campaigns import TWO_DAYS_SHIFT, TWO_DAYS_TURN, ur10_markers, ur10_two_days

import stiffness
from stiffness.cli.main import main
from stiffness.errors import StiffnessError
from stiffness.robot.sources import robots_directory

NOISE = 20e-6  # m
MARKERS = ur10_markers()
TURN, SHIFT = TWO_DAYS_TURN, TWO_DAYS_SHIFT  # rad, m: the tracker's motion between the days


@pytest.fixture(scope="module")
def days(tmp_path_factory):
    """Day A's and day B's campaign folders: the same hidden marker and zero offsets, the
    measuring frame moved (rigidly: ``D``, ``d``)."""
    root = tmp_path_factory.mktemp("drefit")
    day_a, day_b = ur10_two_days(NOISE)
    stiffness.write_pose_campaign(day_a, root / "a")
    stiffness.write_pose_campaign(day_b, root / "b")
    return root / "a", root / "b"


@pytest.fixture(scope="module")
def plain(days):
    a, b = days
    return stiffness.diagnose(a, validate=b, max_steps=1)


@pytest.fixture(scope="module")
def fitted(days):
    a, b = days
    return stiffness.diagnose(a, validate=b, max_steps=1, refit=("frame",))


def test_each_step_with_its_own_frame_sees_the_tracker_move(plain):
    """Without the flag every stage's held-out error is the tracker's motion (over 500
    noise stds; the 4 deg turn alone moves a marker 2 m away by about 140 mm); each stage's
    frame registered there says where the error is: the registration leaves under a tenth
    of it, and the motion it finds is the simulated one (an independent closed form,
    ``D = exp(TURN)``, ``d = SHIFT``) to 1e-3 rad, 2 mm (the baseline's rigid robot misses
    the zero offsets)."""
    steps = plain.to_dict()["steps"]
    assert [s["family"] for s in steps] == ["baseline", "joint_offsets"]
    for s in steps:
        v = s["validation"]
        assert v["unit"] == "m" and v["rms"] > 500 * NOISE
        frame = v["frame_refit"]
        assert frame["applied"] is False and frame["families"] == ["frame"]
        assert frame["rms"] < 0.1 * v["rms"]
        assert np.allclose(np.radians(frame["rotation_deg"]), TURN, atol=1e-3)
        assert np.allclose(frame["translation"], SHIFT, atol=2e-3)


def test_with_the_frame_fitted_the_stage_table_drops_to_the_noise(plain, fitted):
    """With ``refit=("frame",)`` the final step (zero offsets fitted on day A) predicts
    day B to the noise: its 3-D RMS within 30 % of ``sqrt(3) sigma`` (seeds fixed), the
    motion fitted the simulated one to 1e-4 rad and 0.2 mm, 6 parameters; the baseline
    (no zero offsets) keeps the robot's error, above the final's. The stage errors are the
    registration's own ``rms``, and the fit itself is the one without the flag."""
    before, after = plain.to_dict(), fitted.to_dict()
    assert [s["rms"] for s in after["steps"]] == [s["rms"] for s in before["steps"]]
    final = after["steps"][-1]["validation"]
    assert abs(final["rms"] / (np.sqrt(3) * NOISE) - 1) < 0.3
    frame = final["frame_refit"]
    assert frame["applied"] is True and frame["parameters"] == 6
    assert np.allclose(np.radians(frame["rotation_deg"]), TURN, atol=1e-4)
    assert np.allclose(frame["translation"], SHIFT, atol=2e-4)
    assert final["rms"] == pytest.approx(frame["rms"], rel=1e-6)
    assert final["rms"] == pytest.approx(
        before["steps"][-1]["validation"]["frame_refit"]["rms"], rel=1e-6)
    assert after["steps"][0]["validation"]["rms"] > 10 * final["rms"]


def test_the_text_and_the_page_say_it(days, capsys, tmp_path):
    """The text: without the flag, the note naming --refit-frame; with --refit-markers, the
    families fitted and 12 parameters, the stage table's errors at the noise; --json carries
    frame_refit per step; the page says the frame was fitted."""
    a, b = days
    assert main(["diagnose", str(a), "--validate", str(b), "--max-steps", "1",
                 "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "note: the error is mostly the measuring frame's" in out and "--refit-frame" in out
    assert main(["diagnose", str(a), "--validate", str(b), "--max-steps", "1", "--quiet",
                 "--refit-markers", "--out", str(tmp_path / "d")]) == 0
    out = capsys.readouterr().out
    assert "measuring frame and marker offsets fitted to the validation campaign" in out
    assert "(12 parameters)" in out and "note:" not in out
    page = (tmp_path / "d" / "diagnosis.html").read_text()
    assert "with its measuring frame and marker offsets fitted there" in page
    assert "--refit-markers" in page
    assert main(["diagnose", str(a), "--validate", str(b), "--max-steps", "0", "--quiet",
                 "--refit-frame", "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["steps"][0]["validation"]["frame_refit"]["families"] == ["frame"]


def test_deflection_campaigns_refuse_the_flags(capsys, tmp_path):
    """A deflection campaign has no measuring frame: diagnose and validate refuse the flags
    in one line, before any work."""
    campaign = str(robots_directory() / "sk120" / "campaigns" / "table2")
    assert main(["diagnose", campaign, "--validate", campaign, "--refit-frame"]) == 2
    err = capsys.readouterr().err.strip()
    assert "take pose campaigns" in err and len(err.splitlines()) == 1
    with pytest.raises(StiffnessError, match="take pose campaigns"):
        stiffness.diagnose(campaign, validate=campaign, refit=("frame",))
    model = tmp_path / "model.json"
    assert main(["identify", campaign, "--out", str(model)]) == 0
    capsys.readouterr()
    assert main(["validate", str(model), campaign, "--refit-markers"]) == 2
    assert "take pose campaigns" in capsys.readouterr().err


def test_refit_without_validation_or_of_another_family_is_refused(days):
    """``refit`` without ``validate``, or naming another family: one line each."""
    a, b = days
    with pytest.raises(StiffnessError, match="give validate"):
        stiffness.diagnose(a, refit=("frame",))
    with pytest.raises(StiffnessError, match="refit must be"):
        stiffness.diagnose(a, validate=b, refit=("geometry",))


def test_report_of_a_campaign_passes_the_flags_on(days, capsys, tmp_path):
    """``stiffness report CAMPAIGN --validate OTHER --refit-frame`` is ``diagnose``'s: its page
    says the frame was fitted there; without a campaign the flag is refused in one line."""
    a, b = days
    assert main(["report", str(a), "--validate", str(b), "--refit-frame", "--quiet",
                 "--out", str(tmp_path / "r")]) == 0
    assert "measuring frame fitted to the validation campaign" in capsys.readouterr().out
    page = (tmp_path / "r" / "diagnosis.html").read_text()
    assert "with its measuring frame fitted there" in page
    assert main(["report", "--refit-frame", "--out", str(tmp_path / "s")]) == 2
    assert "--refit-frame take(s) a campaign" in capsys.readouterr().err
