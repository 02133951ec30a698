"""What a result of either campaign kind holds and reads alike: :class:`DiagnosisResult`, the
base of :class:`~stiffness.calibration.diagnosis.Diagnosis` and
:class:`~stiffness.calibration.pose_diagnosis.PoseDiagnosis`, and :class:`IdentificationResult`,
the base of :class:`~stiffness.calibration.identification.Identification` and
:class:`~stiffness.calibration.pose_identify.PoseIdentification`. A kind keeps only what its
mathematics makes different: its ``--json`` object, its reported parameters and its files."""

from __future__ import annotations

import abc
import functools
import json
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Generic, TypeVar

from stiffness.calibration import certainty
from stiffness.calibration.campaign import Campaign
from stiffness.calibration.certainty import Certainty
from stiffness.calibration.identifiability import Identifiability
from stiffness.calibration.naming import is_stand_in
from stiffness.calibration.outliers import OUTLIER_THRESHOLD, Outlier
from stiffness.calibration.pose_campaign import PoseCampaign
from stiffness.calibration.search import E, F, SearchKind, Step, kept_steps, label
from stiffness.elastic.effects.base import Parameter
from stiffness.files import atomic_write, refuse_foreign_folder, staged_folder

#: A file of the ``--out`` folder: its name and what writes it at a path.
Output = tuple[str, Callable[[Path], object]]
#: The campaign of a result.
C = TypeVar("C", bound=Campaign | PoseCampaign)


def written(content: str | bytes) -> Callable[[Path], object]:
    """A writer of ``content`` (atomically) at the path it is given."""
    return functools.partial(atomic_write, data=content)


@dataclass(kw_only=True)
class DiagnosisResult(abc.ABC, Generic[C, E, F]):
    """A diagnosis of either kind: the ``campaign`` diagnosed, its ``steps``
    (:class:`~stiffness.calibration.search.Step`: what each added, in order, then those
    removed again) and why the ``search`` (:class:`~stiffness.calibration.search.SearchKind`,
    read by :attr:`how_sure`; ``None``: nothing to be sure of) stopped, the ``loss`` of every
    fit, whether the robot's link ``masses`` were trusted (``known``, ``unknown``), the final
    model's ``outliers`` beyond :data:`OUTLIER_THRESHOLD` noise std (flagged, none dropped)
    and the noise std (m) they are standardised by, and what was ``forbidden`` (``--not``)."""

    campaign: C
    steps: list[Step[E, F]]
    stop_reason: str = ""
    loss: str = "linear"
    masses: str = "known"
    outliers: list[Outlier] = field(default_factory=list)
    outlier_sigma_m: float | None = None
    forbidden: list[str] = field(default_factory=list)
    search: SearchKind[E, F] | None = None

    if TYPE_CHECKING:  # a deflection diagnosis's field, a pose diagnosis's first step

        @property
        def baseline(self) -> F:
            """The baseline's fit."""

    @property
    def final(self) -> F:
        """The final fit: the last step's (the baseline's when no step was taken)."""
        return self.steps[-1].fit if self.steps else self.baseline

    @property
    def unit(self) -> str:
        """The campaign's length unit."""
        return self.campaign.units.length

    @property
    def named_steps(self) -> list[Step[E, F]]:
        """The steps adding what the final model adds (:func:`kept_steps`)."""
        return kept_steps(self.steps, self.final.additions())

    @functools.cached_property
    def how_sure(self) -> list[Certainty]:
        """How sure the diagnosis is of each effect it named, in order (:func:`certainty.
        how_sure`; computed when first asked: it refits the final model without each)."""
        if self.search is None or not self.steps:
            return []
        return certainty.how_sure(self.search, self.final, self.steps[-1].cv_rms,
                                  self.named_steps, self.stand_in)

    def selection(self) -> dict:
        """How the effects were chosen (kept in ``--json`` and the model file): ``forced``
        (``--families``, the forced steps' labels in order) and ``forbidden`` (``--not``)."""
        return {"forced": [s.label for s in self.steps if s.forced],
                "forbidden": list(self.forbidden)}

    @property
    def cut_short(self) -> bool:
        """Whether ``max_steps`` (``--max-steps``) cut the forward search short
        (:attr:`~stiffness.calibration.search.SearchKind.cut_short`; a backward elimination
        may have followed)."""
        return self.search is not None and self.search.cut_short

    def search_end(self) -> dict:
        """How the search ended, as ``--json`` has it (the verdict reads it): the
        ``best_rejected`` candidate (:meth:`best_rejected`), the ``stop_reason`` and
        ``cut_short`` (:attr:`cut_short`: a library effect not tried may be what is
        missing)."""
        return {"best_rejected": self.best_rejected(), "stop_reason": self.stop_reason,
                "cut_short": self.cut_short}

    def best_rejected(self) -> dict | None:
        """The best candidate by BIC of the step that added nothing
        (:class:`~stiffness.calibration.search.Refusal`), as ``--json`` has it (``best_rejected``;
        lengths in the campaign's unit): its ``candidate`` label, ``delta_bic``, its fit's
        ``rms`` and held-out ``cv_rms`` (null: not judged) against those of the model it
        extends (``rms_before``, ``cv_rms_before``), and ``not_judged`` (why the rows cannot
        judge it held out, or null). ``None`` when no step was refused (the search stopped at
        the noise, at ``max_steps`` or with nothing left to try) or none was fitted."""
        refusal = None if self.search is None else self.search.refusal
        if refusal is None or not refusal.ranking:
            return None
        best, lu = refusal.ranking[0], self.campaign.units.length_to_si
        return {"candidate": label(best.effect), "delta_bic": best.delta_bic,
                "rms": best.fit.rms() / lu, "rms_before": refusal.current.rms() / lu,
                "cv_rms": None if best.cv_rms is None else best.cv_rms / lu,
                "cv_rms_before": refusal.cv_current / lu, "not_judged": best.refused}

    @abc.abstractmethod
    def named_parameters(self) -> dict[str, list[Parameter]]:
        """The final model's reported parameters, by the label of what added them."""

    def stand_in(self, label: str) -> bool:
        """Whether what ``label`` added is a stand-in (a determined parameter of the final
        model beyond its physical scale: :func:`stiffness.calibration.naming.is_stand_in`)."""
        return is_stand_in(self.named_parameters().get(label, []))

    def identifiability(self) -> dict:
        """The final fit's fitted and held parameters, by label (:meth:`stiffness.calibration.
        identifiability.Identifiability.to_dict`)."""
        f = self.final
        ident = f.identifiability or Identifiability.full(f.x.size)
        return ident.to_dict(f.labels())

    def outlier_keys(self) -> dict:
        """``outlier_threshold`` and ``outliers``, as ``--json`` has them."""
        return {"outlier_threshold": OUTLIER_THRESHOLD,
                "outliers": [o.to_dict() for o in self.outliers]}

    @abc.abstractmethod
    def to_dict(self) -> dict:
        """The object ``stiffness diagnose --json`` prints (campaign units)."""

    def summary(self) -> dict:
        """The ``--json`` object (:meth:`to_dict`)."""
        return self.to_dict()

    @abc.abstractmethod
    def outputs(self, folder: Path, command: str | None) -> dict[str, Output]:
        """The files of the ``--out`` folder ``folder`` by key (:meth:`write`)."""

    def write(self, folder: str | os.PathLike, command: str | None = None) -> dict[str, Path]:
        """Write the ``--out`` folder (:meth:`outputs`), published whole by one rename, the
        page's provenance naming ``command`` (default: this process's); each path by key."""
        folder = Path(folder)
        files = self.outputs(folder, command)
        refuse_foreign_folder(folder, files["diagnosis"][0], "diagnosis")
        with staged_folder(folder) as stage:
            for name, write in files.values():
                write(stage / name)
        return {key: folder / name for key, (name, _) in files.items()}


@dataclass(kw_only=True)
class IdentificationResult(abc.ABC):
    """An identification of either kind, what :func:`~stiffness.calibration.identify.identify`
    returns: the compliant joints' stiffnesses and the model file :meth:`write_model` wrote
    last (``model_path``, ``None`` before); read once for both: its JSON text and the model
    file written. A kind supplies only what its mathematics makes different: its ``--json``
    object (:meth:`to_dict`) and its model file (:meth:`write_model_file`)."""

    model_path: Path | None = None

    @abc.abstractmethod
    def to_dict(self) -> dict:
        """The object ``stiffness identify --json`` prints (SI)."""

    @abc.abstractmethod
    def write_model_file(self, path: Path) -> Path:
        """Write the kind's model file at ``path`` atomically; returns its path."""

    def to_json(self, indent: int | None = 1) -> str:
        """The result as JSON text (see :meth:`to_dict`)."""
        return json.dumps(self.to_dict(), indent=indent, allow_nan=False)

    def write_model(self, path: str | os.PathLike) -> Path:
        """Write the identified model at ``path`` (:meth:`write_model_file`; read back by
        :func:`stiffness.load_model`, ``validate`` and every ``--model``) atomically;
        :attr:`model_path` is set to it."""
        self.model_path = self.write_model_file(Path(path))
        return self.model_path
