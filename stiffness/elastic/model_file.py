"""Reading a model file (:func:`read_model_file`) and the one elastic model of a model file or
a robot with springs (:func:`load_model`).

``stiffness identify`` (``identified-model.json``) and ``stiffness diagnose --out``
(``final-model.json``) write the same JSON schema (docs/model-file.md; what it holds,
:class:`~stiffness.elastic.model_contents.ModelFile`, in :mod:`stiffness.elastic.model_contents`).
The older files (``format`` ``stiffness-identified-model``, ``-diagnosed-model``, version 1) still
read, and so does a pose calibration's ``final-model.json`` (its robot the calibrated robot, its
elastic families the library's effects: :mod:`stiffness.elastic.calibrated`).

Public API: :func:`read_model_file` (path -> :class:`~stiffness.elastic.model_contents.ModelFile`:
``write``, ``to_dict``, ``check_robot``); :func:`load_model` (a file, a ``ModelFile`` or a robot
with springs -> the one :class:`stiffness.elastic.model.ElasticModel`;
:func:`~stiffness.elastic.file_model.elastic_model_of` for a read file, in
:mod:`stiffness.elastic.file_model` with the fitted deflection). Errors: a file's
(:class:`~stiffness.elastic.model_contents.ModelFileError`,
:class:`~stiffness.elastic.model_contents.ModelRobotError`).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from stiffness.elastic.calibrated import calibrated_elastics
from stiffness.elastic.effects import LIBRARY
from stiffness.elastic.effects.base import Parameter
from stiffness.elastic.file_model import elastic_model_of
from stiffness.elastic.model import ElasticModel
from stiffness.elastic.model_contents import (
    LEGACY_DIAGNOSED,
    LEGACY_IDENTIFIED,
    SCHEMA,
    SCHEMA_NAME,
    SCHEMA_VERSION,
    ModelEffect,
    ModelFile,
    ModelFileError,
)
from stiffness.elastic.parameter_covariance import KEY, ParameterCovariance
from stiffness.errors import (
    DataFileWarning,
    StiffnessError,
    warn_user,
)
from stiffness.files import (
    read_json,
    resolve_source,
)
from stiffness.mechanics.defaults import default_stiffness
from stiffness.robot.calibration import (
    POSE_MODEL_KIND,
    read_pose_calibration,
    refuse_campaign,
)
from stiffness.robot.robot import Robot, load_robot
from stiffness.units import ANGLE_UNITS, FORCE_UNITS, LENGTH_UNITS

#: Formulations a model may be identified with.
FORMULATIONS = ("conventional", "enhanced", "exact")
#: Unit names of the files -> factor to SI.
_UNIT_TO_SI = {**ANGLE_UNITS, **FORCE_UNITS, **LENGTH_UNITS, "N.m/rad": 1.0, "N/m": 1.0,
               "1/(N.m)": 1.0, "1/N": 1.0, "1": 1.0, "SI": 1.0}
#: Units an effect parameter of the current schema may name (the file is SI).
SI_PARAMETER_UNITS = ("m", "rad", "N", "N.m", "kg", "N.m/rad", "N/m", "1/(N.m)", "1/N", "kg.m",
                      "1", "SI")


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
    if parts.weight_left_out:
        warn_user(f"{path}: {parts.weight_left_out}", DataFileWarning)
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
             "k_theta", "effects", "noise", "standard_error", "ci95", "undetermined_joints",
             KEY}
    covariance = None if KEY not in r.doc else ParameterCovariance.from_dict(r.doc[KEY], r.fail)
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
        extra={k2: v for k2, v in r.doc.items() if k2 not in known}, covariance=covariance,
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
