"""The elastic model: a robot with its joint laws, link bends, preloads, target and measurement.

:class:`ElasticModel` is the one object a stiffness model becomes away from its campaign: built
from joint springs (:meth:`ElasticModel.joint_springs`), from a model file
(:func:`stiffness.elastic.model_file.load_model`), or from what a set of effects contributes
(:meth:`ElasticModel.of_parts`, each effect through its one hook
:meth:`stiffness.elastic.effects.base.Effect.contribute`). It holds

* a joint law over the spring joints (the coordinates, or the chain joints of a
  ``[controller]`` with ``springs_on = "chain"``), ``theta - theta_c = law(tau)``: linear
  springs (the baseline's and those effects add), nonlinear springs
  ``tau/k (1 + beta|tau|)``, backlash ``b tanh(tau/tau_s)``; zero compliance for a rigid one;
* link bends (:class:`stiffness.elastic.loaded.LinkBend`): the segment ``a -> b`` bends at
  ``b``'s origin about two axes normal to it, or a joint tilts in its bearing about the two
  axes normal to its rotation axis (``transversal_compliance``);
* preloads: the links' weight with a payload, and spring gravity compensators, whose torque
  ``tau_p`` acts at every pose and whose derivative ``K_p`` adds to ``K_C``;
* the target (moved by a ``target_offset``) and the measurement effects (how a campaign
  observed its deflections: listed, not applied to the robot).

At a pose and a load it answers (:meth:`ElasticModel.at`, an
:class:`~stiffness.elastic.state.ElasticState`, :mod:`stiffness.elastic.state`): the linearised
quantities in both formulations and both 6x6 connections, the definiteness, the critical load
factor along the wrench and the exact loaded equilibrium.

Units: SI (m, N, rad, N.m/rad; m and N/m for prismatic joints).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
import pinocchio as pin

from stiffness.elastic.compensator import Compensator, retargeted
from stiffness.elastic.effects.base import Effect
from stiffness.elastic.effects.geometry import Geometry, joint_axis_column, skew
from stiffness.elastic.effects.parts import ElasticParts
from stiffness.elastic.loaded import LinkBend, bend_frame, linear_deflection
from stiffness.elastic.state import ElasticState
from stiffness.errors import StiffnessError, UnknownNameError
from stiffness.mechanics.defaults import joint_stiffnesses
from stiffness.mechanics.equilibrium import (
    SpringLaw,
    deflected_configuration,
    tangent_equilibrium,
)
from stiffness.mechanics.formulation import as_wrench
from stiffness.mechanics.gravity import joint_preload, require_open_chain, with_payload
from stiffness.mechanics.ik import all_coordinates
from stiffness.robot.robot import Robot, load_robot
from stiffness.units import float_array


@dataclass
class ElasticModel:
    """A robot with what acts on it under a load (SI).

    Attributes
    ----------
    robot
        The robot: its compliant joints are the springs, its target the (moved) target.
    law
        Joint law over ``robot.spring_joints`` (zero compliance: a rigid one).
    links
        Link bends, any order.
    formulation
        The formulation the model was identified with (``enhanced`` or ``conventional``): that
        of the first-order deflection of :func:`stiffness.elastic.loaded.linear_deflection`.
    ignored
        Labels of the effects that do not act on the robot (measurement effects).
    source
        The model file, if any.
    k_theta
        (n,) stiffness of ``robot.compliant_joints`` (N.m/rad, N/m); default ``1 / compliance``.
    payload
        ``(mass kg, centre of mass (3,) m in target frame axes)`` when the links' weight and a
        payload preload the joints, else ``None``.
    compensators
        Spring gravity compensators ``(joint, stiffness N/m, tension N, geometry)``.
    misalignment, force_bias, deflection_offset
        How a campaign observed the deflections (rad, N, m); not applied to the robot.
    applied, not_applied
        A model file's effects that enter the stiffness, and ``(effect, reason)`` of those
        that do not (:class:`stiffness.elastic.model_contents.ModelEffect`).
    beyond_springs
        Labels of the applied effects that a diagonal ``K_theta`` cannot carry (a nonlinear
        spring, a link bend, a preload): the batched scan and the 6x6 connections refuse them.
    fitted
        A model file's fitted prediction ``(q, load, measured) -> dx``
        (:func:`stiffness.elastic.file_model.fitted_deflection`), else ``None``.
    joint_angles
        What the poses given to :meth:`at` are: ``motor`` (commanded; a preload sags them) or
        ``link`` (the unloaded pose already, the campaign's ``[robot] joint_angles``).
    """

    robot: Robot
    law: SpringLaw
    links: tuple[LinkBend, ...] = ()
    formulation: str = "enhanced"
    ignored: tuple[str, ...] = ()
    source: str | None = None
    k_theta: np.ndarray = field(default_factory=lambda: np.zeros(0))
    payload: tuple[float, np.ndarray] | None = None
    compensators: tuple[tuple[str, float, float, dict], ...] = ()
    misalignment: np.ndarray = field(default_factory=lambda: np.zeros(3))
    force_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))
    deflection_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    applied: tuple = ()
    not_applied: tuple = ()
    beyond_springs: tuple[str, ...] = ()
    fitted: Callable[..., np.ndarray] | None = field(default=None, repr=False)
    joint_angles: str = "motor"
    _full: Robot | None = field(default=None, repr=False)
    _springs: Robot | None = field(default=None, repr=False)
    _weighed: pin.Model | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.k_theta.size == 0:
            self.k_theta = 1.0 / self.law.compliance[self.robot.compliant_in_springs]
        if self.payload is not None:
            require_open_chain(self.robot, "gravity_preload")
            self._weighed = with_payload(self.robot, *self.payload)

    # construction ------------------------------------------------------------------------
    @classmethod
    def joint_springs(cls, robot: Robot, k_theta: np.ndarray | list[float],
                      formulation: str = "enhanced") -> ElasticModel:
        """Linear springs ``k_theta`` (N.m/rad, N/m; a vector or a diagonal matrix) on the
        robot's compliant joints.

        Raises
        ------
        StiffnessError
            Not one finite positive stiffness per compliant joint, or off-diagonal terms.
        """
        k = joint_stiffnesses(robot, k_theta)
        n = len(robot.spring_joints)
        compliance_ = np.zeros(n)
        compliance_[robot.compliant_in_springs] = 1.0 / k
        return cls(robot, SpringLaw(compliance_, np.zeros(n), np.zeros(n), np.ones(n)),
                   formulation=formulation, k_theta=k.copy())

    @classmethod
    def of_parts(cls, robot: Robot, parts: ElasticParts, formulation: str = "enhanced",
                 link_columns: dict[tuple[str, str], int] | None = None, **extra
                 ) -> ElasticModel:
        """The model of what effects contributed (:class:`ElasticParts`), on ``robot`` loaded
        with ``parts.springs`` compliant and the target shifted by ``parts.target_shift``.

        ``link_columns`` picks the bend axes (default those of the robot's geometry,
        :attr:`stiffness.elastic.effects.geometry.Geometry.link_columns`); ``extra``: further
        attributes (``source``, ``applied``, ``not_applied``, ``beyond_springs``).
        """
        if parts.bends and link_columns is None:
            link_columns = Geometry.of(robot).link_columns
        links = tuple(LinkBend(a, b, link_columns[(a, b)], (k1, k2))
                      for a, b, k1, k2 in parts.bends) if link_columns is not None else ()
        links += tuple(LinkBend(j, j, _tilt_column(robot, j), (k1, k2), tilt=True)
                       for j, k1, k2 in parts.tilts)
        return cls(robot, parts.law(robot.spring_joints), links, formulation,
                   tuple(parts.not_applied), k_theta=np.array(
                       [parts.springs[j] for j in robot.compliant_joints], dtype=float),
                   payload=parts.payload, compensators=tuple(parts.compensators),
                   misalignment=parts.misalignment, force_bias=parts.force_bias,
                   deflection_offset=parts.deflection_offset, **extra)

    @classmethod
    def with_effects(cls, robot: Robot, k_theta: np.ndarray | list[float],
                     effects: list[tuple[Effect, np.ndarray]], formulation: str = "enhanced"
                     ) -> ElasticModel:
        """Joint springs ``k_theta`` (N.m/rad, N/m) on the robot's compliant joints plus
        ``effects``, each ``(effect, SI parameter values)`` contributing through its one hook
        (:meth:`stiffness.elastic.effects.base.Effect.contribute`); the robot is reloaded
        with the springs effects add and its target moved by a target shift.

        Raises
        ------
        StiffnessError
            A bad stiffness, or an effect that does not fit the robot.
        """
        k = joint_stiffnesses(robot, k_theta)
        parts = ElasticParts(dict(zip(robot.compliant_joints, k.tolist(), strict=True)))
        for effect, values in effects:
            effect.contribute(np.asarray(values, dtype=float), parts)
        parts.check_joints()
        loaded = load_robot(robot.name, frame=robot.target_frame,
                            target_offset=robot.target_offset + parts.target_shift,
                            compliant_joints=tuple(parts.springs), loops=robot.loop_file,
                            fixed_base=robot.fixed_base)
        return cls.of_parts(loaded, parts, formulation)

    # what it is ------------------------------------------------------------------------
    @property
    def full(self) -> Robot:
        """The robot with every coordinate compliant (Jacobians w.r.t. all coordinates)."""
        if self._full is None:
            self._full = all_coordinates(self.robot)
        return self._full

    @property
    def springs(self) -> Robot:
        """The robot whose coordinates are the spring joints, every one compliant
        (:meth:`stiffness.robot.robot.Robot.springs_robot`): the unknowns of the exact
        equilibrium."""
        if self._springs is None:
            self._springs = self.robot.springs_robot()
        return self._springs

    @property
    def joint_only(self) -> bool:
        """Whether joint motions are the only effect (the compensation is closed-form)."""
        return not self.links

    @property
    def preloaded(self) -> bool:
        """Whether a preload (the weight, a compensator) acts at every pose."""
        return self._weighed is not None or bool(self.compensators)

    def compliant_law(self) -> SpringLaw:
        """The joint law over ``robot.compliant_joints`` (the spring joints' law restricted)."""
        idx = self.robot.compliant_in_springs
        law = self.law
        return SpringLaw(law.compliance[idx], law.beta[idx], law.backlash[idx],
                         law.smoothing[idx])

    def ordered_links(self) -> list[LinkBend]:
        """Links from the base to the tip (by the chain position of ``b``, then ``a``)."""
        model = self.robot.model
        depth = {name: len(model.supports[model.getJointId(name)]) for name in model.names}
        return sorted(self.links, key=lambda lk: (depth[lk.b], depth[lk.a]))

    def describe(self) -> str:
        """E.g. ``joint springs on joint1, joint2 + link bend joint2->joint3``."""
        names = [j for j, c in zip(self.robot.spring_joints, self.law.compliance,
                                   strict=True) if c > 0]
        text = f"joint springs on {', '.join(names) or 'no joint'}"
        if np.any(self.law.beta != 0):
            text += " (nonlinear)"
        if np.any(self.law.backlash != 0):
            text += " + backlash"
        return text + "".join(f" + {lk.label}" for lk in self.links)

    def deflection(self, q: np.ndarray, load: np.ndarray, measured: bool = False
                   ) -> np.ndarray:
        """The fitted model's predicted target displacement (3,) in m at coordinates ``q``
        under a dead ``load``: every effect applied, lost motion included, measurement effects
        only with ``measured`` (a model read from a model file only).

        Raises
        ------
        StiffnessError
            A model not read from a model file.
        """
        if self.fitted is None:
            raise StiffnessError("only a model read from a model file has a fitted prediction; "
                                 "use .at(q, wrench).equilibrium() for the exact deflection")
        return self.fitted(q, load, measured)

    def compensator(self, frame: str | None = None, target_offset: np.ndarray | list[float] | None
                    = None, hold: str = "auto", method: str = "auto") -> Compensator:
        """The real-time compensator (:class:`stiffness.elastic.compensator.Compensator`) of the
        model for the target ``frame`` at ``target_offset`` (m, its axes; default the model's
        target: the wrench's point and what is held; laws, bends, preloads and the payload
        carry over); ``hold`` ``pose``, ``position`` or ``auto``; ``method`` ``auto``,
        ``closed-form`` or ``general``."""
        if frame is None and target_offset is None:
            return Compensator(self, hold, method)
        moved = replace(self, robot=retargeted(self.robot, frame, target_offset), _full=None,
                        _springs=None, k_theta=self.k_theta.copy())
        moved._weighed = self._weighed  # the payload stays where it is
        return Compensator(moved, hold, method)

    # at a pose ---------------------------------------------------------------------------
    def configuration(self, q: np.ndarray | list[float]) -> np.ndarray:
        """Full configuration of coordinates (n_coordinates,) or of a full ``q`` (nq,).

        When both have the same length the values are the coordinates: the same thing for
        a robot whose coordinates are its joints, the controller's coordinates for a robot
        with a ``[controller]`` coupling (give it ``robot.coordinates_of(q)``).

        Raises
        ------
        StiffnessError
            Neither length.
        """
        q = float_array(q, "q", lambda: f"the {self.robot.n_coordinates} coordinates of "
                        f"{self.robot.title} (rad, m) or its full configuration of "
                        f"{self.robot.model.nq} values").reshape(-1)
        if q.shape[0] == self.robot.n_coordinates:
            return self.robot.configuration(q)
        if q.shape[0] == self.robot.model.nq:
            return q
        raise StiffnessError(
            f"give {self.robot.n_coordinates} coordinates of {self.robot.title} "
            f"({', '.join(self.robot.coordinate_joints)}) or a full configuration of "
            f"{self.robot.model.nq} values; got {q.shape[0]}")

    def at(self, q: np.ndarray | list[float], wrench: np.ndarray | list[float] | None = None,
           formulation: str = "enhanced", closed: np.ndarray | None = None) -> ElasticState:
        """The model at a pose and a load.

        Parameters
        ----------
        q
            Coordinates (rad, m) in ``robot.coordinate_joints`` order, or a full configuration:
            the commanded pose.
        wrench
            Dead force (3,) N or wrench (6,) N, N.m at the target, base axes; default zero.
        formulation
            Default formulation of the state's linear answers (``enhanced`` or
            ``conventional``).
        closed
            The full closed configuration of ``q`` when already known (an assembly found
            by :meth:`stiffness.robot.robot.Robot.assemble`); default ``robot.configuration(q)``.
        """
        return ElasticState(self, q, np.zeros(3) if wrench is None else wrench, formulation,
                            closed)

    def preload(self, q: np.ndarray, formulation: str = "enhanced"
                ) -> tuple[np.ndarray, np.ndarray]:
        """Torque (n,) of the weight and the compensators on the compliant joints at the full
        configuration ``q``, and its derivative ``K_p`` (n, n): the compensators' always, the
        weight's (``K_g``) in the ``enhanced`` formulation only (zeros without preloads)."""
        return joint_preload(self.robot, self._weighed, self.compensators, q,
                             weight_stiffness=formulation == "enhanced")

    def linear_deflection(self, coords: np.ndarray, wrench: np.ndarray,
                          seed_q: np.ndarray | None = None) -> np.ndarray:
        """First-order target displacement ``C W`` (6,) [m; rad] under the dead ``wrench``
        (base axes) at the commanded coordinates ``coords`` (rad, m), every effect included
        (:func:`stiffness.elastic.loaded.linear_deflection`); under a preload (the weight, a
        compensator) ``C`` is the tangent compliance at the preloaded operating point,
        ``J (K_t - K_C - K_p)^-1 J^T`` (:meth:`ElasticState.compliance`)."""
        coords = float_array(coords, "coords", lambda: f"the {self.robot.n_coordinates} "
                             f"coordinates of {self.robot.title} (rad, m)",
                             size=self.robot.n_coordinates, ndim=1)
        if not self.preloaded:
            return linear_deflection(self, self.robot.spring_command(coords), wrench,
                                     seed_q=seed_q)
        w = as_wrench(wrench)
        q = self.full.configuration(coords, seed=seed_q)
        return self.at(coords, w, closed=q).compliance(slice(0, 6)) @ w

    def preloaded_configuration(self, q: np.ndarray) -> np.ndarray:
        """The unloaded pose under the weight and the compensators: the commanded full
        configuration ``q`` deflected by ``dtheta_0 = f(tau_p + K_p dtheta_0)`` (the joint law
        at frozen geometry, its nonlinear springs included), loops closed."""
        tau_p, k_p = self.preload(q)
        law = SpringLaw(1.0 / self.k_theta, self.compliant_law().beta,
                        np.zeros(len(self.k_theta)), np.ones(len(self.k_theta)))
        dtheta0 = tangent_equilibrium(law, tau_p, k_p)
        return deflected_configuration(self.robot, q, dtheta0, q)

    def tangent_stiffness(self, tau0: np.ndarray, k_c: np.ndarray) -> np.ndarray:
        """(n, n) joint tangent stiffness ``K_t`` at the torques ``tau0 = J^T W (+ tau_p)``:
        ``K_theta`` for linear springs, else the inverse slope of the law (backlash, lost
        motion, left out) at the frozen-geometry equilibrium under ``K_c``."""
        beta = self.compliant_law().beta
        if not np.any(beta != 0):
            return np.diag(self.k_theta)
        law = SpringLaw(1.0 / self.k_theta, beta, np.zeros_like(beta), np.ones_like(beta))
        dtheta = tangent_equilibrium(law, tau0, k_c)
        return np.diag(1.0 / law(tau0 + k_c @ dtheta)[1])

    def link_compliance(self, q: np.ndarray, position: np.ndarray) -> np.ndarray:
        """(6, 6) compliance the link bends add at the full configuration ``q`` with the target
        at ``position`` (m): ``G E diag(1/k) E^T G^T`` per bend (a joint's tilt included),
        ``G = [-[r]x; I]``, ``r`` from the bend's point to the target, ``E = [e_1 e_2]`` its
        axes (:func:`stiffness.elastic.loaded.bend_frame`)."""
        link = np.zeros((6, 6))
        if not self.links:
            return link
        pin.forwardKinematics(self.robot.model, self.robot.data, q)
        for lk in self.links:
            point, e1, e2 = bend_frame(self.robot.model, self.robot.data, lk)
            g = np.vstack([-skew(position - point), np.eye(3)])
            e = np.column_stack([e1, e2])
            link += g @ e @ np.diag([1.0 / lk.stiffness[0], 1.0 / lk.stiffness[1]]) @ e.T @ g.T
        return link


def _tilt_column(robot: Robot, joint: str) -> int:
    """The rotation axis's column of a joint tilting in its bearing.

    Raises
    ------
    UnknownNameError
        Not a revolute joint of ``robot`` about an axis of its frame.
    """
    model = robot.model
    column = (joint_axis_column(model, model.getJointId(joint))
              if model.existJointName(joint) else None)
    if column is None:
        joints = [n for j, n in enumerate(model.names) if j > 0
                  and joint_axis_column(model, j) is not None]
        raise UnknownNameError(f"transversal_compliance needs a revolute joint of {robot.title} "
                               f"about an axis of its frame, got {joint!r}; valid names: "
                               f"{', '.join(joints)}", name=joint, choices=joints)
    return column
