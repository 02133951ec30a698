"""Inverse kinematics of the target frame: damped least squares on Pinocchio, loops closed.

The unknowns are a robot's coordinates (its independent joints, :mod:`stiffness.robot.robot`);
closed loops are re-closed at every step by continuation from the previous configuration, so
the solution stays on the assembly branch of the seed. The frame error is

* position: ``p(q) - p_d`` (m, base axes);
* orientation: ``log3(R(q) R_d^T)`` (rad, base axes), whose derivative is
  ``Jlog3(R R_d^T) R_d R^T omega`` (exact, not the small-angle identity).

Each step is the Levenberg-Marquardt form of damped least squares,
``dq = J^T (J J^T + lambda^2 I)^-1 (-e)``, with ``lambda`` lowered after a successful step and
raised after a failed one, so the method is robust far from the solution and converges
quadratically near it (to about 1e-13 m / rad). Joint limits are respected by clipping every
step into the model's position limits. A redundant robot gets the minimum-norm change from the
seed, which makes a path of solutions continuous.

Units: m, rad (m for prismatic coordinates).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pinocchio as pin

from stiffness.errors import ConvergenceError, StiffnessError
from stiffness.mechanics.formulation import velocity_projection
from stiffness.robot import kinematics
from stiffness.robot.robot import Robot

#: Rows of the frame error a solve can hold.
HOLDS = ("pose", "position")
#: Smallest damping of a step (m, rad: the units of the frame error). Far below the singular
#: values of a usable Jacobian (so convergence stays quadratic), it keeps each step finite where
#: ``J J^T`` is singular (a joint on its limit, a singular pose).
MIN_DAMPING = 1e-9
#: A seed is moved this fraction of each joint's range inside its limits.
SEED_INSET = 1e-3


@dataclass
class IKResult:
    """Solution of :func:`solve_ik`.

    Attributes
    ----------
    coords
        Coordinates (rad, m), one per coordinate joint.
    q
        Full configuration, loops closed.
    position_error
        Norm of the remaining position error (m).
    rotation_error
        Angle of the remaining orientation error (rad); 0 when only the position is held.
    iterations
        Steps taken.
    """

    coords: np.ndarray
    q: np.ndarray
    position_error: float
    rotation_error: float
    iterations: int


def all_coordinates(robot: Robot) -> Robot:
    """The same robot with every coordinate joint compliant (Jacobians w.r.t. all coordinates).

    Shares the Pinocchio model and the loop closure; gets its own ``data``.
    """
    if tuple(robot.compliant_joints) == tuple(robot.coordinate_joints):
        return robot
    coupling = robot.coupling if robot.coupling is None else replace(
        robot.coupling, springs_on="controller")  # rates of the controller's coordinates
    return replace(robot, compliant_joints=tuple(robot.coordinate_joints),
                   data=robot.model.createData(), coupling=coupling)


def coordinate_limits(robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper position limits (rad, m) of the coordinates (+-inf where unbounded)."""
    key = ("coordinate_limits", tuple(robot.coordinate_joints))
    kept = robot.slots.kept.get(key)
    if kept is None:  # read once per robot (each inverse kinematics asks)
        lo, hi = set_joint_limits(robot)
        if robot.coupling is not None:  # the chain's limits, as the controller's coordinates
            lo, hi = robot.coupling.limits(lo, hi)
        kept = robot.slots.kept[key] = (lo, hi)
    return kept[0].copy(), kept[1].copy()


def set_joint_limits(robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper position limits (rad, m) of the joints the coordinates set
    (:meth:`Robot.joint_values`: the coordinate joints, or a ``[controller]``'s chain joints),
    +-inf where unbounded."""
    model = robot.model
    lo, hi = [], []
    names, _ = robot.joint_values(np.zeros(robot.n_coordinates))
    lower, upper = model.lowerPositionLimit, model.upperPositionLimit  # each read builds a view
    for name in names:
        joint = model.joints[model.getJointId(name)]
        if joint.nq == 2:  # continuous joint: cos/sin pair, no limit
            lo.append(-np.inf)
            hi.append(np.inf)
            continue
        a, b = lower[joint.idx_q], upper[joint.idx_q]
        bounded = np.isfinite(a) and np.isfinite(b) and b > a and abs(b - a) < 1e10
        lo.append(a if bounded else -np.inf)
        hi.append(b if bounded else np.inf)
    return np.array(lo), np.array(hi)


def outside_limits(robot: Robot, coords: np.ndarray) -> list[str]:
    """``name = value beyond [lo, hi]`` for each coordinate (rad, m) outside its position limits
    (by more than 1e-9)."""
    lo, hi = coordinate_limits(robot)
    return [f"{name} = {value:.6g} beyond its limits [{a:.6g}, {b:.6g}]"
            for name, value, a, b in zip(robot.coordinate_joints, coords, lo, hi, strict=True)
            if value < a - 1e-9 or value > b + 1e-9]


def frame_error(robot: Robot, position: np.ndarray, rotation: np.ndarray | None
                ) -> tuple[np.ndarray, np.ndarray]:
    """Error (3 or 6,) of the target frame against ``position``/``rotation`` and its Jacobian
    w.r.t. the compliant joints of ``robot`` (kinematics must be up to date at the current q).
    """
    model, data = robot.model, robot.data
    fid = robot.target_frame_id
    jac = kinematics.frame_jacobian(model, data, fid) @ velocity_projection(robot)
    p = data.oMf[fid].translation
    e_p = p - position
    if rotation is None:
        return e_p, jac[:3]
    r = data.oMf[fid].rotation
    m = r @ rotation.T
    e_r = pin.log3(m)
    d_r = pin.Jlog3(m) @ m.T @ jac[3:]
    return np.concatenate([e_p, e_r]), np.vstack([jac[:3], d_r])


def solve_ik(
    robot: Robot,
    position: np.ndarray,
    rotation: np.ndarray | None = None,
    seed: np.ndarray | None = None,
    seed_q: np.ndarray | None = None,
    tolerance: float = 1e-12,
    max_iterations: int = 200,
    limits: bool = True,
    raise_on_failure: bool = True,
) -> IKResult:
    """Coordinates that put the target at ``position`` (and ``rotation``), by damped LS.

    Parameters
    ----------
    robot
        The robot (its target frame is solved for).
    position
        Target position (3,), base frame, m.
    rotation
        Target orientation (3, 3) in the base frame, or None to hold the position only.
    seed
        Starting coordinates (rad, m); default the coordinates of ``seed_q``, else zeros.
    seed_q
        A closed configuration near ``seed`` on the wanted loop branch.
    tolerance
        Convergence on the position (m) and orientation (rad) error norms.
    limits
        Keep the coordinates within the model's position limits.
    raise_on_failure
        Raise if the target is not reached to ``1e3 * tolerance``; else return the best found.

    Raises
    ------
    StiffnessError
        The pose is out of reach (or beyond the joint limits) from this seed.
    """
    full = all_coordinates(robot)
    position = np.asarray(position, dtype=float).reshape(3)
    coords, q, lo, hi = _start(full, seed, seed_q, limits)
    coords, q, err, iterations = _descend(full, position, rotation, coords, q, lo, hi, limits,
                                          tolerance, max_iterations)
    p_err = float(np.linalg.norm(err[:3]))
    r_err = float(np.linalg.norm(err[3:])) if rotation is not None else 0.0
    result = IKResult(coords, q, p_err, r_err, iterations)
    if raise_on_failure and not _converged(err, 1e3 * tolerance):
        within = " within the joint limits" if limits else ""
        raise ConvergenceError(
            f"the target pose is out of reach (inverse kinematics stops {p_err:.3g} m and "
            f"{r_err:.3g} rad away after {iterations} steps{within}); move the pose into the "
            "workspace"
        )
    return result


def _start(full: Robot, seed: np.ndarray | None, seed_q: np.ndarray | None, limits: bool
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The starting coordinates (rad, m: ``seed``, else ``seed_q``'s, else zeros; inside the
    limits when ``limits``), their closed configuration near ``seed_q``, and the coordinates'
    lower and upper position limits (rad, m; infinite where unbounded)."""
    if seed is None:
        seed = full.coordinates_of(seed_q) if seed_q is not None else np.zeros(full.n_coordinates)
    coords = np.asarray(seed, dtype=float).copy()
    lo, hi = coordinate_limits(full)
    if limits:
        coords = inside_limits(coords, lo, hi)
    return coords, full.configuration(coords, seed=seed_q), lo, hi


def _descend(full: Robot, position: np.ndarray, rotation: np.ndarray | None, coords: np.ndarray,
             q: np.ndarray, lo: np.ndarray, hi: np.ndarray, limits: bool, tolerance: float,
             max_iterations: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Damped least-squares descent of the target's error from ``coords`` (rad, m; closed
    configuration ``q``), the damping adapted (x10 on a rejected step, /10 on an accepted one),
    stopped when converged to ``tolerance`` (m, rad), stalled (cost not quartered in 20 steps)
    or the damping above 1e6; returns the best coordinates, their configuration, error
    (:func:`frame_error`: m, rad) and the steps taken."""
    kinematics.update_first_order(full.model, full.data, q)
    err, jac = frame_error(full, position, rotation)
    cost = float(err @ err)
    lam = 1e-3
    iterations = 0
    checkpoint = cost
    for iterations in range(1, max_iterations + 1):  # noqa: B007 (reported)
        if _converged(err, tolerance):
            break
        if iterations % 20 == 0:
            if cost > 0.25 * checkpoint:  # stalled (a limit, a singularity, out of reach)
                break
            checkpoint = cost
        step = _held_step(jac, err, lam, coords, lo, hi) if limits else damped_step(jac, err, lam)
        trial = coords + step
        if limits:
            trial = np.clip(trial, lo, hi)
        try:
            q_trial = full.assemble(trial, seed=q, search=False).q
        except StiffnessError:
            lam *= 10.0
            if lam > 1e6:
                break
            continue
        kinematics.update_first_order(full.model, full.data, q_trial)
        err_t, jac_t = frame_error(full, position, rotation)
        cost_t = float(err_t @ err_t)
        if cost_t < cost:
            coords, q, err, jac, cost = trial, q_trial, err_t, jac_t, cost_t
            lam = max(lam / 10.0, MIN_DAMPING)
        else:
            lam *= 10.0
            if lam > 1e6:
                break
    return coords, q, err, iterations


def _held_step(jac: np.ndarray, err: np.ndarray, lam: float, coords: np.ndarray,
               lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """:func:`damped_step` with an active set: the coordinates (rad, m) at a limit that the step
    pushes outward are held there, the others take the step without them."""
    step = damped_step(jac, err, lam)
    held = ((coords <= lo + 1e-12) & (step < 0)) | ((coords >= hi - 1e-12) & (step > 0))
    if held.any():
        free = ~held
        step = np.zeros_like(step)
        step[free] = damped_step(jac[:, free], err, lam)
    return step


def inside_limits(coords: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """``coords`` (rad, m) clipped into the limits, :data:`SEED_INSET` of each range inside them.

    A seed on a limit leaves the active-set step only the joints that can move away from it,
    which may be too few to move the target at all; a seed just inside keeps them all.
    """
    span = np.where(np.isfinite(hi - lo), hi - lo, 0.0)
    inset = SEED_INSET * span
    return np.clip(coords, lo + inset, hi - inset)


def damped_step(jac: np.ndarray, err: np.ndarray, lam: float) -> np.ndarray:
    """Damped least-squares step ``J^T (J J^T + lambda^2 I)^-1 (-e)``, from the SVD of ``J``.

    The same step written ``V diag(s / (s^2 + lambda^2)) U^T (-e)``: defined at any rank of
    ``J`` (a direction the joints cannot move gets no motion), with ``lambda`` floored at
    :data:`MIN_DAMPING`.
    """
    if jac.shape[1] == 0:
        return np.zeros(0)
    if not (np.isfinite(jac).all() and np.isfinite(err).all()):
        raise ConvergenceError("inverse kinematics met a non-finite Jacobian or pose error "
                               "(a NaN or infinite coordinate or target); give finite values")
    u, s, vt = np.linalg.svd(jac, full_matrices=False)
    lam = max(lam, MIN_DAMPING)
    return vt.T @ ((s / (s ** 2 + lam ** 2)) * (u.T @ -err))


def _converged(err: np.ndarray, tolerance: float) -> bool:
    return bool(np.linalg.norm(err[:3]) <= tolerance
                and (err.shape[0] == 3 or np.linalg.norm(err[3:]) <= tolerance))
