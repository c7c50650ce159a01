"""The numbers behind the thesis' figures 5-9, 5-10 and 5-14, as JSON-able tables (what the plots draw).

- fig 5-9: per trajectory planner and survivability difficulty level, the success and deadlock rates (every gaze
  planner pooled);
- fig 5-10: per trajectory planner, gaze planner and difficulty level, the success rate;
- fig 5-14: per planner pair and velocity ratio v_obs / v_max, the success rate.

Controlled-dataset maps only; a cell is {"n": trials, "rate": pooled rate, "se": binomial standard error}. The
difficulty is the report's sigma-band metric (survivability) normalised to [0, 10] (eq. 4-10, 4-11), cut into
integer levels (pbdyn.analysis.cv.difficulty_level).
"""

from __future__ import annotations

import numpy as np

from pbdyn.analysis.cv import LEVELS, difficulty_level
from pbdyn.analysis.regression import setup_features
from pbdyn.analysis.report import difficulty_table
from pbdyn.analysis.success import grouped_rate, trial_arrays
from pbdyn.outcome import Outcome


def _cells(group: np.ndarray, hit: np.ndarray, n_groups: int) -> list[dict]:
    p, se, n = grouped_rate(group, hit, n_groups)
    return [{"n": int(k), "rate": float(r) if k else None, "se": float(s) if k else None}
            for r, s, k in zip(p, se, n)]


def figure_tables(trials: list[dict], maps: dict, report: dict) -> dict:
    """{"fig_5_9": ..., "fig_5_10": ..., "fig_5_14": ...} from the same trials, maps and report as the plots (see
    the module doc); an empty dict for figs 5-9 and 5-10 when the report has no sigma-band metric."""
    map_ids, diff = difficulty_table(maps, report)
    ta = trial_arrays(trials, map_ids)
    c = np.array([str(maps[m].get("dataset", "")) == report["controlled_dataset"] for m in map_ids])
    on_c = c[ta.map_idx] & ta.flown
    success = ta.is_outcome(Outcome.SUCCESS)
    out: dict = {"levels": list(range(LEVELS)), "fig_5_9": {}, "fig_5_10": {}, "fig_5_14": {}}
    band = (report.get("sigma_bands") or {}).get("metric")
    if band in diff:
        out["difficulty"] = band
        lev = np.where(c, difficulty_level(diff[band]), -1)[ta.map_idx]
        nt, ng = len(ta.trajectories), len(ta.gazes)
        g = np.where(on_c & (lev >= 0), ta.trajectory_idx * LEVELS + lev, -1)
        ok = _cells(g, success, nt * LEVELS)
        dl = _cells(g, ta.is_outcome(Outcome.DEADLOCK), nt * LEVELS)
        for i, traj in enumerate(ta.trajectories):
            out["fig_5_9"][traj] = {Outcome.SUCCESS.value: ok[i * LEVELS:(i + 1) * LEVELS],
                                    Outcome.DEADLOCK.value: dl[i * LEVELS:(i + 1) * LEVELS]}
        g = np.where(on_c & (lev >= 0), (ta.trajectory_idx * ng + ta.gaze_idx) * LEVELS + lev, -1)
        cells = _cells(g, success, nt * ng * LEVELS)
        for i, traj in enumerate(ta.trajectories):
            for j, gaze in enumerate(ta.gazes):
                row = cells[(i * ng + j) * LEVELS:(i * ng + j + 1) * LEVELS]
                if any(x["n"] for x in row):
                    out["fig_5_10"].setdefault(traj, {})[gaze] = row
    v_obs = np.array([setup_features(maps[m])[2] for m in map_ids])[ta.map_idx]
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.round(v_obs / ta.mav_speed, 3)
    keep = on_c & np.isfinite(ratio)
    xs, xi = np.unique(np.where(keep, ratio, np.inf), return_inverse=True)
    xs = xs[np.isfinite(xs)]
    grp = np.where(keep, ta.pair_idx * len(xs) + xi.reshape(-1), -1) if len(xs) else np.full(len(keep), -1)
    cells = _cells(grp, success, len(ta.pairs) * len(xs))
    out["fig_5_14"] = {"ratios": [float(x) for x in xs],
                       "success": {pair: cells[j * len(xs):(j + 1) * len(xs)] for j, pair in enumerate(ta.pairs)}}
    return out
