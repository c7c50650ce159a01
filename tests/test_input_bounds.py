"""Every flag checked before work, bounded inputs, cards checked before they are rendered (issue 41, points 2, 5, 7).

Bad input is one line "pbdyn: error: ..." naming the flag the user typed, exit status 2, nothing written; cards given
to `pbdyn bench --compare` are checked against the shipped schema (pbdyn/benchmark/schema.py, compared here with the
jsonschema package); Markdown outputs escape what they embed.
"""

from __future__ import annotations

import copy
import gzip
import json
import os
import random
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import ROOT, pbdyn_cmd
from tests.fuzz_io import cli

MINI = "pbdyn-2d-mini"
XFF = os.fsdecode(b"\xff")          # a file name byte that is not UTF-8, as Python sees it (surrogateescape)


def _one_line_error(code, out: str, err: str, flag: str) -> None:
    assert code == 2, (code, out, err)
    assert err.count("\n") == 1 and err.startswith("pbdyn: error: ") and "Traceback" not in err, err
    assert flag in err.splitlines()[0], err
    assert out == ""


@pytest.fixture(scope="module")
def card_dir(tmp_path_factory):
    """A real bench folder: straight_line on the mini suite."""
    import pbdyn

    out = tmp_path_factory.mktemp("bench") / "straight"
    pbdyn.bench("straight_line", suite=MINI, out=out, workers=1)
    return out


# ------------------------------------------------------------------------------------------------ cards
def _tampered(card: dict) -> dict[str, dict | list | str]:
    bad = {}
    c = copy.deepcopy(card)
    c["success"]["rate"] = "high"
    bad["string_for_number"] = c
    c = copy.deepcopy(card)
    del c["levels"]
    bad["missing_field"] = c
    c = copy.deepcopy(card)
    c["levels"][0]["outcomes"] = [1, 2]
    bad["list_for_object"] = c
    c = copy.deepcopy(card)
    c["suite"]["hash"] = "not-a-hash"
    bad["bad_hash"] = c
    c = copy.deepcopy(card)
    c["planner"] = None
    bad["null_planner"] = c
    bad["foreign_list"] = [1, 2, 3]
    bad["nested_deep"] = "[" * 100_000 + "]" * 100_000
    bad["nan"] = json.dumps(card).replace('"rate": ' + json.dumps(card["success"]["rate"]), '"rate": NaN', 1)
    return bad


@pytest.mark.parametrize("kind", ["string_for_number", "missing_field", "list_for_object", "bad_hash", "null_planner",
                                  "foreign_list", "nested_deep", "nan"])
def test_compare_refuses_a_bad_or_foreign_card_with_one_line_naming_the_file(card_dir, tmp_path, kind):
    card = json.loads((card_dir / "card.json").read_text())
    doc = _tampered(card)[kind]
    path = tmp_path / f"{kind}.json"
    path.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    code, out, err, _ = cli(["bench", "--compare", str(card_dir), str(path), "--out", str(tmp_path / "cmp")])
    _one_line_error(code, out, err, str(path))
    assert "--compare" in err and not (tmp_path / "cmp").exists()


def test_the_card_validator_decides_as_jsonschema_on_real_and_tampered_cards(card_dir):
    import jsonschema

    from pbdyn.benchmark.schema import card_errors, card_schema, errors

    card = json.loads((card_dir / "card.json").read_text())
    schema = json.loads((ROOT / "pbdyn" / "benchmark" / "card.schema.json").read_text())
    assert card_schema() == schema and card_errors(card) == []
    validator = jsonschema.Draft202012Validator(schema)

    def paths(node, at=()):
        yield at
        if isinstance(node, dict):
            for k, v in node.items():
                yield from paths(v, at + (k,))
        elif isinstance(node, list):
            for i, v in enumerate(node):
                yield from paths(v, at + (i,))

    every = [p for p in paths(card) if p]
    values = [None, "x", 1, -1, 2.5, 3.0, True, [], {}, [1, 2, 3], "a" * 64, "0" * 64, 2, -0.0]
    rng = random.Random(41)
    invalid = 0
    for _ in range(800):
        c = copy.deepcopy(card)
        where = rng.choice(every)
        node = c
        for k in where[:-1]:
            node = node[k]
        if isinstance(node, dict) and rng.random() < 0.3:
            del node[where[-1]]
        else:
            node[where[-1]] = rng.choice(values)
        mine = errors(c, schema)
        assert (not mine) == validator.is_valid(c), (where, mine)
        invalid += bool(mine)
    assert invalid > 200


def test_the_validator_refuses_a_schema_keyword_it_does_not_implement():
    from pbdyn.benchmark.schema import SchemaError, check_subset

    check_subset({"type": "object", "properties": {"a": {"type": "integer", "minimum": 0}}})
    with pytest.raises(SchemaError, match="oneOf"):
        check_subset({"type": "object", "properties": {"a": {"oneOf": [{"type": "integer"}]}}})


def test_markdown_escapes_what_it_embeds_and_html_stays_escaped(card_dir, tmp_path):
    from pbdyn.benchmark.render import card_html, card_markdown

    card = json.loads((card_dir / "card.json").read_text())
    label = "evil|label <script>alert(1)</script> *bold* [link](http://x) $math$ `code`\n# heading"
    card["planner"]["label"] = label
    card["summary"] = label
    forged = tmp_path / "forged.json"
    forged.write_text(json.dumps(card))
    code, out, err, _ = cli(["bench", "--compare", str(card_dir), str(forged), "--out", str(tmp_path / "cmp")])
    assert code == 0 and err == "", err
    assert "\x1b" not in out and len(out.splitlines()) == 3
    for md in ((tmp_path / "cmp" / "compare.md").read_text(), card_markdown(card)):
        assert "<script>" not in md and "\n# heading" not in md
        assert r"evil\|label \<script\>" in md and r"\[link\](http" in md    # no "[...](" link survives
        assert "[link]" not in md.replace(r"\[link\]", "")
    for page in ((tmp_path / "cmp" / "compare.html").read_text(), card_html(card)):
        assert "<script>" not in page and "&lt;script&gt;" in page


def test_compare_md_table_rows_keep_their_column_count(card_dir, tmp_path):
    card = json.loads((card_dir / "card.json").read_text())
    card["planner"]["label"] = "a|b|c"
    forged = tmp_path / "pipes.json"
    forged.write_text(json.dumps(card))
    code, _, err, _ = cli(["bench", "--compare", str(forged), "--out", str(tmp_path / "cmp")])
    assert code == 0, err
    rows = [r for r in (tmp_path / "cmp" / "compare.md").read_text().splitlines() if r.startswith("|")]
    cells = {len(re.findall(r"(?<!\\)\|", r)) for r in rows}
    assert len(cells) == 1, rows


def test_bench_reproduce_json_exits_1_when_the_flights_differ(tmp_path):
    from pbdyn.benchmark.suite import load_suite

    suite = tmp_path / "suite"
    shutil.copytree(load_suite(MINI).folder, suite)
    ref = suite / "reference.json.gz"
    doc = json.loads(gzip.decompress(ref.read_bytes()))
    col = doc["columns"].index("steps")
    row = next(r for r in doc["rows"] if r[0] == "lookahead+straight_line")
    row[col] += 1
    ref.write_bytes(gzip.compress(json.dumps(doc).encode()))
    from pbdyn.benchmark.suite import REFERENCES_DIGEST, references_digest

    manifest = json.loads((suite / "suite.json").read_text())  # references of other flights, recorded as such
    manifest[REFERENCES_DIGEST] = references_digest(doc)
    (suite / "suite.json").write_text(json.dumps(manifest))
    res = subprocess.run(pbdyn_cmd() + ["bench", "straight_line", "--suite", str(suite), "--out", str(tmp_path / "o"),
                                        "--workers", "1", "--reproduce", "--json"],
                         capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert res.returncode == 1, res.stderr
    card = json.loads(res.stdout)
    assert card["reproduction"]["identical"] is False and card["reproduction"]["n_differences"] == 1


# ------------------------------------------------------------------------------------------------ bench's options
@pytest.mark.parametrize("args,flag", [
    (["--workers", "100000"], "--workers"),
    (["--scheduler", "foo://host:1"], "--scheduler"),
    (["--scheduler", "tcp://127.0.0.1:1"], "--scheduler"),
])
def test_bench_checks_workers_and_scheduler_before_making_the_folder(tmp_path, args, flag):
    out = tmp_path / "bench"
    code, stdout, err, _ = cli(["bench", "straight_line", "--suite", MINI, "--out", str(out), *args])
    _one_line_error(code, stdout, err, flag)
    assert not out.exists()


@pytest.mark.parametrize("where", ["file_on_the_way", "proc", "not_utf8"])
def test_bench_checks_that_out_can_be_written_before_anything_is_written(tmp_path, where):
    (tmp_path / "f").write_text("a file")
    out = {"file_on_the_way": str(tmp_path / "f" / "bench"), "proc": "/proc/pbdyn-bench",
           "not_utf8": str(tmp_path / f"b{XFF}")}[where]
    code, stdout, err, _ = cli(["bench", "straight_line", "--suite", MINI, "--out", out, "--workers", "1"])
    _one_line_error(code, stdout, err, "--out")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f"]


@pytest.mark.parametrize("args,flag", [
    (["straight_line", "--gaze", "no_such_gaze"], "--gaze"),
    (["no_such_planner"], "PLANNER"),
    (["straight_line", "--params", '{"no_such": 1}'], "--params.no_such"),
])
def test_bench_errors_name_the_option_the_user_typed(tmp_path, args, flag):
    code, out, err, _ = cli(["bench", *args, "--suite", MINI, "--out", str(tmp_path / "o")])
    _one_line_error(code, out, err, flag)
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------------------------------------------ numeric flags
GEN = ["generate", "--metric", "density", "--target", "0.05", "--tolerance", "0.01", "--count", "1"]
BOUNDED = [
    (GEN + ["--obstacles", "100000"], "--obstacles"),
    (GEN + ["--obstacles", "2000"], "--obstacles"),
    (GEN + ["--radius", "1e300"], "--radius"),
    (GEN + ["--radius", "30"], "--radius"),
    (GEN + ["--speed", "1e300"], "--speed"),
    (GEN + ["--speed", "5e8"], "--speed"),
    (["generate", "--metric", "density", "--target", "0.05", "--tolerance", "1e300"], "--tolerance"),
    (["generate", "--metric", "density", "--target", "1e300", "--tolerance", "0.1"], "--target"),
    (GEN + ["--seed", str(2 ** 70)], "--seed"),
    (GEN + ["--workers", "100000"], "--workers"),
    (["evaluate", str(ROOT / "scenarios" / "quickstart.toml"), "--bootstrap", "1000000000000"], "--bootstrap"),
    (["batch", "quickstart", "--lockstep", str(10 ** 20)], "--lockstep"),
    (["batch", "quickstart", "--limit", str(10 ** 20)], "--limit"),
    (["demo", "quickstart", "--maps", str(10 ** 8)], "--maps"),
    (["replay", "t.npz", "--every", str(10 ** 20)], "--every"),
]


@pytest.mark.parametrize("argv,flag", BOUNDED, ids=[" ".join(a[-2:]) for a, _ in BOUNDED])
def test_numeric_flags_are_held_to_the_limits(tmp_path, argv, flag):
    argv = list(argv)
    if argv[0] in ("generate", "batch"):
        argv += ["--out", str(tmp_path / ("g.toml" if argv[0] == "generate" else "s.sqlite"))]
    if argv[0] == "replay":
        argv += ["--out", str(tmp_path / "r.gif")]
    code, out, err, _ = cli(argv, cwd=tmp_path)
    _one_line_error(code, out, err, flag)
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------------------------ paths, labels, api
def _outputs(tmp_path: Path) -> list[list[str]]:
    store = str(ROOT / "results" / "quickstart.sqlite")
    n = f"x{XFF}"
    t = str(tmp_path)
    return [["batch", "quickstart", "--limit", "1", "--out", f"{t}/{n}.sqlite"],
            ["rollout", "quickstart", "--out", f"{t}/{n}.npz"],
            ["run", "quickstart", "--trace", f"{t}/{n}.npz"],
            ["metrics", "quickstart", "--metric", "density", "--plot", f"{t}/{n}.png"],
            ["calibrate", "quickstart", "--map", "0", "--store", f"{t}/{n}.sqlite"],
            ["generate", "--metric", "density", "--target", "0.05", "--tolerance", "0.01", "--out", f"{t}/{n}.toml"],
            ["evaluate", store, "--html", f"{t}/{n}.html"],
            ["bench", "--compare", str(ROOT / "no-such-card.json"), "--out", f"{t}/{n}"]]


@pytest.mark.parametrize("i", range(8))
def test_an_output_name_that_is_not_utf8_is_refused_with_one_line(tmp_path, i):
    argv = _outputs(tmp_path)[i]
    if argv[0] == "bench":
        res = cli(["bench", "straight_line", "--suite", MINI, "--workers", "1", "--out", argv[-1]])
    else:
        res = cli(argv)
    code, out, err, _ = res
    _one_line_error(code, out, err, "UTF-8")
    assert list(tmp_path.iterdir()) == []


def test_a_scenario_file_named_in_bytes_that_are_not_utf8_is_stored_safely(tmp_path):
    src = (ROOT / "scenarios" / "quickstart.toml").read_text()
    scenario = tmp_path / f"q{XFF}.toml"
    scenario.write_text("\n".join(x for x in src.splitlines() if not x.startswith("name")))
    store = tmp_path / "s.sqlite"
    code, out, err, _ = cli(["batch", str(scenario), "--limit", "1", "--workers", "1", "--out", str(store), "--json"])
    assert code == 0 and "Traceback" not in err, err
    json.loads(out)
    code, out, err, _ = cli(["evaluate", str(store), "--json"])
    assert code in (0, 2) and "internal error" not in err, err


def test_run_batch_names_out_when_it_is_not_a_path():
    import pbdyn

    with pytest.raises(pbdyn.ConfigError, match="^out: must be a path"):
        pbdyn.run_batch("quickstart", 123, workers=1)


def test_a_trace_label_is_bounded(tmp_path):
    from pbdyn.sim.observers import MAX_LABEL_CHARS, trace_label

    assert trace_label("x" * 10) == "x" * 10 and len(trace_label("x" * 5000)) == MAX_LABEL_CHARS
    trace = tmp_path / "t.npz"
    code, _, err, _ = cli(["run", "quickstart", "--trace", str(trace)])
    assert code == 0, err
    arrays = dict(np.load(trace))
    arrays["label"] = np.array("L" * 100_000)
    np.savez(tmp_path / "long.npz", **arrays)
    code, out, err, _ = cli(["replay", str(tmp_path / "long.npz"), "--out", str(tmp_path / "r.png")])
    _one_line_error(code, out, err, "label")
    assert not (tmp_path / "r.png").exists()


def _world_with_urdf(tmp_path: Path, urdf_text: str) -> Path:
    (tmp_path / "body.urdf").write_text(urdf_text)
    world = tmp_path / "world.toml"
    world.write_text('[world]\ndims = 3\nsize = [50.0, 50.0, 20.0]\ntime_limit = 2.0\n\n'
                     '[[bodies]]\nname = "b"\nurdf = "body.urdf"\nposition = [25.0, 25.0, 10.0]\n')
    return world


def test_a_urdf_nested_beyond_the_limit_is_refused_naming_the_file(tmp_path):
    deep = "<a>" * 40 + "</a>" * 40
    urdf = ('<robot name="r"><link name="base"><collision><geometry><box size="1 1 1"/></geometry></collision>'
            f'</link><extra>{deep}</extra></robot>')
    world = _world_with_urdf(tmp_path, urdf)
    code, out, err, _ = cli(["metrics", str(world), "--metric", "density", "--json"])
    _one_line_error(code, out, err, "body.urdf")
    assert "nested" in err


def test_open3d_warnings_stay_off_the_terminal(tmp_path):
    (tmp_path / "junk.obj").write_text("this is not a mesh\nv 1 2\nf 9 9 9\n")
    urdf = ('<robot name="r"><link name="base"><collision><geometry><mesh filename="junk.obj"/></geometry>'
            '</collision></link></robot>')
    world = _world_with_urdf(tmp_path, urdf)
    res = subprocess.run(pbdyn_cmd() + ["metrics", str(world), "--metric", "density", "--json"], capture_output=True,
                         text=True, timeout=120, cwd=ROOT)
    assert "Open3D" not in res.stderr and "\x1b[" not in res.stderr, res.stderr
    assert res.returncode in (0, 2) and res.stderr.count("\n") <= 1, res.stderr
