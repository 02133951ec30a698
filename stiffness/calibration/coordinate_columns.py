"""The coordinate columns of a campaign CSV, as rigs write them.

A campaign's rows carry the robot's coordinates either by position, ``q1..qn`` (every
coordinate, in the robot's coordinate order), or named after the robot's coordinate joints
(``arm_1_joint``), any subset in any order. A coordinate without a column is held at the value
``[robot] fixed = { joint = value }`` declares (in the campaign's angle unit, or its length unit
for a prismatic joint), else at the robot's reference configuration
(:func:`stiffness.mechanics.defaults.reference_configuration`); the readers say so once
(:class:`stiffness.errors.DataFileNote`). Columns no reader knows are ignored with one
:class:`stiffness.errors.UnknownColumnWarning` (the command line's ``--strict`` refuses them).
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np

from stiffness.errors import (
    DataFileNote,
    FileFormatError,
    UnknownColumnWarning,
    did_you_mean,
)
from stiffness.mechanics.defaults import reference_configuration
from stiffness.robot.robot import Robot
from stiffness.units import MAX_CELL, Units, finite_number

#: A positional coordinate column: ``q1``, ``q2``, ...
Q_COLUMN = re.compile(r"q(\d+)$")
#: Names listed in full in a note before it is summarised (``..., and 40 more``).
LISTED = 8


def listed(names: list[str] | tuple[str, ...], limit: int = LISTED) -> str:
    """``a, b, c`` or, past ``limit`` names, ``a, b, ... and N more``."""
    names = list(names)
    if len(names) <= limit:
        return ", ".join(names)
    return f"{', '.join(names[:limit])}, ... and {len(names) - limit} more"


def joints_text(robot: Robot) -> str:
    """The robot's coordinate joints, summarised, for messages."""
    return listed(robot.coordinate_joints)


def locate_coordinates(names: list[str], robot: Robot, data: Path, line: int
                       ) -> list[int | None]:
    """The header position (0-based) of each coordinate's column, ``None`` for a coordinate
    without one.

    Parameters
    ----------
    names
        The header's cells (stripped).

    Raises
    ------
    FileFormatError
        ``q`` columns out of order or not one per coordinate, ``q`` columns mixed with joint
        names, a joint named twice, or no coordinate column at all (line and column named).
    """
    n = robot.n_coordinates
    q_at = [i for i, c in enumerate(names) if Q_COLUMN.match(c)]
    by_name = [i for i, c in enumerate(names) if c in robot.coordinate_joints]

    def fail(col: int, text: str) -> FileFormatError:
        return FileFormatError(text, path=data, line=line, column=col + 1)

    if q_at and by_name:
        raise fail(by_name[0], f"got {names[by_name[0]]!r}, a joint name, beside q columns; "
                               f"name every coordinate column q1..q{n} or after its joint")
    if q_at:
        for k, i in enumerate(q_at):
            if names[i] != f"q{k + 1}":
                raise fail(i, f"got {names[i]!r}, expected 'q{k + 1}' (q columns are q1, q2, "
                              "... in order)")
        if len(q_at) != n:
            col = q_at[min(len(q_at), n)] if len(q_at) > n else q_at[-1] + 1
            raise fail(col, f"{robot.title} has {n} coordinates ({joints_text(robot)}) but the "
                            f"header has {len(q_at)} q columns; give q1..q{n} in that order, or "
                            "name the columns after the joints")
        return list(q_at)
    if not by_name:
        raise fail(1 if len(names) > 1 else 0,
                   f"no coordinate column: name the columns after {robot.title}'s joints "
                   f"({joints_text(robot)}; any subset, any order) or q1..q{n} in that order")
    index: list[int | None] = [None] * n
    for i in by_name:
        k = robot.coordinate_joints.index(names[i])
        if index[k] is not None:
            raise fail(i, f"joint {names[i]!r} has two columns; keep one")
        index[k] = i
    return index


def fixed_values(fixed: dict[str, float], robot: Robot, units: Units,
                 error, what: str = "[robot] fixed") -> dict[str, float]:
    """``[robot] fixed`` (file units) in SI (rad, m), each name a coordinate joint.

    ``error(problem)`` builds the exception naming the file and key; ``what`` names the
    input (``campaign import --fixed``).
    """
    out = {}
    for name, value in fixed.items():
        if name not in robot.coordinate_joints:
            raise error(f"{what} names {name!r}, not a coordinate joint of "
                        f"{robot.title}; {did_you_mean(name, robot.coordinate_joints)}")
        scale = units.length_to_si if robot.is_prismatic(name) else units.angle_to_si
        out[name] = float(value) * scale
    return out


def held_coordinates(robot: Robot, index: list[int | None], fixed_si: dict[str, float],
                     units: Units, data: Path, error, what: str = "[robot] fixed"
                     ) -> np.ndarray:
    """The value (rad, m) of each coordinate without a column (NaN where read); says once
    which are held and at what (:class:`DataFileNote`; ``what`` names the fixed values).

    Raises
    ------
    StiffnessError
        (through ``error``) a coordinate both read from a column and declared fixed.
    """
    held = np.full(robot.n_coordinates, np.nan)
    both = [robot.coordinate_joints[k] for k, i in enumerate(index)
            if i is not None and robot.coordinate_joints[k] in fixed_si]
    if both:
        raise error(f"{what} holds {', '.join(both)}, which {data.name} also reads; "
                    "drop the column or the fixed value")
    missing = [k for k, i in enumerate(index) if i is None]
    if not missing:
        return held
    reference = reference_configuration(robot)
    coords = np.zeros(robot.n_coordinates) if reference is None else reference.coords
    source = "zero" if reference is None else reference.source
    names = robot.coordinate_joints
    pinned, at_reference = [], []
    for k in missing:
        if names[k] in fixed_si:
            held[k] = fixed_si[names[k]]
            unit = units.length if robot.is_prismatic(names[k]) else units.angle
            scale = units.length_to_si if robot.is_prismatic(names[k]) else units.angle_to_si
            pinned.append(f"{names[k]} = {held[k] / scale:.6g} {unit}")
        else:
            held[k] = coords[k]
            at_reference.append(names[k])
    parts = []
    if pinned:
        parts.append(f"{', '.join(pinned)} ({what})")
    if at_reference:
        parts.append(f"{listed(at_reference)} at the reference configuration, the {source}")
    warnings.warn(f"{data}: {len(missing)} of {robot.n_coordinates} coordinates have no "
                  f"column and are held: {'; '.join(parts)}", DataFileNote, stacklevel=3)
    return held


def fill_held(q_read: np.ndarray, held_si: np.ndarray, robot: Robot, units: Units
              ) -> np.ndarray:
    """(n_rows, n_coordinates) coordinates in file units: the read ones (NaN columns where
    held) completed with the held values (SI) in the file's units."""
    prismatic = np.array([robot.is_prismatic(j) for j in robot.coordinate_joints], dtype=bool)
    scale = np.where(prismatic, units.length_to_si, units.angle_to_si)
    out = np.array(q_read, dtype=float)
    held = np.isfinite(held_si)
    out[:, held] = (held_si / scale)[held]
    return out


def warn_unknown(names: list[str], data: Path, what: str) -> None:
    """Say once that header columns ``names`` are ignored (``what``: the columns the file may
    have); :class:`UnknownColumnWarning`, an error under ``--strict``."""
    if names:
        # read as a warning (ignored) and, under --strict, as the error: says both
        shown = [n or "'' (an empty header cell: a trailing comma?)" for n in names]
        warnings.warn(f"{data}: column(s) {listed(shown)} are not campaign columns ({what}): "
                      "ignored, refused under --strict; remove or rename them",
                      UnknownColumnWarning, stacklevel=3)


def near_miss(unknown: list[str], wanted: str) -> str | None:
    """The unknown column that is likely a misspelt ``wanted`` (same letters but case), or
    ``None``."""
    return next((c for c in unknown if c.lower() == wanted.lower()), None)


def check_fixed_table(value, length: str, angle: str) -> str | None:
    """Why ``[robot] fixed`` is malformed (a table of finite numbers), or ``None``."""
    if not isinstance(value, dict) or not all(finite_number(v, MAX_CELL)
                                              for v in value.values()):
        return (f"[robot] fixed must be a table of joint = value, in {angle} (or {length} for "
                f"a prismatic joint), e.g. fixed = {{ head_1_joint = 0.0 }}; got {value!r}")
    return None

