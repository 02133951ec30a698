"""The viewer: :class:`StiffnessViewer` and what it drew (:class:`SceneState`, :class:`FieldState`).

:class:`StiffnessViewer` draws the robot and its deflected copy, the load, the stiffness (or
compliance) ellipsoids of both formulations, ellipsoid fields and animated paths into a
recorded meshcat scene, forwarded to a live server if any, and writes it as a static page
(:meth:`StiffnessViewer.export`). See :mod:`stiffness.viewer` for the conventions.

Units: SI (m, N, rad; N/m, m/N; N.m/rad for joints).
"""

from __future__ import annotations

import contextlib
import html as html_lib
import os
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from stiffness.errors import StiffnessError, UnknownJointError, UnknownNameError
from stiffness.files import atomic_write
from stiffness.mechanics.defaults import default_coordinates, default_load
from stiffness.mechanics.equilibrium import solve_equilibrium
from stiffness.mechanics.formulation import (
    FORMULATIONS,
    as_wrench,
    joint_stiffness,
    tangent_joint_stiffness,
    target_state,
)
from stiffness.robot.robot import Robot
from stiffness.viewer.deps import _meshcat, _pinocchio_meshcat_visualizer
from stiffness.viewer.ellipsoid import (
    QUANTITIES,
    PrincipalEllipsoid,
    RotationalBlock,
    ellipsoid_transform,
    principal_ellipsoid,
    rotational_block,
)
from stiffness.viewer.geometry import Pose, _rotation_y_to, _segment, missing_mesh_notes
from stiffness.viewer.page import render_page
from stiffness.viewer.server import DEFAULT_TIMEOUT, LOOPBACK, LiveServer, _Window
from stiffness.viewer.style import (
    COLORMAPS,
    DEFLECTED_RGBA,
    FORCE_COLOR,
    FORMULATION_LABELS,
    MOMENT_COLOR,
    ROTATIONAL_COLOR,
    _color_of,
    _colorbar,
    _hex,
    _nice,
    _nice_up,
    _rgb_int,
    format_value,
)

#: Formulation choices of :meth:`StiffnessViewer.show` (``both``: side by side).
SHOW_FORMULATIONS = ("both", *FORMULATIONS)
#: Scene paths (below meshcat's root ``/meshcat``).
ROBOT_NODE = "robot"
DEFLECTED_NODE = "deflected"
STIFFNESS_NODE = "stiffness"
FIELD_NODE = "field"
FLOOR_NODE = "floor"
ROTATIONAL_NODE = "rotational"

#: Radius drawn for an unbounded principal value, in multiples of the largest finite radius.
_UNBOUNDED_RADIUS = 3.0
_AXIS_NAMES = ("1", "2", "3")


def display_name(robot: Robot) -> str:
    """The robot's name for titles: its source name, or the URDF's robot name (never a path)."""
    name = robot.name
    if "/" in name or "\\" in name or name.lower().endswith((".urdf", ".xml")):
        name = robot.model.name or Path(name).stem
    return name


def _coordinates_or_zero(robot: Robot) -> np.ndarray:
    """A shipped robot's default coordinates, else zeros (rad, m)."""
    shipped = default_coordinates(robot)
    return np.zeros(robot.n_coordinates) if shipped is None else shipped


def _load_or_zero(robot: Robot, q: np.ndarray, k_theta: np.ndarray) -> np.ndarray:
    """A shipped robot's default load as a wrench [F (N); M (N.m)], else no load."""
    shipped = default_load(robot, q, k_theta)
    return np.zeros(6) if shipped is None else as_wrench(shipped[0])


def _axes_object() -> Any:
    """The three principal axes of a unit sphere (red, green, blue: axes 1, 2, 3)."""
    mg = _meshcat().geometry
    points = np.array([[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0], [0, 0, -1], [0, 0, 1]],
                      dtype=np.float32).T
    colors = np.array([[0.7, 0, 0]] * 2 + [[0, 0.5, 0]] * 2 + [[0, 0, 0.8]] * 2,
                      dtype=np.float32).T
    return mg.LineSegments(mg.PointsGeometry(points, colors),
                           mg.LineBasicMaterial(vertexColors=True))


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
    """

    coords: np.ndarray
    positions: np.ndarray
    ellipsoids: list[PrincipalEllipsoid]
    min_stiffness: np.ndarray
    scale: float
    skipped: int
    color_range: tuple[float, float]


class StiffnessViewer:
    """Browse a robot's stiffness in meshcat: ellipsoids, load, deflection, fields, paths.

    Parameters
    ----------
    robot
        The robot (:func:`stiffness.robot.robot.load_robot`).
    k_theta
        Joint stiffness: one value per compliant joint (N.m/rad; N/m prismatic) or the (n, n)
        matrix.
    live
        Start a live server (the page follows every call; its controls move the joints, the
        load and the formulation, see :meth:`browse`). ``False``: record the scene only, for
        :meth:`export` (no network, no process).
    quantity
        ``stiffness`` (K_X, N/m) or ``compliance`` (C, m/N) ellipsoids.
    size
        Largest ellipsoid radius (m) at the first :meth:`show`, which fixes the scale; default
        12 % of the robot's reach.
    scale
        Radius per unit of principal value (m per N/m or per m/N), instead of ``size``.
    exaggeration
        Factor applied to the deflection of the drawn deflected robot; default: a round number
        making the target's displacement about 8 % of the reach at the first load.
    color_range
        (lo, hi) of the colour scale of k_min (N/m); default from the first :meth:`show`.
    host, port, timeout
        Live server address (127.0.0.1 by default), web port (0: free) and request timeout (s).
    open_browser
        Open the live page in the system's browser (never waits for it).

    Examples
    --------
    >>> robot = load_robot("ur5", frame="tool0")                       # doctest: +SKIP
    >>> with StiffnessViewer(robot, [3e5, 3e5, 2e5, 4e4, 4e4, 4e4]) as v:  # doctest: +SKIP
    ...     v.show([0, -1.2, 1.5, -0.3, 1.57, 0], wrench=[0, 0, -200])
    ...     v.export("ur5.html")
    """

    def __init__(self, robot: Robot, k_theta: Sequence[float] | np.ndarray, *,
                 live: bool = False, quantity: str = "stiffness", size: float | None = None,
                 scale: float | None = None, exaggeration: float | None = None,
                 color_range: tuple[float, float] | None = None, host: str = LOOPBACK,
                 port: int = 0, timeout: float = DEFAULT_TIMEOUT, open_browser: bool = False
                 ) -> None:
        if quantity not in QUANTITIES:
            raise UnknownNameError(f"quantity must be one of {', '.join(QUANTITIES)}, got "
                                   f"{quantity!r}", name=quantity, choices=QUANTITIES)
        k = np.asarray(k_theta, dtype=float)
        self.k_theta = k if k.ndim == 2 else joint_stiffness(k, robot.n_compliant)
        if self.k_theta.shape != (robot.n_compliant, robot.n_compliant):
            raise StiffnessError(f"k_theta must be ({robot.n_compliant}, {robot.n_compliant}) "
                                 f"for {robot.name}, got {self.k_theta.shape}")
        self.robot = robot
        self.quantity = quantity
        self.reach = self._reach()
        self.size = float(size) if size is not None else 0.12 * self.reach
        self._floor_drawn = False
        self._scales: dict[str, float] = {} if scale is None else {quantity: float(scale)}
        self.exaggeration = exaggeration
        self.color_range = color_range
        self.arrow_scale: float | None = None
        self.server = LiveServer(host, port, timeout) if live else None
        self._window = _Window(self.server)
        mc = _meshcat()
        self._vis = mc.meshcat.Visualizer(window=self._window)
        self._lock = threading.RLock()
        self._browser_thread: threading.Thread | None = None
        self._stop_browsing = threading.Event()
        self.state: SceneState | None = None
        self.field_state: FieldState | None = None
        self._frames: dict | None = None
        self._error: str | None = None
        self._formulation = "both"
        self._build_static_scene()
        if open_browser and self.server is not None:
            import webbrowser

            webbrowser.open(self.server.web_url, new=2)

    # ------------------------------------------------------------------ setup

    @property
    def url(self) -> str | None:
        """The live page's address, or ``None`` for a recording viewer."""
        return self.server.web_url if self.server is not None else None

    def _reach(self) -> float:
        model, data = self.robot.model, self.robot.data
        q = pin.neutral(model)
        with contextlib.suppress(StiffnessError):
            q = self.robot.configuration(_coordinates_or_zero(self.robot))
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        points = [data.oMi[j].translation for j in range(model.njoints)]
        points.append(data.oMf[self.robot.target_frame_id].translation)
        return max(float(np.max(np.linalg.norm(points, axis=1))), 0.2)

    def _build_static_scene(self) -> None:
        vis = self._vis
        vis["/Background"].set_property("top_color", [0.98, 0.98, 0.98])
        vis["/Background"].set_property("bottom_color", [0.78, 0.8, 0.84])
        vis["/Grid"].set_property("visible", False)  # replaced by the floor under the robot
        visual = self.robot.visual_model
        self._has_meshes = visual is not None and visual.ngeoms > 0
        if not getattr(self, "_missing_reported", False):
            for line in missing_mesh_notes(self.robot):
                print(f"stiffness viewer: {line}", file=sys.stderr)
            self._missing_reported = True
        if self._has_meshes:
            visualizer = _pinocchio_meshcat_visualizer()
            self._viz = visualizer(self.robot.model, None, visual)
            self._viz.initViewer(viewer=vis)
            self._viz.loadViewerModel(ROBOT_NODE)
            # the deflected robot reuses these meshes: the page copies them (see page._PAGE_JS)
            self._visual_data = visual.createData()
        else:
            mg = _meshcat().geometry
            self._links = self._skeleton_links()
            for root, rgba in ((ROBOT_NODE, (0.55, 0.57, 0.6, 1.0)),
                               (DEFLECTED_NODE, DEFLECTED_RGBA)):
                material = mg.MeshPhongMaterial(color=_rgb_int(rgba), opacity=rgba[3])
                for name, _, _ in self._links:
                    vis[f"{root}/visuals/{name}"].set_object(
                        mg.Cylinder(1.0, 0.015 * self.reach), material)
        vis[DEFLECTED_NODE].set_property("visible", False)
        mg = _meshcat().geometry
        base = f"{STIFFNESS_NODE}"
        vis[f"{base}/target"].set_object(mg.Sphere(0.012 * self.reach),
                                         mg.MeshPhongMaterial(color=0x222222))
        vis[f"{base}/deflection"].set_object(
            mg.Cylinder(1.0, 0.004 * self.reach), mg.MeshPhongMaterial(color=0xCC0000))
        vis[ROTATIONAL_NODE].set_property("visible", False)
        for name, color in (("force", FORCE_COLOR), ("moment", MOMENT_COLOR)):
            material = mg.MeshPhongMaterial(color=color)
            vis[f"{base}/{name}/shaft"].set_object(mg.Cylinder(1.0, 0.008 * self.reach), material)
            vis[f"{base}/{name}/head"].set_object(
                mg.Cylinder(0.06 * self.reach, radiusTop=0.0, radiusBottom=0.02 * self.reach),
                material)

    def _skeleton_links(self) -> list[tuple[str, int, int]]:
        """Segments (name, parent joint, child joint) drawn for robots without meshes."""
        model = self.robot.model
        links = [(f"link_{model.names[j]}", int(model.parents[j]), j)
                 for j in range(1, model.njoints)]
        links.append(("link_target", -1, -1))
        return links

    # ------------------------------------------------------------------ computing

    def _configuration(self, coords: Sequence[float] | np.ndarray | None) -> tuple:
        robot = self.robot
        seed = self.state.q if self.state is not None else None
        if coords is None:
            if self.state is not None:
                return self.state.coords, self.state.q
            coords = _coordinates_or_zero(robot)
        values = np.asarray(coords, dtype=float).reshape(-1)
        if values.shape[0] != robot.n_coordinates and values.shape[0] == robot.model.nq:
            return robot.coordinates_of(values), values
        return values, robot.configuration(values, seed=seed)

    def _load(self, wrench: Sequence[float] | np.ndarray | None, q: np.ndarray | None = None
              ) -> np.ndarray:
        if wrench is None:
            if self.state is not None:
                return self.state.wrench
            if q is None:
                q = self._configuration(None)[1]
            return _load_or_zero(self.robot, q, self.k_theta)
        return as_wrench(wrench)

    def _formulations(self, formulation: str | None) -> tuple[str, tuple[str, ...]]:
        formulation = self._formulation if formulation is None else formulation
        if formulation not in SHOW_FORMULATIONS:
            raise UnknownNameError(
                f"formulation must be one of {', '.join(SHOW_FORMULATIONS)}, got "
                f"{formulation!r}", name=str(formulation), choices=SHOW_FORMULATIONS)
        return formulation, FORMULATIONS[::-1] if formulation == "both" else (formulation,)

    def ellipsoids(self, q: np.ndarray, wrench: np.ndarray, formulations: Sequence[str],
                   quantity: str | None = None) -> tuple[Any, dict[str, PrincipalEllipsoid]]:
        """Target state and principal ellipsoids at a (closed) configuration ``q``."""
        quantity = self.quantity if quantity is None else quantity
        state = target_state(self.robot, q, wrench)
        jac = state.jacobian[:3]
        out = {}
        for name in formulations:
            tangent = tangent_joint_stiffness(self.k_theta, state.k_c, name)
            out[name] = principal_ellipsoid(jac, tangent, name, quantity)
        return state, out

    def _scale(self, quantity: str, ellipsoids: list[PrincipalEllipsoid]) -> float:
        if quantity not in self._scales:
            finite = [np.max(np.abs(e.values[np.isfinite(e.values)]), initial=0.0)
                      for e in ellipsoids]
            largest = max(finite, default=0.0)
            self._scales[quantity] = self.size / largest if largest > 0 else 1.0
        return self._scales[quantity]

    @staticmethod
    def _radii(ellipsoid: PrincipalEllipsoid, scale: float) -> np.ndarray:
        radii = np.abs(ellipsoid.values) * scale
        finite = radii[np.isfinite(radii)]
        cap = _UNBOUNDED_RADIUS * (np.max(finite) if finite.size else 1.0)
        return np.where(np.isfinite(radii), np.maximum(radii, 1e-6 * cap), cap)

    def _deflection(self, coords: np.ndarray, q: np.ndarray, wrench: np.ndarray
                    ) -> tuple[np.ndarray | None, np.ndarray | None, str]:
        if not np.any(wrench):
            return None, None, "no load: no deflection"
        try:
            eq = solve_equilibrium(self.robot, q, self.k_theta, wrench)
        except StiffnessError as exc:
            return None, None, f"no equilibrium: {exc}"
        if self.exaggeration is None:
            moved = float(np.linalg.norm(eq.dx))
            self.exaggeration = _nice(0.08 * self.reach / moved) if moved > 0 else 1.0
        dcoords = np.zeros(self.robot.n_coordinates)
        dcoords[self.robot.compliant_in_coordinates] = eq.dtheta
        try:
            shown = self.robot.configuration(coords + self.exaggeration * dcoords, seed=q)
        except StiffnessError as exc:
            return eq.dx, None, f"deflected pose x{self.exaggeration:g} not drawable: {exc}"
        return eq.dx, shown, ""

    def _color_range(self, values: list[float]) -> tuple[float, float]:
        if self.color_range is None:
            finite = [v for v in values if np.isfinite(v)]
            top = max(finite, default=1.0)
            self.color_range = (0.0, _nice_up(2.0 * top) if top > 0 else 1.0)
        return self.color_range

    # ------------------------------------------------------------------ drawing

    def _robot_poses(self, root: str, q: np.ndarray) -> dict[str, Pose]:
        model, data = self.robot.model, self.robot.data
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        poses = {}
        if self._has_meshes:
            visual = self.robot.visual_model
            pin.updateGeometryPlacements(model, data, visual, self._visual_data)
            for i, obj in enumerate(visual.geometryObjects):
                placement = self._visual_data.oMg[i]
                name = self._viz.getViewerNodeName(obj, pin.GeometryType.VISUAL)
                poses[root + name[len(ROBOT_NODE):]] = Pose(
                    placement.translation.copy(), placement.rotation.copy(),
                    np.asarray(obj.meshScale, dtype=float).copy())
        else:
            target = data.oMf[self.robot.target_frame_id].translation
            for name, parent, child in self._links:
                if child < 0:
                    parent_joint = model.frames[self.robot.target_frame_id].parentJoint
                    start, end = data.oMi[parent_joint].translation, target
                else:
                    start = data.oMi[max(parent, 0)].translation
                    end = data.oMi[child].translation
                poses[f"{root}/visuals/{name}"] = _segment(start, end)
        return poses

    def _arrow_poses(self, name: str, origin: np.ndarray, vector: np.ndarray, length: float
                     ) -> dict[str, Pose]:
        base = f"{STIFFNESS_NODE}/{name}"
        if length <= 0 or not np.any(vector):
            hidden = Pose(origin, np.eye(3), np.full(3, 1e-9))
            return {f"{base}/shaft": hidden, f"{base}/head": hidden}
        direction = vector / np.linalg.norm(vector)
        head = 0.06 * self.reach
        tip = origin + direction * max(length, head)
        neck = tip - direction * head
        shaft = _segment(origin, neck)
        return {f"{base}/shaft": shaft,
                f"{base}/head": Pose(neck + 0.5 * head * direction, _rotation_y_to(direction),
                                     np.ones(3))}

    def _side_direction(self, position: np.ndarray) -> np.ndarray:
        radial = np.array([position[0], position[1], 0.0])
        if np.linalg.norm(radial) < 1e-6:
            return np.array([0.0, 1.0, 0.0])
        side = np.cross([0.0, 0.0, 1.0], radial)
        return side / np.linalg.norm(side)

    def show(self, coords: Sequence[float] | np.ndarray | None = None,
             wrench: Sequence[float] | np.ndarray | None = None,
             formulation: str | None = None, *, quantity: str | None = None) -> SceneState:
        """Draw the robot, its load, its deflection and its ellipsoids at one configuration.

        Parameters
        ----------
        coords
            Robot coordinates (rad; m for prismatic), or a full closed configuration ``q``;
            default: the previous one, else the robot's default (shipped robots), else zeros.
        wrench
            Dead force (3,) N or wrench (6,) N, N.m at the target, base axes; default: the
            previous one, else the robot's default load, else none.
        formulation
            ``both`` (side by side), ``enhanced`` or ``conventional``; default: the previous one
            (``both`` at first).
        quantity
            ``stiffness`` or ``compliance``; default: the viewer's.

        Returns
        -------
        SceneState
            The computed matrices, their eigen-decomposition and the drawn radii.

        Raises
        ------
        StiffnessError
            Bad coordinates or load, a loop that cannot close, a singular tangent stiffness.
        """
        with self._lock:
            if quantity is not None and quantity not in QUANTITIES:
                raise UnknownNameError(f"quantity must be one of {', '.join(QUANTITIES)}, "
                                       f"got {quantity!r}", name=quantity, choices=QUANTITIES)
            quantity = quantity or self.quantity
            formulation, names = self._formulations(formulation)
            coords, q = self._configuration(coords)
            load = self._load(wrench, q)
            state = self._compute(coords, q, load, names, quantity)
            self.state, self.quantity, self._formulation = state, quantity, formulation
            if not self._floor_drawn:
                self._draw_floor(state)
            self._send_poses(state.poses)
            self._style(state)
            self._error = None
            self._send_overlay()
            return state

    def _compute(self, coords: np.ndarray, q: np.ndarray, load: np.ndarray,
                 names: Sequence[str], quantity: str) -> SceneState:
        target, ells = self.ellipsoids(q, load, names, quantity)
        scale = self._scale(quantity, list(ells.values()))
        self._color_range([e.min_stiffness for e in ells.values()])
        position = target.position.copy()
        side = self._side_direction(position)
        radii = {n: self._radii(e, scale) for n, e in ells.items()}
        centers = {}
        for n in names:
            centers[n] = position.copy()
        if len(names) == 2:
            gap = np.max(radii["enhanced"]) + np.max(radii["conventional"]) + 1.5 * self.size
            centers["conventional"] = position + gap * side
        dx, deflected_q, note = self._deflection(coords, q, load)
        rotational = rotational_block(target.jacobian, tangent_joint_stiffness(
            self.k_theta, target.k_c, names[0]), names[0], quantity)
        state = SceneState(coords=np.asarray(coords, dtype=float), q=q, wrench=load,
                           position=position, ellipsoids=ells, centers=centers, radii=radii,
                           scale=scale, quantity=quantity, deflection=dx, deflected_q=deflected_q,
                           exaggeration=float(self.exaggeration or 1.0), note=note,
                           rotational=rotational)
        state.poses = self._poses(state)
        return state

    def _rotational_pose(self, state: SceneState) -> tuple[Pose, np.ndarray]:
        """Pose of the rotational block's ellipsoid (its own scale: largest radius ``size``),
        beside the target on the side away from the conventional ellipsoid; and its radii."""
        block = state.rotational
        finite = np.abs(block.values[np.isfinite(block.values)])
        top = float(np.max(finite)) if finite.size else 1.0
        radii = np.where(np.isfinite(block.values), np.abs(block.values) / (top or 1.0),
                         _UNBOUNDED_RADIUS) * self.size
        radii = np.maximum(radii, 1e-3 * self.size)
        first = next(iter(state.radii.values()))
        gap = float(np.max(first)) + float(np.max(radii)) + 1.5 * self.size
        center = state.position - gap * self._side_direction(state.position)
        return Pose(center, block.directions, radii), radii

    def _draw_floor(self, state: SceneState, extra: np.ndarray | None = None) -> None:
        """A floor under the robot (at the first show): a plate at the lowest joint's height
        with a grid of round spacing, spanning the robot, its ellipsoids and ``extra`` points
        (m; a field's targets)."""
        model, data = self.robot.model, self.robot.data
        pin.forwardKinematics(model, data, state.q)
        points = [data.oMi[j].translation.copy() for j in range(model.njoints)]
        points.append(state.position)
        points += [state.centers[n] for n in state.centers]
        points = np.array(points)
        z = float(points[:, 2].min()) - 0.01 * self.reach
        if extra is not None:
            points = np.vstack([points, np.asarray(extra, dtype=float).reshape(-1, 3)])
        lo, hi = points[:, :2].min(axis=0), points[:, :2].max(axis=0)
        center = 0.5 * (lo + hi)
        half = 1.25 * max(0.5 * float(np.max(hi - lo)), self.reach)
        spacing = _nice(half / 4.0)
        half = spacing * np.ceil(half / spacing)
        mg, vis = _meshcat().geometry, self._vis
        thickness = 0.004 * self.reach
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
        points_xyz = (np.array(segments) + [center[0], center[1], z + 1e-4 * self.reach]).T
        vis[f"{FLOOR_NODE}/grid"].set_object(mg.LineSegments(
            mg.PointsGeometry(points_xyz.astype(np.float32)),
            mg.LineBasicMaterial(color=0xA9ADB5)))
        self.floor = {"z": z, "center": center.tolist(), "half_size": float(half),
                      "spacing": float(spacing)}
        self._floor_drawn = True

    def _poses(self, state: SceneState) -> dict[str, Pose]:
        poses = self._robot_poses(ROBOT_NODE, state.q)
        if state.deflected_q is not None:
            poses.update(self._robot_poses(DEFLECTED_NODE, state.deflected_q))
        p = state.position
        poses[f"{STIFFNESS_NODE}/target"] = Pose(p, np.eye(3), np.ones(3))
        force, moment = state.wrench[:3], state.wrench[3:]
        if self.arrow_scale is None and np.any(force):
            self.arrow_scale = 0.25 * self.reach / float(np.linalg.norm(force))
        arrow_scale = self.arrow_scale or 0.0
        poses.update(self._arrow_poses("force", p, force, arrow_scale * np.linalg.norm(force)))
        moment_length = 0.2 * self.reach if np.any(moment) else 0.0
        poses.update(self._arrow_poses("moment", p, moment, moment_length))
        end = p if state.deflection is None else p + state.exaggeration * state.deflection
        poses[f"{STIFFNESS_NODE}/deflection"] = _segment(p, end)
        hidden = Pose(p, np.eye(3), np.full(3, 1e-9))
        for name in FORMULATIONS:
            base = f"{STIFFNESS_NODE}/{name}"
            if name not in state.ellipsoids:
                for part in ("surface", "axes", "label", "link", *(f"label{a}" for a in
                                                                   _AXIS_NAMES)):
                    poses[f"{base}/{part}"] = hidden
                continue
            ell, c, r = state.ellipsoids[name], state.centers[name], state.radii[name]
            pose = Pose(c, ell.directions, r)
            poses[f"{base}/surface"] = pose
            poses[f"{base}/axes"] = pose
            for i, a in enumerate(_AXIS_NAMES):  # label anchors: the axis tips
                tip = c + ell.directions[:, i] * r[i]
                poses[f"{base}/label{a}"] = Pose(tip, np.eye(3), np.ones(3))
            below = c - np.array([0.0, 0.0, np.max(r)])
            poses[f"{base}/label"] = Pose(below, np.eye(3), np.ones(3))
            poses[f"{base}/link"] = _segment(p, c) if np.linalg.norm(c - p) > 0 else hidden
        if state.rotational is not None:
            pose, radii = self._rotational_pose(state)
            poses[f"{ROTATIONAL_NODE}/surface"] = pose
            poses[f"{ROTATIONAL_NODE}/axes"] = pose
            below = pose.position - np.array([0.0, 0.0, float(np.max(radii))])
            poses[f"{ROTATIONAL_NODE}/label"] = Pose(below, np.eye(3), np.ones(3))
            poses[f"{ROTATIONAL_NODE}/link"] = _segment(p, pose.position)
        else:
            for part in ("surface", "axes", "label", "link"):
                poses[f"{ROTATIONAL_NODE}/{part}"] = hidden
        return poses

    def _send_poses(self, poses: dict[str, Pose]) -> None:
        for path, pose in poses.items():
            self._vis[path].set_transform(pose.matrix())

    def _style(self, state: SceneState) -> None:
        """Objects whose look depends on the values: ellipsoid colours and visibility (the
        labels are the page's, see :meth:`overlay`)."""
        vis, mg = self._vis, _meshcat().geometry
        lo, hi = self.color_range
        vis[DEFLECTED_NODE].set_property("visible", state.deflected_q is not None)
        vis[f"{STIFFNESS_NODE}/deflection"].set_property("visible", state.deflection is not None)
        for name in FORMULATIONS:
            base = f"{STIFFNESS_NODE}/{name}"
            if name not in state.ellipsoids:
                vis[base].set_property("visible", False)
                continue
            vis[base].set_property("visible", True)
            ell = state.ellipsoids[name]
            rgb = _color_of(COLORMAPS[name], (ell.min_stiffness - lo) / (hi - lo))
            vis[f"{base}/surface"].set_object(
                mg.Sphere(1.0), mg.MeshPhongMaterial(color=_rgb_int(rgb), opacity=0.55,
                                                     transparent=True, depthWrite=False))
            vis[f"{base}/axes"].set_object(_axes_object())
            vis[f"{base}/link"].set_object(mg.Cylinder(1.0, 0.003 * self.reach),
                                           mg.MeshPhongMaterial(color=0x888888))
        if state.rotational is not None:
            vis[f"{ROTATIONAL_NODE}/surface"].set_object(
                mg.Sphere(1.0), mg.MeshPhongMaterial(color=ROTATIONAL_COLOR, opacity=0.5,
                                                     transparent=True, depthWrite=False))
            vis[f"{ROTATIONAL_NODE}/axes"].set_object(_axes_object())
            vis[f"{ROTATIONAL_NODE}/link"].set_object(mg.Cylinder(1.0, 0.003 * self.reach),
                                                      mg.MeshPhongMaterial(color=0x888888))
        moment = state.wrench[3:]
        vis[f"{STIFFNESS_NODE}/moment"].set_property("visible", bool(np.any(moment)))
        vis[f"{STIFFNESS_NODE}/force"].set_property("visible", bool(np.any(state.wrench[:3])))

    # ------------------------------------------------------------------ legend

    def overlay(self) -> dict:
        """Legend (and live controls) of the current scene, as the page's JSON."""
        robot, st = self.robot, self.state
        data: dict = {"title": f"{display_name(robot)}: {self.quantity} ellipsoids at "
                               f"{robot.target_frame}", "lines": [], "legend": [],
                      "colorbars": [], "toggles": [], "notes": [], "labels": []}
        if self._error:
            data["error"] = self._error
        data["notes"].extend(missing_mesh_notes(robot))
        if st is not None:
            deg = [format_value(v) for v in self._display_coords(st.coords)]
            data["lines"].append(f"coordinates ({', '.join(robot.coordinate_joints)}): "
                                 f"[{', '.join(deg)}] (deg; m for prismatic)")
            f = st.wrench[:3]
            if not np.any(st.wrench):
                data["lines"].append("no load: the unloaded stiffness (K_C = 0, so enhanced "
                                     "and conventional coincide)")
            data["lines"].append(
                f"load F = [{', '.join(format_value(v) for v in f)}] N "
                f"(|F| = {format_value(float(np.linalg.norm(f)), 'N')})"
                + (f", M = [{', '.join(format_value(v) for v in st.wrench[3:])}] N.m"
                   if np.any(st.wrench[3:]) else "") + ", base axes")
            lo, hi = self.color_range
            symbol = "k" if self.quantity == "stiffness" else "c"
            for name, ell in st.ellipsoids.items():
                values = ", ".join(format_value(v) for v in ell.values)
                base = ["meshcat", STIFFNESS_NODE, name]
                data["labels"].append({"text": name, "kind": "name",
                                       "anchor": [*base, "label"], "center": [*base, "surface"]})
                data["labels"] += [{"text": f"{symbol}{a}", "kind": "axis",
                                    "anchor": [*base, f"label{a}"],
                                    "center": [*base, "surface"]} for a in _AXIS_NAMES]
                where = "at the target" if np.allclose(st.centers[name], st.position) else \
                    "beside the target (grey line)"
                rgb = _color_of(COLORMAPS[name], (ell.min_stiffness - lo) / (hi - lo))
                data["legend"].append({
                    "color": _hex(rgb),
                    "text": f"{FORMULATION_LABELS[name]}, {where}: principal {self.quantity} "
                            f"{symbol}1, {symbol}2, {symbol}3 = [{values}] {ell.units}; k_min = "
                            f"{format_value(ell.min_stiffness, 'N/m')}"})
                data["colorbars"].append({
                    "label": f"{name} colour: k_min, smallest principal stiffness (linear)",
                    "colors": _colorbar(COLORMAPS[name]),
                    "min": format_value(lo, "N/m"), "max": format_value(hi, "N/m")})
                data["toggles"].append({"label": f"{name} ellipsoid",
                                        "path": ["meshcat", STIFFNESS_NODE, name]})
            if len(st.ellipsoids) == 2:
                enh, conv = st.ellipsoids["enhanced"].values, st.ellipsoids["conventional"].values
                with np.errstate(invalid="ignore", divide="ignore"):
                    rel = np.abs(enh - conv) / np.abs(conv)
                rel = rel[np.isfinite(rel)]
                data["lines"].append(
                    "enhanced vs conventional: principal values differ by up to "
                    f"{format_value(100 * float(np.max(rel, initial=0.0)))} % (K_C, the load's "
                    "complementary stiffness)")
            unit = "N/m" if self.quantity == "stiffness" else "m/N"
            data["notes"].append(
                f"radius = {format_value(st.scale, 'm')} per {unit} of principal value "
                f"(axis i along eigenvector i; {format_value(self.size, 'm')} = "
                f"{format_value(self.size / st.scale, unit)}); axes 1, 2, 3 red, green, blue")
            if st.rotational is not None:
                block = st.rotational
                data["legend"].append({
                    "color": _hex([int(ROTATIONAL_COLOR >> s & 255) / 255 for s in (16, 8, 0)]),
                    "text": f"rotational block of the 6x6 {block.formulation} {self.quantity} "
                            f"(hidden at first; own scale, largest radius "
                            f"{format_value(self.size, 'm')}): principal values "
                            f"[{', '.join(format_value(v) for v in block.values)}] "
                            f"{block.units}"})
                data["toggles"].append({"label": f"rotational {self.quantity} ({block.units})",
                                        "path": ["meshcat", ROTATIONAL_NODE]})
                data["labels"].append({"text": f"rotational ({block.units})", "kind": "name",
                                       "anchor": ["meshcat", ROTATIONAL_NODE, "label"],
                                       "center": ["meshcat", ROTATIONAL_NODE, "surface"]})
            if self.arrow_scale:
                data["legend"].append({
                    "color": _hex([int(FORCE_COLOR >> s & 255) / 255 for s in (16, 8, 0)]),
                    "text": f"load arrow: 1 m = {format_value(1 / self.arrow_scale, 'N')}"})
            if st.deflection is not None:
                data["legend"].append({
                    "color": _hex(DEFLECTED_RGBA),
                    "text": f"deflected robot (exact equilibrium), deflection x "
                            f"{format_value(st.exaggeration)}: target moves "
                            f"{format_value(1e3 * float(np.linalg.norm(st.deflection)), 'mm')} "
                            f"(red line, also x {format_value(st.exaggeration)})"})
            if st.note:
                data["notes"].append(st.note)
            data["toggles"].append({"label": "deflected robot", "path": ["meshcat",
                                                                         DEFLECTED_NODE]})
        if self.field_state is not None:
            fs = self.field_state
            data["colorbars"].append({
                "label": f"field ({len(fs.positions)} samples, {fs.ellipsoids[0].formulation}"
                         f" {self.quantity}, radius {format_value(fs.scale, 'm')} per unit): "
                         "k_min (N/m)",
                "colors": _colorbar(COLORMAPS["field"]),
                "min": format_value(fs.color_range[0], "N/m"),
                "max": format_value(fs.color_range[1], "N/m")})
            data["toggles"].append({"label": "ellipsoid field", "path": ["meshcat", FIELD_NODE]})
            if fs.skipped:
                data["notes"].append(f"field: {fs.skipped} samples skipped (loop cannot close "
                                     "or singular stiffness)")
        if self._frames is not None:
            data["frames"] = self._frames
            data["notes"].append("animation: meshcat's Open Controls > Animations (play, time); "
                                 "the legend's values are those of frame 0, the animation "
                                 "frame line gives the frame shown")
        if self.server is not None and st is not None:
            data["controls"] = self._controls_spec()
        data["camera"] = self._camera_spec()
        return data

    def _camera_spec(self) -> dict:
        """Camera looking at the robot, its ellipsoids and the field, from beside the target."""
        model, data = self.robot.model, self.robot.data
        st = self.state
        q = st.q if st is not None else pin.neutral(model)
        pin.forwardKinematics(model, data, q)
        points = [data.oMi[j].translation.copy() for j in range(model.njoints)]
        target = points[-1]
        if st is not None:
            target = st.position
            for name, c in st.centers.items():
                r = float(np.max(st.radii[name]))
                points += [c - r, c + r]
        if self.field_state is not None:
            points += list(self.field_state.positions)
        points = np.array(points)
        lo, hi = points.min(axis=0), points.max(axis=0)
        center = 0.5 * (lo + hi)
        extent = max(0.5 * float(np.linalg.norm(hi - lo)), 0.3)
        radial = np.array([target[0], target[1], 0.0])
        radial = radial / np.linalg.norm(radial) if np.linalg.norm(radial) > 1e-6 else \
            np.array([1.0, 0.0, 0.0])
        side = self._side_direction(radial)
        view = radial - side
        view = np.array([view[0], view[1], 0.0]) / np.linalg.norm(view)
        view = np.cos(0.45) * view + np.array([0.0, 0.0, np.sin(0.45)])
        distance = 1.5 * extent / np.tan(np.deg2rad(37.5))
        # shift the scene right of the legend (top left of the page)
        right = np.cross(-view, [0.0, 0.0, 1.0])
        center = center - 0.45 * extent * right / max(np.linalg.norm(right), 1e-9)
        return {"target": [float(v) for v in center],
                "position": [float(v) for v in center + distance * view]}

    def _display_coords(self, coords: np.ndarray) -> np.ndarray:
        out = np.array(coords, dtype=float)
        for i, name in enumerate(self.robot.coordinate_joints):
            if not self._prismatic(name):
                out[i] = np.rad2deg(out[i])
        return out

    def _prismatic(self, joint: str) -> bool:
        return self.robot.is_prismatic(joint)

    def _controls_spec(self) -> dict:
        st, model = self.state, self.robot.model
        joints = []
        for i, name in enumerate(self.robot.coordinate_joints):
            joint = model.joints[model.getJointId(name)]
            lo, hi = model.lowerPositionLimit[joint.idx_q], model.upperPositionLimit[joint.idx_q]
            if self._prismatic(name):
                lo = lo if np.isfinite(lo) and lo > -10 else -1.0
                hi = hi if np.isfinite(hi) and hi < 10 else 1.0
                joints.append({"name": name, "unit": "m", "to_si": 1.0, "min": lo, "max": hi,
                               "step": (hi - lo) / 1000, "digits": 3, "value": st.coords[i]})
            else:
                lo = np.rad2deg(lo) if joint.nq == 1 and np.isfinite(lo) and lo > -7 else -180.0
                hi = np.rad2deg(hi) if joint.nq == 1 and np.isfinite(hi) and hi < 7 else 180.0
                joints.append({"name": name, "unit": "deg", "to_si": np.pi / 180, "min": lo,
                               "max": hi, "step": 0.1, "digits": 1,
                               "value": float(np.rad2deg(st.coords[i]))})
        force = st.wrench[:3]
        magnitude = float(np.linalg.norm(force))
        if magnitude > 0:
            azimuth = float(np.rad2deg(np.arctan2(force[1], force[0])))
            elevation = float(np.rad2deg(np.arcsin(np.clip(force[2] / magnitude, -1, 1))))
        else:
            azimuth, elevation = 0.0, -90.0
        top = _nice_up(3.0 * magnitude) if magnitude > 0 else 1000.0
        return {"joints": [{k: (float(v) if isinstance(v, (float, np.floating)) else v)
                            for k, v in j.items()} for j in joints],
                "force": {"magnitude": magnitude, "max": max(top, magnitude),
                          "azimuth": azimuth, "elevation": elevation},
                "formulation": self._formulation, "formulations": list(SHOW_FORMULATIONS),
                "quantity": self.quantity, "quantities": list(QUANTITIES)}

    def _send_overlay(self) -> None:
        if self.server is not None:
            self.server.set_overlay(self.overlay())

    # ------------------------------------------------------------------ paths and fields

    def sweep(self, path: Sequence[Sequence[float]] | np.ndarray,
              wrench: Sequence[float] | np.ndarray | None = None,
              formulation: str | None = None, fps: float = 10.0, play: bool = True
              ) -> list[SceneState]:
        """Animate a path through configurations on meshcat's animation timeline.

        Every frame moves the robot, its deflected copy, the load arrow and the ellipsoids
        (axes and radii); the legend's frame line gives the principal values of the frame shown
        (the page's labels name the axes). The scene left outside the animation is frame 0.

        Parameters
        ----------
        path
            (m, n_coordinates) coordinates (rad; m prismatic), one row per frame.
        wrench, formulation
            As in :meth:`show`, for every frame.
        fps
            Frames per second of the timeline.
        play
            Start playing when the page loads (meshcat's Animations panel replays and scrubs).

        Returns
        -------
        list of SceneState
            One per frame.
        """
        mc = _meshcat()
        rows = np.atleast_2d(np.asarray(path, dtype=float))
        if rows.shape[1] != self.robot.n_coordinates or rows.shape[0] < 2:
            raise StiffnessError(
                f"a path needs at least two rows of {self.robot.n_coordinates} coordinates "
                f"({', '.join(self.robot.coordinate_joints)}), got shape {rows.shape}")
        with self._lock:
            first = self.show(rows[0], wrench, formulation)
            states = [first]
            for row in rows[1:]:
                q = self.robot.configuration(row, seed=states[-1].q)
                states.append(self._compute(row, q, first.wrench,
                                            tuple(first.ellipsoids), first.quantity))
            animation = mc.animation.Animation(default_framerate=fps)
            root = self._vis
            for k, st in enumerate(states):
                with animation.at_frame(root, k) as frame:
                    for path_name, pose in st.poses.items():
                        clip = frame[path_name].get_clip()
                        clip.set_property(k, "position", "vector3",
                                          [float(v) for v in pose.position])
                        clip.set_property(k, "quaternion", "quaternion", pose.quaternion())
                        clip.set_property(k, "scale", "vector3", [float(v) for v in pose.scale])
            root.set_animation(animation, play=play, repetitions=1)
            unit = "N/m" if first.quantity == "stiffness" else "m/N"
            self._frames = {"fps": fps, "rows": [
                "coordinates [" + ", ".join(format_value(v) for v in
                                            self._display_coords(st.coords)) + "]; " + "; ".join(
                    f"{n}: [{', '.join(format_value(v) for v in e.values)}] {unit}"
                    for n, e in st.ellipsoids.items()) for st in states]}
            self._send_overlay()
            return states

    def field(self, samples: int | Sequence[Sequence[float]] | np.ndarray = 200,
              wrench: Sequence[float] | np.ndarray | None = None,
              formulation: str = "enhanced", joints: Sequence[str] | None = None,
              seed: int = 0) -> FieldState:
        """Draw an ellipsoid at the target of each of a workspace sample of configurations.

        Parameters
        ----------
        samples
            Number of random configurations (uniform within the joint limits, angles within
            [-180, 180] deg), or an (m, n_coordinates) array of coordinates.
        wrench
            Load at every sample (default: as :meth:`show`).
        formulation
            ``enhanced`` or ``conventional``.
        joints
            Coordinates varied by random samples (default all); the others keep the current
            (or default) values.
        seed
            Random seed.

        Returns
        -------
        FieldState
            Kept samples, their ellipsoids and k_min (N/m, the colour's quantity: viridis on
            the stated range).
        """
        if formulation not in FORMULATIONS:
            raise UnknownNameError(f"formulation must be one of {', '.join(FORMULATIONS)}, "
                                   f"got {formulation!r}", name=formulation,
                                   choices=FORMULATIONS)
        robot = self.robot
        with self._lock:
            base, q_base = self._configuration(None)
            load = self._load(wrench, q_base)
            if isinstance(samples, (int, np.integer)):
                rows = self._random_coordinates(int(samples), base, joints, seed)
            else:
                rows = np.atleast_2d(np.asarray(samples, dtype=float))
            kept, positions, ells = [], [], []
            for row in rows:
                try:
                    q = robot.configuration(row, seed=q_base)
                    target, e = self.ellipsoids(q, load, (formulation,))
                except StiffnessError:
                    continue
                kept.append(row)
                positions.append(target.position.copy())
                ells.append(e[formulation])
            if not ells:
                raise StiffnessError("no sample of the field could be evaluated (the loops "
                                     "cannot close, or every tangent stiffness is singular)")
            positions_a = np.array(positions)
            kmin = np.array([e.min_stiffness for e in ells])
            finite = kmin[np.isfinite(kmin)]
            lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
            if hi <= lo:
                hi = lo + max(abs(lo), 1.0)
            largest = np.array([np.max(np.abs(e.values[np.isfinite(e.values)]), initial=0.0)
                                for e in ells])
            spacing = self._spacing(positions_a)
            scale = 0.45 * spacing / max(float(np.median(largest)), 1e-300)
            mg = _meshcat().geometry
            self._vis[FIELD_NODE].delete()
            for i, (p, e) in enumerate(zip(positions_a, ells, strict=True)):
                rgb = _color_of(COLORMAPS["field"], (kmin[i] - lo) / (hi - lo))
                node = self._vis[f"{FIELD_NODE}/e{i:04d}"]
                node.set_object(mg.Sphere(1.0), mg.MeshLambertMaterial(color=_rgb_int(rgb)))
                radii = np.minimum(self._radii(e, scale), 2.0 * spacing)
                node.set_transform(ellipsoid_transform(p, e.directions, radii))
            self.field_state = FieldState(np.array(kept), positions_a, ells, kmin, scale,
                                          len(rows) - len(kept), (lo, hi))
            if self.state is not None and len(positions_a):
                self._draw_floor(self.state, positions_a)  # under the field too
            self._send_overlay()
            return self.field_state

    def _random_coordinates(self, n: int, base: np.ndarray, joints: Sequence[str] | None,
                            seed: int) -> np.ndarray:
        robot, model = self.robot, self.robot.model
        names = list(robot.coordinate_joints) if joints is None else list(joints)
        unknown = [j for j in names if j not in robot.coordinate_joints]
        if unknown:
            raise UnknownJointError(f"{', '.join(unknown)} are not coordinates of {robot.name}; "
                                    f"coordinates: {', '.join(robot.coordinate_joints)}",
                                    name=unknown[0], choices=robot.coordinate_joints)
        rng = np.random.default_rng(seed)
        rows = np.tile(base, (n, 1))
        for name in names:
            i = robot.coordinate_joints.index(name)
            joint = model.joints[model.getJointId(name)]
            lo, hi = model.lowerPositionLimit[joint.idx_q], model.upperPositionLimit[joint.idx_q]
            bound = 1.0 if self._prismatic(name) else np.pi
            lo = lo if joint.nq == 1 and np.isfinite(lo) and lo > -bound else -bound
            hi = hi if joint.nq == 1 and np.isfinite(hi) and hi < bound else bound
            rows[:, i] = rng.uniform(lo, hi, n)
        return rows

    @staticmethod
    def _spacing(points: np.ndarray) -> float:
        if len(points) < 2:
            return 0.1
        d = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=-1)
        np.fill_diagonal(d, np.inf)
        nearest = d.min(axis=1)
        return max(float(np.median(nearest)), 1e-3)

    # ------------------------------------------------------------------ live browsing

    def apply_control(self, control: dict) -> SceneState:
        """Apply one control state sent by the live page (coordinates, force, formulation).

        ``control`` holds ``coords`` (rad/m), ``force`` (N, base axes; the moment is kept),
        ``formulation`` and ``quantity``, any of them optional.
        """
        wrench = None
        if "force" in control:
            current = self._load(None)
            wrench = np.concatenate([np.asarray(control["force"], dtype=float), current[3:]])
        quantity = control.get("quantity")
        return self.show(control.get("coords"), wrench, control.get("formulation"),
                         quantity=quantity)

    def poll(self) -> int:
        """Apply the latest control change of the live page, if any; the number received."""
        if self.server is None:
            return 0
        events = self.server.events()
        if events:
            try:
                self.apply_control(events[-1])
            except StiffnessError as exc:
                self._error = f"not shown: {exc}"
                self._send_overlay()
        return len(events)

    def browse(self, duration: float | None = None, interval: float = 0.1,
               background: bool = False) -> None:
        """Follow the live page's controls (joints, load, formulation, quantity).

        Parameters
        ----------
        duration
            Seconds to browse (``None``: until Ctrl-C, or :meth:`close` in the background).
        interval
            Polling period (s).
        background
            Run in a daemon thread and return at once (for notebooks).
        """
        if self.server is None:
            raise StiffnessError("browse() needs a live viewer: StiffnessViewer(..., live=True)")
        if background:
            self._stop_browsing.clear()
            self._browser_thread = threading.Thread(
                target=self.browse, kwargs={"duration": duration, "interval": interval},
                daemon=True)
            self._browser_thread.start()
            return
        deadline = None if duration is None else time.monotonic() + duration
        while not self._stop_browsing.is_set():
            if deadline is not None and time.monotonic() >= deadline:
                return
            try:
                self.poll()
            except StiffnessError:
                if self.server is None or not self.server.running:
                    return
            self._stop_browsing.wait(interval)

    def wait_for_browser(self, timeout: float = 10.0) -> bool:
        """Wait at most ``timeout`` s for a browser on the live page; whether one came."""
        return self.server.wait_for_browser(timeout) if self.server is not None else False

    # ------------------------------------------------------------------ output

    def html(self, title: str | None = None) -> str:
        """The scene as a self-contained static HTML page (opens offline)."""
        with self._lock:
            title = title or f"{display_name(self.robot)} stiffness ({self.quantity})"
            return render_page(self._window.scene.commands(), self.overlay(), title)

    def export(self, path: str | os.PathLike, title: str | None = None) -> Path:
        """Write :meth:`html` to ``path``; returns the path."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(path, self.html(title))
        return path

    def commands(self) -> list[dict]:
        """The scene's meshcat commands, decoded, in replay order."""
        unpack = _meshcat().msgpack.unpackb
        return [unpack(c) for c in self._window.scene.commands()]

    def _repr_html_(self) -> str:
        """Notebook display: the live page in an iframe, or the static page in one."""
        if self.url is not None:
            return (f'<iframe src="{html_lib.escape(self.url)}" style="width: 100%; height: '
                    '520px; border: none"></iframe>')
        return (f'<iframe srcdoc="{html_lib.escape(self.html(), quote=True)}" style="width: '
                '100%; height: 520px; border: none"></iframe>')

    def close(self) -> None:
        """Stop browsing and the live server (idempotent)."""
        self._stop_browsing.set()
        if self._browser_thread is not None:
            self._browser_thread.join(timeout=2.0)
            self._browser_thread = None
        if self.server is not None:
            self.server.close()

    def __enter__(self) -> StiffnessViewer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

