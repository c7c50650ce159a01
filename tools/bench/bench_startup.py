"""What a pbdyn process costs before and around its first trial: the median CPU seconds (user + system, the command
and the worker processes it waited for) and wall seconds over n runs of

    version  `pbdyn --version` (a pbdyn without the flag exits 2 after parsing: timed all the same, marked)
    run      `pbdyn run quickstart`
    batch    `pbdyn batch scenarios/quickstart.toml --out NEW.sqlite --limit 1 --workers 1` (one trial, one worker,
             a new store every run)

    .venv/bin/python tools/bench/bench_startup.py [--n 7] [--cases version run batch] [--checkout DIR ...] [--json]

Each --checkout (default: the one this script is in) is a pbdyn source tree run with this interpreter and its installed
dependencies (PYTHONPATH=DIR), through the `pbdyn` console script beside the interpreter when there is one (so that
batch workers start as they do for a user), else `python -m pbdyn`. To compare with the previous commit:
`git worktree add /tmp/pbdyn-old HEAD`, copy the native library (pbdyn/planning/primitives/native/_ruckig_batch.so*)
into it, and pass both checkouts. The runs are interleaved -- run i of every case of every checkout before run i + 1 -- so that a changing
machine load affects all of them alike. One untimed run of each case and checkout comes first: numba's compiled-code
cache and the rollout and metric caches are warm, as after an install's first use.

The commands run with Python's bytecode cache on (PYTHONDONTWRITEBYTECODE is dropped from their environment: a
checkout without __pycache__ would otherwise compile every module in every run). CPU time is
getrusage(RUSAGE_CHILDREN) around each run; it counts the batch's worker process, which the command
waits for. On a loaded machine wall time is noisy and CPU time much less so: the load average is printed with the
results.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_common import machine  # noqa: E402

HERE = Path(__file__).resolve().parents[2]
CASES = ("version", "run", "batch")


def command() -> list[str]:
    """How to run a pbdyn command with this interpreter (PYTHONPATH picks the checkout)."""
    script = Path(sys.executable).with_name("pbdyn")
    return [sys.executable, str(script)] if script.is_file() else [sys.executable, "-m", "pbdyn"]


def arguments(case: str, checkout: Path, scratch: Path, i: int) -> list[str]:
    if case == "version":
        return ["--version"]
    if case == "run":
        return ["run", "quickstart"]
    return ["batch", str(checkout / "scenarios" / "quickstart.toml"), "--out", str(scratch / f"b{i}.sqlite"),
            "--limit", "1", "--workers", "1"]


def timed(argv: list[str], env: dict, cwd: Path, may_fail: bool = False) -> tuple[float, float, int]:
    """(CPU seconds, wall seconds, exit status) of one run of ``argv``; it must succeed unless ``may_fail``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run(argv, env=env, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0 and not may_fail:
        raise SystemExit(f"{' '.join(argv)} failed ({done.returncode}): {done.stderr.strip()[-2000:]}")
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), wall, done.returncode


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=7, help="timed runs of each case (default 7)")
    ap.add_argument("--cases", nargs="+", choices=CASES, default=list(CASES))
    ap.add_argument("--checkout", nargs="+", type=Path, default=[HERE],
                    help="pbdyn source trees to compare (default: this one)")
    ap.add_argument("--json", action="store_true", help="print the results as one JSON document")
    args = ap.parse_args()
    checkouts = [c.resolve() for c in args.checkout]
    for c in checkouts:
        if not (c / "pbdyn" / "__init__.py").is_file():
            raise SystemExit(f"--checkout {c}: not a pbdyn source tree (no pbdyn/__init__.py)")
    drop = ("PBDYN_NATIVE_REPORTED", "PBDYN_POOL_REPORT", "PYTHONDONTWRITEBYTECODE")   # bytecode cached, as installed
    base = {k: v for k, v in os.environ.items() if k not in drop}
    samples: dict[tuple[str, str], list[tuple[float, float]]] = {}
    load = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory(prefix="pbdyn-bench-startup-") as tmp:
        scratch = Path(tmp)
        envs = {c: {**base, "PYTHONPATH": os.pathsep.join([str(c), base.get("PYTHONPATH", "")]).rstrip(os.pathsep)}
                for c in checkouts}
        for c in checkouts:                                  # warm the caches, untimed
            for case in args.cases:
                timed(command() + arguments(case, c, scratch, -1 - checkouts.index(c)), envs[c], scratch,
                      may_fail=case == "version")
        for i in range(args.n):
            for c in checkouts:
                for case in args.cases:
                    argv = command() + arguments(case, c, scratch, i * len(checkouts) + checkouts.index(c))
                    samples.setdefault((str(c), case), []).append(timed(argv, envs[c], scratch,
                                                                        may_fail=case == "version"))
        load.append(os.getloadavg()[0])
    rows = [{"checkout": c, "case": case, "n": len(s), "cpu_s_median": statistics.median(x for x, _, _ in s),
             "wall_s_median": statistics.median(w for _, w, _ in s), "cpu_s_min": min(x for x, _, _ in s),
             "wall_s_min": min(w for _, w, _ in s), "exit_status": sorted({rc for _, _, rc in s})}
            for (c, case), s in samples.items()]
    if args.json:
        print(json.dumps({"machine": machine(), "load_average_1min": load, "results": rows}, indent=1))
        return
    print(machine())
    print(f"load average (1 min) at start and end: {load[0]:.2f}, {load[1]:.2f} on {os.cpu_count()} CPUs")
    print(f"{'checkout':<28} {'case':<8} {'n':>3} {'CPU-s median':>13} {'wall-s median':>14} {'CPU-s min':>10} "
          f"{'wall-s min':>11}")
    for r in rows:
        print(f"{r['checkout'][-28:]:<28} {r['case']:<8} {r['n']:>3} {r['cpu_s_median']:>13.3f} "
              f"{r['wall_s_median']:>14.3f} {r['cpu_s_min']:>10.3f} {r['wall_s_min']:>11.3f}"
              + ("" if r["exit_status"] == [0] else f"  (exit status {r['exit_status']})"))


if __name__ == "__main__":
    main()
