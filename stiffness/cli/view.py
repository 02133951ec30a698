"""``stiffness view``: a robot, its load and its stiffness ellipsoids in the browser (meshcat).

Examples::

    # a self-contained page that opens offline (no server)
    stiffness view --robot sk120 --export sk120-stiffness.html

    # the live viewer on http://127.0.0.1:<free port>/ : joint sliders, load, formulation
    stiffness view --robot ur5 --frame tool0 --q 0,-1.2,1.5,-0.3,1.57,0 \\
        --wrench 0,0,-200 --kq 3e5,3e5,2e5,4e4,4e4,4e4 --open

    # a sweep of one joint on meshcat's animation timeline, and an ellipsoid field
    stiffness view --robot sk120 --deg --sweep joint2=-20:40:31 --field 300 --export sweep.html

The robot, configuration, load and joint-stiffness flags are those of ``stiffness kx`` (its
parser adds them here); SI units throughout (m, N, rad, N.m/rad; degrees with ``--deg``).
"""

from __future__ import annotations

import argparse
import json
import math
import signal

import numpy as np

from stiffness.cli import flags, kx
from stiffness.elastic.model import ElasticModel
from stiffness.errors import StiffnessError
from stiffness.machining.joint_path import read_joint_path
from stiffness.mechanics.formulation import target_state
from stiffness.robot.robot import Robot, coordinate_index
from stiffness.units import FLAG_NUMBER, plain_int
from stiffness.viewer import (
    LOOPBACK,
    QUANTITIES,
    SHOW_FORMULATIONS,
    StiffnessViewer,
)
from stiffness.viewer.ellipsoid import principal_ellipsoid

#: ``stiffness kx`` flags that have no meaning for the viewer.
_KX_ONLY = {"help", "connection", "twist_order"}
#: Frames of a ``--sweep`` without an explicit count.
DEFAULT_SWEEP_FRAMES = 30


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Flags of ``stiffness view``: those of ``stiffness kx`` plus the viewer's own."""
    shared = argparse.ArgumentParser(add_help=False)
    kx.configure_parser(shared)
    for action in shared._actions:
        if action.dest in _KX_ONLY:
            continue
        if action.dest == "json":
            action.help = "print one JSON object (the page or URL, the inputs) on stdout"
        if action.dest == "quiet":
            action.help = "no echo of the inputs"
        if action.dest == "formulation":
            action.choices, action.default = SHOW_FORMULATIONS, "both"
            action.help = ("both (side by side, default), enhanced (K_theta - K_C, A&S eq. 10) "
                           "or conventional (K_theta, eq. 8)")
        parser._add_action(action)
    parser.add_argument("--quantity", choices=QUANTITIES, default="stiffness",
                        help="draw the stiffness (N/m, default) or the compliance (m/N) "
                             "ellipsoid; radii are proportional to the principal values")
    parser.add_argument("--size", type=flags.number,
                        help="largest ellipsoid radius, m (default: 12%% of the robot's reach)")
    parser.add_argument("--exaggeration", type=flags.number,
                        help="factor applied to the drawn deflection (default: a round number "
                             "that moves the target about 8%% of the reach)")
    parser.add_argument("--sweep", metavar="JOINT=START:STOP[:N]",
                        help="animate N configurations (default 30) moving one joint (name, "
                             "or q1, q2...) from START to STOP (rad, m prismatic; degrees with "
                             "--deg)")
    parser.add_argument("--path", metavar="FILE.csv",
                        help="animate a path: one row of coordinates per frame, comma-separated "
                             "(rad, m prismatic; degrees with --deg), or compensate's path "
                             "file (a header line naming the columns)")
    parser.add_argument("--fps", type=flags.number, default=10.0,
                        help="frames per second of the animation (default 10)")
    parser.add_argument("--field", type=flags.integer, metavar="N",
                        help="ellipsoid field over N random configurations, coloured by the "
                             "smallest principal stiffness")
    parser.add_argument("--field-joints",
                        help="coordinates the field varies, comma-separated (default: all)")
    flags.add_seed_flag(parser, "random seed of the field")
    parser.add_argument("--export", metavar="FILE.html",
                        help="write a self-contained static page (opens offline) and exit")
    parser.add_argument("--host", default=LOOPBACK,
                        help="address of the live server (default 127.0.0.1, this machine "
                             "only; another address exposes the viewer to the network)")
    parser.add_argument("--port", type=flags.integer, default=0,
                        help="web port (default: a free one)")
    parser.add_argument("--open", action="store_true",
                        help="open the live page in the system's browser (does not wait)")
    parser.add_argument("--duration", type=flags.number,
                        help="serve the live viewer this many seconds (default: until Ctrl-C)")


def _revolute(robot: Robot, joint: str) -> bool:
    return not robot.is_prismatic(joint)


def resolve(args: argparse.Namespace, inputs: kx.KxInputs | None = None
            ) -> tuple[Robot, np.ndarray, np.ndarray, np.ndarray]:
    """Robot, coordinates (rad, m), joint stiffness (n, n) and load of the kx flags.

    The same resolution as ``stiffness kx`` (:func:`stiffness.cli.kx.resolve_inputs`):
    shipped robots bring their configuration, springs and load; without ``--wrench`` and a
    shipped load, the load is zero (the unloaded stiffness). ``inputs``: already resolved.
    """
    inputs = inputs or kx.resolve_inputs(args, require_load=False)
    return inputs.robot, inputs.coords, inputs.k_theta, inputs.load


def sweep_path(robot: Robot, coords: np.ndarray, spec: str, deg: bool = False) -> np.ndarray:
    """Rows of coordinates of ``JOINT=START:STOP[:N]``, the other joints at ``coords``.

    Raises
    ------
    StiffnessError
        On a malformed specification or an unknown joint.
    """
    name, sep, bounds = spec.partition("=")
    parts = bounds.split(":")
    if not sep or len(parts) not in (2, 3):
        raise StiffnessError(f"--sweep takes JOINT=START:STOP[:N], got {spec!r}")
    index = coordinate_index(robot, name.strip(), "--sweep")
    name = robot.coordinate_joints[index]
    start, stop = flags.parse_list(",".join(parts[:2]), "--sweep")
    try:
        n = plain_int(parts[2], FLAG_NUMBER) if len(parts) == 3 else DEFAULT_SWEEP_FRAMES
    except ValueError as exc:
        raise StiffnessError(f"--sweep: the frame count must be an integer; {exc}") from None
    if n < 2:
        raise StiffnessError(f"--sweep needs at least 2 frames, got {n}")
    if deg and _revolute(robot, name):
        start, stop = np.deg2rad(start), np.deg2rad(stop)
    rows = np.tile(coords, (n, 1))
    rows[:, index] = np.linspace(start, stop, n)
    return rows


def check_view_flags(args: argparse.Namespace) -> None:
    """Refuse, before any work, viewer settings no page can have: a radius or frame rate that
    is not positive, an empty field, a port outside 0..65535 (``--port 99999`` was replaced
    by a free port, silently), a negative duration, an ``--export`` page over an input file.

    Raises
    ------
    StiffnessError
        Naming the flag and what it takes.
    """
    for flag, value, what in (("--size", args.size, "radius in m"),
                              ("--fps", args.fps, "number of frames per second")):
        if value is not None and value <= 0:
            raise StiffnessError(f"{flag} must be a positive {what}, got {value:g}")
    flags.require_at_least_one(args.field, "--field")
    if not 0 <= args.port <= 65535:
        raise StiffnessError(f"--port must be a TCP port, 1 to 65535 (0 or none: a free one), "
                             f"got {args.port}")
    if args.duration is not None and args.duration < 0:
        raise StiffnessError(f"--duration must be 0 or more seconds, got {args.duration:g}")
    flags.check_outputs(args.export, inputs={"--robot": args.robot, "--model": args.model,
                                             "--path": args.path})


def build(args: argparse.Namespace, live: bool, inputs: kx.KxInputs | None = None
          ) -> StiffnessViewer:
    """The viewer with everything the flags ask for drawn (the caller closes it)."""
    robot, coords, k_theta, load = resolve(args, inputs)
    rows = None
    if args.sweep is not None and args.path is not None:
        raise StiffnessError("give --sweep or --path, not both")
    if args.sweep is not None:
        rows = sweep_path(robot, coords, args.sweep, args.deg)
    elif args.path is not None:
        rows = read_joint_path(args.path, robot, args.deg, "--path file").coords
    model = kx.elastic_model_from_args(args)
    options = {"live": live, "quantity": args.quantity, "size": args.size,
               "exaggeration": args.exaggeration, "host": args.host, "port": args.port,
               "open_browser": args.open and live}
    viewer: StiffnessViewer
    if model is not None and model.beyond_springs:
        viewer = ModelViewer(model, robot, k_theta, **options)
    else:
        viewer = StiffnessViewer(robot, k_theta, **options)
    try:
        viewer.show(coords, load, args.formulation)
        if args.field is not None:
            joints = None if args.field_joints is None else [
                j.strip() for j in args.field_joints.split(",") if j.strip()]
            formulation = "enhanced" if args.formulation == "both" else args.formulation
            viewer.field(args.field, load, formulation, joints=joints, seed=args.seed)
        if rows is not None:
            viewer.sweep(rows, load, args.formulation, fps=args.fps)
    except BaseException:
        viewer.close()
        raise
    return viewer


class ModelViewer(StiffnessViewer):
    """The viewer drawing a model file's compliance at each pose and load, its link
    compliance and nonlinear springs' tangents included (:meth:`ElasticModel.at`); the
    drawn deflection is that of its joint springs."""

    def __init__(self, model: ElasticModel, *args, **kwargs) -> None:
        self.compliant_model = model
        super().__init__(*args, **kwargs)

    def ellipsoids(self, q: np.ndarray, wrench: np.ndarray, formulations, quantity=None):
        """Target state and principal ellipsoids of the model's 3x3 compliance."""
        quantity = self.quantity if quantity is None else quantity
        state = target_state(self.robot, q, wrench)
        out = {}
        for name in formulations:
            c = self.compliant_model.at(self.robot.coordinates_of(q), wrench, name,
                                        closed=q).compliance()
            values, vectors = np.linalg.eigh(0.5 * (c + c.T))
            # principal_ellipsoid draws F T^-1 F^T: C = F T^-1 F^T with F = V |L|^1/2 and
            # T = sign(L) (an indefinite compliance past the buckling load keeps its signs)
            factor = vectors * np.sqrt(np.abs(values))
            signs = np.diag(np.where(values < 0.0, -1.0, 1.0))
            out[name] = principal_ellipsoid(factor, signs, name, quantity)
        return state, out


def _say_if_unloaded(viewer: StiffnessViewer) -> None:
    if viewer.state is not None and not np.any(viewer.state.wrench):
        print("no load (give --wrench fx,fy,fz in N): drawing the unloaded stiffness, where "
              "enhanced and conventional coincide")


def _terminate(signum: int, frame: object) -> None:
    raise SystemExit(128 + signum)


def stability(inputs: kx.KxInputs) -> dict:
    """Whether the drawn configuration is stable under its load, and the critical load factor
    (:attr:`stiffness.elastic.state.ElasticState.critical_load_factor`, None when the load
    never buckles the arm along its direction)."""
    model = inputs.model or ElasticModel.joint_springs(inputs.robot, inputs.k_theta)
    state = model.at(inputs.coords, inputs.load, closed=inputs.q)
    factor = state.critical_load_factor
    return {"stable": state.stable, "critical_load_factor": factor if math.isfinite(factor)
            else None}


def stability_line(found: dict) -> str:
    """One line saying whether the arm is stable under the load, with the critical factor."""
    factor = found["critical_load_factor"]
    if factor is None:
        return "stable under this load at any magnitude (K_theta - K_C stays positive definite)"
    if found["stable"]:
        return (f"stable under this load: K_theta - K_C is positive definite up to "
                f"{factor:.4g} times it (the critical load factor)")
    return (f"UNSTABLE under this load: K_theta - K_C is not positive definite (critical load "
            f"factor {factor:.4g}: the arm buckles at {factor:.4g} times the load); the "
            "enhanced ellipsoid is not a stiffness the arm has")


def _report(args: argparse.Namespace, inputs: kx.KxInputs, **where: str | None) -> None:
    """Print where the page is (one JSON object with ``--json``), echo the inputs and say
    whether the arm is stable under the load."""
    summary = {"robot": inputs.robot.name, "frame": inputs.robot.target_frame,
               "formulation": args.formulation, **where, **kx.inputs_summary(inputs),
               "notes": list(inputs.robot.notes)}
    loaded = bool(np.any(inputs.load))
    if loaded:
        summary.update(stability(inputs))
    if args.json:
        print(json.dumps(summary), flush=True)
        return
    for note in summary["notes"]:
        print(f"note: {note}", flush=True)
    if not args.quiet:
        print("\n".join(kx.echo_lines(summary)), flush=True)
    if loaded:
        print(stability_line(summary), flush=True)


def run(args: argparse.Namespace) -> int:
    """Export the static page, or serve the live viewer until Ctrl-C or ``--duration``."""
    check_view_flags(args)
    inputs = kx.resolve_inputs(args, require_load=False)
    if args.export is not None:
        viewer = build(args, live=False, inputs=inputs)
        _say_if_unloaded(viewer)
        path = viewer.export(args.export)
        _report(args, inputs, export=str(path))
        if not args.json:
            print(f"wrote {path}: a self-contained page, open it in a browser (works offline)")
        return 0
    previous = signal.signal(signal.SIGTERM, _terminate)  # so that the server is stopped
    viewer = build(args, live=True, inputs=inputs)
    _say_if_unloaded(viewer)
    try:
        where = "this machine only" if args.host == LOOPBACK else \
            f"{args.host}: reachable from the network"
        _report(args, inputs, url=viewer.url)
        if not args.json:
            print(f"stiffness viewer: {viewer.url} (listening on {where}); Ctrl-C stops it",
                  flush=True)
        viewer.browse(duration=args.duration)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.close()
        signal.signal(signal.SIGTERM, previous)
    return 0
