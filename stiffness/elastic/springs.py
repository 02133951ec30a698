"""The joint springs of a model file, as a simulator takes them: one stiffness per joint.

A model file (:func:`stiffness.elastic.model_file.read_model_file`) gives the baseline's
compliant joints and K_theta, and a diagnosis may add ``joint_compliance`` effects (a joint
declared rigid found to be a spring). Other stiffness effects (a link's compliance, a
nonlinear spring, a compensator, backlash) are not joint springs: they are named, not exported.
Measurement effects (how a campaign was observed) are not properties of the robot.
"""

from __future__ import annotations

from stiffness.elastic.effects.parts import ElasticParts
from stiffness.elastic.model_contents import ModelFile

#: Effect kinds that describe the measurement, not the robot.
_MEASUREMENT = "measurement"


def model_springs(model: ModelFile) -> tuple[dict[str, float], list[str]]:
    """The joint springs of ``model`` (N.m/rad or N/m by joint name) and the labels of its
    robot effects that are not joint springs (left out of an export). Each effect says what it
    is through its class's one hook (:meth:`stiffness.elastic.effects.base.Effect.contribute`):
    those that add a spring are joint springs."""
    parts = ElasticParts({name: float(k) for name, k in zip(model.compliant_joints,
                                                            model.k_theta, strict=True)})
    left_out = []
    for effect in model.effects:
        before = len(parts.springs)
        effect.effect().contribute(effect.values(), parts)
        if len(parts.springs) == before and effect.kind != _MEASUREMENT:
            left_out.append(effect.label)
    return parts.springs, left_out
