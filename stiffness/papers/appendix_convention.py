"""The angle convention and lengths of Appendix I (A&S 2005) relative to Table I and Pinocchio.

The appendix's Jacobian is written in its own angles ``t1..t6``, base axes and length symbols
``L1..L6``, ``D1..D6``. This module holds

* the printed-angle convention of the shipped SK120 model (:func:`printed_convention`) and the
  natural Table I assignment of the length symbols (:func:`table1_lengths_mm`);
* :class:`AppendixConvention`, a candidate map ``t_i = o_i + s_i theta_i`` (``t3`` optionally
  ``+ k theta2``) with a base reflection ``diag(1, f2, f3)``;
* the exhaustive branch-and-bound search of that map (:func:`find_convention`), which scores
  every candidate by the number of Jacobian elements that agree exactly with Pinocchio's.
"""

from __future__ import annotations

import itertools
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from stiffness.errors import StiffnessError
from stiffness.papers.appendix import APPENDIX_TERMS, ELEMENT_NAMES, Term
from stiffness.papers.appendix_eval import TermsByElement, terms_values
from stiffness.papers.sk120 import FIXTURE_A_M, FIXTURE_B_M, AngleConvention, DHRow, read_table1
from stiffness.robot.sources import robots_directory

__all__ = [
    "SEARCH_POSES",
    "SEARCH_REL",
    "AppendixConvention",
    "ConventionSearch",
    "MatchTables",
    "find_convention",
    "printed_convention",
    "table1_lengths_mm",
    "wrap_deg",
]

#: Relative tolerance of the convention search (exact matches only; typos give O(1)).
SEARCH_REL = 1e-6
#: Number of general-wrist poses used by the convention search.
SEARCH_POSES = 8
_OFFSETS_DEG = (0.0, 90.0, 180.0, -90.0)
_SIGNS = (1, -1)
_T3_COUPLINGS = (0, 1, -1)
_BASE_FLIPS = tuple(itertools.product((1, -1), (1, -1)))  # (f2, f3); f1 = +1
_MAX_EQUIVALENT = 32


# --------------------------------------------------------------------------------------------
# Conventions and lengths
# --------------------------------------------------------------------------------------------


def printed_convention() -> AngleConvention:
    """The printed-angle -> Table I DH convention of the shipped SK120 model.

    Returns
    -------
    AngleConvention
        ``theta_DH = offset + sign * q`` (deg offsets), as chosen in
        ``robots/sk120/convention_fit.json``.
    """
    fit = json.loads((robots_directory() / "sk120" / "convention_fit.json").read_text())
    chosen = fit["chosen"]
    return AngleConvention(tuple(int(s) for s in chosen["signs"]),
                           tuple(float(o) for o in chosen["offsets_deg"]))


def table1_lengths_mm(
    table1: Mapping[str, DHRow] | None = None,
    fixture_mm: tuple[float, float] | None = None,
) -> dict[str, float]:
    """Appendix length symbols from Table I (the natural assignment), in mm.

    ``L_i`` / ``D_i`` are the ``a`` / ``d`` of Table I row ``i``; ``L2`` is the five-bar's
    lower arm (row 2b); the L-shaped fixture (``a`` along the tool axis z6, ``b`` along x6)
    extends row 6: ``D6 = d6 + a``, ``L6 = a6 + b``. ``D2`` (a lateral offset of the lower
    arm) has no Table I row and is 0.

    Parameters
    ----------
    table1 : Mapping[str, DHRow], optional
        Table I rows in SI (default: the shipped ``table1_dh.csv``).
    fixture_mm : tuple of float, optional
        Fixture ``(a, b)`` in mm (default: the paper's 112.65, 205.32).

    Returns
    -------
    dict[str, float]
        Value (mm) of every symbol ``L1..L6``, ``D1..D6``.
    """
    if table1 is None:
        table1 = read_table1(robots_directory() / "sk120" / "table1_dh.csv")
    a_fix, b_fix = fixture_mm if fixture_mm is not None else (FIXTURE_A_M * 1e3, FIXTURE_B_M * 1e3)
    mm = 1e3
    return {
        "L1": table1["1"].a * mm, "L2": table1["2b"].a * mm, "L3": table1["3"].a * mm,
        "L4": table1["4"].a * mm, "L5": table1["5"].a * mm, "L6": table1["6"].a * mm + b_fix,
        "D1": table1["1"].d * mm, "D2": 0.0, "D3": table1["3"].d * mm,
        "D4": table1["4"].d * mm, "D5": table1["5"].d * mm, "D6": table1["6"].d * mm + a_fix,
    }


@dataclass(frozen=True)
class AppendixConvention:
    """The appendix's angles and base frame relative to Table I's DH angles and Pinocchio's base.

    ``t_i = offset_i + sign_i * theta_i`` for ``i != 3`` and
    ``t3 = offset_3 + sign_3 * theta_3 + t3_coupling * theta_2`` (``theta`` = Table I DH
    angles; coupling 0 means the appendix's ``t3`` is absolute, like Table I's). Positions
    are ``x_app = diag(base_flips) x_pinocchio`` (plus a constant).

    Attributes
    ----------
    offsets_deg : tuple of float
        ``offset_1..offset_6`` (deg).
    signs : tuple of int
        ``sign_1..sign_6``.
    t3_coupling : int
        Coefficient ``k`` of ``theta_2`` in ``t3``.
    base_flips : tuple of int
        Diagonal of the base reflection (first entry always +1).
    """

    offsets_deg: tuple[float, ...]
    signs: tuple[int, ...]
    t3_coupling: int = 0
    base_flips: tuple[int, int, int] = (1, 1, 1)

    def to_appendix(self, theta_dh: np.ndarray) -> np.ndarray:
        """Appendix angles (rad), shape (..., 6), from Table I DH angles (rad)."""
        theta_dh = np.asarray(theta_dh, dtype=float)
        t = np.deg2rad(self.offsets_deg) + np.asarray(self.signs) * theta_dh
        t[..., 2] = t[..., 2] + self.t3_coupling * theta_dh[..., 1]
        return t

    def dt_dtheta(self) -> np.ndarray:
        """Chain-rule matrix ``T = dt/dtheta`` (3x3) of the first three angles."""
        t = np.diag(np.asarray(self.signs[:3], dtype=float))
        t[2, 1] = self.t3_coupling
        return t

    def rotation(self) -> np.ndarray:
        """Base reflection ``R`` (3x3): ``x_app = R x_pinocchio``."""
        return np.diag(np.asarray(self.base_flips, dtype=float))

    def cost(self) -> int:
        """Number of departures from the identity map (for picking among equivalent ones)."""
        return (sum(o != 0.0 for o in self.offsets_deg) + sum(s < 0 for s in self.signs)
                + 4 * abs(self.t3_coupling) + 4 * sum(f < 0 for f in self.base_flips))

    def in_printed_angles(self, printed: AngleConvention) -> list[tuple[float, int, dict]]:
        """The same map in the paper's printed angles ``q`` (deg offsets).

        Returns
        -------
        list of (float, int, dict)
            Per joint: offset (deg, wrapped to (-180, 180]), sign of ``q_i``, and extra
            coefficients on other printed angles (only ``t3`` can have one, on ``q2``).
        """
        out = []
        for i in range(6):
            off = self.offsets_deg[i] + self.signs[i] * printed.offsets_deg[i]
            extra = {}
            if i == 2 and self.t3_coupling:
                off += self.t3_coupling * printed.offsets_deg[1]
                extra = {"q2": self.t3_coupling * printed.signs[1]}
            out.append((wrap_deg(off), self.signs[i] * printed.signs[i], extra))
        return out

    def describe(self, printed: AngleConvention | None = None) -> str:
        """Words: ``t1 = theta1_DH; t2 = theta2_DH + 180 deg; ...`` (and in printed angles)."""
        dh = "; ".join(
            _affine_text(f"t{i + 1}", self.offsets_deg[i], {f"theta{i + 1}_DH": self.signs[i],
                         **({"theta2_DH": self.t3_coupling} if i == 2 and self.t3_coupling
                            else {})})
            for i in range(6)
        )
        text = f"Table I DH: {dh}"
        if printed is not None:
            pr = "; ".join(
                _affine_text(f"t{i + 1}", off, {f"q{i + 1}": sign, **extra})
                for i, (off, sign, extra) in enumerate(self.in_printed_angles(printed))
            )
            text += f". Printed angles: {pr}"
        flips = self.base_flips
        if flips == (1, 1, 1):
            text += ". Base frame: the same as Table I's frame 0 (x, y, z unchanged)"
        else:
            axes = ", ".join(a for a, f in zip("xyz", flips, strict=True) if f < 0)
            text += f". Base frame: Table I's frame 0 with {axes} reversed"
        return text

    def as_dict(self, printed: AngleConvention | None = None) -> dict:
        """JSON-ready numbers of the map."""
        out = {
            "offsets_deg_vs_table1_dh": [float(o) for o in self.offsets_deg],
            "signs_vs_table1_dh": [int(s) for s in self.signs],
            "t3_coupling_on_theta2": int(self.t3_coupling),
            "base_axis_signs": [int(f) for f in self.base_flips],
        }
        if printed is not None:
            rows = self.in_printed_angles(printed)
            out["offsets_deg_vs_printed"] = [float(o) for o, _, _ in rows]
            out["signs_vs_printed"] = [int(s) for _, s, _ in rows]
        return out


def wrap_deg(angle: float) -> float:
    """An angle (deg) wrapped to (-180, 180], without negative zero.

    Parameters
    ----------
    angle : float
        Angle (deg).

    Returns
    -------
    float
        The same direction in (-180, 180].
    """
    wrapped = (angle + 180.0) % 360.0 - 180.0
    return 180.0 if wrapped == -180.0 else wrapped + 0.0


def _affine_text(lhs: str, offset: float, coefs: Mapping[str, int]) -> str:
    """``lhs = a - b + 90 deg`` from unit coefficients and an offset (deg)."""
    parts: list[str] = []
    for name, c in coefs.items():
        if c == 0:
            continue
        sign = "-" if c < 0 else "+"
        parts.append(f"{sign} {name}" if parts or c < 0 else name)
    text = " ".join(parts)
    if text.startswith("- "):
        text = "-" + text[2:]
    off = wrap_deg(offset)
    if off:
        text += f" {'+' if off > 0 else '-'} {abs(off):g} deg"
    return f"{lhs} = {text}"


# --------------------------------------------------------------------------------------------
# Convention search
# --------------------------------------------------------------------------------------------


def _options() -> tuple[list[tuple[float, int]], list[tuple[float, int, int]]]:
    """Candidate ``(offset, sign)`` per angle, and ``(offset, sign, coupling)`` for ``t3``."""
    single = [(o, s) for o in _OFFSETS_DEG for s in _SIGNS]
    third = [(o, s, k) for k in _T3_COUPLINGS for o in _OFFSETS_DEG for s in _SIGNS]
    return single, third


def _angle_options(i: int, single: Sequence[tuple[float, int]],
                   third: Sequence[tuple[float, int, int]]) -> Sequence[tuple[float, int, int]]:
    """The candidates of angle ``i`` (0-based) as ``(offset, sign, coupling)``: ``third`` for
    ``t3``, else ``single`` with coupling 0 (unused)."""
    return third if i == 2 else [(o, s, 0) for o, s in single]


@dataclass
class ConventionSearch:
    """Result of :func:`find_convention`.

    Attributes
    ----------
    best : AppendixConvention
        The simplest of the conventions with the most matching elements.
    n_matching : int
        Number of elements (of 9, or of 7 with ``full=False``) that match exactly under it.
    matching : list of str
        Those elements.
    equivalent : list of AppendixConvention
        Conventions with the same number of matching elements, simplest first (at most
        ``_MAX_EQUIVALENT``).
    n_equivalent : int
        Number of such conventions.
    n_candidates : int
        Size of the search space.
    """

    best: AppendixConvention
    n_matching: int
    matching: list[str]
    equivalent: list[AppendixConvention]
    n_equivalent: int
    n_candidates: int


class MatchTables:
    """Exact-match tables of the convention search at fixed poses, shared between searches.

    For each element, a boolean table over the candidate conventions (broadcast over the axes
    ``a1..a6, f`` it depends on): whether the element agrees exactly with Pinocchio's at every
    pose. A table depends on the poses and on the element's own terms and length values only,
    so searches at the same poses that differ in other lengths (the fixture placements of
    :mod:`stiffness.papers.crosscheck`) compute each table once.

    Parameters
    ----------
    theta_dh : np.ndarray, shape (P, 6)
        Table I DH angles (rad) of the poses.
    jac_theta : np.ndarray, shape (P, 3, 3)
        Pinocchio Jacobian w.r.t. the DH angles theta1..theta3 (mm/rad), Pinocchio axes.
    """

    _ND = 8  # axes: a1, a2, a3, a4, a5, a6, f, pose

    def __init__(self, theta_dh: np.ndarray, jac_theta: np.ndarray) -> None:
        single, third = _options()
        self.theta_dh, self.jac_theta = theta_dh, jac_theta
        self.n_pose = theta_dh.shape[0]
        scale = np.abs(jac_theta).max(axis=(1, 2))  # (P,)
        self.tol = SEARCH_REL * scale
        trig: dict[str, np.ndarray] = {}
        for i in range(6):
            opts = _angle_options(i, single, third)
            ang = np.array([np.deg2rad(opt[0]) + opt[1] * theta_dh[:, i]
                            + (opt[2] * theta_dh[:, 1] if i == 2 else 0.0) for opt in opts])
            trig[f"cos(t{i + 1})"] = self._axis_array(np.cos(ang), i)
            trig[f"sin(t{i + 1})"] = self._axis_array(np.sin(ang), i)
        c2, s2, c3, s3 = (trig[k] for k in ("cos(t2)", "sin(t2)", "cos(t3)", "sin(t3)"))
        trig["cos(t2-t3)"] = c2 * c3 + s2 * s3
        trig["sin(t2-t3)"] = s2 * c3 - c2 * s3
        self._trig = trig
        n_pose = self.n_pose
        self._sign1 = self._axis_array(np.array([[s] * n_pose for _, s in single], dtype=float),
                                       0)
        self._sign2 = self._axis_array(np.array([[s] * n_pose for _, s in single], dtype=float),
                                       1)
        self._sign3 = self._axis_array(np.array([[s] * n_pose for _, s, _ in third],
                                                dtype=float), 2)
        self._coup3 = self._axis_array(np.array([[k] * n_pose for _, _, k in third],
                                                dtype=float), 2)
        self._flips = [np.ones(len(_BASE_FLIPS)),
                       np.array([f[0] for f in _BASE_FLIPS], dtype=float),
                       np.array([f[1] for f in _BASE_FLIPS], dtype=float)]
        self._tol_b = self.tol.reshape([1] * (self._ND - 1) + [n_pose])
        self._tables: dict[tuple, np.ndarray] = {}

    def _axis_array(self, values: np.ndarray, axis: int) -> np.ndarray:
        shape = [1] * self._ND
        shape[axis] = values.shape[0]
        shape[-1] = self.n_pose
        return values.reshape(shape)

    def _element_values(self, terms: Sequence[Term], lengths: Mapping[str, float]
                        ) -> np.ndarray:
        total = np.zeros([1] * self._ND)
        for term in terms:
            value = term.sign * lengths.get(term.length, 0.0)
            if value == 0.0:
                continue
            prod = np.full([1] * self._ND, value)
            for func, arg in term.factors:
                prod = prod * self._trig[f"{func}({arg})"]
            total = total + prod
        return total

    def _pin_values(self, r: int, c: int) -> np.ndarray:
        nd, n_pose = self._ND, self.n_pose
        f = self._flips[r].reshape([1] * 6 + [len(_BASE_FLIPS), 1])
        jr = [self.jac_theta[:, r, k].reshape([1] * (nd - 1) + [n_pose]) for k in range(3)]
        if c == 0:
            return f * self._sign1 * jr[0]
        if c == 1:
            return f * self._sign2 * (jr[1] - self._coup3 * self._sign3 * jr[2])
        return f * self._sign3 * jr[2]

    def match(self, name: str, terms: Sequence[Term], lengths: Mapping[str, float]
              ) -> np.ndarray:
        """Exact-match table of element ``name`` written as ``terms`` with ``lengths`` (mm)."""
        key = (name, tuple(terms), tuple(lengths.get(t.length, 0.0) for t in terms))
        if key not in self._tables:
            r, c = int(name[1]) - 1, int(name[2]) - 1
            diff = np.abs(self._element_values(terms, lengths) - self._pin_values(r, c))
            self._tables[key] = np.all(diff <= self._tol_b, axis=-1)
        return self._tables[key]


def find_convention(
    theta_dh: np.ndarray, jac_theta: np.ndarray, lengths: Mapping[str, float],
    terms: TermsByElement = APPENDIX_TERMS,
    full: bool = True,
    tables: MatchTables | None = None,
) -> ConventionSearch:
    """Exhaustive search of the appendix's angle convention and base frame.

    Every map ``t_i = o_i + s_i theta_i`` (``o`` in {0, 90, 180, -90} deg, ``s = +-1``),
    ``t3 += k theta2`` (``k`` in {0, 1, -1}), with base reflection ``diag(1, f2, f3)``
    (8^5 * 24 * 4 = 3.1e6 candidates) is scored by the number of elements that agree exactly
    (relative 1e-6) at all given poses. Elements are separable (each depends on a subset of the
    angles), so scores of seven elements are tabulated by broadcasting; J11 and J21 (which
    depend on all six angles) are evaluated only where the total can still reach the best
    (branch and bound).

    Parameters
    ----------
    theta_dh : np.ndarray, shape (P, 6)
        Table I DH angles (rad) of general poses (random wrist, so that the wrist is resolved).
    jac_theta : np.ndarray, shape (P, 3, 3)
        Pinocchio Jacobian w.r.t. the DH angles theta1..theta3 (mm/rad), Pinocchio axes.
    lengths : Mapping[str, float]
        Length symbols (mm).
    terms : Mapping[str, Sequence[Term]]
        Element expressions (default: as printed).
    full : bool
        Score all nine elements (default); if False, only the seven tabulated ones (J11 and
        J21 left out), which is faster when many conventions tie.
    tables : MatchTables, optional
        The match tables of these poses (``MatchTables(theta_dh, jac_theta)``), to share
        between searches at the same poses; default: new ones.

    Returns
    -------
    ConventionSearch
        The best convention, its matching elements and all equivalent ones.
    """
    if tables is None:
        tables = MatchTables(theta_dh, jac_theta)
    elif not (np.array_equal(tables.theta_dh, theta_dh)
              and np.array_equal(tables.jac_theta, jac_theta)):
        raise StiffnessError("find_convention: the match tables were computed at other "
                             "poses; build them from these theta_dh and jac_theta")
    single, third = _options()
    tol = tables.tol

    full_shape = (8, 8, 24, 8, 8, 8, len(_BASE_FLIPS))
    cheap = [n for n in ELEMENT_NAMES if n not in ("J11", "J21")]
    partial = np.zeros(full_shape, dtype=np.int8)
    matches = {}
    for name in cheap:
        matches[name] = tables.match(name, terms[name], lengths)
        partial += matches[name].astype(np.int8)
    bound = int(partial.max())
    if full:
        cand = np.nonzero(partial >= bound - 2)
        totals = partial[cand].astype(int)
        extra_match = _match_j11_j21(cand, single, third, theta_dh, jac_theta, tol, lengths,
                                     terms)
        for ok in extra_match.values():
            totals = totals + ok
    else:
        cand = np.nonzero(partial == bound)
        totals = partial[cand].astype(int)
        extra_match = {}
    best_score = int(totals.max())
    winners = np.nonzero(totals == best_score)[0]
    # simplest first: departures from the identity map
    cost = np.zeros(winners.shape[0], dtype=int)
    for i in range(6):
        opts = _angle_options(i, single, third)
        c_opt = np.array([int(opt[0] != 0.0) + int(opt[1] < 0)
                          + (4 * abs(opt[2]) if i == 2 else 0) for opt in opts])
        cost += c_opt[cand[i][winners]]
    c_flip = np.array([4 * ((f2 < 0) + (f3 < 0)) for f2, f3 in _BASE_FLIPS])
    cost += c_flip[cand[6][winners]]
    order = winners[np.argsort(cost, kind="stable")][:_MAX_EQUIVALENT]
    conventions = []
    for w in order:
        idx = [cand[i][w] for i in range(7)]
        o3, s3, k3 = third[idx[2]]
        offs = tuple(single[idx[i]][0] if i != 2 else o3 for i in range(6))
        sgns = tuple(single[idx[i]][1] if i != 2 else s3 for i in range(6))
        f2, f3 = _BASE_FLIPS[idx[6]]
        conventions.append(AppendixConvention(offs, sgns, k3, (1, f2, f3)))
    best = tuple(cand[i][order[0]] for i in range(7))
    matching = [n for n in cheap if np.broadcast_to(matches[n], full_shape)[best]]
    matching += [n for n, ok in extra_match.items() if ok[order[0]]]
    return ConventionSearch(conventions[0], best_score, sorted(matching), conventions,
                            int(winners.shape[0]), int(np.prod(full_shape)))


def _match_j11_j21(
    cand: tuple[np.ndarray, ...],
    single: Sequence[tuple[float, int]],
    third: Sequence[tuple[float, int, int]],
    theta_dh: np.ndarray,
    jac_theta: np.ndarray,
    tol: np.ndarray,
    lengths: Mapping[str, float],
    terms: TermsByElement,
) -> dict[str, np.ndarray]:
    """Exact-match flags of J11 and J21 for the candidate conventions ``cand`` (indices)."""
    n_cand, n_pose = cand[0].shape[0], theta_dh.shape[0]
    t_cand = np.zeros((n_cand, n_pose, 6))
    for i in range(6):
        opts = _angle_options(i, single, third)
        off = np.deg2rad(np.array([opt[0] for opt in opts]))[cand[i]]
        sgn = np.array([opt[1] for opt in opts], dtype=float)[cand[i]]
        t_cand[:, :, i] = off[:, None] + sgn[:, None] * theta_dh[None, :, i]
        if i == 2:
            k = np.array([opt[2] for opt in opts], dtype=float)[cand[i]]
            t_cand[:, :, i] += k[:, None] * theta_dh[None, :, 1]
    f2 = np.array([f[0] for f in _BASE_FLIPS], dtype=float)[cand[6]]
    s1 = np.array([opt[1] for opt in single], dtype=float)[cand[0]]
    flat = t_cand.reshape(-1, 6)
    out = {}
    for name, row_flip in (("J11", np.ones(n_cand)), ("J21", f2)):
        r = int(name[1]) - 1
        app = terms_values(terms[name], flat, lengths).reshape(n_cand, n_pose)
        pin_v = (row_flip * s1)[:, None] * jac_theta[None, :, r, 0]
        out[name] = np.all(np.abs(app - pin_v) <= tol[None, :], axis=1)
    return out
