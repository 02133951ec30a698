"""The posture search's candidates: every inverse-kinematics branch of the arm found at the
first path point, followed around the angles about the free axis and along the path.

A branch (elbow up or down, wrist flipped or not, ...) is one continuous family of IK solutions;
at the first point the distinct branches are found by IK from the start and from seeds spread
over the joint limits, and named ``A`` (the start's), ``B``, ... Each is followed by two
tracks, up and down from its origin angle: each angle seeded from its neighbour on the same
track (each direction first covers its half of the circle, then the angles the other direction
could not reach, e.g. past a wrist joint's limit), each later point seeded from the same angle
at the previous point. A solution that jumps from its seed by more than
:attr:`PostureProblem.jump` in a revolute coordinate (another branch, or a 2 pi wrap) is
refused, so a track's nodes are all on its branch.

Units: m, rad (m for prismatic coordinates).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from stiffness.elastic.model import ElasticModel
from stiffness.errors import ConvergenceError, StiffnessError
from stiffness.mechanics.formulation import target_jacobian
from stiffness.mechanics.ik import IKResult, coordinate_limits, inside_limits, solve_ik

#: Random IK seeds tried at the first point to find a non-redundant arm's branches.
BRANCH_SEEDS = 32

#: Most branches followed (each costs about ``S`` IK solves per point).
MAX_BRANCHES = 16

#: Two IK solutions within this (rad, m; revolute coordinates modulo 2 pi) are one branch.
SAME_BRANCH = 1e-3


def branch_label(index: int) -> str:
    """Name of the ``index``-th branch found at the first point: ``A``, ``B``, ..."""
    return chr(ord("A") + index)


class PostureProblem:
    """Shared state of one posture search: the model, the path's target frames and wrenches,
    the singularity margin and the joint-step bound (rad)."""

    def __init__(self, em: ElasticModel, positions, frames, free, wrench, wrench_frame,
                 margin, max_step, angular, spacing):
        self.em, self.full = em, em.full
        self.positions, self.frames, self.free = positions, frames, free
        self.wrench, self.wrench_frame = wrench, wrench_frame
        self.margin, self.max_step, self.angular = margin, max_step, angular
        #: Largest revolute change (rad) between an IK solution and the neighbour it was seeded
        #: from that still counts as the same branch (a flip or a 2 pi wrap is larger).
        self.jump = max(np.pi / 2, 2.0 * spacing, 2.0 * max_step)

    def rotation(self, i: int, psi: float) -> np.ndarray:
        return self.frames[i] @ pin.exp3(psi * self.free)

    def solve(self, i: int, psi: float, seeds: list[tuple[np.ndarray, np.ndarray | None]]
              ) -> IKResult | None:
        """IK of point ``i`` at angle ``psi`` from the first seed that converges."""
        for coords, q in seeds:
            try:
                return solve_ik(self.full, self.positions[i], self.rotation(i, psi),
                                seed=coords, seed_q=q)
            except StiffnessError:
                continue
        return None

    def follow(self, i: int, psi: float, seeds: list[IKResult]) -> IKResult | None:
        """IK of point ``i`` at ``psi`` on the branch of the first seed that leads to one."""
        for seed in seeds:
            ik = self.solve(i, psi, [(seed.coords, seed.q)])
            if ik is not None and self.continuous(seed.coords, ik.coords):
                return ik
        return None

    def continuous(self, a: np.ndarray, b: np.ndarray) -> bool:
        """No revolute coordinate jumps between ``a`` and ``b`` (same branch, same wrap)."""
        return bool(np.all(np.abs(a - b)[self.angular] <= self.jump))

    def same_branch(self, a: np.ndarray, b: np.ndarray) -> bool:
        """``a`` and ``b`` are one configuration (revolute coordinates modulo 2 pi)."""
        d = a - b
        d[self.angular] = np.angle(np.exp(1j * d[self.angular]))
        return bool(np.all(np.abs(d) <= SAME_BRANCH))

    def canonical(self, i: int, psi: float, ik: IKResult) -> IKResult:
        """The same configuration with each revolute coordinate in (-pi, pi] where the joint
        limits allow it (a reproducible representative of the branch)."""
        lo, hi = coordinate_limits(self.full)
        wrapped = ik.coords.copy()
        turned = self.angular & ((ik.coords <= -np.pi) | (ik.coords > np.pi))
        wrapped[turned] = np.angle(np.exp(1j * ik.coords[turned]))
        if not turned.any() or np.any(wrapped < lo) or np.any(wrapped > hi):
            return ik
        return self.solve(i, psi, [(wrapped, None)]) or ik

    def admissible(self, ik: IKResult) -> bool:
        jac = target_jacobian(self.full, ik.q)
        return float(np.linalg.svd(jac, compute_uv=False)[-1]) >= self.margin

    def load(self, i: int, psi: float) -> np.ndarray:
        """Base-frame wrench of point ``i`` at angle ``psi``."""
        w = self.wrench[i]
        if self.wrench_frame == "target":
            r = self.rotation(i, psi)
            w = np.concatenate([r @ w[:3], r @ w[3:]])
        return w

    def deflection(self, i: int, psi: float, ik: IKResult) -> np.ndarray:
        return self.em.linear_deflection(ik.coords, self.load(i, psi), seed_q=ik.q)[:3]

    def step_ok(self, a: np.ndarray, b: np.ndarray) -> bool:
        return bool(np.all(np.abs(a - b)[self.angular] <= self.max_step + 1e-12))


@dataclass
class Track:
    """One branch followed around the candidate angles and along the path.

    ``order`` is the walk over the angle indices (from the first point's origin angle, up or
    down); ``nodes[i][k]`` is the IK solution at point ``i``, angle ``k`` (None: none on this
    track).
    """

    branch: int
    order: list[int]
    nodes: list[list[IKResult | None]] = field(default_factory=list)


@dataclass
class Layer:
    """The candidates (angle, branch) of one path point, flattened."""

    iks: list[IKResult]
    angle: np.ndarray
    branch: np.ndarray
    coords: np.ndarray
    vectors: np.ndarray
    values: np.ndarray
    admissible: np.ndarray
    fixed: dict[int, int]  # branch -> index of its fixed-angle node


def branch_origins(problem: PostureProblem, angles: np.ndarray, sweep: list[int],
                    start: np.ndarray, q_start: np.ndarray) -> tuple[int, list[IKResult]]:
    """The distinct IK branches of the first point at the first angle (in ``sweep`` order)
    that has any: from ``start`` and, for a non-redundant arm, :data:`BRANCH_SEEDS` seeds
    spread over the joint limits (seeded generator, reproducible)."""
    full = problem.full
    seeds: list[tuple[np.ndarray, np.ndarray | None]] = [(start, q_start)]
    if full.n_coordinates == 6:
        lo, hi = coordinate_limits(full)
        span = np.where(problem.angular, np.pi, 1.0)
        lo, hi = np.where(np.isfinite(lo), lo, -span), np.where(np.isfinite(hi), hi, span)
        rng = np.random.default_rng(0)
        for _ in range(BRANCH_SEEDS):
            coords = rng.uniform(lo, hi)
            seed = (coords, None) if full.loop.is_open_chain else _loop_seed(problem, coords)
            if seed is not None:
                seeds.append(seed)
    for k in sweep:
        found: list[IKResult] = []
        for seed in seeds:
            ik = problem.solve(0, angles[k], [seed])
            if ik is None:
                continue
            ik = problem.canonical(0, angles[k], ik)
            if not any(problem.same_branch(ik.coords, f.coords) for f in found):
                found.append(ik)
            if len(found) == MAX_BRANCHES:
                break
        if found:
            return k, found
    raise ConvergenceError(
        f"row 1: the pose at {np.round(problem.positions[0], 6).tolist()} m is out of reach "
        "for every angle about the free axis (within the joint limits); move it into the "
        "workspace")


def _loop_seed(problem: PostureProblem, coords: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray | None] | None:
    """A random seed (rad, m) of a closed loop, moved inside the joint limits as the IK moves
    it, with its assembly closed by continuation from the reference one; None when the
    continuation meets a fold. The assembly search (least squares over every joint) is not
    tried: its assembly mode is not checked, and on a hexapod, whose random leg lengths mostly
    do not assemble, it cost half of ``stiffness posture``'s time without ever closing."""
    full = problem.full
    coords = inside_limits(coords, *coordinate_limits(full))
    try:
        return coords, full.assemble(coords, search=False).q
    except StiffnessError:
        return None


def _walk(problem: PostureProblem, i: int, track: Track, order: list[int], angles: np.ndarray,
          row: list[IKResult | None], last: IKResult | None,
          other: list[IKResult | None] | None) -> IKResult | None:
    """Fill ``row`` (point ``i`` of ``track``) along ``order``: each angle seeded from the
    same angle at the previous point, else from the last node of the walk; angles the
    branch's ``other`` track holds are left to it unless this track had them at the previous
    point. Returns the walk's last node."""
    previous = track.nodes[i - 1] if i > 0 else [None] * len(angles)
    for k in order:
        if previous[k] is None and other is not None and other[k] is not None:
            continue
        seeds = [s for s in (previous[k], last) if s is not None]
        row[k] = last = problem.follow(i, angles[k], seeds)
    return last


def _extend_pair(problem: PostureProblem, i: int, up: Track, down: Track, angles: np.ndarray,
                 anchor: IKResult | None) -> None:
    """Append point ``i`` to a branch's two tracks: each walks its half of the circle from
    the origin angle (the short way), then on into the angles the other did not reach."""
    steps = len(angles)
    half = (steps + 1) // 2
    up_row: list[IKResult | None] = [None] * steps
    down_row: list[IKResult | None] = [None] * steps
    up_last = _walk(problem, i, up, up.order[:half], angles, up_row, anchor, None)
    down_last = _walk(problem, i, down, down.order[:steps - half], angles, down_row, anchor,
                      None)
    _walk(problem, i, up, up.order[half:], angles, up_row, up_last, down_row)
    _walk(problem, i, down, down.order[steps - half:], angles, down_row, down_last, up_row)
    up.nodes.append(up_row)
    down.nodes.append(down_row)


def candidate_tracks(problem: PostureProblem, angles: np.ndarray, sweep: list[int],
                      start: np.ndarray, q_start: np.ndarray,
                      progress: Callable[[int], None]) -> tuple[list[Track], list[IKResult]]:
    """Every branch found at the first point, followed around all angles (up and down from
    its origin angle) and along the path; returns the tracks and the branch origins."""
    steps, m = len(angles), len(problem.positions)
    k0, origins = branch_origins(problem, angles, sweep, start, q_start)
    tracks = []
    for b in range(len(origins)):
        tracks.append(Track(b, [(k0 + j) % steps for j in range(steps)]))
        tracks.append(Track(b, [(k0 - j) % steps for j in range(1, steps + 1)]))
    for i in range(m):
        for up, down in zip(tracks[::2], tracks[1::2], strict=True):
            _extend_pair(problem, i, up, down, angles, origins[up.branch] if i == 0 else None)
        _drop_duplicates([t.nodes[i] for t in tracks])
        if all(r is None for t in tracks for r in t.nodes[i]):
            raise ConvergenceError(
                f"row {i + 1}: the pose at {np.round(problem.positions[i], 6).tolist()} m is "
                "out of reach for every angle about the free axis (within the joint limits) "
                "on the branches followed from the first point; move it into the workspace")
        progress(i + 1)
    return tracks, origins


def _drop_duplicates(rows: list[list[IKResult | None]]) -> None:
    """Keep one of the nodes that are the same coordinates at the same angle (in place)."""
    for k in range(len(rows[0])):
        kept: list[np.ndarray] = []
        for row in rows:
            ik = row[k]
            if ik is None:
                continue
            if any(np.max(np.abs(ik.coords - c)) < 1e-6 for c in kept):
                row[k] = None
            else:
                kept.append(ik.coords)


def candidate_layers(problem: PostureProblem, tracks: list[Track], angles: np.ndarray
                     ) -> list[Layer]:
    """The nodes of every point with their deflections, admissibility and fixed-angle node
    per branch (the reference angle is index 0)."""
    layers = []
    for i in range(len(problem.positions)):
        iks, angle, branch = [], [], []
        for t in tracks:
            for k, ik in enumerate(t.nodes[i]):
                if ik is not None:
                    iks.append(ik)
                    angle.append(k)
                    branch.append(t.branch)
        vectors = np.array([problem.deflection(i, angles[k], ik)
                            for k, ik in zip(angle, iks, strict=True)])
        values = np.linalg.norm(vectors, axis=1)
        fixed: dict[int, int] = {}
        for n, (k, b) in enumerate(zip(angle, branch, strict=True)):
            if k == 0 and (b not in fixed or values[n] < values[fixed[b]]):
                fixed[b] = n
        layers.append(Layer(iks, np.array(angle), np.array(branch),
                             np.array([ik.coords for ik in iks]), vectors, values,
                             np.array([problem.admissible(ik) for ik in iks]), fixed))
    return layers


def fixed_values(layer: Layer) -> np.ndarray:
    """Each node's fixed-angle deflection on its own branch (m; inf where out of reach)."""
    by_branch = {b: layer.values[n] for b, n in layer.fixed.items()}
    return np.array([by_branch.get(int(b), np.inf) for b in layer.branch])
