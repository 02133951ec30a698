"""Discrepancy diagnosis: where a model and a campaign disagree, and which effect is missing.

:func:`diagnose` runs the workflow of ``stiffness diagnose``:

1. Fit the campaign's baseline (its ``baseline`` formulation over its ``compliant_joints``;
   ``ln k`` by least squares from a non-negative linear start and the paper's 1e5 N.m/rad).
2. Break the baseline's residuals down by configuration, axis, load magnitude and load sign,
   against the noise level: the declared ``noise_std``, else the pooled scatter of replicate
   rows (same configuration and force), else (said so) the residual scatter of the final model.
3. Search (:func:`stiffness.calibration.search.search`, with :class:`DeflectionSearch`):
   extend the current model by each candidate of :func:`stiffness.elastic.effects.candidates`
   (its own parameters identified jointly with the stiffnesses; every candidate fitted to
   :data:`SCREEN_TOLERANCE`, the best :data:`REFINE_TOP` refitted to the engine's tolerance,
   side by side in forked workers by :func:`stiffness.calibration.fitting.fit_models`), rank
   them by BIC (``RSS / sigma^2 + p ln N`` with a known sigma, ``N ln(RSS / N) + p ln N``
   otherwise, under the step's overdispersion; a parameter-free switch counts one parameter),
   cross-validate the best over configurations (leave-one-configuration-out, or
   :data:`~stiffness.calibration.selection.CV_FOLDS`-fold over configuration labels when there
   are many; a campaign of one configuration over its loads, naming only what those rows can
   judge: :class:`OneConfigurationSearch`) and add the first that beats the current model's;
   until the model fits to noise or nothing helps; then remove, one at a time, any effect the
   final model is better without (BIC and cross-validation: :func:`stiffness.calibration.
   search.eliminate`, a :class:`~stiffness.calibration.search.Step` marked ``removed``). If
   the search ends with the chi-square test still rejecting, the result is *unexplained*
   (:attr:`~stiffness.calibration.diagnosis.Diagnosis.unexplained`) and the final residual's
   structure (:func:`~stiffness.calibration.breakdown.residual_structure`: by load direction
   and row order, correlations with each joint's torque and angle) says where to look.
4. Report the RMS after each step, each added effect's parameters with standard errors and 95 %
   intervals, the residuals before and after, the final model.
5. Report the candidates the campaign cannot tell from the winner (BIC within
   :data:`AMBIGUITY_BIC`, or fitted residual reductions with cosine similarity above
   :data:`SIMILARITY_LIMIT` and BIC within :data:`WEAK_BIC`) and propose the extra poses and
   loads where their predictions differ most, in noise units.

RMS values are over every dx, dy, dz residual component pooled. SI inside; the report converts
to the campaign's units.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import ClassVar, overload

import numpy as np

from stiffness.calibration import fitting
from stiffness.calibration.breakdown import disagreement
from stiffness.calibration.campaign import Campaign, campaign_kind, load_campaign
from stiffness.calibration.deflection_noise import (
    Quantiles,
    fit_noise,
    fit_options,
    interval_quantiles,
    residual_scale,
    robust_scale,
    translation_noise,
    weighting,
)
from stiffness.calibration.deflection_parameters import (
    effect_parameters,
    share,
    stiffness_parameters,
)
from stiffness.calibration.deflection_validation import other_campaign, validated
from stiffness.calibration.diagnosis import SI_UNITS, Ambiguity, Diagnosis
from stiffness.calibration.experiment import propose_measurements
from stiffness.calibration.fitting import Fit, observations
from stiffness.calibration.naming import settle
from stiffness.calibration.outliers import flag_fit
from stiffness.calibration.pose_campaign import PoseCampaign, load_pose_campaign
from stiffness.calibration.pose_diagnose import diagnose_poses
from stiffness.calibration.pose_diagnosis import PoseDiagnosis
from stiffness.calibration.pose_register import REFIT_REFUSED, validation_campaign
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
    SCREEN_TOLERANCE,
    Noise,
    NoiseTerms,
    above_noise,
    config_folds,
    cross_validate,
    extra_fit,
    fit_baseline,
    fit_job,
    fit_model,
    information_criterion,
    noise_terms,
    pooled_replicates,
    row_support,
)
from stiffness.calibration.sign_checks import baseline_builder, fits_note
from stiffness.calibration.solver import check_loss
from stiffness.elastic.effects import LIBRARY, candidates, check_masses, make_effect
from stiffness.elastic.effects.base import Held, Parameter, effect_place, effect_report, place_label
from stiffness.elastic.effects.deflection_face import DeflectionEffect, Settings
from stiffness.elastic.effects.geometry import Geometry, References
from stiffness.elastic.effects.hypothesis import Hypothesis
from stiffness.errors import StiffnessError, did_you_mean
from stiffness.units import Units, whole_number

#: The best candidates of a step (by the first fits' BIC) refitted to the engine's tolerance
#: from there: those ranked, cross-validated and compared.
REFINE_TOP = 6
#: Largest number of effects added.
MAX_STEPS = 5
#: Candidates within this BIC of the winner cannot be told apart.
AMBIGUITY_BIC = 2.0
#: Candidates within this BIC of the winner and with similar signatures cannot be told apart.
WEAK_BIC = 6.0
#: Cosine similarity of fitted residual reductions above which signatures are "similar".
SIMILARITY_LIMIT = 0.95
#: A deflection campaign's candidate: an effect of the library and its fit.
Found = Candidate[DeflectionEffect, Fit]


@overload
def diagnose(campaign: Campaign, max_steps: int | None = ..., seed: int = ..., propose: bool = ...,
             progress: Callable[[str], None] | None = ..., workers: int | None = ...,
             loss: str = ..., effect_settings: dict[str, dict] | None = ...,
             masses: str = ..., validate: Campaign | PoseCampaign | str | os.PathLike | None = ...,
             families: Sequence[str] = ..., not_families: Sequence[str] = ...,
             refit: Sequence[str] = ...) -> Diagnosis: ...


@overload
def diagnose(campaign: PoseCampaign, max_steps: int | None = ..., seed: int = ...,
             propose: bool = ..., progress: Callable[[str], None] | None = ...,
             workers: int | None = ..., loss: str = ...,
             effect_settings: dict[str, dict] | None = ..., masses: str = ...,
             validate: Campaign | PoseCampaign | str | os.PathLike | None = ...,
             families: Sequence[str] = ..., not_families: Sequence[str] = ...,
             refit: Sequence[str] = ...) -> PoseDiagnosis: ...


@overload
def diagnose(campaign: str | os.PathLike, max_steps: int | None = ..., seed: int = ...,
             propose: bool = ..., progress: Callable[[str], None] | None = ...,
             workers: int | None = ..., loss: str = ...,
             effect_settings: dict[str, dict] | None = ..., masses: str = ...,
             validate: Campaign | PoseCampaign | str | os.PathLike | None = ...,
             families: Sequence[str] = ..., not_families: Sequence[str] = ...,
             refit: Sequence[str] = ...) -> Diagnosis | PoseDiagnosis: ...


def diagnose(
    campaign: Campaign | PoseCampaign | str | os.PathLike,
    max_steps: int | None = None,
    seed: int = 0,
    propose: bool = True,
    progress: Callable[[str], None] | None = None,
    workers: int | None = None,
    loss: str = "linear",
    effect_settings: dict[str, dict] | None = None,
    masses: str = "known",
    validate: Campaign | PoseCampaign | str | os.PathLike | None = None,
    families: Sequence[str] = (),
    not_families: Sequence[str] = (),
    refit: Sequence[str] = (),
) -> Diagnosis | PoseDiagnosis:
    """Diagnose what the campaign's baseline model misses (see the module docstring).

    The function behind ``stiffness diagnose``
    (:meth:`~stiffness.calibration.diagnosis.Diagnosis.to_dict` is its ``--json`` object,
    :meth:`~stiffness.calibration.diagnosis.Diagnosis.write` writes its ``--out`` folder).
    A pose campaign (``kind = "poses"``) is diagnosed by
    :func:`stiffness.calibration.pose_diagnose.diagnose_poses` (its ``PoseDiagnosis.to_dict``
    is the command's ``--json`` there), with ``max_steps``, ``seed``, ``progress``,
    ``loss``, ``masses``, ``validate``, ``families``, ``not_families`` and ``refit``.

    Parameters
    ----------
    campaign
        The campaign (SI rows), or the path of a ``campaign.toml`` (or of its folder), of
        either kind.
    max_steps
        Largest number of effects the search adds (a pose campaign's families, forced ones
        not counted); ``None``: :data:`MAX_STEPS` for a deflection campaign, no limit for a
        pose campaign (its families are few).
    seed
        Seed of the fold assignment and of the poses sampled for experiment proposals.
    propose, progress
        Whether to propose extra poses and loads for what cannot be told apart; called with
        a line of text as the search goes.
    workers
        Processes fitting a step's candidates and cross-validation folds side by side
        (:func:`stiffness.calibration.fitting.fit_models`; default the usable cores, 1 in this
        process); for a pose campaign its folds (default in this process); the result does
        not depend on it.
    loss
        ``linear`` or a robust loss for every fit, scaled by the noise std; criteria compare
        :attr:`stiffness.calibration.fitting.Fit.loss_rss` (docs/outliers.md).
    effect_settings
        Declared settings by effect label (:meth:`DeflectionEffect.declare`; :func:`_fit_settings`).
    masses
        Whether the robot's link masses are trusted (``known``) or not (``unknown``): the
        weight is then lumped (a pose model's ``gravity_lumped`` family; a deflection
        campaign's candidate ``gravity_lumped`` instead of ``gravity_preload``).
    validate
        Another campaign of the same kind and robot (or its path), every step's model
        evaluated on it without refitting (a deflection campaign's:
        :func:`stiffness.calibration.deflection_validation.validated`).
    families, not_families
        Families forced in, in order (``diagnose --families``: added first, whatever their
        BIC and held-out error, and never removed again; a deflection campaign's are effect
        names of the library, each at its best place by BIC, or labels ``name(where)``), and
        families never tried (``--not``); recorded under ``selection`` as ``forced`` and
        ``forbidden``.
    refit
        Pose campaigns, with ``validate``: the families fitted to the validation campaign
        before each step's model is judged there, as :func:`stiffness.validate`'s ``refit``
        (``("frame",)``: ``--refit-frame``, a campaign of another day, the tracker moved;
        ``("frame", "markers")``: ``--refit-markers``, a marker plate mounted again); ``()``:
        none, each step's measuring frame registered there all the same (``frame_refit``).

    Raises
    ------
    StiffnessError
        If a configuration cannot be assembled, there are too few residuals, or
        ``max_steps`` is negative; a ``refit`` on a deflection campaign (no measuring frame)
        or without ``validate``.
    """
    if isinstance(campaign, PoseCampaign) or (
            not isinstance(campaign, Campaign) and campaign_kind(campaign) == "poses"):
        if not isinstance(campaign, PoseCampaign):
            campaign = load_pose_campaign(campaign)
        return diagnose_poses(campaign, masses=masses, seed=seed,
                              validate=validation_campaign(validate),
                              progress=progress, loss=loss, families=families,
                              not_families=not_families, max_steps=max_steps,
                              effect_settings=effect_settings, refit=refit)
    if refit:
        raise StiffnessError(REFIT_REFUSED)
    max_steps = MAX_STEPS if max_steps is None else max_steps
    _check_options(max_steps, loss, masses, (seed, workers))
    forbidden = _forbidden(not_families)
    forced = _forced(families, forbidden)
    if not isinstance(campaign, Campaign):
        campaign = load_campaign(campaign)
    other = None if validate is None else other_campaign(campaign, validate)  # before the work
    result = _diagnose_deflections(campaign, max_steps, seed, propose, progress, workers, loss,
                                   effect_settings or {}, masses, forbidden, forced)
    return result if other is None or validate is None else validated(result, other, validate)


def _forbidden(not_families: Sequence[str]) -> tuple[str, ...]:
    """The deflection effects never tried (``--not``: names of the library, everywhere, or
    places ``name(where)`` or ``name:where``, as labels), checked against the library (one
    line naming the valid ones)."""
    return tuple(sorted({_library_label("--not", text)[1] for text in not_families}))


def _forced(families: Sequence[str], forbidden: tuple[str, ...]) -> tuple[str, ...]:
    """The deflection effects forced in (``--families``: names of the library, or places
    ``name(where)`` or ``name:where``, as labels), in order, each once, checked (one line): a
    name of the library, not forbidden too."""
    named = [_library_label("--families", text) for text in families]
    for name, label in named:
        if {name, label} & set(forbidden):
            raise StiffnessError(f"{label} is both forced (--families) and forbidden (--not); "
                                 "name it in one of them")
    return tuple(dict.fromkeys(label for _, label in named))


def _library_label(flag: str, text: str) -> tuple[str, str]:
    """The name and label of the effect ``text`` names to ``flag`` (:func:`effect_place`:
    ``name``, ``name(where)`` or ``name:where``), refused unless the name is of the library
    (one line naming the valid ones)."""
    name, where = effect_place(text, flag)
    if name not in LIBRARY:
        raise StiffnessError(f"{flag} {text!r} is not an effect of the library; "
                             f"{did_you_mean(name, list(LIBRARY))}")
    return name, place_label(name, where)


def _diagnose_deflections(campaign: Campaign, max_steps: int, seed: int, propose: bool,
                          progress: Callable[[str], None] | None, workers: int | None,
                          loss: str, effect_settings: dict[str, dict], masses: str,
                          forbidden: tuple[str, ...] = (), forced: Sequence[str] = ()
                          ) -> Diagnosis:
    """:func:`diagnose` on a deflection campaign, the effects ``forced`` added first (names
    or labels, in order), those named ``forbidden`` never tried."""
    t0 = time.perf_counter()
    say = progress or (lambda text: None)
    compliant = tuple(campaign.robot().compliant_joints)
    geo = Geometry.of(campaign.robot())
    n = campaign.deflection.size * (1 if campaign.rotation is None else 2)
    if n <= len(compliant) + 1:
        raise StiffnessError(f"{n} residual components cannot diagnose a model of "
                             f"{len(compliant)} stiffnesses; add measurement rows")
    known, source, note = translation_noise(campaign, loss)
    sigma = None if known is None else known.sigma
    build = baseline_builder(geo, compliant, masses)
    start = build(campaign)
    rows = start.rows
    pooled = pooled_replicates(known, campaign, loss != "linear")
    base, measured, scale, rot_sigma, rot_source = _baseline_fit(campaign, start, n, sigma,
                                                                 loss, masses, pooled)
    known = pooled
    say(f"baseline {base.model.describe()}: RMS {base.rms():.4g} m")
    folds = config_folds(campaign.config, seed, campaign.wrench)
    cv_base = cross_validate([base], measured, folds, workers)[0]
    one = len(set(campaign.config)) < 2  # held out one load at a time
    kind = (OneConfigurationSearch if one else DeflectionSearch)(
        measured, folds, scale, n, known, workers, say, _declared_settings(base, effect_settings),
        campaign.units, masses, forbidden, campaign)
    current, cv_current = base, cv_base
    for name in forced:
        say(f"step {len(kind.steps) + 1}: {name} (forced)")
        current, cv_current = kind.force(current, name)
    final, stop = search(kind, current, cv_current, max_steps)
    gof_final = (final_terms := noise_terms(final, measured)).p_value(known)
    flipped = fits_note(campaign, build, (base,) if final is base else (base, final),
                        known.sigma, fit_options(len(compliant))) if (
        gof_final is not None and above_noise(gof_final) and loss == "linear" and known
        is not None and base.x.size == len(compliant)) else []
    noise_final = interval_quantiles(known, final, n, campaign, measured)
    note = _final_note(final, n, known, note)
    sigma_used = noise_final.noise.sigma
    quantile, edge = noise_final.two_sided(), noise_final.one_sided()
    cov_final = fitting.compliance_covariance(final, sigma_used, measured)
    noise_base = interval_quantiles(known, base, n, campaign, measured)
    cov_base = fitting.compliance_covariance(base, noise_base.noise.sigma, measured)
    outliers, outlier_sigma = flag_fit(final, measured, sigma, final.penalty_params,
                                       tuple(campaign.config or ()), campaign.lines)
    ambiguities = _ambiguities(kind.ambiguities, sigma_used, campaign, geo,
                               seed if propose else None)
    final_parameters = effect_parameters(final, cov_final, quantile, edge, campaign.units)
    return Diagnosis(
        campaign=campaign, geometry=geo, baseline=base,
        baseline_stiffness=stiffness_parameters(
            base, cov_base, noise_base.two_sided(), noise_base.one_sided()),
        final_stiffness=stiffness_parameters(final, cov_final, quantile, edge),
        noise_std_m=float(sigma_used), noise_std_source=source, noise_note=note, steps=kind.steps,
        stop_reason=stop,
        baseline_disagreement=disagreement((base.predicted - measured)[:, :3], campaign,
                                           sigma_used, rows, geo.angles(rows)),
        final_disagreement=disagreement((final.predicted - measured)[:, :3], campaign,
                                        sigma_used, rows, geo.angles(rows)),
        gof_baseline=noise_terms(base, measured).p_value(known), gof_final=gof_final,
        gof_excluded_rows=final_terms.excluded,
        unexplained=None if gof_final is None else above_noise(gof_final),
        ambiguities=ambiguities, cv_baseline=cv_base, elapsed_s=time.perf_counter() - t0,
        final_parameters=final_parameters, search=kind,
        final_parameters_si=effect_parameters(final, cov_final, quantile, edge, SI_UNITS),
        measured=measured, rotation_noise_std_rad=rot_sigma, rotation_noise_source=rot_source,
        loss=loss, outliers=outliers, outlier_sigma_m=outlier_sigma, masses=masses,
        forbidden=list(forbidden), final_covariance=cov_final,
        baseline_dof=_stiffness_dof(noise_base, base),
        final_dof=_stiffness_dof(noise_final, final), flipped_column=next(iter(flipped), None))


def _stiffness_dof(quantiles: Quantiles, fit: Fit) -> tuple[float | None, ...]:
    """The degrees of freedom of the 95 % intervals of ``fit``'s joint stiffnesses (its first
    columns; ``None``: the normal's), as ``identify`` reports them (``ci95_dof``)."""
    return tuple(quantiles.reported_dof[: len(fit.model.compliant)])


def _check_options(max_steps: int, loss: str, masses: str, counts: tuple) -> None:
    """Refuse a negative or non-integer ``max_steps``, an unknown loss or ``masses``, or a
    seed or a number of workers (``counts``) that is no whole number (one line)."""
    for name, value, least in zip(("seed", "workers"), counts, (0, None), strict=True):
        if value is not None:
            whole_number(value, name, least)
    check_masses(masses)
    check_max_steps(max_steps)
    check_loss(loss)


def _declared_settings(base: Fit, settings: dict[str, dict]) -> dict[str, dict]:
    """``settings`` by effect label (keys ``name(where)`` or ``name:where``,
    :func:`effect_place`), checked: each label a candidate of the campaign's model and its
    settings ones the effect takes (:meth:`DeflectionEffect.declare`; a typed error)."""
    places = [effect_place(key, "effect settings for") for key in settings]
    settings = {place_label(*p): v for p, v in zip(places, settings.values(), strict=True)}
    made = candidates(base.model, settings)
    labels = [e.label for e in made]
    for name, where in places:
        if (label := place_label(name, where)) not in labels:
            same = [e.label for e in made if e.name == name] or labels
            raise StiffnessError(f"effect settings for {label}, which is not a candidate of "
                                 f"this campaign's model; {did_you_mean(label, same)}")
    return settings


#: A declared setting an effect can fit is fitted when the half-width of its 95 % interval is
#: at most this fraction of its value; else it is held at the declared value.
SETTING_PRECISION = 0.5


def _fit_settings(fit: Fit, measured: np.ndarray, scale: float, n: int, known: Noise | None,
                  say: Callable[[str], None]) -> Fit:
    """``fit`` with the declared settings of its last effect (a compensator's lever and base,
    :meth:`Settings.settings_freed`) refitted as parameters and kept where the data determine
    them (finite 95 % intervals within :data:`SETTING_PRECISION` of their values), else held
    with why (:meth:`Settings.settings_held`)."""
    effect = fit.model.effects[-1]
    if not isinstance(effect, Settings) or (freed := effect.settings_freed()) is None:
        return fit
    a, b = fit.model.offsets[-2], fit.model.offsets[-1]
    extra = freed.start()[effect.n_params:]
    trial = fit_model(fit.model.replaced(effects=fit.model.effects[:-1] + (freed,)), measured,
                      scale, np.concatenate([fit.x, extra]), loss=fit.loss, f_scale=fit.f_scale)
    noise = fit_noise(known, trial, n, measured)
    cov = fitting.compliance_covariance(trial, noise.sigma, measured)
    c = b + len(extra)
    freed_params = effect_report(freed, trial.x[a:c], cov[a:c, a:c], trial.model.refs,
                                 SI_UNITS, noise.two_sided())[effect.n_params:]
    reason = _undetermined(freed_params)
    if reason is None and trial.loss_rss <= fit.loss_rss * (1.0 + 1e-9):
        say(f"{freed.label}: {', '.join(q.name for q in freed_params)} fitted")
        return trial
    held = effect.settings_held(reason or "freeing them did not lower the residual")
    return dataclasses.replace(fit, model=fit.model.replaced(effects=fit.model.effects[:-1]
                                                                 + (held,)))


def _undetermined(params: list[Parameter]) -> str | None:
    """Why the data do not determine ``params`` (SI), or ``None`` when they do: finite 95 %
    intervals with half-widths within :data:`SETTING_PRECISION` of the values."""
    for q in params:
        half = 0.5 * (q.ci95[1] - q.ci95[0])
        if not (q.determined and half <= SETTING_PRECISION * abs(q.value)):
            interval = (f"[{q.ci95[0]:.3g}, {q.ci95[1]:.3g}] {q.unit}" if q.determined
                        else "unbounded")
            return f"the data do not determine the {q.name} (95 % interval {interval} when fitted)"
    return None


def _final_note(final: Fit, n: int, known: Noise | None, note: str) -> str:
    """The note on the noise of the final model's intervals (:func:`fit_noise`): ``note``
    with a ``known`` noise, else that it is that model's residual scatter (said so; under a
    robust loss their robust scale)."""
    if known is not None:
        return note
    robust = "" if final.loss == "linear" else " (robust scale, 1.4826 median |residual|)"
    return (f"estimated from the residuals of the final model{robust} "
            f"({final.model.describe()}, "
            f"{n - final.penalty_params} degrees of freedom): it includes any model error "
            "left, so the fit-to-noise test is not available and 'nothing missing' means only "
            "that no candidate helped")


def _baseline_fit(campaign: Campaign, model0: Hypothesis, n: int, sigma: float | None,
                  loss: str = "linear", masses: str = "known", known: Noise | None = None
                  ) -> tuple[Fit, np.ndarray, float, float | None, str | None]:
    """The campaign's baseline ``model0`` fitted (rotations weighted by their noise, estimated
    from the baseline's residuals when not known), with the references of its stiffness and
    of the robot's link ``masses`` (``unknown``: no weight to judge a compensator against);
    under a robust ``loss`` scaled by ``sigma`` (m), else by identify's robust estimate
    (:func:`~stiffness.calibration.deflection_noise.robust_scale`: the rounds of
    :func:`~stiffness.calibration.outliers.robust_rounds` with identify's fits). ``k_ref``
    (:func:`~stiffness.calibration.fitting.reference_stiffness`) counts the springs whose
    compliance's 95 % interval excludes zero at the ``known`` noise (pooled as the report's,
    :func:`~stiffness.calibration.selection.pooled_replicates`; ``None``: declared ``sigma``,
    else the baseline's residual scatter).

    Returns
    -------
    The fit, the observations (m, rotations weighted), the residual scale (m), the rotation
    noise std (rad, or None) and its source.
    """
    deflection = campaign.deflection
    rms_meas = float(np.sqrt(np.mean(deflection ** 2)))
    scale = sigma if sigma is not None else max(rms_meas * 1e-2, 1e-12)
    fit_loss = loss if sigma is not None else "linear"
    rot_sigma: float | None = None
    rot_source: str | None = None
    weight: float | None = None
    weighted: Fit | None = None  # the baseline fitted at the weight, when it took fits
    if campaign.rotation is not None:  # the weight: deflection_noise.weighting
        rotation = campaign.rotation
        rotations = weighting(campaign, sigma, lambda w, _: fit_baseline(
            model0.replaced(rotation_weight=w), observations(deflection, rotation, w), scale,
            fit_loss), robust=loss != "linear")
        weight, rot_sigma, rot_source = (rotations.weight, rotations.sigma_rad,
                                         rotations.source)
        weighted = rotations.fit
    measured = observations(deflection, campaign.rotation, weight)
    model0 = model0.replaced(rotation_weight=weight)
    base = weighted if weighted is not None else fit_baseline(model0, measured, scale, fit_loss)
    noise = known if known is not None or sigma is None else Noise(sigma)
    quantiles = interval_quantiles(noise, base, n, campaign, measured)  # the report's
    k_ref = fitting.reference_stiffness(base, quantiles.noise.sigma, quantiles.two_sided(),
                                        measured)
    base.model = base.model.replaced(refs=References.of(model0.geometry, model0.rows, k_ref,
                                                    deflection, masses))
    if sigma is None and loss == "linear":
        scale = max(base.rms(), 1e-12)
        base = fit_model(base.model, measured, scale, base.x)
    if sigma is None and loss != "linear":  # identify's rounds and fits (issue 35)
        scale = robust_scale(base.model, measured, residual_scale(campaign),
                             fit_options(len(model0.compliant)), None, loss, 1e5)
        base = fit_baseline(base.model, measured, scale, loss)
    return base, measured, scale, rot_sigma, rot_source


@dataclass
class DeflectionSearch:
    """The effect search of :func:`diagnose` over fixed observations (m), cross-validation
    folds, residual scale (m), residual count, known noise (declared or the replicates',
    :class:`~stiffness.calibration.selection.Noise`; ``None``: not known) and workers: a
    deflection campaign's :class:`~stiffness.calibration.search.SearchKind` (the library's
    effects screened by loose full fits, the best refined; held out over configuration
    folds). Its :attr:`steps` and raw :attr:`ambiguities` ``(step, winner, other,
    similarity)`` grow as :func:`~stiffness.calibration.search.search` adds effects; its
    ``campaign`` (``None``: one noise quantile for every parameter) gives the intervals'
    quantiles of a campaign with rotations
    (:func:`~stiffness.calibration.deflection_noise.interval_quantiles`)."""

    measured: np.ndarray
    folds: list[np.ndarray]
    scale: float
    n: int
    noise: Noise | None
    workers: int | None
    say: Callable[[str], None]
    declared: dict[str, dict]
    units: Units
    masses: str = "known"
    forbidden: tuple[str, ...] = ()
    campaign: Campaign | None = None
    steps: list[Step[DeflectionEffect, Fit]] = field(default_factory=list)
    ambiguities: list[tuple[int, Found, Found, float]] = field(default_factory=list)
    dispersion: float = 1.0
    removals: Removals[Fit] | None = None
    refusal: Refusal[DeflectionEffect, Fit] | None = None
    cut_short: bool = False
    stops: ClassVar[dict[Stop, str]] = {
        Stop.LEFT: "no candidate left",
        Stop.BIC: f"no candidate improves BIC by more than {BIC_MARGIN:g}",
        Stop.NAMED: ("the candidates that improve BIC determine none of their parameters "
                     "within its physical scale with an interval excluding zero"),
        Stop.HELD_OUT: ("no candidate that improves BIC also improves the error predicted "
                        "for held-out configurations (cross-validation)")}

    @property
    def sigma(self) -> float | None:
        """The known noise std (m), ``None`` when only the residuals can tell."""
        return None if self.noise is None else self.noise.sigma

    def noise_terms(self, fit: Fit) -> NoiseTerms:
        """:func:`~stiffness.calibration.selection.noise_terms` of ``fit``."""
        return noise_terms(fit, self.measured)

    def candidates(self, current: Fit, only: str | None = None) -> list[Found] | None:
        """Every library extension of ``current`` fitted (screened, the best refined), ranked
        by BIC (the step's overdispersion kept), or ``None`` when there is none; with
        ``only``, those of that effect name or label."""
        effects = [e for e in candidates(current.model, self.declared, self.masses)
                   if not {e.name, e.label} & set(self.forbidden)
                   and only in (None, e.name, e.label)]
        fits = list(zip(effects, fitting.fit_models(
            [fit_job(current.model.extended(e), self.measured, self.scale,
                     current.model.extend_x(current.x, e), tolerance=SCREEN_TOLERANCE,
                     loss=current.loss, f_scale=current.f_scale)
             for e in effects], self.workers), strict=True))
        results, _ = ranked(self, current, fits)
        best = {id(c.effect) for c in results[:REFINE_TOP]}
        refine = [i for i, (e, _) in enumerate(fits) if id(e) in best]
        refined = fitting.fit_models([fit_job(fits[i][1].model, self.measured, self.scale,
                                              fits[i][1].x, loss=current.loss,
                                              f_scale=current.f_scale) for i in refine],
                                     self.workers)
        for i, fit in zip(refine, refined, strict=True):
            fits[i] = (fits[i][0], fit)
        results, self.dispersion = ranked(self, current, fits)
        self.say(f"step {len(self.steps) + 1}: {len(results)} candidates; best "
                 + ", ".join(f"{c.effect.label} dBIC {c.delta_bic:.3g}" for c in results[:3]))
        return results or None

    def parameters(self, c: Found) -> list[Parameter]:
        return self.reported(c.fit, SI_UNITS)[c.fit.model.effects[-1].label]

    def settle(self, c: Found) -> Fit:
        """Issue 36.4 inside a family (:func:`stiffness.calibration.naming.settle`): the parameters
        of ``c``'s effect that the data do not determine held at their nominal value (the
        effect's start, :meth:`Effect.start`: a compensator's stiffness or preload 0, its base
        the declared one; :func:`~stiffness.calibration.fitting.nominal_parameters`), the
        least determined first, each time the fit redone."""
        effect = c.fit.model.effects[-1]
        start = c.fit.model.offsets[-2]

        def hold(fit: Fit, ks: list[int], ps: list[Parameter], whys: list[str]) -> Fit:
            cov = self.covariance(fit)[0]
            held = {f"{effect.label}.{p.name}": Held(why, share(fit, start + k, cov))
                    for k, p, why in zip(ks, ps, whys, strict=True)}
            return fit_job(fit.model.holding(held), self.measured, self.scale, fit.x,
                           loss=fit.loss, f_scale=fit.f_scale).run()

        return settle(c.fit, lambda fit: self.reported(fit, SI_UNITS)[effect.label],
                      effect.physical_scale(c.fit.model.refs), hold)

    def split_confused(self, c: Found) -> None:
        """None: a deflection effect's parameters are only settled (:meth:`settle`)."""

    def unphysical(self, fit: Fit) -> None:
        """None: a deflection effect's values beyond its physical scale make it a stand-in
        (:func:`~stiffness.calibration.naming.is_stand_in`, said in the report), not a
        refusal."""

    def held_out(self, named: Iterator[Found]) -> Iterator[Found]:
        """All cross-validated together over the folds (NaN without folds)."""
        tried = list(named)
        if tried:
            for c, cv in zip(tried, cross_validate([c.fit for c in tried], self.measured,
                                                   self.folds, self.workers), strict=True):
                c.cv_rms = cv
        return iter(tried)

    def accept(self, current: Fit, winner: Found, ranking: list[Found]) -> Fit:
        """The :class:`Step` adding ``winner`` (its declared settings fitted where the data
        determine them, :func:`_fit_settings`): its parameters, the step's ranking, its BIC
        change that of the fit it adds (a settled one's under the step's overdispersion, the
        ranking keeping the full fit's); and the candidates it cannot be told from."""
        for c in ranking[:CV_TOP]:
            similarity = _similarity(current, winner.fit, c.fit, self.scale)
            d_bic = c.bic - winner.bic
            if c is not winner and (d_bic < AMBIGUITY_BIC or (similarity > SIMILARITY_LIMIT
                                                              and d_bic < WEAK_BIC)):
                self.ambiguities.append((len(self.steps) + 1, winner, c, similarity))
        fit = winner.fit = _fit_settings(winner.fit, self.measured, self.scale, self.n,
                                         self.noise, self.say)
        effect = winner.effect = fit.model.effects[-1]
        delta = winner.delta_bic
        if winner.settled:
            sigma = None if self.sigma is None else self.sigma * math.sqrt(self.dispersion)
            delta = information_criterion(fit.loss_rss, self.n, fit.penalty_params, sigma) - (
                winner.bic - winner.delta_bic)
        assert winner.cv_rms is not None  # judged held out
        self.steps.append(Step(effect, fit, delta, winner.cv_rms,
                               [(c.effect, c.delta_bic, c.cv_rms) for c in ranking[:6]],
                               self.reported(fit, self.units)[effect.label], self.dispersion))
        self.say(f"added {effect.label}: RMS {fit.rms():.4g} m")
        return fit

    def reject(self, ranking: list[Found]) -> None:
        """Nothing: a deflection diagnosis keeps the added steps only."""

    def without(self, final: Fit) -> list[Fit]:
        """``final`` without each effect and those acting through it, refitted in order."""
        parts = [final.model.without(i, final.x) for i in range(len(final.model.effects))]
        return fitting.fit_models([fit_job(m, self.measured, final.scale, x, loss=final.loss,
                                           f_scale=final.f_scale) for m, x in parts], self.workers)

    def held_out_of(self, fits: list[Fit]) -> list[float]:
        return cross_validate(fits, self.measured, self.folds, self.workers)

    def force(self, current: Fit, name: str) -> tuple[Fit, float]:
        """``current`` with the effect ``name`` added whatever its BIC and held-out error
        (``diagnose --families``): of its places (a label, ``name(where)``, names one), the
        best by BIC, its undetermined parameters held at nominal; the step marked forced.
        The new fit and its held-out RMS (m).

        Raises
        ------
        StiffnessError
            ``name`` is no candidate of ``current``'s model (one line naming the valid ones;
            a place the effect cannot act at, that effect's own line: :func:`make_effect`).
        """
        ranking = self.candidates(current, only=name)
        if ranking is None:
            effect, where = effect_place(name, "--families")
            if where is not None:
                make_effect(effect, where, current.model.geometry)  # e.g. a compensator on T2
            valid = sorted({e.name for e in candidates(current.model, self.declared,
                                                        self.masses)} - set(self.forbidden))
            raise StiffnessError(f"--families {name}: no candidate of this campaign's model "
                                 f"(a name or a label name(where)); valid: {', '.join(valid)}")
        winner = ranking[0]
        full, winner.fit = winner.fit, self.settle(winner)
        winner.settled = winner.fit is not full
        winner.cv_rms = cross_validate([winner.fit], self.measured, self.folds,
                                       self.workers)[0]
        fit = self.accept(current, winner, ranking)
        self.steps[-1].forced = True
        return fit, winner.cv_rms

    def removable(self, final: Fit) -> list[bool]:
        """Every effect not forced (``--families``), none acting through it (a joint law at
        the joint whose spring it adds, :meth:`Hypothesis.through`)."""
        forced = {s.label for s in self.steps if s.forced}
        return [e.label not in forced and final.model.through(i) == [i]
                for i, e in enumerate(final.model.effects)]

    def remove(self, final: Fit, index: int, fit: Fit) -> DeflectionEffect:
        effect = final.model.effects[index]
        self.say(f"removed {effect.label}: RMS {fit.rms():.4g} m")
        return effect

    def covariance(self, fit: Fit) -> tuple[np.ndarray, Quantiles]:
        """The covariance of ``fit.x`` (:func:`fitting.compliance_covariance`) and the noise it
        is for with its intervals' quantiles (:func:`interval_quantiles`: the known one, else
        estimated from ``fit``'s residuals)."""
        noise = interval_quantiles(self.noise, fit, self.n, self.campaign, self.measured)
        return fitting.compliance_covariance(fit, noise.noise.sigma, self.measured), noise

    def reported(self, fit: Fit, units: Units) -> dict[str, list[Parameter]]:
        """Each effect's parameters in ``fit`` with their intervals."""
        cov, noise = self.covariance(fit)
        return effect_parameters(fit, cov, noise.two_sided(), noise.one_sided(), units)


@dataclass
class OneConfigurationSearch(DeflectionSearch):
    """:class:`DeflectionSearch` on a campaign of one configuration: its rows held out one
    load at a time (:func:`~stiffness.calibration.selection.config_folds` over the loads),
    and a candidate named only where those rows can judge it
    (:func:`~stiffness.calibration.selection.row_support`: each fold's fit keeps more
    residual components than its parameters, and it does not fit below a known noise) and,
    the noise not known, show it (:func:`~stiffness.calibration.selection.extra_fit` against
    the step's current model, :attr:`current_terms`, over its :attr:`tried` candidates);
    else it is refused, said in the stop reason."""

    stops: ClassVar[dict[Stop, str]] = {
        **DeflectionSearch.stops,
        Stop.HELD_OUT: ("no candidate that improves BIC also improves the error predicted "
                        "for held-out loads of the one configuration (cross-validation over "
                        "its rows)"),
        Stop.REFUSED: ("one configuration: its rows can judge none of the candidates that "
                       "improve BIC, so none is named")}
    current_terms: tuple[float, int] = (math.nan, 0)
    tried: int = 0

    def candidates(self, current: Fit, only: str | None = None) -> list[Found] | None:
        results = super().candidates(current, only)
        self.current_terms, self.tried = current.terms(), len(results or ())
        return results

    def held_out(self, named: Iterator[Found]) -> Iterator[Found]:
        """Those the rows can judge and show cross-validated; the others ``refused``, why."""
        tried = list(named)
        for c in tried:
            t = self.noise_terms(c.fit)
            c.refused = row_support(self.folds, self.measured, t.rss, t.p, self.noise,
                                    t.translations, t.n)
            if c.refused is None and self.noise is None:
                c.refused = extra_fit(self.current_terms, c.fit.terms(), self.n, self.tried)
        super().held_out(c for c in tried if c.refused is None)
        return iter(tried)


def _ambiguities(raw: list[tuple[int, Found, Found, float]], sigma: float,
                 campaign: Campaign, geo: Geometry, seed: int | None) -> list[Ambiguity]:
    """The pairs the campaign cannot tell apart, with why, and (``seed`` not None, first
    three) the measurements that would (:func:`propose_measurements`); ``sigma`` in m."""
    ambiguities: list[Ambiguity] = []
    for step_no, w, c, similarity in raw:
        sep = float(np.sqrt(np.mean((w.fit.predicted - c.fit.predicted) ** 2))) / sigma
        d_bic = c.bic - w.bic
        if d_bic < 0 and w.cv_rms is not None and math.isnan(w.cv_rms):
            reason = ("BIC prefers the other, but it was not chosen; a single configuration "
                      "leaves nothing to hold out to compare them by (no cross-validation)")
        elif d_bic < 0:
            reason = ("BIC prefers the other, but it does not predict held-out configurations "
                      "better than the current model (cross-validation)")
        elif d_bic < AMBIGUITY_BIC:
            reason = f"BIC within {AMBIGUITY_BIC:g}"
        elif c.params > w.params:  # the counts d_bic penalises, not a settled fit's
            reason = (f"similar signatures (cosine {similarity:.3f}); the chosen one wins by "
                      "parsimony (fewer parameters), hardly by fit")
        else:
            reason = (f"similar signatures (cosine {similarity:.3f}) and BIC within "
                      f"{WEAK_BIC:g}: weak evidence only")
        amb = Ambiguity(step_no, w.effect.label, c.effect.label, d_bic, similarity, sep,
                        reason, (w.cv_rms, c.cv_rms))
        if seed is not None and len(ambiguities) < 3:
            try:
                amb.proposals = propose_measurements(campaign, geo, w.fit, c.fit, sigma,
                                                     seed=seed)
            except StiffnessError as exc:  # no reachable pose sampled
                amb.proposals = [{"note": str(exc)}]
        ambiguities.append(amb)
    return ambiguities


def _similarity(current: Fit, a: Fit, b: Fit, scale: float) -> float:
    """Cosine similarity of the residual reductions of two candidate fits."""
    da = (a.predicted - current.predicted).reshape(-1) / scale
    db = (b.predicted - current.predicted).reshape(-1) / scale
    na, nb = np.linalg.norm(da), np.linalg.norm(db)
    if na == 0 or nb == 0:
        return 0.0
    return float(da @ db / (na * nb))
