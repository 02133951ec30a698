"""``stiffness simulate --kind poses``: the command writes the pose campaign the Python API
simulates (``simulate_pose_campaign`` of a truth built here by hand, the same seed), its effect
sizes are the closed forms of rigid displacements, ``diagnose`` names the joint spring it hides,
and the flags of the other campaign kind, unknown effects and bad places are refused with one
line (exit 2, nothing written)."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pinocchio as pin
import pytest
from conftest import _joint, _robot_xml

from stiffness.calibration.pose_campaign import load_pose_campaign
from stiffness.calibration.pose_model import Marker
from stiffness.cli.main import main
from stiffness.errors import FlagValueWarning
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.robot import load_robot

BASE = ["simulate", "--kind", "poses", "--robot", "ur10", "--frame", "tool0"]


def _run(capsys, argv: list[str]) -> tuple[int, str, str]:
    capsys.readouterr()
    code = main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_the_command_writes_the_python_apis_campaign(tmp_path, capsys):
    """Every kind of hidden effect through the flags (mm, deg), against a truth built by hand
    in SI and ``simulate_pose_campaign`` with the same seed: the same poses, the same marker
    positions and orientations (to the CSV's digits), the same declared markers."""
    out = tmp_path / "sim"
    code, _, err = _run(capsys, BASE + [
        "--poses", "8", "--seed", "3", "--units", "mm", "--noise", "0.02", "--rotations",
        "--rotation-noise", "0.01", "--marker", "tip=tool0@0,30,50@10,0,0",
        "--marker", "elbow=forearm_link@0,50,200", "--load", "0,0,-150",
        "--effect", "frame=5,-10,60,2000,-1000,300", "--effect", "markers:tip=1,-1,0.5",
        "--effect", "joint_offsets:elbow_joint=0.05",
        "--effect", "geometry:wrist_1_joint=0.4,0,-0.2",
        "--effect", "base_tilt=0.5,-0.3", "--effect", "joint_compliance:shoulder_lift_joint=2e5",
        "--effect", "joint_compliance:elbow_joint=1e5", "--effect", "backlash:elbow_joint=0.01",
        "--effect", "link_compliance:elbow_joint->wrist_1_joint=5e6",
        "--effect", "nonlinear_joint_stiffness:elbow_joint=0.001", "--drift", "0.01,0,0",
        "--out", str(out)])
    assert code == 0, err
    deg, mm = np.pi / 180, 1e-3
    robot = load_robot("ur10", frame="tool0")
    markers = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05]),
                      pin.exp3(np.array([10 * deg, 0, 0]))),
               Marker("elbow", "forearm_link", np.array([0.0, 0.05, 0.2]))]
    offsets, placement = np.zeros(6), np.zeros((6, 6))
    offsets[2] = 0.05 * deg
    placement[3, :3] = [0.4 * mm, 0.0, -0.2 * mm]
    k = np.full(6, np.inf)
    k[1], k[2] = 2e5, 1e5
    hidden = HiddenPoseErrors(
        pin.exp3(np.array([5, -10, 60]) * deg), np.array([2.0, -1.0, 0.3]),
        np.array([[1 * mm, 0.03 - 1 * mm, 0.05 + 0.5 * mm], [0.0, 0.05, 0.2]]), offsets,
        placement, stiffness=k, drift=np.array([1e-5, 0, 0]),
        link_compliance={"elbow_joint->wrist_1_joint": np.full(2, 2e-7)},
        backlash=np.array([0, 0, 0.01 * deg, 0, 0, 0]), base_tilt=np.array([0.5, -0.3]) * deg,
        nonlinear=np.array([0, 0, 1e-3, 0, 0, 0]))
    expected = simulate_pose_campaign(robot, markers, hidden, 8, 2e-5, seed=3,
                                      payload=np.array([0, 0, -150.0, 0, 0, 0]),
                                      rotation_noise_std=0.01 * deg)
    written = load_pose_campaign(out)
    assert written.units.length == "mm" and written.units.angle == "deg"
    np.testing.assert_allclose(written.q, expected.q, rtol=0, atol=1e-12)
    np.testing.assert_allclose(written.positions, expected.positions, rtol=0, atol=1e-12)
    np.testing.assert_allclose(written.rotations, expected.rotations, rtol=0, atol=1e-12)
    assert written.noise_std == pytest.approx(2e-5)
    assert written.noise_std_rotation == pytest.approx(0.01 * deg)
    for m, e in zip(written.markers, markers, strict=True):
        assert (m.name, m.frame) == (e.name, e.frame)
        np.testing.assert_allclose(m.offset, e.offset, atol=1e-15)
        np.testing.assert_allclose(m.rotation, e.rotation, atol=1e-12)
    truth = json.loads((out / "truth.json").read_text())
    assert truth["k_theta_SI"] == [None, 2e5, 1e5, None, None, None]
    assert truth["expected_missing_effects"] == [
        "frame", "markers", "joint_offsets", "geometry", "base_tilt", "joint_compliance",
        "backlash", "link_compliance", "nonlinear_joint_stiffness"]


def test_effect_sizes_are_the_rigid_displacements(tmp_path, capsys):
    """A measuring frame moved by t and a marker offset moved by d (its frame's axes) move
    every marker by |t| and |d|: RMS over the components |t| / sqrt(3) and |d| / sqrt(3)
    (rotations keep lengths), whatever the poses; a rigid arm has no spring."""
    code, printed, err = _run(capsys, BASE + [
        "--poses", "5", "--effect", "frame=0,0,0,3,4,12", "--effect", "markers=-2,6,3",
        "--noise", "0.01", "--json", "--out", str(tmp_path / "sim")])
    assert code == 0, err
    truth = json.loads(printed)
    assert truth["effect_rms"]["frame"] == pytest.approx(13 / np.sqrt(3), rel=1e-12)
    assert truth["effect_rms"]["markers"] == pytest.approx(7 / np.sqrt(3), rel=1e-12)
    assert truth["effect_rms_noise_units"]["markers"] == pytest.approx(700 / np.sqrt(3),
                                                                         rel=1e-12)
    assert truth["k_theta_SI"] is None and truth["hidden"]["backlash"] is None
    assert {"format", "kind", "robot", "compliant_joints", "k_theta_SI", "markers",
            "hidden_effects", "expected_missing_effects", "effect_rms", "effect_rms_noise_units",
            "effect_rms_beyond_frame", "noise_std", "unit", "value_units", "hidden", "settings",
            "model"} == set(truth)
    # a frame move is rigid: nothing of it is left once the measuring frame is fitted
    assert truth["effect_rms_beyond_frame"]["frame"] < 1e-9
    assert truth["kind"] == "poses" and truth["unit"] == "mm"
    assert truth["settings"]["poses"] == 5 and truth["markers"][0]["frame"] == "tool0"


def test_springs_no_payload_loads_on_a_weightless_robot_are_warned(tmp_path, capsys):
    """The SK120's robot file has no link masses: its springs hidden without ``--load`` move
    no marker (0 mm RMS), which one warning line traces to the missing payload; with one they
    move the markers and nothing is warned."""
    argv = ["simulate", "--kind", "poses", "--robot", "sk120", "--poses", "3", "--kq",
            "1.4e6,4e5,9.4e5"]
    with pytest.warns(FlagValueWarning) as record:
        code, out, err = _run(capsys, argv + ["--out", str(tmp_path / "free")])
    assert code == 0, err
    assert "hidden joint_compliance: moves the markers by 0 mm RMS" in out, out
    assert [str(w.message).split(":")[0] for w in record] == ["hidden joint_compliance moves no "
                                                              "marker"]
    assert "sk120 weighs nothing" in str(record[0].message)
    assert "--load FX,FY,FZ" in str(record[0].message)
    with warnings.catch_warnings():
        warnings.simplefilter("error", FlagValueWarning)
        code, out, err = _run(capsys, argv + ["--load", "0,0,-2000", "--out",
                                              str(tmp_path / "held")])
    assert code == 0, err
    assert "hidden joint_compliance: moves the markers by 0 mm" not in out, out


def test_diagnose_names_the_hidden_joint_spring(tmp_path, capsys):
    """A spring of 2e4 N.m/rad hidden on the UR10's shoulder lift (20 poses, 100 N, 20 µm):
    ``diagnose`` of the written campaign adds joint_compliance, and that joint's compliance
    interval holds 1 / 2e4 rad/(N.m)."""
    out = tmp_path / "sim"
    code, printed, err = _run(capsys, BASE + [
        "--poses", "20", "--marker", "tip=tool0@0,30,50", "--load", "0,0,-100", "--noise",
        "0.02", "--effect", "joint_compliance:shoulder_lift_joint=2e4", "--out", str(out)])
    assert code == 0, err
    assert "hidden joint_compliance(shoulder_lift_joint): moves the markers by" in printed
    code, printed, err = _run(capsys, ["diagnose", str(out), "--json"])
    assert code == 0, err
    diagnosis = json.loads(printed)
    assert "joint_compliance" in diagnosis["families"]
    (row,) = [p for p in diagnosis["parameters"]
              if p["parameter"] == "shoulder_lift_joint compliance"]
    low, high = row["ci95"]
    assert low <= 1 / 2e4 <= high


@pytest.mark.parametrize(("flags", "says"), [
    (["--kind", "poses", "--configs", "5"], "--configs is for --kind deflections"),
    (["--kind", "poses", "--plan", "plan.csv"], "design plans deflection campaigns only"),
    (["--kind", "poses", "--max-force", "50", "--baseline", "enhanced"],
     "--max-force, --baseline are for --kind deflections"),
    (["--poses", "5"], "--poses is for --kind poses, not deflections: drop it or add --kind"),
    (["--marker", "tip=tool0", "--wrench", "0,0,-10"], "--marker, --load are for --kind poses"),
    (["--kind", "poses", "--effect", "target_offset=3"], "no effect a pose campaign hides"),
    (["--kind", "poses", "--effect", "gravity_lumped"], "valid names: frame, markers"),
    (["--kind", "poses", "--effect", "backlash=0.1"], "backlash needs a place"),
    (["--kind", "poses", "--effect", "base_tilt:elbow_joint=1,2"], "acts on the whole"),
    (["--kind", "poses", "--effect", "frame=1,2"], "frame takes 3 or 6 value(s), got 2"),
    (["--kind", "poses", "--effect", "joint_compliance:nope=1e4"],
     "'nope' is not a compliant joint of"),
    (["--kind", "poses", "--effect", "markers:nose=1,2,3"], "'nose' is not a marker"),
    (["--kind", "poses", "--effect", "nonlinear_joint_stiffness:elbow_joint=0.001"],
     "acts through elbow_joint's spring"),
    (["--kind", "poses", "--kq", "1e5,1e5,1e5,1e5,1e5,1e5", "--effect",
      "joint_compliance:elbow_joint=1e4"], "either by --kq"),
    (["--kind", "poses", "--effect", "joint_compliance:elbow_joint=-1e4"], "positive values"),
    (["--kind", "poses", "--rotation-noise", "0.01"], "add --rotations"),
    (["--rotation-noise", "0.01"], "add --rotations"),  # a deflection campaign's too
    (["--kind", "poses", "--drift", "1,2"], "--drift takes three lengths"),
    (["--effect", "frame=1,2,3"], "(frame is a pose campaign's: --kind poses)"),
    (["--kind", "poses", "--marker", "tip=nowhere"], "frame 'nowhere' is not a frame of ur10"),
    (["--kind", "poses", "--marker", "a=tool0", "--marker", "a=tool0"], "distinct names"),
    (["--kind", "poses", "--robot", "sk120", "--frame", "fixture_target", "--effect",
      "geometry:elbow=1,0,0"], "elbow is inside a closed loop of sk120"),
])
def test_bad_flags_are_refused_in_one_line(tmp_path, capsys, flags, says):
    """Exit 2, one line on stderr naming the problem, nothing on stdout, nothing written."""
    out = tmp_path / "sim"
    code, printed, err = _run(capsys, ["simulate", "--robot", "ur10", "--frame", "tool0",
                                       *flags, "--out", str(out)])
    assert code == 2 and printed == ""
    assert len(err.strip().splitlines()) == 1 and says in err, err
    assert not out.exists()


def _mimic_arm(folder) -> str:
    """j1 and j2 about z, j3 a ``<mimic>`` follower of j2 (half its angle), then the tool."""
    joints = [_joint("j1", "base", "l1"), _joint("j2", "l1", "l2", xyz=(0.3, 0, 0)),
              _joint("j3", "l2", "l3", xyz=(0.3, 0, 0)).replace(
                  "</joint>", '<mimic joint="j2" multiplier="0.5"/></joint>'),
              _joint("tip", "l3", "tool", xyz=(0.2, 0, 0), kind="fixed")]
    path = folder / "mimic.urdf"
    path.write_text(_robot_xml("mimic", ["base", "l1", "l2", "l3", "tool"], joints))
    return str(path)


@pytest.mark.parametrize("effect", ["backlash:j3=0.1", "joint_compliance:j3=1e4"])
@pytest.mark.parametrize("compliant", [("j1", "j2"), ("j1",)])
def test_a_spring_effect_on_a_mimic_follower_names_its_leader(tmp_path, effect, compliant):
    """A mimic follower cannot be declared compliant (its leader carries the spring: loading
    it so is refused), so the hint names the leader, not '--compliant-joints' for j3."""
    from stiffness.errors import StiffnessError
    from stiffness.planning.pose_simulation import simulate_poses
    path = _mimic_arm(tmp_path)
    with pytest.raises(StiffnessError, match="its leader carries the spring"):
        load_robot(path, compliant_joints=["j1", "j3"])
    robot = load_robot(path, compliant_joints=list(compliant))
    effects = [effect] if effect.startswith("joint") else ["joint_compliance:j1=1e4", effect]
    with pytest.raises(StiffnessError) as info:
        simulate_poses(robot, poses=4, effects=effects)
    text = str(info.value)
    assert "'j3' is not a compliant joint of" in text and "\n" not in text
    assert "mimic follower: its leader 'j2' carries the spring; name j2" in text
    assert ("declared with --compliant-joints" in text) == ("j2" not in compliant)
    assert "declare it with" not in text
