"""The one flag layer every command shares: robot, configuration, load, stiffness, output.

A command declares its flags with the ``add_*`` functions and reads them back with
:func:`robot_from_args`, :func:`coordinates_from_args` and :func:`parse_list`, so that the same
flag has the same name, unit and syntax in every command:

* ``--robot``, ``--frame``, ``--target-offset x,y,z`` (m, the frame's axes),
  ``--compliant-joints a,b,...``, ``--loops FILE`` (a loop declaration instead of the sidecar)
  and ``--fixed-base`` (fix a floating or planar base; docs/robot-files.md);
* ``--q v1,v2,...`` (one value per coordinate, rad or m) or ``--q name=value,...`` (joint names,
  or ``q1``, ``q2``...; the coordinates not named keep the robot's default configuration, zero
  when it has none), ``--deg`` for angles in degrees;
* ``--wrench fx,fy,fz[,mx,my,mz]`` (N, N.m, base axes; ``--load`` is an alias);
* ``--kq k1,k2,...`` (N.m/rad, N/m prismatic);
* ``--seed N`` (a non-negative integer, default 0);
* ``--json`` (one JSON object on stdout) and ``--quiet`` (no progress, no echo of the inputs).

Every number a flag takes is written as a campaign's CSV cells are (``1000``, ``1e3``; not
``1_000``, which Python would read as 1000; :func:`stiffness.units.plain_float`), finite and
within +-1e12 in its unit (``parse_list`` for lists, ``number`` for one-number flags,
``integer`` for counts), the bound of a campaign's CSV cells: beyond it a value is no
coordinate, load or stiffness, and the arithmetic that follows would overflow.

Values that start with a minus sign are taken in the natural form (``--q -35,-60,95``,
``--wrench -10,0,-100``) by :class:`ArgumentParser`, which the ``stiffness`` dispatcher uses;
plain :mod:`argparse` would read them as unknown options.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import sys
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

import numpy as np

from stiffness.errors import FlagValueWarning, OutputError, StiffnessError
from stiffness.files import output_folder
from stiffness.units import FLAG_NUMBER, MAX_CELL, NumberSpellingError, plain_float, plain_int

if TYPE_CHECKING:  # the robot layers load Pinocchio: imported when a flag is read, not declared
    from stiffness.calibration.pose_model import Marker
    from stiffness.elastic.model import ElasticModel
    from stiffness.robot.robot import Robot

#: A command-line token that is a value starting with a minus sign (a negative number or a list
#: of numbers), never an option: ``-35``, ``-.5``, ``-1e3,2``, ``-inf``.
_NEGATIVE_VALUE = re.compile(r"^-(?:\.?\d|inf\b|nan\b)", re.IGNORECASE)
#: ``--q`` items of the form ``name=value``.
_PAIR = re.compile(r"^\s*([^=\s][^=]*?)\s*=\s*(\S.*?)\s*$")

#: Where a value came from, as echoed by the commands.
FROM_FLAG = "flag"
FROM_MODEL = "model file"
FROM_ROBOT = "robot default"


class ArgumentParser(argparse.ArgumentParser):
    """An :class:`argparse.ArgumentParser` that takes option values starting with a minus sign.

    ``--q -35,-60,95`` is rewritten ``--q=-35,-60,95`` before parsing, for every option that
    takes one value (abbreviations included), when the next token is a negative number or a
    number list. Usage errors print on one line (:meth:`error`). Sub-parsers made with
    ``add_subparsers`` inherit the class; ``commands`` maps each command name to its
    sub-parser (filled by :func:`stiffness.cli.main.build_parser`).
    """

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.commands: dict[str, ArgumentParser] = {}

    # typeshed declares this method as three overloads on the namespace's type; one signature
    # that accepts what they accept and returns what argparse returns overrides them all
    def parse_known_args(  # type: ignore[override]
            self, args: Sequence[str] | None = None,
            namespace: argparse.Namespace | None = None) -> tuple[argparse.Namespace, list[str]]:
        """Parse like argparse, after joining negative values to their options."""
        args = sys.argv[1:] if args is None else list(args)
        return super().parse_known_args(join_negative_values(self, args), namespace)

    def error(self, message: str) -> NoReturn:
        """A usage error (an unknown or missing flag, a bad choice) on one line, with where
        the valid flags are listed; exit code 2, as argparse's."""
        self.exit(2, f"{self.prog}: error: {message}; see '{self.prog} --help'\n")


def join_negative_values(parser: argparse.ArgumentParser, argv: Sequence[str]) -> list[str]:
    """``argv`` with ``--flag -1,2`` joined into ``--flag=-1,2`` for ``parser``'s one-value flags.

    Tokens after ``--`` are left alone; so are values that look like options.
    """
    options = {s: a for a in parser._actions for s in a.option_strings}
    out: list[str] = []
    argv = list(argv)
    i = 0
    while i < len(argv):
        token = argv[i]
        if token == "--":
            out.extend(argv[i:])
            break
        action = options.get(token)
        if action is None and token.startswith("--") and "=" not in token and parser.allow_abbrev:
            matches = {options[s] for s in options if s.startswith(token)}
            action = matches.pop() if len(matches) == 1 else None
        if (action is not None and action.nargs in (None, 1) and i + 1 < len(argv)
                and _NEGATIVE_VALUE.match(argv[i + 1]) and argv[i + 1] not in options):
            out.append(f"{token}={argv[i + 1]}")
            i += 2
            continue
        out.append(token)
        i += 1
    return out


def parse_list(text: str, flag: str) -> list[float]:
    """Comma-separated numbers of a flag, e.g. ``"1,2.5,-3"``, each written as a CSV cell's
    (:func:`~stiffness.units.plain_float`: no ``1_000``).

    Raises
    ------
    StiffnessError
        If an item is not a plain number, or not a finite number within
        +-:data:`~stiffness.units.MAX_CELL` (the bound of a campaign's CSV cells: beyond any
        coordinate, load or stiffness, and small enough for the arithmetic that follows).
    """
    values = []
    for item in text.split(","):
        try:
            value = plain_float(item, FLAG_NUMBER)
        except ValueError as exc:
            raise StiffnessError(f"{flag} takes comma-separated numbers; {exc}") from None
        if not np.isfinite(value):
            raise StiffnessError(f"{flag} values must be finite, got {item.strip()!r}")
        if abs(value) > MAX_CELL:
            raise StiffnessError(f"{flag} value {item.strip()} is beyond +-{MAX_CELL:.0e}, "
                                 "larger than any coordinate, load or stiffness (and too large "
                                 "for the arithmetic); check the value and its unit")
        values.append(value + 0.0)  # -0 is 0 (as number does)
    return values


def number(text: str) -> float:
    """An ``argparse`` type for one-number flags (``--noise``, ``--max-force``, ``--fps``...):
    a finite number within +-:data:`~stiffness.units.MAX_CELL`, as :func:`parse_list` checks
    each item of a list flag (the parser's usage error, one line, otherwise)."""
    try:
        value = plain_float(text, FLAG_NUMBER)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    if abs(value) > MAX_CELL:
        raise argparse.ArgumentTypeError(f"{text} is beyond +-{MAX_CELL:.0e}, larger than any "
                                         "setting (and too large for the arithmetic)")
    return value + 0.0  # -0 is 0: NumPy refuses a noise scale of -0.0 (a ValueError)


def integer(text: str) -> int:
    """An ``argparse`` type for integer flags (``--configs``, ``--workers``, ``--port``...):
    optional sign and decimal digits (:func:`~stiffness.units.plain_int`: no ``1_000``, which
    ``int`` reads as 1000; the parser's usage error, one line, otherwise)."""
    try:
        return plain_int(text, FLAG_NUMBER)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def require_at_least_one(value: int | None, flag: str) -> None:
    """Refuse a count flag below 1 (``None``: the flag was not given).

    Raises
    ------
    StiffnessError
        If ``value`` is below 1.
    """
    if value is not None and value < 1:
        raise StiffnessError(f"{flag} must be at least 1, got {value}")


def check_noise_std(value: float | None, flag: str, unit: str, *, zero: bool = False) -> None:
    """Refuse a noise std flag that is not a finite positive number (or zero when ``zero``),
    naming the value and the unit the user gave (``None``: the flag was not given).

    Raises
    ------
    StiffnessError
        If ``value`` is NaN, infinite, negative, or zero without ``zero``.
    """
    if value is None:
        return
    if not (math.isfinite(value) and (value >= 0 if zero else value > 0)):
        bound = ">= 0" if zero else "> 0"
        raise StiffnessError(f"{flag} must be a finite standard deviation {bound}, in {unit}; "
                             f"got {value:g}")


#: Range (m) of a deflection rig's noise std: finer than 10 nm no rig measures a robot's
#: deflection, coarser than 1 cm none is worth calibrating with.
RIG_NOISE_RANGE_M = (1e-8, 1e-2)


def warn_rig_noise(value: float | None, flag: str, unit: str, to_si: float) -> None:
    """Warn (:class:`~stiffness.errors.FlagValueWarning`, one line) when a length noise std
    flag given in the files' length unit ``unit`` (``to_si`` m each) is outside
    :data:`RIG_NOISE_RANGE_M`: ``--noise 2e-6`` in mm is 2 nm, likely meant in m. ``None``
    (not given) and 0 (noise-free) are not warned about."""
    if not value:
        return
    metres = value * to_si
    low, high = RIG_NOISE_RANGE_M
    if low <= metres <= high:
        return
    where = ("below 10 nm, finer than any rig measures" if metres < low
             else "above 1 cm, coarser than any rig worth calibrating with")
    warnings.warn(f"{flag} {value:g} {unit} is {metres:.3g} m, {where}: {flag} is in the files' "
                  f"length unit (here {unit}); give it in {unit} (5 um is "
                  f"{5e-6 / to_si:g} {unit})", FlagValueWarning, stacklevel=2)


#: How ``--kq`` is written, for the one check's message
#: (:func:`~stiffness.mechanics.defaults.joint_stiffnesses`).
KQ_FORM = "comma-separated in their order, or choose the joints with --compliant-joints"


def stiffness_required(robot: Robot) -> StiffnessError:
    """The error of a command that needs ``--kq`` for a robot with no stiffness of its own."""
    return StiffnessError(
        f"--kq is required for {robot.title}: one stiffness per compliant joint "
        f"({', '.join(robot.compliant_joints)}), N.m/rad (N/m prismatic)")


def parse_kq(text: str, robot: Robot) -> list[float]:
    """``--kq``: one stiffness per compliant joint of ``robot`` (N.m/rad, N/m prismatic), its
    numbers read as every flag's (:func:`parse_list`) and checked by the one check of joint
    springs (:func:`~stiffness.mechanics.defaults.joint_stiffnesses`).

    Raises
    ------
    StiffnessError
        If an item is not a plain finite number (:func:`parse_list`), or the values are not
        one positive stiffness per compliant joint: one line naming the joints and the fix.
    """
    from stiffness.mechanics.defaults import joint_stiffnesses

    return joint_stiffnesses(robot, parse_list(text, "--kq"), "--kq", KQ_FORM).tolist()


def parse_names(text: str | None) -> list[str] | None:
    """Comma-separated names (``--compliant-joints a,b``), or None when not given."""
    if text is None:
        return None
    return [name.strip() for name in text.split(",") if name.strip()]


def parse_markers(texts: list[str] | None) -> tuple[list[Marker], dict[str, np.ndarray]]:
    """The ``--marker NAME=FRAME[@X,Y,Z[@RX,RY,RZ]]`` flags (``campaign import``,
    ``simulate``): the markers (offsets in the files' length unit) and the rotation vectors
    given (the files' angle unit), by name."""
    from stiffness.calibration.pose_model import Marker

    out, turns = [], {}
    for text in texts or []:
        name, sep, rest = text.partition("=")
        frame, _, placement = rest.partition("@")
        offset, _, turn = placement.partition("@")
        if not sep or not name.strip() or not frame.strip():
            raise StiffnessError(f"--marker {text!r}: write NAME=FRAME, NAME=FRAME@X,Y,Z or "
                                 "NAME=FRAME@X,Y,Z@RX,RY,RZ")
        parsed = {}
        for what, cells in (("offset", offset), ("rotation", turn)):
            xyz = parse_list(cells, f"--marker {what}") if cells else [0.0, 0.0, 0.0]
            if len(xyz) != 3 or not np.all(np.isfinite(xyz)):
                raise StiffnessError(f"--marker {text!r}: the {what} is three finite numbers")
            parsed[what] = np.array(xyz, dtype=float)
        if turn:
            turns[name.strip()] = parsed["rotation"]
        out.append(Marker(name.strip(), frame.strip(), parsed["offset"]))
    return out, turns


# --- declaring flags -------------------------------------------------------------------------

def add_robot_flags(parser: argparse.ArgumentParser, *, required: bool = False,
                    robot_help: str | None = None) -> None:
    """``--robot``, ``--frame``, ``--target-offset`` (m), ``--compliant-joints``, ``--loops``
    and ``--fixed-base``."""
    parser.add_argument(
        "--robot", required=required,
        help=robot_help or "shipped robot (sk120, griffis-duffy, hexapod), example-robot-data "
                           "name (ur5, panda...), URDF path or robot.toml (a URDF or a DH "
                           "table)")
    parser.add_argument("--frame", help="frame carrying the target (default: the robot's own)")
    parser.add_argument("--target-offset", metavar="X,Y,Z",
                        help="target in the frame's axes, m (default: the robot's own, else 0)")
    parser.add_argument("--compliant-joints", metavar="J1,J2,...",
                        help="comma-separated joints modelled as springs (default: the robot's "
                             "own, else the joints of the chain from the base to the "
                             "target, which move it: not a head, wheels or fingers)")
    parser.add_argument("--loops", metavar="FILE",
                        help="loop declaration (Gepetto's Extended-URDF YAML) instead of the "
                             "one beside the URDF (<name>.loops.yaml, <name>.yaml, robot.yaml)")
    parser.add_argument("--fixed-base", action="store_true",
                        help="fix a floating or planar base at its neutral placement")


def add_configuration_flags(parser: argparse.ArgumentParser, q_help: str | None = None) -> None:
    """``--q`` (values in coordinate order, or name=value pairs) and ``--deg``."""
    parser.add_argument(
        "--q", metavar="Q1,Q2,...|NAME=V,...",
        help=q_help or "joint coordinates, rad (m prismatic): one value per coordinate in the "
                       "robot's order (for closed loops the independent joints suffice), or "
                       "name=value pairs (joint names or q1, q2...; coordinates not named keep "
                       "the robot's default configuration, else 0)")
    parser.add_argument("--deg", action="store_true",
                        help="angles of --q (and of other coordinate flags) in degrees")


def add_wrench_flag(parser: argparse.ArgumentParser, *, repeat: bool = False,
                    help: str | None = None) -> None:
    """``--wrench fx,fy,fz[,mx,my,mz]`` (alias ``--load``): dead load at the target, base axes."""
    text = help or ("dead load at the target, base axes: fx,fy,fz (N) or fx,fy,fz,mx,my,mz "
                    "(N, N.m); --load is an alias")
    if repeat:
        parser.add_argument("--wrench", "--load", dest="wrench", action="append", default=[],
                            metavar="FX,FY,FZ[,MX,MY,MZ]", help=text)
    else:
        parser.add_argument("--wrench", "--load", dest="wrench", metavar="FX,FY,FZ[,MX,MY,MZ]",
                            help=text)


def add_stiffness_flag(parser: argparse.ArgumentParser, help: str | None = None) -> None:
    """``--kq``: one joint stiffness per compliant joint (N.m/rad, N/m prismatic)."""
    parser.add_argument("--kq", metavar="K1,K2,...",
                        help=help or "joint stiffness per compliant joint, in their order, "
                                     "N.m/rad (N/m prismatic); default the robot's own")


def add_seed_flag(parser: argparse.ArgumentParser, help: str) -> None:
    """``--seed``: a non-negative integer (NumPy's generators take no other), default 0."""
    parser.add_argument("--seed", type=_seed, default=0, help=help)


def _seed(text: str) -> int:
    """The ``--seed`` value (an argparse ``type``: refused in argparse's one-line form)."""
    try:
        value = plain_int(text, FLAG_NUMBER)
    except ValueError as exc:
        if isinstance(exc, NumberSpellingError):
            raise argparse.ArgumentTypeError(str(exc)) from None
        value = None
    if value is None or value < 0:
        raise argparse.ArgumentTypeError(f"must be a non-negative integer, got {text!r}")
    return value


def add_output_flags(parser: argparse.ArgumentParser, json_help: str | None = None,
                     quiet_help: str | None = None) -> None:
    """``--json`` and ``--quiet``."""
    parser.add_argument("--json", action="store_true",
                        help=json_help or "print one JSON object (SI) and nothing else on stdout")
    parser.add_argument("--quiet", action="store_true",
                        help=quiet_help or "no progress and no echo of the inputs")


def add_model_flags(parser: argparse.ArgumentParser) -> None:
    """``--model`` with the robot and stiffness flags, for the commands driven by a model file
    (``compensate``, ``posture``, ``track``; read back with :func:`model_from_args`)."""
    parser.add_argument("--model", metavar="M.json",
                        help="model file: identified-model.json (`stiffness identify`) or "
                             "final-model.json (`stiffness diagnose`, with its effects)")
    add_robot_flags(parser, robot_help="shipped robot, example-robot-data name, URDF path or "
                                       "robot.toml, instead of --model (or checked against "
                                       "it); with --model, --frame and --target-offset move "
                                       "the target")
    add_stiffness_flag(parser, help="joint stiffness per compliant joint, N.m/rad (N/m "
                                    "prismatic), when no --model is given; default the robot's")


def add_refit_flags(parser: argparse.ArgumentParser) -> None:
    """``--refit-frame`` and ``--refit-markers`` (``validate``, ``diagnose --validate``): the
    families fitted to a pose validation campaign before a model is judged on it (read by
    :func:`refit_from_args`)."""
    parser.add_argument("--refit-frame", action="store_true",
                        help="pose campaigns: fit the measuring frame (6 parameters) to the "
                        "validation campaign before judging a model on it, the rest of the "
                        "model as it is: a campaign of another day or with the tracker moved")
    parser.add_argument("--refit-markers", action="store_true",
                        help="pose campaigns: fit the markers' offsets to the validation "
                        "campaign too (a marker plate mounted again); implies --refit-frame")


def refit_from_args(args: argparse.Namespace) -> tuple[str, ...]:
    """The ``refit`` of :func:`add_refit_flags`' flags: ``("frame", "markers")``,
    ``("frame",)`` or ``()``."""
    return (("frame", "markers") if args.refit_markers
            else ("frame",) if args.refit_frame else ())


def refit_flag_words(args: argparse.Namespace) -> list[str]:
    """The one flag of :func:`add_refit_flags` that says what was given
    (``--refit-markers`` implies ``--refit-frame``), as a command line repeats it; ``[]``:
    neither."""
    return [f"--refit-{f}" for f in refit_from_args(args)[-1:]]


def add_strict_flag(parser: argparse.ArgumentParser) -> None:
    """``--strict``: refuse campaign CSV columns no reader knows (else ignored with a
    warning; :class:`stiffness.errors.UnknownColumnWarning`)."""
    parser.add_argument("--strict", action="store_true",
                        help="refuse campaign CSV columns that are not campaign columns "
                             "(default: ignored with a warning listing them)")


# --- reading flags ---------------------------------------------------------------------------

@dataclass
class RobotFlags:
    """What the robot flags resolve to (None where neither a flag nor a fallback gives it)."""

    source: str | None
    frame: str | None
    target_offset: list[float] | None
    compliant_joints: list[str] | None
    #: another flag that can name the robot (``--model``), for the error when none does
    alternative: str | None = None
    #: ``--loops FILE`` and ``--fixed-base``
    loops: str | None = None
    fixed_base: bool = False

    def load(self) -> Robot:
        """The robot (:func:`stiffness.robot.robot.load_robot`)."""
        from stiffness.robot.robot import load_robot

        if self.source is None:
            raise StiffnessError(
                "--robot is required" + (f" (or {self.alternative})" if self.alternative else "")
                + ": a shipped robot, an example-robot-data name, a URDF path or a robot.toml")
        return load_robot(self.source, frame=self.frame, target_offset=self.target_offset,
                          compliant_joints=self.compliant_joints, loops=self.loops,
                          fixed_base=self.fixed_base)


def target_offset_from_args(args: argparse.Namespace) -> list[float] | None:
    """``--target-offset`` in m (three values), or None."""
    text = getattr(args, "target_offset", None)
    if text is None:
        return None
    offset = parse_list(text, "--target-offset")
    if len(offset) != 3:
        raise StiffnessError(f"--target-offset takes three lengths x,y,z in m, got {len(offset)}")
    return offset


def robot_flags(args: argparse.Namespace, fallback: Any = None) -> RobotFlags:
    """The robot flags of ``args``; ``fallback`` fills what they leave out.

    ``fallback`` is anything with ``source``, ``frame``, ``target_offset_m`` and
    ``compliant_joints`` attributes, and optionally ``loops`` and ``fixed_base`` (a model
    file, which loads its robot with them), or None.
    """
    joints = parse_names(getattr(args, "compliant_joints", None))
    if joints == []:
        raise StiffnessError("--compliant-joints names no joint; give at least one (j1,j2,...), "
                             "or leave the flag out for the robot's own springs")
    flags = RobotFlags(getattr(args, "robot", None), getattr(args, "frame", None),
                       target_offset_from_args(args), joints,
                       "--model FILE from `stiffness identify`" if hasattr(args, "model")
                       else None, getattr(args, "loops", None),
                       bool(getattr(args, "fixed_base", False)))
    if fallback is not None:
        flags.source = flags.source or fallback.source
        flags.frame = flags.frame or fallback.frame
        if flags.target_offset is None:
            flags.target_offset = [float(v) for v in fallback.target_offset_m]
        if flags.compliant_joints is None:
            flags.compliant_joints = list(fallback.compliant_joints)
        flags.loops = flags.loops or getattr(fallback, "loops", None)
        flags.fixed_base = flags.fixed_base or bool(getattr(fallback, "fixed_base", False))
    return flags


def robot_from_args(args: argparse.Namespace, fallback: object | None = None
                    ) -> tuple[Robot, list[str] | None, list[float] | None]:
    """The robot of ``--robot``, ``--frame``, ``--target-offset`` (m) and ``--compliant-joints``.

    Returns the robot and the compliant joints and offset that were given (None where not),
    with ``fallback`` (see :func:`robot_flags`) filling what the flags leave out.
    """
    flags = robot_flags(args, fallback)
    return flags.load(), flags.compliant_joints, flags.target_offset


def check_outputs(*paths: str | None, inputs: dict[str, str | None] | None = None) -> None:
    """Refuse, before any work, output files that cannot be written (a folder in the way, a
    read-only or missing-and-uncreatable folder) or that are one of the command's ``inputs``
    (by flag: ``--out path.csv`` beside ``--path path.csv`` would replace the path read):
    one-line :class:`OutputError`."""
    for name in paths:
        if name is None:
            continue
        target = Path(name)
        if target.is_dir():
            raise OutputError(f"cannot write {target}: it is a folder; give a file name",
                              path=target)
        output_folder(target.parent, create=False)
        for flag, given in (inputs or {}).items():
            if given is not None and target.is_file() and Path(given).is_file() \
                    and os.path.samefile(target, given):
                raise OutputError(f"cannot write {target}: it is the {flag} file this command "
                                  "reads, which it would replace; give another output file "
                                  "name", path=target)


def model_from_args(args: argparse.Namespace, *outputs: str | None) -> ElasticModel:
    """The elastic model of a command the :func:`add_model_flags` declare: the ``--model``
    file's (checked against ``--robot``), or the robot flags' with ``--kq`` (or the robot's
    own springs); the ``outputs`` files are checked writable first (:func:`check_outputs`), so
    a bad output fails before the model is built.

    Raises
    ------
    StiffnessError
        Neither ``--model`` nor ``--robot``, ``--kq`` or ``--compliant-joints`` beside
        ``--model``, a ``--robot`` that is not the model file's, a missing ``--kq``.
    """
    from stiffness.elastic.file_model import elastic_model_of
    from stiffness.elastic.model import ElasticModel
    from stiffness.elastic.model_file import read_model_file
    from stiffness.mechanics.defaults import default_stiffness
    from stiffness.mechanics.formulation import joint_stiffness

    if args.model is None and args.robot is None:
        raise StiffnessError("--model M.json is required (the identified or diagnosed model), "
                             "or --robot R with --kq")
    check_outputs(*outputs, inputs={"--robot": args.robot, "--model": args.model,
                                    "--path": getattr(args, "path", None)})
    if args.model is not None:
        for flag, value in (("--kq", args.kq), ("--compliant-joints", args.compliant_joints)):
            if value is not None:
                raise StiffnessError(f"{flag} conflicts with --model, which brings the springs; "
                                     f"drop {flag} (or --model)")
        model = read_model_file(args.model)
        if args.robot is not None:
            model.check_robot(args.robot)
        em = elastic_model_of(model, args.frame, target_offset_from_args(args))
        em.source = str(args.model)
        return em
    robot, _, _ = robot_from_args(args)
    kq = parse_kq(args.kq, robot) if args.kq is not None else default_stiffness(robot)
    if kq is None:
        raise stiffness_required(robot)
    return ElasticModel.joint_springs(robot, np.diag(joint_stiffness(kq, robot.n_compliant)))


def _is_revolute(robot: Robot, joint: str) -> bool:
    return not robot.is_prismatic(joint)


def coordinates_from_args(robot: Robot, args: argparse.Namespace, *, required: bool = True,
                          flag: str = "--q") -> np.ndarray:
    """Coordinates (rad, m) of ``--q``/``--deg``, or the robot's reference configuration.

    ``--q`` is either one value per coordinate (``robot.coordinate_joints`` order; for a closed
    loop also one per degree of freedom of the model, of which the independent ones are kept),
    one value per joint outside the end-effector branch (``robot.chain_joints``: an end
    effector's fingers keep their reference value), or ``name=value`` pairs: joint names or ``q1``,
    ``q2``...; the coordinates not named keep the reference configuration
    (:func:`~stiffness.mechanics.defaults.reference_configuration`), or 0 when it has none.
    ``--deg`` converts the revolute ones from degrees. Coordinates beyond their joint limits
    are warned about, by joint.

    Parameters
    ----------
    required
        When ``--q`` is absent and the robot has no reference configuration (closed loops
        without shipped coordinates): raise if True, else zero.

    Raises
    ------
    StiffnessError
        On a malformed value or a wrong count; :class:`UnknownJointError` on an unknown name.
    """
    from stiffness.mechanics.ik import outside_limits

    values = _coordinates_of_flag(robot, args, required, flag)
    beyond = outside_limits(robot, values)
    if beyond:
        revolute = np.array([_is_revolute(robot, j) for j in robot.coordinate_joints])
        hint = ""
        if not getattr(args, "deg", False) and revolute.any() and not outside_limits(
                robot, np.where(revolute, np.deg2rad(values), values)):
            hint = f" (the values look like degrees: add --deg to {flag})"
        warnings.warn(f"{robot.title}: the configuration is outside the joint limits: "
                      f"{'; '.join(beyond)}{hint}", stacklevel=2)
    return values


def _coordinates_of_flag(robot: Robot, args: argparse.Namespace, required: bool,
                         flag: str) -> np.ndarray:
    """:func:`coordinates_from_args` before the limit check."""
    from stiffness.mechanics.defaults import assembly_coordinates, default_coordinates
    from stiffness.robot.robot import coordinate_index

    text = getattr(args, flag.lstrip("-").replace("-", "_"), None)
    if text is None:
        if required and default_coordinates(robot) is None:
            raise StiffnessError(
                f"{flag} is required for {robot.title}: give {robot.n_coordinates} joint values "
                f"({', '.join(robot.coordinate_joints)}) or name=value pairs")
        return assembly_coordinates(robot)  # a loop's assembly when zero does not close
    deg = bool(getattr(args, "deg", False))
    base = assembly_coordinates(robot).copy()
    items = [item for item in text.split(",") if item.strip()]
    pairs = [_PAIR.match(item) for item in items]
    if any(pairs):
        if not all(pairs):
            raise StiffnessError(
                f"{flag} mixes name=value pairs and bare values ({text!r}): give all values in "
                "order, or name=value for each")
        seen: set[int] = set()
        for match in (m for m in pairs if m is not None):
            index = coordinate_index(robot, match.group(1), flag)
            if index in seen:
                raise StiffnessError(f"{flag} names {robot.coordinate_joints[index]} twice; "
                                     "give each coordinate once")
            seen.add(index)
            value = parse_list(match.group(2), flag)
            if len(value) != 1:
                raise StiffnessError(f"{flag} {match.group(0).strip()!r}: one value per name")
            joint = robot.coordinate_joints[index]
            base[index] = np.deg2rad(value[0]) if deg and _is_revolute(robot, joint) \
                else value[0]
        return base
    values = np.array(parse_list(text, flag))
    names = _names_of_values(robot, values.shape[0], flag)
    for name, value in zip(names, values, strict=True):
        if name not in robot.coordinate_joints:
            continue  # a model joint that is no coordinate (a passive loop joint)
        value = np.deg2rad(value) if deg and _is_revolute(robot, name) else value
        base[robot.coordinate_joints.index(name)] = value
    return base


def _names_of_values(robot: Robot, count: int, flag: str) -> list[str]:
    """The joints ``count`` bare ``--q`` values are for: the coordinates, those outside the
    end-effector branch, or every degree of freedom of the model in model order."""
    model = robot.model
    if count == robot.n_coordinates:
        return list(robot.coordinate_joints)
    if count == len(robot.chain_joints):
        return list(robot.chain_joints)
    if count == model.nv:
        return [model.names[j] for j in range(1, model.njoints) for _ in range(model.joints[j].nv)]
    chain = "" if not robot.branch_joints else (
        f", or {len(robot.chain_joints)} without the end-effector branch "
        f"({', '.join(robot.chain_joints)})")
    raise StiffnessError(
        f"{flag} needs {robot.n_coordinates} values for {robot.title} "
        f"({', '.join(robot.coordinate_joints)}){chain}, got {count}; or name=value pairs")


def coordinates_source(robot: Robot, args: argparse.Namespace, flag: str = "--q") -> str:
    """Where :func:`coordinates_from_args` took the coordinates from (for the echo)."""
    from stiffness.mechanics.defaults import reference_configuration

    text = getattr(args, flag.lstrip("-").replace("-", "_"), None)
    reference = reference_configuration(robot)
    rest = reference.source if reference is not None else (
        "zero" if robot.loop.is_open_chain else "the assembly found near the zero pose")
    if text is None:
        return rest if reference is not None else f"{rest} (no default)"
    items = [item for item in text.split(",") if item.strip()]
    if "=" in text and len(items) < robot.n_coordinates:
        if reference is not None:  # of the joints it moved into their limits, the unnamed
            named = _named_coordinates(robot, items, flag)
            rest = reference.source_for([j for j in robot.coordinate_joints if j not in named])
        return f"{FROM_FLAG} {flag} (coordinates not named: {rest})"
    if robot.branch_joints and len(items) == len(robot.chain_joints):
        return f"{FROM_FLAG} {flag} ({', '.join(robot.branch_joints)}: {rest})"
    return f"{FROM_FLAG} {flag}"


def _named_coordinates(robot: Robot, items: list[str], flag: str) -> set[str]:
    """The coordinates ``name=value`` items of ``flag`` name (joint names or ``q1``...;
    items that are no such pair are left out: :func:`coordinates_from_args` refuses them)."""
    from stiffness.robot.robot import coordinate_index

    pairs = [_PAIR.match(item) for item in items]
    return {robot.coordinate_joints[coordinate_index(robot, m.group(1), flag)]
            for m in pairs if m is not None}


def format_named(names: Sequence[str], values: Sequence[float], digits: int = 6) -> str:
    """``name=value`` pairs, comma-separated (the form ``--q`` takes back)."""
    return ",".join(f"{n}={v:.{digits}g}" for n, v in zip(names, values, strict=True))


#: Echoes of more values than this are summarised (:func:`format_named_summary`).
LONG_ECHO = 12


def format_named_summary(names: Sequence[str], values: Sequence[float], keep: Sequence[str]
                         ) -> str:
    """:func:`format_named`, or past :data:`LONG_ECHO` values the ``keep`` names and the
    non-zero values, then how many more are zero (a robot's head, wheels and fingers)."""
    if len(names) <= LONG_ECHO:
        return format_named(names, values)
    shown = [(n, v) for n, v in zip(names, values, strict=True) if n in keep or v != 0]
    zero = [n for n in names if n not in {s for s, _ in shown}]
    text = format_named([n for n, _ in shown], [v for _, v in shown])
    if zero:
        text += (f" (and {len(zero)} more = 0: {', '.join(zero[:3])}"
                 f"{', ...' if len(zero) > 3 else ''})")
    return text
