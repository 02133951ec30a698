"""The stiffest posture along a path: the free rotation about the tool axis (and a redundant
arm's null space) chosen to minimise the deflection under the process wrench.

A path point is a target position and either a tool axis (the direction the target frame's
*free axis* must point along, base frame) or a full orientation. The process is symmetric about
the free axis, so every rotation ``psi`` about it is an admissible pose:
``R(psi) = R_0 exp(psi f)``, ``f`` the free axis in the target frame, ``R_0`` the given
orientation or, for an axis, the frame carried along the path by minimal rotations from the
first point's (so a constant ``psi`` does not spin the tool).

Algorithm:

1. Branches (:mod:`stiffness.machining.branches`): at the first point, inverse kinematics at
   the reference angle from ``start`` and, for a non-redundant arm, from seeds spread over the
   joint limits gives the distinct assembly branches (elbow up/down, wrist flipped or not,
   ...), named ``A`` (the branch of ``start``), ``B``, ... Each is followed around all ``S``
   angles ``psi_ref + 2 pi k / S``, up and down from the reference (each angle seeded from its
   neighbour on the same track, a solution that jumps to another branch or wrap refused; each
   direction covers its half of the circle, then the angles the other could not reach), and
   along the path (each node seeded from the same angle at the previous point, else from its
   neighbour). Damped least squares (:func:`stiffness.mechanics.ik.solve_ik`) holds the joint
   limits; a node is admissible when the smallest singular value of the target Jacobian is at
   least the singularity margin.
2. Dynamic programming over the (angle, branch) nodes: minimise the sum of squared deflections
   ``|C W|`` (the model's first-order position deflection, every effect included) with the joint
   change between consecutive points at most ``max_step`` (and one branch throughout with
   ``branch="keep"``) and, where the fixed-angle posture on the node's branch is admissible, no
   point worse than it; with a robot's declared ``[workspace]``, where its model is calibrated
   (:mod:`stiffness.machining.region`), the fewest points outside it first (not with
   ``ignore_workspace``).
3. Local refinement: each point's angle walks downhill on its branch in half-spacing steps as
   far as the constraints allow (not capped at one spacing), then a bounded scalar minimisation
   polishes it; a redundant arm then descends the deflection in the null space of its pose
   Jacobian (IK re-projects every step onto the pose).

The fixed-angle reference of each point is the reference angle on the chosen node's branch.

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

from stiffness.elastic.model import ElasticModel
from stiffness.elastic.model_file import load_model
from stiffness.errors import StiffnessError
from stiffness.figures import png
from stiffness.files import atomic_write, number_text
from stiffness.machining.branches import (
    Layer,
    PostureProblem,
    branch_label,
    candidate_layers,
    candidate_tracks,
    fixed_values,
)
from stiffness.machining.compensation import WRENCH_FRAMES, point_wrenches
from stiffness.machining.joint_path import angular_coordinates
from stiffness.machining.poses import Poses, free_axis_vector, read_poses, tool_frames
from stiffness.machining.region import Region
from stiffness.mechanics.defaults import assembly_coordinates
from stiffness.mechanics.formulation import target_jacobian
from stiffness.mechanics.ik import IKResult, coordinate_limits
from stiffness.robot.robot import Robot
from stiffness.units import float_array, whole_number

#: Most candidate angles about the free axis (0.1 deg apart); the search costs steps^2.
MAX_STEPS = 3600

#: ``any``: the path may change branch; ``keep``: one branch throughout.
BRANCH_MODES = ("any", "keep")


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
        The same with the fixed angle on the same branch (m); NaN where that posture is out of
        reach.
    ik_position_error, ik_rotation_error
        Remaining IK error of the chosen posture (m, rad).
    branch
        The branch of the chosen posture (``A``, ``B``, ...: :attr:`PostureResult.branches`).
    outside
        What puts the posture outside the robot's declared ``[workspace]``
        (:meth:`~stiffness.calibration.poses.Workspace.departures`); empty inside it.
    """

    coords: np.ndarray
    angle: float
    deflection: np.ndarray
    deflection_fixed: np.ndarray
    ik_position_error: float
    ik_rotation_error: float
    branch: str
    q: np.ndarray = field(repr=False)
    outside: tuple[str, ...] = ()


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
    branches
        Each branch found at the first point: its coordinates there (rad, m) at the angle it was
        found at (the reference angle unless that is out of reach).
    deg
        Whether :meth:`to_dict` and :meth:`csv` give the angles in degrees (else rad).
    workspace
        Whether the robot declares a ``[workspace]``, where its model was calibrated, that the
        postures were judged against (:attr:`PosturePoint.outside`; kept inside unless
        ``ignore_workspace``).
    """

    points: list[PosturePoint]
    joints: tuple[str, ...]
    reference_angle: float
    angles: np.ndarray
    max_step: float
    notes: list[str]
    poses: Poses
    angular: np.ndarray
    branches: dict[str, np.ndarray]
    deg: bool = False
    workspace: bool = False

    def _scale(self) -> np.ndarray:
        """Factor from SI to the written unit of each coordinate."""
        return np.where(self.angular & self.deg, 180.0 / np.pi, 1.0)

    def to_dict(self) -> dict:
        """The object ``stiffness posture --json`` prints: ``joints``, ``rows`` (joint values
        in the written unit, the rest SI; ``in_workspace``, whether the posture is inside the
        robot's declared ``[workspace]``, ``None`` without one, and ``workspace_departures``,
        what puts it outside), ``summary``, ``notes``, ``units``, ``branches`` (each branch's
        coordinates at the first point, in the unit of ``q``)."""
        def num(v: float | np.floating) -> float | None:
            return float(v) if math.isfinite(v) else None

        scale = self._scale()
        unit = ["deg" if (a and self.deg) else ("rad" if a else "m") for a in self.angular]
        rows = [{"q": (p.coords * scale).tolist(), "angle_deg": float(np.rad2deg(p.angle)),
                 "deflection_m": float(np.linalg.norm(p.deflection)),
                 "deflection": p.deflection.tolist(),
                 "deflection_fixed_m": num(np.linalg.norm(p.deflection_fixed)),
                 "ik_residual_m": p.ik_position_error, "ik_residual_rad": p.ik_rotation_error,
                 "branch": p.branch,
                 "in_workspace": not p.outside if self.workspace else None,
                 "workspace_departures": list(p.outside)}
                for p in self.points]
        branches = {name: (c * scale).tolist() for name, c in self.branches.items()}
        return {"joints": list(self.joints), "rows": rows, "summary": self.summary(),
                "notes": self.notes, "branches": branches,
                "units": {"q": unit, "angle_deg": "deg", "deflection_m": "m",
                          "deflection": "m", "deflection_fixed_m": "m", "ik_residual_m": "m",
                          "ik_residual_rad": "rad"}}

    def csv(self) -> str:
        """``OUT.csv`` of ``stiffness posture``: the input columns, the joints (written unit),
        the angle (deg), the deflections (m), the IK residuals (m, rad) and the branch per
        point."""
        def num(value: float | np.floating) -> str:
            return number_text(float(value)) if math.isfinite(value) else ""

        scale = self._scale()
        buf = io.StringIO()
        writer = csv.writer(buf, lineterminator="\n")
        header = self.poses.header
        writer.writerow(header + list(self.joints) + [
            "angle_deg", "deflection_m", "deflection_fixed_m", "ik_residual_m",
            "ik_residual_rad", "branch"])
        for cells, p in zip(self.poses.cells, self.points, strict=True):
            cells = (cells + [""] * len(header))[: len(header)]
            writer.writerow(cells + [num(v) for v in p.coords * scale] + [
                num(np.rad2deg(p.angle)), num(np.linalg.norm(p.deflection)),
                num(np.linalg.norm(p.deflection_fixed)), num(p.ik_position_error),
                num(p.ik_rotation_error), p.branch])
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
        image = png(fig, dpi=110)
        plt.close(fig)
        return image

    def write(self, out: str | os.PathLike | None, figure: str | os.PathLike | None = None
              ) -> list[Path]:
        """Write :meth:`csv` to ``out`` and :meth:`figure_png` to ``figure`` (either may be
        ``None``), both computed before either is written; returns the paths written."""
        files: list[tuple[str | os.PathLike, str | bytes]] = []
        if out is not None:
            files.append((out, self.csv()))
        if figure is not None:
            files.append((figure, self.figure_png()))
        return [atomic_write(path, data) for path, data in files]

    def joint_path(self) -> np.ndarray:
        """(m, n) joint coordinates (rad, m)."""
        return np.array([p.coords for p in self.points])

    def summary(self) -> dict:
        """Max/RMS deflections (m) chosen and fixed (on the chosen branch), their ratio, the
        largest joint step (revolute in deg, prismatic in m), the branches found and used, the
        points outside the declared ``[workspace]`` (``None`` without one)."""
        d = np.array([np.linalg.norm(p.deflection) for p in self.points])
        f = np.array([np.linalg.norm(p.deflection_fixed) for p in self.points])
        ok = np.isfinite(f)
        steps = np.abs(np.diff(self.joint_path(), axis=0))
        turns, slides = steps[:, self.angular], steps[:, ~self.angular]
        out = {
            "max_deflection_m": float(d.max()),
            "rms_deflection_m": float(np.sqrt(np.mean(d ** 2))),
            "max_deflection_fixed_m": float(f[ok].max()) if ok.any() else None,
            "rms_deflection_fixed_m": float(np.sqrt(np.mean(f[ok] ** 2))) if ok.any() else None,
            "fixed_reachable_points": int(ok.sum()),
            "max_joint_step_deg": float(np.rad2deg(turns.max())) if turns.size else 0.0,
            "max_joint_step_m": float(slides.max()) if slides.size else 0.0,
            "max_ik_residual_m": float(max(p.ik_position_error for p in self.points)),
            "max_ik_residual_rad": float(max(p.ik_rotation_error for p in self.points)),
            "reference_angle_deg": float(np.rad2deg(self.reference_angle)),
            "points": len(self.points),
            "branches_found": len(self.branches),
            "branches_used": sorted({p.branch for p in self.points}),
            "points_outside_workspace": sum(bool(p.outside) for p in self.points)
            if self.workspace else None,
        }
        if ok.all() and d.max() > 0:
            out["max_reduction_factor"] = float(f.max() / d.max())
            out["rms_reduction_factor"] = float(np.sqrt(np.mean(f ** 2) / np.mean(d ** 2)))
        return out


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
    branch: str = "any",
    ignore_workspace: bool = False,
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
        IK seed of the first point (rad, m); default the robot's reference pose (its shipped
        coordinates, else for a closed loop the assembly found near zero, else zero).
        Its branch is branch ``A``; the others are found from seeds spread over the limits.
    refine, progress
        Whether to refine each angle locally after the dynamic programming; called with
        (done, total) as the points are solved.
    k_theta
        Joint springs (N.m/rad, N/m) when ``model`` is a robot.
    deg
        Whether :meth:`PostureResult.to_dict` and :meth:`PostureResult.write` give the joint
        values in degrees (the attributes stay rad).
    branch
        ``any``: the path may change branch where the step bound allows; ``keep``: one branch
        along the whole path (the best one).
    ignore_workspace
        Choose among every candidate, not first those inside the robot's declared
        ``[workspace]`` (``--ignore-workspace``); the points outside are still reported.

    Raises
    ------
    StiffnessError
        Bad input, a point no candidate reaches (named by row), or no sequence within
        ``max_step_deg``.
    """
    em = load_model(model, k_theta)
    full = em.full
    poses, w = _poses_and_wrench(positions, axes, quaternions, wrench)
    _check_search(full, steps, (max_step_deg, singularity_margin, reference_angle_deg),
                  wrench_frame, branch)
    problem = _posture_problem(em, poses, w, free_axis, wrench_frame, steps, max_step_deg,
                               singularity_margin)
    ref, angles, sweep = _candidate_angles(steps, reference_angle_deg)
    start = _start_coordinates(full, start)
    total = poses.positions.shape[0] * (2 if refine else 1)
    tick = (lambda n: progress(n, total)) if progress is not None else (lambda n: None)
    # 1. candidate tracks of every branch
    tracks, origins = candidate_tracks(problem, angles, sweep, start, full.configuration(start),
                                       tick)
    layers = candidate_layers(problem, tracks, angles)
    region = Region.of(full, layers, judged=not ignore_workspace)
    # 2. dynamic programming over (angle, branch), inside the declared workspace where it can
    search = (branch == "keep", max_step_deg, singularity_margin)
    choice, notes = _choose(layers, problem, *search, region.penalty())
    # 3. local refinement
    points = _chosen_points(problem, layers, choice, angles, tick if refine else None, region)
    notes += _notes(points, reference_angle_deg) + _workspace_notes(
        region, layers, problem, choice, points, search)
    return PostureResult(points, tuple(full.coordinate_joints), float(ref), angles,
                         float(np.deg2rad(max_step_deg)), notes, poses, problem.angular,
                         {branch_label(b): o.coords for b, o in enumerate(origins)}, deg,
                         region.declared)


def _workspace_notes(region: Region, layers: list[Layer], problem: PostureProblem,
                     choice: list[int], points: list[PosturePoint],
                     search: tuple[bool, float, float]) -> list[str]:
    """What :meth:`Region.notes` says of the chosen path (``choice``, ``points``) against the
    declared workspace, compared, where the search kept inside it, with the stiffest path
    with the workspace not judged (``search``: ``keep``, ``max_step_deg``,
    ``singularity_margin`` as :func:`_choose` takes them); nothing without one."""
    if not region.declared:
        return []
    free = _choose(layers, problem, *search, None)[0] if region.judged else None
    return region.notes([(p.branch, p.outside) for p in points], layers, choice, free)


def _notes(points: list[PosturePoint], reference_angle_deg: float) -> list[str]:
    """What the user should know of the chosen path: it changes branch; the fixed angle
    (``reference_angle_deg``, deg) is out of reach at some points."""
    notes = []
    if len({p.branch for p in points}) > 1:
        notes.append("the path changes branch where the step bound allows it (--branch keep "
                     "holds one)")
    missed = sum(not np.all(np.isfinite(p.deflection_fixed)) for p in points)
    if missed:
        notes.append(f"the fixed angle ({reference_angle_deg:g} deg) is out of reach at {missed} "
                     f"of {len(points)} points on the branch used: "
                     + ("its deflections are over the others, " if missed < len(points) else "")
                     + "no factor; --reference-angle DEG compares with another angle")
    return notes


def _posture_problem(em: ElasticModel, poses: Poses, w: np.ndarray, free_axis: str | np.ndarray,
                     wrench_frame: str, steps: int, max_step_deg: float,
                     singularity_margin: float) -> PostureProblem:
    """The search's shared state: the path's tool frames about the free axis, the wrenches
    (N, N.m), the singularity margin, the joint-step bound (``max_step_deg``, deg, held in rad)
    and the spacing of the ``steps`` candidate angles (rad)."""
    free = free_axis_vector(free_axis)
    return PostureProblem(em, poses.positions, tool_frames(free, poses.axes, poses.quaternions),
                          free, w, wrench_frame, singularity_margin, np.deg2rad(max_step_deg),
                          angular_coordinates(em.full), 2.0 * np.pi / steps)


def _candidate_angles(steps: int, reference_angle_deg: float
                      ) -> tuple[float, np.ndarray, list[int]]:
    """The reference angle (rad), the ``steps`` candidate angles about the free axis (rad,
    the reference plus offsets in (-pi, pi]) and their order outward from the reference."""
    ref = np.deg2rad(reference_angle_deg)
    offsets = 2.0 * np.pi / steps * np.arange(steps)
    offsets = np.where(offsets > np.pi, offsets - 2.0 * np.pi, offsets)
    sweep = sorted(range(steps), key=lambda k: (abs(offsets[k]), offsets[k]))
    return float(ref), ref + offsets, sweep


def _chosen_points(problem: PostureProblem, layers: list[Layer], choice: list[int],
                   angles: np.ndarray, refined: Callable[[int], None] | None, region: Region
                   ) -> list[PosturePoint]:
    """The chosen nodes (refined locally unless ``refined`` is None, which is called with the
    progress count as each point is done; a node inside the declared workspace ``region``
    kept inside it) as points, with the fixed angle's deflection on the same branch (m; NaN
    where out of reach) and what puts each outside the workspace beside them."""
    m = len(layers)
    chosen = [layer.iks[n] for layer, n in zip(layers, choice, strict=True)]
    psi = np.array([angles[layer.angle[n]] for layer, n in zip(layers, choice, strict=True)])
    defl = [layer.vectors[n] for layer, n in zip(layers, choice, strict=True)]
    labels = [int(layer.branch[n]) for layer, n in zip(layers, choice, strict=True)]
    if refined is not None:
        for i, (layer, n) in enumerate(zip(layers, choice, strict=True)):
            _refine_point(problem, i, chosen, psi, defl, fixed_values(layer)[n],
                          2.0 * np.pi / len(angles), region.keeper(i, n))
            refined(m + i + 1)
    points = []
    for i, layer in enumerate(layers):
        f = layer.fixed.get(labels[i])
        fixed_vec = layer.vectors[f] if f is not None else np.full(3, np.nan)
        ik = chosen[i]
        points.append(PosturePoint(ik.coords, float(psi[i]), defl[i], fixed_vec,
                                   ik.position_error, ik.rotation_error,
                                   branch_label(labels[i]), ik.q, region.judge(ik.coords)))
    return points


def _choose(layers: list[Layer], problem: PostureProblem, keep: bool, max_step_deg: float,
            margin: float, penalty: list[np.ndarray] | None) -> tuple[list[int], list[str]]:
    """The DP's choice, bounded point by point by the fixed angle where that is possible,
    with the nodes' ``penalty`` (:meth:`Region.penalty`: the fewest points outside the
    declared workspace; ``None``: not judged)."""
    notes: list[str] = []
    choice = _dynamic_programming(problem, layers, keep, bounded=True, penalty=penalty)
    if choice is None:
        choice = _dynamic_programming(problem, layers, keep, bounded=False, penalty=penalty)
        if choice is not None:
            notes.append("the fixed-angle path itself breaks the joint-step bound or the "
                         "singularity margin somewhere: the chosen path is not bounded by it "
                         "point by point")
    if choice is None:
        raise StiffnessError(
            f"no posture sequence keeps every joint step within {max_step_deg:g} deg (with the "
            f"singularity margin {margin:g}); raise --max-step or --steps")
    return choice, notes


def _dynamic_programming(problem: PostureProblem, layers: list[Layer], keep: bool,
                         bounded: bool, penalty: list[np.ndarray] | None = None
                         ) -> list[int] | None:
    """Node indices (one per point) minimising the sum of squared deflections with every
    revolute step within the bound (and the branch kept, and no node above its branch's
    fixed angle, when asked); None if no such sequence. ``penalty`` (per point, per node;
    m^2) is added to the nodes' squared deflections: large ones make the fewest such nodes
    come first (:meth:`Region.penalty`)."""
    def allowed(layer: Layer) -> np.ndarray:
        ok = layer.admissible.copy()
        if bounded:
            fixed = fixed_values(layer)
            ok &= ~np.isfinite(fixed) | (layer.values <= fixed * (1 + 1e-12))
        return ok

    def own(i: int) -> np.ndarray:
        return layers[i].values ** 2 + (0.0 if penalty is None else penalty[i])

    cost = np.where(allowed(layers[0]), own(0), np.inf)
    backs = []
    for i, (before, layer) in enumerate(zip(layers[:-1], layers[1:], strict=True), 1):
        jumps = np.abs(layer.coords[:, None, :] - before.coords[None, :, :])[..., problem.angular]
        link = np.all(jumps <= problem.max_step + 1e-12, axis=2)
        if keep:
            link &= layer.branch[:, None] == before.branch[None, :]
        reach = np.where(link, cost[None, :], np.inf)
        back = np.argmin(reach, axis=1)
        cost = np.where(allowed(layer), reach[np.arange(len(back)), back] + own(i), np.inf)
        backs.append(back)
        if not np.isfinite(cost).any():
            return None
    n = int(np.argmin(cost))
    if not np.isfinite(cost[n]):
        return None
    choice = [n]
    for back in reversed(backs):
        n = int(back[n])
        choice.append(n)
    return choice[::-1]


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
    positions = np.atleast_2d(float_array(positions, "positions", "(m, 3) points in m or a "
                                          "poses file", finite=False))
    axes = None if axes is None else float_array(axes, "axes", "(m, 3) tool axes", finite=False)
    quaternions = None if quaternions is None else float_array(
        quaternions, "quaternions", "(m, 4) orientations qw,qx,qy,qz", finite=False)
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
        raise StiffnessError("give a process wrench: --wrench fx,fy,fz[,mx,my,mz] (N, N.m; "
                             "Python: wrench=[...]), or fx,fy,fz columns in the poses file")
    return poses, point_wrenches(wrench, m)


def _start_coordinates(full: Robot, start: object) -> np.ndarray:
    """The coordinates (rad, m) the search starts from: ``start``, else the robot's reference
    pose (:func:`~stiffness.mechanics.defaults.assembly_coordinates`: its shipped coordinates,
    else for a closed loop the assembly found near zero, else zero); a ``start`` that is not
    one number per coordinate is refused."""
    if start is None:
        return assembly_coordinates(full)
    return float_array(
        start, "start", f"the {full.n_coordinates} coordinates (rad, m) the search starts from",
        size=full.n_coordinates).reshape(-1)


def _check_search(full: Robot, steps: int, angles: tuple[float, float, float],
                  wrench_frame: str, branch: str) -> None:
    """Refuse an arm that cannot hold a pose, or search settings (``steps``; ``angles``: the
    largest step (deg), the singularity margin, the reference angle (deg)) of another type
    or out of range (one line)."""
    whole_number(steps, "steps", None)
    names = ("max_step_deg", "singularity_margin", "reference_angle_deg")
    needs = ("an angle > 0 (deg)", "a number >= 0", "an angle (deg)")
    for name, value, needed in zip(names, angles, needs, strict=True):  # range checks below
        float_array(value, name, needed, ndim=0, finite=name == "reference_angle_deg")
    max_step_deg, singularity_margin = angles[0], angles[1]
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
    if branch not in BRANCH_MODES:
        raise StiffnessError(f"--branch must be any or keep, got {branch!r}")


def _refine_point(problem: PostureProblem, i: int, chosen: list[IKResult], psi: np.ndarray,
                  defl: list[np.ndarray], bound: float, spacing: float,
                  inside: Callable[[np.ndarray], bool]) -> None:
    """Refine point ``i``'s angle (and null-space posture) in place under the constraints
    (``inside``: whether coordinates may be taken, the declared workspace's judgement).

    The angle walks downhill in half-spacing steps on its branch (each IK seeded from the last
    one) as far as the constraints allow, then a bounded scalar minimisation polishes the best
    bracket; a redundant arm then descends in its null space.
    """
    from scipy.optimize import minimize_scalar

    m = len(chosen)

    def feasible(ik: IKResult) -> bool:
        if i > 0 and not problem.step_ok(chosen[i - 1].coords, ik.coords):
            return False
        if i + 1 < m and not problem.step_ok(chosen[i + 1].coords, ik.coords):
            return False
        return inside(ik.coords) and problem.admissible(ik)

    samples: dict[float, tuple[float, IKResult, np.ndarray]] = {
        float(psi[i]): (float(np.linalg.norm(defl[i])), chosen[i], defl[i])}

    def evaluate(angle: float, seed: IKResult) -> float:
        ik = problem.follow(i, angle, [seed])
        if ik is None or not feasible(ik):
            return np.inf
        vec = problem.deflection(i, angle, ik)
        value = float(np.linalg.norm(vec))
        if np.isfinite(bound) and value > bound * (1 + 1e-12):
            return np.inf
        samples[angle] = (value, ik, vec)
        return value

    h = spacing / 2.0
    for direction in (1.0, -1.0):
        angle, (value, ik, _) = float(psi[i]), samples[float(psi[i])]
        while abs(angle + direction * h - psi[i]) <= np.pi:
            trial = angle + direction * h
            if evaluate(trial, ik) >= value:
                break
            angle, (value, ik, _) = trial, samples[trial]
    centre = min(samples, key=lambda a: samples[a][0])

    def polished(angle: float) -> float:
        seed = samples[min(samples, key=lambda a: abs(a - angle))][1]
        return min(evaluate(angle, seed), 1e9)

    minimize_scalar(polished, bounds=(centre - h, centre + h), method="bounded",
                    options={"xatol": 1e-6})
    best = min(samples, key=lambda a: samples[a][0])
    psi[i], (_, chosen[i], defl[i]) = best, samples[best]
    if problem.full.n_coordinates > 6:
        _null_space_descent(problem, i, chosen, psi, defl, feasible, bound)


def _null_space_descent(problem: PostureProblem, i: int, chosen: list[IKResult], psi: np.ndarray,
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
        return float(np.linalg.norm(problem.em.linear_deflection(coords, load, seed_q=q)[:3]))

    for _ in range(iterations):
        ik = chosen[i]
        jac = target_jacobian(full, ik.q)
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
