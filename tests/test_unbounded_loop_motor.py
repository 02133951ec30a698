"""A closed loop whose unbounded prismatic motor assembles only far from zero.

Gepetto's wl16 leg (example-parallel-robots) has prismatic motors with ``<limit>`` but no
``lower``/``upper``: its zero pose does not close, and the assembly found near it has the motors
near -0.3 m. ``simulate`` and ``design`` drew their poses around zero (the loop box) within the
fallback range 0..0.1 m of an unbounded prismatic joint, where no pose closes continuously from
that assembly: "found only 0 of 4 reachable poses ... check the joint limits" after 71 s. Here
the same on a slider-crank whose slider reaches only [-1 - sqrt(0.55), -1 + sqrt(0.55)] m.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import stiffness
from stiffness.calibration.poses import sample_coordinates
from stiffness.mechanics.defaults import assembly_coordinates

_URDF = """<?xml version="1.0"?>
<robot name="slider_crank">
<link name="base_link"/><link name="plane"/><link name="slider"/><link name="crank"/>
<link name="rod"/><link name="rod_end"/><link name="tool_tip"/>
<joint name="mount" type="fixed"><parent link="base_link"/><child link="plane"/>
 <origin xyz="0 0 0.3" rpy="0 0 0"/></joint>
<joint name="slide" type="prismatic"><parent link="plane"/><child link="slider"/>
 <origin xyz="0 0 0" rpy="0 0 0"/><axis xyz="1 0 0"/><limit effort="100" velocity="1"/></joint>
<joint name="crank_joint" type="revolute"><parent link="plane"/><child link="crank"/>
 <origin xyz="-1.0 0.3 0" rpy="0 0 0"/><axis xyz="0 0 1"/>
 <limit effort="100" velocity="2" lower="-6.3" upper="6.3"/></joint>
<joint name="elbow_joint" type="revolute"><parent link="crank"/><child link="rod"/>
 <origin xyz="0.4 0 0" rpy="0 0 0"/><axis xyz="0 0 1"/>
 <limit effort="100" velocity="2" lower="-6.3" upper="6.3"/></joint>
<joint name="rod_end_joint" type="fixed"><parent link="rod"/><child link="rod_end"/>
 <origin xyz="0.4 0 0" rpy="0 0 0"/></joint>
<joint name="tool_joint" type="fixed"><parent link="rod"/><child link="tool_tip"/>
 <origin xyz="0.2 0.05 0" rpy="0 0 0"/></joint>
</robot>
"""
#: The slider at (s, 0) is reached by the two 0.4 m links from the pivot (-1, 0.3): s in this.
_REACH = (-1.0 - math.sqrt(0.8 ** 2 - 0.3 ** 2), -1.0 + math.sqrt(0.8 ** 2 - 0.3 ** 2))


#: Its <limit> without lower and upper is noted on every load.
pytestmark = pytest.mark.filterwarnings("ignore::stiffness.errors.RobotFileNote")


@pytest.fixture(scope="module")
def slider_crank(tmp_path_factory):
    folder = tmp_path_factory.mktemp("slider")
    (folder / "slider.urdf").write_text(_URDF)
    (folder / "slider.loops.yaml").write_text(
        'closed_loop:\n  - [slider, rod_end]\ntype: ["3D"]\nname_mot: [slide]\n')
    return folder / "slider.urdf"


def test_poses_are_drawn_about_the_assembly_not_zero(slider_crank):
    robot = stiffness.load_robot(str(slider_crank), frame="tool_tip")
    ref = assembly_coordinates(robot)
    assert _REACH[0] < ref[0] < _REACH[1]  # the zero pose does not close: s = 0 is out of reach
    coords = sample_coordinates(robot, 5, np.random.default_rng(3))
    assert coords.shape == (5, 1)
    assert np.all((coords[:, 0] > _REACH[0]) & (coords[:, 0] < _REACH[1]))
    assert np.abs(coords[:, 0] - ref[0]).max() > 1e-4  # drawn, not the reference repeated


def test_simulated_campaign_identifies_the_true_spring(slider_crank, tmp_path):
    sim = stiffness.simulate(str(slider_crank), kq=[4e4], configs=3, max_force=20.0,
                             noise_std_m=5e-6, seed=1, frame="tool_tip")
    sim.write(tmp_path / "camp")
    ident = stiffness.identify(tmp_path / "camp", starts=1)
    assert ident.ci95_low[0] < 4e4 < ident.ci95_high[0]
    assert ident.ci95_high[0] / ident.ci95_low[0] < 1.1  # determined, not a vacuous interval
