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
    fixed = { head_1_joint = 0.0 }     # coordinates without a CSV column, in the [units]
                                       # angle (length for prismatic joints) (optional)
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
measured displacement of the target from its unloaded position. Instead of ``q1..qn`` the
coordinate columns may be named after the robot's coordinate joints, any subset in any order
(as a controller logs them); a coordinate without a column is held at its ``[robot] fixed =
{ joint = value }`` value (the angle unit, or the length unit for a prismatic joint), else at
the robot's reference configuration (:mod:`stiffness.mechanics.defaults`), said once in a
:class:`~stiffness.errors.DataFileNote` (:mod:`stiffness.calibration.coordinate_columns`).
The optional groups ``mx,my,mz`` (applied moment, in the ``[units] moment`` unit, default force
unit x length unit) and ``rx,ry,rz`` (measured small rotation vector of the target frame's
deflection, base axes, in the ``[units] rotation`` unit, default the angle unit) may be given;
each group comes whole (all three columns). Columns are found by name (``config`` first); other
columns (a rig's time stamps) are ignored with one
:class:`~stiffness.errors.UnknownColumnWarning` (refused by the commands' ``--strict``).
``rotation_noise_std`` (also read as ``noise_std_rotation``, the spelling pose campaigns used;
both campaign kinds take either and write ``rotation_noise_std``) needs the rotation columns.
Lines starting with ``#`` and blank lines are skipped; a comment declaring units (as a plan
file's ``# units: angle=deg force=N length=mm``) must agree with ``[units]``. A missing column,
one given twice, or a cell that is not a finite number within +-1e12 is an error naming the
file, the line and the column.

In memory everything is SI (rad, m, N, N.m); the declared units apply only to the files.
This module holds the campaign and :func:`load_campaign`; the ``campaign.toml`` sections are
read by :mod:`stiffness.calibration.campaign_toml`, the CSV by
:mod:`stiffness.calibration.measurements`, and both written by
:mod:`stiffness.calibration.campaign_writer`.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stiffness.calibration.campaign_toml import (
    BASELINES,
    DEFAULT_DATA_FILE,
    RobotSettings,
    TomlFile,
    campaign_robot,
    campaign_toml_path,
    read_campaign_toml,
    rotation_noise,
    typed_value,
)
from stiffness.calibration.coordinate_columns import fixed_values
from stiffness.calibration.measurements import coordinates_in_si, read_rows, warn_copied_rows
from stiffness.calibration.unit_checks import (
    check_configuration_units,
    check_deflection_sign,
    check_deflection_size,
    check_force_unit,
)
from stiffness.errors import (
    StiffnessError,
    UnknownNameError,
    wrong_argument,
)
from stiffness.files import (
    read_text,
    read_toml,
    resolve_path,
    resolve_source,
)
from stiffness.robot.robot import Robot
from stiffness.units import Units


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
        (m,) configuration labels (default: the row numbers ``1..m``).
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
    config: tuple[str, ...] = ()
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
        if not self.config:  # not given: the rows' numbers
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
            raise StiffnessError("campaign units must be a stiffness.units.Units")
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
            robot = self.robot_settings.load(self.folder())
            if robot.n_coordinates != self.q.shape[1]:
                raise StiffnessError(
                    f"robot {self.robot_settings.source} has {robot.n_coordinates} coordinates "
                    f"({', '.join(robot.coordinate_joints)}) but campaign {self.name!r} has "
                    f"{self.q.shape[1]} q values per row; give one q per coordinate joint"
                )
            self._robot = robot
        return self._robot


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
        ``path`` is no path (the Python API's ``campaign`` argument: ``identify(5)``), the file
        cannot be read, or ``kind`` is not one of :data:`CAMPAIGN_KINDS`.
    """
    if not isinstance(path, str | os.PathLike):
        raise wrong_argument("campaign", path, "a Campaign, a PoseCampaign, or the path of a "
                             "campaign.toml or its folder (str or os.PathLike)")
    toml_path = campaign_toml_path(path)
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
    toml_path = campaign_toml_path(path)
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
    units, settings, robot, data_name, noise = campaign_robot(doc, toml, toml_path)
    rot_noise, rot_key = rotation_noise(doc, toml, units.rotation)
    data_path = toml_path.parent / data_name
    fixed = fixed_values(settings.fixed, robot, units,
                         lambda problem: toml.error(problem, "robot", "fixed"))
    rows = read_rows(data_path, robot, units, toml_path, fixed,
                     lambda problem: toml.error(problem, "robot", "fixed"))
    labels, lines = rows.labels, rows.lines
    q = coordinates_in_si(robot, rows.q, units, labels, lines, data_path)
    force = rows.force * units.force_to_si
    deflection = rows.deflection * units.length_to_si
    moment = None if rows.moment is None else rows.moment * units.moment_to_si
    rotation = None if rows.rotation is None else rows.rotation * units.rotation_to_si
    has_moment, has_rotation = moment is not None, rotation is not None
    warn_copied_rows(np.column_stack([a for a in (rows.q, rows.force, rows.deflection,
                                                  rows.moment, rows.rotation) if a is not None]),
                     lines, data_path)
    check_deflection_sign(force, moment, deflection, data_path)
    if check_deflection_size(robot, deflection, force, units, data_path):
        check_force_unit(robot, q, force, moment, deflection, units, data_path)
    check_configuration_units(robot, q, force, moment, deflection, list(labels), data_path)
    if not has_rotation and rot_noise is not None:
        raise toml.error(f"[measurement] {rot_key} is given but {data_name} has no "
                         "rotation columns rx,ry,rz; add them after dz (or after mz) or drop "
                         f"{rot_key}", "measurement", rot_key)
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
