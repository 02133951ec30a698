"""Provenance of a written result: package version, git commit, date, versions, command line.

Foundation layer (imports nothing of the toolkit): any page or JSON a command writes records
where it came from, so that a reader can tell which code produced it and run it again.
"""

from __future__ import annotations

import datetime
import platform
import shlex
import subprocess
import sys
from importlib import metadata
from pathlib import Path

#: Seconds allowed to each ``git`` query (a missing or slow git leaves the commit unknown).
_GIT_TIMEOUT_S = 5.0


def package_version() -> str:
    """The installed ``stiffness`` version, else the one in ``pyproject.toml`` of this checkout."""
    try:
        return metadata.version("stiffness")
    except metadata.PackageNotFoundError:
        pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
        if pyproject.is_file():
            for line in pyproject.read_text().splitlines():
                if line.strip().startswith("version"):
                    return line.split("=", 1)[1].strip().strip("\"'")
        return "unknown"


def _git(*args: str) -> str | None:
    try:
        out = subprocess.run(["git", "-C", str(Path(__file__).resolve().parent), *args],
                             capture_output=True, text=True, timeout=_GIT_TIMEOUT_S, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def git_commit() -> tuple[str | None, bool | None]:
    """``(commit, dirty)`` of the checkout holding this package, ``(None, None)`` outside git."""
    commit = _git("rev-parse", "HEAD")
    if not commit:
        return None, None
    status = _git("status", "--porcelain", "--untracked-files=no")
    return commit, (bool(status) if status is not None else None)


def provenance(command: str | None = None) -> dict:
    """What produced a result.

    Parameters
    ----------
    command
        The command line to record; default this process's (``stiffness`` and its arguments,
        or the Python command line that called the toolkit).

    Returns
    -------
    dict
        ``package_version``, ``git_commit`` (``None`` outside a git checkout), ``git_dirty``
        (uncommitted changes to tracked files), ``date_utc`` (ISO 8601), ``python``,
        ``pinocchio``, ``numpy``, ``platform``, ``command``.
    """
    def version(name: str) -> str:
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            return "not installed"

    if command is None:
        if Path(sys.argv[0]).name == "stiffness":
            command = shlex.join(["stiffness", *sys.argv[1:]])
        else:
            command = "from Python: " + shlex.join(sys.argv)
    commit, dirty = git_commit()
    return {
        "package_version": package_version(),
        "git_commit": commit,
        "git_dirty": dirty,
        "date_utc": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC"),
        "python": platform.python_version(),
        "pinocchio": version("pin"),
        "numpy": version("numpy"),
        "platform": platform.platform(terse=True),
        "command": command,
    }
