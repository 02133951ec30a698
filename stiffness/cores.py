"""How many processes a command may run side by side on this machine, and running
independent tasks in forked workers."""

from __future__ import annotations

import multiprocessing
import os
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any, TypeVar

from threadpoolctl import threadpool_limits

_F = TypeVar("_F", bound=Callable[..., Any])


def usable_cores() -> int:
    """CPUs this process may run on (its affinity where the platform tells it)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def one_blas_thread(func: _F) -> _F:
    """``func`` run with a single-threaded BLAS (the caller's setting restored after).

    For work made of many modest dense products and factorisations (the pose fit's QR,
    least squares and Gram matrices of a few hundred columns): a BLAS thread pool gains
    little there, and on a loaded machine its idle threads spin against the work (a QR of
    1800 x 124 took 2-9 s with two threads at load 15 on 2 cores, 0.2 s with one).
    """
    return threadpool_limits.wrap(limits=1, user_api="blas")(func)


def fork_workers(requested: int | None, tasks: int) -> int:
    """Worker processes to fork for ``tasks`` independent tasks.

    ``requested`` (default :func:`usable_cores`) capped by ``tasks``; 1 (work in this process)
    off Linux (macOS's system libraries are not safe in a forked child, Windows cannot fork)
    or when this process runs other Python threads (a forked child of a threaded process may
    deadlock on a lock another thread held).
    """
    n = usable_cores() if requested is None else requested
    n = max(1, min(n, tasks))
    if n > 1 and (not sys.platform.startswith("linux") or threading.active_count() > 1):
        return 1
    return n


#: The tasks of the running :func:`forked_map`, inherited by its forked workers.
_TASKS: list[Callable[[], Any]] = []


def _exit_with(parent: int) -> None:
    """A forked worker's initializer: exit once the process ``parent`` is gone (a killed
    command must not leave its workers waiting for tasks)."""
    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.2)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def _run_task(index: int) -> Any:
    return _TASKS[index]()


def forked_map(tasks: list[Callable[[], Any]], workers: int | None = None) -> list[Any]:
    """Each task's result, in order: in forked worker processes (:func:`fork_workers`), or in
    this process where forking is unsafe, there is one task, or a worker died.

    The workers inherit the tasks (closures over any data: nothing is pickled but the results
    coming back) and exit with this process.
    """
    global _TASKS
    n = fork_workers(workers, len(tasks))
    if n < 2:
        return [task() for task in tasks]
    _TASKS = tasks
    try:
        with ProcessPoolExecutor(n, mp_context=multiprocessing.get_context("fork"),
                                 initializer=_exit_with, initargs=(os.getpid(),)) as pool:
            return list(pool.map(_run_task, range(len(tasks))))
    except BrokenProcessPool:  # a worker died (killed, out of memory): do the work here
        return [task() for task in tasks]
    finally:
        _TASKS = []
