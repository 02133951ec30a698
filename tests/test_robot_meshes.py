"""Visual meshes: ``package://``, ``package:///`` and relative paths resolved from the URDF's
folder, ``ROS_PACKAGE_PATH`` and example-robot-data; a missing mesh is drawn as a sphere and
said on stderr and in the viewer's page."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from stiffness.cli.main import main as cli_main
from stiffness.robot.robot import load_robot
from stiffness.viewer.page import scene_commands

STL = """solid t
facet normal 0 0 1
outer loop
vertex 0 0 0
vertex 0.1 0 0
vertex 0 0.1 0
endloop
endfacet
endsolid t
"""


def _urdf(meshes: list[str]) -> str:
    links, joints = ['<link name="base_link"/>'], []
    parent = "base_link"
    for i, mesh in enumerate(meshes):
        links.append(f'<link name="l{i}"><visual><geometry><mesh filename="{mesh}"/></geometry>'
                     "</visual></link>")
        joints.append(f'<joint name="j{i}" type="revolute"><parent link="{parent}"/>'
                      f'<child link="l{i}"/><origin xyz="0.2 0 0"/><axis xyz="0 0 1"/>'
                      '<limit effort="1" velocity="1" lower="-3" upper="3"/></joint>')
        parent = f"l{i}"
    return f'<?xml version="1.0"?>\n<robot name="m">{"".join(links + joints)}</robot>\n'


def test_package_relative_and_ros_package_path_meshes(tmp_path, monkeypatch):
    pkg = tmp_path / "ws" / "my_pkg"
    (pkg / "meshes").mkdir(parents=True)
    (pkg / "urdf").mkdir()
    (pkg / "meshes" / "a.stl").write_text(STL)
    (pkg / "urdf" / "b.stl").write_text(STL)
    other = tmp_path / "elsewhere" / "other_pkg" / "meshes"
    other.mkdir(parents=True)
    (other / "c.stl").write_text(STL)
    monkeypatch.setenv("ROS_PACKAGE_PATH", str(tmp_path / "elsewhere"))
    urdf = pkg / "urdf" / "robot.urdf"
    urdf.write_text(_urdf(["package://my_pkg/meshes/a.stl", "b.stl", "package:///b.stl",
                           "package://other_pkg/meshes/c.stl", "package://gone/x.stl"]))
    robot = load_robot(urdf)
    assert [str(m) for m in robot.missing_meshes] == ["package://gone/x.stl (link l4)"]
    paths = [obj.meshPath for obj in robot.visual_model.geometryObjects]
    assert paths[:4] == [str(pkg / "meshes" / "a.stl"), str(pkg / "urdf" / "b.stl"),
                         str(pkg / "urdf" / "b.stl"), str(other / "c.stl")]
    # the missing mesh is a sphere on its own link
    sphere = robot.visual_model.geometryObjects[4]
    assert robot.model.names[sphere.parentJoint] == "j4"
    assert "Sphere" in type(sphere.geometry).__name__


def test_missing_mesh_is_said_on_stderr_and_in_the_page(tmp_path, capsys):
    urdf = tmp_path / "robot.urdf"
    (tmp_path / "a.stl").write_text(STL)
    urdf.write_text(_urdf(["a.stl", "meshes/missing.stl"]))
    out = tmp_path / "page.html"
    assert cli_main(["view", "--robot", str(urdf), "--q", "0.3,0.4", "--kq", "10,20",
                     "--wrench", "1,2,0", "--export", str(out)]) == 0
    err = capsys.readouterr().err
    assert err.count("mesh not found: meshes/missing.stl (link l1); drawn as a sphere") == 1
    page = out.read_text()
    assert "mesh not found: meshes/missing.stl (link l1)" in page
    commands = scene_commands(page)
    assert any("visuals" in c.get("path", "") for c in commands)


def test_mesh_geometry_sits_on_its_link(tmp_path):
    (tmp_path / "a.stl").write_text(STL)
    urdf = tmp_path / "robot.urdf"
    urdf.write_text(_urdf(["a.stl", "a.stl"]))
    robot = load_robot(urdf)
    data, gdata = robot.model.createData(), robot.visual_model.createData()
    q = robot.configuration(np.array([0.5, -0.2]))
    pin.forwardKinematics(robot.model, data, q)
    pin.updateGeometryPlacements(robot.model, data, robot.visual_model, gdata)
    np.testing.assert_allclose(gdata.oMg[1].translation,
                               [0.2 + 0.2 * np.cos(0.5), 0.2 * np.sin(0.5), 0], atol=1e-14)
