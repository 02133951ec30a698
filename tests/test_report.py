"""The SK120 report: summary.json contents, the audit's findings, and the page in a browser."""

from __future__ import annotations

import json
import re
import subprocess
import tempfile
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from browser import chromium

from stiffness.cli.main import main
from stiffness.mechanics.formulation import target_state
from stiffness.papers.tables import read_paper_table, read_table4
from stiffness.robot.robot import load_robot
from stiffness.robot.sources import robots_directory

CLASSES = ("PD", "PSD", "ND", "NSD", "ID")


@pytest.fixture(scope="module")
def report_run(sk120_report_run) -> tuple[Path, str]:
    return sk120_report_run


@pytest.fixture(scope="module")
def report_dir(report_run) -> Path:
    return report_run[0]


@pytest.fixture(scope="module")
def summary(report_dir) -> dict:
    return json.loads((report_dir / "summary.json").read_text())


def test_files_written_without_leftovers(report_dir):
    names = sorted(p.name for p in report_dir.iterdir())
    assert "report.html" in names and "summary.json" in names and "sk120-scene.html" in names
    assert "href='sk120-scene.html'" in (report_dir / "report.html").read_text()
    assert not [n for n in names if n.startswith(".")], names
    # the shipped campaign by its name: the same in every install and output folder
    recorded = json.loads((report_dir / "summary.json").read_text())["campaign"]
    assert recorded == "shipped with stiffness: robots/sk120/campaigns/table2"
    assert (robots_directory() / recorded.rpartition("robots/")[2] / "campaign.toml").is_file()


def test_a_given_campaign_is_recorded_relative_to_the_report(tmp_path, monkeypatch):
    from stiffness.files import resolve_path
    from stiffness.papers import report
    from stiffness.papers.report import write_report
    campaign = tmp_path / "data" / "table2"
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(report, "render_html", lambda summary, figures: "")  # the record only
    write_report(tmp_path / "out" / "r", {"campaign": "data/table2", "provenance": {}}, {})
    recorded = json.loads((tmp_path / "out" / "r" / "summary.json").read_text())["campaign"]
    assert recorded == "../../data/table2"
    assert Path(resolve_path(recorded, tmp_path / "out" / "r")).resolve() == campaign.resolve()


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


def test_report_renders_in_headless_chromium(report_dir, tmp_path):
    browser = chromium()
    page = (report_dir / "report.html").read_text()
    n_figures = page.count("<figure")
    assert n_figures == 6
    probe = ("<script>window.addEventListener('load',()=>{for(const i of document.images)"
             "{i.setAttribute('data-rendered',i.complete&&i.naturalWidth>100?'yes':'no');}"
             "document.body.setAttribute('data-probe','done');});</script>")
    probe_file = tmp_path / "probe.html"  # the page holds its figures: it renders anywhere
    probe_file.write_text(page.replace("</body>", probe + "</body>"))
    with tempfile.TemporaryDirectory() as profile:
        dom = subprocess.run(
            [browser, "--headless", "--no-sandbox", "--disable-gpu",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             "--no-first-run", f"--user-data-dir={profile}", "--virtual-time-budget=5000",
             "--dump-dom", probe_file.as_uri()],
            capture_output=True, text=True, timeout=120, check=False,
        ).stdout
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


# ------------------------------------------------------------------------- the page a reader sees


class _Page(HTMLParser):
    """Visible text (no script or style), tables and their captions, ids and links."""

    def __init__(self) -> None:
        super().__init__()
        self.text: list[str] = []
        self.tables = 0
        self.captions = 0
        self.ids: list[str] = []
        self.links: list[str] = []
        self._skip = 0

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag in ("script", "style"):
            self._skip += 1
        self.tables += tag == "table"
        self.captions += tag == "caption"
        if "id" in attrs:
            self.ids.append(attrs["id"])
        if tag == "a" and attrs.get("href", "").startswith("#"):
            self.links.append(attrs["href"][1:])

    def handle_endtag(self, tag):
        if tag in ("script", "style"):
            self._skip -= 1

    def handle_data(self, data):
        if not self._skip:
            self.text.append(data)


@pytest.fixture(scope="module")
def page(report_dir) -> _Page:
    parsed = _Page()
    parsed.feed((report_dir / "report.html").read_text())
    return parsed


def test_page_opens_on_a_summary_then_contents_then_provenance(page, summary):
    text = " ".join(page.text)
    order = [page.ids.index(a) for a in ("summary", "contents", "provenance")]
    assert order == sorted(order) and page.ids[-1] != "summary"
    assert page.ids.index("summary") < page.ids.index("conventions")
    # every verdict in the summary table is one of the four, every link lands in the page
    for claim in summary["claims"]:
        assert claim["verdict"] in ("reproduced", "not reproduced", "error in the paper",
                                    "undecidable from the paper")
        assert claim["section"] in page.ids
    assert set(page.links) <= set(page.ids)
    prov = summary["provenance"]
    for value in (prov["package_version"], prov["python"], prov["pinocchio"],
                  prov["date_utc"], prov["command"]):
        assert value in text, value
    assert prov["command"].startswith("stiffness report --out ")
    assert re.fullmatch(r"[0-9a-f]{40}", prov["git_commit"] or "0" * 40)
    assert text.rstrip().endswith("the figures as PNG.")  # the "reproduce this" block ends it
    assert prov["command"] in text[text.index("Reproduce this"):]


def test_page_has_no_raw_literals_and_every_table_a_caption(page, report_dir):
    captions = re.findall(r"<caption>(.*?)</caption>", (report_dir / "report.html").read_text(),
                          re.S)
    assert len(captions) == page.tables and all("class='legend'" in c for c in captions)
    text = " ".join(page.text)
    assert '{"' not in text and "': " not in text and "{'" not in text
    assert "_mm" not in text and "Infinity" not in text and "None" not in text
    assert page.tables >= 10 and page.captions == page.tables


def test_plot_labels_are_words_with_units(monkeypatch, summary):
    """Legends, titles and axis labels of the row-by-row figures: no variable names, units
    on the value axes, the configuration rows (A1 ...) on the other."""
    from stiffness.papers import figures

    drawn = []
    monkeypatch.setattr(figures, "png", lambda fig, dpi: drawn.append(fig) or b"")
    figures.table2_comparison(summary["table2"])
    figures.table3_work_per_load(summary["table3"], summary["table3_corrupt_rows"])
    for fig in drawn:
        legends = [*fig.legends, *(ax.get_legend() for ax in fig.axes)]
        texts = [t.get_text() for lg in legends if lg is not None for t in lg.get_texts()]
        assert texts, "a figure without a legend"
        for ax in fig.axes:
            texts += [ax.get_xlabel(), ax.get_ylabel(), ax.get_title()]
            assert "row" in ax.get_xlabel()
            assert [t.get_text() for t in ax.get_xticklabels()][:2] == ["A1", "A2"]
            assert re.search(r"\(.*(mm|N).*\)", ax.get_ylabel()), ax.get_ylabel()
        for text in texts:
            assert not re.search(r"[a-z]_[a-z]", re.sub(r"\$[^$]*\$", "", text)), text


def test_terminal_says_findings_in_the_paper(report_run, summary):
    said = report_run[1]
    assert f"{summary['findings_count']} findings in the paper" in said
    assert "violations" not in said
    assert summary["findings_count"] == len(summary["audit"])
    assert all(a["verdict"] in summary["findings_by_verdict"] for a in summary["audit"])


def _independent_convention(robot, remap, k_theta):
    """Table II RMS (enhanced, paper's K_theta) and a least-squares K_theta (conventional,
    linear in the compliances) with the printed angles remapped, straight from mechanics."""
    err, blocks, values = [], [], []
    for rec in read_paper_table("table2"):
        q = robot.configuration(np.deg2rad(remap(rec["q"])))
        force = rec["force_N"]
        state = target_state(robot, q, force)
        jac = state.jacobian[:3]
        err.append(jac @ np.linalg.solve(k_theta - state.k_c, jac.T @ force) - rec["measured_m"])
        blocks.append(jac * (jac.T @ force)[None, :])
        values.append(rec["measured_m"])
    c, *_ = np.linalg.lstsq(np.vstack(blocks), np.concatenate(values), rcond=None)
    return float(np.sqrt(np.mean(np.square(err)))) * 1e3, 1e3 / c


def test_two_conventions_match_an_independent_computation(summary):
    conventions = summary["conventions"]
    assert [c["name"] for c in conventions] == ["chosen", "alternative"]
    for c in conventions:
        assert {"name", "theta_map", "table2_rms_mm", "table3_sign_agreement",
                "k_theta_Nmm_per_rad"} <= set(c)
        assert 0 <= c["table3_sign_agreement"] <= 25
    robot = load_robot("sk120")
    k_theta = np.diag(robot.defaults["k_theta_SI"])
    # chosen: theta1_DH = 180 - q1, theta6_DH = 90 + q6; alternative: theta1_DH = q1,
    # theta6_DH = q6 (the rest alike), so on the shipped model q1 -> 180 - q1, q6 -> q6 - 90
    remaps = (lambda q: q, lambda q: np.r_[180.0 - q[0], q[1:5], q[5] - 90.0])
    assert "theta1_DH = 0 deg + q1" in conventions[1]["theta_map"]
    assert "theta6_DH = 0 deg + q6" in conventions[1]["theta_map"]
    for c, remap in zip(conventions, remaps, strict=True):
        rms, k = _independent_convention(robot, remap, k_theta)
        assert c["table2_rms_mm"] == pytest.approx(rms, rel=1e-9)
        np.testing.assert_allclose(c["k_theta_Nmm_per_rad"], k, rtol=5e-3)
    # the headline K_theta carries the band over both conventions
    band = summary["k_theta_convention_band_Nmm_per_rad"]
    for j, (lo, hi) in enumerate(band):
        values = [c["k_theta_Nmm_per_rad"][j] for c in conventions]
        assert lo == pytest.approx(min(values)) and hi == pytest.approx(max(values))


def test_table3_corrupt_row_by_work_per_load(summary):
    rows = read_paper_table("table3")
    ratio = np.array([r["work_cartesian"] / np.dot(r["force_N"], r["force_N"]) for r in rows])
    configs = np.array([r["config"] for r in rows])
    in_c = ratio[configs == "C"]
    departure = np.abs(in_c / np.median(in_c) - 1.0)
    assert summary["table3_corrupt_row"] == {"config": "C", "row": int(np.argmax(departure)) + 1}
    entry = next(a for a in summary["audit"] if a["item"].startswith("Table III configuration C"))
    assert "misprinted" in entry["finding"]


def test_findings_say_no_more_than_the_evidence(summary):
    by_item = {a["item"]: a for a in summary["audit"]}
    ident = by_item["identified K_theta"]
    assert ident["verdict"] == "undecidable from the paper"
    assert "not a finding about the paper" in ident["finding"]
    assert by_item["printed joint angles: convention"]["verdict"] == "undecidable from the paper"
    symmetric = by_item["Table II calculated deflections: symmetric linear map of F"]
    assert "Caveat" in symmetric["finding"] and "Table I does not give" not in json.dumps(
        summary["audit"])
    fits = summary["table2_linear_map_fits"]
    for config, fit in fits.items():  # a general map fits to rounding, a symmetric one not all
        assert fit["general_max_residual_mm"] < 1e-4, config
    assert max(f["symmetric_max_residual_mm"] for f in fits.values()) > 10 * max(
        f["ours_symmetric_max_residual_mm"] for f in fits.values())
    signs = [a for a in summary["audit"] if a["item"].endswith("sign of the work difference")]
    for a in signs:  # a sign that flips with the convention is not called a paper error
        agree = a["numbers"]["rows_agreeing_by_convention"]
        if len(set(agree.values())) > 1:
            assert a["verdict"] == "undecidable from the paper"


def test_report_files_hold_no_undefined_number(report_dir):
    """summary.json is strict JSON (no NaN / Infinity tokens: undefined values are null with a
    reason) and every JSON block embedded in the pages is too (docs/reliability.md)."""
    def refuse(token):
        raise AssertionError(f"non-finite number {token}")

    checked = 0
    for path in sorted(report_dir.rglob("*")):
        if path.suffix == ".json":
            json.loads(path.read_text(), parse_constant=refuse)
            checked += 1
        elif path.suffix == ".html":
            for block in re.findall(r'<script type="application/json"[^>]*>(.*?)</script>',
                                    path.read_text(), re.S):
                json.loads(block, parse_constant=refuse)
            checked += 1
    assert checked >= 3


@pytest.mark.parametrize("child, expected", [
    # the second process answers: its parts are used
    ("import pickle, sys; sys.stdout.buffer.write(pickle.dumps({'from': 'child'}))",
     {"from": "child"}),
    # it fails, or imports another stiffness (exit 3): computed in this process
    ("import sys; sys.exit(3)", {"from": "this process"}),
    ("import sys; sys.stdout.write('not a pickle')", {"from": "this process"}),
])
def test_second_process_parts_or_this_process(monkeypatch, child, expected):
    """`stiffness report` takes the campaign-independent parts from its second process when
    that process answers, and computes them itself when it does not."""
    from stiffness.cli import report as command

    monkeypatch.setattr(command, "_INDEPENDENT_CHILD", child)
    monkeypatch.setattr(command, "independent_parts", lambda: {"from": "this process"})
    monkeypatch.setattr(command, "usable_cores", lambda: 2)
    with command.background_independent_parts() as collect:
        assert collect() == expected
