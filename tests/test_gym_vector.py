"""Gymnasium vector environments and the difficulty curriculum (pbdyn.gym.curriculum): the curriculum moves the ladder
level up and down on a scripted policy, counts every ended episode once under vector autoreset, and refuses bad
settings; SyncVectorEnv and AsyncVectorEnv step and autoreset pbdyn's environments."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest

from pbdyn.errors import ConfigError
from pbdyn.gym import AvoidEnv, Curriculum, CurriculumEnv


def _to_goal(obs: np.ndarray, dims: int = 2) -> np.ndarray:
    """A scripted policy: accelerate toward the goal, damp the velocity, no turning."""
    v, g = obs[:dims], obs[dims + 2:2 * dims + 2]
    a = 3.0 * g / max(float(np.linalg.norm(g)), 1e-6) - 2.0 * v
    return np.r_[np.clip(a, -1.0, 1.0), 0.0].astype(np.float32)


def test_the_curriculum_moves_up_above_the_band_down_below_it_and_stays_on_the_ladder():
    cur = Curriculum((1, 2, 3), band=(0.4, 0.7), window=4)
    for ok in (True, True, True, False):          # 0.75 > 0.7: up
        cur.report(ok)
    assert cur.level == 2 and not cur.recent
    for ok in (True, False, True, False):         # 0.5 inside the band: stay, the window slides
        cur.report(ok)
    assert cur.level == 2 and len(cur.recent) == 4
    for ok in (False, False, False):              # window (False, False, False, False) after sliding: down
        cur.report(ok)
    assert cur.level == 1
    for _ in range(4):
        cur.report(False)                         # the easiest level is the floor
    assert cur.level == 1
    for _ in range(12):
        cur.report(True)                          # up to the hardest, and no further
    assert cur.level == 3 and list(cur.recent) == [True] * 4
    assert cur.report(False, level=2) == 3 and list(cur.recent) == [True] * 4     # drawn before the move: not counted
    assert cur.history[-1] == (2, False)
    for kwargs, field in (({"band": (0.8, 0.5)}, "band"), ({"band": "x"}, "band"), ({"window": 0}, "window"),
                          ({"level": 7}, "level")):
        with pytest.raises(ConfigError) as err:
            Curriculum((1, 2, 3), **kwargs)
        assert err.value.field == field


def test_a_shared_curriculum_over_sync_vector_autoreset_moves_both_ways_and_counts_each_episode_once():
    cur = Curriculum(range(1, 10), band=(0.3, 0.6), window=4)
    envs = gymnasium.vector.SyncVectorEnv([lambda: CurriculumEnv(AvoidEnv(), cur) for _ in range(2)])
    try:
        obs, info = envs.reset(seed=0)
        assert list(info["curriculum_level"]) == [1, 1] and list(info["level"]) == [1, 1]
        ended = 0
        for _ in range(4000):
            obs, reward, term, trunc, info = envs.step(np.stack([_to_goal(o) for o in obs]))
            ended += int(np.sum(term | trunc))
            if len(cur.history) >= 32:
                break
    finally:
        envs.close()
    levels = [lv for lv, _ in cur.history]
    assert ended == len(cur.history)                   # every ended episode once; the autoresets not at all
    assert max(levels) >= 2 and any(b < a for a, b in zip(levels, levels[1:]))   # up, and down again
    for lv in set(levels):                             # each move followed the band at the level it left
        assert lv in cur.levels


def test_async_vector_envs_step_and_autoreset_in_their_own_processes():
    envs = gymnasium.vector.AsyncVectorEnv([lambda: AvoidEnv(), lambda: AvoidEnv()])
    try:
        obs, info = envs.reset(seed=[1, 2])
        assert obs.shape == (2, envs.single_observation_space.shape[0])
        assert info["map_id"][0] and info["map_id"][1]
        resets = 0
        for _ in range(300):
            obs, reward, term, trunc, info = envs.step(np.stack([_to_goal(o) for o in obs]))
            assert np.all(np.abs(obs) <= 1.0) and np.all(np.isfinite(reward))
            resets += int(np.sum(term | trunc))
        assert resets >= 2
    finally:
        envs.close()
