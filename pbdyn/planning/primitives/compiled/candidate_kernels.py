"""Compiled evaluation of motion-primitive candidates (numba): limit peaks, frame -> world, and the wall and track
checks (pbdyn.planning.checks (a), (c)), with the float operations numpy performs for the same array expressions.

Numpy's results for these expressions depend on how it evaluates them on the machine: a stacked matrix product goes
to BLAS, which may fuse multiply-adds (fma), and einsum sums three squares in an order set by its SIMD kernels. The
orders numpy uses here are probed once (numpy_orders) and the kernels repeat them, so the planners' trajectories and
decisions are the ones numpy gives, bit for bit (tests/test_candidate_kernels.py compares both). A machine whose
numpy uses an order not known here gets a warning and the first known order: its results stay deterministic.
"""

from __future__ import annotations

import functools
import warnings

import numpy as np

from pbdyn.jit import intrinsic, njit
from pbdyn.planning.primitives.compiled.ruckig_sampling import sample_profiles


@intrinsic
def _fma(typingctx, a, b, c):
    """a * b + c rounded once (IEEE fused multiply-add)."""
    from llvmlite import ir
    from numba import types

    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        fnty = ir.FunctionType(ir.DoubleType(), [ir.DoubleType()] * 3)
        return builder.call(builder.module.declare_intrinsic("llvm.fma", [ir.DoubleType()], fnty), args)

    return sig, codegen


@njit(cache=True, nogil=True)
def fma(a: float, b: float, c: float) -> float:
    """a * b + c with one rounding."""
    return _fma(a, b, c)


@njit(inline="always")
def _sq(x0, x1, x2, d, order):
    """x0^2 + x1^2 (+ x2^2 when d == 3) summed in numpy einsum's order: 0 = left to right, 1 = (x0^2 + x2^2) + x1^2."""
    if d == 2:
        return x0 * x0 + x1 * x1
    if order == 0:
        return (x0 * x0 + x1 * x1) + x2 * x2
    return (x0 * x0 + x2 * x2) + x1 * x1


@njit(inline="always")
def _dot(x, b, j, d, mode):
    """sum_m x[m] b[m, j] as numpy's matmul gives it: mode 0 = products summed left to right, 1 = fused chain
    fma(x[d-1], b[d-1, j], ... fma(x[1], b[1, j], x[0] b[0, j]))."""
    acc = x[0] * b[0, j]
    for m in range(1, d):
        if mode == 1:
            acc = _fma(x[m], b[m, j], acc)
        else:
            acc = acc + x[m] * b[m, j]
    return acc


@njit(cache=True, nogil=True)
def peaks(samples: np.ndarray, counts: np.ndarray, dt: float, sq_order: int):
    """Per trajectory of samples [C, K, 3 (p, v, a), d] (counts[c] valid): (peak speed over samples 1.. (m/s), peak
    acceleration (m/s^2): the larger of the samples' |a| and the step bound). The step bound is the least
    acceleration under which consecutive samples are reachable, max over steps of |v_k+1 - v_k| / dt and
    4 |p_k+1 - p_k - (v_k + v_k+1) dt / 2| / dt^2 (the plan contract's step bounds, pbdyn.sim.contract); its
    squared norms are summed axis by axis in order, as numpy's add.reduce sums so few terms."""
    n_traj = samples.shape[0]
    if counts.shape[0] != n_traj or counts.max() > samples.shape[1]:
        raise ValueError("peaks: mismatched shapes")
    v_peak = np.empty(n_traj)
    a_peak = np.empty(n_traj)
    for c in range(n_traj):
        v_peak[c], a_peak[c] = peak_one(samples[c], counts[c], dt, sq_order)
    return v_peak, a_peak


@njit(cache=True, nogil=True)
def peak_one(s_c: np.ndarray, n: int, dt: float, sq_order: int):
    """peaks for one trajectory of samples s_c [>= n, 3, d] (n valid): (peak speed, peak acceleration)."""
    d = s_c.shape[2]
    sv_max = 0.0
    sa_max = 0.0
    dv_max = 0.0
    gap_max = 0.0
    for k in range(1, n):
        v = s_c[k, 1]
        a = s_c[k, 2]
        sv = _sq(v[0], v[1], v[d - 1], d, sq_order)
        sa = _sq(a[0], a[1], a[d - 1], d, sq_order)
        sv_max = max(sv_max, sv)
        sa_max = max(sa_max, sa)
    for k in range(n - 1):
        dv2 = 0.0
        gap2 = 0.0
        for i in range(d):
            v0 = s_c[k, 1, i]
            v1 = s_c[k + 1, 1, i]
            dv = v1 - v0
            gap = s_c[k + 1, 0, i] - s_c[k, 0, i] - 0.5 * (v0 + v1) * dt
            dv2 += dv * dv
            gap2 += gap * gap
        dv_max = max(dv_max, dv2)
        gap_max = max(gap_max, gap2)
    step = max(np.sqrt(dv_max) / dt, 4.0 * np.sqrt(gap_max) / (dt * dt))
    return np.sqrt(sv_max), max(np.sqrt(sa_max), step)


@njit(cache=True, nogil=True)
def sampled_peaks(prof: np.ndarray, duration: np.ndarray, dt: float, sq_order: int):
    """The samples every dt of trajectories (profile rows prof [C, d, PROFILE_WIDTH], durations [C] (s)) that
    cover their durations, max(2, ceil(duration / dt - 1e-9) + 1) of them (past the duration the end velocity is
    held), and their limit peaks: (samples [C, K, 3, d] in the trajectories' frames, sample counts [C], peak
    speeds [C], peak accelerations [C]) -- sample_profiles and peaks in one call."""
    counts = np.empty(duration.shape[0], dtype=np.int64)
    for c in range(duration.shape[0]):
        counts[c] = max(2, np.int64(np.ceil(duration[c] / dt - 1e-9)) + 1)
    samples = sample_profiles(prof, duration, counts, dt)
    v_peak, a_peak = peaks(samples, counts, dt, sq_order)
    return samples, counts, v_peak, a_peak


@njit(cache=True, nogil=True)
def world_and_screen(frame, counts, bases, p0, v0, a0, wall_lo, wall_hi, track_pos, track_vel, reach2, t, dt,
                     mm_mode, sq_order):
    """Candidates' samples in the world frame, and which of them meet a wall or a track's prediction.

    Args:
        frame: samples [C, K, 3 (p, v, a), d] in each candidate's frame (origin at the MAV), counts[c] valid.
        counts: sample counts [C].
        bases: the candidates' frames [C, d, d] (rows; world -> frame), so world = frame @ basis.
        p0, v0, a0: the MAV's position, velocity, acceleration [d] (sample 0 of every candidate).
        wall_lo, wall_hi: [d] a sample below wall_lo or above wall_hi on an axis meets a wall (m).
        track_pos, track_vel: the tracks' means at time t [M, d] (m, m/s); reach2: [M] squared distance (m^2)
            below which a sample meets a track's constant-velocity prediction.
        t: time of sample 0 (s); dt: sample spacing (s).
        mm_mode, sq_order: numpy's orders (numpy_orders).
    Returns:
        p, v, a [C, K, d] (world, m, m/s, m/s^2; zeros past counts[c]) and bad [C]: True if one of samples
        1..counts[c]-1 meets a wall or a track (checks.py (c), (a)).
    """
    n_c, n_k, _, d = frame.shape
    if (counts.shape[0] != n_c or bases.shape[0] != n_c or counts.max() > n_k or counts.min() < 1
            or track_vel.shape[0] != track_pos.shape[0] or reach2.shape[0] != track_pos.shape[0]):
        raise ValueError("world_and_screen: mismatched shapes")
    out = np.zeros((3, n_c, n_k, d))
    bad = np.zeros(n_c, dtype=np.bool_)
    n_tracks = track_pos.shape[0]
    for c in range(n_c):
        b = bases[c]
        for j in range(d):
            out[0, c, 0, j] = p0[j]
            out[1, c, 0, j] = v0[j]
            out[2, c, 0, j] = a0[j]
        for k in range(1, counts[c]):
            for r in range(3):
                x = frame[c, k, r]
                for j in range(d):
                    w = _dot(x, b, j, d, mm_mode)
                    if r == 0:
                        w = w + p0[j]
                    out[r, c, k, j] = w
        hit = False
        for k in range(1, counts[c]):
            for j in range(d):
                pj = out[0, c, k, j]
                if pj < wall_lo[j] or pj > wall_hi[j]:
                    hit = True
            if hit:
                break
        if not hit and n_tracks:
            for k in range(1, counts[c]):
                tau = (t + dt * k) - t
                p = out[0, c, k]
                for m in range(n_tracks):
                    r0 = (p[0] - track_pos[m, 0]) - tau * track_vel[m, 0]
                    r1 = (p[1] - track_pos[m, 1]) - tau * track_vel[m, 1]
                    r2 = 0.0
                    if d == 3:
                        r2 = (p[2] - track_pos[m, 2]) - tau * track_vel[m, 2]
                    if _sq(r0, r1, r2, d, sq_order) < reach2[m]:
                        hit = True
                        break
                if hit:
                    break
        bad[c] = hit
    return out[0], out[1], out[2], bad


@njit(cache=True)
def _matmul_probe(x, b, mode):
    n_c, n_k, _, d = x.shape
    out = np.empty(x.shape)
    for c in range(n_c):
        for k in range(n_k):
            for r in range(3):
                for j in range(d):
                    out[c, k, r, j] = _dot(x[c, k, r], b[c], j, d, mode)
    return out


@functools.cache
def numpy_orders(d: int) -> tuple[int, int]:
    """(mm_mode, sq_order) of numpy on this machine for d-dimensional candidates, found by evaluating the planners'
    expressions on fixed random arrays: the stacked frame -> world product and the two einsum sums of squares."""
    rng = np.random.default_rng(20261125)
    x = rng.normal(size=(6, 9, 3, d)) * 10.0 ** rng.integers(-3, 3, size=(6, 9, 3, 1))
    b = rng.normal(size=(6, d, d))
    want = x @ b[:, None]
    modes = [m for m in (1, 0) if np.array_equal(_matmul_probe(x, b, m), want)]
    orders = [0]
    if d == 3:
        s = x[:, 1:, 1:]
        e1 = np.einsum("nkij,nkij->nki", s, s)
        e2 = np.einsum("...md,...md->...m", x, x)
        orders = [o for o, sq in ((0, (x[..., 0] * x[..., 0] + x[..., 1] * x[..., 1]) + x[..., 2] * x[..., 2]),
                                  (1, (x[..., 0] * x[..., 0] + x[..., 2] * x[..., 2]) + x[..., 1] * x[..., 1]))
                  if np.array_equal(e1, sq[:, 1:, 1:]) and np.array_equal(e2, sq)]
    if not modes or not orders:
        warnings.warn("numpy evaluates the planners' matrix products or sums of squares in an order pbdyn does not "
                      "know: compiled candidates may differ from numpy's in the last bits (still deterministic)",
                      RuntimeWarning, stacklevel=2)
    return (modes or [1])[0], (orders or [0])[0]


@intrinsic
def _call_ruckig_build(typingctx, addr, n, d, cur_v, cur_a, tgt_p, tgt_v, lim_v, lim_a, jerk, min_duration, prof,
                       duration, result):
    """Call the native library's pbdyn_ruckig_build at ``addr`` (pbdyn.planning.primitives.native) with the arrays' data
    pointers (uintp); its return value."""
    from llvmlite import ir
    from numba import types

    ptr = types.uintp
    sig = types.int32(ptr, types.int64, types.int64, ptr, ptr, ptr, ptr, ptr, ptr, types.float64, types.float64,
                      ptr, ptr, ptr)

    def codegen(context, builder, signature, args):
        i64, dbl, vp = ir.IntType(64), ir.DoubleType(), ir.IntType(8).as_pointer()
        fnty = ir.FunctionType(ir.IntType(32), [i64, i64] + [vp] * 6 + [dbl, dbl] + [vp] * 3)
        fn = builder.inttoptr(args[0], fnty.as_pointer())
        a = list(args[1:])
        call_args = (a[:2] + [builder.inttoptr(x, vp) for x in a[2:8]] + a[8:10]
                     + [builder.inttoptr(x, vp) for x in a[10:]])
        return builder.call(fn, call_args)

    return sig, codegen
