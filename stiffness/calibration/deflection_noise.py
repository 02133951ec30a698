"""The noise of a deflection fit, for ``identify`` and ``diagnose`` alike: each kind's known
noise std (:func:`known_noise`, :func:`translation_noise`), the weight of measured rotations
beside the translations (:func:`weighting`) and the noise of a fit's intervals
(:func:`fit_noise`).

A deflection campaign that measures rotations (rad) beside translations (m) is fitted on
``[d; w r]``, ``w = sigma_t / sigma_r`` (m/rad, :func:`~stiffness.calibration.fitting.
observations`), so that one scale ``sigma_t`` whitens both kinds. Each kind's noise std is
known when declared (``noise_std``, ``rotation_noise_std``), else when the campaign repeats
rows (the replicates' pooled scatter, robust under a robust loss:
:func:`~stiffness.calibration.selection.replicate_noise`), and otherwise estimated from the
residuals of a fit of that kind (:func:`~stiffness.calibration.fitting.kind_noise`). The
residuals depend on the weight they are fitted at, so an estimated std is the fixed point of
``w -> s_t(w) / s_r(w)`` over the caller's baseline fit at ``w``, reached from the ratio of
the known stds or, for an unknown one, of the measured RMS of that kind (:func:`weighting`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from stiffness.calibration.campaign import Campaign
from stiffness.calibration.fitting import Fit, compliance_spread, kind_noise, observations
from stiffness.calibration.selection import Noise, replicate_noise

#: The weight's fixed point is reached when a round moves it by at most this fraction.
WEIGHT_TOLERANCE = 1e-3
#: Baseline fits at most spent on the fixed point (2 to 11 on UR5 campaigns of 2 poses x 2
#: loads, from a first weight far below it: the measured rotations are mostly signal).
MAX_ROUNDS = 20


def known_noise(campaign: Campaign, kind: str = "translation", robust: bool = False
                ) -> tuple[float, int | None, str] | None:
    """A ``kind``'s (``translation``, m; ``rotation``, rad) known noise std, its degrees of
    freedom and its source: the declared one (``None`` degrees of freedom, ``declared``),
    else the replicates' (``replicates``; robust under a robust loss,
    :func:`~stiffness.calibration.selection.replicate_noise`); ``None`` when only the
    residuals can tell (or the campaign measures no rotations)."""
    declared = (campaign.noise_std_m if kind == "translation"
                else campaign.rotation_noise_std_rad)
    if declared is not None:
        return declared, None, "declared"
    rep = replicate_noise(campaign, kind, robust=robust)
    return None if rep is None else (rep[0], rep[1], "replicates")


def translation_noise(campaign: Campaign, loss: str = "linear"
                      ) -> tuple[Noise | None, str, str]:
    """The translation noise (m; ``None`` when only the residuals can tell), its source
    (``declared``, ``replicates`` or ``residuals``) and a note on it: :func:`known_noise` with
    its degrees of freedom, the replicates' robust under a robust ``loss``."""
    known = known_noise(campaign, robust=loss != "linear")
    if known is None:
        return None, "residuals", ""
    sigma, dof, source = known
    if dof is None:
        return Noise(sigma), source, "declared noise_std of the campaign"
    if loss != "linear":
        return (Noise(sigma, dof), source,
                "robust scatter of replicate rows (1.4826 median |deviation from the group "
                f"mean|, {dof} degrees of freedom)")
    return (Noise(sigma, dof), source,
            f"pooled scatter of replicate rows ({dof} degrees of freedom)")


def fit_noise(known: Noise | None, fit: Fit, n: int) -> Noise:
    """The noise of ``fit``'s covariance and intervals over ``n`` residuals
    (:class:`~stiffness.calibration.selection.Noise`): ``known`` (the campaign's, declared or
    the replicates' with their degrees of freedom; identify's, a robust estimate too), else
    estimated from ``fit``'s residuals over its ``n - p`` degrees of freedom; under a robust
    loss the sandwich's, over the directions the reported covariance spreads over
    (:meth:`~stiffness.calibration.selection.Noise.of_fit`, :func:`compliance_spread`)."""
    p = fit.penalty_params
    noise = (known if known is not None
             else Noise.estimated(math.sqrt(fit.loss_rss / max(n - p, 1)), n, p))
    return noise.of_fit(fit.loss, n, compliance_spread(replace(fit, loss="linear")))


@dataclass(frozen=True)
class RotationWeight:
    """The rotations' weight of a campaign that measures them (:func:`weighting`).

    Attributes
    ----------
    weight
        ``w = sigma_t / sigma_r`` (m/rad).
    sigma_rad
        The rotation noise std (rad): the known one, else the residuals' at :attr:`fit`
        (``None`` without degrees of freedom).
    source
        Where ``sigma_rad`` comes from: ``declared``, ``replicates`` or ``residuals``.
    fit
        The caller's baseline fit at :attr:`weight`, ``None`` when both noise stds are known
        (no fit was needed).
    """

    weight: float
    sigma_rad: float | None
    source: str
    fit: Fit | None = None

    def measured(self, campaign: Campaign) -> np.ndarray:
        """The campaign's observations at this weight (m; ``[d; w r]``)."""
        return observations(campaign.deflection, campaign.rotation, self.weight)


def weighting(campaign: Campaign, translation: float | None,
              fit: Callable[[float, Fit | None], Fit], robust: bool = False) -> RotationWeight:
    """The weight of a ``campaign``'s measured rotations, ``sigma_t / sigma_r`` (m/rad).

    Parameters
    ----------
    campaign
        A deflection campaign with measured rotations.
    translation
        The known translation noise std (m: declared, or the replicates'; :func:`known_noise`),
        ``None`` to estimate it from the residuals.
    fit
        The caller's baseline fit at a weight, ``fit(weight, previous)``, ``previous`` the
        last round's fit (``None`` at the first) to start from; asked only when a std is to be
        estimated.
    robust
        Whether the replicates' scatter is the robust one (a robust loss).

    Returns
    -------
    RotationWeight
        The weight with the rotation noise std: both known, their ratio and no fit; else the
        fixed point of ``w -> s_t / s_r``, each unknown std from the residuals of ``fit(w)``
        (:func:`~stiffness.calibration.fitting.kind_noise` over ``6 m`` components and the
        fit's parameters), from the known stds or the measured RMS of the unknown kind, until
        a round moves ``w`` by at most :data:`WEIGHT_TOLERANCE` of it (at most
        :data:`MAX_ROUNDS` fits), with the fit at the weight returned.
    """
    rotation = campaign.rotation
    assert rotation is not None  # a campaign with rotations
    known = known_noise(campaign, "rotation", robust)
    sigma_r, source = (known[0], known[2]) if known is not None else (None, "residuals")
    if translation is not None and sigma_r is not None:
        return RotationWeight(translation / sigma_r, sigma_r, source)
    rms_t = float(np.sqrt(np.mean(campaign.deflection ** 2))) or 1.0
    rms_r = float(np.sqrt(np.mean(rotation ** 2))) or 1.0
    weight = (translation or rms_t) / (sigma_r or rms_r)
    current: Fit | None = None
    estimated = sigma_r
    for _ in range(MAX_ROUNDS):
        current = fit(weight, current)
        res_t, res_r = current.residuals(observations(campaign.deflection, rotation, weight))
        n, p = 2 * campaign.deflection.size, len(current.x)
        s_t = translation if translation is not None else kind_noise(res_t, n, p)
        estimated = sigma_r if sigma_r is not None else kind_noise(res_r, n, p)
        if not s_t or not estimated or math.isclose(s_t / estimated, weight,
                                                    rel_tol=WEIGHT_TOLERANCE):
            break
        weight = s_t / estimated
    else:  # not settled: the last weight, fitted
        current = fit(weight, current)
    return RotationWeight(weight, estimated, source, current)
