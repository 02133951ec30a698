"""Units caught: a campaign's measured lengths checked against its robot.

Tracker data in mm declared as m puts markers a kilometre from a 0.9 m robot and makes
``identify`` 1000x too soft. The readers check what the robot allows and warn (a
:class:`~stiffness.errors.DataFileWarning`, once) with the length unit the data look like, as
the joint-limit check does for angles:

* **Pose campaigns.** The distance between two rows' positions of one marker does not depend on
  where the measuring system stands: it is the distance the robot's kinematics moves the marker
  between the two rows' coordinates. The median ratio of the measured to the nominal distance
  (over row pairs) is about 1 (geometric errors change it by percents); outside
  :data:`SPREAD_RATIO` the unit is wrong (or the robot, or the markers' frames).
* **Deflection campaigns.** A loaded robot's target moves by micrometres to millimetres: the
  median deflection is checked between :data:`SMALLEST_DEFLECTION_M` and
  :data:`LARGEST_DEFLECTION` times the robot's reach (:func:`reach`).
* **Forces.** With the lengths plausible, the deflection per unit load is compared with the one
  the robot's nominal joint springs give (its declared ``k_theta_SI``, else 1e5 SI:
  :func:`~stiffness.calibration.fitting.nominal_stiffness`) at the rows' coordinates and
  loads: a force unit read 1000x off (kN data declared N makes the robot look 1000x softer, N
  data declared kN 1000x stiffer) puts the median ratio outside :data:`COMPLIANCE_RATIO`
  (:data:`NOMINAL_COMPLIANCE_RATIO` without declared springs, whose stiffness is a guess),
  and the other force unit brings it back inside.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.calibration.fitting import nominal_stiffness
from stiffness.elastic.model import ElasticModel
from stiffness.errors import DataFileWarning, StiffnessError
from stiffness.mechanics.defaults import default_stiffness
from stiffness.robot.kinematics import frame_id, reach
from stiffness.robot.robot import Robot
from stiffness.units import FORCE_UNITS, LENGTH_UNITS, Units

#: Accepted median ratio of measured to nominal marker displacements between rows.
SPREAD_RATIO = (0.5, 2.0)
#: Rows compared (evenly spaced through the campaign): enough for a median, cheap to evaluate.
ROWS_CHECKED = 40
#: The smallest median deflection a rig measures (m; 0.1 um, below any tracker's noise):
#: below, the unit is too large.
SMALLEST_DEFLECTION_M = 1e-7
#: The largest median deflection, as a fraction of the robot's reach: beyond, no elastostatics.
LARGEST_DEFLECTION = 0.02
#: Accepted median ratio of measured to predicted deflection at the robot's declared springs:
#: a campaign identifies them, so they may be off by a factor, but not by a force unit's 1000.
COMPLIANCE_RATIO = (1 / 30, 30.0)
#: The same without declared springs (the nominal 1e5 SI is a guess for any robot).
NOMINAL_COMPLIANCE_RATIO = (1 / 200, 200.0)
#: Configurations whose compliance is evaluated (evenly spaced; every loaded row of each): a
#: closed chain's assembly costs ~10 ms, and a unit 1000x off shows at any of them.
CONFIGS_CHECKED = 6


def likely_length_unit(factor: float, units: Units) -> str | None:
    """The length unit (other than the declared one) that multiplies the data's SI values by
    ``factor`` within a factor 2.2, or ``None``."""
    wanted = units.length_to_si * factor
    best = min(LENGTH_UNITS, key=lambda u: abs(math.log10(LENGTH_UNITS[u] / wanted)))
    if best == units.length or abs(math.log10(LENGTH_UNITS[best] / wanted)) > 0.35:
        return None
    return best


def _advice(unit: str | None) -> str:
    if unit is None:
        return "check the length unit, the robot and the markers' frames"
    return f"the data look like {unit}: [units] length = \"{unit}\" (or --units length={unit})"


def nominal_frames(robot: Robot, frames: list[str], q: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The (n, M, 3, 3) rotations and (n, M, 3) origins (m) in the base frame of ``frames`` for
    each row of coordinates ``q`` (n, n_coordinates), by the robot's nominal kinematics (the
    loops closed from the previous row's assembly)."""
    ids = [frame_id(robot.model, f) for f in frames]
    rotations = np.empty((len(q), len(frames), 3, 3))
    origins = np.empty((len(q), len(frames), 3))
    seed = None
    for r, coords in enumerate(q):
        full = robot.configuration(coords, seed)
        seed = None if robot.loop.is_open_chain else full
        pin.framesForwardKinematics(robot.model, robot.data, full)
        for k, fid in enumerate(ids):
            rotations[r, k] = robot.data.oMf[fid].rotation
            origins[r, k] = robot.data.oMf[fid].translation
    return rotations, origins


def nominal_marker_positions(robot: Robot, frames: list[str], offsets: np.ndarray,
                             q: np.ndarray) -> np.ndarray:
    """(n, M, 3) positions (m, base frame) of markers on ``frames`` at ``offsets`` (M, 3) for
    each row of coordinates ``q`` (n, n_coordinates), by the robot's nominal kinematics
    (:func:`nominal_frames`)."""
    return marker_points(*nominal_frames(robot, frames, q), offsets)


def marker_points(rotations: np.ndarray, origins: np.ndarray, offsets: np.ndarray
                  ) -> np.ndarray:
    """(n, M, 3) points (m) at ``offsets`` (M, 3; m, in their frames' axes) of frames turned by
    ``rotations`` (n, M, 3, 3) at ``origins`` (n, M, 3; m)."""
    return np.einsum("nmij,mj->nmi", rotations, offsets) + origins


def marker_spread(robot: Robot, frames: list[str], offsets: np.ndarray, q: np.ndarray,
                  positions: np.ndarray) -> tuple[float, int] | None:
    """The median ratio of the measured to the nominal distance a marker moves between two rows
    (over row pairs of :data:`ROWS_CHECKED` rows, both distances beyond a thousandth of the
    reach) and how many pairs it is over; ``None`` when no pair tells.

    Parameters
    ----------
    frames, offsets
        The markers' frames and nominal offsets (M, 3; m); an offset beyond the robot's reach
        is taken as 0 (in the same unit as the positions, it is as wrong as they are).
    q, positions
        The rows' coordinates (n, n_coordinates; rad, m) and measured positions (n, M, 3; m,
        NaN unseen).
    """
    rows = np.unique(np.linspace(0, len(q) - 1, min(len(q), ROWS_CHECKED)).astype(int))
    size = reach(robot.model)
    offsets = np.where(np.linalg.norm(offsets, axis=1, keepdims=True) <= size, offsets, 0.0)
    try:
        nominal = nominal_marker_positions(robot, frames, offsets, q[rows])
    except StiffnessError:  # a pose the loops cannot close: reported where it is used
        return None
    measured = positions[rows]
    i, j = np.triu_indices(len(rows), 1)
    d_nom = np.linalg.norm(nominal[i] - nominal[j], axis=-1)  # (pairs, M)
    d_meas = np.linalg.norm(measured[i] - measured[j], axis=-1)
    usable = (d_nom > 1e-3 * size) & np.isfinite(d_meas)
    if not usable.any():
        return None
    ratios = d_meas[usable] / d_nom[usable]
    return float(np.median(ratios)), int(ratios.size)


def spread_advice(ratio: float, units: Units) -> str:
    """What to check when the markers move ``ratio`` times as far as the kinematics moves
    them: the length unit that brings it to 1, else the unit, the robot and the frames."""
    return _advice(likely_length_unit(1.0 / ratio, units) if ratio > 0 else None)


def check_marker_spread(robot: Robot, frames: list[str], offsets: np.ndarray, q: np.ndarray,
                        positions: np.ndarray, units: Units, data: Path) -> None:
    """Warn once when the measured marker positions (n, M, 3; m, NaN unseen) move between rows
    by other distances than the nominal kinematics at ``q`` (rad, m) moves them
    (:func:`marker_spread`).

    Warns
    -----
    DataFileWarning
        The median ratio of measured to nominal distances outside :data:`SPREAD_RATIO`, with
        the length unit that would bring it to 1 (:func:`likely_length_unit`).
    """
    spread = marker_spread(robot, frames, offsets, q, positions)
    if spread is None or SPREAD_RATIO[0] <= spread[0] <= SPREAD_RATIO[1]:
        return
    ratio, pairs = spread
    other = _other_angle_unit(robot, frames, offsets, q, positions, units)
    advice = spread_advice(ratio, units) if other is None else (
        f"with the angles read in {other[0]} they move {other[1]:.3g} times as far: the angles "
        f'look like {other[0]}: [units] angle = "{other[0]}" (or --units angle={other[0]})')
    warnings.warn(
        f"{data}: the measured marker positions move {ratio:.3g} times as far between rows as "
        f"{robot.title}'s kinematics moves the markers (median over {pairs} row pairs, "
        f"length unit {units.length}, angle unit {units.angle}); {advice}",
        DataFileWarning, stacklevel=3)


def _other_angle_unit(robot: Robot, frames: list[str], offsets: np.ndarray, q: np.ndarray,
                      positions: np.ndarray, units: Units) -> tuple[str, float] | None:
    """The other angle unit (``deg`` for ``rad`` and back) and the spread ratio the rows show
    with their revolute coordinates read in it, when that ratio is within
    :data:`SPREAD_RATIO`: radians declared as degrees shrink every turn 57 times, which the
    markers' spread shows as a wrong length unit would (FIGAROH's UR10 file read in deg: 8.4)."""
    other = {"deg": "rad", "rad": "deg"}.get(units.angle)
    if other is None:
        return None
    try:
        revolute = np.array([not robot.is_prismatic(j) for j in robot.coordinate_joints])
    except StiffnessError:
        return None
    factor = 180.0 / math.pi if units.angle == "deg" else math.pi / 180.0
    spread = marker_spread(robot, frames, offsets, np.where(revolute, q * factor, q), positions)
    if spread is None or not SPREAD_RATIO[0] <= spread[0] <= SPREAD_RATIO[1]:
        return None
    return other, spread[0]


def check_marker_offsets(robot: Robot, names: list[str], offsets: np.ndarray, units: Units,
                         where: str | Path) -> None:
    """Warn once, naming them, when declared marker offsets (M, 3; m) put a marker farther
    from its frame than the robot's reach: such a marker is not on the robot, and its offset
    is most likely in another length unit than the campaign's.

    Warns
    -----
    DataFileWarning
        The markers, their distance from their frame and the reach.
    """
    size = reach(robot.model)
    far = [(n, float(np.linalg.norm(o))) for n, o in zip(names, offsets, strict=True)
           if np.linalg.norm(o) > size]
    if not far:
        return
    listed = ", ".join(f"{n} {d / units.length_to_si:.4g} {units.length}" for n, d in far)
    warnings.warn(
        f"{where}: marker offset(s) beyond {robot.title}'s reach ({size / units.length_to_si:.4g} "
        f"{units.length}): {listed} from their frame; a marker that far is not on the robot: "
        f"give the offsets in the campaign's length unit ({units.length})",
        DataFileWarning, stacklevel=3)


#: Rows that say the deflections' sign is reversed: at least this many loaded rows, this share of
#: them against their load and a mean cosine of load and deflection below this (noise alone
#: turns a row's sign at random; a stable robot's deflection has a positive work F.C.F).
SIGN_ROWS, SIGN_SHARE, SIGN_COSINE = 5, 0.9, -0.3


def check_deflection_sign(force: np.ndarray, moment: np.ndarray | None, deflection: np.ndarray,
                          data: Path) -> None:
    """Warn once when no row is loaded, or when the measured deflections (m) point against the
    forces (N) in nearly every loaded row without moments: under a load a stable elastic robot
    deflects with a positive work ``F . C F``, so the deflections are unloaded minus loaded
    positions (or the forces the robot's reaction on the sensor).

    Warns
    -----
    DataFileWarning
        Naming the rows and the columns to negate.
    """
    loaded = np.linalg.norm(force, axis=1) > 0
    if moment is not None:
        loaded |= np.linalg.norm(moment, axis=1) > 0
    if not loaded.any():
        columns = "fx,fy,fz" + ("" if moment is None else ",mx,my,mz")
        warnings.warn(f"{data}: no row carries a load (every {columns} is 0): the deflections "
                      "tell nothing of the stiffness; give the loads applied at each row",
                      DataFileWarning, stacklevel=3)
        return
    if moment is not None:
        loaded &= np.linalg.norm(moment, axis=1) == 0
    size = np.linalg.norm(force, axis=1) * np.linalg.norm(deflection, axis=1)
    rows = loaded & (size > 0)
    if rows.sum() < SIGN_ROWS:
        return
    cosine = np.einsum("ij,ij->i", force[rows], deflection[rows]) / size[rows]
    against = int(np.sum(cosine < 0))
    if against < SIGN_SHARE * cosine.size or float(np.mean(cosine)) > SIGN_COSINE:
        return
    warnings.warn(f"{data}: in {against} of {cosine.size} loaded rows the deflection points "
                  f"against the force (mean cosine {np.mean(cosine):.2f}), which a stable "
                  "elastic robot never does: the deflections look like unloaded minus loaded "
                  "positions, or the forces like the robot's reaction; negate dx,dy,dz (loaded "
                  "minus unloaded) or fx,fy,fz (the load applied to the robot)",
                  DataFileWarning, stacklevel=3)


def check_deflection_size(robot: Robot, deflection: np.ndarray, force: np.ndarray,
                          units: Units, data: Path) -> bool:
    """Warn once when the median measured deflection (m) is beyond what a loaded robot of this
    reach deflects (:data:`SMALLEST_DEFLECTION_M` to :data:`LARGEST_DEFLECTION` x reach);
    returns whether it is within (or there is no deflection).

    Warns
    -----
    DataFileWarning
        Naming the median deflection and load, and the length unit that brings the deflections
        into the range.
    """
    sizes = np.linalg.norm(deflection, axis=1)
    sizes = sizes[sizes > 0]
    if not sizes.size:
        return True
    size = float(np.median(sizes))
    low, high = SMALLEST_DEFLECTION_M, LARGEST_DEFLECTION * reach(robot.model)
    if low <= size <= high:
        return True
    middle = math.sqrt(1e-6 * 1e-3)  # a rig's typical deflection: 1 um to 1 mm
    fits = [u for u in LENGTH_UNITS if u != units.length
            and low <= size * LENGTH_UNITS[u] / units.length_to_si <= high]
    unit = min(fits, key=lambda u: abs(math.log10(
        size * LENGTH_UNITS[u] / units.length_to_si / middle)), default=None)
    load = float(np.median(np.linalg.norm(force, axis=1)))
    side = "larger" if size > high else "smaller"
    warnings.warn(
        f"{data}: the median deflection is {size / units.length_to_si:.3g} {units.length} "
        f"({size:.3g} m under a median load of {load:.3g} N), {side} than a loaded robot of "
        f"{robot.title}'s reach ({reach(robot.model):.3g} m) deflects ({low:.0e} m to "
        f"{high:.3g} m); {_advice(unit)}" + (
            "; if it really deflects that much, only the exact equilibrium models it: identify "
            "with --formulation exact" if size > high else ""), DataFileWarning, stacklevel=3)
    return False


def row_compliance_ratios(robot: Robot, q: np.ndarray, force: np.ndarray,
                          moment: np.ndarray | None, deflection: np.ndarray,
                          configs_checked: int | None = CONFIGS_CHECKED
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each loaded row's measured deflection size and the one the robot's nominal joint
    springs predict to first order (``|C W|``, m) at the row's coordinates ``q`` (rad, m) and
    load (N, N.m), the compliance ``C`` taken once per configuration (at most
    ``configs_checked``, evenly spaced; ``None``: all): the rows (indices into ``q``), the
    measured and the predicted sizes (m)."""
    loaded = np.flatnonzero((np.linalg.norm(force, axis=1) > 0)
                            & (np.linalg.norm(deflection, axis=1) > 0))
    if not loaded.size:
        return np.zeros(0, dtype=int), np.zeros(0), np.zeros(0)
    configs, which = np.unique(q[loaded], axis=0, return_inverse=True)
    which = which.reshape(-1)
    model = ElasticModel.joint_springs(robot, nominal_stiffness(robot, robot.compliant_joints))
    rows, measured, predicted = [], [], []
    n = len(configs) if configs_checked is None else min(len(configs), configs_checked)
    for k in np.unique(np.linspace(0, len(configs) - 1, n).astype(int)):
        try:
            c = model.at(configs[k]).compliance(slice(0, 6))[:3]
        except StiffnessError:  # a pose the loops cannot close: reported where it is used
            continue
        for r in loaded[which == k]:
            wrench = np.concatenate([force[r], np.zeros(3) if moment is None else moment[r]])
            size = float(np.linalg.norm(c @ wrench))
            if size > 0 and np.isfinite(size):
                rows.append(int(r))
                measured.append(float(np.linalg.norm(deflection[r])))
                predicted.append(size)
    return np.array(rows, dtype=int), np.array(measured), np.array(predicted)


def compliance_ratio(robot: Robot, q: np.ndarray, force: np.ndarray, moment: np.ndarray | None,
                     deflection: np.ndarray) -> float | None:
    """Median over loaded rows of the measured over the predicted deflection size
    (:func:`row_compliance_ratios`, at most :data:`CONFIGS_CHECKED` configurations); ``None``
    when no row tells."""
    _, measured, predicted = row_compliance_ratios(robot, q, force, moment, deflection)
    ratios = measured / predicted
    return float(np.median(ratios)) if ratios.size else None


#: A configuration whose deflection per unit load is this many times off the campaign's
#: (median over configurations) had a unit slip in its rows: the nominal springs' errors
#: change the ratio between configurations by far less (none in 90 simulated UR5, UR10,
#: Panda and SK120 campaigns of 8 configurations reached it), a unit 1000x off by more; a
#: 10x slip (cm among mm) stays below it.
CONFIGURATION_SLIP = 100.0


def check_configuration_units(robot: Robot, q: np.ndarray, force: np.ndarray,
                              moment: np.ndarray | None, deflection: np.ndarray,
                              labels: list[str], data: Path) -> None:
    """Warn once when some configurations' deflection per unit load is
    :data:`CONFIGURATION_SLIP` times off the others' (median over the configurations of their
    rows' summed measured over summed predicted deflection sizes, :func:`row_compliance_ratios`:
    the largest loads weigh most, a row within the noise little): their deflections or forces
    were written in another unit (a configuration's deflections in m among mm, forces in kN
    among N), which a fit takes as something the model misses. Needs three configurations.

    Warns
    -----
    DataFileWarning
        Naming each such configuration (``labels`` per row), its factor and the fix.
    """
    rows, measured, predicted = row_compliance_ratios(robot, q, force, moment, deflection, None)
    names = np.array([labels[r] for r in rows])
    by = {n: float(measured[names == n].sum() / predicted[names == n].sum())
          for n in dict.fromkeys(names.tolist())}
    if len(by) < 3:
        return
    typical = float(np.median(list(by.values())))
    off = {n: r / typical for n, r in by.items()
           if max(r / typical, typical / r) >= CONFIGURATION_SLIP}
    if off and len(off) < len(by) / 2:
        said = ", ".join(f"{n} ({f:.3g}x)" for n, f in off.items())
        slips = {True: "deflections in a larger unit (m among mm) or forces in a smaller one "
                       "(N among kN)",
                 False: "deflections in a smaller unit (um among mm) or forces in a larger one "
                        "(kN among N)"}
        kinds = "; or ".join(slips[side] for side in sorted({f < 1 for f in off.values()},
                                                             reverse=True))
        warnings.warn(
            f"{data}: the deflection per unit load of configuration {said} is that many times "
            f"the other configurations' (median over them, against the nominal springs): its "
            f"rows look written in another unit ({kinds}), which a fit takes for an effect "
            f"the model misses; convert them to the campaign's [units] or drop them",
            DataFileWarning, stacklevel=3)


def check_force_unit(robot: Robot, q: np.ndarray, force: np.ndarray, moment: np.ndarray | None,
                     deflection: np.ndarray, units: Units, data: Path) -> None:
    """Warn once when the deflection per unit load (SI rows: coordinates ``q``, ``force`` N,
    ``moment`` N.m, ``deflection`` m) is 1000x off the robot's nominal springs in the way a
    force unit read wrong makes it (:func:`compliance_ratio` outside
    :data:`COMPLIANCE_RATIO`, :data:`NOMINAL_COMPLIANCE_RATIO` without declared springs, and
    inside with the other force unit).

    Warns
    -----
    DataFileWarning
        Naming the ratio, the springs compared with and the force unit the data look like.
    """
    ratio = compliance_ratio(robot, q, force, moment, deflection)
    if ratio is None:
        return
    declared = default_stiffness(robot) is not None
    low, high = COMPLIANCE_RATIO if declared else NOMINAL_COMPLIANCE_RATIO
    if low <= ratio <= high:
        return
    likely = [u for u in FORCE_UNITS if u != units.force and low <= ratio * units.force_to_si
              / FORCE_UNITS[u] <= high]
    if not likely:
        return
    springs = "its declared k_theta_SI" if declared else "a nominal 1e5 SI per joint"
    side = "softer" if ratio > 1 else "stiffer"
    warnings.warn(
        f"{data}: the deflections per unit load make {robot.title} {max(ratio, 1 / ratio):.3g} "
        f"times {side} than {springs} (median over the loaded rows, force unit "
        f"{units.force}); the forces look like {likely[0]}: [units] force = \"{likely[0]}\" "
        f"(or --units force={likely[0]})"
        + ("; else check the robot's k_theta_SI (SI: N.m/rad, N/m)" if declared else
           f"; else {robot.title} is that much {side} than the guess: declare its k_theta_SI "
           "in a robot.toml naming its URDF (docs/robot-files.md) to compare with those"),
        DataFileWarning, stacklevel=3)
