"""A diagnosis's steps as tables, for either campaign kind, from its ``--json`` object: each
step's fit (the steps table, text and page) and each step's model on a validation campaign,
the stage table calibration papers publish (``diagnose --validate``; text and page)."""

from __future__ import annotations

from stiffness.htmlpage import esc, table

#: The keys, beside the errors, a stage's validation object may carry, and their columns.
VERDICT_COLUMNS = {"rms_over_noise": "RMS / noise", "verdict": "verdict"}


def step_label(step: dict) -> str:
    """A step (a ``--json`` step object) by name: ``removed`` for a removal, then a pose
    step's family or a deflection step's effect with its place, ``name(where)``."""
    name = step.get("family") or step["effect"] + (f"({step['where']})" if step.get("where")
                                                   else "")
    return ("removed " if step.get("removed") else "") + name


def scored_steps(d: dict) -> list[dict]:
    """The steps of ``d``, the baseline the first, each with ``rms``, ``delta_bic`` and
    ``cv_rms``: a pose diagnosis's as they are, a deflection diagnosis's record
    (:meth:`~stiffness.calibration.diagnosis.Diagnosis.record`) joined to its baseline's and
    its ``step_details``' and ``cv_rms``' scores."""
    if "step_details" not in d:
        return d["steps"]
    cv, validation = d["cv_rms"], d.get("baseline_validation")
    return [{"effect": "baseline", "where": None, "rms": d["baseline_rms"],
             "cv_rms": cv["baseline"],
             **({"validation": validation} if validation else {})}] + [
        {**s, "delta_bic": detail["delta_bic"], "cv_rms": cv_rms} for s, detail, cv_rms in
        zip(d["steps"], d["step_details"], cv["steps"], strict=True)]


def step_lines(d: dict, notes: list[str]) -> list[str]:
    """The text table of :func:`scored_steps`: effect, ``where`` (deflection), parameter count
    (pose), RMS, dBIC, held-out RMS (null: ``unbounded`` for a pose step, ``-`` for a
    deflection step) and any validation RMS; then ``notes``, the forced steps, ``--not`` and
    the candidates a step refused before it added its own (a step's ``refused``: what and
    why)."""
    steps, unit = scored_steps(d), d["unit"]
    where, counted = (any(k in s for s in steps) for k in ("where", "n_parameters"))
    rows = _aligned([["step", "effect".ljust(18), *["where"][:where], *["params"][:counted],
                      f"RMS ({unit})", "dBIC", f"CV RMS ({unit})"]] + [
        [str(i), ("removed " if s.get("removed") else "") + (s.get("family") or s["effect"])
         + (" *" if s.get("forced") else ""), *[s.get("where") or ""][:where],
         *[str(s.get("n_parameters"))][:counted], _number(s["rms"]),
         _number(s.get("delta_bic")),
         _number(s["cv_rms"], "unbounded" if "family" in s else "-")]
        for i, s in enumerate(steps)], 2 + where)
    if any(s.get("validation") for s in steps):
        rows = [rows[0] + "  validation RMS"] + [
            row + (f"  {v['rms']:.4g} (3-D, {v['unit']})" if (v := s.get("validation")) else "")
            for row, s in zip(rows[1:], steps, strict=True)]
    forbidden = d.get("selection", {}).get("forbidden")
    return [*rows, *notes,
            *(["* forced (--families): added first, whatever its BIC and held-out error"]
              if any(s.get("forced") for s in steps) else []),
            *([f"not tried (--not): {', '.join(forbidden)}"] if forbidden else []),
            *(f"step {i} refused {what}: {why}" for i, s in enumerate(steps)
              for what, why in (s.get("refused") or {}).items())]


def _number(v: float | None, null: str = "") -> str:
    return null if v is None else f"{v:.4g}"


def _aligned(rows: list[list[str]], left: int, sep: str = " ", indent: str = "") -> list[str]:
    """``rows`` (the header first) in columns as wide as their widest cell, the first
    ``left`` aligned left, the others right."""
    width = [max(map(len, column)) for column in zip(*rows, strict=True)]
    return [indent + sep.join(c.ljust(w) if j < left else c.rjust(w)
                              for j, (c, w) in enumerate(zip(row, width, strict=True)))
            for row in rows]


def stages(d: dict) -> list[tuple[str, dict]]:
    """Each stage of ``d`` with a validation (a name, its number and :func:`step_label`, and
    its validation): the steps of :func:`scored_steps`, the baseline the first."""
    return [(f"{i} {step_label(s)}", s["validation"]) for i, s in enumerate(scored_steps(d))
            if s.get("validation")]


def steps_table(steps: list[dict], unit: str) -> str:
    """The page's table of ``steps``, ``--json`` step objects (named by :func:`step_label`,
    numbered from 0) with ``delta_bic`` (absent: no cell), ``rms``, ``cv_rms`` and, where the
    kind counts them, ``n_parameters``."""
    counted = any("n_parameters" in s for s in steps)
    rows = [[str(i), esc(step_label(s) + (" (forced)" if s.get("forced") else "")),
             *([s.get("n_parameters", "")] if counted else []), s.get("delta_bic", ""),
             s["rms"], s["cv_rms"]] for i, s in enumerate(steps)]
    return table("Effects added one at a time",
                 ["step", "effect", *(["parameters"] if counted else []), "ΔBIC",
                  f"RMS ({unit})", f"held-out RMS ({unit})"], rows,
                 "ΔBIC: change of the Bayesian information criterion from the previous step "
                 "(negative: the effect earns its parameters). Held-out RMS: the residual on "
                 "configurations left out of the fit. A \"removed\" step: the final model is "
                 "better without the effect (lower BIC, held-out RMS not higher).")


def stage_table(named: list[tuple[str, dict]]) -> list[str]:
    """The text lines: per stage (a name and its validation object,
    :func:`~stiffness.calibration.pose_register.validation_errors` or
    :func:`~stiffness.calibration.validation.deflection_errors`), the held-out 3-D error's
    ``mean ± std (max)`` overall and per marker; the lines of ``diagnose --validate`` (one per
    step, :func:`stages`) and of ``stiffness validate`` (one model)."""
    names, cells = _cells(named)
    return [f"held-out 3-D error ({named[0][1]['unit']}): mean ± std (max)",
            *_aligned([["stage", *names]] + [[name, *row] for (name, _), row in
                                            zip(named, cells, strict=True)], 1, "  ", "  ")]


def stage_section(d: dict) -> list[str]:
    """The page's table of :func:`stages` (none without a validation campaign): the text
    table's cells, with each stage's RMS and, where its validation object has them, its RMS
    over the noise and its verdict."""
    named = stages(d)
    if not named:
        return []
    names, cells = _cells(named)
    extra = [k for k in VERDICT_COLUMNS if any(k in v for _, v in named)]
    rows = [[esc(name), v["rms"], *row, *(v.get(k) if k == "rms_over_noise" else
                                          esc(v.get(k) or "") for k in extra)]
            for (name, v), row in zip(named, cells, strict=True)]
    return [table(f"Held-out 3-D error per stage ({d['unit']})",
                  ["stage", "RMS", *(f"{n}: mean ± std (max)" for n in names),
                   *(VERDICT_COLUMNS[k] for k in extra)], rows,
                  "Each step's model evaluated on the validation campaign "
                  + refitted(named[-1][1]) + ": RMS, and mean, standard deviation and "
                  "maximum of the 3-D error, overall and per marker"
                  + ("; RMS / noise: over sqrt(3) noise std (1 for a model that predicts to "
                     "the noise)." if extra else "."))]


def refitted(v: dict) -> str:
    """How a validation object ``v`` was judged: without refitting, or with the families of
    its ``frame_refit`` fitted to the campaign (``--refit-frame``, ``--refit-markers``)."""
    frame = v.get("frame_refit") or {}
    if not frame.get("applied"):
        return "without refitting"
    return f"with its {refit_words(frame['families'])} fitted there, the rest not refitted"


#: What each family a validation refits is called in its text (``frame_refit``'s ``families``).
REFIT_WORDS = {"frame": "measuring frame", "markers": "marker offsets"}


def refit_words(families: list[str]) -> str:
    """The refitted ``families`` (``frame_refit``'s) in words: ``measuring frame and marker
    offsets``."""
    return " and ".join(REFIT_WORDS[f] for f in families)


def _cells(named: list[tuple[str, dict]]) -> tuple[list[str], list[list[str]]]:
    """The columns (``all``, then the first stage's markers) and each stage's cells."""
    names = ["all", *named[0][1]["markers"]]
    return names, [[_stage_cell(c) for c in (r, *(r["markers"][n] for n in names[1:]))]
                   for _, r in named]


def _stage_cell(r: dict) -> str:
    if r["mean_error"] is None:
        return "never seen"
    return f"{r['mean_error']:.4g} ± {r['std_error']:.2g} ({r['max_error']:.3g})"
