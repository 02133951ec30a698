"""``stiffness check-jacobian``: the printed Appendix I Jacobian (and its K_C) vs Pinocchio's SK120.

The comparison itself is :func:`stiffness.papers.crosscheck.run_crosscheck` (see that module for
the method); this module turns it into the command: ``--json`` prints the report as one JSON
object, ``--quiet`` only the elements that disagree, the default a table. Units: J in mm/rad,
K_C in N.mm/rad per N of force.
"""

from __future__ import annotations

import argparse
import json

from stiffness.cli import flags
from stiffness.errors import StiffnessError
from stiffness.papers.appendix import ELEMENT_NAMES
from stiffness.papers.crosscheck import run_crosscheck


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Options of ``stiffness check-jacobian``."""
    flags.add_output_flags(parser, json_help="print one JSON object (and nothing else) on stdout",
                           quiet_help="print only the elements that disagree (one line each)")
    parser.add_argument("--samples", type=flags.integer, default=200, metavar="N",
                        help="random vertical-wrist workspace poses (default 200)")
    flags.add_seed_flag(parser, "seed of the workspace sample")


def run(args: argparse.Namespace) -> int:
    """Run ``stiffness check-jacobian``; returns the exit status (0)."""
    if args.samples < 0:
        raise StiffnessError(f"--samples must be >= 0, got {args.samples}")
    report = run_crosscheck(args.samples, args.seed)
    if args.json:
        print(json.dumps(report, indent=1))
    elif args.quiet:
        print("\n".join(_disagreements(report)))
    else:
        print(text_report(report))
    return 0


def _disagreements(report: dict) -> list[str]:
    """One line per element of the printed appendix that disagrees with Pinocchio."""
    lines = [f"{m['element']}: {m['explanation']}" for m in report["mismatches"]]
    lines += [f"{m['element']} (invisible at Table I's lengths): {m['explanation']}"
              for m in report["invisible_typos"]]
    return lines or ["the printed appendix agrees with Pinocchio everywhere"]


def text_report(report: dict) -> str:
    """Plain-text summary of a :func:`~stiffness.papers.crosscheck.run_crosscheck` report."""
    lines = [
        "Appendix I (A&S 2005) vs Pinocchio SK120, same physical poses "
        f"({report['n_poses']}: " + ", ".join(
            f"{n} {k}" for k, n in report["n_poses_by_kind"].items()) + ")",
        "",
        "Angle convention of the appendix:",
        "  " + report["conventions"]["description"].replace(". ", ".\n  "),
        "Lengths (mm): " + ", ".join(f"{k}={v:g}" for k, v in report["lengths_mm"].items() if v),
        "",
        f"{'element':8}{'printed max abs':>18}{'max rel':>11}{'corrected max abs':>20}"
        f"{'max rel':>11}   [{report['unit']}]",
    ]
    for name in ELEMENT_NAMES:
        p, c = report["elements"][name], report["elements_corrected"][name]
        lines.append(f"{name:8}{p['max_abs']:18.3e}{p['max_rel']:11.1e}"
                     f"{c['max_abs']:20.3e}{c['max_rel']:11.1e}")
    lines += ["", "Disagreeing elements:"]
    for m in report["mismatches"] or [{"element": "none", "explanation": ""}]:
        lines.append(f"  {m['element']}: {m['explanation']}")
    lines += ["", "Typos invisible at Table I's lengths:"]
    for m in report["invisible_typos"] or [{"element": "none", "explanation": ""}]:
        lines.append(f"  {m['element']}: {m['explanation']}")
    lines += [
        "",
        f"K_C [{report['kc_unit']}]",
        f"{'element':8}{'printed max abs':>18}{'max rel':>11}{'corrected max abs':>20}"
        f"{'max rel':>11}",
    ]
    for name in report["kc_elements"]:
        p, c = report["kc_elements"][name], report["kc_elements_corrected"][name]
        lines.append(f"{name:8}{p['max_abs']:18.3e}{p['max_rel']:11.1e}"
                     f"{c['max_abs']:20.3e}{c['max_rel']:11.1e}")
    lines.append(f"K_C of the printed appendix: max asymmetry "
                 f"{report['kc_printed_max_asymmetry']:.4g}; corrected appendix vs Pinocchio: "
                 f"max rel {report['appendix_kc_max_rel']:.1e}")
    return "\n".join(lines)
