"""Controller coordinates coupled to the chain: the ``[controller]`` section of a ``robot.toml``.

The controller reports its own coordinates ``u``; each chain joint is a linear expression of
them plus a constant, ``q_chain = A u + b`` (a parallelogram's ``j3 = "-J2 - J3"``, a flipped
axis ``j4 = "-J4"``, an offset ``j6 = "J6 + 90"``). The map is constant, and ``A`` has full column
rank: square, or tall when a linkage drives passive chain joints (a torso's last pitch joint
``t4 = "-T2 - T3"``: fewer coordinates than chain joints). Rates map as
``q_chain_dot = A u_dot``: the Jacobian in controller coordinates is ``J A`` and the load
Hessian ``A^T H A`` (docs/robot-files.md, "Controller coordinates").

Expressions are read with :mod:`ast` and only linear ones are accepted: numbers, coordinate
names, ``+``, ``-``, and ``*`` with a number on one side. Constants are in the chain joint's unit
(``angle_unit`` for a revolute joint, ``length_unit`` for a prismatic one).
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stiffness.errors import FileFormatError, did_you_mean
from stiffness.units import ANGLE_UNITS, LENGTH_UNITS

SPRINGS_ON = ("controller", "chain")
_SECTION_KEYS = ("coordinates", "chain", "springs_on", "angle_unit", "length_unit")
#: Condition number of A (ratio of its extreme singular values) beyond which the map counts
#: as losing coordinates.
_CONDITION_LIMIT = 1e10


@dataclass(frozen=True)
class CoordinateMap:
    """``q_chain = matrix @ u + offset`` (rad or m).

    Attributes
    ----------
    coordinates
        The controller's coordinate names (the robot's coordinates), order of ``u``.
    chain
        The chain joints (Pinocchio joints), order of the rows.
    matrix
        (n_chain, n) ``A``, of full column rank (n <= n_chain: square, or tall with passive
        chain joints).
    offset
        (n_chain,) ``b`` in rad or m.
    springs_on
        ``"controller"`` (the springs act on ``u``, the drives) or ``"chain"``.
    prismatic
        Per controller coordinate, whether it drives prismatic joints (a length, m) rather
        than revolute ones (an angle, rad).
    """

    coordinates: tuple[str, ...]
    chain: tuple[str, ...]
    matrix: np.ndarray
    offset: np.ndarray
    springs_on: str
    prismatic: tuple[bool, ...]

    def chain_values(self, coordinates: np.ndarray) -> np.ndarray:
        """Chain joint values (..., n_chain) of controller coordinates (..., n)."""
        return np.asarray(coordinates, dtype=float) @ self.matrix.T + self.offset

    def coordinates_of(self, chain_values: np.ndarray) -> np.ndarray:
        """Controller coordinates (..., n) of chain joint values (..., n_chain): exact on the
        map's range, the least-squares ones off it (a tall ``A``: chain values its passive
        joints do not follow)."""
        rhs = np.asarray(chain_values, dtype=float) - self.offset
        return np.linalg.lstsq(self.matrix, rhs.T, rcond=None)[0].T

    def limits(self, lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Limits (rad or m) of the coordinates from the chain joints' ``lower``, ``upper``:
        a coordinate that alone sets a chain joint (``j = c u + b``) takes that joint's range;
        the others are unbounded (+-inf)."""
        lo, hi = np.full(len(self.coordinates), -np.inf), np.full(len(self.coordinates), np.inf)
        for row, b, a, z in zip(self.matrix, self.offset, lower, upper, strict=True):
            used = np.flatnonzero(row)
            if used.shape[0] != 1 or not (np.isfinite(a) and np.isfinite(z)):
                continue
            i = int(used[0])
            ends = sorted(((a - b) / row[i], (z - b) / row[i]))
            lo[i], hi[i] = max(lo[i], ends[0]), min(hi[i], ends[1])
        return lo, hi

    def column(self, coordinate: str) -> np.ndarray:
        """Chain joint rates per unit rate of one controller coordinate (column of A)."""
        return self.matrix[:, self.coordinates.index(coordinate)]

    def sole_joint(self, coordinate: str) -> str | None:
        """The chain joint ``coordinate`` is one to one (``j = u + b``: it turns that joint
        alone, at rate 1, and nothing else turns it), or ``None``."""
        i = self.coordinates.index(coordinate)
        used = np.flatnonzero(self.matrix[:, i])
        if used.shape[0] != 1 or self.matrix[used[0], i] != 1.0:
            return None
        alone = np.flatnonzero(self.matrix[used[0]]).tolist() == [i]
        return self.chain[int(used[0])] if alone else None


def linear_terms(text: str, names: tuple[str, ...]) -> tuple[dict[str, float], float]:
    """Coefficients and constant of a linear expression of ``names``.

    Raises
    ------
    ValueError
        With what is wrong (not an expression, a name not in ``names``, a product of two
        names, an operator other than ``+ - *``); the caller says where.
    """
    try:
        tree = ast.parse(text, mode="eval")
    except SyntaxError as exc:
        raise ValueError(f"{text!r} is not an expression ({exc.msg})") from None
    coefficients, constant = _linear(tree.body, names)
    return {k: v for k, v in coefficients.items() if v != 0.0}, constant


def _linear(node: ast.AST, names: tuple[str, ...]) -> tuple[dict[str, float], float]:
    if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) \
            and not isinstance(node.value, bool):
        return {}, float(node.value)
    if isinstance(node, ast.Name):
        if node.id not in names:
            raise ValueError(f"{node.id!r} is not a controller coordinate; "
                             f"{did_you_mean(node.id, names)}")
        return {node.id: 1.0}, 0.0
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        terms, constant = _linear(node.operand, names)
        sign = -1.0 if isinstance(node.op, ast.USub) else 1.0
        return {k: sign * v for k, v in terms.items()}, sign * constant
    if isinstance(node, ast.BinOp) and isinstance(node.op, (ast.Add, ast.Sub)):
        left, c_left = _linear(node.left, names)
        right, c_right = _linear(node.right, names)
        sign = 1.0 if isinstance(node.op, ast.Add) else -1.0
        out = dict(left)
        for k, v in right.items():
            out[k] = out.get(k, 0.0) + sign * v
        return out, c_left + sign * c_right
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Mult):
        left, c_left = _linear(node.left, names)
        right, c_right = _linear(node.right, names)
        if left and right:
            raise ValueError("a product of two coordinates is not linear")
        terms, factor = (left, c_right) if left else (right, c_left)
        return {k: v * factor for k, v in terms.items()}, c_left * c_right
    raise ValueError(f"{ast.unparse(node)!r} is not allowed: an expression uses numbers, "
                     "coordinate names, +, - and * by a number")


def read_coordinate_map(section: object, path: str | Path, chain: dict[str, str],
                        units: dict[str, str]) -> CoordinateMap:
    """The ``[controller]`` section of the robot file ``path``.

    Parameters
    ----------
    chain
        Every chain joint with a degree of freedom (model order) -> ``"revolute"`` or
        ``"prismatic"``.
    units
        ``angle_unit`` and ``length_unit`` of the robot file's ``[dh]`` (the constants' units
        when ``[controller]`` declares none), possibly empty.

    Raises
    ------
    FileFormatError
        One line naming the file and the field: an unknown key, a joint without expression or
        an unknown one, an expression that is not linear or names an unknown coordinate, a map
        of the wrong size or singular.
    """
    path = Path(path)

    def fail(field: str, problem: str) -> FileFormatError:
        return FileFormatError(problem, path=path, field=f"[controller].{field}")

    if not isinstance(section, dict):
        raise fail("", "[controller] must be a table")
    extra = sorted(set(section) - set(_SECTION_KEYS))
    if extra:
        raise fail(extra[0], f"unknown key; [controller] has {', '.join(_SECTION_KEYS)}")
    names = section.get("coordinates")
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names) \
            or len(set(names)) != len(names):
        raise fail("coordinates", "must list the controller's coordinate names, each once")
    springs_on = section.get("springs_on", "controller")
    if springs_on not in SPRINGS_ON:
        raise fail("springs_on", f"{springs_on!r} is not one of {', '.join(SPRINGS_ON)}")
    expressions = section.get("chain")
    if not isinstance(expressions, dict):
        raise fail("chain", "must be a table { <chain joint> = \"<linear expression>\", ... }")
    for joint in expressions:
        if joint not in chain:
            raise fail(f"chain.{joint}", f"{joint!r} is not a joint of the chain; "
                       f"{did_you_mean(joint, list(chain))}")
    missing = [j for j in chain if j not in expressions]
    if missing:
        raise fail(f"chain.{missing[0]}", f"the chain joint {missing[0]!r} has no expression: "
                   "give every chain joint one")
    factors = _constant_factors(section, units, fail)
    matrix, offset = np.zeros((len(chain), len(names))), np.zeros(len(chain))
    for i, (joint, kind) in enumerate(chain.items()):
        text = expressions[joint]
        if not isinstance(text, str):
            raise fail(f"chain.{joint}", f"must be a string expression, got {text!r}")
        try:
            terms, constant = linear_terms(text, tuple(names))
        except ValueError as exc:
            raise fail(f"chain.{joint}", str(exc)) from None
        for name, value in terms.items():
            matrix[i, names.index(name)] = value
        if constant != 0.0 and kind not in factors:
            unit = "angle_unit" if kind == "revolute" else "length_unit"
            raise fail(f"chain.{joint}", f"a constant needs its unit: give {unit} in "
                       "[controller] (or [dh])")
        offset[i] = constant * factors.get(kind, 1.0)
    _check_rank(matrix, names, list(chain), fail)
    return CoordinateMap(tuple(names), tuple(chain), matrix, offset, springs_on,
                         _coordinate_kinds(matrix, names, list(chain.values()), fail))


def _coordinate_kinds(matrix: np.ndarray, names: list[str], kinds: list[str], fail
                      ) -> tuple[bool, ...]:
    """Whether each coordinate is a length; one that drives joints of both kinds is refused."""
    out = []
    for i, name in enumerate(names):
        driven = {kinds[j] for j in np.flatnonzero(matrix[:, i])}
        if len(driven) > 1:
            raise fail("chain", f"the coordinate {name!r} drives both revolute and prismatic "
                       "joints: an angle and a length cannot share a coordinate")
        out.append(driven == {"prismatic"})
    return tuple(out)


def _constant_factors(section: dict, units: dict[str, str], fail) -> dict[str, float]:
    """Factor to SI of a constant per chain-joint kind, from the declared units."""
    factors = {}
    for key, table, kind in (("angle_unit", ANGLE_UNITS, "revolute"),
                             ("length_unit", LENGTH_UNITS, "prismatic")):
        unit = section.get(key, units.get(key))
        if unit is None:
            continue
        if unit not in table:
            raise fail(key, f"{unit!r} is not one of {', '.join(table)}")
        factors[kind] = table[unit]
    return factors


def _check_rank(matrix: np.ndarray, names: list[str], chain: list[str], fail) -> None:
    """Refuse a map without full column rank, naming the coordinates the chain loses."""
    sv = np.linalg.svd(matrix, compute_uv=False)
    if len(names) <= len(chain) and sv[-1] > 0 and sv[0] / sv[-1] <= _CONDITION_LIMIT:
        return
    _, s, vt = np.linalg.svd(matrix)
    s = np.concatenate([s, np.zeros(len(names) - s.shape[0])])
    null = vt[s <= s[0] / _CONDITION_LIMIT]
    lost = [n for i, n in enumerate(names) if np.abs(null[:, i]).max() > 1e-6]
    combination = _combination(null[0], names)
    raise fail("chain", f"the chain joints ({', '.join(chain)}) do not determine the "
               f"coordinates {', '.join(map(repr, lost))}: A of q_chain = A u + b has rank "
               f"{len(names) - null.shape[0]} for {len(names)} coordinates ({combination} moves "
               "no chain joint); each coordinate needs a chain joint that it moves apart from "
               "the others")


def _combination(vector: np.ndarray, names: list[str]) -> str:
    """A direction of the coordinates as text, largest weight 1 and the first term positive:
    ``J2 - J3``, ``J1 + 0.5 J4``."""
    vector = vector / vector[np.flatnonzero(np.abs(vector) > 1e-6)[0]]
    vector = vector / np.abs(vector).max()
    terms = []
    for c, name in zip(vector, names, strict=True):
        if abs(c) <= 1e-6:
            continue
        size = "" if abs(abs(c) - 1.0) < 1e-9 else f"{abs(c):.3g} "
        terms.append(("- " if c < 0 else "+ ") + size + name)
    return " ".join(terms).removeprefix("+ ")
