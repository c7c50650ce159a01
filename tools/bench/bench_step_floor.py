"""The slowest steps of local-primitive trials and the least they could cost with today's choices.

Flies the first replicate of --setups controlled setups (LookAhead + local primitives, all 72 pairs x 3 MAV speeds)
in lockstep, as `pbdyn batch` does (after an untimed first setup and the workers' settle_heap), and records each
trial step's wall time, its planning time and the planner's ruckig builds. Then it flies them again, keeps the views
of the steps that built at least --heavy trajectories, replays each through the planner's Python path one candidate
at a time (the same builds as the compiled search: their count is checked) to collect the very ruckig inputs, and
times those builds alone through the native library, and the sampling and limit peaks of the trajectories they
gave (candidate_kernels.sampled_peaks; best of 3 each).

A step's floor is its time with planning reduced to ruckig's own computation: step wall - planning wall + the
library's time for that step's builds (steps under --heavy builds: their builds x the median time per build of the
heavy steps); a second floor adds the sampling and peaks, a third the plan's fixed cost (what a one-build step's
planning costs beyond its build and sampling), which the median step pays too. A step's wall time is all of its tick's
work that it caused or shared (pbdyn.sim.trial._share_rest), so the steps account for the loop's time. The
planner's choice needs those builds and samples: a candidate is accepted or rebuilt on its trajectory's sampled limit
peaks, and rejected on its samples' clearance. If the 99th percentile of the floors exceeds 3x the median step, no
change that keeps every choice can bring the step-time ratio under 3 (issue "Throughput", its target).

    .venv/bin/python tools/bench/bench_step_floor.py [--setups 9] [--heavy 20]
"""

from __future__ import annotations

import argparse
import copy
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")        # as pbdyn batch's workers: one BLAS thread
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]


class _Recorder:
    """Wraps LocalPrimitives: each planner's plan() calls in creation order (lockstep creates one per trial, in
    spec order) with their wall time and builds; optionally copies of the views of chosen (trial, call) pairs."""

    def __init__(self, keep: set | None = None):
        from pbdyn.planning.primitives import local as lp

        self.lp = lp
        self.keep = keep or set()
        self.planners: list = []
        self.calls: dict = {}
        self.views: dict = {}

    def __enter__(self):
        lp, rec = self.lp, self
        init0, plan0 = lp.LocalPrimitives.__init__, lp.LocalPrimitives.plan
        self._saved = (init0, plan0)

        def init(planner, *a, **kw):
            init0(planner, *a, **kw)
            planner._bench_index = len(rec.planners)
            rec.planners.append(planner)
            rec.calls[planner._bench_index] = []

        def plan(planner, view):
            t0 = time.perf_counter()
            out = plan0(planner, view)
            wall = time.perf_counter() - t0
            calls = rec.calls[planner._bench_index]
            key = (planner._bench_index, len(calls))
            calls.append((wall, planner.last_candidates_built))
            if key in rec.keep:
                kept = copy.copy(view)
                object.__setattr__(kept, "grid", view.grid.copy())
                rec.views[key] = (planner, kept)
            return out

        lp.LocalPrimitives.__init__, lp.LocalPrimitives.plan = init, plan
        return self

    def __exit__(self, *exc):
        self.lp.LocalPrimitives.__init__, self.lp.LocalPrimitives.plan = self._saved
        return False


def fly(setups: list[int], keep: set | None = None) -> tuple[list, _Recorder, float]:
    """Fly the first replicate of ``setups`` in lockstep; (per trial the wall time of each step (s), the recorder,
    the wall time of the lockstep loops outside the trials' setups and steps (s): results and the loops' set-up)."""
    from pbdyn.config import load_scenario
    from pbdyn.sim.trial import fly_trials
    from pbdyn.sim.trial import make_trial_spec, make_world
    from pbdyn.world.maps import get_map
    from pbdyn.world.rollout import get_rollout

    sc = load_scenario(ROOT / "scenarios" / "datasets" / "controlled_2d.toml")
    label = next(e.label for e in sc.planners if (e.trajectory, e.gaze) == ("local_primitives", "lookahead"))
    cands = sc.task.candidates
    walls: list = []
    glue = 0.0
    with _Recorder(keep) as rec:
        for s in setups:
            ms = get_map(sc, s * sc.obstacles.maps_per_setup)
            ro = get_rollout(sc, ms)
            world = make_world(make_trial_spec(sc, ms, planner=label, v_max=sc.drone.v_max[0],
                                               start=tuple(cands[0]), goal=tuple(cands[1])), ro)
            for v in sc.drone.v_max:
                specs = [make_trial_spec(sc, ms, planner=label, v_max=v, start=tuple(cands[i]), goal=tuple(cands[j]))
                         for i, j in sc.task.pairs()]
                n0 = len(walls)
                t0 = time.perf_counter()
                results = fly_trials(specs, ro, world=world, step_walls=walls)
                glue += time.perf_counter() - t0 - sum(sum(w) for w in walls[n0:])
                glue -= sum(r.wall_timings["wall_setup_s"] for r in results)
            world.close()
    return walls, rec, glue


def ruckig_inputs(flown, view) -> tuple:
    """The ruckig inputs of the builds of planner ``flown`` (a LocalPrimitives of the flight) on ``view``: a copy of
    it on its Python path, one candidate per chunk (the compiled search's build sequence), with calculate()
    recorded. (inputs in probe_inputs' layout, jerk, minimum duration, the Python path's build count)."""
    planner = copy.copy(flown)
    planner._native = None
    planner.CHUNKS = (1,)
    rows: list = []
    otg = planner._otg

    class _Otg:
        def calculate(self, inp, traj):
            rows.append([*inp.current_velocity, *inp.current_acceleration, *inp.target_position,
                         *inp.target_velocity, inp.max_velocity[0], inp.max_acceleration[0]])
            return otg.calculate(inp, traj)

    planner._otg = _Otg()
    planner.plan(view)
    a = np.array(rows, dtype=float).reshape(-1, 10)
    inputs = (a[:, 0:2], a[:, 2:4], a[:, 4:6], a[:, 6:8], a[:, 8], a[:, 9])
    return inputs, planner.jerk_max, planner.min_duration, planner.last_candidates_built


def main() -> int:
    sys.path.insert(0, str(HERE))
    sys.path.insert(0, str(ROOT))
    from bench_common import best_time, machine

    from pbdyn.experiments.tasks import settle_heap
    from pbdyn.limits import MAX_PLAN_HORIZON_S
    from pbdyn.planning.primitives import native
    from pbdyn.planning.primitives.compiled.candidate_kernels import numpy_orders, sampled_peaks

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--setups", type=int, default=9, help="controlled setups, spread over the 27 (first replicate)")
    ap.add_argument("--heavy", type=int, default=20, help="steps with at least this many builds are replayed")
    args = ap.parse_args()
    print(machine())
    print(native.status())
    if native.ruckig_build_address() is None:
        print("the floor is measured through the native library: build it (make native)")
        return 1
    lib = native._load(native.LIBRARY)
    sq_order = numpy_orders(2)[1]
    setups = sorted({int(round(x)) for x in np.linspace(0, 26, args.setups)})
    fly([setups[0]])                                       # imports, compiled code, the first world: untimed
    settle_heap()
    walls, rec, glue = fly(setups)
    step, plan, builds, keys = [], [], [], []
    for i, ws in enumerate(walls):
        calls = rec.calls[i]
        if len(calls) != len(ws):
            raise SystemExit(f"trial {i}: {len(calls)} plan() calls for {len(ws)} steps (one per step expected)")
        for k, (w, (pw, nb)) in enumerate(zip(ws, calls)):
            step.append(w)
            plan.append(pw)
            builds.append(nb)
            keys.append((i, k))
    step, plan, builds = np.array(step), np.array(plan), np.array(builds)
    heavy = {keys[j]: j for j in np.flatnonzero(builds >= args.heavy).tolist()}   # (trial, step) -> row
    _, rec2, _ = fly(setups, keep=set(heavy))
    ruck = {}                                              # row -> (ruckig time, sampling time, builds) (s)
    for key, (flown, view) in rec2.views.items():
        inputs, jerk, min_dur, n_python = ruckig_inputs(flown, view)
        n_native = rec2.calls[key[0]][key[1]][1]
        if n_python != n_native or inputs[0].shape[0] != n_native:
            raise SystemExit(f"step {key}: replay built {inputs[0].shape[0]} ({n_python}), the flight {n_native}")
        best = best_time(lambda: native.build_with_library(lib, inputs, jerk, min_dur), 3)
        prof, dur, res = native.build_with_library(lib, inputs, jerk, min_dur)
        ok = ((res == 0) | (res == 1)) & (dur <= MAX_PLAN_HORIZON_S)
        prof, dur = np.ascontiguousarray(prof[ok]), np.ascontiguousarray(dur[ok])
        ruck[heavy[key]] = (best, best_time(lambda: sampled_peaks(prof, dur, view.dt, sq_order), 3), n_native)
    per_build = np.array([(t / n, u / n) for t, u, n in ruck.values()]).reshape(-1, 2)
    c_build, c_samp = (float(x) for x in np.median(per_build, axis=0)) if len(ruck) else (0.0, 0.0)
    lib_time, samp_time = builds * c_build, builds * c_samp
    for j, (t, u, _) in ruck.items():
        lib_time[j], samp_time[j] = t, u
    floor = step - plan + lib_time
    floor_s = floor + samp_time
    med = float(np.median(step))
    p99 = float(np.percentile(step, 99))
    f99 = float(np.percentile(floor, 99))
    top = step >= p99
    print(f"setups {setups}: {len(walls)} trials, {step.shape[0]} steps; {len(ruck)} steps with >= {args.heavy} "
          f"builds replayed (ruckig alone: median {c_build * 1e6:.2f} us per build)")
    print(f"step wall: median {med * 1e6:.0f} us, p99 {p99 * 1e6:.0f} us, p99/median {p99 / med:.2f}")
    print(f"builds per step: median {np.median(builds):.0f}, p90 {np.percentile(builds, 90):.0f}, "
          f"p99 {np.percentile(builds, 99):.0f}; slowest 1% of steps: median {np.median(builds[top]):.0f} builds, "
          f"planning {np.median(plan[top]) * 1e6:.0f} us, "
          f"the rest of the step {np.median((step - plan)[top]) * 1e6:.0f} us")
    print(f"floor (planning = ruckig alone): p99 {f99 * 1e6:.0f} us = {f99 / med:.2f}x today's median step "
          f"({f99 / float(np.median(floor)):.2f}x the floors' median); target 3x")
    fs99 = float(np.percentile(floor_s, 99))
    print(f"floor with the sampling and limit peaks of the built trajectories (sampled_peaks, median "
          f"{c_samp * 1e6:.2f} us per build): p99 {fs99 * 1e6:.0f} us = {fs99 / med:.2f}x today's median step")
    fixed = float(np.median(plan[builds == 1])) - c_build - c_samp if (builds == 1).any() else 0.0
    ff99 = float(np.percentile(floor_s + fixed, 99))
    print(f"... plus the plan's fixed cost as in today's one-build steps (their median planning time less one build "
          f"and its sampling: {fixed * 1e6:.1f} us): p99 {ff99 * 1e6:.0f} us = {ff99 / med:.2f}x today's median step")
    print(f"the loop's time outside the trials' setups and steps (their results, the lockstep set-up): {glue:.2f} s, "
          f"{glue / (glue + step.sum()) * 100:.1f}% of the steps' time")
    print(f"loop time in the slowest 1% of steps {step[top].sum() / step.sum() * 100:.1f}%, in steps over 3x the "
          f"median {step[step > 3 * med].sum() / step.sum() * 100:.1f}% "
          f"({(step > 3 * med).mean() * 100:.1f}% of steps)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
