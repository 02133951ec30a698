"""Which parameters a campaign can identify: one pivoted-QR reduction for every fit.

Both campaign kinds use it: a pose fit (:mod:`stiffness.calibration.pose_fit`, the regressor's
columns family by family) and a deflection fit (:func:`stiffness.calibration.fitting.fit_model`,
the baseline's compliances first, then each effect's variables in the order added; so
``diagnose``'s candidates, its final model and ``identify``).

The columns of a regressor (d y / d x over every observed component, each multiplied by its
parameter's typical size) are reduced group by group, in the order given: a column joins when
the part of it orthogonal to the columns already kept is at least :data:`IDENTIFIABILITY_TOL`
of its own norm (the sine of its angle to their span; column-pivoted QR within the group). A
parameter left out either has no effect on the data ("no effect": its column is below
:data:`IDENTIFIABILITY_TOL` of the largest column of its group) or is a combination of kept
ones ("merged": the kept parameters absorb it with the least-squares coefficients reported,
in the parameters' own units). A left-out parameter is held at its nominal value (the
model's start for its joint or effect, whatever the fit starts from:
:func:`stiffness.calibration.solver.held_at_nominal`) and reported as such, never as a value
the data gave.

Near aliases. A fit whose columns are whitened (residuals divided by the noise std) may also
give a ``resolution`` per group: a column nearly in the span of the columns kept from the
earlier groups (sine below :data:`NEAR_ALIAS_SINE`) whose part orthogonal to them is below
that resolution (in noise std per typical size of the parameter: the data tell it from them
by less than that) is merged too. A link bend about an axis parallel to a joint's differs
from that joint's spring only through the second-order kinematics; on a campaign where that
difference is below the noise the two are one compliance, and the joint's absorbs the
bend's. Only against earlier groups: within a group (one effect's parameters) only exact
aliases are merged, so that which of two nearly collinear parameters of one effect is held
is not decided by their column norms at one point; an effect's parameters the data do not
determine are held by the diagnosis, with why (:mod:`stiffness.calibration.diagnose`,
reason ``undetermined``).

Where the columns are taken. A parameter that acts only through an effect's size (a
compensator's base, whose torque scales with a stiffness that is 0 at the start; a vertical base
joint's compliance, which carries gravity's torque only once the base is tilted) has a zero
column where that effect is absent, although the data see it once the effect is there. Every fit
therefore judges its columns at :meth:`Layout.representative` of its start: each effect absent
there (its own parameters all 0) present at its typical size within its bounds
(:func:`identifiable`). The campaign kind supplies the :class:`Layout` (which columns form a
group, which groups merge near aliases, each parameter's typical size, which effects may be
absent) and its columns; the judgement is this module's, one for both kinds.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import linalg

from stiffness.elastic.effects.base import Held

#: Smallest sine between a kept column and the span of the others (documented above).
IDENTIFIABILITY_TOL = 1e-6
#: Largest sine of a near alias (module docstring): an angle of about 3 degrees.
NEAR_ALIAS_SINE = 0.05
#: An effect's parameter the data tell from the columns before it by less than this many noise
#: std per typical size, while nearly their alias, is merged into them
#: (:mod:`stiffness.calibration.identifiability`): about the 95 % normal quantile, so a merged
#: parameter's 95 % interval, given the others, would be wider than its typical size.
NEAR_ALIAS_RESOLUTION = 2.0
#: Relative difference below which two columns' unexplained parts tie in the pivoted
#: reduction (:func:`_pivoted`): the earlier column is kept.
PIVOT_TIE = 1e-9
#: Rows of a regressor per block of :func:`triangular`'s QR (its one copy: this many rows).
TRIANGULAR_BLOCK = 8192
#: Correlation of two estimates above which holding one gives its share to the other: the held
#: parameter's reason names it (:func:`confounded`; a near alias the data do not split).
ALIAS_CORRELATION = 0.9


@dataclass(frozen=True)
class Dropped:
    """A parameter left out of the fit, and why.

    Attributes
    ----------
    index
        Column of the parameter.
    reason
        ``"no effect"``, ``"merged"`` or ``"undetermined"`` (a fit of it left its 95 %
        interval wider than its physical scale: held at its nominal value by the caller,
        :func:`stiffness.calibration.diagnose.settled`, ``held`` saying why).
    merged_into
        For a merged parameter: (kept column, coefficient) pairs, largest first; the kept
        parameters absorb ``coefficient x`` this one (in their own units).
    held
        For an undetermined parameter: why, and what takes its share.
    through_held
        For a merged parameter: the columns of its combination held afterwards as
        undetermined (:meth:`Identifiability.holding`) when it has no expression over the
        parameters fitted: the combination is not fitted, it stays at its nominal value
        (FIGAROH's TALOS left arm: arm_left_4_joint placement y read "acts on the data as -504
        x arm_left_4_joint placement z + 504 x arm_left_3_joint placement z", the first
        held).
    """

    index: int
    reason: str
    merged_into: tuple[tuple[int, float], ...] = ()
    held: Held | None = None
    through_held: tuple[int, ...] = ()

    def describe(self, labels: list[str]) -> str:
        """One clause: ``no effect on the data``, ``merged: acts on the data as 1 x joint2 (SI
        units, per unit of it)`` (its column is that combination of the kept ones': the kept
        parameters absorb it, each its coefficient times it; a coefficient carries the units'
        ratio, -185 N for a torso lift's compliance, m/N, against the frame's height, m) or why
        an undetermined parameter is held (:meth:`Held.text`)."""
        if self.reason == "no effect":
            return "no effect on the data"
        if self.reason == "undetermined":
            return "" if self.held is None else self.held.text()
        big = max((abs(c) for _, c in self.merged_into), default=0.0)
        combo = " + ".join(f"{c:.3g} x {labels[i]}" for i, c in self.merged_into[:3]
                           if abs(c) >= 1e-3 * big)
        if self.through_held:
            names = ", ".join(labels[i] for i in self.through_held)
            return (f"merged into a combination ({combo}) with {names}, held at its nominal "
                    "value (the data do not determine it): not fitted, held at its nominal "
                    "value too")
        return (f"merged: acts on the data as {combo} (SI units, per unit of it)" if combo
                else "merged: absorbed as (negligible)")


@dataclass
class Identifiability:
    """The identifiable columns of a regressor and the dropped ones.

    ``factor`` and ``scales`` (set by :func:`reduce_columns`): the triangular factor of the
    scaled columns reduced and each parameter's typical size, with which :meth:`holding`
    re-expresses a merge over the parameters still fitted.
    """

    kept: list[int]
    dropped: list[Dropped]
    factor: np.ndarray | None = field(default=None, repr=False, compare=False)
    scales: np.ndarray | None = field(default=None, repr=False, compare=False)

    @classmethod
    def full(cls, p: int) -> Identifiability:
        """Every one of ``p`` columns kept."""
        return cls(list(range(p)), [])

    def holding(self, held: dict[int, Held]) -> Identifiability:
        """This reduction with the columns of ``held`` (column: why) dropped as
        ``undetermined``. A merged column whose combination holds one of them is re-expressed
        over the columns still kept (:func:`over_fitted`: its column regressed on theirs
        alone) when they carry it; else it says its combination is not fitted
        (:attr:`Dropped.through_held`)."""
        kept = [i for i in self.kept if i not in held]
        return Identifiability(kept, [self._rebased(d, held, kept) for d in self.dropped
                                      if d.index not in held]
                               + [Dropped(i, "undetermined", held=why)
                                  for i, why in held.items()], self.factor, self.scales)

    def _rebased(self, d: Dropped, held: dict[int, Held], kept: list[int]) -> Dropped:
        """``d`` once ``held`` are held and ``kept`` fitted (:meth:`holding`)."""
        through = tuple(i for i, _ in d.merged_into if i in held)
        if not through:
            return d
        if self.factor is not None and self.scales is not None:
            before = list(dict.fromkeys((*self.kept, *(i for i, _ in d.merged_into))))
            again = over_fitted(self.factor, self.scales, d.index, before, kept, through)
            if again is not None:
                return again
        return replace(d, through_held=tuple(dict.fromkeys((*d.through_held, *through))))

    def dropped_at(self, index: int) -> Dropped | None:
        """The :class:`Dropped` of column ``index``, or ``None`` when it is kept."""
        return next((d for d in self.dropped if d.index == index), None)

    def to_dict(self, labels: list[str]) -> dict:
        """JSON form: kept labels, and each dropped label with its reason, combination and
        the kept parameters an undetermined one is confounded with (:attr:`Held.
        confounded_with`, each correlation to the 3 decimals its note shows; ``labels``: every
        column's label)."""
        return {"tolerance": IDENTIFIABILITY_TOL,
                "kept": [labels[i] for i in self.kept],
                "dropped": [{"parameter": labels[d.index], "reason": d.reason,
                             "note": d.held.text() if d.held else None,
                             "confounded_with": [{"parameter": label, "correlation": round(r, 3)}
                                                 for label, r in (d.held.confounded_with
                                                                  if d.held else ())],
                             "merged_into": [{"parameter": labels[i], "coefficient": c}
                                             for i, c in d.merged_into],
                             "through_held": [labels[i] for i in d.through_held]}
                            for d in self.dropped]}


def confounded(cov: np.ndarray, index: int, others: Iterable[int], labels: list[str]
               ) -> tuple[tuple[str, float], ...]:
    """The estimates of ``others`` correlated with that of ``index`` by at least
    :data:`ALIAS_CORRELATION` in ``cov`` (a fit's covariance; indices are its rows, named by
    ``labels``), as (label, correlation) pairs, the most correlated first; none where
    ``index``'s variance is not finite and positive. Both campaign kinds name, with these,
    what a parameter the naming rules hold is not told apart from
    (:attr:`Held.confounded_with`)."""
    var = np.diag(cov)
    if not math.isfinite(var[index]) or var[index] <= 0:
        return ()
    pairs = [(int(i), float(cov[index, i] / math.sqrt(var[index] * var[i]))) for i in others
             if i != index and math.isfinite(var[i]) and var[i] > 0]
    return tuple((labels[i], r) for i, r in sorted(
        [(i, r) for i, r in pairs if abs(r) >= ALIAS_CORRELATION],
        key=lambda pair: -abs(pair[1])))


@dataclass(frozen=True)
class Layout:
    """How a fit's parameters are judged: what a campaign kind tells :func:`identifiable`.

    Attributes
    ----------
    groups
        The columns of each group, in the order they are reduced (earlier groups keep the
        directions they share with later ones).
    near_alias
        Per group: whether a column nearly aliasing the earlier groups' is merged under a
        ``resolution`` (an effect's own parameters: yes; a freed setting: no).
    scales
        (p,) each parameter's typical size (its own units): the columns handed to
        :func:`identifiable` are the regressor's times these.
    typical
        (p,) each parameter's value at its typical size within its bounds (the
        representative point's value where its effect is absent).
    effects
        Per effect that may be absent: its own columns (all 0: absent) and every column it
        sets at the representative point (its own and the settings it frees).
    keep_first
        Keep every column of the first group with an effect (:func:`reduce_columns`).
    """

    groups: list[list[int]]
    near_alias: list[bool]
    scales: np.ndarray
    typical: np.ndarray
    effects: list[tuple[list[int], list[int]]] = field(default_factory=list)
    keep_first: bool = False

    def reduce(self, a: np.ndarray, resolution: float = 0.0) -> Identifiability:
        """:func:`reduce_columns` of the scaled columns ``a`` (N, p) by this layout."""
        kept = [(g, resolution if near else 0.0)
                for g, near in zip(self.groups, self.near_alias, strict=True) if g]
        return reduce_columns(a, [g for g, _ in kept], self.scales, [f for _, f in kept],
                              keep_first=self.keep_first and bool(self.groups[0]))

    def representative(self, x: np.ndarray) -> np.ndarray:
        """``x`` with every effect absent there (its own columns all 0) at its typical size:
        its columns that are 0 set to :attr:`typical`."""
        out = np.array(x, dtype=float)
        for own, every in self.effects:
            if every and not np.any(out[own]):
                out[every] = np.where(out[every] == 0.0, self.typical[every], out[every])
        return out


def identifiable(layout: Layout, x: np.ndarray,
                 columns: Callable[[np.ndarray], np.ndarray | None],
                 resolution: float = 0.0) -> Identifiability:
    """The parameters a campaign identifies near ``x``: :meth:`Layout.reduce` of its columns
    at :meth:`Layout.representative` ``x`` (at ``x`` itself where the model cannot be
    evaluated there; every parameter kept where it cannot be evaluated at ``x`` either).

    Parameters
    ----------
    columns
        The campaign's regressor at a point, each column times its parameter's typical size
        (whitened by the noise std when ``resolution`` is given), or ``None`` where the model
        cannot be evaluated.
    resolution
        Near aliases an effect's own columns must be told from (module docstring), 0 for none.
    """
    point = layout.representative(x)
    a = columns(point) if not np.array_equal(point, x) else None
    if a is None:
        a = columns(np.asarray(x, dtype=float))
    if a is None or not np.any(a):
        return Identifiability.full(layout.scales.size)
    return layout.reduce(a, resolution)


def same_span(a: np.ndarray, first: list[int], second: list[int]) -> bool:
    """Whether the columns ``first`` and ``second`` of ``a`` span the same space: as many,
    and each of ``second`` in the span of ``first`` (sine of its angle to it below
    :data:`IDENTIFIABILITY_TOL`). Two reductions that merely keep different members of exact
    aliases fit the same model."""
    if len(first) != len(second):
        return False
    if not second:
        return True
    basis, _ = np.linalg.qr(a[:, first])
    part = a[:, second] - basis @ (basis.T @ a[:, second])
    norms = np.linalg.norm(a[:, second], axis=0)
    return bool(np.all(np.linalg.norm(part, axis=0) <= IDENTIFIABILITY_TOL * norms))


def triangular(a: np.ndarray, columns: list[int] | None = None) -> np.ndarray:
    """``R`` (min(N, k), k) of ``a[:, columns] = Q R`` (every column by default), by QR of
    blocks of :data:`TRIANGULAR_BLOCK` rows stacked under the ``R`` so far: no copy of the
    whole (N, p) ``a``. ``R`` keeps every inner product of the columns (``a^T a = R^T R``)."""
    index = np.arange(a.shape[1]) if columns is None else np.asarray(columns, dtype=int)
    return stacked_triangular((a[start:start + TRIANGULAR_BLOCK][:, index]
                               for start in range(0, a.shape[0], TRIANGULAR_BLOCK)),
                              index.size)


def stacked_triangular(blocks: Iterable[np.ndarray], k: int) -> np.ndarray:
    """``R`` (at most (k, k)) of the rows of ``blocks`` (each (rows, k)) stacked: each block's
    QR under the ``R`` so far, so only one block of rows is ever held (``A^T A = R^T R`` for
    ``A`` the blocks stacked)."""
    tri = np.zeros((0, k))
    for block in blocks:
        tri = linalg.qr(np.vstack([tri, block]), mode="r")[0][:k]
    return tri


def reduce_columns(a: np.ndarray, groups: list[list[int]], scales: np.ndarray,
                   resolution: list[float] | None = None, keep_first: bool = False
                   ) -> Identifiability:
    """Identifiable columns of ``a``, group by group (earlier groups first); see module doc.

    ``a`` holds the regressor's columns multiplied by ``scales`` (each parameter's typical
    size); merge coefficients are returned in the parameters' own units. ``resolution``
    (one per group, whitened columns only; default none) merges near aliases too. With
    ``keep_first`` every column of the first group with an effect on the data is kept (a
    fit that reports its own undetermined directions among them: the deflection baseline's
    stiffnesses, :func:`stiffness.calibration.fitting.covariance`).

    Every quantity used (column norms, the part of a column the kept ones do not explain,
    its pivoted QR, the merge coefficients) depends on ``a`` only through ``a^T a``, so the
    reduction runs on ``a``'s :func:`triangular` factor (p, p) instead of its N rows: a large
    campaign's memory is not multiplied here.
    """
    a = triangular(a)
    kept: list[int] = []
    dropped: list[Dropped] = []
    floors = resolution if resolution is not None else [0.0] * len(groups)
    for number, (group, floor) in enumerate(zip(groups, floors, strict=True)):
        norms = np.linalg.norm(a[:, group], axis=0)
        big = norms.max() if len(group) else 0.0
        candidates = [c for c, nrm in zip(group, norms, strict=True)
                      if nrm > IDENTIFIABILITY_TOL * big and nrm > 0]
        dropped += [Dropped(c, "no effect") for c in group if c not in candidates]
        if number == 0 and keep_first:
            kept += candidates
            continue
        if not candidates:
            continue
        rest = a[:, candidates]
        if kept:
            basis, _ = np.linalg.qr(a[:, kept])
            rest = rest - basis @ (basis.T @ rest)
        own = np.linalg.norm(a[:, candidates], axis=0)
        earlier = np.linalg.norm(rest, axis=0)  # the part the earlier groups do not explain
        alias = [i for i, (e, o) in enumerate(zip(earlier, own, strict=True))
                 if e < floor and e < NEAR_ALIAS_SINE * o]
        inside = [i for i in range(len(candidates)) if i not in alias]
        joined = []
        if inside:
            joined = [candidates[inside[p]] for p in _pivoted(
                rest[:, inside], IDENTIFIABILITY_TOL * own[inside])]
        kept += joined
        dropped += _merged(a, kept, [c for c in candidates if c not in joined], scales)
    return Identifiability(kept, dropped, a, np.asarray(scales, dtype=float))


def _pivoted(a: np.ndarray, floors: np.ndarray) -> list[int]:
    """The columns of ``a`` (n, m) a column-pivoted Gram-Schmidt joins, in order: each step
    joins, of the columns whose part orthogonal to those joined is at least their ``floors``
    (m,), the one with the largest part (``|R_ii|`` of a pivoted QR), the earliest among those
    within :data:`PIVOT_TIE` of it: exact aliases (equal parts in exact arithmetic) are told
    apart by their order, not by round-off, so the columns kept do not depend on how ``a``
    was computed (a full regressor or its triangular factor, rows in blocks of any size)."""
    basis = np.zeros((a.shape[0], 0))
    left = list(range(a.shape[1]))
    out: list[int] = []
    while left:
        part = a[:, left] - basis @ (basis.T @ a[:, left])
        part -= basis @ (basis.T @ part)  # twice: orthogonal to the working precision
        norms = np.linalg.norm(part, axis=0)
        able = (norms >= floors[left]) & (norms > 0.0)
        if not able.any():
            break
        pick = int(np.flatnonzero(able & (norms >= (1.0 - PIVOT_TIE) * norms[able].max()))[0])
        out.append(left.pop(pick))
        basis = np.column_stack([basis, part[:, pick] / norms[pick]])
    return out


def _merged(a: np.ndarray, kept: list[int], columns: list[int], scales: np.ndarray
            ) -> list[Dropped]:
    """Each of ``columns`` as a combination of the ``kept`` ones (parameters' own units)."""
    if not columns:
        return []
    if not kept:
        return [Dropped(c, "merged") for c in columns]
    coefs, *_ = np.linalg.lstsq(a[:, kept], a[:, columns], rcond=None)
    out = []
    for column, coef in zip(columns, coefs.T, strict=True):
        coef = coef * scales[kept] / scales[column]
        order = np.argsort(-np.abs(coef))
        pairs = tuple((kept[i], float(coef[i])) for i in order
                      if abs(coef[i]) * scales[column] > 1e-6 * scales[kept[i]])
        out.append(Dropped(column, "merged", pairs))
    return out


def over_fitted(a: np.ndarray, scales: np.ndarray, column: int, before: list[int],
                after: list[int], held: tuple[int, ...]) -> Dropped | None:
    """The merged ``column`` of the scaled columns ``a`` re-expressed over ``after`` (the
    columns still fitted once ``held``, columns of its combination over ``before``, are held
    as undetermined): its column regressed on theirs alone (the held columns projected out),
    coefficients as :func:`_merged` gives them. ``None`` (no expression over the fitted
    parameters) unless the part of it they leave beyond what ``before`` left is no larger
    than the part they leave of a held column (both at their typical sizes: the data do not
    determine that one, so neither this part) and its sine to their span is below
    :data:`NEAR_ALIAS_SINE` (nearly in it, as a near alias merged under a resolution)."""
    if not after:
        return None
    c = a[:, column]
    left = _unexplained(a[:, after], c)
    extra = math.sqrt(max(left ** 2 - _unexplained(a[:, before], c) ** 2, 0.0))
    limit = max(_unexplained(a[:, after], a[:, h]) for h in held)
    if extra > (1.0 + PIVOT_TIE) * limit or left >= NEAR_ALIAS_SINE * np.linalg.norm(c):
        return None
    return _merged(a, after, [column], scales)[0]


def _unexplained(basis: np.ndarray, column: np.ndarray) -> float:
    """Norm of the part of ``column`` the columns ``basis`` do not explain (least squares)."""
    coef, *_ = np.linalg.lstsq(basis, column, rcond=None)
    return float(np.linalg.norm(column - basis @ coef))
