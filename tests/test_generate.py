"""`pbdyn generate --metric` (thesis 5-2-2): maps of a chosen difficulty, written as an ordinary scenario file whose
maps are re-measured, flown and batched like any other; explicit map lists ([[obstacles.maps]])."""

from __future__ import annotations

import json
import subprocess
import tomllib

import pytest

import pbdyn
from pbdyn.config import parse_scenario
from pbdyn.world.maps import enumerate_maps
from tests.conftest import pbdyn_cmd


def cli(args, cwd, timeout=600):
    return subprocess.run(pbdyn_cmd() + args, capture_output=True, text=True, cwd=cwd, timeout=timeout)


def generate(tmp_path, *extra, out="suite.toml"):
    return cli(["generate", "--metric", "survivability", "--target", "5.0", "--tolerance", "0.2", "--count", "4",
                "--out", out, "--json", *extra], tmp_path)


@pytest.fixture(scope="module")
def suite(tmp_path_factory):
    d = tmp_path_factory.mktemp("gen")
    res = generate(d, "--workers", "1")
    assert res.returncode == 0, res.stderr
    assert res.stderr == ""
    return d, json.loads(res.stdout)


def test_generated_maps_hit_the_target_when_measured_again_in_a_fresh_process(suite):
    d, doc = suite
    assert doc["maps"] == 4 and doc["candidates"] >= 4
    text = (d / "suite.toml").read_text()
    listed = tomllib.loads(text)["obstacles"]["maps"]
    assert len(listed) == 4
    for i, entry in enumerate(listed):
        res = cli(["metrics", "suite.toml", "--map", str(i), "--metric", "survivability", "--json"], d)
        assert res.returncode == 0, res.stderr
        value = json.loads(res.stdout)["metrics"]["survivability"]["value"]
        assert abs(value - 5.0) <= 0.2
        assert value == entry["measured"]["survivability"] == doc["values"][i]
        assert 10 <= entry["count"] <= 30 and 0.5 <= entry["radius"] <= 1.5 and 2.0 <= entry["speed"] <= 6.0


def test_a_generated_suite_flies_and_batches_like_any_scenario(suite, tmp_path):
    d, _ = suite
    res = cli(["run", str(d / "suite.toml"), "--map", "3", "--json"], tmp_path)
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["map_index"] == 3
    res = cli(["batch", str(d / "suite.toml"), "--out", "b.sqlite", "--limit", "3", "--workers", "1",
               "--no-metrics", "--json"], tmp_path)
    assert res.returncode == 0, res.stderr
    sc = pbdyn.load_scenario(d / "suite.toml")
    maps = enumerate_maps(sc)
    assert len(maps) == 4
    entry = tomllib.loads((d / "suite.toml").read_text())["obstacles"]["maps"][1]
    assert maps[1].seed == entry["seed"] and maps[1].replicate == entry["replicate"]
    assert maps[1].setup == {k: entry[k] for k in ("count", "radius", "speed", "structure")}


def test_generate_is_deterministic_across_processes_and_worker_counts(suite, tmp_path):
    d, _ = suite
    res = generate(tmp_path, "--workers", "2", out="again.toml")
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "again.toml").read_bytes() == (d / "suite.toml").read_bytes()


def test_an_unreachable_target_is_refused_with_the_family_range(tmp_path):
    res = cli(["generate", "--metric", "survivability", "--target", "11.9", "--tolerance", "0.05", "--count", "3",
               "--out", "x.toml", "--workers", "1"], tmp_path)
    assert res.returncode == 2 and res.stdout == ""
    line = res.stderr.strip()
    assert "\n" not in line and line.startswith("pbdyn: error: --target:")
    assert "outside what family 'uniform' reaches" in line and " to " in line
    assert list(tmp_path.iterdir()) == []


def test_fixed_values_and_another_family_in_3d(tmp_path):
    res = pbdyn.generate_maps(tmp_path / "walls.toml", metric="density", target=0.02, tolerance=0.004, count=3,
                              family="walls", fixed={"count": 12}, workers=1)
    assert len(res.maps) == 3 and all(m.count == 12 for m in res.maps)
    sc = pbdyn.load_scenario(tmp_path / "walls.toml")
    for i in range(3):
        got = pbdyn.compute_metrics(sc, map=i, metrics="density")["density"]["value"]
        assert abs(got - 0.02) <= 0.004 and sc.obstacles.maps[i].structure == "walls"
    res3 = pbdyn.generate_maps(None, metric="survivability", target=11.0, tolerance=0.3, count=2, dims=3,
                               workers=1)
    doc = res3.document
    assert doc["world"]["dims"] == 3 and all(abs(v - 11.0) <= 0.3 for v in res3.summary()["values"])
    assert len(enumerate_maps(parse_scenario(doc))) == 2


def test_explicit_map_lists_are_the_grid_maps_and_are_checked(tmp_path):
    grid = pbdyn.load_scenario({"obstacles": {"count": [12, 20], "radius": 1.0, "speed": 4.0, "maps_per_setup": 3,
                                              "root_seed": 7}})
    listed = pbdyn.load_scenario({"obstacles": {"root_seed": 7, "maps": [
        {"count": 20, "radius": 1.0, "speed": 4.0, "replicate": 2},
        {"count": 12, "radius": 1.0, "speed": 4.0, "replicate": 0}]}})
    g, m = enumerate_maps(grid), enumerate_maps(listed)
    assert (m[0].key, m[0].seed) == (g[5].key, g[5].seed) and (m[1].key, m[1].seed) == (g[0].key, g[0].seed)
    a = pbdyn.rollout(listed, map=0)
    b = pbdyn.rollout(grid, map=5)
    assert (a.positions == b.positions).all()
    with pytest.raises(pbdyn.ConfigError, match=r"obstacles.maps\[0\].seed"):
        pbdyn.load_scenario({"obstacles": {"root_seed": 8, "maps": [
            {"count": 20, "radius": 1.0, "speed": 4.0, "replicate": 2, "seed": m[0].seed}]}})
    with pytest.raises(pbdyn.ConfigError, match="obstacles.count: is not used when obstacles.maps"):
        pbdyn.load_scenario({"obstacles": {"count": 3, "maps": [{"count": 20, "radius": 1.0, "speed": 4.0}]}})
    with pytest.raises(pbdyn.ConfigError, match=r"obstacles.maps\[1\]: is the same map as obstacles.maps\[0\]"):
        pbdyn.load_scenario({"obstacles": {"maps": [{"count": 2, "radius": 1.0, "speed": 4.0},
                                                    {"count": 2, "radius": 1.0, "speed": 4.0}]}})
    with pytest.raises(pbdyn.ConfigError, match=r"obstacles.maps\[0\].structure: unknown structure"):
        pbdyn.load_scenario({"obstacles": {"maps": [{"count": 2, "radius": 1.0, "speed": 4.0, "structure": "x"}]}})


def test_bad_generate_input_is_one_line(tmp_path):
    for args, flag in ((["--family", "nope"], "--family"), (["--metric", "nope"], "--metric"),
                       (["--tolerance", "-1"], "--tolerance"), (["--out", "x.txt"], "--out"),
                       (["--obstacles", "0"], "--obstacles")):
        base = {"--metric": "survivability", "--target": "5", "--tolerance": "0.2", "--count": "2",
                "--out": "s.toml", "--workers": "1"}
        for k, v in zip(args[::2], args[1::2]):
            base[k] = v
        res = cli(["generate", *[x for kv in base.items() for x in kv]], tmp_path)
        assert res.returncode == 2 and res.stderr.count("\n") == 1 and flag in res.stderr, (args, res.stderr)
        assert list(tmp_path.iterdir()) == []
