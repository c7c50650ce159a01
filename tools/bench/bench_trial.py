"""Benchmark of the trial loop: median ms per step and per trial, with the split between world updates, rays,
tracking, planning, gaze and collision checks, and ruckig candidates built per planning step.

Runs straight_line, LookAhead+local_primitives and FullRange+local_primitives on a 10- and a 30-obstacle map
(90 deg sensor, v_max 4 m/s) over several start/goal pairs and prints each configuration's config hash.

    .venv/bin/python tools/bench/bench_trial.py [--pairs N] [--time-limit S]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from bench_common import machine  # noqa: E402

from pbdyn.config import parse_scenario  # noqa: E402
from pbdyn.sim.demo import demo_pairs  # noqa: E402
from pbdyn.sim.trial import SPLITS, make_trial_spec, run_trial  # noqa: E402
from pbdyn.world.maps import enumerate_maps  # noqa: E402
from pbdyn.world.rollout import build_rollout  # noqa: E402

PAIRS = (("straight_line", "lookahead"), ("local_primitives", "lookahead"), ("local_primitives", "fullrange"))


def bench_scenario(count: int, time_limit: float, dims: int = 2):
    """A controlled-set style scenario with one setup of ``count`` obstacles (r 1 m, 4 m/s)."""
    return parse_scenario({
        "name": f"bench_{count}_{dims}d",
        "world": {"time_limit": time_limit, "dims": dims},
        "obstacles": {"count": count, "radius": 1.0, "speed": 4.0, "radius_jitter": 0.2, "root_seed": 11},
        "drone": {"v_max": 4.0},
        "sensor": {"fov_deg": 90.0},
        "planners": [{"trajectory": t, "gaze": g} for t, g in PAIRS],
    })


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=6, help="start/goal pairs per configuration")
    ap.add_argument("--time-limit", type=float, default=80.0)
    args = ap.parse_args()
    print(machine())
    print(f"{'configuration':<40} {'obst':>4} {'trials':>6} {'steps':>6} {'ms/step':>8} {'ms/trial':>9} "
          + " ".join(f"{s[5:-2]:>9}" for s in SPLITS) + f" {'cands':>9}  config_hash")
    for dims, count in ((2, 10), (2, 30), (3, 10), (3, 30)):
        sc = bench_scenario(count, args.time_limit, dims)
        spec_map = enumerate_maps(sc)[0]
        rollout = build_rollout(sc, spec_map)
        cands = sc.task.candidates
        for entry in sc.planners:
            per_step = []
            per_split = {s: [] for s in SPLITS}
            built = []
            trial_times = []
            hashes = []
            outcomes = []
            for i, j in demo_pairs(sc, args.pairs):
                spec = make_trial_spec(sc, spec_map, planner=entry.label, start=cands[i], goal=cands[j])
                prof: dict = {}
                t0 = time.perf_counter()
                res = run_trial(spec, rollout, profile=prof)
                trial_times.append(time.perf_counter() - t0)
                hashes.append(res.config_hash[:12])
                outcomes.append(res.outcome)
                steps = np.sum([prof[s] for s in SPLITS], axis=0)
                per_step.extend(steps.tolist())
                for s in SPLITS:
                    per_split[s].extend(prof[s])
                built.extend(x for x in prof["candidates_built"] if x == x)
            med = 1000 * np.median(per_step)
            split_txt = " ".join(f"{1000 * np.median(per_split[s]):9.4f}" for s in SPLITS)
            cand = f"{np.median(built):3.0f}/{np.mean(built):5.1f}" if built else f"{'-':>9}"
            print(f"{entry.label + f' ({dims}D)':<40} {count:>4} {len(trial_times):>6} {len(per_step):>6} {med:8.4f} "
                  f"{1000 * np.median(trial_times):9.1f} {split_txt} {cand}  {hashes[0]}")
            print(f"{'':<40} outcomes: {', '.join(outcomes)}", file=sys.stderr)
    print("ms/step and splits are medians over all steps; cands = median/mean ruckig builds per planning step.")
    bench_rvo()
    return 0


def bench_rvo(repeats: int = 5) -> None:
    """Median wall time of an RVO rollout: 30 obstacles of 1.5 m at 6 m/s over 80 s (801 steps), 2D and 3D."""
    for dims in (2, 3):
        sc = parse_scenario({"world": {"dims": dims, "time_limit": 80.0},
                             "obstacles": {"count": 30, "radius": 1.5, "speed": 6.0, "motion": "rvo",
                                           "root_seed": 1}})
        spec_map = enumerate_maps(sc)[0]
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            build_rollout(sc, spec_map)
            times.append(time.perf_counter() - t0)
        print(f"RVO rollout {dims}D, 30 obstacles x 80 s: median {np.median(times):.3f} s (n={repeats})")


if __name__ == "__main__":
    sys.exit(main())
