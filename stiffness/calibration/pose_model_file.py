"""The model file of a pose calibration (``final-model.json``): what it holds and how it is
written (:func:`write_pose_model`) and read back into its marker-position model
(:func:`read_pose_model`, through :func:`stiffness.robot.calibration.read_pose_calibration`,
which :func:`stiffness.load_model` reads too), and the parameter table it and ``diagnose
--json`` carry (:func:`parameter_table`). SI throughout."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.calibration.pose_campaign import PoseCampaign
from stiffness.calibration.pose_fit import PoseFit
from stiffness.calibration.pose_model import Loads, Marker, PoseModel
from stiffness.calibration.pose_parameters import PoseJudge
from stiffness.elastic.calibrated import softening
from stiffness.elastic.effects.pose_face import compliance_label, nonlinear_label
from stiffness.elastic.parameter_covariance import KEY, POSE_VARIABLES, ParameterCovariance
from stiffness.errors import FileFormatError
from stiffness.files import atomic_write, jsonable, read_json, written_source
from stiffness.robot.calibration import (
    POSE_MODEL_KIND,
    measuring_placement,
    read_pose_calibration,
)
from stiffness.robot.robot import Robot, load_robot


def parameter_table(fit: PoseFit, judge: PoseJudge | None = None) -> list[dict]:
    """Each parameter with its value, standard deviation and 95 % interval (SI, unit named),
    and whether it sits at its physical lower bound (its interval then one-sided); with the
    campaign's ``judge``, also the keys of a deflection diagnosis's parameters
    (:meth:`~stiffness.elastic.effects.base.Parameter.to_dict`: ``standard_error``, ``ci95``,
    ``determined``, ``held``, ``physical_scale``)."""
    lo, hi = fit.interval()
    std = fit.std()
    kept = set(fit.identifiability.kept)
    judged = ({} if judge is None else
              {p.name: p for ps in judge.parameters(fit).values() for p in ps})
    table = [{"family": p.family, "parameter": p.label, "unit": p.unit,
              "value": float(fit.x[i]), "fitted": i in kept,
              "std": None if i not in kept else jsonable(std[i]),
              "interval_95": None if i not in kept else jsonable([lo[i], hi[i]]),
              "at_bound": i in fit.at_bound,
              **({k: v for k, v in judged[p.label].to_dict().items()
                  if k not in ("value", "unit", "at_bound")} if p.label in judged else {})}
             for i, p in enumerate(fit.model.parameters)]
    for row in table:
        row.update(_softening(row, table))
    return table


def measuring_frame(fit: PoseFit, length_to_si: float) -> dict:
    """The fitted measuring frame whole (``diagnose --json``'s ``measuring_frame``): the
    robot world's placement in the measuring system's axes, ``y = R p + t``
    (:func:`~stiffness.robot.calibration.measuring_placement`: the starting estimate corrected
    by the ``frame`` family, whose parameters are that correction, not the frame): ``rotation``
    (3x3), ``rotation_vector_deg`` (its rotation vector, deg) and ``translation`` (the
    campaign's length unit, ``length_to_si`` m each)."""
    values = {p.label: float(fit.x[i]) for i, p in enumerate(fit.model.parameters)}
    rotation, translation = measuring_placement(fit.model.rotation0, fit.model.translation0,
                                                values)
    return {"rotation": rotation.tolist(),
            "rotation_vector_deg": np.degrees(pin.log3(rotation)).tolist(),
            "translation": (translation / length_to_si).tolist()}


def _softening(row: dict, table: list[dict]) -> dict:
    """A fitted nonlinear spring's row ``gamma`` gets ``beta``, the deflection library's
    softening ``gamma / c`` (value and unit, 1/(N.m) or 1/N, :func:`softening`) with ``c`` its
    spring's fitted compliance, where that was fitted positive; every other row nothing."""
    if row["family"] != "nonlinear_joint_stiffness" or not row["fitted"]:
        return {}
    spring = compliance_label(row["parameter"].removesuffix(nonlinear_label("")))
    c = next((r["value"] for r in table if r["parameter"] == spring and r["fitted"]), 0.0)
    if not c > 0:
        return {}
    beta = softening(row, c)
    return {"beta": {"value": beta.value, "unit": beta.unit, "of": f"gamma / c ({spring})"}}


def pose_model_dict(fit: PoseFit, campaign: PoseCampaign, folder: str | os.PathLike,
                    selection: dict | None = None, plausibility: dict | None = None) -> dict:
    """The model file of a pose calibration written into ``folder``: robot (its source relative
    to ``folder``, :func:`~stiffness.files.written_source`), measuring frame, markers,
    parameters (SI), and ``selection`` (:meth:`PoseDiagnosis.selection`: the forced and
    forbidden families) and ``plausibility`` (:meth:`~stiffness.calibration.
    pose_plausibility.Plausibility.to_dict`, whether the fit can be a calibration) when the fit
    comes from a diagnosis; read by
    :func:`~stiffness.robot.calibration.read_pose_calibration`."""
    s, robot = campaign.settings, campaign.robot
    return {"kind": POSE_MODEL_KIND, "version": 1, "units": "SI",
            "robot": {"source": written_source(s.source, Path(folder), campaign.folder()),
                      "frame": robot.target_frame,
                      "target_offset_m": robot.target_offset.tolist(),
                      "compliant_joints": list(robot.compliant_joints), "name": robot.title,
                      **({"fixed_base": True} if s.fixed_base else {})},
            "measuring_frame": {"rotation": fit.model.rotation0.tolist(),
                                "translation_m": fit.model.translation0.tolist()},
            "markers": [{"name": m.name, "frame": m.frame, "offset_m": list(map(float, m.offset)),
                         "rotation_rad": list(map(float, pin.log3(m.rotation)))}
                        for m in fit.model.markers],
            "load_frame": None if campaign.loads is None else campaign.loads.frame,
            "families": list(fit.model.families),
            "settings": fit.model.settings,
            **({} if selection is None else {"selection": selection}),
            **({} if plausibility is None else {"plausibility": plausibility}),
            "parameters": parameter_table(fit),
            KEY: pose_covariance(fit).to_dict()}


def pose_covariance(fit: PoseFit) -> ParameterCovariance:
    """The covariance of ``fit``'s fitted parameters (:attr:`PoseFit.covariance`, SI, each in
    its unit) in the parameter table's order, labelled by their ``parameter``, for the noise
    std the fit used (:mod:`stiffness.elastic.parameter_covariance`)."""
    kept = list(fit.identifiability.kept)
    order = np.argsort(kept)
    params = [fit.model.parameters[kept[i]] for i in order]
    return ParameterCovariance(tuple(p.label for p in params), tuple(p.unit for p in params),
                               np.asarray(fit.covariance)[np.ix_(order, order)],
                               float(fit.sigma), POSE_VARIABLES)


def write_pose_model(fit: PoseFit, campaign: PoseCampaign, path: str | os.PathLike,
                     selection: dict | None = None, plausibility: dict | None = None) -> Path:
    """Write the pose model file (JSON, atomically; :func:`pose_model_dict`)."""
    path = Path(path)
    atomic_write(path, json.dumps(pose_model_dict(fit, campaign, path.parent, selection,
                                                  plausibility), indent=1) + "\n")
    return path


@dataclass
class PoseModelFile:
    """A pose model file read back: its robot, its model and parameters, and their
    covariance (``None`` in a file written before it)."""

    robot: Robot
    model: PoseModel
    x: np.ndarray
    path: Path
    covariance: ParameterCovariance | None = None


def read_pose_model(path: str | os.PathLike, robot: Robot | None = None) -> PoseModelFile:
    """Read a pose model file written by :func:`write_pose_model`
    (:func:`~stiffness.robot.calibration.read_pose_calibration`) into its marker-position
    model on the nominal robot (``robot``: default the one the file names).

    Raises
    ------
    FileFormatError
        Not a pose model file, or a missing or malformed key (named).
    """
    cal = read_pose_calibration(path)
    try:
        robot = robot or load_robot(cal.source, frame=cal.frame, target_offset=cal.target_offset_m,
                                    compliant_joints=cal.compliant_joints,
                                    fixed_base=cal.fixed_base)
        markers = [Marker(name, frame, offset, cal.declared_rotation(name),
                          cal.is_oriented(name)) for name, frame, offset in cal.markers]
        model = PoseModel(robot, markers, cal.families, (cal.rotation, cal.translation),
                          None if cal.load_frame is None else Loads(cal.load_frame,
                                                                    np.zeros((0, 6))),
                          cal.settings)
        values = cal.values()
        x = np.array([values[p.label] for p in model.parameters])
    except (KeyError, TypeError, ValueError) as exc:
        raise FileFormatError(f"malformed pose model file ({exc!r}); rewrite it with "
                              "stiffness diagnose --out", path=cal.path) from exc
    doc = read_json(cal.path, "pose model file")
    covariance = None if KEY not in doc else ParameterCovariance.from_dict(
        doc[KEY], lambda text: FileFormatError(f"{text}; rewrite it with stiffness diagnose "
                                               "--out", path=cal.path))
    return PoseModelFile(robot, model, x, cal.path, covariance)
