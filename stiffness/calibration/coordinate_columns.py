"""The coordinate columns of a campaign CSV, as rigs write them.

A campaign's rows carry the robot's coordinates either by position, ``q1..qn`` (every
coordinate, in the robot's coordinate order), or named after the robot's coordinate joints
(``arm_1_joint``), any subset in any order. A coordinate without a column is held at the value
``[robot] fixed = { joint = value }`` declares (in the campaign's angle unit, or its length unit
for a prismatic joint), else at the robot's reference configuration
(:func:`stiffness.mechanics.defaults.reference_configuration`); the readers say so once
(:class:`stiffness.errors.DataFileNote`). Columns no reader knows are ignored with one
:class:`stiffness.errors.UnknownColumnWarning` (the command line's ``--strict`` refuses them).

What spreadsheets write is read as the plain file (:func:`canonical_header`,
:func:`is_blank_row`, :func:`trim_empty_columns`): column names in another case or with
surrounding spaces (``Q1``, `` fx ``, ``Tip_X``), the empty last column of a comma ending every
line, rows of empty cells. A units row under the header (:func:`is_units_row`) is the
headers' units to the import (:func:`header_with_units`) and refused by the campaign readers,
whose units are their ``campaign.toml``'s.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Iterable
from decimal import Decimal
from pathlib import Path

import numpy as np

from stiffness.errors import (
    DataFileNote,
    DataFileWarning,
    FileFormatError,
    UnknownColumnWarning,
    did_you_mean,
)
from stiffness.files import csv_cells, csv_float
from stiffness.mechanics.defaults import reference_configuration
from stiffness.robot.robot import Robot
from stiffness.units import (
    ANGLE_UNITS,
    FORCE_UNITS,
    LENGTH_UNITS,
    MAX_CELL,
    MOMENT_UNITS,
    Units,
    finite_number,
)

#: A positional coordinate column: ``q1``, ``q2``, ...
Q_COLUMN = re.compile(r"q(\d+)$")
#: Names listed in full in a note before it is summarised (``..., and 40 more``).
LISTED = 8
#: A number written with a decimal comma (a European spreadsheet's ``72,922``).
DECIMAL_COMMA = re.compile(r"[+-]?\d+,\d+(?:[eE][+-]?\d+)?")
#: The separators a rig's export may use instead of commas (a European spreadsheet's ``;``,
#: a tracker's tab-separated text), by how messages name them.
SEPARATORS = {";": "';'", "\t": "tabs", " ": "spaces"}


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
            if k and names[i] != f"q{k + 1}" and names[i - 2: i - 1] == [f"q{k}"]:
                raise fail(i - 1, f"got {names[i - 1]!r} between q{k} and {names[i]!r}, where "
                                  f"q{k + 1} ({robot.coordinate_joints[k]}) belongs; name it "
                                  f"q{k + 1} (q columns are q1, q2, ... in order)")
            if names[i] != f"q{k + 1}":
                raise fail(i, f"got {names[i]!r}, expected 'q{k + 1}' (q columns are q1, q2, "
                              "... in order)")
        if len(q_at) != n:
            col = q_at[min(len(q_at), n)] if len(q_at) > n else q_at[-1] + 1
            there = (f" (column {col + 1} is {names[col]!r}, where q{len(q_at) + 1} follows)"
                     if len(q_at) < n and col < len(names) else "")
            raise fail(col, f"{robot.title} has {n} coordinates ({joints_text(robot)}) but the "
                            f"header has {len(q_at)} q columns{there}; give q1..q{n} in that "
                            "order, or name the columns after the joints")
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


def canonical_header(cells: list[str], known: Iterable[str]) -> list[str]:
    """The header's cells stripped of surrounding spaces and, where a cell names a ``known``
    column in another case, spelt as that column (``Q1`` -> ``q1``, ``FX`` -> ``fx``,
    ``Tip_X`` -> ``tip_x``). A ``q<digits>`` cell in any case is ``q<digits>``. A cell whose
    lower case matches several known names (joints ``A`` and ``a``) is left as written.

    Two cells of one column in two cases (``fx`` and ``FX``) become two ``fx``: the readers
    refuse a column given twice.
    """
    folded: dict[str, list[str]] = {}
    for name in dict.fromkeys(known):
        folded.setdefault(name.casefold(), []).append(name)
    out = []
    for cell in cells:
        name = cell.strip()
        matches = folded.get(name.casefold(), [])
        if Q_COLUMN.match(name.casefold()):
            name = name.casefold()
        elif name not in matches and len(matches) == 1:
            name = matches[0]
        out.append(name)
    return out


def first_column_problem(cells: list[str]) -> str:
    """How a header whose first cell is not ``config`` is named in the refusal: ``got 'x'``,
    and for an unnamed column before ``config`` what wrote it (a row index: pandas'
    ``DataFrame.to_csv`` without ``index=False``, or a spreadsheet's row numbers)."""
    got = repr(cells[0]) if cells else "nothing"
    if len(cells) > 1 and not cells[0] and cells[1] == "config":
        return (f"got {got}, an unnamed column before config: a row index (pandas writes one "
                "unless to_csv(index=False)); delete that column")
    return f"got {got}"


def is_blank_row(cells: list[str]) -> bool:
    """A row of empty cells only (``,,,,``: a spreadsheet's formatted but empty row), read as a
    blank line."""
    return all(not c.strip() for c in cells)


def _is_number(cell: str) -> bool:
    try:
        csv_float(cell)
    except ValueError:
        return False
    return True


def warn_commented_rows(comments: Iterable[tuple[int, str]], width: int, path: Path,
                        separator: str = ",") -> None:
    """Say once that lines read as comments hold data rows, which would vanish silently.

    A line starting with ``#`` is a comment to every reader. One after the header whose cells
    fill the header's ``width`` (empty cells past it aside), at least two and half of those
    past the first being numbers, is a row commented out or a row whose label starts with
    ``#`` (a rig's row number, ``#12``): skipped either way, and said so
    (:class:`DataFileWarning`) so that a measurement never disappears unseen.

    Parameters
    ----------
    comments
        The comment lines after the header: (1-based line number, the line as written).
    separator
        The file's column separator.
    """
    rows = []
    for number, line in comments:
        try:
            cells = split_cells(line, path, number, separator)
        except FileFormatError:  # not CSV: no row
            continue
        while len(cells) > width and not cells[-1].strip():
            cells.pop()
        numbers = sum(_is_number(c) for c in cells[1:])
        if width > 2 and len(cells) == width and numbers >= max(2, (width - 1) / 2):
            rows.append(number)
    if rows:
        warnings.warn(f"{path}: {len(rows)} line(s) starting with '#' hold a full data row "
                      f"(first: line {rows[0]}) and are skipped as comments; if they are "
                      "measurements, give them a label that does not start with '#'",
                      DataFileWarning, stacklevel=3)


def split_cells(line: str, path: str | Path, number: int, separator: str = ",") -> list[str]:
    """The cells of one line of a rig file separated by ``separator``: a CSV reading
    (:func:`stiffness.files.csv_cells`), or for ``" "`` the runs of spaces and tabs between
    them (``numpy.savetxt``'s, MATLAB's ``save -ascii``, a tracker's text export)."""
    if separator == " ":
        return line.split()
    return csv_cells(line, path, number, separator)


def rig_rows(text: str, path: Path
             ) -> tuple[list[tuple[int, list[str]]], list[tuple[int, str]], str]:
    """The rows of a rig file's ``text`` (the header first) as (1-based line, stripped cells),
    blank, empty (``,,,``) and ``#`` lines skipped; the comment (and blank) lines after the
    header; and the column separator, read from the header: a header that is one cell to a
    comma-separated reading but holds ``;``, tabs or spaces (a European spreadsheet's export,
    a tracker's text file, ``numpy.savetxt``'s) separates the columns with those
    (:data:`SEPARATORS`; spaces: any run of them). Numbers with decimal commas in such a file
    are read by :func:`decimal_commas`. A file without a header (its first row all numbers:
    ``numpy.savetxt``'s, a logger's) gets one naming its columns by position, ``col1`` ..
    ``colN`` (:func:`numbered_header`), said once."""
    separator = ","
    found: list[tuple[int, list[str]]] = []
    comments: list[tuple[int, str]] = []
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            comments.extend([(number, line)] if found else [])  # blank ones are no rows
            continue
        if not found and len(csv_cells(line, path, number)) == 1:
            separator = _separator(line.strip())
        cells = [c.strip() for c in split_cells(line, path, number, separator)]
        if not is_blank_row(cells):
            found.append((number, cells))
    return numbered_header(found, path), comments, separator


def _separator(line: str) -> str:
    """The separator of a rig file whose first line ``line`` is one cell to a comma-separated
    reading: the first of :data:`SEPARATORS` in it, but for a line of numbers (no header)
    separated by runs of spaces or tabs (not tabs alone, which keep their empty cells) any
    such run (``" "``)."""
    separator = next((c for c in SEPARATORS if c in line), ",")
    if separator == "\t" and len(line.split("\t")) != len(line.split()) and all(
            _is_number(c) for c in line.split()):
        return " "
    return separator


def numbered_header(found: list[tuple[int, list[str]]], path: Path
                    ) -> list[tuple[int, list[str]]]:
    """The rows ``found`` (:func:`rig_rows`), with a header ``col1`` .. ``colN`` put before
    them when their first row is all numbers (a file written without a header, whose first
    measurement would otherwise be read as column names and lost), said once
    (:class:`DataFileNote`); else unchanged."""
    if not found or not all(_is_number(c) or DECIMAL_COMMA.fullmatch(c) for c in found[0][1]):
        return found
    number, cells = found[0]
    warnings.warn(f"{path}: no header (line {number} is {len(cells)} numbers): its columns are "
                  f"named by position, col1 .. col{len(cells)}; map them (--map q1=col1,...)",
                  DataFileNote, stacklevel=4)
    return [(number, [f"col{i + 1}" for i in range(len(cells))]), *found]


def decimal_commas(found: list[tuple[int, list[str]]], separator: str, path: Path
                   ) -> list[tuple[int, list[str]]]:
    """The rows ``found`` (:func:`rig_rows`: the header, then the rows) of a file separated by
    ``separator`` (``;`` or tabs) with the numbers written with a decimal comma (``72,922``)
    rewritten with a point, said once (:class:`DataFileNote`); a comma-separated file's rows
    unchanged.

    Raises
    ------
    FileFormatError
        Numbers with a decimal comma and numbers with a decimal point in one file: one of them
        may be a thousands separator (``1,234`` is 1.234 or 1234), so neither is guessed.
    """
    if separator == "," or not found:
        return found
    header, rows = found[0][1], found[1:]
    commas = [(n, j) for n, cells in rows for j, c in enumerate(cells)
              if DECIMAL_COMMA.fullmatch(c)]
    points = [(n, j, c) for n, cells in rows for j, c in enumerate(cells)
              if "." in c and _is_number(c)]
    if commas and points:
        line, column, cell = points[0]
        raise FileFormatError(
            f"{cell!r} has a decimal point, but line {commas[0][0]} has a number with a "
            "decimal comma: with both, one may be a thousands separator (1,234 is 1.234 or "
            "1234); write every number with the same decimal mark", path=path, line=line,
            column=column + 1, field=header[column] if column < len(header) else None)
    if not commas:
        return found
    warnings.warn(f"{path}: columns separated by {SEPARATORS[separator]}, numbers with a "
                  "decimal comma (72,922 read as 72.922)", DataFileNote, stacklevel=3)
    return [found[0], *((n, [c.replace(",", ".") if DECIMAL_COMMA.fullmatch(c) else c
                             for c in cells]) for n, cells in rows)]


def join_key(cell: str) -> str:
    """A join key as files are matched on: a plain number by its value, exactly (``001``,
    ``1`` and ``1.0`` are one sample, as a controller's log and a tracker's export write it;
    a 19-digit time stamp stays itself), any other cell as written."""
    if not _is_number(cell):
        return cell
    value = Decimal(cell.strip())
    return str(value.normalize() + 0) if value.is_finite() else cell


def trim_empty_columns(header: list[str], rows: list[list[str]]
                       ) -> tuple[list[str], list[list[str]]]:
    """The header and rows without the empty columns a spreadsheet export adds at the end
    (a comma ending every line): trailing header cells that are empty above empty cells only,
    and empty cells past the header's width on any row. A nameless column holding a value
    is kept (the readers name it); the rows' other cells are unchanged."""
    width = len(header)
    while width > 1 and not header[width - 1] and all(
            len(r) < width or not r[width - 1].strip() for r in rows):
        width -= 1

    def trimmed(row: list[str]) -> list[str]:
        end = len(row)
        while end > width and not row[end - 1].strip():
            end -= 1
        return row[:end]

    return header[:width], [trimmed(r) for r in rows]


#: What a units row under a header holds besides the units the toolkit reads (each in any
#: case, brackets stripped): their spelt-out forms.
UNIT_WORDS = frozenset(u.casefold() for u in (
    *ANGLE_UNITS, *FORCE_UNITS, *LENGTH_UNITS, *MOMENT_UNITS, "degree", "degrees", "°",
    "radian", "radians", "Nm", "N*m", "N·m", "kNm", "Nmm", "µm", "micron", "in", "inch", "s"))


def unit_cell(cell: str) -> str:
    """A units row's cell without its brackets: ``[mm]`` -> ``mm``."""
    return cell.strip().strip("[]()").strip()


def is_units_row(cells: list[str]) -> bool:
    """A row that names units rather than holding numbers (``,deg,deg,N,mm``, ``unit,[deg],
    ...``: a spreadsheet's second header line): no cell is a number and some cell is a unit."""
    return not any(_is_number(c) for c in cells) and any(
        unit_cell(c).casefold() in UNIT_WORDS for c in cells)


#: Cells of a units row that name no unit (under a label or key column).
_NO_UNIT = ("", "-", "unit", "units")


def header_with_units(header: list[str], units: list[str], path: Path, line: int
                      ) -> list[str]:
    """The header with a units row's units in brackets (``q1`` over ``deg``: ``q1 [deg]``),
    as a header naming its unit is read (``stiffness campaign import``).

    Raises
    ------
    FileFormatError
        A units row of another width than the header, or a unit beside a header that names
        one, or one with spaces or brackets (line and column named).
    """
    if len(units) != len(header):
        raise FileFormatError(f"the units row has {len(units)} cells but the header has "
                              f"{len(header)} columns; give one unit (or an empty cell) per "
                              "column", path=path, line=line)
    out = []
    for i, (name, cell) in enumerate(zip(header, units, strict=True)):
        unit = unit_cell(cell)
        if unit.casefold() in _NO_UNIT:
            out.append(name)
        elif re.search(r"[\[(][^\[\]()]*[\])]$", name) or not re.fullmatch(r"[^\[\]()\s]+",
                                                                            unit):
            raise FileFormatError(f"the units row gives {cell.strip()!r} for column {name!r}, "
                                  "which cannot be read as its unit; give a unit such as deg, "
                                  "N or mm (and none in the header too)", path=path, line=line,
                                  column=i + 1, field=name)
        else:
            out.append(f"{name} [{unit}]")
    return out


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
    names = robot.coordinate_joints
    source = "zero" if reference is None else reference.source_for(
        [names[k] for k in missing if names[k] not in fixed_si])
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

