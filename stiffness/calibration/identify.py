"""Joint-stiffness identification from a measurement campaign (Alici & Shirinzadeh, eq. 11-13).

The unknowns are the stiffnesses ``k`` of the campaign's compliant joints (N.m/rad for revolute
joints, N/m for prismatic ones). For each measurement row ``r`` (configuration ``q_r``, wrench
``W_r`` at the target, measured target displacement ``d_r``) the model predicts

* ``conventional``: ``J K^-1 J^T W`` (A&S eq. 8),
* ``enhanced``: ``J (K - K_C(W))^-1 J^T W`` (A&S eq. 10-11),
* ``exact``: the displacement of the exact elastostatic equilibrium
  (:func:`stiffness.mechanics.equilibrium.solve_equilibrium`; slower),

with ``J`` the translational target Jacobian w.r.t. the compliant joints. ``J`` and ``K_C``
are computed once per row (``K_C`` is linear in the row's own load). The residuals
``(predicted - measured) / s`` are stacked row by row (eq. 13) and their sum of squares
(eq. 12) is minimised by :func:`scipy.optimize.least_squares` (``trf`` and/or ``lm``) over
``ln k`` (positivity, and a scale-free parameterisation), from several starts: the paper's
``1e8 N.mm/rad`` and log-uniform random starts over ``1e2..1e8`` SI units; the best run is
kept and the result says whether all runs agree. Tiny pseudo-residuals
``PRIOR_WEIGHT (ln k - ln k_start)`` keep combinations the data do not see at their start
instead of letting them drift on round-off; they are left out of every reported quantity.

``s`` is the declared measurement noise ``noise_std`` if the campaign gives one (the residuals
are then whitened and ``sigma = noise_std``); otherwise ``s`` is a fixed scale and the noise
``sigma^2 = SS / (N - p)`` is estimated from the residual sum of squares ``SS`` of the ``N``
residuals and ``p`` stiffnesses. The covariance of ``ln k`` is ``sigma^2 (J_r^T J_r)^-1``
with ``J_r`` the residual Jacobian at the optimum; standard errors and 95 % confidence
intervals of ``k`` follow by the delta method on ``ln k``: ``SE(k) = k SE(ln k)`` and
``CI = k exp(+-t SE(ln k))`` (``t`` Student's with ``N - p`` degrees of freedom when sigma is
estimated, normal when declared), so the intervals are asymmetric and stay positive.

A stiffness the data cannot determine is one whose 95 % interval is wider than the value itself
(relative width > 1, infinite when the data do not excite it); a direction in ``ln k`` space is
undetermined when the same criterion fails along a right-singular vector of the whitened
residual Jacobian (singular value below ``t / asinh(1/2)``, or numerically zero).
"""

from __future__ import annotations

import copy
import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import norm
from scipy.stats import t as student_t

from stiffness.calibration.campaign import Campaign, _looks_like_path, _resolve_source
from stiffness.errors import (
    FileFormatError,
    SingularConfigurationError,
    StiffnessError,
    UnknownNameError,
    with_context,
)
from stiffness.files import atomic_write, output_folder, read_json
from stiffness.mechanics.equilibrium import solve_equilibrium
from stiffness.mechanics.formulation import target_state
from stiffness.model.robot import Robot, load_robot

FORMULATIONS = ("conventional", "enhanced", "exact")
METHODS = ("trf", "lm", "both")
#: The paper's initial guess, 1e8 N.mm/rad, in N.m/rad.
PAPER_START_SI = 1e5
#: Range (SI) of the log-uniform random starts.
RANDOM_START_RANGE_SI = (1e2, 1e8)
#: A stiffness is undetermined when its 95 % interval is wider than this times its value.
REL_CI_WIDTH_LIMIT = 1.0
#: Singular values below this fraction of the largest count as zero.
SINGULAR_RTOL = 1e-10
#: Two solutions agree when every determined ln k differs by less than this (0.1 %).
AGREEMENT_TOL_LOG = 1e-3
#: ``format`` tag of identified-model files.
MODEL_FORMAT = "stiffness-identified-model"
#: Default name of the identified-model file.
MODEL_FILE = "identified-model.json"

#: Weight of the pseudo-residuals ``w (ln k - ln k_start)`` added to the scaled residuals: they
#: keep directions the data do not see at their start (instead of drifting on round-off) and
#: move a determined ln k by about ``w^2 / s^2`` of its distance to the start (s >~ 1).
PRIOR_WEIGHT = 1e-6

_PENALTY = 1e6  # scaled residual returned where the model cannot be evaluated (buckling)
_MAX_LOG_K = 230.0  # |ln k| beyond this (k ~ 1e100) is treated as a failed evaluation


def _unit_of(robot: Robot, joint: str) -> str:
    kind = robot.model.joints[robot.model.getJointId(joint)].shortname()
    return "N/m" if kind.startswith("JointModelP") else "N.m/rad"


def _paper_unit(unit: str) -> tuple[str, float]:
    """The papers' unit for a stiffness unit and the factor from SI to it."""
    return ("N.mm/rad", 1e3) if unit == "N.m/rad" else ("N/mm", 1e-3)


# ----------------------------------------------------------------------------------------------
# the deflection model


class DeflectionModel:
    """Predicted target displacements of a campaign's rows as a function of the stiffnesses.

    Parameters
    ----------
    campaign
        The campaign (SI rows).
    formulation
        ``conventional``, ``enhanced`` or ``exact``.
    robot
        The campaign's robot (default :meth:`Campaign.robot`).
    """

    def __init__(self, campaign: Campaign, formulation: str, robot: Robot | None = None) -> None:
        if formulation not in FORMULATIONS:
            raise UnknownNameError(f"unknown formulation {formulation!r}; valid formulations: "
                                   f"{', '.join(FORMULATIONS)}", name=formulation,
                                   choices=FORMULATIONS)
        self.campaign = campaign
        self.formulation = formulation
        self.robot = robot if robot is not None else campaign.robot()
        self.wrench = campaign.wrench
        m, n = campaign.n_rows, self.robot.n_compliant
        configs: dict[tuple[float, ...], np.ndarray] = {}
        self.q0: list[np.ndarray] = []
        self.jac3 = np.empty((m, 3, n))
        self.tau = np.empty((m, n))
        self.k_c = np.zeros((m, n, n))
        for i in range(m):
            key = tuple(campaign.q[i])
            try:
                if key not in configs:
                    configs[key] = self.robot.configuration(campaign.q[i])
                state = target_state(self.robot, configs[key], self.wrench[i])
            except StiffnessError as exc:
                raise with_context(exc, campaign.describe_row(i)) from exc
            self.q0.append(configs[key])
            self.jac3[i] = state.jacobian[:3]
            self.tau[i] = state.jacobian.T @ state.wrench
            self.k_c[i] = state.k_c
        self.n_configurations = len(configs)
        sym = 0.5 * (self.k_c + np.transpose(self.k_c, (0, 2, 1)))
        #: Largest eigenvalue of K_C over the rows (SI); below it K - K_C may be singular.
        self.k_c_max = float(max(0.0, np.linalg.eigvalsh(sym).max())) if n else 0.0

    def with_formulation(self, formulation: str) -> DeflectionModel:
        """The same rows (Jacobians and K_C shared) under another formulation."""
        if formulation not in FORMULATIONS:
            raise UnknownNameError(f"unknown formulation {formulation!r}; valid formulations: "
                                   f"{', '.join(FORMULATIONS)}", name=formulation,
                                   choices=FORMULATIONS)
        other = copy.copy(self)
        other.formulation = formulation
        return other

    @property
    def n_parameters(self) -> int:
        """Number of identified stiffnesses."""
        return self.robot.n_compliant

    def predict(self, k: np.ndarray) -> np.ndarray:
        """(m, 3) predicted target displacements (m) for stiffnesses ``k`` (SI)."""
        return self.predict_with_jacobian(k, jacobian=False)[0]

    def predict_with_jacobian(self, k: np.ndarray, jacobian: bool = True
                              ) -> tuple[np.ndarray, np.ndarray | None]:
        """Predicted displacements (m, 3) and their derivatives (m, 3, p) w.r.t. ``ln k``.

        Raises
        ------
        StiffnessError
            If the model cannot be evaluated (singular tangent stiffness, or the exact
            equilibrium does not converge: the load buckles the robot at these stiffnesses).
        """
        k = np.asarray(k, dtype=float)
        if self.formulation == "exact":
            return self._exact(k, jacobian)
        a = np.broadcast_to(np.diag(k), self.k_c.shape).copy()
        if self.formulation == "enhanced":
            a -= self.k_c
        try:
            inv = np.linalg.inv(a)
        except np.linalg.LinAlgError as exc:
            raise SingularConfigurationError(
                "the tangent stiffness K - K_C is singular for some row: the load is at the "
                "buckling limit there; use the exact formulation or drop that row") from exc
        u = np.einsum("mij,mj->mi", inv, self.tau)
        pred = np.einsum("mij,mj->mi", self.jac3, u)
        if not jacobian:
            return pred, None
        mat = self.jac3 @ inv
        # d pred / d ln k_i = -J A^-1 e_i (A^-1 tau)_i k_i
        return pred, -mat * (u * k)[:, None, :]

    def _exact(self, k: np.ndarray, jacobian: bool) -> tuple[np.ndarray, np.ndarray | None]:
        kmat = np.diag(k)
        m, n = self.campaign.n_rows, len(k)
        pred = np.empty((m, 3))
        jac = np.empty((m, 3, n)) if jacobian else None
        for i in range(m):
            eq = solve_equilibrium(self.robot, self.q0[i], kmat, self.wrench[i])
            pred[i] = eq.dx
            if jacobian:
                # implicit function theorem on K (theta - theta0) = J(theta)^T W:
                # d theta / d k_i = -(K - K_C)^-1 e_i dtheta_i
                state = target_state(self.robot, eq.q, self.wrench[i])
                tangent = kmat - state.k_c
                dtheta = -np.linalg.solve(tangent, np.diag(eq.dtheta * k))
                jac[i] = state.jacobian[:3] @ dtheta
        return pred, jac


# ----------------------------------------------------------------------------------------------
# results


@dataclass
class StartResult:
    """One least-squares run.

    Attributes
    ----------
    start
        Initial stiffnesses (SI) actually used.
    method
        ``trf`` or ``lm``.
    k
        Final stiffnesses (SI).
    cost
        Final sum of squared scaled residuals.
    success, message, nfev
        From :func:`scipy.optimize.least_squares`.
    """

    start: np.ndarray
    method: str
    k: np.ndarray
    cost: float
    success: bool
    message: str
    nfev: int


@dataclass
class UndeterminedDirection:
    """A combination of ``ln k`` the data cannot determine.

    Attributes
    ----------
    components
        Joint name -> component of the unit direction in ``ln k`` space.
    joints
        Joints with a large component (>= 0.3).
    relative_ci_width
        95 % interval width along the direction, relative (inf if not excited at all).
    description
        E.g. ``+0.71 ln K_joint1 -0.71 ln K_joint2``.
    """

    components: dict[str, float]
    joints: tuple[str, ...]
    relative_ci_width: float
    description: str


@dataclass
class Identification:
    """Result of :func:`identify`; stiffnesses in SI (N.m/rad or N/m per joint).

    Attributes
    ----------
    campaign
        Campaign name.
    campaign_path
        Its ``campaign.toml`` (or ``None``).
    robot_source, robot_frame, target_offset_m
        The robot and its measurement target (offset in m, frame axes).
    joints
        Identified (compliant) joints.
    units
        Unit of each stiffness: ``N.m/rad`` or ``N/m``.
    formulation
        ``conventional``, ``enhanced`` or ``exact``.
    method
        ``trf``, ``lm`` or ``both``.
    k
        Identified stiffnesses (SI).
    standard_error
        Delta-method standard errors ``k SE(ln k)`` (SI; inf if undetermined).
    ci95_low, ci95_high
        95 % confidence bounds ``k exp(-+t SE(ln k))`` (SI).
    covariance_log
        (p, p) covariance of ``ln k``.
    sigma_m
        Noise standard deviation used for the covariance (m).
    sigma_source
        ``declared noise_std`` or ``residuals (SS / (N - p))``.
    sigma_residual_m
        Estimate ``sqrt(SS / (N - p))`` from the residuals (m), or ``None`` when N <= p.
    residual_ss_m2
        Eq. 12: sum of squared residuals (m^2).
    n_residuals, n_parameters, n_rows, n_configurations
        Sizes of the problem.
    condition_number
        Condition number of the residual Jacobian w.r.t. ``ln k`` (scale-free).
    singular_values
        Singular values of the whitened residual Jacobian w.r.t. ``ln k``.
    relative_ci_width
        Per joint, ``(high - low) / k``.
    undetermined_joints
        Joints whose relative CI width exceeds :data:`REL_CI_WIDTH_LIMIT`.
    undetermined_directions
        Undetermined directions in ``ln k`` space.
    starts
        Every least-squares run.
    starts_agree
        Whether every run reached the best cost and the same determined stiffnesses.
    methods_agree
        With ``method="both"``: whether the best trf and lm solutions agree; else ``None``.
    predicted, residuals
        (m, 3) predicted displacements and ``predicted - measured`` at the optimum (m).
    k_c_floor
        Starts below this (SI) were raised to it: 2x the largest eigenvalue of K_C over the
        rows, under which K - K_C can be singular (0 for the conventional formulation).
    notes
        Warnings (e.g. declared noise inconsistent with the residuals).
    """

    campaign: str
    campaign_path: str | None
    robot_source: str
    robot_frame: str
    target_offset_m: np.ndarray
    joints: tuple[str, ...]
    units: tuple[str, ...]
    formulation: str
    method: str
    k: np.ndarray
    standard_error: np.ndarray
    ci95_low: np.ndarray
    ci95_high: np.ndarray
    covariance_log: np.ndarray
    sigma_m: float
    sigma_source: str
    sigma_residual_m: float | None
    residual_ss_m2: float
    n_residuals: int
    n_parameters: int
    n_rows: int
    n_configurations: int
    condition_number: float
    singular_values: np.ndarray
    relative_ci_width: np.ndarray
    undetermined_joints: tuple[str, ...]
    undetermined_directions: list[UndeterminedDirection]
    starts: list[StartResult]
    starts_agree: bool
    methods_agree: bool | None
    predicted: np.ndarray
    residuals: np.ndarray
    k_c_floor: float = 0.0
    notes: list[str] = field(default_factory=list)

    @property
    def residual_ss_mm2(self) -> float:
        """Eq. 12 in the paper's unit (mm^2)."""
        return self.residual_ss_m2 * 1e6

    @property
    def rms_residual_m(self) -> float:
        """Root mean square residual component (m)."""
        return math.sqrt(self.residual_ss_m2 / self.n_residuals)

    @property
    def k_paper_units(self) -> np.ndarray:
        """Stiffnesses in the paper's units (N.mm/rad or N/mm)."""
        return np.array([v * _paper_unit(u)[1] for v, u in zip(self.k, self.units, strict=True)])

    def to_dict(self) -> dict:
        """JSON-ready dictionary (SI; eq. 12 also in mm^2; inf and NaN become null)."""
        return _jsonable({
            "campaign": self.campaign,
            "campaign_path": self.campaign_path,
            "robot": {"source": self.robot_source, "frame": self.robot_frame,
                      "target_offset_m": self.target_offset_m,
                      "compliant_joints": list(self.joints)},
            "formulation": self.formulation,
            "method": self.method,
            "joints": [
                {"joint": j, "k": float(k), "unit": u, "k_paper_units": float(kp),
                 "paper_unit": _paper_unit(u)[0], "standard_error": float(se),
                 "ci95": [float(lo), float(hi)], "relative_ci_width": float(w),
                 "determined": j not in self.undetermined_joints}
                for j, k, u, kp, se, lo, hi, w in zip(
                    self.joints, self.k, self.units, self.k_paper_units, self.standard_error,
                    self.ci95_low, self.ci95_high, self.relative_ci_width, strict=True)
            ],
            "ci95_method": "delta method on ln k: k exp(+-t SE(ln k)); t = Student "
                           "(N - p dof) if sigma is estimated, normal if declared",
            "covariance_log": self.covariance_log,
            "sigma_m": self.sigma_m,
            "sigma_source": self.sigma_source,
            "sigma_residual_m": self.sigma_residual_m,
            "residual_norm": {"eq12_m2": self.residual_ss_m2, "eq12_mm2": self.residual_ss_mm2,
                              "rms_m": self.rms_residual_m},
            "n_residuals": self.n_residuals,
            "n_parameters": self.n_parameters,
            "n_rows": self.n_rows,
            "n_configurations": self.n_configurations,
            "condition_number": self.condition_number,
            "singular_values": self.singular_values,
            "undetermined_joints": list(self.undetermined_joints),
            "undetermined_directions": [
                {"components": d.components, "joints": list(d.joints),
                 "relative_ci_width": d.relative_ci_width, "description": d.description}
                for d in self.undetermined_directions
            ],
            "starts_agree": self.starts_agree,
            "methods_agree": self.methods_agree,
            "k_c_floor": self.k_c_floor,
            "starts": [
                {"method": s.method, "start": s.start, "k": s.k, "cost": s.cost,
                 "success": s.success, "nfev": s.nfev, "message": s.message}
                for s in self.starts
            ],
            "residuals_m": self.residuals,
            "notes": list(self.notes),
        })

    def to_json(self, indent: int | None = 1) -> str:
        """The result as JSON text (see :meth:`to_dict`)."""
        return json.dumps(self.to_dict(), indent=indent, allow_nan=False)

    def model_dict(self, relative_to: str | os.PathLike | None = None) -> dict:
        """The identified model as written by :meth:`write_model`.

        Parameters
        ----------
        relative_to
            Folder a URDF source path is written relative to (the model file's folder).
        """
        source = self.robot_source
        if relative_to is not None and _looks_like_path(source):
            try:
                source = os.path.relpath(Path(source).resolve(), Path(relative_to).resolve())
            except ValueError:  # another drive on Windows
                source = str(Path(source).resolve())
            source = Path(source).as_posix()
        return _jsonable({
            "format": MODEL_FORMAT,
            "version": 1,
            "campaign": self.campaign,
            "robot": {"source": source, "frame": self.robot_frame,
                      "target_offset_m": self.target_offset_m,
                      "compliant_joints": list(self.joints)},
            "formulation": self.formulation,
            "k_theta": {"joints": list(self.joints), "values": self.k, "unit": list(self.units)},
            "standard_error": self.standard_error,
            "ci95": {"low": self.ci95_low, "high": self.ci95_high,
                     "method": "delta method on ln k"},
            "undetermined_joints": list(self.undetermined_joints),
            "residual_norm": {"eq12_m2": self.residual_ss_m2,
                              "eq12_mm2": self.residual_ss_mm2},
        })

    def write_model(self, path: str | os.PathLike) -> Path:
        """Write the identified model (``identified-model.json``) atomically; returns its path.

        A URDF source is stored relative to the file's folder; read it back with
        :func:`load_identified_model`.
        """
        path = Path(path)
        output_folder(path.parent)
        text = json.dumps(self.model_dict(path.parent), indent=1, allow_nan=False)
        atomic_write(path, text + "\n")
        return path


def _jsonable(value):
    """Arrays to lists, non-finite floats to None, recursively."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, np.bool_ | bool):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    return value


# ----------------------------------------------------------------------------------------------
# identified models


@dataclass
class IdentifiedModel:
    """An identified model read from ``identified-model.json``.

    Attributes
    ----------
    source, frame, target_offset_m, compliant_joints
        Robot settings (source resolved against the file's folder; offset in m).
    k_theta
        Stiffness per compliant joint (SI), in ``compliant_joints`` order.
    units
        ``N.m/rad`` or ``N/m`` per joint.
    formulation
        Formulation the stiffnesses were identified with.
    ci95_low, ci95_high, standard_error
        Uncertainty (SI; NaN where not determined).
    campaign
        Campaign name.
    path
        The file read.
    """

    source: str
    frame: str
    target_offset_m: np.ndarray
    compliant_joints: tuple[str, ...]
    k_theta: np.ndarray
    units: tuple[str, ...]
    formulation: str
    ci95_low: np.ndarray
    ci95_high: np.ndarray
    standard_error: np.ndarray
    campaign: str
    path: Path

    def robot(self) -> Robot:
        """Load the model's robot (:func:`stiffness.model.robot.load_robot`)."""
        return load_robot(self.source, frame=self.frame, target_offset=self.target_offset_m,
                          compliant_joints=self.compliant_joints)

    def k_theta_matrix(self) -> np.ndarray:
        """Diagonal joint stiffness matrix (SI)."""
        return np.diag(self.k_theta)


def load_identified_model(path: str | os.PathLike) -> IdentifiedModel:
    """Read an ``identified-model.json`` written by :meth:`Identification.write_model`.

    Raises
    ------
    MissingFileError
        Missing or unreadable file.
    FileFormatError
        Not JSON (with its line and column), wrong ``format``, or a missing or malformed key
        (the message names the key).
    """
    path = Path(path)
    doc = read_json(path, f"identified model ({MODEL_FILE} of `stiffness identify`)")
    if not isinstance(doc, dict) or doc.get("format") != MODEL_FORMAT:
        raise FileFormatError(f"the file is not an identified model (its format is not "
                              f"{MODEL_FORMAT!r}); "
                              "give the file written by `stiffness identify`", path=path)

    def get(*keys):
        node = doc
        for key in keys:
            if not isinstance(node, dict) or key not in node:
                raise FileFormatError(f"missing key {'.'.join(keys)}; rewrite the file with "
                                      "`stiffness identify`", path=path)
            node = node[key]
        return node

    def numbers(value, name: str, count: int, allow_null: bool = False) -> np.ndarray:
        ok = isinstance(value, list) and len(value) == count and all(
            (v is None and allow_null) or (isinstance(v, int | float) and not isinstance(v, bool))
            for v in value)
        if not ok:
            raise FileFormatError(f"{name} must be a list of {count} numbers, got {value!r}",
                                  path=path)
        return np.array([np.nan if v is None else v for v in value], dtype=float)

    joints = get("robot", "compliant_joints")
    if not isinstance(joints, list) or not joints or not all(isinstance(j, str) for j in joints):
        raise FileFormatError("robot.compliant_joints must be a list of joint names", path=path)
    n = len(joints)
    if get("k_theta", "joints") != joints:
        raise FileFormatError("k_theta.joints must equal robot.compliant_joints", path=path)
    k = numbers(get("k_theta", "values"), "k_theta.values", n)
    if not np.all(np.isfinite(k)) or np.any(k <= 0):
        raise FileFormatError(f"k_theta.values must be positive, got {k.tolist()}", path=path)
    units = get("k_theta", "unit")
    if not isinstance(units, list) or len(units) != n or not set(units) <= {"N.m/rad", "N/m"}:
        raise FileFormatError("k_theta.unit must list N.m/rad or N/m per joint", path=path)
    formulation = get("formulation")
    if formulation not in FORMULATIONS:
        raise FileFormatError(f"formulation must be one of {', '.join(FORMULATIONS)}", path=path)
    source, frame = get("robot", "source"), get("robot", "frame")
    if not isinstance(source, str) or not isinstance(frame, str):
        raise FileFormatError("robot.source and robot.frame must be strings", path=path)
    return IdentifiedModel(
        source=_resolve_source(source, path.parent),
        frame=frame,
        target_offset_m=numbers(get("robot", "target_offset_m"), "robot.target_offset_m", 3),
        compliant_joints=tuple(joints),
        k_theta=k,
        units=tuple(units),
        formulation=formulation,
        ci95_low=numbers(get("ci95", "low"), "ci95.low", n, allow_null=True),
        ci95_high=numbers(get("ci95", "high"), "ci95.high", n, allow_null=True),
        standard_error=numbers(get("standard_error"), "standard_error", n, allow_null=True),
        campaign=str(doc.get("campaign", "")),
        path=path,
    )


# ----------------------------------------------------------------------------------------------
# identification


def _starts(n: int, count: int, seed: int | None) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    lo, hi = np.log10(RANDOM_START_RANGE_SI)
    starts = [np.full(n, PAPER_START_SI)]
    starts += [10.0 ** rng.uniform(lo, hi, n) for _ in range(count - 1)]
    return starts


def _agree(a: np.ndarray, b: np.ndarray, determined: np.ndarray) -> bool:
    diff = np.abs(np.log(a) - np.log(b))[determined]
    return bool(np.all(diff < AGREEMENT_TOL_LOG))


class _Objective:
    """Scaled residuals ``(predicted - measured) / scale`` over ``x = ln k`` and their Jacobian.

    With ``x_start``, the pseudo-residuals ``PRIOR_WEIGHT (x - x_start)`` are appended.
    """

    def __init__(self, model: DeflectionModel, measured: np.ndarray, scale: float,
                 x_start: np.ndarray | None = None) -> None:
        self.model, self.measured, self.scale, self.x_start = model, measured, scale, x_start
        self.n_res, self.p = measured.size, model.n_parameters
        self._key: bytes | None = None
        self._pred: np.ndarray | None = None
        self._jac: np.ndarray | None = None

    def anchored(self, x_start: np.ndarray) -> _Objective:
        """The same objective pulled weakly towards ``x_start``."""
        return _Objective(self.model, self.measured, self.scale, x_start)

    def _evaluate(self, x: np.ndarray) -> None:
        key = x.tobytes()
        if key == self._key:
            return
        pred = jac = None
        if np.all(np.abs(x) < _MAX_LOG_K):
            try:
                with np.errstate(all="ignore"):
                    pred, jac = self.model.predict_with_jacobian(np.exp(x))
                if not (np.all(np.isfinite(pred)) and np.all(np.isfinite(jac))):
                    pred = jac = None
            except (StiffnessError, np.linalg.LinAlgError):
                pred = jac = None
        self._key, self._pred, self._jac = key, pred, jac

    def data(self, x: np.ndarray) -> np.ndarray:
        """Scaled data residuals (N,), or a large constant where the model fails."""
        self._evaluate(x)
        if self._pred is None:
            return np.full(self.n_res, _PENALTY)
        return ((self._pred - self.measured) / self.scale).reshape(-1)

    def data_jacobian(self, x: np.ndarray) -> np.ndarray:
        """(N, p) derivative of the scaled data residuals w.r.t. ``ln k``."""
        self._evaluate(x)
        if self._jac is None:
            return np.zeros((self.n_res, self.p))
        return (self._jac / self.scale).reshape(self.n_res, self.p)

    def fun(self, x: np.ndarray) -> np.ndarray:
        """Residuals handed to the solver."""
        r = self.data(x)
        if self.x_start is None:
            return r
        return np.concatenate([r, PRIOR_WEIGHT * (x - self.x_start)])

    def jac(self, x: np.ndarray) -> np.ndarray:
        """Their Jacobian."""
        j = self.data_jacobian(x)
        if self.x_start is None:
            return j
        return np.vstack([j, PRIOR_WEIGHT * np.eye(self.p)])


@dataclass
class _Uncertainty:
    covariance_log: np.ndarray
    se_log: np.ndarray
    low: np.ndarray
    high: np.ndarray
    width: np.ndarray
    singular_values: np.ndarray
    condition_number: float
    directions: list[UndeterminedDirection]


def _uncertainty(jac_white: np.ndarray, k: np.ndarray, quantile: float,
                 joints: tuple[str, ...]) -> _Uncertainty:
    """Covariance, CIs and undetermined directions from the whitened Jacobian w.r.t. ln k."""
    p = len(k)
    _, sv, vt = np.linalg.svd(jac_white, full_matrices=True)
    s_full = np.zeros(p)
    s_full[: len(sv)] = sv
    smax = float(s_full.max()) if p else 0.0
    zero = s_full <= SINGULAR_RTOL * smax if smax > 0 else np.ones(p, dtype=bool)
    inv_s2 = np.where(zero, 0.0, 1.0 / np.where(zero, 1.0, s_full) ** 2)
    cov = (vt.T * inv_s2) @ vt
    var = np.diag(cov).copy()
    # a parameter with a component along a direction the data do not see at all
    unexcited = (np.abs(vt[zero]) > 1e-8).any(axis=0) if zero.any() else np.zeros(p, bool)
    var[unexcited] = np.inf
    cov[unexcited, :] = np.inf
    cov[:, unexcited] = np.inf
    se_log = np.sqrt(var)
    with np.errstate(over="ignore", invalid="ignore"):
        low = k * np.exp(-quantile * se_log)
        high = k * np.exp(quantile * se_log)
        width = (high - low) / k
    width = np.where(np.isfinite(width), width, np.inf)

    directions = []
    for s_j, v in zip(s_full, vt, strict=True):
        dir_width = math.inf
        if smax > 0 and s_j > SINGULAR_RTOL * smax and quantile / s_j < 700.0:
            dir_width = 2.0 * math.sinh(quantile / s_j)
        if dir_width <= REL_CI_WIDTH_LIMIT:
            continue
        v = v * (1.0 if v[np.argmax(np.abs(v))] > 0 else -1.0)
        comps = {j: float(c) for j, c in zip(joints, v, strict=True)}
        big = tuple(j for j, c in comps.items() if abs(c) >= 0.3)
        text = " ".join(f"{c:+.2f} ln K_{j}" for j, c in comps.items() if abs(c) >= 0.05)
        directions.append(UndeterminedDirection(comps, big, dir_width, text))
    cond = math.inf if zero.any() else smax / float(s_full.min())
    return _Uncertainty(cov, se_log, low, high, width, s_full, cond, directions)


def identify(
    campaign: Campaign,
    formulation: str | None = None,
    method: str = "trf",
    starts: int = 8,
    seed: int | None = 0,
    robot: Robot | None = None,
    progress: Callable[[int, int, str], None] | None = None,
) -> Identification:
    """Identify the compliant joints' stiffnesses from a campaign (A&S eq. 11-13).

    Parameters
    ----------
    campaign
        The measurements (SI).
    formulation
        ``conventional``, ``enhanced`` or ``exact``; default the campaign's baseline.
    method
        ``trf``, ``lm`` (Levenberg-Marquardt) or ``both`` (each start solved by both).
    starts
        Number of starts: the paper's ``1e8 N.mm/rad`` (1e5 SI) for every joint, then
        ``starts - 1`` log-uniform random starts over ``1e2..1e8`` SI. For the enhanced and
        exact formulations, start values below twice the largest eigenvalue of ``K_C`` over the
        rows are raised to it (below, ``K - K_C`` can be singular and the prediction has poles
        the solver cannot cross). The exact formulation first converges each start with the
        enhanced one, then refines with the exact equilibrium.
    seed
        Seed of the random starts.
    robot
        The campaign's robot (default :meth:`Campaign.robot`).
    progress
        Called as ``progress(done, total, text)`` after each least-squares run.

    Returns
    -------
    Identification
        Best solution over all starts and methods, with its uncertainty.

    Raises
    ------
    StiffnessError
        Unknown formulation or method, fewer than one start, too few residuals (``lm`` needs
        at least as many residuals as stiffnesses; without a declared noise, sigma needs more
        residuals than stiffnesses), or a row whose configuration cannot be assembled.
    """
    formulation = campaign.baseline if formulation is None else formulation
    if formulation not in FORMULATIONS:
        raise UnknownNameError(f"unknown formulation {formulation!r}; valid formulations: "
                               f"{', '.join(FORMULATIONS)}", name=formulation,
                               choices=FORMULATIONS)
    if method not in METHODS:
        raise UnknownNameError(f"unknown method {method!r}; valid methods: {', '.join(METHODS)}",
                               name=method, choices=METHODS)
    if int(starts) < 1:
        raise StiffnessError(f"starts must be at least 1, got {starts}")
    model = DeflectionModel(campaign, formulation, robot)
    rob = model.robot
    p = model.n_parameters
    n_res = 3 * campaign.n_rows
    declared = campaign.noise_std_m is not None
    if method in ("lm", "both") and n_res < p:
        raise StiffnessError(
            f"method lm needs at least as many residuals as stiffnesses ({n_res} < {p}); add "
            "measurement rows or use --method trf"
        )
    if not declared and n_res <= p:
        raise StiffnessError(
            f"{n_res} residuals cannot estimate the noise of {p} stiffnesses; add measurement "
            "rows or declare [measurement] noise_std"
        )
    measured = campaign.deflection
    if declared:
        scale = campaign.noise_std_m
    else:  # any fixed scale: sigma is estimated from the residuals
        rms = float(np.sqrt(np.mean(measured ** 2)))
        scale = rms if rms > 0 else 1e-3

    objective = _Objective(model, measured, scale)
    pre = None
    if formulation == "exact":
        pre = _Objective(model.with_formulation("enhanced"), measured, scale)
    floor = 0.0 if formulation == "conventional" else 2.0 * model.k_c_max
    methods = ("trf", "lm") if method == "both" else (method,)
    runs: list[StartResult] = []
    total = int(starts) * len(methods)
    options = {"xtol": 1e-12, "ftol": 1e-12, "gtol": 1e-12, "max_nfev": 200 * (p + 1)}
    for k0 in _starts(p, int(starts), seed):
        k0 = np.maximum(k0, floor)
        x_start = np.log(k0)
        for meth in methods:
            x0 = x_start
            if pre is not None:
                obj = pre.anchored(x_start)
                x0 = least_squares(obj.fun, x0, jac=obj.jac, method=meth, **options).x
            obj = objective.anchored(x_start)
            sol = least_squares(obj.fun, x0, jac=obj.jac, method=meth, **options)
            data = obj.data(sol.x)
            runs.append(StartResult(start=k0.copy(), method=meth, k=np.exp(sol.x),
                                    cost=float(data @ data), success=bool(sol.success),
                                    message=str(sol.message), nfev=int(sol.nfev)))
            if progress is not None:
                progress(len(runs), total, f"{meth} from {np.array2string(k0, precision=3)}: "
                                           f"cost {runs[-1].cost:.6g}")
    best = min(runs, key=lambda r: r.cost)
    x = np.log(best.k)
    pred = model.predict(best.k)
    ss_m2 = float(np.sum((pred - measured) ** 2))
    dof = n_res - p
    sigma_res = math.sqrt(ss_m2 / dof) if dof > 0 else None
    notes: list[str] = []
    if declared:
        sigma = campaign.noise_std_m
        sigma_source = "declared noise_std"
        quantile = float(norm.ppf(0.975))
        if sigma_res is not None and sigma_res > 2.0 * sigma:
            notes.append(
                f"the residuals (sigma {sigma_res * 1e3:.4g} mm) are much larger than the "
                f"declared noise_std ({sigma * 1e3:.4g} mm): model error or underestimated noise; "
                "the confidence intervals are too narrow"
            )
    else:
        sigma = sigma_res
        sigma_source = "residuals (SS / (N - p))"
        quantile = float(student_t.ppf(0.975, dof))
    unc = _uncertainty(objective.data_jacobian(x) * (scale / sigma), best.k, quantile,
                       rob.compliant_joints)
    undetermined = tuple(j for j, w in zip(rob.compliant_joints, unc.width, strict=True)
                         if not w <= REL_CI_WIDTH_LIMIT)
    determined = np.array([j not in undetermined for j in rob.compliant_joints])

    tol_cost = 1e-6 * best.cost + 1e-20
    at_best = [run.cost <= best.cost + tol_cost for run in runs]
    starts_agree = all(ok and _agree(run.k, best.k, determined)
                       for ok, run in zip(at_best, runs, strict=True))
    if not all(at_best):
        notes.append(
            f"{at_best.count(False)} of {len(runs)} runs ended at a higher cost (a local minimum, "
            "or stalled on a plateau where a stiffness is so high its joint no longer "
            "contributes); the best run is kept"
        )
    elif not starts_agree:
        notes.append("runs reach the same cost with different determined stiffnesses")
    methods_agree = None
    if method == "both":
        best_of = {mm: min((r for r in runs if r.method == mm), key=lambda r: r.cost)
                   for mm in methods}
        methods_agree = _agree(best_of["trf"].k, best_of["lm"].k, determined) and abs(
            best_of["trf"].cost - best_of["lm"].cost) <= tol_cost
    return Identification(
        campaign=campaign.name,
        campaign_path=str(campaign.path) if campaign.path is not None else None,
        robot_source=campaign.resolved_source(),
        robot_frame=rob.target_frame,
        target_offset_m=rob.target_offset.copy(),
        joints=tuple(rob.compliant_joints),
        units=tuple(_unit_of(rob, j) for j in rob.compliant_joints),
        formulation=formulation,
        method=method,
        k=best.k,
        standard_error=best.k * unc.se_log,
        ci95_low=unc.low,
        ci95_high=unc.high,
        covariance_log=unc.covariance_log,
        sigma_m=float(sigma),
        sigma_source=sigma_source,
        sigma_residual_m=sigma_res,
        residual_ss_m2=ss_m2,
        n_residuals=n_res,
        n_parameters=p,
        n_rows=campaign.n_rows,
        n_configurations=model.n_configurations,
        condition_number=unc.condition_number,
        singular_values=unc.singular_values,
        relative_ci_width=unc.width,
        undetermined_joints=undetermined,
        undetermined_directions=unc.directions,
        starts=runs,
        starts_agree=bool(starts_agree),
        methods_agree=methods_agree,
        predicted=pred,
        residuals=pred - measured,
        k_c_floor=floor,
        notes=notes,
    )
