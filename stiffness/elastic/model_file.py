"""The model file: an identified or diagnosed stiffness model, and the elastic model it makes.

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
     ...}

Everything is SI; a parameter's ``unit`` names its unit; the older files (``format``
``stiffness-identified-model``, ``-diagnosed-model``, version 1) still read, and so does a pose
calibration's ``final-model.json`` (its robot the calibrated robot, its elastic families the
library's effects: :mod:`stiffness.elastic.calibrated`).

Public API: :func:`read_model_file` (path -> :class:`ModelFile`: ``write``, ``to_dict``,
``check_robot``); :func:`load_model` (a file, a :class:`ModelFile` or a robot with springs -> the
one :class:`stiffness.elastic.model.ElasticModel`; :func:`elastic_model_of` for a read file);
:func:`fitted_deflection`. Errors: :class:`ModelFileError` (unknown schema, missing or malformed
key), :class:`ModelRobotError` (another robot, an effect on a joint it lacks). ``CompliantModel``,
``ModelCompliance`` and ``model_compliance`` are deprecated names of :func:`elastic_model_of`,
:class:`~stiffness.elastic.model.ElasticState` and ``load_model(path).at(q, load)``.

How each effect enters the elastic model is its class's business (its one hook,
:meth:`stiffness.elastic.effects.base.Effect.contribute`; ``kind`` of
:data:`stiffness.elastic.effects.base.EFFECT_KINDS`): ``stiffness`` and ``preload`` effects change
the robot and its K_X; ``measurement`` effects (how the campaign observed its deflections) and
``lost_motion`` (backlash: a deflection, not a stiffness) are listed, not applied to K_X (the exact
equilibrium and :func:`fitted_deflection` include it). Formulas: docs/model-file.md.
"""

from __future__ import annotations

import functools
import json
import math
import os
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from stiffness.elastic.calibrated import calibrated_elastics
from stiffness.elastic.effects import LIBRARY
from stiffness.elastic.effects.base import Parameter, effect_variables
from stiffness.elastic.effects.deflection_face import DeflectionEffect, Settings
from stiffness.elastic.effects.geometry import Geometry, References
from stiffness.elastic.effects.hypothesis import Hypothesis
from stiffness.elastic.effects.joint_laws import JointEffect
from stiffness.elastic.effects.link_bends import segment
from stiffness.elastic.effects.parts import ElasticParts
from stiffness.elastic.model import ElasticModel, ElasticState
from stiffness.elastic.stiffness_units import wrong_model_stiffness_unit
from stiffness.elastic.undetermined_springs import undetermined_notes
from stiffness.errors import (
    DataFileWarning,
    FileFormatError,
    StiffnessError,
    did_you_mean,
    warn_user,
    with_context,
)
from stiffness.files import (
    atomic_write,
    jsonable,
    output_folder,
    read_json,
    resolve_source,
    written_path,
    written_source,
)
from stiffness.mechanics.defaults import default_stiffness
from stiffness.mechanics.formulation import as_wrench
from stiffness.robot.calibration import (
    POSE_MODEL_KIND,
    moved_robot_file,
    read_pose_calibration,
    refuse_campaign,
    robot_identity,
)
from stiffness.robot.robot import Robot, load_robot
from stiffness.units import ANGLE_UNITS, FORCE_UNITS, LENGTH_UNITS

#: Name and version of the schema written: ``"schema": "stiffness-model/1"``.
SCHEMA_NAME = "stiffness-model"
SCHEMA_VERSION = 1
SCHEMA = f"{SCHEMA_NAME}/{SCHEMA_VERSION}"
#: ``format`` tags of the older files, still read (and still written beside ``schema``).
LEGACY_IDENTIFIED = "stiffness-identified-model"
LEGACY_DIAGNOSED = "stiffness-diagnosed-model"
#: Formulations a model may be identified with.
FORMULATIONS = ("conventional", "enhanced", "exact")
#: Unit names of the files -> factor to SI.
_UNIT_TO_SI = {**ANGLE_UNITS, **FORCE_UNITS, **LENGTH_UNITS, "N.m/rad": 1.0, "N/m": 1.0,
               "1/(N.m)": 1.0, "1/N": 1.0, "1": 1.0, "SI": 1.0}
#: Units an effect parameter of the current schema may name (the file is SI).
SI_PARAMETER_UNITS = ("m", "rad", "N", "N.m", "kg", "N.m/rad", "N/m", "1/(N.m)", "1/N", "kg.m",
                      "1", "SI")


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


# reading ------------------------------------------------------------------------------------------


class _Reader:
    """Typed access to a JSON document with one-line errors naming the file and the key."""

    def __init__(self, doc: dict, path: Path) -> None:
        self.doc, self.path = doc, path

    def fail(self, text: str) -> ModelFileError:
        return ModelFileError(f"{text}; rewrite the file with `stiffness identify` or "
                              "`stiffness diagnose --out`", path=self.path)

    def get(self, *keys, default=KeyError):
        node = self.doc
        for key in keys:
            if not isinstance(node, dict) or key not in node:
                if default is not KeyError:
                    return default
                raise self.fail(f"missing key {'.'.join(keys)}")
            node = node[key]
        return node

    def numbers(self, value, name: str, count: int, allow_null: bool = False) -> np.ndarray:
        ok = isinstance(value, list) and len(value) == count and all(
            (v is None and allow_null) or (isinstance(v, int | float) and not isinstance(v, bool))
            for v in value)
        if not ok:
            raise self.fail(f"{name} must be a list of {count} numbers, got {value!r}")
        return np.array([np.nan if v is None else v for v in value], dtype=float)

    def number(self, value, name: str, allow_null: bool = True) -> float:
        if value is None and allow_null:
            return math.nan
        if not isinstance(value, int | float) or isinstance(value, bool):
            raise self.fail(f"{name} must be a number, got {value!r}")
        return float(value)

    def strings(self, value, name: str) -> list[str]:
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise self.fail(f"{name} must be a list of names")
        return list(value)


def read_model_file(path: str | os.PathLike) -> ModelFile:
    """Read a model file (``identified-model.json``, ``final-model.json``), any known schema.

    Raises
    ------
    MissingFileError
        Missing or unreadable file.
    FileFormatError
        Not JSON (with its line and column).
    ModelFileError
        An unknown schema or version, or a missing or malformed key (one line: file, key).
    """
    path = Path(path)
    refuse_campaign(path)
    doc = read_json(path, "model file (identified-model.json of `stiffness identify` or "
                          "final-model.json of `stiffness diagnose --out`)")
    if not isinstance(doc, dict):
        raise ModelFileError("not a model file (not a JSON object)", path=path)
    reader = _Reader(doc, path)
    schema = doc.get("schema")
    if doc.get("kind") == POSE_MODEL_KIND:
        model = _read_calibration(path)
    elif schema is not None:
        name, _, version = str(schema).partition("/")
        if name != SCHEMA_NAME or version != str(SCHEMA_VERSION):
            raise ModelFileError(
                f"schema {schema!r}, which this version of stiffness does not know (it reads "
                f"{SCHEMA!r} and the older identified and diagnosed model files); upgrade "
                "stiffness or rewrite the file", path=path)
        model = _read_current(reader)
    elif doc.get("format") == LEGACY_IDENTIFIED:
        model = _read_legacy_identified(reader)
    elif doc.get("format") == LEGACY_DIAGNOSED:
        model = _read_legacy_diagnosed(reader)
    else:
        raise ModelFileError(
            f"not a model file (no schema {SCHEMA!r} and no format {LEGACY_IDENTIFIED!r} or "
            f"{LEGACY_DIAGNOSED!r}); give the file written by `stiffness identify` or "
            "`stiffness diagnose --out`", path=path)
    model.path = path
    return model


def _read_calibration(path: Path) -> ModelFile:
    """A pose calibration's file: the calibrated robot (the file is its robot source) with the
    springs and effects of :func:`~stiffness.elastic.calibrated.calibrated_elastics`."""
    cal = read_pose_calibration(path)
    parts = calibrated_elastics(cal)
    if parts.undetermined:
        warn_user(f"{path}: {parts.rigid_note()}", DataFileWarning)
    if parts.left_out:
        warn_user(f"{path}: {', '.join(parts.left_out)} of the calibration are not carried into "
                  "the elastic model (no deflection effect): its predictions leave them out",
                  DataFileWarning)
    k = parts.stiffness
    value, se, low, high = np.array([[p.value, p.standard_error, *p.ci95] for p in k],
                                    dtype=float).reshape(-1, 4).T
    return ModelFile(
        source=str(path.resolve()), frame=cal.frame or load_robot(str(path)).target_frame,
        target_offset_m=cal.target_offset_m, compliant_joints=tuple(p.name for p in k),
        k_theta=value, units=tuple(p.unit for p in k), formulation="exact", standard_error=se,
        ci95_low=low, ci95_high=high, produced_by="diagnose", fixed_base=cal.fixed_base,
        no_spring=parts.no_spring, robot_name=cal.name,
        effects=tuple(ModelEffect(n, w, LIBRARY[n].kind, ps, st, "of the pose calibration")
                      for n, w, ps, st in parts.effects))


def _robot_options(r: _Reader) -> dict:
    """The optional ``robot.loops`` (resolved against the file's folder), ``robot.fixed_base``
    ``robot.joint_angles`` and ``robot.name`` of a current model file."""
    loops = r.get("robot", "loops", default=None)
    if loops is not None and not isinstance(loops, str):
        raise r.fail("robot.loops must be the path of a loop declaration (a string)")
    fixed = r.get("robot", "fixed_base", default=False)
    if not isinstance(fixed, bool):
        raise r.fail(f"robot.fixed_base must be true or false, got {fixed!r}")
    angles = r.get("robot", "joint_angles", default="motor")
    if angles not in ("motor", "link"):
        raise r.fail(f"robot.joint_angles must be motor or link, got {angles!r}")
    if loops is not None:  # relative to the file's folder
        loops = str(Path(loops) if Path(loops).is_absolute() else (r.path.parent / loops).resolve())
    return {"loops": loops, "fixed_base": fixed, "joint_angles": angles,
            "robot_name": str(r.get("robot", "name", default=""))}


def _robot_part(r: _Reader) -> tuple[str, str, np.ndarray]:
    source, frame = r.get("robot", "source"), r.get("robot", "frame")
    if not isinstance(source, str) or not isinstance(frame, str):
        raise r.fail("robot.source and robot.frame must be strings")
    offset = r.numbers(r.get("robot", "target_offset_m"), "robot.target_offset_m", 3)
    return resolve_source(source, r.path.parent), frame, offset


def _formulation(r: _Reader, value) -> str:
    if value not in FORMULATIONS:
        raise r.fail(f"formulation must be one of {', '.join(FORMULATIONS)}, got {value!r}")
    return value


def _stiffness_values(r: _Reader, k: np.ndarray, units) -> None:
    if not np.all(np.isfinite(k)) or np.any(k <= 0):
        raise r.fail(f"k_theta.values must be positive, got {k.tolist()}")
    if not isinstance(units, list) or [u in ("N.m/rad", "N/m") for u in units] != [True] * len(k):
        raise r.fail("k_theta.unit must list N.m/rad or N/m per joint")


def _robot_and_stiffness(r: _Reader, no_joints: str
                         ) -> tuple[str, str, np.ndarray, list[str], np.ndarray, list]:
    """Robot part, compliant joints and the ``k_theta`` table (joints, values, unit) shared by
    the current and the identified v1 layouts; ``no_joints`` is the error for an empty list."""
    source, frame, offset = _robot_part(r)
    joints = r.strings(r.get("robot", "compliant_joints"), "robot.compliant_joints")
    if not joints:
        raise r.fail(no_joints)
    if r.get("k_theta", "joints") != joints:
        raise r.fail("k_theta.joints must equal robot.compliant_joints")
    k = r.numbers(r.get("k_theta", "values"), "k_theta.values", len(joints))
    units = r.get("k_theta", "unit")
    _stiffness_values(r, k, units)
    return source, frame, offset, joints, k, units


def _read_current(r: _Reader) -> ModelFile:
    source, frame, offset, joints, k, units = _robot_and_stiffness(
        r, "robot.compliant_joints must name at least one joint")
    n = len(joints)
    se, low, high = (r.numbers(r.get("k_theta", *key, default=[None] * n),
                               ".".join(("k_theta", *key)), n, allow_null=True)
                     for key in (("standard_error",), ("ci95", "low"), ("ci95", "high")))
    high = np.where(np.isnan(high) & ~np.isnan(low), np.inf, high)
    determined = r.get("k_theta", "determined", default=[True] * n)
    if not isinstance(determined, list) or [type(d) for d in determined] != [bool] * n:
        raise r.fail("k_theta.determined must list true or false per joint")
    raw = r.get("effects", default=[])
    if not isinstance(raw, list):
        raise r.fail("effects must be a list")
    effects = [_read_effect(r, e, f"effects[{i}]", si=True) for i, e in enumerate(raw)]
    noise = r.get("noise", default={}) or {}
    std = noise.get("std_m") if isinstance(noise, dict) else None
    known = {"schema", "format", "version", "produced_by", "campaign", "robot", "formulation",
             "k_theta", "effects", "noise", "standard_error", "ci95", "undetermined_joints"}
    return ModelFile(
        source=source, **_robot_options(r), frame=frame, target_offset_m=offset,
        compliant_joints=tuple(joints),
        k_theta=k, units=tuple(units), formulation=_formulation(r, r.get("formulation")),
        standard_error=se, ci95_low=low, ci95_high=high, effects=tuple(effects),
        noise_std_m=None if std is None else r.number(std, "noise.std_m"),
        noise_source=noise.get("source") if isinstance(noise, dict) else None,
        campaign=str(r.get("campaign", default="")),
        produced_by=str(r.get("produced_by", default="identify")),
        undetermined_joints=tuple(j for j, d in zip(joints, determined, strict=False) if not d),
        extra={k2: v for k2, v in r.doc.items() if k2 not in known},
    )


def _read_legacy_identified(r: _Reader) -> ModelFile:
    source, frame, offset, joints, k, units = _robot_and_stiffness(
        r, "robot.compliant_joints must be a list of joint names")
    n = len(joints)
    return ModelFile(
        source=source, frame=frame, target_offset_m=offset, compliant_joints=tuple(joints),
        k_theta=k, units=tuple(units), formulation=_formulation(r, r.get("formulation")),
        standard_error=r.numbers(r.get("standard_error"), "standard_error", n, allow_null=True),
        ci95_low=r.numbers(r.get("ci95", "low"), "ci95.low", n, allow_null=True),
        ci95_high=r.numbers(r.get("ci95", "high"), "ci95.high", n, allow_null=True),
        campaign=str(r.get("campaign", default="")), produced_by="identify",
        undetermined_joints=tuple(r.get("undetermined_joints", default=[])),
        extra={"residual_norm": r.get("residual_norm", default=None)},
    )


def _read_legacy_diagnosed(r: _Reader) -> ModelFile:
    source, frame, offset = _robot_part(r)
    joints = r.strings(r.get("compliant_joints"), "compliant_joints")
    table = r.get("k_theta")
    if not isinstance(table, dict) or list(table) != joints:
        raise r.fail("k_theta must give each compliant joint's stiffness")
    k, units, se, low, high = [], [], [], [], []
    for j in joints:
        p = _read_parameter(r, j, table[j], f"k_theta.{j}")
        k.append(p.value)
        units.append(p.unit)
        se.append(p.standard_error)
        low.append(p.ci95[0])
        high.append(p.ci95[1])
    _stiffness_values(r, np.array(k), units)
    raw = r.get("effects", default=[])
    effects = [_read_effect(r, e, f"effects[{i}]", si=False) for i, e in enumerate(raw)]
    unit = r.get("unit", default="m")
    std = r.get("noise_std", default=None)
    std_m = None if std is None else r.number(std, "noise_std") * _unit_factor(r, unit, "unit")
    baseline = r.get("baseline")
    return ModelFile(
        source=source, frame=frame, target_offset_m=offset, compliant_joints=tuple(joints),
        k_theta=np.array(k), units=tuple(units), formulation=_formulation(r, baseline),
        standard_error=np.array(se), ci95_low=np.array(low), ci95_high=np.array(high),
        effects=tuple(effects), noise_std_m=std_m,
        noise_source=r.get("noise_std_source", default=None),
        campaign=str(r.get("campaign", default="")), produced_by="diagnose",
    )


def _unit_factor(r: _Reader, unit, where: str) -> float:
    if unit not in _UNIT_TO_SI:
        raise r.fail(f"{where}: unknown unit {unit!r}")
    return _UNIT_TO_SI[unit]


def _read_parameter(r: _Reader, name: str, doc, where: str, si: bool = True) -> Parameter:
    if not isinstance(doc, dict) or "value" not in doc:
        raise r.fail(f"{where} must be an object with value, standard_error, ci95 and unit")
    unit = doc.get("unit", "SI")
    if si and unit not in SI_PARAMETER_UNITS:
        raise r.fail(f"{where}.unit is {unit!r}, but a model file holds SI values; convert the "
                     f"value, its standard error and ci95 to SI and name the unit (valid: "
                     f"{', '.join(SI_PARAMETER_UNITS)})")
    factor = 1.0 if si else _unit_factor(r, unit, where)
    value = r.number(doc["value"], f"{where}.value", allow_null=False)
    se = r.number(doc.get("standard_error"), f"{where}.standard_error")
    ci = doc.get("ci95", [None, None])
    if not isinstance(ci, list) or len(ci) != 2:
        raise r.fail(f"{where}.ci95 must be [low, high]")
    low = r.number(ci[0], f"{where}.ci95[0]")
    high = r.number(ci[1], f"{where}.ci95[1]")
    if si or factor == 1.0:
        si_unit = unit
    else:
        si_unit = "m" if unit in LENGTH_UNITS else "rad" if unit in ANGLE_UNITS else "N"
    return Parameter(name, value * factor, se * factor, (low * factor, high * factor), si_unit)


def _read_effect(r: _Reader, doc, where: str, si: bool) -> ModelEffect:
    if not isinstance(doc, dict) or not isinstance(doc.get("effect"), str):
        raise r.fail(f"{where} must be an object with an effect name")
    name = doc["effect"]
    if name not in LIBRARY:
        raise r.fail(f"{where}: unknown effect {name!r} (valid: {', '.join(LIBRARY)})")
    params = doc.get("parameters", {})
    if not isinstance(params, dict):
        raise r.fail(f"{where}.parameters must be an object")
    parameters = [_read_parameter(r, pn, pd, f"{where}.parameters.{pn}", si)
                  for pn, pd in params.items()]
    need = LIBRARY[name].param_names
    if [p.name for p in parameters][: len(need)] != list(need):
        raise r.fail(f"{where}: {name} needs the parameters {', '.join(need) or 'none'}")
    settings = doc.get("settings", {}) or {}
    return ModelEffect(name, doc.get("where"), LIBRARY[name].kind, parameters,
                       dict(settings), str(doc.get("description", "")))


# the elastic model of a file ----------------------------------------------------------------------

#: Why an effect of a kind that does not change the stiffness is not applied to K_X.
_NOT_STIFFNESS = {"lost_motion": "lost motion: a deflection of +-half_width that does not "
                                 "change the stiffness"}


def elastic_model_of(model: ModelFile, frame: str | None = None,
                     target_offset: np.ndarray | list[float] | None = None) -> ElasticModel:
    """The elastic model of a model file: each effect contributes through its class's one hook
    (:meth:`stiffness.elastic.effects.base.Effect.contribute`).

    Parameters
    ----------
    model
        The model file.
    frame, target_offset
        Another target (frame, offset in m in its axes) than the model's; the model's
        ``target_offset`` effect then does not apply (it moved the campaign's target).

    Raises
    ------
    ModelFileError, UnknownJointError
        A ``joint_compliance`` on a joint ``k_theta`` holds; a joint-law effect on a rigid one;
        a compensator on a controller coordinate that is no one link's chain joint.
    ModelRobotError
        An effect names a joint the robot does not have.
    """
    where = f"{model.path}: " if model.path is not None else ""
    if not model.compliant_joints:
        raise StiffnessError(f"{where}no spring: {model.no_spring or 'the file holds none'}")
    parts = ElasticParts(dict(zip(model.compliant_joints, model.k_theta, strict=True)),
                         keep_target=frame is None and target_offset is None)
    applied, not_applied = [], []
    for e in model.effects:
        try:
            e.effect().contribute(e.values(), parts)
        except StiffnessError as exc:
            raise ModelFileError(str(exc), path=model.path or "model file") from exc
        reason = parts.not_applied.get(e.label, _NOT_STIFFNESS.get(e.kind))
        if reason is None:
            applied.append(e)
        else:
            not_applied.append((e, reason))
    parts.check_joints()
    notes = undetermined_notes(model.undetermined_joints, model.extra.get("confounded_joints"))
    for note in notes:  # older files: no confounded_joints
        warn_user(f"{where}{note}", DataFileWarning)
    offset = model.target_offset_m.copy() if target_offset is None else np.asarray(
        target_offset, dtype=float).reshape(3)
    try:
        robot = load_robot(model.source, frame=frame or model.frame,
                           target_offset=offset + parts.target_shift,
                           compliant_joints=tuple(parts.springs), **model.robot_options())
    except StiffnessError as exc:
        raise with_context(exc, f"{where}the model's robot with its effects") from exc
    if problem := wrong_model_stiffness_unit(model, robot.is_prismatic):
        raise ModelFileError(problem, path=model.path or "model file")
    for e in model.effects:  # a bend's or tilt's joints are the chain's, a joint law's a spring
        law = robot.compliant_joints if isinstance(effect := e.effect(), JointEffect) else ()
        joints = list(dict.fromkeys([*robot.model.names[1:], *law]))  # backlash(T2): a coordinate
        for name in [n for n in segment(e.where) or [e.where] if n is not None and n not in joints]:
            raise ModelRobotError(f"{where}effect {e.label} names {name!r}, not a joint of "
                                  f"{robot.title}; {did_you_mean(str(name), joints)}")
        if isinstance(effect, JointEffect) and (bad := effect.placement_problem(robot, e.where)):
            raise ModelFileError(bad, path=model.path or "model file")  # a compensator on T2
    em = ElasticModel.of_parts(
        robot, parts, "conventional" if model.formulation == "conventional" else "enhanced",
        source=None if model.path is None else str(model.path), applied=tuple(applied),
        not_applied=tuple(not_applied), joint_angles=model.joint_angles,
        beyond_springs=tuple(e.label for e in applied if LIBRARY[e.name].beyond_springs))
    em.fitted = functools.partial(fitted_deflection, model if parts.keep_target else replace(
        model, frame=robot.target_frame, target_offset_m=offset,  # predicted there too
        effects=tuple(e for e in model.effects if e.name != "target_offset")))
    return em


def load_model(source: ElasticModel | Robot | ModelFile | str | os.PathLike,
               k: np.ndarray | list[float] | None = None, frame: str | None = None,
               target_offset: np.ndarray | list[float] | None = None) -> ElasticModel:
    """An elastic model from a model file, or a robot with joint springs.

    Parameters
    ----------
    source
        A model file's path (``identified-model.json`` of ``stiffness identify``,
        ``final-model.json`` of ``stiffness diagnose``) or its :class:`ModelFile`; a
        :class:`~stiffness.robot.robot.Robot` or a robot source (shipped name,
        example-robot-data name, URDF path); or an :class:`ElasticModel` (returned as is).
    k
        Joint stiffness (N.m/rad, N/m), one per compliant joint of a robot; default the
        shipped robot's ``k_theta_SI``. Not with a model file (it brings its own springs).
    frame, target_offset
        Another target (frame; offset in m in its axes) than the file's or the robot's.

    Raises
    ------
    StiffnessError
        A robot without springs, springs given with a model, or the file's errors
        (:class:`ModelFileError`, :class:`ModelRobotError`...).
    """
    if isinstance(source, ElasticModel):
        if k is not None or frame is not None or target_offset is not None:
            raise StiffnessError("an elastic model brings its springs and target; give k, "
                                 "frame or target_offset with a robot")
        return source
    if isinstance(source, str | os.PathLike) and (
            Path(source).suffix.lower() == ".json" or Path(source).is_file()
            and Path(source).read_bytes()[:64].lstrip().startswith(b"{")):
        source = read_model_file(source)
    if isinstance(source, ModelFile):
        if k is not None:
            raise StiffnessError("k goes with a robot; a model file brings its own springs")
        return elastic_model_of(source, frame, target_offset)
    robot = source if isinstance(source, Robot) else load_robot(
        str(source), frame=frame, target_offset=target_offset)
    if k is None:
        k = default_stiffness(robot)
        if k is None:
            raise StiffnessError(f"give k: one stiffness per compliant joint of {robot.title} "
                                 f"({', '.join(robot.compliant_joints)})")
    return ElasticModel.joint_springs(robot, k)


def fitted_deflection(model: ModelFile, q: np.ndarray, load: np.ndarray,
                      measured: bool = False) -> np.ndarray:
    """Predicted target displacement (3,) in m under a dead ``load`` (force or wrench), as
    the fitted model predicts it (:class:`stiffness.elastic.effects.hypothesis.Hypothesis`):
    every effect applied, lost motion included; measurement effects only with ``measured``
    (what the campaign's instrument reads).

    Raises
    ------
    StiffnessError
        Not the coordinates of the model's declared robot.
    """
    declared = model.robot()
    geometry = Geometry.of(declared)
    wrench = as_wrench(load)
    coords = np.asarray(q, dtype=float).reshape(-1)
    if coords.shape[0] != declared.n_coordinates:
        raise StiffnessError(f"give the {declared.n_coordinates} coordinates of "
                             f"{declared.name} ({', '.join(declared.coordinate_joints)})")
    rows = geometry.rows(coords[None], wrench[None, :3], wrench[None, 3:],
                         joint_angles=model.joint_angles)
    parts = ElasticParts({})
    effects, values = [], []
    for e in model.effects:
        if e.kind == "measurement" and not measured:
            continue
        effect = e.effect(geometry)
        effect.contribute(e.values(), parts)
        effects.append(effect)
        values.append(e.values())
    smoothing = np.array([parts.smoothing.get(j, 1.0) for j in geometry.joints])
    refs = References(geometry.joints, 1.0, np.ones(len(geometry.joints)), smoothing, 1.0, 1.0, 1.0)
    baseline = "conventional" if model.formulation == "conventional" else "enhanced"
    if model.formulation == "exact" and not any(e.second_order for e in effects):
        effects.insert(0, LIBRARY["complementary_stiffness"]())
        values.insert(0, np.zeros(0))
    fitted = Hypothesis(geometry, rows, baseline, model.compliant_joints, tuple(effects), refs)
    x = np.concatenate([np.log(model.k_theta)] + [
        effect_variables(e, v, refs) for e, v in zip(effects, values, strict=True)])
    return fitted.predict(x)[0]


# deprecated names (one release) -------------------------------------------------------------------


def _model_compliance(model: ModelFile | ElasticModel | str | os.PathLike, q: np.ndarray,
                      load: np.ndarray | None = None, formulation: str = "enhanced"
                      ) -> ElasticState:
    """Deprecated: ``load_model(model).at(q, load, formulation)``."""
    return load_model(model).at(q, load, formulation)


_DEPRECATED = {
    "CompliantModel": (elastic_model_of, "stiffness.load_model(path) or "
                                         "stiffness.elastic.model_file.elastic_model_of(file)"),
    "ModelCompliance": (ElasticState, "stiffness.elastic.model.ElasticState"),
    "model_compliance": (_model_compliance, "stiffness.load_model(path).at(q, wrench)"),
}


def __getattr__(name: str):
    """The names this module had before the one elastic model, with a DeprecationWarning."""
    if name in _DEPRECATED:
        value, instead = _DEPRECATED[name]
        warnings.warn(f"stiffness.elastic.model_file.{name} is deprecated; use {instead}",
                      DeprecationWarning, stacklevel=2)
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
