"""``stiffness report``: the SK120 paper-reproduction report (the main job).

Writes ``report.html`` (summary of verdicts, contents, provenance, evidence, figures embedded),
``summary.json`` and the figures as PNG into ``--out`` (see :mod:`stiffness.papers.report`).
"""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path

from stiffness.papers.report import build_report, write_report
from stiffness.papers.report_page import verdict_counts


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Flags of ``stiffness report``."""
    parser.add_argument("--out", default="sk120-report", help="output folder (default "
                                                              "./sk120-report)")
    parser.add_argument("--campaign", help="campaign to identify from (default: the shipped "
                                           "Table II campaign)")
    parser.add_argument("--quiet", action="store_true", help="no progress on the terminal")


def command_line(args: argparse.Namespace) -> str:
    """The command that reproduces this run (recorded in the report's provenance)."""
    words = ["stiffness", "report", "--out", str(args.out)]
    if args.campaign:
        words += ["--campaign", str(args.campaign)]
    return shlex.join(words)


def run(args: argparse.Namespace) -> int:
    """Build and write the report, then print a short summary."""
    summary, figures = build_report(args.campaign, quiet=args.quiet,
                                    command=command_line(args))
    out = Path(args.out)
    write_report(out, summary, figures)
    s = summary
    print(f"SK120 report written to {out / 'report.html'} ({s['elapsed_s']:.0f} s)")
    print(f"  Appendix I mismatches: {', '.join(s['appendix_mismatches']) or 'none'}")
    print("  K_theta (N.mm/rad): paper " + ", ".join(f"{k:.4g}" for k in
                                                    s["paper_k_theta_Nmm_per_rad"])
          + " | identified " + ", ".join(f"{k:.4g}" for k in s["identified_k_theta_Nmm_per_rad"]))
    t2 = s["table2_summary"]
    print(f"  Table II: enhanced vs measured {t2['rms_enhanced_vs_measured_mm']:.3f} mm RMS "
          f"(paper's own {t2['rms_paper_calculated_vs_measured_mm']:.3f})")
    print(f"  Table IV printed counts self-consistent: {s['table4_paper_self_consistent']}")
    print(f"  K_theta - K_C PD on the whole grid: {s['kx_positive_definite_everywhere']}; loses "
          f"PD at {s['kx_loses_pd_at_force_N'] / 1e3:.0f} kN")
    verdicts = verdict_counts(s["findings_by_verdict"])
    print(f"  {s['findings_count']} findings in the paper ({verdicts}); see the report")
    return 0
