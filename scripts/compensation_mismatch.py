"""The compensator built from an identified model, with MuJoCo simulating the truth (issue 39.3).

Usage::

    python scripts/compensation_mismatch.py            # one JSON line
    python scripts/compensation_mismatch.py --poses 4  # fewer poses (a smoke run)

Two cases on the UR5 with a 0.1 m tool, springs 3e4, 2e4, 1.5e4 N.m/rad on the arm joints
(the setting of tests/test_diagnose.py), a simulated campaign of 10 configurations x 4 loads
up to 100 N with 5 um noise (``stiffness simulate``), identified with ``stiffness identify``
(arm springs only):

* ``right``: nothing hidden; the truth is the arm springs.
* ``wrong``: a hidden wrist_1 spring of 1e4 N.m/rad (the model's hypothesis, a rigid wrist,
  is wrong); ``stiffness diagnose`` on the same campaign is run to see whether it flags it.

For each, at random poses of the campaign's workspace under a 100 N force in a random
direction, MuJoCo (:class:`stiffness.machining.tracking.MujocoArm`, the true springs, damped
to rest) gives the target's error commanded raw and at the identified model's compensator
command; the identified model's prediction interval for the compensated error is the 95th
percentile of that error over 200 stiffness vectors drawn from its standard errors (the exact
equilibrium of each draw at the command).
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings

import numpy as np

from stiffness.calibration.diagnose import diagnose
from stiffness.calibration.identify import identify
from stiffness.elastic.model import ElasticModel
from stiffness.errors import RobotFileWarning
from stiffness.machining.tracking import MujocoArm
from stiffness.mechanics.formulation import target_state
from stiffness.planning.simulate import parse_effect, simulate
from stiffness.robot.robot import load_robot

ARM = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"]
K_ARM = [3e4, 2e4, 1.5e4]  # N.m/rad
WRIST = 1e4  # N.m/rad, the wrong case's hidden wrist_1 spring
OFFSET = [0.0, 0.0, 0.1]  # m
FORCE = 100.0  # N


def _case(hidden: bool, poses: int, draws: int, seed: int) -> dict:
    effects = [parse_effect(f"joint_compliance:wrist_1_joint={WRIST}")] if hidden else []
    sim = simulate("ur5", kq=K_ARM, effects=effects, configs=10, loads_per_config=4,
                   noise_std_m=5e-6, seed=1, compliant_joints=ARM, target_offset_m=OFFSET,
                   max_force=FORCE)
    model = identify(sim.campaign).model_file()
    robot = load_robot("ur5", target_offset=OFFSET, compliant_joints=ARM)
    identified = ElasticModel.joint_springs(robot, model.k_theta)
    truth_joints = [*ARM, "wrist_1_joint"] if hidden else ARM
    truth = ElasticModel.joint_springs(
        load_robot("ur5", target_offset=OFFSET, compliant_joints=truth_joints),
        [*K_ARM, WRIST] if hidden else K_ARM)
    rng = np.random.default_rng(seed)
    compensator = identified.compensator()
    raw, comp, bound = [], [], []
    for _ in range(poses):
        q = np.array([rng.uniform(-1, 1), rng.uniform(-1.8, -0.6), rng.uniform(0.6, 2.0),
                      rng.uniform(-2, 0), rng.uniform(0.6, 2.4), rng.uniform(-1, 1)])
        direction = rng.normal(size=3)
        wrench = np.concatenate([FORCE * direction / np.linalg.norm(direction), np.zeros(3)])
        nominal = target_state(robot, robot.configuration(q)).position
        command = compensator.command(q, wrench)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RobotFileWarning)
            arm = MujocoArm(truth, q)
        arm.reset(q)
        raw.append(np.linalg.norm(arm.settle(wrench, velocity=1e-11) - nominal))
        arm.reset(command)
        comp.append(np.linalg.norm(arm.settle(wrench, velocity=1e-11) - nominal))
        drawn = model.k_theta + model.standard_error * rng.normal(size=(draws, 3))
        errors = [np.linalg.norm(ElasticModel.joint_springs(robot, k).at(command, wrench)
                                 .equilibrium().position - nominal) for k in drawn]
        bound.append(float(np.quantile(errors, 0.95)))
    raw_a, comp_a, bound_a = np.array(raw), np.array(comp), np.array(bound)
    out = {
        "identified_k_theta": model.k_theta.tolist(),
        "standard_error": model.standard_error.tolist(),
        "raw": {"max_error_m": float(raw_a.max()), "rms_error_m": float(np.sqrt(np.mean(
            raw_a ** 2)))},
        "compensated": {"max_error_m": float(comp_a.max()), "rms_error_m": float(np.sqrt(
            np.mean(comp_a ** 2)))},
        "prediction_95_max_m": float(bound_a.max()),
        "within_prediction": int(np.sum(comp_a <= bound_a)),
        "poses": poses,
        "worse_than_raw": int(np.sum(comp_a > raw_a)),
        "compensated_over_prediction_max": float(np.max(comp_a / bound_a)),
    }
    if hidden:
        summary = diagnose(sim.campaign, propose=False).summary()
        out["diagnose_missing_effects"] = summary["missing_effects"]
        out["diagnose_steps"] = [s.get("added") or s.get("effect") for s in summary["steps"]]
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=12)
    parser.add_argument("--draws", type=int, default=200)
    parser.add_argument("--seed", type=int, default=3)
    args = parser.parse_args(argv)
    print(json.dumps({"right": _case(False, args.poses, args.draws, args.seed),
                      "wrong": _case(True, args.poses, args.draws, args.seed)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
