"""Local motion primitives (thesis 4-1-1, appendix A-2, Algorithm 3) on jerk-limited ruckig trajectories.

Every step the planner fans end points on a circle (3D: a sphere) of radius step_m around the MAV, ranks them by
the angle between their direction and the goal direction, and takes the first one whose trajectory is within the
norm limits and clear (pbdyn.planning.checks). Trajectories are built lazily in rank order, so in open space one
ruckig build per step is typical. The thesis program used minimum-jerk polynomials (Mueller et al.); ruckig gives
jerk-limited, time-synchronised profiles with the same boundary conditions and the program's minimum duration.

Each primitive is built in a frame whose first axis points at its end point (the planner is then invariant to the
arena's orientation, and a straight primitive uses one axis, so the per-axis limits rarely exceed the norm limits).
Norm limits from ruckig's per-axis limits: first build with per-axis (v_max, a_max, jerk_max); if a sample's
|v| or |a| exceeds the norm limit, or two consecutive samples need more than a_max to connect (the plan contract's
step bounds, pbdyn.sim.contract), rebuild with the per-axis limits scaled by 0.95 * limit / observed peak (at most
two rebuilds; the peak does not shrink in proportion to the limit, and the exact ratio tends to land just above it),
then with the conservative per-axis v_max / sqrt(d), a_max / sqrt(d) (docs/design.md "Limits are norms");
a candidate that still violates, or that ruckig rejects, is skipped.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np
import ruckig

from pbdyn.jit import njit
from pbdyn.limits import MAX_PLAN_COUNT, MAX_PLAN_DISTANCE_M, MAX_PLAN_HORIZON_S
from pbdyn.planning import params
from pbdyn.planning.checks import WALL_MARGIN_CAP, static_clear
from pbdyn.planning.primitives.compiled.candidate_kernels import numpy_orders, sampled_peaks, world_and_screen
from pbdyn.planning.primitives.compiled.candidate_search import (frame_inputs_reference, frame_products_known,
                                                                 no_candidate_proof, no_grid_query, search)
from pbdyn.planning.primitives.compiled.ruckig_sampling import PROFILE_WIDTH, profile_row
from pbdyn.planning.primitives.native import ruckig_build_address
from pbdyn.planning.protocols import PlannerContext
from pbdyn.planning.trajectory import Trajectory
from pbdyn.planning.view import View

_TOL = 1e-9
_N_SCALED_REBUILDS = 2
_SCALE_SAFETY = 0.95  # the peak does not scale linearly with the limits: aim slightly below


def sphere_directions(spacing_deg: float) -> np.ndarray:
    """Evenly spread unit vectors [n, 3]: rings at elevations 0, +-spacing, ... (both poles included), each with
    max(1, round(360 cos(el) / spacing)) azimuths k * 360 / n_ring; horizontal ring first."""
    n_half = int(round(90.0 / spacing_deg))
    elevations = [0.0]
    for k in range(1, n_half + 1):
        el = min(k * spacing_deg, 90.0)
        elevations += [el, -el]
    out = []
    for el in elevations:
        e = np.radians(el)
        n_ring = max(1, int(round(360.0 * np.cos(e) / spacing_deg))) if abs(el) < 90.0 else 1
        az = 2.0 * np.pi * np.arange(n_ring) / n_ring
        out.append(np.stack([np.cos(e) * np.cos(az), np.cos(e) * np.sin(az), np.full(n_ring, np.sin(e))], axis=1))
    return np.concatenate(out)


def candidate_directions(dims: int, n_candidates: int, spacing_deg: float) -> np.ndarray:
    """Unit directions [n, d] of the candidate end points (thesis eq. A-4). 2D: n_candidates angles 2 pi k / n,
    k = 0..n-1; 3D: sphere_directions(spacing_deg) (n_candidates is ignored)."""
    if dims == 2:
        ang = 2.0 * np.pi * np.arange(n_candidates) / n_candidates
        return np.stack([np.cos(ang), np.sin(ang)], axis=1)
    if dims == 3:
        return sphere_directions(spacing_deg)
    raise ValueError(f"dims must be 2 or 3, got {dims}")


def rank_by_goal_angle(directions: np.ndarray, to_goal: np.ndarray) -> np.ndarray:
    """Indices of unit ``directions`` [n, d] sorted by their angle to the vector ``to_goal`` [d] (m; goal minus
    MAV position), ascending; ties (angles equal to 1e-12 rad) by index; index order when the MAV is at the goal
    (thesis Algorithm 3, line 7, with the angle as the heuristic cost)."""
    angle = goal_angles(directions, to_goal)
    if angle is None:
        return np.arange(directions.shape[0])
    return np.argsort(angle, kind="stable")


def goal_angles(directions: np.ndarray, to_goal: np.ndarray) -> np.ndarray | None:
    """The angles (rad, rounded to 1e-12) between unit ``directions`` [n, d] and ``to_goal`` [d] that
    rank_by_goal_angle sorts; None when the MAV is at the goal (|to_goal| < 1e-12 m)."""
    got = goal_angles_argmin(directions, to_goal)
    return None if got is None else got[0]


def goal_angles_argmin(directions: np.ndarray, to_goal: np.ndarray) -> tuple[np.ndarray, int] | None:
    """(goal_angles, np.argmin of them: the first NaN if any, else the first smallest), or None at the goal.
    np.round(np.arccos(np.clip(x, -1, 1)), 12) with the same float operations: the clip and the rounding (numpy's:
    x * 1e12, rint, / 1e12) in compiled code around numpy's arccos (tests/test_planners.py compares both)."""
    g = np.asarray(to_goal, dtype=float)
    dist = math.sqrt(float(g @ g))
    if dist < 1e-12:
        return None
    x = directions @ (g / dist)
    _clip_unit(x)
    np.arccos(x, out=x)
    return x, int(_round_argmin(x))


@njit(cache=True, nogil=True)
def _clip_unit(x):
    """x [n] clipped to [-1, 1] in place as np.maximum(x, -1) then np.minimum(., 1) (NaN stays NaN)."""
    for k in range(x.shape[0]):
        v = x[k]
        if v < -1.0:
            x[k] = -1.0
        elif v > 1.0:
            x[k] = 1.0


@njit(cache=True, nogil=True)
def _round_argmin(x):
    """x [n] rounded to 12 decimals in place as np.round does it (x * 1e12, rint, / 1e12); then np.argmin(x): the
    first NaN if any, else the first smallest."""
    best = 0
    for k in range(x.shape[0]):
        x[k] = np.rint(x[k] * 1e12) / 1e12
    for k in range(x.shape[0]):
        v = x[k]
        if v != v:
            return k
        if v < x[best]:
            best = k
    return best


def frame_basis(u: np.ndarray) -> np.ndarray:
    """An orthonormal basis [d, d] (rows) whose first row is the unit vector u (2D or 3D), deterministic."""
    u = np.asarray(u, dtype=float)
    if u.shape[0] == 2:
        return np.array([[u[0], u[1]], [-u[1], u[0]]])
    e = np.zeros(3)
    e[int(np.argmin(np.abs(u)))] = 1.0
    w = np.cross(u, e)
    w /= np.linalg.norm(w)
    return np.stack([u, w, np.cross(u, w)])


@functools.lru_cache(maxsize=16)
def _fan(dims: int, n_candidates: int, spacing_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """The candidates' unit directions [n, d] (candidate_directions, read-only) and their planning frames [n, d, d]
    (frame_basis of each), shared by the planners that ask for the same fan (3D: 412 frames). The frames stay
    writable (the planners never write them) so that the compiled checks see one array type whether a chunk's
    frames are a view or a copy (each new type would be compiled, and a compile mid-trial is a long step)."""
    dirs = candidate_directions(dims, n_candidates, spacing_deg)
    bases = np.stack([frame_basis(u) for u in dirs])
    dirs.setflags(write=False)
    return dirs, bases


class _Built(NamedTuple):
    """Candidates built by LocalPrimitives._build_many: rows (their indices among those asked for, ascending),
    samples p, v, a [m, K, d] (world; counts[i] valid), counts [m], bad [m] (a sample meets a wall or a track)."""

    rows: list
    p: np.ndarray
    v: np.ndarray
    a: np.ndarray
    counts: np.ndarray
    bad: np.ndarray

    @staticmethod
    def nothing(d: int) -> "_Built":
        empty = np.zeros((0, 0, d))
        return _Built([], empty, empty, empty, np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool))

    def samples(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(p, v, a) [K, d] of the i-th built candidate."""
        k = int(self.counts[i])
        return self.p[i, :k], self.v[i, :k], self.a[i, :k]


class LocalPrimitives:
    """Local motion primitives planner (registry name "local_primitives").

    Args:
        context: the trial's fixed facts (dims, dt, limits, arena box).
        n_candidates: number of end points on the circle (2D: at angles 2 pi k / n).
        sphere_spacing_deg: 3D only — end points on the sphere in rings of constant elevation every spacing degrees
            (including the horizontal ring and both poles), each ring holding round(360 cos(el) / spacing) evenly
            spaced points, so neighbours are ~spacing apart everywhere (10 deg: 412 points, 36 in the horizontal
            plane).
        step_m: distance (m) from the MAV to each end point.
        end_speed_frac: end speed as a fraction of v_max, along the candidate's direction; end acceleration 0.
        jerk_max: per-axis jerk limit (m/s^3).
        margin: safety margin (m) added to the MAV radius in the collision check.
        min_duration: minimum primitive duration (s); default max(1.2 step_m / v_max, 0.5) as the thesis program.

    Diagnostics of the last plan() call: last_candidates_built (ruckig calculate() calls), last_candidates_tried,
    last_rank (rank of the chosen candidate, 0 = best; None on failure), last_target (its end point [d]).
    """

    def __init__(self, context: PlannerContext, *, n_candidates: int = 72, sphere_spacing_deg: float = 10.0,
                 step_m: float = 3.0,
                 end_speed_frac: float = 0.5, jerk_max: float = 20.0, margin: float = 0.5,
                 min_duration: float | None = None):
        n_candidates = params.integer("n_candidates", n_candidates, lo=1, hi=MAX_PLAN_COUNT)
        step_m = params.number("step_m", step_m, lo=0.0, lo_open=True, hi=MAX_PLAN_DISTANCE_M)
        end_speed_frac = params.number("end_speed_frac", end_speed_frac, lo=0.0, hi=1.0)
        jerk_max = params.positive("jerk_max", jerk_max)
        margin = params.non_negative("margin", margin)
        if min_duration is not None:
            min_duration = params.number("min_duration", min_duration, lo=0.0, hi=MAX_PLAN_HORIZON_S)
        self.dims = d = int(context.dims)
        self.dt = float(context.dt)
        self.limits = context.limits
        sphere_spacing_deg = params.number("sphere_spacing_deg", sphere_spacing_deg, lo=0.5, hi=90.0)
        self.sphere_spacing_deg = float(sphere_spacing_deg)
        self.n_candidates = int(n_candidates)
        self.step_m = float(step_m)
        self.end_speed = float(end_speed_frac) * self.limits.v_max
        self.jerk_max = float(jerk_max)
        self.margin = float(margin)
        if min_duration is None:
            min_duration = max(1.2 * self.step_m / self.limits.v_max, 0.5)
        self.min_duration = float(min_duration)
        self.directions, self._bases = _fan(d, self.n_candidates, self.sphere_spacing_deg)  # bases [n, d, d]
        self.n_candidates = self.directions.shape[0]
        self._step_dirs = self.step_m * self.directions        # [n, d]: end points relative to the MAV
        self._end_vel = self.end_speed * self.directions        # [n, d]: end velocities
        self._otg = ruckig.Ruckig(d)
        self._traj = ruckig.Trajectory(d)
        self._input_pool: list = []    # ruckig InputParameters with the fixed fields set (_inputs)
        self._no_frames = np.zeros((4, 0, d))
        self._limits_row = np.array([self.limits.v_max, self.limits.a_max, self.jerk_max, self.min_duration,
                                     MAX_PLAN_HORIZON_S, _SCALE_SAFETY, _TOL, 0.0, 0.0])  # t, dt set per view
        self._wall_r = self.limits.radius + min(self.margin, WALL_MARGIN_CAP)   # _screen's wall distance (m)
        self._reach_r = self.limits.radius + self.margin                         # ... and track reach beyond radius
        self._screen_view: View | None = None
        self._stacked_view: View | None = None   # _search_native's per-view arguments, for this view
        self._stacked: tuple = ()
        self._screen_args: tuple = ()
        self.last_candidates_built = 0
        self.last_candidates_tried = 0
        self.last_rank: int | None = None
        self.last_target: np.ndarray | None = None

    # Probed on first use, not in __init__: a planner built only to check its parameters (`pbdyn batch`'s
    # coordinator) loads neither the native library nor numba (pbdyn.jit).
    @functools.cached_property
    def _native(self) -> int | None:
        """The native ruckig batch's entry point, or None (the ruckig Python package)."""
        return ruckig_build_address()

    @functools.cached_property
    def _orders(self) -> tuple[int, int]:
        """(mm_mode, sq_order): numpy's float orders on this machine (candidate_kernels.numpy_orders)."""
        return numpy_orders(self.dims)

    @functools.cached_property
    def _counts(self) -> np.ndarray:
        """search()'s counts: rebuilds, the two orders, whether it computes the frame products itself."""
        return np.array([_N_SCALED_REBUILDS, *self._orders, frame_products_known(self.dims)], dtype=np.int64)

    @property
    def uses_native(self) -> bool:
        """True if this planner builds its candidates through the native ruckig batch and the compiled search
        (pbdyn.planning.primitives.native); False: the ruckig Python package and the Python chunk loop (the same
        plans)."""
        return self._native is not None

    def replan_check(self, view: View) -> bool:
        """Always True: the thesis program replans every step and executes one sample."""
        return True

    def ranked_candidates(self, view: View) -> np.ndarray:
        """Candidate indices sorted by the angle between candidate and goal direction (ascending, ties by index)."""
        return rank_by_goal_angle(self.directions, view.goal - view.position)

    def plan(self, view: View) -> Trajectory | None:
        """The first clear, limit-respecting primitive in rank order, sampled at view.dt; None if none exists.

        Limits and clearance are checked on samples 1..K-1: sample 0 is the current state, which no plan can change.
        When the goal is closer than step_m, the goal itself (end velocity 0) is tried before the fan. Once the best
        candidate has failed, fan candidates whose end point is blocked by a wall or an occupied cell are skipped
        unbuilt (the primitive ends inside the blocked region: stricter than the sampled check only when the end
        time falls between samples), and the others are searched in rank order (_search): with the native ruckig
        batch in one compiled call, candidate by candidate (candidate_search.search); without it built in
        rank-ordered chunks (CHUNKS) whose clearance is checked in one compiled evaluation (_first_clear). Either
        way the same choice as trying them one by one (plan_reference, the reference twin). Before that, once
        the best candidate has failed, none_can_be_clear may prove that no candidate can pass, and the plan fails
        without building another (tried first, the proof cost more over the steps whose best candidate passes
        than it saved on the others).
        """
        self._reset_diagnostics()
        p0 = view.position
        g = view.goal - p0
        g_dist = math.sqrt(float(g @ g))
        offset = 0
        if g_dist < self.step_m:                     # the goal itself, reached at rest, is tried first
            offset = 1
            self.last_candidates_tried += 1
            basis = frame_basis(g / max(g_dist, 1e-12))
            found = self._try_one(view, np.array(view.goal)[None], np.zeros((1, self.dims)), basis[None], 0)
            if found is not None:
                return found
        got = goal_angles_argmin(self.directions, g)
        angles, i = (None, 0) if got is None else got            # the first of rank_by_goal_angle's order ...
        order = None
        if angles is not None and math.isnan(angles[i]):          # ... unless an angle is NaN (argsort puts it last)
            order = np.argsort(angles, kind="stable")
            i = int(order[0])
        end_vel = self._end_vel
        self.last_candidates_tried += 1
        found = self._try_one(view, p0 + self._step_dirs[i:i + 1], end_vel[i:i + 1], self._bases[i:i + 1], offset)
        if found is not None or self.n_candidates == 1 or self.none_can_be_clear(view):
            return found
        if order is None:
            order = np.arange(self.n_candidates) if angles is None else np.argsort(angles, kind="stable")
        idx = order[1:]
        targets = p0 + self._step_dirs[idx]                      # [n - 1, d], ranks 1..
        j, tried, samples = self._search(view, targets, end_vel[idx], self._bases[idx], prune=True)
        self.last_candidates_tried += tried
        if j < 0:
            return None
        return self._chosen(view, targets[j], j + 1 + offset, *samples)

    def none_can_be_clear(self, view: View) -> bool:
        """True if no primitive this planner can return is clear, proven from the current state alone.

        Every returned primitive lasts >= min_duration, so it has samples k = 1..floor(min_duration / dt), and its
        consecutive samples pass the step bounds of _peaks with a_max (|v_k+1 - v_k| <= a_max dt,
        |p_k+1 - p_k - (v_k + v_k+1) dt / 2| <= a_max dt^2 / 4); hence sample k lies within
        b_k = a_max dt^2 (k^2 / 2 + k / 4) of p_0 + k dt v_0. If for some such k that whole ball meets a wall
        (checks.py (c)) or lies inside one track's predicted disc (a), every candidate conflicts at sample k (the
        ball gets 1e-6 m of slack for rounding): the search would fail, and plan() returns None at once.
        Decided in compiled code (candidate_search.no_candidate_proof) with the float operations of the numpy
        evaluation, _none_can_be_clear_reference (its reference twin).
        """
        n_k = int(math.floor(self.min_duration / view.dt - 1e-6))
        if n_k < 1:
            return False
        tracks = view.tracks
        radius = tracks.radius
        if radius.ndim != 1:
            radius = np.ascontiguousarray(np.broadcast_to(radius, tracks.position.shape[:1]))
        return no_candidate_proof(view.position, view.velocity, view.bounds_lo, view.bounds_hi, tracks.position,
                                  tracks.velocity, radius, n_k,
                                  float(view.dt), self.limits.a_max + _TOL,
                                  self._wall_r, self._reach_r, self._orders[1])

    def _none_can_be_clear_reference(self, view: View) -> bool:
        """none_can_be_clear evaluated with numpy: the reference twin of the compiled proof (the same answer)."""
        dt = view.dt
        k = np.arange(1, int(math.floor(self.min_duration / dt - 1e-6)) + 1, dtype=float)
        if k.shape[0] == 0:
            return False
        a_max = self.limits.a_max + _TOL
        centre = view.position + (k * dt)[:, None] * view.velocity                    # [k, d]
        ball = (a_max * dt * dt * (0.5 * k * k + 0.25 * k) + 1e-6)[:, None]           # [k, 1]
        wall_r = self._wall_r
        if np.any((centre + ball < view.bounds_lo + wall_r) | (centre - ball > view.bounds_hi - wall_r)):
            return True
        tracks = view.tracks
        if not len(tracks):
            return False
        pred = tracks.position[None] + (k * dt)[:, None, None] * tracks.velocity[None]    # [k, M, d]
        gap = np.sqrt(np.einsum("kmd,kmd->km", centre[:, None] - pred, centre[:, None] - pred))
        return bool(np.any(gap + ball < tracks.radius + self._reach_r))

    CHUNKS = (4, 8)
    """Sizes of the rank-ordered chunks of candidates built and checked together after the best one failed, on the
    path without the native ruckig batch (the last size repeats). A chunk's fixed cost is about that of one
    candidate's builds, and when the best candidate fails the choice lies at rank ~10 (median; 90th percentile 40):
    chunks of 4 then 8 build the fewest candidates in vain (measured against (3, 6, 12, 24), (3,), (5,), (6,), (8,),
    (6, 12): 1.5% less time per step than the doubling sizes on the controlled sample; the choice never depends on
    them)."""

    def chunk_sizes(self, n: int):
        """The chunk sizes (CHUNKS, the last one repeated) that cover ``n`` candidates."""
        done, k = 0, 0
        while done < n:
            size = self.CHUNKS[min(k, len(self.CHUNKS) - 1)]
            yield size
            done += size
            k += 1

    def _reset_diagnostics(self) -> None:
        self.last_candidates_built = 0
        self.last_candidates_tried = 0
        self.last_rank = None
        self.last_target = None

    def _try_one(self, view: View, target: np.ndarray, vel: np.ndarray, basis: np.ndarray,
                 rank: int) -> Trajectory | None:
        """Build and check one candidate (end point target [1, d] m, end velocity vel [1, d] m/s, frame basis
        [1, d, d], float arrays); its Trajectory (recorded as the choice at ``rank``) or None."""
        j, _, samples = self._search(view, target, vel, basis, prune=False)
        return None if j < 0 else self._chosen(view, target[0], rank, *samples)

    def _search(self, view: View, targets: np.ndarray, vels: np.ndarray, bases: np.ndarray,
                prune: bool) -> tuple[int, int, tuple]:
        """The first clear candidate of the rank-ordered end points targets [n, d] (m), end velocities vels [n, d]
        and frames bases [n, d, d]: those whose end point is blocked skipped unbuilt when ``prune``, the others
        built in chunks (CHUNKS) and checked together. Returns (its index or -1, candidates counted as tried, its
        samples (p, v, a) [K, d]). With the native ruckig batch one compiled call (_search_native); without it
        the Python chunk loop through the ruckig package (_search_reference, its reference twin: the same answer
        bit for bit)."""
        if self._native is not None:
            return self._search_native(view, targets, vels, bases, prune)
        return self._search_reference(view, targets, vels, bases, prune)

    def _search_reference(self, view: View, targets: np.ndarray, vels: np.ndarray, bases: np.ndarray,
                          prune: bool) -> tuple[int, int, tuple]:
        """_search without the native ruckig batch: the pruned candidates built through the ruckig Python package
        in rank-ordered chunks (CHUNKS, _build_many) and checked together (_first_clear); the reference twin of
        _search_native (docs/architecture.md "Fast paths and their reference twins")."""
        rest = np.flatnonzero(static_clear(view, targets, self.margin)) if prune else np.arange(targets.shape[0])
        lo = 0
        for size in self.chunk_sizes(rest.shape[0]):
            sel = rest[lo:lo + size]
            built = self._build_many(view, targets[sel], vels[sel], bases[sel])
            j = self._first_clear(view, built)
            if j >= 0:
                return int(sel[built.rows[j]]), lo + int(built.rows[j]) + 1, built.samples(j)
            lo += size
        return -1, int(rest.shape[0]), ()

    def _search_native(self, view: View, targets: np.ndarray, vels: np.ndarray, bases: np.ndarray,
                       prune: bool) -> tuple[int, int, tuple]:
        """_search in one compiled call (candidate_search.search, through the native ruckig batch); the frame
        inputs are the products _build_many forms, in numpy (frame_inputs_reference, or search's own copy of them
        where frame_products_known)."""
        if self._counts[3]:
            frame_in = self._no_frames                          # search() computes numpy's products itself
        else:
            frame_in = frame_inputs_reference(bases, targets, vels, view.position, view.velocity, view.acceleration)
        if self._stacked_view is not view:
            query = view.grid.collision_query(view.limits.radius + self.margin)
            self._limits_row[7], self._limits_row[8] = view.t, view.dt
            self._stacked = (query is not None, no_grid_query() if query is None else query)
            self._stacked_view = view
        has_grid, query = self._stacked
        tracks = view.tracks
        j, tried, n_built, p, v, a = search(self._native, frame_in, bases, targets, vels, prune, self._limits_row,
                                            self._counts, view.position, view.velocity, view.acceleration,
                                            view.bounds_lo, view.bounds_hi, self._wall_r, tracks.position,
                                            tracks.velocity, tracks.radius, self._reach_r, has_grid, query)
        self.last_candidates_built += int(n_built)
        return int(j), int(tried), (p, v, a)

    def _first_clear(self, view: View, built: "_Built") -> int:
        """Index (into built.rows) of the first built candidate whose samples 1.. are clear (checks.py: walls and
        tracks from _build_many's screen, then the grid in one query for the candidates that passed them); -1 if
        none. The same answer as checks.trajectory_clear on each in turn."""
        counts = built.counts
        p = built.p
        if counts.shape[0] == 1:
            if built.bad[0]:
                return -1
            return -1 if view.grid.collides(p[0, 1:counts[0]], view.limits.radius + self.margin).any() else 0
        left = np.flatnonzero(~built.bad)
        if left.shape[0] == 0:
            return -1
        if left.shape[0] == 1:
            pts = p[left[0], 1:counts[left[0]]]
        else:
            pts = np.concatenate([p[i, 1:counts[i]] for i in left.tolist()])
        hit = view.grid.collides(pts, view.limits.radius + self.margin)
        if not hit.any():
            return int(left[0])
        lo = 0
        for i in left.tolist():
            hi = lo + int(counts[i]) - 1
            if not hit[lo:hi].any():
                return i
            lo = hi
        return -1

    def _chosen(self, view: View, target, rank: int, p, v, a) -> Trajectory:
        self.last_rank = rank
        self.last_target = np.array(target, dtype=float)
        return Trajectory.of_owned(view.t, view.dt, p, v, a)   # both searches give fresh C-contiguous float samples

    def plan_reference(self, view: View) -> Trajectory | None:
        """plan() trying the candidates strictly one at a time in rank order (build, check, next): the reference
        twin that plan()'s chunked evaluation is tested against (the same trajectory, bit for bit, on every view)."""
        self._reset_diagnostics()
        p0 = view.position
        g = view.goal - p0
        order = self.ranked_candidates(view)
        targets = p0 + self.step_m * self.directions          # [n, d]
        end_vel = self.end_speed * self.directions             # [n, d]
        static_ok = None
        rank = 0
        if math.sqrt(float(g @ g)) < self.step_m:
            rank = -1  # the goal itself, reached at rest, is tried first
        for r in range(rank, self.n_candidates):
            if r < 0:
                target, vel = view.goal, np.zeros(self.dims)
                basis = frame_basis(g / max(math.sqrt(float(g @ g)), 1e-12))
            else:
                i = order[r]
                if r > 0:
                    if static_ok is None:  # once the best candidate failed, prune blocked end points in one query
                        static_ok = static_clear(view, targets, self.margin)
                    if not static_ok[i]:
                        continue
                target, vel = targets[i], end_vel[i]
                basis = self._bases[i]
            self.last_candidates_tried += 1
            found = self._try_one(view, np.asarray(target, dtype=float)[None], np.asarray(vel, dtype=float)[None],
                                  basis[None], r + 1 if rank < 0 else r)
            if found is not None:
                return found
        return None

    def _build_many(self, view: View, targets: np.ndarray, vels: np.ndarray, bases: np.ndarray) -> "_Built":
        """The primitives to (targets, vels [n, d], end acceleration 0) within the norm limits (samples 1..K-1;
        sample 0 is the given state), in the world frame, with the wall and track screen of checks.py (a), (c).
        bases: [n, d, d] rows of the planning frames (world -> frame).

        Norm limits from ruckig's per-axis limits (module doc): build with (v_max, a_max); while a sample's |v| or
        |a|, or the step bound between samples (candidate_kernels.peaks), exceeds its norm limit, rebuild with the
        per-axis limit scaled by 0.95 * limit / peak (at most _N_SCALED_REBUILDS times), then once with
        v_max / sqrt(d), a_max / sqrt(d); a build that still violates, or that ruckig rejects, is left out. Each
        rebuild stage runs ruckig once per candidate still open and samples and checks them all in one compiled
        evaluation; the frame changes are the same products as numpy's (candidate_kernels)."""
        d = self.dims
        n = targets.shape[0]
        v_max, a_max = self.limits.v_max, self.limits.a_max
        mm_mode, sq_order = self._orders
        inputs = self._inputs(n)
        cur_v = (bases @ view.velocity).tolist()
        cur_a = (bases @ view.acceleration).tolist()
        tgt_p = (bases @ (np.asarray(targets, dtype=float) - view.position)[:, :, None])[:, :, 0].tolist()
        tgt_v = (bases @ np.asarray(vels, dtype=float)[:, :, None])[:, :, 0].tolist()
        for c in range(n):
            inp = inputs[c]
            inp.current_velocity = cur_v[c]
            inp.current_acceleration = cur_a[c]
            inp.target_position = tgt_p[c]
            inp.target_velocity = tgt_v[c]
        lim_v = [v_max] * n
        lim_a = [a_max] * n
        stage = [0] * n
        accepted: list = [None] * n      # (samples array, its row, sample count) of each accepted candidate
        open_ = list(range(n))
        last = _N_SCALED_REBUILDS + 1
        dt = view.dt
        calculate, traj = self._otg.calculate, self._traj
        working, finished = ruckig.Result.Working, ruckig.Result.Finished
        n_built = 0
        while open_:
            built, keep, flat, durations = [], [], [], []
            for c in open_:
                if stage[c] == last:
                    lim_v[c], lim_a[c] = v_max / math.sqrt(d), a_max / math.sqrt(d)
                inp = inputs[c]
                inp.max_velocity = [lim_v[c]] * d
                inp.max_acceleration = [lim_a[c]] * d
                n_built += 1
                try:
                    result = calculate(inp, traj)
                except (ruckig.RuckigError, ValueError):   # e.g. an error code the binding cannot name
                    result = None
                # rejected: e.g. a target velocity above the per-axis limit, or longer than MAX_PLAN_HORIZON_S
                duration = traj.duration
                if (result == working or result == finished) and duration <= MAX_PLAN_HORIZON_S:
                    built.append(c)
                    durations.append(duration)
                    flat += profile_row(traj)
                elif stage[c] < last:
                    stage[c] = last                  # nothing to scale from: go to the conservative limits
                    keep.append(c)
            if built:
                samples, counts, v_peaks, a_peaks = sampled_peaks(
                    np.array(flat).reshape(len(built), d, PROFILE_WIDTH), np.array(durations), dt, sq_order)
                for i, (c, k, v_peak, a_peak) in enumerate(zip(built, counts.tolist(), v_peaks.tolist(),
                                                               a_peaks.tolist())):
                    if v_peak <= v_max + _TOL and a_peak <= a_max + _TOL:
                        accepted[c] = (samples, i, k)
                        continue
                    if stage[c] >= last:
                        continue
                    if v_peak > v_max:
                        lim_v[c] *= _SCALE_SAFETY * v_max / v_peak
                    if a_peak > a_max:
                        lim_a[c] *= _SCALE_SAFETY * a_max / a_peak
                    stage[c] += 1
                    keep.append(c)
            open_ = sorted(keep)
        self.last_candidates_built += n_built
        rows = [c for c in range(n) if accepted[c] is not None]
        if not rows:
            return _Built.nothing(d)
        counts = np.array([accepted[c][2] for c in rows], dtype=np.int64)
        first = accepted[rows[0]][0]
        if first.shape[0] == len(rows) and all(accepted[c][0] is first and accepted[c][1] == i
                                               for i, c in enumerate(rows)):
            frame = first                            # one stage accepted them all, in order: its samples as they are
        else:
            frame = np.zeros((len(rows), int(counts.max()), 3, d))
            for i, c in enumerate(rows):
                src, j, k = accepted[c]
                frame[i, :k] = src[j, :k]
        wall_lo, wall_hi, track_pos, track_vel, reach2 = self._screen(view)
        p, v, a, bad = world_and_screen(frame, counts, bases if len(rows) == n else bases[rows], view.position,
                                        view.velocity, view.acceleration, wall_lo, wall_hi, track_pos, track_vel,
                                        reach2, view.t, dt, mm_mode, sq_order)
        return _Built(rows, p, v, a, counts, bad)

    def _screen(self, view: View) -> tuple:
        """The wall and track bounds of world_and_screen for ``view`` (kept for the view last asked about): the
        lowest and highest admissible sample coordinate [d] (m; checks.py (c)), the tracks' means [M, d] and the
        squared distances [M] (m^2) below which a sample meets one (a)."""
        if self._screen_view is not view:
            tracks = view.tracks
            reach = tracks.radius + self._reach_r
            self._screen_args = (view.bounds_lo + self._wall_r, view.bounds_hi - self._wall_r, tracks.position,
                                 tracks.velocity, reach * reach)
            self._screen_view = view
        return self._screen_args

    def _inputs(self, n: int) -> list:
        """n ruckig InputParameters with the planner's fixed fields (a pool reused by every plan)."""
        pool = self._input_pool
        d = self.dims
        while len(pool) < n:
            inp = ruckig.InputParameter(d)
            inp.current_position = [0.0] * d
            inp.target_acceleration = [0.0] * d
            inp.max_jerk = [self.jerk_max] * d
            inp.minimum_duration = self.min_duration
            pool.append(inp)
        return pool
