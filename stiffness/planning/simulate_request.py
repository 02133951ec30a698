"""What ``stiffness simulate`` is asked for: the request's checks, its drawn loads, its
record in ``truth.json``'s settings and the line for a row its loads buckle
(:mod:`stiffness.planning.simulate`)."""

from __future__ import annotations

import math
import warnings

import numpy as np

from stiffness.calibration.campaign_toml import JOINT_ANGLES
from stiffness.elastic.effects import make_effect
from stiffness.elastic.effects.geometry import Geometry
from stiffness.errors import FlagValueWarning, StiffnessError, UnknownNameError
from stiffness.mechanics.defaults import joint_stiffnesses
from stiffness.planning.plan import Plan
from stiffness.robot.kinematics import reach
from stiffness.robot.robot import Robot
from stiffness.units import FLAG_NUMBER, MAX_CELL, Units, float_array, plain_float, whole_number

#: Load patterns of :func:`simulate`.
LOAD_PATTERNS = ("random", "ramp", "axes")


#: Most rows a simulated campaign may have (each is an equilibrium solve; ~1e2-1e3 on a rig).
MAX_ROWS = 1_000_000


def draw_loads(pattern: str, n: int, max_force: float, rng: np.random.Generator) -> np.ndarray:
    """``n`` forces (N, rows of 3) of the load pattern ``pattern`` (:data:`LOAD_PATTERNS`), at
    most ``max_force`` (N) each."""
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


def effect_values(text: str, rest: str) -> list[float]:
    """The values after ``=`` (``rest``) of the ``--effect`` ``text``: comma-separated finite
    numbers within the cells' range (none when empty).

    Raises
    ------
    StiffnessError
        A non-number, or a value not finite or beyond the range.
    """
    values: list[float] = []
    if rest.strip():
        for item in rest.split(","):
            try:
                values.append(plain_float(item, FLAG_NUMBER))
            except ValueError as exc:
                raise StiffnessError(f"--effect {text!r}: {exc}") from None
    if not all(math.isfinite(v) and abs(v) <= MAX_CELL for v in values):
        raise StiffnessError(f"--effect {text!r}: values must be finite, within +-{MAX_CELL:.0e}")
    return values


def check_request(configs: int, loads_per_config: int, repeats: int, max_force: float,
                   noise_std_m: float, load_pattern: str, plan_rows: int | None,
                   labels: list[str], joint_angles: str) -> None:
    """Refuse an unknown load pattern or joint-angle kind, sizes below one or beyond
    :data:`MAX_ROWS`, a non-positive force (N), a negative noise (m) or an effect hidden
    twice (``labels``, the hidden effects' labels), in one line."""
    if joint_angles not in JOINT_ANGLES:
        raise StiffnessError(f"joint angles must be motor (the drives' encoders) or link (the "
                             f"link pose as measured), got {joint_angles!r}")
    if load_pattern not in LOAD_PATTERNS:
        raise UnknownNameError(f"unknown load pattern {load_pattern!r}; valid: "
                               f"{', '.join(LOAD_PATTERNS)}", name=load_pattern,
                               choices=LOAD_PATTERNS)
    for name, count in (("configs", configs), ("loads_per_config", loads_per_config),
                        ("repeats", repeats)):
        whole_number(count, name)
    for name, value, needed in (("max_force", max_force, "a force > 0 (N)"),
                                ("noise_std_m", noise_std_m, "a length >= 0 (m)")):
        float_array(value, name, needed, ndim=0, finite=False)
    rows = (plan_rows if plan_rows is not None else configs * loads_per_config) * repeats
    if rows > MAX_ROWS:
        raise StiffnessError(
            f"the campaign would have {rows:.3g} rows ("
            + ("plan rows" if plan_rows is not None else "configs x loads per config")
            + f" x repeats), more than {MAX_ROWS:.0e}, far beyond any rig's campaign and hours "
            "of equilibrium solves; ask for fewer")
    if not (max_force > 0 and math.isfinite(max_force)):
        raise StiffnessError(f"max force must be positive, got {max_force}")
    if not (noise_std_m >= 0 and math.isfinite(noise_std_m)):
        raise StiffnessError(f"noise std must be >= 0, got {noise_std_m}")
    if len(set(labels)) != len(labels):
        raise StiffnessError(f"an effect is hidden twice: {labels}")


def warn_effect_lengths(hidden: list[tuple[str, str | None, tuple[float, ...]]],
                        geometry: Geometry, units: Units) -> None:
    """Warn (:class:`~stiffness.errors.FlagValueWarning`, one line per effect) when a hidden
    effect's lengths, given in the files' length unit ``units.length`` (a target offset, a
    payload's centre of mass, a deflection offset, a prismatic joint's backlash), put it
    farther than the robot's reach (:func:`~stiffness.robot.kinematics.reach`, the
    physical scale of a target offset and of a centre of mass): no effect on this robot is
    that large, the value was meant in a smaller unit (``target_offset=20`` in m, meant in
    mm). ``hidden``: each effect's name, place (or ``None``) and values as given, checked as
    :meth:`~stiffness.elastic.effects.base.Effect.simulated_values` reads them."""
    size = reach(geometry.robot.model)
    for name, where, values in hidden:
        effect = make_effect(name, where, geometry)
        si = effect.simulated_values(values, units)
        lengths = [v for v, (unit, to_si) in zip(si, effect.units(units), strict=False)
                   if unit == units.length and to_si == units.length_to_si]
        metres = float(np.linalg.norm(lengths)) if lengths else 0.0
        if metres <= size:
            continue
        given = (f"{name}:{where}" if where else name) + "=" + ",".join(f"{v:g}" for v in values)
        si_note = "" if units.length == "m" else f" ({metres:.3g} m)"
        example = ("" if units.length == "mm" else
                   f" (--units mm reads them as {metres * 1e-3 / units.length_to_si:.3g} m)")
        warnings.warn(
            f"--effect {given}: its length {metres / units.length_to_si:.3g} "
            f"{units.length}{si_note} is beyond {geometry.robot.title}'s reach ({size:.3g} m), "
            f"no {name} on it; --effect lengths are in the files' length unit (--units, here "
            f"{units.length}): give them in {units.length}, or give --units the unit they are "
            f"in{example}", FlagValueWarning, stacklevel=3)


def rotation_noise_std(rotation_noise_std_rad: float | None, noise_std_m: float,
                       rotations: bool) -> float:
    """The rotation noise std (rad): given, else ``noise_std_m / 0.1 m`` (a 6-D probe whose
    markers are 0.1 m apart); refused when negative or not finite, or given when no
    orientation is measured (``rotations`` false: it would be ignored; the CLI's
    ``--rotation-noise`` without ``--rotations`` alike)."""
    if rotation_noise_std_rad is not None and not rotations:
        raise StiffnessError("rotation_noise_std_rad is the noise of the orientations "
                             "rotations=True measures: pass rotations=True, or drop it")
    if rotation_noise_std_rad is None:
        rotation_noise_std_rad = noise_std_m / 0.1
    if not (rotation_noise_std_rad >= 0 and math.isfinite(rotation_noise_std_rad)):
        raise StiffnessError(f"rotation noise std must be >= 0, got {rotation_noise_std_rad}")
    return rotation_noise_std_rad


def true_stiffness(declared: Robot, kq: list[float] | np.ndarray | None, source: str
                    ) -> np.ndarray:
    """The true stiffness per declared compliant joint (SI): ``kq``, else the shipped
    robot's ``k_theta_SI``; refused unless one positive value per joint."""
    if kq is None:
        if "k_theta_SI" not in declared.defaults:
            raise StiffnessError(f"give the true joint stiffness of {source} (--kq), one per "
                                 f"compliant joint: {', '.join(declared.compliant_joints)}")
        kq = declared.defaults["k_theta_SI"]
    return joint_stiffnesses(declared, kq, "kq")


def request_record(plan: Plan | None, configs: int, loads_per_config: int, repeats: int,
                    load_pattern: str, max_force: float, row_labels: list[str],
                    applied: np.ndarray) -> dict:
    """What was asked for (``truth.json``'s settings): the plan's sizes and largest force
    (N), or the drawn ones."""
    if plan is None:
        return {"configs": configs, "loads_per_config": loads_per_config, "plan": None,
                "repeats": repeats, "max_force_N": max_force, "load_pattern": load_pattern}
    return {"configs": len(dict.fromkeys(row_labels)), "loads_per_config": None,
            "plan": str(plan.path) if plan.path is not None else None, "repeats": repeats,
            "max_force_N": float(np.linalg.norm(applied, axis=1).max()),
            "load_pattern": None}


def settings_record(source: str, declared: Robot, request: dict, seed: int, declare_noise: bool,
                    rotations: bool, rotation_noise_std_rad: float, smoothing: dict[str, float],
                    joint_angles: str) -> dict:
    """``truth.json``'s settings: the robot (its ``source``, the declared target frame and
    offset, m), the ``request`` (:func:`request_record`), the seed, whether the noise is
    declared, whether rotations are recorded and their noise std (rad; None when not), the
    backlash smoothing torque per joint (N.m) and what the joint angles record."""
    return {"robot": {"source": source, "frame": declared.target_frame,
                      "target_offset_m": declared.target_offset.tolist()},
            **request, "seed": seed,
            "declare_noise": declare_noise, "rotations": rotations,
            "rotation_noise_std_rad": rotation_noise_std_rad if rotations else None,
            "backlash_smoothing_Nm": smoothing, "joint_angles": joint_angles}


def buckled_row(robot: Robot, row: int, force: np.ndarray, reason: str) -> str:
    """One line for a simulated row whose exact equilibrium fails (``reason``, the
    equilibrium's own error without its Python-side fix): the row, its load and the flags
    that bring the loads under the robot's buckling load."""
    load = ", ".join(f"{v:.4g}" for v in np.asarray(force, float))
    return (f"simulated row {row + 1} (load {load} N): {reason.split('; ')[0]}; the rows' loads "
            f"buckle {robot.title} at that pose, or come near it (the exact equilibrium is what "
            "the campaign records): lower the loads (--max-force, or a plan's forces) or give "
            "stiffer springs (--kq)")
