"""Buckling of the UR5 upright against a closed form (issue 30, item 3's check).

Upright (``shoulder_lift = -pi/2``, the other joints 0) the three parallel axes (shoulder lift,
elbow, wrist 1) are horizontal and the tool sits at the height of wrist 1. A dead force
``(0, 0, -f)`` at the tool: for a planar chain of parallel axes, ``d2 z / dq_a dq_b =
-h_max(a,b)``, with ``h_i`` the height of the tool above joint i (the second derivative of a
rotated vector is minus its in-plane part), and every other second derivative of ``F . x``
vanishes here, so ``K_C = f [[h1, h2], [h2, h2]]`` on (shoulder lift, elbow) and zero
elsewhere. ``h1 = a2 + a3`` and ``h2 = a3`` from UR's published DH table (a2 = 0.425 m,
a3 = 0.39225 m). ``det(K_theta - lambda K_C) = 0`` is then the quadratic

    lambda^2 f^2 h2 (h1 - h2) - lambda f (k2 h2 + k3 h1) + k2 k3 = 0,

whose smaller root is the critical load factor.
"""

from __future__ import annotations

import contextlib
import io
import json
import math

import numpy as np
import pytest

from stiffness.batch.linalg import critical_load_factor
from stiffness.cli.main import main
from stiffness.mechanics.formulation import target_state
from stiffness.robot.robot import load_robot

#: UR5 DH lengths (m): upper arm a2 and forearm a3 (Universal Robots' published parameters).
A2, A3 = 0.425, 0.39225
#: Joint stiffness (N.m/rad), the issue's values.
KQ = np.array([3e5, 3e5, 2e5, 4e4, 4e4, 4e4])
UPRIGHT = np.array([0.0, -np.pi / 2, 0.0, 0.0, 0.0, 0.0])


def closed_form_factor(f: float, k2: float, k3: float) -> float:
    """The smaller root of the quadratic of the module docstring (load ``(0, 0, -f)``)."""
    h1, h2 = A2 + A3, A3
    a, b, c = f ** 2 * h2 * (h1 - h2), f * (k2 * h2 + k3 * h1), k2 * k3
    return float((b - math.sqrt(b * b - 4 * a * c)) / (2 * a))


@pytest.mark.parametrize("f", [1.0, 1e3, 1e6])
def test_critical_factor_of_the_upright_ur5_matches_the_closed_form(f):
    robot = load_robot("ur5")
    q = robot.configuration(UPRIGHT)
    state = target_state(robot, q, np.array([0.0, 0.0, -f]))
    computed = float(critical_load_factor(np.diag(KQ), state.k_c))
    expected = closed_form_factor(f, KQ[1], KQ[2])
    assert computed == pytest.approx(expected, rel=1e-9)


def kx_definiteness(force_n: float) -> dict:
    """``kx --json``'s definiteness classes for the upright UR5 under ``(0, 0, -force_n)``."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["kx", "--robot", "ur5", "--kq", ",".join(map(repr, KQ.tolist())), "--q",
                     ",".join(map(repr, UPRIGHT.tolist())), "--wrench", f"0,0,{-force_n!r}",
                     "--json"])
    assert code == 0, err.getvalue()
    return json.loads(out.getvalue())["definiteness"]


def test_kx_says_indefinite_just_beyond_the_critical_load():
    """At 0.99 of the closed-form critical force K_theta - K_C is PD; at 1.01 it is not."""
    critical = closed_form_factor(1.0, KQ[1], KQ[2])  # N, for a unit force
    assert kx_definiteness(0.99 * critical)["K_theta_minus_K_C"] == "PD"
    assert kx_definiteness(1.01 * critical)["K_theta_minus_K_C"] != "PD"


def view_stability(force_n: float, tmp_path) -> dict:
    """``view --export --json``'s stability of the upright UR5 under ``(0, 0, -force_n)``."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["view", "--robot", "ur5", "--kq", ",".join(map(repr, KQ.tolist())),
                     "--q", ",".join(map(repr, UPRIGHT.tolist())),
                     "--wrench", f"0,0,{-force_n!r}", "--export", str(tmp_path / "v.html"),
                     "--json"])
    assert code == 0, err.getvalue()
    doc = json.loads(out.getvalue())
    return {"stable": doc["stable"], "critical_load_factor": doc["critical_load_factor"],
            "page_says_unstable": "UNSTABLE under this load" in (tmp_path / "v.html").read_text()}


def test_view_says_stable_or_not_with_the_critical_factor(tmp_path):
    critical = closed_form_factor(1.0, KQ[1], KQ[2])  # N
    below = view_stability(0.99 * critical, tmp_path)
    assert below["stable"] is True and not below["page_says_unstable"]
    assert below["critical_load_factor"] == pytest.approx(1 / 0.99, rel=1e-9)
    beyond = view_stability(1.01 * critical, tmp_path)
    assert beyond["stable"] is False and beyond["page_says_unstable"]
    assert beyond["critical_load_factor"] == pytest.approx(1 / 1.01, rel=1e-9)
    # an upward force never buckles the upright arm: no critical factor (not round-off's 1e15)
    assert view_stability(-100.0, tmp_path)["critical_load_factor"] is None
