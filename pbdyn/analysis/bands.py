"""Share of maps within 1, 2, 3 sigma of the success-vs-difficulty curve fitted on the controlled maps (thesis 4-3,
tables 4-6..4-8)."""

from __future__ import annotations

import numpy as np

from pbdyn.analysis.cv import LEVELS, level_stats


def band_fit(difficulty: np.ndarray, rate: np.ndarray, min_maps: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """The controlled fit (thesis 4-3): per pair j and difficulty level k the mean mu_jk and population std
    sigma_jk of SR_ij (levels with fewer than ``min_maps`` maps are NaN). Returns (mu, sigma), [levels, pairs]."""
    cnt, mu, sd = level_stats(difficulty, rate)
    bad = cnt < min_maps
    return np.where(bad, np.nan, mu), np.where(bad, np.nan, sd)


def band_curve(mu: np.ndarray, sigma: np.ndarray, difficulty: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """mu_j(D), sigma_j(D) at each map's difficulty [maps] for every pair: linear interpolation between the level
    centres k + 0.5, held constant beyond the first/last defined level. Returns [maps, pairs]; NaN for a pair with
    no defined level or a NaN difficulty."""
    d = np.asarray(difficulty, float)
    centres = np.arange(LEVELS) + 0.5
    p = mu.shape[1]
    m_out = np.full((d.shape[0], p), np.nan)
    s_out = np.full((d.shape[0], p), np.nan)
    fin = np.isfinite(d)
    for j in range(p):                                    # a loop over planner pairs only
        ok = np.isfinite(mu[:, j])
        if not ok.any():
            continue
        m_out[fin, j] = np.interp(d[fin], centres[ok], mu[ok, j])
        s_out[fin, j] = np.interp(d[fin], centres[ok], sigma[ok, j])
    return m_out, s_out


def band_shares(mu: np.ndarray, sigma: np.ndarray, difficulty: np.ndarray, rate: np.ndarray,
                ks: tuple[int, ...] = (1, 2, 3)) -> dict:
    """Share of (map, pair) points with |SR_ij - mu_j(D_i)| <= k sigma_j(D_i) for each k (thesis tables 4-6..4-8),
    over the points where both the rate and the fitted curve are defined. Returns {"n_points", "within": [shares]}."""
    m, s = band_curve(mu, sigma, difficulty)
    rate = np.asarray(rate, float)
    ok = np.isfinite(rate) & np.isfinite(m) & np.isfinite(s)
    n = int(ok.sum())
    dev = np.abs(rate - m)[ok]
    sig = s[ok]
    within = [float(np.mean(dev <= k * sig + 1e-12)) if n else float("nan") for k in ks]
    return {"n_points": n, "within": within}
