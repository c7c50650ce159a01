"""A template sensor model for pbdyn: copy this file, rename the class, and change ``scan``.

A sensor model decides what one scan of the MAV's depth sensor sees (thesis 2-4-2); the Perception that holds it
(pbdyn.perception.perceive) keeps the rest: the sensor's parameters, the turn of the ray fan to the MAV's yaw, the
occupancy grid and the noise of the detections. It follows ``pbdyn.perception.registry.SensorModel``:

    Model(perception): built once per trial, after the perception's parameters are set. Inputs: perception.world
        (pbdyn.world.bullet.PyBulletWorld: obstacle_positions [N, d] (m, world frame, where the trial put them),
        obstacle_radii [N] (m), arena_size [d] (m: walls outside [0, L_k] on every axis), obstacle_ids,
        static_ids, wall_ids (PyBullet body ids; walls in the order low x, high x, low y, high y[, low z, high z])),
        perception.grid (pbdyn.perception.grid.OccupancyGrid, cells of res m), dims d, fov_deg, resolution_deg,
        vfov_deg, vresolution_deg (deg; the vertical ones 3D only), range_m (m). Raise ConfigError naming
        "sensor.model" for a world the model cannot see.
    fan() -> unit ray directions [R, d] of the sensor looking along +x (yaw 0), world frame.
    scan(origin, dirs_t) -> (ids, hits, ranges): one scan from origin [d] (m, world frame) along dirs_t [d, R], the
        fan turned to the MAV's yaw (unit vectors, world frame). Marks what it saw in perception.grid (mark_free /
        mark_occupied of world points [n, d], m) and returns ids: the obstacles seen (int64 [m], ascending, unique:
        indices into obstacle_positions); hits: per ray the body id it ends on (int64 [R], -1 for none); ranges:
        per ray the distance to that body, or range_m for none ([R], m). (Returning None instead has the
        Perception cast the fan in PyBullet, as the built-in "raycast" does.)

DiscCaster is deliberately simple but real: it intersects every ray in closed form with the obstacles' discs (2D) or
balls (3D) and the arena's walls, nearest first (an obstacle hides what is behind it), without PyBullet; it cannot
see static bodies, so it refuses worlds that have them. Free space is marked every res / 4 along each ray up to
its hit, and a wall's cell just behind the hit OCCUPIED, as the built-in sensor does.

Sensor models are built in (docs/architecture.md "Where each extension goes"): put the module in
pbdyn/perception/, add one entry to SENSORS in pbdyn/perception/registry.py and its name to
pbdyn.config.SensorConfig.MODELS; a scenario then names it as ``[sensor] model = "disc_caster"``.
"""

from __future__ import annotations

import numpy as np

from pbdyn.errors import ConfigError
from pbdyn.perception.sensor import ray_directions


class DiscCaster:
    """Closed-form rays against discs/balls and walls (see the module docstring)."""

    WALL_NUDGE = 1e-3
    """Distance (m) past a wall hit whose cell is marked OCCUPIED."""

    def __init__(self, perception):
        n_static = int(perception.world.static_ids.shape[0])
        if n_static:
            raise ConfigError("sensor.model", f'"disc_caster" sees obstacles and walls only; this world has {n_static} '
                              'static bodies (use "raycast")', "disc_caster")
        self.perception = perception

    def fan(self) -> np.ndarray:
        """The fan of pbdyn.perception.sensor.ray_directions at yaw 0: [R, d] unit vectors."""
        p = self.perception
        return ray_directions(0.0, p.fov_deg, p.resolution_deg, p.dims, p.vfov_deg, p.vresolution_deg)

    def scan(self, origin: np.ndarray, dirs_t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ids, hits, ranges) of one scan, the grid marked (module docstring)."""
        p = self.perception
        world, grid, range_m = p.world, p.grid, p.range_m
        n_rays = dirs_t.shape[1]
        # obstacles: the smaller root of |origin + t u - c|^2 = r^2 per obstacle and ray (0 from inside)
        rel = np.asarray(world.obstacle_positions, dtype=float) - origin[None, :]         # [N, d] (m)
        b = rel @ dirs_t                                                                   # [N, R] (m)
        c = np.einsum("nd,nd->n", rel, rel) - world.obstacle_radii ** 2                   # [N] (m^2)
        disc = b * b - c[:, None]
        t = b - np.sqrt(np.maximum(disc, 0.0))
        t = np.where(c[:, None] <= 0.0, 0.0, np.where((disc >= 0.0) & (t >= 0.0), t, np.inf))
        t_obs = t.min(axis=0, initial=np.inf)                                             # [R] (m)
        which = np.argmin(t, axis=0) if t.shape[0] else np.zeros(n_rays, dtype=np.int64)
        # walls: the first coordinate to leave [0, L_k]
        size = np.asarray(world.arena_size, dtype=float)[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            t_side = np.stack([np.where(dirs_t < 0.0, -origin[:, None] / dirs_t, np.inf),
                               np.where(dirs_t > 0.0, (size - origin[:, None]) / dirs_t, np.inf)], axis=1)
        t_side = t_side.reshape(-1, n_rays)                                               # [2d, R]: 2 axis + side
        wall = np.argmin(t_side, axis=0)
        t_wall = t_side[wall, np.arange(n_rays)]
        t_hit = np.minimum(t_obs, t_wall)
        obstacle = (t_obs <= t_wall) & (t_obs <= range_m)
        on_wall = ~obstacle & (t_wall <= range_m)
        hits = np.full(n_rays, -1, dtype=np.int64)
        hits[obstacle] = world.obstacle_ids[which[obstacle]]
        hits[on_wall] = world.wall_ids[wall[on_wall]]
        ranges = np.where(obstacle | on_wall, t_hit, range_m)
        # the grid: free samples every res / 4 up to each hit, the cell behind a wall hit occupied
        steps = np.arange(0.0, range_m + 1e-9, grid.res / 4.0)                          # [S] (m)
        along = np.minimum(steps[None, :], ranges[:, None] - 1e-9)                       # [R, S] (m)
        grid.mark_free(origin[None, None, :] + dirs_t.T[:, None, :] * along[:, :, None])
        if on_wall.any():
            grid.mark_occupied(origin[None, :] + dirs_t.T[on_wall] * (t_wall[on_wall] + self.WALL_NUDGE)[:, None])
        return np.unique(which[obstacle]).astype(np.int64), hits, ranges
