"""Frame kinematics from Pinocchio (stiffness.robot.kinematics) against finite differences.

Every derivative is checked against central differences of lower-order quantities computed by
Pinocchio's forward kinematics alone (positions, rotations), or of the Jacobian for the Hessian.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from stiffness.robot import kinematics
from stiffness.robot.robot import load_robot

H = 1e-6


def _random_q(robot, rng):
    """A random configuration of the (open) tree: revolute/prismatic joints only, nq == nv."""
    assert robot.model.nq == robot.model.nv
    return rng.uniform(-np.pi, np.pi, robot.model.nq)


def _fd_over_q(model, data, q, fn, h=H):
    """Central differences of fn(q) over every velocity coordinate, stacked on the last axis."""
    cols = []
    for b in range(model.nv):
        dv = np.zeros(model.nv)
        dv[b] = h
        plus = fn(pin.integrate(model, q, dv))
        minus = fn(pin.integrate(model, q, -dv))
        cols.append((plus - minus) / (2 * h))
    return np.stack(cols, axis=-1)


def _position(model, data, fid):
    def fn(q):
        pin.framesForwardKinematics(model, data, q)
        return data.oMf[fid].translation.copy()
    return fn


def _jacobian(model, data, fid):
    def fn(q):
        kinematics.update_first_order(model, data, q)
        return kinematics.frame_jacobian(model, data, fid).copy()
    return fn


@pytest.mark.parametrize("name", ["ur5", "panda", "sk120"])
def test_jacobian_linear_rows_are_position_derivative(name, ur5, panda, sk120):
    robot = {"ur5": ur5, "panda": panda, "sk120": sk120}[name]
    model, data, fid = robot.model, robot.data, robot.target_frame_id
    rng = np.random.default_rng(11)
    for _ in range(3):
        q = _random_q(robot, rng)  # for the SK120 this is the open tree (loop not closed)
        kinematics.update_first_order(model, data, q)
        jac = kinematics.frame_jacobian(model, data, fid)
        fd = _fd_over_q(model, data, q, _position(model, data, fid))
        assert np.linalg.norm(jac[:3] - fd) <= 1e-7 * np.linalg.norm(fd)


@pytest.mark.parametrize("name", ["ur5", "panda"])
def test_jacobian_angular_rows_are_world_angular_velocity(name, ur5, panda):
    """omega_b such that R(q + h e_b) R(q - h e_b)^T = exp(2 h [omega_b]x): world axes."""
    robot = {"ur5": ur5, "panda": panda}[name]
    model, data, fid = robot.model, robot.data, robot.target_frame_id
    rng = np.random.default_rng(12)
    q = _random_q(robot, rng)
    kinematics.update_first_order(model, data, q)
    jac = kinematics.frame_jacobian(model, data, fid)
    fd = np.zeros((3, model.nv))
    for b in range(model.nv):
        dv = np.zeros(model.nv)
        dv[b] = H
        pin.framesForwardKinematics(model, data, pin.integrate(model, q, dv))
        r_plus = data.oMf[fid].rotation.copy()
        pin.framesForwardKinematics(model, data, pin.integrate(model, q, -dv))
        r_minus = data.oMf[fid].rotation.copy()
        fd[:, b] = pin.log3(r_plus @ r_minus.T) / (2 * H)
    assert np.linalg.norm(jac[3:] - fd) <= 1e-7 * np.linalg.norm(fd)


@pytest.mark.parametrize("name", ["ur5", "panda", "sk120"])
def test_frame_hessian_is_jacobian_derivative(name, ur5, panda, sk120):
    """H[k, a, b] = dJ[k, a]/dq_b for all six rows (the reordering of pin's tensor is right)."""
    robot = {"ur5": ur5, "panda": panda, "sk120": sk120}[name]
    model, data, fid = robot.model, robot.data, robot.target_frame_id
    rng = np.random.default_rng(13)
    for _ in range(3):
        q = _random_q(robot, rng)
        kinematics.update_kinematics(model, data, q)
        hess = kinematics.frame_hessian(model, data, fid)
        assert hess.shape == (6, model.nv, model.nv)
        fd = _fd_over_q(model, data, q, _jacobian(model, data, fid))
        assert np.linalg.norm(hess - fd) <= 1e-7 * np.linalg.norm(fd)
        # the position rows are a true Hessian: symmetric in (a, b)
        lin = hess[:3]
        assert np.abs(lin - lin.transpose(0, 2, 1)).max() <= 1e-12 * np.abs(lin).max()


def test_first_order_and_full_update_agree(ur5):
    model, data, fid = ur5.model, ur5.data, ur5.target_frame_id
    q = np.array([0.3, -1.0, 1.2, -0.7, 1.1, 0.4])
    kinematics.update_first_order(model, data, q)
    p1, r1 = kinematics.frame_position(data, fid), kinematics.frame_rotation(data, fid)
    j1 = kinematics.frame_jacobian(model, data, fid).copy()
    kinematics.update_kinematics(model, data, q)
    np.testing.assert_allclose(kinematics.frame_position(data, fid), p1, rtol=0, atol=1e-15)
    np.testing.assert_allclose(kinematics.frame_rotation(data, fid), r1, rtol=0, atol=1e-15)
    np.testing.assert_allclose(kinematics.frame_jacobian(model, data, fid), j1, atol=1e-15)
    # the returned position and rotation are copies, not views of pin's data
    p1[:] = 0.0
    assert np.linalg.norm(kinematics.frame_position(data, fid)) > 0.1


def test_target_offset_is_in_the_frame_axes():
    """The target frame sits at R_frame @ offset + p_frame (offset in the frame's own axes)."""
    offset = np.array([0.05, -0.12, 0.2])
    robot = load_robot("ur5", frame="tool0", target_offset=offset)
    model, data = robot.model, robot.data
    q = np.array([0.3, -1.0, 1.2, -0.7, 1.1, 0.4])
    pin.framesForwardKinematics(model, data, q)
    tool = data.oMf[model.getFrameId("tool0")]
    expected = tool.rotation @ offset + tool.translation
    kinematics.update_kinematics(model, data, q)
    np.testing.assert_allclose(kinematics.frame_position(data, robot.target_frame_id), expected,
                               atol=1e-14)
    np.testing.assert_allclose(kinematics.frame_rotation(data, robot.target_frame_id),
                               tool.rotation, atol=1e-14)
