"""Unit names of user files and flags, and their factors to SI (rad, N, m, N.m); how a user
writes a number (a CSV cell, a flag's value) and how large it may be."""

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TypeGuard

import numpy as np

from stiffness.errors import UnknownNameError, wrong_argument

#: Unit name -> factor to SI (rad, N, m).
ANGLE_UNITS = {"deg": math.pi / 180.0, "rad": 1.0}
FORCE_UNITS = {"N": 1.0, "kN": 1e3}
LENGTH_UNITS = {"mm": 1e-3, "m": 1.0, "cm": 1e-2, "um": 1e-6}
#: Largest magnitude of a number a user gives (a CSV cell, in the file's units; a flag value, in
#: its unit): far beyond any measurement or setting in any supported unit (1e12 um is 1e6 m),
#: and small enough that products of squares stay finite.
MAX_CELL = 1e12


#: A number as a rig, a spreadsheet or a person writes it: an optional sign, decimal digits with
#: at most one point, an optional exponent (or nan, inf, which the readers refuse as not finite,
#: by name). Python's ``float`` and ``int`` read more: ``1_000`` (1000), other scripts' digits.
_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?"
                     r"|[+-]?(?:nan|inf|infinity)", re.IGNORECASE)
#: An integer as a person writes it: an optional sign and decimal digits.
_INTEGER = re.compile(r"[+-]?[0-9]+")
#: What holds a flag's number (``--kq``, ``--effect``...), in :func:`plain_float`'s messages.
FLAG_NUMBER = "a command-line number"


def plain_float(text: str, where: str) -> float:
    """The number ``text`` holds (surrounding spaces ignored), read as written: the one rule of
    the CSV readers (:func:`stiffness.files.csv_float`) and the command line's number flags.

    Parameters
    ----------
    where
        What holds the number, for the message: ``"a CSV number"``, ``"a flag's number"``.

    Raises
    ------
    ValueError
        ``text`` is not a plain decimal number; the message names it and, for digit separators
        (``1_000``, which ``float`` would read as 1000), the fix.
    """
    return float(_plain(text, _NUMBER, where, "a number"))


def plain_int(text: str, where: str) -> int:
    """The integer ``text`` holds (surrounding spaces ignored): optional sign and decimal
    digits, as :func:`plain_float` reads numbers (no ``1_000``, which ``int`` reads as 1000).

    Raises
    ------
    ValueError
        ``text`` is not a plain integer; the message names it and, for digit separators, the fix.
    """
    return int(_plain(text, _INTEGER, where, "an integer"))


class NumberSpellingError(ValueError):
    """A number written in a way the readers do not take, whose intended value is plain: the
    message names the spelling and the fix (``1_000``: write 1000; ``−5`` with a typographic
    minus, U+2212 or a dash, as copied from a PDF or a word processor: write -5). The readers
    pass this message on; any other :class:`ValueError` of :func:`plain_float` is a cell that
    is no number."""


#: Minus signs and dashes a number copied from a PDF, a word processor or a web page carries
#: in place of the ASCII hyphen-minus.
_MINUS_LOOKALIKES = "\u2212\u2012\u2013\u2014\u2010\u2011\ufe63\uff0d"


def _plain(text: str, rule: re.Pattern[str], where: str, what: str) -> str:
    """``text`` stripped, when ``rule`` matches it; else the ValueError of :func:`plain_float`
    (a :class:`NumberSpellingError` for digit separators and a typographic minus)."""
    stripped = text.strip()
    if rule.fullmatch(stripped):
        return stripped
    if "_" in stripped and rule.fullmatch(stripped.replace("_", "")):
        raise NumberSpellingError(f"{stripped!r} has '_' digit separators, which {where} "
                                  f"cannot have; write {stripped.replace('_', '')}")
    ascii_minus = stripped.translate({ord(c): "-" for c in _MINUS_LOOKALIKES})
    if ascii_minus != stripped and rule.fullmatch(ascii_minus):
        sign = next(c for c in stripped if c in _MINUS_LOOKALIKES)
        raise NumberSpellingError(f"{stripped!r} has a typographic minus sign ({sign}, U+"
                                  f"{ord(sign):04X}, as a PDF or a word processor writes it), "
                                  f"which {where} cannot have; write {ascii_minus}")
    raise ValueError(f"{text!r} is not {what}")


def finite_number(value: object, limit: float = math.inf) -> TypeGuard[int | float]:
    """Whether ``value`` (a file's or flag's value) is a finite number within +-``limit``
    (a bool, None, a string, inf and NaN are not)."""
    return (isinstance(value, int | float) and not isinstance(value, bool)
            and math.isfinite(value) and abs(value) <= limit)


def three_numbers(value: object, limit: float = math.inf) -> bool:
    """Whether ``value`` is a list of three :func:`finite_number` (an offset in a file)."""
    return isinstance(value, list) and len(value) == 3 and all(
        finite_number(v, limit) for v in value)


def float_array(value: object, name: str, needed: str | Callable[[], str],
                size: int | None = None, ndim: int | None = None,
                finite: bool = True) -> np.ndarray:
    """``value`` (a Python API argument: a number, a sequence or an array of numbers) as a
    float array, checked where it enters: numbers only (no string, None or bool), of ``ndim``
    dimensions and ``size`` values when given, finite unless ``finite`` is False (for a caller
    whose own message says more).

    Parameters
    ----------
    name, needed
        The argument's name and what it must be, with its unit (``"q"``, ``"6 joint
        coordinates (rad, m)"``), for the message; ``needed`` may be a function giving that
        text, called only for the message (a hot path's text naming its robot: building it
        took 45 % of a UR5's :meth:`Robot.configuration`, 57 -> 31 us).

    Raises
    ------
    StiffnessError
        ``"<name> must be <needed>, got <what was given>"``
        (:func:`stiffness.errors.wrong_argument`).
    """
    def text() -> str:
        return needed() if callable(needed) else needed

    try:
        array = np.asarray(value)
    except (TypeError, ValueError):  # ragged nesting
        raise wrong_argument(name, value, text()) from None
    if array.dtype.kind not in "iuf" or (ndim is not None and array.ndim != ndim) or (
            size is not None and array.size != size):
        raise wrong_argument(name, value, text())
    array = array.astype(float)
    if finite and not np.all(np.isfinite(array)):
        raise wrong_argument(name, value, text(), "finite numbers: ")
    return array


def whole_number(value: object, name: str, minimum: int | None = 1) -> int:
    """``value`` (a Python API count: ``configs``, ``repeats``) as an int, checked where it
    enters: an integer (a Python or NumPy int; no bool, float or string) of at least
    ``minimum`` (any when None: the caller's own message says more).

    Raises
    ------
    StiffnessError
        ``"<name> must be a whole number >= <minimum>, got <what was given>"``.
    """
    needed = "a whole number" + ("" if minimum is None else f" >= {minimum}")
    if not isinstance(value, int | np.integer) or isinstance(value, bool) or (
            minimum is not None and value < minimum):
        raise wrong_argument(name, value, needed)
    return int(value)


#: Moment unit name -> factor to N.m (every force unit times every length unit).
MOMENT_UNITS = {f"{f}.{ln}": FORCE_UNITS[f] * LENGTH_UNITS[ln]
                for f in FORCE_UNITS for ln in LENGTH_UNITS}

#: SI unit of a joint spring's stiffness by kind of joint (a model file's ``k_theta.unit``).
JOINT_STIFFNESS_UNITS = {"revolute": "N.m/rad", "prismatic": "N/m"}


def wrong_stiffness_unit(joints: Sequence[str], units: Sequence[str],
                         prismatic: Callable[[str], bool], what: str = "k_theta",
                         writer: str = "`stiffness identify`") -> str | None:
    """The one-line problem of the first joint whose stiffness unit is not of its kind.

    Parameters
    ----------
    joints, units
        Joint names and the unit of each one's stiffness (e.g. a model file's ``k_theta``).
    prismatic
        Whether a joint is prismatic (its stiffness in N/m) rather than revolute (N.m/rad).
    what, writer
        What the stiffnesses are, and the command that writes them (in the message).

    Returns
    -------
    str or None
        The joint, the unit found, the unit expected and the fix; ``None`` when every unit is
        :data:`JOINT_STIFFNESS_UNITS` of its joint's kind.
    """
    for joint, unit in zip(joints, units, strict=True):
        kind = "prismatic" if prismatic(joint) else "revolute"
        expected = JOINT_STIFFNESS_UNITS[kind]
        if unit != expected:
            return (f"{what} of {kind} joint {joint!r} is in {unit!r}, expected {expected!r}; "
                    f"the stiffness is of another kind of joint: give {joint}'s in {expected} "
                    f"or rewrite the file with {writer} on this robot")
    return None


@dataclass(frozen=True)
class Units:
    """Units of a campaign's files (in memory everything is SI).

    Attributes
    ----------
    angle
        Unit of joint angles and measured rotations: ``deg`` or ``rad``.
    force
        Unit of forces: ``N`` or ``kN``.
    length
        Unit of deflections, the target offset, noise and prismatic coordinates:
        ``mm``, ``m``, ``cm`` or ``um``.
    rotation_unit
        Unit of measured rotations and their noise (``deg`` or ``rad``), or ``None`` for the
        angle unit.
    moment_unit
        Unit of applied moments, force.length (e.g. ``N.mm``, ``N.m``), or ``None`` for the
        force unit times the length unit.
    """

    angle: str = "deg"
    force: str = "N"
    length: str = "mm"
    rotation_unit: str | None = None
    moment_unit: str | None = None

    def __post_init__(self) -> None:
        for kind, value, table in (("angle", self.angle, ANGLE_UNITS),
                                   ("force", self.force, FORCE_UNITS),
                                   ("length", self.length, LENGTH_UNITS),
                                   ("rotation", self.rotation, ANGLE_UNITS),
                                   ("moment", self.moment, MOMENT_UNITS)):
            if value not in table:
                raise UnknownNameError(
                    f"unknown {kind} unit {value!r}; valid {kind} units: {', '.join(table)}",
                    name=str(value), choices=list(table))

    @property
    def angle_to_si(self) -> float:
        """Factor from the angle unit to rad."""
        return ANGLE_UNITS[self.angle]

    @property
    def force_to_si(self) -> float:
        """Factor from the force unit to N."""
        return FORCE_UNITS[self.force]

    @property
    def length_to_si(self) -> float:
        """Factor from the length unit to m."""
        return LENGTH_UNITS[self.length]

    @property
    def moment_to_si(self) -> float:
        """Factor from the moment unit (default force x length) to N.m."""
        return MOMENT_UNITS[self.moment]

    @property
    def moment(self) -> str:
        """Name of the moment unit, e.g. ``N.mm`` (``[units] moment``, default force.length)."""
        return self.moment_unit or f"{self.force}.{self.length}"

    @property
    def rotation(self) -> str:
        """Unit of measured rotations (``[units] rotation``, default the angle unit)."""
        return self.rotation_unit or self.angle

    @property
    def rotation_to_si(self) -> float:
        """Factor from the rotation unit to rad."""
        return ANGLE_UNITS[self.rotation]
