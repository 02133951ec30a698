"""Lazy imports of the viewer's third-party packages: meshcat and Pinocchio's visualizer.

meshcat's import raises a zmq ``DeprecationWarning``; both helpers silence it only around the
import (never globally). Both import on first use: ``import stiffness.viewer`` does not import
meshcat.
"""

from __future__ import annotations

import functools
import importlib.util
import sys
import warnings
from pathlib import Path
from types import SimpleNamespace
from typing import Any


@functools.cache
def meshcat_modules() -> Any:
    """meshcat and its submodules, imported with its zmq DeprecationWarning silenced locally."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        import meshcat
        import meshcat.animation
        import meshcat.geometry
        import umsgpack

    return SimpleNamespace(
        meshcat=meshcat, geometry=meshcat.geometry, animation=meshcat.animation,
        msgpack=umsgpack,
        viewer_js=Path(meshcat.__file__).parent / "viewer" / "dist" / "main.min.js")


def pinocchio_meshcat_visualizer() -> type:
    """Pinocchio's ``MeshcatVisualizer`` class, imported after :func:`meshcat_modules` (same
    warning).

    ``pinocchio.visualize`` imports every visualizer; its Viser one imports ``trimesh`` (1.3 s
    here) and then ``viser``, and is disabled when either is missing. Where ``viser`` is not
    installed, ``trimesh`` is kept out of that import (an ``ImportError`` at once: the same
    outcome, without loading it); ``trimesh`` imports normally afterwards.
    """
    meshcat_modules()
    skip_trimesh = "trimesh" not in sys.modules and importlib.util.find_spec("viser") is None
    if skip_trimesh:
        sys.modules["trimesh"] = None  # type: ignore[assignment]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            from pinocchio.visualize import MeshcatVisualizer
    finally:
        if skip_trimesh and sys.modules.get("trimesh", 0) is None:
            del sys.modules["trimesh"]
    return MeshcatVisualizer
