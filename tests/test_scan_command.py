"""``stiffness scan``: workspace maps, chunked streaming, resume, Dask.

* The Table IV preset reproduces the definiteness counts of
stiffness.workspace.definiteness.definiteness_scan
  (through batched_definiteness_scan, checked against it in test_batch.py) and obeys K_C's
  linearity in the load (PD(F) = ND(-F)).
* A grid scan's maps equal the one-at-a-time API at sampled configurations; the files
  (manifest, NPZ chunks, Parquet parts, figures, summary) are there and readable.
* A killed scan resumes: only the missing chunks are computed, the maps are unchanged.
* A Dask LocalCluster scan (two workers) writes the same maps as the single-process scan.
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from stiffness.batch import kernels as batch
from stiffness.cli import scan as scan_command
from stiffness.cli.main import main
from stiffness.mechanics.formulation import (
    cartesian_stiffness,
    compliance,
    definiteness,
    target_state,
)
from stiffness.robot.robot import load_robot
from stiffness.workspace import engine
from stiffness.workspace.spec import ScanSpec

ROOT = Path(__file__).resolve().parents[1]
UR5_KQ = "3e5,3e5,2e5,4e4,4e4,4e4"
GRID = ["--axis", "shoulder_lift_joint=-90:0:30", "--axis", "elbow_joint=20:140:40",
        "--axis", "wrist_1_joint=-60:60:60", "--deg"]


def _run(argv, capsys=None):
    code = main(argv)
    out = capsys.readouterr() if capsys is not None else None
    return code, out


def _arrays(folder):
    return engine.load_scan(folder)


# ------------------------------------------------------------------------------ Table IV


def test_table4_preset(tmp_path, capsys):
    """`stiffness scan --robot sk120 --preset table4`: 5824 x 8 maps, the counts of the
    reproduction's scan, linear in the load, written with figures."""
    from stiffness.papers.reproduction import table4_grid, table4_loads
    from stiffness.workspace.definiteness import batched_definiteness_scan

    out = tmp_path / "t4"
    code, captured = _run(["scan", "--robot", "sk120", "--preset", "table4", "--out", str(out),
                           "--json", "--quiet"], capsys)
    assert code == 0
    summary = json.loads(captured.out)
    assert summary["configurations"] == 5824 == summary["valid_configurations"]
    robot = load_robot("sk120")
    names, loads = table4_loads()
    reference = batched_definiteness_scan(robot, table4_grid(), loads,
                                          np.diag(robot.defaults["k_theta_SI"]))
    for j, name in enumerate(names):
        counts = summary["load_cases"][name]["k_c"]
        assert {k: counts[k] for k in ("PD", "PSD", "ND", "NSD", "ID")} == reference.counts(j)
        assert summary["load_cases"][name]["k_theta_minus_k_c"]["PD"] == 5824
        assert summary["load_cases"][name]["k_c_determinant_positive"] == int(
            reference.determinant_positive[:, j].sum())
    for a, b in (("1", "2"), ("3", "6"), ("4", "7"), ("5", "8")):
        ca, cb = summary["load_cases"][a]["k_c"], summary["load_cases"][b]["k_c"]
        assert ca["PD"] == cb["ND"] and ca["ID"] == cb["ID"]
    maps = _arrays(out)
    assert maps["k_x"].shape == (5824, 8, 3, 3)
    np.testing.assert_array_equal(maps["coordinates"], table4_grid())
    for name in ("manifest.json", "summary.json", "definiteness_counts.png",
                 "definiteness_map.png", "stiffness_map.png"):
        assert (out / name).is_file()
        if name.endswith(".png"):
            assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# ------------------------------------------------------------------------------ grid


def test_grid_maps_equal_one_at_a_time(tmp_path, capsys):
    """Every stored quantity equals the one-at-a-time API at sampled configurations."""
    out = tmp_path / "grid"
    code, captured = _run(["scan", "--robot", "ur5", "--kq", UR5_KQ, *GRID, "--load", "0,0,-200",
                           "--load", "150,0,0", "--chunk-size", "7", "--out", str(out),
                           "--no-plots", "--quiet"], capsys)
    assert code == 0
    assert "definiteness of K_C" in captured.out
    maps = _arrays(out)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["n_configurations"] == 4 * 4 * 3 == maps["index"].shape[0]
    assert manifest["n_chunks"] == 7
    np.testing.assert_array_equal(maps["index"], np.arange(48))
    robot = load_robot("ur5")
    k_theta = np.diag([3e5, 3e5, 2e5, 4e4, 4e4, 4e4])
    loads = np.array([[0, 0, -200.0], [150.0, 0, 0]])
    # grid order: first axis outermost
    assert np.allclose(np.rad2deg(maps["coordinates"][:3, 1:4]),
                       [[-90, 20, -60], [-90, 20, 0], [-90, 20, 60]])
    for i in (0, 5, 17, 30, 47):
        q = robot.configuration(maps["coordinates"][i])
        assert maps["valid"][i]
        for j, load in enumerate(loads):
            state = target_state(robot, q, load)
            assert batch.class_names(maps["k_c_class"][i, j]) == definiteness(state.k_c)
            assert batch.class_names(maps["tangent_class"][i, j]) == definiteness(
                k_theta - state.k_c)
            c = compliance(state.jacobian[:3], k_theta - state.k_c)
            k_x = cartesian_stiffness(c)
            np.testing.assert_allclose(maps["k_x"][i, j], k_x, rtol=1e-9,
                                       atol=1e-9 * np.abs(k_x).max())
            np.testing.assert_allclose(maps["k_x_eigenvalues"][i, j],
                                       np.linalg.eigvalsh(0.5 * (k_x + k_x.T)), rtol=1e-9)
        k_conv = cartesian_stiffness(compliance(state.jacobian[:3], k_theta))
        np.testing.assert_allclose(maps["k_x_conventional"][i], k_conv, rtol=1e-9,
                                   atol=1e-9 * np.abs(k_conv).max())
        np.testing.assert_allclose(maps["position"][i], state.position, atol=1e-12)
    summary = json.loads((out / "summary.json").read_text())
    total = sum(summary["load_cases"]["1"]["k_c"].values())
    assert total == 48 and summary["chunks"]["computed"] == 7


def test_parquet_and_figures(tmp_path):
    pq = pytest.importorskip("pyarrow.parquet")
    out = tmp_path / "pq"
    assert main(["scan", "--robot", "ur5", "--kq", UR5_KQ, *GRID, "--format", "both",
                 "--map-axes", "shoulder_lift_joint,elbow_joint", "--out", str(out),
                 "--quiet"]) == 0
    table = pq.read_table(out / "maps.parquet").to_pandas() if _has_pandas() else None
    parts = sorted((out / "maps.parquet").glob("part-*.parquet"))
    assert len(parts) == 1
    arrow = pq.read_table(parts[0])
    assert arrow.num_rows == 48
    assert {"configuration", "load_case", "q_elbow_joint", "x_m", "k_c_class",
            "k_x_eig0_N_per_m", "k_x_22"} <= set(arrow.column_names)
    maps = _arrays(out)
    np.testing.assert_array_equal(arrow.column("k_x_eig0_N_per_m").to_numpy(),
                                  maps["k_x_eigenvalues"][:, 0, 0])
    if table is not None:
        assert len(table) == 48
    for name in ("definiteness_map.png", "stiffness_map.png", "definiteness_counts.png"):
        assert (out / name).read_bytes()[:4] == b"\x89PNG"


def _has_pandas() -> bool:
    try:
        import pandas  # noqa: F401
    except ImportError:
        return False
    return True


def test_samples_default_out_and_single_axis(tmp_path, monkeypatch, capsys):
    """Random samples within joint limits, seeded; the default output folder is new each time;
    a single map axis draws line plots."""
    monkeypatch.chdir(tmp_path)
    argv = ["scan", "--robot", "ur5", "--kq", UR5_KQ, "--samples", "40", "--seed", "3",
            "--axis", "elbow_joint=-2:2", "--chunk-size", "16", "--quiet"]
    assert main(argv) == 0
    assert main(argv) == 0
    first, second = tmp_path / "ur5-samples", tmp_path / "ur5-samples-2"
    assert first.is_dir() and second.is_dir()
    a, b = _arrays(first), _arrays(second)
    np.testing.assert_array_equal(a["coordinates"], b["coordinates"])
    assert np.all(np.abs(a["coordinates"][:, 2]) <= 2.0)
    assert np.unique(a["coordinates"][:, 2]).shape[0] == 40
    assert (first / "stiffness_map.png").is_file()
    capsys.readouterr()


# ------------------------------------------------------------------------------ resume


def test_resume_recomputes_only_missing_chunks(tmp_path):
    out = tmp_path / "resume"
    argv = ["scan", "--robot", "ur5", "--kq", UR5_KQ, *GRID, "--chunk-size", "10",
            "--out", str(out), "--no-plots", "--quiet", "--json"]
    assert main(argv) == 0
    before = _arrays(out)
    # a killed run: chunk 2 never finished, chunk 3 wrote its data but not its aggregate
    (out / "chunks" / "chunk-00002.npz").unlink()
    (out / "chunks" / "aggregate-00002.npz").unlink()
    (out / "chunks" / "aggregate-00003.npz").unlink()
    spec = ScanSpec.from_dict(json.loads((out / "manifest.json").read_text())["spec"])
    summary = engine.run_scan(spec, out, plots=False)
    assert summary["chunks"] == {"total": 5, "computed": 2, "resumed": 3, "chunk_size": 10}
    after = _arrays(out)
    for key in before:
        np.testing.assert_array_equal(before[key], after[key])
    # another scan into the same folder is refused
    assert main(["scan", "--robot", "ur5", "--kq", UR5_KQ, *GRID, "--load", "1,2,3",
                 "--out", str(out), "--quiet"]) == 2


def test_robot_paths_are_relative_to_the_scan_folder(tmp_path, monkeypatch):
    """manifest.json and summary.json name a robot file relative to their folder: a scan given
    the same robot by another relative path resumes it, and the spec read back finds it."""
    (tmp_path / "r").mkdir()
    shutil.copy(ROOT / "examples" / "sk120-dh" / "robot.toml", tmp_path / "r")
    (tmp_path / "work" / "sub").mkdir(parents=True)
    common = ["scan", "--axis", "joint2=-30:30:30", "--deg", "--chunk-size", "2", "--no-plots",
              "--quiet", "--json"]
    monkeypatch.chdir(tmp_path / "work")
    assert main([*common, "--robot", "../r/robot.toml", "--out", "../out/deep"]) == 0
    folder = tmp_path / "out" / "deep"
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["spec"]["robot"]["source"] == "../../r/robot.toml"
    assert json.loads((folder / "summary.json").read_text())["robot"] == "../../r/robot.toml"
    monkeypatch.chdir(tmp_path / "work" / "sub")
    assert engine.run_scan(ScanSpec.from_dict(manifest["spec"], folder), "../../out/deep",
                           plots=False)["chunks"]["resumed"] == 2
    assert main([*common, "--robot", "../../r/robot.toml", "--out", "../../out/deep"]) == 0
    assert engine._manifest_spec(folder).robot["source"] == str(
        (tmp_path / "r" / "robot.toml").resolve())


# ------------------------------------------------------------------------------ Dask


def test_dask_local_cluster_gives_the_same_maps(tmp_path):
    """Two Dask workers (a LocalCluster) write exactly the maps of the single-process scan,
    on a closed-loop robot (shared closures per chunk) and with chunks finishing out of
    order."""
    pytest.importorskip("distributed")
    common = ["scan", "--robot", "sk120", "--samples", "300", "--seed", "1",
              "--axis", "q2=-1:1", "--axis", "q3=-1.5:0.5", "--axis", "q1=-3:3",
              "--load", "0,0,-500", "--load", "300,-200,100", "--chunk-size", "50",
              "--no-plots", "--quiet"]
    local, dask = tmp_path / "local", tmp_path / "dask"
    assert main([*common, "--out", str(local)]) == 0
    assert main([*common, "--out", str(dask), "--workers", "2"]) == 0
    # a given client (a remote cluster): the chunks' arrays travel back and are written here
    distributed = pytest.importorskip("distributed")
    spec = ScanSpec.from_dict(json.loads((local / "manifest.json").read_text())[
        "spec"])
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        gathered = engine.run_scan(spec, tmp_path / "gathered", client=client, plots=False)
    assert gathered["chunks"]["computed"] == 6
    a = _arrays(local)
    for other in (dask, tmp_path / "gathered"):
        b = _arrays(other)
        assert a.keys() == b.keys()
        for key in a:
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    sa = json.loads((local / "summary.json").read_text())
    sb = json.loads((dask / "summary.json").read_text())
    assert sa["load_cases"] == sb["load_cases"] == gathered["load_cases"]


def test_run_chunks_in_process_and_on_a_client():
    """The engine streams every chunk once, in process or on a Dask client."""
    from stiffness.workspace.distributed import run_chunks

    seen = {}
    assert run_chunks(_square, (3,), range(5), seen.__setitem__) == 5
    assert seen == {i: 3 + i * i for i in range(5)}
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        got = {}
        assert run_chunks(_square, (3,), range(9), got.__setitem__, client=client) == 9
    assert got == {i: 3 + i * i for i in range(9)}


def _square(offset: int, index: int) -> int:
    return offset + index * index


def _die_once(marker: str, index: int) -> int:
    """Chunk 3 kills its worker process the first time it runs (a crashed machine)."""
    import os
    from pathlib import Path

    if index == 3 and not Path(marker).exists():
        Path(marker).write_text("killed")
        os._exit(1)
    return index * 10


def test_killed_worker_loses_only_its_chunk(tmp_path):
    """A worker process dies while computing a chunk: Dask restarts it and recomputes that
    chunk only; every chunk is delivered exactly once."""
    distributed = pytest.importorskip("distributed")
    cloudpickle = pytest.importorskip("cloudpickle")
    import sys

    from stiffness.workspace.distributed import run_chunks

    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    marker = tmp_path / "killed"
    try:
        with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                      dashboard_address=None) as cluster, \
                distributed.Client(cluster) as client:
            got: dict[int, int] = {}

            def collect(index: int, value: int) -> None:
                assert index not in got
                got[index] = value

            assert run_chunks(_die_once, (str(marker),), range(8), collect, client=client) == 8
    finally:
        cloudpickle.unregister_pickle_by_value(sys.modules[__name__])
    assert marker.exists()
    assert got == {i: 10 * i for i in range(8)}


# ------------------------------------------------------------------------------ errors


@pytest.mark.parametrize("argv, message", [
    (["--robot", "ur5", "--preset", "table4", "--kq", UR5_KQ], "SK120 grid"),
    (["--robot", "ur5"], "--kq is required"),
    (["--robot", "ur5", "--kq", UR5_KQ, "--axis", "elbow=0:1:0.1"], "not a coordinate"),
    (["--robot", "ur5", "--kq", UR5_KQ, "--axis", "elbow_joint=0..1"], "JOINT=LO:HI"),
    (["--robot", "ur5", "--kq", UR5_KQ, "--axis", "elbow_joint=0:1"], "STEP"),
    (["--robot", "ur5", "--kq", UR5_KQ, "--axis", "q3=1:0:0.1"], "upper bound"),
    (["--robot", "ur5", "--kq", UR5_KQ, "--load", "1,2"], "--load"),
    (["--robot", "ur5", "--kq", UR5_KQ, "--samples", "2.5"], "--samples"),
    (["--robot", "ur5", "--kq", UR5_KQ, "--q", "1,2"], "--q needs 6"),
    (["--robot", "ur5", "--kq", UR5_KQ, "--chunk-size", "0"], "--chunk-size"),
    (["--robot", "ur5", "--kq", UR5_KQ, "--workers", "0"], "--workers"),
    (["--robot", "sk120", "--preset", "table4", "--samples", "5"], "drop --axis"),
])
def test_errors(tmp_path, capsys, argv, message):
    code = main(["scan", *argv, "--out", str(tmp_path / "x"), "--quiet", "--no-plots"])
    assert code == 2
    assert message in capsys.readouterr().err


# ------------------------------------------------------------------------------ fields, dtypes


def _single_pose_maps(robot, coords, loads, k_theta):
    """Every stored quantity at one configuration, by the one-at-a-time API."""
    q = robot.configuration(coords)
    out = {"k_c_class": [], "tangent_class": [], "critical_factor": [], "det": [], "k_x": [],
           "det_sure": []}
    k_half = np.diag(1 / np.sqrt(np.diag(k_theta)))
    for load in loads:
        state = target_state(robot, q, load)
        out["k_c_class"].append(definiteness(state.k_c))
        out["tangent_class"].append(definiteness(k_theta - state.k_c))
        top = np.linalg.eigvalsh(k_half @ (0.5 * (state.k_c + state.k_c.T)) @ k_half)[-1]
        out["critical_factor"].append(1 / top if top > 0 else np.inf)
        out["det"].append(np.linalg.det(state.k_c))
        # the sign of det K_C is round-off where K_C is (numerically) singular
        out["det_sure"].append(abs(out["det"][-1]) > 1e-9 * np.abs(state.k_c).max()
                               ** robot.n_compliant)
        out["k_x"].append(cartesian_stiffness(compliance(state.jacobian[:3],
                                                         k_theta - state.k_c)))
    out["k_x_conventional"] = cartesian_stiffness(compliance(state.jacobian[:3], k_theta))
    out["position"] = state.position
    out["k_c_diagonal"] = [np.diag(target_state(robot, q, f).k_c) for f in np.eye(3)]
    return out


@pytest.mark.parametrize("robot_name, dtype, compression, loads", [
    ("ur5", "float64", None, ["0,0,-200"]),             # one force: gravity route
    ("ur5", "float32", "zstd", ["0,0,-200", "150,0,0"]),  # Hessian route, float32, deflated
    ("sk120", "float32", None, ["0,0,-500"]),           # closed loop, one force
    ("sk120", "float64", "gzip", ["0,0,-500", "300,-200,100"]),
])
def test_every_stored_field_equals_single_pose(tmp_path, robot_name, dtype, compression,
                                               loads):
    """Every field (--fields all) in every dtype, read back by load_scan (derived arrays
    rebuilt), equals the one-at-a-time API; the Parquet table holds the same numbers."""
    pq = pytest.importorskip("pyarrow.parquet")
    out = tmp_path / "f"
    if robot_name == "ur5":
        where = [*GRID, "--kq", UR5_KQ]
    else:
        where = ["--samples", "12", "--axis", "q2=-1:1", "--axis", "q3=-1.5:0.5",
                 "--axis", "q1=-3:3", "--axis", "q5=-1:1"]
    argv = ["scan", "--robot", robot_name, *where, "--fields", "all", "--dtype", dtype,
            "--format", "both", "--chunk-size", "5", "--out", str(out), "--no-plots",
            "--quiet", "--json"]
    for load in loads:
        argv += ["--load", load]
    if compression:
        argv += ["--compression", compression]
    assert main(argv) == 0
    maps = _arrays(out)
    robot = load_robot(robot_name)
    k_theta = (np.diag([3e5, 3e5, 2e5, 4e4, 4e4, 4e4]) if robot_name == "ur5"
               else np.diag(robot.defaults["k_theta_SI"]))
    forces = np.array([[float(v) for v in x.split(",")] for x in loads])
    rtol = 1e-9 if dtype == "float64" else 2e-7
    assert maps["k_x"].dtype == np.float64  # read back as float64 whatever was stored
    for i in range(0, maps["index"].shape[0], 5):
        assert maps["valid"][i]
        ref = _single_pose_maps(robot, maps["coordinates"][i], forces, k_theta)
        for j in range(len(loads)):
            assert batch.class_names(maps["k_c_class"][i, j]) == ref["k_c_class"][j]
            assert batch.class_names(maps["tangent_class"][i, j]) == ref["tangent_class"][j]
            assert maps["critical_factor"][i, j] == pytest.approx(ref["critical_factor"][j],
                                                                  rel=rtol)
            if ref["det_sure"][j]:
                assert maps["k_c_det_positive"][i, j] == (ref["det"][j] > 0)
            k_x = ref["k_x"][j]
            np.testing.assert_allclose(maps["k_x"][i, j], k_x, rtol=rtol,
                                       atol=rtol * np.abs(k_x).max())
            eig = np.linalg.eigvalsh(0.5 * (k_x + k_x.T))
            np.testing.assert_allclose(maps["k_x_eigenvalues"][i, j], eig, rtol=rtol * 10)
            assert maps["regular"][i, j]
            assert batch.class_names(maps["k_x_class"][i, j]) == definiteness(k_x)
        k_conv = ref["k_x_conventional"]
        np.testing.assert_allclose(maps["k_x_conventional"][i], k_conv, rtol=rtol,
                                   atol=rtol * np.abs(k_conv).max())
        np.testing.assert_allclose(maps["position"][i], ref["position"], rtol=rtol,
                                   atol=1e-12)
        diag = np.array(ref["k_c_diagonal"])
        np.testing.assert_allclose(maps["k_c_diagonal"][i], diag, rtol=rtol,
                                   atol=rtol * np.abs(diag).max())
    stored = np.load(out / "chunks" / "chunk-00000.npz")
    assert "k_x_eigenvalues" not in stored and "regular" not in stored  # derivable: not stored
    assert stored["k_x_upper"].dtype == np.dtype(dtype) and stored["k_x_upper"].shape[-1] == 6
    table = pq.read_table(out / "maps.parquet" / "part-00000.parquet")
    assert table.column("k_x_01").type.to_pandas_dtype() == np.dtype(dtype)
    np.testing.assert_allclose(table.column("k_x_01").to_numpy().reshape(-1, len(loads)),
                               maps["k_x"][:5, :, 0, 1], rtol=1e-7)
    if compression:
        assert pq.ParquetFile(out / "maps.parquet" / "part-00000.parquet").metadata.row_group(
            0).column(0).compression.lower() == compression


def test_fields_choose_what_is_stored_and_bytes_are_reported(tmp_path, capsys):
    """--fields k_x stores only K_X's upper triangle (its eigenvalues are rebuilt); the run
    prints its bytes per configuration and they match the files."""
    out = tmp_path / "lean"
    code, captured = _run(["scan", "--robot", "ur5", "--kq", UR5_KQ, *GRID,
                           "--fields", "k_x_eigenvalues", "--dtype", "float32",
                           "--out", str(out), "--quiet"], capsys)
    assert code == 0
    assert "bytes per configuration" in captured.out
    summary = json.loads((out / "summary.json").read_text())
    files = sorted((out / "chunks").glob("chunk-*.npz"))
    assert summary["bytes_written"] == sum(f.stat().st_size for f in files)
    assert summary["bytes_per_configuration"] == pytest.approx(summary["bytes_written"] / 48)
    assert set(np.load(files[0])) == {"k_x_upper"}
    maps = _arrays(out)
    assert {"index", "coordinates", "k_x", "k_x_eigenvalues", "regular", "k_x_class"} == set(
        maps)
    assert "k_c" not in summary["load_cases"]["1"] and "k_x" in summary["load_cases"]["1"]
    assert not (out / "definiteness_counts.png").exists()
    assert main(["scan", "--robot", "ur5", "--kq", UR5_KQ, *GRID, "--fields", "stiffness",
                 "--out", str(tmp_path / "bad"), "--quiet"]) == 2
    assert "unknown field 'stiffness'" in capsys.readouterr().err


def test_console_names_the_stiffness_range_and_where_k_x_is_undefined(tmp_path, capsys):
    """The run's last lines give each load case's principal stiffness range, that of the
    stored maps' eigenvalues, and where K_X is undefined: everywhere for a planar 2R arm, whose
    3x3 compliance has rank 2 (two springs cannot resist three directions)."""
    out = tmp_path / "ur5"
    code, captured = _run(["scan", "--robot", "ur5", "--kq", UR5_KQ, *GRID, "--load", "0,0,-200",
                           "--load", "0,0,0", "--out", str(out), "--no-plots"], capsys)
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    maps = _arrays(out)
    for name, case in summary["load_cases"].items():
        j = int(name) - 1
        low = float(np.nanmin(maps["k_x_eigenvalues"][:, j]))
        high = float(np.nanmax(maps["k_x_eigenvalues"][:, j]))
        assert case["min_principal_stiffness_N_per_m"] == pytest.approx(low, rel=1e-12)
        assert (f"K_X, load case {name}: principal stiffness {low:.4g} to {high:.4g} N/m"
                in captured.out.splitlines())
    planar = tmp_path / "planar.urdf"
    planar.write_text("""<?xml version="1.0"?>
<robot name="planar">
  <link name="base"/><link name="l1"/><link name="l2"/><link name="tip"/>
  <joint name="j1" type="continuous"><parent link="base"/><child link="l1"/>
    <axis xyz="0 0 1"/></joint>
  <joint name="j2" type="continuous"><parent link="l1"/><child link="l2"/>
    <origin xyz="0.4 0 0"/><axis xyz="0 0 1"/></joint>
  <joint name="tip_joint" type="fixed"><parent link="l2"/><child link="tip"/>
    <origin xyz="0.3 0 0"/></joint>
</robot>
""")
    code, captured = _run(["scan", "--robot", str(planar), "--kq", "10,10", "--samples", "30",
                           "--load", "5,0,0", "--out", str(tmp_path / "planar"), "--no-plots"],
                          capsys)
    assert code == 0
    assert captured.out.splitlines()[-1].startswith(
        "K_X: undefined at all 30 valid configurations: the target moves in fewer than 3 "
        "directions at every one")


def test_killed_scan_resumed_with_workers_gives_the_same_maps(tmp_path):
    """A scan killed mid-run (chunks missing, one without its aggregate) and resumed on two
    Dask workers, several chunks per task, gives the maps and summary of an uninterrupted
    one-process scan."""
    pytest.importorskip("distributed")
    common = ["scan", "--robot", "sk120", "--samples", "240", "--seed", "2",
              "--axis", "q2=-1:1", "--axis", "q3=-1.5:0.5", "--axis", "q1=-3:3",
              "--load", "0,0,-500", "--chunk-size", "20", "--no-plots", "--quiet"]
    whole, resumed = tmp_path / "whole", tmp_path / "resumed"
    assert main([*common, "--out", str(whole)]) == 0
    assert main([*common, "--out", str(resumed)]) == 0
    for index in (1, 4, 5, 9):
        (resumed / "chunks" / f"chunk-{index:05d}.npz").unlink()
        (resumed / "chunks" / f"aggregate-{index:05d}.npz").unlink()
    (resumed / "chunks" / "aggregate-00007.npz").unlink()  # data written, not marked done
    assert main([*common, "--out", str(resumed), "--workers", "2",
                 "--chunks-per-task", "2", "--json"]) == 0
    summary = json.loads((resumed / "summary.json").read_text())
    assert summary["chunks"]["computed"] == 5 and summary["chunks"]["resumed"] == 7
    a, b = _arrays(whole), _arrays(resumed)
    assert a.keys() == b.keys()
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    assert json.loads((whole / "summary.json").read_text())["load_cases"] == summary[
        "load_cases"]


def test_failed_write_keeps_the_finished_chunks_and_resumes(tmp_path, monkeypatch):
    """A chunk whose files cannot be written stops the scan with that error; the chunks the
    writer thread finished before it stay complete (files and aggregate), and rerunning the
    command computes only the rest and gives the maps of an uninterrupted scan."""
    from stiffness.errors import OutputError

    common = ["scan", "--robot", "ur5", "--kq", UR5_KQ, "--samples", "60", "--seed", "4",
              "--chunk-size", "10", "--no-plots", "--quiet"]
    whole, broken = tmp_path / "whole", tmp_path / "broken"
    assert main([*common, "--out", str(whole)]) == 0
    write = engine.write_chunk

    def failing(out, spec, index, maps, formats, parts=None):
        if index == 3:
            raise OutputError(f"cannot write {out}: disk full (test)", path=str(out))
        return write(out, spec, index, maps, formats, parts)

    monkeypatch.setattr(engine, "write_chunk", failing)
    with pytest.raises(OutputError):
        engine.run_scan(scan_command.build_spec(_parsed(common + ["--out", str(broken)]))[0],
                        broken, plots=False)
    assert not broken.exists()  # the folder is published whole; the next run resumes it
    building = next(tmp_path.glob(".broken.*.staging"))
    done = sorted(p.name for p in (building / "chunks").glob("aggregate-*.npz"))
    assert "aggregate-00003.npz" not in done and {"aggregate-00000.npz", "aggregate-00001.npz",
                                                 "aggregate-00002.npz"} <= set(done)
    monkeypatch.setattr(engine, "write_chunk", write)
    assert main([*common, "--out", str(broken), "--json"]) == 0
    summary = json.loads((broken / "summary.json").read_text())
    assert summary["chunks"]["resumed"] == len(done)
    a, b = _arrays(whole), _arrays(broken)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def _parsed(argv):
    import argparse

    parser = argparse.ArgumentParser()
    scan_command.configure_parser(parser)
    return parser.parse_args(argv[1:])


def test_scan_of_a_fixed_floating_base_robot_and_its_resume(tmp_path):
    """`scan --fixed-base` loads the same robot where the chunks are computed (its spec says
    so), and the same command resumes the scan. Its default springs are the two joints of the
    leg that carries the target (the chain to the target frame, docs/robot-files.md)."""
    out = tmp_path / "solo"
    argv = ["scan", "--robot", "solo8", "--fixed-base", "--kq", "50,50",
            "--samples", "40", "--chunk-size", "20", "--no-plots", "--quiet", "--out",
            str(out)]
    assert main(argv) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["spec"]["robot"]["fixed_base"] is True
    assert main([*argv, "--json"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["chunks"]["resumed"] == 2 and summary["valid_configurations"] == 40


def test_python_scan_of_a_loaded_robot_reloads_it_with_its_base_and_loop_file(tmp_path):
    """stiffness.scan(robot=Robot): the chunks reload the robot from its name, with its fixed
    base (a fixed solo8 raised FloatingBaseError) and a loop file other than the one its
    source finds (the SK120's own stays out of the spec, as before)."""
    import stiffness

    solo = load_robot("solo8", fixed_base=True)
    result = stiffness.scan(robot=solo, k_theta=[50, 50], samples=4, out=tmp_path / "s",
                            plots=False)
    assert result.to_dict()["valid_configurations"] == 4
    manifest = json.loads((tmp_path / "s" / "manifest.json").read_text())
    assert manifest["spec"]["robot"]["fixed_base"] is True
    from stiffness.workspace.request import _reload_options

    sk120 = load_robot("sk120")
    assert _reload_options(sk120) == {}
    copy = tmp_path / "copy.loops.yaml"
    copy.write_text(Path(sk120.loop_file).read_text())
    assert _reload_options(load_robot("sk120", loops=copy)) == {"loops": str(copy.resolve())}


# ------------------------------------------------------------------------------ scan size


@given(lower=st.floats(-10, 10), width=st.floats(0, 10), step=st.floats(1e-3, 5))
def test_grid_length_is_the_length_of_the_grid_axis(lower, width, step):
    from stiffness.workspace.spec import grid_axis, grid_length

    assert grid_length(lower, lower + width, step) == len(grid_axis(lower, lower + width, step))


def test_chunk_coordinates_are_the_grid_axis_values(ur5):
    """Chunk coordinates come from index arithmetic, not from built axes: the same values."""
    from stiffness.workspace.spec import ScanSpec, grid_axis

    axes = [{"index": 1, "joint": "shoulder_lift_joint", "lower": -1.3, "upper": 0.4,
             "step": 0.17},
            {"index": 2, "joint": "elbow_joint", "lower": 0.2, "upper": 2.0, "step": 0.3}]
    spec = ScanSpec(robot={"source": "ur5"}, preset="grid",
                    coordinate_joints=list(ur5.coordinate_joints), base=[0.1] * 6, axes=axes,
                    samples=None, seed=0, loads=[[0, 0, -100]], load_names=["1"],
                    k_theta=[1e4] * 6, chunk_size=7)
    a, b = (grid_axis(x["lower"], x["upper"], x["step"]) for x in axes)
    expected = np.array([[v, w] for v in a for w in b])
    got = np.concatenate([spec.chunk_coordinates(i)[1] for i in range(spec.n_chunks)])
    np.testing.assert_array_equal(got[:, 1:3], expected)
    np.testing.assert_array_equal(got[:, [0, 3, 4, 5]], 0.1)


@pytest.mark.parametrize("argv, message", [
    (["--axis", "shoulder_lift_joint=0:1:1e-12"], "the figures' maps would have 1e+12 cells"),
    (["--axis", "shoulder_lift_joint=0:1:1e-4", "--axis", "elbow_joint=0:1:1e-4"],
     "(map axes 10001 x 10001, 1 load case), more than 4e+06; use a coarser STEP"),
    (["--axis", "shoulder_lift_joint=0:1:1e-320"], "no finite number of values"),
    (["--samples", "1e12"], "the scan would write at least 2.76e+05 GB (1e+12 configurations)"),
])
def test_scans_too_large_are_refused_before_anything_is_written(tmp_path, capsys, argv,
                                                                message):
    out = tmp_path / "big"
    assert main(["scan", "--robot", "ur5", "--kq", UR5_KQ, *argv, "--out", str(out),
                 "--quiet"]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err
    assert not out.exists()


def test_projected_bytes_bound_the_written_bytes_and_meet_the_free_space(tmp_path, monkeypatch,
                                                                          capsys):
    """The projection is what the chunks then hold; a disk with less free space refuses."""
    import shutil as shutil_module
    from collections import namedtuple


    argv = ["scan", "--robot", "ur5", "--kq", UR5_KQ, "--samples", "600", "--chunk-size",
            "300", "--no-plots", "--quiet"]
    assert main([*argv, "--out", str(tmp_path / "ok")]) == 0
    summary = json.loads((tmp_path / "ok" / "summary.json").read_text())
    spec = ScanSpec.from_dict(
        json.loads((tmp_path / "ok" / "manifest.json").read_text())["spec"])
    per = engine.stored_bytes_per_configuration(spec)
    assert per <= summary["bytes_per_configuration"] <= 1.1 * per
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil_module, "disk_usage", lambda _: usage(10**9, 10**9, 600 * per - 1))
    capsys.readouterr()
    assert main([*argv, "--out", str(tmp_path / "full")]) == 2
    err = capsys.readouterr().err
    assert "the scan would write at least" in err and "GB free" in err, err
    assert not (tmp_path / "full").exists()
    monkeypatch.setattr(shutil_module, "disk_usage", lambda _: usage(10**9, 10**9, 600 * per))
    assert main([*argv, "--out", str(tmp_path / "fits")]) == 0


def test_singularity_ratio_is_that_of_the_singular_values():
    """sigma_min / sigma_max from J J^T's eigenvalues equals numpy's SVD (1e-12), 0 for a
    rank-deficient or short Jacobian, NaN for a non-finite one."""
    from stiffness.workspace.maps import singularity_ratio
    rng = np.random.default_rng(4)
    jac = rng.normal(size=(200, 3, 6))
    jac[0, 2] = jac[0, 0] + jac[0, 1]  # rank 2: the ratio is (about) zero
    jac[1, 0, 0] = np.nan
    values = np.linalg.svd(np.nan_to_num(jac), compute_uv=False)
    ratio = singularity_ratio(jac)
    np.testing.assert_allclose(ratio[2:], values[2:, -1] / values[2:, 0], rtol=1e-12)
    assert ratio[0] < 1e-7 and np.isnan(ratio[1])
    assert np.all(singularity_ratio(rng.normal(size=(5, 3, 2))) == 0.0)


# ------------------------------------------------------------------------------ default load


@pytest.mark.parametrize("robot_name", ["sk120", "ur5"])
def test_default_load_is_the_robots_as_in_kx(robot_name):
    """Without --wrench a scan takes the robot's declared wrench_SI (the load kx and view use)
    and says so; a robot declaring none gets 0,0,-100 N, echoed as the default."""
    parser = argparse.ArgumentParser()
    scan_command.configure_parser(parser)
    args = parser.parse_args(["--robot", robot_name, "--samples", "2"]
                             + ([] if robot_name == "sk120" else ["--kq", UR5_KQ]))
    spec, robot = scan_command.build_spec(args)
    declared = robot.defaults.get("wrench_SI")
    expected = [0.0, 0.0, -100.0] if declared is None else [float(v) for v in declared]
    assert [list(map(float, load)) for load in spec.loads] == [expected]
    wrench_line = next(line for line in scan_command.echo_lines(spec, robot, args)
                       if line.startswith("wrench"))
    assert ("wrench_SI" in wrench_line) == (declared is not None)
    assert robot_name != "sk120" or declared is not None  # the shipped SK120 declares its load


def test_an_axis_beyond_the_joint_limits_is_warned_about(tmp_path, recwarn):
    """``--axis elbow_joint=0:90:30`` without ``--deg`` swept the UR5's elbow to 90 rad with no
    word (``--q`` is warned about); now one warning names the range, the limits and ``--deg``,
    and the same range in degrees is quiet."""
    base = ["scan", "--robot", "ur5", "--kq", UR5_KQ, "--wrench", "0,0,-100", "--quiet",
            "--no-plots"]
    assert main([*base, "--axis", "elbow_joint=0:90:30", "--out", str(tmp_path / "a")]) == 0
    [message] = [str(w.message) for w in recwarn if "--axis" in str(w.message)]
    assert message == ("ur5: --axis elbow_joint runs 0..90, beyond elbow_joint's limits "
                       "[-3.14159, 3.14159] (rad, m) (the values look like degrees: add --deg)")
    recwarn.clear()
    assert main([*base, "--axis", "elbow_joint=0:90:30", "--deg", "--out",
                 str(tmp_path / "b")]) == 0
    assert not [w for w in recwarn if "--axis" in str(w.message)]
