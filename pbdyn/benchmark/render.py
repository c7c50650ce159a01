"""Score cards as Markdown and as one self-contained HTML page, and side-by-side comparisons of cards.

The figure -- success per difficulty level, the planner's curve beside the reference planners' curves, each with its
Wilson 95% band -- is drawn with matplotlib and inlined as SVG (no external file, script or font; the only links a
card page may hold are its failure replays, files of the bench folder). Both forms show the same sections: the
header facts, success per level (and the figure), time to goal and clearance per level, success per MAV speed and
per level and speed, the planners' table (FOV marked with DAGGER for a 360-degree planner), the paired comparisons
(the card's clustered test and Holm p-values), success per map, the MAV, sensor, world and task parameters, failure
replays when the card has them, and the card's "how to read" block. Every number sits under a column heading or a
fact's name that block defines (tests/test_card_v2.py checks it); a table column of per-planner counts is headed
"<defined term>: <planner label>".
"""

from __future__ import annotations

import html
import io
import math
import re

from pbdyn.analysis.html_kit import NA, interval, num, page, table
from pbdyn.benchmark.card import OUTCOMES, rank_text

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


def _nan(x) -> float:
    return math.nan if x is None else float(x)


def _series(levels: list[dict]) -> tuple[list, list, list, list]:
    """(levels, success, band low, band high) of a card's or a reference's per-level entries (nan where none)."""
    return ([lv["level"] for lv in levels], [_nan(lv["rate"]) for lv in levels],
            [_nan(lv["ci95"][0]) for lv in levels], [_nan(lv["ci95"][1]) for lv in levels])


def _others(card: dict) -> list[dict]:
    """The card's references other than its own planner's shipped one."""
    return [r for r in card.get("references", []) if r["label"] != card["planner"]["label"]]


def curve_svg(cards: list[dict], *, references: bool = True) -> str:
    """An SVG figure (text) of success per level: each card's planner (solid, with its Wilson 95% band), and the
    first card's reference planners (dashed, each with its band) when ``references``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with matplotlib.rc_context({"svg.hashsalt": "pbdyn", "svg.fonttype": "none"}):
        fig, ax = plt.subplots(figsize=(7.0, 4.2))
        try:
            for card in cards:
                levels, rate, lo, hi = _series(card["levels"])
                line, = ax.plot(levels, rate, marker="o", lw=2.2, label=_plain(card["planner"]["label"]), zorder=3)
                ax.fill_between(levels, lo, hi, color=line.get_color(), alpha=0.18, lw=0, zorder=1)
            if references and cards:
                for r in _others(cards[0]):
                    levels, rate, lo, hi = _series(r["levels"])
                    line, = ax.plot(levels, rate, ls="--", lw=1.2, marker=".",
                                    label=_plain(f"{_mark(r)} (reference)"), zorder=2)
                    ax.fill_between(levels, lo, hi, color=line.get_color(), alpha=0.07, lw=0, zorder=1)
            ax.set_xlabel("difficulty level (1 = easiest; anchored scale)")
            ax.set_ylabel("success rate (band: Wilson 95% interval)")
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


FAILURES = OUTCOMES[1:]
"""The failure outcomes, in the card's order."""
DAGGER = "\u2020"
"""Marks a planner that sees 360 degrees (sensor FOV; the card's "how to read" block defines it)."""


def _is_360(entry: dict) -> bool:
    fov = entry.get("fov_deg")
    return isinstance(fov, (int, float)) and fov >= 360.0


def _mark(entry: dict) -> str:
    """A planner's label, with DAGGER when it sees 360 degrees."""
    return entry["label"] + (f" {DAGGER}" if _is_360(entry) else "")


def _median_iqr(x: dict | None, fmt: str = ".2f") -> str:
    if not x or x.get("median") is None:
        return NA
    return f"{num(x['median'], fmt)} {interval(x['iqr'], fmt)}"


def _rate_ci(x: dict) -> str:
    return f"{num(x['rate'], '.2f')} {interval(x['ci95'], '.2f')}"


LEVEL_HEAD = ["level", "reference success range", "success [95% CI]", "tasks",
              *(o.replace("_", " ") for o in FAILURES)]
LEVEL_FIGURES_HEAD = ["level", "successful tasks", "time to goal (s), median [IQR]",
                      "min clearance (m), median [IQR]"]
SPEED_HEAD = ["planner", "MAV speed (m/s)", "success [95% CI]", "tasks"]
LEVEL_SPEED_HEAD = ["level", "MAV speed (m/s)", "success [95% CI]", "tasks"]
PLANNERS_HEAD = ["planner", "sensor FOV (deg)", "success [95% CI]", "ability (logits) [95% CI]", "worst-20% levels",
                 "time to goal (s), median [IQR]", "path ratio, median [IQR]", "min clearance (m), median [IQR]",
                 "time per step (ms), median / p99"]
PAIRED_HEAD = ["reference", "tasks in common", "maps", "both", "only this", "only the reference", "neither",
               "difference [95% CI]", "t (df)", "p (clustered)", "p (Holm)"]
MAP_HEAD = ["part", "map id", "level", "family", "map difficulty (logits)"]
MAP_COUNTS = "successes/trials"
"""The per-map table's planner columns are headed "successes/trials: <planner label>"."""


def _level_rows(card: dict) -> list[list[str]]:
    rows = []
    ranges = {lv["level"]: lv["success_range"] for lv in card["suite"]["levels"]}
    for lv in card["levels"]:
        rng = ranges.get(lv["level"])
        rows.append([str(lv["level"]), interval(rng, ".2f") if rng else NA, _rate_ci(lv), str(lv["trials"]),
                     *(str(lv["outcomes"][o]) for o in FAILURES)])
    return rows


def _level_figure_rows(card: dict) -> list[list[str]]:
    return [[str(lv["level"]), str((lv.get("time_to_goal_s") or {}).get("n", 0)),
             _median_iqr(lv.get("time_to_goal_s")), _median_iqr(lv.get("min_clearance_m"))] for lv in card["levels"]]


def _speed_rows(card: dict) -> list[list[str]]:
    rows = []
    for who, label in [(card, card["planner"]["label"] + " (this card)")] + [(r, r["label"]) for r in _others(card)]:
        for x in who.get("by_speed", []):
            rows.append([label, num(x["mav_speed_mps"], "g"), _rate_ci(x), str(x["trials"])])
    return rows


def _level_speed_rows(card: dict) -> list[list[str]]:
    return [[str(x["level"]), num(x["mav_speed_mps"], "g"), _rate_ci(x), str(x["trials"])]
            for x in card.get("by_level_speed", [])]


def _planner_row(entry: dict, label: str) -> list[str]:
    a, pt = entry["ability"], entry["planning_time_ms"]
    return [label, num(entry.get("fov_deg"), "g"), _rate_ci(entry["success"]),
            f"{num(a['logit'], '+.2f')} {interval(a['ci95'], '+.2f')}" if a else NA,
            num(entry["cvar20_success"]["rate"], ".2f"),
            _median_iqr(entry["time_to_goal_s"]), _median_iqr(entry["path_ratio"], ".3f"),
            _median_iqr(entry["min_clearance_m"]), f"{num(pt['median'], '.3f')} / {num(pt['p99'], '.3f')}"]


def _planners_rows(card: dict) -> list[list[str]]:
    me = {**card, "label": card["planner"]["label"], "fov_deg": card["planner"].get("fov_deg")}
    return [_planner_row(me, _mark(me) + " (this card)")] + [_planner_row(r, _mark(r)) for r in _others(card)]


def _p(rec) -> str:
    return rec.get("text", NA) if isinstance(rec, dict) else NA


def _paired_rows(card: dict) -> list[list[str]]:
    rows = []
    for r in _others(card):
        pc = r["paired"]
        test = pc.get("test") or {}
        t = test.get("t")
        t_text = ("inf" if test.get("t_infinite") else num(t, ".2f")) + f" ({test.get('df', NA)})"
        rows.append([_mark(r), str(pc["tasks"]), str(pc.get("maps", NA)), str(pc["both"]), str(pc["a_only"]),
                     str(pc["b_only"]), str(pc["neither"]),
                     f"{num(pc['difference'], '+.3f')} {interval(pc['difference_ci95'], '+.3f')}", t_text,
                     _p(test.get("p")), _p(pc.get("p_holm"))])
    return rows


def _map_head(card: dict) -> list[str]:
    return MAP_HEAD + [f"{MAP_COUNTS}: {_mark({**card['planner']})}"] + [f"{MAP_COUNTS}: {_mark(r)}"
                                                                          for r in _others(card)]


def _map_rows(card: dict) -> list[list[str]]:
    rows = []
    for m in card.get("maps", []):
        cells = [m["part"], m["map_id"], str(m["level"]), str(m.get("family") or NA), num(m.get("difficulty"), "+.2f"),
                 f"{m['planner']['successes']}/{m['planner']['trials']}"]
        for r in _others(card):
            c = m["references"].get(r["label"])
            cells.append(f"{c['successes']}/{c['trials']}" if c else NA)
        rows.append(cells)
    return rows


def _params_text(params) -> str:
    import json

    return json.dumps(params, sort_keys=True, ensure_ascii=False)


def _code_text(code: dict) -> str:
    git = code.get("git")
    where = ("git commit " + git["commit"][:12] + (" with uncommitted changes" if git.get("dirty") else "")
             if git else "not run from a git checkout")
    return f"core {code['core']}; {where}; {code['statement']}"


def _cost_text(cost: dict) -> str:
    def amount(key, unit):
        v = cost.get(key)
        return f"{num(v, '.1f')} {unit}" if isinstance(v, (int, float)) and not isinstance(v, bool) else NA

    runs = cost.get("runs")
    return f"wall {amount('wall_s', 's')}, CPU {amount('cpu_s', 's')}, {runs if runs is not None else NA} run(s)"


def _header_facts(card: dict) -> list[tuple[str, str]]:
    s, a, pv, pl = card["success"], card["ability"], card["provenance"], card["planner"]
    m = pv["machine"]
    facts = [("planner", f"{_mark(pl)} (fingerprint {pl['fingerprint']}; sensor FOV {num(pl.get('fov_deg'), 'g')} "
                         "deg)")]
    if pl.get("trajectory_params"):
        facts.append(("trajectory parameters", _params_text(pl["trajectory_params"])))
    if pl.get("gaze_params"):
        facts.append(("gaze parameters", _params_text(pl["gaze_params"])))
    if pl.get("parameter_files"):
        facts.append(("parameter files", "; ".join(f"{k}: sha256 {v[:12]}" for k, v in
                                                   sorted(pl["parameter_files"].items()))))
    facts += [
        ("suite", f"{card['suite']['name']} v{card['suite']['version']}, hash {card['suite']['hash']} "
                  f"({card['suite']['maps']} maps, {card['suite']['tasks']} tasks, MAV speeds "
                  f"{'/'.join(num(v, 'g') for v in card['suite']['speeds_mps'])} m/s)"),
        ("levels from", card["suite"].get("levels_from", {}).get("text", NA)),
        ("success", f"{_rate_ci(s)} ({s['successes']} of {s['trials']} tasks; flown "
                    f"{card['trials']['flown']} of {card['trials']['expected']}, errors {card['trials']['errors']})"),
        ("ability", (f"{num(a['logit'], '+.2f')} logits {interval(a['ci95'], '+.2f')} on the {pv['scale']} scale")
         if a else NA),
        ("rank", rank_text(card["rank"]) + (" by ability, 95% interval over map resamples"
                                             if card["rank"].get("rank") is not None else "")),
        ("made with", f"pbdyn {pv['pbdyn']} on {m.get('cpu') or m.get('machine')} ({m.get('cpus')} CPUs, "
                      f"{m.get('system')}, Python {m.get('python')}), {pv['date']}"),
    ]
    if pv.get("code"):
        facts.append(("code identity", _code_text(pv["code"])))
    if isinstance(card.get("cost"), dict):
        facts.append(("cost", _cost_text(card["cost"])))
    if "reproduction" in card:
        rp = card["reproduction"]
        facts.append(("reproduction", f"of the shipped reference {rp['reference']}: "
                      + (f"bit for bit on all {rp['tasks']} tasks" if rp["identical"]
                         else f"{rp['n_differences']} difference(s)")))
    if card["suite"].get("note"):
        facts.append(("note", card["suite"]["note"]))
    facts.append(("schema", f"{card['schema']} (card.json holds every number shown here)"))
    return facts


def _dagger_facts(card: dict) -> list[tuple[str, str]]:
    """The footnote of the 360-degree mark, when a planner on the card has it."""
    if not any(_is_360(e) for e in [card["planner"], *_others(card)]):
        return []
    return [(DAGGER, "sees 360 degrees: the FullRange gaze planner gives its MAV a 360-degree sensor (and no yaw "
                     "control), while the others see the suite's sensor field of view; compare with care")]


def _test_facts(card: dict) -> list[tuple[str, str]]:
    cmp = card.get("comparisons") or {}
    return [("test", f"{cmp.get('test', NA)}; {cmp.get('holm_family', NA)} comparison(s) in the Holm family; "
                     "p-values below 1e-6 are shown as < 1e-6")]


def _param_facts(card: dict) -> list[tuple[str, str]]:
    fp = card.get("flight_parameters")
    if not fp:
        return []

    def mav(x):
        v = x["mav"]
        return (f"radius {num(v['radius_m'], 'g')} m, a_max {num(v['a_max_mps2'], 'g')} m/s^2, v_max "
                f"{'/'.join(num(s, 'g') for s in v['v_max_mps'])} m/s, yaw rate limit "
                f"{num(v['yaw_rate_limit_radps'], 'g')} rad/s")

    def sensor(x):
        v = x["sensor"]
        vf = f", vertical FOV {num(v['vfov_deg'], 'g')} deg" if v.get("vfov_deg") is not None else ""
        return (f"FOV {num(v['fov_deg'], 'g')} deg{vf}, range {num(v['range_m'], 'g')} m, resolution "
                f"{num(v['resolution_deg'], 'g')} deg, noise {num(v['noise_std_m'], 'g')} m, model {v['model']}")

    def world(x):
        v = x["world"]
        fh = f", flight height {num(v['flight_height_m'], 'g')} m" if v.get("flight_height_m") is not None else ""
        return (f"{v['dims']}D, arena {' x '.join(num(s, 'g') for s in v['arena_m'])} m, dt {num(v['dt_s'], 'g')} s, "
                f"time limit {num(v['time_limit_s'], 'g')} s, grid {num(v['grid_resolution_m'], 'g')} m{fh}, profile "
                f"{v['profile']}, collision check {v['collision_check']}")

    def task(x):
        v = x["task"]
        return (f"goal radius {num(v['goal_radius_m'], 'g')} m, {v['pairs_per_map']} start/goal pairs per map, "
                f"deadlock after {v['deadlock_steps']} planning failures at rest, start rule {v['start_rule']}")

    out = []
    for term, text in (("MAV", mav), ("sensor", sensor), ("world", world), ("task", task)):
        values = [(x["part"], text(x)) for x in fp["parts"]]
        if len({v for _, v in values}) <= 1:
            out.append((term, values[0][1] if values else NA))
        else:
            out.append((term, "; ".join(f"part {p}: {v}" for p, v in values)))
    return out


def replay_path(path: object) -> str | None:
    """``path`` if it is a plain relative path inside the bench folder (no scheme, not absolute, no "..", no
    backslash or control character), else None: only such a path is linked."""
    from urllib.parse import urlsplit

    if not isinstance(path, str) or not path or path.startswith(("/", "~")) or "\\" in path:
        return None
    if any(ord(c) < 32 or ord(c) == 127 for c in path) or urlsplit(path).scheme or ":" in path.split("/")[0]:
        return None
    if any(part in ("..", "") for part in path.split("/")):
        return None
    return path


def _replay_facts(card: dict) -> list[tuple[str, str, str | None]]:
    """(term, text, link target or None) of the failure replays, when the card has them."""
    fr = card.get("failure_replays")
    if not isinstance(fr, dict):
        return []
    files = [f for f in fr.get("files") or [] if isinstance(f, dict)]
    out = [("failure replays", f"{fr.get('requested', NA)} requested, {len(files)} written", None)]
    for f in files:
        def xy(v):
            return "(" + ", ".join(num(c, "g") for c in v) + ")" if isinstance(v, list) else NA

        text = (f"{f.get('outcome', NA)}, part {f.get('part', NA)}, map {f.get('map_id', NA)}, start "
                f"{xy(f.get('start'))} -> goal {xy(f.get('goal'))} m, {num(f.get('mav_speed'), 'g')} m/s: "
                f"{f.get('file', NA)}")
        if isinstance(f.get("reflown"), dict) and f["reflown"]:
            text = text[:-len(str(f.get("file", NA)))] + (f"(re-flight differs in {', '.join(sorted(f['reflown']))}) "
                                                          f"{f.get('file', NA)}")
        out.append(("failure replay", text, replay_path(f.get("file"))))
    return out


def _definitions(card: dict) -> list[tuple[str, str]]:
    return [(d["term"], f"{d['definition']} ({d['doc']})") for d in card.get("how_to_read", [])]


def _md_table(head: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(md_escape(h) for h in head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(md_escape(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def _md_facts(facts) -> list[str]:
    return [f"- **{md_escape(k)}**: {md_escape(v)}" for k, v in facts]


def _md_link(text: str, target: str) -> str:
    from urllib.parse import quote

    return f"[{md_escape(text)}]({quote(target, safe='/._-')})"


def card_markdown(card: dict) -> str:
    """The card as Markdown."""
    e = md_escape
    parts = [f"# Score card: {e(card['planner']['label'])} on {e(card['suite']['name'])}", "",
             f"> {e(card['summary'])}", ""]
    parts += _md_facts(_header_facts(card))
    parts += ["", "## Success per difficulty level", "", _md_table(LEVEL_HEAD, _level_rows(card)), "",
              "## Time to goal and clearance per level (this planner)", "",
              _md_table(LEVEL_FIGURES_HEAD, _level_figure_rows(card)), "",
              "## Success per MAV speed", "", _md_table(SPEED_HEAD, _speed_rows(card)), "",
              "## Success per level and MAV speed (this planner)", "",
              _md_table(LEVEL_SPEED_HEAD, _level_speed_rows(card)), "",
              "## This planner and the reference planners", "", _md_table(PLANNERS_HEAD, _planners_rows(card)), ""]
    if _dagger_facts(card):
        parts += _md_facts(_dagger_facts(card)) + [""]
    parts += ["## Paired comparison with the reference planners (identical tasks)", ""]
    parts += (_md_facts(_test_facts(card)) + ["", _md_table(PAIRED_HEAD, _paired_rows(card))] if _paired_rows(card)
              else ["No reference results."])
    parts += ["", "## Success per map", "", _md_table(_map_head(card), _map_rows(card)), "",
              "## MAV, sensor, world and task", ""] + _md_facts(_param_facts(card)) + [""]
    replays = _replay_facts(card)
    if replays:
        parts += ["## Failure replays", ""]
        parts += [f"- **{e(k)}**: " + (e(v) if target is None else
                                       e(v[:-len(target)]) + _md_link(target, target)) for k, v, target in replays]
        parts.append("")
    parts += ["## How to read this card", ""] + _md_facts(_definitions(card)) + [""]
    return "\n".join(parts)


def _html_facts(facts, cls: str = "facts") -> str:
    e = html.escape
    return f'<dl class="{cls}">' + "".join(f"<dt>{e(k)}</dt><dd>{e(v)}</dd>" for k, v in facts) + "</dl>"


def card_html(card: dict) -> str:
    """The card as one self-contained HTML page (failure replays, when the card has them, are linked files of the
    bench folder)."""
    from urllib.parse import quote

    e = html.escape
    body = [f"<h1>Score card: {e(card['planner']['label'])} on {e(card['suite']['name'])}</h1>",
            f'<blockquote id="summary">{e(card["summary"])}</blockquote>', _html_facts(_header_facts(card))]
    body += ["<h2>Success per difficulty level</h2>",
             f'<figure id="curve">{curve_svg([card])}<figcaption>Success per difficulty level of '
             f'{e(card["planner"]["label"])} (solid) beside the reference planners (dashed) on '
             f'{e(card["suite"]["name"])}; each band is the Wilson interval of its curve.</figcaption></figure>',
             table(LEVEL_HEAD, _level_rows(card), "levels"),
             "<h2>Time to goal and clearance per level (this planner)</h2>",
             table(LEVEL_FIGURES_HEAD, _level_figure_rows(card), "level-figures"),
             "<h2>Success per MAV speed</h2>", table(SPEED_HEAD, _speed_rows(card), "speeds"),
             "<h2>Success per level and MAV speed (this planner)</h2>",
             table(LEVEL_SPEED_HEAD, _level_speed_rows(card), "level-speeds"),
             "<h2>This planner and the reference planners</h2>",
             table(PLANNERS_HEAD, _planners_rows(card), "references")]
    if _dagger_facts(card):
        body.append(_html_facts(_dagger_facts(card), "footnotes"))
    body.append("<h2>Paired comparison with the reference planners (identical tasks)</h2>")
    body += ([_html_facts(_test_facts(card)), table(PAIRED_HEAD, _paired_rows(card), "paired")]
             if _paired_rows(card) else ["<p>No reference results.</p>"])
    body += ["<h2>Success per map</h2>", table(_map_head(card), _map_rows(card), "maps"),
             "<h2>MAV, sensor, world and task</h2>", _html_facts(_param_facts(card), "parameters")]
    replays = _replay_facts(card)
    if replays:
        items = []
        for k, v, target in replays:
            dd = e(v) if target is None else e(v[:-len(target)]) + f'<a href="{e(quote(target, safe="/._-"))}">' \
                                                                    f"{e(target)}</a>"
            items.append(f"<dt>{e(k)}</dt><dd>{dd}</dd>")
        body += ["<h2>Failure replays</h2>", '<dl class="replays">' + "".join(items) + "</dl>"]
    body += ['<h2 id="how-to-read">How to read this card</h2>', _html_facts(_definitions(card), "how-to-read")]
    return page(f"pbdyn score card: {card['planner']['label']}", body)


COMPARE_HEAD = ["planner", "suite (hash)", "success [95% CI]", "ability (logits) [95% CI]", "rank [95% CI]",
                "worst-20% levels", "time to goal (s)", "path ratio", "min clearance (m)",
                "planner ms/step (median, p99)", "date"]


def comparison_table(cards: list[dict]) -> list[list[str]]:
    """One table row per card."""
    rows = []
    for c in cards:
        a, pt = c["ability"], c["planning_time_ms"]
        rows.append([c["planner"]["label"], f"{c['suite']['name']} ({c['suite']['hash'][:12]})",
                     f"{num(c['success']['rate'], '.2f')} {interval(c['success']['ci95'], '.2f')}",
                     f"{num(a['logit'], '+.2f')} {interval(a['ci95'], '+.2f')}" if a else NA,
                     rank_text(c["rank"]) if c["rank"].get("rank") is not None else NA,
                     num(c["cvar20_success"]["rate"], ".2f"), num(c["time_to_goal_s"]["median"], ".2f"),
                     num(c["path_ratio"]["median"], ".3f"), num(c["min_clearance_m"]["median"], ".2f"),
                     f"{num(pt['median'], '.3f')}, {num(pt['p99'], '.3f')}", c["provenance"]["date"]])
    return rows


def compare_text(cards: list[dict]) -> str:
    """The comparison as a plain-text table (columns padded)."""
    from pbdyn.errors import one_line_text

    rows = [COMPARE_HEAD] + [[one_line_text(c) for c in r] for r in comparison_table(cards)]
    widths = [max(len(r[i]) for r in rows) for i in range(len(COMPARE_HEAD))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows) + "\n"


def compare_html(cards: list[dict]) -> str:
    """The comparison as one self-contained HTML page: the table and every card's curve."""
    e = html.escape
    body = ["<h1>pbdyn score cards compared</h1>", table(COMPARE_HEAD, comparison_table(cards), "compare"),
            f'<figure id="curves">{curve_svg(cards, references=False)}<figcaption>Success per difficulty level of '
            f'each card\'s planner (band: 95% Wilson interval) on {e(cards[0]["suite"]["name"])}.</figcaption>'
            "</figure>"]
    return page("pbdyn score cards compared", body)


def compare_markdown(cards: list[dict]) -> str:
    """The comparison as Markdown."""
    return "# pbdyn score cards compared\n\n" + _md_table(COMPARE_HEAD, comparison_table(cards)) + "\n"
