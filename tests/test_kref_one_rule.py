"""Both campaign kinds take ``k_ref`` (the stiffness physical scales, and so stand-in verdicts,
are judged against) by one rule, :func:`stiffness.calibration.fitting.typical_stiffness`: the
geometric mean of the springs fitted, off their bound, whose compliance's 95 % interval
excludes zero.

The deflection side used to count every spring fitted off its bound, a near-rigid one whose
interval reaches zero included. On a UR5 with arm springs of 2e4 N.m/rad and wrist springs of
1e7 the rig barely sees (wrist_1 and wrist_2 fitted at 5.2e6 and 2.3e6, their intervals
unbounded above) that gave ``k_ref`` 1.57e5 N.m/rad on the deflection side and 1.99e4 on the
pose side for the same springs and intervals.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

import stiffness
from stiffness.calibration import pose_parameters

ARM_K = 2e4  # N.m/rad
KQ = [ARM_K, ARM_K, ARM_K, 1e7, 1e7, 1e7]


@pytest.fixture(scope="module")
def baseline(tmp_path_factory):
    """The baseline diagnosis of a UR5 campaign whose wrist springs are nearly rigid."""
    folder = tmp_path_factory.mktemp("ur5-stiff-wrist")
    stiffness.simulate("ur5", kq=KQ, configs=4, noise_std_m=5e-6, seed=1,
                       target_offset_m=[0.0, 0.0, 0.1]).write(folder)
    return stiffness.diagnose(folder, max_steps=0)


def _reported(diagnosis):
    """Per spring of the baseline: its stiffness (N.m/rad), its compliance's 95 % interval's
    low end read off the reported stiffness interval (``1 / upper``; 0 where unbounded
    above, NaN where not fitted), whether it is fitted and off its bound."""
    fit = diagnosis.baseline
    k = np.exp(fit.x[:len(fit.model.compliant)])
    low, fitted = [], []
    for i, p in enumerate(diagnosis.baseline_stiffness):
        upper = p.ci95[1]
        low.append(math.nan if p.held else 0.0 if not math.isfinite(upper) else 1.0 / upper)
        if i in fit.kept and i not in fit.at_bound and not p.at_bound:
            fitted.append(i)
    return k, np.array(low), fitted


def test_the_case_has_a_near_rigid_spring_whose_interval_reaches_zero(baseline):
    """The case the two old rules disagreed on: a spring fitted off its bound, the data
    unable to bound its stiffness above."""
    k, low, fitted = _reported(baseline)
    near_rigid = [i for i in fitted if low[i] <= 0]
    assert near_rigid and all(k[i] > 10 * ARM_K for i in near_rigid)


def test_deflection_k_ref_is_the_springs_whose_interval_excludes_zero(baseline):
    """k_ref is the geometric mean of exactly the springs whose reported interval is bounded
    (the arm's three), the truth's 2e4 to the fit's 1 %."""
    k, low, fitted = _reported(baseline)
    seen = [i for i in fitted if low[i] > 0]
    assert seen == [0, 1, 2]
    expected = math.exp(np.mean(np.log(k[seen])))
    assert baseline.baseline.model.refs.k_ref == pytest.approx(expected, rel=1e-12)
    assert expected == pytest.approx(ARM_K, rel=0.01)


def test_a_pose_fit_with_the_same_springs_and_intervals_has_the_same_k_ref(baseline):
    """A pose fit (compliances fitted directly) holding the deflection baseline's springs,
    compliance intervals, fitted set and bounds gets the deflection side's k_ref."""
    k, low, _ = _reported(baseline)
    fit = baseline.baseline
    n0 = len(fit.model.compliant)
    pose_fit = SimpleNamespace(
        model=SimpleNamespace(families=(pose_parameters.SPRINGS,),
                              slices=lambda: {pose_parameters.SPRINGS: slice(0, n0)},
                              robot=fit.model.geometry.robot),
        x=1.0 / k, identifiability=SimpleNamespace(kept=list(fit.kept)),
        at_bound=list(fit.at_bound), interval=lambda: (low, np.full(n0, math.nan)))
    assert pose_parameters.reference_stiffness(pose_fit) == pytest.approx(
        fit.model.refs.k_ref, rel=1e-12)
