"""An elastic model at a pose under a load: what :meth:`ElasticModel.at
<stiffness.elastic.model.ElasticModel.at>` answers.

:class:`ElasticState` holds the linearised quantities, ``C = J (K_t - K_C - K_p)^-1 J^T +
C_link`` with ``K_t`` the joint law's tangent at the load (one :class:`Linearisation` per
formulation), ``K_X = C^-1`` in both formulations (``enhanced`` with ``K_C``, A&S eq. 10;
``conventional`` without, eq. 8) and both 6x6 connections of Zefran & Kumar, the definiteness
and the critical load factor along the wrench; and the exact loaded equilibrium
(:meth:`ElasticState.equilibrium`, a :class:`Deflection`:
:func:`stiffness.elastic.loaded.loaded_equilibrium`, or under a preload
:func:`stiffness.mechanics.equilibrium.solve_equilibrium`). With a preload, ``J`` and ``K_C``
are those of the preloaded pose, the commanded one deflected by ``dtheta_0 = f(tau_p + K_p
dtheta_0)``.

Units: SI (m, N, rad, N.m/rad; m and N/m for prismatic joints).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import pinocchio as pin

from stiffness.batch.linalg import critical_load_factor
from stiffness.elastic.compensator import ElasticModel as CompensatedModel
from stiffness.elastic.loaded import Loaded, loaded_equilibrium
from stiffness.errors import StiffnessError, UnknownNameError, wrong_argument
from stiffness.mechanics.equilibrium import deflected_configuration, solve_equilibrium
from stiffness.mechanics.formulation import (
    as_wrench,
    cartesian_stiffness,
    compliance,
    definiteness,
    joint_connection_stiffness,
    tangent_definiteness,
    target_state,
    twist_basis_stiffness,
)
from stiffness.mechanics.wrench import TWIST_ORDERS, reorder_twist
from stiffness.robot.kinematics import reach
from stiffness.robot.robot import Robot
from stiffness.units import float_array


class ElasticModel(CompensatedModel, Protocol):
    """What a state reads of its elastic model (:class:`stiffness.elastic.model.ElasticModel`,
    which imports this module to build its states, :meth:`ElasticModel.at`)."""

    k_theta: np.ndarray
    joint_angles: str
    beyond_springs: tuple[str, ...]
    fitted: Callable[..., np.ndarray] | None

    def configuration(self, q: np.ndarray | list[float]) -> np.ndarray:
        """Full configuration (loops closed) of the coordinates or a full configuration."""
        ...

    def preloaded_configuration(self, q: np.ndarray) -> np.ndarray:
        """The pose the preload sags the commanded full configuration ``q`` to."""
        ...

    def tangent_stiffness(self, tau0: np.ndarray, k_c: np.ndarray) -> np.ndarray:
        """The joint law's tangent stiffness at the torque ``tau0``."""
        ...

    def link_compliance(self, q: np.ndarray, position: np.ndarray) -> np.ndarray:
        """(6, 6) compliance of the link bends at ``q``, the target at ``position``."""
        ...

#: Formulations of the linear answer.
FORMULATIONS = ("conventional", "enhanced")
#: 6x6 connections of Zefran & Kumar (target body axes).
CONNECTIONS = ("joint", "twist")
#: A critical load factor this many times the inverse of K_C's size relative to K_theta comes
#: from round-off (a K_C with no positive eigenvalue): no critical load.
ROUND_OFF_FACTOR = 1e10
#: A whitened ``K_C`` this many times below the wrench's own scale (force x reach + moment,
#: over ``K_theta``) is round-off: a SCARA under a vertical load (its ``K_C`` entries 1e-31
#: N.m/rad) had a critical load factor of 1.4e34 instead of none.
ROUND_OFF_SIZE = 1e-12


@dataclass
class Linearisation:
    """The linear model at a pose and load in one formulation (SI; base axes at the target).

    Attributes
    ----------
    formulation
        ``enhanced`` or ``conventional``.
    k_tangent
        (n, n) joint tangent stiffness at the load.
    k_c
        (n, n) ``K_C`` entering the compliance (zero in the conventional formulation).
    preload_torque, k_preload
        (n,) torque of the weight and compensators, and its derivative ``K_p`` (n, n).
    link_compliance
        (6, 6) compliance of the link bends.
    """

    formulation: str
    k_tangent: np.ndarray
    k_c: np.ndarray
    preload_torque: np.ndarray
    k_preload: np.ndarray
    link_compliance: np.ndarray

    @property
    def joint_stiffness(self) -> np.ndarray:
        """``K_t - K_C - K_p`` (n, n)."""
        return self.k_tangent - self.k_c - self.k_preload


class ElasticState:
    """An elastic model at a commanded pose under a wrench (SI; base axes at the target).

    Attributes
    ----------
    model
        The elastic model.
    q_commanded
        Commanded full configuration (loops closed).
    q
        Operating full configuration: ``q_commanded``, or with a preload the pose it sags to
        (:meth:`~stiffness.elastic.model.ElasticModel.preloaded_configuration`); J and K_C
        are those of this pose.
    load
        The wrench as given: a force (3,) N or a wrench (6,) N, N.m.
    wrench
        The wrench [F (N); M (N.m)] (6,).
    commanded
        Target state at ``q`` under the wrench
        (:class:`stiffness.mechanics.formulation.TargetState`).
    operating
        Target state at the operating pose: ``q``, or with a preload the pose it sags to
        (:meth:`~stiffness.elastic.model.ElasticModel.preloaded_configuration`).
    formulation
        Default formulation of :meth:`compliance`, :meth:`stiffness` and the attributes of
        the linearisation (``k_tangent``, ``compliance``...).
    """

    def __init__(self, model: ElasticModel, q: np.ndarray | list[float],
                 load: np.ndarray | list[float], formulation: str = "enhanced",
                 closed: np.ndarray | None = None) -> None:
        _check_formulation(formulation)
        self.model, self.formulation = model, formulation
        self.load = float_array(load, "the load", "a force (fx,fy,fz in N) or a wrench "
                                "(fx,fy,fz,mx,my,mz in N, N.m)", finite=False).reshape(-1)
        self.wrench = as_wrench(self.load)
        self.q_commanded = model.configuration(q) if closed is None else float_array(
            closed, "closed", f"the full configuration of {model.robot.title} "
            f"({model.robot.model.nq} values, loops closed)", size=model.robot.model.nq, ndim=1)
        self.commanded = target_state(model.robot, self.q_commanded, self.wrench)
        self.q = self.q_commanded
        self.operating = self.commanded
        if model.preloaded and model.joint_angles == "motor":  # link poses are sagged already
            self.q = model.preloaded_configuration(self.q_commanded)
            self.operating = target_state(model.robot, self.q, self.wrench)
        self._linear: dict[str, Linearisation] = {}
        self._link = model.link_compliance(self.q, self.operating.position)

    # the pose ----------------------------------------------------------------------------
    @property
    def robot(self) -> Robot:
        """The model's robot."""
        return self.model.robot

    @property
    def jacobian(self) -> np.ndarray:
        """(6, n) target Jacobian w.r.t. ``robot.compliant_joints`` at the operating pose, rows
        [v (m/rad); omega (rad/rad)]."""
        return self.operating.jacobian

    @property
    def k_c(self) -> np.ndarray:
        """(n, n) complementary stiffness ``K_C`` of the wrench at the operating pose
        (N.m/rad)."""
        return self.operating.k_c

    @property
    def position(self) -> np.ndarray:
        """Target position (m) at the operating pose."""
        return self.operating.position

    @property
    def k_theta(self) -> np.ndarray:
        """(n,) nominal joint stiffness (N.m/rad, N/m)."""
        return self.model.k_theta

    # the linear answer -------------------------------------------------------------------
    def linearisation(self, formulation: str | None = None) -> Linearisation:
        """The linear model in ``formulation`` (default :attr:`formulation`), computed once."""
        formulation = formulation or self.formulation
        _check_formulation(formulation)
        if formulation not in self._linear:
            state = self.operating
            k_c = state.k_c if formulation == "enhanced" else np.zeros_like(state.k_c)
            tau_p, k_p = self.model.preload(self.q, formulation)
            k_t = self.model.tangent_stiffness(state.jacobian.T @ self.wrench + tau_p, k_c + k_p)
            self._linear[formulation] = Linearisation(formulation, k_t, k_c, tau_p, k_p,
                                                      self._link)
        return self._linear[formulation]

    def compliance(self, rows: slice = slice(0, 3), formulation: str | None = None
                   ) -> np.ndarray:
        """Compliance ``J (K_t - K_C - K_p)^-1 J^T + C_link`` on ``rows`` (default the 3x3
        translational block, m/N; ``slice(0, 6)``: the 6x6, rows [v; omega]).

        Raises
        ------
        SingularConfigurationError
            If ``K_t - K_C - K_p`` is singular (the load is at the buckling limit).
        """
        if not isinstance(rows, slice) or not len(range(6)[rows]):
            raise wrong_argument("rows", rows, "a slice of the 6 rows [v; omega] (slice(0, 3))")
        lin = self.linearisation(formulation)
        jac = self.jacobian[rows]
        return compliance(jac, lin.joint_stiffness) + lin.link_compliance[rows, rows]

    def stiffness(self, formulation: str = "enhanced", connection: str | None = None,
                  dims: int | None = None, twist_order: str | None = None) -> np.ndarray:
        """Cartesian stiffness K_X: what ``stiffness kx`` reports for the same model, pose and
        wrench with the same flags (its default with no argument).

        Parameters
        ----------
        formulation
            ``enhanced`` (``K_t - K_C``, A&S eq. 10) or ``conventional`` (eq. 8).
        connection
            ``None``: ``C^-1`` in base axes at the target; ``joint`` or ``twist``: the 6x6
            stiffness of Zefran & Kumar in the target's body axes (joint springs only).
        dims
            3 (N/m) or 6 (blocks N/m | N | N.m/rad); default 6 for a wrench given with six
            components or a connection, else 3.
        twist_order
            Row order of a 6x6 (``v-w`` or ``w-v``); default the robot's own, else ``v-w``.

        Raises
        ------
        SingularConfigurationError
            Where K_X does not exist (singular compliance or Jacobian).
        StiffnessError
            A connection asked of a model with effects beyond joint springs.
        """
        dims = self.dims(connection, dims)
        if connection is not None:
            k_x = self.connection_stiffness(connection)
        else:
            k_x = cartesian_stiffness(self.compliance(slice(0, dims), formulation))
        return k_x if dims == 3 else reorder_twist(k_x, self.twist_order(twist_order))

    def dims(self, connection: str | None = None, dims: int | None = None) -> int:
        """Rows of the answers: ``dims``, or 6 for a wrench or a connection, else 3.

        Raises
        ------
        StiffnessError
            ``dims`` not 3 or 6, or 3 with a connection.
        """
        if dims is None:
            return 6 if self.load.shape[0] == 6 or connection is not None else 3
        if dims not in (3, 6) or (connection is not None and dims != 6):
            raise StiffnessError(f"dims must be 3 or 6 (6 with a connection), got {dims!r}")
        return int(dims)

    def twist_order(self, order: str | None = None) -> str:
        """Row order of 6x6 answers: ``order``, else the robot's ``twist_order``, else ``v-w``.

        Raises
        ------
        StiffnessError
            An unknown order.
        """
        order = order or self.robot.defaults.get("twist_order", "v-w")
        if order not in TWIST_ORDERS:
            raise StiffnessError(f"twist_order of {self.robot.title} must be one of "
                                 f"{list(TWIST_ORDERS)}, got {order!r}")
        return order

    def connection_stiffness(self, connection: str) -> np.ndarray:
        """The 6x6 stiffness of Zefran & Kumar in the target's body axes, rows [v; omega]:
        ``joint`` (``J_b^-T K_theta J_b^-1``) or ``twist`` (``J_b^-T (K_theta - K_C^tw)
        J_b^-1``, asymmetric under load), at the commanded pose.

        Raises
        ------
        StiffnessError
            An unknown connection, or a model with effects beyond joint springs.
        SingularConfigurationError
            A singular body Jacobian (or not six compliant joints).
        """
        if connection not in CONNECTIONS:
            raise UnknownNameError(f"connection must be one of {', '.join(CONNECTIONS)}, got "
                                   f"{connection!r}", name=connection, choices=CONNECTIONS)
        if self.model.beyond_springs or self.model.links or self.model.preloaded or np.any(
                self.model.law.beta != 0):
            raise StiffnessError("--connection gives the 6x6 stiffness of joint springs alone; "
                                 "the model's link_compliance, nonlinear_joint_stiffness or "
                                 "gravity effects cannot enter it: drop --connection")
        k_theta = np.diag(self.k_theta)
        if connection == "joint":
            return joint_connection_stiffness(self.commanded, k_theta)
        return twist_basis_stiffness(self.commanded, k_theta)

    @property
    def k_tangent(self) -> np.ndarray:
        """(n, n) joint tangent stiffness at the load (default formulation)."""
        return self.linearisation().k_tangent

    @property
    def link_compliance(self) -> np.ndarray:
        """(6, 6) compliance of the link bends."""
        return self._link

    @property
    def preload_torque(self) -> np.ndarray:
        """(n,) torque of the weight and compensators at the operating pose."""
        return self.linearisation().preload_torque

    @property
    def k_preload(self) -> np.ndarray:
        """(n, n) its derivative ``K_p`` (default formulation)."""
        return self.linearisation().k_preload

    def k_x(self, rows: slice = slice(0, 3)) -> np.ndarray:
        """``C[rows, rows]^-1`` in the default formulation (default 3x3, N/m), base axes."""
        return cartesian_stiffness(self.compliance(rows))

    # stability ---------------------------------------------------------------------------
    @property
    def definiteness(self) -> dict[str, str]:
        """Definiteness of ``K_C`` and of ``K_theta - K_C`` at the commanded pose
        (:func:`stiffness.mechanics.formulation.definiteness`)."""
        k_theta = np.diag(self.k_theta)
        k_c = self.commanded.k_c
        return {"K_C": definiteness(k_c, atol=self.k_c_round_off),
                "K_theta_minus_K_C": tangent_definiteness(k_theta, k_theta - k_c)}

    @property
    def k_c_round_off(self) -> float:
        """The size (N.m/rad) at or below which an entry or eigenvalue of ``K_C`` is round-off:
        :data:`ROUND_OFF_SIZE` times :meth:`_load_moment`, the order of a physical ``K_C``
        of this wrench (0 without a load). :attr:`definiteness` counts such eigenvalues as
        zero and ``stiffness kx`` reports such entries as 0."""
        return ROUND_OFF_SIZE * self._load_moment()

    @property
    def critical_load_factor(self) -> float:
        """Smallest ``lambda > 0`` with ``K_t - K_p - lambda K_C`` singular: the factor on the
        wrench at which the arm buckles (inf if it never does along this wrench, to round-off:
        :data:`ROUND_OFF_FACTOR`; 0 if the preload alone does). Physical ``K_C`` and ``K_p``
        (those of the enhanced formulation), :func:`stiffness.batch.linalg.critical_load_factor`
        on ``K_t - K_p`` whitened when it is not diagonal."""
        lin = self.linearisation("enhanced")
        base = lin.k_tangent - lin.k_preload
        if np.count_nonzero(base - np.diag(np.diag(base))) == 0:
            factor = float(critical_load_factor(base, self.k_c))
            scale = 1.0 / np.sqrt(np.diag(base))
            scaled = self.k_c * scale[:, None] * scale[None, :]
        else:
            try:
                chol = np.linalg.cholesky(0.5 * (base + base.T))
            except np.linalg.LinAlgError:
                return 0.0
            scaled = np.linalg.solve(chol, np.linalg.solve(chol, self.k_c).T)
            factor = float(critical_load_factor(np.eye(len(base)), scaled))
        size = float(np.linalg.norm(scaled, 2))
        if size <= ROUND_OFF_SIZE * self._load_scale(base):  # K_C nil: round-off alone
            return math.inf
        return factor if math.isfinite(factor) and factor * size < ROUND_OFF_FACTOR else math.inf

    def _load_scale(self, base: np.ndarray) -> float:
        """The size a physical ``K_C`` of this wrench has, whitened by ``base`` (1):
        :meth:`_load_moment` over ``base``'s smallest eigenvalue."""
        low = float(np.linalg.eigvalsh(0.5 * (base + base.T))[0])
        return self._load_moment() / low if low > 0 else math.inf

    def _load_moment(self) -> float:
        """The wrench's force times the robot's reach plus its moment (N.m): the size of a
        physical ``K_C`` (:func:`~stiffness.robot.kinematics.reach`)."""
        return (float(np.linalg.norm(self.wrench[:3])) * reach(self.model.robot.model)
                + float(np.linalg.norm(self.wrench[3:])))

    @property
    def stable(self) -> bool:
        """Whether the arm is stable under the wrench (critical load factor above 1)."""
        return self.critical_load_factor > 1.0

    # the exact answer --------------------------------------------------------------------
    def equilibrium(self) -> Deflection:
        """The exact loaded equilibrium at the commanded pose and its deflection from the
        unloaded one (under a preload both are solved with it; link bends and a preload
        together are not modelled). With ``link`` joint angles the pose given is the unloaded
        equilibrium itself: the springs rest at ``q - law(tau_p(q))``, from which the load
        is solved (:meth:`rest_configuration`).

        Raises
        ------
        StiffnessError
            No convergence, an unstable equilibrium, or link bends with a preload.
        """
        model = self.model
        if not model.preloaded:
            command = self.q_commanded
            loaded = loaded_equilibrium(model, model.robot.spring_values(command), self.wrench,
                                        seed_q=command)
            rest = target_state(model.robot, command)
            return Deflection(loaded.q, loaded.position, loaded.position - rest.position,
                              pin.log3(loaded.rotation @ rest.rotation.T), loaded)
        if model.links:
            raise StiffnessError("the exact equilibrium of link bends under a preload (weight, "
                                 "compensator) is not modelled; drop one of them")
        law = model.compliant_law()
        springs_rest = self.rest_configuration()
        unloaded = (self.q_commanded if model.joint_angles == "link" else solve_equilibrium(
            model.robot, springs_rest, law, np.zeros(6), preload=model.preload).q)
        eq = solve_equilibrium(model.robot, springs_rest, law, self.wrench, preload=model.preload)
        before, after = target_state(model.robot, unloaded), target_state(model.robot, eq.q)
        return Deflection(eq.q, after.position, after.position - before.position,
                          pin.log3(after.rotation @ before.rotation.T), None)

    def rest_configuration(self) -> np.ndarray:
        """Where the springs rest (full configuration, loops closed): the commanded pose, or
        with ``link`` joint angles under a preload the pose given (the unloaded equilibrium
        ``q``) less the joint law's deflection under the preload there, ``q - law(tau_p(q))``
        (exact: the unloaded equilibrium solves ``q - q_rest = law(tau_p(q))``)."""
        model = self.model
        if not (model.preloaded and model.joint_angles == "link"):
            return self.q_commanded
        sag = model.compliant_law()(model.preload(self.q_commanded)[0])[0]
        return deflected_configuration(model.robot, self.q_commanded, -sag, self.q_commanded)


@dataclass
class Deflection:
    """The exact loaded equilibrium of an :class:`ElasticState`.

    Attributes
    ----------
    q
        Full configuration at equilibrium (loops closed; without the bends' rotation).
    position
        Target position (m) at equilibrium, base frame.
    dx
        (3,) target displacement from the unloaded equilibrium (m).
    dphi
        (3,) rotation vector of the target frame from the unloaded equilibrium (rad, base
        axes).
    loaded
        The solver's state with link bends (:class:`stiffness.elastic.loaded.Loaded`), or
        ``None`` under a preload.
    """

    q: np.ndarray
    position: np.ndarray
    dx: np.ndarray
    dphi: np.ndarray
    loaded: Loaded | None = None

    @property
    def twist(self) -> np.ndarray:
        """(6,) ``[dx; dphi]`` (m; rad)."""
        return np.concatenate([self.dx, self.dphi])


def _check_formulation(formulation: str) -> None:
    if formulation not in FORMULATIONS:
        raise UnknownNameError(f"formulation must be one of {', '.join(FORMULATIONS)}, got "
                               f"{formulation!r}", name=formulation, choices=FORMULATIONS)
