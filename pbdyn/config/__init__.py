"""Scenario files (TOML) validated into frozen dataclasses (docs/design.md "Defaults", docs/scenarios.md "Scenario
reference"), in three modules, each importing only the ones before it:

- model: the frozen dataclasses, their defaults (each written once, as the dataclass field's default) and the values
  derived from them (map seeds, canonical JSON, time spans);
- parser: a TOML file or a dict -> a validated Scenario; unknown keys and invalid values raise ConfigError naming the
  field and the value (the "Scenario reference" table is checked against the model's defaults,
  tests/test_config_defaults.py);
- compat: LATER_FIELDS, the fields added after stores and rollout caches were written, and the rule for adding one.

The resolved scenario (``Scenario.to_dict()``) is stored next to every result. The public names of the three are
imported from here (``from pbdyn.config import Scenario``).
"""

from pbdyn.config.compat import LATER_FIELDS, later_fields
from pbdyn.config.model import (BODY_MOTIONS, BUILTIN_STRUCTURES, COLLISION_CHECKS, PROFILE_DEFAULTS, PROFILES,
                                START_RULES, BodyConfig, DroneConfig, GridValue, MapEntry, ObstacleConfig,
                                PlannerEntry, Range, Scenario, SensorConfig, StaticObstacleConfig, StructureConfig,
                                TaskConfig, TrackingConfig, WorldConfig, canonical_json, default_candidates, map_seed,
                                rollout_span_s, stable_hash64, trial_span_s)
from pbdyn.config.parser import (WALL_GAP_MARGIN_M, check_v_max, load_scenario, parse_scenario, stopping_distance,
                                 warn_stopping, with_profile_defaults)
