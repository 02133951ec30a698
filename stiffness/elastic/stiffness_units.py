"""The stiffness units of a model file checked against its robot's joints: ``k_theta``'s (one
per compliant joint) and its effects' ``stiffness`` parameters (a ``joint_compliance``'s spring
on the joint it names; a ``gravity_compensator``'s linear spring, N/m). A stiffness of the wrong
kind (N.m/rad on a prismatic joint, N/m on a revolute one) would load silently and give wrong
numbers; the effects' parameters may also say ``"SI"``, the joint's own kind.
"""

from __future__ import annotations

from collections.abc import Callable

from stiffness.units import JOINT_STIFFNESS_UNITS, wrong_stiffness_unit

#: Unit of the ``stiffness`` parameter of effects whose spring is not the joint's: a
#: gravity compensator's is a linear spring on a lever (N/m, on a revolute joint).
_FIXED_STIFFNESS_UNITS = {"gravity_compensator": "N/m"}


def wrong_model_stiffness_unit(model, prismatic: Callable[[str], bool]) -> str | None:
    """The one-line problem (where, the unit found, the unit expected, the fix) of a model
    file's first stiffness unit that is not of its joint's kind, or ``None``.

    Parameters
    ----------
    model
        The model file (:class:`stiffness.elastic.model_file.ModelFile`): its
        ``compliant_joints``, their ``units`` and its ``effects``.
    prismatic
        Whether a joint of the model's robot is prismatic (``Robot.is_prismatic``).
    """
    if problem := wrong_stiffness_unit(model.compliant_joints, model.units, prismatic):
        return problem
    for i, effect in enumerate(model.effects):
        for p in effect.parameters:
            if p.name != "stiffness" or p.unit == "SI":
                continue
            what = f"effects[{i}] ({effect.label}) stiffness"
            fixed = _FIXED_STIFFNESS_UNITS.get(effect.name)
            if fixed is None:
                problem = wrong_stiffness_unit([str(effect.where)], [p.unit], prismatic, what,
                                               "`stiffness diagnose`")
            elif p.unit != fixed:
                kinds = " or ".join(JOINT_STIFFNESS_UNITS.values())
                problem = (f"{what} is in {p.unit!r}, expected {fixed!r} (the compensator's "
                           f"linear spring, not the joint's {kinds}); give it in {fixed}")
            if problem:
                return problem
    return None
