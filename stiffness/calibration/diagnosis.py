"""The result of :func:`stiffness.calibration.diagnose.diagnose`: the steps, the candidates
and ambiguities, the final model (:class:`Diagnosis`: its ``--json`` object, the whole record,
the model file and the ``--out`` folder).

SI inside; the JSON and the files in the campaign's units.
"""


from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stiffness.calibration.campaign import Campaign
from stiffness.calibration.diagnosis_page import render_diagnosis
from stiffness.calibration.fit_verdict import verdict_sentence
from stiffness.calibration.fitting import Fit
from stiffness.calibration.outliers import robust_noise
from stiffness.calibration.residual_figures import residual_axes_png
from stiffness.calibration.result import DiagnosisResult, Output, written
from stiffness.calibration.selection import GOF_LEVEL
from stiffness.elastic.effects.base import Parameter
from stiffness.elastic.effects.deflection_face import DeflectionEffect, Settings
from stiffness.elastic.effects.geometry import Geometry
from stiffness.elastic.model_contents import ModelEffect, ModelFile
from stiffness.elastic.parameter_covariance import deflection_covariance
from stiffness.elastic.undetermined_springs import confounded_joints
from stiffness.files import jsonable, written_path, written_source
from stiffness.provenance import provenance
from stiffness.units import Units

#: Units of the model file's effect parameters (SI).
SI_UNITS = Units(angle="rad", force="N", length="m")
#: File names written by :meth:`Diagnosis.write`.
DIAGNOSIS_FILE, RESIDUALS_PLOT, FINAL_MODEL_FILE = (
    "diagnosis.json", "residuals.png", "final-model.json")
#: The diagnosis as a page (:mod:`stiffness.calibration.diagnosis_page`).
DIAGNOSIS_PAGE = "diagnosis.html"
#: Noise sources.
NOISE_SOURCES = ("declared", "replicates", "residuals")


@dataclass
class Ambiguity:
    """Two effects the campaign cannot tell apart, and the measurements that would.

    Attributes
    ----------
    step
        Step (1-based) at which they competed.
    chosen, other
        Labels of the added effect and of its rival.
    delta_bic
        BIC of the rival minus the chosen one's.
    similarity
        Cosine similarity of their fitted residual reductions.
    separation
        RMS difference of their predictions over the campaign, noise units.
    reason
        Why they cannot be told apart.
    cv_rms
        Cross-validated RMS (m) of the chosen and of the other (None if not computed).
    proposals
        Extra measurements, best first: coordinates, force, predicted deflections of both, the
        separation in noise units.
    """

    step: int
    chosen: str
    other: str
    delta_bic: float
    similarity: float
    separation: float
    reason: str = ""
    cv_rms: tuple[float | None, float | None] = (None, None)
    proposals: list[dict] = field(default_factory=list)

    def to_dict(self, length_to_si: float = 1.0) -> dict:
        """JSON-ready (CV RMS divided by ``length_to_si``)."""
        return {"step": self.step, "chosen": self.chosen, "other": self.other,
                "reason": self.reason, "delta_bic": self.delta_bic,
                "similarity": self.similarity,
                "cv_rms": [None if v is None else v / length_to_si for v in self.cv_rms],
                "separation_noise_units": self.separation, "proposals": self.proposals}


@dataclass
class Diagnosis(DiagnosisResult[Campaign, DeflectionEffect, Fit]):
    """Result of :func:`~stiffness.calibration.diagnose.diagnose` (SI; :meth:`to_dict` and the
    files use campaign units): what both kinds hold (:class:`~stiffness.calibration.result.
    DiagnosisResult`) and a deflection campaign's own.

    Attributes
    ----------
    geometry
        Its robot's shared geometry.
    baseline
        The baseline fitted.
    baseline_stiffness
        Baseline stiffnesses with uncertainties (N.m/rad or N/m).
    final_stiffness
        The same in the final model.
    noise_std_m, noise_std_source, noise_note
        The noise level (m), where it comes from (:data:`NOISE_SOURCES`) and what that means.
    baseline_disagreement, final_disagreement
        Residual breakdowns (:func:`~stiffness.calibration.breakdown.disagreement`).
    gof_baseline, gof_final
        Chi-square p-values of the baseline and final fits (known noise only; under a robust
        loss over the rows not flagged as outliers,
        :func:`~stiffness.calibration.selection.kept_terms`).
    ambiguities
        What the campaign cannot tell apart.
    cv_baseline
        Cross-validated RMS of the baseline (m).
    elapsed_s
        Wall time (s).
    unexplained
        ``True`` when the search ended (library exhausted, or nothing else passing BIC and
        cross-validation) with the chi-square test still rejecting the final model: something
        outside the library is in the data, or a library effect the campaign is too small to
        confirm (:meth:`~stiffness.calibration.result.DiagnosisResult.best_rejected`), and
        :attr:`final_disagreement` says where to look.
        ``False`` when the final model fits to noise; ``None`` when the noise is only estimated
        from the residuals (no test available).
    gof_excluded_rows
        Rows flagged as outliers that the final fit's fit-to-noise test left out (a robust
        loss's; 0 under least squares).
    validation, baseline_validation
        With a validation campaign (``diagnose --validate``,
        :mod:`stiffness.calibration.deflection_validation`): the final model file on it
        (:meth:`~stiffness.calibration.validation.Validation.to_dict`) and the baseline's
        (as each step's :attr:`~stiffness.calibration.search.Step.validation`); else
        ``None``.
    final_covariance
        The covariance of the final fit's ``x`` (:func:`~stiffness.calibration.fitting.
        compliance_covariance` at :attr:`noise_std_m`), written into the model file in its
        variables (:mod:`stiffness.elastic.parameter_covariance`), or ``None``.
    baseline_dof, final_dof
        Per stiffness of :attr:`baseline_stiffness` and :attr:`final_stiffness`, the degrees
        of freedom of its 95 % interval's Student's t
        (:func:`~stiffness.calibration.deflection_noise.interval_quantiles`, ``None`` for the
        normal's), as ``identify`` reports them: JSON ``ci95_dof`` in each entry. Empty: not
        given.
    flipped_column
        When the final model stays unexplained, the note naming a force, moment, deflection or
        rotation column whose reversed sign lets the baseline, or the final model, explain the
        data (:func:`~stiffness.calibration.sign_checks.fits_note`), else ``None``; in the
        verdict and the ``--json`` key of that name.
    """

    geometry: Geometry
    baseline: Fit
    baseline_stiffness: list[Parameter]
    final_stiffness: list[Parameter]
    noise_std_m: float
    noise_std_source: str
    noise_note: str
    baseline_disagreement: dict
    final_disagreement: dict
    gof_baseline: float | None
    gof_final: float | None
    ambiguities: list[Ambiguity]
    cv_baseline: float
    elapsed_s: float
    final_parameters: dict[str, list[Parameter]] = field(default_factory=dict)
    final_parameters_si: dict[str, list[Parameter]] = field(default_factory=dict)
    unexplained: bool | None = None
    measured: np.ndarray | None = None
    rotation_noise_std_rad: float | None = None
    rotation_noise_source: str | None = None
    validation: dict | None = None
    baseline_validation: dict | None = None
    gof_excluded_rows: int = 0
    final_covariance: np.ndarray | None = None
    baseline_dof: tuple[float | None, ...] = ()
    final_dof: tuple[float | None, ...] = ()
    flipped_column: str | None = None

    def rms_by_kind(self) -> dict:
        """RMS of the baseline's and the final model's residuals per kind: translations in
        the length unit, rotations (when measured) in the campaign's rotation unit."""
        measured = self.campaign.deflection if self.measured is None else self.measured
        out = {}
        for label, fit in (("baseline", self.baseline), ("final", self.final)):
            t, r = fit.rms_by_kind(measured)
            out[label] = {"translation": self._len(t), "rotation": None if r is None
                          else r / self.campaign.units.rotation_to_si}
        return out

    def _len(self, value_m: float) -> float:
        return value_m / self.campaign.units.length_to_si

    @property
    def test(self) -> str:
        """The fit-to-noise test's name (:attr:`Noise.test`, the search's noise): ``chi-square``
        for a declared noise, ``lack-of-fit F`` for the replicates' scatter, ``chi-square +
        lack-of-fit F`` when one kind's noise is declared and the other's is its replicates'."""
        noise = None if self.search is None else self.search.noise
        if noise is not None:
            return noise.test
        return "chi-square" if self.noise_std_source == "declared" else "lack-of-fit F"

    @property
    def unexplained_note(self) -> str:
        """One sentence on the verdict of :attr:`unexplained` and its readings
        (:func:`~stiffness.calibration.fit_verdict.verdict_sentence` of
        :meth:`verdict_keys`)."""
        return verdict_sentence(self.verdict_keys())

    def verdict_keys(self) -> dict:
        """The keys of :meth:`to_dict` the verdict reads
        (:func:`~stiffness.calibration.fit_verdict.verdict_sentence`; campaign units):
        ``unexplained``, the test (``gof_test``, ``gof_p``, ``final_rows_excluded``), the
        noise (``noise_std``, ``noise_std_source``, ``robust_noise_ratio``: the final residual's
        robust std, 1.4826 median |r|, over ``noise_std``; null when the noise is the
        residuals'), the search's end (:meth:`search_end`: ``best_rejected``, ``stop_reason``,
        ``cut_short``), the baseline's held-out RMS (``baseline_cv_rms``, null when not
        finite, ``baseline_cv_unbounded`` when infinite) and the campaign (``rows``,
        ``configurations``, the outliers)."""
        measured = self.campaign.deflection if self.measured is None else self.measured
        f = self.final
        robust = robust_noise(f.residuals(measured)[0], f.penalty_params, f.loss,
                              f.f_scale * f.scale)
        return jsonable({
            "unexplained": self.unexplained, "gof_test": self.test, "gof_p": self.gof_final,
            "final_rows_excluded": self.gof_excluded_rows,
            "noise_std": self._len(self.noise_std_m), "noise_std_source": self.noise_std_source,
            "robust_noise_ratio": None if self.noise_std_source == "residuals" or robust is None
            else robust / self.noise_std_m,
            **self.search_end(),
            "baseline_rms": self._len(self.baseline.rms()),
            "baseline_cv_rms": self._len(self.cv_baseline),
            **({"baseline_cv_unbounded": True} if math.isinf(self.cv_baseline) else {}),
            "rows": self.campaign.n_rows, "configurations": len(set(self.campaign.config)),
            "unit": self.unit, "loss": self.loss, **self.outlier_keys(),
            **({"flipped_column": self.flipped_column} if self.flipped_column else {})})

    @property
    def missing_effects(self) -> list[str]:
        """Names of the effects of the final model (added, not removed again)."""
        return [s.effect.name for s in self.named_steps]

    def to_dict(self) -> dict:
        """The object ``stiffness diagnose --json`` prints (campaign units): the keys of the
        issue, those the verdict reads (:meth:`verdict_keys`) and the verdict
        (``unexplained_note``); :meth:`record` has everything."""
        return jsonable({
            "baseline_rms": self._len(self.baseline.rms()),
            "noise_std": self._len(self.noise_std_m),
            "noise_std_source": self.noise_std_source,
            "steps": [{"effect": s.effect.name, "where": s.effect.where,
                       "rms": self._len(s.fit.rms()),
                       "parameters": {p.name: p.to_dict() for p in s.parameters},
                       "stand_in": not s.removed and self.stand_in(s.effect.label),
                       "removed": s.removed, "forced": s.forced,
                       **({"validation": s.validation} if s.validation else {})}
                      for s in self.steps],
            "missing_effects": self.missing_effects,
            "unexplained": self.unexplained,
            "final_rms": self._len(self.final.rms()),
            "final_stiffness": stiffness_entries(self.final_stiffness, self.final_dof),
            "final_parameters": {label: {p.name: p.to_dict() for p in params}
                                 for label, params in self.final_parameters.items()},
            "unit": self.unit,
            "loss": self.loss,
            "masses": self.masses,
            **self.outlier_keys(),
            "rms_by_kind": self.rms_by_kind(),
            "identifiability": self.confounded(self.identifiability()),
            "how_sure": [c.to_dict(self.campaign.units.length_to_si) for c in self.how_sure],
            "selection": self.selection(),
            **({"baseline_validation": self.baseline_validation}
               if self.baseline_validation else {}),
            **({"validation": self.validation} if self.validation else {}),
            **self.verdict_keys(), "unexplained_note": self.unexplained_note,
        })

    def confounded(self, identifiability: dict) -> dict:
        """``identifiability`` (:meth:`identifiability`) with, where a fitted joint spring of
        the final model is not told apart from an effect's parameter
        (:attr:`Parameter.confounded_with`, issue 35), the key ``confounded``: each such
        spring's compliance label, its note and what it is confounded with (absent when
        none, so other campaigns' output is unchanged)."""
        labels = self.final.labels()
        rows = [{"parameter": labels[i], "note": p.text(),
                 "confounded_with": p.to_dict()["confounded_with"]}
                for i, p in enumerate(self.final_stiffness) if p.confounded_with]
        return {**identifiability, "confounded": rows} if rows else identifiability

    def named_parameters(self) -> dict[str, list[Parameter]]:
        """:attr:`final_parameters` (campaign units)."""
        return self.final_parameters

    def record(self, folder: Path | None = None) -> dict:
        """Everything (``diagnosis.json``): :meth:`to_dict` plus the breakdowns, rankings,
        ambiguities, proposals; ``campaign_path`` as given, or relative to ``folder`` (where
        ``diagnosis.json`` is written; :func:`~stiffness.files.written_path`)."""
        c = self.campaign
        out = self.to_dict()
        out.update({
            "campaign": c.name,
            "robot_name": self.geometry.robot.title,
            "campaign_path": None if c.path is None else str(c.path) if folder is None
            else written_path(c.path, folder),
            "rows": c.n_rows,
            "residual_components": (3 if c.rotation is None else 6) * c.n_rows,
            "configurations": len(set(c.config)),
            "baseline": self.baseline.model.describe(),
            "final_model": self.final.model.describe(),
            "noise_std_note": self.noise_note,
            "fits_to_noise": {"baseline_p_value": self.gof_baseline,
                              "final_p_value": self.gof_final, "level": GOF_LEVEL,
                              "final_rows_excluded": self.gof_excluded_rows},
            "stop_reason": self.stop_reason,
            "unexplained_note": self.unexplained_note,
            "cv_rms": {"baseline": self._len(self.cv_baseline),
                       "steps": [self._len(s.cv_rms) for s in self.steps]},
            "baseline_stiffness": stiffness_entries(self.baseline_stiffness, self.baseline_dof),
            "step_details": [{"effect": s.effect.name, "where": s.effect.where,
                              "description": s.effect.describe(),
                              "delta_bic": s.delta_bic, "dispersion": s.dispersion,
                              "ranking": [
                                  {"effect": e.name, "where": e.where, "delta_bic": d,
                                   "cv_rms": None if cv is None else self._len(cv)}
                                  for e, d, cv in s.ranking]}
                             for s in self.steps],
            "where_baseline_disagrees": self.baseline_disagreement,
            "where_final_disagrees": self.final_disagreement,
            "cannot_tell_apart": [a.to_dict(c.units.length_to_si) for a in self.ambiguities],
            "elapsed_s": self.elapsed_s,
            "rotation_unit": c.units.rotation,
            "rotation_noise_std": None if self.rotation_noise_std_rad is None
            else self.rotation_noise_std_rad / c.units.rotation_to_si,
            "rotation_noise_std_source": self.rotation_noise_source,
        })
        return jsonable(out)

    def model_file(self) -> ModelFile:
        """The final model in the model-file schema (SI): baseline stiffnesses with their
        intervals, each effect with its SI parameters and intervals, the noise."""
        c, f = self.campaign, self.final
        s = c.robot_settings
        refs = f.model.refs
        effects = []
        for e in f.model.effects:
            effects.append(ModelEffect(e.name, e.where, e.kind,
                                       self.final_parameters_si.get(e.label, []),
                                       e.file_settings(refs) if isinstance(e, Settings)
                                       else {}, e.describe()))
        stiff = self.final_stiffness
        return ModelFile(
            source=c.resolved_source(), **c.robot_options(),
            joint_angles=c.robot_settings.joint_angles, robot_name=self.geometry.robot.title,
            frame=self.geometry.robot.target_frame,
            target_offset_m=s.target_offset_m, compliant_joints=tuple(f.model.compliant),
            k_theta=np.array([p.value for p in stiff]), units=tuple(p.unit for p in stiff),
            formulation=f.model.baseline,
            standard_error=np.array([p.standard_error for p in stiff]),
            ci95_low=np.array([p.ci95[0] for p in stiff]),
            ci95_high=np.array([p.ci95[1] for p in stiff]),
            effects=tuple(effects), noise_std_m=self.noise_std_m,
            noise_source=self.noise_std_source, campaign=c.name, produced_by="diagnose",
            covariance=None if self.final_covariance is None else deflection_covariance(
                f.model.effects, f.model.compliant,
                {e.label: [p.unit for p in e.parameters] for e in effects},
                self.final_covariance,
                np.concatenate([np.zeros(0)] + [e.scale(refs) for e in f.model.effects]),
                self.noise_std_m),
            undetermined_joints=tuple(p.name for p in stiff if not (
                math.isfinite(p.ci95[1]) and p.ci95[0] > 0)),
            extra={
                "model": f.model.describe(), "rms": self._len(f.rms()),
                "noise_std": self._len(self.noise_std_m),
                "noise_std_source": self.noise_std_source, "unit": self.unit,
                "unexplained": self.unexplained, "unexplained_note": self.unexplained_note,
                "selection": self.selection(),
                "rotation_noise": None if self.rotation_noise_std_rad is None else {
                    "std_rad": self.rotation_noise_std_rad,
                    "source": self.rotation_noise_source,
                    "weight_m_per_rad": f.model.rotation_weight},
                "baseline": f.model.baseline, "compliant_joints": list(f.model.compliant),
                "parameter_vector": f.x.tolist(),
                "references": {"k_ref": refs.k_ref, "theta_ref": refs.theta_ref,
                               "force_ref": refs.force_ref,
                               "deflection_ref": refs.deflection_ref,
                               "tau_max": dict(zip(refs.joints, refs.tau_max.tolist(),
                                                   strict=True)),
                               "tau_smoothing": dict(zip(refs.joints,
                                                         refs.tau_smoothing.tolist(),
                                                         strict=True))},
                **({"confounded_joints": confounded} if (
                    confounded := confounded_joints(stiff)) else {}),
            },
        )

    def outputs(self, folder: Path, command: str | None) -> dict[str, Output]:
        """``diagnosis.json`` (:meth:`record`), ``residuals.png``, ``final-model.json`` and
        ``diagnosis.html``; :attr:`validation` is recorded under ``validation`` (paths
        relative to ``folder``) and shown on the page with the stages."""
        record = self.record(folder) | ({"validation": _validation_in(self.validation, folder)}
                                        if self.validation else {})
        png = residual_plot(self)
        return {"diagnosis": (DIAGNOSIS_FILE, written(json.dumps(record, indent=1) + "\n")),
                "plot": (RESIDUALS_PLOT, written(png)),
                "final_model": (FINAL_MODEL_FILE, self.model_file().write),
                "page": (DIAGNOSIS_PAGE, written(render_diagnosis(record, png,
                                                                  provenance(command))))}


def _validation_in(validation: dict, folder: Path) -> dict:
    """A validation object (:meth:`~stiffness.calibration.validation.Validation.to_dict`) as
    written into ``folder``: its campaign path and robot source relative to ``folder``."""
    robot = validation.get("robot") or {}
    return {**validation, "campaign": written_path(validation["campaign"], folder),
            **({"robot": {**robot, "source": written_source(robot["source"], folder)}}
               if "source" in robot else {})}


def residual_plot(d: Diagnosis) -> bytes:
    """PNG: residual components (x, y, z) before (baseline) and after (final model), row by
    row (:func:`~stiffness.calibration.residual_figures.residual_axes_png`)."""
    lu = d.campaign.units.length_to_si
    before = (d.baseline.predicted[:, :3] - d.campaign.deflection) / lu
    after = (d.final.predicted[:, :3] - d.campaign.deflection) / lu
    sigma = d.noise_std_m / lu
    labels = d.campaign.config
    starts = [i for i in range(len(labels)) if i == 0 or labels[i] != labels[i - 1]]
    title = "missing: " + (", ".join(s.effect.label for s in d.named_steps) or "nothing")
    return residual_axes_png(before, after, sigma, d.unit,
                             f"{d.campaign.name}: RMS {d.baseline.rms() / lu:.3g} -> "
                             f"{d.final.rms() / lu:.3g} {d.unit} (noise {sigma:.3g}); {title}",
                             starts)


def stiffness_entries(stiffness: list[Parameter], dof: tuple[float | None, ...]) -> dict:
    """The JSON entries of a diagnosis's stiffnesses (:meth:`Parameter.to_dict`), each with
    ``ci95_dof``, its interval's degrees of freedom (``None``: the normal's), where ``dof``
    gives them (``identify --json``'s key and rule)."""
    return {p.name: {**p.to_dict(), **({"ci95_dof": d} if dof else {})}
            for p, d in zip(stiffness, dof or (None,) * len(stiffness), strict=True)}
