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

from pbdyn.analysis.html_kit import interval, num, page, table
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

def _caption(stem: str) -> str:
    for key, text in FIGURE_CAPTIONS.items():
        if stem == key or (key.endswith("_") and stem.startswith(key)):
            return text
    return ""


def _group_sections(section: dict) -> list[str]:
    """Success per setup and per level (report["success_by_group"]) with Wilson 95% intervals; [] without rows."""
    parts = []
    for key, title in (("setup", "setup"), ("level", "level")):
        rows = [[pair, group, str(c.get("n_maps")), str(c.get("trials")), num(c.get("rate")), interval(c.get("ci95"))]
                for pair, cells in (section.get(key) or {}).items() for group, c in cells.items()]
        if rows:
            parts.append(f"<h2>Success by {title}</h2><p>Success of each planner pair per {title} with its 95% "
                         "Wilson interval (error trials not rated).</p>")
            parts.append(table(["planner pair", title, "maps", "trials", "success rate", "95% interval"], rows,
                               name_cols=2))
    return parts


def _paired_section(section: dict) -> list[str]:
    """Every two planner pairs on their common tasks (report["paired"]); [] without comparisons."""
    rows = [[r["a"], r["b"], str(r.get("tasks")), str(r.get("both")), str(r.get("a_only")), str(r.get("b_only")),
             str(r.get("neither")), num(r.get("success_a")), num(r.get("success_b")), num(r.get("difference"), "+.3f"),
             interval(r.get("difference_ci95")), num(r.get("mcnemar_p"), ".4f")]
            for r in section.get("comparisons") or []]
    if not rows:
        return []
    return ["<h2>Paired comparisons</h2><p>Planner pairs A and B compared on the tasks both flew (task = map, "
            "start&rarr;goal, MAV speed): tasks both succeeded on, only A, only B, neither; the difference of success "
            "A &minus; B with its 95% interval from a paired bootstrap resampling maps, and the exact McNemar "
            "p-value of the discordant tasks.</p>",
            table(["A", "B", "tasks", "both", "only A", "only B", "neither", "success A", "success B",
                   "A \u2212 B", "95% interval", "McNemar p"], rows, name_cols=2)]


def render_html(report: dict, table_text: str, figures: list[Path], *, stores: list[str], scenario: dict | None,
                version: str) -> str:
    """The report page as a string (see the module docstring)."""
    from pbdyn.analysis.plots import metric_label

    e = html.escape
    dataset = str(report.get("controlled_dataset", ""))
    parts = [f"<h1>pbdyn evaluation of {e(dataset)}</h1>"]
    parts.append(table(["run", ""], [["pbdyn version", version], ["results", ", ".join(stores)],
                                     ["datasets", ", ".join(report.get("datasets", {}))],
                                     ["trials", str(report.get("n_trials"))],
                                     ["error trials", str(report.get("n_error_trials"))],
                                     ["bootstrap draws", str(report.get("n_boot"))]], name_cols=1))

    parts.append("<h2>Success per planner pair</h2>")
    rows = []
    for pair, per in report.get("success", {}).get("per_pair", {}).items():
        for ds, c in per.items():
            rows.append([pair, ds, str(c.get("n_maps")), str(c.get("n_trials")), num(c.get("rate")),
                         num(c.get("se"))])
    parts.append(table(["planner pair", "dataset", "maps", "trials", "success rate", "standard error"], rows,
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
        label = metric_label(name) + (" (baseline)" if baseline and "baseline" not in metric_label(name) else "")
        if (m.get("beats_baselines_holm") or {}).get("beats"):
            label += " \u2020"
        rows.append([label, num(m.get("srcc_mean")), interval(m.get("srcc_ci95")), num(m.get("within_setup_srcc")),
                     num(fitted.get("srcc")), num(m.get("cv_mean")), num(m.get("compute_time_s"), ".4f")])
        classes.append(" ".join(c for c, on in (("baseline", baseline), ("beats", beats)) if on))
    parts.append(table(["metric", "rank correlation with success", "95% interval", "within setups",
                        "with fitted difficulty", "coefficient of variation", "compute time per map (s)"], rows,
                       row_classes=classes, name_cols=1))

    fd = report.get("fitted_difficulty") or {}
    if fd.get("respondents"):
        parts.append("<h2>Planner abilities (fitted difficulty)</h2>")
        parts.append(f"<p>{e(str(fd.get('model', '')))}; abilities in logits, comparable across maps of "
                     "different difficulty.</p>")
        rows = [[k, num(v.get("ability")), num(v.get("se")), str(v.get("trials"))]
                for k, v in fd["respondents"].items()]
        parts.append(table(["planner pair at MAV speed", "ability", "standard error", "trials"], rows, name_cols=1))

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
    return page(f"pbdyn evaluation: {dataset}", parts)


def write_html(out: str | Path, page: str) -> Path:
    """Write ``page`` to ``out`` atomically (pbdyn.files.atomic_write), creating its folder as --plots does."""
    return atomic_write_text(out, page, make_parents=True)
