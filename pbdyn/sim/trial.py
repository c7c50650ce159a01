"""Flying trials (docs/architecture.md "The trial core", thesis Algorithm 1): the one loop over the trial core.

``fly_trials`` flies N >= 1 trials of one map together: the core (pbdyn.sim.batch.TrialBatch) owns steps (1)-(3), (6) and
(7), shared across the trials; one agent per trial (pbdyn.sim.agent.Agent) owns steps (4)-(5), braking and the plan
contract; observers (pbdyn.sim.observers) record traces and profiles and pace the GUI, per trial. ``run_trial`` is a
batch of one. Each ended trial becomes its TrialResult.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from pbdyn import usercode
from pbdyn.planning.registry import recorded_fingerprint
from pbdyn.sim.agent import Agent, brake, build_planners
from pbdyn.sim.batch import TrialBatch
from pbdyn.sim.observers import SPLITS, ProfileObserver, TraceObserver
from pbdyn.sim.result import TrialResult
from pbdyn.sim.spec import TrialSpec, make_trial_spec
from pbdyn.sim.state import TrialState, make_world
from pbdyn.usercode import decision_watchdog
from pbdyn.world.bullet import PyBulletWorld
from pbdyn.world.rollout import Rollout

__all__ = ["EXECUTIONS", "SPLITS", "TrialBatch", "TrialSpec", "brake", "build_planners", "fly_trials", "make_trial_spec",
           "make_world", "run_trial"]


EXECUTIONS = ("physical", "thesis_program")
"""The execution rules a flight may be switched to (docs/profiles.md): they set the agents and the guard together."""


def run_trial(spec: TrialSpec, rollout: Rollout, *, gui: bool = False, trace_path: str | Path | None = None,
              gui_sleep: float = 0.0, profile: dict | None = None, world: PyBulletWorld | None = None,
              trajectory_planner=None, gaze_planner=None, observers: list | None = None,
              gui_follow: bool = False, execution: str | None = None) -> TrialResult:
    """Fly one trial (a batch of one) and return its TrialResult; what the trial raised is raised.

    gui: show the PyBullet GUI (pbdyn.sim.gui.GuiView: the arena framed, or followed with ``gui_follow``; field of
    view, plan and goal as debug lines; paced to real time when gui_sleep > 0). trace_path: save a per-step trace
    .npz there. profile: if a dict is given, it receives per-step lists of each
    timing split (SPLITS, s), "candidates_built" (the planner's ``last_candidates_built`` when it planned) and
    "planned" (True where replan_check asked for a plan).
    world: a PyBulletWorld from make_world for this map to reuse (batch workers); it is left open.
    trajectory_planner, gaze_planner: a planner class or instance used instead of the spec's named one (the
    row keeps the spec's names). observers: extra observers (pbdyn.sim.observers.Observer). execution: as fly_trials'.
    """
    watchers = list(observers or [])
    if profile is not None:
        watchers.append(ProfileObserver(profile))
    if trace_path is not None:
        watchers.append(TraceObserver(trace_path))
    if gui:
        from pbdyn.sim.gui import GuiView

        watchers.append(GuiView(spec.scenario.world.dt, follow=gui_follow, real_time=gui_sleep > 0))
    return fly_trials([spec], rollout, world=world, gui=gui, observers=[watchers],
               planners=[(trajectory_planner, gaze_planner)], raise_errors=True, execution=execution)[0]


def fly_trials(specs: Sequence[TrialSpec], rollout: Rollout, *, world: PyBulletWorld | None = None, gui: bool = False,
        observers: Sequence[list] | None = None, planners: Sequence[tuple] | None = None,
        step_walls: list | None = None, on_result=None, raise_errors: bool = False,
        execution: str | None = None) -> list:
    """Fly ``specs`` (trials of one map and scenario, in any mix of planner pairs, MAV speeds and start/goal pairs)
    together on ``rollout``: one TrialBatch, one Agent per trial. Returns, per spec in order, its TrialResult or the
    Exception that ended it (a planner or trial that raises ends only its own trial; ``raise_errors``: the first such
    exception is raised instead, once the batch is closed).

    world: make_world of that map to use (left open); else the batch makes its own (``gui``: shown; a batch of one).
    observers: per trial, a list of observers (pbdyn.sim.observers.Observer). planners: per trial, (trajectory,
    gaze) classes or instances used instead of the spec's named ones (None: the spec's). execution: the one switch
    of the execution rules, "physical" or "thesis_program" (EXECUTIONS; default: each scenario's profile): it sets
    the agents (their plan checks, braking and planners' parameters) and the guard together. step_walls: a list
    that receives, per spec in order, the wall time (s) of each of its steps: its own parts, its share of the
    shared work and of the rest of the tick (_share_rest), so that the steps account for the loop's time.
    on_result(index, result_or_exception) is called as each trial ends (batch workers stream rows)."""
    if execution is not None and execution not in EXECUTIONS:
        raise ValueError(f"execution must be one of {', '.join(EXECUTIONS)} or None (got {execution!r})")
    physical = None if execution is None else execution == "physical"
    n = len(specs)
    out = _Results(n, on_result)
    watchers = [list(w) for w in observers] if observers is not None else [[] for _ in range(n)]
    given = list(planners) if planners is not None else [(None, None)] * n
    agents: list[Agent | None] = [None] * n
    agent_s = [0.0] * n
    for i, spec in enumerate(specs):
        t0 = time.perf_counter()
        try:
            agents[i] = Agent(spec, *given[i], physical=physical)
        except Exception as exc:
            if raise_errors:
                raise
            out[i] = exc
        agent_s[i] = time.perf_counter() - t0
    flying = [i for i in range(n) if agents[i] is not None]
    logs: dict[int, _Log] = {}
    if flying:
        t0 = time.perf_counter()
        batch = TrialBatch([specs[i] for i in flying], rollout, world=world, gui=gui,
                           agents=[agents[i] for i in flying])
        world_share = (time.perf_counter() - t0 - sum(batch.setup_s)) / len(flying)
        try:
            for b, i in enumerate(flying):
                logs[i] = _Log(agent_s[i] + batch.setup_s[b] + world_share)
                if watchers[i]:
                    batch.watch(b, watchers[i])
            budget = usercode.PLANNER_CALL_TIMEOUT_S    # one timer for the loop: plug-ins' decisions are budgeted
            with (decision_watchdog(budget) if any(agents[i].plugin for i in flying) else contextlib.nullcontext()):
                _flight(batch, flying, specs, rollout, agents, logs, out)
        finally:
            batch.close()
    if raise_errors:
        for v in out.items:
            if isinstance(v, BaseException):
                raise v
    if step_walls is not None:
        step_walls.extend(logs[i].step_walls if i in logs else [] for i in range(n))
    return list(out.items)


class _Log:
    """One trial's wall times: setup, the SPLITS summed over its steps, each step's wall time and planning time."""

    def __init__(self, setup_s: float):
        self.timings = {"wall_setup_s": setup_s, **{name: 0.0 for name in SPLITS}}
        self.step_walls: list[float] = []
        self.plan_walls: list[float] = []


class _Results:
    """The per-trial results of a flight; setting one also reports it to ``on_result``."""

    def __init__(self, n: int, on_result=None):
        self.items: list = [None] * n
        self.on_result = on_result

    def __setitem__(self, i: int, value) -> None:
        self.items[i] = value
        if self.on_result is not None:
            self.on_result(i, value)


def _flight(batch: TrialBatch, flying: list[int], specs, rollout: Rollout, agents: list, logs: dict,
            out: _Results) -> None:
    """The loop of fly_trials(): each tick the batch steps every trial (its agent decides, the guard, the move and the
    checks, the next sensing, the observers), each step's wall times are logged, and the trials that ended become
    results (those that raised, their exceptions)."""
    window = time.perf_counter()                 # a tick's window: from its sensing to the next tick's sensing
    report = batch.start()
    for b, exc in report.errors.items():
        out[flying[b]] = exc
    results_s = 0.0                              # the results made in the window: not part of its steps
    while not batch.done:
        report = batch.step()                    # (4)-(7), then the next tick's (1)-(3)
        for b, exc in report.errors.items():
            out[flying[b]] = exc
        stepped = []
        for b, splits in report.splits.items():
            if b in report.errors:
                continue
            log = logs[flying[b]]
            timings = log.timings
            for name, value in zip(SPLITS, splits):
                timings[name] += value
            log.step_walls.append(sum(splits))
            log.plan_walls.append(splits[3])
            stepped.append(log)
        _share_rest(stepped, batch.sensed_at - window - results_s)
        window = batch.sensed_at
        results_s = 0.0
        if report.ended:
            t0 = time.perf_counter()
            for b in report.ended:
                i = flying[b]
                try:
                    out[i] = _result(specs[i], rollout, batch.states[b], agents[i], logs[i])
                except Exception as exc:
                    out[i] = exc
            results_s = time.perf_counter() - t0


def _share_rest(stepped: list[_Log], tick_s: float) -> None:
    """Make the steps of one tick account for all of its time (s; the results made in it excluded): what the
    trials' step splits did not measure (views, the act wrapper, each step's bookkeeping, grouping, the trials
    started) is shared out equally among the trials that stepped."""
    if not stepped:
        return
    rest = (tick_s - sum(log.step_walls[-1] for log in stepped)) / len(stepped)
    if rest > 0.0:
        for log in stepped:
            log.step_walls[-1] += rest


def step_summary(timings: dict, step_walls: list, plan_walls: list) -> None:
    """Add the per-step summaries to a trial's wall timings (s): the mean and median step, and the median and 99th
    percentile of the planner's time per step (wall_planning_median_s, wall_planning_p99_s; 0 without steps)."""
    timings["wall_step_mean_s"] = float(np.mean(step_walls)) if step_walls else 0.0
    timings["wall_step_median_s"] = float(np.median(step_walls)) if step_walls else 0.0
    timings["wall_planning_median_s"] = float(np.median(plan_walls)) if plan_walls else 0.0
    timings["wall_planning_p99_s"] = float(np.percentile(plan_walls, 99)) if plan_walls else 0.0


def _result(spec: TrialSpec, rollout: Rollout, state: TrialState, agent: Agent, log: _Log) -> TrialResult:
    """The TrialResult of the ended trial ``state`` (its wall timings summarised into ``log``)."""
    grid_discovered = state.grid.discovered()
    tracked = int(state.tracker.ever_tracked)
    tracked_time = float(state.tracker.tracked_time_s)
    timings = log.timings
    step_summary(timings, log.step_walls, log.plan_walls)
    wall = timings["wall_setup_s"] + sum(log.step_walls)
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
        start=tuple(spec.start), goal=tuple(spec.goal), flight_time_s=round(state.steps * state.dt, 10),
        grid_discovered=grid_discovered, obstacles_tracked=tracked, tracked_time_s=round(tracked_time, 10),
        outcome=state.outcome.value, final_state=agent.state, reason=_reason(state),
        min_clearance_m=float(state.min_clearance), planning_failures=agent.total_failures, steps=state.steps,
        planner_label=spec.planner.label, scenario=sc.name, map_key=ms.key, config_hash=spec.config_hash,
        planner_fingerprint=recorded_fingerprint(spec.planner.trajectory, spec.planner.gaze), profile=sc.profile,
        start_delay_s=round(state.start.time_s, 10),
        max_speed_mps=state.max_speed, max_accel_mps2=state.max_accel,
        limits_exceeded=limits_exceeded(state.max_speed, state.max_accel, state.limits.v_max, state.limits.a_max),
        **task_metrics(spec, state.rollout, state.start.time_s), path_length_m=round(state.path_length, 10),
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


def _reason(state: TrialState) -> str:
    """The outcome's reason, with a note when the "first_clear" start rule found no clear start."""
    if state.start.clear:
        return state.reason
    task = state.spec.scenario.task
    return (f"{state.reason} (the start was not clear for {task.start_window_s:g} s within {task.start_wait_max_s:g} "
            f"s: began at the clearest moment, t = {state.start.time_s:g} s)")


