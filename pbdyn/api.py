"""The public Python API: the one door to pbdyn for notebooks, scripts, the CLI and the tools (docs/api.md).

    import pbdyn
    result = pbdyn.run_trial("quickstart", planner="local_primitives", gaze="lookahead")
    metrics = pbdyn.compute_metrics("quickstart", map=0)
    with pbdyn.open_results("results/quickstart.sqlite") as results:
        trials = results.trials()

Scenarios are given as a path, a bundled scenario's name ("quickstart", "datasets/controlled_2d"), a dict shaped
like the TOML file, or a loaded Scenario. Bad values raise pbdyn.ConfigError naming the parameter and the value.
"""

from __future__ import annotations

import contextlib
import dataclasses
import inspect
import math
import os
from collections.abc import Iterator, Mapping
from pathlib import Path

from typing import TYPE_CHECKING

from pbdyn.config import Scenario, parse_scenario
from pbdyn.config import load_scenario as _load_file
from pbdyn.errors import ConfigError

if TYPE_CHECKING:  # pragma: no cover - the heavy modules load on first use
    from pbdyn.sim.checker import PlannerCheck
    from pbdyn.sim.result import TrialResult
    from pbdyn.world.rollout import Rollout

__all__ = ["load_scenario", "map_info", "rollout", "run_trial", "compute_metrics", "metric_heatmaps", "metric_backend", "run_batch", "merge_results", "replay", "open_results",
           "generate_maps", "calibrate",
           "Results", "export_results", "evaluate", "check_planner", "run_demo"]


def load_scenario(scenario) -> Scenario:
    """A validated Scenario from a path, a bundled scenario's name, a dict shaped like the TOML file, or a
    Scenario (returned as it is). Omitted fields take the README's defaults."""
    if isinstance(scenario, Scenario):
        return scenario
    if isinstance(scenario, Mapping):
        return parse_scenario(scenario)
    if isinstance(scenario, (str, Path)):
        return _load_file(scenario)
    raise ConfigError("scenario", "must be a path, a bundled scenario name, a dict or a Scenario", scenario)


def _map(sc: Scenario, index):
    from pbdyn.world.maps import get_map

    if not isinstance(index, int) or isinstance(index, bool):
        raise ConfigError("map", "must be a map index (an integer)", index)
    return get_map(sc, index)


def map_info(scenario, map: int = 0) -> dict:
    """The map's identity: map_index, map_id, setup (the grid values), replicate and seed."""
    ms = _map(load_scenario(scenario), map)
    return {"map_index": ms.index, "map_id": ms.map_id, "setup": ms.setup, "replicate": ms.replicate,
            "seed": ms.seed}


def rollout(scenario, map: int = 0, *, horizon: float | None = None) -> Rollout:
    """The map's rollout: every obstacle's position and velocity at every step (cached on disk). ``horizon``
    (s): the time to cover (default: the trial time limit plus one step; given: computed afresh, not cached)."""
    from pbdyn.world.rollout import build_rollout, get_rollout

    sc = load_scenario(scenario)
    ms = _map(sc, map)
    if horizon is None:
        return get_rollout(sc, ms)
    if isinstance(horizon, bool) or not isinstance(horizon, (int, float)) or not math.isfinite(horizon) \
            or horizon <= 0:
        raise ConfigError("horizon", "must be a positive number of seconds", horizon)
    return build_rollout(sc, ms, float(horizon))


def _planner_name(obj, kind: str) -> str | None:
    """None for None, the string itself, or "module:QualName" for a class or instance with the needed methods."""
    if obj is None or isinstance(obj, str):
        return obj
    methods = ("replan_check", "plan") if kind == "planner" else ("yaw_rate",)
    missing = [m for m in methods if not callable(getattr(obj, m, None))]
    if missing:
        what = "trajectory" if kind == "planner" else "gaze"
        raise ConfigError(kind, f"is not a {what} planner: missing method(s) {', '.join(missing)}",
                          obj if inspect.isclass(obj) else type(obj))
    from pbdyn.sim.spec import plugin_name

    return plugin_name(obj)


def run_trial(scenario="quickstart", *, planner=None, gaze=None, map: int = 0, start=None, goal=None,
              v_max: float | None = None, trace: str | Path | None = None, gui: bool = False,
              observers: list | None = None, gui_snapshot: str | Path | None = None,
              follow: bool = False) -> TrialResult:
    """Fly one trial and return its TrialResult (``result.outcome``, ``result.to_dict()``).

    planner: a trajectory planner — a registry name ("local_primitives", "global_primitives", "mpc",
        "straight_line", "local_primitives_minjerk"), a scenario entry's label, "package.module:Class", a class or
        an instance (default: the scenario's first [[planners]] entry). gaze: a gaze planner, likewise (default: the entry's).
    map: the map index; start, goal: (x, y[, z]) in m (default: the first and the last candidate); v_max: the MAV's
    speed limit (m/s; default: the first drone.v_max); trace: write per-step arrays to this .npz file; gui: show
    the PyBullet GUI in real time, the arena framed (``follow``: the camera follows the MAV), the field of view,
    plan and goal drawn; gui_snapshot: write a .png of the final state rendered headless (PyBullet's TinyRenderer);
    observers: extra step observers (pbdyn.sim.observers.Observer).
    """
    from pbdyn.sim.spec import make_trial_spec, with_planner_objects
    from pbdyn.sim.trial import run_trial as fly_one

    sc = load_scenario(scenario)
    ms = _map(sc, map)
    tname, gname = _planner_name(planner, "planner"), _planner_name(gaze, "gaze")
    tobj = None if planner is None or isinstance(planner, str) else planner
    gobj = None if gaze is None or isinstance(gaze, str) else gaze
    if trace is not None and not str(trace).endswith(".npz"):
        raise ConfigError("trace", "must name an .npz file", str(trace))
    if trace is not None:   # before flying: a trace that cannot be written fails now, not after the trial
        from pbdyn.errors import check_writable_file

        check_writable_file("trace", trace)
    observers = _observers(observers)
    if gui_snapshot is not None:
        from pbdyn.errors import check_writable_file
        from pbdyn.sim.gui import Snapshot

        if Path(gui_snapshot).suffix.lower() != ".png":
            raise ConfigError("gui_snapshot", "must name a .png file", str(gui_snapshot))
        check_writable_file("gui_snapshot", gui_snapshot)
        observers.append(Snapshot(gui_snapshot))
    spec = make_trial_spec(sc, ms, planner=None if tobj is not None else tname,
                           gaze=None if gobj is not None else gname, v_max=v_max,
                           start=_point(start, "start"), goal=_point(goal, "goal"))
    spec = with_planner_objects(spec, tobj, gobj)
    from pbdyn.world.rollout import get_rollout

    return fly_one(spec, get_rollout(sc, ms), gui=gui, trace_path=trace, gui_sleep=sc.world.dt if gui else 0.0,
               trajectory_planner=tobj, gaze_planner=gobj, observers=observers, gui_follow=follow)


def _observers(value) -> list:
    """``observers`` as a list; ConfigError unless it is None or a list/tuple of objects with on_step and on_end."""
    if value is None:
        return []
    if not isinstance(value, (list, tuple)):
        raise ConfigError("observers", "must be a list of observers (objects with on_step and on_end)", value)
    for obs in value:
        if not all(callable(getattr(obs, m, None)) for m in ("on_step", "on_end")):
            raise ConfigError("observers", "must hold observers (objects with on_step and on_end methods)", obs)
    return list(value)


def _names(value, name: str) -> list[str] | None:
    """``value`` (None, a name or a list of names) as a list of names; ConfigError naming ``name`` otherwise."""
    if value is None:
        return None
    if isinstance(value, str):
        return [value]
    if isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value):
        return list(value)
    raise ConfigError(name, "must be a name or a list of names", value)


def _path(value, name: str) -> str | Path:
    """``value`` if it is a path (str or os.PathLike); ConfigError naming ``name`` otherwise."""
    if isinstance(value, str) or (isinstance(value, os.PathLike) and isinstance(os.fspath(value), str)):
        return value
    raise ConfigError(name, "must be a path (a str or pathlib.Path)", value)


def _point(value, name: str):
    if value is None or isinstance(value, str):
        return value
    try:
        return tuple(float(x) for x in value)
    except (TypeError, ValueError):
        raise ConfigError(name, "must be a sequence of numbers like (4, 25)", value) from None


def compute_metrics(scenario, map: int = 0, *, metrics=None, dense: bool = False, backend: str = "auto") -> dict:
    """The difficulty metrics of one map (thesis chapter 3): {name: {"value", "stderr", "n_samples",
    "n_excluded", "wall_time_s", "cached"}}. metrics: names (default: every sparse metric); dense: use the dense
    sample grids; backend: survivability backend "analytic", "bullet", "mesh" or "auto" (bullet for imported
    worlds with moving bodies, else analytic)."""
    from pbdyn.metrics.cached import map_metrics, metric_names, resolve_backend

    sc = load_scenario(scenario)
    try:
        names = metric_names(_names(metrics, "metrics"), dense)
    except ConfigError as exc:
        raise exc.renamed("metrics") if exc.field == "metric" else exc from None
    chosen = resolve_backend(sc, backend)
    return map_metrics(sc, _map(sc, map), names, backend=chosen)


def predict_success(scenario, map: int = 0, *, backend: str = "auto") -> dict:
    """The predicted reference success of one map (pbdyn.analysis.predict; docs/difficulty-scale.md):
    {"success", "ci": [lo, hi] (95%, for one map), "percentile" (share % of the bundled calibration maps easier
    than it), "features"}, or {"why": ...} when no shipped predictor covers the scenario's dims."""
    from pbdyn.analysis.predict import load_predictors, predicted_success
    from pbdyn.analysis.scale import reference_pairs
    from pbdyn.metrics.cached import resolve_backend
    from pbdyn.metrics.features import map_features

    sc = load_scenario(scenario)
    spec = _map(sc, map)
    predictors = load_predictors()
    if sc.world.dims not in predictors:
        return predicted_success(predictors, {}, sc.world.dims)
    feats = map_features(sc, spec.index, reference_pairs(sc.task.candidates), backend=resolve_backend(sc, backend))
    pred = predicted_success(predictors, feats, sc.world.dims)
    if sc.world.dims == 3 and sc.is_world:
        pred["note"] = ("outside the 3D calibration set, which has no imported world: the 3D predictor knows "
                        "static geometry only as the walls family's, and may be off here")
    return pred


def metric_heatmaps(scenario, map: int = 0, out: str | Path = "heatmap.png", *, metrics=None, dense: bool = False,
                    backend: str = "auto"):
    """`pbdyn metrics --plot`: draw the per-sample values of survivability and VO feasibility (or the requested ones
    of them; the dense grids with ``dense``) of one map as heat maps with its obstacles into ``out`` (.png at 200
    dpi, .pdf, .svg). Returns a HeatmapFigure (path, figure, panels); each metric's samples are
    pbdyn.analysis.heatmap.metric_samples."""
    from pbdyn.analysis.heatmap import check_figure_path, heatmap_metrics, metric_samples, plot_heatmaps
    from pbdyn.metrics.cached import resolve_backend
    from pbdyn.world.rollout import default_horizon, get_rollout

    sc = load_scenario(scenario)
    out = check_figure_path(out)
    names = heatmap_metrics([metrics] if isinstance(metrics, str) else metrics, dense)
    chosen = resolve_backend(sc, backend)
    spec = _map(sc, map)
    ro = get_rollout(sc, spec, default_horizon(sc))
    samples = [metric_samples(sc, ro, n, chosen) for n in names]
    return plot_heatmaps(ro, samples, out, title=f"{sc.name} map {spec.index}")


def metric_backend(scenario, backend: str = "auto") -> str:
    """The survivability backend compute_metrics uses for ``backend`` on this scenario ("auto": bullet for imported
    worlds with moving bodies, else analytic)."""
    from pbdyn.metrics.cached import resolve_backend

    return resolve_backend(load_scenario(scenario), backend)


def run_batch(scenario, out: str | Path, *, workers: int | None = None, scheduler=None, limit: int | None = None,
              extend: bool = False, metrics: bool = True, rerun_changed: bool = False, retry_errors: bool = False,
              progress: bool = True, shard: str | tuple[int, int] | None = None, lockstep: int | None = None,
              command: str = ""):
    """Run (or resume) every trial and map metric of ``scenario`` into the results store ``out`` (SQLite) and
    return a BatchSummary (total, skipped, ran, errors, stored_errors, rerun, maps_computed, wall_time_s).

    workers: local processes (default: CPU count; at most 4 x the CPU count); scheduler: a Dask scheduler address
    ("tcp://host:8786"; checked and probed, a bounded wait) or a dask.distributed Client (tls: a Client made with a
    Security object); limit: only the
    first N trials; extend: accept added grid values, planners, MAV speeds or maps; metrics: compute each map's
    metrics; rerun_changed: re-fly rows whose planner code changed; retry_errors: re-fly stored error rows;
    shard: "I/N" or (I, N), only the I-th of N contiguous blocks of maps (their stores join with merge_stores);
    lockstep: trials of one map flown together per task (default 72; 1: one per task; rows are the same).
    Planners must be given by name in the scenario (workers import them). Local workers start by running the
    calling script again: call it under ``if __name__ == "__main__":`` (at a script's top level it fails at once,
    one line, pbdyn.experiments.mainguard)."""
    from pbdyn.experiments.mainguard import check_not_reimported

    check_not_reimported("run_batch")
    from pbdyn.experiments.runner import BatchOptions
    from pbdyn.experiments.runner import run_batch as batch

    sc = load_scenario(scenario)
    out = _path(out, "out")
    opts = BatchOptions(workers=workers, scheduler=scheduler, limit=limit, extend=extend, metrics=metrics,
                        progress=progress, rerun_changed=rerun_changed, retry_errors=retry_errors, shard=shard)
    if lockstep is not None:
        opts = dataclasses.replace(opts, lockstep=lockstep)
    return batch(sc, out, opts, command=command)


def replay(trace: str | Path, out: str | Path, *, fps: float | None = None, every: int = 1):
    """`pbdyn replay`: draw a trace (run_trial(..., trace=...)) into ``out`` -- .gif or .mp4 (one frame every
    ``every`` steps and the final state, at ``fps``, default real time) or .png (the final state). Returns a
    ReplaySummary (path, frames, width, height in px)."""
    from pbdyn.analysis.replay import write_replay

    return write_replay(_path(trace, "trace"), _path(out, "out"), fps=fps, every=every)


def generate_maps(out: str | Path | None, *, metric: str | None = None, target: float | None = None,
                  tolerance: float, success: float | None = None, count: int = 20,
                  family: str = "uniform", dims: int = 2, scenario=None, fixed: Mapping | None = None,
                  seed: int = 0, workers: int | None = None, progress: bool = False):
    """`pbdyn generate --metric`: ``count`` maps of generator ``family`` (a built-in structure) in ``dims`` D whose
    measured ``metric`` lies within ``tolerance`` of ``target`` (thesis 5-2-2; pbdyn.experiments.generate), written
    to ``out`` (a scenario .toml whose maps 0..count-1 are the found maps; None: not written). ``scenario``: the
    base whose world, MAV, sensor, task and planners the file takes (a path, bundled name or dict shaped like the
    TOML file; default pbdyn's defaults, 50 m arena); ``fixed``: setup values held fixed, e.g. {"count": 10};
    ``seed``: the file's obstacles.root_seed and the search's seed. ``success`` instead of metric/target: maps whose
    reference success flown by the reference panel lies within ``tolerance`` of it (the predictor proposes,
    pbdyn.experiments.generate.generate_by_success). Returns a GeneratedMaps (maps, document, candidates,
    reachable, coefficients, wall_time_s, flown). Unreachable targets raise ConfigError naming the range."""
    from pbdyn.experiments.mainguard import check_not_reimported

    check_not_reimported("generate_maps")
    import tomllib

    from pbdyn.errors import check_writable_file
    from pbdyn.experiments.generate import (PREDICTED, MetricTarget, generate_by_metric, generate_by_success,
                                            stop_on_signals_cleanly, write_scenario)

    if success is not None:
        if metric is not None or target is not None:
            raise ConfigError("success", "cannot be combined with metric/target (two targets)", success)
    elif metric is None or target is None:
        raise ConfigError("metric" if metric is None else "target", "is required (or give success)", None,
                          show_value=False)

    if out is not None:
        out = _path(out, "out")
        if Path(out).suffix.lower() != ".toml":
            raise ConfigError("out", "must name a .toml scenario file", str(out))
        check_writable_file("out", out, make_parents=True)
    base: dict = {}
    if scenario is not None:
        if isinstance(scenario, Mapping):
            base = dict(scenario)
        elif isinstance(scenario, (str, os.PathLike)):
            from pbdyn import resources

            sc = load_scenario(scenario)           # validates it first
            base = tomllib.loads(resources.find_scenario(scenario).read_text(encoding="utf-8"))
            if sc.is_world:
                raise ConfigError("scenario", "is an imported world; generate needs a scenario with generated "
                                  "obstacles", str(scenario))
        else:
            raise ConfigError("scenario", "must be a path, a bundled scenario name or a dict", scenario)
        base.pop("name", None)
    _check_fixed(base, fixed, dims)
    workers = _workers(workers)
    with stop_on_signals_cleanly(out):        # SIGTERM/SIGINT: workers ended, nothing written, BatchInterrupted
        if success is not None:
            req = MetricTarget(PREDICTED, success, tolerance, count, family, dims, base, dict(fixed or {}), seed=seed)
            result = generate_by_success(req, workers=workers, progress=progress)
            what = f"reference success (flown by the reference panel) within {tolerance:g} of {success:g}"
        else:
            req = MetricTarget(metric, target, tolerance, count, family, dims, base, dict(fixed or {}), seed=seed)
            result = generate_by_metric(req, workers=workers, progress=progress)
            what = f"{metric} within {tolerance:g} of {target:g}"
        if out is not None:
            header = (f"pbdyn generate: {len(result.maps)} maps of family {family!r} ({dims}D) with {what}\n(map i "
                      "of this file is the i-th [[obstacles.maps]] entry; measured values as found when it was chosen)")
            write_scenario(out, result.document, header)
    return result


def _check_fixed(base: dict, fixed, dims) -> None:
    """ConfigError naming ``fixed.<key>`` if a held setup value cannot make a scenario on ``base`` (too many
    obstacles, a radius that does not fit the arena, a number beyond pbdyn.limits), before any map is measured."""
    import copy

    from pbdyn.experiments.generate import BOX

    if not isinstance(fixed, Mapping):
        return                      # generate's own check names a fixed that is not a table
    for key in [k for k in ("count", "radius", "speed") if k in fixed]:
        values = {k: BOX[k][0] for k in BOX} | {key: fixed[key]}
        doc = copy.deepcopy(base)
        if dims == 3:
            doc.setdefault("world", {})["dims"] = 3
        obst = {k: v for k, v in doc.get("obstacles", {}).items()
                if k not in ("count", "radius", "speed", "maps_per_setup", "structure", "maps")}
        doc["obstacles"] = obst | values
        try:
            sc = parse_scenario(doc)
        except ConfigError as exc:
            if exc.field.startswith("obstacles."):
                raise ConfigError(f"fixed.{key}", exc.problem, fixed[key]) from None
            raise
        if key == "speed" and fixed[key] * sc.world.dt > max(sc.world.size):
            raise ConfigError("fixed.speed", f"would carry an obstacle across the whole arena ({max(sc.world.size):g} "
                              f"m) in one step of {sc.world.dt:g} s", fixed[key])


def calibrate(scenario, *, maps=None, store: str | Path | None = None, workers: int | None = None,
              progress: bool = False):
    """`pbdyn calibrate`: fly the reference panel on the scenario's maps (all, or the indices ``maps``) into the
    results store ``store`` (default: one in the cache, keyed by what is flown; resumable) and return each map's
    measured difficulty on the anchored scale (pbdyn.analysis.scale.MapDifficulty: reference success with a
    95% interval, difficulty in logits with its interval and percentile among the calibration maps)."""
    from pbdyn.experiments.mainguard import check_not_reimported

    check_not_reimported("calibrate")
    from pbdyn.experiments.calibrate import calibrate as _calibrate

    if maps is not None:
        maps = [maps] if isinstance(maps, int) and not isinstance(maps, bool) else maps
        if not isinstance(maps, (list, tuple, range)) or not maps:
            raise ConfigError("maps", "must be a map index or a non-empty list of them", maps)
    if store is not None:
        from pbdyn.experiments.store import check_store_path

        store = check_store_path(_path(store, "store"), "store")
    return _calibrate(scenario, maps=None if maps is None else list(maps), store=store, workers=_workers(workers),
                      progress=progress)


def bench(planner: str, *, gaze: str | None = None, params: Mapping | None = None,
          gaze_params: Mapping | None = None, suite: str | Path = "pbdyn-2d-v2", out: str | Path,
          workers: int | None = None, scheduler=None, progress: bool = False, reproduce: bool = False,
          rerun_changed: bool = False, failures: int | None = None, failures_format: str | None = None,
          command: str = "") -> dict:
    """`pbdyn bench`: fly ``planner`` (a registry name or "package.module:Class"; gaze: default the thesis pairing)
    on the frozen ``suite`` (a bundled suite name or a suite folder) into the folder ``out`` (resumable) and write its
    score card there (card.json, card.md, card.html; docs/benchmark.md). Returns the card (a dict, schema
    pbdyn-card/2). ``params``: the trajectory planner's parameters (its trajectory_params table, e.g. a policy for
    pbdyn.gym.policy_planner, docs/gym.md); ``gaze_params``: the gaze planner's (its gaze_params table).
    ``reproduce``: also compare the flights with the planner's shipped reference results. ``rerun_changed``: re-fly
    the flights in ``out`` whose planner code or world changed. ``failures``: K, also write replays of up to K failed
    tasks per failure mode into out/failures/ (``failures_format``: "gif", the default, or "mp4")."""
    from pbdyn.experiments.mainguard import check_not_reimported

    check_not_reimported("bench")
    from pbdyn.benchmark.run import bench as _bench

    if scheduler is None:
        workers = _workers(workers)
    return _bench(planner, gaze=gaze, params=params, gaze_params=gaze_params, suite=suite, out=_path(out, "out"),
                  workers=workers, scheduler=scheduler, progress=progress, reproduce=reproduce,
                  rerun_changed=rerun_changed, failures=failures, failures_format=failures_format, command=command)


def compare_cards(cards, *, out: str | Path | None = None) -> list[dict]:
    """`pbdyn bench --compare`: read score cards (card.json files or bench folders) of one suite; with ``out`` (a
    folder), write compare.md and compare.html there. Returns the cards. Cards of different suite versions are
    refused (their numbers are not comparable)."""
    from pbdyn.benchmark.render import compare_html, compare_markdown
    from pbdyn.benchmark.run import read_card
    from pbdyn.files import atomic_write_text

    if isinstance(cards, (str, Path)) or not cards:
        raise ConfigError("card", "give one or more card files", cards)
    docs = [read_card(c) for c in cards]
    first = docs[0]["suite"]
    for c, d in zip(cards, docs):
        if d["suite"]["hash"] != first["hash"]:
            raise ConfigError("card", f"is a card of {d['suite']['name']} ({d['suite']['hash'][:12]}), not of "
                              f"{first['name']} ({first['hash'][:12]}): cards of different suites are not comparable",
                              str(c))
    if out is not None:
        from pbdyn.errors import check_writable_folder

        folder = check_writable_folder("out", _path(out, "out"))
        folder.mkdir(parents=True, exist_ok=True)
        atomic_write_text(folder / "compare.md", compare_markdown(docs))
        atomic_write_text(folder / "compare.html", compare_html(docs))
    return docs


def _workers(workers) -> int:
    """``workers`` (None: the CPU count) as an int >= 1; ConfigError naming it otherwise."""
    if workers is None:
        return max(1, os.cpu_count() or 1)
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ConfigError("workers", "must be an integer >= 1", workers)
    from pbdyn.experiments.runner import BatchOptions, _checked_options

    _checked_options(BatchOptions(workers=workers))       # at most MAX_WORKERS_PER_CPU x the CPU count
    return workers


def merge_results(out: str | Path, inputs):
    """Join results stores of one experiment (e.g. the shards of run_batch(..., shard="I/N")) into ``out``; trials
    held by several inputs are stored once. Returns a MergeSummary (trials, added, duplicates, conflicts, maps)."""
    from pbdyn.experiments.merge import merge_stores
    from pbdyn.experiments.signals import merge_signals

    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    elif isinstance(inputs, (bytes, Mapping)) or not hasattr(inputs, "__iter__"):
        raise ConfigError("inputs", "must be a path or a list of paths of results stores", inputs)
    with merge_signals(out):        # SIGTERM/SIGINT while the inputs are checked, too: one line, nothing written
        return merge_stores(_path(out, "out"), [_path(p, "inputs") for p in inputs])


class Results:
    """A read-only results store: ``trials()`` (one row per trial, map metrics joined as metric_<name>, start and
    goal as start_x/start_y[/start_z] and goal_x/...), ``maps()`` (one row per map), ``scenario`` (the resolved
    scenario the store was made with, a dict) and ``count``."""

    def __init__(self, store):
        self._store = store

    def trials(self):
        """Every trial as a pandas DataFrame, Table 2-2 columns first."""
        from pbdyn.experiments.export import trials_frame

        return trials_frame(self._store)

    def maps(self):
        """Every map with its setup, seed and metrics as a pandas DataFrame (index: map_id)."""
        import pandas as pd

        rows = []
        for map_id, m in self._store.maps().items():
            row = {"map_id": map_id, "map_index": m["map_index"], "seed": m["seed"], "dataset": m["dataset"],
                   "mean_obstacle_speed": m["mean_obstacle_speed"], "mean_obstacle_radius": m["mean_obstacle_radius"],
                   "backend": m["backend"]}
            row.update({f"setup_{k}": v for k, v in m["setup"].items()})
            row.update({f"metric_{k}": v for k, v in m["metrics"].items()})
            rows.append(row)
        return pd.DataFrame(rows).set_index("map_id") if rows else pd.DataFrame()

    @property
    def scenario(self) -> dict:
        """The resolved scenario stored with the results."""
        import json

        text = self._store.get_meta("scenario")
        return json.loads(text) if text else {}

    @property
    def count(self) -> int:
        """Number of stored trials."""
        return self._store.count()


@contextlib.contextmanager
def open_results(path: str | Path) -> Iterator[Results]:
    """Open a results store read-only for the ``with`` block: ``with open_results(p) as r: df = r.trials()``."""
    from pbdyn.experiments.store import ResultsStore

    store = ResultsStore.open(_path(path, "path"))
    try:
        yield Results(store)
    finally:
        store.close()


def check_planner(planner, scenario="quickstart", *, maps=3, pairs: int = 4, gaze: str | None = None,
                  v_max: float | None = None) -> PlannerCheck:
    """Fly ``planner`` (a name, "package.module:Class", a class or an instance) on a few maps of ``scenario`` and
    report every plan that broke the plan contract (``report.ok``, ``print(report)``): the analogue of Gymnasium's
    check_env for trajectory planners. maps: the first N maps or a list of indices; pairs: start/goal pairs per
    map; gaze: the gaze planner (default: the scenario's first entry's); v_max: the MAV speed (m/s)."""
    from pbdyn.sim.checker import check_planner as check

    if not isinstance(planner, str):
        _planner_name(planner, "planner")
    return check(planner, load_scenario(scenario), maps=maps, pairs=pairs, gaze=gaze, v_max=v_max)


def export_results(results: str | Path, path: str | Path, *, format: str | None = None) -> int:
    """Write a store's trials (the table of Results.trials()) to ``path`` as CSV or Parquet (format "csv" or
    "parquet"; default: from the suffix); written atomically with the user's umask. Returns the row count."""
    from pbdyn.experiments.export import export_csv, export_parquet
    from pbdyn.experiments.store import ResultsStore

    results, path = _path(results, "results"), _path(path, "path")
    fmt = format or Path(path).suffix.lstrip(".").lower()
    if fmt not in ("csv", "parquet"):
        raise ConfigError("format", 'must be "csv" or "parquet" (or a path ending in .csv / .parquet)', format or str(path))
    from pbdyn.errors import check_writable_file

    check_writable_file(fmt, path, make_parents=True)
    store = ResultsStore.open(results)
    try:
        return export_csv(store, path) if fmt == "csv" else export_parquet(store, path)
    finally:
        store.close()


def evaluate(results, *, plots: str | Path | None = None, n_boot: int = 1000, pool: bool = False,
             html: str | Path | None = None):
    """How well each metric ranks maps like the planners' success (thesis table 4-5) for one or more stores (the
    first is the reference set; ``pool``: all stores' maps as one dataset, e.g. generated maps and imported worlds
    together): (report dict, text table, written figure paths). ``html``: also write one self-contained HTML page
    of the report with its figures inlined (pbdyn.analysis.html_report). The flight stores of `pbdyn bench`
    (<out>/flights/<part>.sqlite) get their suite's levels (success per level in the report)."""
    import tempfile

    from pbdyn.errors import check_writable_file, check_writable_folder
    from pbdyn.experiments.evaluate import evaluate_stores

    if isinstance(results, (str, os.PathLike)):
        paths = [_path(results, "results")]
    elif isinstance(results, (list, tuple)) and results:
        paths = [_path(r, "results") for r in results]
    else:
        raise ConfigError("results", "must be a results store's path or a non-empty list of them", results)
    if plots is not None:
        check_writable_folder("plots", plots)
    if html is not None:
        if Path(html).suffix.lower() not in (".html", ".htm"):
            raise ConfigError("html", "must name an .html file", str(html))
        check_writable_file("html", html, make_parents=True)
    with tempfile.TemporaryDirectory(prefix="pbdyn-figures-") as tmp:
        figure_dir = tmp if plots is None and html is not None else plots   # the page needs figures to inline
        from pbdyn.benchmark.suite import flight_levels

        report, table, figures = evaluate_stores([str(p) for p in paths], plots=figure_dir, n_boot=n_boot, pool=pool,
                                                 levels=flight_levels(paths))
        if html is not None:
            from pbdyn import __version__
            from pbdyn.analysis.html_report import render_html, write_html

            with open_results(paths[0]) as res:
                scenario = res.scenario
            page = render_html(report, table, figures, stores=[str(p) for p in paths], scenario=scenario,
                               version=__version__)
            write_html(html, page)
    return report, table, figures if plots is not None else []


def run_demo(scenario, *, n_maps: int = 4, n_pairs: int = 3, json_out: bool = False) -> list[dict]:
    """Fly every planner pair of ``scenario`` over a few maps and start/goal pairs; prints a table (stdout, or
    stderr with json_out) and returns the rows."""
    from pbdyn.sim.demo import run_demo as demo

    return demo(load_scenario(scenario), n_maps=n_maps, n_pairs=n_pairs, json_out=json_out)
