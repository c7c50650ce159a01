"""The survivability backends by name: a metric's ``backend`` -> how static MAVs' survival times are found (thesis
eq. 3-6, 3-7; docs/difficulty-metrics.md "Backends").

BACKENDS is the one table of backends: the survivability, task and route metrics take their kernels from it,
pbdyn.metrics.cached resolves a scenario's ``backend`` against it and gives a value the code identity of its
backend's module and no other's. Adding a backend: its module in pbdyn/metrics/ and one entry below.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from pbdyn.errors import ConfigError
from pbdyn.metrics import analytic, bullet_backend, mesh_backend


class Backend(NamedTuple):
    """times(rollout, points [n, d] (m, world frame), *, mav_radius (m), t_max (s), start_time (s)[, mode]) -> the
    survival time [n] (s from start_time, <= t_max) of a static MAV at each point, ``mode`` given if modes has
    several; table: the same for start times [S] (s) at once -> [S, n] (s), or None (times per start); modes: the
    survival modes it computes (pbdyn.metrics.analytic); imported_only: it needs an imported world."""

    times: Callable[..., np.ndarray]
    table: Callable[..., np.ndarray] | None = None
    modes: tuple[str, ...] = ("sampled",)
    imported_only: bool = False


BACKENDS: dict[str, Backend] = {
    "analytic": Backend(analytic.survival_times, modes=analytic.MODES),
    "bullet": Backend(bullet_backend.survival_times_bullet, bullet_backend.survival_table_bullet),
    "mesh": Backend(mesh_backend.survival_times_mesh, imported_only=True),
}
"""name -> backend, in the order error messages list them."""


def kernel(backend: str, mode: str) -> Callable[..., np.ndarray]:
    """times(rollout, points, **kw) of ``backend`` in survival ``mode``; ConfigError naming "backend" or "mode"."""
    if backend not in BACKENDS:
        raise ConfigError("backend", f"unknown backend (known: {', '.join(BACKENDS)})", backend)
    if mode not in analytic.MODES:
        raise ConfigError("mode", f"must be one of {', '.join(analytic.MODES)}", mode)
    entry = BACKENDS[backend]
    if mode not in entry.modes:
        raise ConfigError("backend", f'the {backend} backend supports mode "sampled" only (got mode "{mode}")',
                          backend)
    return functools.partial(entry.times, mode=mode) if len(entry.modes) > 1 else entry.times


def table_kernel(backend: str, mode: str) -> Callable[..., np.ndarray]:
    """table(rollout, points, start_times, **kw) -> [S, n] (s) of ``backend``: its own (the bullet backend keeps one
    client for every start), else its kernel per start."""
    single, own = kernel(backend, mode), BACKENDS[backend].table
    return own or (lambda ro, pts, starts, **kw: np.stack(
        [np.asarray(single(ro, pts, start_time=s, **kw), dtype=float) for s in starts]).reshape(len(starts), -1))
