"""Tests of measurement campaigns: reading, validation errors, units, writing."""

from __future__ import annotations

import re
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from stiffness.calibration.campaign import Campaign, load_campaign
from stiffness.calibration.campaign_toml import CAMPAIGN_FILE, RobotSettings
from stiffness.calibration.campaign_writer import write_campaign
from stiffness.calibration.coordinate_columns import locate_coordinates
from stiffness.errors import FileFormatError, StiffnessError, UnknownColumnWarning
from stiffness.robot.sources import robots_directory
from stiffness.units import Units

TABLE2 = robots_directory() / "sk120" / "campaigns" / "table2"

SK120_TOML = """\
name = "test"
baseline = "enhanced"
[robot]
source = "sk120"
frame = "fixture_target"
target_offset = [0.0, 0.0, 0.0]
compliant_joints = ["joint1", "joint2", "joint3"]
[units]
angle = "deg"
force = "N"
length = "mm"
[measurement]
data = "measurements.csv"
"""
HEADER = "config,q1,q2,q3,q4,q5,q6,fx,fy,fz,dx,dy,dz"
ROW_A = "A,-33.2004,15.9,-55.5957,0,-34.4045,-90.0,9.2295,72.9220,44.1053,0.0300,0.1750,0.0560"
ROW_B = "B,32.5391,32.4702,-19.0085,0,-70.9913,-90.0,-5.3855,-73.2743,-26.0841,-0.071,-0.258,-0.052"

SLIDER_URDF = """<?xml version="1.0"?>
<robot name="slider">
  <link name="base_link"/><link name="carriage"/><link name="arm"/><link name="tip"/>
  <joint name="slide" type="prismatic"><parent link="base_link"/><child link="carriage"/>
    <origin xyz="0 0 0" rpy="0 0 0"/><axis xyz="1 0 0"/>
    <limit effort="100" velocity="1" lower="-2" upper="2"/></joint>
  <joint name="swing" type="revolute"><parent link="carriage"/><child link="arm"/>
    <origin xyz="0 0 0.1" rpy="0 0 0"/><axis xyz="0 0 1"/>
    <limit effort="100" velocity="1" lower="-3" upper="3"/></joint>
  <joint name="tip_joint" type="fixed"><parent link="arm"/><child link="tip"/>
    <origin xyz="0.5 0 0" rpy="0 0 0"/></joint>
</robot>
"""


def write(folder: Path, toml: str = SK120_TOML, csv: str | None = None) -> Path:
    """A campaign folder with the given texts; returns its campaign.toml."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / CAMPAIGN_FILE).write_text(toml)
    if csv is None:
        csv = f"{HEADER}\n{ROW_A}\n{ROW_B}\n"
    (folder / "measurements.csv").write_text(csv)
    return folder / CAMPAIGN_FILE


def error_of(path: Path) -> str:
    with pytest.raises(StiffnessError) as info:
        load_campaign(path)
    return str(info.value)


# ------------------------------------------------------------------------------------ reading


def test_shipped_table2_campaign_reads_in_si():
    c = load_campaign(TABLE2)
    assert c.name == "sk120-table2" and c.baseline == "enhanced"
    assert c.n_rows == 15 and c.config[:6] == ("A",) * 5 + ("B",)
    assert c.q.shape == (15, 6) and c.force.shape == c.deflection.shape == (15, 3)
    assert c.moment is None and c.rotation is None and c.noise_std_m is None
    np.testing.assert_allclose(np.rad2deg(c.q[0]), [-33.2004, 15.9, -55.5957, 0, -34.4045, -90])
    np.testing.assert_allclose(c.force[0], [9.2295, 72.9220, 44.1053])
    np.testing.assert_allclose(c.deflection[0], [0.03e-3, 0.175e-3, 0.056e-3])
    assert c.lines == tuple(range(2, 17))
    robot = c.robot()
    assert robot is c.robot()  # loaded once
    assert robot.target_frame == "fixture_target"
    assert robot.compliant_joints == ("joint1", "joint2", "joint3")


def test_folder_or_file_path(tmp_path):
    toml = write(tmp_path / "c")
    assert load_campaign(toml).n_rows == load_campaign(toml.parent).n_rows == 2


def test_comments_and_blank_lines_are_skipped_and_lines_counted(tmp_path):
    toml = write(tmp_path, csv=f"# provenance\n{HEADER}\n\n{ROW_A}\n# note\n{ROW_B}\n")
    assert load_campaign(toml).lines == (4, 6)


def test_unit_conversion_rad_kn_m(tmp_path):
    toml = SK120_TOML.replace('"deg"', '"rad"').replace('"N"', '"kN"').replace('"mm"', '"m"')
    toml = toml.replace("[0.0, 0.0, 0.0]", "[0.01, 0.02, 0.03]")
    toml += "noise_std = 2e-6\n"
    csv = (f"{HEADER},mx,my,mz,rx,ry,rz\n"
           "A,0.1,0.2,-0.3,0,-1,-1.5,0.5,-0.25,1,1e-4,2e-4,-3e-4,0.01,0.02,0.03,1e-5,2e-5,3e-5\n")
    c = load_campaign(write(tmp_path, toml, csv))
    np.testing.assert_allclose(c.q[0], [0.1, 0.2, -0.3, 0, -1, -1.5])
    np.testing.assert_allclose(c.force[0], [500.0, -250.0, 1000.0])
    np.testing.assert_allclose(c.deflection[0], [1e-4, 2e-4, -3e-4])
    np.testing.assert_allclose(c.moment[0], [10.0, 20.0, 30.0])  # kN.m -> N.m
    np.testing.assert_allclose(c.rotation[0], [1e-5, 2e-5, 3e-5])
    np.testing.assert_allclose(c.robot_settings.target_offset_m, [0.01, 0.02, 0.03])
    np.testing.assert_allclose(c.robot().target_offset, [0.01, 0.02, 0.03])
    assert c.noise_std_m == pytest.approx(2e-6)
    np.testing.assert_allclose(c.wrench[0], [500, -250, 1000, 10, 20, 30])


@pytest.mark.parametrize(("unit", "factor"), [("mm", 1e-3), ("cm", 1e-2), ("um", 1e-6),
                                              ("m", 1.0)])
def test_length_units(tmp_path, unit, factor):
    toml = SK120_TOML.replace('length = "mm"', f'length = "{unit}"').replace(
        "[0.0, 0.0, 0.0]", "[1.0, 2.0, 3.0]") + "noise_std = 5\n"
    csv = f"{HEADER},mx,my,mz\n{ROW_A},1,2,3\n"
    c = load_campaign(write(tmp_path, toml, csv))
    np.testing.assert_allclose(c.deflection[0], np.array([0.03, 0.175, 0.056]) * factor)
    np.testing.assert_allclose(c.robot_settings.target_offset_m, np.array([1, 2, 3]) * factor)
    np.testing.assert_allclose(c.moment[0], np.array([1, 2, 3]) * factor)  # N x length
    assert c.noise_std_m == pytest.approx(5 * factor)
    assert Units(length=unit).moment == f"N.{unit}"


def test_degrees_for_angles_and_rotations(tmp_path):
    csv = f"{HEADER},rx,ry,rz\n{ROW_A},0.001,0,-0.002\n"
    c = load_campaign(write(tmp_path, csv=csv))
    np.testing.assert_allclose(c.rotation[0], np.deg2rad([0.001, 0, -0.002]))
    assert c.moment is None


def test_prismatic_coordinates_take_the_length_unit_and_urdf_is_relative(tmp_path):
    (tmp_path / "robots").mkdir()
    (tmp_path / "robots" / "slider.urdf").write_text(SLIDER_URDF)
    toml = """\
name = "slider"
baseline = "conventional"
[robot]
source = "../robots/slider.urdf"
frame = "tip"
[units]
angle = "deg"
force = "N"
length = "mm"
[measurement]
data = "m.csv"
"""
    folder = tmp_path / "campaign"
    folder.mkdir()
    (folder / CAMPAIGN_FILE).write_text(toml)
    (folder / "m.csv").write_text("config,q1,q2,fx,fy,fz,dx,dy,dz\nA,250,90,0,10,0,0,0.5,0\n")
    c = load_campaign(folder)
    np.testing.assert_allclose(c.q[0], [0.25, np.pi / 2])  # mm -> m, deg -> rad
    assert c.robot().coordinate_joints == ("slide", "swing")
    assert c.robot().compliant_joints == ("slide", "swing")  # default: every coordinate joint
    # written elsewhere, the relative URDF path is rewritten for the new folder
    out = write_campaign(c, tmp_path / "elsewhere" / "deep")
    assert 'source = "../../robots/slider.urdf"' in out.read_text()
    again = load_campaign(out)
    np.testing.assert_allclose(again.q, c.q)
    assert "250.0,90.0" in (out.parent / "m.csv").read_text()


# ------------------------------------------------------------------------------ CSV errors


def csv_error(tmp_path, text: str) -> str:
    return error_of(write(tmp_path, csv=text))


@pytest.mark.parametrize(("header", "line", "column", "words"), [
    ("config,q1,q2,q3,q4,q5,q6,fx,fy,fz,dx,dy", 1, 13, "'dz' is missing"),
    ("config,q1,q2,q3,q4,q5,q6,fx,fy,fz,dx,dy,dz,fx", 1, 14, "'fx' appears twice"),
    ("config,temp,fx,fy,fz,dx,dy,dz", 1, 2, "no coordinate column: name the columns after"),
    ("config,q1,q2,q3,q4,q5,q6,joint1,fx,fy,fz,dx,dy,dz", 1, 8, "a joint name, beside q"),
    # a column in two cases is one column given twice
    ("config,q1,q2,q3,q4,q5,q6,fx,FX,fy,fz,dx,dy,dz", 1, 9, "'fx' appears twice"),
    ("label,q1,q2,q3,q4,q5,q6,fx,fy,fz,dx,dy,dz", 1, 1, "must be 'config'"),
    ("config,q1,q3,q2,q4,q5,q6,fx,fy,fz,dx,dy,dz", 1, 3, "expected 'q2'"),
    # a misnamed q column is named itself (it said: column 4, got 'q3', expected 'q2')
    ("config,q1,joint_two,q3,q4,q5,q6,fx,fy,fz,dx,dy,dz", 1, 3,
     "got 'joint_two' between q1 and 'q3', where q2 (joint2) belongs; name it q2"),
    ("config,q1,q2,q3,q4,q5,fx,fy,fz,dx,dy,dz", 1, 7, "but the header has 5 q columns"),
    ("config,q1,q2,q3,q4,q5,q6,q7,fx,fy,fz,dx,dy,dz", 1, 8, "has 7 q columns"),
    ("config,q1,q2,q3,q4,q5,q6,fx,fy,fz,dx,dy,dz,mx,my", 1, 16, "'mz' is missing"),
    ("config,q1,q2,q3,q4,q5,q6,fx,fy,fz,dx,dy,dz,rx,rz", 1, 16, "'ry' is missing"),
    # a unit in the header (what a rig writes): named as such, not 'dx' missing
    ("config,q1,q2,q3,q4,q5,q6,fx,fy,fz,dx [mm],dy [mm],dz [mm]", 1, 11,
     "got 'dx [mm]': a campaign's columns carry no unit (the [units] of its campaign.toml give "
     "them); name it 'dx', or read the rig's file with `stiffness campaign import`"),
    ("config,q1 (deg),q2,q3,q4,q5,q6,fx,fy,fz,dx,dy,dz", 1, 2, "got 'q1 (deg)': a campaign's"),
])
def test_header_errors_name_file_line_column(tmp_path, header, line, column, words):
    n_cells = len(header.split(","))
    row = ",".join(["A"] + ["0"] * (n_cells - 1))
    msg = csv_error(tmp_path, f"{header}\n{row}\n")
    assert "measurements.csv" in msg
    assert f"line {line}, column {column}" in msg
    assert words in msg


def test_header_error_line_counts_comments(tmp_path):
    msg = csv_error(tmp_path, f"# comment\n\n{HEADER.replace('dz', 'dzz')}\n{ROW_A}\n")
    assert "line 3, column 13: column 'dz' is missing" in msg


@pytest.mark.parametrize(("cell", "column", "shown"), [
    ("abc", 9, "'abc'"), ("nan", 9, "'nan'"), ("NaN", 9, "'NaN'"), ("inf", 9, "'inf'"),
    ("", 9, "an empty cell"),
])
def test_bad_cells_name_file_line_column(tmp_path, cell, column, shown):
    cells = ROW_B.split(",")
    cells[column - 1] = cell
    msg = csv_error(tmp_path, f"{HEADER}\n{ROW_A}\n{','.join(cells)}\n")
    assert re.search(rf"measurements\.csv, line 3, column {column} \(fy\): {re.escape(shown)} "
                     "is not a finite number", msg), msg


def test_row_with_missing_or_extra_cells(tmp_path):
    short = ROW_B.rsplit(",", 1)[0]
    msg = csv_error(tmp_path, f"{HEADER}\n{ROW_A}\n{short}\n")
    assert "line 3, column 13 (dz)" in msg and "12 cells but the header has 13" in msg
    msg = csv_error(tmp_path, f"{HEADER}\n{ROW_A},7\n")
    assert "line 2, column 14" in msg and "14 cells" in msg


def test_empty_label_empty_file_no_rows(tmp_path):
    assert "line 2, column 1 (config)" in csv_error(tmp_path, f"{HEADER}\n,{ROW_A[2:]}\n")
    assert "line 1: the file is empty" in csv_error(tmp_path, "")
    assert "line 2: no measurement rows" in csv_error(tmp_path, f"{HEADER}\n")


def test_missing_csv(tmp_path):
    toml = write(tmp_path)
    (tmp_path / "measurements.csv").unlink()
    msg = error_of(toml)
    assert "measurements.csv" in msg and "[measurement] data" in msg


# ----------------------------------------------------------------------------- TOML errors


@pytest.mark.parametrize(("old", "new", "words"), [
    ('name = "test"\n', "", "missing key name"),
    ('baseline = "enhanced"\n', "", "missing key baseline"),
    ('source = "sk120"\n', "", "missing key [robot] source"),
    ('length = "mm"\n', "", "missing key [units] length"),
    ('data = "measurements.csv"\n', "", "missing key [measurement] data"),
    ('[units]\nangle = "deg"\nforce = "N"\nlength = "mm"\n', "", "missing key units"),
    ('"enhanced"', '"exact"', "unknown baseline 'exact'; valid baselines: conventional, enhanced"),
    ('"deg"', '"grad"', "valid angle units: deg, rad"),
    ('"N"', '"lbf"', "valid force units: N, kN"),
    ('"mm"', '"in"', "valid length units: mm, m, cm, um"),
    ('data = "measurements.csv"', 'data = "measurements.csv"\nnoise_sd = 0.1',
     "unknown key 'noise_sd' in [measurement]"),
    ('data = "measurements.csv"', 'data = "measurements.csv"\nnoise_std = -1',
     "noise_std must be a positive"),
    ('data = "measurements.csv"', 'data = "measurements.csv"\nnoise_std = "small"',
     "noise_std must be a positive number"),
    ("[0.0, 0.0, 0.0]", "[0.0, 0.0]", "target_offset must be three numbers in mm"),
    ("[0.0, 0.0, 0.0]", "[0.0, nan, 0.0]", "target_offset must be three numbers in mm, finite"),
    ("[0.0, 0.0, 0.0]", "[0.0, 1e300, 0.0]", "finite and within +-1e+12, got [0.0, 1e+300"),
    ('compliant_joints = ["joint1", "joint2", "joint3"]', "compliant_joints = []",
     "compliant_joints must be a non-empty list"),
    ('name = "test"', 'name = "test"\ncolour = "red"', "unknown key 'colour' in top level"),
    ('name = "test"', "name = test", "is not valid TOML"),
    ('source = "sk120"', 'source = "sk12O"', "unknown robot 'sk12O'"),
    ('"joint3"]', '"joint9"]', "compliant joint 'joint9' is not a coordinate joint"),
    ('frame = "fixture_target"', 'frame = "nowhere"', "frame 'nowhere' is not in sk120"),
])
def test_toml_errors(tmp_path, old, new, words):
    assert old in SK120_TOML
    msg = error_of(write(tmp_path, SK120_TOML.replace(old, new, 1)))
    assert words in msg
    assert str(tmp_path / CAMPAIGN_FILE) in msg


def test_missing_campaign(tmp_path):
    assert "give a campaign.toml or the folder holding one" in error_of(tmp_path / "none")
    assert "give a campaign.toml" in error_of(tmp_path)  # a folder without one


def test_units_and_campaign_validation():
    with pytest.raises(StiffnessError, match="valid length units: mm, m, cm, um"):
        Units(length="inch")
    settings = RobotSettings("sk120")
    with pytest.raises(StiffnessError, match=r"deflection must have shape \(2, 3\)"):
        Campaign("x", "enhanced", settings, q=np.zeros((2, 6)), force=np.zeros((2, 3)),
                 deflection=np.zeros((3, 3)))
    with pytest.raises(StiffnessError, match="valid baselines"):
        Campaign("x", "linear", settings, q=np.zeros((1, 6)), force=np.zeros((1, 3)),
                 deflection=np.zeros((1, 3)))
    with pytest.raises(StiffnessError, match="labels must be non-empty single-line"):
        Campaign("x", "enhanced", settings, q=np.zeros((1, 6)), force=np.zeros((1, 3)),
                 deflection=np.zeros((1, 3)), config=("a\nb",))
    with pytest.raises(StiffnessError, match="target offset must be three finite lengths"):
        RobotSettings("sk120", target_offset_m=[0.0, np.nan, 0.0])
    c = Campaign("x", "enhanced", settings, q=np.zeros((1, 5)), force=np.zeros((1, 3)),
                 deflection=np.zeros((1, 3)))
    with pytest.raises(StiffnessError, match="has 6 coordinates .* but campaign 'x' has 5"):
        c.robot()


# --------------------------------------------------------------------------------- writing


def test_round_trip_of_the_shipped_campaign(tmp_path):
    c = load_campaign(TABLE2)
    out = write_campaign(c, tmp_path / "copy")
    assert out == tmp_path / "copy" / CAMPAIGN_FILE
    back = load_campaign(out)
    assert (back.name, back.baseline, back.config, back.units) == (c.name, c.baseline, c.config,
                                                                  c.units)
    assert back.robot_settings.frame == "fixture_target"
    assert back.robot_settings.compliant_joints == ("joint1", "joint2", "joint3")
    for attr in ("q", "force", "deflection"):
        np.testing.assert_allclose(getattr(back, attr), getattr(c, attr), rtol=1e-14, atol=1e-18)
    # the data are written in the declared units (deg, N, mm)
    text = (tmp_path / "copy" / "measurements.csv").read_text().splitlines()
    assert text[0] == HEADER
    assert text[1].startswith("A,-33.2004,15.9,-55.5957,0.0,-34.4045,-90.0,9.2295,")


def test_round_trip_with_moments_rotations_noise_and_other_units(tmp_path):
    rng = np.random.default_rng(3)
    m = 4
    c = Campaign(
        name='odd "name"', baseline="conventional",
        robot_settings=RobotSettings("sk120", "tool0", np.array([0.01, -0.02, 0.3]),
                                     ("joint1", "joint2")),
        q=rng.uniform(-1, 1, (m, 6)), force=rng.normal(size=(m, 3)) * 100,
        deflection=rng.normal(size=(m, 3)) * 1e-4, config=("a,b", "c", "c", "d"),
        moment=rng.normal(size=(m, 3)), rotation=rng.normal(size=(m, 3)) * 1e-4,
        noise_std_m=3e-6, units=Units("rad", "kN", "cm"), data_file="data.csv",
    )
    out = write_campaign(c, tmp_path)
    back = load_campaign(out)
    assert back.name == 'odd "name"' and back.config == c.config
    assert back.units == Units("rad", "kN", "cm") and back.data_file == "data.csv"
    assert back.noise_std_m == pytest.approx(3e-6, rel=1e-14)
    assert back.robot().compliant_joints == ("joint1", "joint2")
    np.testing.assert_allclose(back.robot_settings.target_offset_m, [0.01, -0.02, 0.3])
    for attr in ("q", "force", "deflection", "moment", "rotation"):
        np.testing.assert_allclose(getattr(back, attr), getattr(c, attr), rtol=1e-13)
    assert (tmp_path / "data.csv").read_text().startswith(f"{HEADER},mx,my,mz,rx,ry,rz\n")


def test_write_is_atomic_overwrites_and_leaves_no_temporary_files(tmp_path):
    c = load_campaign(TABLE2)
    write_campaign(c, tmp_path)
    (tmp_path / CAMPAIGN_FILE).chmod(0o640)
    c.name = "renamed"
    write_campaign(c, tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == [CAMPAIGN_FILE, "measurements.csv"]
    assert load_campaign(tmp_path).name == "renamed"
    assert (tmp_path / CAMPAIGN_FILE).stat().st_mode & 0o777 == 0o640
    assert (tmp_path / "measurements.csv").stat().st_mode & 0o777 == 0o644


def test_write_accepts_a_campaign_like_object(tmp_path):
    like = SimpleNamespace(
        name="sim", baseline="enhanced", robot_settings=RobotSettings("sk120"),
        q=np.deg2rad([[-33.2004, 15.9, -55.5957, 0, -34.4045, -90.0]]),
        force=np.array([[1.0, 2.0, 3.0]]), deflection=np.array([[1e-5, 2e-5, 3e-5]]),
    )
    back = load_campaign(write_campaign(like, tmp_path))
    assert back.config == ("1",) and back.units == Units()
    np.testing.assert_allclose(back.deflection, like.deflection)
    assert back.robot().target_frame == "fixture_target"  # the shipped robot's default


def test_written_numbers_carry_no_conversion_noise(tmp_path):
    """Issue 38 item 10: 0.1201274 mm, -33.2004 deg and a force of -0.0 N are written as
    such (not 120.12740000000001 or -0.0) and read back to 1e-15."""
    q_deg = np.array([[-33.2004, 15.9, -55.5957, 0.0, -34.4045, -90.0]])
    like = SimpleNamespace(
        name="sim", baseline="enhanced", robot_settings=RobotSettings("sk120"),
        q=np.deg2rad(q_deg), force=np.array([[-0.0, 2.0, 3.0]]),
        deflection=np.array([[1.201274e-4, -2.2e-5, 3.3e-5]]))
    out = write_campaign(like, tmp_path)
    text = (tmp_path / "measurements.csv").read_text()
    row = text.strip().splitlines()[-1].split(",")
    assert row[1:7] == ["-33.2004", "15.9", "-55.5957", "0.0", "-34.4045", "-90.0"], row
    assert row[7:] == ["0.0", "2.0", "3.0", "0.1201274", "-0.022", "0.033"], row
    back = load_campaign(out)
    np.testing.assert_allclose(back.deflection, like.deflection, rtol=1e-15)
    np.testing.assert_allclose(back.q, like.q, rtol=1e-15)


def test_coordinate_columns_named_by_joint_in_any_order(tmp_path):
    """Columns named after the joints, in another order and with a bookkeeping column, read
    the same coordinates as q1..q6 (the bookkeeping column ignored with one warning)."""
    names = ["joint1", "joint2", "joint3", "joint4", "joint5", "joint6"]
    order = [3, 0, 5, 1, 4, 2]
    cells = ROW_A.split(",")
    header = ["config", *(names[k] for k in order), "time", *HEADER.split(",")[7:]]
    row = [cells[0], *(cells[1 + k] for k in order), "12:00:01", *cells[7:]]
    with pytest.warns(UnknownColumnWarning, match="column.s. time are not campaign columns"):
        c = load_campaign(write(tmp_path, csv=f"{','.join(header)}\n{','.join(row)}\n"))
    ref = load_campaign(write(tmp_path / "ref", csv=f"{HEADER}\n{ROW_A}\n"))
    np.testing.assert_allclose(c.q, ref.q)
    np.testing.assert_allclose(c.deflection, ref.deflection)




def test_a_written_campaign_names_where_its_format_is(tmp_path):
    """The first comment of a written campaign.toml pointed at stiffness/campaign.py, which
    does not exist; the file it names now does."""
    write_campaign(load_campaign(TABLE2), tmp_path / "c")
    first = (tmp_path / "c" / CAMPAIGN_FILE).read_text().splitlines()[0]
    [named] = re.findall(r"stiffness/[\w/]+\.py", first)
    assert (Path(__file__).resolve().parents[1] / named).is_file(), first


def test_a_trailing_comma_on_every_line_is_read_without_a_column(tmp_path):
    """A spreadsheet export ending every line with a comma has an empty last column: it was
    an unknown column '' (warned, refused under --strict); an empty column at the end is no
    column, read in silence, under --strict too."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnknownColumnWarning)
        c = load_campaign(write(tmp_path, csv=f"{HEADER},\n{ROW_A},\n"))
    np.testing.assert_array_equal(c.q, load_campaign(write(tmp_path / "ref", csv=f"{HEADER}\n"
                                                                             f"{ROW_A}\n")).q)


def test_windows_separators_in_a_campaign_path_are_read(tmp_path):
    """A campaign.toml written on Windows names its URDF and loop file with backslashes
    (``..\\robot\\sk120.urdf``): refused before ('URDF file .../camp/..\\robot\\sk120.urdf does
    not exist'), read now as ``/`` where that names the file; a name stays a name, and a path
    naming nothing either way stays as written (its error names it so)."""
    import shutil

    from stiffness.files import resolve_path, resolve_source

    shutil.copytree(robots_directory() / "sk120", tmp_path / "robot",
                    ignore=shutil.ignore_patterns("campaigns", "paper"))
    shutil.copytree(robots_directory() / "sk120" / "campaigns" / "table2", tmp_path / "camp")
    toml = tmp_path / "camp" / "campaign.toml"
    toml.write_text(toml.read_text().replace(
        'source = "sk120"', 'source = "..\\\\robot\\\\sk120.urdf"\n'
        'loops = "..\\\\robot\\\\sk120.loops.yaml"', 1))
    camp = load_campaign(tmp_path / "camp")
    assert camp.resolved_source() == str((tmp_path / "robot" / "sk120.urdf").resolve())
    assert Path(camp.robot_options()["loops"]).resolve() == (
        tmp_path / "robot" / "sk120.loops.yaml").resolve()
    assert camp.robot().n_coordinates == 6
    assert resolve_source("ur5", tmp_path) == "ur5"
    assert resolve_path("..\\none.yaml", tmp_path) == str(tmp_path / "..\\none.yaml")


# ------------------------------------------------------------- what spreadsheets write

#: The campaign rows as a rig's spreadsheet may export them, each read as the plain file.
SPREADSHEET_EDGES = {
    "header cases and spaces": (f"{HEADER.replace('config', ' Config').replace('q1', 'Q1')}"
                                .replace("fx", " FX ").replace("dz", "dZ") + f"\n{ROW_A}\n"
                                f"{ROW_B}\n"),
    "trailing comma": f"{HEADER},\n{ROW_A},\n{ROW_B},\n",
    "trailing comma on the rows only": f"{HEADER}\n{ROW_A},\n{ROW_B},,\n",
    "byte-order mark and CRLF": f"\ufeff{HEADER}\r\n{ROW_A}\r\n{ROW_B}\r\n",
    "blank and empty rows at the end": f"{HEADER}\n{ROW_A}\n{ROW_B}\n\n  \n,,,,,,,,,,,,\n\n",
    "comment lines": f"# rig export 2026-12-05\n{HEADER}\n# loads 1..5\n{ROW_A}\n{ROW_B}\n#\n",
}


@pytest.mark.parametrize("text", SPREADSHEET_EDGES.values(), ids=SPREADSHEET_EDGES.keys())
def test_what_spreadsheets_write_reads_the_same_numbers(tmp_path, text):
    """Column names in another case or with spaces (``Q1``, `` FX ``), a comma ending every
    line, a byte-order mark, Windows line ends, blank or empty rows and comment lines: the
    same numbers as the plain file, and no warning (--strict refuses none)."""
    plain = load_campaign(write(tmp_path / "plain", csv=f"{HEADER}\n{ROW_A}\n{ROW_B}\n"))
    toml = write(tmp_path / "edge")
    (tmp_path / "edge" / "measurements.csv").write_bytes(text.encode())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        c = load_campaign(toml)
    for name in ("q", "force", "deflection"):
        np.testing.assert_array_equal(getattr(c, name), getattr(plain, name))
    assert list(c.config) == list(plain.config) == ["A", "B"]


@pytest.mark.parametrize(("text", "line", "words"), [
    (f"{HEADER}\n,deg,deg,deg,deg,deg,deg,N,N,N,mm,mm,mm\n{ROW_A}\n", 2,
     "a units row (deg, deg, deg, deg, deg, deg, N, N, N, mm, mm, mm), not measurements: a "
     "campaign's CSV holds numbers, its units are campaign.toml's [units]; delete the row"),
    (f"{HEADER}\nunit,[deg],[deg],[deg],[deg],[deg],[deg],[N],[N],[N],[mm],[mm],[mm]\n"
     f"{ROW_A}\n", 2, "read the rig's file with `stiffness campaign import`, which reads a "
                      "units row"),
    (HEADER + "\n" + ROW_A.replace("72.9220", '"72,9220"') + "\n", 2,
     "column 9 (fy): '72,9220' is not a finite number; write it with a decimal point, 72.9220"),
    (f"{HEADER}\n{ROW_A.replace('72.9220', '72,9220')}\n", 2,
     "column 14 (extra cell '0.0560'): the row has 14 cells but the header has 13; if a number "
     "has a decimal comma (1,5), it made two cells: write 1.5"),
    (f"{HEADER.replace(',', ';')}\n{ROW_A.replace(',', ';').replace('.', ',')}\n", 1,
     "column 1: the columns are separated by ';', not commas; write the file as CSV with "
     "commas (and '.' as the decimal point)"),
])
def test_what_spreadsheets_write_that_is_not_read_is_one_line(tmp_path, text, line, words):
    """A units row under the header, decimal commas, and a European spreadsheet's ';' with
    decimal commas: one line naming the file, the line and the fix."""
    msg = csv_error(tmp_path, text)
    assert f"measurements.csv, line {line}" in msg and words in msg and "\n" not in msg


def test_a_campaign_file_not_in_utf8_names_the_encoding_to_save(tmp_path):
    toml = write(tmp_path)
    text = f"{HEADER}\n{ROW_A}\n"
    for raw, words in ((text.encode("utf-16"), "UTF-16 text (a spreadsheet's 'Unicode "
                                               "text')"),
                       (("# op\u00e9rateur\n" + text).encode("latin-1"), "not UTF-8 text "
                                                                         "(byte 4)")):
        (tmp_path / "measurements.csv").write_bytes(raw)
        msg = error_of(toml)
        assert words in msg and "save the measurement file ([measurement] data) as UTF-8" in msg


@given(k=st.integers(2, 6), name=st.text(st.characters(codec="ascii", categories=["L", "N"]),
                                          min_size=1, max_size=8))
def test_a_misnamed_q_column_is_the_column_named(sk120, k, name):
    """Law: a header q1..q6 with q_k (k >= 2) written as anything that is neither a q column
    nor a joint of the SK120 is refused at that column, naming it (and q_k's joint when a
    q column follows)."""
    robot = sk120
    assume(not re.match(r"q\d+$", name.casefold()) and name not in robot.coordinate_joints)
    names = ["config"] + [f"q{i}" if i != k else name for i in range(1, 7)]
    with pytest.raises(FileFormatError) as caught:
        locate_coordinates(names, robot, Path("m.csv"), 1)
    assert caught.value.column == k + 1
    message = str(caught.value)
    assert (f"got {name!r} between q{k - 1} and 'q{k + 1}', where q{k} "
            f"({robot.coordinate_joints[k - 1]}) belongs" in message if k < 6 else
            f"(column 7 is {name!r}, where q6 follows)" in message)
