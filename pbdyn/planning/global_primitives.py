"""Global motion primitives (thesis 4-1-1, appendix A-1, Algorithm 2; Liu et al. 2017): A* over
constant-acceleration primitives from the MAV's current state to the goal ball.

Lattice and root. The accelerations are a per-axis grid a = du j, du = a_max / m, j in {-m..m}^d with
|j| <= m (so |a| <= a_max; n_accel = 2 m + 1 values per axis, 0 included). With velocity unit w = du T and
position unit c = du T^2 / 2, a node's state is exactly
    v = w J,   p = base + c P,   (J, P integer vectors; base = p0 + T v0 / 2)
and a primitive with integer acceleration j maps (P, J) -> (P + 2 J + j, J + j). The root is the exact current
state (p0, v0), generally not on that lattice: its children are the primitives that end on a lattice velocity
v1 = w J1 with |v1 - v0| / T <= a_max, i.e. the acceleration grid shifted by v0 (it is the plain grid, with 0,
when v0 is a lattice velocity, e.g. at rest). Their end positions p0 + T (v0 + v1) / 2 = base + c J1 are lattice
points, so every other node is an exact lattice point and is keyed by integers.

Keys and time. Collision checks against the tracks' predictions depend on absolute time, so within the prediction
horizon a node is keyed by (depth, P, J) (a time-expanded search); from depth n_h = ceil(horizon / T) on, the checks
no longer depend on time and nodes are keyed by (n_h, P, J), merging equal states reached at different times.
The search is A* with a closed list over these keys.

Checks (thesis eqs. A-2, A-3, as pbdyn.planning.checks): every world sample (every dt, at absolute times
view.t + k dt) of a primitive must keep the MAV ball (radius + margin) clear of the tracks' constant-velocity
predictions (only samples up to ``horizon_s`` ahead), of OCCUPIED cells, and of the walls (radius +
min(margin, WALL_MARGIN_CAP)); |v| is linear in time along a primitive, so |v| <= v_max at its two ends bounds it
everywhere. A child whose samples reach the goal ball (|p - goal| <= goal_radius) before any conflict is a goal
node: its primitive is cut at that sample and its cost counts up to it. Children are generated and checked for all
accelerations of a node at once (numpy); occupied cells are first screened with a dilated mask of the grid (cached
per grid version), and only flagged samples get the exact OccupancyGrid.collides test.

Trajectory: sample 0 is the current state; then every primitive sampled at the world dt in closed form
(p + v s + a s^2 / 2, v + a s); a[k] is the acceleration applied from sample k to k + 1 (the last sample keeps its
primitive's acceleration). The planner keeps the plan until replan_check finds that its remaining samples meet the
latest predictions (within the horizon) or a newly occupied cell (checked when the grid's version changed), or that
it has run out (thesis 4-1-1 "replanning check", A-2, A-3).
"""

from __future__ import annotations

import heapq
import itertools
import math

import numpy as np

from pbdyn.perception.grid import OCCUPIED
from pbdyn.planning.astar_heuristic import lqmt_lower_bound
from pbdyn.planning.checks import WALL_MARGIN_CAP
from pbdyn.planning.protocols import PlannerContext
from pbdyn.planning.trajectory import Trajectory
from pbdyn.planning.view import View

_A_TOL = 1e-12  # m/s^2: root accelerations may exceed a_max by this rounding slack
_GOAL_TOL = 1e-9  # m: goal samples must be this far inside the goal ball (the trial tests the same samples)


def acceleration_grid(n_accel: int, dims: int) -> np.ndarray:
    """Integer acceleration offsets j [C, d] in {-m..m}^d with |j| <= m, m = (n_accel - 1) / 2 (lexicographic)."""
    m = (n_accel - 1) // 2
    rng = range(-m, m + 1)
    j = np.array(list(itertools.product(rng, repeat=dims)), dtype=np.int64)
    return j[np.einsum("cd,cd->c", j, j) <= m * m]


def dilation_offsets(reach: float, res: float, dims: int) -> np.ndarray:
    """Cell offsets [W, d] whose cell box lies closer than ``reach`` (m) to the box of cell 0 (grid step res)."""
    k = int(math.ceil(reach / res)) + 1
    off = np.array(list(itertools.product(range(-k, k + 1), repeat=dims)), dtype=np.int64)
    gap = np.maximum(np.abs(off) - 1, 0) * res
    return off[np.einsum("wd,wd->w", gap, gap) < reach * reach]


class GlobalPrimitives:
    """Global motion primitives planner (registry name "global_primitives", thesis A-1).

    Args:
        context: the trial's fixed facts (dims, dt, limits, arena box).
        duration_s: primitive duration T (s), default 1 s; rounded to a whole number (>= 1) of world steps.
        n_accel: acceleration grid size per axis (odd, >= 3): accelerations k a_max / m, k = -m..m, m =
            (n_accel - 1) / 2, keeping |a| <= a_max. Default 7 in 2D (29 primitives per node; velocity lattice
            4/3 m/s at T = 1 s, a_max = 4 m/s^2) and 5 in 3D (33 primitives per node).
        rho: time weight of the edge cost |a|^2 T + rho T ((m/s^2)^2; thesis eq. A-1's rho), default 10.
        max_expansions: A* budget, a count of expanded nodes (deterministic, never wall time), default 20000.
        horizon_s: prediction horizon (s), default 5: samples further ahead are not checked against the tracks.
        margin: safety margin (m) added to the MAV radius, default 0.5 (as local_primitives and the thesis program).

    Heuristic: pbdyn.planning.astar_heuristic.lqmt_lower_bound (LQMT bound, free final time and velocity, to the
    goal ball's edge; never overestimates; eq. A-1 with T fixed and zero final velocity can, and is not used).

    Diagnostics: last_status ("found", "exhausted", "budget" or None before any plan), last_expansions,
    last_cost (cost of the returned path), last_path (list of (p, v, g, h) per node, root first),
    n_plans, n_budget_hits (cumulative over this planner's life).
    """

    def __init__(self, context: PlannerContext, *, duration_s: float = 1.0, n_accel: int | None = None,
                 rho: float = 10.0, max_expansions: int = 20000, horizon_s: float = 5.0, margin: float = 0.5,
                 lattice_time_bound: bool = True, epsilon: float = 1.0):
        d = int(context.dims)
        if d not in (2, 3):
            raise ValueError(f"dims must be 2 or 3, got {d}")
        if n_accel is None:
            n_accel = 7 if d == 2 else 5
        if not (isinstance(n_accel, (int, np.integer)) and n_accel >= 3 and n_accel % 2 == 1):
            raise ValueError(f"n_accel must be an odd integer >= 3, got {n_accel!r}")
        for name, value in (("duration_s", duration_s), ("rho", rho), ("horizon_s", horizon_s)):
            if not (math.isfinite(float(value)) and float(value) > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
        if not (math.isfinite(float(margin)) and margin >= 0):
            raise ValueError(f"margin must be a finite number >= 0, got {margin!r}")
        if int(max_expansions) < 1:
            raise ValueError(f"max_expansions must be >= 1, got {max_expansions!r}")
        self.dims = d
        self.dt = float(context.dt)
        self.limits = context.limits
        self.bounds_lo = np.asarray(context.bounds_lo, dtype=float)
        self.bounds_hi = np.asarray(context.bounds_hi, dtype=float)
        self.steps_per_primitive = max(1, int(round(float(duration_s) / self.dt)))
        self.T = self.steps_per_primitive * self.dt
        self.n_accel = int(n_accel)
        self.m = (self.n_accel - 1) // 2
        self.rho = float(rho)
        self.max_expansions = int(max_expansions)
        self.horizon_s = float(horizon_s)
        self.margin = float(margin)
        self.du = self.limits.a_max / self.m            # m/s^2 per acceleration index
        self.w = self.du * self.T                        # m/s per velocity index
        self.c = 0.5 * self.du * self.T * self.T         # m per position index
        self.acc_int = acceleration_grid(self.n_accel, d)   # [C, d]
        self.accelerations = self.du * self.acc_int          # [C, d] m/s^2
        self.n_horizon = max(1, int(math.ceil(self.horizon_s / self.T - 1e-9)))
        self._s = self.dt * np.arange(1, self.steps_per_primitive + 1)   # sample offsets within a primitive [S]
        self._reach = self.limits.radius + self.margin
        self._wall_lo = self.bounds_lo + self.limits.radius + min(self.margin, WALL_MARGIN_CAP)
        self._wall_hi = self.bounds_hi - self.limits.radius - min(self.margin, WALL_MARGIN_CAP)
        self._vj_max2 = (self.limits.v_max / self.w) ** 2 * (1.0 + 1e-12)
        jm = int(math.floor(self.limits.v_max / self.w + 1e-9))
        vel_int = np.array(list(itertools.product(range(-jm, jm + 1), repeat=d)), dtype=np.int64)
        self.lattice_velocities = self.w * vel_int[np.einsum("vd,vd->v", vel_int, vel_int) <= self._vj_max2]
        self.lattice_time_bound = bool(lattice_time_bound)
        self.epsilon = float(epsilon)
        self._mask_grid = None
        self._mask_version = -1
        self._mask: np.ndarray | None = None
        self._offsets: np.ndarray | None = None
        self._checked_grid = None
        self._checked_version = -1
        self._plan: Trajectory | None = None
        self.last_status: str | None = None
        self.last_expansions = 0
        self.last_cost = math.nan
        self.last_path: list[tuple[np.ndarray, np.ndarray, float, float]] = []
        self.n_plans = 0
        self.n_budget_hits = 0

    # ------------------------------------------------------------------ lattice

    def root_children(self, v0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For the exact root velocity v0 [d] (m/s): end velocity indices J1 [C0, d] (lattice velocities w J1 within
        a_max T of v0 and within v_max) and the accelerations (w J1 - v0) / T [C0, d] (m/s^2) that reach them."""
        v0 = np.asarray(v0, dtype=float)
        centre = np.floor(v0 / self.w).astype(np.int64)
        rng = range(-self.m - 1, self.m + 2)
        cand = centre + np.array(list(itertools.product(rng, repeat=self.dims)), dtype=np.int64)
        acc = (self.w * cand - v0) / self.T
        keep = np.sqrt(np.einsum("cd,cd->c", acc, acc)) <= self.limits.a_max + _A_TOL
        keep &= np.einsum("cd,cd->c", cand, cand) <= self._vj_max2
        return cand[keep], acc[keep]

    def heuristic(self, view: View, p: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The A* heuristic [N] for states p, v [N, d] (m, m/s) and the view's goal (astar_heuristic)."""
        lim = self.limits
        vset = self.lattice_velocities if self.lattice_time_bound else None
        return lqmt_lower_bound(view.goal - np.atleast_2d(p), np.atleast_2d(v), view.goal_radius, self.rho,
                                lim.v_max, lim.a_max, vset)

    # ------------------------------------------------------------------ checks

    def _static_mask(self, grid) -> np.ndarray:
        """Flat bool mask over grid cells: True where a point may be within radius + margin of an OCCUPIED cell."""
        if self._mask is not None and self._mask_grid is grid and self._mask_version == grid.version:
            return self._mask
        if self._offsets is None or self._offsets.shape[1] != grid.dims:
            self._offsets = dilation_offsets(self._reach, grid.res, grid.dims)
        mask = np.zeros(grid.shape, dtype=bool)
        occ = np.argwhere(grid.cells == OCCUPIED)
        if occ.shape[0]:
            cells = (occ[:, None, :] + self._offsets[None, :, :]).reshape(-1, grid.dims)
            cells = cells[np.all((cells >= 0) & (cells < np.asarray(grid.shape)), axis=1)]
            mask[tuple(cells.T)] = True
        self._mask, self._mask_grid, self._mask_version = mask.reshape(-1), grid, grid.version
        return self._mask

    def _grid_bad(self, grid, pts: np.ndarray) -> np.ndarray:
        """Per point [K, d]: True if the MAV ball (radius + margin) overlaps an OCCUPIED cell (exact, thesis A-3)."""
        bad = np.zeros(pts.shape[0], dtype=bool)
        if pts.shape[0] == 0:
            return bad
        flagged = self._static_mask(grid)[grid.flat_index(pts)]
        if flagged.any():
            bad[flagged] = grid.collides(pts[flagged], self._reach)
        return bad

    def _tracks_bad(self, view: View, pts: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """pts [C, S, d] at times tau [S] (s after view.t): True [C, S] where a track's prediction is within
        reach (thesis A-2). Only tracks whose predicted segment over the samples' times can come near are tested."""
        tracks = view.tracks
        bad = np.zeros(pts.shape[:2], dtype=bool)
        n_s = int(np.searchsorted(tau, self.horizon_s + 1e-9, side="right"))
        if len(tracks) == 0 or n_s == 0:
            return bad
        q = pts[:, :n_s]
        lo = q.reshape(-1, self.dims).min(axis=0)
        hi = q.reshape(-1, self.dims).max(axis=0)
        reach = tracks.radius + self._reach                                   # [M]
        a = tracks.position + tau[0] * tracks.velocity
        b = tracks.position + tau[n_s - 1] * tracks.velocity
        near = np.all((np.minimum(a, b) - reach[:, None] < hi) & (np.maximum(a, b) + reach[:, None] > lo), axis=1)
        if not near.any():
            return bad
        centres = tracks.position[near][None] + tau[:n_s, None, None] * tracks.velocity[near][None]   # [S', M', d]
        rel = q[:, :, None, :] - centres[None]                                                         # [C, S', M', d]
        r2 = reach[near] ** 2
        bad[:, :n_s] = np.any(np.einsum("csmd,csmd->csm", rel, rel) < r2, axis=2)
        return bad

    # ------------------------------------------------------------------ protocol

    def replan_check(self, view: View) -> bool:
        """True if there is no plan, it has no sample at view.t + dt, or its remaining samples meet the latest
        predictions within the horizon or a cell that became OCCUPIED since the last check (thesis A-2, A-3)."""
        tr = view.trajectory
        if tr is None:
            return True
        k0 = tr.index_at(view.t)
        if k0 < 0 or k0 + 1 >= tr.n_samples:
            return True
        pts = tr.p[k0 + 1:]
        tau = (tr.t0 - view.t) + tr.dt * np.arange(k0 + 1, tr.n_samples)
        if self._tracks_bad(view, pts[None], tau).any():
            return True
        grid = view.grid
        if grid is not self._checked_grid or grid.version != self._checked_version:
            if self._grid_bad(grid, pts).any():
                return True
            self._checked_grid, self._checked_version = grid, grid.version
        return False

    def plan(self, view: View) -> Trajectory | None:
        """A* from the exact current state to the goal ball; the found primitives sampled at view.dt, or None when
        the open list empties ("exhausted") or the expansion budget is spent ("budget")."""
        self.n_plans += 1
        self.last_expansions = 0
        self.last_cost = math.nan
        self.last_path = []
        self._plan = None
        found = self._search(view)
        if found is None:
            return None
        tr = self._trajectory(view, found)
        self._plan = tr
        self._checked_grid, self._checked_version = view.grid, view.grid.version
        return tr

    # ------------------------------------------------------------------ search

    def _search(self, view: View):
        d = self.dims
        p0 = np.asarray(view.position, dtype=float)
        v0 = np.asarray(view.velocity, dtype=float)
        base = p0 + 0.5 * self.T * v0
        goal = np.asarray(view.goal, dtype=float)
        goal_r = view.goal_radius - _GOAL_TOL
        cost_rate = self.rho
        # node storage (index = node id): position, velocity, P, J, depth, g, parent, acceleration, goal sample
        node_p = [p0]
        node_v = [v0]
        node_pj = [None]
        node_n = [0]
        node_g = [0.0]
        node_parent = [-1]
        node_a = [np.zeros(d)]
        node_cut = [-1]
        h0 = float(self.heuristic(view, p0[None], v0[None])[0])
        node_h = [h0]
        best_g: dict[bytes, float] = {}
        closed: set[bytes] = set()
        node_key: list[bytes | None] = [None]
        tie = itertools.count()
        open_heap = [(h0, h0, next(tie), 0)]
        s = self._s
        s2 = 0.5 * s * s
        expansions = 0
        status = "exhausted"
        while open_heap:
            f, _, _, nid = heapq.heappop(open_heap)
            if node_cut[nid] >= 0:
                self.last_status = "found"
                self.last_expansions = expansions
                return nid, (node_p, node_v, node_a, node_parent, node_cut, node_g, node_h)
            key = node_key[nid]
            if key is not None:
                if key in closed or node_g[nid] > best_g[key]:
                    continue
                closed.add(key)
            if expansions >= self.max_expansions:
                status = "budget"
                break
            expansions += 1
            n = node_n[nid]
            p, v = node_p[nid], node_v[nid]
            if nid == 0:
                j_end, acc = self.root_children(v0)
                p_end = base + self.c * j_end
                pj = np.concatenate([j_end, j_end], axis=1)
            else:
                P, J = node_pj[nid][:d], node_pj[nid][d:]
                j_end = J + self.acc_int
                ok = np.einsum("cd,cd->c", j_end, j_end) <= self._vj_max2
                jj = self.acc_int[ok]
                j_end = j_end[ok]
                acc = self.accelerations[ok]
                P_end = P + 2 * J + jj
                p_end = base + self.c * P_end
                pj = np.concatenate([P_end, j_end], axis=1)
            if acc.shape[0] == 0:
                continue
            depth = min(n + 1, self.n_horizon)
            keys_arr = np.concatenate([np.full((pj.shape[0], 1), depth, dtype=np.int64), pj], axis=1)
            keys = [row.tobytes() for row in keys_arr]
            fresh = np.array([k not in closed for k in keys], dtype=bool)
            if not fresh.any():
                continue
            idx = np.flatnonzero(fresh)
            acc, p_end, pj = acc[idx], p_end[idx], pj[idx]
            keys = [keys[i] for i in idx]
            pts = p + s[None, :, None] * v + s2[None, :, None] * acc[:, None, :]          # [C, S, d]
            bad = np.any((pts < self._wall_lo) | (pts > self._wall_hi), axis=2)             # [C, S]
            tau = n * self.T + s
            bad |= self._tracks_bad(view, pts, tau)
            flat = pts.reshape(-1, d)
            todo = ~bad.reshape(-1)
            if todo.any():
                gb = np.zeros(flat.shape[0], dtype=bool)
                gb[todo] = self._grid_bad(view.grid, flat[todo])
                bad |= gb.reshape(bad.shape)
            rel = pts - goal
            in_goal = np.einsum("csd,csd->cs", rel, rel) <= goal_r * goal_r
            n_s = s.shape[0]
            first_bad = np.where(bad.any(axis=1), np.argmax(bad, axis=1), n_s)
            first_goal = np.where(in_goal.any(axis=1), np.argmax(in_goal, axis=1), n_s)
            reach_goal = first_goal < first_bad
            clear = first_bad == n_s
            keep = np.flatnonzero(reach_goal | clear)
            if keep.size == 0:
                continue
            a2 = np.einsum("cd,cd->c", acc, acc)
            g_full = node_g[nid] + (a2 + cost_rate) * self.T
            plain = keep[~reach_goal[keep]]
            h = self.heuristic(view, p_end[plain], self.w * pj[plain, d:]) if plain.size else np.zeros(0)
            h_of = dict(zip(plain.tolist(), h.tolist()))
            g_node = node_g[nid]
            for i in keep.tolist():
                if reach_goal[i]:
                    k = int(first_goal[i])
                    g = g_node + (a2[i] + cost_rate) * float(s[k])
                    hh, cut, key = 0.0, k, None
                else:
                    g = float(g_full[i])
                    hh, cut, key = h_of[i], -1, keys[i]
                    old = best_g.get(key)
                    if old is not None and old <= g:
                        continue
                    best_g[key] = g
                cid = len(node_g)
                node_p.append(p_end[i])
                node_v.append(self.w * pj[i, d:].astype(float))
                node_pj.append(pj[i])
                node_n.append(n + 1)
                node_g.append(g)
                node_parent.append(nid)
                node_a.append(acc[i])
                node_cut.append(cut)
                node_h.append(hh)
                node_key.append(key)
                heapq.heappush(open_heap, (g + self.epsilon * hh, hh, next(tie), cid))
        self.last_status = status
        self.last_expansions = expansions
        if status == "budget":
            self.n_budget_hits += 1
        return None

    def _trajectory(self, view: View, found) -> Trajectory:
        """Sample the found path (root -> goal node) at view.dt; fills last_path and last_cost."""
        nid, (node_p, node_v, node_a, node_parent, node_cut, node_g, node_h) = found
        chain = []
        while nid > 0:
            chain.append(nid)
            nid = node_parent[nid]
        chain.reverse()
        s = self._s
        ps, vs, accs = [view.position[None]], [view.velocity[None]], []
        self.last_path = [(np.array(view.position), np.array(view.velocity), 0.0, node_h[0])]
        prev = 0
        for cid in chain:
            a = node_a[cid]
            ss = s[: node_cut[cid] + 1] if node_cut[cid] >= 0 else s
            p, v = node_p[prev], node_v[prev]
            ps.append(p + ss[:, None] * v + 0.5 * (ss * ss)[:, None] * a)
            vs.append(v + ss[:, None] * a)
            accs.append(np.tile(a, (ss.shape[0], 1)))
            end_p, end_v = (ps[-1][-1], vs[-1][-1]) if node_cut[cid] >= 0 else (node_p[cid], node_v[cid])
            self.last_path.append((np.array(end_p), np.array(end_v), node_g[cid], node_h[cid]))
            prev = cid
        acc = np.concatenate(accs)
        acc = np.concatenate([acc, acc[-1:]])      # a[k]: applied from sample k to k + 1; the last keeps its own
        self.last_cost = node_g[chain[-1]]
        return Trajectory(view.t, view.dt, np.concatenate(ps), np.concatenate(vs), acc)
