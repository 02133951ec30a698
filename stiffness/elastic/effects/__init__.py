"""The effect library: what a model of an elastic robot may miss, one class per effect.

Each effect is one class in a module of its family: joint laws
(:mod:`~stiffness.elastic.effects.joint_laws`), link bends
(:mod:`~stiffness.elastic.effects.link_bends`), preloads
(:mod:`~stiffness.elastic.effects.preloads`), the target and the measurement
(:mod:`~stiffness.elastic.effects.measurement`), the kinematic errors
(:mod:`~stiffness.elastic.effects.kinematic_errors`), all subclasses of
:class:`~stiffness.elastic.effects.base.Effect`. A class carries its prediction in a deflection
campaign's fit (:class:`~stiffness.elastic.effects.hypothesis.Hypothesis`, through its deflection
face, :class:`~stiffness.elastic.effects.deflection_face.DeflectionEffect`), its contribution to
a model used away from its campaign (:meth:`Effect.contribute` into an
:class:`~stiffness.elastic.effects.parts.ElasticParts`) and, where it is a parameter family of
an absolute-pose model, its pose face (:class:`~stiffness.elastic.effects.pose_face.PoseFamily`
hooks). Adding an effect is one class, listed in :data:`EFFECTS` (and in the view of the
campaign kinds it serves: :data:`LIBRARY`, :data:`FAMILIES`), and its test.

The deflection campaigns' library (:data:`LIBRARY`):

``complementary_stiffness``
    Load-dependent geometry: ``K_C`` in the tangent stiffness *and* the second-order kinematics
    of the deflection, ``dx = J dtheta + 1/2 sum_k e_k dtheta^T H_k dtheta`` with ``dtheta`` the
    fixed point of ``dtheta = K^-1 (J^T W + K_C(W) dtheta)``. This is the exact elastostatic
    equilibrium to second order in the deflection (the error is third order: ``dtheta^3 L``).
    No parameter.
``joint_compliance`` (where: a joint)
    A joint declared rigid is a spring; parameter its stiffness ``k`` (N.m/rad or N/m).
``link_compliance`` (where: ``a->b``, two joints of the target's chain)
    The segment between the origins of joints ``a`` and ``b`` bends: a lumped rotational
    compliance about the two axes normal to the segment, at ``b``'s origin ``p_b``. The moment
    there is ``(x_t - p_b) x F + M``; the part of the robot beyond ``p_b`` turns rigidly by
    ``omega = sum_i e_i (e_i . M_b) / k_i``, the target moves by ``omega x (x_t - p_b)``.
    Parameters the stiffnesses ``k_1, k_2`` (N.m/rad) about ``e_1, e_2`` (:func:`link_axes`).
    In a closed loop the rotation is taken as in a serial chain (the loop's reaction to it is
    neglected).
``transversal_compliance`` (where: a compliant revolute joint of the target's chain)
    The joint tilts in its bearing at its origin ``p_j`` about the two axes ``e_1, e_2`` of its
    mounting frame normal to its rotation axis (:func:`~.geometry.tilt_axes`): under the moment
    ``M_j = (x_t - p_j) x F + M`` the part beyond turns by ``omega = sum_i e_i (e_i . M_j) /
    k_i`` and the target moves by ``omega x (x_t - p_j)``. Parameters the tilting stiffnesses
    ``k_1, k_2`` (N.m/rad). Where the segment ending at the joint lies along its axis the
    same two axes bend ``link_compliance``: identifiability reports the two merged.
``backlash`` (where: a compliant joint)
    Lost motion: ``dtheta_j += b tanh(tau_j / tau_s)``, a dead band of half-width ``b`` (rad)
    smoothed over ``tau_s`` = :data:`BACKLASH_SMOOTHING` times the joint's RMS torque over the
    campaign (so it acts like ``b sign(tau_j)`` for all but the smallest torques).
``nonlinear_joint_stiffness`` (where: a compliant joint)
    ``dtheta_j = tau_j / k_j (1 + beta |tau_j|)``: ``beta > 0`` softens, ``beta < 0`` hardens
    (1/(N.m)); reported also as the relative change of compliance at the largest torque.
``frame_misalignment``
    The instrument's frame is rotated against the robot base: measured
    ``dx = R(phi) dx_model`` (rotation vector ``phi``, rad).
``target_offset``
    The target (where the load acts and the deflection is measured) is displaced by ``delta``
    (m, target frame axes) from where the campaign says: ``J_v -> J_v - [R_t delta]x J_w``.
``force_sensor_bias``
    The recorded force carries a constant offset ``b`` (N): the applied force is
    ``F_recorded - b``.
``deflection_offset``
    The measured deflections carry a constant offset ``d`` (m) (the unloaded reference moved,
    an instrument zero drift).
``gravity_preload``
    The links' weight (URDF inertias) and a payload (mass kg, centre of mass m in target frame
    axes) preload the joints (:meth:`DeflectionEffect.preload`): the deflection is the loaded
    minus the unloaded equilibrium at the commanded pose (open chains only).
``gravity_lumped`` (``--masses unknown``, instead of ``gravity_preload``)
    The links' weight with their masses unknown: each weighed link's mass and mass moments
    (kg, kg.m) fitted through the gravity regressor
    (:func:`stiffness.batch.poses.gravity_regressors`), on the chain's springs or a
    ``[controller]``'s; not applied to a model used away from its campaign.
``gravity_compensator`` (where: a revolute compliant joint)
    A spring between the base and a lever on the link, its angle measured from the link's
    upward direction at zero load (:func:`stiffness.mechanics.gravity.compensator_torque`;
    parameters its stiffness N/m and its tension N with the link straight up): its torque
    preloads the joint, its angle derivative adds to the joint's stiffness.
``joint_offsets``
    The joints' zero offsets ``delta_0`` (rad, m): the loaded and unloaded tool are at
    ``q + delta_0``, seen to first order through the Jacobian there,
    ``J -> J + sum_j delta_j dJ/dq_j`` in the load's torques and the output (a second-order
    effect: an offset times the deflection); one parameter per chain joint whose offset moves
    the rows' Jacobian (open chains without a controller map).

The pose model's families (:data:`FAMILIES`, in column order; docs/absolute-poses.md):
``frame``, ``markers``, ``joint_offsets``, ``geometry`` (geometric:
:mod:`~stiffness.elastic.effects.kinematic_errors`); ``base_tilt`` (geometric, through every
gravity torque: :mod:`~stiffness.elastic.effects.base_tilt`); ``joint_compliance``,
``gravity_lumped`` (masses unknown), ``link_compliance``, ``backlash``,
``nonlinear_joint_stiffness``, ``gravity_compensator`` (elastic, the same classes as the
deflection effects of those names); ``transversal_compliance`` (elastic, a joint tilting in its
bearing: :mod:`~stiffness.elastic.effects.link_bends`, also a deflection effect).
``base_tilt``, ``link_compliance``, ``transversal_compliance``, ``backlash`` and
``nonlinear_joint_stiffness`` need the links' masses (not with ``gravity_lumped``);
``gravity_compensator`` and ``nonlinear_joint_stiffness`` act through ``joint_compliance``.

Units: SI inside (m, N, rad, N.m/rad).
"""

from __future__ import annotations

from stiffness.elastic.effects.base import Effect
from stiffness.elastic.effects.base_tilt import BaseTilt
from stiffness.elastic.effects.deflection_face import DeflectionEffect
from stiffness.elastic.effects.geometry import Geometry
from stiffness.elastic.effects.hypothesis import Hypothesis
from stiffness.elastic.effects.joint_laws import (
    Backlash,
    ComplementaryStiffness,
    JointCompliance,
    NonlinearJointStiffness,
)
from stiffness.elastic.effects.kinematic_errors import (
    JointGeometry,
    JointOffsets,
    MarkerOffsets,
    MeasuringFrame,
)
from stiffness.elastic.effects.link_bends import LinkCompliance, TransversalCompliance
from stiffness.elastic.effects.measurement import (
    DeflectionOffset,
    ForceSensorBias,
    FrameMisalignment,
    TargetOffset,
)
from stiffness.elastic.effects.pose_face import PoseFamily
from stiffness.elastic.effects.preloads import GravityCompensator, GravityLumped, GravityPreload
from stiffness.errors import StiffnessError, UnknownEffectError, did_you_mean

#: Every effect of the library: name -> class. The effects with a pose face come in the order
#: a pose model lays out their columns (:data:`FAMILIES`).
EFFECTS: dict[str, type[Effect]] = {
    cls.name: cls for cls in (MeasuringFrame, MarkerOffsets, JointOffsets, JointGeometry,
                              BaseTilt, ComplementaryStiffness, JointCompliance, GravityLumped,
                              LinkCompliance, TransversalCompliance, Backlash,
                              NonlinearJointStiffness,
                              FrameMisalignment, TargetOffset, ForceSensorBias, DeflectionOffset,
                              GravityPreload, GravityCompensator)
}
#: The effects a deflection campaign may miss: name -> class, in the order candidates are
#: listed.
LIBRARY: dict[str, type[DeflectionEffect]] = {
    cls.name: cls for cls in (ComplementaryStiffness, JointCompliance, LinkCompliance,
                              TransversalCompliance, Backlash, NonlinearJointStiffness,
                              FrameMisalignment, TargetOffset, ForceSensorBias, DeflectionOffset,
                              GravityPreload, GravityLumped, GravityCompensator, JointOffsets)
}
#: The parameter families of an absolute-pose model, the effects with a pose face: name ->
#: class, in the order the columns are laid out.
FAMILIES: dict[str, type[PoseFamily]] = {
    name: cls for name, cls in EFFECTS.items() if issubclass(cls, PoseFamily)
}
#: What a campaign's robot's link masses are: ``known`` (the URDF's inertias: the weight is
#: ``gravity_preload``) or ``unknown`` (``gravity_lumped`` fits their gravity parameters).
MASSES = ("known", "unknown")


def check_masses(masses: str) -> None:
    """Refuse a ``masses`` not in :data:`MASSES` (one line)."""
    if masses not in MASSES:
        raise StiffnessError(f"masses must be one of {', '.join(MASSES)}, got {masses!r}")


def make_effect(name: str, where: str | None, geometry: Geometry) -> DeflectionEffect:
    """An effect by name and place, checked against the robot (:meth:`Effect.at_place`).

    Raises
    ------
    UnknownEffectError
        Unknown name.
    UnknownJointError, UnknownNameError
        A missing or unknown joint or link segment in ``where``.
    StiffnessError
        A ``where`` on an effect that acts on the whole campaign.
    """
    if name not in LIBRARY:
        raise UnknownEffectError(f"unknown effect {name!r}; {did_you_mean(name, list(LIBRARY))}",
                                 name=name, choices=list(LIBRARY))
    return LIBRARY[name].at_place(where, geometry)


def candidates(model: Hypothesis, declared: dict[str, dict] | None = None,
               masses: str = "known") -> list[DeflectionEffect]:
    """Every library effect that can extend ``model`` (each effect and place at most once).

    ``complementary_stiffness``; ``joint_compliance`` of each rigid coordinate joint;
    ``link_compliance`` of each chain segment (:meth:`Geometry.link_segments`);
    ``transversal_compliance`` of each revolute chain joint a compliant spring turns (the
    joint, or the chain joints a controller coordinate drives:
    :meth:`~stiffness.robot.robot.Robot.driven_joints`) whose axis is a frame axis
    (:attr:`Geometry.tilt_columns`); ``backlash`` and ``nonlinear_joint_stiffness`` of each
    compliant joint; then the global effects, the weight as ``gravity_preload`` with the
    ``masses`` known, else ``gravity_lumped`` (:data:`MASSES`); ``gravity_compensator`` of
    each revolute compliant joint carrying one link (not a controller coordinate that turns
    several chain joints: :meth:`JointEffect.placement_problem`); ``joint_offsets`` of the
    coordinates whose offset changes the rows' Jacobian (:meth:`JointOffsets.on_rows`). An
    effect whose label ``declared`` names takes those settings
    (:meth:`DeflectionEffect.declare`).
    """
    geo = model.geometry
    have = {e.label for e in model.effects}
    out: list[DeflectionEffect] = []

    def add(effect: DeflectionEffect) -> None:
        if effect.label not in have:
            out.append(effect.declare(declared[effect.label]) if declared
                       and effect.label in declared else effect)

    if not model.second_order:
        add(ComplementaryStiffness())
    for j in geo.joints:
        if j not in model.joints:
            add(make_effect("joint_compliance", j, geo))
    for a, b in geo.link_segments():
        add(LinkCompliance(a=a, b=b, column=geo.link_columns[(a, b)]))
    for j in geo.robot.driven_joints(model.joints):
        if j in geo.tilt_columns:
            add(TransversalCompliance(a=j, b=j, column=geo.tilt_columns[j]))
    for j in model.joints:
        add(make_effect("backlash", j, geo))
        add(make_effect("nonlinear_joint_stiffness", j, geo))
    for name in ("frame_misalignment", "target_offset", "force_sensor_bias",
                 "deflection_offset"):
        add(LIBRARY[name]())
    if geo.robot.loop.is_open_chain:  # the weight of passive loop joints is not modelled
        add(make_effect("gravity_preload" if masses == "known" else "gravity_lumped", None,
                        geo))
    for j in model.joints:
        if not (geo.prismatic[geo.joints.index(j)]
                or GravityCompensator.placement_problem(geo.robot, j)):
            add(make_effect("gravity_compensator", j, geo))
    offsets = JointOffsets.at_place(None, geo).on_rows(model, model.rows)
    if offsets.joints:
        add(offsets)
    return out
