"""Defaults a shipped robot brings in its ``robot.toml``: configuration, springs and load.

Keys (all SI): ``q_deg`` (printed angles, deg) or ``q_SI`` (rad, m) for the coordinates,
``k_theta_SI`` for the compliant joints' springs, and ``wrench_SI`` for the load, or
``rest_q_SI`` for springs whose rest positions differ from the configuration (the load is then
the wrench that holds the target there).
"""

from __future__ import annotations

import numpy as np

from stiffness.mechanics.formulation import as_wrench
from stiffness.mechanics.wrench import holding_wrench
from stiffness.robot.robot import Robot


def default_coordinates(robot: Robot) -> np.ndarray | None:
    """The shipped coordinates (rad, m), or None when the robot brings none."""
    if "q_deg" in robot.defaults:
        return np.deg2rad(np.asarray(robot.defaults["q_deg"], dtype=float))
    if "q_SI" in robot.defaults:
        return np.asarray(robot.defaults["q_SI"], dtype=float)
    return None


def default_stiffness(robot: Robot) -> np.ndarray | None:
    """The shipped joint springs (N.m/rad, N/m) for the shipped compliant joints, or None."""
    if "k_theta_SI" in robot.defaults and tuple(robot.compliant_joints) == tuple(
            robot.defaults.get("compliant_joints", robot.coordinate_joints)):
        return np.asarray(robot.defaults["k_theta_SI"], dtype=float)
    return None


def default_load(robot: Robot, q: np.ndarray, k_theta: np.ndarray
                 ) -> tuple[np.ndarray, str] | None:
    """The shipped load at ``q`` and where it comes from, or None.

    The load is a force (3,) in N or a wrench (6,) [F (N); M (N.m)], base axes:

    ``wrench_SI``, else the wrench holding the target at ``q`` against springs at rest at
    ``rest_q_SI``.
    """
    if "wrench_SI" in robot.defaults:
        return as_wrench(robot.defaults["wrench_SI"])[: len(robot.defaults["wrench_SI"])], \
            "wrench_SI"
    if "rest_q_SI" in robot.defaults:
        load = holding_wrench(robot, q, k_theta, robot.defaults["rest_q_SI"])
        return as_wrench(load), "rest_q_SI (wrench holding the target against the springs)"
    return None
