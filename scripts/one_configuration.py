"""What ``stiffness diagnose`` names on a campaign of ONE configuration (all rows at one pose,
several loads): false names with nothing hidden, and detections of an effect one pose can
determine.

For each robot (a UR5 and a UR10 from example-robot-data with a 10 cm tool, the UR5's three arm
joints compliant, all six of the UR10's; the shipped SK120), each campaign size (rows at the one
configuration, random loads) and seed, a campaign is simulated
(:func:`stiffness.planning.simulate.simulate`, ``configs=1``, declared noise 5 um) with nothing
hidden (the UR5's and UR10's also with the noise undeclared) and with each of two hidden
effects, and diagnosed (:func:`stiffness.calibration.diagnose.diagnose`). A nothing-hidden run
*names* when its final model keeps any effect; a hidden-effect run *finds* the effect when the
final model keeps it by name (``alias``: it keeps what one pose cannot tell from it instead,
:data:`ALIAS`). The table goes to stdout and between the
markers of ``docs/diagnose.md``. With ``--undeclared``, only the UR5's and UR10's campaigns
with the noise undeclared, nothing hidden and each hidden effect (to stdout only).

Usage::

    python scripts/one_configuration.py [--seeds 20] [--rows 3,6,12] [--workers 2] [--no-write]
                                        [--undeclared] [--first-seed 300]

``--first-seed S`` runs seeds S to S + ``--seeds`` - 1 (default 300: seeds 300-319), so a run
can be split over machines or sessions; ``--records`` tabulates their ``--json`` records
joined into one list.
"""

from __future__ import annotations

import argparse
import json
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
from stiffness.planning.simulate import parse_effect, simulate  # noqa: E402

UR_ARM = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"]
TOOL = [0.0, 0.0, 0.1]
ROBOTS = {
    "ur5": {"robot": "ur5", "kq": [3e4, 2e4, 1.5e4], "compliant_joints": UR_ARM,
            "target_offset_m": TOOL, "max_force": 100.0},
    "ur10": {"robot": "ur10", "kq": [1.2e5, 8e4, 6e4, 2e4, 2e4, 1.5e4],
             "target_offset_m": TOOL, "max_force": 100.0},
    "sk120": {"robot": "sk120", "max_force": 400.0},
}
#: robot -> hidden effects (``--effect`` text; lengths in mm, forces in N).
EFFECTS = {
    "ur5": ["joint_compliance:wrist_1_joint=1e4", "deflection_offset=0.03"],
    "ur10": ["deflection_offset=0.03", "force_sensor_bias=5"],
    "sk120": ["joint_compliance:joint5=3e5", "deflection_offset=0.03"],
}
#: Robots whose nothing-hidden campaigns are also run with the noise undeclared (estimated
#: from the residuals: no chi-square stop, BIC on ``N ln(RSS / N)``).
UNDECLARED = ("ur5", "ur10")
#: What one pose cannot tell from the hidden effect: a force bias shifts every row's
#: deflection by the same ``J C J^T b`` there (a deflection offset), and a joint spring is a
#: bend of the segment ending at that joint about the same axis (docs/diagnose.md).
ALIAS = {"deflection_offset": "force_sensor_bias", "force_sensor_bias": "deflection_offset",
         "joint_compliance": "link_compliance"}
#: Before a hidden effect's ``--effect`` text: that campaign with the noise undeclared.
UNDECLARED_PREFIX = "undeclared "
NOISE_M = 5e-6
MARK_START, MARK_END = "<!-- one-configuration:start -->", "<!-- one-configuration:end -->"


def run_one(job: tuple) -> dict:
    """Simulate and diagnose one campaign of one configuration."""
    robot, spec, rows, seed = job
    setup = dict(ROBOTS[robot])
    source = setup.pop("robot")
    hidden = spec.removeprefix(UNDECLARED_PREFIX) if spec is not None else None
    declared = hidden == spec and spec != "undeclared"
    effects = [] if hidden in (None, "undeclared") else [parse_effect(hidden)]
    t0 = time.perf_counter()
    sim = simulate(source, effects=effects, configs=1, loads_per_config=rows,
                   noise_std_m=NOISE_M, seed=seed, declare_noise=declared, **setup)
    result = diagnose(sim.campaign, propose=False, workers=1)
    s = result.summary()
    return {"robot": robot, "spec": spec, "rows": rows, "seed": seed,
            "named": [st["effect"] for st in kept_steps(s)],
            "final_over_noise": s["final_rms"] / (NOISE_M * 1e3), "stop": result.stop_reason,
            "size": (next(iter(sim.effect_rms_m.values())) / NOISE_M) if effects else 0.0,
            "seconds": time.perf_counter() - t0}


def table(results: list[dict], seeds: int, undeclared: bool = False) -> str:
    """A markdown table of the results."""
    sizes = sorted({r["rows"] for r in results})
    lines = [
        f"Campaigns of one random reachable configuration x R random loads (3R residual "
        f"components), {'undeclared' if undeclared else 'declared'} noise {NOISE_M * 1e3:g} mm, "
        f"{seeds} seeds per cell. Nothing "
        "hidden: `named/runs`, runs whose final model keeps an effect (a false name), and the "
        "effects named. A hidden effect: `found/runs` keeping it (+ its one-pose alias, a force "
        "bias for a deflection offset and back), then its median size in noise std.",
        "",
        "| robot | hidden | " + " | ".join(f"R = {r}" for r in sizes) + " |",
        "|---|---|" + "---|" * len(sizes),
    ]
    for robot, spec in cases(undeclared):
        cells = []
        for rows in sizes:
            rs = [r for r in results if (r["robot"], r["spec"], r["rows"]) == (robot, spec, rows)]
            cells.append(_cell(rs, spec) if rs else "-")
        title = {None: "nothing", "undeclared": "nothing, noise undeclared"}.get(
            spec, f"`{str(spec).removeprefix(UNDECLARED_PREFIX)}`"
            + (", noise undeclared" if str(spec).startswith(UNDECLARED_PREFIX) else ""))
        lines.append(f"| {robot} | {title} | " + " | ".join(cells) + " |")
    nulls = [r for r in results if r["spec"] in (None, "undeclared")]
    found = [r for r in results if r["spec"] not in (None, "undeclared")]
    total = sum(r["seconds"] for r in results)
    below = sum(bool(r["named"]) and r["final_over_noise"] < 0.5 for r in results)
    lines += ["", f"Nothing hidden: an effect named in {sum(bool(r['named']) for r in nulls)}"
                  f"/{len(nulls)}; hidden: found in {sum(_found(r) == 1 for r in found)}/"
                  f"{len(found)} (+ {sum(_found(r) == 2 for r in found)} alias). Runs naming "
                  f"an effect with a final RMS below half the noise: {below}. "
                  f"{len(results)} campaigns, {total:.0f} s."]
    return "\n".join(lines)


def cases(undeclared: bool = False) -> list[tuple[str, str | None]]:
    """The (robot, hidden) cases in table order: ``None`` nothing hidden, ``undeclared``
    nothing hidden and the noise undeclared, else the ``--effect`` text, after
    :data:`UNDECLARED_PREFIX` with the noise undeclared; with ``undeclared``, only the cases
    of the :data:`UNDECLARED` robots with the noise undeclared, each hidden effect's too."""
    if undeclared:
        return [(robot, spec) for robot in UNDECLARED for spec in
                ["undeclared", *(UNDECLARED_PREFIX + e for e in EFFECTS[robot])]]
    return [(robot, spec) for robot in ROBOTS
            for spec in [None, *(["undeclared"] if robot in UNDECLARED else []),
                         *EFFECTS[robot]]]


def _found(record: dict) -> int:
    """1 when the run keeps its hidden effect by name, 2 its one-pose alias only, else 0."""
    hidden = record["spec"].removeprefix(UNDECLARED_PREFIX).split(":")[0].split("=")[0]
    return 1 if hidden in record["named"] else 2 if ALIAS.get(hidden) in record["named"] else 0


def _cell(rs: list[dict], spec: str | None) -> str:
    """A table cell of the runs ``rs`` of one case."""
    if spec in (None, "undeclared"):
        names = sorted({n for r in rs for n in r["named"]})
        return (f"{sum(bool(r['named']) for r in rs)}/{len(rs)}"
                + (f" ({', '.join(names)})" if names else ""))
    alias = sum(_found(r) == 2 for r in rs)
    size = float(np.median([r["size"] for r in rs]))
    return (f"{sum(_found(r) == 1 for r in rs)}/{len(rs)}" + (f" + {alias}" if alias else "")
            + f" ({size:.2g} σ)")


def main(argv: list[str] | None = None) -> int:
    """Run the study; returns the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=300,
                        help="the first seed (default 300)")
    parser.add_argument("--rows", default="3,6,12", help="rows per campaign, comma-separated")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--no-write", action="store_true", help="do not update docs/diagnose.md")
    parser.add_argument("--json", type=Path, default=None,
                        help="also write each run's record to this JSON file")
    parser.add_argument("--records", type=Path, default=None,
                        help="tabulate the records of an earlier --json file instead of running")
    parser.add_argument("--undeclared", action="store_true",
                        help="only the UR5's and UR10's campaigns with the noise undeclared, "
                             "nothing hidden and each hidden effect (never written)")
    args = parser.parse_args(argv)
    sizes = [int(r) for r in args.rows.split(",")]
    jobs = [(robot, spec, rows, args.first_seed + seed) for seed in range(args.seeds)
            for robot, spec in cases(args.undeclared) for rows in sizes]
    results = (json.loads(args.records.read_text()) if args.records is not None
               else run_jobs(run_one, jobs, args.workers, args.json))
    text = table(results, args.seeds, args.undeclared)
    print(text)
    if not args.no_write and not args.undeclared:
        return write_between_markers(ROOT / "docs" / "diagnose.md", MARK_START, MARK_END, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
