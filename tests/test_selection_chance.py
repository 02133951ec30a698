"""Chance among a step's many candidates (docs/diagnose.md, *Chance among many candidates*):
the best of dozens of pure-noise candidates passes the BIC margin far more often than one
does, but a step is entered only while the fit-to-noise test rejects the current model, and the
search stops at the first model it accepts; so a declared-noise search names an effect the data
do not hold at about the test's 5 %, not at the margin's rate over the candidates."""

from __future__ import annotations

import numpy as np
from stats import binomial_consistent

from stiffness.calibration.diagnose import diagnose
from stiffness.calibration.selection import (
    BIC_MARGIN,
    Noise,
    above_noise,
    fits_to_noise,
    step_criteria,
)
from stiffness.planning.simulate import parse_effect, simulate


def _pure_noise(n: int, p0: int, k: int, draws: int, sigma: float, seed: int
                ) -> tuple[np.ndarray, np.ndarray]:
    """Pure noise (std ``sigma``, m) on a linear model of ``p0`` random columns over ``n``
    components, ``draws`` times: the model's RSS per draw and each of ``k`` one-column
    extensions' (k, draws), by projecting it off the model (Frisch-Waugh)."""
    rng = np.random.default_rng(seed)
    design, extras = rng.normal(size=(n, p0)), rng.normal(size=(n, k))
    noise = rng.normal(size=(n, draws)) * sigma
    q = np.linalg.qr(design)[0]
    r0 = noise - q @ (q.T @ noise)
    e = extras - q @ (q.T @ extras)
    rss0 = np.sum(r0 ** 2, axis=0)
    return rss0, rss0 - (e.T @ r0) ** 2 / np.sum(e ** 2, axis=0)[:, None]


def test_best_of_36_past_the_margin_only_behind_the_fit_to_noise_test():
    """Pure noise on a linear model (3 columns, 96 components, a declared 20 um noise), 36
    one-column candidates (a UR10 step's count), 2000 draws. The best of the 36 passes the
    BIC margin under the step's overdispersion in 26 % of draws (26.4 % over 40 000 draws;
    one candidate 0.89 %): the multiplicity. The search enters a step only when the
    chi-square test rejects the current model (4.9 %), and there the best passes the margin in
    1.76 % of all draws (40 000 draws): below the test's 5 %. Two-sided binomial at 1e-3
    against the rates measured over 40 000 draws (seed 1; these are seed 0's)."""
    n, p0, k, draws, sigma = 96, 3, 36, 2000, 2e-5
    rss0, rss1 = _pure_noise(n, p0, k, draws, sigma, 0)
    noise = Noise(sigma)
    margin = gate = named = 0
    for d in range(draws):
        base, bics, _ = step_criteria((rss0[d], p0), [(r, p0 + 1) for r in rss1[:, d]], n,
                                      sigma)
        past = min(bics) - base < -BIC_MARGIN
        margin += past
        if fits_to_noise(rss0[d], n, p0, noise) is None:  # the search goes on
            gate += 1
            named += past
    assert binomial_consistent(margin, draws, 0.2645)
    assert binomial_consistent(gate, draws, 0.0489)
    assert binomial_consistent(named, draws, 0.0176)


def test_audit_steps_entered_only_while_the_fit_to_noise_test_rejects():
    """The audit's campaign: a UR10 (arm joints compliant at 1e5, 1e5, 5e4 N.m/rad, 10 cm
    tool), a wrist_1 spring of 2e4 N.m/rad and a shoulder_lift backlash of 0.0012 rad hidden,
    8 configurations x 4 loads of up to 300 N, 20 um declared, seed 2. The search names both
    and a shoulder_pan nonlinear spring the truth lacks: the two-effect model leaves
    chi-square p = 0.014, so the search goes on, and of its 38 candidates the nonlinear spring
    takes 12.8 noise^2 of RSS (likelihood ratio p = 0.0012 under the step's overdispersion
    1.225; 0.046 over the 38, so a Bonferroni correction would name it too), passes the BIC
    margin (-5.9) and the held-out configurations (1.20 against 1.24 noise std), and leaves
    p = 0.072. Such a name comes in about 2 % of these campaigns with nothing, one or both
    effects hidden (docs/diagnose.md). Checked here: every step added was entered with its
    current model rejected by the test, and the search stopped at the first model it accepts."""
    sim = simulate("ur10", kq=[1e5, 1e5, 5e4], target_offset_m=[0.0, 0.0, 0.1],
                   compliant_joints=["shoulder_pan_joint", "shoulder_lift_joint",
                                     "elbow_joint"],
                   effects=[parse_effect("joint_compliance:wrist_1_joint=20000"),
                            parse_effect(f"backlash:shoulder_lift_joint={np.degrees(0.0012)}")],
                   configs=8, loads_per_config=4, max_force=300.0, noise_std_m=2e-5, seed=2)
    d = diagnose(sim.campaign, propose=False, workers=1)
    noise, n = Noise(2e-5), d.search.n
    fits = [d.baseline] + [s.fit for s in d.steps]
    assert not any(s.removed for s in d.steps) and len(d.steps) >= 2
    for fit in fits[:-1]:
        assert above_noise(noise.goodness_of_fit(*_terms(fit, n)))
    assert not above_noise(noise.goodness_of_fit(*_terms(fits[-1], n)))
    assert "explains the data to noise" in d.stop_reason and d.unexplained is False


def _terms(fit, n: int) -> tuple[float, int, int]:
    """``(RSS m^2, N, p)`` of a fit, as the fit-to-noise test takes them."""
    rss, p = fit.terms()
    return rss, n, p
