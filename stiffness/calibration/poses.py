"""Reachable measurement poses: joint limits, the robot's own workspace rules, margins.

:func:`sample_coordinates` draws coordinate vectors a rig could measure at. A pose is kept when

* every coordinate is within its joint limits (revolute joints also within +-pi; joints without
  limits: +-pi, or 0..0.1 m for a prismatic joint), and so is every chain joint a
  ``[controller]`` sets (a passive joint that follows a combination of coordinates too);
* it follows the robot's workspace rules, where its ``robot.toml`` declares a ``[workspace]``
  table (:class:`Workspace`); otherwise the coordinates are uniform within the limits, or, for
  a closed-loop robot (whose limits say little about where it assembles), within
  :data:`~stiffness.mechanics.defaults.LOOP_SPAN_RAD` (revolute) or
  :data:`~stiffness.mechanics.defaults.LOOP_SPAN_FRACTION` of the reference length
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

The ``[workspace]`` table is described by :class:`Workspace`. Units: rad and m inside.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from stiffness.errors import (
    ConvergenceError,
    RobotFileWarning,
    StiffnessError,
    UnknownJointError,
    UnknownNameError,
    did_you_mean,
    warn_user,
)
from stiffness.mechanics import ik
from stiffness.mechanics.defaults import assembly_coordinates, loop_sampling_box
from stiffness.mechanics.formulation import target_state
from stiffness.robot import kinematics
from stiffness.robot.robot import Robot
from stiffness.robot.sources import WORKSPACE_KEYS
from stiffness.units import finite_number

#: A coordinate this close (rad, m) to its workspace range counts as inside it
#: (:meth:`Workspace.departures`): far below any joint's repeatability.
WORKSPACE_TOLERANCE = 1e-6
#: Poses whose target Jacobian exceeds this (m/rad) are near a loop singularity: not drawn.
MAX_JACOBIAN = 10.0
#: Give up when this many draws (plus 10 per pose asked) assemble none.
_FIRST_POSE_TRIES = 50
#: Probe poses used to find the rank the robot's Jacobian reaches in general.
_RANK_PROBES = 8
_RANK_RTOL = 1e-8


@dataclass
class Workspace:
    """Where poses are drawn, from the robot's ``[workspace]`` table in its ``robot.toml``.

    Every key is optional; angles are in ``angle_unit`` (``deg`` by default, or ``rad``),
    prismatic coordinates in m::

        [workspace]
        uniform = { joint1 = [-90.0, 90.0], joint2 = [-70.0, 70.0] }   # ranges
        choice = { joint6 = [-90.0, 90.0] }                             # one of these values
        linear = [ { joint = "joint5", constant = -90.0, terms = { joint3 = -1.0 } } ]
        avoid = [ { terms = { joint2 = 1.0, joint3 = 1.0 }, values = [90.0, -90.0],
                    margin = 15.0 } ]
        target_above_base = false

    A pose draws the ``uniform`` coordinates in the table's order, then every coordinate with
    no rule uniformly within its joint limits (``+-pi`` when unlimited), rejects the pose when
    an ``avoid`` combination ``sum terms * q`` lies within ``margin`` of one of its ``values``,
    draws the ``choice`` coordinates, and sets each ``linear`` coordinate to
    ``constant + sum terms * q`` in order. ``target_above_base`` (default true) rejects poses
    whose target is below the base plane.

    Attributes
    ----------
    uniform
        Coordinate index -> (low, high), SI.
    choice
        Coordinate index -> values, SI.
    linear
        (index, constant, {index: coefficient}) in order, SI.
    avoid
        ({index: coefficient}, values, margin), SI.
    target_above_base
        Whether the target must be above the base plane.
    """

    uniform: dict[int, tuple[float, float]] = field(default_factory=dict)
    choice: dict[int, list[float]] = field(default_factory=dict)
    linear: list[tuple[int, float, dict[int, float]]] = field(default_factory=list)
    avoid: list[tuple[dict[int, float], list[float], float]] = field(default_factory=list)
    target_above_base: bool = True
    declared: bool = False

    @classmethod
    def of(cls, robot: Robot) -> Workspace:
        """The robot's declared workspace (default: its joint limits, target above the base).

        Raises
        ------
        StiffnessError
            On an unknown key, joint or unit, or a malformed rule (one line naming it).
        """
        table = robot.defaults.get("workspace")
        if table is None:
            return cls()
        where = f"[workspace] of {robot.title}"
        if not isinstance(table, dict):
            raise StiffnessError(f"{where} must be a table")
        unknown = set(table) - set(WORKSPACE_KEYS)
        if unknown:
            key = sorted(unknown)[0]
            raise UnknownNameError(f"{where}: unknown key {key!r}; valid keys: "
                                   f"{', '.join(WORKSPACE_KEYS)}", name=key,
                                   choices=WORKSPACE_KEYS)
        unit = table.get("angle_unit", "deg")
        if unit not in ("deg", "rad"):
            raise StiffnessError(f"{where}: angle_unit must be deg or rad, got {unit!r}")
        names = list(robot.coordinate_joints)
        factor = np.array([1.0 if robot.is_prismatic(j) else (
            math.pi / 180.0 if unit == "deg" else 1.0) for j in names])

        def index(name) -> int:
            if name not in names:
                raise UnknownJointError(f"{where}: {name!r} is not a coordinate of "
                                        f"{robot.title}; {did_you_mean(str(name), names)}",
                                        name=str(name), choices=names)
            return names.index(name)

        def number(value, what: str) -> float:
            if not finite_number(value):
                raise StiffnessError(f"{where}: {what} must be a finite number, got {value!r}")
            return float(value)

        def terms(rule: dict, what: str) -> dict[int, float]:
            raw = rule.get("terms", {})
            if not isinstance(raw, dict):
                raise StiffnessError(f"{where}: {what}.terms must map joints to coefficients")
            out = {}
            for joint, c in raw.items():
                i = index(joint)
                # the coefficient relates SI values: q_out = c q_in in the table's units
                out[i] = number(c, f"{what}.terms.{joint}")
            return out

        ws = cls(declared=True)
        for joint, bounds in dict(table.get("uniform", {})).items():
            i = index(joint)
            if not isinstance(bounds, list) or len(bounds) != 2:
                raise StiffnessError(f"{where}: uniform.{joint} must be [low, high]")
            lo, hi = (number(v, f"uniform.{joint}") * factor[i] for v in bounds)
            if hi < lo:
                raise StiffnessError(f"{where}: uniform.{joint} has high below low")
            ws.uniform[i] = (lo, hi)
        for joint, values in dict(table.get("choice", {})).items():
            i = index(joint)
            if not isinstance(values, list) or not values:
                raise StiffnessError(f"{where}: choice.{joint} must be a list of values")
            ws.choice[i] = [number(v, f"choice.{joint}") * factor[i] for v in values]
        for k, rule in enumerate(table.get("linear", [])):
            if not isinstance(rule, dict) or "joint" not in rule:
                raise StiffnessError(f"{where}: linear[{k}] needs a joint")
            i = index(rule["joint"])
            c = terms(rule, f"linear[{k}]")
            scaled = {j: v * factor[i] / factor[j] for j, v in c.items()}
            ws.linear.append((i, number(rule.get("constant", 0.0), f"linear[{k}].constant")
                              * factor[i], scaled))
        for k, rule in enumerate(table.get("avoid", [])):
            if not isinstance(rule, dict) or "terms" not in rule or "margin" not in rule:
                raise StiffnessError(f"{where}: avoid[{k}] needs terms, values and margin")
            c = terms(rule, f"avoid[{k}]")
            ref = factor[next(iter(c))] if c else 1.0
            values = rule.get("values", [0.0])
            if not isinstance(values, list):
                raise StiffnessError(f"{where}: avoid[{k}].values must be a list")
            ws.avoid.append(({j: v * factor[j] / ref for j, v in c.items()},
                             [number(v, f"avoid[{k}].values") * ref for v in values],
                             number(rule["margin"], f"avoid[{k}].margin") * ref))
        above = table.get("target_above_base", True)
        if not isinstance(above, bool):
            raise StiffnessError(f"{where}: target_above_base must be true or false")
        ws.target_above_base = above
        return ws

    def spans(self) -> dict[int, tuple[float, float]]:
        """Coordinate index -> the range (SI) the rules give its poses: a ``uniform`` range,
        the span of a ``choice``'s values, a ``linear`` coordinate's range over its terms'
        (interval arithmetic; none when a term has no range: its joint limits then say, as
        for a coordinate without a rule)."""
        out = dict(self.uniform)
        out.update({i: (min(v), max(v)) for i, v in self.choice.items()})
        for i, constant, terms in self.linear:
            out.pop(i, None)
            if all(j in out for j in terms):
                ends = [(c * out[j][0], c * out[j][1]) for j, c in terms.items()]
                out[i] = (constant + sum(min(e) for e in ends),
                          constant + sum(max(e) for e in ends))
        return out

    def departures(self, robot: Robot, coords: np.ndarray) -> list[str]:
        """What puts the coordinates ``coords`` (rad, m) of ``robot`` outside the declared
        workspace, one phrase each (angles in deg): a coordinate beyond its :meth:`spans`
        (a revolute one by whole turns too: the same pose), an ``avoid`` combination within
        its margin of a value; empty inside, or without a declared workspace. Within
        :data:`WORKSPACE_TOLERANCE` counts as inside (``linear``'s constants are exact)."""
        if not self.declared:
            return []
        names = list(robot.coordinate_joints)
        turn = np.array([not robot.is_prismatic(j) for j in names])
        unit = np.where(turn, 180.0 / math.pi, 1.0)

        def shown(i: int, value: float, named: bool = True) -> str:
            return f"{value * unit[i]:.4g}" + (f" {'deg' if turn[i] else 'm'}" if named else "")

        out = []
        tol = WORKSPACE_TOLERANCE
        for i, (lo, hi) in sorted(self.spans().items()):
            value = float(coords[i])
            shift = (value - lo + tol) % (2.0 * math.pi) - tol if turn[i] else value - lo
            if not -tol <= shift <= hi - lo + tol:
                out.append(f"{names[i]} {shown(i, value)} outside [{shown(i, lo, False)}, "
                           f"{shown(i, hi)}]")
        for terms, combo, near, margin in self.avoided(coords, tol):
            i = next(iter(terms))
            text = " + ".join(names[j] if c == 1.0 else f"{c:g} {names[j]}"
                              for j, c in terms.items())
            out.append(f"{text} {shown(i, combo)} within {shown(i, margin)} of "
                       f"{shown(i, near)}")
        return out

    def avoided(self, coords: np.ndarray, tolerance: float = 0.0
                ) -> list[tuple[dict[int, float], float, float, float]]:
        """The ``avoid`` rules the coordinates ``coords`` (SI) break: each one's terms, their
        combination, its nearest avoided value and the margin, where the combination is within
        the margin less ``tolerance`` of that value."""
        out = []
        for terms, values, margin in self.avoid:
            combo = sum(c * float(coords[j]) for j, c in terms.items())
            near = min(values, key=lambda v: abs(combo - v))
            if abs(combo - near) < margin - tolerance:
                out.append((terms, combo, near, margin))
        return out

    def draw(self, lo: np.ndarray, hi: np.ndarray, rng: np.random.Generator
             ) -> np.ndarray | None:
        """One coordinate vector (SI), or ``None`` when an ``avoid`` rule rejects it."""
        if not self.declared:
            return rng.uniform(lo, hi)
        coords = np.zeros(len(lo))
        for i, (a, b) in self.uniform.items():
            coords[i] = rng.uniform(a, b)
        ruled = set(self.uniform) | set(self.choice) | {i for i, _, _ in self.linear}
        for i in range(len(lo)):
            if i not in ruled:
                coords[i] = rng.uniform(lo[i], hi[i])
        if self.avoided(coords):
            return None
        for i, values in self.choice.items():
            coords[i] = rng.choice(values)
        for i, constant, c in self.linear:
            coords[i] = constant + sum(v * coords[j] for j, v in c.items())
        return coords


#: A prismatic joint's range (m) beyond any real rail: a file's stand-in for 'no limit'
#: (Fetch's base_joint2 of the Robotics Toolbox: -999999..999999).
_NO_RAIL_M = 1e3


def coordinate_limits(robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper limits (rad, m) of the coordinates as poses are drawn.

    Revolute joints within +-pi; a joint without finite limits (a prismatic one's range over
    ``_NO_RAIL_M`` counts as none): +-pi, or 0..0.1 m if prismatic,
    that span centred on the reference pose's value (:func:`assembly_coordinates`) when the
    pose lies outside it (Gepetto's wl16 leg closes with its unbounded motors near -0.3 m).
    """
    model = robot.model
    prismatic = np.array([robot.is_prismatic(j) for j in robot.coordinate_joints], dtype=bool)
    if robot.coupling is not None:  # the chain's limits, as the controller's coordinates
        lo, hi = ik.coordinate_limits(robot)
    else:
        joints = [model.joints[model.getJointId(j)] for j in robot.coordinate_joints]
        lo = np.array([model.lowerPositionLimit[j.idx_q] for j in joints])
        hi = np.array([model.upperPositionLimit[j.idx_q] for j in joints])
    bad = ~np.isfinite(lo) | ~np.isfinite(hi) | (hi <= lo) | (prismatic & (hi - lo > _NO_RAIL_M))
    lo = np.where(bad, np.where(prismatic, 0.0, -math.pi), lo)
    hi = np.where(bad, np.where(prismatic, 0.1, math.pi), hi)
    if np.any(bad & prismatic):
        ref = assembly_coordinates(robot)
        moved = bad & prismatic & ((ref < lo) | (ref > hi))
        lo, hi = np.where(moved, ref - 0.05, lo), np.where(moved, ref + 0.05, hi)
    lo = np.where(prismatic, lo, np.maximum(lo, -math.pi))
    hi = np.where(prismatic, hi, np.minimum(hi, math.pi))
    return lo, hi


def sampling_box(robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    """Box (rad, m) the coordinates are drawn in when no workspace rule says otherwise: the
    limits (:func:`coordinate_limits`), narrowed around the reference assembly for loops."""
    return loop_sampling_box(robot, *coordinate_limits(robot))


def singular_values(robot: Robot, q: np.ndarray) -> np.ndarray:
    """Singular values of the target Jacobian over every coordinate joint, rows ``[v; L omega]``
    (``L`` the base-to-target distance, at least 0.1 m), m/rad; ``q`` closed.

    Raises
    ------
    StiffnessError
        If the loop is singular at ``q``.
    """
    full = ik.all_coordinates(robot)
    state = target_state(full, q)
    length = max(float(np.linalg.norm(state.position)), 0.1)
    jac = np.vstack([state.jacobian[:3], length * state.jacobian[3:]])
    return np.linalg.svd(jac, compute_uv=False)


def fold_ratio(robot: Robot, q: np.ndarray) -> float:
    """``sigma_min / sigma_max`` of the passive columns of the loop-closure Jacobian at ``q``
    (1 for a robot without loops; 0 on a fold)."""
    if robot.loop.is_open_chain or not len(robot.loop.passive_v):
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
    lo, hi = coordinate_limits(robot)
    set_lo, set_hi = ik.set_joint_limits(robot)  # a passive chain joint's too
    box = sampling_box(robot)
    rank = None
    fold_floor = 0.0
    if fold_margin > 0 and not robot.loop.is_open_chain:
        fold_floor = fold_margin * _reference_fold_ratio(robot)
    if singularity_margin > 0:
        probe = np.random.default_rng(int(rng.integers(2 ** 63)))
        rank, best_ratio = _generic_rank(robot, *box, rules, probe)
        singularity_floor = singularity_margin * best_ratio
    out: list[np.ndarray] = []
    below = assembled = 0  # poses that assembled, and those of them with the target below z = 0
    for attempt in range(max_tries * n):
        if len(out) == n or (not out and attempt >= _FIRST_POSE_TRIES + 10 * n):
            break
        coords = rules.draw(*box, rng)
        if coords is None:
            continue
        if np.any(coords < lo - 1e-12) or np.any(coords > hi + 1e-12):
            continue
        values = robot.joint_values(coords)[1]
        if np.any(values < set_lo - 1e-12) or np.any(values > set_hi + 1e-12):
            continue
        try:
            # a pose the continuation from the reference does not reach is refused (the
            # assembly search would close it past a fold, perhaps in another assembly mode)
            q = robot.assemble(coords, search=False).q
            state = target_state(robot, q)
            if np.abs(state.jacobian[:3]).max() > MAX_JACOBIAN:
                continue
            assembled += 1
            if rules.target_above_base and state.position[2] < 0.0:
                below += 1
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
        raise ConvergenceError(f"found only {len(out)} of {n} reachable poses of {robot.title}"
                               + (" away from singularities and folds" if singularity_margin > 0
                                  or fold_margin > 0 else "") + _shortfall_reason(below,
                                                                                assembled))
    if assembled >= 10 and below >= _MOSTLY_BELOW * assembled:
        warn_user(f"the target of {robot.title} was below the base plane (z < 0) in {below} of "
                  f"{assembled} poses that assembled, left out (the poses drawn are among the "
                  f"{assembled - below} others){_BELOW_FIX}", RobotFileWarning)
    return np.array(out)


#: Warn when at least this fraction of the poses that assembled put the target below the base
#: (a UR5 leaves out about half of its poses, Gepetto's 5-bar 97 %).
_MOSTLY_BELOW = 0.8
#: The fix for a robot whose target works below its base (said when most poses put it there).
_BELOW_FIX = (": if it works there (a leg, a hanging arm), declare [workspace] target_above_base "
              "= false in a robot.toml naming the URDF (urdf = \"<file>.urdf\", docs/design.md)")


def _shortfall_reason(below: int, assembled: int) -> str:
    """Why too few poses were found, and the fix: the target below the base plane in most
    poses that assembled (a leg, a hanging arm), else the joint limits."""
    if below > assembled / 2:
        return (f"; the target was below the base plane (z < 0) in {below} of {assembled} poses "
                f"that assembled{_BELOW_FIX}")
    return "; ask for fewer configurations, or check the joint limits"


def _reference_fold_ratio(robot: Robot) -> float:
    """:func:`fold_ratio` at the reference assembly (:func:`assembly_coordinates`: Gepetto's
    wl16 leg, whose zero pose does not close, was judged against an absolute 1 there and
    refused every pose, theirs about 0.003)."""
    try:
        q = robot.configuration(assembly_coordinates(robot))
    except StiffnessError:
        return 1.0  # no reference to compare with: an absolute margin
    return fold_ratio(robot, q)


def _generic_rank(robot: Robot, lo: np.ndarray, hi: np.ndarray, rules: Workspace,
                  rng: np.random.Generator) -> tuple[int, float]:
    """The largest Jacobian rank over a few assembled probe poses (the rank in general), and
    the best ``sigma_r / sigma_1`` among them."""
    svs: list[np.ndarray] = []
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
        raise ConvergenceError(f"no pose of {robot.title} drawn within its joint limits "
                               f"assembles (in {_FIRST_POSE_TRIES} draws); check the limits, or "
                               "declare a [workspace] in its robot.toml")
    rank = max(int(np.sum(sv > _RANK_RTOL * max(sv[0], 1e-300))) for sv in svs)
    return rank, max(float(sv[rank - 1] / sv[0]) if len(sv) >= rank else 0.0 for sv in svs)
