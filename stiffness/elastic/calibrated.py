"""The elastic part of a pose calibration: its springs and effects, as a model file holds them.

A pose calibration's ``final-model.json`` (:mod:`stiffness.robot.calibration`) is a model
file like the others (:func:`stiffness.elastic.model_file.read_model_file`): its robot is the
calibrated robot (the file itself as a robot source), and its elastic families become the
deflection library's effects (:data:`stiffness.elastic.effects.LIBRARY`), whose names they carry:

``joint_compliance``
    each spring's compliance ``c`` (rad/(N.m), m/N) becomes its stiffness ``1/c`` (standard
    error ``s_c / c^2``, 95 % interval ``[1/c_high, 1/c_low]``); a spring the campaign did not
    determine (not fitted, or ``c <= 0``) is held rigid and listed as undetermined;
``gravity_preload``
    with the masses known the springs carried the robot's weight in the calibration, so the
    weight preloads them (no payload); not on a robot with closed loops, which the elastic
    model does not weigh (:attr:`CalibratedElastics.weight_left_out` says so when it weighs
    something);
``backlash``, ``link_compliance``, ``transversal_compliance``, ``gravity_compensator``
    the same effects, with the calibration's smoothing torques, ``1/c`` bend and bearing-tilt
    stiffnesses (a bend or a tilt off the target's chain does not act on it), and the
    compensator's geometry (the default one, or its declared lever and base) with its angle
    from the link's upward direction, as the calibration used them (the upward angle less
    the joint's zero offset: the calibrated robot's joint angles are the commanded ones).
``nonlinear_joint_stiffness``
    each determined spring's compliance per unit torque ``gamma`` (rad/(N.m)^2, m/N^2)
    becomes the deflection library's ``beta = gamma / c`` (1/(N.m), 1/N), with the spring's
    compliance ``c``: ``dtheta = tau / k (1 + beta |tau|)``; its standard error and interval
    are ``gamma``'s over ``c`` (``c``'s own uncertainty left out).

``gravity_lumped`` (masses unknown) is compliance times unknown masses: no stiffness, so a
calibration with it (and no ``joint_compliance``) has no springs. The families of
:data:`NOT_CARRIED` (the base's tilt) have no effect of the deflection library: they are
listed in :attr:`CalibratedElastics.left_out` (the reader warns). Units: SI.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from stiffness.elastic.effects import FAMILIES, make_effect
from stiffness.elastic.effects.base import Parameter
from stiffness.elastic.effects.geometry import Geometry
from stiffness.elastic.effects.pose_face import (
    BACKLASH_SETTING,
    backlash_label,
    bend_label,
    compensator_label,
    compliance_label,
    nonlinear_label,
    tilt_label,
)
from stiffness.elastic.effects.preloads import GravityCompensator
from stiffness.robot.calibration import PoseCalibration, zero_label
from stiffness.robot.robot import load_robot

#: Pose families with no deflection-library effect: the elastic model built from a calibration
#: leaves them out (a stiffness prediction then takes gravity along the base's -z).
NOT_CARRIED = ("base_tilt",)


@dataclass
class CalibratedElastics:
    """The springs and effects of a pose calibration (SI).

    Attributes
    ----------
    stiffness
        One :class:`Parameter` per determined spring (named by its joint), N.m/rad or N/m.
    effects
        ``(name, where, parameters, settings)`` of each library effect.
    undetermined
        Springs the calibration did not determine, held rigid.
    left_out
        Families of the calibration the elastic model does not carry (:data:`NOT_CARRIED`).
    no_spring
        Without springs, why, naming the fix (one line); else "".
    """

    stiffness: list[Parameter] = field(default_factory=list)
    effects: list[tuple[str, str | None, list[Parameter], dict]] = field(default_factory=list)
    undetermined: list[str] = field(default_factory=list)
    left_out: list[str] = field(default_factory=list)
    no_spring: str = ""
    #: why the robot's weight does not preload the springs, or "" (it does, or it weighs
    #: nothing): the elastic model weighs no closed loop
    weight_left_out: str = ""
    #: the fitted joint laws (backlash, nonlinear spring) of springs held rigid, not carried
    with_rigid: list[str] = field(default_factory=list)

    def rigid_note(self) -> str:
        """The springs held rigid, and their fitted joint laws left out with them (one line)."""
        laws = f"; {', '.join(self.with_rigid)} left out with them" if self.with_rigid else ""
        return (f"the compliance of {', '.join(self.undetermined)} is not determined by the "
                f"calibration: held rigid{laws}")


def calibrated_elastics(cal: PoseCalibration) -> CalibratedElastics:
    """The springs and effects of the calibration ``cal`` (module docstring)."""
    rows = {p["parameter"]: p for p in cal.parameters}
    out = CalibratedElastics(left_out=[f for f in NOT_CARRIED if f in cal.families],
                             no_spring=_no_spring(cal))
    if "joint_compliance" not in cal.families:
        return out
    for joint in cal.compliant_joints:
        row = rows.get(compliance_label(joint))
        unit = "N/m" if row is not None and row.get("unit") == "m/N" else "N.m/rad"
        k = None if row is None else _inverse(row, joint, unit)
        if k is None:
            out.undetermined.append(joint)
        else:
            out.stiffness.append(k)
    springs = {p.name for p in out.stiffness}
    if not springs:
        out.no_spring = (f"the calibration determined none of the joint compliances "
                         f"({', '.join(out.undetermined)}); a campaign whose poses or payload "
                         "load the joints more determines them")
    robot = load_robot(cal.source, fixed_base=cal.fixed_base)
    if "gravity_lumped" not in cal.families and not robot.loop.is_open_chain:
        weight = sum(inertia.mass for inertia in robot.model.inertias)
        out.weight_left_out = "" if weight == 0.0 else (
            f"the weight of {robot.title} ({weight:.4g} kg) is not carried into the elastic "
            "model, which weighs no closed loop: its predictions leave gravity's preload out")
    elif "gravity_lumped" not in cal.families:
        out.effects.append(("gravity_preload", None, [
            Parameter(n, 0.0, 0.0, (0.0, 0.0), u)
            for n, u in zip(("mass", "com_x", "com_y", "com_z"), ("kg", "m", "m", "m"),
                            strict=True)], {}))
    smoothing = cal.settings.get(BACKLASH_SETTING, {})
    for joint in cal.compliant_joints:  # in the springs' order
        row = rows.get(backlash_label(joint))
        if row is not None and joint in springs and joint in smoothing:
            out.effects.append(("backlash", joint, [_as_is(row, "half_width")],
                                {"smoothing_torque": float(smoothing[joint])}))
    for joint in [j for j in cal.compliant_joints if j in springs]:
        row = rows.get(nonlinear_label(joint))
        if row is not None and row.get("fitted", True):
            out.effects.append(("nonlinear_joint_stiffness", joint, [
                softening(row, float(rows[compliance_label(joint)]["value"]))], {}))
    out.with_rigid = [f"{name}({joint})" for joint in out.undetermined
                      for name, row in (("backlash", rows.get(backlash_label(joint))),
                                        ("nonlinear_joint_stiffness",
                                         rows.get(nonlinear_label(joint))))
                      if row is not None and row.get("fitted", True) and row["value"] != 0.0]
    if {"gravity_compensator", "link_compliance", "transversal_compliance"} & set(cal.families):
        _geometry_effects(cal, rows, springs, out)
    return out


def _no_spring(cal: PoseCalibration) -> str:
    """Why a calibration without ``joint_compliance`` has no spring, naming the fix."""
    if "gravity_lumped" in cal.families:
        return ("a calibration with --masses unknown (compliance times unknown masses: no "
                "stiffness); diagnose it with --masses known for the stiffness")
    elastic = [f for f in cal.families if FAMILIES[f].family_kind == "elastic"]
    if elastic:
        return (f"the calibration named {', '.join(elastic)} but no joint_compliance, and the "
                "elastic model rests on joint springs; diagnose it with --families "
                "joint_compliance")
    return ("a calibration of geometry only (no elastic family named); diagnose it with "
            "--masses known, or force the springs with --families joint_compliance")


def _geometry_effects(cal: PoseCalibration, rows: dict[str, dict], springs: set[str],
                      out: CalibratedElastics) -> None:
    """The compensators (their geometry as the calibration built it, on the nominal robot), the
    link bends and the joints' bearing tilts of the target's chain."""
    nominal = load_robot(cal.source, frame=cal.frame, target_offset=cal.target_offset_m,
                         compliant_joints=cal.compliant_joints, fixed_base=cal.fixed_base)
    geometry = Geometry.of(nominal)
    compensated = springs if "gravity_compensator" in cal.families else set()
    for joint in sorted(compensated, key=list(cal.compliant_joints).index):
        stiff, tension = (rows.get(compensator_label(joint, w)) for w in ("stiffness", "preload"))
        if stiff is None or tension is None:  # a prismatic spring has no compensator
            continue
        spring = make_effect("gravity_compensator", joint, geometry)
        if isinstance(spring, GravityCompensator):
            declared = cal.settings.get(GravityCompensator.GEOMETRY_SETTING, {})
            spring = spring.declare(declared[joint]) if joint in declared else spring
            sole = (None if nominal.coupling is None or joint not in nominal.coupling.coordinates
                    else nominal.coupling.sole_joint(joint))  # a coordinate's: its joint's
            offset = float(rows.get(zero_label(sole or joint), {}).get("value", 0.0))
            settings = {**spring.settings,  # the calibrated robot's angles exclude the offset
                        "angle_up_rad": spring.settings["angle_up_rad"] - offset}
            out.effects.append(("gravity_compensator", joint,
                                [_as_is(stiff, "stiffness"), _as_is(tension, "preload")],
                                settings))
    for a, b in geometry.link_columns:
        pair = [row for row in (rows.get(bend_label(a, b, i)) for i in (1, 2)) if row]
        _add_bend(out, "link_compliance", f"{a}->{b}", pair)
    for joint in geometry.tilt_columns:
        pair = [row for row in (rows.get(tilt_label(joint, i)) for i in (1, 2)) if row]
        _add_bend(out, "transversal_compliance", joint, pair)


def _add_bend(out: CalibratedElastics, name: str, where: str, pair: list[dict]) -> None:
    """The bend ``name`` at ``where`` of its two fitted compliance rows (stiffnesses ``1/c``;
    one not determined is rigid, ``inf``), unless neither is determined."""
    if len(pair) < 2:
        return
    k = [_inverse(row, f"stiffness_{i + 1}", "N.m/rad") for i, row in enumerate(pair)]
    if any(v is not None for v in k):
        out.effects.append((name, where, [
            v or Parameter(f"stiffness_{i + 1}", math.inf, math.nan, (math.nan, math.nan),
                           "N.m/rad") for i, v in enumerate(k)], {}))


def _inverse(row: dict, name: str, unit: str) -> Parameter | None:
    """The stiffness ``1/c`` of a fitted compliance row (delta method), or ``None`` when the
    calibration did not fit it or found it not positive."""
    c = float(row["value"])
    if not row.get("fitted", True) or not c > 0:
        return None
    std = row.get("std")
    low, high = row.get("interval_95") or (math.nan, math.nan)
    se = math.nan if std is None else float(std) / c ** 2
    ci = (1.0 / high if high is not None and high > 0 else math.nan,
          1.0 / low if low is not None and low > 0 else math.inf)
    return Parameter(name, 1.0 / c, se, ci, unit)


def softening(row: dict, c: float) -> Parameter:
    """The deflection library's ``beta = gamma / c`` (1/(N.m), 1/N) of a fitted nonlinear
    spring's row ``gamma`` and its spring's compliance ``c > 0`` (module docstring)."""
    gamma = _as_is(row, "beta")
    unit = "1/N" if gamma.unit == "m/N^2" else "1/(N.m)"
    low, high = gamma.ci95
    return Parameter("beta", gamma.value / c, gamma.standard_error / c, (low / c, high / c),
                     unit)


def _as_is(row: dict, name: str) -> Parameter:
    """A fitted row's value, standard deviation and interval as a library parameter."""
    std = row.get("std")
    low, high = row.get("interval_95") or (None, None)
    return Parameter(name, float(row["value"]), math.nan if std is None else float(std),
                     (math.nan if low is None else float(low),
                      math.nan if high is None else float(high)), str(row.get("unit", "SI")))
