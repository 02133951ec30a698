"""How many rounds a robust loss's noise scale needs: the measurement behind
``stiffness.calibration.outliers.ROBUST_ROUNDS`` and docs/outliers.md (Robust losses).

Usage::

    python scripts/robust_rounds.py                       # 300 seeds, the table
    python scripts/robust_rounds.py --seeds 50 --workers 2
    python scripts/robust_rounds.py --json

Per seed ``s`` (``numpy.random.default_rng(s)``): a UR5 deflection campaign of the arm's three
springs (3e4, 2e4, 1.5e4 N.m/rad; the target 0.05, 0, 0.1 m in wrist_3's axes), 6 random
configurations x 3 random forces of 40-100 N, measured as the conventional deflection
``J K^-1 J^T f`` (the identified model is then the true one) plus 20 um of Gaussian noise, no
noise declared; and the same campaign with three of its 54 residual components moved by 30
noise stds (random components and signs). Each is identified (``stiffness.identify``, the
conventional formulation, one start) under ``huber`` and ``soft_l1`` with the loss's noise
scale from 1, 2 and 3 rounds (:func:`~stiffness.calibration.outliers.robust_rounds`, its
``ROBUST_ROUNDS`` and ``deflection_noise.SCALE_ROUNDS`` set for the run, so that exactly
that many rounds run, not the default's rounds until the scale settles): the first round's
scale is the robust estimate of a least-squares fit's residuals, which the gross components
inflate; each further round's that of the robust fit scaled by the last.

``--before-shrinkage``: the rule before 5 December 2026, a robust fit's residuals corrected by
least squares' ``sqrt(N / (N - p))`` alone (``outliers.residual_shrinkage`` taken as 1), for the
rounds after the first (the first round's residuals are least squares', never corrected
further).

Counted per loss and number of rounds, over ``3 x seeds`` stiffness intervals: how many cover
the truth, and ``sum z^2 / n``, ``z`` a stiffness's error on its compliance's scale (where its
interval is symmetric) over its standard error, ``(1 - k / k_true) / (SE(k) / k)`` (about
``(N - p) / (N - p - 2)`` = 1.04 when the intervals are right: Student's t over 51 degrees of
freedom).
"""

from __future__ import annotations

import argparse
import functools
import json
import warnings
from multiprocessing import Pool

import numpy as np

from stiffness.calibration import deflection_noise, outliers
from stiffness.calibration.campaign import Campaign
from stiffness.calibration.campaign_toml import RobotSettings
from stiffness.calibration.identify import identify
from stiffness.mechanics.formulation import deflection, target_state
from stiffness.robot.robot import load_robot

ARM = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint")
K = np.array([3e4, 2e4, 1.5e4])  # N.m/rad
OFFSET = np.array([0.05, 0.0, 0.1])  # m
NOISE = 2e-5  # m
CONFIGS, LOADS, GROSS, GROSS_STDS = 6, 3, 3, 30.0
LOSSES = ("huber", "soft_l1")
ROUNDS = (1, 2, 3)


def campaigns(seed: int) -> tuple[Campaign, Campaign]:
    """Seed ``seed``'s campaign without and with the gross components (module docstring)."""
    robot = load_robot("ur5", target_offset=OFFSET, compliant_joints=ARM)
    rng = np.random.default_rng(seed)
    q, force, truth = [], [], []
    for _ in range(CONFIGS):
        coords = rng.uniform(-np.pi, np.pi, 6)
        full = robot.configuration(coords)
        for _ in range(LOADS):
            f = rng.normal(size=3)
            f *= rng.uniform(40.0, 100.0) / np.linalg.norm(f)
            q.append(coords)
            force.append(f)
            truth.append(deflection(target_state(robot, full, f), np.diag(K), "conventional",
                                    rows=slice(0, 3)))
    clean = np.array(truth) + rng.normal(size=(len(q), 3)) * NOISE
    gross = clean.copy().reshape(-1)
    moved = rng.choice(gross.size, GROSS, replace=False)
    gross[moved] += rng.choice([-1.0, 1.0], GROSS) * GROSS_STDS * NOISE

    def campaign(measured: np.ndarray) -> Campaign:
        return Campaign("robust rounds", "conventional",
                        RobotSettings("ur5", target_offset_m=OFFSET, compliant_joints=ARM),
                        q=np.array(q), force=np.array(force), deflection=measured,
                        config=tuple(f"c{i // LOADS}" for i in range(len(q))), _robot=robot)

    return campaign(clean), campaign(gross.reshape(clean.shape))


def seed_results(seed: int, before_shrinkage: bool = False
                 ) -> dict[str, list[tuple[bool, float]]]:
    """Per ``gross/loss/rounds`` key, each stiffness interval of seed ``seed``: whether it
    covers the truth and its ``z`` (``before_shrinkage``: ``--before-shrinkage``)."""
    if before_shrinkage:
        outliers.residual_shrinkage = lambda loss, standardised, threshold: 1.0
    out: dict[str, list[tuple[bool, float]]] = {}
    for gross, campaign in enumerate(campaigns(seed)):
        for loss in LOSSES:
            for rounds in ROUNDS:
                outliers.ROBUST_ROUNDS = deflection_noise.SCALE_ROUNDS = rounds
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    joints = identify(campaign, loss=loss, starts=1).to_dict()["joints"]
                out[f"{gross}/{loss}/{rounds}"] = [
                    (j["ci95"][0] <= truth <= j["ci95"][1],
                     (1.0 - j["k"] / truth) / (j["standard_error"] / j["k"]))
                    for j, truth in zip(joints, K, strict=True)]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=300)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--before-shrinkage", action="store_true",
                        help="least squares' correction alone (the rule before 5 Dec 2026)")
    args = parser.parse_args()
    run = functools.partial(seed_results, before_shrinkage=args.before_shrinkage)
    if args.workers > 1:
        with Pool(args.workers) as pool:
            per_seed = pool.map(run, range(args.seeds))
    else:
        per_seed = [run(s) for s in range(args.seeds)]
    table = {}
    for key in per_seed[0]:
        covered, z = zip(*(r for result in per_seed for r in result[key]), strict=True)
        table[key] = {"intervals": len(z), "covered": int(sum(covered)),
                      "sum_z2_over_n": float(np.mean(np.square(z)))}
    if args.json:
        print(json.dumps({"seeds": args.seeds, "before_shrinkage": args.before_shrinkage,
                          "table": table}))
        return
    print(f"UR5, {CONFIGS} configurations x {LOADS} loads, 3 springs, {NOISE * 1e6:g} um "
          f"undeclared, {args.seeds} seeds: stiffness intervals covering the truth (sum z^2/n)"
          + (" (before the shrinkage correction)" if args.before_shrinkage else ""))
    print(f"{'loss':8} {'rounds':>6} {'clean':>16} {f'{GROSS} components {GROSS_STDS:g} std':>24}")
    for loss in LOSSES:
        for rounds in ROUNDS:
            cells = [table[f"{gross}/{loss}/{rounds}"] for gross in (0, 1)]
            text = [f"{c['covered']}/{c['intervals']} ({c['sum_z2_over_n']:.2f})" for c in cells]
            print(f"{loss:8} {rounds:>6} {text[0]:>16} {text[1]:>24}")


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
