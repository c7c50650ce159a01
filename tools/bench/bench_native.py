"""The native ruckig batch and the compiled candidate search against the ruckig Python package and the Python chunk
loop: time per ruckig build (probe inputs), and the local planner's plan() on views recorded from real lockstep
trials of the controlled dataset (LookAhead + local primitives), split into steps whose best candidate passes and
steps where it fails. Both paths run in this process on the same views (interleaved rounds); their plans are
compared bit for bit.

    .venv/bin/python tools/bench/bench_native.py [--setups 3] [--views 3000] [--rounds 3]
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]


def record_views(setups: int, limit: int) -> list:
    """(planner limits, View) of up to ``limit`` steps of the first replicate of ``setups`` controlled setups, every
    10th step and every step whose best candidate failed (grids copied as they were)."""
    from pbdyn.config import load_scenario
    from pbdyn.planning.primitives import local as lp
    from pbdyn.sim.trial import fly_trials
    from pbdyn.sim.trial import make_trial_spec, make_world
    from pbdyn.world.maps import get_map
    from pbdyn.world.rollout import get_rollout

    views: list = []
    original = lp.LocalPrimitives.plan
    count = [0]

    def plan(self, view):
        out = original(self, view)
        count[0] += 1
        if len(views) < limit and (self.last_rank != 0 or count[0] % 10 == 0):
            kept = copy.copy(view)
            object.__setattr__(kept, "grid", view.grid.copy())
            views.append((self.limits, kept))
        return out

    sc = load_scenario(ROOT / "scenarios" / "datasets" / "controlled_2d.toml")
    label = next(e.label for e in sc.planners if (e.trajectory, e.gaze) == ("local_primitives", "lookahead"))
    lp.LocalPrimitives.plan = plan
    try:
        for s in range(setups):
            ms = get_map(sc, s * sc.obstacles.maps_per_setup)
            ro = get_rollout(sc, ms)
            cands = sc.task.candidates
            specs = [make_trial_spec(sc, ms, planner=label, v_max=v, start=tuple(cands[i]), goal=tuple(cands[j]))
                     for v in sc.drone.v_max for i, j in sc.task.pairs()]
            world = make_world(specs[0], ro)
            fly_trials(specs, ro, world=world)
            world.close()
    finally:
        lp.LocalPrimitives.plan = original
    return views


def main() -> int:
    sys.path.insert(0, str(HERE))
    sys.path.insert(0, str(ROOT))
    from bench_common import best_time, machine

    from pbdyn.planning.primitives import native
    from pbdyn.planning.primitives.local import LocalPrimitives
    from pbdyn.planning.protocols import PlannerContext

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--setups", type=int, default=3)
    ap.add_argument("--views", type=int, default=3000)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    print(machine())
    print(native.status())
    if native.ruckig_build_address() is None:
        print("nothing to compare: build the library (make native)")
        return 1
    lib = native._load(native.LIBRARY)
    for d in (2, 3):
        inputs = native.probe_inputs(d, 2000)
        for name, build in (("library", lambda: native.build_with_library(lib, inputs, 20.0, 0.5)),
                            ("package", lambda: native.build_with_package_reference(inputs, 20.0, 0.5))):
            best = best_time(build, args.rounds)
            print(f"{d}D ruckig build through the {name}: {best / 2000 * 1e6:.2f} us")
    views = record_views(args.setups, args.views)
    planners: dict = {}
    for limits, view in views:
        key = limits.v_max
        if key not in planners:
            ctx = PlannerContext(2, view.dt, limits, view.bounds_lo, view.bounds_hi)
            python = LocalPrimitives(ctx)
            python._native = None
            planners[key] = (LocalPrimitives(ctx), python)
    times = {"native": [], "python": []}
    passes = []
    for r in range(args.rounds):
        for limits, view in views:
            fast, slow = planners[limits.v_max]
            order = ((fast, "native"), (slow, "python")) if r % 2 == 0 else ((slow, "python"), (fast, "native"))
            plans = {}
            for planner, name in order:
                t0 = time.perf_counter()
                plans[name] = planner.plan(view)
                times[name].append(time.perf_counter() - t0)
            a, b = plans["native"], plans["python"]
            if (a is None) != (b is None) or (a is not None and not all(
                    np.array_equal(x, y) for x, y in ((a.p, b.p), (a.v, b.v), (a.a, b.a)))):
                raise SystemExit("native and Python plans differ")
            if r == 0:
                passes.append(fast.last_rank == 0)
    passes = np.tile(np.array(passes), args.rounds)
    print(f"{len(views)} views x {args.rounds} rounds, plans identical; median us per plan (native / python):")
    for label, mask in (("best candidate passes", passes), ("best candidate fails", ~passes)):
        nat = np.median(np.array(times["native"])[mask]) * 1e6
        py = np.median(np.array(times["python"])[mask]) * 1e6
        print(f"  {label:<22} n={int(mask.sum()) // args.rounds:5d}: {nat:7.1f} / {py:7.1f}  ({py / nat:.2f}x)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
