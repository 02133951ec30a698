"""``--out`` naming a folder (or file) that holds something else loses nothing.

A user who writes ``stiffness diagnose CAMPAIGN --out CAMPAIGN`` (the diagnosis beside the
data), ``simulate --out`` or ``design --out`` into a measured campaign's folder, or ``design
--out measurements.csv`` got the measurements deleted or overwritten: the folder writers
replace the whole folder (or the files they write). Now each refuses, in one line, a target that
is not a previous output of its kind (stiffness.files.refuse_foreign_folder), and reruns over
its own previous output still work.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from stiffness import files
from stiffness.cli.main import main
from stiffness.errors import OutputError
from stiffness.planning.plan import check_plan_target
from stiffness.planning.simulate import simulate

TABLE2 = Path(__file__).resolve().parents[1] / "robots" / "sk120" / "campaigns" / "table2"


def _campaign(tmp_path: Path) -> Path:
    folder = tmp_path / "campaign"
    shutil.copytree(TABLE2, folder)
    (folder / "notes.txt").write_text("rig notes\n")
    return folder


def _contents(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_refuse_foreign_folder_rules(tmp_path):
    """Missing, empty and previous outputs pass; foreign files are named, hidden temporaries
    ignored; with ``writes`` only the files that would be overwritten count."""
    files.refuse_foreign_folder(tmp_path / "absent", "diagnosis.json", "diagnosis")
    files.refuse_foreign_folder(tmp_path, "diagnosis.json", "diagnosis")  # empty
    (tmp_path / ".x.123.abc.tmp").write_text("")
    files.refuse_foreign_folder(tmp_path, "diagnosis.json", "diagnosis")
    (tmp_path / "robot.urdf").write_text("<robot/>")
    files.refuse_foreign_folder(tmp_path, "truth.json", "campaign",
                                writes=("campaign.toml",))  # the URDF is kept, not lost
    with pytest.raises(OutputError, match=r"no diagnosis.json\) and holds robot.urdf, which "
                                          r"writing the diagnosis there would delete") as err:
        files.refuse_foreign_folder(tmp_path, "diagnosis.json", "diagnosis")
    assert "\n" not in str(err.value) and err.value.path == tmp_path
    (tmp_path / "campaign.toml").write_text("")
    with pytest.raises(OutputError, match="holds campaign.toml, which .* would overwrite"):
        files.refuse_foreign_folder(tmp_path, "truth.json", "campaign", writes=("campaign.toml",))
    (tmp_path / "truth.json").write_text("{}")
    files.refuse_foreign_folder(tmp_path, "truth.json", "campaign", writes=("campaign.toml",))


@pytest.mark.parametrize("command", [["diagnose", "--max-steps", "0"], ["report"]])
def test_diagnosis_into_the_campaign_folder_is_refused_before_the_work(tmp_path, capsys,
                                                                        command):
    camp = _campaign(tmp_path)
    before = _contents(camp)
    assert main([command[0], str(camp), *command[1:], "--out", str(camp), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "is not a previous diagnosis" in err and "measurements.csv" in err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert _contents(camp) == before


def test_simulate_and_plan_over_a_measured_campaign_are_refused(tmp_path):
    camp = _campaign(tmp_path)
    before = _contents(camp)
    sim = simulate("sk120", configs=1, loads_per_config=1, seed=1)
    with pytest.raises(OutputError, match="not a previous simulated campaign"):
        sim.write(camp)
    with pytest.raises(OutputError, match="not a previous plan folder"):
        check_plan_target(camp)
    with pytest.raises(OutputError, match="is not a plan written by stiffness design"):
        check_plan_target(camp / "measurements.csv")
    assert _contents(camp) == before
    with pytest.raises(OutputError, match=r"--out .*plan.json: a plan is a CSV file .* give e.g. "
                                          r"--out .*plan.csv or --out .*plan$"):
        check_plan_target(tmp_path / "plan.json")  # made a folder named plan.json
    sim.write(tmp_path / "sim")  # a new folder, then a rerun over it
    sim.write(tmp_path / "sim")
    check_plan_target(tmp_path / "sim" / "plan.csv")  # absent


def test_an_output_file_that_is_an_input_is_refused(tmp_path, capsys):
    """``compensate --out path.csv --path path.csv`` replaced the path it read (and a second
    run then doubled its columns); ``robot export --urdf`` over the ``--robot`` URDF or its
    loop file replaced the user's robot file."""
    path = tmp_path / "path.csv"
    path.write_text("q1,q2,q3,q4,q5,q6\n0.1,-1.2,1.5,-0.3,1.57,0.2\n")
    before = path.read_bytes()
    kq = ["--kq", "3e5,3e5,2e5,4e4,4e4,4e4"]
    for command in (["compensate", "--robot", "ur5", *kq, "--wrench", "0,0,-300"],
                    ["posture", "--robot", "ur5", *kq]):
        assert main([*command, "--path", str(path), "--out", str(tmp_path / "." / "path.csv")]) \
            == 2
        err = capsys.readouterr().err
        assert "it is the --path file this command reads" in err and err.count("\n") == 1
    assert path.read_bytes() == before
    sk120 = Path(__file__).resolve().parents[1] / "robots" / "sk120"
    for name in ("sk120.urdf", "sk120.loops.yaml"):
        shutil.copy(sk120 / name, tmp_path / name)
    robot = tmp_path / "sk120.urdf"
    saved = _contents(tmp_path)
    assert main(["robot", "export", "--robot", str(robot), "--urdf", str(robot)]) == 2
    assert "it is the --robot file" in capsys.readouterr().err
    assert main(["robot", "export", "--robot", str(robot), "--urdf",
                 str(tmp_path / "sk120.xml")]) == 2  # its loops would go to sk120.loops.yaml
    assert "it is the loop file" in capsys.readouterr().err
    assert _contents(tmp_path) == saved


def test_view_export_over_an_input_is_refused(tmp_path, capsys):
    """``view --export`` over the ``--path`` file (or the ``--model`` or ``--robot`` file)
    replaced it with the HTML page."""
    path = tmp_path / "path.csv"
    path.write_text("q1,q2,q3,q4,q5,q6\n0.1,-1.2,1.5,-0.3,1.57,0.2\n0.2,-1.2,1.5,-0.3,1.57,0.2\n")
    before = path.read_bytes()
    assert main(["view", "--robot", "ur5", "--kq", "3e5,3e5,2e5,4e4,4e4,4e4", "--path",
                 str(path), "--export", str(path), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "it is the --path file this command reads" in err and err.count("\n") == 1
    assert path.read_bytes() == before


@pytest.mark.parametrize("argv", [
    ["simulate", "--robot", "sk120", "--configs", "1", "--out", "{tmp}/camp.csv"],
    ["diagnose", str(TABLE2), "--out", "{tmp}/diagnosis.html"],
    ["report", "--out", "{tmp}/report.html"],
    ["scan", "--robot", "ur5", "--kq", "3e5,3e5,2e5,4e4,4e4,4e4", "--axis",
     "elbow_joint=0:1:0.5", "--no-plots", "--out", "{tmp}/maps.npz"],
])
def test_an_output_folder_named_like_a_file_is_refused(tmp_path, capsys, argv):
    """``--out report.html`` (or ``maps.npz``, ``camp.csv``) made a folder of that name."""
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert main([*argv, "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "this command writes a folder (several files), not a" in err and err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


def test_python_m_stiffness_is_the_command(tmp_path):
    """``python -m stiffness`` (the console script's folder not on the PATH) said 'No module
    named stiffness.__main__'; it is the command, its errors one line."""
    import subprocess
    import sys

    import stiffness

    run = subprocess.run([sys.executable, "-m", "stiffness", "--version"], capture_output=True,
                         text=True, timeout=60, cwd=tmp_path)
    assert run.returncode == 0 and run.stdout.strip() == f"stiffness {stiffness.__version__}"
    run = subprocess.run([sys.executable, "-m", "stiffness", "kx", "--robot", ""],
                         capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert run.returncode == 2 and run.stderr.startswith("stiffness kx: error: the robot is an "
                                                         "empty name")
