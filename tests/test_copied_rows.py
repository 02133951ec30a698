"""A row written twice (every cell equal to an earlier row's, to the last digit) is warned
about by both campaign readers, once, naming the lines: the fits would count it twice. A
repeated measurement, which differs by its noise, is not."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from pose_campaigns import write_ur5_tip_campaign
from test_campaign import HEADER, ROW_A, ROW_B, write

from stiffness.calibration.campaign import load_campaign
from stiffness.calibration.measurements import warn_copied_markers
from stiffness.calibration.pose_campaign import load_pose_campaign
from stiffness.cli.main import main
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


# --- a marker's columns written twice (FIGAROH's TIAGo mocap export repeats x3..z3 as x4..z4)

MARKERS_COPIED = "markers {} and {} read the same positions, to the last digit, on all {} rows"


def _two_marker_rig(path, rows: int = 4, copy: bool = False) -> None:
    """A UR5 rig file: q1..q6 (rad) and two markers' positions (m), ``b`` on tool0 and ``a``
    on the forearm, each with its own noise (seed 5), or ``b`` a copy of ``a`` (``copy``)."""
    rng = np.random.default_rng(5)
    lines = ["q1,q2,q3,q4,q5,q6,a_x,a_y,a_z,b_x,b_y,b_z"]
    for _ in range(rows):
        a, b = rng.normal(0.5, 0.2, 3), rng.normal(0.5, 0.2, 3)
        lines.append(",".join(repr(float(v)) for v in
                              [*rng.uniform(-1, 1, 6), *a, *(a if copy else b)]))
    path.write_text("\n".join(lines) + "\n")


def test_pose_import_and_reader_warn_a_marker_copied(tmp_path):
    """campaign import --kind poses of a rig whose second marker repeats the first's columns
    warns once naming both (and the reader again); independent markers are not warned about."""
    argv = ["campaign", "import", str(tmp_path / "rig.csv"), "--kind", "poses", "--robot", "ur5",
            "--marker", "a=forearm_link", "--marker", "b=tool0", "--units",
            "angle=rad,length=m", "--quiet", "--out"]
    _two_marker_rig(tmp_path / "rig.csv")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main([*argv, str(tmp_path / "clean")]) == 0
        load_pose_campaign(tmp_path / "clean")
    assert not [w for w in caught if "read the same positions" in str(w.message)]
    _two_marker_rig(tmp_path / "rig.csv", copy=True)
    for read in (lambda: main([*argv, str(tmp_path / "copied")]),
                 lambda: load_pose_campaign(tmp_path / "copied")):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            read()
        assert len([w for w in caught if MARKERS_COPIED.format("a", "b", 4) in str(w.message)
                    and issubclass(w.category, DataFileWarning)]) == 1


def _markers(draw, n_rows: int, n_markers: int) -> np.ndarray:
    """Distinct positions (n_rows, n_markers, 3), NaN where a marker is not seen."""
    pos = np.array(draw(st.lists(st.floats(-5, 5, allow_nan=False), min_size=n_rows * n_markers * 3,
                                 max_size=n_rows * n_markers * 3, unique=True)))
    pos = pos.reshape(n_rows, n_markers, 3)
    hidden = draw(st.lists(st.booleans(), min_size=n_rows * n_markers,
                           max_size=n_rows * n_markers))
    pos[np.array(hidden).reshape(n_rows, n_markers)] = np.nan
    return pos


@given(st.data())
def test_copied_marker_warning_law(data):
    """warn_copied_markers warns exactly when a marker's positions are another's on every row
    (two or more) that sees both: never for distinct readings, always for a copy."""
    n_rows, n_markers = data.draw(st.integers(2, 6)), data.draw(st.integers(2, 4))
    pos = _markers(data.draw, n_rows, n_markers)
    names = [f"m{i}" for i in range(n_markers)]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warn_copied_markers(names, pos, "rig.csv")
    assert not caught
    a, b = data.draw(st.sampled_from([(i, j) for i in range(n_markers)
                                      for j in range(n_markers) if i != j]))
    pos[:, b] = pos[:, a]
    pos[:2, a] = data.draw(st.floats(-5, 5))  # seen by both on two rows at least
    pos[:2, b] = pos[:2, a]
    with pytest.warns(DataFileWarning, match="read the same positions"):
        warn_copied_markers(names, pos, "rig.csv")
