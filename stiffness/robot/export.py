"""A loaded robot written back as a URDF, from its Pinocchio model (any source).

The robot may come from a URDF, an example-robot-data name, a shipped robot or a DH
``robot.toml``: what is written is the :class:`~stiffness.robot.robot.Robot`'s ``pin.Model``,
not the source file, so every edit loading made (a fixed base, joints rewritten) is in it.

The link tree (:func:`link_tree`) is read from the model's frames: each ``BODY`` frame is a
link; a moving joint's child link is the body frame it carries at the joint origin (else a
link ``<joint>_link`` is made); a body frame fixed to another is reached by a fixed joint named
after the ``FIXED_JOINT`` frame before it. Other frames (operational frames, sensors) become
massless links on fixed joints ``<frame>_fixed``; the target frame ``stiffness_target`` that
loading adds is left out (loading the written file adds it again). Each moving joint's link
carries the joint's whole inertia (``model.inertias``: the fixed links' masses are already
merged into it), so the file reloads to the same inertias. Joints keep their type, axis,
limits (an unbounded one as the largest finite double), damping and friction; a mimic follower
keeps its ``<mimic>``. Visuals: the robot's meshes (absolute paths) when it has any, else a
cylinder from each link's origin to each joint or frame it carries.

Units: SI (m, rad, kg, kg.m^2).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from stiffness.errors import StiffnessError
from stiffness.robot.robot import TARGET_FRAME, Robot
from stiffness.robot.urdf_writer import UrdfWriter

#: Pinocchio joint kinds written as URDF joints: kind -> (URDF type, axis or None).
_JOINT_KINDS = {
    "JointModelRX": ("revolute", (1.0, 0.0, 0.0)),
    "JointModelRY": ("revolute", (0.0, 1.0, 0.0)),
    "JointModelRZ": ("revolute", (0.0, 0.0, 1.0)),
    "JointModelRevoluteUnaligned": ("revolute", None),
    "JointModelRUBX": ("continuous", (1.0, 0.0, 0.0)),
    "JointModelRUBY": ("continuous", (0.0, 1.0, 0.0)),
    "JointModelRUBZ": ("continuous", (0.0, 0.0, 1.0)),
    "JointModelRevoluteUnboundedUnaligned": ("continuous", None),
    "JointModelPX": ("prismatic", (1.0, 0.0, 0.0)),
    "JointModelPY": ("prismatic", (0.0, 1.0, 0.0)),
    "JointModelPZ": ("prismatic", (0.0, 0.0, 1.0)),
    "JointModelPrismaticUnaligned": ("prismatic", None),
}

#: Radius of the drawn links, as a fraction of the longest segment (m/m).
_STICK_RADIUS = 0.03


@dataclass
class Link:
    """A link of the written tree: its name, the joint that moves it and its placement in that
    joint's frame (identity for a moving joint's own link)."""

    name: str
    joint: int
    placement: pin.SE3


@dataclass
class FixedJoint:
    """A fixed joint from ``parent`` to ``child`` (link names), ``origin`` in ``parent``."""

    name: str
    parent: str
    child: str
    origin: pin.SE3


@dataclass
class LinkTree:
    """A Pinocchio model as URDF links and joints.

    Attributes
    ----------
    root
        Name of the root link (fixed to the world, moved by joint 0).
    joint_links
        Per joint id, the name of the link that joint moves (its frame is the joint frame).
    links
        Every link by name.
    parents
        Per moving joint id (1...), the link it hangs from and the joint origin in that link.
    fixed
        Fixed joints, parents before children.
    """

    root: str
    joint_links: dict[int, str]
    links: dict[str, Link]
    parents: dict[int, tuple[str, pin.SE3]] = field(default_factory=dict)
    fixed: list[FixedJoint] = field(default_factory=list)


def _unique(name: str, taken: set[str]) -> str:
    """``name``, or ``name_2``, ``name_3``... when taken."""
    out, n = name, 1
    while out in taken:
        n += 1
        out = f"{name}_{n}"
    return out


def _own_links(model: pin.Model) -> dict[int, str]:
    """Per joint (0 = the root), the body frame at its origin, else a made-up link name."""
    own: dict[int, str] = {}
    joint_frames = {f.parentJoint: i for i, f in enumerate(model.frames)
                    if f.type == pin.FrameType.JOINT}
    for f in model.frames:
        if f.type != pin.FrameType.BODY or f.parentJoint in own or not f.placement.isIdentity():
            continue
        expected = joint_frames.get(f.parentJoint, 0)
        if f.parentFrame == expected or f.parentJoint not in joint_frames:
            own[f.parentJoint] = f.name
    taken = {f.name for f in model.frames}
    for j in range(model.njoints):
        if j not in own:
            own[j] = _unique("base_link" if j == 0 else f"{model.names[j]}_link", taken)
            taken.add(own[j])
    return own


def _parent_link(model: pin.Model, tree: LinkTree, frame: int, joint: int) -> Link:
    """The written link nearest up the frame chain from ``frame`` moved by ``joint``, else
    that joint's own link."""
    seen = set()
    while frame not in seen:
        seen.add(frame)
        f = model.frames[frame]
        link = tree.links.get(f.name)
        if link is not None and link.joint == joint and f.type == pin.FrameType.BODY:
            return link
        if frame == 0:
            break
        frame = f.parentFrame
    return tree.links[tree.joint_links[joint]]


def link_tree(robot: Robot) -> LinkTree:
    """The links and joints of ``robot``'s Pinocchio model (see the module docstring).

    Raises
    ------
    StiffnessError
        A joint that a URDF cannot hold (spherical, free-flyer, planar, composite).
    """
    model = robot.model
    for j in range(1, model.njoints):
        kind = model.joints[j].shortname()
        if kind not in _JOINT_KINDS and not _is_mimic(robot, model.names[j]):
            raise StiffnessError(
                f"joint {model.names[j]!r} of {robot.title} is a {kind}, which a URDF cannot "
                "hold; export the robot without the loop file's joint rewrites (or fix its "
                "base with --fixed-base)")
    own = _own_links(model)
    tree = LinkTree(own[0], own, {name: Link(name, j, pin.SE3.Identity())
                                  for j, name in own.items()})
    joint_frames = {f.parentJoint: i for i, f in enumerate(model.frames)
                    if f.type == pin.FrameType.JOINT}
    for j in range(1, model.njoints):
        start = model.frames[joint_frames[j]].parentFrame if j in joint_frames else 0
        parent = _parent_link(model, tree, start, model.parents[j])
        tree.parents[j] = (parent.name, parent.placement.actInv(model.jointPlacements[j]))
    _add_fixed_frames(model, tree)
    return tree


def _add_fixed_frames(model: pin.Model, tree: LinkTree) -> None:
    """Add the body frames fixed to a link, and the other frames, as fixed joints."""
    names = {f.name for f in model.frames} | set(model.names)
    for i, f in enumerate(model.frames):
        if i == 0 or f.type in (pin.FrameType.JOINT, pin.FrameType.FIXED_JOINT) or \
                f.name == TARGET_FRAME or f.name in tree.links:
            continue
        before = model.frames[f.parentFrame]
        if f.type == pin.FrameType.BODY and before.type == pin.FrameType.FIXED_JOINT \
                and before.parentJoint == f.parentJoint \
                and before.placement.isApprox(f.placement, 1e-15):
            name, start = before.name, before.parentFrame
        else:
            name, start = _unique(f"{f.name}_fixed", names), f.parentFrame
            names.add(name)
        parent = _parent_link(model, tree, start, f.parentJoint)
        tree.links[f.name] = Link(f.name, f.parentJoint, f.placement)
        tree.fixed.append(FixedJoint(name, parent.name, f.name,
                                     parent.placement.actInv(f.placement)))


def _is_mimic(robot: Robot, joint: str) -> bool:
    return any(m.follower == joint for m in robot.mimics)


def _matrix(placement: pin.SE3) -> np.ndarray:
    return np.asarray(placement.homogeneous)


def _joint_axis(model: pin.Model, j: int) -> tuple[str, np.ndarray]:
    """URDF type and axis (joint frame) of moving joint ``j``."""
    joint = model.joints[j]
    kind, aligned = _JOINT_KINDS[joint.shortname()]
    axis = joint.extract().axis if aligned is None else aligned
    return kind, np.asarray(axis, dtype=float)


def _limits(model: pin.Model, j: int, kind: str) -> tuple:
    """``(lower, upper, effort, velocity)`` of joint ``j`` (rad or m; None for continuous)."""
    joint = model.joints[j]
    iq, iv = joint.idx_q, joint.idx_v
    effort, velocity = model.effortLimit[iv], model.velocityLimit[iv]
    if kind == "continuous":
        return None, None, effort, velocity
    return model.lowerPositionLimit[iq], model.upperPositionLimit[iq], effort, velocity


def robot_urdf(robot: Robot, visuals: bool = True) -> str:
    """The URDF text of ``robot`` (see the module docstring); with ``visuals``, its meshes or
    else cylinders along its links.

    Raises
    ------
    StiffnessError
        A joint a URDF cannot hold.
    """
    model = robot.model
    tree = link_tree(robot)
    urdf = UrdfWriter(robot.title)
    elements = {}
    for name, link in tree.links.items():
        own = tree.joint_links.get(link.joint) == name
        elements[name] = urdf.link(name, inertia=model.inertias[link.joint] if own else None)
    mimics = {m.follower: m for m in robot.mimics}
    for j in range(1, model.njoints):
        parent, origin = tree.parents[j]
        kind, axis = _joint_axis(model, j)
        m = mimics.get(model.names[j])
        urdf.joint(model.names[j], kind, parent, tree.joint_links[j], _matrix(origin),
                   list(axis), _limits(model, j, kind),
                   dynamics=(model.damping[model.joints[j].idx_v],
                             model.friction[model.joints[j].idx_v]),
                   mimic=None if m is None else (m.leader, m.multiplier, m.offset))
    for fixed in tree.fixed:
        urdf.joint(fixed.name, "fixed", fixed.parent, fixed.child, _matrix(fixed.origin))
    if visuals and not _mesh_visuals(robot, tree, urdf, elements):
        _stick_visuals(robot, tree, urdf, elements)
    return urdf.text()


def _mesh_visuals(robot: Robot, tree: LinkTree, urdf: UrdfWriter, elements: dict) -> bool:
    """Write the robot's visual meshes (absolute paths); False when it has none."""
    objects = [g for g in getattr(robot.visual_model, "geometryObjects", ())
                                         if g.meshPath and isinstance(g.meshPath, str)
                                         and g.meshPath.lower().endswith((".dae", ".stl",
                                                                          ".obj"))]
    if not objects:
        return False
    for g in objects:
        link = _parent_link(robot.model, tree, g.parentFrame, g.parentJoint)
        urdf.visual(elements[link.name], g.name, "mesh",
                    {"filename": g.meshPath, "scale": " ".join(
                        str(float(s)) for s in g.meshScale)},
                    _matrix(link.placement.actInv(g.placement)))
    return True


def _stick_visuals(robot: Robot, tree: LinkTree, urdf: UrdfWriter, elements: dict) -> None:
    """A cylinder from each link's origin to each joint or fixed frame it carries."""
    segments = [(parent, origin.translation) for parent, origin in tree.parents.values()]
    segments += [(f.parent, f.origin.translation) for f in tree.fixed]
    lengths = [float(np.linalg.norm(t)) for _, t in segments]
    radius = _STICK_RADIUS * max(lengths, default=0.0)
    for k, ((parent, tip), length) in enumerate(zip(segments, lengths, strict=True)):
        if length <= 1e-9 or radius <= 0.0:
            continue
        z = tip / length
        x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
        x /= np.linalg.norm(x)
        centre = np.eye(4)
        centre[:3, :3] = np.column_stack([x, np.cross(z, x), z])
        centre[:3, 3] = tip / 2
        urdf.visual(elements[parent], f"{parent}_segment_{k}", "cylinder",
                    {"radius": str(radius), "length": str(length)}, centre)


def loops_yaml(robot: Robot) -> str | None:
    """The loop declaration of ``robot`` (Gepetto's Extended-URDF YAML with our
    ``passive_joints``) to write beside its URDF, or None for a tree."""
    import yaml

    if robot.loop.is_open_chain:
        return None
    declaration = {
        "closed_loop": [[p.frame_a, p.frame_b] for p in robot.loop.pairs],
        "type": [p.kind for p in robot.loop.pairs],
        "name_mot": list(robot.coordinate_joints),
        "passive_joints": list(robot.loop.passive_joints),
    }
    return (f"# Loops of {robot.title}, written by `stiffness robot export`.\n"
            + yaml.safe_dump(declaration, default_flow_style=None, sort_keys=False))
