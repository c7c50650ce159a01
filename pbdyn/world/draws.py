"""The random draws a map's obstacles are made of (pbdyn.world.maps spawns them, pbdyn.world.structure varies
them): values of a setup value (exact, jittered or a range), gamma spreads and unit headings, from the map's
Generator."""

from __future__ import annotations

import numpy as np


def draw_values(value, rng: np.random.Generator, n: int, jitter: float) -> np.ndarray:
    """n values of a setup value (a radius in m or a speed in m/s): uniform in a {min, max} range, else ``value``
    +- ``jitter`` uniform, or exactly ``value`` without jitter (no draw then)."""
    if isinstance(value, dict):
        return rng.uniform(value["min"], value["max"], n)
    if jitter > 0:
        return rng.uniform(value - jitter, value + jitter, n)
    return np.full(n, float(value))


def gamma_values(rng: np.random.Generator, mean: float, cv: float, n: int, floor: float = 0.0) -> np.ndarray:
    """n gamma draws with the given mean and coefficient of variation (shape 1/cv^2, scale mean cv^2), at least
    ``floor``; all equal to ``mean`` for cv = 0."""
    if cv <= 0 or mean <= 0:
        return np.full(n, float(mean))
    k = 1.0 / (cv * cv)
    return np.maximum(rng.gamma(k, mean / k, n), floor)


def random_unit_vectors(rng: np.random.Generator, n: int, dims: int) -> np.ndarray:
    """n uniformly random unit vectors [n, d] (2D: uniform heading; 3D: uniform on the sphere)."""
    if dims == 2:
        th = rng.uniform(0.0, 2.0 * np.pi, n)
        return np.stack([np.cos(th), np.sin(th)], axis=1)
    v = rng.standard_normal((n, dims))
    norm = np.linalg.norm(v, axis=1, keepdims=True)
    norm[norm == 0] = 1.0
    return v / norm
