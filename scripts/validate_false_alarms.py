"""How often ``stiffness validate`` calls a right model "above the noise": the measurement
behind docs/absolute-poses.md (Validation) and docs/model-file.md (``parameter_covariance``).

Usage::

    python scripts/validate_false_alarms.py               # 200 seeds, a text line
    python scripts/validate_false_alarms.py --seeds 400 --json
    python scripts/validate_false_alarms.py --formulation exact --max-force 50
    python scripts/validate_false_alarms.py --kind poses --seeds 400

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

``--kind poses``: a UR10 pose campaign (one marker on tool0, hidden measuring frame, marker
offset and zero offsets of up to 1 mrad, rigid; 12 poses, noise 20 um declared;
``stiffness.simulate_pose_campaign`` seed ``3 s + 1``) fitted with the families ``frame``,
``markers`` and ``joint_offsets`` (``fit_pose_model``, 13 parameters), its pose model file
written (with its ``parameter_covariance``) and validated on a fresh 12-pose campaign (seed
``3 s + 2``) by ``stiffness validate``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
import warnings
from pathlib import Path

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


def pose_verdicts(seed: int, folder: Path) -> tuple[bool, bool]:
    """Whether a right pose model from 12 poses is above the noise on 12 fresh ones: by the
    noise-only test and by the test with its parameters' uncertainty."""
    from stiffness.calibration.pose_fit import (
        campaign_settings,
        fit_pose_model,
        rows_of,
        starting_frame,
    )
    from stiffness.calibration.pose_model import PoseModel
    from stiffness.calibration.pose_model_file import write_pose_model

    robot = stiffness.load_robot("ur10", frame="tool0")
    markers = [stiffness.Marker("tip", "tool0", np.array([0.0, 0.03, 0.05]))]
    hidden = stiffness.HiddenPoseErrors(np.eye(3), np.array([1.5, -0.5, 0.2]),
                                        np.array([[0.0, 0.031, 0.05]]),
                                        np.linspace(-1e-3, 1e-3, 6), np.zeros((6, 6)), None)
    fit_on, judge_on = (stiffness.simulate_pose_campaign(robot, markers, hidden, 12, 2e-5,
                                                         seed=3 * seed + k) for k in (1, 2))
    families = ("frame", "markers", "joint_offsets")
    model = PoseModel(fit_on.robot, fit_on.markers, families, starting_frame(fit_on),
                      fit_on.loads, campaign_settings(fit_on))
    fit = fit_pose_model(model, fit_on, rows_of(model, fit_on), list(families))
    path = write_pose_model(fit, fit_on, folder / "final-model.json")
    v = validate(path, judge_on).to_dict()
    return v["gof_p"] <= 0.05, v["gof_p_with_parameters"] <= 0.05


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=200)
    parser.add_argument("--wrong", action="store_true", help="also a spring 30 %% off")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--formulation", default=None, help="identify's (default enhanced)")
    parser.add_argument("--max-force", type=float, default=100.0, help="N (default 100)")
    parser.add_argument("--kind", choices=("deflections", "poses"), default="deflections")
    args = parser.parse_args()
    old = new = wrong = 0
    for s in range(args.seeds):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if args.kind == "poses":
                with tempfile.TemporaryDirectory() as folder:
                    above = pose_verdicts(s, Path(folder))
                old, new = old + above[0], new + above[1]
                continue
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
    out = {"seeds": args.seeds, "kind": args.kind,
           "formulation": args.formulation or "enhanced",
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
