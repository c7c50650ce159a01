"""Score cards as Markdown and as one self-contained HTML page, and side-by-side comparisons of cards.

The figure -- success per difficulty level, the planner's curve with its 95% band beside the reference planners'
curves -- is drawn with matplotlib and inlined as SVG (no external file, script or font).
"""

from __future__ import annotations

import html
import io
import math
import re

from pbdyn.benchmark.card import OUTCOMES

NA = "n/a"


_MD_SPECIAL = "\\`*_[]<>|~&"
"""Characters a Markdown renderer may read as markup anywhere in a line (emphasis, code, links and images -- with
[ ] escaped, ( ) ! cannot form one -- the table pipe, strike-through, HTML's < > &), each escaped with a
backslash by md_escape."""
_MD_LEADING = re.compile(r"^(?:[#+*-]\s|>|=+$|\d{1,9}[.)]\s)")
"""What is markup only where a line starts (a heading, a list item, a quote, a setext underline, an ordered list):
md_escape escapes the first character of a text that starts so."""


def md_escape(text: object) -> str:
    """``text`` as literal Markdown: one line (control characters escaped), every inline markup character
    backslash-escaped (a pipe cannot end a table cell, a "<" cannot open HTML, a "[" cannot open a link), and a
    leading block marker too."""
    from pbdyn.errors import one_line_text

    line = "".join("\\" + c if c in _MD_SPECIAL else c for c in one_line_text(str(text)))
    if _MD_LEADING.match(line):
        digits = len(line) - len(line.lstrip("0123456789"))
        return line[:digits] + "\\" + line[digits:] if digits else "\\" + line
    return line


def _f(x, fmt: str = ".2f") -> str:
    return NA if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, fmt)


def _ci(pair, fmt: str = ".2f") -> str:
    return f"[{_f(pair[0], fmt)}, {_f(pair[1], fmt)}]" if pair else NA


def _curves(card: dict) -> list[tuple[str, list, list, bool]]:
    """(label, levels, success per level, is the card's planner) of the planner and every reference."""
    out = [(card["planner"]["label"], [lv["level"] for lv in card["levels"]], [lv["rate"] for lv in card["levels"]],
            True)]
    for r in card.get("references", []):
        if r["label"] != card["planner"]["label"]:
            out.append((r["label"], [lv["level"] for lv in r["levels"]], [lv["rate"] for lv in r["levels"]], False))
    return out


def curve_svg(cards: list[dict], *, references: bool = True) -> str:
    """An SVG figure (text) of success per level: each card's planner (with its 95% band), and the first card's
    reference planners (dashed) when ``references``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with matplotlib.rc_context({"svg.hashsalt": "pbdyn", "svg.fonttype": "none"}):
        fig, ax = plt.subplots(figsize=(7.0, 4.0))
        try:
            for i, card in enumerate(cards):
                levels = [lv["level"] for lv in card["levels"]]
                rate = [math.nan if lv["rate"] is None else lv["rate"] for lv in card["levels"]]
                lo = [math.nan if lv["ci95"][0] is None else lv["ci95"][0] for lv in card["levels"]]
                hi = [math.nan if lv["ci95"][1] is None else lv["ci95"][1] for lv in card["levels"]]
                line, = ax.plot(levels, rate, marker="o", lw=2.2, label=_plain(card["planner"]["label"]), zorder=3)
                ax.fill_between(levels, lo, hi, color=line.get_color(), alpha=0.18, lw=0)
            if references and cards:
                for label, levels, rate, own in _curves(cards[0])[1:]:
                    ax.plot(levels, [math.nan if r is None else r for r in rate], ls="--", lw=1.2, marker=".",
                            label=_plain(f"{label} (reference)"), zorder=2)
            ax.set_xlabel("difficulty level (1 = easiest; anchored scale)")
            ax.set_ylabel("success rate")
            ax.set_ylim(-0.02, 1.02)
            if cards:
                ax.set_xticks([lv["level"] for lv in cards[0]["levels"]])
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7, loc="upper right")
            fig.tight_layout()
            buf = io.StringIO()
            fig.savefig(buf, format="svg", metadata={"Date": None, "Creator": None})
        finally:
            plt.close(fig)
    text = buf.getvalue()
    return text[text.index("<svg"):]


def _plain(label: str) -> str:
    """A legend label matplotlib draws as it is: "$" never starts math text, "_" never hides a label."""
    return "\u200b" + label.replace("$", r"\$") if label.startswith("_") else label.replace("$", r"\$")


def _figures_rows(card: dict) -> list[tuple[str, str]]:
    t, p, c, pt = card["time_to_goal_s"], card["path_ratio"], card["min_clearance_m"], card["planning_time_ms"]
    return [
        ("time to goal (s; successful tasks)", f"median {_f(t['median'])}, IQR {_ci(t['iqr'])} (n = {t['n']})"),
        ("path length / straight-line distance to the goal ball (successful tasks)",
         f"median {_f(p['median'], '.3f')}, IQR {_ci(p['iqr'], '.3f')} (n = {p['n']})"),
        ("minimum clearance (m; successful tasks)", f"median {_f(c['median'])}, IQR {_ci(c['iqr'])} (n = {c['n']})"),
        ("planner time per step (ms; wall time, this machine)",
         f"median {_f(pt['median'], '.3f')}, p99 {_f(pt['p99'], '.3f')} (medians over {pt['n']} tasks)"),
        ("worst 20% of levels: mean success", f"{_f(card['cvar20_success']['rate'])} "
                                              f"({card['cvar20_success']['levels']} level(s))"),
    ]


FAILURES = OUTCOMES[1:]
"""The failure outcomes, in the card's order."""


def _level_rows(card: dict) -> list[list[str]]:
    rows = []
    ranges = {lv["level"]: lv["success_range"] for lv in card["suite"]["levels"]}
    for lv in card["levels"]:
        rng = ranges.get(lv["level"])
        rows.append([str(lv["level"]), _ci(rng) if rng else NA, f"{_f(lv['rate'])} {_ci(lv['ci95'])}",
                     str(lv["trials"]), *(str(lv["outcomes"][o]) for o in FAILURES)])
    return rows


LEVEL_HEAD = ["level", "reference success range", "success [95% CI]", "tasks",
              *(o.replace("_", " ") for o in FAILURES)]
PAIRED_HEAD = ["reference", "its success", "tasks in common", "both", "only this", "only the reference", "neither",
               "difference [95% CI]", "McNemar p"]
REFERENCE_HEAD = ["reference", "success [95% CI]", "ability (logits) [95% CI]", "worst-20% levels"]


def _paired_rows(card: dict) -> list[list[str]]:
    rows = []
    for r in card.get("references", []):
        if r["label"] == card["planner"]["label"]:
            continue
        pc = r["paired"]
        rows.append([r["label"], _f(r["success"]["rate"]), str(pc["tasks"]), str(pc["both"]), str(pc["a_only"]),
                     str(pc["b_only"]), str(pc["neither"]),
                     f"{_f(pc['difference'], '+.3f')} {_ci(pc['difference_ci95'], '+.3f')}",
                     _f(pc["mcnemar_p"], ".3g")])
    return rows


def _reference_rows(card: dict) -> list[list[str]]:
    rows = []
    for r in card.get("references", []):
        a = r["ability"]
        rows.append([r["label"], f"{_f(r['success']['rate'])} {_ci(r['success']['ci95'])}",
                     f"{_f(a['logit'], '+.2f')} {_ci(a['ci95'], '+.2f')}" if a else NA,
                     _f(r["cvar20_success"]["rate"])])
    return rows


def _header_facts(card: dict) -> list[tuple[str, str]]:
    s, a, pv = card["success"], card["ability"], card["provenance"]
    m = pv["machine"]
    return [
        ("planner", f"{card['planner']['label']} (fingerprint {card['planner']['fingerprint']})"),
        ("suite", f"{card['suite']['name']} v{card['suite']['version']}, hash {card['suite']['hash']} "
                  f"({card['suite']['maps']} maps, {card['suite']['tasks']} tasks, MAV speeds "
                  f"{'/'.join(_f(v, 'g') for v in card['suite']['speeds_mps'])} m/s)"),
        ("success", f"{_f(s['rate'])} {_ci(s['ci95'])} ({s['successes']} of {s['trials']} tasks; flown "
                    f"{card['trials']['flown']} of {card['trials']['expected']}, errors {card['trials']['errors']})"),
        ("ability", (f"{_f(a['logit'], '+.2f')} logits {_ci(a['ci95'], '+.2f')} on the {pv['scale']} scale; rank "
                     f"{card['rank']['rank']} of {card['rank']['of']} with the references") if a else NA),
        ("made with", f"pbdyn {pv['pbdyn']} on {m.get('cpu') or m.get('machine')} ({m.get('cpus')} CPUs, "
                      f"{m.get('system')}, Python {m.get('python')}), {pv['date']}"),
    ] + ([("code", f"core {pv['code']['core']}; {pv['code']['statement']}")] if pv.get("code") else []) \
        + ([("note", card["suite"]["note"])] if card["suite"].get("note") else [])


def _md_table(head: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(md_escape(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def card_markdown(card: dict) -> str:
    """The card as Markdown."""
    e = md_escape
    parts = [f"# Score card: {e(card['planner']['label'])} on {e(card['suite']['name'])}", "",
             f"> {e(card['summary'])}", ""]
    parts += [f"- **{k}**: {e(v)}" for k, v in _header_facts(card)]
    if "reproduction" in card:
        rp = card["reproduction"]
        parts.append(f"- **reproduction of the shipped reference**: "
                     + ("bit for bit on all " + str(rp["tasks"]) + " tasks" if rp["identical"]
                        else f"{rp['n_differences']} difference(s)"))
    parts += ["", "## Success per difficulty level", "", _md_table(LEVEL_HEAD, _level_rows(card)), "",
              "## Figures", "", _md_table(["figure", "value"], [list(r) for r in _figures_rows(card)]), "",
              "## Paired comparison with the reference planners (identical tasks)", "",
              _md_table(PAIRED_HEAD, _paired_rows(card)) if _paired_rows(card) else "No reference results.", "",
              "## Reference planners", "",
              _md_table(REFERENCE_HEAD, _reference_rows(card)) if card.get("references") else "None shipped.", "",
              f"Schema {e(card['schema'])}; the figure and every number are in card.json.", ""]
    return "\n".join(parts)


_STYLE = """
body { font-family: sans-serif; margin: 2em auto; max-width: 1050px; color: #222; line-height: 1.4; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 1.6em; border-bottom: 1px solid #ccc; }
blockquote { background: #f3f6fb; border-left: 4px solid #79c; margin: 1em 0; padding: 0.5em 1em; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.9em; }
th, td { border: 1px solid #bbb; padding: 3px 8px; text-align: right; } th { background: #eef; }
td:first-child, th:first-child { text-align: left; } dt { font-weight: bold; } dd { margin: 0 0 0.4em 1.5em; }
figure { margin: 1em 0; } figcaption { font-size: 0.9em; color: #444; }
"""


def _html_table(head: list[str], rows: list[list[str]], cls: str = "") -> str:
    e = html.escape
    out = [f'<table class="{cls}"><tr>' + "".join(f"<th>{e(h)}</th>" for h in head) + "</tr>"]
    out += ["<tr>" + "".join(f"<td>{e(c)}</td>" for c in r) + "</tr>" for r in rows]
    return "".join(out) + "</table>"


def _page(title: str, body: list[str]) -> str:
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>" + html.escape(title) +
            f"</title><style>{_STYLE}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")


def card_html(card: dict) -> str:
    """The card as one self-contained HTML page."""
    e = html.escape
    body = [f"<h1>Score card: {e(card['planner']['label'])} on {e(card['suite']['name'])}</h1>",
            f'<blockquote id="summary">{e(card["summary"])}</blockquote>',
            "<dl>" + "".join(f"<dt>{e(k)}</dt><dd>{e(v)}</dd>" for k, v in _header_facts(card)) + "</dl>"]
    if "reproduction" in card:
        rp = card["reproduction"]
        body.append(f"<p>Reproduction of the shipped reference: "
                    f"{'bit for bit on all ' + str(rp['tasks']) + ' tasks' if rp['identical'] else e(str(rp['n_differences'])) + ' difference(s)'}</p>")
    body += ["<h2>Success per difficulty level</h2>",
             f'<figure id="curve">{curve_svg([card])}<figcaption>Success per difficulty level of '
             f'{e(card["planner"]["label"])} (band: 95% Wilson interval) beside the reference planners (dashed) on '
             f'{e(card["suite"]["name"])}.</figcaption></figure>',
             _html_table(LEVEL_HEAD, _level_rows(card), "levels"),
             "<h2>Figures</h2>", _html_table(["figure", "value"], [list(r) for r in _figures_rows(card)], "figures"),
             "<h2>Paired comparison with the reference planners (identical tasks)</h2>",
             _html_table(PAIRED_HEAD, _paired_rows(card), "paired") if _paired_rows(card)
             else "<p>No reference results.</p>",
             "<h2>Reference planners</h2>",
             _html_table(REFERENCE_HEAD, _reference_rows(card), "references") if card.get("references")
             else "<p>None shipped.</p>",
             f"<p>Schema {e(card['schema'])}; every number is in card.json.</p>"]
    return _page(f"pbdyn score card: {card['planner']['label']}", body)


COMPARE_HEAD = ["planner", "suite (hash)", "success [95% CI]", "ability (logits) [95% CI]", "worst-20% levels",
                "time to goal (s)", "path ratio", "min clearance (m)", "planner ms/step (median, p99)", "date"]


def compare_rows(cards: list[dict]) -> list[list[str]]:
    """One table row per card."""
    rows = []
    for c in cards:
        a, pt = c["ability"], c["planning_time_ms"]
        rows.append([c["planner"]["label"], f"{c['suite']['name']} ({c['suite']['hash'][:12]})",
                     f"{_f(c['success']['rate'])} {_ci(c['success']['ci95'])}",
                     f"{_f(a['logit'], '+.2f')} {_ci(a['ci95'], '+.2f')}" if a else NA,
                     _f(c["cvar20_success"]["rate"]), _f(c["time_to_goal_s"]["median"]),
                     _f(c["path_ratio"]["median"], ".3f"), _f(c["min_clearance_m"]["median"]),
                     f"{_f(pt['median'], '.3f')}, {_f(pt['p99'], '.3f')}", c["provenance"]["date"]])
    return rows


def compare_text(cards: list[dict]) -> str:
    """The comparison as a plain-text table (columns padded)."""
    from pbdyn.errors import one_line_text

    rows = [COMPARE_HEAD] + [[one_line_text(c) for c in r] for r in compare_rows(cards)]
    widths = [max(len(r[i]) for r in rows) for i in range(len(COMPARE_HEAD))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows) + "\n"


def compare_html(cards: list[dict]) -> str:
    """The comparison as one self-contained HTML page: the table and every card's curve."""
    e = html.escape
    body = ["<h1>pbdyn score cards compared</h1>", _html_table(COMPARE_HEAD, compare_rows(cards), "compare"),
            f'<figure id="curves">{curve_svg(cards, references=False)}<figcaption>Success per difficulty level of '
            f'each card\'s planner (band: 95% Wilson interval) on {e(cards[0]["suite"]["name"])}.</figcaption>'
            "</figure>"]
    return _page("pbdyn score cards compared", body)


def compare_markdown(cards: list[dict]) -> str:
    """The comparison as Markdown."""
    return "# pbdyn score cards compared\n\n" + _md_table(COMPARE_HEAD, compare_rows(cards)) + "\n"
