"""Scan summaries that say what they cover (issue 30, items 3 and 6): principal stiffness
ranges leave out the configurations near a singularity and those the load buckles, and count
them; a 6-D K_X is summarised per block (N/m and N.m/rad).

The expected numbers are computed pose by pose with the single-configuration functions and
NumPy (SVD of J, eigenvalues of K_theta - K_C and of C^-1), not with the batched kernels.
"""

from __future__ import annotations

import numpy as np
import pytest

from stiffness.mechanics.formulation import target_state
from stiffness.robot.robot import load_robot
from stiffness.workspace.engine import load_scan
from stiffness.workspace.maps import SINGULARITY_MARGIN
from stiffness.workspace.request import scan

KQ = np.array([3e5, 3e5, 2e5, 4e4, 4e4, 4e4])
#: Grid (rad): the elbow from 0.5 deg (almost stretched) to 150.5 deg.
AXES = {"shoulder_lift_joint": (-np.pi / 2, 0.0, np.pi / 12),
        "elbow_joint": (np.deg2rad(0.5), np.deg2rad(150.5), np.pi / 12)}


def expected(robot, coords: np.ndarray, wrench: np.ndarray, kq: np.ndarray) -> dict:
    """Counts and ranges of the summary, pose by pose."""
    rows = 3 if wrench.shape[0] == 3 else 6
    near = unstable = 0
    trans, rot = [], []
    for c in coords:
        state = target_state(robot, robot.configuration(c), wrench)
        s = np.linalg.svd(state.jacobian[:3], compute_uv=False)
        is_near = s[-1] / s[0] < SINGULARITY_MARGIN
        tangent = np.diag(kq) - state.k_c
        is_unstable = np.linalg.eigvalsh(0.5 * (tangent + tangent.T))[0] <= 0
        near += is_near
        unstable += is_unstable
        if is_near or is_unstable:
            continue
        jac = state.jacobian[:rows]
        k_x = np.linalg.inv(jac @ np.linalg.solve(tangent, jac.T))
        trans.append(np.linalg.eigvalsh(0.5 * (k_x[:3, :3] + k_x[:3, :3].T)))
        if rows == 6:
            rot.append(np.linalg.eigvalsh(0.5 * (k_x[3:, 3:] + k_x[3:, 3:].T)))
    out = {"near": near, "unstable": unstable, "min": min(t[0] for t in trans),
           "max": max(t[-1] for t in trans)}
    if rot:
        out.update(rot_min=min(r[0] for r in rot), rot_max=max(r[-1] for r in rot))
    return out


@pytest.mark.parametrize("wrench,springs", [([0.0, 0.0, -4e5], 3),
                                            ([0.0, 0.0, -200.0, 0.0, 0.0, 1.0], 6)])
def test_ranges_leave_out_near_singular_and_unstable_configurations(tmp_path, wrench, springs):
    """Three springs (the arm's, the target at wrist 1: the elbow at 0.5 deg is near-singular)
    under a force that buckles the upright poses; six springs under a wrench (block ranges)."""
    joints = load_robot("ur5").coordinate_joints[:springs]
    robot = load_robot("ur5", frame="wrist_1_link" if springs == 3 else None,
                       compliant_joints=joints)
    kq = KQ[:springs]
    base = np.array([0.0, 0.0, 0.0, 0.0, np.pi / 3, 0.0])  # wrist 2 clear of its singularity
    result = scan(robot, tmp_path / "s", k_theta=kq, axes=AXES, q=base, wrench=wrench,
                  plots=False)
    summary = result.to_dict()
    coords = load_scan(tmp_path / "s")["coordinates"]
    want = expected(robot, coords, np.array(wrench), kq)
    case = summary["load_cases"]["1"]
    assert summary["near_singular"] == want["near"]
    assert want["near"] > 0 or springs == 6
    assert summary["singularity_margin"] == SINGULARITY_MARGIN
    assert case["unstable"] == want["unstable"]
    assert case["min_principal_stiffness_N_per_m"] == pytest.approx(want["min"], rel=1e-6)
    assert case["max_principal_stiffness_N_per_m"] == pytest.approx(want["max"], rel=1e-6)
    if len(wrench) == 6:
        assert case["min_rotational_stiffness_Nm_per_rad"] == pytest.approx(want["rot_min"],
                                                                            rel=1e-6)
        assert case["max_rotational_stiffness_Nm_per_rad"] == pytest.approx(want["rot_max"],
                                                                            rel=1e-6)
    else:
        assert want["unstable"] > 0  # 4e5 N buckles the upright poses (critical 2.5e5 N)



PLANAR_3R = """<robot name="planar3r"><link name="base"/><link name="l1"/><link name="l2"/>
<link name="l3"/><link name="tip"/>
<joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/>
 <limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
<joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0.4 0 0"/>
 <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
<joint name="j3" type="revolute"><parent link="l2"/><child link="l3"/><origin xyz="0.3 0 0"/>
 <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
<joint name="t" type="fixed"><parent link="l3"/><child link="tip"/><origin xyz="0.2 0 0"/>
</joint></robot>"""


def test_a_robot_spanning_fewer_than_three_directions_everywhere_is_named_as_such(tmp_path,
                                                                                  capsys):
    """A planar arm of three springs (as Gepetto's 5-bar and planar delta): its target
    Jacobian has rank 2 at every configuration (checked here pose by pose), so K_X exists
    nowhere. The summary said 'left out of the K_X ranges: 12 of 12 ... near a singularity'
    and 'undefined ... a kinematic singularity, fewer compliant joints than directions, or the
    buckling limit'; now one line names the reason and where the subspace stiffness is."""
    from stiffness.cli.main import main

    (tmp_path / "planar3r.urdf").write_text(PLANAR_3R)
    robot = load_robot(tmp_path / "planar3r.urdf")
    assert main(["scan", "--robot", str(tmp_path / "planar3r.urdf"), "--kq", "1e3,1e3,1e3",
                 "--samples", "12", "--load", "0,-5,0", "--out", str(tmp_path / "s"),
                 "--no-plots", "--quiet"]) == 0
    lines = capsys.readouterr().out.splitlines()
    coords = load_scan(tmp_path / "s")["coordinates"]
    assert len(coords) == 12
    for c in coords:
        s = np.linalg.svd(target_state(robot, robot.configuration(c)).jacobian[:3],
                          compute_uv=False)
        assert s[2] < 1e-12 * s[0] and s[1] > 1e-3 * s[0]
    assert lines[-1] == (
        "K_X: undefined at all 12 valid configurations: the target moves in fewer than 3 "
        "directions at every one (a planar robot, or fewer than 3 compliant joints), so its 3x3 "
        "compliance is singular everywhere; `stiffness kx --q ...` gives the stiffness on the "
        "subspace it spans at one pose")
    assert not [line for line in lines if "left out of the K_X ranges" in line]


def test_sampled_scan_of_a_closed_loop_draws_near_its_reference_assembly(tmp_path):
    """A closed loop's limits say little about where it assembles (Gepetto's legs have none:
    +-pi): `scan --samples` drew there, and Cassie's leg left 13 of 30 samples unassembled after
    1 min 57 s. Now it draws as `design` does, within 0.5 rad of the reference assembly
    (13 s, 1 of 30): the SK120's samples all lie there and all assemble."""
    from stiffness.mechanics.defaults import default_coordinates
    from stiffness.workspace.request import swept_axes

    robot = load_robot("sk120")
    ref = default_coordinates(robot)
    axes = swept_axes(robot, {}, grid=False)
    lower, upper = robot.model.lowerPositionLimit, robot.model.upperPositionLimit
    for a in axes:
        jid = robot.model.getJointId(a["joint"])
        lim = (lower[robot.model.joints[jid].idx_q], upper[robot.model.joints[jid].idx_q])
        assert a["lower"] == pytest.approx(max(lim[0], ref[a["index"]] - 0.5), abs=1e-12)
        assert a["upper"] == pytest.approx(min(lim[1], ref[a["index"]] + 0.5), abs=1e-12)
    scan(robot, tmp_path / "s", samples=6, wrench=[0.0, 0.0, -100.0])
    maps = load_scan(tmp_path / "s")
    assert np.abs(maps["coordinates"] - ref).max() <= 0.5 + 1e-12 and maps["valid"].all()


def test_view_field_of_a_closed_loop_draws_near_its_reference_assembly():
    """`view --field N` drew a closed loop's samples over +-180 deg too: Cassie's leg kept 14
    of 20 after 10.3 s of closures, 19 of 20 in 0.9 s within 0.5 rad of the reference; the
    coordinates not varied keep the base values."""
    from stiffness.mechanics.defaults import default_coordinates
    from stiffness.viewer.layout import random_coordinates

    robot = load_robot("sk120")
    ref = default_coordinates(robot)
    rows = random_coordinates(robot, 40, ref, None, 0)
    assert np.abs(rows - ref).max() <= 0.5 + 1e-12 and np.abs(rows - ref).max() > 0.4
    some = random_coordinates(robot, 5, ref, [robot.coordinate_joints[1]], 0)
    assert np.array_equal(np.delete(some, 1, axis=1), np.delete(np.tile(ref, (5, 1)), 1, axis=1))
