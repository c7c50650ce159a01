"""Linear model of a map quantity on its setup, S = b0 + b1 n + b2 r + b3 v (thesis eq. 5-1, table 5-4).

Setup features of a map: n = obstacle count; r, v = the setup's radius (m) and speed (m/s) when the setup gives a
single value, else (a {"min", "max"} range, drawn per obstacle) the map's actual mean obstacle radius / speed
("mean_obstacle_radius", "mean_obstacle_speed"), falling back to the range midpoint if that is missing. Scalar
setups thus keep the exact grid values the thesis regressed on, and every map of one setup gets the same features.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FEATURES = ("n", "r", "v")
"""Feature names of eq. 5-1: obstacle count, radius (m), speed (m/s)."""


def _value(setup_value, actual) -> float:
    if isinstance(setup_value, dict):
        if actual is not None and np.isfinite(float(actual)):
            return float(actual)
        return 0.5 * (float(setup_value["min"]) + float(setup_value["max"]))
    if setup_value is None:
        return float(actual) if actual is not None else float("nan")
    return float(setup_value)


def setup_features(entry: dict) -> np.ndarray:
    """Features (n, r [m], v [m/s]) of eq. 5-1 for one map entry (see the module docstring); NaN if unknown."""
    s = entry.get("setup") or {}
    n = s.get("count")
    return np.array([float(n) if n is not None else float("nan"),
                     _value(s.get("radius"), entry.get("mean_obstacle_radius")),
                     _value(s.get("speed"), entry.get("mean_obstacle_speed"))])


def setup_key(entry: dict) -> str:
    """A canonical string of the map's (n, r, v) setup, equal for maps that differ only by seed; "" for a map
    without an obstacle count (e.g. an imported world), which belongs to no setup."""
    s = entry.get("setup") or {}
    if s.get("count") is None:
        return ""
    return repr((s.get("count"), _canon(s.get("radius")), _canon(s.get("speed"))))


def _canon(v):
    return tuple(sorted((k, float(x)) for k, x in v.items())) if isinstance(v, dict) else v


@dataclass(frozen=True)
class LinearFit:
    """Least-squares fit y = b0 + X b (thesis eq. 5-1): coefficients [b0, b1, ...], R^2 and the number of rows."""

    coefficients: np.ndarray
    r2: float
    n: int

    def predict(self, x: np.ndarray) -> np.ndarray:
        """b0 + X b for rows x [rows, features] (features with a NaN, i.e. not identifiable, coefficient count 0)."""
        x = np.asarray(x, float)
        return self.coefficients[0] + x @ np.nan_to_num(self.coefficients[1:], nan=0.0)


def fit_linear(x: np.ndarray, y: np.ndarray) -> LinearFit:
    """Ordinary least squares of y [rows] on x [rows, features] with an intercept (thesis eq. 5-1) over the rows
    finite in x and y; R^2 = 1 - SS_res / SS_tot (NaN if y is constant or fewer rows than coefficients). A feature
    that is constant over those rows cannot be told from the intercept: its coefficient is NaN (not identifiable)
    and the fit uses the others."""
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    ok = np.isfinite(y) & np.isfinite(x).all(axis=1)
    xs = x[ok]
    varies = np.ptp(xs, axis=0) > 0 if xs.shape[0] else np.zeros(x.shape[1], dtype=bool)
    a = np.column_stack([np.ones(int(ok.sum())), xs[:, varies]])
    if a.shape[0] < a.shape[1]:
        return LinearFit(np.full(x.shape[1] + 1, np.nan), float("nan"), int(ok.sum()))
    sub, *_ = np.linalg.lstsq(a, y[ok], rcond=None)
    coef = np.full(x.shape[1] + 1, np.nan)
    coef[0] = sub[0]
    coef[1:][varies] = sub[1:]
    res = y[ok] - a @ sub
    tot = y[ok] - y[ok].mean()
    ss_tot = float(tot @ tot)
    r2 = 1.0 - float(res @ res) / ss_tot if ss_tot > 0 else float("nan")
    return LinearFit(coef, r2, int(ok.sum()))
