"""Ray-cast perception (thesis 2-4-2): detect dynamic obstacles in the FOV and update the occupancy grid.

Rays are cast in the PyBullet world from the MAV centre; a ray stops at the first body it meets (occlusion is
real). A dynamic obstacle hit by any ray is detected, and its measurement is its true centre as the world holds it
(plus optional Gaussian noise) -- the thesis' "no perception error" with perfect data association. Every ray frees
the cells of samples taken every <= res/4 along it up to its hit (or full range); a ray ending on a static body or
wall marks the cell just behind its hit point OCCUPIED; dynamic obstacles are tracked, never mapped.

That is the sensor model "raycast"; ``model`` names another of pbdyn.perception.registry.SENSORS, e.g. "marching",
the thesis program's sensor (docs/thesis-program.md "MAV, sensing, tracking"; pbdyn.perception.marching).
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from pbdyn.config import SensorConfig
from pbdyn.errors import ConfigError
from pbdyn.jit import njit
from pbdyn.perception.grid import OccupancyGrid
from pbdyn.perception.registry import SENSORS

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


class PendingScan(NamedTuple):
    """A scan begun (Perception.begin) and not yet completed: sensor origin [d] (m), ray directions [d, R] and the
    fan's rays to cast (pbdyn.world.bullet.FanRays)."""

    origin: np.ndarray
    dirs_t: np.ndarray
    fan: object


_SCRATCH: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _scratch(world, key: tuple, make):
    """The scratch array ``key`` of ``world``, made by ``make()`` on first use: one per world, shared by all of its
    Perceptions (a world is used by one thread, and a scan never interleaves with another)."""
    try:
        pool = _SCRATCH.setdefault(world, {})
    except TypeError:                  # a world that cannot be weakly referenced keeps private buffers
        return make()
    arr = pool.get(key)
    if arr is None:
        arr = pool[key] = make()
    return arr


class Perception:
    """The MAV's depth sensor over a PyBulletWorld, writing into an OccupancyGrid.

    fov_deg / resolution_deg: horizontal field of view and ray spacing (deg; FullRange uses fov_deg = 360).
    range_m: sensor range (m). noise_std: std (m) of the Gaussian noise added to each measured centre (needs rng).
    vfov_deg / vresolution_deg (3D only): vertical field of view and spacing (deg); defaults 60 and resolution_deg.
    Free space is sampled along each ray every <= grid.res / 4.
    model: the sensor model's name in pbdyn.perception.registry.SENSORS (module doc), built as ``sensor``; the
    marching model's parameters: rays (per horizontal fan), march_step (m), march_rule (pbdyn.perception.marching).
    """

    def __init__(self, world, grid: OccupancyGrid, *, fov_deg: float, range_m: float, resolution_deg: float,
                 noise_std: float = 0.0, rng: np.random.Generator | None = None, vfov_deg: float | None = None,
                 vresolution_deg: float | None = None, model: str = "raycast", rays: int | None = None,
                 march_step: float = 0.9, march_rule: str = "ray"):
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
        if model not in SENSORS:
            raise ConfigError("sensor.model", f"must be one of {', '.join(SENSORS)}", model)
        if rays is not None and (not isinstance(rays, (int, np.integer)) or isinstance(rays, bool) or rays < 1):
            raise ConfigError("sensor.rays", "must be an integer >= 1 (or None)", rays)
        if (isinstance(march_step, bool) or not isinstance(march_step, (int, float))
                or not (math.isfinite(float(march_step)) and float(march_step) > 0)):
            raise ConfigError("sensor.march_step", "must be a finite number > 0", march_step)
        if march_rule not in SensorConfig.MARCH_RULES:
            raise ConfigError("sensor.march_rule", f"must be one of {', '.join(SensorConfig.MARCH_RULES)}", march_rule)
        self.model = model
        self.march_step = float(march_step)
        self.march_rule = march_rule
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
        self.rays = None if rays is None else int(rays)
        self.sensor = SENSORS[model](self)
        base = self.sensor.fan()
        self.n_rays = int(base.shape[0])
        self._base_t = np.ascontiguousarray(base.T)                 # [d, R], yaw 0
        n_samples = int(math.ceil(self.range_m / (grid.res / 4.0)))
        self._t = np.linspace(0.0, self.range_m, n_samples + 1)     # free-space sample distances along a ray (m)
        self._t_cells = self._t / grid.res
        self._rot = np.eye(self.dims)
        # Scratch buffers of the free-space marking, reused by every scan: [d, S, R] so the long ray axis is the
        # contiguous one (numpy's inner loops), cell indices as int32 (fast float casts), flat indices as intp.
        # Shared by every Perception of this world (scans run one at a time; lockstep trials would otherwise each
        # keep megabytes of their own in 3D and evict one another from the CPU caches).
        shape_dsr = (self.dims, self._t.shape[0], self.n_rays)
        cell_dtype = np.int32 if grid.cells.size < 2**31 else np.int64
        self._t_full = np.ascontiguousarray(np.broadcast_to(self._t_cells[:, None], shape_dsr[1:]))
        self._dist = _scratch(world, ("dist", shape_dsr), lambda: np.empty(shape_dsr[1:]))
        self._samples = _scratch(world, ("samples", shape_dsr), lambda: np.empty(shape_dsr))
        self._cells_of = _scratch(world, ("cells_of", shape_dsr, cell_dtype),
                                  lambda: np.empty(shape_dsr, dtype=cell_dtype))
        self._flat_small = _scratch(world, ("flat_small", shape_dsr, cell_dtype),
                                    lambda: np.empty(shape_dsr[1:], dtype=cell_dtype))
        self._flat = _scratch(world, ("flat", shape_dsr), lambda: np.empty(shape_dsr[1:], dtype=np.intp))
        self._cell_seen = _scratch(world, ("cell_seen", grid.cells.size),           # all False between scans
                                   lambda: np.zeros(grid.cells.size, dtype=bool))
        self._slab = grid.cells.size // grid.shape[0]                 # cells per index along axis 0
        self._grid_top = np.asarray(grid.shape, dtype=float)
        n_flags = world.obstacle_ids.shape[0] + 1
        self._obstacle_seen = _scratch(world, ("obstacle_seen", n_flags),              # all False between scans
                                       lambda: np.zeros(n_flags, dtype=bool))

    def _rotated(self, yaw: float) -> np.ndarray:
        """Ray directions as [d, R] for ``yaw`` (rad)."""
        c, s = math.cos(yaw), math.sin(yaw)
        rot = self._rot
        rot[0, 0] = rot[1, 1] = c
        rot[1, 0] = s
        rot[0, 1] = -s
        return rot @ self._base_t

    def free_cells(self, o: np.ndarray, dirs_t: np.ndarray, reach: np.ndarray) -> np.ndarray:
        """Flat C-order indices (sorted, unique) of the grid cells the free-space samples of one scan fall in.

        o: sensor position [d] (m); dirs_t: unit ray directions [d, R]; reach: per-ray hit distance (m; inf for
        no hit). Sampling rule: ray r is sampled at the distances min(t_j, reach[r] - 1e-9 res) with
        t_j = j * range / n, j = 0..n, n = ceil(range / (res / 4)) (spacing <= res / 4): every sample up to the
        hit, and those past it collapse onto the point just before it. A sample's cell is, in cell units,
        floor((o - grid.origin) / res + u_r * dist / res), clipped into the grid (the float operations in that order).
        """
        grid = self.grid
        inv = 1.0 / grid.res
        oc = (o - grid.origin) * inv                                   # the sensor, cell units from cell 0's corner
        lim = reach * inv - 1e-9
        if np.any(lim < self._t_cells[-1]):
            dist = np.minimum(self._t_cells[:, None], lim, out=self._dist)                # [S, R]
        else:
            dist = self._t_full
        pts = np.multiply(dirs_t[:, None, :], dist, out=self._samples)                    # [d, S, R]
        pts += oc[:, None, None]
        idx = self._cells_of
        np.copyto(idx, pts, casting="unsafe")   # truncation: == floor for the in-grid (non-negative) coordinates
        # Per axis the samples of a ray are monotone, so a ray's first and last sample bound the others (rounding
        # included): clip only if, on an axis the sensor's reach leaves the grid along, one of those is outside.
        top = self._grid_top
        span = self.range_m * inv
        for k in np.flatnonzero((oc - span < 1e-6) | (oc + span > top - 1e-6)).tolist():
            ends = pts[k, -1]
            if not (0.0 <= oc[k] < top[k]) or ends.min() < 0.0 or ends.max() >= top[k]:
                np.clip(idx, 0, (top.astype(idx.dtype) - 1)[:, None, None], out=idx)
                break
        shape = grid.shape
        small = np.multiply(idx[0], shape[1], out=self._flat_small)
        small += idx[1]
        for k in range(2, self.dims):
            small *= shape[k]
            small += idx[k]
        flat = self._flat
        np.copyto(flat, small)                                         # numpy scatters fastest with intp indices
        seen = self._cell_seen
        seen[flat.reshape(-1)] = True
        # Only the slabs of axis-0 cells the sensor reaches can hold samples (clipped ones included).
        first = min(max(math.floor(oc[0] - span) - 1, 0), shape[0] - 1) * self._slab
        last = (max(min(math.floor(oc[0] + span) + 1, shape[0] - 1), 0) + 1) * self._slab
        cells = np.flatnonzero(seen[first:last])
        cells += first
        seen[cells] = False
        return cells

    def directions(self, yaw: float) -> np.ndarray:
        """Unit ray directions [R, d] for ``yaw`` (rad)."""
        return self._rotated(yaw).T.copy()

    def sense(self, position, yaw: float) -> Detections:
        """Scan from ``position`` [d] (m) looking along ``yaw`` (rad): detections, and the grid updated in place."""
        scan = self.begin(position, yaw)
        if isinstance(scan, Detections):
            return scan
        return self.complete(scan, *self.world.cast_fan_rays(scan.fan))

    def begin(self, position, yaw: float):
        """The first half of sense(): the scan's rays (a PendingScan, to cast with world.cast_fans, possibly with
        other MAVs' fans in one call, then complete()), or the finished Detections (a model that casts no Bullet
        rays, e.g. "marching")."""
        frame = self.begin_frame(position, yaw)
        if isinstance(frame, Detections):
            return frame
        o, dirs_t = frame
        return PendingScan(o, dirs_t, self.world.fan_rays(o, dirs_t.T, self.range_m))

    def begin_frame(self, position, yaw: float):
        """begin() up to the rays: the sensor origin [d] and the ray directions [d, R], to make a PendingScan of
        with world.fan_rays (or world.fan_rays_many, several MAVs' fans culled together); or the finished
        Detections (a model's own scan, SensorModel.scan)."""
        o = np.asarray(position, dtype=float).reshape(self.dims)
        dirs_t = self._rotated(yaw)                                       # [d, R]
        seen = self.sensor.scan(o, dirs_t)
        return (o, dirs_t) if seen is None else self._detections(*seen)

    def complete(self, scan: "PendingScan", hits: np.ndarray, frac: np.ndarray) -> Detections:
        """The second half of sense(): the detections of ``scan`` from its fan's per-ray results (body ids [R],
        fractions [R]; world.cast_fans), and the grid updated in place."""
        world, grid = self.world, self.grid
        o, dirs_t = scan.origin, scan.dirs_t
        if not grid.cells.flags.c_contiguous:
            return self._complete_reference(scan, hits, frac)
        ranges, ids, newly_occupied = _complete_scan(
            grid.cells.reshape(-1), np.asarray(grid.shape, dtype=np.int64), o, grid.origin, grid.res, dirs_t,
            self._t_cells, np.asarray(hits, dtype=np.int64), frac, self.range_m, world.is_static_body,
            world.dynamic_index_of, world.obstacle_ids.shape[0])
        if newly_occupied:
            grid.version += 1
        return self._detections(ids, hits, ranges)

    def _detections(self, ids: np.ndarray, hits: np.ndarray, ranges: np.ndarray) -> Detections:
        """The Detections of a scan that saw obstacles ``ids``: their centres as the world holds them, plus the
        sensor noise."""
        centers = np.asarray(self.world.obstacle_positions, dtype=float)[ids]
        if self.noise_std > 0 and ids.shape[0]:
            centers = centers + self.rng.normal(0.0, self.noise_std, size=centers.shape)
        return Detections(ids, centers, int(hits.shape[0]), hits, ranges)

    def _complete_reference(self, scan: "PendingScan", hits: np.ndarray, frac: np.ndarray) -> Detections:
        """complete() in numpy: the reference twin of the compiled _complete_scan (the same grid and detections),
        used for a grid whose cells are not contiguous."""
        world, grid = self.world, self.grid
        o, dirs_t = scan.origin, scan.dirs_t
        ranges = frac * self.range_m
        grid.mark_free_cells(self.free_cells(o, dirs_t, np.where(hits >= 0, ranges, np.inf)))

        static = np.flatnonzero(world.is_static_body[hits])
        if static.shape[0]:
            grid.mark_occupied(o + dirs_t[:, static].T * (ranges[static] + OCCUPIED_NUDGE)[:, None])

        flags = self._obstacle_seen            # index -1 (no obstacle) lands on the spare last entry
        flags[world.dynamic_index_of[hits]] = True
        ids = np.flatnonzero(flags[:-1])
        flags[:] = False
        return self._detections(ids.astype(np.int64), hits, ranges)


@njit(cache=True, nogil=True)
def _mark_free_samples(cells, shape, oc, dirs_t, lim, t_cells):
    """The free-space marking of a scan (the cells Perception.free_cells lists) in compiled code: for ray r
    (direction dirs_t[:, r]) and sample distance t (cell units, t_cells), the sample oc + dirs_t[:, r] * min(t, lim[r])
    (cell units from cell 0's corner) lies in the cell floor() of it, clipped into the grid; each such cell of
    ``cells`` (flat, C order, of ``shape``) becomes FREE unless it is OCCUPIED (free_cells' float operations, in its
    order). The samples past lim[r], all in the cell of the first one, are visited once; a ray's cell indices are
    formed axis by axis over its samples (loops the compiler vectorises), then marked."""
    d, n_rays = dirs_t.shape
    n_t = t_cells.shape[0]
    flat = np.empty(n_t, dtype=np.int64)
    for r in range(n_rays):
        lr = lim[r]
        n_use = n_t
        for s in range(n_t):
            if t_cells[s] >= lr:            # t_cells ascend: this and every later sample lie at lim[r]
                n_use = s + 1
                break
        for s in range(n_use):
            flat[s] = 0
        for k in range(d):
            dk, ok, top, size = dirs_t[k, r], oc[k], shape[k] - 1, shape[k]
            for s in range(n_use):
                t = t_cells[s]
                dist = lr if t >= lr else min(t, lr)
                i = np.int64(np.floor(dk * dist + ok))
                flat[s] = flat[s] * size + min(max(i, 0), top)
        for s in range(n_use):
            if cells[flat[s]] < 0:
                cells[flat[s]] = 0


@njit(cache=True, nogil=True)
def _complete_scan(cells, shape, o, origin, res, dirs_t, t_cells, hits, frac, range_m, is_static, dynamic_index,
                   n_obstacles):
    """Perception.complete's grid update and detections in compiled code, with the float operations of its reference
    twin Perception._complete_reference: ranges = frac * range_m; the free-space samples of every ray up to its hit
    (_mark_free_samples), then the cell (grid.index: floor((p - origin) / res), clipped) of o + u (range +
    OCCUPIED_NUDGE) of every ray ending on a static body or wall marked OCCUPIED; the obstacles hit, ascending. Body ids
    index is_static / dynamic_index (-1, no body, their last entry). Returns (ranges [R], obstacle ids, whether a cell
    became OCCUPIED)."""
    d, n_rays = dirs_t.shape
    if hits.shape[0] != n_rays or frac.shape[0] != n_rays or o.shape[0] != d or origin.shape[0] != d:
        raise ValueError("complete: mismatched scan shapes")
    n_lookup = is_static.shape[0]
    inv = 1.0 / res
    ranges = frac * range_m
    lim = np.empty(n_rays)
    for r in range(n_rays):
        h = hits[r]
        if h < -1 or h >= n_lookup:
            raise IndexError("a ray hit a body the world does not know")
        lim[r] = (ranges[r] if h >= 0 else np.inf) * inv - 1e-9
    oc = (o - origin) * inv
    _mark_free_samples(cells, shape, oc, dirs_t, lim, t_cells)
    newly = False
    seen = np.zeros(n_obstacles + 1, dtype=np.bool_)
    for r in range(n_rays):
        h = hits[r]
        if is_static[h]:
            dist = ranges[r] + OCCUPIED_NUDGE
            flat = 0
            for k in range(d):
                i = np.int64(np.floor((o[k] + dirs_t[k, r] * dist - origin[k]) / res))
                i = min(max(i, 0), shape[k] - 1)
                flat = flat * shape[k] + i
            if cells[flat] != 1:
                cells[flat] = 1
                newly = True
        seen[dynamic_index[h]] = True
    n_ids = 0
    for m in range(n_obstacles):
        n_ids += seen[m]
    ids = np.empty(n_ids, dtype=np.int64)
    n_ids = 0
    for m in range(n_obstacles):
        if seen[m]:
            ids[n_ids] = m
            n_ids += 1
    return ranges, ids, newly
