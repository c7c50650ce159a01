"""The constant-velocity obstacle motion model, ``obstacles.motion = "cvm"`` (thesis 2-3, fig. 2-3a; docs/scenarios.md
"Scenario reference"): each obstacle keeps its speed and turns at the arena walls, either by specular reflection in
closed form (cvm_fold, ``obstacles.wall_turn = "specular"``) or as the thesis' program stepped it (cvm_program_turn,
``obstacles.wall_turn = "program"``). Its only parameter is obstacles.wall_turn; it has no table of its own.
cvm_fold also moves the constant-velocity bodies of imported worlds (pbdyn.world.imported.bodies).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from pbdyn.motion.protocol import TableKey


def cvm_fold(p0: np.ndarray, v0: np.ndarray, radii: np.ndarray, size: np.ndarray,
             times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Constant-velocity motion with specular reflection at the walls, in closed form (thesis 2-3, CVM).

    Each axis is an independent triangle wave: the centre moves in [r, L - r]; unfolding the reflections,
    u = (p0 - r) + v t is folded with period 2W (W = L - 2r). Exact at any t, no drift.

    Args:
        p0: initial centres [N, d] (m), inside [r, L - r].
        v0: initial velocities [N, d] (m/s).
        radii: [N] (m). size: arena [d] (m). times: [T] (s).
    Returns:
        positions [T, N, d] (m) and velocities [T, N, d] (m/s).
    """
    p0 = np.asarray(p0, dtype=float)
    v0 = np.asarray(v0, dtype=float)
    r = np.asarray(radii, dtype=float)[:, None]
    t = np.asarray(times, dtype=float)[:, None, None]
    lo = r
    width = np.asarray(size, dtype=float)[None, :] - 2.0 * r          # [N, d]
    period = 2.0 * width
    u = (p0 - lo)[None] + v0[None] * t                                 # [T, N, d]
    m = np.mod(u, period[None])
    forward = m < width[None]  # at a wall the velocity is the reflected one (pointing away from it)
    pos = lo[None] + np.where(forward, m, period[None] - m)
    vel = np.where(forward, v0[None], -v0[None])
    return pos, vel


def cvm_program_turn(p0: np.ndarray, v0: np.ndarray, radii: np.ndarray, size: np.ndarray,
                     times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Constant-velocity motion as the thesis' program stepped it (obstacles.wall_turn = "program";
    docs/thesis-program.md "World and obstacles"): each step it computed the next centre p_k + v_k dt, and an axis
    on which that centre would lie less than r from a wall (below r or above L - r) turned away from that wall
    before the move (its velocity and preferred velocity were one array, so the turn took effect in the same step):
    p_k+1 = p_k + v'_k dt. So an obstacle reverses up to |v| dt before the line r from a wall, from where it stands,
    and never reaches it (not mirrored, as the specular cvm_fold). Stepwise, vectorised over obstacles; times must
    be uniform, from 0.

    Args and returns as cvm_fold: p0 [N, d] (m), v0 [N, d] (m/s), radii [N] (m), size [d] (m), times [T] (s);
    positions [T, N, d] (m) and velocities [T, N, d] (m/s; the velocity flown from t_k to t_k+1).
    """
    p = np.array(p0, dtype=float)
    v = np.array(v0, dtype=float)
    r = np.asarray(radii, dtype=float)[:, None]
    hi = np.asarray(size, dtype=float)[None, :] - r
    times = np.asarray(times, dtype=float)
    dt = float(times[1] - times[0]) if times.size > 1 else 0.0
    pos = np.empty((times.size,) + p.shape)
    vel = np.empty((times.size,) + p.shape)
    for k in range(times.size):
        ahead = p + v * dt
        v = np.where(ahead < r, np.abs(v), np.where(ahead > hi, -np.abs(v), v))
        pos[k], vel[k] = p, v
        p = p + v * dt
    return pos, vel


class CVM:
    """The "cvm" model (pbdyn.motion.protocol.MotionModel): params = obstacles.wall_turn ("specular": cvm_fold,
    velocities instantaneous at t_k; "program": cvm_program_turn, velocities flown from t_k to t_k+1)."""

    name = "cvm"
    table: str | None = None
    params_type: type | None = None
    table_keys: tuple[TableKey, ...] = ()

    def params(self, obstacles: Any) -> str:
        """obstacles.wall_turn: "specular" or "program"."""
        return obstacles.wall_turn

    def check_params(self, params: Any, given: Mapping[str, Any], where: str) -> None:
        """Nothing to check (no table)."""

    def key_params(self, obstacles: Any) -> dict:
        """None: wall_turn reaches rollout keys as an obstacles field added later (pbdyn.config.LATER_FIELDS)."""
        return {}

    def rollout(self, p0: np.ndarray, v0: np.ndarray, radii: np.ndarray, size: np.ndarray, times: np.ndarray,
                dt: float, params: str) -> tuple[np.ndarray, np.ndarray]:
        """Positions [T, N, d] (m) and velocities [T, N, d] (m/s) by cvm_program_turn when ``params`` is "program",
        else by cvm_fold (arguments: MotionModel.rollout; dt is implied by the uniform times)."""
        fold = cvm_program_turn if params == "program" else cvm_fold
        return fold(p0, v0, radii, size, times)
