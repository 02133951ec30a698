"""The shipped robots, installed as the package data ``stiffness.robots``.

One folder per robot, each with a ``robot.toml`` (see docs/architecture.md, "Add a robot"),
its URDF and loop file, and the papers' data it brings. Read through
:func:`stiffness.robot.robot.robots_directory`; this file only makes the folder a package.
"""
