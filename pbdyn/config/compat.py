"""Compatibility of keys across versions: the scenario fields added after results stores and rollout caches were
written, which stay out of trial keys (pbdyn.sim.spec) and rollout keys (pbdyn.world.rollout) at their defaults.

The rule. A field added to a section that enters trial keys or rollout keys would change every key: stores would
fly their trials again and caches compute their rollouts again. When its default keeps every existing scenario
flying as before, list it here: at its default it stays out of the keys (a store resumes across the version), and a
scenario that sets another value gets new keys. A field whose default changes what a trial or a map does is never
listed: its keys must change. Sections handled so far: obstacles and tracking; another needs its dataclass in
later_fields() and a call where its keys are built. (Scenario.to_dict likewise leaves out empty structure, map list
and pairs_flown fields.)
"""

from __future__ import annotations

from typing import Mapping

from pbdyn.config.model import ObstacleConfig, TrackingConfig

LATER_FIELDS: dict[str, tuple[str, ...]] = {"obstacles": ("layout", "wall_turn"), "tracking": ("track_radius",)}
"""Per section, the fields later_fields() leaves out of keys at their defaults (module doc: when to add one)."""


def later_fields(section: str, table: Mapping) -> dict:
    """The keys of ``table`` (a scenario section as plain data: "obstacles" or "tracking") that were added after
    stores and rollout caches were written (LATER_FIELDS) and hold their dataclass defaults: left out of trial keys
    and rollout keys, so that those of every scenario not using them stay as they were."""
    cls = {"obstacles": ObstacleConfig, "tracking": TrackingConfig}[section]
    return {k: v for k, v in table.items() if k in LATER_FIELDS[section] and v == getattr(cls, k)}
