"""Paths that travel (issue 38.3): every path written into a campaign or a model file is
relative to that file, so the files work from any working directory and after their folder
moves (both campaign kinds, the deflection and the pose model files)."""

from __future__ import annotations

import shutil

import numpy as np
import pinocchio as pin

from stiffness.calibration.campaign import load_campaign
from stiffness.calibration.pose_campaign import load_pose_campaign, write_pose_campaign
from stiffness.calibration.pose_fit import fit_pose_model, rows_of, starting_frame
from stiffness.calibration.pose_model import Marker, PoseModel
from stiffness.calibration.pose_model_file import read_pose_model, write_pose_model
from stiffness.cli.main import main
from stiffness.elastic.model_file import read_model_file
from stiffness.files import read_toml
from stiffness.robot.robot import load_robot
from stiffness.robot.sources import robots_directory

ROBOT = "two-arm-torso"


def _rig_file(path, robot, rows: int = 6) -> None:
    """A tracker's CSV: 16 coordinates and the right hand's position (the nominal robot's)."""
    rng = np.random.default_rng(0)
    tip = robot.model.getFrameId("right_tcp")
    lines = [",".join([f"q{i + 1}" for i in range(robot.n_coordinates)]
                      + ["tip_x", "tip_y", "tip_z"])]
    for _ in range(rows):
        q = rng.uniform(-0.5, 0.5, robot.n_coordinates)
        pin.framesForwardKinematics(robot.model, robot.data, robot.configuration(q))
        lines.append(",".join(repr(float(v)) for v in [*q, *robot.data.oMf[tip].translation]))
    path.write_text("\n".join(lines) + "\n")


def test_pose_campaign_and_model_travel(tmp_path, monkeypatch, capsys):
    """campaign import --kind poses --robot rel/robot.toml --out deep/dir: the campaign names
    the robot relative to itself; write_pose_campaign elsewhere rebases it; the pose model
    file's robot is found from another directory and after the folder moved."""
    project = tmp_path / "project"
    shutil.copytree(robots_directory() / ROBOT, project / "rel")
    robot = load_robot(str(project / "rel" / "robot.toml"))
    _rig_file(project / "rig.csv", robot)
    monkeypatch.chdir(project)
    assert main(["campaign", "import", "rig.csv", "--kind", "poses", "--robot",
                 "rel/robot.toml", "--marker", "tip=right_tcp", "--units", "angle=rad,length=m",
                 "--out", "deep/dir"]) == 0
    written = read_toml(project / "deep" / "dir" / "campaign.toml")
    assert written["robot"]["source"] == "../../rel/robot.toml"
    monkeypatch.chdir(tmp_path)  # another working directory: diagnose finds the robot
    campaign = load_pose_campaign(project / "deep" / "dir")
    write_pose_campaign(campaign, project / "copies" / "c")
    fams = ["frame", "markers"]
    model = PoseModel(campaign.robot, [Marker("tip", "right_tcp")], tuple(fams),
                      starting_frame(campaign))
    fit = fit_pose_model(model, campaign, rows_of(model, campaign), fams)
    write_pose_model(fit, campaign, project / "out" / "final-model.json")
    moved = shutil.move(str(project), str(tmp_path / "moved"))
    monkeypatch.chdir(moved + "/deep")
    for folder in ("deep/dir", "copies/c"):
        assert load_pose_campaign(f"{moved}/{folder}").robot.n_coordinates == 16
    model_file = f"{moved}/out/final-model.json"
    assert read_pose_model(model_file).robot.name == f"{moved}/rel/robot.toml"
    assert read_model_file(model_file).robot().n_coordinates == 16
    assert main(["robot", "export", "--model", model_file, "--urdf", "calibrated.urdf",
                 "--quiet"]) == 0
    capsys.readouterr()


def test_deflection_campaign_and_model_travel(tmp_path, monkeypatch, capsys):
    """simulate --robot rel/robot.toml and identify --out, then the folder moves: the campaign
    and the model file still name their robot."""
    project = tmp_path / "project"
    shutil.copytree(robots_directory() / ROBOT, project / "rel")
    monkeypatch.chdir(project)
    assert main(["simulate", "--robot", "rel/robot.toml", "--configs", "4", "--out",
                 "deep/campaign", "--quiet"]) == 0
    assert main(["identify", "deep/campaign", "--out", "deep/models/identified-model.json",
                 "--quiet"]) == 0
    moved = shutil.move(str(project), str(tmp_path / "moved"))
    monkeypatch.chdir(tmp_path)
    assert load_campaign(f"{moved}/deep/campaign").robot().n_coordinates == 16
    assert read_model_file(f"{moved}/deep/models/identified-model.json").robot(
        ).n_coordinates == 16
    capsys.readouterr()
