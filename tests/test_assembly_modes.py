"""Assembly modes along the loop-closing continuation, against a closed-form planar five-bar.

The five-bar: motors at A1 = (0, 0) and A2 = (D, 0) in the x-y plane, proximal links of length
A, distal links of length B = A, the two distal ends meeting at the point P (a "3D" loop pair).
With the motor angles given, P is one of the two intersections of the circles of radius B about
the elbows E1, E2; the assembly mode is the side of E1 -> E2 it lies on, the sign of
cross(E2 - E1, P - E1) (the sign of the passive Jacobian's determinant). Where the elbows
coincide (motor angles ``SINGULAR``) the two circles coincide: a singular pose where the modes
meet. A straight coordinate path that passes near it sees the mode's P swing round quickly (the
elbows swap sides); a path exactly through it goes straight on into the other mode, as the
SK120's parallelogram through its flat pose (q2 + q3 = -90 deg), and says so.
"""

from __future__ import annotations

import json

import numpy as np
import pinocchio as pin
import pytest

from stiffness.batch.loops import close_loops
from stiffness.calibration.poses import sample_coordinates
from stiffness.cli.main import main
from stiffness.errors import LoopClosureError
from stiffness.robot.robot import load_robot

D, A, B = 0.3, 0.46, 0.46
# motor angles (absolute, rad) where the elbows coincide, below the motors
_APEX = np.array([D / 2, -np.sqrt(A * A - D * D / 4)])
_THETA_SINGULAR = np.array([np.arctan2(_APEX[1], _APEX[0]),
                            np.arctan2(_APEX[1], _APEX[0] - D)])
# motor angles at zero coordinates: 0.35 rad from the singular pose, elbows apart
THETA0 = _THETA_SINGULAR + np.array([-0.35, 0.35])
SINGULAR = _THETA_SINGULAR - THETA0  # coordinates of the singular pose: (0.35, -0.35) rad
REFERENCE_MODE = -1  # P below the elbows at zero coordinates


def closed_form(coords: np.ndarray, mode: int) -> tuple[np.ndarray, np.ndarray]:
    """Elbows and P (absolute, in the plane, m) at motor coordinates ``coords`` (rad) in
    ``mode`` (+1: P on the left of E1 -> E2, -1 on its right)."""
    theta = THETA0 + coords
    e1 = A * np.array([np.cos(theta[0]), np.sin(theta[0])])
    e2 = np.array([D, 0.0]) + A * np.array([np.cos(theta[1]), np.sin(theta[1])])
    half = e2 - e1
    gap = float(np.linalg.norm(half)) / 2.0
    normal = np.array([-half[1], half[0]]) / (2.0 * gap)
    return np.stack([e1, e2]), (e1 + e2) / 2.0 + mode * np.sqrt(B * B - gap * gap) * normal


def elbow_values(coords: np.ndarray, mode: int) -> np.ndarray:
    """URDF values (rad) of elbow1 and elbow2 at ``coords`` in ``mode``."""
    elbows, p = closed_form(coords, mode)
    ref_elbows, ref_p = closed_form(np.zeros(2), REFERENCE_MODE)
    out = []
    for i in range(2):
        absolute = np.arctan2(*(p - elbows[i])[::-1]) - THETA0[i] - coords[i]
        zero = np.arctan2(*(ref_p - ref_elbows[i])[::-1]) - THETA0[i]
        out.append(absolute - zero)
    return np.array(out)


def _joint(name, parent, child, xyz=(0.0, 0.0), yaw=0.0, kind="revolute"):
    extra = ('<axis xyz="0 0 1"/><limit effort="10" velocity="2" lower="-6.3" upper="6.3"/>'
             if kind == "revolute" else "")
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/>'
            f'<child link="{child}"/><origin xyz="{xyz[0]!r} {xyz[1]!r} 0" '
            f'rpy="0 0 {float(yaw)!r}"/>{extra}</joint>')


@pytest.fixture(scope="module")
def five_bar(tmp_path_factory):
    """The five-bar as URDF + loop file, assembled at zero coordinates in REFERENCE_MODE."""
    elbows, p = closed_form(np.zeros(2), REFERENCE_MODE)
    distal = [np.arctan2(*(p - elbows[i])[::-1]) - THETA0[i] for i in range(2)]
    links = ["base", "prox1", "dist1", "end1", "prox2", "dist2", "end2", "tip"]
    joints = [
        _joint("mot1", "base", "prox1", yaw=THETA0[0]),
        _joint("elbow1", "prox1", "dist1", xyz=(A, 0.0), yaw=distal[0]),
        _joint("end1_joint", "dist1", "end1", xyz=(B, 0.0), kind="fixed"),
        _joint("mot2", "base", "prox2", xyz=(D, 0.0), yaw=THETA0[1]),
        _joint("elbow2", "prox2", "dist2", xyz=(A, 0.0), yaw=distal[1]),
        _joint("end2_joint", "dist2", "end2", xyz=(B, 0.0), kind="fixed"),
        _joint("tip_joint", "dist2", "tip", xyz=(1.15 * B, 0.0), kind="fixed"),
    ]
    folder = tmp_path_factory.mktemp("five_bar")
    urdf = folder / "five_bar.urdf"
    urdf.write_text('<?xml version="1.0"?>\n<robot name="five_bar">'
                    + "".join(f'<link name="{n}"/>' for n in links) + "".join(joints)
                    + "</robot>\n")
    (folder / "five_bar.loops.yaml").write_text(
        'closed_loop:\n  - [end1, end2]\ntype: ["3D"]\nname_mot: [mot1, mot2]\n')
    return urdf


def _mode_and_elbows(robot, q):
    elbows = np.array([robot.value_of(q, "elbow1"), robot.value_of(q, "elbow2")])
    coords = robot.coordinates_of(q)
    match = [m for m in (1, -1) if np.allclose(_wrap(elbow_values(coords, m) - elbows), 0.0,
                                               atol=1e-8)]
    assert len(match) == 1, "the closure is neither closed-form assembly"
    return match[0]


def _wrap(x):
    return (np.asarray(x) + np.pi) % (2.0 * np.pi) - np.pi


def _past_the_singular_pose(offset: float) -> np.ndarray:
    """Coordinates 6 % beyond the singular pose along the ray from zero, moved sideways by
    ``offset`` (rad), so that the straight path passes about ``offset`` from it."""
    ray = SINGULAR / np.linalg.norm(SINGULAR)
    return 1.06 * (SINGULAR + offset * np.array([-ray[1], ray[0]]))


def test_the_fixture_is_the_closed_form(five_bar):
    """At zero coordinates the loop closes in REFERENCE_MODE; the other mode is not it."""
    robot = load_robot(five_bar, frame="tip")
    q = robot.configuration(np.zeros(2))
    assert _mode_and_elbows(robot, q) == REFERENCE_MODE
    assert np.allclose(elbow_values(np.zeros(2), REFERENCE_MODE), 0.0, atol=1e-12)
    assert np.min(np.abs(_wrap(elbow_values(np.zeros(2), -REFERENCE_MODE)))) > 0.5


@pytest.mark.parametrize("offset", [1e-3, 1e-5])
def test_a_path_near_the_singular_pose_keeps_the_assembly_mode(five_bar, offset):
    """Passing 1e-3 or 1e-5 rad from the singular pose, the closure keeps the reference mode
    (it used to hop onto the other one, whose P is close to the straight-on guess) and says no
    singular pose was passed through."""
    robot = load_robot(five_bar, frame="tip")
    coords = _past_the_singular_pose(offset)
    assembly = robot.assemble(coords)
    assert _mode_and_elbows(robot, assembly.q) == REFERENCE_MODE
    assert assembly.singular_crossings == ()
    _, p_same = closed_form(coords, REFERENCE_MODE)
    _, p_other = closed_form(coords, -REFERENCE_MODE)
    assert p_same[1] > 0.0 > p_other[1]  # the reference mode's P swung above the motors


def test_a_path_through_the_singular_pose_goes_straight_on_and_says_so(five_bar):
    """Exactly through it (where the modes meet), the path goes straight on, as the SK120's
    parallelogram through its flat pose, into the other mode, and reports where."""
    robot = load_robot(five_bar, frame="tip")
    assembly = robot.assemble(_past_the_singular_pose(0.0))
    assert _mode_and_elbows(robot, assembly.q) == -REFERENCE_MODE
    (crossing,) = assembly.singular_crossings
    assert np.allclose(crossing, SINGULAR, atol=1e-7)
    assert assembly.as_dict()["singular_crossings"] == [list(crossing)]


def test_an_assembly_found_past_a_fold_says_its_mode_is_unchecked(five_bar):
    """The straight path to motors (-2.91, 2.18) rad meets a fold (the elbows more than 2 B
    apart on the way, not at the end); the assembly search finds an assembly there (here in
    the other mode) and says its mode is not checked (flag, JSON key, note)."""
    robot = load_robot(five_bar, frame="tip")
    coords = np.array([-2.9118, 2.1818])
    elbows = [closed_form(t * coords, REFERENCE_MODE)[0] for t in np.linspace(0.0, 1.0, 101)]
    gaps = np.array([np.linalg.norm(e[1] - e[0]) for e in elbows])
    assert gaps.max() > 2 * B > gaps[-1]  # out of reach on the way, in reach at the end
    assembly = robot.assemble(coords)
    assert assembly.assembly_search and not assembly.mode_checked
    assert assembly.as_dict()["mode_checked"] is False
    assert any("not checked to be in the reference assembly mode" in n
               for n in assembly.notes())
    assert _mode_and_elbows(robot, assembly.q) == -REFERENCE_MODE
    assert robot.assemble(_past_the_singular_pose(1e-3)).mode_checked
    # without the search (sample_coordinates refuses such a pose), the fold is an error
    with pytest.raises(LoopClosureError):
        robot.assemble(coords, search=False)
    assert robot.assemble(_past_the_singular_pose(1e-3), search=False).mode_checked


def test_batched_closures_keep_the_assembly_mode(five_bar):
    """close_loops on poses along a line passing 1e-4 rad from the singular pose: every key
    in the reference mode, at the closed form's elbow angles (3 of the 6 were in the other mode
    before the mode checks, 2 with the continuation's check alone)."""
    robot = load_robot(five_bar, frame="tip")
    grid = SINGULAR + np.outer(np.linspace(-0.05, 0.05, 6), [1.0, 1.0002]) + 1e-4
    out = close_loops(robot, grid)
    assert out.closed.all()
    for q in out.q:
        assert _mode_and_elbows(robot, q) == REFERENCE_MODE


def test_sk120_goes_straight_through_its_flat_parallelogram(sk120):
    """The SK120's path from zero to q2 + q3 = -120 deg passes the flat parallelogram
    (q2 + q3 = -90 deg, three quarters of the way): reported there, and the forearm keeps the
    orientation q3 gives it (the parallelogram stays a parallelogram), as at q2 + q3 = -70 deg,
    which no flat pose separates from zero."""
    forearm = sk120.model.getFrameId("forearm")
    rotations = []
    for q2, crossings in ((30.0, 1), (80.0, 0)):
        coords = np.deg2rad([10.0, q2, -150.0, 0.0, 0.0, 0.0])
        assembly = sk120.assemble(coords)
        assert len(assembly.singular_crossings) == crossings
        if crossings:
            assert np.allclose(assembly.singular_crossings[0], 0.75 * coords, atol=1e-8)
        pin.framesForwardKinematics(sk120.model, sk120.data, assembly.q)
        rotations.append(sk120.data.oMf[forearm].rotation.copy())
    assert np.allclose(rotations[0], rotations[1], atol=1e-10)


def _sk120_args(q2_deg: float) -> list[str]:
    coords = np.deg2rad([10.0, q2_deg, -150.0, 0.0, 0.0, 0.0])
    return ["kx", "--robot", "sk120", "--q", ",".join(repr(float(v)) for v in coords)]


def test_kx_reports_the_flat_parallelogram_it_went_through(capsys):
    """`kx --q` beyond the SK120's flat parallelogram (q2 + q3 = -120 deg): the JSON
    closure's singular_crossings and a note; short of it (-70 deg), none."""
    for q2, crossings in ((30.0, [[0.1309, 0.392699, -1.963495, 0.0, 0.0, 0.0]]), (80.0, [])):
        assert main([*_sk120_args(q2), "--json"]) == 0
        closure = json.loads(capsys.readouterr().out)["closure"]
        assert np.allclose(np.reshape(closure["singular_crossings"], (-1, 6)),
                           np.reshape(crossings, (-1, 6)), atol=1e-6)
    assert main(_sk120_args(30.0)) == 0
    assert ("note: closing the loops from the reference assembly went through a singular pose "
            "of the loops at coordinates [0.1309, 0.392699, -1.963495, 0.0, 0.0, 0.0]"
            ) in capsys.readouterr().out


def test_design_draws_its_poses_in_the_reference_mode(five_bar, tmp_path):
    """Poses drawn over motors within ±100 deg (a robot.toml [workspace] beside the URDF): every
    one closes in the reference mode (1 of these 20 was in the other one before)."""
    for name in ("five_bar.urdf", "five_bar.loops.yaml"):
        (tmp_path / name).write_text((five_bar.parent / name).read_text())
    (tmp_path / "robot.toml").write_text(
        'urdf = "five_bar.urdf"\nframe = "tip"\n[workspace]\nangle_unit = "deg"\n'
        "uniform = { mot1 = [-100.0, 100.0], mot2 = [-100.0, 100.0] }\n"
        "target_above_base = false\n")
    robot = load_robot(tmp_path / "robot.toml")
    for coords in sample_coordinates(robot, 20, np.random.default_rng(0)):
        assembly = robot.assemble(coords)
        assert assembly.mode_checked
        assert _mode_and_elbows(robot, assembly.q) == REFERENCE_MODE
