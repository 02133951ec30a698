"""Mesh files of a URDF's visuals: ``package://``, ``file://`` and relative paths resolved.

Search order for ``package://PKG/REST`` (and ``package:///REST``, which Onshape exports write):

1. the URDF's folder and its ancestors: ``A/PKG/REST``, ``A/REST`` when ``A`` is named PKG, and
   ``A/REST`` for an empty PKG;
2. every folder of ``ROS_PACKAGE_PATH``: ``E/PKG/REST``, ``E/REST`` when ``E`` is named PKG, and
   packages one or two levels below ``E`` (a workspace's ``src/PKG``);
3. example-robot-data's share folder: ``share/example-robot-data/robots/PKG/REST``, and
   ``share/example-robot-data/REST`` for the package ``example-robot-data`` itself (the
   ``package://example-robot-data/robots/...`` paths of its own URDFs).

A relative path is taken from the URDF's folder. A mesh that none of these holds is replaced by a
small sphere (radius :data:`PLACEHOLDER_RADIUS_M`) on the same link and listed in
:class:`MissingMesh` records, so that the viewer can say so and still draw the robot.
"""

from __future__ import annotations

import copy
import os
import re
import warnings
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import unquote

import pinocchio as pin

from stiffness.errors import RobotFileNote
from stiffness.robot import kinematics

#: Radius (m) of the sphere drawn in place of a missing mesh.
PLACEHOLDER_RADIUS_M = 0.02


@dataclass(frozen=True)
class MissingMesh:
    """A visual mesh that could not be found: the link it belongs to and the file name given."""

    link: str
    filename: str

    def __str__(self) -> str:
        return f"{self.filename} (link {self.link})"


def _example_robot_data_share() -> Path | None:
    try:
        from example_robot_data.robots_loader import getModelPath

        return Path(getModelPath("")).resolve()
    except (ImportError, OSError, ValueError):
        return None


def search_roots(urdf: Path) -> list[Path]:
    """Folders searched for packages, in order (see the module docstring)."""
    roots = [urdf.resolve().parent, *urdf.resolve().parent.parents]
    for entry in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep):
        if entry:
            base = Path(entry)
            roots.append(base)
            if base.is_dir():
                roots += sorted(p for p in base.glob("*") if p.is_dir())
                roots += sorted(p for p in base.glob("*/*") if p.is_dir())
    share = _example_robot_data_share()
    if share is not None:
        roots += [share, share.parent]  # .../share/example-robot-data/robots and its package
    return roots


def resolve_mesh(filename: str, urdf: Path, roots: list[Path] | None = None) -> Path | None:
    """Absolute path of a mesh file name of ``urdf``, or None when it cannot be found."""
    if filename.startswith("file://"):
        candidate = Path(unquote(filename[len("file://"):]))
        if not candidate.is_absolute():
            candidate = urdf.resolve().parent / candidate
        return candidate if candidate.is_file() else None
    if not filename.startswith("package://"):
        candidate = Path(filename)
        if not candidate.is_absolute():
            candidate = urdf.resolve().parent / candidate
        return candidate if candidate.is_file() else None
    rest = filename[len("package://"):]
    package, _, tail = rest.partition("/")
    tail = tail.lstrip("/")
    for root in search_roots(urdf) if roots is None else roots:
        candidates = [root / package / tail] if package else [root / tail]
        if package and root.name == package:
            candidates.append(root / tail)
        for candidate in candidates:
            if candidate.is_file():
                return candidate
    return None


def resolve_visual_meshes(urdf: Path, root, model: pin.Model
                          ) -> tuple[pin.GeometryModel | None, tuple[MissingMesh, ...]]:
    """Visual geometry of a parsed URDF (lxml root) with every mesh resolved.

    Returns the Pinocchio ``GeometryModel`` (None when the file has no visuals or Pinocchio
    cannot build them) and the meshes that are missing (replaced by spheres).
    """
    from lxml import etree

    doc = copy.deepcopy(root)
    for collision in list(doc.iter("collision")):
        collision.getparent().remove(collision)
    roots = search_roots(urdf)
    missing: list[MissingMesh] = []
    n_visuals = 0
    for link in doc.iter("link"):
        for visual in link.iter("visual"):
            n_visuals += 1
            for mesh in visual.iter("mesh"):
                name = mesh.get("filename", "")
                found = resolve_mesh(name, urdf, roots)
                if found is not None:
                    mesh.set("filename", str(found))
                    continue
                missing.append(MissingMesh(str(link.get("name")), name))
                geometry = mesh.getparent()
                geometry.remove(mesh)
                etree.SubElement(geometry, "sphere", radius=repr(PLACEHOLDER_RADIUS_M))
    if n_visuals == 0:
        return None, tuple(missing)
    with kinematics.captured_stderr() as err:
        try:
            visual = pin.buildGeomFromUrdfString(model, etree.tostring(doc, encoding="unicode"),
                                                 pin.GeometryType.VISUAL)
        except (RuntimeError, ValueError):
            visual = None
    problems = [m.strip() for m in re.findall(r"Error:\s*(.+)", err[0] if err else "")]
    for problem in dict.fromkeys(problems):
        warnings.warn(f"{urdf}: visuals: {problem} (ignored by Pinocchio; statics do not use "
                      "visuals)", RobotFileNote, stacklevel=3)
    return visual, tuple(missing)
