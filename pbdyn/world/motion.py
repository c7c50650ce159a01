"""Obstacle motion models (thesis 2-3, fig. 2-3)."""

from __future__ import annotations

import numpy as np


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
