"""The reward of a step (docs/gym.md "Reward"): configurable, with every term reported in ``info``.

    r = progress (|p_k - goal| - |p_k+1 - goal|)                (m gained toward the goal)
      - time                                                    (per step)
      - smoothness |a_k+1 - a_k|^2 / a_max^2                     (a change of the commanded acceleration)
      + success            if the trial ended at the goal
      - collision          if it ended in a static or dynamic collision
      - invalid            if it ended as invalid_plan or deadlock (a gaze policy whose planner broke down)

The defaults (progress 1, time 0.01, smoothness 0.01, success 10, collision 10, invalid 10) favour reaching the goal
quickly and smoothly without touching anything; set any term to 0 to switch it off.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from pbdyn.errors import ConfigError
from pbdyn.outcome import Outcome


@dataclass(frozen=True)
class RewardConfig:
    """Weights of the reward terms (see the module docstring); every weight is a finite number >= 0."""

    progress: float = 1.0
    time: float = 0.01
    smoothness: float = 0.01
    success: float = 10.0
    collision: float = 10.0
    invalid: float = 10.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                    or value < 0:
                raise ConfigError(f"reward.{f.name}", "must be a finite number >= 0", value)

    @classmethod
    def of(cls, value) -> RewardConfig:
        """A RewardConfig from None (the defaults), a RewardConfig or a dict of weights (unknown keys refused)."""
        if value is None:
            return cls()
        if isinstance(value, cls):
            return value
        if not isinstance(value, dict):
            raise ConfigError("reward", "must be a RewardConfig or a table of weights", value)
        known = {f.name for f in fields(cls)}
        for key in value:
            if key not in known:
                raise ConfigError(f"reward.{key}", f"unknown reward term (known: {', '.join(sorted(known))})",
                                  value[key])
        return cls(**value)


def step_reward(cfg: RewardConfig, dist0: float, dist1: float, accel0, accel1, a_max: float,
                outcome: Outcome | None) -> tuple[float, dict]:
    """(reward, its terms) of one step: distances to the goal before and after (m), the executed accelerations
    before and after ([d] m/s^2), the MAV's a_max (m/s^2) and the outcome that ended the trial in this step (or
    None)."""
    da = accel1 - accel0
    terms = {"progress": cfg.progress * (dist0 - dist1), "time": -cfg.time,
             "smoothness": -cfg.smoothness * float(da @ da) / (a_max * a_max), "success": 0.0, "collision": 0.0,
             "invalid": 0.0}
    if outcome is Outcome.SUCCESS:
        terms["success"] = cfg.success
    elif outcome in (Outcome.STATIC_COLLISION, Outcome.DYNAMIC_COLLISION):
        terms["collision"] = -cfg.collision
    elif outcome in (Outcome.INVALID_PLAN, Outcome.DEADLOCK):
        terms["invalid"] = -cfg.invalid
    return float(sum(terms.values())), terms
