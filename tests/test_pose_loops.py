"""Absolute-pose calibration of robots with closed kinematic loops (issue 35, "one forward
model"): the SK120's parallelogram five-bar, a tilted non-parallelogram four-bar and the
shipped Stewart-Gough platform (``hexapod``).

The pose model's loaded configuration is the fixed point ``q(u + delta_0 + Delta u)``, the
loops closed over their passive joints, the springs carrying ``S(q)^T (J^T w - g)`` with
``S = dq/du`` the loop's tangent map (:mod:`stiffness.calibration.pose_loops`). Checked here:

* against an independent computation, the elastic model's exact loaded equilibrium
  (``ElasticModel.with_effects(...).at(q, wrench).equilibrium()``, Newton on the constraint
  manifold), to the loops' closure tolerance on displacements of millimetres (measured 4e-15 m
  on the SK120, 2e-13 m on the hexapod, 8e-12 m on the four-bar: the elastic model's closure,
  stopped at its tolerance, where the pose model's is exact to round-off, one Newton step past
  it; 3e-15 m on all three with the elastic model's tolerance at 1e-14 m); the pose
  simulator's truth
  (its own fixed point; the projection through the loop, ``LoopClosure.tangent``, is the
  model's, which the elastic model's equilibrium checks) against it
  too; gravity's torque through the loop (no robot file here has masses: the four-bar is
  given some) against the minimum of the potential energy;
* every Jacobian column against central differences: to 1e-6 of the largest difference at
  rigid springs (exact there: ``J_p T``), to 1e-2 at the springs' compliance (first order in
  ``C dtau/dq``, as on open chains; measured 6e-4 on the SK120);
* end to end: ``stiffness simulate --kind poses`` on the SK120 with hidden springs and zero
  offsets, then ``diagnose``: the springs and offsets are named and their 95 % intervals hold
  the truth;
* the families beyond the joint springs through the loop: the lumped weight against the known
  masses, a base tilt's and every family's columns, a compensator and a link bend against the
  pose simulator (its own spring law, its exact bends);
* an error inside a loop (a passive joint's zero offset, a placement error, bend or tilt at a
  joint on a loop's path) has no parameter, and hiding one is refused with a typed one-line
  error naming the valid joints.
"""

from __future__ import annotations

import json
import pickle

import numpy as np
import pinocchio as pin
import pytest
from pose_columns import assert_columns
from pose_truth import truth
from scipy.optimize import minimize

from stiffness.calibration.pose_loops import LoopGeometryError
from stiffness.calibration.pose_model import Loads, Marker, PoseModel
from stiffness.calibration.poses import sample_coordinates
from stiffness.cli.main import main
from stiffness.elastic.effects import FAMILIES, Backlash
from stiffness.elastic.effects.pose_face import compliance_label
from stiffness.elastic.model import ElasticModel
from stiffness.mechanics.gravity import GRAVITY_PARAMETERS
from stiffness.planning.pose_simulation import hidden_pose_errors
from stiffness.planning.simulate_poses import simulate_pose_campaign, smoothing_torques
from stiffness.robot.loops import CLOSURE_TOLERANCE_M
from stiffness.robot.robot import TARGET_FRAME, load_robot

#: Exact against exact (m): both close the loops to their closure tolerance,
#: :data:`~stiffness.robot.loops.CLOSURE_TOLERANCE_M` (1e-11 m), and no better.
EXACT = 10 * CLOSURE_TOLERANCE_M
#: The families of one model (gravity_lumped stands for unknown masses, others need them).
KNOWN_MASSES = tuple(f for f in FAMILIES if f != "gravity_lumped")


@pytest.fixture(scope="module")
def sk120():
    return load_robot("sk120")


def _rows(robot, seed: int, force: float, n: int = 3):
    """``n`` coordinates near the robot's default pose (or zero), +-0.3 rad, and wrenches
    (``force`` N and a tenth of it in N.m per axis std)."""
    rng = np.random.default_rng(seed)
    q0 = (np.deg2rad(robot.defaults["q_deg"]) if "q_deg" in robot.defaults
          else np.zeros(robot.n_coordinates))
    coords = q0 + rng.uniform(-0.3, 0.3, (n, robot.n_coordinates))
    wrench = rng.normal(size=(n, 6)) * force * np.r_[1.0, 1.0, 1.0, 0.1, 0.1, 0.1]
    return coords, wrench


def _displacements(robot, k: np.ndarray, coords, wrench) -> tuple[np.ndarray, np.ndarray]:
    """The pose model's target marker under each wrench minus without it, and the elastic
    model's exact equilibrium displacement of the target (m), springs ``k``."""
    model = PoseModel(robot, [Marker("tool", TARGET_FRAME)], ("joint_compliance",),
                      (np.eye(3), np.zeros(3)), Loads(TARGET_FRAME, np.zeros((0, 6))))
    assert [p.label for p in model.parameters] == [compliance_label(j)
                                                   for j in robot.compliant_joints]
    x = 1.0 / k
    q = [robot.configuration(c) for c in coords]
    loaded = model.evaluate(x, [model.row_terms(c, w) for c, w in zip(q, wrench, strict=True)],
                            False)[0]
    rest = model.evaluate(x, [model.row_terms(c, None) for c in q], False)[0]
    elastic = ElasticModel.with_effects(robot, k, [])
    exact = np.array([elastic.at(c, w).equilibrium().twist[:3]
                      for c, w in zip(coords, wrench, strict=True)])
    return (loaded - rest)[:, 0], exact


def test_sk120_pose_model_is_the_elastic_models_equilibrium(sk120):
    """The SK120 (no link masses: the wrench the only load), its paper's springs, 1 kN and
    100 N.m wrenches at three poses: the pose model's sag through the five-bar equals the
    elastic model's exact equilibrium to round-off on millimetre displacements."""
    k = np.array(sk120.defaults["k_theta_SI"])
    coords, wrench = _rows(sk120, 0, 1000.0)
    pose, exact = _displacements(sk120, k, coords, wrench)
    assert np.abs(exact).max() > 1e-3
    assert np.abs(pose - exact).max() < EXACT


def test_hexapod_pose_model_is_the_elastic_models_equilibrium():
    """The shipped 6-UPS Stewart-Gough platform (six 3D loops, prismatic legs as springs of
    1e5 N/m, the platform's passive joints solved by the closure), legs within 1 cm of home,
    100 N and 10 N.m wrenches: the pose model equals the elastic model's equilibrium (measured
    2e-13 m on 1.1 mm, the elastic model's closure tolerance)."""
    robot = load_robot("hexapod")
    rng = np.random.default_rng(0)
    home = robot.coordinates_of(robot.assemble(None).q)
    coords = home + rng.uniform(-0.01, 0.01, (3, robot.n_coordinates))
    wrench = rng.normal(size=(3, 6)) * np.r_[100.0, 100.0, 100.0, 10.0, 10.0, 10.0]
    pose, exact = _displacements(robot, np.full(6, 1e5), coords, wrench)
    assert np.abs(exact).max() > 1e-3
    assert np.abs(pose - exact).max() < EXACT


def test_four_bar_pose_model_is_the_elastic_models_equilibrium(tilted_four_bar_robot):
    """A tilted crank-rocker four-bar (not a parallelogram: its passive angles are nonlinear in
    the crank's, so ``S(q)`` changes with the sag), springs on the crank and the tool joint,
    gravity off (the elastic model weighs no loop): the same agreement."""
    robot = load_robot(tilted_four_bar_robot.name, frame="tool_tip",
                       compliant_joints=list(tilted_four_bar_robot.coordinate_joints))
    robot.model.gravity = pin.Motion.Zero()
    k = np.array([300.0, 200.0])[:robot.n_compliant]
    coords, wrench = _rows(robot, 1, 10.0)
    pose, exact = _displacements(robot, k, coords, wrench)
    assert np.abs(exact).max() > 1e-3
    assert np.abs(pose - exact).max() < EXACT


def test_the_simulators_truth_is_the_elastic_models_equilibrium(sk120):
    """The pose simulator's own loaded arm (its fixed point with the loop closed at each
    iterate) under a payload, noise-free, measuring frame the world's: the target where the
    elastic model's equilibrium puts it."""
    k = np.array(sk120.defaults["k_theta_SI"])
    markers = [Marker("tip", TARGET_FRAME)]
    payload = np.array([400.0, 300.0, -2000.0, 50.0, 0.0, 20.0])
    truth = hidden_pose_errors(sk120, markers, [], kq=k)
    campaign = simulate_pose_campaign(sk120, markers, truth, 3, 0.0, seed=2, payload=payload)
    elastic = ElasticModel.with_effects(sk120, k, [])
    exact = np.array([elastic.at(c, payload).equilibrium().position for c in campaign.q])
    assert np.abs(campaign.positions[:, 0] - exact).max() < EXACT


@pytest.fixture(scope="module")
def heavy_four_bar(tilted_four_bar):
    """The tilted four-bar with masses (1-5 kg, centres within 0.2 m of each joint), springs
    on the crank and the tool joint."""
    robot = load_robot(tilted_four_bar.urdf, frame="tool_tip",
                       compliant_joints=["crank_joint", "tool_joint"])
    rng = np.random.default_rng(5)
    for j in range(1, robot.model.njoints):
        robot.model.inertias[j] = pin.Inertia(rng.uniform(1, 5), rng.uniform(-0.2, 0.2, 3),
                                              np.eye(3) * 1e-2)
    robot.data = robot.model.createData()
    return robot


#: The heavy four-bar's springs (N.m/rad): sags of 1-5 mm under its weight.
HEAVY_K = np.array([300.0, 200.0])
HEAVY_MARKERS = [Marker("tool", TARGET_FRAME, np.array([0.05, 0.02, 0.01])),
                 Marker("rocker", "rocker_end", np.array([0.02, 0.01, 0.0]))]


def test_gravity_reaches_the_springs_through_the_loop(heavy_four_bar):
    """The heavy four-bar (springs of 300 and 200 N.m/rad), gravity alone: the pose model's
    loaded tool (springs carrying ``T^T (-g)``) and the pose simulator's are where the minimum
    of the potential energy ``1/2 sum k (u - u_c)^2 + V(q(u))`` puts it (BFGS over ``u``, the
    loop closed by the robot's assembly: its gradient tolerance limits the agreement, measured
    1.7e-9 m on 1-5 mm sags), and agree with each other to the closure tolerance."""
    robot, k = heavy_four_bar, HEAVY_K
    markers = [Marker("tool", TARGET_FRAME)]
    campaign = simulate_pose_campaign(robot, markers, hidden_pose_errors(robot, markers, [],
                                                                         kq=k), 3, 0.0, seed=5)
    model = PoseModel(robot, markers, ("joint_compliance",), (np.eye(3), np.zeros(3)))
    data, fid = robot.model.createData(), robot.model.getFrameId(TARGET_FRAME)
    for coords, simulated in zip(campaign.q, campaign.positions[:, 0], strict=True):
        commanded = robot.configuration(coords)
        pose = model.evaluate(1.0 / k, [model.row_terms(commanded, None)], False)[0][0, 0]

        def energy(u, coords=coords, commanded=commanded):
            q = robot.configuration(coords + u, seed=commanded)
            return 0.5 * np.sum(k * u ** 2) + pin.computePotentialEnergy(robot.model, data, q)

        u = minimize(energy, np.zeros(2), method="BFGS", options={"gtol": 1e-10}).x
        pin.framesForwardKinematics(robot.model, data,
                                    robot.configuration(coords + u, seed=commanded))
        rigid = model.evaluate(np.zeros(2), [model.row_terms(commanded, None)], False)[0]
        assert np.abs(pose - rigid[0, 0]).max() > 1e-3
        assert np.abs(pose - data.oMf[fid].translation).max() < 1e-7
        assert np.abs(pose - simulated).max() < EXACT


def test_lumped_weight_through_the_loop(heavy_four_bar):
    """``gravity_lumped`` on the heavy four-bar: its parameters pair each spring with the
    links it moves through the loop (the rocker's too: the crank turns it), and at the true
    masses (``theta = c_j pi_k``) it predicts what the known masses do (measured 2e-16 m on
    5 mm sags); its columns, and ``base_tilt``'s beside the springs, equal central differences
    to 1e-6 at rigid springs and to 1e-2 at a tenth of these (first order in the compliance,
    as ``joint_compliance``'s: 2.7e-3 measured, 2.4e-3 for the springs alone)."""
    robot, k = heavy_four_bar, HEAVY_K
    frame0 = (np.eye(3), np.zeros(3))
    known = PoseModel(robot, HEAVY_MARKERS, ("joint_compliance",), frame0)
    lumped = PoseModel(robot, HEAVY_MARKERS, ("gravity_lumped",), frame0)
    names = list(robot.model.names)
    x = np.zeros(lumped.size)
    for i, p in enumerate(lumped.parameters):
        spring, pair = p.label.split(" x ")
        body, what = pair.rsplit(" ", 1)
        inertia = robot.model.inertias[names.index(body)]
        moments = dict(zip(GRAVITY_PARAMETERS, [inertia.mass, *(inertia.mass * inertia.lever)],
                           strict=True))
        x[i] = moments[what] / k[robot.compliant_joints.index(spring)]
    assert "crank_joint x rocker_joint m" in [p.label for p in lumped.parameters]
    rng = np.random.default_rng(8)
    rows = [known.row_terms(robot.configuration(c), None)
            for c in rng.uniform(-0.5, 0.5, (3, 2))]
    with_masses = known.evaluate(1.0 / k, rows, False)[0]
    assert np.abs(with_masses - known.evaluate(0.0 * k, rows, False)[0]).max() > 1e-3
    assert np.abs(lumped.evaluate(x, rows, False)[0] - with_masses).max() < EXACT
    scales = np.array([p.scale for p in lumped.parameters])
    assert_columns(lumped, rows, 0.0 * x, scales, 1e-6)
    assert_columns(lumped, rows, 0.1 * x, scales, 1e-2)
    tilted = PoseModel(robot, HEAVY_MARKERS, ("base_tilt", "joint_compliance"), frame0)
    scales = np.array([p.scale for p in tilted.parameters])
    assert_columns(tilted, rows, np.r_[0.01, -0.02, 0.0, 0.0], scales, 1e-6)
    assert_columns(tilted, rows, np.r_[0.01, -0.02, 0.1 / k], scales, 1e-2)


@pytest.mark.parametrize("robot_name", ["sk120", "four_bar"])
def test_columns_equal_central_differences(robot_name, sk120, tilted_four_bar_robot):
    """Every family but ``gravity_lumped`` (its own test), two markers (one on the loop's
    output link; a bend, a tilt, a placement error only outside the loop): at rigid
    springs the analytic columns ``J_p T ...`` are the central differences to 1e-6; at the
    springs' compliance to 1e-2 (the torque's change with the sag, ``C dtau/dq``, left out)."""
    if robot_name == "sk120":
        robot, k, force = sk120, np.array(sk120.defaults["k_theta_SI"]), 100.0
        markers = [Marker("tool", TARGET_FRAME, np.array([0.05, 0.02, 0.1])),
                   Marker("fore", "forearm", np.array([0.1, 0.0, 0.05]))]
    else:
        robot = load_robot(tilted_four_bar_robot.name, frame="tool_tip",
                           compliant_joints=list(tilted_four_bar_robot.coordinate_joints))
        k, force = np.array([3e3, 2e3]), 1.0
        markers = [Marker("tool", TARGET_FRAME, np.array([0.05, 0.02, 0.01])),
                   Marker("rocker", "rocker_end", np.array([0.02, 0.01, 0.0]))]
    coords, wrench = _rows(robot, 3, force)
    loads = Loads(TARGET_FRAME, np.zeros((0, 6)))
    nominal = PoseModel(robot, markers, (), (np.eye(3), np.zeros(3)), loads)
    rows = [nominal.row_terms(robot.configuration(c), w)
            for c, w in zip(coords, wrench, strict=True)]
    model = PoseModel(robot, markers, KNOWN_MASSES, (np.eye(3), np.zeros(3)), loads,
                      nominal.campaign_settings(rows))
    scales = np.array([p.scale for p in model.parameters])
    rng = np.random.default_rng(4)
    sl = model.slices()
    for size, tol in ((0.0, 1e-6), (1.0, 1e-2)):
        x = 0.3 * scales * rng.normal(size=model.size)
        x[sl["joint_compliance"]] = size / k
        x[sl["backlash"]] = 1e-4 * size
        x[sl["nonlinear_joint_stiffness"]] *= size
        for elastic in ("link_compliance", "transversal_compliance", "gravity_compensator"):
            x[sl[elastic]] = np.abs(x[sl[elastic]]) * size
        assert_columns(model, rows, x, scales, tol)


def test_backlash_smoothing_is_the_simulators(sk120):
    """The backlash smoothing torques (2 % of the RMS torque each spring carries) of the pose
    model's campaign settings and of the pose simulator (its path,
    :func:`~stiffness.planning.simulate_poses.loop_torque`, through the same
    ``LoopClosure.tangent``) on SK120 poses under a payload
    agree to 1e-12; through the loop the crank's (joint3) is not the tree's torque at its
    joint, which carries none of the forearm's load."""
    rng = np.random.default_rng(6)
    coords = sample_coordinates(sk120, 10, rng)
    payload = np.array([400.0, 300.0, -2000.0, 50.0, 0.0, 20.0])
    nominal = PoseModel(sk120, [Marker("tip", TARGET_FRAME)], (), (np.eye(3), np.zeros(3)),
                        Loads(TARGET_FRAME, np.tile(payload, (len(coords), 1))))
    rows = [nominal.row_terms(sk120.configuration(c), payload) for c in coords]
    fitted = nominal.campaign_settings(rows)[Backlash.SETTING]
    simulated = smoothing_torques(sk120, coords, payload)
    assert set(fitted) == set(simulated) == set(sk120.compliant_joints)
    for name, tau_s in fitted.items():
        assert simulated[name] == pytest.approx(tau_s, rel=1e-12), name
    crank = sk120.model.joints[sk120.model.getJointId("joint3")].idx_v
    for row in rows:  # the tree's torque at the crank: none
        pin.computeJointJacobians(sk120.model, sk120.data, row.q_full)
        jac = pin.getFrameJacobian(sk120.model, sk120.data, sk120.target_frame_id,
                                   pin.LOCAL_WORLD_ALIGNED)
        assert (jac.T @ payload)[crank] == 0.0
    assert fitted["joint3"] > 0.0


def test_a_bend_outside_the_loop_is_the_simulators(sk120):
    """A link bend beyond the five-bar (joint4 -> joint5, 5e6 N.m/rad about both axes) hidden
    in the simulator (its placements turned exactly, moments from Newton-Euler) under a
    payload, the paper's springs: the pose model at the truth (its bends first order, their
    feedback on the joints' torques left out) reproduces the simulated markers to 1 % of the
    bend's displacement (measured 3e-3; 1.5e-4 with springs 100 times stiffer: the feedback);
    a bend inside the loop has no parameter (the family lays out elbow->joint4 and
    joint4->joint5 only)."""
    k = np.array(sk120.defaults["k_theta_SI"])
    markers = [Marker("tip", "fixture_target"), Marker("fore", "forearm", np.array([0.3, 0, 0.1]))]
    payload = np.array([400.0, 300.0, -2000.0, 50.0, 0.0, 20.0])
    hidden = hidden_pose_errors(sk120, markers, ["link_compliance:joint4->joint5=5e6"], kq=k)
    bent = simulate_pose_campaign(sk120, markers, hidden, 5, 0.0, seed=3, payload=payload)
    straight = simulate_pose_campaign(sk120, markers, hidden_pose_errors(sk120, markers, [],
                                                                          kq=k),
                                      5, 0.0, seed=3, payload=payload)
    model = PoseModel(sk120, markers, ("joint_compliance", "link_compliance"),
                      (np.eye(3), np.zeros(3)), Loads(sk120.target_frame, np.tile(payload, (5, 1))))
    assert [p.label for p in model.parameters if p.family == "link_compliance"] == [
        f"{link} compliance {i}" for link in ("elbow->joint4", "joint4->joint5") for i in (1, 2)]
    x = truth(model, hidden)
    y = model.evaluate(x, [model.row_terms(sk120.configuration(q), payload) for q in bent.q],
                       False)[0]
    size = np.abs(bent.positions - straight.positions).max()
    assert size > 1e-5
    assert np.abs(y - bent.positions).max() < 1e-2 * size


def test_a_compensator_is_the_simulators(sk120):
    """A spring compensator on joint2 (2e5 N/m, 5 kN with the link up: the simulator's own
    spring law and geometry) under a payload, the paper's springs: its torque on an
    independent joint reaches that joint's spring unprojected (``T``'s row there is a unit
    row), and the pose model at the truth reproduces the simulated markers to 1e-12 m
    (measured 4e-16 m on a 4.7 mm effect)."""
    k = np.array(sk120.defaults["k_theta_SI"])
    markers = [Marker("tip", "fixture_target"), Marker("fore", "forearm", np.array([0.3, 0, 0.1]))]
    payload = np.array([400.0, 300.0, -2000.0, 50.0, 0.0, 20.0])
    hidden = hidden_pose_errors(sk120, markers, ["gravity_compensator:joint2=2e5,5e3"], kq=k)
    sprung = simulate_pose_campaign(sk120, markers, hidden, 5, 0.0, seed=3, payload=payload)
    plain = simulate_pose_campaign(sk120, markers, hidden_pose_errors(sk120, markers, [], kq=k),
                                   5, 0.0, seed=3, payload=payload)
    loads = Loads(sk120.target_frame, np.tile(payload, (5, 1)))
    nominal = PoseModel(sk120, markers, (), (np.eye(3), np.zeros(3)), loads)
    rows = [nominal.row_terms(sk120.configuration(q), payload) for q in sprung.q]
    model = PoseModel(sk120, markers, ("joint_compliance", "gravity_compensator"),
                      (np.eye(3), np.zeros(3)), loads, nominal.campaign_settings(rows))
    y = model.evaluate(truth(model, hidden), rows, False)[0]
    assert np.abs(sprung.positions - plain.positions).max() > 1e-3
    assert np.abs(y - sprung.positions).max() < EXACT


def test_a_pose_model_of_a_loop_travels_to_workers(sk120):
    """``diagnose --workers`` pickles the campaign's robot and the fitted pose models: the
    loops' Pinocchio constraints do not pickle, so the robot rebuilds them; the unpickled
    model predicts the same markers and Jacobian, bit for bit."""
    model = PoseModel(sk120, [Marker("tip", TARGET_FRAME)], ("joint_offsets",
                                                             "joint_compliance"),
                      (np.eye(3), np.zeros(3)), Loads(TARGET_FRAME, np.zeros((0, 6))))
    coords, wrench = _rows(sk120, 9, 1000.0)
    rows = [model.row_terms(sk120.configuration(c), w) for c, w in zip(coords, wrench,
                                                                        strict=True)]
    x = np.r_[np.full(6, 1e-3), 1.0 / np.array(sk120.defaults["k_theta_SI"])]
    travelled = pickle.loads(pickle.dumps((model, rows)))
    assert travelled[0].robot.loop.pairs == sk120.loop.pairs
    for ours, theirs in zip(model.evaluate(x, rows), travelled[0].evaluate(x, travelled[1]),
                            strict=True):
        assert np.array_equal(ours, theirs)


def _run(capsys, argv: list[str]) -> tuple[int, str, str]:
    capsys.readouterr()
    code = main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_a_simulated_sk120_campaign_is_recovered(tmp_path, capsys):
    """``stiffness simulate --kind poses --robot sk120`` (20 poses, a marker on the fixture
    and one on the forearm, 20 µm, a 2 kN payload pulling sideways too, the paper's springs,
    zero offsets of 0.1 and -0.05 deg on the parallelogram's drives) and ``diagnose`` with the
    springs and offsets forced in: explained to noise, and the 95 % intervals of the three
    compliances and the two hidden offsets hold the truth, and the model file it writes gives
    ``stiffness kx`` the springs (seed 0; over seeds 0-19 of the
    same campaign through the Python API 98 of 100 intervals held it, sum z^2 / n per
    parameter 0.52-0.99, explained to noise in 19)."""
    out = tmp_path / "sim"
    k = [1.4098e6, 4.0076e5, 9.3528e5]
    code, _, err = _run(capsys, [
        "simulate", "--kind", "poses", "--robot", "sk120", "--poses", "20", "--marker",
        "tip=fixture_target", "--marker", "fore=forearm@300,0,100",
        "--load", "400,300,-2000", "--noise", "0.02", "--kq", ",".join(map(str, k)),
        "--effect", "frame=1,2,-3,500,300,100", "--effect", "joint_offsets:joint2=0.1",
        "--effect", "joint_offsets:joint3=-0.05", "--out", str(out)])
    assert code == 0, err
    code, printed, err = _run(capsys, ["diagnose", str(out), "--json", "--families",
                                       "joint_offsets,joint_compliance", "--max-steps", "0",
                                       "--out", str(tmp_path / "fit")])
    assert code == 0, err
    code, said, err = _run(capsys, ["kx", "--model", str(tmp_path / "fit" / "final-model.json")])
    assert code == 0 and "K_X (N/m)" in said, err  # its springs (the robot weighs nothing)
    diagnosis = json.loads(printed)
    assert not diagnosis["unexplained"]
    rows = {p["parameter"]: p for p in diagnosis["parameters"]}
    truth = {f"{j} compliance": 1.0 / kj
             for j, kj in zip(("joint1", "joint2", "joint3"), k, strict=True)}
    truth.update({"joint2 zero": np.deg2rad(0.1), "joint3 zero": np.deg2rad(-0.05)})
    for label, value in truth.items():
        low, high = rows[label]["ci95"]
        assert low <= value <= high, (label, low, value, high)


def test_loop_geometry_is_refused_with_the_valid_choices(sk120):
    """A placement error, zero offset, bend or tilt hidden inside the five-bar (a passive joint,
    or a joint on the loop's path): one typed line naming the valid joints; the geometry
    family has parameters at joints outside the loop only, the zero offsets at the
    coordinates."""
    markers = [Marker("tip", TARGET_FRAME)]
    with pytest.raises(LoopGeometryError, match="elbow is inside a closed loop") as error:
        hidden_pose_errors(sk120, markers, ["geometry:elbow=1,0,0"])
    assert error.value.choices == ("joint1", "joint4", "joint5", "joint6")
    with pytest.raises(LoopGeometryError, match="joint2 is inside a closed loop"):
        hidden_pose_errors(sk120, markers, ["geometry:joint2=1,0,0"])
    with pytest.raises(LoopGeometryError, match="coupler_joint is inside"):
        hidden_pose_errors(sk120, markers, ["joint_offsets:coupler_joint=0.1"])
    with pytest.raises(LoopGeometryError, match="joint2 is inside a closed loop"):
        hidden_pose_errors(sk120, markers, ["link_compliance:joint1->joint2=1e6"], kq=[1e6] * 3)
    with pytest.raises(LoopGeometryError, match="joint3 is inside a closed loop"):
        hidden_pose_errors(sk120, markers, ["transversal_compliance:joint3=1e6"], kq=[1e6] * 3)
    model = PoseModel(sk120, markers, ("joint_offsets", "geometry"), (np.eye(3), np.zeros(3)))
    placed = {p.label.split(" placement")[0] for p in model.parameters
              if p.family == "geometry"}
    zeros = {p.label.removesuffix(" zero") for p in model.parameters
             if p.family == "joint_offsets"}
    assert placed == {"joint1", "joint4", "joint5", "joint6"}
    assert zeros == set(sk120.coordinate_joints)
