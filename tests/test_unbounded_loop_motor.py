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


def test_design_judges_folds_against_the_assembly(slider_crank):
    """design keeps poses whose fold ratio is at least 0.1 of the reference assembly's; with
    no assembly at zero it took an absolute 1 as that reference and refused every pose of
    Gepetto's wl16 leg (fold ratios about 0.003): "found only 0 of 30 reachable poses away
    from singularities and folds". The plan's slider positions lie in its reach."""
    robot = stiffness.load_robot(str(slider_crank), frame="tool_tip")
    plan = stiffness.design(robot, 2, 20.0, loads_per_config=2, candidates=6, k=[4e4],
                            random_plans=2)
    coords = np.array(plan.plan.q)[:, 0]
    assert np.all((coords > _REACH[0]) & (coords < _REACH[1]))


def test_the_fold_reference_is_the_assemblys(slider_crank):
    """The fold ratio design's margin is relative to: sigma_min / sigma_max of the closure
    Jacobian's passive columns at the reference assembly, here in closed form (the rod end
    pivot + 0.4 (c1, s1) + 0.4 (c12, s12) differentiated in the crank and elbow angles). With
    the zero pose out of reach it was an absolute 1 (wl16: every pose refused)."""
    from stiffness.calibration.poses import _reference_fold_ratio

    robot = stiffness.load_robot(str(slider_crank), frame="tool_tip")
    q = robot.configuration(assembly_coordinates(robot))
    model = robot.model
    t1 = q[model.joints[model.getJointId("crank_joint")].idx_q]
    t12 = t1 + q[model.joints[model.getJointId("elbow_joint")].idx_q]
    jac = 0.4 * np.array([[-np.sin(t1) - np.sin(t12), -np.sin(t12)],
                          [np.cos(t1) + np.cos(t12), np.cos(t12)]])
    sv = np.linalg.svd(jac, compute_uv=False)
    assert _reference_fold_ratio(robot) == pytest.approx(sv[1] / sv[0], rel=1e-9)


@pytest.fixture(scope="module")
def slider_crank_wrist(tmp_path_factory):
    """The slider-crank with a wrist joint (outside the loop) carrying the tool: two
    coordinates, slide and wrist."""
    folder = tmp_path_factory.mktemp("slider-wrist")
    urdf = _URDF.replace('<link name="tool_tip"/>', '<link name="hand"/><link name="tool_tip"/>')
    urdf = urdf.replace(
        '<joint name="tool_joint" type="fixed"><parent link="rod"/><child link="tool_tip"/>',
        '<joint name="wrist" type="revolute"><parent link="rod"/><child link="hand"/>'
        '<origin xyz="0.2 0.05 0" rpy="0 0 0"/><axis xyz="0 0 1"/>'
        '<limit effort="100" velocity="2" lower="-3" upper="3"/></joint>'
        '<joint name="tool_joint" type="fixed"><parent link="hand"/><child link="tool_tip"/>')
    urdf = urdf.replace('<origin xyz="0.2 0.05 0" rpy="0 0 0"/></joint>\n</robot>',
                        '<origin xyz="0.1 0 0" rpy="0 0 0"/></joint>\n</robot>')
    (folder / "arm.urdf").write_text(urdf)
    (folder / "arm.loops.yaml").write_text(
        'closed_loop:\n  - [slider, rod_end]\ntype: ["3D"]\nname_mot: [slide, wrist]\n')
    return folder / "arm.urdf"


def test_scan_holds_the_other_coordinates_at_the_assembly(slider_crank_wrist, tmp_path, capsys):
    """scan --axis wrist without --q held the slider at 0 m, out of its reach
    [-1.74, -0.26] m: every configuration invalid, and the summary still said "K_theta - K_C
    positive definite everywhere: True". Now the slider stays at the assembly and all are
    valid; a sweep out of reach says there is nothing to judge."""
    from stiffness.cli.main import main

    robot = stiffness.load_robot(str(slider_crank_wrist), frame="tool_tip")
    assert set(robot.coordinate_joints) == {"slide", "wrist"}
    kq = ",".join("4e4" if j == "slide" else "2e3" for j in robot.compliant_joints)
    args = ["scan", "--robot", str(slider_crank_wrist), "--frame", "tool_tip", "--kq", kq,
            "--wrench", "0,10,0", "--workers", "1", "--no-plots"]
    assert main([*args, "--axis", "wrist=0:0.2:0.1", "--out", str(tmp_path / "a")]) == 0
    out = capsys.readouterr().out
    slide = assembly_coordinates(robot)[robot.coordinate_joints.index("slide")]
    assert _REACH[0] < slide < _REACH[1] and f"slide={slide:g}" in out
    assert "(3 valid)" in out and "positive definite everywhere: True" in out
    assert main([*args, "--axis", "slide=0:0.02:0.01", "--out", str(tmp_path / "b")]) == 0
    out = capsys.readouterr().out
    assert "(0 valid)" in out and "everywhere" not in out and "nothing to judge" in out
