"""Pose-model evaluation over every row at once (issue 37 item 4): the array kinematics of
:mod:`stiffness.batch.poses` against Pinocchio's own calls, and the model's columns against
finite differences (every family's: tests/test_absolute_poses.py)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from pose_columns import assert_columns

from stiffness.batch.poses import (
    _pinocchio_placements,
    frame_placements,
    integrate,
    joint_placements,
    mass_jacobians,
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
    reference = _pinocchio_placements(model, data, q, True)
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
