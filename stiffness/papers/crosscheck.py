"""The printed Appendix I Jacobian of A&S (2005) vs Pinocchio (``stiffness check-jacobian``).

The paper gives, in its Appendix I, eq. (17), a hand-derived 3x3 positional Jacobian
``J = d(x, y, z) / d(t1, t2, t3)`` of the SK120 end point, as a function of six joint angles
``t1..t6`` and of twelve length symbols ``L1..L6``, ``D1..D6``. :mod:`stiffness.papers.appendix`
holds
it term by term exactly as printed. This module compares it with the Jacobian and the
complementary stiffness K_C that Pinocchio computes on the SK120 model built from Table I
(:mod:`stiffness.papers.sk120`, loop closed), at the same physical poses:

1. **Length mapping.** Table I row ``i`` gives ``D_i`` (its ``d``) and ``L_i`` (its ``a``); the
   five-bar's lower arm is ``L2``; the L-shaped fixture extends row 6 (``D6 = d6 + a``,
   ``L6 = b``). The mapping is checked by a small discrete search over fixture placements and
   confirmed by identifying, element by element, the lengths by least squares.
2. **Angle convention.** The appendix's angles are searched as
   ``t_i = o_i + s_i * theta_i`` (``theta`` = Table I DH angles; offsets multiples of 90 deg,
   signs +-1; ``t3`` optionally relative, ``+ k * theta2``), together with a base-frame
   reflection ``R = diag(1, f2, f3)`` (rotations about z are offsets of ``t1``). The Pinocchio
   Jacobian is mapped into the appendix's convention by the chain rule,
   ``J_app = R J_q G`` with ``G = dq/dt``, and the convention under which most elements agree
   exactly, at general poses, is kept (an exhaustive, branch-and-bound search).
3. **Comparison.** Every element is compared at the paper's printed configurations and over a
   workspace sample; for every element still disagreeing, the smallest edit of the printed
   terms (flip a sign, drop a term, swap a length symbol, a trigonometric function or an
   angle, add a monomial; single edits, then pairs) that makes it match to round-off is
   reported. Nothing is absorbed into the model: the printed terms stay as printed, the
   corrections are listed.
4. **Typos invisible at Table I's lengths.** Table I sets ``D1, D2, D3, L4, L5, D5`` to zero,
   which hides any typo in their terms. They are exposed by (a) an integrability check of the
   printed expressions at generic lengths (model-free: ``dJ[:, i]/dt_j = dJ[:, j]/dt_i`` and
   ``dJ[:, c]/dt1 = z x J[:, c]``) and (b) the same comparison against a Pinocchio model
   built from Table I with those lengths set to non-zero values.
5. **K_C.** Pinocchio's K_C (unit dead forces along each appendix axis) is compared with the
   K_C obtained by differentiating the printed appendix and the corrected appendix
   (complex step); the printed appendix's K_C is not symmetric where a typo breaks
   integrability.

Units in the output: J in mm/rad; K_C in N.mm/rad per N of force (mm/rad), i.e. K_C for a
1 N force. Angles in rad internally, deg in descriptions.

Layout: the angle convention, Table I lengths and convention search are in
:mod:`stiffness.papers.appendix_convention`; evaluation of the terms (J, K_C, integrability) in
:mod:`stiffness.papers.appendix_eval`; the edits that explain a mismatch in
:mod:`stiffness.papers.appendix_edits`; poses and the Pinocchio side in
:mod:`stiffness.papers.appendix_poses`.
This module assembles the report (:func:`run_crosscheck`; the command is
:mod:`stiffness.cli.check_jacobian`); it re-exports
the building blocks listed in ``__all__``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from stiffness.papers.appendix import APPENDIX_TERMS, ELEMENT_NAMES
from stiffness.papers.appendix_convention import (
    SEARCH_POSES,
    SEARCH_REL,
    AppendixConvention,
    ConventionSearch,
    MatchTables,
    find_convention,
    printed_convention,
    table1_lengths_mm,
    wrap_deg,
)
from stiffness.papers.appendix_edits import (
    ROUND_OFF_REL,
    Edit,
    apply_edits,
    edit_delta,
    explain_element,
)
from stiffness.papers.appendix_eval import (
    TermsByElement,
    integrability_violations,
    jacobian_from_terms,
    kc_from_terms,
    terms_values,
)
from stiffness.papers.appendix_poses import (
    LOOP_MARGIN_DEG as LOOP_MARGIN_DEG,  # re-export, see docs
)
from stiffness.papers.appendix_poses import (
    PoseSet,
    build_generic_robot,
    pinocchio_samples,
    sample_poses,
)
from stiffness.papers.sk120 import FIXTURE_A_M, FIXTURE_B_M, AngleConvention, DHRow, read_table1
from stiffness.robot.robot import load_robot
from stiffness.robot.sources import robots_directory

__all__ = [
    "AppendixConvention",
    "ConventionSearch",
    "Edit",
    "PoseSet",
    "apply_edits",
    "explain_element",
    "find_convention",
    "integrability_violations",
    "jacobian_from_terms",
    "kc_from_terms",
    "pinocchio_samples",
    "printed_convention",
    "run_crosscheck",
    "sample_poses",
    "table1_lengths_mm",
]

#: Non-zero values (mm) given to the lengths Table I sets to zero, for the generic-length check.
GENERIC_EXTRA_LENGTHS_MM = {"D1": 37.0, "D3": 53.0, "L4": 71.0, "D5": 29.0, "L5": 43.0}


# --------------------------------------------------------------------------------------------
# Comparisons
# --------------------------------------------------------------------------------------------


def _element_errors(ref: np.ndarray, other: np.ndarray, prefix: str = "J") -> dict[str, dict]:
    """Per-element max abs and max relative (to the largest element of ``ref`` at the pose)."""
    ref = ref.reshape(-1, 3, 3)
    other = other.reshape(-1, 3, 3)
    scale = np.abs(ref).max(axis=(1, 2))
    scale = np.maximum(scale, 1e-12 * max(float(scale.max()), 1e-300))
    diff = np.abs(other - ref)
    out = {}
    for r in range(3):
        for c in range(3):
            out[f"{prefix}{r + 1}{c + 1}"] = {
                "max_abs": float(diff[:, r, c].max()),
                "max_rel": float((diff[:, r, c] / scale).max()),
            }
    return out


def _matches(errors: Mapping[str, dict], rel: float = ROUND_OFF_REL) -> list[str]:
    """Names of the elements whose ``max_rel`` is within ``rel``."""
    return [name for name, e in errors.items() if e["max_rel"] <= rel]


@dataclass
class _Mapped:
    """Pinocchio quantities expressed in the appendix's convention."""

    t: np.ndarray  # (P, 6) appendix angles
    jac: np.ndarray  # (P, 3, 3) mm/rad
    kc: np.ndarray  # (P, 3, 3, 3): [p, k] K_C for a unit force along appendix axis k


def _map_to_appendix(conv: AppendixConvention, printed: AngleConvention, q: np.ndarray,
                     jac_q: np.ndarray, kc_q: np.ndarray) -> _Mapped:
    """Chain rule: ``J_t = R J_q G``, ``K_t(e_k) = G^T K_q(R^T e_k) G``, ``G = dq/dt``."""
    theta = printed.to_dh(q)
    g = np.diag(np.asarray(printed.signs[:3], dtype=float)) @ np.linalg.inv(conv.dt_dtheta())
    rot = conv.rotation()
    jac_t = np.einsum("ab,pbc,cd->pad", rot, jac_q, g)
    kc_pin_axes = np.einsum("kl,plij->pkij", rot.T, kc_q)  # force e_k of appendix = R^T e_k
    kc_t = np.einsum("ia,pkab,bj->pkij", g.T, kc_pin_axes, g)
    return _Mapped(conv.to_appendix(theta), jac_t, kc_t)


def _kc_of_terms(terms: TermsByElement, t: np.ndarray, lengths: Mapping[str, float]
                 ) -> np.ndarray:
    """K_C (P, 3, 3, 3) of element expressions for a unit force along each appendix axis."""
    return np.stack([kc_from_terms(terms, t, np.eye(3)[k], lengths) for k in range(3)], axis=1)


def _identify_lengths(t: np.ndarray, target: np.ndarray, terms: TermsByElement,
                      ) -> dict[str, dict[str, float]]:
    """Per element, least-squares values (mm) of the length symbols it contains."""
    out = {}
    for name in ELEMENT_NAMES:
        r, c = int(name[1]) - 1, int(name[2]) - 1
        symbols = sorted({term.length for term in terms[name]})
        if not symbols:
            continue
        basis = np.column_stack([
            terms_values([tm for tm in terms[name] if tm.length == s], t, {s: 1.0})
            for s in symbols])
        coef = np.linalg.lstsq(basis, target[:, r, c], rcond=None)[0]
        out[name] = {s: float(np.round(v, 6)) + 0.0 for s, v in zip(symbols, coef, strict=True)}
    return out


def _fixture_search(tables: MatchTables, table1: Mapping[str, DHRow]) -> list[dict]:
    """Score a few placements of the fixture (a, b) in the appendix's D6, L6 at the poses of
    ``tables``."""
    a_fix, b_fix = FIXTURE_A_M * 1e3, FIXTURE_B_M * 1e3
    rows = []
    for label, fixture in (("D6 = d6 + a, L6 = b", (a_fix, b_fix)),
                           ("D6 = d6 + a, L6 = -b", (a_fix, -b_fix)),
                           ("D6 = d6 - a, L6 = b", (-a_fix, b_fix)),
                           ("D6 = d6 + b, L6 = a", (b_fix, a_fix)),
                           ("D6 = d6, L6 = 0 (no fixture)", (0.0, 0.0))):
        lengths = table1_lengths_mm(table1, fixture)
        found = find_convention(tables.theta_dh, tables.jac_theta, lengths, full=False,
                                tables=tables)
        rows.append({"assignment": label, "n_matching_of_7_tabulated": found.n_matching,
                     "convention": found.best.describe(),
                     "lengths_mm": {k: v for k, v in lengths.items() if v}})
    return rows


def run_crosscheck(n_samples: int = 200, seed: int = 0) -> dict:
    """Compare Appendix I (as printed, and corrected) with Pinocchio's SK120.

    Parameters
    ----------
    n_samples : int
        Vertical-wrist workspace poses (plus ``max(8, n_samples // 4)`` general-wrist poses
        and the paper's printed configurations).
    seed : int
        Seed of the workspace sample.

    Returns
    -------
    dict
        JSON-ready report: ``elements`` (per-element ``max_abs`` in mm/rad and ``max_rel`` of
        the printed appendix vs Pinocchio after the convention mapping), ``mismatches``
        (elements still disagreeing, with the edit that explains each), ``conventions``,
        ``kc_elements`` / ``kc_elements_corrected`` (K_C of the printed / corrected appendix
        vs Pinocchio's, N.mm/rad per N), ``appendix_kc_max_rel``, ``corrections`` (all edits,
        including those invisible at Table I's lengths), ``lengths_mm``, ``n_poses``,
        ``unit``, ``kc_unit`` and supporting evidence.
    """
    printed = printed_convention()
    table1 = read_table1(robots_directory() / "sk120" / "table1_dh.csv")
    lengths = table1_lengths_mm(table1)
    robot = load_robot("sk120")
    poses = sample_poses(n_samples, seed)
    jac_q, kc_q = pinocchio_samples(robot, poses.q)
    theta = printed.to_dh(poses.q)
    jac_theta = jac_q * np.asarray(printed.signs[:3], dtype=float)[None, None, :]

    # 1-2. convention (and fixture placement) from general-wrist poses
    search_idx = poses.select("general")[:SEARCH_POSES]
    tables = MatchTables(theta[search_idx], jac_theta[search_idx])
    found = find_convention(tables.theta_dh, tables.jac_theta, lengths, tables=tables)
    fixture_rows = _fixture_search(tables, table1)

    # generic lengths: Pinocchio model with the zero lengths of Table I made non-zero
    generic_lengths = {**lengths, **GENERIC_EXTRA_LENGTHS_MM}
    generic_robot = build_generic_robot(GENERIC_EXTRA_LENGTHS_MM, printed)
    generic_idx = poses.select("general")
    g_jac_q, g_kc_q = pinocchio_samples(generic_robot, poses.q[generic_idx])
    g_jac_theta = g_jac_q * np.asarray(printed.signs[:3], dtype=float)[None, None, :]
    found_generic = find_convention(theta[generic_idx][:SEARCH_POSES],
                                    g_jac_theta[:SEARCH_POSES], generic_lengths)
    conv = _kept_convention(found, found_generic, printed, poses.q[search_idx],
                            jac_q[search_idx], kc_q[search_idx], lengths)

    # 3. comparison at Table I's lengths
    mapped = _map_to_appendix(conv, printed, poses.q, jac_q, kc_q)
    app_jac = jacobian_from_terms(APPENDIX_TERMS, mapped.t, lengths)
    elements = _element_errors(mapped.jac, app_jac)
    mismatches, visible = _visible_typos(mapped, elements, lengths)

    # 4. typos invisible at Table I's lengths: generic-length model + integrability
    partly = apply_edits(APPENDIX_TERMS, visible)
    g_mapped = _map_to_appendix(conv, printed, poses.q[generic_idx], g_jac_q, g_kc_q)
    invisible_report, invisible = _invisible_typos(g_mapped, partly, generic_lengths, mapped,
                                                   lengths)
    all_edits = visible + invisible
    corrected = apply_edits(APPENDIX_TERMS, all_edits)
    g_corrected = _element_errors(
        g_mapped.jac, jacobian_from_terms(corrected, g_mapped.t, generic_lengths))

    corrected_elements = _element_errors(
        mapped.jac, jacobian_from_terms(corrected, mapped.t, lengths))
    corrections = [{**e.as_dict(), "visible_at_table1_lengths": e in visible}
                   for e in all_edits]
    conventions = _conventions_report(conv, printed, found, found_generic, len(search_idx),
                                      poses, jac_q, kc_q, lengths)
    return {
        "unit": "mm/rad",
        "kc_unit": "N.mm/rad per N (K_C for a 1 N force along each appendix axis)",
        "n_poses": int(len(poses.q)),
        "n_poses_by_kind": {k: int(len(poses.select(k))) for k in ("paper", "workspace",
                                                                   "general")},
        "relative_error": ("max over poses of |difference| / (largest |element| of the "
                           "Pinocchio matrix at that pose); round-off threshold "
                           f"{ROUND_OFF_REL:g}"),
        "elements": elements,
        "elements_by_pose_kind": {
            kind: _element_errors(mapped.jac[poses.select(kind)], app_jac[poses.select(kind)])
            for kind in ("paper", "workspace", "general") if len(poses.select(kind))},
        "mismatches": mismatches,
        "mismatch_elements": [m["element"] for m in mismatches],
        "conventions": conventions,
        "lengths_mm": lengths,
        "length_mapping": _length_mapping(fixture_rows, mapped),
        "corrections": corrections,
        "invisible_typos": invisible_report,
        "generic_lengths_mm": generic_lengths,
        "elements_generic_lengths_corrected": g_corrected,
        "integrability": {
            "printed": integrability_violations(APPENDIX_TERMS),
            "corrected": integrability_violations(corrected),
        },
        "elements_corrected": corrected_elements,
        **_kc_report(mapped, corrected, lengths),
    }


def _kept_convention(found: ConventionSearch, found_generic: ConventionSearch,
                     printed: AngleConvention, q: np.ndarray, jac_q: np.ndarray,
                     kc_q: np.ndarray, lengths: Mapping[str, float]) -> AppendixConvention:
    """The generic-length search's convention, unless at Table I's ``lengths`` (mm) it matches
    fewer printed elements at the search poses (``q``, ``jac_q``, ``kc_q``) than the Table-I
    search's best does."""
    conv = found_generic.best
    check = _map_to_appendix(conv, printed, q, jac_q, kc_q)
    check_errors = _element_errors(
        check.jac, jacobian_from_terms(APPENDIX_TERMS, check.t, lengths))
    if len(_matches(check_errors, SEARCH_REL)) < found.n_matching:
        conv = found.best
    return conv


def _length_mapping(fixture_rows: list[dict], mapped: _Mapped) -> dict:
    """How the appendix's L_i, D_i follow from Table I, the fixture placements scored, and the
    lengths (mm) identified by least squares from Pinocchio's Jacobians."""
    return {
        "text": ("L_i = a_i and D_i = d_i of Table I row i (L2 = the five-bar's lower arm, "
                 "row 2b); the fixture extends row 6: D6 = d6 + a, L6 = b; D2 = 0"),
        "fixture_search": fixture_rows,
        "identified_by_least_squares_mm": _identify_lengths(
            mapped.t, mapped.jac, APPENDIX_TERMS),
    }


def _visible_typos(mapped: _Mapped, elements: dict, lengths: Mapping[str, float]
                   ) -> tuple[list[dict], list[Edit]]:
    """The printed elements that disagree with Pinocchio at Table I's lengths (beyond
    round-off), each with the edit of its printed terms that explains it; and those edits."""
    scale = np.abs(mapped.jac).max(axis=(1, 2))
    visible: list[Edit] = []
    mismatches = []
    for name in ELEMENT_NAMES:
        if elements[name]["max_rel"] <= ROUND_OFF_REL:
            continue
        r, c = int(name[1]) - 1, int(name[2]) - 1
        expl = explain_element(name, mapped.jac[:, r, c], mapped.t, lengths, scale=scale)
        entry = {"element": name, "max_abs": elements[name]["max_abs"],
                 "max_rel": elements[name]["max_rel"]}
        if expl:
            edits = list(expl[0])
            err = _edit_error(name, APPENDIX_TERMS, edits, mapped, lengths)
            text = " and ".join(e.describe() for e in edits)
            entry["explanation"] = (
                f"{text}; with this edit {name} matches Pinocchio to {err:.1g} mm/rad over "
                f"{len(mapped.t)} poses (it was off by up to {entry['max_abs']:.4g} mm/rad)")
            entry["edits"] = [e.as_dict() for e in edits]
            entry["n_alternative_explanations"] = len(expl) - 1
            visible.extend(edits)
        else:
            entry["explanation"] = ("no single edit or pair of edits of the printed terms "
                                    "explains it")
        mismatches.append(entry)
    return mismatches, visible


def _invisible_typos(g_mapped: _Mapped, partly: TermsByElement,
                     generic_lengths: Mapping[str, float], mapped: _Mapped,
                     lengths: Mapping[str, float]) -> tuple[list[dict], list[Edit]]:
    """Typos invisible at Table I's lengths (``mapped``, ``lengths``: their terms vanish there)
    found with the generic-length model (``g_mapped``, ``generic_lengths``) after the visible
    edits (``partly``), each explained; and their edits."""
    g_scale = np.abs(g_mapped.jac).max(axis=(1, 2))
    g_elements = _element_errors(
        g_mapped.jac, jacobian_from_terms(partly, g_mapped.t, generic_lengths))
    invisible: list[Edit] = []
    invisible_report = []
    for name in ELEMENT_NAMES:
        if g_elements[name]["max_rel"] <= ROUND_OFF_REL:
            continue
        r, c = int(name[1]) - 1, int(name[2]) - 1
        expl = explain_element(name, g_mapped.jac[:, r, c], g_mapped.t, generic_lengths,
                               terms=partly, scale=g_scale)
        entry = {"element": name, "max_abs_generic": g_elements[name]["max_abs"]}
        if expl:
            edits = list(expl[0])
            delta_t1 = max(float(np.abs(edit_delta(e, mapped.t, lengths)).max()) for e in edits)
            zero = sorted({s for e in edits for s in _symbols(e) if lengths.get(s, 0.0) == 0.0})
            entry["explanation"] = " and ".join(e.describe() for e in edits) + (
                f"; with it {name} matches the generic-length model to "
                f"{_edit_error(name, partly, edits, g_mapped, generic_lengths):.1g} mm/rad "
                f"(off by up to {entry['max_abs_generic']:.3g} mm/rad at "
                + ", ".join(f"{s} = {generic_lengths[s]:g}" for s in zero)
                + f" mm). Invisible at Table I's lengths: {', '.join(zero)} = 0 there, so the "
                f"edit changes {name} by {delta_t1:.1g} mm/rad")
            entry["edits"] = [e.as_dict() for e in edits]
            invisible.extend(edits)
        else:
            entry["explanation"] = "not explained by one or two edits"
        invisible_report.append(entry)
    return invisible_report, invisible


def _kc_report(mapped: _Mapped, corrected: TermsByElement, lengths: Mapping[str, float]
               ) -> dict:
    """K_C (N.mm/rad per N) of the printed and the corrected appendix against Pinocchio's:
    per-element errors, their largest relative error, and the asymmetry of each."""
    kc_printed = _kc_of_terms(APPENDIX_TERMS, mapped.t, lengths)
    kc_fixed = _kc_of_terms(corrected, mapped.t, lengths)
    kc_elements = _element_errors(mapped.kc, kc_printed, prefix="K")
    kc_elements_corrected = _element_errors(mapped.kc, kc_fixed, prefix="K")
    asym = np.abs(kc_printed - np.swapaxes(kc_printed, -1, -2)).max(axis=(0, 1))
    pin_asym = float(np.abs(mapped.kc - np.swapaxes(mapped.kc, -1, -2)).max())
    return {
        "kc_elements": kc_elements,
        "kc_elements_corrected": kc_elements_corrected,
        "appendix_kc_max_rel": max(e["max_rel"] for e in kc_elements_corrected.values()),
        "appendix_kc_printed_max_rel": max(e["max_rel"] for e in kc_elements.values()),
        "kc_printed_max_asymmetry": float(asym.max()),
        "kc_pinocchio_max_asymmetry": pin_asym,
    }


def _conventions_report(conv: AppendixConvention, printed: AngleConvention,
                        found: ConventionSearch, found_generic: ConventionSearch,
                        n_search_poses: int, poses: PoseSet, jac_q: np.ndarray,
                        kc_q: np.ndarray, lengths: Mapping[str, float]) -> dict:
    """The convention kept (``conv``), how it maps the printed angles, how it was found (the
    search at Table I's and at generic lengths) and how the plain conventions score."""
    plain = {
        "t = printed q": AppendixConvention(
            tuple(wrap_deg(-s * o) for s, o in zip(printed.signs, printed.offsets_deg,
                                                      strict=True)),
            tuple(printed.signs)),
        "t = Table I DH theta": AppendixConvention((0.0,) * 6, (1,) * 6),
    }
    plain_scores = {}
    for label, alt in plain.items():
        m_alt = _map_to_appendix(alt, printed, poses.q, jac_q, kc_q)
        errs = _element_errors(m_alt.jac, jacobian_from_terms(APPENDIX_TERMS, m_alt.t, lengths))
        plain_scores[label] = {"n_matching_elements": len(_matches(errs)),
                               "matching": _matches(errs)}
    equivalent = [c for c in found.equivalent if c != conv]
    tie_note = ""
    if found.n_equivalent > found_generic.n_equivalent:
        tie_note = (
            f"At Table I's lengths {found.n_equivalent} conventions tie: the wrist's symmetry "
            "(t4 + 180, -t5, t6 + 180) leaves the end point unchanged when L4 = L5 = D5 = 0, "
            "and the mirror image in the base x-z plane (y reversed; t1, t4, t6 negated) is "
            "the same mechanism when no lateral offset (D2, D3) exists. With the generic "
            f"lengths {found_generic.n_equivalent} remain; the simplest is kept.")
    conventions = {
        "description": conv.describe(printed),
        "mapping": conv.as_dict(printed),
        "printed_to_table1_dh": printed.describe(),
        "theta2_theta3": (
            "absolute: the appendix's t2 is the lower arm's angle and t3 the forearm's "
            "(parallelogram), not relative to t2" if conv.t3_coupling == 0
            else f"t3 includes {conv.t3_coupling:+d} x theta2"),
        "chain_rule": ("J_appendix = R J_q G with G = dq/dt = diag(signs_vs_printed) (the "
                       "Pinocchio Jacobian w.r.t. printed q1..q3 mapped to the appendix's "
                       "angles); K_C,appendix = G^T K_C,q G"),
        "search": {
            "candidates": found.n_candidates,
            "poses": n_search_poses,
            "matching_elements": found.n_matching,
            "matching": found.matching,
            "equivalent_at_table1_lengths": found.n_equivalent,
            "equivalent_examples": [c.describe() for c in equivalent[:3]],
            "matching_elements_generic_lengths": found_generic.n_matching,
            "equivalent_at_generic_lengths": found_generic.n_equivalent,
            "note": tie_note,
            "plain_conventions": plain_scores,
        },
    }
    return conventions


def _edit_error(name: str, terms: TermsByElement, edits: Sequence[Edit], mapped: _Mapped,
                lengths: Mapping[str, float]) -> float:
    """Max abs error (mm/rad) of element ``name`` after the edits, against ``mapped.jac``."""
    r, c = int(name[1]) - 1, int(name[2]) - 1
    fixed = apply_edits(terms, edits)
    return float(np.abs(jacobian_from_terms(fixed, mapped.t, lengths)[:, r, c]
                        - mapped.jac[:, r, c]).max())


def _symbols(edit: Edit) -> set[str]:
    """Length symbols of the old and new terms of an edit."""
    return {t.length for t in (edit.old, edit.new) if t is not None}
