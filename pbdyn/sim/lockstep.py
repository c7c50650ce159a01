"""Lockstep trials: the trials that share a map, flown together in one PyBullet world (DESIGN.md "sim").

Obstacles never react to the MAV, so every trial on a map sees the same obstacle poses at the same rollout step.
A trial starts at the tick of its start step k0 (the start rule), so at tick T every running trial senses rollout
step T (T + 1 with sensor.obstacles_at = "next"): the obstacles are posed once per tick and rollout (the thesis
program's start-dependent layouts are rollouts of their own), and every running MAV's rays go to Bullet in one
batch. Then, trial by trial, the agent decides and the environment steps exactly as in run_trial (planners keep
their per-trial interface), so each row is bit-identical to run_trial's (tests/test_lockstep.py); only the wall
times differ (the shared posing and ray batch are shared out equally among the trials they served).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from pbdyn.perception.perceive import Detections
from pbdyn.sim.agent import Agent
from pbdyn.sim.env import TrialEnv
from pbdyn.sim.observers import SPLITS
from pbdyn.sim.outcome import Outcome
from pbdyn.sim.result import TrialResult
from pbdyn.sim.spec import TrialSpec
from pbdyn.world.bullet import PyBulletWorld
from pbdyn.world.rollout import Rollout


@dataclass(eq=False)
class _Trial:
    """One trial's state in a lockstep run."""

    index: int
    spec: TrialSpec
    wall0: float
    agent: Agent | None = None
    env: TrialEnv | None = None
    timings: dict = field(default_factory=dict)
    step_walls: list = field(default_factory=list)


def run_lockstep(specs: Sequence[TrialSpec], rollout: Rollout, world: PyBulletWorld, *,
                 step_walls: list | None = None, on_result=None) -> list:
    """Fly ``specs`` (trials of one map and scenario, in any mix of planner pairs, MAV speeds and start/goal pairs)
    together on ``rollout`` in ``world`` (make_world of that map; left open). Returns, per spec in order, its
    TrialResult (bit-identical to run_trial(spec, rollout, world=world) apart from wall times) or the Exception
    that ended it (a planner or trial that raised ends only its own trial; the others fly on). ``step_walls``: a
    list that receives, per spec in order, the wall time (s) of each of its steps (its share of the shared work
    included). ``on_result(index, result_or_exception)`` is called as each trial ends (batch workers stream rows)."""
    out = _Results(len(specs), on_result)
    trials: list[_Trial] = []
    waiting: list[_Trial] = []
    for i, spec in enumerate(specs):
        tr = _Trial(i, spec, time.perf_counter())
        try:
            tr.agent = Agent(spec)
            tr.env = TrialEnv(spec, rollout, fov_deg=tr.agent.fov_deg, world=world)
        except Exception as exc:
            out[i] = exc
            continue
        tr.timings = {"wall_setup_s": time.perf_counter() - tr.wall0, **{name: 0.0 for name in SPLITS}}
        waiting.append(tr)
        trials.append(tr)
    waiting.sort(key=lambda t: (t.env.k0, t.index))
    running: list[_Trial] = []
    tick = waiting[0].env.k0 if waiting else 0
    while waiting or running:
        while waiting and waiting[0].env.k0 <= tick:
            tr = waiting.pop(0)
            tr.env.reset(sense=False)
            running.append(tr)
        failed = _sense_all(running, world, out)
        if failed:
            running = [tr for tr in running if tr not in failed]
        still = []
        for tr in running:
            try:
                done = _act_and_step(tr)
            except Exception as exc:
                out[tr.index] = exc
                continue
            if done:
                out[tr.index] = _finish(tr, rollout)
            else:
                still.append(tr)
        running = still
        tick += 1
    if step_walls is not None:
        walls = {tr.index: tr.step_walls for tr in trials}
        step_walls.extend(walls.get(i, []) for i in range(len(specs)))
    return list(out.items)


class _Results:
    """The per-trial results of a lockstep run; setting one also reports it to ``on_result``."""

    def __init__(self, n: int, on_result=None):
        self.items: list = [None] * n
        self.on_result = on_result

    def __setitem__(self, i: int, value) -> None:
        self.items[i] = value
        if self.on_result is not None:
            self.on_result(i, value)


def _sense_all(running: list[_Trial], world: PyBulletWorld, out: list) -> list[_Trial]:
    """Steps (1)-(3) for every running trial: obstacles posed once per (rollout, step), the rays of all scans
    cast in one batch, then each trial's detections and tracks. Returns the trials that raised (recorded in out)."""
    failed: dict[int, _Trial] = {}
    groups: dict = {}
    for tr in running:
        groups.setdefault((id(tr.env.rollout), tr.env.sense_index()), []).append(tr)
    for members in groups.values():
        c0 = time.perf_counter()
        members[0].env.pose_obstacles()
        pose_share = (time.perf_counter() - c0) / len(members)
        pending = []
        rays = dict.fromkeys((tr.index for tr in members), 0.0)
        for tr in members:
            env = tr.env
            try:
                env.world.set_mav_pose(env.position, env.yaw)
                scan = env.perception.begin(env.position, env.yaw)
            except Exception as exc:
                out[tr.index] = failed[tr.index] = exc
                continue
            if isinstance(scan, Detections):
                env.detections = scan
            else:
                pending.append((tr, scan))
        c1 = time.perf_counter()
        hits = world.cast_fans([scan.fan for _, scan in pending])
        share = (time.perf_counter() - c1) / max(len(pending), 1)
        for (tr, scan), (ids, frac) in zip(pending, hits):
            t0 = time.perf_counter()
            try:
                tr.env.detections = tr.env.perception.complete(scan, ids, frac)
            except Exception as exc:
                out[tr.index] = failed[tr.index] = exc
                continue
            rays[tr.index] = share + time.perf_counter() - t0
        for tr in members:
            if tr.index in failed:
                continue
            t0 = time.perf_counter()
            try:
                tr.env.track()
            except Exception as exc:
                out[tr.index] = failed[tr.index] = exc
                continue
            tr.env.sense_timings = (pose_share, rays[tr.index], time.perf_counter() - t0)
    return [tr for tr in running if tr.index in failed]


def _act_and_step(tr: _Trial) -> bool:
    """Steps (4)-(7) of one trial, as run_trial's loop body; True once the trial has ended."""
    env, agent = tr.env, tr.agent
    sensed = env.sense_timings
    decision = agent.act(env.view(agent.trajectory))
    if decision.violation is not None:
        env.end(Outcome.INVALID_PLAN, decision.violation.reason)
        return True
    env.step(decision.action, sense=False)
    splits = (*sensed, decision.planning_wall_s, decision.gaze_wall_s, env.collision_wall_s)
    for name, value in zip(SPLITS, splits):
        tr.timings[name] += value
    tr.step_walls.append(sum(splits))
    return env.done


def _finish(tr: _Trial, rollout: Rollout) -> TrialResult:
    """The ended trial's TrialResult, as run_trial makes it."""
    from pbdyn.sim.trial import _result

    env = tr.env
    grid_discovered = env.grid.discovered()
    tracked = int(env.tracker.ever_tracked)
    tracked_time = float(env.tracker.tracked_time_s)
    env.close()
    walls = tr.step_walls
    tr.timings["wall_step_mean_s"] = float(np.mean(walls)) if walls else 0.0
    tr.timings["wall_step_median_s"] = float(np.median(walls)) if walls else 0.0
    wall = tr.timings["wall_setup_s"] + sum(walls)
    return _result(tr.spec, rollout, env, tr.agent, grid_discovered, tracked, tracked_time, wall, tr.timings)
