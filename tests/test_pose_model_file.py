"""One model file for both kinds (issue 35): a pose calibration's ``final-model.json`` is read
by ``stiffness.load_model`` and by every command that takes ``--model``.

The loaded elastic model is checked against an independent computation from the file's
parameters: the nominal UR10 with each joint's placement error ``M_j exp(eps_j)`` applied by
hand, the zero offsets added to the commanded angles (not folded into the placements), the
weight's sag solved by fixed-point iteration, and ``C = J diag(c) J^T`` at the sagged pose.
"""

from __future__ import annotations

import contextlib
import json
import warnings

import numpy as np
import pinocchio as pin
import pytest
from pose_campaigns import PRISM_ARM

from stiffness import load_model
from stiffness.calibration.pose_campaign import write_pose_campaign
from stiffness.calibration.pose_fit import (
    campaign_settings,
    fit_pose_model,
    rows_of,
    starting_frame,
)
from stiffness.calibration.pose_model import Marker, PoseModel
from stiffness.calibration.pose_model_file import write_pose_model
from stiffness.cli.main import main
from stiffness.errors import DataFileWarning, StiffnessError
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.calibration import read_pose_calibration
from stiffness.robot.robot import load_robot

FAMILIES = ["frame", "markers", "joint_offsets", "geometry", "joint_compliance"]
STIFFNESS = np.array([3e5, 2e5, 1.2e5, 4e4, 3e4, 3e4])  # N.m/rad
Q = np.array([0.1, -1.2, 1.0, -0.5, 1.2, 0.3])  # rad
AXES = ("x", "y", "z", "rx", "ry", "rz")


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    """A UR10 pose campaign (30 poses, 150 N payload) fitted with geometry and joint
    compliance, written as a campaign and a pose model file."""
    robot = load_robot("ur10", frame="tool0")
    markers = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05]))]
    rng = np.random.default_rng(3)
    eps = np.zeros((6, 6))
    eps[:, :2] = rng.normal(0.0, 4e-4, (6, 2))
    hidden = HiddenPoseErrors(pin.exp3(rng.normal(size=3)), rng.uniform(-2, 2, 3),
                              np.array([m.offset for m in markers]) + rng.normal(0, 2e-3, (1, 3)),
                              rng.normal(0.0, 1e-3, 6), eps, STIFFNESS)
    c = simulate_pose_campaign(robot, markers, hidden, 30, 1e-5, seed=3,
                               payload=np.array([0.0, 0.0, -150.0, 0.0, 0.0, 0.0]))
    model = PoseModel(robot, markers, tuple(FAMILIES), starting_frame(c), c.loads,
                      campaign_settings(c))
    fit = fit_pose_model(model, c, rows_of(model, c), FAMILIES)
    folder = tmp_path_factory.mktemp("pose-model")
    write_pose_campaign(c, folder / "campaign")
    path = write_pose_model(fit, c, folder / "diagnosis" / "final-model.json")
    return robot, path


def _by_hand(robot, doc: dict, q: np.ndarray) -> np.ndarray:
    """The 3x3 compliance (m/N) at commanded ``q`` from the file's numbers, independently."""
    values = {p["parameter"]: p["value"] for p in doc["parameters"]}
    model = pin.Model(robot.model)
    delta = np.zeros(model.nv)
    for j in range(1, model.njoints):
        name = model.names[j]
        eps = np.array([values.get(f"{name} placement {a}", 0.0) for a in AXES])
        model.jointPlacements[j] = model.jointPlacements[j] * pin.exp6(pin.Motion(eps))
        delta[model.joints[j].idx_v] = values.get(f"{name} zero", 0.0)
    springs = {model.joints[model.getJointId(j)].idx_v: values[f"{j} compliance"]
               for j in doc["robot"]["compliant_joints"]
               if values[f"{j} compliance"] > 0 and next(
                   p["fitted"] for p in doc["parameters"] if p["parameter"] == f"{j} compliance")}
    data = model.createData()
    commanded = pin.integrate(model, robot.configuration(q), delta)
    sag = np.zeros(model.nv)
    for _ in range(100):  # q = q_c + delta + C tau(q), tau = -g(q)
        tau = -pin.computeGeneralizedGravity(model, data, pin.integrate(model, commanded, sag))
        new = np.zeros(model.nv)
        for v, c in springs.items():
            new[v] = c * tau[v]
        if np.max(np.abs(new - sag)) < 1e-15:
            break
        sag = new
    pin.computeJointJacobians(model, data, pin.integrate(model, commanded, sag))
    pin.updateFramePlacements(model, data)
    jac = pin.getFrameJacobian(model, data, robot.target_frame_id, pin.LOCAL_WORLD_ALIGNED)[:3]
    cols = list(springs)
    return jac[:, cols] @ np.diag([springs[v] for v in cols]) @ jac[:, cols].T


def test_load_model_carries_the_calibrated_geometry_and_springs(calibration):
    robot, path = calibration
    doc = json.loads(path.read_text())
    with pytest.warns(UserWarning, match="held rigid"):
        em = load_model(path)
    expected = _by_hand(robot, doc, Q)
    got = em.at(Q, np.zeros(3)).compliance(formulation="conventional")
    assert np.linalg.norm(got - expected) < 1e-8 * np.linalg.norm(expected)
    # the test can fail: without the calibrated geometry the compliance is off by far more
    plain = json.loads(path.read_text())
    plain["parameters"] = [p for p in plain["parameters"] if p["family"] == "joint_compliance"]
    assert np.linalg.norm(_by_hand(robot, plain, Q) - expected) > 1e-3 * np.linalg.norm(expected)
    assert [e.name for e in em.applied] == ["gravity_preload"]
    assert set(em.robot.compliant_joints) == {"shoulder_lift_joint", "elbow_joint",
                                              "wrist_1_joint", "wrist_2_joint"}


def test_every_model_command_accepts_a_pose_model_file(calibration, tmp_path, capsys):
    """kx (also with --robot naming the calibrated robot), view, scan (its springs given: the
    batched scan does not model the weight's preload), compensate, posture, robot export and
    validate take the file (exit 0)."""
    robot, path = calibration
    q = ",".join(map(str, Q))
    poses = tmp_path / "poses.csv"
    poses.write_text("x,y,z,ax,ay,az\n0.8,-0.2,0.4,0,0,-1\n0.8,-0.15,0.4,0,0,-1\n")
    path_csv = tmp_path / "path.csv"
    path_csv.write_text("q1,q2,q3,q4,q5,q6\n" + "\n".join(
        ",".join(map(str, Q + d)) for d in (0.0, 0.05)) + "\n")
    model = ["--model", str(path)]
    commands = [
        ["kx", *model, "--q", q, "--wrench", "0,0,-100", "--json"],
        ["kx", *model, "--robot", "ur10", "--q", q, "--wrench", "0,0,-100", "--json"],
        ["view", *model, "--q", q, "--wrench", "0,0,-100", "--export", str(tmp_path / "v.html")],
        ["scan", *model, "--kq", "2e5,1.2e5,4e4,3e4", "--samples", "4", "--out",
         str(tmp_path / "scan"), "--no-plots", "--quiet"],
        ["compensate", *model, "--path", str(path_csv), "--wrench", "0,0,-100", "--quiet",
         "--out", str(tmp_path / "comp.csv")],
        ["posture", *model, "--path", str(poses), "--wrench", "0,0,100", "--steps", "4",
         "--max-step", "90", "--json"],
        ["robot", "export", *model, "--urdf", str(tmp_path / "calibrated.urdf"), "--mjcf",
         str(tmp_path / "calibrated.xml"), "--quiet"],
        ["validate", str(path), str(path.parent.parent / "campaign"), "--json"],
    ]
    for argv in commands:
        code = main(argv)
        err = capsys.readouterr().err
        assert code == 0, (argv[0], err)


def _hand_written(model: PoseModel, x: np.ndarray, path) -> None:
    """A pose model file written by hand from a model and its parameters (every parameter
    fitted, no uncertainty)."""
    robot = model.robot
    path.write_text(json.dumps({
        "kind": "pose-calibration", "version": 1, "units": "SI",
        "robot": {"source": "ur10", "frame": robot.target_frame, "target_offset_m": [0, 0, 0],
                  "compliant_joints": list(robot.compliant_joints)},
        "measuring_frame": {"rotation": model.rotation0.tolist(),
                            "translation_m": model.translation0.tolist()},
        "markers": [{"name": m.name, "frame": m.frame, "offset_m": m.offset.tolist()}
                    for m in model.markers],
        "load_frame": None, "families": list(model.families), "settings": model.settings,
        "parameters": [{"family": p.family, "parameter": p.label, "unit": p.unit,
                        "value": float(v), "fitted": True, "std": 0.0,
                        "interval_95": [float(v), float(v)]}
                       for p, v in zip(model.parameters, x, strict=True)]}))


def test_the_loaded_model_rests_where_the_calibration_predicts(calibration, tmp_path):
    """With spring compensators and large zero offsets (0.05 rad), the elastic model's unloaded
    pose (the weight and the compensators sag the springs) puts the marker where the
    calibration's own model predicts it (its sag's fixed point): 2.2e-8 m (1e-7 asked); the
    compensators' angles not corrected by the zero offsets put it 1.4e-4 m off."""
    robot, _ = calibration
    markers = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05]))]
    fams = ("frame", "markers", "joint_offsets", "geometry", "joint_compliance",
            "gravity_compensator")
    model = PoseModel(robot, markers, fams, (pin.exp3(np.array([0.1, 0.2, 0.3])),
                                             np.array([1.0, -0.5, 0.2])))
    rng = np.random.default_rng(5)
    values = {p.label: 0.0 for p in model.parameters}
    for p in model.parameters:
        if p.family in ("frame", "markers", "geometry"):
            values[p.label] = rng.normal(0.0, 1e-3)
        elif p.family == "joint_offsets":
            values[p.label] = 0.05
        elif p.family == "joint_compliance":
            values[p.label] = 1.0 / 2e4
        elif p.label.endswith("compensator stiffness"):
            values[p.label] = 4e3
        elif p.label.endswith("compensator preload"):
            values[p.label] = 300.0
    x = np.array([values[p.label] for p in model.parameters])
    _hand_written(model, x, tmp_path / "final-model.json")
    em = load_model(tmp_path / "final-model.json")
    assert sorted(e.label for e in em.applied)[:2] == [
        "gravity_compensator(elbow_joint)", "gravity_compensator(shoulder_lift_joint)"]
    file = read_pose_calibration(tmp_path / "final-model.json")
    rotation, translation = file.measuring_placement()
    qs = np.array([[0.3, -1.0, 1.2, -0.4, 1.0, 0.2], [-0.5, -2.0, 0.7, 0.3, -1.1, 0.5]])
    predicted = model.evaluate(x, [model.row_terms(robot.configuration(q), None) for q in qs],
                               jacobian=False)[0][:, 0]
    calibrated = em.robot
    data = calibrated.model.createData()
    tip = calibrated.model.getFrameId("tool0")
    for q, expected in zip(qs, predicted, strict=True):
        rest = em.preloaded_configuration(em.configuration(q))
        pin.framesForwardKinematics(calibrated.model, data, rest)
        seen = rotation @ data.oMf[tip].act(file.marker_offset(0)) + translation
        assert np.linalg.norm(seen - expected) < 1e-7


def test_a_geometric_calibration_has_no_springs(calibration, tmp_path, capsys):
    """A calibration of geometry only: kx refuses it with one line (no spring), robot export
    writes its geometry."""
    robot, _ = calibration
    markers = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05]))]
    model = PoseModel(robot, markers, ("frame", "markers", "joint_offsets"),
                      (np.eye(3), np.zeros(3)))
    _hand_written(model, np.full(model.size, 1e-3), tmp_path / "geometry.json")
    capsys.readouterr()
    assert main(["kx", "--model", str(tmp_path / "geometry.json"), "--q",
                 ",".join(map(str, Q)), "--wrench", "0,0,-100"]) == 2
    err = capsys.readouterr().err.strip()
    assert "no spring" in err and "\n" not in err, err
    assert main(["robot", "export", "--model", str(tmp_path / "geometry.json"), "--urdf",
                 str(tmp_path / "g.urdf"), "--quiet"]) == 0


def test_a_calibration_without_springs_says_why(calibration, tmp_path):
    """No spring, each case named with its fix (the sweep of issue 47: a 12-pose Talos arm
    diagnosis named link_compliance alone and load_model said "geometry only"): link bends
    without joint springs, every joint compliance held, geometry only."""
    robot, _ = calibration
    markers = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05]))]
    cases = [(("frame", "markers", "link_compliance"), "named link_compliance but no joint_c"),
             (("frame", "markers", "joint_compliance"), "determined none of the joint comp"),
             (("frame", "markers", "joint_offsets"), "geometry only")]
    for n, (families, says) in enumerate(cases):
        model = PoseModel(robot, markers, families, (np.eye(3), np.zeros(3)))
        path = tmp_path / f"c{n}.json"
        _hand_written(model, np.full(model.size, 1e-5), path)
        doc = json.loads(path.read_text())
        for p in doc["parameters"]:
            p["fitted"] = p["family"] != "joint_compliance"  # every spring held at nominal
        path.write_text(json.dumps(doc))
        warns = pytest.warns(DataFileWarning) if n == 1 else contextlib.nullcontext()
        with warns, pytest.raises(StiffnessError, match="no spring") as err:
            load_model(path)
        assert says in str(err.value) and "\n" not in str(err.value), str(err.value)


def test_a_compensator_beside_a_prismatic_spring_loads(tmp_path):
    """A calibration with gravity compensators on a robot with prismatic springs (compensators
    on its revolute joints only): load_model raised "gravity_compensator needs a revolute
    joint" for the prismatic ones (the pose sweep of issue 47, a DH arm with a lift and a
    slide); the compensated revolute joints' effects load."""
    (tmp_path / "robot.toml").write_text(PRISM_ARM)
    robot = load_robot(str(tmp_path / "robot.toml"))
    markers = [Marker("tip", "tool", np.array([0.0, 0.03, 0.05]))]
    model = PoseModel(robot, markers, ("frame", "markers", "joint_compliance",
                                       "gravity_compensator"), (np.eye(3), np.zeros(3)))
    path = tmp_path / "final-model.json"
    _hand_written(model, np.full(model.size, 1e-4), path)
    doc = json.loads(path.read_text())
    doc["robot"].update(source="robot.toml", frame="tool")
    path.write_text(json.dumps(doc))
    em = load_model(path)
    assert [e.label for e in em.applied] == ["gravity_preload", "gravity_compensator(j1)",
                                             "gravity_compensator(j3)",
                                             "gravity_compensator(j5)"]


def test_families_without_a_deflection_effect_are_announced(calibration, tmp_path):
    """A calibration holding base_tilt (no deflection effect yet) is read with a warning
    naming it: the elastic model leaves it out rather than silently."""
    _, path = calibration
    doc = json.loads(path.read_text())
    doc["families"] = [*doc["families"], "base_tilt"]
    doc["parameters"] += [{"family": "base_tilt", "parameter": f"base tilt {a}", "unit": "rad",
                           "value": 0.01, "fitted": True, "std": 1e-3,
                           "interval_95": [0.008, 0.012]} for a in ("rx", "ry")]
    tilted = tmp_path / "diagnosis" / "final-model.json"
    tilted.parent.mkdir()
    tilted.write_text(json.dumps(doc))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_model(tilted)
    said = [w for w in caught if issubclass(w.category, DataFileWarning)]
    assert any("base_tilt of the calibration are not carried" in str(w.message) for w in said)
    assert any("held rigid" in str(w.message) for w in said)
    # each points at this line, the user's call, not inside the library (it named model_file.py)
    assert {w.filename for w in said} == {__file__}


def test_a_calibrated_bearing_tilt_enters_the_compliance(calibration, tmp_path):
    """A calibration holding transversal_compliance (elbow: 2e-6 rad/(N.m) about both axes
    normal to its axis) is carried into the elastic model: its 3x3 compliance gains
    ``[r]x c (I - w w^T) [r]x^T`` (``w`` the elbow's axis from the Jacobian, ``r`` from its
    origin to the target, at the model's operating pose), 1e-9 relative."""
    robot, path = calibration
    doc = json.loads(path.read_text())
    doc["families"] = [*doc["families"], "transversal_compliance"]
    c = 2e-6
    doc["parameters"] += [{"family": "transversal_compliance",
                           "parameter": f"elbow_joint transversal compliance {i}",
                           "unit": "rad/(N.m)", "value": c, "fitted": True, "std": 1e-7,
                           "interval_95": [c - 2e-7, c + 2e-7]} for i in (1, 2)]
    tilted = tmp_path / "tilted" / "final-model.json"
    tilted.parent.mkdir()
    tilted.write_text(json.dumps(doc))
    with pytest.warns(UserWarning, match="held rigid"):
        plain, em = load_model(path), load_model(tilted)
    (tilt,) = em.links
    assert tilt.tilt and tilt.b == "elbow_joint" and tilt.stiffness == (1 / c, 1 / c)
    state = em.at(Q, np.zeros(3))
    added = (state.compliance(formulation="conventional")
             - plain.at(Q, np.zeros(3)).compliance(formulation="conventional"))
    model, data = em.robot.model, em.robot.model.createData()
    joint = model.getJointId("elbow_joint")
    pin.computeJointJacobians(model, data, state.q)
    jac = pin.getJointJacobian(model, data, joint, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
    w = jac[3:, model.joints[joint].idx_v]
    r = state.position - data.oMi[joint].translation
    skew = pin.skew(r)
    expected = skew @ (c * (np.eye(3) - np.outer(w, w))) @ skew.T
    assert np.linalg.norm(added - expected) < 1e-9 * np.linalg.norm(expected)


def test_backlash_follows_the_springs_order_and_is_named_when_left_out(calibration, tmp_path):
    """A calibration with backlash on every spring (bravo7_no_ee: joint6's compliance held at
    0, its backlash fitted): the elastic model listed the others in a set's order (joint2,
    joint4, joint3, joint5 in one run: each process its own) and dropped joint6's silently;
    now in the springs' order, and the warning on the rigid spring names its backlash."""
    _, path = calibration
    doc = json.loads(path.read_text())
    joints = list(doc["robot"]["compliant_joints"])
    doc["families"] = [*doc["families"], "backlash"]
    doc["settings"]["backlash_smoothing_torque"] = {j: 0.5 for j in reversed(joints)}
    doc["parameters"] += [{"family": "backlash", "parameter": f"{j} backlash", "unit": "rad",
                           "value": 1e-4, "fitted": True, "std": 1e-5,
                           "interval_95": [8e-5, 1.2e-4]} for j in joints]
    for row in doc["parameters"]:
        if row["parameter"] == f"{joints[-1]} compliance":
            row.update(value=0.0, fitted=False, std=None, interval_95=None)
    rigid = tmp_path / "rigid" / "final-model.json"
    rigid.parent.mkdir()
    rigid.write_text(json.dumps(doc))
    first, last = joints[0], joints[-1]  # the base joint's: the weight does not load it
    with pytest.warns(DataFileWarning, match=rf"the compliance of {first}, {last} is not "
                      rf"determined by the calibration: held rigid; backlash\({first}\), "
                      rf"backlash\({last}\) left out with them"):
        em = load_model(rigid)
    assert [e.label for e, _ in em.not_applied] == [f"backlash({j})" for j in joints[1:-1]]


def test_a_pose_model_of_another_robot_is_named_by_its_robot(calibration, capsys):
    """kx --model a pose calibration --robot another: the refusal named the calibrated robot
    by the model file's own path ("is of robot '/tmp/.../final-model.json', not 'ur5'")."""
    _, path = calibration
    assert main(["kx", "--model", str(path), "--robot", "ur5", "--wrench", "0,0,-10"]) == 2
    err = capsys.readouterr().err
    assert f"is of robot 'ur10' ({path.resolve()}), not 'ur5'" in err, err
