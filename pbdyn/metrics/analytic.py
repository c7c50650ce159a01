"""The "analytic" survivability backend (pbdyn.metrics.backends): when an obstacle first overlaps a static MAV at
each sample (centre distance < r_i + r_mav; imported worlds: the moving bodies' bounding spheres), in numpy or
compiled code. Modes: "sampled" (the thesis) checks the steps t_k = k dt, k = 0..floor(T_max / dt), the first k
with overlap giving t = k dt; "exact" moves the obstacle linearly between steps and takes the smaller root of
|dp + s w|^2 = (r_i + r_mav)^2 per step, never later than "sampled".
"""

from __future__ import annotations

import numpy as np

from pbdyn import limits
from pbdyn.errors import ConfigError, check_positive
from pbdyn.jit import njit
from pbdyn.metrics.sampling import step_window

MODES = ("sampled", "exact")


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
    mav_radius = check_positive("mav_radius", mav_radius)
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
        chunk = max(1, limits.CHUNK_ELEMENTS // (alive.size * n_obs * dims))
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
