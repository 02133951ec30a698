"""Appendix I of Alici & Shirinzadeh (2005), transcribed exactly as printed.

Source: G. Alici and B. Shirinzadeh, "Enhanced stiffness modeling, identification and
characterization for robot manipulators", IEEE Transactions on Robotics 21(4), 2005,
Appendix I, eq. (17).

The appendix gives, by hand, the 3x3 positional Jacobian of the end point of the
six-joint manipulator studied in the paper,

    J = d(x, y, z) / d(theta_1, theta_2, theta_3)        (rows x, y, z; eq. 3),

as a function of all six joint angles ``t1..t6`` (in the appendix's own angle
convention) and of the link lengths/offsets ``L1..L6`` and ``D1..D6``.

Every element is stored here term by term, with signs, length symbols and trigonometric
factors exactly as they appear in the printed text, *including anything that looks like a
typo*. Nothing is corrected or interpreted in this module: comparing these expressions with
an independent kinematic model, and deciding which printed terms are wrong, is the job of
the cross-check module, not this one.

Units: angles in rad; lengths in whatever unit the caller uses (J then has units of
length/rad, and ``appendix_kc`` returns force unit x length unit / rad).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

__all__ = [
    "APPENDIX_TERMS",
    "ELEMENT_NAMES",
    "Term",
    "appendix_element",
    "appendix_jacobian",
    "appendix_kc",
]

LENGTH_SYMBOLS: tuple[str, ...] = tuple(f"L{i}" for i in range(1, 7)) + tuple(
    f"D{i}" for i in range(1, 7)
)
ANGLE_SYMBOLS: tuple[str, ...] = tuple(f"t{i}" for i in range(1, 7)) + ("t2-t3",)
_FUNCTIONS = {"cos": np.cos, "sin": np.sin}

ELEMENT_NAMES: tuple[str, ...] = tuple(f"J{r}{c}" for r in (1, 2, 3) for c in (1, 2, 3))

_COMPLEX_STEP = 1e-30


@dataclass(frozen=True)
class Term:
    """One printed monomial ``sign * length * f1(arg1) * f2(arg2) * ...``.

    Attributes
    ----------
    sign : int
        +1 or -1, as printed.
    length : str
        Length symbol, one of ``"L1".."L6"``, ``"D1".."D6"``.
    factors : tuple of (str, str)
        Trigonometric factors ``(function, argument)``; function is ``"cos"`` or ``"sin"``,
        argument is ``"t1".."t6"`` or ``"t2-t3"``.
    """

    sign: int
    length: str
    factors: tuple[tuple[str, str], ...]

    def __post_init__(self) -> None:
        if self.sign not in (1, -1):
            raise ValueError(f"sign must be +1 or -1, got {self.sign!r}")
        if self.length not in LENGTH_SYMBOLS:
            raise ValueError(f"unknown length symbol {self.length!r}")
        for func, arg in self.factors:
            if func not in _FUNCTIONS or arg not in ANGLE_SYMBOLS:
                raise ValueError(f"bad factor {(func, arg)!r}")

    def value(
        self,
        theta: Mapping[str, complex | float | np.ndarray],
        lengths: Mapping[str, float],
    ) -> complex | float | np.ndarray:
        """Evaluate the term.

        Parameters
        ----------
        theta : Mapping[str, complex | float | np.ndarray]
            Angles ``"t1".."t6"`` in rad (complex allowed, for complex-step use; arrays
            evaluate the term at many poses).
            ``"t2-t3"`` is computed from ``"t2"`` and ``"t3"``.
        lengths : Mapping[str, float]
            Length symbols; a missing symbol means 0.

        Returns
        -------
        complex | float | np.ndarray
            The term value, in length units (an array for array angles).
        """
        out: complex | float | np.ndarray = self.sign * lengths.get(self.length, 0.0)
        for func, arg in self.factors:
            x = theta["t2"] - theta["t3"] if arg == "t2-t3" else theta[arg]
            out = out * _FUNCTIONS[func](x)
        return out

    def __str__(self) -> str:
        parts = ["+" if self.sign > 0 else "-", self.length]
        parts += [f"{func}({arg})" for func, arg in self.factors]
        return " ".join(parts)


_TERM_RE = re.compile(r"^([+-])\s+([LD][1-6])((?:\s+(?:cos|sin)\((?:t[1-6]|t2-t3)\))*)$")
_FACTOR_RE = re.compile(r"(cos|sin)\((t[1-6]|t2-t3)\)")


def _parse(text: str) -> Term:
    """Build a :class:`Term` from its printed form, e.g. ``"- L3 sin(t1) sin(t3)"``."""
    m = _TERM_RE.match(text.strip())
    if m is None:
        raise ValueError(f"cannot parse term {text!r}")
    sign = 1 if m.group(1) == "+" else -1
    factors = tuple(_FACTOR_RE.findall(m.group(3)))
    return Term(sign, m.group(2), factors)


# Transcription of Appendix I, eq. (17), one printed term per string, in printed order.
# theta_i is written t<i>.  Do NOT correct anything here.
_PRINTED: dict[str, tuple[str, ...]] = {
    "J11": (
        "+ L4 cos(t1) sin(t4)",
        "- D3 cos(t1)",
        "- L1 sin(t1)",
        "+ L6 cos(t1) sin(t4) cos(t5) cos(t6)",
        "+ D5 cos(t1) cos(t4)",
        "+ L6 cos(t1) cos(t4) sin(t6)",
        "+ L5 cos(t1) sin(t4) cos(t5)",
        "+ D6 cos(t1) sin(t4) sin(t5)",
        "- D6 sin(t1) cos(t3) cos(t5)",
        "+ L5 sin(t1) cos(t3) sin(t5)",
        "- L5 sin(t1) sin(t3) cos(t4) cos(t5)",
        "+ L6 sin(t1) cos(t3) sin(t5) cos(t6)",
        "- L3 sin(t1) sin(t3)",
        "- L6 sin(t1) sin(t3) cos(t4) cos(t5) cos(t6)",
        "+ L6 sin(t1) sin(t3) sin(t4) sin(t6)",
        "- D6 sin(t1) sin(t3) cos(t4) sin(t5)",
        "+ D5 sin(t1) sin(t3) sin(t4)",
        "- L4 sin(t1) sin(t3) cos(t4)",
        "- D4 sin(t1) cos(t3)",
        "- L2 sin(t1) sin(t3) sin(t2-t3)",
        "+ L2 sin(t1) cos(t3) cos(t2-t3)",
    ),
    "J12": ("+ L2 cos(t1) sin(t2)",),
    "J13": (
        "+ L6 cos(t1) sin(t3) sin(t5) cos(t6)",
        "- L6 cos(t1) cos(t3) sin(t4) sin(t6)",
        "- D4 cos(t1) sin(t3)",
        "+ L3 cos(t1) cos(t3)",
        "+ D6 cos(t1) cos(t3) cos(t4) sin(t5)",
        "+ L5 cos(t1) cos(t3) cos(t4) cos(t5)",
        "+ L6 cos(t1) cos(t3) cos(t4) cos(t5) cos(t6)",
        "+ L4 cos(t1) cos(t3) cos(t4)",
        "- D6 cos(t1) sin(t3) cos(t5)",
        "- D5 cos(t1) cos(t3) sin(t4)",
        "+ L5 cos(t1) sin(t3) sin(t5)",
    ),
    "J21": (
        "- D4 cos(t1) cos(t3)",
        "+ L3 cos(t1) sin(t3)",
        "- L6 cos(t1) cos(t3) sin(t5) cos(t6)",
        "+ D6 cos(t1) sin(t3) cos(t4) sin(t5)",
        "+ D6 cos(t1) cos(t3) cos(t5)",
        "- D5 cos(t1) sin(t3) sin(t4)",
        "+ L6 sin(t1) sin(t4) cos(t5) cos(t6)",
        "+ D6 sin(t1) sin(t4) sin(t5)",
        "+ L6 sin(t1) cos(t4) sin(t6)",
        "+ L5 sin(t1) sin(t4) cos(t5)",
        "+ L4 sin(t1) sin(t4)",
        "+ D5 sin(t1) cos(t4)",
        "- D1 sin(t1)",
        "+ L6 cos(t1) sin(t3) cos(t4) cos(t5) cos(t6)",
        "- L6 cos(t1) sin(t3) sin(t4) sin(t6)",
        "+ L4 cos(t1) sin(t3) cos(t4)",
        "- L5 cos(t1) cos(t3) sin(t5)",
        "+ L5 cos(t1) sin(t3) cos(t4) cos(t5)",
        "+ L1 cos(t1)",
        "- L2 cos(t1) cos(t3) cos(t2-t3)",
        "+ L2 cos(t1) sin(t3) sin(t2-t3)",
    ),
    "J22": ("+ L2 sin(t1) sin(t2)",),
    "J23": (
        "- D5 sin(t1) cos(t3) sin(t4)",
        "+ L5 sin(t1) cos(t3) cos(t4) cos(t5)",
        "+ L3 sin(t1) cos(t3)",
        "- L6 sin(t1) cos(t3) sin(t4) sin(t6)",
        "+ L6 sin(t1) sin(t3) sin(t5) cos(t6)",
        "+ L4 sin(t1) cos(t3) cos(t4)",
        "- D4 sin(t1) sin(t3)",
        "+ L5 sin(t1) sin(t3) sin(t5)",
        "+ D6 sin(t1) cos(t3) cos(t4) sin(t5)",
        "- D6 sin(t1) sin(t3) cos(t5)",
        "+ L6 sin(t1) cos(t3) cos(t4) cos(t5) cos(t6)",
    ),
    "J31": (),  # printed as 0
    "J32": ("+ L2 cos(t2)",),
    "J33": (
        "+ D5 sin(t3) sin(t4)",
        "- L4 sin(t3) cos(t4)",
        "- L5 sin(t3) cos(t4) cos(t5)",
        "- D4 cos(t3)",
        "+ L6 sin(t3) sin(t4) sin(t6)",
        "- D6 sin(t3) cos(t4) sin(t5)",
        "- L6 sin(t3) cos(t4) cos(t5) cos(t6)",
        "- D6 cos(t3) cos(t5)",
        "+ L5 cos(t3) sin(t5)",
        "- L3 sin(t3)",
        "+ L6 cos(t3) sin(t5) cos(t6)",
    ),
}

APPENDIX_TERMS: dict[str, tuple[Term, ...]] = {
    name: tuple(_parse(t) for t in terms) for name, terms in _PRINTED.items()
}
"""Printed terms of each Jacobian element, keys ``"J11".."J33"`` (``J31`` is empty)."""


def _angle_map(theta: np.ndarray) -> dict[str, complex | float]:
    theta = np.asarray(theta)
    if theta.shape != (6,):
        raise ValueError(f"theta must have shape (6,), got {theta.shape}")
    return {f"t{i + 1}": theta[i] for i in range(6)}


def appendix_element(
    name: str,
    theta: np.ndarray,
    lengths: Mapping[str, float],
) -> complex | float | np.ndarray:
    """Evaluate one printed Jacobian element.

    Parameters
    ----------
    name : str
        Element name, ``"J11".."J33"``.
    theta : np.ndarray, shape (6,)
        Joint angles t1..t6 in rad, appendix convention (real or complex).
    lengths : Mapping[str, float]
        Values of ``L1..L6``, ``D1..D6`` (length unit); missing symbols mean 0.

    Returns
    -------
    complex | float | np.ndarray
        The element value, in length unit / rad (an array for arrays of angles).
    """
    angles = _angle_map(theta)
    # 0 with the input dtype (complex stays complex)
    total: complex | float | np.ndarray = 0.0 * angles["t1"]
    for term in APPENDIX_TERMS[name]:
        total = total + term.value(angles, lengths)
    return total


def appendix_jacobian(theta: np.ndarray, lengths: Mapping[str, float]) -> np.ndarray:
    """3x3 Jacobian as printed in Appendix I, eq. (17).

    Parameters
    ----------
    theta : np.ndarray, shape (6,)
        The six joint angles t1..t6 in rad, in the appendix's own convention. Complex dtype
        is supported (for complex-step differentiation).
    lengths : Mapping[str, float]
        Values of ``L1..L6``, ``D1..D6`` (length unit); missing symbols mean 0.

    Returns
    -------
    np.ndarray, shape (3, 3)
        ``J[r, c] = d(x, y, z)[r] / d theta_{c+1}`` as printed (length unit / rad), with the
        dtype of ``theta`` (at least float64).
    """
    theta = np.asarray(theta)
    dtype = np.result_type(theta.dtype, np.float64)
    theta = theta.astype(dtype)
    jac = np.zeros((3, 3), dtype=dtype)
    for r in range(3):
        for c in range(3):
            jac[r, c] = appendix_element(f"J{r + 1}{c + 1}", theta, lengths)
    return jac


def appendix_kc(
    theta: np.ndarray,
    force: np.ndarray,
    lengths: Mapping[str, float],
) -> np.ndarray:
    """Complementary stiffness K_C of eq. (9), computed from the printed appendix.

    ``K_C[i, j] = sum_k F_k dJ[k, i] / d theta_j`` for ``j`` over the first three angles
    (theta_1..theta_3), i.e. column ``j`` is ``(dJ^T / d theta_j) F``. The derivatives of the
    printed expressions are taken by complex-step differentiation (step ``1e-30j``), which is
    exact to round-off.

    Parameters
    ----------
    theta : np.ndarray, shape (6,)
        Real joint angles t1..t6 in rad, appendix convention.
    force : np.ndarray, shape (3,)
        End-point force (Fx, Fy, Fz), force unit.
    lengths : Mapping[str, float]
        Values of ``L1..L6``, ``D1..D6`` (length unit); missing symbols mean 0.

    Returns
    -------
    np.ndarray, shape (3, 3)
        K_C in force unit x length unit / rad.
    """
    theta = np.asarray(theta, dtype=np.float64)
    force = np.asarray(force, dtype=np.float64)
    if force.shape != (3,):
        raise ValueError(f"force must have shape (3,), got {force.shape}")
    kc = np.zeros((3, 3))
    for j in range(3):
        th = theta.astype(np.complex128)
        th[j] += 1j * _COMPLEX_STEP
        dj = appendix_jacobian(th, lengths).imag / _COMPLEX_STEP
        kc[:, j] = dj.T @ force
    return kc
