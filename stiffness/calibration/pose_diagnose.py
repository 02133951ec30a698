"""Diagnose on pose campaigns: the gap between the nominal robot and a tracker, closed family by
family (docs/absolute-poses.md).

Step 0 is the nominal rigid robot seen through a fitted measuring frame and marker offsets
(the tracker is anywhere; its placement is always unknown). Each later step tries the parameter
families of :data:`CANDIDATES` (:data:`~stiffness.elastic.effects.FAMILIES`: joint
zero offsets, joint placement geometry, and with the masses known joint compliance, link
compliance and backlash under gravity and the applied loads, then a spring compensator or a
nonlinear spring once joint compliance is in; with the masses unknown the lumped compliance) in
deflection diagnose's loop (:func:`stiffness.calibration.search.search`, with :class:`PoseSearch`):
screened by one Gauss-Newton step, the best fitted, held out by leaving one configuration out
at a time from each fit's linearised hat matrix without refitting
(:func:`~stiffness.calibration.pose_fit.held_out_rms`, stable on small campaigns where folds
would leave about as many parameters as poses), then removes any the final model is better
without (:func:`~stiffness.calibration.search.eliminate`; a
:class:`~stiffness.calibration.search.Step` marked ``removed``, never a forced family). The
user may force families in (added first, in order) and forbid others (``diagnose
--families``, ``--not``; kept in the model file's ``selection``). Only identifiable parameters
are fitted (:mod:`stiffness.calibration.pose_fit`).
At the end the residual is tested against the declared noise
(:meth:`~stiffness.calibration.selection.Noise.goodness_of_fit` at
:data:`~stiffness.calibration.selection.GOF_LEVEL`, on
:func:`~stiffness.calibration.pose_fit.noise_terms`: a robust loss's flagged poses left out,
as the search's stop rule leaves them): what is left above it is "unexplained", with its
structure (per marker, per axis, along the row order).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from stiffness.calibration.identifiability import confounded
from stiffness.calibration.naming import held_reason, namable, settle
from stiffness.calibration.pose_campaign import PoseCampaign, loads_no_spring
from stiffness.calibration.pose_diagnosis import (
    BASE_FAMILIES,
    NO_PARAMETER,
    NO_PARAMETER_NOTES,
    UNLOADED,
    PoseDiagnosis,
)
from stiffness.calibration.pose_fit import (
    PoseFit,
    campaign_settings,
    fit_pose_model,
    flag_pose_outliers,
    held_out_rms,
    linearised_rss,
    noise_terms,
    rows_of,
    starting_frame,
)
from stiffness.calibration.pose_model import PoseModel
from stiffness.calibration.pose_parameters import PoseJudge
from stiffness.calibration.pose_plausibility import unphysical_values
from stiffness.calibration.pose_register import check_refit, stage_errors
from stiffness.calibration.search import (
    Candidate,
    Refusal,
    Removals,
    Step,
    Stop,
    check_max_steps,
    ranked,
    search,
)
from stiffness.calibration.selection import (
    BIC_MARGIN,
    CV_TOP,
    Noise,
    NoiseTerms,
    step_criteria,
)
from stiffness.calibration.solver import check_loss
from stiffness.cores import one_blas_thread
from stiffness.elastic.effects import FAMILIES, check_masses
from stiffness.elastic.effects.base import Held, Parameter
from stiffness.elastic.effects.base_tilt import DECLARED_TILT, declared_tilt
from stiffness.elastic.effects.preloads import GravityCompensator, declared_geometry
from stiffness.errors import StiffnessError, TooFewMeasurementsError
from stiffness.workspace.distributed import run_chunks

#: Families tried after the base, by whether the robot's masses are trusted.
#: (link_compliance and backlash need the links' masses; gravity_compensator and
#: nonlinear_joint_stiffness act through joint_compliance, tried once it is in: absolute-poses.md)
CANDIDATES = {"known": ("joint_offsets", "geometry", "joint_compliance",  # keys: MASSES
                        "link_compliance", "transversal_compliance", "base_tilt", "backlash",
                        "gravity_compensator", "nonlinear_joint_stiffness"),
              "unknown": ("joint_offsets", "geometry", "gravity_lumped")}
#: The families that act through the links' weight and the applied loads (tried only with the
#: masses known): none has an effect where nothing loads a spring (:data:`UNLOADED`).
WEIGHED = frozenset(CANDIDATES["known"]) - frozenset(CANDIDATES["unknown"])
#: A progress-bar factory: given a label, a ``(done, total)`` callback or ``None``.
Bar = Callable[[str], Callable[[int, int], None] | None]


def _fit(campaign: PoseCampaign, families: list[str], frame0: tuple[np.ndarray, np.ndarray],
         settings: dict, start: PoseFit | dict[str, float] | None = None,
         loss: str = "linear", scale: float | None = None,
         held: dict[str, Held] | None = None) -> PoseFit:
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


def held_labels(fit: PoseFit) -> dict[str, Held]:
    """The parameters ``fit`` holds at nominal because the data do not determine them
    (label: why)."""
    labels = fit.labels()
    return {labels[d.index]: d.held for d in fit.identifiability.dropped
            if d.reason == "undetermined" and d.held is not None}


def settled(campaign: PoseCampaign, fit: PoseFit, families: list[str], judge: PoseJudge,
            scale: float | None) -> PoseFit:
    """``fit`` (of ``families``, in the order chosen) with the parameters of its last family
    that the data do not determine held at nominal, the least determined first
    (:func:`stiffness.calibration.naming.settle`, as deflection diagnose's effects), then
    any parameter left with an infinite variance."""
    model, family = fit.model, families[-1]
    frame0 = (model.rotation0, model.translation0)

    sizes = model.family_objects[model.families.index(family)].physical_sizes(
        model, judge.references(fit))
    start = model.slices()[family].start
    labels = fit.labels()

    def hold(trial: PoseFit, ks: list[int], ps: list[Parameter], whys: list[str]) -> PoseFit:
        kept = trial.identifiability.kept
        place = {i: c for c, i in enumerate(kept)}
        shares = [confounded(trial.covariance, place[start + k], range(len(kept)),
                             [labels[i] for i in kept])
                  if start + k in place else () for k in ks]
        return _fit(campaign, families, frame0, model.settings, trial, trial.loss, scale,
                    {**held_labels(trial), **{p.name: Held(why, share) for p, why, share in zip(
                        ps, whys, shares or [()] * len(ps), strict=True)}})

    fit = settle(fit, lambda trial: judge.parameters(trial)[family], sizes, hold,
                 lambda trial, loose: _uncorrelated(trial, [start + k for k in loose], loose))
    # a parameter the data leave without any bound at this fit (its column zero: a vertical
    # joint's compensator held at 0 leaves the joint's compliance, kept for the compensator's
    # torque, and a last free spring of it unloaded) is held too, of any family
    for _ in range(model.size):  # each pass holds at least one more
        blind = [p for f in families for p in judge.parameters(fit).get(f, [])
                 if not p.held and not math.isfinite(p.standard_error)]
        if not blind:
            break
        fit = hold(fit, [], blind, [held_reason(p) for p in blind])
    return fit


def split_confused(campaign: PoseCampaign, fit: PoseFit, families: list[str],
                   judge: PoseJudge, scale: float | None) -> PoseFit | None:
    """``fit`` with, while no parameter of its last family may be named
    (:func:`~stiffness.calibration.naming.namable`), one of each pair of that family's fitted
    parameters the data confuse held at nominal: correlated by :data:`CONFUSED_CORRELATION` or
    more, both intervals holding zero; of a pair, the one fewer standard errors from zero,
    whose holding raises the chi-square least (by its t squared, to first order), the other
    then judged alone. ``None`` when there is no such pair.

    A family's misfit the data see only as a sum of its parameters is not unnamed for that: a
    tracker marker on digit_like's tarsus (Gepetto's example-parallel-robots) sees
    ``motor_knee``'s zero offset and ``motor_hip_z``'s alike (correlation 0.9999), so both
    intervals held zero while the family took the misfit from 14 times the noise to it.
    """
    family = families[-1]
    start = fit.model.slices()[family].start
    labels = fit.labels()
    split = None
    for _ in range(fit.model.size):
        params = judge.parameters(fit)[family]
        if namable(params):
            return split
        kept = fit.identifiability.kept
        place = {i: c for c, i in enumerate(kept)}
        loose = {place[start + k]: p for k, p in enumerate(params)
                 if not p.held and start + k in place and not p.excludes_zero
                 and 0.0 < p.standard_error < math.inf}
        cov = fit.covariance
        sd = np.sqrt(np.abs(np.diag(cov)))
        confused = [a for a in loose for b in loose
                    if a != b and abs(cov[a, b]) >= CONFUSED_CORRELATION * sd[a] * sd[b]]
        if not confused:
            return split
        a = min(confused, key=lambda a: abs(loose[a].value) / loose[a].standard_error)
        why = Held(CONFUSED_REASON, confounded(cov, a, range(len(kept)),
                                               [labels[i] for i in kept]))
        fit = split = _fit(campaign, families, (fit.model.rotation0, fit.model.translation0),
                           fit.model.settings, fit, fit.loss, scale,
                           {**held_labels(fit), labels[kept[a]]: why})
    return split


#: Correlation of two estimates of one family at or above which the data confuse them
#: (:func:`split_confused`): they see one combination of the two, not each.
CONFUSED_CORRELATION = 0.99
#: Why :func:`split_confused` holds a parameter.
CONFUSED_REASON = ("held at its nominal value: the data do not tell it from another parameter "
                   "of its family (its 95 % interval held zero)")


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


def screened(campaign: PoseCampaign, families: list[str],
             frame0: tuple[np.ndarray, np.ndarray], settings: dict, current: PoseFit
             ) -> tuple[float, int, int]:
    """:func:`~stiffness.calibration.pose_fit.linearised_rss` of adding ``families[-1]`` to
    ``current``, what it holds at nominal held as the candidate's fit (:func:`_fit`) holds it
    (moving, it gave every family the same spurious gain): objective (m^2), identifiable
    parameters, how many are the new family's."""
    model = PoseModel(campaign.robot, campaign.markers, tuple(families), frame0, campaign.loads,
                      settings)
    index = {p.label: i for i, p in enumerate(model.parameters)}
    return linearised_rss(model, campaign, rows_of(model, campaign), families,
                          warm_start(model, current), current.loss, current.sigma,
                          [index[k] for k in held_labels(current) if k in index])


def candidate_fit(campaign: PoseCampaign, families: list[str],
                  frame0: tuple[np.ndarray, np.ndarray], settings: dict, start: dict[str, float],
                  loss: str, scale: float | None, candidates: list[str], index: int
                  ) -> tuple[PoseFit | None, float]:
    """One task of a step's candidates (module-level: it runs on Dask workers): candidate
    ``candidates[index]`` added to ``families``, fitted from ``start`` (values by label), and
    its held-out RMS (m, :func:`held_out_rms`); ``(None, inf)`` where it cannot be fitted
    (:func:`_candidate`)."""
    fit = _candidate(campaign, families + [candidates[index]], frame0, settings, start, loss,
                     scale)
    return fit, (math.inf if fit is None else held_out_rms(fit, campaign))


def _candidate(campaign: PoseCampaign, families: list[str],
               frame0: tuple[np.ndarray, np.ndarray], settings: dict,
               start: PoseFit | dict[str, float], loss: str, scale: float | None
               ) -> PoseFit | None:
    """:func:`_fit` of a candidate, ``None`` where it keeps at least as many identifiable
    parameters as the campaign has measured components (it cannot be judged: not tried)."""
    try:
        return _fit(campaign, families, frame0, settings, start, loss, scale)
    except TooFewMeasurementsError:
        return None


@one_blas_thread
def diagnose_poses(campaign: PoseCampaign, masses: str = "known", seed: int = 0,
                   validate: PoseCampaign | None = None,
                   progress: Callable[[str], None] | None = None, loss: str = "linear",
                   families: Sequence[str] = (), not_families: Sequence[str] = (),
                   base_tilt: Sequence[float] | None = None, workers: int | None = None,
                   bar: Bar | None = None, max_steps: int | None = None,
                   effect_settings: dict[str, dict] | None = None,
                   refit: Sequence[str] = ()) -> PoseDiagnosis:
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
        Another pose campaign of the same robot and markers, evaluated at every step
        (:func:`~stiffness.calibration.pose_register.stage_errors`: each step's measuring frame
        registered anew there, its ``frame_refit``).
    progress
        Called with one line of text as each step starts (``None``: quiet).
    loss
        ``linear`` (least squares) or a robust loss of
        :data:`~stiffness.calibration.solver.LOSSES` for every fit, scaled by the declared
        noise std, else by the baseline's robust estimate; BIC compares :meth:`PoseFit.loss_rss`,
        the fit-to-noise test the poses not flagged (:mod:`stiffness.calibration.pose_fit`).
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
    max_steps
        Largest number of families the search adds after the forced ones (``diagnose
        --max-steps``; 0: the baseline and the forced families); ``None``: no limit.
    effect_settings
        Declared settings by effect label, as a deflection campaign's: the ``lever_m`` and
        ``base_m`` (m) of a ``gravity_compensator(JOINT)`` (``diagnose
        --compensator-geometry``; model setting ``compensator_geometry_m``, kept in the model
        file); default the library's geometry.
    refit
        With ``validate``: the families fitted to it before each step's model is judged there
        (``("frame",)``, ``diagnose --refit-frame``: the tracker moved; ``("frame",
        "markers")``, ``--refit-markers``: a marker plate mounted again); ``()``: none.

    Raises
    ------
    StiffnessError
        An unknown ``masses`` or ``loss``; a forced or forbidden name that is not a candidate
        family of ``masses``, or a family both forced and forbidden, or forced before the
        family it acts through; a negative ``max_steps``; a ``refit`` not of
        :data:`~stiffness.calibration.pose_register.REFITTABLE`, or without ``validate``.
    """
    say = progress or (lambda text: None)
    refit = check_refit(refit, validate is not None)
    check_masses(masses)
    check_max_steps(max_steps)
    check_loss(loss)
    forced, forbidden = _choice(masses, families, not_families)
    say(f"pose diagnosis: {campaign.n_rows} rows, baseline (measuring frame and markers)")
    frame0 = starting_frame(campaign)
    chosen = list(BASE_FAMILIES)
    settings = _model_settings(campaign, base_tilt, effect_settings)
    empty = _empty(campaign, frame0, settings, CANDIDATES[masses])
    _check_forced(campaign, forced, empty)
    base = _fit(campaign, chosen, frame0, settings, loss=loss)
    judge = PoseJudge.of(campaign, masses)
    scale = None if loss == "linear" else base.sigma  # every fit under one loss scale
    draw = bar or (lambda label: None)
    kind = PoseSearch(campaign, chosen, frame0, settings, scale, say, workers, draw, judge,
                      base.n_observed, campaign.noise_std,
                      _tried(masses, forced, forbidden, empty))
    steps = kind.steps
    steps.append(Step("baseline", base, 0.0, held_out_rms(base, campaign, draw("held-out")),
                      validation=_validation(base, validate, refit)))  # the markers checked first
    for f in forced:
        kind.force(f, loss)
    _, stop = search(kind, steps[-1].fit, steps[-1].cv_rms, max_steps)
    for step in steps[1:]:
        step.validation = _validation(step.fit, validate, refit)
    outliers, sigma = flag_pose_outliers(steps[-1].fit, campaign)
    return PoseDiagnosis(kind.rejected, judge, kind.not_judged, campaign=campaign, steps=steps,
                         masses=masses, loss=loss, forbidden=sorted(forbidden), stop_reason=stop,
                         outliers=outliers, outlier_sigma_m=sigma, search=kind)


def _model_settings(campaign: PoseCampaign, base_tilt: Sequence[float] | None,
                    effect_settings: dict[str, dict] | None) -> dict:
    """The model settings of every fit of the diagnosis: the campaign's, with a declared
    ``base_tilt`` ``(r_x, r_y)`` (rad) and a gravity compensator's declared geometry
    (``lever_m``, ``base_m``, m) from ``effect_settings``.

    Raises
    ------
    StiffnessError
        A base tilt that is not two finite angles, or an invalid compensator geometry.
    """
    settings = campaign_settings(campaign)
    if base_tilt is not None:
        settings[DECLARED_TILT] = [float(v) for v in base_tilt]
        declared_tilt(settings)  # two finite angles, else a one-line error
    if effect_settings:
        settings[GravityCompensator.GEOMETRY_SETTING] = declared_geometry(
            campaign.robot, effect_settings)
    return settings


def _check_forced(campaign: PoseCampaign, forced: Sequence[str], empty: set[str]) -> None:
    """Refuse a forced family with no parameter on the campaign's robot and markers (one
    line, naming the first such family of ``forced``; ``empty`` from :func:`_empty`)."""
    if empty & set(forced):
        f = next(f for f in forced if f in empty)
        raise StiffnessError(f"--families {f}: {f} has no parameter on {campaign.robot.title} "
                             "with these markers (docs/absolute-poses.md, Limits); drop it")


def _tried(masses: str, forced: Sequence[str], forbidden: set[str], empty: set[str]
           ) -> list[str]:
    """The candidate families of ``masses`` the search tries, in their order: neither forced
    (added first), forbidden, nor without a parameter (``empty``, :func:`_empty`)."""
    return [f for f in CANDIDATES[masses] if f not in {*forced, *forbidden, *empty}]


def _empty(campaign: PoseCampaign, frame0: tuple[np.ndarray, np.ndarray], settings: dict,
           families: Sequence[str]) -> set[str]:
    """The ``families`` with no parameter on the campaign's robot and markers (bearing tilts
    where no marker's chain holds a joint the springs turn, a compensator on springs on
    controller coordinates that each turn several chain joints, bends and tilts only inside
    closed loops: nothing to try)."""
    out = set()
    for f in families:
        with_it = (*BASE_FAMILIES, *FAMILIES[f].requires, f)
        sl = PoseModel(campaign.robot, campaign.markers, with_it, frame0, campaign.loads,
                       settings).slices()[f]
        if sl.stop == sl.start:
            out.add(f)
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


#: A pose campaign's candidate: a family's name and its fit.
Family = Candidate[str, PoseFit]


@dataclass
class PoseSearch:
    """The family-by-family search of :func:`diagnose_poses`, a pose campaign's
    :class:`~stiffness.calibration.search.SearchKind`: the ``remaining`` families whose
    requirements are ``chosen`` screened by one Gauss-Newton step, the best fitted (on
    ``workers`` Dask workers above 1), each judged held out by leaving one configuration out
    from its fit's hat matrix (:func:`held_out_rms`; ``bar``: its progress bars) and dropped
    when no configuration's removal can validate it (infinite). ``steps`` (from the
    baseline), ``chosen`` and ``rejected`` (families tried and not added, with their last BIC
    change) grow as the search goes; ``delta`` holds the step's BIC changes (screened or
    fitted), ``full`` the fitted candidates' :meth:`PoseFit.terms`."""

    campaign: PoseCampaign
    chosen: list[str]
    frame0: tuple[np.ndarray, np.ndarray]
    settings: dict
    scale: float | None
    say: Callable[[str], None]
    workers: int | None
    bar: Bar
    judge: PoseJudge
    n: int
    sigma: float | None
    remaining: list[str]
    steps: list[Step[str, PoseFit]] = field(default_factory=list)
    rejected: dict[str, float] = field(default_factory=dict)
    not_judged: dict[str, str] = field(default_factory=dict)
    delta: dict[str, float] = field(default_factory=dict)
    full: dict[str, tuple[float, int]] = field(default_factory=dict)
    removals: Removals[PoseFit] | None = None
    refusal: Refusal[str, PoseFit] | None = None
    cut_short: bool = False
    stops: ClassVar[dict[Stop, str]] = {
        Stop.LEFT: "no candidate family left",
        Stop.BIC: f"no family improves BIC by more than {BIC_MARGIN:g}",
        Stop.NAMED: ("the families that improve BIC determine none of their parameters within "
                     "its physical scale with an interval excluding zero"),
        Stop.HELD_OUT: (f"no family improves BIC by more than {BIC_MARGIN:g} and the held-out "
                        "error"),
        Stop.REFUSED: ("the families that improve BIC fit angles or placements no robot is "
                       "off by (a zero offset or turn beyond a few degrees, a pair that "
                       "cancel, or a joint shifted farther than such a turn moves it), so "
                       "none is named")}

    @property
    def noise(self) -> Noise | None:
        """The declared noise std (position-noise units), ``None`` when not declared."""
        return None if self.sigma is None else Noise(self.sigma)

    def noise_terms(self, fit: PoseFit) -> NoiseTerms:
        """:func:`~stiffness.calibration.pose_fit.noise_terms` of ``fit``: every observed
        component, a robust loss's flagged poses left out."""
        return noise_terms(fit, self.campaign)

    def force(self, family: str, loss: str) -> None:
        """Add ``family`` whatever its BIC and held-out error (``diagnose --families``)."""
        self.say(f"step {len(self.steps)}: {family} (forced)")
        self.chosen.append(family)
        current = self.steps[-1].fit
        fit = settled(self.campaign, _fit(self.campaign, self.chosen, self.frame0, self.settings,
                                          current, loss, self.scale),
                      self.chosen, self.judge, self.scale)
        base, (bic,), dispersion = step_criteria(current.terms(), [fit.terms()], self.n,
                                                 self.sigma)
        cv = held_out_rms(fit, self.campaign, self.bar(f"held-out {family}"))
        self.steps.append(Step(family, fit, bic - base, cv, [(family, bic - base, None)],
                               dispersion=dispersion, forced=True))

    def candidates(self, current: PoseFit) -> list[Family] | None:
        """Each ready family added to :attr:`chosen`, screened from ``current`` by one
        Gauss-Newton step (:func:`~stiffness.calibration.pose_fit.linearised_rss`: what its
        columns explain of the residual, to first order); the best
        :data:`~stiffness.calibration.selection.CV_TOP` by that BIC that pass
        :data:`~stiffness.calibration.selection.BIC_MARGIN` fitted under ``current``'s loss
        and :attr:`scale` (on Dask workers with their held-out RMS, :func:`candidate_fit`); one
        with more identifiable parameters than measured components is not fitted and the next
        in line takes its place."""
        ready = [f for f in self.remaining if set(FAMILIES[f].requires) <= set(self.chosen)]
        if not ready:
            return None
        self.say(f"step {len(self.steps)}: trying {', '.join(ready)}")
        c, families = self.campaign, self.chosen
        held_out: dict[str, float] = {}
        screens = {f: screened(c, families + [f], self.frame0, self.settings, current)
                   for f in ready}
        unloaded = loads_no_spring(c)
        for f, (_, _, fresh) in screens.items():  # none new: BIC change 0, no verdict: said
            if fresh == 0:
                self.not_judged[f] = UNLOADED if unloaded and f in WEIGHED else NO_PARAMETER
            elif self.not_judged.get(f) in NO_PARAMETER_NOTES:
                del self.not_judged[f]
        self.delta = self.deltas(current, {f: (s[0], s[1]) for f, s in screens.items()})
        order = sorted((f for f in ready if self.delta[f] < -BIC_MARGIN and screens[f][2] > 0),
                       key=lambda f: self.delta[f])
        tried: list[tuple[str, PoseFit | None]] = []
        while order and (need := CV_TOP - sum(fit is not None for _, fit in tried)) > 0:
            best, order = order[:need], order[need:]  # the next in line replace those not fitted
            more, held = self._fitted(best, current)
            tried += more
            held_out.update(held)
        fits = [(f, fit) for f, fit in tried if fit is not None]
        ranking, _ = ranked(self, current, fits)
        for candidate in ranking:
            candidate.cv_rms = held_out.get(candidate.effect)
            self.delta[candidate.effect] = candidate.delta_bic
        self.full = {f: fit.terms() for f, fit in fits}
        return ranking

    def _fitted(self, best: list[str], current: PoseFit
                ) -> tuple[list[tuple[str, PoseFit | None]], dict[str, float]]:
        """``best`` each added to :attr:`chosen` and fitted from ``current`` (``None``: more
        identifiable parameters than measured components, rejected for good), with the held-out
        RMS of those fitted on workers."""
        c, families = self.campaign, self.chosen
        held_out: dict[str, float] = {}
        tried: list[tuple[str, PoseFit | None]]
        if self.workers is None or self.workers <= 1 or len(best) < 2:
            tried = [(f, _candidate(c, families + [f], self.frame0, self.settings, current,
                                   current.loss, self.scale)) for f in best]
        else:  # side by side, each with its held-out RMS (in process: as needed, in order)
            done: dict[int, tuple[PoseFit | None, float]] = {}
            run_chunks(candidate_fit, (c, families, self.frame0, self.settings,
                                       _values(current), current.loss, self.scale, best),
                       range(len(best)), lambda i, result: done.__setitem__(i, result),
                       workers=self.workers)
            tried = [(f, done[i][0]) for i, f in enumerate(best)]
            held_out = {f: done[i][1] for i, f in enumerate(best)}
        for f in (f for f, fit in tried if fit is None):  # later steps only add parameters
            self.say(f"  {f}: more identifiable parameters than measured components; not "
                     "fitted, never tried again")
            self.rejected[f] = self.delta[f]
            self.not_judged[f] = (f"not fitted: as many identifiable parameters as the {self.n} "
                                  "measured components, or more")
            self.remaining.remove(f)
        return tried, held_out

    def parameters(self, c: Family) -> list[Parameter]:
        return self.judge.parameters(c.fit)[c.effect]

    def settle(self, c: Family) -> PoseFit:
        return settled(self.campaign, c.fit, self.chosen + [c.effect], self.judge, self.scale)

    def split_confused(self, c: Family) -> PoseFit | None:
        return split_confused(self.campaign, c.fit, self.chosen + [c.effect], self.judge,
                              self.scale)

    def unphysical(self, fit: PoseFit) -> str | None:
        """:func:`~stiffness.calibration.pose_plausibility.unphysical_values` of ``fit``, the
        forced families' values only warned about (the verdict)."""
        return unphysical_values(fit, {s.effect for s in self.steps if s.forced})

    def held_out(self, named: Iterator[Family]) -> Iterator[Family]:
        """Computed as needed, in order; a family that did not win and that the campaign
        cannot validate (infinite) is rejected and never tried again."""
        for c in named:
            if c.cv_rms is None:
                c.cv_rms = held_out_rms(c.fit, self.campaign, self.bar(f"held-out {c.effect}"))
            yield c
            if math.isinf(c.cv_rms):
                self.rejected[c.effect] = self.delta[c.effect]
                self.not_judged[c.effect] = ("held-out RMS infinite: one configuration alone "
                                             "determines some of its parameters")
                self.remaining.remove(c.effect)

    def accept(self, current: PoseFit, winner: Family, ranking: list[Family]) -> PoseFit:
        """Its BIC change that of the fit it adds (a settled fit's own, under the step's
        overdispersion; the ranking keeps the full fit's); the others tried rejected."""
        best, fit = winner.effect, winner.fit
        assert winner.cv_rms is not None  # judged held out
        self.rejected.update({f: d for f, d in self.delta.items() if f != best})
        self.rejected.pop(best, None)
        self.chosen.append(best)
        self.remaining.remove(best)
        settled_delta = self.deltas(current, {**self.full, "": fit.terms()})[""]
        *_, dispersion = step_criteria(current.terms(), [*self.full.values(), fit.terms()],
                                       self.n, self.sigma)
        cv = {c.effect: c.cv_rms for c in ranking}
        self.steps.append(Step(best, fit, self.delta[best] if fit.n_fitted == self.full[best][1]
                               else settled_delta, winner.cv_rms,
                               sorted(((f, d, cv.get(f)) for f, d in self.delta.items()),
                                      key=lambda r: r[1]), dispersion=dispersion,
                               not_judged=self._passed_over(ranking)))
        return fit

    def _passed_over(self, ranking: list[Family]) -> dict[str, str]:
        """Why each family of the step (``ranking``: those fitted) got no held-out verdict:
        an infinite held-out RMS, or screened only (the loop adds those refused or that may
        not be named, :func:`~stiffness.calibration.search.not_judged`)."""
        fitted = {c.effect for c in ranking}
        return {f: self.not_judged.get(f, f"screened {d:+.3g} by one Gauss-Newton step, "
                                          "not fitted")
                for f, d in self.delta.items() if f in self.not_judged or f not in fitted}

    def reject(self, ranking: list[Family]) -> None:
        """The step's families rejected; one refused as unphysical (:meth:`unphysical`) said
        so, and one past the margin on its screen alone, not fitted (others were): its
        screened change is no verdict."""
        self.rejected.update(self.delta)
        self.not_judged.update({c.effect: c.refused for c in ranking if c.refused is not None})
        fitted = {c.effect for c in ranking}
        for f, d in self.delta.items():
            if d < -BIC_MARGIN and f not in fitted and f not in self.not_judged:
                self.not_judged[f] = (f"screened {d:+.3g} by one Gauss-Newton step, not fitted: "
                                      f"the {CV_TOP} best screened were, and none was added")

    def without(self, final: PoseFit) -> list[PoseFit]:
        """``final`` refitted without each family it added; without the last one added by
        the step that made ``final``, that step's current fit (the same model, whose held-out
        error the step beat), not refitted."""
        frame0 = (final.model.rotation0, final.model.translation0)
        last = self.steps[-1]
        before = (self.steps[-2].fit if len(self.steps) > 1 and last.fit is final
                  and not last.removed else None)
        return [before if before is not None and s == last.effect else
                _fit(self.campaign, [f for f in self.chosen if f != s
                                     and s not in FAMILIES[f].requires],
                     frame0, final.model.settings, final, final.loss, self.scale)
                for s in self.chosen[len(BASE_FAMILIES):]]

    def removable(self, final: PoseFit) -> list[bool]:
        """Not forced (``--families``), no other chosen family acting through it."""
        forced = {s.effect for s in self.steps if s.forced}
        return [f not in forced and not any(f in FAMILIES[g].requires for g in self.chosen)
                for f in self.chosen[len(BASE_FAMILIES):]]

    def remove(self, final: PoseFit, index: int, fit: PoseFit) -> str:
        family = self.chosen.pop(len(BASE_FAMILIES) + index)
        self.say(f"removed {family}: the model is better without it")
        return family

    def held_out_of(self, fits: list[PoseFit]) -> list[float]:
        """Each fit's held-out RMS (m); a step's own fit's, the one its step recorded."""
        known = {id(s.fit): s.cv_rms for s in self.steps}
        return [known[id(fit)] if id(fit) in known else held_out_rms(fit, self.campaign)
                for fit in fits]

    def deltas(self, current: PoseFit, terms: dict[str, tuple[float, int]]
               ) -> dict[str, float]:
        """Each extension's BIC change from its :meth:`PoseFit.terms`, under the step's
        overdispersion (:func:`selection.step_criteria`)."""
        base, bics, _ = step_criteria(current.terms(), list(terms.values()), self.n,
                                      self.sigma)
        return {f: b - base for f, b in zip(terms, bics, strict=True)}


def _validation(fit: PoseFit, other: PoseCampaign | None, refit: tuple[str, ...]
                ) -> dict | None:
    return None if other is None else stage_errors(fit.model, fit.x, other, refit)
