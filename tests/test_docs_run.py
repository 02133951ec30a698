"""Docs that run (issue 38 item 11): the code blocks of README.md and docs/*.md are run.

* Every ```python block of a file runs, in order, in one Python process (later blocks use
  what earlier ones defined, as a reader would type them), in a fresh folder where
  ``robots/`` and ``examples/`` are the repository's.
* Every ``stiffness ...`` command of a ```bash, ```sh or ```console block (``$ `` prompts
  dropped, ``\\`` continuations joined) runs in that process too, after the file's Python
  blocks (``stiffness.cli.main.main``, as the console script does), and ends in exit 0.

A block that cannot run here says so on the line before its fence, with the reason:
``<!-- docs-test: skip (why) -->``; a command synopsis (``[--flag ...]`` placeholders) is
marked ``<!-- docs-test: synopsis -->``. The test refuses a marker without a reason.
Blocks skipped for their cost are listed in :data:`SLOW` (checked against the markers), so
the cost of the suite stays visible.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.S | re.M)
MARKER = re.compile(r"<!--\s*docs-test:\s*(skip|synopsis)\s*(\((.+?)\))?\s*-->\s*$", re.M)
#: Blocks skipped because running them costs more than the suite can pay (file, reason word).
SLOW = {("README.md", "slow"), ("docs/absolute-poses.md", "slow"), ("docs/compensation.md", "slow"),
        ("docs/diagnose.md", "slow"), ("docs/performance.md", "slow")}


def blocks(path: Path) -> list[tuple[str, str, int, str | None]]:
    """(language, body, line, marker) of each fenced block of ``path``."""
    text = path.read_text()
    out = []
    for match in FENCE.finditer(text):
        line = text[: match.start()].count("\n") + 1
        before = text[: match.start()].rstrip("\n").rsplit("\n", 1)[-1]
        marker = MARKER.search(before)
        if marker is not None and marker.group(1) == "skip":
            assert marker.group(3), f"{path.name}:{line}: a skip marker needs its reason"
        out.append((match.group(1), match.group(2), line,
                    None if marker is None else marker.group(1)))
    return out


def commands(body: str) -> list[str]:
    """The ``stiffness`` command lines of a shell block (continuations joined, prompts and
    comments dropped)."""
    joined = re.sub(r"\\\n\s*", " ", body)
    out = []
    for line in joined.splitlines():
        line = line.strip().removeprefix("$ ")
        line = line.split(" #", 1)[0].strip()
        if line.startswith("stiffness "):
            out.append(line)
    return out


def documented(path: Path) -> tuple[str, list[str]]:
    """The file's Python to run and its shell commands to run."""
    python, shell = [], []
    for language, body, line, marker in blocks(path):
        if marker is not None:
            continue
        if language == "python":
            python.append(f"# {path.name}:{line}\n{body}")
        elif language in ("bash", "sh", "console"):
            shell += commands(body)
    return "\n".join(python), shell


def folder(tmp_path: Path, path: Path) -> Path:
    """Where ``path``'s blocks run: a fresh folder with the repository's ``robots/`` and
    ``examples/`` and ``docs/``, or inside a copy of the doc's own folder of files
    (``docs/compensation/`` for docs/compensation.md) when it has one, so that its relative
    paths hold."""
    for name in ("robots", "examples"):
        (tmp_path / name).symlink_to(ROOT / name)
    own = path.parent / path.stem
    if path.parent.name == "docs" and own.is_dir():
        shutil.copytree(own, tmp_path / "docs" / path.stem)
        return tmp_path / "docs" / path.stem
    (tmp_path / "docs").symlink_to(ROOT / "docs")  # the docs' example files, read only
    return tmp_path


def run(argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get(
        "PYTHONPATH", "")]), "MPLBACKEND": "Agg"}
    return subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("path", DOCS, ids=[p.name for p in DOCS])
def test_the_code_blocks_run(path: Path, tmp_path: Path):
    """One Python process per file (its blocks, then its commands through
    ``stiffness.cli.main.main``, each to end in exit 0): one import of the toolkit per file."""
    python, shell = documented(path)
    if not python and not shell:
        return
    where = folder(tmp_path, path)
    script = [python, "from stiffness.cli.main import main as _stiffness"]
    script += [f"assert _stiffness({shlex.split(c)[1:]!r}) == 0, {c!r}" for c in shell]
    (where / "blocks.py").write_text("\n".join(script) + "\n")
    done = run([sys.executable, "blocks.py"], where)
    assert done.returncode == 0, f"{path.name}: {done.stderr[-2000:]}"


def test_the_commands_in_example_robot_files_run(capsys):
    """A robot.toml under examples/ that shows a command in a comment (``#   stiffness ...``):
    the command runs from the repository root."""
    from stiffness.cli.main import main

    found = 0
    for toml in sorted((ROOT / "examples").glob("*/robot.toml")):
        for line in toml.read_text().splitlines():
            match = re.match(r"#\s+(stiffness [a-z-]+ --.+)$", line)
            if match:
                found += 1
                argv = [str(ROOT / a) if a.startswith("examples/") else a
                        for a in shlex.split(match.group(1))[1:]]
                assert main(argv) == 0, (toml, line, capsys.readouterr().err)
    assert found >= 1


def test_the_slow_skips_are_the_listed_ones():
    found = set()
    for path in DOCS:
        text = path.read_text()
        for match in MARKER.finditer(text):
            if match.group(1) == "skip" and "slow" in (match.group(3) or ""):
                found.add((str(path.relative_to(ROOT)), "slow"))
    assert found == SLOW
