"""The anchored difficulty scale: one difficulty a paper can quote (docs/difficulty-scale.md).

The difficulty of a task set -- a map with its start/goal pairs and MAV speeds -- is the expected success of a fixed
reference panel of built-in planners at their defaults (PANEL) flying the reference tasks of that map: the ordered
pairs among at most REFERENCE_CANDIDATES of its start/goal candidates (reference_pairs) at each of PANEL_SPEEDS.
It is reported as a success rate and as a logit on a 1PL item-response scale (P(success of respondent j on map i) =
sigmoid(theta_j - b_i), respondents = panel pair x MAV speed) whose zero and unit are fixed once by a frozen
calibration set (scenarios/calibration/): the respondents' abilities theta_j fitted there are shipped with pbdyn,
and every new map's b is estimated against those fixed abilities (linking by fixed respondent parameters, never
re-centred per store). SCALE_VERSION names the panel, the reference tasks and the calibration.
The anchors (load_anchors), a map's difficulty measured from the panel's flights (measure_difficulties) and a
store placed on the scale (place_on_scale) are here too; pbdyn.experiments.calibrate only flies the panel.
"""

from __future__ import annotations

import copy
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pbdyn.config import PlannerEntry, stable_hash64
from pbdyn.errors import ConfigError

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
    return 1.0 / (1.0 + np.exp(-np.asarray(x, float)))


def difficulty_given_abilities(theta, k, n, *, prior_trials: float = PRIOR_TRIALS):
    """The maximum-likelihood difficulty b (logits) of a map whose respondents with fixed abilities ``theta`` [J]
    succeeded ``k`` of ``n`` times (P = sigmoid(theta_j - b)), with ``prior_trials`` pseudo-trials, half
    successes, at the mean ability. ``k``, ``n``: [J] (a float is returned) or [B, J] (B maps or resamples at once:
    an array [B]). Newton's method on the concave log-likelihood."""
    theta, k, n = (np.asarray(x, float) for x in (theta, k, n))
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


def ability_given_difficulties(b, k, n, *, prior_trials: float = PRIOR_TRIALS):
    """The maximum-likelihood ability (logits) of one respondent that succeeded ``k`` [I] of ``n`` [I] times on
    maps of fixed difficulties ``b`` [I] (the mirror of difficulty_given_abilities; ``k``, ``n`` [B, I]: B
    resamples at once, an array [B])."""
    return -difficulty_given_abilities(-np.asarray(b, float), k, n, prior_trials=prior_trials)


# ------------------------------------------------------------------------------------------------ the anchors
RESPONDENTS = tuple(respondent(e.label, v) for e in PANEL for v in PANEL_SPEEDS)
"""The panel's respondents, in a fixed order."""


@dataclass(frozen=True)
class Anchors:
    """The shipped calibration: ``abilities`` (respondent -> logits), the calibration maps' ``difficulties`` per
    dims ({2: [...], 3: [...]}, logits; for percentiles), its version and where it came from (``source``);
    ``code``: the code fingerprints the calibration was flown with (panel label -> [fingerprints]; {} for anchors
    fitted before pbdyn recorded code identities)."""

    version: str
    abilities: dict
    difficulties: dict = field(default_factory=dict)
    source: str = ""
    code: dict = field(default_factory=dict)

    def code_status(self, fingerprint) -> str:
        """Whether this pbdyn flies the calibration's code (docs/design.md "Code identity"): "same" when every
        panel pair's fingerprint now, ``fingerprint(trajectory, gaze)`` (pbdyn.planning.registry.pair_fingerprint,
        passed in: analysis does not import planning), is the one recorded, "other" when one differs, "not
        recorded"."""
        if not self.code:
            return "not recorded"
        for label, fps in self.code.items():
            gaze, _, traj = label.partition("+")
            if list(fps) != [fingerprint(traj, gaze)]:
                return "other"
        return "same"

    def theta(self) -> np.ndarray:
        """The abilities in RESPONDENTS order."""
        return np.array([self.abilities[r] for r in RESPONDENTS])

    def percentile(self, b: float, dims: int) -> float | None:
        """The share (%) of the ``dims``-D calibration maps easier than difficulty ``b`` (None: no such set)."""
        ref = self.difficulties.get(str(dims)) or self.difficulties.get(dims)
        if not ref:
            return None
        ref = np.asarray(ref, float)
        return float(100.0 * (np.sum(ref < b) + 0.5 * np.sum(ref == b)) / ref.size)

    def success(self, b: float) -> float:
        """The panel's expected success on a map of difficulty ``b`` (mean over the respondents)."""
        return float(np.mean(sigmoid(self.theta() - b)))


def load_anchors(path: str | Path | None = None) -> Anchors | None:
    """The anchors shipped with pbdyn (pbdyn/analysis/data/anchors.json) or at ``path``; None if there are none."""
    p = Path(path) if path is not None else Path(__file__).resolve().parent / "data" / ANCHORS_FILE
    if not p.is_file():
        return None
    doc = json.loads(p.read_text())
    missing = [r for r in RESPONDENTS if r not in doc.get("abilities", {})]
    if missing:
        raise ConfigError("anchors", f"lacks the abilities of {', '.join(missing)}", str(p))
    return Anchors(str(doc["version"]), {k: float(v) for k, v in doc["abilities"].items()},
                   doc.get("difficulties", {}), doc.get("source", ""), dict(doc.get("code") or {}))


def scale_name(anchors: Anchors | None) -> str:
    """The scale a number is on, as cards and reports record it: "anchored-<SCALE_VERSION>/<anchors' version>"
    (or "unanchored": no anchors)."""
    return f"anchored-{SCALE_VERSION}/{anchors.version}" if anchors is not None else "unanchored"


# ------------------------------------------------------------------------------------------------ a map's difficulty
@dataclass(frozen=True)
class MapDifficulty:
    """One map's measured difficulty: identity, the panel's trials and reference tasks, the measured reference
    success with its 95% interval, and (when the scale is anchored) the difficulty in logits with its interval
    and percentile among the calibration maps of its dims; ``scale``: scale_name."""

    map_index: int
    map_id: str
    setup: dict
    trials: int
    tasks: int
    success: float
    success_ci: tuple
    difficulty: float | None
    difficulty_ci: tuple | None
    percentile: float | None
    scale: str

    def to_dict(self) -> dict:
        """JSON-able form."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}


def panel_counts(rows: list[dict]) -> dict[str, dict]:
    """map_id -> {"index", "setup", "tasks": [(start, goal)], "success": [T, J] 0/1 counts, "trials": [T, J]}
    from result rows, keeping only the panel's trials (RESPONDENTS); error rows are refused (a calibration with
    failed trials is not a measurement)."""
    col = {r: j for j, r in enumerate(RESPONDENTS)}
    per: dict[str, dict] = {}
    for r in rows:
        name = respondent(r.get("planner_label") or "", r.get("mav_speed") or 0.0)
        if name not in col:
            continue
        if r.get("outcome") == "error":
            raise ConfigError("RESULTS", f"holds an error row of the panel on map {r.get('map_index')} ({name}: "
                              f"{r.get('reason')}); re-fly it (`retry_errors`)", r.get("trial_key"),
                              show_value=False)
        m = per.setdefault(r["map_id"], {"index": r.get("map_index"), "setup": {"count": r.get("obstacle_count"),
                                                                                 "radius": r.get("obstacle_radius"),
                                                                                 "speed": r.get("obstacle_speed")},
                                         "tasks": {}})
        task = (tuple(r["start"]), tuple(r["goal"]))
        cell = m["tasks"].setdefault(task, np.zeros((2, len(RESPONDENTS))))
        cell[0, col[name]] += r.get("outcome") == "success"
        cell[1, col[name]] += 1
    out = {}
    for mid, m in per.items():
        tasks = sorted(m["tasks"])
        arr = np.stack([m["tasks"][t] for t in tasks])                  # [T, 2, J]
        out[mid] = {"index": m["index"], "setup": m["setup"], "tasks": tasks, "success": arr[:, 0, :],
                    "trials": arr[:, 1, :]}
    return out


def measure_difficulties(counts: dict, anchors: Anchors | None, *, n_boot: int = BOOTSTRAP, seed: int = 0,
                         dims: int = 2, speeds=None) -> list[MapDifficulty]:
    """Each map's measured difficulty from panel_counts() (docs/difficulty-scale.md): the share of the panel's
    trials that succeeded, with a 95% interval from ``n_boot`` resamples of its reference tasks (a task's trials by
    the different respondents stay together), and with ``anchors`` the maximum-likelihood difficulty b (logits) with
    the anchored abilities fixed (difficulty_given_abilities), its interval from the same resamples and its
    percentile among the calibration maps. ``speeds``: only the respondents at these MAV speeds (m/s; default
    all). Resamples are drawn from numpy.random.default_rng([seed, stable hash of the map id]), so a map's interval
    depends neither on the other maps nor on the store it was read from."""
    names = [r for r in RESPONDENTS if speeds is None or float(r.rsplit("@", 1)[1]) in speeds]
    cols = [RESPONDENTS.index(r) for r in names]
    out = []
    theta = anchors.theta()[cols] if anchors is not None else None
    for mid, m in sorted(counts.items(), key=lambda kv: (kv[1]["index"] if kv[1]["index"] is not None else -1,
                                                         kv[0])):
        s, n = m["success"], m["trials"]
        if len(cols) < len(RESPONDENTS):
            s, n = s[:, cols], n[:, cols]
        t = s.shape[0]
        rng = np.random.default_rng([seed, stable_hash64(mid)])
        w = rng.multinomial(t, np.full(t, 1.0 / t), size=n_boot).astype(float)   # [B, T]
        ks, ns = w @ s, w @ n                                                      # [B, J]
        rate = ks.sum(axis=1) / ns.sum(axis=1)
        success = float(s.sum() / n.sum())
        ci = (float(np.quantile(rate, 0.025)), float(np.quantile(rate, 0.975)))
        b = b_ci = pct = None
        if theta is not None:
            if not np.all(n.sum(axis=0) > 0):
                missing = [names[j] for j in np.flatnonzero(n.sum(axis=0) == 0)]
                raise ConfigError("RESULTS", f"map {m['index']} lacks the panel's trials of {', '.join(missing)}",
                                  mid, show_value=False)
            b = difficulty_given_abilities(theta, s.sum(axis=0), n.sum(axis=0))
            bb = difficulty_given_abilities(theta, ks, ns)
            b_ci = (float(np.quantile(bb, 0.025)), float(np.quantile(bb, 0.975)))
            pct = anchors.percentile(b, dims)
        out.append(MapDifficulty(int(m["index"]) if m["index"] is not None else -1, mid, m["setup"], int(n.sum()), t,
                                 success, ci, b, b_ci, pct, scale_name(anchors)))
    return out


def format_difficulties(res: list[MapDifficulty]) -> str:
    """A table: one line per map."""
    lines = []
    for r in res:
        head = f"map {r.map_index} ({r.map_id}): reference success {r.success:.2f} [{r.success_ci[0]:.2f}, " \
               f"{r.success_ci[1]:.2f}] ({r.trials} trials, {r.tasks} tasks)"
        if r.difficulty is not None:
            pct = f", percentile {r.percentile:.0f} of the calibration set" if r.percentile is not None else ""
            head += f"; difficulty {r.difficulty:+.2f} logits [{r.difficulty_ci[0]:+.2f}, " \
                    f"{r.difficulty_ci[1]:+.2f}]{pct} (scale {r.scale})"
        else:
            head += "; no anchored scale is shipped with this pbdyn (reference success only)"
        lines.append(head)
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------------------ placing a store
def place_on_scale(trials: list[dict], anchors: Anchors | None, dims: dict | None = None) -> dict:
    """The anchored section of `pbdyn evaluate`: per dataset (store), its maps' difficulties estimated from the
    panel respondents it holds (their shipped abilities fixed) and every respondent's ability given those
    difficulties (logits, standard errors from the likelihood's curvature), or why it cannot be placed (no panel
    pair at a panel speed). ``trials``: pbdyn.experiments.evaluate.load_results rows (map_id, pair, mav_speed,
    outcome, dataset); ``dims``: dataset -> dims (for percentiles). Stores placed are on one scale: linked through
    the fixed abilities, never re-centred."""
    if anchors is None:
        return {"anchored": False, "why": "no anchored scale is shipped with this pbdyn"}
    theta = dict(anchors.abilities)
    out = {"anchored": True, "scale": scale_name(anchors), "datasets": {}}
    by_set: dict[str, list[dict]] = {}
    for t in trials:
        by_set.setdefault(t["dataset"], []).append(t)
    for name, rows in by_set.items():
        cells: dict[tuple, list[int]] = {}
        for t in rows:
            c = cells.setdefault((t["map_id"], respondent(t.get("pair") or "", t.get("mav_speed") or 0.0)), [0, 0])
            c[0] += t.get("outcome") == "success"
            c[1] += 1
        panel = sorted({r for (_, r) in cells if r in theta})
        if not panel:
            out["datasets"][name] = {"placed": False, "why": "no trial of a panel pair (" + ", ".join(
                e.label for e in PANEL) + ") at a panel speed (" + "/".join(f"{v:g}" for v in PANEL_SPEEDS) +
                " m/s): its maps and planners cannot be placed on the anchored scale"}
            continue
        maps = sorted({m for (m, _) in cells})
        diff, se = {}, {}
        for m in maps:
            got = [(theta[r], *cells[(m, r)]) for r in panel if (m, r) in cells]
            if not got:
                continue
            th, k, n = (np.array(x, float) for x in zip(*got))
            b = difficulty_given_abilities(th, k, n)
            p = sigmoid(th - b)
            diff[m], se[m] = b, float(1.0 / np.sqrt(np.sum(n * p * (1 - p)) + 1e-12))
        abil = {}
        for r in sorted({r for (_, r) in cells}):
            got = [(diff[m], *cells[(m, r)]) for m in maps if (m, r) in cells and m in diff]
            if not got:
                continue
            b, k, n = (np.array(x, float) for x in zip(*got))
            a = ability_given_difficulties(b, k, n)
            p = sigmoid(a - b)
            abil[r] = {"ability": a, "se": float(1.0 / np.sqrt(np.sum(n * p * (1 - p)) + 1e-12)),
                       "anchor": theta.get(r), "trials": int(n.sum())}
        vals = np.array(list(diff.values()))
        d = (dims or {}).get(name, 2)
        out["datasets"][name] = {
            "placed": True, "panel_respondents": panel, "maps_placed": len(diff), "maps": len(maps),
            "difficulty": {m: {"logit": diff[m], "se": se[m], "percentile": anchors.percentile(diff[m], d)}
                           for m in diff},
            "difficulty_mean": float(vals.mean()), "difficulty_range": [float(vals.min()), float(vals.max())],
            "abilities": abil}
    out["one_scale"] = [n for n, v in out["datasets"].items() if v["placed"]]
    return out


def format_scale(section: dict) -> str:
    """The anchored section as text lines."""
    if not section.get("anchored"):
        return f"Anchored scale: {section.get('why')}.\n"
    lines = [f"Anchored scale ({section['scale']}; zero = mean difficulty of the 2D calibration maps, unit = 1 "
             "logit; higher = harder). Placed on it (one scale): " + (", ".join(section["one_scale"]) or "none")]
    for name, d in section["datasets"].items():
        if not d["placed"]:
            lines.append(f"  {name}: {d['why']}")
            continue
        lo, hi = d["difficulty_range"]
        lines.append(f"  {name}: {d['maps_placed']} of {d['maps']} maps placed by {len(d['panel_respondents'])} panel "
                     f"respondent(s); difficulty mean {d['difficulty_mean']:+.2f} logits (range {lo:+.2f} to "
                     f"{hi:+.2f})")
        for r, a in d["abilities"].items():
            anchor = f" (anchor {a['anchor']:+.2f})" if a["anchor"] is not None else ""
            lines.append(f"    ability {r:<36} {a['ability']:+.2f} +- {a['se']:.2f}{anchor}  ({a['trials']} trials)")
    return "\n".join(lines) + "\n"
