"""Faults: commands killed mid-run, a full disk, a read-only folder, ``--out`` on a file.

* Each command that writes files (``report``, ``scan``, ``diagnose``, ``identify``,
  ``compensate``) is run once
  uninterrupted (in the test's process; the report is the session's), then started again as a
  process of its own in a fresh folder and killed with SIGKILL at a random
  point of its run (a bounded, seeded loop: one kill per command by default,
  ``STIFFNESS_FAULT_KILLS`` for more). Afterwards every file in its output folder is
  either absent or complete and valid (JSON parses, PNG ends with IEND, HTML is closed, NPZ and
  Parquet load); then the same command is rerun in that folder (in the test's process; a scan
  resumes) and its outputs equal the uninterrupted run's, and no temporary file is left.
* A full disk (a small tmpfs when this process may mount one, else a file-size limit set on
  the command) gives exit 2 with one line, and leaves no half-written file.
* A read-only folder (a read-only tmpfs) and ``--out`` naming an existing file give one line.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import random
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from stiffness.cli.main import main

ROBOTS = Path(__file__).resolve().parents[1] / "robots"
TABLE2 = ROBOTS / "sk120" / "campaigns" / "table2"
DOCS = Path(__file__).resolve().parents[1] / "docs" / "compensation"
#: Kills per command (``STIFFNESS_FAULT_KILLS=20 pytest tests/test_faults.py`` for a long run).
KILLS = int(os.environ.get("STIFFNESS_FAULT_KILLS", "1"))
#: Keys whose values depend on the run (timings, resume bookkeeping), not on its inputs.
VOLATILE = {"elapsed_s", "provenance", "generated", "date", "started", "seconds", "chunks"}


def cli(*args: str, limit_bytes: int | None = None,
        timeout: float = 120.0) -> subprocess.CompletedProcess:
    """``stiffness ARGS``: its exit status and what it printed, warnings included. Run in this
    process (``main``, as the console script runs it, with a fresh interpreter's warning
    filters and its warnings printed, not recorded by pytest: 1-2 s of imports less than a
    process), or as a process of its own under a file-size limit (``limit_bytes``: a limit
    set here would stay on the test worker)."""
    if limit_bytes is None:
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), \
                warnings.catch_warnings():
            warnings.resetwarnings()
            for ignored in (DeprecationWarning, PendingDeprecationWarning, ImportWarning,
                            ResourceWarning):
                warnings.simplefilter("ignore", ignored)
            warnings.showwarning = _printed
            code = main(list(args))
        return subprocess.CompletedProcess(["stiffness", *args], code, out.getvalue(),
                                           err.getvalue())

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))

    return subprocess.run([sys.executable, "-m", "stiffness.cli.main", *args],
                          capture_output=True, text=True, timeout=timeout, preexec_fn=limit)


def _printed(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning on stderr, as an interpreter without pytest shows it."""
    sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))


def without_volatile(value: object) -> object:
    if isinstance(value, dict):
        return {k: without_volatile(v) for k, v in value.items()
                if k not in VOLATILE and not k.endswith("_seconds")}
    if isinstance(value, list):
        return [without_volatile(v) for v in value]
    return value


def check_valid(path: Path) -> None:
    """Raise AssertionError unless ``path`` is a complete file of its kind."""
    data = path.read_bytes()
    assert data, f"{path} is empty"
    suffix = path.suffix
    if suffix == ".json":
        json.loads(data)
    elif suffix == ".png":
        assert data.startswith(b"\x89PNG\r\n\x1a\n") and data[-8:-4] == b"IEND", path
    elif suffix == ".html":
        assert data.rstrip().endswith(b"</html>"), f"{path} is cut short"
    elif suffix == ".npz":
        with np.load(io.BytesIO(data)) as npz:
            for key in npz.files:
                npz[key]
    elif suffix == ".parquet":
        import pyarrow.parquet as pq

        pq.read_table(path)
    elif suffix == ".csv":
        rows = [line.split(",") for line in data.decode().splitlines() if line.strip()
                and not line.startswith("#")]
        assert len({len(r) for r in rows}) == 1, f"{path} has ragged rows"
    elif suffix == ".toml":
        import tomllib

        tomllib.loads(data.decode())


def outputs(folder: Path) -> dict[str, Path]:
    return {str(p.relative_to(folder)): p for p in sorted(folder.rglob("*"))
            if p.is_file() and not p.name.endswith(".tmp")}


def temporaries(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*.tmp")]


def same_outputs(reference: Path, rerun: Path) -> None:
    ref, new = outputs(reference), outputs(rerun)
    assert sorted(ref) == sorted(new)
    for name, path in ref.items():
        if path.suffix == ".json":
            a, b = (without_volatile(json.loads(p.read_text())) for p in (path, new[name]))
            assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True), name
        elif path.suffix == ".npz":
            with np.load(path) as x, np.load(new[name]) as y:
                assert sorted(x.files) == sorted(y.files)
                for key in x.files:
                    np.testing.assert_array_equal(x[key], y[key], err_msg=f"{name}:{key}")


@pytest.fixture(scope="module")
def simulated_campaign(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("faults") / "sim"
    assert main(["simulate", "--robot", "ur5", "--frame", "tool0", "--configs", "6",
                 "--loads-per-config", "2", "--kq", "8e4,8e4,5e4",
                 "--compliant-joints", "shoulder_pan_joint,shoulder_lift_joint,elbow_joint",
                 "--effect", "joint_compliance:wrist_1_joint=5000", "--seed", "3",
                 "--out", str(folder)]) == 0
    return folder


def command_lines(campaign: Path) -> dict[str, list[str]]:
    """Each command's arguments, with ``OUT`` standing for its output folder."""
    return {
        "report": ["report", "--out", "OUT", "--quiet"],
        "identify": ["identify", str(TABLE2), "--starts", "2", "--quiet",
                     "--out", "OUT/identified-model.json"],
        "diagnose": ["diagnose", str(campaign), "--no-proposals", "--max-steps", "1", "--quiet",
                     "--out", "OUT"],
        "compensate": ["compensate", "--robot", "ur5", "--frame", "tool0", "--deg", "--path",
                       str(DOCS / "ur5-path.csv"), "--kq", "8e4,8e4,5e4,2e4,2e4,2e4",
                       "--wrench", "0,0,-300", "--quiet", "--out", "OUT/compensated.csv"],
        "scan": ["scan", "--robot", "ur5", "--frame", "tool0", "--samples", "60000",
                 "--chunk-size", "4000", "--kq", "8e4,8e4,5e4,2e4,2e4,2e4", "--no-plots",
                 "--quiet", "--out", "OUT"],
    }


def run_in(args: list[str], out: Path) -> subprocess.CompletedProcess:
    return cli(*[a.replace("OUT", str(out)) for a in args])


@pytest.mark.parametrize("command", ["report", "identify", "diagnose", "scan", "compensate"])
def test_killed_command_leaves_complete_outputs_and_reruns_identically(
        command, simulated_campaign, tmp_path, request):
    args = command_lines(simulated_campaign)[command]
    if command == "report":
        # the session's uninterrupted report (conftest.py) is the reference; its duration is
        # its build time plus about a second of imports
        reference = request.getfixturevalue("sk120_report")
        duration = json.loads((reference / "summary.json").read_text())["elapsed_s"] + 1.0
    else:
        # the uninterrupted reference in this process (the killed run and the rerun are
        # processes of their own); its duration plus about a second of imports
        reference = tmp_path / "reference"
        start = time.monotonic()
        assert main([a.replace("OUT", str(reference)) for a in args]) == 0
        duration = time.monotonic() - start + 1.0
    rng = random.Random(f"kill-{command}")
    for attempt in range(KILLS):
        out = tmp_path / f"killed-{attempt}"
        process = subprocess.Popen(
            [sys.executable, "-m", "stiffness.cli.main",
             *[a.replace("OUT", str(out)) for a in args]],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(rng.uniform(0.3, 1.0) * duration)
        process.send_signal(signal.SIGKILL)
        process.wait(10)
        if out.exists():
            for path in outputs(out).values():
                check_valid(path)
        rerun = run_in(args, out)
        assert rerun.returncode == 0, rerun.stderr
        same_outputs(reference, out)
        assert not temporaries(out), temporaries(out)


@contextlib.contextmanager
def tmpfs(size: str, read_only: bool = False):
    """A small tmpfs mounted for the test, or None where mounting is not permitted."""
    point = Path(tempfile.mkdtemp(prefix="stiffness-tmpfs-"))
    options = f"size={size}" + (",ro" if read_only else "")
    mounted = shutil.which("mount") is not None and subprocess.run(
        ["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(point)],
        capture_output=True).returncode == 0
    try:
        yield point if mounted else None
    finally:
        if mounted:
            subprocess.run(["umount", "-l", str(point)], capture_output=True)
        with contextlib.suppress(OSError):
            point.rmdir()


def one_line_error(done: subprocess.CompletedProcess, *words: str) -> None:
    assert done.returncode == 2, (done.returncode, done.stderr[-2000:])
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, done.stderr[-2000:]
    assert "Traceback" not in done.stderr
    for word in words:
        assert word in lines[0], lines[0]


def test_full_disk_gives_one_line_and_no_half_written_file(simulated_campaign, tmp_path):
    """A scan projected beyond the free space is refused before it writes; one that fits by
    the projection but fills the disk on the way (its figures, its aggregates) stops at the
    first failed write with one line and no half-written file."""
    too_big = command_lines(simulated_campaign)["scan"]
    fills = ["scan", "--robot", "ur5", "--frame", "tool0", "--samples", "300", "--chunk-size",
             "100", "--kq", "8e4,8e4,5e4,2e4,2e4,2e4", "--quiet", "--out", "OUT"]
    with tmpfs("96k") as small:
        if small is not None:
            out = small / "scan"
            one_line_error(run_in(too_big, out), "the scan would write at least 0.0166 GB",
                           "GB free")
            assert not out.exists()
            done = run_in(fills, out)
        else:
            out = tmp_path / "scan"
            done = cli(*[a.replace("OUT", str(out)) for a in too_big], limit_bytes=48_000)
        one_line_error(done, "cannot write", str(out))
        assert not temporaries(out.parent)
        for path in outputs(out).values() if out.exists() else []:
            check_valid(path)


def test_read_only_folder_gives_one_line(tmp_path):
    with tmpfs("1m", read_only=True) as frozen:
        if frozen is None:
            if os.geteuid() == 0:
                pytest.skip("root writes anywhere and no read-only tmpfs can be mounted here")
            frozen = tmp_path / "frozen"
            frozen.mkdir()
            frozen.chmod(0o555)
        done = cli("identify", str(TABLE2), "--starts", "1", "--quiet",
                   "--out", str(frozen / "model.json"))
        one_line_error(done, "cannot write")
        assert not list(frozen.iterdir())


@pytest.mark.parametrize("command", ["report", "scan", "diagnose"])
def test_out_naming_an_existing_file_gives_one_line(command, simulated_campaign, tmp_path):
    existing = tmp_path / "taken.txt"
    existing.write_text("keep me\n")
    args = command_lines(simulated_campaign)[command]
    done = run_in(args, existing)
    one_line_error(done, str(existing))
    assert existing.read_text() == "keep me\n"


def test_stale_temporaries_of_dead_writers_removed_once_per_folder(tmp_path):
    """A killed writer's temporary files are removed at the first write into their folder
    (any file of it); a live process's are kept; later writes do not list the folder again."""
    from stiffness import files

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    dead_pid = int(dead.stdout)
    stale = tmp_path / f".chunk-00001.npz.{dead_pid}.abc123.tmp"
    live = tmp_path / f".summary.json.{os.getppid()}.xyz789.tmp"
    other = tmp_path / ".notes.tmp"
    for path in (stale, live, other):
        path.write_text("half written")
    files.atomic_write(tmp_path / "chunk-00002.npz", b"data")
    assert not stale.exists() and live.exists() and other.exists()
    late = tmp_path / f".chunk-00003.npz.{dead_pid}.def456.tmp"
    late.write_text("half written")
    files.atomic_write(tmp_path / "chunk-00004.npz", b"data")
    assert late.exists()  # swept once per process: the next run removes it
    assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith(".")) == [
        "chunk-00002.npz", "chunk-00004.npz"]
