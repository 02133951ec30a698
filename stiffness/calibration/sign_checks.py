"""A force, moment, deflection or rotation column written with the wrong sign, named when the
fit misses the data.

A load cell mounted with an axis reversed, or a deflection taken as unloaded minus loaded on
one axis, leaves every unit check plausible (the sizes are right) and makes ``identify`` fit
a model that misses the data by tens of noise stds: a UR5 campaign of 18 rows at 10 µm with
its ``fx`` column negated put two of three springs at the rigid bound and left an RMS 40 times
the noise, which read as "model error or underestimated noise" and sent the user to
``diagnose``, whose library holds no reflection.

``diagnose`` checks its baseline the same way when its final model stays unexplained
(:func:`baseline_builder`), then its final model (:func:`fits_note`), and its verdict adds the
note.

So when a fit does not explain the data to its known noise (declared, or the replicates';
the chi-square test of :func:`stiffness.calibration.deflection_noise.noise_level`),
:func:`flipped_column_note` refits the baseline once per column of :data:`COLUMNS` the
campaign has (``fx, fy, fz, dx, dy, dz``, and ``mx, my, mz`` and ``rx, ry, rz`` when it has
applied moments or measured rotations; a column of zeros is skipped) with that column's sign
reversed (:func:`reversed_fits`: one least-squares run from the fit's stiffnesses, brought
within 1e2..1e8 SI, where a rigid spring's is not; the enhanced formulation for the exact one;
the rotations weighted as the fit weighed them). A column is named in a note when its reversal

* lowers the residual sum of squares by :data:`FLIP_CHI2` noise variances or more: a column
  written with the right sign, reversed, changes it by about ``4 sqrt(S) Z - 4 S`` noise
  variances (``S`` the column's signal in noise variances, ``Z`` standard normal), which
  reaches 25 with probability at most ``P(Z >= 5) = 2.9e-7``, whatever ``S``; and
* explains the misfit: its fit passes the chi-square test against the noise
  (:func:`~stiffness.calibration.selection.above_noise` of ``P(chi2_{N-p} >= RSS /
  sigma^2)``), or leaves at most one :data:`FLIP_GAIN`-th of the misfit beyond the noise's
  ``(N - p) sigma^2`` (another effect the baseline lacks keeps the rest: a hidden backlash
  beside a reversed ``fx``, the reversal's fit still 2.2x the noise), not merely a part of a
  misfit that something else makes.

The data are not changed. One reversal is looked for, in one column. A rotation column is
in effect not checked when the rotations' noise is estimated from the fit's residuals: a
reversed one then reads as rotation noise, and the fit passes the test.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np
from scipy.special import chdtrc

from stiffness.calibration.campaign import Campaign
from stiffness.calibration.fitting import Fit, fit_model, observations
from stiffness.calibration.selection import above_noise
from stiffness.elastic.effects.geometry import Geometry, References
from stiffness.elastic.effects.hypothesis import Hypothesis

#: The residual sum of squares must fall by at least this many noise variances with a column
#: reversed (a right column reversed: probability at most 2.9e-7, module docstring).
FLIP_CHI2 = 25.0
#: ... and its fit pass the chi-square test against the noise, or its excess over the noise's,
#: ``(N - p) sigma^2``, fall at least this many times.
FLIP_GAIN = 10.0
#: A reversal whose fit stays above this many times the noise std in RMS is said to leave
#: something else unexplained.
FLIP_NOISE = 2.0
#: Stiffnesses (SI) each refit starts within, the fit's clipped to them: a rigid spring's
#: ``ln k`` has no slope to leave from (identify's random starts' range).
START_RANGE_SI = (1e2, 1e8)
#: The columns checked, by the campaign array and component they are (the moment and rotation
#: columns when the campaign has them).
COLUMNS = {f"{prefix}{axis}": (array, j)
           for prefix, array in (("f", "force"), ("d", "deflection"), ("m", "moment"),
                                 ("r", "rotation"))
           for j, axis in enumerate("xyz")}


def flipped_column_note(campaign: Campaign, build: Callable[[Campaign], Hypothesis],
                        x: np.ndarray, rss: float, sigma: float, options: dict,
                        weight: float | None = None) -> list[str]:
    """The note naming the column whose reversed sign explains the data, or nothing.

    Parameters
    ----------
    campaign
        The campaign as read (SI).
    build
        The baseline model of a campaign (``stiffness_model`` with the fit's robot and a
        formulation that is not ``exact``), without a rotation weight.
    x
        The fit's parameters, ``ln k`` first (each refit's start, the ``ln k`` brought within
        ``ln 1e2 .. ln 1e8``).
    rss
        The fit's residual sum of squares (m^2; rotations weighted by ``weight``).
    sigma
        The known translation noise std (m).
    options
        The fit's solver options (:func:`stiffness.calibration.deflection_noise.fit_options`).
    weight
        The fit's rotation weight (m/rad: the translations' noise std over the rotations'),
        ``None`` for a fit of the translations alone (a campaign without rotations).
    """
    weight = None if campaign.rotation is None else weight
    dof = observations(campaign.deflection, campaign.rotation, weight).size - len(x)
    if dof <= 0 or rss <= 0.0:
        return []
    noise = dof * sigma ** 2
    found = [(refit, name, rms) for name, (refit, rms)
             in reversed_fits(campaign, build, x, sigma, options, weight).items()
             if rss - refit >= FLIP_CHI2 * sigma ** 2
             and (not above_noise(float(chdtrc(dof, refit / sigma ** 2)))
                  or refit - noise <= (rss - noise) / FLIP_GAIN)]
    if not found:
        return []
    best, name, rms = min(found)
    ratio = math.sqrt(best / dof) / sigma
    rest = (f"; the rest, {ratio:.2g}x the noise, is something else: diagnose the corrected "
            "campaign" if ratio > FLIP_NOISE else "")
    return [f"with the sign of column {name} reversed the residuals fall {rss / best:.3g} times "
            f"(RMS {rms * 1e3:.4g} mm, {ratio:.2g}x the noise): {name} looks written with the "
            "opposite sign (a load cell's axis reversed, or unloaded minus loaded); check its "
            f"sign convention and correct the column{rest}"]


def reversed_fits(campaign: Campaign, build: Callable[[Campaign], Hypothesis], x: np.ndarray,
                  sigma: float, options: dict, weight: float | None = None
                  ) -> dict[str, tuple[float, float]]:
    """The baseline refitted with each column of :data:`COLUMNS` the campaign has reversed in
    turn (a column of zeros skipped): by column, the refit's residual sum of squares (m^2,
    rotations weighted by ``weight``, m/rad) and its translations' RMS (m). The arguments
    are :func:`flipped_column_note`'s."""
    weight = None if campaign.rotation is None else weight
    out = {}
    for name, (array, j) in COLUMNS.items():
        values = getattr(campaign, array)
        if values is None or not np.any(values[:, j]):  # nothing to reverse
            continue
        flipped = values.copy()
        flipped[:, j] *= -1.0
        other = replace(campaign, **{array: flipped})
        measured = observations(other.deflection, other.rotation, weight)
        model = build(other).replaced(rotation_weight=weight)
        start = np.array(x, dtype=float)
        n = len(model.compliant)
        start[:n] = np.clip(start[:n], *np.log(START_RANGE_SI))
        fit = fit_model(model, measured, sigma, start, "trf", anchor=start, **options)
        translations = fit.predicted[:, :3] - measured[:, :3]
        out[name] = (fit.rss, float(np.sqrt(np.mean(translations ** 2))))
    return out


def fits_note(campaign: Campaign, build: Callable[[Campaign], Hypothesis], fits: Sequence[Fit],
              sigma: float, options: dict) -> list[str]:
    """:func:`flipped_column_note` of each of ``fits`` in turn, the first note: ``diagnose``'s
    baseline, then its final model, each refitted over the rows of the campaign with a column
    reversed (``build``'s, :func:`baseline_builder`; the model's effects and their settings
    kept), which names a reversal beside an effect the baseline lacks and the search found (a
    reversed ``rx`` beside a backlash)."""
    for fit in fits:
        def refit(other: Campaign, model: Hypothesis = fit.model) -> Hypothesis:
            return model.replaced(rows=build(other).rows)
        note = flipped_column_note(campaign, refit, fit.x, fit.rss, sigma, options,
                                   fit.model.rotation_weight)
        if note:
            return note
    return []


def baseline_builder(geometry: Geometry, compliant: tuple[str, ...], masses: str
                     ) -> Callable[[Campaign], Hypothesis]:
    """The stiffness-only baseline of a campaign of ``geometry``'s robot, as ``diagnose`` fits
    it (its ``compliant`` joints, the references of the links' ``masses``, the campaign's
    formulation: conventional or enhanced), which ``diagnose`` starts from and refits with a
    column reversed (the ``build`` of :func:`flipped_column_note`)."""
    def build(campaign: Campaign) -> Hypothesis:
        rows = geometry.rows(campaign.q, campaign.force, campaign.moment,
                             labels=[campaign.describe_row(i) for i in range(campaign.n_rows)],
                             joint_angles=campaign.robot_settings.joint_angles)
        return Hypothesis(geometry, rows, campaign.baseline, compliant, (), References.of(
            geometry, rows, 1e5, campaign.deflection, masses))
    return build
