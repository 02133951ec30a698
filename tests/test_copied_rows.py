"""A row written twice (every cell equal to an earlier row's, to the last digit) is warned
about by both campaign readers, once, naming the lines: the fits would count it twice. A
repeated measurement, which differs by its noise, is not."""

from __future__ import annotations

import warnings

import pytest
from pose_campaigns import write_ur5_tip_campaign
from test_campaign import HEADER, ROW_A, ROW_B, write

from stiffness.calibration.campaign import load_campaign
from stiffness.calibration.pose_campaign import load_pose_campaign
from stiffness.errors import DataFileWarning

COPIED = "1 row(s) repeat an earlier row in every cell (first: line {} copies line {})"


def _no_copy_warning(load, path) -> None:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load(path)
    assert not [w for w in caught if "repeat an earlier row" in str(w.message)]


def test_deflection_campaign_row_written_twice(tmp_path):
    toml = write(tmp_path, csv=f"{HEADER}\n{ROW_A}\n{ROW_B}\n{ROW_A}\n")
    with pytest.warns(DataFileWarning, match=COPIED.format(4, 2).replace("(", r"\(")
                      .replace(")", r"\)")):
        assert load_campaign(toml).n_rows == 3  # still read
    repeat = ROW_A[:-1] + "1"  # dz 0.0561: a repeated measurement
    _no_copy_warning(load_campaign, write(tmp_path / "r", csv=f"{HEADER}\n{ROW_A}\n{repeat}\n"))


def test_pose_campaign_row_written_twice(tmp_path):
    write_ur5_tip_campaign(tmp_path)
    _no_copy_warning(load_pose_campaign, tmp_path)
    data = tmp_path / "measurements.csv"
    lines = data.read_text().splitlines()
    data.write_text("\n".join(lines + [lines[1]]) + "\n")
    with pytest.warns(DataFileWarning, match=COPIED.format(5, 2).replace("(", r"\(")
                      .replace(")", r"\)")):
        load_pose_campaign(tmp_path)
