"""What a batch will do, worked out before its store is written (BatchPlan, read_plan), and the stream of the trials
it flies (pending_trials): trials not stored yet, and stored ones to re-fly (changed planner code or world, error
rows with --retry-errors). The existing store is only read here (docs/experiments.md, "Nothing is written until the
batch can start").
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from pbdyn.config import Scenario
from pbdyn.errors import ConfigError
from pbdyn.experiments.extend import (changed_metrics, changed_planners, changed_worlds, check_scenario,
                                     world_fingerprints)
from pbdyn.experiments.options import BatchOptions
from pbdyn.experiments.shards import shard_range
from pbdyn.experiments.store import ResultsStore


@dataclass
class BatchPlan:
    """What a batch will do, worked out before the store is written: pending trial count, rows it replaces, the
    maps whose rollouts the run needs, the maps whose metrics it computes."""

    start: int           # the trials start..start+total-1 of the enumeration (a shard, or all from 0)
    total: int
    pending: int
    rerun: int
    trial_maps: list
    metric_maps: list
    stored: bool          # the store holds trials: pending trials are looked up in it
    stale: dict           # label -> current fingerprint of entries whose rows must be re-flown (rerun_changed)
    worlds: dict = None   # map_id -> world fingerprint (rollout key prefix) of every map of the run's range
    stale_maps: frozenset = frozenset()   # maps whose stored rows were flown in another world (rerun_changed)
    stale_keys: frozenset = frozenset()   # their map keys (the stored rows of another world carry other map ids)


def pending_trials(trials, start: int, stop: int, states_of, stale: dict,
                   retry_errors: bool, stale_maps: frozenset = frozenset()) -> Iterator[tuple[tuple, bool]]:
    """(trial, replaces a stored row) for every trial start..stop-1 that is not stored, or is stored and must be
    re-flown (its planner code or its map's world changed); ``states_of(keys)`` reads the stored states of a chunk
    of keys (None: nothing stored)."""
    it = trials.iter_range(start, stop)
    while True:
        chunk = list(itertools.islice(it, 500))
        if not chunk:
            return
        states = states_of([t[0] for t in chunk]) if states_of is not None else {}
        for t in chunk:
            st = states.get(t[0])
            if t[1].map_id in stale_maps:
                yield t, st is not None
            elif st is None:
                yield t, False
            else:
                label, fp, outcome = st
                if (label in stale and fp != stale[label]) or (retry_errors and outcome == "error"):
                    yield t, True


def check_unique_ids(maps) -> None:
    """ConfigError if two of the run's maps share an id (MapSpec.map_id: a store keys maps by it)."""
    seen: dict[str, int] = {}
    for m in maps:
        if m.map_id in seen:
            raise ConfigError("map", f"maps {seen[m.map_id]} and {m.index} share the id {m.map_id}; a store keys "
                              "maps by id (report this: two different maps should never share one)", m.map_id)
        seen[m.map_id] = m.index


def check_id_rule(store: ResultsStore, out: Path, field: str = "out") -> None:
    """ConfigError if ``store`` holds rows or maps named by another map id rule than this pbdyn's
    (pbdyn.world.maps.MAP_ID_RULE; stores without the meta key were written by the rule before, "setup-1"): their
    ids and the run's would name one map twice."""
    from pbdyn.world.maps import MAP_ID_RULE

    rule = store.get_meta("map_ids")
    if rule == MAP_ID_RULE or (rule is None and store.is_empty()):
        return
    raise ConfigError(field, f"names its maps by the map id rule {rule or 'setup-1'} (an older pbdyn); this pbdyn "
                      f"names them by {MAP_ID_RULE}, and one store cannot hold both (use a new `out` file)", str(out))


def read_plan(out: Path, scenario: Scenario, trials, total: int, options: BatchOptions) -> BatchPlan:
    """Read the existing store (if any) read-only and work out the plan; refuse a changed scenario or changed
    planner code here, before anything is built or written."""
    start, stop, map_idx = shard_range(trials, total, options.shard)
    total = stop - start
    per_map_maps = [trials.maps[i] for i in map_idx]
    check_unique_ids(per_map_maps)
    worlds = world_fingerprints(scenario, per_map_maps)
    if not out.exists() or out.stat().st_size == 0:
        return BatchPlan(start, total, total, 0, per_map_maps, per_map_maps if options.metrics else [], False, {},
                         worlds)
    store = ResultsStore.open(out, field="out")
    try:
        if store._foreign_tables():
            raise ConfigError("out", "is an SQLite file but not a pbdyn results store (use a new `out` file)",
                              str(out))
        check_id_rule(store, out)
        stale, notes = changed_planners(store, scenario)
        if stale and not options.rerun_changed:
            raise ConfigError("; ".join(notes), "planner code changed since these rows were flown; pass "
                              "`rerun_changed` to re-fly them (or use a new `out` file)", show_value=False)
        check_scenario(store, scenario, options.extend, write=False)
        stale_maps, world_notes = changed_worlds(store, scenario, per_map_maps, worlds)
        if stale_maps and not options.rerun_changed:
            raise ConfigError("; ".join(world_notes), "a world's code or files changed since these rows were "
                              "flown; pass `rerun_changed` to re-fly those maps (or use a new `out` file)",
                              show_value=False)
        stale_metrics, metric_notes = (changed_metrics(store, scenario, per_map_maps) if options.metrics
                                       else (frozenset(), []))
        if stale_metrics and not options.rerun_changed:
            raise ConfigError("; ".join(metric_notes), "a metric's code changed since these metrics were computed; "
                              "pass `rerun_changed` to compute them again (or use a new `out` file)",
                              show_value=False)
        if not options.rerun_changed:
            stale = {}
        stored = store.count() > 0
        pending = rerun = 0
        maps: dict[str, object] = {}
        for t, rep in pending_trials(trials, start, stop, store.stored_states if stored else None, stale,
                                     options.retry_errors, stale_maps):
            pending += 1
            rerun += rep
            maps.setdefault(t[1].map_id, t[1])
        done = (store.maps_with_metrics() - stale_maps - stale_metrics) if options.metrics else set()
        metric_maps = [m for m in per_map_maps if m.map_id not in done] if options.metrics else []
        return BatchPlan(start, total, pending, rerun, list(maps.values()), metric_maps, stored, stale, worlds,
                         stale_maps, frozenset(m.key for m in per_map_maps if m.map_id in stale_maps))
    finally:
        store.conn.close()
