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
:data:`~stiffness.calibration.diagnose.CV_TOP` are validated by leaving one configuration out
at a time, from each fit's linearised hat matrix without refitting
(:func:`~stiffness.calibration.pose_fit.held_out_rms`, stable on small campaigns where folds
would leave about as many parameters as poses): the first whose held-out RMS falls is added.
The user may force families in (added first, in order) and forbid others
(``diagnose --families``, ``--not``; kept in the model file's ``selection``).
Only identifiable parameters are fitted (:mod:`stiffness.calibration.pose_fit`). At the
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
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stiffness.calibration.breakdown import error_summary
from stiffness.calibration.certainty import Certainty
from stiffness.calibration.naming import alternative, is_stand_in, namable, settle
from stiffness.calibration.outliers import OUTLIER_THRESHOLD, Outlier
from stiffness.calibration.pose_campaign import PoseCampaign
from stiffness.calibration.pose_fit import (
    PoseFit,
    campaign_settings,
    fit_pose_model,
    flag_pose_outliers,
    held_out_rms,
    linearised_rss,
    predict,
    rows_of,
    starting_frame,
)
from stiffness.calibration.pose_model import Loads, Marker, PoseModel
from stiffness.calibration.pose_orientation import orientation_errors
from stiffness.calibration.pose_parameters import PoseJudge
from stiffness.calibration.selection import (
    BIC_MARGIN,
    CV_TOP,
    GOF_LEVEL,
    fits_to_noise,
    goodness_of_fit,
    step_criteria,
)
from stiffness.calibration.solver import check_loss
from stiffness.cores import one_blas_thread
from stiffness.elastic.effects import FAMILIES, check_masses
from stiffness.elastic.effects.base import Parameter
from stiffness.elastic.effects.base_tilt import DECLARED_TILT, declared_tilt
from stiffness.errors import FileFormatError, StiffnessError
from stiffness.files import atomic_write, written_source
from stiffness.robot.calibration import POSE_MODEL_KIND, read_pose_calibration
from stiffness.robot.robot import Robot, load_robot
from stiffness.workspace.distributed import run_chunks

#: The families every pose diagnosis starts with (the tracker's placement and the markers).
BASE_FAMILIES = ("frame", "markers")
#: Families tried after the base, by whether the robot's masses are trusted.
#: (link_compliance and backlash need the links' masses; gravity_compensator acts through
#: joint_compliance and is tried once that is in: docs/absolute-poses.md.)
CANDIDATES = {"known": ("joint_offsets", "geometry", "joint_compliance",  # keys: MASSES
                        "link_compliance", "transversal_compliance", "base_tilt", "backlash",
                        "gravity_compensator"),
              "unknown": ("joint_offsets", "geometry", "gravity_lumped")}
#: Why a search stops when the families that pass BIC may not be named (issue 36.4).
NOT_NAMABLE = ("the families that improve BIC determine none of their parameters within its "
               "physical scale with an interval excluding zero")
#: A progress-bar factory: given a label, a ``(done, total)`` callback or ``None``.
Bar = Callable[[str], Callable[[int, int], None] | None]
#: The held-out criterion of every step (``cv_rms``): leave one configuration out, from the
#: linearised hat matrix (:func:`~stiffness.calibration.pose_fit.held_out_rms`).
HELD_OUT_CRITERION = "leave-one-configuration-out (linearised hat matrix)"


@dataclass
class PoseStep:
    """One step of a pose diagnosis."""

    family: str
    fit: PoseFit
    delta_bic: float
    cv_rms: float
    validation: dict | None = None
    forced: bool = False
    ranking: dict[str, float] = field(default_factory=dict)


@dataclass
class PoseDiagnosis:
    """The steps, the final fit and the verdict of a pose diagnosis; ``outliers`` the poses
    the final fit does not explain and ``outlier_sigma_m`` the noise std (m) they were
    standardised by (:func:`~stiffness.calibration.pose_fit.flag_pose_outliers`; flagged,
    none dropped)."""

    campaign: PoseCampaign
    masses: str
    steps: list[PoseStep]
    rejected: dict[str, float] = field(default_factory=dict)
    loss: str = "linear"
    forced: list[str] = field(default_factory=list)
    forbidden: list[str] = field(default_factory=list)
    outliers: list[Outlier] = field(default_factory=list)
    outlier_sigma_m: float | None = None
    stop_reason: str = ""
    judge: PoseJudge | None = None
    loss_scale: float | None = None

    @functools.cached_property
    def how_sure(self) -> list[Certainty]:
        """How sure the diagnosis is of each family it added (:func:`_how_sure`; computed
        when first asked: it refits the final model without each)."""
        return _how_sure(self, self.families, self.loss_scale)

    def selection(self) -> dict:
        """How the families were chosen (kept in the model file): ``forced`` and
        ``forbidden`` (``--families``, ``--not``) and the ``held_out`` criterion."""
        return {"forced": self.forced, "forbidden": self.forbidden,
                "held_out": HELD_OUT_CRITERION}

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
                "robot_name": self.campaign.robot.title,
                "unit": self.campaign.units.length, "masses": self.masses,
                "loss": self.loss,
                "noise_std": None if self.campaign.noise_std is None
                else self.campaign.noise_std / lu,
                "steps": [{"family": s.family, "rms": s.fit.rms() / lu,
                           "delta_bic": s.delta_bic, "cv_rms": s.cv_rms / lu,
                           "n_parameters": s.fit.n_fitted, "converged": s.fit.converged,
                           "forced": s.forced, **self._named(s),
                           **({"validation": s.validation} if s.validation else {})}
                          for s in self.steps],
                "rejected": self.rejected, "families": self.families,
                "stop_reason": self.stop_reason,
                "selection": self.selection(),
                "gof_p": self.gof(), "unexplained": self.unexplained,
                "outlier_threshold": OUTLIER_THRESHOLD,
                "outliers": [o.to_dict() for o in self.outliers],
                "identifiability": self.final.identifiability.to_dict(
                    [p.label for p in self.final.model.parameters]),
                "parameters": parameter_table(self.final, self.judge),
                "how_sure": [c.to_dict(lu) for c in self.how_sure],
                "residual_structure": residual_structure(self.final, self.campaign)}

    def stand_in(self, family: str) -> bool:
        """Whether the final model's ``family`` is a stand-in (its size is not physical:
        :func:`stiffness.calibration.naming.is_stand_in`)."""
        if self.judge is None:
            return False
        return is_stand_in(self.judge.parameters(self.final).get(family, []))

    def _named(self, step: PoseStep) -> dict:
        """A step's ``parameters`` (its family's, as that step fitted them, SI) and
        ``stand_in`` (in the final model), the keys of a deflection diagnosis's steps."""
        if self.judge is None or step.family == "baseline":
            return {}
        params = self.judge.parameters(step.fit)[step.family]
        return {"parameters": {p.name: p.to_dict() for p in params},
                "stand_in": self.stand_in(step.family)}


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
    return [{"family": p.family, "parameter": p.label, "unit": p.unit,
             "value": float(fit.x[i]), "fitted": i in kept,
             "std": None if i not in kept else float(std[i]),
             "interval_95": None if i not in kept else [float(lo[i]), float(hi[i])],
             "at_bound": i in fit.at_bound,
             **({k: v for k, v in judged[p.label].to_dict().items()
                 if k not in ("value", "unit", "at_bound")} if p.label in judged else {})}
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
         settings: dict, start: PoseFit | dict[str, float] | None = None,
         loss: str = "linear", scale: float | None = None,
         held: dict[str, str] | None = None) -> PoseFit:
    """Fit ``families``, starting from ``start``'s values of the parameters they share (a fit,
    or its values by label), under ``loss`` scaled by ``scale`` (m; :func:`fit_pose_model`),
    the parameters of ``held`` (label: why; default those ``start`` held) held at nominal."""
    model = PoseModel(campaign.robot, campaign.markers, tuple(families), frame0, campaign.loads,
                      settings)
    if held is None:
        held = held_labels(start) if isinstance(start, PoseFit) else {}
    index = {p.label: i for i, p in enumerate(model.parameters)}
    return fit_pose_model(model, campaign, rows_of(model, campaign), families,
                          None if start is None else warm_start(model, start), loss, scale,
                          held={index[k]: why for k, why in held.items() if k in index})


def held_labels(fit: PoseFit) -> dict[str, str]:
    """The parameters ``fit`` holds at nominal because the data do not determine them
    (label: why)."""
    labels = [p.label for p in fit.model.parameters]
    return {labels[d.index]: d.note for d in fit.identifiability.dropped
            if d.reason == "undetermined"}


def settled(campaign: PoseCampaign, fit: PoseFit, families: list[str], judge: PoseJudge,
            scale: float | None) -> PoseFit:
    """``fit`` (of ``families``, in the order chosen) with the parameters of its last family
    that the data do not determine held at nominal, the least determined first
    (:func:`stiffness.calibration.naming.settle`, as deflection diagnose's effects)."""
    model, family = fit.model, families[-1]
    frame0 = (model.rotation0, model.translation0)

    def hold(trial: PoseFit, ks: list[int], ps: list[Parameter], whys: list[str]) -> PoseFit:
        return _fit(campaign, families, frame0, model.settings, trial, trial.loss, scale,
                    {**held_labels(trial), **{p.name: why for p, why in zip(ps, whys,
                                                                           strict=True)}})

    sizes = model.family_objects[model.families.index(family)].physical_sizes(
        model, judge.references(fit))
    start = model.slices()[family].start
    return settle(fit, lambda trial: judge.parameters(trial)[family], sizes, hold,
                  lambda trial, loose: _uncorrelated(trial, [start + k for k in loose],
                                                     loose))


#: Parameters held together in one refit (:func:`settled`) are correlated by less than this.
HOLD_CORRELATION = 0.3


def _uncorrelated(fit: PoseFit, columns: list[int], loose: list[int]) -> list[int]:
    """Of ``loose`` (the undetermined parameters, least determined first; ``columns`` their
    model columns), the first and each next one whose correlation with every one chosen is
    below :data:`HOLD_CORRELATION` in ``fit``'s covariance."""
    place = {i: c for c, i in enumerate(fit.identifiability.kept)}
    cov = fit.covariance
    chosen: list[int] = []
    for k, i in zip(loose, columns, strict=True):
        if i not in place:
            continue
        a = place[i]
        if all(abs(cov[a, place[j]]) < HOLD_CORRELATION * math.sqrt(cov[a, a] * cov[place[j],
                                                                                  place[j]])
               for j in (columns[loose.index(m)] for m in chosen)):
            chosen.append(k)
    return chosen


def warm_start(model: PoseModel, fit: PoseFit | dict[str, float]) -> np.ndarray:
    """``fit``'s parameter values laid out for ``model`` (zero for parameters it lacks)."""
    values = fit if isinstance(fit, dict) else _values(fit)
    return np.array([values.get(p.label, 0.0) for p in model.parameters])


def _values(fit: PoseFit) -> dict[str, float]:
    """A fit's parameter values by label."""
    return {p.label: float(v) for p, v in zip(fit.model.parameters, fit.x, strict=True)}


def candidate_fit(campaign: PoseCampaign, families: list[str],
                  frame0: tuple[np.ndarray, np.ndarray], settings: dict, start: dict[str, float],
                  loss: str, scale: float | None, candidates: list[str], index: int
                  ) -> tuple[PoseFit, float]:
    """One task of a step's candidates (module-level: it runs on Dask workers): candidate
    ``candidates[index]`` added to ``families``, fitted from ``start`` (values by label), and
    its held-out RMS (m, :func:`held_out_rms`)."""
    fit = _fit(campaign, families + [candidates[index]], frame0, settings, start, loss, scale)
    return fit, held_out_rms(fit, campaign)


@one_blas_thread
def diagnose_poses(campaign: PoseCampaign, masses: str = "known", seed: int = 0,
                   validate: PoseCampaign | None = None,
                   progress: Callable[[str], None] | None = None,
                   loss: str = "linear", families: Sequence[str] = (),
                   not_families: Sequence[str] = (),
                   base_tilt: Sequence[float] | None = None, workers: int | None = None,
                   bar: Bar | None = None) -> PoseDiagnosis:
    """Close the gap between the nominal robot and the measured poses, family by family.

    Parameters
    ----------
    masses
        ``"known"`` (the robot's inertias are trusted: joint compliance times gravity torque)
        or ``"unknown"`` (lumped compliance-times-mass-moment parameters).
    seed
        Kept for the signature shared with deflection diagnose: the held-out criterion
        (leave one configuration out, :func:`~stiffness.calibration.pose_fit.held_out_rms`)
        draws nothing at random.
    validate
        Another pose campaign of the same robot and markers, evaluated at every step.
    progress
        Called with one line of text as each step starts (``None``: quiet).
    loss
        ``linear`` (least squares) or a robust loss of
        :data:`~stiffness.calibration.solver.LOSSES` for every fit, scaled by the declared
        noise std, else by the baseline's robust estimate; BIC and the fit-to-noise test
        compare :meth:`PoseFit.loss_rss` (:mod:`stiffness.calibration.pose_fit`).
    families
        Families forced in (``diagnose --families``): added first, in this order, whatever
        their BIC and held-out error (a family another one acts through must come before it).
    not_families
        Families never tried (``diagnose --not``).
    base_tilt
        A measured tilt ``(r_x, r_y)`` (rad) of the robot's base against gravity
        (``diagnose --base-tilt``, deg there): every model of the diagnosis feels gravity
        turned by it (model setting ``base_tilt_rad``, kept in the model file), and the
        ``base_tilt`` family fits what remains.
    workers
        Above 1, a step's candidate fits (each with its held-out RMS) run side by side on a
        Dask LocalCluster of that many single-threaded processes
        (:func:`~stiffness.workspace.distributed.run_chunks`, as ``scan --workers``); ``None``
        or 1, in this process. The result does not depend on it.
    bar
        Given a label, a progress callback ``(done, total)`` for the held-out criterion's
        configurations (``diagnose`` draws a bar on a terminal), or ``None``.

    Raises
    ------
    StiffnessError
        An unknown ``masses`` or ``loss``; a forced or forbidden name that is not a candidate
        family of ``masses``, or a family both forced and forbidden, or forced before the
        family it acts through.
    """
    say = progress or (lambda text: None)
    check_masses(masses)
    check_loss(loss)
    forced, forbidden = _choice(masses, families, not_families)
    say(f"pose diagnosis: {campaign.n_rows} rows, baseline (measuring frame and markers)")
    frame0 = starting_frame(campaign)
    chosen = list(BASE_FAMILIES)
    settings = campaign_settings(campaign)
    if base_tilt is not None:
        settings[DECLARED_TILT] = [float(v) for v in base_tilt]
        declared_tilt(settings)  # two finite angles, else a one-line error
    base = _fit(campaign, chosen, frame0, settings, loss=loss)
    judge = PoseJudge.of(campaign)
    scale = None if loss == "linear" else base.sigma  # every fit under one loss scale
    draw = bar or (lambda label: None)
    steps = [PoseStep("baseline", base, 0.0, held_out_rms(base, campaign, draw("held-out")),
                      _validation(base, validate))]
    for f in forced:
        say(f"step {len(steps)}: {f} (forced)")
        chosen.append(f)
        fit = settled(campaign, _fit(campaign, chosen, frame0, settings, steps[-1].fit, loss,
                                     scale), chosen, judge, scale)
        delta = _delta_bic(campaign, steps[-1].fit, {f: fit.loss_rss()}, {f: fit.n_fitted})
        steps.append(PoseStep(f, fit, delta[f], held_out_rms(fit, campaign, draw(f"held-out {f}")),
                              _validation(fit, validate), forced=True, ranking=delta))
    remaining = [f for f in CANDIDATES[masses] if f not in forced and f not in forbidden]
    rejected, stop = _search(campaign, chosen, frame0, settings, steps, remaining, scale,
                             validate, say, workers, draw, judge)
    outliers, outlier_sigma = flag_pose_outliers(steps[-1].fit, campaign)
    return PoseDiagnosis(campaign, masses, steps, rejected, loss, list(forced),
                         sorted(forbidden), outliers, outlier_sigma, stop, judge, scale)


def _how_sure(d: PoseDiagnosis, chosen: list[str], scale: float | None) -> list[Certainty]:
    """How sure ``d`` is of each family it added (``chosen``: the final model's families in
    order), as deflection diagnose's effects (:mod:`stiffness.calibration.certainty`): the
    final model refitted without it (and the families acting through it), its BIC change and
    held-out RMS change; the best other family of its step and its BIC change minus the
    chosen one's; whether it is a stand-in."""
    final, campaign = d.final, d.campaign
    frame0 = (final.model.rotation0, final.model.translation0)
    out = []
    for step in d.steps[1:]:
        keep = [f for f in chosen if f != step.family
                and step.family not in FAMILIES[f].requires]
        without = _fit(campaign, keep, frame0, final.model.settings, final, final.loss, scale)
        ranking = sorted(step.ranking.items(), key=lambda item: item[1])
        other, d_other = alternative(ranking, step.family, step.delta_bic)
        out.append(Certainty(step.family,
                             held_out_rms(without, campaign) - d.steps[-1].cv_rms,
                             without.bic(campaign.noise_std) - final.bic(campaign.noise_std),
                             other, d_other, d.stand_in(step.family)))
    return out


def _choice(masses: str, families: Sequence[str], not_families: Sequence[str]
            ) -> tuple[list[str], set[str]]:
    """The forced families (in order) and the forbidden ones, checked (one-line errors)."""
    valid = CANDIDATES[masses]
    for flag, names in (("--families", families), ("--not", not_families)):
        wrong = [f for f in names if f not in valid]
        if wrong:
            raise StiffnessError(f"{flag} {wrong[0]!r} is not a candidate family with masses "
                                 f"{masses}; name some of {', '.join(valid)}")
    both = [f for f in families if f in not_families]
    if both:
        raise StiffnessError(f"{both[0]} is both forced (--families) and forbidden (--not); "
                             "name it in one of them")
    for n, f in enumerate(families):
        missing = [r for r in FAMILIES[f].requires if r not in families[:n]]
        if missing:
            raise StiffnessError(f"--families: {f} acts through {missing[0]}; force "
                                 f"{missing[0]} before it")
    return list(dict.fromkeys(families)), set(not_families)


def _search(campaign: PoseCampaign, chosen: list[str], frame0: tuple[np.ndarray, np.ndarray],
            settings: dict, steps: list[PoseStep], remaining: list[str], scale: float | None,
            validate: PoseCampaign | None, say: Callable[[str], None], workers: int | None,
            bar: Bar, judge: PoseJudge) -> tuple[dict[str, float], str]:
    """The family-by-family search from ``steps[-1]`` over ``remaining`` (``chosen`` and
    ``steps`` extended in place), the candidates' fits on ``workers`` Dask workers above 1,
    ``bar`` the held-out criterion's progress bars, each candidate that may be named
    (``judge``: :func:`stiffness.calibration.naming.namable`) :func:`settled`, until the model
    fits to noise
    (:func:`~stiffness.calibration.selection.fits_to_noise`, deflection diagnose's stop rule)
    or nothing helps; returns the families tried and not added, with their last BIC change,
    and why it stopped."""
    rejected: dict[str, float] = {}
    while True:
        fit = steps[-1].fit
        noise = fits_to_noise(fit.loss_rss(), fit.n_observed, fit.n_fitted, campaign.noise_std)
        if noise is not None:
            return rejected, noise
        ready = [f for f in remaining if set(FAMILIES[f].requires) <= set(chosen)]
        if not ready:
            return rejected, "no candidate family left"
        say(f"step {len(steps)}: trying {', '.join(ready)}")
        tried, held_out, screened = _screened(campaign, chosen, frame0, settings,
                                              steps[-1].fit, ready, scale, workers)
        delta = {**screened, **_delta_bic(campaign, steps[-1].fit,
                                          {f: t.loss_rss() for f, t in tried.items()},
                                          {f: t.n_fitted for f, t in tried.items()})}
        full = {f: (t.loss_rss(), t.n_fitted) for f, t in tried.items()}
        best, cv_new, unfit, namable_any = _winner(
            campaign, tried, delta, steps[-1].cv_rms, held_out, bar,
            functools.partial(_named_fit, campaign, chosen, judge, scale))
        rejected.update({f: delta[f] for f in unfit})
        remaining = [f for f in remaining if f not in unfit]
        if best is None:
            rejected.update(delta)
            return rejected, (f"no family improves BIC by more than {BIC_MARGIN:g} and the "
                              "held-out error" if namable_any else NOT_NAMABLE)
        rejected.update({f: d for f, d in delta.items() if f != best})  # tried, not added
        rejected.pop(best, None)
        chosen.append(best)
        remaining.remove(best)
        fit = tried[best]
        # a settled fit's own BIC change, under the step's overdispersion (the ranking keeps
        # the full fit's)
        settled_delta = _delta_bic(campaign, steps[-1].fit,
                                   {**{f: r for f, (r, _) in full.items()}, "": fit.loss_rss()},
                                   {**{f: k for f, (_, k) in full.items()}, "": fit.n_fitted})
        steps.append(PoseStep(best, fit, delta[best] if fit.n_fitted == full[best][1]
                              else settled_delta[""], cv_new,
                              _validation(fit, validate), ranking=delta))


def _named_fit(campaign: PoseCampaign, chosen: list[str], judge: PoseJudge,
               scale: float | None, family: str, fit: PoseFit) -> PoseFit | None:
    """The candidate ``family``'s ``fit`` :func:`settled`, or ``None`` when it may not be named
    as fitted or once settled (:func:`stiffness.calibration.naming.namable`)."""
    if not namable(judge.parameters(fit)[family]):
        return None
    fit = settled(campaign, fit, chosen + [family], judge, scale)
    return fit if namable(judge.parameters(fit)[family]) else None


def _screened(campaign: PoseCampaign, families: list[str], frame0: tuple[np.ndarray, np.ndarray],
              settings: dict, current: PoseFit, ready: list[str], scale: float | None,
              workers: int | None = None
              ) -> tuple[dict[str, PoseFit], dict[str, float], dict[str, float]]:
    """Each of ``ready`` added to ``families``, screened by one Gauss-Newton step from
    ``current`` (:func:`~stiffness.calibration.pose_fit.linearised_rss`: what its columns
    explain of the residual, to first order); the best
    :data:`~stiffness.calibration.selection.CV_TOP` by that BIC that pass
    :data:`~stiffness.calibration.selection.BIC_MARGIN` are fitted (under ``current``'s loss
    and ``scale``), on ``workers`` Dask workers above 1 (:func:`candidate_fit`). Returns those
    fits, their held-out RMS when computed on workers (else none: computed as needed), and
    every candidate's screened BIC change."""
    screen = {}
    for f in ready:
        model = PoseModel(campaign.robot, campaign.markers, tuple(families + [f]), frame0,
                          campaign.loads, settings)
        screen[f] = linearised_rss(model, campaign, rows_of(model, campaign), families + [f],
                                   warm_start(model, current), current.loss, current.sigma)
    delta = _delta_bic(campaign, current, {f: rss for f, (rss, _) in screen.items()},
                       {f: k for f, (_, k) in screen.items()})
    best = sorted((f for f in ready if delta[f] < -BIC_MARGIN), key=lambda f: delta[f])[:CV_TOP]
    if workers is None or workers <= 1 or len(best) < 2:
        return {f: _fit(campaign, families + [f], frame0, settings, current, current.loss, scale)
                for f in best}, {}, delta
    # side by side on Dask workers, each fit with its held-out RMS (the in-process search
    # validates lazily, in BIC order, until one wins: the same winner)
    done: dict[int, tuple[PoseFit, float]] = {}
    run_chunks(candidate_fit, (campaign, families, frame0, settings, _values(current),
                               current.loss, scale, best), range(len(best)),
               lambda i, result: done.__setitem__(i, result), workers=workers)
    return ({f: done[i][0] for i, f in enumerate(best)},
            {f: done[i][1] for i, f in enumerate(best)}, delta)


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


def _winner(campaign: PoseCampaign, tried: dict[str, PoseFit], delta: dict[str, float],
            cv_current: float, held_out: dict[str, float], bar: Bar,
            named: Callable[[str, PoseFit], PoseFit | None]
            ) -> tuple[str | None, float, list[str], bool]:
    """As deflection diagnose: of the extensions past :data:`BIC_MARGIN` that may be named
    (``named``: the settled fit, or ``None``; taken in BIC order, as needed), the best
    :data:`CV_TOP` are validated in that order, and the first whose held-out RMS (leave one
    configuration out, :func:`~stiffness.calibration.pose_fit.held_out_rms`, of its settled
    fit, which replaces the full one in ``tried``) beats ``cv_current`` wins (``None`` if
    none). Also returns those whose held-out RMS is infinite (a configuration alone
    determines some of their parameters): the campaign cannot validate them, and the search
    drops them; and whether any could be named. ``held_out`` holds those computed already (on
    workers, of the full fits); ``bar`` makes a progress bar of the others."""
    eligible = sorted((f for f in tried if delta[f] < -BIC_MARGIN), key=lambda f: delta[f])
    unfit: list[str] = []
    validated = 0
    for f in eligible:
        fit = named(f, tried[f]) if validated < CV_TOP else None
        if fit is None:
            continue
        validated += 1
        if fit is not tried[f]:
            tried[f] = fit
            held_out.pop(f, None)
        cv = held_out[f] if f in held_out else held_out_rms(fit, campaign,
                                                            bar(f"held-out {f}"))
        if cv < cv_current:
            return f, cv, unfit, True
        if math.isinf(cv):
            unfit.append(f)
    return None, math.nan, unfit, validated > 0


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
                        campaign.noise_std_rotation, campaign.lines)


# ------------------------------------------------------------------------------------------
# the pose model file


def pose_model_dict(fit: PoseFit, campaign: PoseCampaign, folder: str | os.PathLike,
                    selection: dict | None = None) -> dict:
    """The model file of a pose calibration written into ``folder``: robot (its source relative
    to ``folder``, :func:`~stiffness.files.written_source`), measuring frame, markers,
    parameters (SI), and ``selection`` (:meth:`PoseDiagnosis.selection`: the forced and
    forbidden families) when the fit comes from a diagnosis; read by
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
            "markers": [{"name": m.name, "frame": m.frame, "offset_m": list(map(float, m.offset))}
                        for m in fit.model.markers],
            "load_frame": None if campaign.loads is None else campaign.loads.frame,
            "families": list(fit.model.families),
            "settings": fit.model.settings,
            **({} if selection is None else {"selection": selection}),
            "parameters": parameter_table(fit)}


def write_pose_model(fit: PoseFit, campaign: PoseCampaign, path: str | os.PathLike,
                     selection: dict | None = None) -> Path:
    """Write the pose model file (JSON, atomically; :func:`pose_model_dict`)."""
    path = Path(path)
    atomic_write(path, json.dumps(pose_model_dict(fit, campaign, path.parent, selection),
                                  indent=1) + "\n")
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
