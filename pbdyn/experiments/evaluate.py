"""`pbdyn evaluate`: results stores -> the analysis input (pbdyn.analysis.report) -> table, JSON and figures."""

from __future__ import annotations

import json
from pathlib import Path

from pbdyn.errors import ConfigError
from pbdyn.experiments.store import ResultsStore


def _task(row: dict) -> str | None:
    """A trial's task label "start->goal" (m, as stored), or None when the row lacks them."""
    start, goal = row.get("start"), row.get("goal")
    if start is None or goal is None:
        return None
    return f"{','.join(f'{float(x):g}' for x in start)}->{','.join(f'{float(x):g}' for x in goal)}"


def _level(store_map: dict):
    """A map's benchmark level when its store records one (a "level" in the maps row or in the map's setup), else
    None."""
    level = store_map.get("level")
    return (store_map.get("setup") or {}).get("level") if level is None else level


POOLED = "pooled"
"""The dataset name of every map when stores are pooled (load_results(pool=True))."""


def load_results(paths: list[str | Path], pool: bool = False,
                 levels: dict[str, dict[str, int]] | None = None) -> tuple[list[dict], dict[str, dict], str]:
    """(trials, maps, controlled dataset name) from one or more stores: the first store's scenario is the
    reference (controlled) set, the others are compared with it (e.g. the uncontrolled sets). Map ids are prefixed
    with their store's scenario name so that maps of different stores never collide. Stores of different profiles
    ("physical", "thesis_program") are refused: their rows are never pooled; so is a store holding one planner label
    flown with two codes or one map flown in two worlds (pbdyn.experiments.merge.check_same_code). ``pool``: every map belongs to one
    dataset, POOLED (a heterogeneous set; map ids keep their store's prefix). Maps and trial rows carry "level":
    the map's benchmark level when its store records one (see _level), else ``levels``[scenario name][map id] (a
    benchmark suite's levels of its flight stores, pbdyn.benchmark.suite.flight_levels), else None."""
    trials: list[dict] = []
    maps: dict[str, dict] = {}
    names: list[str] = []
    profiles: dict[str, str] = {}
    from pbdyn.experiments.merge import check_same_code

    for path in paths:
        check_same_code([(path, "RESULTS")])      # one planner per label, one world per map
        store = ResultsStore.open(path)
        try:
            rows, store_maps, raw = store.results(), store.maps(), store.get_meta("scenario")
        finally:
            store.close()
        doc = json.loads(raw) if raw else {}
        name = doc.get("name") or Path(path).stem
        if name in names:
            raise ConfigError("RESULTS", f"two stores hold the same scenario {name!r}", str(path))
        profiles[str(path)] = doc.get("profile", "physical")
        if len(set(profiles.values())) > 1:
            listed = ", ".join(f"{Path(p).name}: {v}" for p, v in profiles.items())
            raise ConfigError("RESULTS", f"mixes profiles ({listed}); evaluate one profile at a time", str(path))
        names.append(name)
        known = (levels or {}).get(name) or {}
        for mid, m in store_maps.items():
            maps[f"{name}/{mid}"] = {"setup": m["setup"], "dataset": POOLED if pool else name,
                                     "metrics": m["metrics"],
                                     "metric_times": m["metric_times"],
                                     "mean_obstacle_speed": m["mean_obstacle_speed"],
                                     "mean_obstacle_radius": m["mean_obstacle_radius"],
                                     "level": known.get(mid) if _level(m) is None else _level(m)}
        for r in rows:
            mid = f"{name}/{r.get('map_id')}"
            if mid not in maps:   # a store run with --no-metrics: the map without metrics
                maps[mid] = {"setup": {"count": r.get("obstacle_count"), "radius": r.get("obstacle_radius"),
                                       "speed": r.get("obstacle_speed")}, "dataset": POOLED if pool else name,
                             "metrics": {},
                             "metric_times": {}, "mean_obstacle_speed": None, "mean_obstacle_radius": None,
                             "level": known.get(r.get("map_id"))}
            trials.append({"map_id": mid, "pair": r.get("planner_label"), "trajectory": r.get("planner"),
                           "gaze": r.get("gaze"), "mav_speed": r.get("mav_speed"), "outcome": r.get("outcome"),
                           "obstacle_count": r.get("obstacle_count"), "obstacle_radius": r.get("obstacle_radius"),
                           "obstacle_speed": r.get("obstacle_speed"), "dataset": POOLED if pool else name,
                           "task": _task(r), "task_survivability_s": r.get("task_survivability_s"),
                           "task_flux_per_s": r.get("task_flux_per_s"), "level": maps[mid]["level"]})
    if not trials:
        raise ConfigError("RESULTS", "holds no trials", [str(p) for p in paths])
    return trials, maps, POOLED if pool else names[0]


def evaluate_stores(paths: list[str | Path], *, plots: str | Path | None = None, n_boot: int = 1000,
                    seed: int = 0, pool: bool = False,
                    levels: dict[str, dict[str, int]] | None = None) -> tuple[dict, str, list[Path]]:
    """(report dict, formatted table, figure paths) of the stores (see load_results); report["figures"] holds the
    numbers of figs 5-9, 5-10 and 5-14 (pbdyn.analysis.figure_tables), report["paired"] every two planner pairs
    compared on their common tasks (pbdyn.analysis.paired.paired_table: ``n_boot`` draws, ``seed``) and
    report["success_by_group"] each pair's success per setup and level (pbdyn.analysis.paired.success_by_group;
    ``levels`` as in load_results)."""
    from pbdyn.analysis.figure_tables import figure_tables
    from pbdyn.analysis.report import evaluate, format_table, paired_sections
    from pbdyn.analysis.scale import format_scale, load_anchors, place_on_scale

    trials, maps, controlled = load_results(paths, pool, levels)
    report = evaluate(trials, maps, n_boot=n_boot, seed=seed, controlled=controlled)
    report["figures"] = figure_tables(trials, maps, report)
    report["anchored_scale"] = place_on_scale(trials, load_anchors(), _dims(paths, pool))
    report.update(paired_sections(trials, maps, n_boot=n_boot, seed=seed))
    figures: list[Path] = []
    if plots is not None:
        from pbdyn.analysis.plots import write_plots

        figures = write_plots(trials, maps, report, Path(plots))
    return report, format_table(report) + "\n\n" + format_scale(report["anchored_scale"]), figures


def _dims(paths, pool: bool) -> dict:
    """dataset name -> dims of each store's scenario (for percentiles on the anchored scale)."""
    out = {}
    for path in paths:
        st = ResultsStore.open(path)
        try:
            doc = json.loads(st.get_meta("scenario") or "{}")
        finally:
            st.close()
        out[POOLED if pool else (doc.get("name") or Path(path).stem)] = int(doc.get("world", {}).get("dims", 2))
    return out
