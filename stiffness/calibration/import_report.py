"""What ``campaign import`` read: the report of an import (files, rows, each column's source,
range and unit), and the warning about file columns no campaign column read."""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

from stiffness.errors import UnknownColumnWarning
from stiffness.robot.robot import Robot
from stiffness.units import Units


@dataclass
class ImportReport:
    """What an import read.

    Attributes
    ----------
    files
        The files and their data rows.
    rows
        Campaign rows made.
    deflections
        How the deflections were given (``direct``, ``two column sets``, ``paired rows``).
    columns
        Per campaign column: its source ``FILE:COLUMN``, unit, and the range read (file
        units).
    units
        The units used (:class:`stiffness.units.Units`).
    force_frame, deflection_frame
        The frames the files gave forces and deflections in.
    kind
        ``deflections`` or ``poses`` (absolute marker positions: ``deflections`` and
        ``deflection_frame`` then say so).
    """

    files: list[tuple[str, int]]
    rows: int
    deflections: str
    columns: dict[str, dict]
    units: Units
    force_frame: str
    deflection_frame: str
    kind: str = "deflections"

    def to_dict(self) -> dict:
        """JSON-ready."""
        return {"files": [{"file": f, "rows": n} for f, n in self.files], "rows": self.rows,
                "deflections": self.deflections, "columns": self.columns,
                "units": {"angle": self.units.angle, "force": self.units.force,
                          "length": self.units.length, "moment": self.units.moment},
                "force_frame": self.force_frame, "deflection_frame": self.deflection_frame}

    def lines(self) -> list[str]:
        """The report as text lines."""
        read = f"read {', '.join(f'{f} ({n} rows)' for f, n in self.files)}: {self.rows} "
        if self.kind == "poses":
            out = [read + "campaign rows of absolute marker positions (measuring system's "
                          "frame)" + ("; forces in world axes" if "fx" in self.columns else "")]
        else:
            out = [read + f"campaign rows; deflections {self.deflections}; forces in the "
                          f"{self.force_frame} frame, deflections in the "
                          f"{self.deflection_frame} frame"]
        width = max(len(t) for t in self.columns)
        for target, c in self.columns.items():
            span = "" if c["min"] is None else f"  {c['min']:.6g} .. {c['max']:.6g}"
            out.append(f"  {target.ljust(width)} <- {c['source']}{span} {c['unit']}".rstrip())
        return out


def column_report(mapper: Any, units: Units, robot: Robot, prismatic: np.ndarray,
                  kinds: dict[str, str]) -> dict[str, dict]:
    """Per campaign column read (``mapper.used``, of a
    :class:`stiffness.calibration.rig_import.ColumnMapper`, which imports this module): source,
    unit, range (file units); ``kinds`` gives each non-coordinate column's kind of unit (force,
    moment, length, angle)."""
    out = {}
    for target, column in mapper.used.items():
        unit = ""
        if target.startswith("q") and target[1:].isdigit():
            unit = units.length if prismatic[int(target[1:]) - 1] else units.angle
        elif target in robot.coordinate_joints:
            unit = units.length if robot.is_prismatic(target) else units.angle
        elif target in kinds:
            unit = getattr(units, kinds[target])
        values = column.numbers(empty_is_nan=True) if unit else None
        seen = None if values is None or not np.isfinite(values).any() else values
        out[target] = {"source": f"{column.path.name}:{column.name}", "unit": unit,
                       "min": None if seen is None else float(np.nanmin(seen)) + 0.0,
                       "max": None if seen is None else float(np.nanmax(seen)) + 0.0}  # -0 as 0
    return out


def warn_unused(columns: dict[str, list[Any]], report: ImportReport, key: str | None
                ) -> None:
    """Warn once about file columns no campaign column read (a map may have missed them): an
    :class:`~stiffness.errors.UnknownColumnWarning`, which ``campaign import --strict``
    refuses."""
    used = {c["source"] for c in report.columns.values()}
    left = [f"{c.path.name}:{c.name}" for cs in columns.values() for c in cs
            if f"{c.path.name}:{c.name}" not in used and c.name != key]
    if left:
        warnings.warn(f"columns not imported: {', '.join(left[:8])}"
                      + (", ..." if len(left) > 8 else "") + " (ignored, refused under "
                      "--strict; map them with --map or remove them)", UnknownColumnWarning,
                      stacklevel=2)
