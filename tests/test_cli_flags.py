"""The shared flag layer (stiffness.cli.flags): negative lists, name=value coordinates, aliases."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from stiffness.calibration.campaign import load_campaign
from stiffness.cli import flags
from stiffness.cli.main import build_parser, main
from stiffness.errors import FlagValueWarning, StiffnessError, UnknownJointError

UR5_KQ = "3e5,3e5,2e5,4e4,4e4,4e4"
UR5_DEG = [-35.0, -60.0, 95.0, -40.0, -70.0, 15.0]
UR5_JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
              "wrist_2_joint", "wrist_3_joint"]


def _kx(capsys, *argv: str) -> dict:
    assert main(["kx", *argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def _csv(values) -> str:
    return ",".join(f"{v:g}" for v in values)


def test_negative_lists_and_name_value_pairs_give_the_same_kx_on_ur5(capsys):
    """``--q -35,...`` (natural form), ``--q=-35,...`` and name=value pairs in another order."""
    common = ["--robot", "ur5", "--frame", "tool0", "--kq", UR5_KQ, "--deg"]
    natural = _kx(capsys, *common, "--q", _csv(UR5_DEG), "--wrench", "-10,0,-100")
    equals = _kx(capsys, *common, f"--q={_csv(UR5_DEG)}", "--wrench=-10,0,-100")
    # joint names and q1..q6 (1-based), in another order than the robot's
    names = [n if i % 2 else f"q{i + 1}" for i, n in enumerate(UR5_JOINTS)]
    pairs = ",".join(f"{n}={v:g}" for n, v in reversed(list(zip(names, UR5_DEG, strict=True))))
    named = _kx(capsys, *common, "--q", pairs, "--load", "-10,0,-100")
    for other in (equals, named):
        assert other["J"] == natural["J"] and other["K_X"] == natural["K_X"]
    # the values really are the given ones, converted from degrees
    np.testing.assert_allclose(natural["q"], np.deg2rad(UR5_DEG), rtol=0, atol=1e-15)
    assert natural["wrench"] == [-10.0, 0.0, -100.0]
    assert natural["q_named"] == dict(zip(UR5_JOINTS, natural["q"], strict=True))
    assert natural["sources"] == {"q": "flag --q", "wrench": "flag --wrench",
                                  "K_theta": "flag --kq"}


def test_negative_lists_and_pairs_on_the_sk120(sk120, capsys):
    """On the closed-loop SK120: partial pairs keep the shipped pose for the others."""
    shipped = _kx(capsys, "--robot", "sk120")
    q_deg = [float(v) for v in sk120.defaults["q_deg"]]  # negative first value
    assert q_deg[0] < 0
    natural = _kx(capsys, "--robot", "sk120", "--deg", "--q", ",".join(map(repr, q_deg)))
    only_two = _kx(capsys, "--robot", "sk120", "--deg", "--q",
                   f"joint3={q_deg[2]!r},joint1={q_deg[0]!r}")
    for other in (natural, only_two):
        assert other["q"] == shipped["q"]
        assert other["J"] == shipped["J"] and other["K_X"] == shipped["K_X"]
    assert shipped["sources"]["q"] == "robot default"
    assert only_two["sources"]["q"] == "flag --q (coordinates not named: robot default)"
    # a negative first value in the natural form, and a negative target offset
    moved = _kx(capsys, "--robot", "sk120", "--q", "-0.5,0.2,-1,0,-0.6,-1.5",
                "--target-offset", "-0.1,0,0.05", "--wrench", "-100,0,-200")
    assert moved["q"][0] == -0.5 and moved["target_offset"] == [-0.1, 0.0, 0.05]
    assert moved["wrench"] == [-100.0, 0.0, -200.0]


def test_plain_text_echoes_inputs_with_their_sources(capsys):
    assert main(["kx", "--robot", "sk120", "--q", "joint2=0.3"]) == 0
    text = capsys.readouterr().out
    assert "q [flag --q (coordinates not named: robot default)]" in text
    assert "joint2=0.3," in text
    assert "wrench [robot default (wrench_SI)]" in text and "fx=45.524" in text
    assert "K_theta [robot default]" in text
    assert main(["kx", "--robot", "sk120", "--quiet"]) == 0
    assert "K_theta [" not in capsys.readouterr().out


@pytest.mark.parametrize("command", ["kx", "view", "scan", "simulate"])
def test_every_command_takes_negative_lists(command, tmp_path, capsys):
    argv = {
        "kx": ["--robot", "sk120", "--q", "-0.5,0.2,-1,0,-0.6,-1.5", "--wrench", "-1,0,-2",
               "--target-offset", "-0.01,0,0"],
        "view": ["--robot", "sk120", "--q", "-0.5,0.2,-1,0,-0.6,-1.5", "--wrench", "-1,0,-2",
                 "--target-offset", "-0.01,0,0", "--export", str(tmp_path / "v.html")],
        "scan": ["--robot", "sk120", "--q", "-0.5,0.2,-1,0,-0.6,-1.5", "--wrench", "-1,0,-2",
                 "--load", "-3,0,0", "--target-offset", "-0.01,0,0", "--axis", "joint1=-1:1:1",
                 "--out", str(tmp_path / "s"), "--no-plots"],
        "simulate": ["--robot", "sk120", "--target-offset", "-0.01,0,0", "--configs", "2",
                     "--loads-per-config", "1", "--out", str(tmp_path / "c")],
    }[command]
    assert main([command, *argv, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    if command in ("kx", "view"):
        assert out["q_named"]["joint1"] == -0.5 and out["load_named"]["fx"] == -1.0
    if command == "scan":
        assert [c["load"] for c in out["load_cases"].values()] == [[-1.0, 0.0, -2.0],
                                                                   [-3.0, 0.0, 0.0]]
    if command == "simulate":  # --target-offset is in m, the campaign file in its own unit
        camp = load_campaign(tmp_path / "c")
        np.testing.assert_allclose(camp.robot_settings.target_offset_m, [-0.01, 0, 0], atol=1e-15)


def _parser() -> argparse.ArgumentParser:
    parser = flags.ArgumentParser(prog="t")
    flags.add_configuration_flags(parser)
    flags.add_wrench_flag(parser, repeat=True)
    parser.add_argument("--max", type=float)
    parser.add_argument("--quiet", action="store_true")
    return parser


def test_join_negative_values():
    parser = _parser()
    join = flags.join_negative_values
    assert join(parser, ["--q", "-1,2", "--wr", "-3e2,0,.5", "--load", "-.5,0,0"]) == [
        "--q=-1,2", "--wr=-3e2,0,.5", "--load=-.5,0,0"]
    assert join(parser, ["--max", "-inf"]) == ["--max=-inf"]
    # flags that take no value, values that are not negative numbers, and after --
    assert join(parser, ["--quiet", "-1", "--q", "a=-1", "--", "--q", "-1"]) == [
        "--quiet", "-1", "--q", "a=-1", "--", "--q", "-1"]
    args = parser.parse_args(["--q", "-35,-60", "--deg", "--wrench", "-1,0,0", "--load", "2,0,0"])
    assert args.q == "-35,-60" and args.deg and args.wrench == ["-1,0,0", "2,0,0"]
    with pytest.raises(SystemExit):  # an option where a value is expected is still refused
        parser.parse_args(["--q", "--deg"])


def test_subcommands_inherit_the_parser():
    args = build_parser("kx").parse_args(["kx", "--q", "-1,-2,-3", "--wrench", "-5,0,0"])
    assert (args.q, args.wrench) == ("-1,-2,-3", "-5,0,0")


def test_name_value_coordinates(ur5):
    robot = ur5
    ns = argparse.Namespace
    q = flags.coordinates_from_args(robot, ns(q="elbow_joint=90,q1=-45", deg=True),
                                    required=False)
    np.testing.assert_allclose(q, np.deg2rad([-45, 0, 90, 0, 0, 0]))
    with pytest.raises(UnknownJointError) as info:
        flags.coordinates_from_args(robot, ns(q="elbw=1", deg=False))
    assert info.value.name == "elbw" and info.value.choices == tuple(robot.coordinate_joints)
    with pytest.raises(StiffnessError, match="mixes"):
        flags.coordinates_from_args(robot, ns(q="1,elbow_joint=2", deg=False))
    with pytest.raises(StiffnessError, match="twice"):
        flags.coordinates_from_args(robot, ns(q="q3=1,elbow_joint=2", deg=False))
    with pytest.raises(StiffnessError, match="needs 6 values"):
        flags.coordinates_from_args(robot, ns(q="1,2", deg=False))
    # without --q: the reference configuration, here the zero pose (inside every UR5 limit)
    np.testing.assert_array_equal(flags.coordinates_from_args(robot, ns(q=None, deg=False)),
                                  np.zeros(6))
    assert flags.coordinates_source(robot, ns(q=None)).startswith("zero pose")


def test_parse_list_errors():
    assert flags.parse_list("-1, 2.5,-3e-2", "--x") == [-1.0, 2.5, -0.03]
    with pytest.raises(StiffnessError, match="not a number"):
        flags.parse_list("1,a", "--x")
    with pytest.raises(StiffnessError, match="finite"):
        flags.parse_list("1,nan", "--x")


SEPARATORS = "'1_0' has '_' digit separators, which a command-line number cannot have; write 10"


@pytest.mark.parametrize(("argv", "words"), [
    (["kx", "--robot", "ur5", "--kq", "1_0,2e4,2e4,1e4,1e4,1e4"],  # parse_list
     f"--kq takes comma-separated numbers; {SEPARATORS}"),
    (["simulate", "--robot", "ur5", "--max-force", "1_0", "--out", "s"],  # number
     f"argument --max-force: {SEPARATORS}"),
    (["design", "--robot", "ur5", "--configs", "1_0", "--max-force", "9", "--out", "d"],
     f"argument --configs: {SEPARATORS}"),  # integer
    (["identify", "c", "--seed", "1_0"], f"argument --seed: {SEPARATORS}"),
    (["view", "--robot", "ur5", "--kq", UR5_KQ, "--sweep", "q1=0:1:1_0", "--export", "v.html"],
     f"--sweep: the frame count must be an integer; {SEPARATORS}"),
    (["scan", "--robot", "ur5", "--workers", "١٢", "--out", "s"],
     "argument --workers: '١٢' is not an integer"),
    (["simulate", "--robot", "ur5", "--effect", "backlash:q2=1_0", "--out", "s"],
     f"--effect 'backlash:q2=1_0': {SEPARATORS}"),
    (["track", "--robot", "ur5", "--path", "p.csv", "--timestep", "nan"],
     "argument --timestep: 'nan' is not a finite number"),
])
def test_flag_numbers_are_read_as_csv_cells_are(capsys, tmp_path, monkeypatch, argv, words):
    """Every number flag (lists, one number, counts, seeds) reads numbers by the CSV readers'
    rule (stiffness.units.plain_float): ``1_0`` (which Python reads as 10) and other scripts'
    digits are refused in one line naming the fix, never read as another number."""
    monkeypatch.chdir(tmp_path)
    try:
        code = main(argv)
    except SystemExit as info:  # argparse's usage error
        code = info.code
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and words in err, err


SMALL_SIMULATION = ["simulate", "--robot", "ur5", "--kq", UR5_KQ, "--configs", "1",
                    "--loads-per-config", "1", "--quiet"]
SMALL_DESIGN = ["design", "--robot", "ur5", "--kq", UR5_KQ, "--configs", "2", "--max-force",
                "50", "--loads-per-config", "1", "--candidates", "12", "--random-plans", "2",
                "--quiet"]


@pytest.mark.parametrize(("argv", "words"), [
    ([*SMALL_SIMULATION, "--noise", "2e-6"],  # meant in m: 2 nm in the default mm
     "--noise 2e-06 mm is 2e-09 m, below 10 nm, finer than any rig measures: --noise is in the "
     "files' length unit (here mm); give it in mm (5 um is 0.005 mm)"),
    ([*SMALL_SIMULATION, "--units", "m", "--noise", "0.05"],  # meant in mm: 5 cm in m
     "--noise 0.05 m is 0.05 m, above 1 cm, coarser than any rig worth calibrating with"),
    ([*SMALL_DESIGN, "--noise", "20", "--units", "mm"], "--noise 20 mm is 0.02 m, above 1 cm"),
    ([*SMALL_DESIGN, "--noise", "0.001", "--units", "um"], "--noise 0.001 um is 1e-09 m"),
])
def test_noise_no_rig_has_is_warned_in_the_flags_unit_and_m(tmp_path, argv, words):
    """``--noise`` is in the files' length unit: a std finer than 10 nm or coarser than 1 cm
    (a value meant in another unit) is warned about in one line, in that unit and in m."""
    with pytest.warns(FlagValueWarning) as record:
        assert main([*argv, "--out", str(tmp_path / "out")]) == 0
    messages = [str(w.message) for w in record if w.category is FlagValueWarning]
    assert len(messages) == 1 and words in messages[0], messages


@pytest.mark.parametrize(("argv", "words"), [
    (["--units", "m", "--effect", "target_offset=20"],  # meant in mm: 20 m on a 1.33 m arm
     "--effect target_offset=20: its length 20 m is beyond ur5's reach (1.33 m), no "
     "target_offset on it; --effect lengths are in the files' length unit (--units, here m): "
     "give them in m, or give --units the unit they are in (--units mm reads them as 0.02 m)"),
    (["--units", "cm", "--effect", "gravity_preload=2,0,0,300"],  # its centre of mass: 3 m
     "--effect gravity_preload=2,0,0,300: its length 300 cm (3 m) is beyond ur5's reach"),
    (["--units", "m", "--effect", "target_offset=0.02"], None),
    (["--effect", "target_offset=20", "--effect", "gravity_preload=2,0,0,50"], None),  # mm
])
def test_effect_lengths_beyond_the_reach_are_warned(tmp_path, recwarn, argv, words):
    """``--effect`` lengths are in ``--units``: a target offset or a payload's centre of mass
    farther than the robot's reach (the UR5's, 1.3287 m, summed from its URDF in
    test_physical_scales) was meant in a smaller unit, and is warned about in one line naming
    the value, the reach and the fix; within the reach (20 mm, 0.02 m, a 50 mm centre of
    mass) it is not."""
    assert main([*SMALL_SIMULATION, *argv, "--out", str(tmp_path / "out")]) == 0
    messages = [str(w.message) for w in recwarn if w.category is FlagValueWarning]
    assert messages == [] if words is None else (len(messages) == 1 and words in messages[0]), \
        messages


def test_simulate_default_noise_is_5_um_in_every_unit(tmp_path, recwarn):
    """The default noise is 0.005 mm whatever ``--units`` (it was 0.005 in --units: 5 nm in um,
    5 mm in m), and a noise in the rig range is not warned about."""
    for units, noise in (("um", None), ("m", None), ("mm", "0.005")):
        out = tmp_path / units
        assert main([*SMALL_SIMULATION, "--units", units, "--out", str(out),
                     *(["--noise", noise] if noise else [])]) == 0
        truth = json.loads((out / "truth.json").read_text())
        assert truth["noise_std"] * {"um": 1e-6, "m": 1.0, "mm": 1e-3}[units] == \
            pytest.approx(5e-6, rel=1e-12)
    assert not [w for w in recwarn if w.category is FlagValueWarning]


def test_warnings_print_on_one_line_and_the_callers_format_is_restored(monkeypatch):
    """While ``main`` runs, a warning is formatted as one ``stiffness: warning:`` line; after
    it, the caller's own warning format is back (``main`` is called from Python too)."""
    import warnings

    from stiffness.cli import kx as kx_command

    seen = []

    def run(args) -> int:
        seen.append(warnings.formatwarning("a joint limit is missing", UserWarning,
                                           "robot.py", 12))
        return 0

    monkeypatch.setattr(kx_command, "run", run)
    before = warnings.formatwarning
    assert main(["kx", "--robot", "sk120"]) == 0
    assert seen == ["stiffness: warning: a joint limit is missing\n"]
    assert warnings.formatwarning is before


@pytest.mark.parametrize(("argv", "line"), [
    (["view", "--robot", "ur5", "--out", "x.html"],
     "stiffness view: error: unrecognized arguments: --out x.html; see 'stiffness view --help'"),
    (["scan", "--robot", "ur5", "--outt", "d"],
     "stiffness scan: error: unrecognized arguments: --outt d (did you mean --out?); see "
     "'stiffness scan --help'"),
    (["compensate", "--robot", "ur5"],
     "stiffness compensate: error: the following arguments are required: --path; see "
     "'stiffness compensate --help'"),
    (["scan", "--format", "xml"],
     "stiffness scan: error: argument --format: invalid choice: 'xml' (choose from 'npz', "
     "'parquet', 'both'); see 'stiffness scan --help'"),
    (["--bogus"], "stiffness: error: unrecognized arguments: --bogus; see 'stiffness --help'"),
    (["identify", "campaign", "--seed", "-1"],
     "stiffness identify: error: argument --seed: must be a non-negative integer, got '-1'; see "
     "'stiffness identify --help'"),
    (["scan", "--robot", "ur5", "--seed", "x"],
     "stiffness scan: error: argument --seed: must be a non-negative integer, got 'x'; see "
     "'stiffness scan --help'"),
])
def test_usage_errors_are_one_line_naming_the_command(capsys, argv, line):
    """An unknown, misspelt or missing flag: exit code 2 and one line that names the command,
    the closest flag it has (when one is close) and where its flags are listed."""
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    assert capsys.readouterr().err == line + "\n"


@pytest.mark.parametrize("command", ["kx", "scan", "compensate"])
def test_missing_stiffness_names_the_joints_and_both_units(capsys, tmp_path, command):
    """A robot with no stiffness of its own needs --kq: every command says so in the same
    line, naming the compliant joints and both units (a list may mix revolute and prismatic
    joints)."""
    argv = [command, "--robot", "ur5", "--compliant-joints", "shoulder_pan_joint,elbow_joint"]
    argv += {"kx": ["--wrench", "0,0,-1"], "scan": ["--samples", "4", "--out",
                                                    str(tmp_path / "s")],
             "compensate": ["--path", str(tmp_path / "missing.csv")]}[command]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == (f"stiffness {command}: error: --kq is required for ur5: one stiffness per "
                       "compliant joint (shoulder_pan_joint, elbow_joint), N.m/rad (N/m "
                       "prismatic)")


@pytest.mark.parametrize("command", ["kx", "view", "scan", "compensate"])
def test_wrong_stiffness_count_names_the_flag_and_the_joints(capsys, tmp_path, command):
    """--kq with another count than the compliant joints: one line naming --kq, the joints and
    the fix (kx, view and compensate said 'need one joint stiffness per compliant joint (2),
    got 3', scan 'need 2 finite positive joint stiffnesses'; a new user of a Gepetto 5-bar
    gave 12 values to its 2 motors); since 5 December 2026 the one check of joint springs,
    :func:`~stiffness.mechanics.defaults.joint_stiffnesses`, whose words ``load_model`` uses."""
    argv = [command, "--robot", "ur5", "--compliant-joints", "shoulder_pan_joint,elbow_joint",
            "--kq", "1e4,1e4,1e4"]
    argv += {"kx": ["--wrench", "0,0,-1"], "view": ["--export", str(tmp_path / "v.html")],
             "scan": ["--samples", "4", "--out", str(tmp_path / "s")],
             "compensate": ["--path", str(tmp_path / "missing.csv")]}[command]
    assert main(argv) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"stiffness {command}: error: --kq must be one finite positive stiffness per compliant "
        "joint of ur5 (shoulder_pan_joint, elbow_joint), N.m/rad (N/m prismatic): "
        "comma-separated in their order, or choose the joints with --compliant-joints, got "
        "list [10000.0, 10000.0, 10000.0]")
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("command", ["kx", "simulate", "robot"])
def test_compliant_joints_naming_no_joint_is_refused_as_such(capsys, tmp_path, command):
    """--compliant-joints '' (or ','): one line saying it names no joint (kx said 'need one
    joint stiffness per compliant joint (0), got 1'; others loaded a robot without springs)."""
    argv = {"kx": ["kx", "--wrench", "0,0,-1"],
            "simulate": ["simulate", "--out", str(tmp_path / "c")],
            "robot": ["robot", "export", "--urdf", str(tmp_path / "r.urdf")]}[command]
    assert main([*argv, "--robot", "ur5", "--compliant-joints", " , ", "--kq", "1e5"]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"stiffness {argv[0]}{' export' if command == 'robot' else ''}: error: "
        "--compliant-joints names no joint; give at least one "
        "(j1,j2,...), or leave the flag out for the robot's own springs")
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(("command", "output"), [("compensate", "--out"), ("posture", "--out"),
                                                 ("track", "--plot")])
def test_model_driven_commands_share_the_model_check(capsys, tmp_path, command, output):
    """compensate, posture and track read --model/--robot through one helper: the same line
    when neither is given, and an output that cannot be written refused before the model file
    is read (the model file named here does not exist)."""
    path = ["--path", str(tmp_path / "path.csv")]
    assert main([command, *path]) == 2
    assert capsys.readouterr().err.strip() == (
        f"stiffness {command}: error: --model M.json is required (the identified or diagnosed "
        "model), or --robot R with --kq")
    (tmp_path / "plain").write_text("")
    bad = str(tmp_path / "plain" / "out.csv")
    assert main([command, *path, "--model", str(tmp_path / "none.json"), output, bad]) == 2
    assert "plain: it is a file, not a folder" in capsys.readouterr().err
