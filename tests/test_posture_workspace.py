"""posture judges its candidates against the robot's declared [workspace].

The SK120's robot.toml draws its measurement poses with joint1 in [-90, 90] deg, joint2 in
[-70, 70], joint3 in [-115, 35], joint4 = 0, joint5 = -90 - joint3 (so [-125, 25]) and
joint6 in {-90, 90}: its identified model is calibrated there. Pushed along x, the stiffest
branch at this point has joint1 at 143 deg, outside it; posture recommended it silently.
"""

from __future__ import annotations

import numpy as np
import pytest

from stiffness.elastic.model import ElasticModel
from stiffness.machining.posture import posture
from stiffness.robot.robot import load_robot

#: robots/sk120/robot.toml's [workspace] ranges (deg), read here independently of the code.
RANGES = {0: (-90.0, 90.0), 1: (-70.0, 70.0), 2: (-115.0, 35.0), 3: (0.0, 0.0),
          4: (-125.0, 25.0), 5: (-90.0, 90.0)}


def _inside(coords: np.ndarray) -> bool:
    deg = np.rad2deg(coords)
    ranges = all(lo - 1e-4 <= deg[i] <= hi + 1e-4 for i, (lo, hi) in RANGES.items())
    return ranges and min(abs(deg[1] + deg[2] - 90.0), abs(deg[1] + deg[2] + 90.0)) >= 15.0


@pytest.fixture(scope="module")
def sk120():
    robot = load_robot("sk120")
    return ElasticModel.joint_springs(robot, [1.4098e6, 4.0076e5, 9.3528e5])


def _run(em, point, wrench):
    return posture(em, np.array([point]), axes=np.array([[0.0, 0.0, -1.0]]), wrench=wrench,
                   steps=6, refine=False)


def test_the_path_keeps_inside_the_calibrated_workspace(sk120):
    result = _run(sk120, [-1.39, -0.95, -0.216], [300.0, 0.0, 0.0])
    p = result.points[0]
    assert _inside(p.coords) and p.outside == ()
    row = result.to_dict()["rows"][0]
    assert row["in_workspace"] is True and row["workspace_departures"] == []
    assert result.summary()["points_outside_workspace"] == 0
    # the stiffer branch set aside: outside, stiffer, and said in one line
    (note,) = [n for n in result.notes if "[workspace]" in n]
    assert "\n" not in note and "the stiffest postures leave the [workspace] of sk120" in note
    outside = [b for name, b in result.branches.items() if not _inside(b)]
    assert outside  # the search did find branches outside
    assert np.rad2deg(max(abs(b[0]) for b in outside)) > 90.0


def test_a_point_with_no_posture_inside_is_said_so(sk120):
    # behind the robot: joint1 beyond +-90 deg on every branch
    result = _run(sk120, [1.39, 0.95, -0.216], [300.0, 0.0, 0.0])
    p = result.points[0]
    assert not _inside(p.coords) and p.outside
    assert result.to_dict()["rows"][0]["in_workspace"] is False
    assert result.summary()["points_outside_workspace"] == 1
    (note,) = [n for n in result.notes if "[workspace]" in n]
    assert note.startswith("1 of 1 points have no posture inside the [workspace] of sk120")
    assert "extrapolate the model" in note


def test_a_robot_without_a_workspace_is_not_judged():
    robot = load_robot("ur5", target_offset=[0.1, 0.0, 0.1])
    em = ElasticModel.joint_springs(robot, [3e5, 3e5, 2e5, 4e4, 4e4, 4e4])
    result = posture(em, np.array([[0.45, 0.0, 0.3]]), axes=np.array([[0.0, 0.0, -1.0]]),
                     wrench=[0.0, 0.0, 300.0], steps=4, refine=False,
                     start=[0.0, -1.57, 1.57, -1.57, -1.57, 0.0])
    assert result.to_dict()["rows"][0]["in_workspace"] is None
    assert result.summary()["points_outside_workspace"] is None
    assert not [n for n in result.notes if "[workspace]" in n]


def test_ignore_workspace_takes_the_stiffest_branch_outside(sk120):
    """With ``ignore_workspace`` the SK120 point pushed along x takes the stiffest branch
    within the joint limits, branch B with joint1 at 143 deg (outside [-90, 90]), as before
    the workspace rule; its first-order deflection |C W| is about half the one inside (each
    computed here from the model at the chosen coordinates); the point is still reported
    outside, and one line says so."""
    point, wrench = [-1.39, -0.95, -0.216], [300.0, 0.0, 0.0]
    kept = _run(sk120, point, wrench).points[0]
    result = posture(sk120, np.array([point]), axes=np.array([[0.0, 0.0, -1.0]]),
                     wrench=wrench, steps=6, refine=False, ignore_workspace=True)
    free = result.points[0]
    assert free.branch == "B" and np.rad2deg(free.coords[0]) > 90.0
    assert not _inside(free.coords) and _inside(kept.coords)

    def deflection(coords: np.ndarray) -> float:
        return float(np.linalg.norm(sk120.at(coords).compliance() @ np.array(wrench)))

    assert deflection(free.coords) < 0.6 * deflection(kept.coords)
    row = result.to_dict()["rows"][0]
    assert row["in_workspace"] is False and row["workspace_departures"]
    assert result.summary()["points_outside_workspace"] == 1
    (note,) = [n for n in result.notes if "[workspace]" in n]
    assert note.startswith("1 of 1 points lie outside the [workspace] of sk120")
    assert "not judged (--ignore-workspace" in note
