"""How sure a diagnosis is of each effect it names (``stiffness diagnose``).

For each effect of the final model:

* **held-out cost of removing it**: the final model refitted without it (from the final
  parameters), judged by the kind's held-out criterion (a deflection campaign's configuration
  folds, a pose campaign's leave-one-configuration-out); the cost is that model's held-out RMS
  minus the final model's (m): what predicting unseen configurations loses without the
  effect. Its in-sample counterpart is the BIC change of the removal
  (positive: the effect earns its parameters), under the overdispersion of the step that
  named it (a misfit above the noise acts as extra noise), on that step's scale.
* **best alternative**: the best-ranked other candidate of the step that named it, and its BIC
  minus the chosen one's (a few units: a coin toss; tens: solid).
* **stand-in**: a parameter determined (:attr:`stiffness.elastic.effects.base.Parameter.
  determined`) but beyond its physical scale: the data prefer the effect's shape, its size is
  not physical (a finding only of that shape).

The rules (stand-in, best alternative) are :mod:`stiffness.calibration.naming`'s; the removals
and their held-out RMS the campaign kind's (:class:`~stiffness.calibration.search.SearchKind`).

SI inside; :meth:`Certainty.to_dict` in the campaign's length unit, which both kinds' text
report (:func:`how_sure_lines`) and page (:func:`how_sure_table`) read.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from stiffness.calibration.naming import STAND_IN_NOTE, alternative
from stiffness.calibration.search import E, F, Removals, SearchKind, Step, label
from stiffness.calibration.selection import information_criterion
from stiffness.htmlpage import esc, table


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
        BIC of the final model without it minus the final model's, under the overdispersion
        of the step that named it (:attr:`~stiffness.calibration.search.Step.dispersion`), as
        that step's BIC changes are: removing the last effect added costs what adding it
        gained.
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


def how_sure(kind: SearchKind[E, F], final: F, cv_final: float, named: Sequence[Step[E, F]],
             stand_in: Callable[[str], bool]) -> list[Certainty]:
    """The :class:`Certainty` of what each step ``named`` adds to a diagnosis whose final fit
    is ``final`` (held-out RMS ``cv_final``, m): its step's ranking, its own BIC change and
    whether it is a stand-in (``stand_in`` of its label); removed in turn
    (:meth:`~stiffness.calibration.search.SearchKind.without`, judged held out by
    :meth:`~stiffness.calibration.search.SearchKind.held_out_of`: those the search's
    backward elimination made of ``final``, :attr:`~stiffness.calibration.search.SearchKind.
    removals`, read, not made again)."""
    if not named:
        return []

    def bic(fit: F, dispersion: float) -> float:
        rss, p = fit.terms()
        return information_criterion(rss, kind.n, p, None if kind.sigma is None
                                     else kind.sigma * math.sqrt(dispersion))

    out = kind.removals
    if out is None or out.final is not final:
        out = kind.removals = Removals(final, kind.without(final), {})
    return [Certainty(s.label, cv - cv_final, bic(fit, s.dispersion) - bic(final, s.dispersion),
                      *alternative([(label(e), d) for e, d, _ in s.ranking], s.label,
                                   s.delta_bic), stand_in(s.label))
            for s, fit, cv in zip(named, out.fits, out.held_out(kind, range(len(out.fits))),
                                  strict=True)]


def how_sure_lines(d: dict) -> list[str]:
    """The text report's lines of how sure a diagnosis of either kind is of each effect it
    named, from its ``--json`` object ``d`` (``how_sure``: :meth:`Certainty.to_dict`, the
    cost in ``d["unit"]``), then the stand-ins; none when it named none."""
    if not d.get("how_sure"):
        return []
    lines = ["how sure (each effect removed from the final model, the rest refitted; the best "
             "other candidate of its step):"]
    for c in d["how_sure"]:
        cost = ("not cross-validated" if c["held_out_cost"] is None else
                f"held-out RMS {c['held_out_cost']:+.3g} {d['unit']} without it")
        alt = ("no alternative" if c["alternative"] is None else
               f"best alternative {c['alternative']} (dBIC {c['alternative_delta_bic']:+.3g})")
        verdict = f"; STAND-IN: {STAND_IN_NOTE}" if c["stand_in"] else ""
        lines.append(f"  {c['effect']}: removing it: dBIC {c['removal_delta_bic']:+.3g}, "
                     f"{cost}; {alt}{verdict}")
    stand_ins = [c["effect"] for c in d["how_sure"] if c["stand_in"]]
    return lines + ([f"stand-ins ({STAND_IN_NOTE}): " + ", ".join(stand_ins)] if stand_ins
                    else [])


def how_sure_table(d: dict) -> list[str]:
    """The diagnosis page's table of how sure each named effect is, from the ``--json``
    object ``d`` of either kind (as :func:`how_sure_lines`); none when it named none."""
    if not d.get("how_sure"):
        return []
    return [table("How sure: each named effect", [
        "effect", "ΔBIC without it", f"held-out RMS change without it ({d['unit']})",
        "best alternative", "its ΔBIC", "stand-in"], [
        [esc(c["effect"]), c["removal_delta_bic"], c["held_out_cost"],
         esc(c["alternative"] or "none"), c["alternative_delta_bic"],
         "yes: the data prefer this shape; its size is not physical" if c["stand_in"]
         else "no"] for c in d["how_sure"]],
        "Each effect removed from the final model and the rest refitted: the BIC change "
        "(positive: the effect earns its parameters) and the change of the RMS predicted "
        "for configurations left out (positive: worse without it). Best alternative: the "
        "best other candidate of the step that named it, and its BIC minus the chosen "
        "one's (a few units: a coin toss).")]
