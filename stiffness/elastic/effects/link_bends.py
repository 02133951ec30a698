"""Link bends: ``link_compliance``, a lumped bending of the segment between two joints of the
target's chain (:class:`LinkCompliance`).

The segment ``a -> b`` bends at ``b``'s origin ``p_b`` about the two axes normal to it
(:func:`stiffness.elastic.effects.geometry.link_axes`); the moment there is
``(x_t - p_b) x F + M``, the part beyond ``p_b`` turns by ``omega = sum_i e_i (e_i . M_b) / k_i``
and the target moves by ``omega x (x_t - p_b)``.

Units: SI (m, N, N.m/rad).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from stiffness.elastic.effects.base import Effect, stiffness_report
from stiffness.elastic.effects.geometry import link_axes
from stiffness.errors import StiffnessError, UnknownNameError


def segment(where: str | None) -> tuple[str, str] | None:
    """The two joints of a segment ``A->B`` (or ``A/B``, ``A,B``), or ``None``."""
    for sep in ("->", "/", ","):
        if where and sep in where:
            parts = [s.strip() for s in where.split(sep)]
            return (parts[0], parts[1]) if len(parts) == 2 else None
    return None


@dataclass(eq=False)
class LinkCompliance(Effect):
    """Lumped bending of the segment ``a -> b`` at ``b``'s origin, about two normal axes."""

    a: str = ""
    b: str = ""
    column: int = 0
    name: ClassVar[str] = "link_compliance"
    param_names: ClassVar[tuple[str, ...]] = ("stiffness_1", "stiffness_2")
    beyond_springs: ClassVar[bool] = True
    value_counts: ClassVar[tuple[int, ...]] = (1, 2)

    @classmethod
    def at_place(cls, where, geometry):
        parts = segment(where)
        if parts is None or parts not in geometry.link_columns:
            pairs = [f"{a}->{b}" for a, b in geometry.link_segments()]
            raise UnknownNameError(
                f"link_compliance needs two joints of the target's chain, proximal first, as "
                f"A->B (or A/B); got {where!r}; valid segments: {', '.join(pairs)}",
                name=str(where), choices=pairs)
        return cls(a=parts[0], b=parts[1], column=geometry.link_columns[parts])

    @classmethod
    def declared(cls, where, settings):
        a, b = cls.place_joints(where)
        return cls(a=a, b=b)  # the bend axes come from the robot (ElasticModel)

    @classmethod
    def place_joints(cls, where):
        parts = segment(where)
        if parts is None:
            raise StiffnessError(f"link_compliance needs a segment A->B, got {where!r}")
        return list(parts)

    def simulated_values(self, values, units):
        k = np.array([values[0], values[0]] if len(values) == 1 else values, dtype=float)
        if np.any(k <= 0):
            raise StiffnessError(f"link_compliance:{self.where} needs positive stiffnesses")
        return k

    def contribute(self, values, parts):
        parts.add_bend(self.a, self.b, values[0], values[1])

    @property
    def where(self) -> str:
        return f"{self.a}->{self.b}"

    def bounds(self):
        return np.zeros(2), np.full(2, 1e4)

    def start(self):
        return np.full(2, 1e-3)

    def scale(self, refs):
        return np.full(2, 1.0 / refs.k_ref)

    def variables(self, values, refs):
        return (1.0 / np.asarray(values, dtype=float)[:2]) / self.scale(refs)

    def _omega(self, p, model, rows, force, moment, point):
        ia, ib = model.geometry.chain.index(self.a), model.geometry.chain.index(self.b)
        p_a, p_b = rows.chain_origin[:, ia], rows.chain_origin[:, ib]
        e1, e2 = link_axes(p_a, p_b, rows.chain_rotation[:, ib], self.column)
        r = point - p_b
        m_b = np.cross(r, force) + moment
        omega = (e1 * (p[0] * np.sum(e1 * m_b, axis=1))[:, None]
                 + e2 * (p[1] * np.sum(e2 * m_b, axis=1))[:, None])
        return omega, r

    def displacement(self, p, model, rows, force, moment, point):
        omega, r = self._omega(p, model, rows, force, moment, point)
        return np.cross(omega, r)

    def rotation(self, p, model, rows, force, moment, point):
        return self._omega(p, model, rows, force, moment, point)[0]

    def report(self, u, cov_u, refs, units, quantile):
        return [stiffness_report(n, float(u[i]), float(cov_u[i, i]), 1.0 / refs.k_ref,
                                  "N.m/rad", quantile)
                for i, n in enumerate(self.param_names)]

    def describe(self) -> str:
        return (f"the segment {self.a} -> {self.b} bends at {self.b} about the two axes "
                "normal to it")
