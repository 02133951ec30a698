"""``stiffness validate`` with the model's parameter uncertainty: the residual on the campaign's
seen components has covariance ``sigma^2 I + J Sigma J^T`` (``Sigma`` the fitted parameters'
covariance the model file carries, ``parameter_covariance``; ``J`` the prediction's derivative
with respect to them there), and the test ``r^T (sigma^2 I + J Sigma J^T)^-1 r ~ chi2(N)``
calls a right model from a small campaign "above the noise" at its level, where the noise-only
test did far more often (311 times in 400 here)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

import stiffness
from stiffness.calibration.campaign import load_campaign
from stiffness.calibration.validation import (
    NOISE_ONLY,
    WITH_PARAMETERS,
    ParameterTerm,
    prediction_chi2,
)
from stiffness.calibration.validation_page import format_validation
from stiffness.cli.main import main
from stiffness.elastic.effects.base import Parameter
from stiffness.elastic.effects.geometry import Geometry, References
from stiffness.elastic.effects.hypothesis import Hypothesis
from stiffness.elastic.file_model import fitted_prediction
from stiffness.elastic.model_contents import ModelEffect, ModelFile
from stiffness.elastic.model_file import read_model_file
from stiffness.elastic.parameter_covariance import KEY, ParameterCovariance
from stiffness.robot.robot import load_robot

ARM = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint")
K = np.array([3e4, 2e4, 1.5e4])  # N.m/rad
NOISE = 5e-6  # m
SEEDS = 400
LEVEL = 0.05
FORCE = 60.0  # N, each component of a row's force (std)


def _rows(geo: Geometry, rng: np.random.Generator, configs: int, loads: int) -> Hypothesis:
    """The UR5 arm's three springs over ``configs`` x ``loads`` random rows (60 N forces)."""
    q = np.repeat(rng.uniform(-1.5, 1.5, (configs, 6)), loads, axis=0)
    rows = geo.rows(q, rng.normal(size=(configs * loads, 3)) * FORCE)
    return Hypothesis(geo, rows, "enhanced", ARM, (),
                      References.of(geo, rows, 1e5, np.full((1, 3), 1e-3)))


def _fit(model: Hypothesis, measured: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least squares of ``model`` on ``measured`` by Gauss-Newton from ``x`` (the model is
    nearly linear in ln k: four steps reach round-off) and its covariance
    ``sigma^2 (J^T J)^-1``, the fit's (identify's, the file's) for a declared noise."""
    for _ in range(4):
        pred, jac = model.predict_with_jacobian(x)
        j = jac.reshape(-1, x.size)
        x = x + np.linalg.lstsq(j, (measured - pred).reshape(-1), rcond=None)[0]
    j = model.predict_with_jacobian(x)[1].reshape(-1, x.size)
    return x, NOISE ** 2 * np.linalg.inv(j.T @ j)


@pytest.fixture(scope="module")
def rates():
    """Over SEEDS seeds: a right model fitted on 4 rows (12 components, 3 springs) judged on a
    fresh 12-row campaign (36 components) of the same truth, the truth the model's own (so
    only the noise and the fit's uncertainty are in the residual); and the same model with
    its shoulder_lift spring 30 % stiffer. Returns the counts of "above the noise" at 5 %:
    noise-only test, with the parameters, the wrong spring with the parameters; and the
    wrong spring's distance from the fit in standard errors of its ln k (the smallest)."""
    geo = Geometry.of(load_robot("ur5", compliant_joints=ARM))
    rng = np.random.default_rng(7)
    fit_on, judge_on = _rows(geo, rng, 2, 2), _rows(geo, rng, 4, 3)
    x_true = np.log(K)
    truth_fit, truth_judge = fit_on.predict(x_true), judge_on.predict(x_true)
    old = new = wrong = 0
    distance = np.inf
    for seed in range(SEEDS):
        noise = np.random.default_rng(1000 + seed)
        x, cov = _fit(fit_on, truth_fit + noise.normal(size=truth_fit.shape) * NOISE, x_true)
        measured = truth_judge + noise.normal(size=truth_judge.shape) * NOISE
        n = measured.size
        for shift, right in ((0.0, True), (np.log(1.3), False)):
            y = x + np.array([0.0, shift, 0.0])
            pred, jac = judge_on.predict_with_jacobian(y)
            r = (measured - pred).reshape(-1)
            above = stats.chi2.sf(prediction_chi2(r, jac.reshape(n, -1), cov, NOISE), n) <= LEVEL
            if right:
                old += stats.chi2.sf(r @ r / NOISE ** 2, n) <= LEVEL
                new += above
            else:
                wrong += above
                distance = min(distance, shift / np.sqrt(cov[1, 1]))
    return int(old), int(new), int(wrong), float(distance)


def test_a_right_model_from_a_small_campaign_is_above_the_noise_at_the_level(rates):
    """A right model fitted on 12 components, judged on 36 fresh ones, 400 seeds: the test
    with ``sigma^2 I + J Sigma J^T`` says "above the noise" 11 times (0.028), within the
    two-sided binomial 99 % interval around 0.05 (10 to 32 of 400; these seeds' validation
    noise alone, without any fit, is above its chi2(36) 13 times: a low draw, and over 1500
    seeds the new test's chi-square has mean 35.8 and variance 68.5, chi2(36)'s 36 and 72);
    the noise-only test 311 times (0.78), far above it (this design's fit error on the
    validation rows is as large as the noise there)."""
    old, new, _, _ = rates
    low, high = stats.binom.interval(0.99, SEEDS, LEVEL)
    assert low <= new <= high, (new, old)
    assert old > high + 20, (old, new)


def test_a_wrong_spring_is_still_rejected(rates):
    """The same models with the shoulder_lift spring 30 % stiffer (at least 62 standard
    errors of its ln k from the fit, far beyond its interval): the test with the parameters'
    uncertainty rejects it on at least 95 % of the seeds (400 of 400 measured)."""
    _, _, wrong, distance = rates
    assert distance > 1.96
    assert wrong >= 0.95 * SEEDS, wrong


def test_prediction_chi2_is_the_quadratic_form():
    """Woodbury's k x k form equals ``r^T (sigma^2 I + J Sigma J^T)^-1 r`` solved in N x N,
    for a singular ``Sigma`` too (a zero direction)."""
    rng = np.random.default_rng(3)
    r, j = rng.normal(size=20), rng.normal(size=(20, 4))
    a = rng.normal(size=(4, 3))
    for cov in (a @ a.T, np.diag([2.0, 0.0, 1.0, 0.5])):
        full = r @ np.linalg.solve(0.7 ** 2 * np.eye(20) + j @ cov @ j.T, r)
        assert prediction_chi2(r, j, cov, 0.7) == pytest.approx(full, rel=1e-10)


@pytest.fixture(scope="module")
def ur5(tmp_path_factory):
    """A small UR5 campaign (2 x 2 rows) identified (its model file written), and a fresh
    one (4 x 3 rows) of the same springs."""
    root = tmp_path_factory.mktemp("uncertainty")
    for seed, configs, loads in ((1, 2, 2), (2, 4, 3)):
        stiffness.simulate("ur5", kq=K, compliant_joints=list(ARM), configs=configs,
                           loads_per_config=loads, max_force=100.0, noise_std_m=NOISE,
                           seed=seed).write(root / f"c{seed}")
    assert main(["identify", str(root / "c1"), "--out", str(root / "model.json"),
                 "--quiet"]) == 0
    return root


def test_the_identified_model_file_carries_its_covariance(ur5):
    """identify writes ``parameter_covariance``: ln k of each spring, its variances those of
    the file's standard errors (``se_k = k sd(ln k)``), for the noise the file states."""
    doc = json.loads((ur5 / "model.json").read_text())
    cov = doc[KEY]
    assert cov["labels"] == [f"ln k_theta({j})" for j in ARM] and cov["units"] == ["1"] * 3
    sd = np.sqrt(np.diag(cov["matrix"]))
    np.testing.assert_allclose(sd * doc["k_theta"]["values"], doc["k_theta"]["standard_error"],
                               rtol=1e-9)
    assert cov["noise_std_m"] == doc["noise"]["std_m"] == NOISE


def test_the_parameter_term_is_the_finite_differences_of_the_prediction(ur5):
    """``J Sigma J^T`` of ``validate`` equals that of the derivatives of the model's
    prediction (``load_model(file).deflection`` row by row, batched) by central differences
    of the file's ``k_theta`` in ``ln k`` to 1e-6; the new chi-square is the quadratic form
    with it; the JSON and the text say which test the verdict is."""
    result = stiffness.validate(ur5 / "model.json", ur5 / "c2")
    campaign = load_campaign(ur5 / "c2")
    file = read_model_file(ur5 / "model.json")
    wrench = np.hstack([campaign.force, np.zeros_like(campaign.force) if campaign.moment is None
                        else campaign.moment])
    mm = campaign.units.length_to_si

    def predicted(k: np.ndarray) -> np.ndarray:
        moved = dataclasses.replace(file, k_theta=k)
        return fitted_prediction(moved, campaign.q, wrench)[0].reshape(-1) / mm

    model = stiffness.load_model(file)  # the batched prediction is the model's, row by row
    np.testing.assert_allclose(predicted(file.k_theta) * mm, np.array([
        model.deflection(q, w, measured=True) for q, w in zip(campaign.q, wrench, strict=True)
    ]).reshape(-1), rtol=1e-12, atol=1e-18)

    h = 1e-5
    fd = np.column_stack([(predicted(file.k_theta * np.exp(h * e))
                           - predicted(file.k_theta * np.exp(-h * e))) / (2 * h)
                          for e in np.eye(3)])
    term = result.parameters
    assert term is not None and term.labels == tuple(f"ln k_theta({j})" for j in ARM)
    expected = fd @ file.covariance.matrix @ fd.T
    np.testing.assert_allclose(term.jacobian @ term.covariance @ term.jacobian.T, expected,
                               rtol=1e-6, atol=1e-6 * np.abs(expected).max())
    r = (campaign.deflection.reshape(-1) - predicted(file.k_theta) * mm) / mm
    sigma = NOISE / mm
    assert result.chi2_with_parameters == pytest.approx(
        r @ np.linalg.solve(sigma ** 2 * np.eye(r.size) + expected, r), rel=1e-6)
    out = result.to_dict()
    assert out["verdict_test"] == WITH_PARAMETERS and out["parameter_uncertainty"]["included"]
    assert out["gof_p_with_parameters"] == pytest.approx(stats.chi2.sf(
        out["chi2_with_parameters"], out["dof"]), rel=1e-9)
    assert out["chi2"] == pytest.approx(r @ r / sigma ** 2, rel=1e-6)  # the noise-only test
    assert "chi-square with the model's parameter uncertainty" in format_validation(out)


def test_a_model_file_without_its_covariance_still_validates(ur5, tmp_path):
    """A file written before ``parameter_covariance`` (the key removed): the verdict is the
    noise-only test's, as before, and the text says the parameters' uncertainty is not
    included."""
    doc = json.loads((ur5 / "model.json").read_text())
    del doc[KEY]
    (tmp_path / "old.json").write_text(json.dumps(doc))
    result = stiffness.validate(tmp_path / "old.json", ur5 / "c2")
    out = result.to_dict()
    assert result.parameters is None and out["verdict_test"] == NOISE_ONLY
    assert out["chi2_with_parameters"] is None and out["gof_p_with_parameters"] is None
    assert out["verdict"] == ("above the noise" if out["gof_p"] <= LEVEL
                              else "consistent with the noise")
    assert "its parameters' uncertainty is not included" in format_validation(out)


def _parameter(name: str, value: float, unit: str) -> Parameter:
    return Parameter(name, value, 0.0, (value, value), unit)


def test_the_jacobian_in_every_kind_of_file_variable():
    """A model file with effects of every kind of variable (a joint spring's and a link
    bend's compliances 1/value, a backlash's half width, a frame misalignment's and a force
    bias's values: analytic and finite-difference columns): ``fitted_prediction``'s
    derivatives equal central differences of its prediction (``load_model(file).deflection``
    row by row, batched) in those variables, the file's values changed (1e-5 relative), to
    1e-5 of the largest."""
    effects = (
        ModelEffect("joint_compliance", "wrist_1_joint", "stiffness",
                    [_parameter("stiffness", 5e3, "N.m/rad")]),
        ModelEffect("backlash", "shoulder_lift_joint", "lost_motion",
                    [_parameter("half_width", 2e-4, "rad")], {"smoothing_torque": 2.0}),
        ModelEffect("link_compliance", "shoulder_lift_joint->elbow_joint", "stiffness",
                    [_parameter("stiffness_1", 4e4, "N.m/rad"),
                     _parameter("stiffness_2", 6e4, "N.m/rad")]),
        ModelEffect("frame_misalignment", None, "measurement",
                    [_parameter("rx", 0.01, "rad"), _parameter("ry", -0.02, "rad"),
                     _parameter("rz", 0.005, "rad")]),
        ModelEffect("force_sensor_bias", None, "measurement",
                    [_parameter("fx", 1.0, "N"), _parameter("fy", -2.0, "N"),
                     _parameter("fz", 0.5, "N")]))
    file = ModelFile(source="ur5", frame="tool0", target_offset_m=np.zeros(3),
                     compliant_joints=ARM, k_theta=K, units=("N.m/rad",) * 3,
                     formulation="enhanced", effects=effects)
    rng = np.random.default_rng(5)
    q = rng.uniform(-1.5, 1.5, (4, 6))
    wrench = np.hstack([rng.normal(size=(4, 3)) * 100.0, rng.normal(size=(4, 3)) * 5.0])
    pred, jac, labels = fitted_prediction(file, q, wrench)
    model = stiffness.load_model(file)  # the model's prediction, row by row
    np.testing.assert_allclose(pred, [model.deflection(a, w, measured=True)
                                      for a, w in zip(q, wrench, strict=True)],
                               rtol=1e-12, atol=1e-18)
    variables = [("k", i, "log") for i in range(3)] + [
        (e, i, "inverse" if e < 3 and e != 1 else "value")
        for e, effect in enumerate(effects) for i in range(len(effect.parameters))]
    assert len(labels) == len(variables) == jac.shape[2] == 13
    assert labels[3] == "1/joint_compliance(wrist_1_joint).stiffness"

    def moved(where, i, kind, h):
        if where == "k":
            k = file.k_theta.copy()
            k[i] *= np.exp(h)
            return dataclasses.replace(file, k_theta=k)
        params = list(effects[where].parameters)
        v = params[i].value
        params[i] = dataclasses.replace(params[i], value=1 / (1 / v + h * abs(1 / v))
                                        if kind == "inverse" else v + h * max(abs(v), 1.0))
        return dataclasses.replace(file, effects=tuple(
            dataclasses.replace(e, parameters=params) if n == where else e
            for n, e in enumerate(effects)))

    for column, (where, i, kind) in enumerate(variables):
        h = 1e-5
        step = (1.0 if where == "k" else abs(1 / effects[where].parameters[i].value)
                if kind == "inverse" else max(abs(effects[where].parameters[i].value), 1.0))
        sides = [fitted_prediction(moved(where, i, kind, s * h), q, wrench)[0]
                 for s in (1, -1)]
        fd = (sides[0] - sides[1]) / (2 * h * step)
        np.testing.assert_allclose(jac[:, :, column], fd, rtol=0,
                                   atol=1e-5 * np.abs(fd).max() + 1e-18, err_msg=labels[column])


def test_a_variable_the_fit_did_not_determine_is_taken_as_known():
    """A null row (a held parameter: infinite variance) is left out of the term and named."""
    cov = ParameterCovariance(("a", "b", "c"), ("1",) * 3,
                              np.array([[1.0, np.inf, 0.5], [np.inf] * 3, [0.5, np.inf, 2.0]]))
    matrix, used, left = cov.over(["c", "b", "a", "d"])
    assert used == [0, 2] and left == ["b", "d"]
    np.testing.assert_array_equal(matrix, [[2.0, 0.5], [0.5, 1.0]])
    term = ParameterTerm.of(cov, np.ones(2), np.ones((2, 4)), ["c", "b", "a", "d"], 1.0)
    assert term is not None and term.left_out == ("b", "d") and term.labels == ("c", "a")


finite = st.floats(-1e12, 1e12, allow_nan=False, allow_infinity=False, width=64)


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 5).flatmap(lambda n: st.tuples(
    st.lists(st.lists(finite, min_size=n, max_size=n), min_size=n, max_size=n),
    st.lists(st.booleans(), min_size=n, max_size=n))))
def test_the_model_file_round_trips_its_covariance_exactly(tmp_path_factory, case):
    """Any covariance (held rows infinite) written with the model file reads back bit for
    bit, labels and units too."""
    values, held = case
    n = len(held)
    matrix = np.array(values, dtype=float)
    matrix[np.array(held), :] = np.inf
    matrix[:, np.array(held)] = np.inf
    cov = ParameterCovariance(tuple(f"ln k_theta(j{i})" for i in range(n)), ("1",) * n,
                              matrix, 1e-6)
    file = ModelFile(source="ur5", frame="tool0", target_offset_m=np.zeros(3),
                     compliant_joints=tuple(f"j{i}" for i in range(n)), k_theta=np.ones(n),
                     units=("N.m/rad",) * n, formulation="enhanced", covariance=cov)
    path = file.write(tmp_path_factory.mktemp("round") / "m.json")
    back = read_model_file(path).covariance
    assert back is not None and back.labels == cov.labels and back.units == cov.units
    np.testing.assert_array_equal(back.matrix, matrix)
    assert back.noise_std_m == 1e-6 and back.variables == cov.variables
