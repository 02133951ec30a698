"""Synthetic campaigns with hidden effects: what could a rig detect before measuring?

:func:`simulate` draws reachable configurations
(:func:`stiffness.calibration.poses.sample_coordinates`), or takes the rows of a measurement plan
(:mod:`stiffness.planning.plan`), loads along random directions (or a ramp along one
direction per configuration, or the six axis directions), computes the deflections from the
*exact* elastostatic equilibrium of a true robot that carries the hidden effects, adds Gaussian
noise, and returns a :class:`~stiffness.calibration.campaign.Campaign` that declares only the
baseline (its ``--kq`` joints), plus the hidden truth.

How each hidden effect enters the truth (see :mod:`stiffness.elastic.effects` for the models):

* ``complementary_stiffness``: always in the truth (the equilibrium is exact); hiding it means
  declaring the ``conventional`` baseline, so the campaign's model misses it.
* ``joint_compliance:J=k``: joint J is a spring of stiffness k (N.m/rad, N/m) in the true robot.
* ``link_compliance:A->B=k[,k2]``: after the joint equilibrium, the part beyond B's origin turns
  by ``sum_i e_i (e_i . M_B) / k_i`` (N.m/rad; one value for both axes), with the moment and
  the axes at the deflected configuration (the coupling back into the joint torques is
  second order and neglected); the axes are derived here
  (:func:`stiffness.planning.simulate_poses.link_column` at the reference pose,
  :func:`~stiffness.planning.simulate_poses.bend_axes`), not taken from the fitted model's
  geometry (a test checks the two agree).
* ``transversal_compliance:J=k[,k2]``: the same turn of the part beyond J's origin, about the two
  axes of J's mounting frame normal to its rotation axis, which is found here from J's motion
  subspace (:func:`joint_tilt_axes`).
* ``backlash:J=b``: ``dtheta_J += b tanh(tau_J / tau_s)`` (b in the campaign's angle unit;
  tau_s as in :mod:`stiffness.elastic.effects`, computed here: :func:`row_smoothing_torques`),
  solved exactly with the rest.
* ``nonlinear_joint_stiffness:J=beta``: ``dtheta_J = tau_J / k_J (1 + beta |tau_J|)``, 1/(N.m).
* ``frame_misalignment=rx,ry,rz``: the deflections are measured in a frame rotated by that
  rotation vector (angle unit); ``target_offset=dx,dy,dz``: the true target is that far from
  the declared one (length unit, target frame axes); ``force_sensor_bias=bx,by,bz``: the
  recorded force is the applied one plus b (force unit); ``deflection_offset=dx,dy,dz``: the
  measured deflections carry that offset. One value instead is along (1, 1, 1)/sqrt(3).
* ``gravity_preload=m`` or ``=m,cx,cy,cz``: the robot's weight (URDF inertias) and a payload of
  m kg with its centre of mass at c (length unit, target frame axes, from the target) preload
  the joints; the deflection is the loaded minus the unloaded exact equilibrium under that
  weight (open chains only); ``gravity_lumped`` (that weight with the masses unknown) is not.
* ``gravity_compensator:J=k,F0``: a spring compensator of stiffness k (N/m) and tension F0 (N)
  with the link straight up on the revolute compliant joint J, its angle measured from the
  link's upward direction at zero load (:func:`stiffness.mechanics.gravity.upward_angle`),
  lever and base :data:`stiffness.elastic.effects.preloads.COMPENSATOR_GEOMETRY`
  (:func:`stiffness.mechanics.gravity.compensator_torque`), in the exact equilibrium;
  ``J=k,F0,lever,base`` gives the lever and base lengths (m).

With ``rotations``, the campaign also records the rotation vector of the target frame between
the unloaded and the loaded equilibrium (base axes; rotated by a hidden frame misalignment,
turned further by a hidden link compliance) with its own noise.

The size of each hidden effect is reported as the RMS change it makes to the noise-free
deflections (:attr:`Simulation.effect_rms_m`), in noise units in ``truth.json``.
"""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.calibration.campaign import Campaign
from stiffness.calibration.campaign_toml import CAMPAIGN_FILE, RobotSettings
from stiffness.calibration.campaign_writer import write_campaign
from stiffness.calibration.poses import sample_coordinates
from stiffness.elastic.effects import FAMILIES, LIBRARY, make_effect
from stiffness.elastic.effects.base import effect_place, place_label
from stiffness.elastic.effects.geometry import (
    Geometry,
    cached_robot,
    chain_placements,
    rotation_matrix,
)
from stiffness.elastic.effects.parts import ElasticParts
from stiffness.elastic.model import ElasticModel
from stiffness.errors import (
    ConvergenceError,
    FlagValueWarning,
    StiffnessError,
    UnknownEffectError,
    UnknownNameError,
    UnstableEquilibriumError,
    did_you_mean,
    wrong_argument,
)
from stiffness.files import (
    atomic_write,
    refuse_foreign_folder,
    staged_folder,
    written_path,
    written_source,
)
from stiffness.mechanics.equilibrium import SpringLaw, solve_equilibrium, tangent_equilibrium
from stiffness.mechanics.formulation import as_wrench, target_state
from stiffness.mechanics.gravity import joint_preload, with_payload
from stiffness.planning.plan import Plan, PlannedRobot, plan_and_robot
from stiffness.planning.simulate_poses import (
    SMOOTHING_FRACTION,
    bend_axes,
    link_column,
    rotation_axis_column,
)
from stiffness.planning.simulate_request import (
    buckled_row,
    check_request,
    draw_loads,
    effect_values,
    request_record,
    rotation_noise_std,
    settings_record,
    true_stiffness,
    warn_effect_lengths,
)
from stiffness.robot.declaration import FAR_TARGET
from stiffness.robot.robot import Robot
from stiffness.units import Units, float_array, whole_number

#: File documenting the hidden truth beside ``campaign.toml``.
TRUTH_FILE = "truth.json"


# ------------------------------------------------------------------------------------------
# hidden effects


@dataclass
class HiddenEffect:
    """An effect hidden in a simulated campaign.

    Attributes
    ----------
    name
        Library name (:data:`stiffness.elastic.effects.LIBRARY`).
    where
        Joint, ``A->B`` segment, or ``None``.
    values
        Values as given, in the units of the module docstring.
    """

    name: str
    where: str | None = None
    values: tuple[float, ...] = ()

    @property
    def label(self) -> str:
        """``name`` or ``name(where)``."""
        return place_label(self.name, self.where)

    def to_dict(self) -> dict:
        """JSON-ready."""
        return {"effect": self.name, "where": self.where, "values": list(self.values)}


def parse_effect(text: str) -> HiddenEffect:
    """Parse ``NAME[:WHERE]=value[,value...]`` or ``NAME(WHERE)=value[,value...]``
    (:func:`~stiffness.elastic.effects.base.effect_place`; ``complementary_stiffness`` takes no
    value).

    Raises
    ------
    StiffnessError
        Unknown name, a missing value, a wrong number of values, or a non-number.
    """
    head, _, rest = text.partition("=")
    name, where = effect_place(head, "--effect")
    if name not in LIBRARY:
        pose = f" ({name} is a pose campaign's: --kind poses)" if name in FAMILIES else ""
        raise UnknownEffectError(f"unknown effect {name!r} in --effect {text!r}; "
                                 f"{did_you_mean(name, list(LIBRARY))}{pose}", name=name,
                                 choices=list(LIBRARY))
    values = effect_values(text, rest)
    value_counts = LIBRARY[name].value_counts
    if len(values) not in value_counts:
        counts = " or ".join(str(c) for c in value_counts)
        raise StiffnessError(f"--effect {text!r}: {name} takes {counts} value(s), got "
                             f"{len(values)}")
    return HiddenEffect(name, where, tuple(values))


@dataclass
class Truth:
    """The true robot of a simulation, SI.

    Attributes
    ----------
    robot
        True robot: declared target plus the hidden offset, declared compliant joints plus the
        hidden ones.
    law
        Joint law over ``robot.compliant_joints``.
    links
        ``(a, b, column, k1, k2)`` hidden link compliances, and joints tilting in their bearings
        (``a == b``).
    chain
        The target chain's joints.
    misalignment
        Rotation vector of the instrument frame (rad).
    force_bias
        Recorded minus applied force (N).
    deflection_offset
        Offset of the measured deflections (m).
    gravity
        Whether the robot's weight preloads the joints (``gravity_preload``).
    payload
        ``(mass kg, centre of mass (3,) m in target frame axes)`` of the payload.
    compensators
        ``(joint, stiffness N/m, preload N, geometry)`` of hidden spring gravity compensators
        (:meth:`stiffness.elastic.effects.parts.ElasticParts.add_compensator`).
    model
        The true robot as an elastic model (:class:`stiffness.elastic.model.ElasticModel`), of
        which the truth holds the parts its deflections need.
    zero_offsets
        (n_coordinates,) ``joint_offsets`` (rad, m): each row is exactly at its coordinates plus it.
    """

    robot: Robot
    law: SpringLaw
    links: list[tuple[str, str, int, float, float]] = field(default_factory=list)
    chain: tuple[str, ...] = ()
    misalignment: np.ndarray = field(default_factory=lambda: np.zeros(3))
    force_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))
    deflection_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gravity: bool = False
    payload: tuple[float, np.ndarray] = (0.0, np.zeros(3))
    compensators: list[tuple[str, float, float, dict]] = field(default_factory=list)
    model: ElasticModel | None = None
    zero_offsets: np.ndarray | float = 0.0

    @classmethod
    def of_model(cls, model: ElasticModel, chain: tuple[str, ...]) -> Truth:
        """The truth of an elastic model (``chain``: the target chain's joints)."""
        links = [(lk.a, lk.b, lk.column, *lk.stiffness) for lk in model.links]
        payload = (0.0, np.zeros(3)) if model.payload is None else model.payload
        return cls(model.robot, model.compliant_law(), links, chain, model.misalignment,
                   model.force_bias, model.deflection_offset, model.payload is not None,
                   payload, list(model.compensators), model)

    def __post_init__(self) -> None:
        self._weighed = None
        if self.gravity:
            self._weighed = with_payload(self.robot, self.payload[0], self.payload[1])

    def preload(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Joint preload of the weight and the compensators at the configuration ``q``:
        torque (n,) and its derivative (n, n) over the compliant joints."""
        return joint_preload(self.robot, self._weighed, self.compensators, q)

    @property
    def preloaded(self) -> bool:
        """Whether a preload (weight, compensator) acts."""
        return self._weighed is not None or bool(self.compensators)

    def link_coordinates(self, coords: np.ndarray) -> np.ndarray:
        """The coordinates (m, n_coordinates; rad, m) of the unloaded link pose at each
        commanded row ``coords``: the exact equilibrium under the preload (the commanded ones
        without a preload)."""
        coords = np.asarray(coords, dtype=float)
        if not self.preloaded:
            return coords.copy()
        out = np.empty_like(coords)
        rest: dict[tuple, np.ndarray] = {}
        for i, c in enumerate(coords):
            key = tuple(c)
            if key not in rest:
                eq = solve_equilibrium(self.robot, self.robot.configuration(c), self.law,
                                       np.zeros(6), preload=self.preload)
                rest[key] = self.robot.coordinates_of(eq.q)
            out[i] = rest[key]
        return out

    def deflections(self, coords: np.ndarray, force: np.ndarray, mode: str = "exact",
                    rotations: bool = False) -> np.ndarray:
        """Noise-free measured deflections (m, 3) of rows at ``coords`` under the *applied*
        forces ``force`` (m, 3); with ``rotations``, (m, 6): the deflections and the measured
        rotation vectors of the target frame (rad, base axes).

        Under a preload (weight, compensator) the deflection is the loaded minus the unloaded
        equilibrium at the same commanded pose.

        ``mode``: ``exact`` (the exact equilibrium), ``enhanced`` (``K_C`` of the unloaded
        pose in the tangent, first-order kinematics) or ``conventional`` (first order, no
        ``K_C``): the latter two measure what the linear baselines miss."""
        if mode not in ("exact", "enhanced", "conventional"):
            raise UnknownNameError(f"unknown mode {mode!r}; valid: exact, enhanced, "
                                   "conventional", name=mode,
                                   choices=("exact", "enhanced", "conventional"))
        out = np.empty((len(coords), 6))
        q0: dict[tuple, np.ndarray] = {}
        rest: dict[tuple, tuple | None] = {}
        for i, (c, f) in enumerate(zip(coords, force, strict=True)):
            key = tuple(c)
            if key not in q0:
                q0[key] = self.robot.configuration(c + self.zero_offsets)
                rest[key] = self._unloaded(q0[key], mode)
            try:
                out[i] = self._row(q0[key], f, mode, rest[key])
            except (ConvergenceError, UnstableEquilibriumError) as exc:
                raise type(exc)(buckled_row(self.robot, i, f, str(exc))) from exc
        turn = rotation_matrix(self.misalignment)
        out[:, :3] = out[:, :3] @ turn.T + self.deflection_offset
        out[:, 3:] = out[:, 3:] @ turn.T
        return out if rotations else out[:, :3]

    def _unloaded(self, q0: np.ndarray, mode: str) -> tuple | None:
        """The unloaded state under the preload: (position, rotation) for ``exact``,
        (dtheta, k_p) for the linear modes; ``None`` without a preload."""
        if not self.preloaded:
            return None
        if mode == "exact":
            eq = solve_equilibrium(self.robot, q0, self.law, np.zeros(6), preload=self.preload)
            state = target_state(self.robot, eq.q)
            return state.position, state.rotation
        tau_p, k_p = self.preload(q0)
        return tangent_equilibrium(self.law, tau_p, k_p), tau_p, k_p

    def _row(self, q0: np.ndarray, force: np.ndarray, mode: str, rest: tuple | None
             ) -> np.ndarray:
        robot, law = self.robot, self.law
        wrench = as_wrench(force)
        if mode == "exact":
            eq = solve_equilibrium(robot, q0, law, wrench,
                                   preload=self.preload if rest is not None else None)
            q, x, dx, rot = eq.q, eq.position, eq.dx, eq.rotation
            if rest is not None:
                state = target_state(robot, eq.q)
                dx = state.position - rest[0]
                rot = pin.log3(state.rotation @ rest[1].T)
        else:  # the linear modes: the Jacobian and K_C of the unloaded pose
            base = target_state(robot, q0, wrench)
            tau0 = base.jacobian.T @ wrench
            k_c = base.k_c if mode == "enhanced" else np.zeros_like(base.k_c)
            if rest is None:
                dtheta = tangent_equilibrium(law, tau0, k_c)
            else:
                dtheta = tangent_equilibrium(law, tau0 + rest[1], k_c + rest[2]) - rest[0]
            q, x = q0, base.position
            dx, rot = base.jacobian[:3] @ dtheta, base.jacobian[3:] @ dtheta
        if self.links:
            pin.forwardKinematics(robot.model, robot.data, q)
            origins, rotations = chain_placements(robot, self.chain)
            for a, b, column, k1, k2 in self.links:
                ib = self.chain.index(b)
                if a == b:  # a joint tilting in its bearing (axes derived here)
                    e1, e2 = joint_tilt_axes(robot.model, b, rotations[ib])
                else:
                    e1, e2 = bend_axes(origins[self.chain.index(a)], origins[ib], rotations[ib],
                                       column)
                r = x - origins[ib]
                m_b = np.cross(r, force)
                omega = e1 * (e1 @ m_b) / k1 + e2 * (e2 @ m_b) / k2
                dx = dx + np.cross(omega, r)
                rot = rot + omega
        return np.concatenate([dx, rot])


def joint_tilt_axes(model: pin.Model, joint: str, parent_rotation: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """The two axes (world) a joint tilts about in its bearing: the axes of its mounting frame
    (``parent_rotation`` times its placement's) other than the one it turns about, found from
    its motion subspace (:func:`~stiffness.planning.simulate_poses.rotation_axis_column`), in
    cyclic order."""
    jid = model.getJointId(joint)
    axis = rotation_axis_column(model, jid)
    if axis is None:
        raise StiffnessError(f"transversal_compliance on {joint}: not a revolute joint about an "
                             "axis of its frame")
    mount = parent_rotation @ model.jointPlacements[jid].rotation
    return mount[:, (axis + 1) % 3], mount[:, (axis + 2) % 3]


def build_truth(declared: Robot, kq: np.ndarray, effects: list[HiddenEffect], units: Units,
                smoothing: np.ndarray, geometry: Geometry) -> Truth:
    """The true robot of a simulation from the declared one, its stiffness and hidden effects.

    Each hidden effect contributes through its class's one hook
    (:meth:`stiffness.elastic.effects.base.Effect.contribute`). ``smoothing`` is the backlash
    smoothing torque per coordinate joint (N.m).
    """
    parts = ElasticParts(dict(zip(declared.compliant_joints, kq, strict=True)),
                         smoothing=dict(zip(geometry.joints, smoothing, strict=True)))
    for h in effects:
        effect = make_effect(h.name, h.where, geometry)  # validates where
        effect.contribute(effect.simulated_values(h.values, units), parts)
    parts.check_joints()
    compliant = tuple(parts.springs)
    with warnings.catch_warnings():  # a hidden offset's length: warned in --units at the flag
        warnings.filterwarnings("ignore", FAR_TARGET, FlagValueWarning)
        robot = cached_robot(declared.name, declared.target_frame,
                             tuple(declared.target_offset.copy() + parts.target_shift),
                             compliant, declared.loop_file, declared.fixed_base)
    reference = declared.assemble(None).q
    columns = {(a, b): link_column(declared.model, declared.model.getJointId(a),
                                   declared.model.getJointId(b), reference)
               for a, b, _, _ in parts.bends}
    model = ElasticModel.of_parts(robot, parts, link_columns=columns)
    truth = Truth.of_model(model, geometry.chain)
    truth.zero_offsets = np.array([parts.zero_offsets.get(j, 0) for j in robot.coordinate_joints])
    return truth


# ------------------------------------------------------------------------------------------
# simulation


@dataclass
class Simulation:
    """A simulated campaign and its hidden truth.

    Attributes
    ----------
    campaign
        The campaign (SI), as a user would measure it.
    effects
        Hidden effects.
    kq
        True stiffness of the declared compliant joints (SI).
    noise_std_m
        Noise std (m).
    effect_rms_m
        Per hidden effect label, the RMS change (m) it makes to the noise-free deflections.
    settings
        The simulation's inputs (JSON-ready).
    baseline_error_m
        RMS difference (m) between the exact and the declared baseline's linear deflections of
        the true robot: the load-dependent geometry the baseline misses even with nothing
        hidden (second-order kinematics for ``enhanced``; also ``K_C`` for ``conventional``).
    """

    campaign: Campaign
    effects: list[HiddenEffect]
    kq: np.ndarray
    noise_std_m: float
    effect_rms_m: dict[str, float]
    settings: dict
    baseline_error_m: float = 0.0

    def to_dict(self) -> dict:
        """The object ``stiffness simulate --json`` prints: :meth:`truth`."""
        return self.truth()

    def truth(self, folder: Path | None = None) -> dict:
        """The hidden truth (JSON-ready), documented in ``truth.json``: the robot and plan
        paths as given, or relative to ``folder`` (where ``truth.json`` is written;
        :func:`~stiffness.files.written_source`)."""
        lu = self.campaign.units.length_to_si
        settings = self.settings
        if folder is not None:
            robot = {**settings["robot"], "source": written_source(
                settings["robot"]["source"], folder)}
            settings = {**settings, "robot": robot, "plan": None if settings["plan"] is None
                        else written_path(settings["plan"], folder)}
        return {
            "format": "stiffness-simulation-truth",
            "robot": settings["robot"],
            "baseline": self.campaign.baseline,
            "compliant_joints": list(self.campaign.robot().compliant_joints),
            "k_theta_SI": self.kq.tolist(),
            "hidden_effects": [h.to_dict() for h in self.effects],
            "expected_missing_effects": [h.name for h in self.effects],
            "effect_rms": {k: v / lu for k, v in self.effect_rms_m.items()},
            "effect_rms_noise_units": {k: v / self.noise_std_m if self.noise_std_m > 0
                                       else None for k, v in self.effect_rms_m.items()},
            "baseline_model_error": self.baseline_error_m / lu,
            "baseline_model_error_noise_units": (self.baseline_error_m / self.noise_std_m
                                                 if self.noise_std_m > 0 else None),
            "noise_std": self.noise_std_m / lu,
            "unit": self.campaign.units.length,
            "value_units": {
                "joint_compliance": "N.m/rad (N/m prismatic)", "link_compliance": "N.m/rad",
                "transversal_compliance": "N.m/rad",
                "backlash": f"{self.campaign.units.angle} ({self.campaign.units.length} "
                "prismatic)", "nonlinear_joint_stiffness": "1/(N.m) (1/N prismatic)",
                "frame_misalignment": self.campaign.units.angle,
                "target_offset": self.campaign.units.length,
                "force_sensor_bias": self.campaign.units.force,
                "deflection_offset": self.campaign.units.length, "joint_offsets":
                f"{self.campaign.units.angle} ({self.campaign.units.length} prismatic)",
                "gravity_preload": f"kg, then {self.campaign.units.length} (target frame)",
                "gravity_compensator": "N/m, N, then lever and base in m"},
            "settings": settings,
            "model": ("exact elastostatic equilibrium of the true robot"
                      " (stiffness.planning.simulate)"),
        }

    def write(self, folder: str | Path) -> Path:
        """Write ``campaign.toml``, ``measurements.csv`` and ``truth.json``; returns the toml."""
        folder = Path(folder)
        refuse_foreign_folder(folder, TRUTH_FILE, "simulated campaign",
                              writes=(CAMPAIGN_FILE, Path(self.campaign.data_file).name))
        with staged_folder(folder, keep_others=True) as stage:  # published by one rename
            written = write_campaign(self.campaign, stage)
            atomic_write(stage / TRUTH_FILE,
                         json.dumps(self.truth(folder), indent=1) + "\n")
        path = folder / written.name
        self.campaign.path = path
        return path


def simulate(
    robot: Robot | str | None = None, kq: list[float] | np.ndarray | None = None,
    effects: list[HiddenEffect | str] | None = None, configs: int = 10,
    loads_per_config: int = 4, max_force: float = 100.0, noise_std_m: float = 1e-5,
    seed: int = 0, frame: str | None = None,
    target_offset_m: np.ndarray | list[float] | None = None,
    compliant_joints: list[str] | tuple[str, ...] | None = None, baseline: str | None = None,
    units: Units | None = None, load_pattern: str = "random", repeats: int = 1,
    declare_noise: bool = True, name: str | None = None, rotations: bool = False,
    rotation_noise_std_rad: float | None = None, loops: str | None = None,
    fixed_base: bool = False, plan: Plan | str | os.PathLike | None = None,
    joint_angles: str = "motor",
) -> Simulation:
    """Simulate a campaign with hidden effects: ``stiffness simulate`` (:meth:`Simulation.
    to_dict` is its ``--json`` object, :meth:`Simulation.write` its ``--out`` folder).

    Parameters
    ----------
    robot
        Robot source (shipped name, example-robot-data name, URDF path), or a loaded robot
        (its source, with its target, springs, loops and base unless given); may be omitted
        when ``plan`` is a plan folder (its ``campaign.toml`` names the robot).
    kq, effects
        True stiffness of each declared compliant joint (N.m/rad, N/m; default the shipped
        robot's ``k_theta_SI``); hidden effects (:class:`HiddenEffect`, or their
        ``NAME[:WHERE]=VALUE`` text, :func:`parse_effect`).
    configs, loads_per_config, repeats
        Number of configurations, loads per configuration, and measurements per load (the
        repeats share the deflection and differ by their noise).
    max_force, noise_std_m, seed
        Largest force (N); measurement noise std (m) on each deflection component; random
        seed (poses, loads, noise).
    frame, target_offset_m, compliant_joints
        Declared target and springs (defaults: the robot's, or the plan folder's).
    baseline
        Declared baseline; default ``conventional`` when ``complementary_stiffness`` is hidden,
        else ``enhanced``.
    units
        Units of the files (default deg, N, mm); the effect values are in these units.
    load_pattern
        ``random`` directions and magnitudes in [0.25, 1] max_force, ``ramp`` (one random
        direction per configuration, magnitudes max_force i / M), or ``axes`` (+-x, +-y, +-z at
        max_force).
    declare_noise
        Whether the campaign declares its ``noise_std``.
    name, rotations
        Campaign name; whether it also records the rotations ``rx, ry, rz`` of the target.
    rotation_noise_std_rad
        Their noise std (rad); default ``noise_std_m / 0.1 m`` (a 6-D probe whose markers are
        0.1 m apart). Declared with ``declare_noise``; refused without ``rotations`` (it would
        be ignored).
    loops, fixed_base
        Loop declaration overriding the robot's sidecar, and whether to fix a floating or
        planar base (:func:`stiffness.robot.robot.load_robot`); both are written into the
        campaign's ``[robot]`` table.
    plan
        Rows to simulate exactly (:class:`stiffness.planning.plan.Plan`: coordinates,
        applied forces, labels, or the path of a plan written by ``stiffness design``)
        instead of drawing ``configs`` poses and their loads.
    joint_angles
        What the campaign records as joint angles, written as its ``[robot] joint_angles``:
        ``motor`` (the commanded pose, which a hidden weight or compensator sags) or ``link``
        (the unloaded link pose, the exact equilibrium under that preload). The deflections
        are the same.

    Raises
    ------
    StiffnessError
        On bad inputs (unknown effect place, non-positive stiffness, unknown pattern, no
        robot) or when no reachable pose can be found.
    """
    given = _given_robot(robot, frame, target_offset_m, compliant_joints, loops, fixed_base)
    if plan is not None and not isinstance(plan, Plan):
        plan, given = plan_and_robot(plan, given)
    hidden = _hidden(effects)
    check_request(configs, loads_per_config, repeats, max_force, noise_std_m, load_pattern,
                  None if plan is None else len(plan.q), [h.label for h in hidden], joint_angles)
    declared = _declared_robot(given)
    kq = true_stiffness(declared, kq, str(given.source))
    baseline = _declared_baseline(hidden, baseline)
    rng = np.random.default_rng(whole_number(seed, "seed", 0))
    q, applied, row_labels = _rows(declared, plan, configs, loads_per_config, load_pattern,
                                   max_force, rng)
    rotation_noise_std_rad = rotation_noise_std(rotation_noise_std_rad, noise_std_m, rotations)
    rig = _Rig(noise_std_m, rotation_noise_std_rad, rotations, declare_noise, repeats,
               units or Units())
    truth, smoothing, effect_rms, baseline_error, clean6 = _truth_and_sizes(
        declared, kq, hidden, rig.units, q, applied, baseline)
    recorded_q = truth.link_coordinates(q) if joint_angles == "link" else q
    campaign = rig.campaign(given, declared, name, baseline, recorded_q,
                            applied + truth.force_bias, clean6, row_labels, rng, joint_angles)
    info = settings_record(str(given.source), declared, request_record(
        plan, configs, loads_per_config, repeats, load_pattern, max_force, row_labels, applied),
        seed, declare_noise, rotations, rotation_noise_std_rad, smoothing, joint_angles)
    return Simulation(campaign, hidden, kq, noise_std_m, effect_rms, info, baseline_error)


def _hidden(effects: list[HiddenEffect | str] | None) -> list[HiddenEffect]:
    """The hidden effects of :func:`simulate` (``--effect`` texts parsed), or its one-line
    error for anything but a list of them."""
    if effects is not None and not (isinstance(effects, list | tuple) and all(
            isinstance(e, str | HiddenEffect) for e in effects)):
        raise wrong_argument("effects", effects, "a list of hidden effects "
                             "('backlash:elbow_joint=0.01' or HiddenEffect)")
    return [parse_effect(e) if isinstance(e, str) else e for e in effects or []]


def _given_robot(robot: Robot | str | None, frame: str | None,
                 target_offset_m: np.ndarray | list[float] | None,
                 compliant_joints: list[str] | tuple[str, ...] | None, loops: str | None,
                 fixed_base: bool) -> PlannedRobot:
    """The robot asked for: a source with the target, springs, loops and base given; a loaded
    :class:`Robot` stands for its source (``Robot.name``) with its own target, springs, loop
    file and base where they are not given (the campaign written names them)."""
    if isinstance(robot, Robot):
        frame = robot.target_frame if frame is None else frame
        target_offset_m = robot.target_offset if target_offset_m is None else target_offset_m
        compliant_joints = robot.compliant_joints if compliant_joints is None \
            else compliant_joints
        loops = robot.loop_file if loops is None else loops
        fixed_base = fixed_base or robot.fixed_base
    source = robot.name if isinstance(robot, Robot) else robot
    return PlannedRobot(source, frame, None if target_offset_m is None else [
        float(v) for v in float_array(target_offset_m, "target_offset_m", "three lengths in m",
                                      finite=False).reshape(-1)],
        None if compliant_joints is None else list(compliant_joints), loops, fixed_base)


def _declared_robot(given: PlannedRobot) -> Robot:
    """The declared robot (cached): ``given``'s source, target, springs, loops and base.

    Raises
    ------
    StiffnessError
        No source (neither a robot nor a plan folder naming one).
    """
    if given.source is None:
        raise StiffnessError("--robot is required (or --plan FOLDER written by `stiffness "
                             "design`)")
    return cached_robot(str(given.source), given.frame, None if given.target_offset_m is None
                        else tuple(given.target_offset_m), None
                        if given.compliant_joints is None else tuple(given.compliant_joints),
                        None if given.loops is None else str(Path(given.loops).resolve()),
                        given.fixed_base)


def _declared_baseline(hidden: list[HiddenEffect], baseline: str | None) -> str:
    """The baseline the campaign declares: ``baseline``, by default ``conventional`` when
    ``complementary_stiffness`` is hidden (then required), else ``enhanced``."""
    hidden_cs = any(LIBRARY[h.name].second_order for h in hidden)
    baseline = baseline or ("conventional" if hidden_cs else "enhanced")
    if hidden_cs and baseline != "conventional":
        raise StiffnessError("hiding complementary_stiffness means declaring the conventional "
                             "baseline (the truth is always the exact equilibrium)")
    return baseline


def _truth_and_sizes(declared: Robot, kq: np.ndarray, hidden: list[HiddenEffect],
                     units: Units, q: np.ndarray, applied: np.ndarray, baseline: str
                     ) -> tuple[Truth, dict[str, float], dict[str, float], float, np.ndarray]:
    """The true robot of the rows ``q`` (rad, m) under ``applied`` (N), and what it shows.

    Returns
    -------
    The truth, the backlash smoothing torque (N.m) per geometry joint, each hidden effect's
    RMS size (m), the baseline's RMS linearisation error (m) and the noise-free deflections
    and rotations (rows, 6; m, rad).
    """
    geometry = Geometry.of(declared)
    warn_effect_lengths([(h.name, h.where, h.values) for h in hidden], geometry, units)
    truth = build_truth(declared, kq, list(hidden), units, np.zeros(len(geometry.joints)),
                        geometry)
    smoothing = row_smoothing_torques(geometry.robot, q, applied + truth.force_bias)
    _check_backlash_turned(hidden, geometry.joints, smoothing)
    truth = build_truth(declared, kq, hidden, units, smoothing, geometry)
    clean6 = truth.deflections(q, applied, rotations=True)
    effect_rms = _effect_sizes(truth, declared, hidden, kq, units, smoothing, geometry, q,
                               applied, clean6[:, :3])
    linear = truth.deflections(q, applied, mode=baseline)
    baseline_error = float(np.sqrt(np.mean((clean6[:, :3] - linear) ** 2)))
    return (truth, dict(zip(geometry.joints, smoothing.tolist(), strict=True)), effect_rms,
            baseline_error, clean6)


def _check_backlash_turned(hidden: list[HiddenEffect], joints: tuple[str, ...],
                           smoothing: np.ndarray) -> None:
    """Refuse a hidden backlash on a joint the rows' forces put no torque on (the target on
    its axis: baxter's ``left_w2`` under its ``left_gripper``): it cannot show in the
    deflections, and its dead band, smoothed over no torque, leaves the exact equilibrium
    without a solution to round-off (Newton stalled, said to be a buckling load)."""
    for h in hidden:
        if h.name == "backlash" and h.where in joints and \
                smoothing[joints.index(str(h.where))] <= SMOOTHING_FRACTION * _NO_TORQUE:
            raise StiffnessError(
                f"backlash:{h.where}: the forces of the campaign put no torque on {h.where} (the "
                f"target lies on its axis), so its backlash cannot show in the deflections; "
                "hide it on a joint the loads turn, or move the target off that axis "
                "(--target-offset)")


#: An RMS joint torque (N.m, N) below this is none: the round-off of a target on the axis.
_NO_TORQUE = 1e-9


def row_smoothing_torques(robot: Robot, q: np.ndarray, force: np.ndarray) -> np.ndarray:
    """Backlash smoothing torque ``tau_s`` (N.m, N) of each of ``robot``'s compliant joints:
    :data:`~stiffness.planning.simulate_poses.SMOOTHING_FRACTION` of the RMS torque
    ``J^T F`` the recorded forces ``force`` (rows, 3; N) put on it at the rows' coordinates
    ``q`` (rad, m), at least 1e-9 of it. What backlash's ``b`` means; computed here from the
    target Jacobian, and a test checks it is the fitted model's."""
    jac: dict[tuple, np.ndarray] = {}
    torques = np.empty((len(q), robot.n_compliant))
    for i, (c, f) in enumerate(zip(q, force, strict=True)):
        key = tuple(c)
        if key not in jac:
            jac[key] = target_state(robot, robot.configuration(c)).jacobian[:3]
        torques[i] = jac[key].T @ f
    return SMOOTHING_FRACTION * np.maximum(np.sqrt(np.mean(torques ** 2, axis=0)), _NO_TORQUE)


@dataclass
class _Rig:
    """How the simulated rig measures: noise std of the deflections (m) and rotations (rad),
    whether it records rotations and declares its noise, repeats per load, file units."""

    noise_std_m: float
    rotation_noise_std_rad: float
    rotations: bool
    declare_noise: bool
    repeats: int
    units: Units = field(default_factory=Units)

    def campaign(self, given: PlannedRobot, declared: Robot, name: str | None, baseline: str,
                 q: np.ndarray, recorded: np.ndarray, clean6: np.ndarray,
                 row_labels: list[str], rng: np.random.Generator,
                 joint_angles: str = "motor") -> Campaign:
        """The campaign the rig records: each row ``repeats`` times at the coordinates ``q``
        (of the kind ``joint_angles``), noise added to the noise-free deflections and rotations
        ``clean6`` (m, rad); ``recorded`` forces (N)."""
        reps = np.repeat(np.arange(len(q)), self.repeats)
        measured = clean6[reps, :3] + rng.normal(scale=self.noise_std_m, size=(len(reps), 3))
        rotation = None
        if self.rotations:
            rotation = clean6[reps, 3:] + rng.normal(scale=self.rotation_noise_std_rad,
                                                     size=(len(reps), 3))
        loops = None if given.loops is None else str(Path(given.loops).resolve())
        settings = RobotSettings(declared.name, frame=declared.target_frame,
                                 target_offset_m=declared.target_offset.copy(),
                                 compliant_joints=tuple(declared.compliant_joints),
                                 loops=loops, fixed_base=given.fixed_base,
                                 joint_angles=joint_angles)
        return Campaign(
            name=name or f"simulated-{declared.title}",
            baseline=baseline, robot_settings=settings, q=q[reps], force=recorded[reps],
            deflection=measured, config=tuple(row_labels[i] for i in reps),
            noise_std_m=(self.noise_std_m if self.declare_noise and self.noise_std_m > 0
                         else None),
            units=self.units, _robot=declared, rotation=rotation,
            rotation_noise_std_rad=(self.rotation_noise_std_rad if self.rotations
                                    and self.declare_noise and self.rotation_noise_std_rad > 0
                                    else None),
        )


def _rows(declared: Robot, plan: Plan | None, configs: int, loads_per_config: int,
          load_pattern: str, max_force: float, rng: np.random.Generator
          ) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The rows to simulate: coordinates (rad, m), applied forces (N) and configuration
    labels, the plan's or ``configs`` reachable poses with their loads."""
    if plan is None:
        coords = sample_coordinates(declared, configs, rng)
        q = np.repeat(coords, loads_per_config, axis=0)
        applied = np.vstack([draw_loads(load_pattern, loads_per_config, max_force, rng)
                             for _ in range(configs)])
        return q, applied, [f"C{i // loads_per_config + 1}" for i in range(len(q))]
    if plan.q.shape[1] != declared.n_coordinates:
        raise StiffnessError(f"the plan has {plan.q.shape[1]} coordinates per row but "
                             f"{declared.name} has {declared.n_coordinates}")
    return plan.q.copy(), plan.force.copy(), list(plan.config)


def _effect_sizes(truth: Truth, declared: Robot, hidden: list[HiddenEffect], kq: np.ndarray,
                  units: Units, smoothing: np.ndarray, geometry: Geometry, q: np.ndarray,
                  applied: np.ndarray, clean: np.ndarray) -> dict[str, float]:
    """Per hidden effect, the RMS change (m) it makes to the noise-free deflections
    ``clean`` (m): the truth without it (or, for ``complementary_stiffness``, the
    conventional model) against the truth."""
    effect_rms: dict[str, float] = {}
    for h in hidden:
        if LIBRARY[h.name].second_order:  # hidden by the conventional baseline
            other = truth.deflections(q, applied, mode="conventional")
        else:
            rest = [e for e in hidden if e is not h]
            t = build_truth(declared, kq, rest, units, smoothing, geometry)
            other = t.deflections(q, applied + truth.force_bias - t.force_bias)
        effect_rms[h.label] = float(np.sqrt(np.mean((clean - other) ** 2)))
    return effect_rms
