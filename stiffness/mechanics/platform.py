"""Parallel platforms (Stewart-Gough, Griffis-Duffy couplings) on the loop machinery.

A platform with ``n`` legs between base anchors ``b_i`` and platform anchors ``p_i`` is written
as a URDF tree plus a loop declaration (:func:`platform_urdf`, :func:`platform_loop_declaration`):

* the platform hangs from the base through a virtual six-degree-of-freedom chain (prismatic
  ``platform_x``, ``platform_y``, ``platform_z`` along the base axes, then revolute
  ``platform_rx``, ``platform_ry``, ``platform_rz``), all zero at the reference pose, passive;
* each leg ``i`` is a U-P chain: a universal joint at ``b_i`` (revolute ``leg<i>_ux`` about the
  leg frame's x, then ``leg<i>_uy`` about its y; both zero at the reference pose, where the leg
  frame's z points along the leg), then the prismatic joint ``leg<i>`` along z, whose
  coordinate is the leg length (m): the spring, compliant, actuated;
* the loop ``[leg<i>_tip, leg<i>_anchor]`` ("3D", a spherical joint) closes the leg on the
  platform.

Passive joints: the virtual chain and the universal joints (6 + 2n); constraint rows: 3n. For
six legs the passive Jacobian is square (18 x 18) and the six leg lengths are the coordinates.

Stiffness of the platform (Zefran & Kumar; see docs/spatial-loops.md): the target is the
platform frame; :func:`holding_wrench` is the wrench that holds the platform against springs
with rest lengths other than the current ones; :func:`lie_bracket_term` predicts the
antisymmetric part of the twist-basis stiffness from that wrench; :func:`stiffness_map` maps
the stiffness over platform poses, each pose reached by :func:`solve_pose` (loop-closed inverse
kinematics of the target frame).

Spatial vectors follow Pinocchio: twists ``[v; omega]``, wrenches ``[F; M]`` (N, N.m);
:func:`reorder_twist` permutes 6-vectors and 6x6 matrices to the papers' ``[omega; v]``.
Units: SI (m, N, rad).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from stiffness.errors import ConvergenceError, StiffnessError, UnknownNameError
from stiffness.mechanics.formulation import (
    TargetState,
    joint_connection_stiffness,
    target_state,
    target_states,
    twist_basis_stiffness,
)
from stiffness.model import kinematics
from stiffness.model.robot import Robot

#: Names of the passive virtual joints carrying the platform, in chain order.
VIRTUAL_JOINTS = ("platform_x", "platform_y", "platform_z",
                  "platform_rx", "platform_ry", "platform_rz")

#: Row orders of 6-vectors: Pinocchio's (linear first) and the papers' (angular first).
TWIST_ORDERS = {"v-w": ["vx", "vy", "vz", "wx", "wy", "wz"],
                "w-v": ["wx", "wy", "wz", "vx", "vy", "vz"]}
#: Names of the wrench components dual to each twist order.
WRENCH_ORDERS = {"v-w": ["fx", "fy", "fz", "mx", "my", "mz"],
                 "w-v": ["mx", "my", "mz", "fx", "fy", "fz"]}
_ANGULAR_FIRST = np.array([3, 4, 5, 0, 1, 2])


@dataclass(frozen=True)
class PlatformSpec:
    """Geometry of a leg-spring parallel platform.

    Attributes
    ----------
    name
        Robot name (URDF ``<robot name>``).
    base_anchors
        (n, 3) base attachment points, base frame (m).
    platform_anchors
        (n, 3) platform attachment points, platform frame (m); leg ``i`` joins
        ``base_anchors[i]`` to ``platform_anchors[i]`` (anchors may repeat).
    platform_pose
        Pose of the platform frame in the base frame at the reference configuration (all
        passive joints zero there).
    leg_names
        Prismatic joint names, default ``leg1..legn``.
    """

    name: str
    base_anchors: np.ndarray
    platform_anchors: np.ndarray
    platform_pose: pin.SE3 = field(default_factory=pin.SE3.Identity)
    leg_names: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        base = np.asarray(self.base_anchors, dtype=float)
        plat = np.asarray(self.platform_anchors, dtype=float)
        if base.ndim != 2 or base.shape[1] != 3 or base.shape != plat.shape:
            raise StiffnessError(
                f"base and platform anchors must both be (n, 3) arrays in m, got {base.shape} "
                f"and {plat.shape}"
            )
        object.__setattr__(self, "base_anchors", base)
        object.__setattr__(self, "platform_anchors", plat)
        names = self.leg_names or tuple(f"leg{i + 1}" for i in range(base.shape[0]))
        if len(names) != base.shape[0]:
            raise StiffnessError(f"{len(names)} leg names for {base.shape[0]} legs")
        object.__setattr__(self, "leg_names", tuple(names))

    @property
    def n_legs(self) -> int:
        """Number of legs."""
        return self.base_anchors.shape[0]

    def leg_vectors(self, pose: pin.SE3 | None = None) -> np.ndarray:
        """(n, 3) vectors from base anchors to platform anchors at a platform pose (m)."""
        pose = self.platform_pose if pose is None else pose
        world = self.platform_anchors @ pose.rotation.T + pose.translation
        return world - self.base_anchors

    def leg_lengths(self, pose: pin.SE3 | None = None) -> np.ndarray:
        """Leg lengths (m) at a platform pose (default: the reference pose)."""
        return np.linalg.norm(self.leg_vectors(pose), axis=1)


def _leg_frame(direction: np.ndarray) -> np.ndarray:
    """Rotation whose z axis is ``direction`` (x chosen away from it: no gimbal lock)."""
    z = direction / np.linalg.norm(direction)
    helper = np.eye(3)[int(np.argmin(np.abs(z)))]
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def _origin(xyz: np.ndarray, rotation: np.ndarray | None = None) -> str:
    rpy = np.zeros(3) if rotation is None else pin.rpy.matrixToRpy(rotation)
    return (f'<origin xyz="{xyz[0]:.12g} {xyz[1]:.12g} {xyz[2]:.12g}" '
            f'rpy="{rpy[0]:.17g} {rpy[1]:.17g} {rpy[2]:.17g}"/>')


def _joint(name: str, kind: str, parent: str, child: str, origin: str, axis: str | None = None,
           limits: tuple[float, float] | None = None) -> str:
    text = f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
    text += origin
    if axis is not None:
        text += f'<axis xyz="{axis}"/>'
    if limits is not None:
        text += (f'<limit effort="1e6" velocity="1.0" lower="{limits[0]:.12g}" '
                 f'upper="{limits[1]:.12g}"/>')
    return text + "</joint>"


def platform_urdf(spec: PlatformSpec, reach_m: float | None = None) -> str:
    """URDF text of the platform tree (see the module docstring), lengths in m.

    Parameters
    ----------
    spec
        Platform geometry.
    reach_m
        Range of the virtual prismatic joints and upper limit of the legs (m); default ten
        times the longest leg.
    """
    reach = float(reach_m or 10.0 * np.max(spec.leg_lengths()))
    links = ["base_link"]
    joints = []
    parent = "base_link"
    axes = ("1 0 0", "0 1 0", "0 0 1") * 2
    for i, name in enumerate(VIRTUAL_JOINTS):
        child = "platform" if i == len(VIRTUAL_JOINTS) - 1 else f"{name}_link"
        origin = (_origin(spec.platform_pose.translation, spec.platform_pose.rotation)
                  if i == 0 else _origin(np.zeros(3)))
        kind, limits = ("prismatic", (-reach, reach)) if i < 3 else ("revolute", (-np.pi, np.pi))
        joints.append(_joint(name, kind, parent, child, origin, axes[i], limits))
        links.append(child)
        parent = child
    vectors = spec.leg_vectors()
    for i, leg in enumerate(spec.leg_names):
        rot = _leg_frame(vectors[i])
        links += [f"{leg}_cardan", f"{leg}_cylinder", f"{leg}_rod", f"{leg}_tip", f"{leg}_anchor"]
        joints += [
            _joint(f"{leg}_ux", "revolute", "base_link", f"{leg}_cardan",
                   _origin(spec.base_anchors[i], rot), "1 0 0", (-np.pi, np.pi)),
            _joint(f"{leg}_uy", "revolute", f"{leg}_cardan", f"{leg}_cylinder",
                   _origin(np.zeros(3)), "0 1 0", (-np.pi, np.pi)),
            _joint(leg, "prismatic", f"{leg}_cylinder", f"{leg}_rod", _origin(np.zeros(3)),
                   "0 0 1", (0.0, reach)),
            _joint(f"{leg}_tip_joint", "fixed", f"{leg}_rod", f"{leg}_tip",
                   _origin(np.zeros(3))),
            _joint(f"{leg}_anchor_joint", "fixed", "platform", f"{leg}_anchor",
                   _origin(spec.platform_anchors[i])),
        ]
    body = "".join(f'<link name="{n}"/>' for n in links) + "".join(joints)
    return f'<?xml version="1.0"?>\n<robot name="{spec.name}">{body}</robot>\n'


def platform_loop_declaration(spec: PlatformSpec) -> str:
    """Loop declaration (Extended-URDF YAML text) of :func:`platform_urdf`'s tree."""
    legs = spec.leg_names
    pairs = "".join(f"  - [{leg}_tip, {leg}_anchor]\n" for leg in legs)
    passive = list(VIRTUAL_JOINTS) + [f"{leg}_{u}" for leg in legs for u in ("ux", "uy")]
    return (
        f"# Loop declaration of {spec.name}: each leg's tip meets its platform anchor (a\n"
        "# spherical joint); the leg lengths are actuated (the springs), the virtual platform\n"
        "# chain and the universal joints passive. Written by stiffness.mechanics.platform.\n"
        f"closed_loop:\n{pairs}"
        "type: [" + ", ".join(['"3D"'] * len(legs)) + "]\n"
        f"name_mot: [{', '.join(legs)}]\n"
        f"passive_joints: [{', '.join(passive)}]\n"
    )


# ----------------------------------------------------------------------------- 6-D stiffness


def reorder_twist(x: np.ndarray, order: str = "w-v") -> np.ndarray:
    """A 6-vector or 6x6 matrix from Pinocchio's ``[v; omega]`` order to ``order``.

    ``"v-w"`` returns a copy; ``"w-v"`` swaps the blocks (rows, and columns of a matrix).
    Wrenches ``[F; M]`` become ``[M; F]`` the same way.
    """
    if order not in TWIST_ORDERS:
        raise UnknownNameError(f"twist order must be one of {', '.join(TWIST_ORDERS)}, got "
                               f"{order!r}", name=order, choices=list(TWIST_ORDERS))
    x = np.asarray(x, dtype=float)
    if order == "v-w":
        return x.copy()
    if x.ndim == 1:
        return x[_ANGULAR_FIRST]
    return x[np.ix_(_ANGULAR_FIRST, _ANGULAR_FIRST)]


def holding_wrench(robot: Robot, q: np.ndarray, k_theta: np.ndarray,
                   rest: np.ndarray | list[float]) -> np.ndarray:
    """Dead wrench at the target that holds it at ``q`` against the springs, [F; M] base axes.

    The springs pull with ``tau = K_theta (theta - theta_rest)`` on the compliant joints; the
    holding wrench balances them: ``J^T W = tau`` (J the closed-loop target Jacobian, rows
    [v; omega], base axes at the target). The springs' own wrench on the target is ``-W``
    (Zefran & Kumar's ``W_i = -L_i Phi`` in body components).

    Parameters
    ----------
    robot
        The robot (its target frame carries the wrench).
    q
        Closed configuration.
    k_theta
        (n, n) joint stiffness (N/m for prismatic, N.m/rad for revolute joints).
    rest
        Rest value of each compliant joint (m or rad).

    Raises
    ------
    StiffnessError
        If ``rest`` has the wrong length, or if no target wrench balances the springs (fewer
        than six compliant joints pulling outside the range of ``J^T``).
    """
    rest = np.asarray(rest, dtype=float).reshape(-1)
    if rest.shape[0] != robot.n_compliant or not np.all(np.isfinite(rest)):
        raise StiffnessError(
            f"need one finite rest value per compliant joint ({robot.n_compliant}: "
            f"{', '.join(robot.compliant_joints)}), got {rest.tolist()}"
        )
    theta = robot.coordinates_of(q)[robot.compliant_in_coordinates]
    tau = k_theta @ (theta - rest)
    jac = target_state(robot, q).jacobian
    wrench = np.linalg.lstsq(jac.T, tau, rcond=1e-12)[0]
    if np.linalg.norm(jac.T @ wrench - tau) > 1e-8 * max(1.0, np.linalg.norm(tau)):
        raise StiffnessError(
            "no wrench at the target balances the springs at this configuration (the compliant "
            "joints are not all loaded through the target); give the load explicitly"
        )
    return wrench


def body_wrench(state: TargetState) -> np.ndarray:
    """The state's wrench [F; M] in the target's body axes (N, N.m)."""
    rt = state.rotation.T
    return np.concatenate([rt @ state.wrench[:3], rt @ state.wrench[3:]])


def lie_bracket_term(wrench_body: np.ndarray) -> np.ndarray:
    """Antisymmetric part of the twist-basis stiffness predicted by Zefran & Kumar eq. 34.

    ``K_a[i, j] - K_a[j, i] = [L_j, L_i](Phi) = <W, ad(e_j) e_i>`` for left-invariant basis
    twists ``e_i`` (Pinocchio order [v; omega]) and ``W`` the holding wrench in body
    components (``L_k(Phi) = W_k``). Units: N.m (rows/columns mixing linear and angular: N).

    Returns
    -------
    numpy.ndarray
        (6, 6) matrix ``B`` with ``B[i, j] = W . (e_j x e_i)`` (``x`` the motion cross
        product), Pinocchio order.
    """
    wrench = pin.Force(np.asarray(wrench_body, dtype=float))
    basis = [pin.Motion(e) for e in np.eye(6)]
    return np.array([[wrench.dot(basis[j].cross(basis[i])) for j in range(6)]
                     for i in range(6)])


def jacobian_derivative(robot: Robot, q: np.ndarray) -> np.ndarray:
    """Derivative of the closed-loop target Jacobian, ``D[k, a, b] = dJ[k, a] / d theta_b``.

    ``J`` is the (6, n) Jacobian w.r.t. the compliant joints, rows [v; omega], base axes at the
    target (loops closed). Row ``k`` is the complementary stiffness of the unit wrench ``e_k``:
    ``K_C(W) = sum_k W_k D[k]``. Units: m/rad^2 (m/m^2 for prismatic joints), rad/rad^2.
    """
    return np.stack([s.k_c for s in target_states(robot, q, np.eye(6))])


def solve_pose(robot: Robot, pose: pin.SE3, seed: np.ndarray, max_iterations: int = 50,
               tolerance: float = 1e-12) -> np.ndarray:
    """Closed configuration placing the target frame at ``pose`` (loop-closed inverse kinematics).

    Gauss-Newton on all joints for the loop residual and ``log6(pose^-1 oMt)``, from ``seed``
    (a configuration near the wanted assembly branch).

    Raises
    ------
    ConvergenceError
        If the pose is not reached (outside the workspace, or a singular pose).
    """
    model, data, fid = robot.model, robot.data, robot.target_frame_id
    q = np.asarray(seed, dtype=float).copy()
    for _ in range(max_iterations):
        kinematics.update_first_order(model, data, q)
        err_m = pose.actInv(data.oMf[fid])
        err = pin.log6(err_m).vector
        res = np.concatenate([robot.loop.residual(model, data), err]) if robot.loop else err
        if np.linalg.norm(res) < tolerance:
            return q
        jt = pin.Jlog6(err_m) @ pin.getFrameJacobian(model, data, fid, pin.ReferenceFrame.LOCAL)
        jac = np.vstack([robot.loop.jacobian(model, data), jt]) if robot.loop else jt
        q = pin.integrate(model, q, -np.linalg.lstsq(jac, res, rcond=1e-10)[0])
    raise ConvergenceError(
        f"the target frame of {robot.name} cannot reach the pose {pose.translation.round(6)} m "
        f"(residual {np.linalg.norm(res):.3g} after {max_iterations} iterations): outside "
        "the workspace, or a singular pose"
    )


@dataclass
class PlatformStiffness:
    """Six-dimensional stiffness of a platform at one configuration (Pinocchio order [v; w]).

    Attributes
    ----------
    state
        Kinematics and K_C under the holding wrench.
    k_joint
        Joint-space connection ``J^-T K_theta J^-1`` (symmetric), target body axes.
    k_twist
        Twist basis ``J^-T (K_theta - K_C^tw) J^-1`` (asymmetric under load), body axes.
    wrench_body
        Holding wrench in body axes [F; M] (N, N.m).
    bracket
        ``lie_bracket_term(wrench_body)``: the predicted ``k_twist - k_twist^T``.
    """

    state: TargetState
    k_joint: np.ndarray
    k_twist: np.ndarray
    wrench_body: np.ndarray
    bracket: np.ndarray


def platform_stiffness(robot: Robot, q: np.ndarray, k_theta: np.ndarray,
                       wrench: np.ndarray | None = None,
                       rest: np.ndarray | list[float] | None = None) -> PlatformStiffness:
    """Both Zefran-Kumar stiffnesses at a closed configuration.

    The load is ``wrench`` (dead, [F; M] base axes at the target), or else the wrench holding
    the target against springs at rest values ``rest``, or else zero.
    """
    if wrench is None:
        wrench = np.zeros(6) if rest is None else holding_wrench(robot, q, k_theta, rest)
    state = target_state(robot, q, wrench)
    w_body = body_wrench(state)
    return PlatformStiffness(state, joint_connection_stiffness(state, k_theta),
                             twist_basis_stiffness(state, k_theta), w_body,
                             lie_bracket_term(w_body))


@dataclass
class StiffnessMap:
    """Platform stiffness over a list of target poses.

    Attributes
    ----------
    positions
        (m, 3) target positions (m).
    leg_lengths
        (m, n) compliant-joint coordinates reaching them (m).
    translational_min, translational_max
        (m,) extreme principal stiffnesses (N/m) of the translational block of the compliance
        inverse, ``(C_vv)^-1`` with ``C = K_joint^-1``: the stiffness against a pure force with
        the platform free to rotate.
    rotational_min
        (m,) smallest principal stiffness of ``(C_ww)^-1`` (N.m/rad): against a pure moment.
    asymmetry
        (m,) ``||K_twist - K_twist^T|| / ||K_twist||`` (Frobenius) under the load.
    bracket_error
        (m,) ``max |K_twist - K_twist^T - bracket|``: the eq. 34 check at every pose (SI).
    condition
        (m,) condition number of the closed-loop Jacobian.
    """

    positions: np.ndarray
    leg_lengths: np.ndarray
    translational_min: np.ndarray
    translational_max: np.ndarray
    rotational_min: np.ndarray
    asymmetry: np.ndarray
    bracket_error: np.ndarray
    condition: np.ndarray


def stiffness_map(robot: Robot, poses: list[pin.SE3], k_theta: np.ndarray,
                  wrench: np.ndarray | None = None, seed: np.ndarray | None = None
                  ) -> StiffnessMap:
    """Stiffness of a platform's target over poses (visit neighbours in sequence).

    Each pose is reached by :func:`solve_pose` seeded with the previous solution (first:
    ``seed``, a closed configuration, default the robot's shipped configuration ``q_SI``); the
    load is the dead ``wrench`` ([F; M] base axes, default zero).

    Raises
    ------
    StiffnessError
        Without a seed for a robot that ships no ``q_SI``; on an unreachable pose.
    """
    if seed is None:
        if "q_SI" not in robot.defaults:
            raise StiffnessError(f"{robot.name} ships no q_SI: give a closed seed configuration")
        seed = robot.configuration(np.asarray(robot.defaults["q_SI"], dtype=float))
    q = seed
    out: dict[str, list] = {k: [] for k in StiffnessMap.__dataclass_fields__}
    for pose in poses:
        q = solve_pose(robot, pose, q)
        ps = platform_stiffness(robot, q, k_theta, wrench=wrench)
        comp = np.linalg.inv(ps.k_joint)
        trans = np.linalg.eigvalsh(np.linalg.inv(comp[:3, :3]))
        rot = np.linalg.eigvalsh(np.linalg.inv(comp[3:, 3:]))
        skew = ps.k_twist - ps.k_twist.T
        out["positions"].append(pose.translation.copy())
        out["leg_lengths"].append(robot.coordinates_of(q)[robot.compliant_in_coordinates])
        out["translational_min"].append(trans[0])
        out["translational_max"].append(trans[-1])
        out["rotational_min"].append(rot[0])
        out["asymmetry"].append(np.linalg.norm(skew) / np.linalg.norm(ps.k_twist))
        out["bracket_error"].append(np.abs(skew - ps.bracket).max())
        out["condition"].append(np.linalg.cond(ps.state.jacobian))
    return StiffnessMap(**{k: np.array(v) for k, v in out.items()})
