"""The measurement CSV of a campaign (and of a plan): its header, the units comment, the rows
read into SI (coordinates, forces, moments, deflections, rotations) with their warnings
(coordinates beyond the joint limits, one label at different coordinates).
"""


from __future__ import annotations

import csv
import math
import re
import warnings
from pathlib import Path

import numpy as np

from stiffness.errors import (
    DataFileWarning,
    FileFormatError,
    StiffnessError,
)
from stiffness.files import (
    read_text,
)
from stiffness.mechanics.ik import coordinate_limits
from stiffness.robot.robot import Robot
from stiffness.units import Units

FORCE_COLUMNS = ("fx", "fy", "fz")
DEFLECTION_COLUMNS = ("dx", "dy", "dz")
MOMENT_COLUMNS = ("mx", "my", "mz")
ROTATION_COLUMNS = ("rx", "ry", "rz")


def expected_header(n_q: int) -> list[str]:
    return ["config", *(f"q{i}" for i in range(1, n_q + 1)), *FORCE_COLUMNS,
            *DEFLECTION_COLUMNS]


def _parse_header(cells: list[str], data: Path, line: int, n_q: int | None,
                  robot_text: str = "the robot", joints: tuple[str, ...] = ()
                  ) -> tuple[int, bool, bool]:
    """Check a CSV header; return (number of q columns, has moment, has rotation)."""
    optional = "optional columns after dz: mx,my,mz (moment) then rx,ry,rz (rotation)"

    def fail(col: int, text: str) -> FileFormatError:
        return FileFormatError(text, path=data, line=line, column=col)

    if not cells or cells[0] != "config":
        got = repr(cells[0]) if cells else "nothing"
        raise fail(1, f"the first column must be 'config', got {got}; the header is "
                      f"config,q1,...,qn,fx,fy,fz,dx,dy,dz")
    k = 0
    while 1 + k < len(cells) and cells[1 + k].startswith("q") and cells[1 + k][1:].isdigit():
        if cells[1 + k] != f"q{k + 1}":
            raise fail(2 + k, f"got {cells[1 + k]!r}, expected 'q{k + 1}' "
                              "(q columns are q1, q2, ... in order)")
        k += 1
    if n_q is not None and k != n_q:
        named = cells[1 + k] if 1 + k < len(cells) else None
        if named in joints:
            raise fail(2 + k, f"got {named!r}, a joint name: coordinate columns are named by "
                              f"position, q1..q{n_q}, in the order of {robot_text}")
        raise fail(2 + min(k, n_q), f"{robot_text} has {n_q} coordinates but the header has {k} "
                                    f"q columns; give q1..q{n_q} in that order")
    if k == 0:
        raise fail(2, f"got {cells[1]!r} where q1 was expected" if len(cells) > 1 else
                   "column q1 is missing")
    expected = expected_header(k)
    for col, name in enumerate(expected, start=1):
        if col > len(cells):
            raise fail(col, f"column {name!r} is missing; the header must be "
                            f"{','.join(expected)}")
        if cells[col - 1] != name:
            raise fail(col, f"got {cells[col - 1]!r}, expected {name!r}; the header must be "
                            f"{','.join(expected)} (optionally then mx,my,mz and rx,ry,rz)")
    rest = cells[len(expected):]
    groups = {MOMENT_COLUMNS: "moment", ROTATION_COLUMNS: "rotation"}
    found = {"moment": False, "rotation": False}
    col = len(expected) + 1
    allowed = [MOMENT_COLUMNS, ROTATION_COLUMNS]
    while rest:
        group = next((g for g in allowed if rest[0] == g[0]), None)
        if group is None:
            valid = [c for g in allowed for c in g[:1]]
            hint = f"expected {' or '.join(repr(v) for v in valid)}; " if valid else ""
            raise fail(col, f"column {rest[0]!r} is not a campaign column; {hint}{optional}")
        for j, name in enumerate(group):
            if j >= len(rest):
                raise fail(col + j, f"column {name!r} is missing ({groups[group]} columns come "
                                    f"as {','.join(group)})")
            if rest[j] != name:
                raise fail(col + j, f"got {rest[j]!r}, expected {name!r} "
                                    f"({groups[group]} columns come as {','.join(group)})")
        found[groups[group]] = True
        allowed = allowed[allowed.index(group) + 1:]
        rest = rest[3:]
        col += 3
    return k, found["moment"], found["rotation"]


#: ``units:`` / ``units=`` in a comment: what follows declares the units.
_UNITS_WORD = re.compile(r"\bunits?\s*[:=]", re.IGNORECASE)
#: A comment made only of ``key = value`` pairs (``# angle = rad, force = kN, length = m``).
_ONLY_PAIRS = re.compile(r"^\s*(?:[A-Za-z_]+\s*=\s*[^\s,;=]+[\s,;]*)+$")
#: One ``key = value`` pair of a units comment (separated by spaces, commas or semicolons).
_UNITS_PAIR = re.compile(r"([A-Za-z_]+)\s*=\s*([^\s,;]+)")
_UNITS_KEYS = ("angle", "force", "length")
UNITS_COMMENT_EXAMPLE = "# units: angle=deg force=N length=mm"


def read_units_comment(comment: str, path: Path, line: int) -> Units | None:
    """The units a CSV comment declares, or ``None`` for a comment that declares none.

    Raises
    ------
    FileFormatError
        A comment that mentions units but does not name each of angle, force and length once
        with a known unit (file and line named, the expected form given).
    """
    body = comment.lstrip("#")
    if _UNITS_WORD.search(body):
        text = _UNITS_WORD.split(body, maxsplit=1)[-1]
    elif _ONLY_PAIRS.match(body) and any(
            key.lower() in _UNITS_KEYS for key, _ in _UNITS_PAIR.findall(body)):
        text = body
    else:  # prose ("# force = 100 N along z", "# max force=100"): not a declaration
        return None
    pairs: dict[str, str] = {}
    for key, value in _UNITS_PAIR.findall(text):
        key = key.lower()
        if key not in _UNITS_KEYS:
            raise FileFormatError(f"the units comment names {key!r}; it names "
                                  f"{', '.join(_UNITS_KEYS)}, as in '{UNITS_COMMENT_EXAMPLE}'",
                                  path=path, line=line)
        if key in pairs:
            raise FileFormatError(f"the units comment names {key} twice; name each of "
                                  f"{', '.join(_UNITS_KEYS)} once, as in '{UNITS_COMMENT_EXAMPLE}'",
                                  path=path, line=line)
        pairs[key] = value
    missing = [k for k in _UNITS_KEYS if k not in pairs]
    if missing:
        raise FileFormatError(f"the units comment does not give {' or '.join(missing)}; write "
                              f"it as '{UNITS_COMMENT_EXAMPLE}' with your units", path=path,
                              line=line)
    try:
        return Units(pairs["angle"], pairs["force"], pairs["length"])
    except StiffnessError as exc:
        raise FileFormatError(str(exc), path=path, line=line) from exc


def check_units_comment(declared: Units, expected: Units, source: object, path: Path,
                        line: int) -> None:
    """Refuse a units comment that disagrees with the units declared elsewhere.

    Raises
    ------
    FileFormatError
        The comment's angle, force or length unit differs from ``expected`` (declared by
        ``source``: a ``campaign.toml`` or an earlier comment).
    """
    said = f"angle={declared.angle} force={declared.force} length={declared.length}"
    known = f"angle={expected.angle} force={expected.force} length={expected.length}"
    if said != known:
        raise FileFormatError(f"the units comment says {said} but {source} says {known}; make "
                              "them agree", path=path, line=line)


#: Largest magnitude of a CSV cell, in the file's units: far beyond any measurement in any
#: supported unit (1e12 um is 1e6 m), and small enough that products of squares stay finite.
MAX_CELL = 1e12


def parse_number(cell: str, data: Path, line: int, col: int, name: str) -> float:
    text = cell.strip()
    try:
        value = float(text)
    except ValueError:
        value = None
    if value is None or not math.isfinite(value):
        shown = repr(cell) if text else "an empty cell"
        raise FileFormatError(
            f"{shown} is not a finite number; every q, force, moment, deflection and rotation "
            "cell must be a number", path=data, line=line, column=col, field=name)
    if abs(value) > MAX_CELL:
        raise FileFormatError(
            f"{text} is beyond +-{MAX_CELL:.0e}, larger than any coordinate, force or "
            "deflection a rig measures (and too large for the fit's arithmetic); fix the cell "
            "or its unit", path=data, line=line, column=col, field=name)
    return value


def read_rows(data: Path, n_q: int | None, robot_text: str, units: Units, toml_path: Path,
               joints: tuple[str, ...] = ()):
    text = read_text(data, "measurement file ([measurement] data)")
    header = None
    rows: list[tuple[int, list[str]]] = []
    for number, raw in enumerate(text.splitlines(), start=1):
        if not raw.strip():
            continue
        if raw.lstrip().startswith("#"):
            declared = read_units_comment(raw.strip(), data, number)
            if declared is not None:
                check_units_comment(declared, units, toml_path, data, number)
            continue
        cells = next(csv.reader([raw]))
        if header is None:
            header = [c.strip() for c in cells]
            header_line = number
            continue
        rows.append((number, cells))
    if header is None:
        raise FileFormatError("the file is empty; it needs a header "
                              "config,q1,...,qn,fx,fy,fz,dx,dy,dz and measurement rows",
                              path=data, line=1)
    k, has_moment, has_rotation = _parse_header(header, data, header_line, n_q, robot_text,
                                                joints)
    if not rows:
        raise FileFormatError("no measurement rows after the header; add one row per loaded "
                              "measurement", path=data, line=header_line + 1)
    width = len(header)
    labels, values, lines = [], [], []
    for number, cells in rows:
        if len(cells) != width:
            col = min(len(cells), width) + 1
            name = header[col - 1] if col <= width else f"extra cell {cells[width]!r}"
            raise FileFormatError(
                f"the row has {len(cells)} cells but the header has {width}", path=data,
                line=number, column=col, field=name)
        label = cells[0].strip()
        if not label:
            raise FileFormatError("the configuration label is empty; give a label such as A",
                                  path=data, line=number, column=1, field="config")
        labels.append(label)
        values.append([parse_number(c, data, number, j, header[j - 1])
                       for j, c in enumerate(cells[1:], start=2)])
        lines.append(number)
    return k, has_moment, has_rotation, labels, np.array(values, dtype=float), lines


def prismatic_mask(robot: Robot) -> np.ndarray:
    return np.array([robot.is_prismatic(j) for j in robot.coordinate_joints], dtype=bool)


def _coordinate_unit(robot: Robot, units: Units, index: int) -> tuple[float, str]:
    """Factor to SI and name of the file unit of coordinate ``index`` (length unit for a
    prismatic joint, angle unit otherwise)."""
    if prismatic_mask(robot)[index]:
        return units.length_to_si, units.length
    return units.angle_to_si, units.angle


def coordinates_in_si(robot: Robot, q_file: np.ndarray, units: Units, labels: list[str],
                      lines: list[int] | tuple[int, ...], data: Path) -> np.ndarray:
    """The coordinates of a campaign's or plan's rows in SI (rad, m), from the file's units.

    Parameters
    ----------
    q_file
        (n_rows, n_q) coordinates as written: angles in the angle unit, prismatic joints in
        the length unit.
    labels, lines
        Each row's configuration label and file line (named in the warnings).

    Warns
    -----
    DataFileWarning
        Rows beyond the joint limits, or one label on rows at different coordinates (once
        each, naming the first row).
    """
    q = np.array(q_file, dtype=float)
    prismatic = prismatic_mask(robot)
    q[:, ~prismatic] *= units.angle_to_si
    q[:, prismatic] *= units.length_to_si
    _warn_beyond_limits(robot, q, lines, data, units)
    _warn_shared_labels(robot, labels, q, lines, data, units)
    return q


def _warn_beyond_limits(robot: Robot, q: np.ndarray, lines: list[int] | tuple[int, ...],
                       data: Path, units: Units) -> None:
    """Warn once when rows hold coordinates beyond the robot's joint limits.

    A rig reads its joints within their limits, so such rows usually mean a wrong angle or
    length unit (degrees read as radians) or the wrong robot. They are still read.

    Parameters
    ----------
    q
        Coordinates (n_rows, n_q), rad or m.
    lines
        The file line of each row.
    """
    lo, hi = coordinate_limits(robot)
    slack = 1e-9 * (1.0 + np.abs(q))
    beyond = (q < lo - slack) | (q > hi + slack)
    rows = np.flatnonzero(beyond.any(axis=1))
    if not rows.size:
        return
    i, j = rows[0], int(np.flatnonzero(beyond[rows[0]])[0])
    scale, unit = _coordinate_unit(robot, units, j)
    warnings.warn(
        f"{data}: {rows.size} of {len(q)} rows have coordinates beyond {robot.name}'s joint "
        f"limits (first: line {lines[i]}, q{j + 1} = {q[i, j] / scale:.6g} {unit}, limits "
        f"[{lo[j] / scale:.6g}, {hi[j] / scale:.6g}] {unit}); check the angle and length "
        "units and the robot", DataFileWarning, stacklevel=4)


def _warn_shared_labels(robot: Robot, labels: list[str], q: np.ndarray,
                       lines: list[int] | tuple[int, ...], data: Path, units: Units) -> None:
    """Warn once when one configuration label names rows at different coordinates.

    Rows with one label are one configuration (its loads and repeats): diagnose's
    cross-validation holds them out together and the replicates' scatter pools them. A label
    reused for another pose (a copied row not relabelled) mixes two configurations.

    Parameters
    ----------
    q
        Coordinates (n_rows, n_q), rad or m; rows of one configuration agree to 1e-6 rad / m
        (an encoder's repeatability is far finer than the poses' spacing).
    """
    first: dict[str, int] = {}
    mixed = []
    for i, label in enumerate(labels):
        j = first.setdefault(label, i)
        if j != i and np.max(np.abs(q[i] - q[j])) > 1e-6:
            mixed.append((label, j, i))
    if not mixed:
        return
    label, j, i = mixed[0]
    k = int(np.argmax(np.abs(q[i] - q[j])))
    scale, unit = _coordinate_unit(robot, units, k)
    names = sorted({m[0] for m in mixed})
    warnings.warn(
        f"{data}: {len(names)} configuration label(s) name rows at different coordinates "
        f"({', '.join(names[:5])}{', ...' if len(names) > 5 else ''}; first: {label!r} on lines "
        f"{lines[j]} and {lines[i]}, q{k + 1} {q[j, k] / scale:.6g} vs {q[i, k] / scale:.6g} "
        f"{unit}); rows of one label are one configuration, so give each pose its own label",
        DataFileWarning, stacklevel=4)
