"""Lockstep trials: the trials that share a map, flown together in one PyBullet world (docs/design.md "One trial step").

Obstacles never react to the MAV, so every trial on a map sees the same obstacle poses at the same rollout step.
A trial starts at the tick of its start step k0 (the start rule), so at tick T every running trial senses rollout
step T (T + 1 with sensor.obstacles_at = "next"): the obstacles are posed once per tick and rollout (the thesis
program's start-dependent layouts are rollouts of their own), the running MAVs' ray fans are culled together
(PyBulletWorld.cast_fans_many) and their rays go to Bullet in one batch, and the trials' Kalman trackers step
together (pbdyn.perception.tracker.TrackerBank). Then every agent decides
(planners keep their per-trial interface), the moves of all trials are checked against the obstacles in one
evaluation per (rollout, step) (collision.swept_dynamic_many), and each environment steps as in run_trial. Every row
is bit-identical to run_trial's (tests/test_lockstep.py, tests/test_lockstep_batching.py); only the wall times
differ (shared work is shared out equally among the trials it served).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from pbdyn.perception.perceive import Detections, PendingScan
from pbdyn.perception.tracker import TrackerBank, TrackIdError
from pbdyn.sim.agent import Agent
from pbdyn.sim.env import TrialEnv, check_dynamic_many
from pbdyn.sim.observers import SPLITS
from pbdyn.outcome import Outcome
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
    plan_walls: list = field(default_factory=list)


def run_lockstep(specs: Sequence[TrialSpec], rollout: Rollout, world: PyBulletWorld, *,
                 step_walls: list | None = None, on_result=None) -> list:
    """Fly ``specs`` (trials of one map and scenario, in any mix of planner pairs, MAV speeds and start/goal pairs)
    together on ``rollout`` in ``world`` (make_world of that map; left open). Returns, per spec in order, its
    TrialResult (bit-identical to run_trial(spec, rollout, world=world) apart from wall times) or the Exception that
    ended it (a planner or trial that raised ends only its own trial; the others fly on). ``step_walls``: a list
    that receives, per spec in order, the wall time (s) of each of its steps: its own parts, its share of the shared
    work, and its share of the rest of the tick (_share_rest), so that the steps account for the loop's time.
    ``on_result(index, result_or_exception)`` is called as each trial ends (batch workers stream rows)."""
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
    banks = _Banks(len(trials))
    tick = waiting[0].env.k0 if waiting else 0
    while waiting or running:
        t_tick = time.perf_counter()
        results_s = 0.0                          # time of this tick's _finish calls: results, not steps
        while waiting and waiting[0].env.k0 <= tick:
            tr = waiting.pop(0)
            tr.env.reset(sense=False)
            banks.attach(tr)
            running.append(tr)
        failed = _sense_all(running, world, out, banks)
        if failed:
            running = [tr for tr in running if tr not in failed]
        acting = []
        for tr in running:                   # (4)-(6): every trial decides
            try:
                decision = _act(tr)
            except Exception as exc:
                out[tr.index] = exc
                continue
            if decision is None:
                t0 = time.perf_counter()
                out[tr.index] = _finish(tr, rollout)
                results_s += time.perf_counter() - t0
            else:
                acting.append((tr, decision))
        contacts = _dynamic_contacts(acting)
        still, stepped, ended = [], [], []
        for tr, decision in acting:          # (7): each trial steps, with its share of the batched obstacle check
            try:
                done = _step(tr, decision, contacts.get(tr.index))
            except Exception as exc:
                out[tr.index] = exc
                continue
            stepped.append(tr)
            (ended if done else still).append(tr)
        _share_rest(stepped, time.perf_counter() - t_tick - results_s)
        for tr in ended:
            out[tr.index] = _finish(tr, rollout)
        running = still
        tick += 1
    if step_walls is not None:
        walls = {tr.index: tr.step_walls for tr in trials}
        step_walls.extend(walls.get(i, []) for i in range(len(specs)))
    return list(out.items)


class _Banks:
    """The TrackerBanks of a lockstep run, one per tracker model (trials of one scenario share one)."""

    def __init__(self, capacity: int):
        self.capacity = capacity
        self.banks: list[TrackerBank] = []
        self.where: dict[int, tuple[TrackerBank, int]] = {}      # trial index -> (bank, row)

    def attach(self, tr: _Trial) -> None:
        tracker = tr.env.tracker
        for bank in self.banks:
            row = bank.attach(tracker)
            if row is not None:
                self.where[tr.index] = (bank, row)
                return
        bank = TrackerBank(tracker, self.capacity)
        self.banks.append(bank)
        self.where[tr.index] = (bank, bank.attach(tracker))

    def step(self, members: list[_Trial]) -> dict:
        """Step (3) of the trials in ``members`` (detections set): their trackers step together per bank, then
        each trial's tracks are read. Returns per trial index its tracking time (s: its share of the bank's step
        plus its own read-out) or the exception that ended it."""
        out: dict = {}
        groups: dict = {}
        for tr in members:
            bank, row = self.where[tr.index]
            groups.setdefault(id(bank), (bank, []))[1].append((row, tr))
        for bank, rows in groups.values():
            t0 = time.perf_counter()
            try:
                bank.step([r for r, _ in rows], [tr.env.tracker for _, tr in rows],
                          [tr.env.detections.ids for _, tr in rows], [tr.env.detections.centers for _, tr in rows])
            except TrackIdError:                 # nothing stepped: each trial on its own (the culprits fail so)
                for _, tr in rows:
                    out[tr.index] = _track_one(tr)
                continue
            except Exception as exc:             # (a filter that cannot be stepped ends every trial it holds)
                for _, tr in rows:
                    out[tr.index] = exc
                continue
            try:                                 # every trial's tracks, read out together
                read = bank.read_tracks([r for r, _ in rows], [tr.env.radii for _, tr in rows])
            except Exception:                    # (each on its own, to end only the trials that fail)
                read = None
            share = (time.perf_counter() - t0) / len(rows)
            for k, (_, tr) in enumerate(rows):
                t1 = time.perf_counter()
                try:
                    env = tr.env
                    env.tracks = env.tracker.tracks(env.radii) if read is None else read[k]
                except Exception as exc:
                    out[tr.index] = exc
                    continue
                out[tr.index] = share + time.perf_counter() - t1
        return out


def _track_one(tr: _Trial):
    """Step (3) of one trial on its own: its tracking time (s) or the exception that ended it."""
    t0 = time.perf_counter()
    try:
        tr.env.track()
    except Exception as exc:
        return exc
    return time.perf_counter() - t0


class _Results:
    """The per-trial results of a lockstep run; setting one also reports it to ``on_result``."""

    def __init__(self, n: int, on_result=None):
        self.items: list = [None] * n
        self.on_result = on_result

    def __setitem__(self, i: int, value) -> None:
        self.items[i] = value
        if self.on_result is not None:
            self.on_result(i, value)


def _sense_all(running: list[_Trial], world: PyBulletWorld, out: list, banks: _Banks) -> list[_Trial]:
    """Steps (1)-(3) for every running trial: obstacles posed once per (rollout, step), the rays of all scans
    cast in one batch, then each trial's detections, and the tracks of all (their trackers step together, see
    _Banks). Returns the trials that raised (recorded in out)."""
    failed: dict[int, _Trial] = {}
    by_index = {tr.index: tr for tr in running}
    groups: dict = {}
    for tr in running:
        groups.setdefault((id(tr.env.rollout), tr.env.sense_index()), []).append(tr)
    for members in groups.values():
        c0 = time.perf_counter()
        members[0].env.pose_obstacles()
        pose_share = (time.perf_counter() - c0) / len(members)
        rays = dict.fromkeys((tr.index for tr in members), 0.0)
        fans: dict = {}
        # Nothing reads the MAV body's pose while the scans are made (Bullet's rays exclude it; cast_rays parks it
        # and puts it back): it is placed once per group, at the last member's pose, as trial by trial would leave it.
        last = members[-1].env
        for tr in members:
            env = tr.env
            try:
                if env is last:
                    env.world.set_mav_pose(env.position, env.yaw)
                frame = env.perception.begin_frame(env.position, env.yaw)
            except Exception as exc:
                out[tr.index] = failed[tr.index] = exc
                continue
            if isinstance(frame, Detections):
                env.detections = frame
            else:
                fans.setdefault((env.perception.range_m, frame[1].shape), []).append((tr, frame))
        for (range_m, _), group in fans.items():     # the fans of one shape culled and cast together
            c1 = time.perf_counter()
            try:
                ids, frac = world.cast_fans_many(np.array([o for _, (o, _) in group]),
                                                 np.array([d for _, (_, d) in group]), range_m)
                cast = [(tr, o, dirs_t, ids[k], frac[k]) for k, (tr, (o, dirs_t)) in enumerate(group)]
            except Exception:                         # each trial on its own, to end only the ones that fail
                cast = []
                for tr, (o, dirs_t) in group:
                    try:
                        cast.append((tr, o, dirs_t, *world.cast_fan_rays(world.fan_rays(o, dirs_t.T, range_m))))
                    except Exception as exc:
                        out[tr.index] = failed[tr.index] = exc
            share = (time.perf_counter() - c1) / max(len(cast), 1)
            for tr, o, dirs_t, hit_ids, hit_frac in cast:
                t0 = time.perf_counter()
                try:
                    tr.env.detections = tr.env.perception.complete(PendingScan(o, dirs_t, None), hit_ids, hit_frac)
                except Exception as exc:
                    out[tr.index] = failed[tr.index] = exc
                    continue
                rays[tr.index] = share + time.perf_counter() - t0
        tracked = banks.step([tr for tr in members if tr.index not in failed])
        for index, got in tracked.items():
            tr = by_index[index]
            if isinstance(got, Exception):
                out[index] = failed[index] = got
                continue
            tr.env.sense_timings = (pose_share, rays[index], got)
    return [tr for tr in running if tr.index in failed]


def _act(tr: _Trial):
    """Steps (4)-(6) of one trial (as run_trial's loop body): its Decision, or None when the plan broke the plan
    contract and the trial has ended (INVALID_PLAN)."""
    env, agent = tr.env, tr.agent
    decision = agent.act(env.view(agent.trajectory))
    if decision.violation is not None:
        env.end(Outcome.INVALID_PLAN, decision.violation.reason)
        return None
    return decision


def _dynamic_contacts(acting: list) -> dict:
    """Per trial index: (its swept obstacle contact of this step, its share of the check's time in s), for the
    trials whose checks can be batched (TrialEnv.dynamic_batch_key); each group is checked in one evaluation."""
    groups: dict = {}
    for tr, decision in acting:
        key = tr.env.dynamic_batch_key()
        if key is not None:
            groups.setdefault(key, []).append((tr, decision))
    out: dict = {}
    for members in groups.values():
        if len(members) < 2:
            continue
        c0 = time.perf_counter()
        found = check_dynamic_many([tr.env for tr, _ in members], [d.action.position for _, d in members])
        share = (time.perf_counter() - c0) / len(members)
        for (tr, _), contact in zip(members, found):
            out[tr.index] = (contact, share)
    return out


def _step(tr: _Trial, decision, contact) -> bool:
    """Step (7) of one trial (as run_trial's loop body), given its batched obstacle contact (or None: its own
    check); True once the trial has ended."""
    env = tr.env
    sensed = env.sense_timings
    dynamic, share = contact if contact is not None else (None, 0.0)
    env.step(decision.action, sense=False, dynamic=dynamic)
    splits = (*sensed, decision.planning_wall_s, decision.gaze_wall_s, env.collision_wall_s + share)
    for name, value in zip(SPLITS, splits):
        tr.timings[name] += value
    tr.step_walls.append(sum(splits))
    tr.plan_walls.append(decision.planning_wall_s)
    return env.done


def _share_rest(stepped: list[_Trial], tick_s: float) -> None:
    """Make the steps of one tick account for all of its time (s; the results made in it excluded): what the
    trials' step splits did not measure (views, the act wrapper, each step's bookkeeping, grouping, the trials
    started) is shared out equally among the trials that stepped, as run_trial's step is its whole iteration."""
    if not stepped:
        return
    rest = (tick_s - sum(tr.step_walls[-1] for tr in stepped)) / len(stepped)
    if rest > 0.0:
        for tr in stepped:
            tr.step_walls[-1] += rest


def _finish(tr: _Trial, rollout: Rollout) -> TrialResult:
    """The ended trial's TrialResult, as run_trial makes it."""
    from pbdyn.sim.trial import _result, step_summary

    env = tr.env
    grid_discovered = env.grid.discovered()
    tracked = int(env.tracker.ever_tracked)
    tracked_time = float(env.tracker.tracked_time_s)
    env.close()
    step_summary(tr.timings, tr.step_walls, tr.plan_walls)
    wall = tr.timings["wall_setup_s"] + sum(tr.step_walls)
    return _result(tr.spec, rollout, env, tr.agent, grid_discovered, tracked, tracked_time, wall, tr.timings)
