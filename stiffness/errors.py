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


class OutputError(StiffnessError):
    """An output cannot be written (full disk, read-only folder, a file where a folder goes).

    Attributes
    ----------
    path
        The file or folder that could not be written.
    """

    def __init__(self, message: str, path: object = None) -> None:
        super().__init__(message)
        self.path = path
