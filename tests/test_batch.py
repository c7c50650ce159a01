"""Batch runner and results store: resume after kill -9 (coordinator and worker), Dask = process pool, error rows,
--extend, export round trips and bad input."""

from __future__ import annotations

import csv
import re
import json
import os
import signal
import sqlite3
import subprocess
import time
from pathlib import Path

import pytest

from pbdyn.config import load_scenario
from pbdyn.errors import ConfigError
from pbdyn.experiments.runner import BatchOptions, run_batch
from pbdyn.experiments.store import SCHEMA_VERSION, ResultsStore
from tests.conftest import ROOT, SCENARIOS, pbdyn_cmd

SMALL = """
name = "batch_small"
[world]
time_limit = 30.0
[obstacles]
count = [6, 12]
radius = 1.0
speed = 2.0
maps_per_setup = 1
root_seed = 3
[drone]
v_max = [4.0]
[task]
candidates = [[4.0, 4.0], [46.0, 46.0], [4.0, 46.0], [46.0, 4.0], [25.0, 25.0]]
{planners}
"""
PLANNERS = """
[[planners]]
trajectory = "local_primitives"
gaze = "lookahead"
[[planners]]
trajectory = "straight_line"
gaze = "fullrange"
"""


def small(tmp_path: Path, planners: str = PLANNERS, name: str = "small.toml", **replace) -> Path:
    text = SMALL.format(planners=planners)
    for a, b in replace.items():
        text = text.replace(a, b)
    p = tmp_path / name
    p.write_text(text)
    return p


def rows_without_wall(path: Path) -> dict[str, dict]:
    store = ResultsStore.open(path)
    try:
        return {r["trial_key"]: {k: v for k, v in r.items() if "wall" not in k} for r in store.results()}
    finally:
        store.close()


def batch(args: list[str], **kw) -> subprocess.CompletedProcess:
    return subprocess.run(pbdyn_cmd() + ["batch", *args], capture_output=True, text=True, timeout=600, **kw)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """An uninterrupted 2-worker run of the small experiment (2 maps x 2 planners x 20 pairs = 80 trials)."""
    d = tmp_path_factory.mktemp("ref")
    sc = small(d)
    out = d / "ref.sqlite"
    res = batch([str(sc), "--out", str(out), "--workers", "2", "--json"])
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["trials"] == 80 and doc["ran"] == 80 and doc["errors"] == 0 and doc["maps_computed"] == 2
    return sc, out


def test_rerun_skips_everything_and_store_holds_each_trial_once(reference):
    sc, out = reference
    res = batch([str(sc), "--out", str(out), "--workers", "1", "--json"])
    assert res.returncode == 0
    assert json.loads(res.stdout)["ran"] == 0
    rows = rows_without_wall(out)
    assert len(rows) == 80
    store = ResultsStore.open(out)
    maps = store.maps()
    store.close()
    assert len(maps) == 2 and all(set(m["metrics"]) >= {"survivability", "density"} for m in maps.values())


def _count(path: Path) -> int:
    try:
        with sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=5) as c:
            return int(c.execute("SELECT COUNT(*) FROM trials").fetchone()[0])
    except sqlite3.Error:
        return 0


def _children(pid: int) -> list[int]:
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out.append(int(d.name))
    return out


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_text()
    except OSError:
        return ""


def _wait_rows(path: Path, k: int, proc: subprocess.Popen, timeout: float = 300.0) -> int:
    t0 = time.time()
    while time.time() - t0 < timeout:
        n = _count(path)
        if n >= k:
            return n
        assert proc.poll() is None, "the batch ended before the kill"
        time.sleep(0.05)
    raise AssertionError("no rows committed in time")


def test_kill_9_of_the_coordinator_loses_nothing_and_resume_completes(reference, tmp_path):
    sc, ref_out = reference
    out = tmp_path / "killed.sqlite"
    proc = subprocess.Popen(pbdyn_cmd() + ["batch", str(sc), "--out", str(out), "--workers", "1"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        k = _wait_rows(out, 1, proc)
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    committed = _count(out)
    assert k <= committed < 80
    res = batch([str(sc), "--out", str(out), "--workers", "2", "--json"])
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["already_stored"] == committed
    assert rows_without_wall(out) == rows_without_wall(ref_out)


def test_kill_9_of_a_worker_is_survived(reference, tmp_path):
    sc, ref_out = reference
    out = tmp_path / "worker.sqlite"
    proc = subprocess.Popen(pbdyn_cmd() + ["batch", str(sc), "--out", str(out), "--workers", "2"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        # Kill a worker while trials are certainly pending: before the first commit (commits come at most a second
        # apart once results arrive, and the 80 trials take longer than the workers' start). Waiting for a first row
        # instead raced on fast machines: the pool could finish every trial before the kill, leaving nothing to lose.
        t0 = time.time()
        kids: list[int] = []
        while not kids and time.time() - t0 < 120:
            assert proc.poll() is None, "the batch ended before the kill"
            kids = [c for c in _children(proc.pid) if "spawn" in _cmdline(c)]
            time.sleep(0.02)
        assert kids, "no worker processes found"
        assert _count(out) == 0
        os.kill(kids[0], signal.SIGKILL)
        _, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 0, err
    assert "a worker died" in err
    assert rows_without_wall(out) == rows_without_wall(ref_out)


def _descendants(pid: int) -> list[tuple[int, float]]:
    """(pid, start time) of every descendant of ``pid`` (psutil if installed, else /proc)."""
    try:
        import psutil
    except ImportError:
        out, todo = [], [pid]
        while todo:
            for c in _children(todo.pop()):
                out.append((c, float((Path(f"/proc/{c}/stat").read_text().rsplit(")", 1)[1].split()[19]))))
                todo.append(c)
        return out
    return [(c.pid, c.create_time()) for c in psutil.Process(pid).children(recursive=True)]


def _alive(pid: int, started: float) -> bool:
    """Whether the process ``pid`` started at ``started`` still runs (zombies count as gone)."""
    try:
        import psutil
    except ImportError:
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            return False
        return fields[0] != "Z" and float(fields[19]) == started
    try:
        p = psutil.Process(pid)
        return p.create_time() == started and p.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


SLOW = """
[[planners]]
trajectory = "tests.batch_plugins:SlowPlanner"
gaze = "lookahead"
[[planners]]
trajectory = "straight_line"
gaze = "fullrange"
"""
PLUGIN_ENV = dict(os.environ, PYTHONPATH=str(ROOT))


@pytest.fixture(scope="module")
def slow_reference(tmp_path_factory):
    """An uninterrupted 2-worker run of the small experiment with a planner that takes 2 ms more per plan (80
    trials that last long enough to be signalled mid-batch)."""
    d = tmp_path_factory.mktemp("slow")
    sc = small(d, SLOW)
    out = d / "ref.sqlite"
    res = batch([str(sc), "--out", str(out), "--workers", "2", "--no-metrics", "--json"], env=PLUGIN_ENV)
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["ran"] == 80
    return sc, out


@pytest.mark.parametrize("sig, status", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_sigterm_and_sigint_stop_the_workers_keep_committed_rows_and_resume_exactly(slow_reference, tmp_path, sig,
                                                                                   status):
    sc, ref_out = slow_reference
    out = tmp_path / "signalled.sqlite"
    args = [str(sc), "--out", str(out), "--workers", "2", "--no-metrics", "--lockstep", "10"]
    proc = subprocess.Popen(pbdyn_cmd() + ["batch", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, env=PLUGIN_ENV)
    try:
        _wait_rows(out, 2, proc)
        t0 = time.time()
        while True:          # rows stream as trials end: the second worker may still be starting; wait for it
            kids = _descendants(proc.pid)
            workers = [pid for pid, _ in kids if "spawn_main" in _cmdline(pid)]
            if len(workers) == 2 or time.time() - t0 > 60:
                break
            time.sleep(0.05)
        assert len(workers) == 2, kids
        assert _count(out) < 80, "the batch finished before the signal"
        os.kill(proc.pid, sig)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == status, err
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"pbdyn: batch stopped by {sig.name}: ") and "committed" in last
    assert "Traceback" not in err
    t0 = time.time()
    while any(_alive(*k) for k in kids) and time.time() - t0 < 10:
        time.sleep(0.1)
    assert not [k for k in kids if _alive(*k)], "processes of the batch outlived it"
    committed = _count(out)
    assert 2 <= committed < 80 and f": {committed} trials committed" in last
    res = batch(args + ["--json"], env=PLUGIN_ENV)
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["already_stored"] == committed
    rows, ref = rows_without_wall(out), rows_without_wall(ref_out)
    assert len(rows) == 80 and rows == ref


def test_dask_local_cluster_gives_the_process_pool_rows(reference, tmp_path):
    from dask.distributed import Client, LocalCluster

    sc, ref_out = reference
    out = tmp_path / "dask.sqlite"
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        s = run_batch(load_scenario(sc), out, BatchOptions(scheduler=client, progress=False))
    assert s.ran == 80 and s.errors == 0
    assert rows_without_wall(out) == rows_without_wall(ref_out)


FLAKY = """
[[planners]]
trajectory = "tests.batch_plugins:FlakyPlanner"
gaze = "lookahead"
"""


def test_a_planner_that_raises_gives_error_rows_and_the_batch_completes(tmp_path):
    sc = small(tmp_path, FLAKY)
    out = tmp_path / "flaky.sqlite"
    res = batch([str(sc), "--out", str(out), "--workers", "1", "--json", "--no-metrics"],
                env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["ran"] == 40 and 0 < doc["errors"] < 40
    store = ResultsStore.open(out)
    rows = store.results()
    store.close()
    errs = [r for r in rows if r["outcome"] == "error"]
    assert len(errs) == doc["errors"]
    assert all("start x > 40" in r["error"] and r["start"][0] > 40 for r in errs)
    assert all(r["outcome"] != "error" for r in rows if r["start"][0] < 40)
    again = batch([str(sc), "--out", str(out), "--workers", "1", "--json", "--no-metrics"],
                  env=dict(os.environ, PYTHONPATH=str(ROOT)))
    d2 = json.loads(again.stdout)
    assert (d2["ran"], d2["errors"], d2["stored_errors"]) == (0, 0, doc["errors"])
    before = rows_without_wall(out)
    retry = batch([str(sc), "--out", str(out), "--workers", "1", "--json", "--no-metrics", "--retry-errors"],
                  env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert retry.returncode == 0, retry.stderr
    d3 = json.loads(retry.stdout)
    assert (d3["ran"], d3["rerun"], d3["errors"], d3["stored_errors"]) == (doc["errors"],) * 4
    assert rows_without_wall(out) == before                      # the same rows, once each


def test_extend_accepts_additions_only(reference, tmp_path):
    sc, ref_out = reference
    out = tmp_path / "ext.sqlite"
    out.write_bytes(ref_out.read_bytes())
    more = small(tmp_path, PLANNERS + '[[planners]]\ntrajectory = "local_primitives"\ngaze = "fullrange"\n',
                 name="more.toml")
    res = batch([str(more), "--out", str(out), "--workers", "2"])
    assert res.returncode == 2 and "--extend" in res.stderr and len(res.stderr.strip().splitlines()) == 1
    res = batch([str(more), "--out", str(out), "--workers", "2", "--extend", "--json", "--limit", "60"])
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["already_stored"] == 40 and doc["ran"] == 20     # the first 60: map 0 x 3 planners
    changed = small(tmp_path, name="changed.toml", **{"radius = 1.0": "radius = 1.2"})
    res = batch([str(changed), "--out", str(out), "--extend"])
    assert res.returncode == 2 and "obstacles.radius" in res.stderr


def test_export_round_trips_with_numeric_start_goal_metrics_and_umask(reference, tmp_path):
    import pandas as pd
    from pandas.api.types import is_float_dtype, is_integer_dtype

    from pbdyn.experiments.export import trials_frame

    _, out = reference
    src = tmp_path / "partial.sqlite"            # one map without metrics: its trials get NaN metric columns
    src.write_bytes(out.read_bytes())
    store = ResultsStore.open(src)
    maps = store.maps()
    store.close()
    bare = sorted(maps)[0]
    with sqlite3.connect(src) as c:
        c.execute("UPDATE maps SET metrics_json = NULL WHERE map_id = ?", (bare,))
    df = trials_frame(src)
    assert len(df) == 80 and list(df.columns[:4]) == ["trial_key", "gaze", "planner", "motion_profile"]
    assert "start" not in df and "goal" not in df
    for col in ("start_x", "start_y", "goal_x", "goal_y", "mav_speed", "obstacle_radius", "metric_survivability"):
        assert is_float_dtype(df[col]), col
    assert is_integer_dtype(df["steps"]) and is_integer_dtype(df["map_index"])
    rows = {r["trial_key"]: r for r in ResultsStore.open(src).results()}
    for r in df.itertuples():
        assert [r.start_x, r.start_y, r.goal_x, r.goal_y] == rows[r.trial_key]["start"] + rows[r.trial_key]["goal"]
        if r.map_id == bare:
            assert pd.isna(r.metric_survivability)
        else:
            assert r.metric_survivability == maps[r.map_id]["metrics"]["survivability"]
    assert {f"metric_{m}" for m in maps[sorted(maps)[1]]["metrics"]} <= set(df.columns)
    old = os.umask(0o022)
    try:
        for fmt in ("csv", "parquet"):
            dest = tmp_path / f"trials.{fmt}"
            res = subprocess.run(pbdyn_cmd() + ["export", str(src), f"--{fmt}", str(dest)], capture_output=True,
                                 text=True, timeout=120)
            assert res.returncode == 0, res.stderr
            assert dest.stat().st_mode & 0o777 == 0o644
            back = pd.read_csv(dest) if fmt == "csv" else pd.read_parquet(dest)
            assert list(back.columns) == list(df.columns)
            for col in ("start_x", "goal_y", "flight_time_s", "metric_density", "steps"):
                assert back[col].dtype.kind in "if", (fmt, col)
                assert back[col].tolist() == pytest.approx(df[col].tolist(), nan_ok=True, rel=0, abs=0), (fmt, col)
            assert back["trial_key"].tolist() == df["trial_key"].tolist()
    finally:
        os.umask(old)
    assert not list(tmp_path.glob(".export-*"))


def test_store_columns_follow_the_trial_result_fields(reference):
    from dataclasses import dataclass, fields

    from pbdyn.experiments.store import SCHEMA_VERSION, TRIAL_COLUMNS, trial_columns
    from pbdyn.sim.result import TrialResult

    names = [f.name for f in fields(TrialResult) if f.name != "wall_timings"]
    assert [n for n, _ in TRIAL_COLUMNS] == names
    assert names.index("planner_fingerprint") == names.index("config_hash") + 1
    types = dict(TRIAL_COLUMNS)
    assert (types["steps"], types["mav_speed"], types["gaze"], types["start"], types["obstacle_radius"]) == \
        ("INTEGER", "REAL", "TEXT", "JSON", "JSON")

    @dataclass
    class Row:
        a: int
        b: float
        c: str
        d: tuple[float, ...]
        e: float | dict
        wall_timings: dict

    assert trial_columns(Row) == (("a", "INTEGER"), ("b", "REAL"), ("c", "TEXT"), ("d", "JSON"), ("e", "JSON"))
    _, out = reference
    with sqlite3.connect(f"file:{out}?mode=ro", uri=True) as c:
        cols = [(r[1], r[2]) for r in c.execute("PRAGMA table_info(trials)")]
        version = c.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()[0]
    assert int(version) == SCHEMA_VERSION == 6
    assert cols == [("trial_key", "TEXT")] + [(n, "TEXT" if t == "JSON" else t) for n, t in TRIAL_COLUMNS] + \
        [("error", "TEXT"), ("result_json", "TEXT"), ("finished", "REAL"), ("world_fingerprint", "TEXT")]
    store = ResultsStore.open(out)
    rows = store.results()
    store.close()
    from pbdyn.planning.registry import pair_fingerprint

    assert all(r["planner_fingerprint"] == pair_fingerprint(r["planner"], r["gaze"]) for r in rows)
    assert re.fullmatch(r"pbdyn:[0-9a-f]{16}\+pbdyn:[0-9a-f]{16}\+core:[0-9a-f]{16}", rows[0]["planner_fingerprint"])


def test_a_version_1_store_is_read_and_upgraded_and_its_rows_count_as_changed(reference, tmp_path):
    sc, out = reference
    v1 = tmp_path / "v1.sqlite"
    v1.write_bytes(out.read_bytes())
    with sqlite3.connect(v1) as c:
        c.execute("ALTER TABLE trials DROP COLUMN planner_fingerprint")
        c.execute("UPDATE meta SET value = '1' WHERE key = 'schema_version'")
    store = ResultsStore.open(v1)
    names, rows = store.trial_rows()
    store.close()
    assert len(rows) == 80 and {r[names.index("planner_fingerprint")] for r in rows} == {None}
    res = batch([str(sc), "--out", str(v1), "--workers", "1"])
    assert res.returncode == 2, res.stderr
    line = res.stderr.strip()
    assert "\n" not in line and "--rerun-changed" in line and "planners[0] (lookahead+local_primitives)" in line
    assert "80 stored trials" not in line and "40 stored trials flown with none" in line
    with sqlite3.connect(f"file:{v1}?mode=ro", uri=True) as c:   # a batch that stops before it starts: untouched
        assert c.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()[0] == "1"
        assert "planner_fingerprint" not in {r[1] for r in c.execute("PRAGMA table_info(trials)")}
        assert c.execute("SELECT COUNT(*) FROM runs").fetchone()[0] == \
            sqlite3.connect(f"file:{out}?mode=ro", uri=True).execute("SELECT COUNT(*) FROM runs").fetchone()[0]
    res = batch([str(sc), "--out", str(v1), "--workers", "1", "--rerun-changed", "--limit", "1", "--json"])
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["rerun"] == 1
    with sqlite3.connect(f"file:{v1}?mode=ro", uri=True) as c:   # a batch that runs upgrades the store in place
        assert c.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()[0] == str(SCHEMA_VERSION)
        assert "planner_fingerprint" in {r[1] for r in c.execute("PRAGMA table_info(trials)")}


PLUGIN = """
from pbdyn.planning.straight_line import StraightLine


class Straight(StraightLine):
    \"\"\"A plug-in whose source file the tests edit.\"\"\"
"""


def test_changed_planner_code_stops_the_batch_until_rerun_changed(tmp_path, monkeypatch):
    from pbdyn.planning import registry

    plug = tmp_path / "plug" / "fpplug_mod.py"
    plug.parent.mkdir()
    plug.write_text(PLUGIN)
    monkeypatch.syspath_prepend(str(plug.parent))
    entries = PLANNERS.split("[[planners]]")[1] + '[[planners]]\ntrajectory = "fpplug_mod:Straight"\n' \
        'gaze = "lookahead"\n'
    sc = small(tmp_path, "[[planners]]" + entries, **{
        "[46.0, 46.0], [4.0, 46.0], [46.0, 4.0], [25.0, 25.0]": "[46.0, 46.0], [25.0, 25.0]"})
    out = tmp_path / "fp.sqlite"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(plug.parent), str(ROOT)]))
    args = [str(sc), "--out", str(out), "--workers", "1", "--no-metrics", "--limit", "12", "--json"]
    res = batch(args, env=env)
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["ran"] == 12
    registry.planner_fingerprint.cache_clear()
    fp_old = registry.pair_fingerprint("fpplug_mod:Straight", "lookahead")
    fp_builtin = registry.pair_fingerprint("local_primitives", "lookahead")
    assert fp_builtin.startswith("pbdyn:") and fp_old.startswith("sha256:")
    before = rows_without_wall(out)
    by_label = {lab: {r["planner_fingerprint"] for r in before.values() if r["planner_label"] == lab}
                for lab in ("lookahead+local_primitives", "lookahead+fpplug_mod:Straight")}
    assert by_label == {"lookahead+local_primitives": {fp_builtin},
                        "lookahead+fpplug_mod:Straight": {fp_old}}
    with sqlite3.connect(out) as c:
        finished = dict(c.execute("SELECT trial_key, finished FROM trials"))

    plug.write_text(PLUGIN + "\n# an edit: the same behaviour, other code\n")
    registry.planner_fingerprint.cache_clear()
    fp_new = registry.pair_fingerprint("fpplug_mod:Straight", "lookahead")
    assert fp_new != fp_old and fp_new.split("+", 1)[1] == fp_old.split("+", 1)[1]
    res = batch(args, env=env)
    assert res.returncode == 2
    line = res.stderr.strip()
    assert "\n" not in line and "planners[1] (lookahead+fpplug_mod:Straight): 6 stored trials" in line
    assert "--rerun-changed" in line and "planners[0]" not in line
    assert rows_without_wall(out) == before                       # stopped before running anything

    res = batch(args + ["--rerun-changed"], env=env)
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    assert (doc["ran"], doc["rerun"], doc["already_stored"], doc["errors"]) == (6, 6, 6, 0)
    after = rows_without_wall(out)
    assert set(after) == set(before)                               # replaced in place: no duplicates
    for key, row in after.items():
        changed = row["planner_label"] == "lookahead+fpplug_mod:Straight"
        assert row["planner_fingerprint"] == (fp_new if changed else fp_builtin)
        assert {**row, "planner_fingerprint": None} == {**before[key], "planner_fingerprint": None}
    with sqlite3.connect(out) as c:
        now = dict(c.execute("SELECT trial_key, finished FROM trials"))
    assert {k for k in now if now[k] != finished[k]} == \
        {k for k, r in after.items() if r["planner_label"] == "lookahead+fpplug_mod:Straight"}
    res = batch(args, env=env)
    assert res.returncode == 0 and json.loads(res.stdout)["ran"] == 0


def test_bad_store_inputs_are_one_line_errors(tmp_path, reference):
    _, out = reference
    res = subprocess.run(pbdyn_cmd() + ["export", str(tmp_path / "nope.sqlite"), "--csv", str(tmp_path / "x.csv")],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and "RESULTS: file not found" in res.stderr
    newer = tmp_path / "newer.sqlite"
    newer.write_bytes(out.read_bytes())
    with sqlite3.connect(newer) as c:
        c.execute("UPDATE meta SET value = '99' WHERE key = 'schema_version'")
    res = subprocess.run(pbdyn_cmd() + ["export", str(newer), "--csv", str(tmp_path / "x.csv")],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and "schema version 99" in res.stderr
    with pytest.raises(ConfigError, match="schema version 99"):
        run_batch(load_scenario(SCENARIOS / "quickstart.toml"), newer, BatchOptions(limit=1, progress=False))
    garbage = tmp_path / "garbage.sqlite"
    garbage.write_text("not a database")
    res = subprocess.run(pbdyn_cmd() + ["export", str(garbage), "--csv", str(tmp_path / "x.csv")],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and "RESULTS" in res.stderr
    assert not (tmp_path / "x.csv").exists()


def test_evaluate_prints_the_table_writes_figures_and_json(reference, tmp_path):
    _, out = reference
    res = subprocess.run(pbdyn_cmd() + ["evaluate", str(out), "--plots", str(tmp_path / "fig"), "--bootstrap", "50"],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    for name in ("survivability", "density", "vo_feasibility", "setup_model", "batch_small", "flux",
                 "static_share", "vs best baseline", "Planner abilities", "Trial level", "task_survivability"):
        assert name in res.stdout
    pngs = sorted((tmp_path / "fig").glob("*.png"))
    assert pngs and all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in pngs)
    res = subprocess.run(pbdyn_cmd() + ["evaluate", str(out), "--json", "--bootstrap", "50"], capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    assert set(doc["metrics"]) >= {"survivability", "survivability_dense", "global_survivability", "setup_model"}
    per_map = doc["success"]
    assert per_map
    # baselines stored with every map, compared with every metric; the fitted difficulty of both maps
    assert doc["baselines"]["rows"][:2] == ["setup_model", "flux"] and doc["metrics"]["flux"]["kind"] == "baseline"
    assert set(doc["metrics"]["survivability"]["vs_baselines"]) >= {"setup_model", "flux", "static_share"}
    assert len(doc["fitted_difficulty"]["maps"]) == 2 and len(doc["fitted_difficulty"]["respondents"]) == 2
    assert doc["trial_level"]["predictors"]["task_flux"]["n_trials"] == 80
    figs = doc["figures"]                       # the numbers behind figs 5-9, 5-10 and 5-14
    store = ResultsStore.open(out)
    rows = [r for r in store.results() if r["outcome"] not in (None, "error")]
    store.close()
    assert sum(c["n"] for row in figs["fig_5_14"]["success"].values() for c in row) == len(rows)
    for traj, series in figs["fig_5_9"].items():
        sel = [r for r in rows if r["planner"] == traj]
        assert sum(c["n"] for c in series["success"]) == len(sel)
        assert sum(round(c["rate"] * c["n"]) for c in series["success"] if c["n"]) == \
            sum(r["outcome"] == "success" for r in sel)
        assert sum(round(c["rate"] * c["n"]) for c in series["deadlock"] if c["n"]) == \
            sum(r["outcome"] == "deadlock" for r in sel)
    missing = subprocess.run(pbdyn_cmd() + ["evaluate", str(tmp_path / "none.sqlite")], capture_output=True,
                             text=True, timeout=60)
    assert missing.returncode == 2 and "RESULTS: file not found" in missing.stderr


def test_a_reused_client_and_world_fly_exactly_like_fresh_ones(tmp_path):
    from pbdyn.sim.trial import make_trial_spec, make_world, run_trial
    from pbdyn.world.maps import enumerate_maps
    from pbdyn.world.rollout import build_rollout

    sc = load_scenario(small(tmp_path))
    maps = enumerate_maps(sc)
    cands = sc.task.candidates
    specs = [make_trial_spec(sc, m, planner=label, start=cands[0], goal=cands[1])
             for m in maps for label in ("lookahead+local_primitives", "fullrange+straight_line")]
    rollouts = {m.map_id: build_rollout(sc, m) for m in maps}
    fresh = [run_trial(s, rollouts[s.map_spec.map_id]).without_wall_times() for s in specs]
    from pbdyn.world.pybullet_client import new_client

    reused, world, client, prev = [], None, new_client(), None
    for s in specs:
        ro = rollouts[s.map_spec.map_id]
        if s.map_spec != prev:
            if world is not None:
                world.close()
            world = make_world(s, ro, client=client)
        prev = s.map_spec
        reused.append(run_trial(s, ro, world=world).without_wall_times())
    world.close()
    client.disconnect()
    assert reused == fresh


def test_an_unreachable_scheduler_is_a_one_line_error_and_leaves_no_store(tmp_path):
    out = tmp_path / "never.sqlite"
    res = batch([str(SCENARIOS / "quickstart.toml"), "--out", str(out), "--scheduler", "tcp://no-such-host-xyz:8786",
                 "--limit", "2"])
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "--scheduler: cannot reach a Dask scheduler" in lines[0]
    assert not out.exists()


def test_a_bad_planner_entry_stops_the_batch_before_it_starts(tmp_path):
    sc = small(tmp_path, '[[planners]]\ntrajectory = "local_primitives"\ngaze = "no_such_gaze"\n', name="bad.toml")
    out = tmp_path / "bad.sqlite"
    res = batch([str(sc), "--out", str(out)])
    assert res.returncode == 2 and "planners[0].gaze" in res.stderr and not out.exists()
    sc = small(tmp_path, '[[planners]]\ntrajectory = "mpc"\ntrajectory_params = { horizon = 1 }\n',
               name="bad2.toml")
    res = batch([str(sc), "--out", str(out)])
    assert res.returncode == 2 and "planners[0].trajectory_params" in res.stderr and not out.exists()


def test_evaluate_pools_generated_maps_and_an_imported_world(reference, tmp_path):
    """--pool: every store's maps are one dataset (no reference set), e.g. generated maps and an imported world,
    whose map has no setup label but has the baselines and a fitted difficulty."""
    _, out = reference
    world = tmp_path / "warehouse.sqlite"
    res = batch([str(SCENARIOS / "worlds" / "warehouse_2d.toml"), "--out", str(world), "--limit", "12", "--json"])
    assert res.returncode == 0, res.stderr
    res = subprocess.run(pbdyn_cmd() + ["evaluate", str(out), str(world), "--pool", "--json", "--bootstrap", "20"],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["controlled_dataset"] == "pooled" and doc["datasets"] == {"pooled": 3}
    assert doc["metrics"]["flux"]["n_maps"] == 3
    assert any(m.startswith("warehouse_2d/") for m in doc["fitted_difficulty"]["maps"])
    plain = subprocess.run(pbdyn_cmd() + ["evaluate", str(out), str(world), "--json", "--bootstrap", "20"],
                           capture_output=True, text=True, timeout=300)
    assert plain.returncode == 0 and json.loads(plain.stdout)["datasets"] == {"batch_small": 2, "warehouse_2d": 1}


def test_shards_merge_into_the_unsharded_store_without_duplicates(reference, tmp_path):
    """Two `--shard I/2` stores (one trial per task, so the lockstep default is compared as well) merge into
    exactly the rows and map metrics of the unsharded, lockstep-flown reference; merging again adds nothing."""
    sc, ref_out = reference
    shards = []
    for i in (1, 2):
        out = tmp_path / f"shard{i}.sqlite"
        res = batch([str(sc), "--out", str(out), "--workers", "1", "--shard", f"{i}/2", "--lockstep", "1", "--json"])
        assert res.returncode == 0, res.stderr
        assert json.loads(res.stdout)["ran"] == 40
        shards.append(out)
    assert not set(rows_without_wall(shards[0])) & set(rows_without_wall(shards[1]))
    merged = tmp_path / "merged.sqlite"
    res = subprocess.run(pbdyn_cmd() + ["merge", *map(str, shards), "--out", str(merged), "--json"],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout) == {"results": str(merged), "trials": 80, "added": 80, "duplicates": 0,
                                      "conflicts": 0, "maps": 2}
    assert rows_without_wall(merged) == rows_without_wall(ref_out)
    store = ResultsStore.open(merged)
    try:
        assert len(store.maps()) == 2 and all(m["metrics"] for m in store.maps().values())
    finally:
        store.close()
    again = subprocess.run(pbdyn_cmd() + ["merge", str(ref_out), str(shards[0]), "--out", str(merged), "--json"],
                           capture_output=True, text=True, timeout=120)
    assert json.loads(again.stdout)["added"] == 0 and json.loads(again.stdout)["duplicates"] == 120
    assert len(rows_without_wall(merged)) == 80
    other = small(tmp_path, name="other.toml", **{"root_seed = 3": "root_seed = 4"})
    res = batch([str(other), "--out", str(tmp_path / "other.sqlite"), "--workers", "1", "--limit", "2",
                 "--no-metrics"])
    assert res.returncode == 0, res.stderr
    bad = subprocess.run(pbdyn_cmd() + ["merge", str(shards[0]), str(tmp_path / "other.sqlite"), "--out",
                                        str(tmp_path / "mixed.sqlite")], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "another scenario" in bad.stderr and len(bad.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "mixed.sqlite").exists() and not list(tmp_path.glob(".mixed*"))


@pytest.mark.parametrize("args, fragment", [(["--shard", "3/2"], "--shard"), (["--shard", "0/2"], "--shard"),
                                            (["--shard", "a/b"], "--shard"), (["--lockstep", "0"], "--lockstep")])
def test_bad_shard_and_lockstep_are_one_line_errors(tmp_path, args, fragment):
    sc = small(tmp_path)
    out = tmp_path / "bad.sqlite"
    res = batch([str(sc), "--out", str(out), *args])
    assert res.returncode == 2 and fragment in res.stderr and len(res.stderr.strip().splitlines()) == 1
    assert not out.exists()


def test_the_slurm_array_recipe_flies_shards_that_merge(reference, tmp_path):
    """tools/templates/slurm_array.sh run as two array tasks (SLURM's variables set by hand) gives two complete shard
    stores that merge into the reference rows."""
    import sys

    exe = Path(sys.executable).parent / "pbdyn"
    if not exe.exists():
        pytest.skip("no pbdyn console script beside this interpreter")
    sc, ref_out = reference
    outdir = tmp_path / "out"
    for i in (1, 2):
        env = dict(os.environ, SLURM_ARRAY_TASK_ID=str(i), SLURM_ARRAY_TASK_COUNT="2", SLURM_CPUS_PER_TASK="1",
                   TMPDIR=str(tmp_path), PBDYN=str(exe))
        env.pop("SLURM_TMPDIR", None)
        res = subprocess.run(["bash", str(ROOT / "tools" / "templates" / "slurm_array.sh"), str(sc), str(outdir)],
                             capture_output=True, text=True, timeout=600, env=env)
        assert res.returncode == 0, res.stderr
    shards = sorted(outdir.glob("shard-*.sqlite"))
    assert [p.name for p in shards] == ["shard-1.sqlite", "shard-2.sqlite"]
    merged = tmp_path / "merged.sqlite"
    res = subprocess.run([str(exe), "merge", *map(str, shards), "--out", str(merged)], capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert rows_without_wall(merged) == rows_without_wall(ref_out)


def test_a_pool_worker_settles_its_heap_once_after_its_first_group(tmp_path):
    """Local pool workers (worker_init) freeze their long-lived heap after their first trial group (settle_heap:
    gc.collect, then gc.freeze) and never again; a process without worker_init (Dask workers) never does. In fresh
    processes, so that this one's collector is left as it is."""
    import sys

    code = (
        "import gc, sys\n"
        "from pbdyn.config import load_scenario\n"
        "from pbdyn.experiments import tasks\n"
        "from pbdyn.sim.trial import make_trial_spec\n"
        "from pbdyn.world.maps import get_map\n"
        "from pbdyn.world.rollout import get_rollout\n"
        "sc = load_scenario('quickstart'); ms = get_map(sc, 0); c = sc.task.candidates\n"
        f"path = {str(tmp_path / 'ro.npz')!r}; get_rollout(sc, ms).save(path)\n"
        "specs = tuple(make_trial_spec(sc, ms, start=tuple(c[i]), goal=tuple(c[-1])) for i in (0, 1))\n"
        "task = tasks.TrialGroupTask(('a', 'b'), specs, tasks.RolloutRef('r', path))\n"
        "if sys.argv[1] == 'pool':\n"
        "    tasks.worker_init()\n"
        "counts = []\n"
        "for _ in range(2):\n"
        "    rows = tasks.run_trial_group_task(task)\n"
        "    assert [r[2] for r in rows] == [None, None], rows\n"
        "    counts.append(gc.get_freeze_count())\n"
        "print(*counts)\n")
    got = {}
    for kind in ("pool", "dask"):
        done = subprocess.run([sys.executable, "-c", code, kind], capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr[-2000:]
        got[kind] = [int(x) for x in done.stdout.split()]
    assert got["pool"][0] > 10000 and got["pool"][1] <= got["pool"][0]      # (frozen objects can still be freed)
    assert got["dask"] == [0, 0]
