"""The parameter families of the pose model (absolute-pose calibration), one class per family,
listed in :data:`FAMILIES` (docs/absolute-poses.md).

Adding a family is one class (a :class:`~stiffness.calibration.pose_families.base.PoseFamily`
with its parameters, its part of the prediction and its Jacobian columns), listed here, and its
test. The elastic families carry the names of the deflection library's effects
(:data:`stiffness.elastic.effects.LIBRARY`) and reuse their mathematics.

``frame``, ``markers``, ``joint_offsets``, ``geometry`` (geometric:
:mod:`~stiffness.calibration.pose_families.geometric`); ``joint_compliance``,
``gravity_lumped``, ``backlash``, ``gravity_compensator`` (elastic, through the joints:
:mod:`~stiffness.calibration.pose_families.elastic`); ``link_compliance`` (elastic, the links
bending: :mod:`~stiffness.calibration.pose_families.bends`). ``link_compliance`` and
``backlash`` need the links' masses (not with ``gravity_lumped``); ``gravity_compensator``
acts through ``joint_compliance``.
"""

from __future__ import annotations

from stiffness.calibration.pose_families.base import PoseFamily
from stiffness.calibration.pose_families.bends import LinkCompliancePose
from stiffness.calibration.pose_families.elastic import (
    BacklashPose,
    CompensatorPose,
    GravityLumped,
    JointCompliancePose,
)
from stiffness.calibration.pose_families.geometric import (
    JointGeometry,
    JointOffsets,
    MarkerOffsets,
    MeasuringFrame,
)

#: Family name -> class, in the order the columns are laid out.
FAMILIES: dict[str, type[PoseFamily]] = {
    cls.name: cls for cls in (MeasuringFrame, MarkerOffsets, JointOffsets, JointGeometry,
                              JointCompliancePose, GravityLumped, LinkCompliancePose,
                              BacklashPose, CompensatorPose)
}
