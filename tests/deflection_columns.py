"""A deflection hypothesis's analytic Jacobian columns against central differences of its
whole prediction (one copy for the deflection test files)."""

from __future__ import annotations

import numpy as np


def assert_columns(model, x: np.ndarray, step: float = 1e-5, tol: float = 1e-6) -> None:
    """``model.predict_with_jacobian``'s prediction equals ``model.predict`` and each of its
    columns at ``x`` equals the central difference of ``model.predict`` (step ``step`` in each
    variable) to ``tol`` relative to the largest difference, which must not vanish."""
    pred, jac = model.predict_with_jacobian(x)
    np.testing.assert_allclose(pred, model.predict(x), rtol=1e-12, atol=1e-18)
    for i in range(x.size):
        up, down = x.copy(), x.copy()
        up[i] += step
        down[i] -= step
        central = (model.predict(up) - model.predict(down)) / (2 * step)
        scale = np.abs(central).max()
        assert scale > 0
        assert np.abs(jac[:, :, i] - central).max() < tol * scale, i
