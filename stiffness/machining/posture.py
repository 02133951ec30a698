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

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.elastic.loaded import ElasticModel, as_elastic_model, linear_deflection
from stiffness.errors import ConvergenceError, FileFormatError, StiffnessError
from stiffness.machining.compensation import WRENCH_FRAMES, read_table
from stiffness.mechanics.formulation import as_wrench, target_state
from stiffness.mechanics.ik import IKResult, coordinate_limits, solve_ik
from stiffness.robot.robot import Robot

#: Named free axes (target frame).
AXES = {"x": np.array([1.0, 0.0, 0.0]), "y": np.array([0.0, 1.0, 0.0]),
        "z": np.array([0.0, 0.0, 1.0])}


#: Most candidate angles about the free axis (0.1 deg apart); the search costs steps^2.
MAX_STEPS = 3600


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


def read_poses(path: str | Path) -> Poses:
    """Read ``POSES.csv``: ``x,y,z`` (m) and ``ax,ay,az`` (tool axis) or ``qw,qx,qy,qz``, one
    row per point, optional ``fx,fy,fz[,mx,my,mz]`` (N, N.m) per row.

    Raises
    ------
    MissingFileError, FileFormatError
        Unreadable file, missing columns, a value that is not a finite number (line, column).
    """
    table = read_table(path, "pose file")
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

    return Poses(header, [list(r) for r in table.rows], block(("x", "y", "z")),
                 block(("ax", "ay", "az")) if has_axis else None,
                 block(("qw", "qx", "qy", "qz")) if has_quat else None, table.wrenches())


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
    """

    points: list[PosturePoint]
    joints: tuple[str, ...]
    reference_angle: float
    angles: np.ndarray
    max_step: float
    notes: list[str]

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
) -> PostureResult:
    """The stiffest admissible posture along a path (see the module docstring).

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

    Raises
    ------
    StiffnessError
        Bad input, a point no candidate reaches (named by row), or no sequence within
        ``max_step_deg``.
    """
    em = as_elastic_model(model, k_theta)
    full = em.full
    if isinstance(positions, str | Path):
        read = read_poses(positions)
        positions, axes, quaternions = read.positions, read.axes, read.quaternions
        wrench = read.wrench if wrench is None else wrench
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
    if wrench is None:
        raise StiffnessError("give a process wrench (fx,fy,fz[,mx,my,mz] in N, N.m)")
    w = np.asarray(wrench, dtype=float)
    w = np.array([as_wrench(r) for r in (w.reshape(1, -1) if w.ndim == 1 else w)])
    w = np.repeat(w, m, axis=0) if w.shape[0] == 1 else w
    if w.shape[0] != m:
        raise StiffnessError(f"{w.shape[0]} wrenches for {m} path points")
    free = free_axis_vector(free_axis)
    frames = tool_frames(free, axes, quaternions)
    model_ = full.model
    angular = np.array([not model_.joints[model_.getJointId(j)].shortname().startswith(
        "JointModelP") for j in full.coordinate_joints])
    problem = _Problem(em, positions, frames, free, w, wrench_frame, singularity_margin,
                       np.deg2rad(max_step_deg), angular)
    ref = np.deg2rad(reference_angle_deg)
    offsets = 2.0 * np.pi * np.arange(steps) / steps
    offsets = np.where(offsets > np.pi, offsets - 2.0 * np.pi, offsets)
    angles = ref + offsets
    if start is None:
        from stiffness.mechanics.defaults import default_coordinates

        start = default_coordinates(full)
        start = np.zeros(full.n_coordinates) if start is None else start
    start = np.asarray(start, dtype=float)
    q_start = full.configuration(start)

    # 1. candidate tracks
    iks: list[list[IKResult | None]] = []
    sweep = sorted(range(steps), key=lambda k: (abs(offsets[k]), offsets[k]))
    total = m * steps
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
            seeds.append((start, q_start))
            row[k] = problem.solve(i, angles[k], seeds)
        if all(r is None for r in row):
            raise ConvergenceError(
                f"row {i + 1}: the pose at {np.round(positions[i], 6).tolist()} m is out of "
                f"reach for every angle about the free axis (within the joint limits); move it "
                "into the workspace")
        iks.append(row)
        if progress is not None:
            progress((i + 1) * steps, total + (m if refine else 0))
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
    fixed = deflection[:, 0]
    notes: list[str] = []

    # 2. dynamic programming
    def dp(bounded: bool) -> list[int] | None:
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

    choice = dp(bounded=True)
    if choice is None:
        choice = dp(bounded=False)
        if choice is not None:
            notes.append("the fixed-angle path itself breaks the joint-step bound or the "
                         "singularity margin somewhere: the chosen path is not bounded by it "
                         "point by point")
    if choice is None:
        raise StiffnessError(
            f"no posture sequence keeps every joint step within {max_step_deg:g} deg (with the "
            f"singularity margin {singularity_margin:g}); raise --max-step or --steps")
    chosen_psi = np.array([angles[k] for k in choice])
    chosen = [iks[i][k] for i, k in enumerate(choice)]
    chosen_defl = [vectors[i, k] for i, k in enumerate(choice)]

    # 3. local refinement
    if refine:
        spacing = 2.0 * np.pi / steps
        for i in range(m):
            _refine_point(problem, i, chosen, chosen_psi, chosen_defl, fixed[i], spacing)
            if progress is not None:
                progress(total + i + 1, total + m)
    points = []
    for i in range(m):
        fixed_vec = vectors[i, 0] if np.isfinite(fixed[i]) else np.full(3, np.nan)
        ik = chosen[i]
        points.append(PosturePoint(ik.coords, float(chosen_psi[i]), chosen_defl[i], fixed_vec,
                                   ik.position_error, ik.rotation_error, ik.q))
    return PostureResult(points, tuple(full.coordinate_joints), float(ref), angles,
                         float(np.deg2rad(max_step_deg)), notes)


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
