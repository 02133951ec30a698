"""The identifiability section of a pose diagnosis on a branching robot: the parameters of the
joints no marker moves with are one line, not one line each (FIGAROH's TALOS right-arm campaign
printed 115 ``dropped ... no effect on the data`` lines for the legs, head and left arm)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from stiffness.calibration.identifiability import Dropped, Identifiability
from stiffness.calibration.pose_diagnose import diagnose_poses
from stiffness.calibration.pose_model import Marker
from stiffness.calibration.pose_report import NO_EFFECT_LISTED, dropped_lines, format_pose_report
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.robot import load_robot


def test_joints_off_every_marker_chain_are_one_line_naming_them():
    """Two-arm torso, one marker on the right tool, geometry forced (20 poses, 20 µm, seed 0):
    every left-arm placement and zero has no effect (the joints outside the marker's support,
    from pinocchio's ``model.supports``), the report names them in one line with their count,
    no parameter of the marker's chain is among them, and the JSON still lists each one."""
    robot = load_robot("two-arm-torso", frame="right_tcp")
    markers = [Marker("tip", "right_tcp", np.array([0.0, 0.0, 0.05]))]
    rng = np.random.default_rng(0)
    hidden = HiddenPoseErrors(pin.exp3(rng.normal(size=3)), rng.uniform(-2, 2, 3),
                              np.array([m.offset for m in markers]) + rng.normal(0, 2e-3, (1, 3)),
                              np.zeros(robot.model.nv),
                              rng.normal(0, 2e-4, (robot.model.nv, 6)))
    campaign = simulate_pose_campaign(robot, markers, hidden, 20, 20e-6, seed=0)
    found = diagnose_poses(campaign, families=["geometry"], max_steps=0)
    model = robot.model
    chain = {model.names[j] for j in
             model.supports[model.frames[model.getFrameId("right_tcp")].parentJoint]}
    off_chain = {n for n in model.names[1:] if n not in chain}
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
