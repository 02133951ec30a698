"""The parts of the SK120 report that depend on no campaign and need no figure: the Appendix I
cross-check, and what the 3-D scene shows (:func:`scene_robot`).

It takes about half of the report's time, so ``stiffness report`` computes it in a second
process (with the report's 3-D scene, :func:`stiffness.cli.report.independent_parts`) while
this one identifies and draws the rest; this module imports only what it needs (not the
identification and its optimisers, nor matplotlib), so that process starts quickly.
"""

from __future__ import annotations

import numpy as np

from stiffness.model.robot import Robot, load_robot
from stiffness.papers.crosscheck import run_crosscheck

#: Title of the SK120 meshcat scene written beside the report (its file:
#: :data:`stiffness.papers.report_page.SCENE_FILE`).
SCENE_TITLE = "Motoman SK120: stiffness at configuration A"


def scene_robot() -> tuple[Robot, np.ndarray]:
    """The robot and joint springs (N.m/rad) of the report's 3-D scene.

    The shipped SK120 at its defaults: Table II's configuration A, its largest load there and
    the paper's identified K_theta; the scene shows both formulations' ellipsoids side by side.
    """
    robot = load_robot("sk120")
    return robot, np.asarray(robot.defaults["k_theta_SI"], dtype=float)


def independent_parts() -> dict:
    """The Appendix I cross-check (:func:`~stiffness.papers.crosscheck.run_crosscheck` with its
    defaults).

    Returns
    -------
    dict
        ``{"appendix": cross-check report}``.
    """
    return {"appendix": run_crosscheck()}
