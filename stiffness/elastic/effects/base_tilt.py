"""``base_tilt``, a family of the pose model: the robot's base is not level, so gravity is not
along its ``-z`` axis (docs/absolute-poses.md).

A rigid turn of the whole robot is the measuring frame's (``frame``); what the tilt changes is
every gravity torque. With the base's z axis turned from the upward vertical by the rotation
``R(omega) = exp([r_x, r_y, 0])`` (rad; a rotation about z is no tilt), the gravity the links
feel, in the robot's base axes, is

``g_b = R(omega)^T g_0``,

``g_0`` the robot file's gravity (``-9.81 m/s^2`` along z). ``omega`` is a declared, measured
tilt (setting :data:`DECLARED_TILT`, kept in the model file; zero when none is declared) plus the
family's parameters ``(r_x, r_y)``. The sag ``Delta q = C tau`` then sees
``tau = J_load^T w + M J_com(q)^T g_b`` (``M J_com^T g`` is minus the generalised gravity, linear
in ``g``), so ``d tau / d(r_x, r_y) = M J_com(q)^T [g_b]x J_r(omega)[:, :2]`` (``J_r`` the right
Jacobian of ``exp`` on SO(3): ``R(omega + d) ~ R(omega) exp(J_r d)``), and the columns are
``T J_p diag(d Delta q / d tau) d tau / d(r_x, r_y)`` at the loaded configuration, as every
family acting through the joints' torque, plus the bends' change: the weight's moment at a bend
``m_b (c_b - p_b) x g_b`` turns with ``g_b``, so a marker beyond moves by
``-[x - p_b]x sum_i c_i e_i e_i^T [m_b (c_b - p_b)]x dg``
(:func:`~stiffness.elastic.effects.link_bends.gravity_slope`, for ``link_compliance`` and
``transversal_compliance``).

Units: SI (rad, m/s^2).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
import pinocchio as pin

from stiffness.batch.poses import JointPlacements, mass_jacobians
from stiffness.elastic.effects.geometry import skew
from stiffness.elastic.effects.kinematic_errors import DEFLECTION_OFFSET_RAD
from stiffness.elastic.effects.link_bends import BendCache, gravity_slope
from stiffness.elastic.effects.pose_face import (
    FamilyParameter,
    JointDeflectionFamily,
    MarkerView,
    PoseLayout,
    RowTerms,
)
from stiffness.errors import StiffnessError

#: Model setting: a declared (measured) tilt ``(r_x, r_y)`` of the base (rad), applied to every
#: model of the campaign whether ``base_tilt`` is fitted or not.
DECLARED_TILT = "base_tilt_rad"


def declared_tilt(settings: dict) -> np.ndarray:
    """The declared tilt ``(r_x, r_y)`` (rad) of a model's ``settings`` (zero when none).

    Raises
    ------
    StiffnessError
        A declared tilt that is not two finite numbers.
    """
    given = settings.get(DECLARED_TILT)
    if given is None:
        return np.zeros(2)
    try:
        tilt = np.asarray(given, dtype=float)
    except (TypeError, ValueError):
        tilt = np.full(1, np.nan)
    if tilt.shape != (2,) or not np.all(np.isfinite(tilt)):
        raise StiffnessError(f"{DECLARED_TILT} must be two finite angles (r_x, r_y) in rad, "
                             f"got {given!r}")
    return tilt


def tilted_gravity(gravity: np.ndarray, tilt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gravity in the tilted base's axes ``g_b = exp([r_x, r_y, 0])^T g_0`` (m/s^2) and its
    derivative (3, 2) with respect to ``(r_x, r_y)``: ``[g_b]x J_r(omega)[:, :2]``."""
    omega = np.array([tilt[0], tilt[1], 0.0])
    g_b = pin.exp3(omega).T @ np.asarray(gravity, dtype=float)
    return g_b, skew(g_b) @ pin.Jexp3(omega)[:, :2]


class BaseTilt(JointDeflectionFamily):
    """``base_tilt``: the two angles ``(r_x, r_y)`` (rad) between the base's z axis and the
    upward vertical, beyond any declared tilt; acts through every gravity torque. A family of
    the pose model (no deflection face, as the kinematic errors: a deflection campaign's
    loaded-minus-unloaded difference does not see the weight's direction)."""

    name: ClassVar[str] = "base_tilt"
    family_kind: ClassVar[str] = "geometric"
    family_scale: ClassVar[float] = 1e-3
    needs_masses: ClassVar[bool] = True
    #: a level base is the absent tilt (a vertical base joint carries gravity's torque only
    #: once the base is tilted), as the elastic families' rigid arm
    absent_at_zero: ClassVar[bool] = True
    #: a floor is level to a degree: a tilt beyond a few degrees more than the declared one
    #: (:data:`DECLARED_TILT`) is a mounting not declared (a wall or ceiling), or gravity
    #: taking what the model misses
    plausible_angle_rad: ClassVar[float | None] = DEFLECTION_OFFSET_RAD

    def family_parameters(self, pm: PoseLayout) -> list[FamilyParameter]:
        return [self.param("base tilt rx", "rad"), self.param("base tilt ry", "rad")]

    def perturb_model(self, pm: PoseLayout, x_f: np.ndarray, model: pin.Model) -> None:
        """Gravity turned by the declared tilt plus ``x_f`` (the model's gravity is the robot's,
        the declared tilt applied: :meth:`PoseModel.perturbed_model`)."""
        g_0 = np.asarray(pm.robot.model.gravity.linear, dtype=float)
        g_b, _ = tilted_gravity(g_0, declared_tilt(pm.settings) + x_f)
        model.gravity = pin.Motion(g_b, np.zeros(3))

    def rows_cache(self, pm: PoseLayout, x_f: np.ndarray, model: pin.Model,
                   kin: JointPlacements, rows: list[RowTerms], jacobian: bool
                   ) -> tuple[np.ndarray, np.ndarray] | None:
        """With the Jacobian: d tau / d(r_x, r_y) (n, 1, nv, 2) at each row's loaded
        configuration (``M J_com^T dg``, :func:`~stiffness.batch.poses.mass_jacobians`) and
        ``dg`` = d g_b / d(r_x, r_y) (3, 2) at the tilt."""
        if not jacobian:
            return None
        g_0 = np.asarray(pm.robot.model.gravity.linear, dtype=float)
        dg = tilted_gravity(g_0, declared_tilt(pm.settings) + x_f)[1]
        return (np.swapaxes(mass_jacobians(model, kin), 1, 2) @ dg)[:, None], dg

    def columns(self, pm: PoseLayout, x_f: np.ndarray, view: MarkerView) -> np.ndarray:
        """``T (J_p diag(d Delta q / d tau) d tau / d(r_x, r_y) + d bends / d g  dg)``: the
        joints' sag and the bends (:func:`~stiffness.elastic.effects.link_bends.gravity_slope`
        of every bend family in the model) under the turned gravity."""
        if view.sag is None:
            return np.zeros(view.point.shape + (2,))
        torque, dg = view.caches[self.name]
        if view.tangent is not None:  # through closed loops: T^T d tau
            torque = np.swapaxes(view.tangent, -1, -2)[:, None] @ torque
        dq = view.sag.per_torque[..., None] * torque
        bends = sum((gravity_slope(cache, view) for cache in view.caches.values()
                     if isinstance(cache, BendCache)), np.zeros(view.point.shape + (3,)))
        return view.to_measuring @ (view.j_point @ dq + bends @ dg)
