"""What a policy observes of a trial (docs/gym.md "Observation"): what the MAV knows, never the true obstacle states.

The observation is one float32 vector with every entry in [-1, 1] (scaled, then clipped), in the world frame:

    [0, d)            velocity / v_max
    [d, d + 2)        cos(yaw), sin(yaw)
    [d + 2, 2d + 2)   (goal - position) / L            (L: the arena's largest side, m)
    then, for each of the K tracks nearest the MAV (by surface distance; rows of zeros where fewer are tracked):
        (track position - position) / (2 R)           d values (R: the sensor's range, m)
        (track velocity - velocity) / (2 v_max)       d values
        radius / R                                    1
        sqrt(trace of the position covariance) / R    1  (the track's uncertainty, m)
        mask                                          1  (1: a track, 0: padding)
    then, with ``rays`` = B > 0: the last scan's ranges / R, min-pooled into B bins in ray order
    then, with ``patch`` = P > 0 (odd): the MAV's occupancy grid (static geometry only) in the P^d cells centred on
        the MAV's cell, world-aligned, C order (x slowest): 1 occupied (or outside the grid), 0.5 unknown, 0 free

so its length is 2d + 2 + K (2d + 3) + B + P^d. The tracks are the MAV's Kalman tracks (pbdyn.perception.tracker),
so an obstacle never seen is absent and an occluded one keeps its predicted state and growing uncertainty; the patch
is the MAV's own map (pbdyn.perception.grid, thesis 2-4-2): walls it has not seen are unknown.
"""

from __future__ import annotations

import math

import numpy as np

from pbdyn.errors import ConfigError
from pbdyn.limits import MAX_GYM_PATCH_CELLS, MAX_GYM_RAYS, MAX_GYM_TRACKS
from pbdyn.perception.grid import OCCUPIED, UNKNOWN


PATCH_VALUES = {"occupied": 1.0, "unknown": 0.5, "free": 0.0}
"""What a cell of the occupancy patch reads (a cell outside the grid reads as occupied)."""


def check_patch(patch, dims: int = 2) -> int:
    """``patch`` (P, the occupancy patch's cells per side) checked: 0 (none) or an odd integer >= 1 with P^dims <=
    MAX_GYM_PATCH_CELLS (ConfigError naming ``patch``)."""
    if isinstance(patch, bool) or not isinstance(patch, (int, np.integer)) or patch < 0 \
            or (patch and patch % 2 == 0) or int(patch) ** dims > MAX_GYM_PATCH_CELLS:
        side = math.floor(MAX_GYM_PATCH_CELLS ** (1.0 / dims) + 1e-9)
        side -= 1 - side % 2
        raise ConfigError("patch", f"must be 0 or an odd integer >= 1 and <= {side} in {dims}D (cells per side; "
                          f"P^d <= pbdyn.limits.MAX_GYM_PATCH_CELLS = {MAX_GYM_PATCH_CELLS})", patch)
    return int(patch)


def check_observed(tracks, rays, patch, dims: int = 2) -> tuple[int, int, int]:
    """(K, B, P) of a ``dims``-D environment's observation checked: tracks integers 0..MAX_GYM_TRACKS, rays
    0..MAX_GYM_RAYS, patch as check_patch (ConfigError naming the argument and its value otherwise)."""
    for name, value, limit in (("tracks", tracks, MAX_GYM_TRACKS), ("rays", rays, MAX_GYM_RAYS)):
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= limit:
            raise ConfigError(name, f"must be an integer >= 0 and <= {limit} (pbdyn.limits.MAX_GYM_{name.upper()})",
                              value)
    return tracks, rays, check_patch(patch, dims)


def observation_size(dims: int, tracks: int, rays: int, patch: int = 0) -> int:
    """The length of the observation vector for ``dims`` (2 or 3), K = ``tracks``, B = ``rays`` and P = ``patch``."""
    return 2 * dims + 2 + tracks * (2 * dims + 3) + rays + (patch ** dims if patch else 0)


def observe(state, tracks: int, rays: int, patch: int = 0) -> np.ndarray:
    """The observation (float32 [observation_size]) of a trial's state (pbdyn.sim.state.TrialState) after its
    sensing at t_k; see the module docstring for the layout and scales."""
    sc = state.spec.scenario
    ranges = state.detections.ranges if rays else None
    return observe_parts(state.velocity, state.yaw, state.position, state.goal, state.tracks, state.limits.v_max,
                         float(sc.sensor.range), float(max(sc.world.size)), ranges, tracks, rays,
                         state.grid if patch else None, patch)


def observe_view(view, tracks: int, rays: int = 0, patch: int = 0) -> np.ndarray:
    """The observation (float32 [observation_size]) of a planner's View (pbdyn.planning.view.View): the same vector
    observe() makes of the TrialState the view was taken of (the arena's largest side from the view's bounds; the
    patch from the view's grid). A View carries no scan ranges, so ``rays`` must be 0 (ValueError otherwise): a
    policy observed with depth bins cannot be flown through a View (pbdyn.gym.policy_planner; docs/gym.md)."""
    if rays:
        raise ValueError(f"a View carries no scan ranges: observe_view needs rays = 0 (got {rays!r})")
    arena = float(max((view.bounds_hi - view.bounds_lo).tolist()))
    return observe_parts(view.velocity, view.yaw, view.position, view.goal, view.tracks, view.limits.v_max,
                         float(view.range_m), arena, None, tracks, 0, view.grid if patch else None, patch)


def occupancy_patch(grid, position: np.ndarray, patch: int) -> np.ndarray:
    """The P^d cells of ``grid`` (pbdyn.perception.grid.OccupancyGrid) centred on the cell holding ``position`` [d]
    (m), C order, as PATCH_VALUES (float [P^d]); cells outside the grid read as occupied."""
    d = grid.dims
    h = patch // 2
    centre = np.floor((np.asarray(position, dtype=float) - grid.origin) / grid.res).astype(np.int64)
    lo, hi = centre - h, centre + h + 1
    out = np.full((patch,) * d, PATCH_VALUES["occupied"])
    src_lo = np.maximum(lo, 0)
    src_hi = np.minimum(hi, np.asarray(grid.shape))
    if np.all(src_hi > src_lo):
        cells = grid.cells[tuple(slice(a, b) for a, b in zip(src_lo, src_hi))]
        values = np.where(cells == OCCUPIED, PATCH_VALUES["occupied"],
                          np.where(cells == UNKNOWN, PATCH_VALUES["unknown"], PATCH_VALUES["free"]))
        out[tuple(slice(a, b) for a, b in zip(src_lo - lo, src_hi - lo))] = values
    return out.reshape(-1)


def observe_parts(velocity: np.ndarray, yaw: float, position: np.ndarray, goal: np.ndarray, tracks_seen, v_max: float,
                  range_m: float, arena_m: float, ranges, tracks: int, rays: int, grid=None,
                  patch: int = 0) -> np.ndarray:
    """The observation (float32 [observation_size]) of the MAV's velocity [d] (m/s), yaw (rad), position and goal
    [d] (m), its Kalman tracks (pbdyn.perception.tracks.Tracks or None), v_max (m/s), the sensor's range R (m), the
    arena's largest side L (m), the last scan's ranges (m, ray order; read only when ``rays`` > 0) and the MAV's
    occupancy grid (read only when ``patch`` > 0); world frame. observe() and observe_view() both build it here, so a
    state and a view of it give the same vector."""
    d = position.shape[0]
    rng = range_m
    n_patch = patch ** d if patch else 0
    out = np.zeros(observation_size(d, tracks, rays, patch))
    out[:d] = velocity / v_max
    out[d] = math.cos(yaw)
    out[d + 1] = math.sin(yaw)
    out[d + 2:2 * d + 2] = (goal - position) / arena_m
    tr = tracks_seen
    if tracks and tr is not None and len(tr.ids):
        rel = tr.position - position
        gap = np.sqrt(np.einsum("ij,ij->i", rel, rel)) - tr.radius
        near = np.argsort(gap, kind="stable")[:tracks]
        n = near.size
        cov = tr.covariance[near]
        unc = np.sqrt(np.maximum(np.trace(cov[:, :d, :d], axis1=1, axis2=2), 0.0))
        rows = np.concatenate([rel[near] / (2.0 * rng), (tr.velocity[near] - velocity) / (2.0 * v_max),
                               (tr.radius[near] / rng)[:, None], (unc / rng)[:, None], np.ones((n, 1))], axis=1)
        start = 2 * d + 2
        out[start:start + n * (2 * d + 3)] = rows.reshape(-1)
    if rays:
        ranges = np.asarray(ranges, dtype=float) / rng
        bins = np.array_split(ranges, rays) if ranges.size >= rays else [ranges] * rays
        end = out.shape[0] - n_patch
        out[end - rays:end] = [b.min() if b.size else 1.0 for b in bins]
    if patch:
        out[out.shape[0] - n_patch:] = occupancy_patch(grid, position, patch)
    return np.clip(out, -1.0, 1.0).astype(np.float32)
