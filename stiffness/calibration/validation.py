"""A model evaluated on another campaign without refitting (``stiffness validate``,
``diagnose --validate``): the 3-D error of each row, summarised overall and per marker.

For a deflection campaign the model is a model file of ``identify`` or ``diagnose`` and each
row's error is the measured deflection minus the model's prediction under that row's load (every
effect applied, measurement effects included: what the campaign's instrument reads); the one
"marker" is the campaign's target. For a pose campaign see
:func:`stiffness.calibration.pose_diagnose.validation_errors`.
"""

from __future__ import annotations

import numpy as np

from stiffness.calibration.campaign import Campaign
from stiffness.elastic.model import ElasticModel

#: The name under which a deflection campaign's target is reported.
TARGET = "target"


def error_summary(errors: np.ndarray, length_to_si: float) -> dict:
    """RMS, mean, standard deviation and max of 3-D error norms (m) in the campaign's unit,
    and how many were seen: the keys ``rms``, ``mean_error``, ``std_error`` (the spread of the
    norms about their mean, divided by the count), ``max_error``, ``rows``.

    NaN entries (a marker not seen) are left out; all-NaN gives ``None`` values.
    """
    e = errors[np.isfinite(errors)] / length_to_si
    if not e.size:
        return {"rms": None, "mean_error": None, "std_error": None, "max_error": None,
                "rows": 0}
    return {"rms": float(np.sqrt(np.mean(e ** 2))), "mean_error": float(e.mean()),
            "std_error": float(e.std()), "max_error": float(e.max()), "rows": int(e.size)}


def deflection_errors(model: ElasticModel, campaign: Campaign) -> dict:
    """The ``stiffness validate --json`` object of a model file on a deflection campaign.

    Keys ``rms``, ``mean_error``, ``std_error``, ``max_error`` (of the 3-D deflection error),
    ``unit`` (the campaign's length unit), ``rows`` and ``markers`` (``{"target": the same keys}``).
    """
    wrench = np.hstack([campaign.force, campaign.moment if campaign.moment is not None
                        else np.zeros_like(campaign.force)])
    predicted = np.array([model.deflection(q, w, measured=True)
                          for q, w in zip(campaign.q, wrench, strict=True)])
    errors = np.linalg.norm(campaign.deflection - predicted, axis=1)
    unit = campaign.units.length
    out = {**error_summary(errors, campaign.units.length_to_si), "unit": unit}
    out["markers"] = {TARGET: {**error_summary(errors, campaign.units.length_to_si),
                               "unit": unit}}
    return out
