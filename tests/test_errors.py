"""Typed errors (stiffness.errors): each is raised on its bad input, and the CLI turns it into
exit status 2 and one line on stderr."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest

from stiffness import errors
from stiffness.calibration.campaign import load_campaign
from stiffness.cli import main as cli
from stiffness.elastic.effects import make_effect
from stiffness.elastic.effects.geometry import Geometry
from stiffness.elastic.model_file import read_model_file
from stiffness.errors import (
    ConvergenceError,
    FileFormatError,
    LoopClosureError,
    MissingFileError,
    SingularConfigurationError,
    StiffnessError,
    UnknownEffectError,
    UnknownFrameError,
    UnknownJointError,
    UnknownNameError,
    UnknownRobotError,
    UnstableEquilibriumError,
)
from stiffness.files import read_json, read_toml, read_yaml
from stiffness.mechanics.equilibrium import solve_equilibrium
from stiffness.mechanics.formulation import tangent_joint_stiffness, target_state
from stiffness.planning.simulate import parse_effect
from stiffness.robot.loops import read_loop_declaration
from stiffness.robot.robot import load_robot
from stiffness.robot.sources import robots_directory

TABLE2 = robots_directory() / "sk120" / "campaigns" / "table2"
DOCS_PATH = Path(__file__).resolve().parents[1] / "docs" / "compensation" / "ur5-poses.csv"


def _one_line_error(capsys, argv: list[str]) -> str:
    """Run the CLI; assert exit 2, nothing on stdout, one line on stderr without traceback."""
    assert cli.main(argv) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(f"stiffness {argv[0]}: error: ")
    return err


def test_every_error_is_a_stiffness_error_and_a_value_error():
    for cls in (UnknownNameError, UnknownRobotError, UnknownFrameError, UnknownJointError,
                UnknownEffectError, MissingFileError, FileFormatError, SingularConfigurationError,
                LoopClosureError, ConvergenceError, UnstableEquilibriumError):
        assert issubclass(cls, StiffnessError) and issubclass(cls, ValueError)
    for cls in (UnknownRobotError, UnknownFrameError, UnknownJointError, UnknownEffectError):
        assert issubclass(cls, UnknownNameError)


def test_errors_survive_pickling_and_context():
    """Dask and multiprocessing send errors between processes: type and attributes survive."""
    exc = FileFormatError("bad cell", path="m.csv", line=3, column=5, field="fy")
    assert str(exc) == "m.csv, line 3, column 5 (fy): bad cell"
    back = pickle.loads(pickle.dumps(exc))
    assert type(back) is FileFormatError and (back.line, back.column, back.field) == (3, 5, "fy")
    assert str(back) == str(exc)
    named = UnknownJointError("no joint 'j'", name="j", choices=["a", "b"])
    wrapped = errors.with_context(named, "row 4")
    assert type(wrapped) is UnknownJointError and str(wrapped) == "row 4: no joint 'j'"
    assert wrapped.choices == ("a", "b") and str(named) == "no joint 'j'"
    assert pickle.loads(pickle.dumps(wrapped)).choices == ("a", "b")


def test_unknown_names_carry_the_choices(sk120):
    with pytest.raises(UnknownRobotError) as info:
        load_robot("sk12O")
    assert info.value.name == "sk12O" and "sk120" in info.value.choices
    assert "ur5" in info.value.choices  # example-robot-data names are choices too
    with pytest.raises(UnknownFrameError) as info:
        load_robot("sk120", frame="nowhere")
    assert info.value.name == "nowhere" and "fixture_target" in info.value.choices
    with pytest.raises(UnknownJointError) as info:
        load_robot("sk120", compliant_joints=["joint1", "joint9"])
    assert info.value.name == "joint9" and info.value.choices == sk120.coordinate_joints
    with pytest.raises(UnknownEffectError) as info:
        parse_effect("warp:joint2=1")
    assert info.value.name == "warp" and "backlash" in info.value.choices
    with pytest.raises(UnknownNameError) as info:
        tangent_joint_stiffness(np.eye(3), np.zeros((3, 3)), "linear")
    assert info.value.choices == ("conventional", "enhanced")


def test_an_unknown_joint_of_an_effect_is_named(sk120):
    """``backlash:nope`` said "backlash needs a joint", as if no joint had been given: the
    unknown joint is named, with the valid ones; without a joint the effect still asks for one."""
    geometry = Geometry.of(sk120)
    with pytest.raises(UnknownJointError) as info:
        make_effect("backlash", "nope", geometry)
    message = str(info.value)
    assert message.startswith("backlash:nope: 'nope' is not a joint of sk120 with a spring; "
                              "valid names: joint1, joint2") and "needs" not in message
    assert info.value.name == "nope" and info.value.choices == sk120.coordinate_joints
    with pytest.raises(UnknownJointError, match="backlash needs a joint, e.g. backlash:joint1"):
        make_effect("backlash", None, geometry)


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(MissingFileError) as info:
        load_campaign(tmp_path / "nothere")
    assert info.value.path == tmp_path / "nothere"
    with pytest.raises(MissingFileError):
        read_model_file(tmp_path / "none.json")
    with pytest.raises(MissingFileError):
        load_robot(str(tmp_path / "none.urdf"))
    toml = tmp_path / "bad.toml"
    toml.write_text('name = "x"\nbaseline = \n')
    with pytest.raises(FileFormatError) as info:
        read_toml(toml)
    assert (info.value.line, info.value.column) == (2, 12)
    js = tmp_path / "bad.json"
    js.write_text('{"a": 1,\n  }')
    with pytest.raises(FileFormatError) as info:
        read_json(js)
    assert (info.value.line, info.value.column) == (2, 3)
    yml = tmp_path / "bad.loops.yaml"
    yml.write_text("closed_loop: [[a, b]\ntype: [3D]\n")
    with pytest.raises(FileFormatError) as info:
        read_yaml(yml)
    assert info.value.line == 2
    yml.write_text("closed_loop: [[a, b]]\ntype: [2D]\nname_mot: [j]\n")
    with pytest.raises(FileFormatError, match="loop type '2D' is not supported"):
        read_loop_declaration(yml)
    urdf = tmp_path / "bad.urdf"
    urdf.write_text('<robot name="r">\n  <link name="a">\n</robot>\n')
    with pytest.raises(FileFormatError) as info:
        load_robot(str(urdf))
    assert info.value.path == urdf and info.value.line == 3


def test_campaign_errors_point_at_the_line_and_key(tmp_path):
    folder = tmp_path / "c"
    folder.mkdir()
    text = (TABLE2 / "campaign.toml").read_text()
    (folder / "measurements.csv").write_text((TABLE2 / "measurements.csv").read_text())
    (folder / "campaign.toml").write_text(text.replace('length = "mm"', 'length = "furlong"'))
    with pytest.raises(FileFormatError) as info:
        load_campaign(folder)
    line = next(i for i, raw in enumerate(text.splitlines(), 1) if raw.startswith("length"))
    assert (info.value.line, info.value.column, info.value.field) == (line, 1, "[units] length")
    (folder / "campaign.toml").write_text(text)
    rows = (TABLE2 / "measurements.csv").read_text().splitlines()
    header = next(i for i, raw in enumerate(rows) if raw.startswith("config"))
    cells = rows[header + 1].split(",")
    cells[-1] = "oops"
    rows[header + 1] = ",".join(cells)
    (folder / "measurements.csv").write_text("\n".join(rows) + "\n")
    with pytest.raises(FileFormatError) as info:
        load_campaign(folder)
    assert (info.value.line, info.value.column) == (header + 2, len(cells))
    assert info.value.path.name == "measurements.csv"


def test_loop_closure_singular_convergence_unstable(non_grashof_four_bar, ur5):
    robot = load_robot(non_grashof_four_bar.urdf, frame="tool_tip")
    with pytest.raises(LoopClosureError):
        robot.configuration(np.array([np.pi, 0.0]))  # crank end out of the rocker's reach
    two = load_robot("ur5", frame="tool0",
                     compliant_joints=["shoulder_pan_joint", "shoulder_lift_joint"])
    state = target_state(two, two.configuration(np.zeros(6)), np.array([0.0, 0.0, -1.0]))
    from stiffness.mechanics.formulation import cartesian_stiffness, compliance

    with pytest.raises(SingularConfigurationError):  # two springs cannot hold three directions
        cartesian_stiffness(compliance(state.jacobian[:3], np.diag([1e5, 1e5])))
    # UR5 column pointing up, soft joints: 100 N on top buckles it
    q0 = ur5.configuration(np.array([0.0, -np.pi / 2 + 1e-2, 0.0, -np.pi / 2, 0.0, 0.0]))
    k_theta = np.diag([100.0] * 6)
    load = np.array([0.0, 0.0, -100.0])
    start = target_state(ur5, q0, load)
    assert np.linalg.eigvalsh(0.5 * (k_theta - start.k_c + (k_theta - start.k_c).T))[0] < 0
    with pytest.raises(UnstableEquilibriumError):
        solve_equilibrium(ur5, q0, k_theta, load)
    solve_equilibrium(ur5, q0, k_theta, load / 10)  # a tenth of it is held
    q1 = ur5.configuration(np.array([0.0, -1.0, 1.0, 0.0, 1.0, 0.0]))
    with pytest.raises(ConvergenceError):
        solve_equilibrium(ur5, q1, np.diag([3e5] * 6), np.array([0.0, 0.0, -1e3]),
                          max_iterations=1, tolerance=1e-300)


@pytest.mark.parametrize(("argv", "words"), [
    (["kx", "--robot", "sk12O"], "unknown robot 'sk12O'"),
    (["kx", "--robot", "sk120", "--frame", "nowhere"], "frame 'nowhere' is not in sk120"),
    (["kx", "--robot", "ur5", "--q", "elbw=1", "--kq", "1,1,1,1,1,1", "--wrench", "0,0,-1"],
     "'elbw' is not a coordinate of ur5"),
    (["kx", "--robot", "panda", "--q", "panda_finger_joint2=0.01", "--kq", "1,1,1,1,1,1,1",
      "--wrench", "0,0,-1"], "'panda_finger_joint2' is not a coordinate of panda (a mimic "
     "follower: it follows panda_finger_joint1, set that)"),
    (["kx", "--robot", "sk120", "--model", "{tmp}/none.json"], "no such file"),
    (["kx", "--robot", "sk120", "--model", "{tmp}/bad.json"], "bad.json, line 1, column 2"),
    (["kx", "--robot", "sk120", "--deg", "--q", "-33.2,15.9,-105.9,0,-34.4,-90"],
     "loop of sk120 is singular"),
    (["identify", "{tmp}/none"], "not found"),
    (["identify", "{tmp}/bad.toml"], "bad.toml, line 2, column 12"),
    (["diagnose", "{tmp}/bad.toml"], "is not valid TOML"),
    (["simulate", "--robot", "sk120", "--effect", "warp=1", "--out", "{tmp}/s"],
     "unknown effect 'warp'"),
    (["simulate", "--robot", "ur5", "--kq", "100,100,100,100,100,100", "--max-force", "1000",
      "--configs", "1", "--loads-per-config", "1", "--out", "{tmp}/s"], "did not converge"),
    (["view", "--robot", "sk120", "--path", "{tmp}/none.csv", "--export", "{tmp}/v.html"],
     "no such file"),
    (["scan", "--robot", "sk120", "--axis", "joint9=0:1:1", "--out", "{tmp}/x"],
     "'joint9' is not a coordinate of sk120"),
    (["check-jacobian", "--samples", "-1"], "--samples must be >= 0"),
    (["identify", str(TABLE2 / "measurements.csv")],
     "measurements.csv is a CSV file, not a campaign; give the campaign.toml"),
    (["simulate", "--robot", "ur5", "--kq", "1e5,1e5,1e5,1e4,1e4,1e4", "--noise", "-1",
      "--out", "{tmp}/s"], "--noise must be a finite standard deviation >= 0, in mm; got -1"),
    (["design", "--robot", "ur5", "--kq", "1e5,1e5,1e5,1e4,1e4,1e4", "--configs", "2",
      "--max-force", "100", "--noise", "-0.01", "--units", "um", "--out", "{tmp}/d"],
     "--noise must be a finite standard deviation > 0, in um; got -0.01"),
    (["design", "--robot", "ur5", "--kq", "1e5,1e5,1e5,1e4,1e4,1e4", "--configs", "2",
      "--max-force", "100", "--candidates", "10001", "--out", "{tmp}/d"],
     "--candidates 10001 is more than 10000"),
    (["diagnose", str(TABLE2), "--max-steps", "-1"],
     "--max-steps must be a non-negative integer (0: the baseline only), got -1"),
    (["posture", "--robot", "ur5", "--kq", "1e5,1e5,1e5,1e4,1e4,1e4", "--path", "{tmp}/p.csv",
      "--figure", "{tmp}/f.txt", "--out", "{tmp}/o.csv"], "the figure is a PNG image"),
])
def test_cli_turns_each_error_into_exit_2_and_one_line(tmp_path, capsys, argv, words):
    (tmp_path / "bad.json").write_text("{oops")
    (tmp_path / "bad.toml").write_text('name = "x"\nbaseline = \n')
    err = _one_line_error(capsys, [a.replace("{tmp}", str(tmp_path)) for a in argv])
    assert words in err


@pytest.mark.parametrize(("argv", "words"), [
    (["simulate", "--robot", "ur5", "--rotation-noise", "nan", "--out", "s"],
     "argument --rotation-noise: 'nan' is not a finite number"),
    (["posture", "--robot", "ur5", "--singularity-margin", "nan", "--out", "o.csv"],
     "argument --singularity-margin: 'nan' is not a finite number"),
    (["simulate", "--robot", "ur5", "--max-force", "1e13", "--out", "s"],
     "argument --max-force: 1e13 is beyond +-1e+12"),
])
def test_one_number_flags_are_usage_errors_in_one_line(capsys, argv, words):
    """A one-number flag that is not a finite number within +-1e12: the parser's usage error
    (exit 2, one line), before anything runs."""
    with pytest.raises(SystemExit) as info:
        cli.main(argv)
    out, err = capsys.readouterr()
    assert info.value.code == 2 and out == "" and err.count("\n") == 1 and words in err, err


def test_cli_loop_that_cannot_close(non_grashof_four_bar, capsys):
    err = _one_line_error(capsys, ["kx", "--robot", str(non_grashof_four_bar.urdf), "--frame",
                                   "tool_tip", "--q", "3.14159,0", "--kq", "1e3,1e3",
                                   "--wrench", "0,0,-1"])
    assert "cannot be closed" in err or "does not close" in err


@pytest.mark.parametrize("cls", [UnknownRobotError, FileFormatError, LoopClosureError,
                                 ConvergenceError, UnstableEquilibriumError])
def test_main_maps_every_type_to_one_line(monkeypatch, capsys, cls):
    """A command raising any typed error (even with a multi-line message) exits 2, one line."""
    kwargs = {UnknownRobotError: {"name": "x", "choices": ["a"]},
              FileFormatError: {"path": "f.csv", "line": 2}}.get(cls, {})

    class Command:
        @staticmethod
        def configure_parser(parser):
            parser.add_argument("--q")

        @staticmethod
        def run(args):
            raise cls("first line\nsecond line", **kwargs)

    monkeypatch.setitem(cli.COMMANDS, "boom", ("boom_command", "raises"))
    monkeypatch.setitem(__import__("sys").modules, "boom_command", Command)
    err = _one_line_error(capsys, ["boom", "--q", "-1,2"])
    assert err.rstrip().endswith("first line second line")


@pytest.mark.parametrize("separator", [";", "\t"])
def test_csv_with_another_separator_is_named(tmp_path, separator):
    """A spreadsheet's ';' (decimal commas) or a tab-separated export: every reader of the
    toolkit's own CSV files says which separator it found, in one line, instead of a missing
    'config' or coordinate column (campaign, pose campaign, joint path, plan). The rig import
    reads them since 6 December 2026 (tests/test_spreadsheet_edges.py)."""
    from stiffness.calibration.pose_campaign import load_pose_campaign
    from stiffness.machining.joint_path import read_joint_path
    from stiffness.planning.plan import read_plan

    def semi(source: Path, target: Path) -> Path:
        target.write_text(source.read_text().replace(",", separator))
        return target

    word = "';'" if separator == ";" else "tabs"
    campaign = tmp_path / "c"
    campaign.mkdir()
    (campaign / "campaign.toml").write_text((TABLE2 / "campaign.toml").read_text())
    semi(TABLE2 / "measurements.csv", campaign / "measurements.csv")
    poses = tmp_path / "p"
    poses.mkdir()
    (poses / "campaign.toml").write_text(
        'kind = "poses"\n[robot]\nsource = "sk120"\n[units]\nangle = "deg"\nlength = "mm"\n'
        '[measurement]\ndata = "m.csv"\n[markers]\ntip = { frame = "fixture_target" }\n')
    (poses / "m.csv").write_text(separator.join(["config", "q1", "tip_x"]) + "\n"
                                 + separator.join(["A", "1", "2"]) + "\n")
    robot = load_robot("sk120")
    readers = [lambda: load_campaign(campaign), lambda: load_pose_campaign(poses),
               lambda: read_joint_path(semi(DOCS_PATH.parent / "sk120-path.csv",
                                            tmp_path / "path.csv"), robot),
               lambda: read_plan(campaign / "measurements.csv", robot)]
    for read in readers:
        with pytest.raises(FileFormatError, match=f"separated by {word}, not commas") as info:
            read()
        assert "\n" not in str(info.value)
