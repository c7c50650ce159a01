"""Gymnasium environments: steps per CPU-second of one environment (Avoid and Gaze, 2D and 3D; random actions) and of
the native vector environment (N = 16, 64 episodes in one trial batch; steps of all sub-environments counted), and
the time of a reset on the same map (no new PyBullet world) and on a new map; medians over repeated runs, one
process, one core.

    .venv/bin/python tools/bench/bench_gym.py [--steps 2000] [--repeat 5]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))
sys.path.insert(0, str(HERE))


def steps_per_second(env_id: str, steps: int) -> float:
    """Steps per second of ``env_id`` over ``steps`` steps of random actions (resets included)."""
    import gymnasium

    import pbdyn.gym  # noqa: F401

    env = gymnasium.make(env_id)
    rng = np.random.default_rng(0)
    env.reset(seed=0)
    env.step(env.action_space.sample())          # compiled code loaded before timing
    t0 = time.process_time()
    seed = 1
    env.reset(seed=seed)
    for _ in range(steps):
        _, _, term, trunc, _ = env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
        if term or trunc:
            seed += 1
            env.reset(seed=seed)
    rate = steps / (time.process_time() - t0)
    env.close()
    return rate


def vector_steps_per_second(env_id: str, n: int, steps: int) -> float:
    """Sub-environment steps per CPU-second of the native vector env of ``env_id`` with ``n`` sub-environments over
    at least ``steps`` sub-environment steps of random actions."""
    import gymnasium

    import pbdyn.gym  # noqa: F401

    env = gymnasium.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point")
    rng = np.random.default_rng(0)
    env.reset(seed=0)
    env.step(env.action_space.sample())
    t0 = time.process_time()
    done = 0
    while done < steps:
        env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
        done += n
    rate = done / (time.process_time() - t0)
    env.close()
    return rate


def reset_times(n: int) -> tuple[float, float]:
    """(median reset time on the same map, median on a new map) in s, AvoidEnv on quickstart."""
    from pbdyn.gym import AvoidEnv

    env = AvoidEnv()
    env.reset(seed=0, options={"map": 0})
    same, new = [], []
    for k in range(n):
        t0 = time.perf_counter()
        env.reset(seed=k, options={"map": 0})
        same.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        env.reset(seed=k, options={"map": 1 + k % 8})
        new.append(time.perf_counter() - t0)
        env.reset(seed=k, options={"map": 0})
    env.close()
    return float(np.median(same)), float(np.median(new))


def main() -> int:
    from bench_common import machine

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    print(machine())
    single = {}
    ids = ("pbdyn/Avoid2D-v0", "pbdyn/Avoid3D-v0", "pbdyn/Gaze2D-v0", "pbdyn/Gaze3D-v0")
    for env_id in ids:
        rates = [steps_per_second(env_id, args.steps) for _ in range(args.repeat)]
        single[env_id] = float(np.median(rates))
        print(f"{env_id:<20} {single[env_id]:8.0f} steps per CPU-second (median of {args.repeat}, "
              f"{args.steps} steps each)")
    for env_id in ids:
        for n in (16, 64):
            rates = [vector_steps_per_second(env_id, n, 4 * args.steps) for _ in range(args.repeat)]
            rate = float(np.median(rates))
            print(f"{env_id:<20} native vector N = {n:<3} {rate:8.0f} steps per CPU-second, "
                  f"{rate / single[env_id]:.2f}x the single environment")
    same, new = reset_times(20 * args.repeat)
    print(f"reset, same map: {1000 * same:.1f} ms; another of quickstart's maps, flown before (its world kept): "
          f"{1000 * new:.1f} ms (medians of {20 * args.repeat})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
