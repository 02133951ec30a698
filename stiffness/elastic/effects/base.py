"""The effect base class (:class:`Effect`), its reported parameters (:class:`Parameter`) and why
a fit holds one (:class:`Held`).

An :class:`Effect` is one thing a stiffness model may miss. It has up to three faces:

* in a deflection campaign's fit (:class:`stiffness.elastic.effects.hypothesis.Hypothesis`) it
  enters the array algebra through the prediction hooks of its deflection face
  (:class:`stiffness.elastic.effects.deflection_face.DeflectionEffect`);
* in a model used away from its campaign (:class:`stiffness.elastic.model.ElasticModel`, built
  from a model file or by ``stiffness simulate``) it contributes through one hook,
  :meth:`Effect.contribute`, to an :class:`~stiffness.elastic.effects.parts.ElasticParts`: a
  joint spring or joint-law term, a link bend, a preload, a target shift, a measurement adjustment;
* where it is a parameter family of an absolute-pose model, through the hooks of its pose face
  (:class:`stiffness.elastic.effects.pose_face.PoseFamily`).

Nothing outside an effect's class branches on its name.

Units: SI inside (m, N, rad, N.m/rad).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import ClassVar, TypeVar

import numpy as np

from stiffness.elastic.effects.geometry import Geometry, References
from stiffness.elastic.effects.parts import ElasticParts
from stiffness.errors import StiffnessError

#: An effect's own class (:meth:`Effect.at_place`).
E = TypeVar("E", bound="Effect")
#: How an effect enters a model used away from its campaign: ``stiffness`` (it changes the
#: robot's stiffness and enters K_X), ``measurement`` (how the deflection was observed: listed,
#: not applied), ``lost_motion`` (a deflection that is not a stiffness: listed, not applied),
#: ``preload`` (a load present at every pose, the robot's weight: it moves the operating point
#: and adds its ``K_C``).
EFFECT_KINDS = ("stiffness", "measurement", "lost_motion", "preload")


def place_label(name: str, where: str | None) -> str:
    """An effect's label: ``name``, or ``name(where)`` at a place."""
    return name if where is None else f"{name}({where})"


def effect_place(text: str, flag: str) -> tuple[str, str | None]:
    """The effect name and place (``None``: none) a user wrote, in either spelling:
    ``NAME:WHERE`` (``simulate --effect``, ``design --separate``) or the label ``NAME(WHERE)``
    (``diagnose --families``); ``NAME`` alone has no place.

    The name ends at the first ``:`` or ``(`` (no effect's name holds either), so a place may
    hold both: ``NAME:WHERE`` is all after that colon (``link_compliance:a->b``, a URDF joint
    ``j(1)``), ``NAME(WHERE)`` all between that bracket and the closing one at the end
    (``backlash(a:b)``). The name is not checked (each caller names its flag's choices).

    Raises
    ------
    StiffnessError
        ``NAME(`` with no closing bracket at the end, ``NAME()``, or ``NAME:(WHERE)``, which
        reads either way (one line naming the two spellings).
    """
    text = text.strip()
    cut = min((i for i in (text.find(":"), text.find("(")) if i >= 0), default=len(text))
    name, mark, rest = text[:cut].strip(), text[cut:cut + 1], text[cut + 1:]
    where = (rest if mark == ":" else rest[:-1]).strip()
    if mark == "(" and not (rest.endswith(")") and where):
        raise StiffnessError(f"{flag} {text!r}: write a place {name}(WHERE) with the closing "
                             f"bracket at the end, or {name}:WHERE")
    if mark == ":" and where.startswith("(") and where.endswith(")"):
        raise StiffnessError(f"{flag} {text!r} reads two ways: write {name}{where} for the "
                             f"place {where[1:-1]}, or {name}({where}) for a place named {where}")
    return name, where or None


@dataclass(frozen=True)
class Held:
    """Why a fit holds a parameter at its nominal value instead of fitting it, carried as data
    from the fit that decided it to every refit and report
    (:attr:`~stiffness.elastic.effects.hypothesis.Hypothesis.held`,
    :meth:`stiffness.calibration.identifiability.Identifiability.holding`).

    Attributes
    ----------
    reason
        Why, in words (``held at its nominal value: the data do not determine it ...``).
    confounded_with
        The fitted parameters its estimate is correlated with (label, correlation), the most
        correlated first, which take its share once it is held
        (:func:`stiffness.calibration.identifiability.confounded`); none by default.
    """

    reason: str
    confounded_with: tuple[tuple[str, float], ...] = ()

    def text(self) -> str:
        """The reason, ending with what takes its share: ``...; not told apart from
        compliance(elbow_joint) (correlation 0.998), which takes its share``."""
        if not self.confounded_with:
            return self.reason
        names = ", ".join(f"{label} (correlation {r:.3f})" for label, r in self.confounded_with)
        verb = "takes" if len(self.confounded_with) == 1 else "take"
        return f"{self.reason}; not told apart from {names}, which {verb} its share"


def confounded_note(pairs: tuple[tuple[str, float], ...], value: float, unit: str) -> str:
    """Why a fitted parameter at ``value`` (``unit``) the data do not bound has no interval:
    not told apart from ``pairs`` (label, correlation; :attr:`Parameter.confounded_with`),
    which take its share, its value where the fit left it, not a measurement."""
    why = Held("the data do not bound it", tuple(pairs)).text()
    return f"{why} (the fit left it at {value:.5g} {unit}, not a measurement)"


@dataclass
class Parameter:
    """A reported parameter: value, standard error and 95 % interval in ``unit``.

    Attributes
    ----------
    resolved, scale_note, beyond_scale
        Whether its 95 % interval is narrower than its physical scale
        (:meth:`Effect.physical_scale`), that comparison in words, and whether its value is
        beyond that scale (a compliance: larger than it).
    at_bound
        Whether the fit left it at its physical bound (a compliance at 0: a rigid spring; a
        mass at 0); its interval is then one-sided.
    held
        Why the fit did not move it (not identifiable: "no effect on the data", or merged
        into others, :mod:`stiffness.calibration.identifiability`), "" when fitted: its value
        is then the one it was held at, not a measurement.
    confounded_with
        For a fitted parameter the data do not bound: the fitted parameters its estimate is
        correlated with (label, correlation; :attr:`Held.confounded_with`), which take its
        share; its interval is then not reported (:meth:`confounded_as`). None by default.
    """

    name: str
    value: float
    standard_error: float
    ci95: tuple[float, float]
    unit: str
    held: str = ""
    at_bound: bool = False
    resolved: bool = True
    scale_note: str = ""
    beyond_scale: bool = False
    confounded_with: tuple[tuple[str, float], ...] = ()

    @property
    def determined(self) -> bool:
        """Whether the data determine the parameter: fitted, with a finite standard error and
        a finite interval narrower than its physical scale (:attr:`resolved`,
        :meth:`Effect.physical_scale`)."""
        return not self.held and self.resolved and all(
            math.isfinite(v) for v in (self.standard_error, *self.ci95))

    @property
    def excludes_zero(self) -> bool:
        """Whether its 95 % interval excludes zero (both ends finite and of one sign, or a
        stiffness's lower end above zero); never at its physical bound (:attr:`at_bound`: a
        compliance, stiffness or mass the fit left at 0 is not shown to differ from it)."""
        low, high = self.ci95
        return not self.at_bound and bool((low > 0 and math.isfinite(high)) or high < 0)

    def to_dict(self) -> dict:
        """JSON-ready (inf and NaN become ``None``; ``determined`` says whether the interval
        is bounded, "undetermined" where it is not; ``held`` why the fit did not move it, or
        ``None``; ``at_bound`` whether it sits at its physical bound, its interval then
        one-sided; ``confounded_with``, only for a parameter :meth:`confounded_as`, what it is
        not told apart from, as in :meth:`stiffness.calibration.identifiability.
        Identifiability.to_dict`)."""
        def num(v: float) -> float | None:
            return float(v) if math.isfinite(v) else None
        out: dict[str, object] = {
            "value": num(self.value), "standard_error": num(self.standard_error),
            "ci95": [num(self.ci95[0]), num(self.ci95[1])], "unit": self.unit,
            "determined": self.determined, "held": self.held or None,
            "at_bound": self.at_bound, "physical_scale": self.scale_note or None}
        if self.confounded_with:
            out["confounded_with"] = [{"parameter": label, "correlation": round(r, 3)}
                                      for label, r in self.confounded_with]
        return out

    def confounded_as(self, pairs: tuple[tuple[str, float], ...]) -> Parameter:
        """This fitted parameter, which the data do not bound, not told apart from ``pairs``
        (:attr:`confounded_with`): its value kept, its standard error and interval not
        reported (NaN), since a linearised interval along a near alias is not the
        parameter's (a one-sided bound that excludes the truth); itself where ``pairs`` is
        empty."""
        if not pairs:
            return self
        return replace(self, standard_error=math.nan, ci95=(math.nan, math.nan),
                       resolved=False, confounded_with=pairs)

    def held_as(self, reason: str) -> Parameter:
        """This parameter held by the fit at its value, for ``reason``: no uncertainty."""
        return Parameter(self.name, self.value, math.nan, (math.nan, math.nan), self.unit,
                         reason, resolved=False)

    def text(self) -> str:
        """One line: ``name = value +- se unit [low, high]``, or what the parameter was held
        at and why, or ``name: undetermined (...)`` with its interval and no value where the
        data do not determine it (and what it is not told apart from,
        :attr:`confounded_with`)."""
        if self.held:
            at = "rigid" if math.isinf(self.value) else f"at {self.value:.5g} {self.unit}"
            return f"{self.name} not fitted (held {at}): {self.held}"
        if self.confounded_with:  # its value is where the fit left it along the alias
            return (f"{self.name} undetermined: "
                    f"{confounded_note(self.confounded_with, self.value, self.unit)}")
        if self.at_bound and math.isinf(self.ci95[1]):  # a stiffness of zero compliance
            return (f"{self.name} rigid to the data: its compliance at its bound, zero (one-sided"
                    f" 95 % interval: stiffness above {self.ci95[0]:.5g} {self.unit})")
        if self.at_bound:
            return (f"{self.name} at its physical bound ({self.value:.5g} {self.unit}; one-sided "
                    f"95 % interval [{self.ci95[0]:.5g}, {self.ci95[1]:.5g}])")
        # undetermined: no value printed, so none is read as a measurement
        if not self.resolved and math.isfinite(self.standard_error):
            return (f"{self.name}: undetermined (95 % interval [{self.ci95[0]:.5g}, "
                    f"{self.ci95[1]:.5g}] {self.unit}; {self.scale_note})")
        if not self.determined:
            known = "; ".join(f"{side} {v:.5g} {self.unit}"
                              for side, v in zip(("at least", "at most"), self.ci95, strict=True)
                              if math.isfinite(v) and v != 0)
            return (f"{self.name}: undetermined (the data do not bound it"
                    f"{': 95 % interval ' + known if known else ''})")
        return (f"{self.name} = {self.value:.5g} +- {self.standard_error:.3g} {self.unit} "
                f"[{self.ci95[0]:.5g}, {self.ci95[1]:.5g}]")



class Effect:
    """An effect a model may miss. Its interface, in three parts (hooks default to nothing):

    * what it is: :attr:`name`, :attr:`kind`, :attr:`where`, :attr:`label`, :meth:`describe`;
      placed on a robot by :meth:`at_place` (from a model file, unchecked);
    * its parameters: :attr:`parameter_names`, their sizes :meth:`scale` (SI value of one
      optimiser unit: ``u ~ 1`` is a sizeable effect, SI ``u * scale``) and physical scales
      :meth:`physical_scale`, :meth:`bounds`, :meth:`start`, their :meth:`units` (reported
      by :func:`effect_report`, whose inverse is :func:`effect_variables`);
    * its contribution to a model used away from its campaign: :meth:`contribute`.

    Its part of a campaign's prediction, with its Jacobian columns, is a face of each campaign
    kind it serves: a deflection campaign's
    (:class:`~stiffness.elastic.effects.deflection_face.DeflectionEffect`), a pose model's
    (:class:`~stiffness.elastic.effects.pose_face.PoseFamily`). The per-joint effects share
    :class:`~stiffness.elastic.effects.joint_laws.JointEffect`, the effects with fixed
    settings :class:`~stiffness.elastic.effects.deflection_face.Settings`.
    """

    name: ClassVar[str] = ""
    #: names of the parameters (SI values: the variables times :meth:`scale`)
    param_names: ClassVar[tuple[str, ...]] = ()
    #: how the effect enters a model used away from its campaign
    #: (:mod:`stiffness.elastic.model_file`): one of :data:`EFFECT_KINDS`
    kind: ClassVar[str] = "stiffness"
    #: whether it changes K_X beyond the joint springs' stiffness matrix (a nonlinear spring,
    #: a link bend, a preload): the batched scan and the 6x6 connection stiffness, which take
    #: a diagonal K_theta, cannot apply it
    beyond_springs: ClassVar[bool] = False
    #: how many values ``stiffness simulate --effect NAME=...`` takes
    value_counts: ClassVar[tuple[int, ...]] = (0,)
    #: whether the parameters are never negative (a compliance, a lost motion): the variables
    #: then start small and positive, and so does a pose family's lower bound (0)
    nonnegative: ClassVar[bool] = False
    #: whether the parameters are stiffnesses (N.m/rad, N/m) whose variables are their
    #: compliances in units of the baseline's mean compliance ``1 / k_ref`` (reported by
    #: :func:`stiffness_report`, in the units :meth:`units` names)
    compliance_variables: ClassVar[bool] = False
    #: the name of a dimensionless quantity reported after the parameters, the first optimiser
    #: variable itself (:func:`effect_report`), or ""
    relative_change: ClassVar[str] = ""

    # construction ----------------------------------------------------------------------------
    @classmethod
    def at_place(cls: type[E], where: str | None, geometry: Geometry | None = None) -> E:
        """The effect acting at ``where`` (a joint, ``a->b``, or ``None``), checked against the
        robot's ``geometry`` (:func:`stiffness.elastic.effects.make_effect`); with no
        ``geometry``, as a model file declares it, unchecked (a model file's settings added by
        :meth:`~stiffness.elastic.effects.deflection_face.Settings.configured`).

        Raises
        ------
        StiffnessError
            A ``where`` on an effect that acts on the whole campaign (this default).
        """
        if where:
            raise StiffnessError(f"{cls.name} acts on the whole campaign; drop ':{where}'")
        return cls()

    def simulated_values(self, values: tuple[float, ...], units) -> np.ndarray:
        """SI parameter values of the values of ``stiffness simulate --effect NAME=...``, in
        the campaign's ``units`` (:class:`stiffness.units.Units`).

        Raises
        ------
        StiffnessError
            A value out of range.
        """
        return np.asarray(values, dtype=float)

    # the one hook of a model used away from its campaign ---------------------------------
    def contribute(self, values: np.ndarray, parts: ElasticParts) -> None:
        """Record what the effect does to the robot, with SI parameter ``values`` (in
        :attr:`param_names` order), into ``parts``: a joint spring or a joint-law term, a
        link bend, a preload, a target shift or a measurement adjustment. The default does
        nothing (the effect is in the exact equilibrium anyway)."""

    @property
    def where(self) -> str | None:
        """Where the effect acts (a joint, ``a->b``) or ``None``."""
        return None

    @property
    def label(self) -> str:
        """``name`` or ``name(where)``."""
        return place_label(self.name, self.where)

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Names of this effect's parameters: :attr:`param_names`, and the settings
        :meth:`Settings.settings_freed` made parameters."""
        return self.param_names

    @property
    def n_params(self) -> int:
        """Number of parameters."""
        return len(self.parameter_names)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounds of the optimiser variables (0 below where :attr:`nonnegative`)."""
        return (np.full(self.n_params, 0.0 if self.nonnegative else -1e4),
                np.full(self.n_params, 1e4))

    def start(self) -> np.ndarray:
        """Start of the optimiser variables (the effect nearly absent: 1e-3 where
        :attr:`nonnegative`, else 0)."""
        return np.full(self.n_params, 1e-3 if self.nonnegative else 0.0)

    def physical_scale(self, refs: References) -> np.ndarray:
        """SI size of each parameter beyond which it is not physical on this campaign
        (:attr:`Parameter.determined` needs a 95 % interval narrower than it; a value beyond
        it makes the effect a stand-in). This default: :data:`PHYSICAL_FACTOR` times
        :meth:`scale` (the size of a sizeable effect)."""
        return PHYSICAL_FACTOR * self.scale(refs)

    def scale(self, refs: References) -> np.ndarray:
        """SI value of one unit of each optimiser variable (``1 / k_ref`` where
        :attr:`compliance_variables`, else 1)."""
        return np.full(self.n_params, 1.0 / refs.k_ref if self.compliance_variables else 1.0)

    def units(self, units) -> list[tuple[str, float]]:
        """Each parameter's unit in the campaign's ``units`` (:class:`stiffness.units.Units`)
        and that unit's SI value (``SI``, 1 by default)."""
        return [("SI", 1.0)] * self.n_params

    def describe(self) -> str:
        """One line on what the effect is."""
        return self.label



#: The physical scale of a parameter (:meth:`Effect.physical_scale`) is this many times the
#: size of a sizeable effect (:meth:`Effect.scale`) unless its effect says otherwise.
PHYSICAL_FACTOR = 10.0


def scale_note(width: float, size: float, unit: str) -> str:
    """The comparison of a 95 % interval's ``width`` with a physical scale ``size`` (an
    infinite width, a direction the data do not determine, said so: not a number)."""
    if not math.isfinite(width):
        return f"no finite 95 % interval, its physical scale {size:.3g} {unit}"
    relation = "narrower than" if width < size else "wider than"
    return f"95 % interval {width:.3g} {unit} wide, {relation} its physical scale {size:.3g} {unit}"


def judged(name: str, value: float, standard_error: float, ci95: tuple[float, float],
           unit: str, size: float, quantile: float) -> Parameter:
    """A reported parameter judged against its physical scale ``size`` (its ``unit``):
    resolved when its two-sided interval, ``2 quantile standard_error`` wide, is narrower
    than ``size``, beyond its scale when ``|value|`` exceeds it (both campaign kinds' test,
    :mod:`stiffness.calibration.naming`)."""
    width = 2.0 * quantile * standard_error
    return Parameter(name, value, standard_error, ci95, unit, resolved=bool(width < size),
                     scale_note=scale_note(width, size, unit),
                     beyond_scale=bool(abs(value) > size))


def stiffness_interval(low_c: float, high_c: float) -> tuple[float, float]:
    """The 95 % interval of a stiffness ``k = 1 / c`` from its compliance's ``[low_c,
    high_c]``: ``[1 / high_c, 1 / low_c]``, 0 below when ``high_c`` is unbounded, unbounded
    above when ``low_c`` reaches zero. The one rule of every reported stiffness (a
    deflection is linear in the compliances, so the compliance's interval is the one a
    linear fit gives)."""
    return (1.0 / high_c if high_c > 0 and math.isfinite(high_c) else 0.0,
            1.0 / low_c if low_c > 0 else math.inf)


def stiffness_report(name: str, u: float, var_u: float, scale: float, unit: str,
                      quantile: float) -> Parameter:
    """A stiffness ``1 / (u scale)`` from a compliance variable ``u`` (:func:`reciprocal` of
    the compliance ``u scale`` judged against the physical scale ``PHYSICAL_FACTOR scale``,
    ten times the baseline's mean compliance ``1 / k_ref``)."""
    se_u = math.sqrt(max(var_u, 0.0)) if math.isfinite(var_u) else math.inf
    compliance_unit = "m/N" if unit == "N/m" else "rad/(N.m)"
    ci = ((u - quantile * se_u) * scale, (u + quantile * se_u) * scale)
    return reciprocal(judged(name, u * scale, se_u * scale, ci, compliance_unit,
                             PHYSICAL_FACTOR * scale, quantile), unit)


def reciprocal(compliance: Parameter, unit: str) -> Parameter:
    """The stiffness ``k = 1 / c`` (``unit``) of a reported compliance ``c``: its standard
    error by the delta method, ``se_c / c^2``, and its interval the compliance's carried to
    ``k`` (:func:`stiffness_interval`). At a compliance of zero, its bound, the stiffness is
    infinite and its interval one-sided, from ``1 / c_high`` up (:attr:`Parameter.at_bound`);
    held, resolved and the scale note are the compliance's."""
    c, se_c = compliance.value, compliance.standard_error
    k, se_k = (1.0 / c, se_c / c ** 2) if c > 0 else (math.inf, math.inf)
    ci = stiffness_interval(*compliance.ci95)
    if compliance.held:
        return Parameter(compliance.name, k, math.nan, (math.nan, math.nan), unit,
                         compliance.held, resolved=False)
    return Parameter(compliance.name, k, se_k, ci, unit,
                     at_bound=compliance.at_bound or c <= 0, resolved=compliance.resolved,
                     beyond_scale=compliance.beyond_scale,
                     scale_note="compliance's " + compliance.scale_note)


def effect_report(effect: Effect, u: np.ndarray, cov_u: np.ndarray, refs: References, units,
                  quantile: float) -> list[Parameter]:
    """``effect``'s parameters with uncertainties in the campaign's ``units``
    (:class:`stiffness.units.Units`, :meth:`Effect.units`) from its optimiser variables ``u``
    and their covariance ``cov_u``: stiffnesses from their compliances
    (:attr:`Effect.compliance_variables`, :func:`stiffness_report`), the others judged against
    their physical scales (:func:`judged`); then its relative quantity
    (:attr:`Effect.relative_change`: the first variable, 1), if any."""
    scale = effect.scale(refs)
    if effect.compliance_variables:
        return [stiffness_report(name, float(u[i]), float(cov_u[i, i]), float(scale[i]),
                                 unit, quantile)
                for i, (name, (unit, _)) in enumerate(
                    zip(effect.parameter_names, effect.units(units), strict=True))]
    se = np.sqrt(np.maximum(np.diag(cov_u), 0.0)) * scale
    value = np.asarray(u, dtype=float) * scale
    out = [judged(name, v / factor, s / factor,
                  ((v - quantile * s) / factor, (v + quantile * s) / factor), unit,
                  size / factor, quantile)
           for name, v, s, (unit, factor), size in zip(
               effect.parameter_names, value, se, effect.units(units),
               effect.physical_scale(refs), strict=True)]
    if effect.relative_change:
        se_u, rel = math.sqrt(max(float(cov_u[0, 0]), 0.0)), float(u[0])
        out.append(Parameter(effect.relative_change, rel, se_u,
                             (rel - quantile * se_u, rel + quantile * se_u), "1"))
    return out


def effect_variables(effect: Effect, values: np.ndarray, refs: References) -> np.ndarray:
    """``effect``'s optimiser variables of its reported SI parameter ``values`` (the inverse of
    :func:`effect_report` with SI units; only the first :attr:`Effect.n_params` values are
    used)."""
    values = np.asarray(values, dtype=float)[: effect.n_params]
    return (1.0 / values if effect.compliance_variables else values) / effect.scale(refs)
