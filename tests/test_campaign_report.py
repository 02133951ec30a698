"""One report for any campaign (issue 38 item 9): ``stiffness report CAMPAIGN --out DIR`` writes
diagnose's page for a deflection and for a pose campaign, with the steps, the residual figures
per axis and per marker, the parameters with intervals, the named effects and the validation.

Small simulated campaigns (a few seconds in all)."""

from __future__ import annotations

import base64
import html
import json
import re

import numpy as np
import pinocchio as pin
import pytest

from stiffness.calibration.pose_campaign import write_pose_campaign
from stiffness.cli.main import main
from stiffness.planning.simulate import parse_effect, simulate
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.robot import load_robot

NOISE = 2e-5  # m
PAYLOAD = np.array([0.0, 0.0, -150.0, 0.0, 0.0, 0.0])  # N, N.m at tool0


def _visible(page: str) -> str:
    return html.unescape(re.sub(r"<(script|style)[^>]*>.*?</\1>|<[^>]+>", " ", page, flags=re.S))


def _figures(page: str) -> dict[str, bytes]:
    """The embedded PNGs by their figure id."""
    return {m.group(1): base64.b64decode(m.group(2)) for m in re.finditer(
        r"<figure id='([^']+)'><img alt='[^']*' src='data:image/png;base64,([^']+)'>", page)}


def _pose_campaigns(tmp_path) -> tuple:
    """Two pose campaigns of the same UR10 (two markers, hidden joint offsets and a sagging
    arm): the one fitted and the one it is validated on."""
    robot = load_robot("ur10", frame="tool0")
    markers_ = [("tip", "tool0", [0.0, 0.03, 0.05]), ("elbow", "forearm_link", [0.0, 0.05, 0.2])]
    from stiffness.calibration.pose_model import Marker

    markers = [Marker(n, f, np.array(o)) for n, f, o in markers_]
    rng = np.random.default_rng(3)
    hidden = HiddenPoseErrors(
        frame_rotation=pin.exp3(rng.normal(size=3)), frame_translation=rng.uniform(-2, 2, 3),
        marker_offsets=np.array([m.offset for m in markers]) + rng.normal(0, 2e-3, (2, 3)),
        joint_offsets=rng.normal(0.0, 1e-3, 6), placement_errors=np.zeros((6, 6)),
        stiffness=np.array([3e5, 2e5, 1.2e5, 4e4, 3e4, 3e4]), drift=np.zeros(3))
    folders = []
    for name, seed in (("fit", 3), ("held", 4)):
        c = simulate_pose_campaign(robot, markers, hidden, 16, NOISE, seed=seed, payload=PAYLOAD)
        write_pose_campaign(c, tmp_path / name)
        folders.append(tmp_path / name)
    return folders


def test_report_of_a_pose_campaign(tmp_path, capsys):
    """Steps, residual figures per marker (x, y, z before and after), how sure, the stage table,
    the validation per marker and the parameters with intervals; the folder written whole."""
    fit, held = _pose_campaigns(tmp_path)
    out = tmp_path / "rep"
    assert main(["report", str(fit), "--out", str(out), "--validate", str(held),
                 "--masses", "known", "--quiet"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fit", "held", "rep"]  # no staging
    assert sorted(p.name for p in out.iterdir()) == ["diagnosis.html", "diagnosis.json",
                                                     "final-model.json"]
    record = json.loads((out / "diagnosis.json").read_text())
    page = (out / "diagnosis.html").read_text()
    for anchor in ("steps", "residuals", "how-sure", "stages", "validation", "parameters",
                   "identifiability", "reproduce"):
        assert f"id='{anchor}'" in page, anchor
    assert record["robot_name"] == "ur10" and "<title>Pose diagnosis of campaign " in page
    assert "(ur10)</title>" in page  # the robot named in the title
    assert load_robot(str(out / "final-model.json")).title == "ur10"  # not 'final-model'
    figures = _figures(page)
    assert {"residuals-tip.png", "residuals-elbow.png", "stages.png"} <= set(figures)
    assert all(png.startswith(b"\x89PNG") for png in figures.values())
    visible = _visible(page)
    final = record["steps"][-1]
    assert "joint_offsets" in record["families"], record["families"]
    v = final["validation"]
    for name in ("tip", "elbow"):  # the validation table names each marker with its RMS
        assert re.search(rf"\b{name}\s+\d+\s+{v['markers'][name]['rms']:.4g}\b", visible), name
    for axis, rms in record["residual_structure"]["rms_by_axis"].items():
        assert re.search(rf"axis {axis}\s+{rms:.4g}\b", visible), axis
    if "how_sure" not in record:  # the evidence when each family was added
        step = next(i for i, s in enumerate(record["steps"]) if s["family"] == "joint_offsets")
        gain = record["steps"][step - 1]["cv_rms"] - record["steps"][step]["cv_rms"]
        dbic = record["steps"][step]["delta_bic"]
        assert re.search(rf"joint_offsets\s+{dbic:.4g}\s+{gain:.4g}\b", visible)
    p = next(p for p in record["parameters"] if p["fitted"] and p["family"] == "joint_offsets")
    lo, hi = p["interval_95"]
    assert f"[{lo:.4g}, {hi:.4g}]" in visible
    said = capsys.readouterr().out
    assert "written: " in said and "diagnosis.html" in said


def test_report_of_a_deflection_campaign(tmp_path, capsys):
    """The steps with their held-out RMS, the residual figure (x, y, z before and after),
    the parameters with intervals and the validation on another campaign (the same numbers as
    ``stiffness validate`` of the written final-model.json); the same page as diagnose --out."""
    campaigns = []
    for seed in (2, 3):
        sim = simulate("ur5", kq=[3e4, 2e4, 1.5e4],
                       effects=[parse_effect("force_sensor_bias=8")], configs=5,
                       loads_per_config=3, noise_std_m=1e-5, seed=seed,
                       compliant_joints=["shoulder_pan_joint", "shoulder_lift_joint",
                                         "elbow_joint"])
        campaigns.append(sim.write(tmp_path / f"c{seed}"))
    campaign, other = campaigns
    out = tmp_path / "rep"
    assert main(["report", str(campaign), "--out", str(out), "--validate", str(other),
                 "--quiet"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["diagnosis.html", "diagnosis.json",
                                                     "final-model.json", "residuals.png"]
    page = (out / "diagnosis.html").read_text()
    record = json.loads((out / "diagnosis.json").read_text())
    for anchor in ("residuals", "steps", "parameters", "ambiguities"):
        assert f"id='{anchor}'" in page, anchor
    assert _figures(page)["residuals.png"] == (out / "residuals.png").read_bytes()
    assert record["robot_name"] == "ur5" and "(ur5)</title>" in page
    assert json.loads((out / "final-model.json").read_text())["robot"]["name"] == "ur5"
    visible = _visible(page)
    assert "held-out RMS" in visible
    assert [s["effect"] for s in record["steps"]] == ["force_sensor_bias"]
    assert f"{record['cv_rms']['steps'][0]:.4g}" in visible
    fx = record["steps"][0]["parameters"]["fx"]
    assert f"[{fx['ci95'][0]:.4g}, {fx['ci95'][1]:.4g}]" in visible
    (sure,) = record["how_sure"]  # how sure the named effect is, on the page
    assert re.search(rf"{sure['effect']}\s+{sure['removal_delta_bic']:.4g}\s+"
                     rf"{sure['held_out_cost']:.4g}\b", visible)
    assert "written: " in capsys.readouterr().out
    assert main(["validate", str(out / "final-model.json"), str(other), "--json"]) == 0
    val = json.loads(capsys.readouterr().out)
    v = record["validation"]
    assert v["rms"] == pytest.approx(val["rms"], rel=1e-9) and v["verdict"] == val["verdict"]
    assert "id='validation'" in page
    assert re.search(rf"target\s+{v['rows']}\s+{v['rms']:.4g}\b", visible)
    assert re.search(rf"verdict:\s+{v['verdict'].upper()} \(RMS", visible)  # the text's sentence


@pytest.mark.parametrize(("argv", "said"), [
    (["report", "CAMPAIGN"], "needs --out DIR"),
    (["report", "CAMPAIGN", "--out", "d", "--campaign", "x"], "--campaign picks the SK120"),
    (["report", "--validate", "x", "--out", "d"], "--validate take(s) a campaign"),
    (["report", "CAMPAIGN", "--out", "d", "--masses", "some"], "--masses 'some': give one of"),
])
def test_report_flags_refused_in_one_line(argv, said, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert said in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "d").exists()


def test_report_strict_refuses_unknown_columns(tmp_path, monkeypatch, capsys):
    """``report CAMPAIGN --strict`` (and ``design --existing CAMPAIGN --strict``) refuse a rig's
    bookkeeping column as diagnose --strict does (issue 38 item 1), before any work."""
    import shutil

    from stiffness.robot.sources import robots_directory

    shutil.copytree(robots_directory() / "sk120" / "campaigns" / "table2", tmp_path / "c")
    data = tmp_path / "c" / "measurements.csv"
    lines = data.read_text().splitlines()
    data.write_text("\n".join([lines[0] + ",operator"] + [s + ",bob" for s in lines[1:]]) + "\n")
    monkeypatch.chdir(tmp_path)
    for argv in (["report", "c", "--out", "d", "--strict"],  # design's --existing too
                 ["design", "--existing", "c", "--max-force", "200", "--configs", "2", "--out",
                  "d", "--strict"]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert "operator" in err and "--strict" in err and len(err.strip().splitlines()) == 1
        assert not (tmp_path / "d").exists()
