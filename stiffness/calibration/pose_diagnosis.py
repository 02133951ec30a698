"""The result of a pose diagnosis (:func:`stiffness.calibration.pose_diagnose.diagnose_poses`),
:class:`PoseDiagnosis`: its verdict, its ``--json`` object and its ``--out`` folder (SI inside;
the JSON and the files in the campaign's length unit)."""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stiffness.calibration.breakdown import marker_structure
from stiffness.calibration.fit_verdict import verdict_line, verdict_sentence
from stiffness.calibration.outliers import robust_noise
from stiffness.calibration.pose_campaign import PoseCampaign
from stiffness.calibration.pose_fit import PoseFit, noise_terms
from stiffness.calibration.pose_model_file import (
    measuring_frame,
    parameter_table,
    write_pose_model,
)
from stiffness.calibration.pose_page import render_pose_diagnosis, stage_plot
from stiffness.calibration.pose_parameters import PoseJudge
from stiffness.calibration.pose_plausibility import Plausibility, plausibility
from stiffness.calibration.residual_figures import residual_axes_png
from stiffness.calibration.result import DiagnosisResult, Output, written
from stiffness.calibration.search import Step
from stiffness.calibration.selection import Noise, NoiseTerms, above_noise
from stiffness.elastic.effects.base import Parameter
from stiffness.files import jsonable
from stiffness.provenance import provenance

#: The families every pose diagnosis starts with (the tracker's placement and the markers).
BASE_FAMILIES = ("frame", "markers")
#: Why a family has no BIC change to show: no identifiable parameter (a tilt, no spring in).
NO_PARAMETER = ("no identifiable parameter beside the families in: it moves no marker here, "
                "or only as they do")
#: :data:`NO_PARAMETER` where the cause is that nothing loads a spring (a family of the
#: weight and the loads, on a robot file without link masses and a campaign without loads:
#: :func:`~stiffness.calibration.pose_campaign.loads_no_spring`), with the fix.
UNLOADED = ("no identifiable parameter: no spring is loaded, the robot file giving its links "
            "no mass and the campaign applying no load; declare the links' <inertial> masses, "
            "or measure under known loads (fx..mz columns), or diagnose with --masses unknown "
            "(gravity_lumped fits the weight)")
#: The notes of a family screened with no identifiable parameter (no BIC change to judge).
NO_PARAMETER_NOTES = (NO_PARAMETER, UNLOADED)
#: The held-out criterion of every step (``cv_rms``): leave one configuration out, from the
#: linearised hat matrix (:func:`~stiffness.calibration.pose_fit.held_out_rms`).
HELD_OUT_CRITERION = "leave-one-configuration-out (linearised hat matrix)"


@dataclass
class PoseDiagnosis(DiagnosisResult[PoseCampaign, str, PoseFit]):
    """A pose diagnosis: what both kinds hold (:class:`~stiffness.calibration.result.
    DiagnosisResult`; the steps from the baseline's, the outliers flagged by
    :func:`~stiffness.calibration.pose_fit.flag_pose_outliers`), the families ``rejected``
    (their last BIC change) or ``not_judged`` (why), and the ``judge`` of its parameters."""

    rejected: dict[str, float] = field(default_factory=dict)
    judge: PoseJudge | None = None
    not_judged: dict[str, str] = field(default_factory=dict)

    @property
    def baseline(self) -> PoseFit:
        """The baseline's fit (measuring frame and markers): step 0's."""
        return self.steps[0].fit

    @functools.cached_property
    def plausibility(self) -> Plausibility:
        """Whether the final fit can be a calibration: its lengths against the robot's
        reach, the campaign's marker spread against its kinematics
        (:func:`~stiffness.calibration.pose_plausibility.plausibility`; a unit read 1000x off
        is absorbed by the geometry and reads *explained*)."""
        return plausibility(self.final, self.campaign)

    def selection(self) -> dict:
        """How the families were chosen (kept in the model file): ``forced`` and
        ``forbidden`` (:meth:`DiagnosisResult.selection`) and the ``held_out`` criterion."""
        return {**super().selection(), "held_out": HELD_OUT_CRITERION}

    @property
    def families(self) -> list[str]:
        """Families of the final model, in the order chosen."""
        return list(BASE_FAMILIES) + [s.effect for s in self.named_steps]

    @functools.cached_property
    def final_terms(self) -> NoiseTerms:
        """What the final fit's fit-to-noise test reads
        (:func:`~stiffness.calibration.pose_fit.noise_terms`: every observed component, a
        robust loss's flagged poses left out)."""
        return noise_terms(self.final, self.campaign)

    def gof(self) -> float | None:
        """Chi-square p-value of the final residual (:attr:`final_terms`) against the
        declared noise, or None (:meth:`~stiffness.calibration.selection.Noise.goodness_of_fit`)."""
        sigma = self.campaign.noise_std
        return None if sigma is None else self.final_terms.p_value(Noise(sigma))

    @property
    def unexplained(self) -> bool | None:
        """Whether the final residual is above the declared noise (None: no noise declared;
        :func:`~stiffness.calibration.selection.above_noise`)."""
        p = self.gof()
        return None if p is None else above_noise(p)

    def verdict(self) -> str:
        """Whether the final model explains the poses to their noise (chi-square against the
        declared noise), in words, headed ``UNEXPLAINED`` where it does not
        (:func:`~stiffness.calibration.fit_verdict.verdict_line` of :meth:`verdict_keys`:
        where the residual sits, the poses flagged as outliers, the best family rejected and
        an understated noise)."""
        return verdict_line(self.verdict_keys())

    def best_rejected(self) -> dict | None:
        """:meth:`DiagnosisResult.best_rejected`; when the last step fitted no family (none
        past the BIC margin on its one Gauss-Newton screen), the family of :attr:`rejected`
        with the lowest BIC change (of those with an identifiable parameter,
        :data:`NO_PARAMETER_NOTES`), its RMS and held-out RMS not known (null)."""
        best = super().best_rejected()
        refusal = None if self.search is None else self.search.refusal
        tried = {f: d for f, d in self.rejected.items()
                 if self.not_judged.get(f) not in NO_PARAMETER_NOTES}
        if best is not None or refusal is None or not tried:
            return best
        family = min(tried, key=tried.__getitem__)
        lu = self.campaign.units.length_to_si
        return {"candidate": family, "delta_bic": self.rejected[family], "rms": None,
                "rms_before": refusal.current.rms() / lu, "cv_rms": None,
                "cv_rms_before": refusal.cv_current / lu,
                "not_judged": self.not_judged.get(family)}

    def verdict_keys(self) -> dict:
        """The keys of :meth:`to_dict` the verdict reads
        (:func:`~stiffness.calibration.fit_verdict.verdict_sentence`; lengths in the campaign
        unit): ``kind``, ``unexplained``, the test (``gof_test``, ``gof_p``,
        ``final_rows_excluded``), the noise (``noise_std``, ``noise_std_source``,
        ``robust_noise_ratio``: the final residual's robust std, 1.4826 median |r|, over the
        declared noise; null when none is declared), the search's end (:meth:`search_end`:
        ``best_rejected``, ``stop_reason``, ``cut_short``), where the residual sits
        (``residual_structure``), ``rows`` (poses) and the outliers."""
        c, lu = self.campaign, self.campaign.units.length_to_si
        r = self.final.residual
        robust = robust_noise(r[np.isfinite(r)], self.final.n_fitted, self.final.loss,
                              self.final.noise.sigma)
        return jsonable({
            "kind": "poses", "unexplained": self.unexplained, "gof_test": "chi-square",
            "gof_p": self.gof(), "final_rows_excluded": self.final_terms.excluded,
            "noise_std": None if c.noise_std is None else c.noise_std / lu,
            "noise_std_source": None if c.noise_std is None else "declared",
            "robust_noise_ratio": None if c.noise_std is None or robust is None
            else robust / c.noise_std,
            **self.search_end(),
            "residual_structure": marker_structure(self.final, c), "rows": c.n_rows,
            "unit": c.units.length, "loss": self.loss, **self.outlier_keys()})

    def to_dict(self) -> dict:
        """What ``diagnose --json`` prints for a pose campaign (lengths in the campaign unit;
        an infinite number, a forced family's held-out RMS that one configuration determines,
        as null): its steps and families, those the verdict reads (:meth:`verdict_keys`) and
        the verdict (``unexplained_note``)."""
        lu, verdict = self.campaign.units.length_to_si, self.verdict_keys()
        return jsonable({"campaign": self.campaign.name, "robot_name": self.campaign.robot.title,
                "masses": self.masses,
                "steps": [{"family": s.effect, "rms": s.fit.rms() / lu,
                           "delta_bic": s.delta_bic, "cv_rms": s.cv_rms / lu,
                           "n_parameters": s.fit.n_fitted, "converged": s.fit.converged,
                           "forced": s.forced, "removed": s.removed, "refused": s.refused,
                           **self._named(s),
                           **({"validation": s.validation} if s.validation else {})}
                          for s in self.steps],
                "rejected": self.rejected, "not_judged": self.not_judged,
                "families": self.families,
                "selection": self.selection(),
                "plausible": self.plausibility.plausible,
                "plausibility": self.plausibility.to_dict(),
                "identifiability": self.identifiability(),
                "parameters": parameter_table(self.final, self.judge),
                "measuring_frame": measuring_frame(self.final, lu),
                "how_sure": [c.to_dict(lu) for c in self.how_sure],
                **verdict, "unexplained_note": verdict_sentence(verdict)})

    def named_parameters(self) -> dict[str, list[Parameter]]:
        """Each family's parameters in the final fit (SI), judged against their physical
        scales (:meth:`~stiffness.calibration.pose_parameters.PoseJudge.parameters`)."""
        return {} if self.judge is None else self.judge.parameters(self.final)

    def _named(self, step: Step[str, PoseFit]) -> dict:
        """A step's ``parameters`` (its family's, as that step fitted them, SI) and
        ``stand_in`` (in the final model), the keys of a deflection diagnosis's steps."""
        if self.judge is None or step.effect == "baseline" or step.removed:
            return {}
        params = self.judge.parameters(step.fit)[step.effect]
        return {"parameters": {p.name: p.to_dict() for p in params},
                "stand_in": self.stand_in(step.effect)}

    def write_model(self, path: Path) -> Path:
        """Write the pose model file of the final fit at ``path`` atomically (with how the
        families were chosen and the plausibility); returns its path."""
        return write_pose_model(self.final, self.campaign, path, self.selection(),
                                self.plausibility.to_dict())

    def outputs(self, folder: Path, command: str | None) -> dict[str, Output]:
        """``diagnosis.json`` (:meth:`to_dict`), ``final-model.json`` (the pose model file)
        and ``diagnosis.html`` (the page, with a residual figure per marker and the stage
        figure when there is a validation campaign)."""
        record = self.to_dict()
        page = render_pose_diagnosis(record, stage_plot(record), provenance(command),
                                     marker_residual_plots(self))
        return {"diagnosis": ("diagnosis.json",
                              written(json.dumps(record, indent=1, allow_nan=False) + "\n")),
                "model": ("final-model.json", self.write_model),
                "page": ("diagnosis.html", written(page))}


def marker_residual_plots(d: PoseDiagnosis) -> dict[str, bytes]:
    """One :func:`residual_axes_png` per marker of a pose diagnosis: its measured minus
    predicted position before (the first step: tracker placement and marker offsets only) and
    after (the final model), in the campaign's length unit; keyed by marker name."""
    c = d.campaign
    lu = c.units.length_to_si
    before, after = d.baseline.residual / lu, d.final.residual / lu
    sigma = None if c.noise_std is None else c.noise_std / lu
    plots = {}
    for k, m in enumerate(c.markers):
        plots[m.name] = residual_axes_png(
            before[:, k], after[:, k], sigma, c.units.length,
            f"{c.name}, marker {m.name}: before, the tracker placement and marker offsets "
            f"fitted; after, with {', '.join(d.families[2:]) or 'nothing more'}")
    return plots
