"""Rig files as they come: the CSVs a rig writes, read into a campaign (``campaign import``).

A rig writes one or several CSV files (joint readings, forces, tracker positions), with its
own column names, units and frames. :func:`import_campaign` reads them into an ordinary
:class:`stiffness.calibration.campaign.Campaign` (SI, base axes), which
:func:`stiffness.calibration.campaign_writer.write_campaign` writes for ``identify``, ``diagnose``
and ``design --existing``:

* **Joining.** The files' data rows are joined by row order (every file the same number of
  rows), or by a key column present in every file (``join``; its values unique in each
  file; rows in the first file's order).
* **Column map.** Each campaign column (:data:`TARGETS`) is read from the file column the map
  names (``q1=theta1,fx=Base_Fx``), else from a column of its own name (``dx`` or ``dx [mm]``)
  that the map does not give to another campaign column. A column name found in
  several files is named ``FILE:COLUMN`` (the file's name).
* **Deflections**, one of three ways: ``dx,dy,dz`` (loaded minus unloaded position); two
  column sets ``x_loaded..z_loaded`` and ``x_unloaded..z_unloaded``; or paired rows:
  positions ``x,y,z``, a ``state`` column (``loaded`` or ``unloaded``) and a ``pair`` key,
  each pair one unloaded row and one or more loaded ones (each loaded row is a campaign row;
  its coordinates are the unloaded row's, and a loaded row reading other coordinates is
  refused).
* **Units** (:class:`stiffness.units.Units`): given per kind, or read from the
  headers (``theta1 [deg]``, ``Fx (N)``); a header whose unit disagrees with the given one,
  or columns of one kind in different units, are refused. A kind the import needs and no
  one names is refused too: no unit is assumed.
* **Frames.** Forces (and moments) and deflections are in the base frame or in the tool
  frame (the robot's target frame at the row's coordinates, rotated into base axes with its
  kinematics).
* **Labels.** The ``config`` column, else one label per distinct set of coordinates
  (``P1``, ``P2``, ... in order of appearance).

Every refusal is a one-line :class:`stiffness.errors.FileFormatError` or
:class:`stiffness.errors.StiffnessError` naming the file, the line and the column.
"""

from __future__ import annotations

import math
import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stiffness.calibration.campaign import Campaign
from stiffness.calibration.campaign_toml import BASELINES, RobotSettings
from stiffness.calibration.coordinate_columns import (
    decimal_commas,
    fill_held,
    fixed_values,
    header_with_units,
    held_coordinates,
    is_units_row,
    join_key,
    listed,
    rig_rows,
    trim_empty_columns,
    warn_commented_rows,
)
from stiffness.calibration.import_report import ImportReport, column_report, warn_unused
from stiffness.calibration.measurements import coordinates_in_si
from stiffness.calibration.unit_checks import (
    check_configuration_units,
    check_deflection_sign,
    check_deflection_size,
    check_force_unit,
)
from stiffness.errors import (
    DataFileNote,
    FileFormatError,
    StiffnessError,
    did_you_mean,
)
from stiffness.files import check_csv_header, csv_float, read_text, read_toml
from stiffness.robot.kinematics import frame_rotation, update_first_order
from stiffness.robot.robot import Robot
from stiffness.units import (
    ANGLE_UNITS,
    FORCE_UNITS,
    LENGTH_UNITS,
    MAX_CELL,
    MOMENT_UNITS,
    NumberSpellingError,
    Units,
    finite_number,
)

#: Frames forces and deflections may be given in.
FRAMES = ("base", "tool")
FORCE = ("fx", "fy", "fz")
MOMENT = ("mx", "my", "mz")
DIRECT = ("dx", "dy", "dz")
LOADED = ("x_loaded", "y_loaded", "z_loaded")
UNLOADED = ("x_unloaded", "y_unloaded", "z_unloaded")
POSITION = ("x", "y", "z")
#: Campaign columns a map may name (besides ``q1``, ``q2``, ...).
TARGETS = ("config", *FORCE, *MOMENT, *DIRECT, *LOADED, *UNLOADED, *POSITION, "state", "pair")
#: Values of the ``state`` column of paired rows.
STATES = ("loaded", "unloaded")
#: The kind of unit of each target (q columns: angle, or length for prismatic joints).
UNIT_KINDS = {**{t: "force" for t in FORCE}, **{t: "moment" for t in MOMENT},
         **{t: "length" for t in (*DIRECT, *LOADED, *UNLOADED, *POSITION)}}
_UNIT_TABLES = {"angle": ANGLE_UNITS, "force": FORCE_UNITS, "length": LENGTH_UNITS,
                "moment": MOMENT_UNITS}
#: A header naming its unit, of each kind (the refusal of a unit no one names shows one).
_HEADER_EXAMPLES = {"angle": "theta1 [deg]", "force": "Fx [N]", "length": "X [mm]",
                    "moment": "Mx [N.m]"}
_HEADER_UNIT = re.compile(r"^.*?[\[(]\s*([^\[\]()\s]+)\s*[\])]\s*$")
#: Rows whose coordinates agree to this (rad or m) share a ``P`` label.
SAME_POSE = 1e-9


@dataclass
class Table:
    """One CSV file: its header and data rows (blank lines and ``#`` comments skipped).

    Attributes
    ----------
    path
        The file.
    header
        Column names.
    rows
        Cells of each data row.
    lines
        1-based line number of each data row.
    """

    path: Path
    header: list[str]
    rows: list[list[str]]
    lines: list[int]


@dataclass
class Column:
    """A file column joined into the import's rows.

    Attributes
    ----------
    path, name, index
        Its file, header and 0-based position there.
    cells
        Its cell on each joined row.
    lines
        The file line of each joined row.
    """

    path: Path
    name: str
    index: int
    cells: list[str]
    lines: list[int]

    def error(self, row: int, problem: str) -> FileFormatError:
        """A :class:`FileFormatError` at joined row ``row`` of this column."""
        return FileFormatError(problem, path=self.path, line=self.lines[row],
                               column=self.index + 1, field=self.name)

    def numbers(self, empty_is_nan: bool = False) -> np.ndarray:
        """The cells as finite numbers within +-:data:`MAX_CELL` (file, line and column named
        otherwise); with ``empty_is_nan`` an empty or ``NaN`` cell is NaN (a marker not seen)."""
        out = np.empty(len(self.cells))
        for i, cell in enumerate(self.cells):
            if empty_is_nan and cell.strip().casefold() in ("", "nan"):
                out[i] = math.nan
                continue
            try:
                value = csv_float(cell)
            except ValueError as exc:
                if isinstance(exc, NumberSpellingError):  # 1_000: float() reads 1000
                    raise self.error(i, str(exc)) from None
                value = math.nan
            if not (math.isfinite(value) and abs(value) <= MAX_CELL):
                raise self.error(i, f"{cell!r} is not a number; give a finite number within "
                                    f"+-{MAX_CELL:.0e}")
            out[i] = value
        return out


@dataclass
class ImportSettings:
    """How to read a rig's files (see the module docstring).

    Attributes
    ----------
    column_map
        Campaign column -> file column (``q1`` -> ``theta1``; ``FILE:COLUMN`` when several
        files have it).
    units
        Unit per kind given by the user (``angle``, ``force``, ``length``, ``moment``);
        kinds not given are read from the headers.
    join
        Key column joining the files, or ``None`` for row order.
    force_frame, deflection_frame
        ``base`` or ``tool``.
    fixed
        Values of coordinates without a column (joint -> value in the files' angle or length
        unit), as a campaign's ``[robot] fixed``; the others without one are held at the
        robot's reference configuration.
    """

    column_map: dict[str, str] = field(default_factory=dict)
    units: dict[str, str] = field(default_factory=dict)
    join: str | None = None
    force_frame: str = "base"
    deflection_frame: str = "base"
    fixed: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for kind, value in self.units.items():
            table = _UNIT_TABLES.get(kind)
            if table is None:
                raise StiffnessError(f"unknown unit kind {kind!r}; "
                                     f"{did_you_mean(kind, list(_UNIT_TABLES))}")
            if value not in table:
                raise StiffnessError(f"unknown {kind} unit {value!r}; valid {kind} units: "
                                     f"{', '.join(table)}")
        for label, frame in (("force", self.force_frame), ("deflection", self.deflection_frame)):
            if frame not in FRAMES:
                raise StiffnessError(f"the {label} frame must be base or tool, got {frame!r}")


# ------------------------------------------------------------------------------------------
# reading and joining


def read_table(path: str | os.PathLike) -> Table:
    """Read one CSV file (header first; blank, empty (``,,,``) and ``#`` lines skipped; the
    empty last column of a comma ending every line dropped; a units row under the header
    (``,deg,N,mm``) read as the headers' units, ``q1 [deg]``; columns separated by ``;`` or
    tabs, and decimal commas there, read: :func:`~.coordinate_columns.rig_rows`).

    Raises
    ------
    FileFormatError
        No header or no data row, an empty or repeated column name, or a row with another
        number of cells than the header (file and line named).
    """
    path = Path(path)
    found, comments, separator = rig_rows(read_text(path, "rig file"), path)
    if not found:
        raise FileFormatError("no header; a rig file is a CSV with a header line and data rows",
                              path=path)
    found = decimal_commas(found, separator, path)
    header, rows = trim_empty_columns(found[0][1], [cells for _, cells in found[1:]])
    lines = [number for number, _ in found[1:]]
    warn_commented_rows(comments, len(header), path, separator)
    if rows and is_units_row(rows[0]):
        header = header_with_units(header, rows[0], path, lines[0])
        rows, lines = rows[1:], lines[1:]
    _check_header(header, path, found[0][0])
    for cells, number in zip(rows, lines, strict=True):
        if len(cells) != len(header):
            raise FileFormatError(f"{len(cells)} cells but the header has {len(header)} "
                                  "columns; give one cell per column", path=path, line=number)
    if not rows:
        raise FileFormatError("no data row; a rig file is a CSV with a header line and data "
                              "rows", path=path)
    return Table(path, header, rows, lines)


def _check_header(cells: list[str], path: Path, line: int) -> None:
    check_csv_header(cells, path, line)
    seen: dict[str, int] = {}
    for i, name in enumerate(cells):
        if not name:
            raise FileFormatError("empty column name; name every column", path=path,
                                  line=line, column=i + 1)
        if name in seen:
            raise FileFormatError(f"column {name!r} appears twice (columns {seen[name] + 1} "
                                  f"and {i + 1}); rename one", path=path, line=line,
                                  column=i + 1)
        seen[name] = i


def join_tables(tables: list[Table], key: str | None) -> tuple[dict[str, list[Column]], int]:
    """The files' columns on joined rows: by row order, or by the ``key`` column.

    Returns
    -------
    columns
        Column name -> the columns of that name (one per file having it; the key once).
    n_rows
        Joined rows.

    Raises
    ------
    FileFormatError
        Files of different row counts (row order); a file without the key, a repeated key,
        or a key of the first file missing from another (key join).
    """
    first = tables[0]
    if key is None:
        for t in tables[1:]:
            if len(t.rows) != len(first.rows):
                raise FileFormatError(
                    f"{len(t.rows)} data rows but {first.path.name} has {len(first.rows)}; "
                    "files joined by row order need the same rows (or join them by a key "
                    "column)", path=t.path)
        orders = [list(range(len(first.rows)))] * len(tables)
    else:
        orders = _key_orders(tables, key)
    columns: dict[str, list[Column]] = {}
    for t, order in zip(tables, orders, strict=True):
        for j, name in enumerate(t.header):
            if key is not None and name == key and t is not first:
                continue
            columns.setdefault(name, []).append(
                Column(t.path, name, j, [t.rows[i][j] for i in order],
                       [t.lines[i] for i in order]))
    return columns, len(first.rows)


def _key_orders(tables: list[Table], key: str) -> list[list[int]]:
    """For each table, the row matching each row of the first by ``key``."""
    index = []
    for t in tables:
        if key not in t.header:
            raise FileFormatError(f"no key column {key!r} to join on; "
                                  f"{did_you_mean(key, t.header)}", path=t.path,
                                  line=t.lines[0] - 1 if t.lines else None)
        j = t.header.index(key)
        where: dict[str, int] = {}
        for i, row in enumerate(t.rows):
            value = join_key(row[j])
            if value in where:
                raise FileFormatError(f"key {row[j]!r} repeats line {t.lines[where[value]]}; "
                                      "join keys must be unique in each file (numbers by their "
                                      "value)", path=t.path, line=t.lines[i], column=j + 1,
                                      field=key)
            where[value] = i
        index.append(where)
    first = tables[0]
    j0 = first.header.index(key)
    keys = [join_key(row[j0]) for row in first.rows]
    orders = []
    for t, where in zip(tables, index, strict=True):
        order = []
        for i, (row, value) in enumerate(zip(first.rows, keys, strict=True)):
            if value not in where:
                raise FileFormatError(f"key {row[j0]!r} has no row in {t.path}; every file "
                                      "needs a row for each key", path=first.path,
                                      line=first.lines[i], column=j0 + 1, field=key)
            order.append(where[value])
        extra = set(where) - set(keys)
        if extra:
            i = min(where[k] for k in extra)
            raise FileFormatError(f"key {t.rows[i][t.header.index(key)]!r} has no row in "
                                  f"{first.path}; every file needs a row for each key",
                                  path=t.path, line=t.lines[i], field=key)
        orders.append(order)
    return orders


# ------------------------------------------------------------------------------------------
# mapping


def _bare(header: str) -> str:
    """A header without its unit: ``dx [mm]`` -> ``dx``."""
    match = _HEADER_UNIT.match(header)
    return header[: header.rfind("[" if header.rstrip().endswith("]") else "(")].strip() \
        if match else header


class ColumnMapper:
    """Finds the file column of each campaign column and reads it, with its unit."""

    def __init__(self, columns: dict[str, list[Column]], settings: ImportSettings,
                 files: list[Path]) -> None:
        self.columns, self.settings, self.files = columns, settings, files
        self.used: dict[str, Column] = {}
        self.units_seen: dict[str, list[tuple[str, Column]]] = {}

    def find(self, target: str) -> Column | None:
        """The column of ``target``: the mapped one (which must exist), else one of its own
        name that the map does not give to another campaign column, else ``None``."""
        name = self.settings.column_map.get(target)
        column = self._lookup(name if name is not None else target, target,
                              required=name is not None)
        if name is None and any(column is c for c in self._mapped_elsewhere(target)):
            return None
        if column is not None:
            self.used[target] = column
        return column

    def _mapped_elsewhere(self, target: str) -> list[Column]:
        """The file columns the map gives to campaign columns other than ``target``: a rig's
        ``fx`` mapped to a marker's ``tip_x`` is no force as well."""
        return [c for other, source in self.settings.column_map.items() if other != target
                for c in [self._lookup(source, other, required=False)] if c is not None]

    def _lookup(self, name: str, target: str, required: bool) -> Column | None:
        file_name, _, column = name.rpartition(":")
        column = column if file_name else name
        candidates = self.columns.get(column) or [
            c for named, cs in self.columns.items() if _bare(named) == column for c in cs]
        if file_name:
            candidates = [c for c in candidates if c.path.name == file_name]
        if len(candidates) > 1:
            where = ", ".join(c.path.name for c in candidates)
            raise StiffnessError(f"column {name!r} (for {target}) is in several files ({where});"
                                 f" name it FILE:COLUMN, e.g. {candidates[0].path.name}:{name}")
        if not candidates:
            if not required:
                return None
            files = [f for f in self.files if not file_name or f.name == file_name]
            raise StiffnessError(f"{', '.join(str(f) for f in files or self.files)}: no column "
                                 f"{name!r} (mapped to {target}); "
                                 f"{did_you_mean(column, sorted(self.columns))}")
        return candidates[0]

    def group(self, targets: tuple[str, ...], required: bool) -> list[Column] | None:
        """The columns of a group given whole (all of ``targets``) or, unless ``required``,
        not at all."""
        found = [self.find(t) for t in targets]
        if all(c is None for c in found) and not required:
            return None
        missing = [t for t, c in zip(targets, found, strict=True) if c is None]
        if missing:
            bare = {_bare(named) for named in self.columns}
            cased = {t: b for t in missing for b in sorted(bare) if b.lower() == t.lower()}
            fix = (f"map it ({missing[0]}=COLUMN) or name a column {missing[0]}"
                   if len(cased) < len(missing) else  # 'Fx [N]' is not fx: names are exact
                   f"the files spell them {', '.join(cased.values())}: map them (--map "
                   f"{','.join(f'{t}={b}' for t, b in cased.items())}) or rename the columns")
            raise StiffnessError(f"no column for {', '.join(missing)} in "
                                 f"{', '.join(str(f) for f in self.files)}; {fix}")
        return [c for c in found if c is not None]

    def values(self, target: str, column: Column, kind: str, empty_is_nan: bool = False
               ) -> np.ndarray:
        """A numeric column; its header's unit (if any) noted for ``kind``."""
        match = _HEADER_UNIT.match(column.name)
        if match:
            unit = match.group(1)
            if unit not in _UNIT_TABLES[kind]:
                raise FileFormatError(f"the header says {unit!r}, not a {kind} unit, but the "
                                      f"column is mapped to {target}; valid {kind} units: "
                                      f"{', '.join(_UNIT_TABLES[kind])}", path=column.path,
                                      column=column.index + 1, field=column.name)
            self.units_seen.setdefault(kind, []).append((unit, column))
        return column.numbers(empty_is_nan)

    def unit(self, kind: str, needed: bool) -> str | None:
        """The unit of ``kind``: the one given, which every header must agree with, else the
        headers' own (one unit for all); refused when needed and nowhere named."""
        given = self.settings.units.get(kind)
        seen = self.units_seen.get(kind, [])
        for unit, column in seen:
            if given is not None and unit != given:
                raise FileFormatError(f"mixed units: the header says {unit} but the {kind} "
                                      f"unit given is {given}; convert the column or correct "
                                      "the unit", path=column.path, column=column.index + 1,
                                      field=column.name)
            if unit != seen[0][0]:
                other = seen[0][1]
                raise FileFormatError(f"mixed units: {unit} here but {seen[0][0]} in "
                                      f"{other.path.name} column {other.name!r}; convert "
                                      f"the {kind} columns to one unit", path=column.path,
                                      column=column.index + 1, field=column.name)
        found = given if given is not None else (seen[0][0] if seen else None)
        if found is None and needed:
            raise StiffnessError(f"no {kind} unit: give it (--units {kind}=...) or write it "
                                 f"in the headers, e.g. '{_HEADER_EXAMPLES[kind]}'; valid "
                                 f"{kind} units: {', '.join(_UNIT_TABLES[kind])}")
        return found


# ------------------------------------------------------------------------------------------
# the import


def parse_pairs(text: str | None, flag: str) -> dict[str, str]:
    """``a=b,c=d`` (a ``--map`` or ``--units`` flag) as a dict; one line on a malformed or
    repeated item."""
    out: dict[str, str] = {}
    for item in (text or "").split(","):
        if not item.strip():
            continue
        key, sep, value = (s.strip() for s in item.partition("="))
        if not sep or not key or not value:
            raise StiffnessError(f"{flag} takes NAME=VALUE items separated by commas, got "
                                 f"{item.strip()!r}")
        if key in out:
            raise StiffnessError(f"{flag} names {key} twice")
        out[key] = value
    return out


def read_mapping_file(path: str | os.PathLike) -> ImportSettings:
    """A mapping file: TOML with ``[columns]`` (campaign column = file column), ``[units]``
    (kind = unit), the optional ``join``, ``force_frame`` and ``deflection_frame``, and
    ``fixed = { joint = value }`` (the files' unit).

    Raises
    ------
    FileFormatError
        Invalid TOML, an unknown key, or a value that is not a string.
    """
    doc = read_toml(path, "mapping file")
    known = {"columns", "units", "join", "force_frame", "deflection_frame", "fixed"}
    for key, value in doc.items():
        if key not in known:
            raise FileFormatError(f"unknown key {key!r}; {did_you_mean(key, sorted(known))}",
                                  path=path, field=key)
        if key == "fixed":
            if not (isinstance(value, dict) and all(finite_number(v) for v in value.values())):
                raise FileFormatError("fixed must be a table of finite numbers, e.g. fixed = "
                                      "{ joint6 = 0.0 }", path=path, field=key)
            continue
        tables = ("columns", "units")
        if key in tables and not (isinstance(value, dict)
                                  and all(isinstance(v, str) for v in value.values())):
            raise FileFormatError(f"[{key}] must be a table of strings, e.g. q1 = \"theta1\"",
                                  path=path, field=key)
        if key not in tables and not isinstance(value, str):
            raise FileFormatError(f"{key} must be a string, got {value!r}", path=path,
                                  field=key)
    try:
        return ImportSettings(dict(doc.get("columns", {})), dict(doc.get("units", {})),
                              doc.get("join"), doc.get("force_frame", "base"),
                              doc.get("deflection_frame", "base"),
                              {k: float(v) for k, v in doc.get("fixed", {}).items()})
    except StiffnessError as exc:
        raise FileFormatError(str(exc), path=path) from exc


def load_import_robot(settings: RobotSettings, folder: Path | None = None) -> Robot:
    """The robot of an import (relative paths against ``folder``, default the working
    directory)."""
    return settings.load(Path.cwd() if folder is None else folder)


def import_campaign(files: list[str | os.PathLike], robot_settings: RobotSettings,
                    settings: ImportSettings, name: str = "imported",
                    baseline: str = "enhanced", noise_std: float | None = None,
                    robot: Robot | None = None) -> tuple[Campaign, ImportReport]:
    """Read a rig's CSV files into a campaign (see the module docstring).

    Parameters
    ----------
    files
        The CSV files (one or several).
    robot_settings
        The robot (its source, target frame and offset, compliant joints).
    settings
        Column map, units, join key and frames.
    name, baseline
        The campaign's name and baseline (``conventional`` or ``enhanced``).
    noise_std
        Measurement noise std in the import's length unit, or ``None``.
    robot
        The robot already loaded from ``robot_settings`` (default: loaded here).

    Returns
    -------
    campaign, report
        The campaign in SI (base axes), and what was read.

    Raises
    ------
    StiffnessError
        Anything that cannot be mapped, one line naming the file, line and column.
    """
    if not files:
        raise StiffnessError("give at least one CSV file to import")
    if baseline not in BASELINES:
        raise StiffnessError(f"unknown baseline {baseline!r}; valid: {', '.join(BASELINES)}")
    robot = robot if robot is not None else load_import_robot(robot_settings)
    tables = [read_table(f) for f in files]
    check_map(settings, robot)
    columns, _ = join_tables(tables, settings.join)
    mapper = ColumnMapper(columns, settings, [t.path for t in tables])
    q_cols, q_file, prismatic, held = read_coordinates(mapper, robot)
    force = read_force(mapper)
    moment = read_block(mapper, MOMENT, "moment", False)
    mode, rows, unloaded, delta = _deflections(mapper, q_file)
    units = Units(mapper.unit("angle", bool((~prismatic).any())) or "deg",
                  mapper.unit("force", True) or "N", mapper.unit("length", True) or "mm",
                  moment_unit=mapper.unit("moment", moment is not None))
    q_file = fill_held(q_file, held, robot, units)
    config = mapper.find("config")
    first = q_cols[0]
    lines = [first.lines[i] for i in rows]
    labels = row_labels(config, rows, q_file[unloaded])
    q_si = coordinates_in_si(robot, q_file[unloaded], units, labels, lines, first.path)
    f_si = force[rows] * units.force_to_si
    m_si = None if moment is None else moment[rows] * units.moment_to_si
    d_si = delta * units.length_to_si
    if settings.force_frame == "tool" or settings.deflection_frame == "tool":
        turns = tool_rotations(robot, q_si)
        if settings.force_frame == "tool":
            f_si = np.einsum("rij,rj->ri", turns, f_si)
            m_si = None if m_si is None else np.einsum("rij,rj->ri", turns, m_si)
        if settings.deflection_frame == "tool":
            d_si = np.einsum("rij,rj->ri", turns, d_si)
    check_deflection_sign(f_si, m_si, d_si, first.path)
    if check_deflection_size(robot, d_si, f_si, units, first.path):
        check_force_unit(robot, q_si, f_si, m_si, d_si, units, first.path)
    check_configuration_units(robot, q_si, f_si, m_si, d_si, list(labels), first.path)
    campaign = Campaign(name=name, baseline=baseline, robot_settings=robot_settings, q=q_si,
                        force=f_si, deflection=d_si, config=tuple(labels), moment=m_si,
                        noise_std_m=None if noise_std is None else noise_std
                        * units.length_to_si, units=units, _robot=robot)
    report = ImportReport([(str(t.path), len(t.rows)) for t in tables], len(rows), mode,
                          column_report(mapper, units, robot, prismatic, UNIT_KINDS), units,
                          settings.force_frame, settings.deflection_frame)
    warn_unused(columns, report, settings.join)
    return campaign, report


def read_coordinates(mapper: ColumnMapper, robot: Robot
                     ) -> tuple[list[Column], np.ndarray, np.ndarray, np.ndarray]:
    """The coordinate columns read (q1..qn, or named after the joints: any subset, the rest
    held at the robot's reference configuration, said once), the coordinates (n, n_q) in the
    files' units (the held ones at their SI value until :func:`fill_held` puts them in the
    files' units), which are prismatic, and the held values (rad, m; NaN where read)."""
    prismatic = np.array([robot.is_prismatic(j) for j in robot.coordinate_joints])
    names = robot.coordinate_joints
    q_targets = tuple(f"q{i + 1}" for i in range(robot.n_coordinates))
    by_q = [mapper.find(t) for t in q_targets]
    by_joint = [mapper.find(j) for j in names]
    files = ", ".join(str(f) for f in mapper.files)
    if any(c is not None for c in by_q) and any(c is not None for c in by_joint):
        raise StiffnessError(f"{files}: coordinates come both as q columns and by joint name; "
                             "map or name each coordinate one way")
    if any(c is not None for c in by_q):
        missing = [f"{t} ({j})" for t, j, c in zip(q_targets, names, by_q, strict=True)
                   if c is None]
        if missing:
            raise StiffnessError(f"no column for {listed(missing)} in {files}; map them "
                                 f"({missing[0].split()[0]}=COLUMN) or map the joints by name "
                                 "(JOINT=COLUMN; joints without a column are held)")
        found = by_q
    elif any(c is not None for c in by_joint):
        found = by_joint
    else:
        raise StiffnessError(f"no coordinate column in {files}: map the joints read "
                             f"(JOINT=COLUMN, e.g. {names[0]}=theta1) or name columns after "
                             f"{robot.title}'s joints ({listed(names)}; any subset) or "
                             f"q1..q{robot.n_coordinates}")
    q_cols = [c for c in found if c is not None]
    rows = len(q_cols[0].cells)
    q_read = np.full((rows, robot.n_coordinates), np.nan)
    for k, (c, p) in enumerate(zip(found, prismatic, strict=True)):
        if c is not None:
            q_read[:, k] = mapper.values(c.name, c, "length" if p else "angle")
    index: list[int | None] = [None if c is None else k for k, c in enumerate(found)]
    fixed = mapper.settings.fixed
    turns = [j for j in fixed if j in names and not robot.is_prismatic(j)]
    units = Units(mapper.unit("angle", bool(turns)) or "deg", "N",
                  mapper.unit("length", len(turns) < len(fixed)) or "mm") if fixed else Units()
    held = held_coordinates(robot, index,
                            fixed_values(fixed, robot, units, StiffnessError, "--fixed"),
                            units, q_cols[0].path, StiffnessError, "--fixed")
    return q_cols, np.where(np.isfinite(held), held, q_read), prismatic, held


def check_map(settings: ImportSettings, robot: Robot, targets: tuple[str, ...] = TARGETS
              ) -> None:
    """Refuse a map naming a campaign column that does not exist (``targets``, q1..qn and the
    robot's coordinate joints)."""
    valid = [*targets, *(f"q{i + 1}" for i in range(robot.n_coordinates)),
             *robot.coordinate_joints]
    for target in settings.column_map:
        if target not in valid:
            raise StiffnessError(f"--map names {target!r}, not a campaign column; "
                                 f"{did_you_mean(target, valid)}")


def read_force(mapper: ColumnMapper) -> np.ndarray:
    """(n, 3) applied forces (files' unit): a rig that loads along some axes only (``fz``
    alone) gives those columns; the others are zero, said once (:class:`DataFileNote`).

    Raises
    ------
    StiffnessError
        No force column at all.
    """
    found = [mapper.find(t) for t in FORCE]
    if all(c is None for c in found):
        mapper.group(FORCE, True)  # refused, naming the columns
    rows = len(next(c for c in found if c is not None).cells)
    zero = [t for t, c in zip(FORCE, found, strict=True) if c is None]
    if zero:
        warnings.warn(f"{', '.join(zero)}: no column in {', '.join(str(f) for f in mapper.files)}"
                      "; taken as 0 (the rig loads along the mapped axes only)", DataFileNote,
                      stacklevel=3)
    return np.column_stack([np.zeros(rows) if c is None else mapper.values(t, c, "force")
                            for t, c in zip(FORCE, found, strict=True)])


def read_block(mapper: ColumnMapper, targets: tuple[str, ...], kind: str, required: bool
           ) -> np.ndarray | None:
    """(n, 3) values of a group of columns, or ``None`` when an optional group is absent."""
    cols = mapper.group(targets, required)
    if cols is None:
        return None
    return np.column_stack([mapper.values(t, c, kind) for t, c in zip(targets, cols,
                                                                        strict=True)])


def _deflections(mapper: ColumnMapper, q_file: np.ndarray
                 ) -> tuple[str, np.ndarray, np.ndarray, np.ndarray]:
    """How the deflections come, the joined rows made campaign rows, the row holding each
    one's unloaded pose, and the deflections (file length unit, file frame)."""
    direct = read_block(mapper, DIRECT, "length", False)
    loaded = read_block(mapper, LOADED, "length", False)
    unloaded = read_block(mapper, UNLOADED, "length", False)
    position = read_block(mapper, POSITION, "length", False)
    given = [label for label, block in (("dx,dy,dz", direct), ("x_loaded..z_unloaded", loaded),
                                        ("x_unloaded..z_unloaded", unloaded),
                                        ("x,y,z", position)) if block is not None]
    if direct is not None and len(given) == 1:
        rows = np.arange(direct.shape[0])
        return "direct (dx, dy, dz)", rows, rows, direct
    if loaded is not None and unloaded is not None and len(given) == 2:
        rows = np.arange(loaded.shape[0])
        return "as loaded and unloaded positions", rows, rows, loaded - unloaded
    if position is not None and len(given) == 1:
        rows, ref = _pairs(mapper, q_file)
        return "as paired loaded/unloaded rows", rows, ref, position[rows] - position[ref]
    raise StiffnessError("the deflections need exactly one of: dx,dy,dz; x_loaded,y_loaded,"
                         "z_loaded with x_unloaded,y_unloaded,z_unloaded; or x,y,z with state "
                         "and pair columns" + (f" (found {'; '.join(given)})" if given
                                               else " (found none)"))


def _pairs(mapper: ColumnMapper, q_file: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Paired rows: each loaded row and its pair's unloaded row (refused: another state, a
    pair with no or two unloaded rows or no loaded one, coordinates that differ)."""
    state = mapper.find("state")
    pair = mapper.find("pair")
    if state is None or pair is None:
        raise StiffnessError("positions x,y,z need a state column (loaded/unloaded) and a pair "
                             "column (the key pairing each loaded row with its unloaded row); "
                             "map them (state=COLUMN,pair=COLUMN)")
    reference: dict[str, int] = {}
    loaded: list[int] = []
    for i, cell in enumerate(state.cells):
        word = cell.strip().lower()
        if word not in STATES:
            raise state.error(i, f"state {cell!r} is neither loaded nor unloaded")
        key = pair.cells[i]
        if word == "loaded":
            loaded.append(i)
        elif key in reference:
            raise pair.error(i, f"pair {key!r} has a second unloaded row (first on line "
                                f"{pair.lines[reference[key]]}); give one per pair")
        else:
            reference[key] = i
    for i in loaded:
        if pair.cells[i] not in reference:
            raise pair.error(i, f"unpaired row: pair {pair.cells[i]!r} has no unloaded row")
        j = reference[pair.cells[i]]
        if np.any(np.abs(q_file[i] - q_file[j]) > SAME_POSE * np.maximum(1.0,
                                                                         np.abs(q_file[j]))):
            raise pair.error(i, f"the loaded row reads other coordinates than its unloaded "
                                f"row (line {pair.lines[j]}); pair rows of one pose")
    lonely = sorted(set(reference.values()) - {reference[pair.cells[i]] for i in loaded})
    if lonely:
        raise pair.error(lonely[0], f"unpaired row: pair {pair.cells[lonely[0]]!r} has no "
                                    "loaded row")
    rows = np.array(loaded, dtype=int)
    return rows, np.array([reference[pair.cells[i]] for i in loaded], dtype=int)


def row_labels(config: Column | None, rows: np.ndarray, q_file: np.ndarray) -> list[str]:
    """The ``config`` cells of ``rows``, else ``P1``, ``P2``, ... per distinct pose (rows'
    coordinates ``q_file`` equal to :data:`SAME_POSE` relative)."""
    if config is not None:
        for i in rows:
            if not config.cells[i].strip():
                raise config.error(int(i), "empty configuration label; label every row")
        return [config.cells[i].strip() for i in rows]
    poses: dict[tuple, str] = {}
    out = []
    for q in q_file:
        key = tuple(float(f"{v:.9g}") for v in q)
        out.append(poses.setdefault(key, f"P{len(poses) + 1}"))
    return out


def tool_rotations(robot: Robot, q: np.ndarray) -> np.ndarray:
    """(m, 3, 3) orientation of the robot's target frame in the base frame at each row's
    coordinates ``q`` (m, n, rad or m): tool-axis vectors times it are base-axis vectors."""
    out = np.empty((q.shape[0], 3, 3))
    seed = None
    for r, coords in enumerate(q):
        full = robot.assemble(coords, seed).q
        update_first_order(robot.model, robot.data, full)
        out[r] = frame_rotation(robot.data, robot.target_frame_id)
        seed = full if robot.loop is not None else None
    return out
