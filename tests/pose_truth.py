"""What a simulated pose campaign hides, in a fitted pose model's parameter layout, and its
intervals as the user sees them (issue 40, item 6: one copy for the pose test files).

:func:`truth` lays a :class:`HiddenPoseErrors` out as the model's parameters;
:func:`identifiable_truth` folds the truth of each dropped parameter into the kept ones that
stand for it: a merged one's by its merge coefficients, a held one's (undetermined, held at
nominal by the naming rules) by its column's least-squares projection on the kept columns at
the fit (what the kept parameters' estimates absorb of it, to first order);
:func:`add_intervals` adds a fit's reported intervals (:func:`parameter_table`'s
``interval_95``, what ``diagnose`` writes) of chosen families to a :class:`stats.Coverage`.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from stats import Coverage

from stiffness.calibration.pose_fit import rows_of
from stiffness.calibration.pose_model_file import parameter_table
from stiffness.calibration.pose_orientation import PoseObservations
from stiffness.planning.simulate_poses import HiddenPoseErrors


def truth(model, hidden: HiddenPoseErrors) -> np.ndarray:
    """The hidden values in ``model``'s parameter layout (zero where nothing is hidden)."""
    x = np.zeros(model.size)
    sl = model.slices()
    if "frame" in sl:
        frame = sl["frame"].start
        x[frame:frame + 3] = hidden.frame_translation - model.translation0
        x[frame + 3:frame + 6] = pin.log3(hidden.frame_rotation @ model.rotation0.T)
    if "markers" in sl:  # the offsets; the mounting turns after them are zero (none hidden)
        start = sl["markers"].start
        x[start:start + 3 * len(model.markers)] = (
            hidden.marker_offsets - np.array([m.offset for m in model.markers])).ravel()
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
    if hidden.nonlinear is not None and hidden.stiffness is not None:
        for j, beta, k in zip(model.robot.compliant_joints, hidden.nonlinear, hidden.stiffness,
                              strict=True):
            if f"{j} nonlinear compliance" in labels:  # gamma = c beta
                x[labels[f"{j} nonlinear compliance"]] = beta / k
    for joint, (stiffness, tension) in hidden.compensator.items():
        if f"{joint} compensator stiffness" in labels:
            x[labels[f"{joint} compensator stiffness"]] = stiffness
            x[labels[f"{joint} compensator preload"]] = tension
    if hidden.backlash is not None and "backlash" in sl:
        for j, b in zip(model.robot.compliant_joints, hidden.backlash, strict=True):
            if f"{j} backlash" in labels:  # a joint carrying no torque has none
                x[labels[f"{j} backlash"]] = b
    return x


def identifiable_truth(fit, x: np.ndarray, campaign=None) -> np.ndarray:
    """``x`` with each dropped parameter's truth folded into the kept ones it merges into,
    and each held one's (``undetermined``) into the kept ones by the least-squares projection
    ``c = argmin |J_kept c - J_held|`` of its column at ``fit.x`` (``campaign``'s Jacobian;
    the fit's kept estimates are biased by ``c x_held``, exactly so for a linear model): the
    truth compared with a held parameter's neighbours is then what they stand for. The result
    is kept within the parameters' physical lower bounds (where their estimates stay).

    Raises
    ------
    ValueError
        ``fit`` holds parameters and no ``campaign`` is given.
    """
    out = x.copy()
    held = []
    for d in fit.identifiability.dropped:
        if d.reason == "undetermined":
            held.append(d.index)
        for kept, coef in d.merged_into:
            out[kept] += coef * x[d.index]
    if held and np.any(x[held]):
        if campaign is None:
            raise ValueError("a fit holding parameters needs its campaign to fold them in")
        _, jac = PoseObservations(fit.model, campaign, rows_of(fit.model, campaign)).evaluate(
            fit.x)
        kept = fit.identifiability.kept
        coefs, *_ = np.linalg.lstsq(jac[:, kept], jac[:, held], rcond=None)
        out[kept] += coefs @ x[held]
    # an estimate never leaves its physical lower bound, nor does what it stands for (a
    # truth of 0 at the bound, folded to -1e-10 by a held column's projection, is at it)
    return np.maximum(out, [p.lower for p in fit.model.parameters])


def add_intervals(coverage: Coverage, fit, hidden: HiddenPoseErrors, campaign,
                  families: tuple[str, ...] | None = None) -> int:
    """Add ``fit``'s reported 95 % intervals of ``families`` (every fitted one if ``None``)
    with the identifiable truth (``campaign``: the fit's, for its held parameters); returns
    how many were added."""
    want = identifiable_truth(fit, truth(fit.model, hidden), campaign)
    added = 0
    for i, row in enumerate(parameter_table(fit)):
        if row["fitted"] and (families is None or row["family"] in families):
            coverage.add(row["value"], row["interval_95"], want[i])
            added += 1
    return added
