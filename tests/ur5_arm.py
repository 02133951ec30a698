"""The UR5 arm's three springs under random loads, and the rows' true deflections by the
conventional formula (one copy for the statistical deflection tests, whose identified model is
then the true one)."""

from __future__ import annotations

import numpy as np

from stiffness.mechanics.formulation import deflection, target_state
from stiffness.robot.robot import Robot, load_robot

ARM = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint")
K = np.array([3e4, 2e4, 1.5e4])  # N.m/rad
OFFSET = np.array([0.05, 0.0, 0.1])  # m, the target in wrist_3's axes


def arm_rows(configs: int, loads: int, rotations: bool = False
             ) -> tuple[Robot, np.ndarray, np.ndarray, np.ndarray]:
    """``configs`` random configurations x ``loads`` random forces (40-100 N) of the UR5 arm
    (seed 11): the robot, the rows' coordinates (rows, 6) and forces (rows, 3, N), and their
    true deflections ``J K^-1 J^T f`` (rows, 3, m; with ``rotations`` (rows, 6):
    [translation; rotation], m and rad)."""
    robot = load_robot("ur5", target_offset=OFFSET, compliant_joints=ARM)
    rng = np.random.default_rng(11)
    rows = slice(0, 6 if rotations else 3)
    q, force, truth = [], [], []
    for _ in range(configs):
        coords = rng.uniform(-np.pi, np.pi, 6)
        full = robot.configuration(coords)
        for _ in range(loads):
            f = rng.normal(size=3)
            f *= rng.uniform(40.0, 100.0) / np.linalg.norm(f)
            q.append(coords)
            force.append(f)
            truth.append(deflection(target_state(robot, full, f), np.diag(K), "conventional",
                                    rows=rows))
    return robot, np.array(q), np.array(force), np.array(truth)
