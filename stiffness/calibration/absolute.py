"""Absolute marker positions predicted from commanded coordinates: geometry and elasticity.

A measuring system (laser tracker, motion capture) sees markers fixed to frames of the robot,
in its own frame, at commanded coordinates ``q``; the arm sags under its weight and any applied
wrench. The prediction of marker ``m`` on row ``i`` is

.. math::

    y_{im} = \\exp(\\omega) R_0 \\; {}^{0}M_{f_m}(q_i + \\delta_0 + \\Delta q_i;\\ \\varepsilon)
             \\,(o_m + \\delta o_m) + t_0 + t,

with the parameter families of :data:`FAMILIES`:

``frame``
    the measuring frame's placement relative to its starting estimate ``R_0, t_0``: ``t`` (m,
    measuring-frame axes) and ``omega`` (rad, a rotation vector applied on the left);
``markers``
    each marker's offset correction ``delta o_m`` (m, in its frame's axes);
``joint_offsets``
    joint zero offsets ``delta_0`` (rad, or m for prismatic joints), one per coordinate;
``geometry``
    each moving joint's placement error ``varepsilon_j`` (translation m, rotation rad), applied
    on the right of its placement in its parent, ``M_j exp(varepsilon_j)``; for a joint along a
    frame axis the component along its own motion (the rotation about a revolute joint's axis,
    the translation along a prismatic one's) is the joint's zero offset and belongs to
    ``joint_offsets``, so the two families never share a direction (5 parameters per joint);
``joint_compliance``
    each compliant joint's compliance ``c_j`` (rad/(N.m), or m/N): ``Delta q_j = c_j tau_j``
    with ``tau = J_load(q)^T w - g(q)``, the applied wrench's and gravity's torque at the loaded
    configuration ``q`` itself (the sag's fixed point, :meth:`PoseModel.loaded_configuration`);
``gravity_lumped``
    masses unknown: ``Delta q_j = - sum_k theta_jk Y_jk(q)``, with ``Y`` the gravity regressor
    (Pinocchio's joint-torque regressor at rest, at the loaded configuration) and
    ``theta_jk = c_j pi_k`` lumped; only the combinations the data determine are fitted.

Every column of the Jacobian is analytic (Pinocchio's frame Jacobians, the right Jacobians of
``exp`` on SO(3) and SE(3)); finite differences check it in the tests. The derivative holds
the torques at the loaded configuration fixed (the sag's own change with the parameters is left
out): exact at zero compliance, and off by the relative size of ``C dtau/dq`` (about 1e-3 on
real arms) elsewhere, which shapes the solver's path, not the converged prediction. SI units
throughout.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from stiffness.errors import ConvergenceError, StiffnessError
from stiffness.robot.robot import Robot

#: Whether a robot's link masses are trusted (joint compliance times gravity torque) or not
#: (lumped compliance-times-mass-moment parameters): ``diagnose --masses``.
MASSES = ("known", "unknown")
#: Parameter families, in the order the columns are laid out.
FAMILIES = ("frame", "markers", "joint_offsets", "geometry", "joint_compliance",
            "gravity_lumped")
#: Typical size of one parameter of each family (SI), used to scale the regressor's columns.
SCALES = {"frame": 1e-3, "markers": 1e-3, "joint_offsets": 1e-3, "geometry": 1e-3,
          "joint_compliance": 1e-6, "gravity_lumped": 1e-6}
#: Units of the six components of a placement (the frame's and the geometry's).
PLACEMENT_UNITS = ("m", "m", "m", "rad", "rad", "rad")
#: Unit of a lumped gravity parameter (compliance times a mass or a mass moment).
LUMPED_UNIT = "rad/(N.m) x (kg or kg.m)"
_AXES6 = ("x", "y", "z", "rx", "ry", "rz")
#: Tolerance (rad or m) and iteration cap of the sag's fixed point.
SAG_TOLERANCE = 1e-13
SAG_ITERATIONS = 50
#: Gravity parameters of a link in Pinocchio's order (m, m c_x, m c_y, m c_z, inertia...).
_GRAVITY_PARAMETERS = ("m", "mcx", "mcy", "mcz")


class PoseModelError(StiffnessError):
    """A robot or marker set that absolute-pose calibration cannot model."""


def require_joint_springs(robot: Robot) -> None:
    """Refuse springs on a ``[controller]``'s coordinates: the pose model and its simulator
    put a spring on each compliant joint of the chain.

    Raises
    ------
    PoseModelError
        With ``[controller] springs_on = "controller"``.
    """
    if robot.springs_on_controller:
        raise PoseModelError(
            f"{robot.name}: its springs act on the controller's coordinates ([controller] "
            "springs_on = \"controller\"); absolute-pose calibration puts them on the chain's "
            "joints: set springs_on = \"chain\" and name chain joints in compliant_joints")


@dataclass(frozen=True)
class Marker:
    """A marker fixed to a frame of the robot.

    Attributes
    ----------
    name
        Marker name (the CSV columns ``<name>_x, <name>_y, <name>_z``).
    frame
        Name of the robot frame the marker is fixed to.
    offset
        Nominal position in the frame's axes (m), shape (3,).
    """

    name: str
    frame: str
    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))


@dataclass(frozen=True)
class Parameter:
    """One column of the regressor: its family, label, scale and unit."""

    family: str
    label: str
    scale: float
    unit: str


@dataclass
class Loads:
    """Applied wrenches of each row (world axes, at a frame's origin), or none.

    Attributes
    ----------
    frame
        Frame whose origin the wrench acts at.
    wrench
        (n, 6) force (N) and moment (N.m) in world axes.
    """

    frame: str
    wrench: np.ndarray


@dataclass(frozen=True)
class RowTerms:
    """What a row gives the model: the commanded configuration and the applied wrench.

    Attributes
    ----------
    q_full
        Commanded Pinocchio configuration (nq,).
    wrench
        Applied wrench (6,) in world axes at the load frame (N, N.m), or ``None``.
    """

    q_full: np.ndarray
    wrench: np.ndarray | None


@dataclass(frozen=True)
class Torques:
    """Generalised forces at a configuration (nv,), N.m or N.

    Attributes
    ----------
    gravity
        Gravity's generalised force ``-g(q)``.
    wrench
        The applied wrench's ``J_load(q)^T w``.
    lumped
        d(Delta q)/d theta of the lumped gravity parameters (nv, n_theta).
    """

    gravity: np.ndarray
    wrench: np.ndarray
    lumped: np.ndarray


class PoseModel:
    """Predicted absolute marker positions and their analytic Jacobian.

    Parameters
    ----------
    robot
        An open-chain robot (no closed loops) with the inertias gravity needs.
    markers
        The markers the measuring system sees.
    families
        Which parameter families are in the parameter vector (subset of :data:`FAMILIES`).
    loads
        Applied wrenches per row, or ``None`` (gravity alone).
    frame0
        Starting estimate of the measuring frame: (R_0 (3, 3), t_0 (3,)) mapping robot world
        coordinates to the measuring system's.
    """

    def __init__(self, robot: Robot, markers: list[Marker], families: tuple[str, ...],
                 frame0: tuple[np.ndarray, np.ndarray], loads: Loads | None = None) -> None:
        if not robot.loop.is_open_chain:
            raise PoseModelError(
                f"{robot.name} has closed loops; absolute-pose calibration handles open chains "
                "only: calibrate a serial robot, or use a deflection campaign")
        require_joint_springs(robot)
        unknown = [f for f in families if f not in FAMILIES]
        if unknown:
            raise PoseModelError(f"unknown parameter families {unknown}; valid: "
                                 f"{', '.join(FAMILIES)}")
        self.robot = robot
        self.markers = markers
        self.families = tuple(f for f in FAMILIES if f in families)
        self.rotation0, self.translation0 = (np.asarray(frame0[0], float),
                                             np.asarray(frame0[1], float))
        self.loads = loads
        model = robot.model
        self.frame_ids = [self._frame_id(m.frame) for m in markers]
        self.joints = one_dof_joints(model)
        self.compliant = [int(model.getJointId(n)) for n in robot.compliant_joints]
        self.geometry = [(n, c) for n, j in enumerate(self.joints) for c in range(6)
                         if c != _zero_component(model.joints[j].shortname())]
        self._geometry_index = (np.array([n for n, _ in self.geometry], dtype=int),
                                np.array([c for _, c in self.geometry], dtype=int))
        self.joints_v = [model.joints[j].idx_v for j in self.joints]
        self.compliant_v = [model.joints[j].idx_v for j in self.compliant]
        self._moves = {fid: np.array([j in set(model.supports[model.frames[fid].parentJoint])
                                      for j in self.joints], dtype=float)
                       for fid in set(self.frame_ids)}
        self.parameters = self._parameters()
        self._slices = self._family_slices()

    # ------------------------------------------------------------------ layout

    def _frame_id(self, name: str) -> int:
        model = self.robot.model
        if not model.existFrame(name):
            raise PoseModelError(f"marker frame {name!r} is not a frame of {self.robot.name}; "
                                 "name one of its frames in [markers]")
        return int(model.getFrameId(name))

    def _parameters(self) -> list[Parameter]:
        out: list[Parameter] = []
        names = self.robot.model.names
        for fam in self.families:
            if fam == "frame":
                out += [Parameter(fam, f"frame {a}", SCALES[fam], u)
                        for a, u in zip(_AXES6, PLACEMENT_UNITS, strict=True)]
            elif fam == "markers":
                out += [Parameter(fam, f"{m.name} offset {a}", SCALES[fam], "m")
                        for m in self.markers for a in "xyz"]
            elif fam == "joint_offsets":
                out += [Parameter(fam, f"{names[j]} zero", SCALES[fam], self._unit(j, "rad", "m"))
                        for j in self.joints]
            elif fam == "geometry":
                out += [Parameter(fam, f"{names[self.joints[n]]} placement {_AXES6[c]}",
                                  SCALES[fam], PLACEMENT_UNITS[c]) for n, c in self.geometry]
            elif fam == "joint_compliance":
                out += [Parameter(fam, f"{names[j]} compliance", SCALES[fam],
                                  self._unit(j, "rad/(N.m)", "m/N")) for j in self.compliant]
            else:
                out += [Parameter(fam, f"{names[j]} x {names[k]} {p}", SCALES[fam],
                                  LUMPED_UNIT)
                        for j in self.compliant for k in self._downstream(j)
                        for p in _GRAVITY_PARAMETERS]
        return out

    def _unit(self, joint: int, revolute: str, prismatic: str) -> str:
        return prismatic if self.robot.is_prismatic(self.robot.model.names[joint]) else revolute

    def _downstream(self, joint: int) -> list[int]:
        """Joints whose links move with ``joint`` (its subtree, itself included)."""
        return [int(k) for k in self.robot.model.subtrees[joint]]

    @property
    def size(self) -> int:
        """Number of parameters."""
        return len(self.parameters)

    def slices(self) -> dict[str, slice]:
        """Columns of each family."""
        return self._slices

    def _family_slices(self) -> dict[str, slice]:
        out, start = {}, 0
        for fam in self.families:
            n = sum(p.family == fam for p in self.parameters)
            out[fam] = slice(start, start + n)
            start += n
        return out

    # ------------------------------------------------------------------ evaluation

    def perturbed_model(self, x: np.ndarray) -> pin.Model:
        """The robot's Pinocchio model with the geometry part of ``x`` applied."""
        model = pin.Model(self.robot.model)
        sl = self.slices().get("geometry")
        if sl is not None:
            for j, e in zip(self.joints, self._placement_errors(x, sl), strict=True):
                model.jointPlacements[j] = model.jointPlacements[j] * pin.exp6(pin.Motion(e))
        return model

    def row_terms(self, q_full: np.ndarray, wrench: np.ndarray | None) -> RowTerms:
        """A row's commanded configuration and applied wrench (``None``: gravity alone)."""
        return RowTerms(np.asarray(q_full, dtype=float),
                        None if wrench is None or self.loads is None else np.asarray(wrench))

    def torques(self, model: pin.Model, data: pin.Data, q: np.ndarray,
                wrench: np.ndarray | None) -> Torques:
        """Gravity's and the wrench's generalised forces at ``q`` for ``model``."""
        gravity = -pin.computeGeneralizedGravity(model, data, q).copy()
        applied = np.zeros(model.nv)
        if wrench is not None and self.loads is not None:
            pin.computeJointJacobians(model, data, q)
            pin.updateFramePlacements(model, data)
            applied = pin.getFrameJacobian(model, data, self._frame_id(self.loads.frame),
                                           pin.LOCAL_WORLD_ALIGNED).T @ wrench
        lumped = np.zeros((model.nv, 0))
        if "gravity_lumped" in self.families:
            regressor = pin.computeJointTorqueRegressor(model, data, q, np.zeros(model.nv),
                                                        np.zeros(model.nv))
            lumped = self._lumped_columns(regressor, self.compliant_v)
        return Torques(gravity, applied, lumped)

    def deflection(self, x: np.ndarray, torques: Torques) -> np.ndarray:
        """Joint deflection ``Delta q`` (nv,) under ``torques`` for parameters ``x``.

        The compliance multiplies the applied wrench's torque, and gravity's too unless the
        gravity part is lumped (``gravity_lumped``: masses unknown).
        """
        dq = np.zeros(self.robot.model.nv)
        sl = self.slices()
        v_index = self.compliant_v
        if "joint_compliance" in sl:
            torque = torques.wrench + (0.0 if "gravity_lumped" in sl else torques.gravity)
            dq[v_index] += x[sl["joint_compliance"]] * torque[v_index]
        if "gravity_lumped" in sl:
            dq += torques.lumped @ x[sl["gravity_lumped"]]
        return dq

    @property
    def elastic(self) -> bool:
        """Whether the model has a compliance family (the arm sags)."""
        return bool({"joint_compliance", "gravity_lumped"} & set(self.families))

    def loaded_configuration(self, model: pin.Model, data: pin.Data, x: np.ndarray,
                             row: RowTerms) -> tuple[np.ndarray, Torques | None]:
        """The configuration the links are at, and the torques there.

        ``q = q_c + delta_0 + Delta q`` with ``Delta q = C tau(q)`` solved by fixed-point
        iteration (to :data:`SAG_TOLERANCE`; it contracts by about ``|C dtau/dq|``, 1e-3 for
        real arms).
        """
        offsets = np.zeros(model.nv)
        sl = self.slices().get("joint_offsets")
        if sl is not None:
            offsets[self.joints_v] = x[sl]
        if not self.elastic:
            return pin.integrate(model, row.q_full, offsets), None
        sag = np.zeros(model.nv)
        for _ in range(SAG_ITERATIONS):
            q = pin.integrate(model, row.q_full, offsets + sag)
            torques = self.torques(model, data, q, row.wrench)
            new = self.deflection(x, torques)
            converged = np.max(np.abs(new - sag)) <= SAG_TOLERANCE
            sag = new
            if converged:
                return pin.integrate(model, row.q_full, offsets + sag), torques
        raise ConvergenceError("the sag of the fitted compliance does not converge: the "
                               "compliance is too large for the arm's weight; check the "
                               "campaign's units and masses")

    def _lumped_columns(self, regressor: np.ndarray, v_index: list[int]) -> np.ndarray:
        """d(Delta q)/d theta (nv, n_theta): minus the regressor entries of each pair."""
        nv = self.robot.model.nv
        cols = []
        for j, vj in zip(self.compliant, v_index, strict=True):
            for k in self._downstream(j):
                for p in range(len(_GRAVITY_PARAMETERS)):
                    col = np.zeros(nv)
                    col[vj] = -regressor[vj, 10 * (k - 1) + p]
                    cols.append(col)
        return np.array(cols).T if cols else np.zeros((nv, 0))

    def evaluate(self, x: np.ndarray, rows: list[RowTerms], jacobian: bool = True
                 ) -> tuple[np.ndarray, np.ndarray | None]:
        """Predicted positions (n, M, 3) in the measuring frame (m) and their Jacobian.

        The Jacobian (n, M, 3, p) is d y / d x with the torques at the loaded configuration
        held fixed (exact at zero compliance; module docstring).
        """
        x = np.asarray(x, dtype=float)
        model = self.perturbed_model(x)
        data = model.createData()
        sl = self.slices()
        rot_w, d_omega = self._measuring_rotation(x)
        n, m = len(rows), len(self.markers)
        y = np.empty((n, m, 3))
        jac = np.zeros((n, m, 3, self.size)) if jacobian else None
        jr = self._right_jacobians(x) if jacobian and "geometry" in sl else None
        for i, row in enumerate(rows):
            q, torques = self.loaded_configuration(model, data, x, row)
            pin.forwardKinematics(model, data, q)
            pin.updateFramePlacements(model, data)
            if jacobian:
                pin.computeJointJacobians(model, data, q)
            placement_frames = None if jr is None else self._placement_frames(model, data, jr)
            for k, fid in enumerate(self.frame_ids):
                placement = data.oMf[fid]
                offset = self.marker_offset(x, k)
                point = placement.act(offset)
                world = self.rotation0 @ point
                y[i, k] = rot_w @ world + self.translation0 + self._translation(x)
                if jac is not None:
                    jac[i, k] = self._columns(sl, model, data, torques, placement_frames, fid,
                                              point, world, k, rot_w, d_omega)
        return y, jac

    def _measuring_rotation(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """exp(omega) and d(exp(omega) v)/d omega = -exp(omega) [v]x Jr(omega) (without v)."""
        sl = self.slices().get("frame")
        omega = x[sl][3:] if sl is not None else np.zeros(3)
        return pin.exp3(omega), pin.Jexp3(omega)

    def _translation(self, x: np.ndarray) -> np.ndarray:
        sl = self.slices().get("frame")
        return x[sl][:3] if sl is not None else np.zeros(3)

    def marker_offset(self, x: np.ndarray, k: int) -> np.ndarray:
        """Offset (3,) of marker ``k`` in its frame's axes (m) for parameters ``x``."""
        sl = self.slices().get("markers")
        extra = x[sl][3 * k: 3 * k + 3] if sl is not None else np.zeros(3)
        return np.asarray(self.markers[k].offset, dtype=float) + extra

    def measuring_placement(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(R, t) with ``y = R p + t`` for a robot-world point ``p``, parameters ``x``."""
        rot, _ = self._measuring_rotation(x)
        return rot @ self.rotation0, self.translation0 + self._translation(x)

    def _columns(self, sl: dict[str, slice], model: pin.Model, data: pin.Data,
                 torques: Torques | None,
                 placement_frames: tuple[np.ndarray, np.ndarray, np.ndarray] | None, fid: int,
                 point: np.ndarray, world: np.ndarray, k: int, rot_w: np.ndarray,
                 d_omega: np.ndarray) -> np.ndarray:
        """d y / d x (3, p) of one marker on one row.

        The torques at the loaded configuration are held fixed (their change with the
        parameters, relative size ``|C dtau/dq|``, is left out of the derivative; the
        prediction itself is the converged fixed point).
        """
        cols = np.zeros((3, self.size))
        to_measuring = rot_w @ self.rotation0
        if "frame" in sl:
            start = sl["frame"].start
            cols[:, start:start + 3] = np.eye(3)
            cols[:, start + 3:start + 6] = -rot_w @ _skew(world) @ d_omega
        if "markers" in sl:
            start = sl["markers"].start + 3 * k
            cols[:, start:start + 3] = to_measuring @ data.oMf[fid].rotation
        j_point = self._point_jacobian(model, data, fid, point)
        if "joint_offsets" in sl:
            cols[:, sl["joint_offsets"]] = to_measuring @ j_point[:, self.joints_v]
        if torques is not None and "joint_compliance" in sl:
            torque = torques.wrench + (0.0 if "gravity_lumped" in sl else torques.gravity)
            v_index = self.compliant_v
            cols[:, sl["joint_compliance"]] = to_measuring @ (j_point[:, v_index]
                                                              * torque[v_index])
        if torques is not None and "gravity_lumped" in sl:
            cols[:, sl["gravity_lumped"]] = to_measuring @ j_point @ torques.lumped
        if placement_frames is not None:
            cols[:, sl["geometry"]] = to_measuring @ self._geometry_columns(placement_frames, fid,
                                                                          point)
        return cols

    @staticmethod
    def _point_jacobian(model: pin.Model, data: pin.Data, fid: int, point: np.ndarray
                        ) -> np.ndarray:
        """d point / d v (3, nv), world axes, for a point fixed to frame ``fid``."""
        jac = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
        lever = point - data.oMf[fid].translation
        return jac[:3] - _skew(lever) @ jac[3:]

    def _placement_errors(self, x: np.ndarray, sl: slice) -> np.ndarray:
        """(n_joints, 6) placement errors from the geometry part of ``x``."""
        eps = np.zeros((len(self.joints), 6))
        rows, cols = zip(*self.geometry, strict=True) if self.geometry else ((), ())
        eps[list(rows), list(cols)] = x[sl]
        return eps

    def _right_jacobians(self, x: np.ndarray) -> np.ndarray:
        """(n_joints, 6, 6) right Jacobians of ``exp`` at each joint's placement error."""
        eps = self._placement_errors(x, self.slices()["geometry"])
        return np.array([pin.Jexp6(pin.Motion(e)) for e in eps])

    def _placement_frames(self, model: pin.Model, data: pin.Data, jr: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per joint, ``a = oMi[parent] M_j exp(eps_j)``: ``R_a Jr[:3]``, ``R_a Jr[3:]`` (3, 6)
        each and the origin of ``a`` (3,), stacked over the joints."""
        frames = [data.oMi[model.parents[j]] * model.jointPlacements[j] for j in self.joints]
        rot = np.array([f.rotation for f in frames])
        origin = np.array([f.translation for f in frames])
        return (np.einsum("jab,jbc->jac", rot, jr[:, :3, :]),
                np.einsum("jab,jbc->jac", rot, jr[:, 3:, :]), origin)

    def _geometry_columns(self, placement: tuple[np.ndarray, np.ndarray, np.ndarray],
                          fid: int, point: np.ndarray) -> np.ndarray:
        """d point / d epsilon (3, n_geometry): ``M_j exp(eps)`` perturbed on the right.

        With ``a = oMi[parent] M_j exp(eps)``: ``d point = R_a (d v + d w x r)`` for a twist
        ``(d v, d w) = Jr(eps) d eps`` and ``r`` the point in frame ``a``, i.e.
        ``R_a Jr[:3] - [point - o_a]x R_a Jr[3:]``; zero for joints the point does not move with.
        """
        linear, angular, origin = placement
        lx, ly, lz = (point[None, :] - origin).T[:, :, None]
        ax, ay, az = angular[:, 0], angular[:, 1], angular[:, 2]
        cols = linear - np.stack([ly * az - lz * ay, lz * ax - lx * az, lx * ay - ly * ax], axis=1)
        cols = cols * self._moves[fid][:, None, None]
        rows, comps = self._geometry_index
        return cols[rows, :, comps].T

def one_dof_joints(model: pin.Model) -> list[int]:
    """Ids of the joints with one degree of freedom, in model order (those the geometry and
    zero-offset families perturb)."""
    return [j for j in range(1, model.njoints) if model.joints[j].nv == 1]


def _zero_component(shortname: str) -> int | None:
    """Component of a placement error that is the joint's own zero offset, if any."""
    kind = shortname.replace("JointModel", "")
    for prefix, base in (("RUB", 3), ("R", 3), ("P", 0)):
        if kind.startswith(prefix) and kind[len(prefix):] in ("X", "Y", "Z"):
            return base + "XYZ".index(kind[len(prefix):])
    return None


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def align_frames(world: np.ndarray, measured: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and translation taking ``world`` points onto ``measured`` (least squares).

    Kabsch/Horn on (N, 3) point pairs (rows with NaN ignored); needs three non-collinear points.
    """
    ok = np.all(np.isfinite(measured), axis=1) & np.all(np.isfinite(world), axis=1)
    a, b = world[ok], measured[ok]
    if len(a) < 3 or np.linalg.matrix_rank(a - a.mean(0), tol=1e-9) < 2:
        raise PoseModelError("the measured markers span fewer than three non-collinear points; "
                             "measure more varied poses")
    ca, cb = a.mean(0), b.mean(0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    rot = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return rot, cb - rot @ ca
