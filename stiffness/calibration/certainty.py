"""How sure a diagnosis is of each effect it names (``stiffness diagnose``).

For each effect of the final model:

* **held-out cost of removing it**: the final model refitted without it (from the final
  parameters), cross-validated over the same configuration folds; the cost is that model's
  cross-validated RMS minus the final model's (m): what predicting unseen configurations
  loses without the effect. Its in-sample counterpart is the BIC change of the removal
  (positive: the effect earns its parameters).
* **best alternative**: the best-ranked other candidate of the step that named it, and its BIC
  minus the chosen one's (a few units: a coin toss; tens: solid).
* **stand-in**: a parameter determined (:attr:`stiffness.elastic.effects.base.Parameter.
  determined`) but beyond its physical scale: the data prefer the effect's shape, its size is
  not physical (a finding only of that shape).

The rules (stand-in, best alternative) are :mod:`stiffness.calibration.naming`'s, shared with
pose diagnoses; this module refits a deflection campaign's final model without each effect.

SI inside; :meth:`Certainty.to_dict` in the campaign's length unit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stiffness.calibration import fitting
from stiffness.calibration.fitting import Fit
from stiffness.calibration.naming import STAND_IN_NOTE, alternative, is_stand_in
from stiffness.calibration.selection import cross_validate, fit_job, information_criterion
from stiffness.elastic.effects.base import Parameter


@dataclass
class Certainty:
    """How sure the diagnosis is of one named effect.

    Attributes
    ----------
    effect
        The effect's label.
    held_out_cost
        Cross-validated RMS without it minus the final model's (m); NaN without folds.
    removal_delta_bic
        BIC of the final model without it minus the final model's.
    alternative, alternative_delta_bic
        Label of the best other candidate of its step and its BIC minus the chosen one's
        (``None`` when the step had no other candidate).
    stand_in
        Whether a determined parameter is beyond its physical scale.
    """

    effect: str
    held_out_cost: float
    removal_delta_bic: float
    alternative: str | None
    alternative_delta_bic: float | None
    stand_in: bool

    def to_dict(self, length_to_si: float = 1.0) -> dict:
        """JSON-ready (the cost in the campaign's length unit; NaN as ``None``)."""
        cost = self.held_out_cost / length_to_si
        return {"effect": self.effect,
                "held_out_cost": cost if math.isfinite(cost) else None,
                "removal_delta_bic": self.removal_delta_bic,
                "alternative": self.alternative,
                "alternative_delta_bic": self.alternative_delta_bic,
                "stand_in": self.stand_in}

    def text(self, unit: str, length_to_si: float) -> str:
        """One line of the text report."""
        cost = ("not cross-validated" if not math.isfinite(self.held_out_cost) else
                f"held-out RMS {self.held_out_cost / length_to_si:+.3g} {unit} without it")
        alt = ("no alternative" if self.alternative is None else
               f"best alternative {self.alternative} (dBIC {self.alternative_delta_bic:+.3g})")
        verdict = f"; STAND-IN: {STAND_IN_NOTE}" if self.stand_in else ""
        return (f"  {self.effect}: removing it: dBIC {self.removal_delta_bic:+.3g}, {cost}; "
                f"{alt}{verdict}")


def certainty(final: Fit, steps: list, parameters: dict[str, list[Parameter]],
              measured: np.ndarray, folds: list[np.ndarray], cv_final: float, n: int,
              sigma: float | None, workers: int | None = None) -> list[Certainty]:
    """The :class:`Certainty` of each effect of ``final`` (in order), from the diagnosis's
    ``steps`` (:class:`~stiffness.calibration.diagnosis.Step`: their rankings), the final
    ``parameters`` by effect label, the fitted observations (m), the folds, the final
    model's cross-validated RMS (m), the residual count and the noise std (m, or None)."""
    model = final.model
    if not model.effects:
        return []
    jobs = []
    for i in range(len(model.effects)):
        keep = tuple(e for j, e in enumerate(model.effects) if j != i)
        x = np.delete(final.x, np.arange(model.offsets[i + 1], model.offsets[i + 2]))
        jobs.append(fit_job(model.with_effects(keep), measured, final.scale, x,
                            loss=final.loss, f_scale=final.f_scale))
    without = fitting.fit_models(jobs, workers)
    cv = cross_validate(without, measured, folds, workers) if folds else [math.nan] * len(
        without)
    bic_final = information_criterion(final.loss_rss, n, final.penalty_params, sigma)
    out = []
    for i, (effect, fit, cv_without) in enumerate(zip(model.effects, without, cv,
                                                      strict=True)):
        step = steps[i] if i < len(steps) else None
        other, d_alt = _alternative(step)
        out.append(Certainty(
            effect.label, cv_without - cv_final,
            information_criterion(fit.loss_rss, n, fit.penalty_params, sigma) - bic_final,
            other, d_alt, is_stand_in(parameters.get(effect.label, []))))
    return out


def _alternative(step) -> tuple[str | None, float | None]:
    """The best other candidate of ``step``'s ranking and its BIC minus the chosen one's."""
    if step is None:
        return None, None
    ranking = [(r["effect"] if r["where"] is None else f"{r['effect']}({r['where']})",
                r["delta_bic"]) for r in step.ranking]
    return alternative(ranking, step.effect.label, step.delta_bic)
