"""The viewer: :class:`StiffnessViewer`; what it drew is in :mod:`stiffness.viewer.states`.

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
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from stiffness.errors import StiffnessError, UnknownNameError
from stiffness.files import atomic_write
from stiffness.mechanics.defaults import assembly_coordinates, default_load, joint_stiffnesses
from stiffness.mechanics.equilibrium import deflected_configuration, solve_equilibrium
from stiffness.mechanics.formulation import (
    FORMULATIONS,
    as_wrench,
    tangent_joint_stiffness,
    target_state,
)
from stiffness.robot.robot import Robot
from stiffness.viewer.deps import meshcat_modules, pinocchio_meshcat_visualizer
from stiffness.viewer.drawing import draw_floor, style_objects
from stiffness.viewer.ellipsoid import (
    QUANTITIES,
    PrincipalEllipsoid,
    ellipsoid_transform,
    principal_ellipsoid,
    rotational_block,
)
from stiffness.viewer.geometry import Pose, missing_mesh_notes, segment_pose
from stiffness.viewer.layout import (
    arrow_poses,
    camera_spec,
    ellipsoid_radii,
    floor_layout,
    random_coordinates,
    rotational_pose,
    sample_spacing,
    side_direction,
)
from stiffness.viewer.legend import controls_spec, field_legend, path_frame_rows, scene_legend
from stiffness.viewer.page import render_page
from stiffness.viewer.server import DEFAULT_TIMEOUT, LOOPBACK, LiveServer, RecordingWindow
from stiffness.viewer.states import (
    AXIS_NAMES,
    DEFLECTED_NODE,
    FIELD_CLIP,
    FIELD_NODE,
    ROBOT_NODE,
    ROTATIONAL_NODE,
    SHOW_FORMULATIONS,
    STIFFNESS_NODE,
    FieldState,
    SceneState,
)
from stiffness.viewer.style import (
    COLORMAPS,
    DEFLECTED_RGBA,
    FORCE_COLOR,
    MOMENT_COLOR,
    color_of,
    nice_above,
    nice_below,
    rgb_int,
)


def _load_or_zero(robot: Robot, q: np.ndarray, k_theta: np.ndarray) -> np.ndarray:
    """A shipped robot's default load as a wrench [F (N); M (N.m)], else no load."""
    shipped = default_load(robot, q, k_theta)
    return np.zeros(6) if shipped is None else as_wrench(shipped[0])


class StiffnessViewer:
    """Browse a robot's stiffness in meshcat: ellipsoids, load, deflection, fields, paths.

    Parameters
    ----------
    robot
        The robot (:func:`stiffness.robot.robot.load_robot`).
    k_theta
        Joint stiffness: one finite positive value per compliant joint (N.m/rad; N/m
        prismatic) or their diagonal (n, n) matrix
        (:func:`~stiffness.mechanics.defaults.joint_stiffnesses`, the one check of joint
        springs).
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
        self.k_theta = np.diag(joint_stiffnesses(robot, k_theta))
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
        self._window = RecordingWindow(self.server)
        mc = meshcat_modules()
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
            q = self.robot.configuration(assembly_coordinates(self.robot))
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
        #: The robot's visual geometry when it has meshes to draw, else None (a skeleton).
        self._meshes = visual if visual is not None and visual.ngeoms > 0 else None
        if not getattr(self, "_missing_reported", False):
            for line in missing_mesh_notes(self.robot):
                print(f"stiffness viewer: {line}", file=sys.stderr)
            self._missing_reported = True
        if self._meshes is not None:
            visualizer = pinocchio_meshcat_visualizer()
            self._viz = visualizer(self.robot.model, None, self._meshes)
            self._viz.initViewer(viewer=vis)
            self._viz.loadViewerModel(ROBOT_NODE)
            # the deflected robot reuses these meshes: the page copies them (see page._PAGE_JS)
            self._visual_data = self._meshes.createData()
        else:
            mg = meshcat_modules().geometry
            self._links = self._skeleton_links()
            for root, rgba in ((ROBOT_NODE, (0.55, 0.57, 0.6, 1.0)),
                               (DEFLECTED_NODE, DEFLECTED_RGBA)):
                material = mg.MeshPhongMaterial(color=rgb_int(rgba), opacity=rgba[3])
                for name, _, _ in self._links:
                    vis[f"{root}/visuals/{name}"].set_object(
                        mg.Cylinder(1.0, 0.015 * self.reach), material)
        vis[DEFLECTED_NODE].set_property("visible", False)
        mg = meshcat_modules().geometry
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

    def _configuration(self, coords: Sequence[float] | np.ndarray | None
                       ) -> tuple[np.ndarray, np.ndarray]:
        robot = self.robot
        seed = self.state.q if self.state is not None else None
        if coords is None:
            if self.state is not None:
                return self.state.coords, self.state.q
            coords = assembly_coordinates(robot)
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
            self.exaggeration = nice_below(0.08 * self.reach / moved) if moved > 0 else 1.0
        robot = self.robot
        try:
            if robot.loop.is_open_chain:  # springs on coordinates or on a coupled chain
                shown = deflected_configuration(robot, q, self.exaggeration * eq.dtheta, q)
            else:  # continuation along the coordinates keeps the loops' branch
                dcoords = np.zeros(robot.n_coordinates)
                dcoords[robot.compliant_in_coordinates] = eq.dtheta
                shown = robot.configuration(coords + self.exaggeration * dcoords, seed=q)
        except StiffnessError as exc:
            return eq.dx, None, f"deflected pose x{self.exaggeration:g} not drawable: {exc}"
        return eq.dx, shown, ""

    def _color_range(self, values: list[float]) -> tuple[float, float]:
        if self.color_range is None:
            finite = [v for v in values if np.isfinite(v)]
            top = max(finite, default=1.0)
            self.color_range = (0.0, nice_above(2.0 * top) if top > 0 else 1.0)
        return self.color_range

    # ------------------------------------------------------------------ drawing

    def _robot_poses(self, root: str, q: np.ndarray) -> dict[str, Pose]:
        model, data = self.robot.model, self.robot.data
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        poses = {}
        if self._meshes is not None:
            pin.updateGeometryPlacements(model, data, self._meshes, self._visual_data)
            for i, obj in enumerate(self._meshes.geometryObjects):
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
                poses[f"{root}/visuals/{name}"] = segment_pose(start, end)
        return poses

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
            style_objects(self._vis, state, self._color_range([]), self.reach)
            self._error = None
            self._send_overlay()
            return state

    def _compute(self, coords: np.ndarray, q: np.ndarray, load: np.ndarray,
                 names: Sequence[str], quantity: str) -> SceneState:
        target, ells = self.ellipsoids(q, load, names, quantity)
        scale = self._scale(quantity, list(ells.values()))
        self._color_range([e.min_stiffness for e in ells.values()])
        position = target.position.copy()
        side = side_direction(position)
        radii = {n: ellipsoid_radii(e, scale) for n, e in ells.items()}
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

    def _draw_floor(self, state: SceneState, extra: np.ndarray | None = None) -> None:
        """A floor under the robot (at the first show): a plate at the lowest joint's height
        with a grid of round spacing, spanning the robot, its ellipsoids and ``extra`` points
        (m; a field's targets)."""
        model, data = self.robot.model, self.robot.data
        pin.forwardKinematics(model, data, state.q)
        points = [data.oMi[j].translation.copy() for j in range(model.njoints)]
        points.append(state.position)
        points += [state.centers[n] for n in state.centers]
        z, center, half, spacing = floor_layout(np.array(points), extra, self.reach)
        draw_floor(self._vis, z, center, half, spacing, self.reach)
        self.floor = {"z": z, "center": center.tolist(), "half_size": half,
                      "spacing": spacing}
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
        poses.update(arrow_poses("force", p, force,
                                 arrow_scale * float(np.linalg.norm(force)), self.reach))
        moment_length = 0.2 * self.reach if np.any(moment) else 0.0
        poses.update(arrow_poses("moment", p, moment, moment_length, self.reach))
        end = p if state.deflection is None else p + state.exaggeration * state.deflection
        poses[f"{STIFFNESS_NODE}/deflection"] = segment_pose(p, end)
        hidden = Pose(p, np.eye(3), np.full(3, 1e-9))
        for name in FORMULATIONS:
            base = f"{STIFFNESS_NODE}/{name}"
            if name not in state.ellipsoids:
                for part in ("surface", "axes", "label", "link", *(f"label{a}" for a in
                                                                   AXIS_NAMES)):
                    poses[f"{base}/{part}"] = hidden
                continue
            ell, c, r = state.ellipsoids[name], state.centers[name], state.radii[name]
            pose = Pose(c, ell.directions, r)
            poses[f"{base}/surface"] = pose
            poses[f"{base}/axes"] = pose
            for i, a in enumerate(AXIS_NAMES):  # label anchors: the axis tips
                tip = c + ell.directions[:, i] * r[i]
                poses[f"{base}/label{a}"] = Pose(tip, np.eye(3), np.ones(3))
            below = c - np.array([0.0, 0.0, np.max(r)])
            poses[f"{base}/label"] = Pose(below, np.eye(3), np.ones(3))
            poses[f"{base}/link"] = segment_pose(p, c) if np.linalg.norm(c - p) > 0 else hidden
        if state.rotational is not None:
            pose, radii = rotational_pose(state.rotational, state, self.size)
            poses[f"{ROTATIONAL_NODE}/surface"] = pose
            poses[f"{ROTATIONAL_NODE}/axes"] = pose
            below = pose.position - np.array([0.0, 0.0, float(np.max(radii))])
            poses[f"{ROTATIONAL_NODE}/label"] = Pose(below, np.eye(3), np.ones(3))
            poses[f"{ROTATIONAL_NODE}/link"] = segment_pose(p, pose.position)
        else:
            for part in ("surface", "axes", "label", "link"):
                poses[f"{ROTATIONAL_NODE}/{part}"] = hidden
        return poses

    def _send_poses(self, poses: dict[str, Pose]) -> None:
        for path, pose in poses.items():
            self._vis[path].set_transform(pose.matrix())

    # ------------------------------------------------------------------ legend

    def overlay(self) -> dict:
        """Legend (and live controls) of the current scene, as the page's JSON."""
        robot, st = self.robot, self.state
        data: dict = {"title": f"{robot.title}: {self.quantity} ellipsoids at "
                               f"{robot.target_frame}", "lines": [], "legend": [],
                      "colorbars": [], "toggles": [], "notes": [], "labels": []}
        if self._error:
            data["error"] = self._error
        data["notes"].extend(missing_mesh_notes(robot))
        if st is not None:
            scene_legend(data, robot, st, self.quantity, self._color_range([]), self.size,
                         self.arrow_scale)
        if self.field_state is not None:
            field_legend(data, self.field_state, self.quantity)
        if self._frames is not None:
            data["frames"] = self._frames
            data["notes"].append("animation: meshcat's Open Controls > Animations (play, time); "
                                 "the legend's values are those of frame 0, the animation "
                                 "frame line gives the frame shown")
        if self.server is not None and st is not None:
            data["controls"] = controls_spec(robot, st, self._formulation, self.quantity)
        data["camera"] = camera_spec(robot, st, None if self.field_state is None
                                     else self.field_state.positions)
        return data

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
        mc = meshcat_modules()
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
            self._frames = {"fps": fps, "rows": path_frame_rows(self.robot, states)}
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
            [-180, 180] deg; a closed loop's within 0.5 rad of its reference assembly), or an
            (m, n_coordinates) array of coordinates.
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
                rows = random_coordinates(robot, int(samples), base, joints, seed)
            else:
                rows = np.atleast_2d(np.asarray(samples, dtype=float))
            kept, positions, ells = [], [], []
            for row in rows:
                try:
                    q = robot.configuration(row, seed=q_base)
                    target, at_row = self.ellipsoids(q, load, (formulation,))
                except StiffnessError:
                    continue
                kept.append(row)
                positions.append(target.position.copy())
                ells.append(at_row[formulation])
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
            spacing = sample_spacing(positions_a)
            scale = 0.45 * spacing / max(float(np.median(largest)), 1e-300)
            mg = meshcat_modules().geometry
            self._vis[FIELD_NODE].delete()
            clipped = np.zeros(len(ells), dtype=bool)
            for i, (p, e) in enumerate(zip(positions_a, ells, strict=True)):
                radii = ellipsoid_radii(e, scale)
                clipped[i] = bool(np.any(radii > FIELD_CLIP * spacing))
                rgb = color_of(COLORMAPS["field"], (kmin[i] - lo) / (hi - lo))
                material = mg.MeshLambertMaterial(color=0x9A9A9A, opacity=0.35,
                                                  transparent=True) if clipped[i] else \
                    mg.MeshLambertMaterial(color=rgb_int(rgb))
                node = self._vis[f"{FIELD_NODE}/e{i:04d}"]
                node.set_object(mg.Sphere(1.0), material)
                radii = np.minimum(radii, FIELD_CLIP * spacing)
                node.set_transform(ellipsoid_transform(p, e.directions, radii))
            self.field_state = FieldState(np.array(kept), positions_a, ells, kmin, scale,
                                          len(rows) - len(kept), (lo, hi), clipped)
            if self.state is not None and len(positions_a):
                self._draw_floor(self.state, positions_a)  # under the field too
            self._send_overlay()
            return self.field_state

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
            title = title or f"{self.robot.title} stiffness ({self.quantity})"
            return render_page(self._window.scene.commands(), self.overlay(), title)

    def export(self, path: str | os.PathLike, title: str | None = None) -> Path:
        """Write :meth:`html` to ``path``; returns the path."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(path, self.html(title))
        return path

    def commands(self) -> list[dict]:
        """The scene's meshcat commands, decoded, in replay order."""
        unpack = meshcat_modules().msgpack.unpackb
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

