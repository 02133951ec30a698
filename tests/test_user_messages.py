"""What a new user meets when naming a robot (issue 30, items 4 and 5): meshes of a copied
example-robot-data URDF, robot names in any case, folders, presets that imply their robot,
and no bare ``inf`` in a printed summary."""

from __future__ import annotations

import contextlib
import io
import shutil
from pathlib import Path

import pytest

from stiffness.cli.main import main
from stiffness.errors import StiffnessError, UnknownRobotError
from stiffness.robot.meshes import resolve_mesh
from stiffness.robot.robot import load_robot
from stiffness.robot.sources import resolve_source


def run_cli(argv: list[str]) -> tuple[int, str, str]:
    """Exit status, stdout and stderr of ``stiffness ARGV`` run in this process."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


def test_a_copied_example_robot_data_urdf_finds_its_meshes(tmp_path):
    """``package://example-robot-data/robots/...`` resolves from a copy outside the package."""
    original = resolve_source("ur5").urdf
    copy = tmp_path / "ur5.urdf"
    shutil.copy(original, copy)
    name = "package://example-robot-data/robots/ur_description/meshes/ur5/visual/base.dae"
    found = resolve_mesh(name, copy)
    assert found is not None and found.is_file()
    assert found.resolve() == (original.parents[1] / "meshes/ur5/visual/base.dae").resolve()
    robot = load_robot(copy)
    assert robot.missing_meshes == ()
    assert all(g.meshPath.endswith(".dae") for g in robot.visual_model.geometryObjects)


@pytest.mark.parametrize("given,loaded", [("UR5", "ur5"), ("Panda", "panda"),
                                          ("SK120", "sk120")])
def test_robot_names_ignore_case(given, loaded):
    assert load_robot(given).name == loaded


def test_an_unknown_name_suggests_a_few():
    with pytest.raises(UnknownRobotError) as info:
        load_robot("pandaa")
    message = str(info.value)
    assert "did you mean panda" in message and "\n" not in message
    assert len(message) < 400  # not the 75 names


def test_folders_as_robots(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(StiffnessError, match="is a folder holding no robot.toml and no URDF"):
        load_robot(empty)
    one = tmp_path / "one"
    one.mkdir()
    shutil.copy(resolve_source("ur5").urdf, one / "arm.urdf")
    assert load_robot(one).n_coordinates == 6
    shutil.copy(resolve_source("ur5").urdf, one / "other.urdf")
    with pytest.raises(StiffnessError, match="folder holding 2 URDF files"):
        load_robot(one)
    shipped = Path(__file__).resolve().parents[1] / "robots" / "sk120"
    assert load_robot(shipped).coordinate_joints == load_robot("sk120").coordinate_joints


def test_cli_names_a_folder_as_a_folder(tmp_path):
    code, _, err = run_cli(["kx", "--robot", str(tmp_path), "--kq", "1", "--wrench", "0,0,1"])
    assert code == 2 and "is a folder" in err and "does not exist" not in err


def test_scan_preset_implies_its_robot(tmp_path):
    """``scan --preset table4`` without ``--robot``: the SK120 (the spec only, no scan run)."""
    import argparse

    from stiffness.cli import scan
    from stiffness.cli.flags import ArgumentParser

    parser = ArgumentParser()
    scan.configure_parser(parser)
    args = parser.parse_args(["--preset", "table4", "--out", str(tmp_path / "t4")])
    assert isinstance(args, argparse.Namespace)
    spec, robot = scan.build_spec(args)
    assert robot.name == "sk120" and spec.preset == "table4"


def test_design_says_undetermined_not_inf(tmp_path):
    """One row cannot determine six stiffnesses: the summary says so in words."""
    code, out, err = run_cli(["design", "--robot", "ur5", "--kq", "3e5,3e5,2e5,4e4,4e4,4e4",
                              "--configs", "1", "--loads-per-config", "1", "--max-force",
                              "100", "--noise", "1e-5", "--candidates", "20",
                              "--out", str(tmp_path / "d")])
    assert code == 0, err
    import re

    assert not re.search(r"\b(inf|nan)\b", out, re.IGNORECASE), out
    assert "undetermined: the rows leave that stiffness free" in out


def test_diagnosis_page_says_undetermined_for_an_unbounded_interval():
    """diagnosis.json writes an infinite bound as null: the page says 'undetermined' and what
    is known, not '0 to —'."""
    from stiffness.calibration.parameter_section import parameter_rows

    rows = parameter_rows("joint stiffness", {
        "joint2": {"value": 3.024e7, "standard_error": None, "ci95": [0.0, None],
                   "unit": "N.m/rad"},
        "joint3": {"value": 9.35e5, "standard_error": 1.2e4, "ci95": [9.1e5, 9.6e5],
                   "unit": "N.m/rad"}})
    undetermined, determined = rows
    assert undetermined[3] == "undetermined"
    assert undetermined[4].startswith("<b>undetermined</b> (at least 0, no upper bound")
    assert "—" not in undetermined[4]
    assert determined[3] == 1.2e4 and determined[4] == "[9.1e+05, 9.6e+05]"


def test_kx_says_when_a_pose_is_near_a_kinematic_singularity():
    """A Kinova arm folded back on itself (q2, q3 at 3.1 rad): K_X exists but its two largest
    principal stiffnesses are 5000 and 14000 times the smallest, growing without bound at the
    singularity; kx printed them with no word. The ratio sigma_min/sigma_max of the
    translational Jacobian (Pinocchio's frame Jacobian here) is printed below the scan's 0.01,
    and in --json; a pose away from it gets no note."""
    import json

    import numpy as np
    import pinocchio as pin

    kq = "2e4,2e4,2e4,5e3,5e3,5e3"
    robot = load_robot("kinova")
    for q, near in (("0,3.1,3.1,0,3.14159,0", True), ("0,2.6,4.7,3.1,2.6,0", False)):
        argv = ["kx", "--robot", "kinova", "--kq", kq, "--q", q, "--wrench", "0,0,-50"]
        code, out, _ = run_cli([*argv, "--json"])
        ratio = json.loads(out)["singularity_ratio"]
        full = robot.configuration([float(v) for v in q.split(",")])
        jac = pin.computeFrameJacobian(robot.model, robot.data, full, robot.target_frame_id,
                                       pin.LOCAL_WORLD_ALIGNED)[:3]
        sv = np.linalg.svd(jac[:, robot.compliant_v], compute_uv=False)
        assert ratio == pytest.approx(sv[2] / sv[0], rel=1e-9)
        assert (ratio < 0.01) == near
        code, out, _ = run_cli([*argv, "--quiet"])
        assert code == 0
        notes = [line for line in out.splitlines() if "near a kinematic singularity" in line]
        assert notes == ([f"note: near a kinematic singularity: sigma_min/sigma_max of the "
                          f"translational Jacobian is {ratio:.2g} (below 0.01, where `stiffness "
                          "scan` leaves a pose out of its ranges): the largest principal "
                          "stiffnesses grow without bound as it is approached"] if near else [])
