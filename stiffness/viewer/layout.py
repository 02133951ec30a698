"""Where the viewer puts things: ellipsoid radii, load arrows, the rotational block beside the
target, the floor under the robot, the spacing of a field and the camera.

Positions and lengths in m, base frame.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from stiffness.errors import UnknownJointError
from stiffness.mechanics.defaults import loop_sampling_box
from stiffness.mechanics.ik import coordinate_limits
from stiffness.robot.robot import Robot
from stiffness.viewer.ellipsoid import PrincipalEllipsoid, RotationalBlock
from stiffness.viewer.geometry import Pose, rotation_y_to, segment_pose
from stiffness.viewer.states import STIFFNESS_NODE, SceneState
from stiffness.viewer.style import nice_below

#: Radius drawn for an unbounded principal value, in multiples of the largest finite radius.
UNBOUNDED_RADIUS = 3.0


def side_direction(position: np.ndarray) -> np.ndarray:
    """Horizontal unit vector normal to the radial direction of ``position`` (where the
    conventional ellipsoid goes, beside the target); +y on the vertical axis."""
    radial = np.array([position[0], position[1], 0.0])
    if np.linalg.norm(radial) < 1e-6:
        return np.array([0.0, 1.0, 0.0])
    side = np.cross([0.0, 0.0, 1.0], radial)
    return side / np.linalg.norm(side)


def ellipsoid_radii(ellipsoid: PrincipalEllipsoid, scale: float) -> np.ndarray:
    """Drawn radii (m): ``scale`` times each principal value's magnitude, unbounded ones
    :data:`UNBOUNDED_RADIUS` times the largest finite radius, none below 1e-6 of that cap."""
    radii = np.abs(ellipsoid.values) * scale
    finite = radii[np.isfinite(radii)]
    cap = UNBOUNDED_RADIUS * (np.max(finite) if finite.size else 1.0)
    return np.where(np.isfinite(radii), np.maximum(radii, 1e-6 * cap), cap)


def arrow_poses(name: str, origin: np.ndarray, vector: np.ndarray, length: float,
                reach: float) -> dict[str, Pose]:
    """Poses of the shaft and head of the load arrow ``name`` from ``origin`` along
    ``vector``, ``length`` m long (hidden for a zero length or vector); the head is 6 % of the
    robot's ``reach`` (m)."""
    base = f"{STIFFNESS_NODE}/{name}"
    if length <= 0 or not np.any(vector):
        hidden = Pose(origin, np.eye(3), np.full(3, 1e-9))
        return {f"{base}/shaft": hidden, f"{base}/head": hidden}
    direction = vector / np.linalg.norm(vector)
    head = 0.06 * reach
    tip = origin + direction * max(length, head)
    neck = tip - direction * head
    shaft = segment_pose(origin, neck)
    return {f"{base}/shaft": shaft,
            f"{base}/head": Pose(neck + 0.5 * head * direction, rotation_y_to(direction),
                                 np.ones(3))}


def rotational_pose(block: RotationalBlock, state: SceneState, size: float
                    ) -> tuple[Pose, np.ndarray]:
    """Pose of the rotational block's ellipsoid (its own scale: largest radius ``size``, m),
    beside the target on the side away from the conventional ellipsoid; and its radii (m)."""
    finite = np.abs(block.values[np.isfinite(block.values)])
    top = float(np.max(finite)) if finite.size else 1.0
    radii = np.where(np.isfinite(block.values), np.abs(block.values) / (top or 1.0),
                     UNBOUNDED_RADIUS) * size
    radii = np.maximum(radii, 1e-3 * size)
    first = next(iter(state.radii.values()))
    gap = float(np.max(first)) + float(np.max(radii)) + 1.5 * size
    center = state.position - gap * side_direction(state.position)
    return Pose(center, block.directions, radii), radii


def random_coordinates(robot: Robot, n: int, base: np.ndarray, joints: Sequence[str] | None,
                       seed: int) -> np.ndarray:
    """``n`` rows of coordinates: ``base`` with each of ``joints`` (default all) uniform within
    its limits (a closed loop's: within
    :func:`~stiffness.mechanics.defaults.loop_sampling_box` of its reference assembly, where it
    assembles), clipped to [-180, 180] deg (angles) or [-1, 1] m (prismatic joints)."""
    names = list(robot.coordinate_joints) if joints is None else list(joints)
    unknown = [j for j in names if j not in robot.coordinate_joints]
    if unknown:
        raise UnknownJointError(f"{', '.join(unknown)} are not coordinates of {robot.title}; "
                                f"coordinates: {', '.join(robot.coordinate_joints)}",
                                name=unknown[0], choices=robot.coordinate_joints)
    rng = np.random.default_rng(seed)
    rows = np.tile(base, (n, 1))
    lower, upper = loop_sampling_box(robot, *coordinate_limits(robot))  # +-inf: continuous
    for name in names:
        i = robot.coordinate_joints.index(name)
        lo, hi = lower[i], upper[i]
        bound = 1.0 if robot.is_prismatic(name) else np.pi
        lo = lo if np.isfinite(lo) and lo > -bound else -bound
        hi = hi if np.isfinite(hi) and hi < bound else bound
        rows[:, i] = rng.uniform(lo, hi, n)
    return rows


def sample_spacing(points: np.ndarray) -> float:
    """Median distance (m) from each point to its nearest neighbour (0.1 for one point, at
    least 1 mm)."""
    if len(points) < 2:
        return 0.1
    d = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    nearest = d.min(axis=1)
    return max(float(np.median(nearest)), 1e-3)


def floor_layout(points: np.ndarray, extra: np.ndarray | None, reach: float
                 ) -> tuple[float, np.ndarray, float, float]:
    """Height ``z``, centre (x, y), half side and grid spacing (m) of a floor under
    ``points`` (joints, target, ellipsoid centres): a little below the lowest of them, with
    a round spacing, spanning them, the ``extra`` points (a field's targets) and the reach."""
    z = float(points[:, 2].min()) - 0.01 * reach
    if extra is not None:
        points = np.vstack([points, np.asarray(extra, dtype=float).reshape(-1, 3)])
    lo, hi = points[:, :2].min(axis=0), points[:, :2].max(axis=0)
    center = 0.5 * (lo + hi)
    half = 1.25 * max(0.5 * float(np.max(hi - lo)), reach)
    spacing = nice_below(half / 4.0)
    half = spacing * np.ceil(half / spacing)
    return z, center, float(half), float(spacing)


def camera_spec(robot: Robot, state: SceneState | None, field_positions: np.ndarray | None
                ) -> dict:
    """Camera looking at the target (at the whole field for a field view) from beside it, far
    enough back to keep the robot and its ellipsoids in view: the page's
    ``{"target": [x, y, z], "position": [x, y, z]}`` (m)."""
    model, data = robot.model, robot.data
    q = state.q if state is not None else pin.neutral(model)
    pin.forwardKinematics(model, data, q)
    joints = [data.oMi[j].translation.copy() for j in range(model.njoints)]
    target = joints[-1]
    if state is not None:
        target = state.position
        for name, c in state.centers.items():
            r = float(np.max(state.radii[name]))
            joints += [c - r, c + r]
    if field_positions is not None:
        joints += list(field_positions)
    points = np.array(joints)
    lo, hi = points.min(axis=0), points.max(axis=0)
    center = 0.5 * (lo + hi)
    extent = max(0.5 * float(np.linalg.norm(hi - lo)), 0.3)
    if state is not None and field_positions is None:
        # framed on the target: looking at it, far enough back to keep the robot in view
        center = np.asarray(target, dtype=float)
        extent = max(0.75 * float(np.max(np.linalg.norm(points - center, axis=1))), 0.3)
    radial = np.array([target[0], target[1], 0.0])
    radial = radial / np.linalg.norm(radial) if np.linalg.norm(radial) > 1e-6 else \
        np.array([1.0, 0.0, 0.0])
    side = side_direction(radial)
    view = radial - side
    view = np.array([view[0], view[1], 0.0]) / np.linalg.norm(view)
    view = np.cos(0.45) * view + np.array([0.0, 0.0, np.sin(0.45)])
    distance = 1.5 * extent / np.tan(np.deg2rad(37.5))
    # shift the scene right of the legend (top left of the page)
    right = np.cross(-view, [0.0, 0.0, 1.0])
    center = center - 0.45 * extent * right / max(float(np.linalg.norm(right)), 1e-9)
    return {"target": [float(v) for v in center],
            "position": [float(v) for v in center + distance * view]}
