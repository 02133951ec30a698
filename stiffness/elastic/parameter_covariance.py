"""The covariance of a model file's fitted parameters (key ``parameter_covariance``), what
``stiffness validate`` needs to tell a model's own uncertainty from what it misses.

Both kinds of model file carry it (docs/model-file.md, docs/absolute-poses.md), in the order of
the file's parameters and labelled, SI:

* a deflection model file (``identify``, ``diagnose``): ``ln k`` of each ``k_theta`` joint (k
  in its unit; the fit's own variable), then each effect's parameters in the file's order, a
  stiffness parameter (:attr:`~stiffness.elastic.effects.base.Effect.compliance_variables`)
  as its compliance ``1 / value`` (the reciprocal of its unit: the predicted deflection is
  linear in it) and the others as their SI value; the labels are ``ln k_theta(joint)``,
  ``1/effect(where).name`` and ``effect(where).name``;
* a pose calibration's ``final-model.json``: its fitted parameters (``parameters[].fitted``)
  in the table's order, each in its own unit (``parameters[].unit``), labelled by
  ``parameters[].parameter``.

``matrix`` is ``null`` where the fit did not determine a variable (held at its nominal value,
or along a direction the data do not see: an infinite variance, read back as ``inf``);
``noise_std_m`` is the translation noise std (m) the covariance was computed with.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from stiffness.elastic.effects.deflection_face import DeflectionEffect

#: The model files' key.
KEY = "parameter_covariance"
#: What a deflection model file's variables are (its ``variables`` line).
DEFLECTION_VARIABLES = ("SI: ln k of each k_theta joint (k in its unit), then each effect's "
                        "parameters in the file's order, a stiffness as its compliance "
                        "1/value, the others their value; null: not determined by the fit")
#: What a pose calibration's variables are.
POSE_VARIABLES = ("SI: the fitted parameters (parameters[].fitted) in the table's order, each "
                  "in its own unit; null: not determined by the fit")


@dataclass
class ParameterCovariance:
    """The covariance of a model's fitted parameters (module docstring).

    Attributes
    ----------
    labels, units
        Each variable's label and unit, in the file's parameter order.
    matrix
        (p, p) covariance in those units; ``inf`` where not determined.
    noise_std_m
        The translation noise std (m) the fit's covariance is for, or ``None``.
    variables
        One line saying what the variables are (:data:`DEFLECTION_VARIABLES`,
        :data:`POSE_VARIABLES`).
    """

    labels: tuple[str, ...]
    units: tuple[str, ...]
    matrix: np.ndarray
    noise_std_m: float | None = None
    variables: str = DEFLECTION_VARIABLES

    def __post_init__(self) -> None:
        self.labels, self.units = tuple(self.labels), tuple(self.units)
        self.matrix = np.asarray(self.matrix, dtype=float).reshape(len(self.labels),
                                                                   len(self.labels))

    def to_dict(self) -> dict:
        """The file's object: ``variables``, ``labels``, ``units``, ``matrix`` (rows, ``null``
        where infinite), ``noise_std_m``."""
        return {"variables": self.variables, "labels": list(self.labels),
                "units": list(self.units),
                "matrix": [[None if not np.isfinite(v) else float(v) for v in row]
                           for row in self.matrix],
                "noise_std_m": self.noise_std_m}

    @classmethod
    def from_dict(cls, doc: object, fail: Callable[[str], Exception]) -> ParameterCovariance:
        """Read :meth:`to_dict`'s object; ``fail`` makes the error of a malformed one (its
        text names what is wrong)."""
        if not isinstance(doc, dict):
            raise fail(f"{KEY} must be an object with labels, units and matrix")
        labels, units, rows = doc.get("labels"), doc.get("units"), doc.get("matrix")
        if not (isinstance(labels, list) and isinstance(units, list)
                and all(isinstance(s, str) for s in labels + units)
                and len(units) == len(labels)):
            raise fail(f"{KEY}.labels and {KEY}.units must be lists of as many names")
        n = len(labels)
        if not (isinstance(rows, list) and len(rows) == n and all(
                isinstance(row, list) and len(row) == n and all(
                    v is None or (isinstance(v, int | float) and not isinstance(v, bool))
                    for v in row) for row in rows)):
            raise fail(f"{KEY}.matrix must be {n} rows of {n} numbers (null: not determined)")
        std = doc.get("noise_std_m")
        if std is not None and (not isinstance(std, int | float) or isinstance(std, bool)):
            raise fail(f"{KEY}.noise_std_m must be a number (m) or null")
        matrix = np.array([[np.inf if v is None else float(v) for v in row] for row in rows],
                          dtype=float).reshape(n, n)
        return cls(tuple(labels), tuple(units), matrix, None if std is None else float(std),
                   str(doc.get("variables", "")))

    def over(self, labels: Sequence[str]) -> tuple[np.ndarray, list[int], list[str]]:
        """The covariance of the variables ``labels`` (any order) that it determines: the
        matrix over them, their positions in ``labels``, and the labels left out (not in the
        file, or not determined: taken as known)."""
        where = {label: i for i, label in enumerate(self.labels)}
        finite = {i for i in range(len(self.labels)) if np.isfinite(self.matrix[i, i])}
        used = [k for k, label in enumerate(labels) if where.get(label) in finite]
        rows = [where[labels[k]] for k in used]
        left = [label for k, label in enumerate(labels) if k not in used]
        return self.matrix[np.ix_(rows, rows)], used, left


def stiffness_labels(joints: Sequence[str]) -> list[str]:
    """The labels of a deflection model's ``ln k`` variables."""
    return [f"ln k_theta({j})" for j in joints]


def effect_labels(effect: DeflectionEffect, units: Sequence[str]) -> tuple[list[str], list[str]]:
    """The labels and units of ``effect``'s variables in a deflection model file (its
    parameters' SI ``units``, the first :attr:`~stiffness.elastic.effects.base.Effect.n_params`
    used): ``1/label.name`` in the reciprocal unit for a compliance variable, else
    ``label.name``."""
    names = effect.parameter_names
    units = list(units)[: len(names)] + ["SI"] * (len(names) - len(units))
    if effect.compliance_variables:
        return ([f"1/{effect.label}.{n}" for n in names],
                [f"1/({u})" if u not in ("SI", "1") else u for u in units])
    return [f"{effect.label}.{n}" for n in names], units


def deflection_covariance(effects: Sequence[DeflectionEffect], joints: Sequence[str],
                          units: dict[str, list[str]], x_covariance: np.ndarray,
                          scales: np.ndarray, noise_std_m: float | None
                          ) -> ParameterCovariance:
    """A deflection fit's covariance of its variables ``x`` (``ln k`` of ``joints``, then each
    effect's scaled variables) in the model file's variables: each effect column times its
    ``scales`` (SI value of one unit of the fit's variable,
    :meth:`~stiffness.elastic.effects.base.Effect.scale` at the fit's references), 1 for
    ``ln k``; ``units`` each effect's SI parameter units by label."""
    labels, names = stiffness_labels(joints), ["1"] * len(joints)
    for e in effects:
        more, their = effect_labels(e, units.get(e.label, []))
        labels += more
        names += their
    s = np.concatenate([np.ones(len(joints)), np.asarray(scales, dtype=float)])
    with np.errstate(invalid="ignore"):
        matrix = np.where(np.isinf(x_covariance), np.inf, x_covariance * np.outer(s, s))
    return ParameterCovariance(tuple(labels), tuple(names), matrix, noise_std_m)
