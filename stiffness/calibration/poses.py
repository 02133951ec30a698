"""Reachable measurement poses: joint limits, the robot's own workspace rules, margins.

:func:`sample_coordinates` draws coordinate vectors a rig could measure at. A pose is kept when

* every coordinate is within its joint limits (revolute joints also within +-pi; joints without
  limits: +-pi, or 0..0.1 m for a prismatic joint);
* it follows the robot's workspace rules, where its ``robot.toml`` declares a ``[workspace]``
  table (:class:`Workspace`); otherwise the coordinates are uniform within the limits, or, for
  a closed-loop robot (whose limits say little about where it assembles), within
  :data:`LOOP_SPAN_RAD` (revolute) or :data:`LOOP_SPAN_FRACTION` of the reference length
  (prismatic, at least 1 cm) around its reference assembly (its shipped coordinates, else
  zero);
* the target is above the base plane (z >= 0 in the base frame), unless the workspace says
  ``target_above_base = false``;
* it assembles (loops closed on the reference branch, regular) with a moderate target Jacobian
  (at most :data:`MAX_JACOBIAN` m/rad: a larger one is next to a loop singularity);
* optionally, it is away from singularities: ``sigma_r / sigma_1`` of the target Jacobian over
  every coordinate joint, rows ``[v; L omega]`` (``L`` the base-to-target distance, so both
  rows are lengths per radian), at least ``singularity_margin`` times the best value over a
  few probe poses, ``r`` the rank the robot reaches in general (the largest rank seen there);
* optionally, for closed loops, away from folds: ``sigma_min / sigma_max`` of the passive-joint
  columns of the loop-closure Jacobian (zero where the loop flattens or folds and its passive
  joints are no longer determined) at least ``fold_margin`` times its value at the reference
  assembly (mechanisms with many passive joints are never well conditioned in absolute terms).

A ``[workspace]`` table (angles in ``angle_unit``, ``deg`` or ``rad``; lengths in m)::

    [workspace]
    angle_unit = "deg"
    ranges = { joint1 = [-90.0, 90.0], joint2 = [-70.0, 70.0] }      # uniform, in this order
    avoid = [{ sum = { joint2 = 1.0, joint3 = 1.0 }, values = [90.0, -90.0], margin = 15.0 }]
    choices = { joint6 = [-90.0, 90.0] }                               # one of these values
    fixed = { joint4 = { offset = 0.0 }, joint5 = { offset = -90.0, joint3 = -1.0 } }
    target_above_base = false

``ranges`` narrow the limits of the joints they name; the joints no rule names are uniform
within their limits; ``avoid`` rejects poses where a linear combination of coordinates is
within ``margin`` of one of ``values``; ``fixed`` sets a joint to ``offset + sum(c_j q_j)``
of the drawn ones. Units: rad and m inside.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from stiffness.calibration.effects import cached_robot
from stiffness.errors import ConvergenceError, StiffnessError, UnknownJointError, did_you_mean
from stiffness.mechanics.formulation import target_state
from stiffness.model import kinematics
from stiffness.model.robot import Robot

#: Poses whose target Jacobian exceeds this (m/rad) are near a loop singularity: not drawn.
MAX_JACOBIAN = 10.0
#: Closed loops without workspace rules: revolute coordinates within this of the reference (rad).
LOOP_SPAN_RAD = 0.5
#: ... and prismatic ones within this fraction of their reference length.
LOOP_SPAN_FRACTION = 0.05
#: Give up when this many draws (plus 10 per pose asked) assemble none.
_FIRST_POSE_TRIES = 50
#: Probe poses used to find the rank the robot's Jacobian reaches in general.
_RANK_PROBES = 8
_RANK_RTOL = 1e-8
_KEYS = {"angle_unit", "ranges", "avoid", "choices", "fixed", "target_above_base"}
_ANGLE = {"deg": math.pi / 180.0, "rad": 1.0}


@dataclass
class Avoid:
    """Reject poses with ``|sum_j c_j q_j - v| < margin`` for a ``v`` of ``values`` (rad, m)."""

    terms: dict[int, float]
    values: tuple[float, ...]
    margin: float

    def rejects(self, coords: np.ndarray) -> bool:
        """Whether ``coords`` falls in a band to avoid."""
        s = sum(c * coords[j] for j, c in self.terms.items())
        return any(abs(s - v) < self.margin for v in self.values)


@dataclass
class Workspace:
    """A robot's declared workspace rules (SI), read from the ``[workspace]`` of its robot.toml.

    Attributes
    ----------
    ranges
        Coordinate index -> (low, high), drawn uniformly in declaration order.
    avoid
        Bands of linear combinations to stay out of.
    choices
        Coordinate index -> values, one drawn at random.
    fixed
        Coordinate index -> (offset, {index: coefficient}).
    target_above_base
        Whether the target must be above the base plane.
    """

    ranges: dict[int, tuple[float, float]] = field(default_factory=dict)
    avoid: list[Avoid] = field(default_factory=list)
    choices: dict[int, tuple[float, ...]] = field(default_factory=dict)
    fixed: dict[int, tuple[float, dict[int, float]]] = field(default_factory=dict)
    target_above_base: bool = True

    @classmethod
    def of(cls, robot: Robot) -> Workspace:
        """The rules ``robot`` declares (none: uniform within the limits, target above base).

        Raises
        ------
        StiffnessError
            On an unknown key, an unknown joint or a malformed value.
        """
        table = robot.defaults.get("workspace")
        if table is None:
            return cls()
        where = f"[workspace] of {robot.name}'s robot.toml"
        if not isinstance(table, dict):
            raise StiffnessError(f"{where} must be a table")
        for key in table:
            if key not in _KEYS:
                raise StiffnessError(f"{where}: unknown key {key!r}; "
                                     f"{did_you_mean(key, sorted(_KEYS))}")
        unit = table.get("angle_unit", "rad")
        if unit not in _ANGLE:
            raise StiffnessError(f"{where}: angle_unit must be deg or rad, got {unit!r}")
        joints = list(robot.coordinate_joints)
        model = robot.model
        factor = [1.0 if model.joints[model.getJointId(j)].shortname().startswith("JointModelP")
                  else _ANGLE[unit] for j in joints]

        def index(name: str) -> int:
            if name not in joints:
                raise UnknownJointError(f"{where}: {name!r} is not a coordinate joint; "
                                        f"{did_you_mean(name, joints)}", name=name,
                                        choices=joints)
            return joints.index(name)

        def numbers(value, what: str, count: int | None = None) -> list[float]:
            ok = isinstance(value, list) and all(
                isinstance(v, int | float) and not isinstance(v, bool) for v in value)
            if not ok or (count is not None and len(value) != count) or not value:
                raise StiffnessError(f"{where}: {what} must be a list of "
                                     f"{count or 'some'} numbers, got {value!r}")
            return [float(v) for v in value]

        out = cls(target_above_base=bool(table.get("target_above_base", True)))
        for name, value in table.get("ranges", {}).items():
            i = index(name)
            lo, hi = numbers(value, f"ranges.{name}", 2)
            if not hi > lo:
                raise StiffnessError(f"{where}: ranges.{name} must be [low, high] with low < high")
            out.ranges[i] = (lo * factor[i], hi * factor[i])
        for name, value in table.get("choices", {}).items():
            i = index(name)
            out.choices[i] = tuple(v * factor[i] for v in numbers(value, f"choices.{name}"))
        for name, value in table.get("fixed", {}).items():
            i = index(name)
            if not isinstance(value, dict):
                raise StiffnessError(f"{where}: fixed.{name} must be a table "
                                     "{ offset = ..., joint = coefficient, ... }")
            offset = float(value.get("offset", 0.0)) * factor[i]
            terms = {index(j): float(c) * factor[i] / factor[index(j)]
                     for j, c in value.items() if j != "offset"}
            out.fixed[i] = (offset, terms)
        for k, item in enumerate(table.get("avoid", [])):
            if not isinstance(item, dict) or set(item) != {"sum", "values", "margin"}:
                raise StiffnessError(f"{where}: avoid[{k}] needs exactly sum, values and margin")
            terms = {index(j): float(c) for j, c in item["sum"].items()}
            scale = _ANGLE[unit]
            out.avoid.append(Avoid(terms, tuple(v * scale for v in numbers(
                item["values"], f"avoid[{k}].values")), float(item["margin"]) * scale))
        named = [set(out.ranges), set(out.choices), set(out.fixed)]
        if sum(len(s) for s in named) != len(set().union(*named)):
            raise StiffnessError(f"{where}: a joint is named by more than one of ranges, "
                                 "choices and fixed")
        return out

    @property
    def declared(self) -> bool:
        """Whether any rule is declared."""
        return bool(self.ranges or self.avoid or self.choices or self.fixed)

    def draw(self, lo: np.ndarray, hi: np.ndarray, rng: np.random.Generator
             ) -> np.ndarray | None:
        """One coordinate vector, or ``None`` if it falls in a band to avoid."""
        if not self.declared:
            return rng.uniform(lo, hi)
        coords = np.zeros(lo.shape[0])
        for i, (a, b) in self.ranges.items():
            coords[i] = rng.uniform(max(a, lo[i]), min(b, hi[i]))
        free = [i for i in range(lo.shape[0])
                if i not in self.ranges and i not in self.choices and i not in self.fixed]
        if free:
            coords[free] = rng.uniform(lo[free], hi[free])
        if any(a.rejects(coords) for a in self.avoid):
            return None
        for i, values in self.choices.items():
            coords[i] = rng.choice(values)
        for i, (offset, terms) in self.fixed.items():
            coords[i] = offset + sum(c * coords[j] for j, c in terms.items())
        return coords


def coordinate_limits(robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper limits (rad, m) of the coordinates as poses are drawn.

    Revolute joints within +-pi; a joint without finite limits: +-pi, or 0..0.1 m if prismatic.
    """
    model = robot.model
    joints = [model.joints[model.getJointId(j)] for j in robot.coordinate_joints]
    lo = np.array([model.lowerPositionLimit[j.idx_q] for j in joints])
    hi = np.array([model.upperPositionLimit[j.idx_q] for j in joints])
    prismatic = np.array([j.shortname().startswith("JointModelP") for j in joints])
    bad = ~np.isfinite(lo) | ~np.isfinite(hi) | (hi <= lo)
    lo = np.where(bad, np.where(prismatic, 0.0, -math.pi), lo)
    hi = np.where(bad, np.where(prismatic, 0.1, math.pi), hi)
    lo = np.where(prismatic, lo, np.maximum(lo, -math.pi))
    hi = np.where(prismatic, hi, np.minimum(hi, math.pi))
    return lo, hi


def sampling_box(robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    """Box (rad, m) the coordinates are drawn in when no workspace rule says otherwise: the
    limits (:func:`coordinate_limits`), narrowed around the reference assembly for loops."""
    lo, hi = coordinate_limits(robot)
    if robot.loop is None:
        return lo, hi
    from stiffness.mechanics.defaults import default_coordinates

    ref = default_coordinates(robot)
    ref = np.zeros(robot.n_coordinates) if ref is None else ref
    model = robot.model
    prismatic = np.array([model.joints[model.getJointId(j)].shortname().startswith("JointModelP")
                          for j in robot.coordinate_joints])
    span = np.where(prismatic, np.maximum(LOOP_SPAN_FRACTION * np.abs(ref), 0.01),
                    LOOP_SPAN_RAD)
    return np.maximum(lo, ref - span), np.minimum(hi, ref + span)


def _all_coordinates(robot: Robot) -> Robot:
    if tuple(robot.compliant_joints) == tuple(robot.coordinate_joints):
        return robot
    return cached_robot(robot.name, robot.target_frame, tuple(robot.target_offset),
                        tuple(robot.coordinate_joints))


def singular_values(robot: Robot, q: np.ndarray) -> np.ndarray:
    """Singular values of the target Jacobian over every coordinate joint, rows ``[v; L omega]``
    (``L`` the base-to-target distance, at least 0.1 m), m/rad; ``q`` closed.

    Raises
    ------
    StiffnessError
        If the loop is singular at ``q``.
    """
    full = _all_coordinates(robot)
    state = target_state(full, q)
    length = max(float(np.linalg.norm(state.position)), 0.1)
    jac = np.vstack([state.jacobian[:3], length * state.jacobian[3:]])
    return np.linalg.svd(jac, compute_uv=False)


def fold_ratio(robot: Robot, q: np.ndarray) -> float:
    """``sigma_min / sigma_max`` of the passive columns of the loop-closure Jacobian at ``q``
    (1 for a robot without loops; 0 on a fold)."""
    if robot.loop is None or not len(robot.loop.passive_v):
        return 1.0
    kinematics.update_first_order(robot.model, robot.data, q)
    cp = robot.loop.jacobian(robot.model, robot.data)[:, robot.loop.passive_v]
    sv = np.linalg.svd(cp, compute_uv=False)
    return float(sv[-1] / sv[0]) if sv[0] > 0 else 0.0


def sample_coordinates(robot: Robot, n: int, rng: np.random.Generator, max_tries: int = 200,
                       singularity_margin: float = 0.0, fold_margin: float = 0.0) -> np.ndarray:
    """``n`` random reachable coordinate vectors (rad, m), shape (n, n_coordinates).

    See the module docstring for the rules; the margins are off by default.

    Raises
    ------
    StiffnessError
        If fewer than ``n`` poses are found in ``max_tries * n`` draws.
    """
    rules = Workspace.of(robot)
    lo, hi = coordinate_limits(robot) if rules.declared else sampling_box(robot)
    rank = None
    fold_floor = 0.0
    if fold_margin > 0 and robot.loop is not None:
        fold_floor = fold_margin * _reference_fold_ratio(robot)
    if singularity_margin > 0:
        probe = np.random.default_rng(int(rng.integers(2 ** 63)))
        rank, best_ratio = _generic_rank(robot, lo, hi, rules, probe)
        singularity_floor = singularity_margin * best_ratio
    out: list[np.ndarray] = []
    for attempt in range(max_tries * n):
        if len(out) == n or (not out and attempt >= _FIRST_POSE_TRIES + 10 * n):
            break
        coords = rules.draw(lo, hi, rng)
        if coords is None:
            continue
        if np.any(coords < lo - 1e-12) or np.any(coords > hi + 1e-12):
            continue
        try:
            q = robot.configuration(coords)
            state = target_state(robot, q)
            if np.abs(state.jacobian[:3]).max() > MAX_JACOBIAN:
                continue
            if rules.target_above_base and state.position[2] < 0.0:
                continue
            if fold_floor > 0 and fold_ratio(robot, q) < fold_floor:
                continue
            if rank is not None:
                sv = singular_values(robot, q)
                if sv[rank - 1] < singularity_floor * sv[0]:
                    continue
        except StiffnessError:
            continue
        out.append(coords)
    if len(out) < n:
        raise ConvergenceError(f"found only {len(out)} of {n} reachable poses of {robot.name}"
                               + (" away from singularities and folds" if singularity_margin > 0
                                  or fold_margin > 0 else "")
                               + "; ask for fewer configurations, or check the joint limits")
    return np.array(out)


def _reference_fold_ratio(robot: Robot) -> float:
    """:func:`fold_ratio` at the reference assembly (the shipped coordinates, else zero)."""
    from stiffness.mechanics.defaults import default_coordinates

    ref = default_coordinates(robot)
    try:
        q = robot.configuration(np.zeros(robot.n_coordinates) if ref is None else ref)
    except StiffnessError:
        return 1.0  # no reference to compare with: an absolute margin
    return fold_ratio(robot, q)


def _generic_rank(robot: Robot, lo: np.ndarray, hi: np.ndarray, rules: Workspace,
                  rng: np.random.Generator) -> tuple[int, float]:
    """The largest Jacobian rank over a few assembled probe poses (the rank in general), and
    the best ``sigma_r / sigma_1`` among them."""
    svs = []
    for attempt in range(50 * _RANK_PROBES):
        if len(svs) == _RANK_PROBES or (not svs and attempt >= _FIRST_POSE_TRIES):
            break
        coords = rules.draw(lo, hi, rng)
        if coords is None:
            continue
        try:
            svs.append(singular_values(robot, robot.configuration(coords)))
        except StiffnessError:
            continue
    if not svs:
        raise ConvergenceError(f"no pose of {robot.name} drawn within its joint limits "
                               f"assembles (in {_FIRST_POSE_TRIES} draws); check the limits, or "
                               "declare a [workspace] in its robot.toml")
    rank = max(int(np.sum(sv > _RANK_RTOL * max(sv[0], 1e-300))) for sv in svs)
    return rank, max(float(sv[rank - 1] / sv[0]) if len(sv) >= rank else 0.0 for sv in svs)
