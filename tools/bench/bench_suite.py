"""Benchmark of `pbdyn bench`: the wall time of one planner's bench on a frozen suite, and whether its flights
reproduce the shipped reference results (docs/benchmark.md).

Each repeat runs `pbdyn bench PLANNER --suite SUITE --out NEW --workers W --reproduce` in a fresh process with a
fresh bench folder; the rollout cache is warm after the first repeat (``--cold``: every repeat gets an empty cache
of its own, so the rollouts' computation is timed too). Prints the median wall time over the repeats and the
targets (pbdyn-2d-v1 <= 10 min, pbdyn-3d-v1 <= 20 min, pbdyn-2d-mini <= 1 min on 2 cores).

    .venv/bin/python tools/bench/bench_suite.py [--suite pbdyn-2d-mini] [--planner local_primitives]
        [--workers 2] [--repeat 3] [--cold] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_common import machine  # noqa: E402

TARGETS_S = {"pbdyn-2d-v1": 600.0, "pbdyn-3d-v1": 1200.0, "pbdyn-2d-mini": 60.0}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--suite", default="pbdyn-2d-mini")
    ap.add_argument("--planner", default="local_primitives")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--cold", action="store_true")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    root = Path(__file__).resolve().parents[2]
    times, reproduced = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.repeat):
            env = dict(os.environ)
            if args.cold:
                env["PBDYN_CACHE"] = str(Path(tmp) / f"cache-{i}")
            out = Path(tmp) / f"bench-{i}"
            t0 = time.perf_counter()
            res = subprocess.run([sys.executable, "-m", "pbdyn.cli", "bench", args.planner, "--suite", args.suite,
                                  "--out", str(out), "--workers", str(args.workers), "--reproduce", "--json"],
                                 capture_output=True, text=True, env=env, cwd=root)
            wall = time.perf_counter() - t0
            if res.returncode not in (0, 1):
                sys.stderr.write(res.stderr)
                return res.returncode
            card = json.loads(res.stdout)
            times.append(wall)
            reproduced.append(card["reproduction"]["identical"])
            print(f"repeat {i + 1}: {wall:.1f} s, {card['trials']['flown']} tasks, reproduced bit for bit: "
                  f"{card['reproduction']['identical']}; {card['summary']}")
    target = TARGETS_S.get(args.suite)
    med = statistics.median(times)
    print(f"{args.planner} on {args.suite}: median {med:.1f} s over {len(times)} repeats "
          f"({'cold' if args.cold else 'warm'} rollout cache, {args.workers} workers)"
          + (f"; target <= {target:.0f} s: {'met' if med <= target else 'missed'}" if target else "")
          + f"; reproduced {sum(reproduced)}/{len(reproduced)}")
    if args.json:
        args.json.write_text(json.dumps({"suite": args.suite, "planner": args.planner, "times_s": times,
                                         "median_s": med, "reproduced": reproduced, "machine": machine()},
                                        indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
