"""The loaded robot's exact equilibrium, link bends included.

The elastic model (:class:`stiffness.elastic.model.ElasticModel`) holds:

* a joint law over the spring joints (:attr:`stiffness.robot.robot.Robot.spring_joints`: the
  coordinates, or a ``[controller]``'s chain joints), ``theta - theta_c = law(tau)`` with
  ``tau = J(theta)^T W``
  (linear springs, extra springs on joints the baseline holds rigid, nonlinear springs
  ``tau/k (1 + beta|tau|)`` and backlash ``b tanh(tau/tau_s)``; zero for rigid coordinates);
  ``theta_c`` is the command (the springs' rest positions);
* link compliances (:class:`LinkBend`): the segment ``a -> b`` bends at ``b``'s origin about two
  axes normal to it, modelled exactly as two virtual revolute joints there (a universal joint:
  the second axis is carried by the first) with springs ``k_1, k_2``. The axes are those of
  :func:`stiffness.elastic.effects.geometry.link_axes` at a reference configuration (the nominal one
  of a path point, :func:`frozen_axes`), fixed in the body joint ``b`` is mounted on. The bend
  rotates everything beyond it; loops are closed on the unbent kinematics (as in the effect
  library). A joint tilting in its bearing (``transversal_compliance``) is the same bend at the
  joint's origin about the two axes of its mounting frame normal to its rotation axis
  (:func:`stiffness.elastic.effects.geometry.tilt_axes`; :attr:`LinkBend.tilt`).

Exact equilibrium (:func:`loaded_equilibrium`) under a dead wrench ``W`` at the target: unknowns
``z = [theta, alpha]``, equations ``theta - theta_c = law(J_theta^T W)``,
``alpha = law_link(J_alpha^T W)``, solved by Newton with the tangent ``I - diag(law') K_C``
(``K_C`` of the coordinates from the kinematic Hessians). :func:`bent_kinematics` gives the
target pose and its exact Jacobian w.r.t. ``z`` (product of exponentials of the bends);
:func:`linear_deflection` the first-order deflection ``C W``.

Units: SI (m, N, rad, N.m/rad; m and N/m for prismatic joints).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import pinocchio as pin

from stiffness.elastic.effects.geometry import link_axes, skew, tilt_axes
from stiffness.errors import ConvergenceError, UnstableEquilibriumError
from stiffness.mechanics.equilibrium import SpringLaw
from stiffness.mechanics.formulation import as_wrench, target_state
from stiffness.robot import kinematics
from stiffness.robot.robot import Robot

#: Convergence of the exact equilibrium (rad, m of the joint and bend variables), plus 1e-11
#: of the largest deflection (closure noise of loops).
EQUILIBRIUM_TOLERANCE = 1e-14

# ------------------------------------------------------------------------------------------
# link bends


@dataclass(frozen=True)
class LinkBend:
    """A link compliance: the segment ``a -> b`` bends at ``b``'s origin.

    ``column`` picks the mounting body's axis that :func:`link_axes` makes normal to the
    segment; ``stiffness`` (2,) N.m/rad about ``e_1`` and ``e_2``. With ``tilt`` the joint
    ``b`` (``a == b``) tilts in its bearing: ``column`` is its rotation axis and the bend's axes
    the other two of its mounting frame (:func:`tilt_axes`).
    """

    a: str
    b: str
    column: int
    stiffness: tuple[float, float]
    tilt: bool = False

    @property
    def label(self) -> str:
        """``link bend a->b`` or ``transversal compliance b``."""
        return f"transversal compliance {self.b}" if self.tilt else f"link bend {self.a}->{self.b}"


class LoadedRobot(Protocol):
    """What the exact equilibrium reads of an elastic model
    (:class:`stiffness.elastic.model.ElasticModel`)."""

    robot: Robot
    law: SpringLaw
    links: tuple[LinkBend, ...]
    formulation: str

    @property
    def springs(self) -> Robot:
        """The robot whose coordinates are the spring joints, every one compliant."""
        ...

    def ordered_links(self) -> list[LinkBend]:
        """Links from the base to the tip."""
        ...


def bend_frame(model: pin.Model, data: pin.Data, lk: LinkBend
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The bend's point (``b``'s origin, m) and its two axes ``e_1, e_2`` (world) from the
    current placements ``data``: normal to the segment ``a -> b`` (:func:`link_axes`), or for a
    tilt the joint's bearing axes (:func:`tilt_axes`)."""
    jb = model.getJointId(lk.b)
    point = np.array(data.oMi[jb].translation)
    mount = data.oMi[model.parents[jb]].rotation
    if lk.tilt:
        e1, e2 = tilt_axes(mount @ model.jointPlacements[jb].rotation, lk.column)
    else:
        e1, e2 = link_axes(data.oMi[model.getJointId(lk.a)].translation, point, mount,
                           lk.column)
    return point, e1, e2


def frozen_axes(em: LoadedRobot, links: list[LinkBend]) -> list[np.ndarray]:
    """Bend axes (2, 3) in each mounting body's frame, from the current placements."""
    model, data = em.springs.model, em.springs.data
    out = []
    for lk in links:
        mount = data.oMi[model.parents[model.getJointId(lk.b)]].rotation
        _, e1, e2 = bend_frame(model, data, lk)
        out.append(np.vstack([mount.T @ e1, mount.T @ e2]))
    return out


# ------------------------------------------------------------------------------------------
# kinematics of the loaded robot


@dataclass
class BentKinematics:
    """Target pose and Jacobians of the (bent) robot at ``z = [coords, alpha]`` (``coords``:
    the spring joints' values, :attr:`stiffness.robot.robot.Robot.spring_joints`)."""

    q: np.ndarray
    position: np.ndarray
    rotation: np.ndarray
    jac: np.ndarray  # (6, n + 2m) rows [v; omega] base axes at the target
    k_c: np.ndarray  # (n + 2m, n + 2m): K_C of the coordinates (bend rows zero)


def bent_kinematics(em: LoadedRobot, links: list[LinkBend], axes: list[np.ndarray],
                coords: np.ndarray, alpha: np.ndarray, wrench: np.ndarray,
                seed_q: np.ndarray | None) -> BentKinematics:
    full = em.springs
    n, m = full.n_coordinates, 2 * len(links)
    q = full.configuration(coords, seed=seed_q)
    state = target_state(full, q, wrench)
    k_c = np.zeros((n + m, n + m))
    k_c[:n, :n] = state.k_c
    if not links:
        return BentKinematics(q, state.position, state.rotation, state.jacobian, k_c)
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
    jac = np.vstack([spatial[:3] - skew(position) @ spatial[3:], spatial[3:]])
    return BentKinematics(q, position, rotation, jac, k_c)


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
        Spring joints' values at equilibrium (rad, m): the coordinates, or a
        ``[controller]``'s chain joints for springs on the chain.
    alpha
        Bend angles of the link compliances (rad), two per link (base to tip).
    position, rotation
        Target pose at equilibrium (m; rotation matrix), base frame.
    torque
        Generalised forces ``J^T W`` at equilibrium over ``[coords, alpha]``.
    iterations
        Newton iterations.
    kin
        Pose, Jacobian and K_C at equilibrium (:func:`bent_kinematics`).
    slope
        Slope of the joint and bend laws at the equilibrium torques.
    """

    q: np.ndarray
    coords: np.ndarray
    alpha: np.ndarray
    position: np.ndarray
    rotation: np.ndarray
    torque: np.ndarray
    iterations: int
    kin: BentKinematics = field(repr=False)
    slope: np.ndarray = field(repr=False)


def _law_z(em: LoadedRobot, links: list[LinkBend], tau: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    n = em.springs.n_coordinates
    value, slope = em.law(tau[:n])
    c_link = np.array([1.0 / k for lk in links for k in lk.stiffness])
    return (np.concatenate([value, c_link * tau[n:]]),
            np.concatenate([slope, c_link]))


def loaded_equilibrium(em: LoadedRobot, command: np.ndarray, wrench: np.ndarray,
                       seed_q: np.ndarray | None = None, axes: list[np.ndarray] | None = None,
                       max_iterations: int = 60) -> Loaded:
    """Exact elastostatic equilibrium of the robot commanded at ``command`` under ``wrench``.

    Parameters
    ----------
    em
        The elastic model.
    command
        Commanded values of the spring joints (rad, m): the springs' rest positions
        (:meth:`stiffness.robot.robot.Robot.spring_command` of the commanded coordinates).
    wrench
        Dead force (3,) N or wrench (6,) N, N.m at the target, base axes.
    seed_q
        A closed configuration near the equilibrium (the loop branch), default the command's.
    axes
        Bend axes per link (:func:`frozen_axes`), default those at the command.

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
        kinematics.update_first_order(em.springs.model, em.springs.data,
                                      em.springs.configuration(command, seed=seed_q))
        axes = frozen_axes(em, links)
    z = np.concatenate([command, np.zeros(m)])
    base = np.concatenate([command, np.zeros(m)])
    q = seed_q
    for iterations in range(1, max_iterations + 1):
        kin = bent_kinematics(em, links, axes, z[:n], z[n:], wrench, q)
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
            kin = bent_kinematics(em, links, axes, z[:n], z[n:], wrench, q)
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


def linear_shift(em: LoadedRobot, links: list[LinkBend], kin: BentKinematics, wrench: np.ndarray
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


def linear_deflection(em: LoadedRobot, coords: np.ndarray, wrench: np.ndarray,
                      seed_q: np.ndarray | None = None) -> np.ndarray:
    """First-order deflection ``C W`` (6,) [m; rad] of the target at the spring joints'
    values ``coords`` (rad, m; :meth:`stiffness.robot.robot.Robot.spring_command`)
    under the dead ``wrench`` (base axes), every effect of the model included."""
    wrench = as_wrench(wrench)
    links = em.ordered_links()
    q = em.springs.configuration(coords, seed=seed_q)
    kinematics.update_first_order(em.springs.model, em.springs.data, q)
    axes = frozen_axes(em, links)
    kin = bent_kinematics(em, links, axes, np.asarray(coords, dtype=float),
                      np.zeros(2 * len(links)), wrench, q)
    return linear_shift(em, links, kin, wrench)
