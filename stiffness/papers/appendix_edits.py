"""Edits of the printed Appendix I terms: the smallest correction that explains a mismatch.

An :class:`Edit` changes one printed term of one element (flip its sign, drop it, swap its
length symbol, a trigonometric function or an angle) or adds a missing monomial.
:func:`explain_element` searches single edits, then pairs, for one that makes an element match a
reference to round-off; :func:`apply_edits` returns the corrected expressions. The printed
transcription (:mod:`stiffness.papers.appendix`) is never modified.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from stiffness.papers.appendix import ANGLE_SYMBOLS, APPENDIX_TERMS, LENGTH_SYMBOLS, Term
from stiffness.papers.appendix_eval import TermsByElement, terms_values

__all__ = [
    "ROUND_OFF_REL",
    "Edit",
    "apply_edits",
    "edit_delta",
    "explain_element",
]

#: Relative agreement (to the largest element at the pose) accepted as round-off.
ROUND_OFF_REL = 1e-9


# --------------------------------------------------------------------------------------------
# Edits: explaining a disagreeing element
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Edit:
    """One edit of a printed element.

    Attributes
    ----------
    element : str
        ``"J11".."J33"``.
    kind : str
        ``"sign"`` (flip a term's sign), ``"drop"``, ``"length"`` (swap the length symbol),
        ``"function"`` (cos <-> sin of one factor), ``"argument"`` (another angle in one
        factor) or ``"add"`` (a missing monomial).
    index : int or None
        Position of the edited term in the printed element (None for ``add``).
    old : Term or None
        The printed term (None for ``add``).
    new : Term or None
        The replacement or added term (None for ``drop``).
    """

    element: str
    kind: str
    index: int | None
    old: Term | None
    new: Term | None

    def describe(self) -> str:
        """One sentence, e.g. ``printed term '- D4 cos(t1) cos(t3)' has the wrong sign``."""
        if self.kind == "sign":
            return f"printed term '{self.old}' has the wrong sign (should be '{self.new}')"
        if self.kind == "drop":
            return f"printed term '{self.old}' should not be there"
        if self.kind == "add":
            return f"term '{self.new}' is missing"
        what = {"length": "length symbol", "function": "trigonometric function",
                "argument": "angle"}[self.kind]
        return f"printed term '{self.old}' has the wrong {what} (should be '{self.new}')"

    def as_dict(self) -> dict:
        """JSON-ready description."""
        return {"element": self.element, "kind": self.kind, "index": self.index,
                "printed": None if self.old is None else str(self.old),
                "corrected": None if self.new is None else str(self.new),
                "text": self.describe()}


def apply_edits(terms: TermsByElement, edits: Sequence[Edit]) -> dict[str, tuple[Term, ...]]:
    """A copy of ``terms`` with the edits applied (indices refer to the unedited element).

    Parameters
    ----------
    terms : Mapping[str, Sequence[Term]]
        Element expressions.
    edits : Sequence[Edit]
        Edits (at most one per term, any number of additions).

    Returns
    -------
    dict[str, tuple[Term, ...]]
        Edited expressions.
    """
    out = {name: list(ts) for name, ts in terms.items()}
    drops: dict[str, set[int]] = {}
    for e in edits:
        if e.kind == "add":
            assert e.new is not None  # an addition has its term and no index
            out[e.element].append(e.new)
            continue
        assert e.index is not None  # the other edits are of a printed term
        if e.kind == "drop":
            drops.setdefault(e.element, set()).add(e.index)
        else:
            assert e.new is not None  # and all but a drop replace it
            out[e.element][e.index] = e.new
    for name, idx in drops.items():
        out[name] = [t for i, t in enumerate(out[name]) if i not in idx]
    return {name: tuple(ts) for name, ts in out.items()}


def _monomial_dictionary(terms: TermsByElement, lengths: Mapping[str, float]) -> list[Term]:
    """Candidate missing monomials: every printed trigonometric product (and its t1-rotated
    twin, cos t1 <-> sin t1) with every non-zero length symbol, both signs."""
    shapes: set[tuple[tuple[str, str], ...]] = set()
    for ts in terms.values():
        for term in ts:
            shapes.add(term.factors)
            shapes.add(tuple((("sin" if f == "cos" else "cos"), a) if a == "t1" else (f, a)
                             for f, a in term.factors))
    symbols = [s for s in LENGTH_SYMBOLS if lengths.get(s, 0.0) != 0.0]
    return [Term(sign, sym, factors) for factors in sorted(shapes) for sym in symbols
            for sign in (1, -1)]


def _single_edits(name: str, terms: TermsByElement, lengths: Mapping[str, float]) -> list[Edit]:
    """Every single edit of element ``name``, in the order sign, length, drop, function,
    argument, add."""
    edits: list[Edit] = []
    printed = list(terms[name])
    for i, term in enumerate(printed):
        edits.append(Edit(name, "sign", i, term, Term(-term.sign, term.length, term.factors)))
    for i, term in enumerate(printed):
        for sym in LENGTH_SYMBOLS:
            if sym != term.length:
                edits.append(Edit(name, "length", i, term, Term(term.sign, sym, term.factors)))
    for i, term in enumerate(printed):
        edits.append(Edit(name, "drop", i, term, None))
    for i, term in enumerate(printed):
        for j, (func, arg) in enumerate(term.factors):
            other = "sin" if func == "cos" else "cos"
            factors = term.factors[:j] + ((other, arg),) + term.factors[j + 1:]
            edits.append(Edit(name, "function", i, term, Term(term.sign, term.length, factors)))
    for i, term in enumerate(printed):
        for j, (func, arg) in enumerate(term.factors):
            for new_arg in ANGLE_SYMBOLS:
                if new_arg != arg:
                    factors = term.factors[:j] + ((func, new_arg),) + term.factors[j + 1:]
                    edits.append(Edit(name, "argument", i, term,
                                      Term(term.sign, term.length, factors)))
    present = {(t.sign, t.length, t.factors) for t in printed}
    for term in _monomial_dictionary(terms, lengths):
        if (term.sign, term.length, term.factors) not in present:
            edits.append(Edit(name, "add", None, None, term))
    return edits


def edit_delta(edit: Edit, t: np.ndarray, lengths: Mapping[str, float]) -> np.ndarray:
    """Change of the element's value made by one edit (new term minus old term).

    Parameters
    ----------
    edit : Edit
        The edit.
    t : np.ndarray, shape (P, 6)
        Appendix angles (rad).
    lengths : Mapping[str, float]
        Length symbols (mm).

    Returns
    -------
    np.ndarray, shape (P,)
        ``new - old`` at every pose (mm/rad).
    """
    zero = np.zeros(len(t))
    new = terms_values([edit.new], t, lengths) if edit.new is not None else zero
    old = terms_values([edit.old], t, lengths) if edit.old is not None else zero
    return new - old


def explain_element(
    name: str,
    target: np.ndarray,
    t: np.ndarray,
    lengths: Mapping[str, float],
    terms: TermsByElement = APPENDIX_TERMS,
    scale: np.ndarray | None = None,
    rel_tol: float = ROUND_OFF_REL,
    max_edits: int = 2,
) -> list[tuple[Edit, ...]]:
    """Smallest edits of a printed element that make it match a reference to round-off.

    Single edits are tried first (sign flips, length-symbol swaps, dropped terms, cos/sin
    swaps, angle swaps, added monomials), then pairs of edits on different terms. An
    explanation is accepted when the edited element matches ``target`` within
    ``rel_tol * scale`` at every pose.

    Parameters
    ----------
    name : str
        Element, ``"J11".."J33"``.
    target : np.ndarray, shape (P,)
        Reference values (mm/rad) in the appendix's convention.
    t : np.ndarray, shape (P, 6)
        Appendix angles (rad).
    lengths : Mapping[str, float]
        Length symbols (mm).
    terms : Mapping[str, Sequence[Term]]
        Element expressions to edit (default: as printed).
    scale : np.ndarray, shape (P,), optional
        Per-pose scale of the tolerance (default: ``max |target|``).
    rel_tol : float
        Relative tolerance.
    max_edits : int
        1 or 2.

    Returns
    -------
    list of tuple of Edit
        Accepted explanations, smallest first (empty if none).
    """
    t = np.atleast_2d(np.asarray(t, dtype=float))
    target = np.asarray(target, dtype=float)
    if scale is None:
        scale = np.full(target.shape, max(float(np.abs(target).max()), 1e-300))
    tol = rel_tol * np.asarray(scale)
    resid = (target - terms_values(terms[name], t, lengths)) / tol
    if np.all(np.abs(resid) <= 1.0):
        return [()]
    edits = _single_edits(name, terms, lengths)
    deltas = np.array([edit_delta(e, t, lengths) for e in edits]) / tol[None, :]
    err1 = np.abs(resid[None, :] - deltas).max(axis=1)
    singles: list[tuple[Edit, ...]] = [(e,) for e, err in zip(edits, err1, strict=True)
                                       if err <= 1.0]
    if singles or max_edits < 2:
        return singles
    # pairs: screen with L2 norms (Gram matrix), then verify in the max norm
    n_pose = resid.shape[0]
    gram = deltas @ deltas.T
    rd = deltas @ resid
    sq = resid @ resid - 2.0 * (rd[:, None] + rd[None, :]) + (
        np.diag(gram)[:, None] + np.diag(gram)[None, :] + 2.0 * gram)
    ii, jj = np.nonzero(np.triu(sq <= n_pose * 4.0, k=1))
    pairs: list[tuple[Edit, ...]] = []
    for i, j in zip(ii, jj, strict=True):
        a, b = edits[i], edits[j]
        if a.index is not None and a.index == b.index:
            continue
        if np.abs(resid - deltas[i] - deltas[j]).max() <= 1.0:
            pairs.append((a, b))
    return pairs
