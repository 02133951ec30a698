"""Errors the toolkit raises on bad input: each names the problem and the fix."""

from __future__ import annotations


class StiffnessError(ValueError):
    """Bad input (robot, file, configuration, units).

    The message says what is wrong and how to fix it.
    """


class SingularConfigurationError(StiffnessError):
    """A Jacobian or a tangent stiffness is singular where an inverse is needed."""


def did_you_mean(name: str, valid: list[str] | tuple[str, ...], limit: int = 40) -> str:
    """Text listing the valid names (up to ``limit``), closest matches first when there are many."""
    import difflib

    close = difflib.get_close_matches(name, list(valid), n=3)
    listed = ", ".join(list(valid)[:limit]) + (" ..." if len(valid) > limit else "")
    hint = f" Did you mean {', '.join(close)}?" if close else ""
    return f"valid names: {listed}.{hint}"


class RobotFileError(StiffnessError):
    """A robot file (URDF, loop declaration) that cannot be read: path, line (or None), problem."""

    def __init__(self, path, line: int | None, problem: str) -> None:
        self.path, self.line, self.problem = str(path), line, problem
        where = f"{path}:{line}" if line is not None else f"{path}"
        super().__init__(f"{where}: {problem}")


class LoopClosureError(StiffnessError):
    """A kinematic loop that does not close: ``loop`` names it, ``residual`` is in m (rad)."""

    def __init__(self, message: str, loop: str | None = None, residual: float | None = None
                 ) -> None:
        self.loop, self.residual = loop, residual
        super().__init__(message)


class UndeterminedMotionError(SingularConfigurationError):
    """The target moves with a passive motion that the loop constraints leave undetermined."""


class FloatingBaseError(StiffnessError):
    """A floating or planar base that was not fixed (``--fixed-base`` / ``fixed_base=True``)."""


class RobotFileWarning(UserWarning):
    """Something in a robot file that the toolkit ignores or reads in its own way (one warning
    per thing)."""
