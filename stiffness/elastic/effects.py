"""Effects a stiffness model may miss, and a fast deflection model that composes them.

A campaign's deflections are explained by a *model*: the baseline (``conventional``
``J K^-1 J^T W`` or ``enhanced`` ``J (K - K_C(W))^-1 J^T W``, A&S eq. 8 and 10) over the
campaign's compliant joints, extended by any number of *effects* from :data:`LIBRARY`:

``complementary_stiffness``
    Load-dependent geometry: ``K_C`` in the tangent stiffness *and* the second-order kinematics
    of the deflection, ``dx = J dtheta + 1/2 sum_k e_k dtheta^T H_k dtheta`` with ``dtheta`` the
    fixed point of ``dtheta = K^-1 (J^T W + K_C(W) dtheta)``. This is the exact elastostatic
    equilibrium to second order in the deflection (the error is third order: ``dtheta^3 L``).
    No parameter.
``joint_compliance`` (where: a joint)
    A joint declared rigid is a spring; parameter its stiffness ``k`` (N.m/rad or N/m).
``link_compliance`` (where: ``a->b``, two joints of the target's chain)
    The segment between the origins of joints ``a`` and ``b`` bends: a lumped rotational
    compliance about the two axes normal to the segment, at ``b``'s origin ``p_b``. The moment
    there is ``(x_t - p_b) x F + M``; the part of the robot beyond ``p_b`` turns rigidly by
    ``omega = sum_i e_i (e_i . M_b) / k_i``, the target moves by ``omega x (x_t - p_b)``.
    Parameters the stiffnesses ``k_1, k_2`` (N.m/rad) about ``e_1, e_2`` (:func:`link_axes`).
    In a closed loop the rotation is taken as in a serial chain (the loop's reaction to it is
    neglected).
``backlash`` (where: a compliant joint)
    Lost motion: ``dtheta_j += b tanh(tau_j / tau_s)``, a dead band of half-width ``b`` (rad)
    smoothed over ``tau_s`` = :data:`BACKLASH_SMOOTHING` times the joint's RMS torque over the
    campaign (so it acts like ``b sign(tau_j)`` for all but the smallest torques).
``nonlinear_joint_stiffness`` (where: a compliant joint)
    ``dtheta_j = tau_j / k_j (1 + beta |tau_j|)``: ``beta > 0`` softens, ``beta < 0`` hardens
    (1/(N.m)); reported also as the relative change of compliance at the largest torque.
``frame_misalignment``
    The instrument's frame is rotated against the robot base: measured
    ``dx = R(phi) dx_model`` (rotation vector ``phi``, rad).
``target_offset``
    The target (where the load acts and the deflection is measured) is displaced by ``delta``
    (m, target frame axes) from where the campaign says: ``J_v -> J_v - [R_t delta]x J_w``.
``force_sensor_bias``
    The recorded force carries a constant offset ``b`` (N): the applied force is
    ``F_recorded - b``.
``deflection_offset``
    The measured deflections carry a constant offset ``d`` (m) (the unloaded reference moved,
    an instrument zero drift).
``gravity_preload``
    The links' weight (URDF inertias) and a payload (mass kg, centre of mass m in target frame
    axes) preload the joints (:meth:`Effect.preload`): the deflection is the loaded minus the
    unloaded equilibrium at the commanded pose (open chains only).
``gravity_compensator`` (where: a revolute compliant joint)
    A spring between the base and a lever on the link
    (:func:`stiffness.mechanics.gravity.spring_balancer`; parameters its stiffness N/m and its
    tension N at the joint's zero): its torque preloads the joint, its angle derivative adds
    to the joint's stiffness.

With a :attr:`Model.rotation_weight` a model also predicts the rotation of the target frame,
``J_w dtheta`` plus each effect's rotational part (:meth:`Effect.rotation`,
:meth:`Effect.adjust_rotation`).

Speed: Pinocchio is called once per distinct configuration (:func:`build_rows`), with every
coordinate joint compliant: the target Jacobian (6, n) and ``K_C`` of the six unit wrenches
(6, n, n) (``K_C`` is linear in the wrench; for a unit force along ``k`` it is also the Hessian
of the target coordinate ``x_k`` along the loop manifold), the origins and orientations of the
target chain's joints. Every model is then array algebra over the rows (:meth:`Model.predict`),
cheap enough for least squares over dozens of candidate models with cross-validation.

Units: SI inside (m, N, rad, N.m/rad).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
import pinocchio as pin

from stiffness.batch.equilibrium import solve_equilibria, unloaded_kinematics
from stiffness.errors import (
    StiffnessError,
    UnknownEffectError,
    UnknownJointError,
    UnknownNameError,
    did_you_mean,
    with_context,
)
from stiffness.mechanics.equilibrium import SpringLaw
from stiffness.mechanics.formulation import target_states
from stiffness.mechanics.gravity import gravity_preload, require_open_chain, spring_balancer
from stiffness.robot.robot import Robot, load_robot

#: Backlash smoothing torque, as a fraction of the joint's RMS torque over the campaign.
BACKLASH_SMOOTHING = 0.02
#: Joint origins closer than this (m) do not make a link-compliance segment.
MIN_SEGMENT_M = 0.02
#: Newton iterations of the joint law when it is nonlinear (backlash, nonlinear spring).
LAW_ITERATIONS = 4
#: Baselines a model may start from (``exact``: the exact equilibrium of every row,
#: :func:`stiffness.batch.equilibrium.solve_equilibria`, without effects).
BASELINES = ("conventional", "enhanced", "exact")
#: How an effect enters a model used away from its campaign: ``stiffness`` (it changes the
#: robot's stiffness and enters K_X), ``measurement`` (how the deflection was observed: listed,
#: not applied), ``lost_motion`` (a deflection that is not a stiffness: listed, not applied),
#: ``preload`` (a load present at every pose, the robot's weight: it moves the operating point
#: and adds its ``K_C``).
EFFECT_KINDS = ("stiffness", "measurement", "lost_motion", "preload")
#: Default geometry of ``gravity_compensator`` (m, m, rad): lever on the link, distance of the
#: base attachment from the axis, angle between them at the joint's zero.
COMPENSATOR_GEOMETRY = {"lever_m": 0.1, "base_m": 0.3, "angle0_rad": 0.0}

_UNIT_WRENCHES = np.eye(6)


# ------------------------------------------------------------------------------------------
# geometry cache


def _skew(v: np.ndarray) -> np.ndarray:
    """(..., 3, 3) cross-product matrices of (..., 3) vectors."""
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def _contract(h: np.ndarray, v: np.ndarray, axis: int) -> np.ndarray:
    """(m, k, n) contraction of (m, k, n, n) ``h`` with (m, n) ``v`` over ``h``'s ``axis``
    (2: ``sum_a h_kab v_a``; 3: ``sum_b h_kab v_b``)."""
    return np.einsum("mkab,ma->mkb" if axis == 2 else "mkab,mb->mka", h, v)


def rotation_matrix(phi: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector ``phi`` (rad), Rodrigues' formula."""
    phi = np.asarray(phi, dtype=float)
    angle = float(np.linalg.norm(phi))
    k = _skew(phi)
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

    @property
    def n_rows(self) -> int:
        """Number of rows."""
        return self.force.shape[0]

    def subset(self, index: np.ndarray) -> Rows:
        """The rows ``index`` (an integer or boolean index)."""
        return Rows(*(getattr(self, f)[index] for f in (
            "jac", "k_c_unit", "position", "rotation", "chain_origin", "chain_rotation",
            "force", "moment", "config_index", "coords", "gravity_torque",
            "gravity_stiffness")))

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
        Coordinate joints (the columns of :attr:`Rows.jac`).
    chain
        Joints supporting the target, base to tip (passive loop joints included).
    prismatic
        (n,) whether each coordinate joint is prismatic.
    link_columns
        ``(a, b) -> column`` of ``b``'s mounting body axes used for :func:`link_axes`, chosen
        at the zero coordinates (so a simulator and a diagnosis agree on the axes).
    """

    robot: Robot
    joints: tuple[str, ...]
    chain: tuple[str, ...]
    prismatic: np.ndarray
    link_columns: dict[tuple[str, str], int] = field(default_factory=dict)

    @classmethod
    def of(cls, robot: Robot) -> Geometry:
        """Geometry of ``robot`` (reloaded with every coordinate joint compliant)."""
        full = robot
        if tuple(robot.compliant_joints) != tuple(robot.coordinate_joints):
            full = cached_robot(robot.name, robot.target_frame, tuple(robot.target_offset),
                                tuple(robot.coordinate_joints), robot.loop_file,
                                robot.fixed_base)
        model = full.model
        parent = model.frames[full.target_frame_id].parentJoint
        chain = tuple(model.names[j] for j in model.supports[parent] if j > 0
                      and model.joints[j].nv == 1)
        kinds = [model.joints[model.getJointId(j)].shortname() for j in full.coordinate_joints]
        prismatic = np.array([k.startswith("JointModelP") for k in kinds], dtype=bool)
        geo = cls(full, tuple(full.coordinate_joints), chain, prismatic)
        geo.link_columns = geo._choose_link_columns()
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

    def rows(self, coords: np.ndarray, force: np.ndarray, moment: np.ndarray | None = None,
             labels: list[str] | None = None) -> Rows:
        """Geometry of rows at coordinates ``coords`` (m, n) under ``force``/``moment`` (m, 3).

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
                g_tau[c], g_k[c] = gravity_preload(self.robot, q, columns=self.robot.coordinate_v)
        return Rows(jac[index], k_c[index], pos[index], rot[index], origin[index],
                    chain_rot[index], force, moment, index, coords, g_tau[index], g_k[index])

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
    return e1, np.cross(u, e1)


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
        Geometric mean of the baseline stiffnesses (compliances are in units of ``1/k_ref``).
    tau_max
        (n,) largest |torque| per coordinate joint over the campaign.
    tau_smoothing
        (n,) backlash smoothing torque per coordinate joint.
    theta_ref
        Typical joint deflection (rad).
    force_ref
        RMS applied force (N).
    deflection_ref
        RMS measured deflection (m).
    """

    joints: tuple[str, ...]
    k_ref: float
    tau_max: np.ndarray
    tau_smoothing: np.ndarray
    theta_ref: float
    force_ref: float
    deflection_ref: float

    @classmethod
    def of(cls, geometry: Geometry, rows: Rows, k_ref: float, deflection: np.ndarray
           ) -> References:
        """References from a campaign's rows, its baseline stiffness scale and deflections."""
        tau = np.abs(rows.torques())
        tau_max = np.maximum(tau.max(axis=0), 1e-9)
        tau_rms = np.maximum(np.sqrt(np.mean(tau ** 2, axis=0)), 1e-9)
        theta = float(np.sqrt(np.mean(tau_rms ** 2))) / k_ref
        return cls(geometry.joints, float(k_ref), tau_max, BACKLASH_SMOOTHING * tau_rms,
                   max(theta, 1e-9),
                   max(float(np.sqrt(np.mean(np.sum(rows.force ** 2, axis=1)))), 1e-9),
                   max(float(np.sqrt(np.mean(deflection ** 2))), 1e-12))

    def max_torque(self, joint: str) -> float:
        """Largest |torque| of ``joint`` over the campaign."""
        return float(self.tau_max[self.joints.index(joint)])


# ------------------------------------------------------------------------------------------
# effects


@dataclass
class Parameter:
    """A reported parameter: value, standard error and 95 % interval in ``unit``."""

    name: str
    value: float
    standard_error: float
    ci95: tuple[float, float]
    unit: str

    def to_dict(self) -> dict:
        """JSON-ready (inf and NaN become ``None``)."""
        def num(v: float) -> float | None:
            return float(v) if math.isfinite(v) else None
        return {"value": num(self.value), "standard_error": num(self.standard_error),
                "ci95": [num(self.ci95[0]), num(self.ci95[1])], "unit": self.unit}


class Effect:
    """An effect a model may miss: its name, where it acts, its parameters and its prediction.

    Optimiser variables ``u`` are scaled (:meth:`scale`) so that ``u ~ 1`` is a sizeable effect;
    :meth:`physical` turns them into SI values. Hooks default to doing nothing.
    """

    name: ClassVar[str] = ""
    #: names of the parameters (SI values from :meth:`physical`)
    param_names: ClassVar[tuple[str, ...]] = ()
    #: whether the model gets ``K_C`` and the second-order kinematics
    second_order: ClassVar[bool] = False
    #: a rigid joint this effect makes compliant
    added_joint: str | None = None
    #: the joint whose law this effect changes
    joint: str | None = None
    #: whether the variables enter only through that joint's law, affinely
    #: (:meth:`adjust_law` of :meth:`physical`): the model then differentiates the prediction
    #: with respect to them analytically (:meth:`Model.predict_with_jacobian`)
    through_law: ClassVar[bool] = False
    #: how the effect enters a model used away from its campaign
    #: (:mod:`stiffness.elastic.model_file`): one of :data:`EFFECT_KINDS`
    kind: ClassVar[str] = "stiffness"

    @property
    def where(self) -> str | None:
        """Where the effect acts (a joint, ``a->b``) or ``None``."""
        return None

    @property
    def label(self) -> str:
        """``name`` or ``name(where)``."""
        return self.name if self.where is None else f"{self.name}({self.where})"

    @property
    def n_params(self) -> int:
        """Number of parameters."""
        return len(self.param_names)

    @property
    def penalty_params(self) -> int:
        """Parameters counted by the information criterion (a switch counts as one)."""
        return max(self.n_params, 1)

    def key(self) -> tuple:
        """Identity of the effect (name and where)."""
        return (self.name, self.where)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounds of the optimiser variables."""
        return np.full(self.n_params, -1e4), np.full(self.n_params, 1e4)

    def start(self) -> np.ndarray:
        """Start of the optimiser variables (the effect nearly absent)."""
        return np.zeros(self.n_params)

    def physical(self, u: np.ndarray, refs: References) -> np.ndarray:
        """SI parameter values of optimiser variables ``u``."""
        return np.asarray(u, dtype=float) * self.scale(refs)

    def scale(self, refs: References) -> np.ndarray:
        """SI value of one unit of each optimiser variable."""
        return np.ones(self.n_params)

    def variables(self, values: np.ndarray, refs: References) -> np.ndarray:
        """Optimiser variables of reported SI parameter values (the inverse of :meth:`report`
        with SI units; only the first :attr:`n_params` values are used)."""
        return np.asarray(values, dtype=float)[: self.n_params] / self.scale(refs)

    # hooks ---------------------------------------------------------------------------------
    def adjust_load(self, p: np.ndarray, force: np.ndarray, moment: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
        """Applied load from the recorded one."""
        return force, moment

    def target_shift(self, p: np.ndarray, rows: Rows) -> np.ndarray | None:
        """(m, 3) displacement of the true target from the declared one, world axes."""
        return None

    def adjust_law(self, p: np.ndarray, law: SpringLaw, column: int, refs: References) -> None:
        """Change the law of the model joint at ``column`` (that of :attr:`joint`)."""

    def displacement(self, p: np.ndarray, model: Model, rows: Rows, force: np.ndarray,
                     moment: np.ndarray, point: np.ndarray) -> np.ndarray | None:
        """(m, 3) extra target displacement (m)."""
        return None

    def adjust_output(self, p: np.ndarray, dx: np.ndarray) -> np.ndarray:
        """Measured displacement from the model's."""
        return dx

    def output_tangent(self, p: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Derivative of :meth:`adjust_output` along changes ``t`` (m, 3, P) of the model's
        displacement."""
        return t

    def rotation(self, p: np.ndarray, model: Model, rows: Rows, force: np.ndarray,
                 moment: np.ndarray, point: np.ndarray) -> np.ndarray | None:
        """(m, 3) extra rotation of the target frame (rad, base axes), the rotational part of
        :meth:`displacement`."""
        return None

    def adjust_rotation(self, p: np.ndarray, dphi: np.ndarray) -> np.ndarray:
        """Measured rotation (m, 3) from the model's (the rotational part of
        :meth:`adjust_output`)."""
        return dphi

    def rotation_tangent(self, p: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Derivative of :meth:`adjust_rotation` along changes ``t`` (m, 3, P) of the model's
        rotation."""
        return t

    def preload(self, p: np.ndarray, model: Model, rows: Rows
                ) -> tuple[np.ndarray, np.ndarray] | None:
        """A torque present at the unloaded pose: ``(tau_p (m, n), K_p (m, n, n))`` over the
        model's joints, ``K_p = d tau_p / d theta``, or ``None``. The measured deflection is
        then the loaded minus the unloaded equilibrium (:meth:`Model.predict`)."""
        return None

    # reporting ------------------------------------------------------------------------------
    def report(self, u: np.ndarray, cov_u: np.ndarray, refs: References, units,
               quantile: float) -> list[Parameter]:
        """Parameters with uncertainties in the campaign's units (``units``:
        :class:`stiffness.calibration.campaign.Units`). ``cov_u`` is the covariance of ``u``."""
        scale = self.scale(refs)
        se = np.sqrt(np.maximum(np.diag(cov_u), 0.0)) * scale
        value = self.physical(u, refs)
        out = []
        for name, v, s, (unit, factor) in zip(self.param_names, value, se,
                                              self._units(units), strict=True):
            out.append(Parameter(name, v / factor, s / factor,
                                 ((v - quantile * s) / factor, (v + quantile * s) / factor),
                                 unit))
        return out

    def _units(self, units) -> list[tuple[str, float]]:
        return [("SI", 1.0)] * self.n_params

    def describe(self) -> str:
        """One line on what the effect is."""
        return self.label


class ComplementaryStiffness(Effect):
    """Load-dependent geometry: ``K_C`` and the second-order kinematics of the deflection."""

    name = "complementary_stiffness"
    second_order = True

    def describe(self) -> str:
        return ("the load changes the geometry: K_C in the tangent stiffness and the "
                "second-order kinematics (exact equilibrium to second order)")


def _stiffness_report(name: str, u: float, var_u: float, scale: float, unit: str,
                      quantile: float) -> Parameter:
    """A stiffness ``1 / (u scale)`` from a compliance variable ``u``, delta method."""
    se_u = math.sqrt(max(var_u, 0.0)) if math.isfinite(var_u) else math.inf
    c = u * scale
    k = 1.0 / c if c > 0 else math.inf
    se_k = se_u * scale / c ** 2 if c > 0 else math.inf
    hi_c = (u + quantile * se_u) * scale
    lo_c = (u - quantile * se_u) * scale
    low = 1.0 / hi_c if hi_c > 0 and math.isfinite(hi_c) else 0.0
    high = 1.0 / lo_c if lo_c > 0 else math.inf
    return Parameter(name, k, se_k, (low, high), unit)


@dataclass(eq=False)
class JointCompliance(Effect):
    """A joint declared rigid is a spring of stiffness ``k``."""

    joint_name: str = ""
    prismatic: bool = False
    name: ClassVar[str] = "joint_compliance"
    param_names: ClassVar[tuple[str, ...]] = ("stiffness",)
    through_law: ClassVar[bool] = True

    def __post_init__(self) -> None:
        self.added_joint = self.joint_name
        self.joint = self.joint_name

    @property
    def where(self) -> str:
        return self.joint_name

    def bounds(self):
        return np.zeros(1), np.full(1, 1e4)

    def start(self):
        return np.full(1, 1e-3)

    def scale(self, refs):
        return np.full(1, 1.0 / refs.k_ref)  # compliance

    def adjust_law(self, p, law, column, refs):
        law.compliance[column] = p[0]

    def variables(self, values, refs):
        return (1.0 / np.asarray(values, dtype=float)[:1]) / self.scale(refs)

    def report(self, u, cov_u, refs, units, quantile):
        unit = "N/m" if self.prismatic else "N.m/rad"
        return [_stiffness_report("stiffness", float(u[0]), float(cov_u[0, 0]),
                                  1.0 / refs.k_ref, unit, quantile)]

    def describe(self) -> str:
        return f"joint {self.joint_name}, declared rigid, is a spring"


@dataclass(eq=False)
class LinkCompliance(Effect):
    """Lumped bending of the segment ``a -> b`` at ``b``'s origin, about two normal axes."""

    a: str = ""
    b: str = ""
    column: int = 0
    name: ClassVar[str] = "link_compliance"
    param_names: ClassVar[tuple[str, ...]] = ("stiffness_1", "stiffness_2")

    @property
    def where(self) -> str:
        return f"{self.a}->{self.b}"

    def bounds(self):
        return np.zeros(2), np.full(2, 1e4)

    def start(self):
        return np.full(2, 1e-3)

    def scale(self, refs):
        return np.full(2, 1.0 / refs.k_ref)

    def variables(self, values, refs):
        return (1.0 / np.asarray(values, dtype=float)[:2]) / self.scale(refs)

    def _omega(self, p, model, rows, force, moment, point):
        ia, ib = model.geometry.chain.index(self.a), model.geometry.chain.index(self.b)
        p_a, p_b = rows.chain_origin[:, ia], rows.chain_origin[:, ib]
        e1, e2 = link_axes(p_a, p_b, rows.chain_rotation[:, ib], self.column)
        r = point - p_b
        m_b = np.cross(r, force) + moment
        omega = (e1 * (p[0] * np.sum(e1 * m_b, axis=1))[:, None]
                 + e2 * (p[1] * np.sum(e2 * m_b, axis=1))[:, None])
        return omega, r

    def displacement(self, p, model, rows, force, moment, point):
        omega, r = self._omega(p, model, rows, force, moment, point)
        return np.cross(omega, r)

    def rotation(self, p, model, rows, force, moment, point):
        return self._omega(p, model, rows, force, moment, point)[0]

    def report(self, u, cov_u, refs, units, quantile):
        return [_stiffness_report(n, float(u[i]), float(cov_u[i, i]), 1.0 / refs.k_ref,
                                  "N.m/rad", quantile)
                for i, n in enumerate(self.param_names)]

    def describe(self) -> str:
        return (f"the segment {self.a} -> {self.b} bends at {self.b} about the two axes "
                "normal to it")


@dataclass(eq=False)
class Backlash(Effect):
    """Lost motion at a joint: ``dtheta += b tanh(tau / tau_s)``."""

    joint_name: str = ""
    prismatic: bool = False
    name: ClassVar[str] = "backlash"
    kind: ClassVar[str] = "lost_motion"
    param_names: ClassVar[tuple[str, ...]] = ("half_width",)
    through_law: ClassVar[bool] = True

    def __post_init__(self) -> None:
        self.joint = self.joint_name

    @property
    def where(self) -> str:
        return self.joint_name

    def bounds(self):
        return np.zeros(1), np.full(1, 1e4)

    def start(self):
        return np.full(1, 1e-3)

    def scale(self, refs):
        return np.full(1, refs.theta_ref)

    def adjust_law(self, p, law, column, refs):
        law.backlash[column] = p[0]

    def _units(self, units):
        if self.prismatic:
            return [(units.length, units.length_to_si)]
        return [(units.angle, units.angle_to_si)]

    def describe(self) -> str:
        return f"joint {self.joint_name} has lost motion (a dead band around zero torque)"


@dataclass(eq=False)
class NonlinearJointStiffness(Effect):
    """``dtheta = tau / k (1 + beta |tau|)``: the spring softens (beta > 0) or hardens."""

    joint_name: str = ""
    prismatic: bool = False
    name: ClassVar[str] = "nonlinear_joint_stiffness"
    param_names: ClassVar[tuple[str, ...]] = ("beta",)
    through_law: ClassVar[bool] = True

    def __post_init__(self) -> None:
        self.joint = self.joint_name

    @property
    def where(self) -> str:
        return self.joint_name

    def bounds(self):
        return np.full(1, -0.95), np.full(1, 100.0)

    def scale(self, refs):
        return np.full(1, 1.0 / refs.max_torque(self.joint_name))

    def adjust_law(self, p, law, column, refs):
        law.beta[column] = p[0]

    def report(self, u, cov_u, refs, units, quantile):
        beta = super().report(u, cov_u, refs, units, quantile)[0]
        se_u = math.sqrt(max(float(cov_u[0, 0]), 0.0))
        rel = float(u[0])
        return [beta, Parameter("relative_change_at_max_torque", rel, se_u,
                                (rel - quantile * se_u, rel + quantile * se_u), "1")]

    def _units(self, units):
        return [("1/N" if self.prismatic else "1/(N.m)", 1.0)]

    def describe(self) -> str:
        return f"joint {self.joint_name}'s spring softens or hardens with the load"


class FrameMisalignment(Effect):
    """Measured ``dx = R(phi) dx_model``."""

    name = "frame_misalignment"
    kind = "measurement"
    param_names = ("rx", "ry", "rz")

    def scale(self, refs):
        return np.full(3, 0.01)

    def adjust_output(self, p, dx):
        return dx @ rotation_matrix(p).T

    def output_tangent(self, p, t):
        return rotation_matrix(p) @ t

    def adjust_rotation(self, p, dphi):
        return dphi @ rotation_matrix(p).T

    def rotation_tangent(self, p, t):
        return rotation_matrix(p) @ t

    def _units(self, units):
        return [(units.angle, units.angle_to_si)] * 3

    def describe(self) -> str:
        return "the instrument's frame is rotated against the robot base"


class TargetOffset(Effect):
    """The target is ``delta`` (target frame axes) away from the declared one."""

    name = "target_offset"
    param_names = ("dx", "dy", "dz")

    def scale(self, refs):
        return np.full(3, 0.01)

    def target_shift(self, p, rows):
        return rows.rotation @ p

    def _units(self, units):
        return [(units.length, units.length_to_si)] * 3

    def describe(self) -> str:
        return "the measured target is not where the campaign says (target frame axes)"


class ForceSensorBias(Effect):
    """The recorded force is ``F + b``."""

    name = "force_sensor_bias"
    kind = "measurement"
    param_names = ("fx", "fy", "fz")

    def scale(self, refs):
        return np.full(3, 0.01 * refs.force_ref)

    def adjust_load(self, p, force, moment):
        return force - p, moment

    def _units(self, units):
        return [(units.force, units.force_to_si)] * 3

    def describe(self) -> str:
        return "the recorded force carries a constant offset (base axes)"


class DeflectionOffset(Effect):
    """The measured deflections carry a constant offset."""

    name = "deflection_offset"
    kind = "measurement"
    param_names = ("dx", "dy", "dz")

    def scale(self, refs):
        return np.full(3, 0.01 * refs.deflection_ref)

    def adjust_output(self, p, dx):
        return dx + p

    def _units(self, units):
        return [(units.length, units.length_to_si)] * 3

    def describe(self) -> str:
        return "the measured deflections carry a constant offset (the reference moved)"


class GravityPreload(Effect):
    """The robot's weight (URDF inertias) and a payload preload the joints at every pose."""

    name = "gravity_preload"
    kind = "preload"
    param_names = ("mass", "com_x", "com_y", "com_z")

    def scale(self, refs):
        return np.array([refs.force_ref / 9.81, 0.1, 0.1, 0.1])

    def bounds(self):
        return np.array([0.0, -1e4, -1e4, -1e4]), np.full(4, 1e4)

    def start(self):
        return np.array([0.05, 0.0, 0.0, 0.0])

    def preload(self, p, model, rows):
        idx = model.index
        if rows.gravity_torque is None or not np.all(np.isfinite(rows.gravity_torque)):
            require_open_chain(model.geometry.robot, self.name)
        tau = rows.gravity_torque[:, idx]
        k_g = rows.gravity_stiffness[:, idx][:, :, idx]
        f = p[0] * np.asarray(model.geometry.robot.model.gravity.linear, dtype=float)
        r = rows.rotation @ p[1:4]
        moment = np.cross(r, f)
        wrench = np.hstack([np.broadcast_to(f, moment.shape), moment])
        tau = tau + model.jv.transpose(0, 2, 1) @ f + np.einsum("mkn,mk->mn", model.jw, moment)
        k_p = np.einsum("mk,mkab->mab", wrench, model.h)
        k_p += model.jw.transpose(0, 2, 1) @ (_skew(f) @ _skew(r)) @ model.jw
        return tau, k_g + k_p

    def _units(self, units):
        return [("kg", 1.0)] + [(units.length, units.length_to_si)] * 3

    def describe(self) -> str:
        return ("the robot's weight and a payload preload the joints (the measured deflection "
                "is loaded minus unloaded under that weight)")


@dataclass(eq=False)
class GravityCompensator(Effect):
    """A spring between the base and a lever on the joint's link
    (:func:`stiffness.mechanics.gravity.spring_balancer`)."""

    joint_name: str = ""
    lever_m: float = COMPENSATOR_GEOMETRY["lever_m"]
    base_m: float = COMPENSATOR_GEOMETRY["base_m"]
    angle0_rad: float = COMPENSATOR_GEOMETRY["angle0_rad"]
    name: ClassVar[str] = "gravity_compensator"
    param_names: ClassVar[tuple[str, ...]] = ("stiffness", "preload")

    def __post_init__(self) -> None:
        if not (self.lever_m > 0 and self.base_m > 0 and abs(self.lever_m - self.base_m) > 1e-6):
            raise StiffnessError(f"gravity_compensator:{self.joint_name} needs a lever and a "
                                 f"base distance that are positive and differ, got "
                                 f"{self.lever_m} and {self.base_m} m")

    @property
    def where(self) -> str:
        return self.joint_name

    @property
    def settings(self) -> dict:
        """The spring's geometry (SI)."""
        return {"lever_m": self.lever_m, "base_m": self.base_m, "angle0_rad": self.angle0_rad}

    def scale(self, refs):
        ad = self.lever_m * self.base_m
        return np.array([0.1 * refs.k_ref / ad, 0.1 * refs.k_ref / self.lever_m])

    def bounds(self):
        return np.array([0.0, -1e4]), np.full(2, 1e4)

    def torque(self, p: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Spring torque (N.m) on the joint at angles ``theta`` (rad) and its derivative."""
        return spring_balancer(theta, p[0], p[1], self.lever_m, self.base_m, self.angle0_rad)

    def preload(self, p, model, rows):
        column = model.joints.index(self.joint_name)
        theta = rows.coords[:, model.geometry.joints.index(self.joint_name)]
        tau_s, dtau = self.torque(p, theta)
        m, n = rows.n_rows, len(model.joints)
        tau, k = np.zeros((m, n)), np.zeros((m, n, n))
        tau[:, column] = tau_s
        k[:, column, column] = dtau
        return tau, k

    def _units(self, units):
        return [("N/m", 1.0), ("N", 1.0)]

    def describe(self) -> str:
        return (f"a spring gravity compensator on {self.joint_name} adds its torque and its "
                "angle derivative (a stiffness) to the joint")


#: Effect name -> class, in the order candidates are listed.
LIBRARY: dict[str, type[Effect]] = {
    cls.name: cls for cls in (ComplementaryStiffness, JointCompliance, LinkCompliance, Backlash,
                              NonlinearJointStiffness, FrameMisalignment, TargetOffset,
                              ForceSensorBias, DeflectionOffset, GravityPreload,
                              GravityCompensator)
}
#: Effects the issue requires (``deflection_offset`` is an extra).
REQUIRED_EFFECTS = tuple(n for n in LIBRARY if n != "deflection_offset")


def make_effect(name: str, where: str | None, geometry: Geometry) -> Effect:
    """An effect by name and place, checked against the robot.

    Raises
    ------
    UnknownEffectError
        Unknown name.
    UnknownJointError, UnknownNameError
        A missing or unknown joint or link segment in ``where``.
    StiffnessError
        A ``where`` on an effect that acts on the whole campaign.
    """
    if name not in LIBRARY:
        raise UnknownEffectError(f"unknown effect {name!r}; {did_you_mean(name, list(LIBRARY))}",
                                 name=name, choices=list(LIBRARY))
    cls = LIBRARY[name]
    if cls in (JointCompliance, Backlash, NonlinearJointStiffness):
        if where not in geometry.joints:
            raise UnknownJointError(f"{name} needs a joint, e.g. {name}:{geometry.joints[0]}; "
                                    f"{did_you_mean(str(where), list(geometry.joints))}",
                                    name=str(where), choices=geometry.joints)
        return cls(joint_name=where,
                   prismatic=bool(geometry.prismatic[geometry.joints.index(where)]))
    if cls is LinkCompliance:
        parts = None
        if where:
            for sep in ("->", "/", ","):
                if sep in where:
                    parts = [s.strip() for s in where.split(sep)]
                    break
        if not parts or len(parts) != 2 or tuple(parts) not in geometry.link_columns:
            pairs = [f"{a}->{b}" for a, b in geometry.link_segments()]
            raise UnknownNameError(
                f"link_compliance needs two joints of the target's chain, proximal first, as "
                f"A->B (or A/B); got {where!r}; valid segments: {', '.join(pairs)}",
                name=str(where), choices=pairs)
        return LinkCompliance(a=parts[0], b=parts[1],
                              column=geometry.link_columns[(parts[0], parts[1])])
    if cls is GravityCompensator:
        if where not in geometry.joints or geometry.prismatic[geometry.joints.index(where)]:
            revolute = [j for j, p in zip(geometry.joints, geometry.prismatic, strict=True)
                        if not p]
            raise UnknownJointError(f"gravity_compensator needs a revolute joint, e.g. "
                                    f"gravity_compensator:{revolute[0]}; "
                                    f"{did_you_mean(str(where), revolute)}", name=str(where),
                                    choices=revolute)
        return GravityCompensator(joint_name=where)
    if where:
        raise StiffnessError(f"{name} acts on the whole campaign; drop ':{where}'")
    if cls is GravityPreload:
        require_open_chain(geometry.robot, name)
    return cls()


# ------------------------------------------------------------------------------------------
# the model


class Model:
    """A deflection model: baseline formulation, compliant joints and effects, over some rows.

    The parameter vector ``x`` is ``ln k`` of the baseline's compliant joints followed by each
    effect's scaled variables (:meth:`Effect.physical`).

    Parameters
    ----------
    geometry
        The robot's shared geometry.
    rows
        The rows to predict.
    baseline
        ``conventional`` or ``enhanced``.
    compliant
        The baseline's compliant joints.
    effects
        Effects, in the order added.
    refs
        Variable scales.
    rotation_weight
        ``None``: the model predicts the (m, 3) translations. A weight ``w`` (m/rad): it
        predicts (m, 6) rows ``[dx; w dphi]``, the rotation ``dphi`` of the target frame
        (rad, base axes) in translation-noise units (``w = sigma_t / sigma_r``), so that one
        residual scale whitens both kinds (:mod:`stiffness.calibration.fitting`).
    """

    def __init__(self, geometry: Geometry, rows: Rows, baseline: str,
                 compliant: tuple[str, ...], effects: tuple[Effect, ...], refs: References,
                 rotation_weight: float | None = None) -> None:
        if baseline not in BASELINES:
            raise UnknownNameError(f"unknown baseline {baseline!r}; valid: {', '.join(BASELINES)}",
                                   name=baseline, choices=BASELINES)
        if baseline == "exact" and effects:
            raise StiffnessError("the exact baseline takes no effects (complementary_stiffness "
                                 "approximates it to second order); start from enhanced")
        self.geometry, self.rows, self.baseline = geometry, rows, baseline
        self.compliant, self.effects, self.refs = tuple(compliant), tuple(effects), refs
        self.rotation_weight = None if rotation_weight is None else float(rotation_weight)
        self.joints = self.compliant + tuple(e.added_joint for e in self.effects
                                             if e.added_joint is not None)
        self.index = np.array([geometry.joints.index(j) for j in self.joints], dtype=int)
        self.tangent = baseline == "enhanced" or any(e.second_order for e in self.effects)
        self.second_order = any(e.second_order for e in self.effects)
        sizes = [len(self.compliant)] + [e.n_params for e in self.effects]
        self.offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
        #: exact baseline: its robot, the rows' unloaded configurations and their kinematics
        self._exact_rows: tuple | None = None
        self._prepare()

    def _prepare(self) -> None:
        idx, rows = self.index, self.rows
        self.jv = rows.jac[:, :3][:, :, idx]
        self.jw = rows.jac[:, 3:][:, :, idx]
        self.h = rows.k_c_unit[:, :, idx][:, :, :, idx]
        self._k_c: np.ndarray | None = None
        self._tau: np.ndarray | None = None

    def _exact_robot(self) -> Robot:
        robot = self.geometry.robot
        if self.joints == tuple(robot.compliant_joints):  # every coordinate joint: no reload
            return robot
        return cached_robot(robot.name, robot.target_frame, tuple(robot.target_offset),
                            self.joints, robot.loop_file, robot.fixed_base)

    # construction ----------------------------------------------------------------------------
    def with_rows(self, rows: Rows) -> Model:
        """The same model over other rows."""
        return Model(self.geometry, rows, self.baseline, self.compliant, self.effects, self.refs,
                     self.rotation_weight)

    def extended(self, effect: Effect) -> Model:
        """This model plus ``effect``."""
        return Model(self.geometry, self.rows, self.baseline, self.compliant,
                     self.effects + (effect,), self.refs, self.rotation_weight)

    def with_refs(self, refs: References) -> Model:
        """The same model with other variable scales."""
        return Model(self.geometry, self.rows, self.baseline, self.compliant, self.effects, refs,
                     self.rotation_weight)

    def with_baseline(self, baseline: str) -> Model:
        """The same model under another baseline."""
        return Model(self.geometry, self.rows, baseline, self.compliant, self.effects, self.refs,
                     self.rotation_weight)

    def with_rotation_weight(self, weight: float | None) -> Model:
        """The same model predicting rotations with weight ``weight`` (m/rad), or only
        translations (``None``)."""
        return Model(self.geometry, self.rows, self.baseline, self.compliant, self.effects,
                     self.refs, weight)

    @property
    def n_outputs(self) -> int:
        """Predicted components per row: 3 (translation) or 6 (translation and rotation)."""
        return 3 if self.rotation_weight is None else 6

    def split(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Translations (m, 3) in m and rotations (m, 3) in rad (or ``None``) of predicted or
        measured rows in this model's output layout."""
        values = np.asarray(values, dtype=float)
        if self.rotation_weight is None:
            return values[:, :3], None
        return values[:, :3], values[:, 3:6] / self.rotation_weight

    @property
    def wrench(self) -> np.ndarray:
        """(m, 6) recorded wrenches of the rows."""
        return np.hstack([self.rows.force, self.rows.moment])

    def k_c(self) -> np.ndarray:
        """(m, n, n) ``K_C`` of each row's recorded wrench over :attr:`joints` (computed once;
        not to be modified)."""
        if self._k_c is None:
            self._k_c = np.einsum("mk,mkab->mab", self.wrench, self.h)
        return self._k_c

    def _torques(self) -> np.ndarray:
        """(m, n) ``J^T W`` of each row's recorded wrench over :attr:`joints` (computed once)."""
        if self._tau is None:
            self._tau = np.einsum("mkn,mk->mn", self.jv, self.rows.force) + np.einsum(
                "mkn,mk->mn", self.jw, self.rows.moment)
        return self._tau

    @property
    def n_params(self) -> int:
        """Length of the parameter vector."""
        return int(self.offsets[-1])

    @property
    def penalty_params(self) -> int:
        """Parameters counted by the information criterion."""
        return len(self.compliant) + sum(e.penalty_params for e in self.effects)

    def extend_x(self, x: np.ndarray, effect: Effect) -> np.ndarray:
        """Start vector of :meth:`extended` from this model's ``x``."""
        return np.concatenate([x, effect.start()])

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounds of the parameter vector."""
        n0 = len(self.compliant)
        lo, hi = [np.full(n0, math.log(1e-3))], [np.full(n0, math.log(1e14))]
        for e in self.effects:
            a, b = e.bounds()
            lo.append(a)
            hi.append(b)
        return np.concatenate(lo), np.concatenate(hi)

    def effect_vars(self, x: np.ndarray, i: int) -> np.ndarray:
        """Optimiser variables of effect ``i``."""
        return x[self.offsets[i + 1]: self.offsets[i + 2]]

    def _effect_params(self, x: np.ndarray) -> list[np.ndarray]:
        return [e.physical(self.effect_vars(x, i), self.refs)
                for i, e in enumerate(self.effects)]

    def stiffness(self, x: np.ndarray) -> np.ndarray:
        """Baseline stiffnesses (SI) of parameter vector ``x``."""
        return np.exp(x[: len(self.compliant)])

    # prediction ------------------------------------------------------------------------------
    def law(self, x: np.ndarray, params: list[np.ndarray] | None = None) -> SpringLaw:
        """The joint law over :attr:`joints`."""
        params = self._effect_params(x) if params is None else params
        n = len(self.joints)
        compliance = np.zeros(n)
        compliance[: len(self.compliant)] = np.exp(-x[: len(self.compliant)])
        law = SpringLaw(compliance, np.zeros(n), np.zeros(n),
                  self.refs.tau_smoothing[self.index].copy())
        for e, p in zip(self.effects, params, strict=True):
            if e.joint is not None:
                e.adjust_law(p, law, self.joints.index(e.joint), self.refs)
        return law

    @property
    def analytic_columns(self) -> np.ndarray:
        """(p,) mask of the parameters :meth:`predict_with_jacobian` differentiates: ``ln k``
        and the variables of effects acting through the joint law (:attr:`Effect.through_law`);
        the fitting engine differentiates the others numerically."""
        mask = np.ones(self.n_params, dtype=bool)
        for i, e in enumerate(self.effects):
            mask[self.offsets[i + 1]: self.offsets[i + 2]] = e.through_law
        return mask

    def predict_with_jacobian(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predicted displacements (m, 3) and their derivatives (m, 3, p) w.r.t. ``x`` in
        the columns of :attr:`analytic_columns` (zeros in the others).

        Linear baselines without effects: ``d pred / d ln k_i = -J_v (K - K_C)^-1 e_i k_i u_i``
        with ``u = (K - K_C)^-1 J^T W``; exact: the implicit function theorem on
        ``K dtheta = J(theta)^T W``, ``d dtheta / d k_i = -(K - K_C(theta))^-1 e_i dtheta_i``.
        With effects: the implicit function theorem on the frozen-geometry law
        (:meth:`stiffness.mechanics.equilibrium.SpringLaw.deflection_tangent`), carried through
        the second-order kinematics, the preload's unloaded equilibrium and the effects'
        output maps (:meth:`Effect.output_tangent`).

        Raises
        ------
        np.linalg.LinAlgError
            If the tangent stiffness is singular for some row.
        StiffnessError
            If the exact equilibrium does not converge or is unstable.
        """
        if self.effects:
            pred, _, _, tangent = self._predict(x, tangent=True)
            jac = np.zeros(pred.shape + (self.n_params,))
            jac[:, :, self.analytic_columns] = tangent
            return pred, jac
        k = np.exp(x[: len(self.compliant)])
        if self.baseline == "exact":
            return self._exact(k)
        a = np.broadcast_to(np.diag(k), (self.rows.n_rows, len(k), len(k))).copy()
        if self.baseline == "enhanced":
            a -= self.k_c()
        inv = np.linalg.inv(a)
        u = np.einsum("mij,mj->mi", inv, self._torques())
        out = self.jv if self.rotation_weight is None else np.concatenate(
            [self.jv, self.rotation_weight * self.jw], axis=1)
        pred = np.einsum("mij,mj->mi", out, u)
        return pred, -(out @ inv) * (u * k)[:, None, :]

    def _law_directions(self, x: np.ndarray, law: SpringLaw
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Changes (P, n) of the law's compliance, ``beta`` and backlash per unit of each
        parameter of :attr:`analytic_columns`: ``dc_i / d ln k_i = -c_i``, and for an effect
        acting through the law the difference of the laws one unit apart (exact: such an
        effect sets the law affinely)."""
        columns = np.flatnonzero(self.analytic_columns)
        n = len(self.joints)
        d = np.zeros((3, len(columns), n))
        n0 = len(self.compliant)
        d[0, np.arange(n0), np.arange(n0)] = -law.compliance[:n0]
        for row, column in enumerate(columns[n0:], start=n0):
            step = x.copy()
            step[column] += 1.0
            moved = self.law(step)
            d[:, row] = (moved.compliance - law.compliance, moved.beta - law.beta,
                         moved.backlash - law.backlash)
        return d[0], d[1], d[2]

    def _exact(self, k: np.ndarray, jacobian: bool = True
               ) -> tuple[np.ndarray, np.ndarray | None]:
        """Exact equilibria of every row (:func:`stiffness.batch.equilibrium.solve_equilibria`)
        and their derivatives w.r.t. ``ln k``."""
        if self._exact_rows is None:
            robot = self._exact_robot()
            rows = self.rows
            q0: dict[int, np.ndarray] = {}
            for i in range(rows.n_rows):
                c = int(rows.config_index[i])
                if c not in q0:
                    q0[c] = robot.configuration(rows.coords[i])
            q = np.array([q0[int(c)] for c in rows.config_index])
            self._exact_rows = (robot, q, unloaded_kinematics(robot, q))
        robot, q, base = self._exact_rows
        kmat = np.diag(k)
        eq = solve_equilibria(robot, q, kmat, self.wrench, base=base)
        w = self.rotation_weight
        out = eq.jacobian[:, :3] if w is None else np.concatenate(
            [eq.jacobian[:, :3], w * eq.jacobian[:, 3:]], axis=1)
        pred = eq.dx if w is None else np.hstack([eq.dx, w * eq.rotation])
        if not jacobian:
            return pred, None
        # implicit function theorem: d dtheta / d ln k_i = -(K - K_C)^-1 e_i k_i dtheta_i
        dtheta = -np.linalg.solve(kmat - eq.k_c, eq.dtheta[:, :, None] * np.diag(k))
        return pred, out @ dtheta

    def predict(self, x: np.ndarray, detail: bool = False):
        """(m, 3) predicted measured displacements (m) for parameters ``x``; (m, 6)
        ``[dx; w dphi]`` with a :attr:`rotation_weight` (first-order rotation ``J_w dtheta``
        plus the effects' rotational parts).

        Effects with a :meth:`Effect.preload` (gravity) make the deflection the loaded minus
        the unloaded frozen-geometry equilibrium, ``dtheta = f(tau_W + tau_p + (K_C + K_p)
        dtheta_1) - f(tau_p + K_p dtheta_0)``, seen through the kinematics of the preloaded
        pose to first order in ``dtheta_0``: ``dx += sum_k e_k dtheta^T H_k dtheta_0`` and
        ``dphi += sum_k e_k dtheta^T K_C(e_k moment) dtheta_0``.

        With ``detail``, also returns the joint deflections (m, n) and torques (m, n).

        Raises
        ------
        np.linalg.LinAlgError
            If the tangent stiffness is singular for some row.
        """
        if self.baseline == "exact":
            if detail:
                raise StiffnessError("the exact baseline gives no linear detail")
            return self._exact(np.exp(x[: len(self.compliant)]), jacobian=False)[0]
        dx, dtheta, tau, _ = self._predict(x, tangent=False, torques=detail)
        return (dx, dtheta, tau) if detail else dx

    def _predict(self, x: np.ndarray, tangent: bool, torques: bool = False
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
        """:meth:`predict` of a linear-kinematics baseline: the predicted rows, the joint
        deflections, with ``torques`` the joint torques (else ``None``), and with ``tangent``
        the (m, 3 or 6, P) derivatives of the rows along the parameters of
        :attr:`analytic_columns`."""
        rows = self.rows
        params = self._effect_params(x)
        force, moment = rows.force, rows.moment
        for e, p in zip(self.effects, params, strict=True):
            force, moment = e.adjust_load(p, force, moment)
        jv, jw, point = self.jv, self.jw, rows.position
        for e, p in zip(self.effects, params, strict=True):
            shift = e.target_shift(p, rows)
            if shift is not None:
                jv = jv - _skew(shift) @ jw
                point = point + shift
        tau0 = np.einsum("mkn,mk->mn", jv, force) + np.einsum("mkn,mk->mn", jw, moment)
        law = self.law(x, params)
        directions = self._law_directions(x, law) if tangent else None
        k_c = None
        if self.tangent:
            k_c = np.einsum("mk,mkab->mab", np.hstack([force, moment]), self.h)
        pre_tau = pre_k = None
        for e, p in zip(self.effects, params, strict=True):
            pre = e.preload(p, self, rows)
            if pre is not None:
                pre_tau = pre[0] if pre_tau is None else pre_tau + pre[0]
                pre_k = pre[1] if pre_k is None else pre_k + pre[1]

        def equilibrium(torque, stiffness):
            d = law.frozen_deflection(torque, stiffness, LAW_ITERATIONS)
            return d, (law.deflection_tangent(torque, stiffness, d, *directions)
                       if tangent else None)

        if pre_tau is None:
            dtheta, t_theta = equilibrium(tau0, k_c)
            unloaded = t_unloaded = None
        else:  # loaded minus unloaded equilibrium, both under the preload
            loaded, t_loaded = equilibrium(tau0 + pre_tau,
                                           pre_k if k_c is None else k_c + pre_k)
            unloaded, t_unloaded = equilibrium(pre_tau, pre_k)
            dtheta = loaded - unloaded
            t_theta = t_loaded - t_unloaded if tangent else None
        h_v = self.h[:, :3]
        dx = np.einsum("mkn,mn->mk", jv, dtheta)
        t_dx = jv @ t_theta if tangent else None
        if self.second_order:
            dx = dx + 0.5 * np.einsum("mkab,ma,mb->mk", h_v, dtheta, dtheta)
            if tangent:
                t_dx = t_dx + 0.5 * (_contract(h_v, dtheta, 2) + _contract(h_v, dtheta, 3)
                                     ) @ t_theta
        if unloaded is not None:  # the load acts on the arm already deflected by the preload
            dx = dx + np.einsum("mkab,ma,mb->mk", h_v, dtheta, unloaded)
            if tangent:
                t_dx = (t_dx + _contract(h_v, unloaded, 3) @ t_theta
                        + _contract(h_v, dtheta, 2) @ t_unloaded)
        for e, p in zip(self.effects, params, strict=True):
            extra = e.displacement(p, self, rows, force, moment, point)
            if extra is not None:
                dx = dx + extra
        for e, p in zip(self.effects, params, strict=True):
            dx = e.adjust_output(p, dx)
            if tangent:
                t_dx = e.output_tangent(p, t_dx)
        if self.rotation_weight is not None:
            h_w = self.h[:, 3:]
            dphi = np.einsum("mkn,mn->mk", jw, dtheta)
            t_phi = jw @ t_theta if tangent else None
            if unloaded is not None:  # J_w at the preloaded pose: K_C of unit moments
                dphi = dphi + np.einsum("mkab,ma,mb->mk", h_w, dtheta, unloaded)
                if tangent:
                    t_phi = (t_phi + _contract(h_w, unloaded, 3) @ t_theta
                             + _contract(h_w, dtheta, 2) @ t_unloaded)
            for e, p in zip(self.effects, params, strict=True):
                extra = e.rotation(p, self, rows, force, moment, point)
                if extra is not None:
                    dphi = dphi + extra
            for e, p in zip(self.effects, params, strict=True):
                dphi = e.adjust_rotation(p, dphi)
                if tangent:
                    t_phi = e.rotation_tangent(p, t_phi)
            dx = np.hstack([dx, self.rotation_weight * dphi])
            if tangent:
                t_dx = np.concatenate([t_dx, self.rotation_weight * t_phi], axis=1)
        tau = None
        if torques:
            tau = tau0 if k_c is None else tau0 + np.einsum("mab,mb->ma", k_c, dtheta)
        return dx, dtheta, tau, t_dx

    def describe(self) -> str:
        """E.g. ``enhanced over joint1, joint2 + backlash(joint2)``."""
        text = f"{self.baseline} over {', '.join(self.compliant)}"
        return text + "".join(f" + {e.label}" for e in self.effects)


def candidates(model: Model) -> list[Effect]:
    """Every library effect that can extend ``model`` (each effect and place at most once).

    ``complementary_stiffness``; ``joint_compliance`` of each rigid coordinate joint;
    ``link_compliance`` of each chain segment (:meth:`Geometry.link_segments`); ``backlash``
    and ``nonlinear_joint_stiffness`` of each compliant joint; then the global effects.
    """
    geo = model.geometry
    have = {e.key() for e in model.effects}
    out: list[Effect] = []

    def add(effect: Effect) -> None:
        if effect.key() not in have:
            out.append(effect)

    if not model.second_order:
        add(ComplementaryStiffness())
    for j in geo.joints:
        if j not in model.joints:
            add(make_effect("joint_compliance", j, geo))
    for a, b in geo.link_segments():
        add(LinkCompliance(a=a, b=b, column=geo.link_columns[(a, b)]))
    for j in model.joints:
        add(make_effect("backlash", j, geo))
        add(make_effect("nonlinear_joint_stiffness", j, geo))
    for name in ("frame_misalignment", "target_offset", "force_sensor_bias",
                 "deflection_offset"):
        add(LIBRARY[name]())
    if geo.robot.loop.is_open_chain:  # the weight of passive loop joints is not modelled
        add(GravityPreload())
    for j in model.joints:
        if not geo.prismatic[geo.joints.index(j)]:
            add(make_effect("gravity_compensator", j, geo))
    return out
