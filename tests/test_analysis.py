"""Analysis (thesis 3-2, 4-2, 4-3, 5-2): Srcc, Cv, normalisation/reversal, bootstrap, within-setup Srcc, setup
baseline, sigma bands, eq. 5-1 regression, the report and its figures, on synthetic results tables whose ground
truth is known. Independent references: scipy.stats.spearmanr and plain numpy loops."""

from __future__ import annotations

import itertools
import json
import math

from pathlib import Path

import numpy as np
import pytest
from scipy.stats import spearmanr

from pbdyn.analysis.plots import write_plots
from pbdyn.analysis.regression import fit_linear, setup_features
from pbdyn.analysis.report import SETUP_MODEL, evaluate, format_table
from pbdyn.analysis.srcc import bootstrap_mean_srcc, spearman
from pbdyn.errors import ConfigError

TRAJS = ("local_primitives", "global_primitives")
GAZES = ("fullrange", "lookahead")
PAIRS = tuple(f"{g}+{t}" for g in GAZES for t in TRAJS)
FAILS = ("static_collision", "dynamic_collision", "freezing", "deadlock")
SETUPS = list(itertools.product((10, 20, 30), (0.5, 1.0, 1.5), (2.0, 4.0, 6.0)))


def hidden_difficulty(n, r, v, noise):
    """The synthetic ground truth: a map's difficulty from its setup plus a per-map (seed) part."""
    return 0.1 * n + 1.5 * r + 0.6 * v + noise


def p_success(h, j):
    """Success probability of pair j on a map of hidden difficulty h: strictly decreasing in h."""
    return 1.0 / (1.0 + np.exp(1.1 * (h - 6.5) - 0.4 * j))


def add_trials(trials, rng, map_id, entry, h, n_trials, *, force=None):
    """n_trials per pair on one map (two MAV speeds), outcomes drawn from p_success (or all ``force``)."""
    s = entry["setup"]
    for j, pair in enumerate(PAIRS):
        gaze, traj = pair.split("+")
        hits = rng.random(n_trials) < p_success(h, j)
        fail = rng.integers(0, len(FAILS), n_trials)
        for t in range(n_trials):
            outcome = force or ("success" if hits[t] else FAILS[fail[t]])
            trials.append({"map_id": map_id, "pair": pair, "trajectory": traj, "gaze": gaze,
                           "mav_speed": (2.0, 4.0)[t % 2], "outcome": outcome, "obstacle_count": s["count"],
                           "obstacle_radius": s["radius"], "obstacle_speed": s["speed"],
                           "dataset": entry["dataset"]})


def map_entry(dataset, n, r, v, h, rng, *, mean_speed=None):
    """A maps-table entry whose metrics are known functions of the hidden difficulty h and the setup."""
    metrics = {
        "survivability": 12.0 - 0.8 * h,                         # easier = higher: the "good" metric
        "density": n * math.pi * (r if not isinstance(r, dict) else 1.0) ** 2 / 2500.0,  # setup only, harder = higher
        "vo_feasibility": float(rng.random()),                   # unrelated to difficulty
    }
    return {"setup": {"count": n, "radius": r, "speed": v}, "dataset": dataset, "metrics": metrics,
            "metric_times": {"survivability": 2.0, "density": 0.01, "vo_feasibility": 0.5},
            "mean_obstacle_speed": float(v) if mean_speed is None else mean_speed,
            "mean_obstacle_radius": float(r) if not isinstance(r, dict) else 1.0}


def synthetic(seed=0, per_setup=4, n_trials=16, n_errors=7):
    """Controlled dataset (27 setups x per_setup maps) plus a speed-range dataset from the same model and a
    "shifted" dataset of easy maps whose flights all fail. Returns (trials, maps, hidden difficulty by map)."""
    rng = np.random.default_rng(seed)
    trials, maps, hidden = [], {}, {}
    for (n, r, v), rep in itertools.product(SETUPS, range(per_setup)):
        mid = f"c-{n}-{r}-{v}-{rep}"
        h = hidden_difficulty(n, r, v, rng.normal(0.0, 1.2))
        maps[mid], hidden[mid] = map_entry("controlled", n, r, v, h, rng), h
        add_trials(trials, rng, mid, maps[mid], h, n_trials)
    for i in range(18):
        n, r = (10, 20, 30)[i % 3], (0.5, 1.0, 1.5)[i // 6]
        vbar = float(rng.uniform(2.0, 6.0))
        mid = f"u-speed-{i}"
        h = hidden_difficulty(n, r, vbar, rng.normal(0.0, 1.2))
        maps[mid] = map_entry("speed_range", n, r, {"min": 2.0, "max": 6.0}, h, rng, mean_speed=vbar)
        hidden[mid] = h
        add_trials(trials, rng, mid, maps[mid], h, n_trials)
    for i in range(6):
        mid = f"u-shift-{i}"
        h = hidden_difficulty(10, 0.5, 2.0, 0.0)
        maps[mid], hidden[mid] = map_entry("shifted", 10, 0.5, 2.0, h, rng), h
        add_trials(trials, rng, mid, maps[mid], h, 4, force="dynamic_collision")
    for i in range(n_errors):
        bad = dict(trials[i * 97])
        bad["outcome"] = "error"
        trials.append(bad)
    return trials, maps, hidden


@pytest.fixture(scope="module")
def table():
    return synthetic()


@pytest.fixture(scope="module")
def report(table):
    trials, maps, _ = table
    return evaluate(trials, maps, n_boot=200, seed=3)


def rates_by_hand(trials, map_ids):
    """SR[maps, pairs] counted with plain loops ("error" trials left out)."""
    k = {(m, p): 0 for m in map_ids for p in PAIRS}
    n = dict(k)
    for t in trials:
        if t["outcome"] == "error" or (t["map_id"], t["pair"]) not in n:
            continue
        n[t["map_id"], t["pair"]] += 1
        k[t["map_id"], t["pair"]] += t["outcome"] == "success"
    return np.array([[k[m, p] / n[m, p] if n[m, p] else np.nan for p in PAIRS] for m in map_ids])


def controlled_ids(maps):
    return sorted(m for m, e in maps.items() if e["dataset"] == "controlled")


def test_srcc_and_orientation_match_scipy(table, report):
    trials, maps, _ = table
    ids = controlled_ids(maps)
    sr = rates_by_hand(trials, ids)
    for name, easier_is_higher in (("survivability", True), ("density", False), ("vo_feasibility", None)):
        raw = np.array([maps[m]["metrics"][name] for m in ids])
        ref = np.array([spearmanr(raw, sr[:, j]).statistic for j in range(len(PAIRS))])
        row = report["metrics"][name]
        # eq. 4-11: reversed exactly when the normalised metric correlates positively with success (eq. 3-9 mean)
        assert row["normalisation"]["reversed"] == bool(ref.mean() > 0)
        if easier_is_higher is not None:
            assert row["normalisation"]["reversed"] == easier_is_higher
        assert row["normalisation"]["min"] == pytest.approx(raw.min())
        assert row["normalisation"]["max"] == pytest.approx(raw.max())
        # reported srcc = -Srcc(difficulty, SR): +Srcc(raw, SR) if reversed, else -Srcc(raw, SR)
        expect = ref if row["normalisation"]["reversed"] else -ref
        got = np.array([row["srcc_per_pair"][p] for p in PAIRS])
        np.testing.assert_allclose(got, expect, atol=1e-12)
        assert row["srcc_mean"] == pytest.approx(expect.mean(), abs=1e-12)
        assert row["srcc_std"] == pytest.approx(expect.std(), abs=1e-12)
    assert report["metrics"]["survivability"]["srcc_mean"] > 0.8
    assert abs(report["metrics"]["vo_feasibility"]["srcc_mean"]) < 0.3


def test_spearman_degenerate_and_broadcast():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(5, 40))
    y = rng.normal(size=(5, 40))
    x[2, :10] = x[2, 10:20]                                   # ties
    y[3, 7] = np.nan                                          # pairwise omission
    ref = [spearmanr(x[i], y[i], nan_policy="omit").statistic for i in range(5)]
    np.testing.assert_allclose(spearman(x, y), ref, atol=1e-12)
    assert spearman(np.ones(10), np.arange(10.0)) == 0.0       # constant metric: no ranking information
    assert np.isnan(spearman(np.arange(10.0), np.ones(10)))    # constant success: undefined


def test_bootstrap_by_multiplicities_equals_resampling():
    """The bootstrap evaluates draws as map multiplicities; it must equal scipy's Srcc on the materialised
    resamples (ties from duplicated maps and from the values, NaN holes), averaged over pairs (eq. 3-9)."""
    rng = np.random.default_rng(2)
    d = np.round(rng.random(25), 1)
    rate = np.round(rng.random((25, 3)), 1)
    rate[4, 1] = np.nan
    d[9] = np.nan
    got = bootstrap_mean_srcc(d, rate, np.random.default_rng(11), 40)
    idx = np.random.default_rng(11).integers(0, 25, size=(40, 25))
    ref = [np.nanmean([spearmanr(d[i], rate[i, j], nan_policy="omit").statistic for j in range(3)]) for i in idx]
    np.testing.assert_allclose(got, ref, atol=1e-12)


def test_metric_equal_to_hidden_difficulty_ranks_perfectly():
    """Success counts strictly decreasing in a hidden difficulty h: a metric monotone in h has |Srcc| = 1 with
    either raw direction; after eq. 4-11 its difficulty increases with h, so Srcc(difficulty, SR) = -1 and the
    reported (thesis-sign) srcc = +1."""
    trials, maps = [], {}
    for i in range(30):
        mid = f"m{i:02d}"
        maps[mid] = {"setup": {"count": 10 + i, "radius": 1.0, "speed": 2.0}, "dataset": "controlled",
                     "metrics": {"survivability": 100.0 - 3.0 * i, "density": float(i * i)},
                     "metric_times": {}, "mean_obstacle_speed": 2.0, "mean_obstacle_radius": 1.0}
        for j, pair in enumerate(PAIRS[:2]):
            for t in range(40):
                trials.append({"map_id": mid, "pair": pair, "trajectory": pair.split("+")[1],
                               "gaze": pair.split("+")[0], "mav_speed": 2.0,
                               "outcome": "success" if t < 40 - i - j else "deadlock"})
    rep = evaluate(trials, maps, n_boot=50)
    for name, rev in (("survivability", True), ("density", False)):
        row = rep["metrics"][name]
        assert row["normalisation"]["reversed"] is rev
        assert row["srcc_mean"] == pytest.approx(1.0)
        assert row["srcc_std"] == pytest.approx(0.0)
        assert row["srcc_ci95"] == [pytest.approx(1.0), pytest.approx(1.0)]


def normalised_by_hand(raw):
    """Eq. 4-10 over the controlled maps."""
    return (raw - raw.min()) / (raw.max() - raw.min()) * 10.0


def test_cv_per_level_matches_loops(table, report):
    trials, maps, _ = table
    ids = controlled_ids(maps)
    sr = rates_by_hand(trials, ids)
    for name in ("survivability", "density", "vo_feasibility"):
        row = report["metrics"][name]
        raw = np.array([maps[m]["metrics"][name] for m in ids])
        d = normalised_by_hand(raw)
        if row["normalisation"]["reversed"]:
            d = 10.0 - d
        cv = np.full((10, len(PAIRS)), np.nan)
        for k in range(10):
            in_k = (d >= k) & ((d < k + 1) if k < 9 else (d <= 10.0))
            for j in range(len(PAIRS)):
                vals = sr[in_k, j]
                if vals.size >= 2 and vals.mean() > 0:
                    cv[k, j] = np.std(vals) / np.mean(vals)
        per_pair = np.array([np.mean(cv[np.isfinite(cv[:, j]), j]) for j in range(len(PAIRS))])
        got_pair = np.array([row["cv_per_pair"][p] for p in PAIRS])
        np.testing.assert_allclose(got_pair, per_pair, atol=1e-12)
        assert row["cv_mean"] == pytest.approx(per_pair.mean(), abs=1e-12)
        assert row["cv_std"] == pytest.approx(per_pair.std(), abs=1e-12)
        for k in range(10):
            v = cv[k][np.isfinite(cv[k])]
            got = row["cv_per_level"][str(k)]
            if v.size:
                assert got == pytest.approx(v.mean(), abs=1e-12)
            else:
                assert got is None
    # the good metric groups maps of similar success: lower Cv than the unrelated one
    assert report["metrics"]["survivability"]["cv_mean"] < report["metrics"]["vo_feasibility"]["cv_mean"]


def test_within_setup_srcc_separates_setup_only_metrics(table, report):
    trials, maps, hidden = table
    m = report["metrics"]
    # density is a function of (n, r) only and setup_model of (n, r, v): constant within a setup -> exactly 0,
    # although they rank maps across setups well
    assert m["density"]["within_setup_srcc"] == 0.0
    assert m[SETUP_MODEL]["within_setup_srcc"] == 0.0
    assert m["density"]["srcc_mean"] > 0.3 and m[SETUP_MODEL]["srcc_mean"] > 0.6
    assert m["survivability"]["srcc_mean"] > m[SETUP_MODEL]["srcc_mean"] + 0.1
    assert m["survivability"]["within_setup_n_setups"] == 27
    # the per-map (seed) part of the hidden difficulty is what survivability sees beyond its setup
    assert m["survivability"]["within_setup_srcc"] > 0.4
    # a setup function plus noise unrelated to success: within-setup ~ 0, overall still high
    rng = np.random.default_rng(9)
    maps2 = {k: {**e, "metrics": {"density": e["metrics"]["density"] + 1e-4 * rng.random()}} for k, e in maps.items()}
    rep2 = evaluate(trials, maps2, n_boot=0)
    assert abs(rep2["metrics"]["density"]["within_setup_srcc"]) < 0.12
    assert rep2["metrics"]["density"]["srcc_mean"] > 0.3
    assert rep2["metrics"]["density"]["srcc_ci95"] == [None, None]


def test_bootstrap_interval(table, report):
    trials, maps, _ = table
    row = report["metrics"]["survivability"]
    lo, hi = row["srcc_ci95"]
    assert lo < row["srcc_mean"] < hi and hi - lo < 0.2
    again = evaluate(trials, maps, n_boot=200, seed=3)
    assert again["metrics"]["survivability"]["srcc_ci95"] == row["srcc_ci95"]
    other = evaluate(trials, maps, n_boot=200, seed=4)
    assert other["metrics"]["survivability"]["srcc_ci95"] != row["srcc_ci95"]


def test_regression_recovers_known_coefficients():
    rng = np.random.default_rng(5)
    x = np.column_stack([rng.integers(10, 31, 200), rng.uniform(0.5, 1.5, 200), rng.uniform(2, 6, 200)])
    y = 1.0 + 0.2 * x[:, 0] - 3.0 * x[:, 1] + 0.5 * x[:, 2] + rng.normal(0, 0.05, 200)
    fit = fit_linear(x, y)
    np.testing.assert_allclose(fit.coefficients, [1.0, 0.2, -3.0, 0.5], atol=0.05)
    assert 0.95 < fit.r2 < 1.0

    # through the report: survivability exactly linear in the setup -> table 5-4 line recovered with R^2 = 1
    trials, maps = [], {}
    rng = np.random.default_rng(6)
    for (n, r, v), rep in itertools.product(SETUPS, range(2)):
        mid = f"{n}-{r}-{v}-{rep}"
        surv = 30.0 - (0.3 * n + 4.0 * r + 1.5 * v)
        maps[mid] = {"setup": {"count": n, "radius": r, "speed": v}, "dataset": "controlled",
                     "metrics": {"survivability": surv}, "metric_times": {"survivability": 1.0},
                     "mean_obstacle_speed": v, "mean_obstacle_radius": r + 0.01 * rep}
        add_trials(trials, rng, mid, {"setup": maps[mid]["setup"], "dataset": "controlled"},
                   hidden_difficulty(n, r, v, 0.0), 4)
    rep = evaluate(trials, maps, n_boot=0)
    s = np.array([e["metrics"]["survivability"] for e in maps.values()])
    span = s.max() - s.min()
    g = rep["regression"]
    assert rep["metrics"]["survivability"]["normalisation"]["reversed"] is True
    expect = [10.0 * (s.max() - 30.0) / span, 3.0 / span, 40.0 / span, 15.0 / span]   # difficulty = 10 (max - S)/span
    got = [g["coefficients"][f"b{i}"] for i in range(4)]
    np.testing.assert_allclose(got, expect, atol=1e-9)
    assert g["r2"] == pytest.approx(1.0)
    raw = rep["regression_raw"]["coefficients"]
    np.testing.assert_allclose([raw[f"b{i}"] for i in range(4)], [30.0, -0.3, -4.0, -1.5], atol=1e-9)


def test_setup_features_use_actual_means_for_ranges():
    scalar = {"setup": {"count": 20, "radius": 1.0, "speed": 4.0}, "mean_obstacle_radius": 1.07,
              "mean_obstacle_speed": 4.0}
    ranged = {"setup": {"count": 10, "radius": {"min": 0.5, "max": 1.5}, "speed": {"min": 2.0, "max": 6.0}},
              "mean_obstacle_radius": 0.8, "mean_obstacle_speed": 5.1}
    np.testing.assert_allclose(setup_features(scalar), [20, 1.0, 4.0])
    np.testing.assert_allclose(setup_features(ranged), [10, 0.8, 5.1])
    ranged.pop("mean_obstacle_speed")
    np.testing.assert_allclose(setup_features(ranged), [10, 0.8, 4.0])


def test_sigma_bands(report):
    b = report["sigma_bands"]
    assert b["metric"] == "survivability"
    ds = b["datasets"]
    assert set(ds) == {"controlled", "speed_range", "shifted"}
    for s in ds.values():
        w = [s["within_1sigma"], s["within_2sigma"], s["within_3sigma"]]
        assert 0.0 <= w[0] <= w[1] <= w[2] <= 1.0
    assert ds["controlled"]["controlled"] and ds["controlled"]["n_points"] == 27 * 4 * len(PAIRS)
    assert ds["controlled"]["within_3sigma"] > 0.95
    # same model with drawn speeds: mostly inside the bands; easy maps where everything fails: outside
    assert ds["speed_range"]["within_2sigma"] > 0.75
    assert ds["shifted"]["within_3sigma"] < 0.2


def test_report_fields_success_and_table(table, report):
    trials, maps, _ = table
    json.dumps(report, allow_nan=False)
    assert report["controlled_dataset"] == "controlled"
    assert report["datasets"] == {"controlled": 108, "shifted": 6, "speed_range": 18}
    assert report["n_error_trials"] == 7 and report["outcomes"]["error"] == 7
    assert report["pairs"] == sorted(PAIRS)
    assert list(report["metrics"]) == ["density", "survivability", "vo_feasibility", SETUP_MODEL]
    for name, row in report["metrics"].items():
        for key in ("srcc_mean", "srcc_std", "srcc_per_pair", "srcc_ci95", "within_setup_srcc", "cv_per_level",
                    "cv_mean", "cv_std", "compute_time_s", "normalisation", "n_maps"):
            assert key in row, (name, key)
        assert set(row["srcc_per_pair"]) == set(PAIRS)
    assert report["metrics"]["survivability"]["compute_time_s"] == pytest.approx(2.0)
    assert report["metrics"][SETUP_MODEL]["compute_time_s"] is None
    for key in ("b0", "b1", "b2", "b3"):
        assert report["regression"]["coefficients"][key] is not None
        assert report["setup_model"]["coefficients"][key] is not None
    # per-map rates and standard errors (error trials excluded)
    ids = sorted(maps)
    sr = rates_by_hand(trials, ids)
    rows = {(r["map_id"], r["pair"]): r for r in report["success"]["per_map"]}
    assert len(rows) == len(ids) * len(PAIRS)
    for i in (0, 40, len(ids) - 1):
        for j, p in enumerate(PAIRS):
            r = rows[ids[i], p]
            assert r["rate"] == pytest.approx(sr[i, j])
            assert r["se"] == pytest.approx(math.sqrt(sr[i, j] * (1 - sr[i, j]) / r["n"]))
    flown = sum(r["n"] for r in rows.values())
    assert flown == len(trials) - 7
    assert report["success"]["per_pair"][PAIRS[0]]["shifted"]["rate"] == 0.0

    text = format_table(report)
    for name in report["metrics"]:
        assert name in text
    for word in ("R^2", "speed_range", "shifted", PAIRS[0], "1s"):
        assert word in text


def test_bad_input():
    trials, maps, _ = synthetic(per_setup=1, n_trials=1, n_errors=0)
    with pytest.raises(ConfigError, match="trials.map_id"):
        evaluate(trials + [{**trials[0], "map_id": "nope"}], maps, n_boot=0)
    with pytest.raises(ConfigError, match="trials.outcome"):
        evaluate(trials + [{**trials[0], "outcome": "exploded"}], maps, n_boot=0)
    with pytest.raises(ConfigError, match="controlled"):
        evaluate(trials, maps, n_boot=0, controlled="nope")
    with pytest.raises(ConfigError, match="trials"):
        evaluate([{**t, "outcome": "error"} for t in trials], maps, n_boot=0)


def test_write_plots(table, report, tmp_path):
    trials, maps, _ = table
    paths = write_plots(trials, maps, report, tmp_path / "figs")
    names = sorted(p.name for p in paths)
    others = sorted({m["dataset"] for m in maps.values()} - {report["controlled_dataset"]})
    assert others                                             # the table has uncontrolled datasets (figs 4-14..4-16)
    assert names == sorted(["metric_density.png", "metric_survivability.png", "metric_vo_feasibility.png",
                            f"metric_{SETUP_MODEL}.png", "survivability_trajectory.png", "survivability_gaze.png",
                            "velocity_ratio.png"] + [f"uncontrolled_{d}.png" for d in others])
    import imageio.v2 as iio

    for p in paths:
        data = p.read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n"
        assert len(data) > 10_000, p.name
        assert p.with_suffix(".pdf").read_bytes()[:5] == b"%PDF-"               # paper formats beside every PNG
        assert "<svg" in p.with_suffix(".svg").read_text()[:2000]
        assert iio.imread(p).shape[1] >= 7.0 * 200                             # >= 200 dpi at >= 7 inches
        svg = p.with_suffix(".svg").read_text()
        assert "eq. 4-1" not in svg and "fig. 5-" not in svg                   # labels in words, not equation numbers
    svg = (tmp_path / "figs" / "metric_survivability.svg").read_text()
    assert "success rate (share of trials)" in svg and "difficulty by survivability" in svg


def test_within_setup_reliability_separates_noise_from_real_differences():
    from pbdyn.analysis.success import within_setup_reliability

    rng = np.random.default_rng(3)
    groups = np.repeat(np.arange(20), 5)
    n = np.full((100, 1), 400.0)
    same = rng.binomial(400, 0.5, size=(100, 1)) / 400.0                  # identical maps: only noise
    spread = rng.binomial(400, rng.uniform(0.2, 0.8, size=(100, 1))) / 400.0  # real differences >> noise
    r_same = within_setup_reliability(same, n, groups)
    r_spread = within_setup_reliability(spread, n, groups)
    assert r_same["n_setups"] == 20 and abs(r_same["mean_reliability"]) < 0.35
    assert r_spread["mean_reliability"] > 0.9
    # hand check of one pair: V_b and V_n over setups
    vb = np.mean([spread[groups == g, 0].var(ddof=1) for g in range(20)])
    vn = np.mean([np.mean(spread[groups == g, 0] * (1 - spread[groups == g, 0]) / 400.0) for g in range(20)])
    assert r_spread["per_pair"][0]["reliability"] == pytest.approx(1 - vn / vb, rel=1e-12)


def test_figure_names_from_stores_never_leave_the_plots_folder(table, tmp_path):
    """A dataset (scenario) or metric name with "/" or ".." (names come from stores) gives a safe file name inside
    the plots folder."""
    from pbdyn.analysis.plots import figure_name

    trials, maps, _ = table
    evil = "../../evil/x"
    maps = {mid: dict(m, dataset=evil if m["dataset"] == "shifted" else m["dataset"],
                      metrics={("a/../b" if k == "vo_feasibility" else k): v for k, v in m["metrics"].items()})
            for mid, m in maps.items()}
    trials = [dict(t, dataset=evil if t.get("dataset") == "shifted" else t.get("dataset")) for t in trials]
    rep = evaluate(trials, maps, n_boot=20, seed=3)
    out = tmp_path / "deep" / "er" / "figs"
    paths = write_plots(trials, maps, rep, out)
    names = {p.name for p in paths}
    assert "uncontrolled_.._.._evil_x.png" in names and "metric_a_.._b.png" in names
    assert all(p.parent == out for p in paths)
    assert sorted(f"{Path(n).stem}.{ext}" for n in names for ext in ("pdf", "png", "svg")) == \
        sorted(p.name for p in out.iterdir())
    assert not list(tmp_path.rglob("x.png")) and not (tmp_path / "deep" / "evil").exists()
    assert figure_name("..hidden") == "hidden.png" and figure_name("") == "figure.png"
    assert figure_name("a b/c\x00") == "a_b_c_.png"
