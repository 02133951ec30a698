"""Effects on the joint laws: ``complementary_stiffness`` (load-dependent geometry),
``joint_compliance`` (a rigid joint is a spring), ``backlash`` (lost motion) and
``nonlinear_joint_stiffness`` (a spring that softens or hardens).

Each class carries its prediction hooks (:class:`stiffness.elastic.effects.base.Effect`) and
its contribution to a model used away from its campaign (:meth:`Effect.contribute`).

Units: SI (rad, m, N.m, N.m/rad; m, N, N/m for prismatic joints).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import ClassVar, TypeVar

import numpy as np

from stiffness.elastic.effects.base import Effect, Parameter, stiffness_report
from stiffness.elastic.effects.geometry import Geometry
from stiffness.errors import StiffnessError, UnknownJointError, did_you_mean

JointEffect = TypeVar("JointEffect", "JointCompliance", "Backlash", "NonlinearJointStiffness")


def joint_effect(cls: type[JointEffect], where: str | None, geometry: Geometry) -> JointEffect:
    """``cls`` at the coordinate joint ``where`` of ``geometry``.

    Raises
    ------
    UnknownJointError
        ``where`` is not a coordinate joint.
    """
    name = cls.name
    if where not in geometry.joints:
        raise UnknownJointError(f"{name} needs a joint, e.g. {name}:{geometry.joints[0]}; "
                                f"{did_you_mean(str(where), list(geometry.joints))}",
                                name=str(where), choices=geometry.joints)
    return cls(joint_name=where, prismatic=bool(geometry.prismatic[geometry.joints.index(where)]))


class ComplementaryStiffness(Effect):
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
class JointCompliance(Effect):
    """A joint declared rigid is a spring of stiffness ``k``."""

    joint_name: str = ""
    prismatic: bool = False
    name: ClassVar[str] = "joint_compliance"
    param_names: ClassVar[tuple[str, ...]] = ("stiffness",)
    through_law: ClassVar[bool] = True
    value_counts: ClassVar[tuple[int, ...]] = (1,)

    def __post_init__(self) -> None:
        self.added_joint = self.joint_name
        self.joint = self.joint_name

    @classmethod
    def at_place(cls, where, geometry):
        return joint_effect(cls, where, geometry)

    @classmethod
    def declared(cls, where, settings):
        return cls(joint_name=str(where))

    def simulated_values(self, values, units):
        if values[0] <= 0:
            raise StiffnessError(f"joint_compliance:{self.joint_name} needs a positive stiffness")
        return np.asarray(values, dtype=float)

    def contribute(self, values, parts):
        parts.add_spring(self.joint_name, values[0])

    @property
    def where(self) -> str:
        return self.joint_name

    def bounds(self):
        return np.zeros(1), np.full(1, 1e4)

    def start(self):
        return np.full(1, 1e-3)

    def scale(self, refs):
        return np.full(1, 1.0 / refs.k_ref)  # compliance

    def adjust_law(self, p, law, column, refs):
        law.compliance[column] = p[0]

    def variables(self, values, refs):
        return (1.0 / np.asarray(values, dtype=float)[:1]) / self.scale(refs)

    def report(self, u, cov_u, refs, units, quantile):
        unit = "N/m" if self.prismatic else "N.m/rad"
        return [stiffness_report("stiffness", float(u[0]), float(cov_u[0, 0]),
                                  1.0 / refs.k_ref, unit, quantile)]

    def describe(self) -> str:
        return f"joint {self.joint_name}, declared rigid, is a spring"


@dataclass(eq=False)
class Backlash(Effect):
    """Lost motion at a joint: ``dtheta += b tanh(tau / tau_s)``."""

    joint_name: str = ""
    prismatic: bool = False
    #: smoothing torque (N.m, N) a model file gives; ``None``: the campaign's
    smoothing_torque: float | None = None
    name: ClassVar[str] = "backlash"
    kind: ClassVar[str] = "lost_motion"
    param_names: ClassVar[tuple[str, ...]] = ("half_width",)
    through_law: ClassVar[bool] = True
    value_counts: ClassVar[tuple[int, ...]] = (1,)

    def __post_init__(self) -> None:
        self.joint = self.joint_name

    @classmethod
    def at_place(cls, where, geometry):
        return joint_effect(cls, where, geometry)

    @classmethod
    def declared(cls, where, settings):
        return cls(joint_name=str(where)).configured(settings)

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

    @property
    def where(self) -> str:
        return self.joint_name

    def bounds(self):
        return np.zeros(1), np.full(1, 1e4)

    def start(self):
        return np.full(1, 1e-3)

    def scale(self, refs):
        return np.full(1, refs.theta_ref)

    def adjust_law(self, p, law, column, refs):
        law.backlash[column] = p[0]

    def _units(self, units):
        if self.prismatic:
            return [(units.length, units.length_to_si)]
        return [(units.angle, units.angle_to_si)]

    def describe(self) -> str:
        return f"joint {self.joint_name} has lost motion (a dead band around zero torque)"



@dataclass(eq=False)
class NonlinearJointStiffness(Effect):
    """``dtheta = tau / k (1 + beta |tau|)``: the spring softens (beta > 0) or hardens."""

    joint_name: str = ""
    prismatic: bool = False
    name: ClassVar[str] = "nonlinear_joint_stiffness"
    param_names: ClassVar[tuple[str, ...]] = ("beta",)
    through_law: ClassVar[bool] = True
    beyond_springs: ClassVar[bool] = True
    value_counts: ClassVar[tuple[int, ...]] = (1,)

    def __post_init__(self) -> None:
        self.joint = self.joint_name

    @classmethod
    def at_place(cls, where, geometry):
        return joint_effect(cls, where, geometry)

    @classmethod
    def declared(cls, where, settings):
        return cls(joint_name=str(where))

    def contribute(self, values, parts):
        parts.soften(self.joint_name, values[0])

    @property
    def where(self) -> str:
        return self.joint_name

    def bounds(self):
        return np.full(1, -0.95), np.full(1, 100.0)

    def scale(self, refs):
        return np.full(1, 1.0 / refs.max_torque(self.joint_name))

    def adjust_law(self, p, law, column, refs):
        law.beta[column] = p[0]

    def report(self, u, cov_u, refs, units, quantile):
        beta = super().report(u, cov_u, refs, units, quantile)[0]
        se_u = math.sqrt(max(float(cov_u[0, 0]), 0.0))
        rel = float(u[0])
        return [beta, Parameter("relative_change_at_max_torque", rel, se_u,
                                (rel - quantile * se_u, rel + quantile * se_u), "1")]

    def _units(self, units):
        return [("1/N" if self.prismatic else "1/(N.m)", 1.0)]

    def describe(self) -> str:
        return f"joint {self.joint_name}'s spring softens or hardens with the load"

