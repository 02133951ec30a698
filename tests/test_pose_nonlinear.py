"""The pose face of ``nonlinear_joint_stiffness`` (a spring that softens or hardens): the
parameter ``gamma_j = c_j beta_j`` of ``Delta u_j += gamma_j t_j |t_j|``.

The simulator's nonlinear springs (``Delta u = t / k (1 + beta |t|)``) are checked against the
equilibrium found here independently (the torques from central differences of the potential
energy, springs on controller coordinates); the pose model at the truth reproduces the
simulated arm; its columns and its deflection slope agree with central differences; diagnose
names a hidden hardening spring and covers it, and names none where the springs are linear;
the model file carries ``beta = gamma / c`` into the elastic model, whose rest pose is where the
calibration's own model puts the marker.
"""

from __future__ import annotations

import json

import numpy as np
import pinocchio as pin
import pytest
from pose_campaigns import ur10_markers
from pose_columns import assert_columns
from pose_truth import add_intervals, truth
from scipy import optimize
from stats import Coverage
from test_absolute_poses import _jacobian_case
from test_pose_coupling import FORCE, MARKERS, ROBOT
from test_pose_coupling import STIFFNESS as COUPLED_STIFFNESS
from test_pose_model_file import _hand_written

from stiffness import load_model
from stiffness.calibration.pose_campaign import write_pose_campaign
from stiffness.calibration.pose_diagnose import diagnose_poses
from stiffness.calibration.pose_fit import campaign_settings, predict
from stiffness.calibration.pose_model import Loads, Marker, PoseModel
from stiffness.calibration.pose_model_file import parameter_table, write_pose_model
from stiffness.calibration.pose_report import format_pose_report
from stiffness.cli.main import main
from stiffness.elastic.effects.pose_face import SagState
from stiffness.errors import DataFileWarning, StiffnessError
from stiffness.planning.simulate_poses import (
    HiddenPoseErrors,
    hidden_elasticity,
    loaded_arm,
    simulate_pose_campaign,
)
from stiffness.robot.robot import load_robot

NOISE = 20e-6  # m, tracker-like
PAYLOAD = np.array([0.0, 0.0, -150.0, 0.0, 0.0, 0.0])  # N, N.m at tool0
STIFFNESS = np.array([3e5, 2e5, 1.2e5, 4e4, 3e4, 3e4])  # N.m/rad
#: Hidden hardening (1/(N.m)): the shoulder's and the elbow's compliance 40 % lower at the
#: largest torque they carry in these campaigns (about 275 and 134 N.m).
BETA = np.array([0.0, -0.4 / 275.0, -0.4 / 134.0, 0.0, 0.0, 0.0])
FAMILY = "nonlinear_joint_stiffness"
ELASTIC = ("frame", "markers", "joint_compliance", FAMILY)
#: Families a short diagnosis leaves out (none hidden).
OTHERS = ["joint_offsets", "geometry", "link_compliance", "transversal_compliance", "base_tilt",
          "backlash", "gravity_compensator"]


@pytest.fixture(scope="module")
def ur10():
    return load_robot("ur10", frame="tool0")


def _campaign(robot, seed: int, n: int, beta: np.ndarray | None, noise: float = NOISE):
    """A tracker anywhere, marker offsets off by mm, joint springs (``beta``: nonlinear)."""
    rng = np.random.default_rng(seed)
    markers = ur10_markers()
    hidden = HiddenPoseErrors(pin.exp3(rng.normal(size=3)), rng.uniform(-2, 2, 3),
                              np.array([m.offset for m in markers])
                              + rng.normal(0, 2e-3, (2, 3)),
                              np.zeros(6), np.zeros((6, 6)), STIFFNESS, nonlinear=beta)
    return hidden, simulate_pose_campaign(robot, markers, hidden, n, noise, seed=seed,
                                          payload=PAYLOAD)


def test_nonlinear_controller_springs_equal_the_exact_equilibrium(tmp_path):
    """Springs on controller coordinates (the coupled arm of test_pose_coupling, U2 softening,
    U3 hardening): at 4 commanded poses the simulator's loaded configuration is the root of
    ``du = t(du) / k (1 + beta |t(du)|)``, ``t`` minus the energy's gradient (gravity and the
    tool force, central differences) found here, to 1e-9 rad; the pose model at ``c = 1/k``,
    ``gamma = beta / k`` puts the markers where that root does, to 1e-9 m, and without its
    ``gamma`` more than 1e-5 m away."""
    path = tmp_path / "robot.toml"
    path.write_text(ROBOT)
    robot = load_robot(str(path))
    beta = np.array([0.0, 0.002, -0.003])  # 1/(N.m): U2 softens, U3 hardens
    joints = robot.model.nv
    hidden = HiddenPoseErrors(np.eye(3), np.zeros(3), np.zeros((2, 3)), np.zeros(joints),
                              np.zeros((joints, 6)), COUPLED_STIFFNESS, nonlinear=beta)
    springs = hidden_elasticity(robot, MARKERS, hidden, {})
    model, data = robot.model, robot.model.createData()
    tool = model.getFrameId("tool")
    wrench = np.r_[FORCE, 0.0, 0.0, 0.0]
    rng = np.random.default_rng(0)
    for _ in range(4):
        u = rng.uniform(-1.2, 1.2, 4)

        def q_of(du: np.ndarray, u=u) -> np.ndarray:
            w = u.copy()
            w[:3] += du
            return robot.configuration(w)

        def load_energy(du: np.ndarray) -> float:
            pin.framesForwardKinematics(model, data, q_of(du))
            return (pin.computePotentialEnergy(model, data, q_of(du))
                    - FORCE @ data.oMf[tool].translation)

        def residual(du: np.ndarray) -> np.ndarray:
            t = -np.array([(load_energy(du + 1e-6 * e) - load_energy(du - 1e-6 * e)) / 2e-6
                           for e in np.eye(3)])
            return du - t / COUPLED_STIFFNESS * (1.0 + beta * np.abs(t))

        sol = optimize.root(residual, np.zeros(3), tol=1e-14)
        assert np.abs(residual(sol.x)).max() < 1e-10
        exact = q_of(sol.x)
        assert abs(sol.x[1]) > 1e-4  # a real sag
        _, simulated = loaded_arm(model, robot.configuration(u), springs, wrench, "tool")
        assert np.abs(simulated - exact).max() < 1e-9
        pose = PoseModel(robot, MARKERS, ("joint_compliance", FAMILY), (np.eye(3), np.zeros(3)),
                         Loads("tool", np.zeros((0, 6))),
                         {"nonlinear_largest_torque": {"U2": 1.0, "U3": 1.0}})
        x = np.r_[1.0 / COUPLED_STIFFNESS, beta[1:] / COUPLED_STIFFNESS[1:]]
        row = [pose.row_terms(robot.configuration(u), wrench)]
        pin.framesForwardKinematics(model, data, exact)
        seen = np.array([data.oMf[model.getFrameId(m.frame)].act(m.offset) for m in MARKERS])
        assert np.abs(pose.evaluate(x, row, False)[0][0] - seen).max() < 1e-9
        x[3:] = 0.0
        assert np.abs(pose.evaluate(x, row, False)[0][0] - seen).max() > 1e-5


def test_the_model_reproduces_a_simulated_hardening_arm(ur10):
    """No noise, 12 poses: at the truth (``gamma = beta / k``) the pose model reproduces the
    simulated arm to 1e-9 m, and misses it by more than 10 noise std without ``gamma``. The
    vertical base joint and the last wrist joint carry no torque: no parameter."""
    hidden, c = _campaign(ur10, 3, 12, BETA, noise=0.0)
    settings = campaign_settings(c)
    model = PoseModel(ur10, c.markers, ELASTIC, (np.eye(3), np.zeros(3)), c.loads, settings)
    labels = [p.label for p in model.parameters if p.family == FAMILY]
    assert labels == [f"{j} nonlinear compliance" for j in ("shoulder_lift_joint", "elbow_joint",
                                                            "wrist_1_joint", "wrist_2_joint")]
    assert {p.unit for p in model.parameters if p.family == FAMILY} == {"rad/(N.m)^2"}
    x = truth(model, hidden)
    assert np.abs(predict(model, x, c) - c.positions).max() < 1e-9
    x[model.slices()[FAMILY]] = 0.0
    assert np.abs(predict(model, x, c) - c.positions).max() > 10 * NOISE


def test_columns_and_slope_by_central_differences(ur10):
    """The family's columns at zero compliance (exact) to 1e-6, every column of a sagging,
    hardening arm with a compensator (whose columns go through the deflection's slope) to 1e-2
    (the documented ``C dtau/dq`` approximation); the slope ``d Delta q / d tau`` against
    central differences of the family's deflection in the torque, to 1e-7."""
    families = (*ELASTIC, "gravity_compensator")
    model, rows, x, scales = _jacobian_case(ur10, families, seed=4)
    sl = model.slices()[FAMILY]
    assert sl.stop - sl.start == 6  # the rows' random wrenches load every spring
    rigid = x.copy()
    rigid[model.slices()["joint_compliance"]] = 0.0
    rigid[sl] = 0.0
    rigid[model.slices()["gravity_compensator"]] = 0.0
    assert_columns(model, rows, rigid, scales, 1e-6, range(sl.start, sl.stop))
    x[model.slices()["joint_compliance"]] = np.abs(x[model.slices()["joint_compliance"]])
    assert_columns(model, rows, x, scales, 1e-2)
    family = next(f for f in model.family_objects if f.name == FAMILY)
    gamma, nv = x[sl], ur10.model.nv
    torque = np.random.default_rng(5).normal(0.0, 100.0, (3, 1, nv))  # N.m

    def deflection(t: np.ndarray) -> np.ndarray:
        return family.joint_deflection(model, gamma, SagState(t, t, t, t, t))

    slope = family.deflection_per_torque(model, gamma, SagState(torque, torque, torque,
                                                                torque, torque))
    assert np.abs(slope).max() > 0
    for v in range(nv):
        step = 1e-3 * np.eye(nv)[v]
        fd = (deflection(torque + step) - deflection(torque - step))[..., v] / 2e-3
        assert np.abs(slope[..., v] - fd).max() <= 1e-7 * np.abs(slope).max()


def test_diagnose_names_a_hidden_hardening_spring(ur10):
    """UR10, 30 poses, two markers, 20 um, geometry not tried (none hidden): 3 campaigns with
    the shoulder and the elbow hardening by 40 % at their largest torques, where diagnose names
    nonlinear_joint_stiffness in every one, the fitted parameters' intervals covering the
    identifiable truth at a rate consistent with 95 % (:meth:`stats.Coverage.check`, about 54
    intervals); 2 with linear springs, where it is named in none. Measured over 20 seeds each:
    named in 20 of 20 (none of the linear ones), 343 of 360 intervals covering (38 of 40
    of the nonlinear compliances), 306 of 320 in the linear ones; held-out RMS 0.95-1.16
    times the noise in both."""
    cov = Coverage()
    for seed in range(3):
        hidden, c = _campaign(ur10, seed, 30, BETA)
        d = diagnose_poses(c, not_families=["geometry"])
        assert FAMILY in d.families, (seed, d.families)
        add_intervals(cov, d.final, hidden, c)
    cov.check(min_n=50)
    for seed in range(2):
        _, c = _campaign(ur10, 10 + seed, 30, None)
        d = diagnose_poses(c, not_families=["geometry"])
        assert FAMILY not in d.families, (seed, d.families)


def test_the_model_file_carries_beta(ur10, tmp_path, capsys):
    """A hand-written pose model file with hardening springs: load_model applies
    nonlinear_joint_stiffness with ``beta = gamma / c`` on each spring, and the elastic model's
    rest pose (the weight sagging the nonlinear springs) puts the marker where the
    calibration's own model predicts it, to 1e-7 m; a diagnosis naming the family reports
    ``beta = gamma / c`` beside ``gamma`` in its text and in its --json parameter row, is
    written, validated on its campaign and read by kx --model (exit 0)."""
    _, c = _campaign(ur10, 1, 12, BETA, noise=0.0)
    markers = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05]))]
    model = PoseModel(ur10, markers, ("frame", "markers", "joint_offsets", "joint_compliance",
                                      FAMILY), (np.eye(3), np.zeros(3)), None,
                      campaign_settings(c))
    x = np.zeros(model.size)
    x[model.slices()["joint_offsets"]] = 0.02
    x[model.slices()["joint_compliance"]] = 1.0 / STIFFNESS
    labels = [p.label for p in model.parameters]
    for joint, beta, k in zip(ur10.compliant_joints, BETA, STIFFNESS, strict=True):
        if beta:
            x[labels.index(f"{joint} nonlinear compliance")] = beta / k
    _hand_written(model, x, tmp_path / "final-model.json")
    em = load_model(tmp_path / "final-model.json")
    applied = {e.label: e for e in em.applied}
    for joint, beta in (("shoulder_lift_joint", BETA[1]), ("elbow_joint", BETA[2])):
        effect = applied[f"{FAMILY}({joint})"]
        assert effect.parameters[0].value == pytest.approx(beta, rel=1e-12)
        assert effect.parameters[0].unit == "1/(N.m)"
    qs = np.array([[0.3, -1.0, 1.2, -0.4, 1.0, 0.2], [-0.5, -2.0, 0.7, 0.3, -1.1, 0.5]])
    predicted = model.evaluate(x, [model.row_terms(ur10.configuration(q), None) for q in qs],
                               jacobian=False)[0][:, 0]
    data = em.robot.model.createData()
    tip = em.robot.model.getFrameId("tool0")
    for q, expected in zip(qs, predicted, strict=True):
        pin.framesForwardKinematics(em.robot.model, data,
                                    em.preloaded_configuration(em.configuration(q)))
        assert np.linalg.norm(data.oMf[tip].act(markers[0].offset) - expected) < 1e-7
    hidden, c = _campaign(ur10, 0, 30, BETA)
    d = diagnose_poses(c, families=["joint_compliance", FAMILY], not_families=OTHERS)
    report = format_pose_report(d)
    line = next(s for s in report.splitlines() if "elbow_joint nonlinear compliance" in s)
    table = {r["parameter"]: r["value"] for r in parameter_table(d.final)}
    beta = (table["elbow_joint nonlinear compliance"] / table["elbow_joint compliance"])
    assert "rad/(N.m)^2" in line and f"beta = gamma/c = {beta:.4g} 1/(N.m)" in line, line
    rows = {r["parameter"]: r for r in json.loads(json.dumps(d.to_dict()))["parameters"]}
    assert rows["elbow_joint nonlinear compliance"]["beta"] == {  # what --json prints
        "value": pytest.approx(beta, rel=1e-12), "unit": "1/(N.m)",
        "of": "gamma / c (elbow_joint compliance)"}
    assert rows["elbow_joint nonlinear compliance"]["value"] == table[
        "elbow_joint nonlinear compliance"]  # gamma kept under its own keys
    assert "beta" not in rows["elbow_joint compliance"]
    _check_physical_scales(d, c)
    write_pose_campaign(c, tmp_path / "campaign")
    path = write_pose_model(d.final, c, tmp_path / "d" / "final-model.json")
    assert FAMILY in json.loads(path.read_text())["families"]
    assert main(["validate", str(path), str(tmp_path / "campaign"), "--json"]) == 0
    with pytest.warns(DataFileWarning, match="held rigid"):  # the unloaded base and wrist
        assert main(["kx", "--model", str(path), "--q", "0.1,-1.2,1.0,-0.5,1.2,0.3",
                     "--wrench", "0,0,-100"]) == 0
    capsys.readouterr()


def _check_physical_scales(d, c) -> None:
    """Each ``gamma``'s physical scale is ``1 / (k_ref tau_max)``: ``k_ref`` the geometric mean
    of the stiffnesses the fit determines (kept, off their bound, their compliance's 95 %
    interval above zero), ``tau_max`` the largest torque the joint carries at
    the commanded poses (``-g(q) + J^T w``, computed here with Pinocchio)."""
    fit, robot = d.final, c.robot
    data = robot.model.createData()
    torques = []
    for q, w in zip(c.q, c.loads.wrench, strict=True):
        q_full = robot.configuration(q)
        pin.computeJointJacobians(robot.model, data, q_full)
        pin.updateFramePlacements(robot.model, data)
        jac = pin.getFrameJacobian(robot.model, data, robot.model.getFrameId("tool0"),
                                   pin.LOCAL_WORLD_ALIGNED)
        torques.append(jac.T @ w - pin.computeGeneralizedGravity(robot.model, data, q_full))
    tau_max = np.abs(np.array(torques)).max(axis=0)
    cut = fit.model.slices()["joint_compliance"]
    kept, low = set(fit.identifiability.kept), fit.interval()[0]
    k_ref = np.exp(-np.mean(np.log([fit.x[i] for i in range(cut.start, cut.stop)
                                    if i in kept and i not in fit.at_bound and low[i] > 0])))
    family = next(f for f in fit.model.family_objects if f.name == FAMILY)
    sizes = family.physical_sizes(fit.model, d.judge.references(fit))
    joints = [p.label.removesuffix(" nonlinear compliance") for p in fit.model.parameters
              if p.family == FAMILY]
    expected = [1.0 / (k_ref * tau_max[robot.model.joints[robot.model.getJointId(j)].idx_v])
                for j in joints]
    assert np.allclose(sizes, expected, rtol=1e-9), (sizes, expected)


def test_without_its_torques_or_with_unknown_masses_it_is_refused(ur10):
    """Without the springs' largest torques (the campaign's setting), or beside the lumped
    gravity of unknown masses: one-line typed errors."""
    frame0 = (np.eye(3), np.zeros(3))
    with pytest.raises(StiffnessError, match="largest torque") as err:
        PoseModel(ur10, ur10_markers(), ("joint_compliance", FAMILY), frame0)
    assert "\n" not in str(err.value)
    with pytest.raises(StiffnessError, match="masses"):
        PoseModel(ur10, ur10_markers(), ("gravity_lumped", "joint_compliance", FAMILY), frame0,
                  settings={"nonlinear_largest_torque": {}})
