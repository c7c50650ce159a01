"""`pbdyn evaluate`: how well each difficulty metric ranks maps like the planners' success rates (thesis 3-2, 4-2,
4-3, 5-2), plus honesty checks the thesis lacks, as one JSON-serialisable dict and a text table like table 4-5.

Conventions (documented in the report itself):
- Success rate SR_ij = successes / flown trials of pair j on map i; "error" trials are counted, never rated.
- The metric table (table 4-5 columns), the normalisation and the controlled fits use the controlled dataset only;
  its normaliser (eq. 4-10 min/max, eq. 4-11 reversal) is applied unchanged to the other datasets' maps, whose
  difficulties may therefore fall outside [0, 10].
- Sign: a metric's difficulty D (after eq. 4-11) is high for hard maps, so Srcc(D, SR) <= 0 for a useful metric;
  the report gives srcc = -Srcc(D, SR) = Srcc(10 - D, SR), positive for a metric that ranks maps as success does,
  the sign of the thesis' table 4-5 (survivability 0.93).
- Bootstrap: the controlled maps are resampled with replacement (the same draws for every metric, from
  numpy.random.default_rng(seed)); per draw the mean over pairs of Srcc_j (eq. 3-9); the 95% interval is the
  2.5/97.5 percentile of the draws. The normaliser is held fixed (Srcc does not depend on it beyond its sign).
- Within-setup Srcc: Srcc_j over the maps of one (n, r, v) setup (they differ only by seed), for setups with >= 3
  maps, averaged over (setup, pair). A metric constant within a setup scores 0 there.
- setup_model: eq. 5-1 fitted to the per-map pooled success rate of the controlled maps (in-sample), its
  prediction used as a metric: what the setup alone explains.
"""

from __future__ import annotations

import math

import numpy as np

from pbdyn.analysis.bands import band_fit, band_shares
from pbdyn.analysis.cv import LEVELS, cv_by_level, cv_summary
from pbdyn.analysis.normalise import Normaliser, fit_normaliser
from pbdyn.analysis.regression import FEATURES, LinearFit, fit_linear, setup_features, setup_key
from pbdyn.analysis.srcc import bootstrap_mean_srcc, mean_std, pair_srcc, percentile_ci, within_group_srcc
from pbdyn.analysis.success import (OUTCOMES, SuccessTable, rate_and_se, success_table, trial_arrays,
                                   within_setup_reliability)
from pbdyn.errors import ConfigError
from pbdyn.metrics.catalog import INFO, TABLE_ORDER
from pbdyn.sim.outcome import Outcome

METRIC_ORDER = TABLE_ORDER
"""Row order of table 4-5 (pbdyn.metrics.catalog); other metrics found in the maps follow in name order, then
SETUP_MODEL."""

SETUP_MODEL = "setup_model"
"""Name of the setup-only baseline row (eq. 5-1 of (n, r, v) fitted to success)."""

BAND_METRICS = ("survivability", INFO["survivability"].dense)
"""Metrics tried in order for the sigma bands (tables 4-6..4-8), the regression (table 5-4) and figs 5-9/5-10."""

SIGN_CONVENTION = ("srcc = -Srcc(difficulty, SR) = Srcc(10 - difficulty, SR): positive when the metric ranks maps "
                   "as the success rate does (thesis table 4-5 sign); difficulty = eq. 4-10 then 4-11, high = hard")

MIN_SETUP_MAPS = 3
"""Fewest maps of one setup for the within-setup Srcc."""


def choose_controlled(datasets: list[str], controlled: str | None) -> str:
    """The controlled dataset: ``controlled`` if given (ConfigError if no map has it), else the dataset with the
    most maps (ties: the first name in sort order)."""
    names, counts = np.unique(np.asarray(datasets, dtype=str), return_counts=True)
    if controlled is not None:
        if controlled not in set(names.tolist()):
            raise ConfigError("controlled", f"no map belongs to it (datasets: {', '.join(names)})", controlled)
        return controlled
    return str(names[int(np.argmax(counts))])


def metric_values(maps: dict, map_ids: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Raw metric values [maps] per metric name (NaN where a map lacks it), in METRIC_ORDER then name order."""
    found = set()
    for m in map_ids:
        found.update((maps[m].get("metrics") or {}).keys())
    names = [n for n in METRIC_ORDER if n in found] + sorted(found - set(METRIC_ORDER))
    out = {}
    for n in names:
        v = [(maps[m].get("metrics") or {}).get(n) for m in map_ids]
        out[n] = np.array([float(x) if x is not None else np.nan for x in v])
    return out


def _mean_time(maps: dict, map_ids: tuple[str, ...], name: str) -> float:
    t = [(maps[m].get("metric_times") or {}).get(name) for m in map_ids]
    t = np.array([float(x) for x in t if x is not None])
    t = t[np.isfinite(t)]
    return float(t.mean()) if t.size else float("nan")


def _metric_row(d: np.ndarray, rate: np.ndarray, pairs: tuple[str, ...], keys: list[str], n_boot: int,
                seed: int) -> dict:
    """One table 4-5 row for difficulty d [maps] vs rate [maps, pairs] (controlled maps), sign per SIGN_CONVENTION."""
    per_pair = -pair_srcc(d, rate)
    mean, std = mean_std(per_pair)
    draws = -bootstrap_mean_srcc(d, rate, np.random.default_rng(seed), n_boot) if n_boot > 0 else np.empty(0)
    lo, hi = percentile_ci(draws)
    within, n_setups = within_group_srcc(d, rate, keys, MIN_SETUP_MAPS)
    w_mean, w_std = mean_std(-within)
    cv = cv_summary(cv_by_level(d, rate))
    return {"srcc_mean": mean, "srcc_std": std, "srcc_per_pair": dict(zip(pairs, per_pair.tolist())),
            "srcc_ci95": [lo, hi], "within_setup_srcc": w_mean, "within_setup_srcc_std": w_std,
            "within_setup_n_setups": n_setups, "cv_per_level": {str(k): float(c) for k, c in
                                                                enumerate(cv["per_level"])},
            "cv_per_pair": dict(zip(pairs, cv["per_pair"].tolist())), "cv_mean": cv["mean"], "cv_std": cv["std"],
            "n_maps": int(np.isfinite(d).sum())}


def _fit_dict(fit: LinearFit, target: str) -> dict:
    return {"target": target, "features": list(FEATURES),
            "coefficients": {f"b{i}": float(c) for i, c in enumerate(fit.coefficients)},
            "r2": fit.r2, "n_maps": fit.n}


def _success_block(st: SuccessTable, datasets: np.ndarray, map_ids: tuple[str, ...]) -> dict:
    per_map = [{"map_id": map_ids[i], "dataset": str(datasets[i]), "pair": st.pairs[j], "n": int(st.n[i, j]),
                "successes": int(st.successes[i, j]), "rate": float(st.rate[i, j]), "se": float(st.se[i, j])}
               for i, j in zip(*np.nonzero(st.n > 0))]
    pooled = {map_ids[i]: {"n": int(st.pooled_n[i]), "rate": float(st.pooled_rate[i]),
                           "se": float(st.pooled_se[i])} for i in np.flatnonzero(st.pooled_n > 0)}
    per_pair: dict = {}
    for name in np.unique(datasets):
        sel = datasets == name
        k = st.successes[sel].sum(axis=0)
        n = st.n[sel].sum(axis=0)
        p, se = rate_and_se(k, n)
        for j, pair in enumerate(st.pairs):
            r = st.rate[sel, j]
            r = r[np.isfinite(r)]
            between = float(r.std(ddof=1) / math.sqrt(r.size)) if r.size >= 2 else float("nan")
            if n[j] > 0:
                per_pair.setdefault(pair, {})[str(name)] = {
                    "n_trials": int(n[j]), "n_maps": int(r.size), "rate": float(p[j]), "se": float(se[j]),
                    "se_between_maps": between}
    return {"per_map": per_map, "per_map_pooled": pooled, "per_pair": per_pair}


def _clean(x):
    """JSON-safe copy: numpy scalars to Python numbers, NaN/inf to None, tuples to lists."""
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, np.ndarray):
        return [_clean(v) for v in x.tolist()]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(float(x)) else None
    return x


def evaluate(trials: list[dict], maps: dict, *, n_boot: int = 1000, seed: int = 0,
             controlled: str | None = None) -> dict:
    """Evaluate the difficulty metrics against the planners' success (thesis 3-2, 4-2, 4-3, 5-2) on a results
    table: ``trials`` (dicts with map_id, pair, trajectory, gaze, mav_speed, outcome, ...) and ``maps`` (map_id ->
    {setup, dataset, metrics, metric_times, mean_obstacle_speed, mean_obstacle_radius}); see the module docstring
    for the conventions. ``n_boot`` bootstrap draws (0: no interval), from numpy.random.default_rng(seed).
    ``controlled`` names the controlled dataset (default: the one with the most maps).

    Returns a JSON-serialisable dict (NaN as None): per metric (plus "setup_model") the mean/std Srcc over pairs
    (eq. 3-8, 3-9), per-pair Srcc, its bootstrap 95% CI, the within-setup Srcc, Cv per level and its mean
    (eq. 3-10..3-12), the mean compute time and the normaliser (eq. 4-10, 4-11); per-map/pair success rates with
    standard errors; the sigma-band shares per dataset (tables 4-6..4-8); the eq. 5-1 regression (table 5-4)."""
    if not maps:
        raise ConfigError("maps", "the results hold no maps", 0)
    n_boot = int(n_boot)
    if n_boot < 0:
        raise ConfigError("n_boot", "must be >= 0", n_boot)
    map_ids = tuple(sorted(maps))
    ta = trial_arrays(trials, map_ids)
    if not ta.flown.any():
        raise ConfigError("trials", "no finished trial (every trial is missing or an error)", len(trials))
    st = success_table(ta)
    datasets = np.array([str(maps[m].get("dataset", "")) for m in map_ids])
    ctrl_name = choose_controlled(datasets.tolist(), controlled)
    c = datasets == ctrl_name
    feats = np.array([setup_features(maps[m]) for m in map_ids]).reshape(len(map_ids), 3)
    keys = [setup_key(maps[m]) for m in map_ids]
    keys_c = [k for k, ok in zip(keys, c) if ok]
    rate_c = st.rate[c]

    values = {n: v for n, v in metric_values(maps, map_ids).items() if np.isfinite(v[c]).any()}
    setup_fit = fit_linear(feats[c], st.pooled_rate[c])
    values[SETUP_MODEL] = setup_fit.predict(feats)

    rows: dict = {}
    difficulty: dict = {}
    for name, v in values.items():
        norm = fit_normaliser(v[c], rate_c)
        d = norm.difficulty(v)
        difficulty[name] = d
        row = _metric_row(d[c], rate_c, st.pairs, keys_c, n_boot, seed)
        row["compute_time_s"] = None if name == SETUP_MODEL else _mean_time(maps, map_ids, name)
        row["normalisation"] = norm.as_dict()
        rows[name] = row

    band_name = next((n for n in BAND_METRICS if n in difficulty), None)
    bands = None
    regression = regression_raw = None
    if band_name is not None:
        d = difficulty[band_name]
        mu, sig = band_fit(d[c], rate_c)
        per_ds = {}
        for name in np.unique(datasets):
            sel = datasets == name
            sh = band_shares(mu, sig, d[sel], st.rate[sel])
            per_ds[str(name)] = {"controlled": bool(name == ctrl_name), "n_maps": int(sel.sum()),
                                 "n_points": sh["n_points"], "within_1sigma": sh["within"][0],
                                 "within_2sigma": sh["within"][1], "within_3sigma": sh["within"][2]}
        bands = {"metric": band_name, "fit": {"mean": mu, "sigma": sig, "levels": list(range(LEVELS))},
                 "datasets": per_ds}
        regression = _fit_dict(fit_linear(feats[c], d[c]), f"{band_name} difficulty [0, 10] (eq. 4-10, 4-11)")
        regression_raw = _fit_dict(fit_linear(feats[c], values[band_name][c]), f"{band_name} raw value")

    outcome_counts = np.bincount(ta.outcome_idx, minlength=len(OUTCOMES))
    report = {
        "sign_convention": SIGN_CONVENTION,
        "controlled_dataset": ctrl_name,
        "datasets": {str(n): int(k) for n, k in zip(*np.unique(datasets, return_counts=True))},
        "pairs": list(st.pairs),
        "n_trials": len(trials),
        "n_error_trials": int(outcome_counts[OUTCOMES.index(Outcome.ERROR.value)]),
        "outcomes": dict(zip(OUTCOMES, outcome_counts.tolist())),
        "n_boot": n_boot, "seed": int(seed),
        "metrics": rows,
        "setup_model": {**_fit_dict(setup_fit, "pooled success rate per map"), "rows": "metrics.setup_model"},
        "success": _success_block(st, datasets, map_ids),
        "within_setup_reliability": within_setup_reliability(rate_c, st.n[c], keys_c),
        "sigma_bands": bands,
        "regression": regression,
        "regression_raw": regression_raw,
    }
    return _clean(report)


def difficulty_table(maps: dict, report: dict) -> tuple[tuple[str, ...], dict[str, np.ndarray]]:
    """(map_ids sorted, {metric: difficulty [maps]}) rebuilt from the maps and a report's normalisers (eq. 4-10,
    4-11) and setup-model coefficients (eq. 5-1)."""
    map_ids = tuple(sorted(maps))
    values = metric_values(maps, map_ids)
    coef = report["setup_model"]["coefficients"]
    b = np.array([coef[f"b{i}"] if coef[f"b{i}"] is not None else np.nan for i in range(len(FEATURES) + 1)])
    feats = np.array([setup_features(maps[m]) for m in map_ids]).reshape(len(map_ids), 3)
    values[SETUP_MODEL] = LinearFit(b, float("nan"), 0).predict(feats)
    out = {}
    for name, row in report["metrics"].items():
        norm = row["normalisation"]
        if name in values and norm["min"] is not None and norm["max"] is not None:
            out[name] = Normaliser.from_dict(norm).difficulty(values[name])
    return map_ids, out


def _f(x, spec: str = ".3f") -> str:
    return "-" if x is None else format(x, spec)


def _term(x) -> str:
    return "+ -" if x is None else f"{'-' if x < 0 else '+'} {abs(x):.3f}"


def format_table(report: dict) -> str:
    """Text report laid out like thesis table 4-5 (rows: metrics and setup_model; columns: Srcc mean +- std over
    pairs, bootstrap 95% CI, within-setup Srcc, Cv mean +- std, compute time per map), then the sigma bands
    (tables 4-6..4-8), the eq. 5-1 regression (table 5-4) and the success-rate summary."""
    lines = [f"Controlled dataset: {report['controlled_dataset']}  "
             f"({report['datasets'].get(report['controlled_dataset'], 0)} maps, {len(report['pairs'])} planner "
             f"pairs, {report['n_boot']} bootstrap draws)", f"Sign: {report['sign_convention']}", ""]
    head = f"{'Metric':<24} {'SRCC':>15} {'95% CI':>17} {'within-setup':>13} {'CV':>15} {'time [s]':>9}"
    lines += [head, "-" * len(head)]
    for name, r in report["metrics"].items():
        ci = r["srcc_ci95"]
        lines.append(f"{name:<24} {_f(r['srcc_mean']):>7} +- {_f(r['srcc_std']):<5} "
                     f"[{_f(ci[0]):>6}, {_f(ci[1]):>6}]  {_f(r['within_setup_srcc']):>12} "
                     f"{_f(r['cv_mean']):>7} +- {_f(r['cv_std']):<5} {_f(r['compute_time_s'], '.2f'):>9}")
    rel = report.get("within_setup_reliability") or {}
    if rel.get("n_setups"):
        lines += ["", f"Within-setup reliability of per-map success: {_f(rel['mean_reliability'], '.2f')} (mean over "
                      f"pairs over {rel['n_setups']} setups; 1 - binomial noise variance / between-map variance). A "
                      "metric's within-setup SRCC cannot exceed about its square root."]
    b = report.get("sigma_bands")
    if b:
        lines += ["", f"Share of (map, pair) points within k sigma of the controlled fit of success vs "
                      f"{b['metric']} difficulty (tables 4-6..4-8):"]
        for name, s in b["datasets"].items():
            tag = " (controlled, in-sample)" if s["controlled"] else ""
            lines.append(f"  {name:<30} n={s['n_points']:<6} 1s {_f(s['within_1sigma'], '.1%'):>6}  "
                         f"2s {_f(s['within_2sigma'], '.1%'):>6}  3s {_f(s['within_3sigma'], '.1%'):>6}{tag}")
    lines += ["", "Linear model of the setup (eq. 5-1; table 5-4 is the first line):"]
    for key in ("regression", "regression_raw", "setup_model"):
        g = report.get(key)
        if g:
            c = g["coefficients"]
            lines.append(f"  {g['target']} = {_f(c['b0'])} {_term(c['b1'])} n {_term(c['b2'])} r {_term(c['b3'])} v"
                         f"   R^2 {_f(g['r2'])}  ({g['n_maps']} maps; eq. 5-1)")
    lines += ["", f"Trials: {report['n_trials']} ({report['n_error_trials']} errors, not rated); outcomes: " +
              ", ".join(f"{k} {v}" for k, v in report["outcomes"].items()),
              "Success rate per pair and dataset (binomial se; se between maps):"]
    for pair, per in report["success"]["per_pair"].items():
        for ds, s in per.items():
            lines.append(f"  {pair:<40} {ds:<24} {_f(s['rate'])} +- {_f(s['se'])} "
                         f"({_f(s['se_between_maps'])})  {s['n_trials']} trials, {s['n_maps']} maps")
    return "\n".join(lines)
