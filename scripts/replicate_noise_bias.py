"""Whether the robust replicate noise is unbiased: the measurement behind docs/outliers.md
(Robust losses, the replicates' noise) and ``tests/test_outliers.py``.

Usage::

    python scripts/replicate_noise_bias.py                  # 200000 draws, the table
    python scripts/replicate_noise_bias.py --draws 20000 --seed 1

``selection.replicate_noise(..., robust=True)`` is ``1.4826 median |d|`` over every replicate
row's deviation from its group's mean, each times ``sqrt(m / (m - 1))`` for a group of ``m``
rows (``outliers.robust_noise`` with no parameter counted). Here the same computation on unit
Gaussian noise, vectorised over ``--draws`` draws (``numpy.random.default_rng(--seed)``): for
groups of ``m`` rows of three components, ``G`` groups, the mean of the estimate over the
truth with its standard error and the spread of one estimate; beside it the same statistic
of as many independent N(0, 1) values (the sample median's own finite-size bias, about
``+0.309 / (n + 2)`` for ``n`` values) and the pooled scatter ``sqrt(sum d^2 / dof)``.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from stiffness.calibration.outliers import MAD_TO_STD

#: (rows per group m, groups G): the SK120 campaigns of tests/test_outliers.py (6
#: configurations x 4 loads, measured 2 and 3 times), more rows per group, and the fewest
#: degrees of freedom replicate_noise accepts (9).
DESIGNS = ((2, 24), (3, 24), (4, 24), (2, 12), (3, 8), (2, 3), (3, 2))


def ratios(rng: np.random.Generator, m: int, groups: int, draws: int, chunk: int = 20000
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per draw: the robust replicate estimate, the same statistic of independent values,
    and the pooled scatter (each over the true std 1)."""
    robust, independent, pooled = [], [], []
    dof = groups * (m - 1) * 3
    for start in range(0, draws, chunk):
        k = min(chunk, draws - start)
        e = rng.normal(size=(k, groups, m, 3))
        d = e - e.mean(axis=2, keepdims=True)
        scaled = np.abs(d.reshape(k, -1)) * math.sqrt(m / (m - 1))
        robust.append(MAD_TO_STD * np.median(scaled, axis=1))
        z = np.abs(rng.normal(size=(k, groups * m * 3)))
        independent.append(MAD_TO_STD * np.median(z, axis=1))
        pooled.append(np.sqrt(np.sum(d.reshape(k, -1) ** 2, axis=1) / dof))
    return np.concatenate(robust), np.concatenate(independent), np.concatenate(pooled)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--draws", type=int, default=200_000)
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    print(f"{args.draws} draws: mean estimate / truth +- standard error (spread of one)")
    print(f"{'m':>2} {'G':>3} {'dof':>4} {'robust replicates':>28} {'independent values':>20} "
          f"{'pooled scatter':>16}")
    for m, groups in DESIGNS:
        r, i, p = ratios(rng, m, groups, args.draws)
        se = [x.std(ddof=1) / math.sqrt(x.size) for x in (r, i, p)]
        print(f"{m:>2} {groups:>3} {groups * (m - 1) * 3:>4} "
              f"{f'{r.mean():.5f} +- {se[0]:.5f} ({r.std(ddof=1):.3f})':>28} "
              f"{f'{i.mean():.5f} +- {se[1]:.5f}':>20} {f'{p.mean():.5f}':>16}")


if __name__ == "__main__":
    main()
