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
least-squares registration by centimetres), then least squares over the markers within
:data:`REJECT` robust stds of that fit, so what is left is the robot's calibration's error;
the verdict's chi-square then counts six parameters fitted. The last step is least squares
because the chi-square's count is a least-squares fit's: with soft_l1's uneven weights left in
it, a right UR5 model (12 poses, one marker, frame, marker and zero offsets fitted) judged on
8 poses of another day rejected at the 5 % level 6.0 % (frame) and 7.0 % (marker offsets too)
of 400 seeds; with them out, and the parameters' covariance projected off the refitted columns
(:func:`~stiffness.calibration.validation.refitted_jacobian`), 4.75 % and 5.5 %
(docs/absolute-poses.md, Another day). On a campaign measuring its markers' orientations
(both noises declared) the frame is fitted to them too, weighted by ``sigma_t / sigma_r`` as
the fit and the verdict weigh them: registered on the positions alone, the frame's own fit
error stayed in the orientations, and that UR5 model seen at 5e-5 rad was rejected in 39.5 %
of 200 seeds (now 6.5 %).

The same registration judges each step of a pose diagnosis on its validation campaign
(``stiffness diagnose --validate OTHER --refit-frame``, :func:`stage_errors`). Here too live
the fitted model's errors, residuals and Jacobians on another campaign of its robot, without
refitting (:func:`validation_errors`, :func:`validation_jacobian`: ``stiffness validate``'s and
the stage table's).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
import pinocchio as pin

from stiffness.calibration.breakdown import error_summary, rotation_summary
from stiffness.calibration.campaign import Campaign, campaign_kind
from stiffness.calibration.outliers import MAD_TO_STD
from stiffness.calibration.pose_campaign import PoseCampaign, load_pose_campaign
from stiffness.calibration.pose_fit import predict, rows_of
from stiffness.calibration.pose_model import Marker, PoseModel
from stiffness.calibration.pose_orientation import PoseObservations, orientation_errors
from stiffness.errors import StiffnessError, wrong_argument

#: The families a validation may fit to its campaign (``--refit-frame``, ``--refit-markers``).
REFITTABLE = ("frame", "markers")

#: Why a deflection campaign's validation refuses ``refit`` (``--refit-frame``,
#: ``--refit-markers``): ``stiffness validate``'s and ``diagnose --validate``'s.
REFIT_REFUSED = ("--refit-frame and --refit-markers take pose campaigns: a deflection "
                 "campaign measures loaded minus unloaded positions, with no measuring frame "
                 "to fit; drop them")

#: Gauss-Newton iterations at most, and the step (in m, or rad times the campaign's extent) at
#: which they stop.
MAX_ITERATIONS = 50
STEP_TOL = 1e-9

#: After the robust fit, least squares over the markers whose 3-D error is within this many
#: robust stds of it (a right model's exceeds 6 noise stds once in 10^7 markers).
REJECT = 6.0


def _observations(model: PoseModel, x: np.ndarray, campaign: PoseCampaign,
                  keep: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Measured minus predicted over the seen markers (of ``keep`` (n, M) when given):
    positions (m) and, on a campaign measuring orientations with both noises declared, the
    orientations (rad) weighted by ``sigma_t / sigma_r`` (m/rad) below, as the fit and the
    verdict weigh them, a marker's orientation also where its position is not seen (the
    verdict counts it: left out until 6 December 2026, the frame missed its rows); their
    Jacobian (N, p) and the seen markers' 3-D errors (n, M) (m, 0 where unseen)."""
    residual, jac = validation_jacobian(model, x, campaign)
    seen = np.isfinite(residual).all(axis=2)
    rows = seen if keep is None else seen & keep
    r, j = residual[rows].reshape(-1), jac[rows].reshape(-1, x.size)
    if campaign.rotations is not None and campaign.noise_std is not None \
            and campaign.noise_std_rotation is not None:
        weight = campaign.noise_std / campaign.noise_std_rotation
        turned, turned_jac = validation_orientations(model, x, campaign)
        measured = _in_model_order(model.markers, campaign).rotations
        assert measured is not None  # the campaign's, reordered
        oriented = np.isfinite(measured)  # a marker's orientation seen with no position too
        turns = np.ones_like(seen) if keep is None else keep
        kept = np.broadcast_to(turns[..., None], oriented.shape)[oriented]
        r = np.concatenate([r, weight * turned[kept]])
        j = np.vstack([j, weight * turned_jac[kept]])
    return r, j, np.linalg.norm(np.where(seen[..., None], residual, 0.0), axis=2)


def _gauss_newton(model: PoseModel, x: np.ndarray, campaign: PoseCampaign, frame: np.ndarray,
                  bound: float | None) -> tuple[np.ndarray, int, int, float]:
    """Gauss-Newton on the columns ``frame`` of ``x`` (p,) over :func:`_observations`:
    weighted as soft_l1 at the residual's robust std (or the declared noise if larger) for
    ``bound`` ``None``, else least squares over the seen markers whose 3-D error is within
    ``bound`` (m) at the start. Returns ``x``, the iterations, the rank of the last step and
    the last scale (m)."""
    keep = None
    iterations = rank = 0
    scale = 0.0
    for iterations in range(1, MAX_ITERATIONS + 1):  # noqa: B007 (returned)
        r, jac, errors = _observations(model, x, campaign, keep)
        if bound is not None and keep is None:
            keep = errors <= bound
            r, jac, _ = _observations(model, x, campaign, keep)
        j = jac[:, frame]
        scale = max(MAD_TO_STD * float(np.median(np.abs(r))) if r.size else 0.0,
                    campaign.noise_std or 0.0, np.finfo(float).tiny)
        root = (1.0 + (r / scale) ** 2) ** -0.25 if bound is None else np.ones_like(r)
        step, _, rank, _ = np.linalg.lstsq(j * root[:, None], r * root, rcond=None)
        x[frame] += step
        if np.max(np.abs(step), initial=0.0) < STEP_TOL * (1.0 + np.max(np.abs(x[frame]))):
            break
    return x, iterations, int(rank), scale


def refit_frame(model: PoseModel, x: np.ndarray, campaign: PoseCampaign,
                families: tuple[str, ...] = ("frame",)) -> tuple[np.ndarray, dict]:
    """``x`` (p,) with the parameters of ``families`` (``frame``, and ``markers`` for a
    marker plate mounted again) refitted to ``campaign``'s seen positions, and orientations
    when it measures them with both noises declared (iteratively reweighted least squares,
    soft_l1's weights, then least squares: module docstring), the others held, and the
    registration: ``parameters`` (how many were refitted, the identifiable ones),
    ``translation`` (3,) and ``rotation_deg`` (3,), the rotation vector, of the motion taking
    the model's measuring frame to the refitted one (``y' = D y + d`` for every point ``y``
    the model predicts, ``translation`` ``d`` in m), ``iterations`` and ``rms`` (m, the 3-D
    error after it).

    Raises
    ------
    StiffnessError
        The campaign's markers are not the model's (:func:`validation_jacobian`); a family
        of ``families`` not in the model.
    """
    slices = model.slices()
    if missing := [f for f in families if f not in slices]:
        flags = "--refit-markers" if "frame" not in missing else "--refit-frame, --refit-markers"
        raise StiffnessError(
            f"the model has no {' or '.join(missing)} family to fit to the campaign (its "
            f"families: {', '.join(model.families)}); validate it without refitting "
            f"{' or '.join(missing)} ({flags}), or a model fitted with it")
    frame = np.concatenate([np.arange(slices[f].start, slices[f].stop) for f in families])
    given = np.array(x, dtype=float)
    x, robust_steps, _, scale = _gauss_newton(model, given.copy(), campaign, frame, None)
    # least squares on the markers the robust fit explains: soft_l1's uneven weights left
    # the residual of a right model above its chi-square (module docstring)
    x, iterations, rank, _ = _gauss_newton(model, x, campaign, frame, REJECT * scale)
    iterations += robust_steps
    residual, _ = validation_jacobian(model, x, campaign)
    seen = np.isfinite(residual).all(axis=2)
    old_r, old_t = model.measuring_placement(given)
    new_r, new_t = model.measuring_placement(x)
    turn = new_r @ old_r.T
    return x, {"parameters": int(rank), "translation": (new_t - turn @ old_t).tolist(),
               "rotation_deg": np.degrees(pin.log3(turn)).tolist(),
               "iterations": iterations,
               "rms": float(np.sqrt(np.mean(np.sum(residual[seen] ** 2, axis=1))))}


def check_refit(refit: Sequence[str], validated: bool = True) -> tuple[str, ...]:
    """``refit`` as a tuple of :data:`REFITTABLE` names (``()``: nothing fitted), given
    with a validation campaign (``validated``).

    Raises
    ------
    StiffnessError
        Not a sequence of those names, or names without a validation campaign (one line).
    """
    if not isinstance(refit, tuple | list) or not all(isinstance(f, str) and f in REFITTABLE
                                                      for f in refit):
        raise wrong_argument("refit", refit, "() or a tuple of " + ", ".join(
            map(repr, REFITTABLE)))
    if refit and not validated:
        raise StiffnessError("refit fits the measuring frame to a validation campaign; give "
                             "validate (diagnose --validate OTHER) or drop it")
    return tuple(dict.fromkeys(refit))


def registered(model: PoseModel, x: np.ndarray, campaign: PoseCampaign,
               refit: Sequence[str] = ()) -> tuple[np.ndarray, dict | None]:
    """The parameters a fitted model is judged with on ``campaign``, and its measuring frame
    registered anew there (:func:`refit_frame`, in every case but a model fitted without the
    ``frame`` family, which has none to register: then ``None`` without ``refit``).

    Returns
    -------
    x, frame_refit
        ``x`` with the families of ``refit`` fitted to ``campaign`` (``()``: ``x`` itself),
        and the registration as ``validate --json``'s ``frame_refit``: ``applied`` (``refit``
        given: the errors are after it), ``families`` (those fitted, ``["frame"]`` when none
        was asked), ``parameters`` (their identifiable count), ``rms`` (the 3-D RMS after it),
        ``translation`` and ``unit`` (the campaign's length unit), ``rotation_deg``.

    Raises
    ------
    StiffnessError
        A ``refit`` not of :data:`REFITTABLE`; the campaign's markers not the model's.
    """
    refit = check_refit(refit)
    if not refit and "frame" not in model.slices():  # no frame fitted: nothing to register
        return np.asarray(x, dtype=float), None
    moved, registration = refit_frame(model, x, campaign, refit or ("frame",))
    lu = campaign.units.length_to_si
    return (moved if refit else np.asarray(x, dtype=float)), {
        "applied": bool(refit), "families": list(refit) or ["frame"],
        "parameters": registration["parameters"], "rms": registration["rms"] / lu,
        "translation": [v / lu for v in registration["translation"]],
        "rotation_deg": registration["rotation_deg"], "unit": campaign.units.length}


def validation_campaign(validate: Campaign | PoseCampaign | str | os.PathLike | None
                        ) -> PoseCampaign | None:
    """The pose campaign a pose diagnosis is validated on (loaded from its path), or ``None``.

    Raises
    ------
    StiffnessError
        A deflection campaign given to validate a pose diagnosis (one line).
    """
    if isinstance(validate, Campaign) or (validate is not None and not isinstance(
            validate, PoseCampaign) and campaign_kind(validate) != "poses"):
        name = repr(validate.name) if isinstance(validate, Campaign) else str(validate)
        raise StiffnessError("validate a pose campaign's diagnosis on another pose "
                             f"campaign, not on the deflection campaign {name}")
    if validate is not None and not isinstance(validate, PoseCampaign):
        return load_pose_campaign(validate)
    return validate


def stage_errors(model: PoseModel, x: np.ndarray, campaign: PoseCampaign,
                 refit: Sequence[str] = ()) -> dict:
    """A diagnosis step's model on its validation campaign (a stage of ``diagnose
    --validate``): :func:`validation_errors` with the families of ``refit`` fitted to the
    campaign first (``()``: none), and its ``frame_refit`` (:func:`registered`)."""
    x, frame = registered(model, x, campaign, refit)
    return {**validation_errors(model, x, campaign), "frame_refit": frame}


def validation_errors(model: PoseModel, x: np.ndarray, campaign: PoseCampaign,
                      residual: np.ndarray | None = None) -> dict:
    """3-D position errors of ``campaign`` under a fitted model, without refitting;
    ``residual``: its measured minus predicted positions (m) when already computed
    (:func:`validation_residual` or :func:`validation_jacobian` of the same arguments), else
    predicted here.

    Returns the keys of ``stiffness validate --json``: ``rms``, ``mean_error``, ``std_error``,
    ``max_error`` (of the 3-D error norm), ``unit`` (the campaign's length unit), ``rows`` and
    ``markers`` (the same keys per marker); with measured orientations also ``rotation_rms``,
    ``rotation_mean_error``, ``rotation_max_error`` (of the orientation error's angle) and
    ``rotation_unit`` (the campaign's rotation unit), overall and per marker.
    """
    model, campaign = _on_campaign(model, campaign)
    if residual is None:
        residual = campaign.positions - predict(model, x, campaign)
    err = np.linalg.norm(residual, axis=2)
    lu = campaign.units.length_to_si
    out = {**error_summary(err, lu), "rows": campaign.n_rows, "unit": campaign.units.length}
    out["markers"] = {m.name: {**error_summary(err[:, k], lu), "unit": campaign.units.length}
                      for k, m in enumerate(campaign.markers)}
    if campaign.rotations is not None:
        angle = orientation_errors(model, x, campaign, rows_of(model, campaign))
        out.update(rotation_summary(angle, campaign.units))
        for k, m in enumerate(campaign.markers):
            out["markers"][m.name].update(rotation_summary(angle[:, k], campaign.units))
    return out


def validation_residual(model: PoseModel, x: np.ndarray, campaign: PoseCampaign
                        ) -> np.ndarray:
    """Measured minus predicted positions (n, M, 3) of ``campaign`` (m; NaN where a marker
    was not seen; markers in the model's order, as :func:`validation_errors` reads them)."""
    model, campaign = _on_campaign(model, campaign)
    return campaign.positions - predict(model, x, campaign)


def validation_jacobian(model: PoseModel, x: np.ndarray, campaign: PoseCampaign
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Measured minus predicted positions (n, M, 3) of ``campaign`` (m; NaN where a marker
    was not seen; markers in the model's order, as :func:`validation_errors` reads them) and
    the prediction's Jacobian (n, M, 3, p) with respect to ``x``
    (:meth:`~stiffness.calibration.pose_model.PoseModel.evaluate`, the fit's)."""
    model, campaign = _on_campaign(model, campaign)
    y, jac = model.evaluate(x, rows_of(model, campaign))
    assert jac is not None
    return campaign.positions - y, jac


def validation_orientations(model: PoseModel, x: np.ndarray, campaign: PoseCampaign
                            ) -> tuple[np.ndarray, np.ndarray]:
    """Measured minus predicted orientations of ``campaign``'s seen oriented markers (N_r,)
    in rad (minus the error ``log(R_pred R_meas^T)`` the fit takes,
    :class:`~stiffness.calibration.pose_orientation.PoseObservations`; row by row, markers in
    the model's order) and its prediction's Jacobian (N_r, p) with respect to ``x``. The
    campaign measures orientations and declares both noise stds."""
    model, campaign = _on_campaign(model, campaign)
    observed = PoseObservations(model, campaign, rows_of(model, campaign))
    residual, jac = observed.evaluate(x)
    assert jac is not None and observed.weight is not None
    positions = int(observed.observed.sum())
    return -residual[positions:] / observed.weight, jac[positions:] / observed.weight


def _on_campaign(model: PoseModel, campaign: PoseCampaign) -> tuple[PoseModel, PoseCampaign]:
    """The fitted ``model`` on ``campaign``'s robot and loads, and ``campaign`` with its markers
    in the model's order (:func:`_in_model_order`): what every validation function evaluates."""
    campaign = _in_model_order(model.markers, campaign)
    return PoseModel(campaign.robot, model.markers, model.families,
                     (model.rotation0, model.translation0), campaign.loads,
                     model.settings), campaign


def _in_model_order(fitted: list[Marker], campaign: PoseCampaign) -> PoseCampaign:
    """``campaign`` with its markers in the model's order, one of the model's it does not
    measure unseen on every row (fallen off, or left out, on another day); one the model lacks,
    or on another frame, is refused."""
    given = {m.name: k for k, m in enumerate(campaign.markers)}
    model = {m.name: m.frame for m in fitted}
    for m in campaign.markers:
        if model.get(m.name) != m.frame:
            raise StiffnessError(f"marker {m.name!r} (on {m.frame}) of the campaign is not a "
                                 f"marker of the model ({', '.join(model)}); validate on a "
                                 "campaign of the model's markers")

    def pick(values: np.ndarray) -> np.ndarray:
        return np.stack([values[:, given[m.name]] if m.name in given
                         else np.full(values[:, 0].shape, np.nan) for m in fitted], axis=1)
    return replace(campaign, markers=list(fitted), positions=pick(campaign.positions),
                   rotations=None if campaign.rotations is None else pick(campaign.rotations))
