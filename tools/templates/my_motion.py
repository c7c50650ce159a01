"""A template obstacle motion model for pbdyn: copy this file, rename the class, and change ``rollout``.

A motion model moves a map's generated obstacles from their spawned state (thesis 2-3). Obstacles never react to the
MAV, so a model is a pure function of the obstacles' initial state and its own parameters: the same inputs give
bit-identical outputs (docs/design.md "The data flow (one direction)"). It follows
``pbdyn.motion.protocol.MotionModel``:

Attributes:
    name: its ``obstacles.motion`` value. table: the name of its own scenario table ``[obstacles.<table>]``, or None;
    params_type: the frozen dataclass that table is parsed into (None without one); table_keys: the table's keys
    (pbdyn.motion.protocol.TableKey), () without one.
Methods:
    params(obstacles) -> what rollout() gets as ``params``, read from the scenario's obstacles section
        (pbdyn.config.ObstacleConfig).
    check_params(params, given, where) -> None: checks of a parsed table beyond each key's bounds (ConfigError
        naming the key under ``where``); called only for a model with a table.
    key_params(obstacles) -> dict: every parameter its rollout depends on, as JSON-able data (part of each map's
        rollout key, so a cached rollout is never served for other parameters).
    rollout(p0, v0, radii, size, times, dt, params) -> (positions [T, N, d] (m), velocities [T, N, d] (m/s)), world
        frame: p0 [N, d] (m) the spawned centres, each inside [r_i, size_k - r_i] on every axis; v0 [N, d] (m/s) the
        spawned constant velocities; radii [N] (m); size [d] (m; the arena is the box [0, size_k], z up in 3D);
        times [T] (s, times[k] = k dt); dt (s). Sample 0 is the spawned state; every centre stays in
        [r_i, size_k - r_i].

StopAndGo is deliberately simple but real: each obstacle flies like the constant-velocity model (pbdyn.motion.cvm:
specular reflection at the walls), but only for GO_S seconds out of every GO_S + STOP_S; in between it stands. The
obstacles' phases are staggered, so they do not all stop together. Velocities are the instantaneous ones (0 while
standing).

Models are built in (docs/architecture.md "Where each extension goes"): put the module in pbdyn/motion/, add one
entry to MODELS in pbdyn/motion/registry.py and its module to pbdyn.codeid.MOTION_MODELS; a scenario then names it
as ``[obstacles] motion = "stop_and_go"`` (a model with a table of its own also needs its field on
pbdyn.config.ObstacleConfig).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from pbdyn.motion.cvm import cvm_fold
from pbdyn.motion.protocol import TableKey


class StopAndGo:
    """Constant velocity with wall reflections for GO_S s, then a stop of STOP_S s, staggered per obstacle."""

    name = "stop_and_go"
    table: str | None = None
    params_type: type | None = None
    table_keys: tuple[TableKey, ...] = ()

    GO_S = 3.0
    """Seconds each obstacle flies before it stops (s)."""
    STOP_S = 1.5
    """Seconds it stands (s)."""

    def params(self, obstacles: Any) -> None:
        """None: the model has no parameters of its own."""
        return None

    def check_params(self, params: Any, given: Mapping[str, Any], where: str) -> None:
        """Nothing to check (no table)."""

    def key_params(self, obstacles: Any) -> dict:
        """The timing (s), which every rollout of this model depends on."""
        return {"stop_and_go": {"go_s": self.GO_S, "stop_s": self.STOP_S}}

    def rollout(self, p0: np.ndarray, v0: np.ndarray, radii: np.ndarray, size: np.ndarray, times: np.ndarray,
                dt: float, params: None) -> tuple[np.ndarray, np.ndarray]:
        """Positions [T, N, d] (m) and velocities [T, N, d] (m/s): the constant-velocity motion of cvm_fold, with
        each obstacle's own clock stopped while it stands."""
        period = self.GO_S + self.STOP_S
        n = np.asarray(radii).shape[0]
        phase = (np.arange(n) * 0.618 * period) % period                      # [N] (s): staggered starts
        t = np.asarray(times, dtype=float)[:, None] + phase[None, :]           # [T, N] (s) on each obstacle's clock
        cycles, within = np.divmod(t, period)
        flown = cycles * self.GO_S + np.minimum(within, self.GO_S)            # s spent flying since its clock's 0
        flown0 = flown - flown[0]                                            # ... since t = 0
        moving = within < self.GO_S                                          # [T, N]
        pos = np.empty((t.shape[0], n, np.asarray(p0).shape[1]))
        vel = np.empty_like(pos)
        for i in range(n):           # each obstacle along its own clock (cvm_fold keeps it in the arena)
            p, v = cvm_fold(p0[i:i + 1], v0[i:i + 1], radii[i:i + 1], size, flown0[:, i])
            pos[:, i], vel[:, i] = p[:, 0], v[:, 0] * moving[:, i, None]
        return pos, vel
