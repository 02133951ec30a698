"""A force or deflection column written with the wrong sign, named when the fit misses the data.

A load cell mounted with an axis reversed, or a deflection taken as unloaded minus loaded on
one axis, leaves every unit check plausible (the sizes are right) and makes ``identify`` fit
a model that misses the data by tens of noise stds: a UR5 campaign of 18 rows at 10 µm with
its ``fx`` column negated put two of three springs at the rigid bound and left an RMS 40 times
the noise, which read as "model error or underestimated noise" and sent the user to
``diagnose``, whose library holds no reflection.

``diagnose`` checks its baseline the same way when its final model stays unexplained
(:func:`baseline_builder`), and its verdict adds the note.

So when a fit does not explain the data to its known noise (declared, or the replicates';
the chi-square test of :func:`stiffness.calibration.deflection_noise.noise_level`),
:func:`flipped_column_note` refits the baseline once per column ``fx, fy, fz, dx, dy, dz``
with that column's sign reversed (one least-squares run from the fit's stiffnesses, brought
within 1e2..1e8 SI, where a rigid spring's is not; the enhanced formulation for the exact
one). A column whose reversal brings the residual sum of squares down :data:`FLIP_GAIN` times
or more, to within :data:`FLIP_NOISE` times the noise's (RMS at most twice the noise), is
named in a note; the data are not changed. Campaigns with measured rotations or moments are
not checked (their signs are tied to the forces').
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from stiffness.calibration.campaign import Campaign
from stiffness.calibration.fitting import fit_model
from stiffness.elastic.effects.geometry import Geometry, References
from stiffness.elastic.effects.hypothesis import Hypothesis

#: The residual sum of squares must fall at least this many times with a column reversed.
FLIP_GAIN = 25.0
#: ... to at most this many times the known noise's (``(N - p) sigma^2``): an RMS within 2x.
FLIP_NOISE = 4.0
#: The columns checked, by the campaign array and component they are.
COLUMNS = {"fx": ("force", 0), "fy": ("force", 1), "fz": ("force", 2),
           "dx": ("deflection", 0), "dy": ("deflection", 1), "dz": ("deflection", 2)}


def flipped_column_note(campaign: Campaign, build: Callable[[Campaign], Hypothesis],
                        x: np.ndarray, rss: float, sigma: float, options: dict) -> list[str]:
    """The note naming the column whose reversed sign explains the data, or nothing.

    Parameters
    ----------
    campaign
        The campaign as read (SI); one with rotations or moments is not checked.
    build
        The baseline model of a campaign (``stiffness_model`` with the fit's robot and a
        formulation that is not ``exact``).
    x
        The fit's ``ln k`` (each refit's start, within ``ln 1e2 .. ln 1e8``).
    rss
        The fit's residual sum of squares (m^2).
    sigma
        The known translation noise std (m).
    options
        The fit's solver options (:func:`stiffness.calibration.deflection_noise.fit_options`).
    """
    if campaign.rotation is not None or campaign.moment is not None:
        return []
    dof = 3 * campaign.n_rows - len(x)
    if dof <= 0 or rss <= 0.0:
        return []
    start = np.clip(x, math.log(1e2), math.log(1e8))  # a rigid spring's ln k has no slope
    found = []
    for name, (array, j) in COLUMNS.items():
        flipped = getattr(campaign, array).copy()
        flipped[:, j] *= -1.0
        other = replace(campaign, **{array: flipped})
        fit = fit_model(build(other), other.deflection, sigma, start, "trf", anchor=start,
                        **options)
        if fit.rss * FLIP_GAIN <= rss and fit.rss <= FLIP_NOISE * dof * sigma ** 2:
            found.append((fit.rss, name))
    if not found:
        return []
    best, name = min(found)
    return [f"with the sign of column {name} reversed the residuals fall {rss / best:.3g} times "
            f"(RMS {math.sqrt(best / (3 * campaign.n_rows)) * 1e3:.4g} mm, "
            f"{math.sqrt(best / dof) / sigma:.2g}x the noise): {name} looks written with the "
            "opposite sign (a load cell's axis reversed, or unloaded minus loaded); check its "
            "sign convention and correct the column"]


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
