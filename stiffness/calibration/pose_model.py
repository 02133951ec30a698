"""Absolute marker positions predicted from commanded coordinates: geometry and elasticity.

A measuring system (laser tracker, motion capture) sees markers fixed to frames of the robot,
in its own frame, at commanded coordinates ``q``; the arm sags under its weight and any applied
wrench. The prediction of marker ``m`` on row ``i`` is

.. math::

    y_{im} = \\exp(\\omega) R_0 \\; {}^{0}M_{f_m}(q_i + \\delta_0 + \\Delta q_i;\\ \\varepsilon)
             \\,(o_m + \\delta o_m) + t_0 + t,

with the parameter families of :data:`stiffness.elastic.effects.FAMILIES`:

``frame``
    the measuring frame's placement relative to its starting estimate ``R_0, t_0``: ``t`` (m,
    measuring-frame axes) and ``omega`` (rad, a rotation vector applied on the left);
``markers``
    each marker's offset correction ``delta o_m`` (m, in its frame's axes) and, for a marker
    whose orientation the campaign measures, its mounting turn ``delta_m`` (rad, its own axes:
    its axes ``R_f M_m exp(delta_m)``), which acts on orientations alone
    (:mod:`stiffness.calibration.pose_orientation`);
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
    configuration ``q`` itself (the sag's fixed point, :meth:`PoseModel._loaded_rows`).
    Springs on a ``[controller]``'s coordinates ``u`` (``q_chain = A u + b``,
    ``springs_on = "controller"``) act there: ``Delta u = C_u A^T tau``,
    ``Delta q = A Delta u``; in general ``Delta q = S C S^T tau`` with ``S``
    (:attr:`PoseModel.spring_map`) the joint rates per unit rate of each spring's coordinate;
``gravity_lumped``
    masses unknown: ``Delta q_j = - sum_k theta_jk Y_jk(q)``, with ``Y`` the gravity regressor
    (Pinocchio's joint-torque regressor at rest, at the loaded configuration) and
    ``theta_jk = c_j pi_k`` lumped; only the combinations the data determine are fitted.

On a robot with closed loops the commanded coordinates are the independent ones, every
configuration is the loops' closure over their passive joints, the springs carry the torque
the independent coordinates feel, ``T(q)^T tau`` with ``T = dq/du`` the loop's tangent map,
and the point Jacobians are ``J_p T`` (:mod:`stiffness.calibration.pose_loops`).

Every column of the Jacobian is analytic (Pinocchio's frame Jacobians, the right Jacobians of
``exp`` on SO(3) and SE(3)); finite differences check it in the tests. The derivative holds
the torques at the loaded configuration fixed (the sag's own change with the parameters is left
out): exact at zero compliance, and off by the relative size of ``C dtau/dq`` (about 1e-3 on
real arms) elsewhere, which shapes the solver's path, not the converged prediction. SI units
throughout.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

from stiffness.batch.poses import (
    frame_jacobians,
    frame_placements,
    generalized_gravity,
    integrate,
    joint_kinds,
    joint_placements,
    point_jacobians,
    support_masks,
)
from stiffness.calibration.pose_loops import PoseLoops, projected
from stiffness.calibration.pose_sag import sag_jump
from stiffness.elastic.effects import FAMILIES
from stiffness.elastic.effects.base_tilt import declared_tilt, tilted_gravity
from stiffness.elastic.effects.kinematic_errors import MeasuringFrame
from stiffness.elastic.effects.pose_face import (
    FamilyParameter,
    MarkerView,
    PoseFamily,
    RowTerms,
    SagState,
)
from stiffness.errors import ConvergenceError, StiffnessError
from stiffness.robot.kinematics import frame_id
from stiffness.robot.robot import Robot
from stiffness.units import Units

#: Tolerance (rad or m) and iteration cap of the sag's fixed point.
SAG_TOLERANCE = 1e-13
SAG_ITERATIONS = 50
#: Rows a model of row-at-once families evaluates together (bounds the arrays a large
#: campaign's evaluation holds besides its Jacobian).
ROW_BLOCK = 1024
SAG_DIVERGES = ("the sag of the fitted compliance does not converge: the compliance is too "
                "large for the arm's weight; check the campaign's units and masses")
SAG_BUCKLES = ("the sag of the fitted compliance has no stable equilibrium: the load is beyond "
               "the arm's buckling load; check the campaign's units, masses and loads")
#: Step (rad or m) of the central differences of a sag pass (:meth:`PoseModel._newton_step`).
SAG_DIFFERENCE = 1e-6


class PoseModelError(StiffnessError):
    """A robot or marker set that absolute-pose calibration cannot model."""


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
    rotation
        The marker's own axes in the frame's axes (3, 3): a 6-D probe's mounting, its
        measured orientation that of the frame turned by it; the identity (default) for a
        probe whose axes are the frame's. Declared: the ``markers`` family fits a turn
        ``delta`` about it (``rotation exp(delta)``) where the marker is ``oriented``.
    oriented
        Whether the campaign measures the marker's orientation (set by
        :class:`~stiffness.calibration.pose_campaign.PoseCampaign`): the ``markers`` family
        then fits its mounting turn too.
    """

    name: str
    frame: str
    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    oriented: bool = False


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

    @classmethod
    def read(cls, frame: str, force: np.ndarray, moment: np.ndarray | None, units: Units
             ) -> Loads:
        """The loads of a campaign's forces (n, 3) and moments (n, 3, or ``None``: zero) in
        the files' ``units``."""
        wrench = np.zeros((len(force), 6))
        wrench[:, :3] = force * units.force_to_si
        if moment is not None:
            wrench[:, 3:] = moment * units.moment_to_si
        return cls(frame, wrench)


class PoseModel:
    """Predicted absolute marker positions and their analytic Jacobian.

    Parameters
    ----------
    robot
        A robot with the inertias gravity needs (with closed loops:
        :mod:`stiffness.calibration.pose_loops`).
    markers
        The markers the measuring system sees.
    families
        Which parameter families are in the parameter vector (names in
        :data:`~stiffness.elastic.effects.FAMILIES`).
    loads
        Applied wrenches per row, or ``None`` (gravity alone).
    frame0
        Starting estimate of the measuring frame: (R_0 (3, 3), t_0 (3,)) mapping robot world
        coordinates to the measuring system's.
    settings
        Fixed settings of the families, SI (their keys are documented by the families that
        read them), kept in the model file.
    """

    def __init__(self, robot: Robot, markers: list[Marker], families: tuple[str, ...],
                 frame0: tuple[np.ndarray, np.ndarray], loads: Loads | None = None,
                 settings: dict | None = None) -> None:
        unknown = [f for f in families if f not in FAMILIES]
        if unknown:
            raise PoseModelError(f"unknown parameter families {unknown}; valid: "
                                 f"{', '.join(FAMILIES)}")
        #: the loops' closure and tangent map (``None``: an open chain)
        self.loops = None if robot.loop.is_open_chain else PoseLoops(robot)
        self.robot = robot
        self.markers = markers
        self.settings = dict(settings or {})
        self.family_objects: list[PoseFamily] = [cls() for name, cls in FAMILIES.items()
                                                 if name in families]
        self.families = tuple(f.name for f in self.family_objects)
        _check_combination(self.family_objects)
        self.rotation0, self.translation0 = (np.asarray(frame0[0], float),
                                             np.asarray(frame0[1], float))
        self.loads = loads
        model = robot.model
        self._frame_ids_by_name: dict[str, int] = {}
        self.frame_ids = [self._frame_id(m.frame) for m in markers]
        self.joints = pose_joints(robot)
        self.springs = tuple(robot.compliant_joints)
        self.spring_map = robot.rate_projection(self.springs)
        self._spring_links = [self._links_moved_by(c) for c in range(len(self.springs))]
        # the compliant chain joints: none when the springs act on controller coordinates
        self.compliant = ([] if robot.springs_on_controller else
                          [int(model.getJointId(n)) for n in self.springs])
        self.loop_path = frozenset() if self.loops is None else self.loops.path_joints
        self.geometry = [(n, c) for n, j in enumerate(self.joints) for c in range(6)
                         if j not in self.loop_path  # none that closes a loop
                         and c != _zero_component(model.joints[j].shortname())]
        self.geometry_index = (np.array([n for n, _ in self.geometry], dtype=int),
                               np.array([c for _, c in self.geometry], dtype=int))
        self.joints_v = [model.joints[j].idx_v for j in self.joints]
        self.compliant_v = [model.joints[j].idx_v for j in self.compliant]
        self.moves = {fid: np.array([j in set(model.supports[model.frames[fid].parentJoint])
                                     for j in self.joints], dtype=float)
                      for fid in set(self.frame_ids)}
        # each row's last converged sag, with the row itself (kept alive, so that its id is
        # never reused by another row: the starts, and so the results, are deterministic)
        self._sag_start: dict[int, tuple[RowTerms, np.ndarray]] = {}
        # what families derive from the layout alone, computed at their first evaluation
        self.layout_cache: dict[str, Any] = {}
        self._lumped = any(f.lumps_gravity for f in self.family_objects)
        self._elastic = any(f.family_kind == "elastic" for f in self.family_objects)
        # the perturbed copies of the model differ in placements and gravity only
        self._kinds = joint_kinds(model)
        self._frame_masks = support_masks(model, self.frame_ids)  # the same in perturbed copies
        # the families that implement each per-row hook (the others would add nothing)
        self._hooked = {hook: [f for f in self.family_objects
                               if getattr(type(f), hook) is not getattr(PoseFamily, hook)]
                        for hook in ("configuration_offset", "at_configuration", "joint_torque",
                                     "joint_deflection", "deflection_per_torque",
                                     "marker_displacement")}
        self.parameters: list[FamilyParameter] = []
        self._slices: dict[str, slice] = {}
        for fam in self.family_objects:
            own = fam.family_parameters(self)
            self._slices[fam.name] = slice(len(self.parameters), len(self.parameters) + len(own))
            self.parameters += own

    # ------------------------------------------------------------------ layout

    def _frame_id(self, name: str) -> int:
        known = self._frame_ids_by_name
        if name in known:  # looked up at each sag iteration (the load's frame): a frame scan
            return known[name]
        model = self.robot.model
        if not model.existFrame(name):
            raise PoseModelError(f"marker frame {name!r} is not a frame of {self.robot.title}; "
                                 "name one of its frames in [markers]")
        known[name] = int(frame_id(model, name))
        return known[name]

    def frame_id(self, name: str) -> int:
        """Id of a robot frame by name (a typed error naming it when it is missing)."""
        return self._frame_id(name)

    def joint_unit(self, joint: int, revolute: str, prismatic: str) -> str:
        """``prismatic`` for a prismatic joint, else ``revolute``."""
        return prismatic if self.robot.is_prismatic(self.robot.model.names[joint]) else revolute

    def downstream(self, joint: int) -> list[int]:
        """Joints whose links move with ``joint`` (its subtree, itself included)."""
        return [int(k) for k in self.robot.model.subtrees[joint]]

    def spring_downstream(self, spring: int) -> list[int]:
        """Joints whose links move with spring ``spring``'s coordinate (the subtrees of the
        joints it drives, in model order)."""
        return self._spring_links[spring]

    def _links_moved_by(self, spring: int) -> list[int]:
        """The joints whose links move with spring ``spring``'s coordinate: downstream of the
        joints it drives, a loop's passive joints it moves included (their rates per unit rate
        at the reference assembly)."""
        model = self.robot.model
        rates = self.spring_map[:, spring]
        if self.loops is not None:
            q = self.robot.assemble(None).q[None]
            rates = self.loops.tangent(model, model.createData(), q)[0] @ rates
        driven = [j for j in range(1, model.njoints) if model.joints[j].nv == 1
                  and abs(rates[model.joints[j].idx_v]) > 1e-12]
        return sorted({k for j in driven for k in self.downstream(j)})

    def loop_tangent(self, model: pin.Model, data: pin.Data, q: np.ndarray
                     ) -> np.ndarray | None:
        """(n, nv, nv) ``T = dq/du`` at the closed configurations ``q`` (n, nq) of a robot
        with closed loops (:meth:`PoseLoops.tangent`), ``None`` for an open chain."""
        return None if self.loops is None else self.loops.tangent(model, data, q)

    @property
    def size(self) -> int:
        """Number of parameters."""
        return len(self.parameters)

    def slices(self) -> dict[str, slice]:
        """Columns of each family."""
        return self._slices

    def part(self, x: np.ndarray, family: str) -> np.ndarray | None:
        """The parameters of ``family`` in ``x``, or ``None`` when the model lacks it."""
        sl = self._slices.get(family)
        return None if sl is None else x[sl]

    # ------------------------------------------------------------------ evaluation

    def perturbed_model(self, x: np.ndarray) -> pin.Model:
        """The robot's Pinocchio model with the geometric part of ``x`` applied."""
        model = pin.Model(self.robot.model)
        tilt = declared_tilt(self.settings)
        if tilt.any():  # a declared base tilt turns gravity for every family
            model.gravity = pin.Motion(tilted_gravity(model.gravity.linear, tilt)[0],
                                       np.zeros(3))
        for fam in self.family_objects:
            fam.perturb_model(self, x[self._slices[fam.name]], model)
        return model

    def row_terms(self, q_full: np.ndarray, wrench: np.ndarray | None) -> RowTerms:
        """A row's commanded configuration and applied wrench (``None``: gravity alone)."""
        return RowTerms(np.asarray(q_full, dtype=float),
                        None if wrench is None or self.loads is None else np.asarray(wrench))

    def _state(self, x: np.ndarray, q: np.ndarray, gravity: np.ndarray, applied: np.ndarray,
               extras: dict) -> SagState:
        """The sag's state from gravity's and the wrench's torques (one row: (nv,) each; a
        batch of rows: (n, nv)): the torque the springs carry, with the families' own."""
        state = SagState(q, gravity, applied, applied + (0.0 if self._lumped else gravity),
                         np.zeros(gravity.shape), extras)
        for fam in self._hooked["joint_torque"]:
            extra = fam.joint_torque(self, x[self._slices[fam.name]], state)
            if extra is not None:
                state.torque = state.torque + extra
        return state

    def deflection_slope(self, x: np.ndarray, state: SagState) -> np.ndarray:
        """d(Delta q)/d(torque) (nv,) at ``state``: the sum of the families' (the columns of
        a family that adds a torque need it)."""
        return self._summed("deflection_per_torque", state.torque.shape, x, state)

    def _summed(self, hook: str, shape: tuple[int, ...], x: np.ndarray | dict[str, np.ndarray],
                *args) -> np.ndarray:
        """The sum of the families' ``hook`` (each given its parameters: its slice of ``x``, or
        ``x[name]`` of a dict, then ``args``), zeros of ``shape`` where none contributes."""
        out = np.zeros(shape)
        for fam in self._hooked[hook]:
            own = x[fam.name] if isinstance(x, dict) else x[self._slices[fam.name]]
            part = getattr(fam, hook)(self, own, *args)
            if part is not None:
                out += part
        return out

    def _load_torques(self, model: pin.Model, data: pin.Data, q: np.ndarray,
                      wrench: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """Gravity's ``-g(q)`` and the applied wrench's ``J_load(q)^T w`` (nv,) each."""
        gravity = -pin.computeGeneralizedGravity(model, data, q).copy()
        applied = np.zeros(model.nv)
        if wrench is not None and self.loads is not None:
            pin.computeJointJacobians(model, data, q)
            pin.updateFramePlacements(model, data)
            applied = pin.getFrameJacobian(model, data, self._frame_id(self.loads.frame),
                                           pin.LOCAL_WORLD_ALIGNED).T @ wrench
        return gravity, applied

    def campaign_settings(self, rows: list[RowTerms]) -> dict:
        """The families' fixed settings from a campaign's ``rows`` (every family of
        :data:`~stiffness.elastic.effects.FAMILIES`, whether in this model or not),
        from the torques the joints carry at the commanded poses under the nominal robot
        (gravity with its inertias, and the applied wrench)."""
        torques = self.nominal_torques(rows)
        out: dict = {}
        for cls in FAMILIES.values():
            out.update(cls.campaign_settings(torques, self))
        return out

    def nominal_torques(self, rows: list[RowTerms], wrench: bool = True) -> np.ndarray:
        """(rows, nv) the torques (N.m, N) the joints carry at the commanded poses of ``rows``
        under the nominal robot (gravity with its inertias, and the applied wrench unless
        ``wrench`` is false)."""
        model = self.robot.model
        data = model.createData()
        torques = np.array([sum(self._load_torques(model, data, row.q_full,
                                                   row.wrench if wrench else None))
                            for row in rows]).reshape(len(rows), model.nv)
        if self.loops is None:
            return torques
        q = np.array([row.q_full for row in rows]).reshape(len(rows), model.nq)
        return projected(self.loops.tangent(model, data, q), torques)

    def deflection(self, x: np.ndarray, state: SagState) -> np.ndarray:
        """Joint deflection ``Delta q`` (nv,) at ``state`` for parameters ``x``: the sum of the
        elastic families' parts."""
        return self._summed("joint_deflection", state.torque.shape, x, state)

    @property
    def elastic(self) -> bool:
        """Whether the model has an elastic family (the arm sags)."""
        return self._elastic

    def _offsets(self, x: np.ndarray) -> np.ndarray:
        """The families' shift (nv,) of every commanded configuration (the zero offsets)."""
        return self._summed("configuration_offset", (self.robot.model.nv,), x)

    def evaluate(self, x: np.ndarray, rows: list[RowTerms], jacobian: bool = True
                 ) -> tuple[np.ndarray, np.ndarray | None]:
        """Predicted positions (n, M, 3) in the measuring frame (m) and their Jacobian.

        The Jacobian (n, M, 3, p) is d y / d x with the torques at the loaded configuration
        held fixed (exact at zero compliance; module docstring). Blocks of :data:`ROW_BLOCK`
        rows are evaluated as arrays (Pinocchio in a tight loop, :mod:`stiffness.batch.poses`).
        """
        x = np.asarray(x, dtype=float)
        model = self.perturbed_model(x)
        parts = {f.name: x[self._slices[f.name]] for f in self.family_objects}
        rot_w, d_omega = MeasuringFrame.frame_rotation(self.part(x, "frame"))
        shift = MeasuringFrame.frame_translation(self.part(x, "frame"))
        ev = _Evaluation(model, model.createData(), x, parts, rot_w, d_omega,
                         rot_w @ self.rotation0, self.translation0 + shift, jacobian)
        n, m = len(rows), len(self.markers)
        y = np.empty((n, m, 3))
        jac = np.zeros((n, m, 3, self.size)) if jacobian else None
        for s in range(0, n, ROW_BLOCK):
            self._evaluate_block(ev, rows[s:s + ROW_BLOCK], y[s:s + ROW_BLOCK],
                                 None if jac is None else jac[s:s + ROW_BLOCK])
        return y, jac

    def _evaluate_block(self, ev: _Evaluation, rows: list[RowTerms], y: np.ndarray,
                        jac: np.ndarray | None) -> None:
        """A block of rows of :meth:`evaluate` at once into ``y`` (n, M, 3) and ``jac``
        (n, M, 3, p): the families' hooks on arrays with leading (row, marker) axes."""
        model, x, parts = ev.model, ev.x, ev.parts
        q, state, tangent = self._loaded_rows(model, ev.data, x, rows)
        if ev.jacobian and state is not None:
            state.per_torque = self.deflection_slope(x, state)
        kin = joint_placements(model, ev.data, q, ev.jacobian, self._kinds)
        rotation, translation = frame_placements(model, kin, self.frame_ids)
        offsets = np.array([self.marker_offset(x, k) for k in range(len(self.markers))])
        point = np.einsum("nkab,kb->nka", rotation, offsets) + translation
        j_point = (point_jacobians(model, kin, self.frame_ids, point, self._frame_masks)
                   if ev.jacobian else np.zeros(point.shape + (0,)))
        if ev.jacobian and tangent is not None:  # per independent rate: J_p T
            j_point = j_point @ tangent[:, None]
        caches = {f.name: f.rows_cache(self, parts[f.name], model, kin, rows, ev.jacobian)
                  for f in self.family_objects}
        view = MarkerView(model, ev.data, point, np.zeros(3), ev.to_measuring,
                          ev.rot_w, ev.d_omega, j_point, state, caches, rotation,
                          np.array([self.moves[f] for f in self.frame_ids]),
                          np.eye(len(self.markers)), tangent)
        bent = point + self._displacement(parts, view)
        view.world = bent @ self.rotation0.T
        y[:] = view.world @ ev.rot_w.T + ev.translation
        if jac is not None:
            for fam in self.family_objects:
                jac[..., self._slices[fam.name]] = fam.columns(self, parts[fam.name], view)

    def _loaded_rows(self, model: pin.Model, data: pin.Data, x: np.ndarray,
                     rows: list[RowTerms]
                     ) -> tuple[np.ndarray, SagState | None, np.ndarray | None]:
        """The configurations the links are at, (n, nq), the sag's state there, with
        (n, 1, nv) arrays, and the loops' tangent maps there (:meth:`_configurations`):
        ``q = q_c + delta_0 + Delta q`` with ``Delta q = C tau(q)`` solved by fixed-point
        iteration (to :data:`SAG_TOLERANCE`; it contracts by about
        ``|C dtau/dq|``, 1e-3 for real arms), each row until its own sag converges, started
        from the row's last converged sag (an optimiser's next trial differs little from its
        last), and from zero if that does not converge. A row whose passes contract at a
        steady ratio (a slow mode: a steep lost motion, a lumped weight) jumps to the limit
        they approach (:func:`~stiffness.calibration.pose_sag.sag_jump`) and iterates on from
        there; the verdict stays the plain passes': an attempt fails where they would need
        more than :data:`SAG_ITERATIONS`. A row whose plain step does not shrink (a load that
        stiffens the arm strongly: an eigenvalue of ``C K_C`` below -1, the passes oscillate
        and grow though ``K - K_C`` is positive definite) takes Newton's steps from where its
        attempt started (:meth:`_newton_step`; from the diverged passes they can reach
        another equilibrium), each after a pass that judges convergence as before; an
        equilibrium they reach that is unstable is refused (:data:`SAG_BUCKLES`)."""
        commanded = np.array([row.q_full for row in rows]).reshape(len(rows), model.nq)
        offsets = self._offsets(x)
        if not self.elastic:
            q, tangent = self._configurations(model, data, commanded, offsets)
            return q, None, tangent
        sag, closed, state, _ = self._sag(model, data, x, rows, commanded, offsets)
        q, tangent = self._configurations(model, data, commanded, offsets + sag, closed)
        return q, state, tangent

    def loaded_state(self, x: np.ndarray, rows: list[RowTerms]
                     ) -> tuple[SagState, np.ndarray]:
        """The sag of ``rows`` for parameters ``x`` (an elastic model's) without the closure
        :meth:`_loaded_rows` ends with: the sag's state at the configurations of its last pass
        (``q`` (n, nq), closed on a robot with loops; the torques (n, 1, nv) there) and that
        pass's step (n, nv; on the independent coordinates, at most :data:`SAG_TOLERANCE`),
        which takes them to the converged sag.

        Raises
        ------
        StiffnessError
            If the model has no elastic family.
        ConvergenceError
            If the sag does not converge.
        """
        if not self.elastic:
            raise StiffnessError("a model without an elastic family does not sag: add "
                                 "joint_compliance to its families")
        x = np.asarray(x, dtype=float)
        model = self.perturbed_model(x)
        commanded = np.array([row.q_full for row in rows]).reshape(len(rows), model.nq)
        _, _, state, step = self._sag(model, model.createData(), x, rows, commanded,
                                      self._offsets(x))
        return state, step

    def _sag(self, model: pin.Model, data: pin.Data, x: np.ndarray, rows: list[RowTerms],
             commanded: np.ndarray, offsets: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, SagState, np.ndarray]:
        """The sag's fixed point of :meth:`_loaded_rows` from the ``commanded`` (n, nq)
        configurations moved by the zero ``offsets`` (nv,): the sag (n, nv), each row's last
        closure (n, nq: the commanded configurations on an open chain), the sag's state at
        the configurations of its last pass and that pass's step (n, nv: the sag minus the
        sag of those configurations, at most :data:`SAG_TOLERANCE`)."""
        n, nv = len(rows), model.nv
        wrench = (None if self.loads is None or all(r.wrench is None for r in rows) else
                  np.array([np.zeros(6) if r.wrench is None else r.wrench for r in rows]))
        sag, warm = np.zeros((n, nv)), np.zeros(n, dtype=bool)
        for i, row in enumerate(rows):
            last = self._sag_start.get(id(row))
            if last is not None and last[0] is row:
                sag[i], warm[i] = last[1], True
        at, gravity, applied = np.empty((n, model.nq)), np.empty((n, nv)), np.empty((n, nv))
        final_step = np.empty((n, nv))
        kept: dict[str, np.ndarray] = {}  # the families' extras at ``at``, as computed there
        pending = np.arange(n)
        closed = commanded.copy()  # each row's last closure, whose passive joints seed its next
        for attempt in range(2):  # from the last converged sag, then from zero
            trail = np.zeros((3, n, nv))  # each row's steps of the last three passes
            start = np.zeros(n, dtype=int)  # the pass its plain steps start at (its jump)
            before = np.full(n, np.inf)  # each row's last step (its largest component)
            origin = sag.copy()  # where the attempt starts
            newton = np.full(n, np.inf)  # lowest eigenvalue of a Newton row's last I - dPhi/ds
            failed = np.zeros(0, dtype=int)
            for k in range(SAG_ITERATIONS):
                if not pending.size:
                    break
                q, g, w, extras, new = self._pass(model, data, x, commanded[pending],
                                                  offsets, sag[pending], closed[pending],
                                                  None if wrench is None else wrench[pending])
                closed[pending] = q
                step = new - sag[pending]
                trail[k % 3, pending] = step
                size = np.max(np.abs(step), axis=1)
                done = size <= SAG_TOLERANCE
                # a plain pass that does not shrink the step: Newton's steps from there on
                grows = (k - start[pending] >= 1) & (size >= before[pending]) & ~done
                before[pending] = size
                sag[pending] = new
                steps = np.isfinite(newton[pending]) & ~done
                if steps.any():
                    at_k = pending[steps]
                    sag[at_k], newton[at_k] = self._newton_step(
                        model, data, x, commanded[at_k], offsets, new[steps] - step[steps],
                        step[steps], closed[at_k], None if wrench is None else wrench[at_k])
                if grows.any():  # Newton's steps from the attempt's start (not from afar)
                    back = pending[grows]
                    sag[back], closed[back], newton[back] = origin[back], commanded[back], 1.0
                    start[back] = SAG_ITERATIONS  # no jump, no plain step to compare
                if done.any():
                    finished = pending[done]
                    if np.any(newton[finished] <= 0.0):  # an unstable equilibrium
                        raise ConvergenceError(SAG_BUCKLES)
                    at[finished], gravity[finished], applied[finished] = q[done], g[done], w[done]
                    final_step[finished] = step[done]
                    for f, e in extras.items():
                        kept.setdefault(f, np.empty((n,) + e.shape[1:]))[finished] = e[done]
                    pending, size = pending[~done], size[~done]  # pending only shrinks
                ready = k - start[pending] >= 2 if k >= 2 else None  # three plain steps
                if ready is not None and ready.any():
                    slow = pending[ready]
                    jump, hopeless = sag_jump(trail[:, slow][[k % 3, (k - 1) % 3, (k - 2) % 3]],
                                              size[ready], SAG_ITERATIONS - 1 - k, SAG_TOLERANCE)
                    sag[slow] += jump
                    start[slow[jump.any(axis=1)]] = k + 1
                    if hopeless.any():  # the plain passes would not converge in time
                        failed = np.concatenate([failed, slow[hopeless]])
                        if attempt or not warm[failed].all():
                            raise ConvergenceError(SAG_DIVERGES)
                        pending = pending[~np.isin(pending, failed)]
            pending = np.concatenate([failed, pending])
            if not pending.size or attempt or not warm[pending].all():
                break
            sag[pending], closed[pending] = 0.0, commanded[pending]
        if pending.size:
            raise ConvergenceError(SAG_DIVERGES)
        if self._lumped:  # gravity's torque, outside the sag, only where it converged
            gravity = -generalized_gravity(model, data, at)
        for i, row in enumerate(rows):
            self._sag_start[id(row)] = (row, sag[i])
        extras = {f: e[:, None] for f, e in kept.items()}
        state = self._state(x, at, gravity[:, None], applied[:, None], extras)
        return sag, closed, state, final_step

    def _pass(self, model: pin.Model, data: pin.Data, x: np.ndarray, commanded: np.ndarray,
              offsets: np.ndarray, sag: np.ndarray, closed: np.ndarray,
              wrench: np.ndarray | None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict, np.ndarray]:
        """One pass of the sag, ``Phi(s) = C tau(q_c + delta_0 + s)``, over rows: the
        configurations (n, nq; closed from the passive joints of ``closed``), gravity's and the
        wrench's torques there (n, nv each), the families' extras and the new sag (n, nv)."""
        q, tangent = self._configurations(model, data, commanded, offsets + sag, closed)
        g, w = self._row_torques(model, data, q, tangent, wrench, not self._lumped)
        extras = self._extras(model, data, q)
        return q, g, w, extras, self.deflection(x, self._state(x, q, g, w, extras))

    def _newton_step(self, model: pin.Model, data: pin.Data, x: np.ndarray,
                     commanded: np.ndarray, offsets: np.ndarray, sag: np.ndarray,
                     step: np.ndarray, closed: np.ndarray, wrench: np.ndarray | None
                     ) -> tuple[np.ndarray, np.ndarray]:
        """Newton's step on ``s - Phi(s) = 0`` for rows whose plain passes do not contract
        (an eigenvalue of ``C K_C`` below -1: a load that stiffens the arm strongly):
        ``s + (I - dPhi/ds)^-1 (Phi(s) - s)`` from the sags ``sag`` (p, nv) and their pass's
        ``step`` (p, nv) ``Phi(s) - s``, the tangent by central differences of the pass
        (:data:`SAG_DIFFERENCE`; every family and the loops' closures in it), and the lowest
        real part of the tangent's eigenvalues (p,): positive at a stable equilibrium (for
        linear springs, where ``K - K_C`` is positive definite)."""
        p, nv = sag.shape
        h = SAG_DIFFERENCE * np.eye(nv)
        moved = np.concatenate([sag[:, None] + h, sag[:, None] - h]).reshape(2 * p * nv, nv)
        new = self._pass(model, data, x, np.repeat(np.tile(commanded, (2, 1)), nv, axis=0),
                         offsets, moved, np.repeat(np.tile(closed, (2, 1)), nv, axis=0),
                         None if wrench is None else
                         np.repeat(np.tile(wrench, (2, 1)), nv, axis=0))[-1]
        plus, minus = new.reshape(2, p, nv, nv)
        tangent = np.eye(nv) - np.swapaxes(plus - minus, 1, 2) / (2.0 * SAG_DIFFERENCE)
        lowest = np.linalg.eigvals(tangent).real.min(axis=1)
        return sag + np.linalg.solve(tangent, step[..., None])[..., 0], lowest

    def _configurations(self, model: pin.Model, data: pin.Data, commanded: np.ndarray,
                        shift: np.ndarray, seed: np.ndarray | None = None
                        ) -> tuple[np.ndarray, np.ndarray | None]:
        """(n, nq) the ``commanded`` configurations moved by ``shift`` ((n, nv) or (nv,), on
        the independent coordinates) and, on a robot with closed loops, closed over the
        passive joints, with their (n, nv, nv) tangent maps ``T = dq/du``
        (:meth:`PoseLoops.close`, all rows at once; ``None`` for an open chain). The closure
        starts from the passive joints of ``seed`` (n, nq), closed configurations of the same
        rows a sag pass before (one Newton step fewer), else of the commanded assembly."""
        q = integrate(model, commanded, shift, self._kinds)
        if self.loops is None:
            return q, None
        if seed is not None:
            passive = self.loops.layout.passive_q
            q[:, passive] = seed[:, passive]
        return self.loops.close(model, data, q)

    def _extras(self, model: pin.Model, data: pin.Data, q: np.ndarray) -> dict:
        """The families' :meth:`~stiffness.elastic.effects.pose_face.PoseFamily.
        at_configuration` quantities at the (n, nq) configurations ``q`` (leading axis n)."""
        return {fam.name: fam.at_configuration(self, model, data, q)
                for fam in self._hooked["at_configuration"]}

    def _row_torques(self, model: pin.Model, data: pin.Data, q: np.ndarray,
                     tangent: np.ndarray | None, wrench: np.ndarray | None, gravity_too: bool
                     ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_load_torques` of (n, nq) configurations: (n, nv) each (gravity's zero
        unless ``gravity_too``: a lumped weight's sag does not read it, 10 % of its
        iterations' time); on a robot with closed loops, those the independent coordinates
        feel through the loops' tangent maps ``tangent`` (n, nv, nv) at ``q``."""
        gravity = (-generalized_gravity(model, data, q) if gravity_too
                   else np.zeros((q.shape[0], model.nv)))
        applied = np.zeros(gravity.shape)
        if wrench is not None and self.loads is not None:
            jac = frame_jacobians(model, data, q, self._frame_id(self.loads.frame))
            applied = np.einsum("nkv,nk->nv", jac, wrench)
        if tangent is None:
            return gravity, applied
        return projected(tangent, gravity), projected(tangent, applied)

    def _displacement(self, parts: dict[str, np.ndarray], view: MarkerView) -> np.ndarray:
        """The families' displacement of a marker (robot-world axes, m): the link bends."""
        return self._summed("marker_displacement", view.point.shape, parts, view)

    def marker_offset(self, x: np.ndarray, k: int) -> np.ndarray:
        """Offset (3,) of marker ``k`` in its frame's axes (m) for parameters ``x``."""
        extra = self.part(x, "markers")
        nominal = np.asarray(self.markers[k].offset, dtype=float)
        return nominal if extra is None else nominal + extra[3 * k: 3 * k + 3]

    def measuring_placement(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(R, t) with ``y = R p + t`` for a robot-world point ``p``, parameters ``x``."""
        frame = self.part(x, "frame")
        rot, _ = MeasuringFrame.frame_rotation(frame)
        return rot @ self.rotation0, self.translation0 + MeasuringFrame.frame_translation(frame)



@dataclass
class _Evaluation:
    """What every row of one :meth:`PoseModel.evaluate` shares: the perturbed model and its
    data, the parameters (``x``, per family ``parts``), the measuring frame (``exp(omega)``,
    its right Jacobian, robot-world to measuring axes, translation, m), and whether the
    Jacobian is asked for."""

    model: pin.Model
    data: pin.Data
    x: np.ndarray
    parts: dict[str, np.ndarray]
    rot_w: np.ndarray
    d_omega: np.ndarray
    to_measuring: np.ndarray
    translation: np.ndarray
    jacobian: bool


def _check_combination(families: list[PoseFamily]) -> None:
    """Refuse families whose companions are missing, or that need masses beside a lumped
    gravity (masses unknown)."""
    names = {f.name for f in families}
    for fam in families:
        missing = [r for r in fam.requires if r not in names]
        if missing:
            raise PoseModelError(f"family {fam.name} acts through {', '.join(missing)}: add "
                                 f"{', '.join(missing)} to the model's families")
    lumped = [f.name for f in families if f.lumps_gravity]
    needs = [f.name for f in families if f.needs_masses]
    if lumped and needs:
        raise PoseModelError(f"{', '.join(needs)} need the links' masses, but {lumped[0]} "
                             "stands for unknown masses: use --masses known, or drop them")


def one_dof_joints(model: pin.Model) -> list[int]:
    """Ids of the joints with one degree of freedom, in model order (those the geometry and
    zero-offset families perturb)."""
    return [j for j in range(1, model.njoints) if model.joints[j].nv == 1]


def pose_joints(robot: Robot) -> list[int]:
    """Ids of the joints the zero-offset and geometry families perturb, in model order:
    :func:`one_dof_joints` but a closed loop's passive joints (not commanded: their zero or
    placement is the loop's own geometry)."""
    passive = {int(robot.model.getJointId(n)) for n in robot.loop.passive_joints}
    return [j for j in one_dof_joints(robot.model) if j not in passive]


def _zero_component(shortname: str) -> int | None:
    """Component of a placement error that is the joint's own zero offset, if any."""
    kind = shortname.replace("JointModel", "")
    for prefix, base in (("RUB", 3), ("R", 3), ("P", 0)):
        if kind.startswith(prefix) and kind[len(prefix):] in ("X", "Y", "Z"):
            return base + "XYZ".index(kind[len(prefix):])
    return None


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
