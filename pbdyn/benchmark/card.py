"""The score card of one planner on one suite (schema CARD_SCHEMA; docs/benchmark.md "The score card").

Inputs are task rows (task_row): one per flown task (part, map id, start, goal, MAV speed) with its outcome and
figures. The card holds, for the planner and beside it for every reference planner of the suite:

- success overall, per level, per MAV speed and per level and speed, with Wilson 95% intervals
  (pbdyn.analysis.paired.wilson_interval), and per map (successes / trials);
- its ability on the anchored scale (pbdyn.analysis.scale): the maximum-likelihood ability of the planner, its
  speeds pooled, given the suite maps' fixed measured difficulties (ability_given_difficulties), with a 95% interval
  from resampling the suite's maps (ABILITY_BOOT draws; the same resamples for every planner); its rank among the
  references by ability with a 95% interval from the same resamples (each draw refits every ability and ranks them),
  given only on a suite of at least RANK_MIN_MAPS maps;
- paired comparisons with each reference on the tasks both flew: the discordant counts, the success difference with
  a paired map-bootstrap interval (pbdyn.analysis.paired.paired_comparison), and the cluster-robust Wald t-test of
  the difference with maps as clusters (clustered_paired_test), its p-values Holm-adjusted over the card's
  comparisons (holm_adjust) and stored floored at P_FLOOR (p_record); the exact McNemar p over tasks taken as
  independent stays as a secondary field (mcnemar_p_unclustered);
- outcomes (failure modes) overall and per level; the worst levels' success (CVAR_SHARE: the mean success of the
  lowest 20% of levels, at least one); on the successful tasks, the time to goal (s), the path length over the
  straight-line distance from the start to the goal ball (|goal - start| - goal radius) and the minimum clearance
  (m), overall and (time and clearance) per level; the planner's time per step (ms: the median over the tasks flown
  of each task's median step, and of each task's 99th-percentile step); the sensor's horizontal field of view
  (fov_deg: 360 for a gaze planner that imposes it, FullRange, else the suite's sensor's);
- the suite's name, version and hash, how its levels were assigned (levels_from), the MAV, sensor and task
  parameters of its parts (flight_parameters), pbdyn's version, the planner's fingerprint, the code identities and
  the git commit pbdyn runs from (code_provenance), the machine and the date, a "how to read" block (DEFINITIONS:
  one definition per quantity the card shows, with its docs section), and a one-line summary to quote.

Everything but the planning times, the machine, the git state and the date is a deterministic function of the task
rows (fixed seeds). ``pbdyn bench`` adds "reproduction", "cost", "failure_replays" and the planner's parameter
tables after make_card; the renderer shows them when present.
"""

from __future__ import annotations

import math
import platform
from datetime import datetime, timezone

import numpy as np

from pbdyn.analysis.paired import (P_FLOOR, clustered_paired_test, format_p, holm_adjust, paired_comparison,
                                   wilson_interval)
from pbdyn.outcome import Outcome

CARD_SCHEMA = "pbdyn-card/2"
"""The card's schema name (pbdyn/benchmark/card.schema.json). Cards of pbdyn-card/1 are not read (their paired test
and fields differ): ``pbdyn bench --compare`` refuses them in one line; re-run the bench to get a /2 card."""
OUTCOMES = tuple(o.value for o in Outcome)
"""The outcomes a card counts, in pbdyn.outcome.Outcome's order (success first)."""
CVAR_SHARE = 0.2
ABILITY_BOOT = 1000
"""Map-bootstrap draws of the abilities and the rank (the same resamples for the planner and every reference)."""
RANK_MIN_MAPS = 20
"""The fewest suite maps a card ranks on: below it the map bootstrap has too few distinct maps for a rank (or its
interval) to mean much -- the mini suite has 4 -- and the card gives no rank and says so."""
TEST_NAME = ("cluster-robust Wald t-test of the success difference, maps as clusters (paired differences "
             "regressed on an intercept, map-clustered sandwich variance with the small-sample factor G/(G-1), "
             "Student's t with G-1 degrees of freedom; G maps), Holm-adjusted over the card's comparisons")
"""The paired test a card states."""
TASK_FIELDS = ("part", "map_id", "start", "goal", "mav_speed", "outcome", "flight_time_s", "path_length_m",
               "min_clearance_m", "steps", "planning_failures", "wall_planning_median_s", "wall_planning_p99_s")
"""A task row's fields (units: m, m/s, s); the two wall_* fields are wall times and vary between runs."""
DETERMINISTIC_FIELDS = TASK_FIELDS[:-2]
"""The fields a re-flight must reproduce bit for bit."""
DOC_CARD = "docs/benchmark.md#the-score-card"
DOC_STATS = "docs/benchmark.md#statistics"
DOC_SUITES = "docs/benchmark.md#the-suites"
DOC_REFERENCES = "docs/benchmark.md#reference-results"
DOC_SCALE = "docs/difficulty-scale.md#definition-scale-version-1"
DOC_CODE = "docs/design.md#code-identity"
DOC_DEFAULTS = "docs/design.md#defaults"
DOC_GAZE = "docs/planners.md#gaze-planners"
DOC_OUTCOMES = "docs/design.md#outcomes-and-the-record"
LEVELS_DOC = "docs/benchmark.md#levels"
def _failure_terms() -> tuple:
    """(term, definition, docs section) of each failure outcome, as the level table heads its columns."""
    out = []
    for o in Outcome:
        if o is Outcome.SUCCESS:
            continue
        extra = "; such a task counts as a failure" if o is Outcome.ERROR else ""
        out.append((o.value.replace("_", " "), f"tasks that ended so: {o.reason}{extra}", DOC_OUTCOMES))
    return tuple(out)


DEFINITIONS = (
    ("summary", "the one line to quote: planner, suite and the first 12 digits of its hash, success with its "
                "interval, ability with its interval, rank (or why there is none), worst-20% levels", DOC_CARD),
    ("schema", "the card's format (card.json follows pbdyn/benchmark/card.schema.json; every number shown is in "
               "card.json)", DOC_CARD),
    ("planner", "a trajectory planner with its gaze planner (gaze+trajectory), and its fingerprint: the identity of "
                "its code by content", DOC_CODE),
    ("trajectory parameters", "the trajectory planner's parameters given to the bench (pbdyn bench --params)",
     DOC_CARD),
    ("gaze parameters", "the gaze planner's parameters given to the bench", DOC_CARD),
    ("parameter files", "the sha256 of every file a parameter names (e.g. a policy's weights)", DOC_CARD),
    ("suite", "the frozen set of tasks: name, version, sha256 hash (its identity), maps, tasks and MAV speeds; a "
              "task is (map, start, goal, MAV speed)", DOC_SUITES),
    ("levels from", "how the suite's maps were assigned their difficulty levels, and what that implies for the "
                    "comparison with the references", LEVELS_DOC),
    ("success", "the share of tasks on which the MAV reached the goal ball (an error counts as a failure), with its "
                "Wilson 95% interval", DOC_CARD),
    ("success [95% CI]", "success with its Wilson score 95% interval (tasks taken as independent: a descriptive "
                         "interval; the paired test is clustered by map)", DOC_CARD),
    ("ability", "the planner's maximum-likelihood ability in logits on the anchored scale (higher = more able; "
                "P(success on a map) = sigmoid(ability - the map's difficulty)), its speeds pooled, given the "
                "suite maps' fixed measured difficulties; 95% interval from 1,000 map-bootstrap draws", DOC_SCALE),
    ("ability (logits) [95% CI]", "the ability (logits, anchored scale) with its map-bootstrap 95% interval",
     DOC_SCALE),
    ("rank", "the planner's place among itself and the reference planners by ability (1 = most able), with a 95% "
             "interval from the same map-bootstrap draws (every ability refit on each resample of maps, the maps' "
             "difficulties fixed); not given on a suite of fewer than 20 maps", DOC_STATS),
    ("made with", "pbdyn's version, the machine (CPU, count, system, Python) and the date (UTC) the card was made",
     DOC_CARD),
    ("code identity", "the trial core's identity by content, the git commit of the checkout pbdyn runs from "
                      "(and whether its work tree had uncommitted changes), and per reference whether this pbdyn "
                      "flies the code it was flown with (same / other / not recorded)", DOC_CODE),
    ("cost", "what the bench cost: its wall time (s), the CPU time of its processes (s) and how many runs (starts "
             "of pbdyn bench that flew or drew something; a fully resumed one adds none) it took", DOC_CARD),
    ("reproduction", "with --reproduce: whether the flights reproduce the planner's shipped reference rows field "
                     "by field (everything but wall times)", DOC_REFERENCES),
    ("note", "what a reader of a card of an older suite version should know", DOC_CARD),
    ("test", "the paired test of the card: the " + TEST_NAME + "; p-values below 1e-6 are printed and stored as "
             "< 1e-6", DOC_STATS),
    ("†", "marks a planner that sees 360 degrees (the FullRange gaze planner gives its MAV a 360-degree sensor and "
          "no yaw control) beside planners that see the suite's sensor field of view (90 degrees by default)",
     DOC_GAZE),
    ("sensor FOV (deg)", "the horizontal field of view the planner's MAV sees with: 360 for FullRange (marked †), "
                         "else the suite's sensor's", DOC_GAZE),
    ("level", "a difficulty level of the suite (1 = easiest): the band of the reference panel's success its maps fall "
              "in (on held-out tasks in a v2 suite, on the suite's own tasks in a v1 suite: see levels from)",
     LEVELS_DOC),
    ("reference success range", "the band of the reference panel's mean success that defines the level (measured "
                                "as levels from says)", LEVELS_DOC),
    ("tasks", "tasks flown (map, start, goal, MAV speed)", DOC_CARD),
    *_failure_terms(),
    ("successful tasks", "the tasks the planner succeeded on, over which time to goal and clearance are taken",
     DOC_CARD),
    ("time to goal (s), median [IQR]", "the flight time of the successful tasks (s): median and interquartile "
                                       "range", DOC_CARD),
    ("min clearance (m), median [IQR]", "the smallest distance between the MAV and any obstacle over a successful "
                                        "flight (m): median and interquartile range", DOC_CARD),
    ("path ratio, median [IQR]", "the path length over the straight-line distance from the start to the goal ball "
                                 "(|goal - start| - goal radius), successful tasks: median and interquartile range",
     DOC_CARD),
    ("time per step (ms), median / p99", "the planner's wall time per step on the card's machine (ms): the median "
                                         "over the tasks of each task's median step, and of each task's "
                                         "99th-percentile step", DOC_CARD),
    ("worst-20% levels", "the mean success of the lowest 20% of the levels by success (at least one level): a CVaR "
                         "of the level curve", DOC_CARD),
    ("MAV speed (m/s)", "the MAV's maximum speed v_max the task was flown at", DOC_DEFAULTS),
    ("reference", "a reference planner shipped with the suite (its flights on exactly the suite's tasks)",
     DOC_REFERENCES),
    ("tasks in common", "the tasks both this planner and the reference flew (the paired comparison's tasks)",
     DOC_STATS),
    ("maps", "the maps those tasks lie on: the test's clusters (G)", DOC_STATS),
    ("both", "tasks both planners succeeded on", DOC_STATS),
    ("only this", "tasks only this card's planner succeeded on", DOC_STATS),
    ("only the reference", "tasks only the reference succeeded on", DOC_STATS),
    ("neither", "tasks neither succeeded on", DOC_STATS),
    ("difference [95% CI]", "this planner's success minus the reference's on the tasks in common, with a 95% paired "
                            "bootstrap interval that resamples maps (2,000 draws)", DOC_STATS),
    ("t (df)", "the clustered test's t statistic (the difference over its map-clustered standard error) and its "
               "degrees of freedom (maps - 1); inf when every map gives the same difference", DOC_STATS),
    ("p (clustered)", "the two-sided p-value of the clustered test (raw), printed to two significant digits and as "
                      "< 1e-6 below 1e-6", DOC_STATS),
    ("p (Holm)", "the p-value Holm-adjusted over the card's comparisons (one per reference): reject at level alpha "
                 "when it is below alpha, the family-wise error rate held at alpha", DOC_STATS),
    ("part", "the scenario file of the suite a map comes from (generated maps, or an imported world)", DOC_SUITES),
    ("map id", "the map's id (12 hex digits); within a v1 suite a map is named by its part and id", DOC_SUITES),
    ("family", "the generator family the map comes from (uniform, clustered, crossing, walls, mixed, spread, rvo, "
               "or an imported world)", DOC_SUITES),
    ("map difficulty (logits)", "the map's measured difficulty on the anchored scale (higher = harder)", DOC_SCALE),
    ("successes/trials", "successes over tasks flown on the map, of the planner the column names", DOC_CARD),
    ("MAV", "the MAV of the suite's tasks: radius (m), maximum acceleration a_max (m/s^2), the maximum speeds v_max "
            "it is flown at (m/s), yaw rate limit (rad/s)", DOC_DEFAULTS),
    ("sensor", "the depth sensor: horizontal field of view (deg; 3D also vertical), range (m), ray resolution "
               "(deg), position noise (m, standard deviation), model", DOC_DEFAULTS),
    ("world", "the world of the tasks: dimensions, arena size (m), time step dt (s), time limit (s), occupancy grid "
              "resolution (m), flight height (m, 2D), profile, collision check", DOC_DEFAULTS),
    ("task", "the task rules: goal radius (m), start/goal pairs per map, deadlock after that many consecutive "
             "planning failures at rest, start rule", DOC_DEFAULTS),
    ("failure replay", "a replay of a failed task written by the bench: its outcome, part, map, start and goal (m), "
                       "MAV speed (m/s) and the file, relative to the bench folder", DOC_CARD),
    ("failure replays", "how many failure replays were asked for and how many were written", DOC_CARD),
)
"""The card's "how to read" block: (term, definition, docs section) for every quantity the card shows (a test checks
that every number on card.md and card.html sits under one of these terms)."""


def definitions() -> list[dict]:
    """DEFINITIONS as the card stores them: [{"term", "definition", "doc"}]."""
    return [{"term": t, "definition": d, "doc": doc} for t, d, doc in DEFINITIONS]


def task_row(part: str, result: dict) -> dict:
    """A task row from a store's result dict (pbdyn.experiments.store.ResultsStore.results) of part ``part``."""
    def num(key):
        v = result.get(key)
        return None if v is None else float(v)

    return {"part": part, "map_id": result["map_id"], "start": [float(x) for x in result["start"]],
            "goal": [float(x) for x in result["goal"]], "mav_speed": float(result["mav_speed"]),
            "outcome": result.get("outcome") or Outcome.ERROR.value, "flight_time_s": num("flight_time_s"),
            "path_length_m": num("path_length_m"), "min_clearance_m": num("min_clearance_m"),
            "steps": None if result.get("steps") is None else int(result["steps"]),
            "planning_failures": None if result.get("planning_failures") is None else int(result["planning_failures"]),
            "wall_planning_median_s": num("wall_planning_median_s"), "wall_planning_p99_s": num("wall_planning_p99_s")}


def task_key(row: dict) -> tuple:
    """A task's identity: (part, map id, start, goal, MAV speed)."""
    return (row["part"], row["map_id"], tuple(row["start"]), tuple(row["goal"]), float(row["mav_speed"]))


def _finite(values) -> np.ndarray:
    a = np.array([np.nan if v is None else float(v) for v in values], dtype=float)
    return a[np.isfinite(a)]


def _median_iqr(values) -> dict:
    a = _finite(values)
    if a.size == 0:
        return {"median": None, "iqr": [None, None], "n": 0}
    q = np.quantile(a, [0.25, 0.5, 0.75])
    return {"median": float(q[1]), "iqr": [float(q[0]), float(q[2])], "n": int(a.size)}


def _none(x):
    """``x`` as a finite float, else None (cards are strict JSON)."""
    return float(x) if x is not None and math.isfinite(float(x)) else None


def _rate(rows: list[dict]) -> dict:
    k = sum(r["outcome"] == "success" for r in rows)
    lo, hi = wilson_interval(k, len(rows))
    return {"rate": k / len(rows) if rows else None, "ci95": [lo, hi] if rows else [None, None], "successes": k,
            "trials": len(rows)}


def map_weights(n_maps: int, seed: int, draws: int = ABILITY_BOOT) -> np.ndarray:
    """[draws, n_maps] multinomial map-resample weights from numpy.random.default_rng(seed): the resamples every
    ability of a card (and so its rank) is refit on."""
    rng = np.random.default_rng(seed)
    return rng.multinomial(n_maps, np.full(n_maps, 1.0 / n_maps), size=draws).astype(float)


def _ability_draws(rows: list[dict], difficulty: dict, seed: int, resamples=None) -> tuple[dict, np.ndarray]:
    """The ability (logits) given the maps' fixed difficulties with its map-bootstrap 95% interval, and the
    bootstrap draws [B]. ``resamples``: (the suite's maps in order, their weights [B, M], map_weights) shared by
    every planner of a card; default: weights over the maps ``rows`` cover, drawn from ``seed``. A planner that flew
    every map gets the same draws either way."""
    from pbdyn.analysis.scale import ability_given_difficulties

    maps = sorted({(r["part"], r["map_id"]) for r in rows})
    b = np.array([difficulty[m] for m in maps])
    idx = {m: i for i, m in enumerate(maps)}
    k, n = np.zeros(len(maps)), np.zeros(len(maps))
    for r in rows:
        i = idx[(r["part"], r["map_id"])]
        k[i] += r["outcome"] == "success"
        n[i] += 1
    a = ability_given_difficulties(b, k, n)
    if resamples is None:
        w = map_weights(len(maps), seed)
    else:
        order, weights = resamples
        col = {m: j for j, m in enumerate(order)}
        w = weights[:, [col[m] for m in maps]]
    boot = ability_given_difficulties(b, w * k, w * n)        # every resample at once
    lo, hi = np.quantile(boot, [0.025, 0.975])
    return {"logit": float(a), "ci95": [float(lo), float(hi)]}, boot


def goal_radii(suite) -> dict:
    """part name -> the goal radius (m) of its tasks."""
    return {name: float(sc.task.goal_radius) for name, sc in part_scenarios(suite).items()}


def part_scenarios(suite) -> dict:
    """part name -> its parsed scenario (pbdyn.config.parse_scenario of the part's document)."""
    from pbdyn.config import parse_scenario

    return {p.name: parse_scenario(p.doc, p.path) for p in suite.parts}


def summarise(rows: list[dict], suite, *, seed: int = 0, radius: dict | None = None, resamples=None,
              draws: dict | None = None) -> dict:
    """The per-planner part of a card (success per level, speed, level and speed; ability; outcomes; figures) from
    its task rows. ``radius``: goal_radii(suite) (computed if not given); ``resamples``: the card's shared map
    resamples (_ability_draws); ``draws``: a dict that receives the ability's bootstrap draws under "ability"."""
    levels = [int(lv["level"]) for lv in suite.levels]
    level_of = {(m["part"], m["map_id"]): int(m["level"]) for m in suite.maps}
    difficulty = {(m["part"], m["map_id"]): float(m["difficulty"]) for m in suite.maps}
    radius = goal_radii(suite) if radius is None else radius
    speeds = [float(v) for v in suite.speeds]
    speeds += sorted({float(r["mav_speed"]) for r in rows} - set(speeds))
    by_level: dict = {lv: [] for lv in levels}
    for r in rows:
        by_level.setdefault(level_of[(r["part"], r["map_id"])], []).append(r)
    per_level = []
    for lv in levels:
        sub = by_level[lv]
        ok = [r for r in sub if r["outcome"] == "success"]
        per_level.append({"level": lv, **_rate(sub),
                          "outcomes": {o: sum(r["outcome"] == o for r in sub) for o in OUTCOMES},
                          "time_to_goal_s": _median_iqr(r["flight_time_s"] for r in ok),
                          "min_clearance_m": _median_iqr(r["min_clearance_m"] for r in ok)})
    rates = sorted(x["rate"] for x in per_level if x["rate"] is not None)
    worst = rates[:max(1, math.ceil(CVAR_SHARE * len(rates)))] if rates else []
    ok = [r for r in rows if r["outcome"] == "success"]
    ratio = [r["path_length_m"] / d for r in ok if r["path_length_m"] is not None
             for d in [math.dist(r["start"], r["goal"]) - radius[r["part"]]] if d > 0]
    flew = [r for r in rows if r["outcome"] != Outcome.ERROR.value]
    plan_med = _finite(r["wall_planning_median_s"] for r in flew)
    plan_p99 = _finite(r["wall_planning_p99_s"] for r in flew)
    ability = None
    if rows:
        ability, boot = _ability_draws(rows, difficulty, seed, resamples)
        if draws is not None:
            draws["ability"] = boot
    return {
        "success": _rate(rows),
        "levels": per_level,
        "by_speed": [{"mav_speed_mps": v, **_rate([r for r in rows if float(r["mav_speed"]) == v])} for v in speeds],
        "by_level_speed": [{"level": lv, "mav_speed_mps": v,
                            **_rate([r for r in by_level[lv] if float(r["mav_speed"]) == v])}
                           for lv in levels for v in speeds],
        "ability": ability,
        "outcomes": {o: sum(r["outcome"] == o for r in rows) for o in OUTCOMES},
        "cvar20_success": {"rate": float(np.mean(worst)) if worst else None, "levels": len(worst)},
        "time_to_goal_s": _median_iqr(r["flight_time_s"] for r in ok),
        "path_ratio": _median_iqr(ratio),
        "min_clearance_m": _median_iqr(r["min_clearance_m"] for r in ok),
        "planning_time_ms": {"median": float(np.median(plan_med) * 1e3) if plan_med.size else None,
                             "p99": float(np.median(plan_p99) * 1e3) if plan_p99.size else None,
                             "n": int(plan_med.size)},
    }


def machine() -> dict:
    """The machine a card was made on: OS, architecture, CPU model and count, Python."""
    import os

    cpu = platform.processor() or ""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return {"system": platform.system(), "machine": platform.machine(), "cpu": cpu, "cpus": os.cpu_count(),
            "python": platform.python_version()}


def p_record(p) -> dict:
    """A p-value as a card stores it: {"value": p floored at P_FLOOR (None when untested), "below_floor": whether p
    was below the floor, "text": format_p's text}."""
    if p is None or (isinstance(p, float) and math.isnan(p)):
        return {"value": None, "below_floor": False, "text": format_p(None)}
    p = float(p)
    return {"value": max(p, P_FLOOR), "below_floor": p < P_FLOOR, "text": format_p(p)}


def _paired(mine: list[dict], theirs: list[dict], seed: int) -> tuple[dict, float]:
    """The paired part of a reference's entry (without its Holm p) and the clustered test's raw p."""
    by_task = {task_key(r): r for r in mine}
    common = [(by_task[task_key(r)], r) for r in theirs if task_key(r) in by_task]
    a = [x["outcome"] == "success" for x, _ in common]
    b = [y["outcome"] == "success" for _, y in common]
    maps = [f"{x['part']}/{x['map_id']}" for x, _ in common]
    pc = paired_comparison(a, b, maps, seed=seed)
    test = clustered_paired_test(a, b, maps)
    t = test["t"]
    out = {"tasks": pc["tasks"], "maps": test["maps"], "both": pc["both"], "a_only": pc["a_only"],
           "b_only": pc["b_only"], "neither": pc["neither"], "success_a": _none(pc["success_a"]),
           "success_b": _none(pc["success_b"]), "difference": _none(pc["difference"]),
           "difference_ci95": [_none(x) for x in pc["difference_ci95"]],
           "test": {"estimate": _none(test["estimate"]), "se": _none(test["se"]),
                    "t": t if math.isfinite(t) else None, "t_infinite": math.isinf(t), "df": int(test["df"]),
                    "p": p_record(test["p"])},
           "mcnemar_p_unclustered": p_record(pc["mcnemar_p"])}
    return out, test["p"]


def _rank(ability: dict | None, boot: np.ndarray | None, others: list[tuple[dict | None, np.ndarray | None]],
          n_maps: int) -> dict:
    """The rank by ability among the planner and ``others`` (ability, draws) with its 95% map-bootstrap interval;
    None with a reason below RANK_MIN_MAPS maps."""
    of = 1 + len(others)
    out = {"by": "ability", "rank": None, "of": of, "ci95": [None, None], "draws": 0, "min_maps": RANK_MIN_MAPS,
           "reason": None}
    if ability is None:
        out["reason"] = "no ability: the planner flew no task"
        return out
    if n_maps < RANK_MIN_MAPS:
        out["reason"] = (f"no rank: the suite has {n_maps} maps, a rank needs at least {RANK_MIN_MAPS} (too few maps "
                         "to resample)")
        return out
    out["rank"] = 1 + sum(a is not None and a["logit"] > ability["logit"] for a, _ in others)
    rivals = [d for a, d in others if a is not None and d is not None]
    draws = 1 + (np.sum(np.stack(rivals) > boot[None, :], axis=0) if rivals else np.zeros(boot.shape, int))
    lo, hi = np.quantile(draws, [0.025, 0.975], method="inverted_cdf")
    out.update(ci95=[int(lo), int(hi)], draws=int(boot.size))
    return out


def _fov(gaze, sensor_fov: float | None) -> float | None:
    """The horizontal FOV (deg) a MAV flown with gaze planner ``gaze`` sees: the gaze planner's own fov_deg (FullRange:
    360), else ``sensor_fov`` (the suite's sensor); None if the gaze planner cannot be resolved."""
    if not gaze:
        return sensor_fov
    try:
        from pbdyn.planning.registry import resolve_gaze_planner

        cls = resolve_gaze_planner(str(gaze))
    except Exception:  # a gaze planner this pbdyn cannot resolve: its field of view is unknown
        return None
    own = getattr(cls, "fov_deg", None)
    return float(own) if isinstance(own, (int, float)) and not isinstance(own, bool) else sensor_fov


def flight_parameters(suite, scenarios: dict | None = None) -> dict:
    """The MAV, sensor, world and task parameters of each part of ``suite`` as its flights see them (the part's
    scenario with the suite's speeds), and whether every part has the same ("same_across_parts")."""
    scenarios = part_scenarios(suite) if scenarios is None else scenarios
    parts = []
    for p in suite.parts:
        sc = scenarios[p.name]
        w, d, s, t = sc.world, sc.drone, sc.sensor, sc.task
        parts.append({
            "part": p.name,
            "mav": {"radius_m": float(d.radius), "a_max_mps2": float(d.a_max),
                    "v_max_mps": [float(v) for v in suite.speeds], "yaw_rate_limit_radps": float(d.yaw_rate_limit)},
            "sensor": {"fov_deg": float(s.fov_deg), "vfov_deg": None if s.vfov_deg is None else float(s.vfov_deg),
                       "range_m": float(s.range), "resolution_deg": float(s.resolution_deg),
                       "noise_std_m": float(s.noise_std), "model": str(s.model)},
            "world": {"dims": int(w.dims), "arena_m": [float(x) for x in w.size], "dt_s": float(w.dt),
                      "time_limit_s": float(w.time_limit), "grid_resolution_m": float(w.grid_resolution),
                      "flight_height_m": float(w.flight_height) if int(w.dims) == 2 else None,
                      "profile": str(sc.profile), "collision_check": str(sc.collision_check)},
            "task": {"goal_radius_m": float(t.goal_radius), "pairs_per_map": len(p.pairs),
                     "deadlock_steps": int(t.deadlock_steps), "start_rule": str(t.start_rule)},
        })
    same = all({k: v for k, v in q.items() if k != "part"} == {k: v for k, v in parts[0].items() if k != "part"}
               for q in parts)
    return {"same_across_parts": same, "parts": parts}


def levels_from(suite) -> dict:
    """How the suite's levels were assigned (pbdyn.benchmark.suite.Suite.levels_text): the ``levels_from`` text of its
    manifest for a suite with held-out levels ("source": "suite"), else the statement that its levels come from the
    reference panel's flights on the suite's own tasks, the flights the card compares against ("default")."""
    from pbdyn.benchmark.suite import LEVELS_FROM

    src = suite.doc.get(LEVELS_FROM)
    own = isinstance(src, dict) and bool(src.get("text"))
    return {"text": suite.levels_text, "source": "suite" if own else "default", "doc": LEVELS_DOC}


def make_card(suite, planner: dict, rows: list[dict], references: dict, *, seed: int = 0,
              date: str | None = None) -> dict:
    """The score card (module doc). ``planner``: {"label", "trajectory", "gaze", "fingerprint"}; ``rows``: its
    task rows; ``references``: label -> {"meta": {...}, "rows": [task rows]} (the suite's shipped references)."""
    from pbdyn import __version__
    from pbdyn.analysis.scale import load_anchors, scale_name

    scenarios = part_scenarios(suite)
    radius = {name: float(sc.task.goal_radius) for name, sc in scenarios.items()}
    params = flight_parameters(suite, scenarios)
    fovs = {q["sensor"]["fov_deg"] for q in params["parts"]}
    sensor_fov = fovs.pop() if len(fovs) == 1 else None
    order = sorted({(m["part"], m["map_id"]) for m in suite.maps} | {(r["part"], r["map_id"]) for r in rows})
    resamples = (order, map_weights(len(order), seed))
    got: dict = {}
    mine = summarise(rows, suite, seed=seed, radius=radius, resamples=resamples, draws=got)
    refs, raw_p, rivals = [], [], []
    for label in sorted(references):
        ref_rows = references[label]["rows"]
        theirs: dict = {}
        s = summarise(ref_rows, suite, seed=seed, radius=radius, resamples=resamples, draws=theirs)
        pc, p = _paired(rows, ref_rows, seed)
        meta = references[label]["meta"]
        refs.append({"label": label, "trajectory": meta.get("trajectory"), "gaze": meta.get("gaze"),
                     "fingerprint": meta.get("fingerprint"), "fov_deg": _fov(meta.get("gaze"), sensor_fov),
                     **s, "paired": pc})
        own = label == planner["label"]
        raw_p.append(None if own else p)
        if not own:
            rivals.append((s["ability"], theirs.get("ability")))
    for r, adj in zip(refs, holm_adjust(raw_p)):
        r["paired"]["p_holm"] = p_record(adj)
    family = sum(p is not None and not math.isnan(p) for p in raw_p)
    rank = _rank(mine["ability"], got.get("ability"), rivals, len(suite.maps))
    suite_info = {"name": suite.name, "version": suite.version, "hash": suite.hash, "dims": suite.dims,
                  "maps": len(suite.maps), "tasks": suite.n_tasks(), "speeds_mps": list(suite.speeds),
                  "levels": [{"level": int(lv["level"]), "success_range": lv["success_range"],
                              "maps": sum(int(m["level"]) == int(lv["level"]) for m in suite.maps)}
                             for lv in suite.levels],
                  "levels_from": levels_from(suite),
                  "map_ids": suite.id_rule, **({"note": V1_NOTE} if suite.id_rule == "setup-1" else {})}
    card = {"schema": CARD_SCHEMA, "summary": "", "suite": suite_info,
            "planner": {**planner, "fov_deg": _fov(planner.get("gaze"), sensor_fov)},
            "flight_parameters": params,
            "provenance": {"pbdyn": __version__, "scale": scale_name(load_anchors()), "machine": machine(),
                           "code": code_provenance(planner, references),
                           "date": date or datetime.now(timezone.utc).replace(microsecond=0).isoformat()},
            "trials": {"flown": len(rows), "expected": suite.n_tasks(), "errors": mine["outcomes"][Outcome.ERROR.value]},
            **mine, "rank": rank,
            "comparisons": {"test": TEST_NAME, "clusters": "map", "holm_family": family, "p_floor": P_FLOOR,
                            "secondary": "mcnemar_p_unclustered: the exact McNemar test over the tasks taken as "
                                         "independent (not the card's test: a map's tasks share obstacles)"},
            "references": refs, "maps": per_map(suite, rows, references),
            "how_to_read": definitions()}
    card["summary"] = summary_line(card)
    return card


def per_map(suite, rows: list[dict], references: dict) -> list[dict]:
    """Per suite map (in the manifest's order): part, map id, level, family, difficulty, and the successes and
    trials of the planner and of each reference on it."""
    def counts(task_rows):
        out: dict = {}
        for r in task_rows:
            c = out.setdefault((r["part"], r["map_id"]), [0, 0])
            c[0] += r["outcome"] == "success"
            c[1] += 1
        return out

    mine = counts(rows)
    theirs = {k: counts(references[k]["rows"]) for k in sorted(references)}
    out = []
    for m in suite.maps:
        key = (m["part"], m["map_id"])
        k, n = mine.get(key, (0, 0))
        out.append({"part": m["part"], "map_id": m["map_id"], "level": int(m["level"]),
                    "family": m.get("family"), "difficulty": _none(m.get("difficulty")),
                    "planner": {"successes": int(k), "trials": int(n)},
                    "references": {lab: {"successes": int(c.get(key, (0, 0))[0]), "trials": int(c.get(key, (0, 0))[1])}
                                   for lab, c in theirs.items()}})
    return out


V1_NOTE = ("a pbdyn-suite/1 suite: its map ids follow the rule before (setup values and replicate alone; they repeat "
           "across parts, so a map is named by part and id) and its hash does not cover its reference results, "
           "which are checked against the digest its manifest records (docs/benchmark.md)")
"""The note a card of a v1 suite carries."""


def git_checkout(folder=None, timeout: float = 5.0) -> dict | None:
    """{"commit": HEAD's sha, "dirty": whether tracked files differ from it} of the git checkout pbdyn is imported
    from (``folder``: default the package's parent folder, which must be the checkout's top level), else None: not a
    checkout (an installed pbdyn), git missing, or git failing or slower than ``timeout`` s. Silent: git's output
    and errors are captured, nothing is printed or warned."""
    import os
    import subprocess
    from pathlib import Path

    from pbdyn.codeid import PACKAGE_DIR

    root = Path(folder) if folder is not None else PACKAGE_DIR.parent
    env = {**os.environ, "GIT_OPTIONAL_LOCKS": "0", "LC_ALL": "C", "GIT_TERMINAL_PROMPT": "0"}

    def git(*args) -> str | None:
        res = subprocess.run(["git", *args], cwd=root, capture_output=True, text=True, timeout=timeout, env=env,
                             stdin=subprocess.DEVNULL)
        return res.stdout.strip() if res.returncode == 0 else None

    try:
        top = git("rev-parse", "--show-toplevel")
        if not top or Path(top).resolve() != root.resolve():
            return None
        head = git("rev-parse", "HEAD")
        status = git("status", "--porcelain", "--untracked-files=no")
    except (OSError, ValueError, subprocess.SubprocessError):
        return None
    if not head or status is None or len(head) not in (40, 64):
        return None
    return {"commit": head, "dirty": bool(status)}


def code_provenance(planner: dict, references: dict) -> dict:
    """Which code flew this card and its references (docs/design.md "Code identity"): the trial core's identity
    now, the git checkout pbdyn runs from (git_checkout: commit and dirty, None when it is not one), and per
    reference label whether its recorded fingerprint is what this pbdyn's code gives for that planner pair
    ("same"), another ("other"), or was not recorded by content ("not recorded": references flown before pbdyn
    identified code by content, fingerprints "builtin:..."); "statement" says it in one line. Nothing is refused: a
    reader decides (``pbdyn bench --reproduce`` re-flies a reference)."""
    from pbdyn import codeid
    from pbdyn.planning.registry import recorded_fingerprint

    status = {}
    for label in sorted(references):
        meta = references[label]["meta"]
        fp = str(meta.get("fingerprint") or "")
        if "+core:" not in fp:
            status[label] = "not recorded"
            continue
        now = recorded_fingerprint(meta.get("trajectory"), meta.get("gaze"))   # "": not the same code
        status[label] = "same" if now == fp else "other"
    counts = {k: sum(v == k for v in status.values()) for k in ("same", "other", "not recorded")}
    if not status:
        statement = "no reference results to compare"
    elif counts["same"] == len(status):
        statement = "this pbdyn flies the references' code (every reference's code identity matches)"
    elif counts["not recorded"] == len(status):
        statement = ("the references were flown before pbdyn recorded code identities: whether this pbdyn flies "
                     "their code is unknown (pbdyn bench --reproduce re-flies one)")
    else:
        other = [k for k, v in status.items() if v != "same"]
        statement = (f"{len(other)} of {len(status)} references were flown by other code than this pbdyn's "
                     f"({', '.join(other[:3])}{', ...' if len(other) > 3 else ''}): compare with care "
                     "(pbdyn bench --reproduce re-flies one)")
    return {"core": codeid.core_identity(), "planner": planner.get("fingerprint"), "references": status,
            "statement": statement, "git": git_checkout()}


def rank_text(rank: dict) -> str:
    """The rank as a card prints it: "2 of 6 [1, 3]" (the 95% interval), or the reason there is none."""
    if rank.get("rank") is None:
        return rank.get("reason") or "no rank"
    lo, hi = rank.get("ci95") or [None, None]
    return f"{rank['rank']} of {rank['of']}" + (f" [{lo}, {hi}]" if lo is not None else "")


def summary_line(card: dict) -> str:
    """The one line to quote: planner, suite and hash, success with CI, ability with CI, rank, worst levels."""
    from pbdyn.analysis.html_kit import interval, num

    s, a = card["success"], card["ability"]
    text = (f"{card['planner']['label']} on {card['suite']['name']} ({card['suite']['hash'][:12]}): success "
            f"{num(s['rate'], '.2f')} {interval(s['ci95'], '.2f')} over {s['trials']} tasks")
    if a is not None:
        text += (f"; ability {a['logit']:+.2f} [{a['ci95'][0]:+.2f}, {a['ci95'][1]:+.2f}] logits "
                 f"({card['provenance']['scale']}), " + ("rank " if card["rank"]["rank"] is not None else "")
                 + rank_text(card["rank"]))
    cv = card["cvar20_success"]["rate"]
    if cv is not None:
        text += f"; worst-20% levels {cv:.2f}"
    return text
