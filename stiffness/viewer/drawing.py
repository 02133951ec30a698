"""meshcat objects of the viewer's scene whose look depends on values: the principal axes of
an ellipsoid, the floor, and the ellipsoids' colours and visibility.

Lengths in m; colours by k_min (N/m) on the colour range (:mod:`stiffness.viewer.style`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from stiffness.mechanics.formulation import FORMULATIONS
from stiffness.viewer.deps import meshcat_modules
from stiffness.viewer.geometry import Pose
from stiffness.viewer.states import (
    DEFLECTED_NODE,
    FLOOR_NODE,
    ROTATIONAL_NODE,
    STIFFNESS_NODE,
    SceneState,
)
from stiffness.viewer.style import COLORMAPS, ROTATIONAL_COLOR, color_of, rgb_int


def axes_object() -> Any:
    """The three principal axes of a unit sphere (red, green, blue: axes 1, 2, 3)."""
    mg = meshcat_modules().geometry
    points = np.array([[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0], [0, 0, -1], [0, 0, 1]],
                      dtype=np.float32).T
    colors = np.array([[0.7, 0, 0]] * 2 + [[0, 0.5, 0]] * 2 + [[0, 0, 0.8]] * 2,
                      dtype=np.float32).T
    return mg.LineSegments(mg.PointsGeometry(points, colors),
                           mg.LineBasicMaterial(vertexColors=True))


def draw_floor(vis: Any, z: float, center: np.ndarray, half: float, spacing: float,
               reach: float) -> None:
    """A plate at height ``z`` (m) centred on ``center`` (x, y), ``2 half`` wide, with a grid
    of ``spacing`` (m); thickness and grid offset scale with the robot's ``reach`` (m)."""
    mg = meshcat_modules().geometry
    thickness = 0.004 * reach
    vis[f"{FLOOR_NODE}/plate"].set_object(
        mg.Box([2 * half, 2 * half, thickness]),
        mg.MeshLambertMaterial(color=0xE9E7E1, opacity=0.92, transparent=True))
    vis[f"{FLOOR_NODE}/plate"].set_transform(Pose(
        np.array([center[0], center[1], z - 0.5 * thickness]), np.eye(3),
        np.ones(3)).matrix())
    ticks = np.arange(-half, half + 0.5 * spacing, spacing)
    segments = []
    for t in ticks:
        segments += [[t, -half, 0.0], [t, half, 0.0], [-half, t, 0.0], [half, t, 0.0]]
    points_xyz = (np.array(segments) + [center[0], center[1], z + 1e-4 * reach]).T
    vis[f"{FLOOR_NODE}/grid"].set_object(mg.LineSegments(
        mg.PointsGeometry(points_xyz.astype(np.float32)),
        mg.LineBasicMaterial(color=0xA9ADB5)))


def style_objects(vis: Any, state: SceneState, color_range: tuple[float, float], reach: float
                  ) -> None:
    """Objects whose look depends on the values: ellipsoid colours (k_min on
    ``color_range``, N/m) and visibility (the labels are the page's, see
    :mod:`stiffness.viewer.legend`)."""
    mg = meshcat_modules().geometry
    lo, hi = color_range
    if state.deflected_q is None:  # else as the user left it: off at first (the legend's box)
        vis[DEFLECTED_NODE].set_property("visible", False)
    vis[f"{STIFFNESS_NODE}/deflection"].set_property("visible", state.deflection is not None)
    for name in FORMULATIONS:
        base = f"{STIFFNESS_NODE}/{name}"
        if name not in state.ellipsoids:
            vis[base].set_property("visible", False)
            continue
        vis[base].set_property("visible", True)
        ell = state.ellipsoids[name]
        rgb = color_of(COLORMAPS[name], (ell.min_stiffness - lo) / (hi - lo))
        vis[f"{base}/surface"].set_object(
            mg.Sphere(1.0), mg.MeshPhongMaterial(color=rgb_int(rgb), opacity=0.55,
                                                 transparent=True, depthWrite=False))
        vis[f"{base}/axes"].set_object(axes_object())
        vis[f"{base}/link"].set_object(mg.Cylinder(1.0, 0.003 * reach),
                                       mg.MeshPhongMaterial(color=0x888888))
    if state.rotational is not None:
        vis[f"{ROTATIONAL_NODE}/surface"].set_object(
            mg.Sphere(1.0), mg.MeshPhongMaterial(color=ROTATIONAL_COLOR, opacity=0.5,
                                                 transparent=True, depthWrite=False))
        vis[f"{ROTATIONAL_NODE}/axes"].set_object(axes_object())
        vis[f"{ROTATIONAL_NODE}/link"].set_object(mg.Cylinder(1.0, 0.003 * reach),
                                                  mg.MeshPhongMaterial(color=0x888888))
    moment = state.wrench[3:]
    vis[f"{STIFFNESS_NODE}/moment"].set_property("visible", bool(np.any(moment)))
    vis[f"{STIFFNESS_NODE}/force"].set_property("visible", bool(np.any(state.wrench[:3])))

