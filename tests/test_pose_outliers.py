"""Outlier flags on pose campaigns (issue 35): the poses a fit does not explain, flagged by
deflection campaigns' rule (:func:`stiffness.calibration.outliers.flag_residuals`) and reported
under the same ``outliers`` key.

Measured while writing (UR10, two markers, 20 poses, tracker noise 20 um declared; frame,
markers and zero offsets hidden and fitted; seeds 0-5): a clean campaign flags no pose; with
one marker position of 2 poses moved by 30 x the noise, soft_l1 flags exactly those 2 poses
(standardised residuals 22 to 32), least squares flags them and 1 to 5 clean neighbours that
the outliers pulled the fit away from (4.1 to 7.9), as on deflection campaigns
(docs/outliers.md).
"""

from __future__ import annotations

import json

import numpy as np
import pinocchio as pin
import pytest

from stiffness.calibration.outliers import OUTLIER_THRESHOLD
from stiffness.calibration.pose_campaign import write_pose_campaign
from stiffness.calibration.pose_fit import (
    fit_pose_model,
    flag_pose_outliers,
    rows_of,
    starting_frame,
)
from stiffness.calibration.pose_model import Marker, PoseModel
from stiffness.cli.main import main
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.robot import load_robot

NOISE = 20e-6  # m
NOISE_ROT = 2e-4  # rad
SIZE = 30.0  # outlier size (noise stds)
FAMILIES = ["frame", "markers", "joint_offsets"]
MARKERS = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05])),
           Marker("elbow", "forearm_link", np.array([0.0, 0.05, 0.2]))]


@pytest.fixture(scope="module")
def ur10():
    return load_robot("ur10", frame="tool0")


def _campaign(robot, seed: int, n: int = 20, **kw):
    rng = np.random.default_rng(seed)
    hidden = HiddenPoseErrors(pin.exp3(rng.normal(size=3)), rng.uniform(-2, 2, 3),
                              np.array([m.offset for m in MARKERS])
                              + rng.normal(0, 2e-3, (2, 3)),
                              rng.normal(0.0, 1e-3, 6), np.zeros((6, 6)))
    return simulate_pose_campaign(robot, MARKERS, hidden, n, NOISE, seed=seed, **kw)


def _fit(robot, c, loss: str = "linear"):
    model = PoseModel(robot, c.markers, tuple(FAMILIES), starting_frame(c), c.loads)
    return fit_pose_model(model, c, rows_of(model, c), FAMILIES, loss=loss)


def test_injected_poses_are_flagged_and_clean_ones_are_not(ur10):
    """Seeds 0-2: the clean campaign flags no pose (a false flag has probability about 0.8 %
    per campaign of 120 components); with 2 poses' marker moved by 30 noise stds, soft_l1
    flags exactly those poses, on the moved marker, with the standardised residual (predicted
    minus measured) of the moved component, ``-30 d_a / sqrt(1 - h)`` to within the noise;
    least squares flags them too (and may flag clean neighbours)."""
    for seed in range(3):
        c = _campaign(ur10, seed)
        assert flag_pose_outliers(_fit(ur10, c), c)[0] == []
        rng = np.random.default_rng(100 + seed)
        rows = rng.choice(c.n_rows, 2, replace=False)
        moved = {}
        for r in rows:
            k, d = int(rng.integers(2)), rng.normal(size=3)
            d /= np.linalg.norm(d)
            c.positions[r, k] += SIZE * NOISE * d
            moved[int(r) + 1] = (MARKERS[k].name, d)
        robust = _fit(ur10, c, "soft_l1")
        flags, sigma = flag_pose_outliers(robust, c)
        assert sigma == NOISE  # the declared noise
        assert sorted(o.row for o in flags) == sorted(moved)
        for o in flags:
            marker, d = moved[o.row]
            name, axis = o.component.split("_")
            assert name == marker and o.label == c.labels[o.row - 1] and o.line is None
            expected = -SIZE * d["xyz".index(axis)]
            assert abs(o.standardised_residual) > OUTLIER_THRESHOLD
            assert abs(o.standardised_residual - expected) < 4.0 + 0.2 * abs(expected), (
                o, expected)
        assert set(moved) <= {o.row for o in flag_pose_outliers(_fit(ur10, c), c)[0]}


def test_orientation_outlier_is_flagged_on_its_rotation_component(ur10):
    """With measured orientations (and a marker unseen in one pose), a marker orientation off
    by 30 rotation noise stds about x is flagged on that marker's rotation component, and
    nothing else: positions and weighted orientations share one scale, and the leverages of
    the stacked Jacobian land on their own components."""
    c = _campaign(ur10, 3, rotation_noise_std=NOISE_ROT)
    c.positions[4, 0] = np.nan
    c.rotations[4, 0] = np.nan
    assert flag_pose_outliers(_fit(ur10, c, "soft_l1"), c)[0] == []
    # turned about the measuring frame's x: the orientation error log(R_pred R_meas^T) is
    # -30 noise stds about x
    c.rotations[7, 1] = pin.log3(pin.exp3(np.array([SIZE * NOISE_ROT, 0.0, 0.0]))
                                 @ pin.exp3(c.rotations[7, 1]))
    flags, _ = flag_pose_outliers(_fit(ur10, c, "soft_l1"), c)
    assert [(o.row, o.component) for o in flags] == [(8, "elbow_rx")]
    assert flags[0].standardised_residual == pytest.approx(-SIZE, abs=5.0)


def test_diagnose_reports_pose_outliers(ur10, tmp_path, capsys):
    """``diagnose`` on a pose campaign file: ``outliers`` (label, row, CSV line, component,
    standardised residual) and ``outlier_threshold`` in --json as deflection diagnoses
    report them, the text report's outlier lines and the page's section."""
    c = _campaign(ur10, 5, n=15)
    c.positions[6, 0] += np.array([0.0, 0.0, SIZE * NOISE])
    write_pose_campaign(c, tmp_path / "c")
    args = ["diagnose", str(tmp_path / "c"), "--loss", "soft_l1", "--masses", "unknown",
            "--not", "geometry,gravity_lumped"]
    assert main([*args, "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert payload["outlier_threshold"] == OUTLIER_THRESHOLD
    assert [(o["label"], o["row"], o["line"], o["component"]) for o in payload["outliers"]] \
        == [(c.labels[6], 7, 8, "tip_z")]
    assert payload["outliers"][0]["standardised_residual"] < -20  # predicted - measured
    assert main([*args, "--out", str(tmp_path / "d")]) == 0
    text = capsys.readouterr().out
    assert "outliers (|standardised residual| > 4 noise std; flagged, not dropped): 1 row(s)" \
        in text and f"config {c.labels[6]} row 7 (line 8): tip_z" in text
    page = (tmp_path / "d" / "diagnosis.html").read_text()
    assert "Poses flagged as outliers" in page and "tip_z" in page
    record = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    assert record["outliers"] == payload["outliers"]
