"""Levels measured on held-out tasks (docs/benchmark.md "Levels"): tools/make_suites.py draft-v2, fly-heldout, freeze
and bias on a two-map cut of the mini suite, flown for real."""

from __future__ import annotations

import gzip
import json
import shutil
import sys
from pathlib import Path

import pytest

import pbdyn
from pbdyn.benchmark.levels import level_of
from pbdyn.benchmark.run import load_references, reference_document
from pbdyn.benchmark.suite import LEVELS_FROM, V1_LEVELS_TEXT, load_suite, references_digest

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def tools():
    sys.path.insert(0, str(ROOT / "tools"))
    try:
        import make_suites
    finally:
        sys.path.remove(str(ROOT / "tools"))
    return make_suites


@pytest.fixture(scope="module")
def frozen(tools, tmp_path_factory):
    """A v1 suite of two maps (the mini suite's easiest and hardest), its v2 draft, both frozen from real flights."""
    base = tmp_path_factory.mktemp("suites")
    src = base / "tiny-v1"
    shutil.copytree(ROOT / "scenarios" / "suites" / "pbdyn-2d-mini", src)
    doc = json.loads((src / "suite.json").read_text())
    doc["maps"] = [doc["maps"][0], doc["maps"][-1]]           # its easiest and hardest map
    doc["name"] = "tiny-v1"
    (src / "suite.json").write_text(json.dumps(doc))
    mini = load_suite("pbdyn-2d-mini")                    # the mini suite's reference rows of the two maps
    keep = {m["map_id"] for m in doc["maps"]}
    refs = {k: {"meta": v["meta"], "rows": [r for r in v["rows"] if r["map_id"] in keep]}
            for k, v in load_references(mini).items()}
    ref_doc = reference_document(load_suite(src), refs)
    (src / "reference.json.gz").write_bytes(gzip.compress(json.dumps(ref_doc).encode(), mtime=0))
    doc["references_sha256"] = references_digest(ref_doc)
    (src / "suite.json").write_text(json.dumps(doc))
    old = tools.SUITES
    tools.SUITES = base
    try:
        flights = base / "flights"
        v1 = load_suite(src)
        tools.fly_heldout("tiny-v1", flights, [], workers=1)
        folder = tools.draft_v2("tiny-v2", [src, src], [flights / "heldout"] * 2)   # a map once, whatever its source
        draft = json.loads((folder / "suite.json").read_text())
        tools.fly_references("tiny-v2", flights, [], workers=1)
        tools.freeze("tiny-v2", flights, [flights / "heldout"])
    finally:
        tools.SUITES = old
    return {"v1": v1, "v2": load_suite(folder), "draft": draft, "flights": flights, "base": base}


def test_draft_v2_chooses_by_held_out_flights_and_keeps_the_tasks(frozen):
    v1, draft = frozen["v1"], frozen["draft"]
    assert draft["format"] == "pbdyn-suite/2" and draft[LEVELS_FROM]["tasks"] == "held-out"
    assert draft[LEVELS_FROM]["candidates"] == 2 and len(draft["maps"]) == 2      # both candidates (levels < 4 maps)
    ids = {spec.map_id for p in v1.parts for spec in __import__("pbdyn.world.maps", fromlist=["x"]).enumerate_maps(
        pbdyn.config.parse_scenario(p.doc, p.path))}
    assert {m["map_id"] for m in draft["maps"]} <= ids                       # named by content ids
    assert all(m["level"] is None and m["difficulty"] is None for m in draft["maps"])
    part = draft["parts"][0]
    assert part["pairs_flown"] == [list(q) for q in v1.parts[0].pairs]       # the suite's tasks are v1's
    flown = {c for q in part["pairs_flown"] for c in q}
    leveled = {c for q in part["pairs_leveled"] for c in q}
    assert leveled == {1, 3, 5, 7} and len(part["pairs_leveled"]) == 12     # the edge midpoints, all ordered pairs
    assert not flown & leveled                                             # no start or goal in common


def test_a_v2_freeze_levels_maps_by_the_held_out_flights_only(frozen, tools):
    from pbdyn.benchmark.run import load_references, read_rows

    v2 = frozen["v2"]
    held = tools.heldout_suite(v2)
    assert held.parts[0].pairs == v2.parts[0].level_pairs
    panel = {"lookahead+local_primitives": "local_primitives", "fullrange+global_primitives": "global_primitives",
             "lookahead+mpc": "mpc"}
    h_rows = [r for label, traj in panel.items()
              for r in read_rows(held, frozen["flights"] / "heldout" / traj, label)]
    refs = load_references(v2)
    s_rows = [r for label in panel for r in refs[label]["rows"]]
    assert sorted(refs) == sorted(["lookahead+local_primitives", "fullrange+global_primitives", "lookahead+mpc",
                                   "lookahead+straight_line", "lookahead+local_primitives_minjerk"])
    for m in v2.maps:
        mine = [r["outcome"] == "success" for r in h_rows if r["map_id"] == m["map_id"]]
        theirs = [r["outcome"] == "success" for r in s_rows if r["map_id"] == m["map_id"]]
        assert len(mine) == 3 * 12 and len(theirs) == 3 * 3
        assert m["level_success"] == round(sum(mine) / len(mine), 6)
        assert m["level"] == level_of(sum(mine) / len(mine))
        assert m["reference_success"] == round(sum(theirs) / len(theirs), 6)
    assert set(v2.doc[LEVELS_FROM]["fingerprints"]) == set(panel)
    easy, hard = sorted(v2.maps, key=lambda m: -m["level_success"])
    assert easy["difficulty"] < hard["difficulty"]            # the difficulty follows the held-out success
    assert isinstance(v2.doc[LEVELS_FROM]["offset_logits"], float)
    assert v2.levels_text == v2.doc[LEVELS_FROM]["text"] and frozen["v1"].levels_text == V1_LEVELS_TEXT


def test_a_v2_suite_benches_and_its_references_reproduce(frozen, tmp_path):
    card = pbdyn.bench("straight_line", suite=frozen["v2"].folder, out=tmp_path / "b", workers=1, reproduce=True)
    assert card["reproduction"]["identical"]
    assert card["trials"]["flown"] == frozen["v2"].n_tasks() == 6
    assert "held-out" in json.dumps(card)


def test_the_bias_measurement_compares_suite_and_held_out_flights(frozen, tools, capsys):
    old = tools.SUITES
    tools.SUITES = frozen["base"]
    try:
        out = tools.bias("tiny-v1", frozen["flights"] / "heldout")
    finally:
        tools.SUITES = old
    rows = out["suite_vs_heldout"]
    assert [r["level"] for r in rows] == [2, 9] and all(r["maps"] == 1 for r in rows)
    for r in rows:
        assert r["b_minus_a"] == pytest.approx(r["b"] - r["a"])
    assert out["tasks_per_map"] == {"suite": 9, "heldout": 36}
    for key in ("levels_from_references", "levels_from_heldout"):
        ss = out["same_skill"][key]
        assert ss["levels"] and (ss["ci95"][0] is None or ss["ci95"][0] <= ss["ci95"][1])
    assert "| level | maps |" in capsys.readouterr().out


def test_the_bench_and_its_tools_are_outside_every_flights_code_identity():
    """A frozen suite's references record the code identity they were flown with; the bench, its card and its
    replays are not part of it, so improving them leaves every reference 'same' (docs/design.md "Code identity")."""
    from pbdyn import codeid

    closure = codeid.pbdyn_closure(codeid.CORE_ROOTS)
    assert "pbdyn.sim.trial" in closure and "pbdyn.limits" in closure
    assert not [m for m in closure if m.startswith(("pbdyn.benchmark", "pbdyn.analysis", "pbdyn.experiments"))]
