"""A difficulty curriculum on the anchored scale (docs/gym.md "Curriculum"): the ladder level of the next episodes moves
so that the policy's recent success stays inside a band.

``Curriculum`` holds the state: the level (of the environment's ladder, pbdyn.gym.episodes; 1 = easiest) and the
outcomes of the last ``window`` episodes at that level. When the window is full, a success rate above the band
moves one level up, below it one level down (within the ladder), and the window starts again; inside the band the
oldest outcome gives way to the next.

``CurriculumEnv`` wraps one environment: each reset without a map choice of its own ("map", "level", "difficulty")
asks for a map of the curriculum's level, and each ended episode (terminated or truncated) reports whether it
succeeded. Several wrapped environments may share one Curriculum: with gymnasium's SyncVectorEnv they then move one
level together. Vector autoreset (Gymnasium 1.x, either mode) resets a sub-environment through its wrapper, so the
new episode gets the current level, and the reset itself is never counted as an episode. AsyncVectorEnv copies the
Curriculum into each worker process: each sub-environment then keeps its own.
"""

from __future__ import annotations

from collections import deque

import gymnasium

from pbdyn.errors import ConfigError
from pbdyn.gym.episodes import check_options


class Curriculum:
    """The level of the next episodes and the recent outcomes (see the module docstring). ``levels``: the ladder's
    levels, easiest first; ``band``: (low, high) success rates, 0 <= low < high <= 1; ``window``: episodes per
    decision (>= 1); ``level``: where to start (default the easiest)."""

    def __init__(self, levels, *, band=(0.5, 0.8), window: int = 20, level: int | None = None):
        levels = tuple(int(x) for x in levels)
        if not levels:
            raise ConfigError("levels", "must name at least one level", levels)
        try:
            low, high = (float(x) for x in band)
        except (TypeError, ValueError):
            raise ConfigError("band", "must be (low, high) success rates", band) from None
        if not 0.0 <= low < high <= 1.0:
            raise ConfigError("band", "must satisfy 0 <= low < high <= 1", band)
        if isinstance(window, bool) or not isinstance(window, int) or window < 1:
            raise ConfigError("window", "must be an integer >= 1", window)
        start = levels[0] if level is None else level
        if start not in levels:
            raise ConfigError("level", f"must be one of the ladder's levels {levels}", level)
        self.levels = levels
        self.band = (low, high)
        self.window = window
        self.level = start
        self.recent: deque = deque(maxlen=window)
        self.history: list[tuple[int, bool]] = []       # (level, success) of every episode reported

    def report(self, success: bool, level: int | None = None) -> int:
        """Count one ended episode drawn at ``level`` (default: the current one; an episode drawn at another level,
        before the level moved, is kept in the history but not counted); returns the level of the next episodes."""
        level = self.level if level is None else level
        self.history.append((level, bool(success)))
        if level != self.level:
            return self.level
        self.recent.append(bool(success))
        if len(self.recent) == self.window:
            rate = sum(self.recent) / self.window
            i = self.levels.index(self.level)
            if rate > self.band[1] and i + 1 < len(self.levels):
                self.level = self.levels[i + 1]
                self.recent.clear()
            elif rate < self.band[0] and i > 0:
                self.level = self.levels[i - 1]
                self.recent.clear()
        return self.level


class CurriculumEnv(gymnasium.Wrapper):
    """``env`` (an AvoidEnv or GazeEnv, or a wrapper of one) whose episodes follow ``curriculum`` (default: a new
    Curriculum over the environment's ladder with the given ``band`` and ``window``). ``info["curriculum_level"]``
    is the level the episode was drawn at."""

    def __init__(self, env: gymnasium.Env, curriculum: Curriculum | None = None, *, band=(0.5, 0.8),
                 window: int = 20):
        super().__init__(env)
        if curriculum is None:
            curriculum = Curriculum(env.unwrapped.episodes.levels(), band=band, window=window)
        self.curriculum = curriculum
        self._level: int | None = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        options = check_options(options)
        if not any(options.get(k) is not None for k in ("map", "level", "difficulty")):
            options["level"] = self.curriculum.level
        obs, info = self.env.reset(seed=seed, options=options)
        self._level = info.get("level")
        info["curriculum_level"] = self._level
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        info["curriculum_level"] = self._level
        if (terminated or truncated) and self._level is not None:
            self.curriculum.report(info["outcome"] == "success", self._level)
        return obs, reward, terminated, truncated, info
