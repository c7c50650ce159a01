"""The anchored difficulty scale: one difficulty a paper can quote (docs/difficulty-scale.md).

The difficulty of a task set -- a map with its start/goal pairs and MAV speeds -- is the expected success of a fixed
reference panel of built-in planners at their defaults (PANEL) flying the reference tasks of that map: the ordered
pairs among at most REFERENCE_CANDIDATES of its start/goal candidates (reference_pairs) at each of PANEL_SPEEDS.
It is reported as a success rate and as a logit on a 1PL item-response scale (P(success of respondent j on map i) =
sigmoid(theta_j - b_i), respondents = panel pair x MAV speed) whose zero and unit are fixed once by a frozen
calibration set (scenarios/calibration/): the respondents' abilities theta_j fitted there are shipped with pbdyn,
and every new map's b is estimated against those fixed abilities (linking by fixed respondent parameters, never
re-centred per store). SCALE_VERSION names the panel, the reference tasks and the calibration.
"""

from __future__ import annotations

import copy

from pbdyn.config import PlannerEntry

SCALE_VERSION = "1"
PANEL = (PlannerEntry("local_primitives", "lookahead"), PlannerEntry("global_primitives", "fullrange"),
         PlannerEntry("mpc", "lookahead"))
"""The reference panel: (trajectory, gaze) pairs at their defaults (the thesis' three trajectory planners)."""
PANEL_SPEEDS = (2.0, 4.0, 6.0)
"""MAV speed limits (m/s) the panel flies every reference task at (the thesis' grid, table 4-4)."""
REFERENCE_CANDIDATES = 5
"""At most this many start/goal candidates make a map's reference tasks: 5 -> 20 ordered pairs."""


def reference_candidates(candidates) -> list[int]:
    """Indices of the candidates whose ordered pairs are the reference tasks: all of them if there are at most
    REFERENCE_CANDIDATES, else the one nearest the candidates' centroid and the four extremes of x + y and x - y
    (on the default 3 x 3 grid: the centre and the corners), in index order."""
    pts = [tuple(float(x) for x in c) for c in candidates]
    if len(pts) <= REFERENCE_CANDIDATES:
        return list(range(len(pts)))
    cx = sum(p[0] for p in pts) / len(pts)
    cy = sum(p[1] for p in pts) / len(pts)
    chosen = [min(range(len(pts)), key=lambda i: ((pts[i][0] - cx) ** 2 + (pts[i][1] - cy) ** 2, i))]
    for sign in (1.0, -1.0):                 # the extremes of x + y, then of x - y (ties: the lower index)
        for lowest in (True, False):
            left = [i for i in range(len(pts)) if i not in chosen]
            score = [(pts[i][0] + sign * pts[i][1]) * (1.0 if lowest else -1.0) for i in left]
            chosen.append(left[min(range(len(left)), key=lambda k: (score[k], left[k]))])
    rest = [i for i in range(len(pts)) if i not in chosen]
    return sorted(chosen + rest[:REFERENCE_CANDIDATES - len(chosen)])


def reference_pairs(candidates) -> list[tuple[int, int]]:
    """The reference tasks of a map: every ordered (start, goal) pair of reference_candidates()."""
    idx = reference_candidates(candidates)
    return [(i, j) for i in idx for j in idx if i != j]


def reference_document(doc: dict, candidates) -> dict:
    """A scenario document (TOML-shaped dict) whose experiment is the reference flights of its maps: the same
    world, obstacles, maps, MAV and sensor, with planners = PANEL, drone.v_max = PANEL_SPEEDS and
    task.pairs_flown = reference_pairs(candidates) (``candidates``: the scenario's resolved candidates). The maps
    are unchanged: the candidates stay (maps are built around them); only the pairs flown are chosen."""
    out = copy.deepcopy(doc)
    out["planners"] = [{"trajectory": e.trajectory, "gaze": e.gaze} for e in PANEL]
    out.setdefault("drone", {})["v_max"] = list(PANEL_SPEEDS)
    out.setdefault("task", {})["pairs_flown"] = [list(p) for p in reference_pairs(candidates)]
    return out


# ------------------------------------------------------------------------------------------------ the anchored fit
PRIOR_TRIALS = 1.0
"""Pseudo-trials per map (half successes, by the average anchored respondent), as pbdyn.analysis.irt.fit_rasch:
a map every panel trial of which succeeded (or failed) still gets a finite difficulty."""
BOOTSTRAP = 1000
"""Resamples of a map's reference tasks behind its 95% intervals (tasks, not trials, are resampled: the panel's
trials of one task are not independent)."""
ANCHORS_FILE = "anchors.json"
"""The shipped calibration (pbdyn/analysis/data/): the respondents' abilities and the calibration maps'
difficulties and reference successes."""


def respondent(label: str, v_max: float) -> str:
    """A respondent's name: the panel pair's label at one MAV speed, e.g. "lookahead+mpc@4"."""
    return f"{label}@{float(v_max):g}"


def sigmoid(x):
    """1 / (1 + exp(-x)), elementwise."""
    import numpy as np

    return 1.0 / (1.0 + np.exp(-np.asarray(x, float)))


def difficulty_given_abilities(theta, k, n, *, prior_trials: float = PRIOR_TRIALS):
    """The maximum-likelihood difficulty b (logits) of a map whose respondents with fixed abilities ``theta`` [J]
    succeeded ``k`` of ``n`` times (P = sigmoid(theta_j - b)), with ``prior_trials`` pseudo-trials, half
    successes, at the mean ability. ``k``, ``n``: [J] (a float is returned) or [B, J] (B maps or resamples at once:
    an array [B]). Newton's method on the concave log-likelihood."""
    import numpy as np

    theta = np.asarray(theta, float)
    k = np.asarray(k, float)
    n = np.asarray(n, float)
    one = k.ndim == 1
    k, n = np.atleast_2d(k), np.atleast_2d(n)
    if prior_trials > 0:
        theta = np.append(theta, theta.mean())
        k = np.concatenate([k, np.full((k.shape[0], 1), 0.5 * prior_trials)], axis=1)
        n = np.concatenate([n, np.full((n.shape[0], 1), float(prior_trials))], axis=1)
    rate = np.clip(k.sum(axis=1) / np.maximum(n.sum(axis=1), 1e-300), 1e-6, 1 - 1e-6)
    b = np.log((1.0 - rate) / rate) + theta.mean()
    for _ in range(200):
        p = sigmoid(theta[None, :] - b[:, None])
        grad = np.sum(n * p - k, axis=1)                   # d logL / d b
        curv = np.sum(n * p * (1.0 - p), axis=1)           # -d2 logL / d b2
        step = grad / np.maximum(curv, 1e-12)
        b = b + step
        if np.all(np.abs(step) < 1e-12):
            break
    return float(b[0]) if one else b


def ability_given_difficulties(b, k, n, *, prior_trials: float = PRIOR_TRIALS) -> float:
    """The maximum-likelihood ability (logits) of one respondent that succeeded ``k`` [I] of ``n`` [I] times on
    maps of fixed difficulties ``b`` [I] (the mirror of difficulty_given_abilities)."""
    import numpy as np

    return -difficulty_given_abilities(-np.asarray(b, float), k, n, prior_trials=prior_trials)
