"""The joints' slots in a Pinocchio configuration ``q`` and velocity ``v``, read once per model.

A :class:`~stiffness.robot.robot.Robot` sets its coordinates into ``q`` at every continuation,
Newton and inverse-kinematics step, and reads its compliant joints' velocity indices at each
Jacobian; read from the model, each name copies a joint model out of the bindings.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin


class JointSlots:
    """Slots of the joints of one ``model``: ``(idx_q, nq, idx_v)`` per joint name, and, per
    tuple of names, the one-value joints' positions among them and their ``q`` indices
    (:meth:`placing`) and the velocity indices (:meth:`velocity`)."""

    def __init__(self, model: pin.Model) -> None:
        self.model = model
        self._joints: dict[str, tuple[int, int, int]] = {}
        self._placing: dict[tuple[str, ...], tuple[np.ndarray, np.ndarray, list[int]]] = {}
        self._velocity: dict[tuple[str, ...], np.ndarray] = {}
        #: What the layers above derive from the model's joints alone, by their key (the
        #: compliant joints' rates, the coordinates' limits), so as to derive it once.
        self.kept: dict[tuple[str, tuple[str, ...]], tuple[np.ndarray, ...]] = {}

    def slot(self, name: str) -> tuple[int, int, int]:
        """``(idx_q, nq, idx_v)`` of a joint of the model."""
        slot = self._joints.get(name)
        if slot is None:
            joint = self.model.joints[self.model.getJointId(name)]
            slot = self._joints[name] = (joint.idx_q, joint.nq, joint.idx_v)
        return slot

    def placing(self, names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray, list[int]]:
        """Positions in ``names`` of the joints whose value is one entry of ``q`` (all but a
        continuous joint's cos/sin pair) and those entries' indices in ``q``, and the positions
        of the continuous joints."""
        placed = self._placing.get(names)
        if placed is None:
            one = [(i, self.slot(name)[0]) for i, name in enumerate(names)
                   if self.slot(name)[1] != 2]
            placed = self._placing[names] = (
                np.array([i for i, _ in one], dtype=int), np.array([k for _, k in one], dtype=int),
                [i for i, name in enumerate(names) if self.slot(name)[1] == 2])
        return placed

    def velocity(self, names: tuple[str, ...]) -> np.ndarray | None:
        """The velocity indices of ``names`` (read-only) when :meth:`keep_velocity` kept them."""
        return self._velocity.get(names)

    def keep_velocity(self, names: tuple[str, ...], indices: np.ndarray) -> np.ndarray:
        """Keep ``indices`` (read-only from now) as the velocity indices of ``names``."""
        indices.setflags(write=False)
        self._velocity[names] = indices
        return indices
