"""The SK120 report: summary.json contents, the audit's findings, and the page in a browser."""

from __future__ import annotations

import json
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest

from stiffness.cli.main import main
from stiffness.papers.tables import read_table4

CLASSES = ("PD", "PSD", "ND", "NSD", "ID")


@pytest.fixture(scope="module")
def report_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("report")
    assert main(["report", "--out", str(out), "--quiet"]) == 0
    return out


@pytest.fixture(scope="module")
def summary(report_dir) -> dict:
    return json.loads((report_dir / "summary.json").read_text())


def test_files_written_without_leftovers(report_dir):
    names = sorted(p.name for p in report_dir.iterdir())
    assert "report.html" in names and "summary.json" in names and "sk120-scene.html" in names
    assert "href='sk120-scene.html'" in (report_dir / "report.html").read_text()
    assert not [n for n in names if n.startswith(".")], names


def test_summary_has_the_required_keys(summary):
    for key in ("identified_k_theta_Nmm_per_rad", "identified_k_theta_ci95_Nmm_per_rad",
                "paper_k_theta_Nmm_per_rad", "appendix_mismatches", "table2", "table3",
                "table4", "table4_paper", "table4_paper_self_consistent", "appendix_kc_max_rel",
                "kx_positive_definite_everywhere", "kx_loses_pd_at_force_N", "audit"):
        assert key in summary, key
    assert len(summary["identified_k_theta_Nmm_per_rad"]) == 3
    assert np.all(np.isfinite(summary["identified_k_theta_Nmm_per_rad"]))
    for (lo, hi), k in zip(summary["identified_k_theta_ci95_Nmm_per_rad"],
                           summary["identified_k_theta_Nmm_per_rad"], strict=True):
        assert lo < k < hi
    assert summary["paper_k_theta_Nmm_per_rad"] == pytest.approx([1.4098e9, 4.0076e8, 9.3528e8])
    assert len(summary["table2"]) == 15 and len(summary["table3"]) == 25
    for row in summary["table2"]:
        for col in ("paper_calculated_mm", "conventional_mm", "enhanced_mm", "exact_mm",
                    "measured_mm"):
            assert len(row[col]) == 3
    assert set(summary["table4"]) == {str(i) for i in range(1, 9)}


def test_table4_counts_obey_linearity_in_the_load(summary):
    """Our counts must satisfy K_C(-F) = -K_C(F): PD(F) = ND(-F), ID(F) = ID(-F)."""
    t4 = summary["table4"]
    for a, b in (("1", "2"), ("3", "6"), ("4", "7"), ("5", "8")):
        assert t4[a]["PD"] == t4[b]["ND"] and t4[a]["ND"] == t4[b]["PD"]
        assert t4[a]["ID"] == t4[b]["ID"]
    for case in t4.values():
        assert sum(case[c] for c in CLASSES) == 5824


def test_paper_table4_is_flagged_inconsistent(summary):
    paper = read_table4()
    # independent of the code: the printed case 1 and its opposite case 2
    assert paper["1"]["PD"] != paper["2"]["ND"]
    assert summary["table4_paper_self_consistent"] is False
    assert any("Table IV cases 1 and 2" in a["item"] for a in summary["audit"])


def test_appendix_typo_and_corrected_kc(summary):
    assert summary["appendix_mismatches"] == ["J21"]
    assert summary["appendix_kc_max_rel"] < 1e-8


def test_definiteness_limit_is_consistent(summary):
    assert summary["kx_positive_definite_everywhere"] is True
    # larger than every Table IV load (|F| = 173 N), so the grid stays PD
    assert summary["kx_loses_pd_at_force_N"] > 100 * np.sqrt(3)


def test_report_renders_in_headless_chromium(report_dir):
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        pytest.skip("no chromium on this machine (.ci/run installs Debian's chromium)")
    page = (report_dir / "report.html").read_text()
    n_figures = page.count("<figure")
    assert n_figures == 6
    probe = ("<script>window.addEventListener('load',()=>{for(const i of document.images)"
             "{i.setAttribute('data-rendered',i.complete&&i.naturalWidth>100?'yes':'no');}"
             "document.body.setAttribute('data-probe','done');});</script>")
    probe_file = report_dir / "probe.html"
    probe_file.write_text(page.replace("</body>", probe + "</body>"))
    with tempfile.TemporaryDirectory() as profile:
        dom = subprocess.run(
            [browser, "--headless", "--no-sandbox", "--disable-gpu",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             "--no-first-run", f"--user-data-dir={profile}", "--virtual-time-budget=5000",
             "--dump-dom", probe_file.as_uri()],
            capture_output=True, text=True, timeout=120, check=False,
        ).stdout
    probe_file.unlink()
    assert 'data-probe="done"' in dom
    assert dom.count('data-rendered="yes"') == n_figures
    assert 'data-rendered="no"' not in dom


def test_report_refuses_a_campaign_of_another_robot(tmp_path, capsys):
    campaign = tmp_path / "ur5-campaign"
    assert main(["simulate", "--robot", "ur5", "--kq", "1e5,1e5,1e5,1e4,1e4,1e4",
                 "--configs", "2", "--loads-per-config", "2", "--out", str(campaign)]) == 0
    capsys.readouterr()
    out = tmp_path / "report"
    assert main(["report", "--campaign", str(campaign), "--out", str(out), "--quiet"]) == 2
    assert "must be an SK120 campaign" in capsys.readouterr().err
    assert not out.exists()
