"""A metric's rank agreement with a target (success rates, or the fitted difficulty), and whether it beats the
baselines that need no simulation (docs/design.md "Difficulty: what counts as evidence").

Conventions (those of pbdyn.analysis.report): a metric enters as its difficulty d [maps] (high = hard); the target
is a rate-like matrix [maps, k] (high = easy: success rates per pair, or minus the fitted difficulty as one column);
srcc = -Srcc(d, target), averaged over the k columns, positive when the metric ranks maps as the target does.

Comparisons are paired: every row is bootstrapped over the same resampled maps (the same Generator seed), so the
difference of two rows per draw gives the interval of their difference; within setups the per-(setup, column)
values of two rows are differenced and the mean difference is bootstrapped over setups.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pbdyn.analysis.srcc import bootstrap_mean_srcc, mean_std, pair_srcc, percentile_ci, within_group_srcc

MIN_SETUP_MAPS = 3
"""Fewest maps of one setup for the within-setup Srcc."""


@dataclass(frozen=True)
class Agreement:
    """One row's agreement with one target. srcc (mean over the target's columns), per_column [k], draws [n_boot]
    (bootstrap over maps), within [setups, k] (per setup and column; NaN where undefined), within_mean,
    within_std, n_setups."""

    srcc: float
    std: float
    per_column: np.ndarray
    draws: np.ndarray
    within: np.ndarray
    within_mean: float
    within_std: float
    n_setups: int

    @property
    def ci95(self) -> tuple[float, float]:
        """Percentile 95% interval of the bootstrap draws."""
        return percentile_ci(self.draws)


def agreement(d: np.ndarray, target: np.ndarray, keys: Sequence[str], n_boot: int, seed: int) -> Agreement:
    """Agreement of difficulty ``d`` [maps] with ``target`` [maps, k] (module doc); keys: setup key per map."""
    target = np.asarray(target, float).reshape(len(d), -1)
    per = -pair_srcc(d, target)
    mean, std = mean_std(per)
    draws = -bootstrap_mean_srcc(d, target, np.random.default_rng(seed), n_boot) if n_boot > 0 else np.empty(0)
    within, n_setups = within_group_srcc(d, target, keys, MIN_SETUP_MAPS)
    within = -within.reshape(n_setups, target.shape[1]) if n_setups else np.empty((0, target.shape[1]))
    w_mean, w_std = mean_std(within.reshape(-1))
    return Agreement(mean, std, per, draws, within, w_mean, w_std, n_setups)


ALPHA = 0.025
"""One-sided level of every "beats the baselines" test: a difference whose 95% percentile interval lies above 0
has a one-sided bootstrap p-value (one_sided_p) of about 0.025 or less."""


def one_sided_p(draws: np.ndarray) -> float:
    """Bootstrap p-value of "the difference is <= 0": (1 + draws <= 0) / (1 + finite draws); NaN without draws."""
    d = np.asarray(draws, float)
    d = d[np.isfinite(d)]
    return float((1 + np.count_nonzero(d <= 0.0)) / (1 + d.size)) if d.size else float("nan")


def grouped_mean_draws(sums: np.ndarray, counts: np.ndarray, n_boot: int, seed: int) -> np.ndarray:
    """Bootstrap draws [n_boot] of the pooled mean sum(sums) / sum(counts) when the groups (entries of ``sums`` and
    ``counts`` [G]: per group a sum of values and their number) are resampled with replacement, from
    numpy.random.default_rng(seed); empty when fewer than 2 groups hold a value or n_boot is 0."""
    if n_boot <= 0 or np.count_nonzero(counts) < 2:
        return np.empty(0)
    idx = np.random.default_rng(seed).integers(0, sums.shape[0], size=(n_boot, sums.shape[0]))
    tot = counts[idx].sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(tot > 0, sums[idx].sum(axis=1) / np.maximum(tot, 1.0), np.nan)


def grouped_mean_ci(sums: np.ndarray, counts: np.ndarray, n_boot: int, seed: int) -> list[float]:
    """95% percentile interval of grouped_mean_draws; NaN when there are none."""
    return list(percentile_ci(grouped_mean_draws(sums, counts, n_boot, seed)))


def _group_sums(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(per-row sums of the finite entries, their counts) of values [G, k]."""
    ok = np.isfinite(values)
    return np.where(ok, values, 0.0).sum(axis=1), ok.sum(axis=1).astype(float)


def compare(a: Agreement, b: Agreement, n_boot: int, seed: int) -> dict:
    """Row a minus row b (same maps, same target, same bootstrap draws): across maps ("diff", "ci95", "p": the
    one-sided bootstrap p-value of diff <= 0) and within setups ("within_diff": the mean over the (setup, column)
    entries defined for both, like within_mean; "within_ci95", "within_p": that mean bootstrapped over setups,
    grouped_mean_draws)."""
    nan2 = [float("nan")] * 2
    diff = a.draws - b.draws if a.draws.size else np.empty(0)
    out = {"diff": a.srcc - b.srcc, "ci95": list(percentile_ci(diff)) if diff.size else nan2,
           "p": one_sided_p(diff), "within_diff": float("nan"), "within_ci95": nan2, "within_p": float("nan")}
    if not (a.within.size and a.within.shape == b.within.shape):
        return out
    sums, counts = _group_sums(a.within - b.within)
    if counts.sum() == 0:
        return out
    out["within_diff"] = float(sums.sum() / counts.sum())
    draws = grouped_mean_draws(sums, counts, n_boot, seed)
    out["within_ci95"], out["within_p"] = list(percentile_ci(draws)), one_sided_p(draws)
    return out


def within_ci(a: Agreement, n_boot: int, seed: int) -> list[float]:
    """95% interval of a row's mean within-group Srcc when the groups (setups, or structure families) are resampled
    with replacement (grouped_mean_ci)."""
    if not a.within.size:
        return [float("nan")] * 2
    return grouped_mean_ci(*_group_sums(a.within), n_boot, seed)


def verdict(comparisons: dict[str, dict], key: str = "ci95") -> bool | None:
    """True when the metric beats every baseline (the interval of each difference lies above 0), False when some
    interval does not, None without baselines or intervals."""
    los = [c[key][0] for c in comparisons.values() if c.get(key) and np.isfinite(c[key][0])]
    if not los or len(los) < len(comparisons):
        return None
    return bool(min(los) > 0)


def holm_verdicts(comparisons: dict[str, dict[str, dict]], key: str = "p") -> dict[str, dict]:
    """The "beats every baseline" test of several metrics at once, corrected for their number (Holm).

    comparisons: metric -> {baseline: compare()-like dict holding the p-value ``key``}. A metric beats every
    baseline when each difference is > 0, so its p-value is the largest of its baselines' (an intersection-union
    test needs no correction across baselines); Holm's step-down adjustment (statsmodels multipletests) then
    controls the chance that any metric is wrongly said to beat them all at ALPHA (one-sided). Returns metric ->
    {"p": its p-value, "p_holm": adjusted, "beats": adjusted p <= ALPHA, "n_tests": metrics tested}; metrics
    without a p-value for every baseline are left out."""
    from statsmodels.stats.multitest import multipletests

    names, ps = [], []
    for name, comps in comparisons.items():
        p = [c.get(key) for c in comps.values()]
        if comps and all(x is not None and np.isfinite(x) for x in p):
            names.append(name)
            ps.append(max(p))
    if not names:
        return {}
    adjusted = multipletests(ps, alpha=ALPHA, method="holm")[1]
    return {n: {"p": float(p), "p_holm": float(q), "beats": bool(q <= ALPHA), "n_tests": len(names)}
            for n, p, q in zip(names, ps, adjusted)}


def agreement_dict(a: Agreement) -> dict:
    """The JSON-able summary of an Agreement (draws and per-setup values left out)."""
    return {"srcc": a.srcc, "srcc_std": a.std, "ci95": list(a.ci95), "within_setup_srcc": a.within_mean,
            "within_setup_srcc_std": a.within_std, "within_setup_n_setups": a.n_setups}
