"""The reduction on the triangular factor (:func:`identifiability.reduce_columns` runs on
``R`` of ``a = Q R``, not on ``a``'s N rows) decides as the reduction on the full columns:
the same kept columns in the same order, the same dropped ones and reasons, merge
coefficients equal to 1e-10. The reference below is the reduction on the full matrix
(:func:`reduce_columns` with ``a`` itself in place of its factor), independent of
``triangular``. Exact aliases whose unexplained parts are equal (a tie of the pivoting) keep
the earlier member however the factor was computed (``PIVOT_TIE``), where round-off used to
decide."""

from __future__ import annotations

import numpy as np
import pytest

from stiffness.calibration import identifiability
from stiffness.calibration.identifiability import (
    IDENTIFIABILITY_TOL,
    NEAR_ALIAS_SINE,
    TRIANGULAR_BLOCK,
    reduce_columns,
    stacked_triangular,
    triangular,
)


def _full(a, groups, scales, floors, keep_first, monkeypatch):
    """The reduction on the full (N, p) columns: :func:`reduce_columns` with its triangular
    factor replaced by ``a`` itself (projections by a full ``Q`` of the kept columns)."""
    with monkeypatch.context() as patch:
        patch.setattr(identifiability, "triangular", lambda columns: columns)
        return reduce_columns(a, groups, scales, floors, keep_first=keep_first)


def _campaign(rng, rows):
    """Random columns in 3 groups with exact aliases (combinations, within and across
    groups), near aliases of the earlier groups at 0.5-2 x NEAR_ALIAS_SINE, a zero and a
    tiny column, random scales (no two aliases with equal unexplained parts: no pivoting
    tie)."""
    a = rng.normal(size=(rows, 14)) * rng.uniform(0.1, 10.0, 14)
    a[:, 4] = 2.0 * a[:, 0] - 3.0 * a[:, 1]                      # group 1 from group 0
    a[:, 5] = 0.0                                                 # no effect
    a[:, 6] = 0.5 * a[:, 3]                                       # alias within group 1
    for column, sine in ((7, 0.5), (8, 2.0), (11, 0.8)):          # near aliases of earlier
        along = a[:, :3] @ rng.normal(size=3)
        other = rng.normal(size=rows)
        other -= along * (along @ other) / (along @ along)
        a[:, column] = along + sine * NEAR_ALIAS_SINE * other * np.linalg.norm(along) \
            / np.linalg.norm(other)
    a[:, 12] = 1e-9 * a[:, 13]                                    # tiny beside its group
    a[:, 10] = 2.0 * a[:, 9] - a[:, 3] + a[:, 7]                  # alias across groups
    return a


@pytest.mark.parametrize("seed", range(6))
def test_triangular_reduction_decides_as_the_full_one(seed, monkeypatch):
    rng = np.random.default_rng(seed)
    rows = (300, 9, 40)[seed % 3]  # 9 rows: fewer than columns, R is (9, 14)
    a = _campaign(rng, rows)
    groups = [[0, 1, 2], [3, 4, 5, 6, 7, 8], [9, 10, 11, 12, 13]]
    scales = rng.uniform(1e-3, 1e2, 14)
    # resolutions around the near aliases' orthogonal parts: some merged, some told apart
    floors = [0.0] + list(rng.uniform(0.0, 2.0, 2)
                          * NEAR_ALIAS_SINE * np.linalg.norm(a[:, 7]))
    for keep_first in (False, True):
        for floor in (floors, None):
            got = reduce_columns(a, groups, scales, floor, keep_first=keep_first)
            full = _full(a, groups, scales, floor, keep_first, monkeypatch)
            assert got.kept == full.kept
            assert [(d.index, d.reason) for d in got.dropped] == [
                (d.index, d.reason) for d in full.dropped]
            for d, ref in zip(got.dropped, full.dropped, strict=True):
                coefs = dict(ref.merged_into)
                assert {i for i, _ in d.merged_into} == set(coefs)
                for i, c in d.merged_into:
                    assert c == pytest.approx(coefs[i], rel=1e-10, abs=1e-10)


def test_triangular_factor_over_blocks_keeps_the_inner_products():
    """``triangular`` over several row blocks: R upper triangular, R^T R = a^T a."""
    rng = np.random.default_rng(3)
    a = rng.normal(size=(2 * TRIANGULAR_BLOCK + 5, 6))
    tri = triangular(a, [4, 0, 2])
    assert tri.shape == (3, 3) and np.allclose(np.tril(tri, -1), 0.0)
    sub = a[:, [4, 0, 2]]
    np.testing.assert_allclose(tri.T @ tri, sub.T @ sub, rtol=1e-12)


def _tied(rng, rows):
    """12 columns: 8 independent ones, then exact aliases of columns 1, 3, 4 and 6 with the
    same norms, summed in another order (a chain's parallel axes: translations of
    consecutive joints along a shared axis are the same column computed twice)."""
    base = rng.normal(size=(rows, 8)) * rng.uniform(0.5, 2.0, 8)
    mix = rng.normal(size=(8, 8))
    again = np.column_stack([sum(base[:, k] * mix[k, c] for k in reversed(range(8)))
                             for c in (1, 3, 4, 6)])
    return np.column_stack([base @ mix, again])


@pytest.mark.parametrize("seed", range(4))
def test_pivoting_ties_keep_the_earlier_alias_however_the_factor_was_computed(seed,
                                                                               monkeypatch):
    """Round-off alone used to decide which member of each pair was kept, differently for
    the full columns, their factor over 8192-row blocks and over 64-row blocks (seeds 0-3:
    three different kept sets each); the tie rule keeps the first eight in all three."""
    a = _tied(np.random.default_rng(seed), 600)
    group, ones = [list(range(12))], np.ones(12)
    blocks = stacked_triangular((a[s:s + 64] for s in range(0, 600, 64)), 12)
    for kept in (_full(a, group, ones, None, False, monkeypatch).kept,
                 reduce_columns(a, group, ones).kept, reduce_columns(blocks, group, ones).kept):
        assert sorted(kept) == list(range(8))


def test_columns_past_the_rank_are_not_kept():
    """180 columns of rank 60 on 90 rows, scales 0.01 to 1: 60 kept, each at least
    IDENTIFIABILITY_TOL of its norm away from the span of the others (a pivoting that went on
    past the rank, normalising round-off, kept 73 here, and 91 of 186 columns of rank 62 on a
    30-pose Panda campaign)."""
    rng = np.random.default_rng(5)
    a = (rng.normal(size=(90, 60)) @ rng.normal(size=(60, 180))) * np.logspace(-2, 0, 180)
    kept = reduce_columns(a, [list(range(10)), list(range(10, 180))], np.ones(180)).kept
    assert len(kept) == 60
    for c in kept:
        others = a[:, [k for k in kept if k != c]]
        coef, *_ = np.linalg.lstsq(others, a[:, c], rcond=None)
        assert np.linalg.norm(a[:, c] - others @ coef) >= IDENTIFIABILITY_TOL * np.linalg.norm(
            a[:, c])
