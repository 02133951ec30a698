"""Scene geometry: poses of scene nodes, segments between points, a camera-facing text sprite.

Positions in m, in the base frame; rotations proper (``det = +1``).
"""

from __future__ import annotations

import uuid
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from stiffness.viewer.ellipsoid import ellipsoid_transform


@dataclass
class Pose:
    """Placement of a scene node: ``position`` (m), proper ``rotation``, ``scale`` per axis."""

    position: np.ndarray
    rotation: np.ndarray
    scale: np.ndarray

    def matrix(self) -> np.ndarray:
        """4x4 homogeneous transform ``[rotation diag(scale), position]``."""
        return ellipsoid_transform(self.position, self.rotation, self.scale)

    def quaternion(self) -> list[float]:
        """Rotation as [x, y, z, w] (three.js order)."""
        return [float(c) for c in pin.Quaternion(self.rotation).coeffs()]


def missing_mesh_notes(robot) -> list[str]:
    """One line per visual mesh of ``robot`` that could not be found (drawn as a sphere).

    Meshes are resolved when the robot is loaded (:mod:`stiffness.robot.meshes`: the URDF's
    folder and its ancestors, ``ROS_PACKAGE_PATH``, example-robot-data's share folder).
    """
    missing = list(getattr(robot, "missing_meshes", ()))
    lines = [f"mesh not found: {m}; drawn as a sphere (searched the URDF's folder, "
             "ROS_PACKAGE_PATH and example-robot-data)" for m in missing[:10]]
    if len(missing) > 10:
        lines.append(f"... and {len(missing) - 10} more meshes not found")
    return lines


def rotation_y_to(direction: np.ndarray) -> np.ndarray:
    """A rotation taking +y (three.js cylinders' axis) to the unit vector ``direction``."""
    d = np.asarray(direction, dtype=float)
    d = d / np.linalg.norm(d)
    helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    x = np.cross(d, helper)
    x /= np.linalg.norm(x)
    z = np.cross(x, d)
    return np.column_stack([x, d, z])


def segment_pose(start: np.ndarray, end: np.ndarray) -> Pose:
    """Pose of a unit-height, y-axis cylinder stretched from ``start`` to ``end``."""
    delta = np.asarray(end, dtype=float) - np.asarray(start, dtype=float)
    length = float(np.linalg.norm(delta))
    rotation = rotation_y_to(delta) if length > 1e-12 else np.eye(3)
    return Pose(0.5 * (np.asarray(start) + np.asarray(end)), rotation,
                np.array([1.0, max(length, 1e-9), 1.0]))


class TextSprite:
    """A camera-facing text label (three.js Sprite with meshcat's ``_text`` canvas texture).

    ``height`` (m) is the sprite's side; the text is fitted to its width.
    """

    def __init__(self, text: str, height: float, font_size: int = 40) -> None:
        self.text = text
        self.height = height
        self.font_size = font_size

    def lower(self) -> dict:
        """three.js object JSON (meshcat ``set_object`` payload)."""
        texture, material, obj = (str(uuid.uuid4()) for _ in range(3))
        s = float(self.height)
        return {
            "metadata": {"version": 4.5, "type": "Object"},
            "geometries": [],
            "textures": [{"uuid": texture, "type": "_text", "text": self.text,
                          "font_size": self.font_size, "font_face": "sans-serif"}],
            "materials": [{"uuid": material, "type": "SpriteMaterial", "map": texture,
                           "transparent": True, "depthTest": False, "depthWrite": False}],
            "object": {"uuid": obj, "type": "Sprite", "material": material,
                       "matrix": [s, 0, 0, 0, 0, s, 0, 0, 0, 0, s, 0, 0, 0, 0, 1],
                       "renderOrder": 10},
        }
