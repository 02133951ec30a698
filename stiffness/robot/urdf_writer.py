"""Writing URDF documents: links, joints and their origins from homogeneous transforms.

The one writer of the URDF files the toolkit generates (the SK120 of the paper reproduction,
the parallel platforms of :mod:`stiffness.robot.platform`, any loaded robot written back by
:mod:`stiffness.robot.export`). Numbers are written as Python's shortest round-trip repr, so a
file read back gives the same floats; rotations as Pinocchio's roll-pitch-yaw
(``pin.rpy.matrixToRpy``), the convention the URDF reader inverts. An unbounded limit is
written as the largest finite double (URDF readers refuse ``inf``). Units: SI (m, rad, kg,
kg.m^2, N.m or N, rad/s or m/s).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from lxml import etree

#: The largest finite double: what an unbounded limit is written as.
LARGEST = float(np.finfo(float).max)
#: Radius (m) of the uniform sphere whose rotational inertia a point mass is given when written
#: (docs/robot-files.md): MuJoCo refuses a body whose inertia is not positive definite, and
#: statics see only a link's mass and centre of mass, never its rotational inertia.
POINT_MASS_RADIUS_M = 1e-3


def numbers(values) -> str:
    """A URDF vector attribute: each number as Python's shortest round-trip repr."""
    return " ".join(str(float(v)) for v in values)


def written_inertia(inertia: pin.Inertia) -> np.ndarray:
    """The rotational inertia (kg.m^2, about the centre of mass, 3x3) written for ``inertia``.

    Its eigenvalues are raised by one common amount to at least those of a uniform sphere of
    the link's mass and radius :data:`POINT_MASS_RADIUS_M` (``2/5 m r^2``): a point mass (zero
    inertia, as a DH table's ``links`` allow) or a thin rod becomes positive definite and
    still obeys the triangle inequality; any inertia already above that floor is unchanged.
    Mass and centre of mass, all that statics read, are never changed.
    """
    rotational = np.asarray(inertia.inertia, dtype=float)
    floor = 0.4 * float(inertia.mass) * POINT_MASS_RADIUS_M ** 2
    lowest = float(np.linalg.eigvalsh(rotational).min())
    return rotational + max(0.0, floor - lowest) * np.eye(3)


def bounded(value: float) -> str:
    """A URDF limit: the number, or +-:data:`LARGEST` for an infinite one."""
    return str(float(np.clip(float(value), -LARGEST, LARGEST)))


def transform(xyz=(0.0, 0.0, 0.0), rotation: np.ndarray | None = None) -> np.ndarray:
    """The 4x4 homogeneous transform of a translation ``xyz`` (m) and a rotation matrix."""
    out = np.eye(4)
    out[:3, 3] = xyz
    if rotation is not None:
        out[:3, :3] = rotation
    return out


class UrdfWriter:
    """A URDF document built link by link and joint by joint.

    Parameters
    ----------
    name
        The robot's name (``<robot name>``).
    """

    def __init__(self, name: str) -> None:
        self.robot = etree.Element("robot", name=name)

    @staticmethod
    def origin(parent: etree._Element, matrix: np.ndarray) -> None:
        """Add ``<origin xyz rpy>`` of the 4x4 transform ``matrix`` (m, rad) to ``parent``."""
        rpy = pin.rpy.matrixToRpy(np.ascontiguousarray(matrix[:3, :3]))
        etree.SubElement(parent, "origin", xyz=numbers(matrix[:3, 3]), rpy=numbers(rpy))

    def link(self, name: str, box: tuple[list[float], np.ndarray] | None = None,
             inertia: pin.Inertia | None = None) -> etree._Element:
        """Add a link, optionally with a box visual ``(size (m), origin transform)`` and the
        ``inertia`` of the link (mass kg, centre of mass m and rotational inertia about it
        kg.m^2, in the link's frame, :func:`written_inertia`; omitted when massless). Returns
        the link element."""
        element = etree.SubElement(self.robot, "link", name=name)
        if inertia is not None and inertia.mass > 0.0:
            inertial = etree.SubElement(element, "inertial")
            self.origin(inertial, transform(inertia.lever))
            etree.SubElement(inertial, "mass", value=str(float(inertia.mass)))
            i = written_inertia(inertia)
            etree.SubElement(inertial, "inertia", **{
                key: str(float(i[a, b])) for key, (a, b) in
                (("ixx", (0, 0)), ("ixy", (0, 1)), ("ixz", (0, 2)), ("iyy", (1, 1)),
                 ("iyz", (1, 2)), ("izz", (2, 2)))})
        if box is not None:
            size, centre = box
            self.visual(element, f"{name}_visual", "box", {"size": numbers(size)}, centre)
        return element

    def visual(self, link: etree._Element, name: str, shape: str, attributes: dict[str, str],
               origin: np.ndarray) -> None:
        """Add to ``link`` a visual ``<shape **attributes>`` (``box``, ``cylinder``, ``sphere``,
        ``mesh``; lengths in m) at the 4x4 transform ``origin`` in the link's frame."""
        element = etree.SubElement(link, "visual", name=name)
        etree.SubElement(etree.SubElement(element, "geometry"), shape, **attributes)
        self.origin(element, origin)

    def joint(self, name: str, kind: str, parent: str, child: str, origin: np.ndarray,
              axis: list[float] | None = None,
              limit: tuple[float | None, float | None, float, float] | None = None,
              dynamics: tuple[float, float] | None = None,
              mimic: tuple[str, float, float] | None = None) -> None:
        """Add a joint.

        Parameters
        ----------
        kind
            URDF joint type (``revolute``, ``prismatic``, ``fixed``, ...).
        origin
            4x4 transform of the joint frame in the parent link's frame (m).
        axis
            Joint axis in the joint frame (omitted for fixed joints).
        limit
            ``(lower, upper, effort, velocity)`` in rad or m, N.m or N, rad/s or m/s;
            ``lower`` and ``upper`` None for a continuous joint.
        dynamics
            ``(damping, friction)``: N.m.s/rad or N.s/m, and N.m or N; omitted when None.
        mimic
            ``(leader joint, multiplier, offset (rad or m))``: this joint follows the leader.
        """
        element = etree.SubElement(self.robot, "joint", name=name, type=kind)
        etree.SubElement(element, "parent", link=parent)
        etree.SubElement(element, "child", link=child)
        self.origin(element, origin)
        if axis is not None:
            etree.SubElement(element, "axis", xyz=numbers(axis))
        if limit is not None:
            lower, upper, effort, velocity = limit
            bounds = {} if lower is None or upper is None else {
                "lower": bounded(lower), "upper": bounded(upper)}
            etree.SubElement(element, "limit", effort=bounded(effort),
                             velocity=bounded(velocity), **bounds)
        if dynamics is not None:
            etree.SubElement(element, "dynamics", damping=str(float(dynamics[0])),
                             friction=str(float(dynamics[1])))
        if mimic is not None:
            leader, multiplier, offset = mimic
            etree.SubElement(element, "mimic", joint=leader, multiplier=str(float(multiplier)),
                             offset=str(float(offset)))

    def text(self) -> str:
        """The document, indented, with its XML declaration."""
        return etree.tostring(self.robot, pretty_print=True, xml_declaration=True,
                              encoding="utf-8").decode()
