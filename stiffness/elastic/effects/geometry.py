"""Geometry every effect and hypothesis of one robot shares: per-row Jacobians, ``K_C`` of unit
wrenches and chain placements (:class:`Rows`, :class:`Geometry`), and the scales of the fitting
variables (:class:`References`).

Speed: Pinocchio is called once per distinct configuration (:meth:`Geometry.rows`), with every
coordinate joint compliant: the target Jacobian (6, n) and ``K_C`` of the six unit wrenches
(6, n, n) (``K_C`` is linear in the wrench; for a unit force along ``k`` it is also the Hessian
of the target coordinate ``x_k`` along the loop manifold), the origins and orientations of the
target chain's joints.

Units: SI inside (m, N, rad, N.m/rad).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from stiffness.batch.linalg import cross
from stiffness.batch.poses import gravity_regressors
from stiffness.errors import StiffnessError, with_context
from stiffness.mechanics.formulation import compliant_projection, target_states
from stiffness.mechanics.gravity import gravity_preload, require_open_chain
from stiffness.robot.kinematics import reach
from stiffness.robot.robot import Robot, load_robot

#: Backlash smoothing torque, as a fraction of the joint's RMS torque over the campaign.
BACKLASH_SMOOTHING = 0.02
#: Joint origins closer than this (m) do not make a link-compliance segment.
MIN_SEGMENT_M = 0.02

_UNIT_WRENCHES = np.eye(6)

# ------------------------------------------------------------------------------------------
# geometry cache


def skew(v: np.ndarray) -> np.ndarray:
    """(..., 3, 3) cross-product matrices of (..., 3) vectors."""
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def contract_hessian(h: np.ndarray, v: np.ndarray, axis: int) -> np.ndarray:
    """(m, k, n) contraction of (m, k, n, n) ``h`` with (m, n) ``v`` over ``h``'s ``axis``
    (2: ``sum_a h_kab v_a``; 3: ``sum_b h_kab v_b``)."""
    return np.einsum("mkab,ma->mkb" if axis == 2 else "mkab,mb->mka", h, v)


def rotation_matrix(phi: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector ``phi`` (rad), Rodrigues' formula."""
    phi = np.asarray(phi, dtype=float)
    angle = float(np.linalg.norm(phi))
    k = skew(phi)
    if angle < 1e-8:
        return np.eye(3) + k + 0.5 * k @ k
    return (np.eye(3) + math.sin(angle) / angle * k
            + (1.0 - math.cos(angle)) / angle ** 2 * k @ k)


@dataclass
class Rows:
    """Per-row geometry and loads, SI; arrays indexed by row.

    Attributes
    ----------
    jac
        (m, 6, n) target Jacobian w.r.t. every coordinate joint, rows [v; omega], loops closed.
    k_c_unit
        (m, 6, n, n) ``K_C`` of the six unit wrenches (N.m/rad per N or per N.m).
    position
        (m, 3) target position (m).
    rotation
        (m, 3, 3) target frame orientation.
    chain_origin
        (m, c, 3) world origins of the target chain's joints (m).
    chain_rotation
        (m, c, 3, 3) orientation of the body each chain joint is mounted on.
    force, moment
        (m, 3) applied (recorded) force (N) and moment (N.m) at the target, base axes.
    config_index
        (m,) index of the row's distinct configuration.
    coords
        (m, n_coordinates) the rows' coordinates (rad, m).
    gravity_torque
        (m, n) the links' weight on every coordinate joint, ``-g(q)``
        (:func:`stiffness.mechanics.gravity.gravity_preload`); NaN for a robot with loops.
    gravity_stiffness
        (m, n, n) its derivative ``-dg/dq`` (N.m/rad); NaN for a robot with loops.
    joint_angles
        What ``coords`` are: ``motor`` (the commanded pose, which static preloads sag: the sag
        enters the geometry) or ``link`` (the unloaded pose as measured: preloads set operating
        points and tangent stiffness only), the campaign's ``[robot] joint_angles``.
    """

    jac: np.ndarray
    k_c_unit: np.ndarray
    position: np.ndarray
    rotation: np.ndarray
    chain_origin: np.ndarray
    chain_rotation: np.ndarray
    force: np.ndarray
    moment: np.ndarray
    config_index: np.ndarray
    coords: np.ndarray
    gravity_torque: np.ndarray | None = None
    gravity_stiffness: np.ndarray | None = None
    joint_angles: str = "motor"
    #: the weight's preload per unit gravity parameter, by weighed links
    #: (:meth:`Geometry.weight_regressor`)
    weights: dict = field(default_factory=dict, repr=False, compare=False)
    #: each link bend's point and axes at the rows (``bend_at`` of
    #: :mod:`stiffness.elastic.effects.link_bends`), by bend
    bends: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def n_rows(self) -> int:
        """Number of rows."""
        return self.force.shape[0]

    def subset(self, index: np.ndarray) -> Rows:
        """The rows ``index`` (an integer or boolean index)."""
        return Rows(**{f: getattr(self, f)[index] for f in (
            "jac", "k_c_unit", "position", "rotation", "chain_origin", "chain_rotation",
            "force", "moment", "config_index", "coords", "gravity_torque",
            "gravity_stiffness")}, joint_angles=self.joint_angles)

    def torques(self) -> np.ndarray:
        """(m, n) joint torques ``J^T W`` that hold the recorded loads (N.m or N)."""
        return (np.einsum("mkn,mk->mn", self.jac[:, :3], self.force)
                + np.einsum("mkn,mk->mn", self.jac[:, 3:], self.moment))


@dataclass
class Geometry:
    """What every model of one robot shares: joint names and the all-compliant robot.

    Attributes
    ----------
    robot
        The robot with every coordinate joint compliant (the campaign's frame and offset).
    joints
        Coordinate joints, or the chain joints of springs on the chain (the columns of
        :attr:`Rows.jac`: :attr:`Robot.spring_joints`).
    chain
        Joints supporting the target, base to tip (passive loop joints included).
    prismatic
        (n,) whether each coordinate joint is prismatic.
    link_columns
        ``(a, b) -> column`` of ``b``'s mounting body axes used for :func:`link_axes`, chosen
        at the zero coordinates (so a simulator and a diagnosis agree on the axes).
    tilt_columns
        Revolute chain joint whose axis is an axis of its frame -> that axis's column
        (:func:`joint_axis_column`): the joints whose bearing may tilt
        (``transversal_compliance``, :func:`tilt_axes`); of such joints whose origins coincide
        the last stands for the group (:func:`last_of_groups`).
    """

    robot: Robot
    joints: tuple[str, ...]
    chain: tuple[str, ...]
    prismatic: np.ndarray
    link_columns: dict[tuple[str, str], int] = field(default_factory=dict)
    tilt_columns: dict[str, int] = field(default_factory=dict)
    #: weighed links -> the weight's regressor per distinct configuration
    _weights: dict = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def of(cls, robot: Robot) -> Geometry:
        """Geometry of ``robot`` (reloaded with every coordinate joint compliant)."""
        full = robot
        if tuple(robot.compliant_joints) != tuple(robot.spring_joints):
            full = cached_robot(robot.name, robot.target_frame, tuple(robot.target_offset),
                                tuple(robot.spring_joints), robot.loop_file,
                                robot.fixed_base)
        model = full.model
        parent = model.frames[full.target_frame_id].parentJoint
        chain = tuple(model.names[j] for j in model.supports[parent] if j > 0
                      and model.joints[j].nv == 1)
        prismatic = np.array([full.is_prismatic(j) for j in full.spring_joints], dtype=bool)
        geo = cls(full, tuple(full.spring_joints), chain, prismatic)
        geo.link_columns = geo._choose_link_columns()
        geo.tilt_columns = geo._choose_tilt_columns()
        return geo

    def _placements(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        model, data = self.robot.model, self.robot.data
        pin.forwardKinematics(model, data, q)
        return self._chain_placements()

    def _chain_placements(self) -> tuple[np.ndarray, np.ndarray]:
        return chain_placements(self.robot, self.chain)

    def _reference_q(self) -> np.ndarray:
        """The robot's reference pose: zero coordinates, or for a closed loop that does not
        close there (a hexapod) the assembly found near them (:meth:`Robot.assemble`)."""
        return self.robot.assemble(None).q

    def _choose_link_columns(self) -> dict[tuple[str, str], int]:
        origins, rotations = self._placements(self._reference_q())
        out = {}
        for ia, a in enumerate(self.chain):
            for ib in range(ia + 1, len(self.chain)):
                seg = origins[ib] - origins[ia]
                norm = float(np.linalg.norm(seg))
                if norm < 1e-12:
                    continue
                u = seg / norm
                out[(a, self.chain[ib])] = int(np.argmin(np.abs(rotations[ib].T @ u)))
        return out

    def _choose_tilt_columns(self) -> dict[str, int]:
        origins, _ = self._placements(self._reference_q())
        model = self.robot.model
        columns = [joint_axis_column(model, model.getJointId(name)) for name in self.chain]
        return {name: column for name, column, last in zip(
                    self.chain, columns, last_of_groups(origins, columns), strict=True)
                if column is not None and last}

    def angles(self, rows: Rows) -> dict[str, np.ndarray]:
        """Each spring joint (:attr:`joints`, in order) and its value (m,) (rad or m) at the
        rows: the coordinates, or the chain joints' ``A u + b`` for springs on a
        ``[controller]``'s chain."""
        values = self.robot.spring_command(rows.coords)
        return {j: values[:, i] for i, j in enumerate(self.joints)}

    def rows(self, coords: np.ndarray, force: np.ndarray, moment: np.ndarray | None = None,
             labels: list[str] | None = None, joint_angles: str = "motor") -> Rows:
        """Geometry of rows at coordinates ``coords`` (m, n) under ``force``/``moment`` (m, 3);
        ``joint_angles`` says what the coordinates are (:attr:`Rows.joint_angles`).

        Pinocchio runs once per distinct configuration.

        Raises
        ------
        StiffnessError
            If a configuration cannot be assembled or its loop is singular (the message names
            the row).
        """
        coords = np.atleast_2d(np.asarray(coords, dtype=float))
        force = np.asarray(force, dtype=float).reshape(-1, 3)
        moment = np.zeros_like(force) if moment is None else np.asarray(
            moment, dtype=float).reshape(-1, 3)
        keys: dict[tuple[float, ...], int] = {}
        index = np.empty(coords.shape[0], dtype=int)
        for i, c in enumerate(coords):
            index[i] = keys.setdefault(tuple(c), len(keys))
        n_c, n, nch = len(keys), len(self.joints), len(self.chain)
        jac = np.empty((n_c, 6, n))
        k_c = np.empty((n_c, 6, n, n))
        pos = np.empty((n_c, 3))
        rot = np.empty((n_c, 3, 3))
        origin = np.empty((n_c, nch, 3))
        chain_rot = np.empty((n_c, nch, 3, 3))
        g_tau = np.full((n_c, n), np.nan)
        g_k = np.full((n_c, n, n), np.nan)
        for key, c in keys.items():
            row = int(np.argmax(index == c))
            try:
                q = self.robot.configuration(np.array(key))
                states = target_states(self.robot, q, _UNIT_WRENCHES)
            except StiffnessError as exc:
                where = labels[row] if labels is not None else f"row {row + 1}"
                raise with_context(exc, where) from exc
            origin[c], chain_rot[c] = self._chain_placements()
            jac[c] = states[0].jacobian
            k_c[c] = np.array([s.k_c for s in states])
            pos[c] = states[0].position
            rot[c] = states[0].rotation
            if self.robot.loop.is_open_chain:
                g_tau[c], g_k[c] = gravity_preload(self.robot, q)
        return Rows(jac[index], k_c[index], pos[index], rot[index], origin[index],
                    chain_rot[index], force, moment, index, coords, g_tau[index], g_k[index],
                    joint_angles)

    def weight_regressor(self, rows: Rows, links: tuple[str, ...]
                         ) -> tuple[np.ndarray, np.ndarray]:
        """The weight's preload per unit gravity parameter of the bodies of ``links`` (joint
        names) at the rows: (m, n, P) N.m per kg or kg.m and (m, n, n, P) its derivative, the
        generalized gravity's regressor and its derivative
        (:func:`stiffness.batch.poses.gravity_regressors`) projected on the springs as
        :func:`~stiffness.mechanics.gravity.gravity_preload` projects the weight
        (``tau_g = -E^T Y pi``, ``K_g = -E^T Y_q E pi``, ``E`` the compliant rates'
        :func:`~stiffness.mechanics.formulation.compliant_projection`), computed once per
        distinct configuration of the geometry and the stacked arrays kept with the rows."""
        if links not in rows.weights:
            robot = self.robot
            require_open_chain(robot)
            bodies = [robot.model.getJointId(j) - 1 for j in links]
            done = self._weights.setdefault(links, {})
            keys = [tuple(c) for c in rows.coords]
            new = [k for k in dict.fromkeys(keys) if k not in done]
            if new:
                q = np.array([robot.configuration(np.array(k)) for k in new])
                y, y_q = gravity_regressors(robot.model, robot.model.createData(), q,
                                            derivative=True)
                assert y_q is not None
                e = compliant_projection(robot)
                y = -np.einsum("va,mvkp->makp", e, y[:, :, bodies])
                y_k = -np.einsum("va,mvwkp,wb->mabkp", e, y_q[:, :, :, bodies], e)
                for i, key in enumerate(new):
                    done[key] = (y[i].reshape(e.shape[1], -1),
                                 y_k[i].reshape(e.shape[1], e.shape[1], -1))
            rows.weights[links] = (np.array([done[k][0] for k in keys]),
                                   np.array([done[k][1] for k in keys]))
        return rows.weights[links]

    def link_segments(self, min_length: float = MIN_SEGMENT_M) -> list[tuple[str, str]]:
        """Joint pairs ``(a, b)`` of the chain whose origins are at least ``min_length`` apart
        at the reference pose (:meth:`_reference_q`) and whose distal origin is off the target.

        Of joints whose origins coincide (within ``min_length``, e.g. a spherical wrist), only
        the first stands for the group.
        """
        origins, _ = self._placements(self._reference_q())
        pin.updateFramePlacements(self.robot.model, self.robot.data)
        target = self.robot.data.oMf[self.robot.target_frame_id].translation
        groups: list[int] = []
        for i in range(len(self.chain)):
            if not groups or np.linalg.norm(origins[i] - origins[groups[-1]]) >= min_length:
                groups.append(i)
        out = []
        for n, ia in enumerate(groups):
            for ib in groups[n + 1:]:
                a, b = self.chain[ia], self.chain[ib]
                if (np.linalg.norm(target - origins[ib]) >= min_length
                        and (a, b) in self.link_columns):
                    out.append((a, b))
        return out


@functools.lru_cache(maxsize=32)
def cached_robot(source: str, frame: str | None, target_offset: tuple[float, ...] | None,
                 compliant_joints: tuple[str, ...] | None, loops: str | None = None,
                 fixed_base: bool = False) -> Robot:
    """:func:`stiffness.robot.robot.load_robot`, loaded once per argument set (example-robot-data
    models take about half a second to load). The robot's ``data`` is shared: not for use from
    several threads."""
    return load_robot(source, frame=frame,
                      target_offset=None if target_offset is None else np.array(target_offset),
                      compliant_joints=compliant_joints, loops=loops, fixed_base=fixed_base)


def chain_placements(robot: Robot, chain: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """World origins (c, 3) of the ``chain`` joints and orientations (c, 3, 3) of the bodies
    they are mounted on, from ``robot.data`` (placements must be up to date)."""
    model, data = robot.model, robot.data
    origins, rotations = [], []
    for name in chain:
        jid = model.getJointId(name)
        origins.append(np.array(data.oMi[jid].translation))
        rotations.append(np.array(data.oMi[model.parents[jid]].rotation))
    return np.array(origins), np.array(rotations)


def link_axes(p_a: np.ndarray, p_b: np.ndarray, mount_rotation: np.ndarray, column: int
              ) -> tuple[np.ndarray, np.ndarray]:
    """The two unit axes normal to the segment ``p_a -> p_b`` (each (..., 3)).

    ``e_1`` is the ``column``-th axis of the body ``b`` is mounted on, made normal to the
    segment; ``e_2 = u x e_1`` with ``u`` the segment direction.
    """
    seg = p_b - p_a
    u = seg / np.linalg.norm(seg, axis=-1, keepdims=True)
    ref = mount_rotation[..., :, column]
    e1 = ref - np.sum(ref * u, axis=-1, keepdims=True) * u
    e1 = e1 / np.linalg.norm(e1, axis=-1, keepdims=True)
    return e1, cross(u, e1)


def joint_axis_column(model: pin.Model, joint: int) -> int | None:
    """The column (0, 1, 2 for x, y, z) of a revolute joint's axis in its own frame, or
    ``None`` for another joint or a revolute joint about an arbitrary axis."""
    kind = model.joints[joint].shortname().replace("JointModel", "")
    for prefix in ("RUB", "R"):
        if kind.startswith(prefix) and kind[len(prefix):] in ("X", "Y", "Z"):
            return "XYZ".index(kind[len(prefix):])
    return None


def last_of_groups(origins: np.ndarray, columns: list[int | None]) -> list[bool]:
    """Per joint of a chain (base to tip; ``origins`` (c, 3) m at the reference pose,
    ``columns`` :func:`joint_axis_column`), whether it is not followed by a tilting joint whose
    origin is within :data:`MIN_SEGMENT_M` of its own. Two joints whose origins coincide (the
    Panda's first two, a wrist) turn about one point: the first one's tilts in its bearing, about
    axes fixed in its parent, are the second one's rotation and tilt there when both tilt alike
    (an exact alias under vertical loads), so only the last of such a group tilts."""
    out = []
    for i in range(len(columns)):
        nxt = i + 1
        out.append(not (nxt < len(columns) and columns[nxt] is not None
                        and np.linalg.norm(origins[nxt] - origins[i]) < MIN_SEGMENT_M))
    return out


def tilt_axes(mount_rotation: np.ndarray, column: int) -> tuple[np.ndarray, np.ndarray]:
    """The two unit axes (each (..., 3)) about which a revolute joint tilts in its bearing:
    the columns of its mounting frame ``oMi[parent] M_j`` (rotation ``mount_rotation``, fixed in
    the parent link) other than its rotation axis ``column``, in cyclic order (so
    ``e_1 x e_2`` is the joint's axis)."""
    return mount_rotation[..., :, (column + 1) % 3], mount_rotation[..., :, (column + 2) % 3]


# ------------------------------------------------------------------------------------------
# references (scales of the optimiser's variables)


@dataclass
class References:
    """Scales that make every optimiser variable of order one (SI).

    Attributes
    ----------
    joints
        Coordinate joints (the order of the per-joint arrays).
    k_ref
        Geometric mean of the baseline stiffnesses the fit determines (compliances are in
        units of ``1/k_ref``; :func:`stiffness.calibration.fitting.reference_stiffness`).
    tau_max
        (n,) largest |torque| per coordinate joint over the campaign.
    tau_smoothing
        (n,) backlash smoothing torque per coordinate joint.
    theta_ref
        Typical joint deflection (rad).
    force_ref
        RMS applied force (N): the campaign's load range.
    deflection_ref
        RMS measured deflection (m).
    weight_torque
        Joint name -> largest |torque| (N.m) the links' weight puts on it over the campaign
        (:attr:`Rows.gravity_torque`: the robot's inertias, no payload), for every joint where
        the model gives it; empty where it does not (a robot with loops, or whose links weigh
        nothing) or where the campaign declares its masses unknown (``--masses unknown``: the
        model's weight is not trusted).
    reach_m
        The robot's reach (m, :func:`reach`): how far a target or marker can be from where a
        campaign declares it (1 m where references are built without a robot).
    """

    joints: tuple[str, ...]
    k_ref: float
    tau_max: np.ndarray
    tau_smoothing: np.ndarray
    theta_ref: float
    force_ref: float
    deflection_ref: float
    weight_torque: dict[str, float] = field(default_factory=dict)
    reach_m: float = 1.0

    @classmethod
    def of(cls, geometry: Geometry, rows: Rows, k_ref: float, deflection: np.ndarray,
           masses: str = "known") -> References:
        """References from a campaign's rows, its baseline stiffness scale and deflections,
        the robot's link masses ``known`` or ``unknown`` (:func:`weight_torques`)."""
        return cls.scaled(geometry.joints, float(k_ref), rows.torques(), rms_force(rows.force),
                          max(float(np.sqrt(np.mean(deflection ** 2))), 1e-12),
                          weight_torques(geometry.joints, rows.gravity_torque, masses),
                          reach(geometry.robot.model))

    @classmethod
    def scaled(cls, joints: tuple[str, ...], k_ref: float, torques: np.ndarray,
               force_rms: float, deflection_ref: float, weight_torque: dict[str, float],
               reach_m: float) -> References:
        """References from the springs' torques (rows, n; N.m, N) and the RMS applied force
        (N, :func:`rms_force`) over a campaign, either kind: ``tau_max`` each joint's largest
        |torque|, the smoothing from its RMS, ``theta_ref`` the RMS torque over ``k_ref`` (each
        at least 1e-9)."""
        tau = np.abs(torques)
        tau_max = np.maximum(tau.max(axis=0, initial=0.0), 1e-9)
        tau_rms = np.maximum(np.sqrt(np.mean(tau ** 2, axis=0)), 1e-9) if tau.size else tau_max
        theta = float(np.sqrt(np.mean(tau_rms ** 2))) / k_ref if tau_rms.size else 1e-9
        return cls(joints, k_ref, tau_max, BACKLASH_SMOOTHING * tau_rms, max(theta, 1e-9),
                   max(force_rms, 1e-9), deflection_ref, weight_torque, reach_m)

    def max_torque(self, joint: str) -> float:
        """Largest |torque| of ``joint`` over the campaign."""
        return float(self.tau_max[self.joints.index(joint)])


def rms_force(force: np.ndarray) -> float:
    """RMS norm of the applied forces (rows, 3; N), 0 without any."""
    return float(np.sqrt(np.mean(np.sum(force ** 2, axis=1)))) if force.size else 0.0


def weight_torques(joints: tuple[str, ...] | list[str], torques: np.ndarray | None,
                   masses: str = "known") -> dict[str, float]:
    """:attr:`References.weight_torque` of the weight's torques (rows, n) on ``joints`` (N.m,
    N) under the model's link masses: each joint's largest |torque|; empty when the masses
    are ``unknown`` (``--masses unknown``: the model's weight is not trusted, so nothing is
    judged against it), when the torques are unknown (``None``, NaN: a robot with loops) or
    all zero (links that weigh nothing)."""
    if (masses != "known" or torques is None or not torques.size
            or not np.all(np.isfinite(torques))):
        return {}
    largest = np.abs(torques).max(axis=0)
    if not np.any(largest > 0):
        return {}
    return {j: float(t) for j, t in zip(joints, largest, strict=True)}


# ------------------------------------------------------------------------------------------
# effects

