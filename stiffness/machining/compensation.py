"""Deflection compensation along a path: joint commands that cancel the load's deflection.

A path point gives the *nominal* coordinates ``theta_n`` (the unloaded program). Under the
process wrench ``W`` (a dead load at the target, base axes) the robot commanded at ``theta_c``
rests at its exact elastostatic equilibrium (:mod:`stiffness.elastic.loaded`: every effect
of the model file that acts on the robot); compensation finds the ``theta_c`` whose loaded
equilibrium puts the target at the unloaded nominal pose ``x(theta_n)`` (position, and the
orientation when it is held: see :func:`compensate`):

* joint law only: rest at ``theta = theta_n`` exactly, so ``theta_c = theta_n - law(J(theta_n)^T
  W)`` (closed form, design notes "Compensation along a path");
* otherwise (link compliance): Newton on ``theta_c`` with ``x_loaded(theta_c) = x(theta_n)``,
  each evaluation an exact equilibrium, the Jacobian ``J (I - diag(law') K_C)^-1`` (minimum-norm
  steps when the pose leaves freedom).

Both are the command of the model's real-time compensator
(:class:`stiffness.elastic.compensator.Compensator`, one per path, warm started point to point).
Beside it the usual first-order Cartesian compensation: command the pose shifted by
``-C W`` (``C`` the model's linear compliance at the nominal pose) through inverse kinematics;
its residual grows as the square of the load.

Every residual reported is that of the exact loaded equilibrium at the command, solved anew.
Units: SI (m, N, rad, N.m/rad; m and N/m for prismatic joints).
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.calibration.coordinate_columns import listed
from stiffness.elastic.compensator import Compensator, choose_hold
from stiffness.elastic.loaded import (
    bent_kinematics,
    frozen_axes,
    linear_shift,
    loaded_equilibrium,
)
from stiffness.elastic.model import ElasticModel
from stiffness.elastic.model_file import load_model
from stiffness.errors import (
    DataFileNote,
    FileFormatError,
    StiffnessError,
    with_context,
)
from stiffness.files import atomic_write, check_csv_header, csv_float, number_text, read_text
from stiffness.mechanics.defaults import default_coordinates
from stiffness.mechanics.equilibrium import solve_equilibrium
from stiffness.mechanics.formulation import as_wrench, target_state
from stiffness.mechanics.ik import HOLDS, coordinate_limits, solve_ik
from stiffness.robot import kinematics
from stiffness.robot.robot import Robot

#: Wrench columns a path file may carry (N, N.m).
WRENCH_COLUMNS = ("fx", "fy", "fz", "mx", "my", "mz")
#: Reference frames of a process wrench.
WRENCH_FRAMES = ("base", "target")

# ------------------------------------------------------------------------------------------
# one path point


@dataclass
class PointCompensation:
    """Compensation of one path point (SI).

    Attributes
    ----------
    command
        Exact joint command (rad, m), one per coordinate.
    command_first_order
        First-order Cartesian compensation's command (rad, m).
    deflection
        Target displacement (3,) of the uncompensated robot under the load (m).
    rotation_deflection
        Its rotation vector (3,) (rad).
    residual, rotation_residual
        Target error after the exact compensation (m; rad).
    residual_first_order, rotation_residual_first_order
        Target error after the first-order compensation (m; rad).
    method
        ``closed-form`` or ``general``.
    iterations
        Newton steps of the general solve (0 for the closed form).
    """

    command: np.ndarray
    command_first_order: np.ndarray
    deflection: np.ndarray
    rotation_deflection: np.ndarray
    residual: np.ndarray
    rotation_residual: np.ndarray
    residual_first_order: np.ndarray
    rotation_residual_first_order: np.ndarray
    method: str
    iterations: int
    q_nominal: np.ndarray = field(repr=False)


def compensate_point(em: ElasticModel, coords: np.ndarray, wrench: np.ndarray,
                     hold: str = "pose", method: str = "auto",
                     seed_q: np.ndarray | None = None,
                     compensator: Compensator | None = None) -> PointCompensation:
    """Exact and first-order compensation at nominal coordinates ``coords`` (rad, m).

    Parameters
    ----------
    em
        The elastic model.
    coords
        Nominal coordinates (the unloaded program).
    wrench
        Dead wrench (6,) [N; N.m] at the target, base axes.
    hold
        ``pose`` (position and orientation) or ``position``.
    method
        ``auto`` (closed form when joint motions are the only effect), ``closed-form`` or
        ``general``.
    seed_q
        A closed configuration near ``coords`` (the loop branch).
    compensator
        The compensator giving the exact command (:meth:`ElasticModel.compensator` with
        ``hold`` and ``method``; along a path the same one, warm started from the last point);
        default a new one.

    Raises
    ------
    StiffnessError
        Unstable or non-convergent equilibrium, or the closed form asked for a model with link
        compliance. (A first-order pose out of reach, at a singular pose, is commanded at the
        closest pose inverse kinematics finds: its residual includes the miss.)
    """
    if hold not in HOLDS:
        raise StiffnessError(f"hold must be one of {', '.join(HOLDS)}, got {hold!r}")
    if compensator is None:
        compensator = em.compensator(hold=hold, method=method)
    wrench = as_wrench(wrench)
    full, robot = em.full, em.robot
    coords = np.asarray(coords, dtype=float)
    links = em.ordered_links()
    q_n = full.configuration(coords, seed=seed_q)
    kinematics.update_first_order(em.springs.model, em.springs.data, q_n)
    axes = frozen_axes(em, links)
    nominal = bent_kinematics(em, links, axes, robot.spring_command(coords),
                              np.zeros(2 * len(links)), wrench, q_n)
    pos_n, rot_n = nominal.position.copy(), nominal.rotation.copy()

    if em.preloaded:
        return _preloaded_point(em, coords, wrench, hold, compensator.command(coords, wrench),
                                q_n, (pos_n, rot_n))

    def solve(command):
        return loaded_equilibrium(em, robot.spring_command(command), wrench, seed_q=q_n,
                                  axes=axes)

    uncompensated = solve(coords)
    command = compensator.command(coords, wrench)
    loaded = solve(command)
    # first-order Cartesian compensation: command the pose shifted by -C W through IK
    shift = linear_shift(em, links, nominal, wrench)
    target_rot = pin.exp3(-shift[3:]) @ rot_n if hold == "pose" else None
    # at a singular pose the shifted pose is out of reach by second order (a stretched arm):
    # the first-order method commands IK's closest pose there, and its residual says so
    ik = solve_ik(full, pos_n - shift[:3], target_rot, seed=coords, seed_q=q_n, limits=False,
                  raise_on_failure=False)
    first = solve(ik.coords)
    return PointCompensation(
        command=command,
        command_first_order=ik.coords,
        deflection=uncompensated.position - pos_n,
        rotation_deflection=pin.log3(uncompensated.rotation @ rot_n.T),
        residual=loaded.position - pos_n,
        rotation_residual=pin.log3(loaded.rotation @ rot_n.T),
        residual_first_order=first.position - pos_n,
        rotation_residual_first_order=pin.log3(first.rotation @ rot_n.T),
        method=compensator.method,
        iterations=compensator.iterations,
        q_nominal=q_n,
    )


def _preloaded_point(em: ElasticModel, coords: np.ndarray, wrench: np.ndarray, hold: str,
                     command: np.ndarray, q_n: np.ndarray,
                     nominal: tuple[np.ndarray, np.ndarray]) -> PointCompensation:
    """Compensation under a preload (the weight, a compensator): the load is the process
    wrench *and* the preload, so the command (the compensator's closed form,
    ``theta_n - law(J(theta_n)^T W + tau_p(theta_n))``) also cancels the preload's sag.
    The first-order command shifts the pose by ``J law(...)`` through inverse kinematics.
    Each is checked by the exact equilibrium under the load and the preload
    (:func:`stiffness.mechanics.equilibrium.solve_equilibrium`)."""
    pos_n, rot_n = nominal
    full, robot = em.full, em.robot
    law = em.compliant_law()

    def rest(command: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = full.configuration(command, seed=q_n)
        eq = solve_equilibrium(robot, q, law, wrench, preload=em.preload)
        state = target_state(robot, eq.q)
        return state.position, state.rotation

    shift = target_state(full, q_n).jacobian @ (coords - command)
    target_rot = pin.exp3(-shift[3:]) @ rot_n if hold == "pose" else None
    ik = solve_ik(full, pos_n - shift[:3], target_rot, seed=coords, seed_q=q_n, limits=False,
                  raise_on_failure=False)  # its closest pose, as above
    (p_u, r_u), (p_c, r_c), (p_f, r_f) = rest(coords), rest(command), rest(ik.coords)
    return PointCompensation(
        command=command, command_first_order=ik.coords,
        deflection=p_u - pos_n, rotation_deflection=pin.log3(r_u @ rot_n.T),
        residual=p_c - pos_n, rotation_residual=pin.log3(r_c @ rot_n.T),
        residual_first_order=p_f - pos_n, rotation_residual_first_order=pin.log3(r_f @ rot_n.T),
        method="closed-form", iterations=0, q_nominal=q_n)


# ------------------------------------------------------------------------------------------
# a path


@dataclass
class PathCompensation:
    """Compensation along a path.

    Attributes
    ----------
    points
        Per path point.
    joints
        Coordinate joints (the order of every command).
    hold
        What the exact compensation holds: ``pose`` or ``position``.
    model
        The elastic model used.
    table
        The path as read (its columns, repeated in :meth:`csv`), or its coordinates as
        columns named after the joints (:meth:`JointPath.of_coordinates`).
    deg
        Whether the commands are written in degrees (:meth:`to_dict`, :meth:`csv`; the
        attributes stay SI).
    """

    points: list[PointCompensation]
    joints: tuple[str, ...]
    hold: str
    model: ElasticModel
    table: JointPath
    deg: bool = False

    def _scale(self) -> np.ndarray:
        """Factor from SI to the written unit of each coordinate (deg for angles with
        :attr:`deg`)."""
        return np.where(self.table.angular & self.deg, 180.0 / np.pi, 1.0)

    def to_dict(self) -> dict:
        """The object ``stiffness compensate --json`` prints: ``robot``, ``joints``, ``rows``
        (commands in the written unit, the rest SI), ``summary`` and ``units``."""
        scale = self._scale()
        unit = ["deg" if (a and self.deg) else ("rad" if a else "m")
                for a in self.table.angular]
        rows = [{
            "q_command": (p.command * scale).tolist(),
            "q_command_first_order": (p.command_first_order * scale).tolist(),
            "deflection": p.deflection.tolist(),
            "residual": p.residual.tolist(),
            "residual_first_order": p.residual_first_order.tolist(),
            "rotation_deflection": p.rotation_deflection.tolist(),
            "rotation_residual": p.rotation_residual.tolist(),
            "rotation_residual_first_order": p.rotation_residual_first_order.tolist(),
            "method": p.method,
        } for p in self.points]
        return {
            "robot": self.model.robot.name,
            "joints": list(self.joints),
            "rows": rows,
            "summary": self.summary(),
            "units": {"q_command": unit, "q_command_first_order": unit, "deflection": "m",
                      "residual": "m", "residual_first_order": "m",
                      "rotation_deflection": "rad", "rotation_residual": "rad",
                      "rotation_residual_first_order": "rad",
                      "summary": "m (rad for rotation keys)"},
        }

    def csv(self) -> str:
        """``OUT.csv`` of ``stiffness compensate``: the input columns, ``<joint>_cmd`` (and
        ``q<i>_cmd`` when the input names the coordinates q1..qn; the written unit), ``dx..``,
        ``ex..``, ``ex1..`` (m)."""
        table = self.table
        scale = self._scale()
        buf = io.StringIO()
        writer = csv.writer(buf, lineterminator="\n")
        names = [f"{j}_cmd" for j in self.joints]
        aliases = [f"{c}_cmd" for c in table.column_of if f"{c}_cmd" not in names]
        writer.writerow(table.header + names + aliases
                        + ["dx", "dy", "dz", "ex", "ey", "ez", "ex1", "ey1", "ez1"])
        for cells, p in zip(table.cells, self.points, strict=True):
            cells = cells + [""] * (len(table.header) - len(cells))
            command = [number_text(v) for v in p.command * scale]
            writer.writerow(cells[: len(table.header)] + command + (command if aliases else [])
                            + [number_text(v) for v in np.concatenate(
                                [p.deflection, p.residual, p.residual_first_order])])
        return buf.getvalue()

    def write(self, out: str | os.PathLike) -> Path:
        """Write :meth:`csv` to ``out`` atomically; returns its path."""
        return atomic_write(out, self.csv())

    def array(self, name: str) -> np.ndarray:
        """(m, k) stack of a per-point attribute, e.g. ``"residual"``."""
        return np.array([getattr(p, name) for p in self.points])

    def summary(self) -> dict:
        """``max_deflection_m``, ``rms_deflection_m``, ``max_residual_m``,
        ``max_residual_first_order_m`` (norms of the position errors), and more."""
        d = np.linalg.norm(self.array("deflection"), axis=1)
        e = np.linalg.norm(self.array("residual"), axis=1)
        e1 = np.linalg.norm(self.array("residual_first_order"), axis=1)
        er = np.linalg.norm(self.array("rotation_residual"), axis=1)
        return {
            "max_deflection_m": float(d.max()),
            "rms_deflection_m": float(np.sqrt(np.mean(d ** 2))),
            "max_residual_m": float(e.max()),
            "max_residual_first_order_m": float(e1.max()),
            "rms_residual_first_order_m": float(np.sqrt(np.mean(e1 ** 2))),
            "max_rotation_residual_rad": float(er.max()),
            "points": len(self.points),
            "hold": self.hold,
            "method": sorted({p.method for p in self.points}),
            "model": self.model.describe(),
            "ignored_effects": list(self.model.ignored),
        }


def compensate(
    model: ElasticModel | Robot | str | Path,
    path: np.ndarray | str | Path,
    wrench: np.ndarray | list[float] | None = None,
    wrench_frame: str = "base",
    hold: str = "auto",
    method: str = "auto",
    progress: Callable[[int, int], None] | None = None,
    k_theta: np.ndarray | list[float] | None = None,
    deg: bool = False,
) -> PathCompensation:
    """Joint commands that cancel the deflection along a path (see the module docstring):
    ``stiffness compensate`` (:meth:`PathCompensation.to_dict` is its ``--json`` object,
    :meth:`PathCompensation.write` its ``--out`` file).

    Parameters
    ----------
    model
        The elastic model (:meth:`ElasticModel.joint_springs`), a model file's path
        (:func:`stiffness.elastic.model_file.load_model`), or a robot with ``k_theta``.
    path
        (m, n) nominal coordinates (rad, m), one row per point, model coordinate order; or a
        ``PATH.csv`` (:func:`read_joint_path`; ``deg`` for angles in degrees; its per-row loads
        are used when ``wrench`` is None).
    wrench
        One process wrench (3,) or (6,) for every point, or (m, 6) one per point (N, N.m).
    wrench_frame
        ``base``: base axes; ``target``: the target frame's axes at each nominal pose (held
        fixed in the base while the robot deflects, a dead load).
    hold
        ``pose``, ``position`` or ``auto`` (``pose`` when the coordinates can hold it).
    method
        ``auto``, ``closed-form`` or ``general`` (:func:`compensate_point`).
    progress
        Called with (done, total) after each point.
    k_theta
        Joint springs (N.m/rad, N/m) when ``model`` is a robot (default: its shipped ones).
    deg
        Angles of a ``PATH.csv``, and the commands :meth:`PathCompensation.to_dict` and
        :meth:`PathCompensation.write` give, are in degrees (an array ``path`` stays rad).

    Raises
    ------
    StiffnessError
        A bad path or wrench, or a point where a solve fails (the message names the row).
    """
    em = load_model(model, k_theta)
    table, path, wrench = path_and_wrench(em.robot, path, wrench, deg)
    if wrench_frame not in WRENCH_FRAMES:
        raise StiffnessError(f"wrench frame must be base or target, got {wrench_frame!r}")
    w = np.asarray(wrench, dtype=float)
    w = np.array([as_wrench(r) for r in (w.reshape(1, -1) if w.ndim == 1 else w)])
    if w.shape[0] == 1:
        w = np.repeat(w, path.shape[0], axis=0)
    if w.shape[0] != path.shape[0]:
        raise StiffnessError(f"{w.shape[0]} wrenches for {path.shape[0]} path points")
    lo, hi = coordinate_limits(em.full)
    for i, row in enumerate(path):
        bad = np.flatnonzero((row < lo - 1e-12) | (row > hi + 1e-12))
        if bad.size:
            j = bad[0]
            raise StiffnessError(
                f"path row {i + 1}: {em.robot.coordinate_joints[j]} = {row[j]:.6g} is beyond "
                f"its limits [{lo[j]:.6g}, {hi[j]:.6g}] (rad or m); fix the path or its unit")
    points: list[PointCompensation] = []
    seed = None
    chosen = hold
    compensator = None
    for i, coords in enumerate(path):
        try:
            q = em.full.configuration(coords, seed=seed)
            if chosen == "auto":
                chosen = choose_hold(em, q)
        except StiffnessError as exc:
            raise with_context(exc, f"path row {i + 1}") from exc
        if compensator is None:  # refuses a method the model cannot take: not the row's fault
            compensator = em.compensator(hold=chosen, method=method)
        try:
            load = w[i].copy()
            if wrench_frame == "target":
                kinematics.update_first_order(em.full.model, em.full.data, q)
                rot = em.full.data.oMf[em.full.target_frame_id].rotation
                load = np.concatenate([rot @ load[:3], rot @ load[3:]])
            point = compensate_point(em, coords, load, chosen, method, seed_q=q,
                                     compensator=compensator)
        except StiffnessError as exc:
            raise with_context(exc, f"path row {i + 1}") from exc
        points.append(point)
        seed = point.q_nominal
        if progress is not None:
            progress(i + 1, path.shape[0])
    return PathCompensation(points, tuple(em.robot.coordinate_joints), chosen, em, table, deg)


def path_and_wrench(robot: Robot, path: np.ndarray | str | Path,
                     wrench: np.ndarray | list[float] | None, deg: bool
                     ) -> tuple[JointPath, np.ndarray, np.ndarray | list[float]]:
    """The path as a table, its coordinates (m, n) (SI, checked finite) and the wrench: the
    given one, or the path file's per-row loads (not both).

    Raises
    ------
    StiffnessError
        A path of the wrong width or with a NaN, a wrench both given and in the file, none.
    """
    source = None
    if isinstance(path, str | Path):
        table = read_joint_path(path, robot, deg=deg)
        if wrench is not None and table.wrench is not None:
            raise StiffnessError(f"{path} carries per-row loads (fx,fy,fz...): drop --wrench, "
                                 "or drop those columns")
        source, path = path, table.coords
        if wrench is None:
            wrench = table.wrench
    path = np.atleast_2d(np.asarray(path, dtype=float))
    n = robot.n_coordinates
    if path.shape[1] != n or path.shape[0] == 0:
        raise StiffnessError(
            f"the path needs one column per coordinate of {robot.title} "
            f"({', '.join(robot.coordinate_joints)}); got shape {path.shape}")
    if not np.all(np.isfinite(path)):
        row = int(np.argwhere(~np.isfinite(path))[0, 0])
        raise StiffnessError(f"path row {row + 1} holds a NaN or infinite coordinate; fix it")
    if wrench is None:
        raise StiffnessError("give a wrench (fx,fy,fz[,mx,my,mz] in N, N.m)" if source is None
                             else "give --wrench fx,fy,fz[,mx,my,mz] (N, N.m), or per-row "
                             f"fx,fy,fz columns in {source}")
    if source is None:
        table = JointPath.of_coordinates(robot, path)
    return table, path, wrench


# ------------------------------------------------------------------------------------------
# path files


@dataclass
class JointPath:
    """A joint path read from CSV.

    Attributes
    ----------
    header
        The input columns, as given.
    cells
        The input cells (text), one list per row.
    coords
        (m, n) coordinates in SI (rad, m), model coordinate order.
    wrench
        (m, 6) per-row wrenches (N, N.m), or None.
    column_of
        Input column name of each coordinate.
    angular
        (n,) whether each coordinate is an angle (converted by ``--deg``).
    lines
        File line (1-based) of each row.
    """

    header: list[str]
    cells: list[list[str]]
    coords: np.ndarray
    wrench: np.ndarray | None
    column_of: list[str]
    angular: np.ndarray
    lines: list[int] = field(default_factory=list)

    @classmethod
    def of_coordinates(cls, robot: Robot, coords: np.ndarray) -> JointPath:
        """A path given as (m, n) coordinates (rad, m): one column per coordinate joint, the
        values written in SI."""
        joints = list(robot.coordinate_joints)
        return cls(joints, [[repr(float(v)) for v in row] for row in coords], coords, None,
                   joints, angular_coordinates(robot))


def angular_coordinates(robot: Robot) -> np.ndarray:
    """(n,) whether each coordinate of ``robot`` is an angle (not a prismatic joint's)."""
    return np.array([not robot.is_prismatic(j) for j in robot.coordinate_joints])


@dataclass
class Table:
    """A CSV table: its header, and its non-empty rows with their 1-based file line numbers."""

    path: Path
    header: list[str]
    rows: list[list[str]]
    lines: list[int]

    def column(self, name: str) -> np.ndarray:
        """The finite numbers of column ``name``.

        Raises
        ------
        FileFormatError
            A cell that is not a finite number (its line, column and name).
        """
        k = self.header.index(name)
        out = np.empty(len(self.rows))
        for r, (row, line) in enumerate(zip(self.rows, self.lines, strict=True)):
            cell = row[k].strip() if k < len(row) else ""
            try:
                value = csv_float(cell)
            except ValueError as exc:
                problem = str(exc) if "_" in cell else \
                    f"{cell!r} is not a number; every value must be one"
                raise FileFormatError(problem, path=self.path, line=line, column=k + 1,
                                      field=name) from None
            if not math.isfinite(value):
                raise FileFormatError(f"{cell!r}: every value must be a finite number",
                                      path=self.path, line=line, column=k + 1, field=name)
            out[r] = value
        return out

    def wrenches(self) -> np.ndarray | None:
        """(m, 6) per-row loads of columns ``fx,fy,fz[,mx,my,mz]`` (N, N.m), or None."""
        present = [c for c in WRENCH_COLUMNS if c in self.header]
        if not present:
            return None
        if not all(c in present for c in WRENCH_COLUMNS[:3]) or len(present) not in (3, 6):
            raise FileFormatError("per-row loads need the columns fx, fy, fz (N), and "
                                  "optionally all of mx, my, mz (N.m)", path=self.path, line=1)
        out = np.zeros((len(self.rows), 6))
        for k, c in enumerate(WRENCH_COLUMNS):
            if c in present:
                out[:, k] = self.column(c)
        return out


def read_table(path: str | Path, what: str) -> Table:
    """Read a CSV file with a header line (``what`` names it in errors).

    Raises
    ------
    MissingFileError
        The file cannot be read.
    FileFormatError
        Not UTF-8 text, no data row, or a column name given twice.
    """
    path = Path(path)
    text = read_text(path, what)
    rows, lines = [], []
    for row in csv.reader(io.StringIO(text)):
        if row and any(c.strip() for c in row):
            rows.append(row)
    # csv.reader does not give line numbers: count them on the text (no quoted newlines)
    numbered = [k + 1 for k, line in enumerate(text.splitlines()) if line.strip(" ,\t")]
    lines = numbered[: len(rows)]
    if len(rows) < 2:
        raise FileFormatError(f"no {what} rows: give a header line and one row per point",
                              path=path)
    header = [h.strip() for h in rows[0]]
    check_csv_header(header, path, lines[0])
    for k, name in enumerate(header):
        if name and name in header[:k]:
            raise FileFormatError(f"the column {name!r} appears twice (columns "
                                  f"{header.index(name) + 1} and {k + 1}); name each column once",
                                  path=path, line=lines[0], column=k + 1)
    return Table(path, header, rows[1:], lines[1:])


def read_joint_path(path: str | Path, robot: Robot, deg: bool = False) -> JointPath:
    """Read ``PATH.csv``: one column per coordinate, named by joint name or ``q1..qn`` (model
    coordinate order), or one per joint outside the end-effector branch
    (``robot.chain_joints``: the fingers then keep their reference value), or, by joint name,
    at least every joint that moves the target (:func:`target_chain`; the others, another
    limb's, keep their reference value, said in a :class:`DataFileNote`), one row per point;
    optional ``fx,fy,fz[,mx,my,mz]`` (N, N.m) per row.

    Raises
    ------
    MissingFileError, FileFormatError
        Unreadable file, a missing coordinate column, a value that is not a finite number
        (named by line and column).
    """
    table = read_table(path, "path file")
    written = table.header  # the input's own column names, carried to the output
    table.header = _without_units(table, robot, deg)
    header = table.header
    joints = list(robot.coordinate_joints)
    chain = list(robot.chain_joints)
    by_index = [f"q{i + 1}" for i in range(len(joints))]
    if all(j in header for j in joints):
        column_of = joints
    elif all(q in header for q in by_index):
        column_of = by_index
    elif robot.branch_joints and all(j in header for j in chain):
        column_of = chain  # the fingers of an end effector keep their reference value
    elif all(j in header for j in target_chain(robot)) and not set(by_index) & set(header):
        column_of = [j for j in joints if j in header]  # the other limbs keep theirs
        held = [j for j in joints if j not in header]
        warnings.warn(f"{table.path}: {len(held)} of {len(joints)} coordinates have no column "
                      f"and are held at the reference configuration (they do not move the "
                      f"target): {listed(held)}", DataFileNote, stacklevel=2)
    else:
        missing = [j for j in target_chain(robot) if j not in header]
        missing_q = [q for q in by_index if q not in header]
        shown = missing if len(missing) <= len(missing_q) else missing_q
        other = "" if set(header) & set(joints + by_index) else (
            " (its columns name none of them: is the model file of another robot?)")
        raise FileFormatError(
            f"lacks the coordinate column(s) {', '.join(shown)} of {robot.title}{other}: name "
            f"one column per coordinate ({', '.join(joints)}, or q1..q{len(joints)})",
            path=table.path, line=1)
    angular = angular_coordinates(robot)
    reference = default_coordinates(robot)
    coords = np.tile(np.zeros(len(joints)) if reference is None else reference,
                     (len(table.rows), 1))
    for name, column in zip(joints if column_of is by_index else column_of, column_of,
                            strict=True):
        k = joints.index(name)
        values = table.column(column)
        coords[:, k] = np.deg2rad(values) if deg and angular[k] else values
    wrench = table.wrenches()
    return JointPath(written, [list(r) for r in table.rows], coords, wrench, column_of, angular,
                     table.lines)


#: A column name with its unit in brackets: ``elbow_joint [deg]``, ``fx [N]``.
_HEADER_UNIT = re.compile(r"^(.*?)\s*\[\s*([^\[\]\s]+)\s*\]$")


def _without_units(table: Table, robot: Robot, deg: bool) -> list[str]:
    """The path's header without the units in brackets of its coordinate and load columns,
    each checked against the unit it is read in: rad (deg with ``--deg``), m for a prismatic
    joint, N and N.m (:func:`header_without_units`)."""
    angular = angular_coordinates(robot)
    expected = {}
    for k, joint in enumerate(robot.coordinate_joints):
        expected[joint] = expected[f"q{k + 1}"] = ("deg" if deg else "rad") if angular[k] else "m"
    return header_without_units(table, expected)


def header_without_units(table: Table, expected: dict[str, str]) -> list[str]:
    """``table``'s header with the unit in brackets dropped from the columns of ``expected``
    and the load columns (``elbow_joint [deg]`` -> ``elbow_joint``, ``fx [N]`` -> ``fx``), each
    unit checked against the one the column is read in (``expected``'s, N and N.m or Nm for
    the loads).

    Raises
    ------
    FileFormatError
        A unit that is not the one the column is read in (the fix named), or a column named
        twice once the units are dropped.
    """
    expected = {c: "N" for c in WRENCH_COLUMNS[:3]} | {c: "N.m" for c in WRENCH_COLUMNS[3:]} \
        | expected
    bare: list[str] = []
    for k, name in enumerate(table.header):
        match = _HEADER_UNIT.match(name)
        column, unit = match.groups() if match else (name, None)
        if unit is None or column not in expected:
            bare.append(name)
            continue
        want = expected[column]
        if unit != want and {unit, want} != {"N.m", "Nm"}:
            fix = {("deg", "rad"): "give --deg", ("rad", "deg"): "drop --deg"}.get(
                (unit, want), f"convert the column to {want}")
            raise FileFormatError(f"the header says {unit} but {column} is read in {want}; "
                                  f"{fix}", path=table.path, line=1, column=k + 1, field=name)
        if column in bare or column in table.header[k + 1:]:
            raise FileFormatError(f"the column {column!r} appears twice; name each column once",
                                  path=table.path, line=1, column=k + 1, field=name)
        bare.append(column)
    return bare


def target_chain(robot: Robot) -> list[str]:
    """The coordinate joints that move the target: those of its chain from the base and the
    leaders of mimic followers on it, in coordinate order; every coordinate of a robot with
    closed loops or a controller map (the target may depend on any of them)."""
    if not robot.loop.is_open_chain or robot.coupling is not None:
        return list(robot.coordinate_joints)
    model = robot.model
    support = {model.names[i] for i in model.supports[model.frames[robot.target_frame_id]
                                                       .parentJoint]}
    support |= {m.leader for m in robot.mimics if m.follower in support}
    return [j for j in robot.coordinate_joints if j in support]
