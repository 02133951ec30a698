"""The Python API equals the command line: for each workflow at the package top
(``stiffness.identify``, ``diagnose``, ``simulate``, ``design``, ``compensate``, ``posture``,
``scan``; ``diagnose`` of a pose campaign, ``simulate_poses`` and ``validate``), the result's
``.to_dict()`` is the JSON object the command prints with ``--json`` for the same inputs (the
command run through ``stiffness.cli.main.main``), and what the command writes, the result's
``.write()`` writes the same.

Inputs are tiny (a few rows, poses and candidates) so that the file runs in seconds.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import stiffness
from stiffness.cli.main import main
from stiffness.robot.sources import robots_directory

UR5_ARM = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"]
ARM_K = [3e4, 2e4, 1.5e4]  # N.m/rad
UR5_K = [3e5, 3e5, 2e5, 4e4, 4e4, 4e4]  # N.m/rad
TABLE2 = str(robots_directory() / "sk120" / "campaigns" / "table2")


def _command_json(capsys, argv: list[str]) -> dict:
    """The ``--json`` object the command prints (stdout holds nothing else)."""
    capsys.readouterr()
    assert main(argv + ["--json"]) == 0
    return json.loads(capsys.readouterr().out)


def _as_json(result) -> dict:
    """``result.to_dict()`` through JSON, as the command prints it (tuples become lists)."""
    return json.loads(json.dumps(result.to_dict(), allow_nan=False))


def _without_timing(doc):
    """``doc`` without wall-clock keys (``*_seconds``, ``elapsed_s``), which differ by run."""
    if isinstance(doc, dict):
        return {k: _without_timing(v) for k, v in doc.items()
                if not (k.endswith("_seconds") or k == "elapsed_s")}
    if isinstance(doc, list):
        return [_without_timing(v) for v in doc]
    return doc


@pytest.fixture(scope="module")
def campaign(tmp_path_factory) -> Path:
    """A tiny simulated UR5 campaign with a hidden backlash (its folder)."""
    folder = tmp_path_factory.mktemp("campaign") / "sim"
    sim = stiffness.simulate("ur5", kq=ARM_K, compliant_joints=UR5_ARM, configs=3,
                             loads_per_config=3, max_force=100.0, noise_std_m=5e-6, seed=2,
                             effects=["backlash:shoulder_lift_joint=0.01"])
    sim.write(folder)
    return folder


def test_simulate(tmp_path, capsys):
    argv = ["simulate", "--robot", "ur5", "--compliant-joints", ",".join(UR5_ARM), "--kq",
            ",".join(map(str, ARM_K)), "--effect", "backlash:shoulder_lift_joint=0.01",
            "--configs", "2", "--loads-per-config", "2", "--seed", "4"]
    printed = _command_json(capsys, argv + ["--out", str(tmp_path / "cli")])
    sim = stiffness.simulate("ur5", kq=ARM_K, compliant_joints=UR5_ARM, configs=2,
                             loads_per_config=2, noise_std_m=5e-6, seed=4,
                             effects=["backlash:shoulder_lift_joint=0.01"])
    assert _as_json(sim) == printed
    sim.write(tmp_path / "py")
    for name in ("measurements.csv", "truth.json"):
        assert (tmp_path / "py" / name).read_text() == (tmp_path / "cli" / name).read_text()


def test_simulate_poses(tmp_path, capsys):
    """``simulate --kind poses`` is ``stiffness.simulate_poses``: the same truth and files."""
    effects = ["joint_compliance:shoulder_lift_joint=2e5", "backlash:shoulder_lift_joint=0.01",
               "frame=1,2,3,100,0,0"]
    argv = ["simulate", "--kind", "poses", "--robot", "ur10", "--frame", "tool0", "--poses", "4",
            "--marker", "tip=tool0@0,30,50", "--load", "0,0,-100", "--noise", "0.02",
            "--seed", "5"] + [f"--effect={e}" for e in effects]
    printed = _command_json(capsys, argv + ["--out", str(tmp_path / "cli")])
    sim = stiffness.simulate_poses("ur10", [stiffness.Marker("tip", "tool0", np.array(
        [0.0, 0.03, 0.05]))], poses=4, effects=effects, noise_std_m=2e-5, seed=5,
        payload=[0.0, 0.0, -100.0], frame="tool0")
    assert _as_json(sim) == printed
    sim.write(tmp_path / "py")
    for name in ("campaign.toml", "measurements.csv", "truth.json"):
        assert (tmp_path / "py" / name).read_text() == (tmp_path / "cli" / name).read_text()


def test_identify(tmp_path, capsys):
    out = tmp_path / "identified-model.json"
    printed = _command_json(capsys, ["identify", TABLE2, "--starts", "2", "--out", str(out)])
    written = out.read_text()
    result = stiffness.identify(TABLE2, starts=2)
    assert result.to_dict()["model_file"] is None  # nothing written yet
    assert result.write_model(out) == out
    assert _as_json(result) == printed
    assert out.read_text() == written


def test_diagnose(tmp_path, capsys, campaign):
    argv = ["diagnose", str(campaign), "--max-steps", "1", "--no-proposals", "--workers", "1"]
    printed = _command_json(capsys, argv + ["--out", str(tmp_path / "cli")])
    result = stiffness.diagnose(campaign, max_steps=1, propose=False, workers=1)
    assert _as_json(result) == printed
    assert printed["steps"], "the hidden backlash is found (else the test compares little)"
    result.write(tmp_path / "py")
    for name in ("final-model.json",):
        assert (json.loads((tmp_path / "py" / name).read_text())
                == json.loads((tmp_path / "cli" / name).read_text()))
    assert (_without_timing(json.loads((tmp_path / "py" / "diagnosis.json").read_text()))
            == _without_timing(json.loads((tmp_path / "cli" / "diagnosis.json").read_text())))


def test_design(tmp_path, capsys):
    out = tmp_path / "plan"
    argv = ["design", "--robot", "ur5", "--compliant-joints", ",".join(UR5_ARM), "--kq",
            ",".join(map(str, ARM_K)), "--configs", "2", "--loads-per-config", "2",
            "--max-force", "100", "--candidates", "12", "--random-plans", "3", "--out",
            str(out)]
    printed = _command_json(capsys, argv)
    written = (out / "plan.csv").read_text()
    robot = stiffness.load_robot("ur5", compliant_joints=UR5_ARM)
    result = stiffness.design(robot, 2, 100.0, loads_per_config=2, candidates=12,
                              random_plans=3, k=ARM_K, k_source="--kq")
    assert result.write(out) == out / "plan.csv"
    assert _as_json(result) == printed
    assert (out / "plan.csv").read_text() == written


def test_compensate(tmp_path, capsys):
    path = np.array([[0.1, -1.2, 1.5, -0.3, 1.57, 0.2], [0.2, -1.1, 1.4, -0.3, 1.57, 0.2]])
    csv = tmp_path / "path.csv"
    csv.write_text("q1,q2,q3,q4,q5,q6\n" + "".join(
        ",".join(repr(v) for v in row) + "\n" for row in path.tolist()))
    argv = ["compensate", "--robot", "ur5", "--kq", ",".join(map(str, UR5_K)), "--path",
            str(csv), "--wrench", "0,0,-300", "--out", str(tmp_path / "cli.csv")]
    printed = _command_json(capsys, argv)
    model = stiffness.ElasticModel.joint_springs(stiffness.load_robot("ur5"), UR5_K)
    result = stiffness.compensate(model, path, wrench=[0.0, 0.0, -300.0])
    assert _as_json(result) == printed
    from_file = stiffness.compensate(model, csv, wrench=[0.0, 0.0, -300.0])
    from_file.write(tmp_path / "py.csv")
    assert (tmp_path / "py.csv").read_text() == (tmp_path / "cli.csv").read_text()


def test_posture(tmp_path, capsys):
    poses = tmp_path / "poses.csv"
    poses.write_text("x,y,z,ax,ay,az\n0.45,-0.1,0.3,0,0,-1\n0.45,0.0,0.3,0,0,-1\n")
    start = [0.0, -1.57, 1.57, -1.57, -1.57, 0.0]
    argv = ["posture", "--robot", "ur5", "--frame", "tool0", "--target-offset", "0.1,0,0.1",
            "--kq", ",".join(map(str, UR5_K)), "--path", str(poses), "--wrench", "0,0,300",
            "--steps", "6", "--max-step", "40", "--no-refine", "--start",
            ",".join(map(str, start)), "--out", str(tmp_path / "cli.csv")]
    printed = _command_json(capsys, argv)
    tool = stiffness.load_robot("ur5", frame="tool0", target_offset=[0.1, 0.0, 0.1])
    result = stiffness.posture(tool, poses, wrench=[0.0, 0.0, 300.0], k_theta=UR5_K,
                               steps=6, max_step_deg=40.0, refine=False, start=start)
    assert _as_json(result) == printed
    result.write(tmp_path / "py.csv")
    assert (tmp_path / "py.csv").read_text() == (tmp_path / "cli.csv").read_text()
    arrays = stiffness.posture(tool, result.poses.positions, axes=result.poses.axes,
                               wrench=[0.0, 0.0, 300.0], k_theta=UR5_K, steps=6,
                               max_step_deg=40.0, refine=False, start=start)
    assert _as_json(arrays) == printed


def test_scan(tmp_path, capsys):
    argv = ["scan", "--robot", "ur5", "--kq", ",".join(map(str, UR5_K)), "--axis",
            "shoulder_lift_joint=-1:0:0.5", "--axis", "elbow_joint=0:1:0.5", "--wrench",
            "0,0,-200", "--no-plots", "--out", str(tmp_path / "cli")]
    printed = _command_json(capsys, argv)
    result = stiffness.scan("ur5", tmp_path / "py", k_theta=UR5_K, plots=False,
                            axes={"shoulder_lift_joint": (-1.0, 0.0, 0.5),
                                  "elbow_joint": (0.0, 1.0, 0.5)}, wrench=[0.0, 0.0, -200.0])
    doc = _as_json(result)
    assert doc["out"] == str(tmp_path / "py") and printed["out"] == str(tmp_path / "cli")
    assert set(doc) == set(printed)
    assert _without_timing({**doc, "out": None}) == _without_timing({**printed, "out": None})
    assert (json.loads((tmp_path / "py" / "manifest.json").read_text())["spec"]
            == json.loads((tmp_path / "cli" / "manifest.json").read_text())["spec"])


def test_scan_of_a_model_file(tmp_path, capsys):
    model = stiffness.identify(TABLE2, starts=1).write_model(tmp_path / "m.json")
    argv = ["scan", "--model", str(model), "--axis", "q2=-0.5:0.5:0.5", "--axis",
            "q3=-0.5:0:0.5", "--no-plots", "--out", str(tmp_path / "cli")]
    printed = _command_json(capsys, argv)
    result = stiffness.scan(model=model, out=tmp_path / "py", plots=False,
                            axes={"q2": (-0.5, 0.5, 0.5), "q3": (-0.5, 0.0, 0.5)})
    doc = _as_json(result)
    assert _without_timing({**doc, "out": None}) == _without_timing({**printed, "out": None})
    assert (json.loads((tmp_path / "py" / "manifest.json").read_text())["spec"]
            == json.loads((tmp_path / "cli" / "manifest.json").read_text())["spec"])


@pytest.fixture(scope="module")
def pose_campaigns(tmp_path_factory) -> tuple[Path, Path]:
    """Two small simulated UR10 pose campaigns (one tracker marker, hidden zero offsets and
    a tracker placement): one to diagnose, one to validate on."""
    robot = stiffness.load_robot("ur10", frame="tool0")
    markers = [stiffness.Marker("tip", "tool0", np.array([0.0, 0.03, 0.05]))]
    hidden = stiffness.HiddenPoseErrors(np.eye(3), np.array([1.5, -0.5, 0.2]),
                                        np.array([[0.0, 0.031, 0.05]]),
                                        np.linspace(-1e-3, 1e-3, 6), np.zeros((6, 6)),
                                        np.full(6, 1e5))
    folders = []
    for seed in (1, 2):
        c = stiffness.simulate_pose_campaign(robot, markers, hidden, 15, 2e-5, seed=seed)
        folders.append(stiffness.write_pose_campaign(
            c, tmp_path_factory.mktemp("poses") / f"c{seed}").parent)
    return folders[0], folders[1]


def test_diagnose_of_a_pose_campaign(tmp_path, capsys, pose_campaigns):
    fit, other = pose_campaigns
    printed = _command_json(capsys, ["diagnose", str(fit), "--validate", str(other)])
    result = stiffness.diagnose(fit, validate=other)
    assert _as_json(result) == printed
    assert len(printed["steps"]) > 1, "families are added (else the test compares little)"
    direct = stiffness.diagnose_poses(stiffness.load_pose_campaign(fit),
                                      validate=stiffness.load_pose_campaign(other))
    assert _as_json(direct) == printed


def test_validate(tmp_path, capsys, pose_campaigns, campaign):
    fit, other = pose_campaigns
    assert main(["diagnose", str(fit), "--out", str(tmp_path / "D"), "--quiet"]) == 0
    model = tmp_path / "D" / "final-model.json"
    printed = _command_json(capsys, ["validate", str(model), str(other)])
    assert _as_json(stiffness.validate(model, other)) == printed
    assert printed["markers"]["tip"]["rows"] == 15
    # a pose calibration is evaluated on a deflection campaign of its robot
    # (tests/test_validate_pose_on_deflections.py); this one is a UR5's
    with pytest.raises(stiffness.ModelRobotError, match="not of the model's 'ur10'"):
        stiffness.validate(model, campaign)
    _check_pose_covariance(model, other)


def _check_pose_covariance(model: Path, other: Path) -> None:
    """The pose model file's ``parameter_covariance``: its fitted parameters in the table's
    order, their standard deviations the table's; ``validate`` carries it to the other
    campaign's positions, ``J Sigma J^T`` equal to that of central differences of the
    prediction to 2e-3 of the largest entry (``evaluate``'s Jacobian, the fit's, holds the
    joint torques fixed, exact at zero compliance: 5e-4 measured with this fit's springs)."""
    from stiffness.calibration.pose_model_file import read_pose_model
    from stiffness.calibration.pose_register import validation_jacobian

    doc = json.loads(model.read_text())
    fitted = [p for p in doc["parameters"] if p["fitted"]]
    cov = doc["parameter_covariance"]
    assert cov["labels"] == [p["parameter"] for p in fitted]
    assert cov["units"] == [p["unit"] for p in fitted]
    np.testing.assert_allclose(np.sqrt(np.diag(cov["matrix"])), [p["std"] for p in fitted],
                               rtol=1e-12)
    poses = stiffness.load_pose_campaign(other)
    result = stiffness.validate(model, poses)
    calibration = read_pose_model(model, poses.robot)
    labels = [p.label for p in calibration.model.parameters]
    columns = [labels.index(label) for label in cov["labels"]]
    fd = []
    for i in columns:
        h = 1e-6 * max(1.0, abs(calibration.x[i]))
        sides = [validation_jacobian(calibration.model, calibration.x + s * h * np.eye(
            len(labels))[i], poses)[0] for s in (1, -1)]
        fd.append(-(sides[0] - sides[1]).reshape(-1) / (2 * h))
    fd = np.array(fd).T / poses.units.length_to_si
    expected = fd @ np.array(cov["matrix"]) @ fd.T
    term = result.parameters
    assert term is not None and term.labels == tuple(cov["labels"])
    np.testing.assert_allclose(term.jacobian @ term.covariance @ term.jacobian.T, expected, rtol=0,
                               atol=2e-3 * np.abs(expected).max())
    assert result.to_dict()["verdict_test"] == "noise and the model's parameter uncertainty"


def test_validate_takes_a_model_and_campaigns_loaded(tmp_path, capsys, pose_campaigns,
                                                     campaign):
    """``stiffness.validate`` takes what the other workflows take (the README: a campaign or
    its path): a ModelFile read and a Campaign or PoseCampaign loaded give the command's
    object; it raised TypeError ('expected str, bytes or os.PathLike object, not ModelFile')."""
    model = tmp_path / "m.json"
    stiffness.identify(campaign).write_model(model)
    printed = _command_json(capsys, ["validate", str(model), str(campaign)])
    from stiffness.elastic.model_file import read_model_file

    read = read_model_file(model)
    result = _as_json(stiffness.validate(read, stiffness.load_campaign(campaign)))
    assert result.pop("campaign") == str(campaign / "campaign.toml")  # the loaded one's file
    assert result == {k: v for k, v in printed.items() if k != "campaign"}
    fit, other = pose_campaigns
    assert main(["diagnose", str(fit), "--out", str(tmp_path / "D"), "--quiet"]) == 0
    pose_model = tmp_path / "D" / "final-model.json"
    printed = _command_json(capsys, ["validate", str(pose_model), str(other)])
    loaded = _as_json(stiffness.validate(pose_model, stiffness.load_pose_campaign(other)))
    loaded.pop("campaign"), printed.pop("campaign")
    assert loaded == printed
    with pytest.raises(stiffness.StiffnessError, match="deflection model"):
        stiffness.validate(read, stiffness.load_pose_campaign(other))
