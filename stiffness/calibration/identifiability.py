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
in the parameters' own units). A left-out parameter is held at its start and reported as
such, never as a value the data gave.

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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg

#: Smallest sine between a kept column and the span of the others (documented above).
IDENTIFIABILITY_TOL = 1e-6
#: Largest sine of a near alias (module docstring): an angle of about 3 degrees.
NEAR_ALIAS_SINE = 0.05


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
        :func:`stiffness.calibration.diagnose.settled`, ``note`` saying so).
    merged_into
        For a merged parameter: (kept column, coefficient) pairs, largest first; the kept
        parameters absorb ``coefficient x`` this one (in their own units).
    note
        For an undetermined parameter: why, in words.
    """

    index: int
    reason: str
    merged_into: tuple[tuple[int, float], ...] = ()
    note: str = ""

    def describe(self, labels: list[str]) -> str:
        """One clause: ``no effect on the data``, ``merged: absorbed as 1 x joint2`` or the
        note of an undetermined parameter."""
        if self.reason == "no effect":
            return "no effect on the data"
        if self.reason == "undetermined":
            return self.note
        big = max((abs(c) for _, c in self.merged_into), default=0.0)
        combo = " + ".join(f"{c:.3g} x {labels[i]}" for i, c in self.merged_into[:3]
                           if abs(c) >= 1e-3 * big)
        return f"merged: absorbed as {combo or '(negligible)'}"


@dataclass
class Identifiability:
    """The identifiable columns of a regressor and the dropped ones."""

    kept: list[int]
    dropped: list[Dropped]

    @classmethod
    def full(cls, p: int) -> Identifiability:
        """Every one of ``p`` columns kept."""
        return cls(list(range(p)), [])

    def holding(self, held: dict[int, str]) -> Identifiability:
        """This reduction with the columns of ``held`` (column: why) dropped as
        ``undetermined``."""
        return Identifiability([i for i in self.kept if i not in held],
                               [d for d in self.dropped if d.index not in held]
                               + [Dropped(i, "undetermined", note=why)
                                  for i, why in held.items()])

    def dropped_at(self, index: int) -> Dropped | None:
        """The :class:`Dropped` of column ``index``, or ``None`` when it is kept."""
        return next((d for d in self.dropped if d.index == index), None)

    def to_dict(self, labels: list[str]) -> dict:
        """JSON form: kept labels, and each dropped label with its reason and combination
        (``labels``: every column's label)."""
        return {"tolerance": IDENTIFIABILITY_TOL,
                "kept": [labels[i] for i in self.kept],
                "dropped": [{"parameter": labels[d.index], "reason": d.reason,
                             "note": d.note or None,
                             "merged_into": [{"parameter": labels[i], "coefficient": c}
                                             for i, c in d.merged_into]}
                            for d in self.dropped]}


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
    """
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
            _, r, piv = linalg.qr(rest[:, inside], mode="economic", pivoting=True)
            joined = [candidates[inside[p]] for p, d in zip(piv, np.abs(np.diag(r)),
                                                            strict=False)
                      if d >= IDENTIFIABILITY_TOL * own[inside[p]]]
        kept += joined
        dropped += _merged(a, kept, [c for c in candidates if c not in joined], scales)
    return Identifiability(kept, dropped)


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
