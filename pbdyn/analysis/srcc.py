"""Spearman's rank correlation between a map metric and success rates (thesis eq. 3-8, 3-9), its bootstrap over
maps, and its value within map setups.

All functions here return the plain coefficient of eq. 3-8 between the two arguments; the sign convention of the
report (positive = the metric ranks maps like success does) is applied by the caller.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.stats import rankdata


def spearman(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Spearman's rank correlation (thesis eq. 3-8; average ranks for ties, i.e. Pearson's r of the ranks) along
    the last axis of the broadcast ``x`` and ``y``, over the entries finite in both.

    Degenerate slices: NaN with fewer than 2 joint entries or when ``y`` is constant (nothing to rank against);
    0 when only ``x`` is constant (the metric tells the maps apart no better than chance)."""
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    shape = np.broadcast_shapes(x.shape, y.shape)
    if np.isfinite(x).all() and np.isfinite(y).all():        # fast path: rank each operand once, then broadcast
        rx = np.broadcast_to(rankdata(x, axis=-1), shape)
        ry = np.broadcast_to(rankdata(y, axis=-1), shape)
        ok = np.ones(shape, dtype=bool)
    else:
        x, y = np.broadcast_arrays(x, y)
        ok = np.isfinite(x) & np.isfinite(y)
        rx = rankdata(np.where(ok, x, np.nan), axis=-1, nan_policy="omit")
        ry = rankdata(np.where(ok, y, np.nan), axis=-1, nan_policy="omit")
    n = ok.sum(axis=-1)
    nn = np.maximum(n, 1)
    dx = np.where(ok, rx - (np.where(ok, rx, 0.0).sum(axis=-1) / nn)[..., None], 0.0)
    dy = np.where(ok, ry - (np.where(ok, ry, 0.0).sum(axis=-1) / nn)[..., None], 0.0)
    sxx = (dx * dx).sum(axis=-1)
    syy = (dy * dy).sum(axis=-1)
    sxy = (dx * dy).sum(axis=-1)
    tiny = 1e-9 * np.maximum(n, 1) ** 3
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.clip(sxy / np.sqrt(sxx * syy), -1.0, 1.0)
    r = np.where(sxx <= tiny, 0.0, r)
    return np.where((n < 2) | (syy <= tiny), np.nan, r)


def pair_srcc(metric: np.ndarray, rate: np.ndarray) -> np.ndarray:
    """Srcc_j (thesis eq. 3-8) between a metric [maps] and each pair's success rate rate[maps, pairs]: [pairs]."""
    return spearman(np.asarray(metric, float)[None, :], np.asarray(rate, float).T)


def mean_std(values: np.ndarray) -> tuple[float, float]:
    """Mean (thesis eq. 3-9) and population std over the finite entries; (NaN, NaN) if there are none."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return float("nan"), float("nan")
    return float(v.mean()), float(v.std())


def weighted_ranks(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Average ranks (ties share the mean rank) of ``values`` [maps] in each multiset where map i occurs
    weights[b, i] times (weights [draws, maps], integer counts): the ranks a resample with those multiplicities
    would give every copy of the map. Returns [draws, maps]; entries of weight 0 are meaningless."""
    v = np.asarray(values, float)
    order = np.argsort(v, kind="stable")
    sv = v[order]
    new = np.r_[True, ~(sv[1:] == sv[:-1])]                     # NaNs (weight 0 by the caller) stay singletons
    gid = np.cumsum(new) - 1
    starts = np.flatnonzero(new)
    ends = np.r_[starts[1:], v.size] - 1
    ws = np.asarray(weights, float)[:, order]
    cum = np.cumsum(ws, axis=1)
    before = cum[:, starts] - ws[:, starts]
    grank = before + 0.5 * (cum[:, ends] - before + 1.0)
    out = np.empty_like(ws)
    out[:, order] = grank[:, gid]
    return out


def _weighted_rank_corr(x: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Spearman's coefficient (eq. 3-8) of x, y [maps] in each weighted multiset w [draws, maps] (same conventions
    as ``spearman``): [draws]."""
    rx = weighted_ranks(x, w)
    ry = weighted_ranks(y, w)
    n = w.sum(axis=1)
    nn = np.maximum(n, 1.0)
    dx = rx - ((w * rx).sum(axis=1) / nn)[:, None]
    dy = ry - ((w * ry).sum(axis=1) / nn)[:, None]
    sxx = (w * dx * dx).sum(axis=1)
    syy = (w * dy * dy).sum(axis=1)
    sxy = (w * dx * dy).sum(axis=1)
    tiny = 1e-9 * np.maximum(n, 1.0) ** 3
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.clip(sxy / np.sqrt(sxx * syy), -1.0, 1.0)
    r = np.where(sxx <= tiny, 0.0, r)
    return np.where((n < 2) | (syy <= tiny), np.nan, r)


def bootstrap_mean_srcc(metric: np.ndarray, rate: np.ndarray, rng: np.random.Generator, n_boot: int) -> np.ndarray:
    """Bootstrap distribution [n_boot] of the mean Srcc over pairs (thesis eq. 3-9) when the maps are resampled
    with replacement (metric [maps], rate [maps, pairs]); each draw uses the same resampled maps for every pair.

    Draw b takes maps idx[b] = rng.integers(0, maps, maps); it is evaluated as multiplicities (no resampled copy
    is built), which equals ``spearman`` on metric[idx[b]], rate[idx[b]] exactly. A draw where no pair has a
    defined Srcc is NaN."""
    metric = np.asarray(metric, float)
    rate = np.asarray(rate, float)
    m, p = rate.shape
    idx = rng.integers(0, m, size=(n_boot, m))
    counts = np.bincount((np.arange(n_boot)[:, None] * m + idx).ravel(), minlength=n_boot * m)
    counts = counts.reshape(n_boot, m).astype(float)
    tot = np.zeros(n_boot)
    cnt = np.zeros(n_boot)
    for j in range(p):                                            # a loop over planner pairs only
        ok = np.isfinite(metric) & np.isfinite(rate[:, j])
        r = _weighted_rank_corr(metric, rate[:, j], counts * ok[None, :])
        fin = np.isfinite(r)
        tot += np.where(fin, r, 0.0)
        cnt += fin
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(cnt > 0, tot / np.maximum(cnt, 1.0), np.nan)


def percentile_ci(draws: np.ndarray, level: float = 0.95) -> tuple[float, float]:
    """Percentile bootstrap interval of ``level`` over the finite draws; (NaN, NaN) if none."""
    d = np.asarray(draws, float)
    d = d[np.isfinite(d)]
    if d.size == 0:
        return float("nan"), float("nan")
    a = 50.0 * (1.0 - level)
    lo, hi = np.percentile(d, [a, 100.0 - a])
    return float(lo), float(hi)


def within_group_srcc(metric: np.ndarray, rate: np.ndarray, groups: Sequence[str], min_maps: int = 3
                      ) -> tuple[np.ndarray, int]:
    """Srcc_j (thesis eq. 3-8) computed inside each group of maps (e.g. maps of one (n, r, v) setup, which differ
    only by seed) with at least ``min_maps`` maps; the group "" (maps of no setup) is left out.

    Returns (values [groups_used * pairs], groups_used); values holds NaN where undefined (see ``spearman``)."""
    metric = np.asarray(metric, float)
    rate = np.asarray(rate, float)
    keys, inv = np.unique(np.asarray(groups, dtype=str), return_inverse=True)
    vals = []
    used = 0
    for g in range(len(keys)):
        sel = np.flatnonzero(inv == g)
        if sel.size < min_maps or keys[g] == "":
            continue
        used += 1
        vals.append(pair_srcc(metric[sel], rate[sel]))
    return (np.concatenate(vals) if vals else np.empty(0)), used
