"""Closed-form difficulty baselines that need no simulation (docs/design.md "Difficulty: what counts as evidence").

A difficulty metric is only useful where it beats these. Both are computed from the map's state at one instant:

- flux (the swept-area rate, 1/s): sum_i w_i |v_i| / A -- in 2D w_i = 2 (r_i + r_MAV), the width of the band
  obstacle i sweeps in which a resting MAV disc would be hit, A the arena area; in 3D w_i = pi (r_i + r_MAV)^2,
  A the arena volume. For obstacles placed uniformly at random it is the expected rate at which a fixed point of
  the arena is hit, the closed form behind every simulated "time to first hit" metric.
- static_share (1): the share of the arena in which the MAV's centre would overlap a static body (the bodies
  inflated by the MAV radius, overlaps counted once) -- what flux cannot see.

Imported worlds use the moving bodies' real shapes: in 2D w_i = the width of the body's cross-section in the flight
plane across its velocity, + 2 r_MAV; in 3D the area of its shape projected along its velocity, A_p, as the disc
of the same area inflated by r_MAV, pi (sqrt(A_p / pi) + r_MAV)^2 (exact for spheres). Both measured on cells of
``cell`` m (midpoints inside the shape).
"""

from __future__ import annotations

import math
import time as _time

import numpy as np

from pbdyn.metrics.density import shape_points
from pbdyn.metrics.result import MetricResult
from pbdyn.metrics.survivability import positive

_CHUNK_POINTS = 200_000
"""Grid points per chunk of static_share."""


def swept_width(points: np.ndarray, velocity: np.ndarray, cell: float) -> float:
    """2D: the extent (m) of ``points`` [P, 2] (cell midpoints) across ``velocity``, one cell added for the cells'
    own width; 0 for no points. A still body (|v| = 0) sweeps nothing, so its direction does not matter."""
    if points.shape[0] == 0:
        return 0.0
    v = np.asarray(velocity, dtype=float)[:2]
    speed = float(np.hypot(v[0], v[1]))
    n = np.array([-v[1], v[0]]) / speed if speed > 0 else np.array([0.0, 1.0])
    s = points[:, :2] @ n
    return float(s.max() - s.min() + cell)


def projected_area(points: np.ndarray, velocity: np.ndarray, cell: float) -> float:
    """3D: the area (m^2) of ``points`` [P, 3] (cell midpoints) projected along ``velocity`` onto the plane across it,
    counted on cells of ``cell`` m in that plane; 0 for no points."""
    if points.shape[0] == 0:
        return 0.0
    v = np.asarray(velocity, dtype=float)
    speed = float(np.linalg.norm(v))
    u = v / speed if speed > 0 else np.array([0.0, 0.0, 1.0])
    a = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(u, a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    cells = np.floor(np.stack([points @ e1, points @ e2], axis=1) / cell).astype(np.int64)
    return float(np.unique(cells, axis=0).shape[0] * cell * cell)


def equivalent_radii(rollout, time: float, cell: float | None = None) -> np.ndarray:
    """Per obstacle the radius (m) of the band it sweeps at ``time`` (s): the disc/ball radius of generated
    obstacles; for imported bodies half their swept width across their velocity (2D) or the radius of the disc of
    their projected area (3D), measured on cells of ``cell`` m (default 0.02 m in 2D, 0.05 m in 3D); 0 for a body
    that misses the flight plane."""
    bodies = getattr(rollout, "bodies", None)
    if bodies is None:
        return np.asarray(rollout.radii, dtype=float)
    d = rollout.dims
    cell = positive("cell", cell if cell is not None else (0.02 if d == 2 else 0.05))
    k = rollout.step_index(float(time))
    v = np.asarray(rollout.velocities[k], dtype=float).reshape(-1, d)
    out = np.zeros(rollout.n_obstacles)
    for i, b in enumerate(bodies.moving_index.tolist()):
        pts = shape_points(rollout, b, k, cell)
        out[i] = 0.5 * swept_width(pts, v[i], cell) if d == 2 else math.sqrt(projected_area(pts, v[i], cell) / math.pi)
    return out


def flux(rollout, *, time: float = 0.0, mav_radius: float = 1.0, cell: float | None = None) -> MetricResult:
    """Swept-area rate (1/s; higher = harder): sum_i w_i |v_i| / arena measure at ``time`` (s), w_i = 2 (r_i + r_MAV)
    in 2D, pi (r_i + r_MAV)^2 in 3D with r_i from equivalent_radii (module doc; imported worlds: the real shapes,
    cells of ``cell`` m, and no band for a body that misses the flight plane). per_sample: each obstacle's
    w_i |v_i| (m^2/s in 2D, m^3/s in 3D)."""
    t0 = _time.perf_counter()
    mav_radius = positive("mav_radius", mav_radius)
    k = rollout.step_index(float(time))
    d = rollout.dims
    cell = positive("cell", cell if cell is not None else (0.02 if d == 2 else 0.05))
    v = np.asarray(rollout.velocities[k], dtype=float).reshape(-1, d)
    speed = np.sqrt(np.sum(v * v, axis=1))
    r = equivalent_radii(rollout, time, cell)
    width = 2.0 * (r + mav_radius) if d == 2 else math.pi * (r + mav_radius) ** 2
    bodies = getattr(rollout, "bodies", None)
    if bodies is not None:
        width = np.where(r > 0, width, 0.0)
    per = np.asarray(width * speed, dtype=float)
    per.setflags(write=False)
    total = float(np.prod(rollout.arena_size))
    params = {"time": float(time), "mav_radius": float(mav_radius), "dims": d}
    if bodies is not None:
        params["cell"] = cell
    return MetricResult("flux", float(per.sum() / total), params, int(per.size), 0, per, float("nan"),
                        {"arena_measure": total}, _time.perf_counter() - t0)


def static_share(rollout, *, mav_radius: float = 1.0, cell: float | None = None) -> MetricResult:
    """Share (1; higher = harder) of the arena where the MAV's centre would overlap a static body: the share of the
    midpoints of cells of ``cell`` m (default 0.25 m in 2D, 0.5 m in 3D) within ``mav_radius`` of a static body
    (generated pillars and boxes; imported worlds' still bodies, in 2D their cross-section in the flight plane).
    per_sample: the share blocked by each static body alone [S]."""
    t0 = _time.perf_counter()
    mav_radius = positive("mav_radius", mav_radius)
    d = rollout.dims
    cell = positive("cell", cell if cell is not None else (0.25 if d == 2 else 0.5))
    size = np.asarray(rollout.arena_size, dtype=float)
    axes = [np.arange(0.5 * cell, size[a], cell) for a in range(d)]
    bodies = getattr(rollout, "bodies", None)
    still = [] if bodies is None else np.flatnonzero(~bodies.moving).tolist()
    n_static = len(rollout.static) + len(still)
    h = float(rollout.meta.get("flight_height", 2.0))
    blocked_any = 0
    per = np.zeros(n_static)
    n_points = 0
    xs = axes[0]
    rows = max(1, _CHUNK_POINTS // max(1, int(np.prod([len(a) for a in axes[1:]]))))
    for s in range(0, len(xs), rows):
        grid = np.stack(np.meshgrid(xs[s:s + rows], *axes[1:], indexing="ij"), axis=-1).reshape(-1, d)
        n_points += grid.shape[0]
        hit = np.zeros((n_static, grid.shape[0]), dtype=bool)
        for j, body in enumerate(rollout.static):
            hit[j] = body.footprint_distance(grid) < mav_radius
        if still:
            q = np.concatenate([grid, np.full((grid.shape[0], 1), h)], axis=1) if d == 2 else grid
            field = bodies.field()
            for j, b in enumerate(still):
                hit[len(rollout.static) + j] = field.body_distance(b, q, 0) < mav_radius
        per += hit.sum(axis=1)
        blocked_any += int(np.count_nonzero(hit.any(axis=0))) if n_static else 0
    share = blocked_any / n_points if n_points else 0.0
    per = per / max(n_points, 1)
    per.setflags(write=False)
    return MetricResult("static_share", float(share), {"mav_radius": float(mav_radius), "cell": cell, "dims": d},
                        int(n_points), 0, per, float("nan"), {"n_static": n_static}, _time.perf_counter() - t0)
