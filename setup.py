"""pbdyn's build: everything is declared in setup.cfg; this file adds one build step.

build_gym_hook writes ``pbdyn-gym.pth`` to the root of site-packages, so that an installed pbdyn's Gymnasium ids are
registered when Gymnasium is imported (pbdyn_gym_hook.py says how; docs/gym.md). A wheel carries the file in its root;
an editable install (``pip install -e``) writes it into the editable wheel as well, beside setuptools' own .pth.
"""

from __future__ import annotations

import os

from setuptools import Command, setup
from setuptools.command.build import build

PTH_NAME = "pbdyn-gym.pth"
# One line, run by site at every start-up: a hook module that cannot be found (an editable checkout moved away) is
# skipped instead of printing an error at every start-up.
PTH_LINE = ('import importlib.util; importlib.util.find_spec("pbdyn_gym_hook") and '
            '__import__("pbdyn_gym_hook").install()\n')


class build_gym_hook(Command):
    """Write pbdyn-gym.pth into the build's library root (the editable wheel's root in editable mode)."""

    description = "write the .pth line that registers pbdyn's Gymnasium ids at start-up"
    user_options: list = []

    def initialize_options(self) -> None:
        self.build_lib = None
        self.editable_mode = False

    def finalize_options(self) -> None:
        self.set_undefined_options("build_py", ("build_lib", "build_lib"))

    def _target(self) -> str:
        if self.editable_mode:          # the editable wheel ships only what is under install_lib (its unpacked root)
            return os.path.join(self.get_finalized_command("install").install_lib, PTH_NAME)
        return os.path.join(self.build_lib, PTH_NAME)

    def run(self) -> None:
        target = self._target()
        os.makedirs(os.path.dirname(target), exist_ok=True)
        with open(target, "w", encoding="utf-8") as fh:
            fh.write(PTH_LINE)

    def get_outputs(self) -> list[str]:
        return [] if self.editable_mode else [os.path.join(self.build_lib, PTH_NAME)]

    def get_output_mapping(self) -> dict[str, str]:
        return {}


class build_with_gym_hook(build):
    sub_commands = build.sub_commands + [("build_gym_hook", None)]


setup(cmdclass={"build": build_with_gym_hook, "build_gym_hook": build_gym_hook})
