"""What the viewer drew: :class:`SceneState` (one configuration), :class:`FieldState` (an
ellipsoid field), the scene's node paths and the robot's name in titles.

Units: SI (m, N, rad; N/m, m/N; N.m/rad for joints).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from stiffness.mechanics.formulation import FORMULATIONS
from stiffness.viewer.ellipsoid import PrincipalEllipsoid, RotationalBlock
from stiffness.viewer.geometry import Pose

#: Formulation choices of :meth:`StiffnessViewer.show` (``both``: side by side).
SHOW_FORMULATIONS = ("both", *FORMULATIONS)
#: Scene paths (below meshcat's root ``/meshcat``).
ROBOT_NODE = "robot"
DEFLECTED_NODE = "deflected"
#: Largest radius of a field ellipsoid, in sample spacings (beyond: clipped and marked).
FIELD_CLIP = 2.0
STIFFNESS_NODE = "stiffness"
FIELD_NODE = "field"
FLOOR_NODE = "floor"
ROTATIONAL_NODE = "rotational"

#: Names of the principal axes (axis i along eigenvector i; the page labels k1, k2, k3).
AXIS_NAMES = ("1", "2", "3")


@dataclass
class SceneState:
    """What :meth:`StiffnessViewer.show` drew.

    Attributes
    ----------
    coords
        Robot coordinates (rad, m for prismatic joints).
    q
        Full configuration, loops closed.
    wrench
        Dead wrench at the target [F (N); M (N.m)], base axes.
    position
        Target position (m).
    ellipsoids
        Drawn ellipsoids by formulation.
    centers
        Where each ellipsoid is drawn (m).
    radii
        Drawn radii (m) by formulation, along each ellipsoid's ``directions``.
    scale
        Radius per unit of principal value (m per N/m, or m per m/N).
    quantity
        ``stiffness`` or ``compliance``.
    deflection
        Exact target displacement under the load (m), or ``None`` (no load, or no equilibrium).
    deflected_q
        Configuration drawn as the deflected robot (deflection times ``exaggeration``).
    exaggeration
        Factor applied to the joint deflection for drawing.
    note
        Why the deflected robot is missing, if it is.
    rotational
        Rotational 3x3 block of the 6x6 stiffness (N.m/rad) or compliance (rad/(N.m)) of the
        first formulation drawn, or ``None`` (no 6x6 matrix: fewer than six compliant joints
        for a stiffness); drawn hidden, beside the target, in its own scale.
    poses
        Pose of every scene node drawn (scene path below ``/meshcat`` -> :class:`Pose`).
    """

    coords: np.ndarray
    q: np.ndarray
    wrench: np.ndarray
    position: np.ndarray
    ellipsoids: dict[str, PrincipalEllipsoid]
    centers: dict[str, np.ndarray]
    radii: dict[str, np.ndarray]
    scale: float
    quantity: str
    deflection: np.ndarray | None
    deflected_q: np.ndarray | None
    exaggeration: float
    note: str = ""
    rotational: RotationalBlock | None = None
    poses: dict[str, Pose] = field(default_factory=dict, repr=False)


@dataclass
class FieldState:
    """What :meth:`StiffnessViewer.field` drew: one ellipsoid per workspace sample.

    Attributes
    ----------
    coords
        (m, n) coordinates of the samples kept (rad or m).
    positions
        (m, 3) target positions (m).
    ellipsoids
        Their ellipsoids.
    min_stiffness
        (m,) smallest principal stiffness of each (N/m), the colour scale's quantity.
    scale
        Radius per unit of principal value (m per N/m, or m per m/N).
    skipped
        Samples dropped (loop cannot close, singular tangent stiffness).
    color_range
        (lo, hi) of the colour scale of k_min (N/m).
    clipped
        (m,) whether each ellipsoid was clipped at :data:`FIELD_CLIP` sample spacings (a pose
        near a singularity, whose largest principal value dwarfs the others'); drawn grey and
        translucent.
    """

    coords: np.ndarray
    positions: np.ndarray
    ellipsoids: list[PrincipalEllipsoid]
    min_stiffness: np.ndarray
    scale: float
    skipped: int
    color_range: tuple[float, float]
    clipped: np.ndarray | None = None
