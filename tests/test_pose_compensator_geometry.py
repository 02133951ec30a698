"""A pose campaign's compensators with a declared geometry (``diagnose --compensator-geometry``,
issue 35: the same options for both campaign kinds): the declared lever and base reach the
pose model, the fit and the model file. Checked by the compensator's scaling law: lengths
scaled by ``s`` with the stiffness and tension scaled by ``1/s^2`` and ``1/s`` give the same
torque at every angle, so a fit with doubled lengths finds a quarter of the stiffness and half
the tension."""

from __future__ import annotations

import json

import numpy as np
import pytest

from stiffness.calibration.pose_campaign import write_pose_campaign
from stiffness.calibration.pose_diagnose import diagnose_poses
from stiffness.calibration.pose_fit import campaign_settings, rows_of
from stiffness.calibration.pose_model import Marker, PoseModel
from stiffness.cli.diagnose import compensator_geometry
from stiffness.cli.main import main
from stiffness.elastic.effects.preloads import COMPENSATOR_GEOMETRY, GravityCompensator
from stiffness.errors import StiffnessError
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.robot import load_robot

MARKERS = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05])),
           Marker("elbow", "forearm_link", np.array([0.0, 0.05, 0.2]))]
STIFFNESS = np.array([3e5, 2e5, 1.2e5, 4e4, 3e4, 3e4])  # N.m/rad
SPRING = np.array([5e3, 800.0])  # N/m, N: the shoulder's compensator
JOINT = "shoulder_lift_joint"
DOUBLED = {f"gravity_compensator({JOINT})": {
    "lever_m": 2 * float(COMPENSATOR_GEOMETRY["lever_m"]),
    "base_m": 2 * float(COMPENSATOR_GEOMETRY["base_m"])}}
FAMILIES = ["joint_compliance", "gravity_compensator"]


@pytest.fixture(scope="module")
def campaign():
    """20 poses of a UR10 carrying 150 N, its shoulder compensated by a spring of the
    library's geometry, the measuring frame and markers at their nominal placement."""
    robot = load_robot("ur10", frame="tool0")
    hidden = HiddenPoseErrors(np.eye(3), np.zeros(3), np.array([m.offset for m in MARKERS]),
                              np.zeros(6), np.zeros((6, 6)), STIFFNESS,
                              compensator={JOINT: SPRING})
    return simulate_pose_campaign(robot, MARKERS, hidden, 20, 20e-6, seed=3,
                                  payload=np.array([0.0, 0.0, -150.0, 0.0, 0.0, 0.0]))


def test_declared_lengths_follow_the_scaling_law(campaign):
    """The model with doubled lengths and (k/4, F0/2) predicts what the default one predicts
    with (k, F0), to round-off; with (k, F0) it does not."""
    families = ("frame", "markers", *FAMILIES)

    def predict(settings: dict, spring: np.ndarray) -> np.ndarray:
        model = PoseModel(campaign.robot, MARKERS, families, (np.eye(3), np.zeros(3)),
                          campaign.loads, {**campaign_settings(campaign), **settings})
        x = np.zeros(model.size)
        labels = [p.label for p in model.parameters]
        for joint, k in zip(campaign.robot.compliant_joints, STIFFNESS, strict=True):
            x[labels.index(f"{joint} compliance")] = 1.0 / k
        x[labels.index(f"{JOINT} compensator stiffness")] = spring[0]
        x[labels.index(f"{JOINT} compensator preload")] = spring[1]
        return model.evaluate(x, rows_of(model, campaign), jacobian=False)[0]

    doubled = {GravityCompensator.GEOMETRY_SETTING: {
        JOINT: DOUBLED[f"gravity_compensator({JOINT})"]}}
    default = predict({}, SPRING)
    assert np.abs(predict(doubled, SPRING / [4.0, 2.0]) - default).max() < 1e-10
    assert np.abs(predict(doubled, SPRING) - default).max() > 1e-4


def test_a_fit_with_doubled_lengths_and_its_model_file(campaign, tmp_path, capsys):
    """Diagnosed with the lengths doubled (--compensator-geometry, which reaches
    :func:`diagnose_poses` as its ``effect_settings``), the fit finds the spring scaled by the
    law (each within its 95 % interval, read from the written diagnosis: one diagnosis, not
    one through the API and the same again through the command), the model file keeps the
    geometry and the elastic model read from it carries it; a joint without a compensator is
    refused."""
    folder = tmp_path / "poses"
    write_pose_campaign(campaign, folder)
    lever, base = DOUBLED[f"gravity_compensator({JOINT})"].values()
    assert compensator_geometry([f"{JOINT}={lever},{base}"]) == DOUBLED
    assert main(["diagnose", str(folder), "--families", ",".join(FAMILIES), "--max-steps", "0",
                 "--compensator-geometry", f"{JOINT}={lever},{base}", "--quiet", "--out",
                 str(tmp_path / "out")]) == 0
    capsys.readouterr()
    diagnosis = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    table = {p["parameter"]: p for p in diagnosis["parameters"]}
    for what, true in zip(("stiffness", "preload"), SPRING / [4.0, 2.0], strict=True):
        low, high = table[f"{JOINT} compensator {what}"]["interval_95"]
        assert low <= true <= high, (what, low, true, high)
    model = json.loads((tmp_path / "out" / "final-model.json").read_text())
    assert model["settings"][GravityCompensator.GEOMETRY_SETTING] == {
        JOINT: {"lever_m": lever, "base_m": base}}
    from stiffness import load_model

    elastic = load_model(tmp_path / "out" / "final-model.json")
    lengths = {j: (g["lever_m"], g["base_m"]) for j, _, _, g in elastic.compensators}
    assert lengths.pop(JOINT) == (lever, base)  # the others keep the library's
    assert set(lengths.values()) <= {(COMPENSATOR_GEOMETRY["lever_m"],
                                      COMPENSATOR_GEOMETRY["base_m"])}
    with pytest.raises(StiffnessError, match="revolute compliant joint"):
        diagnose_poses(campaign, max_steps=0,
                       effect_settings={"gravity_compensator(nowhere)": {"lever_m": 0.1}})
