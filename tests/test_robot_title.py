"""A robot is named to the user by its robot.toml's ``name`` (issue 38): echo lines, messages,
reports, page titles, model files and exports, falling back to a shipped or example-robot-data
name, the URDF's robot name or the robot.toml's folder, never a path."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from stiffness.calibration.identify import identify
from stiffness.calibration.validation import validate
from stiffness.cli.main import main
from stiffness.elastic.model_file import read_model_file
from stiffness.errors import StiffnessError
from stiffness.planning.simulate import simulate
from stiffness.robot.robot import load_robot

ARM = """{name}compliant_joints = ["j1", "j2", "j3"]
[dh]
convention = "standard"
length_unit = "m"
angle_unit = "rad"
joints = [
  {{ name = "j1", alpha = 1.5707963267948966, a = 0.0, theta = 0.0, d = 0.4 }},
  {{ name = "j2", alpha = 0.0, a = 0.5, theta = 0.0, d = 0.0 }},
  {{ name = "j3", alpha = 0.0, a = 0.4, theta = 0.0, d = 0.0 }},
]
links = [ {{ mass = 5.0, com = [0.0, 0.0, 0.0] }}, {{ mass = 4.0, com = [-0.25, 0.0, 0.0] }},
          {{ mass = 2.0, com = [-0.2, 0.0, 0.05] }} ]
"""
NAME = "Shop arm 3"


def arm(folder: Path, name: str | None) -> Path:
    folder.mkdir(parents=True)
    toml = folder / "robot.toml"
    toml.write_text(ARM.format(name="" if name is None else f'name = "{name}"\n'))
    return toml


def test_title_is_the_declared_name_else_never_a_path(tmp_path):
    from stiffness.robot.sources import robots_directory

    assert load_robot(str(arm(tmp_path / "a", NAME))).title == NAME
    assert load_robot(str(arm(tmp_path / "kr-arm", None))).title == "kr-arm"  # the folder
    assert load_robot(str(tmp_path / "kr-arm")).title == "kr-arm"
    assert load_robot("ur5").title == "ur5"
    urdf = robots_directory() / "sk120" / "sk120.urdf"
    if urdf.is_file():
        robot = load_robot(str(urdf))
        assert robot.title == robot.model.name and "/" not in robot.title


def test_echo_messages_reports_and_model_files_name_the_robot(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    toml = arm(tmp_path / "robot", NAME)
    assert main(["kx", "--robot", str(toml), "--q", "0,0.5,-1", "--kq", "1e5,1e5,1e5",
                 "--wrench", "0,0,-100"]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[1].startswith(f"{NAME} target at tool"), out
    with pytest.raises(StiffnessError, match=f"^{NAME} has 3 coordinates"):
        load_robot(str(toml)).configuration([0.0, 1.0])
    campaign = tmp_path / "campaign"
    simulate(str(toml), kq=[2e5, 1e5, 5e4], configs=4, loads_per_config=2, seed=1,
             name="shop").write(campaign)
    result = identify(campaign)
    assert result.to_dict()["robot"]["name"] == NAME
    model = tmp_path / "model.json"
    result.write_model(model)
    assert json.loads(model.read_text())["robot"]["name"] == NAME
    assert read_model_file(model).robot_name == NAME
    assert validate(model, campaign).to_dict()["robot"]["name"] == NAME
    assert main(["kx", "--model", str(model), "--robot", "ur5", "--q", "0,0,0,0,0,0",
                 "--wrench", "0,0,-1"]) == 2
    assert f"is of robot '{NAME}' ({toml.resolve()}), not 'ur5'" in capsys.readouterr().err
    assert main(["identify", str(campaign)]) == 0
    assert f"campaign shop ({campaign / 'campaign.toml'}) of {NAME}:" in capsys.readouterr().out
    assert simulate(str(toml), kq=[2e5, 1e5, 5e4], configs=1, loads_per_config=1
                    ).campaign.name == f"simulated-{NAME}"
    assert main(["robot", "export", "--robot", str(toml), "--urdf", "arm.urdf"]) == 0
    assert f'<robot name="{NAME}"' in (tmp_path / "arm.urdf").read_text()


TINY_URDF = """<robot name="tiny_arm">
  <link name="base"/><link name="l1"/><link name="tip"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/>
    <limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <joint name="jt" type="fixed"><parent link="l1"/><child link="tip"/><origin xyz="0.3 0 0"/>
  </joint>
</robot>
"""


@pytest.mark.parametrize(("kwargs", "words"), [
    ({"compliant_joints": ["joint1"]}, "compliant joint 'joint1' is not a coordinate joint of "
                                       "tiny_arm; valid names: j1"),
    ({"frame": "tool0"}, "frame 'tool0' is not in tiny_arm; valid names: "),
])
def test_loading_refusals_name_a_urdf_robot_by_its_name_not_its_path(tmp_path, kwargs, words):
    """A compliant joint or frame a URDF lacks is refused naming the robot as its URDF does
    (a TX40 campaign's 'joint1' said 'not a coordinate joint of /tmp/.../tx40_mdh_modified.urdf'
    while its [robot] fixed said 'of staubli_tx40')."""
    path = tmp_path / "deep" / "arm.urdf"
    path.parent.mkdir()
    path.write_text(TINY_URDF)
    with pytest.raises(StiffnessError) as caught:
        load_robot(str(path), **kwargs)
    assert words in str(caught.value) and str(tmp_path) not in str(caught.value)
