"""The dispatch loop of a batch (execute, Dispatcher): submit the pending trials, in lockstep groups, and the maps'
metric tasks to the workers (pbdyn.experiments.pool), and store what comes back.

The coordinator is the only writer of the store: rows are inserted as they arrive (a lockstep group's rows stream
in as each trial ends) and committed at least every COMMIT_INTERVAL_S, so a killed batch loses no committed trial
and the same command resumes. At most a window of tasks is in flight; a pool whose worker died is restarted (at
most MAX_POOL_RESTARTS times in a row without a row stored in between) with its lost tasks queued again, minus the
rows already stored. A map whose tasks were in flight at ISOLATE_AFTER worker deaths (a plug-in planner that
crashes its process: a segfault, os._exit) is isolated: its trials are flown one at a time in a worker process of
their own (a local pool of one worker beside the main pool), so a death there names its trial, which is stored as an
"error" row ("worker process died (exit -11 / signal SIGSEGV) while flying this trial") and the batch goes on; rows
are the same whether flown in a lockstep group or alone. SIGTERM/SIGINT (a KeyboardInterrupt) keep what has arrived,
commit it and end the workers (docs/experiments.md, "Resume and interruption", "Lockstep").
"""

from __future__ import annotations

import collections
import concurrent.futures as cf
import signal
import sys
import time
from collections.abc import Iterator
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

from pbdyn.config import Scenario
from pbdyn.errors import PbdynError
from pbdyn.experiments.options import BatchOptions
from pbdyn.experiments.plan import BatchPlan
from pbdyn.experiments.pool import WorkerPool
from pbdyn.experiments.progress import Progress
from pbdyn.experiments.store import WORLD_FINGERPRINT_CHARS, ResultsStore
from pbdyn.experiments.tasks import (METRIC_SET, MapTask, RolloutRef, TrialGroupTask, TrialTask, error_row,
                                     run_map_task, run_trial_group_task, run_trial_task, trial_spec)
from pbdyn.world.rollout import default_horizon, rollout_file

COMMIT_INTERVAL_S = 1.0
"""The store is committed at least this often while rows arrive, in s."""
MAX_POOL_RESTARTS = 3
"""How many times in a row a local pool whose worker died is restarted, with no row stored and no map newly
isolated in between, before the batch stops."""
ISOLATE_AFTER = 2
"""A map whose tasks were in flight at this many deaths of local workers is flown one trial at a time in a worker
process of its own (Dispatcher._isolate)."""


def execute(store: ResultsStore, scenario: Scenario, items: Iterator, plan: BatchPlan, files: dict, workers: int,
            options: BatchOptions) -> tuple[int, int, int]:
    """Fly the pending ``items`` ((trial, replaces) pairs, streamed) and compute plan.metric_maps: a map's metrics
    are queued when the stream reaches its first trial (maps without pending trials first), at most a window of
    tasks is in flight, and a pool whose worker died is restarted with the lost tasks queued again. Returns (trials
    stored, error rows among them, maps whose metrics were stored)."""
    return Dispatcher(store, scenario, items, plan, files, workers, options).run()


class Dispatcher:
    """One run of the dispatch loop (execute): the pool, the stream of tasks, the tasks in flight and the counts."""

    def __init__(self, store: ResultsStore, scenario: Scenario, items: Iterator, plan: BatchPlan, files: dict,
                 workers: int, options: BatchOptions):
        self.store, self.scenario, self.items, self.plan, self.files = store, scenario, items, plan, files
        self.pool = WorkerPool(workers, options.scheduler)
        self.progress = (options.progress if isinstance(options.progress, Progress)     # shared by several batches
                         else Progress(plan.pending, options.progress))
        self.ran = self.errors = self.maps = 0
        self.metric_ids = {m.map_id for m in plan.metric_maps}
        self.trial_map_ids = {m.map_id for m in plan.trial_maps}
        self.streamed: dict = {}       # key -> (replaces, taken) of every trial of the lockstep groups in flight
        self.stream = grouped(self._maps_and_trials(), options.lockstep)
        self.retry: collections.deque = collections.deque()
        self.in_flight: dict = {}
        self.last_commit = time.perf_counter()
        self.restarts = 0               # pool restarts in a row without progress (a row stored, a map isolated)
        self.ran_at_break = 0
        self.strikes: collections.Counter = collections.Counter()   # map id -> worker deaths with its tasks in flight
        self.isolated: set = set()      # map ids whose trials fly one at a time in the solo pool
        self.solo: collections.deque = collections.deque()   # ("trial", trial, replaces) items of isolated maps
        self.solo_pool: WorkerPool | None = None
        self.solo_flight: tuple | None = None                # (future, item) of the isolated trial in flight
        self.window = (4 if options.lockstep <= 1 else 2) * workers if not self.pool.dask else max(64, 8 * workers)

    def run(self) -> tuple[int, int, int]:
        """Dispatch until every task is done; (trials stored, error rows, maps stored). The pool is closed at the
        end (its workers ended at once after an interrupt) and the store committed."""
        interrupted = False
        try:
            while True:
                try:
                    self._fly()
                    break
                except BrokenProcessPool:
                    self._recover()
            self.store.commit()
        except KeyboardInterrupt:
            interrupted = True
            self._keep_arrived()
            raise
        finally:
            try:
                self.store.commit()
            finally:
                try:
                    if self.solo_pool is not None:     # closed before the main pool: their guards nest
                        self.solo_pool.close(terminate=True)
                finally:
                    self.pool.close(terminate=interrupted)
        return self.ran, self.errors, self.maps

    # ------------------------------------------------------------------------------------------- the task stream
    def _maps_and_trials(self) -> Iterator[tuple]:
        """("map", map, False) and ("trial", trial, replaces) items: metric maps without pending trials first, a
        metric map just before its first trial, then metric maps the stream never reached."""
        plan, metric_ids = self.plan, self.metric_ids
        for m in plan.metric_maps:
            if m.map_id not in self.trial_map_ids:
                metric_ids.discard(m.map_id)
                yield "map", m, False
        for t, rep in self.items:
            if t[1].map_id in metric_ids:
                metric_ids.discard(t[1].map_id)
                yield "map", t[1], False
            yield "trial", t, rep
        for m in plan.metric_maps:          # metric maps the stream never reached (nothing pending there)
            if m.map_id in metric_ids:
                metric_ids.discard(m.map_id)
                yield "map", m, False

    # ------------------------------------------------------------------------------------------- the loop
    def _fly(self) -> None:
        """Keep the window full and take the results until nothing is left; BrokenProcessPool if the pool broke."""
        while True:
            self._fill()
            self._fill_solo()
            waiting = list(self.in_flight) + ([self.solo_flight[0]] if self.solo_flight is not None else [])
            if not waiting:
                break
            finished, _ = cf.wait(waiting, timeout=None if self.pool.dask else 0.5, return_when=cf.FIRST_COMPLETED)
            self._drain()
            for fut in finished:
                if self.solo_flight is not None and fut is self.solo_flight[0]:
                    self._take_solo()
                    continue
                result = fut.result()
                self._take(self.in_flight.pop(fut), result)
            self._maybe_commit()

    def _fill(self) -> None:
        """Submit retried, then new items until the window is full or the stream ends."""
        while len(self.in_flight) < self.window:
            item = self.retry.popleft() if self.retry else next(self.stream, None)
            if item is None:
                break
            if item[0] == "group":
                item = unfinished(item, self.streamed)
                if item is None:
                    continue
            if item[0] != "map" and map_of(item) in self.isolated:
                self._to_solo(item)
                continue
            try:
                fut = submit(self.pool, self.scenario, item, self.files)
            except BrokenProcessPool:
                self.retry.appendleft(item)
                raise
            self.in_flight[fut] = item

    def _recover(self) -> None:
        """After the pool broke: store what finished, queue the lost tasks again first, commit and restart the
        pool (PbdynError after MAX_POOL_RESTARTS restarts; MainGuardError from the pool's guard)."""
        self.pool.check_broken()
        self._drain()
        lost = []
        for fut, item in self.in_flight.items():
            if _succeeded(fut):
                self._take(item, fut.result())
            else:
                lost.append(item)
        self.in_flight.clear()
        self.retry.extendleft(reversed(lost))
        self.store.commit()
        newly = self._isolate(lost)
        progress = newly or self.ran > self.ran_at_break
        self.ran_at_break = self.ran
        self.restarts = 1 if progress else self.restarts + 1
        if self.restarts > MAX_POOL_RESTARTS:
            left = self.plan.pending - self.ran
            raise PbdynError(f"worker processes died {self.restarts} times in a row; {left} trials not run (re-run "
                             "the same command to resume)") from None
        sys.stderr.write("pbdyn batch: a worker died; restarting the pool and resuming\n")
        self.pool.restart()

    # ------------------------------------------------------------------------------------------- isolation
    def _isolate(self, lost: list) -> bool:
        """Count a worker death against the maps of the ``lost`` tasks; the trials of a map at ISOLATE_AFTER deaths
        are flown one at a time in a process of their own from now on (its lost tasks among them). True if a map was
        newly isolated."""
        newly = False
        for mid in dict.fromkeys(map_of(item) for item in lost):
            self.strikes[mid] += 1
            if self.strikes[mid] >= ISOLATE_AFTER and mid not in self.isolated and not self.pool.dask:
                self.isolated.add(mid)
                newly = True
                sys.stderr.write(f"pbdyn batch: workers died {self.strikes[mid]} times flying map {mid}; flying "
                                 "its trials one per process\n")
        return newly

    def _to_solo(self, item) -> None:
        """Queue the trials of a (group or trial) item of an isolated map for the solo pool, one per task."""
        kind, obj, rep = item
        if kind == "trial":
            self.solo.append(item)
            return
        for t, r in zip(obj, rep):
            self.streamed.pop(t[0], None)
            self.solo.append(("trial", t, r))

    def _fill_solo(self) -> None:
        """Submit the next isolated trial to the solo pool (one worker, one trial at a time)."""
        if self.solo_flight is not None or not self.solo:
            return
        if self.solo_pool is None:
            self.solo_pool = WorkerPool(1, None)
        item = self.solo.popleft()
        self.solo_flight = (submit(self.solo_pool, self.scenario, item, self.files), item)

    def _take_solo(self) -> None:
        """Store the result of the isolated trial in flight; if its worker died, its "error" row (the trial was the
        only task of that process) and a new solo worker."""
        fut, item = self.solo_flight
        self.solo_flight = None
        try:
            result = fut.result()
        except BrokenProcessPool:
            codes = [c for c in self.solo_pool.exit_codes() if c is not None]
            self.solo_pool.check_broken()
            self.solo_pool.restart()
            key, spec, ref = trial_spec_of(self.scenario, item[1], self.files)
            msg = f"worker process died ({exit_text(codes[0] if codes else None)}) while flying this trial"
            result = (key, error_row(TrialTask(key, spec, ref), msg), msg)
        self._take(item, result)

    def _keep_arrived(self) -> None:
        """On an interrupt: store the rows of trials that ended inside groups still in flight and the results that
        have arrived."""
        self._drain()
        for fut, item in list(self.in_flight.items()):
            if _succeeded(fut):
                self._take(item, fut.result())
        if self.solo_flight is not None and _succeeded(self.solo_flight[0]):
            self._take(self.solo_flight[1], self.solo_flight[0].result())
            self.solo_flight = None

    # ------------------------------------------------------------------------------------------- storing rows
    def _take(self, item, result) -> None:
        """Store the result of one finished task."""
        kind, obj, rep = item
        if kind == "map":
            self.store.add_map(result)
            self.maps += 1
        elif kind == "group":
            for key, row, err in result:
                self._take_row(key, row, err)
            for t in obj:
                self.streamed.pop(t[0], None)
        else:
            self._store_row(*result, rep)

    def _drain(self) -> None:
        """Store the rows the local workers have streamed so far."""
        for key, row, err in self.pool.rows():
            self._take_row(key, row, err)

    def _take_row(self, key: str, row: dict, err) -> None:
        """Store one row of a lockstep group (streamed or with its group's result), once."""
        state = self.streamed.get(key)
        if state is None or state[1]:
            return
        self.streamed[key] = (state[0], True)
        self._store_row(key, row, err, state[0])

    def _store_row(self, key: str, row: dict, err, replace_row: bool) -> None:
        self.store.add_trials([(key, row, err)], replace=replace_row, world=self._world_of(row))
        self.ran += 1
        self.errors += err is not None
        self.progress.step()
        self._maybe_commit()

    def _world_of(self, row: dict) -> str | None:
        """The world fingerprint of a row's map."""
        mid = row.get("map_id")
        fp = (self.plan.worlds or {}).get(mid)
        if fp is None and mid in self.files:
            fp = self.files[mid][0][:WORLD_FINGERPRINT_CHARS]
        return fp

    def _maybe_commit(self) -> None:
        now = time.perf_counter()
        if now - self.last_commit >= COMMIT_INTERVAL_S:
            self.store.commit()
            self.last_commit = now


def map_of(item: tuple) -> str:
    """The map id of a stream item (a lockstep group, a map's metrics or one trial)."""
    kind, obj, _ = item
    if kind == "group":
        return obj[0][1].map_id
    return obj.map_id if kind == "map" else obj[1].map_id


def exit_text(code: int | None) -> str:
    """A dead process' exit code as text: "exit -11 / signal SIGSEGV", "exit 3", "exit code unknown"."""
    if code is None:
        return "exit code unknown"
    if code < 0:
        try:
            return f"exit {code} / signal {signal.Signals(-code).name}"
        except ValueError:
            return f"exit {code} / signal {-code}"
    return f"exit {code}"


def _succeeded(fut) -> bool:
    return fut.done() and not fut.cancelled() and fut.exception() is None


def grouped(items: Iterator[tuple], size: int) -> Iterator[tuple]:
    """The stream of ("map", map, False) and ("trial", trial, replaces) items with runs of consecutive trials of one
    map packed into ("group", [trials], [replaces]) items of at most ``size`` (size 1: unchanged)."""
    if size <= 1:
        yield from items
        return
    trials: list = []
    reps: list = []
    for item in items:
        kind, obj, rep = item
        if trials and (kind != "trial" or obj[1].map_id != trials[0][1].map_id or len(trials) >= size):
            yield "group", trials, reps
            trials, reps = [], []
        if kind == "trial":
            trials.append(obj)
            reps.append(rep)
        else:
            yield item
    if trials:
        yield "group", trials, reps


def unfinished(item: tuple, streamed: dict) -> tuple | None:
    """A lockstep group item without the trials whose rows have already been stored (a group re-queued after its
    worker died); registers the rest in ``streamed`` (key -> (replaces, taken)). None if nothing is left."""
    _, trials, reps = item
    keep = [(t, r) for t, r in zip(trials, reps) if not streamed.get(t[0], (r, False))[1]]
    if not keep:
        for t in trials:
            streamed.pop(t[0], None)
        return None
    for t, r in keep:
        streamed[t[0]] = (r, False)
    return "group", [t for t, _ in keep], [r for _, r in keep]


def trial_spec_of(scenario: Scenario, trial, files: dict):
    """(key, TrialSpec, RolloutRef) of one enumerated trial."""
    key, m, entry, v, start, goal = trial
    if m.map_id not in files:     # not foreseen (the store changed under the batch): build it now
        files[m.map_id] = rollout_file(scenario, m, default_horizon(scenario))
    rkey, path = files[m.map_id]
    return key, trial_spec(scenario, m, entry, v, start, goal), RolloutRef(rkey, str(path))


def submit(pool: WorkerPool, scenario: Scenario, item, files: dict):
    """Submit one stream item (a lockstep group, a map's metrics or one trial) to ``pool``; its future."""
    kind, obj, _ = item
    if kind == "group":
        specs = [trial_spec_of(scenario, t, files) for t in obj]
        ref = specs[0][2]
        task = TrialGroupTask(tuple(k for k, _, _ in specs), tuple(s for _, s, _ in specs), ref)
        return pool.submit(run_trial_group_task, task, ref.key, Path(ref.path))
    if kind == "map":
        key, path = files[obj.map_id]
        return pool.submit(run_map_task, MapTask(scenario, obj, RolloutRef(key, str(path)), METRIC_SET, "auto"),
                           key, path)
    key, spec, ref = trial_spec_of(scenario, obj, files)
    return pool.submit(run_trial_task, TrialTask(key, spec, ref), ref.key, Path(ref.path))
