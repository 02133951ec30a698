"""``stiffness simulate --kind poses``: a pose campaign with chosen effects hidden in it.

:func:`simulate_poses` reads the hidden effects as ``stiffness simulate --effect`` writes them
(:func:`parse_pose_effect`; their names are the pose model's families,
:data:`~stiffness.elastic.effects.FAMILIES`, :data:`POSE_EFFECTS`), builds the truth from them
(:func:`hidden_pose_errors`: a :class:`~stiffness.planning.simulate_poses.HiddenPoseErrors`),
simulates what a tracker sees (:func:`~stiffness.planning.simulate_poses.simulate_pose_campaign`:
exact placements, the exact static equilibrium, Gaussian noise) and sizes each hidden effect by
the RMS change its removal makes to the noise-free marker positions.

Effect values, in the campaign's ``units`` (angles in ``units.angle``, lengths in
``units.length``; a prismatic joint's offset and backlash in the length unit):

* ``frame=RX,RY,RZ[,TX,TY,TZ]``: the measuring frame, ``y = R p + t`` for a point ``p`` in the
  robot's world, ``R`` the rotation vector's (angle), ``t`` (length; default 0);
* ``markers[:NAME]=DX,DY,DZ``: the true marker offset is the declared one plus this (length,
  the marker frame's axes); every marker without a name;
* ``joint_offsets[:J]=V[,V...]``: zero offsets of the 1-dof joints: J's, or one value for every
  joint, or one per joint in the model's order (angle);
* ``geometry:J=DX,DY,DZ[,RX,RY,RZ]``: J's placement error ``eps_J`` (``M_J exp(eps_J)``:
  length, then angle);
* ``base_tilt=RX,RY``: the base's z axis turned from the vertical by ``exp([RX, RY, 0])``
  (angle);
* ``joint_compliance:J=K``: a spring of stiffness K (N.m/rad, N/m prismatic) on the compliant
  joint (or controller coordinate) J; the others rigid. ``kq`` instead gives every compliant
  joint its spring;
* ``link_compliance:A->B=K[,K2]``, ``transversal_compliance:J=K[,K2]``: a link bending, a joint
  tilting in its bearing, stiffness about the two axes (N.m/rad; one value for both);
* ``backlash:J=B``: lost motion of half-width B on J's spring (angle);
* ``nonlinear_joint_stiffness:J=BETA``: J's spring softens, ``t / k (1 + beta |t|)``
  (1/(N.m), 1/N prismatic); needs J's spring;
* ``gravity_compensator:J=K,F0``: a spring compensator of stiffness K (N/m) and tension F0 (N)
  with the link up, the pose simulator's geometry
  (:data:`~stiffness.planning.simulate_poses.SPRING_LEVER_M`, ``SPRING_BASE_M``); needs J's
  spring.

The deflection campaigns' effects that a pose campaign does not have (a target offset, a force
sensor's bias...) are refused with the valid names; ``gravity_lumped`` is a fit of unknown
masses, not an effect to hide (the simulated arm weighs what its robot file says).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.calibration.campaign_toml import CAMPAIGN_FILE
from stiffness.calibration.pose_campaign import PoseCampaign, write_pose_campaign
from stiffness.calibration.pose_loops import PoseLoops
from stiffness.calibration.pose_model import Marker, align_frames, pose_joints
from stiffness.elastic.effects import FAMILIES
from stiffness.elastic.effects.base import effect_place
from stiffness.errors import (
    FlagValueWarning,
    StiffnessError,
    UnknownEffectError,
    UnknownFrameError,
    UnknownJointError,
    UnknownNameError,
    did_you_mean,
    warn_user,
)
from stiffness.files import atomic_write, refuse_foreign_folder, staged_folder, written_source
from stiffness.planning.design import DEFAULT_NOISE_STD_M
from stiffness.planning.simulate import TRUTH_FILE, HiddenEffect
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.planning.simulate_request import MAX_ROWS, effect_values, rotation_noise_std
from stiffness.robot.robot import Robot, load_robot
from stiffness.units import Units, float_array, whole_number

#: The effects a pose campaign hides: the pose model's families but ``gravity_lumped``.
POSE_EFFECTS: tuple[str, ...] = tuple(n for n in FAMILIES if n != "gravity_lumped")
#: How many values each takes (``None``: one, or one per 1-dof joint).
_COUNTS: dict[str, tuple[int, ...] | None] = {
    "frame": (3, 6), "markers": (3,), "joint_offsets": None, "geometry": (3, 6),
    "base_tilt": (2,), "joint_compliance": (1,), "link_compliance": (1, 2),
    "transversal_compliance": (1, 2), "backlash": (1,), "nonlinear_joint_stiffness": (1,),
    "gravity_compensator": (2,)}
#: Effects on the whole campaign (no place) and effects that need one (the rest may have one).
_GLOBAL = ("frame", "base_tilt")
_PLACED = ("geometry", "joint_compliance", "link_compliance", "transversal_compliance",
           "backlash", "nonlinear_joint_stiffness", "gravity_compensator")
#: Effects on a spring (a compliant joint or controller coordinate), and those acting through
#: its stiffness (refused on a rigid one).
_ON_SPRING = ("joint_compliance", "backlash", "nonlinear_joint_stiffness", "gravity_compensator")
_THROUGH_SPRING = ("nonlinear_joint_stiffness", "gravity_compensator")
#: Default number of poses.
DEFAULT_POSES = 30


def parse_pose_effect(text: str) -> HiddenEffect:
    """Parse ``NAME[:WHERE]=V[,V...]`` (or ``NAME(WHERE)=...``) of a pose effect
    (:data:`POSE_EFFECTS`; values in the module docstring's units).

    Raises
    ------
    UnknownEffectError
        A name that is no pose effect (the valid ones named).
    StiffnessError
        A place on a whole-campaign effect or none where one is needed, a wrong number of
        values, or a non-number.
    """
    head, _, rest = text.partition("=")
    name, where = effect_place(head, "--effect")
    if name not in POSE_EFFECTS:
        raise UnknownEffectError(
            f"--effect {text!r}: {name!r} is no effect a pose campaign hides; "
            f"{did_you_mean(name, list(POSE_EFFECTS))}", name=name, choices=list(POSE_EFFECTS))
    if where and name in _GLOBAL:
        raise StiffnessError(f"--effect {text!r}: {name} acts on the whole campaign; drop "
                             f"':{where}'")
    if not where and name in _PLACED:
        example = "A->B" if name == "link_compliance" else "JOINT"
        raise StiffnessError(f"--effect {text!r}: {name} needs a place, {name}:{example}=...")
    values = effect_values(text, rest)
    counts = _COUNTS[name] or ((1,) if where else None)
    if (counts is not None and len(values) not in counts) or not values:
        wanted = " or ".join(str(c) for c in counts) if counts else "one or one per joint"
        raise StiffnessError(f"--effect {text!r}: {name} takes {wanted} value(s), got "
                             f"{len(values)}")
    return HiddenEffect(name, where, tuple(values))


def _index(names: list[str], where: str, effect: HiddenEffect, what: str, fix: str = "") -> int:
    """Where ``where`` is in ``names`` (a joint, a spring, a marker), else the one-line error
    naming the valid ones."""
    if where in names:
        return names.index(where)
    error = UnknownNameError if what == "marker" else UnknownJointError
    raise error(f"--effect {effect.label}: {where!r} is not {what}{fix}; "
                f"{did_you_mean(where, names)}", name=where, choices=names)


def _spring_fix(robot: Robot, joint: str) -> str:
    """How to put an effect on a spring at ``joint``, not a compliant joint of ``robot``:
    declare it with ``--compliant-joints``, but a mimic follower cannot be declared (its
    leader carries the spring, :func:`~stiffness.robot.declaration.check_compliant`): name
    its leader."""
    leader = next((m.leader for m in robot.mimics if m.follower == joint), None)
    if leader is None:
        return " (declare it with --compliant-joints)"
    declare = "" if leader in robot.compliant_joints else ", declared with --compliant-joints"
    return (f" (it is a mimic follower: its leader {leader!r} carries the spring; name "
            f"{leader}{declare})")


def _positive(effect: HiddenEffect, values: np.ndarray, zero: bool = False) -> np.ndarray:
    """``values`` refused unless all positive (non-negative with ``zero``)."""
    if not (np.all(values >= 0) if zero else np.all(values > 0)):
        raise StiffnessError(f"--effect {effect.label}: {'non-negative' if zero else 'positive'}"
                             f" values, got {', '.join(f'{v:g}' for v in effect.values)}")
    return values


def hidden_pose_errors(robot: Robot, markers: list[Marker],
                       effects: Sequence[HiddenEffect | str] | None = None,
                       kq: list[float] | np.ndarray | None = None, units: Units | None = None,
                       drift_m: np.ndarray | list[float] | None = None) -> HiddenPoseErrors:
    """The truth of ``effects`` (:func:`parse_pose_effect`, values in ``units``, default SI) on
    ``robot`` seen through ``markers`` (their declared offsets): nothing else hidden, the
    measuring frame the world's, the springs ``kq`` (N.m/rad, N/m; one per compliant joint) or
    those ``joint_compliance`` gives (the other springs rigid: ``inf``), none (``stiffness``
    ``None``) without an elastic effect; ``drift_m`` (m) the measuring frame origin's drift.

    Raises
    ------
    StiffnessError
        An effect hidden twice, at an unknown place, with an out-of-range value, acting through
        a rigid spring, or ``joint_compliance`` with ``kq``.
    """
    units = units or Units("rad", "N", "m")
    hidden = [parse_pose_effect(e) if isinstance(e, str) else e for e in effects or []]
    labels = [h.label for h in hidden]
    if len(set(labels)) != len(labels):
        raise StiffnessError(f"an effect is hidden twice: {labels}")
    model = robot.model
    joints = [str(model.names[j]) for j in pose_joints(robot)]
    _refuse_in_loops(robot, hidden, joints)
    springs = list(robot.compliant_joints)
    truth = HiddenPoseErrors(np.eye(3), np.zeros(3), np.array([m.offset for m in markers],
                                                              dtype=float).reshape(-1, 3),
                             np.zeros(len(joints)), np.zeros((len(joints), 6)),
                             drift=np.zeros(3) if drift_m is None else float_array(
                                 drift_m, "drift_m", "three lengths in m").reshape(3))
    stiffness = _springs(robot, hidden, kq)
    elastic = kq is not None or any(h.name not in ("frame", "markers", "joint_offsets",
                                                   "geometry", "base_tilt") for h in hidden)
    n = len(springs)
    backlash, beta = np.zeros(n), np.zeros(n)
    for h in hidden:
        v = np.asarray(h.values, dtype=float)
        if h.name in _ON_SPRING:
            k = _index(springs, str(h.where), h, "a compliant joint of " + robot.title,
                       _spring_fix(robot, str(h.where)))
            if h.name in _THROUGH_SPRING and not math.isfinite(stiffness[k]):
                raise StiffnessError(f"--effect {h.label} acts through {h.where}'s spring: "
                                     f"give it one (--effect joint_compliance:{h.where}=K, or "
                                     f"--kq)")
            scale = units.length_to_si if robot.is_prismatic(str(h.where)) else units.angle_to_si
            if h.name == "backlash":
                backlash[k] = _positive(h, v, zero=True)[0] * scale
            elif h.name == "nonlinear_joint_stiffness":
                beta[k] = v[0]
            elif h.name == "gravity_compensator":
                truth.compensator[str(h.where)] = _positive(h, v, zero=True)
        elif h.name in ("link_compliance", "transversal_compliance"):
            table = (truth.link_compliance if h.name == "link_compliance"
                     else truth.transversal_compliance)
            table[str(h.where)] = 1.0 / np.resize(_positive(h, v), 2)
        else:
            _geometric(truth, h, v, joints, markers, robot, units)
    if elastic:
        truth.stiffness, truth.backlash, truth.nonlinear = stiffness, backlash, beta
    return truth


def _refuse_in_loops(robot: Robot, hidden: list[HiddenEffect], joints: list[str]) -> None:
    """On a robot with closed loops, refuse an error inside a loop, which the pose model does
    not model: a zero offset of a passive joint, a placement error, a bend at or a tilt of a
    joint on a loop's path (:attr:`PoseLoops.path_joints`).

    Raises
    ------
    LoopGeometryError
        One line naming the valid joints.
    """
    if robot.loop.is_open_chain:
        return
    loops = PoseLoops(robot)
    model = robot.model
    outside = [str(model.names[j]) for j in loops.geometry_joints(
        [int(model.getJointId(n)) for n in joints])]
    for h in hidden:
        where = str(h.where or "")
        joint = where.partition("->")[2] if h.name == "link_compliance" else where
        if h.name not in ("geometry", "joint_offsets", "link_compliance",
                          "transversal_compliance") or not model.existJointName(joint):
            continue
        valid = joints if h.name == "joint_offsets" else outside
        if joint not in valid:
            loops.refuse_placement(joint, valid, f"--effect {h.label}")


def _springs(robot: Robot, hidden: list[HiddenEffect], kq: list[float] | np.ndarray | None
             ) -> np.ndarray:
    """The stiffness (SI) of each compliant joint: ``kq``, else ``joint_compliance``'s, else
    rigid (``inf``)."""
    springs = list(robot.compliant_joints)
    given = [h for h in hidden if h.name == "joint_compliance"]
    if kq is not None:
        if given:
            raise StiffnessError("give the springs either by --kq (every compliant joint) or by "
                                 "--effect joint_compliance:J=K, not both")
        out = float_array(kq, "kq", "one positive stiffness per compliant joint").reshape(-1)
        if out.shape != (len(springs),) or not np.all(out > 0):
            raise StiffnessError(f"kq: one positive stiffness (N.m/rad, N/m) per compliant "
                                 f"joint ({', '.join(springs)}), got {kq!r}")
        return out
    out = np.full(len(springs), np.inf)
    for h in given:
        k = _index(springs, str(h.where), h, "a compliant joint of " + robot.title,
                   _spring_fix(robot, str(h.where)))
        out[k] = _positive(h, np.asarray(h.values, dtype=float))[0]
    return out


def _geometric(truth: HiddenPoseErrors, h: HiddenEffect, v: np.ndarray, joints: list[str],
               markers: list[Marker], robot: Robot, units: Units) -> None:
    """Put the geometric effect ``h`` (values ``v`` in ``units``) into ``truth``."""
    angle, length = units.angle_to_si, units.length_to_si
    if h.name == "frame":
        truth.frame_rotation = pin.exp3(v[:3] * angle)
        truth.frame_translation = np.resize(v[3:], 3) * length if len(v) == 6 else np.zeros(3)
    elif h.name == "base_tilt":
        truth.base_tilt = v * angle
    elif h.name == "markers":
        names = [m.name for m in markers]
        rows = [_index(names, h.where, h, "a marker")] if h.where else range(len(markers))
        for k in rows:
            truth.marker_offsets[k] = truth.marker_offsets[k] + v * length
    elif h.name == "geometry":
        j = _index(joints, str(h.where), h, "a 1-dof joint of " + robot.title)
        truth.placement_errors[j] = np.concatenate([v[:3] * length, np.resize(v[3:], 3) * angle
                                                    if len(v) == 6 else np.zeros(3)])
    else:  # joint_offsets
        scale = np.array([length if robot.is_prismatic(j) else angle for j in joints])
        if h.where:
            j = _index(joints, h.where, h, "a 1-dof joint of " + robot.title)
            truth.joint_offsets[j] = v[0] * scale[j]
        elif len(v) in (1, len(joints)):
            truth.joint_offsets = np.resize(v, len(joints)) * scale
        else:
            raise StiffnessError(f"--effect {h.label}: one value (every joint) or one per joint "
                                 f"({', '.join(joints)}), got {len(v)}")


@dataclass
class PoseSimulation:
    """A simulated pose campaign and its hidden truth.

    Attributes
    ----------
    campaign
        The pose campaign (SI), as a tracker would measure it.
    hidden
        The truth it hides (SI).
    effects
        The hidden effects as given.
    noise_std_m
        Position noise std (m) per component.
    effect_rms_m
        Per hidden effect label (``joint_compliance`` for ``kq``'s springs, ``drift``), the RMS
        change (m) its removal makes to the noise-free marker positions (with the effects that
        act through a spring removed with it).
    settings
        The simulation's inputs (JSON-ready).
    effect_rms_beyond_frame_m
        The same change once the positions without the effect are moved rigidly onto the
        truth (the measuring frame a pose fit always finds): what the campaign can show of it
        (m; NaN when the markers span too few points).
    """

    campaign: PoseCampaign
    hidden: HiddenPoseErrors
    effects: list[HiddenEffect]
    noise_std_m: float
    effect_rms_m: dict[str, float]
    settings: dict
    effect_rms_beyond_frame_m: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict:
        """The object ``stiffness simulate --kind poses --json`` prints: :meth:`truth`."""
        return self.truth()

    def truth(self, folder: Path | None = None) -> dict:
        """The hidden truth (JSON-ready), documented in ``truth.json``: the robot's source as
        given, or relative to ``folder`` (:func:`~stiffness.files.written_source`). Keys as a
        deflection simulation's where they mean the same; ``hidden`` holds the truth in SI
        (:class:`~stiffness.planning.simulate_poses.HiddenPoseErrors`; a rigid spring's
        stiffness ``null``)."""
        c, h = self.campaign, self.hidden
        lu = c.units.length_to_si
        robot = self.settings["robot"]
        if folder is not None:
            robot = {**robot, "source": written_source(robot["source"], folder)}
        names = dict.fromkeys(["joint_compliance"] if self.settings["kq"] is not None else [])
        names.update(dict.fromkeys(e.name for e in self.effects))
        return {
            "format": "stiffness-simulation-truth", "kind": "poses", "robot": robot,
            "compliant_joints": list(c.robot.compliant_joints),
            "k_theta_SI": None if h.stiffness is None else [
                float(k) if math.isfinite(k) else None for k in h.stiffness],
            "markers": [{"name": m.name, "frame": m.frame, "offset": (m.offset / lu).tolist(),
                         "true_offset": (o / lu).tolist()}
                        for m, o in zip(c.markers, h.marker_offsets, strict=True)],
            "hidden_effects": [e.to_dict() for e in self.effects],
            "expected_missing_effects": list(names),
            "effect_rms": {k: v / lu for k, v in self.effect_rms_m.items()},
            "effect_rms_noise_units": {k: v / self.noise_std_m if self.noise_std_m > 0 else None
                                       for k, v in self.effect_rms_m.items()},
            "effect_rms_beyond_frame": {k: None if math.isnan(v) else v / lu
                                        for k, v in self.effect_rms_beyond_frame_m.items()},
            "noise_std": self.noise_std_m / lu, "unit": c.units.length,
            "value_units": _value_units(c.units),
            "hidden": _hidden_dict(h),
            "settings": {**self.settings, "robot": robot},
            "model": ("exact placements and static equilibrium of the true robot under its "
                      "weight and the payload (stiffness.planning.simulate_poses)"),
        }

    def write(self, folder: str | Path) -> Path:
        """Write ``campaign.toml``, ``measurements.csv`` and ``truth.json`` into ``folder``,
        published together by one rename; returns the toml."""
        folder = Path(folder)
        refuse_foreign_folder(folder, TRUTH_FILE, "simulated campaign",
                              writes=(CAMPAIGN_FILE, "measurements.csv"))
        with staged_folder(folder, keep_others=True) as stage:
            written = write_pose_campaign(self.campaign, stage)
            atomic_write(stage / TRUTH_FILE, json.dumps(self.truth(folder), indent=1) + "\n")
        self.campaign.path = folder / written.name
        return self.campaign.path


def _value_units(units: Units) -> dict[str, str]:
    """The unit of each effect's values (``truth.json``'s ``value_units``)."""
    a, length = units.angle, units.length
    return {"frame": f"{a}, then {length}", "markers": length,
            "joint_offsets": f"{a} ({length} prismatic)", "geometry": f"{length}, then {a}",
            "base_tilt": a, "joint_compliance": "N.m/rad (N/m prismatic)",
            "link_compliance": "N.m/rad", "transversal_compliance": "N.m/rad",
            "backlash": f"{a} ({length} prismatic)",
            "nonlinear_joint_stiffness": "1/(N.m) (1/N prismatic)",
            "gravity_compensator": "N/m, N"}


def _hidden_dict(h: HiddenPoseErrors) -> dict:
    """``h`` JSON-ready (SI; a rotation as its rotation vector, rad)."""
    def listed(a: np.ndarray | None) -> list | None:
        return None if a is None else np.asarray(a, dtype=float).tolist()

    return {"frame_rotation_rad": pin.log3(h.frame_rotation).tolist(),
            "frame_translation_m": listed(h.frame_translation),
            "marker_offsets_m": listed(h.marker_offsets), "joint_offsets": listed(h.joint_offsets),
            "placement_errors": listed(h.placement_errors), "drift_m": listed(h.drift),
            "base_tilt_rad": listed(h.base_tilt), "backlash": listed(h.backlash),
            "nonlinear_beta": listed(h.nonlinear),
            "link_compliance_rad_per_Nm": {k: listed(v) for k, v in h.link_compliance.items()},
            "transversal_compliance_rad_per_Nm": {
                k: listed(v) for k, v in h.transversal_compliance.items()},
            "gravity_compensator_N_per_m_N": {k: listed(v) for k, v in h.compensator.items()}}


def simulate_poses(
    robot: Robot | str, markers: list[Marker] | None = None, poses: int = DEFAULT_POSES,
    effects: Sequence[HiddenEffect | str] | None = None,
    kq: list[float] | np.ndarray | None = None, noise_std_m: float = DEFAULT_NOISE_STD_M,
    seed: int = 0,
    payload: np.ndarray | list[float] | None = None, rotations: bool = False,
    rotation_noise_std_rad: float | None = None, drift_m: np.ndarray | list[float] | None = None,
    units: Units | None = None, name: str | None = None, frame: str | None = None,
    compliant_joints: list[str] | tuple[str, ...] | None = None, fixed_base: bool = False,
    declare_noise: bool = True,
) -> PoseSimulation:
    """Simulate a pose campaign with hidden effects: ``stiffness simulate --kind poses``
    (:meth:`PoseSimulation.to_dict` is its ``--json`` object, :meth:`PoseSimulation.write` its
    ``--out`` folder). The campaign is :func:`~stiffness.planning.simulate_poses.
    simulate_pose_campaign`'s of :func:`hidden_pose_errors`'s truth, the same seed the same.

    Parameters
    ----------
    robot, frame, compliant_joints, fixed_base
        Robot source (or a loaded robot, taken as it is), its target frame (where the payload
        acts; default the robot's), its springs (where the effects on a spring may act and
        ``diagnose`` looks for them) and whether a floating base is fixed.
    markers
        The markers with their declared offsets (m); default one, ``tip``, at the target frame.
    poses, seed
        Number of reachable poses drawn; random seed (poses, noise).
    effects, kq, drift_m
        Hidden effects (their ``NAME[:WHERE]=VALUE`` text, :func:`parse_pose_effect`, values in
        ``units``); the stiffness of every compliant joint (N.m/rad, N/m; default none: rigid
        unless ``joint_compliance`` gives a spring); the measuring frame origin's drift over the
        campaign (m).
    noise_std_m, rotations, rotation_noise_std_rad
        Position noise std per component (m); whether the markers' orientations are measured
        too, and their noise std (rad; default ``noise_std_m / 0.1 m``; refused without
        ``rotations``: it would be ignored).
    payload
        Constant wrench at the target frame on every pose, world axes (N, then N.m), or ``None``.
    units, name, declare_noise
        Units of the files and of the effect values (default deg, N, mm); campaign name;
        whether the campaign declares its noise stds.

    Raises
    ------
    StiffnessError
        On bad inputs (an unknown effect or place, a count below one, a negative noise, a
        rotation noise without ``rotations``).
    """
    units = units or Units()
    given = robot if isinstance(robot, Robot) else load_robot(
        str(robot), frame=frame, compliant_joints=None if compliant_joints is None
        else list(compliant_joints), fixed_base=fixed_base)
    markers = markers if markers is not None else [Marker("tip", given.target_frame)]
    _check_robot_and_markers(given, markers)
    poses = whole_number(poses, "poses")
    if poses > MAX_ROWS:
        raise StiffnessError(f"{poses} poses is more than {MAX_ROWS:.0e}; ask for fewer")
    if not (noise_std_m >= 0 and math.isfinite(noise_std_m)):
        raise StiffnessError(f"noise std must be >= 0, got {noise_std_m}")
    wrench = None if payload is None else float_array(payload, "payload", "3 forces (N) or a "
                                                      "wrench of 6 (N, N.m)").reshape(-1)
    if wrench is not None and wrench.shape not in ((3,), (6,)):
        raise StiffnessError(f"payload: three forces (N) or six wrench components (N, N.m), "
                             f"got {wrench.size}")
    wrench = None if wrench is None else np.resize(np.concatenate([wrench, np.zeros(3)]), 6)
    hidden_effects = [parse_pose_effect(e) if isinstance(e, str) else e for e in effects or []]
    truth = hidden_pose_errors(given, markers, hidden_effects, kq, units, drift_m)
    std = rotation_noise_std(rotation_noise_std_rad, noise_std_m, rotations)
    rotation_std = std if rotations else None
    seed = whole_number(seed, "seed", 0)
    campaign = simulate_pose_campaign(given, markers, truth, poses, noise_std_m, seed, wrench,
                                      units, name or "simulated-poses", rotation_std)
    campaign.settings = replace(campaign.settings, fixed_base=given.fixed_base)
    if not declare_noise:
        campaign.noise_std = campaign.noise_std_rotation = None
    sizes, beyond = _effect_sizes(given, markers, hidden_effects, kq, units, drift_m,
                                  campaign.q, wrench)
    _warn_unloaded(given, sizes, wrench)
    settings = {"robot": {"source": given.name, "frame": given.target_frame},
                "poses": poses, "seed": seed,
                "kq": None if kq is None else np.asarray(truth.stiffness).tolist(),
                "payload_SI": None if wrench is None else wrench.tolist(),
                "rotations": rotations, "rotation_noise_std_rad": rotation_std,
                "drift_m": truth.drift.tolist(), "declare_noise": declare_noise}
    return PoseSimulation(campaign, truth, hidden_effects, noise_std_m, sizes, settings, beyond)


#: A hidden effect's RMS on the markers below which it moves none of them (m): float rounding.
UNSEEN_M = 1e-12


def _warn_unloaded(robot: Robot, sizes: dict[str, float], wrench: np.ndarray | None) -> None:
    """Warn (:class:`~stiffness.errors.FlagValueWarning`, one line) when the robot weighs
    nothing (its file has no link masses: the SK120, the hexapod) and no payload loads it, so
    that hidden effects move no marker (``sizes``: each one's RMS, m): springs that carry no
    torque, which a user reading ``0 mm RMS`` may not trace to the missing ``--load``."""
    unseen = [label for label, size in sizes.items() if size < UNSEEN_M]
    if not unseen or (wrench is not None and np.any(wrench)) or pin.computeTotalMass(
            robot.model) > 0:
        return
    warn_user(f"hidden {', '.join(unseen)} moves no marker: {robot.title} weighs nothing (its "
              f"robot file has no link masses) and no payload loads its springs; give one "
              f"(--load FX,FY,FZ in N; from Python payload=[...])", FlagValueWarning)


def _check_robot_and_markers(robot: Robot, markers: list[Marker]) -> None:
    """Refuse no marker, a marker name given twice or a marker on a frame the robot does not
    have (one line)."""
    names = [m.name for m in markers]
    if not names or len(set(names)) != len(names):
        raise StiffnessError(f"a pose campaign needs markers of distinct names, got {names}")
    frames = list(dict.fromkeys(f.name for f in robot.model.frames))
    for m in markers:
        if not robot.model.existFrame(m.frame):
            raise UnknownFrameError(f"marker {m.name!r}: frame {m.frame!r} is not a frame of "
                                    f"{robot.title}; {did_you_mean(m.frame, frames)}",
                                    name=m.frame, choices=frames)


def _effect_sizes(robot: Robot, markers: list[Marker], hidden: list[HiddenEffect],
                  kq: list[float] | np.ndarray | None, units: Units,
                  drift_m: np.ndarray | list[float] | None, poses: np.ndarray,
                  wrench: np.ndarray | None) -> tuple[dict[str, float], dict[str, float]]:
    """Each hidden effect's RMS change (m) of the noise-free marker positions at the
    campaign's commanded ``poses`` (rad, m): the truth against the truth without it (and
    without what acts through a spring it removes); and that change beyond a rigid move of
    the measuring frame (:func:`_beyond_frame`)."""
    def positions(effects: list[HiddenEffect], k: list[float] | np.ndarray | None,
                  drift: np.ndarray | list[float] | None) -> np.ndarray:
        truth = hidden_pose_errors(robot, markers, effects, k, units, drift)
        return simulate_pose_campaign(robot, markers, truth, len(poses), 0.0, 0, wrench,
                                      coordinates=poses).positions

    full = positions(hidden, kq, drift_m)
    without = {}
    if kq is not None:
        without["joint_compliance"] = positions(
            [h for h in hidden if h.name not in _THROUGH_SPRING], None, drift_m)
    for h in hidden:
        spring = h.where if h.name == "joint_compliance" else None
        without[h.label] = positions(
            [e for e in hidden if e is not h and not (e.name in _THROUGH_SPRING and e.where
                                                      == spring)], kq, drift_m)
    if drift_m is not None and np.any(np.asarray(drift_m, dtype=float) != 0):
        without["drift"] = positions(hidden, kq, None)
    sizes = {k: float(np.sqrt(np.nanmean((v - full) ** 2))) for k, v in without.items()}
    return sizes, {k: _beyond_frame(v, full) for k, v in without.items()}


def _beyond_frame(other: np.ndarray, full: np.ndarray) -> float:
    """RMS (m) of the marker positions ``full`` against ``other`` (both (poses, markers, 3))
    once ``other`` is moved rigidly onto ``full`` (the measuring frame every pose fit finds):
    the part of a hidden effect a pose campaign can show (a base joint's zero offset about a
    vertical axis has none); NaN when the markers span too few points to fit a frame."""
    a, b = other.reshape(-1, 3), full.reshape(-1, 3)
    try:
        rot, shift = align_frames(a, b)
    except StiffnessError:
        return math.nan
    return float(np.sqrt(np.nanmean((a @ rot.T + shift - b) ** 2)))
