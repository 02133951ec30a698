"""A 6-D probe mounted turned, caught when a pose campaign is read.

A marker's measured orientation is that of its own axes: its frame's, turned by its declared
``rotation`` (:class:`~stiffness.calibration.pose_model.Marker`). The fit turns them by a
mounting turn about the declared mounting (the ``markers`` family), judged physical within
:data:`~stiffness.elastic.effects.kinematic_errors.MOUNTING_TURN_RAD` (a few degrees): a probe
whose mounting is not declared leaves every orientation off by one constant turn in the
marker's axes, FIGAROH's UR10 probe wrist_3_link's turned by 29.5 deg about its x axis (200
noise std at 0.002 rad), which the fit then takes as an implausible mounting turn. This check
estimates that turn from the nominal robot and warns (a
:class:`~stiffness.errors.DataFileWarning`, once) with the rotation to declare.

The estimate: ``R_measured,i = R0 R_axes(q_i) M`` with the measuring frame's rotation ``R0``
and the mounting ``M`` unknown; from ``R0`` placed by the markers' positions (Kabsch,
:func:`~stiffness.calibration.pose_model.align_frames`, on the nominal kinematics), ``M`` and
``R0`` are in turn the mean rotation (Karcher mean) of ``R_axes^T R0^T R_measured`` and of
``R_measured M^T R_axes^T`` over the rows, and the scatter is the RMS per component of each
row's turn about the fit. A mean turn above
:data:`SMALLEST_TURN_RAD` and :data:`TURN_OVER_SCATTER` times the scatter is a mounting, not the
geometric errors the fit explains.

Units: SI inside (rad); the warning in the campaign's rotation unit.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.calibration.pose_model import Marker, PoseModelError, align_frames
from stiffness.calibration.unit_checks import marker_points, nominal_frames
from stiffness.elastic.effects.kinematic_errors import MOUNTING_TURN_RAD
from stiffness.errors import DataFileWarning, StiffnessError
from stiffness.robot.robot import Robot
from stiffness.units import Units

#: Smallest constant turn (rad) reported: below it, the fit's mounting turn takes it.
SMALLEST_TURN_RAD = MOUNTING_TURN_RAD
#: How far the constant turn must stand above the rows' scatter about it (RMS per component).
TURN_OVER_SCATTER = 5.0
#: Alternations of the measuring frame's and the mounting's mean rotations.
MOUNTING_STEPS = 10
#: Rows used (evenly spaced through the campaign): a constant turn shows in any of them.
ROWS_USED = 60


def mounting_turns(robot: Robot, markers: list[Marker], q: np.ndarray, positions: np.ndarray,
                   rotations: np.ndarray) -> list[tuple[np.ndarray, float] | None]:
    """Each marker's constant turn (rotation vector, rad, in its declared axes) between its
    nominal and measured orientations and the scatter about it (rad, RMS per component);
    ``None`` for a marker without measured orientations, or all ``None`` when the positions
    cannot place the measuring frame.

    Parameters
    ----------
    q, positions, rotations
        The rows' coordinates (n, n_coordinates; rad, m), measured positions (n, M, 3; m) and
        orientations (n, M, 3; rotation vectors, rad), NaN where not seen; :data:`ROWS_USED`
        of them, evenly spaced, are used.
    """
    frames = [m.frame for m in markers]
    rows = np.unique(np.linspace(0, len(q) - 1, min(len(q), ROWS_USED)).astype(int))
    q, positions, rotations = q[rows], positions[rows], rotations[rows]
    try:
        turns, origins = nominal_frames(robot, frames, q)
        nominal = marker_points(turns, origins, np.array([m.offset for m in markers]))
        r0, _ = align_frames(nominal.reshape(-1, 3), positions.reshape(-1, 3))
    except (StiffnessError, PoseModelError):  # reported where the fit meets it
        return [None] * len(markers)
    out: list[tuple[np.ndarray, float] | None] = []
    for k, m in enumerate(markers):
        seen = np.flatnonzero(np.all(np.isfinite(rotations[:, k]), axis=1))
        if not seen.size:
            out.append(None)
            continue
        axes = [turns[i, k] @ m.rotation for i in seen]
        measured = [pin.exp3(rotations[i, k]) for i in seen]
        out.append(_mounting(axes, measured, r0))
    return out


def _mounting(axes: list[np.ndarray], measured: list[np.ndarray], r0: np.ndarray
              ) -> tuple[np.ndarray, float]:
    """``M`` with ``measured_i = R0 axes_i M`` (its rotation vector, rad) and the RMS per
    component of each row's turn about it (rad): the measuring frame's ``R0`` and ``M``
    alternately the mean rotation given the other, from the positions' ``r0`` (whose marker
    offsets are nominal, a probe's often centimetres off: the orientations place it better)."""
    mount = np.eye(3)
    for _ in range(MOUNTING_STEPS):
        mount = _mean([a.T @ r0.T @ r for a, r in zip(axes, measured, strict=True)])
        r0 = _mean([r @ mount.T @ a.T for a, r in zip(axes, measured, strict=True)])
    about = np.array([pin.log3(mount.T @ a.T @ r0.T @ r)
                      for a, r in zip(axes, measured, strict=True)])
    return pin.log3(mount), float(np.sqrt(np.mean(about ** 2)))


def _mean(rotations: list[np.ndarray]) -> np.ndarray:
    """The Karcher mean of rotations (a few fixed-point steps from their mean rotation
    vector)."""
    mean = pin.exp3(np.mean([pin.log3(t) for t in rotations], axis=0))
    for _ in range(3):
        mean = mean @ pin.exp3(np.mean([pin.log3(mean.T @ t) for t in rotations], axis=0))
    return mean


def check_marker_mounting(robot: Robot, markers: list[Marker], q: np.ndarray,
                          positions: np.ndarray, rotations: np.ndarray | None, units: Units,
                          where: str | Path) -> None:
    """Warn once, per marker, when its measured orientations are its declared axes turned by
    one constant rotation (:func:`mounting_turns`): a 6-D probe mounted turned, with the
    rotation to declare in the campaign's rotation unit.

    Warns
    -----
    DataFileWarning
        The marker, the turn and its axis, the scatter, and the ``[markers]`` and
        ``--marker`` spelling of the rotation to declare (the declared one composed with it).
    """
    if rotations is None:
        return
    unit, scale = units.rotation, units.rotation_to_si
    for m, found in zip(markers, mounting_turns(robot, markers, q, positions, rotations),
                        strict=True):
        if found is None:
            continue
        turn, scatter = found
        angle = float(np.linalg.norm(turn))
        if angle < SMALLEST_TURN_RAD or angle < TURN_OVER_SCATTER * scatter:
            continue
        declare = ", ".join(f"{v / scale:.4g}" for v in pin.log3(m.rotation @ pin.exp3(turn)))
        axis = ", ".join(f"{v:.3g}" for v in turn / angle)
        flag = f"--marker {m.name}={m.frame}@X,Y,Z@{declare.replace(' ', '')}"
        warnings.warn(
            f"{where}: marker {m.name}'s measured orientations are its axes on {m.frame} turned "
            f"by a constant {angle / scale:.4g} {unit} about ({axis}) in them (scatter "
            f"{scatter / scale:.3g} {unit} about it): a 6-D probe mounted turned, beyond the "
            f"{MOUNTING_TURN_RAD / scale:.3g} {unit} the fit's mounting turn is judged "
            f"physical within; declare its mounting: [markers] {m.name} rotation = [{declare}] "
            f"({unit}; campaign import {flag})", DataFileWarning, stacklevel=3)
