"""The obstacle motion models by name: ``obstacles.motion`` (and a structure's ``motion``) -> model (thesis 2-3).

MODELS is the one list of models. pbdyn.config reads it to validate ``obstacles.motion``, a structure's
``motion`` and each model's own table ``[obstacles.<table>]`` (keys and bounds from the model's table_keys,
defaults from its params_type, further checks by its check_params); pbdyn.world.rollout builds a map's rollout
through it (build_rollout) and puts each model's key_params into the map's rollout key (rollout_key).

Adding a model: write its module in pbdyn/motion/ (a class following pbdyn.motion.protocol.MotionModel) and add
one entry to MODELS below; nothing else in pbdyn names a model. (Except: a model with a table of its own needs a
field named after the table on pbdyn.config.ObstacleConfig, where a scenario keeps the parsed values.)

Why the models sit below config, in a unit of their own (tests/test_import_rules.py; docs/design.md "Package
sketch"): config validates a scenario's motion names and a model's table when it loads the scenario, and config may
not import pbdyn/world/. Keeping the names and tables in config and the dynamics in world would split every model
across two layers, with two lists of names to keep in step. A model needs nothing of a scenario beyond its own
parameters (numpy, pbdyn.errors and pbdyn.limits only), so each model lives whole in one module here, and config
and world both read this registry.
"""

from __future__ import annotations

from typing import Any

from pbdyn.motion.cvm import CVM
from pbdyn.motion.protocol import MotionModel
from pbdyn.motion.rvo import RVO

MODELS: dict[str, MotionModel] = {"cvm": CVM(), "rvo": RVO()}
"""name -> model, in the order error messages list them."""

KEYED_TABLES = ("rvo",)
"""Model tables that every generated map's rollout key names, as None unless the scenario's motion is that model:
keys were written so before this registry, and stay so that no cached rollout changes key. A model added later
names its parameters only in the keys of scenarios that use it."""


def other_tables(motion: str) -> set[str]:
    """The tables of the models other than ``motion`` (a scenario's settings for models it does not use: left out
    of what identifies its trials and maps)."""
    return {m.table for name, m in MODELS.items() if m.table and name != motion}


def key_params(obstacles: Any) -> dict:
    """The motion model's part of a rollout key's "obstacles" entry (pbdyn.world.rollout.rollout_key) for a
    scenario's obstacles section (pbdyn.config.ObstacleConfig): KEYED_TABLES as None, then the scenario's model's
    key_params."""
    out: dict = dict.fromkeys(KEYED_TABLES)
    out.update(MODELS[obstacles.motion].key_params(obstacles))
    return out
