"""Gymnasium environments' memory: the resident set size (RSS) of one process holding 8 AvoidEnv(patch=9) (as the
training example, tools/examples/train_ppo.py) over 2,000 resets on ladder levels drawn at random (so every
environment visits the ladder's maps), and after close(). Prints the median and peak RSS over the resets, the RSS
before the first and after the last, and after closing all environments.

    .venv/bin/python tools/bench/bench_gym_memory.py [--envs 8] [--resets 2000] [--tree PATH]

``--tree`` measures another checkout (e.g. a git worktree of an older revision) with this script.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def rss_mib() -> float:
    """This process's resident set size now (MiB; Linux /proc)."""
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2 ** 20


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--envs", type=int, default=8, help="environments in the process")
    ap.add_argument("--resets", type=int, default=2000, help="resets in all (round robin over the environments)")
    ap.add_argument("--tree", default=str(HERE.parents[1]), help="the pbdyn checkout to measure")
    args = ap.parse_args()
    sys.path.insert(0, str(HERE))
    sys.path.insert(0, str(Path(args.tree).resolve()))
    from bench_common import machine

    import pbdyn
    from pbdyn.gym import AvoidEnv

    print(machine())
    print(f"pbdyn from {Path(pbdyn.__file__).parent}")
    rss0 = rss_mib()
    envs = [AvoidEnv(patch=9) for _ in range(args.envs)]
    levels = envs[0].episodes.levels()
    rng = np.random.default_rng(0)
    samples, t0 = [], time.perf_counter()
    for k in range(args.resets):
        i = k % args.envs
        envs[i].reset(seed=i if k < args.envs else None, options={"level": int(rng.choice(levels))})
        samples.append(rss_mib())
    took = time.perf_counter() - t0
    for env in envs:
        env.close()
    closed = rss_mib()
    print(f"{args.envs} AvoidEnv(patch=9), {args.resets} resets on random ladder levels in {took:.1f} s "
          f"({1e3 * took / args.resets:.1f} ms per reset)")
    print(f"RSS MiB: before {rss0:.0f}, over the resets median {np.median(samples):.0f} peak {max(samples):.0f}, "
          f"after the last reset {samples[-1]:.0f}, after close() {closed:.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
