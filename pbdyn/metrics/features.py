"""The features of the reference-success predictor (pbdyn.analysis.predict; docs/difficulty-scale.md): pbdyn map
metrics (thesis ch. 3) and task metrics along the static-free routes of a map's reference tasks
(pbdyn.metrics.route), some on a log scale.

FEATURE_TABLE: one row per feature -- its name, the metric it is read from (a map metric of pbdyn.metrics.catalog,
or a route metric), and whether its log is taken (flux and density, floored at LOG_FLOOR first: a map without
movers has flux 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pbdyn.metrics.catalog import NAMES

LOG_FLOOR = 1e-4
"""Flux and density below this are taken as this before the log."""
ROUTE_HORIZON_S = 12.0
"""The route metrics' horizon t_max (s; pbdyn.metrics.route.route_metrics' default)."""


@dataclass(frozen=True)
class Feature:
    """A predictor feature: ``name``, the ``metric`` it is read from, ``route`` (a route metric, not a map metric)
    and ``log`` (its natural log is the feature)."""

    name: str
    metric: str
    route: bool = False
    log: bool = False


FEATURE_TABLE = (
    Feature("survivability", "survivability"),
    Feature("log_flux", "flux", log=True),
    Feature("log_density", "density", log=True),
    Feature("static_share", "static_share"),
    Feature("route_detour", "route_detour", route=True),
    Feature("route_survivability", "route_survivability", route=True),
    Feature("log_route_flux", "route_flux", route=True, log=True),
)
FEATURES = tuple(f.name for f in FEATURE_TABLE)
"""Every feature the predictor may use."""
MAP_METRICS = tuple(dict.fromkeys(f.metric for f in FEATURE_TABLE if not f.route))
"""The map metrics behind FEATURES."""
assert set(MAP_METRICS) <= set(NAMES)


def features_from(metrics: dict, route: dict) -> dict[str, float]:
    """FEATURES from map metric values (name -> value, {"value": ...} or a MetricResult) and route metric values
    (the same)."""
    def val(d, k):
        v = d[k]
        return float(v["value"] if isinstance(v, dict) else getattr(v, "value", v))

    out = {}
    for f in FEATURE_TABLE:
        x = val(route if f.route else metrics, f.metric)
        out[f.name] = math.log(max(x, LOG_FLOOR)) if f.log else x
    return out


def route_features(scenario, rollout, pairs, backend: str = "analytic") -> dict:
    """The route metrics (pbdyn.metrics.route.route_metrics) of one map's rollout over the tasks ``pairs``
    (ordered (start, goal) indices into the scenario's start/goal candidates; the predictor uses the reference
    tasks, pbdyn.analysis.scale.reference_pairs), the scenario's MAV radius, over ROUTE_HORIZON_S."""
    from pbdyn.metrics.route import route_metrics

    return route_metrics(rollout, starts=np.asarray(scenario.task.candidates, float), pairs=pairs,
                         mav_radius=scenario.drone.radius, t_max=ROUTE_HORIZON_S,
                         backend="bullet" if backend == "bullet" else "analytic")


def map_features(scenario, map_index: int, pairs, *, backend: str = "analytic") -> dict[str, float]:
    """FEATURES of map ``map_index`` of ``scenario`` (a Scenario): the map metrics through the metric cache (as
    `pbdyn metrics` computes them; survivability with ``backend``, already resolved) and the route metrics over
    ``pairs`` (route_features)."""
    from pbdyn.metrics.cached import map_metrics
    from pbdyn.world.maps import enumerate_maps
    from pbdyn.world.rollout import default_horizon, get_rollout

    spec = enumerate_maps(scenario)[map_index]
    metrics = map_metrics(scenario, spec, list(MAP_METRICS), backend=backend)
    rollout = get_rollout(scenario, spec, default_horizon(scenario))
    return features_from(metrics, route_features(scenario, rollout, pairs, backend))


def rollout_features(scenario, rollout, pairs, backend: str = "analytic") -> dict[str, float]:
    """FEATURES of one map from its ``rollout`` (long enough for the metrics' horizons), without the cache (pbdyn
    generate's candidates): the map metrics as pbdyn.metrics.cached computes them, then the route metrics."""
    from pbdyn.metrics.cached import run_metric

    metrics = {m: run_metric(scenario, rollout, m, backend).value for m in MAP_METRICS}
    return features_from(metrics, route_features(scenario, rollout, pairs, backend))
