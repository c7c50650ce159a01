"""The local planner's candidate search in one compiled call (LocalPrimitives with the native ruckig batch).

search() does for a rank-ordered list of candidates what LocalPrimitives' Python chunk loop does (the reference,
kept as the path without the native library): skip the candidates whose end point is blocked (walls, OCCUPIED
cells), build the others chunk by chunk (candidate_kernels.build_candidates: ruckig's calculator through the native
library, sampling and the limit rebuilds), take them to the world frame with the wall and track screen
(world_and_screen) and check the grid (the compiled query of OccupancyGrid.collides), returning the first clear
candidate. Every float operation is the reference's, so the choice and the trajectory are the same bit for bit
(tests/test_candidate_search.py); what is saved is the interpreter's work between the kernels: on a typical step
one call instead of a dozen.
"""

from __future__ import annotations

import functools

import numpy as np
from numba import njit

from pbdyn.perception.grid import OCCUPIED, OccupancyGrid, _collides
from pbdyn.planning.candidate_kernels import build_candidates, world_and_screen


@njit(cache=True, nogil=True)
def _blocked(point, wall_lo, wall_hi, has_grid, grid):
    """True if the MAV ball at ``point`` [d] meets a wall (a coordinate below wall_lo or above wall_hi) or, when
    has_grid, an OCCUPIED cell (grid: OccupancyGrid.collision_query's arguments) -- checks.static_clear's test."""
    for j in range(point.shape[0]):
        if point[j] < wall_lo[j] or point[j] > wall_hi[j]:
            return True
    if has_grid:
        return _collides(point.reshape(1, -1), *grid)[0]
    return False


@njit(cache=True, nogil=True)
def search(addr, frame_in, bases, targets, prune, chunks, limits, counts_in, state, walls, tracks, reach2, has_grid,
           grid):
    """The first clear candidate of a rank-ordered list.

    Args:
        addr: the native library's build entry point (pbdyn.planning.native.ruckig_build_address).
        frame_in: [4, m, d] C-contiguous: the candidates' current velocity, current acceleration, target position
            and target velocity in their own frames (m/s, m/s^2, m, m/s), as build_candidates takes them.
        bases: [m, d, d] the candidates' frames (rows; world -> frame); targets: [m, d] their end points (m, world).
        prune: skip candidates whose end point is blocked (checks.static_clear) before building any.
        chunks: chunk sizes (the last one repeats) in which the remaining candidates are built and checked.
        limits: [9] v_max (m/s), a_max (m/s^2), jerk (m/s^3), minimum duration (s), longest duration (s), the
            rebuild safety factor, the limit tolerance, t (s) and dt (s) of the view.
        counts_in: [3] int: the number of limit-scaled rebuilds, numpy's matmul mode and sum-of-squares order
            (candidate_kernels.numpy_orders).
        state: [3, d] the MAV's position, velocity, acceleration (m, m/s, m/s^2; sample 0 of every candidate).
        walls: [2, d] lowest and highest admissible sample coordinate (m).
        tracks: [2, M, d] the tracks' means and velocities at t (m, m/s); reach2: [M] squared reach (m^2).
        has_grid, grid: whether any cell is OCCUPIED, and OccupancyGrid.collision_query's arguments (a grid's
            query arguments of the same types when has_grid is False; unused then).
    Returns:
        (position of the chosen candidate in the list or -1, candidates counted as tried (the chosen one's
        position among those not pruned, plus one; or all of those), ruckig builds, and the chosen trajectory's
        samples p, v, a [K, d] (world; empty when none is clear)).
    """
    m, d = targets.shape[0], targets.shape[1]
    if (frame_in.shape[0] != 4 or frame_in.shape[1] != m or frame_in.shape[2] != d or bases.shape[0] != m
            or limits.shape[0] != 9 or counts_in.shape[0] != 3 or state.shape[0] != 3 or walls.shape[0] != 2
            or tracks.shape[0] != 2 or tracks.shape[1] != reach2.shape[0] or chunks.shape[0] < 1):
        raise ValueError("search: mismatched shapes")
    rest = np.empty(m, dtype=np.int64)
    n_rest = 0
    for c in range(m):
        if not (prune and _blocked(targets[c], walls[0], walls[1], has_grid, grid)):
            rest[n_rest] = c
            n_rest += 1
    n_built = 0
    lo = 0
    k = 0
    while lo < n_rest:
        size = chunks[min(k, chunks.shape[0] - 1)]
        k += 1
        sel = rest[lo:min(lo + size, n_rest)]
        rows, frame, counts, built = build_candidates(
            addr, frame_in[0][sel], frame_in[1][sel], frame_in[2][sel], frame_in[3][sel], limits[0], limits[1],
            limits[2], limits[3], limits[4], counts_in[0], limits[5], limits[6], limits[8], counts_in[2])
        n_built += built
        if rows.shape[0] > 0:
            p, v, a, bad = world_and_screen(frame, counts, bases[sel[rows]], state[0], state[1], state[2], walls[0],
                                            walls[1], tracks[0], tracks[1], reach2, limits[7], limits[8],
                                            counts_in[1], counts_in[2])
            for i in range(rows.shape[0]):
                if bad[i]:
                    continue
                n = counts[i]
                if has_grid and _collides(p[i, 1:n], *grid).any():
                    continue
                return (sel[rows[i]], lo + rows[i] + 1, n_built, p[i, :n].copy(), v[i, :n].copy(),
                        a[i, :n].copy())
        lo += size
    empty = np.zeros((0, d))
    return -1, n_rest, n_built, empty, empty.copy(), empty.copy()


@functools.cache
def no_grid_query() -> tuple:
    """Grid query arguments of the types OccupancyGrid.collision_query returns, for search() calls on a grid with
    no OCCUPIED cell (has_grid False: never read; the same types keep to one compiled version of search)."""
    grid = OccupancyGrid([0.0, 0.0], [1.0, 1.0])
    grid.cells[1, 1] = OCCUPIED
    return grid.collision_query(1.0)
