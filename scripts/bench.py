"""Benchmarks of the batched elastostatics (issue 6): per-configuration cost, Table IV, scaling.

Usage::

    python scripts/bench.py            # tables (ratios and absolute times), then scaling
    python scripts/bench.py --json     # one JSON line: per-robot costs and the Table IV time
    python scripts/bench.py --quick    # fewer configurations and rounds (a smoke run)

Per robot (ur5, panda with its seven arm joints, the SK120 with its loop), per configuration,
all in this process, each the best of several interleaved rounds (the machine is shared: the
minimum is the least disturbed measurement, and interleaving exposes every method to the same
load):

* ``batched_kx_us``: :func:`stiffness.batch.kernels.evaluate`, the loaded enhanced translational K_X
  (K_C, compliance, K_X) of many configurations under one dead force; for the SK120 the loop is
  closed beforehand (``sk120_with_closure_us`` adds the closure of random configurations);
* ``bare_pinocchio_us``: one ``pin.computeStaticTorqueDerivatives`` call per configuration
  (the floor of any Python-driven evaluation: the derivative alone, no Jacobian, no algebra);
* ``finite_difference_us``: what a user writes by hand: central differences of J(q)^T F (two
  frame-Jacobian calls per compliant joint; for the SK120 each perturbed configuration is
  re-closed by :meth:`Robot.configuration` and J is the closed-loop Jacobian), then the same
  compliance and K_X with ``np.linalg`` one configuration at a time.

``table4_scan_s``: the full A&S Table IV scan (5824 configurations x 8 load cases: closures,
kinematics, K_C classes, K_theta - K_C classes, critical loads, enhanced and conventional K_X and
their principal values, NPZ chunk written), one process, robot loaded, figures not drawn.

Scaling: batched K_X for 1e3 ... 1e6 UR5 configurations (time per configuration should stay
flat), and ``stiffness scan`` runs (in subprocesses: wall time and peak memory) over 1e4 ... 1e6
samples, and with 1 and 2 Dask workers.

Issue 15 figures (``--json`` keys), each a ratio or time measured in this run:

* ``scan_end_to_end_over_kernel``: the in-process UR5 scan (default fields) per configuration
  over the batched loaded K_X (``kernel_us``); ``scan_fields_k_x_over_kernel`` with
  ``--fields k_x``; ``bytes_per_configuration`` (default fields, float64) and variants;
* ``dask_two_workers_speedup`` and ``dask_one_worker_over_in_process``: 2e6 configurations in
  process, on one and on two LocalCluster workers (cluster start-up excluded, in ``dask``);
* ``sk120.ratio_to_bare``: the SK120's batched K_X over the bare call;
* ``diagnose_200_rows_s``, ``identify_exact_200_rows_s``, ``report_s``, ``import_s``: new
  processes, imports included (``import_s`` over a bare interpreter);
  ``diagnose_200_rows_with_effects_s``: ``diagnose`` on a campaign with hidden effects;
* the real-time compensator (issue 39; ``--compensator`` runs these alone), on the UR5 and the
  Panda's arm with the links' weight, a 3 kg payload, a softening spring and a backlash, over
  256 poses and a 6-component wrench, against one bare ``pin.forwardKinematics`` +
  ``pin.computeFrameJacobian`` per pose in the same interleaved rounds:
  ``compensator_over_fk_jacobian`` (UR5, one ``command`` per pose, target <= 10),
  ``compensator_panda_over_fk_jacobian`` (<= 10), ``compensator_path_over_fk_jacobian``
  (UR5, ``command_path`` per pose, <= 3) and ``compensator_path_panda_over_fk_jacobian``;
  the times ``compensator_ur5_us``, ``compensator_panda_us``, ``compensator_path_*_us``,
  ``fk_jacobian_*_us``;
* ``load_average``: ``os.getloadavg()`` before and after (the machine is shared);
  ``python_yardstick_s``: a fixed pure-Python loop (2e6 additions, best of three), the
  machine's speed for interpreted code in this run (the commands' times above are mostly
  interpreter and import work: compare days through it).
* pose calibration (issues 29 and 37; ``--pose POSES`` runs these alone), on a simulated
  1000-pose campaign of the two-arm torso with two markers: ``pose_diagnose_1000_poses_s``,
  ``pose_fit_1000_poses_s`` (one full fit), ``pose_fk_1000_poses_s`` (one forward-kinematics
  + frame-Jacobian pass over the rows and markers), ``pose_fit_1000_poses_over_fk`` (target
  <= 100) and ``pose_diagnose_1000_poses_over_fit`` (target <= 15).
* ``--lumped`` alone: the masses-unknown pose fit (``gravity_lumped``) on the 22 Panda poses of
  tests/test_absolute_poses.py, over a forward-kinematics pass of the same rows
  (``pose_lumped_fit_22_poses_over_fk``; :func:`lumped_gravity_costs`).
* ``--design-sampling`` alone: experiment design's pose draws on the Griffis-Duffy platform
  over the closure of the poses kept (``griffis_duffy_sampling_over_assembly``;
  :func:`design_sampling_costs`).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.batch import kernels as batch
from stiffness.mechanics.formulation import velocity_projection
from stiffness.robot.kinematics import LWA, update_first_order
from stiffness.robot.robot import Robot, load_robot

PANDA_ARM = [f"panda_joint{i}" for i in range(1, 8)]
FORCE = np.array([120.0, -80.0, -250.0])  # N


def _robots() -> dict[str, tuple[Robot, np.ndarray]]:
    """name -> (robot, joint stiffness N.m/rad)."""
    return {
        "ur5": (load_robot("ur5"), np.array([3e5, 3e5, 2e5, 4e4, 4e4, 4e4])),
        "panda": (load_robot("panda", compliant_joints=PANDA_ARM),
                  np.array([3e5, 3e5, 2e5, 2e5, 5e4, 5e4, 5e4])),
        "sk120": (load_robot("sk120"), np.array([1.4098e6, 4.0076e5, 9.3528e5])),
    }


def _configurations(robot: Robot, m: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(coordinates, closed q) of m random configurations (SK120: the paper's workspace)."""
    rng = np.random.default_rng(seed)
    if robot.loop.is_open_chain:
        lo, hi = -np.pi, np.pi
        coords = rng.uniform(lo, hi, (m, robot.n_coordinates))
        return coords, batch.tree_configurations(robot, coords)
    lo = np.deg2rad([-180, -70, -115, -180, -180, -180])
    hi = np.deg2rad([180, 70, 35, 180, 180, 180])
    coords = lo + rng.uniform(size=(m, 6)) * (hi - lo)
    closed = batch.close_loops(robot, coords)
    return coords[closed.closed], closed.q[closed.closed]


# ------------------------------------------------------------------------------ methods


def bare_pinocchio(robot: Robot, q: np.ndarray) -> None:
    """``computeStaticTorqueDerivatives`` once per configuration (force at the target)."""
    model, data = robot.model, robot.data
    frame = model.frames[robot.target_frame_id]
    fext = pin.StdVec_Force()
    for _ in range(model.njoints):
        fext.append(pin.Force.Zero())
    fext[frame.parentJoint] = pin.Force(FORCE, np.cross(frame.placement.translation, FORCE))
    derivatives = pin.computeStaticTorqueDerivatives
    for qi in q:
        derivatives(model, data, qi, fext)


def batched(robot: Robot, q: np.ndarray, k_theta: np.ndarray, method: str = "auto") -> None:
    """The batched loaded enhanced K_X (translational, one force)."""
    batch.evaluate(robot, q, FORCE, k_theta, method=method)


def batched_with_closure(robot: Robot, coords: np.ndarray, k_theta: np.ndarray) -> None:
    """The same from coordinates: loop closures included."""
    closed = batch.close_loops(robot, coords)
    batch.evaluate(robot, closed.q, FORCE, k_theta)


def finite_difference(robot: Robot, q: np.ndarray, k_theta: np.ndarray,
                      h: float = 1e-6) -> None:
    """Hand-written baseline: central differences of J(q)^T F, then compliance and K_X."""
    model, data = robot.model, robot.data
    fid = robot.target_frame_id
    k = np.diag(k_theta)
    frame_jacobian = pin.computeFrameJacobian
    cq = [model.joints[model.getJointId(j)].idx_q for j in robot.compliant_joints]
    cv = robot.compliant_v
    n = len(cq)
    if robot.loop.is_open_chain:
        for qi in q:
            jac = frame_jacobian(model, data, qi, fid, LWA)[:3, cv]
            k_c = np.empty((n, n))
            for col, idx in enumerate(cq):
                qp, qm = qi.copy(), qi.copy()
                qp[idx] += h
                qm[idx] -= h
                tp = frame_jacobian(model, data, qp, fid, LWA)[:3, cv].T @ FORCE
                tm = frame_jacobian(model, data, qm, fid, LWA)[:3, cv].T @ FORCE
                k_c[:, col] = (tp - tm) / (2.0 * h)
            c = jac @ np.linalg.solve(k - k_c, jac.T)
            np.linalg.inv(c)
        return
    coordinate_of = robot.compliant_in_coordinates
    for qi in q:
        coords = robot.coordinates_of(qi)
        jac = _closed_jacobian(robot, qi)
        k_c = np.empty((n, n))
        for col, idx in enumerate(coordinate_of):
            taus = []
            for sign in (1.0, -1.0):
                c = coords.copy()
                c[idx] += sign * h
                taus.append(_closed_jacobian(robot, robot.configuration(c, seed=qi)).T @ FORCE)
            k_c[:, col] = (taus[0] - taus[1]) / (2.0 * h)
        c = jac @ np.linalg.solve(k - k_c, jac.T)
        np.linalg.inv(c)


def _closed_jacobian(robot: Robot, q: np.ndarray) -> np.ndarray:
    update_first_order(robot.model, robot.data, q)
    j_full = pin.getFrameJacobian(robot.model, robot.data, robot.target_frame_id, LWA)
    return (j_full @ velocity_projection(robot))[:3]


def _best(functions: dict, counts: dict, rounds: int) -> dict[str, float]:
    """Interleaved rounds; per method the best time per configuration (us)."""
    best = {name: np.inf for name in functions}
    for _ in range(rounds):
        for name, fn in functions.items():
            t0 = time.perf_counter()
            fn()
            best[name] = min(best[name], (time.perf_counter() - t0) / counts[name] * 1e6)
    return best


def per_configuration(quick: bool) -> dict[str, dict[str, float]]:
    """Per-configuration costs of every method on every robot (us)."""
    out = {}
    rounds = 3 if quick else 7
    for name, (robot, k_theta) in _robots().items():
        m = 512 if quick else 4096
        coords, q = _configurations(robot, m, seed=1)
        m = q.shape[0]
        fd_m = min(m, 16 if not robot.loop.is_open_chain else (64 if quick else 256))
        functions = {
            "bare_pinocchio_us": lambda r=robot, q=q: bare_pinocchio(r, q),
            "batched_kx_us": lambda r=robot, q=q, k=k_theta: batched(r, q, k),
            "finite_difference_us": lambda r=robot, q=q[:fd_m], k=k_theta:
                finite_difference(r, q, k),
        }
        counts = {"bare_pinocchio_us": m, "batched_kx_us": m, "finite_difference_us": fd_m}
        if robot.loop.is_open_chain:
            functions["batched_kx_hessian_us"] = lambda r=robot, q=q, k=k_theta: batched(
                r, q, k, "hessian")
            counts["batched_kx_hessian_us"] = m
        else:
            functions["batched_kx_with_closure_us"] = (
                lambda r=robot, c=coords, k=k_theta: batched_with_closure(r, c, k))
            counts["batched_kx_with_closure_us"] = m
        result = _best(functions, counts, rounds)
        result["ratio_to_bare"] = result["batched_kx_us"] / result["bare_pinocchio_us"]
        result["speedup_over_fd"] = result["finite_difference_us"] / result["batched_kx_us"]
        out[name] = result
    return out


def _compensated_models() -> dict:
    """name -> (elastic model, wanted coordinates (m, n)) of the compensator benchmark: the
    UR5 and the Panda's arm with their links' weight, a payload, a softening spring and a
    backlash (the closed form with every preload and a nonlinear law)."""
    from stiffness.elastic.effects.parts import ElasticParts
    from stiffness.elastic.model import ElasticModel

    out = {}
    for name, (robot, k_theta) in _robots().items():
        if not robot.loop.is_open_chain:
            continue
        joints = robot.compliant_joints
        parts = ElasticParts(dict(zip(joints, k_theta, strict=True)),
                             beta={joints[1]: 1e-4}, backlash={joints[2]: 3e-4},
                             smoothing={joints[2]: 2.0})
        parts.weigh(3.0, np.zeros(3))
        coords, _ = _configurations(robot, 256, seed=2)
        out[name] = (ElasticModel.of_parts(robot, parts), coords)
    return out


def compensator_costs(rounds: int) -> dict[str, float]:
    """The real-time compensator (issue 39) against one bare Pinocchio forward kinematics and
    frame Jacobian per pose (``pin.forwardKinematics`` + ``pin.computeFrameJacobian``), in
    interleaved rounds over the same 256 poses (best round): ``command`` per pose, and
    ``command_path`` over the whole path per pose (us and ratios)."""
    out = {}
    wrench = np.array([120.0, -80.0, -250.0, 3.0, -2.0, 1.0])
    for name, (em, coords) in _compensated_models().items():
        robot = em.robot
        model, data, fid = robot.model, robot.model.createData(), robot.target_frame_id
        qs = [robot.configuration(c) for c in coords]
        comp = em.compensator()
        command_out = np.empty(robot.n_coordinates)

        def bare(model=model, data=data, fid=fid, qs=qs):
            for q in qs:
                pin.forwardKinematics(model, data, q)
                pin.computeFrameJacobian(model, data, q, fid, LWA)

        def single(comp=comp, coords=coords, out=command_out):
            for c in coords:
                comp.command(c, wrench, out=out)

        def path(comp=comp, coords=coords):
            comp.command_path(coords, wrench)

        m = len(coords)
        best = _best({"bare": bare, "single": single, "path": path},
                     {"bare": m, "single": m, "path": m}, rounds)
        out[f"compensator_{name}_us"] = best["single"]
        out[f"compensator_path_{name}_us"] = best["path"]
        out[f"fk_jacobian_{name}_us"] = best["bare"]
        out[f"compensator_{name}_over_fk_jacobian"] = best["single"] / best["bare"]
        out[f"compensator_path_{name}_over_fk_jacobian"] = best["path"] / best["bare"]
    out["compensator_over_fk_jacobian"] = out.pop("compensator_ur5_over_fk_jacobian")
    out["compensator_path_over_fk_jacobian"] = out.pop("compensator_path_ur5_over_fk_jacobian")
    return out


def table4_seconds(rounds: int = 3) -> float:
    """Wall time of the Table IV scan in this process (robot loaded, no figures), best of N."""
    from stiffness.cli import scan as scan_command
    from stiffness.workspace import engine as workspace_scan

    parser = argparse.ArgumentParser()
    scan_command.configure_parser(parser)
    spec, _ = scan_command.build_spec(parser.parse_args(["--robot", "sk120", "--preset",
                                                         "table4"]))
    workspace_scan.scan_chunk(spec.to_dict(), 0)  # loads the worker's robot once
    best = np.inf
    for _ in range(rounds):
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            workspace_scan.run_scan(spec, Path(tmp) / "t4", plots=False)
            best = min(best, time.perf_counter() - t0)
    return best


def table4_cli_seconds() -> float:
    """Wall time of `stiffness scan --robot sk120 --preset table4` (new process, figures)."""
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "stiffness.cli.main", "scan", "--robot", "sk120",
                        "--preset", "table4", "--out", str(Path(tmp) / "t4"), "--quiet"],
                       check=True, stdout=subprocess.DEVNULL)
        return time.perf_counter() - t0


def scaling_configurations(sizes: list[int]) -> list[dict]:
    """Batched K_X on the UR5 for growing numbers of configurations (blocks of 4096)."""
    robot, k_theta = _robots()["ur5"]
    rows = []
    for m in sizes:
        rng = np.random.default_rng(m)
        total, done, t0 = 0.0, 0, time.perf_counter()
        while done < m:  # generate in pieces: the input itself would not bound memory
            count = min(65536, m - done)
            q = batch.tree_configurations(robot, rng.uniform(-np.pi, np.pi, (count, 6)))
            t1 = time.perf_counter()
            batch.evaluate(robot, q, FORCE, k_theta)
            total += time.perf_counter() - t1
            done += count
        rows.append({"configurations": m, "seconds": total, "us_per_configuration":
                     total / m * 1e6, "wall_s": time.perf_counter() - t0})
    return rows


_SCAN_SNIPPET = """
import json, resource, sys, tempfile, time
from pathlib import Path
import argparse
from stiffness.cli import scan
import dask
from stiffness.workspace.distributed import CLUSTER_CONFIG, WORKER_ENVIRONMENT, warm_worker
from stiffness.workspace.engine import run_scan
dask.config.set(CLUSTER_CONFIG)
p = argparse.ArgumentParser(); scan.configure_parser(p)
args = p.parse_args(sys.argv[1:-1])
spec, _ = scan.build_spec(args)
workers = int(sys.argv[-1])
client = cluster = None
startup = 0.0
if workers > 1:
    from distributed import Client, LocalCluster
    t0 = time.perf_counter()
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                           dashboard_address=None, env=dict(WORKER_ENVIRONMENT))
    client = Client(cluster)
    client.run(warm_worker, spec.robot)  # each worker loads the robot once
    startup = time.perf_counter() - t0
else:
    warm_worker(spec.robot)
with tempfile.TemporaryDirectory() as tmp:
    t0 = time.perf_counter()
    run_scan(spec, Path(tmp) / "s", plots=False, client=client, write_on_workers=True)
    wall = time.perf_counter() - t0
if client is not None:
    client.close(); cluster.close()
status = dict(line.split(":", 1) for line in open("/proc/self/status").read().splitlines()
              if ":" in line)
self_kb = float(status["VmHWM"].split()[0])  # peak resident memory of this process
child_kb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss  # largest worker
print(json.dumps({"seconds": wall, "startup_s": startup, "driver_peak_MB": self_kb / 1024,
                  "worker_peak_MB": child_kb / 1024}))
"""


def scaling_scans(sizes: list[int], workers: list[int], worker_size: int) -> list[dict]:
    """`stiffness scan` on UR5 samples in subprocesses: wall time and peak memory."""
    base = ["--robot", "ur5", "--kq", "3e5,3e5,2e5,4e4,4e4,4e4", "--load", "0,0,-200",
            "--chunk-size", "8192", "--quiet"]
    runs = [(m, 1) for m in sizes]
    runs += [(worker_size, w) for w in workers if w > 1 or worker_size not in sizes]
    rows = []
    for m, w in runs:
        result = subprocess.run(
            [sys.executable, "-c", _SCAN_SNIPPET, *base, "--samples", str(m), str(w)],
            check=True, capture_output=True, text=True, env={**os.environ})
        row = json.loads(result.stdout.strip().splitlines()[-1])
        row.update({"configurations": m, "workers": w,
                    "us_per_configuration": row["seconds"] / m * 1e6})
        rows.append(row)
    return rows


# ------------------------------------------------------------------------------ issue 15

UR5_SCAN = ["--robot", "ur5", "--frame", "tool0", "--kq", "3e5,3e5,2e5,4e4,4e4,4e4",
            "--load", "0,0,-200", "--quiet", "--no-plots"]


def _scan_spec(argv: list[str]):
    from stiffness.cli import scan as scan_command

    parser = argparse.ArgumentParser()
    scan_command.configure_parser(parser)
    return scan_command.build_spec(parser.parse_args(argv))[0]


def scan_over_kernel(samples: int, rounds: int) -> dict[str, float]:
    """In-process UR5 scan (robot loaded, no figures) per configuration, over the batched
    loaded K_X kernel on the same robot and load, interleaved rounds in this run."""
    from stiffness.workspace.distributed import warm_worker
    from stiffness.workspace.engine import run_scan

    specs = {"default": _scan_spec([*UR5_SCAN, "--samples", str(samples)]),
             "k_x": _scan_spec([*UR5_SCAN, "--samples", str(samples), "--fields", "k_x"]),
             "float32": _scan_spec([*UR5_SCAN, "--samples", str(samples), "--dtype",
                                    "float32"])}
    warm_worker(specs["default"].robot)
    robot = load_robot("ur5", frame="tool0")
    k_theta = np.array([3e5, 3e5, 2e5, 4e4, 4e4, 4e4])
    rng = np.random.default_rng(5)
    q = batch.tree_configurations(robot, rng.uniform(-np.pi, np.pi, (8192, 6)))
    force = np.array([0.0, 0.0, -200.0])
    best = {"kernel": np.inf, **{k: np.inf for k in specs}}
    size = {}
    for _ in range(rounds):
        t0 = time.perf_counter()
        batch.evaluate(robot, q, force, k_theta)
        best["kernel"] = min(best["kernel"], (time.perf_counter() - t0) / q.shape[0])
        for name, spec in specs.items():
            with tempfile.TemporaryDirectory() as tmp:
                t0 = time.perf_counter()
                summary = run_scan(spec, Path(tmp) / "s", plots=False)
                best[name] = min(best[name], (time.perf_counter() - t0) / samples)
            size[name] = summary["bytes_per_configuration"]
    return {
        "kernel_us": best["kernel"] * 1e6,
        "scan_us": best["default"] * 1e6,
        "scan_end_to_end_over_kernel": best["default"] / best["kernel"],
        "scan_fields_k_x_over_kernel": best["k_x"] / best["kernel"],
        "scan_float32_over_kernel": best["float32"] / best["kernel"],
        "bytes_per_configuration": size["default"],
        "bytes_per_configuration_float32": size["float32"],
        "bytes_per_configuration_fields_k_x": size["k_x"],
    }


_DASK_SNIPPET = """
import json, sys, tempfile, time
from pathlib import Path
sys.path.insert(0, sys.argv[1])
import bench
import dask
from stiffness.workspace.distributed import CLUSTER_CONFIG, WORKER_ENVIRONMENT, warm_worker
from stiffness.workspace.engine import run_scan
dask.config.set(CLUSTER_CONFIG)
workers = int(sys.argv[2])
spec = bench._scan_spec(sys.argv[3:])
client = cluster = None
t0 = time.perf_counter()
if workers:
    from distributed import Client, LocalCluster
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                           dashboard_address=None, env=dict(WORKER_ENVIRONMENT))
    client = Client(cluster)
    client.run(warm_worker, spec.robot)
else:
    warm_worker(spec.robot)
startup = time.perf_counter() - t0
with tempfile.TemporaryDirectory() as tmp:
    t0 = time.perf_counter()
    summary = run_scan(spec, Path(tmp) / "s", plots=False, client=client,
                       write_on_workers=True)
    wall = time.perf_counter() - t0
if client is not None:
    client.close(); cluster.close()
print(json.dumps({"seconds": wall, "startup_s": startup, "dask": summary.get("dask")}))
"""


def dask_scaling(samples: int, rounds: int) -> dict:
    """The UR5 scan in a subprocess: in-process, on one and on two LocalCluster workers
    (single-threaded, writing their own chunks), best of ``rounds`` interleaved runs each;
    cluster start-up excluded (reported apart)."""
    argv = [*UR5_SCAN, "--samples", str(samples)]
    best: dict[int, dict] = {}
    for _ in range(rounds):
        for workers in (0, 1, 2):
            result = subprocess.run(
                [sys.executable, "-c", _DASK_SNIPPET, str(Path(__file__).parent),
                 str(workers), *argv], check=True, capture_output=True, text=True,
                env={**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"})
            row = json.loads(result.stdout.strip().splitlines()[-1])
            if workers not in best or row["seconds"] < best[workers]["seconds"]:
                best[workers] = row
    return {
        "configurations": samples,
        "in_process_s": best[0]["seconds"],
        "one_worker_s": best[1]["seconds"],
        "two_workers_s": best[2]["seconds"],
        "cluster_startup_s": best[2]["startup_s"],
        "dask_two_workers_speedup": best[0]["seconds"] / best[2]["seconds"],
        "dask_one_worker_over_in_process": best[1]["seconds"] / best[0]["seconds"],
        "task_overhead_s": (best[2]["dask"] or {}).get("task_overhead_s"),
        "chunk_seconds": (best[2]["dask"] or {}).get("chunk_seconds"),
        "chunks_per_task": (best[2]["dask"] or {}).get("chunks_per_task"),
    }


def scan_time_rows(sizes: list[int], workers: tuple[int, ...] = (0, 2)) -> list[dict]:
    """Wall time of the UR5 scan for each size, in process (0) and on LocalCluster workers
    (start-up excluded), one subprocess per run; each row is also printed as a JSON line."""
    rows = []
    for m in sizes:
        for count in workers:
            result = subprocess.run(
                [sys.executable, "-c", _DASK_SNIPPET, str(Path(__file__).parent),
                 str(count), *UR5_SCAN, "--samples", str(m)], check=True,
                capture_output=True, text=True)
            row = json.loads(result.stdout.strip().splitlines()[-1])
            rows.append({"configurations": m, "workers": count, "seconds": row["seconds"],
                         "startup_s": row["startup_s"], "load": os.getloadavg()[0]})
            print(json.dumps(rows[-1]), flush=True)
    return rows


def draw_scan_time(rows: list[dict], path: Path) -> None:
    """Log-log figure of :func:`scan_time_rows` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for workers, label in ((0, "in process"), (2, "two Dask workers (start-up excluded)")):
        pts = sorted((r["configurations"], r["seconds"]) for r in rows
                     if r["workers"] == workers)
        if pts:
            ax.loglog(*zip(*pts, strict=True), "o-", label=label)
    loads = [r["load"] for r in rows]
    ax.set_xlabel("configurations")
    ax.set_ylabel("wall time (s)")
    ax.set_title("stiffness scan, UR5, one force, default fields\n(2 shared cores, load "
                 f"average {min(loads):.0f}-{max(loads):.0f})", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.savefig(path, dpi=100, bbox_inches="tight")


def _wall(argv: list[str], rounds: int = 1, cwd: str | None = None) -> float:
    """Best wall time (s) of a command in a new process."""
    best = np.inf
    for _ in range(rounds):
        t0 = time.perf_counter()
        subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                       cwd=cwd)
        best = min(best, time.perf_counter() - t0)
    return best


def python_yardstick_s(rounds: int = 3) -> float:
    """Best time (s) of a fixed pure-Python loop: the interpreter's speed on this machine now."""
    best = np.inf
    for _ in range(rounds):
        t0 = time.perf_counter()
        total = 0
        for i in range(2_000_000):
            total += i
        best = min(best, time.perf_counter() - t0)
    return best


def commands_seconds(rounds: int) -> dict[str, float]:
    """``import stiffness`` (over a bare interpreter), ``stiffness report``, and ``diagnose``
    / ``identify --formulation exact`` on a simulated 200-row UR5 campaign (``diagnose`` also
    on one with a hidden backlash and a misaligned frame), each in a new process (imports
    included), best of ``rounds``."""
    python = [sys.executable]
    bare = _wall([*python, "-c", "pass"], rounds)
    out = {"import_s": _wall([*python, "-c", "import stiffness"], rounds) - bare}
    cli = [*python, "-m", "stiffness.cli.main"]
    with tempfile.TemporaryDirectory() as tmp:
        campaign = Path(tmp) / "campaign"
        simulate = [*cli, "simulate", "--robot", "ur5", "--kq", "3e5,3e5,2e5,4e4,4e4,4e4",
                    "--configs", "50", "--loads-per-config", "4", "--seed", "3"]
        subprocess.run([*simulate, "--out", str(campaign)], check=True, capture_output=True)
        out["diagnose_200_rows_s"] = _wall([*cli, "diagnose", str(campaign), "--json"], rounds,
                                           cwd=tmp)
        hidden = Path(tmp) / "campaign-with-effects"  # what diagnose is for: effects to find
        subprocess.run([*simulate, "--effect", "backlash:shoulder_lift_joint=0.01",
                        "--effect", "frame_misalignment=1", "--out", str(hidden)],
                       check=True, capture_output=True)
        out["diagnose_200_rows_with_effects_s"] = _wall(
            [*cli, "diagnose", str(hidden), "--json"], rounds, cwd=tmp)
        out["identify_exact_200_rows_s"] = _wall(
            [*cli, "identify", str(campaign), "--formulation", "exact", "--json"], rounds,
            cwd=tmp)
        out["report_s"] = _wall([*cli, "report", "--out", str(Path(tmp) / "report")], rounds)
    return out


def _pose_campaign(poses: int):
    """A simulated pose campaign: two markers (one per hand) on the shipped two-arm torso (16
    coordinates), hidden tracker placement, marker offsets, zero offsets, link-length errors
    and joint compliance, 30 um noise."""
    from stiffness.calibration.pose_model import Marker
    from stiffness.mechanics.defaults import default_stiffness
    from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign

    robot = load_robot("two-arm-torso")
    markers = [Marker("right", "right_tcp", np.zeros(3)),
               Marker("left", "left_tcp", np.array([0.0, 0.02, 0.0]))]
    rng = np.random.default_rng(0)
    n = robot.n_coordinates
    eps = np.zeros((n, 6))
    eps[:, :2] = rng.normal(0.0, 3e-4, (n, 2))
    hidden = HiddenPoseErrors(pin.exp3(rng.normal(size=3)), rng.uniform(-2, 2, 3),
                              np.array([m.offset for m in markers]) + 2e-3,
                              rng.normal(0.0, 1e-3, n), eps,
                              np.asarray(default_stiffness(robot), dtype=float))
    return simulate_pose_campaign(robot, markers, hidden, poses, 30e-6, seed=1)


def _fk_jacobian_pass(campaign) -> None:
    """One forward-kinematics + frame-Jacobian pass over a pose campaign's rows and markers
    (``pin.computeJointJacobians``, ``pin.updateFramePlacements`` and one
    ``pin.getFrameJacobian`` per marker): the floor of any evaluation of the pose model."""
    robot = campaign.robot
    model, data = robot.model, robot.model.createData()
    fids = [model.getFrameId(m.frame) for m in campaign.markers]
    jacobians, updates, frame_jacobian = (pin.computeJointJacobians, pin.updateFramePlacements,
                                          pin.getFrameJacobian)
    for q in campaign.q:
        q_full = robot.configuration(q)
        jacobians(model, data, q_full)
        updates(model, data)
        for fid in fids:
            frame_jacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)


def _fit_and_fk(campaign, families: tuple[str, ...], rounds: int) -> tuple[float, float]:
    """Wall times (s) of one full pose fit of ``families`` from zero and of
    :func:`_fk_jacobian_pass` over the same rows, each the best of ``rounds``, interleaved."""
    from stiffness.calibration.pose_fit import (
        campaign_settings,
        fit_pose_model,
        rows_of,
        starting_frame,
    )
    from stiffness.calibration.pose_model import PoseModel

    frame0, settings = starting_frame(campaign), campaign_settings(campaign)
    fk, fit = math.inf, math.inf
    for _ in range(rounds):
        start = time.perf_counter()
        _fk_jacobian_pass(campaign)
        fk = min(fk, time.perf_counter() - start)
        start = time.perf_counter()
        model = PoseModel(campaign.robot, campaign.markers, families, frame0, campaign.loads,
                          settings)
        fit_pose_model(model, campaign, rows_of(model, campaign), list(families))
        fit = min(fit, time.perf_counter() - start)
    return fit, fk


def pose_calibration_costs(poses: int, rounds: int = 2) -> dict[str, float]:
    """Issue 29's and 37's pose-calibration figures on :func:`_pose_campaign`, in one run:

    * ``pose_diagnose_{poses}_poses_s``: wall time (s) of diagnose, the full pose library
      (issue 29: under 90 s for 1000 poses on 2 cores);
    * ``pose_fit_{poses}_poses_s``: one full fit (the families the diagnosis names: frame,
      markers, joint_offsets, geometry, joint_compliance) from zero, best of ``rounds``;
    * ``pose_fk_{poses}_poses_s``: :func:`_fk_jacobian_pass` over the same rows, best of
      ``rounds`` interleaved with the fits;
    * ``pose_fit_{poses}_poses_over_fk`` (issue 37 target <= 100) and
      ``pose_diagnose_{poses}_poses_over_fit`` (target <= 15).
    """
    from stiffness.calibration.pose_diagnose import diagnose_poses

    campaign = _pose_campaign(poses)
    fit, fk = _fit_and_fk(campaign, ("frame", "markers", "joint_offsets", "geometry",
                                     "joint_compliance"), rounds)
    start = time.perf_counter()
    diagnose_poses(campaign)
    diagnose = time.perf_counter() - start
    return {f"pose_diagnose_{poses}_poses_s": diagnose, f"pose_fit_{poses}_poses_s": fit,
            f"pose_fk_{poses}_poses_s": fk, f"pose_fit_{poses}_poses_over_fk": fit / fk,
            f"pose_diagnose_{poses}_poses_over_fit": diagnose / fit}


def _panda_lumped_campaign():
    """The masses-unknown case of tests/test_absolute_poses.py: 22 poses of seed 2 of a marker
    on the Panda's hand, the tracker shifted 1 m, 1 mrad zero offsets, 2e4 N.m/rad joints,
    20 um noise."""
    from stiffness.calibration.pose_model import Marker
    from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign

    panda = load_robot("panda", frame="panda_hand", compliant_joints=PANDA_ARM)
    joints = sum(panda.model.joints[j].nv == 1 for j in range(1, panda.model.njoints))
    hidden = HiddenPoseErrors(np.eye(3), np.array([1.0, 0.0, 0.0]), np.array([[0, 0, 0.101]]),
                              np.full(joints, 1e-3), np.zeros((joints, 6)), np.full(7, 2e4))
    return simulate_pose_campaign(panda, [Marker("hand", "panda_hand", np.array([0, 0, 0.1]))],
                                  hidden, 22, 20e-6, seed=2)


def lumped_gravity_costs(rounds: int = 2) -> dict[str, float]:
    """The masses-unknown pose fit (``gravity_lumped``: its sag reads the gravity regressor at
    each fixed-point iteration) on :func:`_panda_lumped_campaign`: one full fit of frame,
    markers, joint_offsets and gravity_lumped from zero (``pose_lumped_fit_22_poses_s``), best
    of ``rounds`` interleaved with :func:`_fk_jacobian_pass` over the same rows
    (``pose_lumped_fk_22_poses_s``), and ``pose_lumped_fit_22_poses_over_fk``."""
    fit, fk = _fit_and_fk(_panda_lumped_campaign(),
                          ("frame", "markers", "joint_offsets", "gravity_lumped"), rounds)
    return {"pose_lumped_fit_22_poses_s": fit, "pose_lumped_fk_22_poses_s": fk,
            "pose_lumped_fit_22_poses_over_fk": fit / fk}


def design_sampling_costs(poses: int = 2, rounds: int = 2) -> dict[str, float]:
    """Experiment design's pose draws on a closed-loop robot whose sampling box is mostly out
    of its loops' reach (Griffis-Duffy): :func:`~stiffness.calibration.poses.
    sample_coordinates` of ``poses`` poses, seed 1 (``griffis_duffy_sampling_{poses}_poses_s``),
    best of ``rounds`` interleaved with the closure of the poses it keeps from the reference
    (:meth:`Robot.assemble`, ``griffis_duffy_assembly_{poses}_poses_s``), and
    ``griffis_duffy_sampling_over_assembly``: the cost of the draws refused per pose kept."""
    from stiffness.calibration.poses import sample_coordinates

    robot = load_robot("griffis-duffy")
    sample, closure = math.inf, math.inf
    for _ in range(rounds):
        start = time.perf_counter()
        coords = sample_coordinates(robot, poses, np.random.default_rng(1))
        sample = min(sample, time.perf_counter() - start)
        start = time.perf_counter()
        for c in coords:
            robot.assemble(c)
        closure = min(closure, time.perf_counter() - start)
    return {f"griffis_duffy_sampling_{poses}_poses_s": sample,
            f"griffis_duffy_assembly_{poses}_poses_s": closure,
            "griffis_duffy_sampling_over_assembly": sample / closure}


# ------------------------------------------------------------------------------ report


def _print_table(costs: dict, t4: float, t4_cli: float | None) -> None:
    print("Per-configuration cost (us, best of interleaved rounds; one force, enhanced "
          "translational K_X)")
    header = (f"{'robot':<7}{'batched K_X':>13}{'bare pin call':>15}{'finite diff.':>14}"
              f"{'batched/bare':>14}{'FD/batched':>12}")
    print(header)
    for name, r in costs.items():
        print(f"{name:<7}{r['batched_kx_us']:>13.2f}{r['bare_pinocchio_us']:>15.2f}"
              f"{r['finite_difference_us']:>14.1f}{r['ratio_to_bare']:>13.2f}x"
              f"{r['speedup_over_fd']:>11.1f}x")
    for name, r in costs.items():
        if "batched_kx_hessian_us" in r:
            print(f"  {name}: kinematic-Hessian route (any number of loads) "
                  f"{r['batched_kx_hessian_us']:.2f} us "
                  f"({r['batched_kx_hessian_us'] / r['bare_pinocchio_us']:.2f}x bare)")
        if "batched_kx_with_closure_us" in r:
            print(f"  {name}: with the loop closure of random configurations "
                  f"{r['batched_kx_with_closure_us']:.1f} us")
    print(f"Table IV scan (5824 x 8, one process, no figures): {t4:.3f} s")
    if t4_cli is not None:
        print(f"`stiffness scan --robot sk120 --preset table4` (new process, imports, figures): "
              f"{t4_cli:.2f} s")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON line")
    parser.add_argument("--quick", action="store_true", help="small sizes (smoke run)")
    parser.add_argument("--no-scaling", action="store_true", help="skip the scaling runs")
    parser.add_argument("--compensator", action="store_true",
                        help="only the compensator's figures (one JSON line)")
    parser.add_argument("--pose", type=int, metavar="POSES",
                        help="only the pose-calibration figures on POSES poses (one JSON line)")
    parser.add_argument("--lumped", action="store_true",
                        help="only the masses-unknown pose fit's figures (one JSON line)")
    parser.add_argument("--design-sampling", action="store_true",
                        help="only the Griffis-Duffy pose draws' figures (one JSON line)")
    parser.add_argument("--plot", metavar="PNG",
                        help="only draw scan time against configurations (1e3 ... 1e7, in "
                             "process and two workers) into PNG")
    parser.add_argument("--plot-max", type=float, default=1e7,
                        help="largest scan of --plot (default 1e7)")
    args = parser.parse_args(argv)
    if args.plot:
        sizes = [int(10 ** k) for k in range(3, 8) if 10 ** k <= args.plot_max]
        draw_scan_time(scan_time_rows(sizes), Path(args.plot))
        return 0
    load_before = os.getloadavg()
    alone = {"lumped": lumped_gravity_costs, "design_sampling": design_sampling_costs}
    for flag, costs_of in alone.items():
        if getattr(args, flag):
            figures = costs_of()
            figures["load_average"] = {"before": list(load_before), "after": list(os.getloadavg())}
            print(json.dumps(figures))
            return 0
    if args.pose:
        pose = pose_calibration_costs(args.pose)
        pose["load_average"] = {"before": list(load_before), "after": list(os.getloadavg())}
        print(json.dumps(pose))
        return 0
    compensator = compensator_costs(5 if args.quick else 15)
    if args.compensator:
        compensator["load_average"] = {"before": list(load_before),
                                       "after": list(os.getloadavg())}
        print(json.dumps(compensator))
        return 0
    costs = per_configuration(args.quick)
    t4 = table4_seconds(2 if args.quick else 3)
    samples = 50000 if args.quick else 400000
    scan = scan_over_kernel(samples, 2 if args.quick else 3)
    dask = dask_scaling(200000 if args.quick else 2000000, 1 if args.quick else 2)
    commands = commands_seconds(1 if args.quick else 2)
    poses = 200 if args.quick else 1000
    commands.update(pose_calibration_costs(poses))
    if args.json:
        out = {name: {k: float(v) for k, v in r.items()} for name, r in costs.items()}
        out["table4_scan_s"] = t4
        out.update(scan)
        out.update({k: v for k, v in dask.items() if k.startswith("dask_")})
        out["dask"] = dask
        out.update(commands)
        out.update(compensator)
        out["load_average"] = {"before": list(load_before), "after": list(os.getloadavg())}
        out["python_yardstick_s"] = python_yardstick_s()
        print(json.dumps(out))
        return 0
    t4_cli = table4_cli_seconds()
    _print_table(costs, t4, t4_cli)
    print(f"\nScan ({samples} UR5 samples, in process) over the kernel: default fields "
          f"{scan['scan_end_to_end_over_kernel']:.2f}x, --fields k_x "
          f"{scan['scan_fields_k_x_over_kernel']:.2f}x, float32 "
          f"{scan['scan_float32_over_kernel']:.2f}x; bytes per configuration "
          f"{scan['bytes_per_configuration']:.0f} (float32 "
          f"{scan['bytes_per_configuration_float32']:.0f}, k_x only "
          f"{scan['bytes_per_configuration_fields_k_x']:.0f})")
    print(f"Dask ({dask['configurations']} configurations): in process "
          f"{dask['in_process_s']:.2f} s, one worker {dask['one_worker_s']:.2f} s "
          f"({dask['dask_one_worker_over_in_process']:.2f}x), two workers "
          f"{dask['two_workers_s']:.2f} s (speed-up {dask['dask_two_workers_speedup']:.2f}x); "
          f"cluster start-up {dask['cluster_startup_s']:.1f} s; task overhead "
          f"{dask['task_overhead_s']}, chunk {dask['chunk_seconds']} s, "
          f"{dask['chunks_per_task']} chunks per task")
    print("Commands: " + ", ".join(f"{k} {v:.2f}" for k, v in commands.items()))
    print("Compensator: " + ", ".join(f"{k} {v:.2f}" for k, v in compensator.items()))
    print(f"load average before/after: {load_before} / {os.getloadavg()}")
    if args.no_scaling:
        return 0
    sizes = [1000, 10000, 100000] if args.quick else [1000, 10000, 100000, 1000000]
    print("\nScaling: batched K_X (UR5, one force), time per configuration")
    print(f"{'configurations':>15}{'seconds':>10}{'us/config':>11}")
    for row in scaling_configurations(sizes):
        print(f"{row['configurations']:>15}{row['seconds']:>10.3f}"
              f"{row['us_per_configuration']:>11.2f}")
    scan_sizes = [10000, 100000] if args.quick else [10000, 100000, 1000000]
    worker_size = 100000 if args.quick else 1000000
    print("\nScaling: `stiffness scan` (UR5 samples, one force, chunks of 8192, NPZ written)")
    print(f"{'configurations':>15}{'workers':>8}{'seconds':>10}{'us/config':>11}"
          f"{'driver MB':>11}{'workers MB':>12}{'cluster start s':>17}")
    rows = scaling_scans(scan_sizes, [1, 2], worker_size)
    for row in rows:
        print(f"{row['configurations']:>15}{row['workers']:>8}{row['seconds']:>10.2f}"
              f"{row['us_per_configuration']:>11.2f}{row['driver_peak_MB']:>11.0f}"
              f"{row['worker_peak_MB']:>12.0f}{row['startup_s']:>17.1f}")
    one = [r for r in rows if r["configurations"] == worker_size and r["workers"] == 1]
    two = [r for r in rows if r["configurations"] == worker_size and r["workers"] == 2]
    if one and two:
        print(f"speed-up with 2 workers at {worker_size} configurations: "
              f"{one[0]['seconds'] / two[0]['seconds']:.2f}x (cluster start-up excluded: "
              f"{two[0]['startup_s']:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
