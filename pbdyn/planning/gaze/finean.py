"""Finean et al. gaze planner ("Oxford"; thesis 4-1-2, eq. 4-5 to 4-7; docs/thesis-program.md "Gaze planners").

Two maps over the MAV's occupancy grid cells (2D: pixels, 3D: voxels of the same grid):
- the age map t_i: seconds since cell i was last observed (initially ``initial_age`` = 5 s). Each call first marks
  observed every cell whose centre the sensor covered at view.t from the MAV's position and yaw -- the shared
  predicate pbdyn.perception.sensor.in_fov over cell centres, so occlusion is ignored (a cell behind a wall or an
  obstacle counts as observed; the grid keeps no per-scan observation record to do better);
- the future-occupancy map v_i (eq. 4-5): the earliest time ahead (s, > 0) at which a sample of the plan in execution
  occupies cell i -- the cell's centre lies within (MAV radius + res/2) of the sample -- and 0 if none does.
Reward per cell (eq. 4-6): c1 if 0 < v_i <= tau_s and t_i >= tau_c; c2 if v_i > tau_s and t_i >= tau_c; otherwise
min(c3 * t_i, 1) -- the thesis program's rule (the thesis text prints max(c3 t_i, 1)). The planner returns, among
``n_rates`` evenly spaced yaw rates in [-limit, +limit] (both limits and 0 always included; the program's 6 rates
lacked the positive limit), the rate whose next-step view -- from the plan's position at view.t + dt (else the MAV's
position) at yaw + rate * dt -- covers the largest summed reward (eq. 4-7). Exact ties go to the smallest |rate|,
then the counter-clockwise one.

Cost: only cells within sensor range (plus one step's travel) of the MAV are read or scored; the window of index
offsets and the plan footprint stencil are precomputed once per grid.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from pbdyn.perception.sensor import in_fov
from pbdyn.planning.gaze.yaw import rate_candidates, tie_break_order
from pbdyn.planning.protocols import PlannerContext
from pbdyn.planning.trajectory import Trajectory
from pbdyn.planning.view import View


def _offsets(reach_cells: int, dims: int, max_norm: float) -> np.ndarray:
    """Integer offsets [W, d] in the box of half-width reach_cells with Euclidean norm <= max_norm (cells)."""
    rng = np.arange(-reach_cells, reach_cells + 1)
    off = np.array(list(itertools.product(rng, repeat=dims)), dtype=np.int64).reshape(-1, dims)
    return off[np.sum(off * off, axis=1) <= max_norm * max_norm]


def _positive(name: str, value) -> float:
    if not isinstance(value, (int, float)) or not math.isfinite(float(value)) or float(value) <= 0:
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return float(value)


class Finean:
    """Age-map and future-occupancy gaze planner of Finean et al. (registry name "finean"; see the module docstring).

    Args (units s or reward units): tau_s (3 s) and tau_c (0.5 s) of eq. 4-6; c1 (1e6), c2 (1e3), c3 (1 per s);
    initial_age (5 s): the age of never-observed cells; n_rates (7): candidate rates (0 is added if missing).
    One instance per trial: the age map persists between calls and is (re)created for a new grid.
    """

    def __init__(self, context: PlannerContext, *, tau_s: float = 3.0, tau_c: float = 0.5, c1: float = 1e6,
                 c2: float = 1e3, c3: float = 1.0, initial_age: float = 5.0, n_rates: int = 7):
        self.tau_s = _positive("tau_s", tau_s)
        self.tau_c = _positive("tau_c", tau_c)
        self.c1, self.c2, self.c3 = _positive("c1", c1), _positive("c2", c2), _positive("c3", c3)
        self.initial_age = _positive("initial_age", initial_age)
        self.limit = float(context.limits.yaw_rate)
        self.rates = rate_candidates(self.limit, n_rates, include_zero=True)
        self._order = tie_break_order(self.rates)
        self.radius = float(context.limits.radius)
        self.dt = float(context.dt)
        self._step_margin = 1.5 * float(context.limits.v_max) * self.dt  # bounds |p(t + dt) - p(t)|
        self._grid = None
        self.last_seen: np.ndarray | None = None  # per flat grid cell: time (s) it was last observed
        self.last_scores: np.ndarray | None = None  # summed reward per candidate rate at the last call

    def _setup(self, view: View) -> None:
        grid = view.grid
        res, d = grid.res, grid.dims
        self._grid = grid
        self._shape = np.asarray(grid.shape, dtype=np.int64)
        self._strides = np.cumprod((grid.shape[1:] + (1,))[::-1])[::-1].astype(np.int64)
        # A cell centre within D of a point in cell `base` has an offset from base of norm <= D / res + sqrt(d) / 2.
        reach = (float(view.range_m) + self._step_margin) / res + math.sqrt(d) / 2.0
        self._reach = int(math.ceil(reach))
        self._window = _offsets(self._reach, d, reach)
        self._window_flat = self._window @ self._strides
        self._window_pos = self._window * res
        fp = (self.radius + res / 2.0) / res
        self._fp_reach = float(self.radius + res / 2.0 + float(view.range_m) + self._step_margin + res)
        self._stencil_reach = int(math.ceil(fp + math.sqrt(d) / 2.0))
        self._stencil = _offsets(self._stencil_reach, d, fp + math.sqrt(d) / 2.0)
        self._stencil_flat = self._stencil @ self._strides
        self._stencil_pos = self._stencil * res
        self._scratch = np.zeros(grid.cells.size)
        self.last_seen = np.full(grid.cells.size, float(view.t) - self.initial_age)

    def _in_grid(self, base: np.ndarray, offsets: np.ndarray, reach: int) -> np.ndarray | None:
        """Mask [S, T] of base [S, d] + offsets [T, d] inside the grid, or None when all are (base >= reach inside)."""
        if np.all(base >= reach) and np.all(base + reach < self._shape):
            return None
        idx = base[:, None, :] + offsets[None]
        return np.all((idx >= 0) & (idx < self._shape), axis=-1)

    def _cells_near(self, position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(flat indices [W], centres relative to ``position`` [W, d] in m) of the window's cells around it."""
        grid = self._grid
        base = grid.index(position)
        rel0 = grid.origin + (base + 0.5) * grid.res - position
        flat, rel = int(base @ self._strides) + self._window_flat, rel0 + self._window_pos
        inside = self._in_grid(base[None], self._window, self._reach)
        if inside is not None:
            flat, rel = flat[inside[0]], rel[inside[0]]
        return flat, rel

    def future_cells(self, view: View, trajectory: Trajectory | None,
                     near: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The future-occupancy map (eq. 4-5) as (flat cell indices [U], earliest time ahead v_i [U] in s, > 0).

        Samples of ``trajectory`` after view.t occupy the cells whose centre lies within MAV radius + res/2 of them.
        near: if given, a point [d] (m); samples farther than sensor range + one step + the footprint are skipped.
        """
        empty = (np.zeros(0, np.int64), np.zeros(0))
        if trajectory is None:
            return empty
        if self._grid is not view.grid:
            self._setup(view)
        grid = self._grid
        tau = trajectory.times - view.t
        keep = tau > 1e-9
        pts = trajectory.p[keep]
        tau = tau[keep]
        if near is not None and pts.shape[0]:
            close = np.sum((pts - near) ** 2, axis=1) <= self._fp_reach ** 2
            pts, tau = pts[close], tau[close]
        if pts.shape[0] == 0:
            return empty
        base = grid.index(pts)                                                      # [S, d]
        rel = (grid.origin + (base + 0.5) * grid.res - pts)[:, None, :] + self._stencil_pos[None]  # [S, T, d]
        r = self.radius + grid.res / 2.0
        ok = np.einsum("stk,stk->st", rel, rel) <= r * r
        inside = self._in_grid(base, self._stencil, self._stencil_reach)
        if inside is not None:
            ok &= inside
        flat = ((base @ self._strides)[:, None] + self._stencil_flat[None])[ok]    # sample-major: tau ascending
        taus = np.broadcast_to(tau[:, None], ok.shape)[ok]
        cells, first = np.unique(flat, return_index=True)                           # first = earliest sample
        return cells, taus[first]

    def age_map(self, t: float) -> np.ndarray:
        """Ages t_i (s) at time t of every grid cell, shaped like grid.cells (initial_age before the first call)."""
        if self.last_seen is None or self._grid is None:
            raise ValueError("the age map exists after the first yaw_rate call")
        return (float(t) - self.last_seen).reshape(self._grid.shape)

    def rewards(self, age: np.ndarray, future: np.ndarray) -> np.ndarray:
        """Per-cell reward of eq. 4-6 for ages t_i [W] (s) and future-occupancy values v_i [W] (s, 0 = none)."""
        r = np.minimum(self.c3 * age, 1.0)
        stale = age >= self.tau_c
        r[stale & (future > 0.0) & (future <= self.tau_s)] = self.c1
        r[stale & (future > self.tau_s)] = self.c2
        return r

    def yaw_rate(self, view: View, trajectory: Trajectory | None) -> float:
        """Record what the sensor covered at view.t, then the rate (rad/s) maximising the next view's reward."""
        if self._grid is not view.grid:
            self._setup(view)
        t = float(view.t)
        p = view.position
        flat, rel_p = self._cells_near(p)
        rel = rel_p
        near = np.flatnonzero(np.einsum("ij,ij->i", rel, rel) <= float(view.range_m) ** 2)  # cheap range cut
        seen = near[in_fov(view.yaw, rel[near], view.fov_deg, view.range_m, view.vfov_deg)]
        self.last_seen[flat[seen]] = t

        p_next = p
        if trajectory is not None and trajectory.covers(t + self.dt) and trajectory.index_at(t + self.dt) >= 1:
            p_next = trajectory.state_at(t + self.dt)[0]
        rel = rel_p - (p_next - p)
        near = np.flatnonzero(np.einsum("ij,ij->i", rel, rel) <= float(view.range_m) ** 2)
        # Only cells some candidate can see are scored: those in the union of the candidates' sectors.
        union_deg = min(360.0, float(view.fov_deg) + 2.0 * math.degrees(self.limit * self.dt) + 1e-6)
        sub = near[in_fov(view.yaw, rel[near], union_deg, view.range_m, view.vfov_deg)]
        rel = rel[sub]

        cells, taus = self.future_cells(view, trajectory, near=p)
        scratch = self._scratch
        scratch[cells] = taus
        flat = flat[sub]
        future = scratch[flat]
        scratch[cells] = 0.0
        reward = self.rewards(t - self.last_seen[flat], future)

        yaws = view.yaw + self.rates * self.dt
        cover = in_fov(yaws[:, None], np.broadcast_to(rel, (yaws.shape[0],) + rel.shape), view.fov_deg,
                       view.range_m, view.vfov_deg)                                  # [C, W']
        scores = cover @ reward
        self.last_scores = scores
        best = self._order[int(np.argmax(scores[self._order]))]
        return float(self.rates[best])
