"""Pose diagnose's selection (issue 37 item 5): the leave-one-configuration-out criterion from
the linearised hat matrix against refitting without each configuration, families forced and
forbidden, recorded in the model file."""

from __future__ import annotations

import dataclasses
import json
import re

import numpy as np
import pinocchio as pin
import pytest
from pose_campaigns import PRISM_ARM, ur10_tip_campaign

from stiffness.calibration.pose_diagnose import CANDIDATES, _fit, diagnose_poses, screened
from stiffness.calibration.pose_fit import (
    campaign_settings,
    fit_pose_model,
    held_out_rms,
    predict,
    rows_of,
    starting_frame,
)
from stiffness.calibration.pose_model import Marker, PoseModel
from stiffness.calibration.pose_model_file import parameter_table
from stiffness.calibration.pose_report import format_pose_report
from stiffness.calibration.selection import BIC_MARGIN
from stiffness.errors import StiffnessError
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.robot import load_robot

NOISE = 20e-6
MARKERS = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05]))]


@pytest.fixture(scope="module")
def ur10():
    return load_robot("ur10", frame="tool0")


def _campaign(robot, n: int, seed: int, placement: float = 1e-4, poses: int | None = None,
              payload: float = 50.0):
    """A campaign of ``n`` poses (drawn from ``poses``, default ``seed``) of the arm whose
    hidden errors ``seed`` draws, carrying ``payload`` (N)."""
    rng = np.random.default_rng(seed)
    eps = rng.normal(0.0, placement, (6, 6))
    hidden = HiddenPoseErrors(pin.exp3(rng.normal(size=3)), rng.uniform(-2, 2, 3),
                              np.array([m.offset for m in MARKERS]) + rng.normal(0, 2e-3, (1, 3)),
                              rng.normal(0.0, 1e-3, 6), eps,
                              stiffness=np.array([3e5, 2e5, 1.2e5, 4e4, 3e4, 3e4]))
    return simulate_pose_campaign(robot, MARKERS, hidden, n, NOISE,
                                  seed=seed if poses is None else poses,
                                  payload=np.array([0.0, 0.0, -payload, 0.0, 0.0, 0.0]))


@pytest.fixture(scope="module")
def forced_compliance(ur10):
    """A 15-pose campaign and its diagnosis with joint_compliance forced and geometry
    forbidden, computed once for the two tests that read it (they only read it)."""
    campaign = _campaign(ur10, 15, 4)
    return campaign, diagnose_poses(campaign, families=["joint_compliance"],
                                    not_families=["geometry"])


@pytest.fixture(scope="module")
def baseline_only(ur10):
    """The diagnosis of an 8-pose campaign with every candidate family forbidden (the
    baseline alone), computed once for the two tests that read it (they only read it)."""
    return diagnose_poses(_campaign(ur10, 8, 4), not_families=CANDIDATES["known"])


@pytest.mark.parametrize("families", [("frame", "markers", "joint_offsets"),
                                      ("frame", "markers", "joint_offsets", "joint_compliance")])
def test_hat_matrix_matches_refitting_without_each_configuration(ur10, families):
    """The linearised leave-one-configuration-out RMS equals the RMS of the held-out
    configuration's residual after refitting without it (12 poses: 1e-3 relative). The
    payload (400 N) keeps every compliance off its physical bound 0 in every refit: the
    deletion formula is that of an unconstrained fit."""
    campaign = _campaign(ur10, 12, 3, payload=400.0)
    frame0 = starting_frame(campaign)
    settings = campaign_settings(campaign)

    def fit_on(c, x0=None):
        model = PoseModel(ur10, MARKERS, families, frame0, c.loads, settings)
        return fit_pose_model(model, c, rows_of(model, c), list(families), x0)

    full = fit_on(campaign)
    sq, count = 0.0, 0
    for i in range(campaign.n_rows):
        part = fit_on(campaign.subset(np.setdiff1d(np.arange(campaign.n_rows), [i])), full.x)
        held = campaign.subset(np.array([i]))
        err = held.positions - predict(part.model, part.x, held)
        sq, count = sq + float(np.sum(err ** 2)), count + err.size
    refit = np.sqrt(sq / count)
    assert held_out_rms(full, campaign) == pytest.approx(refit, rel=1e-3)
    assert refit > 1.2 * full.rms()  # held out is worse than in-sample: the check can fail


def test_forced_and_forbidden_families_are_recorded(forced_compliance, tmp_path):
    """--families adds its families first whatever their BIC (a rigid arm's zero offsets are
    forced even where they explain nothing); --not keeps a family out; both in the model
    file's selection."""
    campaign, d = forced_compliance
    assert [s.effect for s in d.steps[:2]] == ["baseline", "joint_compliance"]
    assert d.steps[1].forced and not any(s.forced for s in d.steps[2:])
    assert "geometry" not in d.families and "geometry" not in d.rejected
    record = d.to_dict()
    assert record["selection"]["forced"] == ["joint_compliance"]
    assert record["selection"]["forbidden"] == ["geometry"]
    # the model file as diagnose --out writes it (PoseDiagnosis.outputs' "model"), without the
    # page and its figures (1.8 s of CPU; written and read in the backward-elimination test)
    model = json.loads(d.write_model(tmp_path / "final-model.json").read_text())
    assert model["selection"] == record["selection"]
    for families, forbid, words in ((["gravity_lumped"], [], "not a candidate"),
                                    (["backlash"], ["backlash"], "both forced"),
                                    (["gravity_compensator", "joint_compliance"], [],
                                     "acts through")):
        with pytest.raises(StiffnessError, match=words):
            diagnose_poses(campaign, families=families, not_families=forbid)


def test_joint_placement_accepted_on_a_small_one_marker_campaign(ur10):
    """37 poses, one marker, hidden joint-placement errors (the campaign of issue 37 item 5):
    geometry is added by its held-out RMS (every fit trains on 36 of 37 configurations), and
    the held-out RMS it reports is what another campaign of the same arm measures."""
    campaign = _campaign(ur10, 37, 3, placement=3e-5)
    d = diagnose_poses(campaign, families=["joint_offsets", "joint_compliance"],
                       not_families=["link_compliance", "backlash", "gravity_compensator"],
                       validate=_campaign(ur10, 37, 3, placement=3e-5, poses=103))
    assert d.families[-1] == "geometry" and not d.steps[-1].forced
    assert d.steps[-1].delta_bic < -BIC_MARGIN
    assert d.steps[-1].cv_rms < 1.3 * NOISE < 0.5 * d.steps[-2].cv_rms
    validation = d.steps[-1].validation
    assert validation is not None  # 3-D error RMS of pure noise: sqrt(3) sigma
    assert validation["rms"] < 1.3 * np.sqrt(3) * NOISE < 0.5 * d.steps[-2].validation["rms"]


def test_the_step_table_aligns_long_family_names(baseline_only):
    """A forced gravity_compensator ('gravity_compensator *', 21 characters) pushed its row's
    numbers past the header's columns (the family column was 18 wide): every row's parameter
    count now ends where the header's 'params' does (the baseline's step relabelled: the
    table's layout alone is under test, so no judge reads the relabelled step's parameters)."""
    d = baseline_only
    long = dataclasses.replace(d.steps[0], effect="gravity_compensator", forced=True)
    lines = format_pose_report(dataclasses.replace(d, steps=[d.steps[0], long], search=None,
                                                   judge=None)).splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("step "))
    end = lines[header].index("params") + len("params")
    rows = lines[header + 1:header + 3]
    assert rows[-1].split()[1] == "gravity_compensator"
    assert all(row[end - 1].isdigit() and row[end] == " " for row in rows), rows


def test_an_infinite_interval_is_written_as_null_and_said(baseline_only, tmp_path):
    """A fitted parameter the data do not determine at the optimum has an infinite standard
    deviation: diagnose --out ended in a traceback ("Out of range float values are not JSON
    compliant: inf": a prism-jointed arm and a 12-pose Talos arm of the sweep of issue 47);
    the files write null, as the model file's undetermined bounds, and the text 'undetermined'
    (the data do not bound it)."""
    d = baseline_only
    fit = d.final
    cov = fit.covariance.copy()
    cov[0, :], cov[:, 0] = np.inf, np.inf
    step = dataclasses.replace(d.steps[0], fit=dataclasses.replace(fit, covariance=cov),
                               cv_rms=np.inf)  # a forced family one configuration determines
    blind = dataclasses.replace(d, steps=[step], search=None)
    written = blind.write(tmp_path / "out")
    record = json.loads(written["diagnosis"].read_text())
    row = record["parameters"][0]
    assert row["std"] is None and row["interval_95"][1] is None
    assert record["steps"][0]["cv_rms"] is None
    model = json.loads(written["model"].read_text())["parameters"][0]
    assert model["interval_95"][1] is None
    line = next(x for x in format_pose_report(blind).splitlines()
                if x.strip().startswith(row["parameter"]))
    assert "undetermined (the data do not bound it" in line and "inf" not in line, line
    step_row = next(x for x in format_pose_report(blind).splitlines() if x.startswith("0 "))
    assert step_row.split()[-1] == "unbounded", step_row


def test_a_parameter_the_data_leave_without_bound_is_held(tmp_path):
    """A vertical base joint's compliance and its compensator's springs are kept at the
    representative point (the compensator's torque loads the joint); once the naming rule
    holds some of them at 0, nothing loads the joint at the optimum: a column zero, its
    variance infinite. The forced compensator step's held-out criterion ended in a traceback
    ("singular matrix"; with geometry and a robust loss the compliance printed 0.173
    rad/(N.m), interval [0, inf]: the pose sweep of issue 47, a DH arm with two prismatic
    joints, 12 poses, 10 N). Such a parameter, of any family, is held at nominal."""
    path = tmp_path / "robot.toml"
    path.write_text(PRISM_ARM)
    robot = load_robot(str(path))
    markers = [Marker("tip", "tool", np.array([0.0, 0.03, 0.05]))]
    rng = np.random.default_rng(1000)
    hidden = HiddenPoseErrors(pin.exp3(rng.normal(size=3)), rng.uniform(-2, 2, 3),
                              np.array([m.offset for m in markers]) + 1e-3,
                              rng.normal(0, 1e-3, 5), rng.normal(0, 2e-4, (5, 6)),
                              np.array([1008.6659014339884, 287881.5815933359,
                                        26532.846327144798, 81184.52545600462,
                                        3821.674448909354]))
    geometry = PoseModel(robot, markers, ("geometry",), (np.eye(3), np.zeros(3))).geometry
    mask = np.zeros((5, 6))
    mask[tuple(np.array(geometry).T)] = 1.0  # none along a joint's own motion
    hidden.placement_errors *= mask
    c = simulate_pose_campaign(robot, markers, hidden, 12, NOISE, seed=0,
                               payload=np.array([0.0, 0.0, -10.0, 0.0, 0.0, 0.0]))
    forced = ["joint_compliance", "gravity_compensator"]
    d = diagnose_poses(c, families=forced,
                       not_families=[f for f in CANDIDATES["known"] if f not in forced])
    table = parameter_table(d.final, d.judge)
    assert all(row["std"] is not None for row in table if row["fitted"])
    assert any(row["parameter"] == "j1 compensator preload" and row["held"].startswith(
        "held at its nominal value") for row in table)


def test_max_steps_limits_the_pose_search(forced_compliance):
    """``max_steps`` counts the families the search adds after the forced ones (it was
    ignored for pose campaigns): 0 keeps the baseline and the forced family, 1 adds the
    unlimited search's first family and stops there, naming the limit and saying so in
    ``--json`` (``cut_short``, which the unlimited search's is not), and the verdict, still
    above the noise, reads it."""
    campaign, free = forced_compliance
    forced = free.families.index("joint_compliance") + 1
    assert len(free.families) > forced  # the search adds something past the forced family
    assert free.to_dict()["cut_short"] is False and "max_steps" not in free.stop_reason
    for limit in (0, 1):
        d = diagnose_poses(campaign, families=["joint_compliance"], not_families=["geometry"],
                           max_steps=limit)
        assert d.families == free.families[:forced + limit]
        s = d.to_dict()
        assert "max_steps" in d.stop_reason and s["cut_short"] is True
        assert s["unexplained"] is True and s["best_rejected"] is None
        assert (f"the search was cut short (stopped after {limit} effects (max_steps)): a "
                "library effect not tried may be what is missing") in s["unexplained_note"]
    with pytest.raises(StiffnessError, match="non-negative integer"):
        diagnose_poses(campaign, max_steps=-1)


def _backlash_stand_in_campaign():
    """UR5, 20 poses, one marker, 100 N payload, soft joints (2e4..3e3 N.m/rad), 1 mm joint
    placement errors, frame, marker and zero offsets hidden; no backlash: the greedy search
    adds ``backlash`` first (it takes a share of the placement errors and the sag), then
    ``geometry`` and ``joint_compliance``, after which the model is better without it."""
    robot = load_robot("ur5", frame="tool0")
    rng = np.random.default_rng(4)
    eps = np.zeros((6, 6))
    eps[:, :2] = rng.normal(0, 1e-3, (6, 2))
    hidden = HiddenPoseErrors(pin.exp3(rng.normal(size=3)), rng.uniform(-2, 2, 3),
                              np.array([m.offset for m in MARKERS]) + rng.normal(0, 2e-3, (1, 3)),
                              rng.normal(0, 1e-3, 6), eps,
                              stiffness=np.array([2e4, 1.5e4, 1e4, 3e3, 3e3, 3e3]))
    return simulate_pose_campaign(robot, MARKERS, hidden, 20, NOISE, seed=4,
                                  payload=np.array([0, 0, -100.0, 0, 0, 0]))


def test_backward_elimination_removes_a_family_the_final_model_is_better_without(tmp_path):
    """The search adds ``backlash`` first, then the hidden geometry and joint compliance;
    backward elimination (:func:`stiffness.calibration.search.eliminate`) removes the
    backlash again: BIC falls by more than the margin under the step's overdispersion and
    the held-out RMS does not rise. The final model names what is hidden, the removal is a
    step marked ``removed`` (``--json``), the stop reason says so, and how sure the diagnosis
    is judges the final model (removing geometry or the springs costs). Forced, the
    backlash stays."""
    campaign = _backlash_stand_in_campaign()
    d = diagnose_poses(campaign)
    assert d.families == ["frame", "markers", "geometry", "joint_compliance"], d.families
    added = [s.effect for s in d.steps[1:] if not s.removed]
    assert added[0] == "backlash" and set(added) == {"backlash", "geometry", "joint_compliance"}
    last = d.steps[-1]
    assert last.removed and last.effect == "backlash" and last.fit is d.final
    assert last.delta_bic < -BIC_MARGIN and last.cv_rms <= d.steps[-2].cv_rms
    assert "backlash" not in d.final.model.families and not d.unexplained
    assert "then removed backlash" in d.stop_reason
    out = d.to_dict()
    assert [s["removed"] for s in out["steps"]] == [False] * 4 + [True]
    assert [c["effect"] for c in out["how_sure"]] == ["geometry", "joint_compliance"]
    assert all(c["removal_delta_bic"] > 0 for c in out["how_sure"])
    assert re.search(r"^4 +removed backlash +31 ", format_pose_report(d), re.M)
    written = d.write(tmp_path / "out")
    model = json.loads(written["model"].read_text())
    assert model["families"] == ["frame", "markers", "geometry", "joint_compliance"]
    assert "<td>removed backlash</td>" in written["page"].read_text()
    forced = diagnose_poses(campaign, families=["backlash"])
    assert "backlash" in forced.families and not any(s.removed for s in forced.steps)


def test_a_family_not_fitted_gives_its_place_and_screens_are_said():
    """A UR10 campaign of 4 poses, two markers (24 components; hidden frame, marker offsets,
    zero offsets, 0.1 mm placement errors, joint springs, a 150 N payload): ``geometry``
    screens best but has as many identifiable parameters as components, so the next in line
    is fitted in its place (``joint_compliance``: screened -1.7e3, fitted +1.9 before it was
    left at its screen; since the screen keeps compliances within their bounds, screened
    -1.3e3, fitted -2.6 and not added, its held-out error not lower); the families that passed
    the margin on their screen alone are said to be screened, not fitted, instead of a BIC
    change read as a verdict."""
    robot = load_robot("ur10", frame="tool0")
    markers = [MARKERS[0], Marker("elbow", "forearm_link", np.array([0.0, 0.05, 0.2]))]
    rng = np.random.default_rng(11)
    hidden = HiddenPoseErrors(
        pin.exp3(rng.normal(size=3)), rng.uniform(-2, 2, 3),
        np.array([m.offset for m in markers]) + rng.normal(0, 2e-3, (2, 3)),
        rng.normal(0.0, 1e-3, 6), rng.normal(0, 1e-4, (6, 6)),
        np.array([3e5, 2e5, 1.2e5, 4e4, 3e4, 3e4]))
    campaign = simulate_pose_campaign(robot, markers, hidden, 4, NOISE, seed=11,
                                      payload=np.array([0, 0, -150.0, 0, 0, 0]))
    d = diagnose_poses(campaign)
    assert d.not_judged["geometry"].startswith("not fitted")
    assert "joint_compliance" not in d.not_judged and d.rejected["joint_compliance"] > -100
    screened_only = {f for f, why in d.not_judged.items() if why.startswith("screened")}
    assert screened_only == {"transversal_compliance", "backlash"}  # the 3 fitted: the others
    assert all(d.rejected[f] < -BIC_MARGIN for f in screened_only)
    assert "screened" in format_pose_report(d)


def test_the_screen_holds_what_the_current_fit_holds():
    """A step screens each family by one Gauss-Newton step from the current fit. On FIGAROH's
    TALOS arm (geometry holding 9 undetermined parameters at nominal) that step moved them
    too: every family gained the same -9.2 in BIC, so that a base tilt and zero offsets adding
    no parameter ranked first and took the three fits from link_compliance. Here the current
    fit holds elbow_joint's zero offset: screening base_tilt (no parameter while no spring
    sags) must give back the current fit, its objective and its count, and no new parameter."""
    campaign = ur10_tip_campaign(12)
    families = ["frame", "markers", "joint_offsets"]
    current = _fit(campaign, families, starting_frame(campaign), {},
                   held={"elbow_joint zero": "held by the test"})
    assert "elbow_joint zero" in {p.label for p, v in zip(current.model.parameters, current.x,
                                                          strict=True) if v == 0.0}
    rss, p, fresh = screened(campaign, [*families, "base_tilt"], starting_frame(campaign), {},
                             current)
    assert fresh == 0 and p == current.n_fitted
    assert rss == pytest.approx(current.loss_rss(), rel=1e-8)


def test_the_screen_keeps_compliances_within_their_bounds():
    """The screen's Gauss-Newton step let compliances go negative, which the bounded fit never
    does: on FIGAROH's TIAGo split, link_compliance and backlash screened at -22 and -23 in
    BIC and fitted at +28 and +9, and took the three fits from geometry (-9.6) and the bearing
    tilts. A rigid UR10 under a 150 N payload (its compliances truly 0): the screen of
    joint_compliance reaches the bounded fit's objective (scipy's trust-region solver, apart
    from the screen's bounded linear step), not the 36 % lower one of the unbounded step."""
    robot = load_robot("ur10", frame="tool0")
    markers = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05]))]
    hidden = HiddenPoseErrors(pin.exp3(np.array([0.1, -0.2, 1.0])), np.array([1.0, -0.5, 0.3]),
                              np.array([[0.001, 0.031, 0.049]]), np.zeros(6), np.zeros((6, 6)))
    campaign = simulate_pose_campaign(robot, markers, hidden, 12, 20e-6, seed=3,
                                      payload=np.array([0.0, 0.0, -150.0, 0.0, 0.0, 0.0]))
    families, frame0 = ["frame", "markers", "joint_offsets"], starting_frame(campaign)
    current = _fit(campaign, families, frame0, {})
    rss, p, _ = screened(campaign, [*families, "joint_compliance"], frame0, {}, current)
    fit = _fit(campaign, [*families, "joint_compliance"], frame0, {}, current)
    assert len(fit.at_bound) >= 3 and p == fit.n_fitted
    assert rss == pytest.approx(fit.loss_rss(), rel=1e-5)
