"""Poses of the Appendix I cross-check and the Pinocchio side of it.

:func:`sample_poses` draws the paper's printed configurations plus a workspace sample
(vertical-wrist and general-wrist poses, away from the flattened parallelogram);
:func:`pinocchio_samples` computes, at those printed configurations, the target Jacobian and
the unit-force K_C of a loop-closed SK120 model; :func:`build_generic_robot` builds the SK120
from Table I with its zero lengths made non-zero (to expose typos invisible at Table I's
lengths).
"""

from __future__ import annotations

import tempfile
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from stiffness.mechanics.formulation import target_states
from stiffness.papers.appendix_convention import SEARCH_POSES, printed_convention
from stiffness.papers.sk120 import AngleConvention, read_table1, sk120_urdf
from stiffness.papers.tables import paper_configurations
from stiffness.robot import kinematics
from stiffness.robot.robot import Robot, load_robot
from stiffness.robot.sources import robots_directory

__all__ = [
    "LOOP_MARGIN_DEG",
    "PoseSet",
    "build_generic_robot",
    "pinocchio_samples",
    "sample_poses",
]

#: Margin (deg) kept from the flattened parallelogram by the random samples.
LOOP_MARGIN_DEG = 2.0
#: Workspace ranges (deg) of the paper, Section VI.
_RANGES_DEG = ((-180.0, 180.0), (-70.0, 70.0), (-115.0, 35.0))


# --------------------------------------------------------------------------------------------
# Poses and the Pinocchio side
# --------------------------------------------------------------------------------------------


@dataclass
class PoseSet:
    """Printed configurations (rad) with a label per pose.

    Attributes
    ----------
    q : np.ndarray, shape (P, 6)
        Printed angles q1..q6 (rad).
    kind : list of str
        ``"paper"``, ``"workspace"`` (vertical wrist) or ``"general"`` (random wrist).
    """

    q: np.ndarray
    kind: list[str]

    def select(self, kind: str) -> np.ndarray:
        """Indices of the poses of one kind."""
        return np.array([i for i, k in enumerate(self.kind) if k == kind], dtype=int)


def sample_poses(
    n_samples: int = 200,
    seed: int = 0,
    n_general: int | None = None,
    loop_margin_deg: float = LOOP_MARGIN_DEG,
) -> PoseSet:
    """The paper's printed configurations plus a workspace sample.

    Parameters
    ----------
    n_samples : int
        Random poses with a vertical tool (printed ``q4 = 0``, ``q5 = -90 - q3``,
        ``q6 = +-90`` deg) within the paper's ranges ``q1 in [-180, 180]``,
        ``q2 in [-70, 70]``, ``q3 in [-115, 35]`` deg.
    seed : int
        Seed of the generator.
    n_general : int, optional
        Extra poses with a random wrist (``q4..q6`` uniform in [-180, 180] deg); default
        ``max(8, n_samples // 4)``.
    loop_margin_deg : float
        Random poses whose five-bar angle ``theta_bar2 = theta2 - theta3`` (Table I) is within
        this margin (deg) of 0 or 180 (the flattened parallelogram, a loop singularity the
        paper's independent joint ranges do not exclude) are redrawn: there the closed-loop
        K_C of the reference loses digits (4e-9 relative, 3e-6 N.mm/rad per N, at 0.4 deg).

    Returns
    -------
    PoseSet
        Paper configurations first, then the vertical-wrist and general samples.
    """
    rng = np.random.default_rng(seed)
    printed = printed_convention()
    if n_general is None:
        n_general = max(SEARCH_POSES, n_samples // 4)

    def arm(n: int) -> np.ndarray:
        out = np.zeros((0, 3))
        while out.shape[0] < n:
            draw = np.column_stack([rng.uniform(lo, hi, n) for lo, hi in _RANGES_DEG])
            q = np.zeros((n, 6))
            q[:, :3] = np.deg2rad(draw)
            theta = printed.to_dh(q)
            ok = np.abs(np.sin(theta[:, 1] - theta[:, 2])) >= np.sin(np.deg2rad(loop_margin_deg))
            out = np.vstack([out, draw[ok]])
        return out[:n]

    paper = np.deg2rad(paper_configurations())
    arm_v = arm(n_samples)
    q6 = rng.choice([-90.0, 90.0], n_samples)
    vertical = np.deg2rad(np.column_stack(
        [arm_v, np.zeros(n_samples), -90.0 - arm_v[:, 2], q6]))
    arm_g = arm(n_general)
    general = np.deg2rad(np.column_stack([arm_g, rng.uniform(-180.0, 180.0, (n_general, 3))]))
    q = np.vstack([paper, vertical, general])
    kind = ["paper"] * len(paper) + ["workspace"] * n_samples + ["general"] * n_general
    return PoseSet(q, kind)


def _polished(robot: Robot, q: np.ndarray, iterations: int = 3) -> np.ndarray:
    """Extra Gauss-Newton steps on the loop closure, down to round-off (pure model accuracy)."""
    model, data, loop = robot.model, robot.data, robot.loop
    for _ in range(iterations):
        kinematics.update_first_order(model, data, q)
        c = loop.residual(model, data)
        cp = loop.jacobian(model, data)[:, loop.passive_v]
        dv = np.zeros(model.nv)
        dv[loop.passive_v] = np.linalg.lstsq(cp, -c, rcond=1e-10)[0]
        q = pin.integrate(model, q, dv)
    return q


def pinocchio_samples(robot: Robot, q_printed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pinocchio target Jacobians and unit-force K_C at printed configurations.

    Parameters
    ----------
    robot : Robot
        An SK120 model whose joints ``joint1..joint6`` take the printed angles
        (``load_robot("sk120")``), compliant joints ``joint1..joint3``.
    q_printed : np.ndarray, shape (P, 6)
        Printed angles (rad).

    Returns
    -------
    jac : np.ndarray, shape (P, 3, 3)
        ``d(target position)/d(q1, q2, q3)`` in mm/rad (loop closed), Pinocchio base axes.
    kc : np.ndarray, shape (P, 3, 3, 3)
        ``kc[p, k]`` = K_C (N.mm/rad) w.r.t. ``q1..q3`` for a 1 N dead force along base axis k.
    """
    names = [f"joint{i + 1}" for i in range(6)]
    order = [names.index(j) for j in robot.coordinate_joints]
    jac = np.zeros((len(q_printed), 3, 3))
    kc = np.zeros((len(q_printed), 3, 3, 3))
    for p, coords in enumerate(q_printed):
        q = robot.configuration(np.asarray(coords)[order])
        if not robot.loop.is_open_chain:
            q = _polished(robot, q)
        states = target_states(robot, q, np.eye(3))  # one kinematics, three unit forces
        kc[p] = [state.k_c * 1e3 for state in states]
        jac[p] = states[-1].jacobian[:3] * 1e3
    return jac, kc


def build_generic_robot(extra_mm: Mapping[str, float], printed: AngleConvention) -> Robot:
    """The SK120 built from Table I with the zero lengths of ``extra_mm`` made non-zero.

    Parameters
    ----------
    extra_mm : Mapping[str, float]
        Values (mm) of some of ``D1, D3, L4, D5, L5`` (zero in Table I).
    printed : AngleConvention
        Printed-angle convention of the model's joints (:func:`printed_convention`).

    Returns
    -------
    Robot
        The loop-closed model, target frame ``fixture_target``, compliant joints
        ``joint1..joint3``.
    """
    table1 = dict(read_table1(robots_directory() / "sk120" / "table1_dh.csv"))
    edits = {"D1": ("1", "d"), "D3": ("3", "d"), "L4": ("4", "a"), "D5": ("5", "d"),
             "L5": ("5", "a")}
    for sym, value in extra_mm.items():
        row, field_name = edits[sym]
        changes: dict[str, Any] = {field_name: value * 1e-3}
        table1[row] = replace(table1[row], **changes)
    loops = robots_directory() / "sk120" / "sk120.loops.yaml"
    with tempfile.TemporaryDirectory(prefix="sk120_generic_") as tmp:
        urdf = Path(tmp) / "sk120_generic.urdf"
        urdf.write_text(sk120_urdf(table1, printed))
        (Path(tmp) / "sk120_generic.loops.yaml").write_text(loops.read_text())
        return load_robot(urdf, frame="fixture_target",
                          compliant_joints=["joint1", "joint2", "joint3"])
