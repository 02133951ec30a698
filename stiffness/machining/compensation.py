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
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.elastic.compensator import Compensator, choose_hold
from stiffness.elastic.loaded import (
    bent_kinematics,
    frozen_axes,
    linear_shift,
    loaded_equilibrium,
)
from stiffness.elastic.model import ElasticModel
from stiffness.elastic.model_file import load_model
from stiffness.errors import StiffnessError, with_context
from stiffness.files import atomic_write, number_text
from stiffness.machining.joint_path import JointPath, read_joint_path
from stiffness.mechanics.equilibrium import solve_equilibrium
from stiffness.mechanics.formulation import as_wrench, target_state
from stiffness.mechanics.ik import HOLDS, coordinate_limits, solve_ik
from stiffness.robot import kinematics
from stiffness.robot.robot import Robot
from stiffness.units import float_array

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
    w = point_wrenches(wrench, path.shape[0])
    check_path_limits(em, path)
    points: list[PointCompensation] = []
    seed = None
    chosen = hold
    compensator = None
    closed_form = hold == "auto" and em.compensator(method=method).method == "closed-form"
    for i, coords in enumerate(path):
        try:
            q = em.full.configuration(coords, seed=seed)
            if chosen == "auto":
                chosen = choose_hold(em, q, generic=closed_form)
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


def check_path_limits(em: ElasticModel, path: np.ndarray) -> None:
    """Refuse a path (m, n) (rad, m) with a coordinate beyond its joint limits (often a path
    in degrees read as radians).

    Raises
    ------
    StiffnessError
        The first such row, named with its joint, value and limits.
    """
    lo, hi = coordinate_limits(em.full)
    for i, row in enumerate(path):
        bad = np.flatnonzero((row < lo - 1e-12) | (row > hi + 1e-12))
        if bad.size:
            j = bad[0]
            raise StiffnessError(
                f"path row {i + 1}: {em.robot.coordinate_joints[j]} = {row[j]:.6g} is beyond "
                f"its limits [{lo[j]:.6g}, {hi[j]:.6g}] (rad or m); fix the path or its unit")


def point_wrenches(wrench: object, m: int) -> np.ndarray:
    """The wrench (m, 6) [N; N.m] at each of ``m`` path points: one force (3,) or wrench (6,)
    for all, or one per point (m, 3) or (m, 6).

    Raises
    ------
    StiffnessError
        Not numbers, rows of neither 3 nor 6 values, another number of rows, a NaN.
    """
    w = float_array(wrench, "wrench", "fx,fy,fz[,mx,my,mz] (N, N.m), or one such row per point",
                    finite=False)
    w = np.array([as_wrench(r) for r in (w.reshape(1, -1) if w.ndim == 1 else w)])
    w = np.repeat(w, m, axis=0) if w.shape[0] == 1 else w
    if w.shape[0] != m:
        raise StiffnessError(f"{w.shape[0]} wrenches for {m} path points")
    return w


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
    n = robot.n_coordinates
    path = np.atleast_2d(float_array(path, "path", f"(m, {n}) coordinates of {robot.title} "
                                     "(rad, m; deg with deg=True) or a joint path file",
                                     finite=False))
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
