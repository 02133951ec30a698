"""Parameters held by a fit, and intervals at physical bounds (issue 36 items 3 and 4).

A parameter the diagnosis holds (:attr:`Hypothesis.held`: the data do not determine it) stays
at its start in every fit of the model and is reported as held with why; a parameter the
solver leaves at its bound gets a one-sided interval and the others' intervals respect the
bound on the side where they would need it crossed (``diagnose._held``). One small link-angle
UR5 campaign with a hidden compensator whose stiffness the data put at 0 (seed 3).
"""

from __future__ import annotations

import numpy as np
from test_joint_angles import ARMS, NOISE, _model, _sim

from stiffness.calibration.diagnose import _effect_parameters, stiffness_parameters
from stiffness.calibration.diagnosis import SI_UNITS
from stiffness.calibration.fitting import parameter_labels
from stiffness.calibration.selection import (
    fit_model,
    held_at_bounds,
    interval_quantile,
    parameter_covariance,
)


def _fit(held: dict[str, str] | None = None):
    arm = ARMS[0]
    c = _sim(arm, 3).campaign
    model, (comp,) = _model(c, [("gravity_compensator", arm[3])], "link")
    model = model.holding(held or {})
    x0 = np.concatenate([np.log(arm[2]), comp.start()])
    return fit_model(model, c.deflection, NOISE, x0), c


def test_a_held_parameter_stays_at_its_start_and_says_why():
    label = f"gravity_compensator({ARMS[0][3]}).stiffness"
    fit, c = _fit({label: "held at its nominal value: test"})
    index = parameter_labels(fit.model).index(label)
    assert fit.x[index] == 0.0
    dropped = fit.identifiability.dropped_at(index)
    assert dropped.reason == "undetermined" and dropped.note == "held at its nominal value: test"
    assert fit.penalty_params == fit.model.penalty_params - 1
    cov = parameter_covariance(fit, NOISE, c.deflection)
    quantile = interval_quantile(NOISE, c.deflection.size, fit.penalty_params)
    stiffness, preload = _effect_parameters(fit, cov, quantile, SI_UNITS)[
        f"gravity_compensator({ARMS[0][3]})"]
    assert stiffness.held == "held at its nominal value: test" and not stiffness.determined
    assert "not fitted (held at 0 N/m)" in stiffness.text()
    # the model derived from it (an extension, other rows) keeps holding it
    assert fit.model.with_effects(fit.model.effects).held == {label: dropped.note}


def test_at_a_bound_the_interval_is_one_sided_and_the_others_respect_it():
    """The free fit puts the compensator's stiffness at 0 (truth 1e5 N/m): its interval starts
    at the bound and does not exclude zero; the preload's lower end is the one with the
    stiffness held at 0 (going lower would need a negative stiffness), its upper end the free
    one; measured 10112 N [8920, 22642] around the truth 2e4 N, where the free interval is
    +-12500 N and the held one +-1190 N."""
    fit, c = _fit()
    labels = parameter_labels(fit.model)
    k = labels.index(f"gravity_compensator({ARMS[0][3]}).stiffness")
    assert fit.at_bound == [k]
    cov = parameter_covariance(fit, NOISE, c.deflection)
    held = held_at_bounds(fit, NOISE, c.deflection)
    quantile = interval_quantile(NOISE, c.deflection.size, fit.penalty_params)
    free = _effect_parameters(fit, cov, quantile, SI_UNITS)
    both = _effect_parameters(fit, cov, quantile, SI_UNITS, held)
    only = _effect_parameters(fit, held, quantile, SI_UNITS)
    label = f"gravity_compensator({ARMS[0][3]})"
    stiffness, preload = both[label]
    assert stiffness.at_bound and stiffness.ci95[0] == stiffness.value
    assert not stiffness.excludes_zero
    assert cov[k, k + 1] > 0  # a higher preload goes with a higher stiffness: allowed upward
    assert preload.ci95 == (only[label][1].ci95[0], free[label][1].ci95[1])
    assert preload.ci95[0] < 2e4 < preload.ci95[1] and preload.excludes_zero
    # the joint stiffnesses follow the same rule
    for p, f, h in zip(stiffness_parameters(fit, cov, quantile, held),
                       stiffness_parameters(fit, cov, quantile),
                       stiffness_parameters(fit, held, quantile), strict=True):
        assert p.ci95[0] in (f.ci95[0], h.ci95[0]) and p.ci95[1] in (f.ci95[1], h.ci95[1])
