"""Experiment design: the poses and loads that identify the joint stiffness, or that tell two
effects apart.

Candidates (:func:`candidate_set`): reachable poses (:func:`stiffness.calibration.poses.
sample_coordinates`: joint limits, the robot's workspace rules, target above the base plane,
loops closed, away from singularities and folds) times the load directions
:data:`LOAD_DIRECTIONS` (the six axes and the eight cube diagonals) at the largest force.

Information. Row ``r`` (pose, force) has the predicted deflection ``d_r(ln k)`` of the
identification's deflection model (:class:`stiffness.calibration.effects.Model`: the
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
maximise it; ``stiffness diagnose`` proposes its extra measurements with this code.

Units: SI inside (m, N, rad, N.m/rad).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from stiffness.calibration.campaign import Campaign, RobotSettings, Units
from stiffness.calibration.diagnose import (
    Fit,
    fit_baseline,
    fit_model,
    replicate_noise,
)
from stiffness.calibration.effects import (
    BASELINES,
    LIBRARY,
    Geometry,
    Model,
    References,
    Rows,
    make_effect,
)
from stiffness.calibration.plan import Plan
from stiffness.calibration.poses import sample_coordinates
from stiffness.errors import (
    StiffnessError,
    UnknownEffectError,
    UnknownNameError,
    UnstableEquilibriumError,
    did_you_mean,
)
from stiffness.model.robot import Robot

#: Load directions of the candidates: the six axes, then the eight cube diagonals (unit).
LOAD_DIRECTIONS = np.vstack([np.eye(3), -np.eye(3)] + [
    np.array([sx, sy, sz]) / math.sqrt(3.0)
    for sx in (1, -1) for sy in (1, -1) for sz in (1, -1)])
#: Design criteria.
CRITERIA = ("D", "A", "E")
#: Default number of candidate poses.
DEFAULT_CANDIDATES = 200
#: Default number of random plans the design is compared with.
DEFAULT_RANDOM_PLANS = 50
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
        Its shared geometry (:class:`stiffness.calibration.effects.Geometry`).
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
        coords = sample_coordinates(robot, int(n_poses), np.random.default_rng(seed),
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
                   formulation: str = "enhanced") -> tuple[Model, np.ndarray]:
    """The identification's deflection model (no effect) over ``rows`` and its parameter
    vector at the nominal stiffness ``k`` (SI)."""
    if formulation not in BASELINES:
        raise UnknownNameError(f"unknown formulation {formulation!r}; valid: "
                               f"{', '.join(BASELINES)}", name=formulation, choices=BASELINES)
    k = np.asarray(k, dtype=float)
    refs = References.of(geometry, rows, float(np.exp(np.mean(np.log(k)))), np.ones((1, 3)))
    return Model(geometry, rows, formulation, compliant, (), refs), np.log(k)


def sensitivities(model: Model, x: np.ndarray, n_columns: int | None = None) -> np.ndarray:
    """(m, 3, c) derivatives of the predicted deflections (m) w.r.t. the first ``c`` entries of
    the parameter vector ``x`` (central differences, step :data:`_FD_STEP`): by default the
    ``ln k`` of the model's compliant joints.

    Raises
    ------
    StiffnessError
        If the tangent stiffness is singular for some row (the load buckles the robot).
    """
    c = len(model.compliant) if n_columns is None else n_columns
    out = np.empty((model.rows.n_rows, 3, c))
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


def parse_separate(text: str) -> tuple[tuple[str, str | None], tuple[str, str | None]]:
    """``EFFECT[:WHERE],EFFECT[:WHERE]`` as two ``(name, where)`` pairs, names checked.

    A link segment may be written ``A->B`` or ``A/B`` (a comma inside a where is not allowed).

    Raises
    ------
    StiffnessError
        Not exactly two effects, or an effect name that is not in the library.
    """
    parts = [s.strip() for s in str(text).split(",") if s.strip()]
    if len(parts) != 2:
        raise StiffnessError(f"--separate takes two effects EFFECT[:WHERE],EFFECT[:WHERE], got "
                             f"{text!r}")
    out = []
    for part in parts:
        name, _, where = part.partition(":")
        name = name.strip()
        if name not in LIBRARY:
            raise UnknownEffectError(f"unknown effect {name!r} in --separate {text!r}; "
                                     f"{did_you_mean(name, list(LIBRARY))}", name=name,
                                     choices=list(LIBRARY))
        out.append((name, where.strip() or None))
    return out[0], out[1]


def check_sizes(configs: int, loads_per_config: int, candidates: int | None) -> None:
    """Check a plan's size against the candidates (``None``: not known yet).

    Raises
    ------
    StiffnessError
        ``configs`` below 1 or above ``candidates``; ``loads_per_config`` outside 1 to the
        number of load directions.
    """
    if int(configs) < 1:
        raise StiffnessError(f"--configs must be at least 1, got {configs}")
    n_dir = len(LOAD_DIRECTIONS)
    if not 1 <= int(loads_per_config) <= n_dir:
        raise StiffnessError(f"--loads-per-config must be between 1 and {n_dir} (the axis and "
                             f"cube-diagonal directions), got {loads_per_config}")
    if candidates is not None and int(configs) > int(candidates):
        raise StiffnessError(f"--configs {configs} is larger than the {candidates} candidate "
                             "poses; raise --candidates or lower --configs")


@dataclass
class Alternatives:
    """Two alternatives fitted to a campaign, and the noise their separation is measured in.

    Attributes
    ----------
    a, b
        The fits (baseline plus each effect).
    labels
        Their effect labels.
    sigma
        Noise std (m).
    sigma_source
        Where ``sigma`` comes from.
    """

    a: Fit
    b: Fit
    labels: tuple[str, str]
    sigma: float
    sigma_source: str


def fit_alternatives(campaign: Campaign, effects: tuple[tuple[str, str | None], ...],
                     sigma: float | None = None) -> Alternatives:
    """Fit the campaign's baseline plus each of two effects, as ``diagnose`` does.

    Parameters
    ----------
    campaign
        The measured campaign.
    effects
        Two ``(name, where)`` pairs (:func:`parse_separate`).
    sigma
        Noise std (m); default the campaign's declared one, else the replicates', else the
        residual scatter of the better fit.

    Raises
    ------
    StiffnessError
        An unknown effect or place, or the same effect twice.
    """
    robot = campaign.robot()
    geo = Geometry.of(robot)
    chosen = [make_effect(name, where, geo) for name, where in effects]
    if chosen[0].key() == chosen[1].key():
        raise StiffnessError(f"--separate needs two different effects, got {chosen[0].label} "
                             "twice")
    rows = geo.rows(campaign.q, campaign.force, campaign.moment,
                    labels=[campaign.describe_row(i) for i in range(campaign.n_rows)])
    measured = campaign.deflection
    source = "given"
    if sigma is None and campaign.noise_std_m is not None:
        sigma, source = campaign.noise_std_m, "declared noise_std of the campaign"
    if sigma is None:
        rep = replicate_noise(campaign)
        if rep is not None:
            sigma, source = rep[0], "replicate rows of the campaign"
    scale = sigma if sigma is not None else max(float(np.sqrt(np.mean(measured ** 2))) * 1e-2,
                                                1e-12)
    refs0 = References.of(geo, rows, 1e5, measured)
    model0 = Model(geo, rows, campaign.baseline, tuple(robot.compliant_joints), (), refs0)
    base = fit_baseline(model0, measured, scale)
    refs = References.of(geo, rows, float(np.exp(np.mean(base.x))), measured)
    base.model = base.model.with_refs(refs)
    fits = [fit_model(base.model.extended(e), measured, scale, base.model.extend_x(base.x, e))
            for e in chosen]
    if sigma is None:
        best = min(fits, key=lambda f: f.rss)
        dof = max(measured.size - best.model.penalty_params, 1)
        sigma, source = math.sqrt(best.rss / dof), "residual scatter of the better fit"
    return Alternatives(fits[0], fits[1], (chosen[0].label, chosen[1].label), float(sigma),
                        source)


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
    ma, mb = a.model.with_rows(rows), b.model.with_rows(rows)
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
                                raw.reshape(k, d), pa.reshape(k, d, 3), pb.reshape(k, d, 3))


def separation_score(acc: list[np.ndarray]) -> np.ndarray:
    """Squared separation (noise units) left after refitting, the smaller of A-to-B and
    B-to-A, of batched sums ``[a_AB, b_AB, M_AB, a_BA, b_BA, M_BA]``."""
    out = []
    for a, b, m in (acc[0:3], acc[3:6]):
        x = np.linalg.solve(m, b[..., None])[..., 0]
        out.append(a - np.sum(b * x, axis=-1))
    return np.maximum(np.minimum(out[0], out[1]), 0.0)


# ------------------------------------------------------------------------------------------
# the design


@dataclass
class Prediction:
    """Predicted precision of a plan (with the existing rows, if any).

    Attributes
    ----------
    relative_se
        (p,) predicted standard error of each k relative to k.
    separation
        Predicted separation of the two alternatives over the plan's rows, noise units
        (``sqrt(sum_r s_r^2)``), or ``None``.
    """

    relative_se: np.ndarray
    separation: float | None = None

    @property
    def mean_relative_se(self) -> float:
        """Mean over the joints of the relative standard error."""
        return float(np.mean(self.relative_se))


@dataclass
class DesignResult:
    """Result of :func:`design` (SI).

    Attributes
    ----------
    plan
        The rows to measure.
    robot
        The robot.
    joints
        Compliant joints (the identified stiffnesses).
    k
        Nominal stiffness the design is local to (SI).
    k_source
        Where ``k`` comes from.
    noise_std_m, noise_source
        Noise std per deflection component (m) and where it comes from.
    criterion
        ``D``, ``A`` or ``E``.
    formulation
        The deflection model's baseline.
    n_candidates, n_directions, max_force
        Candidate poses, load directions, load magnitude (N).
    designed
        Prediction for the plan.
    random
        Predictions for the random plans of the same size.
    existing
        Prediction for the existing campaign alone, or ``None``.
    existing_rows
        Number of rows of the existing campaign (0 if none).
    separate
        The two effect labels of ``--separate``, or ``None``.
    separation_sigma_source
        Where the noise of the separation comes from.
    row_separation
        (rows,) predicted separation of each plan row, noise units, or ``None``.
    exchanges
        Exchanges accepted after the greedy pass.
    notes
        Remarks.
    """

    plan: Plan
    robot: Robot
    joints: tuple[str, ...]
    k: np.ndarray
    k_source: str
    noise_std_m: float
    noise_source: str
    criterion: str
    formulation: str
    n_candidates: int
    n_directions: int
    max_force: float
    designed: Prediction
    random: list[Prediction]
    existing: Prediction | None = None
    existing_rows: int = 0
    separate: tuple[str, str] | None = None
    separation_sigma_source: str | None = None
    row_separation: np.ndarray | None = None
    exchanges: int = 0
    notes: list[str] = field(default_factory=list)

    @property
    def random_relative_se(self) -> np.ndarray:
        """(R, p) relative standard errors of the random plans."""
        return np.array([r.relative_se for r in self.random])

    @property
    def determined(self) -> np.ndarray:
        """(p,) whether the plan determines each stiffness (finite standard error)."""
        return np.isfinite(self.designed.relative_se)

    @property
    def se_ratio(self) -> float:
        """Mean relative SE of the plan over the mean of the random plans' (lower is better),
        over the stiffnesses the plan determines."""
        keep = self.determined
        if not keep.any():
            return math.nan
        mean_random = float(np.mean(self.random_relative_se[:, keep]))
        return float(np.mean(self.designed.relative_se[keep])) / mean_random

    def to_dict(self) -> dict:
        """JSON-ready summary (SI; infinities become ``None``)."""
        def num(v):
            v = float(v)
            return v if math.isfinite(v) else None

        rnd = self.random_relative_se
        rnd_sep = [r.separation for r in self.random if r.separation is not None]
        out = {
            "robot": self.robot.name,
            "compliant_joints": list(self.joints),
            "k_nominal": dict(zip(self.joints, self.k.tolist(), strict=True)),
            "k_source": self.k_source,
            "noise_std_m": self.noise_std_m,
            "noise_source": self.noise_source,
            "criterion": self.criterion,
            "formulation": self.formulation,
            "configs": int(len(dict.fromkeys(self.plan.config))),
            "rows": self.plan.n_rows,
            "candidates": self.n_candidates,
            "load_directions": self.n_directions,
            "max_force_N": self.max_force,
            "exchanges": self.exchanges,
            "existing_rows": self.existing_rows,
            "plan_file": str(self.plan.path) if self.plan.path is not None else None,
            "predicted_relative_se": {
                "plan": {j: num(v) for j, v in zip(self.joints, self.designed.relative_se,
                                                    strict=True)},
                "plan_mean": num(self.designed.mean_relative_se),
                "determined": [j for j, ok in zip(self.joints, self.determined, strict=True)
                               if ok],
                "random_mean": {j: num(v) for j, v in zip(self.joints, rnd.mean(axis=0),
                                                           strict=True)},
                "random_median": {j: num(v) for j, v in zip(self.joints, np.median(rnd, axis=0),
                                                             strict=True)},
                "random_plans": len(self.random),
                "random_plan_mean": num(np.mean([r.mean_relative_se for r in self.random])),
                "ratio_plan_to_random": num(self.se_ratio),
                "existing": None if self.existing is None else {
                    j: num(v) for j, v in zip(self.joints, self.existing.relative_se,
                                              strict=True)},
            },
            "notes": self.notes,
        }
        if self.separate is not None:
            out["separate"] = {
                "effects": list(self.separate),
                "noise_source": self.separation_sigma_source,
                "plan_noise_units": num(self.designed.separation),
                "random_mean_noise_units": num(np.mean(rnd_sep)) if rnd_sep else None,
                "existing_noise_units": None if self.existing is None
                or self.existing.separation is None else num(self.existing.separation),
                "rows_noise_units": [num(v) for v in self.row_separation],
            }
        return out


def _info_of(cands: Candidates, model: Model, x: np.ndarray, sigma: float) -> np.ndarray:
    sens = sensitivities(model.with_rows(cands.rows), x)
    info = row_information(sens, sigma)
    p = info.shape[-1]
    return info.reshape(cands.n_poses, cands.n_directions, p, p)


def design(
    robot: Robot,
    configs: int,
    max_force: float,
    loads_per_config: int = 4,
    candidates: int | Candidates = DEFAULT_CANDIDATES,
    criterion: str = "D",
    k: np.ndarray | list[float] | None = None,
    noise_std_m: float | None = None,
    existing: Campaign | None = None,
    separate: str | tuple | None = None,
    seed: int = 0,
    formulation: str = "enhanced",
    random_plans: int = DEFAULT_RANDOM_PLANS,
    units: Units | None = None,
    progress: Callable[[str], None] | None = None,
) -> DesignResult:
    """Design a measurement plan (see the module docstring).

    Parameters
    ----------
    robot
        The robot; its compliant joints are the stiffnesses to identify.
    configs
        Number of configurations N of the plan.
    max_force
        Load magnitude (N).
    loads_per_config
        Load directions M per configuration (distinct).
    candidates
        Number of candidate poses K, or a :class:`Candidates` built by :func:`candidate_set`.
    criterion
        ``D`` (default), ``A`` or ``E``.
    k
        Nominal stiffness per compliant joint (SI); default the robot's shipped
        ``k_theta_SI``, else the baseline fitted to ``existing``.
    noise_std_m
        Noise std per deflection component (m); default the existing campaign's declared one,
        else 5e-6 m.
    existing
        A measured campaign whose rows count as already chosen (the plan completes it).
    separate
        ``"EFFECT[:WHERE],EFFECT[:WHERE]"``: choose the rows that tell these two alternatives,
        fitted to ``existing``, apart.
    seed
        Seed of the candidate poses and of the random plans.
    formulation
        ``enhanced`` (K_C included, default) or ``conventional``.
    random_plans
        Number of random plans compared with.
    units
        Units of the plan files (default deg, N, mm; the existing campaign's if given).
    progress
        Called with a line of text as the work goes.

    Raises
    ------
    StiffnessError
        No compliant joint; configs or loads per config out of range (more than the candidates
        or the load directions); an unknown criterion or effect; ``separate`` without
        ``existing``; no nominal stiffness; a load that buckles the robot.
    """
    say = progress or (lambda text: None)
    if criterion not in CRITERIA:
        raise UnknownNameError(f"unknown criterion {criterion!r}; valid: {', '.join(CRITERIA)}",
                               name=criterion, choices=CRITERIA)
    if robot.n_compliant == 0:
        raise StiffnessError(f"{robot.name} has no compliant joint: there is no stiffness to "
                             "design for; name the springs with --compliant-joints")
    check_sizes(configs, loads_per_config,
                candidates.n_poses if isinstance(candidates, Candidates) else candidates)
    if not (math.isfinite(max_force) and max_force > 0):
        raise StiffnessError(f"--max-force must be a positive force in N, got {max_force}")
    if int(random_plans) < 1:
        raise StiffnessError(f"--random-plans must be at least 1, got {random_plans}")
    if existing is not None and existing.robot().coordinate_joints != robot.coordinate_joints:
        raise StiffnessError(f"the existing campaign {existing.name!r} is of another robot "
                             f"({existing.robot().name}) than {robot.name}")
    if separate is not None and existing is not None and (
            existing.robot().target_frame != robot.target_frame
            or not np.allclose(existing.robot().target_offset, robot.target_offset)):
        raise StiffnessError("--separate designs for the existing campaign's target; drop "
                             "--frame and --target-offset")
    pair = None
    if separate is not None:
        pair = parse_separate(separate) if isinstance(separate, str) else tuple(separate)
        if existing is None:
            raise StiffnessError("--separate needs --existing CAMPAIGN: the two alternatives are "
                                 "fitted to its measurements")
        geo = Geometry.of(robot)
        for name, where in pair:
            make_effect(name, where, geo)  # unknown effect or place: one line, before any work
    notes: list[str] = []

    # nominal stiffness
    joints = tuple(robot.compliant_joints)
    if k is not None:
        k_arr, k_source = np.asarray(k, dtype=float).reshape(-1), "given"
    elif "k_theta_SI" in robot.defaults and len(robot.defaults["k_theta_SI"]) == len(joints):
        k_arr, k_source = np.asarray(robot.defaults["k_theta_SI"], dtype=float), \
            "the robot's shipped k_theta_SI"
    elif existing is not None:
        geo = Geometry.of(existing.robot())
        rows = geo.rows(existing.q, existing.force, existing.moment)
        model0 = Model(geo, rows, existing.baseline, joints,
                       (), References.of(geo, rows, 1e5, existing.deflection))
        scale = existing.noise_std_m or max(float(np.sqrt(np.mean(existing.deflection ** 2)))
                                            * 1e-2, 1e-12)
        k_arr = np.exp(fit_baseline(model0, existing.deflection, scale).x)
        k_source = f"the baseline fitted to the existing campaign {existing.name!r}"
    else:
        raise StiffnessError(f"--kq is required: the design is local to a nominal stiffness, one "
                             f"per compliant joint ({', '.join(joints)}), N.m/rad (N/m "
                             "prismatic)")
    if k_arr.shape != (len(joints),) or not np.all(np.isfinite(k_arr)) or np.any(k_arr <= 0):
        raise StiffnessError(f"need {len(joints)} positive stiffnesses (one per compliant joint "
                             f"{', '.join(joints)}), got {k_arr.tolist()}")
    if noise_std_m is not None:
        sigma, noise_source = float(noise_std_m), "given"
    elif existing is not None and existing.noise_std_m is not None:
        sigma, noise_source = existing.noise_std_m, "declared noise_std of the existing campaign"
    else:
        sigma, noise_source = 5e-6, "default (5e-6 m)"
    if not (math.isfinite(sigma) and sigma > 0):
        raise StiffnessError(f"the noise std must be a positive length, got {sigma}")

    # candidates and their information
    if isinstance(candidates, Candidates):
        cands = candidates
    else:
        say(f"drawing {candidates} candidate poses")
        cands = candidate_set(robot, int(candidates), max_force, seed)
    model, x = baseline_model(cands.geometry, cands.rows, joints, k_arr, formulation)
    info = _info_of(cands, model, x, sigma)
    prior = None
    existing_pred = None
    if existing is not None:
        ex_rows = cands.geometry.rows(existing.q, existing.force, existing.moment)
        prior = row_information(sensitivities(model.with_rows(ex_rows), x), sigma).sum(axis=0)
        existing_pred = Prediction(standard_errors(prior))

    # selection
    alternatives = None
    if pair is not None:
        say(f"fitting {pair[0][0]} and {pair[1][0]} to {existing.name}")
        alternatives = fit_alternatives(existing, pair, noise_std_m)
        sep = separation_statistics(alternatives, cands)
        selection = select_rows(sep.rows, sep.base, separation_score, int(configs),
                                int(loads_per_config))
        existing_pred.separation = float(np.sqrt(separation_score(sep.base)))
    else:
        say(f"selecting {configs} x {loads_per_config} rows ({criterion}-optimal)")
        selection = select_information(info, int(configs), int(loads_per_config), criterion,
                                       prior)

    def predict(sel: Selection) -> Prediction:
        total = info[sel.poses[:, None], sel.loads].sum(axis=(0, 1))
        if prior is not None:
            total = total + prior
        pred = Prediction(standard_errors(total))
        if alternatives is not None:
            acc = [b + r[sel.poses[:, None], sel.loads].sum(axis=(0, 1))
                   for b, r in zip(sep.base, sep.rows, strict=True)]
            pred.separation = float(np.sqrt(separation_score(acc)))
        return pred

    designed = predict(selection)
    rng = np.random.default_rng(None if seed is None else seed + 7919)
    randoms = [predict(s) for s in random_selections(
        cands.n_poses, cands.n_directions, int(configs), int(loads_per_config),
        int(random_plans), rng)]
    unseen = ~np.isfinite(standard_errors(info.sum(axis=(0, 1))))
    if unseen.any():
        notes.append(f"no candidate row determines {', '.join(np.array(joints)[unseen])}: a force "
                     "at the target does not load it or its motion does not move the target "
                     "(e.g. a last joint whose axis passes through the target); its standard "
                     "error is infinite whatever the plan")
    elif not np.all(np.isfinite(designed.relative_se)):
        notes.append("the plan leaves some stiffness undetermined: add configurations or loads")

    # the plan
    rows_idx = selection.rows(cands.n_directions)
    q = np.repeat(cands.coords[selection.poses], int(loads_per_config), axis=0)
    force = cands.directions[selection.loads.reshape(-1)] * cands.max_force
    taken = set(existing.config) if existing is not None else set()
    prefix = "P"
    while any(f"{prefix}{i + 1}" in taken for i in range(int(configs))):
        prefix += "P"
    labels = tuple(f"{prefix}{i // int(loads_per_config) + 1}" for i in range(len(q)))
    if units is None:
        units = existing.units if existing is not None else Units()
    settings = (existing.robot_settings if existing is not None else RobotSettings(
        robot.name, frame=robot.target_frame, target_offset_m=robot.target_offset.copy(),
        compliant_joints=joints))
    plan = Plan(q=q, force=force, config=labels, units=units, robot_settings=settings,
                name=(f"{existing.name}-plan" if existing is not None else f"plan-{robot.name}"),
                baseline=existing.baseline if existing is not None else formulation,
                noise_std_m=sigma)
    row_sep = None
    if alternatives is not None:
        row_sep = sep.raw.reshape(-1)[rows_idx]
    return DesignResult(
        plan=plan, robot=robot, joints=joints, k=k_arr, k_source=k_source, noise_std_m=sigma,
        noise_source=noise_source, criterion=criterion, formulation=formulation,
        n_candidates=cands.n_poses, n_directions=cands.n_directions, max_force=cands.max_force,
        designed=designed, random=randoms, existing=existing_pred,
        existing_rows=existing.n_rows if existing is not None else 0,
        separate=alternatives.labels if alternatives is not None else None,
        separation_sigma_source=alternatives.sigma_source if alternatives is not None else None,
        row_separation=row_sep, exchanges=selection.exchanges, notes=notes)
