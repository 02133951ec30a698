"""Measurement plans: the rows a rig should measure, in the campaign's measurement format.

A plan is a campaign without its measured columns: a CSV with the header
``config,q1,...,qn,fx,fy,fz`` (a configuration label, the coordinates in the robot's coordinate
order, the force to apply at the target, base axes), in the units of the campaign format
(:mod:`stiffness.calibration.campaign`). Written as

* a single file ``PLAN.csv``: its first line is a comment declaring the units, e.g.
  ``# measurement plan; units: angle=deg force=N length=mm`` (``angle = rad, force = kN`` and
  other spacings read too; a comment that mentions units but cannot be read is an error; no
  comment at all reads as deg, N, mm with a :class:`~stiffness.errors.DataFileWarning`);
* a folder: ``campaign.toml`` (robot, target, compliant joints, units, noise) and the CSV it
  names (``plan.csv``). Once the rig has added the measured ``dx,dy,dz`` columns, the folder is a
  campaign :func:`stiffness.calibration.campaign.load_campaign` reads.

A campaign's own CSV (with ``dx,dy,dz``) reads as a plan too; its measured columns are ignored.
In memory everything is SI (rad, m, N).
"""

from __future__ import annotations

import csv
import io
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stiffness.calibration.campaign import Campaign
from stiffness.calibration.campaign_toml import (
    CAMPAIGN_FILE,
    RobotSettings,
    measurement_noise,
    read_campaign_toml,
    robot_section,
    settings_robot,
    units_section,
)
from stiffness.calibration.campaign_writer import campaign_toml
from stiffness.calibration.coordinate_columns import (
    canonical_header,
    is_blank_row,
    trim_empty_columns,
)
from stiffness.calibration.measurements import (
    DEFLECTION_COLUMNS,
    FORCE_COLUMNS,
    PLAN_COMMENT,
    UNITS_COMMENT_EXAMPLE,
    check_units_comment,
    coordinates_in_si,
    parse_number,
    prismatic_mask,
    read_units_comment,
)
from stiffness.elastic.effects.geometry import cached_robot
from stiffness.errors import (
    DataFileWarning,
    FileFormatError,
    MissingFileError,
    OutputError,
    StiffnessError,
)
from stiffness.files import (
    FILE_SUFFIXES,
    atomic_write,
    check_csv_header,
    csv_cells,
    number_text,
    read_text,
    refuse_foreign_folder,
    resolve_path,
    resolve_source,
    staged_folder,
)
from stiffness.robot.calibration import robot_identity
from stiffness.robot.robot import Robot
from stiffness.units import Units

#: Name of the plan CSV inside a plan folder.
PLAN_FILE = "plan.csv"


@dataclass
class Plan:
    """Rows to measure, SI.

    Attributes
    ----------
    q
        (m, n_coordinates) coordinates (rad, m).
    force
        (m, 3) force to apply at the target, base axes (N).
    config
        (m,) configuration labels.
    units
        Units of the files.
    robot_settings
        Robot, target and compliant joints (``None`` for a bare CSV: give the robot).
    name, baseline
        Campaign name and baseline written with a folder.
    noise_std_m
        Declared measurement noise (m), written with a folder, or ``None``.
    path
        The file read (a CSV, or a folder's ``campaign.toml``), or ``None``.
    """

    q: np.ndarray
    force: np.ndarray
    config: tuple[str, ...]
    units: Units = field(default_factory=Units)
    robot_settings: RobotSettings | None = None
    name: str = "plan"
    baseline: str = "enhanced"
    noise_std_m: float | None = None
    path: Path | None = None

    @property
    def n_rows(self) -> int:
        """Number of rows."""
        return self.q.shape[0]

    def resolved_source(self) -> str | None:
        """Robot source with a relative URDF path resolved against the plan's folder."""
        if self.robot_settings is None:
            return None
        folder = self.path.parent if self.path is not None else Path.cwd()
        return resolve_source(self.robot_settings.source, folder)


def _header(n_q: int) -> list[str]:
    return ["config", *(f"q{i}" for i in range(1, n_q + 1)), "fx", "fy", "fz"]


def plan_csv(plan: Plan, robot: Robot) -> str:
    """The plan's CSV text (units comment, header, rows in the plan's units)."""
    u = plan.units
    prismatic = prismatic_mask(robot)
    q = plan.q.copy()
    q[:, ~prismatic] /= u.angle_to_si
    q[:, prismatic] /= u.length_to_si
    out = io.StringIO()
    out.write(f"{PLAN_COMMENT}; units: angle={u.angle} force={u.force} length={u.length}\n")
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(_header(plan.q.shape[1]))
    for label, qi, fi in zip(plan.config, q, plan.force / u.force_to_si, strict=True):
        writer.writerow([label, *(number_text(v) for v in (*qi, *fi))])
    return out.getvalue()


def check_plan_target(out: str | os.PathLike) -> None:
    """Refuse a plan target that holds something else: a ``.csv`` file that is not a plan (a
    campaign's measurements), or a folder whose ``campaign.toml`` is not a plan folder's
    (:func:`stiffness.files.refuse_foreign_folder`); or a name of another kind of file
    (``plan.json``), which would be a folder.

    Raises
    ------
    OutputError
        Writing the plan there would overwrite measurements or a campaign.
    """
    out = Path(out)
    if out.suffix.lower() in set(FILE_SUFFIXES) - {".csv"} and not out.is_dir():  # plan.json
        raise OutputError(f"--out {out}: a plan is a CSV file (a name ending in .csv) or a "
                          f"folder (campaign.toml and plan.csv); give e.g. --out "
                          f"{out.with_suffix('.csv')} or --out {out.with_suffix('')}", path=out)
    if out.suffix.lower() != ".csv":
        refuse_foreign_folder(out, PLAN_FILE, "plan folder", writes=(CAMPAIGN_FILE,))
        return
    try:
        with out.open("rb") as file:
            first = file.readline(200)
    except OSError:  # absent (or unreadable: the write says so)
        return
    if first and not first.startswith(PLAN_COMMENT.encode()):
        raise OutputError(f"{out} exists and is not a plan written by stiffness design (its "
                          f"first line is not '{PLAN_COMMENT}...'): writing the plan there "
                          "would overwrite it; choose a new file name", path=out)


def write_plan(plan: Plan, robot: Robot, out: str | os.PathLike) -> Path:
    """Write ``plan`` to ``out``: a ``.csv`` file, or a folder (``campaign.toml`` and
    :data:`PLAN_FILE`). Each file is written atomically. Returns the CSV written.

    Raises
    ------
    StiffnessError
        If a folder is asked for a plan without robot settings.
    """
    out = Path(out)
    check_plan_target(out)
    if out.suffix.lower() == ".csv":
        return atomic_write(out, plan_csv(plan, robot))
    if plan.robot_settings is None:
        raise StiffnessError("a plan folder needs the robot settings for its campaign.toml")
    stub = Campaign(name=plan.name, baseline=plan.baseline, robot_settings=plan.robot_settings,
                    q=plan.q, force=plan.force, deflection=np.zeros_like(plan.force),
                    config=plan.config, noise_std_m=plan.noise_std_m, units=plan.units,
                    data_file=PLAN_FILE, _robot=robot)
    with staged_folder(out, keep_others=True) as folder:  # published by one rename
        atomic_write(folder / PLAN_FILE, plan_csv(plan, robot))
        atomic_write(folder / CAMPAIGN_FILE, campaign_toml(stub, out))
    return out / PLAN_FILE


def _settings(toml_path: Path) -> tuple[dict, Units, RobotSettings, float | None]:
    doc, toml = read_campaign_toml(toml_path)
    units = units_section(doc, toml)
    settings = robot_section(doc, toml, units)
    noise = measurement_noise(doc, toml, "noise_std", units.length)
    return doc, units, settings, None if noise is None else float(noise) * units.length_to_si


def _plan_lines(text: str, data: Path, toml_path: Path | None, units: Units
                ) -> tuple[list[str] | None, int, list[tuple[int, list[str]]], Units, int | None]:
    """The plan CSV's lines: its header (None if none) and header line, the rows with their
    line numbers, the units (a units comment's, checked against ``campaign.toml``'s or an
    earlier comment's) and the line of the comment that declared them (or None)."""
    header, header_line, rows, declared_line = None, 0, [], None
    for number, raw in enumerate(text.splitlines(), start=1):
        stripped = raw.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            declared = read_units_comment(stripped, data, number)
            if declared is None:
                continue
            if toml_path is not None or declared_line:
                check_units_comment(declared, units, toml_path or f"line {declared_line}",
                                    data, number)
            units, declared_line = declared, number
            continue
        cells = csv_cells(raw, data, number)
        if is_blank_row(cells):  # ',,,,': a spreadsheet's empty row
            continue
        if header is None:
            header = canonical_header(cells, ["config", *FORCE_COLUMNS, *DEFLECTION_COLUMNS])
            header_line = number
            check_csv_header(header, data, number)
        else:
            rows.append((number, cells))
    if header is not None:  # a comma ending every line: no column
        header, trimmed = trim_empty_columns(header, [cells for _, cells in rows])
        rows = [(number, cells) for (number, _), cells in zip(rows, trimmed, strict=True)]
    return header, header_line, rows, units, declared_line


def _check_header(header: list[str] | None, header_line: int, robot: Robot, data: Path
                  ) -> tuple[list[str], int]:
    """Refuse a missing header or one other than ``config,q1..qn,fx,fy,fz`` (optionally
    then ``dx,dy,dz``), naming the first wrong column; returns it and the number of columns
    read."""
    n_q = robot.n_coordinates
    expected = _header(n_q)
    if header is None:
        raise FileFormatError(f"the plan is empty; it needs the header {','.join(expected)} "
                              "and one row per measurement", path=data)
    width = len(expected)
    if header[:width] != expected or header[width:] not in ([], ["dx", "dy", "dz"]):
        pairs = enumerate(zip(header, expected, strict=False))
        bad = next((i for i, (a, b) in pairs if a != b), min(len(header), width))
        got = repr(header[bad]) if bad < len(header) else "nothing"
        raise FileFormatError(
            f"got {got}; the plan header for {robot.title} ({n_q} coordinates) is "
            f"{','.join(expected)} (optionally then dx,dy,dz, which are ignored)", path=data,
            line=header_line, column=bad + 1)
    return header, width


def read_plan(path: str | os.PathLike, robot: Robot | None = None) -> tuple[Plan, Robot]:
    """Read a plan (a CSV, a folder holding ``campaign.toml``, or that file) and its robot.

    Parameters
    ----------
    path
        The plan.
    robot
        The robot of a bare CSV (a folder names its own; ``robot`` then overrides it).

    Raises
    ------
    MissingFileError
        No such plan.
    FileFormatError
        A header other than ``config,q1..qn,fx,fy,fz`` (optionally then ``dx,dy,dz``), a
        non-numeric or implausibly large cell, a units comment that cannot be read or that
        disagrees with ``campaign.toml`` (file, line and column named).
    StiffnessError
        A bare CSV without a robot.

    Warns
    -----
    DataFileWarning
        A bare CSV without a units comment (read as deg, N, mm), rows beyond the joint limits,
        or one label on rows at different coordinates.
    """
    p = Path(path)
    if not p.exists():
        raise MissingFileError(f"plan {path} not found: give PLAN.csv, or a folder holding "
                               f"{CAMPAIGN_FILE} and its plan CSV", path=p)
    toml_path = p / CAMPAIGN_FILE if p.is_dir() else (p if p.suffix == ".toml" else None)
    doc, units, settings, noise = None, Units(), None, None
    if toml_path is not None:
        if not toml_path.is_file():
            raise MissingFileError(f"plan {path} not found: give PLAN.csv, or a folder holding "
                                   f"{CAMPAIGN_FILE} and its plan CSV", path=toml_path)
        doc, units, settings, noise = _settings(toml_path)
        data = toml_path.parent / doc["measurement"]["data"]
        if robot is None:
            robot = settings_robot(settings, toml_path)
    else:
        data = p
    if robot is None:
        raise StiffnessError(f"plan {path} is a bare CSV: give its robot (--robot ...)")
    header, header_line, rows, units, declared_line = _plan_lines(
        read_text(data, "plan"), data, toml_path, units)
    n_q = robot.n_coordinates
    header, width = _check_header(header, header_line, robot, data)
    if not rows:
        raise FileFormatError("no rows after the header", path=data, line=header_line + 1)
    labels, values = [], []
    for number, cells in rows:
        if len(cells) != len(header):
            raise FileFormatError(f"the row has {len(cells)} cells but the header has "
                                  f"{len(header)}", path=data, line=number)
        label = cells[0].strip()
        if not label:
            raise FileFormatError("the configuration label is empty; give a label such as P1",
                                  path=data, line=number, column=1, field="config")
        labels.append(label)
        values.append([parse_number(c, data, number, j, header[j - 1])
                       for j, c in enumerate(cells[1:width], start=2)])
    if toml_path is None and declared_line is None:
        warnings.warn(f"{data}: the plan declares no units; read as angle=deg force=N "
                      f"length=mm (start it with '{UNITS_COMMENT_EXAMPLE}' to say so)",
                      DataFileWarning, stacklevel=2)
    arr = np.array(values, dtype=float)
    q = coordinates_in_si(robot, arr[:, :n_q], units, labels, [n for n, _ in rows], data)
    plan = Plan(q=q, force=arr[:, n_q:] * units.force_to_si, config=tuple(labels), units=units,
                robot_settings=settings, noise_std_m=noise, path=toml_path or data)
    if doc is not None:
        plan.name, plan.baseline = str(doc["name"]), str(doc["baseline"])
    return plan, robot


@dataclass
class PlannedRobot:
    """The robot a plan is simulated on: the given robot arguments, the plan folder's
    ``campaign.toml`` filling those not given (:func:`plan_and_robot`)."""

    source: str | None
    frame: str | None
    target_offset_m: list[float] | None
    compliant_joints: list[str] | None
    loops: str | None = None
    fixed_base: bool = False


def plan_and_robot(path: str | os.PathLike, robot: PlannedRobot) -> tuple[Plan, PlannedRobot]:
    """The plan at ``path`` and its robot: ``robot`` as given when it names a source (the
    plan's columns are checked against it), else the plan folder's settings filling what
    ``robot`` leaves out (a bare CSV then needs a source: :func:`read_plan` refuses it).

    Raises
    ------
    StiffnessError
        As :func:`read_plan`; a plan folder of another robot than ``robot``'s source.
    """
    declared = None
    if robot.source is not None:
        declared = cached_robot(robot.source, robot.frame, None if robot.target_offset_m is None
                                else tuple(robot.target_offset_m), None
                                if robot.compliant_joints is None
                                else tuple(robot.compliant_joints), None if robot.loops is None
                                else str(Path(robot.loops).resolve()), robot.fixed_base)
    plan, _ = read_plan(path, declared)
    s = plan.robot_settings
    if robot.source is not None and s is not None and \
            robot_identity(str(robot.source)) != robot_identity(plan.resolved_source() or s.source):
        raise StiffnessError(f"plan {path} was designed for robot {s.source!r}, not "
                             f"{str(robot.source)!r}: its poses are that robot's; drop the "
                             "robot (the plan folder names it) or design a plan for this one")
    if robot.source is None and s is not None:
        robot = PlannedRobot(
            plan.resolved_source(), robot.frame or s.frame,
            robot.target_offset_m if robot.target_offset_m is not None
            else [float(v) for v in s.target_offset_m],
            robot.compliant_joints if robot.compliant_joints is not None
            else (None if s.compliant_joints is None else list(s.compliant_joints)),
            robot.loops or (None if s.loops is None or plan.path is None
                            else resolve_path(s.loops, plan.path.parent)),
            robot.fixed_base or s.fixed_base)
    return plan, robot
