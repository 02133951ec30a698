"""Every command on every kind of robot: exit 0, or exit 2 with one error line; never a
traceback (issue 36.2).

Commands: kx, view --export, scan, simulate, identify, diagnose --out (its text report and its
page, the report of a diagnosis), validate, compensate, posture, design, robot export --urdf and
--mjcf, campaign import, and for pose calibration campaign import --kind poses and diagnose of
that pose campaign. Robots: a URDF (UR5), a URDF with loops (the shipped SK120), a DH
table, a DH tree, DH tables with a square ``[controller]`` coupling (the SK120's
parallelogram) with the springs on each side, and with passive chain joints (a tall coupling:
tests/data/torso-passive) with the springs on each side.

The inputs are the smallest valid ones (a campaign of 3 poses x 2 loads, a tracker file of 6
poses, 2 scan samples, 2 path points, one posture target), so the whole matrix costs about
15 s of CPU.
"""

from __future__ import annotations

import contextlib
import io
import traceback
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from stiffness.cli.main import main
from stiffness.mechanics.defaults import default_coordinates
from stiffness.robot.robot import load_robot

DATA = Path(__file__).parent / "data"
SK120_DH = Path(__file__).parents[1] / "examples" / "sk120-dh" / "robot.toml"
TORSO = DATA / "torso-passive" / "robot.toml"
#: Per robot kind: the robot file (or name), and the text edits that move its springs to the
#: chain's joints (``None``: as it is).
KINDS = {
    "urdf": ("ur5", None),  # with UR5_KQ: example-robot-data gives no stiffness
    "urdf-loops": ("sk120", None),
    "dh": (str(DATA / "dh-arm" / "robot.toml"), None),
    "dh-tree": (str(DATA / "dh-tree" / "robot.toml"), None),
    "dh-square-controller": (str(SK120_DH), None),
    "dh-square-chain": (str(SK120_DH), {
        'springs_on = "controller"': 'springs_on = "chain"',
        'compliant_joints = ["joint1", "joint2", "joint3"]':
            'compliant_joints = ["waist", "shoulder", "elbow"]'}),
    "dh-passive-controller": (str(TORSO), None),
    "dh-passive-chain": (str(TORSO), {
        'springs_on = "controller"': 'springs_on = "chain"',
        'compliant_joints = ["T1", "T2", "T3", "A1", "A2"]':
            'compliant_joints = ["t1", "t2", "t3", "t4", "a1", "a2"]',
        "k_theta_SI = [4.0e4, 2.5e4, 2.0e4, 8.0e3, 6.0e3]":
            "k_theta_SI = [4.0e4, 2.5e4, 2.0e4, 1.5e4, 8.0e3, 6.0e3]"}),
}
UR5_KQ = ["--kq", "8e4,8e4,5e4,2e4,2e4,2e4"]
WRENCH = ["--wrench", "10,-20,-40"]
COMMANDS = ("kx", "view", "scan", "simulate", "identify", "diagnose", "validate", "compensate",
            "posture", "design", "export-urdf", "export-mjcf", "campaign-import",
            "campaign-import-poses", "diagnose-poses")


def run_cli(argv: list[str]) -> tuple[int, str]:
    """Exit status and stderr of ``stiffness ARGV`` run in this process (an exception that
    escapes ``main`` is returned as its traceback, exit 1)."""
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            code = main(argv)
    except Exception:  # noqa: BLE001 (the cell reports it)
        return 1, err.getvalue() + traceback.format_exc()
    return code, err.getvalue()


def assert_clean_exit(code: int, stderr: str) -> None:
    """Exit 0, or exit 2 with one error line (warnings aside); never a traceback."""
    assert "Traceback" not in stderr, stderr
    lines = [line for line in stderr.splitlines()
             if line.strip() and ": warning:" not in line and not line.startswith("note:")]
    if code == 0:
        assert not any(": error:" in line for line in lines), stderr
        return
    assert code == 2, (code, stderr)
    assert len(lines) == 1 and ": error:" in lines[0], stderr


class Bench:
    """A robot kind's files: the robot, a tiny campaign, its diagnosis, a path, target poses."""

    def __init__(self, kind: str, folder: Path) -> None:
        source, edits = KINDS[kind]
        if edits is not None:
            text = Path(source).read_text()
            for old, new in edits.items():
                assert old in text, old
                text = text.replace(old, new)
            source = str(folder / "robot.toml")
            Path(source).write_text(text)
        self.folder, self.robot = folder, source
        self.kq = UR5_KQ if source == "ur5" else []
        self.campaign, self.diagnosis = folder / "campaign", folder / "diagnosis"
        self.simulated = run_cli(["simulate", "--robot", source, *self.kq, "--configs", "3",
                                  "--loads-per-config", "2", "--seed", "1", "--quiet",
                                  "--out", str(self.campaign)])
        self.diagnosed = run_cli(["diagnose", str(self.campaign), "--out", str(self.diagnosis),
                                  "--max-steps", "1", "--workers", "1", "--quiet"])
        robot = load_robot(source)
        start = default_coordinates(robot)
        start = np.full(robot.n_coordinates, 0.3) if start is None else start
        coords = start + np.array([[0.0], [0.01]])  # two close path points (rad, m)
        pin.framesForwardKinematics(robot.model, robot.data, robot.configuration(coords[0]))
        placement = robot.data.oMf[robot.target_frame_id]
        self.poses = folder / "poses.csv"  # one target pose: the tool there
        self.poses.write_text("x,y,z,ax,ay,az\n" + ",".join(f"{v:.9g}" for v in (
            *placement.translation, *placement.rotation[:, 2])) + "\n")
        self._pose_rig(robot, start)
        self.path = folder / "path.csv"
        self.path.write_text(",".join(robot.coordinate_joints) + "\n" + "\n".join(
            ",".join(f"{v:.6g}" for v in row) for row in coords) + "\n")

    def _pose_rig(self, robot, start: np.ndarray) -> None:
        """A tracker's file of 6 poses (deg; the tool's marker in mm, 20 um noise), as a rig
        writes it for ``campaign import --kind poses``."""
        rng = np.random.default_rng(2)
        lines = [",".join([*robot.coordinate_joints, "tip_x", "tip_y", "tip_z"])]
        for c in start + rng.uniform(-0.3, 0.3, (6, robot.n_coordinates)):
            pin.framesForwardKinematics(robot.model, robot.data, robot.configuration(c))
            tip = robot.data.oMf[robot.target_frame_id].act(np.array([0.0, 0.0, 0.02]))
            tip = 1e3 * tip + rng.normal(0.0, 0.02, 3)
            lines.append(",".join(f"{v:.9g}" for v in (*np.rad2deg(c), *tip)))
        self.pose_rig = self.folder / "tracker.csv"
        self.pose_rig.write_text("\n".join(lines) + "\n")
        self.marker = f"tip={robot.target_frame}@0,0,20"

    def argv(self, command: str) -> list[str]:
        """The command line of one cell."""
        out, robot = self.folder / command, ["--robot", self.robot, *self.kq]
        return {
            "kx": ["kx", *robot, *WRENCH],
            "view": ["view", *robot, *WRENCH, "--export", str(out) + ".html"],
            "scan": ["scan", *robot, "--samples", "2", "--no-plots", "--quiet", "--out",
                     str(out)],
            "identify": ["identify", str(self.campaign), "--starts", "1", "--quiet", "--out",
                         str(out) + ".json"],
            "validate": ["validate", str(self.diagnosis / "final-model.json"),
                         str(self.campaign)],
            "compensate": ["compensate", *robot, *WRENCH, "--path", str(self.path), "--quiet",
                           "--out", str(out) + ".csv"],
            "posture": ["posture", *robot, *WRENCH, "--path", str(self.poses), "--steps", "2",
                        "--no-refine", "--quiet", "--out", str(out) + ".csv"],
            "design": ["design", *robot, "--configs", "2", "--loads-per-config", "1",
                       "--max-force", "50", "--candidates", "6", "--quiet", "--out",
                       str(out) + ".csv"],
            "export-urdf": ["robot", "export", "--robot", self.robot, "--urdf",
                            str(out) + ".urdf", "--quiet"],
            "export-mjcf": ["robot", "export", *robot, "--mjcf", str(out) + ".xml", "--quiet"],
            "campaign-import": ["campaign", "import", "--robot", self.robot, "--units",
                                "angle=deg,force=N,length=mm", "--out", str(out),
                                str(self.campaign / "measurements.csv")],
            "campaign-import-poses": ["campaign", "import", "--kind", "poses", "--robot",
                                      self.robot, "--units", "angle=deg,length=mm",
                                      "--marker", self.marker, "--noise", "0.02", "--out",
                                      str(self.folder / "poses"), str(self.pose_rig)],
            "diagnose-poses": ["diagnose", str(self.folder / "poses"), "--max-steps", "1",
                               "--workers", "1", "--quiet", "--out", str(out)],
        }[command]


def cell_problem(code: int, stderr: str) -> str | None:
    """Why a cell's outcome is not clean (:func:`assert_clean_exit`), or None."""
    try:
        assert_clean_exit(code, stderr)
    except AssertionError:
        return f"exit {code}: {stderr.strip()[-600:]}"
    return None


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_every_command_on_a_robot_kind(tmp_path, kind):
    """The 15 commands on one robot kind (one test per kind, so that a process builds each
    kind's campaign and diagnosis once); every unclean cell is named."""
    bench = Bench(kind, tmp_path)
    problems = {}
    for command in COMMANDS:
        if command == "simulate":
            outcome = bench.simulated
        elif command == "diagnose":  # its report: the text on stdout and the page
            outcome = bench.diagnosed
            if outcome[0] == 0 and not (bench.diagnosis / "diagnosis.html").stat().st_size:
                outcome = (1, "diagnose --out wrote an empty diagnosis.html")
        else:
            outcome = run_cli(bench.argv(command))
        problem = cell_problem(*outcome)
        if problem is not None:
            problems[command] = problem
    assert not problems, problems
