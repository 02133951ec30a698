"""Joint path files: the one reader of a path of joint coordinates (``stiffness compensate
--path``, ``stiffness view --path``, ``stiffness track``) and the CSV tables it reads.

A path file has one row per point, in either form (:func:`read_joint_path`):

* a header line naming its columns: one per coordinate, by joint name or ``q1..qn`` (model
  coordinate order), or one per joint outside the end-effector branch, or, by joint name, at
  least every joint that moves the target; optional per-row loads ``fx,fy,fz[,mx,my,mz]``
  (N, N.m); a unit in brackets after a name (``elbow_joint [deg]``) is checked against the
  one the column is read in; a name in another case (``ELBOW_JOINT``, ``Q1``, ``FX``) is read
  as the column of that spelling;
* no header (its first line holding data is all numbers): one value per coordinate, or per
  joint outside the end effector's fingers, in model order; no loads.

In both, ``#`` comment lines, blank lines and rows of empty cells are skipped.

The joints without a column keep their reference value
(:func:`~stiffness.mechanics.defaults.assembly_coordinates`). A cell is read as every campaign
cell is (:func:`~stiffness.files.csv_float`). Units: rad and m (degrees with ``deg``), N, N.m.
"""

from __future__ import annotations

import math
import re
import warnings
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stiffness.calibration.coordinate_columns import (
    canonical_header,
    header_with_units,
    is_blank_row,
    is_units_row,
    listed,
    warn_commented_rows,
)
from stiffness.errors import DataFileNote, FileFormatError
from stiffness.files import check_csv_header, csv_cells, csv_float, read_text
from stiffness.mechanics.defaults import assembly_coordinates
from stiffness.robot.robot import Robot
from stiffness.units import NumberSpellingError

#: Wrench columns a path file may carry (N, N.m).
WRENCH_COLUMNS = ("fx", "fy", "fz", "mx", "my", "mz")



@dataclass
class JointPath:
    """A joint path read from CSV.

    Attributes
    ----------
    header
        The input columns, as given.
    cells
        The input cells (text), one list per row.
    coords
        (m, n) coordinates in SI (rad, m), model coordinate order.
    wrench
        (m, 6) per-row wrenches (N, N.m), or None.
    column_of
        Input column name of each coordinate.
    angular
        (n,) whether each coordinate is an angle (converted by ``--deg``).
    lines
        File line (1-based) of each row.
    """

    header: list[str]
    cells: list[list[str]]
    coords: np.ndarray
    wrench: np.ndarray | None
    column_of: list[str]
    angular: np.ndarray
    lines: list[int] = field(default_factory=list)

    @classmethod
    def of_coordinates(cls, robot: Robot, coords: np.ndarray) -> JointPath:
        """A path given as (m, n) coordinates (rad, m): one column per coordinate joint, the
        values written in SI."""
        joints = list(robot.coordinate_joints)
        return cls(joints, [[repr(float(v)) for v in row] for row in coords], coords, None,
                   joints, angular_coordinates(robot))


def angular_coordinates(robot: Robot) -> np.ndarray:
    """(n,) whether each coordinate of ``robot`` is an angle (not a prismatic joint's)."""
    return np.array([not robot.is_prismatic(j) for j in robot.coordinate_joints])


@dataclass
class Table:
    """A CSV table: its header, and its non-empty rows with their 1-based file line numbers."""

    path: Path
    header: list[str]
    rows: list[list[str]]
    lines: list[int]

    def column(self, name: str) -> np.ndarray:
        """The finite numbers of column ``name``.

        Raises
        ------
        FileFormatError
            A cell that is not a finite number (its line, column and name).
        """
        k = self.header.index(name)
        out = np.empty(len(self.rows))
        for r, (row, line) in enumerate(zip(self.rows, self.lines, strict=True)):
            cell = row[k].strip() if k < len(row) else ""
            try:
                value = csv_float(cell)
            except ValueError as exc:
                problem = str(exc) if isinstance(exc, NumberSpellingError) else \
                    f"{cell!r} is not a number; every value must be one"
                raise FileFormatError(problem, path=self.path, line=line, column=k + 1,
                                      field=name) from None
            if not math.isfinite(value):
                raise FileFormatError(f"{cell!r}: every value must be a finite number",
                                      path=self.path, line=line, column=k + 1, field=name)
            out[r] = value
        return out

    def wrenches(self) -> np.ndarray | None:
        """(m, 6) per-row loads of columns ``fx,fy,fz[,mx,my,mz]`` (N, N.m), or None."""
        present = [c for c in WRENCH_COLUMNS if c in self.header]
        if not present:
            return None
        if not all(c in present for c in WRENCH_COLUMNS[:3]) or len(present) not in (3, 6):
            raise FileFormatError("per-row loads need the columns fx, fy, fz (N), and "
                                  "optionally all of mx, my, mz (N.m)", path=self.path, line=1)
        out = np.zeros((len(self.rows), 6))
        for k, c in enumerate(WRENCH_COLUMNS):
            if c in present:
                out[:, k] = self.column(c)
        return out


def read_table(path: str | Path, what: str) -> Table:
    """Read a CSV file with a header line (``what`` names it in errors).

    Raises
    ------
    MissingFileError
        The file cannot be read.
    FileFormatError
        Not UTF-8 text, no data row, or a column name given twice.
    """
    path = Path(path)
    return _table(read_text(path, what), path, what)


def _table(text: str, path: Path, what: str) -> Table:
    """:func:`read_table` of the file's ``text``."""
    rows: list[list[str]] = []
    lines: list[int] = []
    comments: list[tuple[int, str]] = []
    for number, line in enumerate(text.splitlines(), start=1):
        if line.lstrip().startswith("#"):  # a comment, as in a file without a header
            if rows:
                comments.append((number, line))
            continue
        row = csv_cells(line, path, number)
        if not is_blank_row(row):
            rows.append(row)
            lines.append(number)
    if len(rows) < 2:
        raise FileFormatError(f"no {what} rows: give a header line and one row per point",
                              path=path)
    header = [h.strip() for h in rows[0]]
    check_csv_header(header, path, lines[0])
    warn_commented_rows(comments, len(header), path)
    for k, name in enumerate(header):
        if name and name in header[:k]:
            raise FileFormatError(f"the column {name!r} appears twice (columns "
                                  f"{header.index(name) + 1} and {k + 1}); name each column once",
                                  path=path, line=lines[0], column=k + 1)
    return Table(path, header, rows[1:], lines[1:])


def read_joint_path(path: str | Path, robot: Robot, deg: bool = False,
                    what: str = "path file") -> JointPath:
    """Read ``PATH.csv``, one row per point, with or without a header line (module
    docstring). With one: one column per coordinate, named by joint name or ``q1..qn`` (model
    coordinate order), or one per joint outside the end-effector branch
    (``robot.chain_joints``: the fingers then keep their reference value), or, by joint name,
    at least every joint that moves the target (:func:`target_chain`; the others, another
    limb's, keep their reference value, said in a :class:`DataFileNote`); optional
    ``fx,fy,fz[,mx,my,mz]`` (N, N.m) per row. Without one: one value per coordinate or per
    chain joint, in model order (:func:`_numbered_rows`). ``what`` names the file when it
    cannot be read.

    Raises
    ------
    MissingFileError, FileFormatError
        Unreadable file, a missing coordinate column, a row of the wrong length, a value that
        is not a finite number (named by line and column).
    """
    path = Path(path)
    text = read_text(path, what)
    if not _named_columns(text):
        return _numbered_rows(text, path, robot, deg)
    table = _table(text, path, "path file")
    written = table.header  # the input's own column names, carried to the output
    if table.rows and is_units_row(table.rows[0]):  # a spreadsheet's second header line
        table.header = header_with_units([h.strip() for h in table.header], table.rows[0],
                                         path, table.lines[0])
        table.rows, table.lines = table.rows[1:], table.lines[1:]
    joints = list(robot.coordinate_joints)
    table.header = canonical_header(_without_units(table, robot, deg),
                                    [*joints, *WRENCH_COLUMNS])  # ELBOW_JOINT, Q1, FX
    header = table.header
    chain = list(robot.chain_joints)
    by_index = [f"q{i + 1}" for i in range(len(joints))]
    if all(j in header for j in joints):
        column_of = joints
    elif all(q in header for q in by_index):
        column_of = by_index
    elif robot.branch_joints and all(j in header for j in chain):
        column_of = chain  # the fingers of an end effector keep their reference value
    elif all(j in header for j in target_chain(robot)) and not set(by_index) & set(header):
        column_of = [j for j in joints if j in header]  # the other limbs keep theirs
        held = [j for j in joints if j not in header]
        warnings.warn(f"{table.path}: {len(held)} of {len(joints)} coordinates have no column "
                      f"and are held at the reference configuration (they do not move the "
                      f"target): {listed(held)}", DataFileNote, stacklevel=2)
    else:
        missing = [j for j in target_chain(robot) if j not in header]
        missing_q = [q for q in by_index if q not in header]
        shown = missing if len(missing) <= len(missing_q) else missing_q
        other = "" if set(header) & set(joints + by_index) else (
            " (its columns name none of them: a path of another robot?)")
        raise FileFormatError(
            f"lacks the coordinate column(s) {', '.join(shown)} of {robot.title}{other}: name "
            f"one column per coordinate ({', '.join(joints)}, or q1..q{len(joints)})",
            path=table.path, line=1)
    coords = _coordinates(robot, len(table.rows), deg, (
        (name, table.column(column)) for name, column in zip(
            joints if column_of is by_index else column_of, column_of, strict=True)))
    wrench = table.wrenches()
    return JointPath(written, [list(r) for r in table.rows], coords, wrench, column_of,
                     angular_coordinates(robot), table.lines)


def _coordinates(robot: Robot, m: int, deg: bool,
                 columns: Iterable[tuple[str, np.ndarray]]) -> np.ndarray:
    """(m, n) coordinates (SI) of a path of ``m`` points: each (joint, values) of ``columns``
    (degrees with ``deg`` for an angle), every other joint at its reference value."""
    joints = list(robot.coordinate_joints)
    angular = angular_coordinates(robot)
    coords = np.tile(assembly_coordinates(robot), (m, 1))
    for name, values in columns:
        k = joints.index(name)
        coords[:, k] = np.deg2rad(values) if deg and angular[k] else values
    return coords


def _named_columns(text: str) -> bool:
    """Whether the first line of ``text`` that holds data (not blank, not a ``#`` comment) is
    a header: no cell of it is a number."""
    for line in text.splitlines():
        cells = line.split("#", 1)[0].strip()
        if cells:
            return not any(_is_number(cell) for cell in cells.split(","))
    return False


def _is_number(cell: str) -> bool:
    """Whether ``float`` reads ``cell`` (a mistyped number is a row's, not a column name)."""
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _numbered_rows(text: str, path: Path, robot: Robot, deg: bool) -> JointPath:
    """The path of a file without a header: one row of finite numbers per line (``#``
    comments and blank lines skipped), one value per coordinate or per joint outside the end
    effector's fingers (which keep their reference value), in model order; its columns named
    after those joints.

    Raises
    ------
    FileFormatError
        No row, a cell that is not a finite plain number, rows of unequal length (its line)
        or of a length that is neither.
    """
    n = robot.n_coordinates
    rows: list[list[float]] = []
    cells: list[list[str]] = []
    lines: list[int] = []
    for number, line in enumerate(text.splitlines(), start=1):
        data = line.split("#", 1)[0].strip()
        if not data:
            continue
        try:
            row = [csv_float(cell) for cell in data.split(",")]
        except ValueError as exc:
            raise FileFormatError(f"{exc}; give one row of {n} coordinates per line",
                                  path=path, line=number) from exc
        if not all(math.isfinite(v) for v in row) or (rows and len(row) != len(rows[0])):
            raise FileFormatError(f"{data!r} is not a row of finite numbers as long as the "
                                  f"first; give one row of {n} coordinates per line",
                                  path=path, line=number)
        rows.append(row)
        cells.append([cell.strip() for cell in data.split(",")])
        lines.append(number)
    if not rows:
        raise FileFormatError(f"no rows; give one row of {n} coordinates per line", path=path)
    width = len(rows[0])
    given = list(robot.coordinate_joints) if width == n else list(robot.chain_joints)
    if width != len(given):
        chain = "" if not robot.branch_joints else (
            f", or {len(robot.chain_joints)} without the end effector's fingers")
        raise FileFormatError(
            f"each row needs {n} values ({', '.join(robot.coordinate_joints)}){chain}, this "
            f"file has {width}", path=path)
    values = np.array(rows, dtype=float)
    coords = _coordinates(robot, len(rows), deg, ((joint, values[:, i])
                                                  for i, joint in enumerate(given)))
    return JointPath(given, cells, coords, None, given, angular_coordinates(robot), lines)


#: A column name with its unit in brackets: ``elbow_joint [deg]``, ``fx [N]``.
_HEADER_UNIT = re.compile(r"^(.*?)\s*\[\s*([^\[\]\s]+)\s*\]$")


def _without_units(table: Table, robot: Robot, deg: bool) -> list[str]:
    """The path's header without the units in brackets of its coordinate and load columns,
    each checked against the unit it is read in: rad (deg with ``--deg``), m for a prismatic
    joint, N and N.m (:func:`header_without_units`)."""
    angular = angular_coordinates(robot)
    expected = {}
    for k, joint in enumerate(robot.coordinate_joints):
        expected[joint] = expected[f"q{k + 1}"] = ("deg" if deg else "rad") if angular[k] else "m"
    return header_without_units(table, expected)


def header_without_units(table: Table, expected: dict[str, str]) -> list[str]:
    """``table``'s header with the unit in brackets dropped from the columns of ``expected``
    and the load columns (``elbow_joint [deg]`` -> ``elbow_joint``, ``fx [N]`` -> ``fx``), each
    unit checked against the one the column is read in (``expected``'s, N and N.m or Nm for
    the loads).

    Raises
    ------
    FileFormatError
        A unit that is not the one the column is read in (the fix named), or a column named
        twice once the units are dropped.
    """
    expected = {c: "N" for c in WRENCH_COLUMNS[:3]} | {c: "N.m" for c in WRENCH_COLUMNS[3:]} \
        | expected
    bare: list[str] = []
    for k, name in enumerate(table.header):
        match = _HEADER_UNIT.match(name)
        column, unit = match.groups() if match else (name, None)
        if unit is None or column not in expected:
            bare.append(name)
            continue
        want = expected[column]
        if unit != want and {unit, want} != {"N.m", "Nm"}:
            fix = {("deg", "rad"): "give --deg", ("rad", "deg"): "drop --deg"}.get(
                (unit, want), f"convert the column to {want}")
            raise FileFormatError(f"the header says {unit} but {column} is read in {want}; "
                                  f"{fix}", path=table.path, line=1, column=k + 1, field=name)
        if column in bare or column in table.header[k + 1:]:
            raise FileFormatError(f"the column {column!r} appears twice; name each column once",
                                  path=table.path, line=1, column=k + 1, field=name)
        bare.append(column)
    return bare


def target_chain(robot: Robot) -> list[str]:
    """The coordinate joints that move the target: those of its chain from the base and the
    leaders of mimic followers on it, in coordinate order; every coordinate of a robot with
    closed loops or a controller map (the target may depend on any of them)."""
    if not robot.loop.is_open_chain or robot.coupling is not None:
        return list(robot.coordinate_joints)
    model = robot.model
    support = {model.names[i] for i in model.supports[model.frames[robot.target_frame_id]
                                                       .parentJoint]}
    support |= {m.leader for m in robot.mimics if m.follower in support}
    return [j for j in robot.coordinate_joints if j in support]
