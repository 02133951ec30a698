"""Folders published by one rename (stiffness.files.staged_folder), killed at every rename.

The fault-injection hook ``STIFFNESS_KILL_AT_RENAME=N`` makes a process SIGKILL itself just
before the N-th rename of stiffness.files (atomic writes and the publication). A writer of a
realistic multi-file folder (figures, JSON, HTML, a subfolder; a forked process) is killed at
each of its renames, over an absent and over an existing folder; ``stiffness report`` (a
process started as a user starts it) at the rename that publishes its folder. After every
kill the folder is absent, empty, or the complete previous or new folder, never a mix; the
next run sweeps what the dead process left (an aside folder put back when the target is
missing, staging folders removed).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from stiffness import files
from stiffness.errors import OutputError

#: The files of a multi-file folder as the commands write it.
NAMES = ("a.png", "b.png", "c.png", "summary.json", "sub/model.json", "report.html")


def write(target: Path, version: str, kill_at: int | None = None) -> int:
    """Exit status of a process that writes the folder ``target`` holding ``version``,
    killed by the hook at its ``kill_at``-th rename (``-SIGKILL``): a child forked from this
    one (a process of its own, without an interpreter's start), the hook's environment
    variable and rename count its own."""
    pid = os.fork()
    if pid == 0:  # the child: never returns into the test
        code = 1
        try:
            os.environ.pop(files.KILL_AT_RENAME, None)
            if kill_at is not None:
                os.environ[files.KILL_AT_RENAME] = str(kill_at)
            files._RENAMES[0] = 0  # a fresh process has made no rename
            with files.staged_folder(target) as folder:
                for name in NAMES:
                    files.atomic_write(folder / name, f"{version}:{name}\n" * 1000)
            code = 0
        finally:
            os._exit(code)
    _, status = os.waitpid(pid, 0)
    return -os.WTERMSIG(status) if os.WIFSIGNALED(status) else os.WEXITSTATUS(status)


def state(target: Path) -> str:
    """``absent``, ``empty``, or the one version every file holds (all files present)."""
    if not target.exists():
        return "absent"
    found = {str(p.relative_to(target)): p.read_text() for p in target.rglob("*")
             if p.is_file()}
    if not found:
        return "empty"
    assert set(found) == set(NAMES), f"a mix of files: {sorted(found)}"
    versions = {text.split(":", 1)[0] for text in found.values()}
    assert len(versions) == 1, f"a mix of versions: {versions}"
    for name, text in found.items():
        assert text == f"{next(iter(versions))}:{name}\n" * 1000, f"{name} cut short"
    return versions.pop()


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


@pytest.mark.parametrize("previous", [False, True])
def test_killed_at_every_rename_leaves_no_mix_and_the_next_run_sweeps(tmp_path, previous):
    target = tmp_path / "out"
    renames = len(NAMES) + 1 + previous  # each file, the aside rename, the publication
    killed = 0
    for kill_at in range(1, renames + 2):
        shutil.rmtree(target, ignore_errors=True)
        if previous:
            assert write(target, "old") == 0
        done = write(target, "new", kill_at)
        if kill_at <= renames:
            assert done == -signal.SIGKILL, (kill_at, done)
            killed += 1
        else:  # past the last rename: the run ends normally
            assert done == 0, done
        after = state(target)
        expected = {"new"} if kill_at > renames else {"old" if previous else "absent"}
        if previous and kill_at == renames:  # between the aside rename and the publication
            expected = {"absent"}
        assert after in expected, (kill_at, after)
        # the next run sweeps: an interrupted publication's aside folder comes back first
        env_free = write(target, "next", kill_at=1)  # killed at its first rename, after sweeping
        assert env_free == -signal.SIGKILL
        assert state(target) == ("new" if kill_at > renames else
                                 "old" if previous else "absent")
        assert write(target, "final") == 0
        assert state(target) == "final"
        assert leftovers(tmp_path) == [], leftovers(tmp_path)
    assert killed == renames


def test_a_failed_build_leaves_the_target_as_it_was(tmp_path):
    target = tmp_path / "out"
    assert write(target, "old") == 0
    with pytest.raises(RuntimeError), files.staged_folder(target) as folder:
        files.atomic_write(folder / "a.png", "half")
        raise RuntimeError("the command failed")
    assert state(target) == "old"
    assert leftovers(tmp_path) == []


def test_live_processes_staging_is_kept_and_working_folder_refused(tmp_path, monkeypatch):
    target = tmp_path / "out"
    live = tmp_path / f".out.{os.getppid()}.abcd1234.staging"
    live.mkdir()
    assert write(target, "new") == 0
    assert live.is_dir()
    monkeypatch.chdir(target)
    with pytest.raises(OutputError, match="working folder"), files.staged_folder(target):
        pass
    with pytest.raises(OutputError, match="working folder"), files.staged_folder(tmp_path):
        pass


def test_campaign_folder_keeps_the_files_it_does_not_write(tmp_path):
    """keep_others: a URDF beside campaign.toml survives the campaign being rewritten."""
    target = tmp_path / "campaign"
    target.mkdir()
    (target / "robot.urdf").write_text("<robot/>")
    (target / "stale.csv").write_text("old")
    with files.staged_folder(target, keep_others=True) as folder:
        files.atomic_write(folder / "stale.csv", "new")
    assert (target / "robot.urdf").read_text() == "<robot/>"
    assert (target / "stale.csv").read_text() == "new"


def test_report_killed_at_its_publication_leaves_the_previous_report_to_put_back(
        sk120_report, tmp_path):
    """``stiffness report --out D`` (a process of its own, as a user runs it) over a previous
    report, killed just before renaming the new one in, the previous one moved aside: D is
    absent, and the next run puts the previous report back (every file as it was). A kill
    at any other rename is the writer's above: each run of the report computes it again, so
    the command is killed at this one rename only."""
    reference = {p.name for p in sk120_report.iterdir() if p.is_file()}
    kill_at = len(reference) + 2  # each file, the aside rename, the publication
    target = tmp_path / "report"
    shutil.copytree(sk120_report, target)
    summary = json.loads((target / "summary.json").read_text())
    summary["previous"] = True  # marks the previous report
    (target / "summary.json").write_text(json.dumps(summary))
    before = {p.name: p.read_bytes() for p in target.iterdir()}
    env = {**os.environ, files.KILL_AT_RENAME: str(kill_at),
           "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    done = subprocess.run([sys.executable, "-m", "stiffness.cli.main", "report", "--out",
                           str(target), "--quiet"], env=env, capture_output=True, timeout=300)
    assert done.returncode == -signal.SIGKILL, done.stderr[-2000:]
    assert not target.exists()
    with pytest.raises(RuntimeError), files.staged_folder(target):
        raise RuntimeError("a next run that fails at once, after its sweep")
    assert {p.name: p.read_bytes() for p in target.iterdir()} == before
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
