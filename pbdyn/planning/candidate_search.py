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

from pbdyn.planning.candidate_kernels import _fma

from pbdyn.perception.grid import OCCUPIED, OccupancyGrid, _collides
from pbdyn.planning.candidate_kernels import _sq, build_candidates, world_and_screen


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
def search(addr, frame_in, bases, targets, vels, prune, chunks, limits, counts_in, state, walls, tracks, reach2,
           has_grid, grid):
    """The first clear candidate of a rank-ordered list.

    Args:
        addr: the native library's build entry point (pbdyn.planning.native.ruckig_build_address).
        frame_in: [4, m, d] C-contiguous: the candidates' current velocity, current acceleration, target position
            and target velocity in their own frames (m/s, m/s^2, m, m/s), as build_candidates takes them (numpy's
            products); ignored when counts_in[3] is 1 (then computed here, frame_inputs).
        bases: [m, d, d] the candidates' frames (rows; world -> frame); targets: [m, d] their end points (m, world);
            vels: [m, d] their end velocities (m/s, world).
        prune: skip candidates whose end point is blocked (checks.static_clear) before building any.
        chunks: chunk sizes (the last one repeats) in which the remaining candidates are built and checked.
        limits: [9] v_max (m/s), a_max (m/s^2), jerk (m/s^3), minimum duration (s), longest duration (s), the
            rebuild safety factor, the limit tolerance, t (s) and dt (s) of the view.
        counts_in: [4] int: the number of limit-scaled rebuilds, numpy's matmul mode and sum-of-squares order
            (candidate_kernels.numpy_orders), and 1 to compute frame_in here (frame_products_known), else 0.
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
    if counts_in.shape[0] != 4 or state.shape[0] != 3 or state.shape[1] != d:
        raise ValueError("search: mismatched shapes")
    if counts_in[3] == 1:
        frame_in = frame_inputs(bases, targets, vels, state)
    if (frame_in.shape[0] != 4 or frame_in.shape[1] != m or frame_in.shape[2] != d or bases.shape[0] != m
            or vels.shape[0] != m or limits.shape[0] != 9 or walls.shape[0] != 2 or tracks.shape[0] != 2
            or tracks.shape[1] != reach2.shape[0] or chunks.shape[0] < 1):
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


@njit(cache=True, nogil=True)
def no_candidate_proof(position, velocity, bounds_lo, bounds_hi, track_pos, track_vel, track_radius, n_k, dt, a_max,
                       wall_r, reach_r, sq_order):
    """LocalPrimitives.none_can_be_clear: for k = 1..n_k, does the ball of radius a_max dt^2 (k^2/2 + k/4) + 1e-6
    around position + k dt velocity lie in a wall (within wall_r of bounds_lo / bounds_hi) or inside one track's
    prediction (track_pos + k dt track_vel, radius track_radius + reach_r)? The numpy evaluation's float
    operations, element by element (m, m/s, m/s^2, s)."""
    d = position.shape[0]
    n_m = track_pos.shape[0]
    if track_vel.shape[0] != n_m or track_radius.shape[0] != n_m:
        raise ValueError("no_candidate_proof: mismatched shapes")
    centre = np.empty((n_k, d))
    ball = np.empty(n_k)
    scale = a_max * dt * dt
    for i in range(n_k):
        k = float(i + 1)
        kdt = k * dt
        ball[i] = scale * (0.5 * k * k + 0.25 * k) + 1e-6
        for j in range(d):
            centre[i, j] = position[j] + kdt * velocity[j]
            if centre[i, j] + ball[i] < bounds_lo[j] + wall_r or centre[i, j] - ball[i] > bounds_hi[j] - wall_r:
                return True
    for i in range(n_k):
        kdt = float(i + 1) * dt
        for m in range(n_m):
            r0 = centre[i, 0] - (track_pos[m, 0] + kdt * track_vel[m, 0])
            r1 = centre[i, 1] - (track_pos[m, 1] + kdt * track_vel[m, 1])
            r2 = 0.0
            if d == 3:
                r2 = centre[i, 2] - (track_pos[m, 2] + kdt * track_vel[m, 2])
            if np.sqrt(_sq(r0, r1, r2, d, sq_order)) + ball[i] < track_radius[m] + reach_r:
                return True
    return False


@njit(inline="always")
def _matvec_row(b, x, i, d):
    """sum_m b[i, m] x[m] as numpy's stacked matrix-vector product gives it here: the fused chain from the last
    term, fma(b[i, 0], x[0], ... fma(b[i, d-2], x[d-2], b[i, d-1] x[d-1])) (probed: frame_products_known)."""
    acc = b[i, d - 1] * x[d - 1]
    for m in range(d - 2, -1, -1):
        acc = _fma(b[i, m], x[m], acc)
    return acc


@njit(cache=True, nogil=True)
def frame_inputs(bases, targets, vels, state):
    """The candidates' frame inputs [4, m, d] of search(): bases @ velocity, bases @ acceleration,
    bases @ (target - position), bases @ end velocity (state: [3, d] position, velocity, acceleration)."""
    m, d = targets.shape[0], targets.shape[1]
    out = np.empty((4, m, d))
    rel = np.empty(d)
    for c in range(m):
        b = bases[c]
        for j in range(d):
            rel[j] = targets[c, j] - state[0, j]
        for i in range(d):
            out[0, c, i] = _matvec_row(b, state[1], i, d)
            out[1, c, i] = _matvec_row(b, state[2], i, d)
            out[2, c, i] = _matvec_row(b, rel, i, d)
            out[3, c, i] = _matvec_row(b, vels[c], i, d)
    return out


@functools.cache
def frame_products_known(d: int) -> bool:
    """True if frame_inputs gives numpy's products bit for bit here (probed on random frames and vectors, stacks of
    1 to 300): the planner then lets search() compute them; otherwise it keeps numpy's (a machine whose BLAS sums
    in another order)."""
    rng = np.random.default_rng(20261127)
    for n in (1, 2, 7, 71, 300):
        bases = rng.normal(size=(n, d, d)) * 10.0 ** rng.integers(-3, 3, size=(n, 1, 1))
        state = rng.normal(size=(3, d)) * 10.0 ** rng.integers(-2, 3, size=(3, 1))
        targets = state[0] + rng.normal(size=(n, d)) * 3.0
        vels = rng.normal(size=(n, d)) * 10.0 ** rng.integers(-3, 3, size=(n, 1))
        want = (bases @ state[1], bases @ state[2], (bases @ (targets - state[0])[:, :, None])[:, :, 0],
                (bases @ vels[:, :, None])[:, :, 0])
        got = frame_inputs(bases, targets, vels, state)
        if not all(np.array_equal(got[i], want[i]) for i in range(4)):
            return False
    return True
