"""What an obstacle motion model is: the MotionModel protocol every entry of pbdyn.motion.registry.MODELS follows,
and TableKey, one key of a model's own scenario table (docs/scenarios.md "Scenario reference")."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NamedTuple, Protocol

import numpy as np


class TableKey(NamedTuple):
    """One key of a model's table ``[obstacles.<table>]``: its name, whether it is an integer (else a float), and
    its lower bound lo (None: none; lo_open: the bound itself excluded). pbdyn.config checks the value against
    these and takes the default from the model's params_type."""

    name: str
    integer: bool
    lo: float | None = None
    lo_open: bool = False


class MotionModel(Protocol):
    """An obstacle motion model (thesis 2-3, fig. 2-3): how generated obstacles move from their spawned state.

    Obstacles never react to the MAV, so a model is a pure function of the obstacles' initial state and its own
    parameters (docs/design.md "The data flow (one direction)"): the same inputs give bit-identical outputs.

    Attributes:
        name: its ``obstacles.motion`` value, the same as its key in MODELS.
        table: the name of its own parameter table ``[obstacles.<table>]`` in a scenario, or None (it has none).
        params_type: the frozen dataclass the table's values are parsed into (its field defaults are the table's
            defaults), or None without a table.
        table_keys: the table's keys, in the order they are checked; () without a table.
    """

    name: str
    table: str | None
    params_type: type | None
    table_keys: tuple[TableKey, ...]

    def params(self, obstacles: Any) -> Any:
        """The model's parameters, read from a scenario's obstacles section (a pbdyn.config.ObstacleConfig): what
        rollout() is given as ``params``."""
        ...

    def check_params(self, params: Any, given: Mapping[str, Any], where: str) -> None:
        """Checks of a parsed table beyond each key's own bounds (e.g. pbdyn.limits), raising ConfigError naming
        the key under ``where`` ("obstacles.<table>"); ``given``: the keys the scenario's table gave. Called only
        for a model with a table."""
        ...

    def key_params(self, obstacles: Any) -> dict:
        """The entries this model adds to a rollout key's "obstacles" part (pbdyn.world.rollout.rollout_key) when
        it is the scenario's ``obstacles.motion``: every parameter its rollout depends on, as JSON-able data."""
        ...

    def rollout(self, p0: np.ndarray, v0: np.ndarray, radii: np.ndarray, size: np.ndarray, times: np.ndarray,
                dt: float, params: Any) -> tuple[np.ndarray, np.ndarray]:
        """Every obstacle's centre and velocity at every sample time.

        Frame: the world frame, SI units; the arena is the box [0, size_k] on every axis k (z up in 3D).

        Args:
            p0: initial centres [N, d] (m), each inside [r_i, size_k - r_i] on every axis.
            v0: initial velocities [N, d] (m/s): the spawned constant velocities (pbdyn.world.maps.spawn_obstacles).
            radii: obstacle radii [N] (m).
            size: arena extents [d] (m).
            times: sample times [T] (s), uniform from 0: times[k] = k dt.
            dt: the step between samples (s).
            params: the model's parameters, params(obstacles).
        Returns:
            positions [T, N, d] (m) and velocities [T, N, d] (m/s), world frame; sample 0 is the initial state;
            every centre stays in [r_i, size_k - r_i]. What a velocity sample means (the instantaneous one, or the
            one flown over a step) is stated by each model's module.
        """
        ...
