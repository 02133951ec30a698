"""Chunked execution of workspace scans: in this process, or on a Dask distributed cluster.

A scan is split into numbered chunks; a chunk is a pure function of (spec, index), so any
worker can compute it, a chunk whose worker dies is simply recomputed (Dask reschedules it) and
only that chunk's work is lost. Results stream back in completion order to a callback that
writes them to disk; at most ``2 x workers`` chunks are in flight, so the driver's memory is
bounded by the chunk size, not by the size of the scan.

The single-process path (the default) runs the very same chunk function in a loop, so a
distributed scan and a local one write the same maps.

Dask is optional: it is imported only when a scheduler address or a worker count above one is
given (``pip install "dask[distributed]"``). A LocalCluster spawns its worker processes, so a
script that starts one must guard its entry point with ``if __name__ == "__main__":`` (the
``stiffness`` command does).
"""

from __future__ import annotations

import json
import threading
from collections.abc import Callable, Iterable
from typing import Any

from stiffness.errors import StiffnessError
from stiffness.model.robot import Robot, load_robot

_ROBOTS: dict[tuple[int, str], Robot] = {}
_ROBOTS_LOCK = threading.Lock()


def worker_robot(robot_spec: dict) -> Robot:
    """The robot of a scan, loaded once per process and thread (a Robot is not thread-safe).

    Parameters
    ----------
    robot_spec
        Keyword arguments of :func:`stiffness.model.robot.load_robot` (``source``, ``frame``,
        ``target_offset``, ``compliant_joints``), JSON-serialisable.
    """
    key = (threading.get_ident(), json.dumps(robot_spec, sort_keys=True))
    with _ROBOTS_LOCK:
        robot = _ROBOTS.get(key)
    if robot is None:
        robot = load_robot(**robot_spec)
        with _ROBOTS_LOCK:
            _ROBOTS[key] = robot
    return robot


def warm_worker(robot_spec: dict) -> None:
    """Load a scan's robot on a worker ahead of its chunks (``client.run(warm_worker, spec)``);
    returns nothing, so that no robot travels back to the client."""
    worker_robot(robot_spec)


def _dask_client(scheduler: str | None, workers: int | None):
    """A Dask client on ``scheduler``, or on a new LocalCluster of ``workers`` processes."""
    try:
        from distributed import Client, LocalCluster
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise StiffnessError(
            "--scheduler and --workers need Dask distributed: pip install \"dask[distributed]\""
        ) from exc
    if scheduler is not None:
        try:
            return Client(scheduler, timeout="20s"), None
        except (OSError, TimeoutError) as exc:
            raise StiffnessError(
                f"cannot reach the Dask scheduler at {scheduler!r} ({exc}); start one with "
                "`dask scheduler` and give its address, e.g. tcp://10.0.0.5:8786"
            ) from exc
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                           dashboard_address=None)
    return Client(cluster), cluster


def run_chunks(
    func: Callable[..., Any],
    args: tuple,
    indices: Iterable[int],
    on_result: Callable[[int, Any], None],
    scheduler: str | None = None,
    workers: int | None = None,
    client: Any | None = None,
) -> int:
    """Compute ``func(*args, index)`` for every index and hand each result to ``on_result``.

    Parameters
    ----------
    func
        A module-level (picklable) pure function of ``(*args, index)``.
    args
        Its leading arguments (small and picklable: they travel with every task).
    indices
        Chunk indices to compute.
    on_result
        Called in this process as ``on_result(index, result)`` as results arrive (completion
        order with Dask, index order otherwise).
    scheduler
        Address of a running Dask scheduler (``tcp://host:8786``); the scan then runs on its
        workers.
    workers
        Without a scheduler: above 1, a Dask LocalCluster with that many single-threaded worker
        processes on this machine; None or 1, this process (no Dask).
    client
        An existing ``distributed.Client`` (overrides ``scheduler`` and ``workers``).

    Returns
    -------
    int
        Number of chunks computed.
    """
    indices = list(indices)
    if client is None and scheduler is None and (workers is None or workers <= 1):
        for index in indices:
            on_result(index, func(*args, index))
        return len(indices)
    own_cluster = None
    if client is None:
        client, own_cluster = _dask_client(scheduler, workers)
        own_client = True
    else:
        own_client = False
    try:
        from distributed import as_completed

        n_workers = max(1, len(client.scheduler_info().get("workers", {})) or (workers or 1))
        window = 2 * n_workers
        pending = iter(indices)
        futures = {}

        def submit_next() -> bool:
            index = next(pending, None)
            if index is None:
                return False
            future = client.submit(func, *args, index, pure=False, retries=2)
            futures[future.key] = index
            stream.add(future)
            return True

        stream = as_completed([])
        for _ in range(window):
            if not submit_next():
                break
        done = 0
        for future in stream:
            index = futures.pop(future.key)
            result = future.result()
            future.release()
            on_result(index, result)
            done += 1
            submit_next()
        return done
    finally:
        if own_client:
            client.close()
        if own_cluster is not None:
            own_cluster.close()
