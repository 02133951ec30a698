"""The stiffness physical scales are judged against (``k_ref``) leaves out the joints the data
do not see.

``k_ref`` was the geometric mean of every baseline stiffness, a wrist the campaign does not load
at its 1e14 rigid bound included: on a UR5 whose wrist springs are 1e9 N.m/rad (rigid to a
5 um rig) it came out 1.7e6 N.m/rad (3.9e4 without the wrist), every physical scale 43 times
too small, and diagnose named a true 0.02 deg backlash a stand-in ("its size is not
physical"; missing effects: none found physical). Gepetto's talos-like leg (a motor at its
bound) did the same.
"""

from __future__ import annotations

import pytest

import stiffness

TRUTH_K = [2e4, 2e4, 2e4, 1e9, 1e9, 1e9]
TRUTH_BACKLASH_DEG = 0.02


@pytest.fixture(scope="module")
def rigid_wrist_diagnosis(tmp_path_factory):
    folder = tmp_path_factory.mktemp("ur5-rigid-wrist")
    stiffness.simulate("ur5", kq=TRUTH_K, configs=4, noise_std_m=5e-6, seed=1,
                       effects=[f"backlash:shoulder_lift_joint={TRUTH_BACKLASH_DEG}"],
                       target_offset_m=[0.0, 0.0, 0.1]).write(folder)
    return stiffness.diagnose(folder, max_steps=1).to_dict()


def test_a_true_backlash_beside_a_rigid_wrist_is_named_physical(rigid_wrist_diagnosis):
    d = rigid_wrist_diagnosis
    assert d["missing_effects"] == ["backlash"]
    assert [s["stand_in"] for s in d["how_sure"]] == [False]
    low, high = d["final_parameters"]["backlash(shoulder_lift_joint)"]["half_width"]["ci95"]
    assert low < TRUTH_BACKLASH_DEG < high


def test_the_arm_springs_are_determined_and_cover_the_truth(rigid_wrist_diagnosis):
    final = rigid_wrist_diagnosis["final_stiffness"]
    for joint, truth in zip(("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"),
                            TRUTH_K, strict=False):
        assert final[joint]["determined"], joint
        low, high = final[joint]["ci95"]
        assert low < truth < high, (joint, low, high)
