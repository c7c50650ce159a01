"""Train a policy on pbdyn/Avoid2D-v0 with stable-baselines3's PPO (CPU) for a few minutes through the difficulty
curriculum, then print its success per level of the anchored difficulty ladder, with pbdyn's outcomes
(docs/gym.md "A training example").

Its dependencies are the optional extra ``rl`` (stable-baselines3, which brings torch), not part of ``make test``:

    .venv/bin/pip install -e '.[rl]'
    .venv/bin/python tools/examples/train_ppo.py [--minutes 5] [--envs 8] [--episodes 10] [--out results/ppo.zip]

The policy observes the 8 nearest tracks and a 9 x 9 patch of the MAV's occupancy grid (``--tracks``, ``--patch``:
without the patch a policy cannot see walls and shelves, which the tracks do not hold). Each environment keeps the
PyBullet worlds of its last ``--keep-worlds`` maps (default 4, every map of one ladder level; about 29 MiB each,
docs/gym.md "Memory"), and each is closed at the end, which disconnects them. PPO's rewards are normalised
(VecNormalize, observations untouched: they are already in [-1, 1]). The curriculum (pbdyn.gym.Curriculum, shared
by the training environments) starts at the easiest level and moves one level up when the last ``--window`` episodes
succeeded more often than the band's top, down below its bottom. After training, every level is flown
``--episodes`` times by the deterministic policy from fixed seeds, and the ``pbdyn bench`` command that scores the
saved model is printed (``load`` below is its policy factory).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def load(path: str):
    """The policy factory for ``pbdyn bench`` (pbdyn.gym.policy_planner): the saved model's deterministic action."""
    from stable_baselines3 import PPO

    model = PPO.load(path, device="cpu")
    return lambda obs: model.predict(obs, deterministic=True)[0]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=5.0, help="training time (wall clock)")
    ap.add_argument("--envs", type=int, default=8, help="training environments")
    ap.add_argument("--episodes", type=int, default=10, help="evaluation episodes per level")
    ap.add_argument("--window", type=int, default=20, help="curriculum: episodes per decision")
    ap.add_argument("--tracks", type=int, default=8, help="K, the nearest tracks observed")
    ap.add_argument("--patch", type=int, default=9, help="P, cells per side of the occupancy patch observed (odd)")
    ap.add_argument("--keep-worlds", type=int, default=4,
                    help="PyBullet worlds each environment keeps (about 29 MiB each)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="results/ppo-avoid2d.zip", help="where the trained model is saved")
    args = ap.parse_args()
    try:
        from stable_baselines3 import PPO
        from stable_baselines3.common.callbacks import BaseCallback
        from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize
    except ImportError:
        sys.stderr.write("train_ppo: stable-baselines3 is not installed (pip install -e '.[rl]')\n")
        return 2
    sys.path.insert(0, str(ROOT))
    from pbdyn.gym import AvoidEnv, Curriculum, CurriculumEnv

    def make_env():
        return AvoidEnv(tracks=args.tracks, patch=args.patch, keep_worlds=args.keep_worlds)

    probe = make_env()
    levels = probe.episodes.levels()
    probe.close()
    curriculum = Curriculum(levels, band=(0.5, 0.8), window=args.window)
    venv = DummyVecEnv([lambda: CurriculumEnv(make_env(), curriculum) for _ in range(args.envs)])
    venv.seed(args.seed)
    venv = VecNormalize(venv, norm_obs=False, norm_reward=True)

    class Stop(BaseCallback):
        """Ends training after --minutes and prints the curriculum's level now and then."""

        def __init__(self):
            super().__init__()
            self.t0 = time.monotonic()
            self.last = 0.0

        def _on_step(self) -> bool:
            elapsed = time.monotonic() - self.t0
            if elapsed - self.last >= 30.0:
                self.last = elapsed
                recent = [ok for _, ok in curriculum.history[-200:]]
                rate = sum(recent) / len(recent) if recent else 0.0
                print(f"{elapsed / 60:4.1f} min: {self.num_timesteps} steps, {len(curriculum.history)} episodes, "
                      f"curriculum level {curriculum.level}, success of the last {len(recent)} episodes {rate:.2f}",
                      flush=True)
            return elapsed < 60.0 * args.minutes

    model = PPO("MlpPolicy", venv, seed=args.seed, n_steps=256, batch_size=256, learning_rate=3e-4, verbose=0,
                device="cpu")
    model.learn(total_timesteps=10 ** 9, callback=Stop())
    venv.close()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    model.save(args.out)
    reached = max(level for level, _ in curriculum.history) if curriculum.history else levels[0]
    print(f"trained {model.num_timesteps} steps, {len(curriculum.history)} episodes; highest curriculum level "
          f"{reached}; model saved to {args.out}")

    env = make_env()
    print(f"{'level':>5} {'difficulty':>10} {'success':>8}  outcomes ({args.episodes} episodes per level)")
    for level in levels:
        counts: Counter = Counter()
        difficulty = []
        for k in range(args.episodes):
            obs, info = env.reset(seed=100_000 + 1_000 * level + k, options={"level": level})
            difficulty.append(info["difficulty"])
            done = False
            while not done:
                action, _ = model.predict(obs, deterministic=True)
                obs, _, terminated, truncated, info = env.step(action)
                done = terminated or truncated
            counts[info["outcome"]] += 1
        shown = ", ".join(f"{name} {n}" for name, n in counts.most_common())
        print(f"{level:5d} {np.mean(difficulty):10.2f} {counts['success'] / args.episodes:8.2f}  {shown}")
    env.close()
    params = {"policy": "tools.examples.train_ppo:load", "policy_args": {"path": str(Path(args.out).resolve())},
              "tracks": args.tracks, "patch": args.patch}
    print("score it:  PYTHONPATH=. pbdyn bench pbdyn.gym.policy_planner:PolicyPlanner "
          f"--gaze pbdyn.gym.policy_planner:PolicyGaze --params '{json.dumps(params)}' --suite pbdyn-2d-v1 "
          "--out results/bench-ppo")
    return 0


if __name__ == "__main__":
    sys.exit(main())
