"""Gymnasium environments of pbdyn (docs/gym.md). Their ids (pbdyn.gym_ids):

    pbdyn/Avoid2D-v0, pbdyn/Avoid3D-v0   the policy flies the MAV (pbdyn.gym.env.AvoidEnv; quickstart, spheres_3d)
    pbdyn/Gaze2D-v0, pbdyn/Gaze3D-v0     local primitives fly, the policy turns the gaze (pbdyn.gym.env.GazeEnv)

An installed pbdyn registers them when Gymnasium is imported, so ``gymnasium.make("pbdyn/Avoid2D-v0")`` works
with no pbdyn import (pbdyn_gym_hook, beside the package, explains how); importing this package registers them as
well, for interpreters started without site-packages' .pth files (``python -S``) or with PBDYN_GYM_AUTOREGISTER=0.
Keyword arguments of make() go to the environment's constructor.
``gymnasium.make_vec("pbdyn/Avoid2D-v0", num_envs=N, vectorization_mode="vector_entry_point")`` makes the native
vector environment (pbdyn.gym.vector.AvoidVectorEnv, GazeVectorEnv for the Gaze ids: N episodes in one trial batch).
"""

from __future__ import annotations

from gymnasium.envs import registration

from pbdyn.gym.curriculum import Curriculum, CurriculumEnv
from pbdyn.gym.env import AvoidEnv, GazeEnv
from pbdyn.gym.policy_planner import PolicyGaze, PolicyPlanner, policy_pair
from pbdyn.gym.reward import RewardConfig
from pbdyn.gym.vector import AvoidVectorEnv, GazeVectorEnv
from pbdyn.gym_ids import ENV_IDS, register_missing

__all__ = ["AvoidEnv", "AvoidVectorEnv", "GazeEnv", "GazeVectorEnv", "RewardConfig", "Curriculum", "CurriculumEnv",
           "PolicyPlanner", "PolicyGaze", "policy_pair", "ENV_IDS"]

register_missing(registration)
