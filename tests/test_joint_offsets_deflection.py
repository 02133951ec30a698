"""``joint_offsets``' deflection face: the loaded minus the unloaded tool at ``q + delta_0``, seen
through the Jacobian there (:meth:`JointOffsets.jacobian_change`).

Checked against independent computations: its analytic Jacobian columns against central finite
differences of the prediction; its prediction against the exact equilibria
(:func:`stiffness.mechanics.equilibrium.solve_equilibrium`, row by row) at the offset
configurations minus those at the commanded ones (error second order in the offsets); the
simulator's hidden offsets against the same exact equilibria.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import CRANK_ROCKER, write_four_bar

from stiffness.calibration.campaign import load_campaign
from stiffness.calibration.diagnose import diagnose
from stiffness.cli.main import main
from stiffness.elastic.effects import Geometry, Hypothesis, candidates, make_effect
from stiffness.elastic.effects.geometry import References
from stiffness.mechanics.equilibrium import solve_equilibrium
from stiffness.planning.simulate import parse_effect, simulate
from stiffness.robot.robot import load_robot

#: a soft UR10 (docs/diagnose.md, "Joint zero offsets")
KQ = [1.2e5, 8e4, 6e4, 2e4, 2e4, 1.5e4]


def _exact_dx(robot, q, k, force) -> np.ndarray:
    """(m, 3) exact tool displacements (m) of the configurations ``q`` (m, nq) under the forces
    (m, 3) or one force (3,), springs ``k`` (SI): the one-pose solver row by row."""
    force = np.broadcast_to(force, (len(q), 3))
    return np.array([solve_equilibrium(robot, qi, np.diag(k), f).dx
                     for qi, f in zip(q, force, strict=True)])


@pytest.fixture(scope="module")
def ur10():
    sim = simulate("ur10", kq=KQ, configs=4, loads_per_config=2, max_force=300.0, seed=0,
                   noise_std_m=0.0)
    camp = sim.campaign
    robot = camp.robot()
    geo = Geometry.of(robot)
    return camp, robot, geo


def _model(geo, camp, force, extra=(), rotation_weight=None):
    rows = geo.rows(camp.q, force)
    refs = References.of(geo, rows, 4e4, camp.deflection)
    base = Hypothesis(geo, rows, "enhanced", tuple(geo.joints), tuple(extra), refs,
                      rotation_weight=rotation_weight)
    return base.extended(make_effect("joint_offsets", None, geo).on_rows(base, rows))


def test_wrist_3_offset_is_no_parameter_when_the_tool_is_on_its_axis(ur10):
    """The UR10's tool0 lies on wrist_3's axis: its offset moves no Jacobian the campaign
    sees, so the candidate has the other five joints."""
    camp, _, geo = ur10
    model = _model(geo, camp, camp.force)
    assert model.effects[-1].joints == geo.joints[:5]
    assert [e.label for e in candidates(model.replaced(effects=()))].count("joint_offsets") == 1


@pytest.mark.parametrize("extra, rotation_weight", [
    ((), None), (("complementary_stiffness",), None), (("backlash:elbow_joint",), 0.1)])
def test_analytic_columns_match_finite_differences(ur10, extra, rotation_weight):
    camp, _, geo = ur10
    effects = [make_effect(*(e.split(":") + [None])[:2], geo) for e in extra]
    model = _model(geo, camp, camp.force, effects, rotation_weight)
    rng = np.random.default_rng(1)
    x = np.concatenate([np.log(KQ), rng.normal(size=model.n_params - len(KQ))])
    _, jac = model.predict_with_jacobian(x)
    offsets = slice(model.offsets[-2], model.offsets[-1])
    assert model.analytic_columns[offsets].all()
    step = 1e-4
    for i in range(offsets.start, offsets.stop):
        e = np.zeros(model.n_params)
        e[i] = step
        fd = (model.predict(x + e) - model.predict(x - e)) / (2 * step)
        assert np.abs(jac[..., i] - fd).max() <= 1e-6 * np.abs(fd).max()


def test_prediction_is_the_exact_change_to_second_order(ur10):
    """Offsets of 4, 2, 1 and 0.5 mrad on every joint (random signs), a tenth of the load so
    that the deflection's own third order stays below: the prediction's change minus the exact
    equilibria's at ``q + delta_0`` minus at ``q`` falls as delta_0 squared (log-log slope 2),
    with the second-order kinematics in the model."""
    camp, robot, geo = ur10
    force = 0.1 * camp.force
    model = _model(geo, camp, force, [make_effect("complementary_stiffness", None, geo)])
    signs = np.random.default_rng(3).choice([-1.0, 1.0], 6)
    q = np.array([robot.configuration(c) for c in camp.q])
    exact0 = _exact_dx(robot, q, KQ, force)
    x0 = np.concatenate([np.log(KQ), np.zeros(5)])
    sizes, errors = np.array([4e-3, 2e-3, 1e-3, 5e-4]), []
    for d in sizes:
        delta = d * signs
        q_d = np.array([robot.configuration(c + delta) for c in camp.q])
        exact = _exact_dx(robot, q_d, KQ, force) - exact0
        change = model.predict(np.concatenate([np.log(KQ), delta[:5] / 1e-3])) - model.predict(x0)
        errors.append(np.sqrt(np.mean((change - exact) ** 2)))
        assert errors[-1] < 2.0 * d * np.sqrt(np.mean(exact ** 2))  # relative O(delta_0)
    slope = np.polyfit(np.log(sizes), np.log(errors), 1)[0]
    assert 1.8 < slope < 2.2


def test_simulated_offsets_are_the_exact_equilibria_at_the_offset_configuration():
    """``stiffness simulate --effect joint_offsets=...`` measures the exact equilibrium at
    ``q + delta_0`` (not the first-order model): its noise-free deflections equal
    :func:`solve_equilibrium` there."""
    values = (0.2, -0.1, 0.15, -0.3, 0.25, -0.05)  # deg
    sim = simulate("ur10", kq=KQ, configs=3, loads_per_config=2, max_force=300.0, seed=2,
                   noise_std_m=0.0, effects=[parse_effect(
                       "joint_offsets=" + ",".join(str(v) for v in values))])
    camp = sim.campaign
    robot = camp.robot()
    q_d = np.array([robot.configuration(c + np.radians(values)) for c in camp.q])
    exact = _exact_dx(robot, q_d, KQ, camp.force)
    assert np.abs(camp.deflection - exact).max() < 1e-12  # SI
    q = np.array([robot.configuration(c) for c in camp.q])
    unmoved = _exact_dx(robot, q, KQ, camp.force)
    assert np.abs(unmoved - exact).max() > 1e-7  # the offsets show


# --- coupled and closed-loop robots: offsets on the controller's coordinates -----------------

SK120_DH = Path(__file__).parents[1] / "examples" / "sk120-dh" / "robot.toml"
#: the SK120's springs a tenth of the paper's (N.m/rad), so that 300 N deflect it visibly
SK120_KQ = [1.4098e5, 4.0076e4, 9.3528e4]


def _springs_on_chain(tmp_path: Path) -> Path:
    """examples/sk120-dh with its springs on the chain joints (``A`` not the identity)."""
    text = SK120_DH.read_text().replace('springs_on = "controller"', 'springs_on = "chain"')
    text = text.replace('compliant_joints = ["joint1", "joint2", "joint3"]',
                        'compliant_joints = ["waist", "shoulder", "elbow"]')
    path = tmp_path / "sk120-chain" / "robot.toml"
    path.parent.mkdir()
    path.write_text(text)
    return path


def _four_bar(tmp_path: Path):
    """The crank-rocker four-bar of conftest (not a parallelogram: its passive angles are not
    linear in the crank's, so ``K_C``'s closure term is not zero), four poses, forces of
    1 N."""
    linkage = write_four_bar(tmp_path / "fourbar", "fourbar", **CRANK_ROCKER)
    robot = load_robot(linkage.urdf, frame="tool_tip")
    rng = np.random.default_rng(5)
    coords = np.column_stack([rng.uniform(-1.0, 1.0, 4), rng.uniform(-0.8, 0.8, 4)])
    return robot, np.repeat(coords, 2, axis=0), rng.normal(size=(8, 3)) / np.sqrt(3)


def _sk120(source):
    sim = simulate(source, kq=SK120_KQ, configs=4, loads_per_config=2, max_force=300.0,
                   seed=0, noise_std_m=0.0)
    return sim.campaign.robot(), sim.campaign.q, sim.campaign.force


@pytest.mark.parametrize("case", ["sk120-dh", "sk120-dh springs on chain", "sk120",
                                  "four-bar"])
def test_coupled_and_closed_loop_prediction_is_the_exact_change(case, tmp_path):
    """Offsets on the robot's coordinates (the controller's for sk120-dh, whose chain joints
    move by ``A delta_0``; the actuated joints of a closed loop, whose passive joints follow):
    the predicted change minus the exact equilibria's at ``coordinates + delta_0`` minus at
    the coordinates falls as delta_0 squared (log-log slope 2), at 4 to 0.5 mrad on every
    coordinate the offset moves (random signs), loads small enough (9 N on the SK120, 1 N on
    the four-bar) that the left-out change of ``K_C``, first order in delta_0 but second in the
    load, stays below."""
    if case == "four-bar":
        robot, coords, force = _four_bar(tmp_path)
        kq = np.array([3000.0, 1500.0])
    else:
        robot, coords, force = _sk120({"sk120-dh": SK120_DH, "sk120": "sk120"}.get(
            case, _springs_on_chain(tmp_path) if "chain" in case else None))
        kq = np.array(SK120_KQ)
        force = 0.03 * force
    geo = Geometry.of(robot)
    rows = geo.rows(coords, force)
    refs = References.of(geo, rows, float(np.mean(kq)), np.zeros_like(force))
    base = Hypothesis(geo, rows, "enhanced", tuple(robot.compliant_joints),
                      (make_effect("complementary_stiffness", None, geo),), refs)
    offsets = make_effect("joint_offsets", None, geo).on_rows(base, rows)
    assert offsets.joints == robot.coordinate_joints  # every coordinate moves the target
    model = base.extended(offsets)
    signs = np.random.default_rng(3).choice([-1.0, 1.0], robot.n_coordinates)
    q = np.array([robot.configuration(c) for c in coords])
    exact0 = _exact_dx(robot, q, kq, force)
    x0 = np.concatenate([np.log(kq), np.zeros(robot.n_coordinates)])
    sizes, errors = np.array([4e-3, 2e-3, 1e-3, 5e-4]), []
    for d in sizes:
        delta = d * signs
        q_d = np.array([robot.configuration(c + delta, seed=s) for c, s in zip(coords, q,
                                                                                strict=True)])
        exact = _exact_dx(robot, q_d, kq, force) - exact0
        change = model.predict(np.concatenate([np.log(kq), delta / 1e-3])) - model.predict(x0)
        errors.append(np.sqrt(np.mean((change - exact) ** 2)))
        assert errors[-1] < 2.0 * d * np.sqrt(np.mean(exact ** 2))  # relative O(delta_0)
    slope = np.polyfit(np.log(sizes), np.log(errors), 1)[0]
    assert 1.8 < slope < 2.2, (errors, slope)


def test_simulate_cli_hides_offsets_on_the_controller_coordinates(tmp_path, capsys):
    """``stiffness simulate --effect joint_offsets=...`` on sk120-dh (a ``[controller]`` map):
    the offsets are on the controller's coordinates (deg), and the campaign's noise-free
    deflections are the exact equilibria at ``coordinates + delta_0``, read back from its
    files."""
    values = (0.2, -0.1, 0.15, -0.3, 0.25, -0.05)  # deg
    out = tmp_path / "sim"
    assert main(["simulate", "--robot", str(SK120_DH), "--kq", ",".join(map(str, SK120_KQ)),
                 "--effect", "joint_offsets=" + ",".join(map(str, values)), "--configs", "3",
                 "--loads-per-config", "2", "--max-force", "300", "--noise", "0", "--seed",
                 "2", "--out", str(out)]) == 0
    assert "hidden joint_offsets" in capsys.readouterr().out
    camp = load_campaign(out)
    robot = camp.robot()
    q = np.array([robot.configuration(c) for c in camp.q])
    q_d = np.array([robot.configuration(c + np.radians(values), seed=s)
                    for c, s in zip(camp.q, q, strict=True)])
    exact = _exact_dx(robot, q_d, SK120_KQ, camp.force)
    unmoved = _exact_dx(robot, q, SK120_KQ, camp.force)
    assert np.abs(camp.deflection - exact).max() < 1e-9  # m: the files' digits
    assert np.abs(unmoved - exact).max() > 1e-6  # the offsets show


@pytest.mark.parametrize("case", ["sk120-dh springs on chain", "four-bar"])
def test_jacobian_change_is_the_rows_jacobian_moved_along_the_coordinates(case, tmp_path):
    """``jacobian_change`` of a unit offset on each coordinate equals the central difference of
    the rows' Jacobian (``Geometry.rows``, loops closed) at the coordinates moved by it: through
    ``A`` onto the chain joints (springs on sk120-dh's chain), along the loop manifold with its
    curvature (the four-bar)."""
    if case == "four-bar":
        robot, coords, _ = _four_bar(tmp_path)
    else:
        robot, coords, _ = _sk120(_springs_on_chain(tmp_path))
    coords = coords[::2]
    geo = Geometry.of(robot)
    zero = np.zeros((len(coords), 3))
    rows = geo.rows(coords, zero)
    refs = References.of(geo, rows, 1e5, zero)
    model = Hypothesis(geo, rows, "conventional", tuple(geo.joints), (), refs)
    offsets = make_effect("joint_offsets", None, geo)
    step = 1e-6
    for i in range(robot.n_coordinates):
        unit = np.eye(robot.n_coordinates)[i]
        fd = (geo.rows(coords + step * unit, zero).jac
              - geo.rows(coords - step * unit, zero).jac) / (2 * step)
        change = offsets.jacobian_change(unit, model, rows)
        assert np.abs(change - fd).max() < 1e-7 * np.abs(fd).max(), i


#: hidden offsets (deg) on the SK120's six coordinates
HIDDEN_DEG = (0.6, -0.4, 0.5, -0.6, 0.4, -0.3)


@pytest.mark.parametrize("source", [SK120_DH, "sk120"], ids=["sk120-dh", "sk120"])
def test_diagnose_names_offsets_on_a_coupled_and_a_closed_loop_robot(source):
    """The SK120 at half the paper's springs, 12 configurations x 4 loads up to 400 N, 5 µm
    noise, offsets of 0.3-0.6 deg hidden on its coordinates (2.3 noise std RMS): the
    controller's of sk120-dh, the actuated joints of the shipped closed loop. ``diagnose``'s
    first step names ``joint_offsets`` with every offset determined and at least five of six
    intervals covering the truth (seed 0; measured on seeds 0-9, docs/diagnose.md)."""
    sim = simulate(source, kq=[0.5 * k for k in (1.4098e6, 4.0076e5, 9.3528e5)],
                   effects=[parse_effect("joint_offsets=" + ",".join(map(str, HIDDEN_DEG)))],
                   configs=12, loads_per_config=4, max_force=400.0, noise_std_m=5e-6, seed=0)
    steps = diagnose(sim.campaign, max_steps=1, propose=False, workers=1).summary()["steps"]
    assert [s["effect"] for s in steps] == ["joint_offsets"]
    params = list(steps[0]["parameters"].values())
    assert [p["determined"] for p in params] == [True] * 6
    covered = sum(p["ci95"][0] <= t <= p["ci95"][1] for p, t in zip(params, HIDDEN_DEG,
                                                                     strict=True))
    assert covered >= 5
