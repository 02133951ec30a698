"""Kinematic errors: the geometric effects of the library, families of the pose model
(:class:`~stiffness.elastic.effects.pose_face.PoseFamily`): the measuring frame (``frame``),
the markers' offsets and 6-D probes' mounting turns (``markers``), the joints' zero offsets
(``joint_offsets``) and the joints' placement errors (``geometry``); docs/absolute-poses.md,
:mod:`stiffness.calibration.pose_model`. The joints' zero offsets also have a deflection face
(:class:`~stiffness.elastic.effects.deflection_face.DeflectionEffect`: the loaded and unloaded
tool at ``q + delta_0``, through the Jacobian there); the others have none.

Units: SI (m, rad).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import pinocchio as pin

from stiffness.batch.poses import JointPlacements
from stiffness.elastic.effects.deflection_face import HypothesisArrays, Settings
from stiffness.elastic.effects.geometry import Geometry, References, Rows, skew
from stiffness.elastic.effects.pose_face import (
    FamilyParameter,
    MarkerView,
    PoseFamily,
    PoseLayout,
    RowTerms,
)
from stiffness.errors import StiffnessError
from stiffness.robot.calibration import (
    PLACEMENT_AXES,
    PLACEMENT_UNITS,
    frame_label,
    marker_label,
    mounting_label,
    perturbed_placement,
    placement_label,
    zero_label,
)
from stiffness.robot.kinematics import reach

#: Physical scale (rad) of a probe's mounting turn about its declared mounting: a few degrees
#: (beyond, the mounting is declared wrong, :mod:`stiffness.calibration.probe_mounting`).
MOUNTING_TURN_RAD = math.radians(5.0)


#: A joint placement error beyond this fraction of the robot's reach is no calibration: a wrong
#: unit changes every link by all of it, the longest link being at least a tenth of the reach of
#: an arm of up to ten joints, while a machined robot is off its drawing by millimetres
#: (:mod:`stiffness.calibration.pose_plausibility`).
PLACEMENT_FRACTION = 0.1


def placement_lever(model: pin.Model, joint: int, floor: float) -> float:
    """The lever (m) of ``joint``'s placement: the length of the link that carries it, the
    distance from the previous joint (its placement's translation in ``model``); for a joint
    at its parent's origin (axes that meet, as in a wrist) its parent's lever, the turn of the
    link before them moving both; at least ``floor`` (:data:`PLACEMENT_FRACTION` of the
    reach in :meth:`JointGeometry.plausible_lengths`, a typical link of an arm of up to ten
    joints: a short link or one at the base's origin is machined no worse than the links
    around it, and a lever of zero would refuse any shift)."""
    while joint > 0 and not np.any(model.jointPlacements[joint].translation):
        joint = int(model.parents[joint])
    length = float(np.linalg.norm(model.jointPlacements[joint].translation)) if joint else 0.0
    return max(length, floor)


class MeasuringFrame(PoseFamily):
    """``frame``: the measuring frame's translation ``t`` (m) and rotation ``omega`` (rad)
    relative to the starting estimate: ``y = exp(omega) R_0 p + t_0 + t``."""

    name: ClassVar[str] = "frame"

    def family_parameters(self, pm: PoseLayout) -> list[FamilyParameter]:
        return [self.param(frame_label(a), u)
                for a, u in zip(PLACEMENT_AXES, PLACEMENT_UNITS, strict=True)]

    @staticmethod
    def frame_rotation(x_f: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """``exp(omega)`` and its right Jacobian (``None``: no frame parameters)."""
        omega = np.zeros(3) if x_f is None else x_f[3:]
        return pin.exp3(omega), pin.Jexp3(omega)

    @staticmethod
    def frame_translation(x_f: np.ndarray | None) -> np.ndarray:
        """``t`` (m) (``None``: no frame parameters)."""
        return np.zeros(3) if x_f is None else x_f[:3]

    def columns(self, pm: PoseLayout, x_f: np.ndarray, view: MarkerView) -> np.ndarray:
        """``d y = d t - exp(omega) [R_0 p]x Jr(omega) d omega``."""
        turn = -view.rot_w @ skew(view.world) @ view.d_omega
        return np.concatenate([np.broadcast_to(np.eye(3), turn.shape), turn], axis=-1)


class MarkerOffsets(PoseFamily):
    """``markers``: each marker's offset correction ``delta o`` (m, in its frame's axes), then
    each oriented marker's mounting turn ``delta`` (rad, in its own axes: a 6-D probe's axes
    ``R_f M exp(delta)`` with ``M`` its declared mounting), which acts on orientations alone
    (the offset is in the frame's axes, not the probe's)."""

    name: ClassVar[str] = "markers"

    def family_parameters(self, pm: PoseLayout) -> list[FamilyParameter]:
        return ([self.param(marker_label(m.name, a), "m") for m in pm.markers for a in "xyz"]
                + [self.param(mounting_label(m.name, a), "rad") for m in pm.markers
                   if m.oriented for a in PLACEMENT_AXES[3:]])

    def physical_sizes(self, pm: PoseLayout, refs: References) -> np.ndarray:
        """The robot's reach (m, :attr:`References.reach_m`) for an offset, as a deflection
        campaign's ``target_offset``: a marker farther than that from where the campaign puts
        it is not on the robot; :data:`MOUNTING_TURN_RAD` for a mounting turn."""
        turns = 3 * sum(m.oriented for m in pm.markers)
        return np.concatenate([np.full(3 * len(pm.markers), refs.reach_m),
                               np.full(turns, MOUNTING_TURN_RAD)])

    def columns(self, pm: PoseLayout, x_f: np.ndarray, view: MarkerView) -> np.ndarray:
        """``d y = exp(omega) R_0 R_frame d o`` in the marker's own three columns; zero in the
        mounting turns' (positions do not move with them)."""
        turn = view.to_measuring @ view.frame_rotation
        cols = turn[..., :, None, :] * view.selector[..., None, :, None]
        cols = cols.reshape(turn.shape[:-1] + (3 * len(pm.markers),))
        return np.concatenate([cols, np.zeros(cols.shape[:-1] + (x_f.size - cols.shape[-1],))],
                              axis=-1)

    @staticmethod
    def turned(pm: PoseLayout, x_f: np.ndarray, rotation: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
        """The markers' orientations ``R exp(delta)`` from ``rotation`` (n, M, 3, 3), their
        orientations with ``delta = 0`` (measuring axes), and their derivative as a rotation
        vector in measuring axes, ``d theta = R exp(delta) Jr(delta) d delta`` (n, M, 3, n_f)
        (zero in the offsets' columns and in the other markers')."""
        out = np.array(rotation, dtype=float)
        cols = np.zeros(rotation.shape[:-1] + (x_f.size,))
        start = 3 * len(pm.markers)
        for k, m in enumerate(pm.markers):
            if not m.oriented:
                continue
            delta = x_f[start:start + 3]
            out[:, k] = rotation[:, k] @ pin.exp3(delta)
            cols[:, k, :, start:start + 3] = out[:, k] @ pin.Jexp3(delta)
            start += 3
        return out, cols


#: A joint whose offset changes a deflection campaign's Jacobian by less than this fraction of
#: the largest joint's change is not a parameter of ``joint_offsets``' deflection face (a tool
#: on the last joint's axis: that joint's offset moves nothing the campaign observes).
OFFSET_NEGLIGIBLE = 1e-9
#: The size of a sizeable zero offset (rad, m): one optimiser unit of the deflection face.
OFFSET_SCALE = 1e-3
#: A deflection campaign's physical scale of a revolute joint's zero offset (rad): a few
#: degrees, what a zero calibration can plausibly be wrong by (mastering marks are good to a
#: tenth of a degree; an arm off by degrees misses its taught points by centimetres at a metre's
#: reach, and is remastered), and where the face's first-order model
#: ``J(q + delta_0) = J + sum_j delta_j dJ/dq_j`` still holds (its left-out term, about
#: ``delta_0 / 2`` of the kept one, is 4 % here). The pose face's half a turn
#: (:meth:`JointOffsets.physical_sizes`) only says when an offset is another zero: it models
#: any offset exactly.
DEFLECTION_OFFSET_RAD = math.radians(5.0)


def offset_coordinates(geometry: Geometry) -> tuple[str, ...]:
    """The robot's coordinates whose zero offset may move the target, in coordinate order:
    those that drive a joint of the target's chain (a coordinate joint on it, or a
    ``[controller]`` coordinate whose column of ``A`` moves one); every coordinate of a robot
    with closed loops, whose closure may tie each to the target."""
    robot = geometry.robot
    if not robot.loop.is_open_chain:
        return tuple(robot.coordinate_joints)
    chain = set(geometry.chain)
    return tuple(c for c in robot.coordinate_joints if chain & set(robot.driven_joints([c])))


@dataclass(eq=False)
class JointOffsets(Settings, PoseFamily):
    """``joint_offsets``: each 1-dof joint's zero offset ``delta_0`` (rad, m for a prismatic
    joint): the robot is at ``q + delta_0`` where its encoders read ``q``.

    Pose face: the configuration's offset (:meth:`configuration_offset`) on every 1-dof joint
    of the pose model, its columns the markers' Jacobian.

    Deflection face (a deflection campaign's candidate): the campaign observes the tool loaded
    minus unloaded at one commanded ``q``, the same physics at ``q + delta_0``, so an offset
    acts only through the geometry there, to first order the Jacobian
    ``J(q + delta_0) = J + sum_j delta_j dJ/dq_j`` (:meth:`jacobian_change`), in both the load's
    torques ``J^T W`` and the output ``J dtheta``: ``d dx = (dJ dtheta + J C dJ^T W)
    delta_0``, second order (an offset times the deflection). ``dJ[k, b]/dq_j = K_C(e_k)[b,
    j]`` from the rows' ``K_C`` of unit wrenches (:attr:`Rows.k_c_unit`,
    :func:`stiffness.mechanics.formulation.target_states`); ``K_C``'s own change (third order)
    is left out. The offsets are on the robot's coordinates, what its encoders read: a
    ``[controller]``'s coordinates move the chain joints by ``A delta_0``
    (:meth:`chain_rates`), and on a closed loop the passive joints follow (the rows' ``J`` and
    ``K_C`` are along the loop manifold, ``K_C(e_k)`` the Hessian of the target's coordinate
    ``x_k`` there). Its parameters are the offsets of :attr:`joints`: the coordinates that
    drive the target's chain (:func:`offset_coordinates`), less those whose offset changes no
    row's Jacobian (:meth:`on_rows`); each judged against a few degrees
    (:data:`DEFLECTION_OFFSET_RAD`)."""

    #: the coordinates whose offsets are parameters (deflection face), in coordinate order
    joints: tuple[str, ...] = ()
    #: whether each of :attr:`joints` is prismatic (its offset in m)
    prismatic: tuple[bool, ...] = ()
    name: ClassVar[str] = "joint_offsets"
    kind: ClassVar[str] = "measurement"
    moves_jacobian: ClassVar[bool] = True
    #: one value (every joint alike) or one per joint of :attr:`joints`
    value_counts: ClassVar[tuple[int, ...]] = tuple(range(1, 13))
    #: a prismatic joint's zero offset beyond the reach is a unit, not an error
    plausible_reach_fraction: ClassVar[float | None] = 1.0
    #: a revolute joint's encoder zero off by more than a few degrees is remastered, not
    #: calibrated (:data:`DEFLECTION_OFFSET_RAD`); a fit beyond it trades offsets the campaign
    #: does not tell apart, or reads another zero convention
    plausible_angle_rad: ClassVar[float | None] = DEFLECTION_OFFSET_RAD

    @classmethod
    def at_place(cls, where, geometry=None):
        """Every coordinate of ``geometry``'s robot whose offset may move the target
        (:func:`offset_coordinates`; unchecked without ``geometry``).

        Raises
        ------
        StiffnessError
            A place given.
        """
        placed = super().at_place(where, geometry)
        if geometry is None:
            return placed
        robot = geometry.robot
        joints = offset_coordinates(geometry)
        return cls(joints=joints, prismatic=tuple(robot.is_prismatic(j) for j in joints))

    def chain_rates(self, geometry: Geometry) -> np.ndarray:
        """(n_springs, n_offsets) rates of the geometry's spring joints (the columns of
        :attr:`Rows.jac`) per unit offset of each of :attr:`joints`: the coupling's ``A``
        for springs on a ``[controller]``'s chain (``delta q_chain = A delta_0``), else the
        identity's columns (:attr:`~stiffness.robot.robot.Robot.spring_map`). Passive loop
        joints follow through the closure: the rows' Jacobian and ``K_C`` are taken along the
        loop manifold already."""
        robot = geometry.robot
        return robot.spring_map[:, [robot.coordinate_joints.index(j) for j in self.joints]]

    def on_rows(self, model: HypothesisArrays, rows: Rows) -> JointOffsets:
        """This effect on the coordinates whose offset changes some row's Jacobian over
        ``model``'s joints by more than :data:`OFFSET_NEGLIGIBLE` of the largest such
        change."""
        moved = rows.k_c_unit[:, :, model.index] @ self.chain_rates(model.geometry)
        size = np.sqrt(np.sum(moved ** 2, axis=(0, 1, 2)))
        keep = size > OFFSET_NEGLIGIBLE * max(float(size.max(initial=0.0)), 1e-300)
        return dataclasses.replace(self, joints=tuple(np.array(self.joints)[keep].tolist()),
                                   prismatic=tuple(np.array(self.prismatic, bool)[keep].tolist()))

    def configured(self, settings):
        return dataclasses.replace(self, joints=tuple(settings.get("joints", self.joints)),
                                   prismatic=tuple(bool(p) for p in settings.get(
                                       "prismatic", self.prismatic)))

    def file_settings(self, refs):
        return {"joints": list(self.joints), "prismatic": list(self.prismatic)}

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return tuple(f"{j}_zero" for j in self.joints)

    def simulated_values(self, values, units):
        """One value per joint of :attr:`joints` (``--effect joint_offsets=...``; one value:
        every joint alike), in the angle unit (the length unit for a prismatic joint).

        Raises
        ------
        StiffnessError
            Another count of values.
        """
        if len(values) not in (1, len(self.joints)):
            raise StiffnessError(f"joint_offsets takes one value (every joint) or one per joint "
                                 f"of {', '.join(self.joints)}, got {len(values)}")
        return np.resize(np.asarray(values, dtype=float), len(self.joints)) * np.array(
            [units.length_to_si if p else units.angle_to_si for p in self.prismatic])

    def contribute(self, values, parts):
        parts.offset_zeros(self.label, dict(zip(self.joints, np.asarray(values, float).tolist(),
                                                strict=True)))

    def scale(self, refs):
        return np.full(self.n_params, OFFSET_SCALE)

    def physical_scale(self, refs):
        """:data:`DEFLECTION_OFFSET_RAD` for a revolute joint; for a prismatic one the length
        that moves the tool as far as that angle does at the robot's reach (m,
        :attr:`References.reach_m`). Narrower than the pose face's (:meth:`physical_sizes`):
        a deflection campaign sees an offset only through the Jacobian's change, to first
        order."""
        return np.array([refs.reach_m * DEFLECTION_OFFSET_RAD if p else DEFLECTION_OFFSET_RAD
                         for p in self.prismatic])

    def units(self, units):
        return [(units.length, units.length_to_si) if p else (units.angle, units.angle_to_si)
                for p in self.prismatic]

    def jacobian_change(self, p, model, rows):
        """``sum_j (M delta_0)_j dJ/dq_j`` over the model's joints, ``dJ[k, b]/dq_j =
        K_C(e_k)[b, j]`` along the geometry's spring joints ``j`` and ``M`` their rates per
        offset (:meth:`chain_rates`) (m, 6, n)."""
        return rows.k_c_unit[:, :, model.index] @ (self.chain_rates(model.geometry) @ p)

    def describe(self) -> str:
        return ("the joints' zero offsets: the robot is where its encoders read plus the "
                "offsets (the deflection seen through the Jacobian there)")

    def family_parameters(self, pm: PoseLayout) -> list[FamilyParameter]:
        names = pm.robot.model.names
        return [self.param(zero_label(names[j]), pm.joint_unit(j, "rad", "m"))
                for j in pm.joints]

    def physical_sizes(self, pm: PoseLayout, refs: References) -> np.ndarray:
        """Half a turn (pi rad) for a revolute joint: beyond it the offset is another zero,
        not an error; the robot's reach (m, :attr:`References.reach_m`) for a prismatic one."""
        names = pm.robot.model.names
        return np.array([refs.reach_m if pm.robot.is_prismatic(names[j]) else math.pi
                         for j in pm.joints])

    def configuration_offset(self, pm: PoseLayout, x_f: np.ndarray) -> np.ndarray:
        out = np.zeros(pm.robot.model.nv)
        out[pm.joints_v] = x_f
        return out

    def columns(self, pm: PoseLayout, x_f: np.ndarray, view: MarkerView) -> np.ndarray:
        return view.to_measuring @ view.j_point[..., pm.joints_v]


class JointGeometry(PoseFamily):
    """``geometry``: each 1-dof joint's placement error ``eps_j``, ``M_j exp(eps_j)``, without
    the component along its own motion (its zero offset): 5 per joint along a frame axis."""

    name: ClassVar[str] = "geometry"
    plausible_reach_fraction: ClassVar[float | None] = PLACEMENT_FRACTION
    #: a machined joint's axis is off its drawing by fractions of a degree: a placement turned
    #: by more than a zero offset may be (:data:`DEFLECTION_OFFSET_RAD`) is no calibration
    plausible_angle_rad: ClassVar[float | None] = DEFLECTION_OFFSET_RAD

    def family_parameters(self, pm: PoseLayout) -> list[FamilyParameter]:
        names = pm.robot.model.names
        return [self.param(placement_label(names[pm.joints[n]], PLACEMENT_AXES[c]),
                           PLACEMENT_UNITS[c]) for n, c in pm.geometry]

    def plausible_lengths(self, pm: PoseLayout) -> np.ndarray:
        """A placement's translation (each of x, y, z, m) beyond ``tan(5 deg)`` times its
        joint's lever (:func:`placement_lever`) is not physical: a turn of the link by the
        angle limit moves the joint that far, so a larger shift is an angle the limit refuses
        traded into a length (docs/absolute-poses.md, Implausible placements). NaN for the
        turns (judged as angles)."""
        model = pm.robot.model
        floor = PLACEMENT_FRACTION * reach(model)
        tangent = math.tan(DEFLECTION_OFFSET_RAD)
        return np.array([tangent * placement_lever(model, pm.joints[n], floor)
                         if PLACEMENT_UNITS[c] == "m" else np.nan for n, c in pm.geometry])

    def placement_errors(self, pm: PoseLayout, x_f: np.ndarray) -> np.ndarray:
        """(n_joints, 6) placement errors from the family's parameters."""
        eps = np.zeros((len(pm.joints), 6))
        rows, comps = pm.geometry_index
        eps[rows, comps] = x_f
        return eps

    def perturb_model(self, pm: PoseLayout, x_f: np.ndarray, model: pin.Model) -> None:
        for j, e in zip(pm.joints, self.placement_errors(pm, x_f), strict=True):
            model.jointPlacements[j] = perturbed_placement(model.jointPlacements[j], e)

    def rows_cache(self, pm: PoseLayout, x_f: np.ndarray, model: pin.Model,
                   kin: JointPlacements, rows: list[RowTerms], jacobian: bool
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """With the Jacobian, per row and parameter, with ``a = oMi[parent] M_j exp(eps_j)``
        of its joint: ``R_a`` times its column's translation and rotation parts (the column
        of the right Jacobian of ``exp`` at the joint's placement error) and the origin of
        ``a``, (n, 1, n_f, 3) each."""
        if not jacobian:
            return None
        right = np.array([pin.Jexp6(pin.Motion(e)) for e in self.placement_errors(pm, x_f)])
        index, comps = pm.geometry_index
        parents = [int(model.parents[j]) for j in pm.joints]
        out = self._placement_columns(pm, model, kin.rotation[:, parents],
                                      kin.translation[:, parents],
                                      (right[index, :3, comps], right[index, 3:, comps]))
        return out[0][:, None], out[1][:, None], out[2][:, None]

    @staticmethod
    def _placement_columns(pm: PoseLayout, model: pin.Model, parent_rot: np.ndarray,
                           parent_t: np.ndarray, shared: tuple[np.ndarray, np.ndarray]
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`rows_cache` from the parents' placements (n, n_joints, 3, 3) and
        (n, n_joints, 3) (world, m)."""
        own = np.array([model.jointPlacements[j].homogeneous for j in pm.joints]
                       ).reshape(-1, 4, 4)
        own_rot, own_t = own[:, :3, :3], own[:, :3, 3]
        rows, _ = pm.geometry_index
        linear, angular = shared
        # R_a v = R_parent (R_j v): the joints' own placements turn the columns once
        local = np.stack([own_t[rows], np.einsum("gab,gb->ga", own_rot[rows], linear),
                          np.einsum("gab,gb->ga", own_rot[rows], angular)], axis=1)
        # (..., parameter, [o, v, w], axis): rows of local times R_parent^T
        world = local @ np.swapaxes(parent_rot[..., rows, :, :], -1, -2)
        return world[..., 1, :], world[..., 2, :], world[..., 0, :] + parent_t[..., rows, :]

    def columns(self, pm: PoseLayout, x_f: np.ndarray, view: MarkerView) -> np.ndarray:
        """d y / d eps: ``M_j exp(eps)`` perturbed on the right.

        With ``a = oMi[parent] M_j exp(eps)``: ``d point = R_a (d v + d w x r)`` for a twist
        ``(d v, d w) = Jr(eps) d eps`` and ``r`` the point in frame ``a``, i.e.
        ``R_a Jr[:3] - [point - o_a]x R_a Jr[3:]``; zero for joints the point does not move with.
        """
        linear, angular, origin = view.caches[self.name]
        lever = view.point[..., None, :] - origin
        lx, ly, lz = lever[..., 0], lever[..., 1], lever[..., 2]
        ax, ay, az = angular[..., 0], angular[..., 1], angular[..., 2]
        cols = linear - np.stack([ly * az - lz * ay, lz * ax - lx * az, lx * ay - ly * ax],
                                 axis=-1)
        cols *= view.moving[..., pm.geometry_index[0]][..., None]
        return view.to_measuring @ np.swapaxes(cols, -1, -2)
