"""A simulated pose campaign on a robot with closed loops draws again a pose whose truth (the
links at the hidden zero offsets) does not assemble: the commanded assembly reaches it near a
fold the offsets take past. Gepetto's digit_like with 0.5 deg on motor_knee stopped on 'the
kinematic loop does not close' at seeds 2 and 3 of 20 poses; here a non-Grashof four-bar's
crank drawn 0.01 rad inside its fold, with a 0.05 rad offset, checked by the closed form."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import TRIPLE_ROCKER, four_bar_closed_form, write_four_bar

from stiffness.calibration.pose_model import Marker
from stiffness.planning.pose_simulation import hidden_pose_errors
from stiffness.planning.simulate_poses import _truth_reachable, true_model
from stiffness.robot.robot import load_robot

OFFSET_RAD = 0.05


def _fold(a: float, b: float, c: float, d: float) -> float:
    """The crank angle (rad, in (0, pi)) where the crank end is b + c from the rocker pivot:
    the loop's fold, beyond which it does not close (law of cosines)."""
    return math.acos((a * a + d * d - (b + c) ** 2) / (2 * a * d))


def test_a_pose_whose_truth_is_past_a_fold_is_drawn_again(tmp_path):
    bar = write_four_bar(tmp_path, "rockers", **TRIPLE_ROCKER)
    robot = load_robot(bar.urdf, frame="tool_tip")
    assert robot.coordinate_joints == ("crank_joint", "tool_joint")
    fold = _fold(**TRIPLE_ROCKER)
    markers = [Marker("tip", "tool_tip", np.zeros(3))]
    hidden = hidden_pose_errors(robot, markers, [f"joint_offsets:crank_joint={OFFSET_RAD}"])
    assert hidden.joint_offsets[0] == pytest.approx(OFFSET_RAD)
    near, far = np.array([fold - 0.01, 0.2]), np.array([0.3, -0.4])
    four_bar_closed_form(near[0], **TRIPLE_ROCKER)  # the commanded pose closes
    with pytest.raises(ValueError):  # its truth, the crank 0.05 rad further, does not
        four_bar_closed_form(near[0] + OFFSET_RAD, **TRIPLE_ROCKER)
    q = _truth_reachable(robot, true_model(robot, hidden), hidden, np.array([far, near]),
                         np.random.default_rng(0))
    np.testing.assert_array_equal(q[0], far)  # a pose whose truth closes is kept
    assert not np.array_equal(q[1], near)
    four_bar_closed_form(q[1][0] + OFFSET_RAD, **TRIPLE_ROCKER)  # the one drawn closes
