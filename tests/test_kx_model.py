"""`stiffness kx --model` reads the file `stiffness identify` writes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from stiffness.calibration.campaign import load_campaign
from stiffness.calibration.identify import identify
from stiffness.cli.main import main
from stiffness.robot.sources import robots_directory


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    campaign = load_campaign(robots_directory() / "sk120" / "campaigns" / "table2")
    result = identify(campaign, starts=2)
    path = tmp_path_factory.mktemp("model") / "identified-model.json"
    result.write_model(path)
    return result, path


def test_kx_uses_the_identified_robot_and_stiffness(identified, capsys):
    result, path = identified
    assert main(["kx", "--model", str(path), "--wrench", "0,0,-300", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["robot"] == "sk120" and out["frame"] == "fixture_target"
    assert out["compliant_joints"] == ["joint1", "joint2", "joint3"]
    assert np.allclose(out["K_theta"], result.k, rtol=1e-12)
    # the same numbers as giving the stiffnesses by hand
    kq = ",".join(repr(float(k)) for k in result.k)
    assert main(["kx", "--robot", "sk120", "--kq", kq, "--wrench", "0,0,-300", "--json"]) == 0
    by_hand = json.loads(capsys.readouterr().out)
    assert np.allclose(out["K_X"], by_hand["K_X"], rtol=1e-12)


def test_kx_flags_override_the_model(identified, capsys):
    _, path = identified
    assert main(["kx", "--model", str(path), "--kq", "1e6,2e6,3e6", "--wrench", "1,0,0",
                 "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["K_theta"] == [1e6, 2e6, 3e6]


def test_kx_without_robot_or_model_says_what_to_give(capsys):
    assert main(["kx", "--wrench", "1,2,3"]) == 2
    assert "--robot is required (or --model" in capsys.readouterr().err


def test_six_dimensional_principal_values_are_reported_per_block(capsys):
    """A 6-D load: principal stiffnesses per block in their own units (issue 30), equal to the
    inverse eigenvalues of the printed compliance's translational and rotational blocks."""
    cli = main
    argv = ["kx", "--robot", "ur5", "--kq", "3e5,3e5,2e5,4e4,4e4,4e4",
            "--q", "0,-1.2,1.5,-0.3,1.57,0", "--wrench", "0,0,-200,0,5,0"]
    assert cli([*argv, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    c = np.array(out["compliance"])
    assert out["basis"][:3] == ["vx", "vy", "vz"]
    blocks = out["principal_by_block"]
    for key, block, unit in (("translational", c[:3, :3], "N/m"),
                             ("rotational", c[3:, 3:], "N.m/rad")):
        expected = np.sort(1.0 / np.linalg.eigvalsh(0.5 * (block + block.T)))
        np.testing.assert_allclose(blocks[key]["values"], expected, rtol=1e-10)
        assert blocks[key]["unit"] == unit
    assert cli(argv) == 0
    text = capsys.readouterr().out
    assert "principal translational stiffnesses (N/m" in text
    assert "principal rotational stiffnesses (N.m/rad" in text


def test_kx_echoes_a_rigid_spring_as_rigid_not_as_its_file_value(ur5_rigid_wrist_model,
                                                                 capsys):
    """A UR5 campaign loading a wrist spring of 1e13 N.m/rad (rigid to 5 um noise,
    ``ur5_rigid_wrist_model``): its model file keeps where the fit stopped (1.78e5 N.m/rad,
    seed 1) with a 95 % interval open above. ``kx --model`` echoed ``wrist_1_joint=178275`` as
    a stiffness; it now says rigid (held, not determined) with the interval's lower end, and
    ``--json`` names it in ``K_theta_undetermined`` while ``K_theta_named`` keeps the file's
    value."""
    path = ur5_rigid_wrist_model
    doc = json.loads(path.read_text())
    k, low = doc["k_theta"]["values"][3], doc["k_theta"]["ci95"]["low"][3]
    assert doc["undetermined_joints"] == ["wrist_1_joint"]
    assert doc["k_theta"]["ci95"]["high"][3] is None
    args = ["kx", "--model", str(path), "--q", "0,-1.2,1.5,-0.3,1.57,0",
            "--wrench", "0,0,-100"]
    assert main(args) == 0
    echo = next(line for line in capsys.readouterr().out.splitlines()
                if line.startswith("K_theta ["))
    assert f"wrist_1_joint=rigid (held, not determined; stiffer than {low:.3g} at 95 %)" in echo
    assert f"{k:.6g}" not in echo and "elbow_joint=" in echo, echo
    assert main([*args, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert list(out["K_theta_undetermined"]) == ["wrist_1_joint"]
    assert out["K_theta_named"]["wrist_1_joint"] == pytest.approx(k, rel=1e-12)
