"""Loading robots: URDF files, example-robot-data names and the robots shipped in ``robots/``.

:func:`load_robot` returns a :class:`Robot`: the Pinocchio model, its loop closures, the
measurement target (a frame plus an offset in that frame) and which joints are springs.

Coordinates. A robot's *coordinates* are the values of its independent joints (every joint with
a degree of freedom except the passive joints of closed loops), one value per joint, in model
order: an angle (rad) for a revolute or continuous joint, a length (m) for a prismatic one.
:meth:`Robot.configuration` turns them into a full Pinocchio configuration with the loops closed.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.errors import (
    FileFormatError,
    LoopClosureError,
    MissingFileError,
    StiffnessError,
    UnknownFrameError,
    UnknownJointError,
    UnknownRobotError,
    did_you_mean,
)
from stiffness.files import read_toml
from stiffness.model.loops import LoopClosure, build_loop_closure, read_loop_declaration

#: Name of the operational frame added at the measurement target.
TARGET_FRAME = "stiffness_target"

#: Largest joint step (rad or m) of the continuation used to close loops along a path.
_CONTINUATION_STEP = 0.15
#: Largest Newton correction of the passive joints (rad or m) accepted in one continuation step.
_BRANCH_JUMP = 0.05

_SUPPORTED_JOINTS = {
    "JointModelRX", "JointModelRY", "JointModelRZ", "JointModelRevoluteUnaligned",
    "JointModelPX", "JointModelPY", "JointModelPZ", "JointModelPrismaticUnaligned",
    "JointModelRUBX", "JointModelRUBY", "JointModelRUBZ", "JointModelRevoluteUnboundedUnaligned",
}


def robots_directory() -> Path:
    """Folder of the shipped robots: the repository's ``robots/``, installed as package data.

    In order: ``$STIFFNESS_ROBOTS`` if set; the ``robots/`` folder of the source checkout this
    package runs from (``PYTHONPATH`` or an editable install: the checkout's own data, even if
    another copy of the package is installed); else the installed package data
    ``stiffness.robots`` (``robots/`` mapped into the wheel), read with :mod:`importlib.resources`.
    """
    env = os.environ.get("STIFFNESS_ROBOTS")
    if env:
        return Path(env)
    checkout = Path(__file__).resolve().parents[2]
    if (checkout / "pyproject.toml").is_file() and (checkout / "robots" / "__init__.py").is_file():
        return checkout / "robots"
    try:
        data = resources.files("stiffness.robots")
    except ModuleNotFoundError:
        data = None
    if not isinstance(data, Path) or not data.is_dir():
        raise StiffnessError(
            "the shipped robots are missing: this copy of stiffness has no robots/ package data "
            "(reinstall it with `pip install .`, or set STIFFNESS_ROBOTS to a robots/ folder)"
        )
    return data


def shipped_robots() -> list[str]:
    """Names of the robots shipped in ``robots/`` (folders holding a ``robot.toml``)."""
    root = robots_directory()
    return sorted(p.parent.name for p in root.glob("*/robot.toml"))


def example_robot_names() -> list[str]:
    """Names example-robot-data can load."""
    from example_robot_data import robots_loader

    return sorted(robots_loader.ROBOTS)


@dataclass
class Robot:
    """A robot model ready for elastostatics.

    Attributes
    ----------
    name
        Source name (shipped robot, example-robot-data name or URDF path).
    model, data
        Pinocchio model (with the target frame added) and its data.
    target_frame
        Name of the frame carrying the measurement target.
    target_offset
        Target position in ``target_frame`` axes (m).
    target_frame_id
        Id of the operational frame :data:`TARGET_FRAME` placed at the target.
    coordinate_joints
        Independent joints, in model order; a robot's coordinates are their values.
    compliant_joints
        Joints modelled as springs (a subset of ``coordinate_joints``); the rest are rigid.
    loop
        Loop closures, or ``None`` for a tree.
    visual_model
        Pinocchio visual geometry, when the source provides meshes (for the viewer).
    defaults
        Shipped defaults (``q`` in rad/m, ``k_theta`` in SI), empty for other sources. Keys
        read by the toolkit: ``q_deg`` or ``q_SI`` (default coordinates, deg, or rad/m),
        ``k_theta_SI``, ``wrench_SI``, ``rest_q_SI`` (spring rest coordinates: the default load
        is then the wrench that holds the target there), ``twist_order`` (``"v-w"`` or
        ``"w-v"``: row order of printed 6x6 matrices).
    """

    name: str
    model: pin.Model
    data: pin.Data
    target_frame: str
    target_offset: np.ndarray
    target_frame_id: int
    coordinate_joints: tuple[str, ...]
    compliant_joints: tuple[str, ...]
    loop: LoopClosure | None = None
    visual_model: object | None = None
    defaults: dict = field(default_factory=dict)
    _reference: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)

    @property
    def n_coordinates(self) -> int:
        """Number of coordinates (independent joints)."""
        return len(self.coordinate_joints)

    @property
    def n_compliant(self) -> int:
        """Number of compliant joints."""
        return len(self.compliant_joints)

    def joint_v_index(self, joint: str) -> int:
        """Velocity index of a one-degree-of-freedom joint."""
        return self.model.joints[self.model.getJointId(joint)].idx_v

    @property
    def coordinate_v(self) -> np.ndarray:
        """Velocity indices of the coordinate joints."""
        return np.array([self.joint_v_index(j) for j in self.coordinate_joints], dtype=int)

    @property
    def compliant_v(self) -> np.ndarray:
        """Velocity indices of the compliant joints."""
        return np.array([self.joint_v_index(j) for j in self.compliant_joints], dtype=int)

    @property
    def compliant_in_coordinates(self) -> np.ndarray:
        """Position of each compliant joint in the coordinate vector."""
        return np.array([self.coordinate_joints.index(j) for j in self.compliant_joints], dtype=int)

    def coordinates_of(self, q: np.ndarray) -> np.ndarray:
        """Coordinates (rad or m) of a full configuration ``q``."""
        out = np.empty(self.n_coordinates)
        for i, name in enumerate(self.coordinate_joints):
            joint = self.model.joints[self.model.getJointId(name)]
            if joint.nq == 2:
                out[i] = np.arctan2(q[joint.idx_q + 1], q[joint.idx_q])
            else:
                out[i] = q[joint.idx_q]
        return out

    def _tree_configuration(self, coords: np.ndarray, base: np.ndarray) -> np.ndarray:
        q = base.copy()
        for value, name in zip(coords, self.coordinate_joints, strict=True):
            joint = self.model.joints[self.model.getJointId(name)]
            if joint.nq == 2:
                q[joint.idx_q: joint.idx_q + 2] = np.cos(value), np.sin(value)
            else:
                q[joint.idx_q] = value
        return q

    def configuration(self, coords: np.ndarray, seed: np.ndarray | None = None) -> np.ndarray:
        """Full Pinocchio configuration for the given coordinates, loops closed.

        Parameters
        ----------
        coords
            One value per coordinate joint (rad or m), shape (n_coordinates,).
        seed
            A closed configuration on the wanted assembly branch; the loop is closed by
            continuation (tangent predictor, Newton corrector) from it, by default from the
            robot's reference assembly (the closure at zero coordinates).

        Raises
        ------
        StiffnessError
            On a wrong length, a NaN or infinity, or a loop that cannot close.
        """
        coords = np.asarray(coords, dtype=float).reshape(-1)
        if coords.shape[0] != self.n_coordinates:
            raise StiffnessError(
                f"{self.name} has {self.n_coordinates} coordinates "
                f"({', '.join(self.coordinate_joints)}) but {coords.shape[0]} values were given"
            )
        if not np.all(np.isfinite(coords)):
            raise StiffnessError(f"joint coordinates must be finite numbers, got {coords.tolist()}")
        if self.loop is None:
            return self._tree_configuration(coords, pin.neutral(self.model))
        if seed is None:
            start_coords, q = self._reference_assembly()
        else:
            start_coords, q = self.coordinates_of(seed), seed
        return self._continue(start_coords, q, coords)

    def _continue(self, start: np.ndarray, q: np.ndarray, coords: np.ndarray) -> np.ndarray:
        """Close the loops along the straight coordinate path from ``start`` (closed at ``q``).

        Predictor: the tangent (first step) then the secant through the last two solutions,
        which carries the branch through singular poses (e.g. a flat parallelogram). Corrector:
        Newton on the passive joints. A step whose correction exceeds
        :data:`_BRANCH_JUMP` is halved, so the path cannot hop to another assembly branch.
        """
        span = float(np.max(np.abs(coords - start)))
        if span == 0.0:
            return self.loop.close(self.model, self.data, self._tree_configuration(coords, q))
        passive_q = np.concatenate([
            np.arange(j.idx_q, j.idx_q + j.nq)
            for j in (self.model.joints[self.model.getJointId(n)] for n in self.loop.passive_joints)
        ])
        nominal = min(1.0, _CONTINUATION_STEP / span)
        fraction, h = 0.0, nominal
        previous: tuple[np.ndarray, float] | None = None
        while fraction < 1.0 - 1e-12:
            h = min(h, 1.0 - fraction)
            if previous is None:
                pin.computeJointJacobians(self.model, self.data, q)
                dv = np.zeros(self.model.nv)
                dv[self.coordinate_v] = (coords - start) * h
                dv[self.loop.passive_v] = self.loop.passive_rates(
                    self.model, self.data, self.coordinate_v) @ dv[self.coordinate_v]
                predicted = pin.integrate(self.model, q, dv)
            else:
                predicted = q.copy()
                q_prev, h_prev = previous
                predicted[passive_q] += (q[passive_q] - q_prev[passive_q]) * h / h_prev
            target = start + (coords - start) * (fraction + h)
            try:
                closed = self.loop.close(
                    self.model, self.data, self._tree_configuration(target, predicted))
                jump = float(np.max(np.abs(closed[passive_q] - predicted[passive_q])))
            except StiffnessError:
                closed, jump = None, np.inf
            if jump > _BRANCH_JUMP:
                h /= 2.0
                if h < 1e-9:
                    raise LoopClosureError(
                        f"the loops of {self.name} cannot be closed continuously from "
                        f"coordinates {np.round(start, 6).tolist()} to "
                        f"{np.round(coords, 6).tolist()}: the "
                        "path meets a fold of the loop (the pose is unreachable on this branch)"
                    )
                continue
            previous = (q, h)
            q, fraction = closed, fraction + h
            h = min(2.0 * h, nominal)
        return q

    def _reference_assembly(self) -> tuple[np.ndarray, np.ndarray]:
        """Closed configuration the continuation starts from.

        The closure of the neutral configuration, or, for a shipped robot whose ``robot.toml``
        gives its default coordinates ``q_SI`` (rad or m; e.g. leg lengths, which cannot be
        zero), the closure from the neutral passive joints at those coordinates.
        """
        if self._reference is None:
            q0 = pin.neutral(self.model)
            if "q_SI" in self.defaults:
                q0 = self._tree_configuration(np.asarray(self.defaults["q_SI"], dtype=float), q0)
            q0 = self.loop.close(self.model, self.data, q0)
            self._reference = (self.coordinates_of(q0), q0)
        return self._reference


def _read_urdf(path: Path) -> tuple[pin.Model, object | None]:
    """Validate a URDF with yourdfpy, then build the Pinocchio model."""
    import yourdfpy
    from lxml import etree

    if not path.is_file():
        raise MissingFileError(f"URDF file {path} does not exist; give an existing .urdf path",
                               path=path)
    try:  # yourdfpy repairs broken XML silently: parse strictly first
        etree.parse(str(path), etree.XMLParser(recover=False))
    except etree.XMLSyntaxError as exc:
        line, column = exc.position if exc.position else (None, None)
        problem = re.sub(r",? line \d+, column \d+$", "", str(exc.msg))
        raise FileFormatError(f"not a valid URDF: not well-formed XML ({problem}); fix it there",
                              path=path, line=line, column=column) from exc
    try:
        urdf = yourdfpy.URDF.load(str(path), build_scene_graph=False, load_meshes=False)
    except Exception as exc:  # yourdfpy raises lxml, KeyError or ValueError on bad files
        raise FileFormatError(f"not a valid URDF: {exc}", path=path) from exc
    if not urdf.validate():
        raise FileFormatError(f"not a valid URDF: {'; '.join(urdf.errors)}", path=path)
    links = set(urdf.link_map)
    for joint in urdf.robot.joints:
        for role, link in (("parent", joint.parent), ("child", joint.child)):
            if link not in links:
                raise FileFormatError(
                    f"not a valid URDF: joint {joint.name!r} names the {role} link "
                    f"{link!r}, which it does not define; {did_you_mean(str(link), sorted(links))}",
                    path=path)
    try:
        model = pin.buildModelFromUrdf(str(path))
    except (RuntimeError, ValueError) as exc:
        raise FileFormatError(f"Pinocchio cannot build a model from it: {exc}", path=path
                              ) from exc
    visual = None
    try:
        visual = pin.buildGeomFromUrdf(model, str(path), pin.GeometryType.VISUAL, package_dirs=[
            str(path.parent)])
    except (RuntimeError, ValueError):
        visual = None
    return model, visual


def _resolve_source(source: str | os.PathLike) -> tuple[str, pin.Model, object | None, dict]:
    """Model, visuals and shipped settings for a source name or path."""
    text = str(source)
    shipped = shipped_robots()
    if text in shipped:
        folder = robots_directory() / text
        settings = read_toml(folder / "robot.toml", "robot file")
        model, visual = _read_urdf(folder / settings["urdf"])
        settings["_folder"] = folder
        return text, model, visual, settings
    path = Path(text)
    if path.suffix.lower() in (".urdf", ".xml") or path.exists():
        model, visual = _read_urdf(path)
        settings: dict = {"_folder": path.parent}
        sidecar = path.with_suffix(".loops.yaml")
        if sidecar.is_file():
            settings["loops"] = sidecar.name
        return text, model, visual, settings
    erd_names = example_robot_names()
    if text in erd_names:
        import example_robot_data

        wrapper = example_robot_data.load(text)
        return text, wrapper.model, wrapper.visual_model, {}
    raise UnknownRobotError(
        f"unknown robot {text!r}: not a shipped robot ({', '.join(shipped)}), not an existing "
        f"URDF file, and not an example-robot-data name; "
        f"{did_you_mean(text, shipped + erd_names, limit=80)}", name=text,
        choices=shipped + erd_names)


def load_robot(
    source: str | os.PathLike,
    frame: str | None = None,
    target_offset: np.ndarray | list[float] | None = None,
    compliant_joints: list[str] | tuple[str, ...] | None = None,
    loops: str | os.PathLike | None = None,
) -> Robot:
    """Load a robot for elastostatics.

    Parameters
    ----------
    source
        A shipped robot name (``"sk120"``), a path to a URDF (a ``<name>.loops.yaml`` beside it
        declares its loops), or an example-robot-data name (``"ur5"``, ``"panda"``, ...).
    frame
        Frame carrying the measurement target; default: the shipped robot's target frame, else
        the last frame of the model.
    target_offset
        Target position in ``frame`` axes (m); default zero (or the shipped robot's).
    compliant_joints
        Joints modelled as springs; default: the shipped robot's, else every coordinate joint.
    loops
        Loop declaration (YAML) overriding the sidecar.

    Raises
    ------
    StiffnessError
        Unknown source, missing or malformed URDF, unknown frame or joint, unsupported joint type.
    """
    name, model, visual, settings = _resolve_source(source)
    loop = None
    loop_file = loops or settings.get("loops")
    if loop_file is not None:
        loop_path = Path(loop_file)
        if not loop_path.is_absolute() and loops is None:
            loop_path = settings["_folder"] / loop_path
        loop = build_loop_closure(model, read_loop_declaration(loop_path))
    passive = set(loop.passive_joints) if loop else set()
    coordinate_joints = []
    for jid in range(1, model.njoints):
        joint = model.joints[jid]
        if joint.nv == 0 or model.names[jid] in passive:
            continue
        if joint.shortname() not in _SUPPORTED_JOINTS:
            raise StiffnessError(
                f"joint {model.names[jid]!r} is a {joint.shortname()}; only revolute, continuous "
                "and prismatic joints can be coordinates (fix the base, or declare the joint "
                "passive in a loop)"
            )
        coordinate_joints.append(model.names[jid])
    order = settings.get("coordinate_order")
    if order is not None:
        if sorted(order) != sorted(coordinate_joints):
            raise StiffnessError(
                f"coordinate_order {order} of {name} must list exactly its coordinate joints "
                f"{coordinate_joints}"
            )
        coordinate_joints = list(order)

    frame_names = [f.name for f in model.frames]
    if frame is None:
        frame = settings.get("frame", frame_names[-1])
    if not model.existFrame(frame):
        raise UnknownFrameError(
            f"frame {frame!r} is not in {name}; {did_you_mean(frame, frame_names)}",
            name=frame, choices=frame_names)
    if target_offset is None:
        target_offset = settings.get("target_offset_m", [0.0, 0.0, 0.0])
    offset = np.asarray(target_offset, dtype=float).reshape(-1)
    if offset.shape != (3,) or not np.all(np.isfinite(offset)):
        raise StiffnessError(f"target offset must be three finite lengths in m, got {offset}")

    if compliant_joints is None:
        compliant_joints = settings.get("compliant_joints", coordinate_joints)
    compliant_joints = tuple(compliant_joints)
    for joint_name in compliant_joints:
        if joint_name not in coordinate_joints:
            why = " (it is a passive loop joint)" if joint_name in passive else ""
            raise UnknownJointError(
                f"compliant joint {joint_name!r} is not a coordinate joint of {name}{why}; "
                f"{did_you_mean(joint_name, coordinate_joints)}", name=joint_name,
                choices=coordinate_joints)
    if len(set(compliant_joints)) != len(compliant_joints):
        raise StiffnessError(f"compliant joints repeat a name: {list(compliant_joints)}")

    fid = model.getFrameId(frame)
    parent = model.frames[fid]
    placement = parent.placement * pin.SE3(np.eye(3), offset)
    target_id = model.addFrame(
        pin.Frame(TARGET_FRAME, parent.parentJoint, fid, placement, pin.FrameType.OP_FRAME)
    )
    defaults = {k: v for k, v in settings.items() if not k.startswith("_")}
    return Robot(
        name=name,
        model=model,
        data=model.createData(),
        target_frame=frame,
        target_offset=offset,
        target_frame_id=target_id,
        coordinate_joints=tuple(coordinate_joints),
        compliant_joints=compliant_joints,
        loop=loop,
        visual_model=visual,
        defaults=defaults,
    )
