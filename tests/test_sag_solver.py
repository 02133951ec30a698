"""The pose model's sag solver (:meth:`PoseModel._loaded_rows`) against plain fixed-point
passes run to convergence with no cap: a steep lost motion's slow mode (steps shrinking by a
steady ratio) jumps to the same fixed point in fewer passes, and a sag the plain passes would
need more than ``SAG_ITERATIONS`` for is still declared diverging."""

from __future__ import annotations

import numpy as np
import pytest

from stiffness.calibration.pose_fit import campaign_settings, rows_of, starting_frame
from stiffness.calibration.pose_model import SAG_ITERATIONS, SAG_TOLERANCE, Marker, PoseModel
from stiffness.errors import ConvergenceError
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.robot import load_robot

FAMILIES = ("frame", "markers", "joint_offsets", "backlash")


@pytest.fixture(scope="module")
def backlash_model():
    arm = load_robot("xarm7")
    n = arm.n_coordinates
    hidden = HiddenPoseErrors(np.eye(3), np.array([1.0, 0.5, 0.2]), np.array([[0, 0, 0.051]]),
                              np.full(n, 5e-4), np.zeros((n, 6)), np.full(n, 3e4))
    c = simulate_pose_campaign(arm, [Marker("tip", arm.target_frame, np.array([0, 0, 0.05]))],
                               hidden, 12, 20e-6, seed=1)
    model = PoseModel(arm, c.markers, FAMILIES, starting_frame(c), c.loads,
                      campaign_settings(c))
    return model, c


def _plain(model: PoseModel, x: np.ndarray, rows) -> tuple[np.ndarray, int]:
    """The sag by plain passes ``s <- law(tau(q_c + delta_0 + s))`` from zero, every row
    until all converge (no cap but 10 000), and how many passes that took."""
    pin_model = model.perturbed_model(x)
    data = pin_model.createData()
    commanded = np.array([r.q_full for r in rows])
    offsets = model._offsets(x)
    sag = np.zeros((len(rows), pin_model.nv))
    for passes in range(1, 10_000):
        q, tangent = model._configurations(pin_model, data, commanded, offsets + sag)
        g, w = model._row_torques(pin_model, data, q, tangent, None, True)
        new = model.deflection(x, model._state(x, q, g, w, model._extras(pin_model, data, q)))
        step, sag = np.max(np.abs(new - sag)), new
        if step <= SAG_TOLERANCE:
            return sag, passes
    raise AssertionError("the plain passes do not converge")


def _solved(model: PoseModel, x: np.ndarray, rows, monkeypatch) -> tuple[np.ndarray, int]:
    """The solver's loaded configurations from a cold start and its passes."""
    passes = []
    deflection = PoseModel.deflection
    monkeypatch.setattr(PoseModel, "deflection",
                        lambda self, *a: passes.append(1) or deflection(self, *a))
    pin_model = model.perturbed_model(x)
    q, _, _ = model._loaded_rows(pin_model, pin_model.createData(), x, rows)
    monkeypatch.setattr(PoseModel, "deflection", deflection)
    return q, len(passes)


def _parameters(model: PoseModel, half_width: float) -> np.ndarray:
    x = np.zeros(model.size)
    x[model.slices()["backlash"]] = half_width
    return x


def test_slow_mode_jumps_to_the_plain_fixed_point(backlash_model, monkeypatch):
    """Backlash 0.07 rad on every spring: the plain passes need 34 (steps shrinking by a
    steady ratio on the slowest rows); the solver lands on their fixed point to the tolerance
    (3e-14 rad) in 15."""
    model, c = backlash_model
    x = _parameters(model, 0.07)
    rows = rows_of(model, c)
    sag, plain = _plain(model, x, rows)
    q, passes = _solved(model, x, rows, monkeypatch)
    commanded = np.array([r.q_full for r in rows])
    assert np.max(np.abs(q - (commanded + model._offsets(x) + sag))) < SAG_TOLERANCE
    assert passes < plain / 2, (passes, plain)


def test_sag_the_plain_passes_cannot_finish_in_time_still_diverges(backlash_model,
                                                                   monkeypatch):
    """Backlash 0.08 rad: the plain passes converge, but after 681, more than
    SAG_ITERATIONS: declared diverging as before the jumps (a fit refuses such a step)."""
    model, c = backlash_model
    x = _parameters(model, 0.08)
    rows = rows_of(model, c)
    _, plain = _plain(model, x, rows)
    assert plain > SAG_ITERATIONS
    with pytest.raises(ConvergenceError):
        _solved(model, x, rows, monkeypatch)
