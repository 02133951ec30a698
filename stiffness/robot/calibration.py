"""A pose calibration's model file (``final-model.json`` of a pose diagnosis) read, and the
calibrated robot it describes (docs/absolute-poses.md, docs/model-file.md).

The file (``"kind": "pose-calibration"``) holds the robot it calibrates (``robot.source``, a
path relative to the file's folder or a robot name; ``frame``, ``target_offset_m``,
``compliant_joints``, ``fixed_base``), the measuring frame, the markers, the families fitted and
each parameter by label (SI). :func:`read_pose_calibration` is the one reader of that schema;
the calibration layer builds its marker-position model from it, the elastic layer its
``ElasticModel``.

The file is also a robot source: :func:`calibrated_source` is the robot it names with the
calibrated geometry folded into the joint placements (``M_j exp(eps_j) M_joint(delta_j)``: each
joint's placement error and zero offset, so that the commanded joint values give the calibrated
pose), so ``load_robot("final-model.json")`` is the calibrated robot wherever a robot is
(re)loaded by its source. Compliance is not geometry: the springs and the other elastic
families stay in the file (:mod:`stiffness.elastic.model_file`).

Units: SI (m, rad).
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.errors import DataFileWarning, FileFormatError, warn_user
from stiffness.files import looks_like_path, read_json, resolve_source
from stiffness.robot.kinematics import frame_id
from stiffness.robot.sources import (
    RobotSource,
    robots_directory,
    shipped_robots,
)
from stiffness.robot.sources import resolve_source as resolve_robot_source

#: ``kind`` of a pose calibration's model file.
POSE_MODEL_KIND = "pose-calibration"
#: Names and units of the six components of a placement (the measuring frame's, a joint's).
PLACEMENT_AXES = ("x", "y", "z", "rx", "ry", "rz")
PLACEMENT_UNITS = ("m", "m", "m", "rad", "rad", "rad")
#: Frame added by :func:`with_marker_frames` at the measuring system's origin.
MEASURING_FRAME = "measuring_frame"


def frame_label(axis: str) -> str:
    """Label of the measuring frame's parameter along ``axis`` (of :data:`PLACEMENT_AXES`)."""
    return f"frame {axis}"


def marker_label(marker: str, axis: str) -> str:
    """Label of a marker's offset correction along ``axis`` (x, y, z)."""
    return f"{marker} offset {axis}"


def mounting_label(marker: str, axis: str) -> str:
    """Label of a marker's fitted mounting turn about ``axis`` (rx, ry, rz: its own axes)."""
    return f"{marker} mounting {axis}"


def zero_label(joint: str) -> str:
    """Label of a joint's zero offset."""
    return f"{joint} zero"


def placement_label(joint: str, axis: str) -> str:
    """Label of a joint's placement error along ``axis`` (of :data:`PLACEMENT_AXES`)."""
    return f"{joint} placement {axis}"


def perturbed_placement(placement: pin.SE3, error: np.ndarray) -> pin.SE3:
    """A joint placement with its error ``(translation m, rotation rad)`` applied on the
    right: ``M_j exp(eps_j)``."""
    return placement * pin.exp6(pin.Motion(np.asarray(error, dtype=float)))


@dataclass
class PoseCalibration:
    """A pose calibration's model file, read (SI).

    Attributes
    ----------
    path
        The file.
    source
        The calibrated robot's source: a robot name, or a path resolved against the file's
        folder.
    frame, target_offset_m, compliant_joints, fixed_base
        The campaign's target frame (``None``: the robot's default), target offset (m), springs
        and base fixing.
    rotation, translation
        Starting estimate of the measuring frame (3, 3) and (3,) m (``frame`` parameters apply
        on top).
    markers
        ``(name, frame, nominal offset (3,) m)`` of each marker.
    load_frame
        Frame of the campaign's applied wrenches, or ``None``.
    families, settings
        The parameter families fitted and their fixed settings.
    parameters
        Each parameter's row (``family``, ``parameter`` label, ``unit``, ``value``, ``fitted``,
        ``std``, ``interval_95``), in the model's order.
    name
        The calibrated robot's name (``robot.name``; "" in a file without it).
    marker_rotations
        Each marker's declared axes in its frame's axes as a rotation vector (3,) rad, by name
        (a 6-D probe's mounting, the file's ``rotation_rad``); a marker not named has its
        frame's axes.
    """

    path: Path
    source: str
    frame: str | None
    target_offset_m: np.ndarray
    compliant_joints: tuple[str, ...]
    fixed_base: bool
    rotation: np.ndarray
    translation: np.ndarray
    markers: list[tuple[str, str, np.ndarray]]
    load_frame: str | None
    families: tuple[str, ...]
    settings: dict
    parameters: list[dict]
    name: str = ""
    marker_rotations: dict[str, np.ndarray] = field(default_factory=dict)

    def declared_rotation(self, name: str) -> np.ndarray:
        """The declared axes (3, 3) of marker ``name`` in its frame's axes (``rotation_rad``)."""
        return pin.exp3(self.marker_rotations.get(name, np.zeros(3)))

    def marker_rotation(self, name: str) -> np.ndarray:
        """The calibrated axes (3, 3) of marker ``name`` in its frame's axes: the declared ones
        turned by the fitted mounting turn ``delta`` (its own axes, rad) where the fit has one,
        ``M exp(delta)``."""
        v = self.values()
        turn = np.array([v.get(mounting_label(name, a), 0.0) for a in ("rx", "ry", "rz")])
        return self.declared_rotation(name) @ pin.exp3(turn)

    def is_oriented(self, name: str) -> bool:
        """Whether the fit turned marker ``name``'s mounting (its orientations measured)."""
        return mounting_label(name, "rx") in self.values()

    def values(self) -> dict[str, float]:
        """Parameter label -> SI value."""
        return {p["parameter"]: float(p["value"]) for p in self.parameters}

    def robot_options(self) -> dict:
        """Keyword arguments of :func:`stiffness.robot.robot.load_robot` for the calibrated
        robot (its source is the file itself)."""
        return {"frame": self.frame, "target_offset": self.target_offset_m,
                "compliant_joints": self.compliant_joints, "fixed_base": self.fixed_base}

    def measuring_placement(self) -> tuple[np.ndarray, np.ndarray]:
        """(R, t) with ``y = R p + t`` for a robot-world point ``p``: the calibrated measuring
        frame (:func:`measuring_placement`)."""
        return measuring_placement(self.rotation, self.translation, self.values())

    def marker_offset(self, k: int) -> np.ndarray:
        """Calibrated offset (3,) m of marker ``k`` in its frame's axes."""
        name, _, nominal = self.markers[k]
        v = self.values()
        return nominal + np.array([v.get(marker_label(name, a), 0.0) for a in "xyz"])


def measuring_placement(rotation0: np.ndarray, translation0: np.ndarray,
                        values: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) with ``y = R p + t`` for a robot-world point ``p``: a pose calibration's
    measuring frame, its starting estimate ``R_0, t_0`` (m) corrected by the ``frame``
    family's parameters in ``values`` (SI, by label; absent: zero), ``exp(omega) R_0`` and
    ``t_0 + t`` (docs/absolute-poses.md, *What is fitted*)."""
    part = np.array([values.get(frame_label(a), 0.0) for a in PLACEMENT_AXES])
    return pin.exp3(part[3:]) @ np.asarray(rotation0, float), np.asarray(translation0,
                                                                         float) + part[:3]


def is_json(source: str | os.PathLike) -> bool:
    """Whether a robot source names a JSON file (a robot only as a pose calibration's file)."""
    return Path(str(source)).suffix.lower() == ".json"


def is_pose_calibration(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a pose calibration's model file (a JSON object of that kind).

    Raises
    ------
    StiffnessError
        The file is missing, unreadable or not JSON (named, whatever kind it was meant to be).
    """
    refuse_campaign(path)
    doc = read_json(path, "model file")
    return isinstance(doc, dict) and doc.get("kind") == POSE_MODEL_KIND


def refuse_campaign(path: str | os.PathLike) -> None:
    """Refuse a campaign (a ``.toml`` file, or a folder holding a ``campaign.toml``) given
    where a model file is expected, in those words (it was 'not JSON; fix the syntax').

    Raises
    ------
    FileFormatError
        ``path`` is a campaign.
    """
    p = Path(path)
    if p.suffix.lower() == ".toml" or (p / "campaign.toml").is_file():
        raise FileFormatError("a campaign, not a model file; give the identified-model.json of "
                              "`stiffness identify` or the final-model.json of `stiffness "
                              "diagnose --out` (stiffness validate takes MODEL, then CAMPAIGN)",
                              path=p)


def read_pose_calibration(path: str | os.PathLike) -> PoseCalibration:
    """Read a pose calibration's model file, every number checked finite and of its shape.

    Raises
    ------
    FileFormatError
        Not a pose model file, a missing or malformed key, or a number not finite or not of
        its shape (one line naming it).

    Warns
    -----
    DataFileWarning
        The file's ``plausibility`` says the fit is no calibration (a length unit read wrong,
        angles beyond a few degrees, or placements shifted beyond what those degrees turn
        their link by: :mod:`stiffness.calibration.pose_plausibility`), with its verdict.
    """
    path = Path(path)
    doc = read_json(path, "model file")
    if not isinstance(doc, dict) or doc.get("kind") != POSE_MODEL_KIND:
        raise FileFormatError(f"not a pose model file (kind {POSE_MODEL_KIND!r}); give the "
                              "final-model.json of a pose diagnosis", path=path)
    judged = doc.get("plausibility")
    if isinstance(judged, dict) and judged.get("plausible") is False:
        warn_user(f"{path}: {judged.get('verdict')}",
                  DataFileWarning)
    try:
        r = doc["robot"]
        frame = r["frame"]
        cal = PoseCalibration(
            path, _source(str(r["source"]), path.parent),
            None if frame is None else str(frame),
            np.array(r.get("target_offset_m", [0.0, 0.0, 0.0]), float),
            tuple(str(j) for j in r["compliant_joints"]), bool(r.get("fixed_base", False)),
            np.array(doc["measuring_frame"]["rotation"], float),
            np.array(doc["measuring_frame"]["translation_m"], float),
            [(str(m["name"]), str(m["frame"]), np.array(m["offset_m"], float))
             for m in doc["markers"]],
            None if doc["load_frame"] is None else str(doc["load_frame"]),
            tuple(str(f) for f in doc["families"]), dict(doc.get("settings", {})),
            [_parameter(p) for p in doc["parameters"]], str(r.get("name", "")),
            {str(m["name"]): np.array(m["rotation_rad"], float)
             for m in doc["markers"] if "rotation_rad" in m})
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise FileFormatError(f"malformed pose model file ({exc!r}); rewrite it with "
                              "stiffness diagnose --out", path=path) from exc
    _check_numbers(cal)
    return cal


def _source(source: str, folder: Path) -> str:
    """The robot source resolved against the file's folder (a file written before paths were
    written relative to it, whose path is not there, keeps the path as written)."""
    resolved = resolve_source(source, folder)
    return resolved if not looks_like_path(source) or Path(resolved).exists() else source


def _parameter(p: dict) -> dict:
    """One parameter row with its label and value typed (a KeyError or ValueError when not)."""
    if not isinstance(p, dict) or not isinstance(p["parameter"], str) or isinstance(
            p["value"], bool):
        raise ValueError(f"parameter {p!r} is not an object with a label and a value")
    return {**p, "value": float(p["value"])}


def _check_numbers(cal: PoseCalibration) -> None:
    """Refuse numbers that are not finite or not of their shape: the parameters, the target
    offset and marker offsets (3,), and the measuring frame (a 3x3 rotation, a 3-vector)."""
    bad = [p["parameter"] for p in cal.parameters if not np.isfinite(p["value"])]
    bad += [f"marker {name} offset_m" for name, _, offset in cal.markers
            if offset.shape != (3,) or not np.all(np.isfinite(offset))]
    bad += [f"marker {name} rotation_rad" for name, turn in cal.marker_rotations.items()
            if turn.shape != (3,) or not np.all(np.isfinite(turn))]
    if cal.target_offset_m.shape != (3,) or not np.all(np.isfinite(cal.target_offset_m)):
        bad.append("robot target_offset_m")
    rotation, translation = cal.rotation, cal.translation
    if rotation.shape != (3, 3) or not np.all(np.isfinite(rotation)) or not np.allclose(
            rotation.T @ rotation, np.eye(3), atol=1e-6) or np.linalg.det(rotation) < 0:
        bad.append("measuring_frame rotation (a 3x3 rotation matrix)")
    if translation.shape != (3,) or not np.all(np.isfinite(translation)):
        bad.append("measuring_frame translation_m")
    if bad:
        raise FileFormatError(f"pose model file: {bad[0]} is not a finite number of its shape; "
                              "rewrite it with stiffness diagnose --out", path=cal.path)


def calibrated_model(cal: PoseCalibration, model: pin.Model) -> pin.Model:
    """``model`` with the calibrated geometry folded into its joint placements: each 1-dof
    joint's placement error and then its zero offset, ``M_j exp(eps_j) M_joint(delta_j)``, so
    that the commanded joint values give the calibrated pose (joints by name; a joint without
    parameters is left as is)."""
    values = cal.values()
    out = pin.Model(model)
    joints = [j for j in range(1, out.njoints) if out.joints[j].nv == 1]
    step = np.zeros(out.nv)
    for j in joints:
        name = out.names[j]
        error = np.array([values.get(placement_label(name, a), 0.0) for a in PLACEMENT_AXES])
        out.jointPlacements[j] = perturbed_placement(out.jointPlacements[j], error)
        step[out.joints[j].idx_v] = values.get(zero_label(name), 0.0)
    data = out.createData()
    pin.forwardKinematics(out, data, pin.integrate(out, pin.neutral(out), step))
    for j in joints:
        out.jointPlacements[j] = pin.SE3(data.liMi[j])
    return out


def calibrated_source(path: str | os.PathLike) -> RobotSource:
    """The robot source of a pose calibration's file: the source it names, read, with the
    calibrated geometry (:func:`calibrated_model`) and the file's target frame and springs as
    its settings, named by the file's path.

    Raises
    ------
    StiffnessError
        Not a pose calibration's file (a deflection model names its robot: give it with
        ``--model``), a malformed one, or a robot that cannot be read.
    """
    if not is_pose_calibration(path):
        raise FileFormatError("a JSON file is a robot only as a pose calibration's "
                              "final-model.json; give a model file with --model (it names its "
                              "robot)", path=path)
    cal = read_pose_calibration(path)
    nominal = resolve_robot_source(cal.source)
    settings = dict(nominal.settings)
    if cal.frame is not None:
        settings["frame"] = cal.frame
    settings["compliant_joints"] = list(cal.compliant_joints)
    return dataclasses.replace(nominal, name=str(path),
                               model=calibrated_model(cal, nominal.model), settings=settings,
                               notes=[*nominal.notes, f"calibrated geometry of {path}"])


def with_marker_frames(robot, cal: PoseCalibration):
    """The calibrated robot (:class:`stiffness.robot.robot.Robot` loaded from the file) with a
    frame ``marker_<name>`` at each marker's calibrated offset and :data:`MEASURING_FRAME` at
    the measuring system's origin, fixed to the world: the rigid positions of the marker frames
    seen from it are the calibration's rigid predictions (``robot export --urdf``)."""
    model = pin.Model(robot.model)
    for k, (name, frame_name, _) in enumerate(cal.markers):
        frame = model.frames[frame_id(model, frame_name)]
        offset = pin.SE3(cal.marker_rotation(name), cal.marker_offset(k))
        model.addFrame(pin.Frame(f"marker_{name}", frame.parentJoint,
                                 frame_id(model, frame_name), frame.placement * offset,
                                 pin.FrameType.OP_FRAME))
    rot, trans = cal.measuring_placement()
    model.addFrame(pin.Frame(MEASURING_FRAME, 0, 0, pin.SE3(rot, trans).inverse(),
                             pin.FrameType.OP_FRAME))
    return dataclasses.replace(robot, model=model, data=model.createData())


# ------------------------------------------------------------------------------------------
# which robot


def robot_identity(source: str) -> str:
    """A comparable name of a robot source: a shipped robot's name (also for a path to a file
    in its folder), a resolved path, the example-robot-data name; a pose calibration's file
    stands for the robot it calibrates."""
    if source in shipped_robots():
        return source
    path = Path(source)
    if is_json(path) and path.is_file() and is_pose_calibration(path):
        return robot_identity(read_pose_calibration(path).source)
    if looks_like_path(source) or path.exists():
        resolved = path.resolve()
        for name in shipped_robots():
            if resolved.parent == (robots_directory() / name).resolve():
                return name
        return str(resolved)
    return source


def moved_robot_file(recorded: str, name: str, given: str) -> bool:
    """Whether the robot source ``given`` stands in for the robot file ``recorded`` that is no
    longer where a model file names it (the model copied away from its URDF): ``recorded`` a
    path that does not exist, ``given`` an existing file whose robot has the recorded ``name``
    (its URDF's robot name, or its ``robot.toml``'s)."""
    if not name or not looks_like_path(recorded) or Path(recorded).exists() \
            or not Path(given).exists():
        return False
    found = resolve_robot_source(given)
    return name in (found.model.name, found.settings.get("name"))


def kinematic_fingerprint(model: pin.Model) -> str:
    """A short hash of a model's kinematics: its joints' names, types and placements (rounded
    to 1e-9 m and rad). Two robots with the same fingerprint move their frames alike."""
    digest = hashlib.sha256()
    for j in range(1, model.njoints):
        placement = model.jointPlacements[j]
        numbers = np.round(np.concatenate([placement.translation,
                                           placement.rotation.reshape(-1)]), 9) + 0.0
        digest.update(f"{model.names[j]}:{model.joints[j].shortname()}:"
                      f"{model.parents[j]}:{numbers.tolist()}".encode())
    return digest.hexdigest()[:16]


def robot_signature(robot) -> tuple[tuple[str, ...], str]:
    """A robot's (:class:`stiffness.robot.robot.Robot`, which imports this module)
    coordinates and :func:`kinematic_fingerprint`: what two robots share when a campaign of
    one is a campaign of the other."""
    return tuple(robot.coordinate_joints), kinematic_fingerprint(robot.model)


def robot_difference(mine, theirs) -> str | None:
    """What differs between two robots' :func:`robot_signature`: ``"coordinates"``,
    ``"kinematics"`` or ``None`` (the same robot, or a copy of its files)."""
    a, b = robot_signature(mine), robot_signature(theirs)
    if a == b:
        return None
    return "coordinates" if a[0] != b[0] else "kinematics"


def robot_description(robot) -> str:
    """``'title' (n coordinates, kinematics <fingerprint>)``, how a refusal names a robot."""
    coordinates, fingerprint = robot_signature(robot)
    return f"{robot.title!r} ({len(coordinates)} coordinates, kinematics {fingerprint})"
