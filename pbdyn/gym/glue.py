"""What an episode's step gives a policy, built in one place for every environment (docs/gym.md): the observation
(pbdyn.gym.observation), the reward (pbdyn.gym.reward), the ends and the info. AvoidEnv and GazeEnv (a trial batch
of one) and their native vector environments (N trials in one batch) all use ``Glue``, so a sub-environment's step
is built exactly as a single environment's.

Info keys (every step, both kinds): "outcome" (None while the episode runs), "reason" ("" while it runs), "scenario",
"map_index", "map_id", "map_key", "difficulty" and "level" (the map's on the anchored scale; None off the ladder),
"difficulty_clamped", "start" and "goal" (m), "v_max" (m/s), "t" (s, trial time), "speed" (m/s) and
"acceleration" (m/s^2) of the MAV; after a step also "reward_terms" (pbdyn.gym.reward.step_reward).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pbdyn.gym.observation import check_observed, observation_size, observe
from pbdyn.gym.reward import RewardConfig, step_reward
from pbdyn.outcome import Outcome
from pbdyn.sim.state import vector_norm


@dataclass(frozen=True)
class Glue:
    """An environment's observation settings (K tracks, B rays, P patch cells per side) and reward weights."""

    tracks: int
    rays: int
    patch: int
    reward: RewardConfig

    @classmethod
    def of(cls, dims: int, tracks, rays, patch, reward) -> Glue:
        """The settings checked (ConfigError naming a bad one)."""
        return cls(*check_observed(tracks, rays, patch, dims), RewardConfig.of(reward))

    def size(self, dims: int) -> int:
        """The observation's length (pbdyn.gym.observation.observation_size)."""
        return observation_size(dims, self.tracks, self.rays, self.patch)

    def first(self, episode, state) -> tuple[np.ndarray, dict, float]:
        """(observation, info, distance to the goal m) of trial ``state`` as its episode begins."""
        return observe(state, self.tracks, self.rays, self.patch), info(episode, state), goal_distance(state)

    def after(self, episode, state, dist0: float, accel0: np.ndarray) -> tuple:
        """(observation, reward, terminated, truncated, info, distance to the goal m) of trial ``state`` after a
        step that began ``dist0`` m from the goal with the executed acceleration ``accel0`` (m/s^2)."""
        dist = goal_distance(state)
        outcome = state.outcome
        reward, terms = step_reward(self.reward, dist0, dist, accel0, state.acceleration, state.limits.a_max,
                                    outcome)
        terminated = outcome is not None and outcome is not Outcome.FREEZING
        truncated = outcome is Outcome.FREEZING
        return (observe(state, self.tracks, self.rays, self.patch), reward, terminated, truncated,
                info(episode, state, terms), dist)


def goal_distance(state) -> float:
    """|position - goal| of trial ``state`` (m)."""
    return vector_norm(state.position - state.goal)


def info(episode, state, terms: dict | None = None) -> dict:
    """The info of trial ``state`` of ``episode`` (pbdyn.gym.episodes.Episode: its map on the ladder) with the
    reward's ``terms`` after a step (module docstring)."""
    spec = state.spec
    ms = spec.map_spec
    out = {"outcome": None if state.outcome is None else state.outcome.value,
           "reason": state.reason if state.outcome is not None else "",
           "scenario": spec.scenario.name, "map_index": episode.map_index, "map_id": ms.map_id, "map_key": ms.key,
           "difficulty": episode.difficulty, "level": episode.level, "difficulty_clamped": episode.difficulty_clamped,
           "start": tuple(spec.start), "goal": tuple(spec.goal), "v_max": float(spec.v_max), "t": state.t,
           "speed": math.sqrt(float(state.velocity @ state.velocity)),
           "acceleration": math.sqrt(float(state.acceleration @ state.acceleration))}
    if terms is not None:
        out["reward_terms"] = terms
    return out


def stack_infos(infos: list, n: int) -> dict:
    """The vector info of ``n`` sub-environments' ``infos`` (a dict or None each), exactly as Gymnasium's
    VectorEnv._add_info builds it one sub-environment at a time -- the same keys in the same order, each with its
    "_key" mask, an array typed by the first value (a Python or numpy number: that type; an array: its shape and
    dtype; anything else: objects), nested dicts stacked alike -- in one pass per key (tests/test_gym_vector.py
    compares the two)."""
    cols: dict = {}
    for i, info in enumerate(infos):
        for key, value in (info or {}).items():
            col = cols.get(key)
            if col is None:
                cols[key] = col = ([], [])
            col[0].append(i)
            col[1].append(value)
    out: dict = {}
    for key, (idx, values) in cols.items():
        first = values[0]
        if isinstance(first, dict):
            rows = [None] * n
            for i, v in zip(idx, values):
                rows[i] = v
            array = stack_infos(rows, n)
        elif type(first) in (int, float, bool) or isinstance(first, np.number) or isinstance(first, np.ndarray):
            array = np.zeros((n, *np.shape(first)), dtype=type(first) if not isinstance(first, np.ndarray)
                             else first.dtype)
            array[idx] = values
        else:
            array = np.full(n, None, dtype=object)
            array[idx] = np.fromiter(values, dtype=object, count=len(values))
        mask = np.zeros(n, dtype=np.bool_)
        mask[idx] = True
        out[key], out[f"_{key}"] = array, mask
    return out
