"""What a diagnosis may name and how it reports it: the rules of issue 36.4, one
implementation for both campaign kinds (deflection diagnose, :mod:`stiffness.calibration.
diagnose`; pose diagnose, :mod:`stiffness.calibration.pose_diagnose`).

They act on reported parameters (:class:`~stiffness.elastic.effects.base.Parameter`), whatever
the fit behind them:

* **determined** (:attr:`Parameter.determined`): fitted, with a finite 95 % interval narrower
  than the parameter's physical scale (:func:`judged` builds a parameter with that test);
* **settled** (:func:`settle`): inside a candidate that may be named, the parameters the data
  do not determine are held at their nominal value, the least determined first (widest 95 %
  interval for its physical scale, :func:`looseness`), each time the fit redone, until the
  others are determined or one is left;
* **named** (:func:`namable`): an effect with no parameter (a switch), or with at least one
  parameter determined and its interval excluding zero;
* **at a bound** (:func:`one_sided`): a parameter the fit left at its physical bound has a
  one-sided interval from the bound and never counts as excluding zero;
* **stand-in** (:func:`is_stand_in`): a named effect with a determined parameter beyond its
  physical scale: the data prefer its shape, its size is not physical (:data:`STAND_IN_NOTE`);
* **the best alternative** of a named effect (:func:`alternative`): the best other candidate
  of the step that named it, and its BIC minus the chosen one's.

SI or the campaign's units alike: every rule compares a parameter with its own scale.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import TypeVar

import numpy as np

from stiffness.elastic.effects.base import Parameter

#: What a stand-in is, as the reports say it.
STAND_IN_NOTE = "the data prefer this shape; its size is not physical"

F = TypeVar("F")


def namable(parameters: list[Parameter]) -> bool:
    """Whether an effect with these ``parameters`` may be named: none (a switch), or at least
    one determined with a 95 % interval excluding zero."""
    return not parameters or any(p.determined and p.excludes_zero for p in parameters)


def is_stand_in(parameters: list[Parameter]) -> bool:
    """Whether a determined parameter of an effect is beyond its physical scale."""
    return any(p.determined and p.beyond_scale for p in parameters)


def looseness(p: Parameter, size: float) -> float:
    """The width of ``p``'s 95 % interval over its physical scale ``size`` (inf unbounded)."""
    width = p.ci95[1] - p.ci95[0]
    return width / size if math.isfinite(width) and size > 0 else math.inf


def held_reason(p: Parameter) -> str:
    """Why a parameter is held at its nominal value, in words (the ``held`` of the report and
    the ``note`` of its ``identifiability.dropped`` entry)."""
    why = p.scale_note if p.scale_note and not p.resolved else "its 95 % interval is unbounded"
    return f"held at its nominal value: the data do not determine it ({why}, fitted)"


def settle(fit: F, parameters: Callable[[F], list[Parameter]],
           sizes: Sequence[float] | np.ndarray,
           hold: Callable[[F, list[int], list[Parameter], list[str]], F],
           batch: Callable[[F, list[int]], list[int]] | None = None) -> F:
    """``fit`` with the parameters of one effect that the data do not determine held at their
    nominal value, the least determined first, the fit redone each time (module docstring).

    Parameters
    ----------
    parameters
        The effect's reported parameters in a fit (its interval's width against ``sizes``).
    sizes
        Each parameter's physical scale, in the units ``parameters`` reports.
    hold
        The fit redone with parameters ``k`` of the effect (reported as the parameters given)
        held at their nominal value, for the reasons given (:func:`held_reason`), as lists.
    batch
        Which of the undetermined parameters (least determined first) one refit holds: by
        default the first alone (an effect of a deflection campaign, a few parameters); a
        pose family of one parameter per joint or link holds, at each refit, the least
        determined and every other undetermined one nearly uncorrelated with those chosen, so
        that of two parameters the data confuse only the looser is held before the refit
        judges the other again.
    """
    while True:
        params = parameters(fit)
        free = [k for k, p in enumerate(params) if not p.held]
        loose = [k for k in free if not params[k].determined]
        if not loose or len(free) < 2:
            return fit
        loose.sort(key=lambda k: -looseness(params[k], float(sizes[k])))
        chosen = loose[:1] if batch is None else batch(fit, loose) or loose[:1]
        worst = chosen[:max(1, len(free) - 1)]
        fit = hold(fit, worst, [params[k] for k in worst],
                   [held_reason(params[k]) for k in worst])


def one_sided(p: Parameter, from_below: bool) -> Parameter:
    """``p`` at its physical bound: its interval one-sided from the bound (its value) to the
    interval's other end (``from_below``: the bound is its lower one)."""
    ci = (p.value, p.ci95[1]) if from_below else (p.ci95[0], p.value)
    return dataclasses.replace(p, at_bound=True, ci95=ci)


def alternative(ranking: Sequence[tuple[str, float]], chosen: str, chosen_delta: float
                ) -> tuple[str | None, float | None]:
    """The best other candidate of a step (``ranking``: (label, delta BIC), best first) and
    its BIC minus the ``chosen`` one's (its delta BIC ``chosen_delta``), or ``None``, ``None``
    when the step had no other."""
    for label, delta in ranking:
        if label != chosen:
            return label, float(delta - chosen_delta)
    return None, None
