"""A model file evaluated on another campaign of either kind, without refitting: the function
behind ``stiffness validate`` (:func:`validate`; docs/absolute-poses.md).

For a pose campaign (``kind = "poses"``) the model is a pose calibration's ``final-model.json``
(its measuring frame and marker offsets are the model's) and the error is the 3-D position
error, overall and per marker (:func:`stiffness.calibration.pose_diagnose.validation_errors`);
for a deflection campaign the model is a model file of ``identify`` or ``diagnose`` and the
error is the measured deflection minus the model's prediction under each row's load
(:func:`stiffness.calibration.validation.deflection_errors`). Both in the campaign's length
unit.
"""

from __future__ import annotations

import os

from stiffness.calibration.campaign import campaign_kind, load_campaign
from stiffness.calibration.pose_campaign import load_pose_campaign
from stiffness.calibration.pose_diagnose import read_pose_model, validation_errors
from stiffness.calibration.validation import deflection_errors
from stiffness.elastic.model_file import load_model
from stiffness.errors import StiffnessError
from stiffness.robot.calibration import is_pose_calibration


def validate(model: str | os.PathLike, campaign: str | os.PathLike) -> dict:
    """The ``stiffness validate --json`` object: RMS, mean and max of the 3-D error of the
    model file ``model`` on ``campaign`` (a ``campaign.toml`` or its folder), in the campaign's
    length unit.

    Returns
    -------
    dict
        Keys ``rms``, ``mean_error``, ``std_error``, ``max_error``, ``unit``, ``rows`` and
        ``markers`` (the same keys per marker; a deflection campaign's one marker is ``target``).

    Raises
    ------
    StiffnessError
        A pose calibration with a deflection campaign or the other way round, or a file
        that cannot be read.
    """
    pose_model = is_pose_calibration(model)
    if (campaign_kind(campaign) == "poses") != pose_model:
        raise StiffnessError(
            f"{model} is {'a pose calibration' if pose_model else 'a deflection model'} "
            f"and {campaign} is not a {'pose' if pose_model else 'deflection'} campaign; "
            "validate a pose calibration on a pose campaign, a deflection model on a "
            "deflection campaign")
    if not pose_model:
        return deflection_errors(load_model(model), load_campaign(campaign))
    poses = load_pose_campaign(campaign)
    calibration = read_pose_model(model, poses.robot)
    return validation_errors(calibration.model, calibration.x, poses)
