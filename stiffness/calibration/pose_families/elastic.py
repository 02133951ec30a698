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
    m/N), ``tau`` the torque the springs carry at the loaded configuration."""

    name: ClassVar[str] = "joint_compliance"

    def parameters(self, pm: PoseLayout) -> list[Parameter]:
        names = pm.robot.model.names
        return [self.param(f"{names[j]} compliance", pm.joint_unit(j, "rad/(N.m)", "m/N"))
                for j in pm.compliant]

    def joint_deflection(self, pm: PoseLayout, x_f: np.ndarray, state: SagState) -> np.ndarray:
        out = np.zeros(state.torque.size)
        out[pm.compliant_v] = x_f * state.torque[pm.compliant_v]
        return out

    def deflection_per_torque(self, pm: PoseLayout, x_f: np.ndarray, state: SagState
                              ) -> np.ndarray:
        out = np.zeros(state.torque.size)
        out[pm.compliant_v] = x_f
        return out

    def deflection_columns(self, pm: PoseLayout, x_f: np.ndarray, state: SagState
                           ) -> np.ndarray:
        out = np.zeros((state.torque.size, x_f.size))
        out[pm.compliant_v, np.arange(x_f.size)] = state.torque[pm.compliant_v]
        return out


class GravityLumped(JointDeflectionFamily):
    """``gravity_lumped`` (masses unknown): ``Delta q_j = - sum_k theta_jk Y_jk(q)``, ``Y`` the
    gravity regressor at the loaded configuration, ``theta_jk = c_j pi_k`` lumped (``pi_k``:
    the mass and mass moments of link ``k`` downstream of ``j``)."""

    name: ClassVar[str] = "gravity_lumped"
    lumps_gravity: ClassVar[bool] = True

    def parameters(self, pm: PoseLayout) -> list[Parameter]:
        names = pm.robot.model.names
        return [self.param(f"{names[j]} x {names[k]} {p}", LUMPED_UNIT)
                for j in pm.compliant for k in pm.downstream(j) for p in GRAVITY_PARAMETERS]

    def at_configuration(self, pm: PoseLayout, model: pin.Model, data: pin.Data,
                         q: np.ndarray) -> np.ndarray:
        """d(Delta q)/d theta (nv, n_theta): minus the regressor entries of each pair."""
        nv = model.nv
        regressor = pin.computeJointTorqueRegressor(model, data, q, np.zeros(nv), np.zeros(nv))
        pairs = np.array([(vj, 10 * (k - 1) + p)
                          for j, vj in zip(pm.compliant, pm.compliant_v, strict=True)
                          for k in pm.downstream(j) for p in range(len(GRAVITY_PARAMETERS))],
                         dtype=int).reshape(-1, 2)
        out = np.zeros((nv, len(pairs)))
        out[pairs[:, 0], np.arange(len(pairs))] = -regressor[pairs[:, 0], pairs[:, 1]]
        return out

    def joint_deflection(self, pm: PoseLayout, x_f: np.ndarray, state: SagState) -> np.ndarray:
        return state.extras[self.name] @ x_f

    def deflection_columns(self, pm: PoseLayout, x_f: np.ndarray, state: SagState
                           ) -> np.ndarray:
        return state.extras[self.name]

