"""The compiled A* of the global motion primitives planner (GlobalPrimitives(search="compiled"), thesis A-1,
Algorithm 2) against the Python search, on the views of real trials.

Each case flies one trial with the compiled search, keeping a copy of the view of every plan() call (grid and
tracks as they were), then replays the views through a fresh planner of each mode: every view with the compiled
search; with the Python search first up to --python-budget-views views where the compiled search hit the budget
(max_expansions = 20000), then the others in the flight's order, until --python-cap-s (s) of Python search time is
spent. Printed per mode on the views both replayed: n, median ms per search, median us per expansion (searches of
>= 100 expansions), total time over total expansions, budget hits and the median ms of a budget-hitting search,
and the share of searches with the same status, expansions and trajectory (bit for bit); then the compiled search
alone on all views (the whole flight's searches).

Cases: the blocked 2D walls flight (calibration_2d map 29, (25, 25) -> (46, 4) at 6 m/s: budget hits from 15 s
on), quickstart map 8, spheres_3d map 3, and calibration_3d map 25 (3D walls, candidates 0 -> 6 at 6 m/s; flight
time capped by --time-3d s).

    .venv/bin/python tools/bench/bench_astar_compiled.py [--python-cap-s 120] [--python-budget-views 2]
                                                         [--time-3d 30] [--cases walls2d,quickstart,...]
"""

from __future__ import annotations

import argparse
import copy
import math
import os
import sys
import time
import tomllib
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from bench_common import machine  # noqa: E402

from pbdyn.api import load_scenario, run_trial  # noqa: E402
from pbdyn.planning.primitives.global_astar import GlobalPrimitives  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
CASES = ("walls2d", "quickstart", "spheres3d", "walls3d")


def _capped(path: Path, time_limit: float) -> dict:
    doc = tomllib.loads(path.read_text())
    doc["world"]["time_limit"] = time_limit
    return doc


def case_trial(name: str, time_3d: float) -> tuple:
    """(scenario, run_trial keyword arguments) of a case."""
    if name == "walls2d":
        return (_capped(ROOT / "scenarios/calibration/calibration_2d.toml", 80.0),
                {"gaze": "fullrange", "map": 29, "start": (25, 25), "goal": (46, 4), "v_max": 6.0})
    if name == "quickstart":
        return "quickstart", {"gaze": "lookahead", "map": 8}
    if name == "spheres3d":
        return "spheres_3d", {"gaze": "lookahead", "map": 3}
    doc = _capped(ROOT / "scenarios/calibration/calibration_3d.toml", time_3d)
    cands = load_scenario(doc).task.candidates
    return doc, {"gaze": "fullrange", "map": 25, "start": cands[0], "goal": cands[6], "v_max": 6.0}


def record(name: str, time_3d: float) -> tuple:
    """(planner context, [view of every plan() call], outcome, flight wall time s) of a case flown with the
    compiled search."""
    views: list = []
    ctx: list = []

    class Recorder(GlobalPrimitives):
        def __init__(self, context, **params):
            super().__init__(context, **{**params, "search": "compiled"})
            ctx.append(context)

        def plan(self, view):
            views.append(copy.deepcopy(view))
            return super().plan(view)

    scenario, kw = case_trial(name, time_3d)
    t0 = time.perf_counter()
    res = run_trial(scenario, planner=Recorder, **kw)
    return ctx[0], views, res.outcome, time.perf_counter() - t0


def replay(ctx, views: list, search: str, cap_s: float, order=None) -> dict:
    """{view index: (wall s, status, expansions, trajectory)} of plan() on the views in ``order`` (default: all in
    order) until cap_s is spent."""
    gp = GlobalPrimitives(ctx, search=search)
    out, spent = {}, 0.0
    for i in range(len(views)) if order is None else order:
        if spent >= cap_s:
            break
        t0 = time.perf_counter()
        tr = gp.plan(views[i])
        dt = time.perf_counter() - t0
        spent += dt
        out[i] = (dt, gp.last_status, gp.last_expansions, tr)
    return out


def _same(a, b) -> bool:
    return a[1] == b[1] and a[2] == b[2] and (a[3] is None) == (b[3] is None) and (
        a[3] is None or all(np.array_equal(getattr(a[3], n), getattr(b[3], n)) for n in ("p", "v", "a")))


def _stats(rows: list) -> str:
    t = np.array([r[0] for r in rows])
    e = np.array([r[2] for r in rows])
    big = e >= 100
    per_exp = f"{1e6 * np.median(t[big] / e[big]):9.1f}" if big.any() else f"{'-':>9}"
    budget = np.array([r[1] == "budget" for r in rows], dtype=bool)
    t_budget = f"{1e3 * np.median(t[budget]):10.1f}" if budget.any() else f"{'-':>10}"
    return f"{len(rows):>5} {1e3 * np.median(t):10.2f} {per_exp} {1e6 * t.sum() / max(e.sum(), 1):9.1f} " \
           f"{int(e.sum()):>9} {int(budget.sum()):>6} {t_budget}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--python-cap-s", type=float, default=120.0, help="Python search time per case (s)")
    ap.add_argument("--python-budget-views", type=int, default=2,
                    help="budget-hitting views the Python search replays first, per case")
    ap.add_argument("--time-3d", type=float, default=30.0, help="flight time limit of the 3D walls case (s)")
    ap.add_argument("--cases", default=",".join(CASES), help=f"comma-separated, of {', '.join(CASES)}")
    args = ap.parse_args()
    print(machine())
    print("global_primitives defaults; times of plan() (search + sampling); us/exp: median over searches of >= 100 "
          "expansions; total us/exp: sum of times / sum of expansions")
    head = f"{'case':<11} {'mode':<9} {'n':>5} {'ms/search':>10} {'us/exp':>9} {'tot us/exp':>9} {'expans.':>9} " \
           f"{'budget':>6} {'ms/budget':>10}"
    for name in args.cases.split(","):
        ctx, views, outcome, wall = record(name, args.time_3d)
        cc = replay(ctx, views, "compiled", math.inf)
        first = [i for i in cc if cc[i][1] == "budget"][:args.python_budget_views]
        py = replay(ctx, views, "python", args.python_cap_s, first + [i for i in cc if i not in first])
        n = len(py)
        both = [cc[i] for i in py]
        same = sum(_same(py[i], cc[i]) for i in py) / max(n, 1)
        ratio = sum(r[0] for r in py.values()) / max(sum(r[0] for r in both), 1e-12)
        exact = GlobalPrimitives(ctx, search="compiled")._compiled.exact
        print(f"\n{name}: {ctx.dims}D v_max {ctx.limits.v_max:g}, flight {outcome} in {wall:.1f} s (compiled), "
              f"{len(views)} plan() views; numpy orders known everywhere: {exact}")
        print(head)
        print(f"{name:<11} {'python':<9} {_stats(list(py.values()))}")
        print(f"{name:<11} {'compiled':<9} {_stats(both)}")
        print(f"{name:<11} {'comp. all':<9} {_stats(list(cc.values()))}")
        print(f"  same views: speedup {ratio:.1f}x in total time; identical status, expansions and trajectory "
              f"{100 * same:.1f}% of {n}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
