"""Effects on the target and the measurement: ``target_offset`` (the target is elsewhere),
``frame_misalignment`` (the instrument's frame is rotated), ``force_sensor_bias`` (the recorded
force is offset) and ``deflection_offset`` (the measured deflections are offset).

A target offset changes the robot (its target moves); the other three describe how the
campaign observed the deflection and do not act on a robot used away from its campaign.

Units: SI (m, rad, N).
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from stiffness.elastic.effects.deflection_face import DeflectionEffect
from stiffness.elastic.effects.geometry import rotation_matrix

_DIAGONAL = np.ones(3) / math.sqrt(3.0)


def diagonal_vector(values: tuple[float, ...]) -> np.ndarray:
    """Three values as given, or one value along (1, 1, 1)/sqrt(3)."""
    return values[0] * _DIAGONAL if len(values) == 1 else np.array(values, dtype=float)


class VectorEffect(DeflectionEffect):
    """An effect of one three-vector in the campaign's unit of :attr:`quantity` (``angle``,
    ``length`` or ``force``: :class:`stiffness.units.Units`): ``stiffness simulate`` takes its
    three values, or one along (1, 1, 1)/sqrt(3)."""

    quantity: ClassVar[str] = "length"
    value_counts = (1, 3)

    def simulated_values(self, values, units):
        return diagonal_vector(values) * getattr(units, f"{self.quantity}_to_si")

    def scale(self, refs):
        return np.full(3, 0.01)  # 10 mrad, 10 mm

    def units(self, units):
        return [(getattr(units, self.quantity),
                 getattr(units, f"{self.quantity}_to_si"))] * 3


class FrameMisalignment(VectorEffect):
    """Measured ``dx = R(phi) dx_model``."""

    name = "frame_misalignment"
    kind = "measurement"
    param_names = ("rx", "ry", "rz")
    quantity = "angle"

    def contribute(self, values, parts):
        parts.measure(self.label, rotation=values[:3])

    def output_map(self, p):
        return rotation_matrix(p), None

    def describe(self) -> str:
        return "the instrument's frame is rotated against the robot base"


class TargetOffset(VectorEffect):
    """The target is ``delta`` (target frame axes) away from the declared one."""

    name = "target_offset"
    param_names = ("dx", "dy", "dz")

    def contribute(self, values, parts):
        parts.shift_target(self.label, values[:3])

    def physical_scale(self, refs):
        """The robot's reach (m, :attr:`References.reach_m`): a target farther than that from
        the declared one is not on the robot."""
        return np.full(3, refs.reach_m)

    def target_shift(self, p, rows):
        return rows.rotation @ p

    def describe(self) -> str:
        return "the measured target is not where the campaign says (target frame axes)"


class ForceSensorBias(VectorEffect):
    """The recorded force is ``F + b``."""

    name = "force_sensor_bias"
    kind = "measurement"
    param_names = ("fx", "fy", "fz")
    quantity = "force"

    def contribute(self, values, parts):
        parts.measure(self.label, force_bias=values[:3])

    def scale(self, refs):
        return np.full(3, 0.01 * refs.force_ref)

    def physical_scale(self, refs):
        """The campaign's load range (N, :attr:`References.force_ref`, the RMS applied
        force): a bias larger than the loads it is read with is no sensor offset."""
        return np.full(3, refs.force_ref)

    def adjust_load(self, p, force, moment):
        return force - p, moment

    def describe(self) -> str:
        return "the recorded force carries a constant offset (base axes)"


class DeflectionOffset(VectorEffect):
    """The measured deflections carry a constant offset."""

    name = "deflection_offset"
    kind = "measurement"
    param_names = ("dx", "dy", "dz")

    def contribute(self, values, parts):
        parts.measure(self.label, deflection_offset=values[:3])

    def scale(self, refs):
        return np.full(3, 0.01 * refs.deflection_ref)

    def physical_scale(self, refs):
        return np.full(3, refs.deflection_ref)  # the campaign's largest deflection

    def output_map(self, p):
        return None, p

    def describe(self) -> str:
        return "the measured deflections carry a constant offset (the reference moved)"
