"""One trial's state inside a trial batch (docs/architecture.md "The trial core"; docs/design.md "One trial step").

``TrialState`` holds what one trial is: the MAV's state, its sensor, occupancy grid and tracks, its outcome and the
flight's running statistics, and the per-trial parts of the step (the view planners see, the move's collision check,
the goal/time/deadlock rules). It makes no decisions and is stepped only by pbdyn.sim.batch.TrialBatch, which owns
sensing, tracking and the guarded execution of every trial of a batch (a single trial is a batch of one).
"""

from __future__ import annotations

import math
import time

import numpy as np

from pbdyn.config import trial_span_s
from pbdyn.errors import ConfigError
from pbdyn.perception.grid import OccupancyGrid
from pbdyn.perception.perceive import Perception
from pbdyn.perception.tracker import KalmanTracks
from pbdyn.perception.tracks import readonly
from pbdyn.planning.view import MAVLimits, View
from pbdyn.sim.guard import Action
from pbdyn.sim.collision import (DynamicContact, sampled_dynamic, sampled_static, shape_dynamic, swept_dynamic,
                                 swept_dynamic_many, swept_static)
from pbdyn.outcome import Outcome
from pbdyn.sim.spec import TrialSpec
from pbdyn.sim.start import TrialStart, trial_start
from pbdyn.world.bullet import PyBulletWorld
from pbdyn.world.geometry import wrap_angle
from pbdyn.world.rollout import Rollout


def vector_norm(x: np.ndarray) -> float:
    """|x| of a float vector [d] as numpy's linalg.norm computes it (the square root of x.dot(x)), without its
    dispatch (a few us per call on the step's path)."""
    return math.sqrt(float(x.dot(x)))


REST_SPEED = 1e-3  # m/s: "at rest" for the deadlock rule
GOAL_TIE_M = 1e-9  # m: under thesis_program a distance this far above goal_radius is the program's exact tie (<=)

SENSE_SPLITS = ("wall_world_s", "wall_rays_s", "wall_tracking_s")
"""Wall-time splits of steps (1), (2), (3)."""


def make_world(spec: TrialSpec, rollout: Rollout, *, gui: bool = False, client=None) -> PyBulletWorld:
    """The PyBullet world of a trial's map: MAV, obstacles, static bodies, walls (imported worlds: every body by
    its real shape; the moving ones' bounding spheres only cull rays). Reusable for every trial and batch of the same
    map and scenario (TrialBatch(..., world=...)): trials only move the MAV and the obstacles, which every step sets.
    ``client``: an existing BulletClient to reset and reuse (see PyBulletWorld)."""
    sc = spec.scenario
    bodies = rollout.bodies
    urdfs = None if bodies is None or not bodies.moving.any() else \
        [(bodies.urdf[b], tuple(bodies.scale[b])) for b in bodies.moving_index]
    world = PyBulletWorld(dims=sc.world.dims, arena_size=sc.world.size, flight_height=sc.world.flight_height,
                          mav_radius=sc.drone.radius, obstacle_radii=rollout.radii, static_bodies=rollout.static,
                          mav_urdf=str(sc.mav_urdf_path()), gui=gui, client=client, obstacle_urdfs=urdfs)
    if bodies is not None:
        try:
            for b in np.flatnonzero(~bodies.moving).tolist():
                world.add_static_urdf(bodies.urdf[b], bodies.position[0, b], bodies.orientation[0, b],
                                      bodies.scale[b])
        except BaseException:
            world.close()
            raise
    return world


def nominal_radius(spec: TrialSpec, rollout: Rollout) -> float:
    """The setup's obstacle radius (m) when it is one number, else the mean of the map's radii (0 without
    obstacles): the radius the thesis program gave a restarted track (tracking.drop_rule = "program")."""
    r = spec.map_spec.setup.get("radius")
    if isinstance(r, (int, float)) and not isinstance(r, bool):
        return float(r)
    return float(np.mean(rollout.radii)) if rollout.n_obstacles else 0.0


class TrialState:
    """One trial of a batch. Attributes: ``k`` (step index), ``t`` (s), the MAV state
    ``position``/``velocity``/``acceleration`` (m, m/s, m/s^2, world frame [d]) and ``yaw`` (rad), ``detections`` (the
    last sensing), ``tracks``, ``outcome`` (None while running), ``reason``, ``min_clearance`` (m), ``sense_timings``
    (SENSE_SPLITS of the last sensing, s) and ``collision_wall_s`` (the last step's (6)-(7) time, s), ``max_speed``
    (m/s) and ``max_accel`` (m/s^2: the largest of the executed samples' |a| and |v_k+1 - v_k| / dt) and
    ``path_length`` (m: the sum of |p_k+1 - p_k| over the executed steps) of the flight so far. ``start``
    (pbdyn.sim.start.TrialStart): the rollout flown and the rollout step ``k0`` at which the trial's t = 0 lies (the
    start rule; ``start_step``: that step chosen by the caller instead). Times (``t``, the views' times) are trial
    times: t = 0 at the start. ``world`` is the batch's PyBulletWorld (shared by the batch's trials)."""

    def __init__(self, spec: TrialSpec, rollout: Rollout, world: PyBulletWorld, *, fov_deg: float | None = None,
                 start_step: int | None = None):
        sc = spec.scenario
        self.spec = spec
        self.dims = sc.world.dims
        self.dt = sc.world.dt
        self.n_steps = sc.world.n_steps
        task = sc.task
        need = int(round(trial_span_s(sc.world, task) / self.dt))
        if start_step is not None:       # a start step chosen by the caller (a vector environment's next tick)
            need = start_step + self.n_steps + 1
        if rollout.n_steps < need + 1:
            raise ConfigError("rollout", f"covers {rollout.horizon:g} s, the trial needs {need * self.dt:g} s "
                              f"(time limit and start rule {task.start_rule!r})", rollout.n_steps)
        self.start = trial_start(spec, rollout) if start_step is None else TrialStart(rollout, int(start_step))
        self.rollout = rollout = self.start.rollout
        self.k0 = self.start.k0
        self.radii = rollout.radii
        self.limits = MAVLimits(sc.drone.radius, spec.v_max, sc.drone.a_max, sc.drone.yaw_rate_limit)
        self.goal = np.asarray(spec.goal, dtype=float)
        self.goal_radius = sc.task.goal_radius
        # thesis_program: positions lie on the program's 0.1 m pixels, where it tested |p - goal| <= 10 px exactly;
        # in metres such a tie (e.g. 0.8 m and 0.6 m off) rounds a few ulps above the radius
        self._goal_reach = self.goal_radius + (0.0 if sc.physical else GOAL_TIE_M)
        self.deadlock_steps = sc.task.deadlock_steps
        self.world = world
        lo = np.zeros(self.dims)
        hi = np.asarray(sc.world.size, dtype=float)
        self.bounds = (lo, hi)
        self._view_consts = tuple(readonly(np.array(x, dtype=float)) for x in (self.goal, lo, hi))  # shared by views
        self.fov_deg = float(fov_deg) if fov_deg is not None else sc.sensor.fov_deg
        self.swept = sc.collision_check == "swept"
        bodies = rollout.bodies
        self.shape_bodies = None if bodies is None or not bodies.moving.any() else bodies.moving_index
        self.sense_ahead = 1 if sc.sensor.obstacles_at == "next" else 0
        self.grid: OccupancyGrid | None = None
        self.perception: Perception | None = None
        self.tracker: KalmanTracks | None = None
        self.detections = None
        self.tracks = None
        self.k = 0
        self.outcome: Outcome | None = None
        self.reason = ""
        self.max_speed = 0.0
        self.max_accel = 0.0
        self.path_length = 0.0

    def begin(self) -> None:
        """Start the trial (before its first sensing, which the batch makes): fresh grid, tracks and sensor noise;
        the MAV at the start, at rest, facing the goal (or task.start_yaw_deg)."""
        sc = self.spec.scenario
        lo, hi = self.bounds
        self.grid = OccupancyGrid(lo, hi, sc.world.grid_resolution)
        self.perception = Perception(self.world, self.grid, fov_deg=self.fov_deg, range_m=sc.sensor.range,
                                     resolution_deg=sc.sensor.resolution_deg, noise_std=sc.sensor.noise_std,
                                     rng=np.random.default_rng(self.spec.seed), vfov_deg=sc.sensor.vfov_deg,
                                     vresolution_deg=sc.sensor.resolution_deg if self.dims == 3 else None,
                                     model=sc.sensor.model, rays=sc.sensor.rays, march_step=sc.sensor.march_step,
                                     march_rule=sc.sensor.march_rule)
        tr = sc.tracking
        self.tracker = KalmanTracks(self.rollout.n_obstacles, self.dims, self.dt, q=tr.q, r=tr.r, p0_pos=tr.p0_pos,
                                    p0_vel=tr.p0_vel, drop_pos_var=tr.drop_pos_var, bounds_lo=lo, bounds_hi=hi,
                                    drop_rule=tr.drop_rule, nominal_radius=nominal_radius(self.spec, self.rollout),
                                    track_radius=tr.track_radius)
        self.position = np.asarray(self.spec.start, dtype=float)
        self.velocity = np.zeros(self.dims)
        self.acceleration = np.zeros(self.dims)
        if sc.task.start_yaw_deg is None:
            to_goal = self.goal - self.position
            self.yaw = math.atan2(to_goal[1], to_goal[0])
        else:
            self.yaw = wrap_angle(math.radians(sc.task.start_yaw_deg))
        self.k = 0
        self.outcome = None
        self.reason = ""
        self.min_clearance = math.inf
        self.max_speed = 0.0
        self.max_accel = 0.0
        self.path_length = 0.0
        self.collision_wall_s = 0.0
        self.sense_timings = (0.0, 0.0, 0.0)

    @property
    def t(self) -> float:
        """Time of the current step (s)."""
        return self.k * self.dt

    @property
    def done(self) -> bool:
        """True once an outcome has ended the trial."""
        return self.outcome is not None

    @property
    def steps(self) -> int:
        """Steps flown so far (the flight time is steps * dt)."""
        return self.k

    def sense_index(self) -> int:
        """The rollout step whose obstacle poses this step senses (self.rollout)."""
        return self.k0 + self.k + self.sense_ahead

    def pose_obstacles(self) -> None:
        """Step (1): the world's obstacles at the rollout step sense_index() (trials that share the world, the
        rollout and that step need it once)."""
        k = self.sense_index()
        obs_p, _ = self.rollout.at(k)
        self.world.set_obstacle_positions(obs_p, self._body_poses(k))

    def track(self) -> None:
        """Step (3): every track predicts, the detected ones update (self.detections); self.tracks is the result."""
        self.tracker.step(self.detections.ids, self.detections.centers)
        self.tracks = self.tracker.tracks(self.radii)

    def _body_poses(self, k: int):
        """(base positions [M, 3], orientations [M, 4]) of an imported world's moving bodies at rollout step k, or
        None (generated obstacles)."""
        if self.shape_bodies is None:
            return None
        b = self.rollout.bodies
        return b.position[k, self.shape_bodies], b.orientation[k, self.shape_bodies]

    def view(self, trajectory=None) -> View:
        """The read-only snapshot planners see at t_k, with the plan in execution (or None)."""
        sc = self.spec.scenario
        goal, lo, hi = self._view_consts
        return View.of_owned(self.t, self.dt, self.position, self.velocity, self.acceleration, self.yaw, goal,
                             self.goal_radius, self.limits, lo, hi, self.grid, self.tracks, trajectory, self.fov_deg,
                             sc.sensor.range, sc.sensor.vfov_deg)

    def _move(self, action: Action, dynamic: DynamicContact | None = None) -> None:
        """Steps (6)-(7) of an action the batch's guard let through (only TrialBatch.step calls it): the MAV to the action's state at t_k+1, turned
        by the clipped yaw rate; then static collision, dynamic collision, goal, time limit and deadlock, in that
        order; the first that holds ends the trial. ``dynamic``: this move's obstacle contact when the batch checked
        it together with other trials' (dynamic_batch_key)."""
        c5 = time.perf_counter()
        lim = self.limits.yaw_rate
        rate = min(max(float(action.yaw_rate), -lim), lim)
        p1, v1, a1 = action.position, action.velocity, action.acceleration
        yaw1 = float(wrap_angle(self.yaw + rate * self.dt))
        hit, clearance = self.check(self.k, self.position, p1, dynamic)  # (7)
        self.collision_wall_s = time.perf_counter() - c5
        self.min_clearance = min(self.min_clearance, clearance)
        dv = v1 - self.velocity
        self.max_speed = max(self.max_speed, math.sqrt(float(v1 @ v1)))
        self.max_accel = max(self.max_accel, math.sqrt(float(a1 @ a1)), math.sqrt(float(dv @ dv)) / self.dt)
        dp = p1 - self.position
        self.path_length += math.sqrt(float(dp @ dp))
        self.position, self.velocity, self.acceleration, self.yaw = p1, v1, a1, yaw1
        self.k += 1
        if hit is not None:
            self.end(hit)
        elif vector_norm(self.position - self.goal) <= self._goal_reach:
            self.end(Outcome.SUCCESS)
        elif self.k >= self.n_steps:
            self.end(Outcome.FREEZING)
        elif action.consecutive_failures >= self.deadlock_steps and vector_norm(self.velocity) < REST_SPEED:
            self.end(Outcome.DEADLOCK)

    def dynamic_batch_key(self):
        """A key shared by the trials whose next move is checked against the same obstacles in the same step (the
        same rollout, rollout step and MAV radius), so that their swept checks run together (check_dynamic_many);
        None when this trial's check cannot be shared (sampled checks, an imported world's moving bodies)."""
        if not self.swept or self.shape_bodies is not None:
            return None
        return (id(self.rollout), self.k0 + self.k, self.spec.scenario.drone.radius)

    def end(self, outcome: Outcome, reason: str | None = None) -> None:
        """End the trial now with ``outcome`` (reason: a specific explanation, default the outcome's own)."""
        self.outcome = outcome
        self.reason = outcome.reason if reason is None else reason

    def check(self, k: int, p0: np.ndarray, p1: np.ndarray,
              dynamic: DynamicContact | None = None) -> tuple[Outcome | None, float]:
        """Step (7) collision part for the move p0 (t_k) -> p1 (t_k+1) of trial step k: (static/dynamic outcome or
        None, clearance m). ``dynamic``: the obstacles' contact of this move when already known (check_dynamic_many)."""
        r = self.spec.scenario.drone.radius
        k0, k1 = self.k0 + k, self.k0 + k + 1
        st = swept_static(self.world, p0, p1) if self.swept else sampled_static(self.world, p1)
        if dynamic is not None:
            dy = dynamic
        elif self.shape_bodies is not None:      # an imported world's moving bodies: their real shapes
            b = self.rollout.bodies
            dy = shape_dynamic(b.field(), self.shape_bodies, b.position[k0, self.shape_bodies],
                               b.position[k1, self.shape_bodies], p0, p1, k1, r, self.world.to_world3, self.swept)
        elif self.swept:
            dy = swept_dynamic(p0, p1, self.rollout.at(k0)[0], self.rollout.at(k1)[0], self.radii, r)
        else:
            dy = sampled_dynamic(p1, self.rollout.at(k1)[0], self.radii, r)
        clearance = min(float(st.min_clearance), float(dy.min_clearance))
        if st.hit and (not dy.hit or st.fraction <= dy.fraction):
            return Outcome.STATIC_COLLISION, clearance
        if dy.hit:
            return Outcome.DYNAMIC_COLLISION, clearance
        return None, clearance


def check_dynamic_many(states: list, targets: list) -> list[DynamicContact]:
    """The swept obstacle contacts of the moves state.position -> target of trials (TrialStates) with one
    dynamic_batch_key, all at once (the same floats as each trial's own check)."""
    state = states[0]
    k0 = state.k0 + state.k
    return swept_dynamic_many(np.array([s.position for s in states]), np.array(targets), state.rollout.at(k0)[0],
                              state.rollout.at(k0 + 1)[0], state.radii, state.spec.scenario.drone.radius)
