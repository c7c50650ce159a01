"""Success rates SR_ij of planner pairs on maps (thesis 3-2, table 2-2 outcomes) and their standard errors.

Trials whose outcome is "error" (the trial raised in a batch) are not flown trials: they are counted but enter
no rate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pbdyn.errors import ConfigError
from pbdyn.outcome import OUTCOMES, Outcome  # OUTCOMES: outcome names as stored; "error" marks a trial that raised


@dataclass(frozen=True)
class TrialArrays:
    """Trials as parallel arrays [T] of indices into the name tuples (one row per trial)."""

    map_ids: tuple[str, ...]
    pairs: tuple[str, ...]
    trajectories: tuple[str, ...]
    gazes: tuple[str, ...]
    map_idx: np.ndarray
    pair_idx: np.ndarray
    trajectory_idx: np.ndarray
    gaze_idx: np.ndarray
    outcome_idx: np.ndarray
    mav_speed: np.ndarray

    @property
    def flown(self) -> np.ndarray:
        """Mask [T] of trials that ended with a real outcome (not "error")."""
        return self.outcome_idx != OUTCOMES.index(Outcome.ERROR.value)

    def is_outcome(self, name: str | Outcome) -> np.ndarray:
        """Mask [T] of trials with outcome ``name`` (an Outcome or its value)."""
        return self.outcome_idx == OUTCOMES.index(Outcome(name).value)


def _codes(values: list) -> tuple[tuple[str, ...], np.ndarray]:
    names, idx = np.unique(np.asarray([str(v) for v in values], dtype=str), return_inverse=True)
    return tuple(str(n) for n in names), idx.astype(np.int64)


def trial_arrays(trials: list[dict], map_ids: tuple[str, ...]) -> TrialArrays:
    """Index the trial dicts (keys map_id, pair, trajectory, gaze, mav_speed, outcome) against ``map_ids``; a
    trial on an unknown map or with an unknown outcome is a ConfigError."""
    pos = {m: i for i, m in enumerate(map_ids)}
    try:
        map_idx = np.fromiter((pos[t["map_id"]] for t in trials), dtype=np.int64, count=len(trials))
    except KeyError as exc:
        raise ConfigError("trials.map_id", "trial on a map missing from the maps table", exc.args[0]) from None
    opos = {o: i for i, o in enumerate(OUTCOMES)}
    try:
        outcome_idx = np.fromiter((opos[t["outcome"]] for t in trials), dtype=np.int64, count=len(trials))
    except KeyError as exc:
        raise ConfigError("trials.outcome", f"must be one of {', '.join(OUTCOMES)}", exc.args[0]) from None
    pairs, pair_idx = _codes([t["pair"] for t in trials])
    trajs, traj_idx = _codes([t["trajectory"] for t in trials])
    gazes, gaze_idx = _codes([t["gaze"] for t in trials])
    speed = np.fromiter((float(t["mav_speed"]) for t in trials), dtype=float, count=len(trials))
    return TrialArrays(map_ids, pairs, trajs, gazes, map_idx, pair_idx, traj_idx, gaze_idx, outcome_idx, speed)


def rate_and_se(k: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Success rate p = k / n and its binomial standard error sqrt(p (1 - p) / n); NaN where n = 0."""
    k = np.asarray(k, float)
    n = np.asarray(n, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        p = np.where(n > 0, k / n, np.nan)
        se = np.where(n > 0, np.sqrt(p * (1.0 - p) / n), np.nan)
    return p, se


def grouped_rate(group: np.ndarray, hit: np.ndarray, n_groups: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rate of ``hit`` (bool [T]) within each group (int [T] in [0, n_groups); negative = left out).

    Returns (rate, se, n), each [n_groups]; rate and se are NaN for empty groups."""
    keep = group >= 0
    n = np.bincount(group[keep], minlength=n_groups)
    k = np.bincount(group[keep], weights=hit[keep].astype(float), minlength=n_groups)
    p, se = rate_and_se(k, n)
    return p, se, n


@dataclass(frozen=True)
class SuccessTable:
    """Success rates SR_ij [maps, pairs] (thesis 3-2) from flown trials; NaN where a pair never flew a map."""

    map_ids: tuple[str, ...]
    pairs: tuple[str, ...]
    n: np.ndarray
    successes: np.ndarray
    rate: np.ndarray
    se: np.ndarray
    pooled_n: np.ndarray
    pooled_rate: np.ndarray
    pooled_se: np.ndarray


def success_table(ta: TrialArrays) -> SuccessTable:
    """SR_ij = successes / flown trials of pair j on map i (thesis 3-2), its binomial standard error, and the
    per-map rate pooled over every pair's flown trials."""
    m, p = len(ta.map_ids), len(ta.pairs)
    flown = ta.flown
    cell = np.where(flown, ta.map_idx * p + ta.pair_idx, -1)
    success = ta.is_outcome(Outcome.SUCCESS)
    _, _, n = grouped_rate(cell, success, m * p)
    k = np.bincount(cell[flown], weights=success[flown].astype(float), minlength=m * p)
    rate, se = rate_and_se(k, n)
    pr, pse, pn = grouped_rate(np.where(flown, ta.map_idx, -1), success, m)
    return SuccessTable(ta.map_ids, ta.pairs, n.reshape(m, p), k.reshape(m, p).astype(np.int64),
                        rate.reshape(m, p), se.reshape(m, p), pn, pr, pse)


def within_setup_reliability(rate: np.ndarray, n: np.ndarray, groups, min_maps: int = 3) -> dict:
    """How much of the map-to-map spread of success within setups is real rather than trial noise.

    rate, n: success rates and trial counts [maps, pairs]; groups: a setup key per map. Per pair, over the setups
    with >= min_maps flown maps: V_b = mean within-setup sample variance of the rates (ddof 1), V_n = mean binomial
    noise variance rate (1 - rate) / n; reliability = 1 - V_n / V_b (the share of V_b that is not noise; <= 0:
    within a setup, maps cannot be told apart at this trial count). Since noise caps any metric's correlation with
    success near sqrt(reliability), it bounds what the within-setup SRCC can show. Returns per-pair values and
    their mean."""
    rate = np.asarray(rate, float)
    n = np.asarray(n, float)
    keys = np.asarray([str(g) for g in groups])
    out = {"per_pair": [], "n_setups": 0}
    for j in range(rate.shape[1]):
        vb, vn = [], []
        for key in np.unique(keys):
            sel = (keys == key) & (n[:, j] > 0) & np.isfinite(rate[:, j])
            if sel.sum() < min_maps:
                continue
            r = rate[sel, j]
            vb.append(r.var(ddof=1))
            vn.append(np.mean(r * (1.0 - r) / n[sel, j]))
        out["n_setups"] = max(out["n_setups"], len(vb))
        if vb and np.mean(vb) > 0:
            out["per_pair"].append({"between_var": float(np.mean(vb)), "noise_var": float(np.mean(vn)),
                                    "reliability": float(1.0 - np.mean(vn) / np.mean(vb))})
        else:
            out["per_pair"].append({"between_var": float(np.mean(vb)) if vb else float("nan"),
                                    "noise_var": float(np.mean(vn)) if vn else float("nan"),
                                    "reliability": float("nan")})
    rel = [p["reliability"] for p in out["per_pair"] if np.isfinite(p["reliability"])]
    out["mean_reliability"] = float(np.mean(rel)) if rel else float("nan")
    return out
