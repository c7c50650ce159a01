"""Metric names -> functions, and one entry point that validates a metric's name and parameters."""

from __future__ import annotations

import inspect
from typing import Callable

from pbdyn.errors import ConfigError
from pbdyn.metrics.density import density
from pbdyn.metrics.result import MetricResult
from pbdyn.metrics.survivability import global_survivability, survivability, survivability_dense
from pbdyn.metrics.traversability import dynamic_traversability, traversability, traversability_dense
from pbdyn.metrics.vo import vo_feasibility, vo_feasibility_dense

METRICS: dict[str, Callable[..., MetricResult]] = {
    "density": density,
    "traversability": traversability,
    "traversability_dense": traversability_dense,
    "dynamic_traversability": dynamic_traversability,
    "vo_feasibility": vo_feasibility,
    "vo_feasibility_dense": vo_feasibility_dense,
    "survivability": survivability,
    "survivability_dense": survivability_dense,
    "global_survivability": global_survivability,
}

_INTERNAL = ("name",)  # keywords the sparse functions use to label their dense variants; not user parameters


def parameters(name: str) -> tuple[str, ...]:
    """The keyword parameters metric ``name`` accepts; ConfigError for an unknown name."""
    fn = METRICS.get(name)
    if fn is None:
        raise ConfigError("--metric", f"unknown metric (known: {', '.join(sorted(METRICS))})", name)
    return tuple(p.name for p in inspect.signature(fn).parameters.values()
                 if p.kind is inspect.Parameter.KEYWORD_ONLY and p.name not in _INTERNAL)


def compute(rollout, name: str, **params) -> MetricResult:
    """Metric ``name`` of a rollout with the given keyword parameters (every other one at its default).

    ConfigError naming "--metric" for an unknown metric or parameter; the metric's own ConfigError / HorizonError
    for bad values (e.g. "--backend" for an unknown survivability backend).
    """
    allowed = parameters(name)
    for key in params:
        if key not in allowed:
            raise ConfigError("--metric", f"{name} has no parameter {key!r} (allowed: {', '.join(allowed)})", key)
    return METRICS[name](rollout, **params)
