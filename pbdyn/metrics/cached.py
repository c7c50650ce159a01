"""Metric values for a scenario's map, cached on disk per rollout hash (``pbdyn metrics``)."""

from __future__ import annotations

import hashlib
import json
import time

from pbdyn.config import Scenario, canonical_json
from pbdyn.errors import ConfigError
from pbdyn.files import atomic_write_text
from pbdyn.metrics.backends import BACKENDS
from pbdyn.metrics.catalog import BACKEND_METRICS, DENSE, INFO, METRIC_TABLE, NAMES, SPARSE
from pbdyn.world.maps import MapSpec
from pbdyn.world.rollout import cache_dir, default_horizon, get_rollout, rollout_key

def metric_code(name: str, backend: str | None = None) -> str:
    """The identity of the code that computes metric ``name`` with ``backend`` (pbdyn.codeid; docs/design.md "Code
    identity"): its module and its backend's, with the pbdyn modules they use. Part of every cached value's key, so
    the cache never serves a value computed by other code (and serves the old values again after a revert)."""
    from pbdyn import codeid

    own = BACKENDS[backend].times.__module__ if backend else None
    return codeid.identity((INFO[name].module,) + ((own,) if own else ()),
                           tuple(b.times.__module__ for b in BACKENDS.values() if b.times.__module__ != own))


def metrics_code(names, backend: str | None) -> str:
    """One identity for the code behind a set of metric values computed with ``backend`` (metric_code of each
    name, in one digest): recorded with a map's metrics in a results store (maps.metrics_code)."""
    h = hashlib.sha256()
    for name in sorted(names):
        h.update(f"{name}={metric_code(name, backend if name in BACKEND_METRICS else None)}\n".encode())
    return h.hexdigest()[:16]


def metric_names(requested: list[str] | None, dense: bool) -> list[str]:
    """The metrics to compute: the requested names (default: every sparse metric), swapped for their dense variant
    with ``dense``; unknown names raise ConfigError naming --metric."""
    names = list(requested) if requested else list(SPARSE)
    out = []
    for name in names:
        if name not in NAMES:
            raise ConfigError("metric", f"unknown metric (known: {', '.join(sorted(NAMES))})", name)
        name = DENSE.get(name, name) if dense else name
        if name not in out:
            out.append(name)
    return out


def resolve_backend(scenario: Scenario, backend: str) -> str:
    """The survivability backend for ``backend`` ("auto": bullet for an imported world with moving bodies, whose
    real shapes it queries, else analytic); ConfigError naming --backend for an unknown name."""
    if backend == "auto":
        return "bullet" if any(b.moving for b in scenario.bodies) else "analytic"
    if backend not in BACKENDS:
        raise ConfigError("backend", f"unknown backend (known: auto, {', '.join(BACKENDS)})", backend)
    if BACKENDS[backend].imported_only and not scenario.is_world:
        raise ConfigError("backend", f"the {backend} backend works on imported worlds ([[bodies]]); generated "
                          "obstacles are discs/balls: use analytic or bullet", backend)
    return backend


PROFILE_METRIC_PARAMS: dict[str, dict[str, dict]] = {
    "physical": {},
    "thesis_program": {
        **{m.name: {"mav_radius": 0.5} for m in METRIC_TABLE if m.module.endswith(".vo")},
        **{m.name: {"mode": "grid", "marking": "program"} for m in METRIC_TABLE if m.module.endswith(".traversability")},
    },
}
"""Per profile and metric, parameters that replace the scenario-derived ones. thesis_program: the thesis' program
computed VO feasibility with an MAV radius of 0.5 m, and (dynamic) traversability by walking grid cells with the
MAV's centre, cells marked by its own rules (pbdyn.metrics.traversability, marking "program"; docs/profiles.md "Profiles"),
from the scenario's start/goal candidates (PROGRAM_CANDIDATE_METRICS; the program walked from its 9 candidate cells,
which the thesis scenarios' 48 m arena puts at 3, 24, 45 m, not at the arena-derived 4, L/2, L - 4)."""

PROGRAM_CANDIDATE_METRICS = tuple(m.name for m in METRIC_TABLE
                                  if m.module.endswith(".traversability") and m.sparse is None)
"""Metrics whose starts are the scenario's candidates under the thesis_program profile (the traversability metrics
that start from the candidates; their dense variants use a sample grid)."""


def metric_params(scenario: Scenario, name: str, backend: str) -> dict:
    """The parameters a scenario's map metric runs with: the scenario's MAV radius, and the (resolved) backend for
    the survivability-type metrics, then the profile's replacements (PROFILE_METRIC_PARAMS); every other parameter
    at its default."""
    params = {"mav_radius": scenario.drone.radius, **PROFILE_METRIC_PARAMS[scenario.profile].get(name, {})}
    if scenario.profile == "thesis_program" and name in PROGRAM_CANDIDATE_METRICS and not scenario.is_world:
        params["starts"] = [list(c) for c in scenario.task.candidates]
    if name in BACKEND_METRICS:
        params["backend"] = backend
    return params


def run_metric(scenario: Scenario, rollout, name: str, backend: str = "auto"):
    """Metric ``name`` (a MetricResult) of ``rollout``, a map of ``scenario``, as every caller computes a map's
    metric (`pbdyn metrics`, the batch, generate, the predictor's features, the heat maps): with metric_params for
    the scenario's resolved ``backend`` (resolve_backend)."""
    from pbdyn.metrics.registry import compute

    return compute(rollout, name, **metric_params(scenario, name, resolve_backend(scenario, backend)))


def map_metrics(scenario: Scenario, spec: MapSpec, names: list[str], *, backend: str = "analytic",
                use_cache: bool = True) -> dict[str, dict]:
    """Compute (or read from the cache) each named metric of one map; returns name -> MetricResult.to_dict()
    (plus "cached": bool). Survivability-type metrics use ``backend``; the MAV radius is the scenario's."""
    backend = resolve_backend(scenario, backend)
    horizon = default_horizon(scenario)
    rollout = get_rollout(scenario, spec, horizon)
    key = rollout_key(scenario, spec, horizon)
    out = {}
    for name in names:
        params = metric_params(scenario, name, backend)
        code = metric_code(name, params.get("backend"))
        tag = hashlib.sha256(canonical_json({"v": code, "name": name, "params": params}).encode())
        path = cache_dir() / "metrics" / key / f"{name}-{tag.hexdigest()[:16]}.json"
        if use_cache and path.is_file():
            try:
                doc = json.loads(path.read_text())
                doc["cached"] = True
                out[name] = doc
                continue
            except (OSError, ValueError):
                path.unlink(missing_ok=True)
        t0 = time.perf_counter()
        result = run_metric(scenario, rollout, name, backend)
        doc = result.to_dict()
        doc["wall_time_s"] = time.perf_counter() - t0
        if use_cache:
            try:
                atomic_write_text(path, json.dumps(doc, sort_keys=True), make_parents=True)
            except OSError:
                pass
        doc["cached"] = False
        out[name] = doc
    return out
