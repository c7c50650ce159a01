"""Benchmark of the trajectory planners in the trial loop: plan() and whole-step wall times, with trial outcomes.

For 2D and 3D maps of 10 and 30 obstacles (r 1 m, 4 m/s, CVM), LookAhead gaze, 90 deg sensor, v_max 4 m/s, each
planner flies ``--pairs`` start/goal pairs on map 0. Printed per planner and configuration: median / p95 / max of
the planning split (replan_check + plan, per step) and of plan() calls only (steps that planned), of the whole
trial step (world, rays, tracking, planning, gaze, collision), in ms, and the outcome counts. Targets (issue 5):
global primitives <= 2 ms and MPC <= 10 ms median per step in 2D with 30 obstacles.
(tools/bench/bench_global_primitives.py adds the A* search statistics: budget hits, exhausted searches.)

    .venv/bin/python tools/bench/bench_planners.py [--pairs 12] [--planners local_primitives mpc ...]
        [--mpc-backend clarabel|cvxpy] [--time-limit 80] [--profile physical|thesis_program]

local_primitives_minjerk (the thesis program's primitives) mostly fails under the physical profile (its primitives
exceed a_max; every failing step evaluates all candidates): time it with --profile thesis_program.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections import Counter

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from bench_common import machine  # noqa: E402

from pbdyn.config import parse_scenario  # noqa: E402
from pbdyn.sim.demo import demo_pairs  # noqa: E402
from pbdyn.sim.trial import SPLITS, make_trial_spec, run_trial  # noqa: E402
from pbdyn.world.maps import enumerate_maps  # noqa: E402
from pbdyn.world.rollout import build_rollout  # noqa: E402


PLANNERS = ("local_primitives", "global_primitives", "mpc", "straight_line", "local_primitives_minjerk")


def scenario(dims: int, count: int, planner: str, params: dict, time_limit: float, profile: str | None = None):
    """One setup of ``count`` obstacles (r 1 m, 4 m/s), LookAhead + ``planner``, v_max 4 m/s; ``profile``: the
    scenario's top-level profile key (omitted when None: the default profile)."""
    extra = {} if profile is None else {"profile": profile}
    return parse_scenario({
        **extra,
        "name": f"bench_{planner}_{count}_{dims}d",
        "world": {"time_limit": time_limit, "dims": dims},
        "obstacles": {"count": count, "radius": 1.0, "speed": 4.0, "radius_jitter": 0.2, "root_seed": 11},
        "drone": {"v_max": 4.0},
        "sensor": {"fov_deg": 90.0},
        "planners": [{"trajectory": planner, "gaze": "lookahead", "trajectory_params": params}],
    })


def stats(ms: np.ndarray) -> str:
    """'median p95 max' of times in ms."""
    return f"{np.median(ms):7.2f} {np.percentile(ms, 95):7.2f} {ms.max():7.2f}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=12, help="start/goal pairs per configuration")
    ap.add_argument("--planners", nargs="+", default=list(PLANNERS))
    ap.add_argument("--mpc-backend", choices=("clarabel", "cvxpy"), default="clarabel")
    ap.add_argument("--time-limit", type=float, default=80.0)
    ap.add_argument("--profile", choices=("physical", "thesis_program"), default=None,
                    help="the scenarios' profile (default: the scenario default)")
    args = ap.parse_args()
    print(machine())
    print(f"LookAhead, v_max 4 m/s, obstacles r 1 m at 4 m/s, {args.pairs} pairs, map 0 (MPC: {args.mpc_backend})"
          + (f", profile {args.profile}" if args.profile else ""))
    print(f"{'planner':<24} {'config':<8} {'trials':>6} {'steps':>6} | {'planning/step ms: med':>21} {'p95':>7} "
          f"{'max':>7} | {'plan() ms: med':>14} {'p95':>7} {'max':>7} | {'step ms: med':>12} {'p95':>7} {'max':>7} "
          "| outcomes")
    t_all = time.perf_counter()
    for planner in args.planners:
        params = {"backend": args.mpc_backend} if planner == "mpc" else {}
        for dims, count in ((2, 10), (2, 30), (3, 10), (3, 30)):
            sc = scenario(dims, count, planner, params, args.time_limit, args.profile)
            spec_map = enumerate_maps(sc)[0]
            rollout = build_rollout(sc, spec_map)
            cands = sc.task.candidates
            plan_ms, calls_ms, step_ms = [], [], []
            outcomes: Counter = Counter()
            for i, j in demo_pairs(sc, args.pairs):
                spec = make_trial_spec(sc, spec_map, start=cands[i], goal=cands[j])
                prof: dict = {}
                res = run_trial(spec, rollout, profile=prof)
                outcomes[res.outcome] += 1
                planning = 1000.0 * np.asarray(prof["wall_planning_s"])
                plan_ms.extend(planning)
                calls_ms.extend(planning[np.asarray(prof["planned"], bool)])
                step_ms.extend(1000.0 * np.sum([prof[s] for s in SPLITS], axis=0))
            out = ", ".join(f"{k}={v}" for k, v in sorted(outcomes.items()))
            print(f"{planner:<24} {f'{dims}D n={count}':<8} {sum(outcomes.values()):>6} {len(step_ms):>6} | "
                  f"{stats(np.asarray(plan_ms)):>37} | {stats(np.asarray(calls_ms)):>30} | "
                  f"{stats(np.asarray(step_ms)):>28} | {out}", flush=True)
    print(f"total {time.perf_counter() - t_all:.0f} s; times are over all steps of all trials of a configuration.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
