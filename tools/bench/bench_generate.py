"""Benchmark of `pbdyn generate --metric survivability` (pbdyn.generate_maps): time per accepted map, candidates
per accepted map, and whether the written maps measure within the tolerance again in a fresh process.

Configurations: every generator family in 2D, and uniform and mixed in 3D; pbdyn's default scenario. A pilot (the
8 corners of the (n, r, v) box, one map each, measured in this process and not timed) gives each configuration's
range; the target is its middle. Then ``--repeat`` requests of ``--count`` maps within ``--tolerance`` s (seeds
0, 1, ...; ``--workers`` processes, pool start-up included) are timed from their own wall time. The maps of the
first request are measured again with `pbdyn metrics FILE --map i --metric survivability --json`, one fresh process
each (an empty rollout cache), two at a time.

    .venv/bin/python tools/bench/bench_generate.py [--count 20] [--tolerance 0.2] [--repeat 3] [--workers 2]
                                                   [--only uniform:2,rvo:2] [--json FILE]
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from bench_common import machine  # noqa: E402

import pbdyn  # noqa: E402
from pbdyn.config import parse_scenario  # noqa: E402
from pbdyn.experiments.generate import BOX, FAMILIES, MetricTarget, measure_metric, scenario_document  # noqa: E402

METRIC = "survivability"
CONFIGS = tuple((f, 2) for f in FAMILIES) + (("uniform", 3), ("mixed", 3))
TARGET_S_PER_MAP = 2.0
TARGET_WITHIN = 0.95


def pilot_range(family: str, dims: int) -> tuple[float, float]:
    """(min, max) survivability over the 8 corners of the box, one map each."""
    req = MetricTarget(METRIC, 0.0, 1.0, 1, family, dims)
    sc = parse_scenario(scenario_document(req))
    corners = [(i, {"count": n, "radius": r, "speed": v, "structure": family}, i)
               for i, (n, r, v) in enumerate((n, r, v) for n in BOX["count"] for r in BOX["radius"]
                                             for v in BOX["speed"])]
    values = [value for _, value, _ in measure_metric(sc, METRIC, corners)]
    return min(values), max(values)


def remeasure(path: Path, index: int, cache: str) -> float:
    """The map's survivability as `pbdyn metrics` prints it, in a fresh process with the rollout cache ``cache``."""
    env = {**os.environ, "PBDYN_CACHE": cache}
    res = subprocess.run([sys.executable, "-m", "pbdyn", "metrics", str(path), "--map", str(index), "--metric", METRIC,
                          "--json"], capture_output=True, text=True, env=env, timeout=600)
    if res.returncode != 0:
        raise RuntimeError(f"pbdyn metrics {path} --map {index}: {res.stderr.strip()}")
    return float(json.loads(res.stdout)["metrics"][METRIC]["value"])


def bench_config(family: str, dims: int, args, folder: Path) -> dict:
    lo, hi = pilot_range(family, dims)
    target = round(0.5 * (lo + hi), 2)
    runs = []
    for seed in range(args.repeat):
        out = folder / f"{family}_{dims}d_seed{seed}.toml"
        res = pbdyn.generate_maps(out, metric=METRIC, target=target, tolerance=args.tolerance, count=args.count,
                                  family=family, dims=dims, seed=seed, workers=args.workers)
        runs.append({"seed": seed, "file": out, "wall_s": res.wall_time_s, "candidates": res.candidates,
                     "maps": len(res.maps), "values": [c.value for c in res.maps]})
    first = runs[0]
    with tempfile.TemporaryDirectory(prefix="pbdyn-bench-cache-") as cache, \
            cf.ThreadPoolExecutor(2) as pool:
        again = list(pool.map(lambda i: remeasure(first["file"], i, cache), range(first["maps"])))
    again = np.array(again)
    per_map = [r["wall_s"] / r["maps"] for r in runs]
    cands = [r["candidates"] / r["maps"] for r in runs]
    return {"family": family, "dims": dims, "pilot": [lo, hi], "target": target,
            "s_per_map": float(np.median(per_map)), "s_per_map_range": [min(per_map), max(per_map)],
            "candidates_per_map": float(np.median(cands)), "candidates_range": [min(cands), max(cands)],
            "remeasured": int(again.size),
            "within": int(np.sum(np.abs(again - target) <= args.tolerance + 1e-9)),
            "identical": int(np.sum(again == np.array(first["values"])))}


def table(rows: list[dict], args) -> str:
    head = (f"{'family':<10}{'dims':>5}{'pilot range [s]':>18}{'target':>8}{'s/map':>8}{'(min-max)':>13}"
            f"{'cand/map':>10}{'(min-max)':>13}{'within':>10}{'identical':>11}")
    lines = [head, "-" * len(head)]
    for r in rows:
        (plo, phi), (slo, shi), (clo, chi) = r["pilot"], r["s_per_map_range"], r["candidates_range"]
        lines.append(f"{r['family']:<10}{r['dims']:>4}D{plo:>9.2f}-{phi:<8.2f}{r['target']:>8.2f}"
                     f"{r['s_per_map']:>8.2f}{slo:>7.2f}-{shi:<5.2f}{r['candidates_per_map']:>10.1f}{clo:>7.1f}-"
                     f"{chi:<5.1f}{r['within']:>6}/{r['remeasured']:<3}{r['identical']:>7}/{r['remeasured']}")
    worst = max(r["s_per_map"] for r in rows)
    share = sum(r["within"] for r in rows) / max(sum(r["remeasured"] for r in rows), 1)
    lines += ["", f"{args.count} maps per request, tolerance {args.tolerance:g} s, {args.repeat} requests per row "
              f"(median, min-max), workers {args.workers}; re-measured: the first request's maps in fresh processes.",
              f"slowest median {worst:.2f} s per map (target < {TARGET_S_PER_MAP:g}): "
              f"{'met' if worst < TARGET_S_PER_MAP else 'NOT met'}; within tolerance when re-measured "
              f"{100 * share:.1f}% (target >= {100 * TARGET_WITHIN:g}%): "
              f"{'met' if share >= TARGET_WITHIN else 'NOT met'}"]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--count", type=int, default=20)
    ap.add_argument("--tolerance", type=float, default=0.2)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--only", default="", help="FAMILY:DIMS,... (default: every configuration)")
    ap.add_argument("--json", default="", help="also write the rows to this JSON file")
    args = ap.parse_args(argv)
    configs = CONFIGS
    if args.only:
        configs = tuple((f, int(d)) for f, d in (item.split(":") for item in args.only.split(",")))
    print(machine(), flush=True)
    rows = []
    with tempfile.TemporaryDirectory(prefix="pbdyn-bench-generate-") as folder:
        for family, dims in configs:
            rows.append(bench_config(family, dims, args, Path(folder)))
            r = rows[-1]
            print(f"  {family} {dims}D: {r['s_per_map']:.2f} s/map, {r['candidates_per_map']:.1f} candidates/map, "
                  f"{r['within']}/{r['remeasured']} within", file=sys.stderr, flush=True)
    print(table(rows, args))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
