"""A robust pose fit in bounded memory (issue 37 item 6): its trust-region steps run on the
factor of the loss-reweighted Jacobian accumulated over blocks of rows, its sandwich
covariance on the factor of the plain one. Checked here, with blocks of 7 rows, against the
dense Jacobian computed here: the M-estimator's equation, scipy's robust fit of the dense
problem, Huber's sandwich and the flagged poses' standardised residuals."""

from __future__ import annotations

import numpy as np
import pytest
from pose_campaigns import ur10_tip_campaign
from scipy.optimize import least_squares

from stiffness.calibration import pose_orientation
from stiffness.calibration.pose_fit import (
    fit_pose_model,
    flag_pose_outliers,
    layout,
    rows_of,
    starting_frame,
)
from stiffness.calibration.pose_model import PoseModel
from stiffness.calibration.pose_orientation import PoseObservations

FAMILIES = ["frame", "markers", "joint_offsets", "geometry", "joint_compliance"]
MOVED = {4: np.array([0.6, -0.8, 0.0]), 17: np.array([0.0, 0.6, 0.8])}  # row: direction
SIZE = 40.0  # noise stds the moved markers are off by


def _huber(r: np.ndarray, s: float) -> tuple[np.ndarray, np.ndarray]:
    """psi = d phi / d r and d psi / d r of phi(r) = s^2 rho((r / s)^2) / 2, scipy's huber."""
    inside = np.abs(r) <= s
    return np.where(inside, r, s * np.sign(r)), np.where(inside, 1.0, 0.0)


def test_a_robust_fit_in_blocks_is_the_dense_fit(monkeypatch):
    """40 UR10 poses under a 300 N payload, one marker, 2 of them moved by 40 noise stds,
    huber at the declared noise (31 parameters kept), the campaign evaluated 7 rows at a time
    (6 blocks)."""
    campaign = ur10_tip_campaign(40, payload_n=300.0)
    for row, d in MOVED.items():
        campaign.positions[row, 0] += SIZE * campaign.noise_std * d
    monkeypatch.setattr(pose_orientation, "ROW_BLOCK", 7)
    model = PoseModel(campaign.robot, campaign.markers, tuple(FAMILIES),
                      starting_frame(campaign), campaign.loads)
    rows = rows_of(model, campaign)
    least = fit_pose_model(model, campaign, rows, FAMILIES)
    fit = fit_pose_model(model, campaign, rows, FAMILIES, loss="huber")
    kept, s = fit.identifiability.kept, campaign.noise_std
    assert fit.at_bound == [] and fit.sigma == s and fit.factor.shape[0] <= len(kept) + 1

    def dense(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r, j = PoseObservations(model, campaign, rows).evaluate(x)
        return r, j[:, kept]

    r, j = dense(fit.x)
    n, k = j.shape
    # the M-estimator's equation J^T psi(r) = 0, to the solver's tolerance (2e-7 of its
    # value at least squares' optimum)
    scales = layout(model, FAMILIES).scales[kept]
    psi, dpsi = _huber(r, s)
    r0, j0 = dense(least.x)
    assert (np.linalg.norm(scales * (j.T @ psi))
            < 1e-6 * np.linalg.norm(scales * (j0.T @ _huber(r0, s)[0])))
    # scipy's robust fit of the dense problem, from least squares' optimum
    lower = np.array([model.parameters[i].lower for i in kept])

    def full(z: np.ndarray) -> np.ndarray:
        x = least.x.copy()
        x[kept] = z
        return x

    ref = least_squares(lambda z: dense(full(z))[0], least.x[kept],
                        jac=lambda z: dense(full(z))[1], bounds=(lower, np.inf),
                        loss="huber", f_scale=s, x_scale=scales, xtol=1e-12, ftol=1e-12,
                        gtol=1e-12)
    std = np.sqrt(np.diag(fit.covariance))
    assert np.max(np.abs(ref.x - fit.x[kept]) / std) < 1e-6
    # Huber's sandwich A^-1 B A^-1 with its small-sample factor, from the dense Jacobian
    a = np.mean(dpsi) * j.T @ j
    b = np.sum(psi ** 2) / (n - k) * j.T @ j
    factor = 1.0 + k / n * np.var(dpsi) / np.mean(dpsi) ** 2
    sandwich = factor ** 2 * np.linalg.solve(a, np.linalg.solve(a, b).T)
    np.testing.assert_allclose(fit.covariance, sandwich, rtol=1e-8,
                               atol=1e-10 * np.abs(sandwich).max())
    # the moved poses flagged, alone, standardised by the dense hat matrix's leverages
    flags, sigma = flag_pose_outliers(fit, campaign)
    assert sigma == s and sorted(o.row - 1 for o in flags) == sorted(MOVED)
    h = np.einsum("ij,ij->i", j, np.linalg.solve(j.T @ j, j.T).T)
    for o in flags:
        c = o.row - 1
        axis = 3 * c + "xyz".index(o.component.split("_")[1])
        assert o.standardised_residual == pytest.approx(r[axis] / (s * np.sqrt(1 - h[axis])),
                                                        rel=1e-8)
