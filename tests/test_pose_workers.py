"""Pose calibration's parallel and large-campaign plumbing (issue 37 items 4 and 6): the pose
fit runs its linear algebra on a single BLAS thread, the caller's setting restored; a step's
candidate fits (each with its held-out RMS) run on Dask workers with the same diagnosis as in
this process; the held-out criterion reports its progress."""

from __future__ import annotations

import json
import pickle
import subprocess
import sys

import pytest
from pose_campaigns import ur10_tip_campaign
from threadpoolctl import threadpool_info

from stiffness.calibration import pose_diagnose
from stiffness.calibration.pose_diagnose import diagnose_poses
from stiffness.cores import one_blas_thread
from stiffness.workspace.distributed import run_chunks


def test_one_blas_thread_restores_the_callers_setting():
    def threads() -> list[int]:
        return [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]

    before = threads()
    assert one_blas_thread(threads)() == [1] * len(before)
    assert threads() == before


def test_candidates_on_dask_workers_give_the_same_diagnosis(monkeypatch):
    """24 UR10 poses with hidden zero offsets, geometry and joint springs: with ``workers=2``
    the candidates of each step travel (pickled) to Dask workers, fitted there with their
    held-out RMS, and the diagnosis (steps, BIC changes, held-out RMS, parameters) equals the
    in-process one; the held-out criterion draws its progress to the end in process."""
    distributed = pytest.importorskip("distributed")
    campaign = ur10_tip_campaign(24, payload_n=300.0)
    bars: dict[str, tuple[int, int]] = {}

    def bar(label: str):
        return lambda done, total: bars.__setitem__(label, (done, total))

    local = diagnose_poses(campaign, bar=bar).to_dict()
    assert bars and all(done == total == 24 for done, total in bars.values())
    tasks: list[int] = []

    def on_cluster(func, args, indices, on_result, workers=None):
        pickle.loads(pickle.dumps(args))  # what travels to a worker process
        with distributed.LocalCluster(n_workers=workers, threads_per_worker=1,
                                      processes=False, dashboard_address=None) as cluster, \
                distributed.Client(cluster) as client:
            indices = list(indices)
            tasks.append(len(indices))
            return run_chunks(func, args, indices,
                              lambda i, r: on_result(i, pickle.loads(pickle.dumps(r))),
                              client=client)

    monkeypatch.setattr(pose_diagnose, "run_chunks", on_cluster)
    remote = diagnose_poses(campaign, workers=2).to_dict()
    assert tasks and all(n >= 2 for n in tasks)
    assert json.dumps(remote) == json.dumps(local)  # NaN-safe: the same text


RUN_TWICE = """
import sys
from stiffness.workspace import distributed as d

def local(scheduler, workers):  # as d._dask_client: distributed imported inside the context
    from distributed import Client, LocalCluster
    cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                           dashboard_address=None)
    return Client(cluster), cluster

d._dask_client = local
assert "distributed" not in sys.modules
for _ in range(2):
    out = {}
    d.run_chunks(abs, (), [-1, -2], out.__setitem__, workers=2)
    assert out == {-1: 1, -2: 2}, out
import dask
print(dask.config.get("distributed.comm.require-encryption"))
"""


def test_a_second_run_on_workers_keeps_dasks_settings():
    """A diagnosis runs on workers once per step: the first run in a process must not lose
    Dask distributed's settings (``dask.config.set`` entered before distributed was imported
    removed them on exit, and the second step's cluster raised ``KeyError: 'comm'``)."""
    pytest.importorskip("distributed")
    done = subprocess.run([sys.executable, "-c", RUN_TWICE], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
