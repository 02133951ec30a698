"""Synthetic pose campaigns: what a tracker would see of an arm with hidden geometric and
elastic errors, under its weight and an optional payload.

The simulated truth is computed independently of the fitted model
(:mod:`stiffness.calibration.pose_model`): the joint placements are perturbed exactly
(``M_j exp(eps_j)``), the sag is the exact static equilibrium of joint springs under gravity and
the applied wrench, ``K (q_l - q_c - delta_0) = J(q_l)^T w - g(q_l)`` (fixed-point iteration to
1e-14 rad; springs on a ``[controller]``'s coordinates ``u``, ``q_chain = A u + b``, hold
``K_u Delta u = A^T (J^T w - g)`` with ``Delta q = A Delta u``; a nonlinear spring's
``Delta u = t / k (1 + beta |t|)`` at the torque ``t = A^T (J^T w - g)`` it carries), and the
measuring frame is an arbitrary rigid placement. Hidden elastic effects beyond the joint
springs act in the same equilibrium: a spring compensator's torque
(:func:`spring_compensator_torque`, from the spring's attachment points, not from the
library's scalar law) joins the joint's torque,
backlash adds ``b tanh(t / tau_s)`` to its spring's deflection (``t = A^T tau`` on a controller
coordinate; ``tau_s`` computed here from the commanded poses' torques:
:func:`smoothing_torques`), and a link bend rotates the part of the
arm beyond the link's distal joint exactly (its placement turned by ``omega``) under the moment
that part's weight and the wrench exert there, taken from Pinocchio's recursive Newton-Euler
forces (not from the centre-of-mass form the fitted model uses), about two axes normal to the
link derived here (:func:`link_column`, :func:`bend_axes`); a joint tilting in its bearing
(transversal compliance) turns its placement the same way about the two axes of its mounting
frame normal to its own (its rotation axis from its motion subspace:
:func:`rotation_axis_column`). What a parameter means (which axes, which ``tau_s``) must be the
fitted model's; these derivations are this module's own and a test checks they agree. The
fitted model's code supplies only which joint pairs are links (their names). A tilted base
turns the model's gravity into the base's axes, so every torque and every bend of the
equilibrium sees it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from stiffness.batch.linalg import cross
from stiffness.calibration.campaign_toml import RobotSettings
from stiffness.calibration.pose_campaign import PoseCampaign
from stiffness.calibration.pose_model import Loads, Marker, pose_joints
from stiffness.calibration.poses import sample_coordinates
from stiffness.elastic.effects.link_bends import marker_links
from stiffness.elastic.effects.preloads import GravityCompensator, compensated_joints
from stiffness.errors import ConvergenceError, LoopClosureError, StiffnessError
from stiffness.mechanics.equilibrium import SpringLaw
from stiffness.mechanics.gravity import upward_angle
from stiffness.robot.kinematics import frame_id
from stiffness.robot.loops import LoopClosure
from stiffness.robot.robot import Robot
from stiffness.units import Units

#: Fixed-point tolerance of the sag (rad or m) and its iteration cap.
_SAG_TOL = 1e-14
_SAG_ITERATIONS = 200
#: Backlash's smoothing torque over the joint's RMS torque at the campaign's commanded poses:
#: part of the definition of the half-width ``b`` of ``b tanh(tau / tau_s)`` (the fitted
#: model's :data:`~stiffness.elastic.effects.geometry.BACKLASH_SMOOTHING`; the simulator
#: computes ``tau_s`` itself, :func:`smoothing_torques`, and a test checks the two agree).
SMOOTHING_FRACTION = 0.02
#: The hidden compensator's spring: lever on the link and base point on its parent, both from
#: the joint axis (m), in line when the link points up (the library's default geometry).
SPRING_LEVER_M, SPRING_BASE_M = 0.1, 0.3


@dataclass
class HiddenPoseErrors:
    """The truth a simulated pose campaign hides (SI).

    Attributes
    ----------
    frame_rotation, frame_translation
        Placement of the measuring frame: ``y = R p + t`` for a point ``p`` in robot world.
    marker_offsets
        (M, 3) true marker offsets in their frames (m).
    joint_offsets
        (n_joints,) zero offsets of the robot's 1-dof joints (model order), rad or m.
    placement_errors
        (n_joints, 6) placement errors ``eps_j`` of the same joints.
    stiffness
        (n_compliant,) joint stiffness (N.m/rad or N/m) of the robot's compliant joints
        (``inf``: that spring rigid, its backlash alone moving it), or ``None`` for a rigid
        arm.
    drift
        Drift of the measuring frame's origin over the campaign (m), linear along the rows.
    link_compliance
        ``"a->b"`` (joint names of a link of a marker's chain,
        :func:`~stiffness.elastic.effects.link_bends.marker_links`) -> its two bending
        compliances (rad/(N.m)).
    backlash
        (n_compliant,) backlash half-widths (rad or m) of the springs (on the controller's
        coordinates when the springs act there), smoothed as the deflection library's
        (``tau_s`` from the torques the springs carry over the campaign), or ``None``.
    compensator
        Revolute compliant joint name (or a compliant controller coordinate that alone turns
        one chain joint at rate 1, its angle the coordinate's:
        :func:`~stiffness.elastic.effects.preloads.compensated_joints`) -> (stiffness N/m,
        tension N with the link up) of a spring compensator with the library's default
        geometry
        (:func:`spring_compensator_torque`, its angle from the link's upward direction:
        :func:`~stiffness.mechanics.gravity.upward_angle`).
    transversal_compliance
        Name of a revolute joint the springs turn (a compliant joint, or a chain joint a
        compliant controller coordinate drives: :meth:`Robot.driven_joints`) of a marker's
        chain, its axis a frame axis
        (:func:`~stiffness.elastic.effects.link_bends.transversal_joints`) -> its two tilting
        compliances (rad/(N.m)) about the axes of its mounting frame normal to its own (the
        simulator finds the axis itself: :func:`rotation_axis_column`).
    base_tilt
        ``(r_x, r_y)`` (rad): the base's z axis turned from the vertical by
        ``exp([r_x, r_y, 0])``, so the links' weight acts along ``exp(.)^T g``, or ``None``.
    nonlinear
        (n_compliant,) each spring's ``beta`` (1/(N.m), 1/N prismatic) of a nonlinear spring,
        ``Delta u = t / k (1 + beta |t|)`` with ``t`` the torque it carries (``beta > 0``
        softens, ``< 0`` hardens; the deflection library's law), or ``None``: linear springs.
    """

    frame_rotation: np.ndarray
    frame_translation: np.ndarray
    marker_offsets: np.ndarray
    joint_offsets: np.ndarray
    placement_errors: np.ndarray
    stiffness: np.ndarray | None = None
    drift: np.ndarray = field(default_factory=lambda: np.zeros(3))
    link_compliance: dict[str, np.ndarray] = field(default_factory=dict)
    backlash: np.ndarray | None = None
    compensator: dict[str, np.ndarray] = field(default_factory=dict)
    transversal_compliance: dict[str, np.ndarray] = field(default_factory=dict)
    base_tilt: np.ndarray | None = None
    nonlinear: np.ndarray | None = None


def true_model(robot: Robot, hidden: HiddenPoseErrors) -> pin.Model:
    """The robot's model with the hidden placement errors applied (``M_j exp(eps_j)``) and its
    gravity turned into the tilted base's axes."""
    model = pin.Model(robot.model)
    for j, eps in zip(pose_joints(robot), hidden.placement_errors, strict=True):
        model.jointPlacements[j] = model.jointPlacements[j] * pin.exp6(pin.Motion(eps))
    if hidden.base_tilt is not None:
        tilt = pin.exp3(np.array([hidden.base_tilt[0], hidden.base_tilt[1], 0.0]))
        model.gravity = pin.Motion(tilt.T @ model.gravity.linear, np.zeros(3))
    return model


@dataclass
class HiddenElasticity:
    """The hidden elastic effects laid out for the equilibrium (SI).

    Attributes
    ----------
    spring_map
        (nv, n_compliant) joint rates per unit rate of each spring's coordinate (unit columns
        for springs on joints: :meth:`Robot.rate_projection`).
    stiffness
        (n_compliant,) spring stiffness.
    beta
        (n_compliant,) each spring's softening (1/(N.m), 1/N; 0: linear).
    backlash, smoothing
        (n_compliant,) backlash half-widths and smoothing torques.
    compensators
        (velocity index, joint id, the chain joint's angle with the link up (rad: the
        spring's reference plus the offset ``b`` of a controller coordinate's ``q_j = u +
        b``), (stiffness N/m, tension N)) per compensated joint.
    links
        (bend, its two compliances) per bending link or joint tilting in its bearing.
    """

    spring_map: np.ndarray
    stiffness: np.ndarray
    beta: np.ndarray
    backlash: np.ndarray
    smoothing: np.ndarray
    compensators: list[tuple[int, int, float, np.ndarray]]
    links: list[tuple[Bend, np.ndarray]]


@dataclass(frozen=True)
class Bend:
    """A part of the arm turning about two axes at joint ``b``'s origin (joint ids): the link
    ``a -> b`` bending (``a != b``; axes normal to the segment: :func:`bend_axes` from the
    ``column``-th axis of the body ``b`` is mounted on) or joint ``b`` tilting in its bearing
    (``a == b``; the two axes of its mounting frame other than its rotation axis, the
    ``column``-th)."""

    a: int
    b: int
    column: int


def bend_axes(p_a: np.ndarray, p_b: np.ndarray, mount_rotation: np.ndarray, column: int
              ) -> tuple[np.ndarray, np.ndarray]:
    """The two unit axes (3,) a link ``p_a -> p_b`` (m, world) bends about: ``e_2`` normal to
    both the link and the mounting body's ``column``-th axis ``r`` (``u x r / |u x r|``, ``u``
    the link's direction), ``e_1 = e_2 x u`` (``r`` with its part along the link removed)."""
    u = (p_b - p_a) / np.linalg.norm(p_b - p_a)
    e2 = cross(u, mount_rotation[:, column])
    e2 = e2 / np.linalg.norm(e2)
    return cross(e2, u), e2


def link_column(model: pin.Model, a: int, b: int, q: np.ndarray | None = None) -> int:
    """The axis (0, 1, 2) of the body joint ``b`` is mounted on that is most nearly normal to
    the link ``a -> b`` at the configuration ``q`` (default the zero coordinates; the smallest
    ``|u . r_i|``, ``u`` the link's direction; of two normal ones, the one nearer by rounding,
    as the fitted model picks)."""
    data = model.createData()
    pin.forwardKinematics(model, data, pin.neutral(model) if q is None else q)
    seg = data.oMi[b].translation - data.oMi[a].translation
    mount = data.oMi[model.parents[b]].rotation
    return int(np.argmin(np.abs(mount.T @ (seg / np.linalg.norm(seg)))))


def rotation_axis_column(model: pin.Model, joint: int) -> int | None:
    """The frame axis (0, 1, 2) a revolute joint turns about, from its motion subspace (its
    local Jacobian's column), or ``None`` when it is not revolute about a frame axis."""
    jm = model.joints[joint]
    if jm.nv != 1:
        return None
    data = model.createData()
    jac = pin.computeJointJacobian(model, data, pin.neutral(model), joint).reshape(6, -1)
    s = jac[:, jm.idx_v]
    column = int(np.argmax(np.abs(s[3:])))
    if np.linalg.norm(s[:3]) > 1e-12 or abs(abs(s[3 + column]) - 1.0) > 1e-12:
        return None
    return column


def hidden_elasticity(robot: Robot, markers: list[Marker], hidden: HiddenPoseErrors,
                      smoothing: dict[str, float]) -> HiddenElasticity | None:
    """``hidden``'s elastic effects for :func:`loaded_arm` (``None``: a rigid arm).

    Raises
    ------
    StiffnessError
        A hidden link that is not a link of the markers' chains, or a compensator on a joint
        that is not a revolute compliant joint.
    """
    if hidden.stiffness is None:
        return None
    model = robot.model
    for where in hidden.compensator:  # on a link: a coordinate only one to one with its joint
        if problem := GravityCompensator.placement_problem(robot, where):
            raise StiffnessError(f"hidden {problem}")
    names = list(robot.compliant_joints)
    # which joint pairs are links is the fitted model's naming (the parameters it reports);
    # the axes a link bends about are this module's own (link_column, bend_axes)
    links = {f"{model.names[k.a]}->{model.names[k.b]}": (k.a, k.b)
             for k in marker_links(model, [frame_id(model, m.frame) for m in markers])}
    unknown = [w for w in hidden.link_compliance if w not in links]
    if unknown:
        raise StiffnessError(f"hidden link_compliance on {unknown}: not links of the markers' "
                             f"chains; valid: {', '.join(links)}")
    compensated = {name: (j, offset) for name, j, offset in compensated_joints(robot, names)}
    wrong = [j for j in hidden.compensator if j not in compensated]
    if wrong:
        raise StiffnessError(f"hidden gravity_compensator on {wrong}: name revolute compliant "
                             f"joints ({', '.join(compensated)})")
    n = len(names)
    bends = [(Bend(*links[w], link_column(model, *links[w])), np.asarray(c, dtype=float))
             for w, c in hidden.link_compliance.items()]
    return HiddenElasticity(
        robot.rate_projection(robot.compliant_joints), np.asarray(hidden.stiffness, dtype=float),
        np.zeros(n) if hidden.nonlinear is None else np.asarray(hidden.nonlinear, dtype=float),
        np.zeros(n) if hidden.backlash is None else np.asarray(hidden.backlash, dtype=float),
        np.array([smoothing.get(j, 1.0) for j in names]),
        [(model.joints[compensated[j][0]].idx_v, compensated[j][0],
          upward_angle(robot, j).angle_rad + compensated[j][1], np.asarray(p, dtype=float))
         for j, p in hidden.compensator.items()],
        sorted(bends + _tilting(robot, markers, hidden), key=lambda item: item[0].b))


def _tilting(robot: Robot, markers: list[Marker], hidden: HiddenPoseErrors
             ) -> list[tuple[Bend, np.ndarray]]:
    """``hidden``'s joints tilting in their bearings as bends ``(j, j, axis column)``.

    Raises
    ------
    StiffnessError
        A joint that is not a revolute joint the springs turn (a compliant joint, or a chain
        joint a compliant controller coordinate drives) of the markers' chains with its axis
        along a frame axis.
    """
    model = robot.model
    moved = {int(j) for m in markers
             for j in model.supports[model.frames[frame_id(model, m.frame)].parentJoint]}
    joints = {}
    for name in robot.driven_joints(robot.compliant_joints):
        j = int(model.getJointId(name))
        column = rotation_axis_column(model, j) if j in moved else None
        if column is not None:
            joints[name] = Bend(j, j, column)
    wrong = [j for j in hidden.transversal_compliance if j not in joints]
    if wrong:
        raise StiffnessError(f"hidden transversal_compliance on {wrong}: name revolute joints "
                             f"the springs turn on the markers' chains, about a frame axis "
                             f"({', '.join(joints)})")
    return [(joints[j], np.asarray(c, dtype=float))
            for j, c in hidden.transversal_compliance.items()]


def loaded_arm(model: pin.Model, q_command: np.ndarray, springs: HiddenElasticity | None,
               wrench: np.ndarray | None, load_frame: str, loop: LoopClosure | None = None
               ) -> tuple[pin.Model, np.ndarray]:
    """The exact equilibrium of the hidden elasticity under gravity and ``wrench``: the model
    with its links bent and the loaded configuration (fixed point of joints and bends). With
    closed loops (``loop``; ``q_command`` closed) the springs' coordinates are independent
    ones: each iterate is closed over the passive joints and the springs carry the torque
    the independent coordinates feel, :func:`loop_torque`."""
    if springs is None:
        return model, q_command
    try:
        return _sag(model, q_command, springs, wrench, load_frame, loop)
    except LoopClosureError as exc:  # an iterate past the loops' reach
        where = "" if exc.loop is None or exc.residual is None else \
            f" ({exc.loop} stays {exc.residual:.3g} m open)"
        raise ConvergenceError(
            f"the simulated sag takes the loops out of reach{where}: the springs are too soft "
            "for the arm's weight and the payload at this pose; raise the stiffness or lower "
            "the payload") from None


def _sag(model: pin.Model, q_command: np.ndarray, springs: HiddenElasticity,
         wrench: np.ndarray | None, load_frame: str, loop: LoopClosure | None
         ) -> tuple[pin.Model, np.ndarray]:
    """:func:`loaded_arm`'s fixed point (``springs`` given)."""
    bends = np.zeros((len(springs.links), 3))
    dv = np.zeros(model.nv)
    law = SpringLaw(1.0 / springs.stiffness, springs.beta, springs.backlash, springs.smoothing)
    for _ in range(_SAG_ITERATIONS):
        bent = _bent(model, q_command, dv, springs, bends)
        data = bent.createData()
        q = _closed(bent, data, pin.integrate(bent, q_command, dv), loop)
        torque = loop_torque(bent, data, q, loop,
                             _joint_torque(bent, data, q, springs, wrench, load_frame))
        tau = springs.spring_map.T @ torque  # the torque each spring carries
        new = springs.spring_map @ law(tau)[0]
        new_bends = _bend_rotations(bent, data, q, springs, wrench, load_frame)
        change = max(np.max(np.abs(new - dv)), np.max(np.abs(new_bends - bends), initial=0.0))
        dv, bends = new, new_bends
        if change < _SAG_TOL:
            bent = _bent(model, q_command, dv, springs, bends)
            return bent, _closed(bent, bent.createData(), pin.integrate(bent, q_command, dv),
                                 loop)
    raise ConvergenceError("the simulated sag did not converge: the springs are too soft for "
                           "the arm's weight; raise the stiffness")


def _closed(model: pin.Model, data: pin.Data, q: np.ndarray, loop: LoopClosure | None
            ) -> np.ndarray:
    """``q`` with the loops closed over their passive joints (itself for an open chain)."""
    return q if loop is None else loop.close(model, data, q)


def loop_torque(model: pin.Model, data: pin.Data, q: np.ndarray, loop: LoopClosure | None,
                torque: np.ndarray) -> np.ndarray:
    """The generalised force (nv,) the independent coordinates feel of the tree's ``torque``
    at the closed ``q``: ``tau_i + R^T tau_p`` with ``R`` the passive joints' rates per
    independent rate (virtual work through the loop), zero on the passive coordinates;
    ``torque`` itself for an open chain."""
    return torque if loop is None else loop.tangent(model, data, q).T @ torque


def _joint_torque(model: pin.Model, data: pin.Data, q: np.ndarray, springs: HiddenElasticity,
                  wrench: np.ndarray | None, load_frame: str) -> np.ndarray:
    """Gravity's, the wrench's and the compensators' torque (nv,) at ``q``."""
    torque = -pin.computeGeneralizedGravity(model, data, q)
    if wrench is not None:
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        torque = torque + pin.getFrameJacobian(model, data, frame_id(model, load_frame),
                                               pin.LOCAL_WORLD_ALIGNED).T @ wrench
    for v, joint, up, (stiffness, tension) in springs.compensators:
        jm = model.joints[joint]
        theta = (np.arctan2(q[jm.idx_q + 1], q[jm.idx_q]) if jm.nq == 2 else q[jm.idx_q])
        torque[v] += spring_compensator_torque(theta - up, stiffness, tension)
    return torque


def spring_compensator_torque(theta: float, stiffness: float, tension: float,
                              lever_m: float = SPRING_LEVER_M, base_m: float = SPRING_BASE_M
                              ) -> float:
    """Torque (N.m) about its joint's axis of a spring from a base point ``base_m`` above the
    axis to a point of the link ``lever_m`` from it, the link turned by ``theta`` (rad) from
    up; the spring's tension is ``tension + stiffness (L - (base_m - lever_m))`` (N, N/m; L
    its length). Computed from the two points in the joint's plane: ``z . (r x F)``."""
    lever = lever_m * np.array([-np.sin(theta), np.cos(theta)])
    span = np.array([0.0, base_m]) - lever
    length = float(np.hypot(*span))
    force = (tension + stiffness * (length - (base_m - lever_m))) * span / length
    return float(lever[0] * force[1] - lever[1] * force[0])


def _bent(model: pin.Model, q_command: np.ndarray, dv: np.ndarray, springs: HiddenElasticity,
          bends: np.ndarray) -> pin.Model:
    """``model`` with each link's distal placement turned by its bend (world rotation vector
    about the distal joint's origin), base links first."""
    if not springs.links:
        return model
    bent = pin.Model(model)
    data = bent.createData()
    q = pin.integrate(model, q_command, dv)
    for (link, _), omega in zip(springs.links, bends, strict=True):
        pin.forwardKinematics(bent, data, q)
        mount = data.oMi[bent.parents[link.b]].rotation @ bent.jointPlacements[link.b].rotation
        turn = pin.SE3(pin.exp3(mount.T @ omega), np.zeros(3))
        bent.jointPlacements[link.b] = bent.jointPlacements[link.b] * turn
    return bent


def _bend_rotations(model: pin.Model, data: pin.Data, q: np.ndarray, springs: HiddenElasticity,
                    wrench: np.ndarray | None, load_frame: str) -> np.ndarray:
    """(L, 3) bend of each link: ``sum_i e_i c_i (e_i . M_b)``, ``M_b`` the moment about the
    distal joint's origin of the weight beyond it (Newton-Euler: minus the force its parent
    transmits) and of the wrench if it acts beyond."""
    if not springs.links:
        return np.zeros((0, 3))
    zero = np.zeros(model.nv)
    pin.rnea(model, data, q, zero, zero)
    # rnea leaves data.oMi as they were (set only by computeJointJacobians with a wrench):
    # without a payload every link bend read identities and came out NaN
    pin.forwardKinematics(model, data, q)
    pin.updateFramePlacements(model, data)
    fid = frame_id(model, load_frame)
    out = np.zeros((len(springs.links), 3))
    for n, (link, c) in enumerate(springs.links):
        p_b = data.oMi[link.b].translation
        moment = -data.oMi[link.b].rotation @ data.f[link.b].angular
        if wrench is not None and link.b in set(model.supports[model.frames[fid].parentJoint]):
            moment = moment + cross(data.oMf[fid].translation - p_b, wrench[:3]) + wrench[3:]
        if link.a == link.b:  # a joint tilting: the bearing's axes normal to the joint's
            mount = data.oMi[model.parents[link.b]].rotation @ model.jointPlacements[
                link.b].rotation
            e1, e2 = mount[:, (link.column + 1) % 3], mount[:, (link.column + 2) % 3]
        else:
            e1, e2 = bend_axes(data.oMi[link.a].translation, p_b,
                               data.oMi[model.parents[link.b]].rotation, link.column)
        out[n] = e1 * c[0] * (e1 @ moment) + e2 * c[1] * (e2 @ moment)
    return out


def simulate_pose_campaign(robot: Robot, markers: list[Marker], hidden: HiddenPoseErrors,
                           n_poses: int, noise_std: float, seed: int = 0,
                           payload: np.ndarray | None = None, units: Units | None = None,
                           name: str = "simulated-poses",
                           rotation_noise_std: float | None = None,
                           coordinates: np.ndarray | None = None) -> PoseCampaign:
    """A pose campaign of ``n_poses`` reachable poses seen through ``hidden``.

    Parameters
    ----------
    markers
        The markers with their *nominal* offsets (what the campaign file declares).
    payload
        A constant wrench (6,) at the robot's target frame (world axes), or ``None``.
    noise_std
        Isotropic Gaussian noise of each position component (m).
    rotation_noise_std
        When given, the markers' orientations are measured too (rotation vectors of their
        own frames, turned by their ``rotation``, in the measuring frame), each with a
        rotation ``exp(n)``, ``n`` Gaussian of this std per component (rad), applied on the
        measuring side.
    coordinates
        The ``n_poses`` commanded poses (rad, m) instead of drawing them (the seed then draws
        the noise only): another truth seen at a campaign's poses.
    """
    rng = np.random.default_rng(seed)
    model = true_model(robot, hidden)
    q, commands = (
        _commanded_poses(robot, model, hidden, sample_coordinates(robot, n_poses, rng), rng)
        if coordinates is None else _commanded_poses(
            robot, model, hidden, np.asarray(coordinates, dtype=float).reshape(n_poses, -1)))
    loads = None if payload is None else Loads(robot.target_frame,
                                               np.tile(payload, (n_poses, 1)))
    springs = hidden_elasticity(robot, markers, hidden, smoothing_torques(robot, q, payload))
    positions = np.empty((n_poses, len(markers), 3))
    orientations = np.empty((n_poses, len(markers), 3, 3))
    loop = None if robot.loop.is_open_chain else robot.loop
    for i, q_full in enumerate(commands):
        bent, q_l = loaded_arm(model, q_full, springs, payload, robot.target_frame, loop)
        data = bent.createData()
        pin.framesForwardKinematics(bent, data, q_l)
        for k, m in enumerate(markers):
            point = data.oMf[frame_id(bent, m.frame)].act(hidden.marker_offsets[k])
            orientations[i, k] = (hidden.frame_rotation @ data.oMf[frame_id(bent, m.frame)]
                                  .rotation @ m.rotation)
            positions[i, k] = (hidden.frame_rotation @ point + hidden.frame_translation
                               + hidden.drift * i / max(n_poses - 1, 1))
    positions += rng.normal(0.0, noise_std, positions.shape)
    rotations = None
    if rotation_noise_std is not None:
        noise = rng.normal(0.0, rotation_noise_std, positions.shape)
        rotations = np.array([[pin.log3(pin.exp3(e) @ r) for e, r in zip(er, rr, strict=True)]
                              for er, rr in zip(noise, orientations, strict=True)])
    settings = RobotSettings(robot.name, robot.target_frame,
                             compliant_joints=tuple(robot.compliant_joints))
    return PoseCampaign(name, robot, settings, units or Units("rad", "N", "m"), markers,
                        [f"p{i + 1}" for i in range(n_poses)], q, positions, loads, noise_std,
                        rotations=rotations, noise_std_rotation=rotation_noise_std)


def smoothing_torques(robot: Robot, q: np.ndarray, payload: np.ndarray | None
                      ) -> dict[str, float]:
    """Backlash smoothing torque ``tau_s`` (N.m, N) of each spring (compliant joint or
    controller coordinate): the :data:`SMOOTHING_FRACTION` of the RMS torque it carries at the
    commanded poses ``q`` (coordinates, rad or m) of the nominal robot, ``S^T (-g(q) + J(q)^T
    w)`` under its weight and the ``payload`` wrench at the target frame (world axes; ``None``:
    none; ``S``: :meth:`Robot.rate_projection`, the unit columns for springs on joints; with
    closed loops, of the torque the independent coordinates feel, :func:`loop_torque`). A
    spring that carries none gets 1 (its backlash never opens)."""
    model = robot.model
    data = model.createData()
    fid = frame_id(model, robot.target_frame)
    torques = np.empty((len(q), model.nv))
    for i, coords in enumerate(q):
        q_full = robot.configuration(coords)
        torques[i] = -pin.computeGeneralizedGravity(model, data, q_full)
        if payload is not None:
            pin.computeJointJacobians(model, data, q_full)
            pin.updateFramePlacements(model, data)
            torques[i] += pin.getFrameJacobian(model, data, fid,
                                               pin.LOCAL_WORLD_ALIGNED).T @ payload
        torques[i] = loop_torque(model, data, q_full, None if robot.loop.is_open_chain
                                 else robot.loop, torques[i])
    rms = np.sqrt(np.mean((torques @ robot.rate_projection(robot.compliant_joints)) ** 2,
                          axis=0))
    return {name: float(SMOOTHING_FRACTION * r) if r > 0 else 1.0
            for name, r in zip(robot.compliant_joints, rms, strict=True)}


#: Poses drawn again, at most, in place of one whose truth does not assemble.
_REDRAWS = 50


def _commanded_poses(robot: Robot, model: pin.Model, hidden: HiddenPoseErrors, q: np.ndarray,
                     rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The poses ``q`` (rad, m) and the configurations the links are at there before sagging
    (:func:`_command`), each closed once. With ``rng``, a pose whose links, at the hidden zero
    offsets and geometry, do not close the loops is drawn again (:func:`sample_coordinates`):
    the commanded assembly reaches a pose near a fold that the offsets take past it
    (digit_like's knee loop with 0.5 deg on motor_knee: seeds 2 and 3 of 20 poses each drew
    one, and the simulation stopped on 'the kinematic loop does not close'). Unchanged on an
    open chain, or when every pose assembles.

    Raises
    ------
    LoopClosureError
        Without ``rng``, when a pose's truth does not close.
    ConvergenceError
        When :data:`_REDRAWS` poses drawn in place of one all fail so.
    """
    poses, commands = [], []
    for coords in q:
        for _ in range(_REDRAWS):
            try:
                commands.append(_command(robot, model, hidden, coords))
                break
            except LoopClosureError:
                if rng is None:
                    raise
                coords = sample_coordinates(robot, 1, rng)[0]
        else:
            raise ConvergenceError(
                f"the hidden zero offsets or geometry of {robot.title} open its loops at "
                f"{_REDRAWS} poses in a row: they take the loops out of reach; hide smaller ones")
        poses.append(coords)
    return np.array(poses), np.array(commands)


def _command(robot: Robot, model: pin.Model, hidden: HiddenPoseErrors, coords: np.ndarray
             ) -> np.ndarray:
    """The configuration the links are at before sagging: commanded plus zero offsets (the
    loops closed again over their passive joints)."""
    offsets = np.zeros(model.nv)
    offsets[[model.joints[j].idx_v for j in pose_joints(robot)]] = hidden.joint_offsets
    return _closed(model, model.createData(), pin.integrate(model, robot.configuration(coords),
                                                            offsets),
                   None if robot.loop.is_open_chain else robot.loop)
