"""One trial (docs/design.md "One trial step", thesis Algorithm 1): a short loop over the steppable core.

The environment (pbdyn.sim.env.TrialEnv) owns steps (1)-(3), (6) and (7); the agent (pbdyn.sim.agent.Agent) owns
steps (4)-(5), braking and the plan contract; observers (pbdyn.sim.observers) record traces and profiles and pace
the GUI. ``run_trial`` wires them together and turns the ended trial into its TrialResult.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np

from pbdyn.planning.registry import pair_fingerprint
from pbdyn.sim.agent import Agent, brake, build_planners
from pbdyn.sim.env import TrialEnv, make_world
from pbdyn.sim.observers import SPLITS, ProfileObserver, StepRecord, TraceObserver
from pbdyn.outcome import Outcome
from pbdyn.sim.result import TrialResult
from pbdyn.sim.spec import TrialSpec, make_trial_spec
from pbdyn.world.bullet import PyBulletWorld
from pbdyn.world.rollout import Rollout

__all__ = ["SPLITS", "TrialEnv", "TrialSpec", "brake", "build_planners", "make_trial_spec", "make_world",
           "run_trial"]


def run_trial(spec: TrialSpec, rollout: Rollout, *, gui: bool = False, trace_path: str | Path | None = None,
              gui_sleep: float = 0.0, profile: dict | None = None, world: PyBulletWorld | None = None,
              trajectory_planner=None, gaze_planner=None, observers: list | None = None,
              gui_follow: bool = False) -> TrialResult:
    """Fly one trial and return its TrialResult.

    gui: show the PyBullet GUI (pbdyn.sim.gui.GuiView: the arena framed, or followed with ``gui_follow``; field of
    view, plan and goal as debug lines; paced to real time when gui_sleep > 0). trace_path: save a per-step trace
    .npz there. profile: if a dict is given, it receives per-step lists of each
    timing split (SPLITS, s), "candidates_built" (the planner's ``last_candidates_built`` when it planned) and
    "planned" (True where replan_check asked for a plan).
    world: a PyBulletWorld from make_world for this map to reuse (batch workers); it is left open.
    trajectory_planner, gaze_planner: a planner class or instance used instead of the spec's named one (the
    row keeps the spec's names). observers: extra observers (pbdyn.sim.observers.Observer).
    """
    wall0 = time.perf_counter()
    agent = Agent(spec, trajectory_planner, gaze_planner)
    env = TrialEnv(spec, rollout, gui=gui, fov_deg=agent.fov_deg, world=world)
    watchers = list(observers or [])
    if profile is not None:
        watchers.append(ProfileObserver(profile))
    if trace_path is not None:
        watchers.append(TraceObserver(trace_path))
    if gui:
        from pbdyn.sim.gui import GuiView

        watchers.append(GuiView(spec.scenario.world.dt, follow=gui_follow, real_time=gui_sleep > 0))
    timings = {"wall_setup_s": time.perf_counter() - wall0, **{name: 0.0 for name in SPLITS}}
    step_walls: list[float] = []
    plan_walls: list[float] = []
    try:
        env.reset()
        while not env.done:
            c0 = time.perf_counter()
            sensed = env.sense_timings
            view = env.view(agent.trajectory)
            decision = agent.act(view)
            if decision.violation is not None:
                env.end(Outcome.INVALID_PLAN, decision.violation.reason)
                break
            act = decision.action
            record_at = (env.t, env.position, env.velocity, env.acceleration, env.yaw, env.tracks,
                         env.detections.ids)
            env.step(act)
            splits = (*sensed, decision.planning_wall_s, decision.gaze_wall_s, env.collision_wall_s)
            for name, value in zip(SPLITS, splits):
                timings[name] += value
            plan_walls.append(decision.planning_wall_s)
            step_walls.append(time.perf_counter() - c0)   # the whole step (its sensing is the next one's: as long)
            if watchers:
                t, p, v, a, yaw, tracks, ids = record_at
                rate = min(max(act.yaw_rate, -env.limits.yaw_rate), env.limits.yaw_rate)
                record = StepRecord(t, p, v, a, yaw, rate, decision.planned, decision.plan_ok, tracks, ids, splits)
                for w in watchers:
                    w.on_step(env, agent, decision, record)
        for w in watchers:
            w.on_end(env, agent)
        grid_discovered = env.grid.discovered()
        tracked = int(env.tracker.ever_tracked)
        tracked_time = float(env.tracker.tracked_time_s)
    finally:
        env.close()
    step_summary(timings, step_walls, plan_walls)
    return _result(spec, rollout, env, agent, grid_discovered, tracked, tracked_time,
                   time.perf_counter() - wall0, timings)


def step_summary(timings: dict, step_walls: list, plan_walls: list) -> None:
    """Add the per-step summaries to a trial's wall timings (s): the mean and median step, and the median and 99th
    percentile of the planner's time per step (wall_planning_median_s, wall_planning_p99_s; 0 without steps)."""
    timings["wall_step_mean_s"] = float(np.mean(step_walls)) if step_walls else 0.0
    timings["wall_step_median_s"] = float(np.median(step_walls)) if step_walls else 0.0
    timings["wall_planning_median_s"] = float(np.median(plan_walls)) if plan_walls else 0.0
    timings["wall_planning_p99_s"] = float(np.percentile(plan_walls, 99)) if plan_walls else 0.0


def _result(spec: TrialSpec, rollout: Rollout, env: TrialEnv, agent: Agent, grid_discovered: int, tracked: int,
            tracked_time: float, wall: float, timings: dict) -> TrialResult:
    sc = spec.scenario
    ms = spec.map_spec
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
        start=tuple(spec.start), goal=tuple(spec.goal), flight_time_s=round(env.steps * env.dt, 10),
        grid_discovered=grid_discovered, obstacles_tracked=tracked, tracked_time_s=round(tracked_time, 10),
        outcome=env.outcome.value, final_state=agent.state, reason=_reason(env),
        min_clearance_m=float(env.min_clearance), planning_failures=agent.total_failures, steps=env.steps,
        planner_label=spec.planner.label, scenario=sc.name, map_key=ms.key, config_hash=spec.config_hash,
        planner_fingerprint=_fingerprint(spec), profile=sc.profile, start_delay_s=round(env.start.time_s, 10),
        max_speed_mps=env.max_speed, max_accel_mps2=env.max_accel,
        limits_exceeded=limits_exceeded(env.max_speed, env.max_accel, env.limits.v_max, env.limits.a_max),
        **task_metrics(spec, env.rollout, env.start.time_s), path_length_m=round(env.path_length, 10),
        wall_time_s=wall, wall_timings=timings)


TASK_T_MAX_S = 12.0
"""Horizon (s) of the task metrics (survivability's T_max, thesis 4-1); shortened to what the rollout covers."""


def task_metrics(spec: TrialSpec, rollout: Rollout, start_time: float) -> dict:
    """The trial's task metrics (pbdyn.metrics.task) on the flown ``rollout`` from ``start_time`` (s): the
    TrialResult fields task_survivability_s and task_flux_per_s (None where undefined)."""
    from pbdyn.metrics.cached import resolve_backend
    from pbdyn.metrics.task import corridor_flux, corridor_survivability

    sc = spec.scenario
    t_max = min(TASK_T_MAX_S, rollout.horizon - float(start_time))
    if t_max <= 0:
        return {"task_survivability_s": None, "task_flux_per_s": None}
    r = sc.drone.radius
    backend = resolve_backend(sc, "auto")
    key = (tuple(spec.start), tuple(spec.goal), float(start_time), float(r), float(t_max), backend)
    memo = _task_memo(rollout)
    if key not in memo:
        surv, _ = corridor_survivability(rollout, spec.start, spec.goal, start_time=start_time, mav_radius=r,
                                         t_max=t_max, backend=backend)
        flux, _ = corridor_flux(rollout, spec.start, spec.goal, start_time=start_time, mav_radius=r, horizon=t_max)
        memo[key] = {"task_survivability_s": None if not np.isfinite(surv) else round(surv, 10),
                     "task_flux_per_s": None if not np.isfinite(flux) else round(flux, 12)}
    return dict(memo[key])


_TASK_MEMOS: list = []
"""(rollout, {task key: task metrics}) of the last few rollouts: the trials of one map that share a task (other
MAV speeds and planner pairs) share its metrics, which are a function of the rollout and the key alone."""


_TASK_MEMOS_LOCK = threading.Lock()


def _task_memo(rollout: Rollout) -> dict:
    """The task-metrics memo of ``rollout`` (by identity; the 4 most recent rollouts keep theirs)."""
    with _TASK_MEMOS_LOCK:
        for i, (ro, memo) in enumerate(_TASK_MEMOS):
            if ro is rollout:
                if i:
                    _TASK_MEMOS.insert(0, _TASK_MEMOS.pop(i))
                return memo
        _TASK_MEMOS.insert(0, (rollout, {}))
        del _TASK_MEMOS[4:]
        return _TASK_MEMOS[0][1]


LIMIT_TOL = 1e-6
"""Relative tolerance before an executed speed or acceleration counts as exceeding its limit (rounding of the
braking step and of the samples' finite differences)."""


def limits_exceeded(max_speed: float, max_accel: float, v_max: float, a_max: float) -> str:
    """"" if max_speed <= v_max and max_accel <= a_max (relative tolerance LIMIT_TOL), else e.g.
    "acceleration 31.2 m/s^2 > a_max 4 m/s^2 (7.80x)"; "; "-separated when both were exceeded."""
    out = []
    for name, value, limit, unit in (("speed", max_speed, v_max, "m/s"), ("acceleration", max_accel, a_max, "m/s^2")):
        if value > limit * (1.0 + LIMIT_TOL):
            sym = "v_max" if name == "speed" else "a_max"
            out.append(f"{name} {value:.3g} {unit} > {sym} {limit:g} {unit} ({value / limit:.2f}x)")
    return "; ".join(out)


def _reason(env: TrialEnv) -> str:
    """The outcome's reason, with a note when the "first_clear" start rule found no clear start."""
    if env.start.clear:
        return env.reason
    task = env.spec.scenario.task
    return (f"{env.reason} (the start was not clear for {task.start_window_s:g} s within {task.start_wait_max_s:g} "
            f"s: began at the clearest moment, t = {env.start.time_s:g} s)")


def _fingerprint(spec: TrialSpec) -> str:
    """The planner pair's code fingerprint (pbdyn.planning.registry.pair_fingerprint); "" for a planner that
    cannot be imported by its name (e.g. a class defined inside a function)."""
    try:
        return pair_fingerprint(spec.planner.trajectory, spec.planner.gaze)
    except Exception:
        return ""
