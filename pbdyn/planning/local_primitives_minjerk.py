"""The thesis program's local motion primitives ("Jerk_Primitive"; thesis 4-1-1, appendix A-2, Algorithm 3).

Registry name "local_primitives_minjerk". Every step (implementation-facts.md "Trajectory planners"):

- n_candidates = 72 end points on a circle of radius step_m = 3 m around the MAV at angles 2 pi k / n (eq. A-4;
  3D: on a sphere, pbdyn.planning.local_primitives.sphere_directions);
- every end state has velocity end_speed_frac (0.5) x v_max pointing from its own end point at the GOAL (the
  program's vf = 0.5 v_max (goal - p1) / |goal - p1|; not along the candidate's direction, as pbdyn's ruckig
  "local_primitives" does) and acceleration 0; a candidate whose end point is the goal has no such direction (the
  program's 0 / 0 gave NaN samples, which its check rejected) and is never taken -- so a MAV flying straight at a
  goal exactly step_m ahead swerves onto a neighbouring candidate, as the program's did;
- one duration T = max(1.2 step_m / v_max, 0.5 s) for every candidate;
- per axis the minimum-jerk polynomial of Mueller, Hehn & D'Andrea (2015, the thesis' [15]) with the start fully
  fixed to the MAV's (p0, v0, a0) and the end fully fixed to (p1, v1, 0): a quintic,
      p(t) = alpha t^5/120 + beta t^4/24 + gamma t^3/6 + a0 t^2/2 + v0 t + p0,
      [alpha, beta, gamma] = 1/T^5 [[720, -360 T, 60 T^2], [-360 T, 168 T^2, -24 T^3], [60 T^2, -24 T^3, 3 T^4]]
                             [dp, dv, da],
      dp = p1 - p0 - v0 T - a0 T^2/2,  dv = v1 - v0 - a0 T,  da = a1 - a0;
- candidates tried in order of the angle between their direction and the goal direction (Algorithm 3, line 7;
  ties by index, pbdyn.planning.local_primitives.rank_by_goal_angle); the first whose samples 1..K-1 are clear
  (eq. A-2, A-3; pbdyn.planning.checks: tracks' constant-velocity predictions, OCCUPIED cells, walls; margin 0.5 m)
  is returned, and replan_check is always True, so only its first sample is executed.

pbdyn additions (not in the program; off under the thesis_program profile, PROGRAM_PARAMS): when the goal is nearer
than step_m, the goal itself, reached at rest in the same T, is tried before the fan (goal_first, as pbdyn's
local_primitives does). Under the physical profile
(PlannerContext.physical, the default) a candidate is skipped unless every sample 1..K-1 keeps |v| <= v_max and
|a| <= a_max and consecutive samples 0..K-1 meet the plan contract's step bounds (pbdyn.sim.contract:
|v_k+1 - v_k| <= a_max dt, |p_k+1 - p_k - (v_k + v_k+1) dt/2| <= a_max dt^2/4; relative tolerance 1e-9), so the
planner never breaks the contract there. The program bounded no acceleration, and its primitives rarely fit these
limits (from rest at v_max 4 m/s the best one peaks near 17 m/s^2), so under the physical profile this planner
mostly fails and brakes; it exists for the "thesis_program" profile (physical False), where no limit is checked.

Sampling: at k dt for k = 0..ceil(T/dt) (the plan contract's uniform spacing); a sample past T holds the end state
extrapolated (p1 + v1 (t - T), v1, 0). Sample 0 is the MAV's (p, v, a), copied in. samples = "all" checks samples
1..K-1; samples = "program" (PROGRAM_PARAMS) checks, as the program did, samples 1..n_c of candidate c with
n_c = floor(T_c / dt) evaluated in the program's own units and floating point (program_sample_counts): at v_max
6 m/s T = 0.6 s but 0.6 / 0.1 floors to 5, so the primitive's end is never checked; at 2 and 4 m/s 17 of the 72
candidates check one sample fewer than the others. All candidates are evaluated in
one array operation: the samples are linear in (dp, dv, da), with weights [K, 3] fixed by T and dt.

Static check: static_check = "pbdyn" tests the MAV ball + margin against OCCUPIED cells and keeps radius + 0.1 m
from the walls whether or not they were seen; "program" (PROGRAM_PARAMS) is the program's is_free: five probes
per sample (the centre and MAV radius + 1 m along +-x and +-y) against its map's extent and the OCCUPIED cells of
the MAV's grid, whose border ring is the program's wall cells -- so a seen wall keeps the centre 2 m away, an
unseen one only 1 m (pbdyn.planning.checks.program_grid_conflicts).
"""

from __future__ import annotations

import math

import numpy as np

from pbdyn.limits import MAX_PLAN_COUNT, MAX_PLAN_DISTANCE_M, MAX_PLAN_HORIZON_S
from pbdyn.planning import params
from pbdyn.planning.checks import batch_conflicts, grid_conflicts, program_grid_conflicts
from pbdyn.planning.local_primitives import candidate_directions, rank_by_goal_angle
from pbdyn.planning.protocols import PlannerContext
from pbdyn.planning.trajectory import Trajectory
from pbdyn.planning.view import View

_REL_TOL = 1e-9             # the plan contract's relative tolerance on every limit and bound
_COINCIDE_M = 1e-9          # an end point this close to the goal is the goal (the program's 0 / 0 end direction)
_SHRINK = 1.0 - 1e-12       # squared norms against slightly shrunk bounds: rounding never passes a violation
_MAX_BATCH_FLOATS = 1 << 20  # candidates x samples x max(1, tracks) per array evaluation (memory bound)


def _sq_norm(x: np.ndarray) -> np.ndarray:
    """Squared Euclidean norms over the last axis (d = 2 or 3 components; faster than einsum on small arrays)."""
    out = x[..., 0] * x[..., 0]
    for i in range(1, x.shape[-1]):
        out = out + x[..., i] * x[..., i]
    return out


def program_duration(step_m: float, v_max: float) -> float:
    """The program's primitive duration T = max(1.2 step_m / v_max, 0.5) (s); step_m in m, v_max in m/s."""
    return max(1.2 * step_m / v_max, 0.5)


PROGRAM_PX_PER_M = 10.0
"""The thesis program's unit: 10 pixels per metre."""


def program_sample_counts(n_candidates: int, step_m: float, v_max: float, dt: float) -> np.ndarray:
    """Per 2D candidate k (angle 360 k / n deg): the number of samples after the start the thesis program checked,
    floor(max(1.2 |d| / v_max, 0.5) / dt), with |d| and v_max in its pixels and |d| computed as it did
    (numpy's norm of (d cos, d sin) at the angle in degrees), so that its floating-point floor is reproduced."""
    d_px, v_px = step_m * PROGRAM_PX_PER_M, v_max * PROGRAM_PX_PER_M
    out = np.empty(n_candidates, dtype=np.int64)
    for k in range(n_candidates):
        th = math.radians(360.0 * k / n_candidates)
        length = np.linalg.norm(np.array([d_px * np.cos(th), d_px * np.sin(th)]))
        t = max(1.2 * length / v_px, 0.5)
        out[k] = max(1, int(np.floor(t / dt)))
    return out


def min_jerk_matrix(duration: float) -> np.ndarray:
    """The matrix [3, 3] mapping (dp, dv, da) to the jerk polynomial's (alpha, beta, gamma) for the fully fixed
    end state (Mueller, Hehn & D'Andrea 2015; see the module docstring); duration T in s."""
    t = float(duration)
    return np.array([[720.0, -360.0 * t, 60.0 * t * t],
                     [-360.0 * t, 168.0 * t * t, -24.0 * t ** 3],
                     [60.0 * t * t, -24.0 * t ** 3, 3.0 * t ** 4]]) / t ** 5


def min_jerk_coefficients(duration: float, start, end) -> np.ndarray:
    """(alpha, beta, gamma) [3, ...] of the minimum-jerk polynomial from start = (p0, v0, a0) to end = (p1, v1, a1)
    in ``duration`` T (s); each state entry is a scalar or an array (per axis, broadcast), SI units. The jerk is
    alpha t^2/2 + beta t + gamma (m/s^3)."""
    t = float(duration)
    p0, v0, a0 = (np.asarray(x, dtype=float) for x in start)
    p1, v1, a1 = (np.asarray(x, dtype=float) for x in end)
    delta = np.stack(np.broadcast_arrays(p1 - p0 - v0 * t - 0.5 * a0 * t * t, v1 - v0 - a0 * t, a1 - a0))
    return np.tensordot(min_jerk_matrix(t), delta, axes=1)


def min_jerk_weights(duration: float, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weights (Wp, Wv, Wa), each [K, 3], of (dp, dv, da) in the position, velocity and acceleration at ``times``
    [K] (s, 0 <= t <= T): p(t) = p0 + v0 t + a0 t^2/2 + Wp(t) @ (dp, dv, da), v(t) = v0 + a0 t + Wv(t) @ (...),
    a(t) = a0 + Wa(t) @ (...)."""
    t = np.asarray(times, dtype=float)
    m = min_jerk_matrix(duration)
    bp = np.stack([t ** 5 / 120.0, t ** 4 / 24.0, t ** 3 / 6.0], axis=1)
    bv = np.stack([t ** 4 / 24.0, t ** 3 / 6.0, t ** 2 / 2.0], axis=1)
    ba = np.stack([t ** 3 / 6.0, t ** 2 / 2.0, t], axis=1)
    return bp @ m, bv @ m, ba @ m


def min_jerk_states(duration: float, start, end, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, velocity and acceleration [K, d] of the minimum-jerk primitive from start = (p0, v0, a0) to
    end = (p1, v1, a1) (each [d], SI) at ``times`` [K] (s, within [0, T])."""
    coef = min_jerk_coefficients(duration, start, end)          # [3, d]
    p0, v0, a0 = (np.asarray(x, dtype=float) for x in start)
    t = np.asarray(times, dtype=float)[:, None]
    al, be, ga = coef[0][None], coef[1][None], coef[2][None]
    p = al * t ** 5 / 120.0 + be * t ** 4 / 24.0 + ga * t ** 3 / 6.0 + a0 * t * t / 2.0 + v0 * t + p0
    v = al * t ** 4 / 24.0 + be * t ** 3 / 6.0 + ga * t * t / 2.0 + a0 * t + v0
    a = al * t ** 3 / 6.0 + be * t * t / 2.0 + ga * t + a0
    return p, v, a


class LocalPrimitivesMinJerk:
    """The thesis program's local primitives planner (registry name "local_primitives_minjerk"; module docstring).

    Args:
        context: the trial's fixed facts (dims, dt, limits, arena box, physical).
        n_candidates: number of end points on the circle (2D: at angles 2 pi k / n; 72 = 5 deg apart).
        sphere_spacing_deg: 3D only — end points on the sphere in rings every spacing degrees
            (pbdyn.planning.local_primitives.sphere_directions; 10 deg: 412 points).
        step_m: distance (m) from the MAV to each end point.
        end_speed_frac: end speed as a fraction of v_max, pointing at the goal; end acceleration 0.
        margin: safety margin (m) added to the MAV radius in the collision check.
        duration: primitive duration T (s); default max(1.2 step_m / v_max, 0.5) as the thesis program. A duration
            above pbdyn.limits.MAX_PLAN_HORIZON_S builds no primitive (every plan fails).
        goal_first: try the goal itself (at rest) first when it is nearer than step_m (pbdyn; not the program).
        samples: "all" (check samples 1..K-1) or "program" (the program's per-candidate count; 2D with the
            default duration only, else "all"); see the module docstring.
        static_check: "pbdyn" (the MAV ball + margin against OCCUPIED cells, and radius + 0.1 m from the walls;
            pbdyn.planning.checks) or "program" (the program's five probes against its map and the OCCUPIED cells,
            so walls count where they have been seen; checks.program_grid_conflicts).

    Diagnostics of the last plan() call: last_candidates_built (candidates whose samples were computed),
    last_candidates_tried (candidates examined in rank order up to and including the chosen one; all built ones
    on failure), last_rank (rank of the chosen candidate, 0 = best, the goal candidate counting as rank 0 when
    tried; None on failure), last_target (its end point [d]).
    """

    PROGRAM_PARAMS: dict = {"goal_first": False, "samples": "program", "static_check": "program"}
    """The thesis_program profile's parameters (the other defaults are the program's)."""

    def __init__(self, context: PlannerContext, *, n_candidates: int = 72, sphere_spacing_deg: float = 10.0,
                 step_m: float = 3.0, end_speed_frac: float = 0.5, margin: float = 0.5,
                 duration: float | None = None, goal_first: bool = True, samples: str = "all",
                 static_check: str = "pbdyn"):
        n_candidates = params.integer("n_candidates", n_candidates, lo=1, hi=MAX_PLAN_COUNT)
        sphere_spacing_deg = params.number("sphere_spacing_deg", sphere_spacing_deg, lo=0.5, hi=90.0)
        step_m = params.number("step_m", step_m, lo=0.0, lo_open=True, hi=MAX_PLAN_DISTANCE_M)
        end_speed_frac = params.number("end_speed_frac", end_speed_frac, lo=0.0, hi=1.0)
        margin = params.non_negative("margin", margin)
        if duration is not None:
            duration = params.number("duration", duration, lo=0.0, lo_open=True, hi=MAX_PLAN_HORIZON_S)
        if not isinstance(goal_first, bool):
            raise ValueError(f"goal_first must be true or false, got {goal_first!r}")
        if samples not in ("all", "program"):
            raise ValueError(f"samples must be 'all' or 'program', got {samples!r}")
        if static_check not in ("pbdyn", "program"):
            raise ValueError(f"static_check must be 'pbdyn' or 'program', got {static_check!r}")
        self.static_check = static_check
        self.dims = d = int(context.dims)
        self.dt = float(context.dt)
        self.limits = context.limits
        self.physical = bool(context.physical)
        self.sphere_spacing_deg = float(sphere_spacing_deg)
        self.step_m = float(step_m)
        self.end_speed = float(end_speed_frac) * self.limits.v_max
        self.margin = float(margin)
        self.duration = float(program_duration(self.step_m, self.limits.v_max) if duration is None else duration)
        self.directions = candidate_directions(d, int(n_candidates), self.sphere_spacing_deg)
        self.n_candidates = int(self.directions.shape[0])
        self.goal_first = goal_first
        self.checked = None     # [n_candidates] samples checked per candidate (None: all)
        if samples == "program" and d == 2 and duration is None:
            self.checked = program_sample_counts(self.n_candidates, self.step_m, self.limits.v_max, self.dt)
        self._sampling: tuple | None = None
        self._sampling_dt: float | None = None
        self.last_candidates_built = 0
        self.last_candidates_tried = 0
        self.last_rank: int | None = None
        self.last_target: np.ndarray | None = None

    def replan_check(self, view: View) -> bool:
        """Always True: the thesis program replans every step and executes one sample."""
        return True

    def ranked_candidates(self, view: View) -> np.ndarray:
        """Candidate indices sorted by the angle between candidate and goal direction (ascending, ties by index)."""
        return rank_by_goal_angle(self.directions, view.goal - view.position)

    def sample_times(self, dt: float) -> np.ndarray:
        """Sample times [K] (s, from the plan's start): k dt for k = 0..ceil(T/dt) (at least 2 samples)."""
        n = max(2, math.ceil(self.duration / dt - 1e-9) + 1)
        return dt * np.arange(n)

    def _weights(self, dt: float) -> tuple:
        """Per-sample constants for the world step dt (cached): times, clipped times, time past T, held mask,
        and the weights of (dp, dv, da)."""
        if self._sampling is None or self._sampling_dt != dt:
            times = self.sample_times(dt)
            tau = np.minimum(times, self.duration)
            held = times > self.duration
            extra = np.where(held, times - self.duration, 0.0)
            self._sampling = (times, tau, held, extra, *min_jerk_weights(self.duration, tau))
            self._sampling_dt = dt
        return self._sampling

    def plan(self, view: View) -> Trajectory | None:
        """The first clear primitive in rank order (physical profile: also within the limits), sampled at view.dt;
        None if none is (thesis Algorithm 3). Clearance and limits are checked on samples 1..K-1: sample 0 is the
        current state, which no plan can change."""
        self.last_candidates_built = 0
        self.last_candidates_tried = 0
        self.last_rank = None
        self.last_target = None
        if not self.duration <= MAX_PLAN_HORIZON_S:
            return None
        p0 = view.position
        g = view.goal - p0
        dist = math.sqrt(float(g @ g))
        order = self.ranked_candidates(view)
        targets = p0 + self.step_m * self.directions[order]                     # [n, d], rank order
        to_goal = view.goal[None] - targets
        reach = np.sqrt(np.einsum("nd,nd->n", to_goal, to_goal))
        rank = np.flatnonzero(reach > _COINCIDE_M)     # an end point on the goal has no end direction: never taken
        order, targets = order[rank], targets[rank]
        vels = (self.end_speed / reach[rank])[:, None] * to_goal[rank]
        times = self._weights(view.dt)[0]
        checked = None if self.checked is None else np.minimum(self.checked[order], times.shape[0] - 1)
        if self.goal_first and dist < self.step_m:   # the goal itself, reached at rest, is tried first
            targets = np.concatenate([view.goal[None], targets])
            vels = np.concatenate([np.zeros((1, self.dims)), vels])
            rank = np.concatenate([[0], rank + 1])
            if checked is not None:
                checked = np.concatenate([[times.shape[0] - 1], checked])
        n = targets.shape[0]
        chunk = max(1, _MAX_BATCH_FLOATS // (times.shape[0] * max(1, len(view.tracks))))
        for lo in range(0, n, chunk):
            hi = min(n, lo + chunk)
            self.last_candidates_built += hi - lo
            found = self._first_clear(view, targets[lo:hi], vels[lo:hi],
                                      None if checked is None else checked[lo:hi])
            if found is None:
                self.last_candidates_tried += hi - lo
                continue
            j, (p, v, a) = found
            self.last_candidates_tried += j + 1
            self.last_rank = int(rank[lo + j])
            self.last_target = np.array(targets[lo + j], dtype=float)
            return Trajectory(view.t, view.dt, p, v, a)
        return None

    def _samples(self, view: View, targets: np.ndarray, vels: np.ndarray, with_derivatives: bool):
        """Samples (p, v, a) [n, K, d] of the primitives to (targets [n, d], vels [n, d], 0); v and a are None
        unless with_derivatives."""
        times, tau, held, extra, wp, wv, wa = self._weights(view.dt)
        t = self.duration
        p0, v0, a0 = view.position, view.velocity, view.acceleration
        delta = np.stack([targets - (p0 + v0 * t + 0.5 * a0 * t * t),                  # [n, 3, d]
                          vels - (v0 + a0 * t),
                          np.broadcast_to(-a0, targets.shape)], axis=1)
        p = (p0 + tau[:, None] * v0 + (0.5 * tau * tau)[:, None] * a0)[None] + np.matmul(wp, delta)
        p[:, held] = targets[:, None, :] + extra[held][None, :, None] * vels[:, None, :]
        p[:, 0] = p0
        if not with_derivatives:
            return p, None, None
        v = (v0 + tau[:, None] * a0)[None] + np.matmul(wv, delta)
        a = a0 + np.matmul(wa, delta)
        v[:, held] = vels[:, None, :]
        a[:, held] = 0.0
        v[:, 0] = v0
        a[:, 0] = a0
        return p, v, a

    def _within_limits(self, p: np.ndarray, v: np.ndarray, a: np.ndarray, dt: float) -> np.ndarray:
        """Per candidate [n]: the plan contract's speed, acceleration and step bounds hold (samples [n, K, d])."""
        v_max, a_max = self.limits.v_max, self.limits.a_max
        tol = (1.0 + _REL_TOL) ** 2 * _SHRINK
        v1, a1 = v[:, 1:], a[:, 1:]
        ok = _sq_norm(v1).max(axis=1) <= v_max * v_max * tol
        ok &= _sq_norm(a1).max(axis=1) <= a_max * a_max * tol
        dv = v[:, 1:] - v[:, :-1]
        ok &= _sq_norm(dv).max(axis=1) <= (a_max * dt) ** 2 * tol
        gap = p[:, 1:] - p[:, :-1] - 0.5 * (v[:, :-1] + v[:, 1:]) * dt
        ok &= _sq_norm(gap).max(axis=1) <= (a_max * dt * dt / 4.0) ** 2 * tol
        return ok

    def _first_clear(self, view: View, targets: np.ndarray, vels: np.ndarray, checked: np.ndarray | None = None):
        """(index, (p, v, a) [K, d]) of the first candidate (in the given order) that is clear (and, physical
        profile, within the limits), or None. Walls, tracks and limits are evaluated for all candidates at once;
        the occupancy grid for the survivors in order, in batches of 1, 2, 4, ... ``checked`` [n]: samples 1..checked
        of each candidate are checked (None: all)."""
        p, v, a = self._samples(view, targets, vels, with_derivatives=self.physical)
        times = view.t + self._weights(view.dt)[0]
        program = self.static_check == "program"
        ok = ~_by_count(lambda rows, c: batch_conflicts(view, p[rows, 1:c + 1], times[1:c + 1], self.margin,
                                                        walls=not program),
                        p.shape[0], p.shape[1] - 1, checked)
        if self.physical:
            ok &= self._within_limits(p, v, a, view.dt)
        survivors = np.flatnonzero(ok)
        size, start = 1, 0
        while start < survivors.size:
            batch = survivors[start:start + size]
            blocked = _by_count(lambda rows, c: (program_grid_conflicts(view, p[batch[rows], 1:c + 1]) if program
                                                 else grid_conflicts(view, p[batch[rows], 1:c + 1], self.margin)),
                                batch.size, p.shape[1] - 1, None if checked is None else checked[batch])
            if not blocked.all():
                j = int(batch[int(np.argmin(blocked))])
                if v is None:
                    _, v, a = self._samples(view, targets[j:j + 1], vels[j:j + 1], with_derivatives=True)
                    v, a = v[0], a[0]
                else:
                    v, a = v[j], a[j]
                return j, (np.ascontiguousarray(p[j]), np.ascontiguousarray(v), np.ascontiguousarray(a))
            start += size
            size *= 2
        return None


def _by_count(conflicts, n: int, all_samples: int, checked: np.ndarray | None) -> np.ndarray:
    """[n] bool: conflicts(rows, c) evaluated per group of candidates that check the same number c of samples
    (checked [n]; None: every candidate checks all_samples)."""
    if checked is None:
        return conflicts(slice(None), all_samples)
    out = np.zeros(n, dtype=bool)
    for c in np.unique(checked).tolist():
        rows = np.flatnonzero(checked == c)
        out[rows] = conflicts(rows, c)
    return out
