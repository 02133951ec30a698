"""identify (deflection) on a campaign with no residual freedom (one row, three components, for
three springs) whose fit leaves a spring at its bound: the others' values and intervals are
conditional on that spring held rigid, and nothing in the data tests that (diagnose refuses
the campaign). identify printed them as measurements (shoulder_lift 17160 N.m/rad [15808,
18765] against a true 2e4); it now says they are undetermined, conditional on the bound
spring, and lists it in ``conditional_on``."""

import json

import numpy as np
import pytest

import stiffness
from stiffness.calibration.selection import MATERIAL_WIDENING, material_holders
from stiffness.cli.identify import format_table

JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"]
TRUTH = [3e4, 2e4, 1.5e4]  # N.m/rad


def _campaign(loads: int, seed: int):
    return stiffness.simulate("ur5", kq=TRUTH, compliant_joints=JOINTS, configs=1,
                              loads_per_config=loads, max_force=100.0, noise_std_m=2e-5,
                              seed=seed).campaign


def test_with_no_residual_freedom_a_spring_conditional_on_a_bound_one_is_undetermined():
    result = stiffness.identify(_campaign(1, 66), starts=2)
    joints = {j["joint"]: j for j in json.loads(result.to_json())["joints"]}
    assert joints["elbow_joint"]["at_bound"]  # the fit's compliance at zero, truth 1/1.5e4
    lift = joints["shoulder_lift_joint"]
    low, high = lift["ci95"]
    assert not low <= TRUTH[1] <= high  # the conditional interval excludes the truth
    assert lift["conditional_on"] == ["elbow_joint"] and not lift["determined"]
    # the pan's covariance with the elbow's compliance is small (correlation -0.13: freeing
    # the elbow widens its interval by 0.8 %), so it is neither conditional nor undetermined
    assert joints["shoulder_pan_joint"]["conditional_on"] == []
    assert joints["shoulder_pan_joint"]["determined"]
    assert set(result.undetermined_joints) == {"shoulder_lift_joint", "elbow_joint"}
    line = next(s for s in format_table(result).splitlines()
                if s.startswith("shoulder_lift_joint"))
    assert "undetermined: conditional on elbow_joint held at its bound" in line, line
    with pytest.raises(stiffness.StiffnessError, match="cannot diagnose"):
        stiffness.diagnose(_campaign(1, 66), max_steps=0)


def test_only_the_bound_springs_that_move_an_interval_materially_are_named():
    """UR5, five springs, the lift and wrist_1 rigid (1e13 N.m/rad), four configurations of
    two loads, seed 1: both fitted at their bound. The elbow's compliance correlates -0.73
    with the lift's and -0.22 with wrist_1's, wrist_2's 0.56 and 0.007: each is conditional
    on the lift only (freeing wrist_1 would widen their intervals by 2.5 % and 0.003 %), the
    pan (-0.16, -0.11) on neither. Before, every bound spring with a non-zero covariance was
    named: both, for all three."""
    joints = JOINTS + ["wrist_1_joint", "wrist_2_joint"]
    campaign = stiffness.simulate("ur5", kq=[3e4, 1e13, 1.5e4, 1e13, 8e3],
                                  compliant_joints=joints, configs=4, loads_per_config=2,
                                  max_force=100.0, noise_std_m=2e-5, seed=1).campaign
    result = stiffness.identify(campaign, starts=1)
    said = {j["joint"]: j for j in result.to_dict()["joints"]}
    assert said["shoulder_lift_joint"]["at_bound"] and said["wrist_1_joint"]["at_bound"]
    assert said["elbow_joint"]["conditional_on"] == ["shoulder_lift_joint"]
    assert said["wrist_2_joint"]["conditional_on"] == ["shoulder_lift_joint"]
    assert said["shoulder_pan_joint"]["conditional_on"] == []


@pytest.mark.parametrize("rho", [0.25, 0.3, 0.31, 0.5, -0.9])
def test_a_bound_parameter_is_material_when_freeing_it_widens_the_end_by_5_percent(rho):
    """One bound parameter (index 1) beside parameter 0 with correlation ``rho``: freed, the
    held end's std grows from ``sqrt(1 - rho^2)`` to 1 (the Schur complement in closed form),
    by ``1 / sqrt(1 - rho^2) - 1``, material beyond 5 % (|rho| > 0.305); a third, bound but
    uncorrelated, never."""
    cov = np.array([[4.0, 2.0 * 3.0 * rho, 0.0], [2.0 * 3.0 * rho, 9.0, 0.0], [0, 0, 1.0]])
    named = material_holders(cov, 0, [1, 2], [1.0, 1.0])
    widening = 1.0 / np.sqrt(1.0 - rho**2) - 1.0
    assert list(named) == [widening > MATERIAL_WIDENING, False]
    assert MATERIAL_WIDENING == 0.05
