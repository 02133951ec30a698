"""Parallel platforms (Stewart-Gough, Griffis-Duffy couplings) written as a URDF and a loop file.

A platform with ``n`` legs between base anchors ``b_i`` and platform anchors ``p_i`` is written
as a URDF tree plus a loop declaration (:func:`platform_urdf`, :func:`platform_loop_declaration`;
``scripts/generate_hexapod.py`` and ``scripts/generate_griffis_duffy.py`` write the shipped
ones):

* the platform hangs from the base through a virtual six-degree-of-freedom chain (prismatic
  ``platform_x``, ``platform_y``, ``platform_z`` along the base axes, then revolute
  ``platform_rx``, ``platform_ry``, ``platform_rz``), all zero at the reference pose, passive;
* each leg ``i`` is a U-P chain: a universal joint at ``b_i`` (revolute ``leg<i>_ux`` about the
  leg frame's x, then ``leg<i>_uy`` about its y; both zero at the reference pose, where the leg
  frame's z points along the leg), then the prismatic joint ``leg<i>`` along z, whose
  coordinate is the leg length (m): the spring, compliant, actuated;
* the loop ``[leg<i>_tip, leg<i>_anchor]`` ("3D", a spherical joint) closes the leg on the
  platform.

Passive joints: the virtual chain and the universal joints (6 + 2n); constraint rows: 3n. For
six legs the passive Jacobian is square (18 x 18) and the six leg lengths are the coordinates.
The platform's stiffness is in :mod:`stiffness.mechanics.platform`. Units: SI (m, rad).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from stiffness.errors import StiffnessError
from stiffness.robot.urdf_writer import UrdfWriter, transform

#: Names of the passive virtual joints carrying the platform, in chain order.
VIRTUAL_JOINTS = ("platform_x", "platform_y", "platform_z",
                  "platform_rx", "platform_ry", "platform_rz")


@dataclass(frozen=True)
class PlatformSpec:
    """Geometry of a leg-spring parallel platform.

    Attributes
    ----------
    name
        Robot name (URDF ``<robot name>``).
    base_anchors
        (n, 3) base attachment points, base frame (m).
    platform_anchors
        (n, 3) platform attachment points, platform frame (m); leg ``i`` joins
        ``base_anchors[i]`` to ``platform_anchors[i]`` (anchors may repeat).
    platform_pose
        Pose of the platform frame in the base frame at the reference configuration (all
        passive joints zero there).
    leg_names
        Prismatic joint names; empty (the default) names them ``leg1..legn``.
    """

    name: str
    base_anchors: np.ndarray
    platform_anchors: np.ndarray
    platform_pose: pin.SE3 = field(default_factory=pin.SE3.Identity)
    leg_names: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        base = np.asarray(self.base_anchors, dtype=float)
        plat = np.asarray(self.platform_anchors, dtype=float)
        if base.ndim != 2 or base.shape[1] != 3 or base.shape != plat.shape:
            raise StiffnessError(
                f"base and platform anchors must both be (n, 3) arrays in m, got {base.shape} "
                f"and {plat.shape}"
            )
        object.__setattr__(self, "base_anchors", base)
        object.__setattr__(self, "platform_anchors", plat)
        names = self.leg_names or tuple(f"leg{i + 1}" for i in range(base.shape[0]))
        if len(names) != base.shape[0]:
            raise StiffnessError(f"{len(names)} leg names for {base.shape[0]} legs")
        object.__setattr__(self, "leg_names", tuple(names))

    @property
    def n_legs(self) -> int:
        """Number of legs."""
        return self.base_anchors.shape[0]

    def leg_vectors(self, pose: pin.SE3 | None = None) -> np.ndarray:
        """(n, 3) vectors from base anchors to platform anchors at a platform pose (m)."""
        pose = self.platform_pose if pose is None else pose
        world = self.platform_anchors @ pose.rotation.T + pose.translation
        return world - self.base_anchors

    def leg_lengths(self, pose: pin.SE3 | None = None) -> np.ndarray:
        """Leg lengths (m) at a platform pose (default: the reference pose)."""
        return np.linalg.norm(self.leg_vectors(pose), axis=1)


def _leg_frame(direction: np.ndarray) -> np.ndarray:
    """Rotation whose z axis is ``direction`` (x chosen away from it: no gimbal lock)."""
    z = direction / np.linalg.norm(direction)
    helper = np.eye(3)[int(np.argmin(np.abs(z)))]
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def platform_urdf(spec: PlatformSpec, reach_m: float | None = None) -> str:
    """URDF text of the platform tree (see the module docstring), lengths in m.

    Parameters
    ----------
    spec
        Platform geometry.
    reach_m
        Range of the virtual prismatic joints and upper limit of the legs (m); default ten
        times the longest leg.
    """
    reach = float(reach_m or 10.0 * np.max(spec.leg_lengths()))
    urdf = UrdfWriter(spec.name)
    for link in ("base_link", *(f"{name}_link" for name in VIRTUAL_JOINTS[:-1]), "platform"):
        urdf.link(link)
    for leg in spec.leg_names:
        for part in ("cardan", "cylinder", "rod", "tip", "anchor"):
            urdf.link(f"{leg}_{part}")
    axes = np.vstack([np.eye(3), np.eye(3)])
    revolute, legs = (-np.pi, np.pi, 1e6, 1.0), (0.0, reach, 1e6, 1.0)
    parent = "base_link"
    for i, name in enumerate(VIRTUAL_JOINTS):
        child = "platform" if i == len(VIRTUAL_JOINTS) - 1 else f"{name}_link"
        origin = (transform(spec.platform_pose.translation, spec.platform_pose.rotation)
                  if i == 0 else transform())
        kind, limit = ("prismatic", (-reach, reach, 1e6, 1.0)) if i < 3 else ("revolute",
                                                                                revolute)
        urdf.joint(name, kind, parent, child, origin, axes[i], limit)
        parent = child
    vectors = spec.leg_vectors()
    for i, leg in enumerate(spec.leg_names):
        rot = _leg_frame(vectors[i])
        urdf.joint(f"{leg}_ux", "revolute", "base_link", f"{leg}_cardan",
                   transform(spec.base_anchors[i], rot), [1, 0, 0], revolute)
        urdf.joint(f"{leg}_uy", "revolute", f"{leg}_cardan", f"{leg}_cylinder", transform(),
                   [0, 1, 0], revolute)
        urdf.joint(leg, "prismatic", f"{leg}_cylinder", f"{leg}_rod", transform(), [0, 0, 1],
                   legs)
        urdf.joint(f"{leg}_tip_joint", "fixed", f"{leg}_rod", f"{leg}_tip", transform())
        urdf.joint(f"{leg}_anchor_joint", "fixed", "platform", f"{leg}_anchor",
                   transform(spec.platform_anchors[i]))
    return urdf.text()


def platform_loop_declaration(spec: PlatformSpec) -> str:
    """Loop declaration (Extended-URDF YAML text) of :func:`platform_urdf`'s tree."""
    legs = spec.leg_names
    pairs = "".join(f"  - [{leg}_tip, {leg}_anchor]\n" for leg in legs)
    passive = list(VIRTUAL_JOINTS) + [f"{leg}_{u}" for leg in legs for u in ("ux", "uy")]
    return (
        f"# Loop declaration of {spec.name}: each leg's tip meets its platform anchor (a\n"
        "# spherical joint); the leg lengths are actuated (the springs), the virtual platform\n"
        "# chain and the universal joints passive. Written by stiffness.robot.platform.\n"
        f"closed_loop:\n{pairs}"
        "type: [" + ", ".join(['"3D"'] * len(legs)) + "]\n"
        f"name_mot: [{', '.join(legs)}]\n"
        f"passive_joints: [{', '.join(passive)}]\n"
    )
