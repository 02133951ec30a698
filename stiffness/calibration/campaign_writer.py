"""Writing a campaign: ``campaign.toml`` and ``measurements.csv`` in the campaign's units,
published as one folder.
"""


from __future__ import annotations

import csv
import io
import os
from pathlib import Path

import numpy as np

from stiffness.calibration.campaign import Campaign
from stiffness.calibration.campaign_toml import CAMPAIGN_FILE, DEFAULT_DATA_FILE, RobotSettings
from stiffness.calibration.measurements import (
    MOMENT_COLUMNS,
    ROTATION_COLUMNS,
    expected_header,
    prismatic_mask,
)
from stiffness.files import (
    atomic_write,
    number_text,
    staged_folder,
    written_path,
    written_source,
)
from stiffness.units import Units


def _toml_string(text: str) -> str:
    out = ['"']
    for ch in text:
        if ch in '"\\':
            out.append("\\" + ch)
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04X}")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)


def write_campaign(campaign_like, folder: str | os.PathLike) -> Path:
    """Write a campaign as ``campaign.toml`` plus its CSV in ``folder``, published as one folder.

    The folder is built beside ``folder`` and renamed over it
    (:func:`stiffness.files.staged_folder`; other files already in ``folder``, such as the
    robot's URDF, are kept), so a reader never sees a half-written campaign.

    Parameters
    ----------
    campaign_like
        A :class:`Campaign`, or any object with its attributes (``name``, ``baseline``,
        ``robot_settings``, ``q``, ``force``, ``deflection`` and optionally ``config``,
        ``moment``, ``rotation``, ``noise_std_m``, ``units``, ``data_file``, ``path``). Values
        are SI; they are written in the campaign's units (default deg, N, mm).
    folder
        Destination folder, created if missing.

    Returns
    -------
    Path
        The written ``campaign.toml``.

    Raises
    ------
    StiffnessError
        If the campaign is inconsistent (shapes, units, baseline), or its robot cannot be
        loaded (it tells angle coordinates from prismatic lengths).
    """
    c = campaign_like
    if not isinstance(c, Campaign):
        c = Campaign(
            name=c.name, baseline=c.baseline, robot_settings=c.robot_settings, q=c.q,
            force=c.force, deflection=c.deflection, config=tuple(getattr(c, "config", None) or ()),
            moment=getattr(c, "moment", None), rotation=getattr(c, "rotation", None),
            noise_std_m=getattr(c, "noise_std_m", None), units=getattr(c, "units", Units()),
            path=getattr(c, "path", None),
            data_file=getattr(c, "data_file", DEFAULT_DATA_FILE),
            _robot=getattr(c, "_robot", None),
            rotation_noise_std_rad=getattr(c, "rotation_noise_std_rad", None),
        )
    folder = Path(folder)
    u = c.units
    data_name = Path(c.data_file).name or DEFAULT_DATA_FILE
    n_q = c.q.shape[1]
    prismatic = prismatic_mask(c.robot())
    q_out = c.q.copy()
    q_out[:, ~prismatic] /= u.angle_to_si
    q_out[:, prismatic] /= u.length_to_si

    header = expected_header(n_q)
    blocks = [q_out, c.force / u.force_to_si, c.deflection / u.length_to_si]
    if c.moment is not None:
        header += list(MOMENT_COLUMNS)
        blocks.append(c.moment / u.moment_to_si)
    if c.rotation is not None:
        header += list(ROTATION_COLUMNS)
        blocks.append(c.rotation / u.rotation_to_si)
    table = np.hstack(blocks)
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(header)
    for label, row in zip(c.config, table, strict=True):
        writer.writerow([label, *(number_text(v) for v in row)])
    with staged_folder(folder, keep_others=True) as stage:  # published by one rename
        atomic_write(stage / data_name, out.getvalue())
        atomic_write(stage / CAMPAIGN_FILE, campaign_toml(c, folder))
    return folder / CAMPAIGN_FILE


def robot_toml(s: RobotSettings, u: Units, folder: Path, campaign_folder: Path,
               deflections: bool = True) -> list[str]:
    """The ``[robot]`` table of a campaign written into ``folder`` (its paths, relative to
    ``campaign_folder``, made relative to ``folder``), lengths in ``u``; a pose campaign's
    (``deflections`` false) writes its target offset only when not zero and no
    ``joint_angles``."""
    source = written_source(s.source, folder, campaign_folder)
    toml = ["[robot]", f"source = {_toml_string(source)}"]
    if s.frame is not None:
        toml.append(f"frame = {_toml_string(s.frame)}")
    if deflections or np.any(s.target_offset_m != 0):
        offset = ", ".join(number_text(v / u.length_to_si) for v in s.target_offset_m)
        toml.append(f"target_offset = [{offset}]")
    if s.compliant_joints is not None:
        joints = ", ".join(_toml_string(j) for j in s.compliant_joints)
        toml.append(f"compliant_joints = [{joints}]")
    if s.loops is not None:
        toml.append(f"loops = {_toml_string(written_path(s.loops, folder, campaign_folder))}")
    if s.fixed_base:
        toml.append("fixed_base = true")
    if deflections:
        toml.append(f"joint_angles = {_toml_string(s.joint_angles)}")
    return toml


def campaign_toml(c: Campaign, folder: str | os.PathLike) -> str:
    """The ``campaign.toml`` text of ``c`` written into ``folder`` (a relative URDF source is
    made relative to ``folder``); its ``[measurement] data`` is ``c.data_file``'s name."""
    folder = Path(folder)
    u = c.units
    data_name = Path(c.data_file).name or DEFAULT_DATA_FILE
    toml = [
        "# Measurement campaign (its format: stiffness/calibration/campaign.py).",
        f"name = {_toml_string(c.name)}",
        f"baseline = {_toml_string(c.baseline)}",
        "",
        *robot_toml(c.robot_settings, u, folder, c.folder()),
        "",
        "[units]",
        f"angle = {_toml_string(u.angle)}",
        f"force = {_toml_string(u.force)}",
        f"length = {_toml_string(u.length)}",
        *([f"rotation = {_toml_string(u.rotation_unit)}"]
          if u.rotation_unit is not None and c.rotation is not None else []),
        *([f"moment = {_toml_string(u.moment_unit)}"]
          if u.moment_unit is not None and c.moment is not None else []),
        "",
        "[measurement]",
        f"data = {_toml_string(data_name)}",
    ]
    if c.noise_std_m is not None:
        toml.append(f"noise_std = {number_text(c.noise_std_m / u.length_to_si)}")
    if c.rotation_noise_std_rad is not None:
        noise = number_text(c.rotation_noise_std_rad / u.rotation_to_si)
        toml.append(f"rotation_noise_std = {noise}")
    return "\n".join(toml) + "\n"
