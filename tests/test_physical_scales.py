"""Each effect's physical scale (issue 36, items 3 and 4): the size beyond which a parameter is
not physical on its campaign (its effect then a stand-in, :func:`naming.is_stand_in`) and
which a determined parameter's 95 % interval must be narrower than.

Each scale is checked against an independent computation (Pinocchio's gravity at the
campaign's poses, the UR5's link lengths from its URDF, the campaign's forces) and through the
rule itself: a value 2 % beyond the scale, known to 0.1 %, makes the effect a stand-in, 2 %
within does not, so a scale 10 times off in either direction fails.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from stiffness.calibration.diagnose import diagnose
from stiffness.calibration.diagnosis import SI_UNITS
from stiffness.calibration.naming import is_stand_in
from stiffness.calibration.pose_diagnose import CANDIDATES
from stiffness.calibration.pose_fit import campaign_settings, fit_pose_model, rows_of
from stiffness.calibration.pose_model import Marker, PoseModel
from stiffness.calibration.pose_parameters import PoseJudge
from stiffness.elastic.effects import make_effect
from stiffness.elastic.effects.base import effect_report, effect_variables
from stiffness.elastic.effects.geometry import Geometry, References
from stiffness.planning.simulate import simulate
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.robot import load_robot

JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"]
#: The UR5's reach (m) from its URDF's joint origins (base to shoulder 0.089159, to the upper
#: arm 0.13585, the upper arm (0.1197, 0.425), the forearm 0.39225, the wrist 0.093 and
#: 0.09465, the flange 0.0823): the longest chain of placements.
UR5_REACH = 0.089159 + 0.13585 + math.hypot(0.1197, 0.425) + 0.39225 + 0.093 + 0.09465 + 0.0823


@pytest.fixture(scope="module")
def ur5_campaign():
    """A small UR5 deflection campaign (its robot, references and the campaign)."""
    sim = simulate("ur5", kq=[3e4, 2e4, 1.5e4], compliant_joints=JOINTS, max_force=100.0,
                   noise_std_m=0.0, configs=5, loads_per_config=2, seed=0)
    c = sim.campaign
    robot = c.robot()
    geo = Geometry.of(robot)
    rows = geo.rows(c.q, c.force, c.moment)
    return robot, geo, References.of(geo, rows, 2e4, c.deflection), c


def _stand_in(effect, refs, values: np.ndarray) -> bool:
    """Whether ``effect`` with SI ``values`` known to 0.1 % reads as a stand-in."""
    u = effect_variables(effect, values, refs)
    cov = np.diag((1e-3 * np.maximum(np.abs(u), 1e-12)) ** 2)
    return is_stand_in(effect_report(effect, u, cov, refs, SI_UNITS, 1.96))


def _weight_torques(robot, campaign) -> np.ndarray:
    """(rows, nv) |g(q)| at the campaign's poses, from Pinocchio directly."""
    model, data = robot.model, robot.model.createData()
    return np.abs([pin.computeGeneralizedGravity(model, data, robot.configuration(q))
                   for q in campaign.q])


def test_compensator_scale_is_the_weight_its_joint_carries(ur5_campaign):
    """Preload: the largest weight torque on the joint over the campaign over the lever
    (0.1 m, shorter than the base); stiffness: that over the lever squared; a joint the weight
    hardly loads (the last wrist joint) gets 1 % of the largest joint's. Beyond either the
    spring is a stand-in, within it not."""
    robot, geo, refs, campaign = ur5_campaign
    tau = _weight_torques(robot, campaign)
    lift = tau[:, robot.model.joints[robot.model.getJointId("shoulder_lift_joint")].idx_v].max()
    assert 20.0 < lift < 60.0  # N.m: the arm's weight about the shoulder
    comp = make_effect("gravity_compensator", "shoulder_lift_joint", geo)
    np.testing.assert_allclose(comp.physical_scale(refs), [lift / 0.01, lift / 0.1],
                               rtol=1e-9)
    wrist = make_effect("gravity_compensator", "wrist_3_joint", geo)
    np.testing.assert_allclose(wrist.physical_scale(refs),
                               [0.01 * tau.max() / 0.01, 0.01 * tau.max() / 0.1], rtol=1e-9)
    k, f0 = lift / 0.01, lift / 0.1
    for values, beyond in (([0.98 * k, 0.98 * f0], False), ([1.02 * k, 0.5 * f0], True),
                           ([0.5 * k, 1.02 * f0], True), ([0.5 * k, -1.02 * f0], True)):
        assert _stand_in(comp, refs, np.array(values)) is beyond, values


def test_compensator_without_the_weight_takes_the_joint_spring_scale(ur5_campaign):
    """Without the weight (loops, or no inertias): the stiffness whose torque derivative
    k a d is k_ref, the preload k_ref / a."""
    _, geo, refs, _ = ur5_campaign
    bare = References(refs.joints, refs.k_ref, refs.tau_max, refs.tau_smoothing,
                      refs.theta_ref, refs.force_ref, refs.deflection_ref)
    comp = make_effect("gravity_compensator", "shoulder_lift_joint", geo)
    np.testing.assert_allclose(comp.physical_scale(bare),
                               [2e4 / (0.1 * 0.3), 2e4 / 0.1], rtol=1e-12)


def test_target_offset_and_payload_centre_against_the_reach(ur5_campaign):
    """A target offset, and a payload's centre of mass, beyond the robot's reach are not
    physical."""
    _, geo, refs, _ = ur5_campaign
    assert refs.reach_m == pytest.approx(UR5_REACH, rel=1e-9)
    offset = make_effect("target_offset", None, geo)
    assert not _stand_in(offset, refs, np.array([0.0, 0.98 * UR5_REACH, 0.0]))
    assert _stand_in(offset, refs, np.array([0.0, 0.0, -1.02 * UR5_REACH]))
    payload = make_effect("gravity_preload", None, geo)
    mass = 0.1 * refs.force_ref / 9.81
    assert not _stand_in(payload, refs, np.array([mass, 0.98 * UR5_REACH, 0.0, 0.0]))
    assert _stand_in(payload, refs, np.array([mass, 1.02 * UR5_REACH, 0.0, 0.0]))


def test_force_bias_against_the_load_range(ur5_campaign):
    """A force sensor bias beyond the campaign's RMS applied force is not physical."""
    _, geo, refs, campaign = ur5_campaign
    rms = float(np.sqrt(np.mean(np.sum(campaign.force ** 2, axis=1))))
    assert 20.0 < rms < 100.0
    assert refs.force_ref == pytest.approx(rms, rel=1e-12)
    bias = make_effect("force_sensor_bias", None, geo)
    assert not _stand_in(bias, refs, np.array([0.98 * rms, 0.0, 0.0]))
    assert _stand_in(bias, refs, np.array([0.0, 1.02 * rms, 0.0]))


def test_backlash_and_link_compliance_scales(ur5_campaign):
    """Backlash: ten times the campaign's typical joint deflection (the RMS over joints of
    each joint's RMS load torque, over k_ref); a link bend: a compliance ten times the
    baseline's mean, 10 / k_ref."""
    _, geo, refs, campaign = ur5_campaign
    tau = geo.rows(campaign.q, campaign.force, campaign.moment).torques()
    theta = float(np.sqrt(np.mean(np.mean(tau ** 2, axis=0)))) / 2e4
    backlash = make_effect("backlash", "elbow_joint", geo)
    np.testing.assert_allclose(backlash.physical_scale(refs), [10 * theta], rtol=1e-9)
    assert not _stand_in(backlash, refs, np.array([9.8 * theta]))
    assert _stand_in(backlash, refs, np.array([10.2 * theta]))
    bend = make_effect("link_compliance", "shoulder_lift_joint->elbow_joint", geo)
    # stiffnesses: a compliance of 10 / k_ref is a stiffness of k_ref / 10
    assert not _stand_in(bend, refs, np.array([2e4 / 9.8, 2e4 / 9.8]))
    assert _stand_in(bend, refs, np.array([2e4 / 10.2, 2e4]))


def test_compensator_with_the_masses_unknown_takes_the_joint_spring_scale(ur5_campaign):
    """``diagnose --masses unknown`` on a deflection campaign: the URDF's weight is not
    trusted, so the compensator's scale is the joint spring's, k_ref / (a d) and k_ref / a
    (lever 0.1 m, base 0.3 m); with the masses known, the weight its joint carries (the
    largest of Pinocchio's gravity torque on it over the campaign, over a and a^2)."""
    robot, geo, _, campaign = ur5_campaign
    lift = _weight_torques(robot, campaign)[
        :, robot.model.joints[robot.model.getJointId("shoulder_lift_joint")].idx_v].max()
    comp = make_effect("gravity_compensator", "shoulder_lift_joint", geo)
    for masses in ("unknown", "known"):
        refs = diagnose(campaign, max_steps=0, masses=masses).baseline.model.refs
        k_ref = refs.k_ref
        assert 1.4e4 < k_ref < 3.1e4  # the geometric mean of 3e4, 2e4, 1.5e4 N.m/rad
        expected = ([k_ref / (0.1 * 0.3), k_ref / 0.1] if masses == "unknown"
                    else [lift / 0.01, lift / 0.1])
        np.testing.assert_allclose(comp.physical_scale(refs), expected, rtol=1e-9,
                                   err_msg=masses)


@pytest.fixture(scope="module")
def ur5_pose_fit():
    """A UR5 pose campaign without load (markers, compliant joints) and its fit with joint
    compliance and a compensator on every joint."""
    robot = load_robot("ur5", frame="tool0")
    markers = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05])),
               Marker("elbow", "forearm_link", np.array([0.0, 0.05, 0.2]))]
    hidden = HiddenPoseErrors(np.eye(3), np.zeros(3), np.array([m.offset for m in markers]),
                              np.zeros(6), np.zeros((6, 6)), np.full(6, 2e4))
    c = simulate_pose_campaign(robot, markers, hidden, 20, 1e-6, seed=0)
    families = ("frame", "markers", "joint_offsets", "joint_compliance", "gravity_compensator")
    model = PoseModel(robot, c.markers, families, (np.eye(3), np.zeros(3)), c.loads,
                      campaign_settings(c))
    return robot, c, model, fit_pose_model(model, c, rows_of(model, c), list(families))


def test_pose_compensator_with_the_masses_unknown_takes_the_joint_spring_scale(ur5_pose_fit):
    """A pose diagnosis with the masses unknown judges a compensator by the joint spring's
    scales k_ref / (a d) and k_ref / a on every joint, not by the nominal weight (the judge
    of ``diagnose(..., masses="unknown")``, every candidate family forbidden to keep it
    cheap); with the masses known, by the weight."""
    robot, c, model, fit = ur5_pose_fit
    cut = model.slices()["gravity_compensator"]
    lift = _weight_torques(robot, c).max(axis=0)[1]
    labels = [p.label for p in model.parameters]
    k = labels.index("shoulder_lift_joint compensator stiffness") - cut.start
    for masses in ("unknown", "known"):
        judge = diagnose(c, masses=masses, not_families=CANDIDATES[masses]).judge
        refs = judge.references(fit)
        sizes = next(f for f in model.family_objects
                     if f.name == "gravity_compensator").physical_sizes(model, refs)
        assert sizes.size == 12
        if masses == "unknown":
            np.testing.assert_allclose(sizes, np.tile([refs.k_ref / (0.1 * 0.3),
                                                       refs.k_ref / 0.1], 6), rtol=1e-9)
        else:
            np.testing.assert_allclose(sizes[k: k + 2], [lift / 0.01, lift / 0.1], rtol=1e-9)


def test_pose_scales_markers_offsets_and_compensator(ur5_pose_fit):
    """A pose campaign's markers against the reach, revolute zero offsets against half a
    turn, the compensator against the weight its joint carries at the commanded poses."""
    robot, c, model, fit = ur5_pose_fit
    refs = PoseJudge.of(c).references(fit)
    assert refs.reach_m == pytest.approx(UR5_REACH, rel=1e-9)
    by_family = {f.name: f.physical_sizes(model, refs) for f in model.family_objects}
    np.testing.assert_allclose(by_family["markers"], np.full(6, UR5_REACH), rtol=1e-9)
    np.testing.assert_allclose(by_family["joint_offsets"], np.full(6, math.pi))
    tau = _weight_torques(robot, c).max(axis=0)  # no load: the joints carry their weight
    labels = [p.label for p in model.parameters]
    k = (labels.index("shoulder_lift_joint compensator stiffness")
         - model.slices()["gravity_compensator"].start)
    lift = tau[1]
    assert 20.0 < lift < 60.0
    np.testing.assert_allclose(by_family["gravity_compensator"][k: k + 2],
                               [lift / 0.01, lift / 0.1], rtol=1e-9)


def test_lumped_gravity_masses_are_bounded_and_moments_signed(ur5_campaign):
    """``gravity_lumped``: each link's mass is at least 0 (deflection face: the mass itself;
    pose face: a compliance times it); its mass moments m c are signed."""
    _, geo, _, _ = ur5_campaign
    lumped = make_effect("gravity_lumped", None, geo)
    low, high = lumped.bounds()
    names = lumped.parameter_names
    assert len(names) == low.size == 4 * len(lumped.links)
    assert all((v == 0.0) == n.endswith("_m") for n, v in zip(names, low, strict=True))
    assert np.all(low[[not n.endswith("_m") for n in names]] < -1.0) and np.all(high > 1.0)
    robot = load_robot("ur5", frame="tool0")
    model = PoseModel(robot, [Marker("tip", "tool0", np.zeros(3))], ("frame", "gravity_lumped"),
                      (np.eye(3), np.zeros(3)))
    lumped_params = [p for p in model.parameters if p.family == "gravity_lumped"]
    assert lumped_params
    assert all((p.lower == 0.0) == p.label.endswith(" m") for p in lumped_params)
    assert all(p.lower == -math.inf for p in lumped_params if not p.label.endswith(" m"))
