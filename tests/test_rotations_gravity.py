"""Rotations in campaigns, and the robot's weight and spring compensators (issue 16, items 1-2).

Statistical claims run over seeds against binomial bounds; campaigns are tiny (4-6 poses).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math

import numpy as np
import pinocchio as pin
import pytest
from massless import massless
from stats import Coverage

from stiffness.calibration.campaign import load_campaign
from stiffness.calibration.campaign_writer import write_campaign
from stiffness.calibration.diagnose import diagnose
from stiffness.calibration.identify import identify
from stiffness.cli.main import main
from stiffness.elastic.effects import make_effect
from stiffness.elastic.effects.base import effect_variables
from stiffness.elastic.effects.geometry import Geometry, References
from stiffness.elastic.effects.hypothesis import Hypothesis
from stiffness.elastic.file_model import elastic_model_of
from stiffness.elastic.model_file import read_model_file
from stiffness.errors import FileFormatError, StiffnessError
from stiffness.mechanics.gravity import gravity_preload, spring_balancer, with_payload
from stiffness.planning.simulate import parse_effect, simulate
from stiffness.robot.robot import load_robot

ARM = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"]
KQ = np.array([3e4, 2e4, 1.5e4])
NOISE = 5e-6


def _sim(effects=(), seed=0, configs=4, loads=2, robot="ur5", **kw):
    args = {"kq": KQ, "compliant_joints": ARM, "max_force": 100.0, "noise_std_m": NOISE,
            "rotations": True, **kw}
    return simulate(robot, effects=[parse_effect(e) for e in effects], configs=configs,
                    loads_per_config=loads, seed=seed, **args)


@functools.lru_cache(maxsize=8)
def _diagnosed(effect: str, seed: int):
    """A diagnosed campaign of 6 poses x 4 loads with ``effect`` hidden (shared by tests); a
    compensator on the UR5 without its masses (:func:`massless.massless`: the spring, 3.4 times
    the weight the real arm's shoulder carries, is judged against the joint springs)."""
    robot = massless("ur5") if effect.startswith("gravity_compensator") else "ur5"
    sim = _sim([effect], seed=seed, configs=6, loads=4, robot=robot)
    return sim, diagnose(sim.campaign, propose=False)


# ------------------------------------------------------------------------------------------
# identification with rotations


#: All six UR5 joints compliant (N.m/rad), the target 7 cm off wrist_3's axis so that forces
#: load it: six intervals per campaign for the coverage test.
ALL_JOINTS = [*ARM, "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]
KQ_ALL = np.array([3e4, 2e4, 1.5e4, 5e3, 5e3, 4e3])


def test_rotation_intervals_cover_the_truth_at_95_percent():
    """25 campaigns of 4 poses x 2 loads with rotations, all six joints compliant: the
    reported intervals (150) cover the truth two-sidedly (:meth:`stats.Coverage.check`)."""
    cov = Coverage()
    for seed in range(25):
        r = identify(_sim(seed=seed, kq=KQ_ALL, compliant_joints=ALL_JOINTS,
                          target_offset_m=[0.05, 0.0, 0.05]).campaign, starts=1)
        assert r.rotation_residuals is not None and r.n_residuals == 6 * 8
        for joint, truth in zip(r.to_dict()["joints"], KQ_ALL, strict=True):
            cov.add(joint["k"], joint["ci95"], truth)
    cov.check()


def test_the_enhanced_kinematics_bias_is_the_exact_equilibriums():
    """Why the 4 x 2 campaigns' shoulder_lift, elbow and wrist_1 intervals covered 0.92-0.93
    at 100 N (docs/diagnose.md): the enhanced formulation's first-order kinematics departs
    from the simulator's exact equilibrium at second order in the load. Noise-free (1 nm,
    0.01 urad declared), each fitted ln k's error over its standard error is the bias
    identify reports (``kinematics_bias_se``, from the second-order term), within 2 % of the
    largest; halving the load quarters it; the exact formulation's errors are the noise's."""
    errors = {}
    for force in (100.0, 50.0):
        sim = _sim(seed=1, kq=KQ_ALL, compliant_joints=ALL_JOINTS, max_force=force,
                   noise_std_m=1e-9, rotation_noise_std_rad=1e-8,
                   target_offset_m=[0.05, 0.0, 0.05])
        r = identify(sim.campaign, starts=1)
        z = (np.log(r.k) - np.log(KQ_ALL)) / np.sqrt(np.diag(r.covariance_log))
        np.testing.assert_allclose(r.kinematics_bias_se, z, atol=0.02 * np.abs(z).max())
        assert r.to_dict()["kinematics_bias_se"] == pytest.approx(list(r.kinematics_bias_se))
        errors[force] = z
        exact = identify(sim.campaign, formulation="exact", starts=1)
        assert exact.kinematics_bias_se is None
        z_exact = np.log(exact.k / KQ_ALL) / np.sqrt(np.diag(exact.covariance_log))
        assert np.abs(z_exact).max() < 4.0 < 100.0 < np.abs(z).max()  # the 1 nm noise's own
    np.testing.assert_allclose(errors[50.0], errors[100.0] / 4.0,
                               atol=0.03 * np.abs(errors[100.0]).max())
    # at 5 um the 200 N campaign's wrist_1 is biased by about 2 standard errors: said
    noisy = identify(_sim(seed=1, kq=KQ_ALL, compliant_joints=ALL_JOINTS, max_force=200.0,
                          target_offset_m=[0.05, 0.0, 0.05]).campaign, starts=1)
    assert any("first-order kinematics biases k" in n and "wrist_1_joint" in n
               for n in noisy.notes), noisy.notes


def test_rotations_narrow_a_joint_positions_leave_poorly_determined():
    # the target sits 1 cm off wrist_3's axis: its deflection barely moves the target point
    joints = ["shoulder_lift_joint", "elbow_joint", "wrist_3_joint"]
    # 6 configurations: wrist_3's interval with rotations is 0.88 of its value wide (4 gave
    # 1.09 once the interval became the compliance's, cbdc42f), from positions 18.8
    sim = simulate("ur5", kq=[2e4, 1.5e4, 5e3], compliant_joints=joints,
                   target_offset_m=[0.01, 0.0, 0.0], configs=6, loads_per_config=2,
                   max_force=100.0, noise_std_m=NOISE, seed=1, rotations=True)
    both = identify(sim.campaign, starts=1)
    positions = identify(dataclasses.replace(sim.campaign, rotation=None,
                                             rotation_noise_std_rad=None), starts=1)
    assert positions.relative_ci_width[2] > 5.0          # undetermined from positions
    assert both.relative_ci_width[2] < 1.0               # determined with rotations
    assert positions.relative_ci_width[2] / both.relative_ci_width[2] > 10.0
    assert both.ci95_low[2] <= 5e3 <= both.ci95_high[2]


def test_undeclared_rotation_noise_is_estimated_per_kind():
    sim = _sim(seed=3, configs=6)
    c = dataclasses.replace(sim.campaign, rotation_noise_std_rad=None)
    r = identify(c, starts=1)
    truth = NOISE / 0.1
    assert r.rotation_sigma_source == "residuals"
    assert 0.6 * truth < r.rotation_sigma_rad < 1.5 * truth
    d = diagnose(c, propose=False)
    assert d.rotation_noise_source == "residuals"
    rms = d.record()["rms_by_kind"]["final"]
    assert rms["rotation"] == pytest.approx(truth * 180 / np.pi, rel=0.4)   # deg
    assert rms["translation"] == pytest.approx(NOISE * 1e3, rel=0.4)        # mm


# ------------------------------------------------------------------------------------------
# rotational parts of the effects


def _model(robot, coords, force, moment, effects):
    geo = Geometry.of(robot)
    rows = geo.rows(coords, force, moment)
    refs = References.of(geo, rows, 2e4, np.full((1, 3), 1e-3))
    return Hypothesis(geo, rows, "enhanced", tuple(ARM), tuple(effects), refs, rotation_weight=1.0)


def test_effects_rotational_parts():
    robot = load_robot("ur5", compliant_joints=ARM)
    coords = np.tile([0.3, -1.2, 1.5, -0.3, 1.57, 0.2], (3, 1))
    moment = np.array([[5.0, 0, 0], [0, 5.0, 0], [0, 0, 5.0]])
    geo = Geometry.of(robot)
    x0 = np.log(KQ)
    base = _model(robot, coords, np.zeros((3, 3)), moment, ())
    ref = base.predict(x0)
    # a target offset moves where the point is measured: under pure moments the rotations stay
    off = make_effect("target_offset", None, geo)
    m = base.extended(off)
    out = m.predict(np.concatenate([x0, effect_variables(off, np.array([0.05, -0.02, 0.03]),
                                                         m.refs)]))
    np.testing.assert_allclose(out[:, 3:], ref[:, 3:], rtol=1e-12, atol=1e-15)
    assert np.abs(out[:, :3] - ref[:, :3]).max() > 1e-7
    # a frame misalignment turns the measured rotation like the measured translation
    phi = np.array([0.01, -0.02, 0.03])
    mis = make_effect("frame_misalignment", None, geo)
    out = base.extended(mis).predict(np.concatenate([x0, phi / 0.01]))
    turn = pin.exp3(phi)
    np.testing.assert_allclose(out[:, 3:], ref[:, 3:] @ turn.T, rtol=1e-10)
    np.testing.assert_allclose(out[:, :3], ref[:, :3] @ turn.T, rtol=1e-10)


def test_link_compliance_rotation_matches_the_exact_simulation():
    effect = "link_compliance:elbow_joint->wrist_1_joint=5e4"
    sim = _sim([effect], seed=2, noise_std_m=0.0, rotation_noise_std_rad=0.0)
    plain = _sim([], seed=2, noise_std_m=0.0, rotation_noise_std_rad=0.0)
    c = sim.campaign
    robot = c.robot()
    link = make_effect("link_compliance", "elbow_joint->wrist_1_joint", Geometry.of(robot))
    m = _model(robot, c.q, c.force, None, (link,))
    pred = m.predict(np.concatenate([np.log(KQ), effect_variables(link, np.array([5e4, 5e4]),
                                                                  m.refs)]))
    size = np.abs(c.rotation - plain.campaign.rotation).max()
    assert size > 1e-5                          # the bend turns the frame
    assert np.abs(pred[:, 3:] - c.rotation).max() < 0.05 * size


# ------------------------------------------------------------------------------------------
# gravity


def test_gravity_torque_and_stiffness_against_finite_differences():
    robot = load_robot("ur5", compliant_joints=ARM)
    q = robot.configuration(np.array([0.3, -1.0, 1.2, -0.5, 1.0, 0.4]))
    model = with_payload(robot, 7.0, np.array([0.02, -0.03, 0.05]))
    data = model.createData()
    tau, k = gravity_preload(robot, q, model=model)

    def potential(dq):
        return pin.computePotentialEnergy(model, data, pin.integrate(model, q, dq))

    h = 1e-5
    v = robot.compliant_v
    for a, ia in enumerate(v):
        e = np.zeros(model.nv)
        e[ia] = h
        assert tau[a] == pytest.approx(-(potential(e) - potential(-e)) / (2 * h), rel=1e-6,
                                       abs=1e-6)
        plus = gravity_preload(robot, pin.integrate(model, q, e), model=model)[0]
        minus = gravity_preload(robot, pin.integrate(model, q, -e), model=model)[0]
        np.testing.assert_allclose(k[:, a], (plus - minus) / (2 * h), rtol=1e-5, atol=1e-4)


def test_spring_balancer_derivative_and_closed_form():
    theta = np.linspace(-2.5, 2.5, 11)
    tau, dtau = spring_balancer(theta, 3e4, 500.0, 0.1, 0.3, 0.2)
    h = 1e-6
    fd = (spring_balancer(theta + h, 3e4, 500.0, 0.1, 0.3, 0.2)[0]
          - spring_balancer(theta - h, 3e4, 500.0, 0.1, 0.3, 0.2)[0]) / (2 * h)
    np.testing.assert_allclose(dtau, fd, rtol=1e-6, atol=1e-6)
    # a zero-free-length spring balances a pendulum: tau = -k a d sin(phi) (free length 0)
    length0 = 0.3 - 0.1
    t0, _ = spring_balancer(theta, 1e3, 1e3 * length0, 0.1, 0.3, 0.0)
    np.testing.assert_allclose(t0, -1e3 * 0.03 * np.sin(theta), rtol=1e-12, atol=1e-12)


def test_gravity_model_matches_the_exact_equilibrium():
    for effect, values in (("gravity_preload=20,0,0,50", [20.0, 0.0, 0.0, 0.05]),
                           ("gravity_compensator:shoulder_lift_joint=3e4,2000", [3e4, 2e3])):
        h = parse_effect(effect)
        sim = _sim([effect], seed=1, noise_std_m=0.0, rotation_noise_std_rad=0.0)
        c = sim.campaign
        robot = c.robot()
        e = make_effect(h.name, h.where, Geometry.of(robot))
        m = _model(robot, c.q, c.force, None, (e,))
        pred = m.predict(np.concatenate([np.log(KQ),
                                         effect_variables(e, np.array(values), m.refs)]))
        bare = _model(robot, c.q, c.force, None, ()).predict(np.log(KQ))
        meas = np.hstack([c.deflection, c.rotation])
        err = np.sqrt(np.mean((pred - meas)[:, :3] ** 2))
        size = np.sqrt(np.mean((bare - meas)[:, :3] ** 2))
        # measured 10 % (payload) and 6.5 % (compensator) here; 4-8 % on 6 poses x 4 loads
        assert size > 2 * NOISE and err < 0.12 * size, (effect, err, size)


@pytest.mark.parametrize(("effect", "truth"), [
    ("gravity_preload=20,0,0,50", [20.0, 0.0, 0.0, 0.05]),
    ("gravity_compensator:shoulder_lift_joint=3e4,2000", [3e4, 2e3]),
])
def test_hidden_gravity_is_named_first_and_recovered(effect, truth):
    hidden = parse_effect(effect)
    covered = total = 0
    for seed in (1, 3):
        result = _diagnosed(effect, seed)[1]
        assert result.steps and result.steps[0].effect.name == hidden.name
        assert result.steps[0].effect.where == hidden.where
        params = result.final_parameters_si[result.steps[0].effect.label]
        for p, t in zip(params, truth, strict=False):
            if p.held:  # not determined, held at its nominal value: no interval to cover
                continue
            covered += int(p.ci95[0] <= t <= p.ci95[1])
            total += 1
    # at 95 % per interval, missing more than one of these few is a 3 % event (the payload's
    # seed 1 holds com_z, its interval 1.03 m wide against a 1 m scale: 7 intervals, 6 covered)
    assert total >= 2 * len(truth) - 1
    assert covered >= total - 1


def test_payload_in_the_model_file_enters_k_x(tmp_path):
    sim, result = _diagnosed("gravity_preload=20,0,0,50", 3)
    result.write(tmp_path)
    model = read_model_file(tmp_path / "final-model.json")
    [grav] = [e for e in model.effects if e.name == "gravity_preload"]
    assert grav.kind == "preload"
    cm = elastic_model_of(model)
    assert grav in cm.applied
    q = sim.campaign.q[0]
    at = cm.at(q, np.zeros(3))
    assert np.abs(at.preload_torque).max() > 10.0          # the arm's weight, N.m
    step = 5.0
    fd = np.column_stack([(cm.deflection(q, step * e) - cm.deflection(q, -step * e)) / (2 * step)
                          for e in np.eye(3)])
    np.testing.assert_allclose(at.compliance(), fd, rtol=1e-2, atol=1e-12)
    # conventional: no K_C, so no K_g either; the weight still moves the pose
    assert np.abs(cm.at(q, np.zeros(3), "conventional").k_preload).max() == 0.0


def test_compensator_in_the_model_file_enters_k_x(tmp_path):
    sim, result = _diagnosed("gravity_compensator:shoulder_lift_joint=3e4,2000", 3)
    result.write(tmp_path)
    model = read_model_file(tmp_path / "final-model.json")
    comp = [e for e in model.effects if e.name == "gravity_compensator"]
    assert comp and comp[0].kind == "stiffness" and comp[0].settings["lever_m"] == 0.1
    cm = elastic_model_of(model)
    q = sim.campaign.q[0]
    at = cm.at(q, np.zeros(3))
    # the compliance is the derivative of the fitted model's deflection (finite differences);
    # that model is first order in the preload's deflection, at() evaluates at the preloaded
    # pose (7 % apart at the commanded pose, 0.3 % at the preloaded one)
    step = 5.0
    fd = np.column_stack([(cm.deflection(q, step * e) - cm.deflection(q, -step * e)) / (2 * step)
                          for e in np.eye(3)])
    np.testing.assert_allclose(at.compliance(), fd, rtol=1e-2, atol=1e-12)
    # the spring's angle derivative is the joint's extra stiffness at the preloaded angle
    i = cm.robot.compliant_joints.index("shoulder_lift_joint")
    jm = cm.robot.model.joints[cm.robot.model.getJointId("shoulder_lift_joint")]
    # its angle is measured from the joint's zero: the arm without its masses has no upward
    # direction (the upward reference on the arm with them: tests/test_compensator_geometry.py)
    assert comp[0].settings["angle_reference"] == "joint_zero"
    angle_up = comp[0].settings["angle_up_rad"]
    assert angle_up == 0.0
    # on the UR5 with its masses, up is about -pi/2 (its upper arm lies along x at zero)
    real = make_effect("gravity_compensator", "shoulder_lift_joint", Geometry.of(load_robot("ur5")))
    assert real.settings["angle_reference"] == "upward"
    assert real.settings["angle_up_rad"] == pytest.approx(-math.pi / 2, abs=0.02)
    _, dtau = spring_balancer(at.q[jm.idx_q] - angle_up, comp[0].value("stiffness"),
                              comp[0].value("preload"), 0.1, 0.3, 0.0)
    assert at.k_preload[i, i] == pytest.approx(dtau, rel=1e-12)
    assert abs(at.q[jm.idx_q] - q[1]) > 1e-6            # the spring's torque moved the arm


# ------------------------------------------------------------------------------------------
# files and errors


def test_simulate_rotations_writes_and_reads_back(tmp_path):
    out = tmp_path / "sim"
    assert main(["simulate", "--robot", "ur5", "--compliant-joints", ",".join(ARM), "--kq",
                 "3e4,2e4,1.5e4", "--configs", "3", "--loads-per-config", "2", "--rotations",
                 "--effect", "gravity_preload=10", "--out", str(out), "--quiet"]) == 0
    header = (out / "measurements.csv").read_text().splitlines()[0]
    assert header.endswith("dx,dy,dz,rx,ry,rz")
    c = load_campaign(out)
    assert c.rotation is not None and c.rotation_noise_std_rad > 0
    assert "rotation_noise_std" in (out / "campaign.toml").read_text()
    truth = json.loads((out / "truth.json").read_text())
    assert truth["settings"]["rotations"] is True
    # units: rotations in rad while angles stay in deg
    c2 = dataclasses.replace(c, units=dataclasses.replace(c.units, rotation_unit="rad"))
    write_campaign(c2, tmp_path / "rad")
    back = load_campaign(tmp_path / "rad")
    np.testing.assert_allclose(back.rotation, c.rotation, rtol=1e-12)
    assert back.rotation_noise_std_rad == pytest.approx(c.rotation_noise_std_rad)
    assert 'rotation = "rad"' in (tmp_path / "rad" / "campaign.toml").read_text()


def _break(tmp_path, csv_edit=None, toml_edit=None):
    out = tmp_path / "c"
    write_campaign(_sim(seed=0, configs=2).campaign, out)
    if csv_edit:
        path = out / "measurements.csv"
        path.write_text(csv_edit(path.read_text()))
    if toml_edit:
        path = out / "campaign.toml"
        path.write_text(toml_edit(path.read_text()))
    with pytest.raises(StiffnessError) as info:
        load_campaign(out)
    assert isinstance(info.value, FileFormatError)        # typed: names file, line, column
    text = str(info.value)
    assert "\n" not in text
    return text


def _drop_rz(text):
    lines = text.splitlines()
    return "\n".join(",".join(line.split(",")[:-1]) for line in lines) + "\n"


def _nan_in_ry(text):
    lines = text.splitlines()
    cells = lines[2].split(",")
    cells[-2] = "nan"
    lines[2] = ",".join(cells)
    return "\n".join(lines) + "\n"


def test_malformed_rotation_columns_get_one_line_errors(tmp_path):
    assert "'rz'" in _break(tmp_path, csv_edit=_drop_rz)
    text = _break(tmp_path, csv_edit=_nan_in_ry)
    assert "ry" in text and "finite number" in text
    text = _break(tmp_path, toml_edit=lambda t: t.replace('[units]\n', '[units]\nrotation = '
                                                          '"grad"\n'))
    assert "[units] rotation" in text
    text = _break(tmp_path, toml_edit=lambda t: t.replace('angle = "deg"\n', ''))
    assert "angle" in text
    no_rot = lambda t: "\n".join(",".join(r.split(",")[:-3]) for r in t.splitlines()) + "\n"  # noqa: E731
    assert "rotation_noise_std" in _break(tmp_path, csv_edit=no_rot)


def test_both_spellings_of_the_rotation_noise_are_read(tmp_path):
    """``rotation_noise_std`` (written) and ``noise_std_rotation`` (the pose campaigns'
    spelling) give the same campaign; both at once are refused in one line."""
    c = _sim(seed=0, configs=2).campaign
    write_campaign(c, tmp_path / "c")
    path = tmp_path / "c" / "campaign.toml"
    written = path.read_text()
    assert "rotation_noise_std = " in written
    path.write_text(written.replace("rotation_noise_std = ", "noise_std_rotation = "))
    assert load_campaign(tmp_path / "c").rotation_noise_std_rad == pytest.approx(
        c.rotation_noise_std_rad, rel=1e-12)
    text = _break(tmp_path, toml_edit=lambda t: t.replace(
        "rotation_noise_std = ", "noise_std_rotation = 0.002\nrotation_noise_std = "))
    assert "two spellings" in text and "noise_std_rotation" in text
