"""Compiled A* of the global motion primitives planner (thesis A-1, Algorithm 2): GlobalPrimitives(search="compiled").

The norm-lattice search (accel_grid "norm_lattice", heuristic "lqmt", packed int64 node keys) of
GlobalPrimitives._search_reference / _expand (the Python search, its reference twin) in one numba call per plan
(search_kernel): nodes in arrays grown by doubling, a 4-ary heap popped in the order of the Python search's heap tuples
(f, h, insertion counter; all distinct, so any heap pops them alike), one open-addressing table of the keys holding
best_g (-1 once closed) behind a bit filter of the closed keys, and per child and sample (every dt) the wall box, the
tracks' constant-velocity predictions within the horizon (thesis eq. A-2), the OCCUPIED cells (eq. A-3:
astar_static.StaticScreen's masks, its band cells listing their OCCUPIED neighbours, band_lists) and the goal ball, with
first_goal / first_bad, the goal-node cut and the root's exact children (GlobalPrimitives.root_children). The heuristic
is astar_heuristic.lqmt_lower_bound per child (_lqmt). The kernel returns the node arrays; CompiledSearch.run hands the
found path to GlobalPrimitives._trajectory.

Float operations are the Python search's, in its order, so the search expands the same nodes and returns the same
path bit for bit where numpy's own orders are known: einsum's sums of two or three products, the 1-D dot product
and the heuristic's matrix product delta @ V^T (BLAS: gemm, or gemv for a single row, with or without fused
multiply-adds) are probed once per velocity set (numpy_modes) and repeated. Where BLAS evaluates some entries
another way (numpy_modes' ``exact`` False), h may differ in its last bits, and with it the order of nodes whose f
ties to the last bit. tests/test_astar_compiled.py compares both searches on views of real trials.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from pbdyn.jit import njit
from pbdyn.planning.primitives.astar_goal import GOAL_TOL
from pbdyn.planning.primitives.astar_heuristic import _RATIOS
from pbdyn.planning.primitives.compiled.candidate_kernels import _fma

STATUSES = ("found", "exhausted", "budget")   # the kernel's status codes 0, 1, 2 (GlobalPrimitives.last_status)
_EMPTY = -1                                   # key of an empty table slot and of a node without a key (goal nodes)


# ---------------------------------------------------------------- numpy's summation orders

@njit(cache=True, nogil=True)
def _esum(a0, a1, a2, b0, b1, b2, d, order):
    """a . b [d <= 3] as numpy's einsum("nd,nd->n") sums it: left to right, or (order 1, d = 3)
    (a0 b0 + a2 b2) + a1 b1 (its two-lane SIMD kernel)."""
    if d == 2:
        return a0 * b0 + a1 * b1
    if order == 0:
        return (a0 * b0 + a1 * b1) + a2 * b2
    return (a0 * b0 + a2 * b2) + a1 * b1


@njit(cache=True, nogil=True)
def _mdot(a0, a1, a2, b0, b1, b2, d, mode):
    """a . b [d <= 3] as a BLAS dot / gemm / gemv evaluates it: mode 0 products summed left to right; 1 the fused
    chain fma(a2, b2, fma(a1, b1, a0 b0)); 2 the contracted expression fma(a2, b2, fma(a0, b0, a1 b1))."""
    if mode == 0:
        acc = a0 * b0 + a1 * b1
        return acc + a2 * b2 if d == 3 else acc
    if mode == 1:
        acc = _fma(a1, b1, a0 * b0)
    else:
        acc = _fma(a0, b0, a1 * b1)
    return _fma(a2, b2, acc) if d == 3 else acc


@njit(cache=True)
def _probe_einsum(x, y, order):
    out = np.empty(x.shape[0])
    d = x.shape[1]
    for i in range(x.shape[0]):
        out[i] = _esum(x[i, 0], x[i, 1], x[i, d - 1], y[i, 0], y[i, 1], y[i, d - 1], d, order)
    return out


@njit(cache=True)
def _probe_matmul(x, b, mode):
    d = x.shape[1]
    out = np.empty((x.shape[0], b.shape[0]))
    for i in range(x.shape[0]):
        for k in range(b.shape[0]):
            out[i, k] = _mdot(x[i, 0], x[i, 1], x[i, d - 1], b[k, 0], b[k, 1], b[k, d - 1], d, mode)
    return out


def numpy_modes(velocity_set: np.ndarray, max_rows: int) -> tuple[int, int, int, int, bool]:
    """(sq_order, gemm_mode, gemv_mode, dot_mode, exact): how numpy evaluates the planner's expressions on this
    machine with the velocity set [V, d] (m/s): einsum's sums (_esum's order), delta @ V^T for 2..max_rows rows
    (gemm) and for one (gemv), and a 1-D x @ x (_mdot's modes), each the one that agrees with numpy on most
    entries of fixed random arrays. exact: the sums and the products' row maxima (all the heuristic takes of them)
    agree everywhere; else the heuristic may differ from numpy's in the last bits. (OpenBLAS on this project's
    AVX-512 machine computes a few entries of its edge tiles with one fused multiply-add fewer, for V = 389: 3D at
    6 m/s; they belong to velocities inside the set's hull, never a row's maximum.) Cached."""
    vset = np.ascontiguousarray(velocity_set, dtype=float)
    return _numpy_modes(vset.shape[1], vset.tobytes(), int(max_rows))


@functools.cache
def _numpy_modes(d: int, vset_bytes: bytes, max_rows: int) -> tuple[int, int, int, int, bool]:
    vset = np.frombuffer(vset_bytes, dtype=float).reshape(-1, d)
    rng = np.random.default_rng(20260117)
    n_x = max(max_rows, 400)
    x = rng.normal(size=(n_x, d)) * 10.0 ** rng.integers(-2, 3, size=(n_x, 1))
    y = rng.normal(size=(n_x, d)) * 10.0 ** rng.integers(-2, 3, size=(n_x, 1))
    if len(vset) == 0:
        vset = rng.normal(size=(40, d))

    def best(agree, modes):      # (mode with the most agreeing entries, all of them agree)
        score = {m: agree(m) for m in modes}
        m = max(modes, key=lambda k: score[k])
        return m, score[m] == 1.0

    pairs = ((x, x), (x, y), (y, y))
    sq_order, ok_sq = best(lambda o: min(np.mean(np.einsum("nd,nd->n", a, b) == _probe_einsum(a, b, o))
                                         for a, b in pairs), (0, 1) if d == 3 else (0,))
    gemm, _ = best(lambda m: min(np.mean(x[:n] @ vset.T == _probe_matmul(x[:n], vset, m)) for n in (2, 3, 29, 123)),
                   (1, 0, 2))
    ok_gemm = all(np.array_equal((x[:n] @ vset.T).max(axis=1), _probe_matmul(x[:n], vset, gemm).max(axis=1))
                  for n in range(2, max_rows + 1))
    gemv, _ = best(lambda m: np.mean([np.array_equal(x[i:i + 1] @ vset.T, _probe_matmul(x[i:i + 1], vset, m))
                                      for i in range(400)]), (2, 1, 0))
    ok_gemv = all((x[i:i + 1] @ vset.T).max() == _probe_matmul(x[i:i + 1], vset, gemv).max() for i in range(400))
    dot, ok_dot = best(lambda m: np.mean([float(r @ r) == _probe_matmul(r[None], r[None], m)[0, 0] for r in x[:400]]),
                       (1, 0, 2))
    return sq_order, gemm, gemv, dot, bool(ok_sq and ok_gemm and ok_gemv and ok_dot)


# ---------------------------------------------------------------- heuristic (astar_heuristic.lqmt_lower_bound)

@njit(cache=True, nogil=True)
def _lqmt(x0, x1, x2, u0, u1, u2, d, goal_radius, rho, v_max, a_max, vset, ratios, sq_order, mm_mode):
    """lqmt_lower_bound of one state: offset x = p_goal - p (m) and velocity u (m/s), components 2 unused when
    d = 2; vset [V, d] (m/s; V = 0: no lattice bound); ratios: astar_heuristic._RATIOS. mm_mode: the order of
    delta @ V^T (gemm for several rows, gemv for one). Cost units (m/s^2)^2 s."""
    dist = math.sqrt(_esum(x0, x1, x2, x0, x1, x2, d, sq_order))
    gap = dist - goal_radius
    vv = _esum(u0, u1, u2, u0, u1, u2, d, sq_order)
    dv = _esum(x0, x1, x2, u0, u1, u2, d, sq_order)
    # min_time_bound(gap, |u|, v_max, a_max)
    dst = max(gap, 0.0)
    s0 = min(math.sqrt(vv), v_max)
    t1 = (v_max - s0) / a_max
    d1 = (s0 + 0.5 * a_max * t1) * t1
    if dst <= d1:
        t_lb = (math.sqrt(s0 * s0 + 2.0 * a_max * dst) - s0) / a_max
    else:
        t_lb = t1 + (dst - d1) / v_max
    n_v = vset.shape[0]
    if n_v:
        best = -np.inf
        for k in range(n_v):
            val = _mdot(x0, x1, x2, vset[k, 0], vset[k, 1], vset[k, d - 1], d, mm_mode)
            if val > best:
                best = val
        support = max(best, dv) / max(dist, 1e-300)
        t_lb = max(t_lb, gap / max(support, 1e-12))
    t_lb = max(t_lb, 1e-9)
    ratio = dv / max(vv, 1e-300)
    n_i = ratios.shape[0] - 1
    h = np.inf
    for k in range(n_i):
        ta = t_lb * ratios[k]
        tb = t_lb * ratios[k + 1]
        tau = min(max(ratio, ta), tb)
        e0 = x0 - u0 * tau
        e1 = x1 - u1 * tau
        e2 = x2 - u2 * tau
        g = max(math.sqrt(_esum(e0, e1, e2, e0, e1, e2, d, sq_order)) - goal_radius, 0.0)
        h = min(h, 3.0 * g * g / (tb * tb * tb) + rho * ta)
    h = min(h, rho * (t_lb * ratios[n_i]))
    return h if gap > 0 else 0.0


@njit(cache=True, nogil=True)
def lqmt_batch(delta, vel, goal_radius, rho, v_max, a_max, vset, ratios, sq_order, mm_mode):
    """_lqmt per row of delta, vel [N, d] (m, m/s): lqmt_lower_bound(delta, vel, ...) [N] (tests)."""
    d = delta.shape[1]
    out = np.empty(delta.shape[0])
    for i in range(delta.shape[0]):
        out[i] = _lqmt(delta[i, 0], delta[i, 1], delta[i, d - 1], vel[i, 0], vel[i, 1], vel[i, d - 1], d,
                       goal_radius, rho, v_max, a_max, vset, ratios, sq_order, mm_mode)
    return out


# ---------------------------------------------------------------- checks

@njit(cache=True, nogil=True)
def band_lists(maybe, surely, occ, gshape, gstrides, near):
    """The grid screen per cell, from StaticScreen's masks maybe, surely, occupied (flattened in C order, gstrides
    in cells) and its neighbourhood near [W, d]: kind [cells] (0 no OCCUPIED cell within reach, 2 surely within
    reach, 1 the band: its OCCUPIED neighbours' integer coordinates are cells[start[f]:start[f + 1]] [L, d])."""
    n = maybe.shape[0]
    d = gshape.shape[0]
    kind = np.zeros(n, np.int8)
    start = np.zeros(n + 1, np.int64)
    idx = np.empty(d, np.int64)
    cells = np.empty((0, d), np.int64)
    for fill in range(2):                          # count, then fill
        m = 0
        for f in range(n):
            start[f] = m
            if surely[f]:
                kind[f] = 2
                continue
            if not maybe[f]:
                continue
            kind[f] = 1
            r = f
            for j in range(d):
                idx[j] = r // gstrides[j]
                r -= idx[j] * gstrides[j]
            for w in range(near.shape[0]):
                f2 = 0
                inside = True
                for j in range(d):
                    cj = idx[j] + near[w, j]
                    if cj < 0 or cj >= gshape[j]:
                        inside = False
                        break
                    f2 += cj * gstrides[j]
                if inside and occ[f2]:
                    if fill:
                        for j in range(d):
                            cells[m, j] = idx[j] + near[w, j]
                    m += 1
        start[n] = m
        if not fill:
            cells = np.empty((m, d), np.int64)
    return kind, start, cells


@njit(cache=True, nogil=True)
def _gap(lo, x, res):
    """Distance (m) from x to the cell [lo, lo + res] along one axis (0 inside), as StaticScreen.bad takes it."""
    return max(max(lo - x, x - (lo + res)), 0.0)


# ---------------------------------------------------------------- storage

_FILTER_BITS = 18     # the closed keys' bit filter: 2^18 bits (32 KiB), so that most fresh children skip the table
_FILTER_WORDS = 1 << (_FILTER_BITS - 6)

# node table columns (int64; P and J first, [0, d) and [d, 2 d)), after 2 d:
_DEPTH, _PARENT, _ACC, _CUT, _KEY, _GOAL = range(6)


@njit(cache=True, nogil=True)
def _grow(a, n):
    """a [R, K] with twice the rows, the first n copied."""
    out = np.empty((2 * a.shape[0], a.shape[1]), a.dtype)
    out[:n] = a[:n]
    return out


@njit(cache=True, nogil=True)
def _mix(key):
    """The splitmix64 hash of a key (uint64)."""
    z = np.uint64(key)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@njit(cache=True, nogil=True)
def _closed_bit(key):
    """(word, bit mask) of key in the closed keys' bit filter [_FILTER_WORDS] (uint64): the hash's top bits."""
    z = _mix(key) >> np.uint64(64 - _FILTER_BITS)
    return np.int64(z >> np.uint64(6)), np.uint64(1) << (z & np.uint64(63))


@njit(cache=True, nogil=True)
def _slot(tab, key):
    """The row of key in the key table tab [R, 2] (R a power of 2; column 0 the key, _EMPTY if free): where it is,
    or the free row where it goes (linear probing, splitmix64 hash)."""
    mask = tab.shape[0] - 1
    i = np.int64(_mix(key) & np.uint64(mask))
    while True:
        k = tab[i, 0]
        if k == key or k == _EMPTY:
            return i
        i = (i + 1) & mask


@njit(cache=True, nogil=True)
def _rehash(tab):
    """The key table with twice the rows."""
    out = np.full((2 * tab.shape[0], 2), _EMPTY, np.int64)
    for i in range(tab.shape[0]):
        if tab[i, 0] != _EMPTY:
            j = _slot(out, tab[i, 0])
            out[j, 0] = tab[i, 0]
            out[j, 1] = tab[i, 1]
    return out


@njit(cache=True, nogil=True)
def _lt(f1, h1, t1, f2, h2, t2):
    """(f1, h1, t1) < (f2, h2, t2) as Python compares the heap tuples (f, h, counter)."""
    if f1 != f2:
        return f1 < f2
    if h1 != h2:
        return h1 < h2
    return t1 < t2


@njit(cache=True, nogil=True, inline="always")
def _put(heap, i, f, h, t, c):
    """Write the entry (f, h, t, c) into row i of the heap."""
    heap[i, 0] = f
    heap[i, 1] = h
    heap[i, 2] = t
    heap[i, 3] = c


@njit(cache=True, nogil=True)
def _push(heap, size, f, h, t, c):
    """Add (f, h, counter t, node c) to the 4-ary heap [R, 4] of size entries (room checked by the caller); the new
    size. Counters and node ids are stored as float64 (exact below 2^53)."""
    i = size
    while i > 0:
        up = (i - 1) >> 2
        if _lt(heap[up, 0], heap[up, 1], heap[up, 2], f, h, t):
            break
        for j in range(4):
            heap[i, j] = heap[up, j]
        i = up
    _put(heap, i, f, h, t, c)
    return size + 1


@njit(cache=True, nogil=True)
def _pop(heap, size):
    """(the node id of the least entry, removed; the new size). Entries are unique (the counter), so the order of
    the pops is heapq's."""
    top = np.int64(heap[0, 3])
    size -= 1
    if size > 0:
        f, h, t, c = heap[size, 0], heap[size, 1], heap[size, 2], heap[size, 3]
        i = 0
        while True:
            first = 4 * i + 1
            if first >= size:
                break
            m = first
            for ch in range(first + 1, min(first + 4, size)):
                if _lt(heap[ch, 0], heap[ch, 1], heap[ch, 2], heap[m, 0], heap[m, 1], heap[m, 2]):
                    m = ch
            if not _lt(heap[m, 0], heap[m, 1], heap[m, 2], f, h, t):
                break
            for j in range(4):
                heap[i, j] = heap[m, j]
            i = m
        _put(heap, i, f, h, t, c)
    return top, size


# ---------------------------------------------------------------- the search

@njit(cache=True, nogil=True)
def search_kernel(p0, v0, base, goal, goal_radius, goal_r, acc_int, accel, edge_cost, root_J, root_acc, root_cost,
                  s, s2, T, rho, eps, max_exp, n_horizon, key_off, key_mult, vj_max2, c_pos, w_vel, v_max, a_max,
                  vset, ratios, wall_lo, wall_hi, tr_pos, tr_vel, tr_reach, horizon, has_grid, kind, start, cells,
                  gshape, gstrides, origin, res, reach2, h0, sq_order, gemm_mode, gemv_mode, dot_mode):
    """GlobalPrimitives._search_reference (norm lattice, LQMT) from the exact root p0, v0 [d] (m, m/s) with lattice
    origin base [d] (m): weighted A* (eps) over the children of acc_int [C, d] (accel [C, d] m/s^2, edge_cost [C]) and
    the root's (root_J [C0, d], root_acc, root_cost), every sample s [S] (s) checked against the walls, the tracks
    (tr_pos, tr_vel [M, d], tr_reach [M] = radius + reach, m; samples up to horizon, s) and the grid
    (band_lists). h0: the root's heuristic; the modes: numpy_modes.

    Returns (status 0 found / 1 exhausted / 2 budget, expansions, goal node id or -1, node table [N, 2 d + 6]
    int64 (P, J, then depth, parent, acceleration index (into root_acc for the root's children), cut sample (-1
    unless a goal node), key, goal index), g and h [N, 2], goal states [G, 2, d] (p, v at the cut)); node 0 is the
    root. Closed keys keep g = -1 in the key table (a closed key's best g is never read again); a bit filter of
    the closed keys spares most children the table."""
    d = p0.shape[0]
    n_s_all = s.shape[0]
    n_acc = acc_int.shape[0]
    n_root = root_J.shape[0]
    n_ch = max(n_acc, n_root)
    n_tr = tr_pos.shape[0]
    goal_r2 = goal_r * goal_r
    lim_tau = horizon + 1e-9
    cD, cPa, cA, cC, cK, cG = 2 * d + _DEPTH, 2 * d + _PARENT, 2 * d + _ACC, 2 * d + _CUT, 2 * d + _KEY, \
        2 * d + _GOAL
    # nodes (0 = root)
    nodes = np.zeros((4096, 2 * d + 6), np.int64)
    gh = np.zeros((4096, 2))
    nodes[0, cPa] = -1
    nodes[0, cA] = -1
    nodes[0, cC] = -1
    nodes[0, cK] = _EMPTY
    nodes[0, cG] = -1
    gh[0, 1] = h0
    n_nodes = 1
    goal_pv = np.zeros((64, 2 * d))
    n_goal = 0
    # open list
    heap = np.empty((4096, 4))
    hsize = _push(heap, 0, eps * h0, h0, 0.0, 0.0)
    tie = 1
    # keys -> best g (-1: closed)
    tab = np.full((1 << 14, 2), _EMPTY, np.int64)
    tabg = tab.view(np.float64)
    t_used = 0
    closed_bits = np.zeros(_FILTER_WORDS, np.uint64)
    # per expansion scratch
    cJ = np.empty((n_ch, d), np.int64)
    cP = np.empty((n_ch, d), np.int64)
    cacc = np.empty((n_ch, d))
    ccost = np.empty(n_ch)
    ckey = np.empty(n_ch, np.int64)
    cai = np.empty(n_ch, np.int64)
    pts = np.empty((n_ch, n_s_all, d))
    first_goal = np.empty(n_ch, np.int64)
    first_bad = np.empty(n_ch, np.int64)
    pbase = np.empty((n_s_all, d))
    p = np.empty(d)
    v = np.empty(d)
    je = np.empty(d, np.int64)
    lo = np.empty(d)
    hi = np.empty(d)
    lo_q = np.empty(d)
    hi_q = np.empty(d)
    near_tr = np.zeros(n_tr, np.bool_)
    tau = np.empty(n_s_all)
    status = 1
    expansions = 0
    goal_id = -1
    while hsize > 0:
        nid, hsize = _pop(heap, hsize)
        if nodes[nid, cC] >= 0:
            status = 0
            goal_id = nid
            break
        key = nodes[nid, cK]
        if key != _EMPTY:
            i = _slot(tab, key)
            if tab[i, 0] == key and tabg[i, 1] < 0.0:
                continue
            if tab[i, 0] != key:            # (every keyed node's key has a best g: not reached)
                tab[i, 0] = key
                t_used += 1
            tabg[i, 1] = -1.0
            w, b = _closed_bit(key)
            closed_bits[w] |= b
            if 2 * t_used > tab.shape[0]:
                tab = _rehash(tab)
                tabg = tab.view(np.float64)
        if expansions >= max_exp:
            status = 2
            break
        expansions += 1
        # ---- children (GlobalPrimitives._expand)
        n = nodes[nid, cD]
        if nid == 0:
            for j in range(d):
                p[j] = p0[j]
                v[j] = v0[j]
        else:
            for j in range(d):
                p[j] = base[j] + c_pos * nodes[nid, j]
                v[j] = w_vel * nodes[nid, d + j]
        depth_key = min(n + 1, n_horizon)
        nc = 0
        n_cand = n_root if nid == 0 else n_acc
        for r in range(n_cand):
            if nid == 0:
                for j in range(d):
                    cJ[nc, j] = root_J[r, j]
                    cP[nc, j] = root_J[r, j]
            else:
                jj = 0
                for j in range(d):
                    je[j] = nodes[nid, d + j] + acc_int[r, j]
                    jj += je[j] * je[j]
                if not jj <= vj_max2:
                    continue
                for j in range(d):
                    cJ[nc, j] = je[j]
                    cP[nc, j] = nodes[nid, j] + 2 * nodes[nid, d + j] + acc_int[r, j]
            k = (depth_key + key_off[0]) * key_mult[0]
            for j in range(d):
                k += (cP[nc, j] + key_off[1 + j]) * key_mult[1 + j]
                k += (cJ[nc, j] + key_off[1 + d + j]) * key_mult[1 + d + j]
            w, b = _closed_bit(k)
            if closed_bits[w] & b:
                i = _slot(tab, k)
                if tab[i, 0] == k and tabg[i, 1] < 0.0:
                    continue
            for j in range(d):
                cacc[nc, j] = root_acc[r, j] if nid == 0 else accel[r, j]
            ccost[nc] = root_cost[r] if nid == 0 else edge_cost[r]
            ckey[nc] = k
            cai[nc] = r
            nc += 1
        if nc == 0:
            continue
        # samples: (p + s v) + s^2 / 2 a, and their box
        for k in range(n_s_all):
            for j in range(d):
                pbase[k, j] = p[j] + s[k] * v[j]
        for j in range(d):
            lo[j] = np.inf
            hi[j] = -np.inf
        for i in range(nc):
            for k in range(n_s_all):
                for j in range(d):
                    x = pbase[k, j] + s2[k] * cacc[i, j]
                    pts[i, k, j] = x
                    lo[j] = min(lo[j], x)
                    hi[j] = max(hi[j], x)
        # tracks within the horizon: only those whose predicted segment comes near the samples' box
        n_s = 0
        for k in range(n_s_all):
            tau[k] = n * T + s[k]
            if tau[k] <= lim_tau:
                n_s = k + 1
        any_near = False
        if n_tr > 0 and n_s > 0:
            for j in range(d):
                lo_q[j] = np.inf
                hi_q[j] = -np.inf
            for i in range(nc):
                for k in range(n_s):
                    for j in range(d):
                        lo_q[j] = min(lo_q[j], pts[i, k, j])
                        hi_q[j] = max(hi_q[j], pts[i, k, j])
            for m in range(n_tr):
                ok = True
                for j in range(d):
                    a = tr_pos[m, j] + tau[0] * tr_vel[m, j]
                    b = tr_pos[m, j] + tau[n_s - 1] * tr_vel[m, j]
                    if not (min(a, b) - tr_reach[m] < hi_q[j] and max(a, b) + tr_reach[m] > lo_q[j]):
                        ok = False
                        break
                near_tr[m] = ok
                any_near = any_near or ok
        # goal ball: only when the samples' box comes near it
        b0 = b1 = b2 = 0.0
        for j in range(d):
            bj = max(max(lo[j] - goal[j], goal[j] - hi[j]), 0.0)
            if j == 0:
                b0 = bj
            elif j == 1:
                b1 = bj
            else:
                b2 = bj
        test_goal = _mdot(b0, b1, b2, b0, b1, b2, d, dot_mode) <= goal_r2
        # first bad and first goal sample of each child
        n_plain = 0
        for i in range(nc):
            fb = n_s_all
            fg = n_s_all
            for k in range(n_s_all):
                bad = False
                for j in range(d):
                    if pts[i, k, j] < wall_lo[j] or pts[i, k, j] > wall_hi[j]:
                        bad = True
                if not bad and any_near and k < n_s:
                    for m in range(n_tr):
                        if near_tr[m]:
                            r0 = pts[i, k, 0] - (tr_pos[m, 0] + tau[k] * tr_vel[m, 0])
                            r1 = pts[i, k, 1] - (tr_pos[m, 1] + tau[k] * tr_vel[m, 1])
                            r2 = pts[i, k, d - 1] - (tr_pos[m, d - 1] + tau[k] * tr_vel[m, d - 1])
                            if _esum(r0, r1, r2, r0, r1, r2, d, sq_order) < tr_reach[m] * tr_reach[m]:
                                bad = True
                                break
                if not bad and has_grid:         # StaticScreen.bad, the cells as band_lists lists them
                    flat = 0
                    for j in range(d):
                        q = np.int64(math.floor((pts[i, k, j] - origin[j]) / res))
                        flat += min(max(q, 0), gshape[j] - 1) * gstrides[j]
                    kf = kind[flat]
                    if kf == 2:
                        bad = True
                    elif kf == 1:
                        for q in range(start[flat], start[flat + 1]):
                            g0 = _gap(origin[0] + cells[q, 0] * res, pts[i, k, 0], res)
                            g1 = _gap(origin[1] + cells[q, 1] * res, pts[i, k, 1], res)
                            g2 = _gap(origin[d - 1] + cells[q, d - 1] * res, pts[i, k, d - 1], res)
                            if _esum(g0, g1, g2, g0, g1, g2, d, sq_order) < reach2:
                                bad = True
                                break
                if bad:
                    fb = k
                    break
                if test_goal:
                    e0 = pts[i, k, 0] - goal[0]
                    e1 = pts[i, k, 1] - goal[1]
                    e2 = pts[i, k, d - 1] - goal[d - 1]
                    if _esum(e0, e1, e2, e0, e1, e2, d, sq_order) <= goal_r2:
                        fg = k
                        break
            first_bad[i] = fb
            first_goal[i] = fg
            if fb == n_s_all and fg == n_s_all:
                n_plain += 1
        # room for every child
        if n_nodes + nc > nodes.shape[0]:
            nodes, gh = _grow(nodes, n_nodes), _grow(gh, n_nodes)
        if hsize + nc > heap.shape[0]:
            heap = _grow(heap, hsize)
        if n_goal + nc > goal_pv.shape[0]:
            goal_pv = _grow(goal_pv, n_goal)
        g0 = gh[nid, 0]
        mm_mode = gemv_mode if n_plain == 1 else gemm_mode
        for i in range(nc):                 # the clear children, then the goal nodes (the Python push order)
            if first_bad[i] != n_s_all or first_goal[i] != n_s_all:
                continue
            g = g0 + ccost[i]
            key = ckey[i]
            t = _slot(tab, key)
            if tab[t, 0] == key and tabg[t, 1] <= g:
                continue
            if tab[t, 0] != key:
                tab[t, 0] = key
                t_used += 1
            tabg[t, 1] = g
            pe0 = base[0] + c_pos * cP[i, 0]
            pe1 = base[1] + c_pos * cP[i, 1]
            pe2 = base[d - 1] + c_pos * cP[i, d - 1]
            hv = _lqmt(goal[0] - pe0, goal[1] - pe1, goal[d - 1] - pe2, w_vel * cJ[i, 0], w_vel * cJ[i, 1],
                       w_vel * cJ[i, d - 1], d, goal_radius, rho, v_max, a_max, vset, ratios, sq_order, mm_mode)
            cid = n_nodes
            n_nodes += 1
            for j in range(d):
                nodes[cid, j] = cP[i, j]
                nodes[cid, d + j] = cJ[i, j]
            nodes[cid, cD] = n + 1
            nodes[cid, cPa] = nid
            nodes[cid, cA] = cai[i]
            nodes[cid, cC] = -1
            nodes[cid, cK] = key
            nodes[cid, cG] = -1
            gh[cid, 0] = g
            gh[cid, 1] = hv
            hsize = _push(heap, hsize, g + eps * hv, hv, float(tie), float(cid))
            tie += 1
            if 2 * t_used > tab.shape[0]:
                tab = _rehash(tab)
                tabg = tab.view(np.float64)
        for i in range(nc):
            k = first_goal[i]
            if k >= first_bad[i]:
                continue
            a0 = cacc[i, 0]
            a1 = cacc[i, 1]
            a2 = cacc[i, d - 1]
            g = g0 + (_mdot(a0, a1, a2, a0, a1, a2, d, dot_mode) + rho) * s[k]
            for j in range(d):
                goal_pv[n_goal, j] = pts[i, k, j]
                goal_pv[n_goal, d + j] = v[j] + s[k] * cacc[i, j]
            cid = n_nodes
            n_nodes += 1
            for j in range(d):
                nodes[cid, j] = cP[i, j]
                nodes[cid, d + j] = cJ[i, j]
            nodes[cid, cD] = n + 1
            nodes[cid, cPa] = nid
            nodes[cid, cA] = cai[i]
            nodes[cid, cC] = k
            nodes[cid, cK] = _EMPTY
            nodes[cid, cG] = n_goal
            gh[cid, 0] = g
            gh[cid, 1] = 0.0
            n_goal += 1
            hsize = _push(heap, hsize, g, 0.0, float(tie), float(cid))
            tie += 1
    return (status, expansions, goal_id, nodes[:n_nodes], gh[:n_nodes], goal_pv[:n_goal])


# ---------------------------------------------------------------- the planner's side

class CompiledSearch:
    """The constant arrays of one GlobalPrimitives (norm lattice, LQMT, integer keys) for search_kernel, the
    band_lists of its last StaticScreen, and run(): the search of one view. exact: numpy_modes' flag."""

    def __init__(self, planner) -> None:
        gp = planner
        d = gp.dims
        self.gp = gp
        vset = gp.lattice_velocities if gp.lattice_time_bound else np.zeros((0, d))
        self.vset = np.ascontiguousarray(vset, dtype=float)
        # the most children one expansion has: every acceleration, or the root's (|J1 - v0 / w| <= m: <= (2 m + 1)^d)
        self.modes = numpy_modes(gp.lattice_velocities, max(len(gp.acc_int), (2 * gp.m + 1) ** d))
        self.exact = self.modes[4]
        self.acc_int = np.ascontiguousarray(gp.acc_int, dtype=np.int64)
        self.accel = np.ascontiguousarray(gp.accelerations, dtype=float)
        self.edge_cost = np.ascontiguousarray(gp._edge_cost, dtype=float)
        self.s = np.ascontiguousarray(gp._s, dtype=float)
        self.s2 = np.ascontiguousarray(gp._s2, dtype=float)
        self.key_off = np.ascontiguousarray(gp._key_off, dtype=np.int64)
        self.key_mult = np.ascontiguousarray(gp._key_mult, dtype=np.int64)
        self.ratios = np.ascontiguousarray(_RATIOS, dtype=float)
        self.wall_lo = np.array(gp._wall_lo, dtype=float)
        self.wall_hi = np.array(gp._wall_hi, dtype=float)
        self._screen = None
        self._grid_args: tuple = ()

    def _grid(self, screen) -> tuple:
        """search_kernel's grid arguments of a StaticScreen (cached per screen)."""
        if screen is not self._screen:
            grid = screen.grid
            shape = np.asarray(grid.shape, dtype=np.int64)
            strides = np.cumprod(np.concatenate([shape[1:], [1]])[::-1])[::-1].astype(np.int64)
            kind, start, cells = band_lists(*(np.ascontiguousarray(m).reshape(-1) for m in (
                screen.maybe, screen.surely, screen.occupied)), shape, strides,
                np.ascontiguousarray(screen._near, dtype=np.int64))
            self._grid_args = (bool(screen.maybe.any()), kind, start, cells, shape, strides,
                               np.array(grid.origin, dtype=float), float(grid.res), screen.reach * screen.reach)
            self._screen = screen
        return self._grid_args

    def run(self, view, screen):
        """The search of ``view`` with the grid's StaticScreen: (status, expansions, path), path None unless found,
        else per node root first (p, v, g, h, a, cut) as the Python search's nodes hold them."""
        gp = self.gp
        p0 = np.array(view.position, dtype=float)
        v0 = np.array(view.velocity, dtype=float)
        goal = np.array(view.goal, dtype=float)
        base = p0 + 0.5 * gp.T * v0
        h0 = float(gp.heuristic(goal, view.goal_radius, p0[None], v0[None])[0])
        root_J, root_acc = gp.root_children(v0)
        root_cost = (np.einsum("cd,cd->c", root_acc, root_acc) + gp.rho) * gp.T
        tracks = view.tracks
        tr_pos = np.array(tracks.position, dtype=float).reshape(-1, gp.dims)
        tr_vel = np.array(tracks.velocity, dtype=float).reshape(-1, gp.dims)
        tr_reach = np.array(tracks.radius + gp._reach, dtype=float).reshape(-1)
        lim = gp.limits
        sq_order, gemm_mode, gemv_mode, dot_mode, _ = self.modes
        out = search_kernel(
            p0, v0, base, goal, float(view.goal_radius), float(view.goal_radius - GOAL_TOL), self.acc_int, self.accel,
            self.edge_cost, np.ascontiguousarray(root_J, dtype=np.int64), np.ascontiguousarray(root_acc),
            np.ascontiguousarray(root_cost), self.s, self.s2, float(gp.T), gp.rho, gp.epsilon, gp.max_expansions,
            gp.n_horizon, self.key_off, self.key_mult, float(gp._vj_max2), float(gp.c), float(gp.w),
            float(lim.v_max), float(lim.a_max), self.vset, self.ratios, self.wall_lo, self.wall_hi, tr_pos, tr_vel,
            tr_reach, gp.horizon_s, *self._grid(screen), h0, sq_order, gemm_mode, gemv_mode, dot_mode)
        status, expansions, goal_id, nodes, gh, goal_pv = out
        if status != 0:
            return STATUSES[status], int(expansions), None
        d = gp.dims
        parent, ai, cut, gi = (nodes[:, 2 * d + c] for c in (_PARENT, _ACC, _CUT, _GOAL))
        chain = []
        nid = int(goal_id)
        while nid > 0:
            chain.append(nid)
            nid = int(parent[nid])
        chain.reverse()
        path = [(p0, v0, 0.0, h0, np.zeros(d), -1)]
        for cid in chain:
            a = root_acc[ai[cid]] if parent[cid] == 0 else gp.accelerations[ai[cid]]
            if cut[cid] >= 0:
                p, v = goal_pv[gi[cid], :d].copy(), goal_pv[gi[cid], d:].copy()
            else:
                p, v = base + gp.c * nodes[cid, :d], gp.w * nodes[cid, d:2 * d]
            path.append((p, v, float(gh[cid, 0]), float(gh[cid, 1]), a, int(cut[cid])))
        return "found", int(expansions), path
