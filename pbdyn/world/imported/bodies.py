"""Imported worlds: URDF bodies with scripted motion become a rollout of poses (docs/scenarios.md "Imported worlds").

A world file is a scenario whose generated obstacles are replaced by ``[[bodies]]``. Every body's base pose is
computed at every rollout step from its motion (static; constant velocity whose bounding sphere reflects at the
arena walls like the generated obstacles' CVM; a closed waypoint loop at given speeds; or a user function of t).
Trackers, planners, VO and the ``analytic`` survivability backend see each moving body as its *bounding sphere*
(centre [T, M, d] and radius as the rollout's dynamic obstacles); density, traversability and the ``bullet`` and
``mesh`` backends use the real shapes (pbdyn.world.shapes, PyBullet); trials collide with static bodies' real
shapes and with moving bodies' bounding spheres (pbdyn.world.shapes.bounding_sphere).
"""

from __future__ import annotations

import hashlib
import inspect
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pbdyn.config import BodyConfig, Scenario
from pbdyn.errors import ConfigError, import_module, import_object, one_line, shorten
from pbdyn.motion.cvm import cvm_fold
from pbdyn.usercode import USER_CODE_TIMEOUT_S, UserCodeTimeout, quiet_user_code, time_budget
from pbdyn.world.shapes import (BOUNDING_RULE, ShapeField, body_primitives, bounding_sphere, quat_from_rpy,
                                rotation_from_quat)

YAW_ONLY_TOL = 1e-9
MAX_COORDINATE_M = 1e6
"""Largest |coordinate| (m) a motion function may return: finite positions beyond it (1e300) are bugs, and they
overflow the velocity, collision and distance arithmetic downstream."""


@dataclass(frozen=True)
class WorldBodies:
    """Poses of an imported world's bodies at every rollout step (SI, world frame).

    names, urdf (absolute paths), scale [B, 3], moving [B] (bool), position [T, B, 3] (base, m), orientation
    [T, B, 4] (xyzw), sphere_centre [B, 3] (bounding-sphere centre in the base frame, m), sphere_radius [B] (m).
    The rollout's dynamic obstacle i is moving body ``moving_index[i]``.
    """

    names: tuple[str, ...]
    urdf: tuple[str, ...]
    scale: np.ndarray
    moving: np.ndarray
    position: np.ndarray
    orientation: np.ndarray
    sphere_centre: np.ndarray
    sphere_radius: np.ndarray

    def __post_init__(self) -> None:
        for name in ("scale", "position", "orientation", "sphere_centre", "sphere_radius"):
            arr = np.ascontiguousarray(getattr(self, name), dtype=float)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        mv = np.asarray(self.moving, dtype=bool)
        mv.setflags(write=False)
        object.__setattr__(self, "moving", mv)

    @property
    def moving_index(self) -> np.ndarray:
        """Body index of each dynamic obstacle (the moving bodies, in file order)."""
        return np.flatnonzero(self.moving)

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The .npz arrays (prefix "body_")."""
        return {"body_names": np.array(self.names, dtype=str), "body_urdf": np.array(self.urdf, dtype=str),
                "body_scale": self.scale, "body_moving": self.moving, "body_position": self.position,
                "body_orientation": self.orientation, "body_sphere_centre": self.sphere_centre,
                "body_sphere_radius": self.sphere_radius}

    @classmethod
    def from_arrays(cls, a: dict) -> "WorldBodies | None":
        """Inverse of to_arrays (None when the file has no bodies)."""
        if "body_urdf" not in a:
            return None
        return cls(tuple(str(x) for x in a["body_names"]), tuple(str(x) for x in a["body_urdf"]), a["body_scale"],
                   a["body_moving"], a["body_position"], a["body_orientation"], a["body_sphere_centre"],
                   a["body_sphere_radius"])

    def field(self) -> ShapeField:
        """The signed-distance field of the real shapes (cached on this object)."""
        cached = self.__dict__.get("_field")
        if cached is None:
            cached = ShapeField(self)
            object.__setattr__(self, "_field", cached)
        return cached


# ------------------------------------------------------------------------------------------------ motions
def waypoint_loop(waypoints: np.ndarray, speeds: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions [T, d] (m) and velocities [T, d] (m/s) of a point looping through ``waypoints`` [W, d] (back to the
    first) with speed ``speeds[i]`` (m/s) on leg i, starting at waypoints[0] at t = 0."""
    w = np.asarray(waypoints, dtype=float)
    legs = np.roll(w, -1, axis=0) - w
    lengths = np.linalg.norm(legs, axis=1)
    durations = lengths / np.asarray(speeds, dtype=float)
    ends = np.cumsum(durations)
    period = float(ends[-1])
    tau = np.mod(np.asarray(times, dtype=float), period)
    leg = np.minimum(np.searchsorted(ends, tau, side="right"), w.shape[0] - 1)
    start = ends[leg] - durations[leg]
    vel = legs[leg] / durations[leg, None]
    return w[leg] + (tau - start)[:, None] * vel, vel


def _load_function(body: BodyConfig, where: str):
    obj = import_object(body.motion, f"{where}.motion")
    if not callable(obj):
        raise ConfigError(f"{where}.motion", f"{body.motion.partition(':')[2]!r} is not callable", body.motion)
    return obj


_REAL_KINDS = "iuf"
"""numpy dtype kinds a pose may have: integers and floats (not bool, complex, strings or objects)."""


def _shown(value: object) -> str:
    """A returned value as a short one-line text for error messages (its repr; the type if even that fails)."""
    try:
        text = repr(value)
    except KeyboardInterrupt:
        raise
    except BaseException:
        text = f"<{type(value).__name__} object>"
    return shorten(text, 120)


def _real_vector(value: object, n: int, what: str) -> tuple[np.ndarray | None, str]:
    """(value as float [n], "") if it is n real, finite numbers, else (None, what is wrong). Conversion may run
    user code (__float__, __array__); the caller guards it."""
    try:
        arr = np.asarray(value)
    except (ValueError, TypeError, OverflowError):  # ragged nesting and the like
        return None, f"the {what} must be {n} real numbers"
    if arr.dtype.kind == "O":  # a list of Python objects: each must be a real number (bool is not)
        flat = arr.reshape(-1).tolist()
        if any(isinstance(x, (bool, np.bool_)) or not isinstance(x, (int, float, np.integer, np.floating))
               for x in flat):
            return None, f"the {what} must be {n} real numbers"
        try:
            arr = np.array(flat, dtype=float).reshape(arr.shape)
        except OverflowError:
            return None, f"the {what} must be {n} finite numbers"
    if arr.dtype.kind not in _REAL_KINDS:
        return None, f"the {what} must be {n} real numbers"
    if arr.size != n:
        return None, f"the {what} must be {n} numbers, not shape {arr.shape}"
    with np.errstate(all="ignore"):
        out = arr.astype(float).reshape(n)
    if not np.all(np.isfinite(out)):
        return None, f"the {what} must be {n} finite numbers"
    return out, ""


def _pose(out: object) -> tuple[np.ndarray | None, np.ndarray | None, str]:
    """(position [3], unit quaternion xyzw [4], "") from a motion function's return value, or (None, None, what is
    wrong)."""
    q: object = (0.0, 0.0, 0.0, 1.0)
    if isinstance(out, tuple) and len(out) == 2:
        out, q = out
    p, problem = _real_vector(out, 3, "position")
    if p is None:
        return None, None, problem
    if np.any(np.abs(p) > MAX_COORDINATE_M):
        return None, None, f"the position's coordinates must be within +-{MAX_COORDINATE_M:g} m"
    qa, problem = _real_vector(q, 4, "quaternion")
    if qa is None:
        return None, None, problem
    m = float(np.max(np.abs(qa)))
    if m == 0.0:
        return None, None, "the quaternion must not be zero"
    qa = qa / m                                       # scaled first: no overflow for huge components
    return p, qa / float(np.sqrt(qa @ qa)), ""


def _function_poses(body: BodyConfig, where: str, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every pose of a body moved by a user function, called at each time under the user-code rules: its prints go
    to stderr, any exception or exit it raises (not KeyboardInterrupt) and any return value that is not a pose
    (docs/scenarios.md "Imported worlds") become a ConfigError naming ``bodies[i].motion`` with the time, and all its calls
    together must finish within USER_CODE_TIMEOUT_S of wall-clock time."""
    field = f"{where}.motion"
    fn = _load_function(body, where)
    pos = np.empty((times.shape[0], 3))
    quat = np.empty((times.shape[0], 4))
    params = dict(body.params)
    t = float(times[0]) if times.shape[0] else 0.0
    try:
        with quiet_user_code(), time_budget(USER_CODE_TIMEOUT_S) as budget:
            for k, t in enumerate(times.tolist()):
                try:
                    out = fn(t, **params)
                    p, q, problem = _pose(out)
                    if p is None:
                        problem = f"{problem}; it returned {_shown(out)}"
                except (KeyboardInterrupt, UserCodeTimeout):
                    raise
                except BaseException as exc:
                    raise ConfigError(field, f"the motion function raised at t = {t:g} s ({one_line(exc)})",
                                      body.motion) from None
                if p is None:
                    raise ConfigError(field, f"at t = {t:g} s the motion function must return a position [3] or "
                                      f"(position [3], quaternion xyzw [4]): {problem}", body.motion)
                pos[k], quat[k] = p, q
                budget.check()
    except UserCodeTimeout as exc:
        raise ConfigError(field, f"the motion function did not return within {exc.seconds:g} s (its calls over the "
                          f"whole rollout; stopped at t = {t:g} s)", body.motion) from None
    return pos, quat


def build_world_bodies(scenario: Scenario, times: np.ndarray) -> WorldBodies:
    """Every body's pose at ``times`` [T] (s), with its bounding sphere; ConfigError naming the body's field for
    missing files, bodies without collision geometry, bad motion functions or a constant-velocity body whose
    bounding sphere starts outside the arena."""
    dims = scenario.world.dims
    size = np.asarray(scenario.world.size, dtype=float)
    n_t = times.shape[0]
    names, paths, scales, moving, positions, quats, centres, radii = [], [], [], [], [], [], [], []
    for i, body in enumerate(scenario.bodies):
        where = f"bodies[{i}]"
        path = scenario.resolve_path(body.urdf, f"{where}.urdf")
        if not path.is_file():
            raise ConfigError(f"{where}.urdf", "file not found", body.urdf)
        prims = body_primitives(path, body.scale, f"{where}.urdf")
        q0 = quat_from_rpy(np.radians(body.rpy_deg))
        pos = np.tile(np.asarray(body.position, dtype=float), (n_t, 1))
        quat = np.tile(q0, (n_t, 1))
        if body.motion == "waypoints":
            path_d, _ = waypoint_loop(np.asarray(body.waypoints), np.resize(np.asarray(body.speed), len(body.waypoints)),
                                      times)
            pos[:, :dims] = path_d
        elif body.motion not in ("static", "constant_velocity"):
            pos, quat = _function_poses(body, where, times)
        yaw_only = bool(np.all(np.abs(quat[:, :2]) <= YAW_ONLY_TOL))
        c_local, r = bounding_sphere(prims, dims, yaw_only, where, MAX_COORDINATE_M)
        if body.motion == "constant_velocity":
            c0 = pos[0] + rotation_from_quat(q0) @ c_local
            if np.any(c0[:dims] - r < 0) or np.any(c0[:dims] + r > size):
                raise ConfigError(f"{where}.position", f"the body's bounding sphere (radius {r:.3g} m) must start "
                                  "inside the arena to move with constant velocity", list(body.position))
            cen, _ = cvm_fold(c0[None, :dims], np.asarray(body.velocity, float)[None, :], np.array([r]), size, times)
            pos[:, :dims] = cen[:, 0, :] - (rotation_from_quat(q0) @ c_local)[:dims]
        names.append(body.name)
        paths.append(str(path.resolve()))
        scales.append(body.scale)
        moving.append(body.moving)
        positions.append(pos)
        quats.append(quat)
        centres.append(c_local)
        radii.append(r)
    return WorldBodies(tuple(names), tuple(paths), np.array(scales, float).reshape(-1, 3), np.array(moving, bool),
                       np.stack(positions, axis=1), np.stack(quats, axis=1), np.array(centres).reshape(-1, 3),
                       np.array(radii))


def sphere_tracks(bodies: WorldBodies, dims: int, dt: float, scenario: Scenario) -> tuple[np.ndarray, np.ndarray]:
    """Bounding-sphere centres [T, M, d] (m) and velocities [T, M, d] (m/s) of the moving bodies.

    Velocities: exact for constant-velocity and waypoint bodies (their base translates), central differences of
    the centres (one-sided at the ends) for motion functions."""
    idx = bodies.moving_index
    rot = rotation_from_quat(bodies.orientation[:, idx])                       # [T, M, 3, 3]
    cen = bodies.position[:, idx] + np.einsum("tmij,mj->tmi", rot, bodies.sphere_centre[idx])
    cen = cen[:, :, :dims]
    vel = np.zeros_like(cen)
    size = np.asarray(scenario.world.size, float)
    for j, b in enumerate(idx.tolist()):
        cfg = scenario.bodies[b]
        if cfg.motion == "constant_velocity":
            _, v = cvm_fold(cen[:1, j], np.asarray(cfg.velocity, float)[None, :],
                            bodies.sphere_radius[b:b + 1], size, np.arange(cen.shape[0]) * dt)
            vel[:, j] = v[:, 0]
        elif cfg.motion == "waypoints":
            _, v = waypoint_loop(np.asarray(cfg.waypoints), np.resize(np.asarray(cfg.speed), len(cfg.waypoints)),
                                 np.arange(cen.shape[0]) * dt)
            vel[:, j] = v
        elif cen.shape[0] > 1:
            vel[:, j] = np.gradient(cen[:, j], dt, axis=0)
    return cen, vel


def check_candidates(scenario: Scenario, bodies: WorldBodies) -> None:
    """ConfigError if a start/goal candidate's MAV overlaps a static body (no trial could start or end there)."""
    field = bodies.field()
    if not field.indices("static"):
        return
    dims = scenario.world.dims
    cands = np.asarray(scenario.task.candidates, dtype=float).reshape(-1, dims)
    pts = cands if dims == 3 else np.concatenate([cands, np.full((cands.shape[0], 1), scenario.world.flight_height)],
                                                 axis=1)
    for b in field.indices("static"):
        d = field.body_distance(b, pts, 0)
        bad = np.flatnonzero(d < scenario.drone.radius)
        if bad.size:
            i = int(bad[0])
            raise ConfigError(f"task.candidates[{i}]", f"the MAV there overlaps body {bodies.names[b]!r}",
                              list(scenario.task.candidates[i]))


def _file_digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def bodies_fingerprint(scenario: Scenario) -> list[dict]:
    """Path-free description of the bodies for cache keys and config hashes: each body's settings with its URDF
    replaced by the sha256 of the URDF file and of every mesh it names, and a motion function by its module's
    source digest."""
    out = []
    for i, body in enumerate(scenario.bodies):
        d = {"bound": BOUNDING_RULE, "name": body.name, "scale": list(body.scale), "position": list(body.position),
             "rpy_deg": list(body.rpy_deg), "motion": body.motion, "velocity": list(body.velocity),
             "waypoints": [list(w) for w in body.waypoints], "speed": list(body.speed), "params": dict(body.params)}
        path = scenario.resolve_path(body.urdf)
        if path.is_file():
            digests = [_file_digest(path)]
            try:
                digests += [_file_digest(Path(p.mesh)) for p in body_primitives(path, body.scale) if p.kind == "mesh"]
            except ConfigError:
                pass
            d["urdf_sha256"] = digests
        else:
            d["urdf_sha256"] = None
        if body.motion not in ("static", "constant_velocity", "waypoints"):
            try:
                src = inspect.getsourcefile(import_module(body.motion.partition(":")[0], f"bodies[{i}].motion"))
                d["function_sha256"] = _file_digest(Path(src)) if src else None
            except (ConfigError, TypeError, OSError):  # reported properly when the rollout is built
                d["function_sha256"] = None
        out.append(d)
    return out


def describe(bodies: WorldBodies) -> list[dict]:
    """One line of facts per body (name, moving, bounding radius m) for logs and metric parameters."""
    return [{"name": n, "moving": bool(m), "bounding_radius": float(r)}
            for n, m, r in zip(bodies.names, bodies.moving.tolist(), bodies.sphere_radius.tolist())]

