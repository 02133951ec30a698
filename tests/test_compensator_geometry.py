"""The spring compensator's geometry (issue 31, item 2): its angle is measured from the link's
upward direction at zero load (:func:`stiffness.mechanics.gravity.upward_angle`), computed from
the model's gravity and inertias; where no direction is up, from the joint's zero, said so.

Checked against independent computations: the carried centre of mass summed by hand from the
joint placements and link inertias, the joint axis from a finite rotation of the joint, the
gravity torque of ``pin.computeGeneralizedGravity``, and the closed-form balance of a one-joint
arm by a zero-free-length spring (``k a d = m g r``).
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest
from massless import massless
from stats import Coverage

from stiffness.calibration.campaign_writer import write_campaign
from stiffness.calibration.deflection_parameters import stiffness_parameters
from stiffness.calibration.diagnose import diagnose
from stiffness.calibration.diagnosis import SI_UNITS
from stiffness.calibration.fitting import compliance_covariance
from stiffness.calibration.selection import Noise, fit_model
from stiffness.cli.main import main
from stiffness.elastic.effects import make_effect
from stiffness.elastic.effects.base import effect_report
from stiffness.elastic.effects.geometry import Geometry, References
from stiffness.elastic.effects.hypothesis import Hypothesis
from stiffness.elastic.effects.preloads import GravityCompensator
from stiffness.elastic.file_model import elastic_model_of
from stiffness.elastic.model_contents import ModelEffect
from stiffness.elastic.model_file import read_model_file
from stiffness.errors import StiffnessError
from stiffness.mechanics.gravity import spring_balancer, upward_angle
from stiffness.planning.simulate import parse_effect, simulate
from stiffness.robot.robot import load_robot

#: (robot, revolute joints whose axis is horizontal at the neutral configuration)
ARMS = [("ur5", ["shoulder_lift_joint", "elbow_joint", "wrist_1_joint"]),
        ("kinova", ["j2s6s200_joint_2", "j2s6s200_joint_3", "j2s6s200_joint_5"])]
SPRING = (1e5, 3000.0)  # N/m, N
NOISE = 5e-6  # m


def _at(robot, joint: str, angle: float) -> np.ndarray:
    """The neutral configuration with ``joint`` at ``angle`` (rad; one or two coordinates)."""
    model = robot.model
    q = pin.neutral(model)
    jm = model.joints[model.getJointId(joint)]
    if jm.nq == 1:
        q[jm.idx_q] = angle
    else:
        q[jm.idx_q:jm.idx_q + 2] = math.cos(angle), math.sin(angle)
    return q


def _carried_com_and_axis(robot, joint: str, q: np.ndarray):
    """By hand: the centre of mass of every body the joint carries (world), the joint origin
    and its world axis from turning the joint by a small angle."""
    model = robot.model
    data = model.createData()
    pin.forwardKinematics(model, data, q)
    jid = model.getJointId(joint)
    carried = [k for k in range(1, model.njoints) if jid in model.supports[k]]
    mass = sum(model.inertias[k].mass for k in carried)
    com = sum(model.inertias[k].mass * data.oMi[k].act(model.inertias[k].lever)
              for k in carried) / mass
    origin, rotation = data.oMi[jid].translation.copy(), data.oMi[jid].rotation.copy()
    h = 1e-6
    pin.forwardKinematics(model, data, _at(robot, joint, robot.value_of(q, joint) + h))
    axis = rotation @ pin.log3(rotation.T @ data.oMi[jid].rotation) / h
    return com, origin, axis / np.linalg.norm(axis)


@pytest.mark.parametrize(("name", "joints"), ARMS, ids=[a[0] for a in ARMS])
def test_at_the_upward_angle_the_carried_centre_of_mass_is_straight_above_the_axis(name, joints):
    robot = load_robot(name)
    up = -robot.model.gravity.linear / np.linalg.norm(robot.model.gravity.linear)
    for joint in joints:
        found = upward_angle(robot, joint)
        assert found.reference == "upward", (joint, found)
        com, origin, axis = _carried_com_and_axis(robot, joint, _at(robot, joint,
                                                                    found.angle_rad))
        r = com - origin
        r -= axis * (axis @ r)
        u = up - axis * (axis @ up)
        assert np.linalg.norm(r) > 1e-3
        cosine = (r @ u) / np.linalg.norm(r) / np.linalg.norm(u)
        assert cosine == pytest.approx(1.0, abs=1e-9), (joint, cosine)


@pytest.mark.parametrize(("name", "joints"), ARMS, ids=[a[0] for a in ARMS])
def test_spring_torque_vanishes_upright_and_opposes_the_weight(name, joints):
    """Zero at the upward angle; of the opposite sign to the links' gravity torque on the
    joint (pin.computeGeneralizedGravity, other joints neutral) at every other angle."""
    robot = load_robot(name)
    geo = Geometry.of(robot)
    model, data = robot.model, robot.model.createData()
    for joint in joints:
        effect = make_effect("gravity_compensator", joint, geo)
        assert effect.settings["angle_reference"] == "upward"
        theta_up = effect.settings["angle_up_rad"]
        assert abs(float(effect.torque(np.array(SPRING), np.array(theta_up))[0])) < 1e-9
        iv = model.joints[model.getJointId(joint)].idx_v
        checked = 0
        for phi in np.linspace(-3.0, 3.0, 25):
            if abs(phi) < 1e-3:
                continue
            spring = float(effect.torque(np.array(SPRING), np.array(theta_up + phi))[0])
            weight = -pin.computeGeneralizedGravity(model, data, _at(robot, joint,
                                                                     theta_up + phi))[iv]
            assert spring * weight < 0.0, (joint, phi, spring, weight)
            checked += 1
        assert checked == 24


def _one_joint_arm(tmp_path, mass: float, r: float, axis: str, name: str):
    """A URDF: a base, one revolute joint about ``axis``, a link with a point ``mass`` (kg)
    at ``r`` (m) along its x axis."""
    urdf = f"""<robot name="{name}">
  <link name="base"/>
  <link name="arm"><inertial><origin xyz="{r} 0 0"/><mass value="{mass}"/>
    <inertia ixx="1e-9" ixy="0" ixz="0" iyy="1e-9" iyz="0" izz="1e-9"/></inertial></link>
  <link name="tip"/>
  <joint name="hinge" type="revolute"><parent link="base"/><child link="arm"/>
    <origin xyz="0 0 0.5"/><axis xyz="{axis}"/>
    <limit lower="-6.3" upper="6.3" effort="100" velocity="1"/></joint>
  <joint name="tool" type="fixed"><parent link="arm"/><child link="tip"/>
    <origin xyz="{r} 0 0"/></joint>
</robot>"""
    path = tmp_path / f"{name}.urdf"
    path.write_text(urdf)
    return load_robot(path)


def test_zero_length_spring_balances_a_one_joint_arm_in_closed_form(tmp_path):
    """A point mass m at r on a horizontal hinge about y: the link points up at -pi/2 (x turns
    to z), and the spring with k a d = m g r and F0 = k (d - a) (zero free length) cancels the
    weight at every angle."""
    m, r, a, d = 4.0, 0.35, 0.1, 0.3
    robot = _one_joint_arm(tmp_path, m, r, "0 1 0", "hinge_y")
    geo = Geometry.of(robot)
    effect = make_effect("gravity_compensator", "hinge", geo)
    assert effect.settings["angle_up_rad"] == pytest.approx(-math.pi / 2, abs=1e-12)
    g = 9.81
    k = m * g * r / (a * d)
    spring = np.array([k, k * (d - a)])
    data = robot.model.createData()
    worst = 0.0
    for theta in np.linspace(-3.0, 3.0, 31):
        q = np.array([theta])
        weight = -pin.computeGeneralizedGravity(robot.model, data, q)[0]
        # the weight's torque in closed form: m g r sin(phi), phi from straight up
        assert weight == pytest.approx(m * g * r * math.sin(theta + math.pi / 2), abs=1e-9)
        tau, _ = effect.torque(spring, np.array(theta))
        worst = max(worst, abs(float(tau) + weight))
    assert worst < 1e-9 * m * g * r


def test_no_upward_direction_falls_back_to_the_joint_zero_and_says_so(tmp_path):
    vertical = _one_joint_arm(tmp_path, 4.0, 0.35, "0 0 1", "hinge_z")
    found = upward_angle(vertical, "hinge")
    assert (found.angle_rad, found.reference) == (0.0, "joint_zero")
    assert "parallel to gravity" in found.reason
    massless = _one_joint_arm(tmp_path, 0.0, 0.35, "0 1 0", "massless")
    effect = make_effect("gravity_compensator", "hinge", Geometry.of(massless))
    assert effect.settings["angle_reference"] == "joint_zero"
    assert "joint's zero" in effect.describe() and "no mass" in effect.describe()
    on_axis = _one_joint_arm(tmp_path, 4.0, 0.0, "0 1 0", "on_axis")
    assert "on its axis" in upward_angle(on_axis, "hinge").reason


def test_a_controller_coordinate_falls_back_to_its_zero(tmp_path):
    """A robot.toml whose springs sit on controller coordinates (J1 is j1 one to one, J2 drives
    j2 and j3): on J1 the compensator's angle is measured from the coordinate's zero, said so
    (and no crash); J2 is no one link's joint and is refused in one line naming J1 (before, it
    was taken from J2's zero, as for J1)."""
    path = tmp_path / "arm" / "robot.toml"
    path.parent.mkdir()
    path.write_text("""[dh]
convention = "modified"
length_unit = "m"
angle_unit = "rad"
joints = [
  { name = "j1", type = "revolute", alpha = 0.0, a = 0.0, theta = 0.0, d = 0.4 },
  { name = "j2", type = "revolute", alpha = 1.5707963267948966, a = 0.1, theta = 0.0, d = 0.0 },
  { name = "j3", type = "revolute", alpha = 0.0, a = 0.5, theta = 0.0, d = 0.0 },
]
tool = { xyz = [0.4, 0.0, 0.0], rpy = [0.0, 0.0, 0.0] }
links = [ { mass = 5.0, com = [0.0, 0.0, 0.0] }, { mass = 4.0, com = [0.25, 0.0, 0.0] },
          { mass = 3.0, com = [0.2, 0.0, 0.0] } ]
[controller]
coordinates = ["J1", "J2", "J3"]
chain = { j1 = "J1", j2 = "J2", j3 = "-J2 - J3" }
springs_on = "controller"
""")
    robot = load_robot(path)
    effect = make_effect("gravity_compensator", "J1", Geometry.of(robot))
    assert effect.settings["angle_reference"] == "joint_zero"
    assert "controller coordinate" in effect.describe()
    with pytest.raises(StiffnessError, match=r"J2 turns j2, j3 .* \(J1\) or drop it$") as err:
        make_effect("gravity_compensator", "J2", Geometry.of(robot))
    assert "\n" not in str(err.value)
    assert upward_angle(robot, "j2").reference == "upward"  # the chain joint has a link


def test_a_model_file_written_before_the_upward_reference_keeps_its_meaning():
    """Settings without ``angle_reference`` (lever, base, ``angle0_rad`` only) read as the
    joint's zero: phi = theta + angle0_rad, the tension at the joint's zero."""
    old = {"lever_m": 0.12, "base_m": 0.25, "angle0_rad": 0.2}
    effect = GravityCompensator.at_place("joint2").configured(old)
    assert effect.settings["angle_reference"] == "joint_zero"
    assert "before the upward reference" in effect.describe()
    theta = np.linspace(-2.0, 2.0, 9)
    tau, dtau = effect.torque(np.array(SPRING), theta)
    want, dwant = spring_balancer(theta, *SPRING, 0.12, 0.25, 0.2)
    np.testing.assert_allclose(tau, want, rtol=1e-14)
    np.testing.assert_allclose(dtau, dwant, rtol=1e-14)
    assert ModelEffect("gravity_compensator", "joint2", "preload", settings=old).settings == old


# --- the lever and base lengths: declared, or the base fitted when the data determine it ---


def test_the_torque_depends_on_the_lengths_only_through_f0_a_k_a2_and_their_ratio():
    """Closed form behind holding the lever: scaling both lengths by s and F0, k by 1/s,
    1/s^2 leaves the torque and its derivative unchanged (so the data can at most give a/d)."""
    theta = np.linspace(-3.0, 3.0, 41)
    k, f0, a, d = 2e5, 700.0, 0.12, 0.35
    tau, dtau = spring_balancer(theta, k, f0, a, d, 0.0)
    for s in (0.3, 1.7, 4.0):
        t_s, dt_s = spring_balancer(theta, k / s ** 2, f0 / s, s * a, s * d, 0.0)
        np.testing.assert_allclose(t_s, tau, rtol=1e-12, atol=1e-12 * np.abs(tau).max())
        np.testing.assert_allclose(dt_s, dtau, rtol=1e-12, atol=1e-12 * np.abs(dtau).max())
    # and the ratio matters: another a/d with F0 a and k a^2 kept changes the torque
    other, _ = spring_balancer(theta, k, f0, a, 0.5, 0.0)
    assert np.abs(other - tau).max() > 0.05 * np.abs(tau).max()


KINOVA = ("kinova", ["j2s6s200_joint_1", "j2s6s200_joint_2", "j2s6s200_joint_3"],
          [2e4, 1.5e4, 1e4], "j2s6s200_joint_2")
#: A spring slack with the link up (F0 = 0), lever 0.3 m, base 0.4 m: a/d = 0.75 shapes the
#: torque, so the data determine the base given the lever (N/m, N, m, m)
SLACK_SPRING = (1e5, 0.0, 0.3, 0.4)


def _slack_campaign(seed: int, configs: int = 10, loads: int = 4, robot: str = KINOVA[0]):
    _, joints, kq, where = KINOVA
    spec = f"gravity_compensator:{where}=" + ",".join(f"{v:g}" for v in SLACK_SPRING)
    return simulate(robot, kq=kq, compliant_joints=joints, max_force=100.0,
                    noise_std_m=NOISE, effects=[parse_effect(spec)], configs=configs,
                    loads_per_config=loads, seed=seed, joint_angles="link").campaign


def test_the_base_given_the_declared_lever_is_fitted_with_covering_intervals():
    """Small campaigns (6 poses x 3 loads), the lever declared at 0.1 m (the default): the
    fitted base, stiffness and preload are those of the true spring rescaled to that lever
    (d = 0.4 * 0.1/0.3 m, k = 1e5 * 9, F0 = 0); their reported 95 % intervals and the three
    joint stiffnesses' (as diagnose reports them), 150 in all, cover the truth two-sidedly
    (:meth:`stats.Coverage.check`). A joint stiffness the data do not bound and cannot tell
    from its compensator (correlation about 1: joint_2 in 2 of the first 26 campaigns) is
    reported as not told apart, with no interval to count, and a campaign more is drawn."""
    k, f0, a, d = SLACK_SPRING
    s = 0.1 / a
    truth = (*KINOVA[2], k / s ** 2, f0 / s, d * s)
    cov, confounded = Coverage(), []
    for seed in range(40):
        if cov.n >= 150:
            break
        campaign = _slack_campaign(seed, configs=6, loads=3)
        robot = campaign.robot()
        geo = Geometry.of(robot)
        rows = geo.rows(campaign.q, campaign.force, campaign.moment, joint_angles="link")
        refs = References.of(geo, rows, 2e4, campaign.deflection)
        freed = make_effect("gravity_compensator", KINOVA[3], geo).settings_freed()
        assert freed.parameter_names == ("stiffness", "preload", "base")
        model = Hypothesis(geo, rows, "enhanced", tuple(robot.compliant_joints), (freed,), refs)
        fit = fit_model(model, campaign.deflection, NOISE,
                        np.concatenate([np.log(KINOVA[2]), freed.start()]))
        matrix = compliance_covariance(fit, NOISE, campaign.deflection)
        quantile = Noise(NOISE).two_sided()
        edge = Noise(NOISE).one_sided()
        params = [*stiffness_parameters(fit, matrix, quantile, edge),
                  *effect_report(freed, fit.x[3:], matrix[3:, 3:], refs, SI_UNITS, quantile)]
        for p, want in zip(params, truth, strict=True):
            if p.confounded_with:  # no interval: reported as not told apart from the spring
                confounded.append(p)
                continue
            cov.add(p.value, p.ci95, want)
    assert all(p.name in KINOVA[1] and "not told apart" in p.text() for p in confounded)
    assert len(confounded) <= 10, [p.text() for p in confounded]
    cov.check()


def test_diagnose_fits_the_base_or_holds_it_and_the_model_file_says_which(tmp_path):
    """End to end: the slack spring's base is fitted (the model file's parameters carry it,
    geometry_source fitted); the file's elastic model applies the fitted base. The arm without
    its masses (:func:`massless.massless`): the spring, far stronger than the Kinova's weight
    needs, is judged against its joint springs (its angle from the joint's zero)."""
    d = diagnose(_slack_campaign(1, robot=massless(KINOVA[0])), propose=False)
    comp = [e for e in d.final.model.effects if e.name == "gravity_compensator"]
    assert comp and comp[0].settings["geometry_source"] == "fitted", d.final.model.describe()
    path = d.model_file().write(tmp_path / "model.json")
    model = read_model_file(path)
    entry = next(e for e in model.effects if e.name == "gravity_compensator")
    assert entry.settings["geometry_source"] == "fitted"
    assert [p.name for p in entry.parameters] == ["stiffness", "preload", "base"]
    elastic = elastic_model_of(model)
    (_, k, f0, geometry), = elastic.compensators
    assert geometry["base_m"] == pytest.approx(entry.value("base"), rel=1e-12)
    assert geometry["lever_m"] == 0.1
    assert (k, f0) == (entry.value("stiffness"), entry.value("preload"))


def test_declared_geometry_flag_reaches_the_model_file_and_bad_values_are_one_line(tmp_path,
                                                                                     capsys):
    # the UR5 without its masses (:func:`massless.massless`): the spring, 35 times the weight
    # the shoulder carries, is judged against the joint springs
    sim = simulate(massless("ur5"), kq=[3e4, 2e4, 1.5e4],
                   compliant_joints=["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"],
                   max_force=100.0, noise_std_m=NOISE, configs=6, loads_per_config=4, seed=3,
                   effects=[parse_effect("gravity_compensator:shoulder_lift_joint=1e5,2e4")],
                   joint_angles="link")
    write_campaign(sim.campaign, tmp_path / "c")
    assert main(["diagnose", str(tmp_path / "c"), "--no-proposals", "--quiet", "--out",
                 str(tmp_path / "out"), "--compensator-geometry",
                 "shoulder_lift_joint=0.12,0.35"]) == 0
    capsys.readouterr()
    model = read_model_file(tmp_path / "out" / "final-model.json")
    entry = next(e for e in model.effects if e.name == "gravity_compensator")
    # a zero-free-length spring: its torque is k a d sin(phi), the ratio a/d never shows
    assert entry.settings["lever_m"] == 0.12 and entry.settings["base_m"] == 0.35
    assert entry.settings["geometry_source"] == "declared"
    assert "do not determine the base" in entry.settings["geometry_note"]
    assert "declared, held" in entry.description
    for bad in ("shoulder_lift_joint=0.12", "wrist_3_joint=0.1,0.3",
                "shoulder_lift_joint=0.2,0.2"):
        assert main(["diagnose", str(tmp_path / "c"), "--no-proposals", "--quiet",
                     "--compensator-geometry", bad]) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and err, (bad, err)
