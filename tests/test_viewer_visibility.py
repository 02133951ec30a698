"""The default scene shows its ellipsoid (issue 30, item 7's check), rendered in headless
Chromium: in the default UR5 and Panda scenes, the part of the enhanced ellipsoid's screen area
that robot meshes do not cover is at least half of its area.

The ellipsoid's area: pixels that change when it is hidden, with the robot hidden; its
uncovered area: the same with the robot shown (the four renderings of a scene come from one
browser run). Skipped without chromium.
"""

from __future__ import annotations

import contextlib
import io

import numpy as np
import pytest
from test_viewer import render_variants

from stiffness.cli.main import main

#: The scenes: the issue's UR5 and the Panda at its reference posture, 200 N down.
SCENES = {
    "ur5": ["--kq", "3e5,3e5,2e5,4e4,4e4,4e4", "--q", "0,-1.2,1.5,-0.3,1.57,0"],
    "panda": ["--kq", "1e5,1e5,1e5,1e5,1e4,1e4,1e4"],
}
ROBOT = [["meshcat", "robot"], ["meshcat", "deflected"]]
ENHANCED = [["meshcat", "stiffness", "enhanced"]]


def changed(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pixels that differ between two renderings (summed RGB difference above 30)."""
    return np.abs(a - b).sum(axis=2) > 30


@pytest.mark.parametrize("name", sorted(SCENES))
def test_default_scene_shows_most_of_the_ellipsoid(name, tmp_path):
    page = tmp_path / "scene.html"
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["view", "--robot", name, *SCENES[name], "--wrench", "0,0,-200",
                     "--export", str(page)]) == 0
    _, shots = render_variants(page.read_text(), {
        "robot": ROBOT, "robot_no_ell": ROBOT + ENHANCED, "all": [], "no_ell": ENHANCED},
        tmp_path)
    area = changed(shots["robot"], shots["robot_no_ell"]).sum()
    uncovered = changed(shots["all"], shots["no_ell"]).sum()
    assert area > 200, f"the ellipsoid covers only {area} pixels: the scene is not framed on it"
    assert uncovered >= 0.5 * area, f"{uncovered} of {area} ellipsoid pixels visible"

