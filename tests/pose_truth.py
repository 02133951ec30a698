"""What a simulated pose campaign hides, in a fitted pose model's parameter layout, and its
intervals as the user sees them (issue 40, item 6: one copy for the pose test files).

:func:`truth` lays a :class:`HiddenPoseErrors` out as the model's parameters;
:func:`identifiable_truth` folds the truth of each dropped parameter into the kept ones it
merges into (what a kept parameter stands for); :func:`add_intervals` adds a fit's reported
intervals (:func:`parameter_table`'s ``interval_95``, what ``diagnose`` writes) of chosen
families to a :class:`stats.Coverage`.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from stats import Coverage

from stiffness.calibration.pose_diagnose import parameter_table
from stiffness.planning.simulate_poses import HiddenPoseErrors


def truth(model, hidden: HiddenPoseErrors) -> np.ndarray:
    """The hidden values in ``model``'s parameter layout (zero where nothing is hidden)."""
    x = np.zeros(model.size)
    sl = model.slices()
    if "frame" in sl:
        frame = sl["frame"].start
        x[frame:frame + 3] = hidden.frame_translation - model.translation0
        x[frame + 3:frame + 6] = pin.log3(hidden.frame_rotation @ model.rotation0.T)
    if "markers" in sl:
        x[sl["markers"]] = (hidden.marker_offsets
                            - np.array([m.offset for m in model.markers])).ravel()
    if "joint_offsets" in sl:
        x[sl["joint_offsets"]] = hidden.joint_offsets
    if "geometry" in sl:
        x[sl["geometry"]] = [hidden.placement_errors[j, k] for j, k in model.geometry]
    if "joint_compliance" in sl and hidden.stiffness is not None:
        x[sl["joint_compliance"]] = 1.0 / np.asarray(hidden.stiffness)
    labels = {p.label: i for i, p in enumerate(model.parameters)}
    for where, c in hidden.link_compliance.items():
        for k in range(2):
            x[labels[f"{where} compliance {k + 1}"]] = c[k]
    for joint, c in hidden.transversal_compliance.items():
        for k in range(2):
            x[labels[f"{joint} transversal compliance {k + 1}"]] = c[k]
    if hidden.base_tilt is not None and "base_tilt" in sl:
        x[sl["base_tilt"]] = hidden.base_tilt
    if hidden.backlash is not None and "backlash" in sl:
        for j, b in zip(model.robot.compliant_joints, hidden.backlash, strict=True):
            if f"{j} backlash" in labels:  # a joint carrying no torque has none
                x[labels[f"{j} backlash"]] = b
    return x


def identifiable_truth(fit, x: np.ndarray) -> np.ndarray:
    """``x`` with each dropped parameter's truth folded into the kept ones it merges into."""
    out = x.copy()
    for d in fit.identifiability.dropped:
        for kept, coef in d.merged_into:
            out[kept] += coef * x[d.index]
    return out


def add_intervals(coverage: Coverage, fit, hidden: HiddenPoseErrors,
                  families: tuple[str, ...] | None = None) -> int:
    """Add ``fit``'s reported 95 % intervals of ``families`` (every fitted one if ``None``)
    with the identifiable truth; returns how many were added."""
    want = identifiable_truth(fit, truth(fit.model, hidden))
    added = 0
    for i, row in enumerate(parameter_table(fit)):
        if row["fitted"] and (families is None or row["family"] in families):
            coverage.add(row["value"], row["interval_95"], want[i])
            added += 1
    return added
