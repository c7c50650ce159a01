"""The batch runner (`pbdyn batch`): every trial and map metric of a scenario, in parallel, into a results store.

This module is the entry: BatchSummary and run_batch, with the checks run before anything is written (options:
pbdyn.experiments.options; planners, rollouts). The coordinator (this process) enumerates the experiment, skips what
the store already holds (pbdyn.experiments.plan), builds each map's rollout once (cached .npz files, shipped to
workers by path; to Dask workers as bytes, scattered once per map), submits trials and map-metric tasks to a process
pool (spawn: no worker is ever forked from a process holding a PyBullet client) or to a Dask cluster through its
concurrent.futures executor (pbdyn.experiments.pool, pbdyn.experiments.cluster), and is the only writer of the
store: rows are inserted with INSERT OR IGNORE and committed at least once a second (pbdyn.experiments.dispatch), so
killing the coordinator or a worker loses no committed trial and a re-run completes the rest. A trial that raises
becomes an "error" row.

Every row records its planner pair's fingerprint (pbdyn.planning.registry.pair_fingerprint) and its world's (the
first digits of its map's rollout key, which covers an imported world's URDFs, meshes and motion modules). A store
holding rows flown with other planner code, or in a world whose code or files changed, stops the batch before
anything runs, naming what changed (pbdyn.experiments.extend), unless ``rerun_changed`` re-flies exactly those rows
(a changed world's maps: their old rows and metrics are deleted and the maps flown and measured again);
``retry_errors`` re-flies the "error" rows. Re-flown rows replace the old ones row by row (INSERT OR REPLACE).
SIGTERM and SIGINT stop the batch: rows that have arrived are committed, the worker processes are terminated, and
BatchInterrupted (a KeyboardInterrupt; exit status 128 + signal number; pbdyn.experiments.signals) is raised.
See docs/experiments.md.
"""

from __future__ import annotations

import os
import signal
import sqlite3
import time
from dataclasses import dataclass, replace
from pathlib import Path

from pbdyn import __version__
from pbdyn.config import Scenario, canonical_json
from pbdyn.errors import ConfigError
from pbdyn.experiments.cluster import connect
from pbdyn.experiments.dispatch import execute
from pbdyn.experiments.extend import check_scenario
from pbdyn.experiments.mainguard import MainGuardError, check_not_reimported
from pbdyn.experiments.options import BatchOptions
from pbdyn.experiments.plan import BatchPlan, pending_trials, read_plan
from pbdyn.experiments.shards import parse_shard
from pbdyn.experiments.signals import BatchInterrupted, stop_on_signals
from pbdyn.experiments.store import ResultsStore, check_store_path, store_error
from pbdyn.experiments.tasks import enumerate_trials, trial_spec
from pbdyn.world.maps import MAP_ID_RULE
from pbdyn.world.rollout import default_horizon, rollout_file

MAX_WORKERS_PER_CPU = 4
"""--workers may be at most this many times the CPU count (max_workers)."""


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


def max_workers() -> int:
    """The largest --workers accepted: MAX_WORKERS_PER_CPU x the CPU count (more processes than that only add
    memory and switching; each worker holds a PyBullet client and a map's rollout)."""
    return MAX_WORKERS_PER_CPU * max(1, os.cpu_count() or 1)


def _default_workers() -> int:
    """--workers by default: the CPU count."""
    return max(1, os.cpu_count() or 1)


def check_planners(scenario: Scenario) -> None:
    """Build every planner entry at every MAV speed once, as its first trial on the first map builds them
    (pbdyn.sim.agent.build_planners: names, plug-in imports, parameters, the profile's), so that a bad entry is one
    clear error before the batch starts rather than an "error" row for each of its trials."""
    from pbdyn.sim.agent import build_planners

    trials = enumerate_trials(scenario)
    for v in range(len(trials.speeds)):
        for e in range(len(trials.entries) if len(trials) else 0):
            t = trials[(e * len(trials.speeds) + v) * trials.n_pairs]
            build_planners(trial_spec(scenario, t.map, t.planner, t.v_max, t.start, t.goal))


def pending_trials_of(scenario: Scenario, out: str | Path, options: BatchOptions = BatchOptions()) -> int:
    """How many trials run_batch(scenario, out, options) would fly now (stored ones are skipped; stored ones flown
    by other code are counted with rerun_changed), worked out by reading the store only; the ConfigError run_batch
    would raise for options or a store it refuses. Planners are not built (check_planners)."""
    _, options = _checked_options(options)
    out_path = check_store_path(out, "out")
    trials = enumerate_trials(scenario)
    total = len(trials) if options.limit is None else min(options.limit, len(trials))
    return read_plan(out_path, scenario, trials, total, options).pending


def run_batch(scenario: Scenario, out: str | Path, options: BatchOptions = BatchOptions(),
              command: str = "") -> BatchSummary:
    """Run (or resume, or extend) the experiment of ``scenario`` into the results store ``out``. SIGTERM/SIGINT
    raise BatchInterrupted after committing what has arrived and stopping the workers.

    Everything that can fail before the first trial -- options, planners, the store's compatibility, every needed
    rollout, the scheduler -- is done before the store is written, so a failed start leaves no new store file
    and an existing store untouched. The trials are enumerated lazily (--limit N costs O(N)). Called at the top
    level of a script without ``if __name__ == "__main__":`` (which every spawned worker runs again), it fails with
    one line, MainGuardError (pbdyn.experiments.mainguard), instead of restarting its workers over and over."""
    check_not_reimported("run_batch")
    t0 = time.perf_counter()
    workers, options = _checked_options(options)
    out_path = check_store_path(out, "out")
    check_planners(scenario)
    trials = enumerate_trials(scenario)
    total = len(trials) if options.limit is None else min(options.limit, len(trials))
    if isinstance(options.scheduler, str):   # reach the cluster before touching the store
        client = connect(options.scheduler)
        try:
            return run_batch(scenario, out, replace(options, scheduler=client), command)
        finally:
            client.close()
    with stop_on_signals():
        plan = read_plan(out_path, scenario, trials, total, options)
        files = _rollout_files(scenario, plan.trial_maps + plan.metric_maps, out_path)
        existed = out_path.exists()
        store = ResultsStore.create(out_path, field="out")
        remove = False
        try:
            return _run(store, scenario, trials, plan, files, workers, options, command, t0)
        except BatchInterrupted as exc:
            store.commit()
            raise BatchInterrupted(exc.signum, f"batch stopped by {signal.Signals(exc.signum).name}: {store.count()} "
                                   f"trials committed to {out} (re-run the same command to resume)") from None
        except MainGuardError:
            remove = not existed and store.count() == 0      # the workers never started: leave no new store
            raise
        except sqlite3.DatabaseError as exc:
            raise store_error("out", exc, out) from None
        finally:
            try:
                store.close()
            except ConfigError:
                pass
            if remove:
                for suffix in ("", "-wal", "-shm", "-journal"):
                    Path(str(out_path) + suffix).unlink(missing_ok=True)


def _checked_options(options: BatchOptions) -> tuple[int, BatchOptions]:
    """(worker count, options with the shard parsed); ConfigError naming the first bad option."""
    workers = options.workers if options.workers is not None else _default_workers()
    if not isinstance(workers, int) or isinstance(workers, bool) or workers < 1:
        raise ConfigError("workers", "must be an integer >= 1", workers)
    if workers > max_workers():
        raise ConfigError("workers", f"must be <= {max_workers()} ({MAX_WORKERS_PER_CPU} x the "
                          f"{os.cpu_count() or 1} CPUs of this machine)", workers)
    if options.limit is not None and (not isinstance(options.limit, int) or isinstance(options.limit, bool)
                                      or options.limit < 1):
        raise ConfigError("limit", "must be an integer >= 1", options.limit)
    if not isinstance(options.lockstep, int) or isinstance(options.lockstep, bool) or options.lockstep < 1:
        raise ConfigError("lockstep", "must be an integer >= 1", options.lockstep)
    if options.shard is not None:
        options = replace(options, shard=parse_shard(options.shard))
    return workers, options


def _rollout_files(scenario: Scenario, maps: list, out: Path) -> dict[str, tuple[str, Path]]:
    """map_id -> (rollout key, .npz path) of every map, built (or found in the cache) now."""
    horizon = default_horizon(scenario)
    files: dict[str, tuple[str, Path]] = {}
    for m in maps:
        if m.map_id not in files:
            files[m.map_id] = rollout_file(scenario, m, horizon, fallback_dir=out.absolute().parent)
    return files


def _run(store: ResultsStore, scenario: Scenario, trials, plan: BatchPlan, files: dict, workers: int,
         options: BatchOptions, command: str, t0: float) -> BatchSummary:
    """Write the scenario, the world and a run record into the store, fly the plan and sum it up (``t0``: the
    batch's start on time.perf_counter, s)."""
    from pbdyn.world.rollout import world_description

    check_scenario(store, scenario, options.extend)
    if store.get_meta("map_ids") is None:
        store.set_meta("map_ids", MAP_ID_RULE)
    if plan.stale_keys:          # rows of another world go before any row of the current one is added
        store.drop_maps(plan.stale_keys, by="map_key")
    store.set_meta("world", canonical_json(world_description(scenario)))
    run_id = store.start_run(__version__, canonical_json(scenario.to_dict()), command,
                             "dask" if options.scheduler is not None else str(workers))
    ran = errors = maps_done = 0
    if plan.pending or plan.metric_maps:
        items = pending_trials(trials, plan.start, plan.start + plan.total,
                               store.stored_states if plan.stored else None, plan.stale, options.retry_errors,
                               plan.stale_maps)
        ran, errors, maps_done = execute(store, scenario, items, plan, files, workers, options)
    store.end_run(run_id)
    return BatchSummary(plan.total, plan.total - plan.pending, ran, errors, maps_done, time.perf_counter() - t0,
                        rerun=plan.rerun, stored_errors=store.error_count())
