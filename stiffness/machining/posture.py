"""The stiffest posture along a path: the free rotation about the tool axis (and a redundant
arm's null space) chosen to minimise the deflection under the process wrench.

A path point is a target position and either a tool axis (the direction the target frame's
*free axis* must point along, base frame) or a full orientation. The process is symmetric about
the free axis, so every rotation ``psi`` about it is an admissible pose:
``R(psi) = R_0 exp(psi f)``, ``f`` the free axis in the target frame, ``R_0`` the given
orientation or, for an axis, the frame carried along the path by minimal rotations from the
first point's (so a constant ``psi`` does not spin the tool).

Algorithm:

1. Candidates: ``S`` angles ``psi_ref + 2 pi k / S`` per point. Each is solved by damped least
   squares inverse kinematics (:func:`stiffness.mechanics.ik.solve_ik`, joint limits held)
   seeded from the same candidate at the previous point, so every candidate is a continuous
   track; a candidate is admissible when the IK converges within the limits and the smallest
   singular value of the target Jacobian is at least the singularity margin.
2. Dynamic programming over the candidates: minimise the sum of squared deflections
   ``|C W|`` (the model's first-order position deflection, every effect included) with the joint
   change between consecutive points at most ``max_step`` and, where the fixed-angle posture is
   admissible, no point worse than it (the fixed-angle track is one of the DP's paths).
3. Local refinement: each point's angle is refined continuously within one candidate spacing
   (bounded scalar minimisation) under the same constraints; a redundant arm then descends the
   deflection in the null space of its pose Jacobian (IK re-projects every step onto the pose).

Units: m, rad inside (the ``deg`` names report degrees); deflections in m.
"""

from __future__ import annotations

import csv
import io
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.elastic.loaded import ElasticModel, as_elastic_model, linear_deflection
from stiffness.errors import ConvergenceError, StiffnessError
from stiffness.files import atomic_write
from stiffness.machining.compensation import WRENCH_FRAMES, angular_coordinates
from stiffness.machining.poses import Poses, free_axis_vector, read_poses, tool_frames
from stiffness.mechanics.defaults import default_coordinates
from stiffness.mechanics.formulation import as_wrench, target_state
from stiffness.mechanics.ik import IKResult, coordinate_limits, solve_ik
from stiffness.robot.robot import Robot

#: Most candidate angles about the free axis (0.1 deg apart); the search costs steps^2.
MAX_STEPS = 3600


@dataclass
class PosturePoint:
    """The chosen posture at one path point.

    Attributes
    ----------
    coords
        Joint coordinates (rad, m).
    angle
        Chosen rotation about the free axis (rad), relative to the point's reference frame.
    deflection
        First-order position deflection (3,) with the chosen posture (m).
    deflection_fixed
        The same with the fixed angle (m); NaN where that posture is out of reach.
    ik_position_error, ik_rotation_error
        Remaining IK error of the chosen posture (m, rad).
    """

    coords: np.ndarray
    angle: float
    deflection: np.ndarray
    deflection_fixed: np.ndarray
    ik_position_error: float
    ik_rotation_error: float
    q: np.ndarray = field(repr=False)


@dataclass
class PostureResult:
    """The posture path.

    Attributes
    ----------
    points
        Per path point.
    joints
        Coordinate joints (the order of ``coords``).
    reference_angle
        The fixed angle compared against (rad).
    angles
        The ``S`` candidate angles (rad).
    notes
        What the user should know (e.g. the fixed-angle path breaks the step bound).
    poses
        The path as read (its columns, repeated in :meth:`csv`), or as given.
    angular
        (n,) whether each coordinate is an angle.
    deg
        Whether :meth:`to_dict` and :meth:`csv` give the angles in degrees (else rad).
    """

    points: list[PosturePoint]
    joints: tuple[str, ...]
    reference_angle: float
    angles: np.ndarray
    max_step: float
    notes: list[str]
    poses: Poses
    angular: np.ndarray
    deg: bool = False

    def _scale(self) -> np.ndarray:
        """Factor from SI to the written unit of each coordinate."""
        return np.where(self.angular & self.deg, 180.0 / np.pi, 1.0)

    def to_dict(self) -> dict:
        """The object ``stiffness posture --json`` prints: ``joints``, ``rows`` (joint values
        in the written unit, the rest SI), ``summary``, ``notes``, ``units``."""
        def num(v: float):
            return float(v) if math.isfinite(v) else None

        scale = self._scale()
        unit = ["deg" if (a and self.deg) else ("rad" if a else "m") for a in self.angular]
        rows = [{"q": (p.coords * scale).tolist(), "angle_deg": float(np.rad2deg(p.angle)),
                 "deflection_m": float(np.linalg.norm(p.deflection)),
                 "deflection": p.deflection.tolist(),
                 "deflection_fixed_m": num(np.linalg.norm(p.deflection_fixed)),
                 "ik_residual_m": p.ik_position_error, "ik_residual_rad": p.ik_rotation_error}
                for p in self.points]
        return {"joints": list(self.joints), "rows": rows, "summary": self.summary(),
                "notes": self.notes,
                "units": {"q": unit, "angle_deg": "deg", "deflection_m": "m",
                          "deflection": "m", "deflection_fixed_m": "m", "ik_residual_m": "m",
                          "ik_residual_rad": "rad"}}

    def csv(self) -> str:
        """``OUT.csv`` of ``stiffness posture``: the input columns, the joints (written unit),
        the angle (deg), the deflections (m) and the IK residuals (m, rad) per point."""
        def num(value: float) -> str:
            return repr(float(value)) if math.isfinite(value) else ""

        scale = self._scale()
        buf = io.StringIO()
        writer = csv.writer(buf, lineterminator="\n")
        header = self.poses.header
        writer.writerow(header + list(self.joints) + [
            "angle_deg", "deflection_m", "deflection_fixed_m", "ik_residual_m",
            "ik_residual_rad"])
        for cells, p in zip(self.poses.cells, self.points, strict=True):
            cells = (cells + [""] * len(header))[: len(header)]
            writer.writerow(cells + [num(v) for v in p.coords * scale] + [
                num(np.rad2deg(p.angle)), num(np.linalg.norm(p.deflection)),
                num(np.linalg.norm(p.deflection_fixed)), num(p.ik_position_error),
                num(p.ik_rotation_error)])
        return buf.getvalue()

    def figure_png(self) -> bytes:
        """PNG: deflection with the chosen posture and with the fixed angle, and the angle."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        index = np.arange(1, len(self.points) + 1)
        chosen = [1e3 * np.linalg.norm(p.deflection) for p in self.points]
        fixed = [1e3 * np.linalg.norm(p.deflection_fixed) for p in self.points]
        fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(7, 5), sharex=True)
        ax1.plot(index, fixed, "o-", ms=3, label=f"fixed angle "
                 f"({np.rad2deg(self.reference_angle):.3g} deg)")
        ax1.plot(index, chosen, "o-", ms=3, label="chosen posture")
        ax1.set_ylabel("deflection (mm)")
        ax1.legend()
        ax1.grid(alpha=0.3)
        ax2.plot(index, [np.rad2deg(p.angle) for p in self.points], "o-", ms=3)
        ax2.set_ylabel("angle about free axis (deg)")
        ax2.set_xlabel("path point")
        ax2.grid(alpha=0.3)
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=110)
        plt.close(fig)
        return buf.getvalue()

    def write(self, out: str | os.PathLike | None, figure: str | os.PathLike | None = None
              ) -> list[Path]:
        """Write :meth:`csv` to ``out`` and :meth:`figure_png` to ``figure`` (either may be
        ``None``), both computed before either is written; returns the paths written."""
        text = self.csv() if out is not None else None
        png = self.figure_png() if figure is not None else None
        written = []
        if out is not None:
            written.append(atomic_write(out, text))
        if figure is not None:
            written.append(atomic_write(figure, png))
        return written

    def joint_path(self) -> np.ndarray:
        """(m, n) joint coordinates (rad, m)."""
        return np.array([p.coords for p in self.points])

    def summary(self) -> dict:
        """Max/RMS deflections (m) chosen and fixed, their ratio, the largest joint step."""
        d = np.array([np.linalg.norm(p.deflection) for p in self.points])
        f = np.array([np.linalg.norm(p.deflection_fixed) for p in self.points])
        ok = np.isfinite(f)
        steps = np.abs(np.diff(self.joint_path(), axis=0))
        out = {
            "max_deflection_m": float(d.max()),
            "rms_deflection_m": float(np.sqrt(np.mean(d ** 2))),
            "max_deflection_fixed_m": float(f[ok].max()) if ok.any() else None,
            "rms_deflection_fixed_m": float(np.sqrt(np.mean(f[ok] ** 2))) if ok.any() else None,
            "fixed_reachable_points": int(ok.sum()),
            "max_joint_step_deg": float(np.rad2deg(steps.max())) if steps.size else 0.0,
            "max_ik_residual_m": float(max(p.ik_position_error for p in self.points)),
            "max_ik_residual_rad": float(max(p.ik_rotation_error for p in self.points)),
            "reference_angle_deg": float(np.rad2deg(self.reference_angle)),
            "points": len(self.points),
        }
        if ok.all() and d.max() > 0:
            out["max_reduction_factor"] = float(f.max() / d.max())
            out["rms_reduction_factor"] = float(np.sqrt(np.mean(f ** 2) / np.mean(d ** 2)))
        return out


class _Problem:
    """Shared state of one posture search."""

    def __init__(self, em: ElasticModel, positions, frames, free, wrench, wrench_frame,
                 margin, max_step, angular):
        self.em, self.full = em, em.full
        self.positions, self.frames, self.free = positions, frames, free
        self.wrench, self.wrench_frame = wrench, wrench_frame
        self.margin, self.max_step, self.angular = margin, max_step, angular

    def rotation(self, i: int, psi: float) -> np.ndarray:
        return self.frames[i] @ pin.exp3(psi * self.free)

    def solve(self, i: int, psi: float, seeds: list[tuple[np.ndarray, np.ndarray]]
              ) -> IKResult | None:
        """IK of point ``i`` at angle ``psi`` from the first seed that converges."""
        for coords, q in seeds:
            try:
                return solve_ik(self.full, self.positions[i], self.rotation(i, psi),
                                seed=coords, seed_q=q)
            except StiffnessError:
                continue
        return None

    def admissible(self, ik: IKResult) -> bool:
        jac = target_state(self.full, ik.q).jacobian
        return float(np.linalg.svd(jac, compute_uv=False)[-1]) >= self.margin

    def load(self, i: int, psi: float) -> np.ndarray:
        """Base-frame wrench of point ``i`` at angle ``psi``."""
        w = self.wrench[i]
        if self.wrench_frame == "target":
            r = self.rotation(i, psi)
            w = np.concatenate([r @ w[:3], r @ w[3:]])
        return w

    def deflection(self, i: int, psi: float, ik: IKResult) -> np.ndarray:
        return linear_deflection(self.em, ik.coords, self.load(i, psi), seed_q=ik.q)[:3]

    def step_ok(self, a: np.ndarray, b: np.ndarray) -> bool:
        return bool(np.all(np.abs(a - b)[self.angular] <= self.max_step + 1e-12))


def posture(
    model: ElasticModel | Robot | str | Path,
    positions: np.ndarray | str | Path,
    axes: np.ndarray | None = None,
    quaternions: np.ndarray | None = None,
    free_axis: str | np.ndarray = "z",
    wrench: np.ndarray | list[float] | None = None,
    wrench_frame: str = "base",
    steps: int = 36,
    max_step_deg: float = 10.0,
    reference_angle_deg: float = 0.0,
    singularity_margin: float = 1e-3,
    start: np.ndarray | None = None,
    refine: bool = True,
    progress: Callable[[int, int], None] | None = None,
    k_theta: np.ndarray | list[float] | None = None,
    deg: bool = False,
) -> PostureResult:
    """The stiffest admissible posture along a path (see the module docstring): ``stiffness
    posture`` (:meth:`PostureResult.to_dict` is its ``--json`` object,
    :meth:`PostureResult.write` its ``--out`` file and figure).

    Parameters
    ----------
    model
        The elastic model (robot, joint law, link bends), a model file's path, or a robot with
        ``k_theta`` (N.m/rad, N/m).
    positions
        (m, 3) target positions, base frame (m); or a ``POSES.csv`` (:func:`read_poses`).
    axes, quaternions
        (m, 3) tool axes (base frame) or (m, 4) orientations ``qw, qx, qy, qz``: one of them.
    free_axis
        The target frame's axis the process is symmetric about: ``x``, ``y``, ``z`` or a vector.
    wrench
        Process wrench (3,) or (6,) for every point, or (m, 6) per point (N, N.m).
    wrench_frame
        ``base`` or ``target`` (the target frame of each chosen posture).
    steps
        Candidate angles per point (``S``).
    max_step_deg
        Largest change of any revolute coordinate between consecutive points (deg).
    reference_angle_deg
        The fixed angle the result is compared with (deg), relative to each point's reference
        frame (the first point's orientation as given, carried along the path).
    singularity_margin
        Smallest admissible singular value of the 6-row target Jacobian (m/rad, rad/rad).
    start
        IK seed of the first point (rad, m); default the robot's shipped coordinates, else zero.
    refine, progress
        Whether to refine each angle locally after the dynamic programming; called with
        (done, total) as the points are solved.
    k_theta
        Joint springs (N.m/rad, N/m) when ``model`` is a robot.
    deg
        Whether :meth:`PostureResult.to_dict` and :meth:`PostureResult.write` give the joint
        values in degrees (the attributes stay rad).

    Raises
    ------
    StiffnessError
        Bad input, a point no candidate reaches (named by row), or no sequence within
        ``max_step_deg``.
    """
    em = as_elastic_model(model, k_theta)
    full = em.full
    poses, w = _poses_and_wrench(positions, axes, quaternions, wrench)
    _check_search(full, steps, max_step_deg, singularity_margin, wrench_frame)
    m = poses.positions.shape[0]
    free = free_axis_vector(free_axis)
    frames = tool_frames(free, poses.axes, poses.quaternions)
    angular = angular_coordinates(full)
    problem = _Problem(em, poses.positions, frames, free, w, wrench_frame, singularity_margin,
                       np.deg2rad(max_step_deg), angular)
    ref = np.deg2rad(reference_angle_deg)
    offsets = 2.0 * np.pi * np.arange(steps) / steps
    offsets = np.where(offsets > np.pi, offsets - 2.0 * np.pi, offsets)
    angles = ref + offsets
    if start is None:
        start = default_coordinates(full)
        start = np.zeros(full.n_coordinates) if start is None else start
    start = np.asarray(start, dtype=float)
    # 1. candidate tracks
    iks = _candidate_tracks(problem, offsets, angles, (start, full.configuration(start)),
                            progress, m if refine else 0)
    deflection, vectors, admissible = _candidate_deflections(problem, iks, angles)
    # 2. dynamic programming
    choice, notes = _choose_track(problem, iks, deflection, admissible, max_step_deg,
                                  singularity_margin)
    # 3. local refinement
    points = _chosen_points(problem, iks, choice, angles, vectors, deflection[:, 0],
                            progress if refine else None, refine)
    return PostureResult(points, tuple(full.coordinate_joints), float(ref), angles,
                         float(np.deg2rad(max_step_deg)), notes, poses, angular, deg)


def _choose_track(problem: _Problem, iks: list[list[IKResult | None]],
                  deflection: np.ndarray, admissible: np.ndarray, max_step_deg: float,
                  singularity_margin: float) -> tuple[list[int], list[str]]:
    """The candidate chosen per point (:func:`_cheapest_track`, bounded by the fixed angle
    where it can be) and a note when it cannot.

    Raises
    ------
    StiffnessError
        No track within the joint-step bound.
    """
    notes: list[str] = []
    choice = _cheapest_track(problem, iks, deflection, admissible, bounded=True)
    if choice is None:
        choice = _cheapest_track(problem, iks, deflection, admissible, bounded=False)
        if choice is not None:
            notes.append("the fixed-angle path itself breaks the joint-step bound or the "
                         "singularity margin somewhere: the chosen path is not bounded by it "
                         "point by point")
    if choice is None:
        raise StiffnessError(
            f"no posture sequence keeps every joint step within {max_step_deg:g} deg (with the "
            f"singularity margin {singularity_margin:g}); raise --max-step or --steps")
    return choice, notes


def _chosen_points(problem: _Problem, iks: list[list[IKResult | None]], choice: list[int],
                   angles: np.ndarray, vectors: np.ndarray, fixed: np.ndarray,
                   progress: Callable[[int, int], None] | None, refine: bool
                   ) -> list[PosturePoint]:
    """The chosen candidates (refined locally with ``refine``) as points, with the fixed
    angle's deflection (m; NaN where out of reach) beside them."""
    m, steps = vectors.shape[:2]
    chosen_psi = np.array([angles[k] for k in choice])
    chosen = [iks[i][k] for i, k in enumerate(choice)]
    chosen_defl = [vectors[i, k] for i, k in enumerate(choice)]
    if refine:
        total = m * steps
        for i in range(m):
            _refine_point(problem, i, chosen, chosen_psi, chosen_defl, fixed[i],
                          2.0 * np.pi / steps)
            if progress is not None:
                progress(total + i + 1, total + m)
    points = []
    for i in range(m):
        fixed_vec = vectors[i, 0] if np.isfinite(fixed[i]) else np.full(3, np.nan)
        ik = chosen[i]
        points.append(PosturePoint(ik.coords, float(chosen_psi[i]), chosen_defl[i], fixed_vec,
                                   ik.position_error, ik.rotation_error, ik.q))
    return points


def _poses_and_wrench(positions: np.ndarray | str | Path, axes: np.ndarray | None,
                      quaternions: np.ndarray | None, wrench: np.ndarray | list[float] | None
                      ) -> tuple[Poses, np.ndarray]:
    """The poses (read from a ``POSES.csv``, or the arrays as a table) and the (m, 6)
    wrenches (N, N.m): the given one, or the file's per-row loads (not both).

    Raises
    ------
    StiffnessError
        Bad shapes, NaNs, both or neither of axes and orientations, no or two wrenches.
    """
    source = None
    if isinstance(positions, str | Path):
        poses = read_poses(positions)
        if wrench is not None and poses.wrench is not None:
            raise StiffnessError(f"{positions} carries per-row loads (fx,fy,fz...): drop "
                                 "--wrench, or drop those columns")
        source, wrench = positions, poses.wrench if wrench is None else wrench
        positions, axes, quaternions = poses.positions, poses.axes, poses.quaternions
    positions = np.atleast_2d(np.asarray(positions, dtype=float))
    m = positions.shape[0]
    if positions.shape[1] != 3 or m == 0:
        raise StiffnessError(f"positions must be (m, 3) in m, got shape {positions.shape}")
    if (axes is None) == (quaternions is None):
        raise StiffnessError("give each point a tool axis (ax,ay,az) or an orientation "
                             "(qw,qx,qy,qz), not both")
    for name, arr in (("positions", positions), ("axes", axes), ("quaternions", quaternions)):
        if arr is not None and not np.all(np.isfinite(arr)):
            row = int(np.argwhere(~np.isfinite(np.atleast_2d(arr)))[0, 0])
            raise StiffnessError(f"row {row + 1}: {name} hold a NaN or infinity; fix the row")
    if source is None:
        poses = Poses.of_arrays(positions, axes, quaternions)
    if wrench is None:
        raise StiffnessError("give a process wrench (fx,fy,fz[,mx,my,mz] in N, N.m)")
    w = np.asarray(wrench, dtype=float)
    w = np.array([as_wrench(r) for r in (w.reshape(1, -1) if w.ndim == 1 else w)])
    w = np.repeat(w, m, axis=0) if w.shape[0] == 1 else w
    if w.shape[0] != m:
        raise StiffnessError(f"{w.shape[0]} wrenches for {m} path points")
    return poses, w


def _check_search(full: Robot, steps: int, max_step_deg: float, singularity_margin: float,
                  wrench_frame: str) -> None:
    """Refuse an arm that cannot hold a pose, or search settings out of range (one line)."""
    if full.n_coordinates < 6:
        raise StiffnessError(
            f"{full.name} has {full.n_coordinates} coordinates: choosing a posture about the "
            "tool axis needs an arm that can hold a full pose (6 or more)")
    if steps < 1 or not np.isfinite(max_step_deg) or max_step_deg <= 0:
        raise StiffnessError("--steps must be at least 1 and --max-step positive (deg)")
    if not (math.isfinite(singularity_margin) and singularity_margin >= 0):
        raise StiffnessError(f"--singularity-margin must be a finite number >= 0 (the smallest "
                             f"singular value of the target Jacobian), got {singularity_margin:g}")
    if steps > MAX_STEPS:
        raise StiffnessError(f"--steps {steps} is more than {MAX_STEPS} (angles 0.1 deg apart), "
                             "and the path search grows with its square; give at most "
                             f"{MAX_STEPS}")
    if wrench_frame not in WRENCH_FRAMES:
        raise StiffnessError(f"wrench frame must be base or target, got {wrench_frame!r}")


def _candidate_tracks(problem: _Problem, offsets: np.ndarray, angles: np.ndarray,
                      start: tuple[np.ndarray, np.ndarray],
                      progress: Callable[[int, int], None] | None, extra: int
                      ) -> list[list[IKResult | None]]:
    """The IK of every point at every candidate angle (rad; ``None`` where it fails), each
    seeded from the same angle at the previous point, the nearest solved angle, the previous
    point's first solution and ``start`` (coordinates, configuration); ``extra`` progress
    steps follow.

    Raises
    ------
    ConvergenceError
        A point no angle reaches.
    """
    m, steps = problem.positions.shape[0], len(angles)
    iks: list[list[IKResult | None]] = []
    sweep = sorted(range(steps), key=lambda k: (abs(offsets[k]), offsets[k]))
    for i in range(m):
        row: list[IKResult | None] = [None] * steps
        for k in (sweep if i == 0 else range(steps)):
            seeds = []
            if i > 0 and iks[i - 1][k] is not None:
                seeds.append((iks[i - 1][k].coords, iks[i - 1][k].q))
            near = [j for j in sweep if row[j] is not None]
            if near:
                j = min(near, key=lambda j: abs(np.angle(np.exp(1j * (offsets[j] - offsets[k])))))
                seeds.append((row[j].coords, row[j].q))
            if i > 0:
                prev = [r for r in iks[i - 1] if r is not None]
                if prev:
                    seeds.append((prev[0].coords, prev[0].q))
            seeds.append(start)
            row[k] = problem.solve(i, angles[k], seeds)
        if all(r is None for r in row):
            raise ConvergenceError(
                f"row {i + 1}: the pose at {np.round(problem.positions[i], 6).tolist()} m is out "
                "of reach for every angle about the free axis (within the joint limits); move it "
                "into the workspace")
        iks.append(row)
        if progress is not None:
            progress((i + 1) * steps, m * steps + extra)
    return iks


def _candidate_deflections(problem: _Problem, iks: list[list[IKResult | None]],
                           angles: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(m, S) deflection norms (m; inf where unsolved), (m, S, 3) deflections (m) and (m, S)
    admissibility (away from singularities) of the candidates."""
    m, steps = len(iks), len(angles)
    deflection = np.full((m, steps), np.inf)
    vectors = np.full((m, steps, 3), np.nan)
    admissible = np.zeros((m, steps), dtype=bool)
    for i in range(m):
        for k in range(steps):
            ik = iks[i][k]
            if ik is None:
                continue
            vectors[i, k] = problem.deflection(i, angles[k], ik)
            deflection[i, k] = float(np.linalg.norm(vectors[i, k]))
            admissible[i, k] = problem.admissible(ik)
    return deflection, vectors, admissible


def _cheapest_track(problem: _Problem, iks: list[list[IKResult | None]],
                    deflection: np.ndarray, admissible: np.ndarray, bounded: bool
                    ) -> list[int] | None:
    """Dynamic programming: the admissible candidate per point (indices) with the least sum
    of squared deflections whose joint steps stay within the bound; ``bounded``: no point
    worse than the fixed angle's (candidate 0) where that one is admissible. ``None``: none."""
    m, steps = deflection.shape
    fixed = deflection[:, 0]
    ok = admissible.copy()
    if bounded:
        ok &= ~np.isfinite(fixed[:, None]) | (deflection <= fixed[:, None] * (1 + 1e-12))
    cost = np.where(ok[0], deflection[0] ** 2, np.inf)
    back = np.zeros((m, steps), dtype=int)
    for i in range(1, m):
        new = np.full(steps, np.inf)
        for k in range(steps):
            if not ok[i, k]:
                continue
            for j in range(steps):
                if np.isfinite(cost[j]) and cost[j] < new[k] and problem.step_ok(
                        iks[i - 1][j].coords, iks[i][k].coords):
                    new[k], back[i, k] = cost[j], j
            new[k] += deflection[i, k] ** 2
        cost = new
        if not np.isfinite(cost).any():
            return None
    k = int(np.argmin(cost))
    if not np.isfinite(cost[k]):
        return None
    choice = [k]
    for i in range(m - 1, 0, -1):
        k = int(back[i, k])
        choice.append(k)
    return choice[::-1]


def _refine_point(problem: _Problem, i: int, chosen: list[IKResult], psi: np.ndarray,
                  defl: list[np.ndarray], bound: float, spacing: float) -> None:
    """Refine point ``i``'s angle (and null-space posture) in place under the constraints."""
    from scipy.optimize import minimize_scalar

    m = len(chosen)
    cache: dict[float, tuple[float, IKResult, np.ndarray]] = {}

    def feasible(ik: IKResult) -> bool:
        if i > 0 and not problem.step_ok(chosen[i - 1].coords, ik.coords):
            return False
        if i + 1 < m and not problem.step_ok(chosen[i + 1].coords, ik.coords):
            return False
        return problem.admissible(ik)

    def evaluate(angle: float) -> float:
        ik = problem.solve(i, angle, [(chosen[i].coords, chosen[i].q)])
        if ik is None or not feasible(ik):
            return np.inf
        vec = problem.deflection(i, angle, ik)
        value = float(np.linalg.norm(vec))
        if np.isfinite(bound) and value > bound * (1 + 1e-12):
            return np.inf
        cache[angle] = (value, ik, vec)
        return value

    current = float(np.linalg.norm(defl[i]))
    minimize_scalar(lambda a: min(evaluate(a), 1e9), bounds=(psi[i] - spacing, psi[i] + spacing),
                    method="bounded", options={"xatol": 1e-6})
    best = min(cache.items(), key=lambda kv: kv[1][0]) if cache else None
    if best is not None and best[1][0] < current:
        psi[i], (current, chosen[i], defl[i]) = best[0], best[1]
    if problem.full.n_coordinates > 6:
        _null_space_descent(problem, i, chosen, psi, defl, feasible, bound)


def _null_space_descent(problem: _Problem, i: int, chosen: list[IKResult], psi: np.ndarray,
                        defl: list[np.ndarray], feasible, bound: float,
                        iterations: int = 20) -> None:
    """Lower point ``i``'s deflection by moving in the null space of its pose Jacobian.

    Projected steepest descent: the coordinate gradient of ``|C W|`` (central differences)
    projected on the null space of the target Jacobian, joints at a limit that the step pushes
    outward held; a backtracking line search, each trial re-projected onto the pose by IK.
    """
    full = problem.full
    lo, hi = coordinate_limits(full)
    load = problem.load(i, psi[i])
    current = float(np.linalg.norm(defl[i]))

    def value_at(coords: np.ndarray, q: np.ndarray) -> float:
        return float(np.linalg.norm(linear_deflection(problem.em, coords, load, seed_q=q)[:3]))

    for _ in range(iterations):
        ik = chosen[i]
        jac = target_state(full, ik.q).jacobian
        free = np.linalg.norm(jac, axis=0) > 0
        grad = np.zeros(full.n_coordinates)
        h = 1e-6
        for j in np.flatnonzero(free):
            e = np.zeros(full.n_coordinates)
            e[j] = h
            grad[j] = (value_at(ik.coords + e, ik.q) - value_at(ik.coords - e, ik.q)) / (2 * h)
        direction = np.zeros(full.n_coordinates)
        for _ in range(full.n_coordinates):
            js = jac[:, free]
            proj = np.eye(js.shape[1]) - np.linalg.pinv(js, rcond=1e-9) @ js
            direction[:] = 0.0
            direction[free] = -proj @ grad[free]
            blocked = (((ik.coords <= lo + 1e-9) & (direction < 0))
                       | ((ik.coords >= hi - 1e-9) & (direction > 0)))
            if not blocked.any():
                break
            free &= ~blocked
        norm = float(np.linalg.norm(direction))
        if norm < 1e-12 * max(current, 1e-300):
            return
        direction /= norm
        improved = False
        for step in (0.3, 0.1, 0.03, 0.01, 0.003, 0.001):
            new = problem.solve(i, psi[i], [(ik.coords + step * direction, ik.q)])
            if new is None or not feasible(new):
                continue
            vec = problem.deflection(i, psi[i], new)
            value = float(np.linalg.norm(vec))
            if value < current * (1 - 1e-9) and (not np.isfinite(bound) or value <= bound):
                chosen[i], defl[i], current = new, vec, value
                improved = True
                break
        if not improved:
            return
