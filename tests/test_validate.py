"""``stiffness validate`` against the right robot, with a verdict (issue 38.2): a model of one
robot on a campaign of another is refused with one line; on its own robot the residual is
tested against the campaign's declared noise (chi-square over the 3 n seen components)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import stats

import stiffness
from stiffness.calibration.campaign import load_campaign
from stiffness.cli.main import main
from stiffness.elastic.model_contents import ModelRobotError
from stiffness.elastic.model_file import read_model_file

UR5_ARM = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"]
ARM_K = [3e4, 2e4, 1.5e4]  # N.m/rad
NOISE = 5e-6  # m


@pytest.fixture(scope="module")
def ur5(tmp_path_factory):
    """Two simulated UR5 campaigns of the same springs (seeds 1 and 2, noise declared) and the
    model identified on the first."""
    root = tmp_path_factory.mktemp("validate")
    for seed in (1, 2):
        stiffness.simulate("ur5", kq=ARM_K, compliant_joints=UR5_ARM, configs=4,
                           loads_per_config=3, max_force=100.0, noise_std_m=NOISE,
                           seed=seed).write(root / f"c{seed}")
    assert main(["identify", str(root / "c1"), "--out", str(root / "model.json"),
                 "--quiet"]) == 0
    return root


def test_a_model_of_another_robot_is_refused(ur5, tmp_path, capsys):
    """An SK120 model (identified on the shipped Table II campaign) on a UR5 campaign: exit
    2, one line naming both robots."""
    sk120 = tmp_path / "sk120.json"
    assert main(["identify", "robots/sk120/campaigns/table2", "--out", str(sk120),
                 "--quiet"]) == 0
    capsys.readouterr()
    assert main(["validate", str(sk120), str(ur5 / "c2")]) == 2
    err = capsys.readouterr().err.strip()
    assert "not of the model's 'sk120'" in err and "\n" not in err, err
    with pytest.raises(ModelRobotError, match="other coordinates"):
        stiffness.validate(sk120, ur5 / "c2")


@pytest.mark.parametrize("swap", [("c1", "model.json"), ("c1/campaign.toml", "model.json")])
def test_a_campaign_and_a_model_given_the_wrong_way_round_are_named(ur5, swap, capsys):
    """validate CAMPAIGN MODEL (and kx/identify with the other kind of file): each is named
    as the wrong kind, with the order; they said 'model file ... is a folder, not a file' or
    'the file is not JSON; fix the syntax there' of a well-formed campaign.toml."""
    campaign, model = (str(ur5 / name) for name in swap)
    assert main(["validate", campaign, model]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("a campaign, not a model file; give the identified-model.json of "
                        "`stiffness identify` or the final-model.json of `stiffness diagnose "
                        "--out` (stiffness validate takes MODEL, then CAMPAIGN)"), err
    assert main(["kx", "--model", campaign, "--wrench", "0,0,-10"]) == 2
    assert "a campaign, not a model file" in capsys.readouterr().err
    assert main(["identify", model]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("model.json: a JSON file (a model file?), not a campaign; give a "
                        "campaign.toml or the folder holding one (stiffness validate takes "
                        "MODEL, then CAMPAIGN)"), err


def test_verdict_against_the_declared_noise(ur5, tmp_path, capsys):
    """The identified model predicts the other campaign to its noise (chi-square p above
    0.001, RMS about sqrt(3) noise stds); with its springs twice as stiff it is above the
    noise. chi2 is checked against the residuals summed here."""
    result = stiffness.validate(ur5 / "model.json", ur5 / "c2")
    assert main(["validate", str(ur5 / "model.json"), str(ur5 / "c2"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == json.loads(json.dumps(result.to_dict()))
    campaign = load_campaign(ur5 / "c2")
    model = stiffness.load_model(ur5 / "model.json")
    residual = campaign.deflection - np.array(
        [model.deflection(q, w, measured=True) for q, w in zip(campaign.q, campaign.wrench,
                                                               strict=True)])
    chi2 = float(np.sum(residual ** 2)) / NOISE ** 2
    d = result.to_dict()
    assert d["chi2"] == pytest.approx(chi2, rel=1e-9) and d["dof"] == residual.size
    assert d["gof_p"] == pytest.approx(stats.chi2.sf(chi2, residual.size), rel=1e-9)
    assert d["verdict"] == "consistent with the noise" and 0.7 < d["rms_over_noise"] < 1.4
    assert d["robot"]["source"] == "ur5" and d["robot"]["coordinates"][:3] == UR5_ARM
    stiff = read_model_file(ur5 / "model.json")
    stiff.k_theta = stiff.k_theta * 2
    stiff.write(tmp_path / "stiff.json")
    assert stiffness.validate(tmp_path / "stiff.json", ur5 / "c2").verdict == "above the noise"
    assert main(["validate", str(tmp_path / "stiff.json"), str(ur5 / "c2")]) == 0
    assert "verdict: ABOVE THE NOISE" in capsys.readouterr().out


def test_a_gross_row_is_flagged_where_it_is(ur5, tmp_path, capsys):
    """One row of the validation campaign moved by 200 noise stds (a tracker's slip): validate
    said only ABOVE THE NOISE, not where; identify flags such a row, validate did not. Now the
    row is flagged by its label and line (as identify's outliers), and the clean campaign
    flags none. Each component's excess is the shift over the declared noise, up to the
    model's own error (a few noise stds)."""
    import shutil

    shutil.copytree(ur5 / "c2", tmp_path / "c2")
    data = tmp_path / "c2" / "measurements.csv"
    lines = data.read_text().splitlines()
    header = lines[0].split(",")
    cells = lines[5].split(",")
    shift = 200 * NOISE * 1e3  # the campaign is in mm
    cells[header.index("dz")] = repr(float(cells[header.index("dz")]) + shift)
    data.write_text("\n".join([*lines[:5], ",".join(cells), *lines[6:]]) + "\n")
    clean = stiffness.validate(ur5 / "model.json", ur5 / "c2").to_dict()
    assert clean["outliers"] == [] and clean["outlier_threshold"] == 4.0
    moved = stiffness.validate(ur5 / "model.json", tmp_path / "c2").to_dict()
    assert len(moved["outliers"]) == 1, moved["outliers"]
    flagged = moved["outliers"][0]
    assert (flagged["line"], flagged["row"], flagged["component"]) == (6, 5, "dz")
    assert flagged["label"] == cells[0]
    assert -210 < flagged["standardised_residual"] < -190  # predicted minus measured
    assert main(["validate", str(ur5 / "model.json"), str(tmp_path / "c2")]) == 0
    out = capsys.readouterr().out
    assert "1 row(s)\n  config " + cells[0] + " row 5 (line 6): dz -" in out, out
