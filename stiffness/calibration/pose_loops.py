"""Closed kinematic loops in the pose model: the loaded configuration by assembly, and the
loop's tangent map.

On a robot with closed loops (the SK120's parallelogram, Gepetto's parallel robots) the
commanded coordinates are the independent ones ``u`` (every joint with a degree of freedom but
the loops' passive joints); the full configuration ``q(u)`` is the closure of the loops with
the passive joints solved (:func:`stiffness.batch.loops.newton_closure`, Gauss-Newton from
the commanded assembly, so on its branch, all rows at once; a pass of the sag starts from the
last pass's closure). The springs act on independent coordinates
(the robot's compliant joints, or its controller coordinates), and the torque the
independent coordinates feel is

.. math::

    t = T(q)^T \\big(J_{load}(q)^T w - g(q)\\big), \\qquad
    T(q) = \\frac{\\partial q}{\\partial u} = \\begin{bmatrix} I \\\\ -C_p^{+} C_u
    \\end{bmatrix},

with ``C = dc/dq`` the Jacobian of the loops' world-axes residual at the closure
(:func:`stiffness.batch.loops.tangent_maps`, rank-revealing: planar loops give redundant rows;
the same map as :meth:`LoopClosure.tangent`, whose residual has the same zero set); ``T`` is
laid out (nv, nv), its passive
columns zero, so that ``S(q) = T(q) S_0`` is the configuration-dependent analogue of the
constant spring map ``S_0`` (:attr:`PoseLayout.spring_map`, zero on passive joints) and the
springs' torque is ``S_0^T t``. The loaded configuration is the fixed point
``q* = q(u + delta_0 + Delta u)``, ``Delta u = law(S_0^T t(q*))``, and the marker Jacobian
per independent rate is ``J_p(q*) T(q*)`` (design notes, "Closed loops").

Every family acts through this: torques of the tree (gravity's, its regressor, a base tilt's
derivative) reach the springs as ``T^T tau``; a compensator's spring torque on an independent
joint is its own there (``T``'s row of an independent coordinate is a unit row). What would
change a loop's own geometry has no parameter: ``joint_offsets`` only on the independent
coordinates, ``geometry``, ``link_compliance`` and ``transversal_compliance`` only at joints
whose placement error, bend or tilt moves both frames of every loop pair rigidly or neither
(:meth:`PoseLoops.geometry_joints`, :attr:`PoseLayout.loop_path`); such an error hidden
inside a loop is refused (:class:`LoopGeometryError`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from stiffness.batch.loops import ClosureLayout, close_rows, closure_residuals, tangent_maps
from stiffness.errors import StiffnessError
from stiffness.robot.loops import LoopClosure
from stiffness.robot.robot import Robot


class LoopGeometryError(StiffnessError):
    """A hidden error that would change a closed loop's own geometry: a zero offset of a
    passive joint, or a placement error, link bend or bearing tilt at a joint on a loop's path.

    Attributes
    ----------
    name : str
        The joint named.
    choices : tuple of str
        The valid joints.
    """

    def __init__(self, message: str, *, name: str, choices: Sequence[str]) -> None:
        super().__init__(message)
        self.name = str(name)
        self.choices = tuple(str(c) for c in choices)


class PoseLoops:
    """A robot's loop closures as the pose model uses them.

    Parameters
    ----------
    robot
        A robot with closed loops (``robot.loop`` has pairs).
    """

    def __init__(self, robot: Robot) -> None:
        model = robot.model
        self.robot = robot
        path: set[int] = set()
        for fa, fb in self.loop.frame_ids:
            sa = set(model.supports[model.frames[fa].parentJoint])
            sb = set(model.supports[model.frames[fb].parentJoint])
            path |= sa ^ sb
        #: joints on the path between a loop's two frames (their placement closes the loop)
        self.path_joints = frozenset(int(j) for j in path)
        #: what the closure reads of the robot (the loops' points and passive joints)
        self.layout = ClosureLayout.of(robot)

    @property
    def loop(self) -> LoopClosure:
        """The robot's loop closure (read through the robot, which pickles it)."""
        return self.robot.loop

    def geometry_joints(self, joints: Sequence[int]) -> list[int]:
        """The ``joints`` (ids) whose placement errors leave the loops closed: those on no
        loop's path (a common ancestor of both frames moves the loop rigidly; a joint beyond
        neither frame does not touch it)."""
        return [j for j in joints if j not in self.path_joints]

    def refuse_placement(self, joint: str, valid: Sequence[str], what: str) -> None:
        """Refuse ``what`` (a hidden effect's label) at ``joint``, inside a loop (one line).

        Raises
        ------
        LoopGeometryError
            Always: the joint's placement, zero, bend or tilt closes a loop.
        """
        raise LoopGeometryError(
            f"{what}: {joint} is inside a closed loop of {self.robot.title} (a placement "
            f"error, zero offset, bend or tilt there changes the loop's closure, which a pose "
            f"campaign does not model); name one of {', '.join(valid)}", name=joint,
            choices=valid)

    def close(self, model: pin.Model, data: pin.Data, q: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
        """(n, nq) configurations with the loops closed over the passive joints, each from
        its own row of ``q`` (n, nq) (Gauss-Newton: the branch it starts on), and (n, nv, nv)
        ``T = dq/du`` there, all rows at once (:func:`stiffness.batch.loops.close_rows`).

        Raises
        ------
        LoopClosureError
            A row whose loop does not close (the message names the loop).
        """
        return close_rows(self.robot, self.layout, model, data, q)

    def tangent(self, model: pin.Model, data: pin.Data, q: np.ndarray) -> np.ndarray:
        """(n, nv, nv) ``T = dq/du`` at the closed configurations ``q`` (n, nq), all rows at
        once (:func:`stiffness.batch.loops.tangent_maps`)."""
        return tangent_maps(self.layout, closure_residuals(self.layout, model, data, q)[1])


def projected(tangent: np.ndarray, torque: np.ndarray) -> np.ndarray:
    """``T^T tau`` per row: (n, nv) torques the independent coordinates feel (zero on the
    passive ones) of the tree's generalised forces ``torque`` (n, nv)."""
    return np.einsum("nvk,nv->nk", tangent, torque)
