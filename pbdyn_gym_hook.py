"""The start-up hook that registers pbdyn's Gymnasium ids when Gymnasium is imported (docs/gym.md).

Gymnasium 1.x loads no plug-ins, so ``gymnasium.make("pbdyn/Avoid2D-v0")`` would need ``import pbdyn.gym`` first.
Installing pbdyn adds one line to site-packages (``pbdyn-gym.pth``, written by setup.py) that calls `install` when
Python starts. `install` puts a one-shot finder on ``sys.meta_path`` and imports nothing else: not pbdyn, so that
which pbdyn a process imports is still decided by its path when it imports it. When ``gymnasium.envs`` is imported,
the finder lets it load as usual and then registers the ids of pbdyn.gym_ids by name (entry-point strings): pbdyn's
environments are imported only when ``make`` builds one. ``PBDYN_GYM_AUTOREGISTER=0`` turns the hook off
(``import pbdyn.gym`` still registers the ids).

This module sits beside the pbdyn package, not in it, because the interpreter imports it at every start-up.
"""

from __future__ import annotations

import importlib.machinery
import os
import sys

SWITCH = "PBDYN_GYM_AUTOREGISTER"
"""Environment variable: "0" keeps the start-up hook from registering the ids."""


def _register() -> None:
    """Register pbdyn's ids with the loaded gymnasium.envs.registration (nothing if pbdyn cannot be imported)."""
    registration = sys.modules.get("gymnasium.envs.registration")
    if registration is None:
        return
    try:
        from pbdyn.gym_ids import register_missing
    except ImportError:                          # pbdyn removed, this line left behind: Gymnasium works without it
        return
    register_missing(registration)


class _RegisterAfter:
    """Loader wrapper: runs the real loader of ``gymnasium.envs``, then registers pbdyn's ids."""

    def __init__(self, inner):
        self._inner = inner

    def create_module(self, spec):
        return self._inner.create_module(spec)

    def exec_module(self, module) -> None:
        self._inner.exec_module(module)
        _register()

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
        _register()
        return
    if not any(isinstance(f, _GymnasiumFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _GymnasiumFinder())
