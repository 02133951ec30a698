"""The "unexplained" verdict of stiffness diagnose: campaigns with an effect outside the library
end with ``"unexplained": true`` and no library effect named; campaigns with nothing hidden
come back empty. Rates over seeds against binomial bounds."""

from __future__ import annotations

import dataclasses
import html
import math
import re

import numpy as np
import pytest
from scipy.stats import binom

from stiffness.calibration.breakdown import correlation
from stiffness.calibration.diagnose import diagnose
from stiffness.calibration.diagnosis_page import render_diagnosis
from stiffness.calibration.diagnosis_report import format_report
from stiffness.calibration.selection import fit_baseline, fit_model
from stiffness.elastic.effects import candidates
from stiffness.elastic.effects.geometry import Geometry, References
from stiffness.elastic.effects.hypothesis import Hypothesis
from stiffness.planning.simulate import parse_effect, simulate
from stiffness.provenance import provenance

NOISE = 5e-6
UR5 = {"kq": [3e4, 2e4, 1.5e4],
       "compliant_joints": ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"],
       "target_offset_m": [0.0, 0.0, 0.1], "max_force": 100.0}
SEEDS = range(5)
#: Size of the out-of-library effects, RMS over the deflection components, in noise std.
SIZE = 3.0


def temperature_drift(campaign, rng: np.random.Generator) -> np.ndarray:
    """The tracker's reference drifts linearly in time (the row order) along a random
    direction, zero at mid-campaign: a load-independent error no library effect models."""
    m = campaign.n_rows
    t = np.arange(m) / (m - 1) - 0.5
    u = rng.normal(size=3)
    u /= np.linalg.norm(u)
    d = t[:, None] * u
    return d * SIZE * NOISE / math.sqrt(np.mean(d ** 2))


def rezeroing_error(campaign, rng: np.random.Generator) -> np.ndarray:
    """Each configuration's unloaded reference is measured once, with its own error: an
    offset per configuration, random and zero-mean over the campaign."""
    labels = list(dict.fromkeys(campaign.config))
    offsets = rng.normal(size=(len(labels), 3))
    offsets -= offsets.mean(axis=0)
    d = offsets[[labels.index(c) for c in campaign.config]]
    return d * SIZE * NOISE / math.sqrt(np.mean(d ** 2))


OUT_OF_LIBRARY = {"temperature_drift": temperature_drift, "rezeroing_error": rezeroing_error}


def _campaign(seed: int, extra=None):
    sim = simulate("ur5", effects=[], configs=8, loads_per_config=4, noise_std_m=NOISE,
                   seed=seed, **UR5)
    camp = sim.campaign
    if extra is None:
        return camp
    added = extra(camp, np.random.default_rng(1000 + seed))
    return dataclasses.replace(camp, deflection=camp.deflection + added)


@pytest.mark.parametrize("name", list(OUT_OF_LIBRARY))
def test_the_test_effect_is_outside_the_library(name):
    """Design notes: an out-of-library effect must be nearly orthogonal to every library
    signature. Fitted alone (noise-free), no library extension removes more than 20 % of its
    RMS."""
    sim = simulate("ur5", effects=[], configs=8, loads_per_config=4, noise_std_m=0.0, seed=0,
                   **UR5)
    camp = sim.campaign
    added = OUT_OF_LIBRARY[name](camp, np.random.default_rng(1000))
    measured = sim.campaign.deflection + added
    geo = Geometry.of(camp.robot())
    rows = geo.rows(camp.q, camp.force)
    refs = References.of(geo, rows, 1e5, measured)
    model = Hypothesis(geo, rows, camp.baseline, tuple(UR5["compliant_joints"]), (), refs)
    base = fit_baseline(model, measured, NOISE)
    assert base.rms() > 0.9 * SIZE * NOISE
    for effect in candidates(base.model):
        f = fit_model(base.model.extended(effect), measured, NOISE,
                      base.model.extend_x(base.x, effect))
        assert f.rms() > 0.8 * base.rms(), effect.label


def test_out_of_library_is_unexplained_and_names_nothing():
    runs = []
    for name, extra in OUT_OF_LIBRARY.items():
        for seed in SEEDS:
            r = diagnose(_campaign(seed, extra), propose=False)
            s = r.summary()
            runs.append((name, seed, s["unexplained"] is True and s["missing_effects"] == [],
                         r))
    ok = sum(run[2] for run in runs)
    # measured 107/120 over three robots, 20 seeds each (docs/diagnose.md): fewer successes
    # than the 1 % quantile of Binomial(n, 0.892) fails
    assert ok >= binom.ppf(0.01, len(runs), 107 / 120), [
        (n, s, x.summary()["missing_effects"]) for n, s, good, x in runs if not good]
    # the report says where to look: the drift shows in the row order
    drift = next(x for n, _, good, x in runs if n == "temperature_drift" and good)
    structure = drift.record()["where_final_disagrees"]
    corr = structure["correlation"]
    assert corr["row_order"]["r2"] > 0.5 and corr["row_order"]["p_value"] < 1e-6
    assert set(corr["joint_torque"]) == set(corr["joint_angle"]) == set(drift.geometry.joints)
    assert {"by_configuration", "by_axis", "by_load_magnitude", "by_load_direction",
            "by_row_order"} <= set(structure)
    text = format_report(drift)
    assert "UNEXPLAINED" in text and "row order: R2" in text
    # eight configurations: the folds determine the model, no note on them
    assert "too few configurations" not in text
    # the intervals printed above the verdict say they take the model as complete
    assert "too narrow while it misses something" in text.split("UNEXPLAINED")[0]
    full = drift.record()
    assert full["unexplained"] is True and full["missing_effects"] == []
    notes = drift.model_file().to_dict()
    assert notes["unexplained"] is True and "library does not model" in notes[
        "unexplained_note"]
    page = render_diagnosis(full, None, provenance("test"))
    visible = html.unescape(re.sub(r"<(script|style)[^>]*>.*?</\1>|<[^>]+>", " ", page,
                                   flags=re.S))
    assert "id='left'" in page and "torque of shoulder_pan_joint" in visible
    assert "angle of wrist_3_joint" in visible and "rows 1 to 8" in visible
    assert '{"' not in visible and "': " not in visible


def test_nothing_hidden_comes_back_empty():
    runs = [diagnose(_campaign(seed), propose=False) for seed in SEEDS]
    empty = sum(r.summary()["missing_effects"] == [] and r.summary()["unexplained"] is False
                for r in runs)
    # measured on the UR5 38/45 (16/20 of the script's seeds 400-419, 22/25 of this test's
    # seeds 0-24; 53/60 over three robots, docs/diagnose.md): the exact equilibrium's terms
    # beyond the first-order baseline (0.16-0.37 noise std RMS) are real content that
    # complementary_stiffness or a one-parameter effect can take; the 1 % quantile of
    # Bin(n, 38/45)
    assert empty >= binom.ppf(0.01, len(runs), 38 / 45), [
        r.summary()["missing_effects"] for r in runs]
    # a model explained to noise has intervals to sign: no caveat on them
    assert all("too narrow while" not in format_report(r) for r in runs
               if r.summary()["unexplained"] is False)


def test_library_effect_with_an_unexplained_rest():
    """A library effect plus the drift: the library effect is named, the rest is
    unexplained."""
    sim = simulate("ur5", effects=[parse_effect("force_sensor_bias=5")], configs=8,
                   loads_per_config=4, noise_std_m=NOISE, seed=3, **UR5)
    camp = sim.campaign
    camp = dataclasses.replace(camp, deflection=camp.deflection + temperature_drift(
        camp, np.random.default_rng(3)))
    s = diagnose(camp, propose=False).summary()
    assert s["missing_effects"] == ["force_sensor_bias"], s
    assert s["unexplained"] is True


def test_correlation_against_a_closed_form():
    """A residual that is exactly a line in the variable along one axis: R2 = 1, r = +-1 on
    that axis; independent noise: E[r_k^2] = 1/(m - 1), so R2 is 1/49 on average."""
    rng = np.random.default_rng(0)
    v = rng.normal(size=50)
    res = np.zeros((50, 3))
    res[:, 1] = -2e-6 * v
    c = correlation(v, res, NOISE, 1e-3)
    assert c["r2"] == pytest.approx(1.0) and c["r"][1] == pytest.approx(-1.0)
    assert c["explained_ratio"] == pytest.approx(
        math.sqrt(np.sum((res[:, 1] - res[:, 1].mean()) ** 2) / res.size) / NOISE)
    r2 = [correlation(rng.normal(size=50), rng.normal(size=(50, 3)), 1.0, 1.0)["r2"]
          for _ in range(200)]
    assert np.mean(r2) == pytest.approx(1 / 49, rel=0.2)
    assert correlation(np.ones(50), res, NOISE, 1e-3)["r2"] is None


def test_too_few_configurations_for_the_cross_validation_is_said():
    """Two configurations x 3 loads, replicated, a 15 mm target offset hidden (4.3 noise std
    RMS): each fold fits one configuration, the baseline's held-out RMS is 31 times its fit's,
    so no effect passes cross-validation and the verdict is unexplained; its note says the
    folds are too few to confirm a library effect, rather than only that the library lacks
    it."""
    sim = simulate("ur5", kq=[2e4, 2e4, 1e4, 3e3, 3e3, 3e3], configs=2, loads_per_config=3,
                   repeats=2, declare_noise=False, effects=["target_offset=15"],
                   noise_std_m=1e-5, seed=5)
    r = diagnose(sim.campaign, propose=False)
    assert r.unexplained is True and r.missing_effects == [], format_report(r)
    assert r.cv_baseline > 5 * r.baseline.rms()
    assert "too few configurations for the cross-validation" in r.unexplained_note
    assert "on 2 configuration(s)" in r.unexplained_note
    # the noise is the replicates', not declared: no reading of an understated declared noise
    assert r.noise_std_source == "replicates" and "understates" not in r.unexplained_note
