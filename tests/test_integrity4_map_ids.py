"""Integrity round 4: map ids that identify a map (pbdyn.world.maps.MAP_ID_RULE; docs/design.md "Maps and seeds").

A map id is derived from everything that makes the map, so two different maps never share one: the imported
worlds of pbdyn-2d-v1 (which shared one id under the rule before), scenarios that differ in anything that changes
their maps, a world whose URDF changed on disk. Stores record the rule, and a store of the rule before is refused
in one line rather than mixed."""

from __future__ import annotations

import json
import random
import shutil
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

import pbdyn
from pbdyn.benchmark.suite import flight_scenario, load_suite
from pbdyn.config import PlannerEntry
from pbdyn.world.maps import MAP_ID_RULE, enumerate_maps, world_digest

ROOT = Path(__file__).resolve().parents[1]


def _ids(doc) -> list[str]:
    return [m.map_id for m in enumerate_maps(pbdyn.load_scenario(doc))]


def test_the_imported_worlds_of_the_2d_suite_no_longer_share_an_id():
    suite = load_suite("pbdyn-2d-v1")
    entry = PlannerEntry("local_primitives", "lookahead")
    new, old = {}, {}
    for part in suite.parts:
        maps = enumerate_maps(flight_scenario(suite, part, [entry]))
        for m in suite.maps:
            if m["part"] == part.name:
                ms = maps[int(m["map_index"])]
                assert ms.setup_id == m["map_id"]                     # the v1 manifest names maps by setup-1
                new.setdefault(ms.map_id, []).append(part.name)
                old.setdefault(ms.setup_id, []).append(part.name)
    assert max(len(v) for v in old.values()) == 9                     # the collision the rule before had
    assert len(new) == len(suite.maps) and max(len(v) for v in new.values()) == 1


BASE = {"world": {"time_limit": 20.0}, "obstacles": {"count": [5, 8], "maps_per_setup": 2, "root_seed": 3}}


def _changed(change: dict) -> dict:
    """BASE with ``change``: a table's keys updated, a list (static obstacles, planners) replaced."""
    doc = json.loads(json.dumps(BASE))
    for table, values in change.items():
        if isinstance(values, dict):
            doc.setdefault(table, {}).update(values)
        else:
            doc[table] = values
    return doc


@pytest.mark.parametrize("change", [
    {"obstacles": {"root_seed": 4}}, {"world": {"size": [60.0, 60.0]}}, {"world": {"dt": 0.05}},
    {"obstacles": {"radius_jitter": 0.1}}, {"obstacles": {"motion": "rvo"}}, {"obstacles": {"speed": 2.5}},
    {"static_obstacles": [{"kind": "pillar", "center": [25.0, 15.0], "radius": 1.0}]},
    {"task": {"candidates": [[4.0, 4.0], [46.0, 46.0]]}}, {"drone": {"radius": 0.5}},
    {"task": {"spawn_clearance": 2.0}}])
def test_anything_that_changes_the_maps_changes_their_ids(change):
    assert not set(_ids(_changed(change))) & set(_ids(BASE))


@pytest.mark.parametrize("change", [{"world": {"time_limit": 30.0}}, {"drone": {"v_max": [2.0, 6.0]}},
                                    {"sensor": {"fov_deg": 120.0}},
                                    {"planners": [{"trajectory": "straight_line", "gaze": "fullrange"}]}])
def test_what_changes_only_the_trials_keeps_the_ids(change):
    assert _ids(_changed(change)) == _ids(BASE)


def test_an_imported_world_whose_urdf_changed_on_disk_gets_new_ids(tmp_path):
    world = ROOT / "scenarios" / "worlds" / "warehouse_2d.toml"
    shutil.copy(pbdyn.load_scenario(world).resolve_path("box.urdf"), tmp_path / "mybox.urdf")
    copy = tmp_path / "world.toml"
    copy.write_text(world.read_text().replace('urdf = "box.urdf"', 'urdf = "mybox.urdf"'))
    sc = pbdyn.load_scenario(copy)
    urdf = sc.resolve_path(sc.bodies[0].urdf)
    assert urdf.parent == tmp_path                      # the test edits its own copy, never a bundled file
    before = _ids(copy)
    urdf.write_text(urdf.read_text() + "\n<!-- an edit of the world's file -->\n")
    after = _ids(copy)
    assert len(before) == len(after) and not set(before) & set(after)


@pytest.mark.fuzz
def test_fuzz_map_ids_are_unique_across_random_scenarios_and_every_bundled_one():
    """Map-id uniqueness: maps of seeded random scenario variations and of every bundled scenario; one id never
    names two (world digest, key) pairs."""
    named: dict[str, tuple] = {}

    def add(sc):
        for m in list(enumerate_maps(sc))[:40]:
            got = named.setdefault(m.map_id, (m.world, m.key))
            assert got == (m.world, m.key), (m.map_id, sc.name)

    rng = random.Random(41)
    for _ in range(40):
        add(pbdyn.load_scenario({
            "world": {"size": [rng.choice([40.0, 50.0]), 50.0]},
            "obstacles": {"count": [rng.randint(1, 30)], "radius": rng.choice([0.5, 1.0]),
                          "speed": rng.choice([1.0, 2.0]), "root_seed": rng.randint(0, 3),
                          "motion": rng.choice(["cvm", "rvo"]), "maps_per_setup": 3}}))
    for path in sorted((ROOT / "scenarios").rglob("*.toml")):
        try:
            sc = pbdyn.load_scenario(path)
        except pbdyn.ConfigError:          # suite parts with relative worlds load through their suite
            continue
        add(sc)
    assert len(named) > 150


def _batch(args, cwd=ROOT) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pbdyn", *map(str, args)], capture_output=True, text=True,
                          timeout=600, cwd=cwd)


def test_a_store_records_its_id_rule_and_one_of_the_rule_before_is_refused_not_mixed(tmp_path):
    sc = tmp_path / "s.toml"
    sc.write_text('name = "ids"\n[world]\ntime_limit = 10.0\n[obstacles]\ncount = [4]\nmaps_per_setup = 2\n'
                  '[task]\ncandidates = [[4.0, 4.0], [46.0, 46.0]]\n'
                  '[[planners]]\ntrajectory = "straight_line"\ngaze = "lookahead"\n')
    out = tmp_path / "new.sqlite"
    args = ["batch", sc, "--workers", "1", "--no-metrics", "--json"]
    res = _batch(args + ["--out", out, "--limit", "2"])
    assert res.returncode == 0, res.stderr
    with sqlite3.connect(out) as c:
        assert c.execute("SELECT value FROM meta WHERE key = 'map_ids'").fetchone()[0] == MAP_ID_RULE
        ids = {r[0] for r in c.execute("SELECT map_id FROM trials")}
    sce = pbdyn.load_scenario(sc)
    assert ids <= {m.map_id for m in enumerate_maps(sce)}
    old = tmp_path / "old.sqlite"                                       # as an older pbdyn wrote it
    shutil.copy(out, old)
    with sqlite3.connect(old) as c:
        c.execute("DELETE FROM meta WHERE key = 'map_ids'")
        for m in enumerate_maps(sce):
            c.execute("UPDATE trials SET map_id = ? WHERE map_id = ?", (m.setup_id, m.map_id))
    before = old.read_bytes()
    res = _batch(args + ["--out", old])
    assert res.returncode == 2
    line = res.stderr.strip()
    assert "\n" not in line and "map id rule setup-1" in line and "new --out" in line
    assert old.read_bytes() == before
    res = _batch(["merge", out, old, "--out", tmp_path / "merged.sqlite"])
    assert res.returncode == 2 and "map id rule" in res.stderr and "\n" not in res.stderr.strip()
    assert not (tmp_path / "merged.sqlite").exists()
    res = _batch(["merge", out, "--out", tmp_path / "merged.sqlite", "--json"])
    assert res.returncode == 0, res.stderr
    with sqlite3.connect(tmp_path / "merged.sqlite") as c:
        assert c.execute("SELECT value FROM meta WHERE key = 'map_ids'").fetchone()[0] == MAP_ID_RULE


def test_the_gym_quotes_the_map_id_of_the_world_it_flies():
    import gymnasium

    env = gymnasium.make("pbdyn/Avoid2D-v0")
    try:
        _, info = env.reset(seed=0, options={"level": 9})
        suite = load_suite("pbdyn-2d-v1")
        ids = set()
        for part in suite.parts:
            sc = flight_scenario(suite, part, [PlannerEntry("local_primitives", "lookahead")])
            ids |= {m.map_id for m in enumerate_maps(sc)}
        assert info["map_id"] in ids
    finally:
        env.close()


def test_the_world_digest_is_the_same_in_a_fresh_process():
    code = ("import pbdyn; from pbdyn.world.maps import world_digest; "
            "print(world_digest(pbdyn.load_scenario('quickstart')))")
    outs = {subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                           env={**__import__("os").environ, "PYTHONHASHSEED": s}).stdout.strip() for s in ("1", "2")}
    assert outs == {world_digest(pbdyn.load_scenario("quickstart"))}
