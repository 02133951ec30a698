"""Property-based fuzzing of the pose-calibration readers (hypothesis): a pose campaign's
``measurements.csv`` and ``campaign.toml`` (:func:`load_pose_campaign`), and a pose
calibration's ``final-model.json`` (:func:`read_pose_model`).

Each test mutates a valid input (:mod:`fuzzing`) and checks the reader contract: the input is
accepted with the right meaning, or refused with a one-line
:class:`~stiffness.errors.StiffnessError`; nothing else is raised and no file is written.
"""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
from fuzzing import (
    FUZZ,
    assert_reader_contract,
    csv_mutation,
    json_mutations,
    replaced,
    toml_mutation,
    write_text,
)
from hypothesis import given
from hypothesis import strategies as st

from stiffness.calibration.pose_campaign import load_pose_campaign, write_pose_campaign
from stiffness.calibration.pose_diagnose import diagnose_poses
from stiffness.calibration.pose_model import Marker
from stiffness.calibration.pose_model_file import read_pose_model, write_pose_model
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.robot import load_robot

FILES = ("campaign.toml", "measurements.csv")


@pytest.fixture(scope="module")
def pose_folder(tmp_path_factory) -> tuple[Path, Path, Path]:
    """(the working folder, a pristine copy, the calibration's final-model.json) of a small
    two-marker UR10 pose campaign in mm with one marker unseen on some rows."""
    robot = load_robot("ur10", frame="tool0")
    markers = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05])),
               Marker("elbow", "forearm_link", np.array([0.0, 0.05, 0.2]))]
    hidden = HiddenPoseErrors(np.eye(3), np.array([1.2, -0.4, 0.3]),
                              np.array([m.offset for m in markers]), np.zeros(6),
                              np.zeros((6, 6)), np.full(6, 2e5))
    campaign = simulate_pose_campaign(robot, markers, hidden, 12, 2e-5, seed=3)
    campaign.positions[::4, 1] = np.nan  # the elbow marker unseen on every fourth row
    pristine = tmp_path_factory.mktemp("fuzz-pose-pristine")
    write_pose_campaign(campaign, pristine)
    folder = tmp_path_factory.mktemp("fuzz-pose")
    for name in FILES:
        shutil.copy(pristine / name, folder / name)
    fit = diagnose_poses(load_pose_campaign(pristine)).final
    model = write_pose_model(fit, load_pose_campaign(pristine),
                             tmp_path_factory.mktemp("fuzz-pose-model") / "final-model.json")
    return folder, pristine, model


def _restore(folder: Path, pristine: Path) -> None:
    for name in FILES:
        shutil.copy(pristine / name, folder / name)


def _check_meaning(campaign, original) -> None:
    """An accepted campaign holds finite coordinates and, per marker and row, three finite
    coordinates or none; the markers are among the file's (a marker dropped from [markers]
    leaves columns that are ignored with a warning)."""
    assert np.all(np.isfinite(campaign.q)) and campaign.n_rows >= 1
    seen = np.isfinite(campaign.positions)
    assert np.all(seen.all(axis=2) | ~seen.any(axis=2))
    assert {m.name for m in campaign.markers} <= {m.name for m in original.markers}


def _fuzz_file(pose_folder, data, name: str, mutation) -> None:
    folder, pristine, _ = pose_folder
    original = load_pose_campaign(pristine)
    mutated = data.draw(mutation((pristine / name).read_text()))
    try:
        write_text(folder / name, mutated)
        result = assert_reader_contract(lambda: load_pose_campaign(folder), folder)
        if result is not None:
            _check_meaning(result, original)
    finally:
        _restore(folder, pristine)


@FUZZ
@given(data=st.data())
def test_pose_measurement_csv_mutations(pose_folder, data):
    _fuzz_file(pose_folder, data, "measurements.csv", csv_mutation)


@FUZZ
@given(data=st.data())
def test_pose_campaign_toml_mutations(pose_folder, data):
    _fuzz_file(pose_folder, data, "campaign.toml", toml_mutation)


@FUZZ
@given(data=st.data())
def test_pose_model_file_mutations(pose_folder, data):
    _, pristine, model = pose_folder
    doc = json.loads(model.read_text())
    path, value = data.draw(json_mutations(doc))
    target = model.parent / "mutated.json"
    kind = data.draw(st.sampled_from(["node", "truncate"]))
    text = json.dumps(replaced(doc, path, value))
    if kind == "truncate":
        text = json.dumps(doc)[:data.draw(st.integers(0, len(json.dumps(doc)) - 1))]
    target.write_text(text)
    robot = load_pose_campaign(pristine).robot
    try:
        result = assert_reader_contract(lambda: read_pose_model(target, robot), model.parent)
        if result is not None:
            assert np.all(np.isfinite(result.x))
    finally:
        target.unlink()


@FUZZ
@given(data=st.data())
def test_pose_import_reader_contract(pose_folder, data):
    """`campaign import --kind poses` (import_pose_campaign) on a mutated tracker file: a
    finite campaign (three coordinates or none per marker and row) or one line, nothing
    written. The pose import was the one reader of a user's file without such a test."""
    from stiffness.calibration.campaign_toml import RobotSettings
    from stiffness.calibration.pose_import import import_pose_campaign
    from stiffness.calibration.rig_import import ImportSettings

    folder, pristine, _ = pose_folder
    original = load_pose_campaign(pristine)
    units = original.units
    settings = ImportSettings(units={"angle": units.angle, "length": units.length})
    markers = [Marker(m.name, m.frame, m.offset / units.length_to_si) for m in original.markers]
    rig = folder / "tracker.csv"
    try:
        write_text(rig, data.draw(csv_mutation((pristine / "measurements.csv").read_text())))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = assert_reader_contract(lambda: import_pose_campaign(
                [rig], RobotSettings("ur10", frame="tool0"), settings, markers), folder)
        if result is not None:
            _check_meaning(result[0], original)
    finally:
        rig.unlink(missing_ok=True)
