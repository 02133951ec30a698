"""The two printed-angle conventions that keep the SK120's tool vertical, side by side.

The paper prints joint angles without saying how they map onto Table I's DH angles. Among the
conventions in which the tool stays vertical at every printed configuration
(``scripts/generate_sk120.py``), two differ only in the sense and zero of theta1 and in theta6:

* the chosen one (``robots/sk120/convention_fit.json``, best fit to the measured Table II
  deflections): ``theta1_DH = 180 deg - q1``, ``theta6_DH = 90 deg + q6``;
* ``theta1_DH = q1``, ``theta6_DH = q6`` (the fixture offset then points sideways rather than
  radially);

both with ``theta2_DH = -90 deg + q2``, ``theta3_DH = 180 deg - q3``, ``theta4,5_DH = q4,5``.
Nothing in the paper's text decides between them. :func:`compare_conventions` evaluates each on
Table II (RMS against the measured deflections), Table III (signs and sizes of the work
difference) and the identification of K_theta.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from stiffness.calibration.campaign import Campaign
from stiffness.calibration.identify import identify
from stiffness.papers.appendix_convention import printed_convention
from stiffness.papers.reproduction import table2, table2_summary, table3
from stiffness.papers.sk120 import AngleConvention
from stiffness.robot.robot import Robot, load_robot

#: The other tool-vertical convention: theta1 and theta6 without offset or sign change.
RADIAL_ALTERNATIVE = AngleConvention((1, 1, -1, 1, 1, 1), (0.0, -90.0, 180.0, 0.0, 0.0, 0.0))
NMM = 1e3  # N.m/rad -> N.mm/rad


@dataclass
class ConventionResult:
    """One convention's fit to the paper's tables.

    Attributes
    ----------
    name
        ``chosen`` or ``alternative``.
    convention
        The printed-angle map.
    table2_rms_mm
        RMS of the enhanced prediction (paper's K_theta) minus the measured Table II deflection
        over its 45 components, mm.
    table2_rms_paper_calculated_mm
        RMS of the same prediction minus the paper's calculated column, mm.
    table3_sign_agreement
        Rows of Table III where the printed work difference (eq. 14 - eq. 15 with K_C = 0) has
        the sign of ours (``-1/2 dTheta^T K_C dTheta``).
    table3_rows
        Rows of Table III.
    table3_work_ratio
        Median of printed eq. 14 work (read as N.mm) over ours.
    table3_difference_ratio
        Median of |printed work difference| over |ours|.
    table3_rows_by_sign
        Per row ``(config, row within config, agrees)``.
    k_theta_Nmm_per_rad, ci95_Nmm_per_rad
        K_theta identified from the Table II campaign under this convention, and its 95 %
        intervals (independent-noise assumption), N.mm/rad.
    """

    name: str
    convention: AngleConvention
    table2_rms_mm: float
    table2_rms_paper_calculated_mm: float
    table3_sign_agreement: int
    table3_rows: int
    table3_work_ratio: float
    table3_difference_ratio: float
    table3_rows_by_sign: list[tuple[str, int, bool]]
    k_theta_Nmm_per_rad: list[float]
    ci95_Nmm_per_rad: list[list[float]]

    def as_dict(self) -> dict:
        """The ``summary.json`` entry (``theta_map``: the map in words)."""
        return {
            "name": self.name,
            "theta_map": self.convention.describe(),
            "signs": list(self.convention.signs),
            "offsets_deg": list(self.convention.offsets_deg),
            "table2_rms_mm": self.table2_rms_mm,
            "table2_rms_vs_paper_calculated_mm": self.table2_rms_paper_calculated_mm,
            "table3_sign_agreement": self.table3_sign_agreement,
            "table3_rows": self.table3_rows,
            "table3_work_ratio_median": self.table3_work_ratio,
            "table3_difference_ratio_median": self.table3_difference_ratio,
            "table3_disagreeing_rows": [f"{c}{r}" for c, r, ok in self.table3_rows_by_sign
                                        if not ok],
            "k_theta_Nmm_per_rad": self.k_theta_Nmm_per_rad,
            "k_theta_ci95_Nmm_per_rad": self.ci95_Nmm_per_rad,
        }


def angle_map(convention: AngleConvention, model: AngleConvention) -> Callable:
    """Printed angles under ``convention`` -> coordinates of a model built in ``model``, deg.

    Both give the same DH angles: ``o_m + s_m q' = o_c + s_c q``, so
    ``q' = (o_c - o_m + s_c q) / s_m``.
    """
    o_c, s_c = np.asarray(convention.offsets_deg), np.asarray(convention.signs, dtype=float)
    o_m, s_m = np.asarray(model.offsets_deg), np.asarray(model.signs, dtype=float)

    def to_model(q_deg: np.ndarray) -> np.ndarray:
        return (o_c - o_m + s_c * np.asarray(q_deg, dtype=float)) / s_m

    return to_model


def rows_within_configuration(configs: list[str]) -> list[int]:
    """Row number (from 1) of each row within its configuration label."""
    seen: dict[str, int] = {}
    out = []
    for c in configs:
        seen[c] = seen.get(c, 0) + 1
        out.append(seen[c])
    return out


def evaluate_convention(name: str, convention: AngleConvention, robot: Robot,
                        campaign: Campaign, k_theta: np.ndarray, starts: int = 6
                        ) -> ConventionResult:
    """Table II, Table III and the identification under one convention.

    Parameters
    ----------
    name
        Label of the convention.
    convention
        Its printed-angle map.
    robot
        The shipped SK120 (built in :func:`printed_convention`); the printed angles are mapped
        onto its coordinates (:func:`angle_map`).
    campaign
        The Table II campaign (printed angles, rad).
    k_theta
        The paper's joint stiffness (3, 3), N.m/rad.
    starts
        Starts of the identification.
    """
    to_model = angle_map(convention, printed_convention())
    t2 = table2(robot, k_theta, to_model)
    s2 = table2_summary(t2)
    t3 = table3(robot, k_theta, to_model)
    printed = np.array([r["paper_work_cartesian"] - r["paper_work_joint_conventional"]
                        for r in t3])
    ours = np.array([r["work_cartesian_Nmm"] - r["work_joint_conventional_Nmm"] for r in t3])
    agree = np.sign(printed) == np.sign(ours)
    within = rows_within_configuration([r["config"] for r in t3])
    nonzero = (printed != 0) & (ours != 0)
    mapped = dataclasses.replace(campaign, q=np.deg2rad(to_model(np.rad2deg(campaign.q))),
                                 _robot=robot)
    ident = identify(mapped, method="both", starts=starts, robot=robot)
    return ConventionResult(
        name=name, convention=convention,
        table2_rms_mm=s2["rms_enhanced_vs_measured_mm"],
        table2_rms_paper_calculated_mm=s2["rms_enhanced_vs_paper_calculated_mm"],
        table3_sign_agreement=int(agree.sum()), table3_rows=len(t3),
        table3_work_ratio=float(np.median([r["paper_work_cartesian"] / r["work_cartesian_Nmm"]
                                           for r in t3])),
        table3_difference_ratio=float(np.median(np.abs(printed[nonzero] / ours[nonzero]))),
        table3_rows_by_sign=[(r["config"], w, bool(a)) for r, w, a in zip(t3, within, agree,
                                                                          strict=True)],
        k_theta_Nmm_per_rad=(ident.k * NMM).tolist(),
        ci95_Nmm_per_rad=np.column_stack([ident.ci95_low * NMM, ident.ci95_high * NMM]
                                         ).tolist(),
    )


def compare_conventions(campaign: Campaign, k_theta: np.ndarray, starts: int = 6
                        ) -> list[ConventionResult]:
    """The chosen convention (the shipped model) and :data:`RADIAL_ALTERNATIVE`, chosen first."""
    robot = load_robot("sk120")
    return [evaluate_convention(name, convention, robot, campaign, k_theta, starts)
            for name, convention in (("chosen", printed_convention()),
                                     ("alternative", RADIAL_ALTERNATIVE))]
