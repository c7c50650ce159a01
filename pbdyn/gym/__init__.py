"""Gymnasium environments of pbdyn (docs/gym.md): importing this package registers

    pbdyn/Avoid2D-v0, pbdyn/Avoid3D-v0   the policy flies the MAV (pbdyn.gym.env.AvoidEnv; quickstart, spheres_3d)
    pbdyn/Gaze2D-v0, pbdyn/Gaze3D-v0     local primitives fly, the policy turns the gaze (pbdyn.gym.env.GazeEnv)

so that ``gymnasium.make("pbdyn/Avoid2D-v0")`` works after ``import pbdyn.gym`` (or, without the import,
``gymnasium.make("pbdyn.gym:pbdyn/Avoid2D-v0")``). Keyword arguments of make() go to the environment's constructor.
``gymnasium.make_vec("pbdyn/Avoid2D-v0", num_envs=N, vectorization_mode="vector_entry_point")`` makes the native
vector environment (pbdyn.gym.vector.AvoidVectorEnv: N episodes in one trial batch).
"""

from __future__ import annotations

from gymnasium.envs.registration import register, registry

from pbdyn.gym.curriculum import Curriculum, CurriculumEnv
from pbdyn.gym.env import AvoidEnv, GazeEnv
from pbdyn.gym.policy_planner import PolicyGaze, PolicyPlanner, policy_pair
from pbdyn.gym.reward import RewardConfig
from pbdyn.gym.vector import AvoidVectorEnv

__all__ = ["AvoidEnv", "AvoidVectorEnv", "GazeEnv", "RewardConfig", "Curriculum", "CurriculumEnv", "PolicyPlanner",
           "PolicyGaze", "policy_pair", "ENV_IDS"]

ENV_IDS = {"pbdyn/Avoid2D-v0": ("pbdyn.gym.env:AvoidEnv", {"scenario": "quickstart", "dims": 2}),
           "pbdyn/Avoid3D-v0": ("pbdyn.gym.env:AvoidEnv", {"scenario": "spheres_3d", "dims": 3}),
           "pbdyn/Gaze2D-v0": ("pbdyn.gym.env:GazeEnv", {"scenario": "quickstart", "dims": 2}),
           "pbdyn/Gaze3D-v0": ("pbdyn.gym.env:GazeEnv", {"scenario": "spheres_3d", "dims": 3})}
"""id -> (entry point, default constructor arguments) of every registered environment."""

for _id, (_entry, _kwargs) in ENV_IDS.items():
    if _id not in registry:
        _vector = "pbdyn.gym.vector:AvoidVectorEnv" if "Avoid" in _id else None
        register(id=_id, entry_point=_entry, vector_entry_point=_vector, kwargs=dict(_kwargs),
                 disable_env_checker=False)
