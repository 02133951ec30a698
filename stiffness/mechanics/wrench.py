"""Wrenches at the target: the load that holds springs away from rest, body axes, 6-D orders.

Spatial vectors follow Pinocchio: twists ``[v; omega]``, wrenches ``[F; M]`` (N, N.m), base
axes at the target unless stated; :func:`reorder_twist` permutes 6-vectors and 6x6 matrices to
the angular-first order ``[omega; v]`` that Zefran & Kumar use. Units: SI (m, N, rad).
"""

from __future__ import annotations

import numpy as np

from stiffness.errors import StiffnessError, UnknownNameError
from stiffness.mechanics.formulation import TargetState, target_state
from stiffness.robot.robot import Robot

#: Row orders of 6-vectors: Pinocchio's (linear first) and angular first.
TWIST_ORDERS = {"v-w": ["vx", "vy", "vz", "wx", "wy", "wz"],
                "w-v": ["wx", "wy", "wz", "vx", "vy", "vz"]}
#: Names of the wrench components dual to each twist order.
WRENCH_ORDERS = {"v-w": ["fx", "fy", "fz", "mx", "my", "mz"],
                 "w-v": ["mx", "my", "mz", "fx", "fy", "fz"]}
_ANGULAR_FIRST = np.array([3, 4, 5, 0, 1, 2])


def reorder_twist(x: np.ndarray, order: str = "w-v") -> np.ndarray:
    """A 6-vector or 6x6 matrix from Pinocchio's ``[v; omega]`` order to ``order``.

    ``"v-w"`` returns a copy; ``"w-v"`` swaps the blocks (rows, and columns of a matrix).
    Wrenches ``[F; M]`` become ``[M; F]`` the same way.
    """
    if order not in TWIST_ORDERS:
        raise UnknownNameError(f"twist order must be one of {', '.join(TWIST_ORDERS)}, got "
                               f"{order!r}", name=order, choices=list(TWIST_ORDERS))
    x = np.asarray(x, dtype=float)
    if order == "v-w":
        return x.copy()
    if x.ndim == 1:
        return x[_ANGULAR_FIRST]
    return x[np.ix_(_ANGULAR_FIRST, _ANGULAR_FIRST)]


def holding_wrench(robot: Robot, q: np.ndarray, k_theta: np.ndarray,
                   rest: np.ndarray | list[float]) -> np.ndarray:
    """Dead wrench at the target that holds it at ``q`` against the springs, [F; M] base axes.

    The springs pull with ``tau = K_theta (theta - theta_rest)`` on the compliant joints; the
    holding wrench balances them: ``J^T W = tau`` (J the closed-loop target Jacobian, rows
    [v; omega], base axes at the target). The springs' own wrench on the target is ``-W``
    (Zefran & Kumar's ``W_i = -L_i Phi`` in body components).

    Parameters
    ----------
    robot
        The robot (its target frame carries the wrench).
    q
        Closed configuration.
    k_theta
        (n, n) joint stiffness (N/m for prismatic, N.m/rad for revolute joints).
    rest
        Rest value of each compliant joint (m or rad).

    Raises
    ------
    StiffnessError
        If ``rest`` has the wrong length, or if no target wrench balances the springs (fewer
        than six compliant joints pulling outside the range of ``J^T``).
    """
    rest = np.asarray(rest, dtype=float).reshape(-1)
    if rest.shape[0] != robot.n_compliant or not np.all(np.isfinite(rest)):
        raise StiffnessError(
            f"need one finite rest value per compliant joint ({robot.n_compliant}: "
            f"{', '.join(robot.compliant_joints)}), got {rest.tolist()}"
        )
    theta = robot.spring_values(q)[robot.compliant_in_springs]
    tau = k_theta @ (theta - rest)
    jac = target_state(robot, q).jacobian
    wrench = np.linalg.lstsq(jac.T, tau, rcond=1e-12)[0]
    if np.linalg.norm(jac.T @ wrench - tau) > 1e-8 * max(1.0, float(np.linalg.norm(tau))):
        raise StiffnessError(
            "no wrench at the target balances the springs at this configuration (the compliant "
            "joints are not all loaded through the target); give the load explicitly"
        )
    return wrench


def body_wrench(state: TargetState) -> np.ndarray:
    """The state's wrench [F; M] in the target's body axes (N, N.m)."""
    rt = state.rotation.T
    return np.concatenate([rt @ state.wrench[:3], rt @ state.wrench[3:]])
