"""Writing URDF documents: links, joints and their origins from homogeneous transforms.

The one writer of the URDF files the toolkit generates (the SK120 of the paper reproduction,
the parallel platforms of :mod:`stiffness.robot.platform`). Numbers are written as Python's
shortest round-trip repr, so a file read back gives the same floats; rotations as Pinocchio's
roll-pitch-yaw (``pin.rpy.matrixToRpy``), the convention the URDF reader inverts. Units: SI
(m, rad, N.m, rad/s).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from lxml import etree


def numbers(values) -> str:
    """A URDF vector attribute: each number as Python's shortest round-trip repr."""
    return " ".join(str(float(v)) for v in values)


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

    def link(self, name: str, box: tuple[list[float], np.ndarray] | None = None) -> None:
        """Add a link, optionally with a box visual ``(size (m), origin transform)``."""
        element = etree.SubElement(self.robot, "link", name=name)
        if box is not None:
            size, centre = box
            visual = etree.SubElement(element, "visual", name=f"{name}_visual")
            etree.SubElement(etree.SubElement(visual, "geometry"), "box", size=numbers(size))
            self.origin(visual, centre)

    def joint(self, name: str, kind: str, parent: str, child: str, origin: np.ndarray,
              axis: list[float] | None = None,
              limit: tuple[float, float, float, float] | None = None) -> None:
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
            ``(lower, upper, effort, velocity)`` in rad or m, N.m or N, rad/s or m/s.
        """
        element = etree.SubElement(self.robot, "joint", name=name, type=kind)
        etree.SubElement(element, "parent", link=parent)
        etree.SubElement(element, "child", link=child)
        self.origin(element, origin)
        if axis is not None:
            etree.SubElement(element, "axis", xyz=numbers(axis))
        if limit is not None:
            lower, upper, effort, velocity = (float(v) for v in limit)
            etree.SubElement(element, "limit", effort=str(effort), velocity=str(velocity),
                             lower=str(lower), upper=str(upper))

    def text(self) -> str:
        """The document, indented, with its XML declaration."""
        return etree.tostring(self.robot, pretty_print=True, xml_declaration=True,
                              encoding="utf-8").decode()
