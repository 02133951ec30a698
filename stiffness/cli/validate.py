"""``stiffness validate``: a model file evaluated on another campaign, without refitting.

Example::

    stiffness validate calibration/final-model.json held-out-poses/ --json

For a pose campaign (``kind = "poses"``) the model is a pose calibration's
``final-model.json`` (its measuring frame and marker offsets are the model's) and the output is
the 3-D position error, overall and per marker; for a deflection campaign the model is a model
file of ``identify`` or ``diagnose`` (or a pose calibration's, its springs and elastic families
as ``load_model`` reads them) and the error is the measured deflection minus the model's
prediction under each row's load (the one marker is ``target``). Both in the campaign's length
unit: RMS, mean, std and max, then the stage table's line of this model (as ``diagnose
--validate`` prints one per step), and the verdict against the campaign's declared noise (a
chi-square test, with the model's parameter uncertainty when its file carries their
covariance). The campaign must be of the model's robot (one line refuses another).
``--json`` keys: ``rms``, ``mean_error``, ``std_error``, ``max_error``, ``unit``, ``rows``,
``markers`` (the same keys per marker), ``kind``, ``model``, ``campaign``, ``robot``
(``source``, ``coordinates``, ``fingerprint``), ``noise_std``, ``rms_over_noise``, ``chi2``,
``dof``, ``gof_p``, ``verdict``, ``chi2_with_parameters``, ``gof_p_with_parameters``,
``verdict_test``, ``parameter_uncertainty``, ``frame_refit`` (the measuring frame registered
anew on the campaign: ``applied`` with ``--refit-frame``, ``rms`` after it, ``translation``,
``rotation_deg``; ``null`` for a deflection model or a pose model fitted without its frame)
(:class:`stiffness.calibration.validation.Validation`).
"""

from __future__ import annotations

import argparse
import json

from stiffness.calibration.validation import validate
from stiffness.calibration.validation_page import format_validation
from stiffness.cli import flags


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Flags of ``stiffness validate``."""
    parser.add_argument("model", metavar="MODEL", help="model file (final-model.json)")
    parser.add_argument("campaign", metavar="CAMPAIGN",
                        help="campaign.toml, or the folder holding it")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object (campaign units) and nothing else")
    flags.add_refit_flags(parser)
    flags.add_strict_flag(parser)


def run(args: argparse.Namespace) -> int:
    """Run ``stiffness validate``; returns the exit code."""
    result = validate(args.model, args.campaign, refit=flags.refit_from_args(args)).to_dict()
    print(json.dumps(result, indent=1, allow_nan=False) if args.json
          else format_validation(result))
    return 0
