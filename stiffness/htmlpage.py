"""The house template of the pages the toolkit writes (report, diagnosis): escaping, numbers,
tables with captions and legends, the provenance block, contents and the page itself.

Foundation layer (imports only :mod:`stiffness.provenance`). No JSON or Python literal is ever
printed: cells are numbers, words or HTML the caller built from escaped parts.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Sequence

import numpy as np

STYLE = (
    "body{font-family:system-ui,sans-serif;max-width:1180px;margin:auto;padding:0 16px;"
    "color:#222;line-height:1.45}h1{font-size:26px;margin-bottom:4px}h2{margin-top:32px;"
    "border-bottom:1px solid #ddd;padding-bottom:4px}"
    "table{border-collapse:collapse;min-width:640px;"
    "margin:10px 0 18px}td,th{border:1px solid #bbb;padding:3px 7px;font-size:13px;"
    "vertical-align:top}th{background:#f2f2f2}caption{caption-side:top;text-align:left;"
    "padding:4px 0;font-size:13px}.legend{color:#555}.verdict{color:#fff;border-radius:4px;"
    "padding:1px 6px;white-space:nowrap;font-size:12px}.summary td{font-size:14px}"
    "nav ol{columns:2}pre{background:#f6f6f6;padding:10px;overflow-x:auto}img{max-width:100%}"
    "figure{margin:18px 0}figcaption{font-size:13px;color:#444}.lead{font-size:15px}"
    "dl.prov{display:grid;grid-template-columns:max-content auto;gap:2px 14px;font-size:13px}"
    "dl.prov dt{color:#555}tr.group td{border-top:2px solid #888}"
    "code{background:#f3f3f3;padding:0 3px}"
)


def esc(text) -> str:
    """HTML-escaped text."""
    return html.escape(str(text))


def num(x, digits: int = 4) -> str:
    """A number for a cell: ``digits`` significant digits; ``—`` for missing, ``unbounded``
    for an infinite value."""
    if x is None:
        return "—"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, float | np.floating):
        if not np.isfinite(x):
            return "unbounded"
        return f"{x:.{digits}g}"
    return esc(x)


def vec(values, digits: int = 4) -> str:
    """Components ``a, b, c`` with ``digits`` decimals."""
    return ", ".join(f"{x:.{digits}f}" for x in values)


def table(caption: str, headers: list[str], rows: list[list], legend: str = "",
          cls: str = "") -> str:
    """A table with its caption and the legend of its cells; a ``str`` cell is taken as HTML
    (escape it), anything else goes through :func:`num`."""
    head = "".join(f"<th>{esc(h)}</th>" for h in headers)
    body = "".join("<tr>" + "".join(
        f"<td>{c if isinstance(c, str) else num(c)}</td>" for c in row) + "</tr>"
        for row in rows)
    legend_html = f" <span class='legend'>{esc(legend)}</span>" if legend else ""
    return (f"<table class='{cls}'><caption><b>{esc(caption)}</b>{legend_html}</caption>"
            f"<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>")


def figure(anchor: str, png: bytes, caption: str) -> str:
    """An embedded PNG figure with its caption."""
    b64 = base64.b64encode(png).decode()
    return (f"<figure id='{esc(anchor)}'><img alt='{esc(caption)}' "
            f"src='data:image/png;base64,{b64}'><figcaption>{esc(caption)}</figcaption></figure>")


def provenance_block(prov: dict, extra: Sequence[tuple[str, str]] = ()) -> str:
    """The provenance as a definition list (see :func:`stiffness.provenance.provenance`);
    ``extra`` rows are (name, HTML)."""
    commit = prov["git_commit"] or "not a git checkout"
    if prov["git_commit"] and prov["git_dirty"]:
        commit += " (with uncommitted changes)"
    items = [("stiffness version", esc(prov["package_version"])), ("git commit", esc(commit)),
             ("date", esc(prov["date_utc"])), ("Python", esc(prov["python"])),
             ("Pinocchio", esc(prov["pinocchio"])), ("NumPy", esc(prov["numpy"])),
             ("platform", esc(prov["platform"])),
             ("command", f"<code>{esc(prov['command'])}</code>"), *extra]
    return "<dl class='prov'>" + "".join(f"<dt>{esc(k)}</dt><dd>{v}</dd>" for k, v in items) + \
        "</dl>"


def contents(sections: dict[str, str], skip: tuple[str, ...] = ("summary",)) -> str:
    """The table of contents: ``anchor -> heading``."""
    return "<nav id='contents'><h2>Contents</h2><ol>" + "".join(
        f"<li><a href='#{a}'>{esc(t)}</a></li>" for a, t in sections.items() if a not in skip
    ) + "</ol></nav>"


def heading(anchor: str, sections: dict[str, str]) -> str:
    """A section heading with its anchor."""
    return f"<h2 id='{anchor}'>{esc(sections[anchor])}</h2>"


def reproduce_block(prov: dict, anchor: str, sections: dict[str, str], outputs: str) -> str:
    """The closing "reproduce this" section: checkout, install, the command."""
    checkout = f"git checkout {prov['git_commit']}\n" if prov["git_commit"] else ""
    return (f"{heading(anchor, sections)}<p>In a checkout of the <i>stiffness</i> repository "
            f"(Python ≥ 3.10):</p><pre>{esc(checkout)}pip install -e .\n"
            f"{esc(prov['command'])}</pre><p>{esc(outputs)}</p>")


def page(title: str, body: list[str]) -> str:
    """The whole page."""
    return (f"<!doctype html><html lang='en'><head><meta charset='utf-8'><title>{esc(title)}"
            f"</title><style>{STYLE}</style></head><body>" + "\n".join(body)
            + "</body></html>")
