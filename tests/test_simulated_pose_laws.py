"""The pose simulator's hidden laws against closed forms (issue 40, item 4): the truth of
:mod:`stiffness.planning.simulate_poses` is computed from the physics, independently of the
fitted model's effect classes, and each law it adds to the joint springs is checked here on its
own.

* The spring compensator: the torque from the spring's attachment points against the hand
  values at right angles and straight down, and against the library's scalar law
  (:func:`stiffness.mechanics.gravity.spring_balancer`, a separate derivation).
* A link bend: a cantilever whose tool the weight beyond its distal hinge turns (below).
* Backlash: a one-joint pendulum (mass m at r on a horizontal axis) whose sag
  ``delta = tau / k + b tanh(tau / tau_s)``, ``tau = m g r cos(q + delta)``, is solved here by
  bracketing; the simulated marker sits where that angle puts it.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from scipy import optimize

from stiffness.calibration.pose_model import Marker
from stiffness.elastic.effects.geometry import BACKLASH_SMOOTHING
from stiffness.mechanics.gravity import spring_balancer
from stiffness.planning.simulate_poses import (
    SPRING_BASE_M,
    SPRING_LEVER_M,
    HiddenPoseErrors,
    simulate_pose_campaign,
    spring_compensator_torque,
)
from stiffness.robot.robot import load_robot

MASS, RADIUS, LENGTH, G = 4.0, 0.3, 0.5, 9.81  # kg, m (centre of mass), m (marker), m/s^2
PENDULUM = f"""<?xml version="1.0"?>
<robot name="pendulum">
  <link name="base_link"/>
  <link name="arm"><inertial><origin xyz="{RADIUS} 0 0"/><mass value="{MASS}"/>
    <inertia ixx="1e-4" iyy="1e-4" izz="1e-4" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="tool"/>
  <joint name="hinge" type="revolute"><parent link="base_link"/><child link="arm"/>
    <axis xyz="0 1 0"/><limit effort="100" velocity="1" lower="-1.2" upper="1.2"/></joint>
  <joint name="tool_joint" type="fixed"><parent link="arm"/><child link="tool"/>
    <origin xyz="{LENGTH} 0 0"/></joint>
</robot>
"""


def test_compensator_torque_from_its_attachment_points():
    k, f0, a, d = 2e4, 500.0, SPRING_LEVER_M, SPRING_BASE_M
    # link horizontal: spring length sqrt(a^2 + d^2), moment arm a d / L, restoring
    length = np.hypot(a, d)
    tension = f0 + k * (length - (d - a))
    for theta in (np.pi / 2, -np.pi / 2):
        assert spring_compensator_torque(theta, k, f0) == pytest.approx(
            -np.sign(theta) * tension * a * d / length, rel=1e-12)
    # straight up or down the spring is in line with the lever: no torque
    assert spring_compensator_torque(0.0, k, f0) == pytest.approx(0.0, abs=1e-9)
    assert spring_compensator_torque(np.pi, k, f0) == pytest.approx(0.0, abs=1e-9)
    # the library's scalar law, derived separately (L L' = a d sin(phi))
    theta = np.linspace(-3.0, 3.0, 61)
    ours = [spring_compensator_torque(t, k, f0) for t in theta]
    np.testing.assert_allclose(ours, spring_balancer(theta, k, f0, a, d)[0], rtol=1e-10,
                               atol=1e-9)


def test_backlash_sag_of_a_pendulum_is_the_closed_form(tmp_path):
    """A pendulum on a horizontal hinge, spring k and backlash b: every simulated marker (no
    noise, tracker at the base) sits at ``L (cos(q + delta), 0, -sin(q + delta))`` with delta
    the root found here (1e-12 m)."""
    path = tmp_path / "pendulum.urdf"
    path.write_text(PENDULUM)
    robot = load_robot(path, frame="tool", compliant_joints=["hinge"])
    k, b = 300.0, 0.02  # N.m/rad, rad: a sag of a few degrees
    hidden = HiddenPoseErrors(np.eye(3), np.zeros(3), np.zeros((1, 3)), np.zeros(1),
                              np.zeros((1, 6)), np.array([k]), backlash=np.array([b]))
    c = simulate_pose_campaign(robot, [Marker("tip", "tool", np.zeros(3))], hidden, 12, 0.0,
                               seed=2)
    assert robot.model.gravity.linear[2] == pytest.approx(-G)
    q = c.q[:, 0]

    def torque(angle):
        return MASS * G * RADIUS * np.cos(angle)

    tau_s = BACKLASH_SMOOTHING * np.sqrt(np.mean(torque(q) ** 2))
    for qi, seen in zip(q, c.positions[:, 0], strict=True):
        delta = optimize.brentq(lambda x, qi=qi: x - torque(qi + x) / k
                                - b * np.tanh(torque(qi + x) / tau_s), -0.5, 0.5, xtol=1e-15)
        assert abs(delta) > 1e-3
        angle = qi + delta
        np.testing.assert_allclose(seen, LENGTH * np.array([np.cos(angle), 0.0, -np.sin(angle)]),
                                   rtol=0, atol=1e-12)


def _arm_urdf(length: float, radius: float, tool: float, mass: float) -> str:
    """Two hinges on vertical axes (gravity loads neither), the second ``length`` from the
    first, carrying a mass at ``radius`` and the tool at ``tool`` along its x axis."""
    return f"""<?xml version="1.0"?>
<robot name="bender">
  <link name="base_link"/>
  <link name="upper"/>
  <link name="fore"><inertial><origin xyz="{radius} 0 0"/><mass value="{mass}"/>
    <inertia ixx="1e-4" iyy="1e-4" izz="1e-4" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="tool"/>
  <joint name="hinge1" type="revolute"><parent link="base_link"/><child link="upper"/>
    <axis xyz="0 0 1"/><limit effort="100" velocity="1" lower="-3" upper="3"/></joint>
  <joint name="hinge2" type="revolute"><parent link="upper"/><child link="fore"/>
    <origin xyz="{length} 0 0"/><axis xyz="0 0 1"/>
    <limit effort="100" velocity="1" lower="-3" upper="3"/></joint>
  <joint name="tool_joint" type="fixed"><parent link="fore"/><child link="tool"/>
    <origin xyz="{tool} 0 0"/></joint>
</robot>
"""


def test_link_bend_of_a_cantilever_is_the_closed_form(tmp_path):
    """The upper link bends (the same compliance c about both axes normal to it, so their
    choice does not matter) under the moment of the weight beyond its distal hinge: the part
    beyond turns by ``omega = c (M - (M . u) u)`` about the hinge, ``M`` that weight's moment
    at the turned pose (solved here by fixed point), ``u`` the link's direction. The simulated
    tool is where that turn puts it (1e-12 m), the sag itself above 0.1 mm (about 2 cm at
    most). The hinges are rigid (1e12 N.m/rad): the bend tilts the second hinge's axis, whose
    gravity torque would sag it. Without a payload (this case) every bend once came out
    NaN."""
    length, radius, tool, mass, c = 0.6, 0.25, 0.4, 10.0, 2e-3  # m, kg, rad/(N.m)
    path = tmp_path / "bender.urdf"
    path.write_text(_arm_urdf(length, radius, tool, mass))
    robot = load_robot(path, frame="tool", compliant_joints=["hinge1", "hinge2"])
    hidden = HiddenPoseErrors(np.eye(3), np.zeros(3), np.zeros((1, 3)), np.zeros(2),
                              np.zeros((2, 6)), np.array([1e12, 1e12]),
                              link_compliance={"hinge1->hinge2": np.array([c, c])})
    sim = simulate_pose_campaign(robot, [Marker("tip", "tool", np.zeros(3))], hidden, 8, 0.0,
                                 seed=4)
    weight = np.array([0.0, 0.0, -mass * G])
    for (q1, q2), seen in zip(sim.q, sim.positions[:, 0], strict=True):
        hinge = length * np.array([np.cos(q1), np.sin(q1), 0.0])
        u = hinge / length
        turn = np.array([np.cos(q1 + q2), np.sin(q1 + q2), 0.0])  # the forearm's x axis
        omega = np.zeros(3)
        for _ in range(100):
            moment = np.cross(pin.exp3(omega) @ (radius * turn), weight)
            omega = c * (moment - (moment @ u) * u)
        tip = hinge + pin.exp3(omega) @ (tool * turn)
        assert np.linalg.norm(tip - (hinge + tool * turn)) > 1e-4
        np.testing.assert_allclose(seen, tip, rtol=0, atol=1e-12)
