"""How often ``stiffness validate`` calls a right model "above the noise": the measurement
behind docs/absolute-poses.md (Validation) and docs/model-file.md (``parameter_covariance``).

Usage::

    python scripts/validate_false_alarms.py               # 200 seeds, a text line
    python scripts/validate_false_alarms.py --seeds 400 --json
    python scripts/validate_false_alarms.py --formulation exact --max-force 50

Per seed ``s``: a small UR5 campaign (shoulder, elbow springs 3e4, 2e4, 1.5e4 N.m/rad; 2
configurations x 2 loads of 100 N, noise 5 um declared; ``stiffness.simulate`` seed ``2 s +
1``) identified with ``stiffness.identify`` (its model file in memory, with its
``parameter_covariance``), then validated on a fresh campaign of the same robot (4 x 3 rows,
seed ``2 s + 2``). Counted: the verdicts "above the noise" of the noise-only test (``gof_p``)
and of the test with the model's parameter uncertainty (``gof_p_with_parameters``, the
verdict), each at the 5 % level; and, with ``--wrong``, the same model with its
shoulder_lift stiffness 30 % too high (rejections). Prints the counts, the rates and the
two-sided binomial 99 % interval around 0.05. ``--formulation`` is identify's (default its
own: enhanced), ``--max-force`` the campaigns' largest force (N): the simulated truth is the
exact equilibrium, which the enhanced formulation misses by the second order of the load.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import warnings

import numpy as np
from scipy import stats

import stiffness
from stiffness.calibration.validation import validate

ARM = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"]
K = [3e4, 2e4, 1.5e4]  # N.m/rad
NOISE = 5e-6  # m


def campaign(seed: int, configs: int, loads: int, force: float):
    """A simulated UR5 deflection campaign of the three arm springs (largest force N)."""
    return stiffness.simulate("ur5", kq=K, compliant_joints=ARM, configs=configs,
                              loads_per_config=loads, max_force=force, noise_std_m=NOISE,
                              seed=seed).campaign


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=200)
    parser.add_argument("--wrong", action="store_true", help="also a spring 30 %% off")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--formulation", default=None, help="identify's (default enhanced)")
    parser.add_argument("--max-force", type=float, default=100.0, help="N (default 100)")
    args = parser.parse_args()
    old = new = wrong = 0
    for s in range(args.seeds):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = stiffness.identify(campaign(2 * s + 1, 2, 2, args.max_force),
                                       formulation=args.formulation).model_file()
            fresh = campaign(2 * s + 2, 4, 3, args.max_force)
            v = validate(model, fresh).to_dict()
            old += v["gof_p"] <= 0.05
            new += v["gof_p_with_parameters"] <= 0.05
            if args.wrong:
                k = model.k_theta.copy()
                k[1] *= 1.3
                w = validate(dataclasses.replace(model, k_theta=k), fresh).to_dict()
                wrong += w["gof_p_with_parameters"] <= 0.05
    low, high = stats.binom.interval(0.99, args.seeds, 0.05)
    out = {"seeds": args.seeds, "formulation": args.formulation or "enhanced",
           "max_force_n": args.max_force, "noise_only_above": int(old),
           "with_parameters_above": int(new),
           "noise_only_rate": old / args.seeds, "with_parameters_rate": new / args.seeds,
           "binomial_99_interval_counts": [int(low), int(high)],
           **({"wrong_spring_rejected": int(wrong)} if args.wrong else {})}
    print(json.dumps(out) if args.json else
          f"{args.seeds} seeds: noise-only test above the noise {old} ({old / args.seeds:.3f}),"
          f" with the parameters' uncertainty {new} ({new / args.seeds:.3f}); 99 % binomial "
          f"interval around 0.05: {int(low)}..{int(high)}"
          + (f"; a spring 30 % off rejected {wrong}" if args.wrong else ""))


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
