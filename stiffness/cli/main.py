"""The ``stiffness`` command line: a thin dispatcher over one module per command.

Each command module provides ``configure_parser(parser)`` and ``run(args) -> int``; it is
imported only when its command runs, so ``stiffness --help`` stays fast.
"""

from __future__ import annotations

import difflib
import importlib
import os
import sys
import warnings
from typing import NoReturn

from stiffness import __version__
from stiffness.cli.flags import ArgumentParser
from stiffness.errors import (
    DataFileNote,
    RobotFileNote,
    StiffnessError,
    UnknownColumnWarning,
)

#: command name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "kx": ("stiffness.cli.kx", "Cartesian stiffness, K_C and compliance at one configuration"),
    "check-jacobian": (
        "stiffness.cli.check_jacobian",
        "compare the printed Appendix I Jacobian and its K_C with Pinocchio's SK120",
    ),
    "identify": ("stiffness.cli.identify", "identify joint stiffness from a campaign"),
    "report": ("stiffness.cli.report", "the SK120 paper-reproduction report (the main job), or a "
               "campaign's report"),
    "diagnose": ("stiffness.cli.diagnose",
                 "find and name what a model misses against a campaign's measurements"),
    "validate": ("stiffness.cli.validate",
                 "a model file evaluated on another campaign, without refitting"),
    "simulate": ("stiffness.cli.simulate", "write a synthetic campaign with hidden effects"),
    "campaign": ("stiffness.cli.campaign",
                 "campaign import: a campaign folder from the CSV files a rig writes"),
    "design": ("stiffness.cli.design",
               "choose the poses and loads to measure (experiment design)"),
    "view": ("stiffness.cli.view", "stiffness ellipsoids in the browser (meshcat)"),
    "scan": ("stiffness.cli.scan", "stiffness and definiteness maps over a workspace"),
    "compensate": ("stiffness.cli.compensate",
                   "joint commands that cancel the deflection along a path"),
    "track": ("stiffness.cli.track",
              "a path tracked in MuJoCo, raw and with the compensator's commands"),
    "posture": ("stiffness.cli.posture",
                "the stiffest posture about the tool axis along a path"),
    "robot": ("stiffness.cli.robot",
              "robot files: export the loaded robot as a URDF or a MuJoCo model (MJCF)"),
}


def build_parser(only: str | None = None) -> ArgumentParser:
    """Argument parser; configures the subcommand ``only`` (all if None)."""
    parser = ArgumentParser(
        prog="stiffness",
        description="Elastostatics of robot manipulators (SI units: m, N, rad, N.m/rad).",
    )
    parser.add_argument("--version", action="version", version=f"stiffness {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        parser.commands[name] = p
        if only is None or only == name:
            importlib.import_module(module).configure_parser(p)
    return parser


def _one_line_warning(message, category, filename, lineno, line=None) -> str:
    """Warnings on the command line: one line each, no source excerpt (a note, which reports
    what was done rather than a doubt, as ``note``)."""
    word = "note" if issubclass(category, DataFileNote | RobotFileNote) else "warning"
    return f"stiffness: {word}: {message}\n"


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``stiffness`` console script.

    Warnings print on one line while it runs; the caller's warning format is restored after
    (``main`` is also called from Python: tests, notebooks).
    """
    previous = warnings.formatwarning
    warnings.formatwarning = _one_line_warning
    try:
        return _run(argv)
    finally:
        warnings.formatwarning = previous


def _run(argv: list[str] | None) -> int:
    """:func:`main` with the one-line warning format in place."""
    argv = sys.argv[1:] if argv is None else argv
    command = next((a for a in argv if not a.startswith("-")), None)
    parser = build_parser(command if command in COMMANDS else None)
    args, unknown = parser.parse_known_args(argv)
    if unknown:
        _unrecognized(parser, args.command, unknown)
    if args.command is None:
        parser.print_help()
        return 2
    module = importlib.import_module(COMMANDS[args.command][0])
    name = " ".join(w for w in (args.command, getattr(args, "robot_command", None),
                                getattr(args, "action", None)) if w)  # robot export
    try:
        with warnings.catch_warnings():
            if getattr(args, "strict", False):
                warnings.simplefilter("error", UnknownColumnWarning)
            if getattr(args, "quiet", False):  # how the robot file was read: not news
                warnings.simplefilter("ignore", RobotFileNote)
            return int(module.run(args) or 0)
    except (StiffnessError, UnknownColumnWarning) as exc:
        print(f"stiffness {name}: error: {_one_line(str(exc))}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # the reader (| head) stopped: not an error of ours
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as exc:  # a file that cannot be read or written (permissions, disk full...)
        where = f" {exc.filename}" if exc.filename else ""
        print(f"stiffness {name}: error: cannot access{where}: "
              f"{exc.strerror or exc}; check the path and its permissions", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"stiffness {name}: interrupted", file=sys.stderr)
        return 130


def _unrecognized(parser: ArgumentParser, command: str | None,
                  unknown: list[str]) -> NoReturn:
    """Exit on arguments no parser took, as the command's usage error (naming the command and
    the closest flags it has) rather than the top-level parser's."""
    if command is not None:
        parser = parser.commands[command]
    options = [s for a in parser._actions for s in a.option_strings]
    close = [match for token in unknown if token.startswith("--")
             for match in difflib.get_close_matches(token.split("=")[0], options, n=1,
                                                    cutoff=0.75)]
    hint = f" (did you mean {', '.join(dict.fromkeys(close))}?)" if close else ""
    parser.error(f"unrecognized arguments: {' '.join(unknown)}{hint}")


def _one_line(text: str) -> str:
    """An error message on one line (a wrapped third-party message is joined)."""
    return " ".join(part.strip() for part in text.splitlines() if part.strip())


if __name__ == "__main__":
    sys.exit(main())
