"""Survivability (thesis eq. 3-6) and global survivability (eq. 3-7): how long a static MAV survives among the
moving obstacles of a rollout.

A static MAV (disc in 2D, ball in 3D, radius ``mav_radius``) sits at each sample; its survival time is the first
time an obstacle overlaps it, capped at T_max, as the ``backend`` finds it (pbdyn.metrics.backends: "analytic",
discs/balls, modes "sampled" and "exact"; "bullet" and "mesh", the real shapes, mode "sampled").
"""

from __future__ import annotations

import time as _time

import numpy as np

from pbdyn.errors import ConfigError, check_positive
from pbdyn.metrics.backends import kernel, table_kernel
from pbdyn.metrics.result import MetricResult
from pbdyn.metrics.sampling import grid_samples, outside_geometry, step_window
from pbdyn.world.maps import stable_hash64

GLOBAL_START_TIMES = (0.0, 4.0, 8.0, 12.0, 16.0, 20.0)
JITTER_SEED_TAG = 8


# ----------------------------------------------------------------------------------------------------------------
# shared sample handling (also used by vo.py)
# ----------------------------------------------------------------------------------------------------------------
positive = check_positive  # kept as the name vo.py / traversability.py import


def jsonable(value):
    """Plain JSON data (lists, floats, ints, strings) from numpy arrays, tuples and scalars."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def base_points(rollout, points, spacing: float, margin: float) -> np.ndarray:
    """The sample points [n, d] (m): ``points`` if given, else sampling.grid_samples(arena, spacing, margin)."""
    d = rollout.dims
    if points is not None:
        pts = np.asarray(points, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != d:
            raise ConfigError("points", f"must be an array [n, {d}]", jsonable(pts))
        return pts
    return grid_samples(rollout.arena_size, positive("spacing", spacing), float(margin))


def split_static(rollout, pts: np.ndarray, mav_radius: float) -> tuple[np.ndarray, int]:
    """(points whose MAV disc/ball of ``mav_radius`` m overlaps no static body, number left out)."""
    keep = outside_geometry(rollout, pts, mav_radius)
    return pts[keep], int(np.count_nonzero(~keep))


def jitter_offsets(rollout, spacing: float, n: int) -> np.ndarray:
    """``n`` whole-grid offsets [n, d] (m), uniform in [-spacing/2, spacing/2]^d, from a Generator seeded with
    SeedSequence([stable hash of rollout.meta["map_key"] (0 without one), 8]) -- never global random state."""
    key = rollout.meta.get("map_key") if isinstance(rollout.meta, dict) else None
    entropy = stable_hash64(str(key)) if key is not None else 0
    rng = np.random.default_rng(np.random.SeedSequence([entropy, JITTER_SEED_TAG]))
    return rng.uniform(-spacing / 2.0, spacing / 2.0, size=(int(n), rollout.dims))


def jittered_grids(rollout, pts: np.ndarray, spacing: float, n: int, mav_radius: float) -> list[np.ndarray]:
    """The grid ``pts`` [n, d] (m) shifted by each jitter offset, clipped to [r_mav, L - r_mav] per axis, with static
    overlaps removed."""
    lo = np.full(rollout.dims, mav_radius)
    hi = rollout.arena_size - mav_radius
    return [split_static(rollout, np.clip(pts + off[None, :], lo, hi), mav_radius)[0]
            for off in jitter_offsets(rollout, spacing, n)]


def summary(values: np.ndarray) -> tuple[float, float]:
    """(mean, std / sqrt(n)) with the sample std (ddof = 1); NaN where undefined."""
    v = np.asarray(values, dtype=float).ravel()
    if v.size == 0:
        return float("nan"), float("nan")
    err = float(np.std(v, ddof=1) / np.sqrt(v.size)) if v.size > 1 else float("nan")
    return float(np.mean(v)), err


# ----------------------------------------------------------------------------------------------------------------
# metrics
# ----------------------------------------------------------------------------------------------------------------
def survivability(rollout, *, spacing: float = 6.0, margin: float = 2.0, mav_radius: float = 1.0,
                  t_max: float = 12.0, start_time: float = 0.0, mode: str = "sampled", backend: str = "analytic",
                  points=None, n_jitter: int = 8, name: str = "survivability") -> MetricResult:
    """Survivability (thesis eq. 3-6, s): mean over samples of the static MAV's survival time, capped at t_max.

    Samples: grid points margin + k * spacing on every axis while <= L - margin (m; 2D 8 x 8, 3D z layers 2, 8,
    14 m), or ``points`` [n, d]; samples whose MAV overlaps static geometry are left out (n_excluded).
    per_sample: survival times [n] (s). stderr = std / sqrt(n). extra["jitter"]: the value on ``n_jitter`` grids
    shifted by seeded offsets in [-spacing/2, spacing/2]^d (clipped to [r_mav, L - r_mav]) with their mean and std.
    """
    t0 = _time.perf_counter()
    find = kernel(backend, mode)
    mav_radius = positive("mav_radius", mav_radius)
    spacing = positive("spacing", spacing)
    step_window(rollout, start_time, t_max)
    pts, n_excl = split_static(rollout, base_points(rollout, points, spacing, margin), mav_radius)
    grids = [pts] + jittered_grids(rollout, pts, spacing, int(n_jitter), mav_radius)
    times = find(rollout, np.concatenate(grids), mav_radius=mav_radius, t_max=t_max, start_time=start_time)
    parts = np.split(np.asarray(times, dtype=float), np.cumsum([g.shape[0] for g in grids])[:-1])
    per_sample = parts[0]
    value, err = summary(per_sample)
    jit = [float(np.mean(p)) if p.size else float("nan") for p in parts[1:]]
    params = {"spacing": spacing, "margin": float(margin), "mav_radius": mav_radius, "t_max": float(t_max),
              "start_time": float(start_time), "dt": rollout.dt, "mode": mode, "backend": backend,
              "n_jitter": int(n_jitter), "points": None if points is None else jsonable(pts)}
    extra = {"jitter": {"values": jit, "mean": float(np.mean(jit)) if jit else float("nan"),
                        "std": float(np.std(jit, ddof=1)) if len(jit) > 1 else float("nan")}}
    per_sample.setflags(write=False)
    return MetricResult(name, value, params, int(per_sample.size), n_excl, per_sample, err, extra,
                        _time.perf_counter() - t0)


def survivability_dense(rollout, *, spacing: float = 3.0, margin: float = 2.0, mav_radius: float = 1.0,
                        t_max: float = 12.0, start_time: float = 0.0, mode: str = "sampled",
                        backend: str = "analytic", points=None, n_jitter: int = 8) -> MetricResult:
    """Dense survivability (thesis eq. 3-6, s): survivability on the 3 m grid (2D 16 x 16); see survivability()."""
    return survivability(rollout, spacing=spacing, margin=margin, mav_radius=mav_radius, t_max=t_max,
                         start_time=start_time, mode=mode, backend=backend, points=points, n_jitter=n_jitter,
                         name="survivability_dense")


def global_survivability(rollout, *, spacing: float = 12.0, margin: float = 2.0, mav_radius: float = 1.0,
                         t_max: float = 24.0, start_times=GLOBAL_START_TIMES, mode: str = "sampled",
                         backend: str = "analytic", points=None, n_jitter: int = 8) -> MetricResult:
    """Global survivability (thesis eq. 3-7, s): static MAVs at every point of the 12 m grid (2D: 16 points); for
    each start time t_j the time until ANY of them is hit, capped at t_max; the mean over the start times.

    Never above the single-point survival time of any point from the same start. per_sample: the value of each
    start time [K] (s); stderr = std / sqrt(K); extra["jitter"] as in survivability() (the whole metric on each
    jittered grid); extra["first_hit_point"]: per start time the index of the point hit first (-1 if none).
    """
    t0 = _time.perf_counter()
    find = table_kernel(backend, mode)
    mav_radius = positive("mav_radius", mav_radius)
    spacing = positive("spacing", spacing)
    starts = [float(s) for s in np.atleast_1d(np.asarray(start_times, dtype=float))]
    if not starts:
        raise ConfigError("start_times", "must not be empty", jsonable(start_times))
    for s in starts:
        step_window(rollout, s, t_max)
    pts, n_excl = split_static(rollout, base_points(rollout, points, spacing, margin), mav_radius)
    grids = [pts] + jittered_grids(rollout, pts, spacing, int(n_jitter), mav_radius)
    bounds = np.cumsum([g.shape[0] for g in grids])[:-1]
    per_grid = np.full((len(grids), len(starts)), float(t_max))
    first_hit = []
    table = np.asarray(find(rollout, np.concatenate(grids), starts, mav_radius=mav_radius, t_max=t_max), dtype=float)
    for j, times in enumerate(table):
        for g, part in enumerate(np.split(times, bounds)):
            if part.size:
                per_grid[g, j] = min(float(part.min()), float(t_max))
            if g == 0:
                first_hit.append(int(np.argmin(part)) if part.size and part.min() < t_max else -1)
    per_sample = per_grid[0].copy()
    value, err = summary(per_sample)
    jit = [float(np.mean(r)) for r in per_grid[1:]]
    params = {"spacing": spacing, "margin": float(margin), "mav_radius": mav_radius, "t_max": float(t_max),
              "start_times": starts, "dt": rollout.dt, "mode": mode, "backend": backend, "n_jitter": int(n_jitter),
              "n_points": int(pts.shape[0]), "points": None if points is None else jsonable(pts)}
    extra = {"jitter": {"values": jit, "mean": float(np.mean(jit)) if jit else float("nan"),
                        "std": float(np.std(jit, ddof=1)) if len(jit) > 1 else float("nan")},
             "first_hit_point": first_hit}
    per_sample.setflags(write=False)
    return MetricResult("global_survivability", value, params, int(pts.shape[0]), n_excl, per_sample, err, extra,
                        _time.perf_counter() - t0)
