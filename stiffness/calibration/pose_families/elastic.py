"""The elastic families of the pose model acting through the joints: ``joint_compliance``
(the deflection library's effect of that name on every compliant joint, under gravity and the
applied wrench) and ``gravity_lumped`` (masses unknown); docs/absolute-poses.md.

Each adds its part of the joints' deflection ``Delta q`` in the sag's fixed point
(:meth:`stiffness.calibration.absolute.PoseModel.loaded_configuration`).

Units: SI (m, N, rad).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
import pinocchio as pin

from stiffness.calibration.pose_families.base import (
    JointDeflectionFamily,
    Parameter,
    PoseLayout,
    SagState,
)

#: Unit of a lumped gravity parameter (compliance times a mass or a mass moment).
LUMPED_UNIT = "rad/(N.m) x (kg or kg.m)"
#: Gravity parameters of a link in Pinocchio's order (m, m c_x, m c_y, m c_z, inertia...).
GRAVITY_PARAMETERS = ("m", "mcx", "mcy", "mcz")


class JointCompliancePose(JointDeflectionFamily):
    """``joint_compliance``: ``Delta q_j = c_j tau_j`` on each compliant joint (rad/(N.m), or
    m/N), ``tau`` the torque the springs carry at the loaded configuration; springs on
    controller coordinates (``S``: :attr:`PoseLayout.spring_map`) give
    ``Delta q = S diag(c) S^T tau``."""

    name: ClassVar[str] = "joint_compliance"

    def parameters(self, pm: PoseLayout) -> list[Parameter]:
        return [self.param(f"{n} compliance",
                           "m/N" if pm.robot.is_prismatic(n) else "rad/(N.m)")
                for n in pm.springs]

    def joint_deflection(self, pm: PoseLayout, x_f: np.ndarray, state: SagState) -> np.ndarray:
        return pm.spring_map @ (x_f * (pm.spring_map.T @ state.torque))

    def deflection_per_torque(self, pm: PoseLayout, x_f: np.ndarray, state: SagState
                              ) -> np.ndarray:
        """The diagonal of ``S diag(c) S^T``: exact for springs on joints; with springs on
        controller coordinates the coupling's off-diagonal terms are left out (they would
        matter only to a family adding its own torque on a chain joint)."""
        return pm.spring_map ** 2 @ x_f

    def deflection_columns(self, pm: PoseLayout, x_f: np.ndarray, state: SagState
                           ) -> np.ndarray:
        return pm.spring_map * (pm.spring_map.T @ state.torque)


class GravityLumped(JointDeflectionFamily):
    """``gravity_lumped`` (masses unknown): ``Delta q_j = - sum_k theta_jk Y_jk(q)``, ``Y`` the
    gravity regressor at the loaded configuration, ``theta_jk = c_j pi_k`` lumped (``pi_k``:
    the mass and mass moments of link ``k`` downstream of ``j``); for springs on controller
    coordinates ``Delta q = - S_j theta_jk S_j^T Y_k`` (``S_j`` the spring's column of
    :attr:`PoseLayout.spring_map`)."""

    name: ClassVar[str] = "gravity_lumped"
    lumps_gravity: ClassVar[bool] = True

    def parameters(self, pm: PoseLayout) -> list[Parameter]:
        names = pm.robot.model.names
        return [self.param(f"{spring} x {names[k]} {p}", LUMPED_UNIT)
                for c, spring in enumerate(pm.springs) for k in pm.spring_downstream(c)
                for p in GRAVITY_PARAMETERS]

    def at_configuration(self, pm: PoseLayout, model: pin.Model, data: pin.Data,
                         q: np.ndarray) -> np.ndarray:
        """d(Delta q)/d theta (nv, n_theta): ``-S_j (S_j^T Y_k)`` of each pair (minus the
        regressor entry at a spring on a joint)."""
        nv = model.nv
        regressor = pin.computeJointTorqueRegressor(model, data, q, np.zeros(nv), np.zeros(nv))
        pairs = np.array([(c, 10 * (k - 1) + p) for c in range(len(pm.springs))
                          for k in pm.spring_downstream(c)
                          for p in range(len(GRAVITY_PARAMETERS))], dtype=int).reshape(-1, 2)
        springs = pm.spring_map[:, pairs[:, 0]]  # each pair's spring column S_j (nv, n_theta)
        return -springs * np.sum(springs * regressor[:, pairs[:, 1]], axis=0)

    def joint_deflection(self, pm: PoseLayout, x_f: np.ndarray, state: SagState) -> np.ndarray:
        return state.extras[self.name] @ x_f

    def deflection_columns(self, pm: PoseLayout, x_f: np.ndarray, state: SagState
                           ) -> np.ndarray:
        return state.extras[self.name]

