"""A model file evaluated on another campaign of either kind, without refitting: the function
behind ``stiffness validate`` (:func:`validate`; docs/absolute-poses.md), and the errors of a
deflection model on a deflection campaign (:func:`deflection_errors`).

For a pose campaign (``kind = "poses"``) the model is a pose calibration's ``final-model.json``
(its measuring frame and marker offsets are the model's) and the error is the 3-D position
error, overall and per marker (:func:`stiffness.calibration.pose_register.validation_errors`);
for a deflection campaign the model is a model file of ``identify`` or ``diagnose`` (or a
pose calibration's, the elastic model :func:`~stiffness.elastic.model_file.read_model_file`
reads of it) and the error is the measured deflection minus the model's prediction under
each row's load (:func:`deflection_errors`: every effect applied, measurement effects
included, what the campaign's instrument reads; the one "marker" is the campaign's target).
Both in the campaign's length unit.

The campaign must be of the model's robot: the same source, or the same coordinates and
kinematics (:func:`stiffness.robot.calibration.kinematic_fingerprint`); another robot is
refused with one line. With the campaign's declared noise ``sigma`` the verdict is a
chi-square test of the position residual: ``chi2 = sum r^2 / sigma^2`` over the ``3 n`` seen
components (``n`` the markers seen over all rows; nothing is refitted), its p-value against
``chi2(3 n)`` and the ratio ``rms_3d / (sqrt(3) sigma)`` (1 for a model that predicts to the noise).

A campaign that measures rotations and declares their noise ``sigma_r`` (a deflection
campaign's ``rx, ry, rz`` with ``rotation_noise_std``; a pose campaign's oriented markers with
``noise_std_rotation``) has them in the test too, each at its own noise: the rotation residual
(rad) weighted by ``sigma / sigma_r`` (campaign length unit per rad), as the fits weigh it, so
that ``chi2`` sums ``r_t^2 / sigma^2 + r_r^2 / sigma_r^2`` over the seen translation and
rotation components, its degrees of freedom both counts (until 5 December 2026 the rotations
were left out of the test without a word). Rotations measured without a declared noise are
reported, not tested.

That test takes the model's parameters as exact. A model file that carries its fitted
parameters' covariance ``Sigma`` (``parameter_covariance``,
:mod:`stiffness.elastic.parameter_covariance`) is judged instead with the residual's covariance
``sigma^2 I + J Sigma J^T``, ``J`` the prediction's derivative with respect to those parameters
on the seen components (:class:`ParameterTerm`; the weighted rotations' too):
``chi2 = r^T (sigma^2 I + J Sigma J^T)^-1 r`` against chi-square on the same components
(:func:`prediction_chi2`), the test a model from a small campaign passes at its level on
fresh campaigns of the same robot (docs/absolute-poses.md, Validation). The
verdict is that test's; ``chi2`` and ``gof_p`` stay the noise-only test's.

With a declared noise, the rows the model does not predict are flagged (:func:`flagged_rows`),
as ``identify`` flags the rows its fit does not explain: a position component (predicted minus
measured) beyond :data:`~stiffness.calibration.outliers.OUTLIER_THRESHOLD` noise stds. Nothing
is refitted, so no leverage enters; the model's parameter uncertainty is not in it either (it
adds ``prediction_variance_share`` of the noise variance). A gross row (a 5 mm slip among 10 µm
rows) otherwise showed only as a verdict above the noise, not where.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import cast

import numpy as np

from stiffness.calibration import pose_register
from stiffness.calibration.breakdown import error_summary, rotation_summary
from stiffness.calibration.campaign import Campaign, campaign_kind, load_campaign
from stiffness.calibration.outliers import OUTLIER_THRESHOLD, Outlier, flag_outliers
from stiffness.calibration.pose_campaign import PoseCampaign, load_pose_campaign
from stiffness.calibration.pose_model_file import read_pose_model
from stiffness.calibration.pose_register import (
    validation_errors,
    validation_jacobian,
    validation_orientations,
    validation_residual,
)
from stiffness.calibration.selection import Noise, above_noise
from stiffness.elastic.file_model import fitted_prediction
from stiffness.elastic.model import ElasticModel
from stiffness.elastic.model_contents import ModelFile, ModelRobotError
from stiffness.elastic.model_file import load_model, read_model_file
from stiffness.elastic.parameter_covariance import ParameterCovariance
from stiffness.errors import StiffnessError, wrong_argument
from stiffness.robot.calibration import (
    is_pose_calibration,
    read_pose_calibration,
    robot_description,
    robot_difference,
    robot_identity,
    robot_signature,
)
from stiffness.robot.robot import Robot

#: The name under which a deflection campaign's target is reported.
TARGET = "target"


def deflection_errors(model: ElasticModel, campaign: Campaign) -> dict:
    """The ``stiffness validate --json`` object of a model file on a deflection campaign.

    Keys ``rms``, ``mean_error``, ``std_error``, ``max_error`` (of the 3-D deflection error),
    ``unit`` (the campaign's length unit), ``rows`` and ``markers`` (``{"target": the same keys}``).
    """
    wrench = np.hstack([campaign.force, campaign.moment if campaign.moment is not None
                        else np.zeros_like(campaign.force)])
    predicted = np.array([model.deflection(q, w, measured=True)
                          for q, w in zip(campaign.q, wrench, strict=True)])
    return error_keys(campaign, predicted)


def error_keys(campaign: Campaign, predicted: np.ndarray) -> dict:
    """The keys of :func:`deflection_errors` for the deflections (m, 3) in m ``predicted`` at
    ``campaign``'s rows."""
    errors = np.linalg.norm(campaign.deflection - predicted, axis=1)
    unit = campaign.units.length
    out = {**error_summary(errors, campaign.units.length_to_si), "unit": unit}
    out["markers"] = {TARGET: {**error_summary(errors, campaign.units.length_to_si),
                               "unit": unit}}
    return out


def prediction_chi2(residual: np.ndarray, jacobian: np.ndarray, covariance: np.ndarray,
                    sigma: float) -> float:
    """``r^T (sigma^2 I + J Sigma J^T)^-1 r`` of the residual ``r`` (N,), the prediction's
    derivatives ``J`` (N, k) and the parameters' covariance ``Sigma`` (k, k) (its negative
    eigenvalues, round-off, clipped to 0), by Woodbury's identity on ``A = J Sigma^(1/2)``:
    ``(r^T r - b^T (sigma^2 I + A^T A)^-1 b) / sigma^2``, ``b = A^T r`` (a k x k solve: a
    pose campaign has thousands of components)."""
    values, vectors = np.linalg.eigh(0.5 * (covariance + covariance.T))
    a = jacobian @ (vectors * np.sqrt(np.clip(values, 0.0, None)))
    b = a.T @ residual
    inner = sigma ** 2 * np.eye(a.shape[1]) + a.T @ a
    return float((residual @ residual - b @ np.linalg.solve(inner, b)) / sigma ** 2)


#: A variable whose column's norm is below this fraction of the largest column's moves no
#: seen component (the columns are exact: zero off a marker's chain, up to rounding).
_NO_EFFECT = 1e-12


@dataclass
class ParameterTerm:
    """The model's fitted parameters on the campaign's seen components, to carry their
    uncertainty into the test (:func:`prediction_chi2`).

    Attributes
    ----------
    residual
        (N,) measured minus predicted over the seen position components (campaign length
        unit).
    jacobian
        (N, k) the prediction's derivatives with respect to the variables ``labels`` (campaign
        length unit per variable's unit).
    covariance
        (k, k) those variables' covariance from the model file.
    labels
        The variables (the model file's labels).
    left_out
        The model's variables taken as exact: not determined by its fit (held, or along a
        direction its data did not see), of those that move a seen component.
    """

    residual: np.ndarray
    jacobian: np.ndarray
    covariance: np.ndarray
    labels: tuple[str, ...]
    left_out: tuple[str, ...] = ()

    def chi2(self, sigma: float) -> float:
        """:func:`prediction_chi2` with the noise std ``sigma`` (campaign length unit)."""
        return prediction_chi2(self.residual, self.jacobian, self.covariance, sigma)

    @classmethod
    def of(cls, covariance: ParameterCovariance | None, residual: np.ndarray,
           jacobian: np.ndarray, labels: list[str], to_length: float) -> ParameterTerm | None:
        """The term of the residual (SI, m) and the derivatives (m per variable, columns
        ``labels``) over the seen components, in a length unit of ``to_length`` m, with the
        model file's ``covariance`` (``None`` without one). Of the variables its fit did not
        determine, those that move no seen component here (a humanoid's legs under a one-arm
        campaign) are not said to be taken as exact: exact or not, they change nothing."""
        if covariance is None:
            return None
        matrix, used, left = covariance.over(labels)
        norms = np.linalg.norm(jacobian, axis=0) if jacobian.size else np.zeros(len(labels))
        moves = norms > _NO_EFFECT * max(float(norms.max(initial=0.0)), np.finfo(float).tiny)
        return cls(residual / to_length, jacobian[:, used] / to_length, matrix,
                   tuple(labels[k] for k in used),
                   tuple(name for name in left if moves[labels.index(name)]))


@dataclass
class RotationTerm:
    """The rotation components a validation tests, each at its own noise.

    Attributes
    ----------
    residual
        (N_r,) measured minus predicted rotation components (rad) times :attr:`weight`: in
        the campaign's length unit, at the position noise ``sigma``.
    weight
        ``sigma / sigma_r`` (campaign length unit per rad), ``sigma_r`` the declared rotation
        noise std.
    noise_std
        ``sigma_r`` in the campaign's rotation unit.
    """

    residual: np.ndarray
    weight: float
    noise_std: float

    def chi2(self, sigma: float) -> float:
        """``sum r_r^2 / sigma_r^2``: the weighted residual over the position noise
        ``sigma`` (campaign length unit)."""
        return float(self.residual @ self.residual / sigma ** 2)

    def stacked(self, residual: np.ndarray, jacobian: np.ndarray, rotation_rad: np.ndarray,
                rotation_jacobian: np.ndarray, length_to_si: float
                ) -> tuple[np.ndarray, np.ndarray]:
        """The position components (m) and their Jacobian (rows of parameter columns) with
        the rotation components (rad) and theirs below, weighted into metres at the position
        noise as the fits weigh them (:attr:`weight` times ``length_to_si`` m per length
        unit): what :meth:`ParameterTerm.of` takes."""
        weight_si = self.weight * length_to_si
        p = jacobian.shape[-1]
        return (np.concatenate([residual.reshape(-1), weight_si * rotation_rad.reshape(-1)]),
                np.vstack([jacobian.reshape(-1, p), weight_si * rotation_jacobian.reshape(-1, p)]))

    @classmethod
    def of(cls, residual_rad: np.ndarray, noise_m: float | None,
           rotation_noise_rad: float | None, length_to_si: float, rotation_to_si: float
           ) -> RotationTerm | None:
        """The term of the seen rotation residual components (rad) with the declared
        position (m) and rotation (rad) noise stds, ``None`` without either; in a length
        unit of ``length_to_si`` m and a rotation unit of ``rotation_to_si`` rad."""
        if noise_m is None or rotation_noise_rad is None:
            return None
        weight = noise_m / rotation_noise_rad / length_to_si
        return cls(weight * np.asarray(residual_rad, dtype=float).reshape(-1), weight,
                   rotation_noise_rad / rotation_to_si)


#: The words of a verdict's test.
WITH_PARAMETERS = "noise and the model's parameter uncertainty"
NOISE_ONLY = "noise only"


@dataclass
class Validation:
    """A model file evaluated on a campaign, without refitting.

    Attributes
    ----------
    model, campaign
        The model file and the campaign (as given).
    kind
        ``poses`` or ``deflections``.
    errors
        The error summary in the campaign's length unit (``rms``, ``mean_error``,
        ``std_error``, ``max_error``, ``unit``, ``rows``, ``markers``...:
        :func:`~stiffness.calibration.pose_register.validation_errors`,
        :func:`deflection_errors`).
    robot
        The robot both are of: ``source``, ``name`` (:attr:`Robot.title`), ``coordinates``,
        ``fingerprint``.
    noise_std
        The campaign's declared position noise std (campaign unit), or ``None``.
    parameters
        The model's fitted parameters on the seen components (:class:`ParameterTerm`, the
        tested rotations after the positions), or ``None`` for a model file without their
        covariance (written before it): the verdict is then the noise-only test's.
    rotations
        The tested rotation components (:class:`RotationTerm`), ``None`` when the campaign
        measures none or declares no rotation noise (or no position noise).
    outliers
        The rows the model does not predict (:func:`flagged_rows`; none without a noise).
    frame
        A pose model's measuring frame registered anew on the campaign
        (:func:`~stiffness.calibration.pose_register.refit_frame`): ``applied`` (the errors
        are after it: ``validate --refit-frame``), ``families`` refitted (``frame``, and
        ``markers`` with ``--refit-markers``), ``parameters`` (their identifiable count),
        ``rms`` (the 3-D RMS after it),
        ``translation`` (campaign length unit) and ``rotation_deg`` of the motion; ``None``
        for a deflection model, or a pose model fitted without its ``frame`` family.
    refitted
        Parameters fitted to the campaign (those of ``frame["parameters"]`` when applied): the
        chi-square's degrees of freedom are the components less these.
    """

    model: str
    campaign: str
    kind: str
    errors: dict
    robot: dict
    noise_std: float | None
    parameters: ParameterTerm | None = None
    rotations: RotationTerm | None = None
    outliers: tuple[Outlier, ...] = ()
    frame: dict | None = None
    refitted: int = 0

    @property
    def position_components(self) -> int:
        """Seen position components: 3 per marker seen on a row (its ``markers``' counts;
        ``rows`` counts the campaign's rows, which two markers see twice)."""
        return 3 * sum(int(m["rows"] or 0) for m in self.errors["markers"].values())

    @property
    def components(self) -> int:
        """The test's components: the seen position components and the tested rotation
        components."""
        return self.position_components + (0 if self.rotations is None
                                           else self.rotations.residual.size)

    @property
    def chi2(self) -> float | None:
        """``sum r^2 / sigma^2`` over the seen position components (``rms`` is that of the
        3-D errors of every seen marker) plus ``sum r_r^2 / sigma_r^2`` over the tested
        rotation components, or ``None`` without a noise."""
        if self.noise_std is None or self.errors["rms"] is None:
            return None
        rotations = 0.0 if self.rotations is None else self.rotations.chi2(self.noise_std)
        return float((self.errors["rms"] / self.noise_std) ** 2 * self.position_components / 3
                     + rotations)

    def gof(self) -> float | None:
        """Chi-square p-value of the residual against the declared noise, or ``None``."""
        return self._p_value(self.chi2)

    @property
    def chi2_with_parameters(self) -> float | None:
        """``r^T (sigma^2 I + J Sigma J^T)^-1 r`` over the seen components
        (:meth:`ParameterTerm.chi2`), or ``None`` without a noise or a covariance."""
        if self.noise_std is None or self.parameters is None:
            return None
        return self.parameters.chi2(self.noise_std)

    def gof_with_parameters(self) -> float | None:
        """Chi-square p-value of :attr:`chi2_with_parameters` against ``chi2(3 n)``, or
        ``None``."""
        return self._p_value(self.chi2_with_parameters)

    def _p_value(self, chi2: float | None) -> float | None:
        """Chi-square p-value of ``chi2`` on the seen components against the declared noise,
        or ``None`` without either."""
        if chi2 is None or self.noise_std is None:
            return None
        return Noise(self.noise_std).goodness_of_fit(chi2 * self.noise_std ** 2,
                                                     self.components, self.refitted)

    @property
    def verdict_test(self) -> str:
        """What the verdict's test takes the residual's covariance to be:
        :data:`WITH_PARAMETERS` with the model's covariance, else :data:`NOISE_ONLY`."""
        return NOISE_ONLY if self.parameters is None else WITH_PARAMETERS

    @property
    def verdict(self) -> str | None:
        """``consistent with the noise`` or ``above the noise`` (the chi-square test at
        :data:`~stiffness.calibration.selection.GOF_LEVEL`,
        :func:`~stiffness.calibration.selection.above_noise`: :meth:`gof_with_parameters`
        with the model's covariance, else :meth:`gof`), ``None`` without a noise."""
        p = self.gof() if self.parameters is None else self.gof_with_parameters()
        if p is None:
            return None
        return "above the noise" if above_noise(p) else "consistent with the noise"

    def to_dict(self) -> dict:
        """What ``stiffness validate --json`` prints: the error summary's keys, and
        ``kind``, ``robot``, ``noise_std``, ``rms_over_noise`` (3-D RMS over ``sqrt(3)``
        noise stds), ``chi2``, ``dof``, ``gof_p`` (the noise-only test), ``verdict``;
        ``chi2_with_parameters`` and ``gof_p_with_parameters`` (the test with the model's
        parameter covariance, ``None`` without one), ``verdict_test`` (which test the verdict
        is) and ``parameter_uncertainty`` (``included``, ``variables``, ``left_out``:
        those taken as exact, ``prediction_variance_share``: the trace of ``J Sigma J^T``
        over ``N sigma^2``); ``rotation_noise_std`` (the declared rotation noise std in the
        campaign's rotation unit) and ``rotation_components`` (the rotation components in
        ``dof``: 0 when none is tested); ``outlier_threshold`` and ``outliers`` (the flagged
        rows, :class:`~stiffness.calibration.outliers.Outlier`, as ``identify --json``)."""
        rms = self.errors["rms"]
        ratio = (None if self.noise_std is None or rms is None
                 else rms / (math.sqrt(3) * self.noise_std))
        term = self.parameters
        share = (None if term is None or self.noise_std is None or not term.residual.size
                 else float(np.einsum("ij,jk,ik->", term.jacobian, term.covariance,
                                      term.jacobian) / (term.residual.size
                                                        * self.noise_std ** 2)))
        return {**self.errors, "kind": self.kind, "model": self.model,
                "campaign": self.campaign, "robot": self.robot, "noise_std": self.noise_std,
                "rms_over_noise": ratio, "chi2": self.chi2,
                "dof": self.components - self.refitted, "frame_refit": self.frame,
                "rotation_noise_std": None if self.rotations is None
                else self.rotations.noise_std,
                "rotation_components": 0 if self.rotations is None
                else int(self.rotations.residual.size),
                "gof_p": self.gof(), "verdict": self.verdict,
                "chi2_with_parameters": self.chi2_with_parameters,
                "gof_p_with_parameters": self.gof_with_parameters(),
                "verdict_test": self.verdict_test,
                "parameter_uncertainty": {
                    "included": term is not None,
                    "variables": [] if term is None else list(term.labels),
                    "left_out": [] if term is None else list(term.left_out),
                    "prediction_variance_share": share},
                "outlier_threshold": OUTLIER_THRESHOLD,
                "outliers": [o.to_dict() for o in self.outliers]}


def validate(model: ModelFile | str | os.PathLike,
             campaign: Campaign | PoseCampaign | str | os.PathLike,
             refit: tuple[str, ...] = ()) -> Validation:
    """The model file ``model`` (a path, or a deflection model read: :class:`ModelFile`)
    evaluated on ``campaign`` (a ``campaign.toml`` or its folder, or a campaign loaded):
    errors in the campaign's length unit and the verdict against its declared noise. A pose
    calibration's ``final-model.json`` on a deflection campaign is the elastic model
    :func:`~stiffness.elastic.model_file.read_model_file` reads of it (its springs and elastic
    families, on the calibrated robot), as a :class:`ModelFile` of it given here is
    (refused as another kind of campaign until 6 December 2026, given by its path); it carries
    no parameter covariance, so its verdict is the noise-only test's. A pose model's
    measuring frame is registered anew on the campaign in every case, but a model fitted
    without one (:attr:`Validation.frame`);
    with ``refit`` (``("frame",)``: a campaign of another day, the tracker moved; with
    ``"markers"`` too, a marker plate mounted again) those families are fitted to the campaign
    and the errors and the verdict are after it (their parameters counted), else with the
    model's.

    Raises
    ------
    ModelRobotError
        The campaign is of another robot than the model's.
    StiffnessError
        A deflection model with a pose campaign, or a file that cannot be read; a ``refit``
        on a deflection campaign.
    """
    if not isinstance(model, ModelFile | str | os.PathLike):
        raise wrong_argument("model", model, "a model file's path (str or os.PathLike) or a "
                             "ModelFile")
    pose_model = not isinstance(model, ModelFile) and is_pose_calibration(model)
    kind = "poses" if isinstance(campaign, PoseCampaign) else "deflections" if isinstance(
        campaign, Campaign) else campaign_kind(campaign)
    name = str(model.path or "the model") if isinstance(model, ModelFile) else str(model)
    if kind == "poses" and not pose_model:
        raise StiffnessError(
            f"{name} is a deflection model and {campaign_name(campaign)} is not a deflection "
            "campaign; validate a deflection model on a deflection campaign, a pose "
            "calibration on a pose or a deflection campaign")
    if isinstance(model, ModelFile) or kind == "deflections":  # a pose calibration read as
        # the elastic model load_model makes of it (its springs and elastic families)
        if refit:
            raise StiffnessError(pose_register.REFIT_REFUSED)
        declared = model if isinstance(model, ModelFile) else read_model_file(model)
        return validate_deflection_model(  # a deflection campaign: kind said so
            declared, name, cast("Campaign | str | os.PathLike", campaign))
    poses = campaign if isinstance(campaign, PoseCampaign) else load_pose_campaign(
        cast("str | os.PathLike", campaign))
    cal = read_pose_calibration(model)
    robot = same_robot(cal.source, lambda: read_pose_model(model).robot, poses.robot,
                       poses.robot.name, model, campaign_name(campaign))
    calibration = read_pose_model(model, poses.robot)
    refit = pose_register.check_refit(refit)
    moved, registered = pose_register.registered(calibration.model, calibration.x, poses, refit)
    slices = calibration.model.slices()
    frame = [k for f in refit for k in range(slices[f].start, slices[f].stop)]
    calibration = replace(calibration, x=moved)
    # the positions predicted once: with the Jacobian where the parameters' covariance needs it
    residual, jac = (validation_jacobian(calibration.model, calibration.x, poses)
                     if calibration.covariance is not None else
                     (validation_residual(calibration.model, calibration.x, poses), None))
    errors = validation_errors(calibration.model, calibration.x, poses, residual)
    noise = None if poses.noise_std is None else poses.noise_std / poses.units.length_to_si
    rotations = rotation_residual = rotation_jacobian = None
    if poses.rotations is not None and poses.noise_std is not None \
            and poses.noise_std_rotation is not None:  # oriented markers, at their own noise
        rotation_residual, rotation_jacobian = validation_orientations(
            calibration.model, calibration.x, poses)
        rotations = RotationTerm.of(rotation_residual, poses.noise_std, poses.noise_std_rotation,
                                    poses.units.length_to_si, poses.units.rotation_to_si)
    term = None
    if calibration.covariance is not None and jac is not None:
        seen = np.isfinite(residual)
        stacked, stacked_jac = residual[seen], jac[seen]
        if rotations is not None and rotation_residual is not None \
                and rotation_jacobian is not None:
            stacked, stacked_jac = rotations.stacked(stacked, stacked_jac, rotation_residual,
                                                     rotation_jacobian, poses.units.length_to_si)
        if refit:  # fitted here: what the refit absorbs of the others' errors is not left
            stacked_jac = refitted_jacobian(stacked_jac, frame)
        term = ParameterTerm.of(calibration.covariance, stacked, stacked_jac,
                                [p.label for p in calibration.model.parameters],
                                poses.units.length_to_si)
    flagged = flagged_rows(-residual / poses.units.length_to_si, noise, poses.labels, poses.lines,
                           [f"{m.name}_{a}" for m in calibration.model.markers for a in "xyz"])
    return Validation(name, campaign_name(campaign), "poses", errors, robot, noise, term,
                      rotations, flagged, registered,
                      registered["parameters"] if refit and registered else 0)


def refitted_jacobian(jacobian: np.ndarray, refitted: list[int]) -> np.ndarray:
    """The derivatives (N, p) of the tested components (positions, and orientations weighted
    into them, as the registration fits them: :func:`~stiffness.calibration.pose_register.
    refit_frame`) with respect to the model's parameters once the columns ``refitted`` are
    fitted to them by least squares: a change ``dx`` of the others moves them by ``J dx``, of
    which the refit takes ``J_f J_f^+ J dx`` (``J_f`` the refitted columns), leaving the
    projection ``J - J_f J_f^+ J`` (the refitted columns 0). Zeroing the refitted columns
    alone (until 6 December 2026) kept the part the refit absorbs in the residual's
    covariance."""
    frame = jacobian[:, refitted]
    return jacobian - frame @ np.linalg.lstsq(frame, jacobian, rcond=None)[0]


def flagged_rows(residual: np.ndarray, noise: float | None, labels: list[str] | tuple[str, ...],
                 lines: tuple[int, ...] | None, names: list[str]) -> tuple[Outlier, ...]:
    """The rows a model does not predict: a component of ``residual`` (n, k) or (n, M, 3)
    (predicted minus measured, the campaign's length unit, NaN where not seen; ``names`` the
    k components') beyond :data:`~stiffness.calibration.outliers.OUTLIER_THRESHOLD` times the
    declared ``noise`` std; none without one."""
    if noise is None:
        return ()
    z = np.asarray(residual, dtype=float).reshape(len(labels), -1) / noise
    return tuple(flag_outliers(z, tuple(labels), lines, names=names))


def campaign_name(campaign: Campaign | PoseCampaign | str | os.PathLike) -> str:
    """How messages and results name a campaign: its path (a loaded one's, else its name)."""
    if isinstance(campaign, Campaign | PoseCampaign):
        return str(campaign.path) if campaign.path is not None else f"campaign {campaign.name!r}"
    return str(campaign)


def validate_deflection_model(declared: ModelFile, model: str,
                              campaign: Campaign | str | os.PathLike) -> Validation:
    """A deflection model file (read, or built in memory: a diagnosis's final model) evaluated
    on the deflection campaign ``campaign``; ``model`` names the model in messages and the
    result.

    Raises
    ------
    ModelRobotError
        The campaign is of another robot than the model's.
    StiffnessError
        ``campaign`` cannot be read as a deflection campaign.
    """
    measured = campaign if isinstance(campaign, Campaign) else load_campaign(campaign)
    robot = same_robot(declared.source, declared.robot, measured.robot(),
                       measured.resolved_source(), model, campaign_name(campaign))
    # the campaign measured its own target: the model evaluated there (moved only where the
    # campaign's differs, so that a diagnosed target_offset stays otherwise)
    target = measured.robot()
    same = target.target_frame == declared.frame and np.allclose(
        target.target_offset, declared.target_offset_m, rtol=0.0, atol=1e-12)
    if same:  # the model file's checks (its effects on its robot), as load_model makes them
        load_model(declared)
    else:
        load_model(declared, frame=target.target_frame, target_offset=target.target_offset)
    at_target = declared if same else replace(
        declared, frame=target.target_frame, target_offset_m=target.target_offset,
        effects=tuple(e for e in declared.effects if e.name != "target_offset"))
    wrench = np.hstack([measured.force, measured.moment if measured.moment is not None
                        else np.zeros_like(measured.force)])
    # every row at once: the prediction of load_model(...).deflection, row by row
    predicted, jac, labels = fitted_prediction(at_target, measured.q, wrench,
                                               rotations=measured.rotation is not None)
    return deflection_validation(model, campaign_name(campaign), robot, measured, predicted,
                                 jac, labels, at_target.covariance)


def deflection_validation(model: str, campaign: str, robot: dict, measured: Campaign,
                          predicted: np.ndarray, jacobian: np.ndarray | None,
                          labels: list[str], covariance: ParameterCovariance | None
                          ) -> Validation:
    """The :class:`Validation` named ``model`` and ``campaign`` of the predictions (m, 3)
    in m, or (m, 6) with the rotations (rad) when ``measured`` measures them, at
    ``measured``'s rows, their derivatives (m, 3 or 6, p) in the variables ``labels``
    (``None`` without a ``covariance``) and those variables' covariance (``None``: the
    noise-only test): the errors, and the rotations tested at their own noise, weighted by
    ``sigma / sigma_r`` into the positions' (:class:`RotationTerm`), when both are declared."""
    errors = error_keys(measured, predicted[:, :3])
    noise = None if measured.noise_std_m is None else (
        measured.noise_std_m / measured.units.length_to_si)
    residual = (measured.deflection - predicted[:, :3]).reshape(-1)
    jac = None if jacobian is None else jacobian[:, :3].reshape(-1, jacobian.shape[-1])
    rotations = None
    if measured.rotation is not None:
        rotation_residual = measured.rotation - predicted[:, 3:6]
        angle = np.linalg.norm(rotation_residual, axis=1)
        errors.update(rotation_summary(angle, measured.units))
        errors["markers"][TARGET].update(rotation_summary(angle, measured.units))
        rotations = RotationTerm.of(rotation_residual, measured.noise_std_m,
                                    measured.rotation_noise_std_rad, measured.units.length_to_si,
                                    measured.units.rotation_to_si)
        if rotations is not None and jacobian is not None and jac is not None:
            residual, jac = rotations.stacked(residual, jac, rotation_residual,
                                              jacobian[:, 3:6], measured.units.length_to_si)
    term = None if jac is None else ParameterTerm.of(covariance, residual, jac, labels,
                                                      measured.units.length_to_si)
    flagged = flagged_rows((predicted[:, :3] - measured.deflection) / measured.units.length_to_si,
                           noise, measured.config, measured.lines, ["dx", "dy", "dz"])
    return Validation(model, campaign, "deflections", errors, robot, noise, term, rotations,
                      flagged)


def same_robot(model_source: str, model_robot: Callable[[], Robot], campaign_robot: Robot,
               campaign_source: str, model: str | os.PathLike,
               campaign: str | os.PathLike) -> dict:
    """The robot a model and a campaign are both of: the same source, or the same coordinates
    and kinematics (a copy of the robot's files). Returns its ``source``, ``name``,
    ``coordinates`` and kinematic ``fingerprint``; ``model_robot`` loads the model's robot when
    the sources differ.

    Raises
    ------
    ModelRobotError
        Other coordinates or kinematics (one line naming both robots).
    """
    if robot_identity(model_source) != robot_identity(campaign_source):
        other = model_robot()
        if what := robot_difference(other, campaign_robot):
            raise ModelRobotError(
                f"{campaign} is a campaign of robot {robot_description(campaign_robot)}, not "
                f"of the model's {robot_description(other)}: other {what}; validate {model} "
                "on a campaign of its robot")
    coordinates, fingerprint = robot_signature(campaign_robot)
    return {"source": robot_identity(campaign_source), "name": campaign_robot.title,
            "coordinates": list(coordinates), "fingerprint": fingerprint}
