"""`pbdyn evaluate`'s score-card tables on a real store: the trial frame's path and planning-time columns, the paired
comparison of planner pairs on common tasks (counted by hand from the store rows, McNemar against scipy) and success
per setup and level, in the JSON, the text table and the HTML page; paired_comparison on synthetic arrays."""

from __future__ import annotations

import contextlib
import io
import json
import math
import sqlite3
import warnings
from collections import Counter

import numpy as np
import pytest
from scipy.stats import binomtest

import pbdyn
from pbdyn.analysis.html_report import render_html
from pbdyn.analysis.paired import mcnemar_exact, paired_comparison, paired_table, success_by_group, wilson_interval
from pbdyn.analysis.report import format_table
from pbdyn.errors import ConfigError
from pbdyn.experiments.evaluate import evaluate_stores, load_results
from pbdyn.experiments.export import DERIVED, trials_frame
from pbdyn.experiments.store import ResultsStore

SCENARIO = """
name = "paired_small"
[world]
dims = 2
size = [50.0, 50.0]
dt = 0.1
time_limit = 30.0
[obstacles]
count = [4, 12]
radius = 1.0
speed = 2.0
radius_jitter = 0.2
maps_per_setup = 1
root_seed = 7
[drone]
v_max = [4.0]
[task]
candidates = [[4.0, 4.0], [46.0, 46.0], [4.0, 46.0], [46.0, 4.0]]
pairs_flown = [[0, 1], [1, 0], [2, 3], [3, 2], [0, 2], [1, 3]]
[[planners]]
trajectory = "local_primitives"
gaze = "lookahead"
[[planners]]
trajectory = "straight_line"
gaze = "lookahead"
[[planners]]
trajectory = "straight_line"
gaze = "fullrange"
"""
"""2 maps (4 and 12 obstacles) x 6 tasks x 3 planner pairs = 36 trials (about 6 s)."""


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    d = tmp_path_factory.mktemp("paired")
    (d / "paired.toml").write_text(SCENARIO)
    out = d / "paired.sqlite"
    s = pbdyn.run_batch(str(d / "paired.toml"), out, workers=1, progress=False)
    assert (s.total, s.ran, s.errors) == (36, 36, 0)
    return out


def _rows(path) -> list[dict]:
    st = ResultsStore.open(path)
    try:
        return st.results()
    finally:
        st.close()


def _cli(argv: list[str]) -> tuple[int, str, str]:
    """pbdyn.cli.main(argv) in this process: (exit status, stdout, stderr)."""
    from pbdyn import cli

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main(argv)
    return code, out.getvalue(), err.getvalue()


def _copy(src, dst):
    dst.write_bytes(src.read_bytes())
    return dst


def _by_hand(rows: list[dict]) -> dict[str, dict[tuple, bool]]:
    """planner label -> {(map, start, goal, speed): success} of the flown rows."""
    out: dict = {}
    for r in rows:
        if r["outcome"] != "error":
            key = (r["map_id"], tuple(r["start"]), tuple(r["goal"]), r["mav_speed"])
            out.setdefault(r["planner_label"], {})[key] = r["outcome"] == "success"
    return out


# ------------------------------------------------------------------------------------------------ the trial frame
def test_the_trial_frame_carries_path_ratio_and_planning_times(store, tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pbdyn.open_results(store) as res:
            df = res.trials()
    rows = {r["trial_key"]: r for r in _rows(store)}
    cols = list(df.columns)
    assert cols[cols.index("error") + 1:cols.index("error") + 1 + len(DERIVED)] == list(DERIVED)
    assert cols.index("path_length_m") < cols.index("error")
    for name in ("path_length_m", *DERIVED):
        assert df[name].dtype == np.float64, name
    for r in df.itertuples():
        row = rows[r.trial_key]
        dist = math.hypot(r.goal_x - r.start_x, r.goal_y - r.start_y) - 1.0     # to the goal ball (radius 1 m)
        assert r.path_length_m == row["path_length_m"] > 0
        assert r.path_ratio == pytest.approx(row["path_length_m"] / dist, rel=1e-12)
        assert r.wall_planning_median_s == row["wall_planning_median_s"] >= 0
        assert r.wall_planning_p99_s == row["wall_planning_p99_s"] >= r.wall_planning_median_s
    # a store written before the fields: NaN, not 0
    old = _copy(store, tmp_path / "old.sqlite")
    key = df.trial_key.iloc[0]
    with sqlite3.connect(old) as c:
        c.execute("UPDATE trials SET path_length_m = NULL, result_json = json_remove(result_json, "
                  "'$.wall_planning_median_s', '$.wall_planning_p99_s') WHERE trial_key = ?", (key,))
    back = trials_frame(old).set_index("trial_key")
    assert back.loc[key, ["path_length_m", *DERIVED]].isna().all()
    assert back.drop(index=key)[["path_length_m", *DERIVED]].notna().all().all()
    # the export goes through the same frame
    assert pbdyn.export_results(store, tmp_path / "t.csv") == 36
    import pandas as pd

    csv = pd.read_csv(tmp_path / "t.csv")
    assert list(csv.columns) == cols
    assert csv["path_ratio"].tolist() == pytest.approx(df["path_ratio"].tolist(), rel=1e-12)


# ------------------------------------------------------------------------------------------------ evaluate
@pytest.fixture(scope="module")
def evaluated(store):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        report, text, _ = evaluate_stores([store], n_boot=200, seed=0)
    return report, text


def test_paired_counts_equal_a_hand_count_and_mcnemar_is_the_binomial_test(store, evaluated):
    report, _ = evaluated
    hand = _by_hand(_rows(store))
    comps = report["paired"]["comparisons"]
    names = sorted(hand)
    assert [(c["a"], c["b"]) for c in comps] == [(a, b) for i, a in enumerate(names) for b in names[i + 1:]]
    assert len(comps) == 3
    for c in comps:
        a, b = hand[c["a"]], hand[c["b"]]
        common = sorted(a.keys() & b.keys())
        counts = Counter((a[k], b[k]) for k in common)
        assert (c["tasks"], c["both"], c["a_only"], c["b_only"], c["neither"]) == \
            (12, counts[True, True], counts[True, False], counts[False, True], counts[False, False])
        assert c["n_maps"] == 2
        assert c["success_a"] == pytest.approx(sum(a[k] for k in common) / 12)
        assert c["difference"] == pytest.approx(c["success_a"] - c["success_b"])
        n = c["a_only"] + c["b_only"]
        assert c["mcnemar_p"] == (binomtest(c["a_only"], n, 0.5).pvalue if n else 1.0)
        lo, hi = c["difference_ci95"]
        assert lo - 1e-12 <= c["difference"] <= hi + 1e-12
    assert any(c["a_only"] + c["b_only"] > 0 for c in comps)          # the store has discordant tasks
    assert report["paired"]["n_boot"] == 200 and report["paired"]["seed"] == 0


def test_an_error_trial_leaves_its_task_out_of_the_comparisons(store, tmp_path):
    bad = _copy(store, tmp_path / "err.sqlite")
    rows = _rows(store)
    victim = next(r for r in rows if r["planner_label"] == "lookahead+local_primitives")
    with sqlite3.connect(bad) as c:
        c.execute("UPDATE trials SET outcome = 'error', result_json = json_set(result_json, '$.outcome', 'error') "
                  "WHERE trial_key = ?", (victim["trial_key"],))
    trials, maps, _ = load_results([bad])
    comps = {(c["a"], c["b"]): c for c in paired_table(trials, n_boot=50, seed=0)["comparisons"]}
    for (a, b), c in comps.items():
        assert c["tasks"] == (11 if "lookahead+local_primitives" in (a, b) else 12)
    groups = success_by_group(trials, maps)["setup"]["lookahead+local_primitives"]
    assert sum(g["trials"] for g in groups.values()) == 11


def test_success_by_setup_and_level(store, evaluated, tmp_path):
    report, _ = evaluated
    section = report["success_by_group"]
    assert section["level"] is None                       # this store was not flown from a benchmark suite
    rows = [r for r in _rows(store) if r["outcome"] != "error"]
    for pair, cells in section["setup"].items():
        assert list(cells) == ["n=4 r=1 v=2", "n=12 r=1 v=2"]
        for label, cell in cells.items():
            sel = [r for r in rows if r["planner_label"] == pair and label.startswith(f"n={r['obstacle_count']} ")]
            k = sum(r["outcome"] == "success" for r in sel)
            assert (cell["trials"], cell["successes"], cell["n_maps"]) == (len(sel), k, 1)
            assert cell["ci95"] == pytest.approx(list(wilson_interval(k, len(sel))))
            ci = binomtest(k, len(sel)).proportion_ci(method="wilson")
            assert cell["ci95"] == pytest.approx([ci.low, ci.high], abs=1e-12)
    # a suite's store records the level with each map (its setup): per level as well
    lev = _copy(store, tmp_path / "levels.sqlite")
    with sqlite3.connect(lev) as c:
        c.execute("UPDATE maps SET setup_json = json_set(setup_json, '$.level', "
                  "CASE WHEN json_extract(setup_json, '$.count') = 4 THEN 1 ELSE 2 END)")
    trials, maps, _ = load_results([lev])
    assert {t["level"] for t in trials} == {1, 2}
    levels = success_by_group(trials, maps)["level"]
    for pair, cells in levels.items():
        assert list(cells) == ["1", "2"]
        assert [c["trials"] for c in cells.values()] == [section["setup"][pair][s]["trials"]
                                                         for s in ("n=4 r=1 v=2", "n=12 r=1 v=2")]
    report2 = {**report, "success_by_group": json.loads(json.dumps(success_by_group(trials, maps)))}
    assert "Success by level per planner pair" in format_table(report2)


def _index(lines: list[str], prefix: str) -> int:
    return next(i for i, x in enumerate(lines) if x.startswith(prefix))


def test_the_text_json_and_html_reports_hold_the_tables(store, evaluated):
    report, text = evaluated
    lines = text.splitlines()
    without = format_table({k: v for k, v in report.items() if k not in ("paired", "success_by_group")}).splitlines()
    rest = iter(lines)                                    # the report without the two sections: the same lines in
    assert all(any(x == y for y in rest) for x in without)    # the same order, the sections' lines put among them
    setup, sign = _index(lines, "Success by setup per planner pair"), _index(lines, "Sign: ")
    paired = _index(lines, "Paired comparisons on the tasks both pairs flew")
    assert _index(lines, "Verdict: ") < setup < sign < _index(lines, "Metric ") < paired   # success first, then stats
    tail = "\n".join(lines[paired:])
    for c in report["paired"]["comparisons"]:
        line = next(x for x in tail.splitlines() if x.split()[:2] == [c["a"], c["b"]])
        assert line.split()[2:7] == [str(c[k]) for k in ("tasks", "both", "a_only", "b_only", "neither")]
        assert line.split()[-1] == f"{c['mcnemar_p']:.4f}"
    code, out, err = _cli(["evaluate", str(store), "--bootstrap", "200"])     # what `pbdyn evaluate` prints
    assert code == 0 and out.rstrip("\n") == text.rstrip("\n") and "warning" not in err.lower()
    doc = json.loads(json.dumps(report, allow_nan=False))                      # `--json`: no NaN leaks
    assert len(doc["paired"]["comparisons"]) == 3 and set(doc["success_by_group"]["setup"]) == set(doc["pairs"])
    with pbdyn.open_results(store) as res:
        scenario = res.scenario
    html = render_html(report, text, [], stores=[str(store)], scenario=scenario, version=pbdyn.__version__)
    assert "<h2>Paired comparisons</h2>" in html and "<h2>Success by setup</h2>" in html
    assert "<h2>Success by level</h2>" not in html
    for c in doc["paired"]["comparisons"]:
        cells = "".join(f"<td>{c[k]}</td>" for k in ("tasks", "both", "a_only", "b_only", "neither"))
        assert f'<td class="name">{c["a"]}</td><td class="name">{c["b"]}</td>{cells}' in html
    for pair, cells in doc["success_by_group"]["setup"].items():
        for label, c in cells.items():
            assert (f'<td class="name">{pair}</td><td class="name">{label}</td><td>1</td><td>{c["trials"]}</td>'
                    f'<td>{c["rate"]:.3f}</td><td>[{c["ci95"][0]:.3f}, {c["ci95"][1]:.3f}]</td>') in html


def test_the_text_opens_with_the_success_table_and_a_verdict(store, evaluated):
    """`pbdyn evaluate` opens with each pair's success (Wilson interval, counted by hand from the store's rows), the
    trial counts and one verdict line: the pair that succeeds most, and how the best metric compares with the
    setup baseline; every statistic comes after them."""
    report, text = evaluated
    lines = text.splitlines()
    assert lines[0].startswith("Controlled dataset: paired_small ") and lines[1] == ""
    assert lines[2].startswith("Success per planner pair and dataset (Wilson 95% interval")
    flown: dict = {}
    for r in _rows(store):
        if r["outcome"] != "error":
            k, n = flown.get(r["planner_label"], (0, 0))
            flown[r["planner_label"]] = (k + (r["outcome"] == "success"), n + 1)
    assert len(flown) == 3
    for line, (pair, (k, n)) in zip(lines[3:6], sorted(flown.items())):
        lo, hi = wilson_interval(k, n)
        assert line.split() == [pair, "paired_small", f"{k / n:.3f}", f"[{lo:.3f},", f"{hi:.3f}]", "+-",
                                f"{math.sqrt(k / n * (1 - k / n) / n):.3f}", line.split()[7], str(n), "trials,",
                                "2", "maps"]
    assert lines[6].startswith("Trials: 36 (0 errors, not rated); outcomes: success ")
    verdict = lines[7]
    best = max(flown, key=lambda p: flown[p][0] / flown[p][1])
    if sorted(k / n for k, n in flown.values())[-2] < flown[best][0] / flown[best][1]:
        assert verdict.startswith(f"Verdict: {best} succeeds most ({flown[best][0] / flown[best][1]:.3f} [")
    assert "the metrics cannot rank maps here" in verdict or "the setup baseline" in verdict
    assert sum(x.startswith("Verdict: ") for x in lines) == 1 and _index(lines, "Sign: ") > 7


def _verdict_report(rates: dict, metrics: dict) -> dict:
    """A minimal report for verdict_line: pair -> (rate, ci95) on dataset "d"; metric rows as given."""
    return {"controlled_dataset": "d", "metrics": metrics,
            "success": {"per_pair": {p: {"d": {"rate": r, "ci95": ci}} for p, (r, ci) in rates.items()}}}


def test_the_verdict_line():
    from pbdyn.analysis.report import SETUP_MODEL, verdict_line

    setup = {SETUP_MODEL: {"kind": "baseline", "srcc_mean": 0.5}}

    def metric(srcc, lo, hi):
        return {"kind": "metric", "srcc_mean": srcc,
                "vs_baselines": {SETUP_MODEL: {"diff": srcc - 0.5, "ci95": [lo, hi]}}}

    two = {"A": (0.9, [0.8, 0.95]), "B": (0.5, [0.4, 0.6])}
    v = verdict_line(_verdict_report(two, {**setup, "m1": metric(0.7, 0.05, 0.3), "m2": metric(0.6, -0.1, 0.3)}))
    assert v == ("Verdict: A succeeds most (0.900 [0.800, 0.950] on d; next B 0.500 [0.400, 0.600], intervals "
                 "apart); the best metric, m1 (SRCC 0.700), ranks maps better than the setup baseline (setup_model "
                 "SRCC 0.500; difference +0.200 [0.050, 0.300]).")
    close = {"A": (0.6, [0.5, 0.7]), "B": (0.55, [0.45, 0.65])}
    v = verdict_line(_verdict_report(close, {**setup, "m1": metric(0.55, -0.1, 0.2)}))
    assert "A succeeds most" in v and "intervals overlap" in v and "does not rank maps clearly better than" in v
    v = verdict_line(_verdict_report(close, {**setup, "m1": metric(0.3, -0.4, -0.1)}))
    assert "ranks maps worse than the setup baseline" in v
    v = verdict_line(_verdict_report({"A": (0.6, [0.5, 0.7]), "B": (0.6, [0.5, 0.7])}, setup))
    assert v == ("Verdict: A, B succeed equally (0.600 [0.500, 0.700] on d); no difficulty metric to compare with "
                 "the setup baseline.")
    v = verdict_line(_verdict_report({"A": (0.6, [0.5, 0.7])}, {**setup, "m1": {"kind": "metric", "srcc_mean": None}}))
    assert v == ("Verdict: A is the only planner pair (0.600 [0.500, 0.700] on d); the metrics cannot rank maps here "
                 "(too few maps for a rank correlation with success).")
    v = verdict_line(_verdict_report(two, {**setup, "m1": metric(0.7, None, None)}))
    assert "is compared without an interval with the setup baseline" in v


# ------------------------------------------------------------------------------------------------ synthetic
def test_paired_comparison_on_synthetic_arrays():
    rng = np.random.default_rng(11)
    a = rng.random(60) < 0.7
    b = rng.random(60) < 0.4
    maps = np.repeat([f"m{i}" for i in range(12)], 5)
    out = paired_comparison(a, b, maps, n_boot=500, seed=4)
    assert (out["tasks"], out["both"], out["a_only"], out["b_only"], out["neither"]) == \
        (60, int(np.sum(a & b)), int(np.sum(a & ~b)), int(np.sum(~a & b)), int(np.sum(~a & ~b)))
    assert out["both"] + out["a_only"] + out["b_only"] + out["neither"] == 60
    assert out["difference"] == pytest.approx(a.mean() - b.mean())
    assert out["success_a"] == pytest.approx(a.mean()) and out["success_b"] == pytest.approx(b.mean())
    lo, hi = out["difference_ci95"]
    assert lo < out["difference"] < hi
    assert out["mcnemar_p"] == binomtest(out["a_only"], out["a_only"] + out["b_only"], 0.5).pvalue
    assert paired_comparison(a, b, maps, n_boot=500, seed=4) == out                # same seed, same interval
    assert paired_comparison(a, b, maps, n_boot=500, seed=5)["difference_ci95"] != out["difference_ci95"]
    same = paired_comparison(a, a, maps, n_boot=100)
    assert same["difference"] == 0 and same["difference_ci95"] == [0.0, 0.0] and same["mcnemar_p"] == 1.0
    assert all(math.isnan(x) for x in paired_comparison(a, b, maps, n_boot=0)["difference_ci95"])
    with pytest.raises(ConfigError) as err:
        paired_comparison(a, b, maps, n_boot=-1)
    assert err.value.field == "n_boot"
    assert mcnemar_exact(0, 0) == 1.0 and mcnemar_exact(7, 1) == binomtest(7, 8, 0.5).pvalue
    assert all(math.isnan(x) for x in wilson_interval(0, 0))


def test_paired_table_pairs_only_common_tasks():
    def trial(pair, mid, task, outcome):
        return {"pair": pair, "map_id": mid, "task": task, "mav_speed": 4.0, "outcome": outcome}

    trials = [trial("A", "m1", "t1", "success"), trial("A", "m1", "t2", "success"),
              trial("A", "m2", "t1", "dynamic_collision"),
              trial("B", "m1", "t1", "dynamic_collision"), trial("B", "m2", "t1", "success"),
              trial("B", "m2", "t9", "success"), trial("C", "m3", "t1", "success")]   # C shares no task
    rows = paired_table(trials, n_boot=20, seed=1)["comparisons"]
    assert [(r["a"], r["b"], r["tasks"], r["a_only"], r["b_only"], r["n_maps"]) for r in rows] == \
        [("A", "B", 2, 1, 1, 2)]
