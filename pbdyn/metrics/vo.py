"""VO feasibility (thesis eq. 3-4, 3-5): the fraction of sampled MAV velocities outside every obstacle's velocity
obstacle, averaged over sample positions.

For the MAV A at a sample and an obstacle B (snapshot at ``time``), with p = p_B - p_A, R = r_A + r_B, u = v_A - v_B,
v_A is infeasible if u t enters the open disc/ball D(p, R) for some t > 0 (infinite-horizon cone, eq. 3-4): for A
outside D, iff u . p > 0 and |p|^2 |u|^2 - (u . p)^2 < R^2 |u|^2 (the ray passes strictly closer than R to p).
Static bodies (v_B = 0) block v_A when the ray from the sample along v_A enters their footprint inflated by r_A
(exact, see traversability.ray_static). A sample whose MAV overlaps an obstacle scores 0. Imported worlds: moving
bodies are their bounding spheres (VO cones need discs/balls); static bodies block by their real shapes.

Velocity set: 2D 63 headings 2 pi j / 63 x 10 speeds linspace(2, 6, 10) m/s (630); 3D the same speeds along 126
Fibonacci-sphere directions (z_i = 1 - (2 i + 1) / n, azimuth i x pi (3 - sqrt 5)) (1260).
"""

from __future__ import annotations

import time as _time

import numpy as np

from pbdyn import limits
from pbdyn.errors import ConfigError
from pbdyn.metrics.result import MetricResult
from pbdyn.metrics.survivability import base_points, jsonable, positive, split_static, summary
from pbdyn.metrics.traversability import ray_static, ray_walls, shape_distances



def fibonacci_directions(n: int) -> np.ndarray:
    """n nearly uniform unit vectors [n, 3] on the sphere (Fibonacci lattice)."""
    i = np.arange(n, dtype=float)
    z = 1.0 - (2.0 * i + 1.0) / n
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = i * np.pi * (3.0 - np.sqrt(5.0))
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def velocity_set(dims: int, *, n_headings: int = 63, n_directions: int = 126, v_min: float = 2.0,
                 v_max: float = 6.0, n_speeds: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """(unit directions [H, d], velocities [H * S, d] in m/s, direction-major): 2D ``n_headings`` headings
    2 pi j / n_headings, 3D ``n_directions`` Fibonacci directions; speeds linspace(v_min, v_max, n_speeds)."""
    if dims == 2:
        if int(n_headings) < 1:
            raise ConfigError("n_headings", "must be >= 1", n_headings)
        th = 2.0 * np.pi * np.arange(int(n_headings)) / int(n_headings)
        dirs = np.column_stack([np.cos(th), np.sin(th)])
    else:
        if int(n_directions) < 1:
            raise ConfigError("n_directions", "must be >= 1", n_directions)
        dirs = fibonacci_directions(int(n_directions))
    if int(n_speeds) < 1:
        raise ConfigError("n_speeds", "must be >= 1", n_speeds)
    if not 0.0 <= float(v_min) <= float(v_max):
        raise ConfigError("v_min", f"must be in [0, v_max = {v_max}]", v_min)
    speeds = np.linspace(float(v_min), float(v_max), int(n_speeds))
    return dirs, (dirs[:, None, :] * speeds[None, :, None]).reshape(-1, dims)


def infeasible_velocities(points: np.ndarray, obs_pos: np.ndarray, obs_vel: np.ndarray, reach: np.ndarray,
                          velocities: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(infeasible [n, V] bool, inside [n] bool): velocities [V, d] of a MAV at points [n, d] inside the union of
    the obstacles' infinite-horizon velocity obstacles (eq. 3-4; obstacles at obs_pos [N, d] moving at obs_vel
    [N, d], reach [N] = r_i + r_mav), and whether the MAV already overlaps an obstacle."""
    n, n_v, n_o = points.shape[0], velocities.shape[0], obs_pos.shape[0]
    bad = np.zeros((n, n_v), dtype=bool)
    inside = np.zeros(n, dtype=bool)
    if n_o == 0 or n == 0:
        return bad, inside
    u = velocities[:, None, :] - obs_vel[None, :, :]                    # [V, N, d]
    uu = np.sum(u * u, axis=2)                                           # [V, N]
    r2uu = reach[None, :] ** 2 * uu
    step = max(1, limits.CHUNK_ELEMENTS // (n_v * n_o))
    for s in range(0, n, step):
        p = obs_pos[None, :, :] - points[s:s + step, None, :]           # [m, N, d]
        pp = np.sum(p * p, axis=2)                                       # [m, N]
        inside[s:s + step] = np.any(pp < reach[None, :] ** 2, axis=1)
        up = p[:, None, :, 0] * u[None, :, :, 0]                         # u . p [m, V, N], summed over axes
        for a in range(1, p.shape[2]):
            up += p[:, None, :, a] * u[None, :, :, a]
        cone = (up > 0.0) & (pp[:, None, :] * uu[None] - up * up < r2uu[None])
        bad[s:s + step] = np.any(cone, axis=2)
    return bad, inside


def vo_feasibility(rollout, *, spacing: float = 6.0, margin: float = 2.0, mav_radius: float = 1.0,
                   time: float = 0.0, n_headings: int = 63, n_directions: int = 126, v_min: float = 2.0,
                   v_max: float = 6.0, n_speeds: int = 10, include_static: bool = True, points=None,
                   name: str = "vo_feasibility") -> MetricResult:
    """VO feasibility (thesis eq. 3-5, dimensionless in [0, 1]): mean over samples of the fraction of the velocity
    set outside every velocity obstacle (eq. 3-4) of the obstacles at ``time`` (s).

    Samples: the survivability grid (margin + k * spacing per axis, m) or ``points`` [n, d]; samples whose MAV
    overlaps static geometry are left out (n_excluded); a sample whose MAV overlaps an obstacle scores 0.
    per_sample: feasible fraction [n]; stderr = std / sqrt(n); extra["n_velocities"], extra["n_inside"].
    """
    t0 = _time.perf_counter()
    mav_radius = positive("mav_radius", mav_radius)
    spacing = positive("spacing", spacing)
    k = rollout.step_index(float(time))
    dirs, vels = velocity_set(rollout.dims, n_headings=n_headings, n_directions=n_directions, v_min=v_min,
                              v_max=v_max, n_speeds=n_speeds)
    pts, n_excl = split_static(rollout, base_points(rollout, points, spacing, margin), mav_radius)
    pos, vel = rollout.at(k)
    bad, inside = infeasible_velocities(pts, pos, vel, rollout.radii + mav_radius, vels)
    if include_static and pts.shape[0]:
        moving = np.linspace(float(v_min), float(v_max), int(n_speeds)) > 0.0
        blocked = np.zeros((pts.shape[0], dirs.shape[0]), dtype=bool)
        for body in rollout.static:
            blocked |= np.isfinite(ray_static(pts, dirs, body, mav_radius))
        bodies = getattr(rollout, "bodies", None)
        if bodies is not None and not bodies.moving.all():     # imported static shapes: any hit blocks a heading
            walls = ray_walls(pts, dirs, rollout.arena_size, mav_radius)
            blocked |= shape_distances(rollout, k, pts, dirs, mav_radius, walls, "static") < walls - 1e-9
        bad |= (blocked[:, :, None] & moving[None, None, :]).reshape(pts.shape[0], -1)
    per_sample = np.where(inside, 0.0, 1.0 - bad.mean(axis=1) if vels.shape[0] else 1.0)
    value, err = summary(per_sample)
    params = {"spacing": spacing, "margin": float(margin), "mav_radius": mav_radius, "time": float(time),
              "n_headings": int(n_headings) if rollout.dims == 2 else None,
              "n_directions": int(n_directions) if rollout.dims == 3 else None, "v_min": float(v_min),
              "v_max": float(v_max), "n_speeds": int(n_speeds), "include_static": bool(include_static),
              "points": None if points is None else jsonable(pts)}
    extra = {"n_velocities": int(vels.shape[0]), "n_inside": int(np.count_nonzero(inside))}
    per_sample.setflags(write=False)
    return MetricResult(name, value, params, int(pts.shape[0]), n_excl, per_sample, err, extra,
                        _time.perf_counter() - t0)


def vo_feasibility_dense(rollout, *, spacing: float = 3.0, margin: float = 2.0, mav_radius: float = 1.0,
                         time: float = 0.0, n_headings: int = 63, n_directions: int = 126, v_min: float = 2.0,
                         v_max: float = 6.0, n_speeds: int = 10, include_static: bool = True,
                         points=None) -> MetricResult:
    """Dense VO feasibility (thesis eq. 3-5): vo_feasibility() on the 3 m grid (2D 16 x 16)."""
    return vo_feasibility(rollout, spacing=spacing, margin=margin, mav_radius=mav_radius, time=time,
                          n_headings=n_headings, n_directions=n_directions, v_min=v_min, v_max=v_max,
                          n_speeds=n_speeds, include_static=include_static, points=points,
                          name="vo_feasibility_dense")
