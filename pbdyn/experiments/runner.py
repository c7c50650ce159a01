"""The batch runner (`pbdyn batch`): every trial and map metric of a scenario, in parallel, into a results store.

The coordinator (this process) enumerates the experiment, skips what the store already holds, builds each map's
rollout once (cached .npz files, shipped to workers by path; to Dask workers as bytes, scattered once per map),
submits trials and map-metric tasks to a process pool (spawn: no worker is ever forked from a process holding a
PyBullet client) or to a Dask cluster through its concurrent.futures executor, and is the only writer of the
store: rows are inserted with INSERT OR IGNORE and committed at least once a second, so killing the coordinator or
a worker loses no committed trial and a re-run completes the rest. A trial that raises becomes an "error" row.

Every row records its planner pair's fingerprint (pbdyn.planning.registry.pair_fingerprint). A store holding rows
flown with other planner code stops the batch before anything runs, unless ``rerun_changed`` re-flies exactly those
rows; ``retry_errors`` re-flies the "error" rows. Re-flown rows replace the old ones row by row (INSERT OR
REPLACE). SIGTERM and SIGINT stop the batch: rows that have arrived are committed, the worker processes are
terminated, and BatchInterrupted (a KeyboardInterrupt; exit status 128 + signal number) is raised.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, replace
from pathlib import Path

from pbdyn import __version__
from pbdyn.config import Scenario, canonical_json
from pbdyn.errors import ConfigError, PbdynError
from pbdyn.experiments.store import ResultsStore
from pbdyn.experiments.tasks import (METRIC_SET, MapTask, RolloutRef, TrialTask, enumerate_trials, run_map_task,
                                     run_trial_task, trial_spec, worker_init)
from pbdyn.world.maps import enumerate_maps
from pbdyn.world.rollout import default_horizon, rollout_file

COMMIT_INTERVAL_S = 1.0
MAX_POOL_RESTARTS = 3
CONNECT_TIMEOUT_S = 10.0


@dataclass(frozen=True)
class BatchOptions:
    """workers: local processes (default: CPU count); scheduler: a Dask scheduler address ("tcp://host:8786") or
    a dask.distributed Client; limit: fly only the first N trials of the enumeration; extend: accept a scenario
    that adds grid values, planners, MAV speeds or maps to the one in the store; metrics: compute each map's
    metrics (METRIC_SET); progress: a progress line on stderr; rerun_changed: re-fly stored rows whose planner
    fingerprint differs from the current code's (else such rows stop the batch); retry_errors: re-fly stored
    "error" rows."""

    workers: int | None = None
    scheduler: object = None
    limit: int | None = None
    extend: bool = False
    metrics: bool = True
    progress: bool = True
    rerun_changed: bool = False
    retry_errors: bool = False


@dataclass(frozen=True)
class BatchSummary:
    """What a batch run did: trials in the experiment (after --limit), already stored (and kept), run now (rerun of
    them replaced stored rows), this run's error rows, maps whose metrics were computed, and the error rows the
    store holds after the run."""

    total: int
    skipped: int
    ran: int
    errors: int
    maps_computed: int
    wall_time_s: float
    rerun: int = 0
    stored_errors: int = 0


class BatchInterrupted(KeyboardInterrupt):
    """SIGTERM or SIGINT stopped a batch; committed rows are kept. ``exit_status`` = 128 + the signal number."""

    def __init__(self, signum: int, message: str = ""):
        self.signum = signum
        self.exit_status = 128 + signum
        super().__init__(message or f"stopped by {signal.Signals(signum).name}")


@contextlib.contextmanager
def _stop_on_signals() -> Iterator[None]:
    """Within the block, the first SIGTERM or SIGINT raises BatchInterrupted (later ones are ignored while the
    batch cleans up); the previous handlers are restored after it. A no-op outside the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    fired: list[int] = []

    def handler(signum, frame):
        if not fired:
            fired.append(signum)
            raise BatchInterrupted(signum)

    old = {sig: signal.signal(sig, handler) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        yield
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)


# ------------------------------------------------------------------------------------------------ --extend
_GROWABLE = {("obstacles", "count"), ("obstacles", "radius"), ("obstacles", "speed"), ("drone", "v_max"),
             ("planners",)}


def _diff(old, new, path=()) -> Iterator[tuple[tuple, object, object]]:
    if isinstance(old, dict) and isinstance(new, dict):
        for k in sorted(set(old) | set(new)):
            yield from _diff(old.get(k), new.get(k), path + (k,))
    elif old != new:
        yield path, old, new


def scenario_changes(old: dict, new: dict) -> tuple[list[str], list[str]]:
    """(allowed, refused) changes from the stored resolved scenario ``old`` to ``new``: grid values, planners and
    MAV speeds may be added (old ones kept, in order), maps_per_setup may grow; anything else is refused."""
    allowed, refused = [], []
    for path, a, b in _diff(old, new):
        name = ".".join(map(str, path))
        if path in _GROWABLE and isinstance(a, list) and isinstance(b, list) \
                and [canonical_json(x) for x in b[:len(a)]] == [canonical_json(x) for x in a]:
            allowed.append(name)
        elif path == ("obstacles", "maps_per_setup") and isinstance(a, int) and isinstance(b, int) and b > a:
            allowed.append(name)
        else:
            refused.append(name)
    return allowed, refused


def check_scenario(store: ResultsStore, scenario: Scenario, extend: bool) -> None:
    """Record the scenario in a new store; for an existing one require the same scenario, or with ``extend`` only
    additions (ConfigError naming SCENARIO otherwise)."""
    doc = {"name": scenario.name, **scenario.to_dict()}
    new_json = canonical_json(doc)
    old_json = store.get_meta("scenario")
    if old_json is None:
        store.set_meta("scenario", new_json)
        return
    if old_json == new_json:
        return
    import json

    allowed, refused = scenario_changes(json.loads(old_json), doc)
    if refused:
        raise ConfigError("SCENARIO", f"differs from the scenario {store.path.name} was made with in "
                          f"{', '.join(refused)}; --extend only accepts added grid values, planners, MAV speeds or "
                          "maps (use a new --out file)", scenario.source or scenario.name)
    if not extend:
        raise ConfigError("SCENARIO", f"adds to the scenario {store.path.name} was made with ({', '.join(allowed)});"
                          " pass --extend to run the additions", scenario.source or scenario.name)
    store.set_meta("scenario", new_json)


# ------------------------------------------------------------------------------------------------ progress
class Progress:
    """A progress line on stderr: done/total, trials per second and ETA; per finished trial on a terminal, every
    5 s otherwise."""

    def __init__(self, total: int, enabled: bool):
        self.total, self.enabled = total, enabled and total > 0
        self.done = 0
        self.t0 = time.perf_counter()
        self.tty = sys.stderr.isatty()
        self.last = 0.0

    def step(self, n: int = 1) -> None:
        self.done += n
        if not self.enabled:
            return
        now = time.perf_counter()
        if self.tty or now - self.last >= 5.0 or self.done == self.total:
            self.last = now
            rate = self.done / max(now - self.t0, 1e-9)
            eta = (self.total - self.done) / rate if rate > 0 else float("inf")
            line = f"pbdyn batch: {self.done}/{self.total} trials, {rate:.2f}/s, ETA {_fmt_s(eta)}"
            sys.stderr.write(("\r" + line) if self.tty else line + "\n")
            if self.tty and self.done == self.total:
                sys.stderr.write("\n")
            sys.stderr.flush()


def _fmt_s(s: float) -> str:
    if s == float("inf"):
        return "?"
    s = int(round(s))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"


# ------------------------------------------------------------------------------------------------ executors
class _Pool:
    """A process pool (spawn context, BLAS/OpenMP threads = 1 in workers) or a Dask client's executor."""

    def __init__(self, workers: int, scheduler):
        self.client = None
        self.own_client = False
        self.workers = workers
        if scheduler is not None:
            self.client = connect(scheduler) if isinstance(scheduler, str) else scheduler
            self.own_client = isinstance(scheduler, str)
            self.executor = self.client.get_executor(pure=False)
            self.scattered: dict[str, object] = {}
        else:
            self._start()

    def _start(self) -> None:
        for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ.setdefault(var, "1")
        self.executor = cf.ProcessPoolExecutor(max_workers=self.workers, initializer=worker_init,
                                               mp_context=multiprocessing.get_context("spawn"))

    @property
    def dask(self) -> bool:
        return self.client is not None

    def restart(self) -> None:
        self.executor.shutdown(wait=False, cancel_futures=True)
        self._start()

    def submit(self, fn, task, key: str, path: Path):
        """Submit fn(task) -- for Dask fn(task, data) with the rollout's bytes scattered once per map."""
        if not self.dask:
            return self.executor.submit(fn, task)
        if key not in self.scattered:
            self.scattered[key] = self.client.scatter(path.read_bytes(), broadcast=True)
        return self.executor.submit(fn, task, self.scattered[key])

    def close(self, terminate: bool = False) -> None:
        """Shut down: wait for running tasks, or with ``terminate`` cancel them and end the local worker processes
        (SIGTERM, then SIGKILL after 5 s); a Dask cluster's workers are left running."""
        if self.dask:
            self.executor.shutdown(wait=not terminate)     # wait=False cancels the running futures
        elif terminate:
            procs = list((getattr(self.executor, "_processes", None) or {}).values())
            for p in procs:
                p.terminate()
            self.executor.shutdown(wait=False, cancel_futures=True)
            for p in procs:
                p.join(5.0)
                if p.is_alive():
                    p.kill()
                    p.join(1.0)
        else:
            self.executor.shutdown(wait=True, cancel_futures=True)
        if self.own_client:
            self.client.close()


def check_planners(scenario: Scenario) -> None:
    """Resolve and build every planner entry once (names, plug-in imports, parameters), so that a bad entry is one
    clear error before the batch starts rather than an "error" row for each of its trials."""
    import numpy as np

    from pbdyn.planning.protocols import PlannerContext
    from pbdyn.planning.registry import build_planner, resolve_gaze_planner, resolve_trajectory_planner
    from pbdyn.planning.view import MAVLimits

    d = scenario.drone
    for v in d.v_max:
        ctx = PlannerContext(scenario.world.dims, scenario.world.dt, MAVLimits(d.radius, v, d.a_max, d.yaw_rate_limit),
                             np.zeros(scenario.world.dims), np.asarray(scenario.world.size, dtype=float), 0)
        for i, e in enumerate(scenario.planners):
            build_planner(resolve_trajectory_planner(e.trajectory, f"planners[{i}].trajectory"), ctx,
                          e.trajectory_params, f"planners[{i}].trajectory_params")
            build_planner(resolve_gaze_planner(e.gaze, f"planners[{i}].gaze"), ctx, e.gaze_params,
                          f"planners[{i}].gaze_params")


def connect(address: str):
    """A dask.distributed Client of the scheduler at ``address``; ConfigError naming --scheduler if it cannot be
    reached within CONNECT_TIMEOUT_S."""
    from dask.distributed import Client

    try:
        return Client(address, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError, ValueError) as exc:
        raise ConfigError("scheduler", "cannot reach a Dask scheduler there "
                          f"({type(exc).__name__}: {' '.join(str(exc).split())[:160]})", address) from None


def _default_workers() -> int:
    return max(1, os.cpu_count() or 1)


def changed_planners(store: ResultsStore, scenario: Scenario, states: dict | None = None) -> tuple[set[str],
                                                                                                  list[str]]:
    """(keys of stored rows whose planner fingerprint differs from the current code's for their entry, one note per
    changed entry: "planners[i] (label): n stored trials flown with <old>, the code now gives <new>").
    ``states``: store.trial_states() if already read."""
    from pbdyn.planning.registry import pair_fingerprint

    current = {e.label: (i, pair_fingerprint(e.trajectory, e.gaze)) for i, e in enumerate(scenario.planners)}
    stale: set[str] = set()
    seen: dict[str, tuple[int, set[str]]] = {}
    for key, (label, fp, _) in (store.trial_states() if states is None else states).items():
        if label in current and fp != current[label][1]:
            stale.add(key)
            n, fps = seen.get(label, (0, set()))
            seen[label] = (n + 1, fps | {fp or "none"})
    notes = [f"planners[{current[label][0]}] ({label}): {n} stored trials flown with {', '.join(sorted(fps))}, the "
             f"code now gives {current[label][1]}" for label, (n, fps) in sorted(seen.items(),
                                                                                 key=lambda kv: current[kv[0]][0])]
    return stale, notes


def run_batch(scenario: Scenario, out: str | Path, options: BatchOptions = BatchOptions(),
              command: str = "") -> BatchSummary:
    """Run (or resume, or extend) the experiment of ``scenario`` into the results store ``out``. SIGTERM/SIGINT
    raise BatchInterrupted after committing what has arrived and stopping the workers."""
    t0 = time.perf_counter()
    workers = options.workers if options.workers is not None else _default_workers()
    if not isinstance(workers, int) or workers < 1:
        raise ConfigError("workers", "must be an integer >= 1", workers)
    if options.limit is not None and (not isinstance(options.limit, int) or options.limit < 1):
        raise ConfigError("limit", "must be an integer >= 1", options.limit)
    check_planners(scenario)
    maps = enumerate_maps(scenario)
    trials = enumerate_trials(scenario, maps)
    if options.limit is not None:
        trials = trials[: options.limit]
    if isinstance(options.scheduler, str):   # reach the cluster before touching the store
        client = connect(options.scheduler)
        try:
            return run_batch(scenario, out, replace(options, scheduler=client), command)
        finally:
            client.close()
    with _stop_on_signals():
        store = ResultsStore.create(out)
        try:
            return _run(store, scenario, trials, workers, options, command, t0)
        except BatchInterrupted as exc:
            store.commit()
            raise BatchInterrupted(exc.signum, f"batch stopped by {signal.Signals(exc.signum).name}: {store.count()} "
                                   f"trials committed to {out} (re-run the same command to resume)") from None
        finally:
            store.close()


def _run(store: ResultsStore, scenario: Scenario, trials: list, workers: int, options: BatchOptions, command: str,
         t0: float) -> BatchSummary:
    states = store.trial_states()
    stale, notes = changed_planners(store, scenario, states)
    if stale and not options.rerun_changed:
        raise ConfigError("; ".join(notes), "planner code changed since these rows were flown; pass "
                          "--rerun-changed to re-fly them (or use a new --out file)", show_value=False)
    check_scenario(store, scenario, options.extend)
    redo = set(stale) if options.rerun_changed else set()
    if options.retry_errors:
        redo |= {k for k, (_, _, outcome) in states.items() if outcome == "error"}
    pending = [t for t in trials if t[0] not in states or t[0] in redo]
    replace_keys = {t[0] for t in pending if t[0] in states}
    used_maps = {t[1].map_id: t[1] for t in trials}
    need_metrics = [m for mid, m in used_maps.items() if mid not in store.maps_with_metrics()] \
        if options.metrics else []
    run_id = store.start_run(__version__, canonical_json(scenario.to_dict()), command,
                             "dask" if options.scheduler is not None else str(workers))
    ran = errors = maps_done = 0
    if pending or need_metrics:
        horizon = default_horizon(scenario)
        files: dict[str, tuple[str, Path]] = {}
        for m in list({t[1].map_id: t[1] for t in pending}.values()) + need_metrics:
            if m.map_id not in files:
                files[m.map_id] = rollout_file(scenario, m, horizon, fallback_dir=store.path.parent)
        ran, errors, maps_done = _execute(store, scenario, pending, need_metrics, files, workers, options,
                                          replace_keys)
    store.end_run(run_id)
    return BatchSummary(len(trials), len(trials) - len(pending), ran, errors, maps_done, time.perf_counter() - t0,
                        rerun=len(replace_keys), stored_errors=store.error_count())


def _execute(store: ResultsStore, scenario: Scenario, pending: list, need_metrics: list, files: dict, workers: int,
             options: BatchOptions, replace_keys: set[str] = frozenset()) -> tuple[int, int, int]:
    pool = _Pool(workers, options.scheduler)
    progress = Progress(len(pending), options.progress)
    counts = {"ran": 0, "errors": 0, "maps": 0}
    remaining_trials = {t[0]: t for t in pending}
    remaining_maps = {m.map_id: m for m in need_metrics}
    in_flight: dict = {}

    def take(kind: str, item, result) -> None:
        if kind == "map":
            store.add_map(result)
            remaining_maps.pop(item.map_id, None)
            counts["maps"] += 1
        else:
            key, row, err = result
            store.add_trials([(key, row, err)], replace=key in replace_keys)
            remaining_trials.pop(key, None)
            counts["ran"] += 1
            counts["errors"] += err is not None
            progress.step()

    last_commit = time.perf_counter()
    restarts = 0
    interrupted = False
    try:
        while remaining_trials or remaining_maps:
            queue = [("map", m) for m in remaining_maps.values()] + [("trial", t) for t in remaining_trials.values()]
            in_flight.clear()
            window = 4 * workers if not pool.dask else max(64, 8 * workers)
            it = iter(queue)
            try:
                while True:
                    while len(in_flight) < window:
                        item = next(it, None)
                        if item is None:
                            break
                        fut = _submit(pool, scenario, item, files)
                        in_flight[fut] = item
                    if not in_flight:
                        break
                    finished, _ = cf.wait(list(in_flight), return_when=cf.FIRST_COMPLETED)
                    for fut in finished:
                        kind, item = in_flight.pop(fut)
                        take(kind, item, fut.result())
                    now = time.perf_counter()
                    if now - last_commit >= COMMIT_INTERVAL_S:
                        store.commit()
                        last_commit = now
            except BrokenProcessPool:
                store.commit()
                restarts += 1
                if restarts > MAX_POOL_RESTARTS:
                    raise PbdynError(f"worker processes died {restarts} times; {len(remaining_trials)} trials not "
                                     "run (re-run the same command to resume)") from None
                sys.stderr.write(f"pbdyn batch: a worker died; restarting the pool ({restarts}/"
                                 f"{MAX_POOL_RESTARTS}) and resuming\n")
                pool.restart()
        store.commit()
    except KeyboardInterrupt:
        interrupted = True
        for fut, (kind, item) in list(in_flight.items()):   # keep what has arrived
            if fut.done() and not fut.cancelled() and fut.exception() is None:
                take(kind, item, fut.result())
        raise
    finally:
        store.commit()
        pool.close(terminate=interrupted)
    return counts["ran"], counts["errors"], counts["maps"]


def _submit(pool: _Pool, scenario: Scenario, item, files: dict):
    kind, obj = item
    if kind == "map":
        key, path = files[obj.map_id]
        return pool.submit(run_map_task, MapTask(scenario, obj, RolloutRef(key, str(path)), METRIC_SET, "auto"),
                           key, path)
    key, m, entry, v, start, goal = obj
    rkey, path = files[m.map_id]
    spec = trial_spec(scenario, m, entry, v, start, goal)
    return pool.submit(run_trial_task, TrialTask(key, spec, RolloutRef(rkey, str(path))), rkey, path)
