"""Closing the loops along a straight coordinate path, in one assembly mode.

:class:`Continuation` carries a closed configuration from one set of coordinates to another
(:meth:`stiffness.robot.robot.Robot.configuration` starts it from the reference assembly):
predictor (tangent, then secant) and Newton corrector on the passive joints, with steps halved
when the corrector has to move far (a hop to another branch).

Assembly modes: along the path it keeps the sign of the passive constraint Jacobian's
determinant (:meth:`~stiffness.robot.loops.LoopClosure.mode_determinant`), which vanishes only
at a parallel (type-2) singularity, where two modes meet. Where a step changes it,
:func:`locate_crossing` tells a jump onto the other mode across a gap (the path passed near
such a pose, where the modes come close: the step is refused and shortened) from a pass
through the singular pose itself, where the branch goes straight on, as the SK120's
parallelogram through its flat pose, into the other sign, and the pose is reported.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NoReturn

import numpy as np
import pinocchio as pin

from stiffness.errors import LoopClosureError
from stiffness.robot import kinematics
from stiffness.robot.loops import SINGULAR_RATIO, LoopClosure

#: Largest joint step (rad or m) of the continuation.
CONTINUATION_STEP = 0.15
#: Largest Newton correction of the passive joints (rad or m) accepted in one step.
BRANCH_JUMP = 0.05
#: Width (rad or m, along the coordinate path) to which a change of the mode sign is located.
CROSSING_WIDTH = 1e-9
#: Largest change of the passive joints (rad or m) across that width for the branch to count
#: as continuous (a pass through a singular pose) rather than a jump to another mode.
CONTINUOUS_JUMP = 1e-6
#: Newton iterations of a continuation step's corrector: from the predictor a step closes in
#: three to ten (digit_like: 648 of 690 closes); a corrector still short of the tolerance then
#: is near a fold or hopping branches, and the step is shortened as for a failed closure
#: (before, 50: the 11 of 20 digit_like poses that meet a fold cost 2400 iterations each).
CORRECTOR_ITERATIONS = 12
#: Most trials of :func:`locate_crossing` (it needs about ten through a singular pose).
_LOCATE_ITERATIONS = 80
#: Newton iterations of a trial of :func:`locate_crossing` (from the interpolated
#: configuration a continuous branch closes in two to four; slower means a jump).
_LOCATE_NEWTON = 10

#: A basis of :meth:`~stiffness.robot.loops.LoopClosure.passive_basis`.
Basis = tuple[np.ndarray, np.ndarray]


@dataclass
class Continuation:
    """The loops of one robot, closed along straight coordinate paths.

    ``tree_configuration(coords, q)`` sets the coordinates (rad or m) in ``q`` (mimic followers
    included); ``passive_q`` are the configuration indices of the passive joints; ``title()``
    names the robot in an error (only read then: it may look at files).
    """

    model: pin.Model
    data: pin.Data
    loop: LoopClosure
    coordinate_v: np.ndarray
    tree_configuration: Callable[[np.ndarray, np.ndarray], np.ndarray]
    passive_q: np.ndarray
    title: Callable[[], str]

    def close_at(self, start: np.ndarray, coords: np.ndarray, part: float,
                 guess: np.ndarray, iterations: int = 50) -> np.ndarray | None:
        """The loops closed at ``part`` of the path from ``start`` to ``coords``, from
        ``guess`` (None when they do not close within ``iterations`` Newton steps)."""
        try:
            return self.loop.close(self.model, self.data, self.tree_configuration(
                start + (coords - start) * part, guess), iterations)
        except LoopClosureError:
            return None

    def run(self, start: np.ndarray, q: np.ndarray, coords: np.ndarray
            ) -> tuple[np.ndarray, list[tuple[float, ...]]]:
        """Close the loops from ``start`` (closed at ``q``) to ``coords``, in ``q``'s mode.

        Returns the closed configuration and the coordinates (rad or m) of the singular poses
        passed through (see the module).

        Raises
        ------
        LoopClosureError
            When the path meets a fold of the loop (the pose is unreachable on the branch).
        """
        model, data, loop, pq = self.model, self.data, self.loop, self.passive_q
        span = _largest(coords - start)
        if span == 0.0:
            return loop.close(model, data, self.tree_configuration(coords, q)), []
        nominal = min(1.0, CONTINUATION_STEP / span)
        fraction, h = 0.0, nominal
        previous: tuple[np.ndarray, float] | None = None
        crossings: list[tuple[float, ...]] = []
        kinematics.update_first_order(model, data, q)
        jacobian = loop.jacobian(model, data)
        basis = loop.passive_basis(model, data, jacobian)
        rates = loop.passive_rates(model, data, self.coordinate_v, jacobian)  # tangent at q
        while fraction < 1.0 - 1e-12:
            h = min(h, 1.0 - fraction)
            if previous is None:  # the first step, from the start
                dv = np.zeros(model.nv)
                dv[self.coordinate_v] = (coords - start) * h
                dv[loop.passive_v] = rates @ dv[self.coordinate_v]
                predicted = pin.integrate(model, q, dv)
            else:
                predicted = q.copy()
                q_prev, h_prev = previous
                predicted[pq] += (q[pq] - q_prev[pq]) * h / h_prev
                predicted = pin.normalize(model, predicted)  # quaternions of ball joints
            closed = self.close_at(start, coords, fraction + h, predicted,
                                   CORRECTOR_ITERATIONS)
            jump = np.inf if closed is None else _largest(closed[pq] - predicted[pq])
            if closed is not None and jump <= BRANCH_JUMP:
                closed, here, crossing = self._mode_check(
                    start, coords, (fraction, q), (fraction + h, closed), basis)
                if closed is None:  # onto another assembly mode: not taken; the step is cut
                    jump, h = np.inf, h / 4.0  # by 8 (with the halving below): the modes swap
                elif crossing is not None:
                    crossings.append(crossing)
            if closed is None or jump > BRANCH_JUMP:
                h /= 2.0
                if h < 1e-9:
                    self._fold(start, coords, self.tree_configuration(
                        start + (coords - start) * (fraction + h), predicted))
                continue
            previous = (q, h)
            q, fraction, basis = closed, fraction + h, here
            h = min(2.0 * h, nominal)
        return q, crossings

    def _mode_check(self, start: np.ndarray, coords: np.ndarray,
                    before: tuple[float, np.ndarray], after: tuple[float, np.ndarray],
                    basis: Basis) -> tuple[np.ndarray | None, Basis, tuple[float, ...] | None]:
        """A step's end, checked for its assembly mode (data current at the end).

        Returns the configuration to take (None: a jump onto another mode, refused), the basis
        there and the coordinates of the singular pose passed through (or None).
        """
        model, data, loop = self.model, self.data, self.loop
        closed = after[1]
        sign, here = loop.mode_determinant(model, data, basis)
        if sign >= 0:
            return closed, here, None
        verdict, part = locate_crossing(
            model, data, loop, lambda f, g: self.close_at(start, coords, f, g, _LOCATE_NEWTON),
            self.passive_q,
            before, after, _largest(coords - start), basis)
        if verdict == "jump":
            return None, basis, None
        crossing = None
        if verdict == "crossing":
            crossing = tuple((start + (coords - start) * part).tolist())
        kinematics.update_first_order(model, data, closed)
        return closed, loop.mode_determinant(model, data, basis)[1], crossing

    def _fold(self, start: np.ndarray, coords: np.ndarray, q: np.ndarray) -> NoReturn:
        """Raise the :class:`LoopClosureError` of a path stopped at ``q`` by a fold."""
        kinematics.update_first_order(self.model, self.data, q)
        name, worst = max(self.loop.loop_residuals(self.model, self.data),
                          key=lambda item: item[1])
        raise LoopClosureError(
            f"the loops of {self.title()} cannot be closed continuously from "
            f"coordinates {np.round(start, 6).tolist()} to "
            f"{np.round(coords, 6).tolist()}: the "
            "path meets a fold of the loop (the pose is unreachable on this branch)",
            loop=name, residual=worst)


def locate_crossing(model: pin.Model, data: pin.Data, loop: LoopClosure,
                    close_at: Callable[[float, np.ndarray], np.ndarray | None],
                    passive_q: np.ndarray, start: tuple[float, np.ndarray],
                    end: tuple[float, np.ndarray], span: float,
                    basis: Basis) -> tuple[str, float]:
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
    width, chord = fb - fa, _largest(qb[passive_q] - qa[passive_q])
    for _ in range(_LOCATE_ITERATIONS):
        if (fb - fa) * span <= CROSSING_WIDTH:
            break
        if fb - fa < 1e-3 * width and _largest(qb[passive_q] - qa[passive_q]) > 0.5 * chord:
            return "jump", fa  # a thousand times narrower and the joints still jump
        part = min(max(ga / (ga - gb), 0.01), 0.99)  # regula falsi, kept inside the bracket
        fm = fa + (fb - fa) * part
        guess = pin.interpolate(model, qa, qb, part)
        qm = close_at(fm, guess)
        if qm is None:
            return "jump", fm
        chord = _largest(qb[passive_q] - qa[passive_q])
        if _largest(qm[passive_q] - guess[passive_q]) \
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
    if _largest(qb[passive_q] - qa[passive_q]) > CONTINUOUS_JUMP:
        return "jump", fa
    rank = basis[1].shape[1]
    ratios = []
    for q in (qa, qb):
        kinematics.update_first_order(model, data, q)
        sv = np.linalg.svd(loop.jacobian(model, data)[:, loop.passive_v], compute_uv=False)
        ratios.append(sv[rank - 1] / sv[0] if rank else 1.0)
    return ("crossing" if min(ratios) <= SINGULAR_RATIO else "same"), fa


def _largest(change: np.ndarray) -> float:
    """Largest absolute entry of ``change`` (0 when empty)."""
    return float(np.abs(change).max(initial=0.0))
