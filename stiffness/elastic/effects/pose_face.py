"""The pose-model face of an effect (:class:`PoseFamily`): the hooks through which an effect of
the library (:data:`stiffness.elastic.effects.FAMILIES`) is a parameter family of an
absolute-pose model, the parameter a family lays out (:class:`FamilyParameter`), and what the
hooks read: a row (:class:`RowTerms`), the model's layout (:class:`PoseLayout`), the sag's state
at a configuration (:class:`SagState`) and one marker on one row (:class:`MarkerView`).

A family is one effect class: its name, its family kind (``"geometric"`` or ``"elastic"``), its
parameters with their units and typical sizes, and its part of the prediction and of the
Jacobian as methods. The same class serves deflection campaigns through its
:class:`~stiffness.elastic.effects.base.Effect` hooks; as a pose family one object of it acts on
every joint (or link) the model lays out. :class:`~stiffness.calibration.pose_model.PoseModel`
calls the hooks of the families it holds and never branches on a family's name.

Units: SI (m, N, rad).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol

import numpy as np
import pinocchio as pin

from stiffness.batch.poses import JointPlacements
from stiffness.elastic.effects.base import Effect
from stiffness.elastic.effects.geometry import References
from stiffness.robot.robot import Robot

#: A geometric parameter's physical scale is this many times its typical size
#: (:attr:`PoseFamily.family_scale`): ten times a sizeable error, itself ten typical sizes.
POSE_PHYSICAL_FACTOR = 100.0

#: The kinds of family: geometry (where things are) or elasticity (how the arm gives).
FAMILY_KINDS = ("geometric", "elastic")


def compliance_label(joint: str) -> str:
    """Label of a spring's compliance in a pose calibration."""
    return f"{joint} compliance"


def backlash_label(joint: str) -> str:
    """Label of a joint's backlash half-width."""
    return f"{joint} backlash"


def nonlinear_label(joint: str) -> str:
    """Label of a spring's compliance per unit torque ``gamma`` (a nonlinear spring)."""
    return f"{joint} nonlinear compliance"


def compensator_label(joint: str, what: str) -> str:
    """Label of a compensator's ``stiffness`` or ``preload`` on ``joint``."""
    return f"{joint} compensator {what}"


def bend_label(a: str, b: str, axis: int) -> str:
    """Label of the compliance of link ``a -> b`` about its axis ``axis`` (1 or 2)."""
    return f"{a}->{b} compliance {axis}"


def tilt_label(joint: str, axis: int) -> str:
    """Label of the compliance of ``joint``'s bearing tilt about its axis ``axis`` (1 or 2)."""
    return f"{joint} transversal compliance {axis}"


#: Setting of the backlash family: joint -> smoothing torque (N.m, N).
BACKLASH_SETTING = "backlash_smoothing_torque"
#: Setting of the nonlinear spring family: spring -> largest torque it carries (N.m, N).
NONLINEAR_SETTING = "nonlinear_largest_torque"


@dataclass(frozen=True)
class FamilyParameter:
    """One column of the regressor: its family, label, scale (typical size, SI), unit and
    physical lower bound (SI; a compliance, a backlash or a spring's stiffness is never
    negative)."""

    family: str
    label: str
    scale: float
    unit: str
    lower: float = -math.inf


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


class PoseLayout(Protocol):
    """What the families read of the model that holds them
    (:class:`stiffness.calibration.pose_model.PoseModel`): the robot, the markers, the joints'
    layout, the loads and the fixed settings."""

    robot: Robot
    markers: list
    settings: dict
    loads: Any
    frame_ids: list[int]
    joints: list[int]
    compliant: list[int]
    springs: tuple[str, ...]
    spring_map: np.ndarray
    joints_v: list[int]
    compliant_v: list[int]
    geometry: list[tuple[int, int]]
    geometry_index: tuple[np.ndarray, np.ndarray]
    moves: dict[int, np.ndarray]
    #: joints (ids) on the path between a closed loop's two frames: their placement, a bend or
    #: a tilt there changes the loop's closure (empty for an open chain)
    loop_path: frozenset[int]
    #: What families derive from the layout alone (the nominal model's joints, the markers),
    #: by key, computed once per model (:func:`layout_cached`).
    layout_cache: dict[str, Any]

    def frame_id(self, name: str) -> int: ...

    def joint_unit(self, joint: int, revolute: str, prismatic: str) -> str: ...

    def downstream(self, joint: int) -> list[int]: ...

    def spring_downstream(self, spring: int) -> list[int]: ...

    def loop_tangent(self, model: pin.Model, data: pin.Data, q: np.ndarray
                     ) -> np.ndarray | None: ...


def layout_cached(pm: PoseLayout, key: str, compute: Callable[[], Any]) -> Any:
    """``compute()`` once per model ``pm`` (kept in its :attr:`PoseLayout.layout_cache` under
    ``key``): what a family derives from the layout alone, read-only, at each evaluation (the
    links a bend family reads: a forward kinematics and a walk of the markers' chains, 10 % of
    a pose evaluation when recomputed each time)."""
    if key not in pm.layout_cache:
        pm.layout_cache[key] = compute()
    return pm.layout_cache[key]


@dataclass
class SagState:
    """Generalised forces (nv,) at a loaded configuration, and what families derive from it.

    Attributes
    ----------
    q
        The loaded configuration (nq,).
    gravity
        Gravity's generalised force ``-g(q)`` (N.m or N).
    wrench
        The applied wrench's ``J_load(q)^T w``.
    torque
        The torque the joints' springs carry: the wrench's, gravity's unless a family lumps
        it (masses unknown), plus the families' own torques (a compensator's spring).
    per_torque
        d(Delta q)/d(torque) (nv,) of the families' joint deflections at that torque (filled
        when the Jacobian is asked for: :meth:`PoseModel.deflection_slope`).
    extras
        Per-family quantities at ``q`` (:meth:`PoseFamily.at_configuration`).
    """

    q: np.ndarray
    gravity: np.ndarray
    wrench: np.ndarray
    torque: np.ndarray
    per_torque: np.ndarray
    extras: dict[str, Any] = field(default_factory=dict)


@dataclass
class MarkerView:
    """The markers on a batch of n rows, at their loaded configurations: what a family's
    columns read (leading (n, M) axes: rows, markers).

    Attributes
    ----------
    model, data
        The perturbed Pinocchio model and its data (a workspace: it holds no particular row).
    point
        (n, M, 3) marker positions in robot-world axes (m), before any link bend.
    world
        ``R_0`` times the bent marker positions (m).
    to_measuring
        ``exp(omega) R_0``: robot-world to measuring axes.
    rot_w, d_omega
        ``exp(omega)`` and the right Jacobian of ``exp`` at ``omega``.
    j_point
        (n, M, 3, nv) d point / d v, world axes (empty when no Jacobian is asked for).
    sag
        The sag's state, arrays (n, 1, nv) (``None``: a rigid model).
    caches
        Per-family quantities of the rows (:meth:`PoseFamily.rows_cache`).
    frame_rotation
        (n, M, 3, 3) rotations of the markers' frames in the world.
    moving
        (M, n_joints) 1 for the 1-dof joints (:attr:`PoseLayout.joints`) that move each
        marker's frame, else 0.
    selector
        (M, M) one-hot: each marker among the model's markers.
    tangent
        (n, nv, nv) ``T = dq/du`` of a robot with closed loops at each row's loaded
        configuration (``j_point`` already holds it: ``J_p T``; a torque of the tree reaches
        the springs as ``T^T tau``), or ``None``: an open chain, or no Jacobian asked for.
    """

    model: pin.Model
    data: pin.Data
    point: np.ndarray
    world: np.ndarray
    to_measuring: np.ndarray
    rot_w: np.ndarray
    d_omega: np.ndarray
    j_point: np.ndarray
    sag: SagState | None
    caches: dict[str, Any]
    frame_rotation: np.ndarray
    moving: np.ndarray
    selector: np.ndarray
    tangent: np.ndarray | None = None


class PoseFamily(Effect):
    """An effect with a pose-model face: a parameter family of absolute-pose models. Hooks
    default to contributing nothing.

    Class attributes: :attr:`family_kind` (one of :data:`FAMILY_KINDS`), :attr:`family_scale`
    (typical size of a parameter, SI; scales the regressor's columns); its parameters are never
    negative (lower bound 0) where :attr:`Effect.nonnegative`.
    """

    family_kind: ClassVar[str] = "geometric"
    family_scale: ClassVar[float] = 1e-3
    #: whether the family stands in for gravity's torque (masses unknown): the springs then
    #: carry only the applied wrench's known torque
    lumps_gravity: ClassVar[bool] = False
    #: whether the family needs the links' masses (gravity's torque known)
    needs_masses: ClassVar[bool] = False
    #: families that must be in the model with this one
    requires: ClassVar[tuple[str, ...]] = ()
    #: whether its parameters are, per joint or link, its deflection effect's own, judged by
    #: that effect's :meth:`~stiffness.elastic.effects.base.Effect.physical_scale`
    sized_as_effect: ClassVar[bool] = False
    #: whether the family at zero is absent rather than the nominal robot: an elastic family (a
    #: rigid arm) or one that turns gravity (a level base), whose size the other families'
    #: columns depend on (identifiability judges them with it present,
    #: :meth:`stiffness.calibration.identifiability.Layout.representative`). A geometric
    #: correction at zero is the nominal geometry: at a typical 1 mrad a joint placement error
    #: would tell apart parameters that parallel axes make one.
    absent_at_zero: ClassVar[bool] = False
    #: the largest of its lengths (m parameters) a calibration corrects, as a fraction of the
    #: robot's reach (:mod:`stiffness.calibration.pose_plausibility`); ``None``: not judged
    #: (the measuring frame is free, the marker offsets are judged whole)
    plausible_reach_fraction: ClassVar[float | None] = None
    #: the largest of its angles (rad parameters) a calibration corrects (rad,
    #: :mod:`stiffness.calibration.pose_plausibility`); ``None``: not judged (the measuring
    #: frame's rotation is free, a probe's mounting turn is the mounting check's)
    plausible_angle_rad: ClassVar[float | None] = None

    def plausible_lengths(self, pm: PoseLayout) -> np.ndarray | None:
        """The largest value (m) each of its parameters may take as a physical error (what a
        machined robot is off its drawing by, far below a wrong unit's
        :attr:`plausible_reach_fraction`), in :meth:`family_parameters`' order, NaN for a
        parameter not so judged; ``None`` (this default): none is
        (:mod:`stiffness.calibration.pose_plausibility`)."""
        return None

    def family_parameters(self, pm: PoseLayout) -> list[FamilyParameter]:
        """The family's parameters, in column order."""
        raise NotImplementedError

    @classmethod
    def campaign_settings(cls, torques: np.ndarray, pm: PoseLayout) -> dict:
        """Fixed settings the family takes from a campaign (SI), given the (rows, nv) torques
        the joints carry at its commanded poses under the nominal robot; none by default."""
        return {}

    def physical_sizes(self, pm: PoseLayout, refs: References) -> np.ndarray:
        """The physical scale (SI) of each parameter, in :meth:`family_parameters`' order:
        beyond it a value is not physical on this campaign, and an interval wider than it
        leaves the parameter undetermined (:mod:`stiffness.calibration.naming`). This
        default: the effect's own scale, repeated over the joints or links, where
        :attr:`sized_as_effect` (the scale the deflection campaigns judge them by), else
        :data:`POSE_PHYSICAL_FACTOR` times the typical size (0.1 m, 0.1 rad)."""
        n = len(self.family_parameters(pm))
        if self.sized_as_effect:
            return np.resize(self.physical_scale(refs), n)
        return np.full(n, POSE_PHYSICAL_FACTOR * self.family_scale)

    def param(self, label: str, unit: str) -> FamilyParameter:
        """A parameter of this family with its typical size and lower bound."""
        return FamilyParameter(self.name, label, self.family_scale, unit,
                               0.0 if self.nonnegative else -math.inf)

    # --- prediction hooks ---------------------------------------------------------------
    def configuration_offset(self, pm: PoseLayout, x_f: np.ndarray) -> np.ndarray | None:
        """A parameter-given shift of the commanded configuration (nv,), or ``None``."""
        return None

    def perturb_model(self, pm: PoseLayout, x_f: np.ndarray, model: pin.Model) -> None:
        """Change ``model``'s geometry in place (the geometric families that have one)."""

    def at_configuration(self, pm: PoseLayout, model: pin.Model, data: pin.Data,
                         q: np.ndarray) -> Any:
        """Per-family quantities at a batch (n, nq) of configurations of the sag, with a
        leading row axis (kept in :class:`SagState`)."""
        return None

    def joint_torque(self, pm: PoseLayout, x_f: np.ndarray, state: SagState) -> np.ndarray | None:
        """A torque (nv,) the family adds to what the joints' springs carry, or ``None``."""
        return None

    def joint_deflection(self, pm: PoseLayout, x_f: np.ndarray, state: SagState
                         ) -> np.ndarray | None:
        """The family's part (nv,) of the joints' deflection ``Delta q``, or ``None``."""
        return None

    def deflection_per_torque(self, pm: PoseLayout, x_f: np.ndarray, state: SagState
                              ) -> np.ndarray | None:
        """d(its joint deflection)/d(torque) (nv,), diagonal, or ``None``."""
        return None

    def rows_cache(self, pm: PoseLayout, x_f: np.ndarray, model: pin.Model,
                   kin: JointPlacements, rows: list[RowTerms], jacobian: bool) -> Any:
        """Quantities shared by the markers of each of a batch of ``rows`` at their loaded
        configurations (the joints' placements ``kin``, with a leading row axis; their
        Jacobians too when ``jacobian``, whether the columns will be asked for)."""
        return None

    def marker_displacement(self, pm: PoseLayout, x_f: np.ndarray, view: MarkerView
                            ) -> np.ndarray | None:
        """A displacement (3,) of the marker in robot-world axes (a link bend), or ``None``."""
        return None

    def columns(self, pm: PoseLayout, x_f: np.ndarray, view: MarkerView) -> np.ndarray:
        """d y / d x_f (3, n_f) of one marker on one row, measuring axes, the loaded
        configuration held fixed."""
        raise NotImplementedError


class JointDeflectionFamily(PoseFamily):
    """An elastic family acting through the joints' deflection ``Delta q`` (and torque).

    Its columns follow from the chain rule at the loaded configuration:
    ``d y / d x_f = T J_p (d Delta q / d x_f + diag(d Delta q / d tau) d tau / d x_f)``
    with ``T`` to measuring axes and ``J_p`` the marker's point Jacobian.
    """

    family_kind: ClassVar[str] = "elastic"
    family_scale: ClassVar[float] = 1e-6
    absent_at_zero: ClassVar[bool] = True

    def deflection_columns(self, pm: PoseLayout, x_f: np.ndarray, state: SagState
                           ) -> np.ndarray | None:
        """d(Delta q)/d x_f (nv, n_f) at fixed torque, or ``None``."""
        return None

    def torque_columns(self, pm: PoseLayout, x_f: np.ndarray, state: SagState
                       ) -> np.ndarray | None:
        """d(torque)/d x_f (nv, n_f), or ``None``."""
        return None

    def columns(self, pm: PoseLayout, x_f: np.ndarray, view: MarkerView) -> np.ndarray:
        n_f = x_f.size
        if view.sag is None:
            return np.zeros(view.point.shape + (n_f,))
        total = np.zeros(view.sag.torque.shape + (n_f,))
        own = self.deflection_columns(pm, x_f, view.sag)
        if own is not None:
            total += own
        torque = self.torque_columns(pm, x_f, view.sag)
        if torque is not None:
            total += view.sag.per_torque[..., None] * torque
        return view.to_measuring @ (view.j_point @ total)
