"""The ids of pbdyn's Gymnasium environments, and the start-up hook that registers them (docs/gym.md).

Gymnasium 1.x loads no plug-ins, so ``gymnasium.make("pbdyn/Avoid2D-v0")`` would need ``import pbdyn.gym`` first.
Installing pbdyn adds one line to site-packages (``pbdyn-gym.pth``, written by setup.py) that calls `install` when
Python starts. `install` puts a one-shot finder on ``sys.meta_path``; when ``gymnasium.envs`` is imported, the
finder lets it load as usual and then registers the ids below, by name only: no pbdyn environment, and nothing
heavy, is imported until ``make`` builds one. A process that never imports Gymnasium pays one small module import.
``PBDYN_GYM_AUTOREGISTER=0`` turns the hook off (``import pbdyn.gym`` still registers the ids).

This module imports nothing of pbdyn and nothing outside the standard library.
"""

from __future__ import annotations

import importlib.machinery
import os
import sys

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

SWITCH = "PBDYN_GYM_AUTOREGISTER"
"""Environment variable: "0" keeps the start-up hook from registering the ids."""


def register_missing(registration) -> None:
    """Register every id of ENV_IDS not yet in ``registration.registry`` (registration: gymnasium.envs.registration)."""
    for env_id, spec in ENV_IDS.items():
        if env_id not in registration.registry:
            registration.register(id=env_id, entry_point=spec["entry_point"],
                                  vector_entry_point=spec["vector_entry_point"], kwargs=dict(spec["kwargs"]),
                                  disable_env_checker=False)


class _RegisterAfter:
    """Loader wrapper: runs the real loader of ``gymnasium.envs``, then registers pbdyn's ids."""

    def __init__(self, inner):
        self._inner = inner

    def create_module(self, spec):
        return self._inner.create_module(spec)

    def exec_module(self, module) -> None:
        self._inner.exec_module(module)
        registration = sys.modules.get("gymnasium.envs.registration")
        if registration is not None:
            register_missing(registration)

    def __getattr__(self, name):                 # resource readers, is_package, get_code ... of the real loader
        return getattr(self._inner, name)


class _GymnasiumFinder:
    """One-shot meta path finder for ``gymnasium.envs``: finds it as the other finders would, wraps its loader."""

    target = "gymnasium.envs"

    def find_spec(self, fullname, path=None, target=None):
        if fullname != self.target:
            return None
        if self in sys.meta_path:
            sys.meta_path.remove(self)
        for finder in sys.meta_path:
            find = getattr(finder, "find_spec", None)
            spec = find(fullname, path, target) if find is not None else None
            if spec is not None:
                break
        else:
            spec = importlib.machinery.PathFinder.find_spec(fullname, path)
        if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
            return spec
        spec.loader = _RegisterAfter(spec.loader)
        return spec


def install() -> None:
    """Arrange for pbdyn's ids to be registered when Gymnasium is imported (called by pbdyn-gym.pth at start-up).

    Registers at once if Gymnasium is already imported; does nothing when PBDYN_GYM_AUTOREGISTER is "0" or the hook
    is already in place."""
    if os.environ.get(SWITCH, "1").strip() == "0":
        return
    if "gymnasium.envs" in sys.modules:
        registration = sys.modules.get("gymnasium.envs.registration")
        if registration is not None:
            register_missing(registration)
        return
    if not any(isinstance(f, _GymnasiumFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _GymnasiumFinder())
