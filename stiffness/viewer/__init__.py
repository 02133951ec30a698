"""Stiffness ellipsoids in the browser: meshcat scenes of a robot, its load and its stiffness.

:class:`StiffnessViewer` draws, in `meshcat <https://github.com/meshcat-dev/meshcat-python>`_
(through Pinocchio's ``MeshcatVisualizer`` for the robot's meshes):

* the robot at a configuration, and a translucent red copy of it at the *exact* equilibrium
  under the load (:func:`stiffness.mechanics.equilibrium.solve_equilibrium`) with the deflection
  multiplied by a stated factor (``exaggeration``);
* the load arrow at the target (force; a second arrow for a moment, if any);
* the translational stiffness ellipsoid (3x3, N/m) or compliance ellipsoid (m/N) at the target,
  for the ``enhanced`` (K_theta - K_C, A&S eq. 10) and ``conventional`` (K_theta, eq. 8)
  formulations: the enhanced one at the target, the conventional one beside it (linked to the
  target by a grey line), with their principal axes drawn; the page labels the axis tips
  (``k1``, ``k2``, ``k3``) and the ellipsoids with leader lines, never overlapping one another,
  the legend or the robot (a label with no free place is dropped), the values in the legend;
* the rotational 3x3 block of a 6x6 stiffness (N.m/rad) or compliance, hidden until toggled;
* a floor under the robot;
* an ellipsoid field over a workspace sample (:meth:`StiffnessViewer.field`);
* a path through configurations as a meshcat animation (:meth:`StiffnessViewer.sweep`).

A legend (top left of the page) states every scale: ellipsoid radii, colours, load arrow,
exaggeration factor.

Ellipsoid convention. With ``M`` the drawn matrix (the stiffness ``K_X = C^-1`` in N/m, or the
compliance ``C = J (K_theta - K_C)^-1 J^T`` in m/N, translational rows of the target Jacobian,
base axes) and ``M = V diag(lambda) V^T`` its eigen-decomposition (symmetric part, eigenvalues
ascending, ``det V = +1``), the ellipsoid is the unit sphere under the transform
``[V diag(s |lambda|), c]``: principal axis ``i`` is column ``i`` of ``V`` and its radius is
``s |lambda_i|`` (m), linear in the principal value, with ``s`` the stated scale (m per N/m,
or m per m/N). A negative principal stiffness (an indefinite enhanced stiffness under a large
load) is drawn by its magnitude and its value keeps its sign; an unbounded principal
stiffness (the compliance is singular) is drawn clipped and given as ``inf``. The scale, the
colour range and the exaggeration are fixed by the first :meth:`StiffnessViewer.show` (or
given), so that browsing compares like with like.

Colour. Each ellipsoid is coloured by its smallest principal stiffness ``k_min`` (N/m) on a
stated linear range: oranges for the enhanced formulation, blues for the conventional one,
viridis for the field.

Server. The live viewer starts its own server process (meshcat's viewer page, websocket and
ZeroMQ command socket) bound to 127.0.0.1 by default, on free ports; every request to it has a
timeout (nothing waits for a browser forever), and the process is stopped by
:meth:`StiffnessViewer.close`, by leaving a ``with`` block, at interpreter exit, and by itself
when its parent process dies. meshcat 0.3.2's own server binds its web port on every interface
and its ``wait`` can leave its command socket stuck; neither is used.

Modules: :mod:`~stiffness.viewer.core` (the viewer), :mod:`~stiffness.viewer.states` (what it
drew, scene paths), :mod:`~stiffness.viewer.layout` (where things go: radii, arrows, floor,
camera), :mod:`~stiffness.viewer.drawing` (value-dependent meshcat objects),
:mod:`~stiffness.viewer.legend` (the page's legend and controls),
:mod:`~stiffness.viewer.ellipsoid` (ellipsoid algebra), :mod:`~stiffness.viewer.style`
(formatting, colours), :mod:`~stiffness.viewer.geometry` (scene geometry),
:mod:`~stiffness.viewer.scene` (the recorded scene), :mod:`~stiffness.viewer.page` (HTML
pages), :mod:`~stiffness.viewer.server` (the live server; ``python -m stiffness.viewer
--serve ...`` runs it), :mod:`~stiffness.viewer.deps` (lazy imports of meshcat). Everything
public is re-exported here.

Units: SI (m, N, rad; N/m, m/N; N.m/rad for joints).
"""

from stiffness.viewer.core import StiffnessViewer
from stiffness.viewer.ellipsoid import (
    QUANTITIES,
    PrincipalEllipsoid,
    ellipsoid_transform,
    principal_ellipsoid,
)
from stiffness.viewer.geometry import Pose, TextSprite
from stiffness.viewer.page import render_page, scene_commands, scene_transforms
from stiffness.viewer.scene import SceneStore
from stiffness.viewer.server import DEFAULT_TIMEOUT, LOOPBACK, LiveServer, ServerLimits
from stiffness.viewer.states import (
    DEFLECTED_NODE,
    FIELD_NODE,
    ROBOT_NODE,
    SHOW_FORMULATIONS,
    STIFFNESS_NODE,
    FieldState,
    SceneState,
)
from stiffness.viewer.style import (
    COLORMAPS,
    DEFLECTED_RGBA,
    FORCE_COLOR,
    FORMULATION_LABELS,
    MOMENT_COLOR,
    format_value,
)

__all__ = [
    "COLORMAPS",
    "DEFAULT_TIMEOUT",
    "DEFLECTED_NODE",
    "DEFLECTED_RGBA",
    "FIELD_NODE",
    "FORCE_COLOR",
    "FORMULATION_LABELS",
    "LOOPBACK",
    "MOMENT_COLOR",
    "QUANTITIES",
    "ROBOT_NODE",
    "SHOW_FORMULATIONS",
    "STIFFNESS_NODE",
    "FieldState",
    "LiveServer",
    "ServerLimits",
    "Pose",
    "PrincipalEllipsoid",
    "SceneState",
    "SceneStore",
    "StiffnessViewer",
    "TextSprite",
    "ellipsoid_transform",
    "format_value",
    "principal_ellipsoid",
    "render_page",
    "scene_commands",
    "scene_transforms",
]
