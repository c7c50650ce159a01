"""The kit of pbdyn's pages and tables -- the score card (pbdyn.benchmark.render) and the evaluation report
(pbdyn.analysis.html_report, its text in pbdyn.analysis.report and pbdyn.analysis.paired): one stylesheet, the page,
the table, and how a number, an interval and a missing value are printed."""

from __future__ import annotations

import html
import math

NA = "n/a"
"""A missing value (None or NaN), wherever pbdyn prints one."""

STYLE = """
body { font-family: sans-serif; margin: 2em auto; max-width: 1100px; color: #222; line-height: 1.4; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 1.6em; border-bottom: 1px solid #ccc; }
blockquote { background: #f3f6fb; border-left: 4px solid #79c; margin: 1em 0; padding: 0.5em 1em; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.9em; }
th, td { border: 1px solid #bbb; padding: 3px 8px; text-align: right; } th { background: #eef; }
td:first-child, th:first-child { text-align: left; } dt { font-weight: bold; } dd { margin: 0 0 0.4em 1.5em; }
figure { margin: 1em 0; } figcaption { font-size: 0.9em; color: #444; }
dl.how-to-read dd { color: #333; font-size: 0.92em; }
td.name, th.name { text-align: left; } tr.baseline td { color: #555; font-style: italic; }
tr.beats td:first-child { font-weight: bold; color: #0a6; } figure img { max-width: 100%; border: 1px solid #ddd; }
pre { background: #f6f6f6; padding: 0.6em; overflow-x: auto; font-size: 0.8em; }
"""
"""The one stylesheet of every page."""


def num(x, fmt: str = ".3f") -> str:
    """``x`` by the format spec ``fmt``; NA for None or NaN."""
    return NA if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, fmt)


def interval(pair, fmt: str = ".3f") -> str:
    """"[low, high]" (each by num); NA without a pair."""
    return f"[{num(pair[0], fmt)}, {num(pair[1], fmt)}]" if pair else NA


def table(head: list[str], rows: list[list[str]], cls: str = "", *, row_classes: list[str] | None = None,
          name_cols: int = 0) -> str:
    """An HTML table of text (every heading and cell escaped): the heading row, then ``rows``. ``cls``: the
    table's class; ``row_classes``: each row's class ("" for none); ``name_cols``: the first columns hold names
    (class "name", left-aligned)."""
    def cell(tag: str, i: int, text: str) -> str:
        return f'<{tag} class="name">{html.escape(text)}</{tag}>' if i < name_cols else \
            f"<{tag}>{html.escape(text)}</{tag}>"

    out = [(f'<table class="{cls}">' if cls else "<table>") + "<tr>" + "".join(cell("th", i, h) for i, h in
                                                                                 enumerate(head)) + "</tr>"]
    for k, r in enumerate(rows):
        tr = f'<tr class="{row_classes[k]}">' if row_classes and row_classes[k] else "<tr>"
        out.append(tr + "".join(cell("td", i, c) for i, c in enumerate(r)) + "</tr>")
    return "".join(out) + "</table>"


def page(title: str, body: list[str]) -> str:
    """A self-contained HTML page: ``title`` (escaped), the stylesheet, then the ``body`` parts (HTML), one a
    line."""
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>" + html.escape(title) +
            f"</title><style>{STYLE}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")
