"""``diagnose --validate OTHER`` on a deflection campaign: the baseline's and each step's fitted
model evaluated on another deflection campaign of the same robot without refitting (the stage
table of a pose diagnosis, issue 35), and the final model file on it (the ``validation`` key,
:func:`~stiffness.calibration.validation.validate_deflection_model`).

A step's model is its fitted :class:`~stiffness.elastic.effects.hypothesis.Hypothesis` over the
other campaign's rows, every effect applied, measurement effects included (what the other
campaign's instrument reads; at another declared target offset, its own, without a fitted
``target_offset``, as the model file moved there); its errors, noise and verdict are those
of :class:`~stiffness.calibration.validation.Validation`, with the step's own parameter
uncertainty (its fit's covariance at the diagnosis's noise) when the final model file's is
taken. The last stage is the final model: its numbers are the ``validation`` key's (to
rounding).
"""

from __future__ import annotations

import os

import numpy as np

from stiffness.calibration.campaign import Campaign, campaign_kind, load_campaign
from stiffness.calibration.diagnosis import Diagnosis
from stiffness.calibration.fitting import Fit, Objective, compliance_covariance
from stiffness.calibration.pose_campaign import PoseCampaign
from stiffness.calibration.validation import (
    Validation,
    campaign_name,
    deflection_validation,
    same_robot,
    validate_deflection_model,
)
from stiffness.elastic.effects.geometry import Geometry, Rows
from stiffness.elastic.effects.hypothesis import Hypothesis
from stiffness.elastic.parameter_covariance import ParameterCovariance
from stiffness.errors import StiffnessError

#: The keys of a stage's validation: the errors', the noise's and the verdict's (not the model,
#: campaign and robot, which are the final ``validation``'s).
_NOT_STAGE_KEYS = ("model", "campaign", "robot", "kind")


def other_campaign(campaign: Campaign,
                   validate: Campaign | PoseCampaign | str | os.PathLike) -> Campaign:
    """``validate`` read as a deflection campaign of ``campaign``'s robot, before the work.

    Raises
    ------
    StiffnessError
        A pose campaign (one line).
    ModelRobotError
        A campaign of another robot.
    """
    if isinstance(validate, PoseCampaign) or (
            not isinstance(validate, Campaign) and campaign_kind(validate) == "poses"):
        raise StiffnessError(f"--validate {campaign_name(validate)} is a pose campaign; a "
                             "deflection campaign is validated on another deflection campaign "
                             "of the same robot")
    other = validate if isinstance(validate, Campaign) else load_campaign(validate)
    same_robot(campaign.resolved_source(), campaign.robot, other.robot(),
               other.resolved_source(), f"the diagnosis of {campaign.name}",
               campaign_name(validate))
    return other


def validated(d: Diagnosis, other: Campaign,
              validate: Campaign | PoseCampaign | str | os.PathLike) -> Diagnosis:
    """``d`` with its final model file evaluated on ``other`` (``validate`` read by
    :func:`other_campaign`, which names it: :attr:`Diagnosis.validation`) and, when ``other``
    measured the same target frame as ``d``'s campaign (at any offset), the baseline and each
    step too (:attr:`Diagnosis.baseline_validation`, :attr:`Step.validation`)."""
    final = validate_deflection_model(d.model_file(), "the final model", other if isinstance(
        validate, Campaign | PoseCampaign) else validate)
    d.validation = final.to_dict()
    robot = other.robot()
    if robot.target_frame != d.geometry.robot.target_frame:
        return d  # another target frame: only the model file moves there
    moved = not np.allclose(robot.target_offset, d.geometry.robot.target_offset, rtol=0.0,
                            atol=1e-12)
    geometry = Geometry.of(robot) if moved else d.geometry
    rows = geometry.rows(other.q, other.force, other.moment,
                         labels=[other.describe_row(i) for i in range(other.n_rows)],
                         joint_angles=other.robot_settings.joint_angles)
    d.baseline_validation = _stage(d, d.baseline, geometry, rows, other, final, moved)
    for step in d.steps:
        step.validation = _stage(d, step.fit, geometry, rows, other, final, moved)
    return d


def _stage(d: Diagnosis, fit: Fit, geometry: Geometry, rows: Rows, other: Campaign,
           final: Validation, moved: bool) -> dict:
    """The validation keys of ``fit`` (its parameters, not refitted) on ``other``'s ``rows``
    of ``geometry``, against the noise ``final`` states, with ``fit``'s parameter
    uncertainty (its covariance at ``d``'s noise, :func:`~stiffness.calibration.fitting.
    compliance_covariance`, as the final model file's) when ``final`` took the model's;
    ``moved``: ``other`` declared another target offset, its own, so a fitted
    ``target_offset`` (which moved this campaign's) does not apply, as in the model file
    moved there (:func:`~stiffness.elastic.file_model.elastic_model_of`)."""
    m = fit.model
    kept = [i for i, e in enumerate(m.effects) if not (moved and e.name == "target_offset")]
    columns = list(range(m.offsets[1])) + [c for i in kept
                                           for c in range(m.offsets[i + 1], m.offsets[i + 2])]
    x = fit.x[columns]
    model = Hypothesis(geometry, rows, m.baseline, m.compliant,  # rotations in rad (w = 1)
                       tuple(m.effects[i] for i in kept), m.refs,
                       None if other.rotation is None else 1.0, m.held)
    predicted = model.predict(x)
    jac, labels, cov = None, [fit.labels()[c] for c in columns], None
    if final.parameters is not None:  # d pred / d x: analytic, else the fit's differences
        jac = Objective(model, np.zeros_like(predicted), 1.0).data_jacobian(x).reshape(
            *predicted.shape, -1)
        cov = ParameterCovariance(tuple(labels), ("",) * len(labels), compliance_covariance(
            fit, d.noise_std_m, d.measured)[np.ix_(columns, columns)])
    stage = deflection_validation(final.model, final.campaign, final.robot, other, predicted,
                                  jac, labels, cov).to_dict()
    return {k: v for k, v in stage.items() if k not in _NOT_STAGE_KEYS}
