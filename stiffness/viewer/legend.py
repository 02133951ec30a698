"""The page's legend and live controls of a scene (the overlay JSON of
:func:`stiffness.viewer.page.render_page`): what is drawn, in which units and scales.

Values as the legend prints them: joint coordinates in deg (m for prismatic joints), loads in
N and N.m, stiffness in N/m, compliance in m/N.
"""

from __future__ import annotations

import numpy as np

from stiffness.mechanics.ik import coordinate_limits
from stiffness.robot.robot import Robot
from stiffness.viewer.ellipsoid import QUANTITIES
from stiffness.viewer.states import (
    AXIS_NAMES,
    DEFLECTED_NODE,
    FIELD_CLIP,
    FIELD_NODE,
    ROTATIONAL_NODE,
    SHOW_FORMULATIONS,
    STIFFNESS_NODE,
    FieldState,
    SceneState,
)
from stiffness.viewer.style import (
    COLORMAPS,
    DEFLECTED_RGBA,
    FORCE_COLOR,
    FORMULATION_LABELS,
    ROTATIONAL_COLOR,
    color_of,
    colorbar_colors,
    format_value,
    hex_color,
    nice_above,
)


def display_coords(robot: Robot, coords: np.ndarray) -> np.ndarray:
    """Coordinates as the page shows them: deg for angles, m for prismatic joints."""
    out = np.array(coords, dtype=float)
    for i, name in enumerate(robot.coordinate_joints):
        if not robot.is_prismatic(name):
            out[i] = np.rad2deg(out[i])
    return out



def path_frame_rows(robot: Robot, states: list[SceneState]) -> list[str]:
    """One line per frame of an animated path: its coordinates and principal values (units
    of the first frame's quantity)."""
    unit = "N/m" if states[0].quantity == "stiffness" else "m/N"
    return [
        "coordinates [" + ", ".join(format_value(v) for v in
                                    display_coords(robot, st.coords)) + "]; " + "; ".join(
            f"{n}: [{', '.join(format_value(v) for v in e.values)}] {unit}"
            for n, e in st.ellipsoids.items()) for st in states]


def scene_legend(data: dict, robot: Robot, st: SceneState, quantity: str,
                 color_range: tuple[float, float], size: float, arrow_scale: float | None
                 ) -> None:
    """Add the lines, legend entries, labels, notes and toggles of a shown scene to ``data``
    (``size``: the largest ellipsoid radius, m; ``arrow_scale``: m per N of the load arrow)."""
    deg = [format_value(v) for v in display_coords(robot, st.coords)]
    data["lines"].append(f"coordinates ({', '.join(robot.coordinate_joints)}): "
                         f"[{', '.join(deg)}] (deg; m for prismatic)")
    f = st.wrench[:3]
    if not np.any(st.wrench):
        data["lines"].append("no load: the unloaded stiffness (K_C = 0, so enhanced "
                             "and conventional coincide)")
    data["lines"].append(
        f"load F = [{', '.join(format_value(v) for v in f)}] N "
        f"(|F| = {format_value(float(np.linalg.norm(f)), 'N')})"
        + (f", M = [{', '.join(format_value(v) for v in st.wrench[3:])}] N.m"
           if np.any(st.wrench[3:]) else "") + ", base axes")
    ellipsoid_legend(data, st, quantity, color_range)
    unit = "N/m" if quantity == "stiffness" else "m/N"
    data["notes"].append(
        f"radius = {format_value(st.scale, 'm')} per {unit} of principal value "
        f"(axis i along eigenvector i; {format_value(size, 'm')} = "
        f"{format_value(size / st.scale, unit)}); axes 1, 2, 3 red, green, blue")
    if st.rotational is not None:
        block = st.rotational
        data["legend"].append({
            "color": hex_color([int(ROTATIONAL_COLOR >> s & 255) / 255 for s in (16, 8, 0)]),
            "text": f"rotational block of the 6x6 {block.formulation} {quantity} "
                    f"(hidden at first; own scale, largest radius "
                    f"{format_value(size, 'm')}): principal values "
                    f"[{', '.join(format_value(v) for v in block.values)}] "
                    f"{block.units}"})
        data["toggles"].append({"label": f"rotational {quantity} ({block.units})",
                                "path": ["meshcat", ROTATIONAL_NODE]})
        data["labels"].append({"text": f"rotational ({block.units})", "kind": "name",
                               "anchor": ["meshcat", ROTATIONAL_NODE, "label"],
                               "center": ["meshcat", ROTATIONAL_NODE, "surface"]})
    if arrow_scale:
        data["legend"].append({
            "color": hex_color([int(FORCE_COLOR >> s & 255) / 255 for s in (16, 8, 0)]),
            "text": f"load arrow: 1 m = {format_value(1 / arrow_scale, 'N')}"})
    if st.deflection is not None:
        data["legend"].append({
            "color": hex_color(DEFLECTED_RGBA),
            "text": f"deflected robot (exact equilibrium), deflection x "
                    f"{format_value(st.exaggeration)}: target moves "
                    f"{format_value(1e3 * float(np.linalg.norm(st.deflection)), 'mm')} "
                    f"(red line, also x {format_value(st.exaggeration)})"})
    if st.note:
        data["notes"].append(st.note)
    data["toggles"].append({"label": "deflected robot", "path": ["meshcat",
                                                                 DEFLECTED_NODE]})


def ellipsoid_legend(data: dict, st: SceneState, quantity: str,
                     color_range: tuple[float, float]) -> None:
    """Add each drawn ellipsoid's labels, legend entry (principal values), colour bar and
    toggle to ``data``, and how far the two formulations' principal values differ."""
    lo, hi = color_range
    symbol = "k" if quantity == "stiffness" else "c"
    for name, ell in st.ellipsoids.items():
        values = ", ".join(format_value(v) for v in ell.values)
        base = ["meshcat", STIFFNESS_NODE, name]
        data["labels"].append({"text": name, "kind": "name",
                               "anchor": [*base, "label"], "center": [*base, "surface"]})
        data["labels"] += [{"text": f"{symbol}{a}", "kind": "axis",
                            "anchor": [*base, f"label{a}"],
                            "center": [*base, "surface"]} for a in AXIS_NAMES]
        where = "at the target" if np.allclose(st.centers[name], st.position) else \
            "beside the target (grey line)"
        rgb = color_of(COLORMAPS[name], (ell.min_stiffness - lo) / (hi - lo))
        data["legend"].append({
            "color": hex_color(rgb),
            "text": f"{FORMULATION_LABELS[name]}, {where}: principal {quantity} "
                    f"{symbol}1, {symbol}2, {symbol}3 = [{values}] {ell.units}; k_min = "
                    f"{format_value(ell.min_stiffness, 'N/m')}"})
        data["colorbars"].append({
            "label": f"{name} colour: k_min, smallest principal stiffness (linear)",
            "colors": colorbar_colors(COLORMAPS[name]),
            "min": format_value(lo, "N/m"), "max": format_value(hi, "N/m")})
        data["toggles"].append({"label": f"{name} ellipsoid",
                                "path": ["meshcat", STIFFNESS_NODE, name]})
        if name == "enhanced" and ell.min_stiffness < 0:
            data["notes"].append(
                "UNSTABLE under this load: the enhanced stiffness has a negative principal "
                "value (K_theta - K_C is not positive definite), so the arm buckles; the "
                "ellipsoid is drawn by magnitude and is not a stiffness the arm has")
    if len(st.ellipsoids) == 2:
        enh, conv = st.ellipsoids["enhanced"].values, st.ellipsoids["conventional"].values
        with np.errstate(invalid="ignore", divide="ignore"):
            rel = np.abs(enh - conv) / np.abs(conv)
        rel = rel[np.isfinite(rel)]
        data["lines"].append(
            "enhanced vs conventional: principal values differ by up to "
            f"{format_value(100 * float(np.max(rel, initial=0.0)))} % (K_C, the load's "
            "complementary stiffness)")


def field_legend(data: dict, fs: FieldState, quantity: str) -> None:
    """Add an ellipsoid field's colour bar, toggle and skipped samples to ``data``."""
    data["colorbars"].append({
        "label": f"field ({len(fs.positions)} samples, {fs.ellipsoids[0].formulation}"
                 f" {quantity}, radius {format_value(fs.scale, 'm')} per unit): "
                 "k_min (N/m)",
        "colors": colorbar_colors(COLORMAPS["field"]),
        "min": format_value(fs.color_range[0], "N/m"),
        "max": format_value(fs.color_range[1], "N/m")})
    data["toggles"].append({"label": "ellipsoid field", "path": ["meshcat", FIELD_NODE]})
    if fs.skipped:
        data["notes"].append(f"field: {fs.skipped} samples skipped (loop cannot close "
                             "or singular stiffness)")
    clipped = 0 if fs.clipped is None else int(np.sum(fs.clipped))
    if clipped:
        data["notes"].append(
            f"field: {clipped} ellipsoids near a singularity (a principal value far beyond "
            f"the others') clipped at {FIELD_CLIP:g} sample spacings and drawn grey")


def controls_spec(robot: Robot, st: SceneState, formulation: str, quantity: str) -> dict:
    """The live page's controls at the shown scene: joint sliders (deg or m, within the
    joint limits), the force (magnitude N, azimuth and elevation deg), formulation, quantity."""
    joints = []
    lower, upper = coordinate_limits(robot)  # +-inf for continuous joints
    for i, name in enumerate(robot.coordinate_joints):
        lo, hi = lower[i], upper[i]
        if robot.is_prismatic(name):
            lo = lo if np.isfinite(lo) and lo > -10 else -1.0
            hi = hi if np.isfinite(hi) and hi < 10 else 1.0
            joints.append({"name": name, "unit": "m", "to_si": 1.0, "min": lo, "max": hi,
                           "step": (hi - lo) / 1000, "digits": 3, "value": st.coords[i]})
        else:
            lo = np.rad2deg(lo) if np.isfinite(lo) and lo > -7 else -180.0
            hi = np.rad2deg(hi) if np.isfinite(hi) and hi < 7 else 180.0
            joints.append({"name": name, "unit": "deg", "to_si": np.pi / 180, "min": lo,
                           "max": hi, "step": 0.1, "digits": 1,
                           "value": float(np.rad2deg(st.coords[i]))})
    force = st.wrench[:3]
    magnitude = float(np.linalg.norm(force))
    if magnitude > 0:
        azimuth = float(np.rad2deg(np.arctan2(force[1], force[0])))
        elevation = float(np.rad2deg(np.arcsin(np.clip(force[2] / magnitude, -1, 1))))
    else:
        azimuth, elevation = 0.0, -90.0
    top = nice_above(3.0 * magnitude) if magnitude > 0 else 1000.0
    return {"joints": [{k: (float(v) if isinstance(v, (float, np.floating)) else v)
                        for k, v in j.items()} for j in joints],
            "force": {"magnitude": magnitude, "max": max(top, magnitude),
                      "azimuth": azimuth, "elevation": elevation},
            "formulation": formulation, "formulations": list(SHOW_FORMULATIONS),
            "quantity": quantity, "quantities": list(QUANTITIES)}

