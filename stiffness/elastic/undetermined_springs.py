"""What a model file's user is told of the springs its campaign did not determine
(``undetermined_joints``): that ``K_X`` in the directions they govern rests on an unidentified
value, or, for a spring a diagnosis found not told apart from an effect's parameter
(``confounded_joints``, issue 35: a link bend about an axis nearly the joint's), what takes its
share and that its ``k_theta`` is where the fit left it, not a measurement.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from stiffness.elastic.effects.base import Parameter, confounded_note


def confounded_joints(stiffness: Sequence[Parameter]) -> dict:
    """The model file's ``confounded_joints`` of a diagnosis's final joint ``stiffness``: each
    spring :meth:`~stiffness.elastic.effects.base.Parameter.confounded_as` by joint, with
    ``confounded_with`` (parameter, correlation) and ``note``, the text report's phrase
    (:func:`~stiffness.elastic.effects.base.confounded_note`); empty when none."""
    return {p.name: {"confounded_with": p.to_dict()["confounded_with"],
                     "note": confounded_note(p.confounded_with, p.value, p.unit)}
            for p in stiffness if p.confounded_with}


def undetermined_notes(joints: Sequence[str], confounded: object,
                       rigid: Mapping[str, tuple[float, float]] | None = None) -> list[str]:
    """One warning per kind of undetermined spring of a model file: ``joints`` (its
    ``undetermined_joints``) not loaded by the campaign, then those ``rigid`` to it, then each
    one ``confounded`` (its ``confounded_joints``, :func:`confounded_joints`; absent in older
    files) names with its note. A ``confounded`` entry without a text ``note`` is read as
    plainly undetermined.

    Parameters
    ----------
    rigid
        Joint -> (the file's stiffness, its 95 % interval's lower end) for the undetermined
        springs whose interval has no upper end: the campaign loaded them but cannot tell them
        from rigid, so the file's value (where the fit stopped: 1.8e5 N.m/rad, or 4e19 at the
        compliance's zero bound) is no measurement, only the lower end is. Until 6 December
        2026 they were said not to be loaded by their campaign.
    """
    given = confounded if isinstance(confounded, dict) else {}
    notes = {j: given[j]["note"] for j in joints
             if isinstance(given.get(j), dict) and isinstance(given[j].get("note"), str)}
    stiff = {j: v for j, v in (rigid or {}).items() if j in joints and j not in notes}
    plain = [j for j in joints if j not in notes and j not in stiff]
    return ([f"the stiffness of {', '.join(plain)} is marked undetermined (its campaign did "
             "not load it): K_X in the directions it governs rests on an unidentified value"]
            if plain else []) + ([
                f"the stiffness of {', '.join(stiff)} is bounded by its campaign only from "
                "below (stiffer than "
                f"{', '.join(f'{low:.3g}' for _, low in stiff.values())} SI at 95 %, perhaps "
                f"rigid): the file's {', '.join(f'{k:.3g}' for k, _ in stiff.values())} is "
                "where the fit stopped, not a measurement; K_X in the directions it governs "
                "rests on it"]
                if stiff else []) + [f"the stiffness of {j} is marked undetermined: {note}"
                                     for j, note in notes.items()]


def rigid_springs(joints: Sequence[str], k_theta: np.ndarray, ci95_low: np.ndarray | None,
                  ci95_high: np.ndarray | None) -> dict[str, tuple[float, float]]:
    """Joint -> (the file's stiffness, its 95 % interval's lower end) of a model file's springs
    whose interval has a finite lower end and no upper end (:func:`undetermined_notes`'s
    ``rigid``): the campaign cannot tell them from rigid."""
    lows, highs = (np.full(len(joints), np.nan) if v is None else v
                   for v in (ci95_low, ci95_high))
    return {j: (float(k), float(low)) for j, k, low, high in zip(
        joints, k_theta, lows, highs, strict=True)
        if math.isfinite(low) and not math.isfinite(high)}


def undetermined_labels(joints: Sequence[str], rigid: Mapping[str, tuple[float, float]]
                        ) -> dict[str, str]:
    """What an echo of a model file's K_theta prints instead of the value of each of its
    ``joints`` (its ``undetermined_joints``): ``rigid (held, not determined; stiffer than
    8.88e+04 at 95 %)`` for one ``rigid`` to its campaign (:func:`rigid_springs`; no lower end
    when the file has none), else ``undetermined (not a measurement)``. The value (where the fit
    stopped, up to 3.9e19 at a compliance's zero bound) is never echoed as a stiffness."""
    def said(joint: str) -> str:
        if joint not in rigid:
            return "undetermined (not a measurement)"
        low = rigid[joint][1]
        return ("rigid (held, not determined" + (f"; stiffer than {low:.3g} at 95 %)"
                                                  if low > 0 else ")"))
    return {j: said(j) for j in joints}
