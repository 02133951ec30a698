"""Stiffness ellipsoids in the browser: meshcat scenes of a robot, its load and its stiffness.

:class:`StiffnessViewer` draws, in `meshcat <https://github.com/meshcat-dev/meshcat-python>`_
(through Pinocchio's ``MeshcatVisualizer`` for the robot's meshes):

* the robot at a configuration, and a translucent red copy of it at the *exact* equilibrium
  under the load (:func:`stiffness.equilibrium.solve_equilibrium`) with the deflection
  multiplied by a stated factor (``exaggeration``);
* the load arrow at the target (force; a second arrow for a moment, if any);
* the translational stiffness ellipsoid (3x3, N/m) or compliance ellipsoid (m/N) at the target,
  for the ``enhanced`` (K_theta - K_C, A&S eq. 10) and ``conventional`` (K_theta, eq. 8)
  formulations: the enhanced one at the target, the conventional one beside it (linked to the
  target by a grey line), with their principal axes drawn and labelled with value and unit;
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
load) is drawn by its magnitude and labelled with its sign; an unbounded principal stiffness
(the compliance is singular) is drawn clipped and labelled ``inf``. The scale, the colour range
and the exaggeration are fixed by the first :meth:`StiffnessViewer.show` (or given), so that
browsing compares like with like.

Colour. Each ellipsoid is coloured by its smallest principal stiffness ``k_min`` (N/m) on a
stated linear range: oranges for the enhanced formulation, blues for the conventional one,
viridis for the field.

Server. The live viewer starts its own server process (meshcat's viewer page, websocket and
ZeroMQ command socket) bound to 127.0.0.1 by default, on free ports; every request to it has a
timeout (nothing waits for a browser forever), and the process is stopped by
:meth:`StiffnessViewer.close`, by leaving a ``with`` block, at interpreter exit, and by itself
when its parent process dies. meshcat 0.3.2's own server binds its web port on every interface
and its ``wait`` can leave its command socket stuck; neither is used.

Units: SI (m, N, rad; N/m, m/N; N.m/rad for joints).
"""

from __future__ import annotations

import atexit
import base64
import contextlib
import functools
import html as html_lib
import json
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
import uuid
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from stiffness.defaults import default_coordinates, default_load
from stiffness.equilibrium import solve_equilibrium
from stiffness.errors import SingularConfigurationError, StiffnessError
from stiffness.files import atomic_write
from stiffness.formulation import (
    FORMULATIONS,
    as_wrench,
    cartesian_stiffness,
    compliance,
    joint_stiffness,
    tangent_joint_stiffness,
    target_state,
)
from stiffness.robot import Robot, load_robot

#: Address the live server binds by default (loopback only).
LOOPBACK = "127.0.0.1"
#: What the ellipsoids can show.
QUANTITIES = ("stiffness", "compliance")
#: Formulation choices of :meth:`StiffnessViewer.show` (``both``: side by side).
SHOW_FORMULATIONS = ("both", *FORMULATIONS)
#: Colour maps (matplotlib names) of the ellipsoids, by formulation, and of the field.
COLORMAPS = {"enhanced": "Oranges", "conventional": "Blues", "field": "viridis"}
#: Legend text of each formulation.
FORMULATION_LABELS = {
    "enhanced": "enhanced, K_theta - K_C (A&S eq. 10)",
    "conventional": "conventional, K_theta (A&S eq. 8)",
}
#: Colour (RGBA, 0..1) of the deflected robot.
DEFLECTED_RGBA = (0.85, 0.1, 0.1, 0.35)
#: Colours of the force and moment arrows (0xRRGGBB).
FORCE_COLOR = 0x2CA02C
MOMENT_COLOR = 0x9467BD
#: Scene paths (below meshcat's root ``/meshcat``).
ROBOT_NODE = "robot"
DEFLECTED_NODE = "deflected"
STIFFNESS_NODE = "stiffness"
FIELD_NODE = "field"

#: Seconds the client waits for any answer of the live server.
DEFAULT_TIMEOUT = 10.0
#: Radius drawn for an unbounded principal value, in multiples of the largest finite radius.
_UNBOUNDED_RADIUS = 3.0
_AXIS_NAMES = ("1", "2", "3")


# ------------------------------------------------------------------------------------- imports


@functools.cache
def _meshcat() -> Any:
    """meshcat and its submodules, imported with its zmq DeprecationWarning silenced locally."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        import meshcat
        import meshcat.animation
        import meshcat.geometry
        import umsgpack

    class _Modules:
        pass

    modules = _Modules()
    modules.meshcat = meshcat
    modules.geometry = meshcat.geometry
    modules.animation = meshcat.animation
    modules.msgpack = umsgpack
    modules.viewer_js = Path(meshcat.__file__).parent / "viewer" / "dist" / "main.min.js"
    return modules


def _coordinates_or_zero(robot: Robot) -> np.ndarray:
    """A shipped robot's default coordinates, else zeros (rad, m)."""
    shipped = default_coordinates(robot)
    return np.zeros(robot.n_coordinates) if shipped is None else shipped


def _load_or_zero(robot: Robot, q: np.ndarray, k_theta: np.ndarray) -> np.ndarray:
    """A shipped robot's default load as a wrench [F (N); M (N.m)], else no load."""
    shipped = default_load(robot, q, k_theta)
    return np.zeros(6) if shipped is None else as_wrench(shipped[0])


def _pinocchio_meshcat_visualizer() -> type:
    _meshcat()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        from pinocchio.visualize import MeshcatVisualizer
    return MeshcatVisualizer


# ---------------------------------------------------------------------------- ellipsoid algebra


@dataclass
class PrincipalEllipsoid:
    """Eigen-decomposition of one formulation's translational stiffness or compliance.

    Attributes
    ----------
    formulation
        ``enhanced`` or ``conventional``.
    quantity
        ``stiffness`` (``matrix`` is K_X, N/m) or ``compliance`` (``matrix`` is C, m/N).
    matrix
        (3, 3) drawn matrix, base axes at the target.
    values
        Eigenvalues of the symmetric part of ``matrix``, ascending (N/m or m/N); ``inf`` for an
        unbounded stiffness.
    directions
        (3, 3) unit eigenvectors (columns), right-handed (``det = +1``).
    compliance
        (3, 3) translational compliance C (m/N).
    stiffness
        (3, 3) K_X = C^-1 (N/m), or ``None`` where C is singular.
    principal_stiffness
        Principal stiffnesses (N/m) along ``directions``: ``values`` for a stiffness, their
        inverses for a compliance (``inf`` where a compliance vanishes).
    """

    formulation: str
    quantity: str
    matrix: np.ndarray
    values: np.ndarray
    directions: np.ndarray
    compliance: np.ndarray
    stiffness: np.ndarray | None
    principal_stiffness: np.ndarray

    @property
    def units(self) -> str:
        """Unit of ``values``."""
        return "N/m" if self.quantity == "stiffness" else "m/N"

    @property
    def min_stiffness(self) -> float:
        """Smallest principal stiffness (N/m); negative when K_X is indefinite."""
        return float(np.min(self.principal_stiffness))


def _right_handed(vectors: np.ndarray) -> np.ndarray:
    vectors = np.array(vectors, dtype=float)
    if np.linalg.det(vectors) < 0.0:
        vectors[:, -1] *= -1.0
    return vectors


def principal_ellipsoid(jacobian: np.ndarray, tangent_stiffness: np.ndarray, formulation: str,
                        quantity: str = "stiffness") -> PrincipalEllipsoid:
    """Principal values and axes of the translational stiffness (or compliance) at the target.

    Parameters
    ----------
    jacobian
        (3, n) translational target Jacobian (m/rad), base axes.
    tangent_stiffness
        (n, n) ``K_theta - K_C`` (enhanced) or ``K_theta`` (conventional), N.m/rad.
    formulation
        Name stored with the result.
    quantity
        ``stiffness`` (draw K_X, N/m) or ``compliance`` (draw C, m/N).

    Raises
    ------
    SingularConfigurationError
        If the tangent joint stiffness is singular (the buckling limit).
    """
    if quantity not in QUANTITIES:
        raise StiffnessError(f"quantity must be one of {QUANTITIES}, got {quantity!r}")
    c = compliance(jacobian, tangent_stiffness)
    c = 0.5 * (c + c.T)
    try:
        k = cartesian_stiffness(c)
        k = 0.5 * (k + k.T)
    except SingularConfigurationError:
        k = None
    if quantity == "stiffness" and k is not None:
        values, vectors = np.linalg.eigh(k)
        principal_k = values.copy()
        matrix = k
    else:
        c_values, vectors = np.linalg.eigh(c)
        tol = 1e-12 * max(float(np.max(np.abs(c_values))), 1e-300)
        with np.errstate(divide="ignore"):
            principal_k = np.where(np.abs(c_values) > tol, 1.0 / c_values, np.inf)
        if quantity == "compliance":
            values, matrix = c_values, c
        else:  # singular compliance: stiffness unbounded along its null directions
            order = np.argsort(principal_k)
            values, vectors, principal_k = principal_k[order], vectors[:, order], principal_k[order]
            matrix = c
    vectors = _right_handed(vectors)
    return PrincipalEllipsoid(formulation, quantity, matrix, values, vectors, c, k, principal_k)


def ellipsoid_transform(center: np.ndarray, directions: np.ndarray, radii: np.ndarray
                        ) -> np.ndarray:
    """4x4 transform of the unit sphere onto an ellipsoid: ``[directions diag(radii), center]``.

    ``directions`` must be a rotation (unit columns, ``det = +1``); ``radii`` in m.
    """
    t = np.eye(4)
    t[:3, :3] = np.asarray(directions, dtype=float) * np.asarray(radii, dtype=float)[None, :]
    t[:3, 3] = center
    return t


# ------------------------------------------------------------------------------ formatting, maps


def format_value(value: float, unit: str = "") -> str:
    """Three significant digits, compact exponent (``1.41e6 N/m``); ``inf`` for unbounded."""
    if not np.isfinite(value):
        text = "inf" if value > 0 else "-inf"
    else:
        text = f"{value:.3g}"
        if "e" in text:
            mantissa, exponent = text.split("e")
            text = f"{mantissa}e{int(exponent)}"
    return f"{text} {unit}".strip()


def _nice(value: float) -> float:
    """Largest of 1, 2, 5 x 10^k not above ``value`` (> 0)."""
    exponent = np.floor(np.log10(value))
    base = 10.0 ** exponent
    for step in (5.0, 2.0, 1.0):
        if step * base <= value * (1 + 1e-12):
            return float(step * base)
    return float(base)


def _nice_up(value: float) -> float:
    """Smallest of 1, 2, 5 x 10^k not below ``value`` (> 0)."""
    exponent = np.floor(np.log10(value))
    base = 10.0 ** exponent
    for step in (1.0, 2.0, 5.0, 10.0):
        if step * base >= value * (1 - 1e-12):
            return float(step * base)
    return float(10.0 * base)


def _hex(rgb: Sequence[float]) -> str:
    return "#" + "".join(f"{int(round(255 * float(c))):02x}" for c in rgb[:3])


def _rgb_int(rgb: Sequence[float]) -> int:
    return int(_hex(rgb)[1:], 16)


def _colormap(name: str) -> Any:
    from matplotlib import colormaps

    return colormaps[name]


def _color_of(name: str, fraction: float) -> tuple[float, float, float]:
    """Colour of ``fraction`` in [0, 1] on a map; sequential maps skip their whitish end."""
    fraction = float(np.clip(fraction, 0.0, 1.0))
    if name != "viridis":
        fraction = 0.35 + 0.6 * fraction
    r, g, b, _ = _colormap(name)(fraction)
    return (r, g, b)


def _colorbar(name: str, n: int = 9) -> list[str]:
    return [_hex(_color_of(name, f)) for f in np.linspace(0.0, 1.0, n)]


# ------------------------------------------------------------------------------ scene geometry


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


def _rotation_y_to(direction: np.ndarray) -> np.ndarray:
    """A rotation taking +y (three.js cylinders' axis) to the unit vector ``direction``."""
    d = np.asarray(direction, dtype=float)
    d = d / np.linalg.norm(d)
    helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    x = np.cross(d, helper)
    x /= np.linalg.norm(x)
    z = np.cross(x, d)
    return np.column_stack([x, d, z])


def _segment(start: np.ndarray, end: np.ndarray) -> Pose:
    """Pose of a unit-height, y-axis cylinder stretched from ``start`` to ``end``."""
    delta = np.asarray(end, dtype=float) - np.asarray(start, dtype=float)
    length = float(np.linalg.norm(delta))
    rotation = _rotation_y_to(delta) if length > 1e-12 else np.eye(3)
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


def _text_object(text: str, height: float) -> Any:
    """A meshcat Object wrapping :class:`TextSprite` (accepted by ``Visualizer.set_object``)."""
    mg = _meshcat().geometry
    sprite = TextSprite(text, height)

    class _Sprite(mg.Object):
        def __init__(self) -> None:
            self.uuid = str(uuid.uuid4())

        def lower(self) -> dict:
            return sprite.lower()

    return _Sprite()


# ----------------------------------------------------------------------- recorded scene, pages


class SceneStore:
    """The scene as a browser would hold it: meshcat commands, latest per node and kind.

    Replayed in a deterministic order (a node's object, its children, its properties, its
    transform; the animation last), for static pages and for browsers joining a live server.
    Commands are msgpack-packed bytes exactly as meshcat sends them.
    """

    def __init__(self) -> None:
        self.root: dict = self._node()
        self.animation: bytes | None = None

    @staticmethod
    def _node() -> dict:
        return {"object": None, "properties": {}, "transform": None, "children": {}}

    def _find(self, path: str, create: bool = True) -> dict | None:
        node = self.root
        for name in [p for p in path.split("/") if p]:
            if name not in node["children"]:
                if not create:
                    return None
                node["children"][name] = self._node()
            node = node["children"][name]
        return node

    def apply(self, kind: str, path: str, packed: bytes, key: str | None = None) -> None:
        """Record one command (``kind`` = meshcat command type, ``key`` = property name)."""
        if kind == "set_animation":
            self.animation = packed
            return
        if kind == "delete":
            names = [p for p in path.split("/") if p]
            if not names:
                self.root, self.animation = self._node(), None
                return
            parent = self._find("/".join(names[:-1]), create=False)
            if parent is not None:
                parent["children"].pop(names[-1], None)
            return
        node = self._find(path)
        if kind == "set_object":
            node["object"] = packed
        elif kind == "set_transform":
            node["transform"] = packed
        elif kind == "set_property":
            node["properties"][key or ""] = packed

    def commands(self) -> list[bytes]:
        """Every stored command in replay order."""
        out: list[bytes] = []

        def walk(node: dict) -> None:
            if node["object"] is not None:
                out.append(node["object"])
            for child in node["children"].values():
                walk(child)
            out.extend(node["properties"].values())
            if node["transform"] is not None:
                out.append(node["transform"])

        walk(self.root)
        if self.animation is not None:
            out.append(self.animation)
        return out


_PAGE_CSS = """
body { margin: 0; font: 12px/1.3 sans-serif; overflow: hidden; }
#meshcat-pane { width: 100vw; height: 100vh; overflow: hidden; }
#stiffness-overlay { position: absolute; left: 8px; top: 8px; max-width: 360px;
  max-height: calc(100vh - 16px); overflow: auto; background: rgba(255,255,255,0.9);
  border-radius: 6px; padding: 6px 10px; box-shadow: 0 1px 4px rgba(0,0,0,0.3); z-index: 5; }
#stiffness-overlay h1 { font-size: 13px; margin: 2px 0 4px; cursor: pointer; }
#stiffness-overlay.folded > :not(h1) { display: none; }
#stiffness-overlay .swatch { display: inline-block; width: 12px; height: 12px;
  margin-right: 5px; vertical-align: -2px; border: 1px solid #555; }
#stiffness-overlay .bar { height: 10px; border: 1px solid #555; margin: 2px 0; }
#stiffness-overlay .ends { display: flex; justify-content: space-between; font-size: 11px; }
#stiffness-overlay .note { color: #444; font-size: 12px; }
#stiffness-overlay .error { color: #b00; font-weight: bold; }
#stiffness-overlay fieldset { border: 1px solid #bbb; margin: 5px 0; padding: 3px 6px; }
#stiffness-overlay label.row { display: flex; gap: 6px; align-items: center; }
#stiffness-overlay label.row span.name { min-width: 92px; }
#stiffness-overlay label.row input[type=range] { flex: 1; }
#stiffness-overlay label.row span.value { min-width: 64px; text-align: right; }
"""

# The page's script: replays the embedded commands (static page) or the websocket's (live
# page), renders the legend from the overlay JSON, and in the live page sends the controls'
# state back to the server.
_PAGE_JS = r"""
(function () {
  "use strict";
  var GHOST = JSON.parse(document.getElementById("stiffness-ghost").textContent);
  var viewer = new MeshCat.Viewer(document.getElementById("meshcat-pane"));
  window.viewer = viewer;
  var overlay = document.getElementById("stiffness-overlay");
  var live = document.body.getAttribute("data-live") === "true";
  var socket = null, controlsBuilt = null, received = 0, frames = null;
  function bytes(b64) {
    var s = atob(b64), a = new Uint8Array(s.length);
    for (var i = 0; i < s.length; i++) { a[i] = s.charCodeAt(i); }
    return a;
  }
  function el(tag, attrs, text) {
    var e = document.createElement(tag);
    Object.keys(attrs || {}).forEach(function (k) { e.setAttribute(k, attrs[k]); });
    if (text !== undefined) { e.textContent = text; }
    return e;
  }
  function node(path) {
    var n = viewer.scene_tree;
    for (var i = 0; i < path.length; i++) {
      n = n.children[path[i]];
      if (n === undefined) { return null; }
    }
    return n;
  }
  function send(state) {
    if (socket && socket.readyState === 1) {
      socket.send(JSON.stringify({type: "control", state: state}));
    }
  }
  function buildControls(spec, box) {
    var fs = el("fieldset"); fs.appendChild(el("legend", {}, "browse (live)"));
    var inputs = {joints: []}, timer = null;
    function row(name, min, max, step, value, fmt) {
      var lab = el("label", {"class": "row"}); lab.appendChild(el("span", {"class": "name"}, name));
      var inp = el("input", {type: "range", min: min, max: max, step: step});
      inp.value = value;
      var out = el("span", {"class": "value"}, fmt(value));
      inp.addEventListener("input", function () { out.textContent = fmt(+inp.value); changed(); });
      lab.appendChild(inp); lab.appendChild(out); fs.appendChild(lab);
      inp.fmt = fmt; inp.out = out;
      return inp;
    }
    function state() {
      var az = +inputs.azimuth.value * Math.PI / 180, el_ = +inputs.elevation.value * Math.PI / 180;
      var m = +inputs.magnitude.value;
      return {
        coords: inputs.joints.map(function (j, i) { return +j.value * spec.joints[i].to_si; }),
        force: [m * Math.cos(el_) * Math.cos(az), m * Math.cos(el_) * Math.sin(az),
                m * Math.sin(el_)],
        formulation: inputs.formulation.value, quantity: inputs.quantity.value
      };
    }
    function changed() {
      if (timer) { clearTimeout(timer); }
      timer = setTimeout(function () { send(state()); }, 60);
    }
    spec.joints.forEach(function (j) {
      inputs.joints.push(row(j.name, j.min, j.max, j.step, j.value,
        function (v) { return v.toFixed(j.digits) + " " + j.unit; }));
    });
    inputs.magnitude = row("|F| (N)", 0, spec.force.max, spec.force.max / 200, spec.force.magnitude,
      function (v) { return v.toFixed(1) + " N"; });
    inputs.azimuth = row("F azimuth", -180, 180, 1, spec.force.azimuth,
      function (v) { return v.toFixed(0) + " deg"; });
    inputs.elevation = row("F elevation", -90, 90, 1, spec.force.elevation,
      function (v) { return v.toFixed(0) + " deg"; });
    [["formulation", spec.formulations, spec.formulation],
     ["quantity", spec.quantities, spec.quantity]].forEach(function (s) {
        var lab = el("label", {"class": "row"});
        lab.appendChild(el("span", {"class": "name"}, s[0]));
        var sel = el("select");
        s[1].forEach(function (o) { var opt = el("option", {value: o}, o); sel.appendChild(opt); });
        sel.value = s[2]; sel.addEventListener("change", changed);
        lab.appendChild(sel); fs.appendChild(lab); inputs[s[0]] = sel;
      });
    box.appendChild(fs);
    return {fieldset: fs, inputs: inputs};
  }
  function updateControls(spec) {
    var inputs = controlsBuilt.inputs, active = document.activeElement;
    function set(inp, v) {
      if (inp === active) { return; }
      inp.value = v;
      if (inp.out) { inp.out.textContent = inp.fmt(+v); }
    }
    spec.joints.forEach(function (j, i) { set(inputs.joints[i], j.value); });
    set(inputs.magnitude, spec.force.magnitude); set(inputs.azimuth, spec.force.azimuth);
    set(inputs.elevation, spec.force.elevation);
    set(inputs.formulation, spec.formulation); set(inputs.quantity, spec.quantity);
  }
  function render(data) {
    if (!data) { return; }
    var keep = controlsBuilt ? controlsBuilt.fieldset : null;
    overlay.textContent = "";
    var h1 = el("h1", {title: "click to fold or unfold the legend"}, data.title || "");
    h1.addEventListener("click", function () { overlay.classList.toggle("folded"); });
    overlay.appendChild(h1);
    if (data.error) { overlay.appendChild(el("div", {"class": "error"}, data.error)); }
    (data.lines || []).forEach(function (t) { overlay.appendChild(el("div", {}, t)); });
    if (live && data.controls) {
      if (keep) { overlay.appendChild(keep); updateControls(data.controls); }
      else { controlsBuilt = buildControls(data.controls, overlay); }
    }
    (data.legend || []).forEach(function (item) {
      var d = el("div"), sw = el("span", {"class": "swatch"});
      sw.style.background = item.color; d.appendChild(sw);
      d.appendChild(document.createTextNode(item.text)); overlay.appendChild(d);
    });
    (data.colorbars || []).forEach(function (cb) {
      var d = el("div"); d.appendChild(el("div", {}, cb.label));
      var bar = el("div", {"class": "bar"});
      bar.style.background = "linear-gradient(to right, " + cb.colors.join(", ") + ")";
      d.appendChild(bar);
      var ends = el("div", {"class": "ends"});
      ends.appendChild(el("span", {}, cb.min)); ends.appendChild(el("span", {}, cb.max));
      d.appendChild(ends); overlay.appendChild(d);
    });
    if ((data.toggles || []).length) {
      var fs = el("fieldset"); fs.appendChild(el("legend", {}, "show"));
      data.toggles.forEach(function (t) {
        var lab = el("label", {"class": "row"}), box = el("input", {type: "checkbox"});
        var n = node(t.path);
        box.checked = n ? n.object.visible : true;
        box.addEventListener("change", function () {
          var m = node(t.path);
          if (m) { m.vis_controller.setValue(box.checked); viewer.set_dirty(); }
        });
        lab.appendChild(box); lab.appendChild(el("span", {}, t.label)); fs.appendChild(lab);
      });
      overlay.appendChild(fs);
    }
    frames = data.frames || null;
    if (frames) { overlay.appendChild(el("div", {id: "stiffness-frame", "class": "note"}, "")); }
    (data.notes || []).forEach(function (t) {
      overlay.appendChild(el("div", {"class": "note"}, t));
    });
    var connected = socket && socket.readyState === 1 ? "connected" : "connecting";
    var status = el("div", {id: "stiffness-status", "class": "note"},
      live ? "live: " + connected : "static page");
    overlay.appendChild(status);
  }
  function showFrame() {
    if (frames) {
      var box = document.getElementById("stiffness-frame");
      var i = Math.round(viewer.animator.time * frames.fps);
      i = Math.max(0, Math.min(frames.rows.length - 1, i));
      if (box && box.getAttribute("data-frame") !== String(i)) {
        box.setAttribute("data-frame", String(i));
        box.textContent = "animation frame " + i + ": " + frames.rows[i];
      }
    }
    requestAnimationFrame(showFrame);
  }
  function handle(data) {
    try { viewer.handle_command_bytearray(data); }
    catch (err) { console.error("stiffness viewer: command failed", err); }
  }
  // The deflected robot: a translucent red copy of the robot's meshes, made here rather than
  // sent twice (meshcat's colour property cannot recolour multi-material meshes anyway).
  function ghost() {
    var robot = node(["meshcat", "robot", "visuals"]);
    Object.keys(robot ? robot.children : {}).forEach(function (k) {
      var source = robot.children[k].children["<object>"];
      if (!source) { return; }
      var target = viewer.scene_tree.find(["meshcat", "deflected", "visuals", k]);
      if (target.children["<object>"]) { return; }
      target.find(["<object>"]).set_object(source.object.clone());
    });
    var n = node(["meshcat", "deflected"]);
    if (!n) { return; }
    n.object.traverse(function (o) {
      if (!o.isMesh || o.userData.stiffnessGhost) { return; }
      function tint(m) {
        if (Array.isArray(m)) { return m.map(tint); }
        if (!m || typeof m.clone !== "function") { return m; }
        var g = m.clone();
        if (g.color) { g.color.setRGB(GHOST[0], GHOST[1], GHOST[2]); }
        g.map = null; g.opacity = GHOST[3]; g.transparent = true; g.depthWrite = false;
        g.needsUpdate = true;
        return g;
      }
      o.material = tint(o.material);
      o.userData.stiffnessGhost = true;
    });
    viewer.set_dirty();
  }
  var ghostTimer = null;
  JSON.parse(document.getElementById("stiffness-commands").textContent).forEach(function (c) {
    handle(bytes(c));
  });
  ghost();
  var aimed = false;
  function aim(c) {
    // meshcat's world is z-up; three.js (the camera and its orbit controls) is y-up.
    if (!c || aimed) { return; }
    viewer.controls.target.set(c.target[0], c.target[2], -c.target[1]);
    viewer.camera.position.set(c.position[0], c.position[2], -c.position[1]);
    viewer.controls.update(); viewer.set_dirty(); aimed = true;
  }
  var initial = JSON.parse(document.getElementById("stiffness-overlay-data").textContent);
  render(initial);
  if (initial) { aim(initial.camera); }
  if (live) {
    var scheme = location.protocol === "https:" ? "wss://" : "ws://";
    socket = new WebSocket(scheme + location.host + "/websocket");
    socket.binaryType = "arraybuffer";
    viewer.connection = socket;
    socket.onmessage = function (e) {
      if (typeof e.data === "string") {
        var m = JSON.parse(e.data);
        if (m.type === "overlay") { render(m.data); aim(m.data && m.data.camera); }
      } else {
        handle(new Uint8Array(e.data));
        received += 1;
        if (ghostTimer) { clearTimeout(ghostTimer); }
        ghostTimer = setTimeout(ghost, 50);
        document.body.setAttribute("data-received", String(received));
      }
    };
    socket.onopen = function () {
      var s = document.getElementById("stiffness-status");
      if (s) { s.textContent = "live: connected"; }
    };
    socket.onclose = function () {
      var s = document.getElementById("stiffness-status");
      if (s) { s.textContent = "live: disconnected (the viewer's server stopped)"; }
    };
  }
  requestAnimationFrame(showFrame);
  document.body.setAttribute("data-stiffness-ready", "true");
})();
"""


def _json_script(value: Any) -> str:
    return json.dumps(value).replace("</", "<\\/")


def render_page(commands: list[bytes], overlay: dict | None, title: str, live: bool = False
                ) -> str:
    """HTML page of a scene.

    Parameters
    ----------
    commands
        Packed meshcat commands to replay when the page loads.
    overlay
        Legend data (see :meth:`StiffnessViewer.overlay`).
    title
        Page title.
    live
        ``False``: a self-contained page (meshcat's viewer script inlined, no network access).
        ``True``: the live server's page (script from ``/static/``, scene and legend over the
        server's websocket).
    """
    encoded = [base64.b64encode(c).decode("ascii") for c in commands]
    if live:
        viewer_script = '<script src="/static/main.min.js"></script>'
    else:
        viewer_script = "<script>" + _meshcat().viewer_js.read_text() + "</script>"
    return (
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
        f"<title>{html_lib.escape(title)}</title>\n<style>{_PAGE_CSS}</style>\n</head>\n"
        f"<body data-live=\"{'true' if live else 'false'}\">\n"
        "<div id=\"meshcat-pane\"></div>\n<div id=\"stiffness-overlay\"></div>\n"
        f"{viewer_script}\n"
        "<script type=\"application/json\" id=\"stiffness-commands\">"
        f"{_json_script(encoded)}</script>\n"
        f"<script type=\"application/json\" id=\"stiffness-ghost\">{list(DEFLECTED_RGBA)}"
        "</script>\n"
        "<script type=\"application/json\" id=\"stiffness-overlay-data\">"
        f"{_json_script(overlay)}</script>\n"
        f"<script>{_PAGE_JS}</script>\n</body>\n</html>\n"
    )


def scene_commands(page: str) -> list[dict]:
    """Decode the meshcat commands embedded in a page written by :func:`render_page`.

    Returns the unpacked commands (``type``, ``path``, ``object``/``matrix``/...) in replay
    order: read back an exported scene, e.g. to check an ellipsoid's transform.
    """
    match = re.search(r'<script type="application/json" id="stiffness-commands">(.*?)</script>',
                      page, re.S)
    if match is None:
        raise StiffnessError("not a page written by stiffness.viewer (no embedded scene)")
    unpack = _meshcat().msgpack.unpackb
    return [unpack(base64.b64decode(c)) for c in json.loads(match.group(1))]


def scene_transforms(commands: list[dict]) -> dict[str, np.ndarray]:
    """Latest 4x4 transform of each path among decoded commands (meshcat is column-major)."""
    out = {}
    for command in commands:
        if command["type"] == "set_transform":
            out[command["path"]] = np.array(command["matrix"], dtype=float).reshape(4, 4).T
    return out


# ---------------------------------------------------------------------------------- live server


class _Window:
    """meshcat's window protocol: records every command, forwards it to a live server if any."""

    def __init__(self, server: LiveServer | None = None) -> None:
        self.scene = SceneStore()
        self.server = server
        self.web_url = server.web_url if server is not None else None

    def send(self, command: Any) -> None:
        data = command.lower()
        packed = _meshcat().msgpack.packb(data)
        self.scene.apply(data["type"], data["path"], packed, data.get("property"))
        if self.server is not None:
            self.server.request([data["type"].encode(), data["path"].encode(), packed])

    def get_scene(self) -> str:
        return render_page(self.scene.commands(), None, "meshcat")

    def get_image(self) -> Any:
        raise StiffnessError("image capture is not supported; use export() and a browser")

    def close(self) -> None:
        if self.server is not None:
            self.server.close()


class LiveServer:
    """The viewer's web server, in its own process, bound to ``host`` (loopback by default).

    Serves the viewer page at ``web_url``, meshcat's scripts under ``/static/``, the scene over
    a websocket at ``/websocket``, and takes commands on a ZeroMQ socket (``zmq_url``). Every
    request times out after ``timeout`` s; the process stops on :meth:`close`, at interpreter
    exit, or when this process dies.

    Parameters
    ----------
    host
        Address to bind (default 127.0.0.1: unreachable from other machines).
    port
        Web port (0: a free port).
    timeout
        Seconds to wait for the process to start and for each answer.
    """

    def __init__(self, host: str = LOOPBACK, port: int = 0, timeout: float = DEFAULT_TIMEOUT
                 ) -> None:
        import zmq

        self.host, self.timeout = host, float(timeout)
        self._lock = threading.RLock()
        log, self._log_path = tempfile.mkstemp(prefix="stiffness-viewer-", suffix=".log")
        command = [sys.executable, "-m", "stiffness.viewer", "--serve", host, str(int(port)),
                   str(os.getpid()), self._log_path]
        try:
            # own session: a Ctrl-C in a notebook cell does not kill the server
            self.process = subprocess.Popen(
                command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=log,
                start_new_session=True, text=True,
            )
        finally:
            os.close(log)
        self._closed = False
        atexit.register(self.close)
        urls = self._read_urls()
        self.zmq_url, self.web_url = urls["zmq_url"], urls["web_url"]
        threading.Thread(target=self._drain, daemon=True).start()
        self._context = zmq.Context()
        self._socket = None
        self._connect()

    def _read_urls(self) -> dict:
        found: dict = {}
        lines: list[str] = []

        def reader() -> None:
            for line in self.process.stdout:
                lines.append(line.strip())
                if line.startswith("web_url="):
                    return

        thread = threading.Thread(target=reader, daemon=True)
        thread.start()
        thread.join(self.timeout)
        for line in lines:
            if "=" in line:
                key, value = line.split("=", 1)
                found[key] = value
        if "zmq_url" not in found or "web_url" not in found:
            log = self._log_tail()
            code = self.process.poll()
            why = f"exited with code {code}" if code is not None else \
                f"did not start within {self.timeout:g} s"
            self.close()
            raise StiffnessError(f"the viewer's server {why} (its log: {log})")
        return found

    def _drain(self) -> None:
        try:
            for _ in self.process.stdout:
                pass
        except (OSError, ValueError):
            pass

    def _log_tail(self) -> str:
        try:
            return Path(self._log_path).read_text()[-600:].strip() or "empty"
        except OSError:
            return "unreadable"

    def _connect(self) -> None:
        import zmq

        if self._socket is not None:
            self._socket.close(linger=0)
        self._socket = self._context.socket(zmq.REQ)
        self._socket.setsockopt(zmq.LINGER, 0)
        self._socket.setsockopt(zmq.SNDTIMEO, int(self.timeout * 1000))
        self._socket.connect(self.zmq_url)

    def request(self, frames: list[bytes], timeout: float | None = None) -> bytes:
        """Send one command, return the server's answer.

        Raises
        ------
        StiffnessError
            If the server is closed or does not answer within ``timeout`` s (default: the
            server's); the command socket is then reset so later requests still work.
        """
        import zmq

        timeout = self.timeout if timeout is None else timeout
        with self._lock:
            if self._closed:
                raise StiffnessError("the viewer's server is closed")
            try:
                self._socket.send_multipart(frames)
                if self._socket.poll(int(timeout * 1000), zmq.POLLIN):
                    return self._socket.recv()
            except zmq.ZMQError as exc:
                self._connect()
                raise StiffnessError(f"the viewer's server failed: {exc}") from exc
            self._connect()
            alive = "running" if self.process.poll() is None else "exited"
            raise StiffnessError(
                f"the viewer's server ({alive}) did not answer within {timeout:g} s"
            )

    def clients(self) -> int:
        """Number of browsers connected."""
        return int(self.request([b"clients"]))

    def events(self) -> list[dict]:
        """Control changes sent by the pages since the last call, oldest first."""
        return json.loads(self.request([b"events"]))

    def set_overlay(self, overlay: dict) -> None:
        """Send the legend and controls to the server (and its pages)."""
        self.request([b"overlay", json.dumps(overlay).encode()])

    def wait_for_browser(self, timeout: float = 10.0, poll: float = 0.1) -> bool:
        """Wait at most ``timeout`` s for a browser to connect; whether one did."""
        deadline = time.monotonic() + timeout
        while True:
            if self.clients() > 0:
                return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(poll)

    @property
    def running(self) -> bool:
        """Whether the server process is alive."""
        return self.process.poll() is None

    def close(self) -> None:
        """Stop the server process (idempotent)."""
        with self._lock:
            if self._closed:
                return
            if getattr(self, "_socket", None) is not None:
                with contextlib.suppress(StiffnessError):
                    self.request([b"stop"], timeout=1.0)
            self._closed = True
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.process.wait(timeout=2.0)
            if self.process.poll() is None:
                self.process.terminate()
                try:
                    self.process.wait(timeout=3.0)
                except subprocess.TimeoutExpired:
                    self.process.kill()
                    self.process.wait(timeout=3.0)
            if self.process.stdout is not None:
                self.process.stdout.close()
            if getattr(self, "_socket", None) is not None:
                self._socket.close(linger=0)
                self._context.term()
            with contextlib.suppress(OSError):
                os.unlink(self._log_path)
            atexit.unregister(self.close)

    def __enter__(self) -> LiveServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _serve(host: str, port: int, parent_pid: int, log_path: str | None = None) -> int:
    """The server process: meshcat's page scripts, our page, a websocket and a ZeroMQ socket.

    Stops on the ``stop`` command, on SIGTERM, or when ``parent_pid`` is no longer its parent
    (the owner died without closing it; it then removes its log file ``log_path``).
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        import tornado.httpserver
        import tornado.ioloop
        import tornado.netutil
        import tornado.web
        import tornado.websocket
        import zmq
        from meshcat.servers.zmqserver import VIEWER_ROOT, StaticFileHandlerNoCache
        from zmq.eventloop.zmqstream import ZMQStream

    store = SceneStore()
    state: dict = {"overlay": None, "events": [], "pool": set()}
    loop = tornado.ioloop.IOLoop.current()

    class Page(tornado.web.RequestHandler):
        def get(self) -> None:
            self.set_header("Cache-Control", "no-store")
            self.write(render_page([], state["overlay"], "stiffness viewer", live=True))

    class Socket(tornado.websocket.WebSocketHandler):
        def open(self) -> None:  # noqa: A003 (tornado's name)
            state["pool"].add(self)
            for packed in store.commands():
                self.write_message(packed, binary=True)
            if state["overlay"] is not None:
                self.write_message(json.dumps({"type": "overlay", "data": state["overlay"]}))

        def on_message(self, message: str | bytes) -> None:
            try:
                data = json.loads(message)
            except (TypeError, ValueError):
                return
            if isinstance(data, dict) and data.get("type") == "control":
                state["events"] = (state["events"] + [data.get("state", {})])[-100:]

        def on_close(self) -> None:
            state["pool"].discard(self)

    def broadcast(message: bytes | str, binary: bool) -> None:
        for socket in list(state["pool"]):
            try:
                socket.write_message(message, binary=binary)
            except tornado.websocket.WebSocketClosedError:
                state["pool"].discard(socket)

    app = tornado.web.Application([
        (r"/", Page),
        (r"/websocket", Socket),
        (r"/static/(.*)", StaticFileHandlerNoCache, {"path": VIEWER_ROOT}),
    ])
    sockets = tornado.netutil.bind_sockets(port, address=host)
    server = tornado.httpserver.HTTPServer(app)
    server.add_sockets(sockets)
    web_port = sockets[0].getsockname()[1]

    context = zmq.Context()
    rep = context.socket(zmq.REP)
    rep.setsockopt(zmq.LINGER, 0)
    rep.bind(f"tcp://{host}:*")
    zmq_url = rep.getsockopt(zmq.LAST_ENDPOINT).decode()
    stream = ZMQStream(rep)

    def stop() -> None:
        server.stop()
        loop.stop()

    def handle(frames: list[bytes]) -> None:
        kind = frames[0].decode()
        reply = b"ok"
        if kind in ("set_object", "set_transform", "set_property", "set_animation", "delete"):
            if len(frames) != 3:
                reply = b"error: expected 3 frames"
            else:
                key = None
                if kind == "set_property":
                    key = _meshcat().msgpack.unpackb(frames[2]).get("property")
                store.apply(kind, frames[1].decode(), frames[2], key)
                broadcast(frames[2], True)
        elif kind == "overlay":
            state["overlay"] = json.loads(frames[1])
            broadcast(json.dumps({"type": "overlay", "data": state["overlay"]}), False)
        elif kind == "clients":
            reply = str(len(state["pool"])).encode()
        elif kind == "events":
            reply = json.dumps(state["events"]).encode()
            state["events"] = []
        elif kind == "url":
            reply = web_url.encode()
        elif kind == "stop":
            loop.add_callback(stop)
        else:
            reply = b"error: unknown command " + frames[0]
        stream.send(reply)

    stream.on_recv(handle)
    shown_host = f"[{host}]" if ":" in host else host
    web_url = f"http://{shown_host}:{web_port}/"

    def watch_parent() -> None:
        if os.getppid() != parent_pid:
            if log_path:
                with contextlib.suppress(OSError):
                    os.unlink(log_path)
            stop()

    tornado.ioloop.PeriodicCallback(watch_parent, 1000).start()
    print(f"zmq_url={zmq_url}", flush=True)
    print(f"web_url={web_url}", flush=True)
    try:
        loop.start()
    except KeyboardInterrupt:
        pass
    finally:
        stream.close()
        context.term()
    return 0


# ----------------------------------------------------------------------------------- the viewer


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
        The robot (:func:`stiffness.robot.load_robot`).
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
            raise StiffnessError(f"quantity must be one of {QUANTITIES}, got {quantity!r}")
        k = np.asarray(k_theta, dtype=float)
        self.k_theta = k if k.ndim == 2 else joint_stiffness(k, robot.n_compliant)
        if self.k_theta.shape != (robot.n_compliant, robot.n_compliant):
            raise StiffnessError(f"k_theta must be ({robot.n_compliant}, {robot.n_compliant}) "
                                 f"for {robot.name}, got {self.k_theta.shape}")
        self.robot = robot
        self.quantity = quantity
        self.reach = self._reach()
        self.size = float(size) if size is not None else 0.12 * self.reach
        self._label = 0.22 * self.reach
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
        visual = self.robot.visual_model
        self._has_meshes = visual is not None and visual.ngeoms > 0
        if self._has_meshes:
            visualizer = _pinocchio_meshcat_visualizer()
            self._viz = visualizer(self.robot.model, None, visual)
            self._viz.initViewer(viewer=vis)
            self._viz.loadViewerModel(ROBOT_NODE)
            # the deflected robot reuses these meshes: the page copies them (see _PAGE_JS)
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
            raise StiffnessError(
                f"formulation must be one of {SHOW_FORMULATIONS}, got {formulation!r}")
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
                raise StiffnessError(f"quantity must be one of {QUANTITIES}, got {quantity!r}")
            quantity = quantity or self.quantity
            formulation, names = self._formulations(formulation)
            coords, q = self._configuration(coords)
            load = self._load(wrench, q)
            state = self._compute(coords, q, load, names, quantity)
            self.state, self.quantity, self._formulation = state, quantity, formulation
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
        state = SceneState(coords=np.asarray(coords, dtype=float), q=q, wrench=load,
                           position=position, ellipsoids=ells, centers=centers, radii=radii,
                           scale=scale, quantity=quantity, deflection=dx, deflected_q=deflected_q,
                           exaggeration=float(self.exaggeration or 1.0), note=note)
        state.poses = self._poses(state)
        return state

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
            for i, a in enumerate(_AXIS_NAMES):
                side = -1.0 if i == 1 else 1.0  # axis 2 labelled at its other end
                tip = c + side * ell.directions[:, i] * (r[i] + 0.15 * self.size)
                poses[f"{base}/label{a}"] = Pose(tip, np.eye(3), np.ones(3))
            below = c - np.array([0.0, 0.0, np.max(r) + 0.3 * self.size])
            poses[f"{base}/label"] = Pose(below, np.eye(3), np.ones(3))
            poses[f"{base}/link"] = _segment(p, c) if np.linalg.norm(c - p) > 0 else hidden
        return poses

    def _send_poses(self, poses: dict[str, Pose]) -> None:
        for path, pose in poses.items():
            self._vis[path].set_transform(pose.matrix())

    def _style(self, state: SceneState, labels: bool = True) -> None:
        """Objects whose look depends on the values: ellipsoid colours, labels, visibility."""
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
            points = np.array([[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0], [0, 0, -1],
                               [0, 0, 1]], dtype=np.float32).T
            colors = np.array([[0.7, 0, 0]] * 2 + [[0, 0.5, 0]] * 2 + [[0, 0, 0.8]] * 2,
                              dtype=np.float32).T
            vis[f"{base}/axes"].set_object(mg.LineSegments(
                mg.PointsGeometry(points, colors), mg.LineBasicMaterial(vertexColors=True)))
            symbol = "k" if state.quantity == "stiffness" else "c"
            for i, a in enumerate(_AXIS_NAMES):
                text = f"{symbol}{a}"
                if labels:
                    text += f" = {format_value(ell.values[i], ell.units)}"
                vis[f"{base}/label{a}"].set_object(_text_object(text, self._label))
            vis[f"{base}/label"].set_object(_text_object(name, 1.1 * self._label))
            vis[f"{base}/link"].set_object(mg.Cylinder(1.0, 0.003 * self.reach),
                                           mg.MeshPhongMaterial(color=0x888888))
        moment = state.wrench[3:]
        vis[f"{STIFFNESS_NODE}/moment"].set_property("visible", bool(np.any(moment)))
        vis[f"{STIFFNESS_NODE}/force"].set_property("visible", bool(np.any(state.wrench[:3])))

    # ------------------------------------------------------------------ legend

    def overlay(self) -> dict:
        """Legend (and live controls) of the current scene, as the page's JSON."""
        robot, st = self.robot, self.state
        data: dict = {"title": f"{robot.name}: {self.quantity} ellipsoids at "
                               f"{robot.target_frame}", "lines": [], "legend": [],
                      "colorbars": [], "toggles": [], "notes": []}
        if self._error:
            data["error"] = self._error
        if st is not None:
            deg = [format_value(v) for v in self._display_coords(st.coords)]
            data["lines"].append(f"coordinates ({', '.join(robot.coordinate_joints)}): "
                                 f"[{', '.join(deg)}] (deg; m for prismatic)")
            f = st.wrench[:3]
            data["lines"].append(
                f"load F = [{', '.join(format_value(v) for v in f)}] N "
                f"(|F| = {format_value(float(np.linalg.norm(f)), 'N')})"
                + (f", M = [{', '.join(format_value(v) for v in st.wrench[3:])}] N.m"
                   if np.any(st.wrench[3:]) else "") + ", base axes")
            lo, hi = self.color_range
            for name, ell in st.ellipsoids.items():
                values = ", ".join(format_value(v) for v in ell.values)
                where = "at the target" if np.allclose(st.centers[name], st.position) else \
                    "beside the target (grey line)"
                rgb = _color_of(COLORMAPS[name], (ell.min_stiffness - lo) / (hi - lo))
                data["legend"].append({
                    "color": _hex(rgb),
                    "text": f"{FORMULATION_LABELS[name]}, {where}: principal {self.quantity} "
                            f"[{values}] {ell.units}; k_min = "
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
                                 "label values are those of frame 0, the line above follows")
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
        model = self.robot.model
        return model.joints[model.getJointId(joint)].shortname().startswith("JointModelP")

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
        (the 3-D labels keep the axis names). The scene left outside the animation is frame 0.

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
            self._style(first, labels=False)
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
            raise StiffnessError(f"formulation must be one of {FORMULATIONS}, got "
                                 f"{formulation!r}")
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
            self._send_overlay()
            return self.field_state

    def _random_coordinates(self, n: int, base: np.ndarray, joints: Sequence[str] | None,
                            seed: int) -> np.ndarray:
        robot, model = self.robot, self.robot.model
        names = list(robot.coordinate_joints) if joints is None else list(joints)
        unknown = [j for j in names if j not in robot.coordinate_joints]
        if unknown:
            raise StiffnessError(f"{unknown} are not coordinates of {robot.name}; "
                                 f"coordinates: {', '.join(robot.coordinate_joints)}")
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
            title = title or f"{self.robot.name} stiffness ({self.quantity})"
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


def export_sk120_scene(path: Path) -> Path:
    """Write the SK120's static scene (default configuration A and load) to ``path``.

    The report links it. Enhanced and conventional stiffness ellipsoids side by side, the
    deflected robot and the load arrow; a self-contained HTML page that opens offline.
    """
    robot = load_robot("sk120")
    viewer = StiffnessViewer(robot, robot.defaults["k_theta_SI"])
    viewer.show()
    return viewer.export(path, title="Motoman SK120: stiffness at configuration A")


def _main(argv: list[str]) -> int:
    """``python -m stiffness.viewer --serve HOST PORT PARENT_PID [LOG]``: the live server."""
    if len(argv) in (4, 5) and argv[0] == "--serve":
        return _serve(argv[1], int(argv[2]), int(argv[3]), argv[4] if len(argv) == 5 else None)
    print("usage: python -m stiffness.viewer --serve HOST PORT PARENT_PID [LOG] "
          "(started by StiffnessViewer; use `stiffness view`)", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
