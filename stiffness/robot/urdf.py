"""Reading URDF files as tolerantly as Pinocchio's own parser (urdfdom) does.

Whatever Pinocchio's parser accepts loads: a ``<limit effort velocity/>`` without ``lower`` or
``upper``, any XML header version (pybullet's ``<?xml version="0.0"?>``), tags it does not know.
Each kind of thing the toolkit reads differently from the file, or ignores, gives one line
(a :class:`~stiffness.errors.RobotFileNote`, silent under the command line's ``--quiet``, when
the robot loads as the file means it; a :class:`RobotFileWarning` otherwise), not one per
joint. A file Pinocchio refuses gets one
:class:`~stiffness.errors.RobotFileError` line naming the file, the line and the problem
(urdfdom's own diagnosis, which it prints on the C-level standard error, is captured for it).

Also read here, because Pinocchio's algorithms cannot use them: ``<mimic>`` tags (the follower
joint is built as an ordinary joint and :class:`Mimic` records the coupling), and the visual
geometry, whose mesh files are resolved by :mod:`stiffness.robot.meshes`.
"""

from __future__ import annotations

import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.errors import MissingFileError, RobotFileError, RobotFileNote, RobotFileWarning
from stiffness.robot import kinematics
from stiffness.robot.meshes import MissingMesh, resolve_visual_meshes

#: urdfdom messages that only repeat that an earlier, more specific error happened.
_GENERIC = ("is not initialized correctly", "Failed to build tree", "Model xml is not",
            "Failed to parse")
_CHILD_TAGS = ("origin", "axis", "limit", "mimic", "dynamics", "calibration",
               "safety_controller", "inertial", "visual", "collision")
_DECLARATION = re.compile(rb"^\s*<\?xml[^>]*\?>")
_VERSION = re.compile(rb"""version\s*=\s*["']([^"']*)["']""")


@dataclass(frozen=True)
class Mimic:
    """A URDF ``<mimic>``: ``follower = multiplier * leader + offset`` (rad or m)."""

    follower: str
    leader: str
    multiplier: float = 1.0
    offset: float = 0.0


@dataclass
class UrdfRobot:
    """A URDF read for elastostatics.

    Attributes
    ----------
    model
        Pinocchio model (mimic followers as ordinary joints, fixed base).
    visual
        Visual geometry with resolved meshes (primitives stand in for missing ones), or None.
    mimics
        The ``<mimic>`` couplings.
    all_mimics
        Every ``<mimic>`` tag, those of fixed joints included (for the default target frame).
    missing_meshes
        Meshes that could not be found (drawn as primitives).
    """

    model: pin.Model
    visual: pin.GeometryModel | None
    mimics: tuple[Mimic, ...] = ()
    missing_meshes: tuple[MissingMesh, ...] = field(default_factory=tuple)
    all_mimics: tuple[Mimic, ...] = ()


def warn(message: str) -> None:
    """Emit one :class:`RobotFileWarning`."""
    warnings.warn(message, RobotFileWarning, stacklevel=3)


def note(message: str) -> None:
    """Emit one :class:`RobotFileNote` (read the file's own way; silent under ``--quiet``)."""
    warnings.warn(message, RobotFileNote, stacklevel=3)


def _tolerant_bytes(raw: bytes) -> bytes:
    """The file with its XML declaration made acceptable to a strict XML parser."""
    match = _DECLARATION.match(raw)
    if match is None:
        return raw
    return raw[: match.start()] + raw[match.end():]


def _parse_tree(path: Path, raw: bytes, strict: bool):
    """lxml tree of the file (declaration neutralised).

    ``strict``: a file that is not well-formed XML is a :class:`RobotFileError` with its line
    (only asked once Pinocchio has refused the file: what Pinocchio reads, loads); otherwise the
    parser recovers what it can (for warnings, mimic tags and visuals).
    """
    from lxml import etree

    try:
        root = etree.fromstring(_tolerant_bytes(raw), etree.XMLParser(
            recover=not strict, remove_comments=True, huge_tree=True))
    except etree.XMLSyntaxError as exc:
        # the declaration is removed without its line break: line numbers are unchanged
        line = exc.position[0] if exc.position else None
        raise RobotFileError(path, line,
                             f"not a valid URDF: not well-formed XML: {exc.msg}") from exc
    if root is None:
        return etree.fromstring(b"<robot/>")
    return root


def _urdfdom_problem(text: str) -> tuple[str | None, int | None]:
    """The most specific urdfdom message and the line it names, from its stderr output."""
    messages = [m.strip() for m in re.findall(r"Error:\s*(.+)", text)]
    specific = [m for m in messages if not any(g in m for g in _GENERIC)] or messages
    if not specific:
        return None, None
    line = re.search(r"Line number=(\d+)", specific[0])
    return "; ".join(dict.fromkeys(specific[:2])), int(line.group(1)) if line else None


def _element_line(root, message: str) -> int | None:
    """Source line of the joint or link an urdfdom message names in brackets."""
    for name in re.findall(r"\[([^\]]+)\]", message):
        for tag in ("joint", "link"):
            for element in root.iter(tag):
                if element.get("name") != name:
                    continue
                for child in _CHILD_TAGS:  # point at the faulty child element when named
                    if child in message.lower() and element.find(child) is not None:
                        return element.find(child).sourceline
                return element.sourceline
    return None


def _structure_problem(root) -> tuple[str, int] | None:
    """What Pinocchio refuses without naming the element (urdfdom's message omits the line,
    Pinocchio's names no joint): another format's file (SDF, MJCF), a ``<robot>`` without a
    name, the first joint naming a link
    the file does not define, or a ``<limit>`` with a negative effort or velocity."""
    if root.tag != "robot":  # lxml's recovered root of a file with no element is <robot/>
        kind = _OTHER_FORMATS.get(str(root.tag).lower())
        what = f"{kind} file, not a URDF" if kind else "not a URDF"
        return (f"{what}: its root element is <{root.tag}>, a URDF's is <robot>; export or "
                "convert the robot to a URDF and give that file"), root.sourceline
    if not root.get("name"):
        return ("the <robot> element has no name attribute; name the robot, e.g. "
                '<robot name="arm">'), root.sourceline
    links = {link.get("name") for link in root.iter("link")}
    for joint in root.iter("joint"):
        for role in ("parent", "child"):
            element = joint.find(role)
            name = None if element is None else element.get("link")
            if element is not None and name not in links:
                return (f"joint {joint.get('name')!r} names the {role} link {name!r}, which the "
                        "file does not define"), element.sourceline
    return _negative_limit(root)


#: Robot description formats given for a URDF, by their root element.
_OTHER_FORMATS = {"sdf": "an SDFormat (Gazebo)", "mujoco": "a MuJoCo (MJCF)",
                  "collada": "a COLLADA", "model": "a Gazebo model.config"}


def _negative_limit(root) -> tuple[str, int] | None:
    """First joint whose ``<limit>`` gives a negative effort or velocity (some exporters write
    -1 for 'no limit'), which Pinocchio refuses as a minimum above the maximum."""
    def negative(limit) -> list[str]:
        out = []
        for bound in ("effort", "velocity"):
            try:
                if limit is not None and float(limit.get(bound)) < 0:
                    out.append(f"{bound}={limit.get(bound)}")
            except (TypeError, ValueError):
                continue
        return out
    bad = [(joint, negative(joint.find("limit"))) for joint in root.iter("joint")]
    bad = [(joint, values) for joint, values in bad if values]
    if not bad:
        return None
    joint, values = bad[0]
    others = f" (and {len(bad) - 1} more joints)" if len(bad) > 1 else ""
    return (f"joint {joint.get('name')!r} has a negative {' and '.join(values)} in its <limit>"
            f"{others}, which Pinocchio takes as a minimum above the maximum; write the "
            "limits as positive numbers (0 if unknown)"), joint.find("limit").sourceline


def _joint_problem(root) -> tuple[str, int] | None:
    """First moving joint that Pinocchio's parser takes but that cannot move as declared: a
    zero ``<axis>`` (the joint would move nothing) or a ``<limit>`` whose lower bound is above
    its upper one; with the element's line."""
    for joint in root.iter("joint"):
        if joint.get("type") not in ("revolute", "continuous", "prismatic"):
            continue
        name, axis, limit = joint.get("name"), joint.find("axis"), joint.find("limit")
        try:
            direction = [float(v) for v in (axis.get("xyz") or "1 0 0").split()] \
                if axis is not None else [1.0]
            bounds = [float(limit.get(b)) for b in ("lower", "upper")] \
                if limit is not None and None not in (limit.get("lower"), limit.get("upper")) \
                else None
        except ValueError:  # Pinocchio's parser has read them: not reached
            continue
        if axis is not None and not any(direction):
            return (f"joint {name!r} has the zero axis xyz={axis.get('xyz')!r}: it would move "
                    "nothing; give the direction it turns about or slides along"), axis.sourceline
        if bounds is not None and joint.get("type") != "continuous" and bounds[0] > bounds[1]:
            return (f"joint {name!r} has lower={limit.get('lower')} above "
                    f"upper={limit.get('upper')}; swap them"), limit.sourceline
    return None


#: The namespace of xacro's macro elements (``<xacro:include>``, ``<xacro:property>``...).
_XACRO = "{http://ros.org/wiki/xacro}"


def _xacro_problem(path: Path, root) -> tuple[str, int] | None:
    """A xacro file given as a URDF: its first ``<xacro:...>`` element or ``${...}`` /
    ``$(...)`` substitution, unexpanded (Pinocchio's parser skips them, and a hand whose links
    are all in macros read as a robot without joints), with its line."""
    for element in root.iter():
        tag = element.tag if isinstance(element.tag, str) else ""
        found = f"<xacro:{tag[len(_XACRO):]}>" if tag.startswith(_XACRO) else next(
            (f"{k}={v!r}" for k, v in element.attrib.items() if "${" in v or "$(" in v), None)
        if found is not None:
            stem = path.name.removesuffix(".xacro").removesuffix(".urdf")
            out = f"{stem}.urdf" if path.name.endswith(".xacro") else f"{stem}.expanded.urdf"
            return (f"a xacro file, not a URDF: its {found} is not expanded; expand it first "
                    f"(`xacro {path.name} > {out}`, ROS's xacro or `pip install xacro`) and "
                    "load that URDF"), element.sourceline
    return None


def mimic_tags(root, include_fixed: bool = False) -> tuple[Mimic, ...]:
    """The ``<mimic>`` couplings of a parsed URDF (lxml root); those of fixed joints (which
    couple nothing) only with ``include_fixed``."""
    out = []
    for joint in root.iter("joint"):
        tag = joint.find("mimic")
        if tag is None or (joint.get("type") in ("fixed", None) and not include_fixed):
            continue
        out.append(Mimic(str(joint.get("name")), str(tag.get("joint")),
                         float(tag.get("multiplier", 1.0)), float(tag.get("offset", 0.0))))
    return tuple(out)


def _warn_ignored(path: Path, raw: bytes, root, model: pin.Model) -> None:
    """One note per kind of thing the toolkit ignores or reads its own way (not one per
    joint: an Onshape export has dozens of joints without bounds)."""
    match = _DECLARATION.match(raw)
    if match is not None:
        version = _VERSION.search(match.group(0))
        if version is not None and version.group(1) != b"1.0":
            note(f"{path}: XML declaration version {version.group(1).decode()!r} ignored "
                 "(read as XML 1.0, as Pinocchio does)")
    unbounded: dict[str, list[tuple[str, int]]] = {}
    for joint in root.iter("joint"):
        limit = joint.find("limit")
        name = joint.get("name")
        if joint.get("type") not in ("revolute", "prismatic") or limit is None:
            continue
        missing = [b for b in ("lower", "upper") if limit.get(b) is None]
        if missing and model.existJointName(name):
            unbounded.setdefault(" and ".join(missing), []).append((name, limit.sourceline))
            j = model.joints[model.getJointId(name)]
            if "lower" in missing:
                model.lowerPositionLimit[j.idx_q] = -np.inf
            if "upper" in missing:
                model.upperPositionLimit[j.idx_q] = np.inf
    for bounds, joints in unbounded.items():
        note(_unbounded_message(path, bounds, joints))


#: Joints named in full in the note on joints without bounds before it is summarised.
_NAMED_JOINTS = 6


def _unbounded_message(path: Path, missing: str, joints: list[tuple[str, int]]) -> str:
    """The one line saying that ``joints`` (name, line of the ``<limit>``) have a ``<limit>``
    without ``missing`` (``lower``, ``upper`` or both) and are taken as unbounded."""
    side = {"lower": "below", "upper": "above"}.get(missing, "")
    if len(joints) == 1:
        name, line = joints[0]
        return (f"{path}, line {line}: joint {name!r} has a <limit> without {missing}; the "
                f"joint is taken as unbounded{' ' + side if side else ''} (add {missing} to "
                "the <limit> to bound it)")
    shown = ", ".join(f"{name!r} (line {line})" for name, line in joints[:_NAMED_JOINTS])
    more = f" and {len(joints) - _NAMED_JOINTS} more" if len(joints) > _NAMED_JOINTS else ""
    return (f"{path}: {len(joints)} joints have a <limit> without {missing}: {shown}{more}; "
            f"they are taken as unbounded{' ' + side if side else ''} (add {missing} to "
            "their <limit> to bound them)")


def read_urdf(path: str | os.PathLike) -> UrdfRobot:
    """Read a URDF file: model, visuals and mimic couplings.

    Raises
    ------
    MissingFileError
        If the file is missing.
    RobotFileError
        If Pinocchio's parser refuses it (the message names the line).
    """
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"URDF file {path} does not exist; give an existing .urdf path",
                               path=path)
    raw = path.read_bytes()
    xacro = _xacro_problem(path, _parse_tree(path, raw, strict=False)) if b"$" in raw or \
        b"xacro" in raw else None
    if xacro is not None:
        raise RobotFileError(path, xacro[1], xacro[0])
    with kinematics.captured_stderr() as err:
        try:
            model = pin.buildModelFromXML(raw.decode("utf-8", "replace"))
            failure = None
        except (RuntimeError, ValueError) as exc:
            failure = exc
    if failure is not None:
        root = _parse_tree(path, raw, strict=True)
        problem, line = _urdfdom_problem(err[0] if err else "")
        structure = _structure_problem(root)
        if structure is not None:
            problem, line = structure
        if problem is None:
            problem = str(failure)
        raise RobotFileError(
            path, line or _element_line(root, problem),
            f"not a valid URDF (Pinocchio's parser refuses it): {problem}") from failure
    root = _parse_tree(path, raw, strict=False)
    bad = _joint_problem(root)
    if bad is not None:
        raise RobotFileError(path, bad[1], bad[0])
    _warn_ignored(path, raw, root, model)
    mimics = []
    for mimic in mimic_tags(root):
        if model.existJointName(mimic.leader):
            mimics.append(mimic)
        else:  # Pinocchio's parser ignores the tag too; say what that means
            warn(f"{path}: joint {mimic.follower!r} mimics {mimic.leader!r}, which is not a "
                 f"joint of the file: the <mimic> tag is ignored and {mimic.follower!r} is an "
                 "independent joint (fix the leader's name in the file to couple them)")
    visual, missing = resolve_visual_meshes(path, root, model)
    return UrdfRobot(model, visual, tuple(mimics), missing, mimic_tags(root, include_fixed=True))
