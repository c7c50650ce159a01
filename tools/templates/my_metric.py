"""A template difficulty metric for pbdyn: copy this file, rename the function, and change what it measures.

A metric is a pure function of a map's rollout (docs/design.md "The data flow (one direction)"): the obstacles'
state at every step, the arena and its static bodies; never a trial. It is called as ``f(rollout, **params)`` and
returns a ``pbdyn.metrics.result.MetricResult``. Its keyword-only parameters are what a caller may set; every one
needs a default. ``mav_radius`` is set by pbdyn to the scenario's MAV radius.

Inputs (world frame, z up, SI units):
    rollout.times [T] (s, uniform from 0, step rollout.dt s); rollout.positions [T, N, d] and rollout.velocities
        [T, N, d] (m, m/s): every dynamic obstacle's centre and velocity (discs in 2D, balls in 3D; an imported
        world's moving bodies by their bounding spheres); rollout.radii [N] (m); rollout.arena_size [d] (m: the
        arena is the box [0, L_k] on every axis); rollout.static: the static bodies (pbdyn.world.geometry.StaticBody);
        rollout.step_index(t) -> k, the step of time t (s; HorizonError past the rollout's horizon).
    mav_radius (m), time (s), spacing (m), margin (m), cap (m): this metric's parameters (mean_clearance below).
Output: MetricResult(name, value, params, n_samples, n_excluded, per_sample, stderr, extra, wall_time_s) --
    value (the metric, in its unit), params (every parameter used, JSON-able), n_samples (samples in the value),
    n_excluded (samples left out), per_sample (the values behind it, read-only), stderr (std / sqrt(n)), extra
    (further JSON-able results), wall_time_s (s).

mean_clearance is deliberately simple but real: resting MAVs on a grid of sample points; at ``time`` each one's
clearance, the distance from its surface to the nearest obstacle's surface (m, 0 when they overlap, at most
``cap``); the value is the mean (m, higher = easier).

Built-in metrics live in pbdyn/metrics/ (docs/architecture.md "Where each extension goes"): put the module there,
add one MetricInfo row to pbdyn/metrics/catalog.py (its name, label, unit, direction, module) -- the registry
(pbdyn.metrics.registry.METRICS), the cache, the batch and the analysis all read that table -- and every caller
computes it through pbdyn.metrics.cached.run_metric. Until then, call it on any rollout:

    import pbdyn
    from my_metric import mean_clearance
    print(mean_clearance(pbdyn.rollout("quickstart", map=0)).value)
"""

from __future__ import annotations

import time as _time

import numpy as np

from pbdyn.metrics.result import MetricResult
from pbdyn.metrics.sampling import grid_samples, outside_geometry


def mean_clearance(rollout, *, mav_radius: float = 1.0, time: float = 0.0, spacing: float = 6.0,
                   margin: float = 2.0, cap: float = 10.0) -> MetricResult:
    """Mean clearance (m, higher = easier) of resting MAVs at the grid points margin + k spacing (m, every axis) at
    ``time`` (s): per point the distance from the MAV's disc/ball (radius mav_radius, m) to the nearest obstacle
    surface, 0 when they overlap, at most cap (m). Points whose MAV overlaps static geometry are left out.
    per_sample: the clearance of each point [n] (m)."""
    t0 = _time.perf_counter()
    if mav_radius <= 0 or spacing <= 0 or cap <= 0:
        raise ValueError(f"mav_radius, spacing and cap must be > 0 (got {mav_radius}, {spacing}, {cap})")
    grid = grid_samples(rollout.arena_size, float(spacing), float(margin))       # [n, d] (m)
    keep = outside_geometry(rollout, grid, float(mav_radius))
    pts = grid[keep]
    positions, _ = rollout.at(rollout.step_index(float(time)))                    # [N, d] (m)
    gap = np.full(pts.shape[0], float(cap))
    if positions.shape[0] and pts.shape[0]:
        centre = np.linalg.norm(pts[:, None, :] - positions[None, :, :], axis=2)  # [n, N] (m)
        surface = centre - rollout.radii[None, :] - float(mav_radius)
        gap = np.clip(surface.min(axis=1), 0.0, float(cap))
    gap.setflags(write=False)
    n = int(gap.shape[0])
    value = float(gap.mean()) if n else float("nan")
    stderr = float(gap.std(ddof=1) / np.sqrt(n)) if n > 1 else float("nan")
    params = {"mav_radius": float(mav_radius), "time": float(time), "spacing": float(spacing),
              "margin": float(margin), "cap": float(cap)}
    return MetricResult("mean_clearance", value, params, n, int(np.count_nonzero(~keep)), gap, stderr, {},
                        _time.perf_counter() - t0)
