"""The one selection loop of ``diagnose``, for both campaign kinds (:func:`search`).

From the current model, each step stops when it fits to the noise (:func:`~stiffness.
calibration.selection.fits_to_noise` of the kind's :meth:`SearchKind.noise_terms`) or
``max_steps`` were added; else the kind fits its candidate extensions, ranked by BIC under
the step's overdispersion (:func:`ranked`). Of those improving BIC by more than
:data:`~stiffness.calibration.selection.BIC_MARGIN` (in BIC order),
the first :data:`~stiffness.calibration.selection.CV_TOP` that may be named as fitted and once
their undetermined parameters are held at nominal (:mod:`stiffness.calibration.naming`) are
judged held out, and the first whose held-out RMS beats the current model's is added; else the
search stops and says why (:class:`Stop`, in the kind's words). A candidate the kind refuses,
``refused``, is never added, and the first such one's reason ends the stop reason: one whose
fit has values no robot has (:meth:`SearchKind.unphysical`: a pose fit's zero offsets or turns
beyond a few degrees, or a pair of them that cancel; refused before it is judged held out,
whatever its BIC), or one the kind's rows cannot judge held out.

Then backward elimination (:func:`eliminate`): a greedy search can keep an effect that a later
one made redundant (an early stand-in for what the later ones model). The final fit is refitted
without each effect it added (:meth:`SearchKind.without`, except the forced ones and those
another one acts through: :meth:`SearchKind.removable`); those whose removal lowers BIC by more
than :data:`~stiffness.calibration.selection.BIC_MARGIN` under the same overdispersion rule
(:func:`~stiffness.calibration.selection.step_criteria`, the final fit as the current model)
are judged held out in BIC order, the first :data:`~stiffness.calibration.selection.CV_TOP`,
and the first whose held-out RMS is not above the final's and whose refit the kind does not
call unphysical (:meth:`SearchKind.unphysical`) is removed
(:meth:`SearchKind.remove`, recorded as a :class:`Step` marked ``removed``), and so on until
none is. The stop reason then says what was removed after the forward search stopped. The
refits of the last final are kept (:attr:`SearchKind.removals`): how sure the diagnosis is
(:func:`stiffness.calibration.certainty.how_sure`) reads them instead of refitting.

A campaign kind is a small object (:class:`SearchKind`): its candidates and their fits, its
reported parameters, how it settles a candidate, its held-out criterion, how it records a step
and how it removes an added effect again (:func:`stiffness.calibration.certainty.how_sure`):
:class:`stiffness.calibration.diagnose.DeflectionSearch`,
:class:`stiffness.calibration.pose_diagnose.PoseSearch`. Both record their steps as
:class:`Step`, and both kinds' results read them alike
(:class:`stiffness.calibration.result.DiagnosisResult`).
"""

from __future__ import annotations

import enum
import itertools
import math
from collections.abc import Collection, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, Generic, Protocol, TypeVar

import numpy as np

from stiffness.calibration.identifiability import Identifiability
from stiffness.calibration.naming import namable
from stiffness.calibration.selection import (
    BIC_MARGIN,
    CV_TOP,
    Noise,
    NoiseTerms,
    step_criteria,
)
from stiffness.elastic.effects.base import Effect, Parameter
from stiffness.errors import StiffnessError


class Fitted(Protocol):
    """What the loop, :mod:`~stiffness.calibration.certainty` and both kinds' results read of
    a fit of either kind (:class:`~stiffness.calibration.fitting.Fit`,
    :class:`~stiffness.calibration.pose_fit.PoseFit`): ``x``, which it fitted and held."""

    @property
    def x(self) -> np.ndarray: ...

    @property
    def identifiability(self) -> Identifiability | None: ...

    def terms(self) -> tuple[float, int]:
        """Its objective as a sum of squares (m^2) and parameter count: what the criteria take."""

    def rms(self) -> float:
        """RMS residual component (m)."""

    def labels(self) -> list[str]:
        """Each column of ``x`` named."""

    def additions(self) -> Collection[str]:
        """What its model adds to the baseline, by label (effects; pose families)."""


#: What a candidate or a step adds: an effect of the library, or a pose family's name.
E = TypeVar("E", bound=Effect | str)
F = TypeVar("F", bound=Fitted)


@dataclass(eq=False)
class Candidate(Generic[E, F]):
    """One candidate of a step: what it adds (an effect; a pose family's name), its fit, its
    BIC and change from the current model's (the step's ranking: of the fit in full, even
    when ``settled``, ``fit`` then holding undetermined parameters at nominal), the parameter
    count that BIC penalises (``params``, of the fit given, the ranked one: a later settled
    ``fit`` counts fewer) and its held-out RMS (m) once judged, or why the kind refuses it
    (``refused``: then never added; its fit unphysical, :meth:`SearchKind.unphysical`, or
    one configuration's rows cannot judge it,
    :func:`~stiffness.calibration.selection.row_support`); whether it may be named, once the
    step's winner was looked for (``namable``; ``None``: not looked at, :func:`_named`)."""

    effect: E
    fit: F
    bic: float
    delta_bic: float
    cv_rms: float | None = None
    settled: bool = False
    refused: str | None = None
    namable: bool | None = None
    params: int = field(init=False)

    def __post_init__(self) -> None:
        self.params = self.fit.terms()[1]


def label(what: Effect | str) -> str:
    """What a candidate or step adds, by label: an effect's ``name(where)``, a family's name."""
    return what if isinstance(what, str) else what.label


@dataclass
class Step(Generic[E, F]):
    """One step of a diagnosis of either kind: what it adds, or (``removed``) what the backward
    elimination (:func:`eliminate`) removes again, and the fit after it.

    Attributes
    ----------
    effect, fit
        What the step adds or removes (an effect; a pose family's name, ``"baseline"`` for a
        pose diagnosis's step 0) and the fit after it.
    delta_bic, cv_rms, dispersion
        Its BIC change, held-out RMS (m) and overdispersion (its BICs use the noise variance
        times this: :func:`~stiffness.calibration.selection.step_criteria`).
    ranking
        The step's candidates, best first: what each adds, its BIC change and held-out RMS
        (m, or ``None``): a deflection step's best six fitted, a pose step's every family
        tried (screened or fitted); none for a removal.
    parameters
        A deflection step's effect's parameters, campaign units (a pose diagnosis reads its
        families' from the fits).
    validation
        Its model, not refitted, on a validation campaign (``diagnose --validate``), or
        ``None``.
    forced
        Forced in (``diagnose --families``: added first, whatever its BIC and held-out
        error; never removed again).
    not_judged
        The step's candidates passed over without a held-out verdict, by label, and why
        (:func:`not_judged`, added by :func:`search`; a pose step's also an infinite
        held-out RMS, or a family screened but not fitted).
    refused
        The step's candidates the kind refused before the winner (:attr:`Candidate.refused`:
        unphysical, or the rows cannot judge them), by label, and why (added by
        :func:`search`; also in ``not_judged``).
    """

    effect: E
    fit: F
    delta_bic: float
    cv_rms: float
    ranking: list[tuple[E, float, float | None]] = field(default_factory=list)
    parameters: list[Parameter] = field(default_factory=list)
    dispersion: float = 1.0
    validation: dict | None = None
    forced: bool = False
    removed: bool = False
    not_judged: dict[str, str] = field(default_factory=dict)
    refused: dict[str, str] = field(default_factory=dict)

    @property
    def label(self) -> str:
        """What it adds or removes, by :func:`label`."""
        return label(self.effect)


def kept_steps(steps: Sequence[Step[E, F]], labels: Collection[str]) -> list[Step[E, F]]:
    """The steps adding what ``labels`` name (a final model's effects or families), none
    removed again, in order."""
    return [s for s in steps if not s.removed and s.label in labels]


class Stop(enum.Enum):
    """Why a step adds nothing."""

    LEFT = "nothing left to try"
    BIC = "no candidate past the BIC margin"
    NAMED = "none of those may be named"
    HELD_OUT = "none of those beats the held-out error"
    REFUSED = "the kind refuses all of those (unphysical, or its rows cannot judge them)"


#: The words in :func:`search`'s stop reason when ``max_steps`` cut the forward search
#: short (the verdict reads :attr:`SearchKind.cut_short`, the ``--json`` key ``cut_short``).
CUT_SHORT = "(max_steps)"


@dataclass(eq=False)
class Refusal(Generic[E, F]):
    """The forward search's last step, which added nothing (:func:`search`): its candidates,
    best BIC first (:func:`ranked`; a pose step's those fitted), the ``current`` fit they
    extend, its held-out RMS ``cv_current`` (m) and why none was added."""

    ranking: list[Candidate[E, F]]
    current: F
    cv_current: float
    why: Stop


@dataclass(eq=False)
class Removals(Generic[F]):
    """A final fit refitted without each effect it added (:meth:`SearchKind.without`, in
    order) and the held-out RMS (m) of those judged so far, by position."""

    final: F
    fits: list[F]
    cv_rms: dict[int, float]

    def held_out(self, kind: SearchKind[Any, F], which: Sequence[int]) -> list[float]:
        """The held-out RMS (m) of the refits at positions ``which``, each judged once."""
        missing = [i for i in which if i not in self.cv_rms]
        if missing:
            self.cv_rms.update(zip(missing, kind.held_out_of([self.fits[i] for i in missing]),
                                   strict=True))
        return [self.cv_rms[i] for i in which]


class SearchKind(Protocol[E, F]):
    """What a campaign kind supplies to :func:`search`: its residual count ``n`` and noise
    std ``sigma`` (m; ``None``: not known), its words for each :class:`Stop`, the last
    final fit's :class:`Removals` (``None`` before :func:`eliminate`), the step that added
    nothing (:class:`Refusal`, ``None`` unless the forward search stopped so), whether
    ``max_steps`` cut the forward search short (``cut_short``, set by :func:`search`), its
    :class:`Step` records, and the methods below (its fits' objective and parameter count are
    the fits' own, :meth:`Fitted.terms`)."""

    n: int
    stops: ClassVar[dict[Stop, str]]
    removals: Removals[F] | None
    refusal: Refusal[E, F] | None
    cut_short: bool
    steps: list[Step[E, F]]

    @property
    def sigma(self) -> float | None:
        """The noise std (m), ``None`` when not known."""

    @property
    def noise(self) -> Noise | None:
        """The noise std and how it is known (:class:`~stiffness.calibration.selection.Noise`:
        its test of fitting to it), ``None`` when not known."""

    def noise_terms(self, fit: F) -> NoiseTerms:
        """What ``fit``'s fit-to-noise test reads, over the rows it keeps (a robust loss's
        flagged rows left out): :func:`~stiffness.calibration.selection.kept_terms` of the
        kind's residual rows."""

    def candidates(self, current: F) -> list[Candidate[E, F]] | None:
        """The extensions of ``current`` fitted, :func:`ranked` (``None``: none left)."""

    def parameters(self, c: Candidate[E, F]) -> list[Parameter]:
        """The reported parameters (SI) of what ``c`` adds, in ``c.fit``."""

    def settle(self, c: Candidate[E, F]) -> F:
        """``c.fit`` with the undetermined parameters of what it adds held at nominal
        (:func:`~stiffness.calibration.naming.settle`)."""

    def split_confused(self, c: Candidate[E, F]) -> F | None:
        """When no parameter of what ``c`` adds may be named as fitted (:func:`namable`) because
        the data confuse some of them with one another, ``c.fit`` with, of each such pair, the
        one whose holding costs the fit least held at nominal; ``None`` when none are."""

    def unphysical(self, fit: F) -> str | None:
        """Why ``fit`` may not end the search though the data determine it (one line: values
        no robot has, in what the search chose, not in what the user forced), ``None`` when
        it may. A candidate so refused is never judged held out nor added, nor a removal's
        refit kept (:func:`search`)."""

    def held_out(self, named: Iterator[Candidate[E, F]]) -> Iterator[Candidate[E, F]]:
        """The ``named`` candidates in order, each with its held-out RMS ``cv_rms`` (m)."""

    def accept(self, current: F, winner: Candidate[E, F], ranking: list[Candidate[E, F]]
               ) -> F:
        """The step adding ``winner`` to ``current`` recorded; the new current fit."""

    def reject(self, ranking: list[Candidate[E, F]]) -> None:
        """The last step's candidates recorded, none added."""

    def without(self, final: F) -> list[F]:
        """``final`` refitted without each effect it added, in order (how sure a diagnosis
        is, :func:`~stiffness.calibration.certainty.how_sure`)."""

    def held_out_of(self, fits: list[F]) -> list[float]:
        """The held-out RMS (m) of each of ``fits``."""

    def removable(self, final: F) -> list[bool]:
        """Whether each effect ``final`` added (in :meth:`without`'s order) may be removed:
        not forced, and no other effect acts through it."""

    def remove(self, final: F, index: int, fit: F) -> E:
        """``final``'s effect ``index`` removed (``fit``: ``final`` without it), said; that
        effect."""


def check_max_steps(max_steps: int | None) -> None:
    """Refuse a ``max_steps`` (``diagnose --max-steps``) that is not ``None`` or a
    non-negative integer (one line).

    Raises
    ------
    StiffnessError
        A negative, non-integer or boolean ``max_steps``.
    """
    if max_steps is None:
        return
    if isinstance(max_steps, bool) or not isinstance(max_steps, int | np.integer) \
            or max_steps < 0:
        raise StiffnessError(f"--max-steps must be a non-negative integer (0: the baseline "
                             f"only), got {max_steps!r}")


def search(kind: SearchKind[E, F], current: F, cv_current: float,
           max_steps: int | None = None) -> tuple[F, str]:
    """Add ``kind``'s candidates to ``current`` (held-out RMS ``cv_current``, m), then remove
    those the final model is better without (:func:`eliminate`), as the module docstring
    says; the final fit and why the search stopped (``kind.cut_short``: whether
    ``max_steps`` stopped it)."""
    kind.cut_short = False
    final, cv_final, stop = _forward(kind, current, cv_current, max_steps)
    final, removed = eliminate(kind, final, cv_final)
    if removed:
        stop += (f"; then removed {', '.join(removed)}: the final model is better without "
                 f"(BIC lower by more than {BIC_MARGIN:g}, held-out error not higher)")
    return final, stop


def _forward(kind: SearchKind[E, F], current: F, cv_current: float, max_steps: int | None
             ) -> tuple[F, float, str]:
    """The forward search: the last fit, its held-out RMS (m) and why it stopped."""
    added = 0
    while True:
        noise = kind.noise_terms(current).verdict(kind.noise)
        if noise is not None:
            return current, cv_current, noise
        if max_steps is not None and added >= max_steps:
            kind.cut_short = True
            return current, cv_current, f"stopped after {max_steps} effects {CUT_SHORT}"
        ranking = kind.candidates(current)
        if ranking is None:
            return current, cv_current, kind.stops[Stop.LEFT]
        winner, why, refused = _winner(kind, ranking, cv_current)
        if winner is None or winner.cv_rms is None:
            kind.refusal = Refusal(ranking, current, cv_current, why)
            kind.reject(ranking)
            return current, cv_current, kind.stops[why] + "".join(
                f"; {label(c.effect)} not judged: {c.refused}" for c in refused[:1])
        current, cv_current = kind.accept(current, winner, ranking), winner.cv_rms
        kind.steps[-1].not_judged.update(not_judged(ranking))
        kind.steps[-1].refused.update({label(c.effect): c.refused for c in refused
                                       if c.refused is not None})
        added += 1


def eliminate(kind: SearchKind[E, F], final: F, cv_final: float) -> tuple[F, list[str]]:
    """Remove from ``final`` (held-out RMS ``cv_final``, m) the effects it is better without,
    one at a time (the module docstring); the last fit and the labels removed, in order.
    Leaves the last fit's :class:`Removals` in ``kind.removals``."""
    removed: list[str] = []
    while True:
        which = [i for i, ok in enumerate(kind.removable(final)) if ok]
        if not which:
            return final, removed
        out = kind.removals = Removals(final, kind.without(final), {})
        base, bics, dispersion = step_criteria(
            final.terms(), [out.fits[i].terms() for i in which], kind.n, kind.sigma)
        delta = {i: b - base for i, b in zip(which, bics, strict=True)}
        eligible = sorted((i for i in which if delta[i] < -BIC_MARGIN), key=delta.__getitem__)
        drop = next((i for i in eligible[:CV_TOP] if kind.unphysical(out.fits[i]) is None
                     and _not_worse(out.held_out(kind, [i])[0], cv_final)), None)
        if drop is None:
            return final, removed
        final, cv_final = out.fits[drop], out.cv_rms[drop]
        effect = kind.remove(out.final, drop, final)
        kind.steps.append(Step(effect, final, delta[drop], cv_final, dispersion=dispersion,
                               removed=True))
        removed.append(label(effect))


def _not_worse(cv: float, cv_final: float) -> bool:
    """Whether a held-out RMS ``cv`` (m) is not above ``cv_final`` (either NaN: no folds to
    judge by, not held against it)."""
    return math.isnan(cv_final) or math.isnan(cv) or cv <= cv_final


def _winner(kind: SearchKind[E, F], ranking: list[Candidate[E, F]], cv_current: float
            ) -> tuple[Candidate[E, F] | None, Stop, list[Candidate[E, F]]]:
    """The step's winner (a held-out RMS ``cv_current`` not known, NaN, holds none back), or
    ``None`` and why; and the candidates refused (:attr:`Candidate.refused`: unphysical, or
    the rows could not judge them), in order."""
    eligible = [c for c in ranking if c.delta_bic < -BIC_MARGIN]
    if not eligible:
        return None, Stop.BIC, []
    refused: list[Candidate[E, F]] = []
    judged = False
    named = itertools.islice((c for c in eligible if _named(kind, c)), CV_TOP)
    for c in kind.held_out(_physical(kind, named, refused)):
        if c.refused is not None:
            refused.append(c)
            continue
        judged = True
        if c.cv_rms is not None and (c.cv_rms < cv_current or math.isnan(cv_current)):
            return c, Stop.HELD_OUT, _in_order(refused, ranking)
    why = Stop.HELD_OUT if judged else Stop.REFUSED if refused else Stop.NAMED
    return None, why, _in_order(refused, ranking)


def _physical(kind: SearchKind[E, F], named: Iterator[Candidate[E, F]],
              refused: list[Candidate[E, F]]) -> Iterator[Candidate[E, F]]:
    """The ``named`` candidates whose fit the kind does not call unphysical; the others
    ``refused`` (:meth:`SearchKind.unphysical`, why), added to ``refused`` and never judged
    held out."""
    for c in named:
        c.refused = kind.unphysical(c.fit)
        if c.refused is None:
            yield c
        else:
            refused.append(c)


def _in_order(cs: list[Candidate[E, F]], ranking: list[Candidate[E, F]]
              ) -> list[Candidate[E, F]]:
    """``cs`` in the order of ``ranking`` (BIC)."""
    place = {id(c): k for k, c in enumerate(ranking)}
    return sorted(cs, key=lambda c: place[id(c)])


def _named(kind: SearchKind[E, F], c: Candidate[E, F]) -> bool:
    """Whether ``c`` may be named as fitted and still once settled (then ``c.fit``, its held-out
    RMS forgotten); holding parameters never makes a candidate namable, but for one whose
    parameters the data confuse pairwise (:meth:`SearchKind.split_confused`): one of each
    pair held, the other may be named."""
    c.namable = namable(kind.parameters(c))
    if not c.namable:
        split = kind.split_confused(c)
        if split is None:
            return False
        c.fit, c.settled, c.cv_rms = split, True, None
        c.namable = namable(kind.parameters(c))
        if not c.namable:
            return False
    full = c.fit
    c.fit = kind.settle(c)
    if c.fit is not full:
        c.settled, c.cv_rms = True, None
    c.namable = namable(kind.parameters(c))
    return c.namable


#: Why a candidate that may not be named was passed over (:attr:`Step.not_judged`).
NOT_NAMABLE = "it may not be named: no parameter determined with its 95 % interval excluding zero"


def not_judged(ranking: Sequence[Candidate[E, F]]) -> dict[str, str]:
    """The candidates of a step's ``ranking`` passed over unjudged held out, by label, and
    why: the kind refuses them (:attr:`Candidate.refused`) or they may not be named
    (:data:`NOT_NAMABLE`) (a :class:`Step`'s ``not_judged``)."""
    return {label(c.effect): c.refused if c.refused is not None else NOT_NAMABLE
            for c in ranking if c.refused is not None or c.namable is False}


def ranked(kind: SearchKind[E, F], current: F, fits: Sequence[tuple[E, F]]
           ) -> tuple[list[Candidate[E, F]], float]:
    """A step's candidates ``(effect, fit)`` by BIC (best first) under the step's
    overdispersion (:func:`~stiffness.calibration.selection.step_criteria`), and that."""
    current_bic, bics, dispersion = step_criteria(
        current.terms(), [f.terms() for _, f in fits], kind.n, kind.sigma)
    out = [Candidate(e, f, b, b - current_bic) for (e, f), b in zip(fits, bics, strict=True)]
    out.sort(key=lambda c: c.bic)
    return out, dispersion
