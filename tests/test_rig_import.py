"""``stiffness campaign import``: rig files as they come (issue 28, item 3).

The round trip: a campaign written by ``simulate`` is split into three CSV files with the
rig's own column names, forces in the tool frame (rotated with Pinocchio's frame placement,
computed here apart from the importer's route) and deflections as loaded and unloaded
positions in mm (the target's position from Pinocchio plus the deflection); the import gives
back the same rows to 1e-12 and ``identify`` the same stiffnesses. Bad input: one line naming
file, line and column; the reader contract under hypothesis mutations.
"""

from __future__ import annotations

import contextlib
import csv
import io
import re
import warnings
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from fuzzing import FUZZ, assert_reader_contract, csv_mutation, toml_mutation, write_text
from hypothesis import given
from hypothesis import strategies as st

from stiffness.calibration.campaign import load_campaign
from stiffness.calibration.campaign_toml import RobotSettings
from stiffness.calibration.identify import identify
from stiffness.calibration.rig_import import (
    ImportSettings,
    import_campaign,
    parse_pairs,
    read_mapping_file,
)
from stiffness.cli.main import main
from stiffness.errors import DataFileNote, FlagValueWarning, StiffnessError, UnknownColumnWarning

JOINTS = "shoulder_pan_joint,shoulder_lift_joint,elbow_joint"
MAP = ("config=label," + ",".join(f"q{i}=theta{i}" for i in range(1, 7))
       + ",fx=Tool_Fx,fy=Tool_Fy,fz=Tool_Fz,x_loaded=X1,y_loaded=Y1,z_loaded=Z1,"
       "x_unloaded=X0,y_unloaded=Y0,z_unloaded=Z0")


def run_cli(*argv: str) -> tuple[int, str]:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(list(argv))
    return code, out.getvalue()


@pytest.fixture(scope="module")
def original(tmp_path_factory):
    """A small simulated UR5 campaign (conventional baseline, declared noise)."""
    folder = tmp_path_factory.mktemp("sim")
    code, _ = run_cli("simulate", "--robot", "ur5", "--compliant-joints", JOINTS,
                      "--kq", "3e4,2e4,1.5e4", "--configs", "5", "--loads-per-config", "3",
                      "--noise", "0.01", "--baseline", "conventional", "--quiet",
                      "--out", str(folder))
    assert code == 0
    return load_campaign(folder)


def tool_pose(campaign, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (base <- tool) and target position (m) at row ``i``, straight from
    Pinocchio (UR5: no loops, q is the coordinates)."""
    robot = campaign.robot()
    model, data = robot.model, robot.model.createData()
    pin.framesForwardKinematics(model, data, campaign.q[i])
    placement = data.oMf[robot.target_frame_id]
    return placement.rotation.copy(), placement.act(robot.target_offset)


def write_csv(path: Path, header: list[str], rows: list[list]) -> Path:
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows([[repr(float(v)) if isinstance(v, float | np.floating) else v for v in r]
                      for r in rows])
    return path


def rig_files(c, folder: Path) -> list[Path]:
    """Three files joined by a sample key (the tracker's rows shuffled): joint angles in deg
    with labels, forces in the tool frame (N), loaded and unloaded positions in mm."""
    folder.mkdir(parents=True, exist_ok=True)
    joints, forces, tracker = [], [], []
    for i in range(c.n_rows):
        rot, p = tool_pose(c, i)
        joints.append([f"S{i:03d}", c.config[i], *np.degrees(c.q[i])])
        forces.append([f"S{i:03d}", *(rot.T @ c.force[i])])
        tracker.append([f"S{i:03d}", *(p * 1e3), *((p + c.deflection[i]) * 1e3)])
    tracker = [tracker[i] for i in np.random.default_rng(0).permutation(len(tracker))]
    return [write_csv(folder / "joints.csv", ["sample", "label",
                                               *(f"theta{i}" for i in range(1, 7))], joints),
            write_csv(folder / "forces.csv", ["sample", "Tool_Fx", "Tool_Fy", "Tool_Fz"],
                      forces),
            write_csv(folder / "tracker.csv", ["sample", "X0", "Y0", "Z0", "X1", "Y1", "Z1"],
                      tracker)]


def assert_same_rows(a, b) -> None:
    for name in ("q", "force", "deflection"):
        x, y = getattr(a, name), getattr(b, name)
        np.testing.assert_allclose(y, x, rtol=0, atol=1e-12 * np.max(np.abs(x)), err_msg=name)
    assert tuple(a.config) == tuple(b.config)


def test_round_trip_three_files_tool_forces_positions_in_mm(original, tmp_path):
    files = rig_files(original, tmp_path / "rig")
    code, text = run_cli("campaign", "import", *map(str, files), "--robot", "ur5",
                         "--compliant-joints", JOINTS, "--map", MAP, "--join", "sample",
                         "--units", "angle=deg,force=N,length=mm", "--force-frame", "tool",
                         "--noise", "0.01", "--baseline", "conventional",
                         "--out", str(tmp_path / "imported"))
    assert code == 0, text
    assert f"{original.n_rows} campaign rows" in text
    assert re.search(r"q1 +<- joints.csv:theta1 .* deg", text)
    assert re.search(r"fx +<- forces.csv:Tool_Fx .* N", text)
    assert "as loaded and unloaded positions" in text
    back = load_campaign(tmp_path / "imported")
    assert_same_rows(original, back)
    assert back.noise_std_m == pytest.approx(original.noise_std_m, rel=1e-12)
    k_original = identify(original, starts=2).k
    k_back = identify(back, starts=2).k
    np.testing.assert_allclose(k_back, k_original, rtol=1e-8)


def test_paired_rows_with_tool_frame_deflections(original, tmp_path):
    """One file, an unloaded row per pose and its loaded rows after it, deflections in the
    tool frame as positions (mm) in tool axes; labels from the poses (P1, P2, ...)."""
    rows, pair = [], 0
    for i in range(original.n_rows):
        rot, p = tool_pose(original, i)
        angles = list(np.degrees(original.q[i]))
        if i == 0 or original.config[i] != original.config[i - 1]:
            pair += 1
            rows.append([f"pose{pair}", "unloaded", *angles, 0.0, 0.0, 0.0, *(rot.T @ p * 1e3)])
        rows.append([f"pose{pair}", "LOADED", *angles, *original.force[i],
                     *(rot.T @ (p + original.deflection[i]) * 1e3)])
    path = write_csv(tmp_path / "rig.csv", ["pose", "what", *(f"q{i}" for i in range(1, 7)),
                                            "fx", "fy", "fz", "x", "y", "z"], rows)
    settings = ImportSettings({"pair": "pose", "state": "what"},
                              {"angle": "deg", "force": "N", "length": "mm"},
                              deflection_frame="tool")
    campaign, report = import_campaign([path], RobotSettings("ur5", compliant_joints=tuple(
        JOINTS.split(","))), settings, baseline="conventional")
    assert report.deflections == "as paired loaded/unloaded rows"
    for name in ("q", "force", "deflection"):
        x, y = getattr(original, name), getattr(campaign, name)
        np.testing.assert_allclose(y, x, rtol=0, atol=1e-12 * np.max(np.abs(x)))
    labels = dict(zip(original.config, campaign.config, strict=True))
    assert len(set(labels.values())) == len(labels) and set(labels.values()) == {
        f"P{i}" for i in range(1, len(labels) + 1)}


def test_units_from_headers_and_direct_deflections(original, tmp_path):
    """Direct dx,dy,dz in m and forces in kN, the units read from the headers."""
    c = original
    rows = [[*np.radians(np.degrees(c.q[i])), *(c.force[i] / 1e3), *c.deflection[i]]
            for i in range(c.n_rows)]
    header = [*(f"J{i} (rad)" for i in range(1, 7)), "F1 [kN]", "F2 [kN]", "F3 [kN]",
              "dx [m]", "dy [m]", "dz [m]"]
    path = write_csv(tmp_path / "one.csv", header, rows)
    mapping = {**{f"q{i}": f"J{i} (rad)" for i in range(1, 7)},
               "fx": "F1 [kN]", "fy": "F2 [kN]", "fz": "F3 [kN]"}  # dx [m]: by its name
    campaign, report = import_campaign([path], RobotSettings("ur5"), ImportSettings(mapping))
    assert (report.units.angle, report.units.force, report.units.length) == ("rad", "kN", "m")
    np.testing.assert_allclose(campaign.force, c.force, rtol=1e-12)
    np.testing.assert_allclose(campaign.deflection, c.deflection, rtol=0, atol=1e-18)


BASE_ROWS = ["q1,q2,q3,q4,q5,q6,fx,fy,fz,dx,dy,dz",
             "0,-90,90,0,90,0,10,0,0,0.1,0,0",
             "0,-80,90,0,90,0,0,10,0,0,0.1,0"]


def refusal(tmp_path, text: str, **settings) -> str:
    path = tmp_path / "rig.csv"
    path.write_text(text)
    units = settings.pop("units", {"angle": "deg", "force": "N", "length": "mm"})
    with pytest.raises(StiffnessError) as err:
        import_campaign([path], RobotSettings("ur5"), ImportSettings(units=units, **settings))
    message = str(err.value)
    assert "\n" not in message
    return message


def test_refusals_name_file_line_and_column(tmp_path):
    rows = list(BASE_ROWS)
    rows[2] = "0,-80,90,0,90,0,0,ten,0,0,0.1,0"
    msg = refusal(tmp_path, "\n".join(rows))
    assert "rig.csv, line 3, column 8 (fy)" in msg and "'ten' is not a number" in msg
    msg = refusal(tmp_path, "\n".join(BASE_ROWS), column_map={"fx": "Base_Fx"})
    assert "rig.csv" in msg and "no column 'Base_Fx' (mapped to fx)" in msg
    msg = refusal(tmp_path, "\n".join(BASE_ROWS), column_map={"qq1": "q1"})
    assert "'qq1', not a campaign column" in msg
    msg = refusal(tmp_path, "\n".join(BASE_ROWS), units={"angle": "deg", "force": "N"})
    assert "no length unit" in msg
    header = BASE_ROWS[0].replace("q1,q2", "q1 [deg],q2 [rad]")
    msg = refusal(tmp_path, "\n".join([header, *BASE_ROWS[1:]]),
                  column_map={"q1": "q1 [deg]", "q2": "q2 [rad]"}, units={"force": "N",
                                                                           "length": "mm"})
    assert "mixed units" in msg and "column 2 (q2 [rad])" in msg
    msg = refusal(tmp_path, "\n".join([header, *BASE_ROWS[1:]]),
                  column_map={"q1": "q1 [deg]", "q2": "q2 [rad]"})
    assert "mixed units" in msg and "column 2" in msg
    msg = refusal(tmp_path, "\n".join(BASE_ROWS + ["0,0,0"]))
    assert "rig.csv, line 4" in msg and "3 cells" in msg
    # a rig's 'Fx [N]' is not fx (names are exact): the refusal names the map that reads them
    header = BASE_ROWS[0].replace("fx,fy,fz", "Fx [N],Fy [N],Fz [N]")
    msg = refusal(tmp_path, "\n".join([header, *BASE_ROWS[1:]]))
    assert msg.endswith("no column for fx, fy, fz in " + str(tmp_path / "rig.csv") + "; the "
                        "files spell them Fx, Fy, Fz: map them (--map fx=Fx,fy=Fy,fz=Fz) or "
                        "rename the columns")


def test_unpaired_and_repeated_keys(tmp_path):
    head = "pair,state,q1,q2,q3,q4,q5,q6,fx,fy,fz,x,y,z"
    good = ["a,unloaded,0,-90,90,0,90,0,0,0,0,500,0,300",
            "a,loaded,0,-90,90,0,90,0,10,0,0,500.1,0,300"]
    msg = refusal(tmp_path, "\n".join([head, *good, "b,loaded,0,-80,90,0,90,0,10,0,0,1,2,3"]))
    assert "line 4, column 1 (pair)" in msg and "unpaired row" in msg
    msg = refusal(tmp_path, "\n".join([head, *good, "b,unloaded,0,-80,90,0,90,0,0,0,0,1,2,3"]))
    assert "line 4" in msg and "no loaded row" in msg
    msg = refusal(tmp_path, "\n".join([head, *good, "a,idle,0,-90,90,0,90,0,0,0,0,1,2,3"]))
    assert "line 4, column 2 (state)" in msg
    msg = refusal(tmp_path, "\n".join([head, good[0], good[1].replace("-90", "-91", 1)]))
    assert "line 3" in msg and "other coordinates" in msg
    a = tmp_path / "a.csv"
    b = tmp_path / "b.csv"
    a.write_text("k,q1,q2,q3\n1,0,0,0\n2,0,0,0\n")
    b.write_text("k,q4,q5,q6,fx,fy,fz,dx,dy,dz\n1,0,0,0,1,1,1,0,0,0\n1,0,0,0,1,1,1,0,0,0\n")
    with pytest.raises(StiffnessError, match=r"b.csv, line 3, column 1 \(k\): key '1' repeats"):
        import_campaign([a, b], RobotSettings("ur5"), ImportSettings(
            units={"angle": "deg", "force": "N", "length": "mm"}, join="k"))
    with pytest.raises(StiffnessError, match="b.csv: 2 data rows but a.csv has 2|same rows"):
        b.write_text("q4,q5,q6,fx,fy,fz,dx,dy,dz\n0,0,0,1,1,1,0,0,0\n")
        import_campaign([a, b], RobotSettings("ur5"), ImportSettings(
            units={"angle": "deg", "force": "N", "length": "mm"}))


def test_cli_refuses_in_one_line(tmp_path, capsys):
    path = tmp_path / "rig.csv"
    path.write_text("\n".join(BASE_ROWS))
    code = main(["campaign", "import", str(path), "--robot", "ur5", "--units",
                 "angle=deg,force=N", "--out", str(tmp_path / "out")])
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("stiffness campaign import: error:") and "\n" not in err
    assert not (tmp_path / "out").exists()
    code = main(["campaign", "import", str(path), "--robot", "ur5", "--units",
                 "angle=deg,force=N,length=mm", "--json", "--out", str(tmp_path / "out")])
    assert code == 0
    assert (tmp_path / "out" / "campaign.toml").is_file()


@pytest.fixture(scope="module")
def fuzz_folder(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("fuzz-import")
    (folder / "rig.csv").write_text("\n".join(BASE_ROWS) + "\n")
    return folder


@FUZZ
@given(data=st.data())
def test_import_reader_contract(fuzz_folder, data):
    text = "\n".join(BASE_ROWS) + "\n"
    mutated = data.draw(csv_mutation(text))
    settings = ImportSettings(units={"angle": "deg", "force": "N", "length": "mm"})
    try:
        write_text(fuzz_folder / "rig.csv", mutated)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = assert_reader_contract(lambda: import_campaign(
                [fuzz_folder / "rig.csv"], RobotSettings("ur5"), settings), fuzz_folder)
        if result is not None:
            campaign, _ = result
            assert np.all(np.isfinite(campaign.q)) and np.all(np.isfinite(campaign.deflection))
    finally:
        (fuzz_folder / "rig.csv").write_text(text)


MAPPING = """join = "sample"
force_frame = "tool"
deflection_frame = "base"
[columns]
q1 = "theta1"
fx = "Tool_Fx"
[units]
angle = "deg"
force = "N"
length = "mm"
"""


def test_mapping_file_is_read_and_flags_override_it(tmp_path):
    path = tmp_path / "map.toml"
    path.write_text(MAPPING)
    settings = read_mapping_file(path)
    assert settings.column_map == {"q1": "theta1", "fx": "Tool_Fx"}
    assert (settings.join, settings.force_frame, settings.units["length"]) == ("sample",
                                                                               "tool", "mm")
    path.write_text(MAPPING.replace('force_frame = "tool"', 'force_frame = "flange"'))
    with pytest.raises(StiffnessError, match="map.toml: the force frame must be base or tool"):
        read_mapping_file(path)


@FUZZ
@given(data=st.data())
def test_mapping_file_reader_contract(tmp_path_factory, data):
    folder = tmp_path_factory.mktemp("fuzz-map")
    mutated = data.draw(toml_mutation(MAPPING))
    write_text(folder / "map.toml", mutated)
    result = assert_reader_contract(lambda: read_mapping_file(folder / "map.toml"), folder)
    if result is not None:
        assert result.force_frame in ("base", "tool")
        assert all(isinstance(v, str) for v in result.column_map.values())


@FUZZ
@given(text=st.text(max_size=60))
def test_map_and_units_flags_parse_or_refuse_in_one_line(text):
    try:
        pairs = parse_pairs(text, "--map")
    except StiffnessError as exc:
        assert "\n" not in str(exc)
        return
    assert all(k and v and "," not in k for k, v in pairs.items())


def test_quiet_and_a_rig_that_loads_along_z_only(tmp_path, capsys):
    """Issue 38 item 10: ``campaign import --quiet`` prints only what it wrote; mapping only
    ``fz`` is accepted, fx and fy written as 0 with one note."""
    rig = tmp_path / "rig.csv"
    rig.write_text("theta1,theta2,theta3,theta4,theta5,theta6,Fz,dx,dy,dz\n"
                   "0,-60,90,0,45,0,3.5,0.1,0.2,0.3\n10,-50,80,0,45,0,-2,0.1,0.2,0.3\n")
    argv = ["campaign", "import", str(rig), "--robot", "ur5", "--map",
            ",".join(f"q{i}=theta{i}" for i in range(1, 7)) + ",fz=Fz",
            "--units", "angle=deg,force=N,length=mm", "--out", str(tmp_path / "c"), "--quiet"]
    with pytest.warns(DataFileNote, match="fx, fy: no column in .*taken as 0"):
        assert main(argv) == 0
    out = capsys.readouterr().out
    assert out.count("\n") == 1 and out.startswith("wrote "), out
    campaign = load_campaign(tmp_path / "c")
    np.testing.assert_allclose(campaign.force, [[0, 0, 3.5], [0, 0, -2.0]])


def test_a_noise_no_rig_has_is_warned_in_the_files_unit_and_m(tmp_path):
    """``campaign import --noise`` is in the files' length unit (here from --units): 2e-6 mm
    (2 nm, meant in m) is warned about in one line, in mm and in m, and written as given."""
    rig = tmp_path / "rig.csv"
    rig.write_text("theta1,theta2,theta3,theta4,theta5,theta6,Fz,dx,dy,dz\n"
                   "0,-60,90,0,45,0,3.5,0.1,0.2,0.3\n")
    argv = ["campaign", "import", str(rig), "--robot", "ur5", "--map",
            ",".join(f"q{i}=theta{i}" for i in range(1, 7)) + ",fz=Fz", "--noise", "2e-6",
            "--units", "angle=deg,force=N,length=mm", "--out", str(tmp_path / "c"), "--quiet"]
    with pytest.warns(FlagValueWarning, match=r"^--noise 2e-06 mm is 2e-09 m, below 10 nm"):
        assert main(argv) == 0
    assert load_campaign(tmp_path / "c").noise_std_m == pytest.approx(2e-9, rel=1e-12)


def test_the_column_echo_writes_minus_zero_as_zero(tmp_path, capsys):
    """A rig column of -0.0 (a spreadsheet's negative zero) is echoed 0 .. 0, not -0 .. -0
    (issue 38 item 10: no float noise in what is printed or written)."""
    rig = tmp_path / "rig.csv"
    rig.write_text("theta1,theta2,theta3,theta4,theta5,theta6,Fz,dx,dy,dz\n"
                   "0,-60,90,0,45,0,3.5,0.1,-0.0,0.3\n10,-50,80,0,45,0,-2,0.1,-0.0,0.3\n")
    argv = ["campaign", "import", str(rig), "--robot", "ur5", "--map",
            ",".join(f"q{i}=theta{i}" for i in range(1, 7)) + ",fz=Fz",
            "--units", "angle=deg,force=N,length=mm", "--out", str(tmp_path / "c")]
    with pytest.warns(DataFileNote):
        assert main(argv) == 0
    line = next(s for s in capsys.readouterr().out.splitlines() if s.lstrip().startswith("dy"))
    assert line.endswith("0 .. 0 mm") and "-0" not in line, line


def test_import_strict_refuses_columns_it_does_not_import(tmp_path, capsys):
    """Issue 38 item 1: a rig's bookkeeping column is listed and ignored by campaign import,
    refused under --strict (one line, nothing written), as identify/diagnose/validate do."""
    rig = tmp_path / "rig.csv"
    rig.write_text("shoulder_pan_joint,shoulder_lift_joint,elbow_joint,wrist_1_joint,"
                   "wrist_2_joint,wrist_3_joint,operator,fx,fy,fz,dx,dy,dz\n"
                   "0,-60,90,0,45,0,bob,1,2,30,0.01,0.02,0.03\n")
    argv = ["campaign", "import", str(rig), "--robot", "ur5", "--units",
            "angle=deg,force=N,length=mm", "--out", str(tmp_path / "c"), "--quiet"]
    assert main([*argv, "--strict"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "rig.csv:operator" in err and "--strict" in err, err
    assert not (tmp_path / "c").exists()
    with pytest.warns(UnknownColumnWarning, match="columns not imported: rig.csv:operator "):
        assert main(argv) == 0
    assert load_campaign(tmp_path / "c").n_rows == 1


def test_import_fixed_holds_the_joints_without_a_column(tmp_path, capsys):
    """Issue 38 item 1: campaign import --fixed JOINT=VALUE (files' unit), or fixed = {...} in
    the mapping file, holds the coordinates the rig did not log, as a campaign's [robot]
    fixed; the others stay at the reference configuration; a fixed joint with a column and
    an unknown joint are refused."""
    rig = tmp_path / "rig.csv"
    rig.write_text("shoulder_pan_joint,shoulder_lift_joint,elbow_joint,wrist_1_joint,"
                   "fx,fy,fz,dx,dy,dz\n0,-60,90,0,1,2,30,0.01,0.02,0.03\n"
                   "10,-50,80,5,1,2,30,0.01,0.02,0.03\n")
    argv = ["campaign", "import", str(rig), "--robot", "ur5", "--units",
            "angle=deg,force=N,length=mm", "--quiet"]
    with pytest.warns(DataFileNote, match=r"wrist_2_joint = 45 deg \(--fixed\); wrist_3_joint "
                                          r"at the reference configuration"):
        assert main([*argv, "--fixed", "wrist_2_joint=45", "--out", str(tmp_path / "a")]) == 0
    q = load_campaign(tmp_path / "a").q
    np.testing.assert_allclose(q[:, 4], np.radians(45.0), rtol=1e-15)
    np.testing.assert_allclose(q[:, 5], 0.0)  # the UR5's reference configuration
    mapping = tmp_path / "map.toml"
    mapping.write_text("fixed = { wrist_3_joint = -90.0 }\n")
    with pytest.warns(DataFileNote):
        assert main([*argv, "--map-file", str(mapping), "--out", str(tmp_path / "b")]) == 0
    np.testing.assert_allclose(load_campaign(tmp_path / "b").q[:, 5], np.radians(-90.0))
    capsys.readouterr()
    for fixed, words in (("elbow_joint=3", "--fixed holds elbow_joint, which rig.csv also "
                                           "reads"),
                         ("wrist_9_joint=3", "--fixed names 'wrist_9_joint', not a coordinate")):
        assert main([*argv, "--fixed", fixed, "--out", str(tmp_path / "c")]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and words in err, err


def test_a_column_mapped_to_a_marker_is_not_also_read_as_a_force(tmp_path, capsys):
    """A tracker's columns named fx,fy,fz, mapped to a marker's tip_x..tip_z, were also read
    as forces by their own names: the pose import refused with "no force unit" and, given
    one, wrote the marker positions again as a load in N (FIGAROH's UR10 file, its columns
    renamed so). A file column the map gives to one campaign column is that column's only."""
    rig = tmp_path / "rig.csv"
    rows = ["j1,j2,j3,j4,j5,j6,fx,fy,fz"] + [
        f"{a},-1.2,1.5,-0.3,1.57,0,{0.8 + a / 10},{0.1 * a},{1.1 - a / 20}" for a in range(6)]
    rig.write_text("\n".join(rows) + "\n")
    mapping = ",".join([f"q{i}=j{i}" for i in range(1, 7)] + ["tip_x=fx,tip_y=fy,tip_z=fz"])
    with warnings.catch_warnings():  # the made-up positions are not the UR10's: warned
        warnings.simplefilter("ignore")
        assert main(["campaign", "import", str(rig), "--kind", "poses", "--robot", "ur10",
                     "--map", mapping, "--units", "angle=rad,length=m", "--marker",
                     "tip=tool0", "--quiet", "--out", str(tmp_path / "c")]) == 0, \
            capsys.readouterr().err
    header = (tmp_path / "c" / "measurements.csv").read_text().splitlines()[0].split(",")
    assert header[-3:] == ["tip_x", "tip_y", "tip_z"] and "fx" not in header, header


def test_pose_import_refusals_name_the_fix(tmp_path, capsys):
    """A new user's slips with FIGAROH's TIAGo file, each one line naming the fix: no angle
    unit (the header example was 'Fx [N]', a force, for an angle), a marker frame misspelt
    (no closest names were offered), --marker without --kind poses."""
    rig = tmp_path / "rig.csv"
    rig.write_text("q1,q2,q3,q4,q5,q6,x1,y1,z1\n" + "".join(
        f"{a},-1.2,1.5,-0.3,1.57,0,{0.8 + a / 10},{0.1 * a},{1.1 - a / 20}\n" for a in range(4)))
    argv = ["campaign", "import", str(rig), "--robot", "ur10", "--map", "tip_x=x1,tip_y=y1,"
            "tip_z=z1", "--out", str(tmp_path / "c")]
    for extra, words in (
            (["--kind", "poses", "--marker", "tip=tool0"], "e.g. 'theta1 [deg]'; valid angle"),
            (["--kind", "poses", "--units", "angle=rad,length=m", "--marker", "tip=tool_0"],
             "Did you mean tool0"),
            (["--units", "angle=rad,length=m", "--marker", "tip=tool0"], "add --kind poses")):
        assert main([*argv, *extra]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and words in err, err


def test_import_never_replaces_the_rig_file_it_reads(tmp_path, capsys):
    """``campaign import rig/measurements.csv --out rig`` replaced the rig's own file (its
    extra columns and header units lost) with the converted campaign's measurements.csv."""
    rig = tmp_path / "rig"
    rig.mkdir()
    path = rig / "measurements.csv"
    path.write_text("\n".join(BASE_ROWS))
    before = path.read_bytes()
    argv = ["campaign", "import", str(path), "--robot", "ur5", "--units",
            "angle=deg,force=N,length=mm"]
    assert main([*argv, "--out", str(rig)]) == 2
    err = capsys.readouterr().err
    assert f"--out {rig} would replace the rig's file {path} with the campaign's " \
           "measurements.csv; give another --out folder" in err and err.count("\n") == 1
    assert path.read_bytes() == before and not (rig / "campaign.toml").exists()
    assert main([*argv, "--out", str(rig / "campaign"), "--quiet"]) == 0


def test_numeric_join_keys_match_by_value(tmp_path):
    """A controller's log numbers its samples 001, 002, ...; the load cell's file 1, 2, ...;
    the tracker's 1.0, 2.0, ...: the import refused "key '001' has no row in forces.csv".
    Numbers now match by their exact value (a 19-digit time stamp stays itself), other keys
    as written; '1' and '1.0' in one file are one key given twice, refused."""
    units = {"angle": "deg", "force": "N", "length": "mm"}
    rows = [r.split(",") for r in BASE_ROWS[1:]]

    def files(keys: list[list[str]]) -> list[Path]:
        out = []
        for name, cols, ks in zip(("j", "f", "t"), ((0, 6), (6, 9), (9, 12)), keys,
                                  strict=True):
            path = tmp_path / f"{name}.csv"
            head = BASE_ROWS[0].split(",")[cols[0]:cols[1]]
            path.write_text("\n".join([",".join(["k", *head])] + [
                ",".join([k, *r[cols[0]:cols[1]]]) for k, r in zip(ks, rows, strict=True)]))
            out.append(path)
        return out

    settings = ImportSettings(units=units, join="k")
    same, _ = import_campaign(files([["1", "2"]] * 3), RobotSettings("ur5"), settings)
    mixed, _ = import_campaign(files([["001", "002"], ["1", "2"], ["1.0", "2e0"]]),
                               RobotSettings("ur5"), settings)
    for name in ("q", "force", "deflection"):
        np.testing.assert_array_equal(getattr(mixed, name), getattr(same, name))
    stamps = ["1733472000123456789", "1733472000123456788"]
    import_campaign(files([stamps] * 3), RobotSettings("ur5"), settings)  # not one float
    with pytest.raises(StiffnessError, match=r"j.csv, line 3, column 1 \(k\): key '1.0' "
                                             "repeats line 2"):
        import_campaign(files([["1", "1.0"], ["1", "2"], ["1", "2"]]), RobotSettings("ur5"),
                        settings)
