"""A robot's copy without its links' masses (issue 36): a model that gives no weight, whose
``gravity_compensator`` is then judged against the joint springs
(:meth:`~stiffness.elastic.effects.preloads.GravityCompensator.physical_scale`), not against a
weight its joint carries. The tests that exercise a compensator's machinery end to end (its
naming, base, declared geometry, model file) hide springs far stronger than any arm's weight
needs, which the arm with its masses rightly refuses to name (tests/test_joint_angles.py:
a physical compensator is below what those campaigns resolve)."""

from __future__ import annotations

import atexit
import functools
import shutil
import tempfile
from pathlib import Path

import pinocchio as pin

from stiffness.robot.export import robot_urdf
from stiffness.robot.robot import load_robot


@functools.cache
def massless(name: str) -> str:
    """Path of a URDF of robot ``name`` with every body's inertia zero (written once per test
    process, removed at its exit)."""
    robot = load_robot(name)
    for i in range(len(robot.model.inertias)):
        robot.model.inertias[i] = pin.Inertia.Zero()
    folder = Path(tempfile.mkdtemp(prefix="stiffness-massless-"))
    atexit.register(shutil.rmtree, folder, True)
    path = folder / f"{name}-massless.urdf"
    path.write_text(robot_urdf(robot, visuals=False))
    return str(path)
