"""The thesis program's depth sensor as geometry: rays marched in fixed steps (thesis 2-4-2; docs/thesis-program.md
"MAV, sensing, tracking": 50 rays across the FOV, ~0.9 m steps, a ray stops at the first obstacle).

Each ray from the sensor position o along a unit direction u is the sequence of march points o + t_k u with
t_k = k * step, k = 0, 1, ... while t_k < range. The ray's hit is its first point that lies inside (or on) a
dynamic obstacle's disc (2D) / ball (3D), inside (or on) a static body's footprint (pbdyn.world.geometry.StaticBody)
or beyond an arena wall (a coordinate < 0 or >= L: the half-open cells of the occupancy grid put a point at L in
the border cell). At one point an obstacle takes precedence over a static body, a static body over a wall. A body
that fits between two consecutive points is not seen -- the program's sensor, reproduced on purpose.

The program's own stepping (march_rule "program", program_march_distances): each ray steps ``step`` along its
dominant world axis (0.9-1.27 m along the ray in 2D), and its point at or beyond the range still counts for a hit
but is never marked free.

Everything is numpy, vectorised over rays x points x obstacles (obstacles in chunks of pbdyn.limits.CHUNK_ELEMENTS).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pbdyn import limits
from pbdyn.errors import ConfigError
from pbdyn.perception.sensor import ray_directions
from pbdyn.world.geometry import StaticBody

NONE, OBSTACLE, STATIC, WALL = 0, 1, 2, 3
"""Kinds of a ray's hit."""


@dataclass(frozen=True)
class MarchHits:
    """One scan's march.

    points: the march points [R, K, d] (m, world frame). first: per ray the index of its first point inside a body
    (int64 [R]; K for none). kind: per ray NONE / OBSTACLE / STATIC / WALL (int8 [R]). index: per ray the hit's
    obstacle index (the lowest one holding the point), static body index, or wall index 2 * axis + (0 low side, 1
    high side) (int64 [R]; -1 for none). seen: every obstacle holding some ray's hit point (int64, sorted, unique).
    """

    points: np.ndarray
    first: np.ndarray
    kind: np.ndarray
    index: np.ndarray
    seen: np.ndarray


def march_distances(range_m: float, step: float) -> np.ndarray:
    """The march distances t_k = k * step (m) with t_k < range_m, k = 0, 1, ... (at least t_0 = 0)."""
    if not (math.isfinite(range_m) and range_m > 0 and math.isfinite(step) and step > 0):
        raise ValueError(f"range_m and step must be finite and > 0 (got {range_m}, {step})")
    t = step * np.arange(int(math.ceil(range_m / step)) + 1)
    return t[t < range_m]


def program_march_distances(dirs_t: np.ndarray, range_m: float, step: float) -> tuple[np.ndarray, np.ndarray]:
    """The thesis program's march (its Raycast.castRay): per ray of unit directions dirs_t [d, R] the distances
    t_k = k * step / max_i |u_i| (m; ``step`` along the ray's dominant world axis; the program was 2D) for
    k = 0..K_r, K_r the first k with t_k >= range_m, NaN-padded to [R, max K_r + 1]; and K_r [R] (that point is
    tested for a hit only, never marked free)."""
    if not (math.isfinite(range_m) and range_m > 0 and math.isfinite(step) and step > 0):
        raise ValueError(f"range_m and step must be finite and > 0 (got {range_m}, {step})")
    per = step / np.max(np.abs(dirs_t), axis=0)                                     # [R] m per point
    last = np.ceil(range_m / per - 1e-12).astype(np.int64)                          # [R]
    k = np.arange(int(last.max()) + 1)
    ts = k[None, :] * per[:, None]
    ts[k[None, :] > last[:, None]] = np.nan
    return ts, last


def static_bounds(bodies: tuple[StaticBody, ...], dims: int) -> tuple[np.ndarray, np.ndarray]:
    """Per static body a horizontal bounding disc: centres [S, 2] (m, x-y) and radii [S] (m; boxes: half the
    diagonal of their full extents, so the disc also bounds a 3D box's footprint in x-y)."""
    centres = np.array([np.asarray(b.center, dtype=float)[:2] for b in bodies], dtype=float).reshape(-1, 2)
    radii = np.array([b.radius if b.kind == "pillar" else 0.5 * float(np.linalg.norm(np.asarray(b.size, float)[:dims]))
                      for b in bodies], dtype=float)
    return centres, radii


def _first_true(mask: np.ndarray) -> np.ndarray:
    """Per row of a bool [R, K] the first True column, K for none."""
    k = mask.shape[1]
    return np.where(mask.any(axis=1), np.argmax(mask, axis=1), k)


def march(origin: np.ndarray, dirs_t: np.ndarray, ts: np.ndarray, centres: np.ndarray, radii: np.ndarray,
          arena_size: np.ndarray, bodies: tuple[StaticBody, ...] = (), body_bounds=None) -> MarchHits:
    """March every ray of a scan (module doc).

    origin: the sensor [d] (m); dirs_t: unit ray directions [d, R]; ts: march distances, [K] for every ray
    (march_distances) or [R, K] per ray, NaN where a ray has no point (program_march_distances) (m); centres [N, d],
    radii [N]: the dynamic obstacles (m); arena_size [d] (m; walls outside [0, L)); bodies: static bodies;
    body_bounds: their static_bounds (computed if None).
    """
    o = np.asarray(origin, dtype=float)
    d, n_rays = dirs_t.shape
    ts = np.asarray(ts, dtype=float)
    ts2 = ts[None, :] if ts.ndim == 1 else ts                                     # [1 or R, K]
    n_pts = ts2.shape[1]
    pts = o[None, None, :] + dirs_t.T[:, None, :] * ts2[:, :, None]              # [R, K, d] (NaN: no point)
    reach = float(np.nanmax(ts2))

    # dynamic obstacles near enough to hold a march point; |o + t u - c|^2 = t^2 - 2 t u.(c - o) + |c - o|^2
    rel = np.asarray(centres, dtype=float).reshape(-1, d) - o
    dist2 = np.einsum("nd,nd->n", rel, rel)
    r = np.asarray(radii, dtype=float).reshape(-1)
    near = np.flatnonzero(dist2 <= (reach + r) ** 2)
    obs_any = np.zeros((n_rays, n_pts), dtype=bool)
    if near.shape[0]:
        proj = rel[near] @ dirs_t                                                     # [M, R]
        t2, r2 = ts2 * ts2, r[near] ** 2
        step = max(1, limits.CHUNK_ELEMENTS // max(1, n_rays * n_pts))
        for s in range(0, near.shape[0], step):
            d2 = t2[None, :, :] - 2.0 * proj[s:s + step, :, None] * ts2[None, :, :]
            d2 += dist2[near[s:s + step], None, None]
            obs_any |= np.any(d2 <= r2[s:s + step, None, None], axis=0)
    first_obs = _first_true(obs_any)

    # static bodies whose bounding disc comes within reach of the sensor (x-y distance, conservative)
    first_st = np.full(n_rays, n_pts, dtype=np.int64)
    which_st = np.full(n_rays, -1, dtype=np.int64)
    if bodies:
        bc, br = static_bounds(bodies, d) if body_bounds is None else body_bounds
        gap = np.linalg.norm(bc - o[None, :2], axis=1) - br
        for j in np.flatnonzero(gap <= reach).tolist():
            k = _first_true(bodies[j].footprint_distance(pts) <= 0.0)
            better = k < first_st
            first_st[better], which_st[better] = k[better], j

    # walls: a coordinate < 0 or >= L
    size = np.asarray(arena_size, dtype=float)
    low, high = pts < 0.0, pts >= size
    first_wall = _first_true(np.any(low | high, axis=2))

    first = np.minimum(np.minimum(first_obs, first_st), first_wall)
    hit = first < n_pts
    kind = np.full(n_rays, NONE, dtype=np.int8)
    kind[hit & (first_wall == first)] = WALL
    kind[hit & (first_st == first)] = STATIC
    kind[hit & (first_obs == first)] = OBSTACLE
    index = np.full(n_rays, -1, dtype=np.int64)
    rows = np.flatnonzero(kind == STATIC)
    index[rows] = which_st[rows]
    rows = np.flatnonzero(kind == WALL)
    if rows.shape[0]:
        out = low[rows, first[rows]] | high[rows, first[rows]]                       # [W, d]
        axis = np.argmax(out, axis=1)
        index[rows] = 2 * axis + high[rows, first[rows], axis]
    rows = np.flatnonzero(kind == OBSTACLE)
    seen = np.zeros(0, dtype=np.int64)
    if rows.shape[0]:
        # the obstacles holding each hit point, by the same arithmetic as the march above
        th = ts2[rows if ts.ndim == 2 else 0, first[rows]]
        d2 = (th * th)[None, :] - 2.0 * proj[:, rows] * th[None, :]                   # [M, H]
        d2 += dist2[near, None]
        holds = d2 <= r2[:, None]
        index[rows] = near[np.argmax(holds, axis=0)]
        seen = near[holds.any(axis=1)]
    return MarchHits(pts, first, kind, index, seen)


class Marching:
    """The "marching" sensor model (pbdyn.perception.registry.SensorModel; module doc): ``perception.rays`` rays over
    the FOV (None: from its resolution_deg; 3D rows as "raycast"), points ``march_step`` m apart, stepped by
    ``march_rule`` ("program": program_march_distances and, in 2D, the program's fan from -fov/2 in fov/rays steps).
    Sees discs/balls, pillars and boxes: a world with static URDF bodies is refused."""

    def __init__(self, perception):
        self.p = perception
        self.check_world(perception.world)
        self.march_t = march_distances(perception.range_m, perception.march_step)
        self.bounds = static_bounds(tuple(perception.world.static_bodies), perception.dims)

    @staticmethod
    def check_world(world) -> None:
        n_urdf = int(world.static_ids.shape[0]) - len(world.static_bodies)
        if n_urdf:
            raise ConfigError("sensor.model", f"\"marching\" marches through discs/balls, pillars and boxes; this "
                              f"world has {n_urdf} static URDF bodies (use \"raycast\")", "marching")

    def fan(self) -> np.ndarray:
        p = self.p
        if p.march_rule == "program" and p.dims == 2:
            n = p.rays if p.rays is not None else int(round(p.fov_deg / p.resolution_deg)) + 1
            ang = np.radians(-p.fov_deg / 2.0 + p.fov_deg / n * np.arange(n))    # the program's fan
            return np.stack([np.cos(ang), np.sin(ang)], axis=1)
        return ray_directions(0.0, p.fov_deg, p.resolution_deg, p.dims, p.vfov_deg, p.vresolution_deg, p.rays)

    def scan(self, o: np.ndarray, dirs_t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The march points before each ray's hit marked FREE, a static or wall hit point's cell OCCUPIED."""
        world, grid, p = self.p.world, self.p.grid, self.p
        self.check_world(world)
        n_rays = dirs_t.shape[1]
        if p.march_rule == "program":
            ts, tail = program_march_distances(dirs_t, p.range_m, p.march_step)          # [R, K], [R]
            per_ray = ts
        else:
            ts = self.march_t                                                            # [K], every ray
            tail = np.full(n_rays, ts.shape[0])
            per_ray = np.broadcast_to(ts, (n_rays, ts.shape[0]))
        m = march(o, dirs_t, ts, world.obstacle_positions, world.obstacle_radii, world.arena_size,
                  tuple(world.static_bodies), self.bounds)
        n_pts = per_ray.shape[1]
        k = np.arange(n_pts)[None, :]
        before = (k < m.first[:, None]) & (k < tail[:, None])                           # [R, K]
        grid.mark_free(m.points[before])
        ends = np.flatnonzero((m.kind == STATIC) | (m.kind == WALL))
        if ends.shape[0]:
            grid.mark_occupied(m.points[ends, m.first[ends]])
        hits = np.full(m.kind.shape[0], -1, dtype=np.int64)
        for kind, ids in ((OBSTACLE, world.obstacle_ids), (STATIC, world.static_ids), (WALL, world.wall_ids)):
            rows = np.flatnonzero(m.kind == kind)
            hits[rows] = ids[m.index[rows]]
        ranges = np.where(m.kind != NONE, per_ray[np.arange(n_rays), np.minimum(m.first, n_pts - 1)], p.range_m)
        return m.seen, hits, ranges
