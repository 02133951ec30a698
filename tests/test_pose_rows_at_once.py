"""Pose-model evaluation over every row at once (issue 37 item 4): the array kinematics of
:mod:`stiffness.batch.poses` against Pinocchio's own calls, and the model's columns against
finite differences (every family's: tests/test_absolute_poses.py)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from pose_columns import assert_columns

from stiffness.batch.poses import (
    frame_placements,
    gravity_regressors,
    integrate,
    joint_placements,
    mass_jacobians,
    pinocchio_placements,
    point_jacobians,
)
from stiffness.calibration.pose_model import Loads, Marker, PoseModel
from stiffness.robot.robot import load_robot

AT_ONCE = ("frame", "markers", "joint_offsets", "geometry", "joint_compliance")


def _mixed_chain() -> tuple[pin.Model, list[int]]:
    """A chain of every joint kind the array kinematics place (revolute and prismatic, along
    a frame axis and unaligned), randomly placed, with an offset frame on its last link."""
    rng = np.random.default_rng(4)
    model = pin.Model()
    kinds = [pin.JointModelRZ(), pin.JointModelPX(),
             pin.JointModelRevoluteUnaligned(*(v / np.linalg.norm(v) for v in
                                              [rng.normal(size=3)])),
             pin.JointModelPrismaticUnaligned(*(v / np.linalg.norm(v) for v in
                                               [rng.normal(size=3)])),
             pin.JointModelRY()]
    parent = 0
    for n, kind in enumerate(kinds):
        placement = pin.SE3(pin.exp3(rng.normal(size=3)), rng.normal(size=3))
        parent = model.addJoint(parent, kind, placement, f"j{n}")
        model.appendBodyToJoint(parent, pin.Inertia.Random(), pin.SE3.Identity())
    fid = model.addFrame(pin.Frame("tip", parent, 0, pin.SE3(pin.exp3(rng.normal(size=3)),
                                                              rng.normal(size=3)),
                                   pin.FrameType.OP_FRAME))
    return model, [fid]


def test_array_kinematics_match_pinocchio():
    """Joint placements, joint Jacobians, frame placements and a frame point's Jacobian of the
    array kinematics equal Pinocchio's per-configuration results (``data.oMi``, ``data.J``,
    ``data.oMf``, ``getFrameJacobian``) to round-off, on every joint kind they place."""
    model, fids = _mixed_chain()
    data = model.createData()
    rng = np.random.default_rng(5)
    q = rng.uniform(-2, 2, (6, model.nq))
    kin = joint_placements(model, data, q)
    reference = pinocchio_placements(model, data, q, True)
    for a, b in ((kin.rotation, reference.rotation), (kin.translation, reference.translation),
                 (kin.jacobian, reference.jacobian)):
        assert np.allclose(a, b, rtol=0.0, atol=1e-12)
    rot, trans = frame_placements(model, kin, fids)
    points = trans + np.einsum("mfab,b->mfa", rot, np.array([0.1, -0.2, 0.3]))
    jac = point_jacobians(model, kin, fids, points)
    for i in range(q.shape[0]):
        pin.computeJointJacobians(model, data, q[i])
        pin.updateFramePlacements(model, data)
        frame = data.oMf[fids[0]]
        assert np.allclose(rot[i, 0], frame.rotation, atol=1e-12)
        assert np.allclose(trans[i, 0], frame.translation, atol=1e-12)
        j6 = pin.getFrameJacobian(model, data, fids[0], pin.LOCAL_WORLD_ALIGNED)
        lever = points[i, 0] - frame.translation
        assert np.allclose(jac[i, 0], j6[:3] + np.cross(j6[3:].T, lever).T, atol=1e-12)
        assert np.allclose(integrate(model, q[i:i + 1], q[i])[0],
                           pin.integrate(model, q[i], q[i]), atol=0.0)
        j_com = pin.jacobianCenterOfMass(model, data, q[i], False) * data.mass[0]
        assert np.abs(mass_jacobians(model, kin)[i] - j_com).max() <= 1e-12 * np.abs(j_com).max()


def _free_flyer_chain() -> pin.Model:
    """:func:`_mixed_chain` on a free-flyer base (a joint of 6 velocity coordinates)."""
    chain, _ = _mixed_chain()
    model = pin.Model()
    base = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "base")
    model.appendBodyToJoint(base, pin.Inertia.Random(), pin.SE3.Identity())
    for j in range(1, chain.njoints):
        parent = base if chain.parents[j] == 0 else chain.parents[j] + 1
        new = model.addJoint(parent, chain.joints[j], chain.jointPlacements[j], chain.names[j])
        model.appendBodyToJoint(new, chain.inertias[j], pin.SE3.Identity())
    return model


def test_point_jacobians_on_a_free_flyer_base():
    """A frame point's Jacobian on a free-flyer base (Pinocchio places it) is
    ``getFrameJacobian``'s moved to the point, all six base columns included (the support mask
    once kept only a multi-coordinate joint's first column: five of them were zero)."""
    model = _free_flyer_chain()
    fid = model.addFrame(pin.Frame("tip", model.njoints - 1, 0, pin.SE3(np.eye(3), np.ones(3)),
                                   pin.FrameType.OP_FRAME))
    data = model.createData()
    q = np.array([pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq))
                  for _ in range(2)])
    kin = joint_placements(model, data, q)
    _, trans = frame_placements(model, kin, [fid])
    jac = point_jacobians(model, kin, [fid], trans)
    for i in range(q.shape[0]):
        pin.computeJointJacobians(model, data, q[i])
        pin.updateFramePlacements(model, data)
        j6 = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
        assert np.abs(j6[:3, :6]).max(axis=0).min() > 0.1  # each base column moves it
        assert np.allclose(jac[i, 0], j6[:3], rtol=0.0, atol=1e-12)


@pytest.mark.parametrize("source", ["mixed", "free-flyer", "panda", "sk120"])
def test_gravity_regressors_match_pinocchio_and_finite_differences(source):
    """The one regressor of the lumped weight (both faces of ``gravity_lumped``): with random
    gravity parameters ``pi`` (masses 0.1-10 kg, centres of mass within 0.2 m), ``Y pi`` and
    ``Y_q pi`` are ``computeGeneralizedGravity`` and ``computeGeneralizedGravityDerivatives``
    of a model of these masses to 1e-12 relative (measured 2e-15), and ``Y_q`` is the
    central difference of ``Y`` to 1e-7 (measured 5e-10), on every joint kind the array
    kinematics place, a free-flyer base, the Panda (prismatic fingers) and the SK120's tree
    (two branches, loops open)."""
    if source == "mixed":
        model = _mixed_chain()[0]
    elif source == "free-flyer":
        model = _free_flyer_chain()
    else:
        model = load_robot(source).model
    data, rng = model.createData(), np.random.default_rng(7)
    bodies = model.njoints - 1
    q = np.array([pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq))
                  for _ in range(3)])
    y, y_q = gravity_regressors(model, data, q, derivative=True)
    assert y_q is not None and y.shape == (3, model.nv, bodies, 4)
    for i in range(q.shape[0]):
        mass, com = rng.uniform(0.1, 10.0, bodies), rng.uniform(-0.2, 0.2, (bodies, 3))
        weighed = pin.Model(model)
        for k in range(bodies):
            weighed.inertias[k + 1] = pin.Inertia(mass[k], com[k], np.eye(3) * 1e-3)
        pi = np.column_stack([mass, mass[:, None] * com])
        wdata = weighed.createData()
        g = np.array(pin.computeGeneralizedGravity(weighed, wdata, q[i]))
        dg = np.array(pin.computeGeneralizedGravityDerivatives(weighed, wdata, q[i]))
        tau = np.einsum("vkp,kp->v", y[i], pi)
        assert np.abs(tau - g).max() <= 1e-12 * np.abs(g).max()
        k_g = np.einsum("vwkp,kp->vw", y_q[i], pi)
        assert np.abs(k_g - dg).max() <= 1e-12 * np.abs(dg).max()
        step, fd = 1e-6, np.empty(y_q[i].shape)
        for b in range(model.nv):
            dv = np.zeros(model.nv)
            dv[b] = step
            ends = np.array([pin.integrate(model, q[i], dv), pin.integrate(model, q[i], -dv)])
            plus, minus = gravity_regressors(model, data, ends)[0]
            fd[:, b] = (plus - minus) / (2.0 * step)
        assert np.abs(y_q[i] - fd).max() <= 1e-7 * np.abs(y_q[i]).max()


@pytest.fixture(scope="module")
def loaded_case():
    """UR10 with two markers, four loaded rows (a wrench at the tool) and random parameters
    of their typical sizes (compliances positive: the arm sags)."""
    robot = load_robot("ur10", frame="tool0")
    rng = np.random.default_rng(6)
    markers = [Marker("a", "tool0", np.array([0.05, 0.0, 0.1])),
               Marker("b", "wrist_1_link", np.array([0.0, 0.08, 0.0]))]
    frame0 = (pin.exp3(rng.normal(size=3)), np.array([1.0, 2.0, 0.5]))
    loads = Loads("tool0", np.zeros((0, 6)))
    model = PoseModel(robot, markers, AT_ONCE, frame0, loads)
    draws = [(rng.uniform(-2, 2, 6), rng.normal(size=6) * 50) for _ in range(4)]
    rows = [model.row_terms(robot.configuration(q), None if i == 2 else wrench)
            for i, (q, wrench) in enumerate(draws)]  # one row unloaded
    scales = np.array([p.scale for p in model.parameters])
    x = np.abs(rng.normal(size=model.size)) * scales * 3
    return robot, markers, frame0, loads, rows, x, scales


def test_rows_at_once_columns_match_finite_differences(loaded_case):
    """Every column against central differences on the loaded, sagging arm: to 1e-2 (the
    documented fixed-torque approximation of the elastic columns, module docstring of
    pose_model), and to 1e-6 at zero compliance."""
    robot, markers, frame0, loads, rows, x, scales = loaded_case
    model = PoseModel(robot, markers, AT_ONCE, frame0, loads)
    elastic = np.zeros(model.size, dtype=bool)
    elastic[model.slices()["joint_compliance"]] = True
    for tol, point in ((1e-2, x), (1e-6, np.where(elastic, 0.0, x))):
        assert_columns(model, rows, point, scales, tol)
