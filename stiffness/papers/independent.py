"""The parts of the SK120 report that depend on no campaign: the Appendix I cross-check and
the figure of K_C's diagonal parts over the Table IV grid (Figs. 7-9).

They take about a third of the report's time, so ``stiffness report`` computes them in a
second process while this one identifies and draws the rest; this module imports only what
they need (not the identification and its optimisers), so that process starts quickly.
"""

from __future__ import annotations

import numpy as np

from stiffness.model.robot import load_robot
from stiffness.papers import figures as plots
from stiffness.papers.crosscheck import run_crosscheck
from stiffness.papers.reproduction import table4

#: The figure of :func:`independent_parts`.
INDEPENDENT_FIGURE = "partial_derivatives.png"


def independent_parts() -> dict:
    """The Appendix I cross-check (:func:`~stiffness.papers.crosscheck.run_crosscheck` with its
    defaults) and the figure of K_C's diagonal parts over the Table IV grid, with the paper's
    SK120 and K_theta.

    Returns
    -------
    dict
        ``{"appendix": cross-check report, "figures": {"partial_derivatives.png": PNG}}``.
    """
    robot = load_robot("sk120")
    _, scan = table4(robot, np.diag(robot.defaults["k_theta_SI"]))
    return {"appendix": run_crosscheck(),
            "figures": {INDEPENDENT_FIGURE: plots.partial_derivative_maps(scan)}}
