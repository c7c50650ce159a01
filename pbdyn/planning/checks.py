"""Validity checks of a candidate trajectory, shared by the planners (thesis A-2 eq. A-2, A-3).

A sample is in conflict when the MAV ball (radius limits.radius + margin) meets
(a) a track's constant-velocity prediction at the sample's absolute time: centre = position + (t - view.t) velocity
    (tracks' means are at view.t), radius = the track's radius;
(b) an OCCUPIED grid cell (UNKNOWN cells count as free, as in the thesis program);
(c) an arena wall. Walls use the smaller ball radius limits.radius + min(margin, WALL_MARGIN_CAP): the planners'
    safety margin is meant for moving or perceived obstacles, and a full margin at the walls would push the
    reachable box 0.5 m further in and starve the primitive fan near the start/goal candidates 4 m from a wall.
"""

from __future__ import annotations

import numpy as np

from pbdyn.perception.grid import OCCUPIED
from pbdyn.planning.view import View

WALL_MARGIN_CAP = 0.1  # m; largest margin applied against the arena walls


def first_conflict(view: View, p: np.ndarray, times: np.ndarray, margin: float = 0.5) -> int:
    """Index of the first sample of positions p [K, d] (m) at absolute times [K] (s) that conflicts; -1 if none."""
    p = np.asarray(p, dtype=float)
    k = p.shape[0]
    if k == 0:
        return -1
    bad = _wall_hits(view, p, margin)
    if len(view.tracks):
        bad |= _track_hits(view, p, np.asarray(times, dtype=float) - view.t, margin)
    first = int(np.argmax(bad)) if bad.any() else k
    if first > 0:  # the grid query is the expensive one: only where nothing else failed earlier
        grid_bad = view.grid.collides(p[:first], view.limits.radius + margin)
        if grid_bad.any():
            first = int(np.argmax(grid_bad))
    return -1 if first == k else first


def trajectory_clear(view: View, p: np.ndarray, times: np.ndarray, margin: float = 0.5) -> bool:
    """True if no sample of positions p [K, d] (m) at absolute times [K] (s) conflicts (see module doc)."""
    p = np.asarray(p, dtype=float)
    if p.shape[0] == 0:
        return True
    if _wall_hits(view, p, margin).any():
        return False
    if len(view.tracks) and _track_hits(view, p, np.asarray(times, dtype=float) - view.t, margin).any():
        return False
    return not view.grid.collides(p, view.limits.radius + margin).any()


def static_clear(view: View, points: np.ndarray, margin: float = 0.5) -> np.ndarray:
    """Per point [K, d] (m): True if the MAV ball is clear of the walls and of OCCUPIED cells (checks b, c)."""
    return ~_static_bad(view, np.asarray(points, dtype=float), margin, grid=True)


def batch_conflicts(view: View, p: np.ndarray, times: np.ndarray, margin: float = 0.5, *,
                    walls: bool = True) -> np.ndarray:
    """Per candidate of positions p [n, K, d] (m) at absolute times [K] (s): True if any sample meets a wall (c;
    skipped when ``walls`` is False) or a track's constant-velocity prediction (a); the grid (b) is left to
    grid_conflicts. One array evaluation over candidates x samples x tracks: [n, K, M, d] floats."""
    p = np.asarray(p, dtype=float)
    n, k = p.shape[0], p.shape[1]
    if n == 0 or k == 0:
        return np.zeros(n, dtype=bool)
    if walls:
        wall_r = view.limits.radius + min(margin, WALL_MARGIN_CAP)
        bad = np.any((p < view.bounds_lo + wall_r) | (p > view.bounds_hi - wall_r), axis=(1, 2))
    else:
        bad = np.zeros(n, dtype=bool)
    tracks = view.tracks
    if len(tracks):
        tau = np.asarray(times, dtype=float) - view.t
        centres = tracks.position[None, :, :] + tau[:, None, None] * tracks.velocity[None, :, :]   # [K, M, d]
        rel = p[:, :, None, :] - centres[None]                                                      # [n, K, M, d]
        dist2 = rel[..., 0] * rel[..., 0]
        for i in range(1, rel.shape[-1]):
            dist2 = dist2 + rel[..., i] * rel[..., i]
        reach = tracks.radius + (view.limits.radius + margin)
        bad |= np.any(dist2 < reach * reach, axis=(1, 2))
    return bad


def grid_conflicts(view: View, p: np.ndarray, margin: float = 0.5) -> np.ndarray:
    """Per candidate of positions p [n, K, d] (m): True if any sample's MAV ball meets an OCCUPIED cell (b)."""
    p = np.asarray(p, dtype=float)
    n, k, d = p.shape
    if n == 0 or k == 0:
        return np.zeros(n, dtype=bool)
    return view.grid.collides(p.reshape(n * k, d), view.limits.radius + margin).reshape(n, k).any(axis=1)


PROGRAM_PROBE_EXTRA_M = 1.0
"""The thesis program's static probes lay MAV radius + 1 m (its radius + 10 px) from a sample's centre."""


def program_grid_conflicts(view: View, p: np.ndarray) -> np.ndarray:
    """The thesis program's static check (its planners' is_free; docs/thesis-program.md "Collision check"), per
    candidate of positions p [n, K, d] (m): True if, for any sample, one of five probes -- the centre and the
    points MAV radius + 1 m from it along +-x and +-y -- lies outside the program's map (the MAV's grid, whose
    border ring of cells is the program's wall cells) or in an OCCUPIED cell of the MAV's grid. Walls therefore
    count only where a ray has seen them (OCCUPIED ring cells), except that a probe beyond the ring always does;
    the MAV's disc itself is not tested, only the probes (a diagonal approach passes between them)."""
    p = np.asarray(p, dtype=float)
    n, k, d = p.shape
    if n == 0 or k == 0:
        return np.zeros(n, dtype=bool)
    grid = view.grid
    reach = view.limits.radius + PROGRAM_PROBE_EXTRA_M
    offsets = np.zeros((5, d))
    offsets[1, 0], offsets[2, 0], offsets[3, 1], offsets[4, 1] = -reach, reach, -reach, reach
    q = p[:, :, None, :] + offsets                                                  # [n, K, 5, d]
    lo = grid.origin
    hi = grid.origin + np.asarray(grid.shape, dtype=float) * grid.res
    outside = np.any((q < lo) | (q >= hi), axis=-1)
    occupied = grid.value_at(q) == OCCUPIED
    return np.any(outside | occupied, axis=(1, 2))


def _wall_hits(view: View, p: np.ndarray, margin: float) -> np.ndarray:
    """Per sample of positions p [..., K, d] (m): True if the MAV ball (radius + min(margin, WALL_MARGIN_CAP)) meets
    an arena wall (c). NaN samples meet nothing."""
    wall_r = view.limits.radius + min(margin, WALL_MARGIN_CAP)
    return np.any((p < view.bounds_lo + wall_r) | (p > view.bounds_hi - wall_r), axis=-1)


def _track_hits(view: View, p: np.ndarray, tau: np.ndarray, margin: float) -> np.ndarray:
    """Per sample of positions p [..., K, d] (m) at times tau [K] (s) after view.t: True if the MAV ball (radius +
    margin) meets a track's constant-velocity prediction (a). NaN samples meet nothing."""
    tracks = view.tracks
    rel = p[..., None, :] - tracks.position - tau[:, None, None] * tracks.velocity          # [..., K, M, d]
    reach = tracks.radius + (view.limits.radius + margin)
    return np.any(np.einsum("...md,...md->...m", rel, rel) < reach * reach, axis=-1)


def _static_bad(view: View, p: np.ndarray, margin: float, grid: bool) -> np.ndarray:
    bad = _wall_hits(view, p, margin)
    if grid:
        bad |= view.grid.collides(p, view.limits.radius + margin)
    return bad


def within_limits(v: np.ndarray, a: np.ndarray, v_max: float, a_max: float, tol: float = 1e-9) -> bool:
    """True if every sample's speed |v| <= v_max + tol (m/s) and |a| <= a_max + tol (m/s^2); v, a [K, d]."""
    v = np.asarray(v, dtype=float)
    a = np.asarray(a, dtype=float)
    return bool(np.all(np.einsum("kd,kd->k", v, v) <= (v_max + tol) ** 2)
                and np.all(np.einsum("kd,kd->k", a, a) <= (a_max + tol) ** 2))
