"""Deflection compensation along a path: joint commands that cancel the load's deflection.

A path point gives the *nominal* coordinates ``theta_n`` (the unloaded program). Under the
process wrench ``W`` (a dead load at the target, base axes) the robot commanded at ``theta_c``
rests at its exact elastostatic equilibrium; compensation finds the ``theta_c`` whose loaded
equilibrium puts the target at the unloaded nominal pose ``x(theta_n)`` (position, and the
orientation when it is held: see :func:`compensate`).

The elastic model (:class:`ElasticModel`) holds every effect of a model file that acts on the
robot:

* a joint law over the coordinates, ``theta - theta_c = law(tau)`` with ``tau = J(theta)^T W``
  (linear springs, extra springs on joints the baseline holds rigid, nonlinear springs
  ``tau/k (1 + beta|tau|)`` and backlash ``b tanh(tau/tau_s)``; zero for rigid coordinates);
* link compliances (:class:`LinkBend`): the segment ``a -> b`` bends at ``b``'s origin about two
  axes normal to it, modelled exactly as two virtual revolute joints there (a universal joint:
  the second axis is carried by the first) with springs ``k_1, k_2``. The axes are those of
  :func:`stiffness.calibration.effects.link_axes` at the nominal configuration of the point,
  fixed in the body joint ``b`` is mounted on. The bend rotates everything beyond it; loops are
  closed on the unbent kinematics (as in the effect library).

Exact equilibrium (:func:`loaded_equilibrium`): unknowns ``z = [theta, alpha]``, equations
``theta - theta_c = law(J_theta^T W)``, ``alpha = law_link(J_alpha^T W)``, solved by Newton with
the tangent ``I - diag(law') K_C`` (``K_C`` of the coordinates from the kinematic Hessians).

Compensation:

* joint law only: rest at ``theta = theta_n`` exactly, so ``theta_c = theta_n - law(J(theta_n)^T
  W)`` (closed form, design notes "Compensation along a path");
* otherwise (link compliance): Newton on ``theta_c`` with ``x_loaded(theta_c) = x(theta_n)``,
  each evaluation an exact equilibrium, the Jacobian ``J (I - diag(law') K_C)^-1`` (minimum-norm
  steps when the pose leaves freedom).

Beside it the usual first-order Cartesian compensation: command the pose shifted by
``-C W`` (``C`` the model's linear compliance at the nominal pose) through inverse kinematics;
its residual grows as the square of the load.

Every residual reported is that of the exact loaded equilibrium at the command, solved anew.
Units: SI (m, N, rad, N.m/rad; m and N/m for prismatic joints).
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.calibration.effects import Law, link_axes
from stiffness.errors import (
    ConvergenceError,
    FileFormatError,
    MissingFileError,
    StiffnessError,
    UnstableEquilibriumError,
    with_context,
)
from stiffness.mechanics.formulation import as_wrench, target_state
from stiffness.mechanics.ik import HOLDS, all_coordinates, coordinate_limits, solve_ik
from stiffness.model import kinematics
from stiffness.model.robot import Robot

#: Effects of a model file that describe the measuring rig, not the robot (not compensated).
RIG_EFFECTS = ("frame_misalignment", "force_sensor_bias", "deflection_offset", "target_offset")
#: Convergence of the exact equilibrium (rad, m of the joint and bend variables), plus 1e-11
#: of the largest deflection (closure noise of loops).
EQUILIBRIUM_TOLERANCE = 1e-14
#: Convergence of the general compensation solve (m, rad of the target error).
POSE_TOLERANCE = 1e-12
#: Wrench columns a path file may carry (N, N.m).
WRENCH_COLUMNS = ("fx", "fy", "fz", "mx", "my", "mz")
#: Reference frames of a process wrench.
WRENCH_FRAMES = ("base", "target")


# ------------------------------------------------------------------------------------------
# the elastic model


@dataclass(frozen=True)
class LinkBend:
    """A link compliance: the segment ``a -> b`` bends at ``b``'s origin.

    ``column`` picks the mounting body's axis that :func:`link_axes` makes normal to the
    segment; ``stiffness`` (2,) N.m/rad about ``e_1`` and ``e_2``.
    """

    a: str
    b: str
    column: int
    stiffness: tuple[float, float]


@dataclass
class ElasticModel:
    """What acts on the robot under a load: its joint law and its link bends.

    Attributes
    ----------
    robot
        The robot (its coordinates are the path's columns).
    law
        Joint law over ``robot.coordinate_joints`` (zero compliance: a rigid coordinate).
    links
        Link compliances, any order.
    formulation
        Formulation of the model's linear compliance (``enhanced`` with K_C, or
        ``conventional``), used by the first-order compensation only.
    ignored
        Effects of the model file that do not act on the robot (rig effects), by label.
    source
        The model file, if any.
    """

    robot: Robot
    law: Law
    links: tuple[LinkBend, ...] = ()
    formulation: str = "enhanced"
    ignored: tuple[str, ...] = ()
    source: str | None = None
    _full: Robot | None = field(default=None, repr=False)

    @classmethod
    def joint_springs(cls, robot: Robot, k_theta: np.ndarray | list[float],
                      formulation: str = "enhanced") -> ElasticModel:
        """Linear springs ``k_theta`` (N.m/rad, N/m) on the robot's compliant joints."""
        k = np.asarray(k_theta, dtype=float)
        k = np.diag(k) if k.ndim == 2 else k.reshape(-1)
        if k.shape[0] != robot.n_compliant or not np.all(np.isfinite(k)) or np.any(k <= 0):
            raise StiffnessError(
                f"need one finite positive stiffness per compliant joint of {robot.name} "
                f"({', '.join(robot.compliant_joints)}), got {k.tolist()}")
        n = robot.n_coordinates
        compliance = np.zeros(n)
        compliance[robot.compliant_in_coordinates] = 1.0 / k
        return cls(robot, Law(compliance, np.zeros(n), np.zeros(n), np.ones(n)),
                   formulation=formulation)

    def with_target(self, frame: str | None = None,
                    target_offset: np.ndarray | list[float] | None = None) -> ElasticModel:
        """The same springs and bends with the target moved (e.g. to a tool): joint laws and
        link bends act on joints, not on the target, so they carry over unchanged."""
        from stiffness.model.robot import load_robot

        robot = load_robot(self.robot.name, frame=frame or self.robot.target_frame,
                           target_offset=self.robot.target_offset if target_offset is None
                           else target_offset, compliant_joints=self.robot.compliant_joints)
        return ElasticModel(robot, self.law, self.links, self.formulation, self.ignored,
                            self.source)

    @property
    def full(self) -> Robot:
        """The robot with every coordinate compliant (Jacobians w.r.t. all coordinates)."""
        if self._full is None:
            self._full = all_coordinates(self.robot)
        return self._full

    @property
    def joint_only(self) -> bool:
        """Whether joint motions are the only effect (the compensation is closed-form)."""
        return not self.links

    def ordered_links(self) -> list[LinkBend]:
        """Links from the base to the tip (by the chain position of ``b``, then ``a``)."""
        model = self.robot.model
        depth = {name: len(model.supports[model.getJointId(name)]) for name in model.names}
        return sorted(self.links, key=lambda lk: (depth[lk.b], depth[lk.a]))

    def describe(self) -> str:
        """E.g. ``joint springs on joint1, joint2 + link bend joint2->joint3``."""
        names = [j for j, c in zip(self.robot.coordinate_joints, self.law.compliance,
                                   strict=True) if c > 0]
        text = f"joint springs on {', '.join(names) or 'no joint'}"
        if np.any(self.law.beta != 0):
            text += " (nonlinear)"
        if np.any(self.law.backlash != 0):
            text += " + backlash"
        return text + "".join(f" + link bend {lk.a}->{lk.b}" for lk in self.links)


def as_elastic_model(model: ElasticModel | Robot | str | Path,
                     k_theta: np.ndarray | list[float] | None = None) -> ElasticModel:
    """An :class:`ElasticModel` from itself, a model file's path, or a robot with springs
    ``k_theta`` (N.m/rad, N/m; default the shipped robot's).

    Raises
    ------
    StiffnessError
        A robot without springs, or springs given with a model.
    """
    if isinstance(model, Robot):
        if k_theta is None:
            from stiffness.mechanics.defaults import default_stiffness

            k_theta = default_stiffness(model)
            if k_theta is None:
                raise StiffnessError(f"give k_theta: one stiffness per compliant joint of "
                                     f"{model.name} ({', '.join(model.compliant_joints)})")
        return ElasticModel.joint_springs(model, k_theta)
    if k_theta is not None:
        raise StiffnessError("k_theta goes with a robot; a model (file) brings its own springs")
    return model if isinstance(model, ElasticModel) else load_elastic_model(model)


def _frozen_axes(em: ElasticModel, links: list[LinkBend]) -> list[np.ndarray]:
    """Bend axes (2, 3) in each mounting body's frame, from the current placements."""
    model, data = em.full.model, em.full.data
    out = []
    for lk in links:
        ja, jb = model.getJointId(lk.a), model.getJointId(lk.b)
        mount = data.oMi[model.parents[jb]].rotation
        e1, e2 = link_axes(data.oMi[ja].translation, data.oMi[jb].translation, mount, lk.column)
        out.append(np.vstack([mount.T @ e1, mount.T @ e2]))
    return out


# ------------------------------------------------------------------------------------------
# kinematics of the loaded robot


@dataclass
class _Kinematics:
    """Target pose and Jacobians of the (bent) robot at ``z = [coords, alpha]``."""

    q: np.ndarray
    position: np.ndarray
    rotation: np.ndarray
    jac: np.ndarray  # (6, n + 2m) rows [v; omega] base axes at the target
    k_c: np.ndarray  # (n + 2m, n + 2m): K_C of the coordinates (bend rows zero)


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _kinematics(em: ElasticModel, links: list[LinkBend], axes: list[np.ndarray],
                coords: np.ndarray, alpha: np.ndarray, wrench: np.ndarray,
                seed_q: np.ndarray | None) -> _Kinematics:
    full = em.full
    n, m = full.n_coordinates, 2 * len(links)
    q = full.configuration(coords, seed=seed_q)
    state = target_state(full, q, wrench)
    k_c = np.zeros((n + m, n + m))
    k_c[:n, :n] = state.k_c
    if not links:
        return _Kinematics(q, state.position, state.rotation, state.jacobian, k_c)
    model, data = full.model, full.data
    j_world = pin.getFrameJacobian(model, data, full.target_frame_id, pin.ReferenceFrame.WORLD)
    bent = j_world.copy()
    cum = pin.SE3.Identity()
    alpha_cols = []
    chain = set(model.supports[model.frames[full.target_frame_id].parentJoint])
    for i, (lk, ax) in enumerate(zip(links, axes, strict=True)):
        jb = model.getJointId(lk.b)
        point = data.oMi[jb].translation
        mount = data.oMi[model.parents[jb]].rotation
        r1 = pin.exp3(alpha[2 * i] * ax[0])
        r2 = pin.exp3(alpha[2 * i + 1] * ax[1])
        for axis_local in (ax[0], r1 @ ax[1]):
            w = cum.rotation @ mount @ axis_local
            p = cum.act(point)
            alpha_cols.append(np.concatenate([np.cross(p, w), w]))
        rot = mount @ r1 @ r2 @ mount.T
        cum = cum * pin.SE3(rot, point - rot @ point)
        ad = cum.toActionMatrix()
        for jid in chain:
            if jid > 0 and jb in model.supports[jid]:
                joint = model.joints[jid]
                cols = slice(joint.idx_v, joint.idx_v + joint.nv)
                # the latest (most distal) bend proximal to the joint wins: links are ordered
                bent[:, cols] = ad @ j_world[:, cols]
    position = cum.act(state.position)
    rotation = cum.rotation @ state.rotation
    spatial = np.hstack([bent @ state.projection, np.array(alpha_cols).T])
    jac = np.vstack([spatial[:3] - _skew(position) @ spatial[3:], spatial[3:]])
    return _Kinematics(q, position, rotation, jac, k_c)


# ------------------------------------------------------------------------------------------
# exact equilibrium


@dataclass
class Loaded:
    """Exact equilibrium of the loaded robot at a command.

    Attributes
    ----------
    q
        Full configuration at equilibrium (loops closed).
    coords
        Coordinates at equilibrium (rad, m).
    alpha
        Bend angles of the link compliances (rad), two per link (base to tip).
    position, rotation
        Target pose at equilibrium (m; rotation matrix), base frame.
    torque
        Generalised forces ``J^T W`` at equilibrium over ``[coords, alpha]``.
    iterations
        Newton iterations.
    """

    q: np.ndarray
    coords: np.ndarray
    alpha: np.ndarray
    position: np.ndarray
    rotation: np.ndarray
    torque: np.ndarray
    iterations: int
    _kin: _Kinematics = field(repr=False)
    _slope: np.ndarray = field(repr=False)


def _law_z(em: ElasticModel, links: list[LinkBend], tau: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    n = em.full.n_coordinates
    value, slope = em.law(tau[:n])
    c_link = np.array([1.0 / k for lk in links for k in lk.stiffness])
    return (np.concatenate([value, c_link * tau[n:]]),
            np.concatenate([slope, c_link]))


def loaded_equilibrium(em: ElasticModel, command: np.ndarray, wrench: np.ndarray,
                       seed_q: np.ndarray | None = None, axes: list[np.ndarray] | None = None,
                       max_iterations: int = 60) -> Loaded:
    """Exact elastostatic equilibrium of the robot commanded at ``command`` under ``wrench``.

    Parameters
    ----------
    em
        The elastic model.
    command
        Commanded coordinates (rad, m): the joint springs' rest positions.
    wrench
        Dead force (3,) N or wrench (6,) N, N.m at the target, base axes.
    seed_q
        A closed configuration near the equilibrium (the loop branch), default the command's.
    axes
        Bend axes per link (:func:`_frozen_axes`), default those at the command.

    Raises
    ------
    StiffnessError
        Newton does not converge, or the equilibrium is unstable (the load buckles the robot).
    """
    wrench = as_wrench(wrench)
    links = em.ordered_links()
    command = np.asarray(command, dtype=float)
    n, m = command.shape[0], 2 * len(links)
    if axes is None:
        kinematics.update_first_order(em.full.model, em.full.data,
                                      em.full.configuration(command, seed=seed_q))
        axes = _frozen_axes(em, links)
    z = np.concatenate([command, np.zeros(m)])
    base = np.concatenate([command, np.zeros(m)])
    q = seed_q
    for iterations in range(1, max_iterations + 1):
        kin = _kinematics(em, links, axes, z[:n], z[n:], wrench, q)
        q = kin.q
        tau = kin.jac.T @ wrench
        value, slope = _law_z(em, links, tau)
        g = z - base - value
        tol = EQUILIBRIUM_TOLERANCE * (1.0 + 1e3 * float(np.abs(value).max(initial=0.0)))
        if iterations > 1 and np.abs(g).max() <= tol:
            break
        a = np.eye(n + m) - slope[:, None] * kin.k_c
        try:
            step = np.linalg.solve(a, -g)
        except np.linalg.LinAlgError as exc:
            raise UnstableEquilibriumError("the tangent stiffness is singular: the load buckles "
                                           "the robot here; reduce the load") from exc
        z = z + step
        if iterations > 1 and np.abs(step).max() <= tol:
            kin = _kinematics(em, links, axes, z[:n], z[n:], wrench, q)
            tau = kin.jac.T @ wrench
            value, slope = _law_z(em, links, tau)
            break
    else:
        raise ConvergenceError(
            f"the exact equilibrium did not converge in {max_iterations} iterations (residual "
            f"{np.abs(g).max():.3g}): the load may exceed the buckling load; reduce it")
    soft = slope > 0
    if np.any(soft):
        tangent = np.diag(1.0 / slope[soft]) - kin.k_c[np.ix_(soft, soft)]
        lowest = float(np.linalg.eigvalsh(0.5 * (tangent + tangent.T))[0])
        if lowest <= 0:
            raise UnstableEquilibriumError(
                f"the loaded equilibrium is unstable (tangent stiffness eigenvalue {lowest:.3g})"
                ": the load exceeds the buckling load here; reduce the load")
    return Loaded(kin.q, z[:n].copy(), z[n:].copy(), kin.position, kin.rotation, tau,
                  iterations, kin, slope)


# ------------------------------------------------------------------------------------------
# linear deflection


def _linear(em: ElasticModel, links: list[LinkBend], kin: _Kinematics, wrench: np.ndarray
            ) -> np.ndarray:
    """First-order target displacement ``C W`` (6,) [m; rad] of the model at ``kin``.

    The joint law enters by its secant ``law(tau) / tau`` at the holding torques (the linear
    springs themselves for a linear law); ``K_C`` enters for the ``enhanced`` formulation.
    """
    tau = kin.jac.T @ wrench
    value, _ = _law_z(em, links, tau)
    secant = np.divide(value, tau, out=np.zeros_like(value), where=tau != 0)
    k_c = kin.k_c if em.formulation == "enhanced" else np.zeros_like(kin.k_c)
    a = np.eye(k_c.shape[0]) - secant[:, None] * k_c
    try:
        dz = np.linalg.solve(a, secant * tau)
    except np.linalg.LinAlgError as exc:
        raise UnstableEquilibriumError("the tangent stiffness is singular: the load buckles the "
                                       "robot here; reduce the load") from exc
    return kin.jac @ dz


def linear_deflection(em: ElasticModel, coords: np.ndarray, wrench: np.ndarray,
                      seed_q: np.ndarray | None = None) -> np.ndarray:
    """First-order deflection ``C W`` (6,) [m; rad] of the target at ``coords`` (rad, m)
    under the dead ``wrench`` (base axes), every effect of the model included."""
    wrench = as_wrench(wrench)
    links = em.ordered_links()
    q = em.full.configuration(coords, seed=seed_q)
    kinematics.update_first_order(em.full.model, em.full.data, q)
    axes = _frozen_axes(em, links)
    kin = _kinematics(em, links, axes, np.asarray(coords, dtype=float),
                      np.zeros(2 * len(links)), wrench, q)
    return _linear(em, links, kin, wrench)


# ------------------------------------------------------------------------------------------
# one path point


@dataclass
class PointCompensation:
    """Compensation of one path point (SI).

    Attributes
    ----------
    command
        Exact joint command (rad, m), one per coordinate.
    command_first_order
        First-order Cartesian compensation's command (rad, m).
    deflection
        Target displacement (3,) of the uncompensated robot under the load (m).
    rotation_deflection
        Its rotation vector (3,) (rad).
    residual, rotation_residual
        Target error after the exact compensation (m; rad).
    residual_first_order, rotation_residual_first_order
        Target error after the first-order compensation (m; rad).
    method
        ``closed-form`` or ``general``.
    iterations
        Newton steps of the general solve (0 for the closed form).
    """

    command: np.ndarray
    command_first_order: np.ndarray
    deflection: np.ndarray
    rotation_deflection: np.ndarray
    residual: np.ndarray
    rotation_residual: np.ndarray
    residual_first_order: np.ndarray
    rotation_residual_first_order: np.ndarray
    method: str
    iterations: int
    q_nominal: np.ndarray = field(repr=False)


def choose_hold(em: ElasticModel, q: np.ndarray) -> str:
    """``pose`` when the coordinates can hold position and orientation (6-row rank), else
    ``position``."""
    jac = target_state(em.full, q).jacobian
    sv = np.linalg.svd(jac, compute_uv=False)
    rank = int(np.sum(sv > 1e-9 * max(sv[0], 1e-300)))
    return "pose" if rank == 6 else "position"


def _pose_error(loaded_pos, loaded_rot, pos, rot, hold) -> np.ndarray:
    e = loaded_pos - pos
    if hold == "pose":
        e = np.concatenate([e, pin.log3(loaded_rot @ rot.T)])
    return e


def compensate_point(em: ElasticModel, coords: np.ndarray, wrench: np.ndarray,
                     hold: str = "pose", method: str = "auto",
                     seed_q: np.ndarray | None = None) -> PointCompensation:
    """Exact and first-order compensation at nominal coordinates ``coords`` (rad, m).

    Parameters
    ----------
    em
        The elastic model.
    coords
        Nominal coordinates (the unloaded program).
    wrench
        Dead wrench (6,) [N; N.m] at the target, base axes.
    hold
        ``pose`` (position and orientation) or ``position``.
    method
        ``auto`` (closed form when joint motions are the only effect), ``closed-form`` or
        ``general``.
    seed_q
        A closed configuration near ``coords`` (the loop branch).

    Raises
    ------
    StiffnessError
        Unstable or non-convergent equilibrium, a first-order pose out of reach, or the closed
        form asked for a model with link compliance.
    """
    if hold not in HOLDS:
        raise StiffnessError(f"hold must be one of {', '.join(HOLDS)}, got {hold!r}")
    if method not in ("auto", "closed-form", "general"):
        raise StiffnessError(f"method must be auto, closed-form or general, got {method!r}")
    if method == "closed-form" and not em.joint_only:
        raise StiffnessError("the closed form holds for joint compliance only; this model has "
                             "link compliance: use method 'general'")
    wrench = as_wrench(wrench)
    full = em.full
    coords = np.asarray(coords, dtype=float)
    n = coords.shape[0]
    links = em.ordered_links()
    q_n = full.configuration(coords, seed=seed_q)
    kinematics.update_first_order(full.model, full.data, q_n)
    axes = _frozen_axes(em, links)
    nominal = _kinematics(em, links, axes, coords, np.zeros(2 * len(links)), wrench, q_n)
    pos_n, rot_n = nominal.position.copy(), nominal.rotation.copy()
    rows = slice(0, 6 if hold == "pose" else 3)

    def solve(command):
        return loaded_equilibrium(em, command, wrench, seed_q=q_n, axes=axes)

    uncompensated = solve(coords)
    tau_n = nominal.jac.T @ wrench
    iterations = 0
    if method == "general" or (method == "auto" and not em.joint_only):
        used = "general"
        command, loaded = coords.copy(), uncompensated
        best = (np.inf, command, loaded)
        for iterations in range(1, 41):  # noqa: B007 (reported)
            err = _pose_error(loaded.position, loaded.rotation, pos_n, rot_n, hold)
            size = float(np.abs(err).max())
            if size < best[0]:
                best = (size, command, loaded)
            if size <= POSE_TOLERANCE:
                break
            kin = loaded._kin
            a = np.eye(kin.k_c.shape[0]) - loaded._slope[:, None] * kin.k_c
            dz_dc = np.linalg.solve(a, np.eye(a.shape[0])[:, :n])
            jac = kin.jac[rows] @ dz_dc
            if hold == "pose":
                m_rot = loaded.rotation @ rot_n.T
                jac = np.vstack([jac[:3], pin.Jlog3(m_rot) @ m_rot.T @ jac[3:]])
            step = np.linalg.lstsq(jac, -err, rcond=1e-12)[0]
            command = command + step
            loaded = solve(command)
        size, command, loaded = best
        if size > 1e3 * POSE_TOLERANCE:
            raise ConvergenceError(
                f"the general compensation did not converge (target error {size:.3g} m/rad "
                "remains): the load may be near the buckling load; reduce it")
    else:
        used = "closed-form"
        command = coords - em.law(tau_n[:n])[0]
        loaded = solve(command)
    # first-order Cartesian compensation: command the pose shifted by -C W through IK
    shift = _linear(em, links, nominal, wrench)
    target_rot = pin.exp3(-shift[3:]) @ rot_n if hold == "pose" else None
    ik = solve_ik(full, pos_n - shift[:3], target_rot, seed=coords, seed_q=q_n, limits=False)
    first = solve(ik.coords)
    return PointCompensation(
        command=command,
        command_first_order=ik.coords,
        deflection=uncompensated.position - pos_n,
        rotation_deflection=pin.log3(uncompensated.rotation @ rot_n.T),
        residual=loaded.position - pos_n,
        rotation_residual=pin.log3(loaded.rotation @ rot_n.T),
        residual_first_order=first.position - pos_n,
        rotation_residual_first_order=pin.log3(first.rotation @ rot_n.T),
        method=used,
        iterations=iterations,
        q_nominal=q_n,
    )


# ------------------------------------------------------------------------------------------
# a path


@dataclass
class PathCompensation:
    """Compensation along a path.

    Attributes
    ----------
    points
        Per path point.
    joints
        Coordinate joints (the order of every command).
    hold
        What the exact compensation holds: ``pose`` or ``position``.
    model
        The elastic model used.
    """

    points: list[PointCompensation]
    joints: tuple[str, ...]
    hold: str
    model: ElasticModel

    def array(self, name: str) -> np.ndarray:
        """(m, k) stack of a per-point attribute, e.g. ``"residual"``."""
        return np.array([getattr(p, name) for p in self.points])

    def summary(self) -> dict:
        """``max_deflection_m``, ``rms_deflection_m``, ``max_residual_m``,
        ``max_residual_first_order_m`` (norms of the position errors), and more."""
        d = np.linalg.norm(self.array("deflection"), axis=1)
        e = np.linalg.norm(self.array("residual"), axis=1)
        e1 = np.linalg.norm(self.array("residual_first_order"), axis=1)
        er = np.linalg.norm(self.array("rotation_residual"), axis=1)
        return {
            "max_deflection_m": float(d.max()),
            "rms_deflection_m": float(np.sqrt(np.mean(d ** 2))),
            "max_residual_m": float(e.max()),
            "max_residual_first_order_m": float(e1.max()),
            "rms_residual_first_order_m": float(np.sqrt(np.mean(e1 ** 2))),
            "max_rotation_residual_rad": float(er.max()),
            "points": len(self.points),
            "hold": self.hold,
            "method": sorted({p.method for p in self.points}),
            "model": self.model.describe(),
            "ignored_effects": list(self.model.ignored),
        }


def compensate(
    model: ElasticModel | Robot | str | Path,
    path: np.ndarray | str | Path,
    wrench: np.ndarray | list[float] | None = None,
    wrench_frame: str = "base",
    hold: str = "auto",
    method: str = "auto",
    progress: Callable[[int, int], None] | None = None,
    k_theta: np.ndarray | list[float] | None = None,
    deg: bool = False,
) -> PathCompensation:
    """Joint commands that cancel the deflection along a path (see the module docstring).

    Parameters
    ----------
    model
        The elastic model (:meth:`ElasticModel.joint_springs`), a model file's path
        (:func:`load_elastic_model`), or a robot with ``k_theta``.
    path
        (m, n) nominal coordinates (rad, m), one row per point, model coordinate order; or a
        ``PATH.csv`` (:func:`read_joint_path`; ``deg`` for angles in degrees; its per-row loads
        are used when ``wrench`` is None).
    wrench
        One process wrench (3,) or (6,) for every point, or (m, 6) one per point (N, N.m).
    wrench_frame
        ``base``: base axes; ``target``: the target frame's axes at each nominal pose (held
        fixed in the base while the robot deflects, a dead load).
    hold
        ``pose``, ``position`` or ``auto`` (``pose`` when the coordinates can hold it).
    method
        ``auto``, ``closed-form`` or ``general`` (:func:`compensate_point`).
    progress
        Called with (done, total) after each point.
    k_theta
        Joint springs (N.m/rad, N/m) when ``model`` is a robot (default: its shipped ones).
    deg
        Angles of a ``PATH.csv`` are in degrees.

    Raises
    ------
    StiffnessError
        A bad path or wrench, or a point where a solve fails (the message names the row).
    """
    em = as_elastic_model(model, k_theta)
    if isinstance(path, str | Path):
        read = read_joint_path(path, em.robot, deg=deg)
        path = read.coords
        if wrench is None:
            wrench = read.wrench
    path = np.atleast_2d(np.asarray(path, dtype=float))
    n = em.robot.n_coordinates
    if path.shape[1] != n or path.shape[0] == 0:
        raise StiffnessError(
            f"the path needs one column per coordinate of {em.robot.name} "
            f"({', '.join(em.robot.coordinate_joints)}); got shape {path.shape}")
    if not np.all(np.isfinite(path)):
        row = int(np.argwhere(~np.isfinite(path))[0, 0])
        raise StiffnessError(f"path row {row + 1} holds a NaN or infinite coordinate; fix it")
    if wrench_frame not in WRENCH_FRAMES:
        raise StiffnessError(f"wrench frame must be base or target, got {wrench_frame!r}")
    if wrench is None:
        raise StiffnessError("give a wrench (fx,fy,fz[,mx,my,mz] in N, N.m)")
    w = np.asarray(wrench, dtype=float)
    w = np.array([as_wrench(r) for r in (w.reshape(1, -1) if w.ndim == 1 else w)])
    if w.shape[0] == 1:
        w = np.repeat(w, path.shape[0], axis=0)
    if w.shape[0] != path.shape[0]:
        raise StiffnessError(f"{w.shape[0]} wrenches for {path.shape[0]} path points")
    lo, hi = coordinate_limits(em.full)
    for i, row in enumerate(path):
        bad = np.flatnonzero((row < lo - 1e-12) | (row > hi + 1e-12))
        if bad.size:
            j = bad[0]
            raise StiffnessError(
                f"path row {i + 1}: {em.robot.coordinate_joints[j]} = {row[j]:.6g} is beyond "
                f"its limits [{lo[j]:.6g}, {hi[j]:.6g}] (rad or m); fix the path or its unit")
    points: list[PointCompensation] = []
    seed = None
    chosen = hold
    for i, coords in enumerate(path):
        try:
            q = em.full.configuration(coords, seed=seed)
            if chosen == "auto":
                chosen = choose_hold(em, q)
            load = w[i].copy()
            if wrench_frame == "target":
                kinematics.update_first_order(em.full.model, em.full.data, q)
                rot = em.full.data.oMf[em.full.target_frame_id].rotation
                load = np.concatenate([rot @ load[:3], rot @ load[3:]])
            point = compensate_point(em, coords, load, chosen, method, seed_q=q)
        except StiffnessError as exc:
            raise with_context(exc, f"path row {i + 1}") from exc
        points.append(point)
        seed = point.q_nominal
        if progress is not None:
            progress(i + 1, path.shape[0])
    return PathCompensation(points, tuple(em.robot.coordinate_joints), chosen, em)


# ------------------------------------------------------------------------------------------
# model files


def load_elastic_model(path: str | Path) -> ElasticModel:
    """The elastic model of a model file: ``identified-model.json`` (``stiffness identify``)
    or ``final-model.json`` (``stiffness diagnose``), with every effect acting on the robot.

    Raises
    ------
    StiffnessError
        Unreadable file, unknown format, or a malformed key.
    """
    from stiffness.calibration.identify import MODEL_FORMAT as IDENTIFIED
    from stiffness.calibration.identify import load_identified_model

    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise MissingFileError(f"cannot read model file {path}: {exc.strerror}; give the "
                               "identified-model.json or final-model.json", path=path) from exc
    except json.JSONDecodeError as exc:
        raise FileFormatError(f"not JSON ({exc.msg}); give the identified-model.json or "
                              "final-model.json", path=path, line=exc.lineno,
                              column=exc.colno) from exc
    fmt = doc.get("format") if isinstance(doc, dict) else None
    if fmt == IDENTIFIED:
        ident = load_identified_model(path)
        em = ElasticModel.joint_springs(ident.robot(), ident.k_theta,
                                        "conventional" if ident.formulation == "conventional"
                                        else "enhanced")
        em.source = str(path)
        return em
    from stiffness.calibration.diagnose import MODEL_FORMAT as DIAGNOSED

    if fmt != DIAGNOSED:
        raise StiffnessError(
            f"{path} is not a model file (format {fmt!r}); give the identified-model.json "
            "of `stiffness identify` or the final-model.json of `stiffness diagnose`")
    return _diagnosed_model(doc, path)


def _diagnosed_model(doc: dict, path: Path) -> ElasticModel:
    from stiffness.calibration.campaign import _resolve_source
    from stiffness.calibration.effects import Geometry, References, make_effect
    from stiffness.model.robot import load_robot

    def get(*keys):
        node = doc
        for key in keys:
            if not isinstance(node, dict) or key not in node:
                raise StiffnessError(f"{path}: missing key {'.'.join(keys)}; rewrite the file "
                                     "with `stiffness diagnose`")
            node = node[key]
        return node

    compliant = [str(j) for j in get("compliant_joints")]
    effects_doc = get("effects")
    added = [e["where"] for e in effects_doc if e.get("effect") == "joint_compliance"]
    source = _resolve_source(str(get("robot", "source")), path.parent)
    robot = load_robot(source, frame=get("robot", "frame"),
                       target_offset=np.asarray(get("robot", "target_offset_m"), dtype=float),
                       compliant_joints=compliant + added)
    geometry = Geometry.of(robot)
    refs_doc = get("references")
    joints = geometry.joints
    try:
        refs = References(
            joints, float(refs_doc["k_ref"]),
            np.array([float(refs_doc["tau_max"][j]) for j in joints]),
            np.array([float(refs_doc["tau_smoothing"][j]) for j in joints]),
            float(refs_doc["theta_ref"]), float(refs_doc["force_ref"]),
            float(refs_doc["deflection_ref"]))
    except (KeyError, TypeError, ValueError) as exc:
        raise StiffnessError(f"{path}: references are incomplete ({exc}); rewrite the file "
                             "with `stiffness diagnose`") from exc
    x = np.asarray(get("parameter_vector"), dtype=float)
    effects = [make_effect(str(e.get("effect")), e.get("where"), geometry) for e in effects_doc]
    sizes = [len(compliant)] + [e.n_params for e in effects]
    if x.shape[0] != sum(sizes):
        raise StiffnessError(f"{path}: parameter_vector has {x.shape[0]} values for "
                             f"{sum(sizes)} parameters; rewrite the file with `stiffness diagnose`")
    n = robot.n_coordinates
    coord = list(robot.coordinate_joints)
    compliance = np.zeros(n)
    compliance[[coord.index(j) for j in compliant]] = np.exp(-x[: len(compliant)])
    smoothing = np.array([refs.tau_smoothing[joints.index(j)] for j in coord])
    law = Law(compliance, np.zeros(n), np.zeros(n), smoothing)
    links, ignored = [], []
    offset = len(compliant)
    for e in effects:
        p = e.physical(x[offset: offset + e.n_params], refs)
        offset += e.n_params
        if e.name in RIG_EFFECTS:
            ignored.append(e.label)
        elif e.name == "link_compliance":
            links.append(LinkBend(e.a, e.b, e.column, (1.0 / p[0], 1.0 / p[1])))
        elif e.joint is not None:
            e.adjust_law(p, law, coord.index(e.joint), refs)
    formulation = "enhanced" if get("baseline") == "enhanced" or any(
        e.name == "complementary_stiffness" for e in effects) else "conventional"
    return ElasticModel(robot, law, tuple(links), formulation, tuple(ignored), str(path))


# ------------------------------------------------------------------------------------------
# path files


@dataclass
class JointPath:
    """A joint path read from CSV.

    Attributes
    ----------
    header
        The input columns, as given.
    cells
        The input cells (text), one list per row.
    coords
        (m, n) coordinates in SI (rad, m), model coordinate order.
    wrench
        (m, 6) per-row wrenches (N, N.m), or None.
    column_of
        Input column name of each coordinate.
    angular
        (n,) whether each coordinate is an angle (converted by ``--deg``).
    lines
        File line (1-based) of each row.
    """

    header: list[str]
    cells: list[list[str]]
    coords: np.ndarray
    wrench: np.ndarray | None
    column_of: list[str]
    angular: np.ndarray
    lines: list[int] = field(default_factory=list)


@dataclass
class Table:
    """A CSV table: its header, and its non-empty rows with their 1-based file line numbers."""

    path: Path
    header: list[str]
    rows: list[list[str]]
    lines: list[int]

    def column(self, name: str) -> np.ndarray:
        """The finite numbers of column ``name``.

        Raises
        ------
        FileFormatError
            A cell that is not a finite number (its line, column and name).
        """
        k = self.header.index(name)
        out = np.empty(len(self.rows))
        for r, (row, line) in enumerate(zip(self.rows, self.lines, strict=True)):
            cell = row[k].strip() if k < len(row) else ""
            try:
                value = float(cell)
            except ValueError:
                raise FileFormatError(f"{cell!r} is not a number; every value must be one",
                                      path=self.path, line=line, column=k + 1, field=name
                                      ) from None
            if not math.isfinite(value):
                raise FileFormatError(f"{cell!r}: every value must be a finite number",
                                      path=self.path, line=line, column=k + 1, field=name)
            out[r] = value
        return out

    def wrenches(self) -> np.ndarray | None:
        """(m, 6) per-row loads of columns ``fx,fy,fz[,mx,my,mz]`` (N, N.m), or None."""
        present = [c for c in WRENCH_COLUMNS if c in self.header]
        if not present:
            return None
        if not all(c in present for c in WRENCH_COLUMNS[:3]) or len(present) not in (3, 6):
            raise FileFormatError("per-row loads need the columns fx, fy, fz (N), and "
                                  "optionally all of mx, my, mz (N.m)", path=self.path, line=1)
        out = np.zeros((len(self.rows), 6))
        for k, c in enumerate(WRENCH_COLUMNS):
            if c in present:
                out[:, k] = self.column(c)
        return out


def read_table(path: str | Path, what: str) -> Table:
    """Read a CSV file with a header line (``what`` names it in errors).

    Raises
    ------
    MissingFileError
        The file cannot be read.
    FileFormatError
        No data row.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise MissingFileError(f"cannot read {what} {path}: {exc.strerror}; give an existing "
                               "CSV file", path=path) from exc
    rows, lines = [], []
    for row in csv.reader(io.StringIO(text)):
        if row and any(c.strip() for c in row):
            rows.append(row)
    # csv.reader does not give line numbers: count them on the text (no quoted newlines)
    numbered = [k + 1 for k, line in enumerate(text.splitlines()) if line.strip(" ,\t")]
    lines = numbered[: len(rows)]
    if len(rows) < 2:
        raise FileFormatError(f"no {what} rows: give a header line and one row per point",
                              path=path)
    return Table(path, [h.strip() for h in rows[0]], rows[1:], lines[1:])


def read_joint_path(path: str | Path, robot: Robot, deg: bool = False) -> JointPath:
    """Read ``PATH.csv``: one column per coordinate, named by joint name or ``q1..qn`` (model
    coordinate order), one row per point; optional ``fx,fy,fz[,mx,my,mz]`` (N, N.m) per row.

    Raises
    ------
    MissingFileError, FileFormatError
        Unreadable file, a missing coordinate column, a value that is not a finite number
        (named by line and column).
    """
    table = read_table(path, "path file")
    header = table.header
    joints = list(robot.coordinate_joints)
    by_index = [f"q{i + 1}" for i in range(len(joints))]
    if all(j in header for j in joints):
        column_of = joints
    elif all(q in header for q in by_index):
        column_of = by_index
    else:
        missing = [j for j in joints if j not in header]
        missing_q = [q for q in by_index if q not in header]
        shown = missing if len(missing) <= len(missing_q) else missing_q
        other = "" if set(header) & set(joints + by_index) else (
            " (its columns name none of them: is the model file of another robot?)")
        raise FileFormatError(
            f"lacks the coordinate column(s) {', '.join(shown)} of {robot.name}{other}: name "
            f"one column per coordinate ({', '.join(joints)}, or q1..q{len(joints)})",
            path=table.path, line=1)
    coords = np.column_stack([table.column(c) for c in column_of])
    wrench = table.wrenches()
    model = robot.model
    angular = np.array([not model.joints[model.getJointId(j)].shortname().startswith(
        "JointModelP") for j in joints])
    if deg:
        coords[:, angular] = np.deg2rad(coords[:, angular])
    return JointPath(header, [list(r) for r in table.rows], coords, wrench, column_of, angular,
                     table.lines)
