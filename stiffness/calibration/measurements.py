"""The measurement CSV of a campaign (and of a plan): its header, the units comment, the rows
read into SI (coordinates, forces, moments, deflections, rotations) with their warnings
(coordinates beyond the joint limits, one label at different coordinates).
"""


from __future__ import annotations

import math
import re
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stiffness.calibration.coordinate_columns import (
    DECIMAL_COMMA,
    Q_COLUMN,
    canonical_header,
    fill_held,
    first_column_problem,
    held_coordinates,
    is_blank_row,
    is_units_row,
    locate_coordinates,
    near_miss,
    trim_empty_columns,
    warn_commented_rows,
    warn_unknown,
)
from stiffness.errors import (
    DataFileWarning,
    FileFormatError,
    StiffnessError,
)
from stiffness.files import check_csv_header, csv_cells, csv_float, read_text
from stiffness.mechanics.ik import coordinate_limits
from stiffness.robot.robot import Robot
from stiffness.units import MAX_CELL, NumberSpellingError, Units

FORCE_COLUMNS = ("fx", "fy", "fz")
DEFLECTION_COLUMNS = ("dx", "dy", "dz")
MOMENT_COLUMNS = ("mx", "my", "mz")
ROTATION_COLUMNS = ("rx", "ry", "rz")
#: The first line of a measurement plan's CSV (``stiffness design``) starts with it.
PLAN_COMMENT = "# measurement plan"


def expected_header(n_q: int) -> list[str]:
    return ["config", *(f"q{i}" for i in range(1, n_q + 1)), *FORCE_COLUMNS,
            *DEFLECTION_COLUMNS]


@dataclass(frozen=True)
class Header:
    """Where a deflection campaign's columns are (0-based header positions).

    Attributes
    ----------
    coordinates
        Each coordinate's column, ``None`` for one held (:mod:`coordinate_columns`).
    force, deflection
        The ``fx,fy,fz`` and ``dx,dy,dz`` columns.
    moment, rotation
        The ``mx,my,mz`` and ``rx,ry,rz`` columns, or ``None``.
    """

    coordinates: list[int | None]
    force: list[int]
    deflection: list[int]
    moment: list[int] | None
    rotation: list[int] | None


#: A column name with a unit in brackets: ``dx [mm]``, ``q1 (deg)``.
_WITH_UNIT = re.compile(r"^(.*?)\s*[\[(]\s*[^\[\]()\s]+\s*[\])]$")

_HEADER_HELP = ("the header is config, the coordinates (q1..qn, or columns named after the "
                "joints), fx,fy,fz,dx,dy,dz, optionally mx,my,mz and rx,ry,rz")


def known_columns(robot: Robot) -> list[str]:
    """Every column a deflection campaign of ``robot`` may have (the q columns aside), as
    :func:`coordinate_columns.canonical_header` spells them."""
    return ["config", *robot.coordinate_joints, *FORCE_COLUMNS, *DEFLECTION_COLUMNS,
            *MOMENT_COLUMNS, *ROTATION_COLUMNS]


def _parse_header(cells: list[str], data: Path, line: int, robot: Robot) -> Header:
    """Find the columns of a CSV header (any order but ``config`` first); columns no campaign
    has are ignored with a warning (:func:`coordinate_columns.warn_unknown`).

    Raises
    ------
    FileFormatError
        No ``config`` first, coordinate columns that do not fit the robot, a required column
        missing (or misspelt only in case), a group given in part, a column given twice.
    """
    def fail(col: int, text: str) -> FileFormatError:
        return FileFormatError(text, path=data, line=line, column=col)

    if not cells or cells[0] != "config":
        raise fail(1, f"the first column must be 'config', {first_column_problem(cells)}; "
                      f"{_HEADER_HELP}")
    campaign = (*FORCE_COLUMNS, *DEFLECTION_COLUMNS, *MOMENT_COLUMNS, *ROTATION_COLUMNS)
    for i, cell in enumerate(cells):
        match = _WITH_UNIT.match(cell)
        if match and (match.group(1) in campaign or match.group(1) in robot.coordinate_joints
                      or Q_COLUMN.match(match.group(1))):
            raise fail(i + 1, f"got {cell!r}: a campaign's columns carry no unit (the "
                              f"[units] of its campaign.toml give them); name it "
                              f"{match.group(1)!r}, or read the rig's file with `stiffness "
                              "campaign import`, which reads units in headers")
    coordinates = locate_coordinates(cells, robot, data, line)
    for name in campaign:
        if cells.count(name) > 1:
            raise fail(len(cells) - cells[::-1].index(name), f"column {name!r} appears twice; "
                                                              "keep one")
    taken = {0, *(i for i in coordinates if i is not None)}
    unknown = [c for i, c in enumerate(cells) if i not in taken and c not in campaign]

    def group(names: tuple[str, ...], required: bool, what: str) -> list[int] | None:
        present = [n for n in names if n in cells]
        if not present and not required:
            return None
        for name in names:
            if name in cells:
                continue
            typo = near_miss(unknown, name)
            if typo is not None:
                raise fail(cells.index(typo) + 1, f"got {typo!r}, expected {name!r}; "
                                                  f"{_HEADER_HELP}")
            after = max((cells.index(n) for n in present), default=len(cells) - 1) + 2
            raise fail(min(after, len(cells) + 1), f"column {name!r} is missing ({what}); "
                                                   f"{_HEADER_HELP}")
        return [cells.index(n) for n in names]

    force = group(FORCE_COLUMNS, True, "the applied force fx,fy,fz")
    deflection = group(DEFLECTION_COLUMNS, True, "the measured deflection dx,dy,dz")
    moment = group(MOMENT_COLUMNS, False, "moment columns come as mx,my,mz")
    rotation = group(ROTATION_COLUMNS, False, "rotation columns come as rx,ry,rz")
    assert force is not None and deflection is not None  # required groups
    warn_unknown(unknown, data, "a deflection campaign has config, the coordinates, "
                 "fx..dz, mx..mz and rx..rz")
    return Header(coordinates, force, deflection, moment, rotation)


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


def parse_number(cell: str, data: Path, line: int, col: int, name: str) -> float:
    text = cell.strip()
    try:
        value = csv_float(text)
    except ValueError as exc:
        if isinstance(exc, NumberSpellingError):  # 1_000: float() would read 1000
            raise FileFormatError(str(exc), path=data, line=line, column=col, field=name
                                  ) from None
        value = None
    if value is None or not math.isfinite(value):
        shown = repr(cell) if text else "an empty cell"
        fix = (f"write it with a decimal point, {text.replace(',', '.')}"
               if DECIMAL_COMMA.fullmatch(text) else "every q, force, moment, deflection and "
               "rotation cell must be a number")
        raise FileFormatError(f"{shown} is not a finite number; {fix}", path=data, line=line,
                              column=col, field=name)
    if abs(value) > MAX_CELL:
        raise FileFormatError(
            f"{text} is beyond +-{MAX_CELL:.0e}, larger than any coordinate, force or "
            "deflection a rig measures (and too large for the fit's arithmetic); fix the cell "
            "or its unit", path=data, line=line, column=col, field=name)
    return value


@dataclass
class Rows:
    """A deflection campaign's rows in the file's units.

    Attributes
    ----------
    labels, lines
        Each row's configuration label and file line.
    q
        (n, n_coordinates) coordinates, the held ones filled in.
    force, deflection
        (n, 3) each.
    moment, rotation
        (n, 3) each, or ``None`` without their columns.
    """

    labels: list[str]
    lines: list[int]
    q: np.ndarray
    force: np.ndarray
    deflection: np.ndarray
    moment: np.ndarray | None
    rotation: np.ndarray | None


def read_rows(data: Path, robot: Robot, units: Units, toml_path: Path,
              fixed_si: dict[str, float], error: Callable[[str], StiffnessError]) -> Rows:
    """The rows of a deflection campaign's CSV (file units; coordinates without a column
    held at ``fixed_si`` (rad, m) or the robot's reference, ``error`` building the refusal of
    a fixed joint that also has a column)."""
    text = read_text(data, "measurement file ([measurement] data)")
    header = None
    rows: list[tuple[int, list[str]]] = []
    comments: list[tuple[int, str]] = []
    for number, raw in enumerate(text.splitlines(), start=1):
        if not raw.strip():
            continue
        if raw.lstrip().startswith("#"):
            declared = read_units_comment(raw.strip(), data, number)
            if declared is not None:
                check_units_comment(declared, units, toml_path, data, number)
            elif header is not None:
                comments.append((number, raw))
            continue
        cells = csv_cells(raw, data, number)
        if is_blank_row(cells):  # ',,,,': a spreadsheet's empty row
            continue
        if header is None:
            header = canonical_header(cells, known_columns(robot))
            header_line = number
            check_csv_header(header, data, number)
            if text.startswith(PLAN_COMMENT) and not set(DEFLECTION_COLUMNS) & set(header):
                raise FileFormatError(
                    "a measurement plan (stiffness design wrote it), not measurements: it has "
                    "no dx,dy,dz; measure its rows and add them, or simulate it (stiffness "
                    "simulate --plan)", path=data, line=1)
            continue
        rows.append((number, cells))
    if header is None:
        raise FileFormatError("the file is empty; it needs a header "
                              "config,q1,...,qn,fx,fy,fz,dx,dy,dz and measurement rows",
                              path=data, line=1)
    header, cells_of = trim_empty_columns(header, [cells for _, cells in rows])
    rows = [(number, cells) for (number, _), cells in zip(rows, cells_of, strict=True)]
    warn_commented_rows(comments, len(header), data)
    where = _parse_header(header, data, header_line, robot)
    if not rows:
        raise FileFormatError("no measurement rows after the header; add one row per loaded "
                              "measurement", path=data, line=header_line + 1)
    if is_units_row(rows[0][1]):
        raise FileFormatError(
            f"a units row ({', '.join(c.strip() for c in rows[0][1] if c.strip())}), not "
            "measurements: a campaign's CSV holds numbers, its units are campaign.toml's "
            "[units]; delete the row (or make it a comment such as "
            f"'{UNITS_COMMENT_EXAMPLE}'), or read the rig's file with `stiffness campaign "
            "import`, which reads a units row", path=data, line=rows[0][0])
    width = len(header)
    read = [i for i in where.coordinates if i is not None]
    columns = [*read, *where.force, *where.deflection, *(where.moment or []),
               *(where.rotation or [])]
    labels, values, lines = [], [], []
    for number, cells in rows:
        if len(cells) != width:
            col = min(len(cells), width) + 1
            name = header[col - 1] if col <= width else f"extra cell {cells[width]!r}"
            hint = ("; if a number has a decimal comma (1,5), it made two cells: write 1.5"
                    if len(cells) > width else "")
            raise FileFormatError(
                f"the row has {len(cells)} cells but the header has {width}{hint}", path=data,
                line=number, column=col, field=name)
        label = cells[0].strip()
        if not label:
            raise FileFormatError("the configuration label is empty; give a label such as A",
                                  path=data, line=number, column=1, field="config")
        labels.append(label)
        values.append([parse_number(cells[j], data, number, j + 1, header[j])
                       for j in columns])
        lines.append(number)
    table = np.array(values, dtype=float)
    held = held_coordinates(robot, where.coordinates, fixed_si, units, data, error)
    q = np.full((len(rows), robot.n_coordinates), np.nan)
    q[:, [k for k, i in enumerate(where.coordinates) if i is not None]] = table[:, :len(read)]
    col = len(read)
    blocks = []
    for group in (where.force, where.deflection, where.moment, where.rotation):
        blocks.append(None if group is None else table[:, col: col + 3])
        col += 0 if group is None else 3
    force, deflection, moment, rotation = blocks
    assert force is not None and deflection is not None
    return Rows(labels, lines, fill_held(q, held, robot, units), force, deflection, moment,
                rotation)


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


#: Largest excess past a joint limit, as a fraction of the joint's range, read as a reading at
#: its end stop (FIGAROH's TIAGo: the torso lift 0.184 mm past 0.35 m) rather than a unit.
END_STOP = 0.01

#: Lines named when fewer than half of the rows are beyond the limits (FIGAROH's TIAGo: 1 of
#: 22 rows, read as "the angles look like degrees").
MINORITY_LINES = 5


def _warn_beyond_limits(robot: Robot, q: np.ndarray, lines: list[int] | tuple[int, ...],
                       data: Path, units: Units) -> None:
    """Warn once when rows hold coordinates beyond the robot's joint limits.

    A rig reads its joints within their limits, so such rows usually mean a wrong angle or
    length unit (degrees read as radians) or the wrong robot; fewer than half of the rows, the
    others within the limits, a row misread or mistyped (its lines named). They are still
    read.

    Parameters
    ----------
    q
        Coordinates (n_rows, n_q), rad or m.
    lines
        The file line of each row.
    """
    lo, hi = coordinate_limits(robot)

    def outside(values: np.ndarray) -> np.ndarray:
        slack = 1e-9 * (1.0 + np.abs(values))
        return (values < lo - slack) | (values > hi + slack)

    beyond = outside(q)
    rows = np.flatnonzero(beyond.any(axis=1))
    if not rows.size:
        return
    i, j = rows[0], int(np.flatnonzero(beyond[rows[0]])[0])
    scale, unit = _coordinate_unit(robot, units, j)
    hint = "check the angle and length units and the robot"
    revolute = ~prismatic_mask(robot)
    as_degrees = q.copy()
    as_degrees[:, revolute] = np.deg2rad(q[:, revolute])
    if 2 * rows.size < len(q):  # most rows within: a row read or typed wrong, not a unit
        lines_beyond = [str(lines[r]) for r in rows[:MINORITY_LINES]]
        more = f" and {rows.size - MINORITY_LINES} more" if rows.size > MINORITY_LINES else ""
        hint = (f"the other {len(q) - rows.size} rows are within them: a misread or mistyped "
                f"value on line{'s' if rows.size > 1 else ''} {', '.join(lines_beyond)}{more} "
                f"rather than a unit; check {'those rows' if rows.size > 1 else 'that row'}")
    elif units.angle == "rad" and revolute[beyond.any(axis=0)].all() \
            and not outside(as_degrees).any():
        hint = 'the angles look like degrees: [units] angle = "deg" (or --units angle=deg)'
    past = np.where(beyond, np.maximum(lo - q, q - hi), 0.0)
    spans = np.where(np.isfinite(hi - lo), hi - lo, np.inf)
    if (past <= END_STOP * spans).all():  # not a unit: a hair past
        k = int(np.unravel_index(np.argmax(past / spans), past.shape)[1])
        s, u = _coordinate_unit(robot, units, k)
        hint = (f"at most {past[:, k].max() / s:.3g} {u} past, {100 * END_STOP:.0f} % of the "
                "range or less: readings at the end stops, the units look right")
    warnings.warn(
        f"{data}: {rows.size} of {len(q)} rows have coordinates beyond {robot.title}'s joint "
        f"limits (first: line {lines[i]}, q{j + 1} ({robot.coordinate_joints[j]}) = "
        f"{q[i, j] / scale:.6g} {unit}, limits "
        f"[{lo[j] / scale:.6g}, {hi[j] / scale:.6g}] {unit}); {hint}", DataFileWarning,
        stacklevel=4)


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


def first_copies(values: np.ndarray) -> np.ndarray:
    """For each row of ``values`` (n_rows, n_cells), the index of the first row equal to it
    in every cell to the last bit (its own where none comes before): the same row written
    twice, not a repeated measurement, which differs by its noise."""
    first: dict[bytes, int] = {}
    return np.array([first.setdefault(row.tobytes(), i)
                     for i, row in enumerate(np.asarray(values, dtype=float))], dtype=int)


def warn_copied_rows(cells: np.ndarray, lines: list[int] | tuple[int, ...], data: Path) -> None:
    """Warn once when rows repeat an earlier row in every cell.

    A repeated measurement differs from the first by its noise; a row identical to the last
    bit is the same row written twice (a logger or a copy and paste), which the fits would
    count twice: its weight doubled and the intervals too narrow. It is still read.

    Parameters
    ----------
    cells
        (n_rows, n_cells) every number a row holds, as read (NaN for an empty cell).
    lines
        The file line of each row.
    """
    first = first_copies(cells)
    copies = np.flatnonzero(first != np.arange(first.size))
    if copies.size:
        i = int(copies[0])
        j = int(first[i])
        warnings.warn(
            f"{data}: {copies.size} row(s) repeat an earlier row in every cell (first: line "
            f"{lines[i]} copies line {lines[j]}): a row written twice counts twice (its weight "
            "doubled, the intervals too narrow); remove the copies (a repeated measurement "
            "differs by its noise)", DataFileWarning, stacklevel=4)


def warn_copied_markers(names: list[str] | tuple[str, ...], positions: np.ndarray,
                        data: Path | str) -> None:
    """Warn once when a marker's positions equal another marker's on every row both are seen.

    Two markers are two physical points, each read with its own noise: positions equal to the
    last bit on every row are one marker's columns written twice (a tracker export repeating a
    marker, a map naming the same columns twice), which the fits would count twice: its
    weight doubled and the intervals too narrow. The campaign is still read.

    Parameters
    ----------
    names
        The markers' names, in the order of ``positions``' second axis.
    positions
        (n_rows, n_markers, 3) positions as read (NaN where a marker was not seen).
    data
        The file the positions came from, named in the warning.
    """
    pos = np.asarray(positions, dtype=float)
    pairs = []
    for a in range(pos.shape[1]):
        for b in range(a + 1, pos.shape[1]):
            both = np.isfinite(pos[:, a]).all(axis=1) & np.isfinite(pos[:, b]).all(axis=1)
            if both.sum() >= 2 and np.array_equal(pos[both, a], pos[both, b]):
                pairs.append((names[a], names[b], int(both.sum())))
    if pairs:
        first, copy, n = pairs[0]
        others = f" ({len(pairs) - 1} more pair(s))" if len(pairs) > 1 else ""
        warnings.warn(
            f"{data}: markers {first} and {copy} read the same positions, to the last digit, on "
            f"all {n} rows that see both{others}: one marker's columns written twice (a tracker "
            "export repeating a marker, or a map naming the same columns twice), which the fits "
            "count twice (its weight doubled, the intervals too narrow); map each marker to its "
            f"own columns, or drop {copy}", DataFileWarning, stacklevel=4)
