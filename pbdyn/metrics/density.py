"""Obstacle density (thesis eq. 3-1): the obstacles' share of the arena."""

from __future__ import annotations

import time as _time

import numpy as np

from pbdyn.metrics.result import MetricResult
from pbdyn.metrics.survivability import positive
from pbdyn.world.geometry import StaticBody


def static_measure(body: StaticBody, arena_size: np.ndarray) -> float:
    """Footprint area (2D, m^2) or volume (3D, m^3) of a static body: pillars pi r^2 (3D: times the volume height,
    which they span), boxes the product of their extents."""
    d = arena_size.shape[0]
    if body.kind == "pillar":
        area = np.pi * body.radius ** 2
        return float(area if d == 2 else area * arena_size[2])
    return float(np.prod(np.asarray(body.size, dtype=float)[:d]))


def shape_points(rollout, b: int, k: int, cell: float, *, clip: bool = False) -> np.ndarray:
    """The midpoints [P, d] of cells of ``cell`` m over imported body b's bounding box at step k (``clip``: only the
    part inside the arena) that lie inside its real shape; in 2D its cross-section in the flight plane."""
    field = rollout.bodies.field()
    d = rollout.dims
    lo, hi = field.world_bounds(b, k)
    if clip:
        lo = np.maximum(lo[:d], 0.0).tolist() + list(lo[d:])
        hi = np.minimum(hi[:d], rollout.arena_size).tolist() + list(hi[d:])
    h = float(rollout.meta.get("flight_height", 2.0))
    if d == 2 and not lo[2] <= h <= hi[2]:
        return np.zeros((0, 2))
    axes = [np.arange(lo[a] + 0.5 * cell, hi[a], cell) for a in range(d)]
    out = []
    xs = axes[0]
    rows = max(1, 400_000 // max(1, int(np.prod([len(a) for a in axes[1:]]))))
    for s in range(0, len(xs), rows):
        grid = np.stack(np.meshgrid(xs[s:s + rows], *axes[1:], indexing="ij"), axis=-1).reshape(-1, d)
        q = np.concatenate([grid, np.full((grid.shape[0], 1), h)], axis=1) if d == 2 else grid
        out.append(grid[field.body_distance(b, q, k) < 0.0])
    return np.concatenate(out, axis=0) if out else np.zeros((0, d))


def shape_measure(rollout, b: int, k: int, cell: float) -> float:
    """Cross-section area in the flight plane (2D, m^2) or volume (3D, m^3) of imported body b at step k: exact for
    a single-primitive body in 3D, else the cells of ``cell`` m (midpoint rule over the part of the body's bounding
    box inside the arena) whose centre is inside its real shape."""
    field = rollout.bodies.field()
    if rollout.dims == 3 and len(field.prims[b]) == 1 and np.isfinite(field.prims[b][0].volume()):
        return field.prims[b][0].volume()
    return float(shape_points(rollout, b, k, cell, clip=True).shape[0] * cell ** rollout.dims)


def density(rollout, *, time: float = 0.0, mav_radius: float = 1.0, include_static: bool = True,
            cell: float | None = None) -> MetricResult:
    """Obstacle density (thesis eq. 3-1, dimensionless): sum of the obstacles' disc areas pi r_i^2 / arena area
    (3D: ball volumes 4/3 pi r_i^3 / box volume) at ``time`` (s), plus the static bodies' footprints (pillars
    pi r^2, boxes sx sy; 3D volumes) with ``include_static``. Overlaps (obstacle-obstacle, obstacle-static) are not
    deducted and nothing is clipped at the walls, so the value is a sum of shares. ``mav_radius`` is accepted like
    every metric's but does not enter the value. per_sample: each body's area/volume [N (+ S)] (m^2 or m^3).
    Imported worlds: each body's real shape, static bodies with ``include_static``: in 3D its exact volume when it
    is a single primitive or closed mesh, else (and in 2D, the cross-section in the flight plane) the cells of
    ``cell`` m (default 0.02 m in 2D, 0.05 m in 3D) whose centre is inside it.
    """
    t0 = _time.perf_counter()
    positive("mav_radius", mav_radius)
    rollout.step_index(float(time))   # HorizonError past the horizon; radii do not change with time
    d = rollout.dims
    r = rollout.radii
    cell = positive("cell", cell if cell is not None else (0.02 if d == 2 else 0.05))
    bodies = getattr(rollout, "bodies", None)
    if bodies is None:
        measures = np.pi * r ** 2 if d == 2 else 4.0 / 3.0 * np.pi * r ** 3
    else:
        k = rollout.step_index(float(time))
        chosen = [b for b in range(len(bodies.names)) if include_static or bodies.moving[b]]
        measures = np.array([shape_measure(rollout, b, k, cell) for b in chosen], dtype=float)
    if include_static and rollout.static:
        measures = np.concatenate([measures, [static_measure(b, rollout.arena_size) for b in rollout.static]])
    total = float(np.prod(rollout.arena_size))
    value = float(np.sum(measures) / total)
    params = {"time": float(time), "include_static": bool(include_static), "dims": d}
    if bodies is not None:
        params["cell"] = cell
    measures = np.asarray(measures, dtype=float)
    measures.setflags(write=False)
    return MetricResult("density", value, params, int(measures.size), 0, measures, float("nan"),
                        {"arena_measure": total}, _time.perf_counter() - t0)
