"""Median times of the difficulty-evaluation pieces: the closed-form baselines per map, the task metrics per trial,
the item-response fits and the trial-level scores (docs/performance.md).

    .venv/bin/python tools/bench/bench_difficulty.py [--repeat 5]

Maps: the quickstart's 2D and the spheres_3d scenario's first map, and a structured map with walls (2D). Fits:
outcomes simulated from a 1PL model at the sizes of the thesis program comparison (81 maps x 12 respondents x 72
tasks = 69,984 trials) and of the thesis' controlled study (540 maps x 54 respondents x 72 tasks = 2.1 M trials).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from pbdyn.analysis.irt import fit_rasch, fit_rasch_sparse  # noqa: E402
from pbdyn.analysis.trial_level import trial_level  # noqa: E402
from pbdyn.api import load_scenario, rollout  # noqa: E402
from pbdyn.config import parse_scenario  # noqa: E402
from pbdyn.metrics.baselines import flux, static_share  # noqa: E402
from pbdyn.metrics.task import corridor_flux, corridor_survivability  # noqa: E402
from pbdyn.world.maps import enumerate_maps  # noqa: E402
from pbdyn.world.rollout import build_rollout  # noqa: E402
from tools.bench.bench_common import machine  # noqa: E402


def median_ms(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1000.0 * statistics.median(times)


def simulated(n_maps: int, n_resp: int, per: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    b = rng.normal(0.0, 1.5, n_maps)
    theta = rng.normal(0.5, 1.0, n_resp)
    it = np.repeat(np.arange(n_maps), n_resp * per)
    re = np.tile(np.repeat(np.arange(n_resp), per), n_maps)
    y = (rng.random(it.shape) < 1.0 / (1.0 + np.exp(-(theta[re] - b[it])))).astype(float)
    return it, re, y


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    print(machine())
    walls = parse_scenario({"obstacles": {"count": 20, "radius": 1.0, "speed": 4.0, "structure": "walls"}})
    maps = {"quickstart 2D map 0": rollout("quickstart", 0), "spheres_3d map 0": rollout("spheres_3d", 0),
            "structured walls 2D": build_rollout(walls, enumerate_maps(walls)[0])}
    print(f"{'map':<22} {'flux [ms]':>10} {'static_share [ms]':>18} {'task survivability [ms]':>24} "
          f"{'task flux [ms]':>15}")
    for name, ro in maps.items():
        sc = load_scenario("spheres_3d") if ro.dims == 3 else walls
        start, goal = sc.task.candidates[0], sc.task.candidates[-1]
        print(f"{name:<22} {median_ms(lambda: flux(ro), args.repeat):>10.2f} "
              f"{median_ms(lambda: static_share(ro), args.repeat):>18.2f} "
              f"{median_ms(lambda: corridor_survivability(ro, start, goal), args.repeat):>24.2f} "
              f"{median_ms(lambda: corridor_flux(ro, start, goal), args.repeat):>15.2f}")
    print(f"\n{'1PL fit':<58} {'median [s]':>10}")
    for label, (n_maps, n_resp, per) in (("81 maps x 12 respondents x 72 (69,984 trials)", (81, 12, 72)),
                                         ("540 maps x 54 respondents x 72 (2.1 M trials)", (540, 54, 72))):
        it, re, y = simulated(n_maps, n_resp, per)
        items = np.char.add("m", it.astype(str))
        resp = np.char.add("r", re.astype(str))
        reps = max(1, args.repeat // 2)
        print(f"  maps, statsmodels GLM, {label:<34} {median_ms(lambda: fit_rasch(items, resp, y), reps) / 1e3:>10.2f}")
        tasks = np.char.add(items, np.char.add("|", (np.arange(y.size) % per).astype(str)))
        print(f"  tasks, scikit-learn, {label:<36} "
              f"{median_ms(lambda: fit_rasch_sparse(tasks, resp, y), reps) / 1e3:>10.2f}")
    it, re, y = simulated(81, 12, 72)
    preds = {f"p{k}": np.random.default_rng(k).normal(size=y.size) for k in range(10)}
    print(f"\ntrial level, 10 predictors, 69,984 trials: "
          f"{median_ms(lambda: trial_level(y, re, it, preds), max(1, args.repeat // 2)) / 1e3:.2f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
