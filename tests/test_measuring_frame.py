"""The fitted measuring frame whole (``diagnose --json``'s ``measuring_frame`` and the text
report's line): the ``frame`` family's parameters are a correction to the starting (Kabsch)
estimate, which a hidden error biases, so a reader took "frame x = 0.32 mm" for a tracker
placement error on a campaign whose tracker sat exactly at the robot's world. The whole frame
is checked against the simulated truth, not against the fit's own parameters."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

import stiffness
from stiffness.calibration.pose_report import format_pose_report

#: The hidden tracker: rotation vector (deg), then translation (mm), as ``--effect frame=``.
FRAME = (1.0, 2.0, -3.0, 500.0, 300.0, 100.0)


def test_the_reported_measuring_frame_is_the_true_one_with_an_offset_hidden():
    robot = stiffness.load_robot("ur5")
    markers = [stiffness.Marker("tip", "tool0", np.array([0.0, 0.03, 0.05])),
               stiffness.Marker("elbow", "forearm_link", np.array([0.0, 0.05, 0.2]))]
    campaign = stiffness.simulate_poses(
        robot, markers, poses=12, noise_std_m=20e-6, seed=3,
        effects=["frame=" + ",".join(map(str, FRAME)), "joint_offsets:elbow_joint=0.3"]
    ).campaign
    d = stiffness.diagnose(campaign, families=["joint_offsets"], max_steps=0)
    frame = d.summary()["measuring_frame"]
    true_rotation = pin.exp3(np.radians(FRAME[:3]))
    turn = np.degrees(pin.log3(np.array(frame["rotation"]) @ true_rotation.T))
    assert np.linalg.norm(turn) < 2e-3  # deg: 20 um over ~1 m lever arms is ~1e-3 deg
    assert np.allclose(frame["translation"], FRAME[3:], atol=0.05)  # mm
    assert np.allclose(pin.exp3(np.radians(frame["rotation_vector_deg"])), frame["rotation"])
    corrections = {p["parameter"]: p["value"] for p in d.summary()["parameters"]
                   if p["family"] == "frame"}
    assert max(abs(corrections[f"frame {a}"]) for a in "xyz") > 1e-4  # the correction is not
    # the frame: the hidden offset biased the start by more than 0.1 mm
    report = format_pose_report(d)
    t = frame["translation"]
    assert f"t = ({t[0]:.6g}, {t[1]:.6g}, {t[2]:.6g}) mm" in report
