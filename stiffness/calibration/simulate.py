"""Synthetic campaigns with hidden effects: what could a rig detect before measuring?

:func:`simulate` draws reachable configurations
(:func:`stiffness.calibration.poses.sample_coordinates`), or takes the rows of a measurement plan
(:mod:`stiffness.calibration.plan`), loads along random directions (or a ramp along one
direction per configuration, or the six axis directions), computes the deflections from the
*exact* elastostatic equilibrium of a true robot that carries the hidden effects, adds Gaussian
noise, and returns a :class:`~stiffness.calibration.campaign.Campaign` that declares only the
baseline (its ``--kq`` joints), plus the hidden truth.

How each hidden effect enters the truth (see :mod:`stiffness.calibration.effects` for the models):

* ``complementary_stiffness``: always in the truth (the equilibrium is exact); hiding it means
  declaring the ``conventional`` baseline, so the campaign's model misses it.
* ``joint_compliance:J=k``: joint J is a spring of stiffness k (N.m/rad, N/m) in the true robot.
* ``link_compliance:A->B=k[,k2]``: after the joint equilibrium, the part beyond B's origin turns
  by ``sum_i e_i (e_i . M_B) / k_i`` (N.m/rad; one value for both axes), with the moment and
  the axes at the deflected configuration (the coupling back into the joint torques is
  second order and neglected).
* ``backlash:J=b``: ``dtheta_J += b tanh(tau_J / tau_s)`` (b in the campaign's angle unit;
  tau_s as in :mod:`stiffness.calibration.effects`), solved exactly with the rest.
* ``nonlinear_joint_stiffness:J=beta``: ``dtheta_J = tau_J / k_J (1 + beta |tau_J|)``
  (beta in 1/(N.m); > 0 softens).
* ``frame_misalignment=r`` or ``=rx,ry,rz``: the deflections are measured in a frame rotated by
  that rotation vector (angle unit; one value turns about (1, 1, 1)/sqrt(3)).
* ``target_offset=d`` or ``=dx,dy,dz``: the true target is that far from the declared one
  (length unit, target frame axes; one value along (1, 1, 1)/sqrt(3)).
* ``force_sensor_bias=b`` or ``=bx,by,bz``: the recorded force is the applied one plus b
  (force unit; one value along (1, 1, 1)/sqrt(3)).
* ``deflection_offset=d`` or ``=dx,dy,dz``: the measured deflections carry that offset.

The size of each hidden effect is reported as the RMS change it makes to the noise-free
deflections (:attr:`Simulation.effect_rms_m`), in noise units in ``truth.json``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.calibration.campaign import Campaign, RobotSettings, Units, write_campaign
from stiffness.calibration.effects import (
    LIBRARY,
    Geometry,
    LinkCompliance,
    References,
    cached_robot,
    chain_placements,
    link_axes,
    make_effect,
    rotation_matrix,
)
from stiffness.calibration.plan import Plan
from stiffness.calibration.poses import sample_coordinates
from stiffness.errors import (
    StiffnessError,
    UnknownEffectError,
    UnknownJointError,
    UnknownNameError,
    did_you_mean,
)
from stiffness.files import atomic_write
from stiffness.mechanics.equilibrium import SpringLaw, solve_equilibrium, tangent_equilibrium
from stiffness.mechanics.formulation import as_wrench, target_state
from stiffness.model.robot import Robot

#: Load patterns of :func:`simulate`.
LOAD_PATTERNS = ("random", "ramp", "axes")
#: File documenting the hidden truth beside ``campaign.toml``.
TRUTH_FILE = "truth.json"
_DIAGONAL = np.ones(3) / math.sqrt(3.0)


# ------------------------------------------------------------------------------------------
# hidden effects


@dataclass
class HiddenEffect:
    """An effect hidden in a simulated campaign.

    Attributes
    ----------
    name
        Library name (:data:`stiffness.calibration.effects.LIBRARY`).
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
        return self.name if self.where is None else f"{self.name}({self.where})"

    def to_dict(self) -> dict:
        """JSON-ready."""
        return {"effect": self.name, "where": self.where, "values": list(self.values)}


_VALUE_COUNTS = {
    "complementary_stiffness": (0, 1), "joint_compliance": (1,), "link_compliance": (1, 2),
    "backlash": (1,), "nonlinear_joint_stiffness": (1,), "frame_misalignment": (1, 3),
    "target_offset": (1, 3), "force_sensor_bias": (1, 3), "deflection_offset": (1, 3),
}


def parse_effect(text: str) -> HiddenEffect:
    """Parse ``NAME[:where]=value[,value...]`` (``complementary_stiffness`` takes no value).

    Raises
    ------
    StiffnessError
        Unknown name, a missing value, a wrong number of values, or a non-number.
    """
    head, _, rest = text.partition("=")
    name, _, where = head.strip().partition(":")
    name, where = name.strip(), where.strip() or None
    if name not in LIBRARY:
        raise UnknownEffectError(f"unknown effect {name!r} in --effect {text!r}; "
                                 f"{did_you_mean(name, list(LIBRARY))}", name=name,
                                 choices=list(LIBRARY))
    values: list[float] = []
    if rest.strip():
        for item in rest.split(","):
            try:
                values.append(float(item))
            except ValueError:
                raise StiffnessError(f"--effect {text!r}: {item.strip()!r} is not a number"
                                     ) from None
    if not all(math.isfinite(v) for v in values):
        raise StiffnessError(f"--effect {text!r}: values must be finite")
    if len(values) not in _VALUE_COUNTS[name]:
        counts = " or ".join(str(c) for c in _VALUE_COUNTS[name])
        raise StiffnessError(f"--effect {text!r}: {name} takes {counts} value(s), got "
                             f"{len(values)}")
    return HiddenEffect(name, where, tuple(values))


def _vector(values: tuple[float, ...]) -> np.ndarray:
    return values[0] * _DIAGONAL if len(values) == 1 else np.array(values, dtype=float)


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
        ``(a, b, column, k1, k2)`` hidden link compliances.
    chain
        The target chain's joints.
    misalignment
        Rotation vector of the instrument frame (rad).
    force_bias
        Recorded minus applied force (N).
    deflection_offset
        Offset of the measured deflections (m).
    """

    robot: Robot
    law: SpringLaw
    links: list[tuple[str, str, int, float, float]] = field(default_factory=list)
    chain: tuple[str, ...] = ()
    misalignment: np.ndarray = field(default_factory=lambda: np.zeros(3))
    force_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))
    deflection_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def deflections(self, coords: np.ndarray, force: np.ndarray, mode: str = "exact"
                    ) -> np.ndarray:
        """Noise-free measured deflections (m, 3) of rows at ``coords`` under the *applied*
        forces ``force`` (m, 3).

        ``mode``: ``exact`` (the exact equilibrium), ``enhanced`` (``K_C`` of the unloaded
        pose in the tangent, first-order kinematics) or ``conventional`` (first order, no
        ``K_C``): the latter two measure what the linear baselines miss."""
        if mode not in ("exact", "enhanced", "conventional"):
            raise UnknownNameError(f"unknown mode {mode!r}; valid: exact, enhanced, "
                                   "conventional", name=mode,
                                   choices=("exact", "enhanced", "conventional"))
        out = np.empty((len(coords), 3))
        q0 = {}
        for i, (c, f) in enumerate(zip(coords, force, strict=True)):
            key = tuple(c)
            if key not in q0:
                q0[key] = self.robot.configuration(c)
            out[i] = self._row(q0[key], f, mode)
        out = out @ rotation_matrix(self.misalignment).T
        return out + self.deflection_offset

    def _row(self, q0: np.ndarray, force: np.ndarray, mode: str) -> np.ndarray:
        robot, law = self.robot, self.law
        wrench = as_wrench(force)
        base = target_state(robot, q0, wrench)
        tau0 = base.jacobian.T @ wrench
        if mode == "exact":
            eq = solve_equilibrium(robot, q0, law, wrench)
            q, x, dx = eq.q, eq.position, eq.dx
        else:
            k_c = base.k_c if mode == "enhanced" else np.zeros_like(base.k_c)
            dtheta = tangent_equilibrium(law, tau0, k_c)
            q, x, dx = q0, base.position, base.jacobian[:3] @ dtheta
        if self.links:
            pin.forwardKinematics(robot.model, robot.data, q)
            origins, rotations = chain_placements(robot, self.chain)
            for a, b, column, k1, k2 in self.links:
                ia, ib = self.chain.index(a), self.chain.index(b)
                e1, e2 = link_axes(origins[ia], origins[ib], rotations[ib], column)
                r = x - origins[ib]
                m_b = np.cross(r, force)
                omega = e1 * (e1 @ m_b) / k1 + e2 * (e2 @ m_b) / k2
                dx = dx + np.cross(omega, r)
        return dx


def build_truth(declared: Robot, kq: np.ndarray, effects: list[HiddenEffect], units: Units,
                smoothing: np.ndarray, geometry: Geometry) -> Truth:
    """The true robot of a simulation from the declared one, its stiffness and hidden effects.

    ``smoothing`` is the backlash smoothing torque per coordinate joint (N.m).
    """
    offset = declared.target_offset.copy()
    extra, beta, backlash = [], {}, {}
    links, misalignment = [], np.zeros(3)
    force_bias, deflection_offset = np.zeros(3), np.zeros(3)
    stiff = dict(zip(declared.compliant_joints, kq, strict=True))
    for h in effects:
        make_effect(h.name, h.where, geometry)  # validates where
        v = h.values
        if h.name == "joint_compliance":
            if h.where in declared.compliant_joints:
                raise StiffnessError(f"joint_compliance:{h.where}: the joint is already "
                                     "compliant in the campaign")
            if v[0] <= 0:
                raise StiffnessError(f"joint_compliance:{h.where} needs a positive stiffness")
            extra.append(h.where)
            stiff[h.where] = v[0]
        elif h.name == "link_compliance":
            eff = make_effect(h.name, h.where, geometry)
            assert isinstance(eff, LinkCompliance)
            k1, k2 = (v[0], v[0]) if len(v) == 1 else v
            if k1 <= 0 or k2 <= 0:
                raise StiffnessError(f"link_compliance:{h.where} needs positive stiffnesses")
            links.append((eff.a, eff.b, eff.column, float(k1), float(k2)))
        elif h.name == "backlash":
            prismatic = geometry.prismatic[geometry.joints.index(h.where)]
            backlash[h.where] = v[0] * (units.length_to_si if prismatic else units.angle_to_si)
        elif h.name == "nonlinear_joint_stiffness":
            beta[h.where] = v[0]
        elif h.name == "frame_misalignment":
            misalignment = _vector(v) * units.angle_to_si
        elif h.name == "target_offset":
            offset = offset + _vector(v) * units.length_to_si
        elif h.name == "force_sensor_bias":
            force_bias = _vector(v) * units.force_to_si
        elif h.name == "deflection_offset":
            deflection_offset = _vector(v) * units.length_to_si
    compliant = tuple(declared.compliant_joints) + tuple(extra)
    for j in list(beta) + list(backlash):
        if j not in compliant:
            raise UnknownJointError(f"backlash and nonlinear_joint_stiffness act on a compliant "
                                    f"joint ({', '.join(compliant)}), not {j}", name=j,
                                    choices=compliant)
    robot = cached_robot(declared.name, declared.target_frame, tuple(offset), compliant)
    law = SpringLaw(np.array([1.0 / stiff[j] for j in compliant]),
              np.array([beta.get(j, 0.0) for j in compliant]),
              np.array([backlash.get(j, 0.0) for j in compliant]),
              np.array([smoothing[geometry.joints.index(j)] for j in compliant]))
    return Truth(robot, law, links, geometry.chain, misalignment, force_bias, deflection_offset)


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

    def truth(self) -> dict:
        """The hidden truth (JSON-ready), documented in ``truth.json``."""
        lu = self.campaign.units.length_to_si
        return {
            "format": "stiffness-simulation-truth",
            "robot": self.settings["robot"],
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
                "backlash": self.campaign.units.angle, "nonlinear_joint_stiffness": "1/(N.m)",
                "frame_misalignment": self.campaign.units.angle,
                "target_offset": self.campaign.units.length,
                "force_sensor_bias": self.campaign.units.force,
                "deflection_offset": self.campaign.units.length},
            "settings": self.settings,
            "model": ("exact elastostatic equilibrium of the true robot"
                      " (stiffness.calibration.simulate)"),
        }

    def write(self, folder: str | Path) -> Path:
        """Write ``campaign.toml``, ``measurements.csv`` and ``truth.json``; returns the toml."""
        path = write_campaign(self.campaign, folder)
        atomic_write(Path(folder) / TRUTH_FILE, json.dumps(self.truth(), indent=1) + "\n")
        self.campaign.path = path
        return path


def _loads(pattern: str, n: int, max_force: float, rng: np.random.Generator) -> np.ndarray:
    if pattern == "random":
        d = rng.normal(size=(n, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return d * rng.uniform(0.25, 1.0, size=(n, 1)) * max_force
    if pattern == "ramp":
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        return np.outer(np.arange(1, n + 1) / n, d) * max_force
    axes = np.vstack([np.eye(3), -np.eye(3)])
    return axes[np.arange(n) % 6] * max_force


def simulate(
    robot: str,
    kq: list[float] | np.ndarray | None = None,
    effects: list[HiddenEffect] | None = None,
    configs: int = 10,
    loads_per_config: int = 4,
    max_force: float = 100.0,
    noise_std_m: float = 1e-5,
    seed: int = 0,
    frame: str | None = None,
    target_offset_m: np.ndarray | list[float] | None = None,
    compliant_joints: list[str] | tuple[str, ...] | None = None,
    baseline: str | None = None,
    units: Units | None = None,
    load_pattern: str = "random",
    repeats: int = 1,
    declare_noise: bool = True,
    name: str | None = None,
    plan: Plan | None = None,
) -> Simulation:
    """Simulate a campaign with hidden effects.

    Parameters
    ----------
    robot
        Robot source (shipped name, example-robot-data name, URDF path).
    kq
        True stiffness of each declared compliant joint (N.m/rad, N/m); default the shipped
        robot's ``k_theta_SI``.
    effects
        Hidden effects (:func:`parse_effect`).
    configs, loads_per_config, repeats
        Number of configurations, loads per configuration, and measurements per load (the
        repeats share the deflection and differ by their noise).
    max_force
        Largest force (N).
    noise_std_m
        Measurement noise std (m) on each deflection component.
    seed
        Random seed (poses, loads, noise).
    frame, target_offset_m, compliant_joints
        Declared target and springs (defaults: the robot's).
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
    name
        Campaign name.
    plan
        Rows to simulate exactly (:class:`stiffness.calibration.plan.Plan`: coordinates,
        applied forces, labels) instead of drawing ``configs`` poses and their loads.

    Raises
    ------
    StiffnessError
        On bad inputs (unknown effect place, non-positive stiffness, unknown pattern) or when no
        reachable pose can be found.
    """
    effects = list(effects or [])
    units = units or Units()
    if load_pattern not in LOAD_PATTERNS:
        raise UnknownNameError(f"unknown load pattern {load_pattern!r}; valid: "
                               f"{', '.join(LOAD_PATTERNS)}", name=load_pattern,
                               choices=LOAD_PATTERNS)
    if configs < 1 or loads_per_config < 1 or repeats < 1:
        raise StiffnessError("configs, loads per config and repeats must be at least 1")
    if not (max_force > 0 and math.isfinite(max_force)):
        raise StiffnessError(f"max force must be positive, got {max_force}")
    if not (noise_std_m >= 0 and math.isfinite(noise_std_m)):
        raise StiffnessError(f"noise std must be >= 0, got {noise_std_m}")
    labels = [h.label for h in effects]
    if len(set(labels)) != len(labels):
        raise StiffnessError(f"an effect is hidden twice: {labels}")
    declared = cached_robot(str(robot), frame, None if target_offset_m is None else tuple(
        np.asarray(target_offset_m, dtype=float).reshape(-1)), None if compliant_joints is None
        else tuple(compliant_joints))
    if kq is None:
        if "k_theta_SI" not in declared.defaults:
            raise StiffnessError(f"give the true joint stiffness of {robot} (--kq), one per "
                                 f"compliant joint: {', '.join(declared.compliant_joints)}")
        kq = declared.defaults["k_theta_SI"]
    kq = np.asarray(kq, dtype=float).reshape(-1)
    if kq.shape[0] != declared.n_compliant or np.any(kq <= 0) or not np.all(np.isfinite(kq)):
        raise StiffnessError(f"need {declared.n_compliant} positive stiffnesses (one per "
                             f"compliant joint {', '.join(declared.compliant_joints)}), got "
                             f"{kq.tolist()}")
    hidden_cs = any(h.name == "complementary_stiffness" for h in effects)
    baseline = baseline or ("conventional" if hidden_cs else "enhanced")
    if hidden_cs and baseline != "conventional":
        raise StiffnessError("hiding complementary_stiffness means declaring the conventional "
                             "baseline (the truth is always the exact equilibrium)")

    rng = np.random.default_rng(seed)
    if plan is None:
        coords = sample_coordinates(declared, configs, rng)
        q = np.repeat(coords, loads_per_config, axis=0)
        applied = np.vstack([_loads(load_pattern, loads_per_config, max_force, rng)
                             for _ in range(configs)])
        row_labels = [f"C{i // loads_per_config + 1}" for i in range(len(q))]
    else:
        if plan.q.shape[1] != declared.n_coordinates:
            raise StiffnessError(f"the plan has {plan.q.shape[1]} coordinates per row but "
                                 f"{declared.name} has {declared.n_coordinates}")
        q, applied, row_labels = plan.q.copy(), plan.force.copy(), list(plan.config)
    geometry = Geometry.of(declared)
    truth = build_truth(declared, kq, [h for h in effects], units,
                        np.zeros(len(geometry.joints)), geometry)
    recorded = applied + truth.force_bias
    rows = geometry.rows(q, recorded)
    smoothing = References.of(geometry, rows, 1.0, np.ones((1, 3))).tau_smoothing
    truth = build_truth(declared, kq, effects, units, smoothing, geometry)
    clean = truth.deflections(q, applied)

    effect_rms: dict[str, float] = {}
    for h in effects:
        if h.name == "complementary_stiffness":
            other = truth.deflections(q, applied, mode="conventional")
        else:
            rest = [e for e in effects if e is not h]
            t = build_truth(declared, kq, rest, units, smoothing, geometry)
            other = t.deflections(q, applied + truth.force_bias - t.force_bias)
        effect_rms[h.label] = float(np.sqrt(np.mean((clean - other) ** 2)))

    linear = truth.deflections(q, applied, mode=baseline)
    baseline_error = float(np.sqrt(np.mean((clean - linear) ** 2)))

    reps = np.repeat(np.arange(len(q)), repeats)
    measured = clean[reps] + rng.normal(scale=noise_std_m, size=(len(reps), 3))
    config_labels = [row_labels[i] for i in reps]
    settings = RobotSettings(declared.name, frame=declared.target_frame,
                             target_offset_m=declared.target_offset.copy(),
                             compliant_joints=tuple(declared.compliant_joints))
    campaign = Campaign(
        name=name or f"simulated-{Path(str(robot)).stem}",
        baseline=baseline, robot_settings=settings, q=q[reps], force=recorded[reps],
        deflection=measured, config=tuple(config_labels),
        noise_std_m=noise_std_m if declare_noise and noise_std_m > 0 else None,
        units=units, _robot=declared,
    )
    info = {
        "robot": {"source": str(robot), "frame": declared.target_frame,
                  "target_offset_m": declared.target_offset.tolist()},
        "configs": len(dict.fromkeys(row_labels)) if plan is not None else configs,
        "loads_per_config": None if plan is not None else loads_per_config,
        "plan": str(plan.path) if plan is not None and plan.path is not None else None,
        "repeats": repeats,
        "max_force_N": float(np.linalg.norm(applied, axis=1).max()) if plan is not None
        else max_force,
        "load_pattern": None if plan is not None else load_pattern, "seed": seed,
        "declare_noise": declare_noise,
        "backlash_smoothing_Nm": dict(zip(geometry.joints, smoothing.tolist(), strict=True)),
    }
    return Simulation(campaign, effects, kq, noise_std_m, effect_rms, info, baseline_error)
