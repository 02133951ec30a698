"""identify (deflection) on a campaign with no residual freedom (one row, three components, for
three springs) whose fit leaves a spring at its bound: the others' values and intervals are
conditional on that spring held rigid, and nothing in the data tests that (diagnose refuses
the campaign). identify printed them as measurements (shoulder_lift 17160 N.m/rad [15808,
18765] against a true 2e4); it now says they are undetermined, conditional on the bound
spring, and lists it in ``conditional_on``."""

import json

import pytest

import stiffness
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
    assert set(result.undetermined_joints) == set(JOINTS)
    line = next(s for s in format_table(result).splitlines()
                if s.startswith("shoulder_lift_joint"))
    assert "undetermined: conditional on elbow_joint held at its bound" in line, line
    with pytest.raises(stiffness.StiffnessError, match="cannot diagnose"):
        stiffness.diagnose(_campaign(1, 66), max_steps=0)
