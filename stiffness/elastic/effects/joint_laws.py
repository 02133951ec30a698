"""Effects on the joint laws: ``complementary_stiffness`` (load-dependent geometry),
``joint_compliance`` (a rigid joint is a spring), ``backlash`` (lost motion) and
``nonlinear_joint_stiffness`` (a spring that softens or hardens).

Each class carries its prediction hooks
(:class:`stiffness.elastic.effects.deflection_face.DeflectionEffect`) and its contribution to a
model used away from its campaign (:meth:`Effect.contribute`);
``joint_compliance``, ``backlash`` and ``nonlinear_joint_stiffness`` also their pose-model
face (:class:`~stiffness.elastic.effects.pose_face.JointDeflectionFamily`: on every spring of
a pose model, a compliant joint or a controller coordinate through the spring map, under
gravity and the applied wrench, their part of the joints' deflection in the sag's fixed point,
:meth:`stiffness.calibration.pose_model.PoseModel.loaded_configuration`).

The law's terms (``c t``, ``gamma t |t|``, ``b tanh(t / tau_s)``) are
:mod:`stiffness.mechanics.law_terms`'.

Units: SI (rad, m, N.m, N.m/rad; m, N, N/m for prismatic joints).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import ClassVar, TypeVar

import numpy as np

from stiffness.elastic.effects.deflection_face import DeflectionEffect, Settings
from stiffness.elastic.effects.geometry import BACKLASH_SMOOTHING, Geometry, References
from stiffness.elastic.effects.pose_face import (
    BACKLASH_SETTING,
    NONLINEAR_SETTING,
    FamilyParameter,
    JointDeflectionFamily,
    PoseLayout,
    SagState,
    backlash_label,
    compliance_label,
    nonlinear_label,
)
from stiffness.errors import StiffnessError, UnknownJointError, did_you_mean
from stiffness.mechanics.law_terms import (
    linear,
    lost_motion,
    lost_motion_column,
    softening,
    softening_column,
)
from stiffness.robot.robot import Robot

#: A per-joint effect's own class (:meth:`JointEffect.at_place`).
J = TypeVar("J", bound="JointEffect")


def spring_setting(pm: PoseLayout, family: str, setting: str, what: str
                   ) -> tuple[list[int], np.ndarray]:
    """The columns of ``pm``'s spring map that ``family``'s per-spring ``setting`` names (the
    springs carrying torque in the campaign) and their values (N.m or N).

    Raises
    ------
    StiffnessError
        The model was built without the setting.
    """
    given = pm.settings.get(setting)
    if not isinstance(given, dict):
        raise StiffnessError(f"{family} needs each spring's {what} (setting {setting}); build "
                             "the model with pose_fit.campaign_settings(campaign)")
    columns = [s for s, n in enumerate(pm.springs) if n in given]
    return columns, np.array([float(given[pm.springs[s]]) for s in columns])


@dataclass(eq=False)
class JointEffect(DeflectionEffect):
    """The shared part of the per-joint effects (the joint laws, a spring compensator): the
    joint (``joint_name``, whether it is prismatic), where it acts (:attr:`where`: the joint)
    and its placement checked against the robot (a revolute joint where
    :attr:`revolute_only`)."""

    joint_name: str = ""
    prismatic: bool = False
    #: whether the effect needs a revolute joint
    revolute_only: ClassVar[bool] = False
    #: whether the effect acts on one link, at its chain joint's angle (a spring compensator):
    #: a controller coordinate then qualifies only one to one with a chain joint
    #: (:meth:`placement_problem`)
    one_link: ClassVar[bool] = False

    @classmethod
    def at_place(cls: type[J], where: str | None, geometry: Geometry | None = None) -> J:
        """The effect at the coordinate joint ``where`` of ``geometry`` (unchecked without).

        Raises
        ------
        UnknownJointError
            ``where`` is not a coordinate joint (a revolute one where :attr:`revolute_only`).
        """
        if geometry is None:
            return cls(joint_name=str(where))
        joints = [j for j, p in zip(geometry.joints, geometry.prismatic, strict=True)
                  if not (p and cls.revolute_only)]
        if where not in joints:
            kind = "a revolute joint" if cls.revolute_only else "a joint"
            problem = (f"{cls.name} needs {kind}, e.g. {cls.name}:{joints[0]}" if not where else
                       f"{cls.name}:{where}: {where!r} is not {kind} of {geometry.robot.title} "
                       f"with a spring")
            raise UnknownJointError(f"{problem}; {did_you_mean(str(where), joints)}",
                                    name=str(where), choices=joints)
        if problem := cls.placement_problem(geometry.robot, where):
            raise StiffnessError(problem)
        return cls(joint_name=where,
                   prismatic=bool(geometry.prismatic[geometry.joints.index(where)]))

    @classmethod
    def placement_problem(cls, robot: Robot, where: str | None) -> str:
        """Why the effect cannot act at ``robot``'s spring ``where`` (one line naming the fix),
        or "": an effect on one link (:attr:`one_link`) needs a chain joint carrying one link,
        and a controller coordinate is one only when it alone turns one chain joint at rate 1
        (:meth:`~stiffness.robot.coupling.CoordinateMap.sole_joint`; ``T2``, turning ``t2``
        and the passive ``t4``, is none)."""
        coupling = robot.coupling
        if not (cls.one_link and robot.springs_on_controller and coupling is not None
                and where in coupling.coordinates) or coupling.sole_joint(where) is not None:
            return ""
        turned = [j for j, a in zip(coupling.chain, coupling.column(where), strict=True) if a]
        fit = [c for c in robot.compliant_joints
               if coupling.sole_joint(c) is not None and not robot.is_prismatic(c)]
        fix = (f"put it on a coordinate that alone turns one chain joint ({', '.join(fit)}) "
               "or drop it" if fit else "compensators are not available for these springs")
        return (f"{cls.name}:{where} needs a chain joint carrying one link, and controller "
                f"coordinate {where} turns {', '.join(turned)} (springs on the controller's "
                f"coordinates); {fix}")

    @property
    def where(self) -> str:
        return self.joint_name


class ComplementaryStiffness(DeflectionEffect):
    """Load-dependent geometry: ``K_C`` and the second-order kinematics of the deflection."""

    name = "complementary_stiffness"
    second_order = True
    value_counts = (0, 1)

    def simulated_values(self, values, units):
        return np.zeros(0)

    def describe(self) -> str:
        return ("the load changes the geometry: K_C in the tangent stiffness and the "
                "second-order kinematics (exact equilibrium to second order)")


@dataclass(eq=False)
class JointCompliance(JointEffect, JointDeflectionFamily):
    """A joint declared rigid is a spring of stiffness ``k``.

    Pose face: ``Delta q_j = c_j tau_j`` on each compliant joint (rad/(N.m), or m/N), ``tau``
    the torque the springs carry at the loaded configuration; springs on controller
    coordinates (``S``: :attr:`PoseLayout.spring_map`) give ``Delta q = S diag(c) S^T tau``.
    """

    name: ClassVar[str] = "joint_compliance"
    param_names: ClassVar[tuple[str, ...]] = ("stiffness",)
    adds_spring: ClassVar[bool] = True
    through_law: ClassVar[bool] = True
    nonnegative: ClassVar[bool] = True
    compliance_variables: ClassVar[bool] = True
    value_counts: ClassVar[tuple[int, ...]] = (1,)

    def simulated_values(self, values, units):
        if values[0] <= 0:
            raise StiffnessError(f"joint_compliance:{self.joint_name} needs a positive stiffness")
        return np.asarray(values, dtype=float)

    def contribute(self, values, parts):
        parts.add_spring(self.joint_name, values[0])

    def adjust_law(self, p, law, column, refs):
        law.compliance[column] = p[0]

    def units(self, units):
        return [("N/m" if self.prismatic else "N.m/rad", 1.0)]

    def describe(self) -> str:
        return f"joint {self.joint_name}, declared rigid, is a spring"

    # pose face ----------------------------------------------------------------------------
    sized_as_effect: ClassVar[bool] = True

    def family_parameters(self, pm: PoseLayout) -> list[FamilyParameter]:
        return [self.param(compliance_label(n),
                           "m/N" if pm.robot.is_prismatic(n) else "rad/(N.m)")
                for n in pm.springs]

    def joint_deflection(self, pm: PoseLayout, x_f: np.ndarray, state: SagState) -> np.ndarray:
        return linear(x_f, state.torque @ pm.spring_map)[0] @ pm.spring_map.T

    def deflection_per_torque(self, pm: PoseLayout, x_f: np.ndarray, state: SagState
                              ) -> np.ndarray:
        """The diagonal of ``S diag(c) S^T``: exact for springs on joints; with springs on
        controller coordinates the coupling's off-diagonal terms are left out (they would
        matter only to a family adding its own torque on a chain joint)."""
        return pm.spring_map ** 2 @ x_f

    def deflection_columns(self, pm: PoseLayout, x_f: np.ndarray, state: SagState
                           ) -> np.ndarray:
        return pm.spring_map * (state.torque @ pm.spring_map)[..., None, :]


@dataclass(eq=False)
class Backlash(JointEffect, Settings, JointDeflectionFamily):
    """Lost motion at a joint: ``dtheta += b tanh(tau / tau_s)``.

    Pose face: on each spring, ``Delta u_j += b_j tanh(t_j / tau_s)`` with ``t = S^T tau``
    the torque it carries and ``Delta q = S Delta u`` (``S``: :attr:`PoseLayout.spring_map`,
    the unit columns for springs on joints; a spring on a controller coordinate loses motion
    on that coordinate, as the deflection face and the elastic model have it); ``tau_s`` =
    :data:`~stiffness.elastic.effects.geometry.BACKLASH_SMOOTHING` times the RMS of ``t_j``
    over the campaign, setting ``backlash_smoothing_torque`` by spring name; ``b_j`` rad (m
    prismatic), named after the spring. A spring whose torque is nil at every pose of the
    campaign (below :data:`NIL_TORQUE` of the largest spring's RMS: a vertical base axis) has
    no parameter: its lost motion never shows.
    """

    #: smoothing torque (N.m, N) a model file gives; ``None``: the campaign's
    smoothing_torque: float | None = None
    #: the pose face's springs (columns of the spring map) and their smoothing torques,
    #: built once per model
    _pose_layout: tuple[list[int], np.ndarray] | None = field(default=None, init=False,
                                                              repr=False)
    name: ClassVar[str] = "backlash"
    kind: ClassVar[str] = "lost_motion"
    param_names: ClassVar[tuple[str, ...]] = ("half_width",)
    through_law: ClassVar[bool] = True
    nonnegative: ClassVar[bool] = True
    value_counts: ClassVar[tuple[int, ...]] = (1,)

    def configured(self, settings):
        return dataclasses.replace(
            self, smoothing_torque=float(settings.get("smoothing_torque", 1.0)))

    def file_settings(self, refs):
        return {"smoothing_torque": float(refs.tau_smoothing[refs.joints.index(self.joint_name)])}

    def simulated_values(self, values, units):
        return np.array([values[0] * (units.length_to_si if self.prismatic
                                      else units.angle_to_si)])

    def contribute(self, values, parts):
        parts.add_backlash(self.joint_name, values[0], self.smoothing_torque)

    def scale(self, refs):
        return np.full(1, refs.theta_ref)

    def adjust_law(self, p, law, column, refs):
        law.backlash[column] = p[0]

    def units(self, units):
        if self.prismatic:
            return [(units.length, units.length_to_si)]
        return [(units.angle, units.angle_to_si)]

    def describe(self) -> str:
        return f"joint {self.joint_name} has lost motion (a dead band around zero torque)"

    # pose face ----------------------------------------------------------------------------
    family_scale: ClassVar[float] = 1e-4
    sized_as_effect: ClassVar[bool] = True
    needs_masses: ClassVar[bool] = True
    #: the model setting naming each spring's smoothing torque (N.m or N)
    SETTING: ClassVar[str] = BACKLASH_SETTING
    #: RMS torque, relative to the largest spring's, below which a spring carries none
    NIL_TORQUE: ClassVar[float] = 1e-6

    def family_parameters(self, pm: PoseLayout) -> list[FamilyParameter]:
        columns, _ = self._springs(pm)
        return [self.param(backlash_label(pm.springs[s]),
                           "m" if pm.robot.is_prismatic(pm.springs[s]) else "rad")
                for s in columns]

    @classmethod
    def campaign_settings(cls, torques: np.ndarray, pm: PoseLayout) -> dict:
        """``backlash_smoothing_torque``: spring name -> smoothing torque, from the RMS of the
        torques ``t = S^T tau`` each spring carries at the campaign's commanded poses (the
        (rows, nv) ``torques``; springs that carry none left out)."""
        rms = np.sqrt(np.mean((torques @ pm.spring_map) ** 2, axis=0))
        top = float(rms.max(initial=0.0))
        return {cls.SETTING: {n: float(BACKLASH_SMOOTHING * r)
                              for n, r in zip(pm.springs, rms, strict=True)
                              if r > cls.NIL_TORQUE * top}}

    def _springs(self, pm: PoseLayout) -> tuple[list[int], np.ndarray]:
        """The columns of the spring map with a parameter and their smoothing torques."""
        if self._pose_layout is None:  # built once per model
            self._pose_layout = spring_setting(pm, self.name, self.SETTING, "smoothing torque")
        return self._pose_layout

    def _carried(self, pm: PoseLayout, state: SagState
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The spring map's columns (nv, n_f) of the springs with a parameter, the torques
        ``t`` (..., n_f) they carry at ``state`` and the smoothing torques (n_f,)."""
        columns, smooth = self._springs(pm)
        spring_map = pm.spring_map[:, columns]
        return spring_map, state.torque @ spring_map, smooth

    def joint_deflection(self, pm: PoseLayout, x_f: np.ndarray, state: SagState) -> np.ndarray:
        spring_map, t, smooth = self._carried(pm, state)
        return (x_f * lost_motion_column(t, smooth)) @ spring_map.T

    def deflection_per_torque(self, pm: PoseLayout, x_f: np.ndarray, state: SagState
                              ) -> np.ndarray:
        """The diagonal of ``S diag(b sech^2(t / tau_s) / tau_s) S^T`` (as
        ``joint_compliance``'s)."""
        spring_map, t, smooth = self._carried(pm, state)
        return lost_motion(x_f, t, smooth)[1] @ (spring_map ** 2).T

    def deflection_columns(self, pm: PoseLayout, x_f: np.ndarray, state: SagState
                           ) -> np.ndarray:
        spring_map, t, smooth = self._carried(pm, state)
        return spring_map * lost_motion_column(t, smooth)[..., None, :]


@dataclass(eq=False)
class NonlinearJointStiffness(JointEffect, JointDeflectionFamily):
    """``dtheta = tau / k (1 + beta |tau|)``: the spring softens (beta > 0) or hardens.

    Pose face: on each spring, ``Delta u_j += gamma_j t_j |t_j|`` with ``t = S^T tau`` the
    torque the spring carries and ``Delta q = S Delta u`` (``S``:
    :attr:`PoseLayout.spring_map`, the unit columns for springs on joints), so that with
    ``joint_compliance``'s ``c_j t_j`` the spring's secant compliance is ``c_j + gamma_j
    |t_j|``. The parameter is ``gamma_j = c_j beta_j`` (rad/(N.m)^2, m/N^2 prismatic): a hook
    sees only its own family's parameters, and the deflection is linear in ``gamma``; a model
    used away from the campaign takes ``beta = gamma / c``
    (:mod:`stiffness.elastic.calibrated`). Typical size :attr:`family_scale` over the
    spring's largest torque ``tau_max`` at the campaign's commanded poses (setting
    :data:`~stiffness.elastic.effects.pose_face.NONLINEAR_SETTING`), physical scale
    ``1 / (k_ref tau_max)`` (the compliance doubled at ``tau_max``: the deflection face's
    ``1 / tau_max`` over ``k_ref``). A spring carrying no torque in the campaign (below
    :data:`NIL_TORQUE` of the largest) has no parameter. Needs ``joint_compliance`` (whose
    spring it bends) and the links' masses (it acts on the torque the springs carry).
    """

    #: the pose face's springs (columns of the spring map) and their largest torques,
    #: built once per model
    _pose_layout: tuple[list[int], np.ndarray] | None = field(default=None, init=False,
                                                              repr=False)
    name: ClassVar[str] = "nonlinear_joint_stiffness"
    param_names: ClassVar[tuple[str, ...]] = ("beta",)
    through_law: ClassVar[bool] = True
    beyond_springs: ClassVar[bool] = True
    value_counts: ClassVar[tuple[int, ...]] = (1,)
    #: beta times the campaign's largest torque on the joint
    relative_change: ClassVar[str] = "relative_change_at_max_torque"

    def contribute(self, values, parts):
        parts.soften(self.joint_name, values[0])

    def bounds(self):
        return np.full(1, -0.95), np.full(1, 100.0)

    def scale(self, refs):
        return np.full(1, 1.0 / refs.max_torque(self.joint_name))

    def physical_scale(self, refs):
        return self.scale(refs)  # the spring's compliance doubled at the largest torque

    def adjust_law(self, p, law, column, refs):
        law.beta[column] = p[0]

    def units(self, units):
        return [("1/N" if self.prismatic else "1/(N.m)", 1.0)]

    def describe(self) -> str:
        return f"joint {self.joint_name}'s spring softens or hardens with the load"

    # pose face ----------------------------------------------------------------------------
    requires: ClassVar[tuple[str, ...]] = ("joint_compliance",)
    needs_masses: ClassVar[bool] = True
    #: the model setting naming each spring's largest torque (N.m or N)
    SETTING: ClassVar[str] = NONLINEAR_SETTING
    #: largest torque, relative to the largest spring's, below which a spring carries none
    NIL_TORQUE: ClassVar[float] = 1e-6

    def family_parameters(self, pm: PoseLayout) -> list[FamilyParameter]:
        columns, largest = self._springs(pm)
        return [FamilyParameter(self.name, nonlinear_label(pm.springs[s]), self.family_scale / t,
                                "m/N^2" if pm.robot.is_prismatic(pm.springs[s])
                                else "rad/(N.m)^2")
                for s, t in zip(columns, largest, strict=True)]

    @classmethod
    def campaign_settings(cls, torques: np.ndarray, pm: PoseLayout) -> dict:
        """:data:`~stiffness.elastic.effects.pose_face.NONLINEAR_SETTING`: spring name ->
        the largest |torque| it carries at the campaign's commanded poses (``S^T tau`` of the
        (rows, nv) ``torques``; springs that carry none left out)."""
        largest = np.abs(torques @ pm.spring_map).max(axis=0, initial=0.0)
        top = float(largest.max(initial=0.0))
        return {cls.SETTING: {n: float(t) for n, t in zip(pm.springs, largest, strict=True)
                              if t > cls.NIL_TORQUE * top}}

    def physical_sizes(self, pm: PoseLayout, refs: References) -> np.ndarray:
        columns, _ = self._springs(pm)
        return np.array([NonlinearJointStiffness(joint_name=pm.springs[s]).physical_scale(
            refs)[0] / refs.k_ref for s in columns])

    def _springs(self, pm: PoseLayout) -> tuple[list[int], np.ndarray]:
        """The columns of the spring map with a parameter and their largest torques."""
        if self._pose_layout is None:  # built once per model
            self._pose_layout = spring_setting(pm, self.name, self.SETTING, "largest torque")
        return self._pose_layout

    def _carried(self, pm: PoseLayout, state: SagState) -> tuple[np.ndarray, np.ndarray]:
        """The spring map's columns (nv, n_f) of the springs with a parameter and the torques
        (..., n_f) they carry at ``state``."""
        columns, _ = self._springs(pm)
        spring_map = pm.spring_map[:, columns]
        return spring_map, state.torque @ spring_map

    def joint_deflection(self, pm: PoseLayout, x_f: np.ndarray, state: SagState) -> np.ndarray:
        spring_map, t = self._carried(pm, state)
        return softening(x_f, t)[0] @ spring_map.T

    def deflection_per_torque(self, pm: PoseLayout, x_f: np.ndarray, state: SagState
                              ) -> np.ndarray:
        """The diagonal of ``S diag(2 gamma |t|) S^T`` (as ``joint_compliance``'s)."""
        spring_map, t = self._carried(pm, state)
        return softening(x_f, t)[1] @ (spring_map ** 2).T

    def deflection_columns(self, pm: PoseLayout, x_f: np.ndarray, state: SagState
                           ) -> np.ndarray:
        spring_map, t = self._carried(pm, state)
        return spring_map * softening_column(t)[..., None, :]
