"""A loaded robot as a MuJoCo model (MJCF), with joint springs, from its Pinocchio model.

One ``<body>`` per moving joint, placed by the joint's placement in its parent (Pinocchio's
``jointPlacements``), carrying the joint's whole inertia (``model.inertias``: fixed links are
already merged into it) as ``<inertial pos mass fullinertia>``. Each ``BODY`` or operational
frame fixed to a body is a ``<site>`` of the same name (``stiffness_target`` is the target), so
forces can be applied and positions read where the toolkit reads them.

Joints: revolute -> ``hinge`` (continuous ones unlimited), prismatic -> ``slide``, with the
model's finite limits as ``range`` and its damping and friction. A compliant joint gets
``stiffness`` (its spring, N.m/rad or N/m) and ``springref`` (the spring's rest value, rad or m).
A rigid coordinate joint (not compliant) is written without a ``<joint>``: its body is welded
at the joint's rest value, exactly as rigid as the elastostatic model holds it (so is the mimic
follower of a rigid leader). A mimic follower of a compliant joint follows its leader by an
equality constraint (``<joint joint1 joint2 polycoef>``, made stiff by :data:`STIFF_SOLREF`
and :data:`STIFF_SOLIMP`). A robot whose springs act on its controller's coordinates
(``[controller]`` with ``springs_on = "controller"``, ``q_chain = A u + b``) gets a fixed
``<tendon>`` per compliant coordinate, of length ``(A^+ q)_i`` over the chain joints (``A^+``
its pseudo-inverse, a left inverse), with the spring's ``stiffness`` and its rest length as
``springlength`` (:func:`spring_plan`); passive chain joints (a tall ``A``) follow the linkage
by a stiff equality constraint per direction of ``A``'s left null space ``n``: a fixed tendon
``n . q`` held at ``n . b``. A keyframe ``rest`` holds the configuration at the springs' rest.
Gravity is the model's.

Closed loops are refused. MuJoCo closes a loop by a soft equality constraint (``connect``), whose
stiffness scales with the bodies' effective inertia and the time step, not with the joint
springs: on the SK120 under its paper load, damped to rest, the loop gave way by 0.1 mm to
0.5 m depending on ``solref``/``solimp`` and the target missed the exact equilibrium by 47 % to
3000x the deflection, so such an export would not be the robot's elastostatics.

MuJoCo refuses a moving body without mass, or with an inertia that is not positive definite: a
point mass (a DH table's link without ``inertia``) is written with the inertia of a 1 mm
sphere of its mass (:func:`stiffness.robot.urdf_writer.written_inertia`); massless links (a
purely kinematic model) are given :data:`MASSLESS_BOUND_KG` and :data:`MASSLESS_BOUND_KGM2` by
the compiler's ``boundmass``/``boundinertia``, and a warning says so (statics do not see them).
An inertia that breaks the triangle inequality (a robot file's error: fetch's finger links) is
balanced by the compiler's ``balanceinertia``, with a warning naming the links.

Units: SI (m, rad, kg, kg.m^2, N.m/rad, N/m).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin
from lxml import etree

from stiffness.errors import RobotFileWarning, StiffnessError
from stiffness.robot.robot import Robot
from stiffness.robot.urdf_writer import numbers, written_inertia

#: Equality constraints' solver reference (time constant s, damping ratio): the stiffest the
#: default time step allows (MuJoCo keeps the time constant at least two time steps).
STIFF_SOLREF = (0.004, 1.0)
#: Equality constraints' impedance (dmin, dmax, width, midpoint, power): close to 1, so that
#: the constraint gives way little under a static load.
STIFF_SOLIMP = (0.9999, 0.9999, 0.001, 0.5, 2.0)
#: Mass (kg) and inertia (kg.m^2) given to massless moving bodies.
MASSLESS_BOUND_KG = 1e-6
MASSLESS_BOUND_KGM2 = 1e-9

_HINGES = {"JointModelRX", "JointModelRY", "JointModelRZ", "JointModelRevoluteUnaligned"}
_CONTINUOUS = {"JointModelRUBX", "JointModelRUBY", "JointModelRUBZ",
               "JointModelRevoluteUnboundedUnaligned"}
_SLIDES = {"JointModelPX", "JointModelPY", "JointModelPZ", "JointModelPrismaticUnaligned"}
_AXES = {"X": (1.0, 0.0, 0.0), "Y": (0.0, 1.0, 0.0), "Z": (0.0, 0.0, 1.0)}


def _quaternion(rotation: np.ndarray) -> str:
    """MuJoCo's ``quat`` (w x y z) of a rotation matrix."""
    q = pin.Quaternion(np.ascontiguousarray(rotation)).coeffs()  # x y z w
    return numbers([q[3], q[0], q[1], q[2]])


def _place(element: etree._Element, placement: pin.SE3) -> None:
    element.set("pos", numbers(placement.translation))
    element.set("quat", _quaternion(placement.rotation))


def _axis(joint) -> np.ndarray:
    kind = joint.shortname()
    if kind[-1] in _AXES and not kind.endswith("Unaligned"):
        return np.asarray(_AXES[kind[-1]])
    return np.asarray(joint.extract().axis, dtype=float)


def joint_value(joint, q: np.ndarray) -> float:
    """The MuJoCo coordinate (rad or m) of a one-degree-of-freedom joint at ``q``."""
    if joint.shortname() in _CONTINUOUS:
        cos, sin = q[joint.idx_q: joint.idx_q + 2]
        return float(np.arctan2(sin, cos))
    return float(q[joint.idx_q])


def _check_joints(robot: Robot) -> None:
    model = robot.model
    for j in range(1, model.njoints):
        kind = model.joints[j].shortname()
        if kind not in _HINGES | _CONTINUOUS | _SLIDES:
            raise StiffnessError(
                f"joint {model.names[j]!r} of {robot.title} is a {kind}; the MJCF export "
                "writes revolute, continuous and prismatic joints only (export the robot "
                "without the loop file's joint rewrites)")


def _joint(body: etree._Element, robot: Robot, j: int, springs: dict[str, float],
           rest: np.ndarray) -> None:
    """The ``<joint>`` of body ``j``, with its spring when compliant."""
    model = robot.model
    joint = model.joints[j]
    kind = joint.shortname()
    element = etree.SubElement(body, "joint", name=model.names[j],
                               type="slide" if kind in _SLIDES else "hinge",
                               axis=numbers(_axis(joint)))
    lower, upper = model.lowerPositionLimit[joint.idx_q], model.upperPositionLimit[joint.idx_q]
    largest = np.finfo(float).max
    if kind not in _CONTINUOUS and -largest < lower < upper < largest:
        element.set("range", numbers([lower, upper]))
    if model.damping[joint.idx_v] > 0.0:
        element.set("damping", str(float(model.damping[joint.idx_v])))
    if model.friction[joint.idx_v] > 0.0:
        element.set("frictionloss", str(float(model.friction[joint.idx_v])))
    name = model.names[j]
    if name in springs:
        element.set("stiffness", str(float(springs[name])))
        element.set("springref", str(joint_value(joint, rest)))


def _springs_at_limits(robot: Robot, springs: dict[str, float], rest: np.ndarray
                       ) -> list[str]:
    """The sprung joints whose rest value (``rest``, full configuration) sits on (or beyond)
    a finite limit, each with its value and limits (rad, m): tiago's torso lift at 0 m on
    [0, 0.35] m deflected half as far in MuJoCo as in the toolkit under a downward load."""
    model = robot.model
    out = []
    for name in springs:
        if not model.existJointName(name):  # a controller coordinate: its tendon has no range
            continue
        joint = model.joints[model.getJointId(name)]
        lower, upper = model.lowerPositionLimit[joint.idx_q], model.upperPositionLimit[joint.idx_q]
        if joint.shortname() in _CONTINUOUS or not np.isfinite([lower, upper]).all() \
                or max(abs(lower), abs(upper)) >= np.finfo(float).max:
            continue
        value = joint_value(joint, rest)
        tol = 1e-9 * max(1.0, upper - lower)
        if value <= lower + tol or value >= upper - tol:
            out.append(f"{name} ({value:.6g}, limits [{lower:.6g}, {upper:.6g}])")
    return out


def impossible_inertia(inertia: pin.Inertia) -> bool:
    """Whether a body's rotational inertia breaks the triangle inequality (its largest
    principal moment above the sum of the other two: no mass distribution has it; fetch's
    ``l_gripper_finger_link``), which MuJoCo refuses unless its compiler balances it."""
    if inertia.mass <= 0.0:
        return False
    moments = np.linalg.eigvalsh(written_inertia(inertia))
    return bool(moments[0] + moments[1] < moments[2])


def _inertial(body: etree._Element, inertia: pin.Inertia) -> bool:
    """Write the body's inertia (a point mass's raised as :func:`written_inertia` says);
    False when it is massless (nothing written)."""
    if inertia.mass <= 0.0:
        return False
    i = written_inertia(inertia)
    etree.SubElement(body, "inertial", pos=numbers(inertia.lever), mass=str(float(inertia.mass)),
                     fullinertia=numbers([i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2]]))
    return True


def _sites(parent: etree._Element, robot: Robot, j: int, taken: set[str]) -> None:
    """A site per body or operational frame moved by joint ``j``, at its placement."""
    for f in robot.model.frames:
        if f.parentJoint != j or f.name in taken or f.type not in (
                pin.FrameType.BODY, pin.FrameType.OP_FRAME, pin.FrameType.SENSOR):
            continue
        taken.add(f.name)
        _place(etree.SubElement(parent, "site", name=f.name), f.placement)


def _bodies(parent: etree._Element, robot: Robot, j: int, plan: SpringPlan,
            rest: tuple[np.ndarray, pin.Data], order: list[int], massless: list[str],
            taken: set[str]) -> None:
    """The bodies of the children of joint ``j``, depth first (MuJoCo's coordinate order);
    ``rest`` is the rest configuration and the model's data at it."""
    model = robot.model
    q, data = rest
    for child in range(1, model.njoints):
        if model.parents[child] != j:
            continue
        name = model.names[child]
        body = etree.SubElement(parent, "body", name=name)
        rigid = name in plan.welded
        _place(body, data.oMi[j].actInv(data.oMi[child]) if rigid  # welded at rest
               else model.jointPlacements[child])
        if not _inertial(body, model.inertias[child]) and not rigid:
            massless.append(name)  # a moving body: MuJoCo needs its mass
        if not rigid:
            _joint(body, robot, child, plan.joints, q)
            order.append(child)
        _sites(body, robot, child, taken)
        _bodies(body, robot, child, plan, rest, order, massless, taken)


@dataclass
class SpringPlan:
    """How a robot's springs and rigid coordinates become MuJoCo elements.

    Attributes
    ----------
    joints
        Stiffness (N.m/rad or N/m) of each model joint that carries its own spring.
    tendons
        Springs on controller coordinates: ``(name, {joint: coefficient}, stiffness)``, a
        fixed tendon whose length is the coordinate (up to a constant) over the free joints.
    welded
        Model joints held at their rest value (no ``<joint>`` written).
    linkages
        Passive chain joints' linkages: ``({joint: coefficient}, value)``, a combination of
        the chain joints held at ``value`` (rad, m) by the coupling (its left null space).
    """

    joints: dict[str, float] = field(default_factory=dict)
    tendons: list[tuple[str, dict[str, float], float]] = field(default_factory=list)
    welded: set[str] = field(default_factory=set)
    linkages: list[tuple[dict[str, float], float]] = field(default_factory=list)


def spring_plan(robot: Robot, springs: dict[str, float]) -> SpringPlan:
    """The joint springs, tendons and welded joints of ``springs`` on ``robot``.

    Without a controller map, or with springs on the chain, each spring is a joint spring and
    each spring-less coordinate (and its mimic followers) is welded. With springs on controller
    coordinates ``u`` (``q_chain = A u + b``), the coordinate ``u_i = (A^+ (q - b))_i`` is a
    fixed tendon of coefficients ``A^+[i]`` (the pseudo-inverse: a left inverse of a tall
    ``A``); a chain joint set by rigid coordinates alone is welded, and a rigid coordinate that
    still moves with the free joints is refused. A tall ``A`` adds one linkage per direction
    ``n`` of its left null space: ``n . q = n . b`` over the chain.

    Raises
    ------
    StiffnessError
        A spring on a name that takes none, or a rigid controller coordinate that couples
        joints the springs move.
    """
    names = robot.spring_joints
    unknown = [name for name in springs if name not in names]
    if unknown:
        raise StiffnessError(f"a spring on {unknown[0]!r}, which is not a coordinate of "
                             f"{robot.title} that takes one ({', '.join(names)})")
    coupling = robot.coupling
    if coupling is None or coupling.springs_on == "chain":
        welded = {name for name in names if name not in springs}
        welded |= {m.follower for m in robot.mimics if m.leader in welded}
        return SpringPlan(dict(springs), [], welded)
    rigid = [i for i, name in enumerate(coupling.coordinates) if name not in springs]
    compliant = [i for i, name in enumerate(coupling.coordinates) if name in springs]
    fixed = [j for j, row in enumerate(coupling.matrix) if not np.any(row[compliant])]
    free = [j for j in range(len(coupling.chain)) if j not in fixed]
    inverse = np.linalg.pinv(coupling.matrix)
    scale = np.abs(inverse).max()
    for i in rigid:
        if np.any(np.abs(inverse[i, free]) > 1e-12 * scale):
            raise StiffnessError(
                f"the rigid controller coordinate {coupling.coordinates[i]!r} of {robot.title} "
                "moves with joints its springs move, which MuJoCo would hold only by a soft "
                "constraint; give it a spring (--kq with --compliant-joints) to export it")
    tendons = [(coupling.coordinates[i], {coupling.chain[j]: float(inverse[i, j]) for j in free
                                          if inverse[i, j] != 0.0},
                float(springs[coupling.coordinates[i]])) for i in compliant]
    left, _, _ = np.linalg.svd(coupling.matrix)
    linkages = [({coupling.chain[j]: float(n[j]) for j in range(len(n)) if abs(n[j]) > 1e-12},
                 float(n @ coupling.offset)) for n in left[:, coupling.matrix.shape[1]:].T]
    return SpringPlan({}, tendons, {coupling.chain[j] for j in fixed}, linkages)


def _tendons(root: etree._Element, robot: Robot, plan: SpringPlan, rest: np.ndarray) -> None:
    """The springs on controller coordinates, as fixed tendons at rest at ``rest``, and the
    passive joints' linkages as fixed tendons (held by :func:`_equalities`)."""
    linkages = _linkages(robot, plan, rest)
    if not plan.tendons and not linkages:
        return
    model = robot.model
    tendon = etree.SubElement(root, "tendon")
    for name, coefficients, stiffness in plan.tendons:
        length = sum(c * joint_value(model.joints[model.getJointId(j)], rest)
                     for j, c in coefficients.items())
        element = etree.SubElement(tendon, "fixed", name=name, stiffness=str(stiffness),
                                   springlength=str(float(length)))
        for joint, coefficient in coefficients.items():
            etree.SubElement(element, "joint", joint=joint, coef=str(coefficient))
    for name, coefficients, _ in linkages:
        element = etree.SubElement(tendon, "fixed", name=name)
        for joint, coefficient in coefficients.items():
            etree.SubElement(element, "joint", joint=joint, coef=str(coefficient))


def _linkages(robot: Robot, plan: SpringPlan, rest: np.ndarray
              ) -> list[tuple[str, dict[str, float], float]]:
    """The linkages over the written joints: ``(tendon name, {joint: coefficient}, length)``,
    the welded joints' terms moved into the length at their rest values."""
    model = robot.model
    out = []
    for k, (coefficients, value) in enumerate(plan.linkages):
        free = {j: c for j, c in coefficients.items() if j not in plan.welded}
        if free:
            held = sum(c * joint_value(model.joints[model.getJointId(j)], rest)
                       for j, c in coefficients.items() if j in plan.welded)
            out.append((f"linkage{k + 1}", free, value - held))
    return out


def _equalities(root: etree._Element, robot: Robot, plan: SpringPlan, rest: np.ndarray
                ) -> None:
    """Mimic followers of compliant leaders, and the passive joints' linkages (a tendon held
    at its length: MuJoCo measures it from the joints' zero, their ``ref``), as equality
    constraints."""
    stiff = {"solref": numbers(STIFF_SOLREF), "solimp": numbers(STIFF_SOLIMP)}
    equality = etree.SubElement(root, "equality")
    for m in robot.mimics:
        if m.follower in plan.welded:
            continue
        etree.SubElement(equality, "joint", name=f"mimic_{m.follower}", joint1=m.follower,
                         joint2=m.leader, polycoef=numbers([m.offset, m.multiplier, 0, 0, 0]),
                         **stiff)
    for name, _, length in _linkages(robot, plan, rest):
        etree.SubElement(equality, "tendon", name=name, tendon1=name,
                         polycoef=numbers([length, 0, 0, 0, 0]), **stiff)
    if len(equality) == 0:
        root.remove(equality)


def robot_mjcf(robot: Robot, springs: dict[str, float], rest: np.ndarray) -> str:
    """The MJCF text of ``robot`` with joint springs (see the module docstring).

    Parameters
    ----------
    robot
        The robot.
    springs
        Stiffness of each compliant joint by name (N.m/rad or N/m); coordinate joints not
        named are rigid (locked at their rest value).
    rest
        Full Pinocchio configuration at the springs' rest (loops closed): the springs'
        ``springref`` and the keyframe ``rest``.

    Raises
    ------
    StiffnessError
        A closed loop, a joint MJCF export does not write, a spring on a joint that is not a
        coordinate.
    """
    if not robot.loop.is_open_chain:
        raise StiffnessError(
            f"{robot.title} has closed loops, which MuJoCo closes only by soft constraints that "
            "give way under load more than its joint springs (docs/robot-files.md): the MJCF "
            "export writes open chains only; export --urdf instead")
    _check_joints(robot)
    plan = spring_plan(robot, springs)
    model = robot.model
    root = etree.Element("mujoco", model=robot.title)
    compiler = etree.SubElement(root, "compiler", angle="radian", autolimits="true")
    etree.SubElement(root, "option", gravity=numbers(model.gravity.linear))
    world = etree.SubElement(root, "worldbody")
    order: list[int] = []
    massless: list[str] = []
    taken: set[str] = set()
    data = model.createData()
    pin.forwardKinematics(model, data, rest)
    _sites(world, robot, 0, taken)
    _bodies(world, robot, 0, plan, (rest, data), order, massless, taken)
    stopped = _springs_at_limits(robot, springs, rest)
    if stopped:
        warnings.warn(f"{robot.title}: the springs of {', '.join(stopped)} rest on or beyond "
                      "a joint limit, where MuJoCo's range stops their deflection one way (the "
                      "toolkit's statics ignore limits); give --q inside the limits",
                      RobotFileWarning, stacklevel=2)
    impossible = [model.names[j] for j in range(1, model.njoints)
                  if impossible_inertia(model.inertias[j])]
    if impossible:
        compiler.set("balanceinertia", "true")
        warnings.warn(f"{robot.title}: the inertia of the links of {', '.join(impossible)} "
                      "breaks the triangle inequality (a principal moment above the sum of the "
                      "other two, which no body has); MuJoCo's balanceinertia raises the smaller "
                      "moments "
                      "(statics do not see them); correct the robot file's <inertia> to keep "
                      "its own", RobotFileWarning, stacklevel=2)
    if massless:
        compiler.set("boundmass", str(MASSLESS_BOUND_KG))
        compiler.set("boundinertia", str(MASSLESS_BOUND_KGM2))
        warnings.warn(f"{robot.title}: {len(massless)} massless links ({', '.join(massless)}) "
                      f"written with {MASSLESS_BOUND_KG} kg and {MASSLESS_BOUND_KGM2} kg.m^2, "
                      "as MuJoCo needs a mass on every moving body", RobotFileWarning,
                      stacklevel=2)
    _tendons(root, robot, plan, rest)
    _equalities(root, robot, plan, rest)
    keyframe = etree.SubElement(root, "keyframe")
    etree.SubElement(keyframe, "key", name="rest", qpos=numbers(
        [joint_value(model.joints[j], rest) for j in order]))
    return etree.tostring(root, pretty_print=True, encoding="unicode")


def check_mjcf(text: str, name: str) -> None:
    """Compile ``text`` with MuJoCo; a model it refuses raises a one-line error.

    Raises
    ------
    StiffnessError
        MuJoCo does not compile the model (its message, on one line).
    """
    import mujoco

    try:
        mujoco.MjModel.from_xml_string(text)
    except ValueError as exc:
        problem = " ".join(str(exc).split())
        raise StiffnessError(f"MuJoCo refuses the model written for {name}: {problem}; "
                             "report this with the robot file") from exc
