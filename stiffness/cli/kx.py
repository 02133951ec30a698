"""``stiffness kx``: Cartesian stiffness, complementary stiffness and compliance at one pose.

Example::

    stiffness kx --robot ur5 --frame tool0 --q 0,-1.2,1.5,-0.3,1.57,0 \\
        --wrench 0,0,-200 --kq 3e5,3e5,2e5,4e4,4e4,4e4 --json
    stiffness kx --robot griffis-duffy --connection twist --json

A shipped robot brings its defaults (frame, configuration ``q_deg``/``q_SI``, springs
``k_theta_SI``, load ``wrench_SI`` or spring rest values ``rest_q_SI``, whose holding wrench is
then the load; row order ``twist_order``), which flags override.

SI units throughout: m, N, rad, N.m/rad (N/m for prismatic joints).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass, field

import numpy as np

from stiffness.cli import flags
from stiffness.elastic.cartesian import cartesian_report
from stiffness.elastic.file_model import elastic_model_of
from stiffness.elastic.model import ElasticModel
from stiffness.elastic.model_contents import ModelFile
from stiffness.elastic.model_file import read_model_file
from stiffness.elastic.undetermined_springs import rigid_springs, undetermined_labels
from stiffness.errors import StiffnessError
from stiffness.mechanics.defaults import default_coordinates, default_load, default_stiffness
from stiffness.mechanics.formulation import FORMULATIONS, joint_stiffness
from stiffness.mechanics.wrench import TWIST_ORDERS
from stiffness.robot.assembly import Assembly
from stiffness.robot.robot import Robot
from stiffness.workspace.maps import SINGULARITY_MARGIN

_LOAD_NAMES = ("fx", "fy", "fz", "mx", "my", "mz")


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Flags of ``stiffness kx``."""
    flags.add_robot_flags(parser, robot_help=(
        "shipped robot (sk120, griffis-duffy, hexapod), example-robot-data name (ur5, "
        "panda...), URDF path or robot.toml (required unless --model gives it)"))
    parser.add_argument("--model", metavar="FILE",
                        help="model file of `stiffness identify` (identified-model.json) or "
                             "`stiffness diagnose --out` (final-model.json): its robot, target, "
                             "compliant joints, K_theta and the effects that change the "
                             "stiffness (docs/model-file.md); the other flags override them")
    flags.add_configuration_flags(parser)
    flags.add_wrench_flag(parser)
    flags.add_stiffness_flag(parser)
    parser.add_argument("--formulation", choices=FORMULATIONS, default="enhanced",
                        help="conventional (K_C = 0, A&S eq. 8) or enhanced (eq. 10); "
                             "default enhanced")
    parser.add_argument("--connection", choices=("joint", "twist"),
                        help="6x6 stiffness of Zefran & Kumar: joint-space connection "
                             "(J^-T K J^-1) or twist basis (asymmetric under load), "
                             "in the target's body axes")
    parser.add_argument("--twist-order", choices=tuple(TWIST_ORDERS),
                        help="row order of 6x6 results: v-w (Pinocchio: linear first) or w-v "
                             "(Zefran & Kumar: angular first); default the robot's own, else v-w")
    flags.add_output_flags(parser, quiet_help="print the results only, without the echo of "
                                              "the inputs")


def model_file_from_args(args: argparse.Namespace) -> ModelFile | None:
    """The ``--model`` file (checked against ``--robot``), or None (read once per parsed
    command line)."""
    if getattr(args, "model", None) is None:
        return None
    if getattr(args, "_identified_model", None) is None:
        model = read_model_file(args.model)
        if getattr(args, "robot", None) is not None:
            model.check_robot(args.robot)
        args._identified_model = model
    return args._identified_model


def elastic_model_from_args(args: argparse.Namespace) -> ElasticModel | None:
    """The ``--model`` file's elastic model, or None (no ``--model``, or ``--kq`` /
    ``--compliant-joints`` replace the model's springs)."""
    model = model_file_from_args(args)
    if model is None or args.kq is not None or args.compliant_joints is not None:
        return None
    if getattr(args, "_elastic_model", None) is None:
        args._elastic_model = elastic_model_of(model, frame=args.frame,
                                               target_offset=flags.target_offset_from_args(args))
    return args._elastic_model


def model_summary(args: argparse.Namespace) -> dict | None:
    """What the ``--model`` file contributes (JSON-ready), or None without ``--model``."""
    model = model_file_from_args(args)
    if model is None:
        return None
    cm = elastic_model_from_args(args)

    def entry(e, reason=None):
        return {"effect": e.name, "where": e.where, "kind": e.kind,
                "parameters": {p.name: p.value for p in e.parameters},
                **({} if reason is None else {"reason": reason})}

    if cm is None:
        applied, not_applied = [], [
            entry(e, "--kq or --compliant-joints replace the model's springs")
            for e in model.effects]
    else:
        applied = [entry(e) for e in cm.applied]
        not_applied = [entry(e, why) for e, why in cm.not_applied]
    return {"file": str(model.path), "produced_by": model.produced_by,
            "formulation": model.formulation, "effects_applied": applied,
            "effects_not_applied": not_applied}


@dataclass
class KxInputs:
    """What the ``kx`` flags (and a shipped robot's defaults) resolve to, in SI.

    ``*_source`` say where each input came from: a flag, the model file or the robot's default
    (``load_source`` keeps its historical values: ``--wrench``, ``wrench_SI``, ``rest_q_SI...``).
    ``undetermined``: the springs of a model file's K_theta its campaign did not determine
    (its ``undetermined_joints``), each with what the echo says instead of its value
    (:func:`~stiffness.elastic.undetermined_springs.undetermined_labels`).
    """

    robot: Robot
    coords: np.ndarray
    q: np.ndarray
    k_theta: np.ndarray
    load: np.ndarray
    load_source: str
    model: ElasticModel | None = None
    assembly: Assembly | None = None
    q_source: str = flags.FROM_FLAG
    k_theta_source: str = flags.FROM_FLAG
    undetermined: dict[str, str] = field(default_factory=dict)

    @property
    def sources(self) -> dict[str, str]:
        """Where the coordinates, the load and K_theta came from (flag, model file, robot)."""
        load = (f"{flags.FROM_FLAG} --wrench" if self.load_source == "--wrench"
                else f"{flags.FROM_ROBOT} ({self.load_source})")
        return {"q": self.q_source, "wrench": load, "K_theta": self.k_theta_source}


def resolve_inputs(args: argparse.Namespace, require_load: bool = True) -> KxInputs:
    """Robot, configuration, joint stiffness and load of the ``kx`` flags (shared by ``view``).

    Without ``--wrench`` the robot's shipped load is used; if it has none, the load is zero
    when ``require_load`` is false (``view`` draws the unloaded stiffness), else an error.

    Raises
    ------
    StiffnessError
        On a bad flag value, or a missing flag the robot brings no default for.
    """
    model = model_file_from_args(args)
    cm = elastic_model_from_args(args)
    robot = cm.robot if cm is not None else flags.robot_from_args(args, fallback=model)[0]
    reference = args.q is None and default_coordinates(robot) is None
    # without --q and robot defaults: the reference pose (zero, or the assembly found near it)
    coords = None if reference else flags.coordinates_from_args(robot, args)
    kq: np.ndarray | list[float] | None
    springs = None  # the model file whose springs K_theta is, if it is one's
    if cm is not None:
        kq, kq_source, springs = cm.k_theta, f"{flags.FROM_MODEL} {args.model}", model
    elif args.kq is not None:
        kq, kq_source = flags.parse_kq(args.kq, robot), f"{flags.FROM_FLAG} --kq"
    elif model is not None and tuple(model.compliant_joints) == tuple(robot.compliant_joints):
        kq, kq_source, springs = model.k_theta, f"{flags.FROM_MODEL} {args.model}", model
    else:
        kq, kq_source = default_stiffness(robot), flags.FROM_ROBOT
    if kq is None:
        raise flags.stiffness_required(robot)
    k_theta = joint_stiffness(kq, robot.n_compliant)
    undetermined = {} if springs is None else undetermined_labels(
        springs.undetermined_joints, rigid_springs(springs.compliant_joints, springs.k_theta,
                                                   springs.ci95_low, springs.ci95_high))
    assembly = robot.assemble(coords)
    q = assembly.q
    if coords is None:
        coords = robot.coordinates_of(q)
    if args.wrench is not None:
        load, source = np.array(flags.parse_list(args.wrench, "--wrench")), "--wrench"
    else:
        shipped = default_load(robot, q, k_theta)
        if shipped is None and not require_load:
            shipped = np.zeros(3), "none"
        if shipped is None:
            raise StiffnessError(
                "--wrench is required: fx,fy,fz (N) or fx,fy,fz,mx,my,mz (N, N.m)")
        load, source = shipped
    q_source = flags.coordinates_source(robot, args)
    if reference:
        q_source = ("assembly found near the zero pose (no --q)" if assembly.assembly_search
                    else "zero pose (no --q)")
    return KxInputs(robot, coords, q, k_theta, load, source, cm, assembly, q_source=q_source,
                    k_theta_source=kq_source, undetermined=undetermined)


def inputs_summary(inputs: KxInputs) -> dict:
    """The inputs as JSON: coordinates by name, load, K_theta and where each came from;
    ``K_theta_undetermined``: each spring of a model file its campaign did not determine
    (rigid to it, or not loaded), with what the echo says of it; its ``K_theta_named`` value
    is the file's, where the fit stopped, not a measurement."""
    robot = inputs.robot
    return {
        "coordinate_joints": list(robot.coordinate_joints),
        "q_named": dict(zip(robot.coordinate_joints, inputs.coords.tolist(), strict=True)),
        "load_named": dict(zip(_LOAD_NAMES, inputs.load.tolist(), strict=False)),
        "K_theta_named": dict(zip(robot.compliant_joints, np.diag(inputs.k_theta).tolist(),
                                  strict=True)),
        "sources": inputs.sources,
        "K_theta_undetermined": dict(inputs.undetermined),
    }


def echo_lines(summary: dict) -> list[str]:
    """Lines echoing :func:`inputs_summary`: coordinates as name=value, load and K_theta, each
    with where it came from."""
    sources, load = summary["sources"], summary["load_named"]
    q = summary["q_named"]
    k = summary["K_theta_named"]
    said = summary.get("K_theta_undetermined", {})
    springs = ",".join(f"{n}={said[n]}" if n in said else flags.format_named([n], [v])
                       for n, v in k.items())
    return [
        f"q [{sources['q']}] (rad, m prismatic): "
        f"{flags.format_named_summary(list(q), list(q.values()), list(k))}",
        f"wrench [{sources['wrench']}] (N, N.m; base axes): "
        f"{flags.format_named(list(load), list(load.values()))}",
        f"K_theta [{sources['K_theta']}] (N.m/rad, N/m prismatic): {springs}",
    ]


def compute(args: argparse.Namespace) -> dict:
    """Evaluate the stiffness quantities of ``stiffness kx``; returns the JSON object: the
    elastic model at the pose and load (:meth:`stiffness.elastic.model.ElasticModel.at`)
    reported by :func:`stiffness.elastic.cartesian.cartesian_report`, with the inputs."""
    inputs = resolve_inputs(args)
    robot = inputs.robot
    model = inputs.model or ElasticModel.joint_springs(robot, inputs.k_theta)
    state = model.at(inputs.coords, inputs.load, args.formulation, closed=inputs.q)
    report = cartesian_report(state, args.formulation, args.connection, args.twist_order)
    trans = "N/m"
    if len(report["basis"]) == 6:
        order = state.twist_order(args.twist_order)
        blocks = "N/m | N | N.m/rad" if order == "v-w" else "N.m/rad | N | N/m"
        trans = f"{blocks} blocks ([{order.replace('-', '; ')}] order)"
    out = {
        "robot": robot.name,
        "robot_name": robot.title,
        "frame": robot.target_frame,
        "target_offset": robot.target_offset.tolist(),
        "compliant_joints": list(robot.compliant_joints),
        "q": inputs.coords.tolist(),
        "load_source": inputs.load_source,
        **report,
        **inputs_summary(inputs),
        "configuration": _configuration(robot, inputs.q),
        "closure": None if inputs.assembly is None else inputs.assembly.as_dict(),
        "singularity_ratio": _singularity_ratio(np.asarray(report["J"])),
        "notes": list(robot.notes) + ([] if inputs.assembly is None
                                      else inputs.assembly.notes()),
        "units": {
            "J": "m/rad (m/m for prismatic); angular rows rad/rad (rad/m prismatic)",
            "K_C": "N.m/rad (N/m between prismatic joints, N between a prismatic and a revolute)",
            "K_C_round_off": "N.m/rad (K_C entries at or below it are round-off, given as 0)",
            "K_theta": "N.m/rad (N/m prismatic)", "K_X": trans,
            "compliance": "m/N (inverse of K_X)", "eigenvalues": "same as K_X",
            "K_X_subspace": "K_X, eigenvalues: as K_X (pseudo-inverse of the compliance in SI: "
                            "in 6x6, 1 m weighs as 1 rad); directions: unit vectors",
            "position": "m", "q": "rad (m prismatic)", "wrench": "N, N.m",
            "configuration": "rad (m prismatic); Pinocchio q values for multi-coordinate joints",
            "closure": "residual in m (rad for 6D rotation rows)",
            "critical_load_factor": "1 (the factor on the wrench at which K_theta - K_C turns "
                                    "singular; null: never along this wrench)",
            "singularity_ratio": "1 (sigma_min / sigma_max of J's translational rows)",
        },
    }
    summary = model_summary(args)
    if summary is not None:
        out["model"] = summary
    return out


def _singularity_ratio(jacobian: np.ndarray) -> float:
    """``sigma_min / sigma_max`` of the translational rows of ``jacobian`` (0 when they span
    fewer than three directions or are zero): how far the pose is from a singularity."""
    sv = np.linalg.svd(jacobian[:3], compute_uv=False)
    return float(sv[2] / sv[0]) if len(sv) == 3 and sv[0] > 0 else 0.0


def _configuration(robot: Robot, q: np.ndarray) -> dict:
    """Every joint's value after closure, by name (rad or m); a list of its Pinocchio ``q``
    values for a joint with more than one coordinate."""
    out = {}
    model = robot.model
    for jid in range(1, model.njoints):
        joint = model.joints[jid]
        if joint.nq == 0:
            continue
        values = q[joint.idx_q: joint.idx_q + joint.nq]
        out[model.names[jid]] = float(values[0]) if joint.nq == 1 else values.tolist()
    return out


def run(args: argparse.Namespace) -> int:
    """Print the result as JSON or as a short table."""
    result = compute(args)
    if args.json:
        json.dump(result, sys.stdout)
        sys.stdout.write("\n")
        return 0
    np.set_printoptions(precision=5, suppress=False, linewidth=120)
    for note in result["notes"]:
        print(f"note: {note}")
    print(f"{result['robot_name']} target at {result['frame']} + {result['target_offset']} m; "
          f"{result['formulation']} formulation"
          + (f", {result['connection']} connection" if result["connection"] else ""))
    if not args.quiet:
        print("\n".join(echo_lines(result)))
        closure = result["closure"]
        if closure["assembly_search"] or closure["idle_passive_motions"]:
            print(f"closure: residual {closure['residual']:.3g} m, idle passive motions "
                  f"{closure['idle_passive_motions']}, assembly search "
                  f"{'used' if closure['assembly_search'] else 'not needed'}")
    print(f"position (m): {np.array(result['position'])}")
    print(f"J ({result['units']['J']}):\n{np.array(result['J'])}")
    tol = result["K_C_round_off"]
    print("K_C (N.m/rad" + (f"; entries within {tol:.2g} of 0, round-off at this load, as 0"
                            if tol > 0 else "") + f"):\n{np.array(result['K_C'])}")
    if result["K_X"] is None:
        sub = result["K_X_subspace"]
        print(f"K_X undefined: {result['K_X_undefined']}")
        print(f"compliance (m/N blocks), basis {result['basis']}:\n"
              f"{np.array(result['compliance'])}")
        print(f"K_X on the {sub['rank']}-dimensional moving subspace (pseudo-inverse of the "
              f"compliance): principal stiffnesses {np.array(sub['eigenvalues'])}; rigid "
              f"(unbounded) along {np.array(sub['rigid_directions'])}")
    else:
        print(f"K_X ({result['units']['K_X']}), basis {result['basis']}:\n"
              f"{np.array(result['K_X'])}")
        blocks = result.get("principal_by_block")
        if result["stable"] and blocks:
            for name, block in blocks.items():
                print(f"principal {name} stiffnesses ({block['unit']}, {block['note']}): "
                      f"{np.array(block['values'])}")
        elif result["stable"]:
            print(f"principal stiffnesses: {np.array(result['eigenvalues'])}")
        else:
            factor = result["critical_load_factor"]
            print(f"the arm is unstable under this load: K_theta - K_C turns singular at "
                  f"{factor:.4g} times the wrench (critical load factor below 1), so K_X is "
                  "not the stiffness of a stable equilibrium; reduce the load")
        if result["singularity_ratio"] < SINGULARITY_MARGIN:
            print(f"note: near a kinematic singularity: sigma_min/sigma_max of the "
                  f"translational Jacobian is {result['singularity_ratio']:.2g} (below "
                  f"{SINGULARITY_MARGIN:g}, where `stiffness scan` leaves a pose out of its "
                  "ranges): the largest principal stiffnesses grow without bound as it is "
                  "approached")
    print(f"definiteness: {result['definiteness']}")
    if "model" in result:
        m = result["model"]
        label = lambda e: e["effect"] + (f"({e['where']})" if e["where"] else "")  # noqa: E731
        print(f"model {m['file']}: effects in K_X: "
              + (", ".join(label(e) for e in m["effects_applied"]) or "none"))
        for e in m["effects_not_applied"]:
            print(f"  not applied: {label(e)}: {e['reason']}")
    return 0
