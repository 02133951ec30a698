"""CSV cells are read as written: ``1_000`` (which Python's ``float`` reads as 1000) is refused by
every CSV reader (a deflection or pose campaign's measurements, a rig's file, a joint path)
with one line naming the file, line, column, the cell and the fix, never read as a number."""

from __future__ import annotations

import math
import re

import pytest
from pose_campaigns import write_ur5_tip_campaign
from test_campaign import HEADER, ROW_A, ROW_B, csv_error
from test_rig_import import BASE_ROWS, refusal

from stiffness.calibration.pose_campaign import load_pose_campaign
from stiffness.errors import FileFormatError
from stiffness.files import csv_float
from stiffness.machining.joint_path import read_joint_path
from stiffness.robot.robot import load_robot

FIX = "'1_000' has '_' digit separators, which a CSV number cannot have; write 1000"


@pytest.mark.parametrize(("cell", "value"), [("1000", 1000.0), (" -1.5e-3 ", -1.5e-3),
                                             ("+.5", 0.5), ("7.", 7.0), ("1E+02", 100.0)])
def test_plain_decimal_cells_are_read(cell, value):
    assert csv_float(cell) == value


@pytest.mark.parametrize("cell", ["1_000", "0x10", "1e", "--1", "١٢", "1.2.3", "", "1 000"])
def test_other_cells_are_not_numbers(cell):
    """Python's float reads the first and the Arabic-Indic digits; a CSV number is neither."""
    with pytest.raises(ValueError, match="digit separators|is not a number"):
        csv_float(cell)
    assert math.isnan(csv_float("nan")) and csv_float("-inf") == -math.inf  # refused by name


def test_deflection_campaign_refuses_digit_separators(tmp_path):
    cells = ROW_B.split(",")
    cells[8] = "1_000"
    msg = csv_error(tmp_path, f"{HEADER}\n{ROW_A}\n{','.join(cells)}\n")
    assert "measurements.csv, line 3, column 9 (fy): " + FIX in msg and "\n" not in msg


def test_rig_file_refuses_digit_separators(tmp_path):
    rows = list(BASE_ROWS)
    rows[2] = "0,-80,90,0,90,0,0,1_000,0,0,0.1,0"
    assert "rig.csv, line 3, column 8 (fy): " + FIX in refusal(tmp_path, "\n".join(rows))


def test_pose_campaign_refuses_digit_separators(tmp_path):
    write_ur5_tip_campaign(tmp_path)
    data = tmp_path / "measurements.csv"
    lines = data.read_text().splitlines()
    row = next(i for i, line in enumerate(lines) if line and not line.startswith("#")) + 1
    cells = lines[row].split(",")
    cells[-1] = "1_000"
    lines[row] = ",".join(cells)
    data.write_text("\n".join(lines) + "\n")
    with pytest.raises(FileFormatError, match=FIX) as info:
        load_pose_campaign(tmp_path)
    assert info.value.line == row + 1 and info.value.column == len(cells)


def test_joint_path_refuses_digit_separators(tmp_path):
    path = tmp_path / "path.csv"
    path.write_text("q1,q2,q3,q4,q5,q6\n0,-1.2,1.5,-0.3,1.57,0\n0,-1.2,1_000,-0.3,1.57,0\n")
    with pytest.raises(FileFormatError, match=FIX) as info:
        read_joint_path(path, load_robot("ur5"))
    assert (info.value.line, info.value.column) == (3, 3)


@pytest.mark.parametrize("minus", ["\u2212", "\u2013"])
def test_a_typographic_minus_is_named_with_its_fix(tmp_path, minus):
    """A table copied from a PDF or a word processor carries '−' (U+2212) or an en dash for
    the minus sign: every reader refused the cell as no number ("every value must be one",
    "every q, force ... cell must be a number"), without saying what was wrong with a cell
    that looks like -5. Now each names the character and the fix, in one line."""
    from stiffness.cli.flags import parse_list
    from stiffness.errors import StiffnessError

    fix = (f"'{minus}80' has a typographic minus sign ({minus}, U+{ord(minus):04X}, as a PDF "
           "or a word processor writes it), which a CSV number cannot have; write -80")
    cells = ROW_B.split(",")
    cells[8] = f"{minus}80"
    msg = csv_error(tmp_path, f"{HEADER}\n{ROW_A}\n{','.join(cells)}\n")
    assert "measurements.csv, line 3, column 9 (fy): " + fix in msg and "\n" not in msg
    rows = list(BASE_ROWS)
    rows[2] = f"0,{minus}80,90,0,90,0,0,10,0,0,0.1,0"
    assert "rig.csv, line 3, column 2 (q2): " + fix in refusal(tmp_path, "\n".join(rows))
    path = tmp_path / "path.csv"
    path.write_text(f"q1,q2,q3,q4,q5,q6\n0,-1.2,1.5,-0.3,1.57,0\n0,{minus}80,1,-0.3,1.57,0\n")
    with pytest.raises(FileFormatError, match=re.escape(fix)):
        read_joint_path(path, load_robot("ur5"))
    with pytest.raises(StiffnessError, match=re.escape(fix.replace(
            "a CSV number", "a command-line number"))):
        parse_list(f"0,{minus}80", "--q")
