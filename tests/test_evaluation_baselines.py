"""`pbdyn evaluate` beside its baselines and the fitted difficulty (pbdyn.analysis.report, .validation): on the
synthetic study of test_analysis (a hidden per-map difficulty; survivability sees all of it, flux only the setup)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import spearmanr

from pbdyn.analysis.report import SETUP_MODEL, evaluate, format_table
from pbdyn.analysis.validation import ALPHA, agreement, compare, holm_verdicts, one_sided_p
from tests.test_analysis import PAIRS, controlled_ids, synthetic


def _with_flux(maps):
    """Each map plus a closed-form flux baseline: a function of its setup (n, r, v) only, harder = higher."""
    out = {}
    for k, e in maps.items():
        s = e["setup"]
        r = s["radius"] if not isinstance(s["radius"], dict) else 1.0
        flux = s["count"] * 2.0 * (r + 1.0) * e["mean_obstacle_speed"] / 2500.0
        out[k] = {**e, "metrics": {**e["metrics"], "flux": flux}}
    return out


@pytest.fixture(scope="module")
def study():
    trials, maps, hidden = synthetic(seed=1)
    maps = _with_flux(maps)
    for i, t in enumerate(trials):                       # two start/goal tasks per map
        t["task"] = ("4,4->46,46", "46,46->4,4")[i % 2]
    return trials, maps, hidden, evaluate(trials, maps, n_boot=300, seed=5)


def test_rows_are_marked_and_compared_with_every_baseline(study):
    _, _, _, rep = study
    m = rep["metrics"]
    assert rep["baselines"]["rows"] == [SETUP_MODEL, "flux"]
    assert m["flux"]["kind"] == m[SETUP_MODEL]["kind"] == "baseline"
    assert m["survivability"]["kind"] == "metric" and "vs_baselines" not in m["flux"]
    for name in ("survivability", "density", "vo_feasibility"):
        for base in (SETUP_MODEL, "flux"):
            c = m[name]["vs_baselines"][base]
            assert c["diff"] == pytest.approx(m[name]["srcc_mean"] - m[base]["srcc_mean"], abs=1e-12)
            assert c["ci95"][0] <= c["diff"] <= c["ci95"][1]
            # within setups both baselines are constant (SRCC 0): the difference is the metric's own
            assert c["within_diff"] == pytest.approx(m[name]["within_setup_srcc"], abs=1e-9)
    # survivability sees the per-map part of the hidden difficulty: it beats both, across maps and within setups
    assert m["survivability"]["beats_baselines"] is True
    assert m["survivability"]["beats_baselines_within_setup"] is True
    # density (setup only) and a random metric do not
    for name in ("density", "vo_feasibility"):
        assert m[name]["beats_baselines"] is False and m[name]["beats_baselines_within_setup"] is False


def test_paired_comparison_by_hand():
    rng = np.random.default_rng(0)
    h = rng.normal(size=40)
    rate = (-h[:, None] + rng.normal(scale=0.3, size=(40, 3)))
    keys = [str(i // 4) for i in range(40)]
    good, noisy = agreement(h, rate, keys, 400, 1), agreement(h + rng.normal(scale=2.0, size=40), rate, keys, 400, 1)
    c = compare(good, noisy, 400, 2)
    assert c["diff"] == pytest.approx(good.srcc - noisy.srcc)
    np.testing.assert_allclose(sorted(c["ci95"]), np.percentile(good.draws - noisy.draws, [2.5, 97.5]))
    assert c["ci95"][0] > 0                                   # the exact metric beats the noisy one
    same = compare(good, good, 400, 2)
    assert same["diff"] == 0.0 and same["ci95"] == [0.0, 0.0] and same["within_diff"] == 0.0


def test_holm_verdicts_by_hand():
    """A metric's p-value is the largest over its baselines; Holm multiplies the smallest of m by m, the next by
    m - 1 (step-down, monotone); a metric without a p-value for some baseline is not tested."""
    assert one_sided_p(np.array([0.1, 0.2, -0.1, np.nan])) == pytest.approx((1 + 1) / (1 + 3))
    assert one_sided_p(np.array([0.1, 0.0])) == pytest.approx(2 / 3)           # a tie counts against the metric
    assert math.isnan(one_sided_p(np.empty(0)))
    comps = {"a": {"x": {"p": 0.001}, "y": {"p": 0.004}},       # IUT p 0.004 -> Holm 3 x 0.004 = 0.012: beats
             "b": {"x": {"p": 0.011}, "y": {"p": 0.002}},       # 0.011 -> 2 x 0.011 = 0.022: beats
             "c": {"x": {"p": 0.020}, "y": {"p": 0.001}},       # 0.020 -> 1 x 0.020, but monotone: 0.022: beats
             "d": {"x": {"p": 0.5}, "y": {"p": float("nan")}}}  # untested
    v = holm_verdicts(comps)
    assert set(v) == {"a", "b", "c"} and all(r["n_tests"] == 3 for r in v.values())
    assert [v[k]["p"] for k in "abc"] == [0.004, 0.011, 0.020]
    assert [v[k]["p_holm"] for k in "abc"] == pytest.approx([0.012, 0.022, 0.022])
    assert all(v[k]["beats"] for k in "abc")
    comps["c"]["x"]["p"] = 0.03                                # above ALPHA on its own: fails after correction too
    v = holm_verdicts(comps)
    assert v["c"]["p_holm"] == pytest.approx(0.03) and not v["c"]["beats"] and v["b"]["beats"]
    comps["b"]["x"]["p"] = 0.02                                # 2 x 0.02 = 0.04 > ALPHA: b no longer beats them
    assert not holm_verdicts(comps)["b"]["beats"] and ALPHA == 0.025


def test_corrected_verdicts_in_the_report(study):
    """Every metric carries the Holm-corrected verdicts; a corrected verdict is never kinder than the raw one,
    and the p-values agree with the intervals (an interval above 0 means p about <= ALPHA)."""
    *_, rep = study
    m = rep["metrics"]
    tested = [n for n, r in m.items() if r["kind"] == "metric"]
    for name in tested:
        r = m[name]
        h = r["beats_baselines_holm"]
        assert h["n_tests"] == len(tested)
        assert h["p"] == max(c["p"] for c in r["vs_baselines"].values())
        assert h["p_holm"] >= h["p"]
        if h["beats"]:
            assert r["beats_baselines"] is True
        if r["beats_baselines"] is False:
            assert h["p"] > ALPHA - 0.01
        assert r["fitted"]["beats_baselines_holm"]["n_tests"] == len(tested)
        assert "beats_baselines_within_setup_holm" in r
    assert m["survivability"]["beats_baselines_holm"]["beats"] is True
    assert m["density"]["beats_baselines_holm"]["beats"] is False
    text = format_table(rep)
    assert "] **" in next(line for line in text.splitlines() if line.startswith("survivability "))
    assert ("Beats every baseline across maps: survivability (after Holm's correction: survivability)" in text)


def test_fitted_difficulty_recovers_the_hidden_one_and_the_planners_order(study):
    trials, maps, hidden, rep = study
    fd = rep["fitted_difficulty"]
    assert fd["method"] == "statsmodels GLM" and fd["converged"]
    ids = [m for m in controlled_ids(maps)]
    b = np.array([fd["maps"][m]["difficulty"] for m in ids])
    h = np.array([hidden[m] for m in ids])
    assert spearmanr(b, h).statistic > 0.85
    slope = np.polyfit(h, b, 1)[0]                            # the simulation's logit slope is 1.1 per unit of h
    assert 0.8 < slope < 1.4
    # ability grows with the pair index (+0.4 logits per index in the simulation); MAV speed plays no part
    ab = fd["respondents"]
    per_pair = [np.mean([ab[f"{p} @ {v:g} m/s"]["ability"] for v in (2.0, 4.0)]) for p in PAIRS]
    assert np.all(np.diff(per_pair) > 0)
    assert per_pair[-1] - per_pair[0] == pytest.approx(1.2, abs=0.35)
    # every row's agreement with the fitted difficulty: survivability the best, as against success
    m = rep["metrics"]
    assert m["survivability"]["fitted"]["srcc"] > 0.85 > m["density"]["fitted"]["srcc"]
    assert m["survivability"]["fitted"]["beats_baselines"] is True
    # the tasks were labelled the same on every map and drawn from one model: little within-map spread
    t = fd["tasks"]
    assert t["n_tasks"] == 2 * len(maps) and t["within_map_share_noise_corrected"] < 0.2


def test_table_prints_baselines_verdicts_and_abilities(study):
    *_, rep = study
    text = format_table(rep)
    assert "vs best baseline" in text and "Baselines (need no simulation): setup_model, flux" in text
    assert "Beats every baseline across maps: survivability" in text
    assert "Planner abilities" in text and "@ 4 m/s" in text and "Tasks (map, start, goal)" in text
    assert math.isfinite(rep["metrics"]["survivability"]["fitted"]["ci95"][0])


def test_trial_level_scores_a_real_predictor_above_a_random_one():
    from pbdyn.analysis.trial_level import REFERENCE, trial_level

    rng = np.random.default_rng(3)
    n_maps, per = 60, 40
    h = rng.normal(size=n_maps)                                  # map difficulty
    task = rng.normal(size=(n_maps, per))                        # task difficulty on top
    map_idx = np.repeat(np.arange(n_maps), per)
    resp = np.tile(np.arange(2), n_maps * per // 2)
    logit = 0.5 + 0.8 * resp - 1.0 * h[map_idx] - 1.5 * task.reshape(-1)
    y = (rng.random(logit.shape) < 1.0 / (1.0 + np.exp(-logit))).astype(float)
    out = trial_level(y, resp, map_idx, {"map": h[map_idx], "task": task.reshape(-1),
                                         "noise": rng.normal(size=y.size),
                                         "partial": np.where(np.arange(y.size) % 2 == 0, h[map_idx], np.nan)})
    assert list(out)[0] == REFERENCE and out[REFERENCE]["n_trials"] == y.size
    assert out["task"]["log_loss_gain"] > out["map"]["log_loss_gain"] > 0.02
    assert abs(out["noise"]["log_loss_gain"]) < 0.01 and out["task"]["auc"] > out[REFERENCE]["auc"]
    assert out["partial"]["n_trials"] == y.size // 2 and out["partial"]["log_loss_gain"] > 0.02
    # intervals over resampled maps: the noise predictor's gain straddles 0, the task predictor beats the map one
    from pbdyn.analysis.trial_level import compare_predictors, public

    lo, hi = out["noise"]["log_loss_gain_ci95"]
    assert lo < 0.0 < hi and out["task"]["log_loss_gain_ci95"][0] > 0.02
    c = compare_predictors(out, "task", "map", map_idx)
    assert c["diff"] == pytest.approx(out["map"]["log_loss"] - out["task"]["log_loss"], abs=1e-12)
    assert c["ci95"][0] > 0
    assert "_loss" not in public(out)["task"] and "log_loss_gain_ci95" in public(out)["task"]


def test_evaluate_reports_the_trial_level_block(study):
    *_, rep = study
    preds = rep["trial_level"]["predictors"]
    assert "survivability" in preds and "flux" in preds and SETUP_MODEL in preds
    assert preds["survivability"]["log_loss_gain"] > preds["vo_feasibility"]["log_loss_gain"]


def test_corridor_rows_are_map_means_of_the_task_metrics():
    from pbdyn.analysis.report import corridor_means
    from pbdyn.analysis.success import trial_arrays

    trials, maps, hidden = synthetic(seed=2, per_setup=3, n_trials=8)
    maps = _with_flux(maps)
    for i, t in enumerate(trials):
        t["task_survivability_s"] = 12.0 - 0.8 * hidden[t["map_id"]] + (i % 3) * 0.1
        t["task_flux_per_s"] = 0.01 * hidden[t["map_id"]] + (0.001 if i % 2 else 0.0)
    ids = tuple(sorted(maps))
    ta = trial_arrays(trials, ids)
    means = corridor_means(ta, trials, len(ids))
    flown = [t for t in trials if t["outcome"] != "error"]
    m0 = ids[0]
    by_hand = np.mean([t["task_survivability_s"] for t in flown if t["map_id"] == m0])
    assert means["corridor_survivability"][0] == pytest.approx(by_hand, rel=1e-12)
    rep = evaluate(trials, maps, n_boot=100, seed=1)
    m = rep["metrics"]
    assert m["corridor_survivability"]["kind"] == "metric" and m["corridor_flux"]["kind"] == "baseline"
    assert rep["baselines"]["rows"] == [SETUP_MODEL, "flux", "corridor_flux", "flux_model"]
    assert rep["baselines"]["flux_model"]["features"] == ["flux", "corridor_flux"]
    assert m["corridor_survivability"]["srcc_mean"] > 0.8


def test_within_family_srcc_with_intervals_for_structured_maps():
    trials, maps, hidden = synthetic(seed=3, per_setup=4, n_trials=12)
    maps = _with_flux(maps)
    for k, e in maps.items():              # two "structures" per setup: maps 0-1 and 2-3 of each setup
        if e["dataset"] == "controlled":
            e["setup"] = {**e["setup"], "structure": "a" if int(k.rsplit("-", 1)[1]) < 2 else "b"}
    rep = evaluate(trials, maps, n_boot=200, seed=2)
    r = rep["metrics"]["survivability"]
    assert r["within_family_n_groups"] == 0          # families of 2 maps: below the 3 maps a within-group SRCC needs
    for k, e in maps.items():
        if e["dataset"] == "controlled":
            e["setup"]["structure"] = "a"          # one family per setup: the within-setup groups
    rep = evaluate(trials, maps, n_boot=200, seed=2)
    r = rep["metrics"]["survivability"]
    assert r["within_family_srcc"] == pytest.approx(r["within_setup_srcc"], abs=1e-12)
    lo, hi = r["within_family_ci95"]
    assert lo < r["within_family_srcc"] < hi and lo > 0
    c = r["vs_baselines"]["flux"]
    assert c["within_family_diff"] == pytest.approx(c["within_diff"], abs=1e-12)
    assert "Within structure families" in format_table(rep)
