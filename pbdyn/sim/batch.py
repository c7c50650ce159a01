"""The trial core: N >= 1 trials of one map stepped together on one PyBullet world (docs/architecture.md "The trial
core"; the step order is docs/design.md "One trial step", thesis Algorithm 1).

``TrialBatch`` owns the environment's side of every step of its trials -- (1) posing the obstacles, (2) ray
sensing, (3) tracking, (6) executing the next state through the guard (pbdyn.sim.guard) and (7) the collision, goal,
time and deadlock checks -- and shares the work across trials: obstacles never react to the MAV, so every trial on
the map sees the same obstacle poses at the same rollout step; they are posed once per (rollout, step), the running
MAVs' ray fans are culled and cast in one Bullet batch (PyBulletWorld.cast_fans_many), the Kalman trackers of one
model step together (pbdyn.perception.tracker.TrackerBank), and the swept checks of the moves against the same
obstacles run in one evaluation (collision.swept_dynamic_many). A single trial takes the same path with one member
(then the unshared calls, which give the same floats). The decisions (4)-(5) come from an agent given with the trial
(pbdyn.sim.agent.Agent: the batch asks it each step, and a plan that breaks the plan contract ends the trial) or,
for a trial without one, from the caller's action each step (a Gymnasium policy, a test). Observers attached to a
trial (``watch``) see each of its steps and its end, whoever drives it.

Time: a trial starts at the tick of its start step k0 (the start rule, pbdyn.sim.start), so at tick T every running
trial senses rollout step T (T + 1 with sensor.obstacles_at = "next"). A trial whose setup, sensing or checks raise
ends alone (``errors``); the others fly on.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from pbdyn.outcome import Outcome
from pbdyn.perception.perceive import Detections, PendingScan
from pbdyn.perception.tracker import TrackerBank, TrackIdError
from pbdyn.sim.guard import Accel, Action, breach, integrate
from pbdyn.sim.observers import StepRecord
from pbdyn.sim.spec import TrialSpec
from pbdyn.sim.state import TrialState, check_dynamic_many, make_world
from pbdyn.world.bullet import PyBulletWorld
from pbdyn.world.rollout import Rollout


@dataclass(frozen=True)
class StepReport:
    """What one start() or step() of a TrialBatch did. ``ended``: the trials that ended in it (those ended by end()
    or by their agent's broken plan first, then in stepping order); ``refused``: those of them the guard ended
    without a move (invalid_plan); ``errors``: trial index -> the exception that ended that trial in it (a setup,
    an agent, sensing, a check or an observer that raised; such a trial is not in ``ended``: its row is an error);
    ``splits``: trial index -> the wall-time splits (s, pbdyn.sim.observers.SPLITS order) of each trial that moved."""

    ended: tuple[int, ...] = ()
    refused: tuple[int, ...] = ()
    errors: Mapping[int, BaseException] = field(default_factory=lambda: MappingProxyType({}))
    splits: Mapping[int, tuple[float, ...]] = field(default_factory=lambda: MappingProxyType({}))


class TrialBatch:
    """Trials ``specs`` (of one map and scenario; any mix of planner pairs, MAV speeds and start/goal pairs) on
    ``rollout``, in ``world`` (make_world of that map; lent, left open) or in a world of their own (closed by
    close(); ``gui`` shows it). ``agents``: per trial, the pbdyn.sim.agent.Agent that decides its steps (None: the
    caller gives its actions); an agent also sets its trial's sensor field of view (its gaze planner's) and the
    rules the guard executes by (its ``physical``: the one switch, pbdyn.sim.guard); a trial without one follows
    its scenario's profile. ``start_steps``: per trial, the rollout step it begins at (None: the start rule's).

    Use: ``start()``; then, while not ``done``: read ``states[i]`` (or ``view(i)``) of the ``running`` trials and
    call ``step(actions)`` with an Action or Accel for each running trial without an agent (or ``end(i, ...)`` it).
    Both return a StepReport (ended, refused, errors, splits)."""

    def __init__(self, specs: Sequence[TrialSpec], rollout: Rollout, *, world: PyBulletWorld | None = None,
                 agents: Sequence | None = None, gui: bool = False,
                 start_steps: Sequence[int | None] | None = None, capacity: int | None = None):
        specs = list(specs)
        if not specs and world is None:
            raise ValueError("a TrialBatch needs a trial or a world (trials added later: add())")
        if gui and len(specs) > 1:
            raise ValueError("the GUI shows one trial: a batch with gui=True must hold one trial")
        agents = list(agents) if agents is not None else [None] * len(specs)
        starts = list(start_steps) if start_steps is not None else [None] * len(specs)
        if len(agents) != len(specs) or len(starts) != len(specs):
            raise ValueError(f"agents and start_steps need one entry for each of the {len(specs)} trials")
        self.specs = specs
        self.rollout = rollout
        self._errors: dict[int, BaseException] = {}
        self.owns_world = world is None
        self.world = make_world(specs[0], rollout, gui=gui) if world is None else world
        self.states: list[TrialState | None] = []
        self.setup_s: list[float] = []
        self._agents: list = []
        self._physical: list[bool] = []
        self._observers: dict[int, list] = {}
        try:
            for i, spec in enumerate(specs):
                t0 = time.perf_counter()
                try:
                    self._admit(spec, starts[i], agents[i])
                except Exception as exc:
                    self.states.append(None)
                    self._agents.append(None)
                    self._physical.append(True)
                    self._errors[i] = exc
                self.setup_s.append(time.perf_counter() - t0)
        except BaseException:
            self.close()
            raise
        capacity = len(specs) if capacity is None else capacity
        self._banks = _Banks(capacity) if capacity > 1 else None
        self.running: list[int] = []
        self.waiting: list[int] = []
        self._ended_early: list[int] = []
        self.tick = 0
        self.sensed_at = 0.0          # perf_counter() when the last step's sensing of the next tick began

    def _admit(self, spec: TrialSpec, start_step: int | None, agent) -> None:
        """Append a trial's state, agent and guard rules (its agent's, else its scenario's)."""
        fov = None if agent is None else agent.fov_deg
        self.states.append(TrialState(spec, self.rollout, self.world, fov_deg=fov, start_step=start_step))
        self._agents.append(agent)
        self._physical.append(spec.scenario.physical if agent is None else agent.physical)

    # ------------------------------------------------------------------------------------------------ episode
    def start(self) -> StepReport:
        """Start the batch: the trials whose start step is the earliest begin and sense (steps (1)-(3) at t_0);
        the others begin at the tick of their own start step. The report's errors: the trials that failed to set
        up or to begin."""
        ok = [i for i, s in enumerate(self.states) if s is not None]
        self.waiting = sorted(ok, key=lambda i: (self.states[i].k0, i))
        self.running = []
        self._ended_early = []
        self.tick = self.states[self.waiting[0]].k0 if self.waiting else 0
        self._begin_tick()
        errors, self._errors = self._errors, {}
        return StepReport(errors=MappingProxyType(errors))

    @property
    def done(self) -> bool:
        """True once every trial has ended (or raised)."""
        return not self.running and not self.waiting

    def view(self, i: int, trajectory=None):
        """The read-only View trial ``i`` sees at its t_k (with the plan in execution, or None)."""
        return self.states[i].view(trajectory)

    def end(self, i: int, outcome: Outcome, reason: str | None = None) -> None:
        """End running trial ``i`` now with ``outcome`` (e.g. invalid_plan when its plan broke the contract); the
        next step() lists it among the trials that ended."""
        self.states[i].end(outcome, reason)
        self.running.remove(i)
        self._ended_early.append(i)

    def watch(self, i: int, observers) -> None:
        """Attach ``observers`` (pbdyn.sim.observers.Observer) to trial ``i``: each sees every step it moves in and
        its end (not an end by an exception)."""
        self._observers.setdefault(i, []).extend(observers)

    def add(self, spec: TrialSpec, start_step: int, *, agent=None) -> int:
        """Add a trial of the batch's map that begins at rollout step ``start_step`` (>= the next tick: it begins
        and senses with the others when the batch reaches that tick), decided by ``agent`` (or by the caller's
        actions); returns its index. A vector environment's next episodes join a running batch so."""
        if start_step <= self.tick:
            raise ValueError(f"a trial added at tick {self.tick} must start at a later tick (got {start_step})")
        i = len(self.states)
        self._admit(spec, start_step, agent)
        self.specs.append(spec)
        self.setup_s.append(0.0)
        at = len(self.waiting)
        while at and self.states[self.waiting[at - 1]].k0 > start_step:
            at -= 1
        self.waiting.insert(at, i)
        return i

    def release(self, i: int) -> None:
        """Free the tracker-bank row of ended trial ``i`` for a trial added later (its tracker must not be read
        after this)."""
        if self._banks is not None:
            self._banks.release(i)

    def step(self, actions: Mapping | None = None) -> StepReport:
        """One step of every running trial: a trial with an agent decides (steps (4)-(5); a plan that breaks the
        plan contract ends it as invalid_plan), every other running trial takes its action in ``actions`` (an
        Action, or an Accel integrated within the limits); the guard checks each next state and refuses a breach
        (invalid_plan, pbdyn.sim.guard); the trials move and are checked ((6)-(7)); the next tick's trials begin and
        every running trial senses ((1)-(3)); observers see the steps and the ends. Returns the StepReport."""
        actions = {} if actions is None else actions
        ended, self._ended_early = self._ended_early, []
        errors, self._errors = self._errors, {}
        agents, states = self._agents, self.states
        decisions: dict = {}
        for i in list(self.running):                      # (4)-(5): the agents decide
            agent = agents[i]
            if agent is None:
                continue
            st = states[i]
            try:
                decision = agent.act(st.view(agent.trajectory))
            except Exception as exc:
                errors[i] = exc
                self.running.remove(i)
                continue
            if decision.violation is not None:
                st.end(Outcome.INVALID_PLAN, decision.violation.reason)
                self.running.remove(i)
                ended.append(i)
            else:
                decisions[i] = decision
        running = self.running
        if len(actions) + len(decisions) != len(running) or not all(i in actions or i in decisions for i in running):
            missing = [i for i in running if i not in actions and i not in decisions]
            extra = sorted(set(actions) - set(running) | set(actions) & set(decisions))
            raise ValueError(f"step() needs one action per running trial without an agent: missing {missing}, "
                             f"not wanted {extra}")
        refused, moves = [], []
        for i in running:
            st = states[i]
            decision = decisions.get(i)
            act = actions[i] if decision is None else decision.action
            try:
                if isinstance(act, Accel):
                    act = integrate(act, st.position, st.velocity, st.limits, st.dt)
                why = breach(act, st.position, st.velocity, st.limits, st.dt, self._physical[i]) \
                    if isinstance(act, Action) else f"next state broke form (an Action or an Accel, got {act!r})"
            except Exception as exc:
                errors[i] = exc
                continue
            if why is not None:
                st.end(Outcome.INVALID_PLAN, why)
                st.collision_wall_s = 0.0
                refused.append(i)
                ended.append(i)
                continue
            moves.append((i, act))
        contacts = self._dynamic_contacts(moves) if len(moves) > 1 else None
        still, splits, records = [], {}, []
        for i, act in moves:
            st = states[i]
            contact = contacts.get(i) if contacts else None
            before = (st.t, st.position, st.velocity, st.acceleration, st.yaw, st.tracks, st.detections.ids) \
                if i in self._observers else None       # what the observers get of t_k
            try:
                st._move(act, None if contact is None else contact[0])
            except Exception as exc:
                errors[i] = exc
                continue
            if contact is not None:
                st.collision_wall_s += contact[1]
            decision = decisions.get(i)
            splits[i] = (*st.sense_timings, *((decision.planning_wall_s, decision.gaze_wall_s) if decision
                                               else (0.0, 0.0)), st.collision_wall_s)
            if before is not None:
                records.append((i, act, decision, before))
            (ended if st.outcome is not None else still).append(i)
        self.running = still
        self.tick += 1
        self.sensed_at = time.perf_counter()
        self._begin_tick()
        errors.update(self._errors)
        self._errors = {}
        for i, act, decision, before in records:
            lim = states[i].limits.yaw_rate
            self._notify(i, errors, "step", StepRecord(*before[:5], min(max(act.yaw_rate, -lim), lim), *(
                (decision.planned, decision.plan_ok) if decision else (False, True)), *before[5:], splits[i]),
                decision)
        for i in ended:
            if i in self._observers:
                self._notify(i, errors, "end")
        return StepReport(tuple(i for i in ended if i not in errors), tuple(refused), MappingProxyType(errors),
                          MappingProxyType(splits))

    def _notify(self, i: int, errors: dict, what: str, record=None, decision=None) -> None:
        """Trial i's observers' on_step (``record``) or on_end; one that raises ends the trial with its exception."""
        if i in errors:
            return
        st, agent = self.states[i], self._agents[i]
        try:
            for w in self._observers[i]:
                if what == "step":
                    w.on_step(st, agent, decision, record)
                else:
                    w.on_end(st, agent)
        except Exception as exc:
            errors[i] = exc

    def close(self) -> None:
        """Disconnect the PyBullet client if the batch made its world (a lent world stays open)."""
        if self.owns_world:
            self.world.close()

    def __enter__(self) -> TrialBatch:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------------------------------------ sensing
    def _begin_tick(self) -> None:
        """Begin the trials whose start step is this tick, then steps (1)-(3) of every running trial."""
        while self.waiting and self.states[self.waiting[0]].k0 <= self.tick:   # (none after the first ticks)
            i = self.waiting.pop(0)
            st = self.states[i]
            try:
                st.begin()
                if self._banks is not None:
                    self._banks.attach(i, st)
            except Exception as exc:
                self._errors[i] = exc
                continue
            self.running.append(i)
        if self.running:
            self._sense()

    def _sense(self) -> None:
        """Steps (1)-(3) for every running trial: obstacles posed once per (rollout, step), the rays of all scans
        cast in one batch, then each trial's detections, and the tracks of all (their trackers step together)."""
        failed: set[int] = set()
        if self._banks is None:                  # a batch of one
            self._sense_one(self.running[0], failed)
            if failed:
                self.running = []
            return
        groups: dict = {}
        for i in self.running:
            st = self.states[i]
            groups.setdefault((id(st.rollout), st.sense_index()), []).append(i)
        for members in groups.values():
            self._sense_group(members, failed)
        if failed:
            self.running = [i for i in self.running if i not in failed]

    def _sense_one(self, i: int, failed: set) -> None:
        """Steps (1)-(3) of one trial alone (a batch of one): the unshared calls."""
        st = self.states[i]
        try:
            c0 = time.perf_counter()
            st.pose_obstacles()                                             # (1)
            st.world.set_mav_pose(st.position, st.yaw)
            c1 = time.perf_counter()
            st.detections = st.perception.sense(st.position, st.yaw)       # (2)
            c2 = time.perf_counter()
            st.track()                                                      # (3)
            c3 = time.perf_counter()
        except Exception as exc:
            self._errors[i] = exc
            failed.add(i)
            return
        st.sense_timings = (c1 - c0, c2 - c1, c3 - c2)

    def _sense_group(self, members: list[int], failed: set) -> None:
        """Steps (1)-(3) of the trials that sense the same rollout step: shared posing, one ray batch per fan shape,
        the trackers stepped together; each trial's timings are its share of the shared work plus its own."""
        states = self.states
        world = self.world
        c0 = time.perf_counter()
        states[members[0]].pose_obstacles()
        pose_share = (time.perf_counter() - c0) / len(members)
        rays = dict.fromkeys(members, 0.0)
        fans: dict = {}
        # Nothing reads the MAV body's pose while the scans are made (Bullet's rays exclude it; cast_rays parks it
        # and puts it back): it is placed once per group, at the last member's pose, as trial by trial would leave it.
        last = members[-1]
        for i in members:
            st = states[i]
            try:
                if i == last:
                    world.set_mav_pose(st.position, st.yaw)
                frame = st.perception.begin_frame(st.position, st.yaw)
            except Exception as exc:
                self._errors[i] = exc
                failed.add(i)
                continue
            if isinstance(frame, Detections):
                st.detections = frame
            else:
                fans.setdefault((st.perception.range_m, frame[1].shape), []).append((i, frame))
        for (range_m, _), group in fans.items():     # the fans of one shape culled and cast together
            c1 = time.perf_counter()
            try:
                ids, frac = world.cast_fans_many(np.array([o for _, (o, _) in group]),
                                                 np.array([d for _, (_, d) in group]), range_m)
                cast = [(i, o, dirs_t, ids[k], frac[k]) for k, (i, (o, dirs_t)) in enumerate(group)]
            except Exception:                         # each trial on its own, to end only the ones that fail
                cast = []
                for i, (o, dirs_t) in group:
                    try:
                        cast.append((i, o, dirs_t, *world.cast_fan_rays(world.fan_rays(o, dirs_t.T, range_m))))
                    except Exception as exc:
                        self._errors[i] = exc
                        failed.add(i)
            share = (time.perf_counter() - c1) / max(len(cast), 1)
            for i, o, dirs_t, hit_ids, hit_frac in cast:
                t0 = time.perf_counter()
                st = states[i]
                try:
                    st.detections = st.perception.complete(PendingScan(o, dirs_t, None), hit_ids, hit_frac)
                except Exception as exc:
                    self._errors[i] = exc
                    failed.add(i)
                    continue
                rays[i] = share + time.perf_counter() - t0
        sensed = [i for i in members if i not in failed]
        tracked = self._banks.step(sensed, states) if self._banks is not None else \
            {i: _track_one(states[i]) for i in sensed}
        for i, got in tracked.items():
            if isinstance(got, Exception):
                self._errors[i] = got
                failed.add(i)
                continue
            states[i].sense_timings = (pose_share, rays[i], got)

    # ------------------------------------------------------------------------------------------------ checks
    def _dynamic_contacts(self, moves: list) -> dict:
        """Per trial index: (its swept obstacle contact of this step, its share of the check's time in s), for the
        trials whose checks can be batched (TrialState.dynamic_batch_key); each group is checked in one evaluation."""
        if len(moves) < 2:
            return {}
        groups: dict = {}
        for i, act in moves:
            key = self.states[i].dynamic_batch_key()
            if key is not None:
                groups.setdefault(key, []).append((i, act))
        out: dict = {}
        for members in groups.values():
            if len(members) < 2:
                continue
            c0 = time.perf_counter()
            found = check_dynamic_many([self.states[i] for i, _ in members], [a.position for _, a in members])
            share = (time.perf_counter() - c0) / len(members)
            for (i, _), contact in zip(members, found):
                out[i] = (contact, share)
        return out


def _track_one(st: TrialState):
    """Step (3) of one trial on its own: its tracking time (s) or the exception that ended it."""
    t0 = time.perf_counter()
    try:
        st.track()
    except Exception as exc:
        return exc
    return time.perf_counter() - t0


class _Banks:
    """The TrackerBanks of a batch, one per tracker model (trials of one scenario share one)."""

    def __init__(self, capacity: int):
        self.capacity = capacity
        self.banks: list[TrackerBank] = []
        self.where: dict[int, tuple[TrackerBank, int]] = {}      # trial index -> (bank, row)

    def release(self, i: int) -> None:
        """Give trial i's row back to its bank."""
        got = self.where.pop(i, None)
        if got is not None:
            got[0].release(got[1])

    def attach(self, i: int, st: TrialState) -> None:
        tracker = st.tracker
        for bank in self.banks:
            row = bank.attach(tracker)
            if row is not None:
                self.where[i] = (bank, row)
                return
        bank = TrackerBank(tracker, self.capacity)
        self.banks.append(bank)
        self.where[i] = (bank, bank.attach(tracker))

    def step(self, members: list[int], states: list) -> dict:
        """Step (3) of the trials ``members`` (detections set): their trackers step together per bank, then each
        trial's tracks are read. Returns per trial index its tracking time (s: its share of the bank's step plus its
        own read-out) or the exception that ended it."""
        out: dict = {}
        groups: dict = {}
        for i in members:
            bank, row = self.where[i]
            groups.setdefault(id(bank), (bank, []))[1].append((row, i))
        for bank, rows in groups.values():
            t0 = time.perf_counter()
            sts = [states[i] for _, i in rows]
            try:
                bank.step([r for r, _ in rows], [st.tracker for st in sts], [st.detections.ids for st in sts],
                          [st.detections.centers for st in sts])
            except TrackIdError:                 # nothing stepped: each trial on its own (the culprits fail so)
                for _, i in rows:
                    out[i] = _track_one(states[i])
                continue
            except Exception as exc:             # (a filter that cannot be stepped ends every trial it holds)
                for _, i in rows:
                    out[i] = exc
                continue
            try:                                 # every trial's tracks, read out together
                read = bank.read_tracks([r for r, _ in rows], [st.radii for st in sts])
            except Exception:                    # (each on its own, to end only the trials that fail)
                read = None
            share = (time.perf_counter() - t0) / len(rows)
            for k, st in enumerate(sts):
                t1 = time.perf_counter()
                try:
                    st.tracks = st.tracker.tracks(st.radii) if read is None else read[k]
                except Exception as exc:
                    out[rows[k][1]] = exc
                    continue
                out[rows[k][1]] = share + time.perf_counter() - t1
        return out
