"""The robot's own weight as a joint preload: torque and its configuration derivative.

The links' weight (URDF inertias, ``model.gravity``), optionally plus a point payload fixed to
the target frame, acts on the compliant joints as the torque ``tau_g(q) = -g(q)`` (``g`` the
generalised gravity of ``M qdd + C + g = tau``), and its derivative
``K_g = d tau_g / d theta = -dg/dq`` plays the part of ``K_C`` for that load: the joints are in
equilibrium under ``K dtheta = J^T W + tau_g(theta)``, linearised ``tau_g(theta_0) + K_g dtheta``.
Both come from Pinocchio's analytical ``computeGeneralizedGravity`` and
``computeGeneralizedGravityDerivatives``. Open chains only: in a closed loop the passive joints'
weight would have to be carried through the loop's constraint (not implemented; a typed error).

A spring gravity compensator on a revolute joint (:func:`compensator_torque`) measures its angle
from the link's upward direction at zero load (:func:`upward_angle`): the joint angle at which
the centre of mass of everything the joint carries lies straight above its axis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from stiffness.errors import StiffnessError
from stiffness.mechanics.formulation import compliant_projection
from stiffness.robot.robot import Robot


def require_open_chain(robot: Robot, what: str = "gravity effects") -> None:
    """Raise a one-line :class:`StiffnessError` when ``robot`` has closed loops."""
    if not robot.loop.is_open_chain:
        raise StiffnessError(f"{what} need an open chain; {robot.title} has closed loops (the "
                             "weight of passive loop joints is not modelled); drop the effect")


def with_payload(robot: Robot, mass: float, com: np.ndarray) -> pin.Model:
    """A copy of ``robot.model`` with a point ``mass`` (kg) at ``com`` (m, target frame axes,
    from the target point) fixed to the target frame's parent joint."""
    model = pin.Model(robot.model)
    frame = model.frames[robot.target_frame_id]
    lever = frame.placement.act(np.asarray(com, dtype=float))
    model.appendBodyToJoint(frame.parentJoint,
                            pin.Inertia(float(mass), lever, np.zeros((3, 3))), pin.SE3.Identity())
    return model


def gravity_preload(robot: Robot, q: np.ndarray, model: pin.Model | None = None,
                    columns: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Gravity torque on the compliant joints and its derivative at the configuration ``q``.

    Parameters
    ----------
    robot
        An open-chain robot.
    q
        Full configuration.
    model
        The model to weigh (default ``robot.model``; :func:`with_payload` adds a payload).
    columns
        Velocity indices of the joints (default: the compliant joints, each with its mimic
        followers or through the ``[controller]`` coupling: ``compliant_projection``).

    Returns
    -------
    tau, k_g
        ``-g(q)`` (n,) N.m (N for prismatic joints) and ``-dg/dq`` (n, n) N.m/rad.
    """
    require_open_chain(robot)
    model = robot.model if model is None else model
    data = robot.data if model is robot.model else model.createData()
    if columns is None:
        e = compliant_projection(robot)
    else:
        e = np.eye(model.nv)[:, np.asarray(columns, dtype=int)]
    g = np.array(pin.computeGeneralizedGravity(model, data, q))
    dg = np.array(pin.computeGeneralizedGravityDerivatives(model, data, q))
    return -(e.T @ g), -(e.T @ dg @ e)


#: Gravity parameters of a link in Pinocchio's order (mass, then the mass moments m c_x, m c_y,
#: m c_z in the link's joint frame; kg, kg.m): the weight's torque is linear in them.
GRAVITY_PARAMETERS = ("m", "mcx", "mcy", "mcz")


def weighed_bodies(robot: Robot) -> list[int]:
    """The bodies (joint ids) whose weight loads a compliant joint: those with a compliant
    rate (:func:`compliant_projection`) among the joints supporting them."""
    model, e = robot.model, compliant_projection(robot)
    moving = np.flatnonzero(np.any(e != 0.0, axis=1))
    return [k for k in range(1, model.njoints)
            if any(model.joints[j].idx_v in moving for j in model.supports[k] if j > 0)]


def spring_balancer(theta: float | np.ndarray, stiffness: float, preload: float, lever_m: float,
                    base_m: float, angle0: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Torque of a spring gravity compensator on its joint and the torque's angle derivative.

    A spring runs from a point on the base side, ``base_m`` from the joint axis, to a point on
    the link's lever, ``lever_m`` from the axis; ``phi = theta + angle0`` is the angle between
    the two at the axis, ``theta`` the joint's angle from its reference pose (the link straight
    up, :func:`compensator_torque`; ``angle0`` the angle there). Its length and force are

    ``L^2 = a^2 + d^2 - 2 a d cos(phi)``, ``F = F_0 + k_s (L - L(theta = 0))``

    (``a = lever_m``, ``d = base_m``, ``k_s = stiffness`` N/m, ``F_0 = preload`` N, the tension
    at the reference pose). The torque on the joint and its derivative are

    ``tau_s = -F L'``, ``d tau_s / d theta = -(k_s L'^2 + F L'')``, with ``L L' = a d sin(phi)``
    and ``L'^2 + L L'' = a d cos(phi)``,

    so ``k_s L'^2 + F L''`` adds to the joint's stiffness.

    Parameters
    ----------
    theta
        Joint angles from the reference pose (rad), any shape.

    Returns
    -------
    tau, dtau
        Torque (N.m) and its derivative (N.m/rad), shaped like ``theta``.
    """
    a, d = float(lever_m), float(base_m)
    phi = np.asarray(theta, dtype=float) + angle0
    length = np.sqrt(a * a + d * d - 2.0 * a * d * np.cos(phi))
    length0 = np.sqrt(a * a + d * d - 2.0 * a * d * np.cos(angle0))
    d1 = a * d * np.sin(phi) / length
    d2 = (a * d * np.cos(phi) - d1 ** 2) / length
    force = preload + stiffness * (length - length0)
    return -force * d1, -(stiffness * d1 ** 2 + force * d2)


#: Where a compensator's angle is measured from: the link's upward direction at zero load, or
#: the joint's zero where the model has no upward direction (:func:`upward_angle`).
ANGLE_REFERENCES = ("upward", "joint_zero")
#: Below this (m) the carried centre of mass is on the joint's axis.
COM_ON_AXIS_M = 1e-6
#: Below this sine the joint's axis is parallel to gravity (no direction is up).
AXIS_ALONG_GRAVITY = 1e-6


@dataclass(frozen=True)
class UpwardAngle:
    """Where a compensator's angle is measured from (:func:`upward_angle`).

    Attributes
    ----------
    angle_rad
        The joint angle (rad) at which the carried centre of mass is straight above the axis
        (``upward``), or 0 (``joint_zero``).
    reference
        One of :data:`ANGLE_REFERENCES`.
    reason
        Why the joint's zero is the reference (empty for ``upward``).
    """

    angle_rad: float
    reference: str
    reason: str = ""


def upward_angle(robot: Robot, joint: str) -> UpwardAngle:
    """The angle of revolute ``joint`` at which the centre of mass of everything it carries
    (its Pinocchio subtree, links' inertias) lies straight above its axis, the other joints at
    the neutral configuration and no load.

    The carried centre of mass ``c`` and the upward direction ``u = -g/|g|``
    (``model.gravity``) are projected on the plane normal to the axis ``z`` through the joint
    origin; turning the joint by ``atan2(z . (c x u), c . u)`` from its neutral angle brings
    ``c`` above the axis.

    Returns
    -------
    UpwardAngle
        ``upward`` with that angle (rad), or ``joint_zero`` (angle 0) with the reason when no
        direction is up: the axis parallel to gravity, no gravity, the carried centre of mass
        on the axis (e.g. a DH robot without masses), or ``joint`` a controller coordinate
        rather than one joint of the chain.
    """
    model = robot.model
    if not model.existJointName(joint) or model.joints[model.getJointId(joint)].nv != 1:
        return UpwardAngle(0.0, "joint_zero", f"{joint} is not one revolute joint of the chain "
                                              "(a controller coordinate): no link to point up")
    data = model.createData()
    q = pin.neutral(model)
    jid = model.getJointId(joint)
    pin.centerOfMass(model, data, q, True)  # data.com[j]: subtree centre, joint j's frame
    pin.computeJointJacobians(model, data, q)
    jacobian = np.asarray(pin.getJointJacobian(model, data, jid, pin.LOCAL)).reshape(6, model.nv)
    axis = jacobian[3:, model.joints[jid].idx_v]
    axis = axis / np.linalg.norm(axis)
    gravity = data.oMi[jid].rotation.T @ np.asarray(model.gravity.linear, dtype=float)
    up = -gravity - axis * (axis @ -gravity)
    com = np.asarray(data.com[jid], dtype=float)
    com = com - axis * (axis @ com)
    g_norm = float(np.linalg.norm(gravity))
    if g_norm == 0.0 or np.linalg.norm(up) <= AXIS_ALONG_GRAVITY * g_norm:
        return UpwardAngle(0.0, "joint_zero", "the axis is parallel to gravity (or the model "
                                              "has none): no direction is up")
    if not data.mass[jid] > 0.0:
        return UpwardAngle(0.0, "joint_zero", f"{joint} carries no mass (a model without link "
                                              "inertias): no direction is up")
    if np.linalg.norm(com) <= COM_ON_AXIS_M:
        return UpwardAngle(0.0, "joint_zero", f"the centre of mass {joint} carries is on its "
                                              "axis: no direction is up")
    turn = math.atan2(float(axis @ np.cross(com, up)), float(com @ up))
    return UpwardAngle(robot.value_of(q, joint) + turn, "upward")


def compensator_torque(theta: float | np.ndarray, stiffness: float, preload: float,
                       geometry: dict) -> tuple[np.ndarray, np.ndarray]:
    """Torque (N.m) of a spring compensator at joint angles ``theta`` (rad) and its angle
    derivative (N.m/rad): :func:`spring_balancer` at ``phi = theta - angle_up_rad +
    angle0_rad``, the tension ``preload`` (N) at ``theta = angle_up_rad``.

    ``geometry``: ``lever_m``, ``base_m`` (m), ``angle_up_rad`` (the reference angle,
    :func:`upward_angle`; 0 at the joint's zero) and ``angle0_rad`` (the angle between lever
    and base there; 0 when the lever points at the base point, as the upward reference places
    it; a model file's older settings give it without ``angle_up_rad``).
    """
    relative = np.asarray(theta, dtype=float) - float(geometry.get("angle_up_rad", 0.0))
    return spring_balancer(relative, stiffness, preload, geometry["lever_m"],
                           geometry["base_m"], float(geometry.get("angle0_rad", 0.0)))


def joint_preload(robot: Robot, weighed: pin.Model | None,
                  compensators: tuple | list, q: np.ndarray, weight_stiffness: bool = True
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Torque (n,) of the weight and the spring compensators on the compliant joints at the
    full configuration ``q``, and its derivative ``K_p`` (n, n).

    Parameters
    ----------
    robot
        The robot.
    weighed
        Its Pinocchio model with the payload (:func:`stiffness.mechanics.gravity.with_payload`),
        or ``None`` (no weight).
    compensators
        ``(joint, stiffness N/m, tension N, geometry)``
        (:meth:`stiffness.elastic.effects.parts.ElasticParts.add_compensator`).
    weight_stiffness
        Whether the weight's derivative ``K_g = -dg/dq`` enters ``K_p`` (the ``enhanced``
        formulation); the compensators' always does.
    """
    n = robot.n_compliant
    tau, k = np.zeros(n), np.zeros((n, n))
    if weighed is not None:
        tau, k = gravity_preload(robot, q, model=weighed)
        if not weight_stiffness:
            k = np.zeros((n, n))
    for joint, k_s, f0, g in compensators:
        i = list(robot.compliant_joints).index(joint)
        t, dt = compensator_torque(robot.value_of(q, joint), k_s, f0, g)
        tau[i] += t
        k[i, i] += dt
    return tau, k
