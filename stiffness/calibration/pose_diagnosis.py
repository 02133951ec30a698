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
from stiffness.calibration.outliers import STRAY_SHARE, robust_noise
from stiffness.calibration.pose_campaign import PoseCampaign
from stiffness.calibration.pose_fit import PoseFit, noise_terms
from stiffness.calibration.pose_model_file import parameter_table, write_pose_model
from stiffness.calibration.pose_page import render_pose_diagnosis, stage_plot
from stiffness.calibration.pose_parameters import PoseJudge
from stiffness.calibration.pose_plausibility import Plausibility, plausibility
from stiffness.calibration.residual_figures import residual_axes_png
from stiffness.calibration.result import DiagnosisResult, Output, written
from stiffness.calibration.search import Step
from stiffness.calibration.selection import Noise, NoiseTerms, above_noise, excluded_note
from stiffness.elastic.effects.base import Parameter
from stiffness.files import jsonable
from stiffness.provenance import provenance

#: The families every pose diagnosis starts with (the tracker's placement and the markers).
BASE_FAMILIES = ("frame", "markers")
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
        declared noise), in words; where it does not, where the residual sits (RMS by marker
        and axis, the strongest trend along the rows) and the poses flagged as outliers."""
        p = self.gof()
        if p is None:
            return ("noise not declared: whether the final model explains the data to noise "
                    "cannot be said; declare [measurement] noise_std")
        left_out = excluded_note(self.final_terms.excluded)
        if not self.unexplained:
            return f"explained to noise (chi-square p = {p:.3g}{left_out})"
        s = marker_structure(self.final, self.campaign)
        trend = max(s["row_trend"].values(), key=lambda t: abs(t["correlation"]), default=None)
        where = ("" if trend is None else
                 f"; strongest trend along the rows: correlation {trend['correlation']:+.2f}")
        marker, axis = (", ".join(f"{k} {v:.3g}" for k, v in s[key].items())
                        for key in ("rms_by_marker", "rms_by_axis"))
        length = self.campaign.units.length
        noise = self.campaign.noise_std or 0.0
        r = self.final.residual
        robust = robust_noise(r[np.isfinite(r)], self.final.n_fitted) or 0.0
        return (f"UNEXPLAINED: the residual is above the noise (chi-square p = {p:.3g}"
                f"{left_out}); RMS "
                f"({length}) by marker {marker}, by axis {axis}{where}"
                + _flagged(len(self.outliers), self.campaign.n_rows, self.loss)
                + f"; or the declared noise_std ({noise / self.campaign.units.length_to_si:.4g}"
                f" {length}) understates the scatter: the final positions' robust std (1.4826 "
                f"median |r|, which gross poses do not inflate) is {robust / noise:.3g} times it, "
                "and a residual without structure (as large on every marker and axis, no trend "
                "along the rows) points there")

    def to_dict(self) -> dict:
        """What ``diagnose --json`` prints for a pose campaign (lengths in the campaign unit;
        an infinite number, a forced family's held-out RMS that one configuration determines,
        as null)."""
        lu = self.campaign.units.length_to_si
        return jsonable({"kind": "poses", "campaign": self.campaign.name,
                "robot_name": self.campaign.robot.title,
                "unit": self.campaign.units.length, "masses": self.masses,
                "loss": self.loss,
                "noise_std": None if self.campaign.noise_std is None
                else self.campaign.noise_std / lu,
                "steps": [{"family": s.effect, "rms": s.fit.rms() / lu,
                           "delta_bic": s.delta_bic, "cv_rms": s.cv_rms / lu,
                           "n_parameters": s.fit.n_fitted, "converged": s.fit.converged,
                           "forced": s.forced, "removed": s.removed, **self._named(s),
                           **({"validation": s.validation} if s.validation else {})}
                          for s in self.steps],
                "rejected": self.rejected, "not_judged": self.not_judged,
                "families": self.families,
                "stop_reason": self.stop_reason,
                "selection": self.selection(),
                "gof_p": self.gof(), "unexplained": self.unexplained,
                "final_rows_excluded": self.final_terms.excluded,
                "plausible": self.plausibility.plausible,
                "plausibility": self.plausibility.to_dict(),
                **self.outlier_keys(), "identifiability": self.identifiability(),
                "parameters": parameter_table(self.final, self.judge),
                "how_sure": [c.to_dict(lu) for c in self.how_sure],
                "residual_structure": marker_structure(self.final, self.campaign)})

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


def _flagged(n: int, rows: int, loss: str) -> str:
    """The verdict's word on ``n`` poses of ``rows`` flagged as outliers: a few can fail the
    test alone (least squares: a robust loss's test leaves them out); more than
    :data:`~stiffness.calibration.outliers.STRAY_SHARE` of the poses are a pattern the model
    misses (a robust loss's test keeps them), unless (least squares) a few gross poses pulled
    the fit onto the others, which a robust loss tells."""
    if not n:
        return ""
    if n > STRAY_SHARE * rows:
        return (f"; {n} of {rows} poses are flagged as outliers (see outliers): too many for "
                "stray measurements, the model misses something"
                + (", unless a few gross poses pull the least-squares fit onto the others: "
                   "--loss soft_l1 flags those alone" if loss == "linear" else ""))
    return (f"; {n} of {rows} poses are flagged as outliers, which alone can fail the test"
            if loss == "linear" else "")


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
