"""The units of a model file checked against its robot's joints: ``k_theta``'s (one per
compliant joint) and its joint effects' parameters whose kind follows the joint's (a
``joint_compliance``'s stiffness, a ``backlash``'s half width, a
``nonlinear_joint_stiffness``'s beta), and a ``gravity_compensator``'s linear spring (N/m). A
value of the wrong kind (N.m/rad on a prismatic joint, N/m on a revolute one) would load
silently and give wrong numbers; the effects' parameters may also say ``"SI"``, the joint's own
kind.
"""

from __future__ import annotations

from collections.abc import Callable

from stiffness.units import wrong_stiffness_unit

#: SI unit of an effect's parameter by the kind of its joint: (revolute, prismatic).
_JOINT_KIND_UNITS = {("joint_compliance", "stiffness"): ("N.m/rad", "N/m"),
                     ("backlash", "half_width"): ("rad", "m"),
                     ("nonlinear_joint_stiffness", "beta"): ("1/(N.m)", "1/N")}

#: SI unit of an effect's parameter whatever its joint: a gravity compensator's spring is a
#: linear spring on a lever (N/m, on a revolute joint).
_FIXED_UNITS = {("gravity_compensator", "stiffness"): "N/m"}


def wrong_model_stiffness_unit(model, prismatic: Callable[[str], bool]) -> str | None:
    """The one-line problem (where, the unit found, the unit expected, the fix) of a model
    file's first unit that is not of its joint's kind, or ``None``.

    Parameters
    ----------
    model
        The model file (:class:`stiffness.elastic.model_contents.ModelFile`): its
        ``compliant_joints``, their ``units`` and its ``effects``.
    prismatic
        Whether a joint of the model's robot is prismatic (``Robot.is_prismatic``).
    """
    if problem := wrong_stiffness_unit(model.compliant_joints, model.units, prismatic):
        return problem
    for i, effect in enumerate(model.effects):
        for p in effect.parameters:
            key, what = (effect.name, p.name), f"effects[{i}] ({effect.label}) {p.name}"
            if p.unit == "SI" or (key not in _JOINT_KIND_UNITS and key not in _FIXED_UNITS):
                continue
            if key in _FIXED_UNITS:
                expected, why = _FIXED_UNITS[key], "the compensator's linear spring"
            else:
                kind = "prismatic" if prismatic(str(effect.where)) else "revolute"
                expected = _JOINT_KIND_UNITS[key][kind == "prismatic"]
                why = f"of {kind} joint {str(effect.where)!r}"
            if p.unit != expected:
                return (f"{what} is in {p.unit!r}, expected {expected!r} ({why}); the value is "
                        f"of another kind: give it in {expected} or \"SI\", or rewrite the file "
                        "with `stiffness diagnose` on this robot")
    return None
