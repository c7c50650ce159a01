"""The trial loop (DESIGN.md "One trial step", thesis Algorithm 1).

One step t_k -> t_k+1:
 (1) obstacle poses := rollout at t_k; (2) sense with the MAV pose and yaw at t_k; (3) every tracker predicts,
 seen ones update; (4) replan_check -> plan, on failure brake and count; (5) gaze yaw rate; (6) MAV state := the
 trajectory sample at t_k+1 (braking: v -= min(a_max dt, |v|) v/|v|), yaw += clip(rate) dt; (7) at t_k+1 check
 static collision, dynamic collision, goal, time limit (then deadlock) — the first that holds ends the trial.

Environment stepping (``TrialEnv``) is separate from decisions (the planners), so a gymnasium facade can drive
the same core later.
"""

from __future__ import annotations

import hashlib
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pbdyn.config import PlannerEntry, Scenario, canonical_json
from pbdyn.errors import ConfigError
from pbdyn.perception.grid import OccupancyGrid
from pbdyn.perception.perceive import Perception
from pbdyn.perception.tracker import KalmanTracks
from pbdyn.planning.protocols import PlannerContext
from pbdyn.planning.registry import build_planner, resolve_gaze_planner, resolve_trajectory_planner
from pbdyn.planning.trajectory import Trajectory
from pbdyn.planning.view import MAVLimits, View
from pbdyn.sim.collision import sampled_dynamic, sampled_static, swept_dynamic, swept_static
from pbdyn.sim.outcome import Outcome
from pbdyn.sim.result import TrialResult
from pbdyn.world.bullet import PyBulletWorld
from pbdyn.world.imported import bodies_fingerprint
from pbdyn.world.maps import MapSpec, stable_hash64
from pbdyn.world.rollout import Rollout

REST_SPEED = 1e-3  # m/s: "at rest" for the deadlock rule
NORM_EPS = 1e-12


@dataclass(frozen=True)
class TrialSpec:
    """Everything that defines one trial: scenario, map, planner pair, MAV speed, start and goal (m)."""

    scenario: Scenario
    map_spec: MapSpec
    planner: PlannerEntry
    v_max: float
    start: tuple[float, ...]
    goal: tuple[float, ...]

    def resolved(self) -> dict:
        """The canonical, path- and version-free description of the trial (what config_hash hashes)."""
        sc = self.scenario.to_dict()
        skip = {"count", "radius", "speed", "maps_per_setup", "grid_order"}
        if sc["obstacles"]["motion"] != "rvo":
            skip.add("rvo")
        obstacles = {k: v for k, v in sc["obstacles"].items() if k not in skip}
        drone = {k: v for k, v in sc["drone"].items() if k not in ("urdf", "v_max")}
        task = {k: v for k, v in sc["task"].items() if k != "candidates"}
        return {
            "world": sc["world"], "obstacles": obstacles, "map": {"setup": self.map_spec.setup,
                                                                  "replicate": self.map_spec.replicate},
            "static_obstacles": sc["static_obstacles"], "drone": drone, "v_max": float(self.v_max),
            "sensor": sc["sensor"], "tracking": sc["tracking"], "task": task,
            "candidates": sc["task"]["candidates"],
            "start": [float(x) for x in self.start], "goal": [float(x) for x in self.goal],
            "planner": {"trajectory": self.planner.trajectory, "gaze": self.planner.gaze,
                        "trajectory_params": dict(self.planner.trajectory_params),
                        "gaze_params": dict(self.planner.gaze_params)},
            "collision_check": self.scenario.collision_check,
            **({"bodies": bodies_fingerprint(self.scenario)} if self.scenario.is_world else {}),
        }

    @property
    def config_hash(self) -> str:
        """sha256 of the canonical JSON of resolved()."""
        return hashlib.sha256(canonical_json(self.resolved()).encode()).hexdigest()

    @property
    def seed(self) -> int:
        """A per-trial seed (sensor noise, planners that need randomness), derived from config_hash."""
        return stable_hash64(self.config_hash) >> 1


def _parse_point(text: str | None, field_name: str, dims: int) -> tuple[float, ...] | None:
    if text is None:
        return None
    try:
        vals = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise ConfigError(field_name, "must be comma-separated numbers like 4,25", text) from None
    if len(vals) != dims or not all(math.isfinite(v) for v in vals):
        raise ConfigError(field_name, f"must have {dims} finite coordinates", text)
    return vals


def make_trial_spec(scenario: Scenario, map_spec: MapSpec, *, planner: str | None = None, gaze: str | None = None,
                    v_max: float | None = None, start: str | tuple | None = None,
                    goal: str | tuple | None = None) -> TrialSpec:
    """Resolve CLI-style choices into a TrialSpec (defaults: first planner entry, first v_max, first candidate as
    start, last candidate as goal). ``planner`` picks an entry by label or trajectory name, or names a trajectory
    planner; ``gaze`` overrides the entry's gaze planner."""
    entries = scenario.planners
    entry = entries[0]
    if planner is not None:
        match = [e for e in entries if e.label == planner] or [e for e in entries if e.trajectory == planner]
        if gaze is not None:
            match = [e for e in match if e.gaze == gaze] or match
        entry = match[0] if match else PlannerEntry(planner, gaze or entry.gaze)
    if gaze is not None and entry.gaze != gaze:
        entry = PlannerEntry(entry.trajectory, gaze, entry.trajectory_params, {}, "")
    idx = next((i for i, e in enumerate(entries) if e == entry), None)
    resolve_trajectory_planner(entry.trajectory, "--planner" if planner is not None or idx is None
                               else f"planners[{idx}].trajectory")
    resolve_gaze_planner(entry.gaze, "--gaze" if gaze is not None or idx is None else f"planners[{idx}].gaze")
    if v_max is None:
        v = scenario.drone.v_max[0]
    else:
        if not isinstance(v_max, (int, float)) or not math.isfinite(v_max) or v_max <= 0:
            raise ConfigError("--vmax", "must be a positive number", v_max)
        v = float(v_max)
    dims = scenario.world.dims
    cands = scenario.task.candidates
    s = _parse_point(start, "--start", dims) if isinstance(start, str) else (tuple(start) if start else cands[0])
    g = _parse_point(goal, "--goal", dims) if isinstance(goal, str) else (tuple(goal) if goal else cands[-1])
    r = scenario.drone.radius
    for name, pt in (("--start", s), ("--goal", g)):
        for k, x in enumerate(pt):
            if not r <= x <= scenario.world.size[k] - r:
                raise ConfigError(name, f"must lie inside the arena with the MAV's radius ({r:g} m) to spare",
                                  ",".join(f"{c:g}" for c in pt))
    return TrialSpec(scenario, map_spec, entry, v, tuple(map(float, s)), tuple(map(float, g)))


@dataclass
class _Trace:
    """Per-step arrays saved by ``pbdyn run --trace``."""

    t: list = field(default_factory=list)
    p: list = field(default_factory=list)
    v: list = field(default_factory=list)
    a: list = field(default_factory=list)
    yaw: list = field(default_factory=list)
    yaw_rate: list = field(default_factory=list)
    planned: list = field(default_factory=list)
    plan_ok: list = field(default_factory=list)
    track_mean: list = field(default_factory=list)
    track_active: list = field(default_factory=list)
    seen: list = field(default_factory=list)


def brake(p: np.ndarray, v: np.ndarray, a_max: float, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One braking step: v -= min(a_max dt, |v|) v/|v|; p advances with the mean velocity (exact for constant a)."""
    speed = float(np.linalg.norm(v))
    if speed <= 0.0:
        return p.copy(), np.zeros_like(v), np.zeros_like(v)
    dv = min(a_max * dt, speed)
    v1 = v - dv * v / speed
    return p + 0.5 * (v + v1) * dt, v1, (v1 - v) / dt


def _project(x: np.ndarray, limit: float) -> np.ndarray:
    n = float(np.linalg.norm(x))
    return x * (limit / n) if n > limit else x


def _wrap(angle: float) -> float:
    return float((angle + math.pi) % (2.0 * math.pi) - math.pi)


def make_world(spec: TrialSpec, rollout: Rollout, *, gui: bool = False, client=None) -> PyBulletWorld:
    """The PyBullet world of a trial's map: MAV, obstacles, static bodies, walls (imported worlds: static bodies
    by their real shapes, moving ones as their bounding spheres). Reusable for every trial of the same map and
    scenario (run_trial(..., world=...)): trials only move the MAV and the obstacles, which every step sets.
    ``client``: an existing BulletClient to reset and reuse (see PyBulletWorld)."""
    sc = spec.scenario
    world = PyBulletWorld(dims=sc.world.dims, arena_size=sc.world.size, flight_height=sc.world.flight_height,
                          mav_radius=sc.drone.radius, obstacle_radii=rollout.radii, static_bodies=rollout.static,
                          mav_urdf=str(sc.mav_urdf_path()), gui=gui, client=client)
    bodies = rollout.bodies
    if bodies is not None:
        try:
            for b in np.flatnonzero(~bodies.moving).tolist():
                world.add_static_urdf(bodies.urdf[b], bodies.position[0, b], bodies.orientation[0, b],
                                      bodies.scale[b])
        except BaseException:
            world.close()
            raise
    return world


class TrialEnv:
    """The environment side of a trial: world, perception, tracking and the outcome checks (no decisions)."""

    def __init__(self, spec: TrialSpec, rollout: Rollout, *, gui: bool = False, fov_deg: float | None = None,
                 world: PyBulletWorld | None = None):
        sc = spec.scenario
        self.spec = spec
        self.rollout = rollout
        self.dims = sc.world.dims
        self.dt = sc.world.dt
        need = sc.world.n_steps
        if rollout.n_steps < need + 1:
            raise ConfigError("rollout", f"covers {rollout.horizon:g} s, the trial needs {need * self.dt:g} s",
                              rollout.n_steps)
        self.radii = rollout.radii
        self.owns_world = world is None
        self.world = make_world(spec, rollout, gui=gui) if world is None else world
        lo = np.zeros(self.dims)
        hi = np.asarray(sc.world.size, dtype=float)
        self.bounds = (lo, hi)
        self.grid = OccupancyGrid(lo, hi, sc.world.grid_resolution)
        self.fov_deg = float(fov_deg) if fov_deg is not None else sc.sensor.fov_deg
        self.perception = Perception(self.world, self.grid, fov_deg=self.fov_deg, range_m=sc.sensor.range,
                                     resolution_deg=sc.sensor.resolution_deg, noise_std=sc.sensor.noise_std,
                                     rng=np.random.default_rng(spec.seed), vfov_deg=sc.sensor.vfov_deg,
                                     vresolution_deg=sc.sensor.resolution_deg if self.dims == 3 else None)
        tr = sc.tracking
        self.tracker = KalmanTracks(rollout.n_obstacles, self.dims, self.dt, q=tr.q, r=tr.r, p0_pos=tr.p0_pos,
                                    p0_vel=tr.p0_vel, drop_pos_var=tr.drop_pos_var, bounds_lo=lo, bounds_hi=hi)
        self.swept = sc.collision_check == "swept"

    def close(self) -> None:
        """Disconnect the PyBullet client (unless the world was lent by the caller)."""
        if self.owns_world:
            self.world.close()

    def check(self, k: int, p0: np.ndarray, p1: np.ndarray) -> tuple[Outcome | None, float]:
        """Step (7) collision part for the move p0 (t_k) -> p1 (t_k+1): (static/dynamic outcome or None, clearance m)."""
        obs0, _ = self.rollout.at(k)
        obs1, _ = self.rollout.at(k + 1)
        if self.swept:
            st = swept_static(self.world, p0, p1)
            dy = swept_dynamic(p0, p1, obs0, obs1, self.radii, self.spec.scenario.drone.radius)
        else:
            st = sampled_static(self.world, p1)
            dy = sampled_dynamic(p1, obs1, self.radii, self.spec.scenario.drone.radius)
        clearance = min(float(st.min_clearance), float(dy.min_clearance))
        if st.hit and (not dy.hit or st.fraction <= dy.fraction):
            return Outcome.STATIC_COLLISION, clearance
        if dy.hit:
            return Outcome.DYNAMIC_COLLISION, clearance
        return None, clearance


def build_planners(spec: TrialSpec):
    """Instantiate the trial's (trajectory, gaze) planners with their context and params."""
    sc = spec.scenario
    limits = MAVLimits(sc.drone.radius, spec.v_max, sc.drone.a_max, sc.drone.yaw_rate_limit)
    ctx = PlannerContext(sc.world.dims, sc.world.dt, limits, np.zeros(sc.world.dims),
                         np.asarray(sc.world.size, dtype=float), spec.seed)
    idx = next((i for i, e in enumerate(sc.planners) if e == spec.planner), 0)
    tcls = resolve_trajectory_planner(spec.planner.trajectory, f"planners[{idx}].trajectory")
    gcls = resolve_gaze_planner(spec.planner.gaze, f"planners[{idx}].gaze")
    traj = build_planner(tcls, ctx, spec.planner.trajectory_params, f"planners[{idx}].trajectory_params")
    gaze = build_planner(gcls, ctx, spec.planner.gaze_params, f"planners[{idx}].gaze_params")
    return ctx, traj, gaze


SPLITS = ("wall_world_s", "wall_rays_s", "wall_tracking_s", "wall_planning_s", "wall_gaze_s", "wall_collision_s")


def run_trial(spec: TrialSpec, rollout: Rollout, *, gui: bool = False, trace_path: str | Path | None = None,
              gui_sleep: float = 0.0, profile: dict | None = None, world: PyBulletWorld | None = None) -> TrialResult:
    """Fly one trial and return its TrialResult.

    trace_path: save a per-step trace .npz there. profile: if a dict is given, it receives per-step lists of each
    timing split (SPLITS, s), "candidates_built" (the planner's ``last_candidates_built`` when it planned) and
    "planned" (True where replan_check asked for a plan).
    world: a PyBulletWorld from make_world for this map to reuse (batch workers); it is left open.
    """
    wall0 = time.perf_counter()
    sc = spec.scenario
    ctx, planner, gaze = build_planners(spec)
    fov = getattr(gaze, "fov_deg", None)
    env = TrialEnv(spec, rollout, gui=gui, fov_deg=fov, world=world)
    timings = {"wall_setup_s": time.perf_counter() - wall0, **{name: 0.0 for name in SPLITS}}
    step_walls: list[float] = []
    if profile is not None:
        for name in SPLITS + ("candidates_built", "planned"):
            profile[name] = []
    trace = _Trace() if trace_path is not None else None
    dims, dt = ctx.dims, ctx.dt
    limits = ctx.limits
    p = np.asarray(spec.start, dtype=float)
    v = np.zeros(dims)
    a = np.zeros(dims)
    goal = np.asarray(spec.goal, dtype=float)
    to_goal = goal - p
    yaw = math.atan2(to_goal[1], to_goal[0])
    traj: Trajectory | None = None
    fails = total_fails = 0
    state = "PLANNING"
    min_clearance = math.inf
    outcome = Outcome.FREEZING
    n_steps = sc.world.n_steps
    k = 0
    try:
        for k in range(n_steps):
            t = k * dt
            c0 = time.perf_counter()
            obs_p, _ = rollout.at(k)
            env.world.set_obstacle_positions(obs_p)                       # (1)
            env.world.set_mav_pose(p, yaw)
            c1 = time.perf_counter()
            det = env.perception.sense(p, yaw)                            # (2)
            c2 = time.perf_counter()
            env.tracker.step(det.ids, det.centers)                        # (3)
            tracks = env.tracker.tracks(env.radii)
            c3 = time.perf_counter()
            view = View(t, dt, p, v, a, yaw, goal, sc.task.goal_radius, limits, env.bounds[0], env.bounds[1],
                        env.grid, tracks, traj, env.fov_deg, sc.sensor.range, sc.sensor.vfov_deg)
            plan_ok = True
            planned = planner.replan_check(view)
            if planned:                                                   # (4)
                state = "PLANNING"
                new = planner.plan(view)
                if new is None:
                    traj = None
                    fails += 1
                    total_fails += 1
                    plan_ok = False
                else:
                    traj = new
                    fails = 0
                    state = "EXECUTING"
            c4 = time.perf_counter()
            rate = float(gaze.yaw_rate(view, traj))                       # (5)
            if not math.isfinite(rate):
                raise ValueError(f"gaze planner {spec.planner.gaze} returned a non-finite yaw rate")
            rate = min(max(rate, -limits.yaw_rate), limits.yaw_rate)
            c5 = time.perf_counter()
            t1 = t + dt                                                   # (6)
            if traj is not None and traj.covers(t1) and traj.index_at(t1) >= 1:
                p1, v1, a1 = (np.array(x, dtype=float) for x in traj.state_at(t1))
                v1 = _project(v1, limits.v_max)
                a1 = _project(a1, limits.a_max)
            else:
                if traj is not None:
                    traj = None
                    state = "PLANNING"
                p1, v1, a1 = brake(p, v, limits.a_max, dt)
            yaw1 = _wrap(yaw + rate * dt)
            hit, clearance = env.check(k, p, p1)                          # (7)
            c6 = time.perf_counter()
            min_clearance = min(min_clearance, clearance)
            if trace is not None:
                _record(trace, t, p, v, a, yaw, rate, traj, plan_ok, env, det)
            for name, dt_wall in zip(SPLITS, (c1 - c0, c2 - c1, c3 - c2, c4 - c3, c5 - c4, c6 - c5)):
                timings[name] += dt_wall
                if profile is not None:
                    profile[name].append(dt_wall)
            if profile is not None:
                profile["candidates_built"].append(getattr(planner, "last_candidates_built", float("nan")))
                profile["planned"].append(bool(planned))
            step_walls.append(c6 - c0)
            p, v, a, yaw = p1, v1, a1, yaw1
            if hit is not None:
                outcome = hit
                break
            if float(np.linalg.norm(p - goal)) <= sc.task.goal_radius:
                outcome = Outcome.SUCCESS
                break
            if k + 1 >= n_steps:
                outcome = Outcome.FREEZING
                break
            if fails >= sc.task.deadlock_steps and float(np.linalg.norm(v)) < REST_SPEED:
                outcome = Outcome.DEADLOCK
                break
            if gui and gui_sleep > 0:
                time.sleep(gui_sleep)
        steps = k + 1
        grid_discovered = env.grid.discovered()
        tracked = int(env.tracker.ever_tracked)
        tracked_time = float(env.tracker.tracked_time_s)
    finally:
        env.close()
    if trace is not None:
        _save_trace(trace, trace_path, p, v, a, yaw, outcome)
    ms = spec.map_spec
    wall = time.perf_counter() - wall0
    timings["wall_step_mean_s"] = float(np.mean(step_walls)) if step_walls else 0.0
    timings["wall_step_median_s"] = float(np.median(step_walls)) if step_walls else 0.0
    if sc.is_world:   # imported world: the moving bodies, their mean bounding radius and mean speed
        count, speeds = rollout.n_obstacles, np.linalg.norm(rollout.velocities, axis=-1)
        motion, radius = "imported", float(np.mean(rollout.radii)) if count else 0.0
        speed = float(np.mean(speeds)) if count else 0.0
    else:
        count, motion = int(ms.setup["count"]), sc.obstacles.motion
        radius, speed = ms.setup["radius"], ms.setup["speed"]
    return TrialResult(
        gaze=spec.planner.gaze, planner=spec.planner.trajectory, motion_profile=motion,
        map_index=ms.index, map_id=ms.map_id, map_seed=ms.seed, obstacle_count=count,
        obstacle_radius=radius, obstacle_speed=speed, mav_speed=float(spec.v_max),
        start=tuple(spec.start), goal=tuple(spec.goal), flight_time_s=round(steps * dt, 10),
        grid_discovered=grid_discovered, obstacles_tracked=tracked, tracked_time_s=round(tracked_time, 10),
        outcome=outcome.value, final_state=state, reason=outcome.reason, min_clearance_m=float(min_clearance),
        planning_failures=total_fails, steps=steps, planner_label=spec.planner.label, scenario=sc.name,
        map_key=ms.key, config_hash=spec.config_hash, wall_time_s=wall, wall_timings=timings)


def _record(trace: _Trace, t, p, v, a, yaw, rate, traj, plan_ok, env: TrialEnv, det) -> None:
    trace.t.append(t)
    trace.p.append(p.copy())
    trace.v.append(v.copy())
    trace.a.append(a.copy())
    trace.yaw.append(yaw)
    trace.yaw_rate.append(rate)
    trace.plan_ok.append(plan_ok)
    trace.planned.append(None if traj is None else traj.remaining(t).p.copy())
    n, d = env.rollout.n_obstacles, env.dims
    mean = np.full((n, d), np.nan)
    tr = env.tracker.tracks(env.radii)
    mean[tr.ids] = tr.position
    active = np.zeros(n, dtype=bool)
    active[tr.ids] = True
    trace.track_mean.append(mean)
    trace.track_active.append(active)
    seen = np.zeros(n, dtype=bool)
    seen[np.asarray(det.ids, dtype=np.int64)] = True
    trace.seen.append(seen)


def _save_trace(trace: _Trace, path, p, v, a, yaw, outcome: Outcome) -> None:
    """Write the trace .npz atomically: per-step t [S], p/v/a [S, d], yaw [S], yaw_rate [S], plan_ok [S],
    plan [S, Kmax, d] (NaN-padded remaining plan at each step), track_mean [S, N, d] (NaN if inactive),
    track_active [S, N], seen [S, N], final_p/v/a [d], final_yaw, outcome."""
    import os
    import tempfile

    kmax = max([0] + [x.shape[0] for x in trace.planned if x is not None])
    d = p.shape[0]
    plans = np.full((len(trace.t), max(kmax, 1), d), np.nan)
    for i, x in enumerate(trace.planned):
        if x is not None:
            plans[i, : x.shape[0]] = x
    n = len(trace.track_active[0]) if trace.track_active else 0
    arrays = {
        "t": np.asarray(trace.t), "p": np.asarray(trace.p).reshape(-1, d), "v": np.asarray(trace.v).reshape(-1, d),
        "a": np.asarray(trace.a).reshape(-1, d), "yaw": np.asarray(trace.yaw), "yaw_rate": np.asarray(trace.yaw_rate),
        "plan_ok": np.asarray(trace.plan_ok, dtype=bool), "plan": plans,
        "track_mean": np.asarray(trace.track_mean, dtype=float).reshape(len(trace.t), n, d),
        "track_active": np.asarray(trace.track_active, dtype=bool).reshape(len(trace.t), n),
        "seen": np.asarray(trace.seen, dtype=bool).reshape(len(trace.t), n),
        "final_p": p, "final_v": v, "final_a": a, "final_yaw": np.array(yaw), "outcome": np.array(outcome.value),
    }
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".trace-", suffix=".npz", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez_compressed(fh, **arrays)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
