"""Where the posture search trusts its model: the robot's declared ``[workspace]``.

A robot whose ``robot.toml`` declares a ``[workspace]`` table
(:class:`~stiffness.calibration.poses.Workspace`) draws its measurement poses there, so a model
identified from them is only calibrated there. ``stiffness posture`` judges every candidate
node against it (:meth:`~stiffness.calibration.poses.Workspace.departures`), takes the path
with the fewest points outside it (then the stiffest), keeps a refined posture inside when its
node was, and says in one line when the stiffest candidates lie outside or when a point has no
posture inside. A robot without the table is not judged, nor, with ``--ignore-workspace``
(``ignore_workspace=True``), one with it: its nodes are still told inside or outside, and
one line says how many chosen points lie outside.

Units: rad, m; deflections in m.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from stiffness.calibration.poses import Workspace
from stiffness.machining.branches import Layer, branch_label
from stiffness.robot.robot import Robot


@dataclass
class Region:
    """The declared workspace of one search and its judgement of the candidate nodes.

    Attributes
    ----------
    robot
        The robot (its coordinates as the nodes give them).
    workspace
        Its ``[workspace]`` (:meth:`Workspace.of`; not declared: nothing is judged).
    outside
        Per path point, per candidate node, what puts the node outside (empty: inside).
    weight
        The penalty (m^2) of a node outside in the path search: more than the sum of the
        squared deflections of any path, so the fewest points outside come first.
    judged
        Whether the search keeps inside it (false: ``ignore_workspace``, the nodes told
        inside or outside but none set aside).
    """

    robot: Robot
    workspace: Workspace
    outside: list[list[tuple[str, ...]]]
    weight: float
    judged: bool = True

    @classmethod
    def of(cls, robot: Robot, layers: list[Layer], judged: bool = True) -> Region:
        """The workspace of ``robot`` (read once, by :meth:`Workspace.of`) with its judgement
        of every node of ``layers``; ``judged`` false: the search does not keep inside it."""
        workspace = Workspace.of(robot)
        if not workspace.declared:
            return cls(robot, workspace, [], 0.0, judged)
        outside = [[tuple(workspace.departures(robot, c)) for c in layer.coords]
                   for layer in layers]
        total = sum(float(np.max(np.where(np.isfinite(layer.values), layer.values, 0.0) ** 2,
                                 initial=0.0)) for layer in layers)
        return cls(robot, workspace, outside, 2.0 * total if total > 0 else 1.0, judged)

    @property
    def declared(self) -> bool:
        """Whether the robot declares a workspace (else nothing is judged)."""
        return self.workspace.declared

    def judge(self, coords: np.ndarray) -> tuple[str, ...]:
        """What puts the coordinates ``coords`` (rad, m) outside the workspace (empty:
        inside, or none declared)."""
        return tuple(self.workspace.departures(self.robot, coords))

    def penalty(self) -> list[np.ndarray] | None:
        """Per point, per node, :attr:`weight` outside the workspace and 0 inside (m^2);
        ``None`` without a declared workspace or not :attr:`judged`."""
        if not self.declared or not self.judged:
            return None
        return [self.weight * np.array([bool(o) for o in row], dtype=float)
                for row in self.outside]

    def keeper(self, i: int, n: int) -> Callable[[np.ndarray], bool]:
        """Whether coordinates may replace node ``n`` of point ``i`` in the refinement: any
        when the node is outside (or nothing is declared or :attr:`judged`), else those
        inside."""
        if not self.declared or not self.judged or self.outside[i][n]:
            return lambda coords: True
        return lambda coords: not self.judge(coords)

    def notes(self, points: list[tuple[str, tuple[str, ...]]], layers: list[Layer],
              choice: list[int], free: list[int] | None) -> list[str]:
        """One line when points of the chosen path (``points``: each one's branch and what
        puts it outside) are outside the workspace (none inside within reach), or when the
        stiffest path over every node, ``free`` (the search without the workspace), leaves
        it while the chosen one keeps inside; not :attr:`judged`, how many chosen points
        lie outside."""
        where = f"the [workspace] of {self.robot.title} (where its model is calibrated)"
        out = [i for i, (_, outside) in enumerate(points) if outside]
        if out and not self.judged:
            (branch, outside), i = points[out[0]], out[0]
            return [f"{len(out)} of {len(points)} points lie outside {where}, not judged "
                    f"(--ignore-workspace; row {i + 1}, branch {branch}: {outside[0]}): "
                    "their deflections extrapolate the model"]
        if out:
            (branch, outside), i = points[out[0]], out[0]
            return [f"{len(out)} of {len(points)} points have no posture inside {where} "
                    f"within the step bound (row {i + 1}, branch {branch}: {outside[0]}): "
                    "their deflections extrapolate the model"]
        if free is None:
            return []
        away = [i for i, n in enumerate(free) if self.outside[i][n]]
        if not away:
            return []
        i, n = away[0], free[away[0]]
        best = max(float(layer.values[k]) for layer, k in zip(layers, free, strict=True))
        kept = max(float(layer.values[k]) for layer, k in zip(layers, choice, strict=True))
        return [f"the stiffest postures leave {where} (row {i + 1}, branch "
                f"{branch_label(int(layers[i].branch[n]))}: {self.outside[i][n][0]}; "
                f"{best:.4g} m max against {kept:.4g} m inside, before refinement): the path "
                "keeps inside it"]
