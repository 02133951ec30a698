"""Detection rate of ``stiffness diagnose`` when two effects are hidden at once.

For each robot (a UR5 with a 10 cm tool and its three arm joints compliant; the paper's SK120;
a 7-axis Franka Panda from example-robot-data with a 10 cm tool and its first four joints
compliant), each pair of library effects of :data:`PAIRS` and several seeds, a campaign of
``--configs`` configurations x 4 random loads with declared noise is simulated with both
effects hidden (:func:`stiffness.planning.simulate.simulate`) and diagnosed
(:func:`stiffness.calibration.diagnose.diagnose`). A run names *both* when both hidden effects,
at their hidden places, are among the effects named (in any order); *names* when both effect
names are (the place may be one the campaign cannot tell apart); it *fits* when the final RMS
is within 1.5x the noise, and *passes* when the chi-square test of the final model does not
reject at 95 %. The table goes to stdout and between the markers of ``docs/diagnose.md``.

``--unexplained`` measures the "unexplained" verdict instead: campaigns with nothing hidden
plus an effect *outside* the library, defined here (:data:`OUT_OF_LIBRARY`: a temperature drift
of the tracker along the row order, a re-zeroing error per configuration), each at
:data:`OUT_SIZE` noise std RMS, must end with ``"unexplained": true`` and no effect named;
campaigns with nothing hidden must come back empty.

Usage::

    python scripts/detection_pairs.py [--seeds 5] [--configs 10] [--workers 2] [--no-write]
    python scripts/detection_pairs.py --unexplained [--seeds 6] [--configs 8]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from detection_rate import (  # noqa: E402  (scripts/ is on sys.path)
    kept_steps,
    run_jobs,
    write_between_markers,
)

from stiffness.calibration.diagnose import diagnose  # noqa: E402
from stiffness.calibration.selection import GOF_LEVEL  # noqa: E402
from stiffness.planning.simulate import parse_effect, simulate  # noqa: E402

NOISE_MM = 0.005
ROBOTS = {
    "ur5": {"robot": "ur5", "kq": [3e4, 2e4, 1.5e4],
            "compliant_joints": ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"],
            "target_offset_m": [0.0, 0.0, 0.1], "max_force": 100.0},
    "sk120": {"robot": "sk120", "max_force": 400.0},
    "panda": {"robot": "panda", "kq": [2e4, 2e4, 1.5e4, 1.5e4],
              "compliant_joints": [f"panda_joint{i}" for i in range(1, 5)],
              "target_offset_m": [0.0, 0.0, 0.1], "max_force": 50.0},
}
#: robot -> pairs of hidden effects (``--effect`` specs, campaign units: deg, N, mm).
PAIRS = {
    "ur5": [
        ("joint_compliance:wrist_1_joint=30000", "force_sensor_bias=1.5"),
        ("backlash:shoulder_lift_joint=0.005", "frame_misalignment=2"),
        ("nonlinear_joint_stiffness:elbow_joint=0.005", "target_offset=20"),
        ("link_compliance:elbow_joint->wrist_1_joint=150000",
         "backlash:shoulder_lift_joint=0.0015"),
    ],
    "sk120": [
        ("joint_compliance:joint5=1000000", "force_sensor_bias=10"),
        ("backlash:joint2=0.003", "frame_misalignment=2"),
        ("nonlinear_joint_stiffness:joint3=0.0003", "target_offset=100"),
        ("link_compliance:joint2->elbow=6000000", "backlash:joint2=0.001"),
    ],
    "panda": [
        ("joint_compliance:panda_joint6=60000", "force_sensor_bias=1"),
        ("backlash:panda_joint2=0.005", "frame_misalignment=2"),
        ("nonlinear_joint_stiffness:panda_joint4=0.005", "target_offset=20"),
        ("backlash:panda_joint4=0.0015", "force_sensor_bias=0.4"),
    ],
}
MARK_START, MARK_END = "<!-- detection-pairs:start -->", "<!-- detection-pairs:end -->"
OUT_START, OUT_END = "<!-- unexplained:start -->", "<!-- unexplained:end -->"
#: Size of the out-of-library effects: RMS over the deflection components, in noise std.
OUT_SIZE = 3.0


def temperature_drift(campaign, rng: np.random.Generator) -> np.ndarray:
    """(m, 3) the tracker's reference drifting linearly along the row order in a random
    direction, zero at mid-campaign (m)."""
    t = np.arange(campaign.n_rows) / (campaign.n_rows - 1) - 0.5
    u = rng.normal(size=3)
    return t[:, None] * u / np.linalg.norm(u)


def rezeroing_error(campaign, rng: np.random.Generator) -> np.ndarray:
    """(m, 3) a random offset per configuration (its unloaded reference measured once, with
    its own error), zero-mean over the campaign (m)."""
    labels = list(dict.fromkeys(campaign.config))
    offsets = rng.normal(size=(len(labels), 3))
    return (offsets - offsets.mean(axis=0))[[labels.index(c) for c in campaign.config]]


OUT_OF_LIBRARY = {"temperature drift along the row order": temperature_drift,
                  "re-zeroing error per configuration": rezeroing_error}


def run_out(job: tuple) -> dict:
    """Simulate a campaign with nothing hidden, add an out-of-library effect (or none) and
    diagnose it."""
    robot, kind, seed, configs = job
    setup = dict(ROBOTS[robot])
    source = setup.pop("robot")
    t0 = time.perf_counter()
    sim = simulate(source, effects=[], configs=configs, loads_per_config=4,
                   noise_std_m=NOISE_MM * 1e-3, seed=seed, **setup)
    camp = sim.campaign
    if kind is not None:
        d = OUT_OF_LIBRARY[kind](camp, np.random.default_rng(1000 + seed))
        d *= OUT_SIZE * sim.noise_std_m / math.sqrt(np.mean(d ** 2))
        camp = dataclasses.replace(camp, deflection=camp.deflection + d)
    s = diagnose(camp, propose=False).summary()
    return {"robot": robot, "kind": kind, "seed": seed, "named": s["missing_effects"],
            "unexplained": s["unexplained"], "seconds": time.perf_counter() - t0}


def out_table(results: list[dict], seeds: int, configs: int) -> str:
    """Markdown table of the unexplained study."""
    lines = [
        f"Campaigns of {configs} random reachable configurations x 4 random loads, nothing "
        f"from the library hidden, declared noise {NOISE_MM:g} mm, {seeds} seeds per cell; the "
        f"out-of-library effect is {OUT_SIZE:g} noise std RMS. A cell reads `ok/runs`: "
        "out-of-library rows count runs ending with `\"unexplained\": true` and "
        "`missing_effects` empty; the nothing-hidden row counts runs with `missing_effects` "
        "empty and `\"unexplained\": false`. Effects named by the failures follow.",
        "",
        "| campaign | " + " | ".join(ROBOTS) + " |",
        "|---" * (len(ROBOTS) + 1) + "|",
    ]
    for kind in [*OUT_OF_LIBRARY, None]:
        cells = []
        for robot in ROBOTS:
            rs = [r for r in results if r["robot"] == robot and r["kind"] == kind]
            if not rs:
                cells.append("-")
                continue
            good = [(r["unexplained"] is True if kind else r["unexplained"] is False)
                    and not r["named"] for r in rs]
            named = sorted({n for r in rs for n in r["named"]})
            cells.append(f"{sum(good)}/{len(rs)}" + (f" ({', '.join(named)})" if named else ""))
        lines.append(f"| {kind or 'nothing hidden'} | " + " | ".join(cells) + " |")
    out = [r for r in results if r["kind"]]
    null = [r for r in results if not r["kind"]]
    lines += ["", "All robots: out of the library, unexplained and nothing named in "
                  f"{sum(r['unexplained'] is True and not r['named'] for r in out)}/{len(out)}; "
                  "nothing hidden, empty and explained in "
                  f"{sum(r['unexplained'] is False and not r['named'] for r in null)}/"
                  f"{len(null)}."]
    total = sum(r["seconds"] for r in results)
    lines += ["", f"{len(results)} campaigns, {total:.0f} s of simulation and diagnosis."]
    return "\n".join(lines)


def run_one(job: tuple) -> dict:
    """Simulate and diagnose one campaign with a pair hidden."""
    robot, pair, seed, configs = job
    setup = dict(ROBOTS[robot])
    source = setup.pop("robot")
    hidden = [parse_effect(spec) for spec in pair]
    t0 = time.perf_counter()
    sim = simulate(source, effects=hidden, configs=configs, loads_per_config=4,
                   noise_std_m=NOISE_MM * 1e-3, seed=seed, **setup)
    result = diagnose(sim.campaign, propose=False)
    s = result.summary()
    named = [(st["effect"], st["where"]) for st in kept_steps(s)]
    truth = [(h.name, h.where) for h in hidden]
    return {"robot": robot, "pair": pair, "seed": seed,
            "both": all(t in named for t in truth),
            "names": all(t[0] in [n[0] for n in named] for t in truth),
            "found": sum(t in named for t in truth),
            "extra": [f"{n[0]}" for n in named if n not in truth],
            "fits": s["final_rms"] <= 1.5 * s["noise_std"],
            "passes": result.gof_final is not None and result.gof_final > 1 - GOF_LEVEL,
            "snr": [sim.effect_rms_m[h.label] / sim.noise_std_m for h in hidden],
            "seconds": time.perf_counter() - t0}


def table(results: list[dict], seeds: int, configs: int) -> str:
    """Markdown table of the results."""
    lines = [
        f"Campaigns of {configs} random reachable configurations x 4 random loads "
        f"({3 * 4 * configs} residual components), {seeds} seeds per pair, declared noise "
        f"{NOISE_MM:g} mm. `both` = runs naming both hidden effects at their hidden places "
        "(any order); `names` = runs naming both effect names (a place may be one the "
        "campaign cannot tell apart); `one` = runs naming exactly one of the two at its "
        "place; `fit` = final RMS within 1.5x the noise; `chi2` = the final model passes the "
        "chi-square fit-to-noise test (95 %); `extra` = other effects named, with their count. "
        "Sizes: median RMS change of each effect alone on the noise-free deflections, in "
        "noise std.",
        "",
        "| robot | effect A | effect B | size A, B (σ) | both | names | one | fit | chi2 | "
        "extra |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for robot, pairs in PAIRS.items():
        for pair in pairs:
            rs = [r for r in results if r["robot"] == robot and tuple(r["pair"]) == pair]
            if not rs:
                continue
            n = len(rs)
            snr = np.median([r["snr"] for r in rs], axis=0)
            extra: dict[str, int] = {}
            for r in rs:
                for e in r["extra"]:
                    extra[e] = extra.get(e, 0) + 1
            lines.append(
                f"| {robot} | `{pair[0]}` | `{pair[1]}` | {snr[0]:.2g}, {snr[1]:.2g} | "
                f"{sum(r['both'] for r in rs)}/{n} | {sum(r['names'] for r in rs)}/{n} | "
                f"{sum(r['found'] == 1 for r in rs)}/{n} | {sum(r['fits'] for r in rs)}/{n} | "
                f"{sum(r['passes'] for r in rs)}/{n} | "
                + (", ".join(f"{k} {v}" for k, v in sorted(extra.items())) or "-") + " |")
    n = len(results)
    lines += ["", f"All pairs: both named in {sum(r['both'] for r in results)}/{n}, both names "
                  f"in {sum(r['names'] for r in results)}/{n}, final RMS within 1.5x the "
                  f"noise in {sum(r['fits'] for r in results)}/{n}, chi-square passed in "
                  f"{sum(r['passes'] for r in results)}/{n}."]
    total = sum(r["seconds"] for r in results)
    lines += ["", f"{n} campaigns, {total:.0f} s of simulation and diagnosis "
                  f"({total / max(n, 1):.2g} s each)."]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run the study; returns the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--configs", type=int, default=10)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--no-write", action="store_true", help="do not update docs/diagnose.md")
    parser.add_argument("--json", type=Path, default=None,
                        help="also write each run's record to this JSON file")
    parser.add_argument("--unexplained", action="store_true",
                        help="measure the unexplained verdict on out-of-library campaigns")
    args = parser.parse_args(argv)
    if args.unexplained:
        jobs = [(robot, kind, 400 + seed, args.configs) for robot in ROBOTS
                for kind in [*OUT_OF_LIBRARY, None] for seed in range(args.seeds)]
        jobs.sort(key=lambda job: job[2])  # seed by seed: a partial run covers every cell
        results = run_jobs(run_out, jobs, args.workers, args.json)
        text, start, end = out_table(results, args.seeds, args.configs), OUT_START, OUT_END
    else:
        jobs = [(robot, pair, 300 + seed, args.configs) for robot, pairs in PAIRS.items()
                for pair in pairs for seed in range(args.seeds)]
        jobs.sort(key=lambda job: job[2])  # seed by seed: a partial run covers every pair
        results = run_jobs(run_one, jobs, args.workers, args.json)
        text, start, end = table(results, args.seeds, args.configs), MARK_START, MARK_END
    print(text)
    if not args.no_write:
        return write_between_markers(ROOT / "docs" / "diagnose.md", start, end, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
