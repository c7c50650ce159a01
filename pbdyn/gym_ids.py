"""The ids of pbdyn's Gymnasium environments (docs/gym.md), registered by ``import pbdyn.gym`` and, in an installed
pbdyn, by the start-up hook (pbdyn_gym_hook, beside this package) as soon as Gymnasium is imported.

This module imports nothing of pbdyn and nothing outside the standard library, so that the hook can read it without
loading any environment.
"""

from __future__ import annotations

ENV_IDS: dict[str, dict] = {
    "pbdyn/Avoid2D-v0": {"entry_point": "pbdyn.gym.env:AvoidEnv",
                         "vector_entry_point": "pbdyn.gym.vector:AvoidVectorEnv",
                         "kwargs": {"scenario": "quickstart", "dims": 2}},
    "pbdyn/Avoid3D-v0": {"entry_point": "pbdyn.gym.env:AvoidEnv",
                         "vector_entry_point": "pbdyn.gym.vector:AvoidVectorEnv",
                         "kwargs": {"scenario": "spheres_3d", "dims": 3}},
    "pbdyn/Gaze2D-v0": {"entry_point": "pbdyn.gym.env:GazeEnv",
                        "vector_entry_point": "pbdyn.gym.vector:GazeVectorEnv",
                        "kwargs": {"scenario": "quickstart", "dims": 2}},
    "pbdyn/Gaze3D-v0": {"entry_point": "pbdyn.gym.env:GazeEnv",
                        "vector_entry_point": "pbdyn.gym.vector:GazeVectorEnv",
                        "kwargs": {"scenario": "spheres_3d", "dims": 3}},
}
"""id -> register() arguments: entry point, native vector entry point, default constructor arguments."""


def register_missing(registration) -> None:
    """Register every id of ENV_IDS not yet in ``registration.registry`` (registration: gymnasium.envs.registration)."""
    for env_id, spec in ENV_IDS.items():
        if env_id not in registration.registry:
            registration.register(id=env_id, entry_point=spec["entry_point"],
                                  vector_entry_point=spec["vector_entry_point"], kwargs=dict(spec["kwargs"]),
                                  disable_env_checker=False)
