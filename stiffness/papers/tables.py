"""The tables of Alici & Shirinzadeh (2005) shipped in ``robots/sk120/paper/``, read into SI.

The CSV files keep the paper's units (deg, N, mm, J as printed; see each file's header);
conversion to SI happens here, at the boundary.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np

from stiffness.robot.sources import robots_directory

_FILES = {
    "table2": "table2_verification.csv",
    "table3": "table3_works_conventional.csv",
    "table4": "table4_definiteness.csv",
}
#: Configurations of Figs. 4-6 (deg), as printed in their captions.
FIGURE_CONFIGURATIONS_DEG = {
    "fig4": (-89.3803, -62.9809, 21.2489, 0.0, -111.2492, -90.0),
    "fig5": (98.1065, 23.2088, -20.7957, 0.0, -69.2041, 90.0),
    "fig6": (-13.6727, -10.9660, -37.4489, 0.0, -52.5514, -90.0),
}


def paper_file(table: str) -> Path:
    """Path of a shipped paper table (``table2``, ``table3`` or ``table4``)."""
    return robots_directory() / "sk120" / "paper" / _FILES[table]


def _records(table: str) -> list[dict[str, str]]:
    with open(paper_file(table)) as f:
        return list(csv.DictReader(line for line in f if not line.startswith("#")))


def read_paper_table(table: str) -> list[dict]:
    """Rows of Table II or III in SI: ``config``, ``q`` (deg, as printed), ``force_N`` and

    for Table II ``calculated_m`` and ``measured_m`` (m); for Table III ``work_cartesian`` and
    ``work_joint_conventional`` (as printed, labelled J).
    """
    out = []
    for rec in _records(table):
        row: dict[str, Any] = {
            "config": rec["config"],
            "q": np.array([float(rec[f"q{i}"]) for i in range(1, 7)]),
            "force_N": np.array([float(rec[k]) for k in ("fx", "fy", "fz")]),
        }
        if table == "table2":
            row["calculated_m"] = np.array([float(rec[f"calc_d{a}"]) for a in "xyz"]) * 1e-3
            row["measured_m"] = np.array([float(rec[f"meas_d{a}"]) for a in "xyz"]) * 1e-3
        else:
            row["work_cartesian"] = float(rec["work_cartesian_J"])
            row["work_joint_conventional"] = float(rec["work_joint_conventional_J"])
        out.append(row)
    return out


def read_table4() -> dict[str, dict]:
    """Table IV: per case, the force signs and the printed counts PD, PSD, ND, NSD, ID."""
    return {
        rec["case"]: {
            "signs": (int(rec["sx"]), int(rec["sy"]), int(rec["sz"])),
            **{k: int(rec[k]) for k in ("PD", "PSD", "ND", "NSD", "ID")},
        }
        for rec in _records("table4")
    }


def paper_configurations() -> np.ndarray:
    """All distinct printed configurations (deg) of Tables II, III and Figs. 4-6, shape (m, 6)."""
    seen: dict[tuple, None] = {}
    for table in ("table2", "table3"):
        for row in read_paper_table(table):
            seen[tuple(row["q"])] = None
    for q in FIGURE_CONFIGURATIONS_DEG.values():
        seen[tuple(q)] = None
    return np.array(list(seen))
