"""Predicted reference success (pbdyn.analysis.predict): its features, its fit, its shipped coefficients, the
`pbdyn metrics` line, and `pbdyn generate --success` (maps re-flown in a fresh process hit the target)."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

import pbdyn
from pbdyn.analysis.predict import fit_predictor, leave_one_group_out, load_predictor, map_sigma, split_half_reliability
from pbdyn.analysis.scale import reference_pairs
from pbdyn.metrics.features import FEATURES, MAP_METRICS, ROUTE_HORIZON_S, rollout_features
from pbdyn.metrics.features import map_features as _map_features
from pbdyn.metrics.catalog import INFO
from pbdyn.world.maps import enumerate_maps
from pbdyn.world.rollout import build_rollout
from tests.conftest import ROOT, pbdyn_cmd

CAL_2D = ROOT / "scenarios" / "calibration" / "calibration_2d.toml"
CAL_3D = ROOT / "scenarios" / "calibration" / "calibration_3d.toml"
DATA = ROOT / "pbdyn" / "analysis" / "data"


def map_features(sc, index):
    return _map_features(sc, index, reference_pairs(sc.task.candidates))


def cli(args, cwd, timeout=900):
    return subprocess.run(pbdyn_cmd() + args, capture_output=True, text=True, cwd=cwd, timeout=timeout)


def test_features_from_the_cache_equal_features_from_a_fresh_rollout():
    sc = pbdyn.load_scenario(CAL_2D)
    horizon = max([INFO[m].horizon_s for m in MAP_METRICS] + [ROUTE_HORIZON_S]) + sc.world.dt
    for index in (0, 24):                                     # uniform; walls (route detours around the walls)
        cached = map_features(sc, index)
        fresh = rollout_features(sc, build_rollout(sc, enumerate_maps(sc)[index], horizon),
                                 reference_pairs(sc.task.candidates))
        assert cached == fresh and set(cached) == set(FEATURES)
    walls = map_features(sc, 24)
    assert walls["route_detour"] > 1.05 and walls["static_share"] > 0
    assert map_features(sc, 0)["route_detour"] == pytest.approx(1.0, abs=1e-3)


def test_the_fit_recovers_a_known_model_and_its_map_spread():
    rng = np.random.default_rng(5)
    n_maps, trials = 400, 180
    x = rng.normal(size=(n_maps, 2))
    eta = 0.3 + 1.2 * x[:, 0] - 0.7 * x[:, 1] + rng.normal(0.0, 0.5, n_maps)    # map-level spread 0.5 logits
    k = rng.binomial(trials, 1.0 / (1.0 + np.exp(-eta)))
    rows = [{"route_survivability": a, "route_detour": b, "k": int(kk), "n": trials, "dims": 2}
            for (a, b), kk in zip(x, k)]
    model = fit_predictor(rows, ("route_survivability", "route_detour"))
    sd = np.asarray(model.sd)
    slopes = np.asarray(model.coef[1:]) / sd
    assert slopes == pytest.approx([1.2, -0.7], abs=0.12)
    assert model.sigma == pytest.approx(0.5, abs=0.1)
    p, lo, hi = model.predict(rows)
    y = k / trials
    assert 0.9 <= np.mean((y >= lo) & (y <= hi)) <= 0.99          # the interval covers single maps
    assert map_sigma(k, np.full(n_maps, trials), np.log(p / (1 - p))) == pytest.approx(model.sigma)


def test_leave_one_group_out_never_sees_the_held_out_group():
    rng = np.random.default_rng(1)
    rows = [{"survivability": float(s), "k": int(rng.binomial(100, 0.5)), "n": 100, "dims": 2}
            for s in rng.normal(size=30)]
    groups = ["a"] * 10 + ["b"] * 10 + ["c"] * 10
    base = leave_one_group_out(rows, ("survivability",), groups)
    changed = [dict(r) for r in rows]
    for r in changed[:10]:                                    # group a's outcomes change: its own predictions don't
        r["k"] = 100 - r["k"]
    again = leave_one_group_out(changed, ("survivability",), groups)
    assert np.array_equal(base[:10], again[:10]) and not np.array_equal(base[10:], again[10:])


def test_split_half_reliability_tells_noise_from_signal():
    rng = np.random.default_rng(2)
    rates = np.linspace(0.1, 0.9, 12)
    signal = [np.stack([rng.binomial(9, p, 20), np.full(20, 9)], axis=1).astype(float) for p in rates]
    noise = [np.stack([rng.binomial(9, 0.5, 20), np.full(20, 9)], axis=1).astype(float) for _ in rates]
    assert split_half_reliability(signal, np.random.default_rng(0), 50) > 0.9
    assert abs(split_half_reliability(noise, np.random.default_rng(0), 50)) < 0.5


def test_the_shipped_predictor_reproduces_from_the_shipped_calibration_data():
    sys.path.insert(0, str(ROOT / "tools"))
    try:
        import fit_predictor as tool
    finally:
        sys.path.remove(str(ROOT / "tools"))
    shipped = json.loads((DATA / "predictor.json").read_text())["models"]
    refit = tool.fit_chosen(tool.table())["models"]
    assert set(refit) == set(shipped) and "2" in shipped
    for dims, again in refit.items():
        assert again["features"] == shipped[dims]["features"]
        assert np.allclose(again["coef"], shipped[dims]["coef"], rtol=0, atol=1e-9)
        assert np.allclose(again["cov"], shipped[dims]["cov"], rtol=0, atol=1e-9)
        assert again["sigma"] == pytest.approx(shipped[dims]["sigma"], abs=1e-9)
    with open(DATA / "calibration_features.csv") as fh:
        listed = {r["map_id"]: r for r in csv.DictReader(fh)}
    sc = pbdyn.load_scenario(CAL_2D)
    checked = 0
    for spec in enumerate_maps(sc)[::9]:                         # the shipped features are pbdyn's own, recomputed
        if spec.setup_id in listed:                              # (listed by the map id rule of their day)
            f = map_features(sc, spec.index)
            assert all(float(listed[spec.setup_id][k]) == f[k] for k in FEATURES), spec.index
            checked += 1
    assert checked >= 3


def test_pbdyn_metrics_prints_the_predicted_reference_success(tmp_path):
    res = cli(["metrics", str(CAL_2D), "--map", "24", "--metric", "survivability"], tmp_path)
    assert res.returncode == 0 and res.stderr == "", res.stderr
    line = [x for x in res.stdout.splitlines() if x.startswith("predicted reference success")]
    assert len(line) == 1 and "percentile" in line[0] and "[" in line[0]
    res = cli(["metrics", str(CAL_2D), "--map", "24", "--json"], tmp_path)
    pred = json.loads(res.stdout)["predicted_reference_success"]
    model = load_predictor(2)
    feats = map_features(pbdyn.load_scenario(CAL_2D), 24)
    p, lo, hi = model.predict([feats])
    assert pred["success"] == p[0] and pred["ci"] == [lo[0], hi[0]] and lo[0] < p[0] < hi[0]
    assert 0 <= pred["percentile"] <= 100
    three = tmp_path / "three.toml"
    three.write_text('name = "three"\n[world]\ndims = 3\n[obstacles]\ncount = [10]\nradius = 1.0\nspeed = 2.0\n')
    res = cli(["metrics", str(three), "--metric", "density"], tmp_path)
    assert res.returncode == 0, res.stderr
    line = [x for x in res.stdout.splitlines() if x.startswith("predicted reference success")]
    assert load_predictor(3) is not None and len(line) == 1 and "percentile" in line[0] and "outside" not in line[0]
    res = cli(["metrics", str(CAL_3D), "--map", "25", "--metric", "density"], tmp_path)     # a 3D walls map
    assert res.returncode == 0, res.stderr
    assert "outside" not in res.stdout and "predicted reference success" in res.stdout
    world = ROOT / "scenarios" / "worlds" / "imported_3d" / "hangar_0.toml"
    res = cli(["metrics", str(world), "--metric", "density"], tmp_path)                   # an imported 3D world
    assert res.returncode == 0, res.stderr
    assert "outside the 3D calibration set" in res.stdout


@pytest.fixture(scope="module")
def success_suite(tmp_path_factory):
    d = tmp_path_factory.mktemp("gen_success")
    res = cli(["generate", "--success", "0.5", "--tolerance", "0.1", "--count", "1", "--out", "s.toml", "--json",
               "--workers", "2"], d)
    assert res.returncode == 0, res.stderr
    assert res.stderr == ""
    return d, json.loads(res.stdout)


def test_success_mode_maps_hit_the_target_when_flown_again_in_a_fresh_process(success_suite):
    d, doc = success_suite
    assert doc["maps"] == 1 and doc["flown"] >= 1
    entry = tomllib.loads((d / "s.toml").read_text())["obstacles"]["maps"][0]
    measured = entry["measured"]
    assert abs(measured["reference_success"] - 0.5) <= 0.1
    assert measured["reference_success_lo"] <= measured["reference_success"] <= measured["reference_success_hi"]
    res = cli(["calibrate", "s.toml", "--store", "fresh.sqlite", "--json"], d)          # a new store: flown again
    assert res.returncode == 0, res.stderr
    again = json.loads(res.stdout)
    got = again[0] if isinstance(again, list) else again["maps"][0]
    assert got["success"] == measured["reference_success"]
    assert got["trials"] == 180


def test_success_mode_is_deterministic_and_refuses_unreachable_targets(success_suite, tmp_path):
    d, _ = success_suite
    res = cli(["generate", "--success", "0.5", "--tolerance", "0.1", "--count", "1", "--out", "again.toml",
               "--workers", "1"], tmp_path)
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "again.toml").read_bytes() == (d / "s.toml").read_bytes()
    res = cli(["generate", "--success", "0.995", "--tolerance", "0.004", "--count", "2", "--family", "walls",
               "--out", "x.toml", "--workers", "1"], tmp_path)
    assert res.returncode == 2 and res.stdout == ""
    line = res.stderr.strip()
    assert "\n" not in line and line.startswith("pbdyn: error: --success:")
    assert "outside what family 'walls' reaches in 2D" in line and "predicted on" in line
    for args, flag in ((["--success", "0.5", "--metric", "survivability"], "--success"),
                       (["--success", "1.5"], "--success"), (["--target", "5"], "--metric"),
                       (["--success", "0.5", "--tolerance", "0.6"], "--tolerance")):
        base = ["generate", "--count", "1", "--out", "y.toml", "--workers", "1", *args]
        if "--tolerance" not in args:
            base += ["--tolerance", "0.1"]
        res = cli(base, tmp_path)
        assert res.returncode == 2 and res.stderr.count("\n") == 1 and flag in res.stderr, (args, res.stderr)
    assert not (tmp_path / "x.toml").exists() and not (tmp_path / "y.toml").exists()
    assert not Path(tmp_path / "again.toml.tmp").exists()


def test_the_study_picks_the_shipped_feature_set():
    """The leave-one-family-out study over the shipped calibration data chooses the shipped model."""
    sys.path.insert(0, str(ROOT / "tools"))
    try:
        import fit_predictor as tool
    finally:
        sys.path.remove(str(ROOT / "tools"))
    for dims, name in tool.CHOSEN.items():
        rows = [r for r in tool.table() if r["dims"] == dims]
        fam = [r["family"] if r["family"].startswith("imported") else f"{r['dims']}D {r['family']}" for r in rows]
        y = np.array([r["k"] / r["n"] for r in rows])
        assert tool.choose({"models": tool._scores(rows, fam, y)}) == name
        assert tuple(load_predictor(dims).features) == tool.CANDIDATES[name]


@pytest.mark.slow
def test_success_mode_in_3d_keeps_a_map_that_flies_within_the_tolerance_again(tmp_path):
    res = cli(["generate", "--success", "0.8", "--tolerance", "0.05", "--count", "1", "--dims", "3", "--family",
               "uniform", "--out", "s3.toml", "--json", "--workers", "2"], tmp_path)
    assert res.returncode == 0, res.stderr
    entry = tomllib.loads((tmp_path / "s3.toml").read_text())["obstacles"]["maps"][0]
    assert abs(entry["measured"]["reference_success"] - 0.8) <= 0.05
    res = cli(["calibrate", "s3.toml", "--store", "fresh.sqlite", "--json"], tmp_path)
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["maps"][0]["success"] == entry["measured"]["reference_success"]
