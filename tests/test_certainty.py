"""Answers a metrologist would sign (issue 36, items 4 and 5): a parameter is determined only
with a 95 % interval narrower than its physical scale, a determined one beyond it makes its
effect a stand-in, an effect is named only with a determined parameter whose interval excludes
zero, and a campaign with nothing hidden names an effect in few seeds."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from stiffness.calibration.diagnose import diagnose
from stiffness.calibration.diagnosis import SI_UNITS
from stiffness.calibration.naming import is_stand_in
from stiffness.elastic.effects.base import PHYSICAL_FACTOR, effect_report
from stiffness.elastic.effects.geometry import References
from stiffness.elastic.effects.joint_laws import JointCompliance
from stiffness.elastic.effects.measurement import ForceSensorBias
from stiffness.planning.simulate import simulate

REFS = References(("j",), 1e5, np.array([50.0]), np.array([5.0]), 1e-3, 100.0, 1e-4)
Z = 1.959963984540054


def test_a_force_bias_is_determined_against_the_load_range():
    """The bias's physical scale is the campaign's RMS force (100 N): a 95 % interval 2 z se
    wide is determined below it and not above; a determined bias beyond it is a stand-in."""
    e = ForceSensorBias()
    scale = e.scale(REFS)[0]  # 1 N per unit variable
    for se_n, determined in ((20.0, True), (30.0, False)):  # widths 78 N and 118 N
        p = effect_report(e, np.array([0.5, 0.0, 0.0]), np.eye(3) * (se_n / scale) ** 2,
                          REFS, SI_UNITS, Z)[0]
        assert p.standard_error == pytest.approx(se_n)
        assert p.determined is determined
        assert ("narrower than" if determined else "wider than") in p.scale_note
        # both numbers carry their unit (the scale's was bare: 'its physical scale 69')
        assert p.scale_note.endswith(f"its physical scale {100.0:.3g} N"), p.scale_note
    # an undetermined direction (infinite variance) is said so, not "inf N wide" (the pose
    # sweep of issue 47: compensator springs no pose loaded)
    p = effect_report(e, np.array([0.5, 0.0, 0.0]), np.diag([np.inf, 1.0, 1.0]), REFS, SI_UNITS,
                      Z)[0]
    assert not p.determined and p.scale_note.startswith("no finite 95 % interval"), p.scale_note
    assert "inf" not in p.scale_note
    big = effect_report(e, np.array([150.0, 0.0, 0.0]), np.eye(3) * 1e-4, REFS, SI_UNITS, Z)
    assert big[0].determined and big[0].beyond_scale and is_stand_in(big)
    small = effect_report(e, np.array([5.0, 0.0, 0.0]), np.eye(3) * 1e-4, REFS, SI_UNITS, Z)
    assert not is_stand_in(small) and small[0].excludes_zero and not small[1].excludes_zero


def test_a_stiffness_is_determined_on_its_compliance():
    """joint_compliance reports a stiffness; it is determined when its compliance's interval
    (2 z se_c) is narrower than ten compliances of the baseline's mean stiffness (1e-4
    rad/(N.m) here) and its interval excludes a zero compliance only with a finite top."""
    e = JointCompliance(joint_name="j")
    c_ref = 1.0 / REFS.k_ref
    ok = effect_report(e, np.array([0.5]), np.array([[0.01]]), REFS, SI_UNITS, Z)[0]
    assert ok.value == pytest.approx(1.0 / (0.5 * c_ref))
    assert ok.determined and ok.excludes_zero and not ok.beyond_scale
    width = 2 * Z * np.sqrt(6.0) * c_ref  # 9.6 c_ref: still within 10
    assert width < PHYSICAL_FACTOR * c_ref
    wide = effect_report(e, np.array([0.5]), np.array([[7.0]]), REFS, SI_UNITS, Z)[0]
    assert not wide.determined and not wide.excludes_zero  # reaches zero compliance
    soft = effect_report(e, np.array([20.0]), np.array([[0.01]]), REFS, SI_UNITS, Z)
    assert soft[0].determined and soft[0].beyond_scale and is_stand_in(soft)


def test_nothing_hidden_names_few_effects():
    """UR5, three arm joints compliant, 5 configurations x 3 loads, nothing hidden, 16 seeds:
    the number of seeds naming an effect is consistent with at most 5 % (binomial, alpha
    1e-3; 40 seeds named 3, each complementary_stiffness, a switch without parameters)."""
    named = 0
    for seed in range(16):
        sim = simulate("ur5", kq=[3e4, 2e4, 1.5e4], max_force=100.0, configs=5,
                       compliant_joints=["shoulder_pan_joint", "shoulder_lift_joint",
                                         "elbow_joint"], target_offset_m=[0.0, 0.0, 0.1],
                       loads_per_config=3, noise_std_m=5e-6, seed=seed)
        d = diagnose(sim.campaign, propose=False, max_steps=1, workers=1)
        named += bool(d.steps)
        for s in d.steps:
            params = d.final_parameters[s.effect.label]
            assert not params or any(p.determined and p.excludes_zero for p in params)
    assert stats.binom.sf(named - 1, 16, 0.05) > 1e-3, named
