"""The spring compensator's geometry (issue 31, item 2): its angle is measured from the link's
upward direction at zero load (:func:`stiffness.mechanics.gravity.upward_angle`), computed from
the model's gravity and inertias; where no direction is up, from the joint's zero, said so.

Checked against independent computations: the carried centre of mass summed by hand from the
joint placements and link inertias, the joint axis from a finite rotation of the joint, the
gravity torque of ``pin.computeGeneralizedGravity``, and the closed-form balance of a one-joint
arm by a zero-free-length spring (``k a d = m g r``).
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from stiffness.elastic.effects import make_effect
from stiffness.elastic.effects.geometry import Geometry
from stiffness.elastic.effects.preloads import GravityCompensator
from stiffness.elastic.model_file import ModelEffect
from stiffness.mechanics.gravity import spring_balancer, upward_angle
from stiffness.robot.robot import load_robot

#: (robot, revolute joints whose axis is horizontal at the neutral configuration)
ARMS = [("ur5", ["shoulder_lift_joint", "elbow_joint", "wrist_1_joint"]),
        ("kinova", ["j2s6s200_joint_2", "j2s6s200_joint_3", "j2s6s200_joint_5"])]
SPRING = (1e5, 3000.0)  # N/m, N


def _at(robot, joint: str, angle: float) -> np.ndarray:
    """The neutral configuration with ``joint`` at ``angle`` (rad; one or two coordinates)."""
    model = robot.model
    q = pin.neutral(model)
    jm = model.joints[model.getJointId(joint)]
    if jm.nq == 1:
        q[jm.idx_q] = angle
    else:
        q[jm.idx_q:jm.idx_q + 2] = math.cos(angle), math.sin(angle)
    return q


def _carried_com_and_axis(robot, joint: str, q: np.ndarray):
    """By hand: the centre of mass of every body the joint carries (world), the joint origin
    and its world axis from turning the joint by a small angle."""
    model = robot.model
    data = model.createData()
    pin.forwardKinematics(model, data, q)
    jid = model.getJointId(joint)
    carried = [k for k in range(1, model.njoints) if jid in model.supports[k]]
    mass = sum(model.inertias[k].mass for k in carried)
    com = sum(model.inertias[k].mass * data.oMi[k].act(model.inertias[k].lever)
              for k in carried) / mass
    origin, rotation = data.oMi[jid].translation.copy(), data.oMi[jid].rotation.copy()
    h = 1e-6
    pin.forwardKinematics(model, data, _at(robot, joint, robot.value_of(q, joint) + h))
    axis = rotation @ pin.log3(rotation.T @ data.oMi[jid].rotation) / h
    return com, origin, axis / np.linalg.norm(axis)


@pytest.mark.parametrize(("name", "joints"), ARMS, ids=[a[0] for a in ARMS])
def test_at_the_upward_angle_the_carried_centre_of_mass_is_straight_above_the_axis(name, joints):
    robot = load_robot(name)
    up = -robot.model.gravity.linear / np.linalg.norm(robot.model.gravity.linear)
    for joint in joints:
        found = upward_angle(robot, joint)
        assert found.reference == "upward", (joint, found)
        com, origin, axis = _carried_com_and_axis(robot, joint, _at(robot, joint,
                                                                    found.angle_rad))
        r = com - origin
        r -= axis * (axis @ r)
        u = up - axis * (axis @ up)
        assert np.linalg.norm(r) > 1e-3
        cosine = (r @ u) / np.linalg.norm(r) / np.linalg.norm(u)
        assert cosine == pytest.approx(1.0, abs=1e-9), (joint, cosine)


@pytest.mark.parametrize(("name", "joints"), ARMS, ids=[a[0] for a in ARMS])
def test_spring_torque_vanishes_upright_and_opposes_the_weight(name, joints):
    """Zero at the upward angle; of the opposite sign to the links' gravity torque on the
    joint (pin.computeGeneralizedGravity, other joints neutral) at every other angle."""
    robot = load_robot(name)
    geo = Geometry.of(robot)
    model, data = robot.model, robot.model.createData()
    for joint in joints:
        effect = make_effect("gravity_compensator", joint, geo)
        assert effect.settings["angle_reference"] == "upward"
        theta_up = effect.settings["angle_up_rad"]
        assert abs(float(effect.torque(np.array(SPRING), np.array(theta_up))[0])) < 1e-9
        iv = model.joints[model.getJointId(joint)].idx_v
        checked = 0
        for phi in np.linspace(-3.0, 3.0, 25):
            if abs(phi) < 1e-3:
                continue
            spring = float(effect.torque(np.array(SPRING), np.array(theta_up + phi))[0])
            weight = -pin.computeGeneralizedGravity(model, data, _at(robot, joint,
                                                                     theta_up + phi))[iv]
            assert spring * weight < 0.0, (joint, phi, spring, weight)
            checked += 1
        assert checked == 24


def _one_joint_arm(tmp_path, mass: float, r: float, axis: str, name: str):
    """A URDF: a base, one revolute joint about ``axis``, a link with a point ``mass`` (kg)
    at ``r`` (m) along its x axis."""
    urdf = f"""<robot name="{name}">
  <link name="base"/>
  <link name="arm"><inertial><origin xyz="{r} 0 0"/><mass value="{mass}"/>
    <inertia ixx="1e-9" ixy="0" ixz="0" iyy="1e-9" iyz="0" izz="1e-9"/></inertial></link>
  <link name="tip"/>
  <joint name="hinge" type="revolute"><parent link="base"/><child link="arm"/>
    <origin xyz="0 0 0.5"/><axis xyz="{axis}"/>
    <limit lower="-6.3" upper="6.3" effort="100" velocity="1"/></joint>
  <joint name="tool" type="fixed"><parent link="arm"/><child link="tip"/>
    <origin xyz="{r} 0 0"/></joint>
</robot>"""
    path = tmp_path / f"{name}.urdf"
    path.write_text(urdf)
    return load_robot(path)


def test_zero_length_spring_balances_a_one_joint_arm_in_closed_form(tmp_path):
    """A point mass m at r on a horizontal hinge about y: the link points up at -pi/2 (x turns
    to z), and the spring with k a d = m g r and F0 = k (d - a) (zero free length) cancels the
    weight at every angle."""
    m, r, a, d = 4.0, 0.35, 0.1, 0.3
    robot = _one_joint_arm(tmp_path, m, r, "0 1 0", "hinge_y")
    geo = Geometry.of(robot)
    effect = make_effect("gravity_compensator", "hinge", geo)
    assert effect.settings["angle_up_rad"] == pytest.approx(-math.pi / 2, abs=1e-12)
    g = 9.81
    k = m * g * r / (a * d)
    spring = np.array([k, k * (d - a)])
    data = robot.model.createData()
    worst = 0.0
    for theta in np.linspace(-3.0, 3.0, 31):
        q = np.array([theta])
        weight = -pin.computeGeneralizedGravity(robot.model, data, q)[0]
        # the weight's torque in closed form: m g r sin(phi), phi from straight up
        assert weight == pytest.approx(m * g * r * math.sin(theta + math.pi / 2), abs=1e-9)
        tau, _ = effect.torque(spring, np.array(theta))
        worst = max(worst, abs(float(tau) + weight))
    assert worst < 1e-9 * m * g * r


def test_no_upward_direction_falls_back_to_the_joint_zero_and_says_so(tmp_path):
    vertical = _one_joint_arm(tmp_path, 4.0, 0.35, "0 0 1", "hinge_z")
    found = upward_angle(vertical, "hinge")
    assert (found.angle_rad, found.reference) == (0.0, "joint_zero")
    assert "parallel to gravity" in found.reason
    massless = _one_joint_arm(tmp_path, 0.0, 0.35, "0 1 0", "massless")
    effect = make_effect("gravity_compensator", "hinge", Geometry.of(massless))
    assert effect.settings["angle_reference"] == "joint_zero"
    assert "joint's zero" in effect.describe() and "no mass" in effect.describe()
    on_axis = _one_joint_arm(tmp_path, 4.0, 0.0, "0 1 0", "on_axis")
    assert "on its axis" in upward_angle(on_axis, "hinge").reason


def test_a_model_file_written_before_the_upward_reference_keeps_its_meaning():
    """Settings without ``angle_reference`` (lever, base, ``angle0_rad`` only) read as the
    joint's zero: phi = theta + angle0_rad, the tension at the joint's zero."""
    old = {"lever_m": 0.12, "base_m": 0.25, "angle0_rad": 0.2}
    effect = GravityCompensator.declared("joint2", old)
    assert effect.settings["angle_reference"] == "joint_zero"
    assert "before the upward reference" in effect.describe()
    theta = np.linspace(-2.0, 2.0, 9)
    tau, dtau = effect.torque(np.array(SPRING), theta)
    want, dwant = spring_balancer(theta, *SPRING, 0.12, 0.25, 0.2)
    np.testing.assert_allclose(tau, want, rtol=1e-14)
    np.testing.assert_allclose(dtau, dwant, rtol=1e-14)
    assert ModelEffect("gravity_compensator", "joint2", "preload", settings=old).settings == old
