"""How many processes a command may run side by side on this machine."""

from __future__ import annotations

import multiprocessing
import os
import sys
import threading


def usable_cores() -> int:
    """CPUs this process may run on (its affinity where the platform tells it)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def fork_workers(requested: int | None, tasks: int) -> int:
    """Worker processes to fork for ``tasks`` independent tasks.

    ``requested`` (default :func:`usable_cores`) capped by ``tasks``; 1 (work in this process)
    off Linux (macOS's system libraries are not safe in a forked child, Windows cannot fork)
    or when this process runs other Python threads (a forked child of a threaded process may
    deadlock on a lock another thread held).
    """
    n = usable_cores() if requested is None else requested
    n = max(1, min(n, tasks))
    if n > 1 and (not sys.platform.startswith("linux")
                  or "fork" not in multiprocessing.get_all_start_methods()
                  or threading.active_count() > 1):
        return 1
    return n
