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
min(margin, WALL_MARGIN_CAP)); v is linear in time along a primitive and |v| convex, so |v| <= v_max at its two ends
bounds it everywhere. A child whose samples reach the goal ball (|p - goal| <= goal_radius) before any conflict is a
goal node: its primitive is cut at that sample and its cost counts up to it; plans always end in the goal ball.
Children are generated and checked for all accelerations of a node at once (numpy); occupied cells are screened per
grid version (astar_static: exact, with point-to-box distances only near the boundary of the blocked region).

Trajectory: sample 0 is the current state; then every primitive sampled at the world dt in closed form
(p + v s + a s^2 / 2, v + a s); a[k] is the acceleration applied from sample k to k + 1 (the last sample keeps its
primitive's acceleration). The planner keeps the plan until replan_check finds that its remaining samples meet the
latest predictions (within the horizon) or a newly occupied cell (checked when the grid's version changed), or that
it has run out (thesis 4-1-1 "replanning check", A-2, A-3).

Program mode: the thesis program's "Primitive" planner (docs/thesis-program.md "Trajectory planners"; the thesis
text gives only Algorithm 2 and eq. A-1; details below were read from the program, whose unit was 10 px = 1 m).
``accel_grid = "program"``: every node, the root included, gets the same per-axis grid of accelerations, the
program's np.arange(-a_max, a_max, step) with step = 0.4 v_max - 0.5 m/s^2 for v_max <= 4 m/s and 0.4 m/s^2 above
(program_accel_values): 27 / 8 / 20 values per axis at v_max 2 / 4 / 6 m/s (729 / 64 / 400 children in 2D). The
grid is asymmetric (a_max itself is excluded), lacks 0 at 2 and 4 m/s (the program's defect, reproduced) and bounds
each axis, not the norm (|a| up to a_max sqrt(d)). Other speeds follow the same rule; below 2 m/s the 2 m/s grid is
used (the rule gives ever finer grids below it and none at 1.25 m/s). A child's end speed must be strictly below
v_max. These states lie on no common lattice, so nodes are keyed as the program keyed them: by the position's 1 m
cell (the floor of the position rounded to 0.1 m) and the velocity rounded to 0.1 m/s, with no time or depth
(program_keys; the root's key included). States with one key merge: a child with a lower cost replaces the key's
open node (the replaced one is never expanded), and a closed key refuses every later child. Under
PlannerContext.physical = True (the physical profile) children with |a| > a_max are dropped, so plans keep the plan
contract; under physical = False (thesis_program) the full grid is searched.
``heuristic = "program"``: the program ordered nodes by g + 0.5 |p - goal| + 0.1 |v| in pixels, with an edge cost
of |a|^2 + 10 per primitive (a in m/s^2). pbdyn's edge cost (|a|^2 + rho) T is T times that for rho = 10, so the
same order is g + T (5 |p - goal| + 1 |v|), p in m, v in m/s (program_heuristic; not the LQMT bound, and not
admissible). Not reproduced: the program rounded node and trajectory positions to 0.1 m, checked collisions at
2 v_max samples per primitive (pbdyn: every dt), tested occupied cells at 5 points (the centre and radius + 1 m along
each axis; pbdyn: the whole MAV disc + margin) and replanned against the tracks without the margin; its goal test
was a node end within 1 m (pbdyn: the first sample within the goal ball, as in the default mode).
"""

from __future__ import annotations

import heapq
import itertools
import math

import numpy as np

from pbdyn.limits import MAX_PLAN_COUNT, MAX_PLAN_HORIZON_S
from pbdyn.planning import params
from pbdyn.planning.checks import WALL_MARGIN_CAP
from pbdyn.planning.primitives.astar_goal import GOAL_TOL
from pbdyn.planning.primitives.astar_heuristic import lqmt_lower_bound
from pbdyn.planning.primitives.astar_static import StaticScreen
from pbdyn.planning.protocols import PlannerContext
from pbdyn.planning.trajectory import Trajectory
from pbdyn.planning.view import Tracks, View

_A_TOL = 1e-12  # m/s^2: root accelerations may exceed a_max by this rounding slack


def acceleration_grid(n_accel: int, dims: int) -> np.ndarray:
    """Integer acceleration offsets j [C, d] in {-m..m}^d with |j| <= m, m = (n_accel - 1) / 2 (lexicographic)."""
    m = (n_accel - 1) // 2
    j = np.array(list(itertools.product(range(-m, m + 1), repeat=dims)), dtype=np.int64)
    return j[np.einsum("cd,cd->c", j, j) <= m * m]


ACCEL_GRIDS = ("norm_lattice", "program")
HEURISTICS = ("lqmt", "program")
SEARCHES = ("auto", "python", "compiled")
PROGRAM_PX = 0.1         # m: the program's length unit (10 px = 1 m); its node keys round to it
PROGRAM_KEY_CELL_PX = 10  # a program node key's position cell (px): 1 m, the program's grid cell
_PX_PER_M = 10.0
PROGRAM_H_DIST = 5.0     # program heuristic per metre to the goal (0.5 per px), in the program's cost units
PROGRAM_H_SPEED = 1.0    # program heuristic per m/s of speed (0.1 per px/s)
PROGRAM_MIN_V_MAX = 2.0  # m/s: below this speed the program grid of 2 m/s is used


def program_accel_values(v_max: float, a_max: float) -> np.ndarray:
    """The thesis program's per-axis accelerations (m/s^2): np.arange(-a_max, a_max, step) with step = 0.4 v - 0.5
    m/s^2 for v <= 4 m/s, else 0.4 m/s^2, v = max(v_max, 2 m/s) (m/s); 27 / 8 / 20 values at v_max 2 / 4 / 6 with
    a_max 4 (no 0 at 2 and 4 m/s). The program's rule in pixels: step 0.4 v_max - 5 px/s^2 (<= 40 px/s), else 4."""
    v_px = max(float(v_max), PROGRAM_MIN_V_MAX) * _PX_PER_M          # computed in pixels, as the program did
    a_px = float(a_max) * _PX_PER_M
    step = 0.4 * v_px - 5.0 if v_px <= 40.0 else 4.0
    n = int(math.ceil(2.0 * a_px / step - 1e-9))
    return (-a_px + step * np.arange(n)) / _PX_PER_M


def program_acceleration_grid(v_max: float, a_max: float, dims: int) -> np.ndarray:
    """The program's accelerations [n^d, d] (m/s^2): every combination of program_accel_values per axis, first axis
    slowest (the program's nested loops); no norm bound."""
    vals = program_accel_values(v_max, a_max)
    return np.array(list(itertools.product(vals, repeat=dims)), dtype=float).reshape(-1, dims)


def program_heuristic(goal: np.ndarray, p: np.ndarray, v: np.ndarray, duration: float) -> np.ndarray:
    """The program's heuristic [N] in pbdyn's cost units: T (5 |goal - p| + 1 |v|) for states p, v [N, d] (m, m/s),
    T = duration (s) (the program's 0.5 |p - goal| + 0.1 |v| in pixels, scaled as the edge cost; see the module
    doc). Not admissible."""
    rel = np.asarray(goal, dtype=float) - np.atleast_2d(p)
    v = np.atleast_2d(v)
    return duration * (PROGRAM_H_DIST * np.sqrt(np.einsum("nd,nd->n", rel, rel))
                       + PROGRAM_H_SPEED * np.sqrt(np.einsum("nd,nd->n", v, v)))


def program_keys(p: np.ndarray, v: np.ndarray) -> list:
    """Program node keys of states p, v [N, d] (m, m/s): (1 m cell of the position rounded to 0.1 m, velocity
    rounded to 0.1 m/s) per row, as tuples of ints (the program's round(x_px) // 10, round(v_px))."""
    cell = np.floor_divide(np.rint(np.atleast_2d(p) / PROGRAM_PX), PROGRAM_KEY_CELL_PX)
    cols = np.concatenate([cell, np.rint(np.atleast_2d(v) / PROGRAM_PX)], axis=1).astype(np.int64)
    return list(map(tuple, cols.tolist()))


class _Nodes:
    """Node storage of one search; a node's id is its index."""

    __slots__ = ("p", "v", "P", "J", "n", "g", "h", "parent", "a", "cut", "key", "base")

    def __init__(self, base: np.ndarray) -> None:
        for name in self.__slots__[:-1]:
            setattr(self, name, [])
        self.base = base  # lattice origin (m): node p = base + c P

    def add(self, p, v, P, J, n, g, h, parent, a, cut, key) -> int:
        for name, value in zip(self.__slots__[:-1], (p, v, P, J, n, g, h, parent, a, cut, key)):
            getattr(self, name).append(value)
        return len(self.g) - 1


class GlobalPrimitives:
    """Global motion primitives planner (registry name "global_primitives", thesis A-1, Algorithm 2).

    Args:
        context: the trial's fixed facts (dims, dt, limits, arena box).
        duration_s: primitive duration T (s), default 1 s; rounded to a whole number (>= 1) of world steps.
        n_accel: acceleration grid size per axis (odd, >= 3), default (None) 7: accelerations k a_max / m, k = -m..m,
            m = (n_accel - 1) / 2, keeping |a| <= a_max: 29 primitives per node in 2D, 123 in 3D; velocity lattice
            step 4/3 m/s and position step c = 2/3 m at T = 1 s, a_max = 4 m/s^2. Positions keep the parity of the
            velocities (P - J even), so a straight pass misses a goal by up to c sqrt(d - 1) sideways: keep that
            below the goal radius (n_accel = 5 gives c = 1 m, and goals in 3D become unreachable).
        rho: time weight of the edge cost |a|^2 T + rho T (cost units (m/s^2)^2 s; rho in (m/s^2)^2, the rho of
            thesis eq. A-1), default 10: time dominates, so the MAV cruises near v_max.
        epsilon: heuristic weight: nodes are ordered by g + epsilon h (weighted A*), default 1.5; the returned
            path costs at most about epsilon times the lattice optimum (exactly for a consistent heuristic; this
            one is consistent up to its interval discretisation). 1.0 is plain A* (10-100x more expansions in
            open space, where near-equal-cost paths form wide plateaus).
        max_expansions: search budget, a count of expanded nodes (deterministic, never wall time), default 20000
            (tools/bench/bench_global_primitives.py: never hit on the hardest controlled setup, where failed
            searches empty the open list after a few expansions).
        horizon_s: prediction horizon (s), default 5: samples further ahead are not checked against the tracks.
        margin: safety margin (m) added to the MAV radius, default 0.5 (as local_primitives, the thesis program).
        lattice_time_bound: if True (default) the heuristic's minimum time also uses the lattice's velocities
            (astar_heuristic): a bound on every lattice path, much tighter where lattice speeds toward the goal
            are below v_max; False: the bound on every feasible trajectory (always so with the program grid).
        accel_grid: "norm_lattice" (default: the lattice above) or "program" (the thesis program's per-axis grid,
            sized by v_max, and its node keys; see the module doc). n_accel applies to "norm_lattice" only.
        heuristic: "lqmt" (default: astar_heuristic.lqmt_lower_bound) or "program" (program_heuristic).
        search: "auto" (default), "python" (_search_reference / _expand) or "compiled" (the same search in one
            numba call, pbdyn.planning.primitives.compiled.astar; needs accel_grid "norm_lattice" and heuristic
            "lqmt"; falls back to "python" when the lattice's keys do not pack into one int64). "auto" is
            "compiled" where the kernel repeats numpy's float orders on this machine (compiled.astar.numpy_modes'
            ``exact``: the two searches give the same plans bit for bit) and "python" elsewhere, so the default
            never changes a result.

    PROGRAM_PARAMS: the parameters that reproduce the thesis program (merged under a scenario's own params under
    the "thesis_program" profile): its grid, heuristic and node keys, 2 s primitives, plain A* (epsilon 1), no
    prediction horizon (it checked every sample against the predictions), and its budget: its loop gave up at the
    100th iteration, an iteration being one pop, so a goal popped after at most 98 expansions was found and none
    later (max_expansions = 98 here, where a goal node popped after max_expansions expansions is still accepted).
    rho = 10 and margin = 0.5 m are the defaults already.

    Heuristic: astar_heuristic.lqmt_lower_bound, the LQMT bound with free final time and free final velocity to
    the goal ball's edge; it never overestimates (eq. A-1 with T fixed and final velocity 0 can, and is not used).

    Diagnostics: last_status ("found", "exhausted" = open list empty, "budget", or None before any plan),
    last_expansions, last_cost (cost of the returned path), last_path (per node, root first: (p, v, g, h); for
    the goal node the state at its cut sample), n_plans and n_budget_hits (counted over this planner's life).
    """

    PROGRAM_PARAMS: dict = {"accel_grid": "program", "heuristic": "program", "duration_s": 2.0, "epsilon": 1.0,
                             "max_expansions": 98, "horizon_s": MAX_PLAN_HORIZON_S}

    def __init__(self, context: PlannerContext, *, duration_s: float = 1.0, n_accel: int | None = None,
                 rho: float = 10.0, epsilon: float = 1.5, max_expansions: int = 20000, horizon_s: float = 5.0,
                 margin: float = 0.5, lattice_time_bound: bool = True, accel_grid: str = "norm_lattice",
                 heuristic: str = "lqmt", search: str = "auto"):
        d = int(context.dims)
        if d not in (2, 3):
            raise ValueError(f"dims must be 2 or 3, got {d}")
        if accel_grid not in ACCEL_GRIDS:
            raise ValueError(f"accel_grid must be one of {', '.join(ACCEL_GRIDS)}, got {accel_grid!r}")
        if heuristic not in HEURISTICS:
            raise ValueError(f"heuristic must be one of {', '.join(HEURISTICS)}, got {heuristic!r}")
        if search not in SEARCHES:
            raise ValueError(f"search must be one of {', '.join(SEARCHES)}, got {search!r}")
        if search == "compiled" and (accel_grid, heuristic) != ("norm_lattice", "lqmt"):
            raise ValueError("search 'compiled' needs accel_grid 'norm_lattice' and heuristic 'lqmt'")
        program = accel_grid == "program"
        if program and n_accel is not None:
            raise ValueError("n_accel applies to accel_grid 'norm_lattice' only (the program grid is sized by v_max)")
        if n_accel is None:
            n_accel = 7
        if isinstance(n_accel, bool) or not isinstance(n_accel, (int, np.integer)) or n_accel < 3 \
                or n_accel % 2 != 1:
            raise ValueError(f"n_accel must be an odd integer >= 3, got {n_accel!r}")
        for name, value in (("duration_s", duration_s), ("horizon_s", horizon_s)):
            params.number(name, value, lo=0.0, lo_open=True, hi=MAX_PLAN_HORIZON_S)
        params.positive("rho", rho)
        if not (math.isfinite(float(epsilon)) and float(epsilon) >= 1.0):
            raise ValueError(f"epsilon must be a finite number >= 1, got {epsilon!r}")
        if not (math.isfinite(float(margin)) and float(margin) >= 0):
            raise ValueError(f"margin must be a finite number >= 0, got {margin!r}")
        max_expansions = params.integer("max_expansions", max_expansions, lo=1, hi=MAX_PLAN_COUNT)
        if not int(n_accel) <= 101:
            raise ValueError(f"n_accel must be <= 101, got {n_accel!r}")
        self.dims = d
        self.dt = float(context.dt)
        self.limits = lim = context.limits
        self.bounds_lo = np.asarray(context.bounds_lo, dtype=float)
        self.bounds_hi = np.asarray(context.bounds_hi, dtype=float)
        self.steps_per_primitive = max(1, int(round(float(duration_s) / self.dt)))
        self.T = T = self.steps_per_primitive * self.dt
        self.accel_grid = accel_grid
        self.heuristic_kind = heuristic
        self.physical = bool(context.physical)
        self._program = program
        self.rho = float(rho)
        self.epsilon = float(epsilon)
        self.max_expansions = int(max_expansions)
        self.horizon_s = float(horizon_s)
        self.margin = float(margin)
        self.lattice_time_bound = bool(lattice_time_bound)
        self.n_horizon = max(1, int(math.ceil(self.horizon_s / T - 1e-9)))
        if program:
            self._init_program_grid(lim, d)
        else:
            self._init_lattice(lim, d, int(n_accel))
        self._s = self.dt * np.arange(1, self.steps_per_primitive + 1)   # sample offsets in a primitive [S] (s)
        self._s2 = 0.5 * self._s * self._s
        self._table = self._s2[None, :, None] * self.accelerations[:, None, :]   # [C, S, d]
        self._edge_cost = (np.einsum("cd,cd->c", self.accelerations, self.accelerations) + self.rho) * T
        self._reach = lim.radius + self.margin
        wall = lim.radius + min(self.margin, WALL_MARGIN_CAP)
        self._wall_lo = self.bounds_lo + wall
        self._wall_hi = self.bounds_hi - wall
        self._static: StaticScreen | None = None
        self._checked_grid = None
        self._checked_version = -1
        self.last_status: str | None = None
        self.last_expansions = 0
        self.last_cost = math.nan
        self.last_path: list[tuple[np.ndarray, np.ndarray, float, float]] = []
        self.n_plans = 0
        self.n_budget_hits = 0
        self._compiled = None
        lattice = (accel_grid, heuristic) == ("norm_lattice", "lqmt")
        if search != "python" and lattice and self._int_keys:
            from pbdyn.planning.primitives.compiled.astar import CompiledSearch

            compiled = CompiledSearch(self)
            if search == "compiled" or compiled.exact:
                self._compiled = compiled
        self.search_kind = "python" if self._compiled is None else "compiled"   # the search plan() runs

    # ------------------------------------------------------------------ lattice and heuristic

    def _init_lattice(self, lim, d: int, n_accel: int) -> None:
        """The norm-bounded acceleration lattice (module doc) and its packed integer node keys (depth, P, J)."""
        T = self.T
        self.n_accel = n_accel
        self.m = (self.n_accel - 1) // 2
        self.du = lim.a_max / self.m                     # m/s^2 per acceleration index
        self.w = self.du * T                             # m/s per velocity index
        self.c = 0.5 * self.du * T * T                   # m per position index
        self.acc_int = acceleration_grid(self.n_accel, d)            # [C, d]
        self.accelerations = self.du * self.acc_int                   # [C, d] m/s^2
        self._vj_max2 = (lim.v_max / self.w) ** 2 * (1.0 + 1e-12)
        jm = int(math.floor(lim.v_max / self.w + 1e-9))
        vel_int = np.array(list(itertools.product(range(-jm, jm + 1), repeat=d)), dtype=np.int64)
        self.lattice_velocities = self.w * vel_int[np.einsum("vd,vd->v", vel_int, vel_int) <= self._vj_max2]
        # integer keys: (depth, P, J) packed into one int64
        extent = float(np.max(self.bounds_hi - self.bounds_lo)) + 2.0 * (lim.v_max * T + lim.a_max * T * T) + 10.0
        p_span = int(math.ceil(extent / self.c)) + 2
        widths = [self.n_horizon + 1] + [2 * p_span + 1] * d + [2 * jm + 1] * d
        self._key_off = np.array([0] + [p_span] * d + [jm] * d, dtype=np.int64)
        self._key_mult = np.cumprod([1] + widths[:-1]).astype(np.int64)
        self._int_keys = math.prod(widths) < 2 ** 62

    def _init_program_grid(self, lim, d: int) -> None:
        """The thesis program's acceleration grid (program_acceleration_grid), without the children over a_max when
        the profile is physical; no lattice (du, w, c, m are NaN, acc_int and lattice_velocities None)."""
        acc = program_acceleration_grid(lim.v_max, lim.a_max, d)
        self.n_accel = int(program_accel_values(lim.v_max, lim.a_max).shape[0])    # values per axis
        if self.physical:
            acc = acc[np.sqrt(np.einsum("cd,cd->c", acc, acc)) <= lim.a_max + _A_TOL]
        self.accelerations = acc                                                  # [C, d] m/s^2
        self.m = self.du = self.w = self.c = math.nan
        self.acc_int = None
        self.lattice_velocities = None
        self._v_max2 = lim.v_max * lim.v_max

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

    def heuristic(self, goal: np.ndarray, goal_radius: float, p: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The A* heuristic [N] for states p, v [N, d] (m, m/s) and the goal ball: astar_heuristic's LQMT bound, or
        program_heuristic (heuristic = "program", which ignores the goal radius as the program did)."""
        if self.heuristic_kind == "program":
            return program_heuristic(goal, p, v, self.T)
        lim = self.limits
        vset = self.lattice_velocities if self.lattice_time_bound else None
        return lqmt_lower_bound(np.asarray(goal, dtype=float) - np.atleast_2d(p), np.atleast_2d(v), goal_radius,
                                self.rho, lim.v_max, lim.a_max, vset)

    def _keys(self, depth: int, P: np.ndarray, J: np.ndarray) -> list:
        cols = np.concatenate([np.full((P.shape[0], 1), depth, dtype=np.int64), P, J], axis=1)
        if self._int_keys:
            return ((cols + self._key_off) @ self._key_mult).tolist()
        return [row.tobytes() for row in cols]

    # ------------------------------------------------------------------ checks

    def _screen(self, grid) -> StaticScreen:
        """The occupied-cell screen of the grid's current version (cached)."""
        if self._static is None or not self._static.valid_for(grid):
            self._static = StaticScreen(grid, self._reach)
        return self._static

    def _tracks_bad(self, tracks: Tracks, pts: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """pts [C, S, d] at times tau [S] (s after the view's time, ascending): True [C, S] where a track's
        prediction is within its radius + MAV radius + margin (thesis A-2); samples past the horizon are not
        tested. Only tracks whose predicted segment over those times comes near the samples' box are tested."""
        bad = np.zeros(pts.shape[:2], dtype=bool)
        n_s = int(np.searchsorted(tau, self.horizon_s + 1e-9, side="right"))
        if len(tracks) == 0 or n_s == 0:
            return bad
        q = pts[:, :n_s]
        flat = q.reshape(-1, q.shape[-1])
        lo, hi = flat.min(axis=0), flat.max(axis=0)
        reach = tracks.radius + self._reach                                   # [M]
        a = tracks.position + tau[0] * tracks.velocity
        b = tracks.position + tau[n_s - 1] * tracks.velocity
        near = np.all((np.minimum(a, b) - reach[:, None] < hi) & (np.maximum(a, b) + reach[:, None] > lo), axis=1)
        if not near.any():
            return bad
        centres = tracks.position[near][None] + tau[:n_s, None, None] * tracks.velocity[near][None]  # [S', M', d]
        rel = q[:, :, None, :] - centres[None]                                                        # [C, S', M', d]
        bad[:, :n_s] = np.any(np.einsum("csmd,csmd->csm", rel, rel) < reach[near] ** 2, axis=2)
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
        if self._tracks_bad(view.tracks, pts[None], tau).any():
            return True
        grid = view.grid
        if grid is not self._checked_grid or grid.version != self._checked_version:
            if self._screen(grid).bad(pts).any():
                return True
            self._checked_grid, self._checked_version = grid, grid.version
        return False

    def plan(self, view: View) -> Trajectory | None:
        """A* from the exact current state to the goal ball; the found primitives sampled at view.dt (t0 = view.t),
        or None when the open list empties (last_status "exhausted") or the budget is spent ("budget")."""
        self.n_plans += 1
        self.last_cost = math.nan
        self.last_path = []
        found = self._search_reference(view) if self._compiled is None else self._search_compiled(view)
        if found is None:
            return None
        self._checked_grid, self._checked_version = view.grid, view.grid.version
        return self._trajectory(view, *found)

    # ------------------------------------------------------------------ search

    def _search_reference(self, view: View):
        """Weighted A* (epsilon) over the primitive lattice in Python (search "python"); (goal node id, nodes) or
        None (sets diagnostics). The reference twin of the compiled search (_search_compiled), and the only search
        of the program grid and heuristic."""
        p0 = np.array(view.position, dtype=float)
        v0 = np.array(view.velocity, dtype=float)
        goal = np.asarray(view.goal, dtype=float)
        nodes = _Nodes(p0 + 0.5 * self.T * v0)
        h0 = float(self.heuristic(goal, view.goal_radius, p0[None], v0[None])[0])
        root_key = program_keys(p0, v0)[0] if self._program else None
        nodes.add(p0, v0, None, None, 0, 0.0, h0, -1, np.zeros(self.dims), -1, root_key)
        best_g: dict = {}
        # program keys merge different states: the open node of a key is the last one that improved its cost
        live: dict | None = {root_key: 0} if self._program else None
        closed: set = set()
        tie = itertools.count(1)
        heap = [(self.epsilon * h0, h0, 0, 0)]
        expansions = 0
        status = "exhausted"
        while heap:
            nid = heapq.heappop(heap)[3]
            if nodes.cut[nid] >= 0:
                self.last_status, self.last_expansions = "found", expansions
                return nid, nodes
            key = nodes.key[nid]
            if key is not None:
                if key in closed or (live is not None and live[key] != nid):
                    continue
                closed.add(key)
            if expansions >= self.max_expansions:
                status = "budget"
                break
            expansions += 1
            for f, h, cid in self._expand(view, nodes, nid, closed, best_g, live):
                heapq.heappush(heap, (f, h, next(tie), cid))
        self.last_status, self.last_expansions = status, expansions
        if status == "budget":
            self.n_budget_hits += 1
        return None

    def _search_compiled(self, view: View):
        """_search_reference by compiled.astar's kernel: the same result and diagnostics, the nodes of the found
        path only."""
        status, expansions, path = self._compiled.run(view, self._screen(view.grid))
        self.last_status, self.last_expansions = status, expansions
        if path is None:
            if status == "budget":
                self.n_budget_hits += 1
            return None
        nodes = _Nodes(path[0][0] + 0.5 * self.T * path[0][1])
        for i, (p, v, g, h, a, cut) in enumerate(path):
            nodes.add(p, v, None, None, i, g, h, i - 1, a, cut, None)
        return len(path) - 1, nodes

    def _program_children(self, p: np.ndarray, v: np.ndarray):
        """The program grid's children of state p, v [d] (m, m/s) whose end speed is below v_max: end positions and
        velocities [C, d], accelerations [C, d], sample offset table [C, S, d] and edge costs [C]."""
        acc, table, cost = self.accelerations, self._table, self._edge_cost
        v_end = v + self.T * acc
        ok = np.einsum("cd,cd->c", v_end, v_end) < self._v_max2
        if not ok.all():
            sel = np.flatnonzero(ok)
            acc, table, cost, v_end = acc[sel], table[sel], cost[sel], v_end[sel]
        p_end = p + self.T * v + (0.5 * self.T * self.T) * acc
        return p_end, v_end, acc, table, cost

    def _expand(self, view: View, nodes: _Nodes, nid: int, closed: set, best_g: dict, live: dict | None) -> list:
        """Add the valid children of node nid that improve on best_g (all accelerations checked at once); returns
        their (f, h, id). ``live`` (program keys only): key -> the id of its open node, updated here."""
        d = self.dims
        n, p, v = nodes.n[nid], nodes.p[nid], nodes.v[nid]
        if self._program:
            p_end, v_end, acc, table, cost = self._program_children(p, v)
            J_end = P_end = np.zeros((acc.shape[0], 0), dtype=np.int64)    # no lattice indices
            keys = program_keys(p_end, v_end) if acc.shape[0] else []
        else:
            if nid == 0:
                J_end, acc = self.root_children(v)
                P_end = J_end
                table = self._s2[None, :, None] * acc[:, None, :]
                cost = (np.einsum("cd,cd->c", acc, acc) + self.rho) * self.T
                p_end = nodes.base + self.c * P_end
            else:
                P, J = nodes.P[nid], nodes.J[nid]
                J_end = J + self.acc_int
                ok = np.einsum("cd,cd->c", J_end, J_end) <= self._vj_max2
                sel = slice(None) if ok.all() else np.flatnonzero(ok)
                J_end, acc, table, cost = J_end[sel], self.accelerations[sel], self._table[sel], self._edge_cost[sel]
                P_end = P + 2 * J + self.acc_int[sel]
                p_end = nodes.base + self.c * P_end
            v_end = self.w * J_end
            keys = self._keys(min(n + 1, self.n_horizon), P_end, J_end) if acc.shape[0] else []
        if acc.shape[0] == 0:
            return []
        fresh = [i for i, k in enumerate(keys) if k not in closed]
        if not fresh:
            return []
        if len(fresh) < len(keys):
            J_end, P_end, p_end, v_end, acc, table, cost = (x[fresh] for x in (J_end, P_end, p_end, v_end, acc,
                                                                              table, cost))
            keys = [keys[i] for i in fresh]
        s = self._s
        pts = (p + s[:, None] * v)[None] + table                                   # [C, S, d]
        flat = pts.reshape(-1, d)
        lo, hi = flat.min(axis=0), flat.max(axis=0)
        bad = np.zeros(pts.shape[:2], dtype=bool)
        if np.any(lo < self._wall_lo) or np.any(hi > self._wall_hi):
            bad |= np.any((pts < self._wall_lo) | (pts > self._wall_hi), axis=2)
        tau = n * self.T + s
        if len(view.tracks) and tau[0] <= self.horizon_s + 1e-9:
            bad |= self._tracks_bad(view.tracks, pts, tau)
        screen = self._screen(view.grid)
        if screen.box_maybe(lo, hi):
            todo = ~bad.reshape(-1)
            gb = np.zeros(todo.shape[0], dtype=bool)
            gb[todo] = screen.bad(flat[todo])
            bad |= gb.reshape(bad.shape)
        n_c, n_s = bad.shape
        goal = view.goal
        goal_r = view.goal_radius - GOAL_TOL
        box_gap = np.maximum(np.maximum(lo - goal, goal - hi), 0.0)
        if float(box_gap @ box_gap) <= goal_r * goal_r:
            rel = pts - goal
            in_goal = np.einsum("csd,csd->cs", rel, rel) <= goal_r * goal_r
            first_goal = np.where(in_goal.any(axis=1), np.argmax(in_goal, axis=1), n_s)
        else:
            first_goal = np.full(n_c, n_s)
        first_bad = np.where(bad.any(axis=1), np.argmax(bad, axis=1), n_s)
        reach_goal = first_goal < first_bad
        plain = np.flatnonzero((first_bad == n_s) & ~reach_goal)
        h = self.heuristic(goal, view.goal_radius, p_end[plain], v_end[plain]) if plain.size else []
        g0 = nodes.g[nid]
        eps = self.epsilon
        out = []
        if plain.size:
            g_new = (g0 + cost[plain]).tolist()
            rows = zip(plain.tolist(), g_new, np.asarray(h).tolist(), p_end[plain], v_end[plain], P_end[plain],
                       J_end[plain], acc[plain])
            for i, g, hh, pe, ve, Pe, Je, ae in rows:
                key = keys[i]
                old = best_g.get(key)
                if old is not None and old <= g:
                    continue
                best_g[key] = g
                cid = nodes.add(pe, ve, Pe, Je, n + 1, g, hh, nid, ae, -1, key)
                if live is not None:
                    live[key] = cid
                out.append((g + eps * hh, hh, cid))
        for i in np.flatnonzero(reach_goal).tolist():
            k = int(first_goal[i])
            g = g0 + (float(acc[i] @ acc[i]) + self.rho) * float(s[k])
            out.append((g, 0.0, nodes.add(pts[i, k], v + s[k] * acc[i], P_end[i], J_end[i], n + 1, g, 0.0, nid,
                                          acc[i], k, None)))
        return out

    def _trajectory(self, view: View, nid: int, nodes: _Nodes) -> Trajectory:
        """Sample the path root -> goal node nid at view.dt; fills last_path and last_cost."""
        chain = []
        while nid > 0:
            chain.append(nid)
            nid = nodes.parent[nid]
        chain.reverse()
        s, s2 = self._s, self._s2
        ps, vs, accs = [nodes.p[0][None]], [nodes.v[0][None]], []
        self.last_path = [(nodes.p[0].copy(), nodes.v[0].copy(), 0.0, nodes.h[0])]
        prev = 0
        for cid in chain:
            a = nodes.a[cid]
            k = nodes.cut[cid] + 1 if nodes.cut[cid] >= 0 else s.shape[0]
            p, v = nodes.p[prev], nodes.v[prev]
            ps.append(p + s[:k, None] * v + s2[:k, None] * a)
            vs.append(v + s[:k, None] * a)
            accs.append(np.tile(a, (k, 1)))
            self.last_path.append((np.array(nodes.p[cid]), np.array(nodes.v[cid]), nodes.g[cid], nodes.h[cid]))
            prev = cid
        acc = np.concatenate(accs)
        acc = np.concatenate([acc, acc[-1:]])   # a[k]: applied from sample k to k + 1; the last keeps its own
        self.last_cost = nodes.g[chain[-1]]
        return Trajectory(view.t, view.dt, np.concatenate(ps), np.concatenate(vs), acc)
