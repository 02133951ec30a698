"""Pose calibration on several processes and with one BLAS thread (issue 37 items 4 and 6):
cross-validation folds fitted in forked workers give the in-process held-out RMS exactly, and
the pose fit runs its linear algebra on a single BLAS thread, the caller's setting restored."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from threadpoolctl import threadpool_info

from stiffness.calibration.pose_diagnose import _cv_rms, _fit
from stiffness.calibration.pose_fit import campaign_settings, starting_frame
from stiffness.calibration.pose_model import Marker
from stiffness.calibration.selection import config_folds
from stiffness.cores import fork_workers, one_blas_thread
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.robot import load_robot


def _campaign():
    robot = load_robot("ur10", frame="tool0")
    rng = np.random.default_rng(3)
    markers = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05]))]
    n = robot.n_coordinates
    hidden = HiddenPoseErrors(pin.exp3(rng.normal(size=3)), rng.uniform(-1, 1, 3),
                              np.array([[0.0, 0.03, 0.05]]) + 1e-3, rng.normal(0, 1e-3, n),
                              np.zeros((n, 6)), None)
    return simulate_pose_campaign(robot, markers, hidden, 24, 20e-6, seed=3)


def test_folds_on_workers_match_in_process():
    """Six folds of a 24-pose campaign with hidden zero offsets, fitted in two forked workers
    and in this process: the same held-out RMS to the last bit, at the noise."""
    if fork_workers(2, 6) < 2:
        pytest.skip("forking is unsafe here (another thread runs, or not Linux)")
    c = _campaign()
    families = ["frame", "markers", "joint_offsets"]
    frame0 = starting_frame(c)
    fit = _fit(c, families, frame0, campaign_settings(c))
    folds = config_folds(tuple(c.labels), 0)
    here = _cv_rms(c, fit, families, frame0, folds)
    assert _cv_rms(c, fit, families, frame0, folds, workers=2) == here
    assert 10e-6 < here < 40e-6


def test_one_blas_thread_restores_the_callers_setting():
    def threads() -> list[int]:
        return [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]

    before = threads()
    assert one_blas_thread(threads)() == [1] * len(before)
    assert threads() == before
