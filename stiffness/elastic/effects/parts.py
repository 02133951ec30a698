"""What the effects of a model do to its robot (:class:`ElasticParts`), collected through
each effect's one hook, :meth:`stiffness.elastic.effects.base.Effect.contribute`, from which
:class:`stiffness.elastic.model.ElasticModel` is built.

Units: SI (m, N, rad, N.m/rad; m, N, N/m for prismatic joints).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from stiffness.errors import StiffnessError, UnknownJointError
from stiffness.mechanics.equilibrium import SpringLaw


@dataclass
class ElasticParts:
    """What the effects of a model do to its robot, collected through
    :meth:`~stiffness.elastic.effects.base.Effect.contribute` (SI).
    :class:`stiffness.elastic.model.ElasticModel` is built from it.

    Attributes
    ----------
    springs
        Joint -> stiffness (N.m/rad, N/m): the baseline's compliant joints first, then those
        effects make compliant, in order.
    beta, backlash
        Joint -> softening coefficient (1/(N.m), 1/N) and lost-motion half-width (rad, m).
    smoothing
        Joint -> torque (N.m, N) over which a backlash is smoothed (1 where not given).
    bends
        ``(a, b, k_1, k_2)`` link bends (N.m/rad), in order.
    tilts
        ``(joint, k_1, k_2)`` joints tilting in their bearings (N.m/rad), in order.
    payload
        ``(mass kg, centre of mass (3,) m in target frame axes)`` when the robot's weight
        preloads the joints, else ``None``.
    compensators
        ``(joint, stiffness N/m, tension N, geometry)`` spring gravity compensators (geometry:
        ``lever_m``, ``base_m``, ``angle_up_rad``, ``angle0_rad``, ``angle_reference``:
        :func:`stiffness.mechanics.gravity.compensator_torque`).
    target_shift
        (3,) m in target frame axes: where the true target is from the declared one.
    keep_target
        Whether the target is the campaign's (when another target is given, a target shift
        does not apply).
    misalignment, force_bias, deflection_offset
        The instrument's frame rotation vector (rad), recorded minus applied force (N) and the
        offset of measured deflections (m).
    zero_offsets
        Joint -> its zero offset (rad, m): the robot is at the commanded coordinates plus these
        (a simulated truth reads them; not applied to a model used away from its campaign).
    not_applied
        Reasons an effect does not act, by the effect's label (:meth:`skip`).
    """

    springs: dict[str, float]
    beta: dict[str, float] = field(default_factory=dict)
    backlash: dict[str, float] = field(default_factory=dict)
    smoothing: dict[str, float] = field(default_factory=dict)
    bends: list[tuple[str, str, float, float]] = field(default_factory=list)
    tilts: list[tuple[str, float, float]] = field(default_factory=list)
    payload: tuple[float, np.ndarray] | None = None
    compensators: list[tuple[str, float, float, dict]] = field(default_factory=list)
    target_shift: np.ndarray = field(default_factory=lambda: np.zeros(3))
    keep_target: bool = True
    misalignment: np.ndarray = field(default_factory=lambda: np.zeros(3))
    force_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))
    deflection_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    zero_offsets: dict[str, float] = field(default_factory=dict)
    not_applied: dict[str, str] = field(default_factory=dict)

    # what effects record ------------------------------------------------------------------
    def add_spring(self, joint: str, stiffness: float) -> None:
        """A joint held rigid becomes a spring of ``stiffness`` (N.m/rad, N/m).

        Raises
        ------
        StiffnessError
            If the joint is already a spring.
        """
        if joint in self.springs:
            raise StiffnessError(
                f"a joint_compliance effect on {joint}, which is already a compliant joint of "
                "k_theta (two stiffnesses for one spring: the joint is already compliant); "
                "give its stiffness in k_theta and drop the effect")
        self.springs[joint] = float(stiffness)

    def soften(self, joint: str, beta: float) -> None:
        """The joint's spring softens (``beta > 0``, 1/(N.m)) or hardens with the load."""
        self.beta[joint] = float(beta)

    def add_backlash(self, joint: str, half_width: float, smoothing: float | None) -> None:
        """Lost motion of ``half_width`` (rad, m) at the joint, smoothed over ``smoothing``
        (N.m, N; ``None`` keeps the one already set, else 1)."""
        self.backlash[joint] = float(half_width)
        if smoothing is not None:
            self.smoothing[joint] = float(smoothing)

    def add_bend(self, a: str, b: str, k_1: float, k_2: float) -> None:
        """The segment ``a -> b`` bends at ``b``'s origin, stiffnesses ``k_1, k_2``
        (N.m/rad)."""
        self.bends.append((a, b, float(k_1), float(k_2)))

    def add_tilt(self, joint: str, k_1: float, k_2: float) -> None:
        """The revolute ``joint`` tilts in its bearing at its origin about the two axes normal
        to its rotation axis, stiffnesses ``k_1, k_2`` (N.m/rad)."""
        self.tilts.append((joint, float(k_1), float(k_2)))

    def weigh(self, mass: float, centre: np.ndarray) -> None:
        """The links' weight and a payload of ``mass`` (kg) with its centre of mass at
        ``centre`` (m, target frame axes) preload the joints."""
        self.payload = (float(mass), np.asarray(centre, dtype=float).reshape(3))

    def add_compensator(self, joint: str, stiffness: float, tension: float,
                        geometry: dict) -> None:
        """A spring gravity compensator on ``joint`` (N/m, N with the link at its reference
        angle; ``geometry``: :func:`stiffness.mechanics.gravity.compensator_torque`)."""
        self.compensators.append((joint, float(stiffness), float(tension), dict(geometry)))

    def shift_target(self, label: str, delta: np.ndarray) -> None:
        """The true target is ``delta`` (m, target frame axes) from the declared one (not
        applied when another target is given)."""
        if not self.keep_target:
            self.skip(label, "the target given overrides the campaign's")
            return
        self.target_shift = self.target_shift + np.asarray(delta, dtype=float).reshape(3)

    def measure(self, label: str, rotation: np.ndarray | None = None,
                force_bias: np.ndarray | None = None,
                deflection_offset: np.ndarray | None = None) -> None:
        """How the deflections were observed: the instrument's frame rotation (rad), the
        recorded force's bias (N), the measured deflections' offset (m). A measurement effect,
        not a stiffness: listed as not applied to the robot."""
        if rotation is not None:
            self.misalignment = np.asarray(rotation, dtype=float).reshape(3)
        if force_bias is not None:
            self.force_bias = np.asarray(force_bias, dtype=float).reshape(3)
        if deflection_offset is not None:
            self.deflection_offset = np.asarray(deflection_offset, dtype=float).reshape(3)
        self.skip(label, "a measurement effect (how the campaign observed the deflection), "
                         "not a stiffness")

    def offset_zeros(self, label: str, offsets: dict[str, float]) -> None:
        """The joints' zero offsets (joint -> rad, m): the robot's calibration, not its
        stiffness, listed as not applied (a model used away from its campaign takes its
        commanded coordinates as they are)."""
        self.zero_offsets.update({j: float(v) for j, v in offsets.items()})
        self.skip(label, "the joints' zero offsets (the robot's calibration, not its "
                         "stiffness): commanded coordinates are taken as given")

    def skip(self, label: str, reason: str) -> None:
        """Note that the effect ``label`` does not act on the robot, and why."""
        self.not_applied[label] = reason

    # what the model reads -------------------------------------------------------------------
    def check_joints(self) -> None:
        """Joint-law terms and compensators must act on a compliant joint.

        Raises
        ------
        UnknownJointError
            A backlash, nonlinear spring or compensator on a rigid joint.
        """
        compliant = tuple(self.springs)
        for joint in list(self.beta) + list(self.backlash) + [c[0] for c in self.compensators]:
            if joint not in compliant:
                raise UnknownJointError(
                    f"backlash, nonlinear_joint_stiffness and gravity_compensator act on a "
                    f"compliant joint ({', '.join(compliant)}), not {joint}", name=joint,
                    choices=compliant)

    def law(self, joints: list[str] | tuple[str, ...]) -> SpringLaw:
        """The joint law over ``joints`` (zero compliance where a joint is rigid)."""
        return SpringLaw(
            np.array([1.0 / self.springs[j] if j in self.springs else 0.0 for j in joints]),
            np.array([self.beta.get(j, 0.0) for j in joints]),
            np.array([self.backlash.get(j, 0.0) for j in joints]),
            np.array([self.smoothing.get(j, 1.0) for j in joints]))
