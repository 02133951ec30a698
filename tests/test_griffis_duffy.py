"""The Griffis-Duffy coupling of Zefran & Kumar section 5, through the URDF + loop path.

``load_robot("griffis-duffy")`` (robots/griffis-duffy: URDF, loop declaration, robot.toml)
closes the six leg loops; the platform's closed-loop Jacobian, the holding wrench and K_C^tw
come from Pinocchio through stiffness.mechanics.formulation. The printed J^-1, K_j and K_a are
compared to
their last printed digit (half a unit: 0.005 for J^-1, 0.05 for K_j and K_a), converted at this
boundary from SI to the paper's cm and N/cm:

* rows and columns ordered [w; v] (the paper) from Pinocchio's [v; w];
* J^-1 (leg-length rate per basis twist): angular columns m/rad -> cm/rad (x100), linear
  columns m/m (unchanged);
* K_j, K_a: [w, w] block N.m/rad -> N.cm/rad (x100); [w, v] and [v, w] blocks N (unchanged);
  [v, v] block N/m -> N/cm (x0.01).
"""

from __future__ import annotations

import json

import numpy as np
import pinocchio as pin
import pytest

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

from stiffness.cli.main import main
from stiffness.mechanics.formulation import joint_stiffness, target_state
from stiffness.mechanics.platform import lie_bracket_term, platform_stiffness, solve_pose
from stiffness.mechanics.wrench import holding_wrench, reorder_twist
from stiffness.robot.robot import load_robot
from stiffness.robot.sources import robots_directory

FOLDER = robots_directory() / "griffis-duffy"
PAPER = tomllib.loads((FOLDER / "zefran-kumar-section5.toml").read_text())
HALF_J, HALF_K = 0.005, 0.05
#: SI -> paper units for a [w; v]-ordered 6x6 stiffness.
K_TO_PAPER = np.block([[np.full((3, 3), 100.0), np.ones((3, 3))],
                       [np.ones((3, 3)), np.full((3, 3), 0.01)]])


def k_paper(k_si: np.ndarray) -> np.ndarray:
    """A Pinocchio-ordered SI 6x6 stiffness in the paper's order and units."""
    return reorder_twist(k_si, "w-v") * K_TO_PAPER


@pytest.fixture(scope="module")
def gd():
    return load_robot("griffis-duffy")


@pytest.fixture(scope="module")
def shipped(gd):
    """Closed configuration, springs, and both stiffnesses under the holding wrench."""
    q = gd.configuration(np.array(gd.defaults["q_SI"]))
    k = joint_stiffness(gd.defaults["k_theta_SI"], 6)
    return q, k, platform_stiffness(gd, q, k, rest=gd.defaults["rest_q_SI"])


def test_shipped_robot(gd, shipped):
    q, _, _ = shipped
    assert gd.coordinate_joints == gd.compliant_joints == tuple(f"leg{i}" for i in range(1, 7))
    assert len(gd.loop.passive_joints) == 18 and gd.loop.n_rows == 18
    pin.framesForwardKinematics(gd.model, gd.data, q)
    platform = gd.data.oMf[gd.target_frame_id]
    # the platform frame coincides with the fixed frame at O
    np.testing.assert_allclose(platform.translation, 0.0, atol=1e-12)
    np.testing.assert_allclose(platform.rotation, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(gd.coordinates_of(q), gd.defaults["q_SI"], atol=1e-12)
    # the leg tips sit on the printed anchors s, s, t, t, r, r (cm, rounded to 0.1)
    tips = [gd.data.oMf[gd.model.getFrameId(f"leg{i}_tip")].translation for i in range(1, 7)]
    printed = PAPER["points_printed_cm"]
    for tip, name in zip(tips, ["s", "s", "t", "t", "r", "r"], strict=True):
        np.testing.assert_allclose(tip * 100.0, printed[name], atol=0.05)


def test_inverse_jacobian_reproduces_the_paper(shipped):
    """Leg-length rates per basis twist (rows legs, columns [w; v]) to 0.005."""
    _, _, ps = shipped
    j_inv = np.linalg.inv(ps.state.body_jacobian())[:, [3, 4, 5, 0, 1, 2]]
    j_inv_paper = j_inv * np.array([100.0] * 3 + [1.0] * 3)
    assert np.abs(j_inv_paper - PAPER["J_inv"]).max() <= HALF_J


def test_joint_connection_reproduces_the_paper(shipped):
    _, _, ps = shipped
    dev = np.abs(k_paper(ps.k_joint) - PAPER["K_j"]).max()
    assert dev <= HALF_K
    np.testing.assert_allclose(ps.k_joint, ps.k_joint.T, atol=1e-9)


def test_twist_basis_reproduces_the_paper(shipped):
    _, _, ps = shipped
    dev = np.abs(k_paper(ps.k_twist) - PAPER["K_a"]).max()
    assert dev <= HALF_K
    # and it is not the joint connection: the load matters at the printed precision
    assert np.abs(k_paper(ps.k_twist) - PAPER["K_j"]).max() > 100.0


def test_holding_wrench_balances_the_springs(gd, shipped):
    """J^T W = K (q - l): W holds the platform; the springs' wrench is -W."""
    q, k, ps = shipped
    tau = k @ (np.array(gd.defaults["q_SI"]) - np.array(gd.defaults["rest_q_SI"]))
    np.testing.assert_allclose(ps.state.jacobian.T @ ps.state.wrench, tau, atol=1e-10)
    np.testing.assert_allclose(ps.wrench_body, ps.state.wrench, atol=1e-12)  # R = I here
    # legs 1-4 and 6 are stretched (pull the platform in), leg 5 (Q-r, 13.8 < 15 cm) pushes
    assert np.sign(tau).tolist() == [1, 1, 1, 1, -1, 1]


def _potential(gd, k, rest, q):
    lengths = gd.coordinates_of(q)
    return 0.5 * float((lengths - rest) @ k @ (lengths - rest))


def test_twist_basis_is_the_second_derivative_along_basis_twists(gd, shipped):
    """Eq. 29-30 by finite differences through the loop path: W_i = L_i(Phi) (holding wrench,
    body components; the springs' wrench is -L_i Phi) and K_a[i, j] = L_j L_i Phi, Phi the
    springs' energy at the leg lengths that put the platform at A0 exp(s L_j) exp(t L_i)."""
    q0, k, ps = shipped
    rest = np.array(gd.defaults["rest_q_SI"])
    a0 = pin.SE3.Identity()
    cache: dict = {}

    def phi(s, j, t, i):
        key = (round(s, 12), j, round(t, 12), i)
        if key not in cache:
            pose = a0 * pin.exp6(s * np.eye(6)[j]) * pin.exp6(t * np.eye(6)[i])
            cache[key] = _potential(gd, k, rest, solve_pose(gd, pose, q0))
        return cache[key]

    h = 1e-4
    grad = np.array([(phi(h, i, 0.0, 0) - phi(-h, i, 0.0, 0)) / (2 * h) for i in range(6)])
    np.testing.assert_allclose(grad, ps.wrench_body, rtol=1e-6, atol=1e-6)
    h = 1e-3
    k_fd = np.array([[(phi(h, j, h, i) - phi(h, j, -h, i) - phi(-h, j, h, i)
                       + phi(-h, j, -h, i)) / (4 * h * h) for j in range(6)] for i in range(6)])
    np.testing.assert_allclose(k_fd, ps.k_twist, rtol=0, atol=2e-4 * np.abs(ps.k_twist).max())


def test_asymmetry_is_the_lie_bracket_of_the_wrench(shipped):
    """Eq. 34: K_a - K_a^T = [L_j, L_i] Phi, computed from the holding wrench; the printed K_a
    satisfies it to its rounding too."""
    _, _, ps = shipped
    bracket = lie_bracket_term(ps.wrench_body)
    np.testing.assert_allclose(ps.k_twist - ps.k_twist.T, bracket, atol=1e-9)
    printed = np.array(PAPER["K_a"])
    assert np.abs(printed - printed.T - k_paper(bracket)).max() <= 2 * HALF_K
    # K_a - K_j is the load term J^-T K_C^tw J^-1, fixed by the wrench
    jinv = np.linalg.inv(ps.state.body_jacobian())
    np.testing.assert_allclose(ps.k_joint - ps.k_twist, jinv.T @ ps.state.k_c_twist @ jinv,
                               atol=1e-9)


@pytest.mark.parametrize("where", ["shipped", "elsewhere"])
def test_unloaded_twist_basis_is_symmetric_and_equals_joint(gd, shipped, where):
    """At a stationary configuration (springs at rest: no wrench) K_a = K_j, symmetric."""
    q, k, _ = shipped
    if where == "elsewhere":
        goal = pin.SE3(pin.exp3(np.array([0.1, -0.05, 0.2])), np.array([0.01, -0.01, 0.02]))
        q = solve_pose(gd, goal, q)
    rest = gd.coordinates_of(q)
    ps = platform_stiffness(gd, q, k, rest=rest)
    np.testing.assert_allclose(ps.state.wrench, 0.0, atol=1e-12)
    np.testing.assert_allclose(ps.k_twist, ps.k_joint, atol=1e-9 * np.abs(ps.k_joint).max())
    np.testing.assert_allclose(ps.k_twist, ps.k_twist.T, atol=1e-9 * np.abs(ps.k_joint).max())


def test_holding_wrench_needs_one_rest_value_per_spring(gd, shipped):
    q, k, _ = shipped
    from stiffness.errors import StiffnessError

    with pytest.raises(StiffnessError, match="one finite rest value per compliant joint"):
        holding_wrench(gd, q, k, [0.1, 0.2])


def _kx(capsys, *flags):
    assert main(["kx", "--robot", "griffis-duffy", *flags, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


@pytest.mark.parametrize(("connection", "printed"), [("joint", "K_j"), ("twist", "K_a")])
def test_kx_command(capsys, connection, printed):
    """`stiffness kx --robot griffis-duffy --connection joint|twist --json`: K_X in SI, rows
    [w; v] as `basis` says, the holding wrench [M; F]."""
    out = _kx(capsys, "--connection", connection)
    assert out["basis"] == ["wx", "wy", "wz", "vx", "vy", "vz"]
    assert out["wrench_basis"] == ["mx", "my", "mz", "fx", "fy", "fz"]
    k_x = np.array(out["K_X"])
    assert np.abs(k_x * K_TO_PAPER - PAPER[printed]).max() <= HALF_K
    assert out["load_source"].startswith("rest_q_SI")
    wrench = np.array(out["wrench"])
    assert wrench[3:].tolist() == pytest.approx([304.6531, 59.2843, 505.9630], abs=1e-3)
    assert out["K_X_symmetric"] == (connection == "joint")


def test_kx_flags_override_the_shipped_defaults(capsys, gd):
    """--twist-order v-w reorders; --wrench 0 makes K_a = K_j; --kq changes the springs."""
    joint = np.array(_kx(capsys, "--connection", "joint")["K_X"])
    out = _kx(capsys, "--connection", "twist", "--twist-order", "v-w")
    assert out["basis"] == ["vx", "vy", "vz", "wx", "wy", "wz"]
    np.testing.assert_allclose(reorder_twist(np.array(out["K_X"]), "w-v") * K_TO_PAPER,
                               PAPER["K_a"], atol=HALF_K)
    unloaded = _kx(capsys, "--connection", "twist", "--wrench", "0,0,0,0,0,0")
    np.testing.assert_allclose(unloaded["K_X"], joint, atol=1e-9)
    doubled = _kx(capsys, "--connection", "joint", "--kq", "2000,4000,6000,8000,10000,12000")
    np.testing.assert_allclose(doubled["K_X"], 2 * joint, rtol=1e-12)
    q = gd.configuration(np.array(gd.defaults["q_SI"]))
    np.testing.assert_allclose(target_state(gd, q).position, 0.0, atol=1e-12)
