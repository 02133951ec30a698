"""Robots from Denavit-Hartenberg tables: the ``[dh]`` section of a ``robot.toml``.

A row describes one joint and the link it moves (docs/robot-files.md, "DH tables"):

* ``convention = "standard"``: row i is ``Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)`` from DH
  frame i-1 to DH frame i; joint i turns (or slides) about z of frame i-1.
* ``convention = "modified"`` (Craig): row i is ``Rx(alpha_(i-1)) Tx(a_(i-1)) Rz(theta_i)
  Tz(d_i)``; joint i turns (or slides) about z of frame i.

``theta`` (revolute) or ``d`` (prismatic) is the joint's offset: the joint value is added to it.
Lengths in ``length_unit`` (m or mm), angles in ``angle_unit`` (rad or deg); links in SI (kg, m,
kg.m^2). :func:`build_dh_model` builds the Pinocchio model directly: one revolute (``RZ``) or
prismatic (``PZ``) joint per row, placed at its axis, with a body frame ``<name>_link`` at the
joint; the fixed frames, the base (``base``, the first DH frame in the world) and the tool
(``tool``, on the last row's DH frame unless it names a ``parent``) are a fixed-joint frame
``<name>_joint`` carrying a body frame ``<name>``, as Pinocchio's URDF reader builds fixed joints.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.errors import FileFormatError, did_you_mean
from stiffness.units import ANGLE_UNITS, LENGTH_UNITS, finite_number

CONVENTIONS = ("modified", "standard")
JOINT_TYPES = ("revolute", "prismatic")
#: The units a [dh] section may declare (a subset of stiffness.units).
DH_LENGTH_UNITS = ("m", "mm")
DH_ANGLE_UNITS = ("rad", "deg")
#: The parent that names the base (the first DH frame, after ``base``).
BASE = "base"
#: Name of the tool frame, the default target of a DH robot.
TOOL = "tool"

_ROW_KEYS = ("name", "type", "alpha", "a", "theta", "d", "lower", "upper", "parent")
_SECTION_KEYS = ("convention", "length_unit", "angle_unit", "joints", "base", "tool", "frames",
                 "links")
#: Default range of a revolute joint without limits (rad); a prismatic one is unbounded.
_REVOLUTE_RANGE = math.pi


@dataclass(frozen=True)
class DhRow:
    """One joint of the table, in SI.

    ``alpha``, ``theta`` (rad), ``a``, ``d`` (m); ``lower``, ``upper`` in rad (revolute) or m
    (prismatic); ``parent``: a row, a fixed frame or :data:`BASE`.
    """

    name: str
    kind: str
    alpha: float
    a: float
    theta: float
    d: float
    lower: float
    upper: float
    parent: str


@dataclass(frozen=True)
class FixedFrame:
    """A frame fixed to ``parent`` (a row's DH frame, another fixed frame or the base)."""

    name: str
    parent: str
    placement: pin.SE3


@dataclass(frozen=True)
class LinkInertia:
    """Mass (kg), centre of mass (m) and inertia about it (kg.m^2) in ``parent``'s DH frame."""

    parent: str
    mass: float
    com: np.ndarray
    inertia: np.ndarray


@dataclass(frozen=True)
class DhTable:
    """A ``[dh]`` section read into SI."""

    convention: str
    rows: tuple[DhRow, ...]
    base: pin.SE3
    frames: tuple[FixedFrame, ...]
    links: tuple[LinkInertia, ...]


class _Reader:
    """Typed reads of one [dh] section, each failure a one-line :class:`FileFormatError`
    naming the file, the row and the field."""

    def __init__(self, path: Path, section: dict) -> None:
        self.path = path
        self.section = section
        self.length = 1.0
        self.angle = 1.0
        self.length_unit = "m"
        self.angle_unit = "rad"

    def fail(self, where: str, problem: str) -> FileFormatError:
        return FileFormatError(problem, path=self.path, field=where)

    def choice(self, where: str, value: object, choices: tuple[str, ...]) -> str:
        if value not in choices:
            raise self.fail(where, f"{value!r} is not one of {', '.join(choices)}; "
                            f"{did_you_mean(str(value), choices)}")
        return str(value)

    def units(self) -> None:
        for key, choices in (("length_unit", DH_LENGTH_UNITS), ("angle_unit", DH_ANGLE_UNITS)):
            if key not in self.section:
                raise self.fail(f"[dh].{key}", f"missing; give {key} = "
                                f"{' or '.join(repr(c) for c in choices)}")
            self.choice(f"[dh].{key}", self.section[key], choices)
        self.length_unit, self.angle_unit = self.section["length_unit"], self.section["angle_unit"]
        self.length = LENGTH_UNITS[self.length_unit]
        self.angle = ANGLE_UNITS[self.angle_unit]

    def number(self, where: str, value: object) -> float:
        if not finite_number(value):
            raise self.fail(where, f"{value!r} is not a finite number")
        return float(value)

    def vector(self, where: str, value: object, size: int) -> np.ndarray:
        if not isinstance(value, list) or len(value) != size:
            raise self.fail(where, f"must be a list of {size} numbers, got {value!r}")
        return np.array([self.number(f"{where}[{i}]", v) for i, v in enumerate(value)])

    def table(self, where: str, value: object) -> dict:
        if not isinstance(value, dict):
            raise self.fail(where, f"must be a table ({{ key = value, ... }}), got {value!r}")
        return value

    def quantity(self, entry: dict, where: str, key: str, dimension: str) -> float | None:
        """``key`` of a row in SI, given plain (in the section's unit) or with a unit suffix
        (``a_mm``, ``theta_deg``) that must agree with the section's unit; None if absent."""
        declared = self.length_unit if dimension == "length" else self.angle_unit
        units = DH_LENGTH_UNITS if dimension == "length" else DH_ANGLE_UNITS
        given = [k for k in entry if k == key or (k.startswith(key + "_")
                                                    and k[len(key) + 1:] in units)]
        if not given:
            return None
        if len(given) > 1:
            raise self.fail(f"{where}.{given[1]}", f"{key} is given twice ({', '.join(given)})")
        field = given[0]
        unit = field[len(key) + 1:] if field != key else declared
        if unit != declared:
            raise self.fail(f"{where}.{field}", f"mixed units: {field} is in {unit} but [dh] "
                            f"{dimension}_unit is {declared!r}; give every {dimension} of the "
                            f"table in {declared} (or change {dimension}_unit)")
        factor = self.length if dimension == "length" else self.angle
        return self.number(f"{where}.{field}", entry[field]) * factor

    def placement(self, where: str, value: object) -> pin.SE3:
        """An ``{ xyz = [...], rpy = [...] }`` table (length_unit, angle_unit) as an SE3."""
        entry = self.table(where, value)
        extra = sorted(set(entry) - {"xyz", "rpy", "parent", "name"})
        if extra:
            raise self.fail(f"{where}.{extra[0]}", "unknown key; a placement has xyz "
                            f"({self.length_unit}), rpy ({self.angle_unit}), parent")
        xyz = self.vector(f"{where}.xyz", entry.get("xyz", [0.0, 0.0, 0.0]), 3) * self.length
        rpy = self.vector(f"{where}.rpy", entry.get("rpy", [0.0, 0.0, 0.0]), 3) * self.angle
        return pin.SE3(pin.rpy.rpyToMatrix(rpy), xyz)


def _row_where(index: int, entry: dict) -> str:
    name = entry.get("name")
    return f"[dh].joints row {index + 1}" + (f" ({name})" if isinstance(name, str) else "")


def _read_row(reader: _Reader, index: int, entry: object, previous: str) -> DhRow:
    where = _row_where(index, entry if isinstance(entry, dict) else {})
    entry = reader.table(where, entry)
    for key in entry:
        stem = key.rsplit("_", 1)[0] if key.rsplit("_", 1)[-1] in (
            DH_LENGTH_UNITS + DH_ANGLE_UNITS) else key
        if key not in _ROW_KEYS and stem not in _ROW_KEYS:
            raise reader.fail(f"{where}.{key}", f"unknown field; a row has "
                              f"{', '.join(_ROW_KEYS)}; {did_you_mean(key, _ROW_KEYS)}")
    name = entry.get("name")
    if not isinstance(name, str) or not name:
        raise reader.fail(f"{where}.name", "missing field name (the joint's name)")
    kind = reader.choice(f"{where}.type", entry.get("type", "revolute"), JOINT_TYPES)
    values = {}
    for key in ("alpha", "a", "theta", "d"):
        dimension = "angle" if key in ("alpha", "theta") else "length"
        value = reader.quantity(entry, where, key, dimension)
        if value is None:
            unit = reader.length_unit if dimension == "length" else reader.angle_unit
            raise reader.fail(f"{where}.{key}", f"missing field {key} ({dimension} in {unit}); "
                              "every row gives alpha, a, theta and d")
        values[key] = value
    travel = "angle" if kind == "revolute" else "length"
    default = _REVOLUTE_RANGE if kind == "revolute" else math.inf
    lower = reader.quantity(entry, where, "lower", travel)
    upper = reader.quantity(entry, where, "upper", travel)
    lower, upper = -default if lower is None else lower, default if upper is None else upper
    if not lower < upper:
        raise reader.fail(f"{where}.lower", f"lower limit {lower} must be below upper {upper} "
                          "(SI)")
    parent = entry.get("parent", previous)
    if not isinstance(parent, str):
        raise reader.fail(f"{where}.parent", f"must be a joint or frame name, got {parent!r}")
    return DhRow(name, kind, values["alpha"], values["a"], values["theta"], values["d"],
                 lower, upper, parent)


def _read_frames(reader: _Reader, value: object) -> list[FixedFrame]:
    if not isinstance(value, list):
        raise reader.fail("[dh].frames", "must be a list of { name, parent, xyz, rpy } tables")
    frames = []
    for i, entry in enumerate(value):
        where = f"[dh].frames row {i + 1}"
        entry = reader.table(where, entry)
        for key in ("name", "parent"):
            if not isinstance(entry.get(key), str):
                raise reader.fail(f"{where}.{key}", f"missing field {key} (a name)")
        frames.append(FixedFrame(entry["name"], entry["parent"], reader.placement(where, entry)))
    return frames


def _read_links(reader: _Reader, value: object, rows: list[DhRow]) -> list[LinkInertia]:
    """Links per row (no ``parent``: one per row, in order) or keyed by ``parent``."""
    if not isinstance(value, list):
        raise reader.fail("[dh].links", "must be a list of { mass, com, inertia } tables")
    keyed = [isinstance(e, dict) and "parent" in e for e in value]
    if any(keyed) and not all(keyed):
        raise reader.fail("[dh].links", "give parent in every link or in none (then one link "
                          "per joint row, in order)")
    if not any(keyed) and len(value) != len(rows):
        raise reader.fail("[dh].links", f"{len(value)} links for {len(rows)} joint rows: give "
                          "one per row, or key each by parent = \"<joint or frame>\"")
    links = []
    for i, entry in enumerate(value):
        where = f"[dh].links row {i + 1}"
        entry = reader.table(where, entry)
        extra = sorted(set(entry) - {"parent", "mass", "com", "inertia"})
        if extra:
            raise reader.fail(f"{where}.{extra[0]}", "unknown field; a link has parent, mass "
                              "(kg), com (m), inertia (kg.m^2: ixx, iyy, izz, ixy, ixz, iyz)")
        parent = entry["parent"] if any(keyed) else rows[i].name
        if not isinstance(parent, str):
            raise reader.fail(f"{where}.parent", f"must be a joint or frame name, got {parent!r}")
        if "mass" not in entry:
            raise reader.fail(f"{where}.mass", "missing field mass (kg)")
        mass = reader.number(f"{where}.mass", entry["mass"])
        if mass < 0:
            raise reader.fail(f"{where}.mass", f"a mass cannot be negative, got {mass} kg")
        com = reader.vector(f"{where}.com", entry.get("com", [0.0, 0.0, 0.0]), 3)
        six = reader.vector(f"{where}.inertia", entry.get("inertia", [0.0] * 6), 6)
        inertia = np.array([[six[0], six[3], six[4]], [six[3], six[1], six[5]],
                            [six[4], six[5], six[2]]])
        if np.linalg.eigvalsh(inertia).min() < -1e-12 * max(1.0, float(np.abs(six).max())):
            raise reader.fail(f"{where}.inertia", "not a physical inertia (not positive "
                              "semi-definite); give ixx, iyy, izz, ixy, ixz, iyz in kg.m^2 "
                              "about the centre of mass")
        links.append(LinkInertia(parent, mass, com, inertia))
    return links


def read_dh_table(section: object, path: str | Path) -> DhTable:
    """The ``[dh]`` section of the robot file ``path``, in SI.

    Raises
    ------
    FileFormatError
        One line naming the file, the row and the field: a missing or unknown field, an
        unknown convention, type or unit, units mixed within the table, a repeated name.
    """
    reader = _Reader(Path(path), {})
    section = reader.table("[dh]", section)
    reader.section = section
    extra = sorted(set(section) - set(_SECTION_KEYS))
    if extra:
        raise reader.fail(f"[dh].{extra[0]}", f"unknown key; [dh] has {', '.join(_SECTION_KEYS)}; "
                          f"{did_you_mean(extra[0], _SECTION_KEYS)}")
    if "convention" not in section:
        raise reader.fail("[dh].convention", "missing; give convention = \"modified\" (Craig) or "
                          "\"standard\"")
    convention = reader.choice("[dh].convention", section["convention"], CONVENTIONS)
    reader.units()
    joints = section.get("joints")
    if not isinstance(joints, list) or not joints:
        raise reader.fail("[dh].joints", "missing or empty: give one row per joint, base to tip")
    rows: list[DhRow] = []
    for i, entry in enumerate(joints):
        rows.append(_read_row(reader, i, entry, rows[-1].name if rows else BASE))
    base = reader.placement("[dh].base", section.get("base", {}))
    frames = _read_frames(reader, section.get("frames", []))
    tool = reader.table("[dh].tool", section.get("tool", {}))
    frames.append(FixedFrame(TOOL, str(tool.get("parent", rows[-1].name)),
                             reader.placement("[dh].tool", tool)))
    links = _read_links(reader, section["links"], rows) if "links" in section else []
    _check_names(reader, rows, frames, links)
    return DhTable(convention, tuple(rows), base, tuple(frames), tuple(links))


def _check_names(reader: _Reader, rows: list[DhRow], frames: list[FixedFrame],
                 links: list[LinkInertia]) -> None:
    """Distinct names; every parent a row before it, a fixed frame or the base."""
    seen: dict[str, str] = {BASE: "the base"}
    for i, row in enumerate(rows):
        for name in (row.name, f"{row.name}_link"):
            if name in seen:
                raise reader.fail(f"[dh].joints row {i + 1} ({row.name}).name",
                                  f"{name!r} is already {seen[name]}; give every joint and "
                                  "frame its own name")
            seen[name] = f"joint row {i + 1}"
    for i, frame in enumerate(frames):
        where = "[dh].tool" if frame.name == TOOL else f"[dh].frames row {i + 1}"
        if frame.name in seen or f"{frame.name}_joint" in seen:
            raise reader.fail(f"{where}.name", f"{frame.name!r} is already {seen.get(frame.name)}"
                              "; give every joint and frame its own name")
        seen[frame.name] = "a fixed frame"
        seen[f"{frame.name}_joint"] = "a fixed frame"
    known = [BASE] + [r.name for r in rows] + [f.name for f in frames]
    for i, row in enumerate(rows):
        _check_parent(reader, f"[dh].joints row {i + 1} ({row.name}).parent", row.parent, known)
        earlier = {BASE} | {r.name for r in rows[:i]} | {f.name for f in frames}
        if row.parent not in earlier:
            raise reader.fail(f"[dh].joints row {i + 1} ({row.name}).parent",
                              f"parent {row.parent!r} comes later in the table; list a joint "
                              "after its parent")
    for i, frame in enumerate(frames):
        where = "[dh].tool" if frame.name == TOOL else f"[dh].frames row {i + 1}"
        _check_parent(reader, f"{where}.parent", frame.parent, known)
    for i, link in enumerate(links):
        _check_parent(reader, f"[dh].links row {i + 1}.parent", link.parent, known)


def _check_parent(reader: _Reader, where: str, parent: str, known: list[str]) -> None:
    if parent not in known:
        raise reader.fail(where, f"unknown parent {parent!r}: a parent is a joint row, a fixed "
                          f"frame or \"base\"; {did_you_mean(parent, known)}")


def _rot_x(angle: float) -> pin.SE3:
    c, s = math.cos(angle), math.sin(angle)
    return pin.SE3(np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]), np.zeros(3))


def _rot_z(angle: float) -> pin.SE3:
    c, s = math.cos(angle), math.sin(angle)
    return pin.SE3(np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), np.zeros(3))


def _shift(x: float = 0.0, z: float = 0.0) -> pin.SE3:
    return pin.SE3(np.eye(3), np.array([x, 0.0, z]))


def row_transforms(row: DhRow, convention: str) -> tuple[pin.SE3, pin.SE3]:
    """``(before, after)``: the joint's placement in the parent's DH frame, and the row's DH
    frame in the joint's frame, at joint value zero (the row is ``before * motion * after``
    with ``motion`` Rz(q) or Tz(q))."""
    revolute = row.kind == "revolute"
    if convention == "standard":  # Rz(theta) Tz(d) Tx(a) Rx(alpha), joint about z_(i-1)
        before = _rot_z(row.theta) if revolute else _rot_z(row.theta) * _shift(z=row.d)
        after = (_shift(z=row.d) if revolute else pin.SE3.Identity()) \
            * _shift(x=row.a) * _rot_x(row.alpha)
        return before, after
    # modified: Rx(alpha) Tx(a) Rz(theta) Tz(d), joint about z_i; Rz(q) commutes with Tz(d)
    return _rot_x(row.alpha) * _shift(x=row.a) * _rot_z(row.theta) * _shift(z=row.d), \
        pin.SE3.Identity()


def _frame_resolver(table: DhTable, placed: dict[str, tuple[int, pin.SE3]], path: Path):
    """Where each fixed frame sits: (parent joint id, placement in that joint's frame), its
    chain of fixed parents resolved on demand (a cycle is an error)."""
    frames = {f.name: f for f in table.frames}

    def resolve(name: str, visiting: tuple[str, ...] = ()) -> tuple[int, pin.SE3]:
        if name in placed:
            return placed[name]
        if name in visiting:
            raise FileFormatError(f"the fixed frames {' -> '.join(visiting + (name,))} form a "
                                  "cycle; give each a parent up the tree", path=path,
                                  field=f"[dh].frames ({name}).parent")
        if name not in frames:  # a joint row not built yet: it comes later in the table
            raise FileFormatError(f"the joint {visiting[0]!r} hangs on {name!r} (through "
                                  f"{' -> '.join(visiting)}), which comes later in the table; "
                                  "list a joint after its parent", path=path,
                                  field=f"[dh].frames ({visiting[-1]}).parent")
        frame = frames[name]
        joint, above = resolve(frame.parent, visiting + (name,))
        placed[name] = (joint, above * frame.placement)
        return placed[name]
    return resolve


def build_dh_model(table: DhTable, name: str, path: str | Path) -> pin.Model:
    """The Pinocchio model of a DH table (module docstring), fixed base, SI.

    Joint ``row.name`` (``JointModelRZ`` or ``JointModelPZ``) with the row's limits; body frame
    ``<row>_link`` at each joint; ``base``, each fixed frame and ``tool`` as a fixed-joint
    frame and a body frame; the links' inertias appended to the joints that carry them.
    """
    model = pin.Model()
    model.name = name
    world = model.addFrame(pin.Frame("world", 0, 0, pin.SE3.Identity(), pin.FrameType.BODY))
    base_joint = model.addFrame(pin.Frame(f"{BASE}_joint", 0, world, table.base,
                                          pin.FrameType.FIXED_JOINT))
    body_of = {BASE: model.addFrame(pin.Frame(BASE, 0, base_joint, table.base,
                                              pin.FrameType.BODY))}
    placed: dict[str, tuple[int, pin.SE3]] = {BASE: (0, table.base)}
    resolve = _frame_resolver(table, placed, Path(path))
    for row in table.rows:
        parent_joint, above = resolve(row.parent)
        before, after = row_transforms(row, table.convention)
        joint = pin.JointModelRZ() if row.kind == "revolute" else pin.JointModelPZ()
        big = np.array([1e9])
        jid = model.addJoint(parent_joint, joint, above * before, row.name, big, big,
                             np.array([row.lower]), np.array([row.upper]))
        parent_frame = body_of.get(row.parent) or _frame_body(model, row.parent, resolve,
                                                              body_of, table)
        joint_frame = model.addJointFrame(jid, parent_frame)
        body_of[row.name] = model.addBodyFrame(f"{row.name}_link", jid, pin.SE3.Identity(),
                                               joint_frame)
        placed[row.name] = (jid, after)
    for frame in table.frames:
        _frame_body(model, frame.name, resolve, body_of, table)
    for link in table.links:
        jid, at = resolve(link.parent)
        model.appendBodyToJoint(jid, pin.Inertia(link.mass, link.com, link.inertia), at)
    return model


def _frame_body(model: pin.Model, name: str, resolve, body_of: dict[str, int],
                table: DhTable) -> int:
    """The body frame of a fixed frame (and of its fixed parents), added on first use."""
    if name in body_of:
        return body_of[name]
    frame = next(f for f in table.frames if f.name == name)
    parent_frame = _frame_body(model, frame.parent, resolve, body_of, table)
    jid, placement = resolve(name)
    fixed = model.addFrame(pin.Frame(f"{name}_joint", jid, parent_frame, placement,
                                     pin.FrameType.FIXED_JOINT))
    body_of[name] = model.addFrame(pin.Frame(name, jid, fixed, placement, pin.FrameType.BODY))
    return body_of[name]
