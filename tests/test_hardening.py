"""Issue 12, batch part: no failure blocks a store, bounded resources.

A batch that fails before it can start leaves no store (and an existing one untouched); trial and map enumeration
is lazy (--limit N costs O(N)); damaged, truncated, read-only or unusable stores are one-line errors (exit 2), a
full disk too, with the committed rows kept; --scheduler addresses are checked and probed within a bound; --workers
is capped; over-long and unwritable output paths fail before any work.
"""

from __future__ import annotations

import hashlib
import http.server
import json
import os
import socket
import sqlite3
import subprocess
import threading
import time
import tracemalloc
from pathlib import Path

import pytest

from pbdyn.config import load_scenario, parse_scenario
from pbdyn.errors import ConfigError
from pbdyn.experiments import cluster, dispatch, runner
from pbdyn.experiments.runner import BatchOptions, run_batch
from pbdyn.experiments.store import ResultsStore
from pbdyn.experiments.tasks import enumerate_trials, trial_spec
from pbdyn.world.maps import enumerate_maps, get_map
from tests.conftest import SCENARIOS, pbdyn_cmd


def cli(args: list[str], timeout: float = 300, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(pbdyn_cmd() + args, capture_output=True, text=True, timeout=timeout, **kw)


def one_line_exit_2(res: subprocess.CompletedProcess, *needles: str) -> str:
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2, res.stderr
    assert len(lines) == 1, res.stderr
    assert "Traceback" not in res.stderr
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# ------------------------------------------------------------------------------------------------ 1. no store
WORLD = """
name = "cart_world"
[world]
time_limit = 10.0
[[bodies]]
name = "cart"
urdf = "box.urdf"
motion = "pbdyn.world.motions:circle"
params = {{ center = [25.0, 30.0, 1.5], radius = 2.5, period = {period} }}
"""


def test_a_rollout_failure_leaves_no_store_and_the_fixed_world_then_runs(tmp_path):
    world = tmp_path / "world.toml"
    world.write_text(WORLD.format(period="0.0"))              # the motion function divides by zero at rollout time
    out = tmp_path / "w.sqlite"
    args = [str(world), "--out", str(out), "--limit", "1", "--workers", "1", "--no-metrics", "--json"]
    one_line_exit_2(cli(["batch", *args]), "bodies[0].motion", "motion function raised")
    assert not out.exists() and not list(tmp_path.glob("w.sqlite*"))
    world.write_text(WORLD.format(period="9.0"))              # the typo fixed: the same command now runs
    res = cli(["batch", *args])
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["ran"] == 1


def test_a_failure_before_the_start_leaves_an_existing_store_untouched(tmp_path, monkeypatch):
    sc = load_scenario(SCENARIOS / "quickstart.toml")
    out = tmp_path / "q.sqlite"
    run_batch(sc, out, BatchOptions(limit=1, workers=1, progress=False, metrics=False))
    before = digest(out)

    def broken(*a, **k):
        raise ConfigError("bodies[0].motion", "the motion function raised", "x")

    monkeypatch.setattr(runner, "rollout_file", broken)
    per_map = len(enumerate_trials(sc)) // len(enumerate_maps(sc))
    with pytest.raises(ConfigError, match="motion function raised"):     # needs map 1's rollout
        run_batch(sc, out, BatchOptions(limit=per_map + 1, workers=1, progress=False, metrics=False))
    assert digest(out) == before


# ------------------------------------------------------------------------------------------------ 2. lazy
def old_enumerate(scenario, maps):
    """The eager enumeration this replaced (every TrialSpec built, every hash computed, one list)."""
    cands = scenario.task.candidates
    out = []
    for m in maps:
        for entry in scenario.planners:
            for v in scenario.drone.v_max:
                for i, j in scenario.task.pairs():
                    spec = trial_spec(scenario, m, entry, v, cands[i], cands[j])
                    out.append((spec.config_hash, m, entry, float(v), tuple(cands[i]), tuple(cands[j])))
    return out


@pytest.mark.parametrize("name, n_maps", [("quickstart", None), ("datasets/within_setup_2d", 3),
                                          ("datasets/uncontrolled_speed_3d", 2), ("worlds/warehouse_2d.toml", None)])
def test_the_lazy_enumeration_equals_the_old_list(name, n_maps):
    sc = load_scenario(SCENARIOS / name if name.endswith(".toml") else name)
    maps = enumerate_maps(sc)
    old_maps = []
    for setup in sc.setups():                                  # the eager map list this replaced
        for rep in range(sc.obstacles.maps_per_setup):
            old_maps.append((len(old_maps), setup, rep))
    assert [(m.index, m.setup, m.replicate) for m in maps] == old_maps
    assert [get_map(sc, i) for i in range(len(maps))] == list(maps)
    chosen = list(maps) if n_maps is None else maps[:n_maps]
    old = old_enumerate(sc, chosen)
    seq = enumerate_trials(sc, chosen)
    assert len(seq) == len(old) and list(seq) == old
    assert seq[1:7] == old[1:7] and seq[len(old) - 1] == old[-1] and seq[-2] == old[-2]
    assert list(seq.iter_range(5, 9)) == old[5:9]


def test_limit_is_o_n_on_a_huge_grid():
    # 10,000 candidates: 99,990,000 start/goal pairs per map, 100 x 100 setups x 20 maps; --map N and --limit N
    # must not build them
    cands = [[2.0 + 0.46 * (k % 100), 2.0 + 0.46 * (k // 100)] for k in range(10_000)]
    doc = {"name": "huge", "obstacles": {"count": list(range(1, 101)), "radius": [0.1 + 0.001 * k for k in range(100)],
                                         "speed": 1.0, "maps_per_setup": 20},
           "drone": {"v_max": [2.0, 4.0, 6.0]}, "task": {"candidates": cands}}
    sc = parse_scenario(doc)
    tracemalloc.start()
    t0 = time.perf_counter()
    m = get_map(sc, 199_999)
    seq = enumerate_trials(sc)
    first = seq[:3]
    last = seq[len(seq) - 1]
    dt = time.perf_counter() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert m.setup == {"count": 100, "radius": pytest.approx(0.199), "speed": 1.0} and m.replicate == 19
    assert len(seq) == 200_000 * 3 * 10_000 * 9_999
    assert [t[4:] for t in first] == [(tuple(cands[0]), tuple(cands[j])) for j in (1, 2, 3)]
    assert first[0][0] == trial_spec(sc, get_map(sc, 0), sc.planners[0], 2.0, cands[0], cands[1]).config_hash
    assert last[1] == m and last[3] == 6.0 and last[4:] == (tuple(cands[-1]), tuple(cands[-2]))
    assert dt < 5.0 and peak < 50e6, (dt, peak)


def test_the_first_trial_of_controlled_2d_flies_within_seconds(tmp_path):
    out = tmp_path / "c.sqlite"
    t0 = time.perf_counter()
    res = cli(["batch", "datasets/controlled_2d", "--out", str(out), "--limit", "2", "--workers", "1",
               "--no-metrics", "--json"], timeout=120)
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["trials"] == 2
    assert time.perf_counter() - t0 < 30.0          # was minutes: 2.1 million trial hashes before the first trial


# ------------------------------------------------------------------------------------------------ 3. stores
@pytest.fixture(scope="module")
def store6(tmp_path_factory):
    """A real store: 6 quickstart trials with map 0's metrics."""
    d = tmp_path_factory.mktemp("store6")
    out = d / "q.sqlite"
    res = cli(["batch", "quickstart", "--out", str(out), "--limit", "6", "--workers", "1", "--json"])
    assert res.returncode == 0, res.stderr
    return out


def _copy(src: Path, dst: Path) -> Path:
    dst.write_bytes(src.read_bytes())
    return dst


def _three_commands(store: Path, tmp_path: Path) -> list[subprocess.CompletedProcess]:
    return [cli(["batch", "quickstart", "--out", str(store), "--limit", "6", "--workers", "1"]),
            cli(["evaluate", str(store), "--bootstrap", "10"]),
            cli(["export", str(store), "--csv", str(tmp_path / "x.csv")])]


def test_garbage_in_the_middle_of_a_store_is_reported_by_batch_evaluate_and_export(store6, tmp_path):
    bad = _copy(store6, tmp_path / "bad.sqlite")
    data = bytearray(bad.read_bytes())
    page = 4096
    off = (len(data) // page // 2) * page                     # a page in the middle, header first
    data[off:off + 128] = bytes(hashlib.sha256(str(i).encode()).digest()[0] for i in range(128))
    bad.write_bytes(bytes(data))
    batch, evaluate, export = _three_commands(bad, tmp_path)
    one_line_exit_2(batch, "--out", "damaged")
    one_line_exit_2(evaluate, "RESULTS", "damaged")
    one_line_exit_2(export, "RESULTS", "damaged")
    assert not (tmp_path / "x.csv").exists()


def test_a_row_that_is_not_text_or_json_is_a_one_line_error(store6, tmp_path):
    bad = _copy(store6, tmp_path / "row.sqlite")
    with sqlite3.connect(bad) as c:
        k1, k2 = [r[0] for r in c.execute("SELECT trial_key FROM trials ORDER BY trial_key LIMIT 2")]
        c.execute("UPDATE trials SET result_json = CAST(X'7B22FF' AS TEXT) WHERE trial_key = ?", (k1,))  # evaluate
        c.execute("UPDATE trials SET planner = CAST(X'61FF62' AS TEXT) WHERE trial_key = ?", (k2,))      # export
    _, evaluate, export = _three_commands(bad, tmp_path)
    one_line_exit_2(evaluate, "RESULTS", "damaged")
    one_line_exit_2(export, "RESULTS", "damaged")


def test_a_truncated_store_is_a_one_line_error(store6, tmp_path):
    bad = _copy(store6, tmp_path / "cut.sqlite")
    data = bad.read_bytes()
    bad.write_bytes(data[: len(data) // 2])
    batch, evaluate, export = _three_commands(bad, tmp_path)
    one_line_exit_2(batch, "--out")
    one_line_exit_2(evaluate, "RESULTS")
    one_line_exit_2(export, "RESULTS")


def test_unusable_out_paths_are_one_line_errors_and_create_nothing(tmp_path):
    base = ["batch", "quickstart", "--limit", "1", "--workers", "1"]
    folder = tmp_path / "a_folder"
    folder.mkdir()
    one_line_exit_2(cli(base + ["--out", str(folder)]), "--out", "is a folder")
    afile = tmp_path / "plain.txt"
    afile.write_text("x")
    one_line_exit_2(cli(base + ["--out", str(afile / "sub" / "r.sqlite")]), "--out", "is a file, not a folder")
    one_line_exit_2(cli(base + ["--out", str(tmp_path / ("n" * 300) / "r.sqlite")]), "--out", "255 bytes")
    other = tmp_path / "other.sqlite"
    with sqlite3.connect(other) as c:
        c.execute("CREATE TABLE mine (x)")
    before = digest(other)
    one_line_exit_2(cli(base + ["--out", str(other)]), "--out", "not a pbdyn results store")
    assert digest(other) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_folder", "other.sqlite", "plain.txt"]


@pytest.mark.skipif(os.geteuid() == 0, reason="root ignores file permissions (see the path-under-a-file cases)")
def test_read_only_store_and_folder_are_one_line_errors(store6, tmp_path):
    ro = _copy(store6, tmp_path / "ro.sqlite")
    ro.chmod(0o444)
    one_line_exit_2(cli(["batch", "quickstart", "--out", str(ro), "--limit", "7", "--workers", "1"]), "--out",
                    "read-only")
    folder = tmp_path / "rofolder"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        one_line_exit_2(cli(["batch", "quickstart", "--out", str(folder / "r.sqlite"), "--limit", "1"]), "--out",
                        "not writable")
    finally:
        folder.chmod(0o755)


def test_a_read_only_database_is_a_one_line_error_naming_out(store6, tmp_path):
    # works as root too: SQLite refuses to write through a read-only connection, whatever the permissions
    from pbdyn.experiments.store import store_error

    conn = sqlite3.connect(f"file:{store6}?mode=ro", uri=True)
    with pytest.raises(sqlite3.OperationalError) as info:
        conn.execute("INSERT INTO meta VALUES ('x', 'y')")
    conn.close()
    err = store_error("out", info.value, store6)
    assert err.field == "out" and "read-only" in str(err) and "\n" not in str(err)


def test_a_store_locked_past_the_timeout_is_a_one_line_error(store6, tmp_path, monkeypatch):
    from pbdyn.experiments import store as store_mod

    locked = _copy(store6, tmp_path / "locked.sqlite")
    holder = sqlite3.connect(locked)
    holder.execute("BEGIN EXCLUSIVE")                      # another writer holds the store
    monkeypatch.setattr(store_mod, "LOCK_TIMEOUT_S", 0.2)
    try:
        with pytest.raises(ConfigError) as info:
            ResultsStore.create(locked)
    finally:
        holder.rollback()
        holder.close()
    assert info.value.field == "out" and "locked by another process" in str(info.value)


def test_a_full_disk_during_a_batch_is_one_line_exit_2_and_keeps_committed_rows(tmp_path, monkeypatch, capsys):
    from pbdyn import cli as pbdyn_cli

    create = ResultsStore.create.__func__
    out = tmp_path / "full.sqlite"

    def small_disk(cls, path, field="out"):
        store = create(cls, path, field)
        pages = store.conn.execute("PRAGMA page_count").fetchone()[0]
        store.conn.execute(f"PRAGMA max_page_count = {pages + 4}")   # SQLITE_FULL after a few rows
        return store

    monkeypatch.setattr(ResultsStore, "create", classmethod(small_disk))
    monkeypatch.setattr(dispatch, "COMMIT_INTERVAL_S", 0.0)
    status = pbdyn_cli.main(["batch", "quickstart", "--out", str(out), "--limit", "12", "--workers", "1",
                             "--no-metrics"])
    err = [line for line in capsys.readouterr().err.strip().splitlines() if not line.startswith("pbdyn batch: ")]
    assert status == 2 and len(err) == 1 and "--out" in err[0] and "disk is full" in err[0], err
    store = ResultsStore.open(out)
    try:
        n = store.count()
        assert 0 < n < 12 and len(store.results()) == n
    finally:
        store.close()


# ------------------------------------------------------------------------------------------------ 4. scheduler
@pytest.fixture
def fast_probe(monkeypatch):
    monkeypatch.setattr(cluster, "PROBE_TIMEOUT_S", 1.0)
    monkeypatch.setattr(cluster, "CONNECT_TIMEOUT_S", 4.0)


def _listener() -> socket.socket:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen(8)
    return s


def test_a_silent_port_is_refused_within_the_bound(fast_probe):
    with _listener() as s:                     # the kernel accepts; nothing ever answers
        address = f"tcp://127.0.0.1:{s.getsockname()[1]}"
        t0 = time.perf_counter()
        with pytest.raises(ConfigError) as info:
            cluster.connect(address)
        assert time.perf_counter() - t0 < 4.0
    assert info.value.field == "scheduler" and "no Dask handshake" in str(info.value)


def test_a_silent_port_through_the_cli_is_one_line_exit_2(tmp_path):
    out = tmp_path / "never.sqlite"
    with _listener() as s:
        t0 = time.perf_counter()
        res = cli(["batch", "quickstart", "--out", str(out), "--scheduler", f"tcp://127.0.0.1:{s.getsockname()[1]}",
                   "--limit", "1"], timeout=60)
        assert time.perf_counter() - t0 < 30.0
    one_line_exit_2(res, "--scheduler", "no Dask handshake")
    assert not out.exists()


def test_an_http_server_is_refused_without_a_huge_allocation(fast_probe):
    class Quiet(http.server.BaseHTTPRequestHandler):
        def log_message(self, *a):
            pass

    server = http.server.HTTPServer(("127.0.0.1", 0), Quiet)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        with pytest.raises(ConfigError) as info:
            cluster.connect(f"tcp://127.0.0.1:{server.server_address[1]}")
    finally:
        server.shutdown()
        server.server_close()
    assert info.value.field == "scheduler" and "HTTP" in str(info.value)


@pytest.mark.parametrize("address, needle", [
    ("tls://127.0.0.1:8786", "Security"), ("http://127.0.0.1:8787", "HTTP address"), ("ftp://h:1", "scheme"),
    ("tcp://127.0.0.1", "port in 1..65535"), ("tcp://127.0.0.1:0", "port in 1..65535"),
    ("tcp://127.0.0.1:70000", "address like"), ("tcp://:8786", "no host"), ("tcp://h:8786/x", "nothing after"),
    ("", "Dask scheduler address"),
])
def test_malformed_and_tls_addresses_are_one_line_errors(address, needle):
    t0 = time.perf_counter()
    with pytest.raises(ConfigError) as info:
        cluster.connect(address)
    assert info.value.field == "scheduler" and needle in str(info.value) and "\n" not in str(info.value)
    assert time.perf_counter() - t0 < 1.0


def test_a_real_local_cluster_is_reached_by_address(tmp_path):
    from dask.distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as local:
        client = cluster.connect(local.scheduler_address)
        try:
            assert client.scheduler_info()["address"] == local.scheduler_address
        finally:
            client.close()
        s = run_batch(load_scenario(SCENARIOS / "quickstart.toml"), tmp_path / "d.sqlite",
                      BatchOptions(scheduler=local.scheduler_address, limit=1, metrics=False, progress=False))
    assert s.ran == 1 and s.errors == 0


# ------------------------------------------------------------------------------------------------ 5. smaller
def test_workers_are_capped():
    cap = runner.max_workers()
    assert cap == 4 * (os.cpu_count() or 1)
    with pytest.raises(ConfigError, match=f"must be <= {cap}"):
        run_batch(load_scenario(SCENARIOS / "quickstart.toml"), "/nonexistent/never.sqlite",
                  BatchOptions(workers=cap + 1))
    res = cli(["batch", "quickstart", "--out", "/nonexistent/never.sqlite", "--workers", "100000"], timeout=60)
    one_line_exit_2(res, "--workers", f"<= {cap}")
    assert not Path("/nonexistent").exists()


def test_over_long_output_paths_are_one_line_errors(tmp_path):
    long_name = "x" * 300
    one_line_exit_2(cli(["run", "quickstart", "--trace", str(tmp_path / (long_name + ".npz"))]), "--trace",
                    "255 bytes")
    deep = tmp_path / "/".join(["d" * 200] * 25) / "t.npz"
    one_line_exit_2(cli(["run", "quickstart", "--trace", str(deep)]), "--trace", "4096 bytes")
    one_line_exit_2(cli(["batch", "quickstart", "--out", str(tmp_path / long_name)]), "--out", "255 bytes")
    store = tmp_path / "none.sqlite"
    one_line_exit_2(cli(["evaluate", str(store), "--plots", str(tmp_path / long_name)]), "--plots", "255 bytes")
    one_line_exit_2(cli(["export", str(store), "--csv", str(tmp_path / (long_name + ".csv"))]), "--csv",
                    "255 bytes")


def test_an_unwritable_trace_folder_fails_before_the_trial_flies(monkeypatch):
    import pbdyn.sim.trial as trial_mod
    from pbdyn import api

    flown = []
    monkeypatch.setattr(trial_mod, "run_trial", lambda *a, **k: flown.append(1))
    with pytest.raises(ConfigError) as info:       # /proc/self accepts no new file, not even from root
        api.run_trial("quickstart", trace="/proc/self/trace.npz")
    assert info.value.field == "trace" and "cannot be written" in str(info.value)
    assert not flown
