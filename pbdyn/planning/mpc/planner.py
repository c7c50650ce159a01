"""Model predictive control planner (thesis 4-1-1 "Model Predictive Control", appendix A-3; Zhu & Alonso-Mora 2019).

Every step the planner solves one convex problem (pbdyn.planning.mpc.problem) over N steps of the world dt: a double
integrator (eq. A-5), a quadratic cost toward the goal plus control effort (A-6, A-11), Euclidean norm limits on v
and a as second-order cones (A-8), and collision constraints (A-10) made convex by linearisation:

* Tracks (A-10 with constant-velocity predictions): the M tracks nearest to the reference path give one half-plane
  (3D: half-space) per step, tangent to the predicted disc/ball inflated by the MAV radius + margin, with its normal
  pointing from the predicted centre to the reference path's point at that step. The reference path is the previous
  plan (view.trajectory, read at the same absolute times, extrapolated at constant velocity past its end); without
  one, a constant-velocity guess from the current state. A degenerate normal (the reference point at the centre)
  takes the current obstacle-to-MAV direction. Steps whose reference point lies more than 5 cm inside the inflated
  disc all take the normal of the reference's closest approach, so a reference that runs through an obstacle asks
  for one side of it rather than for "in front" at one step and "behind" at the next.
* Occupied grid cells near the MAV: per step, the n_cells cells nearest to the reference point, each as the
  half-plane through the point of the cell's square (3D: cube) nearest to it. UNKNOWN cells count as free, as in
  pbdyn.planning.checks; the grid's 1-cell border is left to the walls.
* Walls (3D: also floor and ceiling) as a box on the MAV centre, shrunk by the MAV radius + wall_margin.

The right-hand side of every linearised row is the support function of the inflated obstacle in the row's normal,
so any unit normal gives a constraint that excludes the whole obstacle. Symmetric deadlock (an obstacle straight
ahead on the goal line gives a normal exactly against the goal direction, and the plan stops in front of it): every
normal within bias_deg of the reverse goal direction is turned to exactly bias_deg from it, all toward one side per
plan (MPC.bias_side: the MAV's lateral velocity, else the side it is on relative to what blocks it, else the left).

Soft constraints: all rows of a step share one slack s_k (cost w_slack per m) and one margin band b_k in
[0, margin - hard_margin] (cost w_band per m): a plan may give up the safety margin down to hard_margin at a moderate
price, and only what goes beyond that is slack. The problem is therefore always feasible; a plan fails (the MAV
brakes) when the solve is not optimal or a slack exceeds max_slack within the first slack_window_s. Unused rows are
padding (zero normal), so the problem's structure never changes and the solver is built once.

Program prediction (``prediction = "program"``, an interpretation): the thesis program's obstacle predictions
"drifted quadratically because of an aliasing bug" (docs/thesis-program.md "MPC"). Its loop over the horizon steps
added k dt v to an obstacle's position list in place, so the list it started step k from already held step k - 1's
prediction; step k therefore got p + (1 + 2 + ... + k) dt v = p + k (k + 1) / 2 dt v instead of p + k dt v (A-10).
That prediction replaces the constant-velocity one for the track rows only (the choice of the M nearest tracks
included, as the program ranked the drifted positions); the reference path, the cells and the walls are unchanged.
The program's constraints were soft and a plan failed only when its solver did not converge, so PROGRAM_PARAMS
also sets max_slack = MAX_PLAN_DISTANCE_M (a slack never fails a plan). Not reproduced: the program's obstacles
were ellipses (tracks as discs of radius + 1 m, occupied cells within 10 m clustered into ellipses) in a nonlinear
problem solved by a proprietary solver (FORCES Pro), the 5 nearest of tracks and clusters together chosen per step;
here they are the linearised discs of the M nearest tracks and the n_cells nearest cells (a convex problem). Its
cost (0.1 |x - goal|^2 plus slack, docs/thesis-program.md) is not adopted: the generated solver's weights, units
(the program worked in pixels) and any acceleration term are unknown, so w_goal, w_acc and ref_dist keep pbdyn's
values.

Limits: the solver gets v_max (1 - limit_eps) and a_max (1 - limit_eps). The returned trajectory is rebuilt from the
solver's accelerations, each first projected onto the a_max ball, by exact integration of A-5 from the current
state, so it satisfies the dynamics to round-off; a velocity above v_max (possible only beyond the solver's
tolerance) is projected onto the v_max ball.
"""

from __future__ import annotations

import math
import time

import numpy as np

from pbdyn.perception.grid import OCCUPIED
from pbdyn.limits import MAX_PLAN_COUNT, MAX_PLAN_DISTANCE_M, MAX_PLAN_HORIZON_S
from pbdyn.planning import params
from pbdyn.planning.checks import WALL_MARGIN_CAP
from pbdyn.planning.mpc.problem import (INACTIVE_RHS, ClarabelMPC, CvxpyMPCReference, MPCData, MPCShape,
                                        MPCSolution, MPCWeights)
from pbdyn.planning.protocols import PlannerContext
from pbdyn.planning.trajectory import Trajectory
from pbdyn.planning.view import View

_DEGENERATE = 1e-9  # m; a normal shorter than this is degenerate
_MAX_CELLS = 64     # occupied cells kept around the MAV before the per-step choice (nearest to the MAV)
_PENETRATION = 0.05  # m; a reference point deeper than this inside an inflated obstacle penetrates it (a plan
#                    resting on a constraint is never taken as penetrating)
SIDE_SPEED = 0.1    # m/s; a lateral speed above this fixes the side normals are turned to (bias_side)


def _unit(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(x / |x| along the last axis (0 where |x| is degenerate), |x|)."""
    n = np.sqrt(np.einsum("...d,...d->...", x, x))
    safe = np.where(n > _DEGENERATE, n, 1.0)
    return np.where((n > _DEGENERATE)[..., None], x / safe[..., None], 0.0), n


def lateral_axis(gdir: np.ndarray) -> np.ndarray:
    """The default side of the unit goal direction: 2D its left normal; 3D the horizontal left z x gdir (x x gdir
    when gdir is vertical)."""
    if gdir.shape[0] == 2:
        return np.array([-gdir[1], gdir[0]])
    w = np.cross([0.0, 0.0, 1.0], gdir)
    if np.linalg.norm(w) < 1e-6:
        w = np.cross([1.0, 0.0, 0.0], gdir)
    return w / np.linalg.norm(w)


def bias_normals(normals: np.ndarray, side: np.ndarray, gdir: np.ndarray, bias_deg: float) -> np.ndarray:
    """Normals [..., d] with every unit normal that lies within bias_deg of -gdir turned to exactly bias_deg from it,
    toward the unit lateral direction side [d] (perpendicular to gdir); other normals are returned unchanged."""
    if bias_deg <= 0:
        return normals
    cos_b = math.cos(math.radians(bias_deg))
    hit = -normals @ gdir > cos_b                                  # the angle to -gdir is below bias_deg
    if not hit.any():
        return normals
    turned = -cos_b * gdir + math.sin(math.radians(bias_deg)) * side
    return np.where(hit[..., None], turned, normals)


PREDICTIONS = ("constant_velocity", "program")


class MPC:
    """MPC trajectory planner (registry name "mpc"; thesis A-3, eqs. A-5..A-11; Zhu & Alonso-Mora 2019).

    Args:
        context: the trial's fixed facts (dims, dt, limits, arena box).
        horizon: N, the number of steps of the world dt (default 25: 2.5 s at 0.1 s, as the thesis program).
        n_tracks: M, the number of tracks constrained (A-10): the nearest to the reference path over the horizon
            by surface distance, ties by track order; default 5, as the thesis program.
        n_cells: occupied grid cells constrained per step (the nearest to that step's reference point).
        margin: safety margin (m) added to the MAV radius against tracks and cells (as pbdyn.planning.checks).
        hard_margin: the part of the margin (m) that is never traded for cost (see the module doc).
        wall_margin: margin (m) added to the MAV radius against the arena walls (default checks.WALL_MARGIN_CAP).
        w_goal: weight of |p_k - ref|^2 (cost per m^2 at every step k = 1..N; Q of A-11, on position).
        w_acc: weight of |u_k|^2 (cost per (m/s^2)^2 at every step k = 0..N-1; R of A-11).
        w_slack: cost per metre of collision slack per step (L1, exact penalty).
        w_band: cost per metre of margin given up per step (L1).
        ref_dist: the goal reference is the goal, or the point ref_dist (m) from the MAV toward it when the goal is
            further; default 2 v_max N dt. Keeps the cost's scale independent of the arena size.
        bias_deg: symmetric-deadlock breaking angle (deg, see the module doc); 0 disables it.
        max_slack: largest slack (m) accepted within the first slack_window_s (s) of a plan.
        relinearise: extra solves per step, each linearised about the previous solve's path, while the slack
            test fails (0: one solve per step).
        limit_eps: relative tightening of v_max and a_max given to the solver.
        backend: "clarabel" (the problem written directly in Clarabel's form, a persistent solver whose data is
            updated each step) or "cvxpy" (the same problem built once in cvxpy with Parameters and re-solved with
            Clarabel); a test checks that they agree.
        prediction: the tracks' predicted centres in the track rows: "constant_velocity" (default, p + k dt v,
            A-10) or "program" (p + k (k + 1) / 2 dt v, the thesis program's aliasing bug; see the module doc).

    PROGRAM_PARAMS: the parameters that reproduce the thesis program (merged under a scenario's own params under the
    "thesis_program" profile): its prediction, and no plan failure on slack (its constraints were soft). Its horizon
    (25 x 0.1 s), its 5 nearest obstacles and |v| <= v_max are the defaults already; see the module doc for what
    is not reproduced.

    Diagnostics of the last plan() call: last_data (MPCData), last_solution (MPCSolution), last_max_slack (m, over
    the slack window), last_fail_reason (None on success), last_solve_wall_s (problem set-up and solves, s),
    last_relinearisations, last_track_index (indices into view.tracks of the constrained tracks, in row order).
    """

    PROGRAM_PARAMS: dict = {"prediction": "program", "max_slack": MAX_PLAN_DISTANCE_M}

    def __init__(self, context: PlannerContext, *, horizon: int = 25, n_tracks: int = 5, n_cells: int = 6,
                 margin: float = 0.5, hard_margin: float = 0.1, wall_margin: float = WALL_MARGIN_CAP,
                 w_goal: float = 1.0, w_acc: float = 0.1, w_slack: float = 1.0e4, w_band: float = 1.0e3,
                 ref_dist: float | None = None, bias_deg: float = 15.0,
                 max_slack: float = 0.05, slack_window_s: float = 1.0, relinearise: int = 0,
                 limit_eps: float = 1.0e-6, backend: str = "clarabel", prediction: str = "constant_velocity"):
        horizon = params.integer("horizon", horizon, lo=2, hi=int(MAX_PLAN_HORIZON_S))
        n_tracks = params.integer("n_tracks", n_tracks, lo=0, hi=MAX_PLAN_COUNT)
        n_cells = params.integer("n_cells", n_cells, lo=0, hi=MAX_PLAN_COUNT)
        wall_margin = params.non_negative("wall_margin", wall_margin)
        max_slack = params.non_negative("max_slack", max_slack)
        slack_window_s = params.non_negative("slack_window_s", slack_window_s)
        margin = params.non_negative("margin", margin)
        hard_margin = params.number("hard_margin", hard_margin, lo=0.0, hi=margin)
        w_goal, w_acc = params.positive("w_goal", w_goal), params.positive("w_acc", w_acc)
        w_slack, w_band = params.positive("w_slack", w_slack), params.positive("w_band", w_band)
        if ref_dist is not None:
            ref_dist = params.positive("ref_dist", ref_dist)
        bias_deg = params.number("bias_deg", bias_deg, lo=0.0, hi=90.0, hi_open=True)
        limit_eps = params.number("limit_eps", limit_eps, lo=0.0, hi=0.1, hi_open=True)
        if backend not in ("clarabel", "cvxpy"):
            raise ValueError(f"backend must be 'clarabel' or 'cvxpy', got {backend!r}")
        if prediction not in PREDICTIONS:
            raise ValueError(f"prediction must be one of {', '.join(PREDICTIONS)}, got {prediction!r}")
        self.dims = d = int(context.dims)
        if d not in (2, 3):
            raise ValueError(f"dims must be 2 or 3, got {d}")
        self.dt = float(context.dt)
        self.limits = lim = context.limits
        self.horizon = int(horizon)
        self.n_tracks = int(n_tracks)
        self.n_cells = int(n_cells)
        self.margin = float(margin)
        self.hard_margin = float(hard_margin)
        self.wall_margin = float(wall_margin)
        self.ref_dist = float(ref_dist) if ref_dist is not None else 2.0 * lim.v_max * self.horizon * self.dt
        self.bias_deg = float(bias_deg)
        self.max_slack = float(max_slack)
        relinearise = params.integer("relinearise", relinearise, lo=0, hi=100)
        self.relinearise = int(relinearise)
        self.last_relinearisations = 0
        self.slack_steps = int(math.floor(slack_window_s / self.dt + 1e-9))
        self.limit_eps = float(limit_eps)
        self.backend = backend
        self.prediction = prediction
        self.weights = MPCWeights(float(w_goal), float(w_acc), float(w_slack), float(w_band))
        self.shape = MPCShape(d, self.horizon, self.dt, self.n_tracks + self.n_cells)
        self._solver = (ClarabelMPC if backend == "clarabel" else CvxpyMPCReference)(self.shape, self.weights)
        self._k = np.arange(1, self.horizon + 1)
        k = self._k.astype(float)
        # seconds ahead at which the track rows read the tracks' constant-velocity predictions, per step k = 1..N
        self._pred_tau = (k * self.dt) if prediction == "constant_velocity" else (0.5 * k * (k + 1.0)) * self.dt
        self.last_data: MPCData | None = None
        self.last_solution: MPCSolution | None = None
        self.last_max_slack = math.nan
        self.last_fail_reason: str | None = None
        self.last_solve_wall_s = 0.0
        self.last_track_index = np.zeros(0, np.int64)

    def replan_check(self, view: View) -> bool:
        """Always True: receding horizon, a new plan every step."""
        return True

    # ------------------------------------------------------------------ linearisation

    def reference_path(self, view: View) -> np.ndarray:
        """Linearisation points [N, d] (m) at view.t + k dt, k = 1..N: the plan in execution read at those times
        (constant velocity past its end), or the constant-velocity guess p + k dt v without one."""
        tau = self._k * self.dt
        tr = view.trajectory
        if tr is None or not tr.covers(view.t):
            return view.position + tau[:, None] * view.velocity
        idx = np.rint((view.t + tau - tr.t0) / tr.dt).astype(np.int64)      # as Trajectory.index_at
        inside = idx < tr.n_samples
        last = tr.n_samples - 1
        extra = (idx - last) * tr.dt
        return np.where(inside[:, None], tr.p[np.minimum(idx, last)], tr.p[last] + extra[:, None] * tr.v[last])

    def goal_direction(self, view: View) -> np.ndarray:
        """Unit direction from the MAV to the goal (to its velocity, else +x, when at the goal)."""
        g, n = _unit(view.goal - view.position)
        if n > 1e-6:
            return g
        v, nv = _unit(np.asarray(view.velocity, float))
        if nv > 1e-6:
            return v
        e = np.zeros(self.dims)
        e[0] = 1.0
        return e

    def _fallback(self, view: View, x: np.ndarray) -> np.ndarray:
        """Unit vectors of x [..., d]; degenerate ones become lateral_axis(goal direction)."""
        u, n = _unit(x)
        return np.where((n > _DEGENERATE)[..., None], u, lateral_axis(self.goal_direction(view)))

    def obstacle_prediction(self, tracks) -> np.ndarray:
        """Predicted track centres [N, M, d] (m) used by the track rows at steps k = 1..N: p + k dt v, or under
        prediction = "program" p + k (k + 1) / 2 dt v (module doc)."""
        return tracks.predict(self._pred_tau)

    def track_rows(self, view: View, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rows of the M nearest tracks: unit normals [M, N, d] (0 for padding), predicted centres [M, N, d] (m) and
        inflated radii [M] (track radius + MAV radius + margin, m). Nearest = smallest surface distance to the
        reference path over the horizon (ties by track order)."""
        n, d, m = self.horizon, self.dims, self.n_tracks
        normals = np.zeros((m, n, d))
        centres = np.zeros((m, n, d))
        reach = np.zeros(m)
        tracks = view.tracks
        self.last_track_index = np.zeros(0, np.int64)
        if m == 0 or len(tracks) == 0:
            return normals, centres, reach
        pred = self.obstacle_prediction(tracks)                               # [N, T, d]
        nrm, dist = _unit(ref[:, None, :] - pred)
        score = (dist - tracks.radius[None, :]).min(axis=0)
        sel = np.argsort(score, kind="stable")[:m]
        self.last_track_index = sel
        now = self._fallback(view, view.position - tracks.position[sel])      # obstacle -> MAV, now [S, d]
        nrm, dist = nrm[:, sel], dist[:, sel]
        nrm = np.where((dist > _DEGENERATE)[..., None], nrm, now[None])
        k = sel.shape[0]
        reach[:k] = tracks.radius[sel] + self.limits.radius + self.margin
        # steps whose reference point is inside the inflated disc all take the normal of the closest approach, so a
        # reference passing through an obstacle asks for one side of it instead of flipping from front to back
        kstar = np.argmin(dist, axis=0)                                       # [S]
        side = nrm[kstar, np.arange(k)]                                       # [S, d]
        inside = dist < reach[None, :k] - _PENETRATION
        nrm = np.where(inside[..., None], side[None], nrm)
        normals[:k] = np.swapaxes(nrm, 0, 1)
        centres[:k] = np.swapaxes(pred[:, sel], 0, 1)
        return normals, centres, reach

    def cell_rows(self, view: View, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rows of occupied cells: per step the n_cells cells nearest to the reference point; unit normals
        [n_cells, N, d] from the cell's nearest point to the reference point (0 for padding) and cell centres
        [n_cells, N, d] (m)."""
        n, d, m = self.horizon, self.dims, self.n_cells
        normals = np.zeros((m, n, d))
        centres = np.zeros((m, n, d))
        if m == 0:
            return normals, centres
        lo_cells = self.nearby_cells(view)                                     # [C, d] lower corners
        if lo_cells.shape[0] == 0:
            return normals, centres
        res = view.grid.res
        hi_cells = lo_cells + res
        q = np.clip(ref[:, None, :], lo_cells[None], hi_cells[None])          # [N, C, d] nearest box points
        nrm, dist = _unit(ref[:, None, :] - q)
        k = min(m, lo_cells.shape[0])
        sel = np.argsort(dist, axis=1, kind="stable")[:, :k]                  # [N, k]
        nrm = np.take_along_axis(nrm, sel[..., None], axis=1)
        dist = np.take_along_axis(dist, sel, axis=1)
        lo_sel = lo_cells[sel]                                                 # [N, k, d]
        now, now_n = _unit(view.position - np.clip(view.position, lo_sel, lo_sel + res))
        now_c = self._fallback(view, view.position - (lo_sel + 0.5 * res))
        now = np.where((now_n > _DEGENERATE)[..., None], now, now_c)
        nrm = np.where((dist > _DEGENERATE)[..., None], nrm, now)
        normals[:k] = np.swapaxes(nrm, 0, 1)
        centres[:k] = np.swapaxes(lo_sel + 0.5 * res, 0, 1)
        return normals, centres

    def nearby_cells(self, view: View) -> np.ndarray:
        """Lower corners [C, d] (m) of the OCCUPIED cells (not the wall border) within reach of this plan, at most
        64, nearest to the MAV first (ties by flat index)."""
        grid = view.grid
        reach = self.limits.v_max * self.horizon * self.dt + self.limits.radius + self.margin + 2.0 * grid.res
        lo_i = grid.index(view.position - reach)
        hi_i = grid.index(view.position + reach)
        lo_i = np.maximum(lo_i, 1)
        hi_i = np.minimum(hi_i, np.asarray(grid.shape) - 2)
        if np.any(hi_i < lo_i):
            return np.zeros((0, self.dims))
        window = grid.cells[tuple(slice(a, b + 1) for a, b in zip(lo_i, hi_i))]
        idx = np.argwhere(window == OCCUPIED)
        if idx.shape[0] == 0:
            return np.zeros((0, self.dims))
        lo = grid.origin + (idx + lo_i) * grid.res
        q = np.clip(view.position, lo, lo + grid.res)
        dist = np.linalg.norm(view.position - q, axis=1)
        keep = np.argsort(dist, kind="stable")[:_MAX_CELLS]
        return lo[keep[dist[keep] <= reach]]

    def bias_side(self, view: View, normals: np.ndarray, gdir: np.ndarray) -> np.ndarray:
        """The one lateral side (unit [d], perpendicular to gdir) toward which this plan turns normals that lie within
        bias_deg of -gdir: the MAV's lateral velocity if above SIDE_SPEED, else the sum of those normals' lateral
        parts (the side the MAV is on relative to what blocks it), else lateral_axis(gdir)."""
        v = np.asarray(view.velocity, float)
        lat_v = v - (v @ gdir) * gdir
        if float(np.linalg.norm(lat_v)) > SIDE_SPEED:
            return lat_v / np.linalg.norm(lat_v)
        c = -normals @ gdir
        blocking = normals[c > math.cos(math.radians(self.bias_deg))]
        if blocking.shape[0]:
            lat = blocking.sum(axis=0)
            lat -= (lat @ gdir) * gdir
            if float(np.linalg.norm(lat)) > 1e-6:
                return lat / np.linalg.norm(lat)
        return lateral_axis(gdir)

    def problem_data(self, view: View, ref_path: np.ndarray | None = None) -> MPCData:
        """The parameter values of this step's problem (see pbdyn.planning.mpc.problem and the module doc),
        linearised about ref_path [N, d] (default: reference_path(view))."""
        p0 = np.asarray(view.position, float)
        if ref_path is None:
            ref_path = self.reference_path(view)
        gdir = self.goal_direction(view)
        tn, tc, reach = self.track_rows(view, ref_path)
        cn, cc = self.cell_rows(view, ref_path)
        normals = np.concatenate([tn, cn])                                    # [R, N, d]
        zero = ~np.any(normals != 0.0, axis=-1)                               # padding rows
        real = normals[~zero]
        if self.bias_deg > 0 and real.shape[0]:
            side = self.bias_side(view, real, gdir)
            normals = np.where(zero[..., None], 0.0, bias_normals(normals, side, gdir, self.bias_deg))
        inflate = self.limits.radius + self.margin
        rhs_t = np.einsum("mnd,mnd->mn", normals[:self.n_tracks], tc) + reach[:, None]
        cn = normals[self.n_tracks:]
        rhs_c = np.einsum("mnd,mnd->mn", cn, cc) + 0.5 * view.grid.res * np.abs(cn).sum(-1) + inflate
        rhs = np.where(zero, INACTIVE_RHS, np.concatenate([rhs_t, rhs_c]))
        to_goal = view.goal - p0
        dist = float(np.linalg.norm(to_goal))
        goal_ref = view.goal if dist <= self.ref_dist else p0 + to_goal * (self.ref_dist / dist)
        wall = self.limits.radius + self.wall_margin
        scale = 1.0 - self.limit_eps
        return MPCData(p0.copy(), np.asarray(view.velocity, float).copy(), np.tile(goal_ref, (self.horizon, 1)),
                       normals, rhs, view.bounds_lo + wall, view.bounds_hi - wall, self.limits.v_max * scale,
                       self.limits.a_max * scale, self.margin - self.hard_margin)

    # ------------------------------------------------------------------ plan

    def solve(self, data: MPCData) -> MPCSolution:
        """Solve one problem with the configured backend."""
        return self._solver.solve(data)

    def plan(self, view: View) -> Trajectory | None:
        """The MPC trajectory (N + 1 samples, sample 0 = the current state; a[k] is the acceleration from sample k
        to k + 1, a[N] = 0), or None if the solve is not optimal or a slack within the slack window exceeds
        max_slack."""
        if abs(view.dt - self.dt) > 1e-12:
            raise ValueError(f"view.dt {view.dt} differs from the planner's dt {self.dt}")
        t0 = time.perf_counter()
        data = self.problem_data(view)
        sol = self.solve(data)
        window = sol.s[:self.slack_steps]
        self.last_max_slack = float(np.max(window)) if window.size else 0.0
        self.last_relinearisations = 0
        while (sol.optimal and self.last_max_slack > self.max_slack
               and self.last_relinearisations < self.relinearise):
            self.last_relinearisations += 1
            data2 = self.problem_data(view, sol.p)
            sol2 = self.solve(data2)
            window = sol2.s[:self.slack_steps]
            slack2 = float(np.max(window)) if window.size else 0.0
            if not sol2.optimal or slack2 >= self.last_max_slack:
                break
            data, sol, self.last_max_slack = data2, sol2, slack2
        self.last_solve_wall_s = time.perf_counter() - t0
        self.last_data, self.last_solution = data, sol
        self.last_fail_reason = None
        if not sol.optimal:
            self.last_fail_reason = f"solver status {sol.status}"
            return None
        if not np.all(np.isfinite(sol.u)) or self.last_max_slack > self.max_slack:
            self.last_fail_reason = f"slack {self.last_max_slack:.3g} m within the first {self.slack_steps} steps"
            return None
        return self._trajectory(view, sol.u)

    def _trajectory(self, view: View, u: np.ndarray) -> Trajectory:
        """Samples of A-5 integrated exactly from the current state with u projected onto the a_max ball."""
        a_max, v_max, dt = self.limits.a_max, self.limits.v_max, self.dt
        un = np.linalg.norm(u, axis=1)
        u = np.where((un > a_max)[:, None], u * (a_max / np.maximum(un, 1e-300))[:, None], u)
        n, d = self.horizon, self.dims
        p = np.empty((n + 1, d))
        v = np.empty((n + 1, d))
        p[0], v[0] = view.position, view.velocity
        v[1:] = v[0] + dt * np.cumsum(u, axis=0)
        p[1:] = p[0] + dt * np.cumsum(v[:-1], axis=0) + (0.5 * dt * dt) * np.cumsum(u, axis=0)
        vn = np.linalg.norm(v[1:], axis=1)
        over = vn > v_max
        if over.any():
            v[1:][over] *= (v_max / vn[over])[:, None]
        a = np.zeros((n + 1, d))
        a[:n] = u
        return Trajectory(view.t, dt, p, v, a)
