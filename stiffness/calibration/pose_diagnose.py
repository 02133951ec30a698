"""Diagnose on pose campaigns: the gap between the nominal robot and a tracker, closed family by
family (docs/absolute-poses.md).

Step 0 is the nominal rigid robot seen through a fitted measuring frame and marker offsets
(the tracker is anywhere; its placement is always unknown). Each later step tries the parameter
families of :data:`CANDIDATES` (:data:`~stiffness.elastic.effects.FAMILIES`: joint
zero offsets, joint placement geometry, and with the masses known joint compliance, link
compliance and backlash under gravity and the applied loads, then a spring compensator once
joint compliance is in; with the masses unknown the lumped compliance) and adds one by deflection
diagnose's criteria: its BIC (:func:`~stiffness.calibration.selection.information_criterion`
with the declared noise, inflated by the step's overdispersion) must fall by more than
:data:`~stiffness.calibration.diagnose.BIC_MARGIN`, and of those the best
:data:`~stiffness.calibration.diagnose.CV_TOP` are cross-validated over configuration labels
(:func:`~stiffness.calibration.selection.config_folds`): the first whose held-out RMS falls is
added. Only identifiable parameters are fitted (:mod:`stiffness.calibration.pose_fit`). At the
end the residual is tested against the declared noise
(:func:`~stiffness.calibration.selection.goodness_of_fit` at
:data:`~stiffness.calibration.selection.GOF_LEVEL`): what is left above it is "unexplained",
with its structure (per marker, per axis, along the row order).
"""

from __future__ import annotations

import functools
import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stiffness.calibration.breakdown import error_summary
from stiffness.calibration.fitting import check_loss
from stiffness.calibration.pose_campaign import PoseCampaign
from stiffness.calibration.pose_fit import (
    PoseFit,
    campaign_settings,
    fit_pose_model,
    linearised_rss,
    predict,
    rows_of,
    starting_frame,
)
from stiffness.calibration.pose_model import Loads, Marker, PoseModel
from stiffness.calibration.pose_orientation import orientation_errors
from stiffness.calibration.selection import (
    BIC_MARGIN,
    CV_TOP,
    GOF_LEVEL,
    config_folds,
    goodness_of_fit,
    step_criteria,
)
from stiffness.cores import forked_map, one_blas_thread
from stiffness.elastic.effects import FAMILIES
from stiffness.errors import ConvergenceError, FileFormatError, StiffnessError
from stiffness.files import atomic_write, written_source
from stiffness.robot.calibration import POSE_MODEL_KIND, read_pose_calibration
from stiffness.robot.robot import Robot, load_robot

#: The families every pose diagnosis starts with (the tracker's placement and the markers).
BASE_FAMILIES = ("frame", "markers")
#: Families tried after the base, by whether the robot's masses are trusted.
#: (link_compliance and backlash need the links' masses; gravity_compensator acts through
#: joint_compliance and is tried once that is in: docs/absolute-poses.md.)
CANDIDATES = {"known": ("joint_offsets", "geometry", "joint_compliance",  # keys: MASSES
                        "link_compliance", "backlash", "gravity_compensator"),
              "unknown": ("joint_offsets", "geometry", "gravity_lumped")}


@dataclass
class PoseStep:
    """One step of a pose diagnosis."""

    family: str
    fit: PoseFit
    delta_bic: float
    cv_rms: float
    validation: dict | None = None


@dataclass
class PoseDiagnosis:
    """The steps, the final fit and the verdict of a pose diagnosis."""

    campaign: PoseCampaign
    masses: str
    steps: list[PoseStep]
    rejected: dict[str, float] = field(default_factory=dict)
    loss: str = "linear"

    @property
    def final(self) -> PoseFit:
        """The last accepted fit."""
        return self.steps[-1].fit

    @property
    def families(self) -> list[str]:
        """Families of the final model, in the order chosen."""
        return list(BASE_FAMILIES) + [s.family for s in self.steps[1:]]

    def gof(self) -> float | None:
        """Chi-square p-value of the final residual (:meth:`PoseFit.loss_rss`) against the
        declared noise, or None (:func:`~stiffness.calibration.selection.goodness_of_fit`)."""
        fit = self.final
        return goodness_of_fit(fit.loss_rss(), fit.n_observed, fit.n_fitted,
                               self.campaign.noise_std)

    @property
    def unexplained(self) -> bool | None:
        """Whether the final residual is above the declared noise (None: no noise declared)."""
        p = self.gof()
        return None if p is None else p < 1 - GOF_LEVEL

    def to_dict(self) -> dict:
        """What ``diagnose --json`` prints for a pose campaign (lengths in the campaign unit)."""
        lu = self.campaign.units.length_to_si
        return {"kind": "poses", "campaign": self.campaign.name,
                "unit": self.campaign.units.length, "masses": self.masses,
                "loss": self.loss,
                "noise_std": None if self.campaign.noise_std is None
                else self.campaign.noise_std / lu,
                "steps": [{"family": s.family, "rms": s.fit.rms() / lu,
                           "delta_bic": s.delta_bic, "cv_rms": s.cv_rms / lu,
                           "n_parameters": s.fit.n_fitted, "converged": s.fit.converged,
                           **({"validation": s.validation} if s.validation else {})}
                          for s in self.steps],
                "rejected": self.rejected, "families": self.families,
                "gof_p": self.gof(), "unexplained": self.unexplained,
                "identifiability": self.final.identifiability.to_dict(self.final.model),
                "parameters": parameter_table(self.final),
                "residual_structure": residual_structure(self.final, self.campaign)}


def parameter_table(fit: PoseFit) -> list[dict]:
    """Each parameter with its value, standard deviation and 95 % interval (SI, unit named)."""
    lo, hi = fit.interval()
    std = fit.std()
    kept = set(fit.identifiability.kept)
    return [{"family": p.family, "parameter": p.label, "unit": p.unit,
             "value": float(fit.x[i]), "fitted": i in kept,
             "std": None if i not in kept else float(std[i]),
             "interval_95": None if i not in kept else [float(lo[i]), float(hi[i])]}
            for i, p in enumerate(fit.model.parameters)]


def residual_structure(fit: PoseFit, campaign: PoseCampaign) -> dict:
    """Where the residual sits: RMS per marker and per axis, and its trend along the rows.

    ``row_trend`` is the slope of each axis's residual against the row index (m per row) and
    the correlation coefficient: a drift (temperature, tracker) shows as a strong trend.
    """
    r = fit.residual
    lu = campaign.units.length_to_si
    per_marker = {m.name: _rms(r[:, k]) / lu for k, m in enumerate(campaign.markers)}
    per_axis = {a: _rms(r[:, :, i]) / lu for i, a in enumerate("xyz")}
    rows = np.arange(r.shape[0], dtype=float)
    trend = {}
    for i, a in enumerate("xyz"):
        values = np.nanmean(r[:, :, i], axis=1)
        ok = np.isfinite(values)
        if ok.sum() > 2 and np.std(values[ok]) > 0:
            slope = float(np.polyfit(rows[ok], values[ok], 1)[0])
            trend[a] = {"slope_per_row": slope / lu,
                        "correlation": float(np.corrcoef(rows[ok], values[ok])[0, 1])}
    return {"rms_by_marker": per_marker, "rms_by_axis": per_axis, "row_trend": trend}


def _rms(values: np.ndarray) -> float:
    v = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(v ** 2))) if v.size else float("nan")


def _fit(campaign: PoseCampaign, families: list[str], frame0: tuple[np.ndarray, np.ndarray],
         settings: dict, start: PoseFit | None = None, loss: str = "linear",
         scale: float | None = None) -> PoseFit:
    """Fit ``families``, starting from ``start``'s values of the parameters they share, under
    ``loss`` scaled by ``scale`` (m; :func:`fit_pose_model`)."""
    model = PoseModel(campaign.robot, campaign.markers, tuple(families), frame0, campaign.loads,
                      settings)
    return fit_pose_model(model, campaign, rows_of(model, campaign), families,
                          None if start is None else warm_start(model, start), loss, scale)


def warm_start(model: PoseModel, fit: PoseFit) -> np.ndarray:
    """``fit``'s parameter values laid out for ``model`` (zero for parameters it lacks)."""
    values = {p.label: v for p, v in zip(fit.model.parameters, fit.x, strict=True)}
    return np.array([values.get(p.label, 0.0) for p in model.parameters])


def _cv_rms(campaign: PoseCampaign, fit: PoseFit, families: list[str],
            frame0: tuple[np.ndarray, np.ndarray], folds: list[np.ndarray],
            workers: int | None = None) -> float:
    """Held-out RMS of the residual components, each fold fitted on the others (started from
    the fit on every row, with its loss and scale); infinite when a fold's model predicts a sag
    that does not converge at a held-out pose, or a fold cannot be fitted (fewer measured
    components than identifiable parameters): its family is then not added. ``workers`` > 1:
    the folds in that many forked processes (:func:`stiffness.cores.forked_map`; each fold is
    self-contained, so the result is the same)."""
    tasks: list[Callable[[], tuple[float, int]]] = [
        functools.partial(_fold_error, campaign, fit, families, frame0, test) for test in folds]
    errors: list[tuple[float, int]]
    if workers is not None and workers > 1:
        errors = forked_map(tasks, workers)
    else:
        errors = []
        for task in tasks:
            errors.append(task())
            if math.isinf(errors[-1][0]):
                break
    sq, count = 0.0, 0
    for fold_sq, fold_count in errors:
        if math.isinf(fold_sq):
            return math.inf
        sq, count = sq + fold_sq, count + fold_count
    return float(np.sqrt(sq / max(count, 1)))


def _fold_error(campaign: PoseCampaign, fit: PoseFit, families: list[str],
                frame0: tuple[np.ndarray, np.ndarray], test: np.ndarray) -> tuple[float, int]:
    """Sum of squares (m^2) and number of the held-out residual components of one fold
    (:func:`_cv_rms`; infinite sum when the fold cannot be fitted or its sag diverges)."""
    train = np.setdiff1d(np.arange(campaign.n_rows), test)
    try:
        part = _fit(campaign.subset(train), families, frame0, fit.model.settings, fit,
                    fit.loss, fit.sigma)
    except StiffnessError:  # the fold has fewer measured components than parameters
        return math.inf, 0
    held = campaign.subset(test)
    try:
        err = held.positions - predict(part.model, part.x, held)
    except ConvergenceError:  # the fold's model sags without bound at a held-out pose
        return math.inf, 0
    err = err[np.isfinite(err)]
    return float(err @ err), int(err.size)


@one_blas_thread
def diagnose_poses(campaign: PoseCampaign, masses: str = "known", seed: int = 0,
                   validate: PoseCampaign | None = None,
                   progress: Callable[[str], None] | None = None,
                   loss: str = "linear", workers: int | None = None) -> PoseDiagnosis:
    """Close the gap between the nominal robot and the measured poses, family by family.

    Parameters
    ----------
    masses
        ``"known"`` (the robot's inertias are trusted: joint compliance times gravity torque)
        or ``"unknown"`` (lumped compliance-times-mass-moment parameters).
    validate
        Another pose campaign of the same robot and markers, evaluated at every step.
    progress
        Called with one line of text as each step starts (``None``: quiet).
    loss
        ``linear`` (least squares) or a robust loss of
        :data:`~stiffness.calibration.fitting.LOSSES` for every fit (folds included), scaled
        by the declared noise std, else by the baseline's robust estimate; BIC and the
        fit-to-noise test compare :meth:`PoseFit.loss_rss` (:mod:`stiffness.calibration.pose_fit`).
    workers
        Processes the cross-validation folds are fitted in side by side (``None`` or 1: in
        this process); the result does not depend on it.
    """
    say = progress or (lambda text: None)
    if masses not in CANDIDATES:
        raise StiffnessError(f"masses must be one of {', '.join(CANDIDATES)}, got {masses!r}")
    check_loss(loss)
    say(f"pose diagnosis: {campaign.n_rows} rows, baseline (measuring frame and markers)")
    frame0 = starting_frame(campaign)
    folds = config_folds(tuple(campaign.labels), seed)
    families = list(BASE_FAMILIES)
    settings = campaign_settings(campaign)
    base = _fit(campaign, families, frame0, settings, loss=loss)
    scale = None if loss == "linear" else base.sigma  # every fit under one loss scale
    cv = _cv_rms(campaign, base, families, frame0, folds, workers)
    steps = [PoseStep("baseline", base, 0.0, cv, _validation(base, validate))]
    rejected: dict[str, float] = {}
    remaining = list(CANDIDATES[masses])
    while True:
        ready = [f for f in remaining if set(FAMILIES[f].requires) <= set(families)]
        if not ready:
            break
        say(f"step {len(steps)}: trying {', '.join(ready)}")
        tried, screened = _screened(campaign, families, frame0, settings, steps[-1].fit, ready,
                                    scale)
        delta = {**screened, **_delta_bic(campaign, steps[-1].fit,
                                          {f: t.loss_rss() for f, t in tried.items()},
                                          {f: t.n_fitted for f, t in tried.items()})}
        best, cv_new, unfit = _winner(campaign, families, frame0, folds, tried, delta,
                                      steps[-1].cv_rms, workers)
        rejected.update({f: delta[f] for f in unfit})
        remaining = [f for f in remaining if f not in unfit]
        if best is None:
            rejected.update(delta)
            break
        families.append(best)
        remaining.remove(best)
        steps.append(PoseStep(best, tried[best], delta[best], cv_new,
                              _validation(tried[best], validate)))
    return PoseDiagnosis(campaign, masses, steps, rejected, loss)


def _screened(campaign: PoseCampaign, families: list[str], frame0: tuple[np.ndarray, np.ndarray],
              settings: dict, current: PoseFit, ready: list[str], scale: float | None
              ) -> tuple[dict[str, PoseFit], dict[str, float]]:
    """Each of ``ready`` added to ``families``, screened by one Gauss-Newton step from
    ``current`` (:func:`~stiffness.calibration.pose_fit.linearised_rss`: what its columns
    explain of the residual, to first order); the best
    :data:`~stiffness.calibration.selection.CV_TOP` by that BIC that pass
    :data:`~stiffness.calibration.selection.BIC_MARGIN` are fitted (under ``current``'s loss
    and ``scale``). Returns those fits and every candidate's screened BIC change."""
    screen = {}
    for f in ready:
        model = PoseModel(campaign.robot, campaign.markers, tuple(families + [f]), frame0,
                          campaign.loads, settings)
        screen[f] = linearised_rss(model, campaign, rows_of(model, campaign), families + [f],
                                   warm_start(model, current), current.loss, current.sigma)
    delta = _delta_bic(campaign, current, {f: rss for f, (rss, _) in screen.items()},
                       {f: k for f, (_, k) in screen.items()})
    best = sorted((f for f in ready if delta[f] < -BIC_MARGIN), key=lambda f: delta[f])[:CV_TOP]
    return {f: _fit(campaign, families + [f], frame0, settings, current, current.loss, scale)
            for f in best}, delta


def _delta_bic(campaign: PoseCampaign, current: PoseFit, rss: dict[str, float],
               params: dict[str, int]) -> dict[str, float]:
    """Each extension's BIC change from its sum of squares ``rss`` (m^2) and its number of
    fitted ``params``, with deflection diagnose's criterion: the declared noise inflated by the
    step's overdispersion (:func:`selection.step_criteria`: what the best extension leaves
    above the noise counts as noise in the step's comparisons)."""
    base, bics, _ = step_criteria((current.loss_rss(), current.n_fitted),
                                  [(rss[f], params[f]) for f in rss], current.n_observed,
                                  campaign.noise_std)
    return {f: b - base for f, b in zip(rss, bics, strict=True)}


def _winner(campaign: PoseCampaign, families: list[str], frame0: tuple[np.ndarray, np.ndarray],
            folds: list[np.ndarray], tried: dict[str, PoseFit], delta: dict[str, float],
            cv_current: float, workers: int | None = None
            ) -> tuple[str | None, float, list[str]]:
    """As deflection diagnose: of the extensions past :data:`BIC_MARGIN`, the best
    :data:`CV_TOP` by BIC are cross-validated in that order, and the first whose held-out RMS
    beats ``cv_current`` wins (``None`` if none). Also returns those whose held-out RMS is
    infinite (a fold cannot be fitted, or its sag diverges at a held-out pose): the campaign
    cannot validate them, and the search drops them."""
    eligible = sorted((f for f in tried if delta[f] < -BIC_MARGIN), key=lambda f: delta[f])
    unfit: list[str] = []
    for f in eligible[:CV_TOP]:
        cv = _cv_rms(campaign, tried[f], families + [f], frame0, folds, workers)
        if cv < cv_current:
            return f, cv, unfit
        if math.isinf(cv):
            unfit.append(f)
    return None, math.nan, unfit


def _validation(fit: PoseFit, other: PoseCampaign | None) -> dict | None:
    return None if other is None else validation_errors(fit.model, fit.x, other)


def validation_errors(model: PoseModel, x: np.ndarray, campaign: PoseCampaign) -> dict:
    """3-D position errors of ``campaign`` under a fitted model, without refitting.

    Returns the keys of ``stiffness validate --json``: ``rms``, ``mean_error``, ``std_error``,
    ``max_error`` (of the 3-D error norm), ``unit`` (the campaign's length unit), ``rows`` and
    ``markers`` (the same keys per marker); with measured orientations also ``rotation_rms``,
    ``rotation_mean_error``, ``rotation_max_error`` (of the orientation error's angle) and
    ``rotation_unit`` (the campaign's rotation unit), overall and per marker.
    """
    campaign = _in_model_order(model.markers, campaign)
    model = PoseModel(campaign.robot, model.markers, model.families,
                      (model.rotation0, model.translation0), campaign.loads, model.settings)
    err = np.linalg.norm(campaign.positions - predict(model, x, campaign), axis=2)
    lu = campaign.units.length_to_si
    out = {**error_summary(err, lu), "rows": campaign.n_rows, "unit": campaign.units.length}
    out["markers"] = {m.name: {**error_summary(err[:, k], lu), "unit": campaign.units.length}
                      for k, m in enumerate(campaign.markers)}
    if campaign.rotations is not None:
        angle = orientation_errors(model, x, campaign, rows_of(model, campaign))
        out.update(_rotation_summary(angle, campaign))
        for k, m in enumerate(campaign.markers):
            out["markers"][m.name].update(_rotation_summary(angle[:, k], campaign))
    return out


def _rotation_summary(angle: np.ndarray, campaign: PoseCampaign) -> dict:
    """``rotation_rms``, ``rotation_mean_error``, ``rotation_max_error`` of error angles (rad)
    in the campaign's rotation unit, and ``rotation_unit``."""
    summary = error_summary(angle, campaign.units.rotation_to_si)
    return {**{f"rotation_{key}": summary[key] for key in ("rms", "mean_error", "max_error")},
            "rotation_unit": campaign.units.rotation}


def _in_model_order(fitted: list[Marker], campaign: PoseCampaign) -> PoseCampaign:
    """``campaign`` with its markers in the model's order (same names and frames required)."""
    given = {m.name: k for k, m in enumerate(campaign.markers)}
    for m in fitted:
        if m.name not in given or campaign.markers[given[m.name]].frame != m.frame:
            raise StiffnessError(f"marker {m.name!r} (on {m.frame}) of the model is not a marker "
                                 f"of the campaign ({', '.join(given)}); validate on a campaign "
                                 "with the model's markers")
    if len(given) != len(fitted):
        raise StiffnessError(f"the campaign has markers {list(given)}, the model "
                             f"{[m.name for m in fitted]}: validate with the same markers")
    order = [given[m.name] for m in fitted]
    return PoseCampaign(campaign.name, campaign.robot, campaign.settings, campaign.units,
                        list(fitted), campaign.labels, campaign.q, campaign.positions[:, order],
                        campaign.loads, campaign.noise_std, campaign.path,
                        None if campaign.rotations is None else campaign.rotations[:, order],
                        campaign.noise_std_rotation)


# ------------------------------------------------------------------------------------------
# the pose model file


def pose_model_dict(fit: PoseFit, campaign: PoseCampaign, folder: str | os.PathLike) -> dict:
    """The model file of a pose calibration written into ``folder``: robot (its source relative
    to ``folder``, :func:`~stiffness.files.written_source`), measuring frame, markers,
    parameters (SI); read by :func:`~stiffness.robot.calibration.read_pose_calibration`."""
    s, robot = campaign.settings, campaign.robot
    return {"kind": POSE_MODEL_KIND, "version": 1, "units": "SI",
            "robot": {"source": written_source(s.source, Path(folder), campaign.folder()),
                      "frame": robot.target_frame,
                      "target_offset_m": robot.target_offset.tolist(),
                      "compliant_joints": list(robot.compliant_joints),
                      **({"fixed_base": True} if s.fixed_base else {})},
            "measuring_frame": {"rotation": fit.model.rotation0.tolist(),
                                "translation_m": fit.model.translation0.tolist()},
            "markers": [{"name": m.name, "frame": m.frame, "offset_m": list(map(float, m.offset))}
                        for m in fit.model.markers],
            "load_frame": None if campaign.loads is None else campaign.loads.frame,
            "families": list(fit.model.families),
            "settings": fit.model.settings,
            "parameters": parameter_table(fit)}


def write_pose_model(fit: PoseFit, campaign: PoseCampaign, path: str | os.PathLike) -> Path:
    """Write the pose model file (JSON, atomically)."""
    path = Path(path)
    atomic_write(path, json.dumps(pose_model_dict(fit, campaign, path.parent), indent=1) + "\n")
    return path


@dataclass
class PoseModelFile:
    """A pose model file read back: its robot, its model and parameters."""

    robot: Robot
    model: PoseModel
    x: np.ndarray
    path: Path


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
        markers = [Marker(name, frame, offset) for name, frame, offset in cal.markers]
        model = PoseModel(robot, markers, cal.families, (cal.rotation, cal.translation),
                          None if cal.load_frame is None else Loads(cal.load_frame,
                                                                    np.zeros((0, 6))),
                          cal.settings)
        values = cal.values()
        x = np.array([values[p.label] for p in model.parameters])
    except (KeyError, TypeError, ValueError) as exc:
        raise FileFormatError(f"malformed pose model file ({exc!r}); rewrite it with "
                              "stiffness diagnose --out", path=cal.path) from exc
    return PoseModelFile(robot, model, x, cal.path)
