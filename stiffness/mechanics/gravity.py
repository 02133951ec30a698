"""The robot's own weight as a joint preload: torque and its configuration derivative.

The links' weight (URDF inertias, ``model.gravity``), optionally plus a point payload fixed to
the target frame, acts on the compliant joints as the torque ``tau_g(q) = -g(q)`` (``g`` the
generalised gravity of ``M qdd + C + g = tau``), and its derivative
``K_g = d tau_g / d theta = -dg/dq`` plays the part of ``K_C`` for that load: the joints are in
equilibrium under ``K dtheta = J^T W + tau_g(theta)``, linearised ``tau_g(theta_0) + K_g dtheta``.
Both come from Pinocchio's analytical ``computeGeneralizedGravity`` and
``computeGeneralizedGravityDerivatives``. Open chains only: in a closed loop the passive joints'
weight would have to be carried through the loop's constraint (not implemented; a typed error).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from stiffness.errors import StiffnessError
from stiffness.mechanics.formulation import compliant_projection
from stiffness.robot.robot import Robot


def require_open_chain(robot: Robot, what: str = "gravity effects") -> None:
    """Raise a one-line :class:`StiffnessError` when ``robot`` has closed loops."""
    if not robot.loop.is_open_chain:
        raise StiffnessError(f"{what} need an open chain; {robot.name} has closed loops (the "
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


def spring_balancer(theta: float | np.ndarray, stiffness: float, preload: float, lever_m: float,
                    base_m: float, angle0: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Torque of a spring gravity compensator on its joint and the torque's angle derivative.

    A spring runs from a point on the base side, ``base_m`` from the joint axis, to a point on
    the link's lever, ``lever_m`` from the axis; ``phi = theta + angle0`` is the angle between
    the two at the axis (``angle0`` at the joint's zero). Its length and force are

    ``L^2 = a^2 + d^2 - 2 a d cos(phi)``, ``F = F_0 + k_s (L - L(theta = 0))``

    (``a = lever_m``, ``d = base_m``, ``k_s = stiffness`` N/m, ``F_0 = preload`` N, the tension
    at the joint's zero). The torque on the joint and its derivative are

    ``tau_s = -F L'``, ``d tau_s / d theta = -(k_s L'^2 + F L'')``, with ``L L' = a d sin(phi)``
    and ``L'^2 + L L'' = a d cos(phi)``,

    so ``k_s L'^2 + F L''`` adds to the joint's stiffness.

    Parameters
    ----------
    theta
        Joint angles (rad), any shape.

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
