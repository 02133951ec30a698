"""Experiment design, the mathematics: candidate rows, Fisher information, criteria, greedy and
exchange selection, and the separation of two fitted alternatives.

Candidates (:func:`candidate_set`): reachable poses (:func:`stiffness.calibration.poses.
sample_coordinates`: joint limits, the robot's workspace rules, target above the base plane,
loops closed, away from singularities and folds) times the load directions
:data:`LOAD_DIRECTIONS` (the six axes and the eight cube diagonals) at the largest force.

Information. Row ``r`` (pose, force) has the predicted deflection ``d_r(ln k)`` of the
identification's deflection model (:class:`stiffness.elastic.effects.hypothesis.Hypothesis`: the
``enhanced`` baseline ``J (K - K_C(F))^-1 J^T F`` by default, ``K_C`` included) and the
sensitivity ``S_r = dd_r / d ln k`` (3, p) at the nominal stiffness (central differences of the
model's prediction). Under independent noise of std ``sigma`` on each deflection component the
Fisher information of ``ln k`` is ``I = sum_r S_r^T S_r / sigma^2`` (design notes, "Experiment
design"); the predicted standard error of ``ln k_i``, i.e. of ``k_i`` relative to ``k_i``, is
``sqrt((I^-1)_ii)``.

Criteria (larger is better): ``D`` ``log det I``, ``A`` ``-trace I^-1`` (the sum of the
relative variances), ``E`` ``lambda_min(I)``. A plan is ``N`` configurations with ``M`` distinct
load directions each. Selection is greedy (each step adds the pose whose best ``M`` directions,
chosen one by one, raise the criterion most, starting from the rows already measured when a
campaign is given, and a ridge of :data:`RIDGE` times the mean row information so that the
first steps are defined) and then Fedorov-style exchange passes: each chosen configuration is
replaced by the best candidate pose (its own included, with its directions re-chosen) and each
load direction by the best direction at its pose, while the criterion improves.

Separation (:class:`SeparationStatistics`). To tell two alternatives ``A`` and ``B`` fitted
to a campaign apart, the rows are chosen where their predictions differ most relative to the
noise, ``D_r = (d_A(r) - d_B(r)) / sigma``, counting only the part of the difference that
neither can absorb by refitting its own parameters to the other's predictions over the
campaign's rows and the plan's (linearised: the residual of ``D`` after projection on the
other's parameter sensitivities, the smaller of A-to-B and B-to-A). The plan's separation is
the square root of that residual sum of squares, in noise units (the noncentrality of the test
between them); it grows only with rows that add evidence. The same greedy and exchange passes
maximise it; ``stiffness diagnose`` proposes its extra measurements with this code, and
:mod:`stiffness.planning.design` designs whole plans with it.

Units: SI inside (m, N, rad, N.m/rad).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from stiffness.calibration.campaign import Campaign
from stiffness.calibration.exact_baseline import ExactObservation
from stiffness.calibration.fitting import Fit
from stiffness.calibration.poses import sample_coordinates
from stiffness.elastic.effects.geometry import Geometry, References, Rows
from stiffness.elastic.effects.hypothesis import BASELINES, Hypothesis
from stiffness.errors import StiffnessError, UnknownNameError, UnstableEquilibriumError
from stiffness.robot.robot import Robot
from stiffness.units import whole_number

#: Load directions of the candidates: the six axes, then the eight cube diagonals (unit).
LOAD_DIRECTIONS = np.vstack([np.eye(3), 0.0 - np.eye(3)] + [  # 0 - 0: no -0 printed
    np.array([sx, sy, sz]) / math.sqrt(3.0)
    for sx in (1, -1) for sy in (1, -1) for sz in (1, -1)])
#: Design criteria.
CRITERIA = ("D", "A", "E")
#: Candidate poses keep ``sigma_r / sigma_1`` of the Jacobian at least this fraction of the
#: best over probe poses (away from singularities).
SINGULARITY_MARGIN = 0.1
#: Closed-loop candidate poses keep the passive-joint conditioning at least this fraction of
#: the reference assembly's (away from folds).
FOLD_MARGIN = 0.1
#: Ridge of the greedy start, relative to the mean information of one candidate row.
RIDGE = 1e-6
#: Largest number of exchange passes.
EXCHANGE_PASSES = 10
#: Step in ln k of the central differences of the sensitivities.
_FD_STEP = 1e-5
#: A swap must improve the criterion by more than this (relative).
_IMPROVEMENT = 1e-9


# ------------------------------------------------------------------------------------------
# candidates


@dataclass
class Candidates:
    """Candidate rows: every pose with every load direction.

    Attributes
    ----------
    robot
        The robot (its compliant joints are the identified ones).
    geometry
        Its shared geometry (:class:`stiffness.elastic.effects.Geometry`).
    coords
        (K, n) candidate poses (rad, m).
    directions
        (D, 3) unit load directions.
    max_force
        Load magnitude (N).
    rows
        Geometry of the K * D rows, pose-major: row ``pose * D + direction``.
    """

    robot: Robot
    geometry: Geometry
    coords: np.ndarray
    directions: np.ndarray
    max_force: float
    rows: Rows

    @property
    def n_poses(self) -> int:
        """Number of candidate poses K."""
        return self.coords.shape[0]

    @property
    def n_directions(self) -> int:
        """Number of load directions D."""
        return self.directions.shape[0]

    def subset(self, poses: np.ndarray) -> Candidates:
        """The candidates at the poses ``poses`` (indices), in that order."""
        poses = np.asarray(poses, dtype=int)
        d = self.n_directions
        index = (poses[:, None] * d + np.arange(d)).reshape(-1)
        return Candidates(self.robot, self.geometry, self.coords[poses], self.directions,
                          self.max_force, self.rows.subset(index))


def candidate_set(robot: Robot, n_poses: int, max_force: float, seed: int | None = 0,
                  singularity_margin: float = SINGULARITY_MARGIN,
                  fold_margin: float = FOLD_MARGIN,
                  coords: np.ndarray | None = None) -> Candidates:
    """Candidate poses and loads (see the module docstring).

    Parameters
    ----------
    robot
        The robot.
    n_poses
        Number of candidate poses.
    max_force
        Load magnitude (N).
    seed
        Seed of the poses.
    singularity_margin, fold_margin
        Margins of :func:`stiffness.calibration.poses.sample_coordinates`.
    coords
        Poses to use instead of drawing them (rad, m), shape (K, n).

    Raises
    ------
    StiffnessError
        A non-positive force or pose count, or too few reachable poses.
    """
    if not (math.isfinite(max_force) and max_force > 0):
        raise StiffnessError(f"--max-force must be a positive force in N, got {max_force}")
    if coords is None:
        if int(n_poses) < 1:
            raise StiffnessError(f"--candidates must be at least 1, got {n_poses}")
        rng = np.random.default_rng(None if seed is None else whole_number(seed, "seed", 0))
        coords = sample_coordinates(robot, int(n_poses), rng,
                                    singularity_margin=singularity_margin,
                                    fold_margin=fold_margin)
    coords = np.atleast_2d(np.asarray(coords, dtype=float))
    geometry = Geometry.of(robot)
    d = len(LOAD_DIRECTIONS)
    q = np.repeat(coords, d, axis=0)
    force = np.tile(LOAD_DIRECTIONS * max_force, (coords.shape[0], 1))
    rows = geometry.rows(q, force)
    return Candidates(robot, geometry, coords, LOAD_DIRECTIONS.copy(), float(max_force), rows)


# ------------------------------------------------------------------------------------------
# information


def baseline_model(geometry: Geometry, rows: Rows, compliant: tuple[str, ...], k: np.ndarray,
                   formulation: str = "enhanced") -> tuple[Hypothesis, np.ndarray]:
    """The identification's deflection model (no effect) over ``rows`` and its parameter
    vector at the nominal stiffness ``k`` (SI)."""
    if formulation not in BASELINES:
        raise UnknownNameError(f"unknown formulation {formulation!r}; valid: "
                               f"{', '.join(BASELINES)}", name=formulation, choices=BASELINES)
    k = np.asarray(k, dtype=float)
    refs = References.of(geometry, rows, float(np.exp(np.mean(np.log(k)))), np.ones((1, 3)))
    return (Hypothesis(geometry, rows, formulation, compliant, (), refs, exact=ExactObservation),
            np.log(k))


def sensitivities(model: Hypothesis, x: np.ndarray, n_columns: int | None = None) -> np.ndarray:
    """(m, 3, c) derivatives of the predicted deflections (m) w.r.t. the first ``c`` entries of
    the parameter vector ``x`` (central differences, step :data:`_FD_STEP`): by default the
    ``ln k`` of the model's compliant joints. A model that also predicts rotations gives
    (m, 6, c), its rotation rows weighted as in :mod:`stiffness.calibration.fitting`.

    Raises
    ------
    StiffnessError
        If the tangent stiffness is singular for some row (the load buckles the robot).
    """
    c = len(model.compliant) if n_columns is None else n_columns
    out = np.empty((model.rows.n_rows, model.n_outputs, c))
    try:
        with np.errstate(all="ignore"):
            for i in range(c):
                step = np.zeros_like(x)
                step[i] = _FD_STEP
                out[:, :, i] = (model.predict(x + step) - model.predict(x - step)) / (
                    2 * _FD_STEP)
    except np.linalg.LinAlgError as exc:
        raise UnstableEquilibriumError("K - K_C is singular at a candidate row: the largest "
                                       "force buckles the robot at these stiffnesses; lower "
                                       "--max-force") from exc
    if not np.all(np.isfinite(out)):
        raise UnstableEquilibriumError("the deflection model cannot be evaluated at some "
                                       "candidate rows; lower --max-force")
    return out


def row_information(sens: np.ndarray, sigma: float) -> np.ndarray:
    """(m, p, p) Fisher information of ``ln k`` of each row, ``S_r^T S_r / sigma^2``."""
    return np.einsum("mkp,mkq->mpq", sens, sens) / sigma ** 2


def criterion_value(info: np.ndarray, criterion: str) -> np.ndarray:
    """Criterion of information matrices (..., p, p), larger is better; ``-inf`` if singular.

    ``D``: ``log det I``; ``A``: ``-trace I^-1``; ``E``: ``lambda_min(I)``.
    """
    lam = np.linalg.eigvalsh(0.5 * (info + np.swapaxes(info, -1, -2)))
    scale = np.maximum(np.abs(lam).max(axis=-1, keepdims=True), 1e-300)
    ok = np.all(lam > 1e-12 * scale, axis=-1)
    if criterion == "E":
        return lam[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        if criterion == "D":
            value = np.sum(np.log(np.where(ok[..., None], lam, 1.0)), axis=-1)
        elif criterion == "A":
            value = -np.sum(1.0 / np.where(ok[..., None], lam, 1.0), axis=-1)
        else:
            raise UnknownNameError(f"unknown criterion {criterion!r}; valid: "
                                   f"{', '.join(CRITERIA)}", name=criterion, choices=CRITERIA)
    return np.where(ok, value, -np.inf)


def standard_errors(info: np.ndarray) -> np.ndarray:
    """(..., p) predicted standard errors of ``ln k`` (relative SE of k): ``sqrt(diag I^-1)``;
    ``inf`` where the information is singular."""
    lam, vec = np.linalg.eigh(0.5 * (info + np.swapaxes(info, -1, -2)))
    scale = np.maximum(np.abs(lam).max(axis=-1, keepdims=True), 1e-300)
    ok = lam > 1e-12 * scale
    inv = np.where(ok, 1.0 / np.where(ok, lam, 1.0), 0.0)
    var = np.einsum("...ij,...j,...ij->...i", vec, inv, vec)
    # a parameter with a component along an unseen direction is undetermined
    unseen = np.einsum("...ij,...j->...i", np.abs(vec) > 1e-8, ~ok) > 0
    return np.where(unseen, np.inf, np.sqrt(np.maximum(var, 0.0)))


# ------------------------------------------------------------------------------------------
# selection


@dataclass
class Selection:
    """A plan over the candidates: ``poses[i]`` with the load directions ``loads[i]``.

    Attributes
    ----------
    poses
        (N,) candidate pose indices.
    loads
        (N, M) direction indices.
    value
        Criterion (information designs) or summed squared separation (separation designs).
    exchanges
        Number of accepted exchanges after the greedy pass.
    """

    poses: np.ndarray
    loads: np.ndarray
    value: float
    exchanges: int = 0

    def rows(self, n_directions: int) -> np.ndarray:
        """(N * M,) candidate row indices, configuration by configuration."""
        return (self.poses[:, None] * n_directions + self.loads).reshape(-1)


Score = Callable[[list[np.ndarray]], np.ndarray]


def _best_loads(rows: list[np.ndarray], base: list[np.ndarray], m: int, score: Score,
                allowed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For every pose, ``m`` distinct directions chosen one by one on top of ``base``.

    ``rows[i]`` (K, D, ...) are additive statistics of each candidate row, ``base[i]`` (...)
    their sum over the rows already chosen; ``score`` maps batched sums to values (larger is
    better). Returns the score per pose (K,) (``-inf`` where not allowed) and the directions
    (K, m).
    """
    k, d = rows[0].shape[:2]
    acc = [np.broadcast_to(b, (k,) + b.shape).copy() for b in base]
    used = np.zeros((k, d), dtype=bool)
    chosen = np.empty((k, m), dtype=int)
    idx = np.arange(k)
    for j in range(m):
        value = score([a[:, None] + r for a, r in zip(acc, rows, strict=True)])
        value[used] = -np.inf
        best = np.argmax(value, axis=1)
        chosen[:, j] = best
        used[idx, best] = True
        for a, r in zip(acc, rows, strict=True):
            a += r[idx, best]
    return np.where(allowed, score(acc), -np.inf), chosen


def _better(new: float, old: float) -> bool:
    return new > old + _IMPROVEMENT * (abs(old) + 1e-300) if math.isfinite(old) else new > old


def select_rows(rows: list[np.ndarray], base: list[np.ndarray], score: Score, n_configs: int,
                loads_per_config: int, passes: int = EXCHANGE_PASSES) -> Selection:
    """Greedy selection then exchange passes maximising ``score`` of additive row statistics.

    Parameters
    ----------
    rows
        Statistics of each candidate row, each (K, D, ...); a plan's statistics are their sums
        over its rows plus ``base``.
    base
        Statistics already in hand (the rows of an existing campaign, a ridge).
    score
        Batched sums -> criterion (larger is better).
    n_configs, loads_per_config
        Plan size N x M.
    passes
        Largest number of exchange passes: each chosen configuration is replaced by the best
        candidate pose (its own included, directions re-chosen), then each load direction by
        the best one at its pose, while the score improves.
    """
    k = rows[0].shape[0]
    chosen = np.zeros(k, dtype=bool)
    poses, loads = np.empty(n_configs, dtype=int), np.empty((n_configs, loads_per_config), int)
    total = [b.copy() for b in base]

    def plus(acc, pose, dirs, sign=1.0):
        return [a + sign * r[pose, dirs].sum(axis=0) for a, r in zip(acc, rows, strict=True)]

    for i in range(n_configs):
        value, dirs = _best_loads(rows, total, loads_per_config, score, ~chosen)
        best = int(np.argmax(value))
        poses[i], loads[i] = best, dirs[best]
        chosen[best] = True
        total = plus(total, best, dirs[best])
    current = float(score(total))
    exchanges = 0
    for _ in range(passes):
        changed = False
        for i in range(n_configs):
            rest = plus(total, poses[i], loads[i], -1.0)
            allowed = ~chosen
            allowed[poses[i]] = True
            value, dirs = _best_loads(rows, rest, loads_per_config, score, allowed)
            best = int(np.argmax(value))
            if _better(float(value[best]), current):
                chosen[poses[i]], chosen[best] = False, True
                poses[i], loads[i] = best, dirs[best]
                total = plus(rest, best, dirs[best])
                current, exchanges, changed = float(score(total)), exchanges + 1, True
            for j in range(loads_per_config):
                pose = poses[i]
                rest = [a - r[pose, loads[i, j]] for a, r in zip(total, rows, strict=True)]
                value = score([a[None] + r[pose] for a, r in zip(rest, rows, strict=True)])
                value[np.delete(loads[i], j)] = -np.inf
                best = int(np.argmax(value))
                if _better(float(value[best]), current):
                    loads[i, j] = best
                    total = [a + r[pose, best] for a, r in zip(rest, rows, strict=True)]
                    current, exchanges, changed = float(score(total)), exchanges + 1, True
        if not changed:
            break
    return Selection(poses, loads, current, exchanges)


def select_information(info: np.ndarray, n_configs: int, loads_per_config: int,
                       criterion: str = "D", prior: np.ndarray | None = None,
                       passes: int = EXCHANGE_PASSES) -> Selection:
    """The plan maximising a criterion of the Fisher information (module docstring).

    Parameters
    ----------
    info
        (K, D, p, p) information of each candidate row.
    n_configs, loads_per_config
        Plan size N x M.
    criterion
        ``D``, ``A`` or ``E``.
    prior
        (p, p) information already in hand (the rows of an existing campaign).
    passes
        Largest number of exchange passes.
    """
    p = info.shape[-1]
    mean_row = float(np.mean(np.trace(info, axis1=2, axis2=3))) / max(p, 1)
    base = (np.zeros((p, p)) if prior is None else np.asarray(prior, dtype=float)) \
        + RIDGE * max(mean_row, 1e-300) * np.eye(p)
    return select_rows([info], [base], lambda acc: criterion_value(acc[0], criterion),
                       n_configs, loads_per_config, passes)


def random_selections(k: int, d: int, n_configs: int, loads_per_config: int, count: int,
                      rng: np.random.Generator) -> list[Selection]:
    """``count`` random plans of the same size from the same candidates."""
    out = []
    for _ in range(count):
        poses = rng.choice(k, size=n_configs, replace=False)
        loads = np.array([rng.choice(d, size=loads_per_config, replace=False)
                          for _ in range(n_configs)])
        out.append(Selection(poses, loads, math.nan))
    return out


# ------------------------------------------------------------------------------------------
# separating two alternatives


class Fitted(Protocol):
    """A model fitted to a campaign: its :class:`~stiffness.elastic.effects.Model` (over the
    campaign's rows) and parameter vector."""

    model: Hypothesis
    x: np.ndarray


@dataclass
class Alternatives:
    """Two alternatives fitted to a campaign, and the noise their separation is measured in.

    Attributes
    ----------
    a, b
        The fits (e.g. :class:`stiffness.calibration.fitting.Fit`: the baseline plus each
        effect), anything with the fitted ``model`` (over the campaign's rows) and its ``x``.
    labels
        Their effect labels.
    sigma
        Noise std (m).
    sigma_source
        Where ``sigma`` comes from.
    """

    a: Fitted
    b: Fitted
    labels: tuple[str, str]
    sigma: float
    sigma_source: str


@dataclass
class SeparationStatistics:
    """Additive statistics of the test between two fitted alternatives, row by row.

    With ``D_r = (d_A(r) - d_B(r)) / sigma`` and ``G_r`` the derivative of ``d_B(r) / sigma``
    w.r.t. B's parameters, the squared separation left once B is refitted (linearised) to A's
    predictions over a set of rows is ``a - b^T M^-1 b`` with ``a = sum |D_r|^2``,
    ``b = sum G_r^T D_r``, ``M = sum G_r^T G_r``; the same with A and B exchanged; the
    separation is the smaller of the two (:func:`separation_score`).

    Attributes
    ----------
    rows
        ``[a_AB, b_AB, M_AB, a_BA, b_BA, M_BA]`` of each candidate row, each (K, D, ...).
    base
        Their sums over the measured rows, plus a ridge on ``M``.
    raw
        (K, D) ``|D_r|``: the difference of the two fitted predictions in noise units.
    predicted_a, predicted_b
        (K, D, 3) predictions of A and B (m).
    """

    rows: list[np.ndarray]
    base: list[np.ndarray]
    raw: np.ndarray
    predicted_a: np.ndarray
    predicted_b: np.ndarray


def _row_statistics(alt: Alternatives, rows: Rows) -> tuple[list[np.ndarray], np.ndarray,
                                                            np.ndarray, np.ndarray]:
    a, b = alt.a, alt.b
    ma, mb = a.model.replaced(rows=rows), b.model.replaced(rows=rows)
    try:
        with np.errstate(all="ignore"):
            pa, pb = ma.predict(a.x), mb.predict(b.x)
    except np.linalg.LinAlgError as exc:
        raise UnstableEquilibriumError("an alternative cannot be evaluated at some candidate "
                                       "rows (the load buckles it); lower --max-force") from exc
    diff = (pa - pb) / alt.sigma
    ga = sensitivities(ma, a.x, len(a.x)) / alt.sigma
    gb = sensitivities(mb, b.x, len(b.x)) / alt.sigma
    sq = np.sum(diff ** 2, axis=1)
    stats = [sq, np.einsum("mkq,mk->mq", gb, diff), np.einsum("mkq,mkr->mqr", gb, gb),
             sq, np.einsum("mkq,mk->mq", ga, -diff), np.einsum("mkq,mkr->mqr", ga, ga)]
    return stats, np.sqrt(sq), pa, pb


def separation_statistics(alt: Alternatives, candidates: Candidates) -> SeparationStatistics:
    """The statistics of every candidate row, on top of the rows the alternatives were fitted
    to (their models' own rows).

    Raises
    ------
    StiffnessError
        If an alternative cannot be evaluated at the candidates.
    """
    k, d = candidates.n_poses, candidates.n_directions
    stats, raw, pa, pb = _row_statistics(alt, candidates.rows)
    measured, _, _, _ = _row_statistics(alt, alt.a.model.rows)
    base = [m.sum(axis=0) for m in measured]
    for i in (2, 5):  # a ridge keeps M invertible where a parameter is not excited
        scale = float(np.mean(np.trace(stats[i], axis1=1, axis2=2))) / stats[i].shape[-1]
        base[i] = base[i] + RIDGE * max(scale, 1e-300) * np.eye(stats[i].shape[-1])
    return SeparationStatistics([v.reshape((k, d) + v.shape[1:]) for v in stats], base,
                                raw.reshape(k, d), pa.reshape(k, d, -1), pb.reshape(k, d, -1))


def separation_score(acc: list[np.ndarray]) -> np.ndarray:
    """Squared separation (noise units) left after refitting, the smaller of A-to-B and
    B-to-A, of batched sums ``[a_AB, b_AB, M_AB, a_BA, b_BA, M_BA]``."""
    out = []
    for a, b, m in (acc[0:3], acc[3:6]):
        x = np.linalg.solve(m, b[..., None])[..., 0]
        out.append(a - np.sum(b * x, axis=-1))
    return np.maximum(np.minimum(out[0], out[1]), 0.0)


def propose_measurements(campaign: Campaign, geometry: Geometry, a: Fit, b: Fit,
                         sigma: float, n_poses: int = 40, n_best: int = 3, seed: int = 0
                         ) -> list[dict]:
    """Extra poses and loads where two fitted models' predictions differ most.

    The experiment design's separation (:func:`separation_statistics`): ``n_poses``
    reachable candidate poses, loads along the axes and cube diagonals at the campaign's largest
    force; the ``n_best`` poses, one load each, that add the most separation left after either
    model is refitted, in the campaign's units. Each proposal's ``separation_noise_units`` is
    ``|dx_a - dx_b| / sigma`` there.
    """
    f_max = float(np.linalg.norm(campaign.force, axis=1).max())
    cands = candidate_set(geometry.robot, n_poses, f_max, seed)
    labels = (a.model.describe(), b.model.describe())
    sep = separation_statistics(Alternatives(a, b, labels, sigma, ""), cands)
    chosen = select_rows(sep.rows, sep.base, separation_score, min(n_best, cands.n_poses), 1)
    u = campaign.units
    robot = geometry.robot
    prismatic = np.array([robot.is_prismatic(j) for j in robot.coordinate_joints], dtype=bool)
    out = []
    for pose, load in zip(chosen.poses, chosen.loads[:, 0], strict=True):
        qc = cands.coords[pose].copy()
        qc[~prismatic] /= u.angle_to_si
        qc[prismatic] /= u.length_to_si
        force = cands.directions[load] * cands.max_force
        out.append({"q": qc.tolist(), "force": (force / u.force_to_si).tolist(),
                    "deflection_chosen": (sep.predicted_a[pose, load, :3]
                                          / u.length_to_si).tolist(),
                    "deflection_other": (sep.predicted_b[pose, load, :3]
                                         / u.length_to_si).tolist(),
                    "separation_noise_units": float(sep.raw[pose, load])})
    return out
