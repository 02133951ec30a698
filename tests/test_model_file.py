"""The model file (stiffness.elastic.model_file): schema, older files, effects at a pose."""

from __future__ import annotations

import json
import shutil
import warnings
from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest
from test_campaign import SLIDER_URDF

from stiffness.elastic.effects import LIBRARY
from stiffness.elastic.effects.base import Parameter
from stiffness.elastic.file_model import elastic_model_of
from stiffness.elastic.model_contents import (
    SCHEMA,
    ModelEffect,
    ModelFile,
    ModelFileError,
    ModelRobotError,
)
from stiffness.elastic.model_file import load_model, read_model_file
from stiffness.errors import UnknownJointError
from stiffness.robot.robot import load_robot
from stiffness.robot.sources import robots_directory

ARM = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint")
K_ARM = np.array([3e4, 2e4, 1.5e4])
Q = np.array([0.3, -1.1, 1.4, -0.5, 1.2, 0.2])


def _p(name: str, value: float, unit: str) -> Parameter:
    return Parameter(name, value, 0.01 * value, (0.98 * value, 1.02 * value), unit)


def _ur5_model(*effects: ModelEffect) -> ModelFile:
    return ModelFile(source="ur5", frame="tool0", target_offset_m=[0.0, 0.0, 0.1],
                     compliant_joints=ARM, k_theta=K_ARM, units=("N.m/rad",) * 3,
                     formulation="enhanced", effects=effects, noise_std_m=5e-6,
                     noise_source="declared", campaign="test", produced_by="diagnose")


def _tool_position(robot, q: np.ndarray) -> np.ndarray:
    pin.framesForwardKinematics(robot.model, robot.data, q)
    return robot.data.oMf[robot.target_frame_id].translation.copy()


def _fd_kx(robot, q: np.ndarray, k: np.ndarray, force: np.ndarray, h: float = 1e-6
           ) -> np.ndarray:
    """Enhanced K_X = (J (K - K_C)^-1 J^T)^-1 with J and K_C = d(J^T F)/dq from central
    differences of the target position (a serial arm: every compliant joint is a q entry)."""
    idx = [robot.model.joints[robot.model.getJointId(j)].idx_q for j in robot.compliant_joints]

    def jac(qq):
        out = np.empty((3, len(idx)))
        for c, i in enumerate(idx):
            e = np.zeros_like(qq)
            e[i] = h
            out[:, c] = (_tool_position(robot, qq + e) - _tool_position(robot, qq - e)) / (2 * h)
        return out

    j = jac(q)
    k_c = np.empty((len(idx), len(idx)))
    for c, i in enumerate(idx):
        e = np.zeros_like(q)
        e[i] = 1e-4
        k_c[:, c] = ((jac(q + e) - jac(q - e)).T @ force) / 2e-4
    return np.linalg.inv(j @ np.linalg.solve(np.diag(k) - k_c, j.T))


def test_round_trip_keeps_everything(tmp_path):
    model = _ur5_model(
        ModelEffect("joint_compliance", "wrist_1_joint", "stiffness",
                    [_p("stiffness", 1e4, "N.m/rad")]),
        ModelEffect("backlash", "elbow_joint", "lost_motion", [_p("half_width", 1e-4, "rad")],
                    {"smoothing_torque": 0.3}),
        ModelEffect("deflection_offset", None, "measurement",
                    [_p("dx", 1e-5, "m"), _p("dy", 0.0, "m"), _p("dz", 2e-5, "m")]))
    path = model.write(tmp_path / "m.json")
    doc = json.loads(path.read_text())
    assert doc["schema"] == SCHEMA and doc["noise"] == {"std_m": 5e-6, "source": "declared"}
    assert [e["kind"] for e in doc["effects"]] == ["stiffness", "lost_motion", "measurement"]
    back = read_model_file(path)
    np.testing.assert_array_equal(back.k_theta, K_ARM)
    assert back.compliant_joints == ARM and back.formulation == "enhanced"
    assert [e.label for e in back.effects] == [e.label for e in model.effects]
    assert back.effects[1].settings == {"smoothing_torque": 0.3}
    assert back.effects[0].value("stiffness") == 1e4


def test_older_identified_file_reads(tmp_path):
    old = {"format": "stiffness-identified-model", "version": 1, "campaign": "c",
           "robot": {"source": "ur5", "frame": "tool0", "target_offset_m": [0, 0, 0.1],
                     "compliant_joints": list(ARM)},
           "formulation": "enhanced",
           "k_theta": {"joints": list(ARM), "values": K_ARM.tolist(), "unit": ["N.m/rad"] * 3},
           "standard_error": [1.0, 2.0, None], "ci95": {"low": [1, 2, 3], "high": [4, 5, None]},
           "undetermined_joints": ["elbow_joint"], "residual_norm": {"eq12_m2": 1e-9}}
    path = tmp_path / "identified-model.json"
    path.write_text(json.dumps(old))
    model = read_model_file(path)
    np.testing.assert_array_equal(model.k_theta, K_ARM)
    assert model.effects == () and model.undetermined_joints == ("elbow_joint",)
    assert np.isnan(model.standard_error[2])


def test_older_diagnosed_file_reads_in_its_units(tmp_path):
    old = {"format": "stiffness-diagnosed-model", "version": 1, "campaign": "c",
           "robot": {"source": "ur5", "frame": "tool0", "target_offset_m": [0, 0, 0.1]},
           "baseline": "enhanced", "compliant_joints": list(ARM),
           "k_theta": {j: {"value": k, "standard_error": 1.0, "ci95": [k - 2, k + 2],
                           "unit": "N.m/rad"} for j, k in zip(ARM, K_ARM, strict=True)},
           "effects": [{"effect": "target_offset", "where": None, "parameters": {
               a: {"value": v, "standard_error": 0.1, "ci95": [v - 0.2, v + 0.2], "unit": "mm"}
               for a, v in (("dx", 20.0), ("dy", 0.0), ("dz", -10.0))}}],
           "noise_std": 0.005, "noise_std_source": "declared", "unit": "mm"}
    path = tmp_path / "final-model.json"
    path.write_text(json.dumps(old))
    model = read_model_file(path)
    np.testing.assert_allclose(model.effects[0].values(), [0.02, 0.0, -0.01])
    assert model.effects[0].parameters[0].unit == "m" and model.noise_std_m == 5e-6
    compliant = elastic_model_of(model)
    np.testing.assert_allclose(compliant.robot.target_offset, [0.02, 0.0, 0.09])


def test_unknown_schema_and_other_robot_are_one_line_errors(tmp_path):
    path = _ur5_model().write(tmp_path / "m.json")
    doc = json.loads(path.read_text())
    doc["schema"] = "stiffness-model/7"
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    with pytest.raises(ModelFileError, match="schema 'stiffness-model/7'") as info:
        read_model_file(bad)
    assert "\n" not in str(info.value)
    model = read_model_file(path)
    model.check_robot("ur5")
    with pytest.raises(ModelRobotError, match="is of robot 'ur5', not 'panda'"):
        model.check_robot("panda")
    # an effect on a joint the robot does not have
    for name in ("joint_compliance", "nonlinear_joint_stiffness"):
        wrong = _ur5_model(ModelEffect(name, "wrist_9_joint", "stiffness",
                                       [_p(LIBRARY[name].param_names[0], 1e4, "SI")]))
        with pytest.raises((UnknownJointError, ModelRobotError), match="wrist_9_joint"):
            elastic_model_of(wrong)
    # a shipped robot by name or by the path of its URDF is the same robot
    sk120 = ModelFile(source="sk120", frame="fixture_target", target_offset_m=np.zeros(3),
                      compliant_joints=("joint1",), k_theta=[1e6], units=("N.m/rad",),
                      formulation="enhanced")
    sk120.check_robot(robots_directory() / "sk120" / "sk120.urdf")
    with pytest.raises(ModelRobotError, match="not 'ur5'"):
        sk120.check_robot("ur5")


@pytest.mark.parametrize(("effect", "where", "param", "unit"), [
    ("joint_compliance", "wrist_1_joint", "stiffness", "N.mm/rad"),
    ("backlash", "elbow_joint", "half_width", "deg"),
    ("deflection_offset", None, "dx", "mm"),
])
def test_an_effect_parameter_in_other_than_si_is_refused(tmp_path, effect, where, param, unit):
    """The file is SI: a parameter naming another unit would be read as SI, silently wrong."""
    params = [_p(n, 1e-4, "rad" if effect == "backlash" else "m") for n in
              LIBRARY[effect].param_names]
    if effect == "joint_compliance":
        params = [_p("stiffness", 1e4, "N.m/rad")]
    path = _ur5_model(ModelEffect(effect, where, LIBRARY[effect].kind, params)).write(
        tmp_path / "m.json")
    assert read_model_file(path).effects[0].value(param) == params[0].value
    doc = json.loads(path.read_text())
    doc["effects"][0]["parameters"][param]["unit"] = unit
    path.write_text(json.dumps(doc))
    with pytest.raises(ModelFileError) as info:
        read_model_file(path)
    message = str(info.value)
    assert f"effects[0].parameters.{param}.unit is {unit!r}, but a model file holds SI " \
        "values" in message and "valid: m, rad, N, N.m, kg, N.m/rad" in message, message


def test_joint_compliance_enters_k_x_like_a_spring():
    k_wrist = 1e4
    model = _ur5_model(ModelEffect("joint_compliance", "wrist_2_joint", "stiffness",
                                   [_p("stiffness", k_wrist, "N.m/rad")]))
    force = np.array([20.0, -10.0, -80.0])
    result = load_model(model).at(Q, force)
    assert result.robot.compliant_joints == ARM + ("wrist_2_joint",)
    true = load_robot("ur5", frame="tool0", target_offset=[0, 0, 0.1],
                      compliant_joints=ARM + ("wrist_2_joint",))
    expected = _fd_kx(true, true.configuration(Q), np.append(K_ARM, k_wrist), force)
    np.testing.assert_allclose(result.k_x(), expected, rtol=1e-5)


def test_link_and_nonlinear_effects_are_the_tangent_of_the_fitted_deflection():
    """Conventional formulation: the compliance is d(deflection)/dF of the fitted model."""
    model = _ur5_model(
        ModelEffect("link_compliance", "elbow_joint->wrist_1_joint", "stiffness",
                    [_p("stiffness_1", 4e4, "N.m/rad"), _p("stiffness_2", 6e4, "N.m/rad")]),
        ModelEffect("nonlinear_joint_stiffness", "shoulder_lift_joint", "stiffness",
                    [_p("beta", 0.004, "1/(N.m)")]),
        ModelEffect("frame_misalignment", None, "measurement",
                    [_p("rx", 0.03, "rad"), _p("ry", 0.0, "rad"), _p("rz", 0.0, "rad")]))
    model.formulation = "conventional"
    compliant = elastic_model_of(model)
    assert [e.name for e, _ in compliant.not_applied] == ["frame_misalignment"]
    force = np.array([30.0, 10.0, -60.0])
    at = compliant.at(Q, force, "conventional")
    h = 1e-3
    fd = np.column_stack([(compliant.deflection(Q, force + h * e)
                           - compliant.deflection(Q, force - h * e)) / (2 * h)
                          for e in np.eye(3)])
    np.testing.assert_allclose(at.compliance(), fd, rtol=1e-6, atol=1e-12)
    assert np.abs(at.link_compliance).max() > 0
    # the measurement effect is not in the deflection unless asked for
    measured = compliant.deflection(Q, force, measured=True)
    assert not np.allclose(measured, compliant.deflection(Q, force))


# --------------------------------------------------------------- the check, end to end


def test_diagnosed_wrist_spring_enters_kx_at_a_new_pose(tmp_path, capsys):
    """simulate a UR5 campaign with a hidden wrist spring, diagnose --out, kx --model at a pose
    that is not in the campaign: K_X within 2 % of the true model's (finite differences of
    Pinocchio's forward kinematics, with the hidden spring)."""
    from stiffness.cli.main import main

    k_wrist = 1.5e3
    camp, diag = tmp_path / "camp", tmp_path / "diag"
    assert main(["simulate", "--robot", "ur5", "--frame", "tool0", "--compliant-joints",
                 ",".join(ARM), "--kq", ",".join(f"{k:g}" for k in K_ARM),
                 "--target-offset", "0,0,0.15", "--effect", f"joint_compliance:wrist_2_joint="
                 f"{k_wrist:g}", "--configs", "8", "--loads-per-config", "4", "--max-force",
                 "100", "--noise", "0.005", "--seed", "1", "--out", str(camp)]) == 0
    assert main(["diagnose", str(camp), "--out", str(diag), "--no-proposals", "--quiet"]) == 0
    capsys.readouterr()
    q, force = np.array([0.4, -1.3, 1.6, -0.9, 1.1, 0.5]), np.array([0.0, 0.0, -80.0])
    assert main(["kx", "--model", str(diag / "final-model.json"), "--q",
                 ",".join(map(str, q)), "--wrench", "0,0,-80", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    true = load_robot("ur5", frame="tool0", target_offset=[0, 0, 0.15],
                      compliant_joints=ARM + ("wrist_2_joint",))
    expected = _fd_kx(true, true.configuration(q), np.append(K_ARM, k_wrist), force)
    k_x = np.array(out["K_X"])
    error = np.linalg.norm(k_x - expected) / np.linalg.norm(expected)
    assert error <= 0.02, (error, out["model"])
    # the baseline model alone (no wrist spring) is off by over 5x the tolerance: the
    # diagnosed effect made the difference
    baseline = load_robot("ur5", frame="tool0", target_offset=[0, 0, 0.15], compliant_joints=ARM)
    rigid_wrist = _fd_kx(baseline, baseline.configuration(q), K_ARM, force)
    assert np.linalg.norm(rigid_wrist - expected) > 0.1 * np.linalg.norm(expected)
    assert out["model"]["effects_applied"]


def test_kx_model_of_another_robot_is_one_line(tmp_path, capsys):
    from stiffness.cli.main import main

    path = _ur5_model().write(tmp_path / "m.json")
    assert main(["kx", "--model", str(path), "--robot", "panda", "--json"]) == 2
    err = capsys.readouterr().err.strip()
    assert "is of robot 'ur5', not 'panda'" in err and "\n" not in err
    bad = tmp_path / "future.json"
    bad.write_text(json.dumps({"schema": "stiffness-model/2"}))
    assert main(["kx", "--model", str(bad), "--json"]) == 2
    assert "schema 'stiffness-model/2'" in capsys.readouterr().err


def test_kx_lists_measurement_effects_and_applies_stiffness_ones(tmp_path, capsys):
    from stiffness.cli.main import main

    model = _ur5_model(
        ModelEffect("joint_compliance", "wrist_1_joint", "stiffness",
                    [_p("stiffness", 2e4, "N.m/rad")]),
        ModelEffect("force_sensor_bias", None, "measurement",
                    [_p("fx", 1.0, "N"), _p("fy", 2.0, "N"), _p("fz", 3.0, "N")]))
    path = model.write(tmp_path / "m.json")
    args = ["kx", "--model", str(path), "--q", ",".join(map(str, Q)), "--wrench", "0,10,-50"]
    assert main(args + ["--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["compliant_joints"] == list(ARM) + ["wrist_1_joint"]
    assert out["K_theta"] == K_ARM.tolist() + [2e4]
    assert [e["effect"] for e in out["model"]["effects_not_applied"]] == ["force_sensor_bias"]
    assert out["model"]["effects_not_applied"][0]["kind"] == "measurement"
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "effects in K_X: joint_compliance(wrist_1_joint)" in text
    assert "not applied: force_sensor_bias" in text
    # --kq replaces the model's springs: nothing of the model's effects applies
    assert main(args + ["--kq", "1e4,1e4,1e4", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["compliant_joints"] == list(ARM) and not out["model"]["effects_applied"]


def _link_model() -> ModelFile:
    return _ur5_model(
        ModelEffect("joint_compliance", "wrist_1_joint", "stiffness",
                    [_p("stiffness", 2e4, "N.m/rad")]),
        ModelEffect("link_compliance", "elbow_joint->wrist_1_joint", "stiffness",
                    [_p("stiffness_1", 4e4, "N.m/rad"), _p("stiffness_2", 6e4, "N.m/rad")]))


def test_view_model_draws_the_models_compliance(tmp_path, capsys):
    """The exported ellipsoid's radii are proportional to the principal compliances of the
    model (link compliance included), not of its joint springs alone."""
    from stiffness.cli.main import main
    from stiffness.viewer import scene_commands, scene_transforms

    path = _link_model().write(tmp_path / "m.json")
    page = tmp_path / "page.html"
    force = [0.0, 0.0, -100.0]
    assert main(["view", "--model", str(path), "--q", ",".join(map(str, Q)), "--wrench",
                 "0,0,-100", "--formulation", "enhanced", "--quantity", "compliance",
                 "--export", str(page)]) == 0
    capsys.readouterr()
    matrix = scene_transforms(scene_commands(page.read_text()))[
        "/meshcat/stiffness/enhanced/surface"]
    radii = np.sort(np.linalg.norm(matrix[:3, :3], axis=0))
    with_link = np.linalg.eigvalsh(load_model(_link_model()).at(Q, force).compliance())
    np.testing.assert_allclose(radii / with_link, radii[0] / with_link[0], rtol=1e-6)
    springs = elastic_model_of(_link_model())
    at = springs.at(Q, force)
    joints_only = np.linalg.eigvalsh(at.compliance() - at.link_compliance[:3, :3])
    assert not np.allclose(radii / joints_only, radii[0] / joints_only[0], rtol=1e-3)


def test_scan_model_scans_the_models_springs(tmp_path, capsys):
    from stiffness.cli.main import main

    model = _ur5_model(ModelEffect("joint_compliance", "wrist_1_joint", "stiffness",
                                   [_p("stiffness", 2e4, "N.m/rad")]))
    path = model.write(tmp_path / "m.json")
    out = tmp_path / "scan"
    assert main(["scan", "--model", str(path), "--samples", "6", "--load", "0,0,-100",
                 "--out", str(out), "--no-plots", "--quiet", "--json"]) == 0
    capsys.readouterr()
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["spec"]["k_theta"] == K_ARM.tolist() + [2e4]
    # the echo names where the springs came from (it said "robot default" for the model's)
    assert main(["scan", "--model", str(path), "--samples", "2", "--load", "0,0,-100",
                 "--out", str(tmp_path / "echo"), "--no-plots"]) == 0
    assert f"K_theta [model file {path}] (N.m/rad" in capsys.readouterr().out
    assert manifest["spec"]["robot"]["compliant_joints"] == list(ARM) + ["wrist_1_joint"]
    from stiffness.workspace.engine import load_scan

    chunk = load_scan(out)  # the stored maps, derived arrays and coordinates rebuilt
    compliant = elastic_model_of(model)
    for i in range(2):
        expected = compliant.at(chunk["coordinates"][i], [0, 0, -100.0]).k_x()
        np.testing.assert_allclose(chunk["k_x"][i, 0], expected, rtol=1e-9)
    path = _link_model().write(tmp_path / "link.json")
    assert main(["scan", "--model", str(path), "--samples", "6", "--out",
                 str(tmp_path / "no"), "--quiet"]) == 2
    assert "link_compliance(elbow_joint->wrist_1_joint) changes K_X" in capsys.readouterr().err


def test_fixed_base_and_loop_file_travel_with_the_model(tmp_path):
    """A model identified on a robot loaded with a fixed base and a loop file records both
    (the loop file relative to the model's folder), and every use of the model loads the robot
    the same way: a floating-base robot's model gives its compliance at a new pose (the foot
    moves with its leg's two joints: rank 2)."""
    joints = ("FL_HFE", "FL_KFE", "FR_HFE", "FR_KFE", "HL_HFE", "HL_KFE", "HR_HFE", "HR_KFE")
    loops = tmp_path / "declared" / "robot.loops.yaml"
    loops.parent.mkdir()
    loops.write_text("closed_loop: []\n")
    model = ModelFile(source="solo8", frame="FL_FOOT", target_offset_m=np.zeros(3),
                      compliant_joints=joints, k_theta=np.full(8, 50.0),
                      units=("N.m/rad",) * 8, formulation="enhanced", fixed_base=True)
    path = model.write(tmp_path / "models" / "m.json")
    doc = json.loads(path.read_text())
    assert doc["robot"]["fixed_base"] is True and "loops" not in doc["robot"]
    back = read_model_file(path)
    assert back.fixed_base and back.loops is None
    cm = elastic_model_of(back)
    q = cm.robot.configuration(np.full(8, 0.4))
    compliance = load_model(back).at(q, np.array([0.0, 0.0, -5.0])).compliance()
    assert np.all(np.isfinite(compliance)) and np.linalg.matrix_rank(compliance) == 2
    with_loops = ModelFile(**{**model.__dict__, "loops": str(loops), "path": None})
    doc = json.loads(with_loops.write(tmp_path / "models" / "l.json").read_text())
    assert doc["robot"]["loops"] == "../declared/robot.loops.yaml"
    assert read_model_file(tmp_path / "models" / "l.json").loops == str(loops.resolve())
    plain = json.loads(_ur5_model().write(tmp_path / "u.json").read_text())["robot"]
    assert "fixed_base" not in plain and "loops" not in plain  # files as before


def test_commands_taking_the_robot_from_a_model_file_load_it_with_its_fixed_base(tmp_path):
    """`robot export --model`, `kx --model --kq` and `scan --model --kq` take the robot from
    the model file as a fallback of the robot flags: with its fixed base too (they refused
    the solo8 of a `--fixed-base` campaign's model: 'fix the base ... with --fixed-base')."""
    from stiffness.cli.main import main

    model = ModelFile(source="solo8", frame="FL_FOOT", target_offset_m=np.zeros(3),
                      compliant_joints=("FL_HFE", "FL_KFE"), k_theta=np.full(2, 50.0),
                      units=("N.m/rad",) * 2, formulation="enhanced", fixed_base=True)
    path = str(model.write(tmp_path / "m.json"))
    assert main(["robot", "export", "--model", path, "--urdf", str(tmp_path / "s.urdf"),
                 "--quiet"]) == 0
    assert 'name="root_joint"' not in (tmp_path / "s.urdf").read_text()
    assert main(["kx", "--model", path, "--kq", "60,60", "--q", "FL_HFE=0.4,FL_KFE=-0.8",
                 "--wrench", "0,0,-5", "--json"]) == 0
    out = tmp_path / "scan"
    assert main(["scan", "--model", path, "--kq", "60,60", "--samples", "4", "--no-plots",
                 "--quiet", "--out", str(out)]) == 0
    assert json.loads((out / "manifest.json").read_text())["spec"]["robot"]["fixed_base"]


def test_a_model_moved_to_another_target_predicts_its_deflection_there(tmp_path):
    """load_model(file, target_offset=...) predicts the fitted deflection at that target, as
    the same model declared there does (it predicted at the file's own target), and validate
    evaluates the model at the campaign's target: a UR5 model of tool0 + 0.1 m on a campaign
    measured at tool0 + 0.25 m with its springs had a 3-D error RMS of 0.54 mm, 108x the
    0.005 mm noise (now 0.0082 mm, sqrt(3) noise for a 3-D norm)."""
    import stiffness

    model = _ur5_model(ModelEffect("frame_misalignment", None, "measurement",
                                   [_p(n, 1e-3, "rad") for n in ("rx", "ry", "rz")]))
    far = ModelFile(**{**model.__dict__, "target_offset_m": [0.0, 0.0, 0.25], "path": None})
    path, far_path = model.write(tmp_path / "m.json"), far.write(tmp_path / "far.json")
    load = np.array([30.0, -40.0, -80.0])
    moved = load_model(path, target_offset=[0.0, 0.0, 0.25]).deflection(Q, load, measured=True)
    np.testing.assert_allclose(moved, load_model(far_path).deflection(Q, load, measured=True),
                               rtol=1e-12, atol=0)
    assert np.linalg.norm(moved - load_model(path).deflection(Q, load)) > 1e-5
    stiffness.simulate("ur5", kq=K_ARM, compliant_joints=ARM, target_offset_m=[0, 0, 0.25],
                       configs=4, loads_per_config=2, noise_std_m=5e-6, seed=3,
                       ).write(tmp_path / "c")
    assert stiffness.validate(path, tmp_path / "c").errors["rms"] < 3 * 5e-3  # mm


def test_joint_compliance_on_a_compliant_joint_is_refused(tmp_path):
    """Two stiffnesses for one spring: the effect would silently replace k_theta's."""
    model = _ur5_model(ModelEffect("joint_compliance", "elbow_joint", "stiffness",
                                   [_p("stiffness", 1e4, "N.m/rad")]))
    path = model.write(tmp_path / "m.json")
    with pytest.raises(ModelFileError, match="joint_compliance effect on elbow_joint, which is "
                       "already a compliant joint of k_theta") as info:
        elastic_model_of(read_model_file(path))
    assert str(info.value).startswith(str(path)) and "\n" not in str(info.value)


def test_an_effect_on_a_controller_coordinate_loads(tmp_path):
    """A robot whose springs act on its [controller] coordinates (tests/data/torso-passive):
    diagnose names backlash(T2) there, and the model file it wrote was refused ("names 'T2',
    not a joint of torso-passive"), though T2 is the spring the effect acts on. The nonlinear
    spring on T2 enters K_X as the tangent of the fitted deflection. A bend's or a tilt's joint
    must be a joint of the chain, not a coordinate."""
    torso = robots_directory().parent / "tests" / "data" / "torso-passive" / "robot.toml"
    springs = ("T1", "T2", "T3", "A1", "A2")
    model = ModelFile(
        source=str(torso), frame="tool", target_offset_m=[0.0, 0.0, 0.0],
        compliant_joints=springs, k_theta=np.array([4e4, 2.5e4, 2e4, 8e3, 6e3]),
        units=("N.m/rad",) * 5, formulation="conventional", noise_std_m=5e-6,
        noise_source="declared", campaign="test", produced_by="diagnose", effects=(
            ModelEffect("backlash", "T2", "lost_motion", [_p("half_width", 1e-4, "rad")]),
            ModelEffect("nonlinear_joint_stiffness", "T2", "stiffness",
                        [_p("beta", 0.01, "1/(N.m)")])))
    compliant = elastic_model_of(read_model_file(model.write(tmp_path / "m.json")))
    assert [e.label for e, _ in compliant.not_applied] == ["backlash(T2)"]
    q, force = np.radians([10.0, 20.0, 15.0, -30.0, 40.0]), np.array([20.0, -15.0, -60.0])
    spring = elastic_model_of(replace(model, effects=model.effects[1:]))  # no lost motion
    h = 1e-3
    fd = np.column_stack([(spring.deflection(q, force + h * e)
                           - spring.deflection(q, force - h * e)) / (2 * h)
                          for e in np.eye(3)])
    plain = load_model(str(torso), k=[4e4, 2.5e4, 2e4, 8e3, 6e3]).at(q, force, "conventional")
    at = compliant.at(q, force, "conventional")
    np.testing.assert_allclose(at.compliance(), fd, rtol=1e-8, atol=0)
    assert np.abs(at.compliance() - plain.compliance()).max() > 0.05 * np.abs(fd).max()
    for effect, where, name in (("link_compliance", "t1->T9", "T9"),
                                ("transversal_compliance", "T2", "T2")):  # tilts a joint
        other = replace(model, effects=(ModelEffect(effect, where, "stiffness", [
            _p("stiffness_1", 1e5, "N.m/rad"), _p("stiffness_2", 1e5, "N.m/rad")]),))
        with pytest.raises(ModelRobotError, match=f"names '{name}', not a joint of torso-passive"):
            elastic_model_of(other)


def test_an_undetermined_stiffness_is_used_with_a_warning(tmp_path):
    from stiffness.errors import DataFileWarning

    model = _ur5_model()
    model.undetermined_joints = ("elbow_joint",)
    path = model.write(tmp_path / "m.json")
    assert json.loads(path.read_text())["k_theta"]["determined"] == [True, True, False]
    with pytest.warns(DataFileWarning, match="the stiffness of elbow_joint is marked "
                      "undetermined"):
        compliant = elastic_model_of(read_model_file(path))
    np.testing.assert_array_equal(compliant.k_theta, K_ARM)
    with warnings.catch_warnings(record=True) as caught:  # at the user's line, not inside
        warnings.simplefilter("always")
        load_model(path)
    assert [(w.category, w.filename) for w in caught] == [(DataFileWarning, __file__)]


@pytest.mark.parametrize(("joint", "wrong", "expected"), [("slide", "N.m/rad", "N/m"),
                                                           ("swing", "N/m", "N.m/rad")])
def test_a_stiffness_unit_of_the_wrong_kind_of_joint_is_refused(tmp_path, joint, wrong,
                                                                 expected):
    """A written model file edited to give the prismatic joint's stiffness in N.m/rad, or the
    revolute one's in N/m, is refused naming the joint and both units; as written it loads
    (a 1e5 N/m slide along x under 10 N along x deflects 1e-4 m)."""
    (tmp_path / "slider.urdf").write_text(SLIDER_URDF)
    model = ModelFile(source=str(tmp_path / "slider.urdf"), frame="tip",
                      target_offset_m=[0.0, 0.0, 0.0], compliant_joints=("slide", "swing"),
                      k_theta=[1e5, 2e3], units=("N/m", "N.m/rad"), formulation="conventional")
    path = model.write(tmp_path / "model.json")
    moved = load_model(path).deflection(np.zeros(2), np.array([10.0, 0.0, 0.0]))
    assert np.allclose(moved, [1e-4, 0.0, 0.0], rtol=1e-9, atol=1e-15)
    doc = json.loads(path.read_text())
    units = doc["k_theta"]["unit"]
    units[doc["k_theta"]["joints"].index(joint)] = wrong
    path.write_text(json.dumps(doc))
    with pytest.raises(ModelFileError) as info:
        load_model(path)
    message = str(info.value)
    assert "\n" not in message
    assert all(s in message for s in (repr(joint), repr(wrong), repr(expected)))


@pytest.mark.parametrize(("unit", "refused"), [("N/m", False), ("SI", False),
                                               ("N.m/rad", True)])
def test_an_effects_stiffness_unit_of_the_wrong_kind_of_joint_is_refused(tmp_path, unit,
                                                                        refused):
    """A joint_compliance effect makes the prismatic slide a 1e5 N/m spring (10 N along it
    deflects the tip 1e-4 m; the swing's 2e3 N.m/rad spring is not loaded: the force passes
    through its axis); written in N/m or "SI" it loads, in N.m/rad it is refused naming the
    effect, the joint and both units."""
    (tmp_path / "slider.urdf").write_text(SLIDER_URDF)
    effect = ModelEffect("joint_compliance", "slide", "stiffness", [_p("stiffness", 1e5, unit)])
    path = ModelFile(source=str(tmp_path / "slider.urdf"), frame="tip",
                     target_offset_m=[0.0, 0.0, 0.0], compliant_joints=("swing",),
                     k_theta=[2e3], units=("N.m/rad",), formulation="conventional",
                     effects=(effect,)).write(tmp_path / "model.json")
    if not refused:
        moved = load_model(path).deflection(np.zeros(2), np.array([10.0, 0.0, 0.0]))
        np.testing.assert_allclose(moved, [1e-4, 0.0, 0.0], rtol=1e-9, atol=1e-15)
        return
    with pytest.raises(ModelFileError) as info:
        load_model(path)
    message = str(info.value)
    assert "\n" not in message and "effects[0] (joint_compliance(slide)) stiffness" in message
    assert all(s in message for s in ("'slide'", "'N.m/rad'", "'N/m'"))


def test_a_compensators_spring_in_a_joints_unit_is_refused(tmp_path):
    """A gravity compensator's spring is linear (N/m) on a revolute joint: N.m/rad is not its
    unit, whatever the joint."""
    model = _ur5_model(ModelEffect("gravity_compensator", "shoulder_lift_joint",
                                   LIBRARY["gravity_compensator"].kind,
                                   [_p("stiffness", 1e4, "N.m/rad"), _p("preload", 50.0, "N")]))
    with pytest.raises(ModelFileError, match=r"gravity_compensator\(shoulder_lift_joint\)\) "
                       r"stiffness is in 'N.m/rad', expected 'N/m'"):
        elastic_model_of(read_model_file(model.write(tmp_path / "m.json")))


@pytest.mark.parametrize(("effect", "param", "kind", "wrong", "expected"), [
    ("backlash", "half_width", "lost_motion", "m", "rad"),
    ("nonlinear_joint_stiffness", "beta", "stiffness", "1/N", "1/(N.m)")])
def test_a_joint_effects_unit_of_a_prismatic_joint_on_a_revolute_one_is_refused(
        tmp_path, effect, param, kind, expected, wrong):
    """A backlash half width in m (or a softening beta in 1/N) on the revolute elbow would be
    read as rad (1/(N.m)): refused naming the effect, the joint and both units."""
    model = _ur5_model(ModelEffect(effect, "elbow_joint", kind, [_p(param, 1e-4, wrong)]))
    with pytest.raises(ModelFileError) as info:
        elastic_model_of(read_model_file(model.write(tmp_path / "m.json")))
    message = str(info.value)
    assert f"effects[0] ({effect}(elbow_joint)) {param} is in {wrong!r}, expected " \
           f"{expected!r} (of revolute joint 'elbow_joint')" in message and "\n" not in message


def test_a_model_file_moved_away_from_its_urdf_takes_it_from_robot(tmp_path, capsys):
    """A model file names its URDF relative to itself: copied elsewhere (sent to a colleague)
    it could not be used at all, since ``--robot`` at the URDF's new place was refused as
    'another robot'. A --robot of the same robot name now stands in for the missing file; a
    robot of another name is still refused, and so is another robot while the file is there."""
    from stiffness.cli.main import main

    (tmp_path / "robot").mkdir()
    urdf = tmp_path / "robot" / "slider.urdf"
    urdf.write_text(SLIDER_URDF)
    model = ModelFile(source=str(urdf), frame="tip", target_offset_m=np.zeros(3),
                      compliant_joints=("slide", "swing"), k_theta=np.array([1e5, 2e4]),
                      units=("N/m", "N.m/rad"), formulation="enhanced", robot_name="slider")
    (tmp_path / "a" / "b").mkdir(parents=True)
    moved = model.write(tmp_path / "a" / "b" / "identified-model.json")
    kx = ["kx", "--model", str(moved), "--wrench", "0,0,-10", "--json"]
    assert main(kx) == 0  # beside its URDF (relative path ../../robot/slider.urdf)
    at_home = json.loads(capsys.readouterr().out)["K_X"]
    shutil.move(str(tmp_path / "a"), str(tmp_path / "robot" / "a"))  # now ../../slider.urdf
    moved = tmp_path / "robot" / "a" / "b" / "identified-model.json"
    assert main(kx[:2] + [str(moved)] + kx[3:]) == 2
    assert "slider.urdf does not exist" in capsys.readouterr().err
    assert main(kx[:2] + [str(moved), "--robot", str(urdf)] + kx[3:]) == 0
    np.testing.assert_array_equal(json.loads(capsys.readouterr().out)["K_X"], at_home)
    with pytest.raises(ModelRobotError, match="is of robot 'slider'"):
        read_model_file(moved).check_robot("ur5")
    (tmp_path / "robot" / "other.urdf").write_text(SLIDER_URDF)
    with pytest.raises(ModelRobotError, match="is of robot 'slider'"):
        model.check_robot(str(tmp_path / "robot" / "other.urdf"))  # the model's file is there
