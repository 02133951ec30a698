"""posture when the fixed angle it compares with is out of reach.

On Tiago (8 arm coordinates, the torso's prismatic one first) a vertical tool axis leaves the
fixed angle psi = 0 (the hand frame at the identity orientation) out of the arm's reach: the
summary printed "n/a m fixed angle (factor n/a)" and nothing said why. Now the line says the
fixed angle is out of reach and a note counts the points and names --reference-angle.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from scipy.optimize import least_squares

from stiffness.cli.main import main
from stiffness.mechanics.defaults import default_coordinates
from stiffness.robot.robot import load_robot

POSITIONS = [(0.128050, -0.931075, 0.706500), (0.175271, -0.928754, 0.722094)]
ARM = ["torso_lift_joint"] + [f"arm_{i}_joint" for i in range(1, 8)]
K = "1e6,3e4,3e4,2e4,2e4,1e4,5e3,5e3"


@pytest.fixture(scope="module")
def poses(tmp_path_factory):
    path = tmp_path_factory.mktemp("tiago") / "poses.csv"
    path.write_text("x,y,z,ax,ay,az\n" + "".join(f"{x},{y},{z},0,0,1\n" for x, y, z in POSITIONS))
    return path


def test_the_identity_hand_orientation_is_out_of_reach_there():
    """Independent check: bounded least squares over the arm's coordinates (within their
    limits) from 8 random starts leaves the pose at psi = 0 (identity rotation) unreached."""
    robot = load_robot("tiago")
    model, coords0 = robot.model, default_coordinates(robot)
    arm = [robot.coordinate_joints.index(j) for j in ARM]
    qi = [model.joints[model.getJointId(j)].idx_q for j in ARM]
    lo, hi = model.lowerPositionLimit[qi], model.upperPositionLimit[qi]

    def residual(x: np.ndarray) -> np.ndarray:
        coords = coords0.copy()
        coords[arm] = x
        pin.framesForwardKinematics(model, robot.data, robot.configuration(coords))
        pose = robot.data.oMf[robot.target_frame_id]
        return np.concatenate([pose.translation - POSITIONS[0], 0.2 * pin.log3(pose.rotation)])

    rng = np.random.default_rng(0)
    best = min(np.linalg.norm(least_squares(residual, rng.uniform(lo, hi), bounds=(lo, hi)).fun)
               for _ in range(8))
    assert best > 0.05


def test_the_summary_says_the_fixed_angle_is_out_of_reach(poses, capsys):
    code = main(["posture", "--robot", "tiago", "--kq", K, "--path", str(poses), "--wrench",
                 "0,0,-50", "--steps", "4", "--max-step", "30", "--no-refine"])
    out = capsys.readouterr().out
    assert code == 0
    assert "n/a" not in out
    assert "max deflection: " in out and "fixed angle out of reach" in out
    assert ("note: the fixed angle (0 deg) is out of reach at 2 of 2 points on the branch used"
            in out) and "--reference-angle" in out
