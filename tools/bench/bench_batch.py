"""Benchmark of the batch runner: trials per second with 1 and 2 workers (scaling efficiency), process pool vs a
local Dask cluster, and the store + transport overhead per trial.

The workload is the first ``--trials`` trials of scenarios/quickstart.toml (map metrics off), each configuration
run ``--repeat`` times into a fresh store (rollouts come from the shared cache, built once before timing).
Overhead = 1 - (sum of the trials' own wall_time_s) / (workers x batch wall time): the share of worker capacity
not spent flying (transport, store, scheduling, start-up). The store alone is timed by inserting the same rows
into a fresh store with a commit per second.

    .venv/bin/python tools/bench/bench_batch.py [--trials 96] [--repeat 3] [--no-dask] [--lockstep N]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from bench_common import machine  # noqa: E402

from pbdyn.config import load_scenario  # noqa: E402
from pbdyn.experiments.runner import BatchOptions, run_batch  # noqa: E402
from pbdyn.experiments.store import ResultsStore  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def one_run(scenario, n: int, workers: int, **opts) -> tuple[float, float, float, list[dict]]:
    """(batch wall time s, sum of trial wall times s, steady-state overhead, rows) of one fresh run.

    Steady state: between the moment every worker has delivered its first row and the last row (store
    timestamps), overhead = 1 - (trial wall times of the rows finished in that window) / (workers x window)."""
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "bench.sqlite"
        t0 = time.perf_counter()
        run_batch(scenario, out, BatchOptions(limit=n, metrics=False, progress=False, workers=workers, **opts))
        wall = time.perf_counter() - t0
        store = ResultsStore.open(out)
        rows = store.results()
        stamps = sorted(store.conn.execute("SELECT finished, wall_time_s FROM trials").fetchall())
        store.close()
    start = stamps[workers - 1][0]
    window = stamps[-1][0] - start
    busy = sum(w for f, w in stamps[workers:])
    steady = 1.0 - busy / (workers * window) if window > 0 else float("nan")
    return wall, float(sum(r.get("wall_time_s", 0.0) for r in rows)), steady, rows


def store_cost(rows: list[dict], repeat: int = 5) -> float:
    """Median seconds per trial to insert ``rows`` into a fresh store, committing once a second (and at the end)."""
    times = []
    for _ in range(repeat):
        with tempfile.TemporaryDirectory() as d:
            store = ResultsStore.create(Path(d) / "s.sqlite")
            t0 = time.perf_counter()
            last = t0
            for i, r in enumerate(rows):
                store.add_trials([(f"k{i}", r, None)])
                if time.perf_counter() - last >= 1.0:
                    store.commit()
                    last = time.perf_counter()
            store.commit()
            times.append((time.perf_counter() - t0) / max(len(rows), 1))
            store.close()
    return float(np.median(times))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=96)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-dask", action="store_true")
    ap.add_argument("--lockstep", type=int, default=None, help="trials of one map per task (default: pbdyn batch's)")
    args = ap.parse_args(argv)
    opts = {} if args.lockstep is None else {"lockstep": args.lockstep}
    sc = load_scenario(ROOT / "scenarios" / "quickstart.toml")
    print(machine())
    print(f"workload: first {args.trials} trials of quickstart.toml, {args.repeat} runs each (median), lockstep "
          f"{args.lockstep if args.lockstep is not None else BatchOptions().lockstep}")
    one_run(sc, min(args.trials, 8), 1)            # warm the rollout cache
    results = {}
    for label, w in (("pool, 1 worker", 1), ("pool, 2 workers", 2)):
        results[label] = ([one_run(sc, args.trials, w, **opts) for _ in range(args.repeat)], w)
    if not args.no_dask:
        from dask.distributed import Client, LocalCluster

        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
                Client(cluster) as client:
            runs = [one_run(sc, args.trials, 2, scheduler=client, **opts) for _ in range(args.repeat)]
        results["dask LocalCluster, 2 workers"] = (runs, 2)
    print(f"{'configuration':32s}{'trials/s':>10s}{'wall s':>9s}{'overhead':>10s}{'steady':>9s}")
    rates = {}
    for label, (runs, w) in results.items():
        wall = float(np.median([r[0] for r in runs]))
        busy = float(np.median([r[1] for r in runs]))
        steady = float(np.median([r[2] for r in runs]))
        rates[label] = args.trials / wall
        overhead = 1.0 - busy / (w * wall)
        print(f"{label:32s}{rates[label]:10.2f}{wall:9.2f}{100 * overhead:9.1f}%{100 * steady:8.1f}%")
    print("overhead: share of worker capacity not spent flying over the whole run (incl. worker start-up);"
          " steady: the same once every worker has delivered a row")
    speedup = rates["pool, 2 workers"] / rates["pool, 1 worker"]
    print(f"scaling 1 -> 2 workers: {speedup:.2f}x (efficiency {100 * speedup / 2:.0f}%)")
    rows = results["pool, 1 worker"][0][0][3]
    per = store_cost(rows)
    trial = float(np.median([r.get("wall_time_s", 0.0) for r in rows]))
    print(f"store: {1e3 * per:.3f} ms per trial row ({100 * per / trial:.2f}% of a median trial of {trial:.3f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
