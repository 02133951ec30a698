"""How a diagnosis's final fit stands against the noise, as text, for either campaign kind from
its ``--json`` object: the final RMS over the noise, why the search stopped and, under a robust
loss, where the intervals come from (:func:`fit_lines`); and the verdict, whether the final
model explains the data to the noise and, where it does not, every reading of that
(:func:`verdict_sentence`, the sentence of both kinds' reports, pages and ``unexplained_note``).
"""

from __future__ import annotations

from stiffness.calibration.outliers import STRAY_SHARE
from stiffness.calibration.selection import (
    BIC_MARGIN,
    GOF_LEVEL,
    OVERSTATED_P,
    UNPHYSICAL,
    excluded_note,
    noise_overstated,
)

#: A baseline whose held-out RMS is this many times its fit's has folds too small to determine
#: it (campaigns of 5 to 8 configurations: 1.05 to 1.6; 2 configurations: 31 to 65; 3: 3.5 to
#: 4.6), so the cross-validation cannot confirm an effect (:func:`verdict_sentence`).
WEAK_FOLDS = 5.0
#: What a residual without structure looks like: a pose campaign's, a deflection campaign's.
_FLAT = ("as large on every marker and axis, no trend along the rows",
         "as large in every configuration, axis, load and row block")


def fit_lines(d: dict) -> list[str]:
    """The final RMS (``final_rms``, or the last step's) over ``noise_std`` (null: not
    declared), the ``stop_reason`` and a ``loss`` other than linear."""
    rms = d["final_rms"] if "final_rms" in d else d["steps"][-1]["rms"]
    noise = d["noise_std"]
    ratio = "noise not declared" if noise is None else f"{rms / noise:.3g}x noise"
    lines = [f"final RMS {rms:.4g} {d['unit']} ({ratio})"
             + (f"; stopped: {d['stop_reason']}" if d.get("stop_reason") else "")]
    if d.get("loss", "linear") != "linear":
        lines.append(f"loss {d['loss']} (every fit; intervals from Huber's sandwich covariance)")
    return lines


def verdict_line(d: dict) -> str:
    """:func:`verdict_sentence`, headed ``UNEXPLAINED:`` when the final model does not
    explain the data to the noise (the reports' line)."""
    sentence = verdict_sentence(d)
    return f"UNEXPLAINED: {sentence}" if d.get("unexplained") else sentence


def verdict_sentence(d: dict) -> str:
    """Whether the final model explains the data to the noise, in one sentence, from the
    ``--json`` object ``d`` of either campaign kind (a pose campaign's has ``kind`` "poses").

    Reads ``unexplained`` (null: no known noise, not tested), ``gof_test``, ``gof_p`` and
    ``final_rows_excluded`` (the rows a robust loss's test left out,
    :func:`~stiffness.calibration.selection.kept_terms`); explained, whether the noise looks
    overstated (:func:`~stiffness.calibration.selection.noise_overstated`). Unexplained, every
    reading the numbers allow: a missing effect outside the library, or a library effect this
    campaign is too small to confirm (``best_rejected``: what it did, what would confirm it;
    else why the search added nothing, ``stop_reason``, or that ``--max-steps`` cut it short,
    ``cut_short``; ``searched`` false: no search was run, ``stiffness identify``'s fit),
    folds too small to confirm one
    (``baseline_cv_rms`` over ``baseline_rms`` above :data:`WEAK_FOLDS`, on ``configurations``),
    where the residual sits (``residual_structure``, or ``where_final_disagrees``), the rows
    flagged as outliers (``outliers`` of ``rows``, under ``loss``), an understated declared
    noise (``robust_noise_ratio``: the final residual's robust std over ``noise_std``) and a
    column whose reversed sign explains the data (``flipped_column``, a deflection campaign's:
    :mod:`stiffness.calibration.sign_checks`)."""
    flag = d.get("unexplained")
    if flag is None:
        estimated = (" (it is estimated from the final model's residuals)"
                     if d.get("noise_std_source") == "residuals" else "")
        return (f"not tested: no noise is known{estimated}, so whether the final model explains "
                "the data to noise cannot be said; declare [measurement] noise_std")
    test = f"{d['gof_test']} p = {d['gof_p']:.3g}"
    left_out = excluded_note(d.get("final_rows_excluded", 0))
    if not flag:
        return (f"the final model explains the data to noise ({test}{left_out})") + (
            f"; its residual is far below the noise ({d['gof_test']} lower tail p < "
            f"{OVERSTATED_P:g}): overstated noise, or averaged rows; the intervals are too "
            "wide and an effect below the noise goes unseen"
            if noise_overstated(d["gof_p"]) else "")
    return (f"the residual is still above the noise ({test} <= {1 - GOF_LEVEL:.2g}{left_out})"
            + _missing(d) + _weak_folds(d) + _where(d) + _flagged(d) + _understated(d)
            + (f"; {d['flipped_column']}" if d.get("flipped_column") else ""))


def _missing(d: dict) -> str:
    """What the search's end says is missing: an effect outside the library, or the best
    library effect it rejected (when it lowers BIC), which this campaign is too small to
    confirm; with ``searched`` false (``stiffness identify``, which searches nothing), what
    the fit left out."""
    if d.get("searched") is False:  # stiffness identify: the springs forced in, nothing tried
        return (" and nothing was searched (identify fits the springs with the measuring frame "
                "and markers only): what the data hold beyond them, a geometric error a "
                "diagnosis names (joint offsets, placements) or something the library does not "
                "model, is in the residual and in the stiffnesses")
    best = d.get("best_rejected")
    if best is None:
        stop = d.get("stop_reason", "")
        if d.get("cut_short"):  # --max-steps stopped it (a backward elimination may follow)
            return (f" and the search was cut short ({stop}): a library effect not tried may "
                    "be what is missing (stiffness diagnose tries more with a larger --max-steps)")
        return (f" and the search added nothing more ({stop}): the data contain something the "
                "library does not model")
    unit, name = d["unit"], best["candidate"]
    head = " and no further library effect passes BIC and cross-validation: the data contain " \
        "something the library does not model"
    if not best["delta_bic"] < 0:  # no candidate explains more than its parameters cost
        return f"{head} (none lowers BIC: the best, {name}, dBIC {best['delta_bic']:+.3g})"
    did = (f"{name}, lowers the RMS from {best['rms_before']:.4g} to {best['rms']:.4g} {unit} "
           f"(dBIC {best['delta_bic']:+.3g}" if best.get("rms") is not None else
           f"{name} (dBIC {best['delta_bic']:+.3g} on a first-order screen, not fitted")
    forced = f"'{name}'" if "(" in name else name
    if str(best.get("not_judged") or "").startswith(UNPHYSICAL):  # more data: the same values
        return (f"{head}, or the model's joints are not the robot's: the best rejected "
                f"candidate, {did}{_why_rejected(best, unit)}), fits values no robot is off by, "
                "and more configurations would not make them physical; check each joint's "
                "zero, sign and axis against the controller's, and how the controller counts "
                "its angles (a forearm angle read from the horizontal, as a Fanuc's J3 with its "
                "J2/J3 interaction, is a serial model's joint 3 plus joint 2: declared in a "
                "robot.toml's [controller], the columns are read as logged)")
    return (f"{head}, or a library effect this campaign is too small to confirm: the best "
            f"rejected candidate, {did}{_why_rejected(best, unit)}); more configurations or "
            f"loads can confirm it, and --families {forced} forces it in to show its "
            "parameters' intervals")


def _why_rejected(best: dict, unit: str) -> str:
    """Why ``best_rejected`` was not added, from its numbers: its BIC change short of the
    margin, rows that cannot judge it, parameters too poorly determined to be named, or its
    held-out RMS not below the model's."""
    if not best["delta_bic"] < -BIC_MARGIN:
        return f", short of the margin -{BIC_MARGIN:g}"
    if best.get("not_judged"):
        return f"; not judged held out: {best['not_judged']}"
    cv, before = best.get("cv_rms"), best.get("cv_rms_before")
    if cv is None:
        return "; its parameters too poorly determined to be named"
    against = "" if before is None else f" against the model's {before:.4g}"
    return f"; held-out RMS {cv:.4g}{against} {unit}"


def _weak_folds(d: dict) -> str:
    """The other reading on too few configurations: when the baseline's own held-out RMS is
    :data:`WEAK_FOLDS` times its fit's, each fold cannot determine the model, and
    cross-validation refuses library effects that are there (a UR5 of 2 configurations x 3
    loads with a hidden 15 mm target offset: 31 times). A deflection campaign's keys."""
    cv, fit = d.get("baseline_cv_rms"), d.get("baseline_rms")
    if d.get("baseline_cv_unbounded"):
        times = "unbounded against"
    elif cv is not None and fit and cv / fit > WEAK_FOLDS:
        times = f"{cv / fit:.3g} times"
    else:
        return ""
    return (f"; or too few configurations for the cross-validation to confirm an effect: on "
            f"{d['configurations']} configuration(s) the baseline's own held-out RMS is {times} "
            "its fit's, so a library effect may be what is missing; measure more configurations")


def _where(d: dict) -> str:
    """Where the final residual sits: a pose campaign's RMS by marker and axis and its
    strongest trend along the rows (``residual_structure``); a deflection campaign's in
    ``where_final_disagrees``."""
    s = d.get("residual_structure")
    if s is None:
        return "; the residual's structure (where_final_disagrees) says where to look"
    marker, axis = (", ".join(f"{k} {v:.3g}" if v is not None else f"{k} never seen"
                              for k, v in s[key].items())
                    for key in ("rms_by_marker", "rms_by_axis"))  # a marker no row sees
    trend = max(s["row_trend"].values(), key=lambda t: abs(t["correlation"]), default=None)
    return (f"; the residual's structure says where to look: RMS ({d['unit']}) by marker "
            f"{marker}, by axis {axis}" + ("" if trend is None else
                                           f"; strongest trend along the rows: correlation "
                                           f"{trend['correlation']:+.2f}"))


def _flagged(d: dict) -> str:
    """The rows flagged as outliers: a few can fail the test alone under least squares (a
    robust loss's test leaves them out, :func:`excluded_note`); more than
    :data:`~stiffness.calibration.outliers.STRAY_SHARE` of the rows are a pattern the model
    misses, which every loss's test keeps, unless (least squares) a few gross rows pulled the
    fit onto the others, which a robust loss tells."""
    n, rows, linear = len(d.get("outliers") or []), d["rows"], d.get("loss") == "linear"
    noun = _noun(d)
    if not n:
        return ""
    head = f"; {n} of {rows} {noun} are flagged as outliers (see outliers)"
    if n > STRAY_SHARE * rows:
        return (f"{head}: too many for stray measurements, the model misses something"
                + (f", unless a few gross {noun} pull the least-squares fit onto the others "
                   f"(flagging clean {noun} too): --loss soft_l1 weighs them down and flags "
                   "those alone" if linear else
                   f"; the {d['loss']} fit's test keeps them all (it leaves out only stray "
                   f"{noun}, at most {STRAY_SHARE:.0%} of them)"))
    return (f"{head}, which alone can fail the test; a least-squares fit pulled by gross "
            f"{noun} flags clean {noun} too: --loss soft_l1 weighs them down" if linear else "")


def _understated(d: dict) -> str:
    """The other reading under a declared noise: the noise understated (a residual without
    structure, about as large everywhere, points there), with the final residual's robust
    std in units of it (``robust_noise_ratio``: 1.4826 median |r|, which gross rows do not
    inflate)."""
    ratio = d.get("robust_noise_ratio")
    if d.get("noise_std_source") != "declared" or ratio is None:
        return ""
    noun = _noun(d)
    return (f"; or the declared noise_std ({d['noise_std']:.4g} {d['unit']}) understates the "
            f"scatter: the final residual's robust std (1.4826 median |r|, which gross {noun} "
            f"do not inflate) is {ratio:.3g} times it, and a residual without structure "
            f"({_FLAT[noun == 'rows']}) points there")


def _noun(d: dict) -> str:
    """What a campaign's rows are called: a pose campaign's (``kind`` "poses") poses."""
    return "poses" if d.get("kind") == "poses" else "rows"
