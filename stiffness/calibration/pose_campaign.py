"""Pose campaigns: absolute marker positions measured at commanded coordinates.

A pose campaign (``kind = "poses"`` in its ``campaign.toml``, docs/absolute-poses.md) holds, per
row, a configuration label, the commanded coordinates ``q1..qn`` and the position of each marker
in the measuring system's frame (``<marker>_x, <marker>_y, <marker>_z``; a marker's three cells
empty where it was not seen), optionally its orientation (``<marker>_rx, _ry, _rz``: the rotation
vector of the marker's frame in the measuring frame, ``[units] rotation`` unit, default the
angle unit; noise ``[measurement] rotation_noise_std``, or ``noise_std_rotation``, in that
unit), optionally the applied wrench ``fx, fy, fz[, mx, my, mz]`` (world axes, at
``[load] frame``). Gravity always acts.
Units as in deflection campaigns; in memory SI.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.calibration.campaign_toml import (
    CAMPAIGN_FILE,
    ROTATION_NOISE_KEYS,
    RobotSettings,
    TomlFile,
    campaign_robot,
    check_table_keys,
    read_campaign_toml,
    rotation_noise,
)
from stiffness.calibration.campaign_writer import robot_toml
from stiffness.calibration.coordinate_columns import (
    canonical_header,
    fill_held,
    first_column_problem,
    fixed_values,
    held_coordinates,
    is_blank_row,
    is_units_row,
    locate_coordinates,
    trim_empty_columns,
    warn_commented_rows,
    warn_unknown,
)
from stiffness.calibration.measurements import (
    coordinates_in_si,
    parse_number,
    warn_copied_markers,
    warn_copied_rows,
)
from stiffness.calibration.pose_model import Loads, Marker
from stiffness.calibration.probe_mounting import check_marker_mounting
from stiffness.calibration.unit_checks import check_marker_offsets, check_marker_spread
from stiffness.errors import DataFileWarning, FileFormatError, StiffnessError, did_you_mean
from stiffness.files import (
    atomic_write,
    check_csv_header,
    csv_cells,
    number_text,
    read_text,
    staged_folder,
)
from stiffness.robot.robot import Robot
from stiffness.units import Units, three_numbers

_KEYS = {
    "": {"kind", "name", "robot", "units", "measurement", "markers", "load"},
    "robot": {"source", "frame", "target_offset", "compliant_joints", "loops", "fixed_base",
              "fixed"},
    "units": {"angle", "force", "length", "rotation", "moment"},
    "measurement": {"data", "noise_std", *ROTATION_NOISE_KEYS},
    "load": {"frame"},
}
_REQUIRED = {"": ("kind", "robot", "units", "measurement", "markers"),
             "robot": ("source",), "units": ("angle", "length"), "measurement": ("data",),
             "load": ()}
_WRENCH = ("fx", "fy", "fz", "mx", "my", "mz")
#: Suffixes of a marker's orientation columns (rotation vector, measuring frame).
ROTATION_AXES = ("rx", "ry", "rz")


@dataclass
class PoseCampaign:
    """A pose campaign in SI.

    Attributes
    ----------
    name
        Campaign label.
    robot
        The loaded robot of ``[robot]``.
    settings
        The ``[robot]`` table (source, frame, compliant joints...).
    units
        Units of the files.
    markers
        The markers, with their nominal offsets (m), flagged ``oriented`` where a row
        measures their orientation.
    labels
        Configuration label of each row.
    q
        (n, n_coordinates) commanded coordinates (rad, m).
    positions
        (n, M, 3) measured positions (m, measuring frame); NaN where a marker was not seen.
    loads
        Applied wrenches (world axes, N and N.m) at a frame, or ``None``.
    noise_std
        Declared position noise (m), or ``None``.
    path
        The campaign.toml, or ``None`` for a campaign built in memory.
    rotations
        (n, M, 3) measured orientations of the markers' frames in the measuring frame
        (rotation vectors, rad); NaN where not measured; ``None`` without rotation columns.
    noise_std_rotation
        Declared rotation noise (rad, per component), or ``None``.
    lines
        Each row's line in the measurement CSV, or ``None`` for a campaign built in memory.
    """

    name: str
    robot: Robot
    settings: RobotSettings
    units: Units
    markers: list[Marker]
    labels: list[str]
    q: np.ndarray
    positions: np.ndarray
    loads: Loads | None = None
    noise_std: float | None = None
    path: Path | None = None
    rotations: np.ndarray | None = None
    noise_std_rotation: float | None = None
    lines: tuple[int, ...] | None = None

    def __post_init__(self) -> None:
        """Flag the markers whose orientation is measured on some row (their mounting turn is
        then fitted, :class:`~stiffness.calibration.pose_model.Marker`); a subset keeps its
        campaign's flags, so that every fold fits the same parameters. A rotation noise
        without measured orientations is refused (one line), as a deflection campaign's."""
        if self.noise_std_rotation is not None and self.rotations is None:
            raise StiffnessError("noise_std_rotation is given but the campaign has no measured "
                                 "orientations (<marker>_rx,_ry,_rz); add them or drop "
                                 "noise_std_rotation")
        if self.rotations is not None:
            seen = np.isfinite(self.rotations).all(axis=-1).any(axis=0)
            self.markers = [m if m.oriented or not seen[k] else replace(m, oriented=True)
                            for k, m in enumerate(self.markers)]

    @property
    def n_rows(self) -> int:
        """Number of rows."""
        return len(self.labels)

    @cached_property
    def configurations(self) -> np.ndarray:
        """(n, nq) each row's full Pinocchio configuration (:meth:`Robot.configuration`, loops
        closed), computed once: every model of a diagnosis reads them."""
        return np.array([self.robot.configuration(q) for q in self.q]).reshape(self.n_rows, -1)

    def folder(self) -> Path:
        """Folder the ``[robot]`` paths are relative to (the campaign file's, else the working
        directory: an imported campaign's paths are as given on the command line)."""
        return self.path.parent if self.path is not None else Path.cwd()

    @property
    def n_observed(self) -> int:
        """Number of measured position components (3 per seen marker)."""
        return int(np.isfinite(self.positions).sum())

    def subset(self, rows: np.ndarray) -> PoseCampaign:
        """The campaign restricted to ``rows`` (indices or a mask)."""
        idx = np.arange(self.n_rows)[rows]
        return replace(self, labels=[self.labels[i] for i in idx], q=self.q[idx],
                       positions=self.positions[idx], loads=None if self.loads is None
                       else Loads(self.loads.frame, self.loads.wrench[idx]),
                       rotations=None if self.rotations is None else self.rotations[idx],
                       lines=None if self.lines is None else tuple(self.lines[i] for i in idx))


def loads_no_spring(campaign: PoseCampaign) -> bool:
    """Whether nothing in ``campaign`` loads a spring: its robot's links have no mass (a robot
    file without ``<inertial>``, as ROS-Industrial's) and it applies no wrench (no ``fx..mz``
    columns, or all zero). Gravity then bends no joint and the poses hold nothing of the
    springs' stiffness."""
    mass = sum(float(inertia.mass) for inertia in campaign.robot.model.inertias)
    loads = campaign.loads
    return mass <= 0 and (loads is None or not bool(np.any(loads.wrench != 0)))


def _check_table(doc: dict, section: str, toml: TomlFile) -> None:
    check_table_keys(doc, section, toml, _KEYS[section], _REQUIRED[section],
                     lambda key, label: f"missing key {key} in {label} of a pose campaign: "
                                        "see docs/absolute-poses.md", " of a pose campaign")


def _markers(doc: dict, toml: TomlFile, units: Units) -> list[Marker]:
    table = doc["markers"]
    if not isinstance(table, dict) or not table:
        raise toml.error("[markers] must name at least one marker, e.g. "
                         'tip = { frame = "tool0" }', "", "markers")
    out = []
    for name, spec in table.items():
        if not isinstance(spec, dict) or not isinstance(spec.get("frame"), str):
            raise toml.error(f"[markers] {name} must be a table with frame = \"<frame name>\"",
                             "markers", name)
        extra = set(spec) - {"frame", "offset", "rotation"}
        if extra:
            raise toml.error(f"[markers] {name}: unknown key(s) {sorted(extra)}; valid: frame, "
                             "offset, rotation", "markers", name)
        offset = spec.get("offset", [0.0, 0.0, 0.0])
        if not three_numbers(offset):
            raise toml.error(f"[markers] {name}: offset must be three finite numbers in "
                             f"{units.length}, got {offset!r}", "markers", name)
        turn = spec.get("rotation", [0.0, 0.0, 0.0])
        if not three_numbers(turn):
            raise toml.error(f"[markers] {name}: rotation must be three finite numbers (a "
                             f"rotation vector in {units.rotation}), got {turn!r}", "markers",
                             name)
        out.append(Marker(name, spec["frame"], np.array(offset, float) * units.length_to_si,
                          pin.exp3(np.array(turn, float) * units.rotation_to_si)))
    return out


def _header(cells: list[str], data: Path, line: int, robot: Robot, markers: list[Marker]
            ) -> tuple[list[int | None], list[list[int]], list[int], list[list[int] | None]]:
    """Check the header; (each coordinate's column or ``None`` when held, each marker's x, y,
    z columns, the wrench columns, each marker's rx, ry, rz columns or ``None``)."""
    names = [c.strip() for c in cells]
    if not names or names[0] != "config":
        raise FileFormatError(f"the first column must be config, {first_column_problem(names)};"
                              " then the "
                              f"coordinates (q1..q{robot.n_coordinates}, or columns named after "
                              "the joints) and the markers' columns", path=data, line=line)
    twice = sorted({c for c in names if names.count(c) > 1})
    if twice:
        raise FileFormatError(f"column(s) {twice} appear more than once; keep one of each",
                              path=data, line=line)
    coordinates = locate_coordinates(names, robot, data, line)
    columns = []
    for m in markers:
        cols = [f"{m.name}_{a}" for a in "xyz"]
        if not all(c in names for c in cols):
            cased = [f"{n} as {c}" for c in cols for n in names
                     if n.lower() == c.lower() and n != c]
            raise FileFormatError(f"marker {m.name!r} of [markers] has no columns "
                                  f"{', '.join(cols)}; " + (
                                      f"rename {', '.join(cased)} (names are exact)" if cased
                                      else "add them (empty cells where it was not seen)"),
                                  path=data, line=line)
        columns.append([names.index(c) for c in cols])
    present = [c for c in _WRENCH if c in names]
    taken = {0, *(i for i in coordinates if i is not None)}
    known = {f"{m.name}_{a}" for m in markers for a in ("x", "y", "z", *ROTATION_AXES)} | set(
        _WRENCH)
    warn_unknown([c for i, c in enumerate(names) if i not in taken and c not in known], data,
                 "a pose campaign has config, the coordinates, <marker>_x/_y/_z per marker "
                 "(optionally _rx/_ry/_rz) and optionally fx..mz")
    if present and present not in (list(_WRENCH[:3]), list(_WRENCH)):
        raise FileFormatError("give the applied wrench as fx,fy,fz or fx,fy,fz,mx,my,mz",
                              path=data, line=line)
    return coordinates, columns, [names.index(c) for c in present], _rotation_columns(
        names, markers, data, line)


def _rotation_columns(names: list[str], markers: list[Marker], data: Path, line: int
                      ) -> list[list[int] | None]:
    """Each marker's rx, ry, rz columns, or ``None`` without them (some but not all refused)."""
    out: list[list[int] | None] = []
    for m in markers:
        cols = [f"{m.name}_{a}" for a in ROTATION_AXES]
        present = [c in names for c in cols]
        if any(present) and not all(present):
            raise FileFormatError(f"marker {m.name!r} has some of {', '.join(cols)}; give all "
                                  "three rotation columns or none", path=data, line=line)
        out.append([names.index(c) for c in cols] if all(present) else None)
    return out


def _rows(data: Path, robot: Robot, markers: list[Marker]
          ) -> tuple[list[str], list[int | None], np.ndarray, np.ndarray, np.ndarray | None,
                     list[int], np.ndarray | None]:
    """Labels, each coordinate's column (``None``: held), the read coordinates (file units,
    NaN where held), positions (file units, NaN unseen), wrench (file units), line numbers,
    rotations (file units, NaN unseen; ``None`` without rotation columns)."""
    text = read_text(data, "measurement file ([measurement] data)")
    lines: list[tuple[int, list[str]]] = []
    comments: list[tuple[int, str]] = []
    for number, raw in enumerate(text.splitlines(), start=1):
        if raw.lstrip().startswith("#"):  # a line at a time: a quote in a comment is text
            if lines:
                comments.append((number, raw))
            continue
        cells = csv_cells(raw, data, number)
        if not is_blank_row(cells):
            lines.append((number, cells))
    if lines:
        check_csv_header(lines[0][1], data, lines[0][0])
    if len(lines) < 2:
        raise FileFormatError("no data rows after the header", path=data)
    known = ["config", *robot.coordinate_joints, *_WRENCH, *(
        f"{m.name}_{a}" for m in markers for a in ("x", "y", "z", *ROTATION_AXES))]
    header, cells_of = trim_empty_columns(canonical_header(lines[0][1], known),
                                          [cells for _, cells in lines[1:]])
    lines = [lines[0], *((number, cells) for (number, _), cells in zip(lines[1:], cells_of,
                                                                       strict=True))]
    warn_commented_rows(comments, len(header), data)
    if is_units_row(lines[1][1]):
        raise FileFormatError(
            f"a units row ({', '.join(c.strip() for c in lines[1][1] if c.strip())}), not "
            "measurements: a campaign's CSV holds numbers, its units are campaign.toml's "
            "[units]; delete the row, or read the rig's file with `stiffness campaign import "
            "--kind poses`, which reads a units row", path=data, line=lines[1][0])
    coordinates, columns, wrench_cols, rot_columns = _header(header, data, lines[0][0], robot,
                                                                 markers)
    labels, q, pos, wrench, numbers, rot = [], [], [], [], [], []
    for number, cells in lines[1:]:
        if len(cells) != len(header):
            raise FileFormatError(f"{len(cells)} cells, the header has {len(header)}; give one "
                                  "cell per column", path=data, line=number)
        labels.append(cells[0].strip())
        q.append([math.nan if j is None else parse_number(cells[j], data, number, j + 1,
                                                          header[j])
                  for j in coordinates])
        pos.append([_position(cells, c, data, number, m.name)
                    for c, m in zip(columns, markers, strict=True)])
        wrench.append([parse_number(cells[j], data, number, j + 1, "load")
                       for j in wrench_cols])
        rot.append([[math.nan] * 3 if c is None else _position(cells, c, data, number, m.name,
                                                               ROTATION_AXES)
                    for c, m in zip(rot_columns, markers, strict=True)])
        numbers.append(number)
    w = np.array(wrench, float) if wrench_cols else None
    r = np.array(rot, float) if any(c is not None for c in rot_columns) else None
    return (labels, coordinates, np.array(q, float).reshape(len(labels), -1),
            np.array(pos, float), w, numbers, r)


def _position(cells: list[str], columns: list[int], data: Path, line: int, name: str,
              axes: tuple[str, ...] = ("x", "y", "z")) -> list[float]:
    raw = [cells[c].strip() for c in columns]
    unseen = [c.casefold() in ("", "nan") for c in raw]  # a tracker writes NaN for a dropout
    if all(unseen):
        return [math.nan] * 3
    if any(unseen):
        raise FileFormatError(f"marker {name!r} has some but not all of its three cells; leave "
                              "all three empty (or NaN) where it was not seen", path=data,
                              line=line)
    return [parse_number(c, data, line, columns[i] + 1, f"{name}_{axes[i]}")
            for i, c in enumerate(raw)]


def load_pose_campaign(path: str | os.PathLike) -> PoseCampaign:
    """Read and validate a pose campaign (a ``campaign.toml`` with ``kind = "poses"``).

    Raises
    ------
    StiffnessError
        Missing file, unknown or missing keys, unknown units, a marker on a frame the robot
        lacks, a CSV with missing columns, partial marker cells or non-numeric cells (file,
        line and column named).
    """
    toml_path = Path(path)
    if toml_path.is_dir():
        toml_path = toml_path / CAMPAIGN_FILE
    doc, toml = read_campaign_toml(toml_path, _check_table, ("robot", "units", "measurement",
                                                             "load"))
    doc["units"].setdefault("force", "N")
    if doc["kind"] != "poses":
        raise toml.error(f"kind = {doc['kind']!r}: this reader takes pose campaigns "
                         '(kind = "poses")', "", "kind")
    units, settings, robot, data_name, noise = campaign_robot(doc, toml, toml_path)
    markers = _markers(doc, toml, units)
    for m in markers:
        if not robot.model.existFrame(m.frame):
            raise toml.error(f"[markers] {m.name}: frame {m.frame!r} is not a frame of "
                             f"{robot.title}; "
                             f"{did_you_mean(m.frame, [f.name for f in robot.model.frames])}",
                             "markers", m.name)
    data = toml_path.parent / data_name
    labels, coordinates, q_read, pos, wrench, numbers, rot = _rows(data, robot, markers)
    warn_copied_rows(np.column_stack([a.reshape(len(labels), -1) for a in (q_read, pos, wrench,
                                                                           rot) if a is not None]),
                     numbers, data)
    warn_copied_markers([m.name for m in markers], pos, data)
    unseen = [m.name for k, m in enumerate(markers) if not np.isfinite(pos[:, k]).any()]
    if unseen and len(unseen) < len(markers):  # none seen: the fit refuses, naming the counts
        warnings.warn(f"{data}: marker(s) {', '.join(unseen)} of [markers] are seen on no row "
                      "(their cells all empty): nothing calibrates their offsets; map them to "
                      "the tracker's columns, or drop them from [markers]", DataFileWarning,
                      stacklevel=2)
    fixed = fixed_values(settings.fixed, robot, units,
                         lambda problem: toml.error(problem, "robot", "fixed"))
    held = held_coordinates(robot, coordinates, fixed, units, data,
                            lambda problem: toml.error(problem, "robot", "fixed"))
    q = coordinates_in_si(robot, fill_held(q_read, held, robot, units), units, labels,
                          numbers, data)
    offsets = np.array([m.offset for m in markers])
    check_marker_offsets(robot, [m.name for m in markers], offsets, units,
                         f"{toml_path} [markers]")
    check_marker_spread(robot, [m.frame for m in markers], offsets, q,
                        pos * units.length_to_si, units, data)
    check_marker_mounting(robot, markers, q, pos * units.length_to_si,
                          None if rot is None else rot * units.rotation_to_si, units, data)
    loads = None if wrench is None else Loads.read(
        str(doc.get("load", {}).get("frame", robot.target_frame)), wrench[:, :3],
        wrench[:, 3:] if wrench.shape[1] == 6 else None, units)
    return PoseCampaign(str(doc.get("name", toml_path.parent.name)), robot, settings, units,
                        markers, labels, q, pos * units.length_to_si, loads,
                        None if noise is None else noise * units.length_to_si, toml_path,
                        None if rot is None else rot * units.rotation_to_si,
                        _rotation_noise(doc, toml, units, rot is not None), tuple(numbers))


def _rotation_noise(doc: dict, toml: TomlFile, units: Units, measured: bool) -> float | None:
    """``[measurement] rotation_noise_std`` (or ``noise_std_rotation``) in rad, or None;
    refused without rotation columns."""
    noise, key = rotation_noise(doc, toml, units.rotation)
    if noise is None:
        return None
    if not measured:
        raise toml.error(f"[measurement] {key} is given but no marker has "
                         "<marker>_rx,_ry,_rz columns; add them or drop the key",
                         "measurement", key)
    return float(noise) * units.rotation_to_si


def write_pose_campaign(c: PoseCampaign, folder: str | os.PathLike) -> Path:
    """Write ``c`` as ``folder/campaign.toml`` and ``measurements.csv`` in its units (the
    robot's paths relative to ``folder``, :func:`~stiffness.files.written_path`)."""
    folder = Path(folder)
    u = c.units
    lines = ['kind = "poses"', f'name = "{c.name}"', "",
             *robot_toml(c.settings, u, folder, c.folder(), deflections=False), "", "[units]",
             f'angle = "{u.angle}"', f'force = "{u.force}"', f'length = "{u.length}"']
    if c.rotations is not None:
        lines.append(f'rotation = "{u.rotation}"')
    lines += ["", "[measurement]", 'data = "measurements.csv"']
    if c.noise_std is not None:
        lines.append(f"noise_std = {c.noise_std / u.length_to_si!r}")
    if c.noise_std_rotation is not None and c.rotations is not None:
        lines.append(f"rotation_noise_std = {c.noise_std_rotation / u.rotation_to_si!r}")
    if c.loads is not None:
        lines += ["", "[load]", f'frame = "{c.loads.frame}"']
    lines += ["", "[markers]"] + [
        f'{m.name} = {{ frame = "{m.frame}", offset = ['
        + ", ".join(number_text(v / u.length_to_si) for v in m.offset) + "]"
        + ("" if np.allclose(m.rotation, np.eye(3), rtol=0, atol=1e-15) else ", rotation = ["
           + ", ".join(number_text(v / u.rotation_to_si) for v in pin.log3(m.rotation)) + "]")
        + " }" for m in c.markers]
    with staged_folder(folder, keep_others=True) as stage:  # published by one rename
        atomic_write(stage / CAMPAIGN_FILE, "\n".join(lines) + "\n")
        atomic_write(stage / "measurements.csv", _csv_text(c))
    return folder / CAMPAIGN_FILE


def _csv_text(c: PoseCampaign) -> str:
    u = c.units
    header = ["config"] + [f"q{i + 1}" for i in range(c.q.shape[1])] + [
        f"{m.name}_{a}" for m in c.markers for a in "xyz"]
    if c.rotations is not None:
        header += [f"{m.name}_{a}" for m in c.markers for a in ROTATION_AXES]
    if c.loads is not None:
        header += list(_WRENCH)
    prismatic = np.array([c.robot.is_prismatic(j) for j in c.robot.coordinate_joints])
    q = np.where(prismatic, c.q / u.length_to_si, c.q / u.angle_to_si)
    out = [",".join(header)]
    for i, label in enumerate(c.labels):
        cells = [label] + [number_text(v) for v in q[i]]
        for k in range(len(c.markers)):
            p = c.positions[i, k] / u.length_to_si
            cells += ["", "", ""] if not np.all(np.isfinite(p)) else [number_text(v) for v in p]
        for r in ([] if c.rotations is None else c.rotations[i] / u.rotation_to_si):
            cells += ["", "", ""] if not np.all(np.isfinite(r)) else [number_text(v) for v in r]
        if c.loads is not None:
            w = c.loads.wrench[i]
            cells += [number_text(v / u.force_to_si) for v in w[:3]]
            cells += [number_text(v / u.moment_to_si) for v in w[3:]]
        out.append(",".join(cells))
    return "\n".join(out) + "\n"
