"""Results never mix (integrity round 3): a world whose code or files changed refuses to extend a store until
`--rerun-changed` re-flies its maps, and `pbdyn merge` refuses stores flown with other planner or world code."""

from __future__ import annotations

import json
import os
import sqlite3
import subprocess
from pathlib import Path

import pytest

from pbdyn.experiments.store import ResultsStore
from tests.conftest import ROOT, pbdyn_cmd
from tests.helpers import child_pids, process_running

MOTION = """
import math


def orbit(t, *, center=(25.0, 30.0, 2.0), radius=3.0, period=10.0):
    a = 2.0 * math.pi * t / period
    return [center[0] + radius * math.cos(a), center[1] + radius * math.sin(a), center[2]]
"""

WORLD = """
name = "fp_world"
[world]
dims = 2
size = [50.0, 50.0]
time_limit = 20.0
flight_height = 2.0
[drone]
v_max = [4.0]
[task]
candidates = [[4.0, 4.0], [46.0, 46.0], [4.0, 46.0]]
[[bodies]]
name = "crate"
urdf = "crate.urdf"
position = [30.0, 14.0, 1.5]
[[bodies]]
name = "mover"
urdf = "crate.urdf"
motion = "fpworld_motion:orbit"
[[planners]]
trajectory = "local_primitives"
gaze = "lookahead"
"""


def _crate(size: float = 2.0) -> str:
    return f"""<robot name="crate"><link name="base"><inertial><mass value="0"/><inertia ixx="0" ixy="0" ixz="0"
iyy="0" iyz="0" izz="0"/></inertial><collision><geometry><box size="{size} {size} 3"/></geometry></collision>
</link></robot>"""


def batch(args, env):
    return subprocess.run(pbdyn_cmd() + ["batch", *args], capture_output=True, text=True, timeout=600, env=env)


def rows(path: Path) -> dict[str, tuple]:
    with sqlite3.connect(f"file:{path}?mode=ro", uri=True) as c:
        return {r[0]: r[1:] for r in c.execute("SELECT trial_key, map_id, world_fingerprint, outcome, reason "
                                               "FROM trials")}


@pytest.fixture()
def world(tmp_path):
    (tmp_path / "mods").mkdir()
    (tmp_path / "mods" / "fpworld_motion.py").write_text(MOTION)
    (tmp_path / "crate.urdf").write_text(_crate())
    sc = tmp_path / "world.toml"
    sc.write_text(WORLD)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path / "mods"), str(ROOT)]))
    return tmp_path, sc, env


def test_an_edited_motion_module_refuses_to_extend_the_store_until_rerun_changed(world):
    tmp_path, sc, env = world
    out = tmp_path / "w.sqlite"
    args = [str(sc), "--out", str(out), "--workers", "1", "--json"]
    res = batch(args, env)
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["ran"] == 6
    before = rows(out)
    fps = {r[1] for r in before.values()}
    assert len(before) == 6 and len(fps) == 1 and len(next(iter(fps))) == 16
    with sqlite3.connect(out) as c:
        (rkey,) = c.execute("SELECT rollout_key FROM maps").fetchone()
    assert rkey.startswith(next(iter(fps)))

    # the same behaviour module with a changed orbit: the world differs, the scenario file does not
    (tmp_path / "mods" / "fpworld_motion.py").write_text(MOTION.replace("radius=3.0", "radius=6.0"))
    res = batch(args, env)
    assert res.returncode == 2 and res.stdout == ""
    line = res.stderr.strip()
    assert "\n" not in line and line.startswith("pbdyn: error:")
    assert "bodies[1] (mover): its motion module (fpworld_motion:orbit)" in line and "--rerun-changed" in line
    assert "6 trials" in line
    assert rows(out) == before                                   # refused before anything was written

    res = batch(args + ["--rerun-changed"], env)
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["ran"] == 6 and doc["maps_computed"] == 1
    after = rows(out)
    assert len(after) == 6 and not set(after) & set(before)      # the old world's rows are gone, none left beside
    new_fp = {r[1] for r in after.values()}
    assert len(new_fp) == 1 and new_fp != fps
    with sqlite3.connect(out) as c:
        (rkey2,) = c.execute("SELECT rollout_key FROM maps").fetchone()
        assert c.execute("SELECT COUNT(*) FROM maps").fetchone()[0] == 1
    assert rkey2.startswith(next(iter(new_fp)))                  # the map's metrics are the new world's
    res = batch(args, env)
    assert res.returncode == 0 and json.loads(res.stdout)["ran"] == 0

    (tmp_path / "crate.urdf").write_text(_crate(2.5))             # a world file changed
    res = batch(args, env)
    assert res.returncode == 2
    assert "bodies[0] (crate): its URDF or meshes (crate.urdf)" in res.stderr
    assert "bodies[1] (mover): its URDF or meshes" in res.stderr and "motion module" not in res.stderr


def test_a_store_from_before_world_fingerprints_is_judged_by_its_maps_rollout_keys(world):
    tmp_path, sc, env = world
    out = tmp_path / "w.sqlite"
    args = [str(sc), "--out", str(out), "--workers", "1", "--json", "--limit", "2"]
    assert batch(args, env).returncode == 0
    with sqlite3.connect(out) as c:                               # as schema 3 wrote it
        c.execute("ALTER TABLE trials DROP COLUMN world_fingerprint")
        c.execute("DELETE FROM meta WHERE key = 'world'")
        c.execute("UPDATE meta SET value = '3' WHERE key = 'schema_version'")
    (tmp_path / "mods" / "fpworld_motion.py").write_text(MOTION.replace("period=10.0", "period=7.0"))
    res = batch(args[:-2], env)
    assert res.returncode == 2 and "--rerun-changed" in res.stderr and "map(s) 0" in res.stderr


def _merge(out, *inputs):
    return subprocess.run(pbdyn_cmd() + ["merge", *map(str, inputs), "--out", str(out), "--json"],
                          capture_output=True, text=True, timeout=300)


def test_merge_refuses_stores_flown_in_different_worlds(world):
    tmp_path, sc, env = world
    a, b = tmp_path / "a.sqlite", tmp_path / "b.sqlite"
    assert batch([str(sc), "--out", str(a), "--workers", "1", "--limit", "3", "--no-metrics"], env).returncode == 0
    (tmp_path / "mods" / "fpworld_motion.py").write_text(MOTION.replace("radius=3.0", "radius=5.0"))
    res = batch([str(sc), "--out", str(b), "--workers", "1", "--no-metrics"], env)
    assert res.returncode == 0, res.stderr
    res = _merge(tmp_path / "m.sqlite", a, b)
    assert res.returncode == 2 and res.stdout == ""
    line = res.stderr.strip()
    assert "\n" not in line and "world" in line and "map 0" in line and "b.sqlite" in line
    assert not (tmp_path / "m.sqlite").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".m.sqlite")]


def test_merge_refuses_one_planner_label_flown_with_two_codes(tmp_path):
    plug = tmp_path / "plug"
    plug.mkdir()
    (plug / "mergeplug_mod.py").write_text("from pbdyn.planning.straight_line import StraightLine\n\n\n"
                                           "class Straight(StraightLine):\n    pass\n")
    sc = tmp_path / "s.toml"
    sc.write_text('name = "m"\n[world]\ntime_limit = 10.0\n[obstacles]\ncount = 4\nmaps_per_setup = 2\n'
                  '[drone]\nv_max = [4.0]\n[task]\ncandidates = [[4.0, 4.0], [46.0, 46.0]]\n'
                  '[[planners]]\ntrajectory = "mergeplug_mod:Straight"\ngaze = "lookahead"\n')
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(plug), str(ROOT)]))
    a, b = tmp_path / "a.sqlite", tmp_path / "b.sqlite"
    base = [str(sc), "--workers", "1", "--no-metrics"]
    assert batch(base + ["--out", str(a), "--shard", "1/2"], env).returncode == 0
    (plug / "mergeplug_mod.py").write_text((plug / "mergeplug_mod.py").read_text() + "# edited\n")
    assert batch(base + ["--out", str(b), "--shard", "2/2"], env).returncode == 0
    res = _merge(tmp_path / "m.sqlite", a, b)
    assert res.returncode == 2, res.stdout
    line = res.stderr.strip()
    assert "\n" not in line and "lookahead+mergeplug_mod:Straight" in line and "planner" in line
    assert not (tmp_path / "m.sqlite").exists()
    # the same code in both: the shards merge
    c = tmp_path / "c.sqlite"
    assert batch(base + ["--out", str(c), "--shard", "1/2"], env).returncode == 0
    res = _merge(tmp_path / "m.sqlite", c, b)
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["trials"] == 4
    store = ResultsStore.open(tmp_path / "m.sqlite")
    try:
        assert store.count() == 4
    finally:
        store.close()


def _inflated_pair(tmp_path, rows_each: int = 60000):
    """Two stores of one small experiment, each inflated with ``rows_each`` synthetic trial rows (distinct keys,
    small JSON) so that merging them takes long enough to be interrupted."""
    sc = tmp_path / "s.toml"
    sc.write_text('name = "m"\n[world]\ntime_limit = 10.0\n[obstacles]\ncount = 4\nmaps_per_setup = 1\n'
                  '[drone]\nv_max = [4.0]\n[task]\ncandidates = [[4.0, 4.0], [46.0, 46.0]]\n'
                  '[[planners]]\ntrajectory = "straight_line"\ngaze = "lookahead"\n')
    a = tmp_path / "a.sqlite"
    assert batch([str(sc), "--out", str(a), "--workers", "1", "--no-metrics"], dict(os.environ)).returncode == 0
    with sqlite3.connect(a) as c:
        cols = [r[1] for r in c.execute("PRAGMA table_info(trials)")]
        sel = ", ".join("trial_key || '-' || x" if n == "trial_key" else "'{}'" if n == "result_json" else n
                        for n in cols)
        c.execute(f"INSERT INTO trials ({', '.join(cols)}) SELECT {sel} FROM trials, (WITH RECURSIVE s(x) AS "
                  f"(SELECT 1 UNION ALL SELECT x + 1 FROM s WHERE x < {rows_each // 2}) SELECT x FROM s)")
    b = tmp_path / "b.sqlite"
    b.write_bytes(a.read_bytes())
    with sqlite3.connect(b) as c:
        c.execute("UPDATE trials SET trial_key = trial_key || 'b'")
    return a, b


def _temps(folder: Path, name: str) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith(f".{name}.merging-"))


def _start_merge_and_wait_for_its_temp(tmp_path, a, b, out):
    import time

    proc = subprocess.Popen(pbdyn_cmd() + ["merge", str(a), str(b), "--out", str(out)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not _temps(tmp_path, out.name):
        assert proc.poll() is None and time.monotonic() < deadline, "the merge ended before it could be stopped"
        time.sleep(0.01)
    time.sleep(0.2)
    return proc


@pytest.mark.parametrize("sig, status", [("SIGINT", 130), ("SIGTERM", 143)])
def test_a_merge_stopped_by_a_signal_leaves_nothing_behind(tmp_path, sig, status):
    import signal

    a, b = _inflated_pair(tmp_path)
    out = tmp_path / "m.sqlite"
    proc = _start_merge_and_wait_for_its_temp(tmp_path, a, b, out)
    proc.send_signal(getattr(signal, sig))
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == status, err
    assert err.strip().count("\n") == 0 and f"merge stopped by {sig}" in err and "Traceback" not in err
    assert not out.exists() and _temps(tmp_path, out.name) == []


def test_a_killed_merge_leaves_temp_files_that_the_next_merge_removes(tmp_path):
    import signal

    a, b = _inflated_pair(tmp_path)
    out = tmp_path / "m.sqlite"
    proc = _start_merge_and_wait_for_its_temp(tmp_path, a, b, out)
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=60)
    left = _temps(tmp_path, out.name)
    assert left and not out.exists()
    res = _merge(out, a, b)
    assert res.returncode == 0, res.stderr
    assert _temps(tmp_path, out.name) == [] and out.exists()




def test_workers_exit_when_their_coordinator_is_killed(tmp_path):
    import signal
    import time

    sc = tmp_path / "s.toml"
    sc.write_text('name = "k"\n[obstacles]\ncount = 10\nmaps_per_setup = 4\n[drone]\nv_max = [2.0]\n'
                  '[[planners]]\ntrajectory = "local_primitives"\ngaze = "lookahead"\n')
    proc = subprocess.Popen(pbdyn_cmd() + ["batch", str(sc), "--out", str(tmp_path / "k.sqlite"), "--workers", "2",
                                           "--no-metrics"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 90
    while not (tmp_path / "k.sqlite").exists() or len(child_pids(proc.pid)) < 3:   # 2 workers + resource tracker
        assert proc.poll() is None and time.monotonic() < deadline, "the batch ended or never started its workers"
        time.sleep(0.1)
    time.sleep(1.0)
    kids = child_pids(proc.pid)
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)
    deadline = time.monotonic() + 10
    while any(process_running(k) for k in kids) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = [k for k in kids if process_running(k)]
    for k in left:
        os.kill(k, signal.SIGKILL)
    assert not left, f"{len(left)} of {len(kids)} child processes still ran 10 s after the coordinator's SIGKILL"


def test_evaluate_refuses_a_store_holding_two_worlds_under_one_map(world):
    tmp_path, sc, env = world
    out = tmp_path / "w.sqlite"
    assert batch([str(sc), "--out", str(out), "--workers", "1", "--limit", "4"], env).returncode == 0
    res = subprocess.run(pbdyn_cmd() + ["evaluate", str(out), "--bootstrap", "10", "--json"], capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    with sqlite3.connect(out) as c:            # rows of one map made in another world (a hand-joined store)
        c.execute("UPDATE trials SET world_fingerprint = '0123456789abcdef' WHERE rowid IN "
                  "(SELECT rowid FROM trials LIMIT 2)")
    res = subprocess.run(pbdyn_cmd() + ["evaluate", str(out), "--bootstrap", "10", "--json"], capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 2 and res.stdout == ""
    assert res.stderr.count("\n") == 1 and "map 0" in res.stderr and "two worlds" in res.stderr
