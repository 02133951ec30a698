"""The meshcat stiffness viewer (stiffness.viewer, ``stiffness view``).

* The ellipsoids in the scene (read back from the exported page's commands, and from the
  browser's scene tree) have the eigenvectors of the computed matrix as axes and the stated
  scale times its eigenvalues as radii.
* The static page is self-contained: headless Chromium (Debian's ``chromium``, SwiftShader
  WebGL, network disabled) loads it, finds the robot's links and the ellipsoids in
  ``viewer.scene_tree``, and its renderings show them (pixels change where they project when
  they are hidden; the ellipsoids add their colours; every variant of a page is rendered in
  one browser run).
* The live server listens on 127.0.0.1 only (its listening sockets, and a refused connection to
  the machine's non-loopback address), serves the page that Chromium connects to, takes the
  page's controls, never blocks on an unresponsive server, and stops with its owner.

Browser tests skip where no chromium can be found, except under ``.ci/run``, where they fail
(tests/browser.py).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from browser import chromium

from stiffness.cli.main import main as cli_main
from stiffness.cli.report import export_scene
from stiffness.errors import StiffnessError
from stiffness.mechanics.formulation import (
    FORMULATIONS,
    cartesian_stiffness,
    compliance,
    tangent_joint_stiffness,
    target_state,
)
from stiffness.robot.robot import load_robot
from stiffness.viewer import (
    LOOPBACK,
    LiveServer,
    StiffnessViewer,
    format_value,
    scene_commands,
    scene_transforms,
)

UR5_Q = [0.0, -1.2, 1.5, -0.3, 1.57, 0.0]
UR5_KQ = [3e5, 3e5, 2e5, 4e4, 4e4, 4e4]
WINDOW = (1000, 700)
#: Canvas size forced in the pages under test (the viewport of --dump-dom and --screenshot
#: runs differ).
CANVAS = (960, 540)
#: Chromium flags: headless, SwiftShader WebGL (``--use-gl=swiftshader`` renders blank here).
CHROMIUM_FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
    "--disable-component-update", "--disable-sync", "--no-first-run",
    "--enable-unsafe-swiftshader", "--hide-scrollbars", f"--window-size={WINDOW[0]},{WINDOW[1]}",
]
#: No network for the static page: every host name fails, every proxied request too.
OFFLINE_FLAGS = ["--host-resolver-rules=MAP * ~NOTFOUND", "--proxy-server=127.0.0.1:9"]


# -------------------------------------------------------------------------------- helpers


def run_chromium(url: str, *extra: str, timeout: float = 90.0) -> str:
    """Run headless chromium on ``url`` with a fresh profile; its stdout."""
    with tempfile.TemporaryDirectory(ignore_cleanup_errors=True) as profile:
        result = subprocess.run(
            [chromium(), *CHROMIUM_FLAGS, f"--user-data-dir={profile}",
             "--virtual-time-budget=5000", *extra, url],
            capture_output=True, text=True, timeout=timeout, check=False,
        )
    return result.stdout


def png_pixels(path: Path) -> np.ndarray:
    """RGB pixels (H, W, 3) of a screenshot chromium wrote."""
    from PIL import Image

    assert path.is_file(), "chromium wrote no screenshot"
    return np.asarray(Image.open(path).convert("RGB"), dtype=float)


def page_overlay(page: str) -> dict:
    """The legend and label data embedded in an exported page."""
    found = re.search(r'<script type="application/json" id="stiffness-overlay-data">(.*?)'
                      r'</script>', page, re.S)
    assert found is not None, "no overlay data in the page"
    return json.loads(found.group(1).replace("<\\/", "</"))


def computed_stiffness(robot, coords, k_theta, load) -> dict[str, np.ndarray]:
    """Translational K_X of both formulations, straight from stiffness.mechanics.formulation."""
    q = robot.configuration(np.asarray(coords, dtype=float))
    state = target_state(robot, q, load)
    k = np.diag(k_theta)
    return {f: cartesian_stiffness(compliance(state.jacobian[:3],
                                              tangent_joint_stiffness(k, state.k_c, f)))
            for f in FORMULATIONS}


def assert_ellipsoid(matrix: np.ndarray, k_x: np.ndarray, scale: float, center=None) -> None:
    """A scene transform is the unit sphere onto eig(k_x): axes = eigenvectors,
    radii = scale * eigenvalues (ascending, axis i = column i)."""
    values, vectors = np.linalg.eigh(k_x)
    linear = matrix[:3, :3]
    radii = np.linalg.norm(linear, axis=0)
    np.testing.assert_allclose(radii, scale * values, rtol=1e-6)
    directions = linear / radii
    np.testing.assert_allclose(np.abs(np.sum(directions * vectors, axis=0)), 1.0, atol=1e-6)
    assert np.linalg.det(directions) > 0
    if center is not None:
        np.testing.assert_allclose(matrix[:3, 3], center, atol=1e-9)


def non_loopback_ipv4() -> str | None:
    """This machine's address on its default route (no packet is sent), if any."""
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.connect(("10.255.255.255", 9))
            ip = s.getsockname()[0]
            if not ip.startswith("127."):
                return ip
    except OSError:
        pass
    try:
        out = subprocess.run(["hostname", "-I"], capture_output=True, text=True,
                             timeout=5).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    return next((a for a in out.split() if "." in a and not a.startswith("127.")), None)


def listening_sockets(pid: int) -> list[tuple[str, int]]:
    """(address, port) of the TCP sockets process ``pid`` listens on (from /proc)."""
    inodes = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            link = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:
            continue
        if link.startswith("socket:["):
            inodes.add(link[8:-1])
    out = []
    for table, family in (("/proc/net/tcp", 4), ("/proc/net/tcp6", 6)):
        if not Path(table).exists():
            continue
        for line in Path(table).read_text().splitlines()[1:]:
            fields = line.split()
            if fields[3] != "0A" or fields[9] not in inodes:  # 0A: LISTEN
                continue
            address, port = fields[1].split(":")
            if family == 4:
                ip = socket.inet_ntop(socket.AF_INET, bytes.fromhex(address)[::-1])
            else:
                raw = bytes.fromhex(address)
                ip = socket.inet_ntop(socket.AF_INET6, b"".join(
                    raw[i:i + 4][::-1] for i in range(0, 16, 4)))
            out.append((ip, int(port, 16)))
    return out


def refused(host: str, port: int) -> bool:
    try:
        with socket.create_connection((host, port), timeout=2.0):
            return False
    except ConnectionRefusedError:
        return True
    except OSError:
        return True  # unreachable counts as not served


# --------------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def sk120_page(tmp_path_factory, sk120):
    """The SK120 scene written by the report hook, and the viewer's own computation."""
    folder = tmp_path_factory.mktemp("viewer")
    path = export_scene(folder / "sk120-scene.html")
    viewer = StiffnessViewer(sk120, sk120.defaults["k_theta_SI"])
    state = viewer.show()
    return path, viewer, state


# ------------------------------------------------------------------ ellipsoids in the scene


def test_exported_ellipsoids_are_the_eigendecomposition(sk120_page, sk120):
    path, viewer, state = sk120_page
    page = path.read_text()
    transforms = scene_transforms(scene_commands(page))
    coords = np.deg2rad(sk120.defaults["q_deg"])
    k_x = computed_stiffness(sk120, coords, sk120.defaults["k_theta_SI"],
                             sk120.defaults["wrench_SI"])
    position = target_state(sk120, sk120.configuration(coords)).position
    for name in FORMULATIONS:
        matrix = transforms[f"/meshcat/stiffness/{name}/surface"]
        # the enhanced one at the target, the conventional one beside it
        assert_ellipsoid(matrix, k_x[name], state.scale,
                         position if name == "enhanced" else None)
        # the axes are drawn with the same transform (unit segments along x, y, z)
        np.testing.assert_array_equal(transforms[f"/meshcat/stiffness/{name}/axes"], matrix)
    # the stated scale is the one drawn
    assert f"radius = {format_value(state.scale, 'm')} per N/m" in page
    # the page's labels name the axes at their tips; the legend carries values and units
    overlay = page_overlay(page)
    labels = {tuple(label["anchor"]): label["text"] for label in overlay["labels"]}
    assert labels[("meshcat", "stiffness", "enhanced", "label1")] == "k1"
    assert {"enhanced", "conventional"} <= set(labels.values())
    values = np.linalg.eigh(k_x["enhanced"])[0]
    legend = " ".join(item["text"] for item in overlay["legend"])
    assert f"k1, k2, k3 = [{', '.join(format_value(v) for v in values)}] N/m" in legend
    for i in range(3):  # anchored at the axis tips: centre + radius along eigenvector i
        tip = transforms[f"/meshcat/stiffness/enhanced/label{i + 1}"][:3, 3]
        axis = transforms["/meshcat/stiffness/enhanced/surface"][:3, i]
        np.testing.assert_allclose(tip, position + axis, atol=1e-9)


def test_ur5_scene_and_compliance_quantity(ur5):
    k_x = computed_stiffness(ur5, UR5_Q, UR5_KQ, [0.0, 0.0, -200.0])
    viewer = StiffnessViewer(ur5, UR5_KQ)
    state = viewer.show(UR5_Q, [0.0, 0.0, -200.0], "enhanced")
    transforms = scene_transforms(viewer.commands())
    assert_ellipsoid(transforms["/meshcat/stiffness/enhanced/surface"], k_x["enhanced"],
                     state.scale, state.position)
    meshes = [c["path"] for c in viewer.commands() if c["type"] == "set_object"
              and c["path"].startswith("/meshcat/robot/visuals/")]
    assert len(meshes) == ur5.visual_model.ngeoms
    # only the enhanced ellipsoid is visible
    props = {(c["path"], c["property"]): c["value"] for c in viewer.commands()
             if c["type"] == "set_property"}
    assert props[("/meshcat/stiffness/conventional", "visible")] is False
    # compliance ellipsoids: eigenvectors of C = K^-1, radii = scale * eig(C)
    state = viewer.show(quantity="compliance")
    c_x = np.linalg.inv(k_x["enhanced"])
    transforms = scene_transforms(viewer.commands())
    assert_ellipsoid(transforms["/meshcat/stiffness/enhanced/surface"], c_x, state.scale,
                     state.position)
    assert state.ellipsoids["enhanced"].units == "m/N"


def test_unbounded_stiffness_is_drawn_clipped(four_bar_robot):
    """Two compliant joints: K_X is infinite out of the loop's plane, drawn clipped."""
    viewer = StiffnessViewer(four_bar_robot, [100.0, 100.0])
    state = viewer.show([0.3, 0.2], [0.0, -50.0, 0.0], "enhanced")
    ell = state.ellipsoids["enhanced"]
    assert np.isinf(ell.values[-1]) and ell.stiffness is None
    radii = state.radii["enhanced"]
    assert np.all(np.isfinite(radii)) and radii[-1] == pytest.approx(3.0 * radii[1])
    legend = " ".join(item["text"] for item in viewer.overlay()["legend"])
    assert "k1, k2, k3 = [" in legend and ", inf] N/m" in legend


def test_sweep_animates_each_frames_ellipsoid(ur5):
    viewer = StiffnessViewer(ur5, UR5_KQ)
    path = np.tile(UR5_Q, (4, 1))
    path[:, 1] = np.linspace(-1.4, -0.8, 4)
    states = viewer.sweep(path, [0.0, 0.0, -200.0], "both", fps=8)
    assert len(states) == 4
    animation = [c for c in viewer.commands() if c["type"] == "set_animation"]
    assert len(animation) == 1
    clips = {a["path"]: a["clip"] for a in animation[0]["animations"]}
    clip = clips["/meshcat/stiffness/enhanced/surface"]
    tracks = {t["name"]: [k["value"] for k in t["keys"]] for t in clip["tracks"]}
    assert clip["fps"] == 8
    for k, row in enumerate(path):
        k_x = computed_stiffness(ur5, row, UR5_KQ, [0.0, 0.0, -200.0])["enhanced"]
        values = np.linalg.eigh(k_x)[0]
        np.testing.assert_allclose(tracks[".scale"][k], states[0].scale * values, rtol=1e-6)
        np.testing.assert_allclose(tracks[".position"][k], states[k].position, atol=1e-9)
    # the robot moves along the path too
    assert any(p.startswith("/meshcat/robot/visuals/") for p in clips)
    assert '"frames": {"fps": 8' in viewer.html()


def test_field_is_coloured_by_minimum_stiffness(ur5):
    viewer = StiffnessViewer(ur5, UR5_KQ)
    viewer.show(UR5_Q, [0.0, 0.0, -200.0])
    field = viewer.field(120, joints=["shoulder_lift_joint", "elbow_joint"], seed=3)
    assert len(field.positions) + field.skipped == 120 and len(field.positions) > 100
    commands = [c for c in viewer.commands() if c["path"].startswith("/meshcat/field/")]
    objects = [c for c in commands if c["type"] == "set_object"]
    assert len(objects) == len(field.positions)
    colors = np.array([c["object"]["materials"][0]["color"] for c in objects])
    order = np.argsort(field.min_stiffness)
    # viridis: the weakest dark purple, the stiffest bright yellow
    weakest, stiffest = colors[order[0]], colors[order[-1]]
    assert (weakest >> 16) < 0x60 and (stiffest >> 8 & 255) > 0xC0
    assert field.color_range == (field.min_stiffness.min(), field.min_stiffness.max())
    transforms = scene_transforms(commands)
    first = transforms["/meshcat/field/e0000"]
    np.testing.assert_allclose(first[:3, 3], field.positions[0])
    assert "ellipsoid field" in viewer.html()


# ---------------------------------------------------------------------------- static page


def test_static_page_is_self_contained(sk120_page):
    page = sk120_page[0].read_text()
    assert not re.search(r"<(script|link|img|iframe)[^>]+(src|href)=", page)
    assert "MeshCat.Viewer" in page


#: Fixes the canvas size (the viewports of --dump-dom and --screenshot runs differ), and drops
#: the scene's commands from the DOM once the page's script has loaded them: --dump-dom then
#: prints the page without them (a UR5 page: 9.8 MB -> 0.9 MB, 8.0 -> 6.8 s of chromium's CPU).
FIX_CANVAS = """
<script>
(function () { var resize = viewer.set_3d_pane_size.bind(viewer);
  viewer.set_3d_pane_size = function () { resize(CANVAS[0], CANVAS[1]); };
  viewer.set_3d_pane_size();
  var commands = document.getElementById("stiffness-commands");
  if (commands) { commands.remove(); } })();
</script>
""".replace("CANVAS", json.dumps(CANVAS))

PROBE = FIX_CANVAS + r"""
<script>
window.addEventListener("load", function () { setTimeout(function () {
  var out = {ready: document.body.getAttribute("data-stiffness-ready"), links: {}, ellipsoids: {},
             points: []};
  function node(path) { var n = viewer.scene_tree;
    for (var i = 0; i < path.length; i++) { n = n.children[path[i]]; if (!n) { return null; } }
    return n; }
  viewer.render();
  var visuals = node(["meshcat", "robot", "visuals"]);
  Object.keys(visuals ? visuals.children : {}).forEach(function (k) {
    var o = visuals.children[k].children["<object>"];
    out.links[k] = o ? o.object.type : null; });
  ["enhanced", "conventional"].forEach(function (f) {
    var n = node(["meshcat", "stiffness", f, "surface"]);
    if (n) { n.object.updateMatrix();
      out.ellipsoids[f] = {type: n.children["<object>"].object.type,
                           matrix: Array.from(n.object.matrix.elements)}; } });
  var W = viewer.renderer.domElement.clientWidth, H = viewer.renderer.domElement.clientHeight;
  POINTS.forEach(function (p) {
    var v = viewer.camera.position.clone().set(p[0], p[1], p[2]);
    viewer.scene.localToWorld(v); v.project(viewer.camera);
    out.points.push([(v.x + 1) / 2 * W, (1 - v.y) / 2 * H]); });
  var pre = document.createElement("pre"); pre.id = "probe"; pre.hidden = true;
  pre.textContent = JSON.stringify(out); document.body.appendChild(pre);
}, 300); });
</script>
""".replace("CANVAS", json.dumps(CANVAS))

#: Renders the scene once per variant, each with its own scene nodes hidden (VARIANTS: name ->
#: paths in the scene tree; the legend and labels hidden in all), and appends every canvas as a
#: PNG data URL to the page: the variants come from one browser run, not one run each.
RENDER_VARIANTS = FIX_CANVAS + """
<script>
window.addEventListener("load", function () { setTimeout(function () {
  ["stiffness-overlay", "stiffness-labels"].forEach(function (id) {
    var e = document.getElementById(id); if (e) { e.style.display = "none"; } });
  function node(path) { var n = viewer.scene_tree;
    path.forEach(function (p) { n = n && n.children[p]; }); return n; }
  var out = {};
  Object.keys(VARIANTS).forEach(function (key) {
    var hidden = VARIANTS[key].map(node).filter(function (n) { return n; });
    hidden.forEach(function (n) { n.object.visible = false; });
    viewer.render();
    out[key] = viewer.renderer.domElement.toDataURL("image/png");
    hidden.forEach(function (n) { n.object.visible = true; });
  });
  viewer.set_dirty();
  var pre = document.createElement("pre"); pre.id = "variants"; pre.hidden = true;
  pre.textContent = JSON.stringify(out); document.body.appendChild(pre);
}, 300); });
</script>
"""


def render_variants(page: str, variants: dict[str, list[list[str]]], folder: Path,
                    script: str = "", *extra: str) -> tuple[str, dict[str, np.ndarray]]:
    """The canvas pixels (H, W, 3) of ``page`` rendered with each variant's scene nodes hidden,
    all from one headless chromium run (``--dump-dom``, with ``extra`` flags), and the page's
    DOM after the run; ``script`` is added to the page after the variants' script."""
    import base64
    import html
    import io

    from PIL import Image

    extra_html = RENDER_VARIANTS.replace("VARIANTS", json.dumps(variants)) + script
    (folder / "variants.html").write_text(page.replace("</body>", extra_html + "</body>"))
    dom = run_chromium((folder / "variants.html").as_uri(), *OFFLINE_FLAGS, "--dump-dom", *extra)
    match = re.search(r'<pre id="variants"[^>]*>(.*?)</pre>', dom, re.S)
    assert match, "the variants were not rendered: the page did not load or WebGL failed"
    shots = {}
    for key, url in json.loads(html.unescape(match.group(1))).items():
        png = base64.b64decode(url.split(",", 1)[1])
        shots[key] = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=float)
    return dom, shots


def test_static_page_renders_in_headless_chromium(sk120_page, sk120, tmp_path):
    path, viewer, state = sk120_page
    page = path.read_text()
    robot_paths = [["meshcat", "robot"], ["meshcat", "deflected"]]
    ellipsoid_paths = [["meshcat", "stiffness", f] for f in FORMULATIONS]
    # probe points (meshcat world, m): link centres, then points inside each ellipsoid
    pin_points = [pose.position for name, pose in state.poses.items()
                  if name.startswith("robot/visuals/")]
    inside = {}
    for name in FORMULATIONS:
        ell, c, r = state.ellipsoids[name], state.centers[name], state.radii[name]
        inside[name] = [c + 0.55 * (np.cos(a) * r[2] * ell.directions[:, 2]
                                    + np.sin(a) * r[1] * ell.directions[:, 1])
                        for a in np.linspace(0.0, 2 * np.pi, 8, endpoint=False)]
    points = pin_points + inside["enhanced"] + inside["conventional"]
    probe = PROBE.replace("POINTS", json.dumps([list(map(float, p)) for p in points]))
    # three renderings from one browser run: everything, no robot, no ellipsoids (overlay
    # hidden); the probe (hidden output) runs in the same page, and the window's screenshot
    # is the canvas the user sees
    dom, variants = render_variants(
        page, {"all": [], "no_robot": robot_paths, "no_ellipsoids": ellipsoid_paths}, tmp_path,
        probe[len(FIX_CANVAS):], f"--screenshot={tmp_path / 'all.png'}")
    match = re.search(r'<pre id="probe"[^>]*>(.*?)</pre>', dom, re.S)
    assert match, "the probe did not run: the page did not load or WebGL failed"
    import html

    found = json.loads(html.unescape(match.group(1)))
    assert found["ready"] == "true"
    # the robot's links and the ellipsoids are in the browser's scene tree
    assert set(found["links"]) == {g.name for g in sk120.visual_model.geometryObjects}
    assert set(found["links"].values()) == {"Mesh"}
    k_x = computed_stiffness(sk120, state.coords, sk120.defaults["k_theta_SI"], state.wrench)
    for name in FORMULATIONS:
        assert found["ellipsoids"][name]["type"] == "Mesh"
        matrix = np.array(found["ellipsoids"][name]["matrix"]).reshape(4, 4).T
        assert_ellipsoid(matrix, k_x[name], state.scale)
    # pixels: hide the robot (resp. the ellipsoids) and the pixels where they project change
    window = png_pixels(tmp_path / "all.png")
    assert window.shape[:2] == (WINDOW[1], WINDOW[0])
    full = variants["all"]
    assert full.shape[:2] == (CANVAS[1], CANVAS[0])
    assert window.std() > 5, "blank window screenshot: WebGL did not render"
    assert full.std() > 5, "blank canvas: WebGL did not render"
    px = np.array(found["points"])

    def patch(image, p):
        x, y = int(round(p[0])), int(round(p[1]))
        assert 3 <= x < CANVAS[0] - 3 and 3 <= y < CANVAS[1] - 3, f"{p} is off screen"
        return image[y - 3:y + 4, x - 3:x + 4]

    def changed(a, b, p):
        return np.mean(np.abs(patch(a, p) - patch(b, p)).sum(axis=2) > 30) > 0.5

    n_links = len(pin_points)
    link_hits = [changed(full, variants["no_robot"], p) for p in px[:n_links]]
    assert np.mean(link_hits) >= 0.7, f"robot links not visible: {link_hits}"
    for i, name in enumerate(("enhanced", "conventional")):
        pts = px[n_links + 8 * i: n_links + 8 * (i + 1)]
        hits = [changed(full, variants["no_ellipsoids"], p) for p in pts]
        assert np.mean(hits) >= 0.5, f"{name} ellipsoid not visible: {hits}"
        # its colour: orange (red over blue) for enhanced, blue for conventional
        shift = np.mean([patch(full, p).mean(axis=(0, 1)) - patch(
            variants["no_ellipsoids"], p).mean(axis=(0, 1)) for p, h in zip(pts, hits,
                                                                            strict=True) if h],
            axis=0)
        sign = 1.0 if name == "enhanced" else -1.0
        assert sign * (shift[0] - shift[2]) > 15, f"{name} colour shift {shift}"


SEEK_PROBE = r"""
<script>
window.addEventListener("load", function () { setTimeout(function () {
  var out = [], n = viewer.scene_tree.children.meshcat.children.stiffness.children.enhanced
    .children.surface;
  TIMES.forEach(function (t) {
    viewer.animator.pause(); viewer.animator.seek(t); n.object.updateMatrix();
    out.push(Array.from(n.object.matrix.elements)); });
  var pre = document.createElement("pre"); pre.id = "probe";
  pre.textContent = JSON.stringify({actions: viewer.animator.actions.length, matrices: out});
  document.body.appendChild(pre);
}, 300); });
</script>
"""


def test_sweep_plays_on_the_browsers_timeline(sk120, tmp_path):
    """The exported sweep loads into meshcat's animator; each frame's time shows its ellipsoid."""
    viewer = StiffnessViewer(sk120, sk120.defaults["k_theta_SI"])
    path = np.tile(np.deg2rad(sk120.defaults["q_deg"]), (3, 1))
    path[:, 1] += np.deg2rad([-15.0, 0.0, 15.0])
    states = viewer.sweep(path, fps=4)
    page = viewer.html().replace("</body>", SEEK_PROBE.replace(
        "TIMES", json.dumps([k / 4 for k in range(3)])) + "</body>")
    (tmp_path / "sweep.html").write_text(page)
    dom = run_chromium((tmp_path / "sweep.html").as_uri(), *OFFLINE_FLAGS, "--dump-dom")
    match = re.search(r'<pre id="probe">(.*?)</pre>', dom, re.S)
    assert match, "the page or its animation did not load"
    import html

    found = json.loads(html.unescape(match.group(1)))
    assert found["actions"] > 10  # robot links, deflected robot, ellipsoids, arrow
    for k, row in enumerate(path):
        k_x = computed_stiffness(sk120, row, sk120.defaults["k_theta_SI"], states[k].wrench)
        matrix = np.array(found["matrices"][k]).reshape(4, 4).T
        assert_ellipsoid(matrix, k_x["enhanced"], states[0].scale, states[k].position)


# ----------------------------------------------------------------------------- live server


class DevTools:
    """Headless chromium on ``url``, driven over the DevTools protocol (no new dependency)."""

    def __init__(self, url: str, timeout: float = 30.0) -> None:
        import tornado.websocket

        self.profile = tempfile.TemporaryDirectory(ignore_cleanup_errors=True)
        self.process = subprocess.Popen(
            [chromium(), *CHROMIUM_FLAGS, f"--user-data-dir={self.profile.name}",
             "--remote-debugging-port=0", url],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        port_file = Path(self.profile.name) / "DevToolsActivePort"
        deadline = time.monotonic() + timeout
        while not (port_file.exists() and port_file.read_text().strip()):
            assert time.monotonic() < deadline, "chromium's DevTools did not start"
            time.sleep(0.05)
        port = int(port_file.read_text().split()[0])
        targets = json.load(urllib.request.urlopen(f"http://127.0.0.1:{port}/json", timeout=10))
        page = next(t for t in targets if t["type"] == "page")
        async def connect():
            return await tornado.websocket.websocket_connect(page["webSocketDebuggerUrl"],
                                                             max_message_size=2**28)

        self.loop = asyncio.new_event_loop()
        self.conn = self.loop.run_until_complete(connect())
        self.calls = 0

    async def _call(self, method: str, params: dict) -> dict:
        self.calls += 1
        await self.conn.write_message(json.dumps({"id": self.calls, "method": method,
                                                  "params": params}))
        while True:
            message = json.loads(await self.conn.read_message())
            if message.get("id") == self.calls:
                return message

    def evaluate(self, expression: str):
        """Value of a JavaScript expression in the page."""
        reply = self.loop.run_until_complete(asyncio.wait_for(self._call(
            "Runtime.evaluate", {"expression": expression, "returnByValue": True}), 20))
        result = reply["result"]
        assert "exceptionDetails" not in result, result
        return result["result"].get("value")

    def wait_for(self, expression: str, timeout: float = 20.0):
        """Wait until ``expression`` is truthy (errors, e.g. while loading, count as false)."""
        guarded = ("(function () { try { return " + expression
                   + "; } catch (e) { return null; } })()")
        deadline = time.monotonic() + timeout
        while not (value := self.evaluate(guarded)):
            assert time.monotonic() < deadline, f"timed out waiting for {expression}"
            time.sleep(0.1)
        return value

    def close(self) -> None:
        self.conn.close()
        self.loop.close()
        with contextlib.suppress(ProcessLookupError):  # chromium and its helper processes
            os.killpg(self.process.pid, signal.SIGTERM)
        self.process.wait(timeout=10)
        self.profile.cleanup()


#: JavaScript: local 4x4 transform (column-major) of a scene node, or null.
NODE_MATRIX = """(function (path) { var n = viewer.scene_tree;
  for (var i = 0; i < path.length; i++) { n = n.children[path[i]]; if (!n) { return null; } }
  n.object.updateMatrix(); return Array.from(n.object.matrix.elements); })(PATH)"""


def browser_matrix(browser: DevTools, path: list[str]) -> np.ndarray | None:
    value = browser.evaluate(NODE_MATRIX.replace("PATH", json.dumps(path)))
    return None if value is None else np.array(value).reshape(4, 4).T


@pytest.fixture(scope="module")
def live_sk120(sk120):
    """A live SK120 viewer (its server process stopped at the end of the module)."""
    viewer = StiffnessViewer(sk120, sk120.defaults["k_theta_SI"], live=True)
    viewer.show()
    yield viewer
    process = viewer.server.process
    viewer.close()
    assert process.poll() is not None, "the server outlived the viewer"


def test_live_server_listens_on_loopback_only(live_sk120):
    server = live_sk120.server
    assert server.web_url.startswith(f"http://{LOOPBACK}:")
    web_port = int(server.web_url.rsplit(":", 1)[1].strip("/"))
    zmq_port = int(server.zmq_url.rsplit(":", 1)[1])
    # its listening sockets: both ports, 127.0.0.1 only
    if Path("/proc/net/tcp").exists():
        listening = listening_sockets(server.process.pid)
        assert {port for _, port in listening} == {web_port, zmq_port}
        assert {ip for ip, _ in listening} == {LOOPBACK}
    assert not refused(LOOPBACK, web_port)
    page = urllib.request.urlopen(server.web_url, timeout=10).read().decode()
    assert 'data-live="true"' in page and "/static/main.min.js" in page
    ip = non_loopback_ipv4()
    if ip is None:
        pytest.skip("this machine has no non-loopback IPv4 address to try the ports on")
    assert refused(ip, web_port) and refused(ip, zmq_port)


def test_live_page_browsed_from_chromium(live_sk120, sk120):
    viewer, state = live_sk120, live_sk120.state
    server = viewer.server
    browser = DevTools(server.web_url)
    try:
        # the page connects and receives the scene, the ellipsoid as computed
        browser.wait_for("+document.body.getAttribute('data-received') > 20")
        assert viewer.wait_for_browser(timeout=5.0)
        assert browser.evaluate("document.getElementById('stiffness-status').textContent"
                                ) == "live: connected"
        links = browser.evaluate(
            "Object.keys(viewer.scene_tree.children.meshcat.children.robot"
            ".children.visuals.children)")
        assert set(links) == {g.name for g in sk120.visual_model.geometryObjects}
        k_x = computed_stiffness(sk120, state.coords, sk120.defaults["k_theta_SI"],
                                 state.wrench)
        for name in FORMULATIONS:
            matrix = browser_matrix(browser, ["meshcat", "stiffness", name, "surface"])
            assert_ellipsoid(matrix, k_x[name], state.scale)
        # browse: move joint2 by 10 deg, triple the load, show only the enhanced ellipsoid
        sliders = browser.evaluate(
            "document.querySelectorAll('#stiffness-overlay input[type=range]').length")
        assert sliders == sk120.n_coordinates + 3
        joint2 = float(np.rad2deg(state.coords[1])) + 10.0
        magnitude = 3.0 * float(np.linalg.norm(state.wrench[:3]))
        browser.evaluate(f"""(function () {{
          var s = document.querySelectorAll('#stiffness-overlay input[type=range]');
          s[1].value = {joint2}; s[1].dispatchEvent(new Event('input'));
          s[{sk120.n_coordinates}].value = {magnitude};
          s[{sk120.n_coordinates}].dispatchEvent(new Event('input'));
          var f = document.querySelector('#stiffness-overlay select');
          f.value = 'enhanced'; f.dispatchEvent(new Event('change')); }})()""")
        deadline = time.monotonic() + 10
        while viewer.poll() == 0:
            assert time.monotonic() < deadline, "the page's controls never arrived"
            time.sleep(0.05)
        new = viewer.state
        assert tuple(new.ellipsoids) == ("enhanced",)
        assert np.rad2deg(new.coords[1]) == pytest.approx(joint2, abs=0.051)
        assert np.linalg.norm(new.wrench[:3]) == pytest.approx(magnitude, rel=0.01)
        k_x = computed_stiffness(sk120, new.coords, sk120.defaults["k_theta_SI"],
                                 new.wrench)["enhanced"]
        browser.wait_for("!viewer.scene_tree.children.meshcat.children.stiffness"
                         ".children.conventional.object.visible")
        deadline = time.monotonic() + 10
        while True:  # the browser's scene follows
            matrix = browser_matrix(browser, ["meshcat", "stiffness", "enhanced", "surface"])
            try:
                assert_ellipsoid(matrix, k_x, state.scale, new.position)
                break
            except AssertionError:
                assert time.monotonic() < deadline, "the browser's scene did not follow"
                time.sleep(0.1)
    finally:
        browser.close()


def test_server_requests_time_out_and_recover():
    with LiveServer(timeout=5.0) as server:
        assert server.clients() == 0
        assert server.wait_for_browser(timeout=0.3) is False
        os.kill(server.process.pid, signal.SIGSTOP)
        try:
            start = time.monotonic()
            with pytest.raises(StiffnessError, match="did not answer within 0.5 s"):
                server.request([b"clients"], timeout=0.5)
            assert time.monotonic() - start < 3.0
        finally:
            os.kill(server.process.pid, signal.SIGCONT)
        assert server.clients() == 0  # the command socket was reset and works again
        web_port = int(server.web_url.rsplit(":", 1)[1].strip("/"))
    assert server.process.poll() is not None
    assert refused(LOOPBACK, web_port)


OWNER = """
import os, sys
from stiffness.viewer import LiveServer
server = LiveServer()
print(server.process.pid, server._log_path, flush=True)
os._exit(0) if sys.argv[1] == "killed" else None
"""


@pytest.mark.parametrize("ending", ["killed", "normal"])
def test_server_stops_with_its_owner(ending):
    """Normal exit: atexit stops it; killed owner (no atexit): it stops itself."""
    owner = subprocess.run([sys.executable, "-c", OWNER, ending], capture_output=True,
                           text=True, timeout=60, check=True)
    pid, log = owner.stdout.split()
    deadline = time.monotonic() + 10
    while Path(f"/proc/{pid}").exists() and "Z" not in _state(int(pid)):
        assert time.monotonic() < deadline, f"server {pid} still running after its owner"
        time.sleep(0.1)
    assert not Path(log).exists(), "the server's log file was left behind"


def _state(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0]
    except OSError:
        return "gone"


# ----------------------------------------------------------------------------- CLI, imports


def test_cli_export(tmp_path, capsys):
    out = tmp_path / "ur5.html"
    code = cli_main(["view", "--robot", "ur5", "--frame", "tool0", "--q",
                     ",".join(map(str, UR5_Q)), "--wrench", "0,0,-200", "--kq",
                     ",".join(map(str, UR5_KQ)), "--formulation", "conventional",
                     "--quantity", "compliance", "--export", str(out)])
    assert code == 0 and out.is_file()
    assert "self-contained" in capsys.readouterr().out
    transforms = scene_transforms(scene_commands(out.read_text()))
    k_x = computed_stiffness(load_robot("ur5", frame="tool0"), UR5_Q, UR5_KQ,
                             [0.0, 0.0, -200.0])["conventional"]
    matrix = transforms["/meshcat/stiffness/conventional/surface"]
    c_values = np.linalg.eigvalsh(np.linalg.inv(k_x))
    radii = np.linalg.norm(matrix[:3, :3], axis=0)
    np.testing.assert_allclose(radii / c_values, radii[0] / c_values[0], rtol=1e-6)


def test_cli_sweep_and_errors(tmp_path, capsys):
    out = tmp_path / "sweep.html"
    assert cli_main(["view", "--robot", "sk120", "--deg", "--sweep", "joint2=0:30:5",
                     "--export", str(out)]) == 0
    assert '"frames": {"fps": 10.0' in out.read_text()
    assert cli_main(["view", "--robot", "sk120", "--sweep", "joint9=0:1",
                     "--export", str(out)]) == 2
    assert "joint9" in capsys.readouterr().err
    assert cli_main(["view", "--robot", "sk120", "--sweep", "joint2=0", "--export",
                     str(out)]) == 2
    assert "JOINT=START:STOP" in capsys.readouterr().err


@pytest.mark.parametrize(("flag", "value", "words"), [
    ("--port", "99999", "--port must be a TCP port, 1 to 65535"),  # was a free port, silently
    ("--size", "-0.1", "--size must be a positive radius in m, got -0.1"),
    ("--fps", "0", "--fps must be a positive number of frames per second"),
    ("--field", "0", "--field must be at least 1, got 0"),  # was 'the loops cannot close'
    ("--duration", "-1", "--duration must be 0 or more seconds"),
])
def test_cli_refuses_impossible_viewer_settings_before_the_work(capsys, flag, value, words):
    assert cli_main(["view", "--robot", "nowhere", flag, value]) == 2  # before the robot
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1


def test_cli_live_serves_for_its_duration():
    cli = subprocess.run([sys.executable, "-m", "stiffness.cli.main", "view", "--robot", "sk120",
                          "--duration", "0.5"], capture_output=True, text=True, timeout=60)
    assert cli.returncode == 0, cli.stderr
    url = re.search(r"(http://127\.0\.0\.1:(\d+)/)", cli.stdout)
    assert url and "this machine only" in cli.stdout
    assert refused(LOOPBACK, int(url.group(2)))  # stopped on exit


def test_import_keeps_warnings_local():
    """meshcat's zmq DeprecationWarning does not escape, even with warnings as errors."""
    code = ("import warnings; warnings.simplefilter('error')\n"
            "from stiffness.viewer.deps import meshcat_modules, pinocchio_meshcat_visualizer\n"
            "meshcat_modules(); pinocchio_meshcat_visualizer()\n"
            "try:\n"
            "    warnings.warn('still an error', DeprecationWarning)\n"
            "except DeprecationWarning:\n"
            "    pass\n"
            "else:\n"
            "    raise SystemExit('DeprecationWarning silenced globally')\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 0, result.stderr


# ------------------------------------------------------------------ legible labels and floor

LABEL_PROBE = FIX_CANVAS + r"""
<script>
window.addEventListener("load", function () { setTimeout(function () {
  viewer.render();
  var canvas = viewer.renderer.domElement.getBoundingClientRect();
  var W = canvas.width, H = canvas.height;
  function screen(p) {
    var v = viewer.camera.position.clone().set(p[0], p[1], p[2]);
    viewer.scene.localToWorld(v); v.project(viewer.camera);
    return [canvas.left + (v.x + 1) / 2 * W, canvas.top + (1 - v.y) / 2 * H, v.z];
  }
  var labels = Array.from(document.querySelectorAll(".stiffness-label")).filter(function (e) {
    return getComputedStyle(e).display !== "none"; }).map(function (e) {
    var r = e.getBoundingClientRect();
    return {text: e.textContent, l: r.left, t: r.top, r: r.right, b: r.bottom}; });
  var o = document.getElementById("stiffness-overlay").getBoundingClientRect();
  var plate = viewer.scene_tree.children.meshcat.children.floor.children.plate;
  var box = plate.children["<object>"].object;
  box.geometry.computeBoundingBox(); box.updateWorldMatrix(true, false);
  var bb = box.geometry.boundingBox, floor = [];
  for (var i = 0; i <= 10; i++) { for (var j = 0; j <= 10; j++) {
    var v = bb.min.clone();
    v.x = bb.min.x + (bb.max.x - bb.min.x) * i / 10;
    v.y = bb.min.y + (bb.max.y - bb.min.y) * j / 10;
    v.z = bb.max.z;
    v.applyMatrix4(box.matrixWorld); v.project(viewer.camera);
    floor.push([canvas.left + (v.x + 1) / 2 * W, canvas.top + (1 - v.y) / 2 * H, v.z]); } }
  var bodies = [], stiff = viewer.scene_tree.children.meshcat.children.stiffness;
  ["enhanced", "conventional"].forEach(function (f) {
    var n = stiff && stiff.children[f] && stiff.children[f].children.surface;
    if (!n || !n.object.visible) { return; }
    n.object.updateWorldMatrix(true, false);
    var v = viewer.camera.position.clone().setFromMatrixPosition(n.object.matrixWorld);
    v.project(viewer.camera);
    bodies.push([canvas.left + (v.x + 1) / 2 * W, canvas.top + (1 - v.y) / 2 * H, v.z]); });
  var pre = document.createElement("pre"); pre.id = "probe";
  pre.textContent = JSON.stringify({labels: labels, robot: ROBOT.map(screen), floor: floor,
    ellipsoids: bodies,
    canvas: [canvas.left, canvas.top, canvas.right, canvas.bottom],
    legend: [o.left, o.top, o.right, o.bottom], title: document.title});
  document.body.appendChild(pre);
}, 1500); });
</script>
""".replace("CANVAS", json.dumps(CANVAS))


def robot_points(robot, q, per_link: int = 6) -> list[list[float]]:
    """Points along the robot's skeleton (joint origins and between parent and child), m."""
    import pinocchio as pin

    model, data = robot.model, robot.data
    pin.forwardKinematics(model, data, q)
    points = []
    for j in range(1, model.njoints):
        a, b = data.oMi[int(model.parents[j])].translation, data.oMi[j].translation
        points += [list(map(float, a + (b - a) * t)) for t in np.linspace(0, 1, per_link)]
    return points


def rendered_layout(page: Path, robot, q, tmp_path: Path) -> dict:
    probe = LABEL_PROBE.replace("ROBOT", json.dumps(robot_points(robot, q)))
    probe_page = tmp_path / f"{page.stem}-probe.html"
    probe_page.write_text(page.read_text().replace("</body>", probe + "</body>"))
    dom = run_chromium(probe_page.as_uri(), *OFFLINE_FLAGS, "--dump-dom")
    match = re.search(r'<pre id="probe">(.*?)</pre>', dom, re.S)
    assert match, "the probe did not run: the page did not load or WebGL failed"
    import html

    return json.loads(html.unescape(match.group(1)))


def overlap(a: dict, b: dict) -> bool:
    return a["l"] < b["r"] and b["l"] < a["r"] and a["t"] < b["b"] and b["t"] < a["b"]


@pytest.mark.parametrize("case", ["hexapod", "ur5-unloaded"])
def test_labels_never_overlap_and_the_floor_is_in_frame(case, tmp_path, capsys):
    """Measured in the rendered page: label rectangles disjoint, off the legend, the robot's
    skeleton and the ellipsoids' centres, inside the canvas; the floor plate under the robot
    inside the frame. The UR5 is drawn without --wrench: the unloaded stiffness, said on the
    terminal and the page."""
    out = tmp_path / f"{case}.html"
    if case == "hexapod":
        argv, robot = ["view", "--robot", "hexapod"], load_robot("hexapod")
        coords = np.asarray(robot.defaults["q_SI"], dtype=float)
    else:
        argv = ["view", "--robot", "ur5", "--frame", "tool0", "--q", ",".join(map(str, UR5_Q)),
                "--kq", ",".join(map(str, UR5_KQ))]
        robot, coords = load_robot("ur5", frame="tool0"), np.asarray(UR5_Q)
    assert cli_main([*argv, "--export", str(out)]) == 0
    said = capsys.readouterr().out
    page = out.read_text()
    overlay = page_overlay(page)
    if case == "ur5-unloaded":
        assert "unloaded stiffness" in said
        assert any("no load" in line for line in overlay["lines"])
        transforms = scene_transforms(scene_commands(page))
        k_x = computed_stiffness(robot, coords, UR5_KQ, [0.0, 0.0, 0.0])
        scale = np.linalg.norm(transforms["/meshcat/stiffness/enhanced/surface"][:3, 0]) / \
            np.linalg.eigvalsh(k_x["enhanced"])[0]
        assert_ellipsoid(transforms["/meshcat/stiffness/enhanced/surface"], k_x["enhanced"],
                         scale)
        np.testing.assert_allclose(k_x["enhanced"], k_x["conventional"])
    layout = rendered_layout(out, robot, robot.configuration(coords), tmp_path)
    assert "/" not in layout["title"] and layout["title"].startswith(robot.name)
    labels = layout["labels"]
    assert len(labels) >= 4, labels  # names and most axis labels find a place
    left, top, right, bottom = layout["canvas"]
    legend = dict(zip("ltrb", layout["legend"], strict=True))
    for i, a in enumerate(labels):
        assert left <= a["l"] and a["r"] <= right and top <= a["t"] and a["b"] <= bottom, a
        assert not overlap(a, legend), a
        for b in labels[i + 1:]:
            assert not overlap(a, b), (a, b)
        for x, y, z in layout["robot"] + layout["ellipsoids"]:
            if -1 < z < 1:
                assert not (a["l"] < x < a["r"] and a["t"] < y < a["b"]), (a, (x, y))
    assert layout["ellipsoids"], "no ellipsoid in the scene"
    floor = np.array(layout["floor"])
    inside = ((floor[:, 0] > left) & (floor[:, 0] < right) & (floor[:, 1] > top)
              & (floor[:, 1] < bottom) & (np.abs(floor[:, 2]) < 1))
    assert inside.mean() > 0.2, f"floor mostly outside the frame ({inside.mean():.0%} inside)"
    robot_y = np.array([y for _, y, z in layout["robot"] if -1 < z < 1])
    assert np.median(floor[inside, 1]) > np.min(robot_y), "floor not under the robot"


def test_page_title_is_the_robots_name_not_its_path():
    from stiffness.robot.sources import robots_directory

    robot = load_robot(robots_directory() / "sk120" / "sk120.urdf", frame="fixture_target",
                       compliant_joints=["joint1", "joint2", "joint3"])
    viewer = StiffnessViewer(robot, [1e6, 4e5, 9e5])
    viewer.show(np.deg2rad(load_robot("sk120").defaults["q_deg"]), [0.0, 0.0, -100.0])
    title = re.search(r"<title>(.*?)</title>", viewer.html()).group(1)
    assert "/" not in title and ".urdf" not in title
    assert title.startswith(robot.model.name) and viewer.overlay()["title"].startswith(
        robot.model.name)


def test_rotational_block_of_the_six_by_six_stiffness():
    """Hexapod (six compliant legs): the rotational 3x3 block of K_X = C6^-1, in N.m/rad, drawn
    hidden beside the target with its own scale and a toggle; none for a 3-joint SK120."""
    robot = load_robot("hexapod")
    k_theta = np.asarray(robot.defaults["k_theta_SI"], dtype=float)
    coords = np.asarray(robot.defaults["q_SI"], dtype=float)
    wrench = np.asarray(robot.defaults["wrench_SI"], dtype=float)
    viewer = StiffnessViewer(robot, k_theta)
    state = viewer.show(coords, wrench, "enhanced")
    target = target_state(robot, robot.configuration(coords), wrench)
    tangent = tangent_joint_stiffness(np.diag(k_theta), target.k_c, "enhanced")
    k6 = np.linalg.inv(compliance(target.jacobian, tangent))
    block = 0.5 * (k6[3:, 3:] + k6[3:, 3:].T)
    np.testing.assert_allclose(state.rotational.values, np.linalg.eigvalsh(block), rtol=1e-8)
    assert state.rotational.units == "N.m/rad"
    transforms = scene_transforms(viewer.commands())
    radii = np.linalg.norm(transforms["/meshcat/rotational/surface"][:3, :3], axis=0)
    np.testing.assert_allclose(radii / radii.max(), state.rotational.values
                               / state.rotational.values.max(), rtol=1e-8)
    assert radii.max() == pytest.approx(viewer.size)
    overlay = viewer.overlay()
    assert {"label": "rotational stiffness (N.m/rad)", "path": ["meshcat", "rotational"]} in \
        overlay["toggles"]
    hidden = [c for c in viewer.commands() if c["type"] == "set_property"
              and c["path"] == "/meshcat/rotational" and c["property"] == "visible"]
    assert hidden and hidden[-1]["value"] is False
    sk120 = load_robot("sk120")
    assert StiffnessViewer(sk120, sk120.defaults["k_theta_SI"]).show().rotational is None
