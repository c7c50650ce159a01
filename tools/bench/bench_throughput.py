"""Throughput: trials per CPU-second of an older revision (one trial at a time, as its batch workers flew them) and of
this checkout (trial batches of one map, as `pbdyn batch` flies them now), measured interleaved map by map in one run, with
the step-time distribution and the projected time of one planner pair's full controlled study on 2 cores.

Workloads: "quickstart" (scenarios/quickstart.toml, every planner entry, all 72 start/goal pairs, maps
0..--quick-maps-1) and "controlled" (one planner pair of scenarios/datasets/controlled_2d.toml, default LookAhead +
local primitives, all 72 pairs x 3 MAV speeds on the first --maps-per-setup replicates of every one of the 27 setups:
5,832 trials with 1 replicate). Each code version runs in its own long-lived process (BLAS threads 1, PYTHONHASHSEED
0) fed one map at a time, old and new alternating; CPU time is the process time of the flying itself (rollouts are
built before timing; each worker first flies the first map untimed: imports, and numba compiling or loading its code;
then, where the code has it, it settles its heap as pbdyn batch's workers do after their first group:
pbdyn.experiments.tasks.settle_heap). Every row (wall times excluded) is compared old vs new: the code change must not
change a result. A step's time counts all of its work: lockstep's step walls account for their ticks' time
(pbdyn.sim.trial._share_rest); one trial at a time, the trial's time outside its step splits (views, the planner
call's wrapper, bookkeeping, its first sensing and its result) is spread evenly over its steps. The projection is
trials / (2 x trials per CPU-second) for 540 maps x 216 trials.

    .venv/bin/python tools/bench/bench_throughput.py [--ref REV] [--maps-per-setup 1] [--quick-maps 3] [--old-batches]
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
FULL_STUDY_TRIALS = 540 * 3 * 72

WORKER = r'''
import hashlib, json, os, sys, time
sys.path.insert(0, sys.argv[1])
import pbdyn
assert pbdyn.__file__.startswith(sys.argv[1]), pbdyn.__file__
from pbdyn.config import load_scenario
from pbdyn.sim.trial import make_trial_spec, make_world, run_trial
from pbdyn.world.maps import get_map
from pbdyn.world.rollout import get_rollout
try:
    from pbdyn.sim.trial import fly_trials               # the trial core (a batch of N trials, one loop)
    def run_lockstep(specs, ro, world, step_walls=None):
        return fly_trials(specs, ro, world=world, step_walls=step_walls)
except ImportError:
    try:
        from pbdyn.sim.lockstep import run_lockstep      # older revisions: the separate lockstep loop
    except ImportError:
        run_lockstep = None
try:
    from pbdyn.experiments.tasks import settle_heap       # what pbdyn batch's workers do after their first group
except ImportError:
    settle_heap = None
lockstep = sys.argv[2] == "lockstep"
scenarios = {}
first = True
for line in sys.stdin:
    job = json.loads(line)
    sc = scenarios.setdefault(job["scenario"], load_scenario(job["scenario"]))
    ms = get_map(sc, job["map"])
    ro = get_rollout(sc, ms)
    cands = sc.task.candidates
    groups = []
    for label in job["entries"]:
        for v in sc.drone.v_max:
            groups.append([make_trial_spec(sc, ms, planner=label, v_max=v, start=tuple(cands[i]),
                                           goal=tuple(cands[j])) for i, j in sc.task.pairs()])
    world = make_world(groups[0][0], ro)
    c0, w0 = time.process_time(), time.perf_counter()
    results, walls = [], []
    for specs in groups:
        if lockstep:
            results += run_lockstep(specs, ro, world, step_walls=walls)
        else:
            for spec in specs:
                prof = {}
                r = run_trial(spec, ro, world=world, profile=prof)
                results.append(r)
                steps = [sum(x) for x in zip(*(prof[k] for k in prof if k.startswith("wall_")))]
                rest = r.wall_time_s - r.wall_timings.get("wall_setup_s", 0.0) - sum(steps)   # outside the splits
                walls.append([w + rest / len(steps) for w in steps] if steps and rest > 0.0 else steps)
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    world.close()
    digests = []
    for r in results:
        row = r.without_wall_times()
        row.pop("planner_fingerprint", None)
        digests.append(hashlib.sha256(json.dumps(row, sort_keys=True).encode()).hexdigest()[:16])
    steps = [round(w * 1e6, 1) for ws in walls for w in ws]
    print(json.dumps({"cpu": cpu, "wall": wall, "trials": len(results), "steps": steps, "rows": digests}),
          flush=True)
    if first and settle_heap is not None:
        settle_heap()
    first = False
'''


class Worker:
    """A long-lived process flying maps with the code in ``tree`` (lockstep or one trial at a time)."""

    def __init__(self, tree: Path, lockstep: bool, cache: str):
        env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1",
                   PYTHONHASHSEED="0", PBDYN_CACHE=cache)
        self.proc = subprocess.Popen([sys.executable, "-c", WORKER, str(tree), "lockstep" if lockstep else "one"],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env,
                                     cwd=tempfile.gettempdir())

    def fly(self, scenario: Path, map_index: int, entries: list[str]) -> dict:
        self.proc.stdin.write(json.dumps({"scenario": str(scenario), "map": map_index, "entries": entries}) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError("a benchmark worker died")
        return json.loads(line)

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait(timeout=60)


def workloads(args) -> list[tuple[str, Path, int, list[str]]]:
    """(workload, scenario file, map index, planner entry labels) of every map to fly, in order."""
    sys.path.insert(0, str(ROOT))
    from pbdyn.config import load_scenario

    quick = ROOT / "scenarios" / "quickstart.toml"
    qsc = load_scenario(quick)
    out = [("quickstart", quick, m, [e.label for e in qsc.planners]) for m in range(args.quick_maps)]
    ctrl = ROOT / "scenarios" / "datasets" / "controlled_2d.toml"
    csc = load_scenario(ctrl)
    per_setup = csc.obstacles.maps_per_setup
    label = next(e.label for e in csc.planners if (e.trajectory, e.gaze) == tuple(args.pair.split("+")))
    for setup in range(args.setups):
        for rep in range(args.maps_per_setup):
            out.append(("controlled", ctrl, setup * per_setup + rep, [label]))
    return out


def main() -> int:
    sys.path.insert(0, str(HERE))
    from bench_common import machine, share_native_library

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ref", default="7c81067", help="git revision of the old code (default 7c81067: main before "
                                                     "cheap failing plans and lockstep)")
    ap.add_argument("--maps-per-setup", type=int, default=1, help="controlled maps per setup (27 setups)")
    ap.add_argument("--setups", type=int, default=27, help="controlled setups to fly (a quick check: fewer)")
    ap.add_argument("--quick-maps", type=int, default=3, help="quickstart maps")
    ap.add_argument("--pair", default="local_primitives+lookahead", help="controlled planner pair trajectory+gaze")
    ap.add_argument("--old-batches", action="store_true",
                    help="the old revision flies its maps in groups of 72 too (a revision that has lockstep or the "
                         "trial core), so that old and new compare the same way of flying")
    args = ap.parse_args()
    print(machine())
    sys.path.insert(0, str(ROOT))
    from pbdyn.planning.primitives import native

    print(f"this checkout: {native.status()}")
    jobs = workloads(args)
    cache = os.environ.get("PBDYN_CACHE") or tempfile.mkdtemp(prefix="pbdyn-bench-cache-")
    per = {w: {"old": [], "new": []} for w in ("quickstart", "controlled")}
    with tempfile.TemporaryDirectory(prefix="pbdyn-old-") as tmp:
        old_tree = Path(tmp) / "old"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-q", str(old_tree), args.ref],
                       check=True)
        print(f"old tree: {share_native_library(old_tree)}")
        workers = {"old": Worker(old_tree, args.old_batches, cache), "new": Worker(ROOT, True, cache)}
        try:
            for w in workers.values():          # untimed: imports, and numba compiling (new tree) or loading
                w.fly(*jobs[0][1:])
            for n, (name, scenario, m, entries) in enumerate(jobs):
                order = ("old", "new") if n % 2 == 0 else ("new", "old")
                got = {w: workers[w].fly(scenario, m, entries) for w in order}
                if got["old"]["rows"] != got["new"]["rows"]:
                    raise SystemExit(f"rows differ between {args.ref} and this checkout on {name} map {m}")
                for w in order:
                    per[name][w].append(got[w])
                print(f"{name} map {m}: old {got['old']['trials'] / got['old']['cpu']:.1f}, new "
                      f"{got['new']['trials'] / got['new']['cpu']:.1f} trials/CPU-s", file=sys.stderr)
        finally:
            for w in workers.values():
                w.close()
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(old_tree)], check=False)
    how = "groups of 72 as its pbdyn batch flew them" if args.old_batches else "one trial at a time"
    print(f"old = {args.ref} ({how}), new = this checkout (trial batches of 72 as pbdyn batch); "
          "rows identical old vs new; "
          f"each worker first flew {jobs[0][0]} map {jobs[0][2]} untimed (start-up)")
    print(f"{'workload':<12} {'code':<4} {'trials':>7} {'CPU s':>8} {'trials/CPU-s':>13} {'median map':>11} "
          f"{'step median ms':>15} {'p99 ms':>8} {'p99/med':>8}")
    rates = {}
    for name, d in per.items():
        for w in ("old", "new"):
            runs = d[w]
            if not runs:
                continue
            trials = sum(r["trials"] for r in runs)
            cpu = sum(r["cpu"] for r in runs)
            steps = np.concatenate([np.asarray(r["steps"]) for r in runs]) / 1000.0
            med, p99 = float(np.median(steps)), float(np.percentile(steps, 99))
            rates[(name, w)] = trials / cpu
            per_map = float(np.median([r["trials"] / r["cpu"] for r in runs]))
            print(f"{name:<12} {w:<4} {trials:7d} {cpu:8.1f} {trials / cpu:13.2f} {per_map:11.2f} {med:15.3f} "
                  f"{p99:8.3f} {p99 / med:8.2f}")
        if (name, "old") in rates:
            print(f"{name:<12} new/old trials per CPU-second: {rates[(name, 'new')] / rates[(name, 'old')]:.2f}x")
    for w in ("old", "new"):
        r = rates.get(("controlled", w))
        if r:
            print(f"projected full controlled study of {args.pair} ({FULL_STUDY_TRIALS} trials) on 2 cores, {w}: "
                  f"{FULL_STUDY_TRIALS / (2 * r) / 60:.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())
