"""Measurement campaigns: a ``campaign.toml`` and the CSV of measurements beside it.

A campaign is the input of :mod:`stiffness.calibration.identify` (and the output of ``stiffness
simulate``)::

    name = "ur5-bench-2024"
    baseline = "enhanced"              # or "conventional": the model to start from
    [robot]
    source = "ur5"                     # shipped robot, example-robot-data name, or a URDF path
                                       # relative to this file
    frame = "tool0"                    # frame carrying the measurement target (optional)
    target_offset = [0.0, 0.0, 100.0]  # target in that frame, in the [units] length (optional)
    compliant_joints = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"]
                                       # springs; the rest rigid (optional)
    loops = "robot.yaml"               # loop declaration, relative to this file (optional)
    fixed_base = false                 # fix a floating or planar base (optional)
    joint_angles = "motor"             # motor | link: what the recorded angles are (optional)
    [units]
    angle = "deg"                      # deg | rad
    force = "N"                        # N | kN
    length = "mm"                      # mm | m | cm | um
    rotation = "deg"                   # unit of rx, ry, rz (optional; default the angle unit)
    moment = "N.mm"                    # unit of mx, my, mz (optional; default force.length)
    [measurement]
    data = "measurements.csv"
    noise_std = 0.005                  # measurement noise std, length unit (optional)
    rotation_noise_std = 0.001         # rotation noise std, rotation unit (optional)

``joint_angles`` says what the recorded joint angles are. ``motor`` (the default): the drives'
encoders, the commanded pose; static preloads (the links' weight, a spring compensator) sag the
unloaded pose by ``(K - K_C)^-1 tau_p``, which enters the geometry. ``link``: the unloaded pose
as measured; preloads set the joints' operating points and tangent stiffness but do not move
the pose.

Omitted optional keys take :func:`stiffness.robot.robot.load_robot`'s defaults (the shipped robot's
frame and compliant joints, else the model's last frame and every coordinate joint). Unknown
keys are errors (a misspelt ``noise_std`` would otherwise be silently ignored).

The CSV has a header and the columns ``config,q1,...,qn,fx,fy,fz,dx,dy,dz``: a configuration
label, the robot's coordinates in its coordinate order (``Robot.coordinate_joints``; angles in
the angle unit, prismatic joints in the length unit), the force applied at the target and the
measured displacement of the target from its unloaded position. The optional groups
``mx,my,mz`` (applied moment, in the ``[units] moment`` unit, default force unit x length
unit) and ``rx,ry,rz`` (measured small rotation vector of the target frame's deflection, base
axes, in the ``[units] rotation`` unit, default the angle unit) may follow, in that order; each
group comes whole (all three columns). ``rotation_noise_std`` needs the rotation columns.
Lines starting with ``#`` and blank lines are skipped; a comment declaring units (as a plan
file's ``# units: angle=deg force=N length=mm``) must agree with ``[units]``. Any other column,
a missing column, or a cell that is not a finite number within +-1e12 is an error naming the
file, the line and the column.

In memory everything is SI (rad, m, N, N.m); the declared units apply only to the files.
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stiffness.errors import (
    DataFileWarning,
    FileFormatError,
    MissingFileError,
    StiffnessError,
    UnknownNameError,
    did_you_mean,
    with_context,
)
from stiffness.files import (
    atomic_write,
    looks_like_path,
    read_text,
    read_toml,
    resolve_path,
    resolve_source,
    staged_folder,
    written_path,
)
from stiffness.mechanics.ik import coordinate_limits
from stiffness.robot.robot import Robot, load_robot
from stiffness.units import ANGLE_UNITS, FORCE_UNITS, LENGTH_UNITS, MOMENT_UNITS

#: Campaign file name inside a campaign folder.
CAMPAIGN_FILE = "campaign.toml"
#: Default measurement file name.
DEFAULT_DATA_FILE = "measurements.csv"
#: Models a campaign may start from.
BASELINES = ("conventional", "enhanced")
#: What a campaign's joint angles are: the drives' encoders (the commanded pose, which static
#: preloads sag) or the unloaded link pose as measured.
JOINT_ANGLES = ("motor", "link")


_FORCE_COLUMNS = ("fx", "fy", "fz")
_DEFLECTION_COLUMNS = ("dx", "dy", "dz")
_MOMENT_COLUMNS = ("mx", "my", "mz")
_ROTATION_COLUMNS = ("rx", "ry", "rz")

_TOML_KEYS = {
    "": {"kind", "name", "baseline", "robot", "units", "measurement"},
    "robot": {"source", "frame", "target_offset", "compliant_joints", "loops", "fixed_base",
              "joint_angles"},
    "units": {"angle", "force", "length", "rotation", "moment"},
    "measurement": {"data", "noise_std", "rotation_noise_std"},
}
_REQUIRED_KEYS = {
    "": ("name", "baseline", "robot", "units", "measurement"),
    "robot": ("source",),
    "units": ("angle", "force", "length"),
    "measurement": ("data",),
}
_KEY_HELP = {
    "name": 'a label for the campaign, e.g. name = "ur5-bench-2024"',
    "baseline": f"the model to start from, one of {', '.join(BASELINES)}",
    "robot": "a [robot] table with at least source",
    "units": "a [units] table with angle, force and length",
    "measurement": "a [measurement] table with data (the CSV file name)",
    "source": "a shipped robot name, an example-robot-data name, or a URDF path relative to "
              "the campaign file",
    "angle": f"one of {', '.join(ANGLE_UNITS)}",
    "force": f"one of {', '.join(FORCE_UNITS)}",
    "length": f"one of {', '.join(LENGTH_UNITS)}",
    "data": 'the measurement CSV beside the campaign file, e.g. data = "measurements.csv"',
}


@dataclass(frozen=True)
class Units:
    """Units of a campaign's files (in memory everything is SI).

    Attributes
    ----------
    angle
        Unit of joint angles and measured rotations: ``deg`` or ``rad``.
    force
        Unit of forces: ``N`` or ``kN``.
    length
        Unit of deflections, the target offset, noise and prismatic coordinates:
        ``mm``, ``m``, ``cm`` or ``um``.
    rotation_unit
        Unit of measured rotations and their noise (``deg`` or ``rad``), or ``None`` for the
        angle unit.
    moment_unit
        Unit of applied moments, force.length (e.g. ``N.mm``, ``N.m``), or ``None`` for the
        force unit times the length unit.
    """

    angle: str = "deg"
    force: str = "N"
    length: str = "mm"
    rotation_unit: str | None = None
    moment_unit: str | None = None

    def __post_init__(self) -> None:
        for kind, value, table in (("angle", self.angle, ANGLE_UNITS),
                                   ("force", self.force, FORCE_UNITS),
                                   ("length", self.length, LENGTH_UNITS),
                                   ("rotation", self.rotation, ANGLE_UNITS),
                                   ("moment", self.moment, MOMENT_UNITS)):
            if value not in table:
                raise UnknownNameError(
                    f"unknown {kind} unit {value!r}; valid {kind} units: {', '.join(table)}",
                    name=str(value), choices=list(table))

    @property
    def angle_to_si(self) -> float:
        """Factor from the angle unit to rad."""
        return ANGLE_UNITS[self.angle]

    @property
    def force_to_si(self) -> float:
        """Factor from the force unit to N."""
        return FORCE_UNITS[self.force]

    @property
    def length_to_si(self) -> float:
        """Factor from the length unit to m."""
        return LENGTH_UNITS[self.length]

    @property
    def moment_to_si(self) -> float:
        """Factor from the moment unit (default force x length) to N.m."""
        return MOMENT_UNITS[self.moment]

    @property
    def moment(self) -> str:
        """Name of the moment unit, e.g. ``N.mm`` (``[units] moment``, default force.length)."""
        return self.moment_unit or f"{self.force}.{self.length}"

    @property
    def rotation(self) -> str:
        """Unit of measured rotations (``[units] rotation``, default the angle unit)."""
        return self.rotation_unit or self.angle

    @property
    def rotation_to_si(self) -> float:
        """Factor from the rotation unit to rad."""
        return ANGLE_UNITS[self.rotation]


@dataclass
class RobotSettings:
    """The ``[robot]`` table of a campaign.

    Attributes
    ----------
    source
        Shipped robot name, example-robot-data name, or URDF path (relative paths are relative
        to the campaign file's folder, or to the working directory for an unsaved campaign).
    frame
        Frame carrying the target, or ``None`` for the robot's default.
    target_offset_m
        Target position in ``frame`` axes (m), shape (3,).
    compliant_joints
        Joints modelled as springs, or ``None`` for the robot's default.
    loops
        Loop declaration overriding the one beside the URDF (a path, relative like
        ``source``), or ``None``.
    fixed_base
        Fix a floating or planar base at its neutral placement (docs/robot-files.md).
    joint_angles
        ``motor`` (the commanded pose; preloads sag it) or ``link`` (the unloaded pose as
        measured), :data:`JOINT_ANGLES`.
    """

    source: str
    frame: str | None = None
    target_offset_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    compliant_joints: tuple[str, ...] | None = None
    loops: str | None = None
    fixed_base: bool = False
    joint_angles: str = "motor"

    def __post_init__(self) -> None:
        self.source = str(self.source)
        offset = np.asarray(self.target_offset_m, dtype=float).reshape(-1)
        if offset.shape != (3,) or not np.all(np.isfinite(offset)):
            raise StiffnessError(
                f"the target offset must be three finite lengths, got {offset.tolist()}"
            )
        self.target_offset_m = offset
        if self.compliant_joints is not None:
            self.compliant_joints = tuple(str(j) for j in self.compliant_joints)
        if self.joint_angles not in JOINT_ANGLES:
            raise StiffnessError(f"joint_angles must be motor (the drives' encoders) or link "
                                 f"(the link pose as measured), got {self.joint_angles!r}")


@dataclass
class Campaign:
    """A measurement campaign, in SI.

    Attributes
    ----------
    name
        Campaign label.
    baseline
        Model to start from: ``conventional`` or ``enhanced``.
    robot_settings
        Robot source, target frame and offset, compliant joints.
    q
        (m, n_coordinates) robot coordinates per row, rad (revolute) or m (prismatic).
    force
        (m, 3) force applied at the target, base axes, N.
    deflection
        (m, 3) measured target displacement from its unloaded position, base axes, m.
    config
        (m,) configuration labels.
    moment
        (m, 3) moment applied at the target, N.m, or ``None``.
    rotation
        (m, 3) measured small rotation vector of the target frame, rad, or ``None``.
    noise_std_m
        Standard deviation of the deflection measurement noise, m, or ``None`` if unknown.
    rotation_noise_std_rad
        Standard deviation of the rotation measurement noise, rad, or ``None`` if unknown.
    units
        Units of the files.
    path
        The ``campaign.toml`` this was read from (or written to), or ``None``.
    data_file
        Name of the measurement CSV, relative to the campaign file.
    lines
        (m,) CSV line number of each row (1-based), or ``None`` for a campaign built in memory.
    """

    name: str
    baseline: str
    robot_settings: RobotSettings
    q: np.ndarray
    force: np.ndarray
    deflection: np.ndarray
    config: tuple[str, ...] | None = None
    moment: np.ndarray | None = None
    rotation: np.ndarray | None = None
    noise_std_m: float | None = None
    units: Units = field(default_factory=Units)
    path: Path | None = None
    data_file: str = DEFAULT_DATA_FILE
    lines: tuple[int, ...] | None = None
    _robot: Robot | None = field(default=None, repr=False, compare=False)
    rotation_noise_std_rad: float | None = None

    def __post_init__(self) -> None:
        if self.baseline not in BASELINES:
            raise UnknownNameError(
                f"unknown baseline {self.baseline!r}; valid baselines: {', '.join(BASELINES)}",
                name=str(self.baseline), choices=BASELINES)
        self.q = np.atleast_2d(np.asarray(self.q, dtype=float))
        m = self.q.shape[0]
        if m == 0:
            raise StiffnessError("a campaign needs at least one measurement row")
        for label in ("force", "deflection", "moment", "rotation"):
            value = getattr(self, label)
            if value is None:
                continue
            arr = np.asarray(value, dtype=float)
            if arr.shape != (m, 3):
                raise StiffnessError(
                    f"campaign {label} must have shape ({m}, 3) like its {m} rows of q, "
                    f"got {np.shape(value)}"
                )
            if not np.all(np.isfinite(arr)):
                raise StiffnessError(f"campaign {label} must be finite numbers")
            setattr(self, label, arr)
        if not np.all(np.isfinite(self.q)):
            raise StiffnessError("campaign coordinates q must be finite numbers")
        if self.config is None:
            self.config = tuple(str(i + 1) for i in range(m))
        self.config = tuple(str(c) for c in self.config)
        for label in self.config:
            if not label.strip() or "\n" in label or "\r" in label:
                raise StiffnessError(f"configuration labels must be non-empty single-line text, "
                                     f"got {label!r}")
        if len(self.config) != m:
            raise StiffnessError(f"campaign needs {m} configuration labels, got {len(self.config)}")
        if self.noise_std_m is not None:
            self.noise_std_m = float(self.noise_std_m)
            if not (math.isfinite(self.noise_std_m) and self.noise_std_m > 0):
                raise StiffnessError(
                    f"noise_std must be a positive finite length, got {self.noise_std_m}"
                )
        if self.rotation_noise_std_rad is not None:
            self.rotation_noise_std_rad = float(self.rotation_noise_std_rad)
            if not (math.isfinite(self.rotation_noise_std_rad)
                    and self.rotation_noise_std_rad > 0):
                raise StiffnessError(f"rotation_noise_std must be a positive finite angle, got "
                                     f"{self.rotation_noise_std_rad}")
            if self.rotation is None:
                raise StiffnessError("rotation_noise_std is given but the campaign has no "
                                     "measured rotations (columns rx, ry, rz); add them or drop "
                                     "rotation_noise_std")
        if not isinstance(self.units, Units):
            raise StiffnessError("campaign units must be a stiffness.calibration.campaign.Units")
        if self.path is not None:
            self.path = Path(self.path)

    @property
    def n_rows(self) -> int:
        """Number of measurement rows."""
        return self.q.shape[0]

    @property
    def wrench(self) -> np.ndarray:
        """(m, 6) applied wrenches [F (N); M (N.m)] per row (moment zero when not given)."""
        moment = np.zeros_like(self.force) if self.moment is None else self.moment
        return np.hstack([self.force, moment])

    def folder(self) -> Path:
        """Folder relative paths are resolved against (the campaign file's, else the cwd)."""
        return self.path.parent if self.path is not None else Path.cwd()

    def resolved_source(self) -> str:
        """Robot source with a relative URDF path resolved against :meth:`folder`."""
        return resolve_source(self.robot_settings.source, self.folder())

    def robot_options(self) -> dict:
        """The robot's ``loops`` (resolved against :meth:`folder`) and ``fixed_base``, as
        keyword arguments of :func:`stiffness.robot.robot.load_robot`."""
        s = self.robot_settings
        return {"loops": None if s.loops is None else resolve_path(s.loops, self.folder()),
                "fixed_base": s.fixed_base}

    def describe_row(self, i: int) -> str:
        """Where row ``i`` comes from, e.g. ``measurements.csv line 7 (config A)``."""
        where = f"row {i + 1}"
        if self.lines is not None:
            data = (self.folder() / self.data_file) if self.path is not None else self.data_file
            where = f"{data} line {self.lines[i]}"
        return f"{where} (config {self.config[i]})"

    def robot(self) -> Robot:
        """The campaign's robot, loaded once (:func:`stiffness.robot.robot.load_robot`).

        Raises
        ------
        StiffnessError
            If the robot cannot be loaded or its coordinate count differs from ``q``'s columns.
        """
        if self._robot is None:
            s = self.robot_settings
            robot = load_robot(self.resolved_source(), frame=s.frame,
                               target_offset=s.target_offset_m,
                               compliant_joints=s.compliant_joints, **self.robot_options())
            if robot.n_coordinates != self.q.shape[1]:
                raise StiffnessError(
                    f"robot {s.source} has {robot.n_coordinates} coordinates "
                    f"({', '.join(robot.coordinate_joints)}) but campaign {self.name!r} has "
                    f"{self.q.shape[1]} q values per row; give one q per coordinate joint"
                )
            self._robot = robot
        return self._robot


# ----------------------------------------------------------------------------------------------
# reading


@dataclass
class TomlFile:
    """A campaign TOML file: its path and text, to point errors at the line of a key."""

    path: Path
    text: str

    def position(self, section: str, key: str | None) -> tuple[int | None, int | None]:
        """1-based line and column of ``key = ...`` in ``[section]`` ("" for the top level),
        of the section header when ``key`` is None, or (None, None) when not found."""
        current = ""
        for number, raw in enumerate(self.text.splitlines(), start=1):
            header = re.match(r"^\s*\[\s*([^\]]+?)\s*\]", raw)
            if header:
                current = header.group(1)
                if key is None and current == section:
                    return number, raw.index("[") + 1
                continue
            if key is not None and current == section:
                match = re.match(rf"^(\s*)(\"?){re.escape(key)}\2\s*=", raw)
                if match:
                    return number, len(match.group(1)) + 1
        return None, None

    def error(self, problem: str, section: str = "", key: str | None = None
              ) -> FileFormatError:
        """A :class:`FileFormatError` at ``key`` of ``[section]`` (or at the section)."""
        line, column = self.position(section, key)
        label = None if key is None else (f"[{section}] {key}" if section else key)
        return FileFormatError(problem, path=self.path, line=line, column=column, field=label)


def _check_keys(table: dict, where: str, toml: TomlFile) -> None:
    section = "" if where == "" else where
    label = "top level" if where == "" else f"[{where}]"
    for key in table:
        if key not in _TOML_KEYS[section]:
            raise toml.error(f"unknown key {key!r} in {label}; "
                             f"{did_you_mean(key, sorted(_TOML_KEYS[section]))}", section, key)
    for key in _REQUIRED_KEYS[section]:
        if key not in table:
            prefix = "" if where == "" else f"[{where}] "
            raise toml.error(f"missing key {prefix}{key}: add {_KEY_HELP[key]}", section)


def typed_value(value, kind: type | tuple, toml: TomlFile, section: str, key: str, what: str):
    if not isinstance(value, kind) or isinstance(value, bool):
        label = f"[{section}] {key}" if section else key
        raise toml.error(f"{label} must be {what}, got {value!r}", section, key)
    return value


def read_campaign_toml(path: Path) -> tuple[dict, TomlFile]:
    toml = TomlFile(path, read_text(path, "campaign file"))
    doc = read_toml(path, "campaign file")
    _check_keys(doc, "", toml)
    for section in ("robot", "units", "measurement"):
        if not isinstance(doc[section], dict):
            raise toml.error(f"{section} must be a [{section}] table, got {doc[section]!r}",
                             "", section)
        _check_keys(doc[section], section, toml)
    return doc, toml


def _campaign_path(path: str | os.PathLike) -> Path:
    p = Path(path)
    if p.is_dir():
        p = p / CAMPAIGN_FILE
    if not p.is_file():
        raise MissingFileError(
            f"campaign {path} not found: give a {CAMPAIGN_FILE} or the folder holding one",
            path=p)
    if p.suffix.lower() == ".csv":
        raise FileFormatError(f"{p.name} is a CSV file, not a campaign; give the {CAMPAIGN_FILE} "
                              "that names it (or the folder holding both)", path=p)
    return p


def _expected_header(n_q: int) -> list[str]:
    return ["config", *(f"q{i}" for i in range(1, n_q + 1)), *_FORCE_COLUMNS,
            *_DEFLECTION_COLUMNS]


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
    expected = _expected_header(k)
    for col, name in enumerate(expected, start=1):
        if col > len(cells):
            raise fail(col, f"column {name!r} is missing; the header must be "
                            f"{','.join(expected)}")
        if cells[col - 1] != name:
            raise fail(col, f"got {cells[col - 1]!r}, expected {name!r}; the header must be "
                            f"{','.join(expected)} (optionally then mx,my,mz and rx,ry,rz)")
    rest = cells[len(expected):]
    groups = {_MOMENT_COLUMNS: "moment", _ROTATION_COLUMNS: "rotation"}
    found = {"moment": False, "rotation": False}
    col = len(expected) + 1
    allowed = [_MOMENT_COLUMNS, _ROTATION_COLUMNS]
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


def _read_rows(data: Path, n_q: int | None, robot_text: str, units: Units, toml_path: Path,
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


def settings_robot(settings: RobotSettings, toml_path: Path) -> Robot:
    """The robot a ``campaign.toml``'s ``[robot]`` names (paths relative to that file).

    Raises
    ------
    StiffnessError
        The robot cannot be loaded (the message starts with the file and ``[robot]``).
    """
    folder = toml_path.parent
    try:
        return load_robot(resolve_source(settings.source, folder), frame=settings.frame,
                          target_offset=settings.target_offset_m,
                          compliant_joints=settings.compliant_joints,
                          loops=None if settings.loops is None else resolve_path(
                              settings.loops, folder),
                          fixed_base=settings.fixed_base)
    except StiffnessError as exc:
        raise with_context(exc, f"{toml_path}: [robot]") from exc


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


def units_section(doc: dict, toml: TomlFile) -> Units:
    """The ``[units]`` table of a campaign.toml, each unit checked (key named on error)."""
    u = doc["units"]
    for key, table in (("angle", ANGLE_UNITS), ("force", FORCE_UNITS),
                       ("length", LENGTH_UNITS)):
        value = u[key]
        if value not in table:
            raise toml.error(f"[units] {key} = {value!r} is not a known {key} unit; valid "
                             f"{key} units: {', '.join(table)}", "units", key)
    for key, table in (("rotation", ANGLE_UNITS), ("moment", MOMENT_UNITS)):
        value = u.get(key)
        if value is not None and value not in table:
            raise toml.error(f"[units] {key} = {value!r} is not a known {key} unit; valid "
                             f"{key} units: {', '.join(table)}; omit it for the default",
                             "units", key)
    return Units(u["angle"], u["force"], u["length"], u.get("rotation"), u.get("moment"))


def robot_section(doc: dict, toml: TomlFile, units: Units) -> RobotSettings:
    """The ``[robot]`` table of a campaign.toml, each key checked (key named on error)."""
    r = doc["robot"]
    source = typed_value(r["source"], str, toml, "robot", "source", "a string")
    frame = r.get("frame")
    if frame is not None:
        typed_value(frame, str, toml, "robot", "frame", "a frame name (string)")
    offset = r.get("target_offset", [0.0, 0.0, 0.0])
    if (not isinstance(offset, list) or len(offset) != 3
            or not all(isinstance(v, int | float) and not isinstance(v, bool)
                       and math.isfinite(v) and abs(v) <= MAX_CELL for v in offset)):
        raise toml.error(f"[robot] target_offset must be three numbers in {units.length}, "
                         f"finite and within +-{MAX_CELL:.0e}, got {offset!r}", "robot",
                         "target_offset")
    joints = r.get("compliant_joints")
    if joints is not None and (not isinstance(joints, list) or not joints
                               or not all(isinstance(j, str) for j in joints)):
        raise toml.error(f"[robot] compliant_joints must be a non-empty list of joint names, "
                         f"got {joints!r}", "robot", "compliant_joints")
    loops = r.get("loops")
    if loops is not None:
        typed_value(loops, str, toml, "robot", "loops", "a loop-declaration path (string)")
    fixed_base = r.get("fixed_base", False)
    if not isinstance(fixed_base, bool):
        raise toml.error(f"[robot] fixed_base must be true or false, got {fixed_base!r}",
                         "robot", "fixed_base")
    joint_angles = r.get("joint_angles", "motor")
    if joint_angles not in JOINT_ANGLES:
        raise toml.error(f"[robot] joint_angles must be \"motor\" (the drives' encoders) or "
                         f"\"link\" (the link pose as measured), got {joint_angles!r}", "robot",
                         "joint_angles")
    return RobotSettings(source, frame, np.array(offset, dtype=float) * units.length_to_si,
                         tuple(joints) if joints is not None else None, loops, fixed_base,
                         joint_angles)


def noise_section(doc: dict, toml: TomlFile, units: Units) -> float | None:
    """``[measurement] noise_std`` in the file's length unit, or None (key named on error)."""
    m = doc["measurement"]
    noise = m.get("noise_std")
    if noise is not None:
        typed_value(noise, int | float, toml, "measurement", "noise_std",
               f"a positive number in {units.length}")
        if not (math.isfinite(noise) and noise > 0):
            raise toml.error(f"[measurement] noise_std must be a positive finite number in "
                             f"{units.length}, got {noise!r}; omit it if unknown",
                             "measurement", "noise_std")
    return noise


#: Campaign kinds: loaded-minus-unloaded deflections (the default) or absolute marker poses.
CAMPAIGN_KINDS = ("deflections", "poses")


class CampaignKindError(StiffnessError):
    """A campaign of another kind than the reader takes (``kind`` names the one given)."""

    def __init__(self, message: str, kind: str) -> None:
        super().__init__(message)
        self.kind = kind
        self.choices = list(CAMPAIGN_KINDS)


def campaign_kind(path: str | os.PathLike) -> str:
    """The ``kind`` of a campaign (``deflections`` when the key is absent).

    Raises
    ------
    StiffnessError
        The file cannot be read, or ``kind`` is not one of :data:`CAMPAIGN_KINDS`.
    """
    toml_path = _campaign_path(path)
    doc = read_toml(toml_path, "campaign file")
    kind = doc.get("kind", "deflections")
    if kind not in CAMPAIGN_KINDS:
        toml = TomlFile(toml_path, read_text(toml_path, "campaign file"))
        raise toml.error(f"kind = {kind!r} is not a campaign kind; valid kinds: "
                         f"{', '.join(CAMPAIGN_KINDS)}", "", "kind")
    return str(kind)


def load_campaign(path: str | os.PathLike) -> Campaign:
    """Read and validate a campaign; the result is in SI and carries its loaded robot.

    Parameters
    ----------
    path
        A ``campaign.toml`` or the folder holding one.

    Returns
    -------
    Campaign
        Rows in SI (rad/m, N, N.m, m); :meth:`Campaign.robot` returns the robot loaded here.

    Raises
    ------
    StiffnessError
        Missing file, invalid TOML, missing or unknown keys, unknown units or baseline, robot
        that cannot be loaded, or a CSV with missing/extra/misnamed columns, a wrong number of
        q columns, a non-numeric, NaN or implausibly large cell, or a units comment that
        disagrees with ``[units]`` (file, line and column named).

    Warns
    -----
    DataFileWarning
        Rows beyond the joint limits, or one label on rows at different coordinates
        (:func:`coordinates_in_si`).
    """
    toml_path = _campaign_path(path)
    kind = campaign_kind(toml_path)
    if kind != "deflections":
        raise CampaignKindError(f"{toml_path}: kind = {kind!r} is a pose campaign (absolute "
                                "marker positions); read it with load_pose_campaign, or "
                                "give a deflection campaign", kind=kind)
    doc, toml = read_campaign_toml(toml_path)
    name = typed_value(doc["name"], str, toml, "", "name", "a string")
    baseline = typed_value(doc["baseline"], str, toml, "", "baseline", "a string")
    if baseline not in BASELINES:
        raise toml.error(f"unknown baseline {baseline!r}; valid baselines: "
                         f"{', '.join(BASELINES)}", "", "baseline")
    units = units_section(doc, toml)
    settings = robot_section(doc, toml, units)
    source = settings.source
    m = doc["measurement"]
    data_name = typed_value(m["data"], str, toml, "measurement", "data", "a file name")
    noise = noise_section(doc, toml, units)
    rot_noise = m.get("rotation_noise_std")
    if rot_noise is not None:
        typed_value(rot_noise, int | float, toml, "measurement", "rotation_noise_std",
               f"a positive number in {units.rotation}")
        if not (math.isfinite(rot_noise) and rot_noise > 0):
            raise toml.error(f"[measurement] rotation_noise_std must be a positive finite number "
                             f"in {units.rotation}, got {rot_noise!r}; omit it if unknown",
                             "measurement", "rotation_noise_std")
    data_path = toml_path.parent / data_name

    robot = settings_robot(settings, toml_path)

    robot_text = f"robot {source} ({', '.join(robot.coordinate_joints)})"
    k, has_moment, has_rotation, labels, values, lines = _read_rows(
        data_path, robot.n_coordinates, robot_text, units, toml_path, robot.coordinate_joints)
    q = coordinates_in_si(robot, values[:, :k], units, labels, lines, data_path)
    col = k
    force = values[:, col: col + 3] * units.force_to_si
    deflection = values[:, col + 3: col + 6] * units.length_to_si
    col += 6
    moment = rotation = None
    if has_moment:
        moment = values[:, col: col + 3] * units.moment_to_si
        col += 3
    if has_rotation:
        rotation = values[:, col: col + 3] * units.rotation_to_si
    elif rot_noise is not None:
        raise toml.error(f"[measurement] rotation_noise_std is given but {data_name} has no "
                         "rotation columns rx,ry,rz; add them after dz (or after mz) or drop "
                         "rotation_noise_std", "measurement", "rotation_noise_std")
    if units.moment_unit is not None and not has_moment:
        raise toml.error(f"[units] moment is given but {data_name} has no moment columns "
                         "mx,my,mz; add them after dz or drop the key", "units", "moment")
    if units.rotation_unit is not None and not has_rotation:
        raise toml.error(f"[units] rotation is given but {data_name} has no rotation columns "
                         "rx,ry,rz; add them after dz (or after mz) or drop the key",
                         "units", "rotation")
    return Campaign(
        name=name, baseline=baseline, robot_settings=settings, q=q, force=force,
        deflection=deflection, config=tuple(labels), moment=moment, rotation=rotation,
        noise_std_m=None if noise is None else float(noise) * units.length_to_si, units=units,
        path=toml_path, data_file=data_name, lines=tuple(lines), _robot=robot,
        rotation_noise_std_rad=(None if rot_noise is None
                                else float(rot_noise) * units.rotation_to_si),
    )


# ----------------------------------------------------------------------------------------------
# writing


def _toml_string(text: str) -> str:
    out = ['"']
    for ch in text:
        if ch in '"\\':
            out.append("\\" + ch)
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04X}")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)


def _num(x: float) -> str:
    return repr(float(x))


def write_campaign(campaign_like, folder: str | os.PathLike) -> Path:
    """Write a campaign as ``campaign.toml`` plus its CSV in ``folder``, published as one folder.

    The folder is built beside ``folder`` and renamed over it
    (:func:`stiffness.files.staged_folder`; other files already in ``folder``, such as the
    robot's URDF, are kept), so a reader never sees a half-written campaign.

    Parameters
    ----------
    campaign_like
        A :class:`Campaign`, or any object with its attributes (``name``, ``baseline``,
        ``robot_settings``, ``q``, ``force``, ``deflection`` and optionally ``config``,
        ``moment``, ``rotation``, ``noise_std_m``, ``units``, ``data_file``, ``path``). Values
        are SI; they are written in the campaign's units (default deg, N, mm).
    folder
        Destination folder, created if missing.

    Returns
    -------
    Path
        The written ``campaign.toml``.

    Raises
    ------
    StiffnessError
        If the campaign is inconsistent (shapes, units, baseline), or its robot cannot be
        loaded (it tells angle coordinates from prismatic lengths).
    """
    c = campaign_like
    if not isinstance(c, Campaign):
        c = Campaign(
            name=c.name, baseline=c.baseline, robot_settings=c.robot_settings, q=c.q,
            force=c.force, deflection=c.deflection, config=getattr(c, "config", None),
            moment=getattr(c, "moment", None), rotation=getattr(c, "rotation", None),
            noise_std_m=getattr(c, "noise_std_m", None), units=getattr(c, "units", Units()),
            path=getattr(c, "path", None),
            data_file=getattr(c, "data_file", DEFAULT_DATA_FILE),
            _robot=getattr(c, "_robot", None),
            rotation_noise_std_rad=getattr(c, "rotation_noise_std_rad", None),
        )
    folder = Path(folder)
    u = c.units
    data_name = Path(c.data_file).name or DEFAULT_DATA_FILE
    n_q = c.q.shape[1]
    prismatic = prismatic_mask(c.robot())
    q_out = c.q.copy()
    q_out[:, ~prismatic] /= u.angle_to_si
    q_out[:, prismatic] /= u.length_to_si

    header = _expected_header(n_q)
    blocks = [q_out, c.force / u.force_to_si, c.deflection / u.length_to_si]
    if c.moment is not None:
        header += list(_MOMENT_COLUMNS)
        blocks.append(c.moment / u.moment_to_si)
    if c.rotation is not None:
        header += list(_ROTATION_COLUMNS)
        blocks.append(c.rotation / u.rotation_to_si)
    table = np.hstack(blocks)
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(header)
    for label, row in zip(c.config, table, strict=True):
        writer.writerow([label, *(_num(v) for v in row)])
    with staged_folder(folder, keep_others=True) as stage:  # published by one rename
        atomic_write(stage / data_name, out.getvalue())
        atomic_write(stage / CAMPAIGN_FILE, campaign_toml(c, folder))
    return folder / CAMPAIGN_FILE


def campaign_toml(c: Campaign, folder: str | os.PathLike) -> str:
    """The ``campaign.toml`` text of ``c`` written into ``folder`` (a relative URDF source is
    made relative to ``folder``); its ``[measurement] data`` is ``c.data_file``'s name."""
    folder = Path(folder)
    u = c.units
    s = c.robot_settings
    source = s.source
    if looks_like_path(source):
        resolved = Path(c.resolved_source())
        try:
            source = os.path.relpath(resolved, folder.resolve())
        except ValueError:  # another drive on Windows
            source = str(resolved)
        source = Path(source).as_posix()

    data_name = Path(c.data_file).name or DEFAULT_DATA_FILE
    toml = [
        "# Measurement campaign (see stiffness/campaign.py for the format).",
        f"name = {_toml_string(c.name)}",
        f"baseline = {_toml_string(c.baseline)}",
        "",
        "[robot]",
        f"source = {_toml_string(source)}",
    ]
    if s.frame is not None:
        toml.append(f"frame = {_toml_string(s.frame)}")
    offset = ", ".join(_num(v / u.length_to_si) for v in s.target_offset_m)
    toml.append(f"target_offset = [{offset}]")
    if s.compliant_joints is not None:
        joints = ", ".join(_toml_string(j) for j in s.compliant_joints)
        toml.append(f"compliant_joints = [{joints}]")
    if s.loops is not None:
        loops = written_path(resolve_path(s.loops, c.folder()), folder)
        toml.append(f"loops = {_toml_string(loops)}")
    if s.fixed_base:
        toml.append("fixed_base = true")
    toml.append(f"joint_angles = {_toml_string(s.joint_angles)}")
    toml += [
        "",
        "[units]",
        f"angle = {_toml_string(u.angle)}",
        f"force = {_toml_string(u.force)}",
        f"length = {_toml_string(u.length)}",
        *([f"rotation = {_toml_string(u.rotation_unit)}"]
          if u.rotation_unit is not None and c.rotation is not None else []),
        *([f"moment = {_toml_string(u.moment_unit)}"]
          if u.moment_unit is not None and c.moment is not None else []),
        "",
        "[measurement]",
        f"data = {_toml_string(data_name)}",
    ]
    if c.noise_std_m is not None:
        toml.append(f"noise_std = {_num(c.noise_std_m / u.length_to_si)}")
    if c.rotation_noise_std_rad is not None:
        toml.append(f"rotation_noise_std = {_num(c.rotation_noise_std_rad / u.rotation_to_si)}")
    return "\n".join(toml) + "\n"
