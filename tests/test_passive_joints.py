"""Passive coupled joints (issue 36.1): a ``[controller]`` with fewer coordinates than chain
joints, ``q_chain = A u + b`` with ``A`` tall (tests/data/torso-passive: the chest pitch
``t4 = -T2 - T3`` follows a linkage), springs on the controller's coordinates or on the chain.

The references are built here from Pinocchio's chain Jacobian, ``K_C`` of the chain by central
differences of ``J^T W`` and the linkage's ``A`` written out by hand, never from the toolkit's
coupling.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from scipy import optimize

from stiffness.elastic.model import ElasticModel
from stiffness.robot.robot import load_robot

TORSO = Path(__file__).parent / "data" / "torso-passive" / "robot.toml"
#: The linkage by hand: rows t1, t2, t3, t4, a1, a2; columns T1, T2, T3, A1, A2.
A = np.array([[1, 0, 0, 0, 0], [0, 1, 0, 0, 0], [0, 0, 1, 0, 0], [0, -1, -1, 0, 0],
              [0, 0, 0, 1, 0], [0, 0, 0, 0, 1]], dtype=float)
#: Springs on the chain's six joints (N.m/rad): the chest's own, through its linkage, too.
K_CHAIN = np.array([4.0e4, 2.5e4, 2.0e4, 1.5e4, 8.0e3, 6.0e3])
K_CONTROLLER = np.array([4.0e4, 2.5e4, 2.0e4, 8.0e3, 6.0e3])
FORCE = np.array([20.0, -15.0, -60.0])


def torso(tmp_path: Path, springs_on: str) -> object:
    """The torso with its springs on the controller's coordinates or on the chain."""
    if springs_on == "controller":
        return load_robot(TORSO)
    text = TORSO.read_text().replace('springs_on = "controller"', 'springs_on = "chain"')
    text = text.replace('compliant_joints = ["T1", "T2", "T3", "A1", "A2"]',
                        'compliant_joints = ["t1", "t2", "t3", "t4", "a1", "a2"]')
    text = text.replace("k_theta_SI = [4.0e4, 2.5e4, 2.0e4, 8.0e3, 6.0e3]",
                        "k_theta_SI = [4.0e4, 2.5e4, 2.0e4, 1.5e4, 8.0e3, 6.0e3]")
    path = tmp_path / "chain" / "robot.toml"
    path.parent.mkdir(exist_ok=True)
    path.write_text(text)
    return load_robot(path)


def chain_q(robot, chain: np.ndarray) -> np.ndarray:
    """Full configuration with the chain joints t1..a2 at ``chain`` (rad), set by name."""
    q = pin.neutral(robot.model)
    for name, value in zip(("t1", "t2", "t3", "t4", "a1", "a2"), chain, strict=True):
        q[robot.model.joints[robot.model.getJointId(name)].idx_q] = value
    return q


def chain_jacobian(robot, chain: np.ndarray) -> np.ndarray:
    """(6, 6) target Jacobian over the chain joints, world axes at the target."""
    model, data = robot.model, robot.model.createData()
    j = pin.computeFrameJacobian(model, data, chain_q(robot, chain), robot.target_frame_id,
                                 pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
    v = [model.joints[model.getJointId(n)].idx_v for n in ("t1", "t2", "t3", "t4", "a1", "a2")]
    return j[:, v]


def chain_kc(robot, chain: np.ndarray, force: np.ndarray) -> np.ndarray:
    """K_C of the chain: central differences (h = 1e-6 rad) of ``J_pos^T F``."""
    h = 1e-6
    cols = [(chain_jacobian(robot, chain + h * e)[:3].T @ force
             - chain_jacobian(robot, chain - h * e)[:3].T @ force) / (2 * h) for e in np.eye(6)]
    return np.array(cols).T


@pytest.mark.parametrize("springs_on", ["controller", "chain"])
def test_kx_equals_the_hand_built_reference(tmp_path, springs_on):
    """K_X (enhanced, force rows) at 4 random poses against ``C = J A (K - A^T K_C A)^-1
    (J A)^T`` (springs on the controller) or ``J (K - K_C)^-1 J^T`` over the chain (springs on
    the chain joints, the commanded pose ``A u + b``), to 1e-9 relative. Measured: 2.4e-13
    and 3.2e-13 (the reference's K_C by central differences)."""
    robot = torso(tmp_path, springs_on)
    assert robot.n_coordinates == 5 and robot.coupling.matrix.shape == (6, 5)
    k = K_CONTROLLER if springs_on == "controller" else K_CHAIN
    model = ElasticModel.joint_springs(robot, k)
    rng = np.random.default_rng(3)
    for _ in range(4):
        u = rng.uniform(-0.8, 0.8, 5)
        chain = A @ u
        j, k_c = chain_jacobian(robot, chain)[:3], chain_kc(robot, chain, FORCE)
        if springs_on == "controller":
            j, k_c = j @ A, A.T @ k_c @ A
        reference = np.linalg.inv(j @ np.linalg.solve(np.diag(k) - k_c, j.T))
        k_x = model.at(u, FORCE).k_x()
        assert np.abs(k_x - reference).max() <= 1e-9 * np.abs(reference).max()


def _energy_equilibrium(robot, u: np.ndarray, springs_on: str) -> np.ndarray:
    """The chain joints at rest under FORCE, found here: the minimum of
    ``d^T K d / 2 - F . p(q)`` over the spring deflections ``d`` (the controller's, moving the
    chain by ``A d``, or the chain's own), by BFGS on central-difference gradients."""
    model, data = robot.model, robot.model.createData()
    k = K_CONTROLLER if springs_on == "controller" else K_CHAIN
    spread = A if springs_on == "controller" else np.eye(6)

    def energy(d: np.ndarray) -> float:
        pin.framesForwardKinematics(model, data, chain_q(robot, A @ u + spread @ d))
        return 0.5 * d @ (k * d) - FORCE @ data.oMf[robot.target_frame_id].translation

    def gradient(d: np.ndarray) -> np.ndarray:
        h = 1e-7
        return np.array([(energy(d + h * e) - energy(d - h * e)) / (2 * h)
                         for e in np.eye(len(k))])

    sol = optimize.minimize(energy, np.zeros(len(k)), jac=gradient, method="BFGS",
                            options={"gtol": 1e-9})
    return A @ u + spread @ sol.x


@pytest.mark.parametrize("springs_on", ["controller", "chain"])
def test_exact_deflection_equals_the_energy_minimum(tmp_path, springs_on):
    """The model's exact equilibrium (ElasticState.equilibrium) puts the chain joints where
    the energy minimum does, to 1e-9 rad, at 3 poses with deflections over 1 mrad. With the
    springs on the chain the chest t4 deflects on its own (off the linkage's A u + b).
    Measured: 7.5e-12 rad (controller), 1.2e-10 rad (chain) of 2 mrad deflections."""
    robot = torso(tmp_path, springs_on)
    k = K_CONTROLLER if springs_on == "controller" else K_CHAIN
    model = ElasticModel.joint_springs(robot, k)
    rng = np.random.default_rng(4)
    names = ("t1", "t2", "t3", "t4", "a1", "a2")
    for _ in range(3):
        u = rng.uniform(-0.8, 0.8, 5)
        exact = _energy_equilibrium(robot, u, springs_on)
        eq = model.at(u, FORCE).equilibrium()
        got = np.array([eq.q[robot.model.joints[robot.model.getJointId(n)].idx_q]
                        for n in names])
        assert np.abs(exact - A @ u).max() > 1e-3
        assert np.abs(got - exact).max() < 1e-9, np.abs(got - exact).max()


def test_kx_command_with_springs_on_a_square_and_a_tall_chain(tmp_path, capsys):
    """``stiffness kx --kq`` on a coupled robot with springs on the chain (it ended in
    ``ValueError: tuple.index(x)``): the SK120 as a DH table with its parallelogram coupling
    (square A) and the torso (tall A), exit 0 with K_X printed."""
    from stiffness.cli.main import main

    sk120 = Path(__file__).parents[1] / "examples" / "sk120-dh" / "robot.toml"
    text = sk120.read_text().replace('springs_on = "controller"', 'springs_on = "chain"')
    text = text.replace('compliant_joints = ["joint1", "joint2", "joint3"]',
                        'compliant_joints = ["waist", "shoulder", "elbow"]')
    square = tmp_path / "sk120" / "robot.toml"
    square.parent.mkdir()
    square.write_text(text)
    tall = torso(tmp_path, "chain")
    for path, kq in ((square, "1e6,1e6,1e6"), (tall.name, ",".join(map(str, K_CHAIN)))):
        assert main(["kx", "--robot", str(path), "--kq", kq]) == 0
        assert "K_X (N/m)" in capsys.readouterr().out


def test_mjcf_linkage_holds_the_passive_joint_under_load():
    """The torso exported to MuJoCo with its springs on the controller's coordinates (fixed
    tendons over the chain, pseudo-inverse coefficients) and the chest's linkage as a stiff
    equality on the tendon ``t2 + t3 + t4`` (A's left null space): at the rest keyframe the
    linkage holds exactly; under a force at the target, gravity off, damped for 3 s, the
    target sits where the exact equilibrium puts it to 1e-3 of the deflection (MuJoCo's
    equality gives way a little). Measured: 1.5e-4 of a 0.94 mm deflection, the linkage
    1.2e-7 rad off."""
    import mujoco

    from stiffness.mechanics.equilibrium import solve_equilibrium
    from stiffness.robot.mjcf import robot_mjcf

    robot = load_robot(TORSO)
    q0 = robot.configuration(np.deg2rad([10.0, 20.0, 15.0, -30.0, 40.0]))
    xml = robot_mjcf(robot, dict(zip(robot.compliant_joints, K_CONTROLLER, strict=True)), q0)
    assert xml.count("<fixed ") == 6 and 'tendon1="linkage1"' in xml
    m = mujoco.MjModel.from_xml_string(xml)
    m.opt.gravity[:] = 0.0
    m.opt.timestep = 1e-3
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    m.dof_armature[:] = 0.05
    m.dof_damping[:] = 100.0
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    mujoco.mj_forward(m, d)
    assert abs(d.efc_pos[0]) < 1e-12  # the linkage closed at rest
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "stiffness_target")
    for _ in range(3000):
        d.qfrc_applied[:] = 0.0
        mujoco.mj_applyFT(m, d, FORCE, np.zeros(3), d.site_xpos[site], m.site_bodyid[site],
                          d.qfrc_applied)
        mujoco.mj_step(m, d)
    exact = solve_equilibrium(robot, q0, np.diag(K_CONTROLLER), FORCE)
    assert np.linalg.norm(exact.dx) > 5e-4
    assert np.abs(d.qvel).max() < 1e-8 and abs(d.efc_pos[0]) < 1e-6
    relative = np.linalg.norm(d.site_xpos[site] - exact.position) / np.linalg.norm(exact.dx)
    assert relative < 1e-3, relative


#: Markers on the torso: on the tool, and on the chest (moved by the passive joint t4).
MARKERS = [("tip", "tool", [0.02, 0.0, 0.03]), ("chest", "t4_link", [0.05, 0.1, 0.0])]


def _pose_campaign(robot, k_true: np.ndarray, seed: int, n_poses: int):
    from stiffness.calibration.pose_model import Marker
    from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign

    rng = np.random.default_rng(7)  # the same hidden errors in every campaign
    markers = [Marker(n, f, np.array(o)) for n, f, o in MARKERS]
    hidden = HiddenPoseErrors(pin.exp3(rng.normal(0, 0.2, 3)), rng.uniform(-1, 1, 3),
                              np.array([m.offset for m in markers]) + rng.normal(0, 2e-3, (2, 3)),
                              rng.normal(0, 1e-3, 6), np.zeros((6, 6)), k_true)
    return simulate_pose_campaign(robot, markers, hidden, n_poses, 20e-6, seed=seed,
                                  payload=np.r_[FORCE, 0.0, 0.0, 0.0])


@pytest.mark.parametrize("springs_on", ["controller", "chain"])
def test_pose_campaign_identifies_and_reproduces_to_the_noise(tmp_path, springs_on):
    """A simulated pose campaign of the torso (30 poses under gravity and a payload, 20 um
    noise; the zero offsets of the six chain joints, the frame and the markers hidden) is fitted
    with frame, markers, joint offsets and joint compliance, springs on the controller's five
    coordinates or on the chain's six joints: the fit's RMS is the noise's (0.75 to 1.25), the
    compliances within 4 standard errors of the truth, and the fitted model predicts another
    campaign of 20 poses to 1.3 x the noise. Measured over seeds 0, 2, 3 (held out: seed + 10):
    fit RMS 0.90 to 1.04 x noise, held out 0.94 to 1.15 x, compliance |z| <= 1.33, on each
    side."""
    from stiffness.calibration.pose_fit import fit_pose_model, rows_of, starting_frame
    from stiffness.calibration.pose_model import PoseModel

    robot = torso(tmp_path, springs_on)
    k_true = K_CONTROLLER if springs_on == "controller" else K_CHAIN
    fams = ["frame", "markers", "joint_offsets", "joint_compliance"]
    c = _pose_campaign(robot, k_true, 0, 30)
    model = PoseModel(robot, c.markers, tuple(fams), starting_frame(c), c.loads)
    fit = fit_pose_model(model, c, rows_of(model, c), fams)
    noise = 20e-6
    rms = float(np.sqrt(np.nanmean(fit.residual ** 2)))
    assert 0.75 < rms / noise < 1.25, rms / noise
    sl = model.slices()["joint_compliance"]
    kept = list(fit.identifiability.kept)
    for i, truth in zip(range(sl.start, sl.stop), 1.0 / k_true, strict=True):
        se = np.sqrt(fit.covariance[kept.index(i), kept.index(i)])
        assert abs(fit.x[i] - truth) < 4 * se, (model.parameters[i].label, fit.x[i], truth, se)
    other = _pose_campaign(robot, k_true, 1, 20)
    held = PoseModel(robot, c.markers, tuple(fams), (model.rotation0, model.translation0),
                     other.loads)
    predicted, _ = held.evaluate(fit.x, rows_of(held, other), False)
    error = float(np.sqrt(np.mean((predicted - other.positions) ** 2)))
    assert error / noise < 1.3, error / noise


@pytest.mark.parametrize("springs_on", ["controller", "chain"])
def test_deflection_campaign_identifies_and_reproduces_to_the_noise(tmp_path, springs_on):
    """A simulated deflection campaign of the torso (planning.simulate: 8 poses x 3 loads up to
    100 N, 10 um noise) identified with the springs on the controller's coordinates or on the
    chain's joints (the chest's own included): every stiffness inside its 95 % interval, the
    residual at the noise (0.7 to 1.3), and the identified model file predicts another
    campaign (other poses and loads) to 1.3 x the noise. Measured (seeds 0 and 2): residual
    0.95, 0.96 (controller) and 1.21, 0.99 (chain) x noise; held out 1.05, 0.96 and 1.04,
    1.00 x."""
    from stiffness.calibration.identify import identify
    from stiffness.calibration.validation import deflection_errors
    from stiffness.elastic.model_file import load_model
    from stiffness.planning.simulate import simulate

    source = str(torso(tmp_path, springs_on).name)
    k_true = K_CONTROLLER if springs_on == "controller" else K_CHAIN
    runs = [simulate(source, kq=k_true, configs=8, loads_per_config=3, noise_std_m=1e-5,
                     seed=seed) for seed in (0, 1)]
    ident = identify(runs[0].campaign, starts=2)
    assert np.all((ident.ci95_low <= k_true) & (k_true <= ident.ci95_high)), (
        ident.ci95_low, k_true, ident.ci95_high)
    residual = np.sqrt(ident.residual_ss_m2 / ident.n_residuals) / 1e-5
    assert 0.7 < residual < 1.3, residual
    path = ident.write_model(tmp_path / "identified-model.json")
    held = deflection_errors(load_model(path), runs[1].campaign)
    rms_m = held["rms"] * runs[1].campaign.units.length_to_si / np.sqrt(3)  # per component
    assert rms_m / 1e-5 < 1.3, rms_m / 1e-5


def test_drawn_poses_keep_the_passive_joint_within_its_limits(tmp_path):
    """The chest t4 = -T2 - T3 limited to +-30 deg while T2, T3 each range over +-60 deg:
    every pose drawn for a campaign keeps |T2 + T3| within 30 deg (without the check, about
    half of them would not)."""
    from stiffness.calibration.poses import sample_coordinates

    path = tmp_path / "tight" / "robot.toml"
    path.parent.mkdir()
    path.write_text(TORSO.read_text().replace("lower = -120, upper = 120",
                                              "lower = -30, upper = 30"))
    coords = sample_coordinates(load_robot(path), 20, np.random.default_rng(0))
    assert np.abs(coords[:, 1] + coords[:, 2]).max() <= np.deg2rad(30.0) + 1e-12


@pytest.mark.parametrize("springs_on", ["controller", "chain"])
def test_scan_maps_equal_the_model_at_each_pose(tmp_path, springs_on):
    """``stiffness scan`` (the batched kernels) over a 3 x 3 grid of T2, T3 gives at every
    pose the K_X of the elastic model (checked against the hand-built reference above), to
    1e-9 relative, under the scan's default load."""
    from stiffness.cli.main import main
    from stiffness.workspace.engine import load_scan

    robot = torso(tmp_path, springs_on)
    out = tmp_path / "scan"
    assert main(["scan", "--robot", str(robot.name), "--axis", "T2=-0.5:0.5:0.5", "--axis",
                 "T3=-0.5:0.5:0.5", "--wrench", "0,0,-100", "--quiet", "--no-plots",
                 "--out", str(out)]) == 0
    scan = load_scan(out)
    model = ElasticModel.joint_springs(
        robot, K_CONTROLLER if springs_on == "controller" else K_CHAIN)
    assert scan["coordinates"].shape == (9, 5) and bool(np.all(scan["valid"]))
    for coords, k_x in zip(scan["coordinates"], scan["k_x"][:, 0], strict=True):
        reference = model.at(coords, [0.0, 0.0, -100.0]).k_x()
        assert np.abs(k_x - reference).max() <= 1e-9 * np.abs(reference).max()


def test_compensation_with_springs_on_the_passive_joint_is_exact(tmp_path):
    """Springs on the chain, the chest's own included: no command moves the chest's
    deflection alone, so ``auto`` takes the general method (Newton on the commands through
    A), which holds the target to 1e-12 m of a 2.9 mm deflection at 5 poses; the closed form
    (least squares through A) would leave 2.4 mm at the first."""
    from stiffness.machining.compensation import compensate_point

    robot = torso(tmp_path, "chain")
    model = ElasticModel.joint_springs(robot, K_CHAIN)
    wrench = np.r_[FORCE, 0.0, 0.0, 0.0]
    u0 = np.deg2rad([10.0, 20.0, 15.0, -30.0, 40.0])
    closed = compensate_point(model, u0, wrench, hold="position", method="closed-form")
    assert np.linalg.norm(closed.residual) > 0.5 * np.linalg.norm(closed.deflection)
    for u in u0 + np.random.default_rng(5).uniform(-0.3, 0.3, (5, 5)):
        point = compensate_point(model, u, wrench, hold="position")
        assert point.method == "general" and np.linalg.norm(point.deflection) > 1e-3
        assert np.linalg.norm(point.residual) < 1e-12
