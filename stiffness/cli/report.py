"""``stiffness report``: the SK120 paper-reproduction report (the main job) and its 3-D scene;
with a campaign, that campaign's report.

``stiffness report CAMPAIGN --out DIR`` (a deflection or a pose campaign) runs ``stiffness
diagnose CAMPAIGN --out DIR`` (:mod:`stiffness.cli.diagnose`) and writes the same folder:
``diagnosis.html`` (the report: steps with held-out RMS, residuals before and after per axis and
per marker, the named effects, the parameters with intervals, the validation), ``diagnosis.json``
and ``final-model.json``. Without ``CAMPAIGN``:

Writes ``report.html`` (summary of verdicts, contents, provenance, evidence, figures embedded),
``summary.json`` and the figures as PNG into ``--out`` (see :mod:`stiffness.papers.report`),
and the meshcat scene of :func:`stiffness.papers.independent.scene_robot`, drawn by
:mod:`stiffness.viewer` (a layer above the papers). With two or more CPUs the parts that depend
on no campaign (the Appendix I cross-check, the Table IV scan with Figs. 7-9 and the 3-D
scene, about half of the work, :func:`independent_parts`) run meanwhile in a second Python
process (:func:`background_independent_parts`).
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
from stiffness.cli import flags
from stiffness.cores import usable_cores
from stiffness.errors import StiffnessError
from stiffness.files import atomic_write, check_folder_name, output_folder

# The report, the figures and the viewer are imported by the functions that use them: `run`
# starts the second process before this one spends its time importing them.


def scene_html() -> str:
    """The report's static 3-D scene (self-contained HTML, opens offline).

    Enhanced and conventional stiffness ellipsoids side by side, the deflected robot and the
    load arrow, at :func:`~stiffness.papers.independent.scene_robot`'s configuration and load.
    """
    from stiffness.papers.independent import SCENE_TITLE, scene_robot
    from stiffness.viewer import StiffnessViewer

    robot, k_theta = scene_robot()
    viewer = StiffnessViewer(robot, k_theta)
    viewer.show()
    return viewer.html(title=SCENE_TITLE)


def export_scene(path: Path) -> Path:
    """Write :func:`scene_html` to ``path`` atomically."""
    return atomic_write(path, scene_html())


def independent_parts() -> dict:
    """:func:`stiffness.papers.independent.independent_parts` (the Appendix I cross-check, the
    Table IV part) and the 3-D scene (:func:`scene_html`, under ``"scene"``), imported when
    called."""
    from stiffness.papers.independent import independent_parts as compute

    return {**compute(), "scene": scene_html()}


#: The second process: :func:`independent_parts`, pickled on stdout, if it imports the same
#: stiffness as this process (its ``__init__`` file is the argument); else exit 3.
_INDEPENDENT_CHILD = ("import pickle, sys, stiffness; "
                      "sys.exit(3) if stiffness.__file__ != sys.argv[1] else None; "
                      "from stiffness.cli.report import independent_parts; "
                      "sys.stdout.buffer.write(pickle.dumps(independent_parts()))")


#: Single-threaded BLAS in the second process: two processes with a BLAS thread pool each on
#: two cores slow each other down (idle pool threads spin).
_ONE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


@contextmanager
def background_independent_parts() -> Iterator[Callable[[], dict]]:
    """:func:`independent_parts` (the Appendix I cross-check and the 3-D scene), started in a
    second Python process where there is a second CPU;
    yields the function that returns them.

    The process is a fresh interpreter running only those parts (nothing of the caller's
    ``__main__`` is re-run) on the same ``stiffness``, in its own session (Ctrl-C is the
    parent's to handle), ended on leaving the block. If it fails, imports another
    ``stiffness`` or is not started, the parts are computed in this process (a real error is
    then raised here, as without the second process).
    """
    if usable_cores() < 2:
        yield independent_parts
        return
    child = subprocess.Popen([sys.executable, "-c", _INDEPENDENT_CHILD, stiffness.__file__],
                             stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                             stderr=subprocess.DEVNULL, start_new_session=True,
                             env={**os.environ, **_ONE_THREAD})

    def result() -> dict:
        data, _ = child.communicate()
        if child.returncode == 0:
            try:
                return pickle.loads(data)
            except (pickle.UnpicklingError, EOFError):
                pass
        return independent_parts()

    try:
        yield result
    finally:
        if child.poll() is None:
            child.kill()
        child.wait()
        if child.stdout is not None:
            child.stdout.close()


#: Output folder of the SK120 report when ``--out`` is not given.
SK120_OUT = "sk120-report"


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Flags of ``stiffness report``."""
    parser.add_argument("user_campaign", nargs="?", metavar="CAMPAIGN",
                        help="a deflection or pose campaign (campaign.toml or its folder): "
                             "write its report (diagnose's page and record) into --out "
                             "instead of the SK120 report")
    parser.add_argument("--out", help=f"output folder (default ./{SK120_OUT} for the SK120 "
                                      "report; required with CAMPAIGN)")
    parser.add_argument("--campaign", help="SK120 report: campaign to identify from (default: "
                                           "the shipped Table II campaign)")
    parser.add_argument("--quiet", action="store_true", help="no progress on the terminal")
    group = parser.add_argument_group("with CAMPAIGN (as stiffness diagnose)")
    group.add_argument("--validate", metavar="CAMPAIGN",
                       help="another campaign of the same kind and robot the final model is "
                            "evaluated on without refitting (a pose campaign: every step)")
    # No choices here: the values are diagnose's (checked by run_campaign), and importing them
    # would delay the SK120 report's second process by the fitting stack's import.
    group.add_argument("--masses", help="link masses known (default) or unknown, as "
                                        "stiffness diagnose --masses")
    group.add_argument("--loss", help="linear (default) or a robust loss, as stiffness "
                                      "diagnose --loss")
    group.add_argument("--seed", type=flags.integer,
                       help="seed of the cross-validation folds; default 0")
    flags.add_refit_flags(parser)  # with --validate, as stiffness diagnose (pose campaigns)
    group.add_argument("--strict", action="store_true",  # applied by cli.main to the run
                       help="refuse campaign CSV columns that are not campaign columns, as "
                            "stiffness diagnose --strict")


#: The flags that only a campaign's report takes.
_CAMPAIGN_FLAGS = ("validate", "masses", "loss", "seed")


def run_campaign(args: argparse.Namespace) -> int:
    """``stiffness report CAMPAIGN --out DIR``: ``stiffness diagnose CAMPAIGN --out DIR`` with
    the flags given (its text report on stdout, its folder written whole)."""
    from stiffness.calibration.solver import LOSSES
    from stiffness.cli import diagnose
    from stiffness.elastic.effects import MASSES

    for flag, allowed in (("masses", MASSES), ("loss", LOSSES)):
        value = getattr(args, flag)
        if value is not None and value not in allowed:
            raise StiffnessError(f"--{flag} {value!r}: give one of {', '.join(allowed)}")
    if args.campaign:
        raise StiffnessError("--campaign picks the SK120 report's campaign; for a report of "
                             "your campaign give it alone: stiffness report CAMPAIGN --out DIR")
    if not args.out:
        raise StiffnessError("stiffness report CAMPAIGN needs --out DIR, the folder the "
                             "report is written in")
    words = [str(args.user_campaign), "--out", str(args.out)]
    for flag in _CAMPAIGN_FLAGS:
        value = getattr(args, flag)
        words += [] if value is None else [f"--{flag}", str(value)]
    words += flags.refit_flag_words(args)
    words += ["--quiet"] if args.quiet else []
    parser = argparse.ArgumentParser(prog="stiffness diagnose")
    diagnose.configure_parser(parser)
    return diagnose.run(parser.parse_args(words))


def command_line(args: argparse.Namespace) -> str:
    """The command that reproduces this run (recorded in the report's provenance)."""
    words = ["stiffness", "report", "--out", str(args.out)]
    if args.campaign:
        words += ["--campaign", str(args.campaign)]
    return shlex.join(words)


def run(args: argparse.Namespace) -> int:
    """Build and write the report (the SK120 one, or ``CAMPAIGN``'s: :func:`run_campaign`),
    then print a short summary."""
    if args.user_campaign:
        return run_campaign(args)
    given = [f"--{flag}" for flag in _CAMPAIGN_FLAGS if getattr(args, flag) is not None]
    given += flags.refit_flag_words(args)
    if given:
        raise StiffnessError(f"{', '.join(given)} take(s) a campaign: stiffness report "
                             "CAMPAIGN --out DIR (the SK120 report has no such option)")
    args.out = args.out or SK120_OUT
    out = output_folder(args.out, create=False)  # before the work: a bad --out fails at once
    check_folder_name(out)
    scene: dict[str, str] = {}
    with background_independent_parts() as collect:
        from stiffness.papers.report import build_report

        def independent() -> dict:
            parts = collect()
            scene["html"] = parts["scene"]
            return parts

        summary, figures = build_report(args.campaign, quiet=args.quiet,
                                        command=command_line(args), independent=independent)
    from stiffness.papers.report import write_report
    from stiffness.papers.report_page import verdict_counts

    write_report(out, summary, figures, scene=lambda path: atomic_write(path, scene["html"]))
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
