"""Tests of the Appendix I cross-check (``stiffness check-jacobian``).

The independent tests compare :func:`stiffness.papers.appendix.appendix_jacobian` (the verbatim
transcription) with Pinocchio's target Jacobian (``target_state``) directly, with the angle
map written out by hand (t1 = 180 deg - q1, t2 = q2 + 90 deg, t3 = -q3, t4 = q4, t5 = q5,
t6 = q6 + 90 deg; so dt/dq = diag(-1, 1, -1) for the first three) and Table I's lengths, so
they do not depend on the search code they check.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from stiffness.cli import main as cli
from stiffness.mechanics.formulation import target_state
from stiffness.papers.appendix import APPENDIX_TERMS, appendix_jacobian, appendix_kc
from stiffness.papers.crosscheck import (
    AppendixConvention,
    Edit,
    apply_edits,
    explain_element,
    find_convention,
    integrability_violations,
    jacobian_from_terms,
    kc_from_terms,
    run_crosscheck,
    table1_lengths_mm,
)
from stiffness.papers.sk120 import FIXTURE_A_M, FIXTURE_B_M
from stiffness.papers.tables import paper_configurations
from stiffness.robot.robot import load_robot

#: Table I lengths in the appendix's symbols (mm), written out by hand.
LENGTHS = {"L1": 215.0, "L2": 1100.0, "L3": 250.0, "D4": 1300.0,
           "D6": 230.0 + FIXTURE_A_M * 1e3, "L6": FIXTURE_B_M * 1e3}
#: dt/dq of the first three angles.
G = np.diag([-1.0, 1.0, -1.0])
ELEMENTS = [f"J{r}{c}" for r in (1, 2, 3) for c in (1, 2, 3)]
D4_SIGN = Edit("J21", "sign", 0, APPENDIX_TERMS["J21"][0],
               type(APPENDIX_TERMS["J21"][0])(1, "D4", (("cos", "t1"), ("cos", "t3"))))


def appendix_angles(q_deg: np.ndarray) -> np.ndarray:
    """Appendix angles (rad) of printed angles (deg), by hand."""
    q = np.asarray(q_deg, dtype=float)
    t = np.array([180.0 - q[0], q[1] + 90.0, -q[2], q[3], q[4], q[5] + 90.0])
    return np.deg2rad(t)


@pytest.fixture(scope="module")
def sk120_poses() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Printed poses (deg), Pinocchio J (mm/rad, w.r.t. appendix angles), K_C per unit force."""
    robot = load_robot("sk120")
    rng = np.random.default_rng(11)
    poses = [*paper_configurations()]
    while len(poses) < 11 + 25:
        q = np.r_[rng.uniform(-180, 180), rng.uniform(-70, 70), rng.uniform(-115, 35),
                  rng.uniform(-180, 180, 3)]
        if abs(np.sin(np.deg2rad(q[1] + q[2] - 270.0))) > np.sin(np.deg2rad(5.0)):
            poses.append(q)
    poses = np.array(poses)
    jac, kc = [], []
    for q_deg in poses:
        q = robot.configuration(np.deg2rad(q_deg))
        states = [target_state(robot, q, f) for f in np.eye(3)]
        jac.append(states[0].jacobian[:3] * 1e3 @ G)
        kc.append([G.T @ s.k_c @ G * 1e3 for s in states])
    return poses, np.array(jac), np.array(kc)


@pytest.fixture(scope="module")
def report() -> dict:
    return run_crosscheck(n_samples=60, seed=3)


# ------------------------------------------------------------------ independent comparisons


def test_eight_elements_match_pinocchio_to_round_off(sk120_poses) -> None:
    poses, jac, _ = sk120_poses
    for q_deg, jp in zip(poses, jac, strict=True):
        ja = appendix_jacobian(appendix_angles(q_deg), LENGTHS)
        scale = np.abs(jp).max()
        for name in ELEMENTS:
            r, c = int(name[1]) - 1, int(name[2]) - 1
            if name != "J21":
                assert abs(ja[r, c] - jp[r, c]) <= 1e-9 * scale, (name, q_deg)


def test_printed_j21_is_off_by_twice_the_d4_term(sk120_poses) -> None:
    poses, jac, _ = sk120_poses
    worst = 0.0
    for q_deg, jp in zip(poses, jac, strict=True):
        t = appendix_angles(q_deg)
        ja = appendix_jacobian(t, LENGTHS)
        expected = -2.0 * LENGTHS["D4"] * np.cos(t[0]) * np.cos(t[2])
        assert ja[1, 0] - jp[1, 0] == pytest.approx(expected, abs=1e-8 * np.abs(jp).max())
        worst = max(worst, abs(expected))
    assert worst > 100.0  # a visible typo, not round-off


def test_corrected_appendix_kc_matches_pinocchio(sk120_poses) -> None:
    poses, _, kc = sk120_poses
    corrected = apply_edits(APPENDIX_TERMS, [D4_SIGN])
    t = np.array([appendix_angles(q) for q in poses])
    for k in range(3):
        ka = kc_from_terms(corrected, t, np.eye(3)[k], LENGTHS)
        scale = np.abs(kc[:, k]).max(axis=(1, 2))[:, None, None]
        assert np.all(np.abs(ka - kc[:, k]) <= 1e-8 * scale)


def test_printed_appendix_kc_is_asymmetric_and_off(sk120_poses) -> None:
    poses, _, kc = sk120_poses
    t = appendix_angles(poses[0])
    k_printed = appendix_kc(t, np.array([0.0, 1.0, 0.0]), LENGTHS)
    assert np.abs(k_printed - k_printed.T).max() > 100.0
    assert np.abs(k_printed - kc[0, 1]).max() > 100.0


def test_kc_from_terms_reproduces_appendix_kc() -> None:
    rng = np.random.default_rng(2)
    t = rng.uniform(-np.pi, np.pi, (4, 6))
    force = np.array([0.3, -1.2, 0.7])
    ours = kc_from_terms(APPENDIX_TERMS, t, force, LENGTHS)
    for p in range(4):
        np.testing.assert_allclose(ours[p], appendix_kc(t[p], force, LENGTHS), atol=1e-9)
    np.testing.assert_allclose(jacobian_from_terms(APPENDIX_TERMS, t, LENGTHS)[2],
                               appendix_jacobian(t[2], LENGTHS), atol=1e-12)


# ------------------------------------------------------------------------------- the report


def test_report_convention(report) -> None:
    mapping = report["conventions"]["mapping"]
    assert mapping["offsets_deg_vs_table1_dh"] == [0.0, 180.0, 180.0, 0.0, 0.0, 0.0]
    assert mapping["signs_vs_table1_dh"] == [1] * 6
    assert mapping["t3_coupling_on_theta2"] == 0
    assert mapping["base_axis_signs"] == [1, 1, 1]
    assert mapping["offsets_deg_vs_printed"] == [180.0, 90.0, 0.0, 0.0, 0.0, 90.0]
    assert mapping["signs_vs_printed"] == [-1, 1, -1, 1, 1, 1]
    search = report["conventions"]["search"]
    assert search["matching_elements"] == 8
    assert search["equivalent_at_generic_lengths"] == 1
    # neither the printed angles nor Table I's angles are the appendix's
    for alt in search["plain_conventions"].values():
        assert alt["n_matching_elements"] <= 1


def test_report_lengths(report) -> None:
    assert report["lengths_mm"] == pytest.approx({**dict.fromkeys(
        ("L4", "L5", "D1", "D2", "D3", "D5"), 0.0), **LENGTHS})
    assert table1_lengths_mm() == report["lengths_mm"]
    ident = report["length_mapping"]["identified_by_least_squares_mm"]
    assert ident["J33"]["D4"] == pytest.approx(1300.0)
    assert ident["J33"]["D6"] == pytest.approx(342.65)
    assert ident["J21"]["D4"] == pytest.approx(-1300.0)  # the typo shows here too


def test_report_elements_and_mismatches(report) -> None:
    for name in ELEMENTS:
        err = report["elements"][name]
        if name == "J21":
            assert err["max_abs"] > 1000.0
        else:
            assert err["max_rel"] < 1e-9, name
        assert report["elements_corrected"][name]["max_rel"] < 1e-9
        assert report["elements_generic_lengths_corrected"][name]["max_rel"] < 1e-9
    assert report["mismatch_elements"] == ["J21"]
    (mismatch,) = report["mismatches"]
    assert mismatch["element"] == "J21"
    assert "'- D4 cos(t1) cos(t3)' has the wrong sign" in mismatch["explanation"]
    assert mismatch["edits"][0]["corrected"] == "+ D4 cos(t1) cos(t3)"
    assert mismatch["n_alternative_explanations"] == 0
    paper = report["elements_by_pose_kind"]["paper"]
    assert all(paper[n]["max_rel"] < 1e-9 for n in ELEMENTS if n != "J21")


def test_report_invisible_typo(report) -> None:
    invisible = [c for c in report["corrections"] if not c["visible_at_table1_lengths"]]
    assert [(c["element"], c["printed"], c["corrected"]) for c in invisible] == [
        ("J21", "- D1 sin(t1)", "- D3 sin(t1)")]
    assert "Invisible at Table I's lengths" in report["invisible_typos"][0]["explanation"]
    printed = {(v["symbol"], v["condition"]) for v in report["integrability"]["printed"]}
    assert {s for s, _ in printed} == {"D1", "D3", "D4"}
    assert report["integrability"]["corrected"] == []


def test_report_kc(report) -> None:
    assert report["appendix_kc_max_rel"] < 1e-8
    assert report["kc_elements"]["K13"]["max_rel"] > 0.1  # printed D4 typo enters K_C
    assert report["kc_printed_max_asymmetry"] > 1000.0
    assert report["kc_pinocchio_max_asymmetry"] < 1e-6
    assert "N.mm/rad" in report["kc_unit"]


# ---------------------------------------------------------------------------- search pieces


def test_integrability_of_printed_terms() -> None:
    symbols = {v["symbol"] for v in integrability_violations(APPENDIX_TERMS)}
    assert symbols == {"D1", "D3", "D4"}


def test_explain_element_finds_single_and_pair() -> None:
    rng = np.random.default_rng(5)
    t = rng.uniform(-np.pi, np.pi, (40, 6))
    lengths = {**LENGTHS, "L4": 71.0, "D5": 29.0, "L5": 43.0}
    truth = jacobian_from_terms(APPENDIX_TERMS, t, lengths)[:, 2, 2]
    terms = list(APPENDIX_TERMS["J33"])
    one = type(terms[0])(-terms[3].sign, terms[3].length, terms[3].factors)
    two = type(terms[0])(terms[6].sign, "L5", terms[6].factors)
    single = {**APPENDIX_TERMS, "J33": tuple(terms[:3] + [one] + terms[4:])}
    expl = explain_element("J33", truth, t, lengths, terms=single)
    assert expl and expl[0][0].kind == "sign" and expl[0][0].index == 3
    double = {**APPENDIX_TERMS, "J33": tuple(terms[:3] + [one] + terms[4:6] + [two] + terms[7:])}
    assert not explain_element("J33", truth, t, lengths, terms=double, max_edits=1)
    pairs = explain_element("J33", truth, t, lengths, terms=double)
    assert any({(e.kind, e.index) for e in pair} == {("sign", 3), ("length", 6)}
               for pair in pairs)


def test_find_convention_recovers_a_synthetic_map() -> None:
    rng = np.random.default_rng(8)
    theta = rng.uniform(-np.pi, np.pi, (8, 6))
    lengths = {**LENGTHS, "D3": 53.0, "L4": 71.0, "D5": 29.0, "L5": 43.0}
    corrected = apply_edits(APPENDIX_TERMS, [D4_SIGN, Edit(
        "J21", "length", 12, APPENDIX_TERMS["J21"][12],
        type(APPENDIX_TERMS["J21"][12])(-1, "D3", (("sin", "t1"),)))])
    conv = AppendixConvention((90.0, 0.0, 180.0, 0.0, -90.0, 0.0), (-1, 1, 1, 1, -1, 1), 0,
                              (1, -1, 1))
    j_app = jacobian_from_terms(corrected, conv.to_appendix(theta), lengths)
    j_theta = np.einsum("ab,pbc,cd->pad", conv.rotation(), j_app, conv.dt_dtheta())
    found = find_convention(theta, j_theta, lengths, terms=corrected)
    assert found.n_matching == 9
    assert found.best == conv


# ------------------------------------------------------------------------------------- CLI


def test_cli_json(capsys) -> None:
    assert cli.main(["check-jacobian", "--json"]) == 0
    out = capsys.readouterr().out
    data = json.loads(out)
    for key in ("elements", "mismatches", "conventions", "kc_elements", "unit",
                "kc_elements_corrected", "appendix_kc_max_rel", "corrections", "lengths_mm",
                "n_poses"):
        assert key in data
    assert data["unit"] == "mm/rad"
    assert set(data["elements"]) == set(ELEMENTS)
    assert all(set(v) == {"max_abs", "max_rel"} for v in data["elements"].values())
    assert [m["element"] for m in data["mismatches"]] == ["J21"]
    assert {"element", "max_abs", "explanation"} <= set(data["mismatches"][0])
    assert data["n_poses"] == 11 + 200 + 50


def test_cli_text(capsys) -> None:
    assert cli.main(["check-jacobian", "--samples", "10", "--seed", "2"]) == 0
    out = capsys.readouterr().out
    assert "J21" in out and "wrong sign" in out
    assert "t2 = q2 + 90 deg" in out


def test_cli_rejects_negative_samples(capsys) -> None:
    assert cli.main(["check-jacobian", "--samples", "-1"]) == 2
    assert "--samples" in capsys.readouterr().err
