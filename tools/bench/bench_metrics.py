"""Benchmark of the difficulty metrics: median wall time per map and metric, beside the thesis' times.

Configurations: controlled_2d maps with 10 and with 30 obstacles, controlled_3d maps with 30 obstacles (radius
1 m, speed 4 m/s, replicates 0..maps-1). Each metric runs ``--repeat`` times on each map (after one warm-up run);
the table shows the median over all runs in ms, the thesis' table 4-5 time per map, the thesis' public program
measured on this machine (docs/thesis-program.md "Measured speed") and the speed-up of the 2D 30-obstacle median
over table 4-5. The last row times all eight 2D metrics of table 4-5 computed one after the other on one map.
Survivability-type metrics are timed with every available backend (``bullet`` when pbdyn.metrics.bullet_backend
imports). Rollouts are built before timing (they are cached and shared with the trials).

A second table times every metric on the example imported worlds (scenarios/worlds/) with the analytic, bullet
and mesh backends.

    .venv/bin/python tools/bench/bench_metrics.py [--maps 3] [--repeat 5] [--no-bullet] [--no-worlds]
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from bench_common import machine  # noqa: E402

from pbdyn.config import load_scenario  # noqa: E402
from pbdyn.metrics.catalog import BACKEND_METRICS, METRIC_TABLE, TABLE_ORDER  # noqa: E402
from pbdyn.metrics.registry import compute  # noqa: E402
from pbdyn.world.maps import enumerate_maps  # noqa: E402
from pbdyn.world.rollout import build_rollout  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = ROOT / "scenarios"

# the thesis' public program measured on this machine, s as "lo-hi" text (docs/thesis-program.md "Measured speed")
PROGRAM = {"density": "0.2-0.5", "traversability": "0.2-0.7", "dynamic_traversability": "0.4-0.9",
           "vo_feasibility": "8-22", "vo_feasibility_dense": "33-90", "survivability": "45-62",
           "global_survivability": "115-277"}
# metric -> (thesis table 4-5 time per map in s, public program time), every metric in the catalog's order
THESIS = {m.name: (m.thesis_time_s, PROGRAM.get(m.name, "-")) for m in METRIC_TABLE}
EIGHT = TABLE_ORDER
WORLDS = (("warehouse_2d", "warehouse_2d"), ("mixed_3d", "mixed_3d"))
CONFIGS = (("2D n=10", "controlled_2d.toml", 10), ("2D n=30", "controlled_2d.toml", 30),
           ("3D n=30", "controlled_3d.toml", 30))


def rollouts(scenario_file: str, count: int, n_maps: int) -> list:
    """The first ``n_maps`` replicates of setup (count, radius 1, speed 4) of a scenario."""
    sc = load_scenario(SCENARIOS / scenario_file)
    specs = [m for m in enumerate_maps(sc) if m.setup == {"count": count, "radius": 1.0, "speed": 4.0}]
    return [build_rollout(sc, m) for m in specs[:n_maps]]


def timed(fn, repeat: int) -> list[float]:
    """Wall times (s) of ``repeat`` calls after one warm-up call."""
    fn()
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def fmt_ms(values: list[float]) -> str:
    """Median of ``values`` (s) in ms, 9 characters wide."""
    if not values:
        return f"{'-':>9s}"
    ms = 1e3 * float(np.median(values))
    return f"{ms:9.3f}" if ms < 1 else f"{ms:9.2f}" if ms < 10 else f"{ms:9.1f}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--maps", type=int, default=3, help="maps per configuration (default 3)")
    ap.add_argument("--repeat", type=int, default=5, help="timed runs per metric and map (default 5, >= 5)")
    ap.add_argument("--no-bullet", action="store_true", help="time the analytic backend only")
    ap.add_argument("--no-worlds", action="store_true", help="skip the imported-world table")
    args = ap.parse_args(argv)
    if args.repeat < 5:
        ap.error("--repeat must be >= 5")
    backends = ["analytic"]
    if not args.no_bullet:
        try:
            importlib.import_module("pbdyn.metrics.bullet_backend")
            backends.append("bullet")
        except ImportError as exc:
            print(f"(bullet backend not available: {exc})", file=sys.stderr)

    print(machine())
    print(f"median wall time per map in ms ({args.maps} maps x {args.repeat} runs; radius 1 m, speed 4 m/s)")
    maps = {label: rollouts(f, n, args.maps) for label, f, n in CONFIGS}
    rows = []
    for name in THESIS:
        for backend in backends if name in BACKEND_METRICS else ["analytic"]:
            params = {"backend": backend} if name in BACKEND_METRICS else {}
            cells = []
            for label, _, _ in CONFIGS:
                runs = []
                for ro in maps[label]:
                    runs += timed(lambda: compute(ro, name, **params), args.repeat)
                cells.append(runs)
            rows.append((name + ("" if backend == "analytic" else " [bullet]"), cells, THESIS[name]))
    two_d = [label for label, _, _ in CONFIGS if label.startswith("2D")]
    for backend in backends:
        cells = []
        for label, _, _ in CONFIGS:
            runs = []
            if label in two_d:
                for ro in maps[label]:
                    runs += timed(lambda: [compute(ro, n, **({"backend": backend} if n in BACKEND_METRICS else {}))
                                           for n in EIGHT], args.repeat)
            cells.append(runs)
        thesis_total = sum(THESIS[n][0] for n in EIGHT)
        rows.append((f"all eight 2D metrics{'' if backend == 'analytic' else ' [bullet]'}", cells,
                     (thesis_total, "-")))

    head = f"{'metric':34s}" + "".join(f"{label:>10s}" for label, _, _ in CONFIGS)
    print(head + f"{'table 4-5':>11s}{'program':>10s}{'speed-up':>11s}")
    for name, cells, (thesis_s, program) in rows:
        line = f"{name:34s}" + "".join(" " + fmt_ms(c) for c in cells)
        ref = cells[1]
        speed = f"{thesis_s / float(np.median(ref)):10.0f}x" if thesis_s and ref else f"{'-':>11s}"
        line += f"{(f'{thesis_s:g} s' if thesis_s else '-'):>11s}{(program + ' s' if program != '-' else '-'):>10s}"
        print(line + speed)
    print("speed-up: table 4-5 time / median of the 2D n=30 column; 'program': the thesis' public program per map "
          "on this machine (docs/thesis-program.md)")
    if not args.no_worlds:
        world_table(args.repeat, backends)
    return 0


def world_table(repeat: int, backends: list[str]) -> None:
    """Median ms per metric on the example imported worlds (real shapes), every survivability backend."""
    from pbdyn.world.rollout import build_rollout as build

    worlds = {}
    for label, name in WORLDS:
        sc = load_scenario(SCENARIOS / "worlds" / f"{name}.toml")
        worlds[label] = build(sc, enumerate_maps(sc)[0])
    print(f"\nimported worlds: median wall time in ms ({repeat} runs after a warm-up)")
    print(f"{'metric':34s}" + "".join(f"{label:>14s}" for label, _ in WORLDS))
    for name in THESIS:
        for backend in (backends + ["mesh"]) if name in BACKEND_METRICS else ["analytic"]:
            params = {"backend": backend} if name in BACKEND_METRICS else {}
            cells = [timed(lambda ro=ro: compute(ro, name, **params), repeat) for ro in worlds.values()]
            tag = "" if name not in BACKEND_METRICS else f" [{backend}]"
            print(f"{name + tag:34s}" + "".join("     " + fmt_ms(c) for c in cells))
    print("analytic survivability on a world uses the moving bodies' bounding spheres; bullet and mesh their shapes")


if __name__ == "__main__":
    sys.exit(main())
