"""Assembly search: a closed configuration near a pose whose loops do not close.

When the passive joints alone cannot close the loops from a pose (the zero pose of a CAD export
is often not assembled), :func:`least_squares_assembly` moves *all* free joints (independent and
passive) by damped Gauss-Newton (Levenberg-Marquardt: small steps, so the result stays near
the pose) until the loop residual vanishes; the caller then restores the requested
independent values and closes over the passive joints from there.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from stiffness.robot import kinematics
from stiffness.robot.loops import CLOSURE_TOLERANCE_M, LoopClosure, LoopPair

#: Iterations of the all-joint least squares.
MAX_ITERATIONS = 400


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
        pose); empty when the closure kept the reference assembly mode all the way
        (:mod:`stiffness.robot.continuation`).
    mode_checked
        False when the straight path from the reference assembly met a fold of the loops and
        the assembly search found this one near the coordinates: its assembly mode is then not
        known to be the reference's.
    """

    q: np.ndarray
    residual: float
    idle_passive_motions: int
    assembly_search: bool
    singular_crossings: tuple[tuple[float, ...], ...] = ()
    mode_checked: bool = True

    def as_dict(self) -> dict:
        """The JSON ``closure`` object of ``kx``."""
        return {"residual": self.residual, "idle_passive_motions": self.idle_passive_motions,
                "assembly_search": self.assembly_search,
                "singular_crossings": [list(c) for c in self.singular_crossings],
                "mode_checked": self.mode_checked}

    def notes(self) -> list[str]:
        """One line per singular pose the closure passed through, and one when the mode was
        not checked (none when it kept the reference assembly mode)."""
        unchecked = [] if self.mode_checked else [
            "the straight path from the reference assembly meets a fold of the loops before "
            "these coordinates; the assembly the assembly search found near them is not "
            "checked to be in the reference assembly mode (it may be another one)"]
        return unchecked + [
            f"closing the loops from the reference assembly went through a singular pose of "
            f"the loops at coordinates {np.round(c, 6).tolist()} (rad or m), where two assembly "
            "modes meet; beyond it the loops are on the branch that goes straight on (as a "
            "parallelogram through its flat pose), the other sign of the passive Jacobian's "
            "determinant" for c in self.singular_crossings]


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


def _names(pairs: list[LoopPair]) -> str:
    """Up to four pairs as ``[a, b]``, then how many more."""
    shown = ", ".join(f"[{p.frame_a}, {p.frame_b}]" for p in pairs[:4])
    return shown + (f" and {len(pairs) - 4} more" if len(pairs) > 4 else "")


def assembly_diagnosis(model: pin.Model, data: pin.Data, loop: LoopClosure, q: np.ndarray,
                       free_v: np.ndarray, follow: Callable[[np.ndarray], np.ndarray]) -> str:
    """What in the loop file keeps the assembly search from closing the loops near ``q``: a
    clause for the error naming the pairs and the fix.

    Each pair is closed alone by :func:`least_squares_assembly` over ``free_v``, and, a "6D"
    pair (a weld), also as "3D" (the frames' origins meeting). A pair that cannot meet even
    alone names the loop file's frames (or the URDF's path between them); a "6D" pair that
    closes only as "3D" is a ball or pin closure typed as a weld (Gepetto's ``generateYAML``
    writes every pair "6D"); when every pair closes alone, all of them taken as "3D" are tried
    together.
    """
    def closes(pairs: tuple[LoopPair, ...]) -> bool:
        points = loop.retyped(model, pairs)
        found = least_squares_assembly(model, data, points, q, free_v, follow)[1]
        return found <= 1e3 * CLOSURE_TOLERANCE_M

    def as_point(pair: LoopPair) -> LoopPair:
        return LoopPair(pair.frame_a, pair.frame_b, "3D")

    apart = [p for p in loop.pairs if not closes((as_point(p),))]
    if apart:
        return (f"the frames of {_names(apart)} cannot meet even with that loop alone: the "
                "loop file pairs frames no joint path brings together (or the URDF lacks a "
                "joint on that path)")
    welds = [p for p in loop.pairs if p.kind == "6D" and not closes((p,))]
    if not welds and not (any(p.kind == "6D" for p in loop.pairs)
                          and closes(tuple(map(as_point, loop.pairs)))):
        return "each loop closes alone but not all together: check the loop file's frame pairs"
    named = f" ({_names(welds)} cannot close as welds even alone)" if welds else ""
    return (f"the loops close with the 6d pairs typed 3d (frames whose origins meet), not as "
            f"declared{named}: type the ball and pin closures 3d in the loop file")
