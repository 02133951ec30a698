"""A force, moment, deflection or rotation column with its sign reversed is named
(stiffness.calibration.sign_checks): identify's fit then misses the data by tens of noise stds,
and the note said only "model error or underestimated noise"."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import stiffness
from stiffness.calibration.deflection_noise import (
    fit_options,
    residual_scale,
    translation_noise,
    weighted_observations,
)
from stiffness.calibration.fitting import fit_model
from stiffness.calibration.identify import PAPER_START_SI, stiffness_model
from stiffness.calibration.sign_checks import baseline_builder, fits_note, flipped_column_note
from stiffness.elastic.effects.geometry import Geometry
from stiffness.mechanics.equilibrium import solve_equilibrium

ARM = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"]
K = [3e4, 2e4, 1.5e4]  # N.m/rad
UR5 = {"kq": K, "compliant_joints": ARM, "configs": 6, "loads_per_config": 3,
       "noise_std_m": 1e-5}
SK120_DH = Path(__file__).resolve().parents[1] / "examples" / "sk120-dh" / "robot.toml"


@pytest.fixture(scope="module")
def clean():
    """A UR5 campaign of 6 configurations x 3 loads at 10 um, the noise declared."""
    return stiffness.simulate("ur5", kq=K, compliant_joints=ARM, configs=6, loads_per_config=3,
                              noise_std_m=1e-5, seed=1).campaign


def _flipped(campaign, array: str, j: int):
    values = getattr(campaign, array).copy()
    values[:, j] *= -1.0
    return replace(campaign, **{array: values})


def _sign_notes(result) -> list[str]:
    return [n for n in result.notes if "sign of column" in n]


@pytest.mark.parametrize("array, j, name", [("force", 0, "fx"), ("deflection", 1, "dy")])
def test_a_reversed_column_is_named(clean, array, j, name):
    """fx negated (two of the three springs went to the rigid bound, RMS 40x the noise) and
    dy negated: the note names the column, the residual with it reversed back at the noise
    (the campaign's own fit: RMS 0.90x)."""
    result = stiffness.identify(_flipped(clean, array, j), starts=2)
    said = _sign_notes(result)
    assert len(said) == 1, result.notes
    assert f"with the sign of column {name} reversed the residuals fall " in said[0]
    gain = float(said[0].split(" times ")[0].rsplit(" ", 1)[1])
    assert gain > 100  # 1.96e3 (fx), 1.68e3 (dy)
    assert f"{name} looks written with the opposite sign" in said[0]
    ratio = float(said[0].split("x the noise")[0].rsplit(", ", 1)[1])
    assert 0.5 < ratio < 1.5, said[0]


def test_a_clean_campaign_and_a_missed_effect_name_no_column(clean):
    """The clean campaign fits to noise (no check); one with a force sensor bias of 5 N on x
    (a model error no sign explains, RMS 4x the noise) is not blamed on a column either."""
    assert _sign_notes(stiffness.identify(clean, starts=2)) == []
    biased = replace(clean, force=clean.force + np.array([5.0, 0.0, 0.0]))
    result = stiffness.identify(biased, starts=2)
    assert any("larger than the declared noise_std" in n for n in result.notes), result.notes
    assert _sign_notes(result) == []


def test_diagnose_names_the_reversed_column_in_its_verdict(clean):
    """diagnose's verdict on fx negated said UNEXPLAINED, 'the data contain something the
    library does not model' (no reflection is in it); it now ends with the same note as
    identify's, and --json has it as flipped_column. A clean campaign has no such key."""
    found = stiffness.diagnose(_flipped(clean, "force", 0), max_steps=0)
    d = found.to_dict()
    assert d["unexplained"] is True
    assert d["flipped_column"].startswith("with the sign of column fx reversed the residuals "
                                          "fall ")
    assert found.unexplained_note.endswith("; " + d["flipped_column"])
    assert "flipped_column" not in stiffness.diagnose(clean, max_steps=0).to_dict()


def test_a_fit_without_residual_freedom_is_not_checked(clean):
    """One row of three components for three springs, the noise declared: no chi-square
    (p_value None). The check's condition compared None with the level: a TypeError
    traceback from identify on a one-row campaign (found by the rig-data sweep)."""
    one = replace(clean, q=clean.q[:1], force=clean.force[:1], deflection=clean.deflection[:1],
                  config=clean.config[:1], lines=None)
    result = stiffness.identify(one, starts=1)
    assert result.fits_to_noise["p_value"] is None and _sign_notes(result) == []


def _with_moments(campaign, seed: int):
    """``campaign`` (with rotations) under moments besides its forces, uniform in +-10 N.m per
    axis: its deflections and rotations recomputed from the exact equilibrium
    (:func:`solve_equilibrium`, Newton on the full kinematics, not the fitted linear model) of
    the springs ``K``, with the campaign's noise drawn again."""
    rng = np.random.default_rng(1000 + seed)
    robot = campaign.robot()
    moment = rng.uniform(-10.0, 10.0, campaign.force.shape)
    deflection, rotation = np.empty_like(moment), np.empty_like(moment)
    for i in range(campaign.n_rows):
        eq = solve_equilibrium(robot, robot.configuration(campaign.q[i]), np.diag(K),
                               np.concatenate([campaign.force[i], moment[i]]))
        deflection[i], rotation[i] = eq.dx, eq.rotation
    return replace(campaign, moment=moment,
                   deflection=deflection + rng.normal(0.0, campaign.noise_std_m, moment.shape),
                   rotation=rotation + rng.normal(0.0, campaign.rotation_noise_std_rad,
                                                  moment.shape))


def _ur5(kind: str, seed: int, effects: tuple[str, ...] = ()):
    """A UR5 campaign of 18 rows at 10 um: forces only, with measured rotations (0.1 mrad), or
    with both and applied moments (no hidden effect then)."""
    campaign = stiffness.simulate("ur5", effects=list(effects), rotations=kind != "forces",
                                  seed=seed, **UR5).campaign
    return _with_moments(campaign, seed) if kind == "moments" else campaign


def _checked(campaign) -> list[str]:
    """The check on identify's baseline fit (its model, weighting and solver options; one start
    at its paper start), run whether or not that fit misses the data."""
    model = stiffness_model(campaign, "enhanced")
    options = fit_options(len(model.compliant))
    known = translation_noise(campaign)[0]
    assert known is not None
    model, (measured, weight, _, _) = weighted_observations(
        campaign, model, residual_scale(campaign), options, known, "linear", PAPER_START_SI)
    fit = fit_model(model, measured, known.sigma,
                    np.full(len(model.compliant), math.log(PAPER_START_SI)), **options)
    return flipped_column_note(campaign, lambda c: stiffness_model(c, "enhanced"), fit.x,
                               fit.rss, known.sigma, options, weight)


HIDDEN = ((), ("backlash:shoulder_lift_joint=0.002",), ("force_sensor_bias=5",),
          ("frame_misalignment=2",))


@pytest.mark.parametrize("kind", ["forces", "rotations", "moments"])
def test_honest_campaigns_name_no_column(kind):
    """No column reversed, 12 seeds each, forces only, with rotations, with moments and
    rotations (the first two with a hidden effect in turn: none, a backlash, a 5 N force sensor
    bias, a 2 deg frame misalignment, which make the real fit miss the noise and run the check):
    the check, run on every one, names nothing. Reversing a right column raised the residual
    sum of squares in every campaign of a sweep of 3 seeds (UR5 and SK120-DH, these hidden
    effects), by 38 noise variances at least (the SK120's rotations; 600 for the others),
    where naming takes a fall of 25."""
    named = {}
    for seed in range(12):
        effects = () if kind == "moments" else HIDDEN[seed % len(HIDDEN)]
        notes = _checked(_ur5(kind, seed, effects))
        if notes:
            named[(seed, effects)] = notes
    assert named == {}


@pytest.fixture(scope="module")
def with_moments():
    """A UR5 campaign of 18 rows with rotations and moments, no column reversed."""
    return _ur5("moments", 1)


@pytest.mark.parametrize("array, j, name", [("force", 0, "fx"), ("deflection", 0, "dx"),
                                            ("moment", 0, "mx"), ("rotation", 0, "rx")])
def test_a_reversed_column_is_named_with_rotations_and_moments(with_moments, array, j, name):
    """identify on the campaign with moments and rotations, one column negated (RMS 28x, 25x,
    16x, 6.1x the noise): the note names that column, the fit with it reversed back at the
    noise; the campaign as it is has no note."""
    assert _sign_notes(stiffness.identify(with_moments, starts=2)) == []
    result = stiffness.identify(_flipped(with_moments, array, j), starts=2)
    said = _sign_notes(result)
    assert len(said) == 1, result.notes
    assert said[0].startswith(f"with the sign of column {name} reversed the residuals fall ")
    ratio = float(said[0].split("x the noise")[0].rsplit(", ", 1)[1])
    assert 0.5 < ratio < 1.5, said[0]


def test_the_sk120_scenario_with_rotations_and_a_backlash():
    """The SK120-DH campaign of `stiffness simulate --effect backlash:joint2=0.002 --rotations`
    (40 rows at 5 um) with fx negated: diagnose ended UNEXPLAINED after adding a transversal
    compliance and a force sensor bias, and no note (rotations were not checked). Its verdict
    now names fx; the fit with fx reversed back is 2.2x the noise (the backlash the baseline
    lacks), which the note says; identify's note is the same."""
    campaign = stiffness.simulate(str(SK120_DH), effects=["backlash:joint2=0.002"],
                                  rotations=True, noise_std_m=5e-6, seed=0).campaign
    flipped = _flipped(campaign, "force", 0)
    d = stiffness.diagnose(flipped).to_dict()
    assert d["unexplained"] is True
    note = d["flipped_column"]
    assert note.startswith("with the sign of column fx reversed the residuals fall ")
    ratio = float(note.split("x the noise")[0].rsplit(", ", 1)[1])
    assert 1.5 < ratio < 3.0, note
    assert note.endswith(f"the rest, {ratio:.2g}x the noise, is something else: diagnose the "
                         "corrected campaign")
    assert _sign_notes(stiffness.identify(flipped, starts=2)) == [note]
    assert "flipped_column" not in stiffness.diagnose(campaign, max_steps=1).to_dict()


def test_diagnose_names_a_reversed_rotation_beside_the_effect_it_finds():
    """The same SK120-DH campaign with rx negated instead: the rotations under 100 N are near
    their noise, and with rx reversed back the baseline's misfit beyond the noise falls only
    1.2 times (the backlash keeps the rest), not the 10 times its check asks. diagnose adds the
    backlash and stays UNEXPLAINED; its final model refitted with rx reversed back falls 1.59
    times, to 1x the noise, and the verdict names rx. identify, whose model has no backlash,
    names nothing."""
    campaign = stiffness.simulate(str(SK120_DH), effects=["backlash:joint2=0.002"],
                                  rotations=True, noise_std_m=5e-6, seed=0).campaign
    flipped = _flipped(campaign, "rotation", 0)
    found = stiffness.diagnose(flipped)
    d = found.to_dict()
    assert found.missing_effects == ["backlash"] and d["unexplained"] is True
    assert d["flipped_column"].startswith("with the sign of column rx reversed the residuals "
                                          "fall ")
    assert "is something else" not in d["flipped_column"]
    assert _sign_notes(stiffness.identify(flipped, starts=2)) == []


SK120_HIDDEN = (("backlash:joint2=0.002",), ("force_sensor_bias=5",), ("frame_misalignment=2",),
                ("backlash:joint2=0.002", "nonlinear_joint_stiffness:joint3=0.001"))


def test_honest_diagnoses_name_no_column():
    """SK120-DH campaigns with rotations, no column reversed, one hidden effect or two (seeds
    0-3): diagnose's check, run on its baseline and its final model whether or not that stays
    unexplained, names nothing (reversing a right column raised the residual sum of squares by
    34.8 noise variances at least in a sweep of 56 diagnoses of SK120-DH and UR5 campaigns)."""
    named = {}
    for seed, effects in enumerate(SK120_HIDDEN):
        campaign = stiffness.simulate(str(SK120_DH), effects=list(effects), rotations=True,
                                      noise_std_m=5e-6, seed=seed).campaign
        found = stiffness.diagnose(campaign)
        robot = campaign.robot()
        build = baseline_builder(Geometry.of(robot), tuple(robot.compliant_joints), "known")
        notes = fits_note(campaign, build, (found.baseline, found.final), found.noise_std_m,
                          fit_options(robot.n_compliant))
        if notes:
            named[(seed, effects)] = notes
    assert named == {}
