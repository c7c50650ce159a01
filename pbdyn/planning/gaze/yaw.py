"""Yaw arithmetic the gaze planners share (rad, rad/s): headings, rate clipping, and the candidate rates and
tie-break order of the sampled gaze planners (pbdyn.planning.gaze.finean, pbdyn.planning.gaze.owl). Angles are
wrapped by pbdyn.world.geometry.wrap_angle."""

from __future__ import annotations

import math

import numpy as np

from pbdyn.limits import MAX_PLAN_COUNT
from pbdyn.planning import params

_EPS = 1e-6


def heading(vec: np.ndarray) -> float | None:
    """Heading (rad) of the x-y part of vec, or None when it is shorter than 1e-6."""
    x, y = float(vec[0]), float(vec[1])
    if math.hypot(x, y) < _EPS:
        return None
    return math.atan2(y, x)


def clip_rate(rate: float, limit: float) -> float:
    """float(np.clip(rate, -limit, limit)) for a Python float (rad/s), by numpy's own rule (NaN stays NaN, else
    max(rate, -limit) then min(., limit), each keeping its first operand unless the second is strictly beyond it),
    without numpy's dispatch (a few us per call)."""
    if rate != rate:
        return float(rate)
    low = -limit
    m = rate if rate > low else low
    return float(m if m < limit else limit)


def rate_candidates(limit: float, n: int, include_zero: bool = True) -> np.ndarray:
    """Candidate yaw rates (rad/s): n evenly spaced values in [-limit, +limit] (both limits included), plus 0 when
    ``include_zero`` and n is even; sorted ascending. n >= 2."""
    n = params.integer("the number of candidate rates", n, lo=2, hi=MAX_PLAN_COUNT)
    rates = np.linspace(-float(limit), float(limit), int(n))
    if include_zero and not np.any(rates == 0.0):
        rates = np.sort(np.append(rates, 0.0))
    return rates


def tie_break_order(rates: np.ndarray) -> np.ndarray:
    """Indices of ``rates`` by increasing |rate|, counter-clockwise (positive) first on equal |rate|: the order in
    which sampled gaze planners break exact score ties."""
    return np.lexsort((-rates, np.abs(rates)))
