"""The PyBullet world: the MAV, dynamic obstacles, static bodies and walls as collision geometry (docs/design.md).

Poses are set, then queried (ray tests, closest points); stepSimulation is never called. One BulletClient per
world, created in the process that uses it (never fork after creating a world, never share it across threads).

2D worlds (the MAV in the plane z = flight_height, "h"): dynamic obstacles and static pillars are vertical
cylinders spanning the flight band [0, 2h] (their visual shape). Their *collision* shape is, by default, the
sphere of the same radius centred in the flight plane: every query pbdyn makes in 2D lies in that plane (rays at
z = h, the MAV sphere centred at z = h), where the sphere's and the cylinder's cross-sections are the same disc,
so all results are identical -- while Bullet 3.2.7 ray tests against cylinders cost ~8 us per hit against
~0.6 us for spheres. ``exact_pillars=True`` loads true cylinders instead. Walls are boxes just outside the arena.
3D worlds: obstacles are spheres, static pillars span the full height, 6 walls (floor and ceiling included).

Body ids are the small consecutive integers PyBullet assigns: the MAV first, then the obstacles in index order,
then static bodies, then walls.

Sensor fans go through cast_fan, which sends Bullet only the rays that can meet a body (fan_candidates: bounding
spheres of the obstacles, AABBs of static bodies, the arena box for the walls); the others are known misses, so
the results equal casting every ray, at a fraction of the cost (Bullet's ray test costs ~0.5-1.5 us per ray).

Bodies are loaded from URDF files scaled at load (pbdyn.world.imported.urdf_loading); the client, its quiet import
and the GUI's display check are pbdyn.world.pybullet_client's.
"""

from __future__ import annotations

import contextlib
import functools
import math
import operator
import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

from pbdyn.errors import ConfigError, check_positive
from pbdyn.jit import njit
from pbdyn.world.geometry import StaticBody
from pbdyn.world.imported.urdf_loading import IDENTITY_QUATERNION, load_scaled_urdf, urdf_path
from pbdyn.world.pybullet_client import new_client, pybullet, stdout_to_stderr

RAY_BATCH = 16383
"""Rays per rayTestBatch call (PyBullet refuses batches of 16384 or more)."""

MAV_GROUP = 0x100
"""Collision filter group bit of the MAV; ray tests mask it out so they never report the MAV."""

CULL_PAD = 0.05
"""Margin (m) added to every body's bound when cast_fan decides which rays cannot hit anything."""

_RAY_MASK = ~MAV_GROUP
_BODY_ID = operator.itemgetter(0)
_HIT_FRACTION = operator.itemgetter(2)
_NONE, _MAV, _DYNAMIC, _STATIC, _WALL = 0, 1, 2, 3, 4
_KIND_NAMES = ("none", "mav", "dynamic", "static", "wall")


def yaw_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """Quaternion (x, y, z, w) of a rotation by ``yaw`` (rad) about the world z axis."""
    return (0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw))


class FanRays(NamedTuple):
    """The rays of one sensor fan that need Bullet (PyBulletWorld.fan_rays): n_rays of the fan, the indices of the
    ones kept (None: all), and their start and end points [k, 3] (m, world frame)."""

    n_rays: int
    selected: np.ndarray | None
    starts: np.ndarray
    ends: np.ndarray


class PyBulletWorld:
    """Collision geometry of one trial or metric run, in one PyBullet client (SI units, world frame, z-up).

    Keyword-only arguments:
        dims: 2 or 3. arena_size: [d] (m); the arena is [0, L] per axis.
        flight_height: the 2D flight plane z = h (m); the 2D band is [0, 2h]. Unused in 3D.
        mav_radius: MAV collision sphere radius (m). obstacle_radii: [N] (m), dynamic obstacles.
        static_bodies: StaticBody list (pillars, boxes). mav_urdf: the MAV model (default urdf/quadrotor.urdf;
        loaded scaled uniformly by mav_radius). wall_thickness: (m). gui: PyBullet GUI instead of DIRECT.
        exact_pillars: load 2D pillars with cylinder collision shapes instead of the equivalent spheres.
        client: an existing BulletClient to reuse (it is reset, then filled with this world; close() leaves it
        connected) -- one client per batch worker for every map it flies.

    Public attributes: client, dims, mav_id, obstacle_ids (int64 [N]), static_ids, wall_ids (int64), arena_size,
    flight_height, mav_radius, obstacle_radii, obstacle_positions ([N, d], the last positions set; obstacles start
    parked far outside the arena), mav_position [d], mav_yaw, dynamic_index_of / is_static_body (see body_kind).
    """

    def __init__(self, *, dims: int, arena_size: Sequence[float], flight_height: float = 2.0, mav_radius: float,
                 obstacle_radii, static_bodies: Sequence[StaticBody] = (), mav_urdf: str | None = None,
                 wall_thickness: float = 1.0, gui: bool = False, exact_pillars: bool = False, client=None,
                 obstacle_urdfs: Sequence[tuple[str, Sequence[float]]] | None = None):
        if dims not in (2, 3):
            raise ConfigError("dims", "must be 2 or 3", dims)
        self.dims = int(dims)
        size = np.asarray(arena_size, dtype=float).reshape(-1)
        if size.shape != (self.dims,) or np.any(~np.isfinite(size)) or np.any(size <= 0):
            raise ConfigError("arena_size", f"must be {self.dims} finite numbers > 0", tuple(np.ravel(arena_size)))
        self.arena_size = size
        self.flight_height = check_positive("flight_height", flight_height)
        self.mav_radius = check_positive("mav_radius", mav_radius)
        radii = np.asarray(obstacle_radii, dtype=float).reshape(-1)
        if np.any(~np.isfinite(radii)) or np.any(radii <= 0):
            raise ConfigError("obstacle_radii", "must all be finite and > 0", radii.tolist())
        self.obstacle_radii = radii
        if obstacle_urdfs is not None and len(obstacle_urdfs) != radii.shape[0]:
            raise ConfigError("obstacle_urdfs", f"must give one (urdf, scale) per obstacle ({radii.shape[0]})",
                              len(obstacle_urdfs))
        self.obstacle_urdfs = None if obstacle_urdfs is None else tuple(obstacle_urdfs)
        self.wall_thickness = check_positive("wall_thickness", wall_thickness)
        if mav_urdf is not None and not Path(mav_urdf).is_file():
            raise ConfigError("mav_urdf", "file not found", str(mav_urdf))
        self._pid = os.getpid()
        self._owns_client = client is None
        if client is None:
            self.client = new_client(gui)
        else:   # a client lent by the caller (batch workers): emptied, then rebuilt for this world
            self.client = client
            self.client.resetSimulation()
        self._closed = False
        try:
            self._build(mav_urdf, tuple(static_bodies), exact_pillars)
        except BaseException:
            self.close()
            raise

    def _build(self, mav_urdf: str | None, static_bodies: tuple[StaticBody, ...], exact_pillars: bool) -> None:
        try:
            self.client.setPhysicsEngineParameter(numThreads=1)
        except TypeError:  # not a parameter of this PyBullet build
            pass
        self._cid = self.client._client
        self._reset_pose = functools.partial(pybullet.resetBasePositionAndOrientation, physicsClientId=self._cid)
        self._ray_batch = functools.partial(pybullet.rayTestBatch, physicsClientId=self._cid)
        self._closest = functools.partial(pybullet.getClosestPoints, physicsClientId=self._cid)
        self._overlapping = functools.partial(pybullet.getOverlappingObjects, physicsClientId=self._cid)
        self._num_bodies = functools.partial(pybullet.getNumBodies, physicsClientId=self._cid)

        h, size, radii = self.flight_height, self.arena_size, self.obstacle_radii
        # The MAV: mass > 0, its own collision group (rays mask it out), at the arena centre.
        self.mav_position = self._plane_point(0.5 * size)
        self.mav_yaw = 0.0
        self.mav_id = load_scaled_urdf(self.client, mav_urdf or urdf_path("quadrotor"), (self.mav_radius,) * 3,
                                       self.to_world3(self.mav_position))
        self.client.setCollisionFilterGroupMask(self.mav_id, -1, MAV_GROUP, -1)
        self._mav_pose3 = self.to_world3(self.mav_position).tolist()
        self._mav_quat = IDENTITY_QUATERNION
        self._mav_parking = [-1.0e4, -1.0e4, -1.0e4]
        self._probe = self.client.createCollisionShape(pybullet.GEOM_SPHERE, radius=self.mav_radius)

        # Dynamic obstacles, parked far outside the arena until set_obstacle_positions.
        parked = np.zeros((radii.shape[0], self.dims))
        parked[:, 0] = -1.0e4 - 10.0 * (radii.max(initial=0.0) + 1.0) * np.arange(radii.shape[0])
        if self.dims == 2:
            parked[:, 1] = 0.5 * size[1]
        ids = []
        for i, (r, p) in enumerate(zip(radii, parked)):
            if self.obstacle_urdfs is not None:          # an imported world's moving body, by its real shape
                path, scale = self.obstacle_urdfs[i]
                ids.append(load_scaled_urdf(self.client, path, scale, self.to_world3(p)))
            elif self.dims == 2:
                ids.append(load_scaled_urdf(self.client, urdf_path("pillar"), (r, r, 2.0 * h), self.to_world3(p),
                                            cylinders_as_spheres=not exact_pillars))
            else:
                ids.append(load_scaled_urdf(self.client, urdf_path("sphere"), (r, r, r), p))
        self.obstacle_ids = np.asarray(ids, dtype=np.int64)
        self.obstacle_positions = parked

        self.static_bodies = static_bodies
        self.static_ids = np.asarray([self._load_static(b, i, exact_pillars)
                                      for i, b in enumerate(static_bodies)], dtype=np.int64)
        self.wall_ids = np.asarray(self._load_walls(), dtype=np.int64)
        self._build_lookup()

    # ----------------------------------------------------------------------------------------- construction
    def _plane_point(self, p: np.ndarray) -> np.ndarray:
        return np.asarray(p, dtype=float)[: self.dims].copy()

    def _load_static(self, body: StaticBody, i: int, exact_pillars: bool) -> int:
        field = f"static_bodies[{i}]"
        c = np.asarray(body.center, dtype=float).reshape(-1)
        quat = yaw_quaternion(float(body.yaw))
        h, size = self.flight_height, self.arena_size
        if body.kind == "pillar":
            r = check_positive(f"{field}.radius", body.radius)
            if c.shape[0] < 2:
                raise ConfigError(f"{field}.center", "needs x and y", tuple(c))
            if self.dims == 2:
                return load_scaled_urdf(self.client, urdf_path("pillar"), (r, r, 2.0 * h), (c[0], c[1], h), quat,
                                        cylinders_as_spheres=not exact_pillars)
            return load_scaled_urdf(self.client, urdf_path("pillar"), (r, r, size[2]), (c[0], c[1], 0.5 * size[2]),
                                    quat)
        if body.kind == "box":
            ext = np.asarray(body.size, dtype=float).reshape(-1)
            if ext.shape[0] < self.dims or np.any(ext[: self.dims] <= 0) or c.shape[0] < self.dims:
                raise ConfigError(field, f"a box needs {self.dims} positive sizes and a {self.dims}-d center",
                                  (tuple(c), tuple(ext)))
            if self.dims == 2:
                return load_scaled_urdf(self.client, urdf_path("box"), (ext[0], ext[1], 2.0 * h), (c[0], c[1], h),
                                        quat)
            return load_scaled_urdf(self.client, urdf_path("box"), ext[:3], c[:3], quat)
        raise ConfigError(f"{field}.kind", "must be 'pillar' or 'box'", body.kind)

    def _load_walls(self) -> list[int]:
        t, L = self.wall_thickness, self.arena_size
        if self.dims == 2:
            zc, zs = self.flight_height, 2.0 * self.flight_height
            slabs = [((-0.5 * t, 0.5 * L[1], zc), (t, L[1] + 2 * t, zs)),
                     ((L[0] + 0.5 * t, 0.5 * L[1], zc), (t, L[1] + 2 * t, zs)),
                     ((0.5 * L[0], -0.5 * t, zc), (L[0] + 2 * t, t, zs)),
                     ((0.5 * L[0], L[1] + 0.5 * t, zc), (L[0] + 2 * t, t, zs))]
        else:
            slabs = []
            for axis in range(3):
                for side in (0, 1):
                    centre = 0.5 * L.copy()
                    centre[axis] = -0.5 * t if side == 0 else L[axis] + 0.5 * t
                    ext = L + 2 * t
                    ext[axis] = t
                    slabs.append((tuple(centre), tuple(ext)))
        return [load_scaled_urdf(self.client, urdf_path("box"), ext, centre) for centre, ext in slabs]

    def _build_lookup(self) -> None:
        n = 1 + int(max([self.mav_id, *self.obstacle_ids, *self.static_ids, *self.wall_ids]))
        # One extra trailing "none" entry so that index -1 (PyBullet's "no body") maps to it.
        kind = np.full(n + 1, _NONE, dtype=np.int8)
        index = np.full(n + 1, -1, dtype=np.int64)
        kind[self.mav_id], index[self.mav_id] = _MAV, 0
        for code, ids in ((_DYNAMIC, self.obstacle_ids), (_STATIC, self.static_ids), (_WALL, self.wall_ids)):
            kind[ids] = code
            index[ids] = np.arange(ids.shape[0])
        self._kind, self._index = kind, index
        self.dynamic_index_of = np.where(kind == _DYNAMIC, index, -1)
        """Body id -> obstacle index, or -1 (index with -1 is valid: the last entry is "no body")."""
        self.is_static_body = (kind == _STATIC) | (kind == _WALL)
        """Body id -> True for static bodies and walls (index -1 gives False)."""
        self._known_bodies = 1 + self.obstacle_ids.shape[0] + self.static_ids.shape[0] + self.wall_ids.shape[0]
        # Ray-culling bounds (see fan_candidates): a sphere per dynamic obstacle; per static body its AABB and the
        # sphere around it, all grown by CULL_PAD, in the fan's d dimensions; the walls' inner faces (the arena box).
        boxes = [self._body_aabb(int(b)) for b in self.static_ids.tolist()]
        lo = np.array([b[0] for b in boxes], dtype=float).reshape(-1, 3)[:, : self.dims]
        hi = np.array([b[1] for b in boxes], dtype=float).reshape(-1, 3)[:, : self.dims]
        n = self.obstacle_ids.shape[0]
        self._cull_lo, self._cull_hi = lo - CULL_PAD, hi + CULL_PAD
        self._cull_centres = np.concatenate([np.zeros((n, self.dims)), 0.5 * (lo + hi)])
        bound = np.concatenate([self.obstacle_radii, 0.5 * np.linalg.norm(hi - lo, axis=1)]) + CULL_PAD
        self._cull_bound = bound
        self._cull_bound2 = bound * bound
        self._cull_reach = (math.nan, bound)         # (range_m, (range_m + bound)^2) of the last fan
        self._cull_inner = (np.full(self.dims, CULL_PAD), self.arena_size - CULL_PAD)
        # nearest_static's broad phase: (AABB, body id) of every static body and wall (fixed bodies)
        solid_ids = [*self.static_ids.tolist(), *self.wall_ids.tolist()]
        solid = [self._body_aabb(int(b)) for b in solid_ids]
        self._solid = [((tuple(a.tolist()), tuple(b.tolist())), int(body)) for (a, b), body in zip(solid, solid_ids)]

    def _body_aabb(self, body: int) -> tuple[np.ndarray, np.ndarray]:
        """World AABB (lo [3], hi [3]) of every link of ``body`` (Bullet's broadphase boxes, margins included)."""
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        for link in range(-1, self.client.getNumJoints(body)):
            a, b = self.client.getAABB(body, link)
            lo, hi = np.minimum(lo, a), np.maximum(hi, b)
        return lo, hi

    def add_static_urdf(self, path: str | Path, position: Sequence[float],
                        orientation: Sequence[float] = IDENTITY_QUATERNION,
                        scale_xyz: Sequence[float] = (1.0, 1.0, 1.0)) -> int:
        """Load an extra static body from a URDF file (imported worlds); returns its body id (static index = order)."""
        body = load_scaled_urdf(self.client, path, scale_xyz, position, orientation, use_fixed_base=True)
        self.static_ids = np.append(self.static_ids, np.int64(body))
        self._build_lookup()
        return body

    # ----------------------------------------------------------------------------------------- queries
    def body_kind(self, body_id: int) -> tuple[str, int]:
        """("dynamic", obstacle index) | ("static", static index) | ("wall", wall index) | ("mav", 0) | ("none", -1)."""
        b = int(body_id)
        if b < -1 or b >= self._kind.shape[0] - 1:
            return ("none", -1)
        return (_KIND_NAMES[self._kind[b]], int(self._index[b]))

    def to_world3(self, points) -> np.ndarray:
        """World points [..., d] -> [..., 3] (2D: z = flight_height appended)."""
        pts = np.asarray(points, dtype=float)
        if self.dims == 3:
            return pts.copy()
        z = np.full(pts.shape[:-1] + (1,), self.flight_height)
        return np.concatenate([pts, z], axis=-1)

    def set_obstacle_positions(self, positions, poses=None) -> None:
        """Move the dynamic obstacles to ``positions`` [N, d] (m; their bounding spheres' centres, which ray culling
        uses); 2D pillars stay centred on the flight plane. A world of real-shape obstacles (obstacle_urdfs) also
        needs ``poses`` = (base positions [N, 3] (m), orientations [N, 4] xyzw) for its bodies."""
        if os.getpid() != self._pid:
            raise RuntimeError("a PyBulletWorld cannot be used in a process forked after its creation")
        pos = np.array(positions, dtype=float).reshape(self.obstacle_ids.shape[0], self.dims)
        self.obstacle_positions = pos
        reset = self._reset_pose
        if self.obstacle_urdfs is not None:
            if poses is None:
                raise ValueError("a world of real-shape obstacles needs their poses")
            base, quat = poses
            for body, p, q in zip(self.obstacle_ids.tolist(), np.asarray(base, float).tolist(),
                                  np.asarray(quat, float).tolist()):
                reset(body, p, q)
            return
        for body, p in zip(self.obstacle_ids.tolist(), self.to_world3(pos).tolist()):
            reset(body, p, IDENTITY_QUATERNION)

    def set_mav_pose(self, position, yaw: float) -> None:
        """Place the MAV at ``position`` [d] (m) with ``yaw`` (rad)."""
        self.mav_position = self._plane_point(position)
        self.mav_yaw = float(yaw)
        self._mav_pose3 = self.to_world3(self.mav_position).tolist()
        self._mav_quat = yaw_quaternion(self.mav_yaw)
        self._reset_pose(self.mav_id, self._mav_pose3, self._mav_quat)

    def ray_test(self, origins, ends) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cast rays origins[i] -> ends[i] ([R, 3], m, world frame); the MAV body is never reported.

        Returns (body_ids int64 [R], -1 for no hit; fractions [R] along each ray, 1.0 for no hit;
        hit_points [R, 3] = origin + fraction (end - origin), the end point for no hit). Batches of < 16384 rays.
        Hits on curved shapes are accurate to ~1 mm (Bullet's GJK ray cast; they err early, never late).
        A ray starting inside a body reports that body at fraction 0 (spheres) or passes it (other shapes).
        """
        o = np.asarray(origins, dtype=float).reshape(-1, 3)
        e = np.asarray(ends, dtype=float).reshape(-1, 3)
        ids, frac = self.cast_rays(o, e)
        return ids, frac, o + frac[:, None] * (e - o)

    def cast_rays(self, origins: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """ray_test without the hit points: (body_ids int64 [R], fractions [R]) for float arrays [R, 3]."""
        n = origins.shape[0]
        if ends.shape[0] != n:
            raise ValueError(f"ray_test: {n} origins but {ends.shape[0]} ends")
        ids = np.empty(n, dtype=np.int64)
        frac = np.empty(n, dtype=float)
        # The mask alone keeps the MAV out of the results; parking it far away for the duration also spares
        # Bullet the per-ray work of a shape enclosing every ray origin (~15 us per 91 rays, measured).
        self._reset_pose(self.mav_id, self._mav_parking, IDENTITY_QUATERNION)
        try:
            for lo in range(0, n, RAY_BATCH):
                hi = min(n, lo + RAY_BATCH)
                res = self._ray_batch(origins[lo:hi], ends[lo:hi], numThreads=1, collisionFilterMask=_RAY_MASK)
                ids[lo:hi] = np.fromiter(map(_BODY_ID, res), np.int64, hi - lo)
                frac[lo:hi] = np.fromiter(map(_HIT_FRACTION, res), float, hi - lo)
        finally:
            self._reset_pose(self.mav_id, self._mav_pose3, self._mav_quat)
        frac[ids < 0] = 1.0
        return ids, frac

    def fan_candidates(self, origin, directions, range_m: float) -> np.ndarray:
        """Bool [R]: False for each ray of a fan that provably meets no body of this world (the rest may).

        Rays run from ``origin`` [d] along unit ``directions`` [R, d] (2D: rays in the flight plane) for range_m (m).
        A ray is kept if (1) its line, ahead of the origin, passes within radius + CULL_PAD of a dynamic obstacle's
        centre (the world's own spheres / 2D pillars, at obstacle_positions) within reach; or (2) it does so for
        the sphere around a static body's AABB (+ CULL_PAD; 2D: the xy box) while the box spanned by its segment
        overlaps that AABB; or (3) its segment leaves the arena shrunk by CULL_PAD (where the walls are), or
        starts outside it. Conservative: Bullet reports (-1, 1.0) for every ray this returns False for.
        """
        o = np.asarray(origin, dtype=float).reshape(self.dims)
        dirs_t = np.asarray(directions, dtype=float).reshape(-1, self.dims).T        # [d, R]
        reach = float(range_m)
        if self._cull_reach[0] != reach:
            self._cull_reach = (reach, (reach + self._cull_bound) ** 2)
        inner_lo, inner_hi = self._cull_inner
        if np.any(o <= inner_lo) or np.any(o >= inner_hi):
            return np.ones(dirs_t.shape[1], dtype=bool)
        keep = None
        if np.any(o - reach <= inner_lo) or np.any(o + reach >= inner_hi):      # (3) the walls are within reach
            end = o[:, None] + reach * dirs_t                                     # [d, R]
            keep = ((end <= inner_lo[:, None]) | (end >= inner_hi[:, None])).any(axis=0)
        n_dyn = self.obstacle_ids.shape[0]
        cen = self._cull_centres
        cen[:n_dyn] = self.obstacle_positions
        rel = cen - o
        dist2 = (rel * rel).sum(axis=1)
        near = np.flatnonzero(dist2 <= self._cull_reach[1])
        if near.shape[0]:
            gap = dist2[near] - self._cull_bound2[near]
            # The line o + t u (t >= 0) meets a sphere at distance D, radius b (D > b) iff
            # u . (c - o) >= sqrt(D^2 - b^2); from inside a sphere every ray may hit it.
            along_min = np.where(gap > 0.0, np.sqrt(np.maximum(gap, 0.0)), -np.inf)
            ok = (rel[near] @ dirs_t) >= along_min[:, None]                        # [M, R]
            box = near[n_dyn <= near] - n_dyn
            if box.shape[0]:                                                       # (2)
                end = o[:, None] + reach * dirs_t
                seg_lo, seg_hi = np.minimum(end, o[:, None]), np.maximum(end, o[:, None])
                lo, hi = self._cull_lo[box][:, :, None], self._cull_hi[box][:, :, None]
                ok[near.shape[0] - box.shape[0]:] &= ((seg_lo <= hi) & (seg_hi >= lo)).all(axis=1)
            hit = ok.any(axis=0) if ok.shape[0] > 1 else ok[0]
            keep = hit if keep is None else keep | hit
        return np.zeros(dirs_t.shape[1], dtype=bool) if keep is None else keep

    def fan_candidates_many(self, origins: np.ndarray, dirs_t: np.ndarray, range_m: float) -> np.ndarray:
        """fan_candidates for T fans at once: origins [T, d], unit directions [T, d, R] (every fan R rays); bool
        [T, R]. The same bounds and tests, evaluated in compiled code (_cull_fans) for all fans together; it too
        returns False only for rays that provably meet nothing (a ray within rounding of a bound may be kept by one
        and not the other, and Bullet reports no hit for it either way: the bounds are CULL_PAD beyond every
        body)."""
        o = np.ascontiguousarray(origins, dtype=float)
        dirs_t = np.ascontiguousarray(dirs_t, dtype=float)
        reach = float(range_m)
        if self._cull_reach[0] != reach:
            self._cull_reach = (reach, (reach + self._cull_bound) ** 2)
        inner_lo, inner_hi = self._cull_inner
        n_dyn = self.obstacle_ids.shape[0]
        cen = self._cull_centres
        cen[:n_dyn] = self.obstacle_positions
        return _cull_fans(o, dirs_t, reach, inner_lo, inner_hi, cen, n_dyn, self._cull_reach[1], self._cull_bound2,
                          self._cull_lo, self._cull_hi)

    def fan_rays_many(self, origins: np.ndarray, dirs_t: np.ndarray, range_m: float) -> list["FanRays"]:
        """fan_rays (culled) for T fans at once: origins [T, d], unit directions [T, d, R]; the FanRays per fan, with
        the same start and end points as fan_rays computes (culling may differ only as fan_candidates_many says)."""
        o = np.asarray(origins, dtype=float)
        n_rays = dirs_t.shape[2]
        if self._num_bodies() != self._known_bodies:
            return [self.fan_rays(o[i], dirs_t[i].T, range_m, cull=False) for i in range(o.shape[0])]
        keep = self.fan_candidates_many(o, dirs_t, range_m)
        o3 = self.to_world3(o)
        out = []
        for i, row in enumerate(keep):
            sel = np.flatnonzero(row)
            out.append(self._fan_of(o3[i], dirs_t[i].T, None if sel.shape[0] == n_rays else sel, range_m))
        return out

    def cast_fans_many(self, origins: np.ndarray, dirs_t: np.ndarray, range_m: float) -> tuple[np.ndarray, np.ndarray]:
        """cast_fans(fan_rays_many(origins, dirs_t, range_m)) as two arrays: body ids [T, R] (int64) and fractions
        [T, R] of T fans from origins [T, d] along unit directions [T, d, R] -- the same rays (kept by the same
        culling, with the same start and end points, in the same order) sent to Bullet in one cast_rays call,
        without a FanRays per fan."""
        o = np.asarray(origins, dtype=float)
        dirs_t = np.ascontiguousarray(dirs_t, dtype=float)
        n_fans, _, n_rays = dirs_t.shape
        if self._num_bodies() != self._known_bodies:
            keep = np.ones((n_fans, n_rays), dtype=bool)
        else:
            keep = self.fan_candidates_many(o, dirs_t, range_m)
        starts, ends, where = _fan_segments(np.ascontiguousarray(self.to_world3(o)), dirs_t, keep, float(range_m))
        ids = np.full(n_fans * n_rays, -1, dtype=np.int64)
        frac = np.ones(n_fans * n_rays)
        if where.shape[0]:
            ids[where], frac[where] = self.cast_rays(starts, ends)
        return ids.reshape(n_fans, n_rays), frac.reshape(n_fans, n_rays)

    def cast_fan(self, origin, directions, range_m: float, *, cull: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Cast rays from ``origin`` [d] along unit ``directions`` [R, d] to range_m (m): (body_ids [R], fractions [R]).

        The same results as cast_rays on the rays origin -> origin + range_m * direction (2D: in the plane
        z = flight_height), but rays that fan_candidates proves empty are not sent to Bullet (they get -1, 1.0).
        Culling is skipped (cull=False, or bodies in the client this world did not create) and relies on bodies
        being moved only through set_obstacle_positions.
        """
        return self.cast_fan_rays(self.fan_rays(origin, directions, range_m, cull=cull))

    def cast_fan_rays(self, fan: "FanRays") -> tuple[np.ndarray, np.ndarray]:
        """cast_fan's (body_ids [R], fractions [R]) of one fan of rays (fan_rays); Bullet is not called when culling
        left no ray."""
        if fan.starts.shape[0] == 0:
            return self.fan_results(fan, np.empty(0, np.int64), np.empty(0))
        return self.fan_results(fan, *self.cast_rays(fan.starts, fan.ends))

    def fan_rays(self, origin, directions, range_m: float, *, cull: bool = True) -> "FanRays":
        """The rays cast_fan sends to Bullet for this fan (culled as there), to cast later, possibly together
        with other fans in one cast_rays call (lockstep trials); fan_results turns their hits into cast_fan's."""
        o = np.asarray(origin, dtype=float).reshape(self.dims)
        dirs = np.asarray(directions, dtype=float).reshape(-1, self.dims)
        n = dirs.shape[0]
        o3 = self.to_world3(o)
        if cull and self._num_bodies() == self._known_bodies:
            sel = np.flatnonzero(self.fan_candidates(o, dirs, range_m))
            if sel.shape[0] == n:
                sel = None
        else:
            sel = None
        return self._fan_of(o3, dirs, sel, range_m)

    def _fan_of(self, o3: np.ndarray, dirs: np.ndarray, sel: np.ndarray | None, range_m: float) -> "FanRays":
        """The FanRays of the rays ``sel`` (None: all) along unit ``dirs`` [R, d] from o3 [3] to range_m (m)."""
        k = dirs.shape[0] if sel is None else sel.shape[0]
        starts = np.empty((k, 3))
        starts[:] = o3
        ends = starts.copy()
        if k:
            ends[:, : self.dims] += float(range_m) * (dirs if sel is None else dirs[sel])
        return FanRays(dirs.shape[0], sel, starts, ends)

    @staticmethod
    def fan_results(fan: "FanRays", hit_ids: np.ndarray, hit_frac: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """cast_fan's (body_ids [R], fractions [R]) from the hits of the fan's rays (cast_rays on its starts, ends)."""
        if fan.selected is None:          # every ray was cast
            return hit_ids, hit_frac
        ids = np.full(fan.n_rays, -1, dtype=np.int64)
        frac = np.ones(fan.n_rays)
        ids[fan.selected] = hit_ids
        frac[fan.selected] = hit_frac
        return ids, frac

    def cast_fans(self, fans: Sequence["FanRays"]) -> list[tuple[np.ndarray, np.ndarray]]:
        """cast_fan's results for several fans of rays (fan_rays), cast in one cast_rays call."""
        if len(fans) <= 1:
            return [self.cast_fan_rays(f) for f in fans]
        counts = [f.starts.shape[0] for f in fans]
        if sum(counts) == 0:
            return [self.cast_fan_rays(f) for f in fans]
        ids, frac = self.cast_rays(np.concatenate([f.starts for f in fans]), np.concatenate([f.ends for f in fans]))
        out, lo = [], 0
        for f, c in zip(fans, counts):
            out.append(self.fan_results(f, ids[lo:lo + c], frac[lo:lo + c]))
            lo += c
        return out

    def clearance_to_bodies(self, position, body_ids, max_dist: float) -> np.ndarray:
        """Signed distance (m) from the MAV sphere at ``position`` [d] to each body in ``body_ids``, capped at max_dist.

        Uses a free-standing sphere of the MAV radius (the MAV body itself is not moved). Negative = penetration.
        """
        p3 = self.to_world3(self._plane_point(position)).tolist()
        md = float(max_dist)
        out = np.full(len(body_ids), md)
        for k, b in enumerate(np.asarray(body_ids, dtype=np.int64).tolist()):
            pts = self._closest(-1, b, md, collisionShapeA=self._probe, collisionShapePositionA=p3)
            if pts:
                out[k] = min(md, min(c[8] for c in pts))
        return out

    def nearest_static(self, position, max_dist: float) -> tuple[float, int]:
        """(signed distance m, body id) from the MAV sphere at ``position`` [d] to the nearest static body or wall.

        PyBullet getClosestPoints against the true static geometry of the static bodies and walls whose AABB meets the
        query box (the ones within reach); returns (max_dist, -1) if nothing is nearer than max_dist (on an exact tie
        the body found first, static bodies before walls). The MAV body is not moved (a probe sphere is used).
        """
        p3l = np.asarray(position, dtype=float)[: self.dims].tolist()   # to_world3 of the plane point, as floats
        if self.dims == 2:
            p3l.append(float(self.flight_height))
        md = float(max_dist)
        reach = self.mav_radius + max(md, 0.0) + 1e-6
        x0, x1, x2 = p3l
        q_lo, q_hi = [x0 - reach, x1 - reach, x2 - reach], [x0 + reach, x1 + reach, x2 + reach]
        # A body nearer than max_dist to the probe lies in the query box, so only the static bodies and walls whose
        # AABB meets it can be (the bodies Bullet's broad phase would return, less the moving ones), unless bodies
        # were added behind this world: then Bullet's broad phase is asked.
        if self._num_bodies() != self._known_bodies:
            return self._nearest_static_broadphase(p3l, md, q_lo, q_hi)
        best, best_id = md, -1
        for (lo, hi), body in self._solid:
            if (lo[0] <= q_hi[0] and hi[0] >= q_lo[0] and lo[1] <= q_hi[1] and hi[1] >= q_lo[1]
                    and lo[2] <= q_hi[2] and hi[2] >= q_lo[2]):
                for c in self._closest(-1, body, md, collisionShapeA=self._probe, collisionShapePositionA=p3l):
                    if c[8] < best:
                        best, best_id = float(c[8]), body
        return best, best_id

    def _nearest_static_broadphase(self, p3l: list, md: float, q_lo: list, q_hi: list) -> tuple[float, int]:
        """nearest_static's answer with Bullet's broad phase choosing the bodies (every static body or wall with a
        link in the query box q_lo..q_hi), for a client holding bodies this world did not add."""
        found = self._overlapping(q_lo, q_hi)
        best, best_id = md, -1
        if not found:
            return best, best_id
        is_static = self.is_static_body
        for body, _link in found:
            if body < 0 or body >= is_static.shape[0] - 1 or not is_static[body]:
                continue
            for c in self._closest(-1, body, md, collisionShapeA=self._probe, collisionShapePositionA=p3l):
                if c[8] < best:
                    best, best_id = float(c[8]), int(body)
        return best, best_id

    def static_clearance(self, position, max_dist: float) -> float:
        """Signed distance (m) from the MAV sphere at ``position`` [d] to the nearest static body or wall.

        Negative = penetration; max_dist if nothing is nearer. The MAV body is not moved: the query uses a free
        probe sphere of the MAV radius, so it has no side effects.
        """
        return self.nearest_static(position, max_dist)[0]

    # ----------------------------------------------------------------------------------------- lifetime
    def close(self) -> None:
        """Disconnect the PyBullet client (idempotent); a lent client is left connected (its bodies stay until the
        next world resets it)."""
        if not self._closed:
            self._closed = True
            if self._owns_client:
                with stdout_to_stderr():
                    self.client.disconnect()

    def __enter__(self) -> "PyBulletWorld":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@contextlib.contextmanager
def what_if_pose(world: PyBulletWorld, position, yaw: float) -> Iterator[PyBulletWorld]:
    """Temporarily place the MAV at ``position`` [d] / ``yaw`` (rad); its previous pose is restored on exit."""
    old_p, old_yaw = world.mav_position.copy(), world.mav_yaw
    world.set_mav_pose(position, yaw)
    try:
        yield world
    finally:
        world.set_mav_pose(old_p, old_yaw)


@njit(cache=True, nogil=True)
def _fan_segments(o3, dirs_t, keep, reach):
    """The rays of fans kept by ``keep`` [T, R], fan by fan, as _fan_of makes them: starts o3[t] [3] (m, world) and
    ends o3[t] + reach * dirs_t[t, :, r] on the first d coordinates ([N, 3] each), and their flat indices t R + r."""
    n_fans, d, n_rays = dirs_t.shape
    n = 0
    for t in range(n_fans):
        for r in range(n_rays):
            n += keep[t, r]
    starts = np.empty((n, 3))
    ends = np.empty((n, 3))
    where = np.empty(n, dtype=np.int64)
    i = 0
    for t in range(n_fans):
        for r in range(n_rays):
            if not keep[t, r]:
                continue
            for j in range(3):
                starts[i, j] = o3[t, j]
                ends[i, j] = o3[t, j]
            for j in range(d):
                ends[i, j] = o3[t, j] + reach * dirs_t[t, j, r]
            where[i] = t * n_rays + r
            i += 1
    return starts, ends, where


@njit(cache=True, nogil=True)
def _cull_fans(o, dirs_t, reach, inner_lo, inner_hi, cen, n_dyn, near2, bound2, box_lo, box_hi):
    """PyBulletWorld.fan_candidates_many's keep mask [T, R] for fans from o [T, d] along dirs_t [T, d, R] to
    ``reach`` (m): a ray is kept if (3) the fan starts outside the arena shrunk by CULL_PAD (inner_lo, inner_hi)
    or the ray's end leaves it, or (1) for a body m (centre cen[m], bounding sphere bound2[m] squared, within
    near2[m] squared of the origin) u . (c - o) >= sqrt(|c - o|^2 - b^2) (from inside the sphere always), (2) for
    a static body (m >= n_dyn) also the ray's segment box overlapping its AABB (box_lo, box_hi [S, d])."""
    n_fans, d, n_rays = dirs_t.shape
    n_bodies = cen.shape[0]
    keep = np.zeros((n_fans, n_rays), dtype=np.bool_)
    near = np.empty(n_bodies, dtype=np.int64)
    along_min = np.empty(n_bodies)
    rel = np.empty((n_bodies, d))
    for t in range(n_fans):
        outside = False
        walls = False
        for j in range(d):
            if o[t, j] <= inner_lo[j] or o[t, j] >= inner_hi[j]:
                outside = True
            if o[t, j] - reach <= inner_lo[j] or o[t, j] + reach >= inner_hi[j]:
                walls = True
        if outside:
            keep[t, :] = True
            continue
        n_near = 0
        for m in range(n_bodies):
            dist2 = 0.0
            for j in range(d):
                rel[m, j] = cen[m, j] - o[t, j]
                dist2 += rel[m, j] * rel[m, j]
            if dist2 <= near2[m]:
                gap = dist2 - bound2[m]
                along_min[m] = np.sqrt(gap) if gap > 0.0 else -np.inf
                near[n_near] = m
                n_near += 1
        for r in range(n_rays):
            hit = False
            if walls:
                for j in range(d):
                    end = o[t, j] + reach * dirs_t[t, j, r]
                    if end <= inner_lo[j] or end >= inner_hi[j]:
                        hit = True
            i = 0
            while not hit and i < n_near:
                m = near[i]
                i += 1
                along = 0.0
                for j in range(d):
                    along += rel[m, j] * dirs_t[t, j, r]
                if along < along_min[m]:
                    continue
                if m < n_dyn:
                    hit = True
                    continue
                overlap = True
                for j in range(d):
                    end = o[t, j] + reach * dirs_t[t, j, r]
                    lo = min(end, o[t, j])
                    hi = max(end, o[t, j])
                    if not (lo <= box_hi[m - n_dyn, j] and hi >= box_lo[m - n_dyn, j]):
                        overlap = False
                hit = overlap
            keep[t, r] = hit
    return keep
