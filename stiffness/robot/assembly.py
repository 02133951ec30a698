"""Assembly search: a closed configuration near a pose whose loops do not close.

When the passive joints alone cannot close the loops from a pose (the zero pose of a CAD export
is often not assembled), :func:`least_squares_assembly` moves *all* free joints (independent and
passive) by damped Gauss-Newton (Levenberg-Marquardt: small steps, so the result stays near
the pose) until the loop residual vanishes; the caller then restores the requested
independent values and closes over the passive joints from there.

Assembly modes: the continuation of :meth:`stiffness.robot.robot.Robot.configuration` keeps the
sign of the passive constraint Jacobian's determinant
(:meth:`~stiffness.robot.loops.LoopClosure.mode_determinant`). Where a step changes it,
:func:`locate_crossing` tells a pass through a singular pose (the branch goes on
continuously, as a parallelogram through its flat pose) from a jump onto the other assembly
mode across a gap (the path passed near a parallel singularity, where the two modes come
close: the step is then refused and shortened).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from stiffness.robot import kinematics
from stiffness.robot.loops import CLOSURE_TOLERANCE_M, SINGULAR_RATIO, LoopClosure

#: Iterations of the all-joint least squares.
MAX_ITERATIONS = 400
#: Width (rad or m, along the coordinate path) to which a change of the mode sign is located.
CROSSING_WIDTH = 1e-9
#: Largest change of the passive joints (rad or m) across that width for the branch to count
#: as continuous (a pass through a singular pose) rather than a jump to another mode.
CONTINUOUS_JUMP = 1e-6
#: Most trials of :func:`locate_crossing` (it needs about ten through a singular pose).
_LOCATE_ITERATIONS = 80


@dataclass
class Assembly:
    """A closed configuration and how it was found.

    Attributes
    ----------
    q
        Full configuration (loops closed).
    residual
        Norm of the loop residual at ``q`` (m; rad for 6D rotation rows).
    idle_passive_motions
        Number of passive motions the constraints leave undetermined at ``q`` (they do not
        move the target).
    assembly_search
        Whether the all-joint least-squares search was needed.
    singular_crossings
        Coordinates (rad or m) at which the path from the reference assembly went through a
        singular pose of the loops (the sign of the passive Jacobian's determinant changes
        there, the branch going straight on, as the SK120's parallelogram through its flat
        pose); empty when the closure kept the reference assembly mode all the way.
    """

    q: np.ndarray
    residual: float
    idle_passive_motions: int
    assembly_search: bool
    singular_crossings: tuple[tuple[float, ...], ...] = ()

    def as_dict(self) -> dict:
        """The JSON ``closure`` object of ``kx``."""
        return {"residual": self.residual, "idle_passive_motions": self.idle_passive_motions,
                "assembly_search": self.assembly_search,
                "singular_crossings": [list(c) for c in self.singular_crossings]}

    def notes(self) -> list[str]:
        """One line per singular pose the closure passed through (none when it kept the
        reference assembly mode)."""
        return [f"closing the loops from the reference assembly passed through a singular pose "
                f"at coordinates {np.round(c, 6).tolist()} (rad or m), where two assembly "
                "modes meet; beyond it they are on the branch that goes straight on (as a "
                "parallelogram through its flat pose), not the reference's mode; give --q on "
                "the near side of that pose for the reference mode"
                for c in self.singular_crossings]


def locate_crossing(model: pin.Model, data: pin.Data, loop: LoopClosure,
                    close_at: Callable[[float, np.ndarray], np.ndarray | None],
                    passive_q: np.ndarray, start: tuple[float, np.ndarray],
                    end: tuple[float, np.ndarray], span: float,
                    basis: tuple[np.ndarray, np.ndarray]) -> tuple[str, float]:
    """What happened in a continuation step whose end has the other mode sign.

    Locates the change of sign of the mode determinant
    (:meth:`~stiffness.robot.loops.LoopClosure.mode_determinant`, in ``basis``, the step
    start's or, when the step starts on a singular pose, the last one before it: then the
    crossing is there) within
    :data:`CROSSING_WIDTH` (``span`` is the path's largest coordinate change, rad
    or m) by the Illinois variant of regula falsi, closing each trial from the configuration
    interpolated between the bracket's ends with ``close_at(fraction, guess)`` (None when it
    does not close).

    Returns
    -------
    verdict, fraction
        ``"crossing"``: the passive joints change by at most :data:`CONTINUOUS_JUMP` across
        the change and a singular value of the passive Jacobian vanishes there
        (:data:`~stiffness.robot.loops.SINGULAR_RATIO`): a pass through a singular pose at
        ``fraction`` of the path (the step stands); ``"same"``: continuous, but nothing
        vanishes (the basis had turned; the step stands); ``"jump"``: the passive joints jump
        there (or a trial does not close, or lands off the chord): the step hopped to another
        assembly mode and must be shortened.
    """
    (fa, qa), (fb, qb) = start, end
    kinematics.update_first_order(model, data, qa)
    ga, here = loop.mode_determinant(model, data, basis)
    if here is basis:  # the step starts on a singular pose, where the modes meet
        return "crossing", fa
    kinematics.update_first_order(model, data, qb)
    gb, kept = loop.mode_determinant(model, data, basis)[0], 0
    for _ in range(_LOCATE_ITERATIONS):
        if (fb - fa) * span <= CROSSING_WIDTH:
            break
        part = min(max(ga / (ga - gb), 0.01), 0.99)  # regula falsi, kept inside the bracket
        fm = fa + (fb - fa) * part
        guess = pin.interpolate(model, qa, qb, part)
        qm = close_at(fm, guess)
        if qm is None:
            return "jump", fm
        chord = float(np.max(np.abs(qb[passive_q] - qa[passive_q]), initial=0.0))
        if float(np.max(np.abs(qm[passive_q] - guess[passive_q]), initial=0.0)) \
                > 0.5 * chord + CONTINUOUS_JUMP:
            return "jump", fm
        kinematics.update_first_order(model, data, qm)
        gm = loop.mode_determinant(model, data, basis)[0]
        if gm > 0:
            fa, qa, ga = fm, qm, gm
            gb, kept = (gb / 2.0 if kept == 1 else gb), 1  # Illinois: b kept twice
        else:
            fb, qb, gb = fm, qm, gm
            ga, kept = (ga / 2.0 if kept == -1 else ga), -1
    if float(np.max(np.abs(qb[passive_q] - qa[passive_q]), initial=0.0)) > CONTINUOUS_JUMP:
        return "jump", fa
    rank = basis[1].shape[1]
    ratios = []
    for q in (qa, qb):
        kinematics.update_first_order(model, data, q)
        sv = np.linalg.svd(loop.jacobian(model, data)[:, loop.passive_v], compute_uv=False)
        ratios.append(sv[rank - 1] / sv[0] if rank else 1.0)
    return ("crossing" if min(ratios) <= SINGULAR_RATIO else "same"), fa


def least_squares_assembly(model: pin.Model, data: pin.Data, loop: LoopClosure, q: np.ndarray,
                           free_v: np.ndarray, follow: Callable[[np.ndarray], np.ndarray]
                           ) -> tuple[np.ndarray, float]:
    """Minimise the loop residual over the velocity coordinates ``free_v`` from ``q``.

    ``follow`` re-applies dependent joints (mimic followers) after each step. Returns the
    configuration reached and its residual norm.
    """
    q = follow(q.copy())
    kinematics.update_first_order(model, data, q)
    c = loop.residual(model, data)
    cost = float(c @ c)
    damping = 1e-6
    for _ in range(MAX_ITERATIONS):
        if np.sqrt(cost) < CLOSURE_TOLERANCE_M:
            break
        jac = loop.jacobian(model, data)[:, free_v]
        # damped Gauss-Newton step (J^T J + mu I) dq = -J^T c: small, minimum-norm-like steps
        # that also converge to a least-squares minimum whose residual is not zero
        step = -np.linalg.solve(jac.T @ jac + damping * np.eye(jac.shape[1]), jac.T @ c)
        norm = float(np.linalg.norm(step))
        if norm > 0.5:
            step *= 0.5 / norm
        dv = np.zeros(model.nv)
        dv[free_v] = step
        trial = follow(pin.integrate(model, q, dv))
        kinematics.update_first_order(model, data, trial)
        c_trial = loop.residual(model, data)
        cost_trial = float(c_trial @ c_trial)
        if cost_trial < cost:
            q, c, cost = trial, c_trial, cost_trial
            damping = max(damping / 3.0, 1e-12)
        else:
            damping *= 10.0
            if damping > 1e8:
                break
            kinematics.update_first_order(model, data, q)
    kinematics.update_first_order(model, data, q)
    return q, float(np.linalg.norm(loop.residual(model, data)))
