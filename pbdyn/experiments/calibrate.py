"""`pbdyn calibrate` (docs/difficulty-scale.md): the reference panel flies the maps' reference tasks at the panel
speeds (pbdyn.analysis.scale.reference_document) through the batch runner into a results store (resumable; by
default one in the cache, keyed by what is flown), and the anchored scale measures each map from the panel's trials
there (measure_store, pbdyn.analysis.scale.measure_difficulties). A map of a world whose code changed refuses to
extend the store like any batch (pbdyn.experiments.runner).
"""

from __future__ import annotations

import hashlib
import json
import tomllib
from pathlib import Path

from pbdyn.analysis.scale import (BOOTSTRAP, Anchors, MapDifficulty, load_anchors, measure_difficulties,
                                  panel_counts, reference_document)
from pbdyn.config import Scenario, canonical_json, parse_scenario
from pbdyn.errors import ConfigError


def reference_scenario(scenario, maps=None) -> tuple[Scenario, dict[str, int]]:
    """(the scenario that flies the reference panel on ``scenario``'s maps -- all, or the indices ``maps`` --, map
    id -> the map's index in ``scenario``): its document with the panel, the panel speeds and the reference pairs
    (pbdyn.analysis.scale.reference_document); chosen maps become an explicit map list (the same maps). Relative
    paths resolve against the original file."""
    from pbdyn.config import load_scenario
    from pbdyn.world.maps import enumerate_maps

    if isinstance(scenario, Scenario):
        sc, doc = scenario, {"name": scenario.name, **scenario.to_dict()}
    elif isinstance(scenario, dict):
        sc, doc = parse_scenario(scenario), dict(scenario)
    elif isinstance(scenario, (str, Path)):
        from pbdyn import resources

        sc, doc = load_scenario(scenario), tomllib.loads(resources.find_scenario(scenario).read_text(encoding="utf-8"))
    else:
        raise ConfigError("scenario", "must be a path, a bundled scenario name or a dict shaped like the TOML file",
                          scenario)
    all_maps = enumerate_maps(sc)
    index = {m.map_id: m.index for m in (all_maps if maps is None else [])}
    if maps is not None:
        chosen = []
        for m in maps:
            if isinstance(m, bool) or not isinstance(m, int) or not 0 <= m < len(all_maps):
                raise ConfigError("map", f"must be a map index in [0, {len(all_maps) - 1}]", m)
            if m not in chosen:
                chosen.append(m)
                index[all_maps[m].map_id] = m
        if not sc.is_world:
            obst = {k: v for k, v in doc.get("obstacles", {}).items()
                    if k not in ("count", "radius", "speed", "maps_per_setup", "structure", "maps")}
            keep = ("count", "radius", "speed", "structure")
            obst["maps"] = [{**{k: v for k, v in all_maps[m].setup.items() if k in keep},
                             "replicate": all_maps[m].replicate} for m in chosen]
            doc = {**doc, "obstacles": obst}
    ref = reference_document(doc, sc.task.candidates)
    ref["name"] = f"{sc.name}_reference"
    return parse_scenario(ref, sc.source), index


def default_store(ref: Scenario) -> Path:
    """Where a calibration is kept unless told: <cache>/calibration/<name>-<hash of what is flown and the code that
    flies it>.sqlite (an edit of pbdyn's code starts another store; reverting it finds the old one)."""
    from pbdyn.planning.registry import pair_fingerprint
    from pbdyn.world.rollout import cache_dir, world_description

    code = [pair_fingerprint(e.trajectory, e.gaze) for e in ref.planners] + [world_description(ref)]
    digest = hashlib.sha256(canonical_json({"scenario": ref.to_dict(), "code": code}).encode()).hexdigest()[:16]
    return cache_dir() / "calibration" / f"{ref.name}-{digest}.sqlite"


def calibrate(scenario, *, maps=None, store=None, workers=None, progress: bool = False,
              anchors: Anchors | None = None, n_boot: int = BOOTSTRAP, seed: int = 0) -> list[MapDifficulty]:
    """Fly the reference panel on the maps (resuming a store that holds part of it) and return each map's measured
    difficulty (measure_store). ``store``: the results store (default: default_store); ``anchors``: default the
    shipped ones."""
    from pbdyn.experiments.runner import BatchOptions, run_batch

    ref, index = reference_scenario(scenario, maps)
    path = Path(store) if store is not None else default_store(ref)
    run_batch(ref, path, BatchOptions(workers=workers, metrics=False, progress=progress))
    res = measure_store(path, anchors=load_anchors() if anchors is None else anchors, n_boot=n_boot, seed=seed,
                        dims=ref.world.dims, index=index)
    return [r for r in res if r.map_id in index]


def measure_store(path, *, anchors: Anchors | None, n_boot: int = BOOTSTRAP, seed: int = 0,
                  dims: int | None = None, index: dict | None = None) -> list[MapDifficulty]:
    """measure_difficulties() of the panel's trials in the results store ``path``; ``index``: map id -> the map index
    to report (default: the store's)."""
    from pbdyn.experiments.store import ResultsStore

    st = ResultsStore.open(path)
    try:
        rows = st.results()
        doc = json.loads(st.get_meta("scenario") or "{}")
    finally:
        st.close()
    counts = panel_counts(rows)
    for mid in set(counts) & set(index or ()):
        counts[mid]["index"] = index[mid]
    if not counts:
        raise ConfigError("RESULTS", "holds no trial of the reference panel", str(path))
    return measure_difficulties(counts, anchors, n_boot=n_boot, seed=seed,
                                dims=dims or int(doc.get("world", {}).get("dims", 2)))
