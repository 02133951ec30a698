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
from stiffness.elastic.calibrated import (
    BACKLASH_SETTING,
    backlash_label,
    compensator_label,
    compliance_label,
)
from stiffness.elastic.effects.geometry import BACKLASH_SMOOTHING
from stiffness.elastic.effects.preloads import GravityCompensator
from stiffness.errors import StiffnessError
from stiffness.mechanics.gravity import upward_angle
from stiffness.robot.robot import Robot

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
        return [self.param(compliance_label(n),
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


def _joint_angle(model: pin.Model, joint: int, q: np.ndarray) -> float:
    """Angle (rad) of a revolute joint at ``q`` (a continuous joint's from its cos, sin)."""
    jm = model.joints[joint]
    if jm.nq == 2:
        return float(np.arctan2(q[jm.idx_q + 1], q[jm.idx_q]))
    return float(q[jm.idx_q])


class BacklashPose(JointDeflectionFamily):
    """``backlash``: lost motion on each compliant joint, ``Delta q_j += b_j tanh(tau_j /
    tau_s)`` (the deflection library's rule: ``tau_s`` =
    :data:`~stiffness.elastic.effects.geometry.BACKLASH_SMOOTHING` times the joint's RMS torque
    over the campaign, setting ``backlash_smoothing_torque``); ``b_j`` rad (m prismatic). A
    joint whose torque is nil at every pose of the campaign (below :data:`NIL_TORQUE` of the
    largest joint's RMS: a vertical base axis) has no parameter: its lost motion never shows."""

    name: ClassVar[str] = "backlash"
    scale: ClassVar[float] = 1e-4
    needs_masses: ClassVar[bool] = True
    #: the model setting naming each compliant joint's smoothing torque (N.m or N)
    SETTING: ClassVar[str] = BACKLASH_SETTING
    #: RMS torque, relative to the largest joint's, below which a joint carries none
    NIL_TORQUE: ClassVar[float] = 1e-6

    def parameters(self, pm: PoseLayout) -> list[Parameter]:
        names = pm.robot.model.names
        return [self.param(backlash_label(names[j]), pm.joint_unit(j, "rad", "m"))
                for j, _, _ in self._joints(pm)]

    @classmethod
    def campaign_settings(cls, torques: np.ndarray, pm: PoseLayout) -> dict:
        """``backlash_smoothing_torque``: joint name -> smoothing torque, from the (rows, nv)
        torques the joints carry at the campaign's commanded poses (joints that carry none
        left out)."""
        names = pm.robot.model.names
        rms = np.sqrt(np.mean(torques[:, pm.compliant_v] ** 2, axis=0))
        top = float(rms.max(initial=0.0))
        return {cls.SETTING: {names[j]: float(BACKLASH_SMOOTHING * r)
                              for j, r in zip(pm.compliant, rms, strict=True)
                              if r > cls.NIL_TORQUE * top}}

    def __init__(self) -> None:
        self._layout: tuple[list[int], np.ndarray] | None = None

    def _joints(self, pm: PoseLayout) -> list[tuple[int, int, float]]:
        """(joint id, velocity index, smoothing torque) of each joint with a parameter."""
        given = pm.settings.get(self.SETTING)
        if not isinstance(given, dict):
            raise StiffnessError("backlash needs each compliant joint's smoothing torque "
                                 f"(setting {self.SETTING}); build the model with "
                                 "pose_fit.campaign_settings(campaign)")
        names = pm.robot.model.names
        return [(j, v, float(given[names[j]]))
                for j, v in zip(pm.compliant, pm.compliant_v, strict=True) if names[j] in given]

    def _ratio(self, pm: PoseLayout, state: SagState) -> tuple[list[int], np.ndarray,
                                                                np.ndarray]:
        """Velocity indices, ``tau_j / tau_s`` and ``tau_s`` of the joints with a parameter."""
        if self._layout is None:  # built once per model
            joints = self._joints(pm)
            self._layout = ([v for _, v, _ in joints], np.array([s for _, _, s in joints]))
        v_index, smooth = self._layout
        return v_index, state.torque[v_index] / smooth, smooth

    def joint_deflection(self, pm: PoseLayout, x_f: np.ndarray, state: SagState) -> np.ndarray:
        v_index, ratio, _ = self._ratio(pm, state)
        out = np.zeros(state.torque.size)
        out[v_index] = x_f * np.tanh(ratio)
        return out

    def deflection_per_torque(self, pm: PoseLayout, x_f: np.ndarray, state: SagState
                              ) -> np.ndarray:
        v_index, ratio, smooth = self._ratio(pm, state)
        out = np.zeros(state.torque.size)
        out[v_index] = x_f * (1.0 - np.tanh(ratio) ** 2) / smooth
        return out

    def deflection_columns(self, pm: PoseLayout, x_f: np.ndarray, state: SagState
                           ) -> np.ndarray:
        v_index, ratio, _ = self._ratio(pm, state)
        out = np.zeros((state.torque.size, x_f.size))
        out[v_index, np.arange(x_f.size)] = np.tanh(ratio)
        return out


class CompensatorPose(JointDeflectionFamily):
    """``gravity_compensator``: a spring between the base and a lever on each revolute
    compliant joint's link (the deflection library's effect,
    :class:`~stiffness.elastic.effects.preloads.GravityCompensator`, with its default geometry
    and its angle measured from the link's upward direction); its torque at the loaded joint
    angle joins what the joint's spring carries. Parameters per joint: the
    spring's stiffness (N/m) and its tension at the joint's zero (N); the torque is linear in
    both. Needs ``joint_compliance`` (the torque acts through the joint's compliance)."""

    name: ClassVar[str] = "gravity_compensator"
    requires: ClassVar[tuple[str, ...]] = ("joint_compliance",)
    #: typical sizes of the stiffness (N/m) and the tension (N)
    SIZES: ClassVar[tuple[float, float]] = (1e3, 1e2)

    def __init__(self) -> None:
        self._springs: list[tuple[int, GravityCompensator]] | None = None

    @staticmethod
    def spring(robot: Robot, joint: str) -> GravityCompensator:
        """The library's compensator on ``joint`` with its default geometry, its angle
        measured from the link's upward direction
        (:func:`~stiffness.mechanics.gravity.upward_angle`)."""
        up = upward_angle(robot, joint)
        return GravityCompensator(joint_name=joint, angle_up_rad=up.angle_rad,
                                  angle_reference=up.reference, reference_reason=up.reason)

    def _joints(self, pm: PoseLayout) -> list[tuple[int, GravityCompensator]]:
        """Each revolute compliant joint (id) and its spring (built once per model)."""
        if self._springs is None:
            names = pm.robot.model.names
            self._springs = [(j, self.spring(pm.robot, names[j])) for j in pm.compliant
                             if not pm.robot.is_prismatic(names[j])]
        return self._springs

    def parameters(self, pm: PoseLayout) -> list[Parameter]:
        return [Parameter(self.name, compensator_label(spring.joint_name, what), size, unit)
                for _, spring in self._joints(pm)
                for what, size, unit in zip(("stiffness", "preload"), self.SIZES, ("N/m", "N"),
                                            strict=True)]

    def _unit_torques(self, pm: PoseLayout, q: np.ndarray) -> list[tuple[int, np.ndarray]]:
        """Per joint, its velocity index and the torque (N.m) per unit stiffness and per unit
        tension at the loaded angle."""
        model = pm.robot.model
        out = []
        for j, spring in self._joints(pm):
            theta = _joint_angle(model, j, q)
            out.append((model.joints[j].idx_v,
                        np.array([float(spring.torque(unit, np.array(theta))[0])
                                  for unit in (np.array([1.0, 0.0]), np.array([0.0, 1.0]))])))
        return out

    def joint_torque(self, pm: PoseLayout, x_f: np.ndarray, state: SagState) -> np.ndarray:
        out = np.zeros(state.torque.size)
        model = pm.robot.model
        for n, (j, spring) in enumerate(self._joints(pm)):
            p = x_f[2 * n: 2 * n + 2]
            if p.any():  # a spring without stiffness or tension adds nothing
                theta = np.array(_joint_angle(model, j, state.q))
                out[model.joints[j].idx_v] += float(spring.torque(p, theta)[0])
        return out

    def torque_columns(self, pm: PoseLayout, x_f: np.ndarray, state: SagState) -> np.ndarray:
        out = np.zeros((state.torque.size, x_f.size))
        for n, (v, unit) in enumerate(self._unit_torques(pm, state.q)):
            out[v, 2 * n: 2 * n + 2] = unit
        return out
