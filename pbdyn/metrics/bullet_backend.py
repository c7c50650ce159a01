"""The ``bullet`` survivability backend: survival times (thesis eq. 3-6, 3-7, "sampled" mode) from PyBullet collision
queries between static MAV spheres at the sample points and the world's moving bodies, of any shape.

Independent of the analytic kernel (pbdyn.metrics.analytic is never imported). One DIRECT BulletClient per
call, holding only what the query needs: one *query body* per sample (a sphere of the MAV radius, mass 1 so that
Bullet generates contacts against the mass-0 obstacles) and the *target bodies* that move. Collision filters keep
query bodies from colliding with each other and with anything but the targets (group QUERY_GROUP, mask
TARGET_GROUP; targets: group TARGET_GROUP, mask QUERY_GROUP), so static geometry is ignored -- samples overlapping it
are left out by the caller. Per step the targets are placed with resetBasePositionAndOrientation, then
performCollisionDetection + getContactPoints (stepSimulation is never called); a sample is hit when a contact
point between its sphere and a target has distance < 0 (penetration; touching at distance 0 does not count, as in
the analytic kernel's strict '<'). Hit samples are parked far away, so later steps only test the living ones.

Precision: sphere-sphere contact distances are exact up to double rounding (|c_a - c_b| - (r_a + r_b)); other
shapes go through Bullet's GJK/EPA or dedicated box-sphere algorithms (faces exact, box edges/corners rounded by
the collision margin, ~0.04 m by default).

2D: query spheres and the default obstacle shapes (spheres of the pillar radius) are centred in the flight plane
z = flight_height, where they cut the same discs as the vertical pillars; ``exact_pillars=True`` uses real
cylinders spanning [0, 2 h] instead (GJK, slower and less exact).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pbdyn.errors import ConfigError, check_positive, HorizonError
from pbdyn.metrics.sampling import step_window
from pbdyn.world.imported.urdf_loading import load_scaled_urdf
from pbdyn.world.pybullet_client import bullet_client, pybullet, silenced_stdout, stdout_to_stderr

QUERY_GROUP = 0x200
"""Collision filter group of the query (MAV) spheres."""

TARGET_GROUP = 0x400
"""Collision filter group of the moving target bodies (obstacles)."""

PARK = (1.0e6, 1.0e6, 1.0e6)
"""Where hit query spheres are parked (m): far from every target, and parked queries never collide with each other."""

_IDENTITY = (0.0, 0.0, 0.0, 1.0)


@dataclass(frozen=True)
class ExtraBody:
    """A moving body of any shape for survival_times_bullet (imported worlds; world frame, m).

    urdf: URDF file; scale: (sx, sy, sz) applied at load (see pbdyn.world.imported.urdf_loading.load_scaled_urdf).
    pose: either positions [T, 3] (m) sampled at the rollout's steps (row k = time k dt; 2D bodies give their real z),
    or a function t (s) -> position [3], or -> (position [3], quaternion xyzw [4]).
    orientations: optional quaternions [T, 4] (xyzw) with array poses (default identity).
    """

    urdf: str | Path
    scale: Sequence[float] = (1.0, 1.0, 1.0)
    pose: np.ndarray | Callable | None = None
    orientations: np.ndarray | None = None

    def pose_at(self, k: int, t: float) -> tuple[list[float], list[float]]:
        """(position [3], quaternion [4]) at rollout step k / time t (s)."""
        if callable(self.pose):
            out = self.pose(t)
            if isinstance(out, tuple) and len(out) == 2 and np.size(out[0]) == 3:
                return [float(x) for x in out[0]], [float(x) for x in out[1]]
            return [float(x) for x in np.asarray(out, float).reshape(3)], list(_IDENTITY)
        pos = np.asarray(self.pose, dtype=float)
        if k >= pos.shape[0]:
            raise HorizonError(f"extra body {self.urdf}: pose needed at step {k}, only {pos.shape[0]} given")
        quat = _IDENTITY if self.orientations is None else np.asarray(self.orientations, float)[k]
        return [float(x) for x in pos[k]], [float(x) for x in quat]


# ------------------------------------------------------------------------------------------------ low level
def _client_of(client_or_world):
    return getattr(client_or_world, "client", client_or_world)


def _set_filter(client, body: int, group: int, mask: int) -> None:
    for link in range(-1, client.getNumJoints(body)):
        client.setCollisionFilterGroupMask(body, link, group, mask)


def add_query_spheres(client_or_world, points3, radius: float) -> np.ndarray:
    """Create one query sphere (mass 1, radius ``radius`` m) at each of ``points3`` [n, 3] (m, world frame) in the
    client, in group QUERY_GROUP with mask TARGET_GROUP; returns their body ids (int64 [n])."""
    client = _client_of(client_or_world)
    pts = np.asarray(points3, dtype=float).reshape(-1, 3)
    if pts.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    shape = client.createCollisionShape(pybullet.GEOM_SPHERE, radius=float(radius))
    ids = client.createMultiBody(baseMass=1.0, baseCollisionShapeIndex=shape, batchPositions=pts.tolist())
    client.syncBodyInfo()  # bodies created in a batch are unknown to the client until synced
    ids = np.atleast_1d(np.asarray(ids, dtype=np.int64))
    for b in ids.tolist():
        client.setCollisionFilterGroupMask(b, -1, QUERY_GROUP, TARGET_GROUP)
    return ids


def survival_steps_bodies(client_or_world, query_ids, target_ids, set_poses: Callable[[int], None],
                          n_steps: int) -> np.ndarray:
    """First step k in 0..n_steps at which each query body penetrates a target body; -1 if never (int64 [n]).

    client_or_world: a BulletClient (or anything with a ``client`` attribute, e.g. a PyBulletWorld) -- use a client
    dedicated to this query: the targets' collision filters are set to (TARGET_GROUP, QUERY_GROUP) for good (every
    link), so they stop colliding with anything else, and hit query bodies are left parked at PARK.
    query_ids: query spheres from add_query_spheres. target_ids: the moving bodies. set_poses(k): places the targets
    for step k (resetBasePositionAndOrientation). Never calls stepSimulation.
    """
    client = _client_of(client_or_world)
    query = np.asarray(query_ids, dtype=np.int64).reshape(-1)
    first = np.full(query.shape[0], -1, dtype=np.int64)
    if query.shape[0] == 0:
        return first
    for b in np.asarray(target_ids, dtype=np.int64).reshape(-1).tolist():
        _set_filter(client, b, TARGET_GROUP, QUERY_GROUP)
    # body id -> sample index (-1: not a query body); one extra trailing entry so that id -1 maps to -1.
    lookup = np.full(int(max(query.max(), client.getNumBodies())) + 2, -1, dtype=np.int64)
    lookup[query] = np.arange(query.shape[0])
    cid = client._client
    detect = pybullet.performCollisionDetection
    contacts = pybullet.getContactPoints
    reset = pybullet.resetBasePositionAndOrientation
    n_alive = query.shape[0]
    for k in range(int(n_steps) + 1):
        set_poses(k)
        detect(physicsClientId=cid)
        found = contacts(physicsClientId=cid)
        if not found:
            continue
        rows = np.array([(c[1], c[2], c[8]) for c in found], dtype=float)
        pen = rows[rows[:, 2] < 0.0]
        if pen.shape[0] == 0:
            continue
        idx = np.maximum(lookup[pen[:, 0].astype(np.int64)], lookup[pen[:, 1].astype(np.int64)])
        idx = np.unique(idx[idx >= 0])
        idx = idx[first[idx] < 0]
        if idx.shape[0] == 0:
            continue
        first[idx] = k
        for b in query[idx].tolist():
            reset(b, PARK, _IDENTITY, physicsClientId=cid)
        n_alive -= idx.shape[0]
        if n_alive == 0:
            break
    return first


# ------------------------------------------------------------------------------------------------ rollout level
def plane_height(rollout, flight_height: float | None = None) -> float:
    """The 2D flight plane z (m): ``flight_height`` if given, else the rollout's (imported worlds), else 2 m."""
    if flight_height is not None:
        return check_positive("flight_height", flight_height)
    meta = rollout.meta if isinstance(getattr(rollout, "meta", None), dict) else {}
    return float(meta.get("flight_height", 2.0))


def world_bodies(rollout) -> tuple[ExtraBody, ...]:
    """The moving bodies of an imported world's rollout as ExtraBody targets (their real shapes and poses)."""
    bodies = getattr(rollout, "bodies", None)
    if bodies is None:
        return ()
    return tuple(ExtraBody(bodies.urdf[b], tuple(bodies.scale[b]), bodies.position[:, b], bodies.orientation[:, b])
                 for b in bodies.moving_index.tolist())


class _RolloutScene:
    """A DIRECT client with the rollout's obstacles (and extra bodies) as targets and a query sphere per point.

    For an imported world the targets are its moving bodies' real shapes, not their bounding spheres."""

    def __init__(self, rollout, points, mav_radius: float, flight_height: float, exact_pillars: bool,
                 extra_bodies: Sequence[ExtraBody]):
        d = rollout.dims
        pts = np.asarray(points, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != d:
            raise ValueError(f"points must have shape [n, {d}] (got {pts.shape})")
        self.rollout, self.dims, self.h = rollout, d, plane_height(rollout, flight_height)
        self.spheres = getattr(rollout, "bodies", None) is None
        self.extra = world_bodies(rollout) + tuple(extra_bodies)
        with silenced_stdout():
            self.client = bullet_client.BulletClient(connection_mode=pybullet.DIRECT)
        try:
            self._build(pts, mav_radius, exact_pillars)
        except BaseException:
            self.close()
            raise

    def _build(self, pts: np.ndarray, mav_radius: float, exact_pillars: bool) -> None:
        c, ro = self.client, self.rollout
        try:
            c.setPhysicsEngineParameter(numThreads=1)
        except TypeError:  # not a parameter of this PyBullet build
            pass
        shapes: dict[float, int] = {}
        ids = []
        for r in (ro.radii.tolist() if self.spheres else []):
            if r not in shapes:
                if self.dims == 2 and exact_pillars:
                    shapes[r] = c.createCollisionShape(pybullet.GEOM_CYLINDER, radius=r, height=2.0 * self.h)
                else:
                    shapes[r] = c.createCollisionShape(pybullet.GEOM_SPHERE, radius=r)
            ids.append(c.createMultiBody(baseMass=0.0, baseCollisionShapeIndex=shapes[r], basePosition=PARK))
        for i, body in enumerate(self.extra):
            if not Path(body.urdf).is_file():
                raise ConfigError(f"extra_bodies[{i}].urdf", "file not found", str(body.urdf))
            if body.pose is None or (not callable(body.pose) and np.ndim(body.pose) != 2):
                raise ConfigError(f"extra_bodies[{i}].pose", "must be positions [T, 3] or a function of t", body.pose)
            ids.append(load_scaled_urdf(c, body.urdf, body.scale, PARK))
        n_spheres = ro.n_obstacles if self.spheres else 0
        self.obstacle_ids = ids[:n_spheres]
        self.extra_ids = ids[n_spheres:]
        self.target_ids = np.asarray(ids, dtype=np.int64)
        self.query_ids = add_query_spheres(c, self.to3(pts), mav_radius)
        self._cid = c._client

    def to3(self, p: np.ndarray) -> np.ndarray:
        if self.dims == 3:
            return np.asarray(p, dtype=float)
        return np.concatenate([p, np.full(p.shape[:-1] + (1,), self.h)], axis=-1)

    def poser(self, k0: int) -> Callable[[int], None]:
        """set_poses(k): the targets at rollout step k0 + k."""
        reset, cid, ro = pybullet.resetBasePositionAndOrientation, self._cid, self.rollout
        obs, extra, extra_ids = self.obstacle_ids, self.extra, self.extra_ids

        def set_poses(k: int) -> None:
            step = k0 + k
            for b, p in zip(obs, self.to3(ro.positions[step]).tolist()):
                reset(b, p, _IDENTITY, physicsClientId=cid)
            for b, body in zip(extra_ids, extra):
                p, q = body.pose_at(step, float(ro.times[step]))
                reset(b, p, q, physicsClientId=cid)
        return set_poses

    def close(self) -> None:
        with stdout_to_stderr():
            self.client.disconnect()


MAX_QUERIES = 128
"""Query spheres per client: Bullet needs ~0.2 ms to create a body, so bigger sample sets are run in passes of at
most this many spheres, moved between passes (and between start times) instead of re-created."""


def survival_table_bullet(rollout, points, start_times, *, mav_radius: float = 1.0, t_max: float = 12.0,
                          flight_height: float | None = None, exact_pillars: bool = False,
                          extra_bodies: Sequence[ExtraBody] = (), max_queries: int = MAX_QUERIES) -> np.ndarray:
    """Survival times [S, n] (s, relative to each start) of static MAV spheres at ``points`` [n, d] (m) for each of
    ``start_times`` [S] (s), by PyBullet collision queries (thesis eq. 3-6, "sampled"); see survival_times_bullet.

    One client holds the targets and at most ``max_queries`` query spheres; samples are run in passes (chunks in
    the given order), and for every pass each start time reuses the same spheres. HorizonError past the horizon.
    """
    mav_radius = check_positive("mav_radius", mav_radius)
    starts = [float(s) for s in np.asarray(start_times, dtype=float).reshape(-1)]
    windows = [step_window(rollout, s, t_max) for s in starts]
    pts = np.asarray(points, dtype=float).reshape(-1, rollout.dims)
    out = np.full((len(starts), pts.shape[0]), float(t_max))
    if pts.shape[0] == 0 or not starts or (rollout.n_obstacles == 0 and not extra_bodies):
        return out
    q = max(1, int(max_queries))
    scene = _RolloutScene(rollout, pts[:q], mav_radius, flight_height, exact_pillars, extra_bodies)
    try:
        reset, cid = pybullet.resetBasePositionAndOrientation, scene._cid
        all3 = scene.to3(pts).tolist()
        for lo in range(0, pts.shape[0], q):
            hi = min(pts.shape[0], lo + q)
            ids = scene.query_ids[: hi - lo]
            for j, (k0, n_steps) in enumerate(windows):
                for b, p in zip(scene.query_ids.tolist(), all3[lo:hi] + [list(PARK)] * (q - (hi - lo))):
                    reset(b, p, _IDENTITY, physicsClientId=cid)
                first = survival_steps_bodies(scene.client, ids, scene.target_ids, scene.poser(k0), n_steps)
                hit = first >= 0
                out[j, lo:hi][hit] = np.minimum(first[hit] * rollout.dt, float(t_max))
    finally:
        scene.close()
    return out


def survival_times_bullet(rollout, points, *, mav_radius: float = 1.0, t_max: float = 12.0, start_time: float = 0.0,
                          flight_height: float | None = None, exact_pillars: bool = False,
                          extra_bodies: Sequence[ExtraBody] = ()) -> np.ndarray:
    """Survival time (s, relative to ``start_time``) of a static MAV sphere at each point [n, d] (m, world frame)
    among the rollout's obstacles (and ``extra_bodies``), by PyBullet collision queries (thesis eq. 3-6, "sampled").

    The first step t_k = start_time + k dt, k = 0..floor(t_max / dt), at which the MAV sphere of ``mav_radius`` (m)
    penetrates an obstacle body (distance < 0; 2D: obstacles are the pillar spheres in the plane z = flight_height,
    ``exact_pillars`` for real cylinders; 3D: balls; imported worlds: the moving bodies' real shapes) gives k dt;
    never hit gives t_max. Static bodies are ignored (the caller leaves out samples overlapping them). HorizonError
    if start_time + t_max is past the horizon.
    """
    return survival_table_bullet(rollout, points, [start_time], mav_radius=mav_radius, t_max=t_max,
                                 flight_height=flight_height, exact_pillars=exact_pillars,
                                 extra_bodies=extra_bodies)[0]
