"""Whether a results store fits this run: the --extend scenario diff, planners whose code changed since their rows
were flown, and maps whose world changed (docs/experiments.md, "Keys, seeds and extending" and "Results never go
stale silently").

The stored resolved scenario may only grow (grid values, planners, MAV speeds, maps); a changed planner or world
stops the batch unless --rerun-changed re-flies exactly those rows (pbdyn.experiments.plan decides which).
"""

from __future__ import annotations

from collections.abc import Iterator

from pbdyn.config import Scenario, canonical_json
from pbdyn.errors import ConfigError
from pbdyn.experiments.store import WORLD_FINGERPRINT_CHARS, ResultsStore
from pbdyn.world.rollout import default_horizon

_GROWABLE = {("obstacles", "count"), ("obstacles", "radius"), ("obstacles", "speed"), ("drone", "v_max"),
             ("planners",), ("obstacles", "maps")}
"""Paths of the resolved scenario whose lists may grow (old entries kept, in order) under --extend."""


def _diff(old, new, path=()) -> Iterator[tuple[tuple, object, object]]:
    """(path, old value, new value) of every place where the nested dicts ``old`` and ``new`` differ."""
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


def check_scenario(store: ResultsStore, scenario: Scenario, extend: bool, write: bool = True) -> None:
    """Record the scenario in a new store; for an existing one require the same scenario, or with ``extend`` only
    additions (ConfigError naming SCENARIO otherwise). ``write=False``: check only."""
    doc = {"name": scenario.name, **scenario.to_dict()}
    new_json = canonical_json(doc)
    old_json = store.get_meta("scenario")
    if old_json is None:
        if write:
            store.set_meta("scenario", new_json)
        return
    if old_json == new_json:
        return
    import json

    old = json.loads(old_json)
    old_profile = old.get("profile", "physical")
    if old_profile != scenario.profile:
        raise ConfigError("SCENARIO", f"has profile {scenario.profile!r} but {store.path.name} holds "
                          f"{old_profile!r} rows; a store holds one profile (use a new `out` file)",
                          scenario.source or scenario.name)
    allowed, refused = scenario_changes(old, doc)
    if refused:
        raise ConfigError("SCENARIO", f"differs from the scenario {store.path.name} was made with in "
                          f"{', '.join(refused)}; `extend` only accepts added grid values, planners, MAV speeds or "
                          "maps (use a new `out` file)", scenario.source or scenario.name)
    if not extend:
        raise ConfigError("SCENARIO", f"adds to the scenario {store.path.name} was made with ({', '.join(allowed)});"
                          " pass `extend` to run the additions", scenario.source or scenario.name)
    if write:
        store.set_meta("scenario", new_json)


def changed_planners(store: ResultsStore, scenario: Scenario) -> tuple[dict[str, str], list[str]]:
    """(label -> the current code's fingerprint of every entry whose stored rows were flown with other code, one
    note per such entry: "planners[i] (label): n stored trials flown with <old>, the code now gives <new>").
    Counted in SQL: no stored key is read."""
    from pbdyn.planning.registry import pair_fingerprint

    current = {e.label: (i, pair_fingerprint(e.trajectory, e.gaze)) for i, e in enumerate(scenario.planners)}
    seen: dict[str, tuple[int, set[str]]] = {}
    for label, fp, n in store.fingerprint_counts():
        if label in current and fp != current[label][1]:
            k, fps = seen.get(label, (0, set()))
            seen[label] = (k + n, fps | {fp or "none"})
    notes = [f"planners[{current[label][0]}] ({label}): {n} stored trials flown with {', '.join(sorted(fps))}, the "
             f"code now gives {current[label][1]}" for label, (n, fps) in sorted(seen.items(),
                                                                                 key=lambda kv: current[kv[0]][0])]
    return {label: current[label][1] for label in seen}, notes


def world_fingerprints(scenario: Scenario, maps: list) -> dict[str, str]:
    """map_id -> world fingerprint of each map: the first WORLD_FINGERPRINT_CHARS hex digits of its rollout key,
    which covers everything its obstacles' motion depends on (settings, seed, the rollout model's version, an
    imported world's URDF, mesh and motion-module digests)."""
    from pbdyn.world.rollout import rollout_key

    horizon = default_horizon(scenario)
    return {m.map_id: rollout_key(scenario, m, horizon)[:WORLD_FINGERPRINT_CHARS] for m in maps}


def changed_worlds(store: ResultsStore, scenario: Scenario, maps: list,
                   worlds: dict[str, str]) -> tuple[frozenset, list[str]]:
    """(map ids of ``maps`` whose stored trials or metrics were made in another world than the current code and
    files give, notes naming them and what changed). Rows stored before world fingerprints were recorded (schema
    < 4) are judged by their map's stored rollout key where the store has one."""
    import json

    from pbdyn.world.rollout import world_changes, world_description

    stored = store.world_fingerprints(by="map_key")     # an edited world keeps its maps' keys, not their ids
    changed = []
    for m in maps:
        got = stored.get(m.key)
        if got and any(fp and fp != worlds[m.map_id] for fp in got):
            changed.append((m, sum(got.values())))
    if not changed:
        return frozenset(), []
    old = store.get_meta("world")
    what = world_changes(json.loads(old), world_description(scenario), scenario) if old else []
    because = f" ({'; '.join(what)} changed)" if what else ""
    shown = ", ".join(f"{m.index} ({m.map_id}, {n} trials)" for m, n in changed[:5])
    more = f" and {len(changed) - 5} more" if len(changed) > 5 else ""
    return frozenset(m.map_id for m, _ in changed), [
        f"the world of map(s) {shown}{more} differs from the one their stored rows were flown in{because}"]


def changed_metrics(store: ResultsStore, scenario: Scenario, maps: list) -> tuple[frozenset, list[str]]:
    """(map ids of ``maps`` whose stored metrics were computed by other code than the current one, notes naming
    them): the maps' recorded metrics_code against pbdyn.metrics.cached.metrics_code of the batch's metric set.
    Maps whose metrics predate schema 6 record no code and are not judged."""
    from pbdyn.experiments.tasks import METRIC_SET
    from pbdyn.metrics.cached import metrics_code, resolve_backend

    stored = store.metric_codes()
    if not stored:
        return frozenset(), []
    current = metrics_code(METRIC_SET, resolve_backend(scenario, "auto"))
    changed = [m for m in maps if stored.get(m.map_id, current) != current]
    if not changed:
        return frozenset(), []
    shown = ", ".join(f"{m.index} ({m.map_id})" for m in changed[:5])
    more = f" and {len(changed) - 5} more" if len(changed) > 5 else ""
    return frozenset(m.map_id for m in changed), [
        f"the metrics of map(s) {shown}{more} were computed by code {stored[changed[0].map_id]}, the code now "
        f"gives {current}"]
