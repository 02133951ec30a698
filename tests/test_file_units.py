"""Units declared in CSV files, implausible cells and coordinates beyond the joint limits.

A plan's units comment must be read whatever its spacing, or refused when it cannot be; a plan
without one reads in deg/N/mm with a warning; a comment that disagrees with ``campaign.toml``
is refused; cells too large for any measurement are refused; rows beyond the joint limits
(degrees read as radians) are read with a warning that names the first one.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from stiffness.calibration.campaign import load_campaign
from stiffness.errors import DataFileWarning, FileFormatError
from stiffness.planning.plan import read_plan
from stiffness.units import (
    ANGLE_UNITS,
    FORCE_UNITS,
    LENGTH_UNITS,
    MAX_CELL,
    wrong_stiffness_unit,
)

HEADER = "config,q1,q2,q3,q4,q5,q6,fx,fy,fz"
#: Two UR5 rows (deg, N) within the joint limits (+-360 deg, elbow +-180 deg).
ROWS = ["P1,-25.09,167.78,22.40,-86.81,-92.99,139.72,57.735,57.735,57.735",
        "P2,10.0,-60.0,80.0,-20.0,90.0,0.0,0,0,100"]
Q_DEG = np.array([[-25.09, 167.78, 22.40, -86.81, -92.99, 139.72],
                  [10.0, -60.0, 80.0, -20.0, 90.0, 0.0]])
F_N = np.array([[57.735] * 3, [0, 0, 100]])


def plan_text(comment: str | None, rows: list[str] = ROWS) -> str:
    return "".join([f"{comment}\n" if comment is not None else "", HEADER, "\n",
                    *(f"{r}\n" for r in rows)])


def read(tmp_path: Path, text: str, robot):
    path = tmp_path / "plan.csv"
    path.write_text(text)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        plan, _ = read_plan(path, robot)
    return plan, [str(w.message) for w in caught if w.category is DataFileWarning]


@pytest.mark.parametrize("comment", [
    "# measurement plan; units: angle=rad force=kN length=m",
    "# units: angle = rad, force = kN, length = m",
    "#Units: angle=rad; force=kN; length=m",
    "# angle=rad force=kN length=m",
    "# units = length = m , force = kN , angle = rad",
])
def test_units_comment_in_any_spacing_converts_to_si(ur5, tmp_path, comment):
    rows = ["P1,0.1,-0.2,0.3,-0.4,0.5,-0.6,0.5,-0.25,1"]
    plan, caught = read(tmp_path, plan_text(comment, rows), ur5)
    assert caught == []
    np.testing.assert_allclose(plan.q, [[0.1, -0.2, 0.3, -0.4, 0.5, -0.6]])
    np.testing.assert_allclose(plan.force, [[500.0, -250.0, 1000.0]])
    assert (plan.units.angle, plan.units.force, plan.units.length) == ("rad", "kN", "m")


@given(angle=st.sampled_from(list(ANGLE_UNITS)), force=st.sampled_from(list(FORCE_UNITS)),
       length=st.sampled_from(list(LENGTH_UNITS)), order=st.permutations([0, 1, 2]),
       space=st.sampled_from(["", " ", "  "]), sep=st.sampled_from([" ", ", ", "; ", ","]))
def test_units_comment_property(ur5, tmp_path_factory, angle, force, length, order, space,
                                sep):
    """Every unit triple, in any order and spacing, reads as declared."""
    pairs = [f"angle{space}={space}{angle}", f"force{space}={space}{force}",
             f"length{space}={space}{length}"]
    comment = "# units: " + sep.join(pairs[i] for i in order)
    row = "P1,1.0,-0.5,0.8,-2.0,0.9,0.0,0,0,100"  # within the limits in deg and in rad
    plan, caught = read(tmp_path_factory.mktemp("u"), plan_text(comment, [row]), ur5)
    assert caught == []
    np.testing.assert_allclose(plan.force, [[0, 0, 100 * FORCE_UNITS[force]]])
    np.testing.assert_allclose(plan.q, [np.array([1.0, -0.5, 0.8, -2.0, 0.9, 0.0])
                                        * ANGLE_UNITS[angle]])


@pytest.mark.parametrize(("comment", "words"), [
    ("# units: angle=rad force=kN", "does not give length"),
    ("# units: rad, kN, m", "does not give angle or force or length"),
    ("# units: angle=rad force=kN length=m torque=N.m", "names 'torque'"),
    ("# units: angle=rad angle=deg force=N length=m", "names angle twice"),
    ("# units: angle=grad force=N length=mm", "valid angle units: deg, rad"),
])
def test_unreadable_units_comment_is_refused_with_the_form(ur5, tmp_path, comment, words):
    with pytest.raises(FileFormatError) as info:
        read(tmp_path, plan_text(comment), ur5)
    message = str(info.value)
    assert words in message and "plan.csv, line 1" in message, message
    assert "\n" not in message


def test_plan_without_units_reads_deg_n_mm_with_a_warning(ur5, tmp_path):
    plan, caught = read(tmp_path, plan_text(None), ur5)
    np.testing.assert_allclose(plan.q, np.deg2rad(Q_DEG))
    np.testing.assert_allclose(plan.force, F_N)
    assert len(caught) == 1 and "declares no units; read as angle=deg force=N length=mm" \
        in caught[0]
    _, caught = read(tmp_path, plan_text("# plan for the bench; forces at the tool"), ur5)
    assert len(caught) == 1  # a comment without units is not a declaration


def test_two_disagreeing_units_comments_are_refused(ur5, tmp_path):
    text = plan_text("# units: angle=deg force=N length=mm").replace(
        HEADER, "# units: angle=rad force=N length=mm\n" + HEADER)
    with pytest.raises(FileFormatError, match=r"line 2: the units comment says angle=rad .* "
                       r"but line 1 says angle=deg"):
        read(tmp_path, text, ur5)


def _campaign(tmp_path: Path, comment: str) -> Path:
    folder = tmp_path / "camp"
    folder.mkdir()
    (folder / "campaign.toml").write_text(
        'name = "t"\nbaseline = "enhanced"\n[robot]\nsource = "ur5"\n'
        '[units]\nangle = "deg"\nforce = "N"\nlength = "mm"\n'
        '[measurement]\ndata = "measurements.csv"\n')
    rows = [f"{r},0.1,0.2,0.3" for r in ROWS]
    (folder / "measurements.csv").write_text(
        f"{comment}\n{HEADER},dx,dy,dz\n" + "".join(f"{r}\n" for r in rows))
    return folder


def test_csv_units_comment_must_agree_with_campaign_toml(tmp_path):
    folder = _campaign(tmp_path, "# units: angle=rad force=N length=mm")
    for read_folder in (load_campaign, read_plan):
        with pytest.raises(FileFormatError, match=r"measurements\.csv, line 1: the units "
                           r"comment says angle=rad force=N length=mm but .*campaign\.toml "
                           r"says angle=deg"):
            read_folder(folder)


def test_agreeing_csv_units_comment_is_accepted(tmp_path):
    folder = _campaign(tmp_path, "# measurement plan; units: angle=deg force=N length=mm")
    np.testing.assert_allclose(load_campaign(folder).q, np.deg2rad(Q_DEG))


@pytest.mark.parametrize(("cell", "accepted"), [("9e11", True), ("-9.99e11", True),
                                                ("1.01e12", False), ("1e160", False),
                                                ("-1e300", False)])
def test_cells_beyond_any_measurement_are_refused(ur5, tmp_path, cell, accepted):
    row = ROWS[1].split(",")
    row[7] = cell  # fx
    text = plan_text("# units: angle=deg force=N length=mm", [ROWS[0], ",".join(row)])
    if accepted:
        plan, _ = read(tmp_path, text, ur5)
        assert plan.force[1, 0] == float(cell)
        return
    with pytest.raises(FileFormatError) as info:
        read(tmp_path, text, ur5)
    assert re.search(rf"line 4, column 8 \(fx\): {re.escape(cell)} is beyond \+-1e\+12",
                     str(info.value)), str(info.value)
    assert MAX_CELL == 1e12


def test_rows_beyond_the_joint_limits_warn_once_naming_the_first(ur5, tmp_path):
    """Degrees read as radians: every row but the zero one is beyond +-2 pi."""
    _, caught = read(tmp_path, plan_text("# units: angle=rad force=N length=mm"), ur5)
    assert len(caught) == 1, caught
    assert ("2 of 2 rows have coordinates beyond ur5's joint limits (first: line 3, q1 "
            "(shoulder_pan_joint) = -25.09 rad, limits [-6.28319, 6.28319] rad)") in caught[0]
    _, caught = read(tmp_path, plan_text("# units: angle=deg force=N length=mm"), ur5)
    assert caught == []


def test_campaign_rows_beyond_the_elbow_limit_warn(tmp_path):
    folder = _campaign(tmp_path, "# a campaign")
    text = (folder / "measurements.csv").read_text().replace(",80.0,", ",190.0,")
    (folder / "measurements.csv").write_text(text)
    with pytest.warns(DataFileWarning, match=r"1 of 2 rows .* \(first: line 4, q3 "
                      r"\(elbow_joint\) = 190 deg, limits \[-180, 180\] deg\)"):
        load_campaign(folder)


def test_a_label_reused_for_another_pose_warns_naming_both_lines(ur5, tmp_path):
    same = ROWS[0].replace("57.735,57.735,57.735", "0,0,100")  # P1 again, another load
    other = ROWS[1].replace("P2", "P1")  # a copied row not relabelled
    units = "# units: angle=deg force=N length=mm"
    _, caught = read(tmp_path, plan_text(units, [ROWS[0], same, ROWS[1]]), ur5)
    assert caught == []
    _, caught = read(tmp_path, plan_text(units, [ROWS[0], same, other]), ur5)
    assert len(caught) == 1, caught
    assert ("1 configuration label(s) name rows at different coordinates (P1; first: 'P1' on "
            "lines 3 and 5, q2 167.78 vs -60 deg)") in caught[0]


def test_a_campaign_label_reused_for_another_pose_warns(tmp_path):
    folder = _campaign(tmp_path, "# a campaign")
    data = folder / "measurements.csv"
    data.write_text(data.read_text().replace("P2,", "P1,"))
    with pytest.warns(DataFileWarning, match=r"'P1' on lines 3 and 4, q2 167.78 vs -60 deg"):
        load_campaign(folder)


def test_a_byte_order_mark_is_dropped_from_every_kind_of_user_file(tmp_path):
    """Spreadsheets and Windows editors start UTF-8 files with U+FEFF: TOML, JSON, YAML and
    CSV files read the same with it as without it."""
    from stiffness.files import read_json, read_text, read_toml, read_yaml

    texts = {"a.toml": ('x = 1\n[t]\ny = "z"\n', read_toml, {"x": 1, "t": {"y": "z"}}),
             "a.json": ('{"x": [1, 2]}', read_json, {"x": [1, 2]}),
             "a.yaml": ("x: [1, 2]\n", read_yaml, {"x": [1, 2]}),
             "a.csv": ("a,b\n1,2\n", read_text, "a,b\n1,2\n")}
    for name, (text, reader, expected) in texts.items():
        path = tmp_path / name
        path.write_text("\ufeff" + text, encoding="utf-8")
        assert reader(path) == expected, name
    folder = _campaign(tmp_path, "# a campaign")
    toml = folder / "campaign.toml"
    toml.write_text("\ufeff" + toml.read_text(), encoding="utf-8")
    np.testing.assert_allclose(load_campaign(folder).q, np.deg2rad(Q_DEG))


def test_a_plan_folder_checks_its_campaign_toml_as_a_campaign_does(tmp_path):
    """One reader of [units], [robot] and noise_std: a plan folder's NaN target offset is
    refused with the file and the key, as load_campaign refuses it."""
    folder = _campaign(tmp_path, "# a plan")
    toml = folder / "campaign.toml"
    toml.write_text(toml.read_text().replace('source = "ur5"\n',
                                             'source = "ur5"\ntarget_offset = [0.0, nan, 0.0]\n'))
    for reader in (load_campaign, read_plan):
        with pytest.raises(FileFormatError, match=r"campaign\.toml, line 5.*\[robot\] "
                           r"target_offset must be three numbers in mm, finite"):
            reader(folder)


@pytest.mark.parametrize("prose", ["# force = 100 N along z", "# max force=100",
                                   "# config=P1 is the home pose", "# length of the tool = 0.1 m"])
def test_prose_comments_are_not_units_declarations(ur5, tmp_path, prose):
    """Only ``units:`` comments and comments made of unit pairs alone declare units."""
    text = plan_text("# units: angle=deg force=N length=mm").replace(HEADER, prose + "\n" + HEADER)
    plan, caught = read(tmp_path, text, ur5)
    assert caught == []
    np.testing.assert_allclose(plan.force, F_N)
    _, caught = read(tmp_path, plan_text(prose), ur5)
    assert len(caught) == 1 and "declares no units" in caught[0], caught


@given(st.lists(st.tuples(st.booleans(), st.sampled_from(["N.m/rad", "N/m", "N.mm/rad"])),
                max_size=6))
def test_a_stiffness_unit_is_refused_exactly_when_not_of_its_joints_kind(springs):
    """``wrong_stiffness_unit`` names the first joint whose unit is not N/m (prismatic) or
    N.m/rad (revolute), and nothing when every one is."""
    joints = [f"j{i}" for i in range(len(springs))]
    kinds = dict(zip(joints, (p for p, _ in springs), strict=True))
    units = [u for _, u in springs]
    bad = [j for j, (p, u) in zip(joints, springs, strict=True)
           if u != ("N/m" if p else "N.m/rad")]
    problem = wrong_stiffness_unit(joints, units, kinds.__getitem__)
    if not bad:
        assert problem is None
    else:
        assert problem is not None and f"joint {bad[0]!r}" in problem
        assert repr(units[joints.index(bad[0])]) in problem


def test_a_reading_a_hair_past_a_limit_is_not_blamed_on_the_units(tmp_path):
    """FIGAROH's TIAGo reads its torso lift at 0.350184 m, limits [0, 0.35] m: the warning
    said "check the angle and length units and the robot". A coordinate at most 1 % of its
    range past a limit is a reading at the end stop: said so, with how far past."""
    folder = _campaign(tmp_path, "# a campaign")
    text = (folder / "measurements.csv").read_text().replace(",80.0,", ",180.5,")
    (folder / "measurements.csv").write_text(text)
    with pytest.warns(DataFileWarning, match=r"\(elbow_joint\) = 180.5 deg, limits \[-180, "
                      r"180\] deg\); at most 0.5 deg past, 1 % of the range or less: readings "
                      r"at the end stops, the units look right"):
        load_campaign(folder)


def test_one_row_past_a_limit_among_rows_within_is_not_blamed_on_the_units(tmp_path):
    """FIGAROH's TIAGo (exp_data_oct.csv, rad): the last of 22 rows reads arm_4_joint at
    -0.896 rad, limits [-0.393, 2.356] rad, and the warning said "the angles look like
    degrees" (in degrees every row would sit within a few degrees of zero, inside every
    limit). A minority of rows beyond, every other row within the limits in the declared unit,
    is a misread or mistyped row: said so, naming its line; every row beyond still names the
    degrees."""
    folder = tmp_path / "camp"
    folder.mkdir()
    (folder / "campaign.toml").write_text(
        'name = "t"\nbaseline = "enhanced"\n[robot]\nsource = "ur5"\n'
        '[units]\nangle = "rad"\nforce = "N"\nlength = "mm"\n'
        '[measurement]\ndata = "measurements.csv"\n')
    q = np.random.default_rng(0).uniform(-1.2, 1.2, (5, 6))
    q[3, 2] = 3.6  # elbow_joint, limits [-pi, pi]: 0.46 rad past, 7 % of its range
    rows = "".join(f"P{i},{','.join(f'{v:.4f}' for v in r)},0,0,100,0.1,0.2,0.3\n"
                   for i, r in enumerate(q))
    (folder / "measurements.csv").write_text(f"{HEADER},dx,dy,dz\n{rows}")
    with pytest.warns(DataFileWarning) as caught:
        load_campaign(folder)
    said = [str(w.message) for w in caught if "joint limits" in str(w.message)]
    assert len(said) == 1 and "look like degrees" not in said[0], said
    assert said[0].endswith("the other 4 rows are within them: a misread or mistyped value on "
                            "line 5 rather than a unit; check that row"), said[0]
    (folder / "measurements.csv").write_text(f"{HEADER},dx,dy,dz\n" + "".join(
        f"P{i},10,-60,80,-20,90,{i}.5,0,0,100,0.1,0.2,0.3\n" for i in range(5)))
    with pytest.warns(DataFileWarning, match="the angles look like degrees"):
        load_campaign(folder)
