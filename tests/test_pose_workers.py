"""Pose calibration with one BLAS thread (issue 37 item 4): the pose fit runs its linear
algebra on a single BLAS thread, the caller's setting restored. (Its held-out criterion refits
nothing per configuration, so no folds go to workers: tests/test_pose_selection.py.)"""

from __future__ import annotations

from threadpoolctl import threadpool_info

from stiffness.cores import one_blas_thread


def test_one_blas_thread_restores_the_callers_setting():
    def threads() -> list[int]:
        return [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]

    before = threads()
    assert one_blas_thread(threads)() == [1] * len(before)
    assert threads() == before
