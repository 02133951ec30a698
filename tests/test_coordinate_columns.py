"""Campaign CSVs as controllers write them (issue 38, item 1): coordinate columns named after
the robot's joints, any subset in any order, the rest held at ``[robot] fixed`` values or the
robot's reference configuration (said once); unknown columns ignored with a warning (refused
under ``--strict``); q1..qn unchanged. Checked on example-robot-data's TIAGo (48 coordinates,
a controller logs its 8 arm and torso joints) against the coordinates written.
"""

from __future__ import annotations

import contextlib
import io
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stiffness.calibration.campaign import load_campaign
from stiffness.calibration.campaign_toml import RobotSettings
from stiffness.calibration.measurements import read_rows
from stiffness.calibration.pose_campaign import load_pose_campaign
from stiffness.calibration.rig_import import ImportSettings, import_campaign
from stiffness.cli.main import main
from stiffness.errors import (
    DataFileNote,
    FileFormatError,
    StiffnessError,
    UnknownColumnWarning,
)
from stiffness.mechanics.defaults import reference_configuration
from stiffness.robot.robot import load_robot
from stiffness.robot.sources import robots_directory
from stiffness.units import Units

LOGGED = ("torso_lift_joint", "arm_1_joint", "arm_2_joint", "arm_3_joint", "arm_4_joint",
          "arm_5_joint", "arm_6_joint", "arm_7_joint")
TOML = """\
name = "tiago-rig"
baseline = "enhanced"
[robot]
source = "tiago"
{extra}
[units]
angle = "deg"
force = "N"
length = "mm"
[measurement]
data = "measurements.csv"
"""


@pytest.fixture(scope="module")
def tiago():
    return load_robot("tiago")


def logged_rows(robot, n: int, seed: int = 0) -> np.ndarray:
    """(n, 8) logged coordinates (deg; torso in mm) inside the joints' limits."""
    rng = np.random.default_rng(seed)
    lo, hi = robot.model.lowerPositionLimit, robot.model.upperPositionLimit
    out = np.empty((n, len(LOGGED)))
    for k, name in enumerate(LOGGED):
        i = robot.model.joints[robot.model.getJointId(name)].idx_q
        value = rng.uniform(lo[i] + 0.1 * (hi[i] - lo[i]), hi[i] - 0.1 * (hi[i] - lo[i]), n)
        out[:, k] = value * 1000 if robot.is_prismatic(name) else np.rad2deg(value)
    return out


def write_campaign(folder: Path, header: list[str], rows: list[list[str]], extra: str = ""
                   ) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "campaign.toml").write_text(TOML.format(extra=extra))
    text = ",".join(header) + "\n" + "\n".join(",".join(r) for r in rows) + "\n"
    (folder / "measurements.csv").write_text(text)
    return folder / "campaign.toml"


def expected_q(robot, logged: np.ndarray, order: list[str], fixed: dict | None = None
               ) -> np.ndarray:
    """The full coordinates (rad, m): TIAGo's reference with the logged joints set (and
    fixed)."""
    reference = reference_configuration(robot)
    assert reference is not None
    q = np.tile(reference.coords, (logged.shape[0], 1))
    for k, name in enumerate(order):
        j = robot.coordinate_joints.index(name)
        q[:, j] = logged[:, k] / 1000 if robot.is_prismatic(name) else np.deg2rad(logged[:, k])
    for name, value in (fixed or {}).items():
        q[:, robot.coordinate_joints.index(name)] = np.deg2rad(value)
    return q


LOAD = ["10", "-5", "20", "0.1", "-0.02", "0.3"]


def test_tiago_joint_columns_any_order_with_bookkeeping(tmp_path, tiago):
    """8 of TIAGo's 48 coordinates logged by name, shuffled, with a timestamp column: the q
    read is q0 with those 8 set; one note says 40 are held (the list summarised), one warning
    lists the ignored column; the same rows written as q1..q48 read the same."""
    logged = logged_rows(tiago, 4)
    order = list(np.random.default_rng(1).permutation(LOGGED))
    perm = [LOGGED.index(n) for n in order]
    header = ["config", "stamp", *order, "fx", "fy", "fz", "dx", "dy", "dz"]
    rows = [[f"P{i}", f"12:00:0{i}", *(repr(float(v)) for v in logged[i, perm]), *LOAD]
            for i in range(4)]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        c = load_campaign(write_campaign(tmp_path / "named", header, rows))
    want = expected_q(tiago, logged[:, perm], order)
    np.testing.assert_allclose(c.q, want, atol=1e-12)
    notes = [str(w.message) for w in caught if w.category is DataFileNote]
    unknown = [str(w.message) for w in caught if w.category is UnknownColumnWarning]
    assert len(notes) == 1 and "40 of 48 coordinates have no column and are held" in notes[0]
    assert "... and 32 more at the reference configuration, the zero pose" in notes[0], notes[0]
    assert len(unknown) == 1 and "column(s) stamp are not campaign columns" in unknown[0]
    # q1..q48 in the robot's order: the same campaign
    full = np.where([tiago.is_prismatic(j) for j in tiago.coordinate_joints], want * 1000,
                    np.rad2deg(want))
    q_header = ["config", *(f"q{i + 1}" for i in range(48)), "fx", "fy", "fz", "dx", "dy", "dz"]
    q_rows = [[f"P{i}", *(repr(float(v)) for v in full[i]), *LOAD] for i in range(4)]
    again = load_campaign(write_campaign(tmp_path / "q", q_header, q_rows))
    np.testing.assert_allclose(again.q, c.q, atol=1e-12)
    np.testing.assert_allclose(again.deflection, c.deflection)


def test_fixed_values_in_the_campaign_units_and_their_refusals(tmp_path, tiago):
    logged = logged_rows(tiago, 2)
    header = ["config", *LOGGED, "fx", "fy", "fz", "dx", "dy", "dz"]
    rows = [[f"P{i}", *(repr(float(v)) for v in logged[i]), *LOAD] for i in range(2)]
    toml = write_campaign(tmp_path, header, rows, "fixed = { head_1_joint = 30, head_2_joint "
                                                  "= -12.5 }")
    with pytest.warns(DataFileNote, match=r"head_1_joint = 30 deg, head_2_joint = -12.5 deg "
                                          r"\(\[robot\] fixed\)"):
        c = load_campaign(toml)
    np.testing.assert_allclose(c.q, expected_q(tiago, logged, list(LOGGED),
                                               {"head_1_joint": 30, "head_2_joint": -12.5}),
                               atol=1e-12)
    for extra, words in [
        ('fixed = { head_joint = 1 }', "not a coordinate joint of tiago; valid names:"),
        ('fixed = { arm_1_joint = 1 }', "which measurements.csv also reads"),
        ('fixed = { head_1_joint = "x" }', "must be a table of joint = value, in deg"),
    ]:
        toml = write_campaign(tmp_path, header, rows, extra)
        with pytest.raises(FileFormatError) as info:
            load_campaign(toml)
        assert words in str(info.value) and "[robot] fixed" in str(info.value), info.value


@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_reader_takes_any_subset_in_any_order(tiago, tmp_path, data):
    """Property: any subset of the coordinate joints, in any order, among bookkeeping columns
    in any place, reads the written values and q0 elsewhere (the reader itself, robot loaded
    once)."""
    joints = data.draw(st.lists(st.sampled_from(tiago.coordinate_joints), min_size=1,
                                max_size=12, unique=True))
    extras = data.draw(st.lists(st.sampled_from(["time", "note", "temp_C", "seq", "q_raw"]),
                                max_size=3, unique=True))
    columns = [*joints, "fx", "fy", "fz", "dx", "dy", "dz", *extras]
    columns = data.draw(st.permutations(columns))
    values = data.draw(st.lists(st.floats(-1.0, 1.0), min_size=len(joints),
                                max_size=len(joints)))
    cell = dict(zip(joints, values, strict=True)) | dict(zip(
        ["fx", "fy", "fz", "dx", "dy", "dz"], [1.0, 2.0, 3.0, 0.1, 0.2, 0.3], strict=True))
    data_file = tmp_path / "m.csv"
    data_file.write_text("config," + ",".join(columns) + "\nA," + ",".join(
        repr(cell[c]) if c in cell else "x" for c in columns) + "\n")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rows = read_rows(data_file, tiago, Units("rad", "N", "m"), tmp_path / "c.toml", {},
                         StiffnessError)
    reference = reference_configuration(tiago)
    assert reference is not None
    want = reference.coords.copy()
    for name, value in zip(joints, values, strict=True):
        want[tiago.coordinate_joints.index(name)] = value
    np.testing.assert_allclose(rows.q[0], want, atol=1e-15)
    np.testing.assert_allclose(rows.force[0], [1.0, 2.0, 3.0])
    np.testing.assert_allclose(rows.deflection[0], [0.1, 0.2, 0.3])
    ignored = [w for w in caught if w.category is UnknownColumnWarning]
    assert len(ignored) == (1 if extras else 0)
    held = [w for w in caught if w.category is DataFileNote]
    assert len(held) == (1 if len(joints) < 48 else 0)


def test_pose_campaign_by_joint_name(tmp_path):
    """A pose campaign with UR5 joints named out of order and one held at [robot] fixed reads
    the same coordinates as q1..q6."""
    robot = load_robot("ur5")
    names = list(robot.coordinate_joints)
    q = np.array([[10.0, -40.0, 60.0, -20.0, 90.0, 5.0], [30.0, -60.0, 80.0, 10.0, 45.0, 5.0]])
    toml = ('kind = "poses"\nname = "p"\n[robot]\nsource = "ur5"\n{fixed}\n[units]\n'
            'angle = "deg"\nlength = "m"\n[measurement]\ndata = "measurements.csv"\n'
            '[markers]\ntip = {{ frame = "tool0" }}\n')
    (tmp_path / "q").mkdir()
    (tmp_path / "q" / "campaign.toml").write_text(toml.format(fixed=""))
    (tmp_path / "q" / "measurements.csv").write_text(
        "config," + ",".join(f"q{i + 1}" for i in range(6)) + ",tip_x,tip_y,tip_z\n"
        + "".join(f"P{i}," + ",".join(repr(float(v)) for v in q[i]) + ",0.1,0.2,0.3\n"
                  for i in range(2)))
    (tmp_path / "named").mkdir()
    (tmp_path / "named" / "campaign.toml").write_text(
        toml.format(fixed=f"fixed = {{ {names[5]} = 5 }}"))
    order = [4, 0, 3, 1, 2]
    (tmp_path / "named" / "measurements.csv").write_text(
        "config,tip_x,tip_y,tip_z," + ",".join(names[k] for k in order) + ",operator\n"
        + "".join(f"P{i},0.1,0.2,0.3," + ",".join(repr(float(q[i, k])) for k in order) + ",ann\n"
                  for i in range(2)))
    with pytest.warns(UnknownColumnWarning, match="operator"):
        named = load_pose_campaign(tmp_path / "named")
    np.testing.assert_allclose(named.q, load_pose_campaign(tmp_path / "q").q, atol=1e-12)


def test_strict_refuses_unknown_columns_in_one_line(tmp_path):
    folder = tmp_path / "table2"
    shutil.copytree(robots_directory() / "sk120" / "campaigns" / "table2", folder)
    data = next(folder.glob("*.csv"))
    lines = data.read_text().splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("config"))
    lines = [line + (",temp" if i == header else ",21.5" if i > header and line.strip()
                     and not line.startswith("#") else "") for i, line in enumerate(lines)]
    data.write_text("\n".join(lines) + "\n")
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(["identify", str(folder), "--strict", "--out", str(tmp_path / "m.json")])
    assert code == 2
    assert err.getvalue().count("\n") == 1 and "column(s) temp are not campaign columns" in \
        err.getvalue() and "Traceback" not in err.getvalue(), err.getvalue()
    assert "ignored, refused under --strict; remove or rename them" in err.getvalue()
    assert not (tmp_path / "m.json").exists()


def test_import_maps_by_joint_name_and_names_the_joints(tmp_path, tiago):
    """``campaign import --map arm_1_joint=theta1,...``: the mapped joints read, the rest held;
    a file without coordinate columns is refused naming the joints."""
    logged = logged_rows(tiago, 3)
    rig = tmp_path / "rig.csv"
    rig.write_text("label," + ",".join(f"theta{k}" for k in range(8)) + ",Fx,Fy,Fz,DX,DY,DZ\n"
                   + "".join(f"P{i}," + ",".join(repr(float(v)) for v in logged[i])
                             + ",1,2,3,0.1,0.2,0.3\n" for i in range(3)))
    column_map = {"config": "label", **{j: f"theta{k}" for k, j in enumerate(LOGGED)},
                  "fx": "Fx", "fy": "Fy", "fz": "Fz", "dx": "DX", "dy": "DY", "dz": "DZ"}
    units = {"angle": "deg", "force": "N", "length": "mm"}
    with pytest.warns(DataFileNote, match="40 of 48 coordinates have no column"):
        campaign, report = import_campaign([rig], RobotSettings("tiago"),
                                           ImportSettings(column_map, units), robot=tiago)
    np.testing.assert_allclose(campaign.q, expected_q(tiago, logged, list(LOGGED)), atol=1e-12)
    assert report.columns["arm_1_joint"]["unit"] == "deg"
    assert report.columns["torso_lift_joint"]["unit"] == "mm"
    with pytest.raises(StiffnessError, match="no coordinate column in .*rig.csv: map the "
                                             "joints read .*torso_lift_joint, arm_1_joint"):
        import_campaign([rig], RobotSettings("tiago"),
                        ImportSettings({"fx": "Fx", "fy": "Fy", "fz": "Fz", "dx": "DX",
                                        "dy": "DY", "dz": "DZ"}, units), robot=tiago)
    with pytest.raises(StiffnessError, match=r"no column for q2 \(arm_1_joint\), q3 "
                                             r"\(arm_2_joint\)"):
        import_campaign([rig], RobotSettings("tiago"),
                        ImportSettings({"q1": "theta0", "fx": "Fx", "fy": "Fy", "fz": "Fz",
                                        "dx": "DX", "dy": "DY", "dz": "DZ"}, units),
                        robot=tiago)
