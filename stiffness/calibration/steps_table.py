"""The steps table of either campaign kind's diagnosis page: what each step of the search added
(or removed), its BIC change, its RMS and its held-out RMS, in the campaign's length unit."""

from __future__ import annotations

from stiffness.calibration.stage_table import step_label
from stiffness.htmlpage import esc, table


def steps_table(steps: list[dict], unit: str) -> str:
    """The table of ``steps``: ``--json`` step objects (:func:`~stiffness.calibration.
    stage_table.step_label` names them) with ``delta_bic`` (absent: no cell), ``rms`` and
    ``cv_rms``, numbered from 0, and ``n_parameters`` where the kind counts them."""
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
