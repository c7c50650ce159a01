"""Benchmark of the MPC planner in the trial loop: plan() and whole-step wall times, with trial outcomes.

For 2D and 3D maps of 10 and 30 obstacles (r 1 m, 4 m/s, CVM), LookAhead gaze, 90 deg sensor, v_max 4 m/s, the MPC
flies ``--pairs`` start/goal pairs on map 0. Printed per configuration: median / p95 / max of plan() (the trial's
planning split, which is replan_check + plan) and of the whole trial step (world, rays, tracking, planning, gaze,
collision), in ms over all steps, and the outcome counts. Target (issue 5): median step <= 10 ms in 2D with 30
obstacles.

    .venv/bin/python tools/bench/bench_mpc.py [--pairs 12] [--backend clarabel|cvxpy] [--time-limit 80]
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


def scenario(dims: int, count: int, backend: str, time_limit: float):
    """One setup of ``count`` obstacles (r 1 m, 4 m/s), LookAhead + MPC, v_max 4 m/s."""
    return parse_scenario({
        "name": f"bench_mpc_{count}_{dims}d",
        "world": {"time_limit": time_limit, "dims": dims},
        "obstacles": {"count": count, "radius": 1.0, "speed": 4.0, "radius_jitter": 0.2, "root_seed": 11},
        "drone": {"v_max": 4.0},
        "sensor": {"fov_deg": 90.0},
        "planners": [{"trajectory": "mpc", "gaze": "lookahead", "trajectory_params": {"backend": backend}}],
    })


def stats(ms: np.ndarray) -> str:
    """'median p95 max' of times in ms."""
    return f"{np.median(ms):7.2f} {np.percentile(ms, 95):7.2f} {ms.max():7.2f}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=12, help="start/goal pairs per configuration")
    ap.add_argument("--backend", choices=("clarabel", "cvxpy"), default="clarabel")
    ap.add_argument("--time-limit", type=float, default=80.0)
    args = ap.parse_args()
    print(machine())
    print(f"MPC backend {args.backend}, LookAhead, v_max 4 m/s, obstacles r 1 m at 4 m/s, {args.pairs} pairs, map 0")
    print(f"{'config':<10} {'trials':>6} {'steps':>6} | {'plan() ms: med':>14} {'p95':>7} {'max':>7} | "
          f"{'step ms: med':>12} {'p95':>7} {'max':>7} | outcomes")
    t_all = time.perf_counter()
    for dims, count in ((2, 10), (2, 30), (3, 10), (3, 30)):
        sc = scenario(dims, count, args.backend, args.time_limit)
        spec_map = enumerate_maps(sc)[0]
        rollout = build_rollout(sc, spec_map)
        cands = sc.task.candidates
        plan_ms, step_ms = [], []
        outcomes: Counter = Counter()
        for i, j in demo_pairs(sc, args.pairs):
            spec = make_trial_spec(sc, spec_map, start=cands[i], goal=cands[j])
            prof: dict = {}
            res = run_trial(spec, rollout, profile=prof)
            outcomes[res.outcome] += 1
            plan_ms.extend(1000.0 * np.asarray(prof["wall_planning_s"]))
            step_ms.extend(1000.0 * np.sum([prof[s] for s in SPLITS], axis=0))
        out = ", ".join(f"{k}={v}" for k, v in sorted(outcomes.items()))
        print(f"{f'{dims}D n={count}':<10} {sum(outcomes.values()):>6} {len(step_ms):>6} | "
              f"{stats(np.asarray(plan_ms)):>30} | {stats(np.asarray(step_ms)):>28} | {out}", flush=True)
    print(f"total {time.perf_counter() - t_all:.0f} s; times are over all steps of all trials of a configuration.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
