"""Loading robots: URDF files, example-robot-data names and the robots shipped in ``robots/``.

:func:`load_robot` returns a :class:`Robot`: the Pinocchio model, its loop closures, the
measurement target (a frame plus an offset in that frame) and which joints are springs.

Coordinates. A robot's *coordinates* are the values of its independent joints (every joint with
a degree of freedom except the passive joints of closed loops and mimic followers), one value
per joint, in model order unless the robot declares ``coordinate_order``: an angle (rad) for a
revolute or continuous joint, a length (m) for a prismatic one. :meth:`Robot.configuration`
turns them into a full Pinocchio configuration with the loops closed (searching for an assembly
when the pose does not close, :mod:`stiffness.robot.assembly`).

Loading steps (docs/robot-files.md): read the source (:mod:`stiffness.robot.sources`,
:mod:`stiffness.robot.urdf`); apply the loop file's ``joint_name``/``joint_type`` rewrites
(:mod:`stiffness.robot.rewrite`); fix a floating or planar base when asked; build the loop
closures; choose the target frame (:mod:`stiffness.robot.targets`).
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.errors import (
    LoopClosureError,
    StiffnessError,
    UnknownJointError,
    did_you_mean,
)
from stiffness.robot import kinematics
from stiffness.robot.assembly import Assembly, assembly_diagnosis, least_squares_assembly
from stiffness.robot.calibration import calibrated_source, is_json
from stiffness.robot.continuation import Continuation
from stiffness.robot.coupling import CoordinateMap
from stiffness.robot.declaration import (
    check_compliant,
    checked_mimics,
    controller_map,
    free_joints,
    joint_names,
    ordered_coordinates,
    target_offset_of,
)
from stiffness.robot.loops import (
    CLOSURE_TOLERANCE_M,
    LoopClosure,
    LoopDeclaration,
    build_loop_closure,
)
from stiffness.robot.meshes import MissingMesh
from stiffness.robot.rewrite import EditedVisual, fix_base, rewrite_joints
from stiffness.robot.slots import JointSlots
from stiffness.robot.sources import RobotSource, check_counts, loop_declaration, resolve_source
from stiffness.robot.targets import (
    branch_joints,
    checked_target_frame,
    default_target_offset,
    gripper_joints,
    target_chain,
)
from stiffness.robot.urdf import Mimic
from stiffness.units import float_array

#: Name of the operational frame added at the measurement target.
TARGET_FRAME = "stiffness_target"

#: Fraction of the way from the requested pose to the assembly found by the search that the
#: reference assembly steps on, into the loops' reach (see Robot._step_inside).
_INSIDE_STEP = 0.1

@dataclass
class Robot:
    """A robot model ready for elastostatics.

    Attributes
    ----------
    name
        Source name (shipped robot, example-robot-data name, URDF path or robot.toml).
    model, data
        Pinocchio model (with the target frame added) and its data.
    target_frame
        Name of the frame carrying the measurement target.
    target_offset
        Target position in ``target_frame`` axes (m).
    target_frame_id
        Id of the operational frame :data:`TARGET_FRAME` placed at the target.
    coordinate_joints
        Independent joints, in model order (or the robot's ``coordinate_order``); a robot's
        coordinates are their values.
    compliant_joints
        Joints modelled as springs (a subset of ``coordinate_joints``); the rest are rigid.
    loop
        Loop closures (:meth:`LoopClosure.open_chain`, with no pairs, for a tree).
    visual_model
        Pinocchio visual geometry, when the source provides meshes (for the viewer); for
        example-robot-data robots read on first use (it is most of their loading time).
    defaults
        Shipped defaults (``q`` in rad/m, ``k_theta`` in SI), empty for other sources. Keys
        read by the toolkit: ``q_deg`` or ``q_SI`` (default coordinates, deg, or rad/m),
        ``k_theta_SI``, ``wrench_SI``, ``rest_q_SI`` (spring rest coordinates: the default load
        is then the wrench that holds the target there), ``twist_order`` (``"v-w"`` or
        ``"w-v"``: row order of printed 6x6 matrices), ``reference_posture`` (the name of
        example-robot-data's reference configuration, ``q0``, in ``model.referenceConfigurations``).
    mimics
        Mimic followers (``<mimic>`` tags): they follow their leader, a coordinate joint, and
        have neither a coordinate nor a spring of their own.
    missing_meshes
        Visual meshes that could not be found (drawn as primitives by the viewer).
    notes
        What loading did that the user should hear once (a base fixed, a loop file read).
    loop_file
        The loop declaration read, or None.
    fixed_base
        Whether a floating or planar base was fixed (``load_robot(..., fixed_base=True)``).
    coupling
        The controller's coordinates and their map to the chain joints (a ``[controller]``
        section), or None: the coordinates are then joints of the model.
    """

    name: str
    model: pin.Model
    data: pin.Data
    target_frame: str
    target_offset: np.ndarray
    target_frame_id: int
    coordinate_joints: tuple[str, ...]
    compliant_joints: tuple[str, ...]
    loop: LoopClosure = field(default_factory=LoopClosure.open_chain)
    _visual: pin.GeometryModel | None = field(default=None, repr=False)
    defaults: dict = field(default_factory=dict)
    mimics: tuple[Mimic, ...] = ()
    missing_meshes: tuple[MissingMesh, ...] = ()
    notes: tuple[str, ...] = ()
    loop_file: str | None = None
    fixed_base: bool = False
    coupling: CoordinateMap | None = None
    last_assembly: Assembly | None = field(default=None, repr=False)
    _reference: tuple[np.ndarray, np.ndarray, bool] | None = field(default=None, repr=False)
    _visual_loader: Callable[[], pin.GeometryModel | None] | None = field(default=None, repr=False)
    #: The joints' slots in ``q`` and ``v``, read once per model (:mod:`stiffness.robot.slots`).
    _slots: JointSlots | None = field(default=None, init=False, repr=False, compare=False)

    def __getstate__(self) -> dict:
        """The robot to pickle (a Dask worker's task, a deep copy): its loop closure as its
        frame pairs and passive joints, whose Pinocchio constraints do not pickle
        (:meth:`__setstate__` builds them again on the model)."""
        state = dict(self.__dict__)
        state["loop"] = (self.loop.pairs, self.loop.passive_joints)
        return state

    def __setstate__(self, state: dict) -> None:
        """The robot of :meth:`__getstate__`'s state, its loop closure built again."""
        pairs, passive = state["loop"]
        state["loop"] = (build_loop_closure(state["model"], LoopDeclaration(pairs, (), passive))
                         if pairs else LoopClosure.open_chain())
        self.__dict__.update(state)

    @property
    def visual_model(self) -> pin.GeometryModel | None:
        """Pinocchio visual geometry of :attr:`model`, or None (no meshes)."""
        if self._visual_loader is not None:
            self._visual, self._visual_loader = self._visual_loader(), None
        return self._visual

    @property
    def title(self) -> str:
        """The robot's name for the user (echo lines, messages, reports, page titles): the
        ``name`` its ``robot.toml`` declares; else a shipped or example-robot-data robot's
        name; else, for a file, the URDF's robot name (a pose calibration's: its model's; else
        the file's stem) or the folder of a ``robot.toml``, never a path."""
        return robot_title(self.name, self.defaults, self.model.name)

    @property
    def n_coordinates(self) -> int:
        """Number of coordinates (independent joints)."""
        return len(self.coordinate_joints)

    @property
    def branch_joints(self) -> tuple[str, ...]:
        """Coordinate joints of an end-effector branch, which the target does not depend on
        (fingers or a gripper beside the target's chain); none for a robot with closed loops
        or a controller map, whose target may depend on every coordinate through them."""
        return branch_joints(self.model, self.target_frame_id, self.coordinate_joints,
                             not self.loop.is_open_chain or self.coupling is not None)

    @property
    def chain_joints(self) -> tuple[str, ...]:
        """Coordinate joints but those of the end-effector branch (:attr:`branch_joints`), in
        coordinate order: the values ``--q`` and path files need at least."""
        branch = set(self.branch_joints)
        return tuple(j for j in self.coordinate_joints if j not in branch)

    @property
    def n_compliant(self) -> int:
        """Number of compliant joints."""
        return len(self.compliant_joints)

    def joint_v_index(self, joint: str) -> int:
        """Velocity index of a one-degree-of-freedom joint."""
        if not self.model.existJointName(joint):
            raise StiffnessError(f"{joint!r} is a controller coordinate of {self.title}, not a "
                                 "joint: it has no velocity index (use rate_projection)")
        return self._slot(joint)[2]

    @property
    def coordinate_v(self) -> np.ndarray:
        """Velocity indices of the coordinate joints (a robot without ``coupling``)."""
        return np.array([self.joint_v_index(j) for j in self.coordinate_joints], dtype=int)

    @property
    def compliant_v(self) -> np.ndarray:
        """Velocity indices (read-only) of the compliant joints (when joints of the model)."""
        joints = tuple(self.compliant_joints)
        kept = self.slots.velocity(joints)
        return kept if kept is not None else self.slots.keep_velocity(
            joints, np.array([self.joint_v_index(j) for j in joints], dtype=int))

    @property
    def spring_joints(self) -> tuple[str, ...]:
        """The names a spring can act on: the coordinates, or the chain joints of a
        ``[controller]`` with ``springs_on = "chain"``."""
        if self.coupling is not None and self.coupling.springs_on == "chain":
            return self.coupling.chain
        return self.coordinate_joints

    @property
    def springs_on_controller(self) -> bool:
        """Whether the springs act on controller coordinates (not joints of the model)."""
        return self.coupling is not None and self.coupling.springs_on == "controller"

    @property
    def compliant_is_selection(self) -> bool:
        """Whether each compliant rate moves one joint alone (no mimic follower, no coupling):
        the velocity map S of a tree is then a selection of joint columns."""
        return not self.mimics and not self.springs_on_controller

    @property
    def stiffness_coordinates(self) -> str:
        """The coordinates K_theta refers to: ``"controller"`` (a ``[controller]`` with
        ``springs_on = "controller"``) or ``"chain"`` (the model's joints)."""
        return "controller" if self.springs_on_controller else "chain"

    def is_prismatic(self, name: str) -> bool:
        """Whether a coordinate or joint is a length (m) rather than an angle (rad)."""
        if self.coupling is not None and name in self.coupling.coordinates:
            return self.coupling.prismatic[self.coupling.coordinates.index(name)]
        return self._joint(name).shortname().startswith("JointModelP")

    def rate_projection(self, names: tuple[str, ...] | list[str]) -> np.ndarray:
        """(nv, len(names)) joint rates per unit rate of each named coordinate or joint.

        A joint's column is a unit column (plus each mimic follower at its multiplier); a
        controller coordinate's column is its column of the map's A spread on the chain
        joints. Passive loop joints stay still (the loop closure adds them).
        """
        out = np.zeros((self.model.nv, len(names)))
        for i, name in enumerate(names):
            if self.coupling is not None and name in self.coupling.coordinates:
                for joint, rate in zip(self.coupling.chain, self.coupling.column(name),
                                       strict=True):
                    out[self.joint_v_index(joint), i] += rate
                continue
            out[self.joint_v_index(name), i] = 1.0
            for m in self.mimics:
                if m.leader == name:
                    out[self.joint_v_index(m.follower), i] += m.multiplier
        return out

    def driven_joints(self, names: tuple[str, ...] | list[str]) -> tuple[str, ...]:
        """The model's joints the named coordinates or joints turn or slide, each once: the
        named joints themselves (the names' order), then the chain joints the named controller
        coordinates move (a non-zero entry in their columns of ``A``; a passive chain joint,
        ``t4 = -T2 - T3``, with them), in chain order."""
        coupling = self.coupling
        coordinates = () if coupling is None else coupling.coordinates
        joints = tuple(dict.fromkeys(n for n in names if n not in coordinates))
        if coupling is None:
            return joints
        rates = np.array([coupling.column(n) for n in names if n in coordinates]).reshape(
            -1, len(coupling.chain))
        return joints + tuple(j for j, moved in zip(coupling.chain, np.any(rates != 0.0, axis=0),
                                                    strict=True) if moved and j not in joints)

    def joint_values(self, coords: np.ndarray) -> tuple[tuple[str, ...], np.ndarray]:
        """The joints the coordinates set and their values (..., n) (rad or m): the
        coordinate joints themselves, or the chain joints through the ``coupling``."""
        if self.coupling is None:
            return self.coordinate_joints, np.asarray(coords, dtype=float)
        return self.coupling.chain, self.coupling.chain_values(coords)

    @property
    def compliant_in_coordinates(self) -> np.ndarray:
        """Position of each compliant joint in the coordinate vector.

        Raises
        ------
        StiffnessError
            When the springs act on the chain joints of a ``[controller]`` (they are not
            coordinates: use :attr:`compliant_in_springs`).
        """
        if self.spring_joints != self.coordinate_joints:
            raise StiffnessError(f"the springs of {self.title} act on its chain joints, not on "
                                 "its coordinates ([controller] springs_on = \"chain\")")
        return self.compliant_in_springs

    @property
    def compliant_in_springs(self) -> np.ndarray:
        """Position of each compliant joint in :attr:`spring_joints`."""
        return np.array([self.spring_joints.index(j) for j in self.compliant_joints], dtype=int)

    @property
    def spring_map(self) -> np.ndarray:
        """(n_springs, n_coordinates) rates of the :attr:`spring_joints` per unit rate of the
        coordinates: the coupling's ``A`` for springs on the chain, else the identity."""
        if self.spring_joints != self.coordinate_joints and self.coupling is not None:
            return self.coupling.matrix.copy()
        return np.eye(self.n_coordinates)

    def spring_command(self, coords: np.ndarray) -> np.ndarray:
        """Values (..., n_springs) of the :attr:`spring_joints` at coordinates (..., n)
        (rad, m): ``A u + b`` for springs on the chain, else the coordinates themselves."""
        if self.spring_joints != self.coordinate_joints and self.coupling is not None:
            return self.coupling.chain_values(coords)
        return np.asarray(coords, dtype=float)

    def spring_values(self, q: np.ndarray) -> np.ndarray:
        """Values (rad, m) of the :attr:`spring_joints` in the full configuration ``q``."""
        if self.spring_joints != self.coordinate_joints:
            return np.array([self._value(q, name) for name in self.spring_joints])
        return self.coordinates_of(q)

    def coordinate_motion(self, spring_motion: np.ndarray) -> np.ndarray:
        """The coordinates' motion (n,) (rad, m) that moves the :attr:`spring_joints` by
        ``spring_motion`` (n_springs,): itself, or through the coupling's ``A`` (least
        squares when ``A`` is tall: passive chain joints cannot be commanded apart)."""
        if self.spring_joints != self.coordinate_joints and self.coupling is not None:
            return np.linalg.lstsq(self.coupling.matrix, np.asarray(spring_motion, dtype=float),
                                   rcond=None)[0]
        return np.asarray(spring_motion, dtype=float)

    def springs_robot(self) -> Robot:
        """The same robot with every spring joint compliant and the spring joints as its
        coordinates: itself (its coordinates already) with all of them compliant, or for
        springs on a ``[controller]``'s chain the chain alone (no coupling). Shares the
        Pinocchio model; gets its own ``data``."""
        names = self.spring_joints
        coupling = None if names != self.coordinate_joints else self.coupling
        if coupling is not None:
            coupling = replace(coupling, springs_on="controller")
        if names == self.compliant_joints and coupling is self.coupling:
            return self
        return replace(self, coordinate_joints=names, compliant_joints=names,
                       data=self.model.createData(), coupling=coupling, _reference=None,
                       last_assembly=None)

    def _joint(self, name: str):
        return self.model.joints[self.model.getJointId(name)]

    @property
    def slots(self) -> JointSlots:
        """Joint slots in ``q`` and ``v``, read once per model, and :attr:`JointSlots.kept`."""
        if self._slots is None or self._slots.model is not self.model:
            self._slots = JointSlots(self.model)
        return self._slots

    def _slot(self, name: str) -> tuple[int, int, int]:
        """``(idx_q, nq, idx_v)`` of a joint (looked up once per model)."""
        return self.slots.slot(name)

    def _value(self, q: np.ndarray, name: str) -> float:
        idx, nq, _ = self._slot(name)
        if nq == 2:
            return float(np.arctan2(q[idx + 1], q[idx]))
        return float(q[idx])

    def _set_value(self, q: np.ndarray, name: str, value: float) -> None:
        idx, nq, _ = self._slot(name)
        if nq == 2:
            q[idx: idx + 2] = np.cos(value), np.sin(value)
        else:
            q[idx] = value

    def value_of(self, q: np.ndarray, name: str) -> float:
        """The value (rad or m) of a coordinate or a joint in the full configuration ``q``."""
        if self.coupling is not None and name in self.coupling.coordinates:
            return float(self.coordinates_of(q)[self.coupling.coordinates.index(name)])
        return self._value(q, name)

    def coordinates_of(self, q: np.ndarray) -> np.ndarray:
        """Coordinates (rad or m) of a full configuration ``q``."""
        if self.coupling is not None:
            return self.coupling.coordinates_of(
                np.array([self._value(q, name) for name in self.coupling.chain]))
        return np.array([self._value(q, name) for name in self.coordinate_joints])

    def follow(self, q: np.ndarray) -> np.ndarray:
        """``q`` with every mimic follower set from its leader (in place; returned)."""
        for m in self.mimics:
            self._set_value(q, m.follower, m.multiplier * self._value(q, m.leader) + m.offset)
        return q

    def _tree_configuration(self, coords: np.ndarray, base: np.ndarray) -> np.ndarray:
        q = base.copy()
        names, values = self.joint_values(coords)
        if len(values) != len(names):
            raise ValueError(f"{len(values)} values for the {len(names)} joints {names}")
        where, slots, pairs = self.slots.placing(tuple(names))
        q[slots] = values[where]
        for i in pairs:  # continuous joints: a cos/sin pair each
            self._set_value(q, names[i], values[i])
        return self.follow(q)

    def configuration(self, coords: np.ndarray, seed: np.ndarray | None = None) -> np.ndarray:
        """Full Pinocchio configuration for the given coordinates, loops closed.

        Parameters
        ----------
        coords
            One value per coordinate joint (rad or m), shape (n_coordinates,).
        seed
            A closed configuration on the wanted assembly branch; the loop is closed by
            continuation (tangent predictor, Newton corrector) from it, by default from the
            robot's reference assembly (the closure at zero coordinates, found by the
            assembly search when zero does not close).

        Raises
        ------
        StiffnessError
            On a wrong length, a NaN or infinity.
        LoopClosureError
            When no assembly exists near the pose (the message gives the residual and the loop).
        """
        return self.assemble(coords, seed).q

    def assemble(self, coords: np.ndarray | None, seed: np.ndarray | None = None,
                 search: bool = True) -> Assembly:
        """:meth:`configuration` with how the loops were closed (residual, idle passive
        motions, whether the assembly search was needed); also kept as ``last_assembly``.

        ``coords=None`` asks for the robot's reference pose: zero coordinates (or the shipped
        ``q_SI``) and, when that pose does not close, the assembly found near it by moving
        every joint (its coordinates then differ from zero: read them with
        :meth:`coordinates_of`). ``search=False`` raises the continuation's
        :class:`LoopClosureError` instead of searching (for a caller that refuses a searched
        assembly, whose mode is not checked: the search is most of the cost of a pose out of
        reach).
        """
        if coords is None:
            if self.loop.is_open_chain:
                return self.assemble(np.zeros(self.n_coordinates))
            start_coords, q, searched = self._reference_assembly()
            self.last_assembly = self.closure_report(q, searched)
            return self.last_assembly
        def needed() -> str:
            return f"the {self.n_coordinates} coordinates of {self.title} (rad, m)"

        coords = float_array(coords, "joint coordinates", needed, finite=False).reshape(-1)
        if coords.shape[0] != self.n_coordinates:
            raise StiffnessError(
                f"{self.title} has {self.n_coordinates} coordinates "
                f"({', '.join(self.coordinate_joints)}) but {coords.shape[0]} values were given"
            )
        coords = float_array(coords, "joint coordinates", needed)
        if self.loop.is_open_chain:
            q = self._tree_configuration(coords, pin.neutral(self.model))
            self.last_assembly = Assembly(q, 0.0, 0, False)
            return self.last_assembly
        searched = False
        if seed is None:
            start_coords, start_q, searched = self._reference_assembly()
        else:
            start_coords, start_q = self.coordinates_of(seed), seed
        crossings: list[tuple[float, ...]] = []
        checked = True
        try:
            q, crossings = self._continue(start_coords, start_q, coords)
        except LoopClosureError:
            if not search:
                raise
            q = self._search(coords, self._tree_configuration(coords, start_q))
            searched, checked = True, False
        self.last_assembly = self.closure_report(q, searched)
        self.last_assembly.singular_crossings = tuple(crossings)
        self.last_assembly.mode_checked = checked
        return self.last_assembly

    def closure_report(self, q: np.ndarray, searched: bool = False) -> Assembly:
        """Residual and idle passive motions of the loops at ``q`` (no closure is attempted)."""
        if self.loop.is_open_chain:
            return Assembly(q, 0.0, 0, searched)
        kinematics.update_first_order(self.model, self.data, q)
        residual = float(np.linalg.norm(self.loop.residual(self.model, self.data)))
        idle = self.loop.idle_motions(self.model, self.data).shape[1]
        return Assembly(q, residual, idle, searched)

    def _search(self, coords: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Assembly search near ``q``: all free joints by least squares, then the closure over
        the passive joints at the requested ``coords``.

        Raises
        ------
        LoopClosureError
            With the residual and the loop that cannot close.
        """
        model, data, loop = self.model, self.data, self.loop
        try:
            return loop.close(model, data, q)
        except LoopClosureError:
            pass
        free_v = np.concatenate([self.coordinate_v, loop.passive_v]).astype(int)
        found, residual = least_squares_assembly(model, data, loop, q, free_v, self.follow)
        if residual > 1e3 * CLOSURE_TOLERANCE_M:
            name, worst = max(loop.loop_residuals(model, data), key=lambda item: item[1])
            raise LoopClosureError(
                f"{self.title} has no assembly near coordinates "
                f"{np.round(coords, 6).tolist()}: even moving every joint, the loop {name} keeps "
                f"a residual of {worst:.3g} m (total {residual:.3g}); check the loop file's "
                "frame pairs and the joint values", loop=name, residual=worst)
        try:
            return loop.close(model, data, self._tree_configuration(coords, found))
        except LoopClosureError:
            pass
        try:
            return self._continue(self.coordinates_of(found), found, coords)[0]
        except LoopClosureError:
            pass
        closest, left = least_squares_assembly(model, data, loop,
                                               self._tree_configuration(coords, found),
                                               loop.passive_v, self.follow)
        if left <= 1e3 * CLOSURE_TOLERANCE_M:
            return loop.close(model, data, closest)
        name, worst = max(loop.loop_residuals(model, data), key=lambda item: item[1])
        raise LoopClosureError(
            f"{self.title}: the loop {name} cannot be closed at coordinates "
            f"{np.round(coords, 6).tolist()}: the closest the passive joints reach leaves a "
            f"residual of {worst:.3g} m (an assembly exists at "
            f"{np.round(self.coordinates_of(found), 6).tolist()}); the pose is out of the "
            "loop's reach; check the joint values and their units", loop=name, residual=worst)

    def _continue(self, start: np.ndarray, q: np.ndarray, coords: np.ndarray
                  ) -> tuple[np.ndarray, list[tuple[float, ...]]]:
        """Close the loops along the straight coordinate path from ``start`` (closed at ``q``)
        in ``q``'s assembly mode (:class:`~stiffness.robot.continuation.Continuation`); also
        the coordinates of the singular poses passed through."""
        passive_q = np.concatenate([
            np.arange(idx, idx + nq) for idx, nq, _ in map(self._slot, self.loop.passive_joints)
        ] + [np.zeros(0)]).astype(int)
        return Continuation(self.model, self.data, self.loop, self.coordinate_v,
                            self._tree_configuration, passive_q, lambda: self.title
                            ).run(start, q, coords)

    def _step_inside(self, start: np.ndarray, q: np.ndarray) -> np.ndarray:
        """An assembly a little further from ``start`` than ``q``, when one closes.

        The assembly nearest to a pose that does not close lies on the edge of the loops' reach
        (a fold, where the passive joints are not determined to first order); stepping on by
        :data:`_INSIDE_STEP` of the way (at most 0.05 rad or m) gives a regular pose nearby.
        """
        found = self.coordinates_of(q)
        delta = found - start
        span = float(np.max(np.abs(delta), initial=0.0))
        if span == 0.0:
            return q
        step = delta * min(_INSIDE_STEP, 0.05 / span)
        try:
            return self._continue(found, q, found + step)[0]
        except LoopClosureError:
            return q

    def _reference_assembly(self) -> tuple[np.ndarray, np.ndarray, bool]:
        """Closed configuration the continuation starts from, and whether it needed the search.

        The closure of the neutral configuration, or, for a shipped robot whose ``robot.toml``
        gives its default coordinates ``q_SI`` (rad or m; e.g. leg lengths, which cannot be
        zero), the closure from the neutral passive joints at those coordinates. When that does
        not close, the assembly search near it (all joints, least squares) gives the reference.
        """
        if self._reference is None:
            q0 = pin.neutral(self.model)
            coords = np.zeros(self.n_coordinates)
            if "q_SI" in self.defaults:
                coords = np.asarray(self.defaults["q_SI"], dtype=float)
            q0 = self._tree_configuration(coords, q0)
            try:
                q0, searched = self.loop.close(self.model, self.data, q0), False
            except LoopClosureError:
                free_v = np.concatenate([self.coordinate_v, self.loop.passive_v]).astype(int)
                found, residual = least_squares_assembly(self.model, self.data, self.loop, q0,
                                                         free_v, self.follow)
                if residual > 1e3 * CLOSURE_TOLERANCE_M:
                    name, worst = max(self.loop.loop_residuals(self.model, self.data),
                                      key=lambda item: item[1])
                    why = assembly_diagnosis(self.model, self.data, self.loop, q0, free_v,
                                             self.follow)
                    raise LoopClosureError(
                        f"{self.title} has no assembly near its zero pose: even moving every "
                        f"joint, the loop {name} keeps a residual of {worst:.3g} m; {why}",
                        loop=name, residual=worst) from None
                q0, searched = self._step_inside(coords, self.loop.close(
                    self.model, self.data, found)), True
            self._reference = (self.coordinates_of(q0), q0, searched)
        return self._reference


def robot_title(name: str, settings: dict, model_name: str) -> str:
    """:attr:`Robot.title` of a robot loaded from the source ``name`` with the robot-file
    settings ``settings`` and the Pinocchio model name ``model_name``: never a path."""
    declared = settings.get("name")
    if isinstance(declared, str) and declared.strip():
        return declared.strip()
    if not ("/" in name or "\\" in name or "." in Path(name).name or os.path.isdir(name)):
        return name
    path = Path(name)
    if path.suffix.lower() == ".toml" or path.is_dir():
        folder = path.resolve() if path.is_dir() else path.resolve().parent
        return folder.name or name
    if path.suffix.lower() in (".urdf", ".xml", ".json") and model_name:
        return model_name
    return path.stem or name


def load_robot(
    source: str | os.PathLike,
    frame: str | None = None,
    target_offset: np.ndarray | list[float] | None = None,
    compliant_joints: str | list[str] | tuple[str, ...] | None = None,
    loops: str | os.PathLike | None = None,
    fixed_base: bool = False,
) -> Robot:
    """Load a robot for elastostatics.

    Parameters
    ----------
    source
        A shipped robot name (``"sk120"``), a path to a URDF (a ``<name>.loops.yaml``,
        ``<name>.yaml`` or ``robot.yaml`` beside it declares its loops), a ``robot.toml`` (or
        its folder: a URDF's settings, or a DH table and controller coordinates,
        docs/robot-files.md), an example-robot-data name (``"ur5"``) or a pose calibration.
    frame
        Frame carrying the measurement target; default: the shipped robot's target frame, else
        the tip frame of the longest chain of moving joints (:mod:`stiffness.robot.targets`).
    target_offset
        Target position in ``frame`` axes (m); default zero (or the shipped robot's).
    compliant_joints
        Joints modelled as springs (names, or one string of them comma-separated); default: the
        shipped robot's, else the coordinate joints on the chain from the base to the target,
        which move it (not a head, wheels, fingers or another limb; every coordinate of a robot
        with loops or controller coordinates; :func:`stiffness.robot.targets.target_chain`).
    loops
        Loop declaration (YAML, Gepetto's Extended-URDF format) overriding the sidecar.
    fixed_base
        Fix a floating or planar base at its neutral placement (else such a base is refused).

    Raises
    ------
    StiffnessError
        Unknown source, missing or malformed file (:class:`~stiffness.errors.RobotFileError`),
        unknown frame or joint (the robot named by :func:`robot_title`), unsupported joint
        type, floating base without ``fixed_base`` (:class:`~stiffness.errors.FloatingBaseError`).
    """
    src = calibrated_source(source) if is_json(source) else resolve_source(source)
    declaration = loop_declaration(src, loops)
    model, visual, visual_loader, notes = _edited_model(src, declaration, fixed_base)
    loop, mimics = _loop_and_mimics(src, model, declaration)
    coordinate_joints, spring_names, coupling, settings = _coordinates(
        src, model, loop, mimics, loops)
    title = robot_title(src.name, settings, model.name)
    frame, fid, offset = _target(src, title, model, loop, settings, frame, target_offset)
    springs = settings.get("compliant_joints", target_chain(  # default: the joints moving it
        model, fid, spring_names, coupling is not None or not loop.is_open_chain, mimics))
    settings = check_counts(settings, coordinate_joints, springs)
    compliant_joints = tuple(springs if compliant_joints is None else joint_names(compliant_joints))
    check_compliant(title, compliant_joints, spring_names, set(loop.passive_joints),
                    {m.follower for m in mimics}, coupling, model)
    target_id = _add_target_frame(model, fid, offset)  # before the data, which holds its frame
    return Robot(
        name=src.name,
        model=model,
        data=model.createData(),
        target_frame=frame,
        target_offset=offset,
        target_frame_id=target_id,
        coordinate_joints=tuple(coordinate_joints),
        compliant_joints=compliant_joints,
        loop=loop,
        _visual=visual,
        _visual_loader=visual_loader,
        defaults={k: v for k, v in settings.items() if not k.startswith("_")},
        mimics=mimics,
        missing_meshes=src.missing_meshes,
        notes=tuple(notes),
        loop_file=None if declaration is None else declaration.path,
        fixed_base=fixed_base,
        coupling=coupling,
    )


def _loop_and_mimics(src: RobotSource, model: pin.Model, declaration: LoopDeclaration | None
                     ) -> tuple[LoopClosure, tuple[Mimic, ...]]:
    """The loop closures of ``model`` (an open chain without a declaration) and the source's
    mimic couplings that still apply (:func:`~stiffness.robot.declaration.checked_mimics`)."""
    loop = LoopClosure.open_chain() if declaration is None else build_loop_closure(
        model, declaration, dependent=tuple(m.follower for m in src.mimics))
    return loop, checked_mimics(src.name, src.mimics, model, set(loop.passive_joints))


def _coordinates(src: RobotSource, model: pin.Model, loop: LoopClosure, mimics: tuple[Mimic, ...],
                 loops: str | os.PathLike | None
                 ) -> tuple[list[str], list[str], CoordinateMap | None, dict]:
    """The coordinate joints (in ``coordinate_order``; the controller's coordinates when the
    file maps them), the joints that can carry a spring, the controller map (None without one)
    and the settings (:func:`~stiffness.robot.declaration.ordered_coordinates`)."""
    dependent = set(loop.passive_joints) | {m.follower for m in mimics}
    coordinate_joints, settings = ordered_coordinates(
        src.name, src.settings, free_joints(model, dependent), loops)
    coupling = controller_map(src.name, settings, model, coordinate_joints,
                              not loop.is_open_chain, mimics)
    spring_names = coordinate_joints
    if coupling is not None:
        coordinate_joints = list(coupling.coordinates)
        spring_names = coordinate_joints if coupling.springs_on == "controller" \
            else list(coupling.chain)
    return coordinate_joints, spring_names, coupling, settings


def _target(src: RobotSource, title: str, model: pin.Model, loop: LoopClosure, settings: dict,
            frame: str | None, target_offset: np.ndarray | list[float] | None
            ) -> tuple[str, int, np.ndarray]:
    """The target frame (checked, or the default one: not a loop's or a gripper's), its id, and
    the target's offset (3,) in its axes (m): the given or declared one, else the default."""
    closure = frozenset(n for p in loop.pairs for n in (p.frame_a, p.frame_b))
    gripper = gripper_joints(model, src.all_mimics + src.mimics)
    defaulted = frame is target_offset is None and not {"frame", "target_offset_m"} & {*settings}
    frame = checked_target_frame(
        title, model, frame if frame is not None else settings.get("frame"), closure, gripper)
    fid = kinematics.frame_id(model, frame)  # a default target is off the tip joint's origin
    offset = default_target_offset(model, fid) if defaulted else target_offset_of(
        target_offset, settings, src.name, model, frame)
    return frame, fid, offset


def _add_target_frame(model: pin.Model, fid: int, offset: np.ndarray) -> int:
    """Add the :data:`TARGET_FRAME` at ``offset`` (3,) (m) in frame ``fid``'s axes to ``model``;
    return its frame id."""
    parent = model.frames[fid]
    placement = parent.placement * pin.SE3(np.eye(3), offset)
    return model.addFrame(
        pin.Frame(TARGET_FRAME, parent.parentJoint, fid, placement, pin.FrameType.OP_FRAME))


def _edited_model(src: RobotSource, declaration: LoopDeclaration | None, fixed_base: bool
                  ) -> tuple[pin.Model, pin.GeometryModel | None, EditedVisual | None, list[str]]:
    """The source's model and visual geometry with the loop file's joint rewrites and the
    base fixed when ``fixed_base``; the same edits for the geometry read later (when drawn);
    and the notes saying what was done."""
    name, model, visual = src.name, src.model, src.visual
    notes = list(src.notes)
    if declaration is not None:
        model, visual = rewrite_joints(model, visual, declaration.rewrites)
        if declaration.rewrites:
            notes.append("joints rewritten: " + ", ".join(
                f"{j} -> {k}" for j, k in declaration.rewrites.items()))
    model, visual, base_notes = fix_base(model, visual, name, fixed_base)
    notes += base_notes
    visual_loader = None
    if src.visual_loader is not None:  # the same edits on the geometry, when it is drawn
        visual_loader = EditedVisual(pin.Model(src.model), src.visual_loader,
                                     None if declaration is None else declaration.rewrites,
                                     name, fixed_base)
    return model, visual, visual_loader, notes


def coordinate_index(robot: Robot, name: str, what: str) -> int:
    """Position in the coordinate vector of a joint name or ``q1``, ``q2``... (1-based);
    ``what`` names the input (a flag) in the error.

    Raises
    ------
    UnknownJointError
        If ``name`` is neither a coordinate joint nor ``q1..qn``.
    """
    names = list(robot.coordinate_joints)
    if name in names:
        return names.index(name)
    match = re.fullmatch(r"q(\d+)", name)
    if match and 1 <= int(match.group(1)) <= len(names):
        return int(match.group(1)) - 1
    passive = not robot.loop.is_open_chain and name in robot.loop.passive_joints
    leader = next((m.leader for m in robot.mimics if m.follower == name), None)
    why = (" (a passive loop joint: it follows the others)" if passive else
           f" (a mimic follower: it follows {leader}, set that)" if leader else "")
    raise UnknownJointError(
        f"{what}: {name!r} is not a coordinate of {robot.title}{why}; use a joint name or q1..q"
        f"{len(names)}: {did_you_mean(name, names)}", name=name, choices=names)
