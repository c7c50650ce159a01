"""The sensor models by name: ``sensor.model`` -> how a scan finds what the MAV sees (thesis 2-4-2).

SENSORS is the one table of models; pbdyn.perception.perceive.Perception builds the one its ``model`` names (config,
below perception, lists the same names in SensorConfig.MODELS; tests/test_templates.py keeps the two in step).
Adding a model: a class following SensorModel in pbdyn/perception/ (template: tools/templates/my_sensor.py), one
entry in SENSORS and its name in SensorConfig.MODELS.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from pbdyn.perception.marching import Marching
from pbdyn.perception.sensor import ray_directions


class SensorModel(Protocol):
    """Built as ``Model(perception)`` once the perception's parameters are set (world, grid, dims, fov_deg,
    resolution_deg, vfov_deg, vresolution_deg, range_m, rays, march_step, march_rule); ConfigError naming
    "sensor.model" for a world it cannot see. The Perception turns the fan to the yaw and adds the noise."""

    def fan(self) -> np.ndarray:
        """Unit ray directions [R, d] (world frame) of the sensor looking along +x (yaw 0)."""

    def scan(self, origin: np.ndarray, dirs_t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """One scan from ``origin`` [d] (m) along the turned fan ``dirs_t`` [d, R] (unit, world frame): the cells
        seen marked in perception.grid, and (ids: obstacles seen, int64 [m], ascending, unique; hits: per ray the
        PyBullet body id it ends on, int64 [R], -1 none; ranges: per ray its distance or range_m, [R] m). None: the
        Perception casts the fan in PyBullet ("raycast")."""


class Raycast:
    """"raycast": PyBullet rays along the fan of pbdyn.perception.sensor.ray_directions (perceive module doc)."""

    def __init__(self, perception):
        self.perception = perception

    def fan(self) -> np.ndarray:
        p = self.perception
        return ray_directions(0.0, p.fov_deg, p.resolution_deg, p.dims, p.vfov_deg, p.vresolution_deg)

    def scan(self, origin: np.ndarray, dirs_t: np.ndarray) -> None:
        return None


SENSORS: dict[str, type] = {"raycast": Raycast, "marching": Marching}
"""name -> model class, in the order error messages list them."""
