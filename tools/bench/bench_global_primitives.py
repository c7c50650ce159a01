"""Benchmark of the global motion primitives planner (thesis A-1) in real trials.

Part 1: LookAhead + global_primitives on one map of 10 and of 30 obstacles (r 1 m, 4 m/s, v_max 4 m/s), 2D and 3D,
over several start/goal pairs: median / p95 / max time of one plan() call, of the planner per step (replan_check +
plan, the trial's wall_planning_s split) and of the whole trial step; search expansions; outcomes; budget hits.
Part 2: the controlled set's hardest setup (scenarios/controlled_2d.toml: 30 obstacles, 1.5 m, 6 m/s) with LookAhead
and FullRange over its v_max values: how often the expansion budget is hit, against how often the open list
empties (a map-made failure), and the trial outcomes.

    .venv/bin/python tools/bench/bench_global_primitives.py [--pairs N] [--hard-maps N] [--hard-pairs N]
                                                            [--epsilon E] [--max-expansions N]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import tomllib
from collections import Counter
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from bench_common import machine  # noqa: E402

from pbdyn.config import load_scenario, parse_scenario  # noqa: E402
from pbdyn.planning import registry  # noqa: E402
from pbdyn.planning.primitives.global_astar import GlobalPrimitives  # noqa: E402
from pbdyn.sim.demo import demo_pairs  # noqa: E402
from pbdyn.outcome import OUTCOMES  # noqa: E402
from pbdyn.sim.trial import SPLITS, make_trial_spec, run_trial  # noqa: E402
from pbdyn.world.maps import enumerate_maps  # noqa: E402
from pbdyn.world.rollout import build_rollout  # noqa: E402

HARD = Path(__file__).resolve().parents[2] / "scenarios" / "controlled_2d.toml"
NAME = "bench_timed_global_primitives"
CALLS: list[tuple[float, int, str]] = []   # (plan() wall time s, expansions, status) of every plan() call


class TimedGlobalPrimitives(GlobalPrimitives):
    """GlobalPrimitives that records the wall time, expansions and status of every plan() call."""

    def plan(self, view):
        t0 = time.perf_counter()
        out = super().plan(view)
        CALLS.append((time.perf_counter() - t0, self.last_expansions, self.last_status))
        return out


def _stats_ms(x) -> str:
    x = 1000.0 * np.asarray(x, dtype=float)
    if x.size == 0:
        return f"{'-':>25}"
    return f"{np.median(x):7.3f}/{np.percentile(x, 95):7.2f}/{x.max():8.1f}"


def bench_scenario(count: int, dims: int, params: dict):
    """A controlled-set style scenario with one setup of ``count`` obstacles (r 1 m, 4 m/s), v_max 4 m/s."""
    return parse_scenario({
        "name": f"bench_gp_{count}_{dims}d", "world": {"dims": dims},
        "obstacles": {"count": count, "radius": 1.0, "speed": 4.0, "radius_jitter": 0.2, "root_seed": 11},
        "drone": {"v_max": 4.0}, "planners": [{"trajectory": NAME, "gaze": "lookahead", "trajectory_params": params}],
    })


def run_set(sc, maps, pairs, v_maxes) -> dict:
    """Fly every (map, pair, v_max); per-call and per-step timings, outcomes and search statuses."""
    CALLS.clear()
    plan_step, trial_step, outcomes = [], [], Counter()
    cands = sc.task.candidates
    for spec_map in maps:
        rollout = build_rollout(sc, spec_map)
        for i, j in pairs:
            for v_max in v_maxes:
                spec = make_trial_spec(sc, spec_map, v_max=v_max, start=cands[i], goal=cands[j])
                prof: dict = {}
                res = run_trial(spec, rollout, profile=prof)
                outcomes[res.outcome] += 1
                plan_step += prof["wall_planning_s"]
                trial_step += np.sum([prof[s] for s in SPLITS], axis=0).tolist()
    calls = list(CALLS)
    return {"plan": [c[0] for c in calls], "exp": [c[1] for c in calls], "status": Counter(c[2] for c in calls),
            "plan_step": plan_step, "trial_step": trial_step, "outcomes": outcomes}


def _outcome_text(c: Counter) -> str:
    return " ".join(f"{k}={c[k]}" for k in OUTCOMES if c[k])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=12, help="start/goal pairs per configuration of part 1")
    ap.add_argument("--hard-maps", type=int, default=5, help="maps of the hardest controlled setup (part 2)")
    ap.add_argument("--hard-pairs", type=int, default=18, help="start/goal pairs per map (part 2)")
    ap.add_argument("--epsilon", type=float, default=None, help="heuristic weight (default: the planner's)")
    ap.add_argument("--max-expansions", type=int, default=None, help="search budget (default: the planner's)")
    args = ap.parse_args()
    params = {k: v for k, v in (("epsilon", args.epsilon), ("max_expansions", args.max_expansions)) if v is not None}
    registry.TRAJECTORY_PLANNERS[NAME] = TimedGlobalPrimitives
    print(machine())
    print(f"global_primitives parameters: defaults{' except ' + str(params) if params else ''}")
    print("times in ms as median/p95/max; plan() = one search; planner/step = replan_check + plan per trial step")
    print(f"{'configuration':<24} {'trials':>6} {'plans':>6} {'plan() ms':>25} {'planner/step ms':>25} "
          f"{'trial step ms':>25} {'expansions':>16}  statuses / outcomes")
    t_all = time.perf_counter()
    for dims in (2, 3):
        for count in (10, 30):
            sc = bench_scenario(count, dims, params)
            r = run_set(sc, enumerate_maps(sc)[:1], demo_pairs(sc, args.pairs), [4.0])
            exp = np.asarray(r["exp"])
            exp_txt = f"{np.median(exp):5.0f}/{np.percentile(exp, 95):5.0f}/{exp.max():5.0f}" if exp.size else "-"
            n_trials = sum(r["outcomes"].values())
            print(f"{f'{dims}D LookAhead {count} obst':<24} {n_trials:>6} {len(r['plan']):>6} {_stats_ms(r['plan'])} "
                  f"{_stats_ms(r['plan_step'])} {_stats_ms(r['trial_step'])} {exp_txt:>16}  "
                  f"{dict(r['status'])} / {_outcome_text(r['outcomes'])}")
    hard = load_scenario(HARD)
    maps = [m for m in enumerate_maps(hard) if (m.setup["count"], m.setup["radius"], m.setup["speed"]) ==
            (30, 1.5, 6.0)][:args.hard_maps]
    print(f"\nhardest controlled setup (30 obstacles, 1.5 m, 6 m/s): {len(maps)} maps x {args.hard_pairs} pairs x "
          f"v_max {list(hard.drone.v_max)}")
    for gaze in ("lookahead", "fullrange"):
        doc = tomllib.loads(HARD.read_text())
        sc = parse_scenario({**doc, "planners": [{"trajectory": NAME, "gaze": gaze, "trajectory_params": params}]})
        sc_maps = [m for m in enumerate_maps(sc) if m.key in {x.key for x in maps}]
        r = run_set(sc, sc_maps, demo_pairs(sc, args.hard_pairs), list(sc.drone.v_max))
        st = r["status"]
        n_plans = sum(st.values())
        print(f"  {gaze:<10} trials {sum(r['outcomes'].values()):>4}  plans {n_plans:>5}  budget hits "
              f"{st['budget']:>3} ({100.0 * st['budget'] / max(n_plans, 1):.1f}%)  open list emptied "
              f"{st['exhausted']:>4}  found {st['found']:>4}  plan() ms {_stats_ms(r['plan'])}  "
              f"outcomes: {_outcome_text(r['outcomes'])}")
    print(f"\ntotal {time.perf_counter() - t_all:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
