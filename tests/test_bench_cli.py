"""`pbdyn bench` for every kind of planner, its progress, its advice and its failure replays (docs/cli.md
"pbdyn bench", docs/benchmark.md "Parameters, failure replays and cost"), on real mini-suite flights.

- --gaze-params: a built-in gaze planner with a non-default parameter flies other trials than its default, the card
  and the bench folder record the table, and a folder of other gaze parameters is refused in one line;
- one progress line with one ETA counts every task of a suite of two parts;
- a folder flown by a plug-in whose module was edited is refused with advice bench accepts; --rerun-changed
  re-flies it;
- --failures K writes real replays (GIFs that decode, one frame per step; MP4 on request), reused when run again;
- the card's cost counts the worker processes' CPU and adds up over the invocations that flew into the folder.
"""

from __future__ import annotations

import copy
import json
import resource
import shutil
import sqlite3
import time
from pathlib import Path

import pytest

from tests.conftest import ROOT
from tests.test_bench import MINI, _bench
from tests.test_flag_names import foreign_flags


def _card(out: Path) -> dict:
    """The bench folder's card, checked against the card schema (pbdyn.benchmark.run.read_card)."""
    from pbdyn.benchmark.run import read_card

    card = json.loads((out / "card.json").read_text())
    assert read_card(out) == card
    return card


def _rows(out: Path) -> list[dict]:
    from pbdyn.benchmark.run import read_rows
    from pbdyn.benchmark.suite import load_suite

    return read_rows(load_suite(MINI), out)


def _one_line_error(res, flag: str) -> None:
    assert res.returncode == 2, (res.stdout, res.stderr)
    assert res.stderr.count("\n") == 1 and "Traceback" not in res.stderr, res.stderr
    assert res.stderr.startswith(f"pbdyn: error: {flag}"), res.stderr
    assert not foreign_flags("bench", res.stderr), res.stderr


def test_gaze_params_are_flown_recorded_and_keep_a_folder_apart(tmp_path):
    import pbdyn
    from pbdyn.benchmark.card import DETERMINISTIC_FIELDS, task_key
    from pbdyn.errors import ConfigError

    default = tmp_path / "default"
    base = pbdyn.bench("local_primitives", gaze="rotating", suite=MINI, out=default, workers=2)
    out = tmp_path / "turning"
    args = ["local_primitives", "--gaze", "rotating", "--suite", MINI, "--out", str(out), "--workers", "2"]
    res = _bench(args + ["--gaze-params", '{"rate_fraction": -0.25}'])
    assert res.returncode == 0, res.stderr
    card = _card(out)
    assert card["planner"]["gaze_params"] == {"rate_fraction": -0.25} and "trajectory_params" not in card["planner"]
    assert "gaze_params" not in base["planner"]
    assert json.loads((out / "bench.json").read_text())["gaze_params"] == {"rate_fraction": -0.25}
    mine, theirs = {task_key(r): r for r in _rows(out)}, {task_key(r): r for r in _rows(default)}
    assert set(mine) == set(theirs) and len(mine) == 12        # the same tasks, flown otherwise
    differ = [k for k in mine if any(mine[k][f] != theirs[k][f] for f in DETERMINISTIC_FIELDS)]
    assert len(differ) >= 6 and any(mine[k]["outcome"] != theirs[k]["outcome"] for k in differ)
    # the Python API passes them: the same table resumes the folder (nothing to fly), the same card
    again = pbdyn.bench("local_primitives", gaze="rotating", gaze_params={"rate_fraction": -0.25}, suite=MINI,
                        out=out, workers=1)
    assert again["success"] == card["success"] and again["cost"] == card["cost"]
    # other gaze parameters never land in the same folder
    before = (out / "card.json").read_bytes()
    res = _bench(args + ["--gaze-params", '{"rate_fraction": 0.5}'], timeout=120)
    _one_line_error(res, "--out")
    assert 'with other gaze parameters ({"rate_fraction": -0.25})' in res.stderr
    assert (out / "card.json").read_bytes() == before
    # a bad gaze parameter is refused before the folder is made, naming the key as typed
    for table, named in (('{"zz": 1}', "--gaze-params.zz"), ('{"rate_fraction": NaN}', "--gaze-params.rate_fraction"),
                         ('{"rate_fraction": 2}', "--gaze-params")):
        res = _bench(args[:-4] + ["--out", str(tmp_path / "bad"), "--gaze-params", table], timeout=120)
        _one_line_error(res, named)
    assert not (tmp_path / "bad").exists()
    with pytest.raises(ConfigError, match=r"^gaze_params\.zz: unknown parameter"):
        pbdyn.bench("local_primitives", gaze="rotating", gaze_params={"zz": 1}, suite=MINI, out=tmp_path / "bad")
    with pytest.raises(ConfigError, match=r"^gaze_params: must be a table"):
        pbdyn.bench("local_primitives", gaze_params=[1], suite=MINI, out=tmp_path / "bad")
    assert not (tmp_path / "bad").exists()


def two_part_suite(folder: Path) -> Path:
    """The mini suite with a second part (a copy of its scenario flying one pair per map): 12 + 4 tasks, no
    reference results."""
    src = ROOT / "scenarios" / "suites" / MINI
    folder.mkdir()
    shutil.copy(src / "generated.toml", folder / "generated.toml")
    shutil.copy(src / "generated.toml", folder / "second.toml")
    doc = json.loads((src / "suite.json").read_text())
    doc["name"] = "two-parts"
    doc.pop("references_sha256", None)
    doc["parts"].append({"name": "second", "scenario": "second.toml", "pairs_flown": [[0, 2]]})
    doc["maps"] += [{**copy.deepcopy(m), "part": "second", "tasks": 1} for m in doc["maps"]]
    (folder / "suite.json").write_text(json.dumps(doc, indent=1))
    return folder


def test_one_progress_line_counts_every_task_of_the_suite(tmp_path):
    from pbdyn.benchmark.suite import load_suite

    suite = load_suite(two_part_suite(tmp_path / "suite"))
    assert len(suite.parts) == 2 and suite.n_tasks() == 16
    out = tmp_path / "bench"
    res = _bench(["straight_line", "--suite", str(suite.folder), "--out", str(out), "--workers", "2"])
    assert res.returncode == 0, res.stderr
    lines = res.stderr.splitlines()
    counts = [line.split(":", 1)[1].split()[0] for line in lines if line.startswith("pbdyn bench: ")]
    done = [int(c.split("/")[0]) for c in counts]
    assert {c.split("/")[1] for c in counts} == {"16"}, res.stderr      # one total: the whole suite's
    assert done[0] >= 1 and done[-1] == 16 and done == sorted(done) and len(counts) >= 2, res.stderr
    assert all("ETA" in line for line in lines if line.startswith("pbdyn bench: ")), res.stderr
    assert not any(line.startswith("pbdyn batch") for line in lines), res.stderr     # no line per part
    assert _card(out)["trials"]["flown"] == 16
    assert sorted(p.name for p in (out / "flights").iterdir()) == ["generated.sqlite", "second.sqlite"]


def _plugin(folder: Path, body: str) -> None:
    (folder / "edited_planner.py").write_text("from my_planner import GoalSeeker\n\n\nclass Mine(GoalSeeker):\n"
                                              f"    {body}\n")


def test_a_folder_of_edited_planner_code_is_refused_with_bench_advice_and_rerun_changed_refies_it(tmp_path):
    import subprocess
    import sys

    _plugin(tmp_path, "pass")
    out = tmp_path / "bench"
    args = ["edited_planner:Mine", "--suite", MINI, "--out", str(out), "--workers", "2"]
    assert _bench(args, tmp_path).returncode == 0
    _plugin(tmp_path, "edited = True")                      # the planner's code changes
    res = _bench(args, tmp_path)
    _one_line_error(res, "--out")
    assert "flights/generated.sqlite holds 12 trials of lookahead+edited_planner:Mine" in res.stderr
    assert "pass --rerun-changed" in res.stderr and "another --out folder" in res.stderr
    assert "--out file" not in res.stderr and "planners[0]" not in res.stderr
    res = _bench(args + ["--rerun-changed"], tmp_path)
    assert res.returncode == 0, res.stderr
    assert res.stderr.count("pbdyn bench: 12/12 trials") == 1       # all of them re-flown
    code = (f"import sys; sys.path[:0] = [{str(tmp_path)!r}, {str(ROOT / 'tools' / 'templates')!r}]\n"
            "from pbdyn.planning.registry import pair_fingerprint\n"
            "print(pair_fingerprint('edited_planner:Mine', 'lookahead'))")
    now = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    with sqlite3.connect(f"file:{out / 'flights' / 'generated.sqlite'}?mode=ro", uri=True) as c:
        stored = {fp for (fp,) in c.execute("SELECT DISTINCT planner_fingerprint FROM trials")}
    assert stored == {now} and _card(out)["planner"]["fingerprint"] == now     # every row of the edited code
    ledger = json.loads((out / "cost.json").read_text())["runs"]
    assert [r["flown"] for r in ledger] == [12, 12] and _card(out)["cost"]["runs"] == 2


def test_failure_replays_are_real_files_on_the_card_and_reused(tmp_path):
    import imageio.v3 as iio

    from pbdyn.benchmark.card import task_key
    from pbdyn.outcome import FAILURES

    out = tmp_path / "bench"
    args = ["local_primitives", "--suite", MINI, "--out", str(out), "--workers", "2"]
    t0 = time.perf_counter()
    res = _bench(args + ["--failures", "1"])
    took = time.perf_counter() - t0
    assert res.returncode == 0, res.stderr
    card = _card(out)
    rows = {task_key(r): r for r in _rows(out)}
    modes = [m.value for m in FAILURES if card["outcomes"][m.value]]
    fr = card["failure_replays"]
    assert fr["requested"] == 1 and [f["outcome"] for f in fr["files"]] == modes and len(modes) >= 2
    for f in fr["files"]:
        assert f["file"] == f"failures/{f['outcome']}-1.gif" and "reflown" not in f
        row = rows[task_key(f)]
        assert row["outcome"] == f["outcome"]
        frames = iio.imread(out / f["file"], index=None)
        assert frames.ndim == 4 and frames.shape[0] == row["steps"] + 1 >= 10    # every step and the end
        assert frames.shape[1] >= 320 and frames[-1].std() > 0
    assert "failure replays: 2 in" in res.stdout
    print(f"bench --failures 1 on {MINI}: {took:.1f} s, {len(fr['files'])} replays")
    # run again: nothing to fly, the same replays kept, nothing added to the cost
    stamps = {p.name: p.stat().st_mtime_ns for p in (out / "failures").iterdir()}
    res = _bench(args + ["--failures", "1"])
    assert res.returncode == 0, res.stderr
    assert {p.name: p.stat().st_mtime_ns for p in (out / "failures").iterdir()} == stamps
    again = _card(out)
    assert again["failure_replays"] == fr and again["cost"] == card["cost"]
    # bad requests: one line, nothing changed
    before = (out / "card.json").read_bytes()
    for extra, flag in ((["--failures", "0"], "--failures"), (["--failures", "1001"], "--failures"),
                        (["--failures", "x"], "--failures"), (["--failures-format", "gif"], "--failures-format"),
                        (["--failures", "1", "--failures-format", "webm"], "--failures-format")):
        _one_line_error(_bench(args + extra, timeout=120), flag)
    assert (out / "card.json").read_bytes() == before
    # MP4 on request: the GIFs of the earlier choice are replaced
    res = _bench(args + ["--failures", "1", "--failures-format", "mp4"])
    assert res.returncode == 0, res.stderr
    files = _card(out)["failure_replays"]["files"]
    assert [f["file"] for f in files] == [f"failures/{m}-1.mp4" for m in modes]
    assert sorted(p.name for p in (out / "failures").iterdir()) == sorted(
        [f"{m}-1.mp4" for m in modes] + ["replays.json"])
    import imageio.v2 as iio2

    for f in files:
        reader = iio2.get_reader(out / f["file"], format="FFMPEG")
        try:
            assert reader.count_frames() == rows[task_key(f)]["steps"] + 1
        finally:
            reader.close()


def test_a_re_flight_that_differs_from_its_row_is_said_on_the_card(tmp_path):
    """The replay re-flies the row's trial; where the re-flight does not give the row (here: a row altered by hand),
    the card entry says how (``reflown``) and a warning says so."""
    import imageio.v3 as iio

    import pbdyn
    from pbdyn.benchmark.failures import write_replays
    from pbdyn.benchmark.run import planner_entry
    from pbdyn.benchmark.suite import load_suite
    from pbdyn.errors import PbdynWarning

    out = tmp_path / "bench"
    pbdyn.bench("straight_line", suite=MINI, out=out, workers=2)
    row = next(r for r in _rows(out) if r["outcome"] != "success")
    altered = {**row, "steps": row["steps"] + 1}
    with pytest.warns(PbdynWarning, match=r"^failures: the re-flight of task .* differs from its row in steps "):
        fr = write_replays(load_suite(MINI), planner_entry("straight_line"), "fp", [altered], out, 1, "gif")
    (entry,) = fr["files"]
    assert entry["reflown"] == {"steps": row["steps"]} and entry["outcome"] == row["outcome"]
    assert iio.imread(out / entry["file"], index=None).shape[0] == row["steps"] + 1     # the re-flight's frames


def test_the_cost_counts_the_workers_cpu_and_adds_up_over_invocations(tmp_path):
    import pbdyn
    from pbdyn.errors import ConfigError

    def cpu(who) -> float:
        r = resource.getrusage(who)
        return r.ru_utime + r.ru_stime

    out = tmp_path / "bench"
    t0, self0, kids0 = time.perf_counter(), cpu(resource.RUSAGE_SELF), cpu(resource.RUSAGE_CHILDREN)
    card = pbdyn.bench("straight_line", suite=MINI, out=out, workers=1)
    wall = time.perf_counter() - t0
    self_s, kids_s = cpu(resource.RUSAGE_SELF) - self0, cpu(resource.RUSAGE_CHILDREN) - kids0
    cost = card["cost"]
    assert kids_s > 0.5                                   # the worker process flew the 12 tasks
    assert kids_s - 0.05 <= cost["cpu_s"] <= self_s + kids_s + 0.05 and 0 < cost["wall_s"] <= wall
    assert cost["runs"] == 1
    again = pbdyn.bench("straight_line", suite=MINI, out=out, workers=1)      # fully resumed: adds nothing
    assert again["cost"] == cost
    with sqlite3.connect(out / "flights" / "generated.sqlite") as c:          # a third of the tasks to fly again
        c.execute("DELETE FROM trials WHERE rowid IN (SELECT rowid FROM trials LIMIT 4)")
    third = pbdyn.bench("straight_line", suite=MINI, out=out, workers=1)
    assert third["cost"]["runs"] == 2 and third["cost"]["cpu_s"] > cost["cpu_s"]
    assert [r["flown"] for r in json.loads((out / "cost.json").read_text())["runs"]] == [12, 4]
    (out / "cost.json").write_text("{not json")
    with pytest.raises(ConfigError, match=r"^out: holds a cost ledger cost.json that is not"):
        pbdyn.bench("straight_line", suite=MINI, out=out, workers=1)
