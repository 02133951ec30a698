"""Defaults a robot brings: its reference configuration, and a shipped robot's springs and load.

Keys of a shipped robot's ``robot.toml`` (all SI): ``q_deg`` (printed angles, deg) or ``q_SI``
(rad, m) for the coordinates, ``k_theta_SI`` for the compliant joints' springs, and
``wrench_SI`` for the load, or ``rest_q_SI`` for springs whose rest positions differ from the
configuration (the load is then the wrench that holds the target there). An example-robot-data
robot brings its reference posture (``q0``); other trees the zero pose, with the joints whose
limits exclude zero at the middle of their limits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stiffness.errors import LoopClosureError, StiffnessError, wrong_argument
from stiffness.mechanics.formulation import as_wrench
from stiffness.mechanics.ik import coordinate_limits
from stiffness.mechanics.wrench import holding_wrench
from stiffness.robot.robot import Robot
from stiffness.units import float_array


@dataclass(frozen=True)
class ReferenceConfiguration:
    """A robot's own configuration: ``coords`` (rad, m) and where it comes from (``source``, as
    the commands echo it)."""

    coords: np.ndarray
    source: str
    #: the joints the zero pose moves to the middle of their limits (empty for other sources)
    moved: tuple[str, ...] = ()

    def source_for(self, joints: list[str] | tuple[str, ...]) -> str:
        """:attr:`source` naming, of the joints moved to the middle of their limits, only those
        among ``joints`` (the coordinates a message says are held at this configuration: a
        joint read from a file is not held, wherever the reference puts it)."""
        if not self.moved:
            return self.source
        return _zero_pose_source([name for name in self.moved if name in joints])


def reference_configuration(robot: Robot) -> ReferenceConfiguration | None:
    """The configuration a robot is used at when none is given.

    In order: a shipped robot's ``q_deg`` or ``q_SI``; example-robot-data's reference posture
    (its ``q0``); for a tree, the zero pose with each joint whose limits exclude zero at the
    middle of its limits. None for a robot with closed loops or controller coordinates that
    brings no coordinates (its reference is the assembly found near the neutral pose,
    :meth:`Robot.assemble`, or zero).
    """
    if "q_deg" in robot.defaults:
        return ReferenceConfiguration(np.deg2rad(np.asarray(robot.defaults["q_deg"], dtype=float)),
                                      "robot default")
    if "q_SI" in robot.defaults:
        return ReferenceConfiguration(np.asarray(robot.defaults["q_SI"], dtype=float),
                                      "robot default")
    posture = robot.defaults.get("reference_posture")
    for entry in robot.model.referenceConfigurations if posture else ():
        if entry.key() == posture and entry.data().shape[0] == robot.model.nq:
            coords, turned = _turned_into_limits(robot, robot.coordinates_of(
                np.asarray(entry.data())))
            return ReferenceConfiguration(coords, f"robot default (example-robot-data reference "
                                                  f"posture {posture!r}{turned})")
    if not robot.loop.is_open_chain or robot.coupling is not None:
        return None
    lo, hi = coordinate_limits(robot)
    outside = (lo > 0.0) | (hi < 0.0)
    coords = np.zeros(len(lo))
    for i in np.flatnonzero(outside):  # the middle, or the one finite limit (no inf - inf)
        finite = [v for v in (lo[i], hi[i]) if np.isfinite(v)]
        coords[i] = sum(finite) / len(finite)
    if not outside.any():
        return ReferenceConfiguration(coords, "zero pose (the robot brings no configuration)")
    moved = tuple(str(name) for name in np.asarray(robot.coordinate_joints)[outside])
    return ReferenceConfiguration(coords, _zero_pose_source(list(moved)), moved)


def _zero_pose_source(moved: list[str]) -> str:
    """The source of a tree's zero-pose reference whose joints ``moved`` sit at the middle of
    their limits (those exclude zero)."""
    if not moved:
        return "zero pose"
    whose = "its" if len(moved) == 1 else "their"
    return (f"zero pose with {', '.join(moved)} at the middle of {whose} limits "
            "(zero is outside them)")


def _turned_into_limits(robot: Robot, coords: np.ndarray) -> tuple[np.ndarray, str]:
    """``coords`` with each revolute coordinate outside its limits turned by a multiple of
    2 pi into them where that fits (the same pose: kinova's posture has j2s6s200_joint_3 at
    -pi/2, its limits are [0.33, 5.95] rad), and the note saying which (empty if none)."""
    if robot.coupling is not None:
        return coords, ""
    lo, hi = coordinate_limits(robot)
    out, turned = coords.copy(), []
    for i, name in enumerate(robot.coordinate_joints):
        if robot.is_prismatic(name) or lo[i] <= coords[i] <= hi[i]:
            continue
        inside = coords[i] + 2.0 * np.pi * np.ceil((lo[i] - coords[i]) / (2.0 * np.pi))
        if inside <= hi[i]:
            out[i] = inside
            turned.append(name)
    note = f"; {', '.join(turned)} moved by whole turns into its limits" if turned else ""
    return out, note


def default_coordinates(robot: Robot) -> np.ndarray | None:
    """The coordinates (rad, m) of :func:`reference_configuration`, or None."""
    reference = reference_configuration(robot)
    return None if reference is None else reference.coords


def default_stiffness(robot: Robot) -> np.ndarray | None:
    """The shipped joint springs (N.m/rad, N/m) for the shipped compliant joints, or None."""
    if "k_theta_SI" in robot.defaults and tuple(robot.compliant_joints) == tuple(
            robot.defaults.get("compliant_joints", robot.coordinate_joints)):
        return np.asarray(robot.defaults["k_theta_SI"], dtype=float)
    return None


def joint_stiffnesses(robot: Robot, k_theta: object, name: str = "k_theta",
                      form: str = "a vector or a diagonal matrix") -> np.ndarray:
    """``k_theta`` as the user gives it (N.m/rad, N/m prismatic; a vector or a diagonal matrix)
    as one finite positive stiffness per compliant joint of ``robot`` (n_compliant,): the one
    check of joint springs, given to the Python API (``load_model``'s ``k``, ``simulate``'s
    ``kq``, ``design``'s ``k``, :class:`~stiffness.viewer.StiffnessViewer`'s ``k_theta``) or
    as the flag ``--kq`` (its numbers read by the command line first), ``name`` the argument's
    name and ``form`` how it is written, for the message.

    Raises
    ------
    StiffnessError
        ``"<name> must be one finite positive stiffness per compliant joint of <robot> (...),
        N.m/rad (N/m prismatic): <form>, got <what was given>"``, or off-diagonal terms.
    """
    needed = (f"one finite positive stiffness per compliant joint of {robot.title} "
              f"({', '.join(robot.compliant_joints)}), N.m/rad (N/m prismatic): {form}")
    k = float_array(k_theta, name, needed, finite=False)
    if k.ndim == 2 and k.shape[0] == k.shape[1]:
        if np.any(k != np.diag(np.diag(k))):  # its coupling was dropped
            raise StiffnessError(f"{name} of {robot.title} couples joints: joint springs are "
                                 "one per joint; give a vector or a diagonal matrix")
        k = np.diag(k)
    elif k.ndim > 2 or (k.ndim == 2 and min(k.shape) != 1):
        raise wrong_argument(name, k_theta, needed)
    k = k.reshape(-1)
    if k.shape[0] != robot.n_compliant or not np.all(np.isfinite(k)) or np.any(k <= 0):
        raise wrong_argument(name, k_theta, needed)
    return k


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


#: Closed loops without workspace rules: revolute coordinates within this of the reference (rad).
LOOP_SPAN_RAD = 0.5
#: ... and prismatic ones within this fraction of their reference length (at least 1 cm).
LOOP_SPAN_FRACTION = 0.05


def loop_sampling_box(robot: Robot, lo: np.ndarray, hi: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The box ``lo, hi`` (rad, m; per coordinate) to draw random poses in, narrowed for a
    closed-loop robot (whose limits say little about where it assembles: Gepetto's legs have
    none) to :data:`LOOP_SPAN_RAD` (revolute) or :data:`LOOP_SPAN_FRACTION` of the reference
    length (prismatic) around its reference assembly (:func:`assembly_coordinates`);
    unchanged for an open chain. ``design``'s candidates and ``scan --samples`` draw in it."""
    if robot.loop.is_open_chain:
        return lo, hi
    ref = assembly_coordinates(robot)
    prismatic = np.array([robot.is_prismatic(j) for j in robot.coordinate_joints])
    span = np.where(prismatic, np.maximum(LOOP_SPAN_FRACTION * np.abs(ref), 0.01),
                    LOOP_SPAN_RAD)
    return np.maximum(lo, ref - span), np.minimum(hi, ref + span)


def assembly_coordinates(robot: Robot) -> np.ndarray:
    """The coordinates (rad, m) of a robot's reference pose: :func:`default_coordinates`, else,
    for closed loops, those of the assembly found near the zero pose (:meth:`Robot.assemble`:
    Gepetto's wl16 leg closes only with its prismatic motors near -0.3 m), else zero."""
    ref = default_coordinates(robot)
    if ref is not None:
        return ref
    if robot.loop.is_open_chain:
        return np.zeros(robot.n_coordinates)
    try:
        return robot.coordinates_of(robot.assemble(None).q)
    except LoopClosureError:  # no assembly near zero: the draws will say why
        return np.zeros(robot.n_coordinates)
