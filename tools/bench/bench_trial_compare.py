"""Old vs new trial loop, measured interleaved in one run: median ms per simulated step of each configuration.

Runs the same workload (bench_trial.py's planner pairs on a 10- and a 30-obstacle 2D map and a 10-obstacle 3D
map, N start/goal pairs each) alternately with the code of a git revision (default 145e667, main before the
steppable core) and with this checkout, each round in fresh processes, and prints per configuration the median over
rounds of the loop time per step (the steps' wall-time splits, what bench_trial.py reports) and of the whole
trial's wall time per step (including building the trial's PyBullet world), old and new, and the ratios old/new
(> 1: the new code is faster). Each process first flies one untimed trial of every planner pair (its start-up:
imports, numba loading -- or, the first time in a tree, compiling -- the compiled code on first use), whose wall
time is printed apart; before the rounds, one untimed run per version fills the caches of compiled code.

    .venv/bin/python tools/bench/bench_trial_compare.py [--ref REV] [--rounds R] [--pairs N]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]

WORKLOAD = r'''
import json, os, sys, time
sys.path.insert(0, sys.argv[1])
import pbdyn
assert pbdyn.__file__.startswith(sys.argv[1]), pbdyn.__file__
from pbdyn.config import parse_scenario
from pbdyn.sim.demo import demo_pairs
from pbdyn.sim.trial import make_trial_spec, run_trial
from pbdyn.world.maps import enumerate_maps
from pbdyn.world.rollout import build_rollout
pairs = int(sys.argv[2])
PAIRS = (("straight_line", "lookahead"), ("local_primitives", "lookahead"), ("local_primitives", "fullrange"),
         ("global_primitives", "lookahead"), ("mpc", "lookahead"))
out = {}
for dims, count in ((2, 10), (2, 30), (3, 10)):
    sc = parse_scenario({"name": "cmp", "world": {"time_limit": 40.0, "dims": dims},
                         "obstacles": {"count": count, "radius": 1.0, "speed": 4.0, "radius_jitter": 0.2,
                                       "root_seed": 11},
                         "drone": {"v_max": 4.0}, "sensor": {"fov_deg": 90.0},
                         "planners": [{"trajectory": t, "gaze": g} for t, g in PAIRS]})
    m = enumerate_maps(sc)[0]
    ro = build_rollout(sc, m)
    cands = sc.task.candidates
    if not out:                 # process start-up (imports, compiled code loaded or compiled on first use):
        i, j = demo_pairs(sc, 1)[0]     # one untimed trial of every planner pair
        t0 = time.perf_counter()
        for e in sc.planners:
            run_trial(make_trial_spec(sc, m, planner=e.label, start=cands[i], goal=cands[j]), ro)
        out["_first_trial_s"] = time.perf_counter() - t0
    for e in sc.planners:
        wall = steps = loop = 0.0
        for i, j in demo_pairs(sc, pairs):
            spec = make_trial_spec(sc, m, planner=e.label, start=cands[i], goal=cands[j])
            t0 = time.perf_counter()
            res = run_trial(spec, ro)
            wall += time.perf_counter() - t0
            steps += res.steps
            loop += res.wall_timings["wall_step_mean_s"] * res.steps
        out[f"{e.label} {dims}D n={count}"] = (wall, steps, loop, pairs)
print(json.dumps(out))
'''


def run(tree: Path, pairs: int) -> dict:
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", PYTHONHASHSEED="0")
    env["PBDYN_CACHE"] = env.get("PBDYN_CACHE") or tempfile.mkdtemp(prefix="pbdyn-bench-cache-")
    text = subprocess.run([sys.executable, "-c", WORKLOAD, str(tree), str(pairs)], capture_output=True, text=True,
                          check=True, cwd=tempfile.gettempdir(), env=env).stdout
    return json.loads(text.strip().splitlines()[-1])


def main() -> int:
    sys.path.insert(0, str(HERE))
    from bench_common import machine, share_native_library

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ref", default="145e667", help="git revision of the old code (default 145e667)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--pairs", type=int, default=4)
    args = ap.parse_args()
    print(machine())
    with tempfile.TemporaryDirectory(prefix="pbdyn-old-") as tmp:
        old_tree = Path(tmp) / "old"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-q", str(old_tree), args.ref],
                       check=True)
        print(f"old tree: {share_native_library(old_tree)}")
        try:
            for tree in (old_tree, ROOT):      # untimed: fills numba's on-disk caches of a new tree (compiles)
                run(tree, 1)
            per = {"old": [], "new": []}
            for r in range(args.rounds):
                order = ("old", "new") if r % 2 == 0 else ("new", "old")
                for which in order:
                    per[which].append(run(old_tree if which == "old" else ROOT, args.pairs))
                print(f"round {r + 1}/{args.rounds} done", file=sys.stderr)
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(old_tree)], check=False)
    print(f"{'configuration':<36} {'loop ms/step old':>16} {'new':>7} {'old/new':>7}   {'trial ms/step old':>17} "
          f"{'new':>7} {'old/new':>7}   (median of {args.rounds} interleaved rounds, {args.pairs} pairs each)")
    loops, totals = [], []
    for key in per["old"][0]:
        if key.startswith("_"):
            continue
        lo, ln = (np.median([1000 * d[key][2] / d[key][1] for d in per[w]]) for w in ("old", "new"))
        to, tn = (np.median([1000 * d[key][0] / d[key][1] for d in per[w]]) for w in ("old", "new"))
        loops.append(lo / ln)
        totals.append(to / tn)
        print(f"{key:<36} {lo:16.4f} {ln:7.4f} {lo / ln:7.3f}   {to:17.4f} {tn:7.4f} {to / tn:7.3f}")
    print(f"{'median ratio old/new':<36} {'':>16} {'':>7} {np.median(loops):7.3f}   {'':>17} {'':>7} "
          f"{np.median(totals):7.3f}")
    first = [np.median([d.get("_first_trial_s", np.nan) for d in per[w]]) for w in ("old", "new")]
    print(f"each process's first trial of every pair (untimed above: start-up, compiled code loaded), s: old "
          f"{first[0]:.3f}, new {first[1]:.3f} (median)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
