"""The anchored difficulty scale: one difficulty a paper can quote (README "Difficulty on one scale").

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
