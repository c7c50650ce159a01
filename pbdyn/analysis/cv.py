"""Coefficient of variation of success rates among maps of one difficulty level (thesis eq. 3-10..3-12)."""

from __future__ import annotations

import numpy as np

LEVELS = 10
"""Integer difficulty levels k = 0..9 of the [0, 10] scale (thesis eq. 3-10)."""


def difficulty_level(difficulty: np.ndarray) -> np.ndarray:
    """Level k of each map (thesis eq. 3-10): floor(D), with D = 10 put in level 9 so the levels partition
    [0, 10]; -1 for NaN or for D outside [0, 10]."""
    d = np.asarray(difficulty, float)
    ok = np.isfinite(d) & (d >= 0.0) & (d <= LEVELS)
    k = np.floor(np.where(ok, d, 0.0)).astype(np.int64)
    return np.where(ok, np.minimum(k, LEVELS - 1), -1)


def level_stats(difficulty: np.ndarray, rate: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per level k and pair j the count, mean mu_jk and population std sigma_jk of SR_ij over the maps of level k
    with a rate (thesis eq. 3-10, 3-11). Inputs difficulty [maps], rate [maps, pairs]; outputs [levels, pairs],
    mean and std NaN for an empty cell."""
    rate = np.asarray(rate, float)
    lev = difficulty_level(difficulty)
    ok = (lev[:, None] >= 0) & np.isfinite(rate)
    onehot = (lev[:, None] == np.arange(LEVELS)[None, :]).astype(float)          # [maps, levels]
    w = ok.astype(float)
    r0 = np.where(ok, rate, 0.0)
    cnt = onehot.T @ w
    s1 = onehot.T @ r0
    with np.errstate(invalid="ignore", divide="ignore"):
        mu = np.where(cnt > 0, s1 / cnt, np.nan)
        dev = np.where(ok, rate - mu[np.maximum(lev, 0)], 0.0)                   # two-pass variance
        var = np.where(cnt > 0, (onehot.T @ (dev * dev)) / cnt, np.nan)
    return cnt, mu, np.sqrt(var)


def cv_by_level(difficulty: np.ndarray, rate: np.ndarray, min_maps: int = 2) -> np.ndarray:
    """Cv_jk = sigma_jk / mu_jk (thesis eq. 3-11) per level k and pair j, [levels, pairs]; NaN where the level holds
    fewer than ``min_maps`` maps with a rate of pair j, or mu_jk = 0 (undefined)."""
    cnt, mu, sd = level_stats(difficulty, rate)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where((cnt >= min_maps) & (mu > 0), sd / mu, np.nan)


def cv_summary(cv: np.ndarray) -> dict:
    """Summary of Cv_jk [levels, pairs]: per level the mean over pairs (thesis eq. 3-12), per pair the mean over
    its defined levels, and the mean and population std of those per-pair means (the "CV mean +- std" of
    table 4-5). Undefined entries are skipped; NaN where nothing is defined."""
    cv = np.asarray(cv, float)
    fin = np.isfinite(cv)
    c0 = np.where(fin, cv, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        per_level = np.where(fin.any(axis=1), c0.sum(axis=1) / fin.sum(axis=1), np.nan)
        per_pair = np.where(fin.any(axis=0), c0.sum(axis=0) / fin.sum(axis=0), np.nan)
    pp = per_pair[np.isfinite(per_pair)]
    return {"per_level": per_level, "per_pair": per_pair,
            "mean": float(pp.mean()) if pp.size else float("nan"),
            "std": float(pp.std()) if pp.size else float("nan")}
