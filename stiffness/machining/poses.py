"""Target poses along a path for ``stiffness posture``: the ``POSES.csv`` reader and the tool
frames a free axis leaves (a tool axis carried along the path by minimal rotations, or the
given orientations).

Units: m for positions; axes and orientations are unitless (unit vectors, quaternions).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.errors import FileFormatError, StiffnessError
from stiffness.machining.joint_path import header_without_units, read_table

#: Named free axes (target frame).
AXES = {"x": np.array([1.0, 0.0, 0.0]), "y": np.array([0.0, 1.0, 0.0]),
        "z": np.array([0.0, 0.0, 1.0])}


def free_axis_vector(axis: str | np.ndarray) -> np.ndarray:
    """Unit free axis (3,) in the target frame from ``x``, ``y``, ``z`` or a vector."""
    if isinstance(axis, str):
        if axis.lower() in AXES:
            return AXES[axis.lower()]
        try:
            axis = np.array([float(v) for v in axis.split(",")])
        except ValueError:
            raise StiffnessError(f"free axis must be x, y, z or ax,ay,az; got {axis!r}") from None
    v = np.asarray(axis, dtype=float).reshape(-1)
    if v.shape != (3,) or not np.all(np.isfinite(v)) or np.linalg.norm(v) < 1e-12:
        raise StiffnessError(f"free axis must be a non-zero 3-vector, got {v.tolist()}")
    return v / np.linalg.norm(v)


def _minimal_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation taking unit vector ``a`` to unit vector ``b``."""
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(a @ b)
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        perp = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(perp) < 1e-6:
            perp = np.cross(a, [0.0, 1.0, 0.0])
        return pin.exp3(np.pi * perp / np.linalg.norm(perp))
    return pin.exp3(axis / s * np.arctan2(s, c))


def tool_frames(free: np.ndarray, axes: np.ndarray | None = None,
                quaternions: np.ndarray | None = None) -> np.ndarray:
    """Reference orientations ``R_0`` (m, 3, 3) of the path points (``psi = 0``).

    ``quaternions`` (m, 4) ``qw, qx, qy, qz`` give them directly; ``axes`` (m, 3) give the
    direction of the free axis, the frame being carried along by minimal rotations from the
    minimal rotation of ``free`` onto the first axis.

    Raises
    ------
    StiffnessError
        A zero axis or quaternion (named by row).
    """
    if quaternions is not None:
        out = []
        for i, qv in enumerate(np.asarray(quaternions, dtype=float)):
            norm = np.linalg.norm(qv)
            if not np.isfinite(norm) or norm < 1e-9:
                raise StiffnessError(f"row {i + 1}: the orientation qw,qx,qy,qz is zero; give a "
                                     "unit quaternion")
            w, x, y, z = qv / norm
            out.append(pin.Quaternion(w, x, y, z).toRotationMatrix())
        return np.array(out)
    frames, previous = [], None
    for i, a in enumerate(np.asarray(axes, dtype=float)):
        norm = np.linalg.norm(a)
        if not np.isfinite(norm) or norm < 1e-9:
            raise StiffnessError(f"row {i + 1}: the tool axis ax,ay,az is zero; give a direction")
        a = a / norm
        if previous is None:
            frame = _minimal_rotation(free, a)
        else:
            frame = _minimal_rotation(previous[1], a) @ previous[0]
        frames.append(frame)
        previous = (frame, a)
    return np.array(frames)


@dataclass
class Poses:
    """A path of target poses read from CSV (SI).

    Attributes
    ----------
    header, cells
        The input columns and cells (text), as given.
    positions
        (m, 3) target positions (m).
    axes, quaternions
        (m, 3) tool axes or (m, 4) orientations ``qw, qx, qy, qz`` (one of them is None).
    wrench
        (m, 6) per-row wrenches (N, N.m), or None.
    """

    header: list[str]
    cells: list[list[str]]
    positions: np.ndarray
    axes: np.ndarray | None
    quaternions: np.ndarray | None
    wrench: np.ndarray | None

    @classmethod
    def of_arrays(cls, positions: np.ndarray, axes: np.ndarray | None,
                  quaternions: np.ndarray | None) -> Poses:
        """Poses given as arrays: columns ``x,y,z`` and ``ax,ay,az`` or ``qw,qx,qy,qz``, the
        values written in SI."""
        names = ["x", "y", "z"] + (["ax", "ay", "az"] if axes is not None
                                   else ["qw", "qx", "qy", "qz"])
        orientation = axes if axes is not None else quaternions
        assert orientation is not None  # the caller gives the axes or the quaternions
        values = np.column_stack([positions, orientation])
        return cls(names, [[repr(float(v)) for v in row] for row in values], positions, axes,
                   quaternions, None)


def read_poses(path: str | Path) -> Poses:
    """Read ``POSES.csv``: ``x,y,z`` (m) and ``ax,ay,az`` (tool axis) or ``qw,qx,qy,qz``, one
    row per point, optional ``fx,fy,fz[,mx,my,mz]`` (N, N.m) per row.

    Raises
    ------
    MissingFileError, FileFormatError
        Unreadable file, missing columns, a value that is not a finite number (line, column).
    """
    table = read_table(path, "pose file")
    written = table.header  # the input's own column names, carried to the output
    table.header = header_without_units(table, {"x": "m", "y": "m", "z": "m"})
    header = table.header
    missing = [c for c in ("x", "y", "z") if c not in header]
    if missing:
        raise FileFormatError(f"lacks the column(s) {', '.join(missing)}: give x,y,z (m) and "
                              "ax,ay,az or qw,qx,qy,qz", path=table.path, line=1)
    has_axis = all(c in header for c in ("ax", "ay", "az"))
    has_quat = all(c in header for c in ("qw", "qx", "qy", "qz"))
    if has_axis == has_quat:
        raise FileFormatError("needs exactly one of the column groups ax,ay,az (tool axis) and "
                              "qw,qx,qy,qz (orientation)", path=table.path, line=1)

    def block(names) -> np.ndarray:
        return np.column_stack([table.column(c) for c in names])

    return Poses(written, [list(r) for r in table.rows], block(("x", "y", "z")),
                 block(("ax", "ay", "az")) if has_axis else None,
                 block(("qw", "qx", "qy", "qz")) if has_quat else None, table.wrenches())


