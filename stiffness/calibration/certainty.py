"""How sure a diagnosis is of each effect it names (``stiffness diagnose``).

For each effect of the final model:

* **held-out cost of removing it**: the final model refitted without it (from the final
  parameters), judged by the kind's held-out criterion (a deflection campaign's configuration
  folds, a pose campaign's leave-one-configuration-out); the cost is that model's held-out RMS
  minus the final model's (m): what predicting unseen configurations loses without the
  effect. Its in-sample counterpart is the BIC change of the removal
  (positive: the effect earns its parameters), under one overdispersion for every removal:
  the least misfit per degree of freedom that the final model, its removals or any
  candidate of the steps that named its effects leaves (:func:`dispersion`; a misfit above
  the noise acts as extra noise, :func:`~stiffness.calibration.selection.step_criteria`'s
  rule over every model the comparison can draw on). So an effect named earlier, under a
  misfit the later effects explained, is judged on what the final model leaves, not on that
  larger misfit; and the last effect named is judged on at least its own step's evidence:
  removing it costs what adding it gained (more only when the final model or a removal
  leaves less misfit than every model of that step), although its step's overdispersion came
  from a candidate not added (FIGAROH's TIAGo: ``geometry`` left 11.4 times the noise
  variance, the final model 19.1).
* **best alternative**: the best-ranked other candidate of the step that named it, and its BIC
  minus the chosen one's (a few units: a coin toss; tens: solid), and why it was not chosen
  (:class:`NotChosen`, from what that step recorded): ranked after the chosen one by BIC, or,
  ranked before it, refused on its held-out RMS (against the chosen one's) or passed over
  without a held-out verdict (why the rows could not judge it, or that it may not be named).
  The step ranks its candidates fitted in full, and only then holds the chosen one's
  undetermined parameters at nominal (:func:`~stiffness.calibration.naming.settle`): its BIC
  as named can rise past an alternative ranked after it, whose BIC change is then negative
  although its BIC was worse; the reason then says so (:data:`WORSE_BIC_IN_FULL`: its BIC
  against the chosen one's both fitted in full, and what holding cost the chosen one).
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
from stiffness.calibration.selection import information_criterion, step_criteria
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
        :func:`dispersion` (the module docstring).
    alternative, alternative_delta_bic
        Label of the best other candidate of its step and its BIC minus the chosen one's
        (``None`` when the step had no other candidate).
    not_chosen
        Why that alternative was not chosen (``None`` when there is none).
    stand_in
        Whether a determined parameter is beyond its physical scale.
    """

    effect: str
    held_out_cost: float
    removal_delta_bic: float
    alternative: str | None
    alternative_delta_bic: float | None
    stand_in: bool
    not_chosen: NotChosen | None = None

    def to_dict(self, length_to_si: float = 1.0) -> dict:
        """JSON-ready (the cost in the campaign's length unit; NaN as ``None``)."""
        cost = self.held_out_cost / length_to_si
        return {"effect": self.effect,
                "held_out_cost": cost if math.isfinite(cost) else None,
                "removal_delta_bic": self.removal_delta_bic,
                "alternative": self.alternative,
                "alternative_delta_bic": self.alternative_delta_bic,
                "alternative_not_chosen": None if self.not_chosen is None
                else self.not_chosen.to_dict(length_to_si),
                "stand_in": self.stand_in}


#: :attr:`NotChosen.reason`: ranked after the chosen one by BIC (its fit in full).
WORSE_BIC = "worse BIC"
#: :attr:`NotChosen.reason`: ranked after the chosen one by BIC, both fitted in full, but below
#: the chosen one's once the latter's undetermined parameters were held at nominal.
WORSE_BIC_IN_FULL = "worse BIC fitted in full"
#: :attr:`NotChosen.reason`: judged held out and refused.
HELD_OUT = "held-out error"
#: :attr:`NotChosen.reason`: passed over without a held-out verdict.
NOT_JUDGED = "not judged held out"


@dataclass
class NotChosen:
    """Why the best alternative of a step was not chosen.

    Attributes
    ----------
    reason
        :data:`WORSE_BIC`, :data:`WORSE_BIC_IN_FULL`, :data:`HELD_OUT` or :data:`NOT_JUDGED`.
    held_out_rms, chosen_held_out_rms
        :data:`HELD_OUT`: its held-out RMS and the chosen one's (m); else NaN.
    note
        :data:`NOT_JUDGED`: why (:attr:`~stiffness.calibration.search.Step.not_judged`), or
        ``None`` when the step did not say.
    ranked_delta_bic
        :data:`WORSE_BIC_IN_FULL`: its BIC minus the chosen one's as the step ranked them,
        both fitted in full (a pose family the step did not fit, by its screen; positive);
        else NaN.
    """

    reason: str
    held_out_rms: float = math.nan
    chosen_held_out_rms: float = math.nan
    note: str | None = None
    ranked_delta_bic: float = math.nan

    def to_dict(self, length_to_si: float = 1.0) -> dict:
        """JSON-ready (lengths in the campaign's unit; NaN as ``None``)."""
        def length(x: float) -> float | None:
            return x / length_to_si if math.isfinite(x) else None
        return {"reason": self.reason, "held_out_rms": length(self.held_out_rms),
                "chosen_held_out_rms": length(self.chosen_held_out_rms), "note": self.note,
                "ranked_delta_bic": self.ranked_delta_bic
                if math.isfinite(self.ranked_delta_bic) else None}


def not_chosen(step: Step[E, F], alt: str | None) -> NotChosen | None:
    """Why ``alt``, the best alternative of ``step`` (:func:`~stiffness.calibration.naming.
    alternative`), was not chosen, from what the step recorded: ranked after the chosen one
    (:data:`WORSE_BIC`; :data:`WORSE_BIC_IN_FULL` with the ranking's BIC difference when its
    BIC is below the chosen one's as named, ``step.delta_bic``, whose undetermined parameters
    were held after the ranking); else passed over unjudged (its ``not_judged`` note), or
    judged held out and refused (its held-out RMS, then not below the model's the step
    extended, against the chosen one's: :data:`HELD_OUT`)."""
    if alt is None:
        return None
    if label(step.ranking[0][0]) != alt:  # ranking[0] is the chosen one, fitted in full
        delta = next(d for e, d, _ in step.ranking if label(e) == alt)
        if delta < step.delta_bic:
            return NotChosen(WORSE_BIC_IN_FULL, ranked_delta_bic=delta - step.ranking[0][1])
        return NotChosen(WORSE_BIC)
    cv = step.ranking[0][2]
    if alt in step.not_judged or cv is None:
        return NotChosen(NOT_JUDGED, note=step.not_judged.get(alt))
    return NotChosen(HELD_OUT, cv, step.cv_rms)


def dispersion(kind: SearchKind[E, F], final: F, removals: Sequence[F],
               named: Sequence[Step[E, F]]) -> float:
    """The overdispersion every removal of :func:`how_sure` is judged under:
    :func:`~stiffness.calibration.selection.step_criteria`'s ``c`` over ``final`` and its
    ``removals``, or the least :attr:`~stiffness.calibration.search.Step.dispersion` of the
    steps ``named`` (each its step's models' least misfit per degree of freedom, over the
    noise variance) when smaller; 1 with an unknown noise.

    Each is the misfit some fitted model leaves above the noise: the least of them is the best
    estimate the search has of what no model explains, so the same misfit is not counted as
    noise on one comparison and as explained on another. The last effect named is thus never
    judged on a larger overdispersion than its step's, which may have come from a candidate
    not added.
    """
    *_, c = step_criteria(final.terms(), [fit.terms() for fit in removals], kind.n, kind.sigma)
    return min([c, *(s.dispersion for s in named)])


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

    out = kind.removals
    if out is None or out.final is not final:
        out = kind.removals = Removals(final, kind.without(final), {})
    c = dispersion(kind, final, out.fits, named)
    sigma = None if kind.sigma is None else kind.sigma * math.sqrt(c)
    base, *bics = (information_criterion(rss, kind.n, p, sigma)
                   for rss, p in (f.terms() for f in [final, *out.fits]))
    certain = []
    for s, bic, cv in zip(named, bics, out.held_out(kind, range(len(out.fits))),
                          strict=True):
        alt, delta = alternative([(label(e), d) for e, d, _ in s.ranking], s.label, s.delta_bic)
        certain.append(Certainty(s.label, cv - cv_final, bic - base, alt, delta,
                                 stand_in(s.label), not_chosen(s, alt)))
    return certain


def why_not_text(c: dict, unit: str) -> str:
    """Why a ``how_sure`` entry's best alternative was not chosen, in words (its
    ``alternative_not_chosen``, lengths in ``unit``); empty when it has none."""
    why = c.get("alternative_not_chosen")
    if why is None:
        return ""
    if why["reason"] == HELD_OUT:
        return (f"held-out RMS {why['held_out_rms']:.4g} {unit} against the chosen one's "
                f"{why['chosen_held_out_rms']:.4g} {unit}")
    if why["reason"] == NOT_JUDGED and why["note"]:
        return f"{NOT_JUDGED}: {why['note']}"
    if why["reason"] == WORSE_BIC_IN_FULL:
        ranked = why["ranked_delta_bic"]
        return (f"{WORSE_BIC_IN_FULL}: dBIC {ranked:+.3g} against the chosen one fitted in full, "
                f"whose BIC then rose by {ranked - c['alternative_delta_bic']:.3g} with its "
                "undetermined parameters held at nominal")
    return why["reason"]


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
        why = why_not_text(c, d["unit"])
        alt = ("no alternative" if c["alternative"] is None else
               f"best alternative {c['alternative']} (dBIC {c['alternative_delta_bic']:+.3g}"
               f"{f'; not chosen: {why}' if why else ''})")
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
        "best alternative", "its ΔBIC", "why not chosen", "stand-in"], [
        [esc(c["effect"]), c["removal_delta_bic"], c["held_out_cost"],
         esc(c["alternative"] or "none"), c["alternative_delta_bic"],
         esc(why_not_text(c, d["unit"])),
         "yes: the data prefer this shape; its size is not physical" if c["stand_in"]
         else "no"] for c in d["how_sure"]],
        "Each effect removed from the final model and the rest refitted: the BIC change "
        "(positive: the effect earns its parameters) and the change of the RMS predicted "
        "for configurations left out (positive: worse without it). Best alternative: the "
        "best other candidate of the step that named it, and its BIC minus the chosen "
        "one's (a few units: a coin toss), and why it was not chosen: ranked after it by "
        "BIC (both fitted in full, before the chosen one's undetermined parameters were held "
        "at nominal), its held-out RMS against the chosen one's, or why it was not judged "
        "held out.")]
