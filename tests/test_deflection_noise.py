"""The weight of measured rotations, ``sigma_t / sigma_r``: one rule for identify and diagnose
(:mod:`stiffness.calibration.deflection_noise`)."""

import dataclasses
import functools

import numpy as np
import pytest

from stiffness import simulate
from stiffness.calibration.diagnose import diagnose
from stiffness.calibration.identify import identify

ARM = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"]
NOISE, ROTATION_NOISE = 5e-6, 5e-5


@functools.lru_cache(maxsize=2)
def _campaign(repeats: int):
    return simulate("ur5", configs=4, loads_per_config=6 // repeats, repeats=repeats,
                    noise_std_m=NOISE, rotation_noise_std_rad=ROTATION_NOISE, seed=3,
                    kq=[3e4, 2e4, 1.5e4], max_force=20.0, compliant_joints=ARM,
                    target_offset_m=[0.0, 0.0, 0.1], rotations=True).campaign


def _kind_std(residual: np.ndarray, n: int, p: int) -> float:
    """A kind's std from its residuals, its share of the ``p`` parameters removed."""
    return float(np.sqrt(np.sum(residual ** 2) / (residual.size - p * residual.size / n)))


def _pooled(values: np.ndarray, repeats: int) -> float:
    """The pooled scatter of rows repeated ``repeats`` times in a row."""
    groups = values.reshape(-1, repeats, 3)
    deviations = groups - groups.mean(axis=1, keepdims=True)
    return float(np.sqrt(np.sum(deviations ** 2) / (groups.shape[0] * (repeats - 1) * 3)))


@pytest.mark.parametrize("declared", [(True, False), (False, True), (False, False)])
def test_an_estimated_weight_is_the_residuals_fixed_point(declared):
    """Rows measured once, one or both noise stds not declared: identify's and diagnose's
    weight is the ratio of the stds their own baseline's residuals give at that weight (to
    the 0.1 % the fixed point stops at), the declared std in place of an estimate, and the two
    agree. Until 6 December 2026 diagnose weighted a declared rotation noise against the
    measured translations' RMS when the translation noise was not declared (4.08 m/rad where
    the residuals say 0.087)."""
    c = _campaign(1)
    c = dataclasses.replace(c, noise_std_m=NOISE if declared[0] else None,
                            rotation_noise_std_rad=ROTATION_NOISE if declared[1] else None)
    r = identify(c, starts=1)
    d = diagnose(c, propose=False, workers=1, max_steps=0)
    n, p = 6 * c.n_rows, 3
    res_t, res_r = d.baseline.residuals(d.measured)
    for weight, (t, rot) in ((r.rotation_weight_m_per_rad, (r.residuals, r.rotation_residuals)),
                             (d.baseline.model.rotation_weight, (res_t, res_r))):
        s_t = NOISE if declared[0] else _kind_std(t, n, p)
        s_r = ROTATION_NOISE if declared[1] else _kind_std(rot, n, p)
        assert weight == pytest.approx(s_t / s_r, rel=2e-3)
    assert r.rotation_weight_m_per_rad == pytest.approx(d.baseline.model.rotation_weight,
                                                        rel=1e-6)
    assert 0.05 < r.rotation_weight_m_per_rad < 0.2  # about NOISE / ROTATION_NOISE
    assert r.rotation_sigma_source == ("declared rotation_noise_std" if declared[1]
                                       else "residuals")


def test_replicates_give_identify_the_weight_and_the_noise_as_diagnose():
    """Rows measured twice, neither noise declared: identify weighs the rotations by the ratio
    of the two kinds' pooled replicate scatters, takes the translations' as its noise and
    tests it by the pooled lack-of-fit F, as diagnose does (until 6 December 2026 identify
    read no replicates with rotations: weight 0.110 for the replicates' 0.142 here)."""
    c = dataclasses.replace(_campaign(2), noise_std_m=None, rotation_noise_std_rad=None)
    r = identify(c, starts=1)
    d = diagnose(c, propose=False, workers=1, max_steps=0)
    assert c.rotation is not None
    s_t, s_r = _pooled(c.deflection, 2), _pooled(c.rotation, 2)
    assert r.rotation_weight_m_per_rad == pytest.approx(s_t / s_r, rel=1e-12)
    assert d.baseline.model.rotation_weight == pytest.approx(s_t / s_r, rel=1e-12)
    assert r.rotation_sigma_rad == pytest.approx(s_r, rel=1e-12)
    assert r.rotation_sigma_source == d.rotation_noise_source == "replicates"
    assert r.noise.sigma == pytest.approx(s_t, rel=1e-12) and r.noise.dof == 36
    assert r.fits_to_noise is not None and r.fits_to_noise["test"] == d.test == "lack-of-fit F"
    assert r.fits_to_noise["p_value"] == pytest.approx(d.gof_baseline, rel=1e-6)


def test_a_robust_identify_reads_the_replicates_as_diagnose():
    """Rows measured twice, no rotations, the noise not declared, ``--loss huber``: identify
    takes the replicates' robust scatter (36 degrees of freedom) and tests the fit against it
    as diagnose does (until 6 December 2026 it took the robust estimate from its residuals,
    5.45 um here against the replicates' 5.70 um, and tested nothing)."""
    c = dataclasses.replace(_campaign(2), noise_std_m=None, rotation=None,
                            rotation_noise_std_rad=None)
    r = identify(c, starts=1, loss="huber")
    d = diagnose(c, propose=False, workers=1, max_steps=0, loss="huber")
    assert r.sigma_source == "replicates (robust scatter, 36 degrees of freedom)"
    assert d.noise_std_source == "replicates"
    assert r.noise.sigma == pytest.approx(d.noise_std_m, rel=1e-12)
    assert 0.7 * NOISE < r.noise.sigma < 1.3 * NOISE
    assert r.fits_to_noise is not None
    assert r.fits_to_noise["p_value"] == pytest.approx(d.gof_baseline, rel=1e-6)
