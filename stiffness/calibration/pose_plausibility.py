"""Whether a pose fit is a calibration: its geometric parameters against the robot's size, and
the campaign's marker spread against the robot's kinematics.

A pose campaign whose length unit is read 1000x off (declared mm, written m, or the reverse)
does not stop the fit: the joint placement errors (``geometry``) shrink or stretch every link
and the marker offsets follow, until the residual sits at the noise. Its chi-square then reads
*explained* and its parameters like a calibration. Three things tell it apart, each from the
robot's size (its reach, :func:`~stiffness.robot.kinematics.reach`):

* **Placement errors beyond a tenth of the reach** (:data:`PLACEMENT_FRACTION`): a wrong unit
  changes every link's length by all of it, and of ``n`` joints' links the longest is at least
  ``1/n`` of the reach (a tenth or more for the arms of up to ten joints), while a machined
  robot is off its drawing by millimetres. A prismatic joint's zero offset beyond the reach
  too.
* **A marker beyond the reach from its frame** (its fitted offset ``o + delta o``): not on the
  robot.
* **The spread** (:func:`~stiffness.calibration.unit_checks.marker_spread`): the distance a
  marker moves between two rows does not depend on where the measuring system stands, so
  its median ratio to the nominal kinematics' is about 1 whatever the fit; outside
  :data:`~stiffness.calibration.unit_checks.SPREAD_RATIO` the unit (or the robot, or the
  markers' frames) is wrong, and the length unit that brings it to 1 is the likely one.

Any of them makes the fit *not a calibration* (:attr:`Plausibility.plausible` false). The
measuring frame is free (a tracker 250 m from the robot, or a site's coordinates, is normal),
its rotation too: a unit shows in lengths.

Angles are judged apart, against the physical limit of their family
(:attr:`~stiffness.elastic.effects.pose_face.PoseFamily.plausible_angle_rad`, a few degrees:
:data:`~stiffness.elastic.effects.kinematic_errors.DEFLECTION_OFFSET_RAD`): a revolute joint's
zero offset, a joint placement's turn or the base's tilt beyond it is **implausible**
(:attr:`Plausibility.turned`; :attr:`Plausibility.plausible` false as well, the verdict headed
``IMPLAUSIBLE ANGLES`` when the lengths are plausible). An encoder zero off by degrees is
remastered, not calibrated; a fit that puts it there has traded parameters the campaign does
not tell apart, or the model's zero convention is not the robot's. Where the covariance shows
the trade, a pair of angles, one beyond its limit and the other beyond half of it, whose
estimates correlate past :data:`CANCEL_CORRELATION` in the sense that makes their effects
cancel (``rho a b > 0``: nearly parallel columns, opposite values), is named as *cancelling*
(:class:`Cancelling`). A probe's mounting turn is the mounting check's
(:mod:`stiffness.calibration.probe_mounting`).

Lengths are judged as physical errors too, against the angle limit
(:meth:`~stiffness.elastic.effects.pose_face.PoseFamily.plausible_lengths`): a joint
placement's translation beyond ``tan(5 deg)`` times its link (the distance from the previous
joint, at least a tenth of the reach) is **implausible** (:attr:`Plausibility.shifted`;
:attr:`Plausibility.plausible` false, the verdict headed ``IMPLAUSIBLE PLACEMENTS``, or
``IMPLAUSIBLE ANGLES AND PLACEMENTS``, when the lengths are in the right unit): the turn of
the link by the angle limit moves the joint that far, so a larger shift is such a turn, or a
pair of zero offsets that cancel, traded into a length, which a search refused as an angle
would otherwise name as a machining error (:func:`unphysical_values`).

A marker whose fitted offset is a unit's factor (10 or more) times its declared one, in the
same direction (cosine above :data:`SAME_DIRECTION`), had its offset declared in another unit
than the campaign's: the fit corrected it, so the calibration stands, and a note names the
unit and the offset to declare (:class:`OffsetUnit`).

SI throughout; the text in the campaign's length unit where it quotes the files.
"""

from __future__ import annotations

import math
from collections.abc import Collection
from dataclasses import dataclass

import numpy as np

from stiffness.calibration.pose_campaign import PoseCampaign
from stiffness.calibration.pose_fit import PoseFit
from stiffness.calibration.selection import UNPHYSICAL
from stiffness.calibration.unit_checks import (
    SPREAD_RATIO,
    likely_length_unit,
    marker_spread,
    spread_advice,
)
from stiffness.elastic.effects import FAMILIES
from stiffness.elastic.effects.kinematic_errors import DEFLECTION_OFFSET_RAD, PLACEMENT_FRACTION
from stiffness.files import number_text
from stiffness.robot.kinematics import reach
from stiffness.units import LENGTH_UNITS, Units

#: Cosine between a marker's declared and fitted offsets above which they point the same way.
SAME_DIRECTION = 0.95
#: At most this many parameters are quoted in the verdict line (all in ``--json``).
QUOTED = 3
#: Correlation of two angles' estimates past which, their values cancelling, the campaign does
#: not tell them apart (the fit trades one for the other).
CANCEL_CORRELATION = 0.9


@dataclass(frozen=True)
class Beyond:
    """A fitted length beyond what a calibration corrects: ``parameter`` (a label of the
    parameter table, or ``<marker> offset`` for a marker's fitted offset), its ``value`` and
    the ``limit`` it is beyond (m)."""

    parameter: str
    value: float
    limit: float
    #: "m", or "rad" for an angle (:attr:`Plausibility.turned`)
    unit: str = "m"

    def to_dict(self) -> dict:
        return {"parameter": self.parameter, "value": self.value, "limit": self.limit,
                "unit": self.unit}

    def text(self) -> str:
        """``label value unit`` (an angle in rad and deg)."""
        if self.unit == "rad":
            return f"{self.parameter} {self.value:+.3g} rad ({math.degrees(self.value):+.3g} deg)"
        return f"{self.parameter} {self.value:.3g} m"


@dataclass(frozen=True)
class Cancelling:
    """Two angles (rad) whose estimates correlate by ``correlation`` in the sense that makes
    their effects cancel, one beyond its limit (module docstring)."""

    parameters: tuple[str, str]
    values: tuple[float, float]
    correlation: float

    def text(self) -> str:
        a, b = self.parameters
        return (f"{a} and {b} ({math.degrees(self.values[0]):+.3g} and "
                f"{math.degrees(self.values[1]):+.3g} deg) cancel: their estimates correlate "
                f"{self.correlation:+.3f}, the campaign does not tell them apart")

    def to_dict(self) -> dict:
        return {"parameters": list(self.parameters), "values": list(self.values),
                "unit": "rad", "correlation": self.correlation}


@dataclass(frozen=True)
class OffsetUnit:
    """A marker whose fitted offset (3,; m) is ``factor`` times its declared one (3,; m) in the
    same direction: declared in ``unit``, not in the campaign's."""

    marker: str
    declared: np.ndarray
    fitted: np.ndarray
    factor: float
    unit: str

    def note(self, units: Units) -> str:
        """The report's line: the unit and the offset to declare (campaign length unit)."""
        numbers = self.declared / units.length_to_si * LENGTH_UNITS[self.unit] / units.length_to_si
        return (f"note: marker {self.marker}'s fitted offset ({_numbers(self.fitted, units)}) "
                f"{units.length} is {self.factor:.3g} times its declared "
                f"({_numbers(self.declared, units)}) {units.length}: its declared offset looks "
                f"like {self.unit}; in {units.length}: "
                f"offset = [{_numbers(numbers, units, si=False)}]")

    def to_dict(self, units: Units) -> dict:
        return {"marker": self.marker, "declared": (self.declared / units.length_to_si).tolist(),
                "fitted": (self.fitted / units.length_to_si).tolist(), "unit": units.length,
                "factor": self.factor, "likely_length_unit": self.unit}


def _numbers(v: np.ndarray, units: Units, si: bool = True) -> str:
    scale = units.length_to_si if si else 1.0
    return ", ".join(number_text(float(f"{x / scale:.4g}")) for x in v)


@dataclass(frozen=True)
class Plausibility:
    """Whether a pose fit is a calibration (module docstring): the lengths beyond what one
    corrects, the campaign's marker spread (median ratio, ``None`` when no row pair tells) and
    the markers whose offsets were declared in another unit."""

    robot: str
    reach_m: float
    units: Units
    beyond: tuple[Beyond, ...]
    spread: float | None
    offsets: tuple[OffsetUnit, ...]
    #: angles beyond their family's limit (rad), and the pairs of angles that cancel
    turned: tuple[Beyond, ...] = ()
    cancelling: tuple[Cancelling, ...] = ()
    #: placement translations beyond what the angle limit moves a joint over its link (m)
    shifted: tuple[Beyond, ...] = ()

    @property
    def spread_off(self) -> bool:
        """Whether the markers move by other distances than the kinematics moves them."""
        return self.spread is not None and not SPREAD_RATIO[0] <= self.spread <= SPREAD_RATIO[1]

    @property
    def plausible(self) -> bool:
        """Whether the fit can be a calibration (no length or angle beyond it, the spread
        about 1)."""
        return (not self.beyond and not self.spread_off and not self.turned
                and not self.shifted)

    @property
    def lengths_plausible(self) -> bool:
        """Whether the lengths and the spread can be a calibration's (no unit read wrong;
        :attr:`shifted` lengths are a physical question, not a unit's)."""
        return not self.beyond and not self.spread_off

    @property
    def likely_unit(self) -> str | None:
        """The length unit the data look like, from the spread, or ``None``."""
        if not self.spread_off or self.spread is None or self.spread <= 0:
            return None
        return likely_length_unit(1.0 / self.spread, self.units)

    def verdict(self) -> str | None:
        """The report's line when the fit is no calibration (``None`` when it can be one):
        ``NOT A CALIBRATION`` for a unit (:meth:`length_verdict`; the placements it moves
        need no other word), else ``IMPLAUSIBLE ANGLES`` (:meth:`angle_verdict`),
        ``IMPLAUSIBLE PLACEMENTS`` (:meth:`placement_verdict`) or both; the angles' part
        follows a unit's."""
        if self.plausible:
            return None
        angles = f"; and {self.angle_verdict()}" if self.turned else ""
        if not self.lengths_plausible:
            return f"{self.length_verdict()}{angles}"
        if not self.shifted:
            return f"IMPLAUSIBLE ANGLES: {self.angle_verdict()}"
        if not self.turned:
            return f"IMPLAUSIBLE PLACEMENTS: {self.placement_verdict()}"
        return f"IMPLAUSIBLE ANGLES AND PLACEMENTS: {self.angle_verdict()}; and " \
               f"{self.placement_verdict()}"

    def angle_verdict(self) -> str:
        """The angles beyond their limits, the pairs that cancel, and what to do."""
        return (f"the fit turns {_turned_text(self.turned, self.cancelling)}; poses that move "
                "these joints over more of their range tell such parameters apart, or the "
                "model's zero or axis differs from the robot's (check the joint's zero and "
                "sign)")

    def placement_verdict(self) -> str:
        """The placements moved beyond their limits, and what to do."""
        return (f"the fit moves {_shifted_text(self.shifted)}; poses that move the joints "
                "before them over more of their range tell such a shift from those joints' "
                "zero offsets, or the model's links differ from the robot's (check its "
                "drawing)")

    def length_verdict(self) -> str:
        """``NOT A CALIBRATION``: the lengths and spread (module docstring)."""
        parts = []
        if self.spread_off and self.spread is not None:
            parts.append(f"the measured markers move {self.spread:.3g} times as far between "
                         f"poses as {self.robot}'s kinematics moves them")
        if self.beyond:
            parts.append(f"the fit moves {_quoted([b.text() for b in self.beyond])}"
                         + f", beyond what a calibration corrects on a robot of reach "
                         f"{self.reach_m:.3g} m (a tenth of it for a placement, all of it for "
                         "a marker)")
        advice = (spread_advice(self.spread, self.units) if self.spread_off and self.spread
                  else "check the length unit, the robot and the markers' frames")
        return "NOT A CALIBRATION: " + "; ".join(parts) + f"; {advice}"

    def notes(self) -> list[str]:
        """The markers' offset notes (:meth:`OffsetUnit.note`)."""
        return [o.note(self.units) for o in self.offsets]

    def to_dict(self) -> dict:
        """``plausibility`` in ``diagnose --json`` and ``identify --json``."""
        return {"plausible": self.plausible, "verdict": self.verdict(),
                "spread_ratio": self.spread, "spread_range": list(SPREAD_RATIO),
                "likely_length_unit": self.likely_unit, "reach_m": self.reach_m,
                "placement_limit_m": PLACEMENT_FRACTION * self.reach_m,
                "beyond": [b.to_dict() for b in self.beyond],
                "marker_offsets": [o.to_dict(self.units) for o in self.offsets],
                "beyond_angles": [b.to_dict() for b in self.turned],
                "beyond_placements": [b.to_dict() for b in self.shifted],
                "cancelling": [c.to_dict() for c in self.cancelling]}


def plausibility(fit: PoseFit, campaign: PoseCampaign) -> Plausibility:
    """Judge ``fit`` of ``campaign`` (module docstring)."""
    model, robot = fit.model, campaign.robot
    size = reach(robot.model)
    beyond = []
    for i, p in enumerate(model.parameters):
        fraction = FAMILIES[p.family].plausible_reach_fraction
        if fraction is not None and p.unit == "m" and abs(fit.x[i]) > fraction * size:
            beyond.append(Beyond(p.label, float(fit.x[i]), fraction * size))
    offsets = []
    for k, m in enumerate(model.markers):
        fitted = model.marker_offset(fit.x, k)
        if np.linalg.norm(fitted) > size:
            beyond.append(Beyond(f"{m.name} offset", float(np.linalg.norm(fitted)), size))
        unit = _declared_unit(np.asarray(m.offset, float), fitted, campaign.units)
        if unit is not None:
            offsets.append(OffsetUnit(m.name, np.asarray(m.offset, float), fitted, *unit))
    spread = marker_spread(robot, [m.frame for m in campaign.markers],
                           np.array([m.offset for m in campaign.markers]), campaign.q,
                           campaign.positions)
    beyond.sort(key=lambda b: -abs(b.value) / b.limit)
    turned = _turned(fit)
    return Plausibility(robot.title, size, campaign.units, tuple(beyond),
                        None if spread is None else spread[0], tuple(offsets), turned,
                        _cancelling(fit, turned), _shifted(fit))


def _angle_limits(fit: PoseFit) -> np.ndarray:
    """(p,) each parameter's angle limit (rad; NaN: not an angle its family judges)."""
    limits = [FAMILIES[p.family].plausible_angle_rad for p in fit.model.parameters]
    return np.array([np.nan if lim is None or p.unit != "rad" else lim
                     for lim, p in zip(limits, fit.model.parameters, strict=True)])


def _turned(fit: PoseFit) -> tuple[Beyond, ...]:
    """The angles beyond their family's limit, farthest first."""
    limits = _angle_limits(fit)
    out = [Beyond(p.label, float(fit.x[i]), float(limits[i]), "rad")
           for i, p in enumerate(fit.model.parameters) if abs(fit.x[i]) > limits[i]]
    return tuple(sorted(out, key=lambda b: -abs(b.value) / b.limit))


def _shifted(fit: PoseFit) -> tuple[Beyond, ...]:
    """The lengths beyond their family's physical limit
    (:meth:`~stiffness.elastic.effects.pose_face.PoseFamily.plausible_lengths`), farthest
    first."""
    model = fit.model
    limits = np.full(model.size, np.nan)
    for family in model.family_objects:
        own = family.plausible_lengths(model)
        if own is not None:
            limits[model.slices()[family.name]] = own
    out = [Beyond(p.label, float(fit.x[i]), float(limits[i]))
           for i, p in enumerate(model.parameters) if abs(fit.x[i]) > limits[i]]
    return tuple(sorted(out, key=lambda b: -abs(b.value) / b.limit))


def _quoted(texts: list[str]) -> str:
    """The first :data:`QUOTED` of ``texts``, joined, and how many more there are."""
    more = len(texts) - QUOTED
    return ", ".join(texts[:QUOTED]) + (f" (and {more} more)" if more > 0 else "")


def _shifted_text(shifted: tuple[Beyond, ...]) -> str:
    """The lengths ``shifted`` beyond their limits (the first :data:`QUOTED`), with their
    limits, as the verdict and a search's refusal quote them."""
    return (_quoted([f"{b.parameter} {b.value:+.3g} m (limit {b.limit:.3g} m)" for b in shifted])
            + f", beyond what a turn of {math.degrees(DEFLECTION_OFFSET_RAD):.3g} deg moves "
            "a joint over its link (the distance from the previous joint, at least "
            f"{PLACEMENT_FRACTION:g} of the reach)")


def _cancelling(fit: PoseFit, turned: tuple[Beyond, ...]) -> tuple[Cancelling, ...]:
    """The pairs of fitted angles whose estimates correlate past :data:`CANCEL_CORRELATION`
    with values that cancel (``rho a b > 0``), one beyond its limit and the other beyond half
    of it (module docstring)."""
    if not turned:
        return ()
    limits, kept, x = _angle_limits(fit), fit.identifiability.kept, fit.x
    std = np.sqrt(np.diag(fit.covariance))
    labels = [p.label for p in fit.model.parameters]
    out = []
    for a in range(len(kept)):
        for b in range(a + 1, len(kept)):
            i, j = kept[a], kept[b]
            if not (abs(x[i]) > 0.5 * limits[i] and abs(x[j]) > 0.5 * limits[j]
                    and max(abs(x[i]) / limits[i], abs(x[j]) / limits[j]) > 1.0):
                continue  # NaN limits (not judged angles) compare false
            with np.errstate(divide="ignore", invalid="ignore"):  # a zero std: NaN, no pair
                rho = float(fit.covariance[a, b] / (std[a] * std[b]))
            if abs(rho) > CANCEL_CORRELATION and rho * x[i] * x[j] > 0:
                out.append(Cancelling((labels[i], labels[j]), (float(x[i]), float(x[j])), rho))
    return tuple(out)


def _turned_text(turned: tuple[Beyond, ...], cancelling: tuple[Cancelling, ...]) -> str:
    """The angles ``turned`` beyond their limits (the first :data:`QUOTED`) and the pairs
    that cancel, as the verdict and a search's refusal quote them."""
    limit = max(b.limit for b in turned)
    cancel = "".join(f"; {c.text()}" for c in cancelling)
    return (_quoted([b.text() for b in turned])
            + f", beyond the {math.degrees(limit):.3g} deg an encoder zero, a joint axis or a "
            f"level base is off by{cancel}")


def unphysical_values(fit: PoseFit, forced: Collection[str] = ()) -> str | None:
    """Why diagnose's search may not name ``fit`` (one line,
    :meth:`~stiffness.calibration.pose_diagnose.PoseSearch.unphysical`): of a family not
    ``forced`` (``diagnose --families``, whose values the verdict only warns about), an angle
    beyond its family's limit or in a pair of angles that cancel, or a placement shifted
    beyond its limit (module docstring); named as the verdict names them. ``None`` when there
    is none."""
    family = {p.label: p.family for p in fit.model.parameters}
    turned = _turned(fit)
    pairs = tuple(c for c in _cancelling(fit, turned)
                  if any(family[a] not in forced for a in c.parameters))
    paired = {a for c in pairs for a in c.parameters}
    named = tuple(b for b in turned if family[b.parameter] not in forced or b.parameter in paired)
    shifted = tuple(b for b in _shifted(fit) if family[b.parameter] not in forced)
    parts = ([f"turns {_turned_text(named, pairs)}"] if named else []) + (
        [f"moves {_shifted_text(shifted)}"] if shifted else [])
    if not parts:
        return None
    return (f"{UNPHYSICAL}: its fit {'; and '.join(parts)}, and a named family's values are "
            "physical ones (docs/absolute-poses.md, Implausible angles and placements)")


def _declared_unit(declared: np.ndarray, fitted: np.ndarray, units: Units
                   ) -> tuple[float, str] | None:
    """``(factor, unit)`` when ``fitted`` (m) is a unit's factor times ``declared`` (m) in the
    same direction (module docstring), else ``None``."""
    a, b = float(np.linalg.norm(declared)), float(np.linalg.norm(fitted))
    if a == 0 or b == 0 or float(declared @ fitted) < SAME_DIRECTION * a * b:
        return None
    factor = b / a
    if abs(math.log10(factor)) < 0.5:  # not a unit's factor (10 or more)
        return None
    unit = likely_length_unit(factor, units)
    return None if unit is None else (factor, unit)
