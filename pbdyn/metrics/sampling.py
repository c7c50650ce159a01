"""Sample grids shared by the metrics (implementation-facts.md "Metrics as computed for the thesis' tables")."""

from __future__ import annotations

import itertools

import numpy as np

from pbdyn.world.geometry import StaticBody


def axis_samples(length: float, spacing: float, margin: float = 2.0, first: float | None = None) -> np.ndarray:
    """Points first + k * spacing (first defaults to margin) for k >= 0 while <= length - margin (m)."""
    start = margin if first is None else first
    n = int(np.floor((length - margin - start) / spacing + 1e-9)) + 1
    return start + spacing * np.arange(max(n, 0))


def grid_samples(size, spacing: float, margin: float = 2.0, first: float | None = None,
                 offset=None) -> np.ndarray:
    """All grid points [n, d] of axis_samples on every axis of an arena of extents ``size`` (rows in
    itertools.product order: x slowest, the last axis fastest); ``offset`` [d] shifts the whole grid (jittered grids)."""
    axes = [axis_samples(float(L), spacing, margin, first) for L in size]
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
