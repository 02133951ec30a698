"""The result of :func:`stiffness.calibration.identify.identify` on a deflection campaign: the
identified stiffnesses with their uncertainty, every least-squares run, what the data cannot
determine (:class:`Identification`, an :class:`~stiffness.calibration.result.
IdentificationResult` as a pose campaign's: its ``--json`` object and the identified-model file).

Stiffnesses in SI (N.m/rad, N/m); the papers' N.mm/rad beside them.
"""


from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stiffness.calibration.outliers import Outlier, outlier_keys
from stiffness.calibration.result import IdentificationResult
from stiffness.calibration.selection import Noise
from stiffness.elastic.model_contents import ModelFile
from stiffness.elastic.parameter_covariance import ParameterCovariance, stiffness_labels
from stiffness.files import jsonable
from stiffness.robot.robot import Robot


def stiffness_unit(robot: Robot, joint: str) -> str:
    """The SI unit of a joint's stiffness: ``N/m`` (prismatic) or ``N.m/rad``."""
    return "N/m" if robot.is_prismatic(joint) else "N.m/rad"


def _paper_unit(unit: str) -> tuple[str, float]:
    """The papers' unit for a stiffness unit and the factor from SI to it."""
    return ("N.mm/rad", 1e3) if unit == "N.m/rad" else ("N/mm", 1e-3)


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
class Identification(IdentificationResult):
    """Result of :func:`~stiffness.calibration.identify.identify` on a deflection campaign;
    stiffnesses in SI (N.m/rad or N/m per joint); ``model_path`` and :meth:`write_model` as
    :class:`~stiffness.calibration.result.IdentificationResult` has them.

    Attributes
    ----------
    campaign
        Campaign name.
    campaign_path
        Its ``campaign.toml`` (or ``None``).
    robot_source, robot_frame, target_offset_m
        The robot and its measurement target (offset in m, frame axes).
    robot_loops, robot_fixed_base
        The robot's loop declaration (absolute path) and whether its base was fixed.
    robot_name
        The robot's name for the user (:attr:`stiffness.robot.robot.Robot.title`).
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
        95 % confidence bounds, the compliance's ``c -+ t SE(c)`` (``SE(c) = c SE(ln k)``)
        carried to ``k = 1 / c``: ``k / (1 + t SE(ln k))``, ``k / (1 - t SE(ln k))`` (inf
        when the compliance's interval reaches zero) (SI).
    covariance_log
        (p, p) covariance of ``ln k``.
    noise
        Noise standard deviation used for the covariance (m, :attr:`sigma_m`) and whether it
        is declared or estimated (:class:`~stiffness.calibration.selection.Noise`).
    sigma_source
        ``declared noise_std``, ``residuals (SS / (N - p))`` or (a robust loss) ``robust
        estimate (1.4826 median |residual|)``.
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
        Joints the data do not determine, by diagnose's rule
        (:attr:`~stiffness.elastic.effects.base.Parameter.determined`: fitted, with a finite
        95 % interval whose compliance's width is narrower than its physical scale).
    undetermined_directions
        Undetermined directions in ``ln k`` space.
    held
        Per joint, why the fit held its stiffness at the start instead of fitting it (the
        identifiability's clause: ``no effect on the data``, ``merged: ...``), or ``None``:
        fitted. Empty: every joint fitted.
    at_bound
        Per joint, whether it is rigid to the data (its compliance fitted within
        :data:`~stiffness.calibration.fitting.RIGID_COMPLIANCE` typical sizes of its bound's,
        :func:`~stiffness.calibration.fitting.rigid_joints`): its
        interval is then one-sided, ``[ci95_low, inf]``, and it has no standard error. Empty:
        none.
    kinematics_bias_se
        The enhanced formulation's first-order kinematics' bias of each stiffness, in its
        standard errors (:func:`~stiffness.calibration.identify.kinematics_bias`; NaN for a
        held one), ``None`` for the other formulations; JSON ``kinematics_bias_se``.
    ci95_dof
        Per joint, the degrees of freedom of its interval's Student t quantile
        (:func:`~stiffness.calibration.deflection_noise.interval_quantiles`), ``None`` for the
        normal's (a declared noise); JSON ``ci95_dof`` in each joint's entry. Empty: not given.
    physical_scale
        Per joint, its 95 % interval against its physical scale in words (diagnose's
        ``physical_scale``; empty: not judged), JSON ``joints[].physical_scale``.
    conditional_on
        Per joint, the springs rigid to the data (at their bound) its estimate and interval
        are conditional on (held there; those that move an end of its interval materially,
        :func:`~stiffness.calibration.selection.material_holders`), JSON
        ``joints[].conditional_on``; empty: none. With
        no residual freedom (residual components no more than fitted stiffnesses) such a
        joint is undetermined, as diagnose refuses that campaign (docs/diagnose.md).
    fits_to_noise
        The test of fitting to a known noise (declared, or the replicates'), JSON
        ``fits_to_noise``: its ``p_value``, ``level``, ``test`` and ``final_rows_excluded``
        (the rows flagged as outliers a robust loss's test leaves out, 0 under least squares;
        :func:`~stiffness.calibration.selection.noise_terms`); ``None`` when the noise is
        estimated from the residuals.
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
    rotation_residuals
        (m, 3) rotation residuals (rad) when the campaign measures rotations, else ``None``;
        ``predicted`` and ``residuals`` are then the translations and ``residual_ss_m2`` sums
        both kinds in translation-noise units (rotations weighted by
        ``rotation_weight_m_per_rad = sigma_t / sigma_r``).
    rotation_sigma_rad, rotation_sigma_source
        The rotation noise std (rad) and where it comes from (``declared
        rotation_noise_std``, ``replicates`` or ``residuals``).
    loss
        The fit's loss (:data:`stiffness.calibration.solver.LOSSES`).
    outliers
        Rows whose standardised residual exceeds :data:`OUTLIER_THRESHOLD`
        (:mod:`stiffness.calibration.outliers`), flagged and kept.
    outlier_sigma_m
        The noise std the residuals are standardised by (m).
    stiffness_coordinates
        The coordinates the stiffnesses refer to: ``"controller"`` (the springs act on the
        controller's coordinates of a ``[controller]`` robot file) or ``"chain"`` (the
        kinematic chain's joints).
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
    noise: Noise
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
    rotation_residuals: np.ndarray | None = None
    rotation_sigma_rad: float | None = None
    rotation_sigma_source: str | None = None
    rotation_weight_m_per_rad: float | None = None
    robot_loops: str | None = None
    robot_fixed_base: bool = False
    loss: str = "linear"
    robot_name: str = ""
    outliers: list[Outlier] = field(default_factory=list)
    outlier_sigma_m: float | None = None
    stiffness_coordinates: str = "chain"
    held: tuple[str | None, ...] = ()
    at_bound: tuple[bool, ...] = ()
    kinematics_bias_se: np.ndarray | None = None
    ci95_dof: tuple[float | None, ...] = ()
    physical_scale: tuple[str, ...] = ()
    fits_to_noise: dict | None = None
    conditional_on: tuple[tuple[str, ...], ...] = ()

    @property
    def sigma_m(self) -> float:
        """Noise standard deviation used for the covariance (m)."""
        return float(self.noise.sigma)

    @property
    def held_joints(self) -> tuple[str | None, ...]:
        """:attr:`held`, one entry per joint (``None`` for each when every joint was fitted)."""
        return self.held or (None,) * len(self.joints)

    @property
    def ci95_method(self) -> str:
        """How the 95 % intervals are computed."""
        if self.loss == "linear":
            return ("the compliance's interval c -+ t SE(c), SE(c) = c SE(ln k), carried to "
                    "k = 1/c: k / (1 +- t SE(ln k)); t = Student with the replicates' dof "
                    "for their scatter, N - p dof for the residuals', normal if declared; with "
                    "rotations, per joint the Welch-Satterthwaite dof of the two kinds' "
                    "(ci95_dof)")
        return (f"Huber's sandwich covariance of the {self.loss} fit's ln k; the compliance's "
                "interval carried to k = 1/c: k / (1 +- t SE(ln k)), t = Student (N - p dof)")

    @property
    def rms_by_kind(self) -> dict[str, float | None]:
        """RMS residual component of the translations (m) and of the rotations (rad, ``None``
        without measured rotations)."""
        rot = self.rotation_residuals
        return {"translation_m": float(np.sqrt(np.mean(self.residuals ** 2))),
                "rotation_rad": None if rot is None else float(np.sqrt(np.mean(rot ** 2)))}

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
        """JSON-ready dictionary (SI; eq. 12 also in mm^2; inf and NaN become null): the
        object ``stiffness identify --json`` prints (``model_file``: the file
        :meth:`write_model` wrote, ``None`` before)."""
        return jsonable({
            "campaign": self.campaign,
            "campaign_path": self.campaign_path,
            "robot": {"source": self.robot_source, "frame": self.robot_frame,
                      "target_offset_m": self.target_offset_m,
                      "compliant_joints": list(self.joints),
                      **({"name": self.robot_name} if self.robot_name else {}),
                      **({"loops": self.robot_loops} if self.robot_loops else {}),
                      **({"fixed_base": True} if self.robot_fixed_base else {})},
            "formulation": self.formulation,
            "method": self.method,
            "stiffness_coordinates": self.stiffness_coordinates,
            "joints": [
                {"joint": j, "k": float(k), "unit": u, "k_paper_units": float(kp),
                 "paper_unit": _paper_unit(u)[0], "standard_error": float(se),
                 "ci95": [float(lo), float(hi)], "relative_ci_width": float(w),
                 "determined": j not in self.undetermined_joints, "held": h, "at_bound": b,
                 "physical_scale": s or None, "ci95_dof": dof,
                 "conditional_on": list(c)}
                for j, k, u, kp, se, lo, hi, w, h, b, s, dof, c in zip(
                    self.joints, self.k, self.units, self.k_paper_units, self.standard_error,
                    self.ci95_low, self.ci95_high, self.relative_ci_width, self.held_joints,
                    self.at_bound or (False,) * len(self.joints),
                    self.physical_scale or ("",) * len(self.joints),
                    self.ci95_dof or (None,) * len(self.joints),
                    self.conditional_on or ((),) * len(self.joints), strict=True)
            ],
            "ci95_method": self.ci95_method,
            "kinematics_bias_se": None if self.kinematics_bias_se is None else [
                float(b) if math.isfinite(b) else None for b in self.kinematics_bias_se],
            "loss": self.loss,
            **outlier_keys(self.outliers, self.outlier_sigma_m),
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
            "rms": self.rms_by_kind,
            "rotations": None if self.rotation_residuals is None else {
                "sigma_rad": self.rotation_sigma_rad, "sigma_source": self.rotation_sigma_source,
                "weight_m_per_rad": self.rotation_weight_m_per_rad,
                "rms_rad": self.rms_by_kind["rotation_rad"],
                "residuals_rad": self.rotation_residuals},
            "fits_to_noise": self.fits_to_noise,
            "notes": list(self.notes),
            "model_file": None if self.model_path is None else str(self.model_path),
        })

    def model_file(self) -> ModelFile:
        """The identified model (:class:`stiffness.elastic.model_contents.ModelFile`)."""
        return ModelFile(
            source=self.robot_source, loops=self.robot_loops, fixed_base=self.robot_fixed_base,
            frame=self.robot_frame, robot_name=self.robot_name,
            target_offset_m=self.target_offset_m, compliant_joints=self.joints, k_theta=self.k,
            units=self.units, formulation=self.formulation,
            standard_error=self.standard_error, ci95_low=self.ci95_low,
            ci95_high=self.ci95_high, noise_std_m=self.sigma_m,
            noise_source="declared" if self.noise.declared else "residuals",
            campaign=self.campaign, produced_by="identify",
            undetermined_joints=self.undetermined_joints,
            covariance=ParameterCovariance(tuple(stiffness_labels(self.joints)),
                                           ("1",) * len(self.joints), self.covariance_log,
                                           self.sigma_m),
            extra={"residual_norm": {"eq12_m2": self.residual_ss_m2,
                                     "eq12_mm2": self.residual_ss_mm2},
                   **({} if self.rotation_residuals is None else {"rotation_noise": {
                       "std_rad": self.rotation_sigma_rad,
                       "source": self.rotation_sigma_source,
                       "weight_m_per_rad": self.rotation_weight_m_per_rad}})},
        )

    def write_model_file(self, path: Path) -> Path:
        """Write the identified model (``identified-model.json``, :meth:`model_file`)
        atomically; returns its path. A URDF source is stored relative to the file's folder;
        read it back with :func:`stiffness.elastic.model_file.read_model_file`."""
        return self.model_file().write(path)
