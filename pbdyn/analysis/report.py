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
- Corridor rows: when the trials carry task metrics (pbdyn.metrics.task), corridor_survivability and corridor_flux
  are a map's means of them over its flown trials -- survivability and flux along the corridors its tasks fly.
- Baselines (rows of kind "baseline"): setup_model, the closed-form metrics that need no simulation
  (pbdyn.metrics.baselines: flux, static_share; corridor_flux) and, when two or more of them vary, flux_model (a
  linear fit of the pooled success on them, in-sample like setup_model). Every other row (kind "metric") is compared with each baseline, paired over
  the same bootstrap draws (pbdyn.analysis.validation): "vs_baselines" holds the SRCC difference and its 95%
  interval across maps and within setups; "beats_baselines" is True only when every interval lies above 0.
  Several metrics are tested at once, so each verdict also comes corrected for their number ("*_holm": the largest
  of a metric's one-sided bootstrap p-values over the baselines, Holm-adjusted over the metrics tested;
  pbdyn.analysis.validation.holm_verdicts): only those verdicts bound the chance that any metric is wrongly said
  to beat the baselines.
- Structured maps (a "structure" in their setup): "within_family_srcc" is the within-setup Srcc over the maps of one
  setup and one structure (they differ only by seed), beside the within-setup Srcc over all structures of a setup,
  with a 95% interval over resampled families ("within_family_ci95") and, in "vs_baselines", the paired
  within-family difference to each baseline ("within_family_diff", "within_family_ci95").
- Fitted difficulty: a 1PL item-response model (pbdyn.analysis.irt) of every flown trial, items = maps,
  respondents = planner pair at one MAV speed; "fitted_difficulty" holds the planners' abilities (a score
  comparable across maps) and each map's difficulty with its standard error, and every row's "fitted" its SRCC
  against minus the fitted difficulty (same sign as against success), with the same baseline comparisons. A second
  fit with items = tasks (map, start, goal) reports how much of the difficulty lies between the tasks of a map.
"""

from __future__ import annotations

import math

import numpy as np

from pbdyn.analysis.bands import band_fit, band_shares
from pbdyn.analysis.cv import LEVELS, cv_by_level, cv_summary
from pbdyn.analysis.html_kit import NA, interval, num
from pbdyn.analysis.normalise import Normaliser, fit_normaliser
from pbdyn.analysis.paired import wilson_interval
from pbdyn.analysis.regression import FEATURES, LinearFit, fit_linear, setup_features, setup_key
from pbdyn.analysis.validation import (Agreement, agreement, agreement_dict, compare, holm_verdicts, verdict,
                                      within_ci)
from pbdyn.analysis.success import (OUTCOMES, SuccessTable, rate_and_se, success_table, trial_arrays,
                                   within_setup_reliability)
from pbdyn.errors import ConfigError
from pbdyn.metrics.catalog import BASELINES, INFO, TABLE_ORDER
from pbdyn.outcome import Outcome

METRIC_ORDER = TABLE_ORDER
"""Row order of table 4-5 (pbdyn.metrics.catalog); other metrics found in the maps follow in name order, then
SETUP_MODEL."""

SETUP_MODEL = "setup_model"
"""Name of the setup-only baseline row (eq. 5-1 of (n, r, v) fitted to success)."""

BASELINE_MODEL = "flux_model"
"""Name of the baseline row fitted on the closed-form baselines (when more than one varies)."""

MAX_GLM_ITEMS = 1500
"""Above this many maps the map-level item-response fit uses the sparse fit (pbdyn.analysis.irt)."""

BAND_METRICS = ("survivability", INFO["survivability"].dense)
"""Metrics tried in order for the sigma bands (tables 4-6..4-8), the regression (table 5-4) and figs 5-9/5-10."""

SIGN_CONVENTION = ("srcc = -Srcc(difficulty, SR) = Srcc(10 - difficulty, SR): positive when the metric ranks maps "
                   "as the success rate does (thesis table 4-5 sign); difficulty = eq. 4-10 then 4-11, high = hard")


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
                seed: int) -> tuple[dict, Agreement]:
    """One table 4-5 row for difficulty d [maps] vs rate [maps, pairs] (controlled maps), sign per SIGN_CONVENTION,
    and its Agreement (bootstrap draws and per-setup values, for the paired baseline comparisons)."""
    ag = agreement(d, rate, keys, n_boot, seed)
    lo, hi = ag.ci95
    cv = cv_summary(cv_by_level(d, rate))
    return ({"srcc_mean": ag.srcc, "srcc_std": ag.std, "srcc_per_pair": dict(zip(pairs, ag.per_column.tolist())),
             "srcc_ci95": [lo, hi], "within_setup_srcc": ag.within_mean, "within_setup_srcc_std": ag.within_std,
             "within_setup_n_setups": ag.n_setups, "cv_per_level": {str(k): float(c) for k, c in
                                                                    enumerate(cv["per_level"])},
             "cv_per_pair": dict(zip(pairs, cv["per_pair"].tolist())), "cv_mean": cv["mean"], "cv_std": cv["std"],
             "n_maps": int(np.isfinite(d).sum())}, ag)


def _vs_baselines(out: dict, agree: dict, name: str, bases: list[str], n_boot: int, seed: int) -> dict:
    """Row ``name`` against every baseline (pbdyn.analysis.validation.compare, same draws), written into ``out`` as
    vs_baselines, beats_baselines and beats_baselines_within_setup; returns the comparisons."""
    comps = {b: compare(agree[name], agree[b], n_boot, seed) for b in bases}
    out["vs_baselines"] = comps
    out["beats_baselines"] = verdict(comps)
    out["beats_baselines_within_setup"] = verdict(comps, "within_ci95")
    return comps


HOLM_FIELDS = {"p": "beats_baselines_holm", "within_p": "beats_baselines_within_setup_holm",
               "within_family_p": "beats_baselines_within_family_holm"}
"""Which p-value of the baseline comparisons (validation.compare) feeds which multiplicity-corrected verdict
(validation.holm_verdicts: across maps, within setups, within structure families)."""


def _respondent(pair: str, speed: float) -> str:
    return f"{pair} @ {speed:g} m/s"


TASK_FIELDS = {"task_survivability": "task_survivability_s", "task_flux": "task_flux_per_s"}
"""Task metrics (pbdyn.metrics.task) as trial-level predictors: name -> the trial row's field."""

CORRIDOR_ROWS = {"corridor_survivability": "task_survivability_s", "corridor_flux": "task_flux_per_s"}
"""Map rows from the task metrics: a map's mean over its flown trials (its start/goal tasks)."""

CORRIDOR_BASELINE = "corridor_flux"
"""The map mean of the closed-form task metric: a baseline (it needs no simulation)."""

BASELINE_ROWS = (SETUP_MODEL, *BASELINES, CORRIDOR_BASELINE, BASELINE_MODEL)
"""Every row that is a baseline (kind "baseline"), in report order."""

TASK_BASELINE = "task_flux"
"""The closed-form task metric: a baseline predictor at the trial level."""


def _trial_values(trials: list[dict], idx: np.ndarray, key: str) -> np.ndarray:
    """The float field ``key`` of trials[idx] (NaN where None)."""
    return np.array([np.nan if trials[i].get(key) is None else float(trials[i][key]) for i in idx])


def _respondents(ta, idx: np.ndarray) -> list[str]:
    """The respondent (planner pair at its MAV speed) of trials idx."""
    return [_respondent(ta.pairs[p], v) for p, v in zip(ta.pair_idx[idx], ta.mav_speed[idx])]


def corridor_means(ta, trials: list[dict], n_maps: int) -> dict[str, np.ndarray]:
    """Per map [n_maps] the mean of each task metric over its flown trials (CORRIDOR_ROWS; NaN where none): the
    map's survivability and flux along the corridors its tasks fly, rather than over a grid of the arena."""
    flown = np.flatnonzero(ta.flown)
    out = {}
    for name, key in CORRIDOR_ROWS.items():
        v = _trial_values(trials, flown, key)
        ok = np.isfinite(v)
        if not ok.any():
            continue
        idx = ta.map_idx[flown][ok]
        tot = np.bincount(idx, weights=v[ok], minlength=n_maps)
        cnt = np.bincount(idx, minlength=n_maps)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[name] = np.where(cnt > 0, tot / np.maximum(cnt, 1), np.nan)
    return out


def _trial_level(ta, trials: list[dict], difficulty: dict, controlled: np.ndarray) -> dict | None:
    """Held-out trial-level scores (pbdyn.analysis.trial_level) of every row's map difficulty and of the task
    metrics, on the flown trials of the controlled maps; None with fewer than 2 such maps or one outcome only."""
    from pbdyn.analysis.trial_level import REFERENCE, compare_predictors, public, trial_level

    sel = np.flatnonzero(ta.flown & controlled[ta.map_idx])
    if sel.size == 0 or np.unique(ta.map_idx[sel]).size < 2:
        return None
    success = ta.is_outcome(Outcome.SUCCESS)[sel].astype(float)
    if np.unique(success).size < 2:
        return None
    _, resp = np.unique(np.asarray(_respondents(ta, sel), dtype=str), return_inverse=True)
    preds = {name: d[ta.map_idx[sel]] for name, d in difficulty.items()}
    for name, key in TASK_FIELDS.items():
        v = _trial_values(trials, sel, key)
        if np.isfinite(v).any():
            preds[name] = v
    scores = trial_level(success, resp, ta.map_idx[sel], preds)
    bases = [b for b in (*BASELINE_ROWS, TASK_BASELINE) if b in scores]
    out = public(scores)
    tested = {}
    for name in scores:
        if name in bases or name == REFERENCE:
            continue
        comps = tested[name] = {b: compare_predictors(scores, name, b, ta.map_idx[sel]) for b in bases}
        out[name]["vs_baselines"] = comps
        out[name]["beats_baselines"] = verdict(comps)
    for name, v in holm_verdicts(tested).items():
        out[name]["beats_baselines_holm"] = v
    return {"method": "logistic regression of success on [predictor, planner indicators], held-out maps "
                      "(scikit-learn, GroupKFold); vs_baselines: the baseline's held-out log-loss minus the "
                      "predictor's, 95% interval over resampled maps", "baselines": bases, "predictors": out}


def fitted_difficulty(ta, trials: list[dict], map_ids: tuple[str, ...]) -> tuple[np.ndarray, dict]:
    """The 1PL fit of the flown trials (pbdyn.analysis.irt): (difficulty [maps] (logits; NaN for a map without
    flown trials), JSON-able summary with the planners' abilities, each map's difficulty and se, and the task-level
    fit's summary)."""
    from pbdyn.analysis.irt import PRIOR_SD, fit_rasch, fit_rasch_sparse

    flown = np.flatnonzero(ta.flown)
    success = ta.is_outcome(Outcome.SUCCESS)[flown].astype(float)
    resp = _respondents(ta, flown)
    items = [map_ids[i] for i in ta.map_idx[flown]]
    both = 0 < success.sum() < success.size          # the sparse fit needs successes and failures
    fit = (fit_rasch_sparse if len(set(items)) > MAX_GLM_ITEMS and both else fit_rasch)(items, resp, success)
    pos = {m: i for i, m in enumerate(fit.items)}
    b = np.array([fit.difficulty[pos[m]] if m in pos else np.nan for m in map_ids])
    summary = {"model": "1PL (Rasch): P(success) = sigmoid(ability - difficulty), logits; difficulties centred",
               **fit.as_dict()}
    summary["maps"] = summary.pop("items")                  # the items of this fit are the maps
    tasks = [t.get("task") for t in trials]
    if not both:
        summary["tasks"] = {"skipped": "every flown trial had the same outcome"}
    elif all(x is not None for x in tasks):
        titems = [f"{map_ids[ta.map_idx[i]]}|{tasks[i]}" for i in flown]
        tf = fit_rasch_sparse(titems, resp, success)
        by_map = np.array([x.split("|", 1)[0] for x in tf.items])
        bt = tf.difficulty
        within = np.concatenate([bt[by_map == m] - bt[by_map == m].mean() for m in np.unique(by_map)])
        total = float(bt.var())
        noise = float(np.mean(tf.difficulty_se ** 2))
        summary["tasks"] = {"method": tf.method, "n_tasks": len(tf.items), "prior_sd": PRIOR_SD,
                            "difficulty_sd": float(bt.std()), "within_map_sd": float(within.std()),
                            "within_map_share_of_variance": float(within.var() / total) if total > 0 else None,
                            "within_map_share_noise_corrected": float(max(within.var() - noise, 0.0) / total)
                            if total > 0 else None, "mean_se": float(tf.difficulty_se.mean())}
    return b, summary


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
                    "se_between_maps": between, "successes": int(k[j]),
                    "ci95": list(wilson_interval(int(k[j]), int(n[j])))}
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
    families = [(maps[m].get("setup") or {}).get("structure") for m in map_ids]
    fam_c = [f"{k}|{f}" for k, f, ok in zip(keys, families, c) if ok] \
        if any(f is not None for f, ok in zip(families, c) if ok) else None
    rate_c = st.rate[c]

    values = {n: v for n, v in metric_values(maps, map_ids).items() if np.isfinite(v[c]).any()}
    values.update({n: v for n, v in corridor_means(ta, trials, len(map_ids)).items() if np.isfinite(v[c]).any()})
    setup_fit = fit_linear(feats[c], st.pooled_rate[c])
    values[SETUP_MODEL] = setup_fit.predict(feats)
    varying = [n for n in (*BASELINES, CORRIDOR_BASELINE) if n in values and np.nanstd(values[n][c]) > 0]
    baseline_fit = None
    if len(varying) >= 2:
        bx = np.stack([values[n] for n in varying], axis=1)
        baseline_fit = fit_linear(bx[c], st.pooled_rate[c])
        values[BASELINE_MODEL] = baseline_fit.predict(bx)

    fitted_b, fitted_summary = fitted_difficulty(ta, trials, map_ids)
    fitted_target = (-fitted_b)[:, None]
    has_fit = np.isfinite(fitted_b[c]).sum() >= 2

    rows: dict = {}
    difficulty: dict = {}
    agree: dict = {}
    agree_fit: dict = {}
    agree_fam: dict = {}
    for name, v in values.items():
        norm = fit_normaliser(v[c], rate_c)
        d = norm.difficulty(v)
        difficulty[name] = d
        row, agree[name] = _metric_row(d[c], rate_c, st.pairs, keys_c, n_boot, seed)
        if fam_c is not None:
            fam = agree_fam[name] = agreement(d[c], rate_c, fam_c, 0, seed)
            row["within_family_srcc"], row["within_family_n_groups"] = fam.within_mean, fam.n_setups
            row["within_family_ci95"] = within_ci(fam, n_boot, seed)
        row["compute_time_s"] = None if name in (SETUP_MODEL, BASELINE_MODEL) else _mean_time(maps, map_ids, name)
        row["normalisation"] = norm.as_dict()
        if has_fit:
            agree_fit[name] = agreement(d[c], fitted_target[c], keys_c, n_boot, seed)
            row["fitted"] = agreement_dict(agree_fit[name])
        rows[name] = row
    base_rows = [n for n in BASELINE_ROWS if n in rows]
    tested: dict[str, dict] = {}
    tested_fit: dict[str, dict] = {}
    for name, row in rows.items():
        row["kind"] = "baseline" if name in base_rows else "metric"
        if name in base_rows:
            continue
        comps = tested[name] = _vs_baselines(row, agree, name, base_rows, n_boot, seed)
        if agree_fam:
            for b, cmp in comps.items():
                fc = compare(agree_fam[name], agree_fam[b], n_boot, seed)
                cmp["within_family_diff"], cmp["within_family_ci95"] = fc["within_diff"], fc["within_ci95"]
                cmp["within_family_p"] = fc["within_p"]
            row["beats_baselines_within_family"] = verdict(comps, "within_family_ci95")
        if has_fit:
            tested_fit[name] = _vs_baselines(row["fitted"], agree_fit, name, base_rows, n_boot, seed)
    for key, field in HOLM_FIELDS.items():
        for name, v in holm_verdicts(tested, key).items():
            rows[name][field] = v
    for name, v in holm_verdicts(tested_fit).items():
        rows[name]["fitted"]["beats_baselines_holm"] = v

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

    trial_block = _trial_level(ta, trials, difficulty, c)
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
        "baselines": {"rows": base_rows, "flux_model": None if baseline_fit is None else
                      {"features": varying, "coefficients": [float(x) for x in baseline_fit.coefficients],
                       "r2": baseline_fit.r2, "n_maps": baseline_fit.n}},
        "fitted_difficulty": fitted_summary,
        "trial_level": trial_block,
        "success": _success_block(st, datasets, map_ids),
        "within_setup_reliability": within_setup_reliability(rate_c, st.n[c], keys_c),
        "within_family_reliability": None if fam_c is None else within_setup_reliability(rate_c, st.n[c], fam_c),
        "sigma_bands": bands,
        "regression": regression,
        "regression_raw": regression_raw,
    }
    return _clean(report)


def paired_sections(trials: list[dict], maps: dict, *, n_boot: int = 1000, seed: int = 0) -> dict:
    """The report's "success_by_group" (each pair's success per setup and level, Wilson 95% intervals) and "paired"
    (every two pairs on their common tasks, ``n_boot`` paired-bootstrap draws from ``seed``, exact McNemar p)
    sections (pbdyn.analysis.paired), JSON-safe (NaN as None); format_table prints them when a report has them."""
    from pbdyn.analysis.paired import paired_table, success_by_group

    return _clean({"success_by_group": success_by_group(trials, maps),
                   "paired": paired_table(trials, n_boot=n_boot, seed=seed)})


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


def _term(x) -> str:
    return f"+ {NA}" if x is None else f"{'-' if x < 0 else '+'} {abs(x):.3f}"


def verdict_mark(row: dict, raw: str = "beats_baselines", holm: str = "beats_baselines_holm") -> str:
    """' **' when a row beats every baseline after the multiplicity correction (verdict ``holm``), ' *' when only
    without it (verdict ``raw``), else ''."""
    if (row.get(holm) or {}).get("beats"):
        return " **"
    return " *" if row.get(raw) else ""


def beaters(rows: dict, raw: str = "beats_baselines", holm: str = "beats_baselines_holm", *, sub: str | None = None,
            none: str = "no metric") -> str:
    """The rows (name -> report row; ``sub``: the verdicts of that sub-dict, e.g. "fitted") that beat every baseline
    (verdict ``raw``) and those that still do after Holm's correction; ``none`` when no row does."""
    def pick(r: dict) -> dict:
        return r if sub is None else (r.get(sub) or {})

    beats = [n for n, r in rows.items() if pick(r).get(raw)]
    kept = [n for n in beats if (pick(rows[n]).get(holm) or {}).get("beats")]
    if not beats:
        return none
    return f"{', '.join(beats)} (after Holm's correction: {', '.join(kept) if kept else 'none'})"


def _success_lines(report: dict) -> list[str]:
    """The success table: each planner pair's success per dataset with its Wilson 95% interval, binomial se and the
    se between maps; then the trial and outcome counts."""
    lines = ["Success per planner pair and dataset (Wilson 95% interval; +- binomial se, in parentheses the se "
             "between maps; error trials not rated):"]
    for pair, per in report["success"]["per_pair"].items():
        for ds, s in per.items():
            lines.append(f"  {pair:<40} {ds:<24} {_rate_text(s)} +- {num(s['se'])} "
                         f"({num(s['se_between_maps'])})  {s['n_trials']} trials, {s['n_maps']} maps")
    lines.append(f"Trials: {report['n_trials']} ({report['n_error_trials']} errors, not rated); outcomes: "
                 + ", ".join(f"{k} {v}" for k, v in report["outcomes"].items()))
    return lines


def _rate_text(s: dict) -> str:
    return f"{num(s['rate'])} {interval(s.get('ci95') or [None, None])}"


def verdict_line(report: dict) -> str:
    """One line: which planner pair succeeds most on the controlled dataset (with its Wilson interval, and whether
    it is clearly ahead of the next: the intervals apart), and whether the best difficulty metric (highest SRCC)
    ranks maps better than the setup baseline (setup_model; the 95% interval of their paired SRCC difference)."""
    ds = report["controlled_dataset"]
    rated = [(pair, per[ds]) for pair, per in report["success"]["per_pair"].items()
             if ds in per and per[ds].get("rate") is not None]
    rated.sort(key=lambda kv: -kv[1]["rate"])
    if not rated:
        pairs = f"no planner pair has a rated trial on {ds}"
    elif len(rated) == 1:
        pairs = f"{rated[0][0]} is the only planner pair ({_rate_text(rated[0][1])} on {ds})"
    else:
        top = [p for p, s in rated if s["rate"] == rated[0][1]["rate"]]
        if len(top) > 1:
            pairs = f"{', '.join(top)} succeed equally ({_rate_text(rated[0][1])} on {ds})"
        else:
            (best, sb), (nxt, sn) = rated[0], rated[1]
            lo, hi = (sb.get("ci95") or [None])[0], (sn.get("ci95") or [None, None])[1]
            apart = "" if lo is None or hi is None else (", intervals apart" if lo > hi else ", intervals overlap")
            pairs = (f"{best} succeeds most ({_rate_text(sb)} on {ds}; next {nxt} {_rate_text(sn)}{apart})")
    candidates = [n for n, r in report["metrics"].items() if r.get("kind") != "baseline"]
    metrics = {n: report["metrics"][n] for n in candidates if report["metrics"][n]["srcc_mean"] is not None}
    setup = report["metrics"].get(SETUP_MODEL) or {}
    if not candidates:
        metric = "no difficulty metric to compare with the setup baseline"
    elif not metrics:
        metric = "the metrics cannot rank maps here (too few maps for a rank correlation with success)"
    elif setup.get("srcc_mean") is None:
        metric = "no setup baseline to compare the metrics with (it needs maps of several setups)"
    else:
        name = max(metrics, key=lambda n: metrics[n]["srcc_mean"])
        vs = (metrics[name].get("vs_baselines") or {}).get(SETUP_MODEL) or {}
        ci = vs.get("ci95") or [None, None]
        diff = f"{SETUP_MODEL} SRCC {num(setup['srcc_mean'])}; difference {num(vs.get('diff'), '+.3f')}"
        if ci[0] is None or ci[1] is None:
            how, detail = "is compared without an interval with", f"{diff}; 0 bootstrap draws"
        else:
            how = ("ranks maps better than" if ci[0] > 0 else "ranks maps worse than" if ci[1] < 0
                   else "does not rank maps clearly better than")
            detail = f"{diff} {interval(ci)}"
        metric = f"the best metric, {name} (SRCC {num(metrics[name]['srcc_mean'])}), {how} the setup baseline ({detail})"
    return f"Verdict: {pairs}; {metric}."


def format_table(report: dict) -> str:
    """Text report. It opens with the success table (each planner pair's success per dataset with its Wilson 95%
    interval, the trial and outcome counts) and a verdict line (verdict_line), then success per setup and level when
    the report has them (paired_sections). The statistics follow: the table laid out like thesis table 4-5 (rows:
    metrics and setup_model; columns: Srcc mean +- std over pairs, bootstrap 95% CI, within-setup Srcc, Cv mean +-
    std, compute time per map), the fitted difficulty, the trial level, the sigma bands (tables 4-6..4-8), the eq.
    5-1 regression (table 5-4) and, when the report has them, the paired comparisons."""
    lines = [f"Controlled dataset: {report['controlled_dataset']}  "
             f"({report['datasets'].get(report['controlled_dataset'], 0)} maps, {len(report['pairs'])} planner "
             f"pairs, {report['n_boot']} bootstrap draws)", ""]
    lines += _success_lines(report)
    lines.append(verdict_line(report))
    if report.get("success_by_group"):
        from pbdyn.analysis.paired import format_success_by_group

        lines += format_success_by_group(report["success_by_group"])
    lines += ["", f"Sign: {report['sign_convention']}", ""]
    base = [n for n in (report.get("baselines") or {}).get("rows", []) if n in report["metrics"]]
    best = max(base, key=lambda n: -math.inf if report["metrics"][n]["srcc_mean"] is None
               else report["metrics"][n]["srcc_mean"]) if base else None
    head = (f"{'Metric':<24} {'SRCC':>15} {'95% CI':>17} {'within-setup':>13} {'fitted':>7} "
            f"{'vs best baseline [95% CI]':>27} {'CV':>15} {'time [s]':>9}")
    lines += [head, "-" * len(head)]
    for name, r in report["metrics"].items():
        ci = r["srcc_ci95"]
        vs = (r.get("vs_baselines") or {}).get(best) if best else None
        if vs is not None:
            mark = verdict_mark(r)
            cmp = f"{_term(vs['diff'])} [{num(vs['ci95'][0]):>6}, {num(vs['ci95'][1]):>6}]{mark}"
        else:
            cmp = "(baseline)" if r.get("kind") == "baseline" else NA
        fitted = (r.get("fitted") or {}).get("srcc")
        lines.append(f"{name:<24} {num(r['srcc_mean']):>7} +- {num(r['srcc_std']):<5} "
                     f"[{num(ci[0]):>6}, {num(ci[1]):>6}]  {num(r['within_setup_srcc']):>12} {num(fitted):>7} "
                     f"{cmp:>27} {num(r['cv_mean']):>7} +- {num(r['cv_std']):<5} {num(r['compute_time_s'], '.2f'):>9}")
    if base:
        lines += ["", f"Baselines (need no simulation): {', '.join(base)}; best across maps: {best}. "
                      "'fitted': SRCC against the fitted difficulty (1PL). '*': beats every baseline (95% CI of the "
                      "paired SRCC difference above 0); '**': still after Holm's correction for the number of "
                      "metrics tested.",
                  "Beats every baseline across maps: " + beaters(report["metrics"]) + "; within setups: "
                  + beaters(report["metrics"], "beats_baselines_within_setup", "beats_baselines_within_setup_holm")
                  + "."]
    fd = report.get("fitted_difficulty")
    if fd:
        lines += ["", f"Fitted difficulty: {fd['model']} ({fd['method']}, {fd['n_items']} maps). Planner "
                      "abilities (logits; comparable across maps of different difficulty):"]
        for name, a in sorted(fd["respondents"].items(), key=lambda kv: -kv[1]["ability"]):
            lines.append(f"  {name:<44} {a['ability']:+.3f} +- {a['se']:.3f}  ({a['trials']} trials)")
        t = fd.get("tasks")
        if t and "n_tasks" in t:
            lines.append(f"  Tasks (map, start, goal) as items ({t['method']}, {t['n_tasks']} tasks): difficulty sd "
                         f"{num(t['difficulty_sd'])}, within maps {num(t['within_map_sd'])} (share of variance "
                         f"{num(t['within_map_share_of_variance'])}, {num(t['within_map_share_noise_corrected'])} "
                         f"after the fit's own noise; mean se {num(t['mean_se'])})")
    tl = report.get("trial_level")
    if tl:
        lines += ["", "Trial level (held-out maps): AUC and log-loss of predicting each trial's success from the "
                      "predictor and the planner; gain = log-loss of 'planners only' minus the model's (> 0 helps):"]
        for name, r in tl["predictors"].items():
            ci = r.get("log_loss_gain_ci95") or [None, None]
            mark = verdict_mark(r)
            lines.append(f"  {name:<26} AUC {num(r['auc'])}  log-loss {num(r['log_loss'], '.4f')}  gain "
                         f"{num(r['log_loss_gain'], '+.4f')} [{num(ci[0], '+.4f')}, {num(ci[1], '+.4f')}]  "
                         f"({r['n_trials']} trials){mark}")
        lines.append(f"  ('*': lower held-out log-loss than every baseline predictor ({', '.join(tl['baselines'])}),"
                     " 95% interval over resampled maps; '**': still after Holm's correction for the number of "
                     "predictors tested)")
    fams = [(n, r) for n, r in report["metrics"].items() if r.get("within_family_srcc") is not None]
    if fams:
        fr = report.get("within_family_reliability") or {}
        lines += ["", f"Within structure families (maps of one setup and structure; reliability "
                      f"{num(fr.get('mean_reliability'), '.2f')}; 95% CI over families): " +
                  ", ".join(f"{n} {num(r['within_family_srcc'])} [{num(r['within_family_ci95'][0], '.2f')}, "
                            f"{num(r['within_family_ci95'][1], '.2f')}]" for n, r in fams)]
    rel = report.get("within_setup_reliability") or {}
    if rel.get("n_setups"):
        lines += ["", f"Within-setup reliability of per-map success: {num(rel['mean_reliability'], '.2f')} (mean over "
                      f"pairs over {rel['n_setups']} setups; 1 - binomial noise variance / between-map variance). A "
                      "metric's within-setup SRCC cannot exceed about its square root."]
    b = report.get("sigma_bands")
    if b:
        lines += ["", f"Share of (map, pair) points within k sigma of the controlled fit of success vs "
                      f"{b['metric']} difficulty (tables 4-6..4-8):"]
        for name, s in b["datasets"].items():
            tag = " (controlled, in-sample)" if s["controlled"] else ""
            lines.append(f"  {name:<30} n={s['n_points']:<6} 1s {num(s['within_1sigma'], '.1%'):>6}  "
                         f"2s {num(s['within_2sigma'], '.1%'):>6}  3s {num(s['within_3sigma'], '.1%'):>6}{tag}")
    lines += ["", "Linear model of the setup (eq. 5-1; table 5-4 is the first line):"]
    for key in ("regression", "regression_raw", "setup_model"):
        g = report.get(key)
        if g:
            c = g["coefficients"]
            lines.append(f"  {g['target']} = {num(c['b0'])} {_term(c['b1'])} n {_term(c['b2'])} r {_term(c['b3'])} v"
                         f"   R^2 {num(g['r2'])}  ({g['n_maps']} maps; eq. 5-1)")
    if report.get("paired"):
        from pbdyn.analysis.paired import format_paired

        lines += format_paired(report["paired"])
    return "\n".join(lines)
