"""The parts of the SK120 report that depend on no campaign: the Appendix I cross-check, the
Table IV definiteness scan with its findings and Figs. 7-9 (:func:`definiteness_part`), and
what the 3-D scene shows (:func:`scene_robot`).

They take about half of the report's time, so ``stiffness report`` computes them in a second
process (with the report's 3-D scene, :func:`stiffness.cli.report.independent_parts`) while
this one identifies and draws the rest; this module imports only what they need (not the
identification and its optimisers), so that process starts quickly.
"""

from __future__ import annotations

import numpy as np

from stiffness.papers.crosscheck import run_crosscheck
from stiffness.papers.figures import partial_derivative_maps
from stiffness.papers.reproduction import (
    PAPER_CRITICAL_FORCE_N,
    AuditEntry,
    audit_table4,
    table4,
)
from stiffness.papers.tables import read_table4
from stiffness.robot.robot import Robot, load_robot

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


#: The report summary's keys that :func:`definiteness_part` fills, in their order.
DEFINITENESS_KEYS = ("table4", "table4_determinant_rule", "table4_paper", "table4_signs",
                     "table4_paper_self_consistent", "table4_grid",
                     "kx_positive_definite_everywhere", "kx_loses_pd_at_force_N",
                     "kx_loses_pd_where")


def definiteness_part(robot: Robot, k_theta: np.ndarray) -> dict:
    """Table IV reproduced and audited, the force at which K_theta - K_C loses definiteness
    (Section VI), and Figs. 7-9.

    Parameters
    ----------
    robot : Robot
        The shipped SK120.
    k_theta : numpy.ndarray
        Joint stiffness, (3, 3), N.m/rad.

    Returns
    -------
    dict
        ``"summary"``: the report summary's :data:`DEFINITENESS_KEYS`; ``"audit"``: the
        findings (:class:`~stiffness.papers.reproduction.AuditEntry`); ``"figure"``: the PNG of
        Figs. 7-9 (:func:`~stiffness.papers.figures.partial_derivative_maps`).
    """
    t4, scan = table4(robot, k_theta)
    printed = read_table4()
    paper_t4 = {k: {c: v[c] for c in ("PD", "PSD", "ND", "NSD", "ID")}
                for k, v in printed.items()}
    consistent, audit = audit_table4(paper_t4, t4["ours"], t4["ours_determinant_rule"])
    magnitudes = np.linalg.norm(scan.loads, axis=1)
    critical = scan.critical_factor * magnitudes[None, :]
    where = np.unravel_index(np.argmin(critical), critical.shape)
    summary = {
        "table4": t4["ours"],
        "table4_determinant_rule": t4["ours_determinant_rule"],
        "table4_paper": paper_t4,
        "table4_signs": {k: list(v["signs"]) for k, v in printed.items()},
        "table4_paper_self_consistent": consistent,
        "table4_grid": ("theta1 -180..180, theta2 -70..70, theta3 -115..35 deg, step 0.2 rad; "
                        "wrist vertical (q4 = 0, q5 = -90 - q3, q6 = -90 deg); |F_i| = 100 N"),
        "kx_positive_definite_everywhere": bool(np.all(scan.tangent_classes == "PD")),
        "kx_loses_pd_at_force_N": float(np.min(critical)),
        "kx_loses_pd_where": {
            "q_deg": np.rad2deg(scan.coordinates[where[0]]).round(4).tolist(),
            "load_case": list(printed)[where[1]],
            "direction": (scan.loads[where[1]] / magnitudes[where[1]]).tolist(),
        },
    }
    if summary["kx_loses_pd_at_force_N"] > 2 * PAPER_CRITICAL_FORCE_N:
        audit.append(AuditEntry(
            item="Section VI: force for K_theta - K_C to lose definiteness",
            law="K_theta - s K_C(F) is PD exactly for s < 1/lambda_max(K^-1/2 K_C K^-1/2)",
            finding=(f"the paper says ~10 kN; over the Table IV grid and load directions the "
                     f"smallest such force is {summary['kx_loses_pd_at_force_N'] / 1e3:.0f} kN"),
            numbers={"ours_N": summary["kx_loses_pd_at_force_N"],
                     "paper_N": PAPER_CRITICAL_FORCE_N}, verdict="not reproduced"))
    return {"summary": summary, "audit": audit, "figure": partial_derivative_maps(scan)}


def independent_parts() -> dict:
    """The Appendix I cross-check (:func:`~stiffness.papers.crosscheck.run_crosscheck` with its
    defaults) and :func:`definiteness_part` of the shipped SK120 with the paper's K_theta.

    Returns
    -------
    dict
        ``{"appendix": cross-check report, "definiteness": definiteness part}``.
    """
    robot = load_robot("sk120")
    k_theta = np.diag(np.asarray(robot.defaults["k_theta_SI"], dtype=float))
    return {"appendix": run_crosscheck(), "definiteness": definiteness_part(robot, k_theta)}
