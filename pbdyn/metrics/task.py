"""Task-level difficulty: metrics of one start/goal task on a map, measured along and around the straight
start-goal corridor from the moment the trial starts (joined to every trial's row).

Corridor samples (corridor_points): points every ``spacing`` m along the segment from start to goal (both ends
included) and the same points shifted ``half_width`` m to each side (2D: +-the left normal; 3D: +-two unit vectors
across the segment), kept where the MAV disc/ball stays inside the arena and off static geometry.

- corridor_survivability (s; higher = easier): thesis eq. 3-6 on the corridor samples -- the mean over samples of
  the time until an obstacle overlaps a resting MAV there, capped at t_max -- from ``start_time`` (the trial's
  start), with the map's survivability kernel (pbdyn.metrics.backends; the backend that sees the real shapes
  for imported worlds).
- corridor_flux (1/s; higher = harder): its closed-form, simulation-free analogue, the swept-area rate of
  pbdyn.metrics.baselines restricted to the corridor: the number of (sample, obstacle) pairs whose straight path
  from the state at ``start_time`` over ``horizon`` s (no walls) passes within r_i + r_MAV of the sample, per sample
  and second. For obstacles placed uniformly at random its expectation is the map's flux; on a real map it counts
  the obstacles actually headed across this corridor. Imported bodies: half their swept width (2D) or the radius of
  the disc of their projected area (3D) as r_i (pbdyn.metrics.baselines).
"""

from __future__ import annotations

import math

import numpy as np

from pbdyn.metrics.backends import kernel
from pbdyn.metrics.baselines import equivalent_radii
from pbdyn.metrics.survivability import positive, split_static


def corridor_points(start, goal, arena_size, *, spacing: float = 3.0, half_width: float = 3.0,
                    mav_radius: float = 1.0) -> np.ndarray:
    """The corridor samples [n, d] (m; module doc), before static geometry is removed."""
    s = np.asarray(start, dtype=float)
    g = np.asarray(goal, dtype=float)
    d = s.shape[0]
    spacing = positive("spacing", spacing)
    seg = g - s
    length = float(np.linalg.norm(seg))
    n_along = max(1, int(math.ceil(length / spacing))) + 1
    line = s[None, :] + np.linspace(0.0, 1.0, n_along)[:, None] * seg[None, :]
    u = seg / length if length > 0 else np.eye(d)[0]
    if d == 2:
        across = [np.array([-u[1], u[0]])]
    else:
        a = np.array([0.0, 0.0, 1.0]) if abs(u[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        e1 = np.cross(u, a)
        e1 /= np.linalg.norm(e1)
        across = [e1, np.cross(u, e1)]
    pts = [line] + [line + sign * half_width * e[None, :] for e in across for sign in (1.0, -1.0)] \
        if half_width > 0 else [line]
    pts = np.concatenate(pts, axis=0)
    size = np.asarray(arena_size, dtype=float)
    inside = np.all((pts >= mav_radius) & (pts <= size - mav_radius), axis=1)
    return pts[inside]


def corridor_survivability(rollout, start, goal, *, start_time: float = 0.0, mav_radius: float = 1.0,
                           t_max: float = 12.0, spacing: float = 3.0, half_width: float = 3.0,
                           backend: str = "analytic") -> tuple[float, int]:
    """(corridor survivability (s), number of samples) of the task start -> goal (module doc); NaN for no sample."""
    pts = corridor_points(start, goal, rollout.arena_size, spacing=spacing, half_width=half_width,
                          mav_radius=mav_radius)
    pts, _ = split_static(rollout, pts, mav_radius)
    if pts.shape[0] == 0:
        return float("nan"), 0
    times = kernel(backend, "sampled")(rollout, pts, mav_radius=mav_radius, t_max=t_max, start_time=start_time)
    return float(np.mean(times)), int(pts.shape[0])


def corridor_flux(rollout, start, goal, *, start_time: float = 0.0, mav_radius: float = 1.0,
                  horizon: float = 12.0, spacing: float = 3.0, half_width: float = 3.0,
                  radii: np.ndarray | None = None) -> tuple[float, int]:
    """(corridor flux (1/s), number of samples) of the task start -> goal (module doc); NaN for no sample.
    ``radii``: the obstacles' equivalent radii (pbdyn.metrics.baselines.equivalent_radii; computed when None)."""
    horizon = positive("horizon", horizon)
    pts = corridor_points(start, goal, rollout.arena_size, spacing=spacing, half_width=half_width,
                          mav_radius=mav_radius)
    pts, _ = split_static(rollout, pts, mav_radius)
    if pts.shape[0] == 0:
        return float("nan"), 0
    return points_flux(rollout, pts, start_time=start_time, mav_radius=mav_radius, horizon=horizon,
                       radii=radii), int(pts.shape[0])


def points_flux(rollout, pts: np.ndarray, *, start_time: float = 0.0, mav_radius: float = 1.0,
                horizon: float = 12.0, radii: np.ndarray | None = None) -> float:
    """corridor_flux's closed form (1/s) on given samples [n, d] (m, n > 0): (sample, obstacle) pairs whose straight
    path over ``horizon`` s from ``start_time`` passes within r_i + r_MAV of the sample, per sample and second."""
    horizon = positive("horizon", horizon)
    if rollout.n_obstacles == 0:
        return 0.0
    k = rollout.step_index(float(start_time))
    p = np.asarray(rollout.positions[k], dtype=float).reshape(rollout.n_obstacles, -1)
    v = np.asarray(rollout.velocities[k], dtype=float).reshape(rollout.n_obstacles, -1)
    r = equivalent_radii(rollout, start_time) if radii is None else np.asarray(radii, dtype=float)
    # distance from each sample to each obstacle's path segment p + v tau, tau in [0, horizon]
    rel = pts[:, None, :] - p[None, :, :]                                     # [n, N, d]
    vv = np.sum(v * v, axis=1)                                                # [N]
    with np.errstate(invalid="ignore", divide="ignore"):
        tau = np.where(vv > 0, np.sum(rel * v[None, :, :], axis=2) / vv, 0.0)
    tau = np.clip(tau, 0.0, horizon)
    closest = rel - tau[:, :, None] * v[None, :, :]
    hit = np.sum(closest * closest, axis=2) < (r[None, :] + mav_radius) ** 2
    return float(np.count_nonzero(hit) / (pts.shape[0] * horizon))
