"""Metric names -> functions (from the one table, pbdyn.metrics.catalog), and one entry point that validates a
metric's name and parameters."""

from __future__ import annotations

import importlib
import inspect
from typing import Callable

from pbdyn.errors import ConfigError
from pbdyn.metrics.catalog import INFO, METRIC_TABLE, MetricInfo  # noqa: F401  (re-exported)
from pbdyn.metrics.result import MetricResult

METRICS: dict[str, Callable[..., MetricResult]] = {
    m.name: getattr(importlib.import_module(m.module), m.name) for m in METRIC_TABLE}
"""Name -> function ``f(rollout, **params) -> MetricResult``, in METRIC_TABLE order."""

_INTERNAL = ("name",)  # keywords the sparse functions use to label their dense variants; not user parameters


def parameters(name: str) -> tuple[str, ...]:
    """The keyword parameters metric ``name`` accepts; ConfigError for an unknown name."""
    fn = METRICS.get(name)
    if fn is None:
        raise ConfigError("metric", f"unknown metric (known: {', '.join(sorted(METRICS))})", name)
    return tuple(p.name for p in inspect.signature(fn).parameters.values()
                 if p.kind is inspect.Parameter.KEYWORD_ONLY and p.name not in _INTERNAL)


def compute(rollout, name: str, **params) -> MetricResult:
    """Metric ``name`` of a rollout with the given keyword parameters (every other one at its default).

    ConfigError naming "metric" for an unknown metric or parameter; the metric's own ConfigError / HorizonError
    for bad values (e.g. "backend" for an unknown survivability backend).
    """
    allowed = parameters(name)
    for key in params:
        if key not in allowed:
            raise ConfigError("metric", f"{name} has no parameter {key!r} (allowed: {', '.join(allowed)})", key)
    return METRICS[name](rollout, **params)
