"""Benchmark of the gaze planners: median ms per gaze decision (one yaw_rate call) inside real trials, 2D and 3D.

Every registered gaze planner flies with local_primitives on one map of ``--obstacles`` obstacles (r 1 m, 2 m/s;
v_max 4 m/s; 90 deg sensor, 3D 90 x 60 deg) over ``--pairs`` start/goal pairs; the trial loop's per-step
"wall_gaze_s" split (the yaw_rate call alone) is collected over all steps. Target: <= 0.5 ms median in 2D.

    .venv/bin/python tools/bench/bench_gaze.py [--pairs N] [--obstacles N] [--time-limit S]
"""

from __future__ import annotations

import argparse
import os
import sys

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from bench_common import machine  # noqa: E402

from pbdyn.config import parse_scenario  # noqa: E402
from pbdyn.planning.registry import GAZE_PLANNERS  # noqa: E402
from pbdyn.sim.demo import demo_pairs  # noqa: E402
from pbdyn.sim.trial import make_trial_spec, run_trial  # noqa: E402
from pbdyn.world.maps import enumerate_maps  # noqa: E402
from pbdyn.world.rollout import build_rollout  # noqa: E402

TARGET_2D_MS = 0.5


def bench_scenario(dims: int, count: int, time_limit: float):
    """One setup of ``count`` obstacles (r 1 m, 2 m/s), v_max 4 m/s, local_primitives with every gaze planner."""
    sensor = {"fov_deg": 90.0} if dims == 2 else {"fov_deg": 90.0, "vfov_deg": 60.0, "resolution_deg": 2.0}
    return parse_scenario({
        "name": f"bench_gaze_{dims}d",
        "world": {"dims": dims, "time_limit": time_limit},
        "obstacles": {"count": count, "radius": 1.0, "speed": 2.0, "radius_jitter": 0.2, "root_seed": 11},
        "drone": {"v_max": 4.0},
        "sensor": sensor,
        "planners": [{"trajectory": "local_primitives", "gaze": g} for g in GAZE_PLANNERS],
    })


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=4, help="start/goal pairs per gaze planner")
    ap.add_argument("--obstacles", type=int, default=20)
    ap.add_argument("--time-limit", type=float, default=40.0)
    args = ap.parse_args()
    print(machine())
    print(f"{'gaze':<22} {'dims':>4} {'trials':>6} {'n':>6} {'median ms':>10} {'p90 ms':>8} {'max ms':>8}  outcomes")
    worst_2d = 0.0
    for dims in (2, 3):
        sc = bench_scenario(dims, args.obstacles, args.time_limit)
        spec_map = enumerate_maps(sc)[0]
        rollout = build_rollout(sc, spec_map)
        cands = sc.task.candidates
        pairs = demo_pairs(sc, args.pairs)
        for entry in sc.planners:
            gaze_ms: list[float] = []
            outcomes = []
            for i, j in pairs:
                spec = make_trial_spec(sc, spec_map, planner=entry.label, start=cands[i], goal=cands[j])
                prof: dict = {}
                res = run_trial(spec, rollout, profile=prof)
                gaze_ms.extend(1000.0 * x for x in prof["wall_gaze_s"])
                outcomes.append(res.outcome)
            ms = np.asarray(gaze_ms)
            med = float(np.median(ms))
            if dims == 2:
                worst_2d = max(worst_2d, med)
            summary = ", ".join(f"{o}:{outcomes.count(o)}" for o in sorted(set(outcomes)))
            print(f"{entry.gaze:<22} {dims:>4} {len(pairs):>6} {ms.shape[0]:>6} {med:10.4f} "
                  f"{np.percentile(ms, 90):8.4f} {ms.max():8.4f}  {summary}")
    verdict = "met" if worst_2d <= TARGET_2D_MS else "MISSED"
    print(f"n = gaze calls (one per trial step). Worst 2D median {worst_2d:.4f} ms: "
          f"target <= {TARGET_2D_MS} ms {verdict}.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
