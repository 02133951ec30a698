"""Simulated pose campaigns shared by several test files."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.calibration.pose_campaign import PoseCampaign, write_pose_campaign
from stiffness.calibration.pose_model import Marker
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.robot import load_robot


def ur10_markers() -> list[Marker]:
    """Two tracker markers on a UR10: on its tool and on its forearm (offsets in m)."""
    return [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05])),
            Marker("elbow", "forearm_link", np.array([0.0, 0.05, 0.2]))]


def ur10_tip_campaign(poses: int, payload_n: float | None = None) -> PoseCampaign:
    """``poses`` UR10 poses of one marker on tool0 (20 um noise, seed 2) with a hidden frame,
    marker offset, zero offsets, link geometry errors and joint springs, under a downward
    payload of ``payload_n`` (N; ``None``: no payload)."""
    robot = load_robot("ur10", frame="tool0")
    markers = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05]))]
    rng = np.random.default_rng(2)
    hidden = HiddenPoseErrors(pin.exp3(rng.normal(size=3)), rng.uniform(-2, 2, 3),
                              np.array([m.offset for m in markers]) + 2e-3,
                              rng.normal(0.0, 1e-3, 6), rng.normal(0.0, 2e-4, (6, 6)),
                              stiffness=np.array([3e5, 2e5, 1.2e5, 4e4, 3e4, 3e4]))
    payload = None if payload_n is None else np.array([0.0, 0.0, -payload_n, 0, 0, 0])
    return simulate_pose_campaign(robot, markers, hidden, poses, 20e-6, seed=2, payload=payload)


@functools.cache
def ur10_rigid_lift_campaign() -> PoseCampaign:
    """30 UR10 poses of its two markers (:func:`ur10_markers`, 20 um noise, 150 N downward
    payload, seed 3) with a hidden frame and marker offsets off by mm, joint springs, the
    shoulder lift rigid (its compliance's truth at the bound 0), no zero offsets or link
    geometry errors. Built once per test process: tests only read it (test_interval_noise and
    test_standard_error_at_bound fit it, with huber and least squares)."""
    robot = load_robot("ur10", frame="tool0")
    markers = ur10_markers()
    rng = np.random.default_rng(3)
    hidden = HiddenPoseErrors(pin.exp3(rng.normal(size=3)), rng.uniform(-2, 2, 3),
                              np.array([m.offset for m in markers])
                              + rng.normal(0, 2e-3, (2, 3)), np.zeros(6), np.zeros((6, 6)),
                              np.array([3e5, np.inf, 1.2e5, 4e4, 3e4, 3e4]))
    return simulate_pose_campaign(robot, markers, hidden, 30, 20e-6, seed=3,
                                  payload=np.array([0.0, 0.0, -150.0, 0.0, 0.0, 0.0]))


def write_ur5_tip_campaign(folder: Path) -> None:
    """A UR5 pose campaign of three poses of one marker on tool0 (10 um noise, seed 1, nothing
    hidden but the springs at 2e5 N.m/rad) written to ``folder``."""
    robot = load_robot("ur5")
    markers = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05]))]
    hidden = HiddenPoseErrors(np.eye(3), np.zeros(3), np.array([m.offset for m in markers]),
                              np.zeros(6), np.zeros((6, 6)), np.full(6, 2e5))
    write_pose_campaign(simulate_pose_campaign(robot, markers, hidden, 3, 1e-5, seed=1),
                        folder)


#: A DH arm with two prismatic joints (a vertical lift and a radial slide); ``{}`` the two
#: prismatic rows' ``lower = 0.0`` (TOML inline tables hold to one line).
PRISM_ARM = """name = "prism-arm"
frame = "tool"
[dh]
convention = "standard"
length_unit = "m"
angle_unit = "deg"
joints = [
  { name = "j1", alpha = 0, a = 0.0, theta = 0, d = 0.4, lower = -170, upper = 170 },
  { name = "j2", type = "prismatic", alpha = -90, a = 0.1, theta = 0, d = 0.3, {}upper = 0.5 },
  { name = "j3", alpha = 90, a = 0.4, theta = 0, d = 0.0, lower = -120, upper = 120 },
  { name = "j4", type = "prismatic", alpha = -90, a = 0.0, theta = 0, d = 0.2, {}upper = 0.3 },
  { name = "j5", alpha = 0, a = 0.15, theta = 0, d = 0.0, lower = -150, upper = 150 },
]
tool = { xyz = [0.0, 0.0, 0.05], rpy = [0.0, 0.0, 0.0] }
links = [
  { mass = 8.0, com = [0.0, 0.0, -0.1] },
  { mass = 6.0, com = [-0.05, 0.0, 0.0] },
  { mass = 5.0, com = [-0.2, 0.0, 0.0] },
  { mass = 3.0, com = [0.0, 0.0, -0.1] },
  { mass = 1.5, com = [-0.07, 0.0, 0.0] },
]
""".replace("{}", "lower = 0.0, ")


#: The tracker's motion between the two days of :func:`ur10_two_days`: a turn (rotation
#: vector, rad) and a shift (m).
TWO_DAYS_TURN = np.radians(4.0) * np.array([0.6, 0.0, 0.8])
TWO_DAYS_SHIFT = np.array([0.03, -0.01, 0.005])


def ur10_two_days(noise: float) -> tuple[PoseCampaign, PoseCampaign]:
    """Day A (30 poses, seed 5) and day B (15 poses, seed 6) of a UR10's two markers
    (:func:`ur10_markers`, ``noise`` m): the same hidden marker and zero offsets, the
    measuring frame moved rigidly between them (``D = exp(TWO_DAYS_TURN)``,
    ``d = TWO_DAYS_SHIFT``)."""
    robot = load_robot("ur10", frame="tool0")
    markers = ur10_markers()
    rng = np.random.default_rng(5)
    rotation, translation = pin.exp3(rng.normal(size=3)), rng.uniform(-2, 2, 3)
    offsets = np.array([m.offset for m in markers]) + rng.normal(0, 2e-3, (2, 3))
    zeros = rng.normal(0.0, 1e-3, 6)
    day_a = simulate_pose_campaign(
        robot, markers, HiddenPoseErrors(rotation, translation, offsets, zeros,
                                         np.zeros((6, 6))), 30, noise, seed=5)
    motion = pin.exp3(TWO_DAYS_TURN)
    day_b = simulate_pose_campaign(
        robot, markers, HiddenPoseErrors(motion @ rotation, motion @ translation
                                         + TWO_DAYS_SHIFT, offsets, zeros, np.zeros((6, 6))),
        15, noise, seed=6)
    return day_a, day_b
