"""The thesis program's local motion primitives ("Jerk_Primitive"; thesis 4-1-1, appendix A-2, Algorithm 3).

Registry name "local_primitives_minjerk". Every step (docs/thesis-program.md "Trajectory planners"):

- n_candidates = 72 end points on a circle of radius step_m = 3 m around the MAV at angles 2 pi k / n (eq. A-4;
  3D: on a sphere, pbdyn.planning.primitives.local.sphere_directions);
- every end state has velocity end_speed_frac (0.5) x v_max pointing from its own end point at the GOAL (the
  program's vf = 0.5 v_max (goal - p1) / |goal - p1|; not along the candidate's direction, as pbdyn's ruckig
  "local_primitives" does) and acceleration 0; a candidate whose end point is the goal has no such direction (the
  program's 0 / 0 gave NaN samples, which its check rejected) and is never taken -- so a MAV flying straight at a
  goal exactly step_m ahead swerves onto a neighbouring candidate; with arithmetic = "program" (PROGRAM_PARAMS) the
  end velocities come from the program's pixel arithmetic, where such an end point may also leave a residue of ulps
  whose direction the end velocity takes (program_end_velocities);
- one duration T = max(1.2 step_m / v_max, 0.5 s) for every candidate;
- per axis the minimum-jerk polynomial of Mueller, Hehn & D'Andrea (2015, the thesis' [15]) with the start fully
  fixed to the MAV's (p0, v0, a0) and the end fully fixed to (p1, v1, 0): a quintic,
      p(t) = alpha t^5/120 + beta t^4/24 + gamma t^3/6 + a0 t^2/2 + v0 t + p0,
      [alpha, beta, gamma] = 1/T^5 [[720, -360 T, 60 T^2], [-360 T, 168 T^2, -24 T^3], [60 T^2, -24 T^3, 3 T^4]]
                             [dp, dv, da],
      dp = p1 - p0 - v0 T - a0 T^2/2,  dv = v1 - v0 - a0 T,  da = a1 - a0;
- candidates tried in order of the angle between their direction and the goal direction (Algorithm 3, line 7;
  ties by index, pbdyn.planning.primitives.local.rank_by_goal_angle); the first whose samples 1..K-1 are clear
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
n_c = floor(T_c / dt) evaluated in the program's own units and floating point (program_sample_counts, with its
numpy 1.23.4's last bits): at v_max 6 m/s T = 0.6 s but 0.6 / 0.1 floors to 5 at 65 of the 72 candidates, so their
end is never checked (6 samples at the other 7); at 2 and 4 m/s 30 of the 72 check one sample fewer than the rest.
All candidates are evaluated in one array operation: the samples are linear in (dp, dv, da), with weights [K, 3]
fixed by T and dt.

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
from pbdyn.planning.primitives.local import candidate_directions, rank_by_goal_angle
from pbdyn.planning.protocols import PlannerContext
from pbdyn.planning.trajectory import Trajectory
from pbdyn.planning.view import View
from pbdyn.world.maps import PROGRAM_PX_PER_M, PROGRAM_WALL_M

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


PROGRAM_SAMPLE_COUNTS: dict[float, tuple[int, ...]] = {
    2.0: (18, 17, 18, 18, 17, 17, 17, 18, 18, 18, 18, 18, 17, 17, 17, 18, 18, 18, 18, 18, 18, 18, 18, 18, 17, 18, 18,
          18, 18, 18, 17, 17, 18, 18, 18, 17, 18, 17, 18, 18, 18, 17, 17, 17, 18, 18, 18, 18, 17, 17, 17, 18, 18, 17,
          18, 17, 17, 18, 18, 17, 17, 18, 17, 17, 17, 18, 17, 17, 17, 18, 18, 17),
    4.0: (9, 8, 9, 9, 8, 8, 8, 9, 9, 9, 9, 9, 8, 8, 8, 9, 9, 9, 9, 9, 9, 9, 9, 9, 8, 9, 9, 9, 9, 9, 8, 8, 9, 9, 9, 8,
          9, 8, 9, 9, 9, 8, 8, 8, 9, 9, 9, 9, 8, 8, 8, 9, 9, 8, 9, 8, 8, 9, 9, 8, 8, 9, 8, 8, 8, 9, 8, 8, 8, 9, 9, 8),
    6.0: (5, 5, 5, 6, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5, 6, 5, 5, 5, 5, 5, 6, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5, 6, 5, 5,
          5, 5, 5, 6, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5, 6, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5, 6, 5, 5),
}
"""Per MAV speed (m/s): the samples the program checked per candidate (72, 3 m, dt 0.1 s), as its numpy 1.23.4
computed them (tools/program_tables.py writes this table)."""


def program_sample_counts(n_candidates: int, step_m: float, v_max: float, dt: float) -> np.ndarray:
    """Per 2D candidate k (angle 360 k / n deg): the number of samples after the start the thesis program checked,
    floor(max(1.2 |d| / v_max, 0.5) / dt), with |d| and v_max in its pixels and |d| = numpy's norm of
    (d cos, d sin) at the angle in degrees: for the program's own setting (72 candidates, 3 m, dt 0.1 s, v_max 2, 4
    or 6 m/s) PROGRAM_SAMPLE_COUNTS, whose floors depend on its numpy's last bit; else computed so here."""
    if (n_candidates, step_m, dt) == (72, 3.0, 0.1) and float(v_max) in PROGRAM_SAMPLE_COUNTS:
        return np.asarray(PROGRAM_SAMPLE_COUNTS[float(v_max)], dtype=np.int64)
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


PROGRAM_TIE_ORDERS: dict[float, tuple[int, ...]] = {
    0.0: (0, 71, 1, 2, 70, 3, 69, 4, 68, 5, 67, 66, 6, 65, 7, 64, 8, 63, 9, 62, 10, 61, 11, 60, 12, 59, 13, 58, 14,
           15, 57, 16, 56, 17, 55, 54, 18, 19, 53, 20, 52, 21, 51, 22, 50, 49, 23, 24, 48, 25, 47, 26, 46, 27, 45,
           28, 44, 43, 29, 30, 42, 41, 31, 40, 32, 39, 33, 34, 38, 35, 37, 36),
    45.0: (9, 10, 8, 7, 11, 6, 12, 5, 13, 4, 14, 3, 15, 2, 16, 17, 1, 0, 18, 71, 19, 20, 70, 21, 69, 68, 22, 67, 23,
           24, 66, 65, 25, 64, 26, 63, 27, 62, 28, 61, 29, 30, 60, 31, 59, 32, 58, 33, 57, 34, 56, 55, 35, 54, 36,
           53, 37, 38, 52, 51, 39, 50, 40, 49, 41, 48, 42, 43, 47, 46, 44, 45),
    90.0: (18, 17, 19, 20, 16, 15, 21, 22, 14, 23, 13, 24, 12, 25, 11, 26, 10, 27, 9, 28, 8, 29, 7, 30, 6, 31, 5, 32,
           4, 33, 3, 2, 34, 35, 1, 36, 0, 37, 71, 38, 70, 39, 69, 40, 68, 41, 67, 66, 42, 43, 65, 64, 44, 63, 45, 62,
           46, 61, 47, 60, 48, 59, 49, 50, 58, 51, 57, 52, 56, 55, 53, 54),
    135.0: (27, 26, 28, 29, 25, 30, 24, 31, 23, 32, 22, 33, 21, 34, 20, 19, 35, 18, 36, 17, 37, 38, 16, 15, 39, 14,
           40, 13, 41, 12, 42, 11, 43, 44, 10, 45, 9, 46, 8, 47, 7, 6, 48, 49, 5, 50, 4, 3, 51, 52, 2, 53, 1, 54, 0,
           55, 71, 70, 56, 57, 69, 58, 68, 59, 67, 60, 66, 61, 65, 62, 64, 63),
    180.0: (36, 35, 37, 38, 34, 33, 39, 40, 32, 41, 31, 42, 30, 43, 29, 44, 28, 45, 27, 26, 46, 25, 47, 24, 48, 23,
           49, 50, 22, 21, 51, 20, 52, 53, 19, 54, 18, 17, 55, 56, 16, 57, 15, 14, 58, 13, 59, 12, 60, 61, 11, 62,
           10, 9, 63, 64, 8, 65, 7, 66, 6, 67, 5, 68, 4, 69, 3, 2, 70, 71, 1, 0),
    -45.0: (63, 62, 64, 65, 61, 66, 60, 67, 59, 68, 58, 69, 57, 56, 70, 55, 71, 54, 0, 1, 53, 2, 52, 3, 51, 4, 50, 5,
           49, 48, 6, 7, 47, 8, 46, 45, 9, 44, 10, 11, 43, 12, 42, 13, 41, 40, 14, 39, 15, 16, 38, 37, 17, 18, 36,
           19, 35, 20, 34, 33, 21, 32, 22, 31, 23, 30, 24, 29, 25, 28, 26, 27),
    -90.0: (54, 53, 55, 52, 56, 57, 51, 50, 58, 49, 59, 48, 60, 61, 47, 46, 62, 45, 63, 44, 64, 65, 43, 66, 42, 67,
           41, 68, 40, 39, 69, 38, 70, 37, 71, 36, 0, 35, 1, 2, 34, 3, 33, 32, 4, 5, 31, 30, 6, 29, 7, 28, 8, 9, 27,
           26, 10, 25, 11, 24, 12, 13, 23, 22, 14, 15, 21, 20, 16, 17, 19, 18),
    -135.0: (45, 46, 44, 47, 43, 48, 42, 41, 49, 50, 40, 51, 39, 38, 52, 37, 53, 36, 54, 35, 55, 34, 56, 57, 33, 58,
           32, 31, 59, 30, 60, 61, 29, 62, 28, 27, 63, 26, 64, 65, 25, 24, 66, 23, 67, 22, 68, 21, 69, 20, 70, 71,
           19, 18, 0, 1, 17, 2, 16, 15, 3, 14, 4, 13, 5, 12, 6, 7, 11, 10, 8, 9),
}
"""The program's candidate order (indices k of theta = 5k deg) at the goal directions phi (deg) where its costs
tie, as its numpy 1.23.4 argsort left them (tools/program_tables.py writes this table; docs/profiles.md "Profiles")."""


def _snap_px(px: np.ndarray) -> np.ndarray:
    """Pixel values snapped to whole pixels within 1e-6 px (the program's positions lay on them after every step)."""
    whole = np.round(px)
    return np.where(np.abs(px - whole) < 1e-6, whole, px)


def program_pixels(p: np.ndarray) -> np.ndarray:
    """Positions p [..., 2] (m, pbdyn's frame) in the program's pixel frame (10 px per m, origin 1 m outside pbdyn's),
    snapped to whole pixels (_snap_px)."""
    return _snap_px((np.asarray(p, dtype=float) + PROGRAM_WALL_M) * PROGRAM_PX_PER_M)


PROGRAM_THETA_DEG = np.arange(0, 360, 5)
"""The program's 72 candidate angles (deg); candidate k of pbdyn's 72 in 2D lies at the same angle."""


def program_unit_vectors() -> np.ndarray:
    """The program's candidate directions [72, 2], each computed as it did (np.cos / np.sin of math.radians of the
    angle in degrees), to the last bit."""
    return np.array([[np.cos(math.radians(t)), np.sin(math.radians(t))] for t in PROGRAM_THETA_DEG])


def program_rank(to_goal: np.ndarray) -> np.ndarray:
    """The program's order of its 72 candidates for the goal vector ``to_goal`` [2] (m, goal minus MAV): by the
    squared wrapped difference (deg^2) between theta = 5k deg and phi = degrees(atan2(dy, dx)) computed from the
    vector in its pixels (snapped to whole pixels within 1e-6 px); ties at the eight directions where they occur in
    PROGRAM_TIE_ORDERS' order, any other tie by index."""
    d = _snap_px(np.asarray(to_goal, dtype=float) * PROGRAM_PX_PER_M)
    phi = math.degrees(math.atan2(float(d[1]), float(d[0])))
    if phi in PROGRAM_TIE_ORDERS:
        return np.asarray(PROGRAM_TIE_ORDERS[phi])
    diff = np.abs(PROGRAM_THETA_DEG % 360 - phi % 360)
    return np.argsort(np.where(diff <= 180, diff, 360 - diff) ** 2, kind="stable")


def program_end_velocities(p0: np.ndarray, goal: np.ndarray, unit: np.ndarray, step_m: float,
                           end_speed: float) -> np.ndarray:
    """End velocities [n, 2] (m/s) of candidates with the program's directions ``unit`` [n, 2] from p0 [2] (m), as
    its pixel arithmetic gave them: p1 = p0 + d unit and vf = end_speed (goal - p1) / |goal - p1| in pixels. Where p1
    falls on the goal the difference is whatever floating point leaves of it: exactly 0 (NaN rows: its check
    rejected them) or a residue of ulps whose direction vf takes (e.g. the straight candidate 3 m short of a goal at
    y = 4 m points vf along -y)."""
    p0_px, goal_px = program_pixels(p0), program_pixels(goal)
    p1 = p0_px[None] + (step_m * PROGRAM_PX_PER_M) * unit
    gap = goal_px[None] - p1
    norm = np.sqrt(np.einsum("nd,nd->n", gap, gap))
    with np.errstate(divide="ignore", invalid="ignore"):
        return ((end_speed * PROGRAM_PX_PER_M) / norm)[:, None] * gap / PROGRAM_PX_PER_M


class LocalPrimitivesMinJerk:
    """The thesis program's local primitives planner (registry name "local_primitives_minjerk"; module docstring).

    Args:
        context: the trial's fixed facts (dims, dt, limits, arena box, physical).
        n_candidates: number of end points on the circle (2D: at angles 2 pi k / n; 72 = 5 deg apart).
        sphere_spacing_deg: 3D only — end points on the sphere in rings every spacing degrees
            (pbdyn.planning.primitives.local.sphere_directions; 10 deg: 412 points).
        step_m: distance (m) from the MAV to each end point.
        end_speed_frac: end speed as a fraction of v_max, pointing at the goal; end acceleration 0.
        margin: safety margin (m) added to the MAV radius in the collision check.
        duration: primitive duration T (s); default max(1.2 step_m / v_max, 0.5) as the thesis program. A duration
            above pbdyn.limits.MAX_PLAN_HORIZON_S builds no primitive (every plan fails).
        goal_first: try the goal itself (at rest) first when it is nearer than step_m (pbdyn; not the program).
        samples: "all" (check samples 1..K-1) or "program" (the program's per-candidate count; 2D with the
            default duration only, else "all"); see the module docstring.
        arithmetic: "pbdyn" (rank by angle, ties by index; end velocities in metres, an end point on the goal
            never taken) or "program" (2D with 72 candidates: the program's ranking, program_rank, and end
            velocities, program_end_velocities, in its pixel arithmetic; else "pbdyn").
        static_check: "pbdyn" (the MAV ball + margin against OCCUPIED cells, and radius + 0.1 m from the walls;
            pbdyn.planning.checks) or "program" (the program's five probes against its map and the OCCUPIED cells,
            so walls count where they have been seen; checks.program_grid_conflicts).

    Diagnostics of the last plan() call: last_candidates_built (candidates whose samples were computed),
    last_candidates_tried (candidates examined in rank order up to and including the chosen one; all built ones
    on failure), last_rank (rank of the chosen candidate, 0 = best, the goal candidate counting as rank 0 when
    tried; None on failure), last_target (its end point [d]).
    """

    PROGRAM_PARAMS: dict = {"goal_first": False, "samples": "program", "static_check": "program",
                            "arithmetic": "program"}
    """The thesis_program profile's parameters (the other defaults are the program's)."""

    def __init__(self, context: PlannerContext, *, n_candidates: int = 72, sphere_spacing_deg: float = 10.0,
                 step_m: float = 3.0, end_speed_frac: float = 0.5, margin: float = 0.5,
                 duration: float | None = None, goal_first: bool = True, samples: str = "all",
                 static_check: str = "pbdyn", arithmetic: str = "pbdyn"):
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
        if arithmetic not in ("pbdyn", "program"):
            raise ValueError(f"arithmetic must be 'pbdyn' or 'program', got {arithmetic!r}")
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
        self.arithmetic = arithmetic
        self._program_unit = (program_unit_vectors() if arithmetic == "program" and d == 2
                              and self.n_candidates == PROGRAM_THETA_DEG.size else None)
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
        """Candidate indices sorted by the angle between candidate and goal direction (ascending, ties by index;
        arithmetic = "program" with the program's 72 candidates in 2D: program_rank)."""
        if self._program_unit is not None:
            return program_rank(view.goal - view.position)
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
        if self._program_unit is not None:
            vels = program_end_velocities(p0, view.goal, self._program_unit[order], self.step_m, self.end_speed)
            rank = np.flatnonzero(np.isfinite(vels).all(axis=1))
        else:
            to_goal = view.goal[None] - targets
            reach = np.sqrt(np.einsum("nd,nd->n", to_goal, to_goal))
            rank = np.flatnonzero(reach > _COINCIDE_M)   # an end point on the goal has no end direction: never taken
            vels = (self.end_speed / np.where(reach > _COINCIDE_M, reach, 1.0))[:, None] * to_goal
        order, targets, vels = order[rank], targets[rank], vels[rank]
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
