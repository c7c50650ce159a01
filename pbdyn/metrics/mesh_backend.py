"""The ``mesh`` survivability backend: survival times (thesis eq. 3-6, 3-7, "sampled" mode) from signed distances
between the static MAV's centre at each sample and the real shapes of an imported world's moving bodies.

Independent of both other backends: no PyBullet, no bounding spheres. Each body's collision geometry is a signed-
distance field in its own frame (pbdyn.world.shapes: exact closed forms for URDF boxes, spheres and cylinders;
open3d RaycastingScene for <mesh> geometry), so instead of moving the bodies the samples are moved into each
body's frame at every step -- all samples x all steps of a time chunk in one vectorised query per body. A sample
is hit at step k when its distance to a body is < the MAV radius (penetration; touching does not count, as in the
other backends). 2D worlds: the MAV is the sphere of its radius centred in the flight plane, as for ``bullet``.
"""

from __future__ import annotations

import numpy as np

from pbdyn.errors import ConfigError, check_positive
from pbdyn.metrics.sampling import plane_points, step_window

CHUNK_POINTS = 400_000
"""Upper bound on the sample x step points of one query (memory)."""


def survival_times_mesh(rollout, points, *, mav_radius: float = 1.0, t_max: float = 12.0,
                        start_time: float = 0.0) -> np.ndarray:
    """Survival time (s, relative to ``start_time``) of a static MAV at each point [n, d] (m) among an imported
    world's moving bodies, by signed distances to their real shapes: the first step t_k = start_time + k dt,
    k = 0..floor(t_max / dt), with distance < mav_radius gives k dt; never hit gives t_max.

    ConfigError for a rollout that is not an imported world (generated obstacles are discs/balls: use
    ``analytic``); HorizonError past the rollout's horizon."""
    bodies = getattr(rollout, "bodies", None)
    if bodies is None:
        raise ConfigError("backend", "the mesh backend works on imported worlds ([[bodies]]); generated "
                          "obstacles are discs/balls: use analytic or bullet", "mesh")
    mav_radius = check_positive("mav_radius", mav_radius)
    k0, n_steps = step_window(rollout, start_time, t_max)
    pts = np.asarray(points, dtype=float).reshape(-1, rollout.dims)
    out = np.full(pts.shape[0], float(t_max))
    moving = bodies.moving_index.tolist()
    if pts.shape[0] == 0 or not moving:
        return out
    field = bodies.field()
    p3 = plane_points(rollout, pts)
    first = np.full(pts.shape[0], -1, dtype=np.int64)
    alive = np.arange(pts.shape[0])
    k = 0
    while k <= n_steps and alive.size:
        chunk = max(1, CHUNK_POINTS // alive.size)
        stop = min(n_steps + 1, k + chunk)
        steps = np.arange(k0 + k, k0 + stop)                                   # [c]
        q = np.broadcast_to(p3[alive][None, :, :], (steps.size, alive.size, 3)).reshape(-1, 3)
        s = np.repeat(steps, alive.size)
        dist = np.full(q.shape[0], np.inf)
        for b in moving:
            dist = np.minimum(dist, field.body_distance(b, q, s))
        hit = (dist < mav_radius).reshape(steps.size, alive.size)
        got = hit.any(axis=0)
        first[alive[got]] = k + np.argmax(hit[:, got], axis=0)
        alive = alive[~got]
        k = stop
    done = first >= 0
    out[done] = np.minimum(first[done] * rollout.dt, float(t_max))
    return out
