"""One self-contained HTML page of an evaluation (`pbdyn evaluate --html FILE.html`): the run (stores, scenario,
pbdyn version), success per planner pair (then, when the report has them, per setup and benchmark level, and the
paired comparisons of planner pairs on common tasks), every metric's rank correlation with success beside the
baselines and against the fitted difficulty, the planners' fitted abilities, the figures inlined as PNG data, the
full text table, and the resolved scenario. No external files, scripts or fonts: the page opens from disk in any
browser.
"""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path

from pbdyn.files import atomic_write_text

FIGURE_CAPTIONS = {
    "metric_": "Success rate of every map against its difficulty by one metric, per planner pair (dots: maps; "
               "lines: mean and one standard deviation per difficulty level). Thesis figures 4-5 to 4-12.",
    "survivability_trajectory": "Success and deadlock rates of each trajectory planner against difficulty by "
                                "survivability. Thesis figure 5-9.",
    "survivability_gaze": "Success rate of each gaze planner, per trajectory planner, against difficulty by "
                          "survivability. Thesis figure 5-10.",
    "uncontrolled_": "Maps of an uncontrolled dataset against the controlled dataset's mean and spread. Thesis "
                     "figures 4-14 to 4-16.",
    "velocity_ratio": "Success against the ratio of obstacle speed to MAV speed limit. Thesis figure 5-14.",
}

_STYLE = """
body { font-family: sans-serif; margin: 2em auto; max-width: 1100px; color: #222; line-height: 1.4; }
h1 { font-size: 1.6em; } h2 { font-size: 1.25em; margin-top: 1.8em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.9em; }
th, td { border: 1px solid #bbb; padding: 3px 8px; text-align: right; } th { background: #eef; }
td.name, th.name { text-align: left; } tr.baseline td { color: #555; font-style: italic; }
figure { margin: 1.2em 0; } figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 0.9em; color: #444; } pre { background: #f6f6f6; padding: 0.6em; overflow-x: auto;
font-size: 0.8em; } .beats { font-weight: bold; color: #0a6; } td { white-space: nowrap; }
"""


def _num(x, fmt: str = "{:.3f}") -> str:
    return "-" if x is None or (isinstance(x, float) and x != x) else fmt.format(x)


def _ci(ci) -> str:
    if not ci or ci[0] is None:
        return "-"
    return f"[{_num(ci[0])}, {_num(ci[1])}]"


def _table(headers: list[str], rows: list[list[str]], classes: list[str] | None = None, name_cols: int = 1) -> str:
    head = "".join(f'<th class="name">{html.escape(h)}</th>' if i < name_cols else f"<th>{html.escape(h)}</th>"
                   for i, h in enumerate(headers))
    body = []
    for k, row in enumerate(rows):
        cls = f' class="{classes[k]}"' if classes and classes[k] else ""
        cells = "".join(f'<td class="name">{c}</td>' if i < name_cols else f"<td>{c}</td>" for i, c in enumerate(row))
        body.append(f"<tr{cls}>{cells}</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def _caption(stem: str) -> str:
    for key, text in FIGURE_CAPTIONS.items():
        if stem == key or (key.endswith("_") and stem.startswith(key)):
            return text
    return ""


def _group_sections(section: dict) -> list[str]:
    """Success per setup and per level (report["success_by_group"]) with Wilson 95% intervals; [] without rows."""
    e = html.escape
    parts = []
    for key, title in (("setup", "setup"), ("level", "level")):
        rows = [[e(pair), e(group), str(c.get("n_maps")), str(c.get("trials")), _num(c.get("rate")),
                 _ci(c.get("ci95"))] for pair, cells in (section.get(key) or {}).items() for group, c in cells.items()]
        if rows:
            parts.append(f"<h2>Success by {title}</h2><p>Success of each planner pair per {title} with its 95% "
                         "Wilson interval (error trials not rated).</p>")
            parts.append(_table(["planner pair", title, "maps", "trials", "success rate", "95% interval"], rows,
                                name_cols=2))
    return parts


def _paired_section(section: dict) -> list[str]:
    """Every two planner pairs on their common tasks (report["paired"]); [] without comparisons."""
    e = html.escape
    rows = [[e(r["a"]), e(r["b"]), str(r.get("tasks")), str(r.get("both")), str(r.get("a_only")),
             str(r.get("b_only")), str(r.get("neither")), _num(r.get("success_a")), _num(r.get("success_b")),
             _num(r.get("difference"), "{:+.3f}"), _ci(r.get("difference_ci95")), _num(r.get("mcnemar_p"), "{:.4f}")]
            for r in section.get("comparisons") or []]
    if not rows:
        return []
    return ["<h2>Paired comparisons</h2><p>Planner pairs A and B compared on the tasks both flew (task = map, "
            "start&rarr;goal, MAV speed): tasks both succeeded on, only A, only B, neither; the difference of success "
            "A &minus; B with its 95% interval from a paired bootstrap resampling maps, and the exact McNemar "
            "p-value of the discordant tasks.</p>",
            _table(["A", "B", "tasks", "both", "only A", "only B", "neither", "success A", "success B",
                    "A \u2212 B", "95% interval", "McNemar p"], rows, name_cols=2)]


def render_html(report: dict, table_text: str, figures: list[Path], *, stores: list[str], scenario: dict | None,
                version: str) -> str:
    """The report page as a string (see the module docstring)."""
    from pbdyn.analysis.plots import metric_label

    e = html.escape
    parts = [f"<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>pbdyn evaluation: "
             f"{e(str(report.get('controlled_dataset', '')))}</title><style>{_STYLE}</style></head><body>"]
    parts.append(f"<h1>pbdyn evaluation of {e(str(report.get('controlled_dataset', '')))}</h1>")
    parts.append(_table(["run", ""], [["pbdyn version", e(version)], ["results", e(", ".join(stores))],
                                   ["datasets", e(", ".join(report.get("datasets", {})))],
                                   ["trials", str(report.get("n_trials"))],
                                   ["error trials", str(report.get("n_error_trials"))],
                                   ["bootstrap draws", str(report.get("n_boot"))]], name_cols=1))

    parts.append("<h2>Success per planner pair</h2>")
    rows = []
    for pair, per in report.get("success", {}).get("per_pair", {}).items():
        for ds, c in per.items():
            rows.append([e(pair), e(ds), str(c.get("n_maps")), str(c.get("n_trials")), _num(c.get("rate")),
                         _num(c.get("se"))])
    parts.append(_table(["planner pair", "dataset", "maps", "trials", "success rate", "standard error"], rows,
                        name_cols=2))
    parts += _group_sections(report.get("success_by_group") or {})
    parts += _paired_section(report.get("paired") or {})

    parts.append("<h2>Does a metric rank maps like success does?</h2>")
    parts.append(f"<p>{e(str(report.get('sign_convention', '')))}. Baselines need no simulation; a metric is "
                 "useful only where it beats them (bold: its 95% interval of the paired difference to every "
                 "baseline lies above 0; &dagger;: it still does after Holm's correction for the number of "
                 "metrics tested).</p>")
    rows, classes = [], []
    for name, m in report.get("metrics", {}).items():
        fitted = m.get("fitted") or {}
        baseline = m.get("kind") == "baseline"
        beats = m.get("beats_baselines")
        label = e(metric_label(name)) + (" (baseline)" if baseline and "baseline" not in metric_label(name) else "")
        if (m.get("beats_baselines_holm") or {}).get("beats"):
            label += " &dagger;"
        rows.append([f'<span class="beats">{label}</span>' if beats else label, _num(m.get("srcc_mean")),
                     _ci(m.get("srcc_ci95")), _num(m.get("within_setup_srcc")), _num(fitted.get("srcc")),
                     _num(m.get("cv_mean")), _num(m.get("compute_time_s"), "{:.4f}")])
        classes.append("baseline" if baseline else "")
    parts.append(_table(["metric", "rank correlation with success", "95% interval", "within setups",
                         "with fitted difficulty", "coefficient of variation", "compute time per map (s)"], rows,
                        classes))

    fd = report.get("fitted_difficulty") or {}
    if fd.get("respondents"):
        parts.append("<h2>Planner abilities (fitted difficulty)</h2>")
        parts.append(f"<p>{e(str(fd.get('model', '')))}; abilities in logits, comparable across maps of "
                     "different difficulty.</p>")
        rows = [[e(k), _num(v.get("ability")), _num(v.get("se")), str(v.get("trials"))]
                for k, v in fd["respondents"].items()]
        parts.append(_table(["planner pair at MAV speed", "ability", "standard error", "trials"], rows))

    if figures:
        parts.append("<h2>Figures</h2>")
        for path in figures:
            data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
            stem = Path(path).stem
            parts.append(f'<figure><img alt="{e(stem)}" src="data:image/png;base64,{data}"><figcaption>'
                         f"<b>{e(stem)}</b>. {e(_caption(stem))}</figcaption></figure>")

    parts.append("<h2>The full evaluation table</h2>")
    parts.append(f"<pre>{e(table_text)}</pre>")
    if scenario is not None:
        parts.append("<h2>Scenario</h2><details><summary>the resolved scenario of the results</summary>"
                     f"<pre>{e(json.dumps(scenario, indent=1, sort_keys=True))}</pre></details>")
    parts.append("</body></html>\n")
    return "".join(parts)


def write_html(out: str | Path, page: str) -> Path:
    """Write ``page`` to ``out`` atomically (pbdyn.files.atomic_write), creating its folder as --plots does."""
    return atomic_write_text(out, page, make_parents=True)
