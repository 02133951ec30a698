"""``stiffness report``: the SK120 paper-reproduction report (the main job) and its 3-D scene.

Writes ``report.html`` (summary of verdicts, contents, provenance, evidence, figures embedded),
``summary.json`` and the figures as PNG into ``--out`` (see :mod:`stiffness.papers.report`),
and the meshcat scene of :func:`stiffness.papers.report.scene_robot`, drawn by
:mod:`stiffness.viewer` (a layer above the papers). With two or more CPUs the Appendix I
cross-check (independent of the rest, about a fifth of the work) runs meanwhile in a second
Python process (:func:`background_crosscheck`).
"""

from __future__ import annotations

import argparse
import os
import pickle
import shlex
import subprocess
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import stiffness
from stiffness.files import output_folder
from stiffness.papers.crosscheck import run_crosscheck
from stiffness.papers.report import SCENE_TITLE, build_report, scene_robot, write_report
from stiffness.papers.report_page import verdict_counts
from stiffness.viewer import StiffnessViewer


def export_scene(path: Path) -> Path:
    """Write the report's static 3-D scene to ``path`` (self-contained HTML, opens offline).

    Enhanced and conventional stiffness ellipsoids side by side, the deflected robot and the
    load arrow, at :func:`~stiffness.papers.report.scene_robot`'s configuration and load.
    """
    robot, k_theta = scene_robot()
    viewer = StiffnessViewer(robot, k_theta)
    viewer.show()
    return viewer.export(path, title=SCENE_TITLE)


#: The second process: the cross-check with its defaults, pickled on stdout, if it imports
#: the same stiffness as this process (its ``__init__`` file is the argument); else exit 3.
_CROSSCHECK_CHILD = ("import pickle, sys, stiffness; "
                     "sys.exit(3) if stiffness.__file__ != sys.argv[1] else None; "
                     "from stiffness.papers.crosscheck import run_crosscheck; "
                     "sys.stdout.buffer.write(pickle.dumps(run_crosscheck()))")


@contextmanager
def background_crosscheck() -> Iterator[Callable[[], dict]]:
    """:func:`~stiffness.papers.crosscheck.run_crosscheck`, started in a second Python
    process where there is a second CPU; yields the function that returns its report.

    The process is a fresh interpreter running only the cross-check (nothing of the caller's
    ``__main__`` is re-run) on the same ``stiffness``, in its own session (Ctrl-C is the
    parent's to handle), ended on leaving the block. If it fails, imports another
    ``stiffness`` or is not started, the report is computed in this process (a real error of
    the cross-check is then raised here, as without the second process).
    """
    if _usable_cpus() < 2:
        yield run_crosscheck
        return
    child = subprocess.Popen([sys.executable, "-c", _CROSSCHECK_CHILD, stiffness.__file__],
                             stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                             stderr=subprocess.DEVNULL, start_new_session=True)

    def result() -> dict:
        data, _ = child.communicate()
        if child.returncode == 0:
            try:
                return pickle.loads(data)
            except (pickle.UnpicklingError, EOFError):
                pass
        return run_crosscheck()

    try:
        yield result
    finally:
        if child.poll() is None:
            child.kill()
        child.wait()
        child.stdout.close()


def _usable_cpus() -> int:
    """CPUs this process may run on (its affinity where the platform tells it)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


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
    out = output_folder(args.out, create=False)  # before the work: a bad --out fails at once
    with background_crosscheck() as appendix:
        summary, figures = build_report(args.campaign, quiet=args.quiet,
                                        command=command_line(args), appendix=appendix)
    write_report(out, summary, figures, scene=export_scene)
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
