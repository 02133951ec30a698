"""What a model file holds: :class:`ModelFile` and its :class:`ModelEffect` s (SI), the names
of its schema, its errors, and its writing (:meth:`ModelFile.write`, :meth:`ModelFile.to_dict`).

``stiffness identify`` (``identified-model.json``) and ``stiffness diagnose --out``
(``final-model.json``) write the same JSON schema, documented in ``docs/model-file.md``::

    {"schema": "stiffness-model/1",
     "robot": {"source", "frame", "target_offset_m", "compliant_joints",
               "loops", "fixed_base", "joint_angles", "name"},  # the last four when given
     "formulation": "conventional" | "enhanced" | "exact",
     "k_theta": {"joints", "values", "unit", "standard_error", "ci95": {"low", "high"},
                 "determined"},
     "effects": [{"effect", "where", "kind", "description",
                  "parameters": {name: {"value", "standard_error", "ci95", "unit"}},
                  "settings": {...}}],
     "noise": {"std_m", "source"},
     "parameter_covariance": {"variables", "labels", "units", "matrix", "noise_std_m"},
     ...}

Everything is SI; a parameter's ``unit`` names its unit. The file is read by
:func:`stiffness.elastic.model_file.read_model_file`; the elastic model it makes is
:mod:`stiffness.elastic.file_model`'s. Errors: :class:`ModelFileError` (unknown schema, missing or
malformed key), :class:`ModelRobotError` (another robot, an effect on a joint it lacks).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stiffness.elastic.effects import LIBRARY
from stiffness.elastic.effects.base import Parameter
from stiffness.elastic.effects.deflection_face import DeflectionEffect, Settings
from stiffness.elastic.effects.geometry import Geometry
from stiffness.elastic.parameter_covariance import KEY, ParameterCovariance
from stiffness.errors import (
    FileFormatError,
    StiffnessError,
)
from stiffness.files import (
    atomic_write,
    jsonable,
    output_folder,
    written_path,
    written_source,
)
from stiffness.robot.calibration import (
    moved_robot_file,
    robot_identity,
)
from stiffness.robot.robot import Robot, load_robot

#: Name and version of the schema written: ``"schema": "stiffness-model/1"``.
SCHEMA_NAME = "stiffness-model"
SCHEMA_VERSION = 1
SCHEMA = f"{SCHEMA_NAME}/{SCHEMA_VERSION}"
#: ``format`` tags of the older files, still read (and still written beside ``schema``).
LEGACY_IDENTIFIED = "stiffness-identified-model"
LEGACY_DIAGNOSED = "stiffness-diagnosed-model"


class ModelFileError(FileFormatError):
    """A model file of an unknown schema, or with a missing or malformed key (the message
    starts with the file)."""


class ModelRobotError(StiffnessError):
    """A model file used with another robot than its own, or whose effects name joints its
    robot does not have."""


# the model ----------------------------------------------------------------------------------------


@dataclass
class ModelEffect:
    """An effect of a model file, SI.

    Attributes
    ----------
    name
        Library name (:data:`stiffness.elastic.effects.LIBRARY`).
    where
        A joint, ``a->b``, or ``None``.
    kind
        ``stiffness``, ``measurement`` or ``lost_motion``.
    parameters
        Values with standard errors and 95 % intervals, SI (each names its unit).
    settings
        Fixed settings of the effect (``smoothing_torque`` of a backlash, N.m or N).
    description
        One line on what it is.
    """

    name: str
    where: str | None
    kind: str
    parameters: list[Parameter] = field(default_factory=list)
    settings: dict = field(default_factory=dict)
    description: str = ""

    @property
    def label(self) -> str:
        """``name`` or ``name(where)``."""
        return self.name if self.where is None else f"{self.name}({self.where})"

    def value(self, name: str) -> float:
        """The SI value of parameter ``name``."""
        for p in self.parameters:
            if p.name == name:
                return float(p.value)
        raise ModelFileError(f"effect {self.label} has no parameter {name!r}", path="model file")

    def values(self) -> np.ndarray:
        """SI values in the effect's parameter order."""
        return np.array([p.value for p in self.parameters], dtype=float)

    def effect(self, geometry: Geometry | None = None) -> DeflectionEffect:
        """The library's effect with its settings, placed on ``geometry`` (unchecked without)."""
        effect = LIBRARY[self.name].at_place(self.where, geometry)
        return effect.configured(self.settings) if isinstance(effect, Settings) else effect

    def to_dict(self) -> dict:
        """JSON-ready."""
        return {"effect": self.name, "where": self.where, "kind": self.kind,
                "description": self.description,
                "parameters": {p.name: p.to_dict() for p in self.parameters},
                "settings": dict(self.settings)}


@dataclass
class ModelFile:
    """A stiffness model: robot, compliant joints, K_theta with intervals, formulation,
    effects, noise (SI).

    Attributes
    ----------
    source, frame, target_offset_m
        The robot and its measurement target (offset in m, frame axes). A URDF source is an
        absolute path in memory (relative to the file's folder on disk); a pose calibration's
        is the file itself (the calibrated robot).
    loops, fixed_base, robot_name
        The robot's loop declaration (a path, like ``source``) and whether its floating or
        planar base is fixed: how the robot is loaded (:meth:`robot_options`); its name for
        the user (:attr:`stiffness.robot.robot.Robot.title`), or "".
    compliant_joints, k_theta, units
        The baseline's compliant joints, their stiffness (N.m/rad or N/m) and unit names.
    standard_error, ci95_low, ci95_high
        Uncertainty of ``k_theta`` (NaN or inf where undetermined).
    formulation
        ``conventional``, ``enhanced`` or ``exact``: what ``k_theta`` was identified with.
    effects
        Effects added by a diagnosis (none for an identification).
    noise_std_m, noise_source
        Measurement noise std (m) and where it comes from, or ``None``.
    campaign, produced_by
        Campaign name; ``identify`` or ``diagnose``.
    undetermined_joints, no_spring
        Joints whose stiffness the campaign could not determine; why a calibration has none.
    extra, path
        Further keys kept as written (e.g. ``residual_norm``); the file read, or ``None``.
    covariance
        The fitted parameters' covariance (``parameter_covariance``, SI:
        :class:`~stiffness.elastic.parameter_covariance.ParameterCovariance`), or ``None``
        (a file written before it, or a model not fitted).
    """

    source: str
    frame: str
    target_offset_m: np.ndarray
    compliant_joints: tuple[str, ...]
    k_theta: np.ndarray
    units: tuple[str, ...]
    formulation: str
    standard_error: np.ndarray | None = None
    ci95_low: np.ndarray | None = None
    ci95_high: np.ndarray | None = None
    effects: tuple[ModelEffect, ...] = ()
    noise_std_m: float | None = None
    noise_source: str | None = None
    campaign: str = ""
    produced_by: str = "identify"
    undetermined_joints: tuple[str, ...] = ()
    extra: dict = field(default_factory=dict)
    path: Path | None = None
    loops: str | None = None
    fixed_base: bool = False
    joint_angles: str = "motor"
    robot_name: str = ""
    no_spring: str = ""
    covariance: ParameterCovariance | None = None

    def __post_init__(self) -> None:
        n = len(self.compliant_joints)
        self.compliant_joints = tuple(self.compliant_joints)
        self.target_offset_m = np.asarray(self.target_offset_m, dtype=float).reshape(3)
        self.k_theta = np.asarray(self.k_theta, dtype=float).reshape(n)
        self.standard_error, self.ci95_low, self.ci95_high = (
            np.full(n, np.nan) if v is None else np.asarray(v, dtype=float).reshape(n)
            for v in (self.standard_error, self.ci95_low, self.ci95_high))
        self.effects = tuple(self.effects)

    # views -----------------------------------------------------------------------------
    def robot_options(self) -> dict:
        """``loops`` and ``fixed_base``, as keyword arguments of
        :func:`stiffness.robot.robot.load_robot`."""
        return {"loops": self.loops, "fixed_base": self.fixed_base}

    def robot(self) -> Robot:
        """The declared robot (baseline compliant joints, declared target), effects not applied."""
        return load_robot(self.source, frame=self.frame, target_offset=self.target_offset_m,
                          compliant_joints=self.compliant_joints, **self.robot_options())

    def check_robot(self, source: str | os.PathLike) -> None:
        """Refuse (``ModelRobotError``) a ``source`` naming another robot than the model's; a
        model file moved away from its robot file takes ``source`` (:func:`moved_robot_file`)."""
        if moved_robot_file(self.source, self.robot_name, str(source)):
            self.source = str(source)
        if robot_identity(str(source)) != robot_identity(self.source):
            where = f" {self.path}" if self.path is not None else ""
            mine = repr(self.source) if self.robot_name in ("", self.source) else (
                f"{self.robot_name!r} ({self.source})")
            raise ModelRobotError(
                f"the model file{where} is of robot {mine}, not {str(source)!r}; drop "
                "--robot (the model names its robot) or give the model of that robot")

    # writing ---------------------------------------------------------------------------
    def to_dict(self, relative_to: str | os.PathLike | None = None) -> dict:
        """The file's JSON object (a URDF source relative to ``relative_to`` when given)."""
        folder = None if relative_to is None else Path(relative_to)
        source = self.source if folder is None else written_source(self.source, folder)
        joints = list(self.compliant_joints)
        determined = [j not in self.undetermined_joints for j in joints]
        robot: dict[str, object] = {"source": source, "frame": self.frame,
                                    "target_offset_m": self.target_offset_m,
                                    "compliant_joints": joints}
        if self.loops is not None:
            robot["loops"] = self.loops if folder is None else written_path(self.loops, folder)
        if self.fixed_base:
            robot["fixed_base"] = True
        robot.update({"joint_angles": self.joint_angles} if self.joint_angles != "motor" else {})
        robot.update({"name": self.robot_name} if self.robot_name else {})
        doc = {
            "schema": SCHEMA,
            "format": LEGACY_IDENTIFIED if self.produced_by == "identify" else LEGACY_DIAGNOSED,
            "version": 1, "produced_by": self.produced_by, "campaign": self.campaign,
            "robot": robot, "formulation": self.formulation,
            "k_theta": {"joints": joints, "values": self.k_theta, "unit": list(self.units),
                        "standard_error": self.standard_error,
                        "ci95": {"low": self.ci95_low, "high": self.ci95_high},
                        "determined": determined},
            "effects": [e.to_dict() for e in self.effects],
            "noise": {"std_m": self.noise_std_m, "source": self.noise_source},
            # the keys of the first identified-model files, kept for their readers
            "standard_error": self.standard_error,
            "ci95": {"low": self.ci95_low, "high": self.ci95_high,
                     "method": "delta method on ln k"},
            "undetermined_joints": list(self.undetermined_joints),
        }
        if self.covariance is not None:
            doc[KEY] = self.covariance.to_dict()
        for key, value in self.extra.items():
            doc.setdefault(key, value)
        return jsonable(doc)

    def write(self, path: str | os.PathLike) -> Path:
        """Write the file atomically (a URDF source relative to its folder); returns the path."""
        path = Path(path)
        output_folder(path.parent)
        text = json.dumps(self.to_dict(path.parent), indent=1, allow_nan=False)
        atomic_write(path, text + "\n")
        return path
