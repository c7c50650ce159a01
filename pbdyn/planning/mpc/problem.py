"""The MPC's convex problem (thesis A-3, eqs. A-5..A-11) with a fixed structure, and its two solver paths.

Decision variables (d = 2 or 3, N horizon steps of dt): p_k, v_k for k = 1..N (m, m/s), u_k for k = 0..N-1 (m/s^2,
constant over step k -> k+1), one collision slack s_k >= 0 (m) and one margin-band use b_k (m) per step k = 1..N.

    minimise   sum_k w_goal |p_k - ref_k|^2 + sum_k w_acc |u_k|^2 + sum_k (w_slack s_k + w_band b_k)   (A-6, A-11)
    subject to p_k+1 = p_k + dt v_k + dt^2/2 u_k,  v_k+1 = v_k + dt u_k,  (p_0, v_0) given          (A-5, A-7)
               |v_k| <= v_lim, |u_k| <= a_lim      (second-order cones)                               (A-8)
               n_jk . p_k + s_k + b_k >= rhs_jk    (R rows per step: tracks and cells)               (A-10)
               wall_lo - s_k <= p_k <= wall_hi + s_k
               s_k >= 0,  0 <= b_k <= band

rhs_jk includes the full safety margin; the band lets a plan give up to ``band`` metres of it at a moderate price
(w_band), and only what goes beyond the band is slack s_k (the quantity a plan is judged by).

Every quantity that changes from step to step (initial state, reference, row normals and right-hand sides) is a
parameter; the sparsity pattern, the cone list and the row count never change (unused rows are given n = 0 and a
right-hand side far below any reachable value). ``ClarabelMPC`` writes the parameters straight into Clarabel's CSC data
and updates one persistent solver; ``CvxpyMPCReference`` states the same problem in cvxpy with Parameters (DPP) and
re-solves it with Clarabel. Both return an ``MPCSolution``; a test checks that they agree.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

INACTIVE_RHS = -1.0e3  # m; right-hand side of a padding row: 0 . p_k + s_k >= -1000 always holds

# Clarabel settings of both paths. The problem is scaled by construction (unit normals, metres, seconds):
# Ruiz equilibration computed once on the first step's data made later solves stop at "AlmostSolved" now and then,
# and iterative refinement costs ~40% of the solve time without changing the status on this problem.
SOLVER_SETTINGS = {"equilibrate_enable": False, "iterative_refinement_enable": False, "max_threads": 1}


@dataclass(frozen=True)
class MPCShape:
    """The fixed structure of the problem.

    Attributes:
        dims: spatial dimension d (2 or 3).
        horizon: number of steps N.
        dt: step (s).
        rows: collision rows per step R (tracks + occupied cells, padded).
    """

    dims: int
    horizon: int
    dt: float
    rows: int


@dataclass(frozen=True)
class MPCWeights:
    """Cost weights (A-11): w_goal on |p_k - ref_k|^2 (cost per m^2), w_acc on |u_k|^2 (cost per (m/s^2)^2),
    w_slack on each metre of collision slack and w_band on each metre of margin given up, per step (L1)."""

    w_goal: float
    w_acc: float
    w_slack: float
    w_band: float


@dataclass(frozen=True)
class MPCData:
    """The parameter values of one solve (all world frame, SI).

    Attributes:
        p0, v0: initial state [d] (m, m/s).
        ref: goal reference per step [N, d] (m) for p_1..p_N.
        normals: row normals [R, N, d] (unit, or 0 for a padding row).
        rhs: row right-hand sides [R, N] (m): n . p_k + s_k >= rhs.
        wall_lo, wall_hi: box the MAV centre must stay in [d] (m).
        v_lim, a_lim: norm bounds (m/s, m/s^2) given to the solver.
        band: the part of the margin (m) a row may give up at price w_band (0 <= b_k <= band).
    """

    p0: np.ndarray
    v0: np.ndarray
    ref: np.ndarray
    normals: np.ndarray
    rhs: np.ndarray
    wall_lo: np.ndarray
    wall_hi: np.ndarray
    v_lim: float
    a_lim: float
    band: float


@dataclass(frozen=True)
class MPCSolution:
    """A solver's answer: p, v [N, d] (k = 1..N), u [N, d] (k = 0..N-1), s, b [N] (k = 1..N); ``optimal`` is True
    only for a status of "solved"; ``status`` is the solver's status text; ``iterations`` its iteration count."""

    p: np.ndarray
    v: np.ndarray
    u: np.ndarray
    s: np.ndarray
    b: np.ndarray
    optimal: bool
    status: str
    iterations: int


class ClarabelMPC:
    """The problem stated directly in Clarabel's form (min 1/2 z'Pz + q'z, Az + s = b, s in K); built once, then
    each ``solve`` writes the parameters into A's CSC values, b and q and updates the persistent solver.

    Variable order z = [p_1..p_N, v_1..v_N, u_0..u_N-1, s_1..s_N, b_1..b_N] (p/v/u blocks k-major, axis-minor).
    Row order: 2dN dynamics equalities; N slack rows, 2N band rows, RN collision rows, 2dN wall rows (nonnegative
    cone); N velocity cones and N acceleration cones of size d + 1.
    """

    def __init__(self, shape: MPCShape, weights: MPCWeights, *, max_iter: int = 100):
        import clarabel

        self._clarabel = clarabel
        self.shape = shape
        self.weights = weights
        d, n, r = shape.dims, shape.horizon, shape.rows
        nd = n * d
        self._ip, self._iv, self._iu, self._is = 0, nd, 2 * nd, 3 * nd
        self._ib = 3 * nd + n
        self.n_var = 3 * nd + 2 * n
        rows, cols, vals = [], [], []

        def add(rr, cc, vv):
            rows.append(np.asarray(rr, np.int64).ravel())
            cols.append(np.asarray(cc, np.int64).ravel())
            vals.append(np.broadcast_to(np.asarray(vv, float), np.shape(rr)).ravel())

        h = 0.5 * shape.dt ** 2
        kk, ii = np.meshgrid(np.arange(n), np.arange(d), indexing="ij")     # [N, d]
        pos_row = 2 * d * kk + ii                                            # dynamics rows of step k -> k+1
        vel_row = pos_row + d
        p_col = self._ip + d * kk + ii
        v_col = self._iv + d * kk + ii
        u_col = self._iu + d * kk + ii
        add(pos_row, p_col, 1.0)
        add(pos_row, u_col, -h)
        add(vel_row, v_col, 1.0)
        add(vel_row, u_col, -shape.dt)
        add(pos_row[1:], p_col[:-1], -1.0)
        add(pos_row[1:], v_col[:-1], -shape.dt)
        add(vel_row[1:], v_col[:-1], -1.0)
        m = 2 * nd
        s_col = self._is + np.arange(n)
        b_col = self._ib + np.arange(n)
        add(m + np.arange(n), s_col, -1.0)                                   # -s_k <= 0
        m += n
        add(m + np.arange(n), b_col, -1.0)                                   # -b_k <= 0
        m += n
        self._band_row0 = m
        add(m + np.arange(n), b_col, 1.0)                                    # b_k <= band
        m += n
        self._coll_row0 = m
        cr = m + n * np.arange(r)[:, None] + np.arange(n)[None, :]           # [R, N]
        add(cr, np.broadcast_to(s_col, (r, n)), -1.0)
        add(cr, np.broadcast_to(b_col, (r, n)), -1.0)
        self._normal_start = sum(len(x) for x in rows)
        cr3 = np.broadcast_to(cr[:, :, None], (r, n, d))
        pc3 = np.broadcast_to(p_col[None], (r, n, d))
        add(cr3, pc3, 0.0)                                                   # -n_jk . p_k (parameter)
        m += r * n
        self._wall_row0 = m
        wl = m + 2 * d * kk + ii                                             # -p <= -lo ; p <= hi
        add(wl, p_col, -1.0)
        add(wl, np.broadcast_to(s_col[:, None], (n, d)), -1.0)
        add(wl + d, p_col, 1.0)
        add(wl + d, np.broadcast_to(s_col[:, None], (n, d)), -1.0)
        m += 2 * nd
        self._soc_row0 = m
        socv = m + (d + 1) * np.arange(n)[:, None] + 1 + np.arange(d)[None, :]
        add(socv, v_col, -1.0)
        m += n * (d + 1)
        socu = m + (d + 1) * np.arange(n)[:, None] + 1 + np.arange(d)[None, :]
        add(socu, u_col, -1.0)
        m += n * (d + 1)
        self.n_row = m
        r_all, c_all, v_all = np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)
        nnz = r_all.shape[0]
        # CSC built from integer tags so that tag -> data position is known (no duplicate entries exist)
        tag = sp.csc_matrix((np.arange(1, nnz + 1, dtype=float), (r_all, c_all)), shape=(m, self.n_var))
        tag.sort_indices()
        if tag.nnz != nnz:
            raise AssertionError("duplicate entries in the MPC constraint matrix")
        order = tag.data.astype(np.int64) - 1                               # data position -> COO entry
        self._normal_pos = np.empty(nnz, np.int64)
        self._normal_pos[order] = np.arange(nnz)
        self._normal_pos = self._normal_pos[self._normal_start:self._normal_start + r * n * d]
        self._A = sp.csc_matrix((v_all[order], tag.indices.copy(), tag.indptr.copy()), shape=(m, self.n_var))
        self._b = np.zeros(m)
        self._b[self._coll_row0:self._coll_row0 + r * n] = -INACTIVE_RHS
        diag = np.zeros(self.n_var)
        diag[self._ip:self._iv] = 2.0 * weights.w_goal
        diag[self._iu:self._is] = 2.0 * weights.w_acc
        self._P = sp.diags(diag).tocsc()
        self._q = np.zeros(self.n_var)
        self._q[self._is:self._ib] = weights.w_slack
        self._q[self._ib:] = weights.w_band
        self._cones = [clarabel.ZeroConeT(2 * nd), clarabel.NonnegativeConeT(3 * n + r * n + 2 * nd)]
        self._cones += [clarabel.SecondOrderConeT(d + 1)] * (2 * n)
        settings = clarabel.DefaultSettings()
        settings.verbose = False
        settings.presolve_enable = False
        settings.input_sparse_dropzeros = False
        settings.max_iter = int(max_iter)
        for key, value in SOLVER_SETTINGS.items():
            setattr(settings, key, value)
        self._settings = settings
        self._solver = None

    def _fill(self, data: MPCData) -> None:
        d, n, r = self.shape.dims, self.shape.horizon, self.shape.rows
        A, b, q = self._A, self._b, self._q
        A.data[self._normal_pos] = -np.asarray(data.normals, float).reshape(-1)
        b[:] = 0.0
        dt = self.shape.dt
        b[0:d] = data.p0 + dt * data.v0
        b[d:2 * d] = data.v0
        b[self._band_row0:self._band_row0 + n] = data.band
        b[self._coll_row0:self._coll_row0 + r * n] = -np.asarray(data.rhs, float).reshape(-1)
        w = b[self._wall_row0:self._wall_row0 + 2 * n * d].reshape(n, 2, d)
        w[:, 0, :] = -data.wall_lo
        w[:, 1, :] = data.wall_hi
        socs = b[self._soc_row0:].reshape(2 * n, d + 1)
        socs[:n, 0] = data.v_lim
        socs[n:, 0] = data.a_lim
        q[self._ip:self._iv] = -2.0 * self.weights.w_goal * np.asarray(data.ref, float).reshape(-1)

    def solve(self, data: MPCData) -> MPCSolution:
        """Solve for one set of parameter values."""
        self._fill(data)
        if self._solver is None:
            self._solver = self._clarabel.DefaultSolver(self._P, self._q, self._A, self._b, self._cones,
                                                        self._settings)
        else:
            self._solver.update(A=self._A.data, b=self._b, q=self._q)
        sol = self._solver.solve()
        z = np.asarray(sol.x, float)
        status = str(sol.status)
        n, d = self.shape.horizon, self.shape.dims
        p = z[:self._iv].reshape(n, d).copy()
        v = z[self._iv:self._iu].reshape(n, d).copy()
        u = z[self._iu:self._is].reshape(n, d).copy()
        ok = status.split(".")[-1].lower() == "solved"
        return MPCSolution(p, v, u, z[self._is:self._ib].copy(), z[self._ib:].copy(), ok, status,
                           int(sol.iterations))


def _failed(shape: MPCShape, status: str, iterations: int = 0) -> MPCSolution:
    nan = np.full((shape.horizon, shape.dims), np.nan)
    return MPCSolution(nan, nan, nan, np.full(shape.horizon, np.nan), np.full(shape.horizon, np.nan), False, status,
                       iterations)


class CvxpyMPCReference:
    """The same problem in cvxpy, built once with Parameters (DPP) and re-solved with Clarabel each call (backend
    "cvxpy"): the reference twin of ClarabelMPC, agreeing within solver tolerances (tests/test_mpc.py)."""

    def __init__(self, shape: MPCShape, weights: MPCWeights):
        import cvxpy as cp

        self._cp = cp
        self.shape = shape
        d, n, r, dt = shape.dims, shape.horizon, shape.rows, shape.dt
        P = cp.Variable((n, d))
        V = cp.Variable((n, d))
        U = cp.Variable((n, d))
        S = cp.Variable(n)
        B = cp.Variable(n)
        self._vars = (P, V, U, S, B)
        self.p0 = cp.Parameter(d)
        self.v0 = cp.Parameter(d)
        self.ref = cp.Parameter((n, d))
        self.normals = [cp.Parameter((n, d)) for _ in range(r)]
        self.rhs = cp.Parameter((r, n))
        self.wall_lo = cp.Parameter(d)
        self.wall_hi = cp.Parameter(d)
        self.v_lim = cp.Parameter(nonneg=True)
        self.a_lim = cp.Parameter(nonneg=True)
        self.band = cp.Parameter(nonneg=True)
        h = 0.5 * dt * dt
        cons = [P[0] == self.p0 + dt * self.v0 + h * U[0], V[0] == self.v0 + dt * U[0],
                P[1:] == P[:-1] + dt * V[:-1] + h * U[1:], V[1:] == V[:-1] + dt * U[1:], S >= 0,
                B >= 0, B <= self.band]
        for j in range(r):
            cons.append(cp.sum(cp.multiply(self.normals[j], P), axis=1) + S + B >= self.rhs[j])
        for i in range(d):
            cons += [P[:, i] >= self.wall_lo[i] - S, P[:, i] <= self.wall_hi[i] + S]
        cons += [cp.norm(V, 2, axis=1) <= self.v_lim, cp.norm(U, 2, axis=1) <= self.a_lim]
        cost = (weights.w_goal * cp.sum_squares(P - self.ref) + weights.w_acc * cp.sum_squares(U)
                + weights.w_slack * cp.sum(S) + weights.w_band * cp.sum(B))
        self.problem = cp.Problem(cp.Minimize(cost), cons)
        if not self.problem.is_dcp(dpp=True):
            raise AssertionError("the MPC problem is not DPP")

    def solve(self, data: MPCData) -> MPCSolution:
        """Solve for one set of parameter values (Clarabel through cvxpy)."""
        self.p0.value = np.asarray(data.p0, float)
        self.v0.value = np.asarray(data.v0, float)
        self.ref.value = np.asarray(data.ref, float)
        for j, par in enumerate(self.normals):
            par.value = np.asarray(data.normals[j], float)
        self.rhs.value = np.asarray(data.rhs, float)
        self.wall_lo.value = np.asarray(data.wall_lo, float)
        self.wall_hi.value = np.asarray(data.wall_hi, float)
        self.v_lim.value = float(data.v_lim)
        self.a_lim.value = float(data.a_lim)
        self.band.value = float(data.band)
        try:
            self.problem.solve(solver=self._cp.CLARABEL, warm_start=False, **SOLVER_SETTINGS)
        except self._cp.error.SolverError as exc:
            return _failed(self.shape, f"solver error: {exc}")
        P, V, U, S, B = self._vars
        status = self.problem.status
        iters = int(self.problem.solver_stats.num_iters or 0) if self.problem.solver_stats is not None else 0
        if P.value is None:
            return _failed(self.shape, status, iters)
        return MPCSolution(np.array(P.value), np.array(V.value), np.array(U.value), np.array(S.value),
                           np.array(B.value), status == self._cp.OPTIMAL, status, iters)
