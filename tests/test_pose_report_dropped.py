"""A pose diagnosis and its validation on a branching robot: the parameters of the joints no
marker moves with are one line of the identifiability section, not one line each, and not
"taken as exact" in the validation's verdict (FIGAROH's TALOS right-arm campaign printed 115
``dropped ... no effect on the data`` lines, and ``validate`` named 26 zero offsets of the legs,
head and left arm as parameters its fit did not determine)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from stiffness.calibration.identifiability import Dropped, Identifiability
from stiffness.calibration.pose_campaign import write_pose_campaign
from stiffness.calibration.pose_diagnose import diagnose_poses
from stiffness.calibration.pose_model import Marker
from stiffness.calibration.pose_model_file import write_pose_model
from stiffness.calibration.pose_report import NO_EFFECT_LISTED, dropped_lines, format_pose_report
from stiffness.calibration.validation import validate
from stiffness.calibration.validation_page import format_validation
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.robot import load_robot


def _right_arm(poses: int, seed: int, families: list[str]):
    """A two-arm torso campaign (one marker on the right tool, 20 µm, placement errors of
    0.2 mm/mrad) diagnosed with ``families`` forced; the joints off the marker's chain
    (pinocchio's ``model.supports``)."""
    robot = load_robot("two-arm-torso", frame="right_tcp")
    markers = [Marker("tip", "right_tcp", np.array([0.0, 0.0, 0.05]))]
    rng = np.random.default_rng(0)
    hidden = HiddenPoseErrors(pin.exp3(rng.normal(size=3)), rng.uniform(-2, 2, 3),
                              np.array([m.offset for m in markers]) + rng.normal(0, 2e-3, (1, 3)),
                              np.zeros(robot.model.nv),
                              rng.normal(0, 2e-4, (robot.model.nv, 6)))
    campaign = simulate_pose_campaign(robot, markers, hidden, poses, 20e-6, seed=seed)
    model = robot.model
    chain = {model.names[j] for j in
             model.supports[model.frames[model.getFrameId("right_tcp")].parentJoint]}
    found = diagnose_poses(campaign, families=families, max_steps=0)
    return campaign, found, {n for n in model.names[1:] if n not in chain}


def test_joints_off_every_marker_chain_are_one_line_naming_them():
    """Two-arm torso, one marker on the right tool, geometry forced (20 poses, 20 µm, seed 0):
    every left-arm placement and zero has no effect (the joints outside the marker's support,
    from pinocchio's ``model.supports``), the report names them in one line with their count,
    no parameter of the marker's chain is among them, and the JSON still lists each one."""
    _, found, off_chain = _right_arm(20, 0, ["geometry"])
    none = [d["parameter"] for d in found.to_dict()["identifiability"]["dropped"]
            if d["reason"] == "no effect"]
    assert len(none) > NO_EFFECT_LISTED
    assert {name.split(" ")[0] for name in none} == off_chain
    report = format_pose_report(found).splitlines()
    assert not [line for line in report if line.endswith("no effect on the data")]
    (line,) = [line for line in report if line.startswith(f"  dropped {len(none)} parameters")]
    assert f"of {len(off_chain)} joints or frames" in line
    named = line.split("moves with them): ")[1].split(" (each")[0].split(" and ")[0].split(", ")
    assert set(named) <= off_chain and len(named) == min(8, len(off_chain))


def test_a_few_parameters_without_effect_keep_a_line_each():
    """At most :data:`NO_EFFECT_LISTED` without effect: each its own line, as before; one more
    and they are one line, the merged ones still one line each."""
    labels = [f"j{i} zero" for i in range(10)] + ["frame x"]
    few = Identifiability([0], [Dropped(i, "no effect") for i in range(1, NO_EFFECT_LISTED + 1)])
    assert dropped_lines(few, labels)[1:] == [
        f"  dropped j{i} zero: no effect on the data" for i in range(1, NO_EFFECT_LISTED + 1)]
    many = Identifiability([0], [Dropped(i, "no effect") for i in range(1, 9)]
                           + [Dropped(10, "merged", ((0, 2.0),))])
    lines = dropped_lines(many, labels)
    assert lines[1] == ("  dropped 8 parameters of 8 joints or frames: no effect on the data "
                        "(nothing measured moves with them): j1, j2, j3, j4, j5, j6, j7, j8 "
                        "(each one in --json)")
    assert lines[2:] == ["  merged frame x: merged: acts on the data as 2 x j0 zero (SI units, "
                         "per unit of it)"]


def test_validation_does_not_name_parameters_that_move_nothing_as_taken_as_exact(tmp_path):
    """Two-arm torso, joint zero offsets fitted on 20 poses (seed 0), validated on 10 others
    (seed 1): the left arm's zero offsets (no effect on either campaign) are not among the
    parameters the verdict says were taken as exact, and the text does not name them."""
    campaign, found, off_chain = _right_arm(20, 0, ["joint_offsets"])
    path = write_pose_model(found.final, campaign, tmp_path / "final-model.json")
    held, _, _ = _right_arm(10, 1, ["joint_offsets"])
    write_pose_campaign(held, tmp_path / "held")
    result = validate(path, tmp_path / "held").to_dict()
    left = result["parameter_uncertainty"]["left_out"]
    assert not {name.split(" ")[0] for name in left} & off_chain, left
    text = format_validation(result)
    assert not [joint for joint in off_chain if joint in text]
