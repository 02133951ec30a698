"""Files in and out: typed errors on reading, atomic output.

Reading (:func:`read_text`, :func:`read_toml`, :func:`read_json`, :func:`read_yaml`): a file that
is missing or unreadable raises :class:`~stiffness.errors.MissingFileError`, one whose syntax is
broken a :class:`~stiffness.errors.FileFormatError` with its line and column, each with a
one-line message naming the file, the problem and the fix.

Writing (:func:`atomic_write`, :func:`atomic_write_with`, :func:`output_folder`,
:func:`staged_folder`): a reader never sees a half-written file, and a failure loses nothing.
The data is written to a temporary file beside the target (``.<name>.<pid>.<random>.tmp``),
flushed to disk, then renamed over the target. A process killed mid-write leaves the target as
it was (absent or the previous complete version) plus at most its temporary file, which the
next write of the same target removes once its writing process is gone. A write that fails (a
full disk, a read-only folder, ``--out`` naming an existing file) removes its temporary file
and raises :class:`~stiffness.errors.OutputError` with one line naming the path and the fix.

A command that writes a folder (a report, a diagnosis, a campaign, a plan, a scan) builds it
in a staging folder beside the target (``.<name>.<pid>.<random>.staging``) and publishes it by
one rename (:func:`staged_folder`); an existing target is first renamed aside
(``.<name>.<pid>.<random>.aside``) and removed after. Killed at any point, the target is absent,
or the complete previous folder, or the complete new one, never a mix. The next run for the same
target sweeps what dead processes left: their staging folders are removed (a resumable scan
adopts one instead) and an aside folder is put back when the target is absent (killed between
the two renames), else removed.

Fault injection (tests only): with ``STIFFNESS_KILL_AT_RENAME=N`` in the environment, the
process kills itself with SIGKILL just before the N-th rename this module makes (1-based,
counting atomic writes and folder publications), so a test can stop a command at each of them.
"""

from __future__ import annotations

import contextlib
import csv
import errno
import json
import math
import os
import re
import shutil
import signal
import sys
import tempfile
from collections.abc import Callable, Collection, Iterator
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from stiffness.errors import FileFormatError, MissingFileError, OutputError
from stiffness.units import plain_float

#: Where tomllib (and tomli) put the position in their messages.
_TOML_POSITION = re.compile(r"\s*\(at line (\d+), column (\d+)\)")


def number_text(value: float) -> str:
    """A number as a user file writes it: the shortest text that reads back the value rounded
    to 15 significant digits, so a unit conversion's last-bit noise (0.1201274 m written in mm
    as ``120.12740000000001``) is not written; ``-0.0`` is written ``0.0``. 15 digits keep
    every measured digit (a float's round-off is 1e-16 relative)."""
    rounded = float(f"{float(value):.15g}")
    return repr(rounded + 0.0)  # + 0.0 turns -0.0 into 0.0


def read_text(path: str | os.PathLike[str], what: str = "file") -> str:
    """The UTF-8 text of ``path`` (``what`` names the file in the error, e.g. "campaign file"),
    without the byte-order mark that spreadsheets and some editors put at its start.

    Raises
    ------
    MissingFileError
        If the file does not exist or cannot be read.
    FileFormatError
        If it is not UTF-8 text.
    """
    path = Path(path)
    try:
        return path.read_text(encoding="utf-8").removeprefix("\ufeff")
    except FileNotFoundError:
        raise MissingFileError(f"cannot read {what} {path}: no such file; check the path",
                               path=path) from None
    except IsADirectoryError:
        raise MissingFileError(f"{what} {path} is a folder, not a file; give the file",
                               path=path) from None
    except OSError as exc:
        raise MissingFileError(f"cannot read {what} {path}: {exc.strerror}; check its "
                               "permissions", path=path) from exc
    except UnicodeDecodeError as exc:
        if path.read_bytes()[:2] in (b"\xff\xfe", b"\xfe\xff"):
            raise FileFormatError(f"UTF-16 text (a spreadsheet's 'Unicode text'); save the "
                                  f"{what} as UTF-8 (a spreadsheet's 'CSV UTF-8')",
                                  path=path) from exc
        raise FileFormatError(f"not UTF-8 text (byte {exc.start}); save the {what} as UTF-8",
                              path=path) from exc


def csv_float(cell: str) -> float:
    """The number a CSV cell holds (surrounding spaces ignored), read as written
    (:func:`stiffness.units.plain_float`: no ``1_000``).

    Raises
    ------
    ValueError
        The cell is not a plain decimal number; the message names the cell and, for digit
        separators (``1_000``, which ``float`` would read as 1000), the fix.
    """
    return plain_float(cell, "a CSV number")


def csv_cells(line: str, path: str | os.PathLike[str], number: int,
              separator: str = ",") -> list[str]:
    """The cells of one line of a CSV file (``number``: its 1-based line), as the files'
    readers take them a line at a time (a quote opened in a cell closes at the line's end);
    ``separator`` another than the comma (a rig file's ``;`` or tab).

    Raises
    ------
    FileFormatError
        The line is not CSV to Python's reader (a cell over its 128 KiB limit).
    """
    try:
        return next(csv.reader([line], delimiter=separator), [])
    except csv.Error as exc:
        raise FileFormatError(f"not CSV ({exc}); write one row per line, cells separated by "
                              "commas", path=path, line=number) from exc


def check_csv_header(cells: list[str], path: str | os.PathLike[str], line: int) -> None:
    """Refuse a CSV header that is one cell holding semicolons or tabs: a file written with
    another separator (a spreadsheet's ``;`` with decimal commas, a tab-separated export),
    whose every line would otherwise read as one column.

    Raises
    ------
    FileFormatError
        The header is one cell with ``;`` or a tab in it.
    """
    if len(cells) == 1:
        for separator, name in ((";", "';'"), ("\t", "tabs")):
            if separator in cells[0]:
                raise FileFormatError(f"the columns are separated by {name}, not commas; write "
                                      "the file as CSV with commas (and '.' as the decimal "
                                      "point)", path=path, line=line, column=1)


def read_toml(path: str | os.PathLike[str], what: str = "TOML file") -> dict[str, Any]:
    """The table of a TOML file; syntax errors carry their line and column."""
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # Python 3.10: the tomli backport has the same API
        import tomli as tomllib

    text = read_text(path, what)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        message = str(exc)
        where = _TOML_POSITION.search(message)
        problem = _TOML_POSITION.sub("", message)
        raise FileFormatError(
            f"the file is not valid TOML ({problem}); fix the syntax there", path=path,
            line=int(where.group(1)) if where else None,
            column=int(where.group(2)) if where else None) from exc


def read_json(path: str | os.PathLike[str], what: str = "JSON file") -> Any:
    """The content of a JSON file; syntax errors carry their line and column."""
    text = read_text(path, what)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise FileFormatError(f"the file is not JSON ({exc.msg}); fix the syntax there",
                              path=path, line=exc.lineno, column=exc.colno) from exc


def read_yaml(path: str | os.PathLike[str], what: str = "YAML file") -> Any:
    """The content of a YAML file; syntax errors carry their line and column."""
    import yaml

    text = read_text(path, what)
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = " ".join(str(getattr(exc, "problem", None) or exc).split())
        raise FileFormatError(
            f"the file is not valid YAML ({problem}); fix the syntax there", path=path,
            line=None if mark is None else mark.line + 1,
            column=None if mark is None else mark.column + 1) from exc


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


def output_folder(path: str | os.PathLike[str], create: bool = True) -> Path:
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


#: Folders whose stale temporary files this process has removed (:func:`_remove_stale_temporaries`).
_SWEPT_FOLDERS: set[Path] = set()


def _remove_stale_temporaries(folder: Path) -> None:
    """Remove the temporary files in ``folder`` left by writers that no longer run (killed),
    once per folder and process: a scan writes thousands of files into one folder, and
    listing it at every write would cost time growing with the files already written."""
    if folder in _SWEPT_FOLDERS:
        return
    _SWEPT_FOLDERS.add(folder)
    for stale in folder.glob(".*.tmp"):
        parts = stale.name[: -len(".tmp")].rsplit(".", 2)  # .<name>.<pid>.<random>
        if len(parts) != 3 or not parts[1].isdigit():
            continue
        pid = int(parts[1])
        if pid == os.getpid():
            continue
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            stale.unlink(missing_ok=True)
        except PermissionError:
            continue  # another user's live process


def atomic_write_with(path: str | os.PathLike[str], write: Callable[[BinaryIO], object]) -> Path:
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
    _remove_stale_temporaries(path.parent)
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
        _rename(tmp, path)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        raise _output_error(path, exc) from exc
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def atomic_write(path: str | os.PathLike[str], data: bytes | str) -> Path:
    """Write ``data`` (text is UTF-8 encoded, newlines kept as given) atomically to ``path``."""
    payload = data.encode("utf-8") if isinstance(data, str) else data
    return atomic_write_with(path, lambda f: f.write(payload))


#: Renames made by this process (the count :data:`KILL_AT_RENAME` compares with).
_RENAMES = [0]
#: Environment variable of the fault-injection hook (see the module docstring).
KILL_AT_RENAME = "STIFFNESS_KILL_AT_RENAME"


def _rename(source: str | os.PathLike[str], target: str | os.PathLike[str]) -> None:
    """:func:`os.replace`, counted for the fault-injection hook."""
    _RENAMES[0] += 1
    if os.environ.get(KILL_AT_RENAME) == str(_RENAMES[0]):
        os.kill(os.getpid(), signal.SIGKILL)
    os.replace(source, target)


#: Suffixes of the folders :func:`staged_folder` makes beside its target.
_STAGING, _ASIDE = ".staging", ".aside"


def _leftovers(target: Path, suffix: str) -> list[tuple[Path, int]]:
    """Folders ``.<target name>.<pid>.<random><suffix>`` beside ``target`` and their pids."""
    out = []
    prefix = f".{target.name}."
    for path in target.parent.iterdir():
        if not (path.name.startswith(prefix) and path.name.endswith(suffix)):
            continue
        parts = path.name[len(prefix): -len(suffix)].split(".")
        if len(parts) == 2 and parts[0].isdigit() and path.is_dir():
            out.append((path, int(parts[0])))
    return out


def _dead(pid: int) -> bool:
    """Whether no process ``pid`` runs (another user's live process counts as running)."""
    if pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        return False
    return False


def _sweep(target: Path, resume: bool) -> Path | None:
    """Clean what dead processes left beside ``target``; return a staging folder to resume
    (with ``resume``), else None."""
    for aside, pid in _leftovers(target, _ASIDE):
        if _dead(pid):
            if not target.exists():
                os.replace(aside, target)  # killed between its two renames: put it back
            else:
                shutil.rmtree(aside, ignore_errors=True)
    adopted = None
    stagings = sorted(_leftovers(target, _STAGING), key=lambda s: -s[0].stat().st_mtime)
    for staging, pid in stagings:
        if not (_dead(pid) or (resume and pid == os.getpid())):
            continue
        if resume and adopted is None:
            adopted = staging
        else:
            shutil.rmtree(staging, ignore_errors=True)
    return adopted


def _hidden_name(target: Path, suffix: str) -> Path:
    return target.parent / f".{target.name}.{os.getpid()}.{os.urandom(4).hex()}{suffix}"


def _refuse_enclosing(target: Path) -> None:
    """Refuse to replace the working folder or one enclosing it."""
    here = Path.cwd().resolve()
    if target.exists() and (target.resolve() == here or target.resolve() in here.parents):
        raise OutputError(f"cannot write the output folder {target}: it is the working folder "
                          "or encloses it, and publishing replaces it whole; give a new folder",
                          path=target)


#: Names of files of other kinds, which an output folder's name does not end with (``--out
#: report.html`` made a folder named ``report.html``).
FILE_SUFFIXES = (".json", ".toml", ".txt", ".csv", ".tsv", ".xlsx", ".xls", ".dat", ".html",
                 ".png", ".npz", ".parquet", ".urdf", ".xml", ".yaml")


def check_folder_name(target: str | os.PathLike[str]) -> None:
    """Refuse an output folder named like a file (``report.html``, ``maps.npz``) that is not
    already a folder: the command writes a folder there, not that file.

    Raises
    ------
    OutputError
        Naming the folder the command would make instead.
    """
    target = Path(target)
    if target.suffix.lower() in FILE_SUFFIXES and not target.is_dir():
        raise OutputError(f"--out {target}: this command writes a folder (several files), not "
                          f"a {target.suffix} file; give a folder name, e.g. --out "
                          f"{target.with_suffix('')}", path=target)


def refuse_foreign_folder(target: str | os.PathLike[str], marker: str, what: str,
                          writes: Collection[str] | None = None) -> None:
    """Refuse to write the folder ``target`` over files that are not a previous ``what``.

    A folder publisher replaces ``target`` (whole, or with ``writes`` only the files of those
    names): over a campaign folder given as ``--out`` by mistake it would delete or overwrite
    the measurements. ``target`` is taken for a previous output when it holds ``marker`` (a
    file every such output has), or when it is missing or empty.

    Raises
    ------
    OutputError
        ``target`` holds files without ``marker`` that the write would delete (``writes``
        None) or overwrite (those among ``writes``).
    """
    target = Path(target)
    if not target.is_dir():
        return
    names = sorted(p.name for p in target.iterdir()
                   if not (p.name.startswith(".") and p.name.endswith(".tmp")))
    if marker in names:
        return
    lost = names if writes is None else [n for n in names if n in writes]
    if lost:
        shown = ", ".join(lost[:3]) + (f" and {len(lost) - 3} more" if len(lost) > 3 else "")
        verb = "delete" if writes is None else "overwrite"
        raise OutputError(f"{target} is not a previous {what} (it has no {marker}) and holds "
                          f"{shown}, which writing the {what} there would {verb}; choose a new "
                          "or empty folder", path=target)


@contextlib.contextmanager
def staged_folder(target: str | os.PathLike[str], resume: bool = False,
                  keep_others: bool = False) -> Iterator[Path]:
    """Build the folder ``target`` in a staging folder beside it, then publish it by one rename.

    Yields the staging folder to write into. When the block ends normally, an existing
    ``target`` is renamed aside, the staging folder renamed to ``target`` and the old folder
    removed; when it raises, the staging folder is removed and ``target`` is left as it was.
    Inside another ``staged_folder`` of the same process (``target`` is a staging folder
    being built) it yields ``target`` itself. See the module docstring for what a kill leaves.

    Parameters
    ----------
    resume
        Start from what is there (a resumable scan): a staging folder for ``target`` left by
        a dead process (or by a failed build of this one) is adopted, else the files of an
        existing ``target`` are linked (or copied) into the new staging folder; a build that
        fails keeps its staging folder for the next run to continue.
    keep_others
        Keep the files of an existing ``target`` that the new folder does not write (a
        campaign folder may hold the robot's URDF or the rig's files): they are linked into
        the staging folder before it is published.

    Raises
    ------
    OutputError
        ``target`` or a parent is a file, the folder is not writable, or ``target`` is the
        working folder or encloses it.
    """
    target = Path(target)
    if target.name.endswith(_STAGING) and f".{os.getpid()}." in target.name:
        yield target
        return
    output_folder(target, create=False)
    check_folder_name(target)
    _refuse_enclosing(target)
    output_folder(target.parent)
    adopted = _sweep(target, resume)
    staging = _hidden_name(target, _STAGING)
    try:
        if adopted is not None:
            os.replace(adopted, staging)
        elif resume and target.is_dir():
            shutil.copytree(target, staging, copy_function=_link_or_copy)
        else:
            staging.mkdir()
    except OSError as exc:
        raise _output_error(staging, exc) from exc
    try:
        yield staging
    except OutputError as exc:  # named where the user looks: the target, not the staging
        if not resume:
            shutil.rmtree(staging, ignore_errors=True)
        raise OutputError(str(exc).replace(str(staging), str(target)),
                          path=str(exc.path).replace(str(staging), str(target))) from exc
    except BaseException:
        if not resume:  # a resumable build is kept for the next run to continue
            shutil.rmtree(staging, ignore_errors=True)
        raise
    if keep_others and target.is_dir():
        _carry_over(target, staging)
    if target.is_dir():
        _keep_modes(target, staging)
    _publish(staging, target)


def _keep_modes(target: Path, staging: Path) -> None:
    """Give each rewritten file the permissions its old copy in ``target`` had (as
    :func:`atomic_write` does for one file): a user's ``chmod`` survives the command."""
    for old in target.rglob("*"):
        new = staging / old.relative_to(target)
        if old.is_file() and new.is_file() and not old.is_symlink():
            try:
                shutil.copymode(old, new)
            except OSError:
                continue  # a mode that cannot be set is no reason to lose the output


def _carry_over(old: Path, new: Path) -> None:
    """Link (or copy) into ``new`` the files of ``old`` that ``new`` does not have."""
    for path in old.rglob("*"):
        there = new / path.relative_to(old)
        if path.is_file() and not path.name.endswith(".tmp") and not there.exists():
            there.parent.mkdir(parents=True, exist_ok=True)
            _link_or_copy(str(path), str(there))


def _link_or_copy(source: str, destination: str) -> None:
    """A hard link of ``source`` at ``destination``, or a copy where links are not possible
    (files are replaced by rename, never rewritten in place, so a link shares nothing that
    changes)."""
    try:
        os.link(source, destination)
    except OSError:
        shutil.copy2(source, destination)


def _publish(staging: Path, target: Path) -> None:
    """Rename ``staging`` to ``target``, an existing ``target`` moved aside first."""
    aside = None
    try:
        if target.exists():
            aside = _hidden_name(target, _ASIDE)
            _rename(target, aside)
        _rename(staging, target)
    except OSError as exc:
        if aside is not None and not target.exists():
            os.replace(aside, target)
        shutil.rmtree(staging, ignore_errors=True)
        raise _output_error(target, exc) from exc
    if aside is not None:
        shutil.rmtree(aside, ignore_errors=True)


# ------------------------------------------------------------------------------------------
# paths written into user files


def looks_like_path(source: str) -> bool:
    return (Path(source).suffix.lower() in (".urdf", ".xml", ".toml") or "/" in source
            or os.sep in source or Path(source).is_absolute())


def _posix_separators(path: str, folder: Path) -> str:
    """``path`` as written in a file in ``folder``, with Windows separators (a relative
    ``..\\robot\\arm.urdf`` written on Windows) read as ``/`` where the path as written names
    nothing and the other does (on Windows, and where it names a file, as it is)."""
    if os.sep == "\\" or "\\" not in path or (folder / path).exists():
        return path
    other = path.replace("\\", "/")
    return other if (folder / other).exists() else path


def resolve_path(path: str, folder: Path) -> str:
    """A file path of a campaign (``loops``): absolute as is, else relative to ``folder``
    (Windows separators read as ``/``: :func:`_posix_separators`)."""
    path = _posix_separators(path, folder)
    return path if Path(path).is_absolute() else str(folder / path)


def written_path(path: str | os.PathLike[str], folder: Path, base: Path | None = None) -> str:
    """A path as written into a file in ``folder``: relative to ``folder`` (POSIX separators;
    absolute on another drive), so that the file and what it names travel together. A relative
    ``path`` is taken relative to ``base`` (default the working directory), where it was given.
    Readers resolve it against the file's folder (:func:`resolve_path`, :func:`resolve_source`).
    """
    resolved = Path(base or Path.cwd()) / path
    try:
        written = os.path.relpath(resolved.resolve(), folder.resolve())
    except ValueError:  # another drive on Windows
        written = str(resolved.resolve())
    return Path(written).as_posix()


def written_source(source: str, folder: Path, base: Path | None = None) -> str:
    """A robot source as written into a file in ``folder``: a robot name as is, a path by
    :func:`written_path` (relative to ``base``, default the working directory)."""
    return written_path(source, folder, base) if looks_like_path(source) else source


def resolve_source(source: str, folder: Path) -> str:
    """A robot name as is; a relative URDF path made absolute against ``folder`` (Windows
    separators read as ``/``: :func:`_posix_separators`)."""
    source = _posix_separators(source, folder)
    if looks_like_path(source) and not Path(source).is_absolute():
        return str((folder / source).resolve())
    return source


def jsonable(value):
    """JSON-ready: arrays to lists, numpy scalars to Python, non-finite floats to None,
    recursively."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, np.bool_ | bool):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    return value
