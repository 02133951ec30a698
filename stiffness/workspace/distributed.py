"""Chunked execution of workspace scans: in this process, or on a Dask distributed cluster.

A scan is split into numbered chunks; a chunk is a pure function of (spec, index), so any
worker can compute it, a chunk whose worker dies is simply recomputed (Dask reschedules it) and
only that task's work is lost. On a cluster, a task computes one or more consecutive chunks:
as many as make Dask's measured per-task overhead a small share of the task
(:func:`chunks_per_task`). Results stream back in completion order to a callback; at most
``2 x workers`` tasks are in flight, so the driver's memory is bounded by the chunk size, not
by the size of the scan.

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
import time
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from stiffness.errors import StiffnessError
from stiffness.robot.robot import Robot, load_robot

_ROBOTS: dict[str, list[Robot]] = {}
_IN_USE: dict[int, tuple[str, Robot]] = {}
_ROBOTS_LOCK = threading.Lock()


def worker_robot(robot_spec: dict) -> Robot:
    """The robot of a scan for this thread, loaded once per process (a Robot holds one
    Pinocchio Data, so two threads never share one).

    A process keeps a pool of loaded robots per spec: a thread keeps the one it got until it
    asks for another spec, and a new thread takes a free one, so a robot loaded ahead of the
    chunks (:func:`warm_worker`, run by ``client.run`` in the worker's event-loop thread) is
    the one its executor thread computes with.

    Parameters
    ----------
    robot_spec
        Keyword arguments of :func:`stiffness.robot.robot.load_robot` (``source``, ``frame``,
        ``target_offset``, ``compliant_joints``), JSON-serialisable.
    """
    key = json.dumps(robot_spec, sort_keys=True)
    thread = threading.get_ident()
    with _ROBOTS_LOCK:
        held = _IN_USE.get(thread)
        if held is not None and held[0] == key:
            return held[1]
        if held is not None:
            _ROBOTS.setdefault(held[0], []).append(held[1])  # give the other spec's back
            del _IN_USE[thread]
        free = _ROBOTS.get(key)
        robot = free.pop() if free else None
    if robot is None:
        robot = load_robot(**robot_spec)
    with _ROBOTS_LOCK:
        alive = {t.ident for t in threading.enumerate()}
        for other in [t for t in _IN_USE if t not in alive]:  # threads that ended
            spec_key, done = _IN_USE.pop(other)
            _ROBOTS.setdefault(spec_key, []).append(done)
        _IN_USE[thread] = (key, robot)
    return robot


def warm_worker(robot_spec: dict) -> None:
    """Load a scan's robot on a worker ahead of its chunks (``client.run(warm_worker, spec)``)
    into the process's pool, unless the process already holds one; returns nothing, so that
    no robot travels back to the client."""
    key = json.dumps(robot_spec, sort_keys=True)
    with _ROBOTS_LOCK:
        if _ROBOTS.get(key) or any(k == key for k, _ in _IN_USE.values()):
            return
    robot = load_robot(**robot_spec)
    with _ROBOTS_LOCK:
        _ROBOTS.setdefault(key, []).append(robot)


def _dask_client(scheduler: str | None, workers: int | None):
    """A Dask client on ``scheduler``, or on a new LocalCluster of ``workers`` processes.

    LocalCluster workers are single-threaded processes with single-threaded BLAS
    (:data:`WORKER_ENVIRONMENT`); an external cluster should be started the same way
    (``dask worker ADDRESS --nworkers N --nthreads 1``, see docs/performance.md).
    """
    from distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            return Client(scheduler, timeout="20s"), None
        except (OSError, TimeoutError) as exc:
            raise StiffnessError(
                f"cannot reach the Dask scheduler at {scheduler!r} ({exc}); start one with "
                "`dask scheduler` and give its address, e.g. tcp://10.0.0.5:8786"
            ) from exc
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                           dashboard_address=None, env=dict(WORKER_ENVIRONMENT))
    return Client(cluster), cluster


#: Environment of LocalCluster worker processes (set it for ``dask worker`` too): single-threaded
#: BLAS (a worker is one core; threaded BLAS on tiny matrices only adds contention); glibc's
#: malloc trim threshold above a chunk's work arrays (Dask's nanny sets 64 kB, which returns
#: them to the system after each chunk and pays page faults to get them back) *and* an mmap
#: threshold of 32 MB (its maximum): setting either disables glibc's dynamic mmap threshold,
#: so without the second every work array above 128 kB is a fresh mmap, zero-filled page by
#: page (measured here: a UR5 chunk of 8192 configurations took 66 ms with the trim threshold
#: alone, 50 ms with both, as without either); no statistical profiler (it samples the
#: computing thread's stack every 10 ms, under the GIL); and the worker's periodic
#: housekeeping (event-loop tick, system and memory monitors) at intervals of seconds rather
#: than tens of milliseconds.
WORKER_ENVIRONMENT = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
                      "MKL_NUM_THREADS": "1", "MALLOC_TRIM_THRESHOLD_": str(128 * 2**20),
                      "MALLOC_MMAP_THRESHOLD_": str(32 * 2**20),
                      "DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED": "False",
                      "DASK_DISTRIBUTED__ADMIN__TICK__INTERVAL": "1s",
                      "DASK_DISTRIBUTED__ADMIN__SYSTEM_MONITOR__INTERVAL": "10s",
                      "DASK_DISTRIBUTED__WORKER__MEMORY__MONITOR_INTERVAL": "1s"}
#: Dask configuration around a LocalCluster: the same housekeeping intervals for its scheduler
#: and nannies (they run in this process, beside the client), and :data:`WORKER_ENVIRONMENT`
#: as the nannies' pre-spawn environment, set before each worker process starts (glibc reads
#: the MALLOC_ variables at process start; the ``env`` of a LocalCluster is applied after it).
CLUSTER_CONFIG = {"distributed.admin.tick.interval": "1s",
                  "distributed.admin.system-monitor.interval": "10s",
                  "distributed.worker.memory.monitor-interval": "1s",  # the nannies' monitor
                  "distributed.nanny.pre-spawn-environ": WORKER_ENVIRONMENT}

#: Target share of a task's time spent on Dask's per-task overhead when choosing the number
#: of chunks per task.
OVERHEAD_SHARE = 0.02
#: Tasks per worker kept at least, for load balance and progress.
TASKS_PER_WORKER = 4


def run_group(func: Callable[..., Any], args: tuple, indices: tuple[int, ...],
              grouped: bool = False) -> tuple[dict[int, Any], float]:
    """``{index: func(*args, index)}`` for consecutive chunks (``grouped``: ``func(*args,
    indices)`` returns that dict itself), and the seconds it took (one Dask task)."""
    t0 = time.perf_counter()
    results = (func(*args, indices) if grouped
               else {index: func(*args, index) for index in indices})
    return results, time.perf_counter() - t0


def _noop() -> None:
    """A task that does nothing (measures Dask's per-task overhead)."""


def task_overhead(client: Any, rounds: int = 5) -> float:
    """Median round trip (s) of an empty task through the scheduler and a worker."""
    times = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        client.submit(_noop, pure=False).result()
        times.append(time.perf_counter() - t0)
    return float(sorted(times)[len(times) // 2])


def chunks_per_task(overhead_s: float, chunk_s: float, remaining: int, n_workers: int) -> int:
    """Chunks per task so that the per-task overhead is at most :data:`OVERHEAD_SHARE` of a
    task, with at least :data:`TASKS_PER_WORKER` tasks per worker left."""
    wanted = int(np.ceil(overhead_s / (OVERHEAD_SHARE * max(chunk_s, 1e-9))))
    balance = max(1, remaining // (TASKS_PER_WORKER * n_workers))
    return int(max(1, min(wanted, balance)))


def run_chunks(
    func: Callable[..., Any],
    args: tuple,
    indices: Iterable[int],
    on_result: Callable[[int, Any], None],
    scheduler: str | None = None,
    workers: int | None = None,
    client: Any | None = None,
    group: int | None = None,
    warm: tuple[Callable[[Any], None], Any] | None = None,
    stats: dict | None = None,
    grouped: bool = False,
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
    group
        Consecutive chunks per Dask task. Default: the first tasks hold one chunk each; their
        measured compute time and the measured per-task overhead (:func:`task_overhead`) then
        set it for each task submitted (:func:`chunks_per_task`, which keeps
        :data:`TASKS_PER_WORKER` tasks per worker in the work left: tasks shrink towards the
        end, so that the workers finish together).
    warm
        ``(function, argument)`` run once on every worker (or in this process) before the
        chunks, e.g. loading the robot; returns nothing.
    stats
        Filled, on a cluster, with ``workers``, ``chunks_per_task`` (the largest task),
        ``task_overhead_s`` and ``chunk_seconds`` (median compute time of a chunk on a
        worker).
    grouped
        ``func(*args, indices)`` computes a task's consecutive chunks at once and returns
        ``{index: result}`` (e.g. to write one chunk while computing the next).

    Returns
    -------
    int
        Number of chunks computed.
    """
    indices = list(indices)
    if client is None and scheduler is None and (workers is None or workers <= 1):
        if warm is not None:
            warm[0](warm[1])
        for index in indices:
            result = func(*args, (index,))[index] if grouped else func(*args, index)
            on_result(index, result)
        return len(indices)
    try:  # before dask.config.set: importing distributed later drops its defaults
        import distributed  # noqa: F401  (e.g. distributed.comm: KeyError 'comm')
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise StiffnessError(
            "--scheduler and --workers need Dask distributed: pip install \"dask[distributed]\""
        ) from exc
    import dask

    with dask.config.set(CLUSTER_CONFIG):
        own_cluster = None
        if client is None:
            client, own_cluster = _dask_client(scheduler, workers)
            own_client = True
        else:
            own_client = False
        try:
            return _run_on_client(client, func, args, indices, on_result, workers, group,
                                  warm, {} if stats is None else stats, grouped)
        finally:
            if own_client:
                client.close()
            if own_cluster is not None:
                own_cluster.close()


def _run_on_client(client: Any, func: Callable[..., Any], args: tuple, indices: list[int],
                   on_result: Callable[[int, Any], None], workers: int | None,
                   group: int | None, warm: tuple | None, stats: dict, grouped: bool
                   ) -> int:
    """:func:`run_chunks` on a Dask client: a window of ``2 x workers`` tasks in flight."""
    from distributed import as_completed

    if warm is not None:
        client.run(warm[0], warm[1])
    n_workers = max(1, len(client.nthreads()) or (workers or 1))
    overhead = task_overhead(client) if group is None else None
    size: dict = {"group": group or 1, "largest": group or 1}
    chunk_times: list[float] = []
    pending = list(reversed(indices))
    futures: dict[str, tuple[int, ...]] = {}
    stream = as_completed([])

    def submit_next() -> bool:
        if not pending:
            return False
        if overhead is not None and "chunk_s" in size:  # guided: tasks shrink as the work does
            size["group"] = chunks_per_task(overhead, size["chunk_s"], len(pending), n_workers)
            size["largest"] = max(size["largest"], size["group"])
        count = min(size["group"], len(pending))
        chunk = tuple(pending.pop() for _ in range(count))
        future = client.submit(run_group, func, args, chunk, grouped, pure=False, retries=2)
        futures[future.key] = chunk
        stream.add(future)
        return True

    for _ in range(2 * n_workers):
        if not submit_next():
            break
    done = 0
    for future in stream:
        futures.pop(future.key)
        results, seconds = future.result()
        future.release()
        for index, result in results.items():
            on_result(index, result)
        done += len(results)
        chunk_times.append(seconds / max(1, len(results)))
        if group is None and len(chunk_times) == min(n_workers, len(indices)):  # first wave
            size["chunk_s"] = float(np.median(chunk_times))  # a chunk's compute time
        submit_next()
    stats.update({"workers": n_workers, "chunks_per_task": size["largest"],
                  "task_overhead_s": overhead,
                  "chunk_seconds": float(np.median(chunk_times)) if chunk_times else None})
    return done
