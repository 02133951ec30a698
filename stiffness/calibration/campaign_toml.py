"""``campaign.toml``: its keys and their types, the ``[units]``, ``[robot]`` and
``[measurement]`` sections read into SI, and the robot a ``[robot]`` table names.
"""


from __future__ import annotations

import math
import os
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from types import UnionType

import numpy as np

from stiffness.calibration.coordinate_columns import check_fixed_table
from stiffness.errors import (
    FileFormatError,
    MissingFileError,
    StiffnessError,
    did_you_mean,
    with_context,
)
from stiffness.files import (
    read_text,
    read_toml,
    resolve_path,
    resolve_source,
)
from stiffness.robot.robot import Robot, load_robot
from stiffness.units import (
    ANGLE_UNITS,
    FORCE_UNITS,
    LENGTH_UNITS,
    MAX_CELL,
    MOMENT_UNITS,
    Units,
    three_numbers,
)

#: Campaign file name inside a campaign folder.
CAMPAIGN_FILE = "campaign.toml"
#: Default measurement file name.
DEFAULT_DATA_FILE = "measurements.csv"
#: Models a campaign may start from.
BASELINES = ("conventional", "enhanced")
#: What a campaign's joint angles are: the drives' encoders (the commanded pose, which static
#: preloads sag) or the unloaded link pose as measured.
JOINT_ANGLES = ("motor", "link")

_TOML_KEYS = {
    "": {"kind", "name", "baseline", "robot", "units", "measurement"},
    "robot": {"source", "frame", "target_offset", "compliant_joints", "loops", "fixed_base",
              "joint_angles", "fixed"},
    "units": {"angle", "force", "length", "rotation", "moment"},
    "measurement": {"data", "noise_std", "rotation_noise_std", "noise_std_rotation"},
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
    fixed
        Coordinates the measurement CSV has no column for, held at these values, in the
        campaign's angle unit (its length unit for a prismatic joint); the others without a
        column are held at the robot's reference configuration.
    """

    source: str
    frame: str | None = None
    target_offset_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    compliant_joints: tuple[str, ...] | None = None
    loops: str | None = None
    fixed_base: bool = False
    joint_angles: str = "motor"
    fixed: dict[str, float] = field(default_factory=dict)

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

    def load(self, folder: Path) -> Robot:
        """The robot these settings name, relative paths against ``folder``
        (:func:`stiffness.robot.robot.load_robot`)."""
        return load_robot(resolve_source(self.source, folder), frame=self.frame,
                          target_offset=self.target_offset_m,
                          compliant_joints=self.compliant_joints, fixed_base=self.fixed_base,
                          loops=None if self.loops is None else resolve_path(self.loops, folder))


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


def _check_keys(table: dict, section: str, toml: TomlFile) -> None:
    check_table_keys(table, section, toml, _TOML_KEYS[section], _REQUIRED_KEYS[section],
                     lambda key, label: f"missing key {'' if section == '' else f'[{section}] '}"
                                        f"{key}: add {_KEY_HELP[key]}")


def check_table_keys(table: dict, section: str, toml: TomlFile, valid: set[str],
                     required: tuple[str, ...], missing: Callable[[str, str], str],
                     kind: str = "") -> None:
    """Refuse an unknown key of ``[section]`` ("" the top level) with a did-you-mean, and a
    missing required one with ``missing(key, label)``; ``kind`` follows the table's label in
    the unknown-key message (e.g. " of a pose campaign")."""
    label = "top level" if section == "" else f"[{section}]"
    for key in table:
        if key not in valid:
            raise toml.error(f"unknown key {key!r} in {label}{kind}; "
                             f"{did_you_mean(key, sorted(valid))}", section, key)
    for key in required:
        if key not in table:
            raise toml.error(missing(key, label), section)


def typed_value(value, kind: type | UnionType | tuple, toml: TomlFile, section: str, key: str,
                what: str):
    if not isinstance(value, kind) or isinstance(value, bool):
        label = f"[{section}] {key}" if section else key
        raise toml.error(f"{label} must be {what}, got {value!r}", section, key)
    return value


def read_campaign_toml(path: Path, check: Callable[[dict, str, TomlFile], None] | None = None,
                       sections: tuple[str, ...] = ("robot", "units", "measurement")
                       ) -> tuple[dict, TomlFile]:
    """A campaign file's tables, each key checked by ``check(table, section, toml)``
    (default: a deflection campaign's keys) at the top level and in each of ``sections``
    present, which must be tables."""
    check = check or _check_keys
    toml = TomlFile(path, read_text(path, "campaign file"))
    doc = read_toml(path, "campaign file")
    check(doc, "", toml)
    for section in (s for s in sections if s in doc):
        if not isinstance(doc[section], dict):
            raise toml.error(f"{section} must be a [{section}] table, got {doc[section]!r}",
                             "", section)
        check(doc[section], section, toml)
    return doc, toml


def campaign_toml_path(path: str | os.PathLike) -> Path:
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
    if p.suffix.lower() == ".json":
        raise FileFormatError("a JSON file (a model file?), not a campaign; give a "
                              f"{CAMPAIGN_FILE} or the folder holding one (stiffness validate "
                              "takes MODEL, then CAMPAIGN)", path=p)
    return p


def units_section(doc: dict, toml: TomlFile) -> Units:
    """The ``[units]`` table of a campaign.toml, each unit checked (key named on error)."""
    u = doc["units"]
    for key, table in (("angle", ANGLE_UNITS), ("force", FORCE_UNITS),
                       ("length", LENGTH_UNITS)):
        value = u[key]
        if not isinstance(value, str) or value not in table:
            raise toml.error(f"[units] {key} = {value!r} is not a known {key} unit; valid "
                             f"{key} units: {', '.join(table)}", "units", key)
    for key, table in (("rotation", ANGLE_UNITS), ("moment", MOMENT_UNITS)):
        value = u.get(key)
        if value is not None and (not isinstance(value, str) or value not in table):
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
    if not three_numbers(offset, MAX_CELL):
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
    fixed = r.get("fixed", {})
    problem = check_fixed_table(fixed, units.length, units.angle)
    if problem is not None:
        raise toml.error(problem, "robot", "fixed")
    return RobotSettings(source, frame, np.array(offset, dtype=float) * units.length_to_si,
                         tuple(joints) if joints is not None else None, loops, fixed_base,
                         joint_angles, {str(k): float(v) for k, v in fixed.items()})


def measurement_noise(doc: dict, toml: TomlFile, key: str, unit: str) -> float | None:
    """``[measurement] <key>``, a noise std in the file's ``unit`` (``noise_std`` in the
    length unit, a rotation noise in the rotation unit), or None (key named on error)."""
    noise = doc["measurement"].get(key)
    if noise is not None:
        typed_value(noise, int | float, toml, "measurement", key, f"a positive number in {unit}")
        if not (math.isfinite(noise) and noise > 0):
            raise toml.error(f"[measurement] {key} must be a positive finite number in {unit}, "
                             f"got {noise!r}; omit it if unknown", "measurement", key)
    return noise


#: The two spellings of the rotation noise key, in both campaign kinds: the one the writers
#: write first (docs/diagnose.md, docs/absolute-poses.md).
ROTATION_NOISE_KEYS = ("rotation_noise_std", "noise_std_rotation")


def rotation_noise(doc: dict, toml: TomlFile, unit: str) -> tuple[float | None, str]:
    """``[measurement] rotation_noise_std`` (or its other spelling, ``noise_std_rotation``), a
    noise std in the rotation ``unit``, or None; and the key the file uses (to name in errors).

    Raises
    ------
    FileFormatError
        Both spellings given, or a value that is not a positive finite number.
    """
    given = [key for key in ROTATION_NOISE_KEYS if key in doc["measurement"]]
    if len(given) > 1:
        raise toml.error("[measurement] gives both rotation_noise_std and noise_std_rotation, "
                         "two spellings of one key; keep one", "measurement", given[1])
    key = given[0] if given else ROTATION_NOISE_KEYS[0]
    return measurement_noise(doc, toml, key, unit), key


def campaign_robot(doc: dict, toml: TomlFile, toml_path: Path
                   ) -> tuple[Units, RobotSettings, Robot, str, float | None]:
    """What both kinds of campaign.toml give alike, each key checked: the ``[units]``, the
    ``[robot]`` settings and the robot they name (:func:`settings_robot`), the measurement
    file's name (``[measurement] data``) and the position noise std (``noise_std``, the
    file's length unit, or None)."""
    units = units_section(doc, toml)
    settings = robot_section(doc, toml, units)
    data = typed_value(doc["measurement"]["data"], str, toml, "measurement", "data",
                       "a file name")
    noise = measurement_noise(doc, toml, "noise_std", units.length)
    return units, settings, settings_robot(settings, toml_path), data, noise


def settings_robot(settings: RobotSettings, toml_path: Path) -> Robot:
    """The robot a ``campaign.toml``'s ``[robot]`` names (paths relative to that file).

    Raises
    ------
    StiffnessError
        The robot cannot be loaded (the message starts with the file and ``[robot]``).
    """
    try:
        return settings.load(toml_path.parent)
    except StiffnessError as exc:
        raise with_context(exc, f"{toml_path}: [robot]") from exc
