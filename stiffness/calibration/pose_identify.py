"""Joint stiffness from a pose campaign (``stiffness identify`` on a tracker's marker positions).

Identification is a diagnosis with no effects, for either campaign kind: on a deflection
campaign the baseline's stiffnesses alone (:func:`stiffness.calibration.identify.identify`);
on a pose campaign the pose diagnosis's baseline (measuring frame, marker offsets) with the
springs forced in and nothing searched, :func:`~stiffness.calibration.pose_diagnose.
diagnose_poses` with ``families=["joint_compliance"]`` and ``max_steps=0``: the same fit, the
same naming rules and the same outlier flags as ``diagnose``. The springs' compliances ``c``
are fitted under gravity and the applied wrench at the sag's fixed point
(:class:`~stiffness.calibration.pose_model.PoseModel`); each spring's stiffness ``k = 1 / c``
is reported with its compliance's 95 % interval carried to ``k``
(:func:`~stiffness.elastic.effects.base.reciprocal`), as a deflection identification reports
it; a compliance at its bound, zero, is "rigid to the data", its interval one-sided.

The chi-square verdict says whether the nominal geometry with these springs explains the
measured poses to their noise. Where it does not, the stiffnesses have absorbed what the model
misses (joint offsets, joint placements, bends), and ``stiffness diagnose`` finds that.

SI inside (m, N, rad, N.m/rad, N/m).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from stiffness.calibration.fit_verdict import verdict_line
from stiffness.calibration.outliers import describe_outliers, outlier_keys
from stiffness.calibration.pose_campaign import PoseCampaign, loads_no_spring
from stiffness.calibration.pose_diagnose import diagnose_poses
from stiffness.calibration.pose_diagnosis import PoseDiagnosis
from stiffness.calibration.pose_model_file import parameter_table
from stiffness.calibration.pose_parameters import SPRINGS
from stiffness.calibration.result import IdentificationResult
from stiffness.calibration.selection import material_holders
from stiffness.elastic.effects.base import Parameter, reciprocal
from stiffness.elastic.effects.pose_face import compliance_label
from stiffness.errors import StiffnessError
from stiffness.files import jsonable

#: A compliance's unit -> its stiffness's.
STIFFNESS_UNITS = {"rad/(N.m)": "N.m/rad", "m/N": "N/m"}


@dataclass
class PoseIdentification(IdentificationResult):
    """The springs' stiffnesses identified from a pose campaign, with the fit behind them
    (:attr:`diagnosis`: its baseline and the forced ``joint_compliance`` step) and the model
    file :meth:`write_model` wrote (``model_path``, ``None`` before): an
    :class:`~stiffness.calibration.result.IdentificationResult`, as a deflection campaign's."""

    diagnosis: PoseDiagnosis

    @property
    def stiffnesses(self) -> list[Parameter]:
        """Each spring's stiffness (N.m/rad or N/m, by joint name) with its 95 % interval,
        from its compliance's (:func:`~stiffness.elastic.effects.base.reciprocal`)."""
        d = self.diagnosis
        assert d.judge is not None  # every pose diagnosis has its campaign's judge
        springs = {p.name: p for p in d.judge.parameters(d.final).get(SPRINGS, [])}
        out = []
        for joint in d.final.model.springs:
            c = springs[compliance_label(joint)]
            out.append(replace(reciprocal(c, STIFFNESS_UNITS[c.unit]), name=joint))
        return out

    def merged_with(self) -> dict[str, list[dict]]:
        """Joint -> the parameters merged into its spring's compliance (``parameter``, its
        label; ``coefficient``: the kept compliance absorbs that times the merged parameter,
        :attr:`~stiffness.calibration.identifiability.Dropped.merged_into`), for each spring
        that carries a merge: its fitted value is that combination, not its own stiffness.
        Springs that carry none are left out."""
        fit = self.diagnosis.final
        labels = fit.labels()
        out: dict[str, list[dict]] = {}
        for joint in fit.model.springs:
            column = labels.index(compliance_label(joint))
            carried = [{"parameter": labels[d.index], "coefficient": c}
                       for d in fit.identifiability.dropped if d.reason == "merged"
                       for i, c in d.merged_into if i == column]
            if carried:
                out[joint] = carried
        return out

    def conditional_on(self) -> dict[str, list[str]]:
        """Joint -> the parameters at their physical bound (a rigid spring's compliance at 0:
        its joint's name; else its label) its spring's estimate and interval are conditional
        on, held there: those that hold an end of its interval and move it materially
        (:func:`~stiffness.calibration.selection.material_holders`, the rule of both campaign
        kinds). Springs conditional on none, at their bound or not fitted are left out."""
        fit = self.diagnosis.final
        labels, kept = fit.labels(), list(fit.identifiability.kept)
        joints = {compliance_label(j): j for j in fit.model.springs}
        bound = [kept.index(i) for i in fit.at_bound if i in kept]
        out: dict[str, list[str]] = {}
        for joint in fit.model.springs:
            column = labels.index(compliance_label(joint))
            if not bound or column not in kept or column in fit.at_bound:
                continue
            on = material_holders(fit.covariance, kept.index(column), bound,
                                  np.ones(len(bound)))
            names = [joints.get(labels[kept[b]], labels[kept[b]])
                     for b, named in zip(bound, on, strict=True) if named]
            if names:
                out[joint] = names
        return out

    def no_freedom(self) -> bool:
        """Whether the fit has no residual freedom (measured components no more than fitted
        parameters, which diagnose refuses): nothing in the data tests a bound it holds a
        spring's estimate on, so such a spring is undetermined (:meth:`conditional_on`)."""
        fit = self.diagnosis.final
        return fit.n_observed <= fit.n_fitted

    def write_model_file(self, path: Path) -> Path:
        """Write the pose model file of the fit atomically (:meth:`PoseDiagnosis.write_model`);
        returns its path."""
        return self.diagnosis.write_model(path)

    def to_dict(self) -> dict:
        """What ``stiffness identify --json`` prints for a pose campaign (SI): the keys of a
        deflection identification where they mean the same (``joints`` with ``k``,
        ``unit``, ``standard_error``, ``ci95``, ``relative_ci_width``, ``determined``), and
        the pose fit's (``families``, ``parameters``, ``gof_p``, ``unexplained``, and
        ``final_rows_excluded``: the poses its test left out, a robust loss's). A spring
        whose compliance carries merged parameters has ``merged_with`` (:meth:`merged_with`,
        the form of ``identifiability.dropped[].merged_into``): its ``k`` is that
        combination's, not the joint's stiffness, so it is not ``determined``."""
        d, fit = self.diagnosis, self.diagnosis.final
        merged = self.merged_with()
        conditional = self.conditional_on()
        unsure = set(merged) | (set(conditional) if self.no_freedom() else set())
        return jsonable({
            "kind": "poses", "campaign": d.campaign.name,
            "robot": {"name": d.campaign.robot.title,
                      "compliant_joints": list(fit.model.springs)},
            "families": d.families, "loss": d.loss,
            "joints": [{"joint": p.name, "k": p.value, "unit": p.unit,
                        "standard_error": p.standard_error, "ci95": list(p.ci95),
                        "relative_ci_width": (p.ci95[1] - p.ci95[0]) / p.value,
                        "determined": p.determined and p.name not in unsure,
                        "conditional_on": conditional.get(p.name, []),
                        "at_bound": p.at_bound,
                        "held": p.held or None,
                        **({"merged_with": merged[p.name]} if p.name in merged else {})}
                       for p in self.stiffnesses],
            "undetermined_joints": [p.name for p in self.stiffnesses
                                    if not p.determined or p.name in unsure],
            "sigma_m": fit.sigma, "sigma_source": fit.sigma_source, "rms_m": fit.rms(),
            "gof_p": d.gof(), "unexplained": d.unexplained,
            "final_rows_excluded": d.final_terms.excluded,
            "plausible": d.plausibility.plausible, "plausibility": d.plausibility.to_dict(),
            "n_residuals": fit.n_observed, "n_parameters": fit.n_fitted,
            "n_rows": d.campaign.n_rows, **outlier_keys(d.outliers, d.outlier_sigma_m),
            "parameters": parameter_table(fit, d.judge),
            "model_file": None if self.model_path is None else str(self.model_path)})

    def format(self) -> str:
        """The human-readable report (SI)."""
        d, fit = self.diagnosis, self.diagnosis.final
        c = d.campaign
        lines = [f"pose campaign {c.name} of {c.robot.title}: {c.n_rows} poses, "
                 f"{len(c.markers)} marker(s), {fit.n_observed} measured components, "
                 f"{fit.n_fitted} parameters ({', '.join(d.families)}); loss {d.loss}",
                 "the springs' stiffness with the measuring frame and markers, nothing else "
                 "fitted (stiffness diagnose searches the rest)", ""]
        verdict = d.plausibility.verdict()
        if verdict is not None:  # a unit read wrong: no diagnosis finds what is missing
            lines += [verdict, "NOT TO BE TRUSTED: these stiffnesses take what the robot's "
                      "kinematics cannot (above), whatever the verdict below"]
        elif d.unexplained:
            lines.append("NOT TO BE TRUSTED: the model does not explain the poses (verdict "
                         "below); these stiffnesses take what it misses")
        merged, conditional = self.merged_with(), self.conditional_on()
        lines += [f"  {_carrying(p, merged[p.name]) if p.name in merged else p.text()}"
                  + (_conditional(conditional[p.name], fit.n_observed, fit.n_fitted)
                     if p.name in conditional else "") for p in self.stiffnesses]
        lines += ["", f"RMS {fit.rms():.4g} m per component; sigma {fit.sigma:.4g} m "
                      f"({fit.sigma_source}); "
                  + verdict_line({**d.verdict_keys(), "searched": False})]
        lines += d.plausibility.notes()
        if d.unexplained and verdict is None:
            where = c.name if c.path is None else str(c.path.parent)
            lines.append(f"the stiffnesses absorb what the model misses and their intervals "
                         f"are too narrow; run stiffness diagnose {where} to find it")
        lines += describe_outliers(d.outliers)
        return "\n".join(lines)


def _carrying(p: Parameter, merged: list[dict]) -> str:
    """The line of a spring ``p`` whose compliance carries ``merged`` parameters
    (:meth:`PoseIdentification.merged_with`): its value is said as the combination it is."""
    names = ", ".join(f"{m['coefficient']:.3g} x {m['parameter']}" for m in merged)
    value = "rigid" if math.isinf(p.value) else f"{p.value:.5g} {p.unit}"
    return (f"{p.name}: not its own stiffness: its compliance carries merged parameters "
            f"({names}, SI units), so the fitted {value} is 1 / (its compliance + that "
            "combination), a combination the data do not split")


def _conditional(names: list[str], observed: int, fitted: int) -> str:
    """What a spring's line adds when its estimate is conditional on ``names`` held at their
    bound (:meth:`PoseIdentification.conditional_on`): undetermined with no residual
    freedom (``observed`` components no more than ``fitted`` parameters)."""
    said = f"conditional on {', '.join(names)} held at its bound"
    if observed <= fitted:
        return (f"; undetermined: {said}, with {observed} measured components for {fitted} "
                "parameters (no residual freedom to test that bound)")
    return f" ({said})"


def identify_poses(campaign: PoseCampaign, loss: str = "linear",
                   progress: Callable[[str], None] | None = None) -> PoseIdentification:
    """The springs' stiffnesses from a pose campaign (module docstring).

    Parameters
    ----------
    campaign
        The pose campaign (SI).
    loss
        ``linear`` (least squares) or a robust loss of
        :data:`~stiffness.calibration.solver.LOSSES`, as ``diagnose --loss``.
    progress
        Called with a line of text as each fit starts (``None``: quiet).

    Raises
    ------
    StiffnessError
        An unknown loss; a robot whose springs the campaign cannot load (no masses and no
        applied wrench: ``joint_compliance`` has no parameter).
    """
    _check_loaded(campaign)
    return PoseIdentification(diagnose_poses(campaign, loss=loss, families=[SPRINGS],
                                             max_steps=0, progress=progress))


def _check_loaded(campaign: PoseCampaign) -> None:
    """Refuse a campaign that loads no spring: a robot whose links have no mass (a URDF
    without ``<inertial>``) measured under no applied wrench. Every stiffness would have no
    effect on the data and the report would list each joint "not fitted"."""
    if not loads_no_spring(campaign):
        return
    raise StiffnessError(
        f"{campaign.robot.title}'s file gives its links no mass and the campaign applies no "
        "load: gravity bends no joint, so these poses hold nothing of the springs' stiffness; "
        "give the links' masses (the robot file's <inertial>) or measure under known loads "
        "(fx, fy, fz columns); stiffness diagnose calibrates the geometry")
