"""stiffness: elastostatics of robot manipulators on Pinocchio.

Load a robot (URDF, example-robot-data name or a shipped robot, closed loops included), then
compute its Jacobian, complementary stiffness K_C, compliance and Cartesian stiffness with and
without the load-dependent term, and the exact elastostatic equilibrium. SI units throughout.

Example::

    import numpy as np
    import stiffness

    robot = stiffness.load_robot("sk120")
    q = robot.configuration(np.deg2rad(robot.defaults["q_deg"]))   # printed angles, loop closed
    state = stiffness.target_state(robot, q, load=[45.5, 364.5, 211.3])   # N, base axes
    k_theta = np.diag(robot.defaults["k_theta_SI"])                 # N.m/rad
    c_x = stiffness.compliance(state.jacobian[:3], k_theta - state.k_c)   # m/N
"""

from stiffness.calibration.compensation import ElasticModel, compensate
from stiffness.calibration.posture import posture
from stiffness.errors import SingularConfigurationError, StiffnessError
from stiffness.mechanics.equilibrium import solve_equilibrium
from stiffness.mechanics.formulation import (
    cartesian_stiffness,
    compliance,
    definiteness,
    ellipsoid,
    joint_connection_stiffness,
    joint_stiffness,
    target_state,
    target_states,
    twist_basis_stiffness,
    work_balance,
)
from stiffness.model.robot import Robot, load_robot

__all__ = [
    "ElasticModel",
    "Robot",
    "SingularConfigurationError",
    "StiffnessError",
    "cartesian_stiffness",
    "compensate",
    "compliance",
    "definiteness",
    "ellipsoid",
    "joint_connection_stiffness",
    "joint_stiffness",
    "load_robot",
    "posture",
    "solve_equilibrium",
    "target_state",
    "target_states",
    "twist_basis_stiffness",
    "work_balance",
]
