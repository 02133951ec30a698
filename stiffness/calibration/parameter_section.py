"""A final model's parameters with standard errors, 95 % intervals and units: the table of
either kind's diagnosis page and the lines of either kind's text report, from its ``--json``
parameter objects (a pose diagnosis's ``parameters`` rows carry a deflection diagnosis's
keys)."""

from __future__ import annotations

import math

from stiffness.elastic.effects.base import Parameter, confounded_note
from stiffness.htmlpage import esc, num, table
from stiffness.units import finite_number


def parameter_rows(where: str, parameters: dict) -> list[list]:
    """Rows of the parameter table, each parameter of ``parameters`` (by name) under the part
    ``where``; a fitted interval as ``[low, high]`` (one-sided at a physical bound, said); an
    interval without a finite bound (JSON null) and an infinite standard error are said to
    be undetermined, with what is known, or with what it is not told apart from
    (``confounded_with``: the text report's phrase,
    :func:`~stiffness.elastic.effects.base.confounded_note`); a parameter the fit held (not
    identifiable) is said to be, with why."""
    rows = []
    for name, p in parameters.items():
        se = p.get("standard_error", p.get("std"))
        spread = se if finite_number(se) else "-" if p.get("held") else "undetermined"
        rows.append([esc(where), esc(name), p["value"], spread, _interval(p),
                     esc(p.get("unit", ""))])
    return rows


def _interval(p: dict) -> str:
    """A parameter's 95 % interval cell (:func:`parameter_rows`)."""
    lo, hi = p.get("ci95") or p.get("interval_95") or (None, None)
    if p.get("held"):
        return f"<b>not fitted</b> (held at this value: {esc(p['held'])})"
    if p.get("confounded_with"):  # not told apart from an effect's parameter
        pairs = tuple((c["parameter"], c["correlation"]) for c in p["confounded_with"])
        return "<b>undetermined</b>: " + esc(confounded_note(pairs, p["value"],
                                                             p.get("unit", "")))
    if finite_number(lo) and finite_number(hi):
        return f"[{num(lo)}, {num(hi)}]" + (" one-sided: at its physical bound"
                                            if p.get("at_bound") else "")
    known = f"at least {num(lo)}, " if finite_number(lo) else ""
    return f"<b>undetermined</b> ({known}no upper bound: the measurements do not bound it)"


def parameter_table(rows: list[list]) -> str:
    """The table of :func:`parameter_rows`."""
    return table("Identified parameters of the final model",
                 ["part", "parameter", "value", "standard error", "95 % interval", "unit"],
                 rows, "Intervals from the fit's covariance at the stated noise (a robust "
                 "loss: Huber's sandwich covariance), one-sided at a physical bound.")


def parameter_lines(parameters: dict[str, dict], indent: str = "  ") -> list[str]:
    """The text beside :func:`parameter_rows`: a line per parameter of ``parameters`` (by name),
    :meth:`~stiffness.elastic.effects.base.Parameter.text`, and a nonlinear spring's ``beta``."""
    return [indent + _parameter(name, p).text() + ("" if (beta := p.get("beta")) is None else
                                                   f"  beta = gamma/c = {beta['value']:.4g} "
                                                   f"{beta['unit']}")
            for name, p in parameters.items()]


def _parameter(name: str, p: dict) -> Parameter:
    """The parameter a ``--json`` parameter object was written from (:meth:`~stiffness.elastic.
    effects.base.Parameter.to_dict`, or a pose row's ``std`` and ``interval_95``; null: inf)."""
    se, (lo, hi) = (p.get("standard_error", p.get("std")),
                    p.get("ci95") or p.get("interval_95") or (None, None))
    spread = (math.inf if se is None else se, -math.inf if lo is None else lo,
              math.inf if hi is None else hi)
    return Parameter(name, math.inf if p["value"] is None else p["value"], spread[0],
                     spread[1:], p.get("unit", ""), held=p.get("held") or "",
                     at_bound=bool(p.get("at_bound")),
                     resolved=p.get("determined", True) or bool(p.get("held")) or not all(
                         map(math.isfinite, spread)),
                     scale_note=p.get("physical_scale") or "",
                     confounded_with=tuple((c["parameter"], c["correlation"])
                                           for c in p.get("confounded_with", [])))
