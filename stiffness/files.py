"""Atomic file output: a reader never sees a half-written file, and a failure loses nothing.

Every output of the toolkit goes through :func:`atomic_write_with`: the data is written to a
temporary file beside the target (``.<name>.<pid>.<random>.tmp``), flushed to disk, then
renamed over the target. A process killed mid-write leaves the target as it was (absent or the
previous complete version) plus at most its temporary file, which the next write of the same
target removes once its writing process is gone. A write that fails (a full disk, a read-only
folder, ``--out`` naming an existing file) removes its temporary file and raises
:class:`~stiffness.errors.OutputError` with one line naming the path and the fix.
"""

from __future__ import annotations

import errno
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

from stiffness.errors import OutputError

#: What to do about each kind of write failure.
_FIXES = {
    errno.ENOSPC: "free some space or choose another output folder",
    errno.EDQUOT: "free some space or choose another output folder",
    errno.EFBIG: "the file is over this process's size limit; choose another output folder",
    errno.EROFS: "the file system is read-only; choose another output folder",
    errno.EACCES: "the folder is not writable; choose another output folder",
    errno.EPERM: "the folder is not writable; choose another output folder",
    errno.EEXIST: "a file stands where a folder is needed; remove it or choose another path",
    errno.ENOTDIR: "a file stands where a folder is needed; remove it or choose another path",
    errno.EISDIR: "a folder stands where the file is to be written; choose another path",
}


def _output_error(path: Path, exc: OSError) -> OutputError:
    fix = _FIXES.get(exc.errno or -1, "check the path and the disk")
    return OutputError(f"cannot write {path}: {exc.strerror or exc}; {fix}", path=path)


def output_folder(path: str | os.PathLike, create: bool = True) -> Path:
    """Check (and with ``create``, make) the folder ``path`` for outputs.

    With ``create=False`` nothing is made: the check a command runs before its work, so a
    bad ``--out`` fails at once and a refused run leaves no folder behind.

    Raises
    ------
    OutputError
        ``path`` or one of its parents is an existing file, or the folder cannot be created
        or written.
    """
    path = Path(path)
    existing = path
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        what = "it is" if existing == path else f"{existing} is"
        raise OutputError(f"cannot write into {path}: {what} a file, not a folder; remove it "
                          f"or choose another output folder", path=path)
    if not os.access(existing, os.W_OK | os.X_OK):
        raise OutputError(f"cannot write into {path}: {existing} is not writable; choose "
                          f"another output folder", path=path)
    if create:
        try:
            path.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise _output_error(path, exc) from exc
    return path


def _remove_stale_temporaries(path: Path) -> None:
    """Remove temporary files of ``path`` left by writers that no longer run (killed)."""
    for stale in path.parent.glob(f".{path.name}.*.tmp"):
        parts = stale.name[len(path.name) + 2:].split(".")
        if not parts or not parts[0].isdigit():
            continue
        pid = int(parts[0])
        if pid == os.getpid():
            continue
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            stale.unlink(missing_ok=True)
        except PermissionError:
            continue  # another user's live process


def atomic_write_with(path: str | os.PathLike, write: Callable[[BinaryIO], object]) -> Path:
    """Write through ``write(binary_file)`` into a temporary file beside ``path``, then rename.

    The file keeps the mode of the file it replaces (else ``rw-r--r--``); on any error the
    temporary file is removed and ``path`` is left as it was.

    Raises
    ------
    OutputError
        The file cannot be written (full disk, read-only folder, a file where the folder
        should be); nothing is left half-written.
    """
    path = Path(path)
    output_folder(path.parent)
    _remove_stale_temporaries(path)
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.{os.getpid()}.",
                                   suffix=".tmp")
    except OSError as exc:
        raise _output_error(path, exc) from exc
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, path.stat().st_mode & 0o777 if path.exists() else 0o644)
        os.replace(tmp, path)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        raise _output_error(path, exc) from exc
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def atomic_write(path: str | os.PathLike, data: bytes | str) -> Path:
    """Write ``data`` (text is UTF-8 encoded, newlines kept as given) atomically to ``path``."""
    payload = data.encode("utf-8") if isinstance(data, str) else data
    return atomic_write_with(path, lambda f: f.write(payload))
