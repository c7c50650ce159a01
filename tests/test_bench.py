"""`pbdyn bench`: frozen suites, shipped reference results and score cards (docs/benchmark.md).

The template planner (tools/templates/my_planner.py) is benched on the mini suite through the CLI; its card must
satisfy the card's JSON schema and render in a real headless Chromium; a bench interrupted by SIGINT and resumed
gives the card an uninterrupted bench gives; a built-in planner's flights reproduce its shipped reference bit for
bit; a planner that raises on some tasks gets "error" counted on its card; cards compare; the shipped suites'
hashes are fixed here.
"""

from __future__ import annotations

import json
import os
import re
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.conftest import ROOT, pbdyn_cmd

MINI = "pbdyn-2d-mini"
SUITE_HASHES = {
    "pbdyn-2d-mini": "1ebf60b5ddf4865644a88b0182b6863b73f1e92794ace2bf3d8fec2f9ce7a8bb",
    "pbdyn-2d-v1": "cdf42b856533c2df2cbd1f907d54fe566ddc189d67ed1eff18343eb28e83613a",
    "pbdyn-3d-v1": "46f419e083d62c1363216616c8da9570453f2aaae48a681f64781e1552ec315f",
    "pbdyn-2d-v2": "68e9b4cf09384fc6221876bf279f53f4780f3ed867087f9c2e5c68a6443c71fe",
}
"""The shipped suites' identities: a changed hash means the suite changed, which a frozen suite never does (a new
suite gets a new name or version)."""
TEMPLATES = ROOT / "tools" / "templates"
OUTPUT = ROOT / "results" / "test-output"


def _env(extra_path: Path | None = None) -> dict:
    env = dict(os.environ)
    paths = [str(TEMPLATES), str(ROOT)] + ([str(extra_path)] if extra_path else [])
    env["PYTHONPATH"] = os.pathsep.join(paths + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    return env


def _bench(args: list[str], extra_path: Path | None = None, timeout: int = 600) -> subprocess.CompletedProcess:
    return subprocess.run(pbdyn_cmd() + ["bench", *args], capture_output=True, text=True, timeout=timeout,
                          env=_env(extra_path))


def _stable(card: dict) -> dict:
    """A card without what varies between runs: the date, the git state, the bench's cost and the planner's wall
    times per step."""
    out = json.loads(json.dumps(card))
    out["provenance"].pop("date")
    out["provenance"]["code"].pop("git", None)
    out.pop("cost", None)
    out.pop("planning_time_ms")
    return out


@pytest.fixture(scope="module")
def template_card(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench") / "template"
    res = _bench(["my_planner:GoalSeeker", "--suite", MINI, "--out", str(out), "--workers", "2"])
    assert res.returncode == 0, res.stderr
    assert res.stderr.count("\n") <= 20 and "Traceback" not in res.stderr and "Warning" not in res.stderr
    return out, res


def test_the_template_planner_gets_a_valid_card_on_the_mini_suite(template_card):
    import jsonschema

    from pbdyn.benchmark.render import md_escape
    from pbdyn.benchmark.suite import load_suite

    out, res = template_card
    card = json.loads((out / "card.json").read_text())
    schema = json.loads((ROOT / "pbdyn" / "benchmark" / "card.schema.json").read_text())
    jsonschema.validate(card, schema)
    suite = load_suite(MINI)
    assert card["suite"]["hash"] == suite.hash and card["summary"] in res.stdout
    assert card["planner"]["label"] == "lookahead+my_planner:GoalSeeker"
    assert card["planner"]["fingerprint"].startswith("sha256:")
    assert card["trials"] == {"flown": suite.n_tasks(), "expected": suite.n_tasks(), "errors": 0}
    assert [lv["level"] for lv in card["levels"]] == [lv["level"] for lv in suite.levels]
    assert sum(lv["trials"] for lv in card["levels"]) == card["success"]["trials"] == suite.n_tasks()
    assert sum(card["outcomes"].values()) == suite.n_tasks()
    assert {r["label"] for r in card["references"]} == {
        "lookahead+local_primitives", "fullrange+global_primitives", "lookahead+mpc", "lookahead+straight_line",
        "lookahead+local_primitives_minjerk"}
    for ref in card["references"]:          # every paired table adds up to the tasks both flew
        pc = ref["paired"]
        assert pc["both"] + pc["a_only"] + pc["b_only"] + pc["neither"] == pc["tasks"] == suite.n_tasks()
    assert card["rank"]["of"] == 6 and card["rank"]["rank"] is None       # 4 maps: too few to rank
    assert "no rank" in card["rank"]["reason"] and "no rank" in card["summary"]
    md = (out / "card.md").read_text()
    assert md_escape(card["summary"]) in md and "p (clustered)" in md and "## How to read this card" in md


def test_the_card_renders_in_a_real_browser(template_card):
    from tests.test_html_report import _browser

    out, _ = template_card
    text = (out / "card.html").read_text()
    card = json.loads((out / "card.json").read_text())
    replays = {f["file"] for f in (card.get("failure_replays") or {}).get("files", [])}
    links = re.findall(r'(?:src|href)="(?!#|data:)([^"]*)"', text)
    assert "<script" not in text and set(links) <= replays     # self-contained but for the bench's replay files
    driver = _browser()
    try:
        driver.get((out / "card.html").absolute().as_uri())
        figure = driver.execute_script(
            "const s = document.querySelector('#curve svg'); const r = s.getBoundingClientRect();"
            "return [r.width, r.height, s.querySelectorAll('path').length]")
        tables = driver.execute_script(
            "return Object.fromEntries(Array.from(document.querySelectorAll('table')).map(t => [t.className,"
            " t.rows.length]))")
        summary = driver.execute_script("return document.getElementById('summary').textContent")
        OUTPUT.mkdir(parents=True, exist_ok=True)
        driver.save_screenshot(str(OUTPUT / "bench_card.png"))
    finally:
        driver.quit()
    assert figure[0] > 300 and figure[1] > 150 and figure[2] > 10
    assert tables["levels"] == 1 + len(card["levels"]) and tables["paired"] == 1 + 5 and tables["references"] == 7
    assert tables["maps"] == 1 + card["suite"]["maps"] and tables["speeds"] == 1 + 6 * len(card["suite"]["speeds_mps"])
    assert summary == card["summary"]


def _rows(store: Path) -> int:
    try:
        with sqlite3.connect(f"file:{store}?mode=ro", uri=True) as c:
            return c.execute("SELECT COUNT(*) FROM trials").fetchone()[0]
    except sqlite3.Error:
        return 0


def test_a_bench_resumed_after_sigint_gives_the_card_of_an_uninterrupted_one(tmp_path):
    whole = tmp_path / "whole"          # MPC: slow enough per map that the bench is still flying when interrupted
    res = _bench(["mpc", "--suite", MINI, "--out", str(whole), "--workers", "1", "--reproduce"])
    assert res.returncode == 0, res.stderr
    assert "bit for bit on all 12 tasks" in res.stdout
    cut = tmp_path / "cut"
    proc = subprocess.Popen(pbdyn_cmd() + ["bench", "mpc", "--suite", MINI, "--out", str(cut),
                                           "--workers", "1"], env=_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    store = cut / "flights" / "generated.sqlite"
    deadline = time.monotonic() + 300
    while _rows(store) == 0 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert not (cut / "card.json").exists()
    assert 0 < _rows(store) < 12
    res = _bench(["mpc", "--suite", MINI, "--out", str(cut), "--workers", "1"])
    assert res.returncode == 0, res.stderr
    a = json.loads((whole / "card.json").read_text())
    b = json.loads((cut / "card.json").read_text())
    assert a.pop("reproduction")["identical"]
    assert _stable(a) == _stable(b)


def test_a_planner_that_raises_on_some_tasks_gets_error_on_its_card(tmp_path):
    (tmp_path / "fragile_planner.py").write_text(
        "from my_planner import GoalSeeker\n\n"
        "class Fragile(GoalSeeker):\n"
        "    def plan(self, view):\n"
        "        if view.t == 0.0 and view.position[0] > 20.0:\n"
        "            raise ZeroDivisionError('a planner bug')\n"
        "        return super().plan(view)\n")
    out = tmp_path / "fragile"
    res = _bench(["fragile_planner:Fragile", "--suite", MINI, "--out", str(out), "--workers", "1"], tmp_path)
    assert res.returncode == 0, res.stderr
    card = json.loads((out / "card.json").read_text())
    from pbdyn.benchmark.suite import load_suite

    suite = load_suite(MINI)
    raising = sum(1 for m in suite.maps for q in suite.part(m["part"]).pairs
                  if suite.part(m["part"]).doc is not None and _start_x(suite, m["part"], q[0]) > 20.0)
    assert raising > 0 and card["outcomes"]["error"] == card["trials"]["errors"] == raising
    assert card["success"]["trials"] == suite.n_tasks()
    assert sum(lv["outcomes"]["error"] for lv in card["levels"]) == raising


def _start_x(suite, part: str, candidate: int) -> float:
    from pbdyn.config import parse_scenario

    p = suite.part(part)
    return float(parse_scenario(p.doc, p.path).task.candidates[candidate][0])


def test_cards_compare_side_by_side_and_cards_of_other_suites_are_refused(template_card, api_card, tmp_path):
    out, _ = template_card
    other, _ = api_card
    cmp_dir = tmp_path / "cmp"
    res = _bench(["--compare", str(out / "card.json"), str(other), "--out", str(cmp_dir)])
    assert res.returncode == 0, res.stderr
    lines = res.stdout.splitlines()
    assert lines[0].startswith("planner") and len(lines) == 3
    assert lines[1].startswith("lookahead+my_planner:GoalSeeker") and lines[2].startswith("lookahead+straight_line")
    html = (cmp_dir / "compare.html").read_text()
    assert "<svg" in html and "lookahead+straight_line" in html and (cmp_dir / "compare.md").is_file()
    card = json.loads((other / "card.json").read_text())
    card["suite"]["hash"] = "0" * 64
    forged = tmp_path / "forged.json"
    forged.write_text(json.dumps(card))
    res = _bench(["--compare", str(out / "card.json"), str(forged)])
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "not comparable" in res.stderr


def test_bad_bench_input_gets_one_line(tmp_path):
    cases = [(["no_such_planner", "--suite", MINI, "--out", str(tmp_path / "a")], "planner"),
             (["local_primitives", "--suite", "no-such-suite", "--out", str(tmp_path / "b")], "--suite"),
             (["local_primitives", "--suite", MINI], "--out"),
             (["--compare", str(tmp_path / "missing.json")], "--compare")]
    full = tmp_path / "full"
    full.mkdir()
    (full / "notes.txt").write_text("mine")
    cases.append((["local_primitives", "--suite", MINI, "--out", str(full)], "--out"))
    for args, field in cases:
        res = _bench(args, timeout=120)
        assert res.returncode == 2, (args, res.stdout, res.stderr)
        assert res.stderr.count("\n") == 1 and field in res.stderr and "Traceback" not in res.stderr, res.stderr
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    assert sorted(p.name for p in full.iterdir()) == ["notes.txt"]


def test_a_bench_folder_never_mixes_two_planners(template_card):
    out, _ = template_card
    res = _bench(["straight_line", "--suite", MINI, "--out", str(out)], timeout=120)
    assert res.returncode == 2 and "holds the bench of lookahead+my_planner:GoalSeeker" in res.stderr


def test_the_shipped_suites_have_their_fixed_hashes_and_matching_references():
    from pbdyn.benchmark.run import load_references
    from pbdyn.benchmark.suite import load_suite, suite_names

    assert set(SUITE_HASHES) <= set(suite_names())
    for name, expected in SUITE_HASHES.items():
        suite = load_suite(name)
        assert suite.hash == expected, name
        refs = load_references(suite)          # refuses a reference file of another suite version
        assert len(refs) == 5 and all(len(r["rows"]) == suite.n_tasks() for r in refs.values())
        for m in suite.maps:                   # every map's measured difficulty and level are stored
            lo, hi = next(lv["success_range"] for lv in suite.levels if lv["level"] == m["level"])
            s = m.get("level_success", m["reference_success"])     # v2: the level's flights are held-out ones
            assert lo <= s <= hi or (m["level"] == 1 and s >= lo)
            assert m["difficulty_ci95"][0] <= m["difficulty"] <= m["difficulty_ci95"][1]


@pytest.fixture(scope="module")
def api_card(tmp_path_factory):
    import pbdyn

    out = tmp_path_factory.mktemp("bench_api") / "straight"
    return out, pbdyn.bench("straight_line", suite=MINI, out=out, workers=1)


def test_the_api_benches_and_returns_the_card(api_card):
    out, card = api_card
    assert card["planner"]["label"] == "lookahead+straight_line"
    assert json.loads((out / "card.json").read_text())["summary"] == card["summary"]
    ref = next(r for r in card["references"] if r["label"] == "lookahead+straight_line")
    assert ref["success"] == card["success"] and ref["paired"]["a_only"] == ref["paired"]["b_only"] == 0


@pytest.mark.slow
@pytest.mark.parametrize("suite,planner", [("pbdyn-2d-v1", "local_primitives"), ("pbdyn-2d-v1", "mpc"),
                                           ("pbdyn-3d-v1", "local_primitives"), ("pbdyn-2d-v2", "local_primitives"),
                                           ("pbdyn-2d-v2", "straight_line")])
def test_reference_results_of_the_full_suites_reproduce_bit_for_bit(suite, planner, tmp_path):
    res = _bench([planner, "--suite", suite, "--out", str(tmp_path / planner), "--reproduce"], timeout=5400)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "bit for bit" in res.stdout


def test_the_benchmark_page_examples_run(tmp_path, monkeypatch):
    from tests.test_readme import FENCE, RUN_TAG

    text = (ROOT / "docs" / "benchmark.md").read_text(encoding="utf-8")
    blocks = [m.group(2) for m in FENCE.finditer(text) if m.group(1).strip() == RUN_TAG]
    assert blocks
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": "benchmark_page"}
    for code in blocks:
        exec(compile(code, "docs/benchmark.md", "exec"), namespace)
    assert (tmp_path / "bench-straight" / "card.html").is_file() and (tmp_path / "compare" / "compare.md").is_file()


def test_evaluate_on_a_bench_flight_store_gives_success_per_suite_level(api_card):
    """pbdyn evaluate on <out>/flights/<part>.sqlite knows the suite's levels: success per level equals the card's."""
    import pbdyn

    out, card = api_card
    report, table, _ = pbdyn.evaluate(out / "flights" / "generated.sqlite", n_boot=50)
    levels = report["success_by_group"]["level"]["lookahead+straight_line"]
    want = {str(lv["level"]): lv for lv in card["levels"] if lv["trials"]}
    assert set(levels) == set(want) and len(levels) >= 3
    for lv, cell in levels.items():
        assert (cell["successes"], cell["trials"]) == (want[lv]["successes"], want[lv]["trials"])
    assert "level" in table
