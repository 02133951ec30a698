"""Evaluating Appendix I element expressions, as printed or edited, at many poses.

The element expressions of :mod:`stiffness.papers.appendix` (or edited copies, see
:mod:`stiffness.papers.appendix_edits`) are sums of :class:`~stiffness.papers.appendix.Term`. This
module
evaluates them vectorized over poses, for real or complex angles: the value of one element, the
3x3 Jacobian, K_C by complex-step differentiation, and the model-free integrability check of a
set of expressions. It knows nothing of Pinocchio or of angle conventions: the angles are the
appendix's ``t1..t6`` and the lengths its symbols, in mm.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from stiffness.papers.appendix import APPENDIX_TERMS, ELEMENT_NAMES, LENGTH_SYMBOLS, Term

__all__ = [
    "TermsByElement",
    "integrability_violations",
    "jacobian_from_terms",
    "kc_from_terms",
    "terms_values",
]

#: Element expressions by name, ``"J11".."J33"`` -> terms.
TermsByElement = Mapping[str, Sequence[Term]]

_COMPLEX_STEP = 1e-30


# --------------------------------------------------------------------------------------------
# Evaluating printed (or edited) terms, vectorized over poses
# --------------------------------------------------------------------------------------------


def terms_values(terms: Sequence[Term], t: np.ndarray, lengths: Mapping[str, float]) -> np.ndarray:
    """Sum of a sequence of terms at many poses.

    Parameters
    ----------
    terms : Sequence[Term]
        Terms of one element (or any subset of them).
    t : np.ndarray, shape (P, 6)
        Appendix angles t1..t6 (rad), real or complex.
    lengths : Mapping[str, float]
        Length symbols (mm); missing ones are 0.

    Returns
    -------
    np.ndarray, shape (P,)
        The sum at every pose, with the dtype of ``t``.
    """
    angles = {f"t{i + 1}": t[:, i] for i in range(6)}
    out = np.zeros(t.shape[0], dtype=t.dtype)
    for term in terms:
        out = out + term.value(angles, lengths)
    return out


def jacobian_from_terms(
    terms: TermsByElement, t: np.ndarray, lengths: Mapping[str, float]
) -> np.ndarray:
    """3x3 Jacobians of a set of element expressions at many poses.

    Parameters
    ----------
    terms : Mapping[str, Sequence[Term]]
        Terms of ``"J11".."J33"`` (e.g. :data:`stiffness.papers.appendix.APPENDIX_TERMS`).
    t : np.ndarray, shape (P, 6)
        Appendix angles t1..t6 (rad), real or complex.
    lengths : Mapping[str, float]
        Length symbols (mm); missing ones are 0.

    Returns
    -------
    np.ndarray, shape (P, 3, 3)
        ``J[p, r, c]`` in mm/rad.
    """
    t = np.atleast_2d(np.asarray(t))
    t = t.astype(np.result_type(t.dtype, np.float64))
    jac = np.zeros((t.shape[0], 3, 3), dtype=t.dtype)
    for name in ELEMENT_NAMES:
        r, c = int(name[1]) - 1, int(name[2]) - 1
        jac[:, r, c] = terms_values(terms[name], t, lengths)
    return jac


def kc_from_terms(
    terms: TermsByElement, t: np.ndarray, force: np.ndarray, lengths: Mapping[str, float]
) -> np.ndarray:
    """K_C (A&S eq. 9) of a set of element expressions, by complex-step differentiation.

    ``K_C[p, i, j] = sum_k F_k dJ[k, i] / dt_j`` (j over t1..t3), as
    :func:`stiffness.papers.appendix.appendix_kc`, vectorized over poses.

    Parameters
    ----------
    terms : Mapping[str, Sequence[Term]]
        Element expressions.
    t : np.ndarray, shape (P, 6)
        Real appendix angles (rad).
    force : np.ndarray, shape (3,)
        Force (N) in the appendix's base axes.
    lengths : Mapping[str, float]
        Length symbols (mm).

    Returns
    -------
    np.ndarray, shape (P, 3, 3)
        K_C in N.mm/rad.
    """
    t = np.atleast_2d(np.asarray(t, dtype=float))
    force = np.asarray(force, dtype=float)
    kc = np.zeros((t.shape[0], 3, 3))
    for j in range(3):
        tc = t.astype(np.complex128)
        tc[:, j] += 1j * _COMPLEX_STEP
        dj = jacobian_from_terms(terms, tc, lengths).imag / _COMPLEX_STEP
        kc[:, :, j] = np.einsum("k,pki->pi", force, dj)
    return kc


# --------------------------------------------------------------------------------------------
# Model-free integrability check
# --------------------------------------------------------------------------------------------


def integrability_violations(
    terms: TermsByElement = APPENDIX_TERMS, n_poses: int = 16, seed: int = 1
) -> list[dict]:
    """Conditions a position Jacobian must satisfy, checked symbol by symbol at random angles.

    For every length symbol alone (value 1): ``dJ[:, i]/dt_j = dJ[:, j]/dt_i`` (the columns
    are derivatives of one position) and ``dJ[:, c]/dt1 = z x J[:, c]`` (t1 turns about the
    base z axis). The expressions are linear in the lengths, so this detects inconsistent
    terms whatever the lengths' values, including those Table I sets to zero.

    Parameters
    ----------
    terms : Mapping[str, Sequence[Term]]
        Element expressions.
    n_poses : int
        Number of random angle sets.
    seed : int
        Seed.

    Returns
    -------
    list of dict
        ``{"symbol", "condition", "max_abs"}`` for each violated condition (per unit length).
    """
    rng = np.random.default_rng(seed)
    t = rng.uniform(-np.pi, np.pi, (n_poses, 6))
    out = []
    for sym in LENGTH_SYMBOLS:
        lengths = {sym: 1.0}
        jac = jacobian_from_terms(terms, t, lengths)
        d = []
        for j in range(3):
            tc = t.astype(np.complex128)
            tc[:, j] += 1j * _COMPLEX_STEP
            d.append(jacobian_from_terms(terms, tc, lengths).imag / _COMPLEX_STEP)
        checks = {}
        for i, j in ((0, 1), (0, 2), (1, 2)):
            checks[f"dJ[:,{i + 1}]/dt{j + 1} = dJ[:,{j + 1}]/dt{i + 1}"] = d[j][:, :, i] - d[i][
                :, :, j]
        for c in range(3):
            rot = np.stack([-jac[:, 1, c], jac[:, 0, c], np.zeros(n_poses)], axis=1)
            checks[f"dJ[:,{c + 1}]/dt1 = z x J[:,{c + 1}]"] = d[0][:, :, c] - rot
        for cond, diff in checks.items():
            err = float(np.abs(diff).max())
            if err > 1e-9:
                out.append({"symbol": sym, "condition": cond, "max_abs": err})
    return out
