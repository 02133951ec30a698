"""A folder written once per test run and shared by its test workers (pytest-xdist): the
first worker to need it writes it under a file lock, the others wait, then read it."""

from __future__ import annotations

import contextlib
import fcntl
from collections.abc import Iterator
from pathlib import Path

import pytest


@contextlib.contextmanager
def run_folder(tmp_path_factory: pytest.TempPathFactory, worker_id: str,
               name: str) -> Iterator[Path]:
    """The folder of this test run (above each worker's own), with the lock ``name.lock`` in
    it held while inside: write ``name``'s files there unless they exist."""
    root = tmp_path_factory.getbasetemp()
    if worker_id != "master":
        root = root.parent  # the folder of this run, above each worker's own
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        yield root
