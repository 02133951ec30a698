"""A pose fit's parameters as the naming rules read them (:mod:`stiffness.calibration.naming`):
each family's parameters with their 95 % intervals, judged against their physical scales.

The physical scale of each parameter is its family's (:meth:`~stiffness.elastic.effects.
pose_face.PoseFamily.physical_sizes`) on the campaign's references
(:class:`~stiffness.elastic.effects.geometry.References`), the ones deflection campaigns judge
the same effects by:

* ``k_ref``, the stiffness compliances are measured against
  (:func:`reference_stiffness`): the geometric mean of the joint stiffnesses the fit
  determines when ``joint_compliance`` is in its model, by the one rule of both campaign
  kinds (:func:`~stiffness.calibration.fitting.typical_stiffness`): a spring fitted, off its
  bound, its compliance's 95 % interval excluding zero (a finite stiffness interval); a
  joint the data do not move or cannot tell from rigid sets no scale. Else the geometric
  mean of the robot's declared ``k_theta_SI``, else
  :data:`~stiffness.calibration.fitting.NOMINAL_STIFFNESS`: a joint, link or bearing
  compliance's scale is ``10 / k_ref``;
* the torques each spring carries at the commanded poses under the nominal robot (gravity and
  the applied wrench): the typical joint deflection ``theta_ref`` (RMS torque over ``k_ref``),
  whose ten times is a backlash's scale; the largest, ``tau_max``: a nonlinear spring's
  ``gamma`` scale ``1 / (k_ref tau_max)`` (the compliance doubled at ``tau_max``);
* the torques the links' weight puts on each joint at those poses (the nominal inertias): a
  compensator's preload and stiffness balance at most the largest of its joint's
  (:meth:`~stiffness.elastic.effects.preloads.GravityCompensator.physical_scale`); with the
  masses unknown that weight is not trusted and the compensator takes the joint spring's
  scales instead;
* the robot's reach (:func:`~stiffness.robot.kinematics.reach`): a marker's offset
  (a marker farther than that from where the campaign puts it is not on the robot) and a
  prismatic joint's zero offset; a revolute joint's zero offset: half a turn (pi rad, beyond
  it another zero, not an error);
* the other geometric families: 100 times their typical size (0.1 m, 0.1 rad).

SI throughout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stiffness.calibration.fitting import NOMINAL_STIFFNESS, typical_stiffness
from stiffness.calibration.naming import one_sided
from stiffness.calibration.pose_campaign import PoseCampaign
from stiffness.calibration.pose_fit import PoseFit, rows_of
from stiffness.calibration.pose_model import PoseModel
from stiffness.elastic.effects.base import Parameter, judged
from stiffness.elastic.effects.geometry import References, rms_force, weight_torques
from stiffness.mechanics.defaults import default_stiffness
from stiffness.robot.kinematics import reach

#: The family whose fitted compliances give ``k_ref`` (module docstring).
SPRINGS = "joint_compliance"


@dataclass
class PoseJudge:
    """What a pose campaign gives the physical scales: the joints' torques at its commanded
    poses under the nominal robot (rows, nv; N.m, N), its RMS applied force (N), the
    weight's part of those torques (rows, nv; N.m, N) and whether the robot's link masses
    are ``known`` or ``unknown`` (unknown: nothing is judged against that weight)."""

    torques: np.ndarray
    force_rms: float
    weight: np.ndarray
    masses: str = "known"

    @classmethod
    def of(cls, campaign: PoseCampaign, masses: str = "known") -> PoseJudge:
        """The judge of ``campaign``'s fits, its robot's link masses ``masses``."""
        nominal = PoseModel(campaign.robot, campaign.markers, (), (np.eye(3), np.zeros(3)),
                            campaign.loads)
        rows = rows_of(nominal, campaign)
        force = (np.zeros((1, 3)) if campaign.loads is None
                 else np.asarray(campaign.loads.wrench)[:, :3])
        return cls(nominal.nominal_torques(rows), rms_force(force),
                   nominal.nominal_torques(rows, wrench=False), masses)

    def references(self, fit: PoseFit) -> References:
        """The references of ``fit``'s physical scales (module docstring), over its model's
        springs."""
        model = fit.model
        pin_model = model.robot.model
        single = [j for j in range(1, pin_model.njoints) if pin_model.joints[j].nv == 1]
        weight = weight_torques([pin_model.names[j] for j in single],
                                self.weight[:, [pin_model.joints[j].idx_v for j in single]],
                                self.masses)
        # and on each controller coordinate's spring: what it carries, S^T tau
        carried = weight_torques(model.springs, self.weight @ model.spring_map, self.masses)
        weight.update({k: v for k, v in carried.items() if k not in weight})
        return References.scaled(tuple(model.springs), reference_stiffness(fit),
                                 self.torques @ model.spring_map, self.force_rms, 1e-12, weight,
                                 reach(pin_model))

    def parameters(self, fit: PoseFit) -> dict[str, list[Parameter]]:
        """Each family's parameters in ``fit`` (by family name, in the model's order) with
        their 95 % intervals, judged against their physical scales; a parameter the fit did
        not move is held with why, one at its physical bound one-sided."""
        model, refs = fit.model, self.references(fit)
        lo, hi = fit.interval()
        std = fit.std()
        z = fit.noise.two_sided()
        labels = fit.labels()
        out: dict[str, list[Parameter]] = {}
        for family in model.family_objects:
            cut = model.slices()[family.name]
            sizes = family.physical_sizes(model, refs)
            params = []
            for i, size in zip(range(cut.start, cut.stop), sizes, strict=True):
                p = model.parameters[i]
                dropped = fit.identifiability.dropped_at(i)
                if dropped is not None:
                    params.append(Parameter(p.label, float(fit.x[i]), math.nan,
                                            (math.nan, math.nan), p.unit).held_as(
                                                dropped.describe(labels)))
                    continue
                q = judged(p.label, float(fit.x[i]), float(std[i]),
                           (float(lo[i]), float(hi[i])), p.unit, float(size), z)
                params.append(one_sided(q, True) if i in fit.at_bound else q)
            out[family.name] = params
        return out


def reference_stiffness(fit: PoseFit) -> float:
    """``k_ref`` (N.m/rad) of ``fit``'s physical scales (module docstring): the geometric mean
    of the joint stiffnesses it determines (:func:`~stiffness.calibration.fitting.
    typical_stiffness`, the one rule of both campaign kinds), those fitted, off their bound
    and with a compliance whose 95 % interval excludes zero; else the robot's declared
    springs', else :data:`~stiffness.calibration.fitting.NOMINAL_STIFFNESS`.

    It was one over the median of the fitted positive compliances: on a UR10 with one true
    spring of 2e4 N.m/rad, elbow and wrist_1 nearly rigid (8.5e-8 and 3.2e-6 rad/(N.m), both
    intervals reaching zero), the median was wrist_1's, ``k_ref`` 3.1e5, the scale 3.2e-5,
    and the true 5e-5 rad/(N.m) spring was called a stand-in, "its size not physical"."""
    model = fit.model
    declared = default_stiffness(model.robot)
    nominal = (declared if declared is not None and np.all(declared > 0)
               else [NOMINAL_STIFFNESS])
    if SPRINGS not in model.families:
        return typical_stiffness([], [], [], nominal)
    cut = model.slices()[SPRINGS]
    kept = set(fit.identifiability.kept)
    fitted = [i - cut.start for i in range(cut.start, cut.stop)
              if i in kept and i not in fit.at_bound]
    return typical_stiffness(fit.x[cut], fit.interval()[0][cut], fitted, nominal)
