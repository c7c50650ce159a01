"""Ray-cast perception (thesis 2-4-2): detect dynamic obstacles in the FOV and update the occupancy grid.

Rays are cast in the PyBullet world from the MAV centre; a ray stops at the first body it meets (occlusion is
real). A dynamic obstacle hit by any ray is detected, and its measurement is its true centre as the world holds it
(plus optional Gaussian noise) -- the thesis' "no perception error" with perfect data association. Every ray frees
the cells of samples taken every <= res/4 along it up to its hit (or full range); a ray ending on a static body or
wall marks the cell just behind its hit point OCCUPIED; dynamic obstacles are tracked, never mapped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pbdyn.errors import ConfigError
from pbdyn.perception.grid import OccupancyGrid
from pbdyn.perception.sensor import ray_directions

OCCUPIED_NUDGE = 1e-3
"""Distance (m) past a static hit point used to pick the cell marked OCCUPIED."""


@dataclass(frozen=True)
class Detections:
    """One scan's result.

    ids: obstacle indices seen (int64 [m], sorted ascending, unique). centers: their centres [m, d] (m, world
    frame; true centres plus the sensor noise). n_rays: rays cast. hits: per-ray body ids (int64 [R], -1 = none).
    ranges: per-ray distance to the hit, or the sensor range for no hit (m, [R]).
    """

    ids: np.ndarray
    centers: np.ndarray
    n_rays: int
    hits: np.ndarray
    ranges: np.ndarray


class Perception:
    """The MAV's depth sensor over a PyBulletWorld, writing into an OccupancyGrid.

    fov_deg / resolution_deg: horizontal field of view and ray spacing (deg; FullRange uses fov_deg = 360).
    range_m: sensor range (m). noise_std: std (m) of the Gaussian noise added to each measured centre (needs rng).
    vfov_deg / vresolution_deg (3D only): vertical field of view and spacing (deg); defaults 60 and resolution_deg.
    Free space is sampled along each ray every <= grid.res / 4.
    """

    def __init__(self, world, grid: OccupancyGrid, *, fov_deg: float, range_m: float, resolution_deg: float,
                 noise_std: float = 0.0, rng: np.random.Generator | None = None, vfov_deg: float | None = None,
                 vresolution_deg: float | None = None):
        for name, value in (("sensor.fov_deg", fov_deg), ("sensor.range", range_m),
                            ("sensor.resolution_deg", resolution_deg)):
            if not (math.isfinite(float(value)) and float(value) > 0):
                raise ConfigError(name, "must be a finite number > 0", value)
        if float(fov_deg) > 360.0:
            raise ConfigError("sensor.fov_deg", "must be <= 360", fov_deg)
        if not (math.isfinite(float(noise_std)) and float(noise_std) >= 0):
            raise ConfigError("sensor.noise_std", "must be a finite number >= 0", noise_std)
        if noise_std > 0 and rng is None:
            raise ConfigError("sensor.noise_std", "needs an np.random.Generator (rng) when > 0", noise_std)
        if grid.dims != world.dims:
            raise ConfigError("grid", f"has {grid.dims} dimensions, the world {world.dims}", grid.dims)
        self.world = world
        self.grid = grid
        self.dims = world.dims
        self.fov_deg = float(fov_deg)
        self.range_m = float(range_m)
        self.resolution_deg = float(resolution_deg)
        self.noise_std = float(noise_std)
        self.rng = rng
        if self.dims == 3:
            self.vfov_deg = 60.0 if vfov_deg is None else float(vfov_deg)
            self.vresolution_deg = self.resolution_deg if vresolution_deg is None else float(vresolution_deg)
        else:
            self.vfov_deg = self.vresolution_deg = None
        base = ray_directions(0.0, self.fov_deg, self.resolution_deg, self.dims, self.vfov_deg, self.vresolution_deg)
        self.n_rays = int(base.shape[0])
        self._base_t = np.ascontiguousarray(base.T)                 # [d, R], yaw 0
        n_samples = int(math.ceil(self.range_m / (grid.res / 4.0)))
        self._t = np.linspace(0.0, self.range_m, n_samples + 1)     # free-space sample distances along a ray (m)
        self._t_cells = self._t / grid.res
        self._rot = np.eye(self.dims)
        self._starts = np.empty((self.n_rays, 3))
        self._ends = np.empty((self.n_rays, 3))
        self._cell_seen = np.zeros(grid.cells.size, dtype=bool)
        self._obstacle_seen = np.zeros(world.obstacle_ids.shape[0] + 1, dtype=bool)

    def _rotated(self, yaw: float) -> np.ndarray:
        """Ray directions as [d, R] for ``yaw`` (rad)."""
        c, s = math.cos(yaw), math.sin(yaw)
        rot = self._rot
        rot[0, 0] = rot[1, 1] = c
        rot[1, 0] = s
        rot[0, 1] = -s
        return rot @ self._base_t

    def _mark_free(self, o: np.ndarray, dirs_t: np.ndarray, reach: np.ndarray) -> None:
        """Mark FREE the cells of the samples along each ray r (dirs_t: [d, R]) up to just before reach[r] (m).

        Samples lie every <= res/4 from the origin; those past a ray's hit collapse onto the point just before it.
        Cells are computed on [d, R, S] arrays (numpy is slow on a tiny last axis) and de-duplicated through a
        scratch mask, so grid.mark_free sees each cell once.
        """
        grid = self.grid
        inv = 1.0 / grid.res
        dist = np.minimum(self._t_cells, (reach * inv - 1e-9)[:, None])          # [R, S], cell units
        pts = dirs_t[:, :, None] * dist                                          # [d, R, S]
        pts += ((o - grid.origin) * inv)[:, None, None]                           # from the grid's corner
        idx = pts.astype(np.int64)        # truncation == floor for the non-negative in-grid values
        shape = grid.shape
        if np.any(o - self.range_m < grid.origin) or np.any(o + self.range_m >= grid.origin + np.asarray(shape) *
                                                             grid.res):
            np.clip(idx, 0, np.reshape(shape, (-1, 1, 1)) - 1, out=idx)   # the scan may leave the grid
        flat = idx[0]
        for k in range(1, self.dims):
            flat = flat * shape[k] + idx[k]
        seen = self._cell_seen
        seen[flat.ravel()] = True
        cells = np.flatnonzero(seen)
        seen[cells] = False
        grid.mark_free(grid.cell_center(np.stack(np.unravel_index(cells, shape), axis=-1)))

    def directions(self, yaw: float) -> np.ndarray:
        """Unit ray directions [R, d] for ``yaw`` (rad)."""
        return self._rotated(yaw).T.copy()

    def set_obstacle_positions(self, positions) -> None:
        """Move the world's dynamic obstacles (same as world.set_obstacle_positions)."""
        self.world.set_obstacle_positions(positions)

    def sense(self, position, yaw: float) -> Detections:
        """Scan from ``position`` [d] (m) looking along ``yaw`` (rad): detections, and the grid updated in place."""
        world, grid = self.world, self.grid
        o = np.asarray(position, dtype=float).reshape(self.dims)
        dirs_t = self._rotated(yaw)                                       # [d, R]
        origin3 = world.to_world3(o)
        starts, ends = self._starts, self._ends
        starts[:] = origin3
        ends[:] = origin3
        ends[:, : self.dims] += self.range_m * dirs_t.T
        hits, frac = world.cast_rays(starts, ends)
        ranges = frac * self.range_m
        self._mark_free(o, dirs_t, np.where(hits >= 0, ranges, np.inf))

        static = world.is_static_body[hits]
        if static.any():
            grid.mark_occupied(o + dirs_t.T[static] * (ranges[static] + OCCUPIED_NUDGE)[:, None])

        flags = self._obstacle_seen            # index -1 (no obstacle) lands on the spare last entry
        flags[world.dynamic_index_of[hits]] = True
        ids = np.flatnonzero(flags[:-1])
        flags[:] = False
        centers = np.asarray(world.obstacle_positions, dtype=float)[ids]
        if self.noise_std > 0 and ids.shape[0]:
            centers = centers + self.rng.normal(0.0, self.noise_std, size=centers.shape)
        return Detections(ids.astype(np.int64), centers, int(hits.shape[0]), hits, ranges)
