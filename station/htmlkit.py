"""Pieces of the self-contained HTML reports: inline SVG figures, escaping, tables, the page.

Every report of the project is one HTML file with its plots inlined as SVG:
no script, stylesheet or font is loaded from anywhere (labs are often offline).
"""

from __future__ import annotations

import html
import io
import re
from collections.abc import Iterable, Mapping

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

CSS = """
body{font-family:system-ui,sans-serif;margin:2em auto;max-width:1100px;color:#222}
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:3px 8px;text-align:right}
th{background:#eee}td.l,th.l{text-align:left}.ok{color:#070}.bad{color:#b00}h2{border-bottom:1px solid #ccc}
"""


# The SVG's ids from a fixed salt and no creation date: the same figure is the same text, so two reports of one
# session differ only where their contents do.
SVG_SALT = "station"


def svg(fig) -> str:
    """A matplotlib figure as inline SVG (the figure is closed)."""
    buf = io.StringIO()
    with matplotlib.rc_context({"svg.hashsalt": SVG_SALT}):
        fig.savefig(buf, format="svg", bbox_inches="tight", metadata={"Date": None})
    plt.close(fig)
    text = buf.getvalue()
    return text[text.index("<svg") :]


def esc(x: object) -> str:
    return html.escape(str(x))


def table(header: Iterable[str], rows: Iterable[Iterable[object]]) -> str:
    """A table; the first column left-aligned, cells escaped."""
    head = "".join(f"<th{' class=l' if i == 0 else ''}>{esc(h)}</th>" for i, h in enumerate(header))
    body = "".join(
        "<tr>" + "".join(f"<td{' class=l' if i == 0 else ''}>{esc(c)}</td>" for i, c in enumerate(r)) + "</tr>"
        for r in rows
    )
    return f"<table><tr>{head}</tr>{body}</table>"


def mapping_table(values: Mapping[str, object]) -> str:
    return table(("key", "value"), values.items())


def document(title: str, parts: Iterable[str]) -> str:
    """The whole page: a title and the given HTML parts."""
    head = f"<!doctype html><html><head><meta charset=utf-8><title>{esc(title)}</title><style>{CSS}</style></head>"
    return "\n".join([head, "<body>", f"<h1>{esc(title)}</h1>", *parts, "</body></html>"])


def provenance_section(provenance: Mapping[str, object]) -> str:
    """Where the session came from (station.provenance): software, station, operator, host, time, instrument."""
    if not provenance:
        return '<h2>Provenance</h2><p class="note">not recorded</p>'
    shown = {k: ("not recorded" if v is None else v) for k, v in provenance.items()}
    return "<h2>Provenance</h2>" + mapping_table(shown)


def with_provenance(html: str, provenance: Mapping[str, object]) -> str:
    """A report with its session's provenance right after the title (or at the end of a page without one)."""
    section = provenance_section(provenance)
    if "</h1>" in html:
        return html.replace("</h1>", "</h1>\n" + section, 1)
    return html.replace("</body>", section + "\n</body>", 1) if "</body>" in html else html + section


def html_fragment(document: str) -> str:
    """The body of a self-contained HTML report (`document`), for a notebook's output cell."""
    match = re.search(r"<body>(.*)</body>", document, re.S)
    return match.group(1) if match else document
