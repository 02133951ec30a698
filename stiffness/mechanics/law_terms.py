"""The terms of the joint law, each written once.

A spring's deflection under the torque ``t`` it carries is the sum of three terms
(:class:`stiffness.mechanics.equilibrium.SpringLaw`):

* linear: ``c t``, ``c`` the compliance (rad/(N.m), m/N);
* softening: ``g t |t|``, ``g = c beta`` (rad/(N.m)^2, m/N^2; ``beta`` 1/(N.m), 1/N), the
  spring's secant compliance ``c + g |t|`` (softening for ``g > 0``, hardening below);
* lost motion: ``b tanh(t / s)``, a dead band of half-width ``b`` (rad, m) smoothed over the
  torque ``s`` (N.m, N).

Each term is linear in its parameter (``c``, ``g``, ``b``): its *column* is its value per unit
parameter (``t``, ``t |t|``, ``tanh(t / s)``), its *slope* its derivative w.r.t. ``t``. Every
model that evaluates the law (the exact and frozen equilibria, the deflection campaigns'
hypotheses, the pose model's joint families, the real-time compensator, the simulated
campaigns) reads these functions. Arrays broadcast: parameters (n,) against torques (..., n).
"""

from __future__ import annotations

import numpy as np


def linear(c: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``c t`` and its slope ``c`` (shaped like ``c``: it broadcasts against ``t``)."""
    return c * t, c


def softening(g: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``g t |t|`` and its slope ``2 g |t|``."""
    a = np.abs(t)
    return g * t * a, 2.0 * g * a


def softening_column(t: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``t |t|``, the softening term per unit ``g`` (into ``out`` when given)."""
    out = np.abs(t, out=out)
    out *= t
    return out


def lost_motion(b: np.ndarray, t: np.ndarray, s: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """``b tanh(t / s)`` and its slope ``b sech^2(t / s) / s``."""
    th = np.tanh(t / s)
    return b * th, b / s * (1.0 - th ** 2)


def lost_motion_column(t: np.ndarray, s: np.ndarray, out: np.ndarray | None = None
                       ) -> np.ndarray:
    """``tanh(t / s)``, the lost motion per unit ``b`` (into ``out`` when given)."""
    out = np.divide(t, s, out=out)
    return np.tanh(out, out=out)
