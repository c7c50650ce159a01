"""Survivability (thesis eq. 3-6) and global survivability (eq. 3-7): how long a static MAV survives among the
moving obstacles of a rollout.

A static MAV (disc in 2D, ball in 3D, radius ``mav_radius``) sits at each sample; its survival time is the first
time an obstacle overlaps it (centre distance < r_i + r_mav; planar in 2D, Euclidean in 3D), capped at T_max.

Modes of the analytic kernel:
    "sampled" (the thesis): overlap is checked at the steps t_k = k dt, k = 0..floor(T_max / dt); the first k with
        overlap gives t = k dt.
    "exact": the obstacle moves linearly between steps; the first contact is the smaller root of
        |dp + s w|^2 = (r_i + r_mav)^2 per step, so it is never later than "sampled".

Backends: "analytic" (this module, numpy over samples x obstacles x steps, chunked in time; imported worlds: the
moving bodies' bounding spheres), "bullet" (pbdyn.metrics.bullet_backend, collision queries against the world's
bodies, real shapes) and "mesh" (pbdyn.metrics.mesh_backend, signed distances to the real shapes of an imported
world); the last two "sampled" mode only, imported lazily.
"""

from __future__ import annotations

import time as _time

import numpy as np

from pbdyn.errors import ConfigError, check_positive
from pbdyn.jit import njit
from pbdyn.metrics.result import MetricResult
from pbdyn.metrics.sampling import grid_samples, outside_geometry, step_window
from pbdyn.world.maps import stable_hash64

MODES = ("sampled", "exact")
BACKENDS = ("analytic", "bullet", "mesh")
GLOBAL_START_TIMES = (0.0, 4.0, 8.0, 12.0, 16.0, 20.0)
CHUNK_ELEMENTS = 4_000_000
"""Upper bound on the elements of one temporary array (samples x obstacles x steps of a time chunk)."""
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
# kernel
# ----------------------------------------------------------------------------------------------------------------
def _sq_dist(pts: np.ndarray, obs: np.ndarray) -> np.ndarray:
    """Squared distances [c, m, N] between points [m, d] and obstacle centres [c, N, d] (loop over the d axes)."""
    out = None
    for a in range(pts.shape[1]):
        diff = pts[None, :, None, a] - obs[:, None, :, a]
        out = diff * diff if out is None else out + diff * diff
    return out


def survival_times(rollout, points, *, mav_radius: float = 1.0, t_max: float = 12.0, start_time: float = 0.0,
                   mode: str = "sampled") -> np.ndarray:
    """Survival time (s, relative to ``start_time``) of a static MAV at each point [n, d] (m, world frame) (eq. 3-6).

    The first time an obstacle overlaps the MAV (centre distance < r_i + mav_radius), capped at t_max.
    mode "sampled": first step k >= 0 with overlap, t = k dt (thesis; compiled, each point stopping at its first hit:
    _first_overlap, whose numpy reference twin is _survival_reference); "exact": first contact with linear motion
    between steps (closed form), never later than "sampled" (numpy, chunked in time; samples already hit are dropped
    from later chunks). HorizonError if start_time + t_max is past the horizon.
    """
    if mode not in MODES:
        raise ConfigError("mode", f"must be one of {', '.join(MODES)}", mode)
    pts = np.asarray(points, dtype=float).reshape(-1, rollout.dims)
    mav_radius = positive("mav_radius", mav_radius)
    k0, n_steps = step_window(rollout, start_time, t_max)
    t_max = float(t_max)
    out = np.full(pts.shape[0], t_max)
    if pts.shape[0] == 0 or rollout.n_obstacles == 0:
        return out
    reach2 = (rollout.radii + mav_radius) ** 2
    window = rollout.positions[k0:k0 + n_steps + 1]                    # [K + 1, N, d]
    dt = rollout.dt
    if mode == "sampled" and pts.shape[1] == window.shape[2]:
        _first_overlap(np.ascontiguousarray(pts), np.ascontiguousarray(window, dtype=float),
                       np.ascontiguousarray(reach2, dtype=float), float(dt), t_max, out)
        return out
    return _survival_reference(pts, window, reach2, dt, t_max, mode, out)


def _survival_reference(pts, window, reach2, dt, t_max, mode, out):
    """survival_times in numpy, chunked in time: the "exact" mode, and the reference twin of the compiled "sampled"
    mode (_first_overlap: the same floats); fills and returns ``out`` (s; t_max where nothing overlaps)."""
    alive = np.arange(pts.shape[0])
    first = 0
    n_steps, n_obs, dims = window.shape[0] - 1, window.shape[1], window.shape[2]
    n_items = n_steps + 1 if mode == "sampled" else n_steps            # steps, or intervals between steps
    while first < n_items and alive.size:
        chunk = max(1, CHUNK_ELEMENTS // (alive.size * n_obs * dims))
        stop = min(n_items, first + chunk)
        sub = pts[alive]
        if mode == "sampled":
            hit = np.any(_sq_dist(sub, window[first:stop]) < reach2, axis=2)      # [c, m]
            got = hit.any(axis=0)
            t_hit = (first + np.argmax(hit, axis=0)) * dt
        else:
            t_hit = _exact_chunk(sub, window[first:stop + 1], reach2)
            got = np.isfinite(t_hit)
            t_hit = (first + t_hit) * dt
        out[alive[got]] = np.minimum(t_hit[got], t_max)
        alive = alive[~got]
        first = stop
    return out


@njit(cache=True, nogil=True)
def _first_overlap(pts, window, reach2, dt, t_max, out):
    """survival_times' "sampled" mode in compiled code: for each point [n, d], the first step k of window [K, N, d]
    with an obstacle j whose squared centre distance (_sq_dist's sum over the axes in order) is below reach2[j];
    out[i] = min(k dt, t_max) (numpy's floats), left as it is when there is none. Each point stops at its first hit."""
    n_k, n_obs, d = window.shape
    for i in range(pts.shape[0]):
        for k in range(n_k):
            hit = False
            for j in range(n_obs):
                diff = pts[i, 0] - window[k, j, 0]
                sq = diff * diff
                for a in range(1, d):
                    diff = pts[i, a] - window[k, j, a]
                    sq = sq + diff * diff
                if sq < reach2[j]:
                    hit = True
                    break
            if hit:
                t = float(k) * dt
                out[i] = t if t <= t_max else t_max
                break


def _exact_chunk(pts: np.ndarray, obs: np.ndarray, reach2: np.ndarray) -> np.ndarray:
    """First contact [m] in units of steps from the chunk's first step (inf if none) of points [m, d] with obstacles
    moving linearly between the chunk's c + 1 positions obs [c + 1, N, d]."""
    p0, p1 = obs[:-1], obs[1:]
    dp0 = pts[None, :, None, :] - p0[:, None, :, :]                     # [c, m, N, d]
    w = (p0 - p1)[:, None, :, :]                                          # relative displacement (MAV is static)
    a = np.sum(w * w, axis=-1)                                            # [c, 1, N]
    b = np.sum(dp0 * w, axis=-1)                                          # [c, m, N] (half the linear coefficient)
    c = np.sum(dp0 * dp0, axis=-1) - reach2
    s_star = np.clip(np.divide(-b, a, out=np.zeros_like(b), where=a > 0), 0.0, 1.0)
    lowest = (a * s_star + 2.0 * b) * s_star + c
    end = _sq_dist(pts, p1) < reach2                                      # the sampled test at the interval's end
    hit = (lowest < 0.0) | end
    disc = np.sqrt(np.maximum(b * b - a * c, 0.0))
    denom = -b + disc
    frac = np.divide(c, denom, out=np.ones_like(c), where=(c > 0.0) & (denom > 0.0))   # cancellation-free root
    frac = np.where(c <= 0.0, 0.0, np.clip(frac, 0.0, 1.0))
    k = np.arange(obs.shape[0] - 1, dtype=float)[:, None, None]
    t = np.where(hit, k + frac, np.inf)
    return t.min(axis=(0, 2))


def _kernel(backend: str, mode: str):
    """The per-sample survival function of ``backend``: analytic survival_times or the bullet backend's
    survival_times_bullet (imported lazily; "sampled" mode only)."""
    if backend not in BACKENDS:
        raise ConfigError("backend", f"unknown backend (known: {', '.join(BACKENDS)})", backend)
    if mode not in MODES:
        raise ConfigError("mode", f"must be one of {', '.join(MODES)}", mode)
    if backend == "analytic":
        return lambda ro, pts, **kw: survival_times(ro, pts, mode=mode, **kw)
    if mode != "sampled":
        raise ConfigError("backend", f'the {backend} backend supports mode "sampled" only (got mode "{mode}")',
                          backend)
    if backend == "mesh":
        from pbdyn.metrics import mesh_backend

        return lambda ro, pts, **kw: mesh_backend.survival_times_mesh(ro, pts, **kw)
    from pbdyn.metrics import bullet_backend

    return lambda ro, pts, **kw: bullet_backend.survival_times_bullet(ro, pts, **kw)


def _table_kernel(backend: str, mode: str):
    """kernel(rollout, points, start_times, **kw) -> survival times [S, n] (s) for several start times; the bullet
    backend keeps one client for all of them."""
    single = _kernel(backend, mode)
    if backend == "bullet":
        from pbdyn.metrics import bullet_backend

        return lambda ro, pts, starts, **kw: bullet_backend.survival_table_bullet(ro, pts, starts, **kw)
    return lambda ro, pts, starts, **kw: np.stack([np.asarray(single(ro, pts, start_time=s, **kw), dtype=float)
                                                   for s in starts]).reshape(len(starts), -1)


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
    kernel = _kernel(backend, mode)
    mav_radius = positive("mav_radius", mav_radius)
    spacing = positive("spacing", spacing)
    step_window(rollout, start_time, t_max)
    pts, n_excl = split_static(rollout, base_points(rollout, points, spacing, margin), mav_radius)
    grids = [pts] + jittered_grids(rollout, pts, spacing, int(n_jitter), mav_radius)
    times = kernel(rollout, np.concatenate(grids), mav_radius=mav_radius, t_max=t_max, start_time=start_time)
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
    kernel = _table_kernel(backend, mode)
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
    table = np.asarray(kernel(rollout, np.concatenate(grids), starts, mav_radius=mav_radius, t_max=t_max), dtype=float)
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
