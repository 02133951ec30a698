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

from stiffness.batch.poses import joint_placements
from stiffness.calibration.pose_model import Loads, Marker, PoseModel
from stiffness.calibration.poses import sample_coordinates
from stiffness.elastic.effects.geometry import (
    BACKLASH_SMOOTHING,
    MIN_SEGMENT_M,
    Geometry,
    References,
    chain_placements,
    link_axes,
    tilt_axes,
)
from stiffness.elastic.effects.joint_laws import Backlash
from stiffness.elastic.effects.link_bends import (
    LinkCompliance,
    TransversalCompliance,
    marker_links,
    transversal_joints,
)
from stiffness.mechanics.gravity import spring_balancer
from stiffness.planning.simulate import joint_tilt_axes, row_smoothing_torques
from stiffness.planning.simulate_poses import (
    SPRING_BASE_M,
    SPRING_LEVER_M,
    HiddenPoseErrors,
    bend_axes,
    link_column,
    rotation_axis_column,
    simulate_pose_campaign,
    smoothing_torques,
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


def _robots_with_markers():
    """The UR10, the Panda and the two-arm torso with markers on their hands and forearms."""
    arm = tuple(f"panda_joint{i}" for i in range(1, 8))
    return [(load_robot("ur10", frame="tool0"), ["tool0", "forearm_link"]),
            (load_robot("panda", frame="panda_hand", compliant_joints=arm),
             ["panda_hand", "panda_link4"]),
            (load_robot("two-arm-torso"), ["right_tcp", "left_tcp"])]


def test_simulator_and_fitted_model_derive_the_same_axes_and_smoothing():
    """What a hidden bend's or backlash's parameter means is a convention both sides must
    share; the simulator derives it on its own (:func:`link_column`, :func:`bend_axes`,
    :func:`rotation_axis_column`, :func:`smoothing_torques`). On three robots: every link of
    the markers' chains gets the fitted model's column, and at 20 random configurations the
    same two bending axes (1e-12); every compliant revolute joint of the chains the same
    tilting axes; the smoothing torques over 15 poses under a payload the fitted model's
    campaign settings (1e-12 relative)."""
    rng = np.random.default_rng(7)
    for robot, frames in _robots_with_markers():
        model = robot.model
        fids = [model.getFrameId(f) for f in frames]
        links = marker_links(model, fids)
        compliant = [int(model.getJointId(n)) for n in robot.compliant_joints
                     if model.existJointName(n)]
        tilting = transversal_joints(model, fids, compliant)
        assert len(links) >= 3 and len(tilting) >= 4, robot.name
        assert [link_column(model, k.a, k.b) for k in links] == [k.column for k in links]
        moved = {j for f in fids for j in model.supports[model.frames[f].parentJoint]}
        ours = [j for j in compliant if j in moved and rotation_axis_column(model, j) is not None]
        # of tilting joints whose origins coincide only the last tilts (last_of_groups)
        data = model.createData()
        pin.forwardKinematics(model, data, pin.neutral(model))
        kept = [k.b for k in tilting]
        for j in ours:
            beyond = [c for c in model.subtrees[j] if c != j and model.parents[c] == j]
            grouped = any(np.linalg.norm(data.oMi[c].translation - data.oMi[j].translation)
                          < MIN_SEGMENT_M and rotation_axis_column(model, c) is not None
                          for c in beyond)
            assert (j in kept) != grouped, (robot.name, model.names[j])
        assert [rotation_axis_column(model, k.b) for k in tilting] == [k.column for k in tilting]
        data = model.createData()
        for q in sample_coordinates(robot, 20, rng):
            pin.forwardKinematics(model, data, robot.configuration(q))
            origins = np.array([data.oMi[k.b].translation for k in links])
            kin = joint_placements(model, data, robot.configuration(q)[None], False)
            e1, e2 = (a[0] for a in LinkCompliance.bend_axes(model, kin, links, origins[None]))
            for n, k in enumerate(links):
                mine = bend_axes(data.oMi[k.a].translation, origins[n],
                                 data.oMi[model.parents[k.b]].rotation, k.column)
                np.testing.assert_allclose(np.array(mine), [e1[n], e2[n]], rtol=0, atol=1e-12)
            t1, t2 = (a[0] for a in TransversalCompliance.bend_axes(
                model, kin, tilting, np.zeros((1, len(tilting), 3))))
            for n, k in enumerate(tilting):
                mount = (data.oMi[model.parents[k.b]].rotation
                         @ model.jointPlacements[k.b].rotation)
                assert np.allclose(t1[n], mount[:, (k.column + 1) % 3], rtol=0, atol=1e-15)
                assert np.allclose(t2[n], mount[:, (k.column + 2) % 3], rtol=0, atol=1e-15)
        payload = np.concatenate([rng.normal(0, 50, 3), rng.normal(0, 5, 3)])
        q = sample_coordinates(robot, 15, rng)
        loads = Loads(robot.target_frame, np.tile(payload, (len(q), 1)))
        nominal = PoseModel(robot, [Marker(f, f, np.zeros(3)) for f in frames], (),
                            (np.eye(3), np.zeros(3)), loads)
        fitted = nominal.campaign_settings([nominal.row_terms(robot.configuration(c), payload)
                                            for c in q])[Backlash.SETTING]
        simulated = smoothing_torques(robot, q, payload)
        assert fitted and set(fitted) <= set(simulated), robot.name
        for name, tau_s in fitted.items():
            assert simulated[name] == pytest.approx(tau_s, rel=1e-12), (robot.name, name)


def test_deflection_simulator_derives_the_fitted_link_columns():
    """The deflection simulator's hidden bends (:func:`stiffness.planning.simulate.build_truth`)
    take their axis column from :func:`link_column` at the robot's reference pose: for every
    segment of the target chain of the UR5, the SK120 (closed loop) and the Panda, the column
    the fitted model's geometry chose, and the same axes as its ``link_axes`` at 10 random
    configurations each (1e-12); and every joint that may tilt in its bearing the fitted model's
    tilting axes (:func:`~stiffness.planning.simulate.joint_tilt_axes`, its axis from its
    motion subspace)."""
    rng = np.random.default_rng(3)
    for name in ("ur5", "sk120", "panda"):
        robot = load_robot(name)
        geo = Geometry.of(robot)
        model = geo.robot.model
        reference = geo.robot.assemble(None).q
        ids = {j: int(model.getJointId(j)) for j in geo.chain}
        assert len(geo.link_columns) >= 10, name
        for (a, b), column in geo.link_columns.items():
            assert link_column(model, ids[a], ids[b], reference) == column, (name, a, b)
        for coords in sample_coordinates(geo.robot, 10, rng):
            pin.forwardKinematics(model, geo.robot.data, geo.robot.configuration(coords))
            origins, mounts = chain_placements(geo.robot, geo.chain)
            for (a, b), column in geo.link_columns.items():
                ia, ib = geo.chain.index(a), geo.chain.index(b)
                fitted = link_axes(origins[ia], origins[ib], mounts[ib], column)
                np.testing.assert_allclose(bend_axes(origins[ia], origins[ib], mounts[ib], column),
                                           fitted, rtol=0, atol=1e-12)
            for joint, column in geo.tilt_columns.items():  # transversal_compliance
                ib, placement = geo.chain.index(joint), model.jointPlacements[ids[joint]]
                fitted = tilt_axes(mounts[ib] @ placement.rotation, column)
                np.testing.assert_allclose(joint_tilt_axes(model, joint, mounts[ib]), fitted,
                                           rtol=0, atol=1e-12)


def test_deflection_simulator_derives_the_fitted_smoothing_torques():
    """Backlash's smoothing torque in the deflection simulator
    (:func:`stiffness.planning.simulate.row_smoothing_torques`, from the target Jacobian) is the
    fitted model's (:meth:`References.of` over the campaign's rows) on the UR5, the SK120
    (closed loop) and the hexapod (1e-12 relative): 6 configurations x 2 random forces."""
    rng = np.random.default_rng(5)
    for name in ("ur5", "sk120", "hexapod"):
        geo = Geometry.of(load_robot(name))
        q = np.repeat(sample_coordinates(geo.robot, 6, rng), 2, axis=0)
        force = rng.normal(0.0, 100.0, (len(q), 3))
        fitted = References.of(geo, geo.rows(q, force), 1.0, np.ones((1, 3))).tau_smoothing
        np.testing.assert_allclose(row_smoothing_torques(geo.robot, q, force), fitted, rtol=1e-12,
                                   err_msg=name)
