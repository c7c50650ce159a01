"""The score card of one planner on one suite (schema CARD_SCHEMA; docs/benchmark.md "The score card").

Inputs are task rows (task_row): one per flown task (part, map id, start, goal, MAV speed) with its outcome and
figures. The card holds, for the planner and beside it for every reference planner of the suite:

- success overall and per level, with Wilson 95% intervals (pbdyn.analysis.paired.wilson_interval);
- its ability on the anchored scale (pbdyn.analysis.scale): the maximum-likelihood ability of the planner, its
  speeds pooled, given the suite maps' fixed measured difficulties (ability_given_difficulties), with a 95% interval
  from resampling the suite's maps (ABILITY_BOOT draws); its rank among the references by ability;
- paired comparisons with each reference on the tasks both flew (pbdyn.analysis.paired.paired_comparison: discordant
  counts, exact McNemar p, the success difference with a paired map-bootstrap interval);
- outcomes (failure modes) overall and per level; the worst levels' success (CVAR_SHARE: the mean success of the
  lowest 20% of levels, at least one); on the successful tasks, the time to goal (s), the path length over the
  straight-line distance from the start to the goal ball (|goal - start| - goal radius) and the minimum clearance
  (m); the planner's time per step (ms: the median over the tasks flown of each task's median step, and of each
  task's 99th-percentile step);
- the suite's name, version and hash, pbdyn's version, the planner's fingerprint, the machine and the date, and a
  one-line summary to quote.

Everything but the planning times, the machine and the date is a deterministic function of the task rows.
"""

from __future__ import annotations

import math
import platform
from datetime import datetime, timezone

import numpy as np

from pbdyn.analysis.paired import paired_comparison, wilson_interval
from pbdyn.outcome import Outcome

CARD_SCHEMA = "pbdyn-card/1"
OUTCOMES = tuple(o.value for o in Outcome)
"""The outcomes a card counts, in pbdyn.outcome.Outcome's order (success first)."""
CVAR_SHARE = 0.2
ABILITY_BOOT = 1000
TASK_FIELDS = ("part", "map_id", "start", "goal", "mav_speed", "outcome", "flight_time_s", "path_length_m",
               "min_clearance_m", "steps", "planning_failures", "wall_planning_median_s", "wall_planning_p99_s")
"""A task row's fields (units: m, m/s, s); the two wall_* fields are wall times and vary between runs."""
DETERMINISTIC_FIELDS = TASK_FIELDS[:-2]
"""The fields a re-flight must reproduce bit for bit."""


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


def _rate(rows: list[dict]) -> dict:
    k = sum(r["outcome"] == "success" for r in rows)
    lo, hi = wilson_interval(k, len(rows))
    return {"rate": k / len(rows) if rows else None, "ci95": [lo, hi] if rows else [None, None], "successes": k,
            "trials": len(rows)}


def _ability(rows: list[dict], difficulty: dict, seed: int) -> dict:
    """The ability (logits) given the maps' fixed difficulties, with a map-bootstrap 95% interval."""
    from pbdyn.analysis.scale import ability_given_difficulties, difficulty_given_abilities

    maps = sorted({(r["part"], r["map_id"]) for r in rows})
    b = np.array([difficulty[m] for m in maps])
    idx = {m: i for i, m in enumerate(maps)}
    k = np.zeros(len(maps))
    n = np.zeros(len(maps))
    for r in rows:
        i = idx[(r["part"], r["map_id"])]
        k[i] += r["outcome"] == "success"
        n[i] += 1
    a = ability_given_difficulties(b, k, n)
    rng = np.random.default_rng(seed)
    w = rng.multinomial(len(maps), np.full(len(maps), 1.0 / len(maps)), size=ABILITY_BOOT).astype(float)
    boot = -difficulty_given_abilities(-b, w * k, w * n)      # every resample at once (the mirror, as in scale)
    lo, hi = np.quantile(boot, [0.025, 0.975])
    return {"logit": float(a), "ci95": [float(lo), float(hi)]}


def goal_radii(suite) -> dict:
    """part name -> the goal radius (m) of its tasks."""
    from pbdyn.config import parse_scenario

    return {p.name: float(parse_scenario(p.doc, p.path).task.goal_radius) for p in suite.parts}


def summarise(rows: list[dict], suite, *, seed: int = 0) -> dict:
    """The per-planner part of a card (success, levels, ability, outcomes, figures) from its task rows."""
    levels = [int(lv["level"]) for lv in suite.levels]
    level_of = {(m["part"], m["map_id"]): int(m["level"]) for m in suite.maps}
    difficulty = {(m["part"], m["map_id"]): float(m["difficulty"]) for m in suite.maps}
    per_level = []
    for lv in levels:
        sub = [r for r in rows if level_of[(r["part"], r["map_id"])] == lv]
        per_level.append({"level": lv, **_rate(sub),
                          "outcomes": {o: sum(r["outcome"] == o for r in sub) for o in OUTCOMES}})
    rates = sorted(x["rate"] for x in per_level if x["rate"] is not None)
    worst = rates[:max(1, math.ceil(CVAR_SHARE * len(rates)))] if rates else []
    ok = [r for r in rows if r["outcome"] == "success"]
    radius = goal_radii(suite)
    ratio = [r["path_length_m"] / d for r in ok if r["path_length_m"] is not None
             for d in [math.dist(r["start"], r["goal"]) - radius[r["part"]]] if d > 0]
    flew = [r for r in rows if r["outcome"] != Outcome.ERROR.value]
    plan_med = _finite(r["wall_planning_median_s"] for r in flew)
    plan_p99 = _finite(r["wall_planning_p99_s"] for r in flew)
    return {
        "success": _rate(rows),
        "levels": per_level,
        "ability": _ability(rows, difficulty, seed) if rows else None,
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


def make_card(suite, planner: dict, rows: list[dict], references: dict, *, seed: int = 0,
              date: str | None = None) -> dict:
    """The score card (module doc). ``planner``: {"label", "trajectory", "gaze", "fingerprint"}; ``rows``: its
    task rows; ``references``: label -> {"meta": {...}, "rows": [task rows]} (the suite's shipped references)."""
    from pbdyn import __version__
    from pbdyn.experiments.calibrate import load_anchors
    from pbdyn.analysis.scale import SCALE_VERSION

    anchors = load_anchors()
    mine = summarise(rows, suite, seed=seed)
    refs = []
    by_task = {task_key(r): r for r in rows}
    for label in sorted(references):
        ref_rows = references[label]["rows"]
        s = summarise(ref_rows, suite, seed=seed)
        common = [(by_task[task_key(r)], r) for r in ref_rows if task_key(r) in by_task]
        pc = paired_comparison([a["outcome"] == "success" for a, _ in common],
                               [b["outcome"] == "success" for _, b in common],
                               [f"{a['part']}/{a['map_id']}" for a, _ in common], seed=seed)
        refs.append({"label": label, "trajectory": references[label]["meta"].get("trajectory"),
                     "gaze": references[label]["meta"].get("gaze"),
                     "fingerprint": references[label]["meta"].get("fingerprint"), **s, "paired": pc})
    ability = mine["ability"]
    rank = None
    if ability is not None:
        rank = 1 + sum(r["ability"] is not None and r["ability"]["logit"] > ability["logit"] for r in refs
                       if r["label"] != planner["label"])
    n_ranked = 1 + sum(r["label"] != planner["label"] for r in refs)
    suite_info = {"name": suite.name, "version": suite.version, "hash": suite.hash, "dims": suite.dims,
                  "maps": len(suite.maps), "tasks": suite.n_tasks(), "speeds_mps": list(suite.speeds),
                  "levels": [{"level": int(lv["level"]), "success_range": lv["success_range"],
                              "maps": sum(int(m["level"]) == int(lv["level"]) for m in suite.maps)}
                             for lv in suite.levels],
                  "map_ids": suite.id_rule, **({"note": V1_NOTE} if suite.id_rule == "setup-1" else {})}
    scale = f"anchored-{SCALE_VERSION}/{anchors.version}" if anchors is not None else "unanchored"
    card = {"schema": CARD_SCHEMA, "summary": "", "suite": suite_info, "planner": dict(planner),
            "provenance": {"pbdyn": __version__, "scale": scale, "machine": machine(),
                           "code": code_provenance(planner, references),
                           "date": date or datetime.now(timezone.utc).replace(microsecond=0).isoformat()},
            "trials": {"flown": len(rows), "expected": suite.n_tasks(), "errors": mine["outcomes"][Outcome.ERROR.value]},
            **mine, "rank": {"by": "ability", "rank": rank, "of": n_ranked}, "references": refs}
    card["summary"] = summary_line(card)
    return card


V1_NOTE = ("a pbdyn-suite/1 suite: its map ids follow the rule before (setup values and replicate alone; they repeat "
           "across parts, so a map is named by part and id) and its hash does not cover its reference results, "
           "which are checked against the digest its manifest records (docs/benchmark.md)")
"""The note a card of a v1 suite carries."""


def code_provenance(planner: dict, references: dict) -> dict:
    """Which code flew this card and its references (docs/design.md "Code identity"): the trial core's identity
    now, and per reference label whether its recorded fingerprint is what this pbdyn's code gives for that planner
    pair ("same"), another ("other"), or was not recorded by content ("not recorded": references flown before
    pbdyn identified code by content, fingerprints "builtin:..."); "statement" says it in one line. Nothing is
    refused: a reader decides (``pbdyn bench --reproduce`` re-flies a reference)."""
    from pbdyn import codeid
    from pbdyn.planning.registry import pair_fingerprint

    status = {}
    for label in sorted(references):
        meta = references[label]["meta"]
        fp = str(meta.get("fingerprint") or "")
        if "+core:" not in fp:
            status[label] = "not recorded"
            continue
        try:
            now = pair_fingerprint(meta.get("trajectory"), meta.get("gaze"))
        except Exception:  # a reference planner this pbdyn cannot resolve: not the same code
            now = ""
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
            "statement": statement}


def summary_line(card: dict) -> str:
    """The one line to quote: planner, suite and hash, success with CI, ability with CI, rank, worst levels."""
    s, a = card["success"], card["ability"]
    text = (f"{card['planner']['label']} on {card['suite']['name']} ({card['suite']['hash'][:12]}): success "
            f"{_f(s['rate'])} [{_f(s['ci95'][0])}, {_f(s['ci95'][1])}] over {s['trials']} tasks")
    if a is not None:
        text += (f"; ability {a['logit']:+.2f} [{a['ci95'][0]:+.2f}, {a['ci95'][1]:+.2f}] logits "
                 f"({card['provenance']['scale']}), rank {card['rank']['rank']} of {card['rank']['of']}")
    cv = card["cvar20_success"]["rate"]
    if cv is not None:
        text += f"; worst-20% levels {cv:.2f}"
    return text


def _f(x) -> str:
    return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.2f}"
