"""No traceback, ever: ``posture``, ``compensate``, ``kx`` and ``view --export`` on random seeds,
poses and loads of five example-robot-data arms end in exit 0, or in exit 2 with one error line;
so do ``kx``, ``view --export`` and ``simulate`` given any flag value (NaN, infinities, 1e308,
1e-308, zero, negative, text: issue 38 item 7, where ``--kq 1e308`` ended in ``LinAlgError``).

Also the case that used to end in ``numpy.linalg.LinAlgError: Singular matrix`` (the Panda's
damped IK step with the damping shrunk to ~1e-12 and the seed on joint 4's limit), and the
damped step itself against its normal-equations form.
"""

from __future__ import annotations

import contextlib
import io
import math
import tempfile
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from fuzzing import LONG
from hypothesis import given, settings
from hypothesis import strategies as st

from stiffness.cli.flags import number, parse_list
from stiffness.cli.main import main
from stiffness.errors import StiffnessError
from stiffness.mechanics.ik import coordinate_limits, damped_step, inside_limits, solve_ik
from stiffness.robot.robot import load_robot

#: Five example-robot-data arms that load in a few ms, and the joints of their arm (springs).
ARMS = {
    "ur5": ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
            "wrist_2_joint", "wrist_3_joint"],
    "panda": [f"panda_joint{i}" for i in range(1, 8)],
    "xarm7": [f"joint{i}" for i in range(1, 8)],
    "z1": [f"joint{i}" for i in range(1, 7)],
    "kinova": [f"j2s6s200_joint_{i}" for i in range(1, 7)],
}
#: Examples per command: each runs a whole command (about 0.1-6 s), so 8 in CI's time budget;
#: 300 under the ``long`` profile (about 50 min for all five tests: tests/conftest.py).
FEW = settings(max_examples=300 if LONG else 8, deadline=None)
#: Flag values: a dozen commands per test in CI, 300 under the ``long`` profile (about 2 min).
FLAG_VALUES = settings(max_examples=300 if LONG else 12, deadline=None)
#: Numbers that break naive flag readers, written as a user would.
NASTY_NUMBERS = ["nan", "inf", "-inf", "1e308", "-1e308", "1e309", "1e-308", "0", "-0", "-1",
                 "1e12", "-1e12", "1e13", "1e-12", "abc", "", "0x10", "1e6"]
number_text = st.one_of(st.sampled_from(NASTY_NUMBERS),
                        st.floats(allow_nan=True, allow_infinity=True).map(repr))


def run_cli(argv: list[str]) -> tuple[int, str]:
    """Exit status and stderr of ``stiffness ARGV`` run in this process."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = main(argv)
        except SystemExit as exc:  # a usage error: argparse's one line and exit 2
            code = exc.code if isinstance(exc.code, int) else 2
    return code, err.getvalue()


def assert_clean_exit(code: int, stderr: str) -> None:
    """Exit 0, or exit 2 with one error line; never a traceback."""
    assert "Traceback" not in stderr, stderr
    errors = [line for line in stderr.splitlines() if ": error:" in line]
    if code == 0:
        assert not errors, stderr
        return
    assert code == 2, (code, stderr)
    assert len(errors) == 1, stderr
    others = [line for line in stderr.splitlines()
              if line.strip() and ": error:" not in line and ": warning:" not in line]
    assert not others, stderr


def robot_flags(name: str, rng: np.random.Generator) -> list[str]:
    """``--robot``, the arm's springs and random stiffnesses (N.m/rad) over four decades."""
    kq = 10 ** rng.uniform(2, 6, size=len(ARMS[name]))
    return ["--robot", name, "--compliant-joints", ",".join(ARMS[name]),
            "--kq", ",".join(f"{k:.6g}" for k in kq)]


def random_coordinates(name: str, rng: np.random.Generator, rows: int) -> np.ndarray:
    """``rows`` coordinate vectors (rad, m), mostly inside the limits, some beyond them."""
    robot = load_robot(name)
    lo, hi = coordinate_limits(robot)
    lo, hi = np.maximum(lo, -np.pi), np.minimum(hi, np.pi)
    span = hi - lo
    return rng.uniform(lo - 0.01 * span, hi + 0.01 * span, size=(rows, robot.n_coordinates))


def random_wrench(rng: np.random.Generator) -> str:
    """A force (N) of random direction and a magnitude from 1e-3 to 1e9 N."""
    force = rng.normal(size=3)
    force *= 10 ** rng.uniform(-3, 9) / np.linalg.norm(force)
    return ",".join(f"{f:.6g}" for f in force)


def random_poses(name: str, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Two target positions (m) and tool axes: mostly a reachable pose (forward kinematics of
    random coordinates) and one near it, sometimes points anywhere in a 1.6 m box."""
    if rng.random() < 0.25:
        return rng.uniform([-0.8, -0.8, -0.2], [0.8, 0.8, 1.0], size=(2, 3)), \
            rng.normal(size=(2, 3))
    robot = load_robot(name)
    q = robot.configuration(random_coordinates(name, rng, 1)[0])
    pin.framesForwardKinematics(robot.model, robot.data, q)
    placement = robot.data.oMf[robot.target_frame_id]
    start, axis = placement.translation, placement.rotation[:, 2]
    return np.array([start, start + rng.normal(scale=0.02, size=3)]), np.array([axis, axis])


cases = st.tuples(st.sampled_from(sorted(ARMS)), st.integers(0, 2 ** 32 - 1))


@FEW
@given(cases)
def test_kx_never_a_traceback(case):
    name, seed = case
    rng = np.random.default_rng(seed)
    q = random_coordinates(name, rng, 1)[0]
    argv = ["kx", *robot_flags(name, rng), "--q", ",".join(f"{v:.6g}" for v in q),
            "--wrench", random_wrench(rng)]
    assert_clean_exit(*run_cli(argv))


#: Valid values of the list flags on the UR5 (one of their items is replaced).
VALID = {"--kq": ["1e4"] * 6, "--wrench": ["0", "0", "-10"],
         "--q": ["0.1", "-1.2", "1.4", "-0.5", "1.2", "0.3"], "--target-offset": ["0", "0", "0.1"]}


def flag_argv(command: str, flag: str, item: int, value: str, folder: str) -> list[str]:
    """``command`` on the UR5 with valid flags but ``flag``'s ``item`` set to ``value``."""
    if command == "simulate":
        return ["simulate", "--robot", "ur5", "--compliant-joints", ",".join(ARMS["ur5"][:3]),
                "--kq", "1e4,1e4,1e4", "--configs", "2", "--loads-per-config", "1", "--quiet",
                "--out", str(Path(folder) / "sim"), f"{flag}={value}"]
    values = {k: list(v) for k, v in VALID.items()}
    values[flag][item % len(values[flag])] = value
    argv = [command, "--robot", "ur5", "--compliant-joints", ",".join(ARMS["ur5"])]
    for name, items in values.items():
        argv.append(f"{name}={','.join(items)}")
    return argv + (["--export", str(Path(folder) / "v.html")] if command == "view" else [])


@pytest.mark.parametrize(("command", "flag", "value"), [
    ("view", "--kq", "1e308"), ("kx", "--kq", "1e308"), ("kx", "--wrench", "1e308"),
    ("view", "--q", "1e300"), ("simulate", "--noise", "nan"), ("simulate", "--max-force", "1e308"),
])
def test_flag_values_of_the_issue_end_in_one_line(command, flag, value, tmp_path):
    """The values that ended in LinAlgError or a blamed singularity (issue 38 item 7)."""
    code, err = run_cli(flag_argv(command, flag, 0, value, str(tmp_path)))
    assert code == 2 and ("beyond +-1e+12" in err or "finite" in err), err
    assert_clean_exit(code, err)


def test_minus_zero_is_zero(tmp_path):
    """``--noise -0`` (found by the long profile): NumPy refuses a normal scale of -0.0 with a
    ValueError, so the flag readers give +0.0; simulate then runs noise-free."""
    assert math.copysign(1.0, number("-0")) == 1.0
    assert [math.copysign(1.0, v) for v in parse_list("-0,0", "--wrench")] == [1.0, 1.0]
    code, err = run_cli(flag_argv("simulate", "--noise", 0, "-0", str(tmp_path)))
    assert code == 0, err


@FLAG_VALUES
@given(st.sampled_from(["kx", "view", "simulate"]), st.sampled_from(sorted(VALID)),
       st.integers(0, 5), number_text,
       st.sampled_from(["--noise", "--max-force", "--rotation-noise"]))
def test_any_flag_value_never_a_traceback(command, flag, item, value, one_number_flag):
    """kx and view --export with any item of --kq, --wrench, --q or --target-offset, and
    simulate with any one-number flag: exit 0 or one error line."""
    with tempfile.TemporaryDirectory() as folder:
        argv = flag_argv(command, one_number_flag if command == "simulate" else flag, item,
                         value, folder)
        assert_clean_exit(*run_cli(argv))


@FEW
@given(cases)
def test_view_export_never_a_traceback(case):
    name, seed = case
    rng = np.random.default_rng(seed)
    q = random_coordinates(name, rng, 1)[0]
    with tempfile.TemporaryDirectory() as folder:
        argv = ["view", *robot_flags(name, rng), "--q", ",".join(f"{v:.6g}" for v in q),
                "--wrench", random_wrench(rng), "--export", str(Path(folder) / "v.html")]
        assert_clean_exit(*run_cli(argv))


@FEW
@given(cases)
def test_compensate_never_a_traceback(case):
    name, seed = case
    rng = np.random.default_rng(seed)
    robot = load_robot(name)
    coords = random_coordinates(name, rng, 3)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "path.csv"
        rows = [",".join(robot.coordinate_joints)]
        rows += [",".join(f"{v:.6g}" for v in row) for row in coords]
        path.write_text("\n".join(rows) + "\n")
        argv = ["compensate", *robot_flags(name, rng), "--path", str(path),
                "--wrench", random_wrench(rng), "--out", str(Path(folder) / "out.csv")]
        assert_clean_exit(*run_cli(argv))


@FEW
@given(cases)
def test_posture_never_a_traceback(case):
    name, seed = case
    rng = np.random.default_rng(seed)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "poses.csv"
        points, axes = random_poses(name, rng)
        rows = ["x,y,z,ax,ay,az"] + [",".join(f"{v:.6g}" for v in (*p, *a))
                                     for p, a in zip(points, axes, strict=True)]
        path.write_text("\n".join(rows) + "\n")
        argv = ["posture", *robot_flags(name, rng), "--path", str(path), "--steps", "8",
                "--wrench", random_wrench(rng), "--out", str(Path(folder) / "out.csv")]
        assert_clean_exit(*run_cli(argv))


def test_panda_posture_that_met_a_singular_ik_step(tmp_path):
    """The issue's case: a Panda pose whose IK from the zero seed (joint 4 beyond its limit,
    clipped onto it) shrank the damping until ``J J^T + lambda^2 I`` was singular."""
    path = tmp_path / "poses.csv"
    path.write_text("x,y,z,ax,ay,az\n"
                    "-0.68299486,0.29819108,0.66010082,-0.50374439,-0.70378346,0.50092957\n"
                    "-0.62663592,-0.66757426,0.48775658,-0.75929178,0.48958937,0.42869365\n")
    for extra in ([], ["--json"]):
        code, stderr = run_cli(["posture", "--robot", "panda", "--compliant-joints",
                                ",".join(ARMS["panda"]), "--kq", "1e4,1e4,1e4,1e4,1e3,1e3,1e3",
                                "--path", str(path), "--wrench", "0,0,-50",
                                "--out", str(tmp_path / "p.csv"), *extra])
        assert_clean_exit(code, stderr)
        # the second point is 0.93 m from the shoulder, beyond the Panda's 0.855 m reach
        assert code == 2 and "row 2" in stderr, stderr


def test_ik_from_a_seed_on_a_limit_raises_only_typed_errors():
    """Seeds on the limits (every joint on one of its two), poses in reach (forward kinematics
    of random coordinates inside the limits) and out of it (beyond the 0.855 m reach): a
    result within the limits or a StiffnessError, never another exception."""
    robot = load_robot("panda")
    lo, hi = coordinate_limits(robot)
    rng = np.random.default_rng(0)
    solved = reachable = 0
    for trial in range(40):
        seed = np.where(rng.random(robot.n_coordinates) < 0.5, lo, hi)
        if trial % 2:
            q = robot.configuration(rng.uniform(lo, hi))
            pin.framesForwardKinematics(robot.model, robot.data, q)
            placement = robot.data.oMf[robot.target_frame_id]
            target, rotation = placement.translation.copy(), placement.rotation.copy()
            reachable += 1
        else:
            direction = rng.normal(size=3)
            target = 1.5 * direction / np.linalg.norm(direction)
            rotation = pin.exp3(rng.normal(size=3))
        try:
            result = solve_ik(robot, target, rotation, seed=seed)
        except StiffnessError as exc:
            assert "\n" not in str(exc)
            continue
        solved += 1
        assert np.all(result.coords >= lo - 1e-12) and np.all(result.coords <= hi + 1e-12)
        assert result.position_error < 1e-9
    assert reachable // 4 <= solved <= reachable


def test_seed_is_moved_inside_the_limits():
    lo, hi = np.array([-1.0, 0.0, -np.inf]), np.array([1.0, 0.04, np.inf])
    inside = inside_limits(np.array([-3.0, 0.04, 7.0]), lo, hi)
    assert lo[0] < inside[0] < -0.99 and 0.0 < inside[1] < 0.04 and inside[2] == 7.0


@pytest.mark.parametrize("rank", [6, 3, 0])
def test_damped_step_equals_the_normal_equations(rank):
    """The SVD form of the damped step against ``J^T (J J^T + lambda^2 I)^-1 (-e)`` (solved
    directly, where that matrix is regular: lambda = 1e-3), at full and deficient rank."""
    rng = np.random.default_rng(rank)
    jac = rng.normal(size=(6, rank)) @ rng.normal(size=(rank, 7))
    err = rng.normal(size=6)
    lam = 1e-3
    direct = jac.T @ np.linalg.solve(jac @ jac.T + lam ** 2 * np.eye(6), -err)
    # the direct solve loses cond(J J^T + lambda^2 I) * eps, up to ~1e-8 at deficient rank
    assert np.allclose(damped_step(jac, err, lam), direct, rtol=1e-7, atol=1e-12)
    assert np.all(np.isfinite(damped_step(jac, err, 0.0)))
