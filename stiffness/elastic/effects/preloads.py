"""Preloads: loads present at every pose. ``gravity_preload`` (the links' weight and a payload),
``gravity_compensator`` (a spring between the base and a lever on a link) and, for pose models
whose links' masses are unknown, ``gravity_lumped`` (the weight's sag lumped with the joints'
compliance).

The measured deflection is then the loaded minus the unloaded equilibrium at the commanded
pose; the preload's torque joins the joint load (a nonlinear spring's operating point) and its
derivative the stiffness. In a pose model (the pose face,
:class:`~stiffness.elastic.effects.pose_face.JointDeflectionFamily`) a compensator's torque at
the loaded joint angle joins what the joint's spring carries.

Units: SI (kg, m, N, N/m, N.m, rad).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
import pinocchio as pin

from stiffness.batch.linalg import cross
from stiffness.batch.poses import gravity_regressors
from stiffness.elastic.effects.base import PHYSICAL_FACTOR, effect_place
from stiffness.elastic.effects.deflection_face import DeflectionEffect, Settings
from stiffness.elastic.effects.geometry import References, skew
from stiffness.elastic.effects.joint_laws import JointEffect
from stiffness.elastic.effects.pose_face import (
    FamilyParameter,
    JointDeflectionFamily,
    PoseLayout,
    SagState,
    compensator_label,
    layout_cached,
)
from stiffness.errors import StiffnessError
from stiffness.mechanics.gravity import (
    ANGLE_REFERENCES,
    GRAVITY_PARAMETERS,
    compensator_torque,
    require_open_chain,
    upward_angle,
    weighed_bodies,
)
from stiffness.robot.kinematics import reach
from stiffness.robot.robot import Robot

#: Default geometry of ``gravity_compensator`` (m, m, rad, rad): lever on the link, distance of
#: the base attachment from the axis, the reference angle (:func:`upward_angle`; 0: the joint's
#: zero, as a model file written before the upward reference reads) and the angle between lever
#: and base there.
COMPENSATOR_GEOMETRY: dict[str, float | str] = {
    "lever_m": 0.1, "base_m": 0.3, "angle_up_rad": 0.0, "angle0_rad": 0.0,
    "angle_reference": "joint_zero"}
#: Unit of a lumped gravity parameter (compliance times a mass or a mass moment).
LUMPED_UNIT = "rad/(N.m) x (kg or kg.m)"
#: Lower bound of each gravity parameter (:data:`GRAVITY_PARAMETERS`) in ``gravity_lumped``:
#: a mass is never negative; a mass moment ``m c_i`` takes the sign of the centre's
#: coordinate ``c_i`` in the link's joint frame, either.
MASS_LOWER = {"m": 0.0, "mcx": -math.inf, "mcy": -math.inf, "mcz": -math.inf}


@dataclass(eq=False)
class GravityPreload(DeflectionEffect):
    """The robot's weight (URDF inertias) and a payload preload the joints at every pose.

    The payload's centre of mass is fitted within ``reach_m`` of the target frame's origin
    along each axis (the robot's reach, :func:`reach`): a centre of mass tens of metres away
    is no payload, and a small mass there mimics other effects' angle dependence.
    """

    reach_m: float = 1e3
    name: ClassVar[str] = "gravity_preload"
    kind: ClassVar[str] = "preload"
    param_names: ClassVar[tuple[str, ...]] = ("mass", "com_x", "com_y", "com_z")
    beyond_springs: ClassVar[bool] = True
    value_counts: ClassVar[tuple[int, ...]] = (1, 4)

    @classmethod
    def at_place(cls, where, geometry=None):
        placed = super().at_place(where, geometry)
        if geometry is None:
            return placed
        require_open_chain(geometry.robot, cls.name)
        return cls(reach_m=reach(geometry.robot.model))

    def simulated_values(self, values, units):
        if values[0] < 0:
            raise StiffnessError(f"gravity_preload needs a payload mass >= 0 kg, got {values[0]}")
        com = np.zeros(3) if len(values) == 1 else np.array(values[1:4]) * units.length_to_si
        return np.concatenate([[float(values[0])], com])

    def contribute(self, values, parts):
        parts.weigh(values[0], values[1:4])

    def scale(self, refs):
        return np.array([refs.force_ref / 9.81, 0.1, 0.1, 0.1])

    def physical_scale(self, refs):
        """A payload :data:`~stiffness.elastic.effects.base.PHYSICAL_FACTOR` times the weight
        of the campaign's load range (kg, ``force_ref / g``), its centre of mass
        within the robot's reach (m, :attr:`References.reach_m`) of the target."""
        return np.array([PHYSICAL_FACTOR * refs.force_ref / 9.81] + [refs.reach_m] * 3)

    def bounds(self):
        com = self.reach_m / 0.1  # variables: com / 0.1 m (scale)
        return np.array([0.0, -com, -com, -com]), np.array([1e4, com, com, com])

    def start(self):
        return np.array([0.05, 0.0, 0.0, 0.0])

    def preload(self, p, model, rows):
        idx = model.index
        if rows.gravity_torque is None or not np.all(np.isfinite(rows.gravity_torque)):
            require_open_chain(model.geometry.robot, self.name)
        tau = rows.gravity_torque[:, idx]
        k_g = rows.gravity_stiffness[:, idx][:, :, idx]
        f = p[0] * np.asarray(model.geometry.robot.model.gravity.linear, dtype=float)
        r = rows.rotation @ p[1:4]
        moment = cross(r, f)
        wrench = np.hstack([np.broadcast_to(f, moment.shape), moment])
        tau = tau + model.jv.transpose(0, 2, 1) @ f + np.einsum("mkn,mk->mn", model.jw, moment)
        k_p = np.einsum("mk,mkab->mab", wrench, model.h)
        k_p += model.jw.transpose(0, 2, 1) @ (skew(f) @ skew(r)) @ model.jw
        return tau, k_g + k_p

    def units(self, units):
        return [("kg", 1.0)] + [(units.length, units.length_to_si)] * 3

    def describe(self) -> str:
        return ("the robot's weight and a payload preload the joints (the measured deflection "
                "is loaded minus unloaded under that weight)")


#: Where a compensator's lever and base lengths come from: the library's defaults
#: (:data:`COMPENSATOR_GEOMETRY`), the user's declaration, or the fit (when the data determine
#: them).
GEOMETRY_SOURCES = ("default", "declared", "fitted")
#: Bounds of the fitted base length, as multiples of its declared value (and on the declared
#: side of the lever).
GEOMETRY_RANGE = (0.05, 20.0)
#: A compensator's physical scale takes its joint's weight torque as at least this fraction of
#: the largest one the weight puts on any joint (:meth:`GravityCompensator.physical_scale`).
WEIGHT_FLOOR = 0.01


@dataclass(eq=False)
class GravityCompensator(JointEffect, Settings, JointDeflectionFamily):
    """A spring between the base and a lever on the joint's link, its angle measured from the
    link's upward direction at zero load
    (:func:`stiffness.mechanics.gravity.compensator_torque`,
    :func:`stiffness.mechanics.gravity.upward_angle`). Its lever and base lengths are settings
    (the library's defaults or the user's declaration). The torque depends on the stiffness
    ``k``, the preload ``F0``, the lever ``a`` and the base ``d`` exactly through ``F0 a``,
    ``k a^2`` and ``a / d`` (scaling both lengths by ``s`` and ``F0, k`` by ``1/s, 1/s^2``
    leaves it unchanged): the lever is always the declared one (``k`` and ``F0`` are in its
    terms), the base becomes the parameter ``base`` (m) after them when the data determine the
    ratio (``geometry_source = "fitted"``, :meth:`settings_freed`).

    Pose face: one compensator with its default geometry (:meth:`upward`), or the one the
    model's setting :data:`GEOMETRY_SETTING` declares (:meth:`declared_at`), on each revolute
    compliant joint, or controller coordinate that alone turns one revolute chain joint
    (:func:`compensated_joints`: on that joint, its angle the coordinate's); its torque at the
    loaded joint angle joins what the joint's spring carries. Parameters per joint: the
    spring's stiffness (N/m) and its tension at the joint's zero (N); the torque is linear in
    both. Needs ``joint_compliance`` (the torque acts
    through the joint's compliance)."""

    lever_m: float = float(COMPENSATOR_GEOMETRY["lever_m"])
    base_m: float = float(COMPENSATOR_GEOMETRY["base_m"])
    angle0_rad: float = float(COMPENSATOR_GEOMETRY["angle0_rad"])
    angle_up_rad: float = float(COMPENSATOR_GEOMETRY["angle_up_rad"])
    angle_reference: str = str(COMPENSATOR_GEOMETRY["angle_reference"])
    reference_reason: str = ""
    geometry_source: str = "default"
    geometry_note: str = ""
    #: the pose face's chain joints (id), their angles' offsets and their compensators, built
    #: once per model
    _pose_springs: list[tuple[int, float, GravityCompensator]] | None = field(
        default=None, init=False, repr=False)
    name: ClassVar[str] = "gravity_compensator"
    param_names: ClassVar[tuple[str, ...]] = ("stiffness", "preload")
    beyond_springs: ClassVar[bool] = True
    value_counts: ClassVar[tuple[int, ...]] = (2, 4)
    revolute_only: ClassVar[bool] = True
    one_link: ClassVar[bool] = True

    def __post_init__(self) -> None:
        if not (self.lever_m > 0 and self.base_m > 0 and abs(self.lever_m - self.base_m) > 1e-6):
            raise StiffnessError(f"gravity_compensator:{self.joint_name} needs a lever and a "
                                 f"base distance that are positive and differ, got "
                                 f"{self.lever_m} and {self.base_m} m")
        if self.angle_reference not in ANGLE_REFERENCES:
            raise StiffnessError(f"gravity_compensator:{self.joint_name}: angle_reference must "
                                 f"be one of {', '.join(ANGLE_REFERENCES)}, got "
                                 f"{self.angle_reference!r}")
        if self.geometry_source not in GEOMETRY_SOURCES:
            raise StiffnessError(f"gravity_compensator:{self.joint_name}: geometry_source must "
                                 f"be one of {', '.join(GEOMETRY_SOURCES)}, got "
                                 f"{self.geometry_source!r}")

    @classmethod
    def at_place(cls, where, geometry=None):
        placed = super().at_place(where, geometry)  # checked: a revolute joint of one link
        return placed if geometry is None else cls.upward(geometry.robot, str(where))

    def configured(self, settings):
        g = {**COMPENSATOR_GEOMETRY, **settings}
        return dataclasses.replace(self, lever_m=float(g["lever_m"]), base_m=float(g["base_m"]),
                                   angle0_rad=float(g["angle0_rad"]),
                                   angle_up_rad=float(g["angle_up_rad"]),
                                   angle_reference=str(g["angle_reference"]),
                                   reference_reason="" if "angle_reference" in settings
                                   else "a model file written before the upward reference",
                                   geometry_source=str(settings.get("geometry_source",
                                                                    "default")),
                                   geometry_note=str(settings.get("geometry_note", "")))

    def declare(self, settings):
        unknown = sorted(set(settings) - {"lever_m", "base_m"})
        if unknown:
            raise StiffnessError(f"{self.label} takes lever_m and base_m (m), not "
                                 f"{', '.join(unknown)}")
        values = {k: float(v) for k, v in settings.items()}
        if not all(math.isfinite(v) and v > 0 for v in values.values()):
            raise StiffnessError(f"{self.label}: lever_m and base_m must be positive lengths "
                                 f"in m, got {settings}")
        return dataclasses.replace(self, **values, geometry_source="declared")

    def settings_freed(self):
        if self.geometry_source == "fitted":
            return None
        return dataclasses.replace(self, geometry_source="fitted",
                                   geometry_note=f"base fitted from the {self.geometry_source} "
                                                 f"{self.base_m:g} m, lever {self.lever_m:g} m "
                                                 f"{self.geometry_source}")

    def settings_held(self, reason):
        return dataclasses.replace(self, geometry_note=(
            f"{reason}: the torque depends on k, F0, lever a and base d only through F0 a, "
            "k a^2 and a/d"))

    def file_settings(self, refs):
        return dict(self.settings)

    def simulated_values(self, values, units):
        if len(values) == 4 and not (values[2] > 0 and values[3] > 0
                                     and abs(values[2] - values[3]) > 1e-6):
            raise StiffnessError(f"gravity_compensator:{self.joint_name}=k,F0,lever,base needs "
                                 f"a lever and a base (m) that are positive and differ, got "
                                 f"{values[2]} and {values[3]}")
        return np.asarray(values, dtype=float)

    def contribute(self, values, parts):
        parts.add_compensator(self.joint_name, values[0], values[1], self.geometry(values))

    @property
    def parameter_names(self) -> tuple[str, ...]:
        fitted = ("base",) if self.geometry_source == "fitted" else ()
        return self.param_names + fitted

    @property
    def settings(self) -> dict:
        """The spring's geometry (SI), where its angle is measured from, and where its lever
        and base lengths come from (:data:`GEOMETRY_SOURCES`) with why."""
        return {"lever_m": self.lever_m, "base_m": self.base_m, "angle_up_rad": self.angle_up_rad,
                "angle0_rad": self.angle0_rad, "angle_reference": self.angle_reference,
                "geometry_source": self.geometry_source, "geometry_note": self.geometry_note}

    def geometry(self, values: np.ndarray) -> dict:
        """:attr:`settings` with the lengths of SI ``values``: (stiffness, preload, base) of
        a fitted base, or (stiffness, preload, lever, base) of ``stiffness simulate``."""
        g = self.settings
        if len(values) == 4:
            g.update(lever_m=float(values[2]), base_m=float(values[3]))
        elif len(values) == 3:
            g.update(base_m=float(values[2]))
        return g

    def scale(self, refs):
        ad = self.lever_m * self.base_m
        spring = [0.1 * refs.k_ref / ad, 0.1 * refs.k_ref / self.lever_m]
        return np.array(spring + ([self.base_m] if self.n_params == 3 else []))

    def physical_scale(self, refs):
        """The spring that balances the weight its joint carries (SI): with ``tau_w`` (N.m)
        the largest torque the links' weight puts on the joint over the campaign
        (:attr:`References.weight_torque`) and ``r = min(a, d)`` (m) the largest moment arm
        the spring reaches (``a d sin(phi) / L``, the lever ``a`` with the default geometry),

        * preload ``tau_w / r`` (N): the tension that balances that torque at that arm; a
          larger one turns the link against its weight at every angle;
        * stiffness ``tau_w / r^2`` (N/m): the spring whose tension grows by that much over
          ``r`` of stretch (its stroke is ``2 r``); the classical zero-free-length balancer
          of the whole weight, ``k a d = tau_w``, has ``k = tau_w / (a d)``, within it;
        * a fitted base: 10 times its length (:meth:`Effect.physical_scale`).

        ``tau_w`` is at least :data:`WEIGHT_FLOOR` times the largest the weight puts on any
        joint (a joint that carries almost nothing still gets a scale). Where the model does
        not give the weight (a robot with loops, or whose links weigh nothing) the scales are
        the joint spring's instead: the stiffness ``k_ref / (a d)`` whose torque derivative
        ``k a d`` equals the baseline stiffness ``k_ref`` (N.m/rad), the preload
        ``k_ref / a``."""
        a, d = self.lever_m, self.base_m
        base = list(super().physical_scale(refs)[2:])
        weight = refs.weight_torque
        if not weight or self.joint_name not in weight:
            return np.array([refs.k_ref / (a * d), refs.k_ref / a] + base)
        tau = max(weight[self.joint_name], WEIGHT_FLOOR * max(weight.values()))
        arm = min(a, d)
        return np.array([tau / arm ** 2, tau / arm] + base)

    def bounds(self):
        lo, hi = [0.0, -1e4], [1e4, 1e4]
        if self.n_params == 3:  # the base stays on its side of the lever (L > 0)
            ratio = self.lever_m / self.base_m
            low, high = ((ratio * (1 + 1e-3), GEOMETRY_RANGE[1]) if ratio < 1
                         else (GEOMETRY_RANGE[0], ratio * (1 - 1e-3)))
            lo, hi = lo + [low], hi + [high]
        return np.array(lo), np.array(hi)

    def start(self):
        return np.array([0.0, 0.0] + ([1.0] if self.n_params == 3 else []))

    def torque(self, p: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Spring torque (N.m) on the joint at angles ``theta`` (rad) and its derivative."""
        return compensator_torque(theta, p[0], p[1], self.geometry(p))

    def preload(self, p, model, rows):
        column = model.joints.index(self.joint_name)
        theta = model.geometry.angles(rows)[self.joint_name]
        tau_s, dtau = self.torque(p, theta)
        m, n = rows.n_rows, len(model.joints)
        tau, k = np.zeros((m, n)), np.zeros((m, n, n))
        tau[:, column] = tau_s
        k[:, column, column] = dtau
        return tau, k

    def units(self, units):
        return [("N/m", 1.0), ("N", 1.0)] + [(units.length, units.length_to_si)] * (
            self.n_params - 2)

    def describe(self) -> str:
        if self.angle_reference == "upward":
            origin = (f"its angle measured from the link's upward direction at zero load "
                      f"({self.joint_name} = {self.angle_up_rad:.4g} rad)")
        else:
            why = f": {self.reference_reason}" if self.reference_reason else ""
            origin = f"its angle measured from the joint's zero{why}"
        if self.geometry_source == "fitted":
            lengths = self.geometry_note
        else:
            held = f", held: {self.geometry_note}" if self.geometry_note else ""
            lengths = (f"lever {self.lever_m:g} m and base {self.base_m:g} m "
                       f"{self.geometry_source}{held}")
        return (f"a spring gravity compensator on {self.joint_name} ({lengths}; {origin}) adds "
                "its torque and its angle derivative (a stiffness) to the joint")

    # pose face ----------------------------------------------------------------------------
    requires: ClassVar[tuple[str, ...]] = ("joint_compliance",)
    #: typical sizes of the stiffness (N/m) and the tension (N)
    SIZES: ClassVar[tuple[float, float]] = (1e3, 1e2)
    #: the model setting declaring compensators' geometry: joint -> {lever_m, base_m} (m)
    GEOMETRY_SETTING: ClassVar[str] = "compensator_geometry_m"

    @classmethod
    def upward(cls, robot: Robot, joint: str) -> GravityCompensator:
        """The compensator on ``joint`` with its default geometry, its angle measured from the
        link's upward direction (:func:`~stiffness.mechanics.gravity.upward_angle`)."""
        up = upward_angle(robot, joint)
        return cls(joint_name=joint, angle_up_rad=up.angle_rad, angle_reference=up.reference,
                   reference_reason=up.reason)

    def _pose_joints(self, pm: PoseLayout) -> list[tuple[int, float, GravityCompensator]]:
        """Each compensated chain joint (id), the offset (rad) of the spring's angle on it and
        its spring (:func:`compensated_joints`; built once per model), its lever and base
        those the model's setting :data:`GEOMETRY_SETTING` declares for it, else the
        library's defaults."""
        if self._pose_springs is None:
            declared = pm.settings.get(self.GEOMETRY_SETTING, {})
            self._pose_springs = [(j, offset, self.declared_at(pm.robot, name, declared))
                                  for name, j, offset in compensated_joints(pm.robot,
                                                                            pm.springs)]
        return self._pose_springs

    @classmethod
    def declared_at(cls, robot: Robot, joint: str, declared: dict[str, dict]
                    ) -> GravityCompensator:
        """The compensator on ``joint`` (:meth:`upward`) with the lever and base (m)
        ``declared[joint]`` gives (``diagnose --compensator-geometry``), if any."""
        spring = cls.upward(robot, joint)
        return spring if joint not in declared else spring.declare(declared[joint])

    def physical_sizes(self, pm: PoseLayout, refs: References) -> np.ndarray:
        # each spring's own (its lever and base): the deflection effect's scale
        return np.concatenate([spring.physical_scale(refs)[:2]
                               for _, _, spring in self._pose_joints(pm)] or [np.zeros(0)])

    def family_parameters(self, pm: PoseLayout) -> list[FamilyParameter]:
        return [FamilyParameter(self.name, compensator_label(spring.joint_name, what), size,
                                unit, lower)
                for _, _, spring in self._pose_joints(pm)
                for what, size, unit, lower in zip(("stiffness", "preload"), self.SIZES,
                                                   ("N/m", "N"), (0.0, -math.inf),
                                                   strict=True)]

    def joint_torque(self, pm: PoseLayout, x_f: np.ndarray, state: SagState) -> np.ndarray:
        """The springs' torques at the loaded angles: (nv,) of a row, or the shape of
        ``state.torque`` over a batch of rows (``state.q`` (n, nq))."""
        out = np.zeros(state.torque.shape)
        model = pm.robot.model
        for n, (j, offset, spring) in enumerate(self._pose_joints(pm)):
            p = x_f[2 * n: 2 * n + 2]
            if p.any():  # a spring without stiffness or tension adds nothing
                v = model.joints[j].idx_v
                torque = spring.torque(p, _joint_angle(model, j, state.q) - offset)[0]
                out[..., v] += torque.reshape(out[..., v].shape)
        return out

    def torque_columns(self, pm: PoseLayout, x_f: np.ndarray, state: SagState) -> np.ndarray:
        """d torque / d(stiffness, tension) of each spring: its torque per unit stiffness and
        per unit tension at the loaded angle (the torque is linear in both)."""
        out = np.zeros(state.torque.shape + (x_f.size,))
        model = pm.robot.model
        for n, (j, offset, spring) in enumerate(self._pose_joints(pm)):
            v, theta = model.joints[j].idx_v, _joint_angle(model, j, state.q) - offset
            for c, unit in enumerate((np.array([1.0, 0.0]), np.array([0.0, 1.0]))):
                out[..., v, 2 * n + c] = spring.torque(unit, theta)[0].reshape(
                    out[..., v, 2 * n + c].shape)
        return out


def compensated_joints(robot: Robot, springs: tuple[str, ...] | list[str]
                       ) -> list[tuple[str, int, float]]:
    """The springs of ``springs`` a compensator can act on, each with the revolute chain
    joint (id) whose link it turns and the offset ``b`` (rad) of that joint's angle from the
    spring's, ``q_j = u + b``: a revolute spring joint (``b = 0``), or a controller coordinate
    that alone turns one revolute chain joint at rate 1
    (:meth:`~stiffness.robot.coupling.CoordinateMap.sole_joint`, e.g. the torso's ``T1``;
    :meth:`JointEffect.placement_problem` refuses the others). Its angle is the coordinate's,
    from its zero, as the deflection face and the elastic model measure it
    (:meth:`Robot.value_of`)."""
    coupling = robot.coupling
    out = []
    for name in springs:
        joint, offset = name, 0.0
        if coupling is not None and name in coupling.coordinates:
            sole = coupling.sole_joint(name)
            if sole is None:
                continue
            joint, offset = sole, float(coupling.offset[coupling.chain.index(sole)])
        if not robot.is_prismatic(joint):
            out.append((name, int(robot.model.getJointId(joint)), offset))
    return out


def declared_geometry(robot: Robot, settings: dict[str, dict]) -> dict[str, dict]:
    """Compensators' declared lever and base (m) by joint, from declared settings by effect
    label (``gravity_compensator(JOINT)`` or ``gravity_compensator:JOINT``, :func:`effect_place`:
    ``diagnose --compensator-geometry``), checked:
    each a revolute compliant joint of ``robot``, two positive lengths
    (:meth:`GravityCompensator.declare`); the pose model's setting
    :attr:`GravityCompensator.GEOMETRY_SETTING`.

    Raises
    ------
    StiffnessError
        Another effect's label, a joint that carries no compensator, or lengths that are not
        two positive ones.
    """
    valid = [name for name, _, _ in compensated_joints(robot, robot.compliant_joints)]
    out = {}
    for label, lengths in settings.items():
        name, joint = effect_place(label, "declared settings")
        if name != "gravity_compensator" or joint not in valid:
            raise StiffnessError(f"declared settings {label}: a pose campaign takes those of "
                                 f"gravity_compensator(JOINT), JOINT a revolute compliant joint "
                                 f"of {robot.title}: {', '.join(valid) or 'none'}")
        spring = GravityCompensator(joint_name=str(joint)).declare(lengths)
        out[joint] = {"lever_m": spring.lever_m, "base_m": spring.base_m}
    return out


def _joint_angle(model: pin.Model, joint: int, q: np.ndarray) -> np.ndarray:
    """Angle (rad) of a revolute joint at ``q`` (nq,), or at each of a batch (..., nq) (a
    continuous joint's from its cos, sin)."""
    jm = model.joints[joint]
    if jm.nq == 2:
        return np.arctan2(q[..., jm.idx_q + 1], q[..., jm.idx_q])
    return np.asarray(q[..., jm.idx_q], dtype=float)


@dataclass(eq=False)
class GravityLumped(Settings, DeflectionEffect, JointDeflectionFamily):
    """``gravity_lumped``: the links' weight when their masses are unknown (``--masses
    unknown``), linear in each weighed link's gravity parameters (mass and mass moments,
    :data:`~stiffness.mechanics.gravity.GRAVITY_PARAMETERS`) through the gravity regressor.

    Deflection face (a deflection campaign's candidate instead of ``gravity_preload``): the
    weight ``tau_g = Y(q) pi`` and its stiffness ``K_g = Y_K(q) pi`` preload the joints
    (:meth:`preload`, :meth:`Geometry.weight_regressor`), ``pi`` the gravity parameters of
    :attr:`links` (kg, kg.m in each link's joint frame); combinations the campaign cannot tell
    apart are merged by the fit's identifiability.

    Pose face: ``Delta q_j = - sum_k theta_jk Y_jk(q)``, ``Y`` the gravity regressor at the
    loaded configuration (:meth:`at_configuration`), ``theta_jk = c_j pi_k`` lumped (``pi_k``:
    the mass and mass moments of link ``k`` downstream of ``j``); for springs on controller
    coordinates ``Delta q = - S_j theta_jk S_j^T Y_k`` (``S_j`` the spring's column of
    :attr:`PoseLayout.spring_map`).

    Both faces read one regressor, :func:`stiffness.batch.poses.gravity_regressors` (the
    deflection face with its derivative: ``Y_K = -Y_q`` on the springs)."""

    #: the weighed links (the joints of their bodies), in model order
    links: tuple[str, ...] = ()
    name: ClassVar[str] = "gravity_lumped"
    kind: ClassVar[str] = "preload"
    beyond_springs: ClassVar[bool] = True
    lumps_gravity: ClassVar[bool] = True

    @classmethod
    def at_place(cls, where, geometry=None):
        placed = super().at_place(where, geometry)
        if geometry is None:
            return placed
        require_open_chain(geometry.robot, cls.name)
        names = geometry.robot.model.names
        return cls(links=tuple(names[k] for k in weighed_bodies(geometry.robot)))

    def configured(self, settings):
        return dataclasses.replace(self, links=tuple(settings.get("links", self.links)))

    def file_settings(self, refs):
        return {"links": list(self.links)}

    def simulated_values(self, values, units):
        raise StiffnessError("gravity_lumped is not simulated (its parameters are combinations "
                             "of masses); hide the robot's weight as gravity_preload")

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return tuple(f"{link}_{p}" for link in self.links for p in GRAVITY_PARAMETERS)

    def scale(self, refs):
        mass = refs.force_ref / 9.81  # the load's size: 0.1 m levers
        return np.tile([mass, 0.1 * mass, 0.1 * mass, 0.1 * mass], len(self.links))

    def bounds(self):
        """Each link's mass (:data:`MASS_LOWER`) at least 0; its mass moments ``m c`` are
        signed (a centre of mass on either side of the joint's origin)."""
        lower = np.tile([MASS_LOWER[p] for p in GRAVITY_PARAMETERS], len(self.links))
        return np.maximum(lower, -1e4), np.full(lower.size, 1e4)

    def preload(self, p, model, rows):
        y, y_k = model.geometry.weight_regressor(rows, self.links)
        idx = model.index
        return y[:, idx] @ p, y_k[:, idx][:, :, idx] @ p

    def contribute(self, values, parts):
        parts.skip(self.label, "the weight of unknown masses, lumped: its parameters are "
                               "combinations of the links' masses the campaign determines, "
                               "which the robot's inertias cannot hold")

    def units(self, units):
        return [("kg", 1.0), ("kg.m", 1.0), ("kg.m", 1.0), ("kg.m", 1.0)] * len(self.links)

    def describe(self) -> str:
        return ("the links' weight, their masses unknown (fitted gravity parameters), preloads "
                "the joints (the measured deflection is loaded minus unloaded under it)")

    def family_parameters(self, pm: PoseLayout) -> list[FamilyParameter]:
        """Per spring and link downstream of it, ``c_j pi_k`` of each gravity parameter: the
        spring's compliance (>= 0) times the link's mass (>= 0) is at least 0; times a mass
        moment it is signed (:data:`MASS_LOWER`)."""
        names = pm.robot.model.names
        return [FamilyParameter(self.name, f"{spring} x {names[k]} {p}", self.family_scale,
                                LUMPED_UNIT, MASS_LOWER[p])
                for c, spring in enumerate(pm.springs) for k in pm.spring_downstream(c)
                for p in GRAVITY_PARAMETERS]

    def at_configuration(self, pm: PoseLayout, model: pin.Model, data: pin.Data,
                         q: np.ndarray) -> np.ndarray:
        """d(Delta q)/d theta (nv, n_theta): ``-S_j (S_j^T Y_k)`` of each pair (minus the
        regressor entry at a spring on a joint); (n, nv, n_theta) at a batch (n, nq) of
        configurations. ``S^T Y`` is one product of the spring map with the regressor, read
        at each pair's (spring, body, parameter) (:func:`_lumped_layout`): exactly the
        regressor's entry for a spring on a joint (one unit entry in ``S_j``)."""
        regressor, _ = gravity_regressors(model, data, q.reshape(-1, model.nq))
        tangent = pm.loop_tangent(model, data, q.reshape(-1, model.nq))
        if tangent is not None:  # through closed loops: T^T Y
            regressor = np.einsum("nvu,nvkp->nukp", tangent, regressor)
        springs, pick = layout_cached(pm, "gravity_lumped pairs", lambda: _lumped_layout(pm))
        carried = pm.spring_map.T @ regressor.reshape(regressor.shape[:2] + (-1,))
        carried = carried.reshape(regressor.shape[0], -1)[:, pick]  # (n, n_theta)
        return (-springs * carried[:, None, :]).reshape(q.shape[:-1] + springs.shape)

    def joint_deflection(self, pm: PoseLayout, x_f: np.ndarray, state: SagState) -> np.ndarray:
        return state.extras[self.name] @ x_f

    def deflection_columns(self, pm: PoseLayout, x_f: np.ndarray, state: SagState
                           ) -> np.ndarray:
        return state.extras[self.name]


def _lumped_layout(pm: PoseLayout) -> tuple[np.ndarray, np.ndarray]:
    """Each lumped gravity parameter's spring column ``S_j`` (nv, n_theta) and the position
    of its (spring, body, gravity parameter) in ``S^T Y`` flattened per row (spring-major;
    ``Y`` the regressor of :func:`~stiffness.batch.poses.gravity_regressors`: bodies of joints
    1 .. njoints - 1, then :data:`GRAVITY_PARAMETERS`), in the family's parameter order: of
    the layout alone, built once per model (:func:`layout_cached`), not at each of a fit's sag
    iterations (read-only)."""
    n_p, bodies = len(GRAVITY_PARAMETERS), pm.robot.model.njoints - 1
    pairs = np.array([(c, k - 1, p) for c in range(len(pm.springs))
                      for k in pm.spring_downstream(c) for p in range(n_p)],
                     dtype=int).reshape(-1, 3)
    springs = pm.spring_map[:, pairs[:, 0]]
    pick = (pairs[:, 0] * bodies + pairs[:, 1]) * n_p + pairs[:, 2]
    springs.setflags(write=False)
    pick.setflags(write=False)
    return springs, pick
