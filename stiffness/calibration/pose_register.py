"""The measuring frame registered anew on a validation campaign (``stiffness validate
--refit-frame``).

A pose calibration's measuring frame is where the tracker stood on the day of its campaign. A
campaign of another day (the tracker moved, its world frame calibrated again, the robot driven
elsewhere) sees the same robot from another frame: validated with the model's frame, its error
is that rigid motion, whatever the robot's calibration. FIGAROH's TALOS left arm, calibrated on
7 February 2022 (18 poses, 0.36 mm RMS per component) and validated on 10 February (62 poses):
93 mm of 3-D error, 12 mm of it varying. :func:`refit_frame` fits the six ``frame``
parameters alone to the other campaign's positions (Gauss-Newton on the fitted model's own
Jacobian, every other parameter at the model's value; each step weighted as soft_l1 weighs
the residuals at their robust std, 1.4826 times their median absolute value, or the declared
noise if larger: FIGAROH's TIAGo campaigns have ghost markers 0.2-1 m off, which moved a
least-squares registration by centimetres), so what is left is the robot's calibration's
error; the verdict's chi-square then counts six parameters fitted.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from stiffness.calibration.pose_campaign import PoseCampaign
from stiffness.calibration.pose_diagnose import validation_jacobian
from stiffness.calibration.pose_model import PoseModel

#: The normal distribution's std over its median absolute value.
ROBUST_STD = 1.4826

#: Gauss-Newton iterations at most, and the step (in m, or rad times the campaign's extent) at
#: which they stop.
MAX_ITERATIONS = 50
STEP_TOL = 1e-9


def refit_frame(model: PoseModel, x: np.ndarray, campaign: PoseCampaign,
                families: tuple[str, ...] = ("frame",)) -> tuple[np.ndarray, dict]:
    """``x`` (p,) with the parameters of ``families`` (``frame``, and ``markers`` for a
    marker plate mounted again) refitted to ``campaign``'s seen positions (iteratively
    reweighted least squares, soft_l1's weights: module docstring), the others held, and the
    registration: ``parameters`` (how many were refitted, the identifiable ones),
    ``translation`` (3,) and ``rotation_deg`` (3,), the rotation vector, of the motion taking
    the model's measuring frame to the refitted one (``y' = D y + d`` for every point ``y``
    the model predicts, ``translation`` ``d`` in m), ``iterations`` and ``rms`` (m, the 3-D
    error after it).

    Raises
    ------
    StiffnessError
        The campaign's markers are not the model's (:func:`validation_jacobian`).
    """
    slices = model.slices()
    frame = np.concatenate([np.arange(slices[f].start, slices[f].stop) for f in families])
    given = np.array(x, dtype=float)
    x = given.copy()
    iterations = rank = 0
    for iterations in range(1, MAX_ITERATIONS + 1):  # noqa: B007 (reported)
        residual, jac = validation_jacobian(model, x, campaign)
        seen = np.isfinite(residual).all(axis=2)
        r = residual[seen].reshape(-1)
        j = jac[seen][..., frame].reshape(r.size, -1)
        # soft_l1's weights, at the residual's robust std: a ghost marker does not move it
        scale = max(ROBUST_STD * float(np.median(np.abs(r))), campaign.noise_std or 0.0,
                    np.finfo(float).tiny)
        root = (1.0 + (r / scale) ** 2) ** -0.25
        step, _, rank, _ = np.linalg.lstsq(j * root[:, None], r * root, rcond=None)
        x[frame] += step
        if np.max(np.abs(step)) < STEP_TOL * (1.0 + np.max(np.abs(x[frame]))):
            break
    residual, _ = validation_jacobian(model, x, campaign)
    seen = np.isfinite(residual).all(axis=2)
    old_r, old_t = model.measuring_placement(given)
    new_r, new_t = model.measuring_placement(x)
    turn = new_r @ old_r.T
    return x, {"parameters": int(rank), "translation": (new_t - turn @ old_t).tolist(),
               "rotation_deg": np.degrees(pin.log3(turn)).tolist(),
               "iterations": iterations,
               "rms": float(np.sqrt(np.mean(np.sum(residual[seen] ** 2, axis=1))))}

