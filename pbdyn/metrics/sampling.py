"""Sample grids shared by the metrics (docs/thesis-program.md "Metrics as computed for the thesis' tables")."""

from __future__ import annotations

import itertools

import numpy as np

from pbdyn import limits
from pbdyn.errors import HorizonError, check_positive
from pbdyn.world.geometry import StaticBody


def axis_samples(length: float, spacing: float, margin: float = 2.0, first: float | None = None) -> np.ndarray:
    """Points first + k * spacing (first defaults to margin) for k >= 0 while <= length - margin (m)."""
    start = margin if first is None else first
    n = (length - margin - start) / spacing + 1e-9
    limits.check_limit("spacing", "sample points per axis", n, limits.MAX_METRIC_SAMPLES, spacing)
    n = int(np.floor(n)) + 1
    return start + spacing * np.arange(max(n, 0))


def grid_samples(size, spacing: float, margin: float = 2.0, first: float | None = None,
                 offset=None) -> np.ndarray:
    """All grid points [n, d] of axis_samples on every axis of an arena of extents ``size`` (rows in
    itertools.product order: x slowest, the last axis fastest); ``offset`` [d] shifts the whole grid (jittered
    grids). ConfigError naming ``spacing`` above limits.MAX_METRIC_SAMPLES points."""
    axes = [axis_samples(float(L), spacing, margin, first) for L in size]
    limits.check_limit("spacing", "sample points (the arena's extents / spacing, per axis)",
                       float(np.prod([float(a.shape[0]) for a in axes])), limits.MAX_METRIC_SAMPLES, spacing)
    pts = np.array(list(itertools.product(*axes)), dtype=float).reshape(-1, len(axes))
    if offset is not None:
        pts = pts + np.asarray(offset, dtype=float)[None, :]
    return pts


def outside_static(points: np.ndarray, static: tuple[StaticBody, ...], radius: float) -> np.ndarray:
    """True for points [n, d] whose MAV ball/disc of ``radius`` (m) does not overlap any static body."""
    ok = np.ones(points.shape[0], dtype=bool)
    for body in static:
        ok &= body.footprint_distance(points) >= radius
    return ok


def plane_points(rollout, points: np.ndarray) -> np.ndarray:
    """Points [n, d] as world points [n, 3]: 2D points go to the flight plane z = h (imported worlds' h, else 2 m)."""
    pts = np.asarray(points, dtype=float).reshape(-1, rollout.dims)
    if rollout.dims == 3:
        return pts
    h = float(rollout.meta.get("flight_height", 2.0)) if isinstance(rollout.meta, dict) else 2.0
    return np.concatenate([pts, np.full((pts.shape[0], 1), h)], axis=1)


def outside_geometry(rollout, points: np.ndarray, radius: float) -> np.ndarray:
    """outside_static for a rollout: also False where the MAV of ``radius`` (m) overlaps an imported world's static
    body (its real shape at t = 0)."""
    ok = outside_static(points, rollout.static, radius)
    bodies = getattr(rollout, "bodies", None)
    if bodies is not None and points.shape[0] and not bodies.moving.all():
        ok &= bodies.field().distance(plane_points(rollout, points), 0, "static") >= radius
    return ok


def step_window(rollout, start_time: float, t_max: float) -> tuple[int, int]:
    """(k0, K): the rollout step of ``start_time`` and the number of steps floor(t_max / dt) after it (the rule of
    every survivability backend); ConfigError for t_max <= 0, HorizonError past the rollout's horizon."""
    t_max = check_positive("t_max", t_max)
    k0 = rollout.step_index(float(start_time))
    n = int(np.floor(float(t_max) / rollout.dt + 1e-9))
    if k0 + n >= rollout.n_steps:
        raise HorizonError(f"survivability needs the obstacles until t = {float(start_time) + float(t_max):.3f} s, "
                           f"past the rollout's horizon {rollout.horizon:.3f} s")
    return k0, n
