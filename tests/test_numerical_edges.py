"""Numerical edge cases: singular poses, zero and buckling loads, stiffness spread, prismatic.

Each case gives a correct answer (checked against an independent computation: finite
differences, a closed form, exact rational arithmetic) or a one-line typed error; no output file
of any command holds NaN or infinity unless its schema says the value is undefined and names it
(docs/reliability.md, "Numerical edge cases").
"""

from __future__ import annotations

import csv
import json
import re
from fractions import Fraction
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from scipy.linalg import eigh
from scipy.optimize import brentq

from stiffness.batch import kernels as batch
from stiffness.batch.linalg import critical_load_factor
from stiffness.cli.main import main
from stiffness.errors import (
    SingularConfigurationError,
    UnstableEquilibriumError,
)
from stiffness.mechanics.equilibrium import solve_equilibrium, torque_scale
from stiffness.mechanics.formulation import (
    CONDITION_LIMIT,
    cartesian_stiffness,
    compliance,
    definiteness,
    subspace_stiffness,
    tangent_definiteness,
    target_state,
)
from stiffness.robot.robot import load_robot
from stiffness.workspace.engine import UNDEFINED
from stiffness.workspace.maps import derive
from stiffness.workspace.spec import ScanSpec

UR5_K = [3e5, 3e5, 2e5, 4e4, 4e4, 4e4]
UR5_KQ = ",".join(map(str, UR5_K))
#: Wrist singularity (wrist_2 = 0: wrist_1 and wrist_3 axes aligned) and elbow singularity
#: (elbow = 0: arm stretched), rad.
UR5_WRIST = [0.3, -1.2, 1.5, -0.3, 0.0, 0.4]
UR5_ELBOW = [0.3, -1.2, 0.0, -0.3, 1.5, 0.4]
#: UR5 standing straight up: tool0 on the vertical through every horizontal joint axis.
UR5_UP = [0.0, -np.pi / 2, 0.0, -np.pi / 2, 0.0, 0.0]
#: SK120 with q2 + q3 = -90 deg: the parallelogram folded flat (deg, printed angles).
SK120_FLAT_DEG = [-33.2, 15.9, -105.9, 0.0, -34.4, -90.0]
EPS = np.finfo(float).eps


@pytest.fixture(scope="module")
def ur5():
    return load_robot("ur5", frame="tool0")


def _strict_json(text: str):
    """JSON without NaN / Infinity tokens (Python's json accepts them; strict JSON does not)."""
    def refuse(token):
        raise AssertionError(f"non-finite number {token} in JSON output")
    return json.loads(text, parse_constant=refuse)


def _kx(capsys, *argv) -> dict:
    assert main(["kx", *argv, "--json"]) == 0
    return _strict_json(capsys.readouterr().out)


def _fd_jacobian(robot, coords, h=1e-6) -> np.ndarray:
    """(6, n) Jacobian [v; omega] by central differences of the target pose (open chains)."""
    cols = []
    for k in range(len(coords)):
        e = np.zeros(len(coords))
        e[k] = h
        plus = target_state(robot, robot.configuration(np.asarray(coords) + e))
        minus = target_state(robot, robot.configuration(np.asarray(coords) - e))
        v = (plus.position - minus.position) / (2 * h)
        w = pin.log3(plus.rotation @ minus.rotation.T) / (2 * h)
        cols.append(np.concatenate([v, w]))
    return np.column_stack(cols)


# ------------------------------------------------------------------------------ singular poses


@pytest.mark.parametrize("coords", [UR5_WRIST, UR5_ELBOW], ids=["wrist", "elbow"])
def test_kx_at_ur5_singularities(capsys, ur5, coords):
    """3x3: K_X exists (the position Jacobian keeps rank 3) and equals inv(J K^-1 J^T) of the
    FD Jacobian; 6x6: K_X is null with the reason, the compliance is finite and right, and the
    moving subspace has rank 5 with the rigid wrench direction felt by no joint."""
    q = ",".join(map(str, coords))
    j_fd = _fd_jacobian(ur5, coords)
    k_inv = np.diag(1.0 / np.array(UR5_K))
    three = _kx(capsys, "--robot", "ur5", "--q", q, "--kq", UR5_KQ, "--wrench", "0,0,0")
    c3 = j_fd[:3] @ k_inv @ j_fd[:3].T
    # FD truncation (h^2 ~ 1e-12) and cancellation (eps/h ~ 2e-10) bound the FD Jacobian
    np.testing.assert_allclose(three["compliance"], c3, rtol=0, atol=1e-8 * np.abs(c3).max())
    np.testing.assert_allclose(three["K_X"], np.linalg.inv(c3), rtol=1e-6)
    assert three["K_X_undefined"] is None and three["K_X_subspace"] is None
    six = _kx(capsys, "--robot", "ur5", "--q", q, "--kq", UR5_KQ, "--wrench", "0,0,0,0,0,0")
    assert six["K_X"] is None and six["eigenvalues"] is None
    assert six["definiteness"]["K_X"] is None
    assert re.search(r"compliance is singular \(condition number [0-9.e+]+\)", six["K_X_undefined"])
    c6 = j_fd @ k_inv @ j_fd.T
    np.testing.assert_allclose(six["compliance"], c6, rtol=0, atol=1e-8 * np.abs(c6).max())
    sub = six["K_X_subspace"]
    assert sub["rank"] == 5 and len(sub["rigid_directions"]) == 1
    rigid = np.array(sub["rigid_directions"][0])
    assert np.abs(j_fd.T @ rigid).max() < 1e-8  # no joint feels that wrench
    k_sub = np.array(sub["K_X"])
    np.testing.assert_allclose(k_sub @ c6 @ k_sub, k_sub, rtol=0, atol=1e-6 * np.abs(k_sub).max())
    np.testing.assert_allclose(sub["eigenvalues"], np.sort(1 / np.linalg.svd(c6)[1][:5]),
                               rtol=1e-6)
    joint = _kx(capsys, "--robot", "ur5", "--q", q, "--kq", UR5_KQ, "--connection", "joint",
                "--wrench", "0,0,-100")
    assert joint["K_X"] is None and "condition number" in joint["K_X_undefined"]
    assert joint["K_X_subspace"]["rank"] == 5


def test_kx_text_at_a_singularity(capsys):
    """The table output says K_X is undefined and why, and prints the compliance instead."""
    assert main(["kx", "--robot", "ur5", "--q", ",".join(map(str, UR5_ELBOW)), "--kq", UR5_KQ,
                 "--wrench", "0,0,-10,0,0,0", "--quiet"]) == 0
    text = capsys.readouterr().out
    assert re.search(r"^K_X undefined: the compliance is singular \(condition number", text, re.M)
    assert "compliance (m/N blocks)" in text and "5-dimensional moving subspace" in text
    assert "nan" not in text.lower()


def test_library_at_ur5_singularity(ur5):
    """target_state and compliance are finite, cartesian_stiffness raises one typed line,
    subspace_stiffness gives the rest; the exact equilibrium converges and approaches the linear
    deflection; batch.evaluate flags the 6x6 K_X and keeps the compliance."""
    q = ur5.configuration(np.array(UR5_WRIST))
    load = np.array([10.0, -20.0, -100.0])
    state = target_state(ur5, q, load)
    assert np.isfinite(state.jacobian).all() and np.isfinite(state.k_c).all()
    c = compliance(state.jacobian, np.diag(UR5_K) - state.k_c)
    assert np.isfinite(c).all()
    with pytest.raises(SingularConfigurationError) as info:
        cartesian_stiffness(c)
    assert "\n" not in str(info.value) and "condition number" in str(info.value)
    sub = subspace_stiffness(c)
    assert sub.rank == 5 and np.abs(state.jacobian.T @ sub.rigid).max() < 1e-9
    assert subspace_stiffness(c[:3, :3]).rank == 3  # regular: the plain inverse
    np.testing.assert_allclose(subspace_stiffness(c[:3, :3]).stiffness,
                               np.linalg.inv(c[:3, :3]), rtol=1e-10)
    errors = []
    for scale in (0.1, 1.0):
        eq = solve_equilibrium(ur5, q, np.diag(UR5_K), scale * load)
        c_s = compliance(state.jacobian, np.diag(UR5_K) - scale * state.k_c)  # K_C is linear
        linear = c_s[:3] @ np.concatenate([scale * load, np.zeros(3)])
        errors.append(np.linalg.norm(eq.dx - linear) / np.linalg.norm(linear))
    # exact - linear is second order in the load: the relative error is the size of the
    # deflection (3e-4 rad at full load) and scales with the load
    assert errors[1] < 1e-3 and 7 < errors[1] / errors[0] < 13
    result = batch.evaluate(ur5, q[None], [[*load, 0, 0, 0]], UR5_K)
    assert not result.regular[0, 0] and np.isnan(result.k_x).all()
    np.testing.assert_allclose(result.compliance[0, 0], c, rtol=0, atol=1e-12 * np.abs(c).max())
    three = batch.evaluate(ur5, q[None], [load], UR5_K)
    assert three.regular[0, 0] and np.isfinite(three.k_x).all()


PLANAR_2R = """<robot name="planar2r"><link name="base"/><link name="l1"/><link name="l2"/>
<link name="tip"/>
<joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/>
 <limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
<joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0.4 0 0"/>
 <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
<joint name="t" type="fixed"><parent link="l2"/><child link="tip"/><origin xyz="0.3 0 0"/>
</joint></robot>"""


def test_subspace_stiffness_of_a_buckled_planar_arm_keeps_its_sign(tmp_path, capsys):
    """A planar 2R arm pushed along itself past its buckling load: K_theta - K_C is indefinite,
    so is the 2-D compliance, and the stiffness on the moving subspace has a negative principal
    value. It was printed positive (1/singular values: Gepetto's 5-bar next to its parallel
    singularity showed [10.6, 5.6e4] N/m while unstable); now the signed eigenvalues of C's
    inverse on its range, from C's own eigen-decomposition here."""
    import json

    from stiffness.cli.main import main

    (tmp_path / "planar2r.urdf").write_text(PLANAR_2R)
    argv = ["kx", "--robot", str(tmp_path / "planar2r.urdf"), "--kq", "10,10", "--q", "0,0.3"]
    for load, unstable in (("-200,0,0", True), ("0,-5,0", False)):
        assert main([*argv, "--wrench", load, "--json"]) == 0
        out = json.loads(capsys.readouterr().out)
        lam, vec = np.linalg.eigh(np.array(out["compliance"]))
        on_range = np.abs(lam) > 1e-12 * np.abs(lam).max()
        assert on_range.sum() == 2 and out["K_X_subspace"]["rank"] == 2
        np.testing.assert_allclose(out["K_X_subspace"]["eigenvalues"],
                                   np.sort(1.0 / lam[on_range]), rtol=1e-9)
        assert (min(out["K_X_subspace"]["eigenvalues"]) < 0) == unstable == (not out["stable"])


def test_flat_sk120_parallelogram_is_one_typed_line(capsys):
    """Folded flat, the passive joints are not determined by the actuated ones: K_C, J and the
    compliance do not exist there. One-at-a-time calls raise; batch and scan mark it invalid."""
    sk = load_robot("sk120")
    coords = np.deg2rad(SK120_FLAT_DEG)
    with pytest.raises(SingularConfigurationError, match="loop of sk120 is singular"):
        target_state(sk, sk.configuration(coords))
    assert main(["kx", "--robot", "sk120", "--deg", "--q", ",".join(map(str, SK120_FLAT_DEG)),
                 "--json"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "loop of sk120 is singular" in err
    closed = batch.close_loops(sk, np.vstack([coords, np.deg2rad([-33.2, 15.9, -55.6, 0, -34.4,
                                                                   -90.0])]))
    kin = batch.batch_kinematics(sk, closed.q)
    result = batch.evaluate(sk, kin, [[0.0, 0.0, -100.0]], [1.4e6, 4.0e5, 9.4e5])
    assert result.valid.tolist() == [False, True] and result.regular[:, 0].tolist() == [False, True]
    assert np.isfinite(result.k_x[1]).all()


# ------------------------------------------------------------------------- zero load, buckling


def _closed_form_k_c(ur5, coords, force) -> np.ndarray:
    """K_C = sum_k F_k d2x_k / dq_a dq_b of a serial chain of revolute joints, from the joint
    axes and origins only: d2p/dq_a dq_b = w_a x (w_b x (p - o_b)) for a <= b."""
    q = ur5.configuration(np.array(coords))
    model, data = ur5.model, ur5.data
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    p = data.oMf[ur5.target_frame_id].translation
    axes, origins = [], []
    for name in ur5.compliant_joints:
        jid = model.getJointId(name)
        column = pin.getJointJacobian(model, data, jid, pin.ReferenceFrame.WORLD)
        axes.append(column[3:, model.joints[jid].idx_v])
        origins.append(data.oMi[jid].translation)
    n = len(axes)
    k_c = np.zeros((n, n))
    for a in range(n):
        for b in range(a, n):
            d2 = np.cross(axes[a], np.cross(axes[b], p - origins[b]))
            k_c[a, b] = k_c[b, a] = force @ d2
    return k_c


def test_zero_load(capsys, ur5):
    """No load: K_C = 0, both formulations agree, the equilibrium is the start (1 iteration)."""
    q = ",".join(map(str, UR5_WRIST))
    out = _kx(capsys, "--robot", "ur5", "--q", q, "--kq", UR5_KQ, "--wrench", "0,0,0")
    assert np.array(out["K_C"]).max() == 0 and out["definiteness"]["K_C"] == "PSD"
    conv = _kx(capsys, "--robot", "ur5", "--q", q, "--kq", UR5_KQ, "--wrench", "0,0,0",
               "--formulation", "conventional")
    np.testing.assert_allclose(out["K_X"], conv["K_X"], rtol=1e-12)
    eq = solve_equilibrium(ur5, ur5.configuration(np.array(UR5_WRIST)), np.diag(UR5_K),
                           np.zeros(3))
    assert eq.iterations == 1 and not eq.dx.any()
    kin = batch.batch_kinematics(ur5, ur5.configuration(np.array(UR5_WRIST))[None])
    assert np.isinf(batch.definiteness_map(kin, np.zeros((1, 3)), UR5_K).critical_factor).all()


def test_buckling_load_from_eigenvalues(capsys, ur5):
    """UR5 straight up under a load along the arm: the critical load factor of the batch layer
    equals the closed form (generalised eigenvalues of K_theta and the axis-formula K_C); just
    below it everything is positive definite and the exact equilibrium holds; just above, the
    linear formulation says indefinite and the exact equilibrium raises one typed line."""
    k_theta = np.diag([300.0, 300.0, 200.0, 40.0, 40.0, 40.0])
    unit = np.array([0.0, 0.0, -1.0])  # 1 N pressing down the column
    k_c = _closed_form_k_c(ur5, UR5_UP, unit)
    state = target_state(ur5, ur5.configuration(np.array(UR5_UP)), unit)
    np.testing.assert_allclose(state.k_c, k_c, rtol=0, atol=1e-9)
    top = eigh(0.5 * (k_c + k_c.T), k_theta, eigvals_only=True)[-1]
    critical = critical_load_factor(k_theta, state.k_c)
    assert critical == pytest.approx(1.0 / top, rel=1e-9)
    q0 = ur5.configuration(np.array(UR5_UP))
    kq = ",".join(map(str, np.diag(k_theta)))
    coords = ",".join(map(str, UR5_UP))
    for factor, tangent_class in ((1 - 1e-3, "PD"), (1 + 1e-3, "ID")):
        load = factor * critical * unit
        out = _kx(capsys, "--robot", "ur5", "--q", coords, "--kq", kq,
                  "--wrench", ",".join(map(str, load)))
        assert out["definiteness"]["K_theta_minus_K_C"] == tangent_class
        if tangent_class == "PD":
            eq = solve_equilibrium(ur5, q0, k_theta, load)
            # the straight column is the stable equilibrium; round-off torques (1e-12 |W| m)
            # are amplified by 1 / (1 - 0.999) near the buckling load: dx ~ 1e-9 m
            assert np.abs(eq.dx).max() < 1e-7
        else:
            assert out["definiteness"]["K_X"] != "PD"
            with pytest.raises(UnstableEquilibriumError) as info:
                solve_equilibrium(ur5, q0, k_theta, load)
            assert "\n" not in str(info.value) and "buckling" in str(info.value)


@pytest.mark.parametrize("magnitude", [1e-3, 1.0, 1e2, 1e4])
def test_equilibrium_with_the_load_along_the_arm_converges(ur5, magnitude):
    """|J^T W| is round-off (~1e-12 |W|) when the load runs along the arm: the convergence test
    is relative to the terms of the residual (residual_scale), so it converges at once."""
    q0 = ur5.configuration(np.array(UR5_UP))
    k_theta = np.diag(UR5_K)
    load = np.array([0.0, 0.0, magnitude])  # pulling up: tension (the wrist offsets of 0.1 m
    # couple it to the wrist springs: stable while magnitude * 0.1 m << 4e4 N.m/rad)
    state = target_state(ur5, q0, load)
    assert np.abs(state.jacobian.T @ state.wrench).max() < 1e-10 * magnitude
    eq = solve_equilibrium(ur5, q0, k_theta, load)
    assert eq.iterations <= 3 and np.abs(eq.dx).max() < 1e-12 * max(magnitude, 1.0)
    assert torque_scale(state.jacobian, state.wrench).max() > 0.1 * magnitude


# ---------------------------------------------------------- stiffness spread, prismatic joint

RPR_URDF = """<?xml version="1.0"?>
<robot name="rpr">
  <link name="base"/><link name="l1"/><link name="l2"/><link name="l3"/><link name="tip"/>
  <joint name="yaw" type="revolute"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.2"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/>
  </joint>
  <joint name="slide" type="prismatic"><parent link="l1"/><child link="l2"/>
    <origin xyz="0.4 0 0"/><axis xyz="1 0 0"/>
    <limit lower="-0.2" upper="0.2" effort="1" velocity="1"/></joint>
  <joint name="pitch" type="revolute"><parent link="l2"/><child link="l3"/>
    <origin xyz="0.1 0 0"/><axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="1" velocity="1"/>
  </joint>
  <joint name="tool" type="fixed"><parent link="l3"/><child link="tip"/><origin xyz="0.3 0 0"/>
  </joint>
</robot>
"""
RPR_Q = np.array([0.3, 0.05, 0.4])  # rad, m, rad


def _rpr_tip(q) -> np.ndarray:
    """Closed form of the tip: yaw about z at 0.2 m height, slide along the arm, pitch about y."""
    yaw, slide, pitch = q
    reach = 0.5 + slide + 0.3 * np.cos(pitch)
    return np.array([np.cos(yaw) * reach, np.sin(yaw) * reach, 0.2 - 0.3 * np.sin(pitch)])


def _rpr_jacobian(q, h=1e-6) -> np.ndarray:
    return np.column_stack([(_rpr_tip(q + h * e) - _rpr_tip(q - h * e)) / (2 * h)
                            for e in np.eye(3)])


@pytest.fixture(scope="module")
def rpr(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("rpr") / "rpr.urdf"
    path.write_text(RPR_URDF)
    return path


def _exact_inverse(m: np.ndarray) -> np.ndarray:
    """Inverse of a 3x3 float matrix in exact rational arithmetic (then rounded once)."""
    a = [[Fraction(float(x)) for x in row] for row in m]
    cof = [[a[(j + 1) % 3][(i + 1) % 3] * a[(j + 2) % 3][(i + 2) % 3]
            - a[(j + 1) % 3][(i + 2) % 3] * a[(j + 2) % 3][(i + 1) % 3] for j in range(3)]
           for i in range(3)]
    det = sum(a[0][k] * cof[k][0] for k in range(3))
    return np.array([[float(cof[i][j] / det) for j in range(3)] for i in range(3)])


def test_prismatic_next_to_revolute_against_closed_form(capsys, rpr):
    """J, K_C (mixed N.m/rad, N, N/m entries) and the compliance of the RPR arm equal the closed
    form; moderate stiffness gives K_X to round-off."""
    force = np.array([5.0, -3.0, -40.0])
    out = _kx(capsys, "--robot", str(rpr), "--frame", "tip", "--q",
              ",".join(map(str, RPR_Q)), "--kq", "1e3,1e5,1e4",
              "--wrench", ",".join(map(str, force)))
    jac = _rpr_jacobian(RPR_Q)
    np.testing.assert_allclose(out["J"], jac, rtol=0, atol=1e-9)
    h = 1e-5
    k_c = np.column_stack([(_rpr_jacobian(RPR_Q + h * e).T @ force
                            - _rpr_jacobian(RPR_Q - h * e).T @ force) / (2 * h)
                           for e in np.eye(3)])
    np.testing.assert_allclose(out["K_C"], k_c, rtol=0, atol=1e-5 * np.abs(k_c).max())
    tangent = np.diag([1e3, 1e5, 1e4]) - np.array(out["K_C"])
    c = jac @ np.linalg.solve(tangent, jac.T)
    np.testing.assert_allclose(out["compliance"], c, rtol=0, atol=1e-8 * np.abs(c).max())


def test_twelve_orders_of_stiffness(capsys, rpr):
    """k from 1e-2 N.m/rad to 1e10 N/m: the compliance is right to round-off; K_X = C^-1 is
    right to the bound eps * cond(C) its inversion allows (measured against the exact rational
    J^-T K J^-1 of the same J); one more order pushes cond(C) past 1e12 and K_X becomes null
    with the condition number named, while the compliance stays right."""
    args = ["--robot", str(rpr), "--frame", "tip", "--q", ",".join(map(str, RPR_Q)),
            "--wrench", "0,0,0"]
    for kq, defined in (([1e-2, 1e10, 1e4], True), ([1e-3, 1e10, 1e4], False)):
        out = _kx(capsys, *args, "--kq", ",".join(map(str, kq)))
        assert out["definiteness"]["K_theta_minus_K_C"] == "PD"
        jac = np.array(out["J"])
        c_exact = jac @ np.diag(1.0 / np.array(kq)) @ jac.T
        np.testing.assert_allclose(out["compliance"], c_exact, rtol=0,
                                   atol=8 * EPS * np.abs(c_exact).max())
        cond = np.linalg.cond(c_exact)
        assert (cond < CONDITION_LIMIT) == defined
        robot = load_robot(str(rpr), frame="tip")
        regular = batch.evaluate(robot, robot.configuration(RPR_Q)[None], [[0.0, 0, 0]], kq)
        assert regular.regular[0, 0] == defined  # the batched test is the same 2-norm one
        if defined:
            j_inv = _exact_inverse(jac)
            k_exact = j_inv.T @ np.diag(kq) @ j_inv
            # inverting C perturbed by eps |C| perturbs K_X by K (eps |C|) K: eps cond(C) |K|
            bound = 10 * EPS * cond
            for k_x in (np.array(out["K_X"]), regular.k_x[0, 0]):  # one at a time, batched
                assert np.abs(k_x - k_exact).max() / np.abs(k_exact).max() <= bound
            assert bound < 1e-2  # the answer keeps at least two significant digits
            values = np.linalg.eigvalsh(k_exact)
            rel = np.abs(np.array(out["eigenvalues"]) - values) / values
            assert rel.max() <= bound
        else:
            assert out["K_X"] is None
            found = float(re.search(r"condition number ([0-9.e+]+)", out["K_X_undefined"])[1])
            assert found == pytest.approx(cond, rel=1e-2) and found > CONDITION_LIMIT
            assert "orders of magnitude" in out["K_X_undefined"]


def test_equilibrium_with_twelve_orders_and_a_prismatic_joint(rpr):
    """Under a vertical force only the pitch spring works; its closed-form equilibrium
    k3 (t - t0) = 0.3 P cos t (brentq) matches Newton, with yaw at 1e-2 and slide at 1e10."""
    robot = load_robot(str(rpr), frame="tip")
    k_theta = np.diag([1e-2, 1e10, 50.0])
    force = 40.0
    q0 = robot.configuration(RPR_Q)
    eq = solve_equilibrium(robot, q0, k_theta, np.array([0.0, 0.0, -force]))
    pitch = brentq(lambda t: 50.0 * (t - RPR_Q[2]) - 0.3 * force * np.cos(t), RPR_Q[2],
                   RPR_Q[2] + 1.0, xtol=1e-15)
    assert eq.dtheta[2] == pytest.approx(pitch - RPR_Q[2], rel=1e-10)
    assert abs(eq.dtheta[0]) < 1e-12 and abs(eq.dtheta[1]) < 1e-15
    np.testing.assert_allclose(eq.dx, _rpr_tip([RPR_Q[0], RPR_Q[1], pitch]) - _rpr_tip(RPR_Q),
                               rtol=0, atol=1e-12)
    assert definiteness(k_theta) == "PSD"  # 1e-2 is below 1e-9 of 1e10: counted as zero
    assert tangent_definiteness(k_theta, k_theta - target_state(robot, eq.q, [0, 0, -force]).k_c
                                ) == "PD"  # in the metric of K_theta (what kx reports)


# ------------------------------------------------------------------- no NaN in any output file


def _check_json(path: Path) -> None:
    _strict_json(path.read_text())


def _check_csv(path: Path) -> None:
    with path.open() as f:
        for row in csv.reader(f):
            for cell in row:
                try:
                    value = float(cell)
                except ValueError:
                    continue
                assert np.isfinite(value), f"{path}: {cell!r}"


def _check_html(path: Path) -> None:
    """Every embedded JSON block is strict; every scene transform is finite."""
    page = path.read_text()
    for block in re.findall(r'<script type="application/json"[^>]*>(.*?)</script>', page, re.S):
        _strict_json(block)
    if 'id="stiffness-commands"' in page:
        from stiffness.viewer.page import scene_commands, scene_transforms

        for matrix in scene_transforms(scene_commands(page)).values():
            assert np.isfinite(matrix).all(), path


def _check_scan(folder: Path) -> None:
    """NaN / inf in a scan's arrays only where manifest.json's "undefined" says, nowhere else."""
    manifest = _strict_json((folder / "manifest.json").read_text())
    assert manifest["undefined"] == _strict_json(json.dumps(UNDEFINED))
    spec = ScanSpec.from_dict(manifest["spec"])
    for chunk in sorted((folder / "chunks").glob("chunk-*.npz")):
        # the stored arrays with the derived ones rebuilt, as load_scan reads them
        maps = derive(spec, int(chunk.stem.split("-")[1]), dict(np.load(chunk)))
        valid, regular = maps["valid"], maps["regular"]
        for key, value in maps.items():
            if value.dtype.kind != "f":
                continue
            bad = ~np.isfinite(value).reshape(value.shape[0], -1).all(axis=1) if value.ndim > 1 \
                else ~np.isfinite(value)
            if key in ("k_x", "k_x_eigenvalues"):
                nan = np.isnan(value).reshape(*regular.shape, -1)
                assert (nan.all(axis=-1) == ~regular).all() and (nan.any(axis=-1) == ~regular).all()
                assert not np.isinf(value).any()
            elif key in ("k_x_conventional", "k_x_conventional_eigenvalues"):
                nan = np.isnan(value).reshape(value.shape[0], -1)
                assert (nan.all(axis=1) == ~maps["regular_conventional"]).all()
                assert (nan.any(axis=1) == ~maps["regular_conventional"]).all()
            elif key == "critical_factor":
                assert (np.isnan(value).any(axis=1) == ~valid).all()
                assert not (value == -np.inf).any()
            elif key in ("position", "k_c_diagonal"):
                assert (bad == ~valid).all(), key
            else:
                assert not bad.any(), f"{chunk.name}: {key}"
    for agg in sorted((folder / "chunks").glob("aggregate-*.npz")):
        for key, value in np.load(agg).items():
            assert not np.isnan(value).any(), f"{agg.name}: {key}"  # only +-inf sentinels
    parquet = folder / "maps.parquet"
    if parquet.is_dir():
        import pyarrow.parquet as pq

        table = pq.read_table(parquet).to_pydict()
        regular = np.array(table["regular"])
        for name, column in table.items():
            values = np.asarray(column)
            if values.dtype.kind != "f":
                continue
            nan = np.isnan(values)
            if name.startswith("k_x_conventional"):
                assert (nan == ~np.array(table["regular_conventional"])).all(), name
            elif name.startswith("k_x_"):
                assert (nan == ~regular).all(), name
            elif name == "critical_factor" or name.endswith("_m") or name.startswith(
                    "k_c_diag_"):
                assert (nan == ~np.array(table["valid"])).all(), name
            else:
                assert not nan.any(), name
    for name in ("manifest.json", "summary.json"):
        _check_json(folder / name)


def check_outputs(root: Path) -> int:
    """Check every JSON, CSV, HTML and scan output under ``root``; returns the files checked."""
    checkers = {".json": _check_json, ".csv": _check_csv, ".html": _check_html}
    count = 0
    for path in sorted(root.rglob("*")):
        if path.suffix in checkers:
            checkers[path.suffix](path)
            count += 1
    for manifest in root.rglob("manifest.json"):
        _check_scan(manifest.parent)
        count += 1
    return count


def _write_edge_campaign(tmp_path: Path) -> Path:
    """A small UR5 campaign plus a row at the wrist singularity and a zero-load row."""
    camp = tmp_path / "camp"
    assert main(["simulate", "--robot", "ur5", "--kq", "1e5,1e5,1e5,1e4,1e4,1e4", "--configs",
                 "4", "--loads-per-config", "2", "--max-force", "200", "--seed", "3", "--quiet",
                 "--out", str(camp)]) == 0
    ur5 = load_robot("ur5", frame="tool0")
    rows = []
    for label, deg, force in (("W", [20, -60, 80, -20, 0, 30], [0, 0, -150.0]),
                              ("Z", [20, -60, 80, -20, 40, 30], [0, 0, 0.0])):
        q = ur5.configuration(np.deg2rad(deg))
        dx = solve_equilibrium(ur5, q, np.diag([1e5, 1e5, 1e5, 1e4, 1e4, 1e4]),
                               np.array(force)).dx * 1e3
        rows.append(",".join(map(str, [label, *deg, *force, *dx])))
    with (camp / "measurements.csv").open("a") as f:
        f.write("\n".join(rows) + "\n")
    return camp


def test_no_command_writes_an_undefined_number(tmp_path, capsys):
    """simulate, identify, diagnose, scan (NPZ and Parquet), view --export and kx --json on
    inputs with singular poses, a flat parallelogram, zero loads and a 12-order stiffness
    spread: strict JSON, finite CSV, NaN in the maps only where the manifest names it."""
    camp = _write_edge_campaign(tmp_path)
    assert main(["identify", str(camp), "--starts", "1", "--quiet",
                 "--out", str(tmp_path / "identified.json")]) == 0
    assert main(["diagnose", str(camp), "--quiet", "--out", str(tmp_path / "diagnosis")]) == 0
    assert main(["scan", "--robot", "ur5", "--axis", "elbow_joint=-0.5:0.5:0.5",
                 "--axis", "wrist_2_joint=-0.5:0.5:0.5", "--q", ",".join(map(str, UR5_WRIST)),
                 "--kq", UR5_KQ, "--wrench", "0,0,-200,0,0,0", "--wrench", "0,0,0,0,0,0",
                 "--format", "both", "--no-plots", "--quiet", "--out",
                 str(tmp_path / "scan-ur5")]) == 0
    assert main(["scan", "--robot", "sk120", "--deg", "--axis", "joint3=-115.9:-95.9:10",
                 "--q", ",".join(map(str, SK120_FLAT_DEG)), "--format", "both", "--no-plots",
                 "--quiet", "--out", str(tmp_path / "scan-sk120")]) == 0
    for name, extra in (("wrist", ["--q", ",".join(map(str, UR5_WRIST)), "--kq", UR5_KQ]),
                        ("two-joints", ["--q", ",".join(map(str, UR5_ELBOW)), "--kq", "3e5,3e5",
                                        "--compliant-joints",
                                        "shoulder_pan_joint,shoulder_lift_joint"])):
        assert main(["view", "--robot", "ur5", *extra, "--wrench", "0,0,-200", "--quiet",
                     "--export", str(tmp_path / f"view-{name}.html")]) == 0
    capsys.readouterr()
    for name, argv in (("kx-6x6", ["--robot", "ur5", "--q", ",".join(map(str, UR5_ELBOW)),
                                   "--kq", UR5_KQ, "--wrench", "0,0,-10,0,0,0"]),
                       ("kx-twist", ["--robot", "ur5", "--q", ",".join(map(str, UR5_WRIST)),
                                     "--kq", UR5_KQ, "--connection", "twist",
                                     "--wrench", "0,0,-50,0,1,0"]),
                       ("kx-zero", ["--robot", "ur5", "--q", ",".join(map(str, UR5_UP)),
                                    "--kq", UR5_KQ, "--wrench", "0,0,0"])):
        assert main(["kx", *argv, "--json"]) == 0
        (tmp_path / f"{name}.json").write_text(capsys.readouterr().out)
    summary = _strict_json((tmp_path / "scan-ur5" / "summary.json").read_text())
    ur5_scan = tmp_path / "scan-ur5"
    ur5_spec = ScanSpec.from_dict(_strict_json((ur5_scan / "manifest.json").read_text())["spec"])
    singular = int((~derive(ur5_spec, 0, dict(np.load(ur5_scan / "chunks" / "chunk-00000.npz")))
                    ["regular"][:, 0]).sum())
    assert singular == 5  # elbow = 0 (3 poses) or wrist_2 = 0 (3 poses), one shared
    assert summary["load_cases"]["1"]["k_x_undefined"] == singular
    flat = _strict_json((tmp_path / "scan-sk120" / "summary.json").read_text())
    assert flat["valid_configurations"] == flat["configurations"] - 1
    assert check_outputs(tmp_path) >= 14
