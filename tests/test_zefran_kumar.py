"""Zefran & Kumar, "Affine connections for the Cartesian stiffness matrix", section 5 and eq. 34.

* Section 5 prints J^-1 (rounded to 0.01) and K = diag(10, 20, 30, 40, 50, 60) N/cm, and the
  joint-connection stiffness K_j = J^-T K J^-1 (rounded to 0.1). The paper orders twists
  [omega; v] and wrenches [tau; F]; K_j is computed in that order here (the arithmetic does not
  depend on it). Units: K in N/cm; K_j in the paper's mixed N, cm units.
* The twist-basis stiffness K_a (eq. 30) of stiffness.mechanics.formulation against a
finite-difference
  definition, its asymmetry against eq. 34 (Lie bracket of the basis twists), K_a = K_j where
  the wrench vanishes; and the printed K_a's asymmetry against the structure eq. 34 implies.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from stiffness.mechanics.formulation import (
    TargetState,
    joint_connection_stiffness,
    target_state,
    twist_basis_stiffness,
)

#: Section 5, printed J^-1 (rows: legs; columns: basis twists [omega; v]).
J_INV_PRINTED = np.array([
    [0.00, 0.00, 0.00, 0.62, 0.35, 0.70],
    [0.00, -5.83, 2.92, 0.37, 0.42, 0.83],
    [0.00, -6.36, 0.41, 0.41, 0.06, 0.91],
    [4.89, -2.82, -4.12, 0.54, -0.24, 0.81],
    [5.27, -3.04, -3.38, 0.47, -0.15, 0.87],
    [0.00, 0.00, 0.00, 0.62, 0.25, 0.74],
])
K_LEGS = np.diag([10.0, 20.0, 30.0, 40.0, 50.0, 60.0])  # N/cm
#: Section 5, printed K_j.
K_J_PRINTED = np.array([
    [2345.9, -1354.5, -1695.2, 229.3, -87.1, 387.0],
    [-1354.5, 2674.9, 559.7, -253.8, -9.6, -493.8],
    [-1695.2, 559.7, 1423.5, -141.6, 90.5, -219.8],
    [229.3, -253.8, -141.6, 57.3, 6.4, 87.2],
    [-87.1, -9.6, 90.5, 6.4, 12.0, 7.7],
    [387.0, -493.8, -219.8, 87.2, 7.7, 140.7],
])
#: Section 5, printed K_a (eq. 30, asymmetric).
K_A_PRINTED = np.array([
    [2141.4, -1725.1, -3895.1, 206.9, -581.5, 466.5],
    [-2094.7, 4107.4, -336.5, 303.5, 5.3, -836.8],
    [-1518.7, 608.6, 3263.9, -239.5, 516.7, -212.2],
    [206.9, -202.4, -180.2, 80.0, 5.2, 75.6],
    [-75.5, 5.3, 212.0, 5.2, 39.3, 5.2],
    [407.2, -532.2, -212.2, 75.6, 5.2, 150.6],
])

#: Printing half-units: J^-1 to 0.01, K_j and K_a to 0.1.
HALF_J = 0.005
HALF_K = 0.05


def rounding_bound(j_inv: np.ndarray, k_diag: np.ndarray, half: float) -> np.ndarray:
    """Worst-case |(P + E)^T K (P + E) - P^T K P| entrywise over |E_ij| <= half (interval
    arithmetic, exact for a diagonal K >= 0):
    sum_i k_i (half |P_ia| + |P_ib| half + half^2)."""
    a = np.abs(j_inv)
    return (k_diag[:, None, None]
            * (half * a[:, :, None] + half * a[:, None, :] + half**2)).sum(axis=0)


#: Tolerance on each K_j entry: the printed J^-1's rounding propagated through J^-T K J^-1
#: (rigorous bound), plus the rounding of the printed K_j itself.
K_J_TOLERANCE = rounding_bound(J_INV_PRINTED, np.diag(K_LEGS), HALF_J) + HALF_K


def _state_from_inverse_jacobian(state: TargetState, j_inv: np.ndarray) -> TargetState:
    """A copy of an unloaded six-joint ``state`` carrying J = (J^-1)^-1 and identity axes."""
    return dataclasses.replace(state, jacobian=np.linalg.inv(j_inv), rotation=np.eye(3))


def test_printed_k_j_from_printed_inverse_jacobian():
    """K_j = J^-T K J^-1 reproduces the printed K_j within the propagated rounding."""
    k_j = J_INV_PRINTED.T @ K_LEGS @ J_INV_PRINTED
    assert np.all(np.abs(k_j - K_J_PRINTED) <= K_J_TOLERANCE)
    # the bound is informative: 0.5 to 5.8 per entry (entries up to 2675); the measured
    # deviations (up to 2.3) use at most 55 % of it; 1 % stiffer springs exceed it 4.9-fold
    assert K_J_TOLERANCE.max() < 6.0
    assert (np.abs(k_j - K_J_PRINTED) / K_J_TOLERANCE).max() < 0.6
    assert np.abs(k_j - K_J_PRINTED).max() > 0.5 * HALF_K  # J^-1 rounding is visible


def test_joint_connection_stiffness_reproduces_printed_k_j(ur5):
    """The toolkit's joint-connection stiffness, fed the printed J^-1, gives the printed K_j."""
    unloaded = target_state(ur5, ur5.configuration(np.zeros(6)))
    state = _state_from_inverse_jacobian(unloaded, J_INV_PRINTED)
    for body in (True, False):  # identity orientation: body and base axes coincide
        k_j = joint_connection_stiffness(state, K_LEGS, body=body)
        assert np.all(np.abs(k_j - K_J_PRINTED) <= K_J_TOLERANCE)
        np.testing.assert_allclose(k_j, k_j.T, atol=1e-9)


@pytest.mark.parametrize(
    "wrong",
    [
        J_INV_PRINTED @ K_LEGS @ J_INV_PRINTED.T,  # J^-1 K J^-T: wrong side
        J_INV_PRINTED.T @ np.diag([60.0, 50.0, 40.0, 30.0, 20.0, 10.0]) @ J_INV_PRINTED,
        J_INV_PRINTED.T @ (K_LEGS * 1.01) @ J_INV_PRINTED,  # 1 % stiffer springs
    ],
)
def test_printed_k_j_comparison_discriminates(wrong):
    """The tolerance is tight enough to reject nearby wrong formulas."""
    assert not np.all(np.abs(wrong - K_J_PRINTED) <= K_J_TOLERANCE)


def test_printed_k_a_asymmetry_has_eq34_structure():
    """Eq. 34: K_a - K_a^T = W([L_j, L_i]). In the paper's [omega; v] order the bracket of two
    translations vanishes, and that of a rotation e_a with a translation e_b is the translation
    e_a x e_b: so the v-v block of K_a is symmetric and the omega-v block of K_a - K_a^T is
    antisymmetric (zero diagonal) — to the printing's rounding (2 x 0.05)."""
    skew = K_A_PRINTED - K_A_PRINTED.T
    tol = 2 * HALF_K + 1e-9
    assert np.abs(skew[3:, 3:]).max() <= tol
    block = skew[:3, 3:]
    assert np.abs(np.diag(block)).max() <= tol
    assert np.abs(block + block.T).max() <= 2 * tol
    # and the asymmetry is real (eq. 34 is not trivially satisfied by a symmetric matrix)
    assert np.abs(skew).max() > 1000.0
    # and K_a differs from K_j: a different connection, a different matrix
    assert np.abs(K_A_PRINTED - K_J_PRINTED).max() > 1000.0


# ----------------------------------------------------------------- the toolkit's twist basis


def _bracket(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """se(3) bracket in Pinocchio's [v; omega] order: (w1 x v2 - w2 x v1, w1 x w2)."""
    v1, w1, v2, w2 = x[:3], x[3:], y[:3], y[3:]
    return np.r_[np.cross(w1, v2) - np.cross(w2, v1), np.cross(w1, w2)]


UR5_Q = np.array([0.3, -1.0, 1.2, -0.7, 1.1, 0.4])
UR5_K = np.diag([3e4, 3e4, 2e4, 5e3, 5e3, 5e3])


def _body_jacobian(state):
    return np.vstack([state.rotation.T @ state.jacobian[:3], state.rotation.T @ state.jacobian[3:]])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_twist_basis_stiffness_is_fd_of_spring_wrench_along_body_twists(ur5, seed):
    """K_a[:, j] = d W_b / d t along the left-invariant field of the j-th body twist, where
    W_b = J_b^-T K_theta (theta - theta0) is the wrench the springs hold (body axes) and
    theta0 is such that it equals the applied wrench at theta."""
    rng = np.random.default_rng(seed)
    coords = UR5_Q + rng.uniform(-0.4, 0.4, 6)
    wrench = np.r_[rng.normal(size=3) * 200.0, rng.normal(size=3) * 20.0]
    state = target_state(ur5, ur5.configuration(coords), wrench)
    jb = _body_jacobian(state)
    body_wrench = np.r_[state.rotation.T @ wrench[:3], state.rotation.T @ wrench[3:]]
    theta0 = coords - np.linalg.solve(UR5_K, jb.T @ body_wrench)

    def spring_wrench(theta):
        s = target_state(ur5, ur5.configuration(theta))
        return np.linalg.solve(_body_jacobian(s).T, UR5_K @ (theta - theta0))

    np.testing.assert_allclose(spring_wrench(coords), body_wrench, atol=1e-9)
    h = 1e-6
    numeric = np.zeros((6, 6))
    for j in range(6):
        dtheta = np.linalg.solve(jb, np.eye(6)[j])  # joint rates of the j-th body twist
        numeric[:, j] = (spring_wrench(coords + h * dtheta)
                         - spring_wrench(coords - h * dtheta)) / (2 * h)
    k_a = twist_basis_stiffness(state, UR5_K)
    assert np.linalg.norm(k_a - numeric) <= 1e-6 * np.linalg.norm(numeric)


@pytest.mark.parametrize("seed", [3, 4, 5])
def test_twist_basis_asymmetry_is_the_lie_bracket(ur5, seed):
    """Eq. 34 for left-invariant basis twists: (K_a - K_a^T)[i, j] = W_b . [xi_j, xi_i],
    whatever the robot and its joint stiffness; K_j stays symmetric."""
    rng = np.random.default_rng(seed)
    coords = UR5_Q + rng.uniform(-0.4, 0.4, 6)
    wrench = np.r_[rng.normal(size=3) * 200.0, rng.normal(size=3) * 20.0]
    state = target_state(ur5, ur5.configuration(coords), wrench)
    body_wrench = np.r_[state.rotation.T @ wrench[:3], state.rotation.T @ wrench[3:]]
    basis = np.eye(6)
    expected = np.array([[body_wrench @ _bracket(basis[j], basis[i]) for j in range(6)]
                         for i in range(6)])
    k_theta = np.diag(rng.uniform(1e3, 1e5, 6))
    k_a = twist_basis_stiffness(state, k_theta)
    skew = k_a - k_a.T
    assert np.abs(expected).max() > 10.0
    assert np.abs(skew - expected).max() <= 1e-9 * np.abs(k_a).max()
    k_j = joint_connection_stiffness(state, k_theta)
    np.testing.assert_allclose(k_j, k_j.T, atol=1e-9 * np.abs(k_j).max())


def test_twist_basis_equals_joint_connection_without_load(ur5):
    """Where the wrench vanishes (a stationary point of the potential) K_a = K_j."""
    state = target_state(ur5, ur5.configuration(UR5_Q))
    k_a = twist_basis_stiffness(state, UR5_K)
    k_j = joint_connection_stiffness(state, UR5_K)
    np.testing.assert_allclose(k_a, k_j, atol=1e-9 * np.abs(k_j).max())
    np.testing.assert_allclose(k_a, k_a.T, atol=1e-9 * np.abs(k_j).max())
    # and it is J_b^-T K_theta J_b^-1 with the body Jacobian
    jb_inv = np.linalg.inv(_body_jacobian(state))
    np.testing.assert_allclose(k_j, jb_inv.T @ UR5_K @ jb_inv, rtol=1e-9, atol=1e-6)
