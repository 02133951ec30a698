"""The elastic model a model file makes (:func:`elastic_model_of`) and the deflection its fit
predicts (:func:`fitted_deflection`).

How each effect enters the elastic model is its class's business (its one hook,
:meth:`stiffness.elastic.effects.base.Effect.contribute`; ``kind`` of
:data:`stiffness.elastic.effects.base.EFFECT_KINDS`): ``stiffness`` and ``preload`` effects change
the robot and its K_X; ``measurement`` effects (how the campaign observed its deflections) and
``lost_motion`` (backlash: a deflection, not a stiffness) are listed, not applied to K_X (the exact
equilibrium and :func:`fitted_deflection` include it). Formulas: docs/model-file.md.
"""

from __future__ import annotations

import functools
from dataclasses import replace

import numpy as np

from stiffness.elastic.effects import LIBRARY
from stiffness.elastic.effects.base import effect_variables
from stiffness.elastic.effects.geometry import Geometry, References
from stiffness.elastic.effects.hypothesis import Hypothesis
from stiffness.elastic.effects.joint_laws import JointEffect
from stiffness.elastic.effects.link_bends import segment
from stiffness.elastic.effects.parts import ElasticParts
from stiffness.elastic.model import ElasticModel
from stiffness.elastic.model_contents import ModelFile, ModelFileError, ModelRobotError
from stiffness.elastic.parameter_covariance import effect_labels, stiffness_labels
from stiffness.elastic.stiffness_units import wrong_model_stiffness_unit
from stiffness.elastic.undetermined_springs import rigid_springs, undetermined_notes
from stiffness.errors import (
    DataFileWarning,
    StiffnessError,
    did_you_mean,
    warn_user,
    with_context,
)
from stiffness.mechanics.formulation import as_wrench
from stiffness.robot.robot import load_robot

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
    rigid = rigid_springs(model.compliant_joints, model.k_theta, model.ci95_low,
                          model.ci95_high)
    notes = undetermined_notes(model.undetermined_joints, model.extra.get("confounded_joints"),
                               rigid)
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
    coords = np.asarray(q, dtype=float).reshape(-1)
    if coords.shape[0] != declared.n_coordinates:
        raise StiffnessError(f"give the {declared.n_coordinates} coordinates of "
                             f"{declared.name} ({', '.join(declared.coordinate_joints)})")
    fitted, x, _, _ = _fitted(model, coords[None], as_wrench(load)[None], measured)
    return fitted.predict(x)[0]


def fitted_prediction(model: ModelFile, q: np.ndarray, wrench: np.ndarray,
                      measured: bool = True, rotations: bool = False
                      ) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The fitted model's predicted displacements (m, 3) in m at the rows ``q`` (m,
    n_coordinates) under the wrenches (m, 6) (:func:`fitted_deflection` of each row), their
    derivatives (m, 3, p) with respect to the model file's parameter variables
    (:mod:`stiffness.elastic.parameter_covariance`: ``ln k``, an effect's compliance or SI
    value), and those variables' labels. The derivatives are the fit's: analytic where
    :meth:`Hypothesis.predict_with_jacobian` has them (:attr:`Hypothesis.analytic_columns`),
    central differences (relative step :data:`FD_STEP`) in the other columns, as the fitting
    engine takes them. With ``rotations`` the rows are (m, 6) and (m, 6, p): the target's
    displacement (m) then its rotation vector (rad, base axes), as a campaign measuring
    rotations is fitted (:attr:`Hypothesis.rotation_weight` 1 m/rad)."""
    fitted, x, labels, scale = _fitted(model, np.asarray(q, dtype=float),
                                       np.asarray(wrench, dtype=float), measured,
                                       1.0 if rotations else None)
    pred, jac = fitted.predict_with_jacobian(x)
    for i in np.flatnonzero(~fitted.analytic_columns):
        h = FD_STEP * max(1.0, abs(x[i]))
        step = np.zeros_like(x)
        step[i] = h
        jac[:, :, i] = (fitted.predict(x + step) - fitted.predict(x - step)) / (2.0 * h)
    width = 6 if rotations else 3
    return pred[:, :width], jac[:, :width] / scale, labels


#: Relative step of :func:`fitted_prediction`'s central differences (the fitting engine's).
FD_STEP = 1e-6


def _fitted(model: ModelFile, q: np.ndarray, wrench: np.ndarray, measured: bool,
            rotation_weight: float | None = None
            ) -> tuple[Hypothesis, np.ndarray, list[str], np.ndarray]:
    """The fitted model of ``model`` over the rows ``q`` (m, n_coordinates) under ``wrench``
    (m, 6), predicting rotations too with a ``rotation_weight`` (m/rad,
    :class:`Hypothesis`): its hypothesis, its parameter vector, each column's label in the file's
    covariance (:func:`~stiffness.elastic.parameter_covariance.effect_labels`) and the
    file variable's value of one unit of the column (1 for ``ln k``, the effect's
    :meth:`~stiffness.elastic.effects.base.Effect.scale` at unit references)."""
    geometry = Geometry.of(model.robot())
    rows = geometry.rows(q, wrench[:, :3], wrench[:, 3:], joint_angles=model.joint_angles)
    parts = ElasticParts({})
    effects, values, units = [], [], []
    for e in model.effects:
        if e.kind == "measurement" and not measured:
            continue
        effect = e.effect(geometry)
        effect.contribute(e.values(), parts)
        effects.append(effect)
        values.append(e.values())
        units.append([p.unit for p in e.parameters])
    smoothing = np.array([parts.smoothing.get(j, 1.0) for j in geometry.joints])
    refs = References(geometry.joints, 1.0, np.ones(len(geometry.joints)), smoothing, 1.0, 1.0, 1.0)
    labels = stiffness_labels(model.compliant_joints)
    for effect, unit in zip(effects, units, strict=True):
        labels += effect_labels(effect, unit)[0]
    scale = np.concatenate([np.ones(len(model.compliant_joints))]
                           + [e.scale(refs) for e in effects])
    baseline = "conventional" if model.formulation == "conventional" else "enhanced"
    if model.formulation == "exact" and not any(e.second_order for e in effects):
        effects.insert(0, LIBRARY["complementary_stiffness"]())
        values.insert(0, np.zeros(0))
    fitted = Hypothesis(geometry, rows, baseline, model.compliant_joints, tuple(effects), refs,
                        rotation_weight)
    x = np.concatenate([np.log(model.k_theta)] + [
        effect_variables(e, v, refs) for e, v in zip(effects, values, strict=True)])
    return fitted, x, labels, scale
