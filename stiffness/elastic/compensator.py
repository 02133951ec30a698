"""A real-time deflection compensator: the joint command that puts the loaded tool where asked.

:meth:`stiffness.elastic.model.ElasticModel.compensator` returns a :class:`Compensator`. Its
:meth:`Compensator.command` maps the wanted coordinates ``theta_n`` (the unloaded program: the
links are to rest there) and a dead wrench ``W`` at the target (base axes) to the command
``theta_c`` whose exact elastostatic equilibrium, under the model's joint laws, preloads (the
weight, a payload, spring compensators), couplings and ``W``, puts the target on the pose of
``theta_n``:

* joint motions only (no link bend): the links rest at ``theta_n`` exactly when
  ``theta_c = theta_n - law(J(theta_n)^T W + tau_p(theta_n))``, the law evaluated at the
  torque the links carry there. Exact for any joint law (nonlinear springs, backlash), not a
  linearisation: the torque is known at the pose the links are to rest at. On an open chain
  this is the *fast path*: one ``pin.computeFrameJacobian`` (and one
  ``pin.computeGeneralizedGravity`` under the weight) writing into the compensator's own
  ``pin.Data``, then vectorised NumPy on preallocated arrays (``out=``), no loop over joints;
  :meth:`Compensator.command_path` does a whole path with one Pinocchio pass per pose and the
  algebra batched over the path.
* link bends (or the general method asked): Newton on ``theta_c`` with
  ``x_loaded(theta_c) = x(theta_n)``, each evaluation an exact equilibrium of the joints and
  the bends (:func:`stiffness.elastic.loaded.loaded_equilibrium`), the step through the loaded
  Jacobian ``J (I - diag(law') K_C)^-1`` (least squares when the pose leaves freedom). Warm
  started from the previous call's correction ``theta_c - theta_n``.
* closed loops: the closed form, each loop closed from the previous call's configuration.

The compensator lives in the elastic layer (it reads the elastic model's laws, preloads and
bends, and the exact equilibrium); :mod:`stiffness.machining.compensation` uses it for
``stiffness compensate`` and adds the residual checks and the first-order comparison.

Units: SI (m, N, rad, N.m/rad; m and N/m for prismatic joints).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Protocol

import numpy as np
import pinocchio as pin

from stiffness.elastic.loaded import (
    Loaded,
    LoadedRobot,
    bent_kinematics,
    frozen_axes,
    loaded_equilibrium,
)
from stiffness.errors import ConvergenceError, StiffnessError
from stiffness.mechanics.equilibrium import SpringLaw
from stiffness.mechanics.formulation import compliant_projection, target_state
from stiffness.mechanics.gravity import compensator_torque
from stiffness.mechanics.ik import HOLDS
from stiffness.mechanics.law_terms import lost_motion_column, softening_column
from stiffness.robot import kinematics
from stiffness.robot.robot import TARGET_FRAME, Robot
from stiffness.robot.targets import checked_target_frame

#: Convergence of the general solve (m, rad of the target error).
POSE_TOLERANCE = 1e-12
#: Methods of :class:`Compensator`.
METHODS = ("auto", "closed-form", "general")


class ElasticModel(LoadedRobot, Protocol):
    """What the compensator reads of an elastic model
    (:class:`stiffness.elastic.model.ElasticModel`, which imports this module)."""

    compensators: tuple[tuple[str, float, float, dict], ...]
    _weighed: pin.Model | None

    @property
    def full(self) -> Robot:
        """The robot with every coordinate compliant."""
        ...

    @property
    def joint_only(self) -> bool:
        """Whether joint motions are the only effect."""
        ...

    @property
    def preloaded(self) -> bool:
        """Whether a preload acts at every pose."""
        ...

    def compliant_law(self) -> SpringLaw:
        """The joint law over the compliant joints."""
        ...

    def preload(self, q: np.ndarray, formulation: str = "enhanced"
                ) -> tuple[np.ndarray, np.ndarray]:
        """Preload torque and its derivative at ``q``."""
        ...


def retargeted(robot: Robot, frame: str | None, target_offset: np.ndarray | list[float] | None
               ) -> Robot:
    """``robot`` with its target moved to ``frame`` (default its target frame) at
    ``target_offset`` (m in the frame's axes, default none): a copy of its Pinocchio model
    whose target frame (:data:`stiffness.robot.robot.TARGET_FRAME`) is placed there.

    Raises
    ------
    UnknownFrameError
        A frame the robot does not have, or one no joint moves.
    """
    frame = robot.target_frame if frame is None else frame
    offset = np.zeros(3) if target_offset is None else np.asarray(
        target_offset, dtype=float).reshape(3)
    model = pin.Model(robot.model)
    checked_target_frame(robot.name, model, frame, frozenset(), frozenset())
    fid = kinematics.frame_id(model, frame)
    parent = model.frames[fid]
    model.frames[robot.target_frame_id] = pin.Frame(
        TARGET_FRAME, parent.parentJoint, fid, parent.placement * pin.SE3(np.eye(3), offset),
        pin.FrameType.OP_FRAME)
    return replace(robot, model=model, data=model.createData(), target_frame=frame,
                   target_offset=offset, _reference=None)


def choose_hold(em: ElasticModel, q: np.ndarray, generic: bool = False) -> str:
    """``pose`` when the coordinates can hold position and orientation (6-row rank at the full
    configuration ``q``), else ``position``.

    With ``generic`` (the closed form, which cancels the deflection exactly at any pose, a
    singular one included: the command is the nominal pose less the deflection), a singular
    ``q`` (a UR arm's upright home, where a path often starts) is judged by the arm's rank
    next to it, every coordinate moved by :data:`_GENERIC_STEP`: the arm's ability, not its
    first point's, decides (such a first point held a UR5's whole path by its position only).
    """
    if _rank6(em.full, q):
        return "pose"
    if not generic:
        return "position"
    robot = em.full
    coords = robot.coordinates_of(q)
    step = np.random.default_rng(0).choice((-1.0, 1.0), coords.shape) * _GENERIC_STEP
    try:
        nearby = robot.configuration(coords + step, seed=q)
    except StiffnessError:  # the loops do not close there: keep the point's own answer
        return "position"
    return "pose" if _rank6(robot, nearby) else "position"


#: How far (rad, m) each coordinate is moved off a singular point to judge the arm's rank.
_GENERIC_STEP = 0.05


def _rank6(robot: Robot, q: np.ndarray) -> bool:
    """Whether the target Jacobian at ``q`` has 6 independent rows (relative 1e-9)."""
    sv = np.linalg.svd(target_state(robot, q).jacobian, compute_uv=False)
    return int(np.sum(sv > 1e-9 * max(sv[0], 1e-300))) == 6


class Compensator:
    """Joint commands that cancel a model's deflection, one call per controller tick.

    Build it with :meth:`stiffness.elastic.model.ElasticModel.compensator`.

    Attributes
    ----------
    model
        The elastic model (its target is the point held and where the wrench acts).
    hold
        ``pose``, ``position`` or ``auto`` (link bends only: what Newton holds; ``auto``
        chooses at the first call). Joint motions alone are cancelled exactly: every frame
        of the arm then rests where ``theta_n`` puts it.
    method
        ``closed-form`` or ``general`` (resolved from ``auto``: ``general`` with link bends,
        or with springs on passive chain joints, whose deflection no command moves alone).
    fast
        Whether :meth:`command` runs the allocation-free fast path (open chain, closed form).
    iterations
        Newton steps of the last general solve (0 for the closed form).
    loaded
        The exact equilibrium at the last general command (None for the closed form).
    """

    def __init__(self, model: ElasticModel, hold: str = "auto", method: str = "auto") -> None:
        if hold not in (*HOLDS, "auto"):
            raise StiffnessError(f"hold must be one of auto, {', '.join(HOLDS)}, got {hold!r}")
        if method not in METHODS:
            raise StiffnessError(f"method must be auto, closed-form or general, got {method!r}")
        bends = ", ".join(lk.label for lk in model.links)
        if method == "closed-form" and not model.joint_only:
            raise StiffnessError("the closed form holds for joint compliance only; this model "
                                 f"bends beyond its joints ({bends}): use method 'general'")
        if model.preloaded and (not model.joint_only or method == "general"):
            raise StiffnessError("compensation under a preload (the weight, a compensator) is "
                                 "closed-form for joint compliance only; this model "
                                 + (f"bends beyond its joints ({bends})" if bends else
                                    "asks for the general method") + ": drop one of them")
        self.model, self.hold = model, hold
        robot = model.robot
        # springs on passive chain joints (a tall coupling): their deflection is no command,
        # the closed form cancels it only in least squares
        uncommandable = robot.spring_map.shape[0] > robot.spring_map.shape[1]
        self.method = "general" if method == "general" or not model.joint_only or (
            method == "auto" and uncommandable and not model.preloaded) else "closed-form"
        self.fast = self.method == "closed-form" and robot.loop.is_open_chain
        self.iterations = 0
        self.loaded: Loaded | None = None
        n, nc = robot.n_coordinates, robot.n_compliant
        law = model.compliant_law()
        springs = np.eye(len(robot.spring_joints))[:, robot.compliant_in_springs]
        # coordinate motion per compliant joint's deflection (through a coupling's A)
        select = np.column_stack([robot.coordinate_motion(e) for e in springs.T])
        # the law c tau + c beta tau |tau| + b tanh(tau / s) as one map of the stacked terms
        # [tau, tau |tau|, tanh(tau / s)] (those present; the columns of law_terms) to the
        # coordinates' motion
        self._softening, self._backlash = bool(np.any(law.beta)), bool(np.any(law.backlash))
        blocks = [law.compliance] + [law.compliance * law.beta] * self._softening + [
            law.backlash] * self._backlash
        self._map = np.hstack([select * b for b in blocks])  # (n, k nc)
        self._smoothing = law.smoothing
        self._stack = np.zeros(len(blocks) * nc)
        self._views = self._split(self._stack, nc)  # (tau, tau |tau|, tanh(tau / s)) or None
        self._comp = [(robot.spring_joints.index(j), robot.compliant_joints.index(j), k, f, g)
                      for j, k, f, g in model.compensators]  # (spring joint, column, ...)
        self._wrench = np.zeros(6)
        self._shift, self._out = np.zeros(n), np.zeros(n)
        self._q_prev: np.ndarray | None = None
        self._correction = np.zeros(n)
        self._select = select
        if self.fast:
            self._setup_fast()

    # ------------------------------------------------------------------------------------
    # set-up of the fast path

    def _setup_fast(self) -> None:
        robot, model = self.model.robot, self.model.robot.model
        self._data = model.createData()
        self._fid = robot.target_frame_id
        weighed = self.model._weighed
        self._weighed = None if weighed is None else (weighed, weighed.createData())
        self._projection = np.ascontiguousarray(compliant_projection(robot))  # (nv, nc)
        self._generalised = np.zeros(model.nv)
        rows, offsets = self._joint_map()
        self._q = pin.neutral(model)
        one = [(j.idx_q, r, o) for j, r, o in zip(*self._joints(rows), offsets, strict=True)
               if j.nq == 1]
        two = [(j.idx_q, r, o) for j, r, o in zip(*self._joints(rows), offsets, strict=True)
               if j.nq == 2]
        n = robot.n_coordinates
        self._one = (np.array([i for i, _, _ in one], dtype=int),
                     np.array([r for _, r, _ in one]).reshape(len(one), n),
                     np.array([o for _, _, o in one]))
        self._two = (np.array([i for i, _, _ in two], dtype=int),
                     np.array([r for _, r, _ in two]).reshape(len(two), n),
                     np.array([o for _, _, o in two]))
        # every configuration entry a linear map of the coordinates: one product
        self._linear = len(two) == 0 and len(one) == model.nq and not np.any(self._one[2])
        self._q_map = np.zeros((model.nq, n))
        if self._linear:
            self._q_map[self._one[0]] = self._one[1]
        self._direct = self._linear and np.array_equal(self._q_map, np.eye(n))
        self._angles1, self._angles2 = np.zeros(len(one)), np.zeros(len(two))
        # every joint rate a compliant rate, in order (no product for the projection)
        self._every_rate = np.array_equal(self._projection, np.eye(model.nv))

    def _joint_map(self) -> tuple[list[tuple[str, np.ndarray]], list[float]]:
        """Each joint the coordinates set, as ``(name, row)`` with its value ``row @ u +
        offset`` (rad, m): the coordinate joints, or the chain joints through the coupling,
        and the mimic followers."""
        robot = self.model.robot
        n = robot.n_coordinates
        if robot.coupling is None:
            rows = [(name, np.eye(n)[i]) for i, name in enumerate(robot.coordinate_joints)]
            offsets = [0.0] * n
        else:
            c = robot.coupling
            rows = [(name, c.matrix[i].astype(float)) for i, name in enumerate(c.chain)]
            offsets = [float(v) for v in c.offset]
        index = {name: i for i, (name, _) in enumerate(rows)}
        for m in robot.mimics:
            leader = index[m.leader]
            rows.append((m.follower, m.multiplier * rows[leader][1]))
            offsets.append(m.multiplier * offsets[leader] + m.offset)
        return rows, offsets

    def _joints(self, rows: list[tuple[str, np.ndarray]]) -> tuple[list, list[np.ndarray]]:
        model = self.model.robot.model
        return [model.joints[model.getJointId(name)] for name, _ in rows], [r for _, r in rows]

    # ------------------------------------------------------------------------------------
    # the command

    def command(self, q_target: np.ndarray, wrench: np.ndarray | None = None,
                out: np.ndarray | None = None) -> np.ndarray:
        """The joint command (n,) (rad, m) whose loaded equilibrium holds the target on the
        pose of ``q_target``.

        Parameters
        ----------
        q_target
            Wanted coordinates (n,) (rad, m), ``robot.coordinate_joints`` order: where the
            links are to rest.
        wrench
            Dead force (3,) N or wrench (6,) N, N.m at the target, base axes; default none
            (the preloads alone).
        out
            Array (n,) to write the command into (then the fast path allocates nothing of its
            own); default a new array.

        Raises
        ------
        StiffnessError
            A general solve that does not converge, an unstable equilibrium, a loop that does
            not close.
        """
        w = self._wrench
        if wrench is None:
            w.fill(0.0)
        elif len(wrench) == 6:
            np.copyto(w, wrench)
        else:
            w[3:] = 0.0
            np.copyto(w[:3], wrench)
        result = self._out if out is None else out
        if self.fast:
            self._fast(np.asarray(q_target, dtype=float), w, result)
        elif self.method == "closed-form":
            self._closed_form(np.asarray(q_target, dtype=float), w, result)
        else:
            self._general(np.asarray(q_target, dtype=float), w, result)
        return result.copy() if out is None else result

    def command_path(self, path: np.ndarray, wrench: np.ndarray | None = None) -> np.ndarray:
        """:meth:`command` of every row of ``path`` (m, n) (rad, m) under one wrench (3,) or
        (6,), or one per row (m, 3) or (m, 6) (N, N.m, base axes): (m, n) commands. On the
        fast path one Pinocchio pass per pose and the algebra over the whole path at once."""
        path = np.atleast_2d(np.asarray(path, dtype=float))
        m = path.shape[0]
        w = np.zeros((m, 6))
        if wrench is not None:
            given = np.atleast_2d(np.asarray(wrench, dtype=float))
            w[:, : given.shape[1]] = given
        if not self.fast:
            return np.array([self.command(row, wi) for row, wi in zip(path, w, strict=True)])
        model, data, fid = self.model.robot.model, self._data, self._fid
        qs = self._configurations(path)
        jacobians = np.empty((m, 6, model.nv))
        frame_jacobian = pin.computeFrameJacobian
        lwa = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        for i, q in enumerate(qs):
            jacobians[i] = frame_jacobian(model, data, q, fid, lwa)
        gen = np.einsum("ik,ikv->iv", w, jacobians)
        if self._weighed is not None:
            weighed, wdata = self._weighed
            gravity = pin.computeGeneralizedGravity
            weights = np.empty((m, model.nv))
            for i, q in enumerate(qs):
                weights[i] = gravity(weighed, wdata, q)
            gen -= weights
        nc = self.model.robot.n_compliant
        stack = np.empty((m, self._stack.shape[0]))
        stack[:, :nc] = gen @ self._projection
        self._add_compensators(path, stack[:, :nc])
        self._terms(self._split(stack, nc))
        return path - stack @ self._map.T

    # ------------------------------------------------------------------------------------
    # the fast path

    def _fast(self, u: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
        model = self.model.robot.model
        q = self._configuration(u)
        jac = pin.computeFrameJacobian(model, self._data, q, self._fid,
                                       pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        tau = self._views[0]
        gen = tau if self._every_rate else self._generalised  # J^T W over the joint rates
        np.dot(w, jac, out=gen)
        if self._weighed is not None:
            np.subtract(gen, pin.computeGeneralizedGravity(*self._weighed, q), out=gen)
        if not self._every_rate:
            np.dot(gen, self._projection, out=tau)
        if self._comp:
            self._add_compensators(u, tau)
        self._terms(self._views)
        np.dot(self._map, self._stack, out=self._shift)
        np.subtract(u, self._shift, out=out)

    def _split(self, stack: np.ndarray, nc: int) -> tuple:
        """Views ``(tau, tau |tau|, tanh(tau / s))`` of ``stack`` (..., k nc) (``None`` for a
        term the law does not have)."""
        blocks = iter(range(nc, stack.shape[-1], nc))
        square = stack[..., next(blocks):][..., :nc] if self._softening else None
        smooth = stack[..., next(blocks):][..., :nc] if self._backlash else None
        return stack[..., :nc], square, smooth

    def _terms(self, views: tuple) -> None:
        """Fill the law's nonlinear terms from the torques (views of :meth:`_split`)."""
        tau, square, smooth = views
        if square is not None:
            softening_column(tau, out=square)
        if smooth is not None:
            lost_motion_column(tau, self._smoothing, out=smooth)

    def _configuration(self, u: np.ndarray) -> np.ndarray:
        """The full configuration of coordinates ``u`` (open chain), into the compensator's
        buffer."""
        q = self._q
        if self._direct:
            np.copyto(q, u)
            return q
        if self._linear:
            return np.dot(self._q_map, u, out=q)
        idx, rows, offsets = self._one
        if idx.size:
            np.dot(rows, u, out=self._angles1)
            self._angles1 += offsets
            q.put(idx, self._angles1)
        idx, rows, offsets = self._two
        if idx.size:
            angles = self._angles2
            np.dot(rows, u, out=angles)
            angles += offsets
            q.put(idx, np.cos(angles))
            q.put(idx + 1, np.sin(angles))
        return q

    def _configurations(self, path: np.ndarray) -> np.ndarray:
        """(m, nq) full configurations of the rows of ``path`` (open chain)."""
        qs = np.repeat(self._q[None, :], path.shape[0], axis=0)
        if self._direct:
            qs[:] = path
            return qs
        idx, rows, offsets = self._one
        if idx.size:
            qs[:, idx] = path @ rows.T + offsets
        idx, rows, offsets = self._two
        if idx.size:
            angles = path @ rows.T + offsets
            qs[:, idx], qs[:, idx + 1] = np.cos(angles), np.sin(angles)
        return qs

    def _add_compensators(self, u: np.ndarray, tau: np.ndarray) -> None:
        """Add the spring compensators' torque at coordinates ``u`` (..., n) to ``tau``
        (..., nc), in place (one term per compensator, at its spring joint's value)."""
        values = self.model.robot.spring_command(u)
        for i, column, k_s, f0, geometry in self._comp:
            tau[..., column] += compensator_torque(values[..., i], k_s, f0, geometry)[0]

    # ------------------------------------------------------------------------------------
    # closed loops, link bends

    def _closed_form(self, u: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
        """The closed form on a robot with closed loops (each closed from the last call's
        configuration)."""
        em = self.model
        q = em.full.configuration(u, seed=self._q_prev)
        self._q_prev = q
        tau = target_state(em.robot, q).jacobian.T @ w
        if em.preloaded:
            tau = tau + em.preload(q)[0]
        np.subtract(u, self._select @ em.compliant_law()(tau)[0], out=out)

    def _general(self, u: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
        """Newton on the command with link bends, the bend axes frozen at ``u`` (as the
        effect library's), started from the last call's correction."""
        em = self.model
        robot, links = em.robot, em.ordered_links()
        q_n = em.full.configuration(u, seed=self._q_prev)
        self._q_prev = q_n
        kinematics.update_first_order(em.springs.model, em.springs.data, q_n)
        axes = frozen_axes(em, links)
        nominal = bent_kinematics(em, links, axes, robot.spring_command(u),
                                  np.zeros(2 * len(links)), w, q_n)
        if self.hold == "auto":
            self.hold = choose_hold(em, q_n)

        def solve(command: np.ndarray) -> Loaded:
            return loaded_equilibrium(em, robot.spring_command(command), w, seed_q=q_n,
                                      axes=axes)

        start = u + self._correction
        command, loaded, self.iterations = general_command(
            start, solve(start), solve, (nominal.position.copy(), nominal.rotation.copy()),
            self.hold, robot.spring_map)
        self.loaded = loaded
        self._correction = command - u
        np.copyto(out, command)


def _pose_error(loaded_pos, loaded_rot, pos, rot, hold) -> np.ndarray:
    e = loaded_pos - pos
    if hold == "pose":
        e = np.concatenate([e, pin.log3(loaded_rot @ rot.T)])
    return e


def general_command(start: np.ndarray, loaded: Loaded, solve: Callable[[np.ndarray], Loaded],
                    nominal: tuple[np.ndarray, np.ndarray], hold: str, spring_map: np.ndarray
                    ) -> tuple[np.ndarray, Loaded, int]:
    """Newton on the command (rad, m) whose loaded equilibrium (``solve(command)``) holds the
    nominal pose ``(position m, rotation)``, from ``start`` (its equilibrium ``loaded``): each
    step through the loaded Jacobian ``J (I - diag(law') K_C)^-1 M`` (least squares; ``M`` the
    spring joints' rates per coordinate rate, :attr:`stiffness.robot.robot.Robot.spring_map`);
    the best iterate within 40.

    Returns
    -------
    The command, its loaded equilibrium and the iterations taken.

    Raises
    ------
    ConvergenceError
        The coordinates cannot move the held components, or no convergence (near buckling).
    """
    pos_n, rot_n = nominal
    n = spring_map.shape[0]
    rows = slice(0, 6 if hold == "pose" else 3)
    command = start.copy()
    best = (np.inf, command, loaded)
    for iterations in range(1, 41):  # noqa: B007 (reported)
        err = _pose_error(loaded.position, loaded.rotation, pos_n, rot_n, hold)
        size = float(np.abs(err).max())
        if size < best[0]:
            best = (size, command, loaded)
        if size <= POSE_TOLERANCE:
            break
        kin = loaded.kin
        a = np.eye(kin.k_c.shape[0]) - loaded.slope[:, None] * kin.k_c
        dz_dc = np.linalg.solve(a, np.eye(a.shape[0])[:, :n] @ spring_map)
        jac = kin.jac[rows] @ dz_dc
        if hold == "pose":
            m_rot = loaded.rotation @ rot_n.T
            jac = np.vstack([jac[:3], pin.Jlog3(m_rot) @ m_rot.T @ jac[3:]])
        step = np.linalg.lstsq(jac, -err, rcond=1e-12)[0]
        command = command + step
        loaded = solve(command)
    size, command, loaded = best
    if size > 1e3 * POSE_TOLERANCE:
        sv = np.linalg.svd(jac, compute_uv=False)
        rank = int(np.sum(sv > 1e-9 * max(sv[0], 1e-300)))
        if rank < jac.shape[0]:
            raise ConvergenceError(
                f"the coordinates cannot cancel this deflection: they move only {rank} of "
                f"the {jac.shape[0]} held target components here ({size:.3g} m/rad "
                "remains); hold fewer (--hold position) or move away from the singularity")
        raise ConvergenceError(
            f"the general compensation did not converge (target error {size:.3g} m/rad "
            "remains): the load may be near the buckling load; reduce it")
    return command, loaded, iterations
