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
    sim.write(tmp_path / "sim")  # a new folder, then a rerun over it
    sim.write(tmp_path / "sim")
    check_plan_target(tmp_path / "sim" / "plan.csv")  # absent
