"""stiffness: elastostatics of robot manipulators on Pinocchio.

Load a robot (URDF, example-robot-data name or a shipped robot, closed loops included), then
compute its Jacobian, complementary stiffness K_C, compliance and Cartesian stiffness with and
without the load-dependent term, and the exact elastostatic equilibrium; evaluate many
configurations at once, scan a workspace, identify joint stiffness from measurements and find
what a model misses, and draw stiffness ellipsoids. SI units throughout (m, N, rad, N.m/rad).

The main functions and classes of every layer are here (see docs/architecture.md), not their
low-level helpers (those stay in their modules): the robot and mechanics are imported with the
package; the batch, workspace, calibration, planning, machining, papers and viewer entries are
imported on first use (they bring SciPy's optimisers, matplotlib, meshcat). The workflow
commands are functions here too: ``identify``, ``diagnose``, ``simulate``, ``design``,
``compensate``, ``posture``, ``track`` and ``scan`` take Python objects (SI) and return results
whose ``.to_dict()`` is the command's ``--json`` object; the result classes
(``Identification``, ``Diagnosis``, ``PoseDiagnosis``, ``Validation``...), the models
(``ElasticModel``, ``PoseModel``) and every error and warning the package raises
(``StiffnessError`` and its subclasses) are here too.

Example::

    import numpy as np
    import stiffness

    robot = stiffness.load_robot("sk120")
    q = robot.configuration(np.deg2rad(robot.defaults["q_deg"]))   # printed angles, loop closed
    state = stiffness.target_state(robot, q, load=[45.5, 364.5, 211.3])   # N, base axes
    k_theta = np.diag(robot.defaults["k_theta_SI"])                 # N.m/rad
    c_x = stiffness.compliance(state.jacobian[:3], k_theta - state.k_c)   # m/N
"""

#: The package version (the single source: pyproject.toml reads it from here).
__version__ = "0.1.0"

import importlib

from stiffness.errors import (
    ConvergenceError,
    DataFileNote,
    DataFileWarning,
    FileFormatError,
    FlagValueWarning,
    FloatingBaseError,
    LoopClosureError,
    MissingFileError,
    OutputError,
    RobotFileError,
    RobotFileNote,
    RobotFileWarning,
    SingularConfigurationError,
    StiffnessError,
    TooFewMeasurementsError,
    UndeterminedMotionError,
    UnknownColumnWarning,
    UnknownEffectError,
    UnknownFrameError,
    UnknownJointError,
    UnknownNameError,
    UnknownRobotError,
    UnstableEquilibriumError,
)
from stiffness.mechanics.defaults import default_coordinates, default_load, default_stiffness
from stiffness.mechanics.equilibrium import Equilibrium, solve_equilibrium
from stiffness.mechanics.formulation import (
    TargetState,
    cartesian_stiffness,
    compliance,
    definiteness,
    deflection,
    ellipsoid,
    joint_connection_stiffness,
    joint_stiffness,
    target_state,
    target_states,
    twist_basis_stiffness,
    work_balance,
)
from stiffness.mechanics.platform import platform_stiffness, solve_pose
from stiffness.mechanics.wrench import holding_wrench
from stiffness.robot.robot import Robot, load_robot
from stiffness.robot.sources import shipped_robots

#: Entries of the upper layers, imported on first use: name -> module defining it.
_ON_FIRST_USE = {
    # batch: many configurations at once
    "batch_kinematics": "stiffness.batch.kernels",
    "close_loops": "stiffness.batch.loops",
    "definiteness_map": "stiffness.batch.kernels",
    # workspace: workspace maps (scan: the command `stiffness scan` as a function)
    "ScanSpec": "stiffness.workspace.engine",
    "run_scan": "stiffness.workspace.engine",
    "load_scan": "stiffness.workspace.engine",
    "scan": "stiffness.workspace.request",
    "ScanResult": "stiffness.workspace.request",
    # calibration: campaigns, identification, diagnosis, and their results and errors
    "Campaign": "stiffness.calibration.campaign",
    "CampaignKindError": "stiffness.calibration.campaign",
    "load_campaign": "stiffness.calibration.campaign",
    "identify": "stiffness.calibration.identify",
    "Identification": "stiffness.calibration.identification",
    "diagnose": "stiffness.calibration.diagnose",
    "Diagnosis": "stiffness.calibration.diagnosis",
    # calibration from absolute poses (docs/absolute-poses.md)
    "Marker": "stiffness.calibration.pose_model",
    "PoseCampaign": "stiffness.calibration.pose_campaign",
    "load_pose_campaign": "stiffness.calibration.pose_campaign",
    "write_pose_campaign": "stiffness.calibration.pose_campaign",
    "PoseModel": "stiffness.calibration.pose_model",
    "PoseModelError": "stiffness.calibration.pose_model",
    "LoopGeometryError": "stiffness.calibration.pose_loops",
    "diagnose_poses": "stiffness.calibration.pose_diagnose",
    "PoseDiagnosis": "stiffness.calibration.pose_diagnosis",
    "PoseIdentification": "stiffness.calibration.pose_identify",
    "validate": "stiffness.calibration.validation",
    "Validation": "stiffness.calibration.validation",
    # planning: synthetic campaigns, experiment design
    "simulate": "stiffness.planning.simulate",
    "Simulation": "stiffness.planning.simulate",
    "HiddenPoseErrors": "stiffness.planning.simulate_poses",
    "simulate_pose_campaign": "stiffness.planning.simulate_poses",
    "simulate_poses": "stiffness.planning.pose_simulation",
    "PoseSimulation": "stiffness.planning.pose_simulation",
    "design": "stiffness.planning.design",
    "DesignResult": "stiffness.planning.design",
    # machining: compensation along a path, the stiffest posture
    "ElasticModel": "stiffness.elastic.model",
    "ElasticState": "stiffness.elastic.state",
    "load_model": "stiffness.elastic.model_file",
    "ModelFileError": "stiffness.elastic.model_contents",
    "ModelRobotError": "stiffness.elastic.model_contents",
    "compensate": "stiffness.machining.compensation",
    "PathCompensation": "stiffness.machining.compensation",
    "posture": "stiffness.machining.posture",
    "PostureResult": "stiffness.machining.posture",
    "track": "stiffness.machining.tracking",
    "Tracking": "stiffness.machining.tracking",
    # papers: the SK120 reproduction
    "build_report": "stiffness.papers.report",
    # viewer: stiffness ellipsoids in the browser
    "StiffnessViewer": "stiffness.viewer",
}


def __getattr__(name: str):
    """Import an upper-layer entry of :data:`__all__` on first use."""
    module = _ON_FIRST_USE.get(name)
    if module is None:
        raise AttributeError(f"module 'stiffness' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_ON_FIRST_USE))


__all__ = [
    "Campaign",
    "CampaignKindError",
    "ConvergenceError",
    "DataFileNote",
    "DataFileWarning",
    "DesignResult",
    "Diagnosis",
    "ElasticModel",
    "ElasticState",
    "Equilibrium",
    "FileFormatError",
    "FlagValueWarning",
    "FloatingBaseError",
    "HiddenPoseErrors",
    "Identification",
    "LoopClosureError",
    "LoopGeometryError",
    "Marker",
    "MissingFileError",
    "ModelFileError",
    "ModelRobotError",
    "OutputError",
    "PathCompensation",
    "PoseCampaign",
    "PoseDiagnosis",
    "PoseIdentification",
    "PoseModel",
    "PoseModelError",
    "PoseSimulation",
    "PostureResult",
    "Robot",
    "RobotFileError",
    "RobotFileNote",
    "RobotFileWarning",
    "ScanResult",
    "ScanSpec",
    "Simulation",
    "SingularConfigurationError",
    "StiffnessError",
    "StiffnessViewer",
    "TargetState",
    "Tracking",
    "TooFewMeasurementsError",
    "UndeterminedMotionError",
    "UnknownColumnWarning",
    "UnknownEffectError",
    "UnknownFrameError",
    "UnknownJointError",
    "UnknownNameError",
    "UnknownRobotError",
    "UnstableEquilibriumError",
    "Validation",
    "__version__",
    "batch_kinematics",
    "build_report",
    "cartesian_stiffness",
    "close_loops",
    "compensate",
    "compliance",
    "default_coordinates",
    "default_load",
    "default_stiffness",
    "definiteness",
    "definiteness_map",
    "deflection",
    "design",
    "diagnose",
    "diagnose_poses",
    "ellipsoid",
    "holding_wrench",
    "identify",
    "joint_connection_stiffness",
    "joint_stiffness",
    "load_campaign",
    "load_model",
    "load_pose_campaign",
    "load_robot",
    "load_scan",
    "platform_stiffness",
    "posture",
    "run_scan",
    "scan",
    "shipped_robots",
    "simulate",
    "simulate_pose_campaign",
    "simulate_poses",
    "solve_equilibrium",
    "solve_pose",
    "target_state",
    "target_states",
    "track",
    "twist_basis_stiffness",
    "validate",
    "work_balance",
    "write_pose_campaign",
]
