"""Experiment design, the workflow of ``stiffness design``: a plan of N configurations x M
loads that identifies the joint stiffness best (or completes a measured campaign, or tells two
alternatives fitted to it apart), with the predicted standard errors of the plan and of random
plans of the same size.

The mathematics (candidates, Fisher information of ln k, D/A/E criteria, greedy and exchange
selection, the separation left after refitting) is in :mod:`stiffness.calibration.experiment`;
the plan files in :mod:`stiffness.planning.plan`.

Units: SI inside (m, N, rad, N.m/rad).
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stiffness.calibration.campaign import Campaign, load_campaign
from stiffness.calibration.campaign_toml import RobotSettings
from stiffness.calibration.deflection_noise import interval_quantiles
from stiffness.calibration.experiment import (
    CRITERIA,
    LOAD_DIRECTIONS,
    Alternatives,
    Candidates,
    Selection,
    SeparationStatistics,
    baseline_model,
    candidate_set,
    random_selections,
    row_information,
    select_information,
    select_rows,
    sensitivities,
    separation_score,
    separation_statistics,
    standard_errors,
)
from stiffness.calibration.fitting import reference_stiffness
from stiffness.calibration.selection import Noise, fit_baseline, fit_model, replicate_noise
from stiffness.elastic.effects import LIBRARY, make_effect
from stiffness.elastic.effects.base import effect_place
from stiffness.elastic.effects.geometry import Geometry, References
from stiffness.elastic.effects.hypothesis import BASELINES, Hypothesis
from stiffness.elastic.model_contents import ModelFile
from stiffness.elastic.model_file import read_model_file
from stiffness.errors import StiffnessError, UnknownEffectError, UnknownNameError, did_you_mean
from stiffness.mechanics.defaults import joint_stiffnesses
from stiffness.planning.plan import Plan, write_plan
from stiffness.planning.simulate import build_truth, row_smoothing_torques
from stiffness.robot.calibration import robot_description, robot_difference, robot_identity
from stiffness.robot.robot import Robot, load_robot
from stiffness.units import Units, float_array, whole_number

#: Default number of candidate poses.
DEFAULT_CANDIDATES = 200
#: Most candidate poses (memory and time grow linearly: ~0.1 MB and ~10 ms each for a UR5).
MAX_CANDIDATES = 10_000
#: Default number of random plans the design is compared with.
DEFAULT_RANDOM_PLANS = 50
#: Default measurement noise std per deflection component, m (0.005 mm: a dial gauge's or a
#: laser tracker's), of a design and of ``stiffness simulate``.
DEFAULT_NOISE_STD_M = 5e-6


def parse_separate(text: str) -> tuple[tuple[str, str | None], tuple[str, str | None]]:
    """``EFFECT[:WHERE],EFFECT[:WHERE]`` as two ``(name, where)`` pairs, names checked; a
    place may also be written ``EFFECT(WHERE)``
    (:func:`~stiffness.elastic.effects.base.effect_place`).

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
        name, where = effect_place(part, "--separate")
        if name not in LIBRARY:
            raise UnknownEffectError(f"unknown effect {name!r} in --separate {text!r}; "
                                     f"{did_you_mean(name, list(LIBRARY))}", name=name,
                                     choices=list(LIBRARY))
        out.append((name, where))
    return out[0], out[1]


def check_sizes(configs: int, loads_per_config: int, candidates: int | None) -> None:
    """Check a plan's size against the candidates (``None``: not known yet).

    Raises
    ------
    StiffnessError
        ``configs`` below 1 or above ``candidates``; ``candidates`` above
        :data:`MAX_CANDIDATES`; ``loads_per_config`` outside 1 to the number of load
        directions.
    """
    if int(configs) < 1:
        raise StiffnessError(f"--configs must be at least 1, got {configs}")
    n_dir = len(LOAD_DIRECTIONS)
    if not 1 <= int(loads_per_config) <= n_dir:
        raise StiffnessError(f"--loads-per-config must be between 1 and {n_dir} (the axis and "
                             f"cube-diagonal directions), got {loads_per_config}")
    if candidates is not None and int(candidates) > MAX_CANDIDATES:
        raise StiffnessError(f"--candidates {candidates} is more than {MAX_CANDIDATES}: the search "
                             "keeps every candidate's loads and information matrices in memory "
                             "(about 0.1 MB and 10 ms each on a 6-joint arm); give at most "
                             f"{MAX_CANDIDATES}")
    if candidates is not None and int(configs) > int(candidates):
        raise StiffnessError(f"--configs {configs} is larger than the {candidates} candidate "
                             "poses; raise --candidates or lower --configs")


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
    if chosen[0].label == chosen[1].label:
        raise StiffnessError(f"--separate needs two different effects, got {chosen[0].label} "
                             "twice")
    rows = geo.rows(campaign.q, campaign.force, campaign.moment,
                    labels=[campaign.describe_row(i) for i in range(campaign.n_rows)],
                    joint_angles=campaign.robot_settings.joint_angles)
    measured = campaign.deflection
    source, known = "given", None if sigma is None else Noise(sigma)
    if sigma is None and (declared := campaign.noise_std_m) is not None:
        (sigma, source), known = (declared, "declared noise_std of the campaign"), Noise(declared)
    if sigma is None and (rep := replicate_noise(campaign)) is not None:
        (sigma, source), known = (rep[0], "replicate rows of the campaign"), Noise(*rep)
    scale = sigma if sigma is not None else max(float(np.sqrt(np.mean(measured ** 2))) * 1e-2,
                                                1e-12)
    model0 = Hypothesis(geo, rows, campaign.baseline, tuple(robot.compliant_joints), (),
                        References.of(geo, rows, 1e5, measured))
    base = fit_baseline(model0, measured, scale)
    q = interval_quantiles(known, base, measured.size, None, measured)  # diagnose's intervals
    k_ref = reference_stiffness(base, q.noise.sigma, q.two_sided(), measured)
    base.model = base.model.replaced(refs=References.of(geo, rows, k_ref, measured))
    fits = [fit_model(base.model.extended(e), measured, scale, base.model.extend_x(base.x, e))
            for e in chosen]
    if sigma is None:
        best = min(fits, key=lambda f: f.rss)
        dof = max(measured.size - best.penalty_params, 1)
        sigma, source = math.sqrt(best.rss / dof), "residual scatter of the better fit"
    return Alternatives(fits[0], fits[1], (chosen[0].label, chosen[1].label), float(sigma), source)


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
    linearisation
        ``(rms_m, largest_m)``: the RMS (m) by which ``formulation``'s linear deflections miss
        the exact equilibrium at the nominal stiffness on the plan's rows, and the largest
        exact deflection (m); ``None`` when the exact equilibrium was not found.
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
    linearisation: tuple[float, float] | None = None

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

    def write(self, out: str | os.PathLike) -> Path:
        """Write the plan (:func:`stiffness.planning.plan.write_plan`: ``PLAN.csv``, or a folder
        with ``campaign.toml`` and ``plan.csv``); returns the CSV written, now
        ``plan.path``."""
        self.plan.path = write_plan(self.plan, self.robot, out)
        return self.plan.path

    def to_dict(self) -> dict:
        """JSON-ready summary (SI; infinities become ``None``): the object ``stiffness design
        --json`` prints (``plan_file``: the plan :meth:`write` wrote)."""
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
            "linearisation_error": None if self.linearisation is None else {
                "rms_m": self.linearisation[0],
                "noise_units": self.linearisation[0] / self.noise_std_m,
                "largest_deflection_m": self.linearisation[1]},
        }
        if self.separate is not None:
            out["separate"] = {
                "effects": list(self.separate),
                "noise_source": self.separation_sigma_source,
                "plan_noise_units": num(self.designed.separation),
                "random_mean_noise_units": num(np.mean(rnd_sep)) if rnd_sep else None,
                "existing_noise_units": None if self.existing is None
                or self.existing.separation is None else num(self.existing.separation),
                "rows_noise_units": [] if self.row_separation is None
                else [num(v) for v in self.row_separation],
            }
        return out


def _info_of(cands: Candidates, model: Hypothesis, x: np.ndarray, sigma: float) -> np.ndarray:
    sens = sensitivities(model.replaced(rows=cands.rows), x)
    info = row_information(sens, sigma)
    p = info.shape[-1]
    return info.reshape(cands.n_poses, cands.n_directions, p, p)


def design_robot(robot: str | None = None, frame: str | None = None,
                 target_offset_m: list[float] | np.ndarray | None = None,
                 compliant_joints: list[str] | tuple[str, ...] | None = None,
                 loops: str | None = None, fixed_base: bool = False,
                 model: ModelFile | None = None, existing: Campaign | None = None) -> Robot:
    """The robot a design is for: the given source, target and springs, the model file's
    (``model``), else the existing campaign's filling what is not given (the existing
    campaign's own robot when nothing is given).

    Raises
    ------
    StiffnessError
        No robot from any of them.
    """
    fallback: tuple[str, str | None, np.ndarray, tuple[str, ...]] | None = None
    if model is not None:
        fallback = (model.source, model.frame, model.target_offset_m, model.compliant_joints)
        options = model.robot_options()
    elif existing is not None:
        if all(v is None for v in (robot, frame, target_offset_m, compliant_joints)):
            return existing.robot()
        if robot is not None and robot_identity(robot) != robot_identity(
                existing.resolved_source()):  # another robot: not the campaign's frame, springs
            _check_existing_robot(load_robot(robot, loops=loops, fixed_base=fixed_base), existing)
        s = existing.robot_settings
        fallback = (existing.resolved_source(), s.frame, s.target_offset_m,
                    s.compliant_joints or existing.robot().compliant_joints)
        options = existing.robot_options()
    if fallback is not None:  # the model's or campaign's loop file and fixed base too
        loops = loops or options["loops"]
        fixed_base = fixed_base or options["fixed_base"]
        robot = robot or fallback[0]
        frame = frame or fallback[1]
        if target_offset_m is None:
            target_offset_m = [float(v) for v in fallback[2]]
        if compliant_joints is None:
            compliant_joints = list(fallback[3])
    if robot is None:
        raise StiffnessError("--robot is required (or --model FILE, or --existing CAMPAIGN)")
    return load_robot(robot, frame=frame, target_offset=target_offset_m,
                      compliant_joints=compliant_joints, loops=loops, fixed_base=fixed_base)


def design(
    robot: Robot | str | None, configs: int, max_force: float, loads_per_config: int = 4,
    candidates: int | Candidates = DEFAULT_CANDIDATES, criterion: str = "D",
    k: np.ndarray | list[float] | None = None, noise_std_m: float | None = None,
    existing: Campaign | str | os.PathLike | None = None, separate: str | tuple | None = None,
    seed: int = 0, formulation: str | None = None,
    random_plans: int = DEFAULT_RANDOM_PLANS, units: Units | None = None,
    progress: Callable[[str], None] | None = None,
    model: ModelFile | str | os.PathLike | None = None, k_source: str | None = None,
) -> DesignResult:
    """Design a measurement plan (see the module docstring): ``stiffness design``
    (:meth:`DesignResult.to_dict` is its ``--json`` object once :meth:`DesignResult.write`
    has written the plan).

    Parameters
    ----------
    robot
        The robot (its compliant joints are the stiffnesses to identify), or its source
        (:func:`design_robot`: ``model``'s or ``existing``'s target and springs; ``None``:
        theirs entirely).
    configs, loads_per_config
        Configurations N of the plan, and load directions M per configuration (distinct).
    max_force
        Load magnitude (N).
    candidates, criterion
        Number of candidate poses K, or a :class:`Candidates` built by :func:`candidate_set`;
        ``D`` (default), ``A`` or ``E``.
    k, k_source
        Nominal stiffness per compliant joint (SI) and where it comes from (default
        ``given``); default ``model``'s K_theta (same compliant joints), the robot's shipped
        ``k_theta_SI``, else the baseline fitted to ``existing``.
    noise_std_m
        Noise std per deflection component (m); default the existing campaign's declared one,
        else :data:`DEFAULT_NOISE_STD_M`.
    existing
        A measured campaign (or its path) whose rows count as already chosen (the plan
        completes it).
    separate
        ``"EFFECT[:WHERE],EFFECT[:WHERE]"``: choose the rows that tell these two alternatives,
        fitted to ``existing``, apart.
    seed, random_plans
        Seed of the candidate poses and of the random plans; how many random plans.
    formulation
        ``enhanced`` (K_C included) or ``conventional``; default ``existing``'s baseline,
        else ``model``'s formulation, else ``enhanced``.
    units, progress
        Units of the plan files (default deg, N, mm; the existing campaign's if given); called
        with a line of text as the work goes.
    model
        An identified model file (or its path): the robot's target and springs, the nominal
        stiffness and formulation.

    Raises
    ------
    StiffnessError
        No compliant joint; configs or loads per config out of range (more than the candidates
        or the load directions); an unknown criterion or effect; ``separate`` without
        ``existing``; no nominal stiffness; a load that buckles the robot.
    """
    say = progress or (lambda text: None)
    robot, existing, model, formulation = _inputs(robot, existing, model, formulation)
    pair = _check_request(robot, configs, max_force, loads_per_config, candidates, criterion,
                          random_plans, existing, separate)
    joints = tuple(robot.compliant_joints)
    k_arr, k_source = _nominal_stiffness(robot, k, k_source, model, existing)
    sigma, noise_source = _noise_level(noise_std_m, existing)
    cands = _candidates(robot, candidates, max_force, seed, say)
    search = _Search.of(cands, joints, k_arr, formulation, sigma, existing)
    alternatives = _alternatives(search, pair, existing, noise_std_m, say)
    if alternatives is None:
        say(f"selecting {configs} x {loads_per_config} rows ({criterion}-optimal)")
    selection = search.select(int(configs), int(loads_per_config), criterion)
    designed = search.predict(selection)
    randoms = _random_predictions(search, configs, loads_per_config, random_plans, seed)
    plan = _plan(robot, cands, selection, int(configs), int(loads_per_config), existing,
                 units, formulation, sigma)
    linearisation = linearisation_error(robot, k_arr, plan, formulation)  # the model's reach
    return DesignResult(
        plan=plan, robot=robot, joints=joints, k=k_arr, k_source=k_source,
        noise_std_m=sigma, noise_source=noise_source, criterion=criterion,
        formulation=formulation, n_candidates=cands.n_poses, n_directions=cands.n_directions,
        max_force=cands.max_force, designed=designed, random=randoms,
        existing=search.existing,
        existing_rows=existing.n_rows if existing is not None else 0,
        separate=alternatives.labels if alternatives is not None else None,
        separation_sigma_source=alternatives.sigma_source if alternatives is not None else None,
        row_separation=None if alternatives is None else search.row_separation(selection),
        exchanges=selection.exchanges, linearisation=linearisation,
        notes=search.notes(designed, joints) + _linearisation_notes(
            linearisation, sigma, formulation, max_force))


def _candidates(robot: Robot, candidates: int | Candidates, max_force: float, seed: int,
                say: Callable[[str], None]) -> Candidates:
    """``candidates`` if built, else that many candidate poses drawn (loads ``max_force``, N)."""
    if isinstance(candidates, Candidates):
        return candidates
    say(f"drawing {candidates} candidate poses")
    return candidate_set(robot, int(candidates), max_force, seed)


def _alternatives(search: _Search, pair: tuple | None, existing: Campaign | None,
                  noise_std_m: float | None, say: Callable[[str], None]) -> Alternatives | None:
    """The two alternatives of ``pair`` fitted to ``existing``, set on ``search``; or None."""
    if pair is None or existing is None:  # _check_request: a pair has an existing
        return None
    say(f"fitting {pair[0][0]} and {pair[1][0]} to {existing.name}")
    alternatives = fit_alternatives(existing, pair, noise_std_m)
    search.separate(alternatives)
    return alternatives


def _random_predictions(search: _Search, configs: int, loads_per_config: int,
                        random_plans: int, seed: int | None) -> list[Prediction]:
    """The predictions of ``random_plans`` random plans of the same size from the candidates
    (seeded by ``seed``)."""
    rng = np.random.default_rng(None if seed is None else whole_number(seed, "seed", 0) + 7919)
    return [search.predict(s) for s in random_selections(
        search.cands.n_poses, search.cands.n_directions, int(configs), int(loads_per_config),
        int(random_plans), rng)]


def linearisation_error(robot: Robot, k: np.ndarray, plan: Plan, formulation: str
                        ) -> tuple[float, float] | None:
    """How far the design's linear model is from the exact equilibrium on the plan's rows.

    Parameters
    ----------
    robot, k
        The robot and its nominal stiffness per compliant joint (N.m/rad, N/m).
    plan
        The rows (coordinates rad, m; forces N).
    formulation
        ``enhanced`` or ``conventional``.

    Returns
    -------
    ``(rms_m, largest_m)``: the RMS difference (m) between the exact and the linear
    deflections per component, and the largest exact deflection (m); ``None`` when the exact
    equilibrium is not found at some row (the load buckles the robot there, or the loop
    passes a singularity).
    """
    geometry = Geometry.of(robot)
    smoothing = row_smoothing_torques(geometry.robot, plan.q, plan.force)  # as simulate's
    truth = build_truth(robot, np.asarray(k, dtype=float), [], plan.units, smoothing, geometry)
    try:
        exact = truth.deflections(plan.q, plan.force)
    except StiffnessError:
        return None
    linear = truth.deflections(plan.q, plan.force, mode=formulation)
    return (float(np.sqrt(np.mean((exact - linear) ** 2))),
            float(np.linalg.norm(exact, axis=1).max()))


def _linearisation_notes(linearisation: tuple[float, float] | None, sigma: float,
                         formulation: str, max_force: float) -> list[str]:
    """The note when the plan's loads take the robot out of the design's linear model (its
    predicted errors assume the model)."""
    fix = (f"the predicted errors assume that model; identify with --formulation exact, or "
           f"lower --max-force ({max_force:g} N)")
    if linearisation is None:
        return [f"the exact equilibrium is not found at some of the plan's rows (the load "
                f"buckles the robot, or a loop passes a singularity): {fix}"]
    rms, largest = linearisation
    if rms <= sigma:
        return []
    return [f"at the nominal stiffness the {formulation} model misses the exact equilibrium by "
            f"{rms / sigma:.3g} noise std RMS on the plan's rows (the largest deflection "
            f"{largest * 1e3:.3g} mm): {fix}"]


def _inputs(robot: Robot | str | None, existing: Campaign | str | os.PathLike | None,
            model: ModelFile | str | os.PathLike | None, formulation: str | None
            ) -> tuple[Robot, Campaign | None, ModelFile | None, str]:
    """The robot (:func:`design_robot` unless given), the existing campaign and the model
    file read, and the formulation: given, else the existing campaign's baseline, else the
    model file's, else ``enhanced``."""
    if existing is not None and not isinstance(existing, Campaign):
        existing = load_campaign(existing)
    if model is not None and not isinstance(model, ModelFile):
        model = read_model_file(model)
    if not isinstance(robot, Robot):
        robot = design_robot(robot, model=model, existing=existing)
    if existing is not None:
        _check_existing_robot(robot, existing)
    if formulation is None:
        formulation = (existing.baseline if existing is not None else model.formulation
                       if model is not None and model.formulation in BASELINES else "enhanced")
    return robot, existing, model, formulation


def _check_existing_robot(robot: Robot, existing: Campaign) -> None:
    """Refuse to complete a campaign measured on another robot (other coordinates or
    kinematics: :func:`~stiffness.robot.calibration.kinematic_fingerprint`), whose rows the
    plan would take for this robot's, in one line naming both."""
    measured = existing.robot()
    if what := robot_difference(robot, measured):
        raise StiffnessError(
            f"the existing campaign {existing.name!r} was measured on "
            f"{robot_description(measured)}, not on {robot_description(robot)}: other {what}; "
            "drop --robot "
            f"(the campaign names its robot) or complete a campaign of {robot.title}")


def _check_request(robot: Robot, configs: int, max_force: float, loads_per_config: int,
                   candidates: int | Candidates, criterion: str, random_plans: int,
                   existing: Campaign | None, separate: str | tuple | None
                   ) -> tuple | None:
    """Refuse, in one line and before any work, what :func:`design` cannot do; returns the
    two ``(name, where)`` effects of ``separate`` (or ``None``)."""
    if criterion not in CRITERIA:
        raise UnknownNameError(f"unknown criterion {criterion!r}; valid: {', '.join(CRITERIA)}",
                               name=criterion, choices=CRITERIA)
    if robot.n_compliant == 0:
        raise StiffnessError(f"{robot.title} has no compliant joint: there is no stiffness to "
                             "design for; name the springs with --compliant-joints")
    for name, count in (("configs", configs), ("loads_per_config", loads_per_config),
                        ("random_plans", random_plans)) + (
            () if isinstance(candidates, Candidates) else (("candidates", candidates),)):
        whole_number(count, name)
    float_array(max_force, "max_force", "a force > 0 (N)", ndim=0, finite=False)
    check_sizes(configs, loads_per_config,
                candidates.n_poses if isinstance(candidates, Candidates) else candidates)
    if not (math.isfinite(max_force) and max_force > 0):
        raise StiffnessError(f"--max-force must be a positive force in N, got {max_force}")
    if int(random_plans) < 1:
        raise StiffnessError(f"--random-plans must be at least 1, got {random_plans}")
    if existing is not None and existing.robot().coordinate_joints != robot.coordinate_joints:
        raise StiffnessError(f"the existing campaign {existing.name!r} is of another robot "
                             f"({existing.robot().title}) than {robot.title}")
    if separate is not None and existing is not None and (
            existing.robot().target_frame != robot.target_frame
            or not np.allclose(existing.robot().target_offset, robot.target_offset)):
        raise StiffnessError("--separate designs for the existing campaign's target; drop "
                             "--frame and --target-offset")
    if separate is None:
        return None
    pair = parse_separate(separate) if isinstance(separate, str) else tuple(separate)
    if existing is None:
        raise StiffnessError("--separate needs --existing CAMPAIGN: the two alternatives are "
                             "fitted to its measurements")
    geo = Geometry.of(robot)
    for name, where in pair:
        make_effect(name, where, geo)  # unknown effect or place: one line, before any work
    return pair


def _nominal_stiffness(robot: Robot, k: np.ndarray | list[float] | None, given: str | None,
                       model: ModelFile | None, existing: Campaign | None
                       ) -> tuple[np.ndarray, str]:
    """The nominal stiffness (SI) per compliant joint and where it comes from (``given``
    unless None): ``k``, ``model``'s K_theta (same compliant joints), the robot's shipped
    ``k_theta_SI``, else the baseline fitted to ``existing``."""
    joints = tuple(robot.compliant_joints)
    if k is None and model is not None and tuple(model.compliant_joints) == joints:
        k, given = model.k_theta, given or f"the model file {model.path}"
    if k is not None:
        return joint_stiffnesses(robot, k, "k"), given or "given"
    if "k_theta_SI" in robot.defaults and len(robot.defaults["k_theta_SI"]) == len(joints):
        k_arr, k_source = np.asarray(robot.defaults["k_theta_SI"], dtype=float), \
            "the robot's shipped k_theta_SI"
    elif existing is not None:
        geo = Geometry.of(existing.robot())
        rows = geo.rows(existing.q, existing.force, existing.moment,
                        joint_angles=existing.robot_settings.joint_angles)
        model0 = Hypothesis(geo, rows, existing.baseline, joints,
                       (), References.of(geo, rows, 1e5, existing.deflection))
        scale = existing.noise_std_m or max(float(np.sqrt(np.mean(existing.deflection ** 2)))
                                            * 1e-2, 1e-12)
        k_arr = np.exp(fit_baseline(model0, existing.deflection, scale).x)
        k_source = f"the baseline fitted to the existing campaign {existing.name!r}"
    else:
        raise StiffnessError(f"--kq is required: the design is local to a nominal stiffness, one "
                             f"per compliant joint ({', '.join(joints)}), N.m/rad (N/m "
                             "prismatic)")
    return joint_stiffnesses(robot, k_arr, k_source), given or k_source


def _noise_level(noise_std_m: float | None, existing: Campaign | None) -> tuple[float, str]:
    """The noise std per deflection component (m) and where it comes from."""
    if noise_std_m is not None:
        sigma = float(float_array(noise_std_m, "noise_std_m", "a length > 0 (m)", ndim=0,
                                  finite=False))
        noise_source = "given"
    elif existing is not None and existing.noise_std_m is not None:
        sigma, noise_source = existing.noise_std_m, "declared noise_std of the existing campaign"
    else:
        sigma, noise_source = DEFAULT_NOISE_STD_M, "default"  # the value is printed beside it
    if not (math.isfinite(sigma) and sigma > 0):
        raise StiffnessError(f"the noise std must be a positive length, got {sigma}")
    return sigma, noise_source


@dataclass
class _Search:
    """The candidates' information (and, when separating, their separation statistics) and
    the selection of :func:`design`."""

    cands: Candidates
    info: np.ndarray
    prior: np.ndarray | None
    existing: Prediction | None
    alternatives: Alternatives | None = None
    sep: SeparationStatistics | None = None

    @classmethod
    def of(cls, cands: Candidates, joints: tuple[str, ...], k: np.ndarray, formulation: str,
           sigma: float, existing: Campaign | None) -> _Search:
        """The information of every candidate row (and of the existing rows) about ln k."""
        model, x = baseline_model(cands.geometry, cands.rows, joints, k, formulation)
        info = _info_of(cands, model, x, sigma)
        prior, existing_pred = None, None
        if existing is not None:
            ex_rows = cands.geometry.rows(existing.q, existing.force, existing.moment,
                                          joint_angles=existing.robot_settings.joint_angles)
            prior = row_information(sensitivities(model.replaced(rows=ex_rows), x),
                                    sigma).sum(axis=0)
            existing_pred = Prediction(standard_errors(prior))
        return cls(cands, info, prior, existing_pred)

    def separate(self, alternatives: Alternatives) -> None:
        """Select for the separation of two alternatives fitted to the existing campaign."""
        self.alternatives = alternatives
        self.sep = separation_statistics(alternatives, self.cands)
        assert self.existing is not None  # the alternatives were fitted to it
        self.existing.separation = float(np.sqrt(separation_score(self.sep.base)))

    def select(self, configs: int, loads_per_config: int, criterion: str) -> Selection:
        """The chosen poses and loads: the best separation, else the criterion."""
        if self.sep is not None:
            return select_rows(self.sep.rows, self.sep.base, separation_score, configs,
                               loads_per_config)
        return select_information(self.info, configs, loads_per_config, criterion, self.prior)

    def predict(self, sel: Selection) -> Prediction:
        """The predicted precision (and separation) of a selection with the existing rows."""
        total = self.info[sel.poses[:, None], sel.loads].sum(axis=(0, 1))
        if self.prior is not None:
            total = total + self.prior
        pred = Prediction(standard_errors(total))
        if self.sep is not None:
            acc = [b + r[sel.poses[:, None], sel.loads].sum(axis=(0, 1))
                   for b, r in zip(self.sep.base, self.sep.rows, strict=True)]
            pred.separation = float(np.sqrt(separation_score(acc)))
        return pred

    def row_separation(self, selection: Selection) -> np.ndarray:
        """(rows,) the predicted separation of each plan row, noise units (after
        :meth:`separate`)."""
        assert self.sep is not None  # called after separate()
        return self.sep.raw.reshape(-1)[selection.rows(self.cands.n_directions)]

    def notes(self, designed: Prediction, joints: tuple[str, ...]) -> list[str]:
        """Remarks on stiffnesses no candidate, or the plan, determines."""
        unseen = ~np.isfinite(standard_errors(self.info.sum(axis=(0, 1))))
        if unseen.any():
            return [f"no candidate row determines {', '.join(np.array(joints)[unseen])}: a "
                    "force at the target does not load it or its motion does not move the "
                    "target (e.g. a last joint whose axis passes through the target); its "
                    "standard error is infinite whatever the plan"]
        if not np.all(np.isfinite(designed.relative_se)):
            return ["the plan leaves some stiffness undetermined: add configurations or loads"]
        return []


def _plan(robot: Robot, cands: Candidates, selection: Selection, configs: int,
          loads_per_config: int, existing: Campaign | None, units: Units | None,
          formulation: str, sigma: float) -> Plan:
    """The selected rows as a plan (labels that do not clash with the existing campaign's,
    its units and robot settings when completing it)."""
    q = np.repeat(cands.coords[selection.poses], loads_per_config, axis=0)
    force = cands.directions[selection.loads.reshape(-1)] * cands.max_force
    taken = set(existing.config) if existing is not None else set()
    prefix = "P"
    while any(f"{prefix}{i + 1}" in taken for i in range(configs)):
        prefix += "P"
    labels = tuple(f"{prefix}{i // loads_per_config + 1}" for i in range(len(q)))
    if units is None:
        units = existing.units if existing is not None else Units()
    settings = (dataclasses.replace(  # its paths as from here (the plan rebases them)
        existing.robot_settings, source=existing.resolved_source(),
        loops=existing.robot_options()["loops"]) if existing is not None else RobotSettings(
        robot.name, frame=robot.target_frame, target_offset_m=robot.target_offset.copy(),
        compliant_joints=tuple(robot.compliant_joints)))
    return Plan(q=q, force=force, config=labels, units=units, robot_settings=settings,
                name=(f"{existing.name}-plan" if existing is not None else f"plan-{robot.title}"),
                baseline=existing.baseline if existing is not None else formulation,
                noise_std_m=sigma)
