"""A pose model's analytic Jacobian columns against central differences (one copy for the pose
test files): the step is the parameter's scale for an elastic family (its columns are
linear in the compliance near zero) and 1 % of it for a geometric one."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from stiffness.calibration.pose_model import Loads, PoseModel
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


def loaded_rows(robot, markers, rng: np.random.Generator, n: int = 3):
    """The tool loads (none recorded), the nominal model of ``markers`` and ``n`` rows at
    coordinates uniform in +-0.8 (rad, m) under random wrenches (100 N, 10 N.m per axis std)."""
    loads = Loads("tool", np.zeros((0, 6)))
    nominal = PoseModel(robot, markers, (), (np.eye(3), np.zeros(3)), loads)
    rows = [nominal.row_terms(robot.configuration(rng.uniform(-0.8, 0.8, robot.n_coordinates)),
                              rng.normal(size=6) * np.r_[100.0, 100.0, 100.0, 10.0, 10.0, 10.0])
            for _ in range(n)]
    return loads, nominal, rows
