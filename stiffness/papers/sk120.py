"""The Motoman SK120 of Alici & Shirinzadeh (2005): URDF from Table I and its angle convention.

Table I gives standard Denavit-Hartenberg rows (``Rz(theta) Tz(d) Tx(a) Rx(alpha)``) for the
serial chain 1, and for the parallelogram five-bar 1b, 2b, 3b, then 3, 4, 5, 6. The five-bar
relations are ``theta_b1 = theta3``, ``theta_b2 = theta2 - theta3``, ``theta_b2 + theta_b3 = pi``,
``L_b1 = L_b3 = 542 mm``, ``L_b2 = L2 = 1100 mm``, so that, in frame 1:

* the lower arm (joint2, length L2) points at the DH angle ``theta2``;
* the crank (joint3, length 542) points at ``theta3``; the coupler (1100) stays parallel to the
  lower arm; the forearm points at ``pi + theta3`` (its rear extension, 542, parallels the crank).

The URDF keeps the five-bar as a tree: base -> joint1 -> joint2 (lower arm) -> elbow (passive)
-> forearm -> joint4 -> joint5 -> joint6 -> tool0 -> fixture target, and the branch joint3
(crank) -> coupler_joint (passive) -> coupler. The loop is closed by a point constraint between
``coupler_end`` and ``forearm_rear`` (``robots/sk120/sk120.loops.yaml``).

URDF joint values are the paper's printed angles: the DH angle of joint i is
``theta_DH_i = offset_i + sign_i * q_i``; :class:`AngleConvention` holds the signs and offsets,
and the shipped URDF uses the convention selected by ``scripts/generate_sk120.py`` (see
``docs/sk120.md``). Lengths in the URDF are in m.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from stiffness.robot.urdf_writer import UrdfWriter

#: L-shaped fixture: a along the tool plate's axis (z6), b normal to it (x6), in m.
FIXTURE_A_M = 0.11265
FIXTURE_B_M = 0.20532
#: Joint stiffness identified by the paper (N.mm/rad), joints 1, 2, 3.
PAPER_K_THETA_NMM_PER_RAD = (1.4098e9, 4.0076e8, 9.3528e8)


@dataclass(frozen=True)
class AngleConvention:
    """Map from printed joint angles to Table I's DH angles: ``theta_DH = offset + sign * q``.

    Attributes
    ----------
    signs
        +1 or -1 for joints 1..6.
    offsets_deg
        DH angle (deg) at printed zero for joints 1..6.
    """

    signs: tuple[int, ...] = (1, 1, 1, 1, 1, 1)
    offsets_deg: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

    def to_dh(self, q_printed_rad: np.ndarray) -> np.ndarray:
        """DH angles (rad) of printed angles (rad), shape (..., 6)."""
        return np.deg2rad(self.offsets_deg) + np.asarray(self.signs) * q_printed_rad

    def describe(self) -> str:
        """Human-readable mapping, e.g. ``theta2_DH = -90 + q2``."""
        parts = []
        for i, (s, o) in enumerate(zip(self.signs, self.offsets_deg, strict=True), start=1):
            sign = "+" if s > 0 else "-"
            parts.append(f"theta{i}_DH = {o:g} deg {sign} q{i}")
        return "; ".join(parts)


@dataclass(frozen=True)
class DHRow:
    """One Table I row (standard DH): alpha (rad), d (m), a (m)."""

    name: str
    alpha: float
    d: float
    a: float


def read_table1(path: str | Path) -> dict[str, DHRow]:
    """Read Table I (``alpha_deg, d_mm, a_mm``) into SI rows keyed by joint name."""
    rows = {}
    with open(path) as f:
        lines = [line for line in f if not line.startswith("#")]
    for rec in csv.DictReader(lines):
        rows[rec["joint"]] = DHRow(
            rec["joint"], np.deg2rad(float(rec["alpha_deg"])), float(rec["d_mm"]) * 1e-3,
            float(rec["a_mm"]) * 1e-3,
        )
    return rows


def _rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    return m


def _rot_x(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    m = np.eye(4)
    m[1:3, 1:3] = [[c, -s], [s, c]]
    return m


def _trans(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = x, y, z
    return m


def _dh_fixed(row: DHRow) -> np.ndarray:
    """The constant part ``Tz(d) Tx(a) Rx(alpha)`` of a DH row."""
    return _trans(row.a, 0.0, row.d) @ _rot_x(row.alpha)


def sk120_urdf(table1: dict[str, DHRow], convention: AngleConvention) -> str:
    """URDF text of the SK120 (tree form of the five-bar) in a given angle convention.

    Lengths in m, angles in rad; every revolute joint is limited to [-pi, pi] rad, 1e4 N.m and
    2 rad/s. The links' visuals are boxes 0.12 m thick along their length.
    """
    o = np.deg2rad(convention.offsets_deg)
    s = convention.signs
    crank = table1["1b"].a
    coupler = table1["2b"].a
    r1, r3, r4, r5, r6 = (table1[k] for k in ("1", "3", "4", "5", "6"))
    robot = UrdfWriter("motoman_sk120")

    def link(name: str, length: float = 0.0, axis: str = "x") -> None:
        box = None
        if length:
            centre = {"x": _trans(length / 2), "z": _trans(z=length / 2)}[axis]
            size = {"x": [abs(length), 0.12, 0.12], "z": [0.12, 0.12, abs(length)]}[axis]
            box = (size, centre)
        robot.link(name, box)

    def joint(name: str, parent: str, child: str, origin: np.ndarray,
              sign: int | None = None) -> None:
        if sign is None:
            robot.joint(name, "fixed", parent, child, origin)
        else:
            robot.joint(name, "revolute", parent, child, origin, [0.0, 0.0, sign],
                        (-np.pi, np.pi, 10000.0, 2.0))

    link_args: list[tuple[Any, ...]] = [
        ("base_link",), ("link1", r1.a), ("lower_arm", coupler), ("crank", crank),
        ("coupler", coupler), ("forearm", -crank), ("link4", r4.d, "z"), ("link5",),
        ("link6", r6.d, "z"), ("coupler_end",), ("forearm_rear",), ("tool0",),
        ("fixture_target",)]
    for args in link_args:
        link(*args)
    shoulder = _dh_fixed(r1)
    joint("joint1", "base_link", "link1", _rot_z(o[0]), s[0])
    joint("joint2", "link1", "lower_arm", shoulder @ _rot_z(o[1]), s[1])
    joint("joint3", "link1", "crank", shoulder @ _rot_z(o[2]), s[2])
    joint("elbow", "lower_arm", "forearm", _trans(coupler) @ _rot_z(np.pi + o[2] - o[1]), 1)
    joint("coupler_joint", "crank", "coupler", _trans(crank) @ _rot_z(o[1] - o[2]), 1)
    joint("coupler_end_joint", "coupler", "coupler_end", _trans(coupler))
    joint("forearm_rear_joint", "forearm", "forearm_rear", _trans(-crank))
    joint("joint4", "forearm", "link4", _rot_z(-np.pi / 2) @ _dh_fixed(r3) @ _rot_z(o[3]),
          s[3])
    joint("joint5", "link4", "link5", _dh_fixed(r4) @ _rot_z(o[4]), s[4])
    joint("joint6", "link5", "link6", _dh_fixed(r5) @ _rot_z(o[5]), s[5])
    joint("tool0_joint", "link6", "tool0", _dh_fixed(r6))
    joint("fixture_joint", "tool0", "fixture_target", _trans(FIXTURE_B_M, 0.0, FIXTURE_A_M))
    return robot.text()
