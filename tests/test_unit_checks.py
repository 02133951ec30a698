"""Units caught (issue 38 item 4): measured lengths in the wrong unit are warned about with the
unit they look like, for pose campaigns (marker displacements against the nominal kinematics,
which do not depend on where the tracker stands) and deflection campaigns (deflections against
the robot's reach); radians that look like degrees are told to use degrees.
"""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from stiffness.calibration.campaign import load_campaign
from stiffness.calibration.pose_campaign import load_pose_campaign, write_pose_campaign
from stiffness.calibration.pose_model import Marker
from stiffness.errors import DataFileWarning
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.robot import load_robot
from stiffness.robot.sources import robots_directory
from stiffness.units import Units

TABLE2 = robots_directory() / "sk120" / "campaigns" / "table2"


def caught(read) -> list[str]:
    with warnings.catch_warnings(record=True) as found:
        warnings.simplefilter("always")
        read()
    return [str(w.message) for w in found if issubclass(w.category, DataFileWarning)]


@pytest.fixture(scope="module")
def pose_folder(tmp_path_factory):
    """A UR10 pose campaign in mm, tracker 3 m away and turned (hidden placement), 12 rows."""
    robot = load_robot("ur10", frame="tool0")
    markers = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05]))]
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    hidden = HiddenPoseErrors(turn, np.array([3.0, -1.0, 0.4]), np.array([m.offset for m in
                                                                          markers]),
                              np.zeros(6), np.zeros((6, 6)), np.full(6, 2e5))
    campaign = simulate_pose_campaign(robot, markers, hidden, 12, 2e-5, seed=4,
                                      units=Units("deg", "N", "mm"))
    folder = tmp_path_factory.mktemp("poses")
    write_pose_campaign(campaign, folder)
    return folder


def declared_as(source: Path, folder: Path, declared: str) -> Path:
    """A copy of the millimetre campaign ``source`` at ``folder`` whose campaign.toml declares
    its lengths in ``declared`` instead (the numbers unchanged)."""
    shutil.copytree(source, folder)
    toml = folder / "campaign.toml"
    text = toml.read_text()
    assert 'length = "mm"' in text
    toml.write_text(text.replace('length = "mm"', f'length = "{declared}"'))
    return folder


def test_pose_angles_in_radians_declared_degrees_suggest_radians(tmp_path):
    """A UR10 pose campaign whose joint angles are in rad but declared deg (FIGAROH's UR10
    calibration.csv imported with --units angle=deg: markers 8.4 times as far apart as the
    kinematics moved them, the advice to check the length unit): the angles read in rad bring
    the spread to 1, and the warning names that unit, not a length unit."""
    robot = load_robot("ur10", frame="tool0")
    markers = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05]))]
    hidden = HiddenPoseErrors(np.eye(3), np.array([2.0, 0.0, 0.3]),
                              np.array([m.offset for m in markers]), np.zeros(6),
                              np.zeros((6, 6)), np.full(6, 2e5))
    campaign = simulate_pose_campaign(robot, markers, hidden, 12, 2e-5, seed=4,
                                      units=Units("rad", "N", "mm"))
    write_pose_campaign(campaign, tmp_path / "rad")
    assert not [m for m in caught(lambda: load_pose_campaign(tmp_path / "rad"))
                if "marker positions" in m]
    toml = tmp_path / "rad" / "campaign.toml"
    toml.write_text(toml.read_text().replace('angle = "rad"', 'angle = "deg"'))
    messages = [m for m in caught(lambda: load_pose_campaign(tmp_path / "rad"))
                if "marker positions" in m]
    assert len(messages) == 1, messages
    assert 'the angles look like rad: [units] angle = "rad"' in messages[0], messages[0]
    assert "length unit" not in messages[0].split("; ", 1)[1]


@pytest.mark.parametrize(("declared", "words"), [
    ("mm", None), ("m", 'the data look like mm: [units] length = "mm"'),
    ("um", 'the data look like mm: [units] length = "mm"'),
])
def test_pose_positions_in_the_wrong_unit(pose_folder, tmp_path, declared, words):
    """The same numbers declared mm (right: no warning), m (1000x too far) or um."""
    folder = declared_as(pose_folder, tmp_path / declared, declared)
    messages = [m for m in caught(lambda: load_pose_campaign(folder)) if "marker positions" in m]
    if words is None:
        assert messages == []
        return
    assert len(messages) == 1 and words in messages[0], messages
    ratio = 1000.0 if declared == "m" else 1e-3
    assert f"move {ratio:.3g} times as far" in messages[0].replace("1e+03", "1e+03"), messages[0]


@pytest.mark.parametrize(("declared", "words"), [
    ("mm", None), ("m", 'the data look like mm: [units] length = "mm"'),
])
def test_deflections_in_the_wrong_unit(tmp_path, declared, words):
    """The SK120's Table II (deflections of 0.03-0.3 mm in mm): declared m they are 3-30 cm,
    beyond 2% of the robot's reach."""
    folder = declared_as(TABLE2, tmp_path / "t2", declared)
    messages = [m for m in caught(lambda: load_campaign(folder)) if "median deflection" in m]
    if words is None:
        assert messages == []
        return
    assert len(messages) == 1 and words in messages[0] and "larger than" in messages[0], messages
    # a robot this soft (a Solo12 leg at 50 N.m/rad under 50 N: 101 mm) is not told only to
    # change its unit
    assert messages[0].endswith("; if it really deflects that much, only the exact equilibrium "
                                "models it: identify with --formulation exact"), messages[0]


def test_radians_that_look_like_degrees_suggest_degrees(tmp_path):
    folder = tmp_path / "t2"
    shutil.copytree(TABLE2, folder)
    toml = folder / "campaign.toml"
    toml.write_text(toml.read_text().replace('angle = "deg"', 'angle = "rad"'))
    messages = [m for m in caught(lambda: load_campaign(folder)) if "joint limits" in m]
    assert len(messages) == 1 and 'the angles look like degrees: [units] angle = "deg"' in \
        messages[0], messages


def scaled_forces(source: Path, folder: Path, factor: float, declared: str | None = None
                  ) -> Path:
    """A copy of campaign ``source`` at ``folder`` whose fx, fy, fz numbers are multiplied by
    ``factor`` and, when given, whose force unit is declared ``declared``."""
    shutil.copytree(source, folder)
    data = folder / "measurements.csv"
    lines = data.read_text().splitlines()
    header = lines[0].split(",")
    forces = [header.index(k) for k in ("fx", "fy", "fz")]
    out = [lines[0]]
    for line in lines[1:]:
        cells = line.split(",")
        for i in forces:
            cells[i] = repr(float(cells[i]) * factor)
        out.append(",".join(cells))
    data.write_text("\n".join(out) + "\n")
    if declared is not None:
        toml = folder / "campaign.toml"
        toml.write_text(toml.read_text().replace('force = "N"', f'force = "{declared}"'))
    return folder


def force_messages(folder: Path) -> list[str]:
    return [m for m in caught(lambda: load_campaign(folder)) if "per unit load" in m]


@pytest.mark.parametrize(("factor", "declared", "words"), [
    (1.0, None, None),
    (1.0, "kN", 'the forces look like N: [units] force = "N"'),  # N data declared kN
    (1e-3, None, 'the forces look like kN: [units] force = "kN"'),  # kN data declared N
    (1e-3, "kN", None),  # kN data declared kN
])
def test_forces_in_the_wrong_unit_against_declared_springs(tmp_path, factor, declared, words):
    """The SK120's Table II against its declared k_theta_SI (measured over predicted deflection
    0.95): a force unit read wrong makes it ~1000x softer or stiffer, told with the unit."""
    messages = force_messages(scaled_forces(TABLE2, tmp_path / "t2", factor, declared))
    if words is None:
        assert messages == []
        return
    assert len(messages) == 1 and words in messages[0], messages
    assert "its declared k_theta_SI" in messages[0] and "else check the robot's k_theta_SI" \
        in messages[0]  # declared springs in N.mm/rad would look the same
    assert ("stiffer" if declared == "kN" else "softer") in messages[0]


@pytest.fixture(scope="module")
def soft_ur5(tmp_path_factory):
    """A UR5 campaign (no declared springs: compared with the nominal 1e5 SI) of a robot 20x
    softer than nominal, 3 configurations x 2 loads, in N."""
    from stiffness.planning.simulate import simulate

    folder = tmp_path_factory.mktemp("ur5") / "c"
    simulate("ur5", kq=[5e3] * 6, configs=3, loads_per_config=2, seed=2).write(folder)
    return folder


def test_forces_in_kn_read_as_n_against_nominal_springs(soft_ur5, tmp_path):
    """A soft robot without declared springs is no false alarm in N; its forces written in kN
    and read as N (1000x smaller) are told to be kN, and the import of such a rig file too."""
    assert force_messages(soft_ur5) == []
    folder = scaled_forces(soft_ur5, tmp_path / "kn", 1e-3)
    messages = force_messages(folder)
    assert len(messages) == 1 and 'the forces look like kN' in messages[0], messages
    assert "a nominal 1e5 SI per joint" in messages[0] and "softer" in messages[0]
    # a robot that soft (a hobby arm's servos: so101 at 300 N.m/rad read 848x) is told how
    assert "else ur5 is that much softer than the guess: declare its k_theta_SI" in messages[0]
    from stiffness.calibration.campaign_toml import RobotSettings
    from stiffness.calibration.rig_import import ImportSettings, import_campaign

    imported = caught(lambda: import_campaign(
        [folder / "measurements.csv"], RobotSettings("ur5"),
        ImportSettings(units={"angle": "deg", "force": "N", "length": "mm"})))
    assert [m for m in imported if "the forces look like kN" in m], imported


def _table2_with(tmp_path: Path, change) -> Path:
    """Table II copied with ``change(cells)`` applied to each data row's cells."""
    folder = tmp_path / "c"
    shutil.copytree(TABLE2, folder)
    data = folder / "measurements.csv"
    lines = data.read_text().splitlines()
    data.write_text("\n".join([lines[0], *(",".join(change(line.split(","))) for line in
                                           lines[1:])]) + "\n")
    return folder


def test_reversed_deflections_and_unloaded_campaigns_are_warned_about(tmp_path):
    """A rig that writes unloaded minus loaded positions (every deflection against its load:
    the SK120 then identified 'rigid' for all three joints, silently), or a campaign with no
    load at all (identified 'undetermined', silently), is warned about in one line; Table II
    as published is not, nor the same rows with a few signs flipped by noise."""
    def negate(columns):
        return lambda cells: [f"{-float(c):g}" if i in columns else c
                              for i, c in enumerate(cells)]

    assert caught(lambda: load_campaign(TABLE2)) == []
    [message] = caught(lambda: load_campaign(_table2_with(tmp_path / "d", negate({10, 11, 12}))))
    assert "in 15 of 15 loaded rows the deflection points against the force" in message
    assert "negate dx,dy,dz (loaded minus unloaded) or fx,fy,fz" in message
    assert caught(lambda: load_campaign(_table2_with(tmp_path / "f", negate({7, 8, 9})))) \
        == [message.replace(str(tmp_path / "d"), str(tmp_path / "f"))]
    [message] = caught(lambda: load_campaign(_table2_with(
        tmp_path / "z", lambda cells: [*cells[:7], "0", "0", "0", *cells[10:]])))
    assert message.endswith("no row carries a load (every fx,fy,fz is 0): the deflections tell "
                            "nothing of the stiffness; give the loads applied at each row")
    flipped = iter(range(100))  # two rows in 15 against their load: noise, not a sign convention
    assert caught(lambda: load_campaign(_table2_with(
        tmp_path / "n", lambda cells: negate({10, 11, 12})(cells) if next(flipped) < 2
        else cells))) == []


def slipped(source: Path, folder: Path, config: str, columns: tuple[str, ...]) -> Path:
    """A copy of campaign ``source`` whose ``columns`` on the rows of ``config`` are divided by
    1000 (that configuration's numbers written in a unit 1000x larger)."""
    shutil.copytree(source, folder)
    data = folder / "measurements.csv"
    lines = data.read_text().splitlines()
    header = lines[0].split(",")
    out = [lines[0]]
    for line in lines[1:]:
        cells = line.split(",")
        if cells[0] == config:
            for c in columns:
                cells[header.index(c)] = repr(float(cells[header.index(c)]) / 1000)
        out.append(",".join(cells))
    data.write_text("\n".join(out) + "\n")
    return folder


def test_one_configuration_in_another_unit_is_named(tmp_path):
    """One configuration's deflections written in m (or its forces in kN) among a campaign in
    mm and N: the campaign-wide medians stay plausible, a least-squares diagnosis then names
    a stand-in and an effect that is not there (a UR5 of 6 configurations: gravity_preload
    and nonlinear_joint_stiffness, 20 rows flagged); the configuration is named with its
    factor, 1000 either way, and a clean campaign is no false alarm."""
    from stiffness.planning.simulate import simulate

    clean = tmp_path / "clean"
    simulate("ur5", kq=[2e4, 2e4, 1e4, 3e3, 3e3, 3e3], configs=6, loads_per_config=3,
             seed=7).write(clean)

    def slip_messages(folder: Path) -> list[str]:
        return [m for m in caught(lambda: load_campaign(folder))
                if "per unit load of configuration" in m]

    assert slip_messages(clean) == []
    for config, columns, factor, words in (
            ("C3", ("dx", "dy", "dz"), 1e-3, "deflections in a larger unit (m among mm)"),
            ("C2", ("fx", "fy", "fz"), 1e3, "forces in a larger one (kN among N)")):
        messages = slip_messages(slipped(clean, tmp_path / config, config, columns))
        assert len(messages) == 1 and words in messages[0], messages
        said = float(messages[0].split(f"configuration {config} (")[1].split("x)")[0])
        assert said == pytest.approx(factor, rel=0.5), messages
