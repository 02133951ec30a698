"""One identifiability for both campaign kinds (:mod:`stiffness.calibration.identifiability`):
the reduction against closed forms, and a deflection campaign whose link bend aliases a joint
spring reporting the merge instead of a rigid joint with an interval [0, inf], the merged
parameter held at its nominal value whatever the fit starts from; physical bounds: a rigid
joint's compliance is never fitted negative."""

from __future__ import annotations

import json
import math

import numpy as np
import pinocchio as pin
import pytest
from scipy import stats

from stiffness.calibration.diagnose import diagnose
from stiffness.calibration.diagnosis_report import format_report
from stiffness.calibration.identifiability import (
    Dropped,
    Identifiability,
    confounded,
    reduce_columns,
)
from stiffness.calibration.pose_fit import fit_pose_model, rows_of, starting_frame
from stiffness.calibration.pose_model import Marker, PoseModel
from stiffness.calibration.selection import bounded_intervals, fit_model
from stiffness.cli.main import main
from stiffness.elastic.effects import make_effect
from stiffness.elastic.effects.base import Held
from stiffness.elastic.effects.geometry import Geometry, References
from stiffness.elastic.effects.hypothesis import Hypothesis
from stiffness.planning.simulate import parse_effect, simulate
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.robot import load_robot

UR5_PARALLEL = ["shoulder_lift_joint", "elbow_joint", "wrist_1_joint"]


def test_reduction_keeps_merges_and_drops_against_closed_forms():
    """Columns e1, e2, 2 e1 - 3 e2 (scaled), zero, and e1 + 1e-3 e3: the third is merged with
    the coefficients of its own units, the fourth has no effect, the fifth is kept unless a
    resolution above its orthogonal part (1e-3) is asked for."""
    e = np.eye(4)
    scales = np.array([1.0, 2.0, 0.5, 1.0, 1.0])
    # a's columns are the regressor's times the scales: the regressor's third column is
    # (2 e1 - 3 e2) / 0.5 in a, i.e. 2 x (e1 / 1) - 3 x (e2 / 2) x 2 in own units
    a = np.column_stack([e[0], e[1], 2 * e[0] - 3 * e[1], 0 * e[0], e[0] + 1e-3 * e[2]])
    ident = reduce_columns(a, [[0, 1], [2, 3], [4]], scales)
    assert ident.kept == [0, 1, 4]
    merged = ident.dropped_at(2)
    assert merged is not None and merged.reason == "merged"
    coefs = dict(merged.merged_into)
    # own units: x_kept absorbs c x_merged with c = a-coef * scale_kept / scale_merged
    assert coefs[0] == pytest.approx(2 * 1.0 / 0.5) and coefs[1] == pytest.approx(-3 * 2.0 / 0.5)
    assert ident.dropped_at(3).reason == "no effect"
    strict = reduce_columns(a, [[0, 1], [2, 3], [4]], scales, [0.0, 0.0, 1e-2])
    assert strict.kept == [0, 1] and strict.dropped_at(4).reason == "merged"
    loose = reduce_columns(a, [[0, 1], [2, 3], [4]], scales, [0.0, 0.0, 1e-4])
    assert loose.kept == [0, 1, 4]


@pytest.fixture(scope="module")
def aliased():
    """UR5 with three parallel compliant joints and a bend of elbow -> wrist_1 hidden: the
    bend about the axis parallel to wrist_1's is that joint's spring to first order."""
    sim = simulate("ur5", kq=[3e4, 2e4, 1.5e4], compliant_joints=UR5_PARALLEL,
                   target_offset_m=[0.0, 0.0, 0.1], max_force=100.0,
                   effects=[parse_effect("link_compliance:elbow_joint->wrist_1_joint=5e4")],
                   configs=6, loads_per_config=4, noise_std_m=5e-6, seed=0)
    return diagnose(sim.campaign, max_steps=1, propose=False, workers=1)


def test_a_bend_aliasing_a_joint_spring_is_reported_merged(aliased):
    d = aliased
    assert [s.effect.label for s in d.steps] == ["link_compliance(elbow_joint->wrist_1_joint)"]
    dropped = {x["parameter"]: x for x in d.identifiability()["dropped"]}
    bend = "link_compliance(elbow_joint->wrist_1_joint).stiffness_1"
    assert dropped[bend]["reason"] == "merged"
    into = dropped[bend]["merged_into"][0]
    assert into["parameter"] == "compliance(wrist_1_joint)"
    assert into["coefficient"] == pytest.approx(1.0, abs=0.02)
    # the joint's spring absorbs the bend: the two compliances in series
    wrist = {p.name: p for p in d.final_stiffness}["wrist_1_joint"]
    assert wrist.determined
    assert wrist.value == pytest.approx(1.0 / (1 / 1.5e4 + 1 / 5e4), rel=0.03)
    held = {p.name: p for p in d.final_parameters[d.steps[0].effect.label]}["stiffness_1"]
    assert held.held.startswith("merged") and not held.determined
    text = format_report(d)
    assert "inf" not in text and "1e+14" not in text and "not fitted" in text
    summary = json.loads(json.dumps(d.to_dict()))
    step = summary["steps"][0]["parameters"]["stiffness_1"]
    assert step["held"].startswith("merged") and step["determined"] is False


def test_a_merged_parameter_is_held_at_its_nominal_value_whatever_the_start():
    """The aliased campaign's bend fitted from its nominal start and from a warm one (its
    variables at 3, as a refit from another fit's optimum): the merged variable is held at its
    nominal value, the bend's start, in both, and the two fits agree. Held at the warm start
    instead, the joint absorbed the bend minus its held share: the 3-unit bend (compliance
    1.5e-4 rad/(N.m)) is beyond the pair in series (1 / 11400), so the wrist's compliance went
    to its bound, wrist_1 rigid at 1e14 N.m/rad and the RSS 72 times larger (measured before
    the rule; from 0.3 units the wrist printed 13751 N.m/rad instead of 11405)."""
    sim = simulate("ur5", kq=[3e4, 2e4, 1.5e4], compliant_joints=UR5_PARALLEL,
                   target_offset_m=[0.0, 0.0, 0.1], max_force=100.0,
                   effects=[parse_effect("link_compliance:elbow_joint->wrist_1_joint=5e4")],
                   configs=6, loads_per_config=4, noise_std_m=5e-6, seed=0)
    c = sim.campaign
    geo = Geometry.of(c.robot())
    rows = geo.rows(c.q, c.force, c.moment)
    base = Hypothesis(geo, rows, "enhanced", tuple(UR5_PARALLEL), (),
                      References.of(geo, rows, 2e4, c.deflection))
    bend = make_effect("link_compliance", "elbow_joint->wrist_1_joint", geo)
    model = base.extended(bend)
    cold = base.extend_x(np.log([3e4, 2e4, 1.5e4]), bend)
    warm = np.concatenate([cold[:3], [3.0, 3.0]])
    fits = [fit_model(model, c.deflection, 5e-6, x0) for x0 in (cold, warm)]
    for fit in fits:
        (merged,) = fit.identifiability.dropped
        assert merged.reason == "merged" and merged.index == 3
        assert fit.x[3] == bend.start()[0]
    np.testing.assert_allclose(fits[1].x, fits[0].x, rtol=1e-6)
    assert fits[1].rss == pytest.approx(fits[0].rss, rel=1e-9)
    # the wrist's spring absorbs the bend: the two compliances in series
    assert np.exp(fits[1].x[2]) == pytest.approx(1.0 / (1 / 1.5e4 + 1 / 5e4), rel=0.03)


def _binomial_consistent(hits: int, n: int, level: float = 0.95, alpha: float = 1e-3) -> bool:
    return (stats.binom.cdf(hits, n, level) > alpha / 2
            and stats.binom.sf(hits - 1, n, level) > alpha / 2)


def test_a_rigid_joint_never_gets_a_negative_compliance():
    """UR10 pose campaigns (30 poses, two markers, 20 µm, a 150 N payload) whose truth has a
    rigid shoulder_lift_joint (compliance 0), 8 seeds: no fitted compliance is negative (the
    unbounded fit gave 5 negative in 12 seeds), one at its bound has a one-sided interval from
    0, and the intervals of the compliances off their bound cover the truth at a rate
    consistent with 95 % (binomial, alpha 1e-3)."""
    robot = load_robot("ur10", frame="tool0")
    markers = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05])),
               Marker("elbow", "forearm_link", np.array([0.0, 0.05, 0.2]))]
    stiffness = np.array([3e5, np.inf, 1.2e5, 4e4, 3e4, 3e4])
    families = ["frame", "markers", "joint_compliance"]
    joints = list(robot.compliant_joints)
    hits = count = at_bound = 0
    for seed in range(8):
        rng = np.random.default_rng(seed)
        hidden = HiddenPoseErrors(pin.exp3(rng.normal(size=3)), rng.uniform(-2, 2, 3),
                                  np.array([m.offset for m in markers])
                                  + rng.normal(0, 2e-3, (2, 3)),
                                  np.zeros(6), np.zeros((6, 6)), stiffness)
        c = simulate_pose_campaign(robot, markers, hidden, 30, 20e-6, seed=seed,
                                   payload=np.array([0.0, 0.0, -150.0, 0.0, 0.0, 0.0]))
        model = PoseModel(robot, c.markers, tuple(families), starting_frame(c), c.loads)
        fit = fit_pose_model(model, c, rows_of(model, c), families)
        lo, hi = fit.interval()
        for i in fit.identifiability.kept:
            p = model.parameters[i]
            if p.family != "joint_compliance":
                continue
            assert fit.x[i] >= 0.0 and lo[i] >= 0.0
            truth = 1.0 / stiffness[joints.index(p.label.split()[0])]
            if i in fit.at_bound:
                at_bound += 1
                assert fit.x[i] == 0.0 and lo[i] == 0.0 < hi[i]
                continue
            hits += int(lo[i] <= truth <= hi[i])
            count += 1
    assert at_bound >= 2  # the rigid joint sits at its bound in some seeds
    assert count >= 25 and _binomial_consistent(hits, count), (hits, count)


def test_a_bound_parameter_the_data_do_not_determine_holds_no_interval():
    """A parameter at its bound whose variance is infinite (along a direction the data do not
    determine: its covariance row and column inf) cannot be held: the others' intervals are
    conditional on the determined ones alone (closed form, the Schur complement). It crashed
    with "SVD did not converge" (the pose sweep of issue 47: an xarm7 compensator candidate
    with springs the campaign could not load)."""
    cov = np.array([[4.0, np.inf, 1.0], [np.inf, np.inf, np.inf], [1.0, np.inf, 2.0]])
    x, lower = np.array([1.0, 0.0, 0.0]), np.array([-np.inf, 0.0, 0.0])
    lo, hi = bounded_intervals(x, lower, cov, [1, 2], 1.96, 1.645)
    assert lo[0] == pytest.approx(1.0 - 1.96 * np.sqrt(4.0 - 1.0 / 2.0))  # x2 pushed: held
    assert hi[0] == pytest.approx(1.0 + 1.96 * 2.0)  # x2 pulled off its bound: free
    assert (lo[1], hi[1]) == (0.0, np.inf) and hi[2] == pytest.approx(1.645 * np.sqrt(2.0))


def test_a_near_alias_at_its_bound_leaves_an_interval_that_covers():
    """A linear least-squares fit under bounds, 1000 seeds, closed form by scipy's
    ``lsq_linear``: x0 free, x1 (truth 0.3) and x2 (truth 0) bounded below by 0; x0's column
    and x1's are 0.9995 alike (a near alias: when x1 sits at 0, x0 takes its share) and x2's
    moves with x0 (correlation 0.53). x0's interval from :func:`bounded_intervals` covers the
    truth at a rate of at least 95 % (binomial, alpha 1e-3; measured 997/1000); with every
    parameter at its bound held on a side where one of them is pushed past it (x1 held too
    when only x2 is pushed: the Panda's two wrist tilts, docs/absolute-poses.md) it covered
    888/1000, and that rule is shown to fail here."""
    from scipy.optimize import lsq_linear

    t = np.linspace(0.0, 1.0, 40)
    a = np.column_stack([np.ones(40), 1.0 + 0.15 * t, -(np.sin(7 * t) + 0.1)])
    truth, sigma, lower = np.array([1.0, 0.3, 0.0]), 0.1, np.array([-np.inf, 0.0, 0.0])
    full = sigma ** 2 * np.linalg.inv(a.T @ a)
    rng = np.random.default_rng(0)
    hits = strict_hits = 0
    for _ in range(1000):
        sol = lsq_linear(a, a @ truth + rng.normal(0.0, sigma, 40), bounds=(lower, np.inf),
                         tol=1e-12)
        bound = [i for i in (1, 2) if sol.active_mask[i] != 0]
        x = sol.x.copy()
        x[bound] = 0.0
        lo, hi = bounded_intervals(x, lower, full, bound, 1.96, 1.645)
        assert np.all(lo <= x) and np.all(x <= hi) and np.all(lo >= lower)
        hits += lo[0] <= truth[0] <= hi[0]
        free = [i for i in range(3) if i not in bound]
        held = sigma ** 2 * np.linalg.inv(a[:, free].T @ a[:, free])[0, 0]
        pushed = full[0, bound]
        strict_lo = x[0] - 1.96 * np.sqrt(held if np.any(pushed > 0) else full[0, 0])
        strict_hi = x[0] + 1.96 * np.sqrt(held if np.any(pushed < 0) else full[0, 0])
        strict_hits += strict_lo <= truth[0] <= strict_hi
    assert stats.binom.cdf(hits, 1000, 0.95) > 1e-3, hits
    assert stats.binom.cdf(strict_hits, 1000, 0.95) < 1e-3, strict_hits


def test_the_others_intervals_at_a_bound_cover_and_holding_it_on_both_ends_does_not():
    """The one rule at a bound of both campaign kinds (:func:`end_covariances`, through
    :func:`bounded_intervals`), checked two-sided (coverage and spread, tests/stats.py) on the
    closed form of a two-parameter linear fit bounded below on x1 (2000 draws): x0 and x1
    correlated -0.9, x1's truth two standard errors above its bound (the fit puts it at the
    bound 2 % of the time, then x0 is the held fit ``x0 - rho x1``). The rule covers x0 at
    nominal (measured 1905/2000, sum z^2 / n 0.98); holding x1 on both ends (the covariance
    of a fit with it held) is too narrow where the bound is not the truth (1877/2000, sum z^2
    / n 1.32) and fails the same check."""
    from stats import Coverage

    from stiffness.calibration.selection import holding

    rho = -0.9
    full = np.array([[1.0, rho], [rho, 1.0]])
    draws = np.array([0.0, 2.0]) + np.random.default_rng(0).multivariate_normal(
        np.zeros(2), full, 2000)
    rule, both = Coverage(), Coverage()
    for x in draws:
        bound = [1] if x[1] < 0.0 else []
        if bound:  # the bounded least-squares optimum (KKT): x1 at 0, x0 the held fit
            x = np.array([x[0] - rho * x[1], 0.0])
        lo, hi = bounded_intervals(x, np.array([-np.inf, 0.0]), full, bound, 1.96, 1.645)
        rule.add(x[0], (lo[0], hi[0]), 0.0)
        half = 1.96 * math.sqrt(holding(full, bound)[0, 0])
        both.add(x[0], (x[0] - half, x[0] + half), 0.0)
    rule.check(design_effect=1.0)
    with pytest.raises(AssertionError):
        both.check(design_effect=1.0)


def test_each_end_holds_only_the_bound_parameters_it_pushes():
    """:func:`end_covariances` against closed forms: x0 correlated +0.6 with x1 and -0.5 with
    x2, both at a lower bound. Lowering x0 pushes x1 below its bound (positive covariance):
    the low end holds x1 alone, its covariance the inverse of the information's block over
    x0 and x2 (a fit with x1 held); raising x0 pushes x2: the high end holds x2 alone. With
    x2 at an upper bound instead, lowering x0 pushes both (the low end holds both) and raising
    it neither (the high end is the free one)."""
    from stiffness.calibration.selection import end_covariances, holding

    cov = np.array([[1.0, 0.6, -0.5], [0.6, 1.0, 0.1], [-0.5, 0.1, 1.0]])
    info = np.linalg.inv(cov)
    low, high = end_covariances(cov, 0, [1, 2], [1.0, 1.0])
    np.testing.assert_allclose(low[np.ix_([0, 2], [0, 2])],
                               np.linalg.inv(info[np.ix_([0, 2], [0, 2])]), atol=1e-12)
    np.testing.assert_allclose(high[np.ix_([0, 1], [0, 1])],
                               np.linalg.inv(info[np.ix_([0, 1], [0, 1])]), atol=1e-12)
    assert low[0, 0] == pytest.approx(1.0 - 0.36) and high[0, 0] == pytest.approx(1.0 - 0.25)
    low, high = end_covariances(cov, 0, [1, 2], [1.0, -1.0])  # x2 at an upper bound
    np.testing.assert_allclose(low, holding(cov, [1, 2]), atol=1e-12)
    assert high is cov


def test_a_held_parameter_names_what_it_is_confounded_with():
    """Two unit columns at cosine rho: the least-squares estimates' correlation is -rho
    (closed form, (A^T A)^-1 of [[1, rho], [rho, 1]]). Beyond ALIAS_CORRELATION the held
    parameter's reason names the other with that correlation, and identifiability's JSON lists
    it under ``confounded_with``; below it, nothing."""
    e = np.eye(4)
    labels = ["compliance(elbow_joint)", "bend.stiffness_2", "frame x"]
    for rho, named in ((0.95, True), (-0.97, True), (0.5, False)):
        a = np.column_stack([e[0], rho * e[0] + math.sqrt(1 - rho ** 2) * e[1], e[2]])
        cov = np.linalg.inv(a.T @ a)
        pairs = confounded(cov, 1, [0, 1, 2], labels)
        assert pairs == ((("compliance(elbow_joint)", pytest.approx(-rho, abs=1e-12)),)
                         if named else ())
        held = Held("held at its nominal value: why", pairs)
        dropped = Identifiability([0, 2], []).holding({1: held}).to_dict(labels)["dropped"]
        assert dropped[0]["confounded_with"] == (
            [{"parameter": "compliance(elbow_joint)", "correlation": round(-rho, 3)}]
            if named else [])
        assert dropped[0]["note"] == held.text()
        assert ("(correlation" in held.text()) is named
    # a pose label has spaces; two named, the most correlated first
    held = Held("why", (("frame x", -0.95), ("compliance(elbow_joint)", 0.93)))
    assert held.text() == ("why; not told apart from frame x (correlation -0.950), "
                           "compliance(elbow_joint) (correlation 0.930), which take its share")
    (dropped,) = Identifiability([0, 2], []).holding({1: held}).to_dict(labels)["dropped"]
    assert [(c["parameter"], c["correlation"]) for c in dropped["confounded_with"]] == [
        ("frame x", -0.95), ("compliance(elbow_joint)", 0.93)]


def test_a_forced_bend_held_beside_the_elbow_spring_names_it(tmp_path, capsys):
    """UR5 deflection campaign (6 configurations x 4 loads, seed 0) with a stiff bend of the
    upper arm hidden (2e6 N.m/rad), forced in: the bend's second axis, nearly the elbow's
    (0.12 m joint offset), is held as undetermined, and the text and --json say it is not
    told apart from the elbow's spring and how correlated (0.969 measured)."""
    bend = "link_compliance(shoulder_lift_joint->elbow_joint)"
    assert main(["simulate", "--robot", "ur5", "--kq", "8e4,6e4,4e4,1.2e4,1.2e4,1e4",
                 "--configs", "6", "--loads-per-config", "4", "--seed", "0", "--quiet",
                 "--effect", "link_compliance:shoulder_lift_joint->elbow_joint=2e6",
                 "--out", str(tmp_path)]) == 0
    capsys.readouterr()
    assert main(["diagnose", str(tmp_path), "--families", bend, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    (held,) = [d for d in out["identifiability"]["dropped"] if d["reason"] == "undetermined"]
    assert held["parameter"] == f"{bend}.stiffness_2"
    (other,) = held["confounded_with"]
    assert other["parameter"] == "compliance(elbow_joint)" and other["correlation"] > 0.9
    assert f"compliance(elbow_joint) (correlation {other['correlation']:.3f})" in held["note"]


def test_a_pose_parameter_held_beside_the_elbow_spring_names_it():
    """UR5 pose campaign (30 poses, two markers, 20 um, seed 0), joint_compliance and
    nonlinear_joint_stiffness forced: the elbow's nonlinear compliance is held as undetermined,
    and its reason (as data, :attr:`Held.confounded_with`, and in the note and --json) says it
    is not told apart from the elbow's compliance, correlation -0.971 measured."""
    from stiffness.calibration.pose_diagnose import diagnose_poses

    robot = load_robot("ur5", frame="tool0")
    markers = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05])),
               Marker("elbow", "forearm_link", np.array([0.0, 0.05, 0.2]))]
    rng = np.random.default_rng(0)
    hidden = HiddenPoseErrors(pin.exp3(rng.normal(size=3)), rng.uniform(-2, 2, 3),
                              np.array([m.offset for m in markers]) + rng.normal(0, 2e-3, (2, 3)),
                              np.zeros(6), np.zeros((6, 6)),
                              np.array([3e5, np.inf, 1.2e5, 4e4, 3e4, 3e4]))
    campaign = simulate_pose_campaign(robot, markers, hidden, 30, 20e-6, seed=0)
    found = diagnose_poses(campaign, families=["joint_compliance", "nonlinear_joint_stiffness"],
                           max_steps=0)
    labels = [p.label for p in found.final.model.parameters]
    (held,) = [d for d in found.final.identifiability.dropped
               if d.held is not None and d.held.confounded_with]
    assert labels[held.index] == "elbow_joint nonlinear compliance"
    ((other, r),) = held.held.confounded_with
    assert other == "elbow_joint compliance" and -1.0 <= r < -0.9
    (said,) = [d for d in found.to_dict()["identifiability"]["dropped"]
               if d["confounded_with"]]
    assert said["confounded_with"] == [{"parameter": other, "correlation": round(r, 3)}]
    assert f"not told apart from {other} (correlation {r:.3f}), which takes" in said["note"]


def test_a_merge_reads_as_what_the_merged_parameter_does():
    """FIGAROH's TIAGo printed "torso_lift_joint ...: merged: absorbed as -185 x frame z", read
    as the compliance being -185 frame heights; its column is -185 times the frame height's
    (the coefficient in SI, N: the weight the lift carries), so it acts as -185 x frame z."""
    d = Dropped(0, "merged", ((1, -185.0), (2, 1.96)))
    assert d.describe(["torso_lift_joint compliance", "frame z", "frame y"]) == (
        "merged: acts on the data as -185 x frame z + 1.96 x frame y (SI units, per unit of it)")


def test_a_merge_through_a_held_column_says_it_is_not_fitted():
    """FIGAROH's TALOS left arm (18 poses, geometry): arm_left_4_joint placement y was
    reported 'merged: acts on the data as -504 x arm_left_4_joint placement z + 504 x
    arm_left_3_joint placement z', the first then held as undetermined: the combination is not
    fitted and neither is it. Columns a, b and c = 2 a - b (random, 20 rows): one merges into
    the two kept with the coefficients least squares gives (the independent computation); one
    of those held, the merged one's clause names it and says it is held at its nominal value,
    JSON through_held."""
    from stiffness.calibration.identifiability import reduce_columns
    from stiffness.elastic.effects.base import Held

    rng = np.random.default_rng(4)
    a, b = rng.normal(size=20), rng.normal(size=20)
    columns = np.column_stack([a, b, 2 * a - b])
    ident = reduce_columns(columns, [[0, 1, 2]], np.ones(3))
    (merged,) = ident.dropped
    kept = sorted(ident.kept)
    coefficients, *_ = np.linalg.lstsq(columns[:, kept], columns[:, merged.index], rcond=None)
    expected = dict(zip(kept, coefficients, strict=True))
    assert dict(merged.merged_into) == pytest.approx(expected, abs=1e-9)
    labels = ["a", "b", "c"]
    assert merged.describe(labels).startswith("merged: acts on the data as")
    held = ident.holding({kept[0]: Held("held at its nominal value: the data do not "
                                        "determine it")})
    clause = held.dropped_at(merged.index).describe(labels)
    assert "acts on the data" not in clause
    assert f"with {labels[kept[0]]}, held at its nominal value" in clause
    assert clause.endswith("not fitted, held at its nominal value too")
    entry = next(d for d in held.to_dict(labels)["dropped"]
                 if d["parameter"] == labels[merged.index])
    assert entry["through_held"] == [labels[kept[0]]]


def _near_collinear(rng, rows=40, sine=1e-3):
    """Columns a, b (b = a turned by ``sine`` rad: two placements nearly alike, both kept)
    and g, random."""
    a, g, n = rng.normal(size=(3, rows))
    n -= a * (a @ n) / (a @ a)
    b = a + sine * np.linalg.norm(a) * n / np.linalg.norm(n)
    return a, b, g


def test_a_merge_through_a_held_column_is_re_expressed_over_the_fitted_ones():
    """Placements a and b nearly alike (b is a turned by 1e-3 rad), g another, and a later
    group's c = g + 0.5 b (merged: 1 x g + 0.5 x b). Once b is held as undetermined the
    fitted a and g carry c but for 0.5 x the part of b they miss (the data do not determine
    that part of b at its typical size, so neither that of c): the merge is re-expressed
    over a and g, its coefficients those of c regressed on a and g alone (least squares on
    the full columns), not 'not fitted'. With c = g + 504 b - 503.5 a (near-cancelling
    coefficients, the TALOS left arm's) the part of c a and g miss is 504 x b's: no
    expression over the fitted ones; the clause says it is not fitted and the +-504 are
    reported as they are."""
    rng = np.random.default_rng(7)
    a, b, g = _near_collinear(rng)
    labels = ["a", "b", "g", "c"]
    why = Held("held at its nominal value: the data do not determine it")
    columns = np.column_stack([a, b, g, g + 0.5 * b])
    ident = reduce_columns(columns, [[0, 1, 2], [3]], np.ones(4))
    assert sorted(ident.kept) == [0, 1, 2]
    assert dict(ident.dropped_at(3).merged_into) == pytest.approx({2: 1.0, 1: 0.5}, abs=1e-6)
    merged = ident.holding({1: why}).dropped_at(3)
    expected, *_ = np.linalg.lstsq(columns[:, [0, 2]], columns[:, 3], rcond=None)
    assert dict(merged.merged_into) == pytest.approx({0: expected[0], 2: expected[1]},
                                                     abs=1e-9)
    assert expected[0] == pytest.approx(0.5, abs=1e-2) and merged.through_held == ()
    assert merged.describe(labels).startswith("merged: acts on the data as 1 x g + 0.5 x a")
    entry = ident.holding({1: why}).to_dict(labels)["dropped"][0]
    assert entry["parameter"] == "c" and entry["through_held"] == []

    columns[:, 3] = g + 504.0 * b - 503.5 * a
    ident = reduce_columns(columns, [[0, 1, 2], [3]], np.ones(4))
    assert dict(ident.dropped_at(3).merged_into) == pytest.approx(
        {1: 504.0, 0: -503.5, 2: 1.0}, rel=1e-6)
    for hold in (0, 1):
        merged = ident.holding({hold: why}).dropped_at(3)
        assert merged.through_held == (hold,)
        assert merged.describe(labels).startswith(
            f"merged into a combination (504 x b + -503 x a + 1 x g) with {labels[hold]}")
