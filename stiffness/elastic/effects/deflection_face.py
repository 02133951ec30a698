"""The deflection-campaign face of an effect (:class:`DeflectionEffect`): the hooks through which
an effect of the library (:data:`stiffness.elastic.effects.LIBRARY`) enters a deflection
campaign's prediction (:class:`stiffness.elastic.effects.hypothesis.Hypothesis`), with the flags
that say where its Jacobian columns are taken analytically, and what the hooks read of the
hypothesis (:class:`HypothesisArrays`); the fixed settings beside some effects' parameters, which
a deflection model file keeps and a diagnosis may free (:class:`Settings`).

Units: SI (m, N, rad, N.m/rad).
"""

from __future__ import annotations

from typing import ClassVar, Protocol

import numpy as np

from stiffness.elastic.effects.base import Effect
from stiffness.elastic.effects.geometry import Geometry, References, Rows
from stiffness.errors import StiffnessError
from stiffness.mechanics.equilibrium import SpringLaw


class HypothesisArrays(Protocol):
    """What the prediction hooks read of the hypothesis they extend
    (:class:`stiffness.elastic.effects.hypothesis.Hypothesis`): the shared geometry, the joints
    of its law and their columns, and the rows' Jacobians and ``K_C`` over those joints."""

    geometry: Geometry
    joints: tuple[str, ...]
    index: np.ndarray
    jv: np.ndarray
    jw: np.ndarray
    h: np.ndarray


class DeflectionEffect(Effect):
    """An effect with a deflection-campaign face: its part of the prediction of a campaign's
    rows, whose Jacobian columns :class:`~stiffness.elastic.effects.hypothesis.Hypothesis`
    takes analytically where :attr:`through_law`, :attr:`linear_motion` or
    :attr:`moves_jacobian` says they are affine. Hooks default to nothing: the joint's law
    (:meth:`adjust_law`), the load (:meth:`adjust_load`), the target (:meth:`target_shift`),
    the Jacobian (:meth:`jacobian_change`), an extra displacement (:meth:`target_motion`), the
    measured output (:meth:`output_map`), a preload (:meth:`preload`)."""

    #: whether the model gets ``K_C`` and the second-order kinematics
    second_order: ClassVar[bool] = False
    #: whether the effect makes its joint (:attr:`where`), rigid in the baseline, a spring
    adds_spring: ClassVar[bool] = False
    #: whether the variables enter only through the law of the joint :attr:`where`, affinely
    #: (:meth:`adjust_law` of the SI values): the model then differentiates the prediction
    #: with respect to them analytically (:meth:`Hypothesis.predict_with_jacobian`)
    through_law: ClassVar[bool] = False
    #: whether the variables enter only through :meth:`target_motion`, linearly (a bend): the
    #: model then takes their columns exactly, as the motion at unit variables
    #: (:attr:`Hypothesis.analytic_columns`)
    linear_motion: ClassVar[bool] = False
    #: whether the variables enter only through :meth:`jacobian_change`, linearly (joint zero
    #: offsets): the model then differentiates the prediction with respect to them
    #: analytically, through the torques ``J^T W`` and the output ``J dtheta``
    moves_jacobian: ClassVar[bool] = False

    def adjust_load(self, p: np.ndarray, force: np.ndarray, moment: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
        """Applied load from the recorded one."""
        return force, moment

    def target_shift(self, p: np.ndarray, rows: Rows) -> np.ndarray | None:
        """(m, 3) displacement of the true target from the declared one, world axes."""
        return None

    def adjust_law(self, p: np.ndarray, law: SpringLaw, column: int, refs: References) -> None:
        """Change the law of the model joint at ``column`` (that of :attr:`where`; called
        when :attr:`through_law`)."""

    def target_motion(self, p: np.ndarray, model: HypothesisArrays, rows: Rows,
                      force: np.ndarray, moment: np.ndarray, point: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray] | None:
        """(m, 3) extra target displacement (m) and (m, 3) extra rotation of the target frame
        (rad, base axes), or ``None``."""
        return None

    def jacobian_change(self, p: np.ndarray, model: HypothesisArrays, rows: Rows
                        ) -> np.ndarray | None:
        """(m, 6, n) change of the target Jacobian over the model's joints (:attr:`index` of
        ``model``), rows ``[v; omega]``, linear in ``p`` (called when :attr:`moves_jacobian`),
        or ``None``: it moves the load's torques ``J^T W`` and the output ``J dtheta`` alike."""
        return None

    def output_map(self, p: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
        """How the instrument reads the model's output: a rotation ``R`` (3, 3) of both the
        displacement and the rotation (``measured = R model``) and an offset (3,) m of the
        displacement, each ``None`` when absent (this default). Affine, so its derivative
        along changes ``t`` (m, 3, P) of the model's output is ``R t``."""
        return None, None

    def preload(self, p: np.ndarray, model: HypothesisArrays, rows: Rows
                ) -> tuple[np.ndarray, np.ndarray] | None:
        """A torque present at the unloaded pose: ``(tau_p (m, n), K_p (m, n, n))`` over the
        model's joints, ``K_p = d tau_p / d theta``, or ``None``. The measured deflection is
        then the loaded minus the unloaded equilibrium (:meth:`Hypothesis.predict`)."""
        return None

    def declare(self, settings: dict) -> DeflectionEffect:
        """This effect with settings its user declared (SI; ``stiffness diagnose``'s
        ``effect_settings``: a compensator's lever and base, :class:`Settings`).

        Raises
        ------
        StiffnessError
            Settings the effect does not take (this default: any).
        """
        if settings:
            raise StiffnessError(f"{self.label} takes no declared settings; drop "
                                 f"{', '.join(settings)}")
        return self


class Settings(DeflectionEffect):
    """An effect with fixed settings beside its parameters (SI: a backlash's smoothing torque,
    a compensator's geometry, the links ``gravity_lumped`` weighs); the effects without derive
    from :class:`DeflectionEffect` alone. A model file keeps them (:meth:`file_settings`) and
    reads them back (:meth:`configured`); where a user declared them
    (:meth:`DeflectionEffect.declare`: a compensator's lever and base), a fit frees them as
    further parameters (:meth:`settings_freed`) or holds them (:meth:`settings_held`)."""

    def configured(self, settings: dict) -> DeflectionEffect:
        """This effect with a model file's fixed ``settings`` (:meth:`file_settings`)."""
        raise NotImplementedError

    def file_settings(self, refs: References) -> dict:
        """Fixed settings a model file keeps beside the parameters (SI)."""
        raise NotImplementedError

    def settings_freed(self) -> DeflectionEffect | None:
        """This effect with its declared settings as further parameters, appended after
        :attr:`parameter_names` (fitted when the data determine them), or ``None`` when it has
        no such settings (this default)."""
        return None

    def settings_held(self, reason: str) -> DeflectionEffect:
        """This effect with its declared settings held, and ``reason`` (one clause: why the
        data do not determine them) recorded (an effect whose :meth:`settings_freed` frees
        some)."""
        raise NotImplementedError

