"""What a model file's user is told of the springs its campaign did not determine
(``undetermined_joints``): that ``K_X`` in the directions they govern rests on an unidentified
value, or, for a spring a diagnosis found not told apart from an effect's parameter
(``confounded_joints``, issue 35: a link bend about an axis nearly the joint's), what takes its
share and that its ``k_theta`` is where the fit left it, not a measurement.
"""

from __future__ import annotations

from collections.abc import Sequence

from stiffness.elastic.effects.base import Parameter, confounded_note


def confounded_joints(stiffness: Sequence[Parameter]) -> dict:
    """The model file's ``confounded_joints`` of a diagnosis's final joint ``stiffness``: each
    spring :meth:`~stiffness.elastic.effects.base.Parameter.confounded_as` by joint, with
    ``confounded_with`` (parameter, correlation) and ``note``, the text report's phrase
    (:func:`~stiffness.elastic.effects.base.confounded_note`); empty when none."""
    return {p.name: {"confounded_with": p.to_dict()["confounded_with"],
                     "note": confounded_note(p.confounded_with, p.value, p.unit)}
            for p in stiffness if p.confounded_with}


def undetermined_notes(joints: Sequence[str], confounded: object) -> list[str]:
    """One warning per kind of undetermined spring of a model file: ``joints`` (its
    ``undetermined_joints``) not loaded by the campaign, then each one ``confounded`` (its
    ``confounded_joints``, :func:`confounded_joints`; absent in older files) names with its
    note. A ``confounded`` entry without a text ``note`` is read as plainly undetermined."""
    given = confounded if isinstance(confounded, dict) else {}
    notes = {j: given[j]["note"] for j in joints
             if isinstance(given.get(j), dict) and isinstance(given[j].get("note"), str)}
    plain = [j for j in joints if j not in notes]
    return ([f"the stiffness of {', '.join(plain)} is marked undetermined (its campaign did "
             "not load it): K_X in the directions it governs rests on an unidentified value"]
            if plain else []) + [f"the stiffness of {j} is marked undetermined: {note}"
                                 for j, note in notes.items()]
