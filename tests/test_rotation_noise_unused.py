"""A rotation noise std given where no orientation is measured is refused in one line, never
silently ignored: both campaign kinds' ``[measurement]`` key in either spelling
(``rotation_noise_std``, ``noise_std_rotation``) without rotation columns, naming the key the
file used; a campaign built in memory of either kind; and both simulators' Python APIs, as
``stiffness simulate --rotation-noise`` without ``--rotations`` is (before 6 December 2026
``simulate`` and ``simulate_poses`` dropped the std without a word, and a pose campaign built
in memory kept it)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from pose_campaigns import write_ur5_tip_campaign

from stiffness.calibration.campaign import load_campaign
from stiffness.calibration.campaign_writer import write_campaign
from stiffness.calibration.pose_campaign import load_pose_campaign
from stiffness.errors import FileFormatError, StiffnessError
from stiffness.planning.pose_simulation import simulate_poses
from stiffness.planning.simulate import simulate

ARM = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"]


def _deflections(**kw):
    return simulate("ur5", kq=[3e4, 2e4, 1.5e4], compliant_joints=ARM, configs=1,
                    loads_per_config=2, seed=1, **kw)


def _one_line(info: pytest.ExceptionInfo) -> str:
    text = str(info.value)
    assert "\n" not in text, text
    return text


@pytest.mark.parametrize("key", ["rotation_noise_std", "noise_std_rotation"])
@pytest.mark.parametrize("kind", ["deflections", "poses"])
def test_the_key_without_rotation_columns_is_refused_by_its_name(tmp_path, kind, key):
    folder = tmp_path / "c"
    if kind == "deflections":
        write_campaign(_deflections().campaign, folder)
    else:
        write_ur5_tip_campaign(folder)
    toml = folder / "campaign.toml"
    text = toml.read_text()
    assert "rotation" not in text.split("[measurement]")[1].split("[")[0]
    toml.write_text(text.replace('data = "measurements.csv"',
                                 f'data = "measurements.csv"\n{key} = 0.01'))
    with pytest.raises(FileFormatError) as info:
        (load_campaign if kind == "deflections" else load_pose_campaign)(folder)
    text = _one_line(info)
    assert f"[measurement] {key} is given" in text and "drop" in text, text
    assert key == "rotation_noise_std" or "rotation_noise_std is" not in text


def test_campaigns_built_in_memory_refuse_it(tmp_path):
    campaign = _deflections().campaign
    assert campaign.rotation is None
    with pytest.raises(StiffnessError) as info:
        dataclasses.replace(campaign, rotation_noise_std_rad=1e-3)
    assert "no measured rotations" in _one_line(info)
    write_ur5_tip_campaign(tmp_path / "p")
    poses = load_pose_campaign(tmp_path / "p")
    assert poses.rotations is None and poses.noise_std_rotation is None
    with pytest.raises(StiffnessError) as info:
        dataclasses.replace(poses, noise_std_rotation=1e-3)
    assert "no measured orientations" in _one_line(info)
    with_turns = dataclasses.replace(poses, rotations=np.zeros(poses.positions.shape),
                                     noise_std_rotation=1e-3)
    assert with_turns.noise_std_rotation == 1e-3  # with orientations it is taken


def test_both_simulators_refuse_a_rotation_noise_without_rotations():
    with pytest.raises(StiffnessError) as info:
        _deflections(rotation_noise_std_rad=1e-3)
    assert "rotations=True" in _one_line(info)
    with pytest.raises(StiffnessError) as info:
        simulate_poses("ur5", poses=2, rotation_noise_std_rad=1e-3)
    assert "rotations=True" in _one_line(info)
    # with rotations the std is the one the campaign declares
    measured = _deflections(rotations=True, rotation_noise_std_rad=1e-3).campaign
    assert measured.rotation is not None and measured.rotation_noise_std_rad == 1e-3
