"""What code identity by content costs a process (docs/design.md "Code identity"; docs/performance.md).

Each round starts a fresh interpreter that imports what a batch imports, then times every identity a batch of the
quickstart scenario asks for: the planner fingerprints of its three pairs (each with the trial core's identity),
its rollouts' code (cvm, rvo, imported) and its maps' metrics code. "cold": an empty cache folder (every file read
and hashed); "warm": the record of the build's files is on disk (files checked by size and modification time).

    .venv/bin/python tools/bench/bench_codeid.py [--rounds 7]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_common import machine  # noqa: E402

CHILD = """
import json, time
import pbdyn.experiments.runner, pbdyn.metrics.cached, pbdyn.world.rollout, pbdyn.planning.registry
from pbdyn.experiments.tasks import METRIC_SET
t0 = time.perf_counter()
from pbdyn.planning.registry import pair_fingerprint
for traj, gaze in (("local_primitives", "lookahead"), ("local_primitives", "fullrange"), ("straight_line", "lookahead")):
    pair_fingerprint(traj, gaze)
from pbdyn.world.rollout import rollout_code
for m in ("cvm", "rvo", None):
    rollout_code(m)
from pbdyn.metrics.cached import metrics_code
metrics_code(METRIC_SET, "analytic")
print(json.dumps({"ms": 1e3 * (time.perf_counter() - t0)}))
"""


def run(cache: str) -> float:
    res = subprocess.run([sys.executable, "-c", CHILD], env={"PBDYN_CACHE": cache, "PATH": "/usr/bin:/bin"},
                         capture_output=True, text=True, check=True)
    return json.loads(res.stdout)["ms"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=7)
    args = ap.parse_args(argv)
    cold, warm = [], []
    for _ in range(args.rounds):
        with tempfile.TemporaryDirectory() as cache:
            cold.append(run(cache))
            warm.append(run(cache))
    print(machine())
    print(f"identities of a quickstart batch, fresh process, n={args.rounds}: cold median {statistics.median(cold):.1f} ms "
          f"(min {min(cold):.1f}), warm median {statistics.median(warm):.1f} ms (min {min(warm):.1f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
