"""The viewer's HTML page: render a recorded scene and its legend; read a page's scene back.

:func:`render_page` writes a self-contained static page (meshcat's viewer script inlined, no
network access) or the live server's page (scene and legend over its websocket);
:func:`scene_commands` and :func:`scene_transforms` decode the scene embedded in a static page.
"""

from __future__ import annotations

import base64
import html as html_lib
import json
import re
from typing import Any

import numpy as np

from stiffness.errors import StiffnessError
from stiffness.viewer.deps import meshcat_modules
from stiffness.viewer.style import DEFLECTED_RGBA

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
#stiffness-labels { position: absolute; left: 0; top: 0; width: 100vw; height: 100vh;
  pointer-events: none; overflow: hidden; z-index: 4; }
#stiffness-labels svg { position: absolute; left: 0; top: 0; width: 100%; height: 100%; }
#stiffness-labels .stiffness-label { position: absolute; display: none; white-space: nowrap;
  font: 12px/1.2 sans-serif; padding: 1px 4px; background: rgba(255,255,255,0.88);
  border: 1px solid #777; border-radius: 3px; color: #111; }
#stiffness-labels .stiffness-label.name { font-weight: bold; }
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
  // ---- labels: HTML boxes at the projected anchors, with leader lines. Placed greedily in
  // order (names first): each tries offsets outward from its ellipsoid's centre and is
  // dropped if every offset would overlap a placed label, the legend, the robot, an
  // ellipsoid or leave the frame.
  var labelLayer = document.getElementById("stiffness-labels");
  var SVGNS = "http://www.w3.org/2000/svg";
  var leaders = document.createElementNS(SVGNS, "svg");
  labelLayer.appendChild(leaders);
  var labelSpecs = [], labelEls = [], lastLayout = -1e9, lastCamera = "";
  var Vec3 = viewer.camera.position.constructor;
  var DISTANCES = [12, 30, 56], ANGLES = [0, 0.6, -0.6, 1.2, -1.2, 1.9, -1.9, Math.PI];
  function shown(path) {
    var n = node(path);
    if (!n) { return null; }
    for (var o = n.object; o; o = o.parent) { if (!o.visible) { return null; } }
    return n.object;
  }
  function worldOf(o) {
    o.updateWorldMatrix(true, false);
    return new Vec3().setFromMatrixPosition(o.matrixWorld);
  }
  function screenOf(v, w, h) {
    var p = v.clone().project(viewer.camera);
    if (!(p.z > -1 && p.z < 1)) { return null; }
    return [(p.x + 1) / 2 * w, (1 - p.y) / 2 * h];
  }
  function robotSegments(w, h) {
    // every mesh of the robot (and its deflected copy) as a thick screen segment along its
    // longest local axis
    var out = [];
    ["robot", "deflected"].forEach(function (root) {
      var top = shown(["meshcat", root]);
      if (!top) { return; }
      top.traverseVisible(function (o) {
        if (!o.isMesh || !o.geometry) { return; }
        if (!o.geometry.boundingBox) { o.geometry.computeBoundingBox(); }
        var box = o.geometry.boundingBox, c = new Vec3(), size = new Vec3();
        box.getCenter(c); box.getSize(size);
        var s = [size.x, size.y, size.z];
        var axis = s[0] >= s[1] && s[0] >= s[2] ? 0 : (s[1] >= s[2] ? 1 : 2);
        var a = c.clone(), b = c.clone(), side = c.clone();
        a.setComponent(axis, c.getComponent(axis) - s[axis] / 2);
        b.setComponent(axis, c.getComponent(axis) + s[axis] / 2);
        var k = (axis + 1) % 3, m = (axis + 2) % 3, other = s[k] >= s[m] ? k : m;
        side.setComponent(other, c.getComponent(other) + s[other] / 2);
        o.updateWorldMatrix(true, false);
        [a, b, c, side].forEach(function (v) { v.applyMatrix4(o.matrixWorld); });
        var pa = screenOf(a, w, h), pb = screenOf(b, w, h);
        var pc = screenOf(c, w, h), ps = screenOf(side, w, h);
        if (!pa || !pb) { return; }
        var t = pc && ps ? Math.hypot(ps[0] - pc[0], ps[1] - pc[1]) : 3;
        out.push([pa, pb, Math.max(t, 3)]);
      });
    });
    return out;
  }
  function ellipses(w, h) {
    // each shown ellipsoid's image on screen, to first order about its centre: the ellipse of
    // shape V V^T, V = the projected principal semi-axes (its axis labels' anchors)
    var byCenter = {};
    labelSpecs.forEach(function (spec) {
      if (spec.kind !== "axis") { return; }
      var anchor = shown(spec.anchor), center = shown(spec.center);
      if (!anchor || !center) { return; }
      var C = screenOf(worldOf(center), w, h), A = screenOf(worldOf(anchor), w, h);
      if (!C || !A) { return; }
      var key = spec.center.join("/");
      var e = byCenter[key] || (byCenter[key] = {c: C, a: 0, b: 0, d: 0});
      var vx = A[0] - C[0], vy = A[1] - C[1];
      e.a += vx * vx; e.b += vx * vy; e.d += vy * vy;
    });
    return Object.keys(byCenter).map(function (k) { return byCenter[k]; }).filter(
      function (e) { return e.a * e.d - e.b * e.b > 1e-6; });
  }
  function coversEllipse(box, e) {
    // the box contains the ellipse's centre, or one of a grid of its points lies inside it
    var det = e.a * e.d - e.b * e.b;
    if (e.c[0] > box.l && e.c[0] < box.r && e.c[1] > box.t && e.c[1] < box.b) { return true; }
    for (var i = 0; i <= 4; i++) {
      for (var j = 0; j <= 2; j++) {
        var x = box.l + (box.r - box.l) * i / 4 - e.c[0];
        var y = box.t + (box.b - box.t) * j / 2 - e.c[1];
        if ((e.d * x * x - 2 * e.b * x * y + e.a * y * y) / det <= 1.0) { return true; }
      }
    }
    return false;
  }
  function overlaps(a, b, gap) {
    return a.l < b.r + gap && b.l < a.r + gap && a.t < b.b + gap && b.t < a.b + gap;
  }
  function hitsSegment(box, seg) {
    var a = seg[0], b = seg[1], t = seg[2];
    var n = Math.max(2, Math.ceil(Math.hypot(b[0] - a[0], b[1] - a[1]) / 4));
    for (var i = 0; i <= n; i++) {
      var x = a[0] + (b[0] - a[0]) * i / n, y = a[1] + (b[1] - a[1]) * i / n;
      if (x > box.l - t && x < box.r + t && y > box.t - t && y < box.b + t) { return true; }
    }
    return false;
  }
  function buildLabels(specs) {
    labelEls.forEach(function (e) { e.remove(); });
    labelSpecs = specs || [];
    labelEls = labelSpecs.map(function (spec) {
      var e = el("div", {"class": "stiffness-label " + spec.kind}, spec.text);
      labelLayer.appendChild(e);
      return e;
    });
    lastLayout = -1e9;
  }
  function layoutLabels() {
    var canvas = viewer.renderer.domElement.getBoundingClientRect();
    var w = canvas.width, h = canvas.height;
    var o = overlay.getBoundingClientRect();
    var legend = {l: o.left - canvas.left, t: o.top - canvas.top, r: o.right - canvas.left,
                  b: o.bottom - canvas.top};
    var placed = [], segments = robotSegments(w, h), bodies = ellipses(w, h);
    while (leaders.firstChild) { leaders.removeChild(leaders.firstChild); }
    labelSpecs.forEach(function (spec, i) {
      var e = labelEls[i];
      e.style.display = "none";
      e.removeAttribute("data-placed");
      var anchor = shown(spec.anchor), center = shown(spec.center);
      if (!anchor) { return; }
      var A = screenOf(worldOf(anchor), w, h);
      if (!A) { return; }
      var C = center ? screenOf(worldOf(center), w, h) : null;
      var dx = 0, dy = 1;
      if (spec.kind !== "name" && C) {
        dx = A[0] - C[0]; dy = A[1] - C[1];
        var norm = Math.hypot(dx, dy);
        if (norm > 1e-6) { dx /= norm; dy /= norm; } else { dx = 0; dy = -1; }
      }
      e.style.display = "block";
      var bw = e.offsetWidth, bh = e.offsetHeight, found = null;
      for (var di = 0; di < DISTANCES.length && !found; di++) {
        for (var ai = 0; ai < ANGLES.length && !found; ai++) {
          var ca = Math.cos(ANGLES[ai]), sa = Math.sin(ANGLES[ai]);
          var ux = dx * ca - dy * sa, uy = dx * sa + dy * ca;
          var reach = DISTANCES[di] + Math.abs(ux) * bw / 2 + Math.abs(uy) * bh / 2;
          var cx = A[0] + ux * reach, cy = A[1] + uy * reach;
          var box = {l: cx - bw / 2, t: cy - bh / 2, r: cx + bw / 2, b: cy + bh / 2};
          if (box.l < 2 || box.t < 2 || box.r > w - 2 || box.b > h - 2) { continue; }
          if (overlaps(box, legend, 4)) { continue; }
          if (placed.some(function (p) { return overlaps(box, p, 3); })) { continue; }
          if (segments.some(function (sg) { return hitsSegment(box, sg); })) { continue; }
          if (bodies.some(function (b) { return coversEllipse(box, b); })) { continue; }
          found = box;
        }
      }
      if (!found) { e.style.display = "none"; return; }
      placed.push(found);
      e.style.left = (canvas.left + found.l) + "px";
      e.style.top = (canvas.top + found.t) + "px";
      e.setAttribute("data-placed", "true");
      var px = Math.max(found.l, Math.min(A[0], found.r));
      var py = Math.max(found.t, Math.min(A[1], found.b));
      var line = document.createElementNS(SVGNS, "line");
      line.setAttribute("x1", canvas.left + A[0]); line.setAttribute("y1", canvas.top + A[1]);
      line.setAttribute("x2", canvas.left + px); line.setAttribute("y2", canvas.top + py);
      line.setAttribute("stroke", "#555"); line.setAttribute("stroke-width", "1");
      leaders.appendChild(line);
      var dot = document.createElementNS(SVGNS, "circle");
      dot.setAttribute("cx", canvas.left + A[0]); dot.setAttribute("cy", canvas.top + A[1]);
      dot.setAttribute("r", "2"); dot.setAttribute("fill", "#555");
      leaders.appendChild(dot);
    });
    document.body.setAttribute("data-labels-placed",
      String(labelEls.filter(function (e) { return e.hasAttribute("data-placed"); }).length));
  }
  function maybeLayout(now) {
    var cam = viewer.camera.matrixWorld.elements.join(",") + viewer.animator.time;
    if (cam !== lastCamera || now - lastLayout > 500) {
      lastCamera = cam; lastLayout = now;
      try { layoutLabels(); } catch (err) { console.error("stiffness viewer: labels", err); }
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
    buildLabels(data.labels);
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
  function showFrame(now) {
    maybeLayout(now || 0);
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
    overTheRobot();
    viewer.set_dirty();
  }
  // The ellipsoids, their axes, the target and the load drawn over the robot's meshes (no
  // depth test, drawn last): a wrist or a hand would otherwise hide an ellipsoid smaller than
  // itself, and the translucent surfaces still show the robot behind them.
  function overTheRobot() {
    ["stiffness", "rotational"].forEach(function (root) {
      var n = node(["meshcat", root]);
      if (!n) { return; }
      n.object.traverse(function (o) {
        if (!o.material) { return; }
        o.renderOrder = 10;
        (Array.isArray(o.material) ? o.material : [o.material]).forEach(function (m) {
          if (m.depthTest) { m.depthTest = false; m.needsUpdate = true; }
        });
      });
    });
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
        viewer_script = "<script>" + meshcat_modules().viewer_js.read_text() + "</script>"
    return (
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
        f"<title>{html_lib.escape(title)}</title>\n<style>{_PAGE_CSS}</style>\n</head>\n"
        f"<body data-live=\"{'true' if live else 'false'}\">\n"
        "<div id=\"meshcat-pane\"></div>\n<div id=\"stiffness-labels\"></div>\n"
        "<div id=\"stiffness-overlay\"></div>\n"
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
    unpack = meshcat_modules().msgpack.unpackb
    return [unpack(base64.b64decode(c)) for c in json.loads(match.group(1))]


def scene_transforms(commands: list[dict]) -> dict[str, np.ndarray]:
    """Latest 4x4 transform of each path among decoded commands (meshcat is column-major)."""
    out = {}
    for command in commands:
        if command["type"] == "set_transform":
            out[command["path"]] = np.array(command["matrix"], dtype=float).reshape(4, 4).T
    return out
