"""Batch runner and results store: resume after kill -9 (coordinator and worker), Dask = process pool, error rows,
--extend, export round trips and bad input."""

from __future__ import annotations

import csv
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
from pbdyn.experiments.store import ResultsStore
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
        _wait_rows(out, 1, proc)
        kids = [c for c in _children(proc.pid) if "spawn" in Path(f"/proc/{c}/cmdline").read_text()]
        assert kids, "no worker processes found"
        os.kill(kids[0], signal.SIGKILL)
        _, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 0, err
    assert "a worker died" in err
    assert rows_without_wall(out) == rows_without_wall(ref_out)


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


def test_export_round_trips(reference, tmp_path):
    import pyarrow.parquet as pq

    _, out = reference
    store = ResultsStore.open(out)
    names, rows = store.trial_rows()
    store.close()
    assert names[:4] == ["trial_key", "gaze", "planner", "motion_profile"]
    for fmt in ("csv", "parquet"):
        dest = tmp_path / f"trials.{fmt}"
        res = subprocess.run(pbdyn_cmd() + ["export", str(out), f"--{fmt}", str(dest)], capture_output=True,
                             text=True, timeout=120)
        assert res.returncode == 0, res.stderr
        if fmt == "csv":
            with open(dest, newline="") as fh:
                back = list(csv.reader(fh))
            assert back[0] == names
            assert back[1:] == [["" if v is None else str(v) for v in r] for r in rows]
        else:
            table = pq.read_table(dest)
            assert table.column_names == names
            assert [tuple(r.values()) for r in table.to_pylist()] == rows


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
    for name in ("survivability", "density", "vo_feasibility", "setup_model", "batch_small"):
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
    from pbdyn.world.bullet import new_client

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
