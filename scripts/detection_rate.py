"""Detection rate of ``stiffness diagnose`` against effect size, robots and noise levels.

For each robot (a UR5 with a 10 cm tool and its three arm joints compliant; the paper's SK120),
each library effect at three sizes, two noise levels and several seeds, a campaign of
``--configs`` configurations x 4 random loads is simulated with that effect hidden
(:func:`stiffness.planning.simulate.simulate`) and diagnosed
(:func:`stiffness.calibration.diagnose.diagnose`). A
run *detects* the effect when the first effect named is the hidden one at the hidden place;
it *fits* when the final RMS is within 1.5x the noise. Campaigns with nothing hidden measure
the false-alarm rate. The tables go to stdout and between the markers of ``docs/diagnose.md``.

Usage::

    python scripts/detection_rate.py [--seeds 4] [--configs 10] [--workers 2] [--no-write]
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from scipy import stats

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from stiffness.calibration.diagnose import diagnose  # noqa: E402
from stiffness.planning.simulate import parse_effect, simulate  # noqa: E402

UR5_ARM = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"]
ROBOTS = {
    "ur5": {"robot": "ur5", "kq": [3e4, 2e4, 1.5e4], "compliant_joints": UR5_ARM,
            "target_offset_m": [0.0, 0.0, 0.1], "max_force": 100.0},
    "sk120": {"robot": "sk120", "max_force": 400.0},
}
#: robot -> [(effect spec without value, sizes, unit)]; complementary_stiffness sizes are the
#: largest force (N): the load-dependent geometry grows with the load.
EFFECTS = {
    "ur5": [
        ("complementary_stiffness", (50, 100, 200), "N (max force)"),
        ("joint_compliance:wrist_1_joint", (1e5, 3e4, 1e4), "N.m/rad"),
        ("link_compliance:elbow_joint->wrist_1_joint", (5e5, 1.5e5, 5e4), "N.m/rad"),
        ("backlash:shoulder_lift_joint", (5e-4, 1.5e-3, 5e-3), "deg"),
        ("nonlinear_joint_stiffness:elbow_joint", (5e-4, 1.5e-3, 5e-3), "1/(N.m)"),
        ("frame_misalignment", (0.2, 0.6, 2.0), "deg"),
        ("target_offset", (2.0, 6.0, 20.0), "mm"),
        ("force_sensor_bias", (0.5, 1.5, 5.0), "N"),
    ],
    "sk120": [
        ("complementary_stiffness", (500, 1500, 4000), "N (max force)"),
        ("joint_compliance:joint5", (3e6, 1e6, 3e5), "N.m/rad"),
        ("link_compliance:joint2->elbow", (2e7, 6e6, 2e6), "N.m/rad"),
        ("backlash:joint2", (3e-4, 1e-3, 3e-3), "deg"),
        ("nonlinear_joint_stiffness:joint3", (1e-4, 3e-4, 1e-3), "1/(N.m)"),
        ("frame_misalignment", (0.2, 0.6, 2.0), "deg"),
        ("target_offset", (10.0, 30.0, 100.0), "mm"),
        ("force_sensor_bias", (1.0, 3.0, 10.0), "N"),
    ],
}
NOISES_MM = (0.005, 0.02)
SNR_BINS = (0.0, 0.5, 1.0, 2.0, 4.0, 8.0, math.inf)
MARK_START, MARK_END = "<!-- detection-rate:start -->", "<!-- detection-rate:end -->"


def kept_steps(summary: dict) -> list[dict]:
    """The ``--json`` steps adding the final model's effects: not a step removing one
    (``removed``, backward elimination), not one a later step removed."""
    gone = {(st["effect"], st["where"]) for st in summary["steps"] if st.get("removed")}
    return [st for st in summary["steps"] if (st["effect"], st["where"]) not in gone]


def run_one(job: tuple) -> dict:
    """Simulate and diagnose one campaign."""
    robot, spec, size, noise_mm, seed, configs = job
    setup = dict(ROBOTS[robot])
    source = setup.pop("robot")
    effects = []
    if spec is not None:
        if spec == "complementary_stiffness":
            setup["max_force"] = float(size)
            effects = [parse_effect(spec)]
        else:
            effects = [parse_effect(f"{spec}={size}")]
    t0 = time.perf_counter()
    sim = simulate(source, effects=effects, configs=configs, loads_per_config=4,
                   noise_std_m=noise_mm * 1e-3, seed=seed, **setup)
    result = diagnose(sim.campaign, propose=False)
    s = result.summary()
    kept = kept_steps(s)
    first = s["steps"][0] if s["steps"] and s["steps"][0] in kept else None
    hidden = effects[0] if effects else None
    detected = (hidden is not None and first is not None
                and (first["effect"], first["where"]) == (hidden.name, hidden.where))
    named_first = (hidden is not None and first is not None
                   and first["effect"] == hidden.name)
    snr = (next(iter(sim.effect_rms_m.values())) / sim.noise_std_m) if effects else 0.0
    return {"robot": robot, "spec": spec, "size": size, "noise": noise_mm, "seed": seed,
            "detected": detected, "name_first": named_first,
            "named": [st["effect"] for st in kept],
            "fits": s["final_rms"] <= 1.5 * s["noise_std"], "snr": snr,
            "baseline_error": sim.baseline_error_m / sim.noise_std_m,
            "seconds": time.perf_counter() - t0}


def tables(results: list[dict], seeds: int, configs: int) -> str:
    """Markdown tables of the results."""
    lines = [
        f"Campaigns of {configs} random reachable configurations x 4 random loads "
        f"({3 * 4 * configs} residual components), {seeds} seeds per cell, declared noise. "
        "A cell reads `detected/runs` (the hidden effect, at the hidden place, named first), "
        "then the median size of the hidden effect in noise std (RMS change of the noise-free "
        "deflections), `name` = runs whose first effect has the right name (the place may be "
        "another one the campaign cannot tell apart), `fit` = runs whose final RMS is within "
        "1.5x the noise.",
        "",
        "| robot | effect | size | noise 0.005 mm | noise 0.02 mm |",
        "|---|---|---|---|---|",
    ]
    for robot, effects in EFFECTS.items():
        for spec, sizes, unit in effects:
            for size in sizes:
                cells = []
                for noise in NOISES_MM:
                    rs = [r for r in results if (r["robot"], r["spec"], r["size"], r["noise"])
                          == (robot, spec, size, noise)]
                    if not rs:
                        cells.append("-")
                        continue
                    det = sum(r["detected"] for r in rs)
                    name = sum(r["name_first"] for r in rs)
                    fit = sum(r["fits"] for r in rs)
                    snr = float(np.median([r["snr"] for r in rs]))
                    cells.append(f"{det}/{len(rs)} ({snr:.2g} σ; name {name}, fit {fit})")
                lines.append(f"| {robot} | `{spec}` | {size:g} {unit} | " + " | ".join(cells)
                             + " |")
    lines += ["", "Detection rate against the effect's size in noise units, all effects, robots "
                  "and noise levels pooled:", "",
              "| effect size (noise std RMS) | " + " | ".join(
                  f"{lo:g}–{hi:g}" if math.isfinite(hi) else f"> {lo:g}"
                  for lo, hi in zip(SNR_BINS[:-1], SNR_BINS[1:], strict=True)) + " |",
              "|---" * len(SNR_BINS) + "|"]
    row = []
    for lo, hi in zip(SNR_BINS[:-1], SNR_BINS[1:], strict=True):
        rs = [r for r in results if r["spec"] is not None and lo <= r["snr"] < hi]
        row.append(f"{sum(r['detected'] for r in rs)}/{len(rs)}" if rs else "-")
    lines.append("| detected first | " + " | ".join(row) + " |")
    names = sorted({r["spec"].split(":")[0] for r in results if r["spec"]})
    for name in names:
        cells = []
        for lo, hi in zip(SNR_BINS[:-1], SNR_BINS[1:], strict=True):
            rs = [r for r in results if r["spec"] and r["spec"].split(":")[0] == name
                  and lo <= r["snr"] < hi]
            cells.append(f"{sum(r['detected'] for r in rs)}/{len(rs)}" if rs else "-")
        lines.append(f"| `{name}` | " + " | ".join(cells) + " |")
    nulls = [r for r in results if r["spec"] is None]
    if nulls:
        lines += ["", "Nothing hidden (false alarms):", "",
                  "| robot | noise | empty `missing_effects` | named instead | enhanced "
                  "baseline's own error (noise std) |", "|---|---|---|---|---|"]
        for robot in ROBOTS:
            for noise in NOISES_MM:
                rs = [r for r in nulls if (r["robot"], r["noise"]) == (robot, noise)]
                if not rs:
                    continue
                empty = sum(not r["named"] for r in rs)
                named = sorted({n for r in rs for n in r["named"]})
                err = float(np.median([r["baseline_error"] for r in rs]))
                lines.append(f"| {robot} | {noise:g} mm | {empty}/{len(rs)} | "
                             f"{', '.join(named) or '-'} | {err:.2g} |")
        lines += ["", null_rate(nulls)]
    total = sum(r["seconds"] for r in results)
    lines += ["", f"{len(results)} campaigns, {total:.0f} s of simulation and diagnosis "
                  f"({total / max(len(results), 1):.2g} s each)."]
    return "\n".join(lines)


def null_rate(nulls: list[dict]) -> str:
    """The pooled false-naming rate of the campaigns with nothing hidden against the 5 % a
    95 % stop rule lets through: count, one-sided 95 % upper bound (Clopper-Pearson) and the
    binomial probability of so many or more at 5 %."""
    n = len(nulls)
    k = sum(bool(r["named"]) for r in nulls)
    upper = float(stats.beta.ppf(0.95, k + 1, n - k)) if k < n else 1.0
    tail = float(stats.binom.sf(k - 1, n, 0.05))
    return (f"Nothing hidden, both robots and noises pooled: an effect named in {k}/{n} "
            f"campaigns ({100 * k / n:.0f} %; one-sided 95 % upper bound {100 * upper:.1f} %); "
            f"at a true rate of 5 %, {k} or more of {n} has probability {tail:.2g}.")


def main(argv: list[str] | None = None) -> int:
    """Run the study; returns the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--null-seeds", type=int, default=10)
    parser.add_argument("--configs", type=int, default=10)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--no-write", action="store_true", help="do not update docs/diagnose.md")
    parser.add_argument("--json", type=Path, default=None,
                        help="also write each run's record to this JSON file")
    args = parser.parse_args(argv)
    jobs = []
    for robot, effects in EFFECTS.items():
        for spec, sizes, _ in effects:
            for size in sizes:
                for noise in NOISES_MM:
                    for seed in range(args.seeds):
                        jobs.append((robot, spec, size, noise, 100 + seed, args.configs))
        for noise in NOISES_MM:
            for seed in range(args.null_seeds):
                jobs.append((robot, None, 0.0, noise, 200 + seed, args.configs))
    jobs.sort(key=lambda job: job[4] % 100)  # seed by seed: a partial run covers every row
    results = run_jobs(run_one, jobs, args.workers, args.json)
    text = tables(results, args.seeds, args.configs)
    print(text)
    if not args.no_write:
        return write_between_markers(ROOT / "docs" / "diagnose.md", MARK_START, MARK_END, text)
    return 0


def run_jobs(run: Callable[[tuple], dict], jobs: list[tuple], workers: int,
             json_path: Path | None) -> list[dict]:
    """``run`` over ``jobs`` on ``workers`` processes, in order; the count done on stderr and
    (``json_path`` given) every record so far in that file after each job."""
    results = []
    with ProcessPoolExecutor(max_workers=workers) as pool:
        for result in pool.map(run, jobs):
            results.append(result)
            print(f"{len(results)}/{len(jobs)} campaigns", file=sys.stderr, flush=True)
            if json_path is not None:
                write_records(json_path, results)
    return results


def write_records(path: Path, results: list[dict]) -> None:
    """Write each run's record to ``path`` as JSON (NumPy scalars as Python numbers)."""
    path.write_text(json.dumps(results, indent=1,
                               default=lambda o: o.item() if hasattr(o, "item") else str(o)))


def write_between_markers(doc: Path, start: str, end: str, text: str) -> int:
    """Replace what stands between the lines ``start`` and ``end`` of ``doc`` by ``text``;
    exit code 1 (and nothing written) when the markers are missing."""
    old = doc.read_text()
    pattern = re.compile(re.escape(start) + ".*?" + re.escape(end), re.S)
    if not pattern.search(old):
        print(f"markers not found in {doc}; table not written", file=sys.stderr)
        return 1
    doc.write_text(pattern.sub(lambda _: f"{start}\n{text}\n{end}", old))
    print(f"written to {doc}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
