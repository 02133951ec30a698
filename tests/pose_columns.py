"""A pose model's analytic Jacobian columns against central differences (one copy for the pose
test files): the step is the parameter's scale for an elastic family (its columns are
linear in the compliance near zero) and 1 % of it for a geometric one."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from stiffness.elastic.effects import FAMILIES


def assert_columns(model, rows, x: np.ndarray, scales: np.ndarray, tol: float,
                   columns: Iterable[int] | None = None) -> None:
    """Each of ``columns`` (default all) of ``model.evaluate``'s Jacobian at ``x`` equals the
    central difference to ``tol`` relative to the largest difference (at least 1e-3 m)."""
    _, jac = model.evaluate(x, rows)
    assert jac is not None
    for c in range(model.size) if columns is None else columns:
        elastic = FAMILIES[model.parameters[c].family].family_kind == "elastic"
        h = (1.0 if elastic else 1e-2) * scales[c]
        e = np.zeros(model.size)
        e[c] = h
        fd = (model.evaluate(x + e, rows, False)[0] - model.evaluate(x - e, rows, False)[0]) / (
            2 * h)
        assert np.abs(jac[..., c] - fd).max() <= tol * max(np.abs(fd).max(), 1e-3), \
            model.parameters[c].label
