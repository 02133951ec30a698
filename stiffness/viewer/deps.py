"""Lazy imports of the viewer's third-party packages: meshcat and Pinocchio's visualizer.

meshcat's import raises a zmq ``DeprecationWarning``; both helpers silence it only around the
import (never globally). Both import on first use: ``import stiffness.viewer`` does not import
meshcat.
"""

from __future__ import annotations

import functools
import warnings
from pathlib import Path
from typing import Any


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


def _pinocchio_meshcat_visualizer() -> type:
    """Pinocchio's ``MeshcatVisualizer`` class, imported after :func:`_meshcat` (same warning)."""
    _meshcat()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        from pinocchio.visualize import MeshcatVisualizer
    return MeshcatVisualizer
