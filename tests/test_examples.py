"""Every script in examples/ runs as a user would run it, and says what it claims.

Each example runs in a fresh interpreter from a temporary folder (nothing is written into the
checkout); all of them start at once (the suite's time budget). Besides a clean exit, each
example's printed check is read back: the linear deflection agrees with the exact equilibrium
to second order, the batched K_C with the single-pose one, the identified springs with the
simulated ones, the SK120's pose calibration's intervals with the truth computed here.
"""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "examples").glob("*.py"))


@pytest.fixture(scope="module")
def outputs(tmp_path_factory) -> dict[str, subprocess.CompletedProcess]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env["MPLBACKEND"] = "Agg"
    cwd = tmp_path_factory.mktemp("examples")
    running = {p.name: subprocess.Popen([sys.executable, str(p)], cwd=cwd, env=env, text=True,
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE)
               for p in EXAMPLES}
    done = {}
    for name, process in running.items():
        out, err = process.communicate(timeout=600)
        done[name] = subprocess.CompletedProcess(process.args, process.returncode, out, err)
    assert not list(cwd.iterdir()), "an example wrote into its working folder"
    return done


def _number(pattern: str, text: str) -> float:
    match = re.search(pattern, text)
    assert match, f"no match for {pattern!r} in:\n{text}"
    return float(match.group(1))


def test_there_are_examples():
    assert len(EXAMPLES) >= 4
    for path in EXAMPLES:
        assert re.fullmatch(r"\d\d_[a-z0-9_]+\.py", path.name), path.name
        assert path.read_text().startswith('"""'), f"{path.name} has no docstring"


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_example_runs(path, outputs):
    done = outputs[path.name]
    assert done.returncode == 0, f"{path.name} failed:\n{done.stderr[-3000:]}"
    assert done.stdout.strip(), f"{path.name} printed nothing"


def test_kx_example_linear_deflection_meets_the_exact_one(outputs):
    gap = _number(r"\(([0-9.e+-]+) apart", outputs["01_kx_ur5.py"].stdout)
    assert 0.0 < gap < 1e-2


def test_closed_loop_example_finds_where_definiteness_is_lost(outputs):
    text = outputs["02_closed_loop_sk120.py"].stdout
    assert _number(r"at (\d+) x this load", text) > 1.0
    assert re.search(r"just above it, (ID|NSD|ND|PSD)\b", text), text


def test_identify_example_recovers_the_springs(outputs):
    error = _number(r"largest relative error ([0-9.]+)%", outputs["03_identify_campaign.py"].stdout)
    assert error < 5.0


def test_batch_example_matches_the_single_pose_path(outputs):
    text = outputs["04_batch_scan.py"].stdout
    assert _number(r"single-pose one to ([0-9.e+-]+)", text) < 1e-10
    assert re.search(r"scan: \d+ configurations", text), text


def test_compensation_example_cancels_the_deflection(outputs):
    text = outputs["05_compensate_ur5.py"].stdout
    assert _number(r"residual ([0-9.e+-]+) m exact", text) < 1e-9
    assert _number(r"\(factor ([0-9.]+)\)", text) > 1.0


def test_pose_calibration_example_closes_the_gap_to_the_noise(outputs):
    text = outputs["07_pose_calibration.py"].stdout
    assert _number(r"from ([0-9.]+) um to", text) > 300.0
    assert _number(r"to ([0-9.]+) um \(noise", text) < 25.0


def test_sk120_pose_example_holds_the_truth_in_its_intervals(outputs):
    """The SK120 from a tracker (seed 0, 10 poses, 20 um): explained to noise, and the 95 %
    interval it prints for each compliance (1/k of the paper's springs, written here) and each
    hidden zero offset (0.1 and -0.05 deg) holds the truth, and a compliance's is narrower than
    10 % of it (a fit that determines nothing would hold anything)."""
    text = outputs["08_pose_calibration_sk120.py"].stdout
    assert "explains the data to noise" in text, text
    truth = {"joint1 compliance": 1 / 1.4098e6, "joint2 compliance": 1 / 4.0076e5,
             "joint3 compliance": 1 / 9.3528e5, "joint2 zero": math.radians(0.1),
             "joint3 zero": math.radians(-0.05)}
    number = r"([0-9.e+-]+)"
    for label, value in truth.items():
        low = _number(rf"{label}: .*\[{number},", text)
        high = _number(rf"{label}: .*, {number}\]", text)
        assert low <= value <= high, (label, low, value, high)
        if "compliance" in label:
            assert high - low < 0.1 * value, (label, low, high)


def test_python_loop_example_finds_the_bend_and_its_stiffness(outputs):
    text = outputs["06_python_loop.py"].stdout
    assert "+ link_compliance(elbow_joint->wrist_1_joint)" in text
    assert _number(r"K_X within ([0-9.]+)% of the true", text) < 2.0
    assert _number(r"the springs alone: ([0-9.]+)% off", text) > 3.0
