"""Shared fixtures: robots loaded once per module, test linkages written as URDF, FD helpers.

Robots: the shipped SK120 (closed five-bar), UR5 (all six joints, or only the first three
compliant for the 3x3 translational cases), Panda (the seven arm joints compliant: redundant).

Test linkages (written to a temporary folder as a URDF plus its ``.loops.yaml`` sidecar):

* ``four_bar``: a planar crank-rocker four-bar (not a parallelogram) with a tool joint on the
  coupler carrying the target, so the closed-loop K_C is 2x2 and its multiplier term is large;
* ``tilted_four_bar``: the same linkage mounted on a tilted plane, so the loop's redundant
  constraint direction (the plane normal) is not a base axis;
* ``spatial_four_bar``: an R-U-S-R spatial linkage (crank, universal joint, point contact, rocker
  with a skew axis): a non-planar loop whose point constraint has full rank 3;
* ``non_grashof_four_bar``: a triple-rocker whose crank cannot turn a full circle.

Finite differences (``fd`` fixture): central differences over the robot coordinates of the
compliant joints, the loops being closed by :meth:`Robot.configuration` seeded from the base
configuration (the same assembly branch).
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

# One BLAS thread per test process, set before NumPy loads: pytest-xdist runs a process per
# core, and OpenBLAS's threads on top of them oversubscribe the machine (a 360x50 SVD took
# 1.5 ms single-threaded and 26-73 ms oversubscribed on this 2-core machine).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

# The Python processes of a run (the test workers, and the examples, the docs' blocks, killed
# commands, the wheel's commands they start) share one bytecode cache outside the checkout.
# Where PYTHONDONTWRITEBYTECODE is set (as in this project's containers) each process compiled the
# package from source again (0.17 s of CPU for ``stiffness kx``, 0.4 s for a command that
# imports the calibration) and each test worker rewrote the asserts of every test module it
# collected (8 of its 16 s of collection), measured 2026-12-06. A cache the caller chose
# (PYTHONPYCACHEPREFIX) is kept; nothing is written into the checkout.
if os.environ.get("PYTHONDONTWRITEBYTECODE") and "PYTHONPYCACHEPREFIX" not in os.environ:
    sys.pycache_prefix = os.path.join(tempfile.gettempdir(),
                                      f"stiffness-tests-pycache-{os.getuid()}")
    sys.dont_write_bytecode = False
    os.environ["PYTHONPYCACHEPREFIX"] = sys.pycache_prefix
    del os.environ["PYTHONDONTWRITEBYTECODE"]

import numpy as np  # noqa: E402
import pytest
from hypothesis import HealthCheck, settings
from shared_run import run_folder

from stiffness.mechanics.formulation import target_state
from stiffness.robot.robot import Robot, load_robot

# Hypothesis profiles, loaded before any test module: ``ci`` (default) is derandomized, so a
# run is reproducible and never fails on an example another run stored; ``random`` explores new
# examples (``HYPOTHESIS_PROFILE=random python -m pytest``); ``long`` runs the fuzz tests of
# tests/test_fuzz_readers.py with thousands of examples and tests/test_no_traceback.py's flag
# values with 300 commands and its commands with 300 examples each (measured 2026-12-04 on the
# shared 2-core machine: flag values 110 s, kx 39 s, compensate 47 s, posture 19 min, view
# --export 28 min; about 50 min in all; it found simulate --noise -0's ValueError).
# No deadline: speed lives in scripts/bench.py, never in a test (a 0.7 ms example took 705 ms
# once on the loaded machine and failed test_batch_linalg's property).
_QUIET = [HealthCheck.function_scoped_fixture, HealthCheck.too_slow]
settings.register_profile("ci", derandomize=True, suppress_health_check=_QUIET, deadline=None)
settings.register_profile("random", suppress_health_check=_QUIET, deadline=None)
settings.register_profile("long", suppress_health_check=_QUIET, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

#: Test files started first, the costliest first (CPU per file measured with -n 0 on the
#: loaded 2-core machine, session 41: absolute poses ~80 s, pose elastic ~70 s, diagnose ~48 s,
#: robust poses ~45 s, examples ~32 s, wheel ~29 s, ...; a whole run's --durations=40 added
#: joint_angles, faults and design; session 48, one core: pose_selection 17 s, unexplained
#: 9 s and rotation_second_order 5 s, which ran late, by name). The suite runs with
#: ``--dist loadfile`` (pyproject.toml): each file on one worker, so a module's fixtures are
#: computed once, and the long files start first instead of ending the run on one worker
#: while the other idles. test_report first: it computes the shared SK120 report
#: (``sk120_report_run``) that test_wheel, test_publish, test_faults and test_headline_numbers
#: then read instead of waiting for it. The other files follow in their collection order.
SLOW_FIRST = (
    "test_report.py", "test_absolute_poses.py", "test_pose_elastic.py", "test_joint_angles.py",
    "test_diagnose.py", "test_pose_robust.py", "test_examples.py", "test_wheel.py",
    "test_faults.py", "test_design.py", "test_pose_selection.py", "test_command_matrix.py",
    "test_scan_command.py", "test_viewer.py", "test_posture_branches.py", "test_no_traceback.py",
    "test_compensator_geometry.py", "test_unexplained.py", "test_posture.py",
    "test_detection_tables.py", "test_rotation_second_order.py",
    "test_docs_run.py", "test_publish.py", "test_viewer_visibility.py", "test_pose_workers.py",
)


def pytest_configure(config) -> None:
    """A pytest-xdist worker runs on its share of the CPUs (worker i of n: every n-th CPU from
    the i-th, or one CPU when there are more workers than CPUs), as its processes' affinity.

    xdist already runs a test process per core (``-n auto``); a library call that fans out to
    forked workers by default (``diagnose``'s candidate fits: :func:`stiffness.cores.usable_cores`
    reads this affinity) would only compete with the other test workers for the same cores,
    at the cost of the forks (the 20 diagnoses of test_joint_angles: 48 s of CPU in the test
    process, 68 s with their forks). Tests of the forked paths ask for their workers
    explicitly. A run without xdist (``-n 0``) keeps the library's defaults.
    """
    worker, count = os.environ.get("PYTEST_XDIST_WORKER"), os.environ.get(
        "PYTEST_XDIST_WORKER_COUNT")
    if worker is None or count is None or not hasattr(os, "sched_setaffinity"):
        return
    cpus, n = sorted(os.sched_getaffinity(0)), int(count)
    index = int(worker.removeprefix("gw")) % n  # a worker xdist restarts is numbered on: gw2
    os.sched_setaffinity(0, cpus[index::n] if n <= len(cpus) else [cpus[index % len(cpus)]])


def pytest_collection_modifyitems(config, items) -> None:
    """The files of :data:`SLOW_FIRST` first, in that order (stable otherwise)."""
    here = Path(__file__).parent
    missing = [name for name in SLOW_FIRST if not (here / name).is_file()]
    if missing:
        raise pytest.UsageError(f"conftest.SLOW_FIRST names {missing[0]}, not a test file")
    rank = {name: i for i, name in enumerate(SLOW_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


#: SK120 workspace of the paper (printed angles, deg): theta1, theta2, theta3.
SK120_WORKSPACE_DEG = ((-180.0, 180.0), (-70.0, 70.0), (-115.0, 35.0))

#: UR5 and Panda arm joints.
UR5_ARM = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"]
PANDA_ARM = [f"panda_joint{i}" for i in range(1, 8)]


# --------------------------------------------------------------------------------------- robots


@pytest.fixture(scope="module")
def sk120() -> Robot:
    return load_robot("sk120")


@pytest.fixture(scope="module")
def ur5() -> Robot:
    return load_robot("ur5")


@pytest.fixture(scope="module")
def ur5_arm() -> Robot:
    """UR5 with only its first three joints compliant (3x3 translational cases)."""
    return load_robot("ur5", compliant_joints=UR5_ARM)


@pytest.fixture(scope="module")
def panda() -> Robot:
    """Panda with its seven arm joints compliant (redundant), target at the hand TCP."""
    return load_robot("panda", compliant_joints=PANDA_ARM)


def sk120_coordinates(u: np.ndarray) -> np.ndarray:
    """SK120 coordinates (rad) from six numbers in [0, 1]: theta1..3 in the paper's workspace,
    the wrist angles in [-180, 180] deg."""
    u = np.asarray(u, dtype=float)
    lo = np.array([b[0] for b in SK120_WORKSPACE_DEG] + [-180.0] * 3)
    hi = np.array([b[1] for b in SK120_WORKSPACE_DEG] + [180.0] * 3)
    return np.deg2rad(lo + u * (hi - lo))


@pytest.fixture(scope="module")
def sk120_coords():
    """Function mapping six numbers in [0, 1] to SK120 workspace coordinates (rad)."""
    return sk120_coordinates


# ---------------------------------------------------------------------------- finite differences


def _coordinate_fd(robot: Robot, coords: np.ndarray, fn, h: float = 1e-5) -> np.ndarray:
    """Central differences of ``fn(TargetState)`` over the compliant joints' coordinates.

    Returns an array of shape fn(...).shape + (n_compliant,). Loops are closed by
    ``robot.configuration`` seeded with the base configuration (same assembly branch).
    """
    coords = np.asarray(coords, dtype=float)
    q0 = robot.configuration(coords)
    columns = []
    for i in robot.compliant_in_coordinates:
        values = []
        for sign in (1.0, -1.0):
            c = coords.copy()
            c[i] += sign * h
            values.append(np.asarray(fn(target_state(robot, robot.configuration(c, seed=q0)))))
        columns.append((values[0] - values[1]) / (2.0 * h))
    return np.stack(columns, axis=-1)


def _rel_err(a: np.ndarray, b: np.ndarray) -> float:
    """Frobenius-norm error of ``a`` relative to the reference ``b``."""
    return float(np.linalg.norm(np.asarray(a) - np.asarray(b)) / np.linalg.norm(b))


@pytest.fixture(scope="module")
def fd():
    """Finite-difference helpers: ``fd.coordinates(robot, coords, fn, h)`` and ``fd.rel_err``."""
    return SimpleNamespace(coordinates=_coordinate_fd, rel_err=_rel_err)


# ------------------------------------------------------------------------------- test linkages


def _num(v: float) -> str:
    return repr(float(v))


def _vec(v) -> str:
    return " ".join(_num(x) for x in v)


def _joint(name: str, parent: str, child: str, xyz=(0, 0, 0), rpy=(0, 0, 0), axis=(0, 0, 1),
           kind: str = "revolute") -> str:
    extra = ""
    if kind != "fixed":
        extra = f'<axis xyz="{_vec(axis)}"/>'
    if kind == "revolute":
        extra += '<limit effort="100" velocity="2" lower="-6.3" upper="6.3"/>'
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{_vec(xyz)}" rpy="{_vec(rpy)}"/>{extra}</joint>')


def _robot_xml(name: str, links: list[str], joints: list[str]) -> str:
    body = "".join(f'<link name="{link}"/>' for link in links) + "".join(joints)
    return f'<?xml version="1.0"?>\n<robot name="{name}">{body}</robot>\n'


LOOP_SIDECAR = (
    'closed_loop:\n  - [coupler_end, rocker_end]\ntype: ["3D"]\n'
    'name_mot: [crank_joint, tool_joint]\n'
)


def four_bar_closed_form(phi: float, a: float, b: float, c: float, d: float, branch: int = 1
                         ) -> tuple[float, float]:
    """Absolute coupler and rocker angles (rad, in the loop plane) of a planar four-bar.

    Ground pivots at (0, 0) (crank, length a) and (d, 0) (rocker, length c); coupler length b;
    crank angle ``phi``. ``branch`` = +1 or -1 selects the assembly (the sign of the angle
    between the crank-pivot-to-rocker-pivot direction and the coupler, seen from the crank end).
    Raises ValueError when the loop cannot close.
    """
    crank_end = a * np.array([np.cos(phi), np.sin(phi)])
    to_pivot = np.array([d, 0.0]) - crank_end
    e = float(np.linalg.norm(to_pivot))
    cos_alpha = (b * b + e * e - c * c) / (2.0 * b * e)
    if abs(cos_alpha) > 1.0:
        raise ValueError("the four-bar cannot close at this crank angle")
    coupler = np.arctan2(to_pivot[1], to_pivot[0]) + branch * np.arccos(cos_alpha)
    rocker_end = crank_end + b * np.array([np.cos(coupler), np.sin(coupler)])
    rocker = np.arctan2(rocker_end[1], rocker_end[0] - d)
    return float(coupler), float(rocker)


@dataclass
class FourBar:
    """A planar four-bar test linkage written as URDF: lengths (m) and the assembly offsets."""

    urdf: Path
    a: float
    b: float
    c: float
    d: float
    beta0: float
    psi0: float
    tilt: tuple[float, float, float]

    def passive_closed_form(self, phi: float, branch: int = 1) -> tuple[float, float]:
        """URDF values (rad) of coupler_joint and rocker_joint at crank angle ``phi``, on the
        assembly branch of the zero configuration (+1) or the other one (-1)."""
        coupler, rocker = four_bar_closed_form(phi, self.a, self.b, self.c, self.d, branch)
        return coupler - phi - self.beta0, rocker - self.psi0


def write_four_bar(folder: Path, name: str, a: float, b: float, c: float, d: float,
                   tilt=(0.0, 0.0, 0.0)) -> FourBar:
    """Planar four-bar in the x-y plane of a ``plane`` link (mounted on the base with ``tilt``
    roll-pitch-yaw), assembled at zero joint values on the +1 branch.

    Joints: crank_joint (ground-crank, at the origin), coupler_joint (crank-coupler),
    rocker_joint (ground-rocker, at (d, 0, 0)) and tool_joint (coupler-tool, off the coupler
    line). Loop frames: coupler_end (far end of the coupler), rocker_end (far end of the rocker).
    Target frame: tool_tip.
    """
    beta0, psi0 = four_bar_closed_form(0.0, a, b, c, d)
    links = ["base_link", "plane", "crank", "coupler", "coupler_end", "tool", "tool_tip",
             "rocker", "rocker_end"]
    joints = [
        _joint("mount", "base_link", "plane", xyz=(0.1, -0.2, 0.3), rpy=tilt, kind="fixed"),
        _joint("crank_joint", "plane", "crank"),
        _joint("coupler_joint", "crank", "coupler", xyz=(a, 0, 0), rpy=(0, 0, beta0)),
        _joint("coupler_end_joint", "coupler", "coupler_end", xyz=(b, 0, 0), kind="fixed"),
        _joint("tool_joint", "coupler", "tool", xyz=(0.35 * b, 0.15, 0)),
        _joint("tool_tip_joint", "tool", "tool_tip", xyz=(0.25, 0.05, 0), kind="fixed"),
        _joint("rocker_joint", "plane", "rocker", xyz=(d, 0, 0), rpy=(0, 0, psi0)),
        _joint("rocker_end_joint", "rocker", "rocker_end", xyz=(c, 0, 0), kind="fixed"),
    ]
    folder.mkdir(parents=True, exist_ok=True)
    urdf = folder / f"{name}.urdf"
    urdf.write_text(_robot_xml(name, links, joints))
    (folder / f"{name}.loops.yaml").write_text(LOOP_SIDECAR)
    return FourBar(urdf, a, b, c, d, beta0, psi0, tuple(tilt))


def write_spatial_four_bar(folder: Path, name: str = "rusr") -> Path:
    """R-U-S-R spatial linkage, closed at zero joint values.

    crank_joint (axis z) -> universal joint u1_joint (y), u2_joint (z) -> coupler, whose far end
    (coupler_end) meets the end of a rocker (rocker_joint, skew axis normal to the rocker) in a
    point contact. tool_joint (skew axis) on the coupler carries the target ``tool_tip``.
    """
    crank_end = np.array([0.2, 0.0, 0.0])
    coupler = np.array([0.3, 0.4, 0.5])
    pivot = np.array([0.6, -0.1, 0.05])
    rocker = crank_end + coupler - pivot
    axis = np.cross(rocker, [1.0, 0.3, -0.2])
    axis /= np.linalg.norm(axis)
    links = ["base_link", "crank", "ulink", "coupler", "coupler_end", "tool", "tool_tip",
             "rocker", "rocker_end"]
    joints = [
        _joint("crank_joint", "base_link", "crank"),
        _joint("u1_joint", "crank", "ulink", xyz=crank_end, axis=(0, 1, 0)),
        _joint("u2_joint", "ulink", "coupler", axis=(0, 0, 1)),
        _joint("coupler_end_joint", "coupler", "coupler_end", xyz=coupler, kind="fixed"),
        _joint("tool_joint", "coupler", "tool", xyz=0.5 * coupler, axis=(0.6, 0.0, 0.8)),
        _joint("tool_tip_joint", "tool", "tool_tip", xyz=(0.1, 0.2, 0.05), kind="fixed"),
        _joint("rocker_joint", "base_link", "rocker", xyz=pivot, axis=axis),
        _joint("rocker_end_joint", "rocker", "rocker_end", xyz=rocker, kind="fixed"),
    ]
    folder.mkdir(parents=True, exist_ok=True)
    urdf = folder / f"{name}.urdf"
    urdf.write_text(_robot_xml(name, links, joints))
    (folder / f"{name}.loops.yaml").write_text(LOOP_SIDECAR)
    return urdf


#: Crank-rocker (Grashof: s + l = 0.9 < p + q = 1.1, crank shortest): the crank turns fully and
#: the loop never reaches a toggle (passive Jacobian regular everywhere).
CRANK_ROCKER = {"a": 0.2, "b": 0.7, "c": 0.5, "d": 0.6}
#: Triple rocker: at crank angle pi the crank end is 1.1 m from the rocker pivot > b + c = 0.65.
TRIPLE_ROCKER = {"a": 0.5, "b": 0.3, "c": 0.35, "d": 0.6}
TILT_RPY = (0.3, -0.5, 0.7)


@pytest.fixture(scope="module")
def linkage_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("linkages")


@pytest.fixture(scope="module")
def four_bar(linkage_dir) -> FourBar:
    return write_four_bar(linkage_dir / "planar", "fourbar", **CRANK_ROCKER)


@pytest.fixture(scope="module")
def tilted_four_bar(linkage_dir) -> FourBar:
    return write_four_bar(linkage_dir / "tilted", "fourbar", **CRANK_ROCKER, tilt=TILT_RPY)


@pytest.fixture(scope="module")
def non_grashof_four_bar(linkage_dir) -> FourBar:
    return write_four_bar(linkage_dir / "rocker", "rockers", **TRIPLE_ROCKER)


@pytest.fixture(scope="module")
def spatial_four_bar(linkage_dir) -> Path:
    return write_spatial_four_bar(linkage_dir / "spatial")


@pytest.fixture(scope="module")
def four_bar_robot(four_bar) -> Robot:
    return load_robot(four_bar.urdf, frame="tool_tip")


@pytest.fixture(scope="module")
def tilted_four_bar_robot(tilted_four_bar) -> Robot:
    return load_robot(tilted_four_bar.urdf, frame="tool_tip")


@pytest.fixture(scope="module")
def spatial_robot(spatial_four_bar) -> Robot:
    return load_robot(spatial_four_bar, frame="tool_tip")


# ---------------------------------------------------------------------------- the SK120 report


@pytest.fixture(scope="session")
def sk120_report_run(tmp_path_factory, worker_id) -> tuple[Path, str]:
    """Folder written once per test run by ``stiffness report --quiet`` (summary.json, ...)
    and what the command printed. Tests only read it (it is shared by the run's test workers:
    the first to need it writes it under a file lock, the others wait and read)."""
    from stiffness.cli.main import main

    with run_folder(tmp_path_factory, worker_id, "sk120-report") as root:
        out, printed = root / "sk120-report", root / "sk120-report.stdout"
        if not printed.exists():
            said = io.StringIO()
            with contextlib.redirect_stdout(said):
                assert main(["report", "--out", str(out), "--quiet"]) == 0
            printed.write_text(said.getvalue())
    return out, printed.read_text()


@pytest.fixture(scope="session")
def sk120_report(sk120_report_run) -> Path:
    """The folder of :func:`sk120_report_run`."""
    return sk120_report_run[0]


@pytest.fixture(scope="session")
def ur5_rigid_wrist_model(tmp_path_factory, worker_id) -> Path:
    """The model file ``identify`` writes (its defaults) of one simulated UR5 campaign loading
    a wrist spring of 1e13 N.m/rad, rigid to its 5 um noise (pan, lift, elbow 3e4, 2e4, 1.5e4
    N.m/rad; 4 configurations of 3 loads up to 100 N, seed 1): written once per test run (about
    1.5 s of CPU) in the run's folder, under a lock, for test_kx_model and
    test_confounded_springs, which only read it."""
    import stiffness

    with run_folder(tmp_path_factory, worker_id, "ur5-rigid-wrist") as root:
        folder = root / "ur5-rigid-wrist"
        if not (folder / "m.json").exists():
            joints = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
                      "wrist_1_joint"]
            stiffness.simulate("ur5", kq=[3e4, 2e4, 1.5e4, 1e13], compliant_joints=joints,
                               configs=4, loads_per_config=3, max_force=100.0,
                               noise_std_m=5e-6, seed=1).write(folder / "c")
            stiffness.identify(folder / "c").write_model(folder / "m.json")
    return folder / "m.json"
