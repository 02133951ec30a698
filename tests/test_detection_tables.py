"""The detection tables of ``docs/diagnose.md``, reduced (issue 40, item 3): a few of the
campaigns ``scripts/detection_rate.py`` and ``scripts/detection_pairs.py`` run, through the
scripts' own ``run_one`` (same robots, loads, noise and seeds), against the rates the tables
document, read from the page, with two-sided binomial bounds (:func:`stats.binomial_consistent`
at 1 % each side: the reduced count must be one the documented rate makes likely).

* Large effects (the hidden effect 4 noise std RMS or more: the UR5's and the SK120's
  backlash rows at their largest size) are named first at their place at the table's rate
  for that range (56/57 today).
* Tiny effects (below 0.5 noise std, five rows at their smallest size) are not, at the
  table's rate (4/139): a search that names effects the data cannot show fails here.
* Nothing hidden: ``missing_effects`` empty at the rate of the table's null rows (98/100).
* Two hidden at once: both named at their places at the pair table's rate (56/60) and the
  final model passes the chi-square test at its rate (60/60).

About 9 s of one core (pairs 2.5 s, large single effects 1 s, the rest 0.2 s each). A
bound on two runs only rejects both failing (P = 0.1-0.5 % at the documented rates); the
scripts measure the rates, this keeps the code that produced them honest.
"""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path
from types import ModuleType

import pytest
from stats import binomial_consistent

ROOT = Path(__file__).resolve().parents[1]
DOC = (ROOT / "docs" / "diagnose.md").read_text()
#: Two-sided level of every bound (1 % each side).
ALPHA = 0.02


def _script(name: str, monkeypatch: pytest.MonkeyPatch) -> ModuleType:
    """``scripts/<name>.py`` as a module (``scripts/`` on the path: the pair script imports the
    rate script)."""
    monkeypatch.syspath_prepend(str(ROOT / "scripts"))
    spec = importlib.util.spec_from_file_location(f"_{name}", ROOT / "scripts" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _fraction(text: str) -> tuple[int, int]:
    hits, n = text.split("/")
    return int(hits), int(n)


def _documented_by_size() -> dict[str, tuple[int, int]]:
    """The single-effect table's ``detected first`` row: size bin -> (detected, runs)."""
    head = re.search(r"^\| effect size \(noise std RMS\) \|(.*)\|$", DOC, re.M)
    row = re.search(r"^\| detected first \|(.*)\|$", DOC, re.M)
    assert head and row, "docs/diagnose.md lost the detection-rate table"
    return {b.strip(): _fraction(c.strip()) for b, c in zip(head.group(1).split("|"),
                                                            row.group(1).split("|"),
                                                            strict=True)}


def _documented_nulls() -> tuple[int, int]:
    """The null rows (nothing hidden): runs with ``missing_effects`` empty, all pooled."""
    cells = re.findall(r"^\| (?:ur5|sk120) \| [0-9.]+ mm \| (\d+/\d+) \|", DOC, re.M)
    assert len(cells) == 4, "docs/diagnose.md lost the null rows of the detection table"
    counts = [_fraction(c) for c in cells]
    return sum(h for h, _ in counts), sum(n for _, n in counts)


def _check(label: str, hits: int, n: int, documented: tuple[int, int], runs: list) -> None:
    """``hits`` of ``n`` against the ``documented`` count's rate (a count of all or none
    taken as half a run short of it: 60/60 is not a certainty)."""
    h, m = documented
    rate = h / m if 0 < h < m else (h + 0.5) / (m + 1)
    assert binomial_consistent(hits, n, rate, ALPHA), (
        f"{label}: {hits}/{n} against the documented {h}/{m}", runs)


def test_single_effect_table_reduced(monkeypatch):
    """Seven campaigns of the single-effect table plus five null ones, each the script's own
    (its seeds 100 and 200)."""
    rate = _script("detection_rate", monkeypatch)
    by_size = _documented_by_size()
    large = [("ur5", "backlash:shoulder_lift_joint", 5e-3, 0.005),
             ("sk120", "backlash:joint2", 3e-3, 0.005)]
    tiny = [("ur5", "complementary_stiffness", 50, 0.005),
            ("ur5", "frame_misalignment", 0.2, 0.02),
            ("ur5", "target_offset", 2.0, 0.02),
            ("ur5", "force_sensor_bias", 0.5, 0.02),
            ("sk120", "backlash:joint2", 3e-4, 0.02)]
    runs = [rate.run_one((*row, 100, 10)) for row in large]
    assert all(r["snr"] >= 4 for r in runs), runs
    pooled = [by_size[b] for b in ("4–8", "> 8")]
    _check("large effects named first", sum(r["detected"] for r in runs), len(runs),
           (sum(h for h, _ in pooled), sum(n for _, n in pooled)), runs)
    runs = [rate.run_one((*row, 100, 10)) for row in tiny]
    assert all(r["snr"] < 0.5 for r in runs), runs
    _check("tiny effects named first", sum(r["detected"] for r in runs), len(runs),
           by_size["0–0.5"], runs)
    runs = [rate.run_one((robot, None, 0.0, noise, 200 + seed, 10))
            for robot, noise, seed in (("ur5", 0.005, 0), ("ur5", 0.005, 1), ("ur5", 0.02, 0),
                                       ("sk120", 0.005, 0), ("sk120", 0.02, 0))]
    _check("nothing hidden, nothing named", sum(not r["named"] for r in runs), len(runs),
           _documented_nulls(), runs)


def test_pair_table_reduced(monkeypatch):
    """Two campaigns of the pair table (a Panda and an SK120 pair, the script's seed 300)."""
    pairs = _script("detection_pairs", monkeypatch)
    summary = re.search(r"All pairs: both named in (\d+/\d+), both names in \d+/\d+, final RMS "
                        r"within 1\.5x the noise in \d+/\d+, chi-square passed in (\d+/\d+)\.",
                        DOC)
    assert summary, "docs/diagnose.md lost the pair table's summary line"
    runs = [pairs.run_one(("panda", pairs.PAIRS["panda"][0], 300, 10)),
            pairs.run_one(("sk120", pairs.PAIRS["sk120"][1], 300, 10))]
    _check("both named", sum(r["both"] for r in runs), len(runs),
           _fraction(summary.group(1)), runs)
    _check("chi-square passed", sum(r["passes"] for r in runs), len(runs),
           _fraction(summary.group(2)), runs)
