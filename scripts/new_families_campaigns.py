"""Issue 37's must-show runs for the two new pose families: simulated campaigns with each hidden.

For each robot (UR10, Panda, the two-arm torso, the torso with a passive joint of
tests/data/torso-passive with its springs on the chain) and each hidden family
(``transversal_compliance``: three joints of the markers' chains tilting in their bearings;
``base_tilt``: the base tilted by 2-3.4 degrees, on the robot softened 4x), over seeds 0..N-1:
a 30-pose campaign (20 um noise, a payload at the target) with the frame, markers and joint
offsets hidden as well, diagnosed as a user would with ``--families joint_offsets,
joint_compliance --not geometry,backlash,gravity_compensator`` (the hidden geometry is none).
It records whether the hidden family is named, the 95 % intervals of its parameters against
the truth (identifiable truth: merged parameters folded in), and the final held-out RMS
(leave one configuration out) over the noise.

Family ``nonlinear_joint_stiffness`` (not run by default; ``--families
nonlinear_joint_stiffness``): the two springs that carry the largest torques at the commanded
poses harden by 40 % at those torques (:func:`hardening`), diagnosed with the same flags.

Mode ``not-offered`` (``--not transversal_compliance`` as well, the tilts hidden): what the
diagnosis ends with instead (unexplained, or the stand-in families) and its held-out RMS over
the noise. Mode ``nothing`` (``--families nothing``): the same campaigns with neither family
hidden; ``named`` counts the seeds naming any family beyond the forced ones and the frame and
markers (issue 36: at most the 5 % a 95 % stop rule lets through).

Deflection campaigns (``--families deflection,deflection-not-offered``): the same robots,
the target's chain compliant (:data:`DEFLECTION`), a campaign of 15 configurations x 4 random
loads at the target (20 um noise, the exact equilibrium of the true robot:
:func:`stiffness.planning.simulate.simulate`) hiding the tilts of the 2nd to 4th compliant
tilting joints of the target's chain at 0.5-1x their joint's compliance, diagnosed as
``stiffness diagnose`` does (every library effect a candidate; ``--not
transversal_compliance`` in the second mode). It records whether a tilt is named first and
which hidden tilts are named at their joints, the 95 % intervals of the named ones against the
truth, what else is named, and the last step's held-out RMS (cross-validated over
configurations) over the noise.

Not part of the test suite (minutes); run as::

    PYTHONPATH=. python scripts/new_families_campaigns.py --seeds 10 --json out.json
    PYTHONPATH=. python scripts/new_families_campaigns.py --seeds 10 \
        --families deflection,deflection-not-offered

Units: SI inside; the report prints ratios and counts.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import pinocchio as pin

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # the suite's coverage helpers (stats, pose_truth)

from pose_truth import add_intervals  # noqa: E402
from stats import Coverage, binomial_consistent  # noqa: E402

from stiffness.calibration.diagnose import diagnose  # noqa: E402
from stiffness.calibration.pose_diagnose import diagnose_poses  # noqa: E402
from stiffness.calibration.pose_fit import campaign_settings  # noqa: E402
from stiffness.calibration.pose_model import Marker  # noqa: E402
from stiffness.calibration.pose_model_file import parameter_table  # noqa: E402
from stiffness.elastic.effects.geometry import Geometry  # noqa: E402
from stiffness.elastic.effects.link_bends import transversal_joints  # noqa: E402
from stiffness.elastic.effects.pose_face import NONLINEAR_SETTING  # noqa: E402
from stiffness.mechanics.defaults import default_stiffness  # noqa: E402
from stiffness.planning.simulate import HiddenEffect, simulate  # noqa: E402
from stiffness.planning.simulate_poses import (  # noqa: E402
    HiddenPoseErrors,
    simulate_pose_campaign,
)
from stiffness.robot.robot import load_robot  # noqa: E402

NOISE = 20e-6  # m
POSES = 30
FORCED = ["joint_offsets", "joint_compliance"]
NOT_HIDDEN = ["geometry", "backlash", "gravity_compensator"]
TORSO = ROOT / "tests" / "data" / "torso-passive" / "robot.toml"
#: Deflection campaigns: robot -> (target frame, compliant joints (the target's chain), their
#: stiffness N.m/rad, the largest load at the target N); the torso's robot file is the one of
#: :func:`robot_setup` (springs on its six chain joints).
DEFLECTION = {
    "ur10": ("tool0", None, [3e5, 2e5, 1.2e5, 4e4, 3e4, 3e4], 300.0),
    "panda": ("panda_hand", [f"panda_joint{i}" for i in range(1, 8)],
              [2e4, 2e4, 1.5e4, 1.5e4, 5e3, 5e3, 5e3], 50.0),
    "two-arm-torso": ("right_tcp", ["torso_yaw", "torso_pitch", "right_shoulder_pitch",
                                    "right_shoulder_roll", "right_shoulder_yaw", "right_elbow"],
                      [2e4, 3e4, 8e3, 8e3, 6e3, 5e3], 50.0),
    "torso-passive": ("tool", None, [4.0e4, 2.5e4, 2.0e4, 1.5e4, 8.0e3, 6.0e3], 100.0),
}
#: Deflection campaigns: configurations, loads per configuration.
CONFIGS, LOADS = 15, 4


def robot_setup(name: str, tmp: Path) -> tuple:
    """``name``'s (robot, markers, joint stiffness N.m/rad, payload wrench at the target N, N.m
    or ``None``); ``tmp`` a folder for the torso's robot file with its springs on the chain."""
    if name == "ur10":
        return (load_robot("ur10", frame="tool0"),
                [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05])),
                 Marker("elbow", "forearm_link", np.array([0.0, 0.05, 0.2]))],
                np.array([3e5, 2e5, 1.2e5, 4e4, 3e4, 3e4]),
                np.array([0.0, 0.0, -150.0, 0.0, 0.0, 0.0]))
    if name == "panda":
        arm = tuple(f"panda_joint{i}" for i in range(1, 8))
        return (load_robot("panda", frame="panda_hand", compliant_joints=arm),
                [Marker("hand", "panda_hand", np.array([0.0, 0.0, 0.1]))],
                np.array([2e4, 2e4, 1.5e4, 1.5e4, 5e3, 5e3, 5e3]),
                np.array([0.0, 0.0, -30.0, 0.0, 0.0, 0.0]))
    if name == "two-arm-torso":
        tree = load_robot("two-arm-torso")
        return (tree, [Marker("right", "right_tcp", np.zeros(3)),
                       Marker("left", "left_tcp", np.array([0.0, 0.02, 0.0]))],
                np.asarray(default_stiffness(tree), dtype=float), None)
    chain = tmp / "torso-passive-chain.toml"
    chain.write_text(TORSO.read_text().replace(
        'springs_on = "controller"', 'springs_on = "chain"').replace(
        'compliant_joints = ["T1", "T2", "T3", "A1", "A2"]',
        'compliant_joints = ["t1", "t2", "t3", "t4", "a1", "a2"]').replace(
        "k_theta_SI = [4.0e4, 2.5e4, 2.0e4, 8.0e3, 6.0e3]",
        "k_theta_SI = [4.0e4, 2.5e4, 2.0e4, 1.5e4, 8.0e3, 6.0e3]"))
    return (load_robot(str(chain)),
            [Marker("tip", "tool", np.array([0.02, 0.0, 0.03])),
             Marker("chest", "t4_link", np.array([0.05, 0.1, 0.0]))],
            np.array([4.0e4, 2.5e4, 2.0e4, 1.5e4, 8.0e3, 6.0e3]),
            np.array([20.0, -15.0, -60.0, 0.0, 0.0, 0.0]))


def _tilting_joints(robot, markers) -> list[str]:
    """Three joints that tilt: the 2nd to 4th of the markers' chains' tilting joints."""
    model = robot.model
    joints = transversal_joints(model, [model.getFrameId(m.frame) for m in markers],
                                [int(model.getJointId(n)) for n in robot.compliant_joints])
    names = [model.names[k.b] for k in joints]
    return names[1:4] if len(names) > 3 else names


def hidden_errors(robot, markers, stiffness, family: str, rng) -> HiddenPoseErrors:
    """What a campaign hides: the frame, markers, zero offsets and joint stiffness, and
    ``family`` (module docstring)."""
    n = sum(robot.model.joints[j].nv == 1 for j in range(1, robot.model.njoints))
    hidden = HiddenPoseErrors(
        pin.exp3(rng.normal(size=3)), rng.uniform(-2, 2, 3),
        np.array([m.offset for m in markers]) + rng.normal(0, 2e-3, (len(markers), 3)),
        rng.normal(0.0, 1e-3, n), np.zeros((n, 6)), stiffness.copy())
    if family == "base_tilt":
        hidden.stiffness = stiffness / 4
        hidden.base_tilt = rng.choice([-1, 1], 2) * rng.uniform(0.035, 0.06, 2)
    elif family == "transversal_compliance":  # of the order of the joint's own compliance
        k = dict(zip(robot.compliant_joints, stiffness, strict=True))
        hidden.transversal_compliance = {
            j: rng.uniform(0.5, 1.0, 2) / k[j] for j in _tilting_joints(robot, markers)}
    return hidden


def run_one(robot, markers, stiffness, payload, family: str, mode: str, seed: int,
            poses: int = POSES) -> dict:
    """One campaign of ``poses`` poses and its diagnosis: what was named, coverage, held-out
    RMS / noise."""
    rng = np.random.default_rng(seed)
    hidden = hidden_errors(robot, markers, stiffness, family, rng)
    campaign = simulate_pose_campaign(robot, markers, hidden, poses, NOISE, seed=seed,
                                      payload=payload)
    if family == "nonlinear_joint_stiffness":  # the same poses, the springs hardening
        hidden.nonlinear = hardening(robot, campaign)
        campaign = simulate_pose_campaign(robot, markers, hidden, poses, NOISE, seed=seed,
                                          payload=payload)
    refused = NOT_HIDDEN + (["transversal_compliance"] if mode == "not-offered" else [])
    start = time.perf_counter()
    d = diagnose_poses(campaign, families=FORCED, not_families=refused)
    seconds = time.perf_counter() - start
    cov = Coverage()
    labels = []
    extra = [f for f in d.families if f not in ("frame", "markers", *FORCED)]
    if family in d.families:
        add_intervals(cov, d.final, hidden, campaign, (family,))
        labels = [row["parameter"] for row in parameter_table(d.final)
                  if row["fitted"] and row["family"] == family]
    return {"seed": seed, "families": d.families, "labels": labels,
            "named": family in d.families if family != "nothing" else bool(extra),
            "unexplained": d.unexplained, "covered": cov.hits, "intervals": cov.n,
            "z": cov.z, "held_out_over_noise": [s.cv_rms / NOISE for s in d.steps],
            "fit_rms_over_noise": d.final.rms() / NOISE, "seconds": seconds,
            "hidden": {k: np.asarray(v).tolist() for k, v in (
                [("base_tilt", hidden.base_tilt)] if family == "base_tilt"
                else [("beta", hidden.nonlinear)] if hidden.nonlinear is not None
                else hidden.transversal_compliance.items())}}


def hardening(robot, campaign) -> np.ndarray:
    """``beta`` (1/(N.m)) of each spring: the two that carry the largest torques at the
    ``campaign``'s commanded poses harden by 40 % at those torques (``beta = -0.4 /
    tau_max``), the others linear."""
    largest = campaign_settings(campaign)[NONLINEAR_SETTING]
    beta = np.zeros(len(robot.compliant_joints))
    for joint in sorted(largest, key=largest.get)[-2:]:
        beta[list(robot.compliant_joints).index(joint)] = -0.4 / largest[joint]
    return beta


def deflection_one(name: str, source: str, mode: str, seed: int) -> dict:
    """One deflection campaign of ``name`` (robot file or name ``source``) hiding three
    bearing tilts, diagnosed with every library effect (``mode`` ``deflection``) or all but
    ``transversal_compliance`` (``deflection-not-offered``): named first, which hidden tilts
    are named, their intervals against the truth, held-out RMS / noise (module docstring)."""
    frame, compliant, kq, max_force = DEFLECTION[name]
    robot = load_robot(source, frame=frame, compliant_joints=compliant)
    k = dict(zip(robot.compliant_joints, kq, strict=True))
    tilting = [j for j in Geometry.of(robot).tilt_columns if j in k][1:4]
    rng = np.random.default_rng(seed)
    truth = {j: k[j] / rng.uniform(0.5, 1.0, 2) for j in tilting}  # N.m/rad
    sim = simulate(source, kq=kq, frame=frame, compliant_joints=compliant,
                   target_offset_m=[0.0, 0.0, 0.1], max_force=max_force, configs=CONFIGS,
                   loads_per_config=LOADS, noise_std_m=NOISE, seed=seed,
                   effects=[HiddenEffect("transversal_compliance", j, tuple(v))
                            for j, v in truth.items()])
    start = time.perf_counter()
    d = diagnose(sim.campaign, propose=False, workers=1,
                 not_families=["transversal_compliance"] if mode.endswith("not-offered")
                 else ())
    seconds = time.perf_counter() - start
    labels = [s.effect.label for s in d.named_steps]  # the final model's (none removed)
    first = d.steps[0].effect.label if d.steps else ""
    cov = Coverage()
    for j, k_true in truth.items():
        named = d.final_parameters_si.get(f"transversal_compliance({j})")
        for p, t in zip(named or [], k_true, strict=bool(named)):
            if not p.held:
                cov.add(p.value, p.ci95, t)
    held_out = d.steps[-1].cv_rms if d.steps else d.cv_baseline
    aliases = {a.other for a in d.ambiguities if a.chosen in labels}  # told apart from none
    return {"seed": seed, "families": ["baseline", *labels],
            "named": first.startswith("transversal_compliance("),
            "tilts_named": sum(f"transversal_compliance({j})" in labels for j in truth),
            "tilts_named_or_alias": sum(f"transversal_compliance({j})" in set(labels) | aliases
                                        for j in truth),
            "tilts_hidden": len(truth), "unexplained": d.unexplained, "covered": cov.hits,
            "intervals": cov.n, "z": cov.z, "held_out_over_noise": [held_out / NOISE],
            "fit_rms_over_noise": d.final.rms() / NOISE, "seconds": seconds,
            "tilt_sizes_over_noise": [v / NOISE for v in sim.effect_rms_m.values()],
            "hidden": {j: v.tolist() for j, v in truth.items()}}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=0,
                        help="seeds first-seed .. first-seed + seeds - 1 (split a study)")
    parser.add_argument("--robots", default="ur10,panda,two-arm-torso,torso-passive")
    parser.add_argument("--families", default="transversal_compliance,base_tilt,not-offered")
    parser.add_argument("--json", help="write every run here")
    args = parser.parse_args()
    import tempfile
    out: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.robots.split(","):
            robot, markers, stiffness, payload = robot_setup(name, Path(tmp))
            source = robot.name if name != "torso-passive" else str(
                Path(tmp) / "torso-passive-chain.toml")
            for what in args.families.split(","):
                family = "transversal_compliance" if what == "not-offered" else what
                mode = "not-offered" if what == "not-offered" else "offered"
                runs = []
                for seed in range(args.first_seed, args.first_seed + args.seeds):
                    r = (deflection_one(name, source, what, seed)
                         if what.startswith("deflection") else
                         run_one(robot, markers, stiffness, payload, family, mode, seed))
                    runs.append(r)
                    print(f"{name} {what} seed {seed}: {'+'.join(r['families'][1:])}; "
                          f"unexplained {r['unexplained']}; covered {r['covered']}/"
                          f"{r['intervals']}; held-out/noise "
                          f"{r['held_out_over_noise'][-1]:.3f}; {r['seconds']:.0f} s",
                          flush=True)
                    if args.json:
                        Path(args.json).write_text(json.dumps(out + [{
                            "robot": name, "what": what, "runs": runs}], indent=1))
                out.append({"robot": name, "what": what, "runs": runs})
                _summary(name, what, runs)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


def _summary(name: str, what: str, runs: list[dict]) -> None:
    named = sum(r["named"] for r in runs)
    hits, n = sum(r["covered"] for r in runs), sum(r["intervals"] for r in runs)
    ratio = [r["held_out_over_noise"][-1] for r in runs]
    z2 = float(np.sum(np.square([z for r in runs for z in r["z"]]))) if n else float("nan")
    if "tilts_named" in runs[0]:
        print(f"SUMMARY {name} {what}: hidden tilts named "
              f"{sum(r['tilts_named'] for r in runs)}/{sum(r['tilts_hidden'] for r in runs)}"
              f", named or reported as not told apart from the one named "
              f"{sum(r['tilts_named_or_alias'] for r in runs)}", flush=True)
    print(f"SUMMARY {name} {what}: named {named}/{len(runs)}; covered {hits}/{n} "
          f"(binomially consistent with 95 %: {binomial_consistent(hits, n) if n else None}; "
          f"sum z^2 / n = {z2 / max(n, 1):.3g}); held-out/noise "
          f"{min(ratio):.3f}-{max(ratio):.3f} (median {np.median(ratio):.3f}); unexplained "
          f"{sum(bool(r['unexplained']) for r in runs)}/{len(runs)}", flush=True)


if __name__ == "__main__":
    raise SystemExit(main())
