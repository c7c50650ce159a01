"""Benchmark of `pbdyn generate --success` (pbdyn.generate_maps(success=...)): time per accepted map, candidates
flown per accepted map, and whether the kept maps fly within the tolerance again in a fresh process.

Each configuration (a generator family in 2D, pbdyn's default scenario) asks for ``--count`` maps within
``--tolerance`` of ``--success`` with an empty cache of its own (every flight is timed), ``--workers`` processes.
Then ``--refly`` of the kept maps are flown again by `pbdyn calibrate FILE --map i --store NEW --json` in a fresh
process with a new store, and their measured success is compared with the file's and with the tolerance.

    .venv/bin/python tools/bench/bench_generate_success.py [--success 0.5] [--tolerance 0.05] [--count 3]
        [--workers 2] [--only uniform,rvo] [--refly 1] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from bench_common import machine  # noqa: E402

FAMILIES = ("uniform", "clustered", "crossing", "mixed", "spread", "rvo", "walls")
TARGET_S_PER_MAP = 60.0
TARGET_WITHIN = 0.90


def run(family: str, args, work: Path) -> dict:
    """One configuration: generate in a fresh process with its own cache, then re-fly."""
    cache = work / f"cache-{family}"
    out = work / f"{family}.toml"
    env = {**os.environ, "PBDYN_CACHE": str(cache)}
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "pbdyn", "generate", "--success", str(args.success), "--tolerance",
                          str(args.tolerance), "--count", str(args.count), "--family", family, "--out", str(out),
                          "--workers", str(args.workers), "--json"], capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if res.returncode != 0:
        return {"family": family, "error": res.stderr.strip(), "wall_s": wall}
    doc = json.loads(res.stdout)
    maps = tomllib.loads(out.read_text())["obstacles"]["maps"]
    refly = []
    for i in range(min(args.refly, len(maps))):
        fresh = subprocess.run([sys.executable, "-m", "pbdyn", "calibrate", str(out), "--map", str(i), "--store",
                                str(work / f"refly-{family}-{i}.sqlite"), "--workers", str(args.workers), "--json"],
                               capture_output=True, text=True, env={**os.environ,
                                                                    "PBDYN_CACHE": str(work / f"c2-{family}")})
        got = json.loads(fresh.stdout)["maps"][0]["success"]
        refly.append({"map": i, "file": maps[i]["measured"]["reference_success"], "reflown": got,
                      "within": abs(got - args.success) <= args.tolerance})
    return {"family": family, "maps": doc["maps"], "flown": doc["flown"], "predicted": doc["candidates"],
            "wall_s": wall, "s_per_map": wall / max(doc["maps"], 1), "measured": doc["measured"],
            "predicted_range": doc["reachable"], "refly": refly}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--success", type=float, default=0.5)
    ap.add_argument("--tolerance", type=float, default=0.05)
    ap.add_argument("--count", type=int, default=3)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--refly", type=int, default=1)
    ap.add_argument("--only", help="comma-separated families (default: all but walls)")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    fams = args.only.split(",") if args.only else [f for f in FAMILIES if f != "walls"]
    rows = []
    print(machine())
    print(f"--success {args.success} --tolerance {args.tolerance} --count {args.count} --workers {args.workers}")
    print("| family | maps | flown | s per map | flown success | re-flown within |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as d:
        for fam in fams:
            r = run(fam, args, Path(d))
            rows.append(r)
            if "error" in r:
                print(f"| {fam} | error: {r['error']} | | {r['wall_s']:.0f} | | |", flush=True)
                continue
            ok = sum(x["within"] for x in r["refly"])
            print(f"| {fam} | {r['maps']} | {r['flown']} | {r['s_per_map']:.1f} | "
                  f"{min(r['measured']):.2f}-{max(r['measured']):.2f} | {ok}/{len(r['refly'])} |", flush=True)
    done = [r for r in rows if "error" not in r]
    if done:
        per = sorted(r["s_per_map"] for r in done)
        within = [x["within"] for r in done for x in r["refly"]]
        print(f"median s per map {per[len(per) // 2]:.1f} (target < {TARGET_S_PER_MAP:g}); re-flown within tolerance "
              f"{sum(within)}/{len(within)} (target >= {TARGET_WITHIN:.0%})")
    if args.json:
        args.json.write_text(json.dumps({"machine": machine(), "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
