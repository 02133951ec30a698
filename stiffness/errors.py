"""Errors the toolkit raises on bad input: each names the problem and the fix in one line.

Every error is a :class:`StiffnessError` (a :class:`ValueError`, so older ``except ValueError``
code keeps working); the subclasses say what went wrong and carry what a program needs to react:

* :class:`UnknownNameError` (:class:`UnknownRobotError`, :class:`UnknownFrameError`,
  :class:`UnknownJointError`, :class:`UnknownEffectError`): ``name`` and the valid ``choices``;
* :class:`MissingFileError`: ``path``;
* :class:`FileFormatError`: ``path``, ``line`` and ``column`` (1-based, None when unknown);
* :class:`SingularConfigurationError`: a Jacobian or tangent stiffness that must be inverted is
  singular;
* :class:`RobotFileError` (a :class:`FileFormatError`): a URDF or loop file that cannot be read;
* :class:`LoopClosureError`: a kinematic loop cannot be closed at the given coordinates
  (``loop`` and ``residual`` when known);
* :class:`UndeterminedMotionError` (a :class:`SingularConfigurationError`): the target moves
  with a passive motion the loops leave free;
* :class:`FloatingBaseError`: a floating or planar base that ``--fixed-base`` would fix;
* :class:`ConvergenceError`: an iterative solver did not converge;
* :class:`UnstableEquilibriumError`: the load buckles the robot (K_theta - K_C not positive
  definite at the equilibrium).

Warnings: :class:`RobotFileWarning` (its :class:`RobotFileNote` a note, silent under the
command line's ``--quiet``), :class:`DataFileWarning` (its :class:`DataFileNote`,
:class:`UnknownColumnWarning`), :class:`FlagValueWarning`.

The command line turns each into exit status 2 and one line on stderr.
"""

from __future__ import annotations

import copy
import os
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path


def _restore(cls: type[BaseException], args: tuple, state: dict) -> BaseException:
    """Rebuild a pickled error (keyword-only attributes survive Dask and multiprocessing)."""
    exc = cls.__new__(cls)
    exc.args = args
    exc.__dict__.update(state)
    return exc


class StiffnessError(ValueError):
    """Bad input (robot, file, configuration, units, flag value).

    The message says what is wrong and how to fix it, on one line.
    """

    def __reduce__(self):  # noqa: D105
        return _restore, (type(self), self.args, dict(self.__dict__))


class UnknownNameError(StiffnessError):
    """A name (robot, frame, joint, effect...) that is not among the valid ones.

    Attributes
    ----------
    kind : str
        What was named ("robot", "frame", "joint", "effect", or "name").
    name : str
        The name given.
    choices : tuple of str
        The valid names.
    """

    kind = "name"

    def __init__(self, message: str, *, name: str, choices: Sequence[str]) -> None:
        super().__init__(message)
        self.name = str(name)
        self.choices = tuple(str(c) for c in choices)


class UnknownRobotError(UnknownNameError):
    """A robot that is neither shipped, nor an example-robot-data name, nor a URDF file."""

    kind = "robot"


class UnknownFrameError(UnknownNameError):
    """A frame the robot model does not have."""

    kind = "frame"


class UnknownJointError(UnknownNameError):
    """A joint (or coordinate) the robot does not have, or not of the kind required."""

    kind = "joint"


class UnknownEffectError(UnknownNameError):
    """An effect that is not in the effect library."""

    kind = "effect"


class MissingFileError(StiffnessError):
    """A file or folder that does not exist or cannot be read.

    Attributes
    ----------
    path : pathlib.Path
    """

    def __init__(self, message: str, *, path: str | os.PathLike[str]) -> None:
        super().__init__(message)
        self.path = Path(path)


class OutputError(StiffnessError):
    """An output that cannot be written (full disk, read-only folder, a file where a folder goes).

    Attributes
    ----------
    path : pathlib.Path
        The file or folder that could not be written.
    """

    def __init__(self, message: str, *, path: str | os.PathLike[str]) -> None:
        super().__init__(message)
        self.path = Path(path)


class FileFormatError(StiffnessError):
    """A file whose content is malformed; the message starts with where.

    Parameters
    ----------
    problem : str
        What is wrong and how to fix it (without the location).
    path : str or Path
        The file.
    line, column : int, optional
        1-based position of the problem, when known.
    field : str, optional
        Name of the field at that position (a CSV column, a TOML key).

    The message is ``"<path>, line L, column C (field): <problem>"`` (the known parts only).
    """

    def __init__(self, problem: str, *, path: str | os.PathLike[str], line: int | None = None,
                 column: int | None = None, field: str | None = None) -> None:
        where = str(path)
        if line is not None:
            where += f", line {line}"
        if column is not None:
            where += f", column {column}"
        if field is not None:
            where += f" ({field})"
        super().__init__(f"{where}: {problem}")
        self.path = Path(path)
        self.line = line
        self.column = column
        self.field = field
        self.problem = problem


class SingularConfigurationError(StiffnessError):
    """A Jacobian or a tangent stiffness is singular where an inverse is needed."""


class LoopClosureError(StiffnessError):
    """The kinematic loops cannot be closed at the given coordinates (out of reach, or branch).

    Attributes
    ----------
    loop : str or None
        The loop that cannot close (``[frame_a, frame_b]``), when known.
    residual : float or None
        Its residual (m; rad for 6D rotation rows), when known.
    """

    def __init__(self, message: str, loop: str | None = None, residual: float | None = None
                 ) -> None:
        super().__init__(message)
        self.loop = loop
        self.residual = residual


class ConvergenceError(StiffnessError):
    """An iterative solver (equilibrium, inverse kinematics, fit) did not converge."""


class TooFewMeasurementsError(StiffnessError):
    """A fit with at least as many identifiable parameters as measured components: the data do
    not determine it (measure more poses or rows)."""


class UnstableEquilibriumError(StiffnessError):
    """The load buckles the robot: the equilibrium is unstable or the tangent stiffness singular."""


def with_context(exc: StiffnessError, context: str) -> StiffnessError:
    """A copy of ``exc``, of the same type and attributes, its message prefixed by ``context``.

    For re-raising an error with where it happened (``raise with_context(exc, row) from exc``)
    without losing its type.
    """
    out = copy.copy(exc)
    out.args = (f"{context}: {exc}", *exc.args[1:])
    return out


def given(value: object) -> str:
    """How a wrong argument is named in a message: its type, and its value (shortened) or its
    shape (an array)."""
    kind, shape = type(value).__name__, getattr(value, "shape", None)
    if isinstance(shape, tuple) and (len(shape) > 1 or getattr(value, "size", 13) > 12):
        return f"{kind} of shape {shape}"
    text = repr(value.tolist() if isinstance(shape, tuple) else value)  # type: ignore[attr-defined]
    return f"{kind} {text if len(text) <= 60 else text[:57] + '...'}"


def wrong_argument(name: str, value: object, needed: str, prefix: str = "") -> StiffnessError:
    """The error of a Python API argument of the wrong type, size or value, in one line:
    ``"<name> must be <prefix><needed>, got <given(value)>"``."""
    return StiffnessError(f"{name} must be {prefix}{needed}, got {given(value)}")


def did_you_mean(name: str, valid: list[str] | tuple[str, ...], limit: int = 40) -> str:
    """Text listing the valid names (up to ``limit``), closest matches first when there are many."""
    import difflib

    close = difflib.get_close_matches(name, list(valid), n=3)
    listed = ", ".join(list(valid)[:limit]) + (" ..." if len(valid) > limit else "")
    hint = f" Did you mean {', '.join(close)}?" if close else ""
    return f"valid names: {listed}.{hint}"


class RobotFileError(FileFormatError):
    """A robot file (URDF, loop declaration) that cannot be read: ``path``, ``line`` (or None)
    and ``problem``, in :class:`FileFormatError`'s one-line form."""

    def __init__(self, path: str | os.PathLike[str], line: int | None, problem: str,
                 column: int | None = None) -> None:
        super().__init__(problem, path=path, line=line, column=column)


class UndeterminedMotionError(SingularConfigurationError):
    """The target moves with a passive motion that the loop constraints leave undetermined."""


class FloatingBaseError(StiffnessError):
    """A floating or planar base that was not fixed (``--fixed-base`` / ``fixed_base=True``)."""


class RobotFileWarning(UserWarning):
    """Something in a robot file that the toolkit ignores or reads in its own way (one warning
    per thing)."""


class RobotFileNote(RobotFileWarning):
    """What reading a robot file did its own way that the user should hear once, though the
    robot loads as the file means it: joints whose ``<limit>`` gives no bounds taken as
    unbounded, an XML declaration's version ignored, visuals Pinocchio cannot read (statics do
    not use them). The command line prints it as a note, and not at all under ``--quiet``."""


class DataFileWarning(UserWarning):
    """Something in a campaign, plan, path or model file that is read, but may not be what the
    user meant: a plan that declares no units, coordinates beyond the joint limits, a model
    stiffness marked undetermined."""


class FlagValueWarning(UserWarning):
    """A flag's value that is read, but may not be what the user meant: a noise std in the
    files' length unit (``--noise``) that is no rig's, finer than 10 nm or coarser than 1 cm."""


class DataFileNote(DataFileWarning):
    """What reading a campaign did that the user should hear once, though nothing is wrong:
    coordinates without a column held at fixed or reference values."""


class UnknownColumnWarning(DataFileWarning):
    """Campaign CSV columns no reader knows (a rig's bookkeeping), ignored; the command line's
    ``--strict`` refuses them."""


def warn_user(message: str, category: type[Warning]) -> None:
    """:func:`warnings.warn` pointed at the first caller outside this package (the user's
    line, whatever the depth of the calls inside the package; the outermost frame when there
    is none, as on the command line)."""
    package = os.path.dirname(os.path.abspath(__file__)) + os.sep
    frame, level = sys._getframe(1), 2  # the function that warns: stacklevel 2 from here
    while frame.f_back is not None and os.path.abspath(frame.f_code.co_filename).startswith(
            package):
        frame, level = frame.f_back, level + 1
    warnings.warn(message, category, stacklevel=level)
