"""A pose campaign from the CSV files a rig writes (``stiffness campaign import --kind poses``).

The files are joined, mapped and read as for a deflection campaign
(:mod:`stiffness.calibration.rig_import`: ``--join``, ``--map``, ``--units``, units in the
headers). The campaign columns are ``config`` (optional), ``q1..qn``, each marker's
``<marker>_x, <marker>_y, <marker>_z`` in the measuring system's frame (all three cells empty
where it was not seen), optionally its orientation ``<marker>_rx, _ry, _rz`` (rotation vector
of the marker's frame in the measuring frame, in the files' angle unit; all three columns or
none, all three cells or none) and optionally the applied wrench ``fx, fy, fz[, mx, my, mz]`` (world
axes, at the robot's target frame). Positions are absolute, so no frame is converted.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.calibration.campaign import RobotSettings, Units, coordinates_in_si
from stiffness.calibration.coordinate_columns import fill_held
from stiffness.calibration.import_report import ImportReport, column_report, warn_unused
from stiffness.calibration.measurements import warn_copied_markers
from stiffness.calibration.pose_campaign import ROTATION_AXES, PoseCampaign
from stiffness.calibration.pose_model import Loads, Marker
from stiffness.calibration.probe_mounting import check_marker_mounting
from stiffness.calibration.rig_import import (
    FORCE,
    MOMENT,
    UNIT_KINDS,
    ColumnMapper,
    ImportSettings,
    Table,
    check_map,
    join_tables,
    load_import_robot,
    read_block,
    read_coordinates,
    read_table,
    row_labels,
)
from stiffness.calibration.unit_checks import check_marker_offsets, check_marker_spread
from stiffness.errors import DataFileWarning, StiffnessError, UnknownFrameError, did_you_mean
from stiffness.robot.robot import Robot


def marker_targets(markers: list[Marker]) -> tuple[str, ...]:
    """The campaign columns of the markers: ``<marker>_x, _y, _z`` each, and the optional
    ``<marker>_rx, _ry, _rz``."""
    return tuple(f"{m.name}_{a}" for m in markers
                 for a in ("x", "y", "z", *ROTATION_AXES, *QUATERNION_AXES))


#: What a rig's orientation columns may hold (:func:`as_rotation_vectors`; ``quaternion``:
#: :func:`quaternion_vectors`).
ROTATION_FORMATS = ("vector", "rpy", "quaternion")

#: A marker's quaternion columns (``--rotation-format quaternion``): ``<marker>_qx, _qy, _qz,
#: _qw``, the scalar last (ROS's and most trackers' order; a file writing it first maps it).
QUATERNION_AXES = ("qx", "qy", "qz", "qw")

#: Largest departure of a quaternion's norm from 1 read as rounding (values written with 3 or
#: 4 decimals: FIGAROH's TIAGo exp_data_0924.csv, norms 0.9977-1.0003 but one); beyond it
#: the rows are warned about (that file's line 3: 1.0324, a value typed wrong), and beyond
#: :data:`QUATERNION_NORM_REFUSED` refused (not quaternions: columns mapped wrong).
QUATERNION_NORM_TOL = 0.01
QUATERNION_NORM_REFUSED = 0.5


def quaternion_vectors(quaternions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Quaternions (n, 4) ``x, y, z, w`` (NaN rows: not seen) as rotation vectors (n, 3) rad,
    each normalised, and their norms (n,) (NaN where not seen)."""
    out = np.full((quaternions.shape[0], 3), np.nan)
    norms = np.linalg.norm(quaternions, axis=1)
    for i, q in enumerate(quaternions):
        if np.all(np.isfinite(q)) and norms[i] > 0:
            x, y, z, w = q / norms[i]
            out[i] = pin.log3(pin.Quaternion(w, x, y, z).toRotationMatrix())
    return out, norms


def as_rotation_vectors(rotations: np.ndarray, rotation_format: str) -> np.ndarray:
    """Orientations (..., 3) rad as rotation vectors (NaN rows kept): as they are for
    ``"vector"``; for ``"rpy"`` roll, pitch, yaw ``R = Rz(yaw) Ry(pitch) Rx(roll)``."""
    if rotation_format == "vector":
        return rotations
    out = np.full(rotations.shape, np.nan)
    for index in np.ndindex(rotations.shape[:-1]):
        if np.all(np.isfinite(rotations[index])):
            out[index] = pin.log3(pin.rpy.rpyToMatrix(*rotations[index]))
    return out


def import_pose_campaign(files: list[str | os.PathLike], robot_settings: RobotSettings,
                         settings: ImportSettings, markers: list[Marker],
                         name: str = "imported", noise_std: float | None = None,
                         robot: Robot | None = None,
                         noise_std_rotation: float | None = None,
                         marker_turns: dict[str, np.ndarray] | None = None,
                         rotation_format: str = "vector"
                         ) -> tuple[PoseCampaign, ImportReport]:
    """Read a rig's CSV files into a pose campaign (SI), and what was read (the report of
    :func:`stiffness.calibration.rig_import.import_campaign`, each column listed).

    Parameters
    ----------
    markers
        The markers (name, frame, nominal offset in the files' length unit).
    noise_std
        Position noise std in the files' length unit, or ``None``.
    noise_std_rotation
        Orientation noise std in the files' angle unit, or ``None`` (refused without
        orientation columns).
    marker_turns
        A marker's axes in its frame's axes (a 6-D probe's mounting), as a rotation vector in
        the files' angle unit, by marker name; the others have their frame's axes.
    rotation_format
        What the orientation columns hold: ``"vector"`` (the campaign's rotation vector) or
        ``"rpy"`` (roll, pitch, yaw about the fixed x, y, z axes, ``R = Rz(yaw) Ry(pitch)
        Rx(roll)``: ROS's and FIGAROH's ``phix, phiy, phiz``), turned into rotation vectors.

    Raises
    ------
    StiffnessError
        Anything that cannot be mapped (file, line and column named), a marker with some but not
        all of its three cells on a row, or a frame the robot lacks.
    """
    if not files:
        raise StiffnessError("give at least one CSV file to import")
    if not markers:
        raise StiffnessError("a pose campaign needs at least one --marker NAME=FRAME")
    robot = robot if robot is not None else load_import_robot(robot_settings)
    _check_frames(robot, markers)
    tables = [read_table(f) for f in files]
    check_map(settings, robot, ("config", *FORCE, *MOMENT, *marker_targets(markers)))
    columns, _ = join_tables(tables, settings.join)
    mapper = ColumnMapper(columns, settings, [t.path for t in tables])
    q_cols, q_file, prismatic, held = read_coordinates(mapper, robot)
    positions = _positions(mapper, markers, tables[0].path)
    rotations = _orientations(mapper, markers, positions.shape[0], rotation_format,
                              noise_std_rotation)
    force = read_block(mapper, FORCE, "force", False)
    moment = read_block(mapper, MOMENT, "moment", False) if force is not None else None
    units = _units(mapper, prismatic, rotations is not None, force is not None,
                   moment is not None)
    rows = np.arange(q_file.shape[0])
    labels = row_labels(mapper.find("config"), rows, q_file)
    q_file = fill_held(q_file, held, robot, units)
    q = coordinates_in_si(robot, q_file, units, labels, q_cols[0].lines, q_cols[0].path)
    offsets = np.array([m.offset for m in markers], float) * units.length_to_si
    check_marker_offsets(robot, [m.name for m in markers], offsets, units, "--marker")
    check_marker_spread(robot, [m.frame for m in markers], offsets, q,
                        positions * units.length_to_si, units, q_cols[0].path)
    loads = None if force is None else Loads.read(robot.target_frame, force, moment, units)
    campaign = PoseCampaign(name, robot, robot_settings, units,
                            _scaled_markers(markers, marker_turns, units), labels, q,
                            positions * units.length_to_si, loads,
                            None if noise_std is None else noise_std * units.length_to_si,
                            rotations=None if rotations is None
                            else rotations if rotation_format == "quaternion"
                            else as_rotation_vectors(rotations * units.angle_to_si,
                                                     rotation_format),
                            noise_std_rotation=None if noise_std_rotation is None
                            else noise_std_rotation * units.angle_to_si)
    check_marker_mounting(robot, campaign.markers, q, campaign.positions, campaign.rotations,
                          units, q_cols[0].path)
    report = _report(tables, campaign.n_rows, mapper, units, robot, prismatic, markers)
    warn_unused(columns, report, settings.join)
    return campaign, report


def _units(mapper: ColumnMapper, prismatic: np.ndarray, rotations: bool, force: bool,
           moment: bool) -> Units:
    """The files' units (angle default rad, force N, length m): each asked of the mapper only
    where the files have that kind (an angle for a revolute coordinate or ``rotations``)."""
    return Units(mapper.unit("angle", bool((~prismatic).any()) or rotations) or "rad",
                 mapper.unit("force", force) or "N",
                 mapper.unit("length", True) or "m",
                 moment_unit=mapper.unit("moment", moment))


def _check_frames(robot: Robot, markers: list[Marker]) -> None:
    """Refuse a marker on a frame the robot lacks (one line, naming the nearest frames)."""
    for m in markers:
        if not robot.model.existFrame(m.frame):
            names = list(dict.fromkeys(f.name for f in robot.model.frames))
            raise UnknownFrameError(f"marker {m.name!r}: frame {m.frame!r} is not a frame of "
                                    f"{robot.title}; {did_you_mean(m.frame, names)}",
                                    name=m.frame, choices=names)


def _orientations(mapper: ColumnMapper, markers: list[Marker], n: int, rotation_format: str,
                  noise_std_rotation: float | None) -> np.ndarray | None:
    """(n, markers, 3) the markers' orientation columns in the files' angle unit, as the files
    hold them (``rotation_format``; quaternions as rotation vectors in rad,
    :func:`_quaternions`), NaN for a marker without them; ``None`` when no marker has them.

    Raises
    ------
    StiffnessError
        An unknown ``rotation_format``, or a rotation noise std without orientation columns.
    """
    if rotation_format not in ROTATION_FORMATS:
        raise StiffnessError(f"rotation format {rotation_format!r}: valid "
                             f"{', '.join(ROTATION_FORMATS)}")
    if rotation_format == "quaternion":  # rotation vectors in rad already
        rotations = _quaternions(mapper, markers, n)
    else:
        turns = [_marker(mapper, m, ROTATION_AXES, "angle", False) for m in markers]
        rotations = (None if all(t is None for t in turns) else np.stack(
            [np.full((n, 3), np.nan) if t is None else t for t in turns], axis=1))
    if noise_std_rotation is not None and rotations is None:
        columns = "_qx,_qy,_qz,_qw" if rotation_format == "quaternion" else "_rx,_ry,_rz"
        raise StiffnessError("a rotation noise is given but no marker has orientation columns "
                             f"(<marker>{columns}); map them or drop the rotation noise")
    return rotations


def _quaternions(mapper: ColumnMapper, markers: list[Marker], n: int) -> np.ndarray | None:
    """(n, markers, 3) rotation vectors (rad) of the markers' quaternion columns
    (:data:`QUATERNION_AXES`), NaN for a marker without them; ``None`` when no marker has
    them.

    Raises
    ------
    StiffnessError
        A marker with some of the four cells of a row (as its positions), or a quaternion
        off unit norm (:func:`quaternion_vectors`; file, line and column named).
    """
    out, found = np.full((n, len(markers), 3), np.nan), False
    for k, m in enumerate(markers):
        values = _marker(mapper, m, QUATERNION_AXES, "angle", False, units=False)
        if values is None:
            continue
        found = True
        out[:, k], norms = quaternion_vectors(values)
        off = np.abs(np.nan_to_num(norms, nan=1.0) - 1.0)
        if not (off > QUATERNION_NORM_TOL).any():
            continue
        columns = mapper.group(tuple(f"{m.name}_{a}" for a in QUATERNION_AXES), True)
        assert columns is not None
        rows = np.flatnonzero(off > QUATERNION_NORM_TOL)
        if off.max() > QUATERNION_NORM_REFUSED:  # the worst row's own values and norm
            worst = int(np.argmax(off))
            said = _quaternion_text(m, values[worst], norms[worst])
            raise columns[0].error(worst, f"{said}, not 1: not a quaternion; map "
                                   f"{m.name}_qx,_qy,_qz,_qw to the quaternion's x, y, z and w "
                                   "(scalar) columns")
        lines = columns[0].lines
        said = _quaternion_text(m, values[rows[0]], norms[rows[0]])
        warnings.warn(f"{columns[0].path}: {rows.size} of {int(np.isfinite(norms).sum())} rows "
                      f"hold quaternions off unit norm by more than {QUATERNION_NORM_TOL:g} "
                      f"(first: line {lines[rows[0]]}, {said}); read normalised: check "
                      f"line{'s' if rows.size > 1 else ''} "
                      f"{', '.join(str(lines[r]) for r in rows[:5])}", DataFileWarning,
                      stacklevel=2)
    return out if found else None


def _quaternion_text(marker: Marker, quaternion: np.ndarray, norm: float) -> str:
    """A marker's row of quaternion cells and its norm, as the warning and the refusal quote
    them."""
    return (f"marker {marker.name}'s quaternion (x, y, z, w) = ("
            f"{', '.join(f'{v:.6g}' for v in quaternion)}) has norm {norm:.6g}")


def _scaled_markers(markers: list[Marker], marker_turns: dict[str, np.ndarray] | None,
                    units: Units) -> list[Marker]:
    """The ``markers`` in SI: their offsets (m) and mountings (rotation matrices, from the
    rotation vectors of ``marker_turns`` in the files' angle unit; identity when not given)."""
    mounts = marker_turns or {}
    return [Marker(m.name, m.frame, np.asarray(m.offset, float) * units.length_to_si,
                   pin.exp3(np.array(mounts.get(m.name, np.zeros(3)), dtype=float)
                            * units.angle_to_si))
            for m in markers]


def _report(tables: list[Table], n_rows: int, mapper: ColumnMapper, units: Units, robot: Robot,
            prismatic: np.ndarray, markers: list[Marker]) -> ImportReport:
    """What was read: the files and their rows, the campaign's ``n_rows``, and each column
    with its unit kind (a marker's positions length, its orientations angle)."""
    kinds = UNIT_KINDS | {f"{m.name}_{a}": "length" for m in markers for a in "xyz"} | {
        f"{m.name}_{a}": "angle" for m in markers for a in ROTATION_AXES}
    return ImportReport([(str(t.path), len(t.rows)) for t in tables], n_rows,
                        "none (absolute marker positions)",
                        column_report(mapper, units, robot, prismatic, kinds), units, "world",
                        "measuring system", kind="poses")


def _positions(mapper: ColumnMapper, markers: list[Marker], path: Path) -> np.ndarray:
    """(n, markers, 3) the markers' positions in the files' unit, NaN where not seen; a
    marker's columns that copy another's are warned about (:func:`warn_copied_markers`)."""
    seen = [_marker(mapper, m) for m in markers]
    positions = np.stack([p for p in seen if p is not None], axis=1)  # required: all there
    warn_copied_markers([m.name for m in markers], positions, path)
    return positions


def _marker(mapper: ColumnMapper, marker: Marker, axes: tuple[str, ...] = ("x", "y", "z"),
            kind: str = "length", required: bool = True, units: bool = True
            ) -> np.ndarray | None:
    """(n, len(axes)) positions (or orientations: ``axes`` ``rx, ry, rz``, ``kind`` angle;
    quaternions, ``units`` false: numbers without a unit) of a marker in the files' unit, NaN
    where its cells are empty; ``None`` for optional columns absent."""
    targets = tuple(f"{marker.name}_{a}" for a in axes)
    cols = mapper.group(targets, required)
    if cols is None:
        return None
    values = np.column_stack([mapper.values(t, c, kind, empty_is_nan=True) if units
                              else c.numbers(True) for t, c in zip(targets, cols, strict=True)])
    seen = np.isfinite(values)
    partial = np.flatnonzero(seen.any(axis=1) & ~seen.all(axis=1))
    if partial.size:
        row = int(partial[0])
        column = cols[int(np.flatnonzero(~seen[row])[0])]
        count, which = ("three", "all three") if len(axes) == 3 else ("four", "all four")
        raise column.error(row, f"marker {marker.name!r} has some but not all of its {count} "
                                f"cells on this row; leave {which} empty where it was not seen")
    return values
