"""Scan presets the papers provide to ``stiffness scan --preset NAME``.

A preset turns a robot into the options of a workspace scan (grid axes, the coordinates that
follow them, load cases) without the scan layer knowing about any paper: the scan command
looks the name up in :data:`SCAN_PRESETS` and builds an ordinary grid
:class:`~stiffness.workspace.spec.ScanSpec` from its
:class:`~stiffness.workspace.request.ScanPreset`.

* ``table4``: Alici & Shirinzadeh's Section VI / Table IV grid on the SK120 (theta1 -180..180,
  theta2 -70..70, theta3 -115..35 deg, step 0.2 rad, wrist vertical: q4 = 0,
  q5 = -90 deg - theta3, q6 = -90 deg), the eight +-100 N load cases; the same configurations,
  in the same order, as :func:`stiffness.papers.reproduction.table4_grid`.

Angles in rad, loads in N.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from stiffness.errors import StiffnessError
from stiffness.papers.reproduction import table4_loads
from stiffness.robot.robot import Robot
from stiffness.workspace.request import ScanPreset


def table4_preset(robot: Robot) -> ScanPreset:
    """The Table IV grid (see the module docstring) for the SK120.

    Raises
    ------
    StiffnessError
        If the robot does not have the SK120's six coordinates and three compliant joints.
    """
    if robot.n_coordinates != 6 or robot.n_compliant != 3:
        raise StiffnessError(
            "--preset table4 is the SK120 grid of A&S Table IV (six coordinates, three "
            f"compliant joints); {robot.title} has {robot.n_coordinates} and "
            f"{robot.n_compliant}"
        )
    ranges = [(-np.pi, np.pi), (np.deg2rad(-70.0), np.deg2rad(70.0)),
              (np.deg2rad(-115.0), np.deg2rad(35.0))]
    axes = [{"index": i, "joint": robot.coordinate_joints[i], "lower": float(lo),
             "upper": float(hi), "step": 0.2} for i, (lo, hi) in enumerate(ranges)]
    names, loads = table4_loads()
    return ScanPreset(axes=axes, base=[0.0, 0.0, 0.0, 0.0, -np.pi / 2, -np.pi / 2],
                      couplings=[{"index": 4, "axis": 2, "factor": -1.0}],
                      load_names=names, loads=loads.tolist(), map_axes=[1, 2], name="table4")


#: Preset name -> builder of its scan options from the loaded robot.
SCAN_PRESETS: dict[str, Callable[[Robot], ScanPreset]] = {"table4": table4_preset}
#: Preset name -> the robot it is made for (``scan --preset`` loads it when no robot is given).
PRESET_ROBOTS: dict[str, str] = {"table4": "sk120"}
