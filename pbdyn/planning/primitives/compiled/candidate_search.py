"""The local planner's candidate search in one compiled call (LocalPrimitives with the native ruckig batch).

search() returns for a rank-ordered list of candidates what LocalPrimitives' Python chunk loop returns (the
reference, kept as the path without the native library): it skips the candidates whose end point is blocked
(walls, OCCUPIED cells), then builds the others one at a time -- ruckig's calculator through the native library,
sampling and the limit rebuilds (_build_one, the rules of LocalPrimitives._build_many) -- takes each one's
positions to the world frame sample by sample with the wall and track screen (_screened_out: world_and_screen's
test, stopping at the first sample that fails), checks the grid (the compiled query of OccupancyGrid.collides), and
stops at the first clear one, whose velocities and accelerations alone are then taken to the world (_to_world).
Every float operation is the reference's, so the choice and the trajectory are the same bit for bit
(tests/test_native.py); what is saved is the interpreter's work between the kernels (one call per search instead of
a dozen), the builds of a chunk's candidates after the chosen one (the reference builds chunks to spread its
per-call cost; here a call costs little), and the frame changes of rejected candidates past their first conflict.
"""

from __future__ import annotations

import functools

import numpy as np

from pbdyn.jit import njit
from pbdyn.perception.grid import OCCUPIED, OccupancyGrid, _point_collides
from pbdyn.planning.primitives.compiled.candidate_kernels import _call_ruckig_build, _dot, _fma, _sq, peak_one
from pbdyn.planning.primitives.compiled.ruckig_sampling import PROFILE_WIDTH, sample_into


@njit(cache=True, nogil=True)
def _blocked(point, wall_lo, wall_hi, has_grid, grid, base):
    """True if the MAV ball at ``point`` [d] meets a wall (a coordinate below wall_lo or above wall_hi) or, when
    has_grid, an OCCUPIED cell (grid: OccupancyGrid.collision_query's arguments) -- checks.static_clear's test.
    base: scratch [d] (int64)."""
    for j in range(point.shape[0]):
        if point[j] < wall_lo[j] or point[j] > wall_hi[j]:
            return True
    if has_grid:
        return _point_collides(point, base, *grid)
    return False


@njit(cache=True, nogil=True)
def _grid_hit(pts, grid, base):
    """True if the MAV ball at any of the points [K, d] meets an OCCUPIED cell (OccupancyGrid.collides(...).any(),
    stopping at the first that does)."""
    for i in range(pts.shape[0]):
        if _point_collides(pts[i], base, *grid):
            return True
    return False


@njit(cache=True, nogil=True)
def _build_one(addr, frame_in, c, limits, counts_in, scratch, prof, dur, res, buf, t_sum):
    """Candidate c's rebuild stages (LocalPrimitives._build_many's rules; its Python loop is the reference): build
    with the per-axis limits (v_max, a_max); while a sample's |v| or |a| or a step bound exceeds its norm limit,
    rebuild with the limit scaled by safety * limit / peak (at most n_rebuilds times), then once with v_max /
    sqrt(d), a_max / sqrt(d); a build ruckig rejects or longer than the horizon goes straight to those. Samples as
    sampled_peaks takes them (sample_into, peak_one). Returns (the accepted trajectory's sample count, 0 if none;
    ruckig builds; the sample buffer [K, 3, d] holding its samples in its frame -- ``buf``, or a larger one when it
    had too few rows). scratch [6, d]: input buffers; prof, dur, res: the library's outputs; t_sum: scratch [7]."""
    d = frame_in.shape[2]
    v_max, a_max, tol, dt = limits[0], limits[1], limits[6], limits[8]
    last = counts_in[0] + 1
    for i in range(4):
        for j in range(d):
            scratch[i, j] = frame_in[i, c, j]
    lim_v = v_max
    lim_a = a_max
    stage = 0
    n_built = 0
    while True:
        if stage == last:
            lim_v = v_max / np.sqrt(d)
            lim_a = a_max / np.sqrt(d)
        scratch[4, 0] = lim_v
        scratch[5, 0] = lim_a
        _call_ruckig_build(addr, 1, d, scratch[0].ctypes.data, scratch[1].ctypes.data, scratch[2].ctypes.data,
                           scratch[3].ctypes.data, scratch[4].ctypes.data, scratch[5].ctypes.data, limits[2],
                           limits[3], prof.ctypes.data, dur.ctypes.data, res.ctypes.data)
        n_built += 1
        if (res[0] == 0 or res[0] == 1) and dur[0] <= limits[4]:
            n = max(2, np.int64(np.ceil(dur[0] / dt - 1e-9)) + 1)
            if n > buf.shape[0]:
                buf = np.empty((n, 3, d))
            sample_into(prof[0], dur[0], n, dt, buf, t_sum)
            v_peak, a_peak = peak_one(buf, n, dt, counts_in[2])
            if v_peak <= v_max + tol and a_peak <= a_max + tol:
                return n, n_built, buf
            if stage >= last:
                break
            if v_peak > v_max:
                lim_v *= limits[5] * v_max / v_peak
            if a_peak > a_max:
                lim_a *= limits[5] * a_max / a_peak
            stage += 1
        elif stage < last:
            stage = last
        else:
            break
    return 0, n_built, buf


@njit(cache=True, nogil=True)
def _screened_out(buf, n, b, p0, walls, track_pos, track_vel, reach2, t, dt, mm_mode, sq_order, pos):
    """world_and_screen's test for one candidate (samples buf[:n] in its frame b [d, d]): True if one of samples
    1..n-1 meets a wall or a track's prediction (the same float operations, stopping at the first sample that
    does). Writes the world positions of samples 1.. it reached to pos [>= n, d] (m)."""
    d = p0.shape[0]
    n_tracks = track_pos.shape[0]
    for k in range(1, n):
        x = buf[k, 0]
        for j in range(d):
            pj = _dot(x, b, j, d, mm_mode) + p0[j]
            pos[k, j] = pj
            if pj < walls[0, j] or pj > walls[1, j]:
                return True
        tau = (t + dt * k) - t
        for m in range(n_tracks):
            r0 = (pos[k, 0] - track_pos[m, 0]) - tau * track_vel[m, 0]
            r1 = (pos[k, 1] - track_pos[m, 1]) - tau * track_vel[m, 1]
            r2 = 0.0
            if d == 3:
                r2 = (pos[k, 2] - track_pos[m, 2]) - tau * track_vel[m, 2]
            if _sq(r0, r1, r2, d, sq_order) < reach2[m]:
                return True
    return False


@njit(cache=True, nogil=True)
def _to_world(buf, n, b, state, mm_mode):
    """The samples buf[:n] [n, 3, d] of a candidate in its frame b taken to the world: p, v, a [n, d] (m, m/s,
    m/s^2), sample 0 the MAV's state (state [3, d]) -- world_and_screen's rows for it."""
    d = state.shape[1]
    out = np.empty((3, n, d))
    for r in range(3):
        for j in range(d):
            out[r, 0, j] = state[r, j]
    for k in range(1, n):
        for r in range(3):
            x = buf[k, r]
            for j in range(d):
                w = _dot(x, b, j, d, mm_mode)
                if r == 0:
                    w = w + state[0, j]
                out[r, k, j] = w
    return out[0], out[1], out[2]


@njit(cache=True, nogil=True)
def search(addr, frame_in, bases, targets, vels, prune, limits, counts_in, position, velocity, acceleration,
           bounds_lo, bounds_hi, wall_r, track_pos, track_vel, track_radius, reach_r, has_grid, grid):
    """The first clear candidate of a rank-ordered list, built and checked one candidate at a time.

    Args:
        addr: the native library's build entry point (pbdyn.planning.primitives.native.ruckig_build_address).
        frame_in: [4, m, d] C-contiguous: the candidates' current velocity, current acceleration, target position
            and target velocity in their own frames (m/s, m/s^2, m, m/s; numpy's products); ignored when
            counts_in[3] is 1 (then computed here, frame_inputs).
        bases: [m, d, d] the candidates' frames (rows; world -> frame); targets: [m, d] their end points (m, world);
            vels: [m, d] their end velocities (m/s, world).
        prune: skip candidates whose end point is blocked (checks.static_clear) before building any.
        limits: [9] v_max (m/s), a_max (m/s^2), jerk (m/s^3), minimum duration (s), longest duration (s), the
            rebuild safety factor, the limit tolerance, t (s) and dt (s) of the view.
        counts_in: [4] int: the number of limit-scaled rebuilds, numpy's matmul mode and sum-of-squares order
            (candidate_kernels.numpy_orders), and 1 to compute frame_in here (frame_products_known), else 0.
        position, velocity, acceleration: the MAV's state [d] (m, m/s, m/s^2; sample 0 of every candidate).
        bounds_lo, bounds_hi: the arena box [d] (m); wall_r: a sample closer than this to its border meets a wall
            (m; the lowest admissible coordinate is bounds_lo + wall_r, the highest bounds_hi - wall_r).
        track_pos, track_vel: the tracks' means and velocities at t [M, d] (m, m/s); track_radius [M] (m); reach_r:
            added to a track's radius, the distance below which a sample meets its prediction (m).
        has_grid, grid: whether any cell is OCCUPIED, and OccupancyGrid.collision_query's arguments (a grid's
            query arguments of the same types when has_grid is False; unused then).
    Returns:
        (position of the chosen candidate in the list or -1, candidates counted as tried (the chosen one's
        position among those not pruned, plus one; or all of those), ruckig builds, and the chosen trajectory's
        samples p, v, a [K, d] (world; empty when none is clear)).
    """
    m, d = targets.shape[0], targets.shape[1]
    n_tracks = track_pos.shape[0]
    if (counts_in.shape[0] != 4 or position.shape[0] != d or velocity.shape[0] != d or acceleration.shape[0] != d
            or bounds_lo.shape[0] != d or bounds_hi.shape[0] != d or track_vel.shape[0] != n_tracks
            or track_radius.shape[0] != n_tracks or (n_tracks and (track_pos.shape[1] != d
                                                                   or track_vel.shape[1] != d))):
        raise ValueError("search: mismatched shapes")
    state = np.empty((3, d))
    walls = np.empty((2, d))
    for j in range(d):
        state[0, j] = position[j]
        state[1, j] = velocity[j]
        state[2, j] = acceleration[j]
        walls[0, j] = bounds_lo[j] + wall_r
        walls[1, j] = bounds_hi[j] - wall_r
    reach2 = np.empty(n_tracks)
    for i in range(n_tracks):
        reach = track_radius[i] + reach_r
        reach2[i] = reach * reach
    if counts_in[3] == 1:
        frame_in = frame_inputs(bases, targets, vels, state)
    if (frame_in.shape[0] != 4 or frame_in.shape[1] != m or frame_in.shape[2] != d or bases.shape[0] != m
            or vels.shape[0] != m or limits.shape[0] != 9):
        raise ValueError("search: mismatched shapes")
    scratch = np.zeros((6, d))
    prof = np.zeros((1, d, PROFILE_WIDTH))
    dur = np.zeros(1)
    res = np.zeros(1, dtype=np.int64)
    buf = np.empty((32, 3, d))
    pos = np.empty((32, d))
    t_sum = np.empty(7)
    base = np.empty(d, dtype=np.int64)
    n_built = 0
    tried = 0
    for c in range(m):
        if prune and _blocked(targets[c], walls[0], walls[1], has_grid, grid, base):
            continue
        tried += 1
        n, built, buf = _build_one(addr, frame_in, c, limits, counts_in, scratch, prof, dur, res, buf, t_sum)
        n_built += built
        if n == 0:
            continue
        if pos.shape[0] < n:
            pos = np.empty((buf.shape[0], d))
        if _screened_out(buf, n, bases[c], state[0], walls, track_pos, track_vel, reach2, limits[7], limits[8],
                         counts_in[1], counts_in[2], pos):
            continue
        if has_grid and _grid_hit(pos[1:n], grid, base):
            continue
        p, v, a = _to_world(buf, n, bases[c], state, counts_in[1])
        return c, tried, n_built, p, v, a
    empty = np.zeros((0, d))
    return -1, tried, n_built, empty, empty.copy(), empty.copy()


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


def frame_inputs_reference(bases, targets, vels, position, velocity, acceleration) -> np.ndarray:
    """frame_inputs in numpy (its reference twin, and what the planner uses where frame_products_known is False):
    [4, m, d] = bases @ velocity, bases @ acceleration, bases @ (target - position), bases @ end velocity (frames
    bases [m, d, d], targets and end velocities [m, d]; position, velocity, acceleration [d] in m, m/s, m/s^2)."""
    out = np.empty((4, targets.shape[0], bases.shape[-1]))
    out[0] = bases @ velocity
    out[1] = bases @ acceleration
    out[2] = (bases @ (targets - position)[:, :, None])[:, :, 0]
    out[3] = (bases @ vels[:, :, None])[:, :, 0]
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
        want = frame_inputs_reference(bases, targets, vels, state[0], state[1], state[2])
        got = frame_inputs(bases, targets, vels, state)
        if not all(np.array_equal(got[i], want[i]) for i in range(4)):
            return False
    return True
