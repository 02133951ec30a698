"""Link bends: ``link_compliance``, a lumped bending of the segment between two joints of the
target's chain (:class:`LinkCompliance`).

The segment ``a -> b`` bends at ``b``'s origin ``p_b`` about the two axes normal to it
(:func:`stiffness.elastic.effects.geometry.link_axes`); the moment there is
``(x_t - p_b) x F + M``, the part beyond ``p_b`` turns by ``omega = sum_i e_i (e_i . M_b) / k_i``
and the target moves by ``omega x (x_t - p_b)``.

Pose face (:class:`~stiffness.elastic.effects.pose_face.PoseFamily`): each link of a marker's
chain bends under the weight beyond it and the applied wrench. A *link* is a segment ``a -> b``
between consecutive joints of a marker's chain whose origins are at least
:data:`~stiffness.elastic.effects.geometry.MIN_SEGMENT_M` apart at the zero coordinates (of
joints whose origins coincide, a spherical wrist, the first stands for the group). It bends at
``b``'s origin ``p_b`` about the two axes ``e_1, e_2`` normal to it (:func:`link_axes`, the axis
column chosen at the zero coordinates as for a deflection campaign). The moment there is the
weight of everything beyond ``b`` and the applied wrench if it acts beyond ``b``,

``M_b = m_b (c_b - p_b) x g + [(x_w - p_b) x F + M]``

(``m_b, c_b``: mass and centre of mass of ``b``'s subtree, from the model's inertias); the part
beyond ``p_b`` turns by ``omega_b = sum_i e_i c_i (e_i . M_b)`` and a marker beyond it moves by
``omega_b x (x - p_b)``. Parameters the compliances ``c_1, c_2`` (rad/(N.m)) of each link:
linear, so the columns are exact at a given loaded configuration. The bend is evaluated at the
sag's loaded configuration; its own feedback on the joints' torques (the bent links' weight
moving, relative size ``|c dtau/dq|``) is left out.

Units: SI (m, N, N.m/rad).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import pinocchio as pin

from stiffness.batch.linalg import cross, cross_matrices
from stiffness.batch.poses import JointPlacements, frame_placements
from stiffness.elastic.effects.deflection_face import DeflectionEffect
from stiffness.elastic.effects.geometry import (
    MIN_SEGMENT_M,
    Geometry,
    Rows,
    joint_axis_column,
    last_of_groups,
    link_axes,
    tilt_axes,
)
from stiffness.elastic.effects.pose_face import (
    FamilyParameter,
    MarkerView,
    PoseFamily,
    PoseLayout,
    RowTerms,
    bend_label,
    layout_cached,
    tilt_label,
)
from stiffness.errors import StiffnessError, UnknownNameError


def segment(where: str | None) -> tuple[str, str] | None:
    """The two joints of a segment ``A->B`` (or ``A/B``, ``A,B``), or ``None``."""
    for sep in ("->", "/", ","):
        if where and sep in where:
            parts = [s.strip() for s in where.split(sep)]
            return (parts[0], parts[1]) if len(parts) == 2 else None
    return None


@dataclass(frozen=True)
class Link:
    """A bending link ``a -> b`` (joint ids) and the column of ``b``'s mounting body axes
    that :func:`link_axes` makes normal to it."""

    a: int
    b: int
    column: int


def marker_links(model: pin.Model, frame_ids: list[int]) -> list[Link]:
    """The links of the markers' chains (each once, base first), at the zero coordinates."""
    data = model.createData()
    pin.forwardKinematics(model, data, pin.neutral(model))
    out: list[Link] = []
    for fid in dict.fromkeys(frame_ids):
        chain = [j for j in model.supports[model.frames[fid].parentJoint]
                 if j > 0 and model.joints[j].nv == 1]
        groups: list[int] = []
        for j in chain:
            if not groups or np.linalg.norm(data.oMi[j].translation
                                            - data.oMi[groups[-1]].translation) >= MIN_SEGMENT_M:
                groups.append(j)
        for a, b in zip(groups, groups[1:], strict=False):
            seg = data.oMi[b].translation - data.oMi[a].translation
            mount = data.oMi[model.parents[b]].rotation
            link = Link(int(a), int(b), int(np.argmin(np.abs(mount.T @ seg))))
            if link not in out:
                out.append(link)
    return out


def carried_moments(pm: PoseLayout, model: pin.Model, kin: JointPlacements,
                         joints: list[int], rows: list[RowTerms]
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Over a batch of rows, from their joints' placements ``kin``: the origins ``p_b`` of
    ``joints``, the moment ``M_b`` about each that the part beyond it carries, ``m_b (c_b -
    p_b) x g`` of its subtree's weight (the model's gravity) plus the applied wrench's
    ``(x_w - p_b) x F + M`` when it acts beyond (N.m, world axes), and the weight's arm
    ``m_b (c_b - p_b)`` (kg.m: ``d M_b / d g = [m_b (c_b - p_b)]x``), (n, L, 3) each; the arm
    as ``sum_k m_k c_k - m_b p_b`` over the bodies ``k`` of ``b``'s subtree (no division: a
    massless subtree carries nothing)."""
    origins = kin.translation[:, joints]
    masses = np.array([model.inertias[k].mass for k in range(model.njoints)])
    levers = np.array([model.inertias[k].lever for k in range(model.njoints)])
    centres = np.einsum("nkab,kb->nka", kin.rotation, levers) + kin.translation
    weights = layout_cached(pm, f"subtrees {joints}", lambda: _subtrees(model, joints)) * masses
    arms = (np.einsum("lk,nka->nla", weights, centres)
            - weights.sum(axis=1)[None, :, None] * origins)
    moments = cross(arms, np.asarray(model.gravity.linear, dtype=float))
    loaded = [i for i, row in enumerate(rows) if row.wrench is not None]
    if loaded and pm.loads is not None:
        fid = pm.frame_id(pm.loads.frame)
        beyond = layout_cached(pm, f"loaded beyond {joints}", lambda: np.array(
            [b in set(model.supports[model.frames[fid].parentJoint]) for b in joints],
            dtype=float).reshape(-1, 1))
        wrench = np.array([rows[i].wrench for i in loaded]).reshape(-1, 6)
        x_w = frame_placements(model, kin, [fid])[1][loaded]  # (n_loaded, 1, 3)
        moments[loaded] += beyond * (cross(x_w - origins[loaded], wrench[:, None, :3])
                                     + wrench[:, None, 3:])
    return origins, moments, arms


def _subtrees(model: pin.Model, joints: list[int]) -> np.ndarray:
    """(L, njoints) 1 where a body is in the subtree of ``joints[l]`` (of its weight)."""
    subtree = np.zeros((len(joints), model.njoints))
    for n, b in enumerate(joints):
        subtree[n, list(model.subtrees[b])] = 1.0
    return subtree


@dataclass
class BendCache:
    """A batch of n rows' bends at their loaded configurations (world axes).

    Attributes
    ----------
    origins
        (n, 1, L, 3) each bend's origin ``p_b`` (m).
    turns
        (n, 1, L, 2, 3) ``e_i (e_i . M_b)``: the rotation per unit compliance (rad per
        rad/(N.m)).
    beyond
        (M, L) whether each of the model's markers moves with each bend.
    per_gravity
        (n, 1, L, 3, 3) d omega_b / d g at the family's compliances (rad per m/s^2): the
        bends' change with the direction of gravity (``base_tilt``'s columns); ``None``
        without a Jacobian.
    """

    origins: np.ndarray
    turns: np.ndarray
    beyond: np.ndarray
    per_gravity: np.ndarray | None


def gravity_slope(cache: BendCache, view: MarkerView) -> np.ndarray:
    """d(marker displacement)/d g (n, M, 3, 3), world axes, of one bend family's ``cache``:
    ``sum_b -[x - p_b]x d omega_b / d g`` over the bends each marker is beyond."""
    if cache.per_gravity is None:
        return np.zeros(view.point.shape + (3,))
    lever = view.point[..., None, :] - cache.origins
    # cross_matrices(r) is -[r]x
    slopes = cross_matrices(lever.reshape(-1, 3)).reshape(lever.shape + (3,)) @ cache.per_gravity
    return np.einsum("...l,...lac->...ac", cache.beyond, slopes)


@dataclass(eq=False)
class LinkCompliance(DeflectionEffect, PoseFamily):
    """Lumped bending of the segment ``a -> b`` at ``b``'s origin, about two normal axes.

    Pose face: each link of the markers' chains bends at its distal joint's origin about the
    two axes normal to it, under the weight beyond and the applied wrench."""

    a: str = ""
    b: str = ""
    column: int = 0
    name: ClassVar[str] = "link_compliance"
    param_names: ClassVar[tuple[str, ...]] = ("stiffness_1", "stiffness_2")
    beyond_springs: ClassVar[bool] = True
    value_counts: ClassVar[tuple[int, ...]] = (1, 2)
    linear_motion: ClassVar[bool] = True
    nonnegative: ClassVar[bool] = True
    compliance_variables: ClassVar[bool] = True

    @classmethod
    def at_place(cls, where, geometry=None):
        parts = segment(where)
        if geometry is None:  # the bend axes come from the robot (ElasticModel)
            if parts is None:
                raise StiffnessError(f"link_compliance needs a segment A->B, got {where!r}")
            return cls(a=parts[0], b=parts[1])
        if parts not in geometry.link_columns:
            pairs = [f"{a}->{b}" for a, b in geometry.link_segments()]
            raise UnknownNameError(
                f"link_compliance needs two joints of the target's chain, proximal first, as "
                f"A->B (or A/B); got {where!r}; valid segments: {', '.join(pairs)}",
                name=str(where), choices=pairs)
        return cls(a=parts[0], b=parts[1], column=geometry.link_columns[parts])

    def simulated_values(self, values, units):
        k = np.array([values[0], values[0]] if len(values) == 1 else values, dtype=float)
        if np.any(k <= 0):
            raise StiffnessError(f"{self.name}:{self.where} needs positive stiffnesses")
        return k

    def contribute(self, values, parts):
        parts.add_bend(self.a, self.b, values[0], values[1])

    @property
    def where(self) -> str:
        return f"{self.a}->{self.b}"

    def units(self, units):
        return [("N.m/rad", 1.0)] * 2

    def bend_at(self, geometry: Geometry, rows: Rows
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The bend's point ``p_b`` and its two axes (each (m, 3), world) at the rows: ``b``'s
        origin, the axes normal to the segment (:func:`link_axes`)."""
        ia, ib = geometry.chain.index(self.a), geometry.chain.index(self.b)
        p_b = rows.chain_origin[:, ib]
        e1, e2 = link_axes(rows.chain_origin[:, ia], p_b, rows.chain_rotation[:, ib],
                           self.column)
        return p_b, e1, e2

    def _omega(self, p, model, rows, force, moment, point):
        # the bend's point and axes depend on the rows alone: computed once per rows (at each
        # model evaluation they cost a tenth of a diagnosis's fits)
        key = (self.name, self.a, self.b, self.column)
        if key not in rows.bends:
            rows.bends[key] = self.bend_at(model.geometry, rows)
        p_b, e1, e2 = rows.bends[key]
        r = point - p_b
        m_b = cross(r, force) + moment
        omega = (e1 * (p[0] * np.sum(e1 * m_b, axis=1))[:, None]
                 + e2 * (p[1] * np.sum(e2 * m_b, axis=1))[:, None])
        return omega, r

    def target_motion(self, p, model, rows, force, moment, point):
        omega, r = self._omega(p, model, rows, force, moment, point)
        return cross(omega, r), omega

    def describe(self) -> str:
        return (f"the segment {self.a} -> {self.b} bends at {self.b} about the two axes "
                "normal to it")

    # pose face ----------------------------------------------------------------------------
    family_kind: ClassVar[str] = "elastic"
    absent_at_zero: ClassVar[bool] = True
    family_scale: ClassVar[float] = 1e-6
    needs_masses: ClassVar[bool] = True
    sized_as_effect: ClassVar[bool] = True

    def family_parameters(self, pm: PoseLayout) -> list[FamilyParameter]:
        names = pm.robot.model.names
        return [self.param(bend_label(names[link.a], names[link.b], i), "rad/(N.m)")
                for link in self.links(pm) for i in (1, 2)]

    def links(self, pm: PoseLayout) -> list[Link]:
        """The model's bending links (:func:`marker_links`; computed once per model), but
        those bending at a joint on a closed loop's path (:attr:`PoseLayout.loop_path`)."""
        return layout_cached(pm, f"{self.name} links", lambda: [
            link for link in marker_links(pm.robot.model, pm.frame_ids)
            if link.b not in pm.loop_path])

    def rows_cache(self, pm: PoseLayout, x_f: np.ndarray, model: pin.Model,
                   kin: JointPlacements, rows: list[RowTerms], jacobian: bool
                   ) -> BendCache:
        """The rows' bends (:class:`BendCache`) at their loaded configurations
        (:func:`carried_moments`)."""
        links = self.links(pm)
        joints = [link.b for link in links]
        origins, moments, arms = carried_moments(pm, model, kin, joints, rows)
        e1, e2 = self.bend_axes(model, kin, links, origins)
        turns = np.stack([e1 * np.sum(e1 * moments, axis=-1, keepdims=True),
                          e2 * np.sum(e2 * moments, axis=-1, keepdims=True)], axis=-2)
        markers = layout_cached(pm, f"{self.name} beyond", lambda: np.array(
            [[link.b in set(model.supports[model.frames[fid].parentJoint]) for link in links]
             for fid in pm.frame_ids], dtype=float).reshape(len(pm.frame_ids), len(links)))
        per_gravity = None
        if jacobian:  # d omega_b / d g = sum_i c_i e_i e_i^T [m_b (c_b - p_b)]x
            # (cross_matrices(a) is -[a]x)
            c = x_f.reshape(-1, 2)
            axes = (c[:, 0, None, None] * e1[..., :, None] * e1[..., None, :]
                    + c[:, 1, None, None] * e2[..., :, None] * e2[..., None, :])
            per_gravity = -(axes @ cross_matrices(arms.reshape(-1, 3)).reshape(axes.shape))
            per_gravity = per_gravity[:, None]
        return BendCache(origins[:, None], turns[:, None], markers, per_gravity)

    @staticmethod
    def bend_axes(model: pin.Model, kin: JointPlacements, links: list[Link],
                  origins: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The two bending axes (n, L, 3) each of every link over a batch of rows, world
        axes: normal to the link (:func:`link_axes`)."""
        e1, e2 = np.zeros(origins.shape), np.zeros(origins.shape)
        proximal = kin.translation[:, [link.a for link in links]]
        mounts = kin.rotation[:, [int(model.parents[link.b]) for link in links]]
        columns = np.array([link.column for link in links], dtype=int)
        for column in set(columns.tolist()):
            sel = columns == column
            e1[:, sel], e2[:, sel] = link_axes(proximal[:, sel], origins[:, sel],
                                               mounts[:, sel], column)
        return e1, e2

    def _lever(self, view: MarkerView) -> tuple[np.ndarray, np.ndarray]:
        """Per link, the turn per unit compliance (L, 2, 3) of the links the marker is beyond
        (zero for the others), and the marker's lever from ``p_b`` (L, 3)."""
        cache = view.caches[self.name]
        return (cache.turns * cache.beyond[..., None, None],
                view.point[..., None, :] - cache.origins)

    def marker_displacement(self, pm: PoseLayout, x_f: np.ndarray, view: MarkerView
                            ) -> np.ndarray:
        turns, lever = self._lever(view)
        omega = np.einsum("...lik,li->...lk", turns, x_f.reshape(-1, 2))
        return cross(omega, lever).sum(axis=-2)

    def columns(self, pm: PoseLayout, x_f: np.ndarray, view: MarkerView) -> np.ndarray:
        turns, lever = self._lever(view)
        cols = cross(turns, lever[..., None, :]).reshape(turns.shape[:-3] + (-1, 3))
        return view.to_measuring @ np.swapaxes(cols, -1, -2)  # (..., 3, 2L)


def transversal_joints(model: pin.Model, frame_ids: list[int], compliant: list[int]
                       ) -> list[Link]:
    """The revolute joints among ``compliant`` (joint ids: the joints the springs turn) of the
    markers' chains whose axis is a frame axis, as ``Link(j, j, axis column)`` (each once,
    base first; :func:`joint_axis_column`); of such joints whose origins coincide at the zero
    coordinates only the last tilts (:func:`last_of_groups`)."""
    data = model.createData()
    pin.forwardKinematics(model, data, pin.neutral(model))
    tilting: set[int] = set()
    for fid in dict.fromkeys(frame_ids):
        chain = [j for j in model.supports[model.frames[fid].parentJoint]
                 if j > 0 and model.joints[j].nv == 1]
        columns = [joint_axis_column(model, j) for j in chain]
        origins = np.array([data.oMi[j].translation for j in chain]).reshape(-1, 3)
        tilting |= {j for j, column, last in zip(chain, columns, last_of_groups(origins, columns),
                                                 strict=True) if column is not None and last}
    return [Link(j, j, column) for j in sorted(tilting & set(compliant))
            if (column := joint_axis_column(model, j)) is not None]


class TransversalCompliance(LinkCompliance):
    """``transversal_compliance`` (where: a revolute joint of the target's chain): the joint
    tilts in its bearing about the two axes ``e_1, e_2`` normal to its rotation axis (the other
    two axes of its mounting frame ``oMi[parent] M_j``, fixed in the parent link:
    :func:`~stiffness.elastic.effects.geometry.tilt_axes`), at its origin ``p_j``, under the
    moment the part beyond it carries: the part beyond turns by
    ``omega_j = sum_i e_i (e_i . M_j) / k_i``.

    Deflection face: ``M_j = (x_t - p_j) x F + M`` of the applied wrench, the target moves by
    ``omega_j x (x_t - p_j)``; parameters the tilting stiffnesses ``k_1, k_2`` (N.m/rad). Pose
    face: each compliant revolute joint of the markers' chains tilts under its subtree's weight
    and the applied wrench beyond (:meth:`bend_axes`); parameters the compliances ``c_1, c_2``
    (rad/(N.m)) per joint. In a model used away from its campaign it is a bend at
    ``p_j`` about those axes (:class:`stiffness.elastic.loaded.LinkBend` with ``tilt``), in
    ``K_X`` and the exact equilibrium. It is :class:`LinkCompliance` with the joint's axes
    instead of the link's: where the two coincide the identifiable reduction reports them
    merged."""

    name: ClassVar[str] = "transversal_compliance"
    #: typical size (rad/(N.m)): a crossed-roller bearing's tilting stiffness is about 1e7
    #: N.m/rad on a 10 kg arm
    family_scale: ClassVar[float] = 1e-7

    @classmethod
    def at_place(cls, where, geometry=None):
        if geometry is None:  # the axis comes from the robot (ElasticModel)
            if not where or segment(where) is not None:
                raise StiffnessError(f"transversal_compliance needs one joint, got {where!r}")
            return cls(a=where, b=where)
        if where not in geometry.tilt_columns:
            joints = list(geometry.tilt_columns)
            raise UnknownNameError(
                f"transversal_compliance needs a revolute joint of the target's chain (its axis "
                f"an axis of its frame); got {where!r}; valid names: {', '.join(joints)}",
                name=str(where), choices=joints)
        return cls(a=where, b=where, column=geometry.tilt_columns[where])

    def contribute(self, values, parts):
        parts.add_tilt(self.b, values[0], values[1])

    @property
    def where(self) -> str:
        return self.b

    def describe(self) -> str:
        return (f"joint {self.b} tilts in its bearing about the two axes normal to its "
                "rotation axis")

    def bend_at(self, geometry: Geometry, rows: Rows
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The joint's origin ``p_j`` and its bearing's two axes (each (m, 3), world) at the
        rows (:func:`~stiffness.elastic.effects.geometry.tilt_axes`)."""
        ib = geometry.chain.index(self.b)
        model = geometry.robot.model
        placement = model.jointPlacements[model.getJointId(self.b)].rotation
        e1, e2 = tilt_axes(rows.chain_rotation[:, ib] @ placement, self.column)
        return rows.chain_origin[:, ib], e1, e2

    # pose face ----------------------------------------------------------------------------
    def family_parameters(self, pm: PoseLayout) -> list[FamilyParameter]:
        names = pm.robot.model.names
        return [self.param(tilt_label(names[link.b], i), "rad/(N.m)")
                for link in self.links(pm) for i in (1, 2)]

    def links(self, pm: PoseLayout) -> list[Link]:
        """The model's tilting joints (:func:`transversal_joints`) among the joints its springs
        turn (the compliant joints, or the chain joints of compliant controller coordinates:
        :meth:`~stiffness.robot.robot.Robot.driven_joints`), but those on a closed loop's path
        (:attr:`PoseLayout.loop_path`); computed once per model."""
        model = pm.robot.model
        return layout_cached(pm, f"{self.name} links", lambda: transversal_joints(
            model, pm.frame_ids,
            [j for j in (int(model.getJointId(n)) for n in pm.robot.driven_joints(pm.springs))
             if j not in pm.loop_path]))

    @staticmethod
    def bend_axes(model: pin.Model, kin: JointPlacements, links: list[Link],
                  origins: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The bearing's two axes (n, L, 3) each normal to each joint's rotation axis over a
        batch of rows, world axes (:func:`tilt_axes` of the joint's mounting frame
        ``oMi[parent] M_j``, fixed in the parent link)."""
        e1, e2 = np.zeros(origins.shape), np.zeros(origins.shape)
        for n, link in enumerate(links):
            mount = (kin.rotation[:, int(model.parents[link.b])]
                     @ model.jointPlacements[link.b].rotation)
            e1[:, n], e2[:, n] = tilt_axes(mount, link.column)
        return e1, e2
