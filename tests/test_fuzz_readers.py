"""Property-based fuzzing of every reader of user files and flags (hypothesis).

Each test mutates a valid input (see :mod:`fuzzing`) and checks the reader contract: it
accepts the input with the right meaning, or raises a one-line
:class:`~stiffness.errors.StiffnessError`; it never raises anything else, never exceeds the
per-example deadline, and never writes a file. Run the long profile by hand with
``HYPOTHESIS_PROFILE=long python -m pytest tests/test_fuzz_readers.py``.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from fuzzing import (
    FUZZ,
    assert_reader_contract,
    csv_mutation,
    json_mutations,
    replaced,
    toml_mutation,
    write_text,
)
from hypothesis import given
from hypothesis import strategies as st

from stiffness.calibration.campaign import load_campaign
from stiffness.cli import flags
from stiffness.errors import StiffnessError
from stiffness.robot.robot import load_robot
from stiffness.units import MAX_CELL

ROBOTS = Path(__file__).resolve().parents[1] / "robots"
TABLE2 = ROBOTS / "sk120" / "campaigns" / "table2"


@pytest.fixture(scope="module")
def campaign_folder(tmp_path_factory) -> Path:
    """A copy of the Table II campaign whose robot is the shipped SK120 (loaded once)."""
    folder = tmp_path_factory.mktemp("fuzz-campaign")
    for name in ("campaign.toml", "measurements.csv"):
        shutil.copy(TABLE2 / name, folder / name)
    load_campaign(folder)  # warm the robot cache
    return folder


def restore(folder: Path) -> None:
    for name in ("campaign.toml", "measurements.csv"):
        shutil.copy(TABLE2 / name, folder / name)


def check_campaign_meaning(campaign, original) -> None:
    """An accepted campaign holds finite SI numbers, row for row those of the file."""
    for array in (campaign.q, campaign.force, campaign.deflection):
        assert np.all(np.isfinite(array))
    assert campaign.q.shape[0] == campaign.force.shape[0] == campaign.deflection.shape[0]
    assert campaign.q.shape[0] >= 1


@FUZZ
@given(data=st.data())
def test_measurement_csv_mutations(campaign_folder, data):
    original = load_campaign(campaign_folder)
    text = (TABLE2 / "measurements.csv").read_text()
    mutated = data.draw(csv_mutation(text))
    try:
        write_text(campaign_folder / "measurements.csv", mutated)
        result = assert_reader_contract(lambda: load_campaign(campaign_folder), campaign_folder)
        if result is not None:
            check_campaign_meaning(result, original)
    finally:
        restore(campaign_folder)


@FUZZ
@given(data=st.data())
def test_campaign_toml_mutations(campaign_folder, data):
    original = load_campaign(campaign_folder)
    text = (TABLE2 / "campaign.toml").read_text()
    mutated = data.draw(toml_mutation(text))
    try:
        write_text(campaign_folder / "campaign.toml", mutated)
        result = assert_reader_contract(lambda: load_campaign(campaign_folder), campaign_folder)
        if result is not None:
            check_campaign_meaning(result, original)
            if result.units.length == original.units.length:
                # the same file units: the same SI deflections
                np.testing.assert_allclose(result.deflection, original.deflection)
    finally:
        restore(campaign_folder)


def test_campaign_units_convert_to_si(campaign_folder):
    """Declaring the lengths in m instead of mm divides nothing: the same numbers, x1000."""
    original = load_campaign(campaign_folder)
    text = (TABLE2 / "campaign.toml").read_text().replace('length = "mm"', 'length = "m"')
    try:
        (campaign_folder / "campaign.toml").write_text(text)
        metres = load_campaign(campaign_folder)
        np.testing.assert_allclose(metres.deflection, original.deflection * 1000.0)
    finally:
        restore(campaign_folder)


# ------------------------------------------------------------------------------ list flags

numbers = st.floats(allow_nan=True, allow_infinity=True, width=64)


@FUZZ
@given(values=st.lists(numbers, min_size=1, max_size=8))
def test_parse_list_reads_back_finite_numbers(values):
    text = ",".join(repr(v) for v in values)
    try:
        parsed = flags.parse_list(text, "--q")
    except StiffnessError as exc:
        assert "\n" not in str(exc)
        assert not all(math.isfinite(v) and abs(v) <= MAX_CELL for v in values)
        return
    assert parsed == values


@FUZZ
@given(text=st.text(max_size=40))
def test_parse_list_on_any_text(text):
    try:
        parsed = flags.parse_list(text, "--wrench")
    except StiffnessError as exc:
        assert "\n" not in str(exc).strip()
        return
    assert all(math.isfinite(v) for v in parsed)


@FUZZ
@given(tokens=st.lists(st.sampled_from(["--q", "-35,-60,95", "-1e3", "--deg", "--", "-x",
                                        "--wrench", "-10,0,-100", "1,2", "--json", "=", "-"]),
                       max_size=8))
def test_negative_values_rewrite_keeps_every_token(tokens):
    """The argv rewrite only joins a one-value flag to a negative value; nothing is lost."""
    parser = flags.ArgumentParser(prog="t")
    parser.add_argument("--q")
    parser.add_argument("--wrench")
    parser.add_argument("--deg", action="store_true")
    parser.add_argument("--json", action="store_true")
    joined = flags.join_negative_values(parser, tokens)
    assert "".join(t.replace("=", "") for t in joined) == "".join(
        t.replace("=", "") for t in tokens)


@FUZZ
@given(pairs=st.lists(st.tuples(st.sampled_from(["shoulder_pan_joint", "elbow_joint", "q1",
                                                  "q6", "nope", "q0", "q99", ""]),
                                st.sampled_from(["0.5", "-1", "nan", "x", "", "1e400"])),
                      min_size=1, max_size=4))
def test_named_coordinates_flag(ur5, pairs):
    text = ",".join(f"{name}={value}" for name, value in pairs)
    args = argparse.Namespace(q=text, deg=False)
    try:
        q = flags.coordinates_from_args(ur5, args)
    except StiffnessError as exc:
        assert "\n" not in str(exc).strip()
        return
    assert np.all(np.isfinite(q))


# ---------------------------------------------------------------------- URDF and loop files


@pytest.fixture(scope="module")
def four_bar(tmp_path_factory) -> Path:
    """A shipped closed-loop robot's URDF and loop file, copied for mutation."""
    folder = tmp_path_factory.mktemp("fuzz-urdf")
    for path in (ROBOTS / "sk120").glob("sk120.*"):
        shutil.copy(path, folder / path.name)
    return folder


@FUZZ
@given(data=st.data())
def test_loop_file_mutations(four_bar, data):
    loops = four_bar / "sk120.loops.yaml"
    text = (ROBOTS / "sk120" / "sk120.loops.yaml").read_text()
    lines = text.splitlines()
    kind = data.draw(st.sampled_from(["truncate", "line", "type", "empty", "binary"]))
    if kind == "truncate":
        mutated = text[:data.draw(st.integers(0, len(text)))]
    elif kind == "line":
        i = data.draw(st.integers(0, len(lines) - 1))
        lines[i] = data.draw(st.sampled_from(["closed_loop: 3", "- [a, b]", "type: 9D",
                                              "  - [ , ]", "passive_joints: {x: 1}", ":", "[",
                                              "loop_types: [3d, 6D, nD]", "\t- x"]))
        mutated = "\n".join(lines)
    elif kind == "type":
        mutated = text.replace("3D", data.draw(st.sampled_from(["3d", "6d", "2D", "", "3D3D"])))
    elif kind == "empty":
        mutated = ""
    else:
        mutated = text[:data.draw(st.integers(0, len(text)))] + "\udcff\x00"
    try:
        write_text(loops, mutated)
        robot = assert_reader_contract(lambda: load_robot(str(four_bar / "sk120.urdf")),
                                       four_bar)
        if robot is not None:
            assert robot.model.nq > 0
    finally:
        shutil.copy(ROBOTS / "sk120" / "sk120.loops.yaml", loops)


@FUZZ
@given(data=st.data())
def test_urdf_mutations(four_bar, data):
    urdf = four_bar / "sk120.urdf"
    text = (ROBOTS / "sk120" / "sk120.urdf").read_text()
    kind = data.draw(st.sampled_from(["truncate", "attribute", "tag", "empty", "binary"]))
    if kind == "truncate":
        mutated = text[:data.draw(st.integers(0, len(text)))]
    elif kind == "attribute":
        target = data.draw(st.sampled_from(['xyz="', 'rpy="', 'lower="', 'upper="',
                                            'type="', 'link="', 'name="']))
        at = text.find(target, data.draw(st.integers(0, len(text) // 2)))
        value = data.draw(st.sampled_from(["nan ", "inf ", "1e999 ", "x ", " ", "\u00e9 "]))
        mutated = text if at < 0 else text[:at + len(target)] + value + text[at + len(target):]
    elif kind == "tag":
        mutated = text.replace("</joint>", data.draw(st.sampled_from(["", "</link>", "<joint>"])),
                               1)
    elif kind == "empty":
        mutated = ""
    else:
        mutated = "\udcff\udcfe" + text
    try:
        write_text(urdf, mutated)
        robot = assert_reader_contract(lambda: load_robot(str(urdf)), four_bar)
        if robot is not None:
            assert robot.model.nq > 0
    finally:
        shutil.copy(ROBOTS / "sk120" / "sk120.urdf", urdf)


SK120_DH = Path(__file__).resolve().parents[1] / "examples" / "sk120-dh" / "robot.toml"


@FUZZ
@given(data=st.data())
def test_dh_robot_toml_mutations(tmp_path_factory, data):
    """A DH robot.toml with controller coordinates (examples/sk120-dh): any mutation loads a
    robot whose kinematics are finite at its default pose, or is refused in one line."""
    folder = tmp_path_factory.mktemp("fuzz-dh")
    toml = folder / "robot.toml"
    write_text(toml, data.draw(toml_mutation(SK120_DH.read_text())))
    robot = assert_reader_contract(lambda: load_robot(str(toml)), folder)
    if robot is not None:
        q = robot.configuration(np.zeros(robot.n_coordinates))
        assert np.all(np.isfinite(q)) and robot.model.nq > 0


# ------------------------------------------------------------------------------ model files


@pytest.fixture(scope="module")
def model_file(tmp_path_factory) -> Path:
    from stiffness.cli.main import main

    folder = tmp_path_factory.mktemp("fuzz-model")
    path = folder / "identified-model.json"
    assert main(["identify", str(TABLE2), "--starts", "1", "--quiet", "--out", str(path)]) == 0
    return path


@FUZZ
@given(data=st.data())
def test_model_file_mutations(model_file, data):
    from stiffness.elastic.model_file import read_model_file

    doc = json.loads(model_file.read_text())
    path, value = data.draw(json_mutations(doc))
    target = model_file.parent / "mutated.json"
    kind = data.draw(st.sampled_from(["node", "truncate", "nan"]))
    text = json.dumps(doc)
    if kind == "node":
        text = json.dumps(replaced(doc, path, value))
    elif kind == "truncate":
        text = text[:data.draw(st.integers(0, len(text) - 1))]
    else:
        text = text.replace("e+", "e+9999", 1) if "e+" in text else text.replace("1", "NaN", 1)
    target.write_text(text)
    try:
        model = assert_reader_contract(lambda: read_model_file(target), model_file.parent)
        if model is not None:
            k = np.asarray(model.k_theta, dtype=float)
            assert np.all(np.isfinite(k)) and np.all(k > 0)
    finally:
        target.unlink()


# ------------------------------------------------------------------ path and pose CSV files

DOCS = Path(__file__).resolve().parents[1] / "docs" / "compensation"


@FUZZ
@given(data=st.data())
def test_joint_path_mutations(ur5, tmp_path_factory, data):
    from stiffness.machining.joint_path import read_joint_path

    folder = tmp_path_factory.mktemp("fuzz-path")
    text = (DOCS / "ur5-path.csv").read_text()
    original = read_joint_path(DOCS / "ur5-path.csv", ur5, deg=True)
    path = folder / "path.csv"
    write_text(path, data.draw(csv_mutation(text)))
    result = assert_reader_contract(lambda: read_joint_path(path, ur5, deg=True), folder)
    if result is not None:
        assert np.all(np.isfinite(result.coords))
        assert result.coords.shape[1] == original.coords.shape[1]


@FUZZ
@given(data=st.data())
def test_pose_file_mutations(tmp_path_factory, data):
    from stiffness.machining.poses import read_poses

    folder = tmp_path_factory.mktemp("fuzz-poses")
    text = (DOCS / "ur5-poses.csv").read_text()
    path = folder / "poses.csv"
    write_text(path, data.draw(csv_mutation(text)))
    result = assert_reader_contract(lambda: read_poses(path), folder)
    if result is not None:
        for value in vars(result).values():
            if isinstance(value, np.ndarray) and value.dtype.kind == "f":
                assert np.all(np.isfinite(value))


PLAN_UNITS = "# measurement plan; units: angle=deg force=N length=mm\n"
PLAN = """config,q1,q2,q3,q4,q5,q6,fx,fy,fz
P1,-25.09,167.78,22.40,-86.81,-92.99,139.72,57.735,57.735,57.735
P1,-25.09,167.78,22.40,-86.81,-92.99,139.72,-57.735,-57.735,-57.735
P2,10.0,-60.0,80.0,-20.0,90.0,0.0,0,0,100
"""


@FUZZ
@given(data=st.data())
def test_plan_file_mutations(ur5, tmp_path_factory, data):
    from stiffness.planning.plan import read_plan

    folder = tmp_path_factory.mktemp("fuzz-plan")
    path = folder / "plan.csv"
    keep_units = data.draw(st.booleans())
    write_text(path, (PLAN_UNITS if keep_units else "") + data.draw(csv_mutation(PLAN)))
    result = assert_reader_contract(lambda: read_plan(path, ur5), folder)
    if result is not None:
        plan, _ = result
        for value in vars(plan).values():
            if isinstance(value, np.ndarray) and value.dtype.kind == "f":
                assert np.all(np.isfinite(value))


def test_plan_reads_back_in_si(ur5, tmp_path):
    from stiffness.planning.plan import read_plan

    path = tmp_path / "plan.csv"
    path.write_text(PLAN_UNITS + PLAN)
    plan, _ = read_plan(path, ur5)
    arrays = {k: v for k, v in vars(plan).items() if isinstance(v, np.ndarray)}
    q = next(v for v in arrays.values() if v.ndim == 2 and v.shape[1] == 6)
    np.testing.assert_allclose(q[-1], np.deg2rad([10.0, -60.0, 80.0, -20.0, 90.0, 0.0]))
